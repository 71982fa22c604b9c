//! One simulated viewer: a real WebSocket session that says hello, flies its camera path
//! sending poses at a fixed rate, and records every frame that arrives (time, size,
//! header). Statistics are computed afterwards from the records (`super::stats`).

use super::paths::Paths;
use crate::protocol::{
    clip, ClientMessage, FrameHeader, Hello, PoseUpdate, ServerMessage, ViewPose, Welcome,
};
use anyhow::Context as _;
use futures_util::{SinkExt as _, StreamExt as _};
use std::sync::atomic::{AtomicU64, Ordering::Relaxed};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio::net::TcpStream;
use tokio::sync::watch;
use tokio_tungstenite::tungstenite::{self, http::Uri, Message};
use tokio_tungstenite::{MaybeTlsStream, WebSocketStream};

type Ws = WebSocketStream<MaybeTlsStream<TcpStream>>;

/// Longest wait for the TCP + WebSocket handshake, and then for the welcome.
const HANDSHAKE_TIMEOUT: Duration = Duration::from_secs(15);
/// Longest wait for the server's close reply when a viewer leaves.
const CLOSE_TIMEOUT: Duration = Duration::from_secs(5);

/// The server to load: its WebSocket URL and its `host:port` for `/healthz` and `/metrics`.
#[derive(Debug, Clone)]
pub(crate) struct Target {
    pub(crate) ws_url: String,
    pub(crate) authority: String,
}

impl Target {
    pub(crate) fn parse(url: &str) -> anyhow::Result<Target> {
        let uri: Uri = url
            .parse()
            .with_context(|| format!("--url {url:?}: not a URL; use ws://HOST:PORT/ws"))?;
        match uri.scheme_str() {
            Some("ws") => {}
            Some("wss") => anyhow::bail!(
                "--url {url}: wss:// (TLS) is not supported; connect to the server's plain ws:// port"
            ),
            other => anyhow::bail!(
                "--url {url}: scheme {:?} is not ws; use ws://HOST:PORT/ws",
                other.unwrap_or("")
            ),
        }
        let host = uri
            .host()
            .with_context(|| format!("--url {url}: no host; use ws://HOST:PORT/ws"))?;
        let port = uri.port_u16().unwrap_or(80);
        Ok(Target {
            ws_url: url.to_string(),
            authority: format!("{host}:{port}"),
        })
    }
}

/// Opens a session: WebSocket handshake, hello, welcome. Errors say what the server said.
pub(crate) async fn open(target: &Target, hello: &Hello) -> anyhow::Result<(Ws, Welcome)> {
    let url = &target.ws_url;
    let (mut ws, _) = match tokio::time::timeout(
        HANDSHAKE_TIMEOUT,
        tokio_tungstenite::connect_async(url.as_str()),
    )
    .await
    {
        Err(_) => anyhow::bail!(
            "{url}: no WebSocket handshake within {} s",
            HANDSHAKE_TIMEOUT.as_secs()
        ),
        Ok(Ok(ok)) => ok,
        Ok(Err(tungstenite::Error::Http(response))) => {
            let body = response
                .body()
                .as_deref()
                .map(|b| String::from_utf8_lossy(b).trim().to_string())
                .unwrap_or_default();
            anyhow::bail!(
                "{url}: the server refused the WebSocket upgrade with HTTP {}: {body}",
                response.status()
            )
        }
        Ok(Err(tungstenite::Error::Io(e))) => anyhow::bail!(
            "cannot connect to {url} ({e}): is `fogcast serve` running there? (`make run` starts one on 127.0.0.1:8080)"
        ),
        Ok(Err(e)) => return Err(e).with_context(|| format!("connecting to {url}")),
    };
    ws.send(Message::text(ClientMessage::Hello(hello.clone()).to_json()))
        .await
        .with_context(|| format!("{url}: sending the hello"))?;
    let answer = tokio::time::timeout(HANDSHAKE_TIMEOUT, async {
        loop {
            match ws.next().await {
                Some(Ok(Message::Text(t))) => {
                    return match serde_json::from_str::<ServerMessage>(&t) {
                        Ok(ServerMessage::Welcome(w)) => Ok(w),
                        Ok(ServerMessage::Error(e)) => Err(anyhow::anyhow!(
                            "{url}: the server refused the hello: {}: {}",
                            e.code.as_str(),
                            e.message
                        )),
                        Err(e) => Err(anyhow::anyhow!(
                            "{url}: the answer to the hello is not a welcome ({e}): {t}"
                        )),
                    }
                }
                Some(Ok(Message::Close(c))) => {
                    return Err(anyhow::anyhow!(
                        "the server closed the session instead of welcoming it: {}",
                        c.map(|c| format!("{} {}", u16::from(c.code), c.reason))
                            .unwrap_or_else(|| "no reason given".into())
                    ))
                }
                Some(Ok(_)) => continue,
                Some(Err(e)) => {
                    return Err(anyhow::anyhow!(
                        "{url}: connection lost during the hello: {e}"
                    ))
                }
                None => return Err(anyhow::anyhow!("{url}: connection closed during the hello")),
            }
        }
    })
    .await
    .map_err(|_| {
        anyhow::anyhow!(
            "{url}: no welcome within {} s of the hello",
            HANDSHAKE_TIMEOUT.as_secs()
        )
    })??;
    Ok((ws, answer))
}

/// One frame as it arrived.
#[derive(Debug, Clone, Copy)]
pub(crate) struct FrameRecord {
    pub(crate) at: Instant,
    /// Bytes of the whole WebSocket message (header + JPEG).
    pub(crate) bytes: u32,
    pub(crate) header: FrameHeader,
}

/// Counters the coordinator reads while the viewers run.
#[derive(Debug, Default)]
pub(crate) struct Live {
    pub(crate) frames: AtomicU64,
    /// Why the stream ended early (server close, error), once it has.
    pub(crate) ended: Mutex<Option<String>>,
}

impl Live {
    pub(crate) fn ended(&self) -> Option<String> {
        self.ended.lock().unwrap_or_else(|e| e.into_inner()).clone()
    }
}

/// Everything one viewer saw.
#[derive(Debug, Default)]
pub(crate) struct ViewerRecord {
    pub(crate) frames: Vec<FrameRecord>,
    /// When pose `seq` was sent is `pose_sent[seq - 1]` (sequence numbers start at 1).
    pub(crate) pose_sent: Vec<Instant>,
    /// Frames whose header or JPEG markers do not match the session.
    pub(crate) bad_frames: u64,
    /// Error messages the server sent.
    pub(crate) server_errors: Vec<String>,
}

/// Where one viewer flies.
pub(crate) struct Flight {
    pub(crate) paths: Arc<Paths>,
    /// First path slot of this session; it owns `welcome.poses.len()` slots from there.
    pub(crate) first_slot: usize,
    /// Slots over all sessions of the sweep point.
    pub(crate) slots: usize,
    pub(crate) pose_hz: f64,
    /// Time 0 of the camera paths.
    pub(crate) epoch: Instant,
}

/// Streams until `stop` turns true or the server ends the session.
pub(crate) async fn stream(
    mut ws: Ws,
    welcome: Welcome,
    flight: Flight,
    live: Arc<Live>,
    mut stop: watch::Receiver<bool>,
) -> ViewerRecord {
    let mut rec = ViewerRecord::default();
    let mut tick = tokio::time::interval(Duration::from_secs_f64(1.0 / flight.pose_hz));
    // After a stall, carry on at the rate rather than bursting into the rate limit.
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    let mut ended = None;
    loop {
        tokio::select! {
            biased;
            // (The guard `wait_for` returns is not Send: drop it inside the block.)
            () = async { let _ = stop.wait_for(|s| *s).await; } => break,
            msg = ws.next() => match msg {
                Some(Ok(Message::Binary(b))) => {
                    let at = Instant::now();
                    match FrameHeader::parse(&b) {
                        Some((header, jpeg)) => {
                            let fits = header.layout == welcome.layout
                                && u32::from(header.views) == welcome.views
                                && u32::from(header.width) == welcome.width
                                && u32::from(header.height) == welcome.height
                                && jpeg.starts_with(&[0xFF, 0xD8])
                                && jpeg.ends_with(&[0xFF, 0xD9]);
                            if !fits {
                                rec.bad_frames += 1;
                            }
                            rec.frames.push(FrameRecord { at, bytes: b.len() as u32, header });
                            live.frames.fetch_add(1, Relaxed);
                        }
                        None => rec.bad_frames += 1,
                    }
                }
                Some(Ok(Message::Text(t))) => match serde_json::from_str::<ServerMessage>(&t) {
                    Ok(ServerMessage::Error(e)) => rec.server_errors.push(format!("{}: {}", e.code.as_str(), e.message)),
                    Ok(ServerMessage::Welcome(_)) => {}
                    Err(_) => rec.server_errors.push(format!("unreadable server message: {}", clip(&t))),
                },
                Some(Ok(Message::Close(c))) => {
                    ended = Some(format!(
                        "the server closed the session: {}",
                        c.map(|c| format!("{} {}", u16::from(c.code), c.reason)).unwrap_or_else(|| "no reason given".into())
                    ));
                    break;
                }
                Some(Ok(_)) => {}
                Some(Err(e)) => { ended = Some(format!("connection error: {e}")); break; }
                None => { ended = Some("the connection ended".into()); break; }
            },
            _ = tick.tick() => {
                let seq = rec.pose_sent.len() as u32 + 1;
                let t = flight.epoch.elapsed().as_secs_f64();
                let views: Vec<ViewPose> = welcome.poses.iter().enumerate()
                    .map(|(j, start)| flight.paths.pose(flight.first_slot + j, flight.slots, t, start))
                    .collect();
                let msg = ClientMessage::Pose(PoseUpdate { seq, views });
                rec.pose_sent.push(Instant::now());
                if let Err(e) = ws.send(Message::text(msg.to_json())).await {
                    ended = Some(format!("sending a pose failed: {e}"));
                    break;
                }
            }
        }
    }
    match ended {
        Some(why) => *live.ended.lock().unwrap_or_else(|e| e.into_inner()) = Some(why),
        None => {
            // A clean goodbye: close frame, then wait for the server's reply.
            let _ = tokio::time::timeout(CLOSE_TIMEOUT, async {
                if ws.close(None).await.is_ok() {
                    while let Some(Ok(_)) = ws.next().await {}
                }
            })
            .await;
        }
    }
    rec
}
