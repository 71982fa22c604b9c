//! The cost budget: views are admitted by what they cost (pixels per frame, and the GPU
//! binding their batch needs), so five 1920×1080 sessions are each either served or
//! refused with a clear `over_budget` error — never accepted and then starved — while a
//! 320×180 viewer connected throughout keeps receiving frames.

mod server_support;

use fogcast::protocol::{ErrorMessage, ServerMessage, Welcome};
use fogcast::server::ServerConfig;
use futures_util::StreamExt as _;
use server_support::*;
use tokio_tungstenite::tungstenite::Message;

/// The welcome, or the fatal error and close code that refused the hello.
async fn answer(ws: &mut Ws) -> Result<Welcome, (ErrorMessage, u16)> {
    let mut error = None;
    loop {
        let msg = tokio::time::timeout(PATIENCE, ws.next())
            .await
            .expect("an answer in time")
            .expect("stream open")
            .expect("no error");
        match msg {
            Message::Text(t) => match serde_json::from_str(&t).unwrap() {
                ServerMessage::Welcome(w) => return Ok(w),
                ServerMessage::Error(e) => error = Some(e),
            },
            Message::Close(Some(c)) => {
                return Err((error.expect("an error before the close"), c.code.into()))
            }
            other => panic!("unexpected before the welcome: {other:?}"),
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn five_1080p_sessions_are_served_or_refused_while_a_small_viewer_streams() {
    five_1080p_sessions(ServerConfig::default().max_pixels_per_frame).await;
}

/// Without a pixel budget only the GPU's binding limit refuses: whatever is admitted
/// must then render (the prediction matches the real allocation), none may fail.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn without_a_pixel_budget_the_binding_limit_admits_only_what_renders() {
    five_1080p_sessions(u64::MAX).await;
}

async fn five_1080p_sessions(max_pixels_per_frame: u64) {
    let server = start(ServerConfig {
        max_width: 1920,
        max_height: 1080,
        max_pixels_per_frame,
        ..test_config()
    })
    .await;
    let addr = server.local_addr();
    let viewer = Viewer::start(addr, 320, 180).await;
    viewer.wait_frames(0, 2).await;

    let (mut served, mut refused) = (Vec::new(), Vec::new());
    for _ in 0..5 {
        let mut ws = connect(addr).await;
        send_json(&mut ws, hello(1920, 1080)).await;
        match answer(&mut ws).await {
            Ok(w) => {
                assert_eq!((w.width, w.height), (1920, 1080));
                served.push(ws);
            }
            Err((e, close)) => {
                assert_eq!((e.code.as_str(), close), ("over_budget", 4413), "{e:?}");
                assert!(
                    e.message.contains("MiB per buffer") || e.message.contains("pixels per frame"),
                    "names the limit: {}",
                    e.message
                );
                assert!(
                    e.message.contains("fits now is"),
                    "offers a size: {}",
                    e.message
                );
                eprintln!("refused: {}", e.message);
                refused.push(e.message);
            }
        }
    }
    eprintln!("served {} of 5, refused {}", served.len(), refused.len());
    assert_eq!(served.len() + refused.len(), 5);
    // Every session that was served gets frames of the size it was told.
    for ws in &mut served {
        let (h, _) = next_frame(ws).await;
        assert_eq!((h.width, h.height), (1920, 1080));
    }
    let n = viewer.frames();
    viewer.wait_frames(n, 3).await;
    let (sessions, _) = server.counts();
    assert_eq!(sessions, 1 + served.len());
    let m = metrics(addr).await;
    assert_eq!(
        metric(&m, "fogcast_render_errors_total", ""),
        0.0,
        "no admitted size failed"
    );
    drop(served);
    server.shutdown().await.unwrap();
}
