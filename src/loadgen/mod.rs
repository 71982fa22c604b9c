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
//!
//! Streaming scenarios (issue 17): every viewer acks its frames (`--ack`), asks for
//! `--codec jpeg|h264`, and optionally measures image quality against raw frames
//! (`--raw-every`, [`quality`]); the first `--throttled` viewers of a point read their
//! socket at `--throttle-kbps` ([`Throttled`]) and are reported as their own class; a
//! baseline phase (`--baseline-s`) measures every viewer on a fast link first; the
//! window is also cut into `--window-s` pieces so latency and memory creep show;
//! `--churn-s` closes and reopens every session periodically; `--check-*` turn the
//! numbers into pass/fail ([`Checks`]).

mod checks;
mod cli;
mod client;
mod output;
mod paths;
mod point;
pub mod quality;
mod scrape;
mod stats;
mod throttle;

pub use checks::{CheckResult, Checks};
pub use cli::{loadgen, AckArg, CodecArg, LayoutArg, LoadgenArgs, SweepArg};
pub use output::write_report;
pub use throttle::Throttled;

use crate::protocol::{Codec, Hello, Layout, MAX_SPLIT_VIEWS, PROTOCOL_VERSION};
use anyhow::Context as _;
use client::Target;
use paths::Paths;
use serde::Serialize;
use std::collections::BTreeMap;
use std::sync::Arc;
use std::time::Instant;

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
    /// Frame codec each session asks for.
    pub codec: Codec,
    /// Every viewer acks every frame it receives (flow control on the server).
    pub ack: bool,
    /// Bitrate ceiling each session asks for, kbit/s (default: the server's).
    pub max_kbps: Option<u32>,
    /// Ask for a raw frame every `raw_every` frames and measure the encoded frames' PSNR
    /// against them (needs a server with `debug_raw_frames`).
    pub raw_every: Option<u32>,
    /// The throttled viewers read their socket at this many kbit/s.
    pub throttle_kbps: Option<u32>,
    /// How many viewers of each point are throttled (the first ones).
    pub throttled: usize,
    /// Length of the windows the measured run is cut into (latency, fps and server
    /// memory per window), seconds.
    pub window_s: f64,
    /// Every viewer closes and reopens its session this often, seconds (staggered).
    pub churn_s: Option<f64>,
    /// Seconds of a baseline phase with every viewer on a fast link (the same views,
    /// so the same render cost), before the throttled ones reconnect through their slow
    /// links and the measured window starts.
    pub baseline_s: Option<f64>,
    /// Pass/fail checks on the numbers.
    pub checks: Checks,
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
            codec: Codec::Jpeg,
            ack: true,
            max_kbps: None,
            raw_every: None,
            throttle_kbps: None,
            throttled: 0,
            window_s: 60.0,
            churn_s: None,
            baseline_s: None,
            checks: Checks::default(),
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
        self.validate_streaming()
    }

    /// The streaming scenario's flags (issue 17), checked.
    fn validate_streaming(&self) -> anyhow::Result<()> {
        if self.codec == Codec::H264 {
            for s in &self.sizes {
                anyhow::ensure!(
                    s.width.is_multiple_of(2) && s.height.is_multiple_of(2),
                    "frame size {s} with --codec h264: H.264 needs an even width and height"
                );
            }
        }
        if let Some(k) = self.max_kbps {
            anyhow::ensure!(
                k > 0,
                "--max-kbps 0: must be positive (the server refuses anything below its min_kbps, 150 by default)"
            );
        }
        if let Some(n) = self.raw_every {
            anyhow::ensure!((1..=1000).contains(&n), "--raw-every {n}: must be 1..=1000");
        }
        match self.throttle_kbps {
            Some(k) => {
                anyhow::ensure!(
                    (8..=10_000_000).contains(&k),
                    "--throttle-kbps {k}: must be 8..=10000000"
                );
                let per = self.views_per_session();
                for &n in &self.viewers {
                    let sessions = n / per;
                    anyhow::ensure!(
                        self.throttled <= sessions,
                        "--throttled {}: the point of {n} views has only {sessions} sessions",
                        self.throttled
                    );
                    anyhow::ensure!(
                        self.baseline_s.is_none() || self.throttled < sessions,
                        "--baseline-s with --throttled {} at {n} views: the baseline needs at least one unthrottled viewer",
                        self.throttled
                    );
                }
            }
            None => anyhow::ensure!(
                self.throttled == 0,
                "--throttled {}: give --throttle-kbps too (the rate the throttled viewers read at)",
                self.throttled
            ),
        }
        for (flag, v, lo, hi) in [
            ("--window-s", Some(self.window_s), 1.0, 3600.0),
            ("--churn-s", self.churn_s, 1.0, 3600.0),
            ("--baseline-s", self.baseline_s, 1.0, 3600.0),
        ] {
            if let Some(v) = v {
                anyhow::ensure!(
                    v.is_finite() && (lo..=hi).contains(&v),
                    "{flag} {v}: must be {lo}..={hi}"
                );
            }
        }
        anyhow::ensure!(
            self.checks.fps_within.is_none() || self.baseline_s.is_some(),
            "--check-fps-within compares with a baseline: give --baseline-s too"
        );
        if self.checks.memory_growth.is_some() || self.checks.creep.is_some() {
            let windows = self.windows();
            anyhow::ensure!(
                windows >= 3,
                "--check-memory-growth/--check-creep compare windows of the run, but --seconds {} / --window-s {} makes {windows}; make --window-s at most a third of --seconds",
                self.seconds,
                self.window_s
            );
        }
        self.checks.validate()
    }

    /// Windows the measured run is cut into: equal parts of about `window_s`.
    pub fn windows(&self) -> usize {
        ((self.seconds / self.window_s).round() as usize).max(1)
    }

    /// Throttled sessions of a point of `sessions` sessions (the first ones).
    fn throttled_of(&self, sessions: usize) -> usize {
        if self.throttle_kbps.is_some() {
            self.throttled.min(sessions)
        } else {
            0
        }
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
            codec: Some(self.codec),
            max_kbps: self.max_kbps,
            raw_every: self.raw_every,
            token: self.token.clone(),
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
    /// Frames whose header or payload did not match the session (should be 0).
    pub bad_frames: u64,
    /// Whether this viewer read its socket at `--throttle-kbps`.
    pub throttled: bool,
    /// Mean encoded payload per frame (header and raw frames excluded), bytes.
    pub encoded_bytes_per_frame: f64,
    /// Key frames received (every JPEG; H.264 IDRs).
    pub key_frames: u64,
    /// Raw (debugging) frames received; not counted in frames, fps or bytes.
    pub raw_frames: u64,
    /// Encoded frames that did not decode (`--raw-every` only; each asked for a key frame).
    pub decode_errors: u64,
    /// PSNR of the encoded frames against the raw ones (`--raw-every` only).
    pub quality: Option<Quality>,
    /// Sessions this viewer opened during the whole point (more than 1 with churn).
    pub sessions_opened: u64,
    /// Failed attempts to reopen a churned session.
    pub reopen_failures: u64,
    /// Welcomes with `reason: bandwidth`: the server changed the frame size.
    pub bandwidth_welcomes: u64,
    /// The server did not know acks (`unknown_type`), so this viewer stopped sending them.
    pub acks_refused: bool,
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
    /// Mean encoded payload per frame over every viewer's frames (raw excluded), bytes.
    pub encoded_bytes_per_frame: f64,
    /// Key frames received, all viewers.
    pub key_frames: u64,
    /// Frames that did not decode, all viewers (`--raw-every`).
    pub decode_errors: u64,
    /// PSNR over every viewer's compared frames (`--raw-every`).
    pub quality: Option<Quality>,
}

/// PSNR of the encoded frames against the raw frames of the same frame number.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Quality {
    /// Frames compared.
    pub compared: usize,
    /// Mean PSNR, dB (identical pictures count as [`quality::PSNR_CAP_DB`]).
    pub psnr_mean_db: f64,
    /// Lowest PSNR, dB.
    pub psnr_min_db: f64,
}

/// Which viewers a class holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ViewerClass {
    /// Viewers reading their socket as fast as frames come.
    Unthrottled,
    /// Viewers reading at `--throttle-kbps`.
    Throttled,
}

impl ViewerClass {
    /// The class's name in reports.
    pub fn as_str(self) -> &'static str {
        match self {
            ViewerClass::Unthrottled => "unthrottled",
            ViewerClass::Throttled => "throttled",
        }
    }
}

/// One window of the measured run, over the viewers of one class.
#[derive(Debug, Clone, Serialize)]
pub struct WindowStats {
    /// Start, seconds into the measured run.
    pub start_s: f64,
    /// End, seconds.
    pub end_s: f64,
    /// Mean of the viewers' fps in the window.
    pub fps_mean: f64,
    /// 95th percentile pose-to-frame latency over the window's samples, ms.
    pub latency_p95_ms: Option<f64>,
    /// Latency samples in the window.
    pub latency_samples: usize,
}

/// The viewers of one class within a point.
#[derive(Debug, Clone, Serialize)]
pub struct ClassResult {
    /// Throttled or not.
    pub class: ViewerClass,
    /// Sessions of the class.
    pub sessions: usize,
    /// The rate they read at, kbit/s (throttled class).
    pub throttle_kbps: Option<u32>,
    /// Over the whole measured window.
    pub summary: PointSummary,
    /// Per `--window-s` window.
    pub windows: Vec<WindowStats>,
}

/// The server's memory over one window of the measured run.
#[derive(Debug, Clone, Serialize)]
pub struct ServerWindow {
    /// Start, seconds into the measured run.
    pub start_s: f64,
    /// End, seconds.
    pub end_s: f64,
    /// Largest `fogcast_resident_memory_bytes` scraped in the window (once a second), MiB.
    pub resident_memory_mib: Option<f64>,
}

/// The baseline phase: every viewer on a fast link, before the throttled ones reconnect
/// through their slow links (its numbers are the unthrottled viewers').
#[derive(Debug, Clone, Serialize)]
pub struct Baseline {
    /// Length, seconds.
    pub seconds: f64,
    /// The server's render-loop fps meanwhile (on a CPU renderer the throttled viewers'
    /// views slow it down too, whatever their links).
    pub server_fps: f64,
    /// Sessions measured (the unthrottled ones).
    pub sessions: usize,
    /// Their numbers.
    pub summary: PointSummary,
}

/// Sessions loadgen opened against what the server counted.
#[derive(Debug, Clone, Serialize)]
pub struct SessionAccounting {
    /// Sessions loadgen opened (welcomes received), churn included.
    pub opened_by_loadgen: u64,
    /// Failed reopen attempts (not sessions).
    pub reopen_failures: u64,
    /// Growth of `fogcast_sessions_total` from before the first hello to after the
    /// server let the last session go.
    pub server_opened: u64,
    /// Growth of `fogcast_sessions_closed_total`, when the server has it.
    pub server_closed: Option<u64>,
    /// `fogcast_sessions` before the point.
    pub open_before: u64,
    /// `fogcast_sessions` after the point.
    pub open_after: u64,
    /// Every session opened is one the server counted, and it closed them all.
    pub accounted: bool,
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
    /// Unthrottled and throttled viewers apart (those that had viewers), with windows.
    pub classes: Vec<ClassResult>,
    /// The server's memory per window.
    pub server_windows: Vec<ServerWindow>,
    /// The baseline phase (`--baseline-s`).
    pub baseline: Option<Baseline>,
    /// Sessions opened and closed, loadgen's count against the server's.
    pub sessions_accounting: SessionAccounting,
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
    /// The `--check-*` results (empty without checks).
    pub checks: Vec<CheckResult>,
}

impl LoadgenReport {
    /// The checks that failed.
    pub fn failed_checks(&self) -> Vec<&CheckResult> {
        self.checks.iter().filter(|c| !c.passed).collect()
    }
}

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
        "loadgen: {} — scene {:?}, up to {} views; sweep {:?} views, {} s each after {} s warm-up, poses at {} Hz, {} {:?} {} q{}{}",
        config.url,
        health.scene,
        health.max_viewers,
        config.viewers,
        config.seconds,
        config.warmup_s,
        config.pose_hz,
        size_list(&config.sizes),
        config.layout,
        config.codec.as_str(),
        config.quality,
        streaming_summary(config)
    ));
    let mut points = Vec::new();
    for &n in &config.viewers {
        let point = point::run_point(config, &target, &paths, n, progress)
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
        checks: checks::evaluate(&config.checks, &points),
        points,
    })
}

/// ", h264, acks, raw every 5, 1 viewer at 1000 kbit/s, …" for the progress line.
fn streaming_summary(c: &LoadgenConfig) -> String {
    let mut parts = vec![if c.ack { "acks" } else { "no acks" }.to_string()];
    if let Some(n) = c.raw_every {
        parts.push(format!("PSNR against a raw frame every {n}"));
    }
    if let Some(k) = c.throttle_kbps {
        parts.push(format!("{} viewer(s) per point at {k} kbit/s", c.throttled));
    }
    if let Some(b) = c.baseline_s {
        parts.push(format!("{b} s baseline"));
    }
    if let Some(s) = c.churn_s {
        parts.push(format!("sessions reopened every {s} s"));
    }
    parts.push(format!("{} window(s)", c.windows()));
    format!(", {}", parts.join(", "))
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
