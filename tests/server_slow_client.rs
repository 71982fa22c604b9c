//! A client that never reads must not slow the others down or grow the server's memory:
//! its frames are dropped (latest-frame-wins), and after `stall_timeout_s` it is closed.

mod server_support;

use fogcast::server::{resident_memory_bytes, ServerConfig};
use futures_util::SinkExt as _;
use server_support::*;
use std::time::{Duration, Instant};
use tokio_tungstenite::tungstenite::Message;

const READERS: usize = 3;
const PHASE: Duration = Duration::from_secs(3);
const FPS: f64 = 10.0;

/// Frames each viewer received during `PHASE`, and the phase's real length.
async fn measure(viewers: &[Viewer]) -> (Vec<u64>, Duration) {
    let before: Vec<u64> = viewers.iter().map(Viewer::frames).collect();
    let started = Instant::now();
    tokio::time::sleep(PHASE).await;
    let elapsed = started.elapsed();
    (
        viewers
            .iter()
            .zip(before)
            .map(|(v, b)| v.frames() - b)
            .collect(),
        elapsed,
    )
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_client_that_never_reads_does_not_slow_the_others() {
    let config = ServerConfig {
        // Capped well below what 4 small views sustain here (30-47 fps uncapped, varying
        // run to run on a 2-core machine): a render thread that waited on the stalled
        // client would stop once its buffers filled, which shows as frames missing
        // against the cap, while the machine's own jitter does not decide the result.
        fps: FPS,
        // A small kernel buffer fills after a few frames, so the stall shows quickly.
        send_buffer_bytes: 4096,
        stall_timeout_s: 8.0,
        ..test_config()
    };
    let server = start(config).await;
    let addr = server.local_addr();
    let mut viewers = Vec::new();
    for _ in 0..READERS {
        viewers.push(Viewer::start(addr, 64, 36).await);
    }
    for v in &viewers {
        v.wait_frames(0, 3).await;
    }
    // A fourth reader of the same size, well behaved, during the first phase: both phases
    // then render the same 4 views, so what is compared is the stall, not the cost of one
    // more view (which, with the grid cached, is most of a frame's cost).
    let control = Viewer::start(addr, 64, 36).await;
    control.wait_frames(0, 3).await;
    let (without, t_without) = measure(&viewers).await;
    drop(control);
    wait_metrics(addr, "the fourth reader left", |m| {
        metric(m, "fogcast_sessions", "") == READERS as f64
    })
    .await;

    // The stalled client: a tiny receive buffer, a hello for the same view size (so the
    // render load is one more view in the same batch), high quality, then never a read.
    let socket = tokio::net::TcpSocket::new_v4().unwrap();
    socket.set_recv_buffer_size(2048).unwrap();
    let tcp = socket.connect(addr).await.unwrap();
    let (mut stalled, _) = tokio_tungstenite::client_async(format!("ws://{addr}/ws"), tcp)
        .await
        .unwrap();
    let hello = serde_json::json!({"type": "hello", "version": 1, "width": 64, "height": 36, "quality": 100});
    stalled
        .send(Message::text(hello.to_string()))
        .await
        .unwrap();
    // Its frames start being dropped once the kernel buffers between us are full.
    wait_metrics(addr, "frames dropped for the stalled client", |m| {
        metric(m, "fogcast_frames_dropped_total", "client_slow") > 0.0
    })
    .await;
    let rss_start = resident_memory_bytes().unwrap_or(0);
    let (with, t_with) = measure(&viewers).await;
    let rss_end = resident_memory_bytes().unwrap_or(0);
    let m = metrics(addr).await;
    assert_eq!(
        metric(&m, "fogcast_sessions", ""),
        (READERS + 1) as f64,
        "the stalled client was connected throughout"
    );

    let rate = |frames: &[u64], t: Duration| {
        frames.iter().sum::<u64>() as f64 / READERS as f64 / t.as_secs_f64()
    };
    let (fps_without, fps_with) = (rate(&without, t_without), rate(&with, t_with));
    let ratio = fps_with / fps_without;
    let dropped = metric(&m, "fogcast_frames_dropped_total", "client_slow");
    eprintln!(
        "fps per reader without the stalled client {fps_without:.1} ({without:?}), with it {fps_with:.1} ({with:?}), ratio {ratio:.2}; \
         frames dropped for slow clients {dropped}; RSS {:.1} -> {:.1} MiB; slot bytes {}",
        rss_start as f64 / 1048576.0,
        rss_end as f64 / 1048576.0,
        metric(&m, "fogcast_frame_slot_bytes", "")
    );
    assert!(
        fps_without >= 0.8 * FPS,
        "the readers got {fps_without:.1} fps of the {FPS} cap before the stall: the machine is too slow for this test"
    );
    assert!(
        ratio >= 0.8 && fps_with >= 0.8 * FPS,
        "the other clients' frame rate fell to {ratio:.2} of what it was ({fps_with:.1} of the {FPS} fps cap)"
    );
    for (i, (w, wo)) in with.iter().zip(&without).enumerate() {
        assert!(
            *w as f64 >= 0.7 * *wo as f64,
            "reader {i}: {w} frames with the stalled client vs {wo} without"
        );
    }
    // Bounded memory: at most one waiting frame per session, and no growth worth the name.
    assert!(metric(&m, "fogcast_frame_slot_bytes", "") <= (READERS + 1) as f64 * 64.0 * 1024.0);
    assert!(
        rss_end < rss_start + 32 * 1024 * 1024,
        "RSS grew from {rss_start} to {rss_end} bytes"
    );

    // A frame that cannot leave within stall_timeout_s ends the session.
    wait_metrics(addr, "the stalled session closed", |m| {
        metric(m, "fogcast_sessions_stalled_total", "") == 1.0
            && metric(m, "fogcast_sessions", "") == READERS as f64
    })
    .await;
    let m = metrics(addr).await;
    assert!(metric(&m, "fogcast_frame_slot_bytes", "") <= READERS as f64 * 64.0 * 1024.0);
    for v in &viewers {
        let n = v.frames();
        v.wait_frames(n, 2).await;
    }
    drop(stalled);
    drop(viewers);
    server.shutdown().await.unwrap();
}
