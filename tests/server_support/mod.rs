//! Helpers shared by the server tests: an in-process server on an ephemeral loopback
//! port, a protocol client over tokio-tungstenite, `/metrics` scraping, JPEG decoding.
#![allow(dead_code)] // each test binary uses a different subset

use fogcast::protocol::{ErrorMessage, FrameHeader, ServerMessage, ViewPose, Welcome};
use fogcast::server::{Server, ServerConfig};
use futures_util::{SinkExt as _, StreamExt as _};
use std::net::SocketAddr;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering::Relaxed};
use std::sync::Arc;
use std::time::Duration;
use tokio::io::{AsyncReadExt as _, AsyncWriteExt as _};
use tokio::net::TcpStream;
use tokio_tungstenite::tungstenite::Message;
use tokio_tungstenite::{MaybeTlsStream, WebSocketStream};

pub type Ws = WebSocketStream<MaybeTlsStream<TcpStream>>;

/// Generous bound for anything the server should do "soon" on lavapipe (a frame of 16
/// tiny views takes well under a second); only a hang reaches it.
pub const PATIENCE: Duration = Duration::from_secs(30);

/// A config for tests: loopback, ephemeral port, small frames.
pub fn test_config() -> ServerConfig {
    ServerConfig {
        port: 0,
        fps: 20.0,
        max_width: 640,
        max_height: 360,
        hello_timeout_s: 5.0,
        ..ServerConfig::default()
    }
}

pub fn init_logs() {
    let _ = tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| "fogcast=warn".into()),
        )
        .with_test_writer()
        .try_init();
}

pub async fn start(config: ServerConfig) -> Server {
    init_logs();
    assert!(
        config.addr.is_loopback(),
        "tests only ever serve on loopback"
    );
    Server::start(config).await.expect("server starts")
}

pub async fn connect(addr: SocketAddr) -> Ws {
    let (ws, _) = tokio_tungstenite::connect_async(format!("ws://{addr}/ws"))
        .await
        .expect("websocket connects");
    ws
}

pub async fn send_json(ws: &mut Ws, v: serde_json::Value) {
    ws.send(Message::text(v.to_string())).await.expect("send");
}

pub fn hello(width: u32, height: u32) -> serde_json::Value {
    serde_json::json!({"type": "hello", "version": 1, "width": width, "height": height})
}

/// Next text message, skipping frames; panics on close or timeout.
pub async fn next_text(ws: &mut Ws) -> ServerMessage {
    loop {
        let msg = tokio::time::timeout(PATIENCE, ws.next())
            .await
            .expect("a message in time")
            .expect("stream open")
            .expect("no error");
        match msg {
            Message::Text(t) => {
                return serde_json::from_str(&t).unwrap_or_else(|e| panic!("server JSON {t}: {e}"))
            }
            Message::Binary(_) | Message::Ping(_) | Message::Pong(_) | Message::Frame(_) => {
                continue
            }
            Message::Close(c) => panic!("closed while waiting for a text message: {c:?}"),
        }
    }
}

pub async fn welcome(ws: &mut Ws, hello: serde_json::Value) -> Welcome {
    send_json(ws, hello).await;
    match next_text(ws).await {
        ServerMessage::Welcome(w) => w,
        other => panic!("expected a welcome, got {other:?}"),
    }
}

/// Next frame (header + JPEG bytes), skipping text messages.
pub async fn next_frame(ws: &mut Ws) -> (FrameHeader, Vec<u8>) {
    loop {
        let msg = tokio::time::timeout(PATIENCE, ws.next())
            .await
            .expect("a frame in time")
            .expect("stream open")
            .expect("no error");
        match msg {
            Message::Binary(b) => {
                let (h, jpeg) = FrameHeader::parse(&b).expect("valid frame header");
                return (h, jpeg.to_vec());
            }
            Message::Close(c) => panic!("closed while waiting for a frame: {c:?}"),
            _ => continue,
        }
    }
}

/// Reads until the server's fatal error and close frame; returns both.
pub async fn expect_fatal(ws: &mut Ws) -> (ErrorMessage, u16, String) {
    let mut error = None;
    loop {
        let msg = match tokio::time::timeout(PATIENCE, ws.next())
            .await
            .expect("server answers in time")
        {
            Some(Ok(m)) => m,
            Some(Err(e)) => {
                panic!("connection error before the close frame (error so far: {error:?}): {e}")
            }
            None => panic!("connection ended without a close frame (error so far: {error:?})"),
        };
        match msg {
            Message::Text(t) => {
                if let Ok(ServerMessage::Error(e)) = serde_json::from_str(&t) {
                    error = Some(e);
                }
            }
            Message::Close(Some(c)) => {
                // Sends the close reply tungstenite queued, completing the handshake.
                let _ = ws.flush().await;
                let e = error.expect("an error message before the close frame");
                assert!(e.fatal, "the error before a close is marked fatal: {e:?}");
                return (e, u16::from(c.code), c.reason.to_string());
            }
            Message::Close(None) => panic!("close frame without a code (error: {error:?})"),
            _ => {}
        }
    }
}

/// Next error message, skipping frames; the session must stay open.
pub async fn expect_error(ws: &mut Ws) -> ErrorMessage {
    match next_text(ws).await {
        ServerMessage::Error(e) => e,
        other => panic!("expected an error, got {other:?}"),
    }
}

/// A plain HTTP/1.1 GET on loopback: (status, body).
pub async fn http_get(addr: SocketAddr, path: &str) -> (u16, String) {
    let mut s = TcpStream::connect(addr).await.expect("connect");
    s.write_all(
        format!("GET {path} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n\r\n").as_bytes(),
    )
    .await
    .unwrap();
    let mut buf = Vec::new();
    tokio::time::timeout(PATIENCE, s.read_to_end(&mut buf))
        .await
        .expect("HTTP answer in time")
        .unwrap();
    let text = String::from_utf8_lossy(&buf).to_string();
    let status = text
        .split_whitespace()
        .nth(1)
        .and_then(|c| c.parse().ok())
        .unwrap_or(0);
    let body = text
        .split_once("\r\n\r\n")
        .map(|(_, b)| b.to_string())
        .unwrap_or_default();
    (status, body)
}

/// Sum of every sample of metric `name` whose labels contain `labels`.
pub fn metric(text: &str, name: &str, labels: &str) -> f64 {
    text.lines()
        .filter(|l| !l.starts_with('#'))
        .filter_map(|l| {
            let (key, value) = l.rsplit_once(' ')?;
            let (n, rest) = key.split_once('{').map_or((key, ""), |(n, r)| (n, r));
            (n == name && rest.contains(labels))
                .then(|| value.parse::<f64>().ok())
                .flatten()
        })
        .sum()
}

pub async fn metrics(addr: SocketAddr) -> String {
    let (status, body) = http_get(addr, "/metrics").await;
    assert_eq!(status, 200);
    body
}

pub fn decode_jpeg(jpeg: &[u8]) -> image::RgbImage {
    image::load_from_memory_with_format(jpeg, image::ImageFormat::Jpeg)
        .expect("a valid JPEG")
        .to_rgb8()
}

/// Mean absolute difference of two same-size images' channels (0–255).
pub fn mean_abs_diff(a: &image::RgbImage, b: &image::RgbImage) -> f64 {
    assert_eq!(a.dimensions(), b.dimensions());
    let sum: u64 = a
        .as_raw()
        .iter()
        .zip(b.as_raw())
        .map(|(x, y)| x.abs_diff(*y) as u64)
        .sum();
    sum as f64 / a.as_raw().len() as f64
}

/// Saves `img` under `$FOGCAST_TEST_OUT` when set (for looking at what a test saw).
pub fn save_for_inspection(img: &image::RgbImage, name: &str) {
    if let Some(dir) = std::env::var_os("FOGCAST_TEST_OUT") {
        let dir = std::path::PathBuf::from(dir);
        std::fs::create_dir_all(&dir).unwrap();
        img.save(dir.join(name)).unwrap();
    }
}

pub fn mean_luma(img: &image::RgbImage) -> f64 {
    img.pixels()
        .map(|p| 0.2126 * p[0] as f64 + 0.7152 * p[1] as f64 + 0.0722 * p[2] as f64)
        .sum::<f64>()
        / (img.width() * img.height()) as f64
}

/// A well-behaved viewer in the background: mono session, sends a pose every 100 ms,
/// counts the frames it receives. Dropping it disconnects.
pub struct Viewer {
    pub frames: Arc<AtomicU64>,
    pub closed: Arc<AtomicBool>,
    task: tokio::task::JoinHandle<()>,
}

impl Viewer {
    pub async fn start(addr: SocketAddr, width: u32, height: u32) -> Viewer {
        Viewer::start_with(addr, hello(width, height)).await
    }

    /// As [`Viewer::start`] with a hello of the caller's (a token, say).
    pub async fn start_with(addr: SocketAddr, hello: serde_json::Value) -> Viewer {
        let mut ws = connect(addr).await;
        let w = welcome(&mut ws, hello).await;
        let pose = w.poses[0];
        let frames = Arc::new(AtomicU64::new(0));
        let closed = Arc::new(AtomicBool::new(false));
        let (f, c) = (frames.clone(), closed.clone());
        let task = tokio::spawn(async move {
            let mut seq = 0u32;
            let mut tick = tokio::time::interval(Duration::from_millis(100));
            loop {
                tokio::select! {
                    msg = ws.next() => match msg {
                        Some(Ok(Message::Binary(_))) => { f.fetch_add(1, Relaxed); }
                        Some(Ok(Message::Close(_))) | None | Some(Err(_)) => break,
                        Some(Ok(_)) => {}
                    },
                    _ = tick.tick() => {
                        seq += 1;
                        let p = ViewPose { position: [pose.position[0], pose.position[1], pose.position[2] + 0.01 * (seq % 10) as f64], ..pose };
                        let msg = serde_json::json!({"type": "pose", "seq": seq, "views": [p]});
                        if ws.send(Message::text(msg.to_string())).await.is_err() { break; }
                    }
                }
            }
            c.store(true, Relaxed);
        });
        Viewer {
            frames,
            closed,
            task,
        }
    }

    pub fn frames(&self) -> u64 {
        self.frames.load(Relaxed)
    }

    /// Waits until the viewer has received `n` more frames than `since`.
    pub async fn wait_frames(&self, since: u64, n: u64) {
        tokio::time::timeout(PATIENCE, async {
            while self.frames() < since + n {
                assert!(
                    !self.closed.load(Relaxed),
                    "the well-behaved viewer was disconnected"
                );
                tokio::time::sleep(Duration::from_millis(10)).await;
            }
        })
        .await
        .expect("the well-behaved viewer keeps receiving frames");
    }
}

impl Drop for Viewer {
    fn drop(&mut self) {
        self.task.abort();
    }
}

/// Polls `/metrics` until `pred` holds (for counters updated asynchronously).
pub async fn wait_metrics(addr: SocketAddr, what: &str, pred: impl Fn(&str) -> bool) -> String {
    tokio::time::timeout(PATIENCE, async {
        loop {
            let m = metrics(addr).await;
            if pred(&m) {
                return m;
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    })
    .await
    .unwrap_or_else(|_| panic!("metrics never showed {what}"))
}
