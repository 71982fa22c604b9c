//! Connection hardening, with real sockets: a half-sent request (slowloris) is closed
//! by the header-read timeout and does not hold up shutdown; idle unauthenticated
//! connections are capped per address and do not count against the sessions' capacity;
//! cross-origin upgrades are refused; wrong tokens back off per address; `/metrics` can
//! require a token.

mod server_support;

use fogcast::protocol::ServerMessage;
use fogcast::server::ServerConfig;
use server_support::*;
use std::net::SocketAddr;
use std::time::{Duration, Instant};
use tokio::io::{AsyncReadExt as _, AsyncWriteExt as _};
use tokio::net::{TcpSocket, TcpStream};
use tokio_tungstenite::tungstenite::client::IntoClientRequest as _;
use tokio_tungstenite::tungstenite::http::HeaderValue;

const TOKEN: &str = "s3cret-token";

/// A TCP connection to `addr` from the loopback address `from` (127.0.0.x).
async fn tcp_from(from: &str, addr: SocketAddr) -> TcpStream {
    let s = TcpSocket::new_v4().unwrap();
    s.bind(format!("{from}:0").parse().unwrap()).unwrap();
    s.connect(addr).await.expect("tcp connects")
}

/// A WebSocket to `/ws` from `from`; `Err` when the upgrade is refused or cut.
async fn ws_from(from: &str, addr: SocketAddr) -> Result<Ws, String> {
    let tcp = tcp_from(from, addr).await;
    let (ws, _) = tokio_tungstenite::client_async(
        format!("ws://{addr}/ws"),
        tokio_tungstenite::MaybeTlsStream::Plain(tcp),
    )
    .await
    .map_err(|e| e.to_string())?;
    Ok(ws)
}

/// Reads until the server closes the connection; the bytes it sent before.
async fn read_until_closed(s: &mut TcpStream) -> Vec<u8> {
    let mut buf = Vec::new();
    tokio::time::timeout(PATIENCE, s.read_to_end(&mut buf))
        .await
        .expect("the server closes the connection")
        .ok();
    buf
}

const HALF_REQUEST: &[u8] = b"GET /ws HTTP/1.1\r\nHost: 127.0.0.1\r\nUpgrade: websocket\r\n";

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_slowloris_is_closed_by_the_header_timeout_and_does_not_block_shutdown() {
    let server = start(ServerConfig {
        header_timeout_s: 1.0,
        ..test_config()
    })
    .await;
    let addr = server.local_addr();
    let mut silent = TcpStream::connect(addr).await.unwrap();
    let mut slow = TcpStream::connect(addr).await.unwrap();
    slow.write_all(HALF_REQUEST).await.unwrap();
    let started = Instant::now();
    let _ = read_until_closed(&mut slow).await;
    let held = started.elapsed();
    eprintln!(
        "half-sent request closed after {:.2} s (timeout 1 s)",
        held.as_secs_f64()
    );
    assert!(
        held >= Duration::from_millis(900),
        "closed by the timeout, not at once: {held:?}"
    );
    // A connection that never sends a byte is closed too.
    let _ = read_until_closed(&mut silent).await;
    // A viewer is served meanwhile and after.
    let viewer = Viewer::start(addr, 64, 36).await;
    viewer.wait_frames(0, 2).await;
    server.shutdown().await.unwrap();

    // Shutdown with a half-sent request open (and no header timeout to save us): the
    // deadline closes it.
    let server = start(ServerConfig {
        header_timeout_s: 3600.0,
        shutdown_timeout_s: 1.0,
        ..test_config()
    })
    .await;
    let addr = server.local_addr();
    let mut slow = TcpStream::connect(addr).await.unwrap();
    slow.write_all(HALF_REQUEST).await.unwrap();
    tokio::time::sleep(Duration::from_millis(200)).await;
    tokio::time::timeout(PATIENCE, server.shutdown())
        .await
        .expect("shutdown finishes with a half-sent request open")
        .unwrap();
    let _ = read_until_closed(&mut slow).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_hundred_idle_unauthenticated_connections_do_not_lock_out_a_token_holder() {
    let server = start(ServerConfig {
        token: Some(TOKEN.into()),
        hello_timeout_s: 60.0,
        max_connections: 4,
        max_pending_per_ip: 16,
        ..test_config()
    })
    .await;
    let addr = server.local_addr();
    let mut idle = Vec::new();
    let mut cut = 0;
    for _ in 0..100 {
        match ws_from("127.0.0.2", addr).await {
            Ok(ws) => idle.push(ws),
            Err(_) => cut += 1,
        }
    }
    eprintln!(
        "idle upgrades from one address: {} open, {cut} cut",
        idle.len()
    );
    assert_eq!(idle.len(), 16, "capped per address");
    // More than max_connections are open and waiting for a hello: they do not count.
    let mut ws = ws_from("127.0.0.1", addr)
        .await
        .expect("the token holder connects");
    let hello = serde_json::json!({"type": "hello", "version": 1, "width": 64, "height": 36, "token": TOKEN});
    let w = welcome(&mut ws, hello).await;
    assert_eq!(w.width, 64);
    next_frame(&mut ws).await;
    drop(idle);
    server.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn cross_origin_upgrades_are_refused() {
    let server = start(ServerConfig {
        allowed_origins: vec!["https://fog.example.org".into()],
        ..test_config()
    })
    .await;
    let addr = server.local_addr();
    let with_origin = |origin: &str| {
        let mut req = format!("ws://{addr}/ws").into_client_request().unwrap();
        req.headers_mut()
            .insert("Origin", HeaderValue::from_str(origin).unwrap());
        req
    };
    let refused = tokio_tungstenite::connect_async(with_origin("https://evil.example")).await;
    match refused {
        Err(tokio_tungstenite::tungstenite::Error::Http(resp)) => {
            assert_eq!(resp.status().as_u16(), 403)
        }
        other => panic!("a cross-origin upgrade must be refused with 403: {other:?}"),
    }
    for ok in [
        format!("http://{addr}"),
        "http://localhost:3000".into(),
        "https://fog.example.org".into(),
    ] {
        let (mut ws, _) = tokio_tungstenite::connect_async(with_origin(&ok))
            .await
            .unwrap_or_else(|e| panic!("origin {ok} is allowed: {e}"));
        welcome(&mut ws, hello(64, 36)).await;
    }
    server.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn wrong_tokens_back_off_per_address_and_metrics_can_need_a_token() {
    let server = start(ServerConfig {
        token: Some(TOKEN.into()),
        metrics_token: Some("m3trics".into()),
        ..test_config()
    })
    .await;
    let addr = server.local_addr();
    let attempt = |from: &'static str, token: &'static str| async move {
        let mut ws = ws_from(from, addr).await.unwrap();
        let hello = serde_json::json!({"type": "hello", "version": 1, "width": 64, "height": 36, "token": token});
        send_json(&mut ws, hello).await;
        match next_text(&mut ws).await {
            ServerMessage::Welcome(_) => Ok(()),
            ServerMessage::Error(e) => Err(e.message),
        }
    };
    let mut messages = Vec::new();
    for _ in 0..4 {
        messages.push(attempt("127.0.0.3", "guess").await.unwrap_err());
    }
    assert!(messages.iter().all(|m| m == "wrong token"), "{messages:?}");
    // Backing off: even the right token is not checked now.
    let e = attempt("127.0.0.3", TOKEN).await.unwrap_err();
    assert!(e.contains("retry in"), "{e}");
    // Another address is not affected.
    attempt("127.0.0.4", TOKEN).await.unwrap();

    let get = |auth: Option<&'static str>| async move {
        let mut s = TcpStream::connect(addr).await.unwrap();
        let auth = auth.map_or(String::new(), |a| format!("Authorization: Bearer {a}\r\n"));
        s.write_all(
            format!("GET /metrics HTTP/1.1\r\nHost: {addr}\r\n{auth}Connection: close\r\n\r\n")
                .as_bytes(),
        )
        .await
        .unwrap();
        let text = String::from_utf8_lossy(&read_until_closed(&mut s).await).to_string();
        text.split_whitespace().nth(1).unwrap_or("").to_string()
    };
    assert_eq!(get(None).await, "401");
    assert_eq!(get(Some("nope")).await, "401");
    assert_eq!(get(Some("m3trics")).await, "200");
    assert_eq!(
        http_get(addr, "/healthz").await.0,
        200,
        "healthz stays public"
    );
    server.shutdown().await.unwrap();
}

/// The real binary: SIGTERM with a half-sent request open exits within the shutdown
/// deadline (before the fix it waited for the client to leave).
#[cfg(unix)]
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sigterm_with_a_half_sent_request_open_exits() {
    let dir = std::env::temp_dir().join(format!("fogcast-sigterm-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let config = dir.join("serve.toml");
    std::fs::write(
        &config,
        "port = 0\nheader_timeout_s = 3600.0\nhello_timeout_s = 3600.0\nshutdown_timeout_s = 1.0\n",
    )
    .unwrap();
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_fogcast"))
        .args(["serve", "--config"])
        .arg(&config)
        .stdout(std::process::Stdio::piped())
        .spawn()
        .expect("fogcast serve starts");
    let stdout = child.stdout.take().unwrap();
    let url = tokio::time::timeout(
        PATIENCE,
        tokio::task::spawn_blocking(move || {
            use std::io::BufRead as _;
            for line in std::io::BufReader::new(stdout).lines() {
                if let Some(rest) = line.unwrap().strip_prefix("fogcast serving http://") {
                    return rest.split_whitespace().next().unwrap().to_string();
                }
            }
            panic!("fogcast serve exited before serving");
        }),
    )
    .await
    .expect("the server starts in time")
    .unwrap();
    let addr: SocketAddr = url.parse().unwrap();
    let mut slow = TcpStream::connect(addr).await.unwrap();
    slow.write_all(HALF_REQUEST).await.unwrap();
    tokio::time::sleep(Duration::from_millis(200)).await;
    let pid = child.id().to_string();
    let started = Instant::now();
    assert!(std::process::Command::new("kill")
        .args(["-TERM", &pid])
        .status()
        .unwrap()
        .success());
    let waited = tokio::time::timeout(PATIENCE, async {
        loop {
            if let Some(status) = child.try_wait().unwrap() {
                return status;
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    })
    .await;
    let Ok(status) = waited else {
        let _ = child.kill();
        panic!("fogcast did not exit after SIGTERM with a half-sent request open");
    };
    eprintln!(
        "exited {status} {:.2} s after SIGTERM (shutdown_timeout_s 1)",
        started.elapsed().as_secs_f64()
    );
    assert!(status.success(), "{status}");
    let _ = read_until_closed(&mut slow).await;
    let _ = std::fs::remove_dir_all(&dir);
}
