//! The server streams frames to real WebSocket clients: 16 mono viewers at once, and
//! stereo and split-4 sessions whose frames tile their views as documented.

mod server_support;

use fogcast::protocol::{Layout, ViewPose, FRAME_HEADER_BYTES};
use server_support::*;
use std::time::Duration;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sixteen_mono_viewers_all_receive_frames() {
    let server = start(test_config()).await;
    let addr = server.local_addr();
    let (status, body) = http_get(addr, "/healthz").await;
    assert_eq!(status, 200);
    assert!(body.contains("\"status\":\"ok\""), "{body}");
    let (status, page) = http_get(addr, "/").await;
    assert_eq!(status, 200);
    assert!(
        page.contains("<canvas"),
        "the browser client is served at /"
    );

    // Poses on the wire are in the scene file's coordinates: a new session stands on
    // the file's camera loop (the server renders in a space moved by the scene's origin).
    let (_, camera) = fogcast::scene::load_camera_path("colonnade").unwrap();
    let heights = camera.path.iter().map(|p| f64::from(p[1]));
    let (low, high) = heights.fold((f64::MAX, f64::MIN), |(a, b), y| (a.min(y), b.max(y)));
    let mut clients = Vec::new();
    for _ in 0..16 {
        let mut ws = connect(addr).await;
        let w = welcome(&mut ws, hello(64, 36)).await;
        assert_eq!(
            (w.layout, w.views, w.width, w.height, w.header_bytes),
            (Layout::Mono, 1, 64, 36, FRAME_HEADER_BYTES)
        );
        let y = w.poses[0].position[1];
        assert!(
            (low - 1e-3..=high + 1e-3).contains(&y),
            "welcome pose {:?} is not on the file's camera loop (heights {low}..{high})",
            w.poses[0]
        );
        clients.push(ws);
    }
    assert_eq!(server.counts(), (16, 16));
    // The 17th view is over the default limit of 16.
    let mut extra = connect(addr).await;
    send_json(&mut extra, hello(64, 36)).await;
    let (e, code, _) = expect_fatal(&mut extra).await;
    assert_eq!((e.code.as_str(), code), ("server_full", 1013));

    for (i, ws) in clients.iter_mut().enumerate() {
        // Two frames each: the second proves the stream goes on.
        for _ in 0..2 {
            let (h, jpeg) = next_frame(ws).await;
            assert_eq!(
                (h.layout, h.views, h.width, h.height),
                (Layout::Mono, 1, 64, 36),
                "client {i}"
            );
            let img = decode_jpeg(&jpeg);
            assert_eq!(img.dimensions(), (64, 36));
            assert!(mean_luma(&img) > 5.0, "client {i}: frame is black");
        }
    }

    // A pose's sequence number comes back in the header of a frame rendered with it.
    let ws = &mut clients[0];
    let pose = ViewPose {
        position: [0.0, 1.7, 4.0],
        orientation: [0.0, 0.0, 0.0, 1.0],
        fov_y_deg: 60.0,
    };
    send_json(
        ws,
        serde_json::json!({"type": "pose", "seq": 4242, "views": [pose]}),
    )
    .await;
    let mut seen = false;
    for _ in 0..50 {
        let (h, _) = next_frame(ws).await;
        if h.pose_seq == 4242 {
            seen = true;
            break;
        }
    }
    assert!(seen, "pose seq echoed in a frame header");

    let m = metrics(addr).await;
    for (name, labels) in [
        ("fogcast_frames_total", ""),
        ("fogcast_views_rendered_total", ""),
        ("fogcast_frames_sent_total", ""),
        ("fogcast_bytes_sent_total", ""),
        ("fogcast_frames_encoded_total", ""),
        ("fogcast_rays_traced_total", ""),
        ("fogcast_encode_seconds_count", ""),
        ("fogcast_render_seconds_count", ""),
        ("fogcast_frame_seconds_count", ""),
    ] {
        assert!(metric(&m, name, labels) > 0.0, "{name} is zero:\n{m}");
    }
    assert_eq!(metric(&m, "fogcast_viewers", ""), 16.0);
    assert_eq!(metric(&m, "fogcast_sessions", ""), 16.0);
    assert!(
        m.contains("fogcast_stage_gpu_seconds_sum{stage="),
        "per-stage GPU times exported"
    );
    assert_eq!(
        metric(&m, "fogcast_client_errors_total", "code=\"server_full\""),
        1.0
    );

    drop(clients);
    drop(extra);
    wait_metrics(addr, "all sessions gone", |m| {
        metric(m, "fogcast_sessions", "") == 0.0 && metric(m, "fogcast_connections", "") == 0.0
    })
    .await;
    server.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn stereo_and_split_sessions_tile_their_views() {
    let server = start(test_config()).await;
    let addr = server.local_addr();
    // Views of 64x32 everywhere: one render batch, and tiles on 16-pixel JPEG block edges.
    let base = ViewPose {
        position: [0.0, 1.7, 3.0],
        orientation: [0.0, 0.0, 0.0, 1.0],
        fov_y_deg: 70.0,
    };
    let yaw = |deg: f64| {
        let h = deg.to_radians() / 2.0;
        [0.0, h.sin(), 0.0, h.cos()]
    };

    let mut split = connect(addr).await;
    let w = welcome(&mut split, serde_json::json!({"type": "hello", "version": 1, "width": 128, "height": 64, "layout": "split", "views": 4, "quality": 95})).await;
    assert_eq!(
        (
            w.layout,
            w.views,
            w.view_width,
            w.view_height,
            w.poses.len()
        ),
        (Layout::Split, 4, 64, 32, 4)
    );
    let split_poses: Vec<ViewPose> = [0.0, 90.0, 180.0, 270.0]
        .iter()
        .map(|d| ViewPose {
            orientation: yaw(*d),
            ..base
        })
        .collect();
    send_json(
        &mut split,
        serde_json::json!({"type": "pose", "seq": 1, "views": split_poses}),
    )
    .await;

    let mut stereo = connect(addr).await;
    let w = welcome(&mut stereo, serde_json::json!({"type": "hello", "version": 1, "width": 128, "height": 32, "layout": "stereo", "eye_distance_m": 0.5, "quality": 95})).await;
    assert_eq!(
        (
            w.layout,
            w.views,
            w.view_width,
            w.view_height,
            w.poses.len()
        ),
        (Layout::Stereo, 2, 64, 32, 1)
    );
    send_json(
        &mut stereo,
        serde_json::json!({"type": "pose", "seq": 1, "views": [base]}),
    )
    .await;

    // A mono viewer with split view 0's pose: its frame must equal that tile.
    let mut mono = connect(addr).await;
    welcome(&mut mono, serde_json::json!({"type": "hello", "version": 1, "width": 64, "height": 32, "quality": 95})).await;
    send_json(
        &mut mono,
        serde_json::json!({"type": "pose", "seq": 1, "views": [split_poses[0]]}),
    )
    .await;

    let frame_with_seq = |seq: u32| move |h: &fogcast::protocol::FrameHeader| h.pose_seq == seq;
    async fn wait_for(
        ws: &mut Ws,
        ok: impl Fn(&fogcast::protocol::FrameHeader) -> bool,
    ) -> (fogcast::protocol::FrameHeader, image::RgbImage) {
        for _ in 0..100 {
            let (h, jpeg) = next_frame(ws).await;
            if ok(&h) {
                return (h, decode_jpeg(&jpeg));
            }
        }
        panic!("no frame with the pose applied");
    }
    let (h, split_img) = wait_for(&mut split, frame_with_seq(1)).await;
    assert_eq!(
        (h.layout, h.views, h.width, h.height),
        (Layout::Split, 4, 128, 64)
    );
    assert_eq!(split_img.dimensions(), (128, 64));
    let (h, stereo_img) = wait_for(&mut stereo, frame_with_seq(1)).await;
    assert_eq!(
        (h.layout, h.views, h.width, h.height),
        (Layout::Stereo, 2, 128, 32)
    );
    assert_eq!(stereo_img.dimensions(), (128, 32));
    let (_, mono_img) = wait_for(&mut mono, frame_with_seq(1)).await;

    save_for_inspection(&split_img, "split4.png");
    save_for_inspection(&stereo_img, "stereo.png");
    save_for_inspection(&mono_img, "mono.png");
    let tile = |img: &image::RgbImage, x: u32, y: u32| {
        image::imageops::crop_imm(img, x, y, 64, 32).to_image()
    };
    let tiles: Vec<_> = (0..4)
        .map(|i| tile(&split_img, (i % 2) * 64, (i / 2) * 32))
        .collect();
    for (i, t) in tiles.iter().enumerate() {
        assert!(mean_luma(t) > 5.0, "split tile {i} is black");
    }
    // Four directions: four different pictures.
    for i in 0..4 {
        for j in i + 1..4 {
            let d = mean_abs_diff(&tiles[i], &tiles[j]);
            assert!(
                d > 2.0,
                "split tiles {i} and {j} look the same (mean diff {d:.2})"
            );
        }
    }
    // Tile 0 is the same view as the mono session's frame (same batch, same pose).
    let d = mean_abs_diff(&tiles[0], &mono_img);
    assert!(
        d < 3.0,
        "split tile 0 differs from the mono frame of the same pose: mean diff {d:.2}"
    );

    // Stereo: two eyes half a metre apart see the same scene, shifted.
    let (left, right) = (tile(&stereo_img, 0, 0), tile(&stereo_img, 64, 0));
    assert!(
        mean_luma(&left) > 5.0 && mean_luma(&right) > 5.0,
        "stereo eyes are black"
    );
    let eyes = mean_abs_diff(&left, &right);
    assert!(
        eyes > 0.5,
        "eyes 0.5 m apart see the same image (mean diff {eyes:.2})"
    );
    // ... and with zero eye distance both halves are the same image.
    send_json(
        &mut stereo,
        serde_json::json!({"type": "configure", "eye_distance_m": 0.0}),
    )
    .await;
    tokio::time::sleep(Duration::from_millis(50)).await;
    send_json(
        &mut stereo,
        serde_json::json!({"type": "pose", "seq": 2, "views": [base]}),
    )
    .await;
    let (_, img) = wait_for(&mut stereo, frame_with_seq(2)).await;
    let same = mean_abs_diff(&tile(&img, 0, 0), &tile(&img, 64, 0));
    assert!(
        same < 1.5 && same < eyes,
        "zero eye distance: halves differ by {same:.2} (0.5 m: {eyes:.2})"
    );

    // A split session can change its view count; the frame follows.
    send_json(
        &mut split,
        serde_json::json!({"type": "configure", "views": 3}),
    )
    .await;
    let (h, img) = wait_for(&mut split, |h| h.views == 3).await;
    assert_eq!((h.layout, h.width, h.height), (Layout::Split, 128, 64));
    assert!(
        mean_luma(&tile(&img, 64, 32)) < 1.0,
        "the unused fourth tile of a 3-view split is black"
    );
    assert_eq!(server.counts(), (3, 2 + 3 + 1));
    server.shutdown().await.unwrap();
}
