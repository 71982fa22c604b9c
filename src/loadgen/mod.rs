//! `fogcast loadgen`: load a running `fogcast serve` from the outside with real WebSocket
//! viewers and measure what each of them gets (`docs/loadtest.md`).
//!
//! For each point of the sweep (a number of views), loadgen opens the sessions (hello →
//! welcome, `docs/protocol.md`) — all at one frame size, or split as evenly as possible
//! over several (a mixed sweep, [`MIXED_SWEEP_SIZES`]) — lets every viewer fly its own
//! camera path sending poses
//! at a fixed rate, waits until every viewer has frames and a warm-up has passed, then
//! measures a fixed window:
//!
//! - per viewer: delivered fps, pose-to-frame latency p50/p95/p99 (the frame header
//!   echoes the last pose's `seq`; latency is arrival time minus that pose's send time,
//!   on the first frame showing each pose), bytes/s, frames the server dropped for it
//!   (the header's per-session counter) and render-loop frames it missed (gaps in the
//!   header's frame number), the longest gap between frames, and frames per second of
//!   the window (the timeline that shows a viewer was served the whole time);
//! - per frame size: the same over the viewers of that size;
//! - on the server: the deltas of `/metrics` over the window (render-loop fps, frame,
//!   render and encode ms, GPU ms per stage, rays per frame — the shared grid's among
//!   them — render calls per frame, bytes sent, drops, memory).
//!
//! Then it closes the sessions, waits for the server to let them go, and goes on to the
//! next point. [`run`] does the sweep, [`write_report`] writes loadgen.json, .csv, .md
//! and the plots.

mod cli;
mod client;
mod output;
mod paths;
mod scrape;
mod stats;

pub use cli::{loadgen, LayoutArg, LoadgenArgs, SweepArg};
pub use output::write_report;

use crate::protocol::{Hello, Layout, MAX_SPLIT_VIEWS, PROTOCOL_VERSION};
use anyhow::Context as _;
use client::{Flight, Live, Target};
use paths::Paths;
use serde::Serialize;
use std::collections::BTreeMap;
use std::sync::atomic::Ordering::Relaxed;
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio::sync::watch;

/// A frame size a session asks for, written `WIDTHxHEIGHT` (`320x180`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct FrameSize {
    /// Frame width, pixels.
    pub width: u32,
    /// Frame height, pixels.
    pub height: u32,
}

impl std::fmt::Display for FrameSize {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}x{}", self.width, self.height)
    }
}

impl std::str::FromStr for FrameSize {
    type Err = String;

    fn from_str(s: &str) -> Result<FrameSize, String> {
        let bad = || format!("frame size {s:?}: write WIDTHxHEIGHT, e.g. 320x180");
        let (w, h) = s.trim().split_once(['x', 'X']).ok_or_else(bad)?;
        Ok(FrameSize {
            width: w.trim().parse().map_err(|_| bad())?,
            height: h.trim().parse().map_err(|_| bad())?,
        })
    }
}

/// Frame size of every session in a uniform sweep, unless told otherwise.
pub const DEFAULT_SIZE: FrameSize = FrameSize {
    width: 256,
    height: 144,
};

/// Points of a uniform sweep, unless told otherwise.
pub const DEFAULT_VIEWERS: [usize; 4] = [1, 4, 8, 16];

/// The mixed sweep's frame sizes (`--sweep mixed`): three 16:9 sizes a browser client
/// might ask for, a third of the sessions at each.
pub const MIXED_SWEEP_SIZES: [FrameSize; 3] = [
    FrameSize {
        width: 320,
        height: 180,
    },
    FrameSize {
        width: 480,
        height: 270,
    },
    FrameSize {
        width: 640,
        height: 360,
    },
];

/// The mixed sweep's points: multiples of three views, so each size gets exactly a third,
/// up to the server's default limit of 16 views.
pub const MIXED_SWEEP_VIEWERS: [usize; 5] = [3, 6, 9, 12, 15];

/// What to load and how.
#[derive(Debug, Clone, Serialize)]
pub struct LoadgenConfig {
    /// The server's WebSocket URL, `ws://HOST:PORT/ws`.
    pub url: String,
    /// Views per sweep point (each session has `views_per_session` of them).
    pub viewers: Vec<usize>,
    /// Measured seconds per point.
    pub seconds: f64,
    /// Seconds between every viewer having its first frame and the measured window.
    pub warmup_s: f64,
    /// Longest wait for every viewer's first frame, seconds (a new view size makes the
    /// server build a renderer first).
    pub first_frame_timeout_s: f64,
    /// Pose messages each session sends per second.
    pub pose_hz: f64,
    /// Frame sizes the sessions ask for (the whole frame: both eyes, all tiles): each
    /// point's sessions take them in turn, so they split as evenly as possible.
    pub sizes: Vec<FrameSize>,
    /// JPEG quality each session asks for.
    pub quality: u8,
    /// Session layout.
    pub layout: Layout,
    /// Views of a `split` session (2–4); ignored for the other layouts.
    pub split_views: u32,
    /// Token for servers that require one (never written to the report).
    #[serde(skip)]
    pub token: Option<String>,
    /// Scene whose camera loop the viewers fly (default: the server's scene per `/healthz`).
    pub scene: Option<String>,
}

impl Default for LoadgenConfig {
    fn default() -> Self {
        LoadgenConfig {
            url: "ws://127.0.0.1:8080/ws".into(),
            viewers: DEFAULT_VIEWERS.to_vec(),
            seconds: 10.0,
            warmup_s: 3.0,
            first_frame_timeout_s: 120.0,
            pose_hz: 30.0,
            sizes: vec![DEFAULT_SIZE],
            quality: 75,
            layout: Layout::Mono,
            split_views: 2,
            token: None,
            scene: None,
        }
    }
}

impl LoadgenConfig {
    /// Views one session renders.
    pub fn views_per_session(&self) -> usize {
        match self.layout {
            Layout::Mono => 1,
            Layout::Stereo => 2,
            Layout::Split => self.split_views as usize,
        }
    }

    /// Checks every value; the error names the flag, the value and the range.
    pub fn validate(&self) -> anyhow::Result<()> {
        Target::parse(&self.url)?;
        anyhow::ensure!(
            !self.viewers.is_empty(),
            "--viewers: give at least one count, e.g. 1,4,8,16"
        );
        if self.layout == Layout::Split {
            anyhow::ensure!(
                (2..=MAX_SPLIT_VIEWS).contains(&self.split_views),
                "--split-views {}: must be 2..={MAX_SPLIT_VIEWS}",
                self.split_views
            );
        }
        let per = self.views_per_session();
        for &n in &self.viewers {
            anyhow::ensure!((1..=256).contains(&n), "--viewers {n}: must be 1..=256");
            anyhow::ensure!(
                n % per == 0,
                "--viewers {n}: a {} session has {per} views, so each count must be a multiple of {per}",
                format!("{:?}", self.layout).to_lowercase()
            );
        }
        for (flag, v, lo, hi) in [
            ("--seconds", self.seconds, 1.0, 3600.0),
            ("--warmup", self.warmup_s, 0.0, 600.0),
            (
                "--first-frame-timeout",
                self.first_frame_timeout_s,
                1.0,
                3600.0,
            ),
            ("--pose-hz", self.pose_hz, 0.1, 1000.0),
        ] {
            anyhow::ensure!(
                v.is_finite() && (lo..=hi).contains(&v),
                "{flag} {v}: must be {lo}..={hi}"
            );
        }
        anyhow::ensure!(
            !self.sizes.is_empty(),
            "--mix: give at least one frame size, e.g. 320x180,480x270,640x360"
        );
        for (i, s) in self.sizes.iter().enumerate() {
            anyhow::ensure!(
                (16..=8192).contains(&s.width) && (16..=8192).contains(&s.height),
                "frame size {s}: width and height must each be 16..=8192 (the server has its own, usually lower, limits)"
            );
            anyhow::ensure!(
                !self.sizes[..i].contains(s),
                "--mix: {s} is given twice; list each size once"
            );
        }
        anyhow::ensure!(
            (1..=100).contains(&self.quality),
            "--quality {}: must be 1..=100",
            self.quality
        );
        Ok(())
    }

    /// Frame size of session `i` of a point: the sizes in turn.
    fn size_of_session(&self, i: usize) -> FrameSize {
        self.sizes[i % self.sizes.len()]
    }

    fn hello(&self, size: FrameSize) -> Hello {
        Hello {
            version: PROTOCOL_VERSION,
            width: size.width,
            height: size.height,
            layout: self.layout,
            views: (self.layout == Layout::Split).then_some(self.split_views),
            quality: Some(self.quality),
            eye_distance_m: None,
            token: self.token.clone(),
            ..Hello::default()
        }
    }
}

/// Pose-to-frame latency percentiles (nearest rank), milliseconds.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Latency {
    /// Latency samples (poses seen in a frame).
    pub samples: usize,
    /// Median.
    pub p50_ms: f64,
    /// 95th percentile.
    pub p95_ms: f64,
    /// 99th percentile.
    pub p99_ms: f64,
    /// Mean.
    pub mean_ms: f64,
    /// Largest.
    pub max_ms: f64,
}

/// What one simulated viewer (one session) got during the measured window.
#[derive(Debug, Clone, Serialize)]
pub struct ViewerStats {
    /// Viewer number within the point (0-based).
    pub index: usize,
    /// Server session id (from the welcome).
    pub session: u64,
    /// Views of the session.
    pub views: u32,
    /// Frame size the session asked for.
    pub size: FrameSize,
    /// Frames received.
    pub frames: u64,
    /// Frames received per second.
    pub fps: f64,
    /// Bytes received (frame headers + JPEG).
    pub bytes: u64,
    /// Bytes received per second.
    pub bytes_per_s: f64,
    /// Mean bytes per frame.
    pub mean_frame_bytes: f64,
    /// Pose-to-frame latency (`None`: no pose came back in a frame).
    pub latency: Option<Latency>,
    /// Pose messages sent.
    pub poses_sent: u64,
    /// Frames the server dropped for this session (its header counter's growth).
    pub dropped_server: u64,
    /// Render-loop frames this session did not receive (gaps in the header frame number).
    pub missed_frames: u64,
    /// Longest time without a frame, from the window's start to its end, ms.
    pub max_gap_ms: f64,
    /// Frames received in each second of the window.
    pub timeline: Vec<u32>,
    /// Seconds of the window in which no frame arrived.
    pub seconds_without_frames: usize,
    /// Mean render time the frame headers report, ms.
    pub header_render_ms: Option<f64>,
    /// Mean compose + encode time the frame headers report, ms.
    pub header_encode_ms: Option<f64>,
    /// Frames whose header or JPEG did not match the session (should be 0).
    pub bad_frames: u64,
    /// Error messages the server sent (should be none).
    pub server_errors: Vec<String>,
    /// Why the session ended before the window did (should be `None`).
    pub ended_early: Option<String>,
    /// The viewer stayed connected, received frames, and either got frames in every
    /// second of the window or got every frame the server rendered in it (below 1
    /// render-loop frame per second some seconds have no frame for anyone).
    pub served_throughout: bool,
}

/// One sweep point over all its viewers.
#[derive(Debug, Clone, Serialize)]
pub struct PointSummary {
    /// Mean of the viewers' fps.
    pub fps_mean: f64,
    /// Lowest viewer fps.
    pub fps_min: f64,
    /// Highest viewer fps.
    pub fps_max: f64,
    /// Latency over every viewer's samples.
    pub latency: Option<Latency>,
    /// Bytes per second over all viewers.
    pub bytes_per_s_total: f64,
    /// Mean bytes per second of one viewer.
    pub bytes_per_s_per_viewer: f64,
    /// Frames received by all viewers.
    pub frames_total: u64,
    /// Frames the server dropped, all viewers.
    pub dropped_server_total: u64,
    /// Render-loop frames missed, all viewers.
    pub missed_frames_total: u64,
    /// Longest time any viewer went without a frame, ms.
    pub max_gap_ms: f64,
    /// Every viewer received frames in every second of the window and stayed connected.
    pub every_viewer_every_second: bool,
    /// Every viewer was [served throughout](ViewerStats::served_throughout).
    pub every_viewer_served_throughout: bool,
    /// Viewers whose session ended before the window did.
    pub viewers_ended_early: usize,
    /// Frames that did not match their session, all viewers.
    pub bad_frames: u64,
}

/// The server's side of a sweep point: `/metrics` deltas over the measured window.
#[derive(Debug, Clone, Serialize)]
pub struct ServerStats {
    /// Seconds between the two scrapes.
    pub seconds: f64,
    /// Render-loop frames.
    pub frames: u64,
    /// Render-loop frames per second.
    pub fps: f64,
    /// Mean render-loop frame time (all render calls of a frame), ms.
    pub frame_ms: Option<f64>,
    /// Mean render call (every session of every size, upload to readback), ms.
    pub render_ms: Option<f64>,
    /// Mean JPEG encode of one session frame, ms.
    pub encode_ms: Option<f64>,
    /// Render calls (one per frame; more only when a failed frame is retried per size).
    pub render_calls: u64,
    /// Views rendered.
    pub views_rendered: u64,
    /// Render calls that failed.
    pub render_errors: u64,
    /// Mean GPU time per render call of each stage (timestamp queries), ms.
    pub stage_gpu_ms: BTreeMap<String, f64>,
    /// Shadow rays traced per render-loop frame, per stage.
    pub rays_per_frame: BTreeMap<String, f64>,
    /// Render calls per render-loop frame (1 with one world for every size; it was the
    /// number of view sizes when each size had its own renderer).
    pub render_calls_per_frame: f64,
    /// Rays traced into the shared world-space shadow grid per render-loop frame
    /// (`fogcast_rays_traced_total{stage="shared_grid"}` over `fogcast_frames_total`):
    /// one grid's worth when the grid is shared by every view size, that times the
    /// number of sizes when each size's render call fills its own.
    pub grid_rays_per_frame: f64,
    /// Grid rays per render call.
    pub grid_rays_per_render_call: f64,
    /// Session frames encoded.
    pub frames_encoded: u64,
    /// Session frames written to sockets.
    pub frames_sent: u64,
    /// Bytes written to sockets.
    pub bytes_sent: u64,
    /// Frames dropped because a client had not taken the previous one.
    pub dropped_client_slow: u64,
    /// Frames skipped because the session's previous frame was still encoding.
    pub dropped_encoder_busy: u64,
    /// Open sessions at the end of the window.
    pub sessions: u64,
    /// Views rendered per frame at the end of the window.
    pub viewers: u64,
    /// View sizes in the server's last frame (one viewer set each, one world for all).
    pub view_sizes: u64,
    /// Server resident memory at the end of the window, MiB.
    pub resident_memory_mib: f64,
}

/// The viewers of one frame size within a sweep point.
#[derive(Debug, Clone, Serialize)]
pub struct SizeResult {
    /// The frame size.
    pub size: FrameSize,
    /// Sessions of this size.
    pub sessions: usize,
    /// Views of those sessions.
    pub views: usize,
    /// Over those viewers only (latency pooled over their samples).
    pub summary: PointSummary,
}

/// One sweep point.
#[derive(Debug, Clone, Serialize)]
pub struct PointResult {
    /// Views rendered for the viewers of this point.
    pub viewers: usize,
    /// Sessions (each of `views_per_session` views).
    pub sessions: usize,
    /// Seconds from the hellos to every viewer having a frame.
    pub first_frames_s: f64,
    /// Length of the measured window, seconds.
    pub window_s: f64,
    /// This machine's 1-minute load average at the end of the window: other work
    /// competing with the server for the CPU (the renderer runs on it, lavapipe).
    pub load_average_1m: Option<f64>,
    /// Over all viewers.
    pub summary: PointSummary,
    /// Per frame size, in the order of the config's sizes (those that had sessions).
    pub sizes: Vec<SizeResult>,
    /// The server's numbers.
    pub server: ServerStats,
    /// Each viewer.
    pub per_viewer: Vec<ViewerStats>,
}

/// Everything a loadgen run measured.
#[derive(Debug, Clone, Serialize)]
pub struct LoadgenReport {
    /// The command line, when run from the CLI.
    pub command: String,
    /// What was asked for.
    pub config: LoadgenConfig,
    /// The server's scene (from `/healthz`).
    pub scene: String,
    /// The server's view limit.
    pub server_max_viewers: usize,
    /// How the viewers' camera paths were made.
    pub camera_paths: String,
    /// This machine: CPU model and logical cores (loadgen and the server share it when
    /// the URL is loopback).
    pub machine: String,
    /// Seconds the whole run took.
    pub duration_s: f64,
    /// One per sweep point, in the order run.
    pub points: Vec<PointResult>,
}

/// Longest wait for the server to let the previous point's sessions go.
const DRAIN_TIMEOUT: Duration = Duration::from_secs(30);

/// Runs the sweep against the server at `config.url`; `progress` gets one line at a time.
pub async fn run(
    config: &LoadgenConfig,
    command: &str,
    progress: &(dyn Fn(&str) + Sync),
) -> anyhow::Result<LoadgenReport> {
    config.validate()?;
    let started = Instant::now();
    let target = Target::parse(&config.url)?;
    let health = scrape::health(&target.authority).await?;
    let free = health.max_viewers.saturating_sub(health.viewers);
    for &n in &config.viewers {
        anyhow::ensure!(
            n <= free,
            "--viewers {n}: the server at {} renders at most {} views and {} are in use; \
             ask for fewer or start the server with --max-views {n}",
            config.url,
            health.max_viewers,
            health.viewers
        );
    }
    let scene = config.scene.clone().unwrap_or_else(|| health.scene.clone());
    let (paths, fallback) = tokio::task::spawn_blocking(move || Paths::load(&scene))
        .await
        .context("loading the scene's camera loop")?;
    if let Some(why) = fallback {
        progress(&format!(
            "loadgen: no camera loop ({why}); viewers circle their welcome viewpoints instead (--scene sets the scene)"
        ));
    }
    let paths = Arc::new(paths);
    progress(&format!(
        "loadgen: {} — scene {:?}, up to {} views; sweep {:?} views, {} s each after {} s warm-up, poses at {} Hz, {} {:?} q{}",
        config.url,
        health.scene,
        health.max_viewers,
        config.viewers,
        config.seconds,
        config.warmup_s,
        config.pose_hz,
        size_list(&config.sizes),
        config.layout,
        config.quality
    ));
    let mut points = Vec::new();
    for &n in &config.viewers {
        let point = run_point(config, &target, &paths, n, progress)
            .await
            .with_context(|| format!("sweep point of {n} views"))?;
        points.push(point);
    }
    Ok(LoadgenReport {
        command: command.to_string(),
        config: config.clone(),
        scene: health.scene,
        server_max_viewers: health.max_viewers,
        camera_paths: paths.describe(),
        machine: machine(),
        duration_s: started.elapsed().as_secs_f64(),
        points,
    })
}

async fn run_point(
    config: &LoadgenConfig,
    target: &Target,
    paths: &Arc<Paths>,
    views: usize,
    progress: &(dyn Fn(&str) + Sync),
) -> anyhow::Result<PointResult> {
    let per = config.views_per_session();
    let sessions = views / per;
    let baseline = scrape::metrics(&target.authority)
        .await?
        .get("fogcast_sessions", "");
    let size_of: Vec<FrameSize> = (0..sessions).map(|i| config.size_of_session(i)).collect();
    progress(&format!(
        "loadgen: {views} views: opening {sessions} sessions ({})",
        sessions_per_size(&config.sizes, &size_of)
    ));
    let opened_at = Instant::now();
    let mut opened = Vec::with_capacity(sessions);
    for (i, size) in size_of.iter().enumerate() {
        let (ws, welcome) = client::open(target, &config.hello(*size))
            .await
            .with_context(|| format!("viewer {i} of {sessions} ({size})"))?;
        opened.push((ws, welcome));
    }
    let slots_per_session = opened.first().map_or(1, |(_, w)| w.poses.len());
    let (stop_tx, stop_rx) = watch::channel(false);
    let epoch = Instant::now();
    let mut tasks = Vec::with_capacity(sessions);
    let mut lives = Vec::with_capacity(sessions);
    let mut meta = Vec::with_capacity(sessions);
    for (i, (ws, welcome)) in opened.into_iter().enumerate() {
        let live = Arc::new(Live::default());
        let flight = Flight {
            paths: paths.clone(),
            first_slot: i * slots_per_session,
            slots: sessions * slots_per_session,
            pose_hz: config.pose_hz,
            epoch,
        };
        meta.push((welcome.session, welcome.views));
        lives.push(live.clone());
        tasks.push(tokio::spawn(client::stream(
            ws,
            welcome,
            flight,
            live,
            stop_rx.clone(),
        )));
    }
    // Stops the viewers whatever happens below (an error, a timeout).
    let _stop_guard = StopOnDrop(stop_tx.clone());

    let deadline = opened_at + Duration::from_secs_f64(config.first_frame_timeout_s);
    loop {
        if let Some((i, why)) = lives
            .iter()
            .enumerate()
            .find_map(|(i, l)| Some((i, l.ended()?)))
        {
            anyhow::bail!("viewer {i} ended before its first frames: {why}");
        }
        if lives.iter().all(|l| l.frames.load(Relaxed) > 0) {
            break;
        }
        if Instant::now() > deadline {
            let waiting: Vec<usize> = (0..sessions)
                .filter(|&i| lives[i].frames.load(Relaxed) == 0)
                .collect();
            anyhow::bail!(
                "viewers {waiting:?} got no frame within {} s (--first-frame-timeout)",
                config.first_frame_timeout_s
            );
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    let first_frames_s = opened_at.elapsed().as_secs_f64();
    progress(&format!(
        "loadgen: {views} views: every viewer has frames after {first_frames_s:.1} s; warming up {} s",
        config.warmup_s
    ));
    tokio::time::sleep(Duration::from_secs_f64(config.warmup_s)).await;

    let before = scrape::metrics(&target.authority).await?;
    let t0 = Instant::now();
    let window = Duration::from_secs_f64(config.seconds);
    let mut last: Vec<u64> = lives.iter().map(|l| l.frames.load(Relaxed)).collect();
    let mut second = 0;
    while t0.elapsed() < window {
        let next = t0 + Duration::from_secs(second + 1);
        let wake = next.min(t0 + window);
        tokio::time::sleep_until(wake.into()).await;
        second += 1;
        let now: Vec<u64> = lives.iter().map(|l| l.frames.load(Relaxed)).collect();
        let mut got: Vec<u64> = now.iter().zip(&last).map(|(a, b)| a - b).collect();
        got.sort_unstable();
        last = now;
        progress(&format!(
            "loadgen: {views} views: {:>4.0} s  frames in the last second per viewer: min {} median {} max {}",
            t0.elapsed().as_secs_f64(),
            got[0],
            got[got.len() / 2],
            got[got.len() - 1]
        ));
    }
    let t1 = Instant::now();
    let after = scrape::metrics(&target.authority).await?;
    let load_average_1m = crate::report::load_average();

    let _ = stop_tx.send(true);
    let mut per_viewer = Vec::with_capacity(sessions);
    let mut latencies = Vec::with_capacity(sessions);
    for (i, ((task, live), (session, views_of))) in
        tasks.into_iter().zip(&lives).zip(meta).enumerate()
    {
        let rec = task.await.context("a viewer task failed")?;
        latencies.push(stats::latencies(&rec, t0, t1));
        per_viewer.push(stats::viewer(
            i,
            session,
            (views_of, size_of[i]),
            &rec,
            (t0, t1),
            live.ended(),
        ));
    }
    let summary = stats::summary(&per_viewer, latencies.concat());
    let sizes = stats::per_size(&config.sizes, &per_viewer, &latencies);
    let server = scrape::server_stats(&before, &after);
    progress(&format!(
        "loadgen: {views} views: {}, server {:.1} fps, {:.1} render calls and {:.0} grid rays per frame{}",
        describe(&summary),
        server.fps,
        server.render_calls_per_frame,
        server.grid_rays_per_frame,
        match (summary.every_viewer_every_second, summary.every_viewer_served_throughout) {
            (true, _) => "",
            (false, true) => "; some second had no frame (the server rendered under 1 fps then), but every viewer got every frame",
            (false, false) => "; SOME VIEWER WAS NOT SERVED THROUGHOUT",
        }
    ));
    if sizes.len() > 1 {
        for s in &sizes {
            progress(&format!(
                "loadgen: {views} views:   {} ({}): {}",
                s.size,
                sessions_count(s.sessions),
                describe(&s.summary)
            ));
        }
    }

    // Let the server release the sessions before the next point asks for views.
    let drained = tokio::time::timeout(DRAIN_TIMEOUT, async {
        loop {
            match scrape::metrics(&target.authority).await {
                Ok(m) if m.get("fogcast_sessions", "") <= baseline => return Ok(()),
                Ok(_) => tokio::time::sleep(Duration::from_millis(50)).await,
                Err(e) => return Err(e),
            }
        }
    })
    .await;
    match drained {
        Ok(r) => r?,
        Err(_) => anyhow::bail!(
            "the server still had sessions {} s after the viewers left",
            DRAIN_TIMEOUT.as_secs()
        ),
    }
    Ok(PointResult {
        viewers: views,
        sessions,
        first_frames_s,
        window_s: t1.duration_since(t0).as_secs_f64(),
        load_average_1m,
        summary,
        sizes,
        server,
        per_viewer,
    })
}

/// "fps per viewer (min), latency percentiles, bandwidth per viewer" of a summary.
pub(crate) fn describe(s: &PointSummary) -> String {
    let lat = s.latency.map_or_else(
        || "no latency samples".into(),
        |l| {
            format!(
                "latency p50 {:.0} / p95 {:.0} / p99 {:.0} ms",
                l.p50_ms, l.p95_ms, l.p99_ms
            )
        },
    );
    format!(
        "{:.1} fps per viewer (min {:.1}), {lat}, {:.0} KiB/s per viewer",
        s.fps_mean,
        s.fps_min,
        s.bytes_per_s_per_viewer / 1024.0
    )
}

/// "256x144", or "320x180, 480x270 and 640x360 (each point's sessions split evenly over
/// them)".
pub(crate) fn size_list(sizes: &[FrameSize]) -> String {
    match sizes {
        [one] => one.to_string(),
        [rest @ .., last] => format!(
            "{} and {last} (each point's sessions split evenly over them)",
            rest.iter()
                .map(FrameSize::to_string)
                .collect::<Vec<_>>()
                .join(", ")
        ),
        [] => String::new(),
    }
}

/// "1 session", "2 sessions".
pub(crate) fn sessions_count(n: usize) -> String {
    format!("{n} session{}", if n == 1 { "" } else { "s" })
}

/// "320x180: 2, 480x270: 1" — the sessions of each size, in the order of `sizes`.
fn sessions_per_size(sizes: &[FrameSize], size_of: &[FrameSize]) -> String {
    sizes
        .iter()
        .map(|s| format!("{s}: {}", size_of.iter().filter(|t| *t == s).count()))
        .collect::<Vec<_>>()
        .join(", ")
}

struct StopOnDrop(watch::Sender<bool>);

impl Drop for StopOnDrop {
    fn drop(&mut self) {
        let _ = self.0.send(true);
    }
}

/// "CPU model, N logical cores" of this machine.
fn machine() -> String {
    let cores = std::thread::available_parallelism().map_or(0, |n| n.get());
    let model = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("model name"))
                .and_then(|l| l.split_once(':'))
                .map(|(_, m)| m.trim().to_string())
        })
        .unwrap_or_else(|| "unknown CPU".into());
    format!("{model}, {cores} logical cores")
}
