//! Failures are loud and contained: a render that fails (error or panic) is retried per
//! view size and closes only the sessions of the size that fails, with a reason, `/healthz` turns `degraded`, encoder
//! panics are caught, and a session that never gets a frame is closed, not left hanging.
//! Faults are injected in the real server's render loop (`ServerConfig::fault`).

mod server_support;

use fogcast::server::config::{Fault, FaultKind};
use fogcast::server::ServerConfig;
use server_support::*;

fn faulty(kind: FaultKind) -> ServerConfig {
    ServerConfig {
        fault: Some(Fault {
            view_width: 96,
            kind,
        }),
        ..test_config()
    }
}

async fn health(addr: std::net::SocketAddr) -> (u16, serde_json::Value) {
    let (status, body) = http_get(addr, "/healthz").await;
    (status, serde_json::from_str(&body).expect("healthz JSON"))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_failed_render_closes_only_its_sessions_and_healthz_degrades() {
    let server = start(faulty(FaultKind::RenderError)).await;
    let addr = server.local_addr();
    let viewer = Viewer::start(addr, 64, 36).await;
    viewer.wait_frames(0, 2).await;
    let (status, h) = health(addr).await;
    assert_eq!((status, h["status"].as_str()), (200, Some("ok")), "{h}");

    // Two sessions of the failing size: both are told and closed.
    let mut victims = Vec::new();
    for _ in 0..2 {
        let mut ws = connect(addr).await;
        welcome(&mut ws, hello(96, 54)).await;
        victims.push(ws);
    }
    for ws in &mut victims {
        let (e, close, reason) = expect_fatal(ws).await;
        assert_eq!((e.code.as_str(), close), ("render_failed", 1011), "{e:?}");
        assert!(e.message.contains("96×54"), "names the size: {}", e.message);
        assert!(reason.starts_with("render_failed"), "{reason}");
    }
    let n = viewer.frames();
    viewer.wait_frames(n, 5).await;

    let (status, h) = health(addr).await;
    assert_eq!(status, 200, "frames still flow: {h}");
    assert_eq!(h["status"], "degraded", "{h}");
    let reasons = h["reasons"].to_string();
    assert!(reasons.contains("96×54"), "{reasons}");
    assert!(h["render_errors"].as_u64().unwrap() >= 1, "{h}");
    let m = metrics(addr).await;
    assert!(metric(&m, "fogcast_render_errors_total", "") >= 1.0);
    assert_eq!(server.counts(), (1, 1), "only the viewer is left");
    server.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_render_panic_is_caught_and_closes_only_its_sessions() {
    let server = start(faulty(FaultKind::RenderPanic)).await;
    let addr = server.local_addr();
    let viewer = Viewer::start(addr, 64, 36).await;
    viewer.wait_frames(0, 2).await;
    let mut ws = connect(addr).await;
    welcome(&mut ws, hello(96, 54)).await;
    let (e, close, _) = expect_fatal(&mut ws).await;
    assert_eq!((e.code.as_str(), close), ("render_failed", 1011), "{e:?}");
    assert!(e.message.contains("panic"), "{}", e.message);
    let n = viewer.frames();
    viewer.wait_frames(n, 5).await;
    let m = metrics(addr).await;
    assert!(metric(&m, "fogcast_panics_total", "thread=\"render\"") >= 1.0);
    assert_eq!(health(addr).await.1["status"], "degraded");
    server.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn encoder_panics_are_caught_and_a_starved_session_is_closed() {
    let server = start(ServerConfig {
        frame_timeout_s: 2.0,
        ..faulty(FaultKind::EncodePanic)
    })
    .await;
    let addr = server.local_addr();
    let viewer = Viewer::start(addr, 64, 36).await;
    viewer.wait_frames(0, 2).await;
    let mut ws = connect(addr).await;
    welcome(&mut ws, hello(96, 54)).await;
    // Every one of its frames panics in the encoder: it gets none, and is closed for it.
    let (e, close, reason) = expect_fatal(&mut ws).await;
    assert_eq!((e.code.as_str(), close), ("no_frames", 1011), "{e:?}");
    assert!(reason.starts_with("no_frames"), "{reason}");
    let n = viewer.frames();
    viewer.wait_frames(n, 5).await;
    let m = metrics(addr).await;
    assert!(metric(&m, "fogcast_panics_total", "thread=\"encode\"") >= 1.0);
    assert!(metric(&m, "fogcast_sessions_starved_total", "") >= 1.0);
    assert_eq!(health(addr).await.1["status"], "degraded");
    server.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_silently_skipped_session_is_closed_by_the_frame_timeout() {
    let server = start(ServerConfig {
        frame_timeout_s: 2.0,
        ..faulty(FaultKind::Skip)
    })
    .await;
    let addr = server.local_addr();
    let viewer = Viewer::start(addr, 64, 36).await;
    let mut ws = connect(addr).await;
    welcome(&mut ws, hello(96, 54)).await;
    let (e, close, _) = expect_fatal(&mut ws).await;
    assert_eq!((e.code.as_str(), close), ("no_frames", 1011), "{e:?}");
    let n = viewer.frames();
    viewer.wait_frames(n, 3).await;
    server.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_new_view_size_joins_the_one_world_and_every_frame_is_one_render_call() {
    let server = start(test_config()).await;
    let addr = server.local_addr();
    let viewer = Viewer::start(addr, 64, 36).await;
    viewer.wait_frames(0, 2).await;
    let other = Viewer::start(addr, 96, 54).await;
    other.wait_frames(0, 2).await;
    let m = wait_metrics(addr, "both view sizes in one frame", |m| {
        metric(m, "fogcast_view_sizes", "") == 2.0
    })
    .await;
    let (frames, calls) = (
        metric(&m, "fogcast_frames_total", ""),
        metric(&m, "fogcast_render_calls_total", ""),
    );
    let (v0, o0) = (viewer.frames(), other.frames());
    viewer.wait_frames(v0, 3).await;
    other.wait_frames(o0, 3).await;
    let m = metrics(addr).await;
    let frames = metric(&m, "fogcast_frames_total", "") - frames;
    let calls = metric(&m, "fogcast_render_calls_total", "") - calls;
    eprintln!("{frames} frames, {calls} render calls with two view sizes");
    assert!(frames >= 3.0, "{frames}");
    assert_eq!(
        calls, frames,
        "one render call (one world) per frame, not one per size"
    );
    let grid_rays = metric(&m, "fogcast_grid_rays_last_frame", "");
    eprintln!("grid rays in the last frame: {grid_rays}");
    assert!(grid_rays.is_finite() && grid_rays >= 0.0);
    server.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_lost_device_ends_every_session_cleanly_and_is_reported() {
    let server = start(faulty(FaultKind::DeviceLost)).await;
    let addr = server.local_addr();
    let mut bystander = connect(addr).await;
    welcome(&mut bystander, hello(64, 36)).await;
    next_frame(&mut bystander).await;
    let mut ws = connect(addr).await;
    welcome(&mut ws, hello(96, 54)).await;
    for ws in [&mut ws, &mut bystander] {
        let (e, close, _) = expect_fatal(ws).await;
        assert_eq!((e.code.as_str(), close), ("render_failed", 1011), "{e:?}");
    }
    let (status, h) = tokio::time::timeout(PATIENCE, async {
        loop {
            let (status, h) = health(addr).await;
            if status == 503 {
                return (status, h);
            }
            tokio::time::sleep(std::time::Duration::from_millis(50)).await;
        }
    })
    .await
    .expect("/healthz reports the lost device");
    eprintln!("{status} {h}");
    assert_eq!(
        (h["status"].as_str(), h["rendering"].as_bool()),
        (Some("degraded"), Some(false))
    );
    assert!(h["reasons"].to_string().contains("device was lost"), "{h}");
    // New sessions are refused with the reason, not accepted and starved.
    let mut late = connect(addr).await;
    send_json(&mut late, hello(64, 36)).await;
    let (e, close, _) = expect_fatal(&mut late).await;
    assert_eq!((e.code.as_str(), close), ("render_failed", 1011), "{e:?}");
    assert!(e.message.contains("device was lost"), "{}", e.message);
    server.shutdown().await.unwrap();
}
