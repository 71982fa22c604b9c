//! One simulated viewer: a real WebSocket session that says hello, flies its camera path
//! sending poses at a fixed rate, acks every frame, and records every frame that arrives
//! (time, size, header). With `--raw-every` it decodes the encoded frames and measures
//! their PSNR against the raw ones; with `--churn-s` it closes and reopens its session
//! periodically; with `--throttle-kbps` it reads its socket slowly. Statistics are
//! computed afterwards from the records (`super::stats`).

use super::paths::Paths;
use super::quality::{payload_looks_valid, psnr, StreamDecoder};
use super::throttle::Throttled;
use crate::protocol::{
    clip, Ack, ClientMessage, ErrorCode, FrameCodec, FrameHeader, Hello, PoseUpdate, ServerMessage,
    ViewPose, Welcome,
};
use anyhow::Context as _;
use futures_util::{SinkExt as _, StreamExt as _};
use std::sync::atomic::{AtomicU64, Ordering::Relaxed};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio::net::TcpStream;
use tokio::sync::watch;
use tokio_tungstenite::tungstenite::{self, http::Uri, Message};
use tokio_tungstenite::WebSocketStream;

pub(crate) type Ws = WebSocketStream<Throttled<TcpStream>>;

/// Longest wait for the TCP + WebSocket handshake, and then for the welcome.
const HANDSHAKE_TIMEOUT: Duration = Duration::from_secs(15);
/// Longest wait for the server's close reply when a viewer leaves.
const CLOSE_TIMEOUT: Duration = Duration::from_secs(5);
/// A churning viewer tries this many times, [`REOPEN_PAUSE`] apart, to open its next
/// session (the server may not have released the previous one's views yet).
const REOPEN_ATTEMPTS: u32 = 40;
const REOPEN_PAUSE: Duration = Duration::from_millis(250);

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

/// Opens a session: TCP connection (its reads limited to `throttle_kbps`), WebSocket
/// handshake, hello, welcome. Errors say what the server said.
pub(crate) async fn open(
    target: &Target,
    hello: &Hello,
    throttle_kbps: Option<u32>,
) -> anyhow::Result<(Ws, Welcome)> {
    let url = &target.ws_url;
    let connect = async {
        let tcp = TcpStream::connect(&target.authority)
            .await
            .map_err(tungstenite::Error::Io)?;
        tcp.set_nodelay(true).map_err(tungstenite::Error::Io)?;
        tokio_tungstenite::client_async(url.as_str(), Throttled::new(tcp, throttle_kbps)).await
    };
    let (mut ws, _) = match tokio::time::timeout(HANDSHAKE_TIMEOUT, connect).await
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

/// One frame as it arrived (raw debugging frames are not recorded as frames).
#[derive(Debug, Clone, Copy)]
pub(crate) struct FrameRecord {
    pub(crate) at: Instant,
    /// Bytes of the whole WebSocket message (header + encoded payload).
    pub(crate) bytes: u32,
    /// Bytes of the encoded payload alone.
    pub(crate) payload_bytes: u32,
    /// Which of the viewer's sessions it came in (0: the first; churn opens more).
    pub(crate) session_no: u32,
    pub(crate) header: FrameHeader,
}

/// Counters the coordinator reads while the viewers run.
#[derive(Debug, Default)]
pub(crate) struct Live {
    pub(crate) frames: AtomicU64,
    /// Sessions this viewer opened after its first (churn), readable after an abort.
    pub(crate) reopened: AtomicU64,
    /// Why the stream ended early (server close, error), once it has.
    pub(crate) ended: Mutex<Option<String>>,
}

impl Live {
    pub(crate) fn ended(&self) -> Option<String> {
        self.ended.lock().unwrap_or_else(|e| e.into_inner()).clone()
    }

    fn end(&self, why: String) {
        *self.ended.lock().unwrap_or_else(|e| e.into_inner()) = Some(why);
    }
}

/// Everything one viewer saw.
#[derive(Debug, Default)]
pub(crate) struct ViewerRecord {
    pub(crate) frames: Vec<FrameRecord>,
    /// When pose `seq` was sent is `pose_sent[seq - 1]` (sequence numbers start at 1 and
    /// go on across the viewer's sessions).
    pub(crate) pose_sent: Vec<Instant>,
    /// Frames whose header or payload do not match the session.
    pub(crate) bad_frames: u64,
    /// Error messages the server sent.
    pub(crate) server_errors: Vec<String>,
    /// Raw (debugging) frames received.
    pub(crate) raw_frames: u64,
    /// PSNR of each encoded frame compared with its raw frame, dB, and when it arrived.
    pub(crate) psnr: Vec<(Instant, f64)>,
    /// Encoded frames that did not decode (each answered with a keyframe request).
    pub(crate) decode_errors: u64,
    /// Sessions this viewer opened (1 without churn).
    pub(crate) sessions_opened: u64,
    /// Failed attempts to open a churned session again, and the last reason.
    pub(crate) reopen_failures: u64,
    pub(crate) last_reopen_error: Option<String>,
    /// Welcomes with `reason: bandwidth` (the server changed the frame size).
    pub(crate) bandwidth_welcomes: u64,
    /// The server answered an ack with `unknown_type` (a server from before acks): this
    /// viewer stopped acking.
    pub(crate) acks_refused: bool,
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

/// How one viewer behaves beyond flying.
pub(crate) struct Behaviour {
    /// The server and hello, to open churned sessions again.
    pub(crate) target: Target,
    pub(crate) hello: Hello,
    /// Reads limited to this many kbit/s.
    pub(crate) throttle_kbps: Option<u32>,
    /// Ack every frame.
    pub(crate) ack: bool,
    /// Decode encoded frames and compare them with raw ones (`raw_every`).
    pub(crate) measure_quality: bool,
    /// Close and reopen the session: first after `.0`, then every `.1`.
    pub(crate) churn: Option<(Duration, Duration)>,
}

/// How one session of a viewer ended.
enum SessionEnd {
    /// The coordinator said stop.
    Stopped,
    /// Time to churn: close and open a new session.
    Churn,
    /// The server or the connection ended it.
    Lost(String),
}

/// Streams until `stop` turns true or the server ends the session; with churn, closes
/// and reopens its session on schedule.
pub(crate) async fn stream(
    mut ws: Ws,
    mut welcome: Welcome,
    flight: Flight,
    behaviour: Behaviour,
    live: Arc<Live>,
    mut stop: watch::Receiver<bool>,
) -> ViewerRecord {
    let mut rec = ViewerRecord {
        sessions_opened: 1,
        ..ViewerRecord::default()
    };
    let mut tick = tokio::time::interval(Duration::from_secs_f64(1.0 / flight.pose_hz));
    // After a stall, carry on at the rate rather than bursting into the rate limit.
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    let mut next_churn = behaviour.churn.map(|(first, _)| Instant::now() + first);
    let mut session_no = 0;
    loop {
        let end = session(
            &mut ws,
            &mut welcome,
            &flight,
            &behaviour,
            (&mut tick, &mut stop, next_churn, session_no),
            &live,
            &mut rec,
        )
        .await;
        match end {
            SessionEnd::Stopped => {
                goodbye(&mut ws).await;
                break;
            }
            SessionEnd::Lost(why) => {
                live.end(why);
                break;
            }
            SessionEnd::Churn => {
                goodbye(&mut ws).await;
                match reopen(&behaviour, &mut stop, &mut rec).await {
                    Ok(Some((new_ws, new_welcome))) => {
                        ws = new_ws;
                        welcome = new_welcome;
                        session_no += 1;
                        rec.sessions_opened += 1;
                        live.reopened.fetch_add(1, Relaxed);
                    }
                    Ok(None) => break,
                    Err(why) => {
                        live.end(why);
                        break;
                    }
                }
                // On schedule, unless reopening took so long the slot has passed.
                let period = behaviour.churn.map_or(Duration::MAX, |(_, p)| p);
                let now = Instant::now();
                next_churn = next_churn.and_then(|t| t.checked_add(period)).map(|t| {
                    if t < now {
                        now + period
                    } else {
                        t
                    }
                });
            }
        }
    }
    rec
}

/// A clean goodbye: close frame, then wait for the server's reply.
async fn goodbye(ws: &mut Ws) {
    let _ = tokio::time::timeout(CLOSE_TIMEOUT, async {
        if ws.close(None).await.is_ok() {
            while let Some(Ok(_)) = ws.next().await {}
        }
    })
    .await;
}

/// Opens the next session of a churning viewer, retrying while the server has not let
/// the previous one go; `Ok(None)` when told to stop meanwhile.
async fn reopen(
    b: &Behaviour,
    stop: &mut watch::Receiver<bool>,
    rec: &mut ViewerRecord,
) -> Result<Option<(Ws, Welcome)>, String> {
    for _ in 0..REOPEN_ATTEMPTS {
        if *stop.borrow() {
            return Ok(None);
        }
        match open(&b.target, &b.hello, b.throttle_kbps).await {
            Ok(opened) => return Ok(Some(opened)),
            Err(e) => {
                rec.reopen_failures += 1;
                rec.last_reopen_error = Some(format!("{e:#}"));
                tokio::time::sleep(REOPEN_PAUSE).await;
            }
        }
    }
    Err(format!(
        "could not open session {} after {REOPEN_ATTEMPTS} attempts: {}",
        rec.sessions_opened + 1,
        rec.last_reopen_error.as_deref().unwrap_or("no reason")
    ))
}

/// One session's stream: frames in, poses and acks out, until stop, churn or loss.
async fn session(
    ws: &mut Ws,
    welcome: &mut Welcome,
    flight: &Flight,
    b: &Behaviour,
    (tick, stop, churn_at, session_no): (
        &mut tokio::time::Interval,
        &mut watch::Receiver<bool>,
        Option<Instant>,
        u32,
    ),
    live: &Live,
    rec: &mut ViewerRecord,
) -> SessionEnd {
    let mut decoder = StreamDecoder::default();
    // After an H.264 decode error, the P frames until the requested key frame cannot
    // decode either: they are not tried (nor counted as more errors).
    let mut awaiting_key = false;
    // The raw frame sent right before its encoded frame: (frame number, RGBA pixels).
    let mut raw: Option<(u32, Vec<u8>)> = None;
    let churn = async {
        match churn_at {
            Some(t) => tokio::time::sleep_until(t.into()).await,
            None => std::future::pending().await,
        }
    };
    tokio::pin!(churn);
    loop {
        let mut reply = None;
        tokio::select! {
            biased;
            // (The guard `wait_for` returns is not Send: drop it inside the block.)
            () = async { let _ = stop.wait_for(|s| *s).await; } => return SessionEnd::Stopped,
            () = &mut churn => return SessionEnd::Churn,
            msg = ws.next() => match msg {
                Some(Ok(Message::Binary(bytes))) => {
                    let at = Instant::now();
                    match FrameHeader::parse(&bytes) {
                        Some((header, payload)) if header.codec == FrameCodec::Raw => {
                            rec.raw_frames += 1;
                            let want = usize::from(header.width) * usize::from(header.height) * 4;
                            if payload.len() != want {
                                rec.bad_frames += 1;
                            } else if b.measure_quality {
                                raw = Some((header.frame, payload.to_vec()));
                            }
                        }
                        Some((header, payload)) => {
                            let fits = header.layout == welcome.layout
                                && u32::from(header.views) == welcome.views
                                && u32::from(header.width) == welcome.width
                                && u32::from(header.height) == welcome.height
                                && header.codec.code() == welcome.codec.code()
                                && payload_looks_valid(header.codec, payload);
                            if !fits {
                                rec.bad_frames += 1;
                            }
                            rec.frames.push(FrameRecord {
                                at,
                                bytes: bytes.len() as u32,
                                payload_bytes: payload.len() as u32,
                                session_no,
                                header,
                            });
                            live.frames.fetch_add(1, Relaxed);
                            if b.ack && !rec.acks_refused {
                                reply = Some(ClientMessage::Ack(Ack { frame: header.frame }));
                            }
                            if header.key {
                                awaiting_key = false;
                            }
                            if b.measure_quality && !awaiting_key {
                                match decoder.decode(&header, payload) {
                                    Ok(Some(rgb)) => {
                                        if let Some((_, pixels)) = raw.take().filter(|(n, _)| *n == header.frame) {
                                            if let Some(db) = psnr(&rgb, &pixels) {
                                                rec.psnr.push((at, db));
                                            }
                                        }
                                    }
                                    Ok(None) => {}
                                    Err(_) => {
                                        rec.decode_errors += 1;
                                        decoder.reset();
                                        if header.codec == FrameCodec::H264 {
                                            awaiting_key = true;
                                            // The ack goes out first, then the request.
                                            if let Some(ack) = reply.take() {
                                                if let Err(e) = ws.send(Message::text(ack.to_json())).await {
                                                    return SessionEnd::Lost(format!("sending an ack failed: {e}"));
                                                }
                                            }
                                            reply = Some(ClientMessage::Keyframe);
                                        }
                                    }
                                }
                            }
                        }
                        None => rec.bad_frames += 1,
                    }
                }
                Some(Ok(Message::Text(t))) => match serde_json::from_str::<ServerMessage>(&t) {
                    Ok(ServerMessage::Error(e)) if e.code == ErrorCode::UnknownType && e.message.contains("\"ack\"") => {
                        // An older server: carry on without acks rather than be closed
                        // for too many errors.
                        rec.acks_refused = true;
                    }
                    Ok(ServerMessage::Error(e)) => rec.server_errors.push(format!("{}: {}", e.code.as_str(), e.message)),
                    Ok(ServerMessage::Welcome(w)) => {
                        if w.reason == crate::protocol::WelcomeReason::Bandwidth {
                            rec.bandwidth_welcomes += 1;
                        }
                        *welcome = w;
                    }
                    Err(_) => rec.server_errors.push(format!("unreadable server message: {}", clip(&t))),
                },
                Some(Ok(Message::Close(c))) => {
                    return SessionEnd::Lost(format!(
                        "the server closed the session: {}",
                        c.map(|c| format!("{} {}", u16::from(c.code), c.reason)).unwrap_or_else(|| "no reason given".into())
                    ));
                }
                Some(Ok(_)) => {}
                Some(Err(e)) => return SessionEnd::Lost(format!("connection error: {e}")),
                None => return SessionEnd::Lost("the connection ended".into()),
            },
            _ = tick.tick() => {
                let seq = rec.pose_sent.len() as u32 + 1;
                let t = flight.epoch.elapsed().as_secs_f64();
                let views: Vec<ViewPose> = welcome.poses.iter().enumerate()
                    .map(|(j, start)| flight.paths.pose(flight.first_slot + j, flight.slots, t, start))
                    .collect();
                rec.pose_sent.push(Instant::now());
                reply = Some(ClientMessage::Pose(PoseUpdate { seq, views }));
            }
        }
        if let Some(msg) = reply {
            if let Err(e) = ws.send(Message::text(msg.to_json())).await {
                return SessionEnd::Lost(format!("sending a message failed: {e}"));
            }
        }
    }
}
