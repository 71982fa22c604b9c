//! `fogcast loadgen` against a real server: two WebSocket viewers for a few seconds get
//! frames, finite ordered latency percentiles and bytes; the report files are written;
//! a mixed sweep (three frame sizes at once) serves every size and reports each; an
//! unreachable server, a refused hello and a sweep over the server's view limit give
//! errors that say so. The streaming scenario (issue 17): the throttle wrapper reads at
//! its rate, PSNR follows its formula, and a short throttled + churning run passes the
//! soak's checks. No timing assertions beyond the throttle's ±15 % (DESIGN.md §7).

mod server_support;

use fogcast::loadgen::quality::{psnr, PSNR_CAP_DB};
use fogcast::loadgen::{
    run, write_report, Checks, FrameSize, LoadgenConfig, Throttled, ViewerClass,
};
use fogcast::protocol::Codec;
use fogcast::server::ServerConfig;
use server_support::*;
use std::time::{Duration, Instant};
use tokio::io::{AsyncReadExt as _, AsyncWriteExt as _};

fn config_for(addr: std::net::SocketAddr) -> LoadgenConfig {
    LoadgenConfig {
        url: format!("ws://{addr}/ws"),
        viewers: vec![2],
        seconds: 3.0,
        warmup_s: 0.5,
        pose_hz: 20.0,
        sizes: vec![FrameSize {
            width: 64,
            height: 36,
        }],
        ..LoadgenConfig::default()
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn two_viewers_get_frames_latency_and_bytes() {
    let server = start(test_config()).await;
    let addr = server.local_addr();
    let config = config_for(addr);
    let report = run(&config, "test", &|line| eprintln!("{line}"))
        .await
        .expect("loadgen runs");

    assert_eq!(report.scene, "colonnade");
    assert!(
        report.camera_paths.contains("camera loop"),
        "viewers fly the scene's loop: {}",
        report.camera_paths
    );
    assert_eq!(report.points.len(), 1);
    let p = &report.points[0];
    assert_eq!((p.viewers, p.sessions, p.per_viewer.len()), (2, 2, 2));
    assert!(p.window_s >= 3.0, "window {} s", p.window_s);
    for v in &p.per_viewer {
        let who = format!("viewer {} (session {})", v.index, v.session);
        assert!(v.frames > 0, "{who} received no frames");
        assert!(v.fps > 0.0 && v.fps.is_finite(), "{who}: fps {}", v.fps);
        assert!(v.bytes > 0 && v.bytes_per_s > 0.0, "{who}: no bytes");
        assert!(
            v.mean_frame_bytes > 32.0,
            "{who}: frames are a header and a JPEG ({} bytes)",
            v.mean_frame_bytes
        );
        let l = v
            .latency
            .unwrap_or_else(|| panic!("{who}: no latency samples"));
        assert!(l.samples > 0);
        for x in [l.p50_ms, l.p95_ms, l.p99_ms, l.mean_ms, l.max_ms] {
            assert!(x.is_finite() && x >= 0.0, "{who}: latency {l:?}");
        }
        assert!(
            l.p50_ms <= l.p95_ms && l.p95_ms <= l.p99_ms && l.p99_ms <= l.max_ms,
            "{who}: percentiles out of order {l:?}"
        );
        assert!(v.poses_sent > 0, "{who} sent poses");
        assert_eq!(v.bad_frames, 0, "{who}: frames not matching the session");
        assert!(v.server_errors.is_empty(), "{who}: {:?}", v.server_errors);
        assert_eq!(v.ended_early, None, "{who}");
        assert_eq!(v.timeline.len(), 3, "{who}: one count per second");
        assert_eq!(
            v.timeline.iter().map(|&n| u64::from(n)).sum::<u64>(),
            v.frames,
            "{who}: the timeline adds up to the frames"
        );
        assert!(v.header_render_ms.is_some_and(|ms| ms > 0.0), "{who}");
        // JPEG: every frame a key frame; the payload is the frame less its 40-byte header.
        assert_eq!(v.key_frames, v.frames, "{who}");
        assert!(
            (v.mean_frame_bytes - v.encoded_bytes_per_frame - 40.0).abs() < 1e-6,
            "{who}: {} bytes per frame, {} encoded",
            v.mean_frame_bytes,
            v.encoded_bytes_per_frame
        );
        assert_eq!(
            (v.raw_frames, v.sessions_opened, v.quality),
            (0, 1, None),
            "{who}"
        );
        assert!(!v.throttled, "{who}");
    }
    let a = &p.sessions_accounting;
    assert_eq!(
        (a.opened_by_loadgen, a.server_opened, a.open_after),
        (2, 2, 0),
        "{a:?}"
    );
    assert!(a.accounted && report.checks.is_empty(), "{a:?}");
    assert_eq!(p.classes.len(), 1, "unthrottled viewers only");
    let pooled = p.summary.latency.expect("pooled latency");
    assert!(pooled.p50_ms <= pooled.p95_ms && pooled.p95_ms <= pooled.p99_ms);
    assert_eq!(
        pooled.samples,
        p.per_viewer
            .iter()
            .map(|v| v.latency.map_or(0, |l| l.samples))
            .sum::<usize>()
    );
    let s = &p.server;
    assert!(s.frames > 0 && s.fps > 0.0, "server frames {s:?}");
    assert!(s.frame_ms.is_some_and(|ms| ms > 0.0), "{s:?}");
    assert!(s.bytes_sent > 0 && s.frames_sent > 0, "{s:?}");
    assert_eq!(
        (s.viewers, s.sessions),
        (2, 2),
        "the server saw both viewers"
    );
    assert!(!s.stage_gpu_ms.is_empty(), "GPU stage times scraped");

    // loadgen waited for the server to let the sessions go.
    assert_eq!(server.counts(), (0, 0));

    let out = std::env::temp_dir().join(format!("fogcast-loadgen-test-{}", std::process::id()));
    let files = write_report(&report, &out).expect("report written");
    for name in [
        "loadgen.json",
        "loadgen.csv",
        "loadgen.md",
        "loadgen_fps.png",
        "loadgen_latency.png",
        "loadgen_timeline.png",
    ] {
        let path = out.join(name);
        assert!(files.contains(&path), "{name} listed");
        assert!(std::fs::metadata(&path).unwrap().len() > 0, "{name} empty");
    }
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("loadgen.json")).unwrap()).unwrap();
    let v0 = &json["points"][0]["per_viewer"][0];
    for key in [
        "fps",
        "bytes_per_s",
        "dropped_server",
        "missed_frames",
        "timeline",
    ] {
        assert!(!v0[key].is_null(), "loadgen.json per-viewer field {key}");
    }
    assert!(v0["latency"]["p99_ms"].is_number());
    let csv = std::fs::read_to_string(out.join("loadgen.csv")).unwrap();
    assert_eq!(csv.lines().count(), 3, "a header and one row per viewer");
    let md = std::fs::read_to_string(out.join("loadgen.md")).unwrap();
    assert!(md.contains("## Every viewer at 2 views"), "{md}");
    std::fs::remove_dir_all(&out).unwrap();
    server.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_mixed_sweep_serves_and_reports_every_size() {
    let server = start(test_config()).await;
    let size = |width, height| FrameSize { width, height };
    let sizes = vec![size(64, 36), size(96, 54), size(128, 72)];
    let config = LoadgenConfig {
        viewers: vec![3],
        sizes: sizes.clone(),
        seconds: 2.0,
        ..config_for(server.local_addr())
    };
    let report = run(&config, "test", &|line| eprintln!("{line}"))
        .await
        .expect("loadgen runs");
    let p = &report.points[0];
    assert_eq!((p.viewers, p.sessions), (3, 3));
    assert_eq!(
        p.sizes
            .iter()
            .map(|z| (z.size, z.sessions, z.views))
            .collect::<Vec<_>>(),
        sizes.iter().map(|&s| (s, 1, 1)).collect::<Vec<_>>(),
        "a third of the sessions at each size"
    );
    for z in &p.sizes {
        let s = &z.summary;
        assert!(
            s.frames_total > 0 && s.fps_mean > 0.0,
            "{}: no frames {s:?}",
            z.size
        );
        assert!(s.latency.is_some_and(|l| l.samples > 0), "{}", z.size);
        assert_eq!(s.bad_frames, 0, "{}: frames of another size", z.size);
    }
    let mut seen: Vec<FrameSize> = p.per_viewer.iter().map(|v| v.size).collect();
    seen.sort_by_key(|s| s.width);
    assert_eq!(seen, sizes, "each viewer reports its size");
    let s = &p.server;
    assert_eq!(s.viewers, 3, "{s:?}");
    assert!(s.render_calls_per_frame > 0.0, "{s:?}");
    assert!(
        s.grid_rays_per_frame > 0.0
            && (s.grid_rays_per_frame - s.render_calls_per_frame * s.grid_rays_per_render_call)
                .abs()
                <= 1e-6 * s.grid_rays_per_frame,
        "grid rays per frame and per render call scraped: {s:?}"
    );
    assert_eq!(server.counts(), (0, 0));

    let out = std::env::temp_dir().join(format!("fogcast-loadgen-mixed-{}", std::process::id()));
    write_report(&report, &out).expect("report written");
    let md = std::fs::read_to_string(out.join("loadgen.md")).unwrap();
    for want in [
        "mono frames at 64x36, 96x54 and 128x72",
        "## Per frame size",
        "| 96x54 |",
        "sessions per size",
        "grid rays/frame",
    ] {
        assert!(md.contains(want), "loadgen.md lacks {want:?}:\n{md}");
    }
    let csv = std::fs::read_to_string(out.join("loadgen.csv")).unwrap();
    assert!(csv.lines().next().unwrap().contains(",size,"), "{csv}");
    assert!(csv.contains(",128x72,"), "{csv}");
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("loadgen.json")).unwrap()).unwrap();
    let point = &json["points"][0];
    assert_eq!(point["sizes"][1]["size"]["width"], 96);
    assert!(point["sizes"][2]["summary"]["fps_mean"].is_number());
    assert!(point["server"]["grid_rays_per_frame"].is_number());
    std::fs::remove_dir_all(&out).unwrap();
    server.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn errors_name_the_problem() {
    // Nobody listens on a port that was just released.
    let free = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let gone = free.local_addr().unwrap();
    drop(free);
    let e = run(&config_for(gone), "", &|_| {}).await.unwrap_err();
    let msg = format!("{e:#}");
    assert!(
        msg.contains("cannot reach") && msg.contains(&gone.to_string()),
        "{msg}"
    );

    let bad = LoadgenConfig {
        url: "http://127.0.0.1:1/ws".into(),
        ..LoadgenConfig::default()
    };
    assert!(format!("{:#}", bad.validate().unwrap_err()).contains("http"));
    let odd = LoadgenConfig {
        layout: fogcast::protocol::Layout::Stereo,
        viewers: vec![3],
        ..LoadgenConfig::default()
    };
    assert!(format!("{:#}", odd.validate().unwrap_err()).contains("--viewers 3"));

    // A server with a token refuses a hello without one; loadgen passes its reason on.
    let server = start(ServerConfig {
        token: Some("s3cret".into()),
        max_views: 4,
        ..test_config()
    })
    .await;
    let addr = server.local_addr();
    let e = run(&config_for(addr), "", &|_| {}).await.unwrap_err();
    let msg = format!("{e:#}");
    assert!(
        msg.contains("refused the hello") && msg.contains("unauthorized"),
        "{msg}"
    );
    // More views than the server renders: refused before connecting anyone.
    let too_many = LoadgenConfig {
        viewers: vec![8],
        token: Some("s3cret".into()),
        ..config_for(addr)
    };
    let msg = format!("{:#}", run(&too_many, "", &|_| {}).await.unwrap_err());
    assert!(
        msg.contains("--viewers 8") && msg.contains("at most 4"),
        "{msg}"
    );
    server.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_throttle_reads_at_its_rate() {
    // A sender that writes as fast as the socket takes it.
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    let sender = tokio::spawn(async move {
        while let Ok((mut s, _)) = listener.accept().await {
            tokio::spawn(async move {
                let chunk = vec![7u8; 64 * 1024];
                while s.write_all(&chunk).await.is_ok() {}
            });
        }
    });
    const KBPS: u32 = 2000;
    let tcp = tokio::net::TcpStream::connect(addr).await.unwrap();
    let mut slow = Throttled::new(tcp, Some(KBPS));
    let mut buf = vec![0u8; 256 * 1024];
    let started = Instant::now();
    let mut bytes = 0usize;
    while started.elapsed() < Duration::from_secs(2) {
        bytes += slow.read(&mut buf).await.unwrap();
    }
    let kbps = bytes as f64 * 8.0 / 1000.0 / started.elapsed().as_secs_f64();
    assert!(
        (kbps - f64::from(KBPS)).abs() <= 0.15 * f64::from(KBPS),
        "read {bytes} bytes at {kbps:.0} kbit/s through a {KBPS} kbit/s throttle"
    );
    // Without a rate the wrapper passes everything: the same sender gives far more.
    let tcp = tokio::net::TcpStream::connect(addr).await.unwrap();
    let mut fast = Throttled::new(tcp, None);
    let started = Instant::now();
    let mut fast_bytes = 0usize;
    while started.elapsed() < Duration::from_millis(300) {
        fast_bytes += fast.read(&mut buf).await.unwrap();
    }
    let fast_kbps = fast_bytes as f64 * 8.0 / 1000.0 / started.elapsed().as_secs_f64();
    assert!(
        fast_kbps > 5.0 * f64::from(KBPS),
        "unthrottled {fast_kbps:.0} kbit/s: the sender, not the throttle, set the rate"
    );
    sender.abort();
}

#[test]
fn psnr_is_capped_for_identical_pictures_and_follows_the_formula_for_noise() {
    let (w, h) = (32usize, 16usize);
    let raw: Vec<u8> = (0..w * h)
        .flat_map(|i| [100 + (i % 50) as u8, 90, 120 - (i % 30) as u8, 255])
        .collect();
    let same: Vec<u8> = raw
        .chunks_exact(4)
        .flat_map(|p| [p[0], p[1], p[2]])
        .collect();
    assert_eq!(psnr(&same, &raw), Some(PSNR_CAP_DB));
    // ±8 on every channel, alternating: MSE 64, PSNR 10·log10(255²/64) = 30.07 dB.
    let noisy: Vec<u8> = same
        .iter()
        .enumerate()
        .map(|(i, v)| if i % 2 == 0 { v + 8 } else { v - 8 })
        .collect();
    let db = psnr(&noisy, &raw).unwrap();
    let want = 10.0 * (255.0f64 * 255.0 / 64.0).log10();
    assert!((db - want).abs() < 1e-9, "PSNR {db} dB, formula {want} dB");
    assert!((want - 30.07).abs() < 0.01);
    assert_eq!(
        psnr(&noisy[..30], &raw),
        None,
        "different sizes are not compared"
    );
}

/// The soak's throttled and churn scenarios in short: 3 sessions, the first reading at
/// 100 kbit/s (about half of what a 96x54 JPEG stream asks at first; the H.264 stream of
/// that size fits in it), everyone reopening its session every 5 s, a baseline of the
/// unthrottled two first; the soak's checks, looser.
async fn throttled_and_churning(codec: Codec) {
    let server = start(test_config()).await;
    let config = LoadgenConfig {
        codec,
        viewers: vec![3],
        seconds: 12.0,
        warmup_s: 1.0,
        window_s: 3.0,
        throttle_kbps: Some(100),
        throttled: 1,
        baseline_s: Some(4.0),
        churn_s: Some(5.0),
        sizes: vec![FrameSize {
            width: 96,
            height: 54,
        }],
        checks: Checks {
            latency_p95_ms: Some(1500.0),
            creep: Some(5.0),
            fps_within: Some(0.5),
            memory_growth: Some(0.5),
            sessions: true,
        },
        ..config_for(server.local_addr())
    };
    let report = run(&config, "test", &|line| eprintln!("{line}"))
        .await
        .expect("loadgen runs");
    let p = &report.points[0];
    let classes: Vec<(ViewerClass, usize)> =
        p.classes.iter().map(|c| (c.class, c.sessions)).collect();
    assert_eq!(
        classes,
        vec![(ViewerClass::Unthrottled, 2), (ViewerClass::Throttled, 1)]
    );
    assert!(p.per_viewer[0].throttled && !p.per_viewer[1].throttled);
    for c in &p.classes {
        assert_eq!(c.windows.len(), 4, "{:?}: 12 s in 3 s windows", c.class);
        assert!(c.summary.frames_total > 0, "{:?} got no frames", c.class);
    }
    // The throttled viewer gets no more than its link carries (100 kbit/s = 12.5 KB/s).
    let slow = &p.classes[1].summary;
    assert!(
        slow.bytes_per_s_per_viewer <= 1.15 * 12_500.0,
        "the throttled viewer read {:.0} B/s",
        slow.bytes_per_s_per_viewer
    );
    let b = p.baseline.as_ref().expect("a baseline phase");
    assert_eq!(b.sessions, 2);
    assert!(b.summary.fps_mean > 0.0);
    assert_eq!(p.server_windows.len(), 4);
    assert!(p
        .server_windows
        .iter()
        .all(|w| w.resident_memory_mib.is_some_and(|m| m > 0.0)));
    // Churn: every viewer opened more than one session, and the server counted each.
    let a = &p.sessions_accounting;
    assert!(
        p.per_viewer.iter().all(|v| v.sessions_opened >= 2),
        "{:?}",
        p.per_viewer
            .iter()
            .map(|v| v.sessions_opened)
            .collect::<Vec<_>>()
    );
    assert_eq!(a.server_opened, a.opened_by_loadgen, "{a:?}");
    let names: Vec<&str> = report.checks.iter().map(|c| c.check.as_str()).collect();
    for want in [
        "--check-latency-p95-ms",
        "--check-creep",
        "--check-fps-within",
        "--check-memory-growth",
        "--check-sessions",
    ] {
        assert!(names.contains(&want), "{want} evaluated: {names:?}");
    }
    for c in &report.checks {
        eprintln!("{} {}: {}", c.check, c.passed, c.detail);
    }
    let failed = report.failed_checks();
    assert!(failed.is_empty(), "checks failed: {failed:#?}");
    assert_eq!(server.counts(), (0, 0));

    let out = std::env::temp_dir().join(format!(
        "fogcast-loadgen-soak-{}-{}",
        codec.as_str(),
        std::process::id()
    ));
    let files = write_report(&report, &out).expect("report written");
    assert!(
        files.contains(&out.join("loadgen_windows.png")),
        "{files:?}"
    );
    let md = std::fs::read_to_string(out.join("loadgen.md")).unwrap();
    for want in [
        "loadgen_windows.png",
        "## Viewer classes",
        "baseline (every link fast)",
        "## Over time",
        "## Sessions",
        "## Checks",
    ] {
        assert!(md.contains(want), "loadgen.md lacks {want:?}:\n{md}");
    }
    std::fs::remove_dir_all(&out).unwrap();
    server.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_throttled_jpeg_viewer_and_churn_pass_the_checks() {
    throttled_and_churning(Codec::Jpeg).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_throttled_h264_viewer_and_churn_pass_the_checks() {
    throttled_and_churning(Codec::H264).await;
}

/// `--raw-every` on a `debug_raw_frames` server: both codecs decode, match their raw
/// frames closely, and the raw frames count in neither frames nor bytes.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn raw_frames_measure_the_quality_of_both_codecs() {
    let server = start(ServerConfig {
        debug_raw_frames: true,
        // A key frame inside the measured window whatever its length.
        gop_frames: 10,
        ..test_config()
    })
    .await;
    let size = FrameSize {
        width: 128,
        height: 72,
    };
    for codec in [Codec::Jpeg, Codec::H264] {
        let config = LoadgenConfig {
            viewers: vec![1],
            seconds: 3.0,
            codec,
            raw_every: Some(2),
            sizes: vec![size],
            ..config_for(server.local_addr())
        };
        let report = run(&config, "test", &|line| eprintln!("{line}"))
            .await
            .expect("loadgen runs");
        let v = &report.points[0].per_viewer[0];
        let who = codec.as_str();
        assert!(v.frames > 0 && v.raw_frames > 0, "{who}: {v:?}");
        assert_eq!((v.bad_frames, v.decode_errors), (0, 0), "{who}: {v:?}");
        assert!(v.server_errors.is_empty(), "{who}: {:?}", v.server_errors);
        let raw_bytes = f64::from(size.width * size.height * 4);
        assert!(
            v.encoded_bytes_per_frame > 0.0 && v.encoded_bytes_per_frame < raw_bytes / 2.0,
            "{who}: {} encoded bytes per frame; raw frames must not count",
            v.encoded_bytes_per_frame
        );
        assert!(v.key_frames >= 1, "{who}: no key frame");
        if codec == Codec::H264 {
            assert!(
                v.key_frames < v.frames,
                "{who}: P frames between key frames"
            );
        }
        let q = v
            .quality
            .unwrap_or_else(|| panic!("{who}: no frame compared"));
        assert!(
            q.compared > 0 && q.compared as u64 <= v.frames,
            "{who}: {q:?}"
        );
        assert!(
            q.psnr_min_db > 25.0 && q.psnr_min_db <= q.psnr_mean_db && q.psnr_mean_db < PSNR_CAP_DB,
            "{who}: PSNR {q:?}"
        );
        assert_eq!(report.points[0].summary.quality, Some(q));
    }
    server.shutdown().await.unwrap();
}
