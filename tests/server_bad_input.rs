//! Untrusted input: every kind of bad client message gets a clear error (and, where
//! fatal, a close frame with a reason), while a well-behaved viewer connected the whole
//! time keeps receiving frames, and nothing leaks once the bad clients are gone.

mod server_support;

use fogcast::server::ServerConfig;
use futures_util::SinkExt as _;
use server_support::*;
use tokio::io::AsyncWriteExt as _;
use tokio_tungstenite::tungstenite::Message;

const TOKEN: &str = "s3cret-token";

fn hello_json(width: u32, height: u32) -> serde_json::Value {
    serde_json::json!({"type": "hello", "version": 1, "width": width, "height": height, "token": TOKEN})
}

fn pose(position: &str, orientation: &str, fov: &str) -> String {
    format!(
        r#"{{"type":"pose","seq":1,"views":[{{"position":{position},"orientation":{orientation},"fov_y_deg":{fov}}}]}}"#
    )
}

/// A fresh connection that sends `messages` (text) and must be refused with `code`.
async fn refused(
    addr: std::net::SocketAddr,
    messages: &[String],
    code: &str,
    close: u16,
) -> String {
    let mut ws = connect(addr).await;
    for m in messages {
        ws.send(Message::text(m.clone())).await.unwrap();
    }
    let (e, close_code, reason) = expect_fatal(&mut ws).await;
    assert_eq!(
        (e.code.as_str(), close_code),
        (code, close),
        "message: {}",
        e.message
    );
    assert!(
        reason.starts_with(code),
        "close reason names the error: {reason}"
    );
    assert!(e.message.len() > 10, "the error says what was wrong: {e:?}");
    e.message
}

/// An open session; returns it after its welcome.
async fn session(addr: std::net::SocketAddr) -> Ws {
    let mut ws = connect(addr).await;
    welcome(&mut ws, hello_json(64, 36)).await;
    ws
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_input_gets_clear_errors_and_other_viewers_keep_streaming() {
    let config = ServerConfig {
        token: Some(TOKEN.into()),
        max_views: 4,
        hello_timeout_s: 1.0,
        max_messages_per_s: 50.0,
        ..test_config()
    };
    let server = start(config).await;
    let addr = server.local_addr();
    let viewer = Viewer::start_with(addr, hello_json(64, 36)).await;
    viewer.wait_frames(0, 2).await;
    let mut kinds = 0;
    // After each kind, the well-behaved viewer must get another frame.
    let mut checkpoint = |name: &str| {
        kinds += 1;
        eprintln!("bad input kind {kinds}: {name}");
        viewer.frames()
    };

    // 1-2. Missing and wrong token.
    let n = checkpoint("missing token");
    let mut no_token = hello_json(64, 36);
    no_token.as_object_mut().unwrap().remove("token");
    refused(addr, &[no_token.to_string()], "unauthorized", 4401).await;
    let mut wrong = hello_json(64, 36);
    wrong["token"] = "guess".into();
    refused(addr, &[wrong.to_string()], "unauthorized", 4401).await;
    viewer.wait_frames(n, 1).await;

    // 3. JSON errors in the handshake: fatal.
    let n = checkpoint("invalid JSON hello");
    refused(addr, &["{\"type\":\"hello\",".into()], "bad_json", 4400).await;
    refused(addr, &["[]".into()], "invalid_message", 4400).await;
    viewer.wait_frames(n, 1).await;

    // 4. Anything but a hello first.
    let n = checkpoint("pose before hello");
    refused(
        addr,
        &[pose("[0,1,2]", "[0,0,0,1]", "60")],
        "hello_required",
        4400,
    )
    .await;
    refused(
        addr,
        &[serde_json::json!({"version": 1, "width": 64, "height": 36}).to_string()],
        "invalid_message",
        4400,
    )
    .await;
    let mut old = hello_json(64, 36);
    old["version"] = 99.into();
    refused(addr, &[old.to_string()], "unsupported_version", 4400).await;
    viewer.wait_frames(n, 1).await;

    // 5. Resolutions out of bounds or not tileable.
    let n = checkpoint("resolution out of bounds");
    for (w, h, layout) in [
        (100_000, 36, "mono"),
        (0, 36, "mono"),
        (64, 4, "mono"),
        (641, 36, "mono"),
        (65, 36, "stereo"),
        (16, 16, "stereo"),
    ] {
        let mut m = hello_json(w, h);
        m["layout"] = layout.into();
        let msg = refused(addr, &[m.to_string()], "invalid_hello", 4400).await;
        assert!(
            msg.contains(&format!("{w}x{h}")),
            "the error names the resolution: {msg}"
        );
    }
    let mut neg = hello_json(64, 36);
    neg["width"] = (-64).into();
    refused(addr, &[neg.to_string()], "invalid_message", 4400).await;
    viewer.wait_frames(n, 1).await;

    // 6. Too many views: per session, and over the server's view limit (4, one in use).
    let n = checkpoint("too many views");
    let mut five = hello_json(128, 72);
    five["layout"] = "split".into();
    five["views"] = 5.into();
    refused(addr, &[five.to_string()], "invalid_hello", 4400).await;
    let mut four = hello_json(128, 72);
    four["layout"] = "split".into();
    four["views"] = 4.into();
    refused(addr, &[four.to_string()], "server_full", 1013).await;
    viewer.wait_frames(n, 1).await;

    // 7. No hello at all.
    let n = checkpoint("hello timeout");
    refused(addr, &[], "hello_timeout", 4408).await;
    viewer.wait_frames(n, 1).await;

    // 8-13. Bad messages inside a session: a clear, non-fatal error each, and the
    // session goes on streaming.
    let n = checkpoint("non-fatal errors in a session");
    let mut ws = session(addr).await;
    let good = pose("[0,1.7,3]", "[0,0,0,1]", "60");
    // 20 errors: exactly the per-session budget per 10 s (one more is case 16).
    let cases: Vec<(&str, String, &str)> = vec![
        ("invalid JSON", "{not json".into(), "bad_json"),
        ("NaN", pose("[NaN,0,0]", "[0,0,0,1]", "60"), "bad_json"),
        (
            "number beyond f64",
            pose("[1e400,0,0]", "[0,0,0,1]", "60"),
            "bad_json",
        ),
        (
            "unknown type",
            r#"{"type":"teleport","to":[0,0,0]}"#.into(),
            "unknown_type",
        ),
        (
            "type not a string",
            r#"{"type":7}"#.into(),
            "invalid_message",
        ),
        (
            "missing field",
            r#"{"type":"pose","seq":1}"#.into(),
            "invalid_message",
        ),
        (
            "unknown field",
            r#"{"type":"pose","seq":1,"views":[],"admin":true}"#.into(),
            "invalid_message",
        ),
        (
            "seq out of range",
            r#"{"type":"pose","seq":-1,"views":[]}"#.into(),
            "invalid_message",
        ),
        (
            "huge position (inf as f32)",
            pose("[1e39,0,0]", "[0,0,0,1]", "60"),
            "invalid_pose",
        ),
        (
            "position out of the world",
            pose("[0,2e5,0]", "[0,0,0,1]", "60"),
            "invalid_pose",
        ),
        (
            "zero-length quaternion",
            pose("[0,1,2]", "[0,0,0,0]", "60"),
            "invalid_pose",
        ),
        (
            "tiny quaternion",
            pose("[0,1,2]", "[1e-9,0,0,0]", "60"),
            "invalid_pose",
        ),
        (
            "quaternion with 3 numbers",
            pose("[0,1,2]", "[0,0,1]", "60"),
            "invalid_message",
        ),
        (
            "zero fov",
            pose("[0,1,2]", "[0,0,0,1]", "0"),
            "invalid_pose",
        ),
        (
            "huge fov",
            pose("[0,1,2]", "[0,0,0,1]", "1e30"),
            "invalid_pose",
        ),
        (
            "wrong number of views in a pose",
            r#"{"type":"pose","seq":1,"views":[]}"#.into(),
            "invalid_pose",
        ),
        (
            "second hello",
            hello_json(64, 36).to_string(),
            "invalid_message",
        ),
        (
            "configure out of bounds",
            r#"{"type":"configure","width":100000}"#.into(),
            "invalid_hello",
        ),
        (
            "configure over the view limit",
            r#"{"type":"configure","layout":"split","views":4,"width":128,"height":72}"#.into(),
            "server_full",
        ),
        (
            "configure bad quality",
            r#"{"type":"configure","quality":0}"#.into(),
            "invalid_hello",
        ),
    ];
    for (what, text, code) in &cases {
        ws.send(Message::text(text.clone())).await.unwrap();
        let e = expect_error(&mut ws).await;
        assert_eq!(e.code.as_str(), *code, "{what}: {}", e.message);
        assert!(!e.fatal, "{what} is not fatal");
    }
    ws.send(Message::text(good.clone())).await.unwrap();
    next_frame(&mut ws).await;
    viewer.wait_frames(n, 1).await;
    drop(ws);

    // 14. Binary garbage: fatal, 1003.
    let n = checkpoint("binary garbage");
    let mut ws = session(addr).await;
    ws.send(Message::binary(vec![0xde, 0xad, 0xbe, 0xef, 0, 1, 2, 3]))
        .await
        .unwrap();
    let (e, code, _) = expect_fatal(&mut ws).await;
    assert_eq!((e.code.as_str(), code), ("binary_not_supported", 1003));
    viewer.wait_frames(n, 1).await;

    // 15. Oversized message: fatal, 1009; far beyond the WebSocket limit the socket is cut.
    let n = checkpoint("oversized message");
    let mut ws = session(addr).await;
    let big = format!(
        r#"{{"type":"pose","seq":1,"views":[],"pad":"{}"}}"#,
        "x".repeat(20_000)
    );
    ws.send(Message::text(big)).await.unwrap();
    let (e, code, _) = expect_fatal(&mut ws).await;
    assert_eq!((e.code.as_str(), code), ("message_too_large", 1009));
    let mut ws = session(addr).await;
    let _ = ws.send(Message::text("y".repeat(1 << 20))).await;
    let ended = tokio::time::timeout(PATIENCE, async {
        use futures_util::StreamExt as _;
        while let Some(Ok(_)) = ws.next().await {}
    })
    .await;
    assert!(ended.is_ok(), "a 1 MiB message ends the connection");
    viewer.wait_frames(n, 1).await;

    // 16. Too many invalid messages: fatal, 1008.
    let n = checkpoint("error flood");
    let mut ws = session(addr).await;
    for _ in 0..25 {
        ws.send(Message::text("{oops")).await.unwrap();
    }
    let (e, code, _) = expect_fatal(&mut ws).await;
    assert_eq!((e.code.as_str(), code), ("too_many_errors", 1008));
    viewer.wait_frames(n, 1).await;

    // 17. Pose flood: a rate_limited warning, then fatal 4429.
    let n = checkpoint("pose flood");
    let mut ws = session(addr).await;
    for _ in 0..400 {
        if ws.feed(Message::text(good.clone())).await.is_err() {
            break;
        }
    }
    let _ = ws.flush().await;
    let mut warned = false;
    let fatal = loop {
        match next_text_or_close(&mut ws).await {
            Some(fogcast::protocol::ServerMessage::Error(e)) if !e.fatal => {
                assert_eq!(e.code.as_str(), "rate_limited");
                warned = true;
            }
            Some(fogcast::protocol::ServerMessage::Error(e)) => break e,
            Some(_) => {}
            None => panic!("closed without a fatal error"),
        }
    };
    assert!(warned, "a flood is warned about before it is closed");
    assert_eq!(fatal.code.as_str(), "rate_limited");
    viewer.wait_frames(n, 1).await;

    // 18. Disconnects at any moment: raw garbage instead of HTTP, a half-sent upgrade,
    // an upgrade without hello, a session dropped while frames are in flight.
    let n = checkpoint("abrupt disconnects");
    let mut raw = tokio::net::TcpStream::connect(addr).await.unwrap();
    raw.write_all(&[0x16, 0x03, 0x01, 0xff, 0x00, 0x13, 0x37])
        .await
        .unwrap();
    drop(raw);
    let mut half = tokio::net::TcpStream::connect(addr).await.unwrap();
    half.write_all(b"GET /ws HTTP/1.1\r\nHost: x\r\nUpgrade: websocket\r\n")
        .await
        .unwrap();
    drop(half);
    drop(connect(addr).await);
    for _ in 0..3 {
        let mut ws = session(addr).await;
        ws.send(Message::text(good.clone())).await.unwrap();
        next_frame(&mut ws).await;
        drop(ws); // no close frame: the TCP connection just ends
    }
    viewer.wait_frames(n, 2).await;

    assert!(kinds >= 12, "at least 12 kinds of bad input ({kinds})");
    // Nothing leaked: only the viewer's session and connection remain.
    let m = wait_metrics(addr, "only the viewer left", |m| {
        metric(m, "fogcast_sessions", "") == 1.0
            && metric(m, "fogcast_connections", "") == 1.0
            && metric(m, "fogcast_viewers", "") == 1.0
    })
    .await;
    assert!(
        metric(&m, "fogcast_frame_slot_bytes", "") < 64.0 * 1024.0,
        "slot bytes bounded:\n{m}"
    );
    assert!(metric(&m, "fogcast_client_errors_total", "code=\"invalid_pose\"") >= 6.0);
    assert!(
        !viewer.closed.load(std::sync::atomic::Ordering::Relaxed),
        "the viewer stayed connected"
    );
    eprintln!(
        "viewer received {} frames during {kinds} kinds of bad input",
        viewer.frames()
    );
    drop(viewer);
    server.shutdown().await.unwrap();
}

/// Next text message, `None` at the close frame or end of stream.
async fn next_text_or_close(ws: &mut Ws) -> Option<fogcast::protocol::ServerMessage> {
    use futures_util::StreamExt as _;
    loop {
        match tokio::time::timeout(PATIENCE, ws.next())
            .await
            .expect("server answers in time")
        {
            Some(Ok(Message::Text(t))) => return Some(serde_json::from_str(&t).unwrap()),
            Some(Ok(Message::Close(_))) | None | Some(Err(_)) => return None,
            Some(Ok(_)) => {}
        }
    }
}
