//! Server counters and their Prometheus text export (`/metrics`).
//!
//! Counters are atomics bumped by the render thread, the encoders and the session tasks;
//! nothing here blocks anyone for longer than a map insert.

use crate::protocol::ErrorCode;
use crate::render::{FrameStats, Stage};
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::sync::atomic::{AtomicI64, AtomicU64, Ordering::Relaxed};
use std::sync::Mutex;

/// A Prometheus summary without quantiles: sum of seconds and count.
#[derive(Default)]
pub(crate) struct Summary {
    sum_ns: AtomicU64,
    count: AtomicU64,
}

impl Summary {
    pub(crate) fn observe_ms(&self, ms: f64) {
        self.sum_ns.fetch_add((ms.max(0.0) * 1e6) as u64, Relaxed);
        self.count.fetch_add(1, Relaxed);
    }

    fn write(&self, out: &mut String, name: &str, labels: &str) {
        let lbl = if labels.is_empty() {
            String::new()
        } else {
            format!("{{{labels}}}")
        };
        let _ = writeln!(
            out,
            "{name}_sum{lbl} {}",
            self.sum_ns.load(Relaxed) as f64 * 1e-9
        );
        let _ = writeln!(out, "{name}_count{lbl} {}", self.count.load(Relaxed));
    }
}

/// Why a frame did not reach a client.
#[derive(Debug, Clone, Copy)]
pub(crate) enum DropReason {
    /// The client was not ready for it: a newer frame replaced it before the client's
    /// socket took it, or its flow window was full (skipped before encoding).
    ClientSlow,
    /// The session's previous frame was still being encoded.
    EncoderBusy,
    /// Rendered at a size the client has not been told (yet, or any more): a configure
    /// changed it; only frames of the size in the last welcome are sent.
    Resized,
    /// The H.264 rate control skipped it: the session's bitrate was spent.
    RateControl,
}

/// Every counter of the server.
#[derive(Default)]
pub(crate) struct Telemetry {
    pub(crate) frames: AtomicU64,
    pub(crate) views_rendered: AtomicU64,
    pub(crate) render_calls: AtomicU64,
    /// Shared-grid rays of the last render call (one world: the frame's).
    grid_rays_last: AtomicU64,
    pub(crate) render_errors: AtomicU64,
    /// Panics caught on the render thread (the frame or size group was dropped).
    pub(crate) render_panics: AtomicU64,
    /// Panics caught on the encoder pool (that session's frame was dropped).
    pub(crate) encode_panics: AtomicU64,
    /// Sessions closed because no frame reached them within the frame timeout.
    pub(crate) sessions_starved: AtomicU64,
    pub(crate) frame_seconds: Summary,
    pub(crate) render_seconds: Summary,
    pub(crate) encode_seconds: Summary,
    stage_gpu: Mutex<BTreeMap<String, (f64, u64)>>,
    rays: [AtomicU64; 4],
    /// Frames encoded, per codec (JPEG, H.264).
    pub(crate) frames_jpeg: AtomicU64,
    pub(crate) frames_h264: AtomicU64,
    /// H.264 key frames encoded.
    pub(crate) key_frames: AtomicU64,
    /// Raw debug frames sent (`raw_every`).
    pub(crate) raw_frames: AtomicU64,
    /// Frame-size changes made for a client's bandwidth, down and up.
    pub(crate) resized_down: AtomicU64,
    pub(crate) resized_up: AtomicU64,
    /// Sessions closed (any reason); opened − closed = open.
    pub(crate) sessions_closed: AtomicU64,
    /// Sessions closed by the idle timeout.
    pub(crate) sessions_idle: AtomicU64,
    /// Sum over sessions of their target bitrate, kbit/s (gauge, set by the writers).
    pub(crate) target_kbps_sum: AtomicI64,
    pub(crate) frames_sent: AtomicU64,
    pub(crate) bytes_sent: AtomicU64,
    dropped_slow: AtomicU64,
    dropped_busy: AtomicU64,
    dropped_resized: AtomicU64,
    dropped_rate: AtomicU64,
    pub(crate) sessions_total: AtomicU64,
    pub(crate) sessions_stalled: AtomicU64,
    pub(crate) connections: AtomicI64,
    pub(crate) connections_refused: AtomicU64,
    pub(crate) slot_bytes: AtomicI64,
    pub(crate) view_sizes: AtomicI64,
    errors: Mutex<BTreeMap<(ErrorCode, bool), u64>>,
}

/// The stages that trace shadow rays, with their `/metrics` label.
fn ray_stages() -> impl Iterator<Item = (Stage, &'static str)> {
    Stage::ALL
        .into_iter()
        .filter_map(|s| s.rays().map(|(_, label)| (s, label)))
}

impl Telemetry {
    /// Adds one render call's counters and GPU stage times.
    pub(crate) fn record_render(&self, stats: &FrameStats) {
        self.render_calls.fetch_add(1, Relaxed);
        self.grid_rays_last
            .store(stats.rays.of_stage(Stage::SharedGrid), Relaxed);
        self.views_rendered.fetch_add(stats.viewers as u64, Relaxed);
        self.render_seconds.observe_ms(stats.frame_ms);
        for (slot, (stage, _)) in self.rays.iter().zip(ray_stages()) {
            slot.fetch_add(stats.rays.of_stage(stage), Relaxed);
        }
        let mut stages = self.stage_gpu.lock().unwrap_or_else(|e| e.into_inner());
        for s in &stats.stage_gpu_ms {
            let e = stages.entry(s.stage.clone()).or_default();
            e.0 += s.gpu_ms * 1e-3;
            e.1 += 1;
        }
    }

    pub(crate) fn dropped(&self, reason: DropReason) {
        match reason {
            DropReason::ClientSlow => self.dropped_slow.fetch_add(1, Relaxed),
            DropReason::EncoderBusy => self.dropped_busy.fetch_add(1, Relaxed),
            DropReason::Resized => self.dropped_resized.fetch_add(1, Relaxed),
            DropReason::RateControl => self.dropped_rate.fetch_add(1, Relaxed),
        };
    }

    /// Frames dropped for any reason.
    pub(crate) fn frames_dropped(&self) -> u64 {
        self.dropped_slow.load(Relaxed)
            + self.dropped_busy.load(Relaxed)
            + self.dropped_resized.load(Relaxed)
            + self.dropped_rate.load(Relaxed)
    }

    pub(crate) fn client_error(&self, code: ErrorCode, fatal: bool) {
        *self
            .errors
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .entry((code, fatal))
            .or_default() += 1;
    }

    /// The Prometheus text exposition of every counter; `sessions` and `views` are the
    /// live gauges from the session table.
    pub(crate) fn export(&self, sessions: usize, views: usize) -> String {
        let mut o = String::with_capacity(4096);
        let metric =
            |o: &mut String, name: &str, kind: &str, help: &str, samples: &[(&str, f64)]| {
                let _ = writeln!(o, "# HELP {name} {help}\n# TYPE {name} {kind}");
                for (labels, v) in samples {
                    if labels.is_empty() {
                        let _ = writeln!(o, "{name} {v}");
                    } else {
                        let _ = writeln!(o, "{name}{{{labels}}} {v}");
                    }
                }
            };
        let n = |a: &AtomicU64| a.load(Relaxed) as f64;
        metric(
            &mut o,
            "fogcast_sessions",
            "gauge",
            "Open viewer sessions.",
            &[("", sessions as f64)],
        );
        metric(
            &mut o,
            "fogcast_viewers",
            "gauge",
            "Views rendered per frame (mono 1, stereo 2, split 2-4 per session).",
            &[("", views as f64)],
        );
        metric(
            &mut o,
            "fogcast_connections",
            "gauge",
            "Open WebSocket connections, handshakes included.",
            &[("", self.connections.load(Relaxed) as f64)],
        );
        metric(
            &mut o,
            "fogcast_connections_refused_total",
            "counter",
            "Sessions refused at max_connections, and connections closed over max_pending_per_ip or max_pending.",
            &[("", n(&self.connections_refused))],
        );
        metric(
            &mut o,
            "fogcast_sessions_total",
            "counter",
            "Sessions opened.",
            &[("", n(&self.sessions_total))],
        );
        metric(
            &mut o,
            "fogcast_sessions_closed_total",
            "counter",
            "Sessions closed, any reason (opened minus closed is fogcast_sessions).",
            &[("", n(&self.sessions_closed))],
        );
        metric(
            &mut o,
            "fogcast_sessions_idle_total",
            "counter",
            "Sessions closed because they sent no pose for idle_timeout_s.",
            &[("", n(&self.sessions_idle))],
        );
        metric(
            &mut o,
            "fogcast_sessions_stalled_total",
            "counter",
            "Sessions closed because one frame could not be sent within stall_timeout_s.",
            &[("", n(&self.sessions_stalled))],
        );
        metric(
            &mut o,
            "fogcast_frames_total",
            "counter",
            "Render-loop frames with at least one view.",
            &[("", n(&self.frames))],
        );
        metric(
            &mut o,
            "fogcast_views_rendered_total",
            "counter",
            "Views rendered.",
            &[("", n(&self.views_rendered))],
        );
        metric(
            &mut o,
            "fogcast_render_calls_total",
            "counter",
            "Render calls: one per frame for every session of every size (more only when a failed frame is retried per view size).",
            &[("", n(&self.render_calls))],
        );
        metric(
            &mut o,
            "fogcast_grid_rays_last_frame",
            "gauge",
            "Shadow rays traced into the shared world-space grid in the last frame, for every viewer of every size together.",
            &[("", n(&self.grid_rays_last))],
        );
        metric(
            &mut o,
            "fogcast_render_errors_total",
            "counter",
            "Render calls that failed.",
            &[("", n(&self.render_errors))],
        );
        metric(
            &mut o,
            "fogcast_panics_total",
            "counter",
            "Panics caught and contained, per thread kind.",
            &[
                ("thread=\"render\"", n(&self.render_panics)),
                ("thread=\"encode\"", n(&self.encode_panics)),
            ],
        );
        metric(
            &mut o,
            "fogcast_sessions_starved_total",
            "counter",
            "Sessions closed because no frame reached them within the frame timeout.",
            &[("", n(&self.sessions_starved))],
        );
        metric(
            &mut o,
            "fogcast_view_sizes",
            "gauge",
            "View sizes rendered in the last frame (one viewer set each, all in one world).",
            &[("", self.view_sizes.load(Relaxed) as f64)],
        );
        let rays: Vec<(String, f64)> = ray_stages()
            .zip(&self.rays)
            .map(|((_, s), a)| (format!("stage=\"{s}\""), n(a)))
            .collect();
        let rays: Vec<(&str, f64)> = rays.iter().map(|(l, v)| (l.as_str(), *v)).collect();
        metric(
            &mut o,
            "fogcast_rays_traced_total",
            "counter",
            "Shadow rays traced, per stage.",
            &rays,
        );
        metric(
            &mut o,
            "fogcast_frames_encoded_total",
            "counter",
            "Session frames encoded, per codec.",
            &[
                ("codec=\"jpeg\"", n(&self.frames_jpeg)),
                ("codec=\"h264\"", n(&self.frames_h264)),
            ],
        );
        metric(
            &mut o,
            "fogcast_key_frames_total",
            "counter",
            "H.264 key frames encoded (stream starts, configures, client requests, GOP).",
            &[("", n(&self.key_frames))],
        );
        metric(
            &mut o,
            "fogcast_raw_frames_total",
            "counter",
            "Raw debug frames sent (raw_every).",
            &[("", n(&self.raw_frames))],
        );
        metric(
            &mut o,
            "fogcast_bandwidth_resizes_total",
            "counter",
            "Frame-size changes the server made for a client's bandwidth.",
            &[
                ("direction=\"down\"", n(&self.resized_down)),
                ("direction=\"up\"", n(&self.resized_up)),
            ],
        );
        metric(
            &mut o,
            "fogcast_target_kbps",
            "gauge",
            "Sum of every session's adaptive target bitrate, kbit/s.",
            &[("", self.target_kbps_sum.load(Relaxed) as f64)],
        );
        metric(
            &mut o,
            "fogcast_frames_sent_total",
            "counter",
            "Session frames written to a socket.",
            &[("", n(&self.frames_sent))],
        );
        metric(
            &mut o,
            "fogcast_bytes_sent_total",
            "counter",
            "Frame bytes written to sockets (headers included).",
            &[("", n(&self.bytes_sent))],
        );
        metric(
            &mut o,
            "fogcast_frames_dropped_total",
            "counter",
            "Session frames dropped: the client was not ready (replaced by a newer frame, or its flow window full), the previous frame was still encoding, rendered at a size the client was not told, or skipped by the H.264 rate control.",
            &[("reason=\"client_slow\"", n(&self.dropped_slow)), ("reason=\"encoder_busy\"", n(&self.dropped_busy)), ("reason=\"resized\"", n(&self.dropped_resized)), ("reason=\"rate_control\"", n(&self.dropped_rate))],
        );
        metric(
            &mut o,
            "fogcast_frame_slot_bytes",
            "gauge",
            "Encoded frames waiting in latest-frame slots, bytes.",
            &[("", self.slot_bytes.load(Relaxed) as f64)],
        );
        metric(
            &mut o,
            "fogcast_resident_memory_bytes",
            "gauge",
            "Resident memory of the server process.",
            &[("", resident_memory_bytes().unwrap_or(0) as f64)],
        );
        let errors: Vec<(String, f64)> = self
            .errors
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .iter()
            .map(|((code, fatal), v)| {
                (
                    format!("code=\"{}\",fatal=\"{fatal}\"", code.as_str()),
                    *v as f64,
                )
            })
            .collect();
        let errors: Vec<(&str, f64)> = errors.iter().map(|(l, v)| (l.as_str(), *v)).collect();
        metric(
            &mut o,
            "fogcast_client_errors_total",
            "counter",
            "Client messages rejected, per error code.",
            &errors,
        );
        for (name, help, s) in [
            (
                "fogcast_frame_seconds",
                "Render-loop frame time (all render calls of a frame).",
                &self.frame_seconds,
            ),
            (
                "fogcast_render_seconds",
                "Host time of one batched render call, upload to readback.",
                &self.render_seconds,
            ),
            (
                "fogcast_encode_seconds",
                "Compose + JPEG encode time of one session frame.",
                &self.encode_seconds,
            ),
        ] {
            let _ = writeln!(o, "# HELP {name} {help}\n# TYPE {name} summary");
            s.write(&mut o, name, "");
        }
        let _ = writeln!(o, "# HELP fogcast_stage_gpu_seconds GPU time per render stage (timestamp queries).\n# TYPE fogcast_stage_gpu_seconds summary");
        for (stage, (sum, count)) in self
            .stage_gpu
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .iter()
        {
            let _ = writeln!(
                o,
                "fogcast_stage_gpu_seconds_sum{{stage=\"{stage}\"}} {sum}"
            );
            let _ = writeln!(
                o,
                "fogcast_stage_gpu_seconds_count{{stage=\"{stage}\"}} {count}"
            );
        }
        o
    }
}

/// Resident set size from `/proc/self/status` (Linux; `None` elsewhere).
pub fn resident_memory_bytes() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmRSS:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}
