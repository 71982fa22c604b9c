//! The render thread: the only owner of the wgpu device's work. Each frame it snapshots
//! every session's latest poses, renders all of them in one call — one world (grid,
//! shadow maps, transmittance) for every session whatever its view size, one submission —
//! and hands each session's frame (its views already tiled in place) to the encoder pool.
//! It never waits on a client: a session whose previous frame is still being encoded
//! skips this one, and a frame nobody took is replaced (both counted).
//!
//! A failed or panicking frame is retried once per view size, so that only the sessions
//! of the size that fails are closed (`render_failed`); the others get this frame.

use super::config::FaultKind;
use super::encode::EncodeJob;
use super::hub::{Hub, SessionSnapshot};
use super::telemetry::DropReason;
use super::validate::ProtocolError;
use crate::gpu::GpuContext;
use crate::protocol::{Codec, ErrorCode};
use crate::render::{FrameTarget, Renderer, Settings, TargetView, TargetsOutput, ViewerId};
use crate::scene::Bvh;
use std::collections::BTreeMap;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::atomic::Ordering::{AcqRel, Relaxed, Release};
use std::sync::Arc;
use std::time::{Duration, Instant};

pub(crate) struct RenderLoop {
    hub: Arc<Hub>,
    ctx: Arc<GpuContext>,
    encoders: rayon::ThreadPool,
    /// The one renderer; `None` after a panic left it half-updated (rebuilt before the
    /// next frame from the BVH kept here).
    renderer: Option<Renderer>,
    bvh: Bvh,
    settings: Settings,
    frame: u64,
}

/// The viewer id of view `view` of session `session`: stable while the session lives.
fn viewer_id(session: u64, view: usize) -> ViewerId {
    session * 8 + view as ViewerId
}

/// The frame a session asks for: its views tiled as its layout says.
fn target_of(s: &SessionSnapshot) -> FrameTarget {
    let spec = &s.spec;
    FrameTarget {
        width: spec.width,
        height: spec.height,
        view_width: spec.view_width,
        view_height: spec.view_height,
        views: s
            .cameras
            .iter()
            .enumerate()
            .map(|(i, camera)| {
                let (x, y) = spec.tile_origin(i);
                TargetView {
                    id: viewer_id(s.session.id, i),
                    camera: *camera,
                    origin: [x, y],
                }
            })
            .collect(),
    }
}

impl RenderLoop {
    /// The render loop over `renderer` (built from `bvh` under `settings`, kept to
    /// rebuild it after a panic).
    pub(crate) fn new(
        hub: Arc<Hub>,
        ctx: Arc<GpuContext>,
        bvh: Bvh,
        settings: Settings,
        renderer: Renderer,
    ) -> anyhow::Result<RenderLoop> {
        let threads = match hub.config.encode_threads {
            0 => std::thread::available_parallelism().map_or(2, |n| n.get()),
            n => n,
        };
        let encoders = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .thread_name(|i| format!("fogcast-encode-{i}"))
            .build()?;
        Ok(RenderLoop {
            hub,
            ctx,
            encoders,
            renderer: Some(renderer),
            bvh,
            settings,
            frame: 0,
        })
    }

    /// Runs until the hub shuts down.
    pub(crate) fn run(mut self) {
        let hub = self.hub.clone();
        self.run_frames();
        hub.render_stopped();
    }

    fn run_frames(&mut self) {
        let period = Duration::from_secs_f64(1.0 / self.hub.config.fps);
        let mut next = Instant::now();
        while !self.hub.shutdown.load(Relaxed) {
            self.hub.heartbeat();
            // Sessions already marked failed are closing; nothing is rendered for them.
            let sessions: Vec<_> = self
                .hub
                .snapshot()
                .into_iter()
                .filter(|s| !s.session.is_failed())
                .collect();
            if sessions.is_empty() {
                self.hub.wait_for_sessions(Duration::from_millis(250));
                next = Instant::now();
                continue;
            }
            let started = Instant::now();
            // A panic anywhere in the frame (outside a render call, which is caught on
            // its own) drops this frame; the renderer may be mid-update, so it is rebuilt.
            if let Err(panic) = catch_unwind(AssertUnwindSafe(|| self.render_frame(sessions))) {
                let what = format!("the render loop panicked: {}", panic_message(&*panic));
                tracing::error!(error = %what, "frame dropped");
                self.hub.telemetry.render_panics.fetch_add(1, Relaxed);
                self.hub.record_failure(what);
                self.renderer = None;
            }
            self.hub
                .telemetry
                .frame_seconds
                .observe_ms(started.elapsed().as_secs_f64() * 1e3);
            // Frame pacing: hold the cap, but never try to catch up on missed frames.
            next += period;
            let now = Instant::now();
            if next > now {
                std::thread::sleep(next - now);
            } else {
                next = now;
            }
        }
        tracing::info!(frames = self.frame, "render loop stopped");
    }

    fn render_frame(&mut self, sessions: Vec<SessionSnapshot>) {
        self.frame += 1;
        if let Some(why) = self.hub.device_lost() {
            let e = ProtocolError::new(
                ErrorCode::RenderFailed,
                format!(
                    "the server's GPU device was lost ({why}); it cannot render until restarted"
                ),
            );
            for s in &sessions {
                s.session.fail(e.clone());
            }
            return;
        }
        let time_s = (self.hub.started.elapsed().as_secs_f64() % 86_400.0) as f32;
        // An injected `Skip` fault leaves its size out without a word.
        let sessions: Vec<SessionSnapshot> = sessions
            .into_iter()
            .filter(|s| self.fault_for(&[s]) != Some(FaultKind::Skip))
            .collect();
        let all: Vec<&SessionSnapshot> = sessions.iter().collect();
        match self.render(&all, time_s) {
            Ok(out) => self.deliver(&all, out),
            Err(error) => {
                // Retried per view size: only the size that fails closes its sessions.
                let mut by_size: BTreeMap<(u32, u32), Vec<&SessionSnapshot>> = BTreeMap::new();
                for s in &all {
                    let size = (s.spec.view_width, s.spec.view_height);
                    by_size.entry(size).or_default().push(s);
                }
                if by_size.len() == 1 {
                    self.fail(&all, error);
                } else {
                    for group in by_size.values() {
                        match self.render(group, time_s) {
                            Ok(out) => self.deliver(group, out),
                            Err(error) => self.fail(group, error),
                        }
                    }
                }
            }
        }
        self.hub.telemetry.frames.fetch_add(1, Relaxed);
    }

    /// The fault injected for any of these sessions' view sizes (tests only).
    fn fault_for(&self, sessions: &[&SessionSnapshot]) -> Option<FaultKind> {
        let f = self.hub.config.fault?;
        sessions
            .iter()
            .any(|s| s.spec.view_width == f.view_width)
            .then_some(f.kind)
    }

    /// Renders the sessions' frames in one call; a wgpu error or a panic comes back as
    /// the error's text (a panic also drops the renderer, rebuilt next time).
    fn render(
        &mut self,
        sessions: &[&SessionSnapshot],
        time_s: f32,
    ) -> Result<TargetsOutput, String> {
        let targets: Vec<FrameTarget> = sessions.iter().map(|s| target_of(s)).collect();
        let fault = self.fault_for(sessions);
        let result = catch_unwind(AssertUnwindSafe(|| {
            match fault {
                Some(FaultKind::RenderPanic) => panic!("injected render panic"),
                Some(FaultKind::RenderError) => anyhow::bail!("injected render error"),
                Some(FaultKind::DeviceLost) => self.ctx.device.destroy(),
                _ => {}
            }
            let renderer = match &mut self.renderer {
                Some(r) => r,
                empty => empty.insert(Renderer::with_bvh(
                    self.ctx.clone(),
                    self.hub.scene.clone(),
                    &self.bvh,
                    self.settings,
                )?),
            };
            // wgpu errors of this frame come back here as an error instead of reaching
            // the default handler (which panics).
            let device = self.ctx.device.clone();
            let oom = device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
            let validation = device.push_error_scope(wgpu::ErrorFilter::Validation);
            let out = renderer.render_targets(&targets, time_s);
            let invalid = pollster::block_on(validation.pop());
            let out_of_memory = pollster::block_on(oom.pop());
            if let Some(e) = invalid.or(out_of_memory) {
                anyhow::bail!("wgpu: {e}");
            }
            out
        }));
        let view_sizes = self.renderer.as_ref().map_or(0, |r| r.view_sizes().len());
        self.hub
            .telemetry
            .view_sizes
            .store(view_sizes as i64, Relaxed);
        match result {
            Ok(Ok(out)) => Ok(out),
            Ok(Err(e)) => {
                self.hub.telemetry.render_errors.fetch_add(1, Relaxed);
                // The failed frame may have moved the world's change tracking on without
                // its work reaching the GPU.
                if let Some(r) = &mut self.renderer {
                    r.invalidate();
                }
                Err(format!("{e:#}"))
            }
            Err(panic) => {
                self.hub.telemetry.render_panics.fetch_add(1, Relaxed);
                self.renderer = None;
                Err(format!("panic: {}", panic_message(&*panic)))
            }
        }
    }

    /// Loud and contained: every one of these sessions is told and closed.
    fn fail(&self, sessions: &[&SessionSnapshot], error: String) {
        let mut sizes: Vec<String> = sessions
            .iter()
            .map(|s| format!("{}×{}", s.spec.view_width, s.spec.view_height))
            .collect();
        sizes.dedup();
        let sizes = sizes.join(", ");
        tracing::error!(sizes = %sizes, sessions = sessions.len(), error = %error, "render failed; closing the sessions of these view sizes");
        self.hub
            .record_failure(format!("rendering {sizes} views failed: {error}"));
        let e = ProtocolError::new(
            ErrorCode::RenderFailed,
            format!("rendering this session's {sizes} views failed on the server: {error}"),
        );
        for s in sessions {
            s.session.fail(e.clone());
        }
    }

    /// Whether a session can take a frame now: its flow window is open (clients that
    /// ack), and for H.264 its writer has taken the previous frame — an encoded access
    /// unit must reach the decoder, so frames for a slow client are skipped here,
    /// before encoding, not replaced after it.
    fn wants_frame(&self, snap: &SessionSnapshot) -> bool {
        let stream = &snap.session.stream;
        stream.ready.load(Relaxed)
            && !(snap.spec.codec == Codec::H264 && snap.session.slot.is_full())
    }

    /// Hands each session its frame for encoding.
    fn deliver(&self, sessions: &[&SessionSnapshot], out: TargetsOutput) {
        self.hub.telemetry.record_render(&out.stats);
        let render_us = (out.stats.frame_ms * 1e3) as u32;
        let frame_no = self.frame as u32;
        for (snap, image) in sessions.iter().zip(out.images) {
            if !self.wants_frame(snap) {
                snap.session
                    .count_drop(&self.hub.telemetry, DropReason::ClientSlow);
                snap.session.stream.skipped.fetch_add(1, Relaxed);
                continue;
            }
            if snap.session.encoding.swap(true, AcqRel) {
                snap.session
                    .count_drop(&self.hub.telemetry, DropReason::EncoderBusy);
                continue;
            }
            let job = EncodeJob {
                session: snap.session.clone(),
                spec: snap.spec,
                image,
                frame: frame_no,
                pose_seq: snap.pose_seq,
                render_us,
            };
            let hub = self.hub.clone();
            let panics = self.hub.config.fault.is_some_and(|f| {
                f.kind == FaultKind::EncodePanic && f.view_width == job.spec.view_width
            });
            self.encoders.spawn(move || {
                let session = job.session.clone();
                let result = catch_unwind(AssertUnwindSafe(|| {
                    if panics {
                        panic!("injected encoder panic");
                    }
                    job.run(&hub)
                }));
                if let Err(panic) = result {
                    // A panic in a rayon job would abort the process; this frame is
                    // dropped instead and the session's next one is encoded as usual.
                    let what = format!("an encoder panicked: {}", panic_message(&*panic));
                    tracing::error!(session = session.id, error = %what, "frame dropped");
                    hub.telemetry.encode_panics.fetch_add(1, Relaxed);
                    hub.record_failure(what);
                    session.encoding.store(false, Release);
                }
            });
        }
    }
}

/// The text of a caught panic's payload.
fn panic_message(panic: &(dyn std::any::Any + Send)) -> String {
    panic
        .downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| panic.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "(no message)".into())
}
