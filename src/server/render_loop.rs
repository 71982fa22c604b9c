//! The render thread: the only owner of the wgpu device's work. Each frame it snapshots
//! every session's latest poses, renders all views, and hands each session's images to
//! the encoder pool. It never waits on a client: a session whose previous frame is still
//! being encoded skips this one, and a frame nobody took is replaced (both counted).
//!
//! The renderer batches views of one size per call, while sessions may ask for
//! different resolutions; so views are grouped by view size and each group is one
//! `render` call (one submission with every view of that size) per frame. Each size has
//! its own [`Renderer`] — its per-viewer volumes fit that size, so groups do not
//! reallocate each other's volumes every frame — and the world-space grid is updated
//! once per group. Clients that pick the same resolution therefore share everything.
//! A new size's renderer is built on a builder thread; its views wait until it is ready
//! while every other group renders on. A failed or panicking render call closes the
//! sessions of that size only (`render_failed`); a panic elsewhere drops the frame.

use super::config::FaultKind;
use super::encode::EncodeJob;
use super::hub::{Hub, SessionSnapshot};
use super::telemetry::DropReason;
use super::validate::ProtocolError;
use crate::gpu::GpuContext;
use crate::protocol::ErrorCode;
use crate::render::{Renderer, Settings};
use crate::scene::Bvh;
use std::collections::{BTreeMap, HashMap, HashSet};
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::atomic::Ordering::{AcqRel, Relaxed, Release};
use std::sync::{mpsc, Arc};
use std::time::{Duration, Instant};

/// Renderers kept for view sizes no session uses right now (a client that reconnects or
/// switches back avoids rebuilding pipelines).
const IDLE_RENDERERS_KEPT: usize = 2;

struct CachedRenderer {
    renderer: Renderer,
    last_frame: u64,
}

pub(crate) struct RenderLoop {
    hub: Arc<Hub>,
    ctx: Arc<GpuContext>,
    encoders: rayon::ThreadPool,
    renderers: HashMap<(u32, u32), CachedRenderer>,
    /// Sizes whose renderer the builder thread is making.
    building: HashSet<(u32, u32)>,
    /// Sizes whose renderer could not be built, with the error (reported once).
    build_failed: HashMap<(u32, u32), String>,
    build_tx: mpsc::Sender<(u32, u32)>,
    built_rx: mpsc::Receiver<Built>,
    frame: u64,
}

/// A renderer from the builder thread, for one view size.
type Built = ((u32, u32), Result<Renderer, String>);

/// Builds renderers for new view sizes (pipelines and the shared grid: 140–190 ms on a
/// GPU, more on lavapipe) off the render thread, so a client asking for a new size
/// does not stall the frame for everyone; its views are rendered once it is ready.
fn run_builder(
    ctx: Arc<GpuContext>,
    hub: Arc<Hub>,
    bvh: Bvh,
    settings: Settings,
    requests: mpsc::Receiver<(u32, u32)>,
    built: mpsc::Sender<Built>,
) {
    for (width, height) in requests {
        let started = Instant::now();
        let slow = hub
            .config
            .fault
            .is_some_and(|f| f.kind == FaultKind::SlowBuild && f.view_width == width);
        if slow {
            std::thread::sleep(Duration::from_secs(3));
        }
        let result = catch_unwind(AssertUnwindSafe(|| {
            Renderer::with_bvh(ctx.clone(), hub.scene.clone(), &bvh, settings)
        }));
        let result = match result {
            Ok(Ok(r)) => {
                tracing::info!(
                    width,
                    height,
                    ms = started.elapsed().as_millis() as u64,
                    "renderer created for a new view size"
                );
                Ok(r)
            }
            Ok(Err(e)) => Err(format!("creating a renderer: {e:#}")),
            Err(panic) => {
                hub.telemetry.render_panics.fetch_add(1, Relaxed);
                Err(format!(
                    "creating a renderer panicked: {}",
                    panic_message(&*panic)
                ))
            }
        };
        if built.send(((width, height), result)).is_err() {
            return;
        }
    }
}

impl RenderLoop {
    pub(crate) fn new(
        hub: Arc<Hub>,
        ctx: Arc<GpuContext>,
        bvh: Bvh,
        settings: Settings,
    ) -> anyhow::Result<RenderLoop> {
        let threads = match hub.config.encode_threads {
            0 => std::thread::available_parallelism().map_or(2, |n| n.get()),
            n => n,
        };
        let encoders = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .thread_name(|i| format!("fogcast-encode-{i}"))
            .build()?;
        let (build_tx, requests) = mpsc::channel();
        let (built, built_rx) = mpsc::channel();
        let builder_hub = hub.clone();
        std::thread::Builder::new()
            .name("fogcast-build".into())
            .spawn({
                let ctx = ctx.clone();
                move || run_builder(ctx, builder_hub, bvh, settings, requests, built)
            })?;
        Ok(RenderLoop {
            hub,
            ctx,
            encoders,
            renderers: HashMap::new(),
            building: HashSet::new(),
            build_failed: HashMap::new(),
            build_tx,
            built_rx,
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
                self.evict_idle();
                self.hub.wait_for_sessions(Duration::from_millis(250));
                next = Instant::now();
                continue;
            }
            let started = Instant::now();
            // A panic anywhere in the frame (outside a render call, which is caught on
            // its own) drops this frame; the renderers may be mid-update, so they go too.
            if let Err(panic) = catch_unwind(AssertUnwindSafe(|| self.render_frame(sessions))) {
                let what = format!("the render loop panicked: {}", panic_message(&*panic));
                tracing::error!(error = %what, "frame dropped");
                self.hub.telemetry.render_panics.fetch_add(1, Relaxed);
                self.hub.record_failure(what);
                self.renderers.clear();
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
        self.collect_built();
        let frame_no = self.frame as u32;
        let time_s = (self.hub.started.elapsed().as_secs_f64() % 86_400.0) as f32;
        // Views grouped by size: (session index, view index) per camera.
        let mut groups: BTreeMap<(u32, u32), Vec<(usize, usize)>> = BTreeMap::new();
        for (si, s) in sessions.iter().enumerate() {
            for vi in 0..s.cameras.len() {
                groups
                    .entry((s.spec.view_width, s.spec.view_height))
                    .or_default()
                    .push((si, vi));
            }
        }
        let mut images: Vec<Vec<Option<Vec<u8>>>> = sessions
            .iter()
            .map(|s| vec![None; s.cameras.len()])
            .collect();
        let mut render_us = vec![0u32; sessions.len()];
        for ((w, h), members) in &groups {
            let cameras: Vec<_> = members
                .iter()
                .map(|&(si, vi)| sessions[si].cameras[vi])
                .collect();
            let fault = self
                .hub
                .config
                .fault
                .filter(|f| f.view_width == *w)
                .map(|f| f.kind);
            if fault == Some(FaultKind::Skip) {
                continue;
            }
            let result = catch_unwind(AssertUnwindSafe(|| {
                if fault == Some(FaultKind::RenderPanic) {
                    panic!("injected render panic for {w}×{h} views");
                }
                if fault == Some(FaultKind::RenderError) {
                    anyhow::bail!("injected render error for {w}×{h} views");
                }
                if fault == Some(FaultKind::DeviceLost) {
                    self.ctx.device.destroy();
                }
                let device = self.ctx.device.clone();
                let Some(renderer) = self.renderer_for(*w, *h)? else {
                    return Ok(None);
                };
                // wgpu errors of this render call come back here as an error instead of
                // reaching the default handler (which panics).
                let oom = device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
                let validation = device.push_error_scope(wgpu::ErrorFilter::Validation);
                let out = renderer.render(&cameras, *w, *h, time_s);
                let invalid = pollster::block_on(validation.pop());
                let out_of_memory = pollster::block_on(oom.pop());
                if let Some(e) = invalid.or(out_of_memory) {
                    anyhow::bail!("wgpu: {e}");
                }
                out.map(Some)
            }));
            let error = match result {
                // Its renderer is being built: these views wait a frame or a few.
                Ok(Ok(None)) => continue,
                Ok(Ok(Some(out))) => {
                    self.hub.telemetry.record_render(&out.stats);
                    let us = (out.stats.frame_ms * 1e3) as u32;
                    for (&(si, vi), img) in members.iter().zip(out.images) {
                        images[si][vi] = Some(img);
                        render_us[si] = render_us[si].max(us);
                    }
                    continue;
                }
                Ok(Err(e)) => {
                    self.hub.telemetry.render_errors.fetch_add(1, Relaxed);
                    format!("{e:#}")
                }
                Err(panic) => {
                    self.hub.telemetry.render_panics.fetch_add(1, Relaxed);
                    // The renderer may be half-updated: build a fresh one next time.
                    self.renderers.remove(&(*w, *h));
                    format!("panic: {}", panic_message(&*panic))
                }
            };
            // Loud and contained: every session with a view of this size is told and
            // closed; the other size groups of this frame go on.
            tracing::error!(width = w, height = h, views = cameras.len(), error = %error, "render failed; closing the sessions of this view size");
            self.hub
                .record_failure(format!("rendering {w}×{h} views failed: {error}"));
            let e = ProtocolError::new(
                ErrorCode::RenderFailed,
                format!("rendering this session's {w}×{h} views failed on the server: {error}"),
            );
            for &(si, _) in members {
                sessions[si].session.fail(e.clone());
            }
        }
        self.hub.telemetry.frames.fetch_add(1, Relaxed);
        for ((snap, imgs), render_us) in sessions.into_iter().zip(images).zip(render_us) {
            let Some(images) = imgs.into_iter().collect::<Option<Vec<_>>>() else {
                continue;
            };
            if snap.session.encoding.swap(true, AcqRel) {
                snap.session
                    .count_drop(&self.hub.telemetry, DropReason::EncoderBusy);
                continue;
            }
            let job = EncodeJob {
                session: snap.session,
                spec: snap.spec,
                images,
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
                    let what = format!("a JPEG encoder panicked: {}", panic_message(&*panic));
                    tracing::error!(session = session.id, error = %what, "frame dropped");
                    hub.telemetry.encode_panics.fetch_add(1, Relaxed);
                    hub.record_failure(what);
                    session.encoding.store(false, Release);
                }
            });
        }
        self.evict_idle();
    }

    /// Takes the renderers the builder finished.
    fn collect_built(&mut self) {
        while let Ok((size, result)) = self.built_rx.try_recv() {
            self.building.remove(&size);
            match result {
                Ok(renderer) => {
                    self.renderers.insert(
                        size,
                        CachedRenderer {
                            renderer,
                            last_frame: self.frame,
                        },
                    );
                }
                Err(e) => {
                    self.build_failed.insert(size, e);
                }
            }
        }
        self.hub
            .telemetry
            .renderers
            .store(self.renderers.len() as i64, Relaxed);
    }

    /// The renderer for views of this size; `None` while the builder makes it (asked
    /// for here the first time), an error when it could not be built.
    fn renderer_for(&mut self, width: u32, height: u32) -> anyhow::Result<Option<&mut Renderer>> {
        let size = (width, height);
        if let Some(e) = self.build_failed.remove(&size) {
            anyhow::bail!(e);
        }
        let frame = self.frame;
        if let Some(cached) = self.renderers.get_mut(&size) {
            cached.last_frame = frame;
            return Ok(Some(&mut cached.renderer));
        }
        if self.building.insert(size) {
            self.build_tx
                .send(size)
                .map_err(|_| anyhow::anyhow!("the renderer builder thread has stopped"))?;
        }
        Ok(None)
    }

    /// Drops the least recently used renderers beyond those in use plus a few idle ones.
    fn evict_idle(&mut self) {
        let mut idle: Vec<((u32, u32), u64)> = self
            .renderers
            .iter()
            .filter(|(_, c)| c.last_frame < self.frame)
            .map(|(k, c)| (*k, c.last_frame))
            .collect();
        if idle.len() <= IDLE_RENDERERS_KEPT {
            return;
        }
        idle.sort_by_key(|(_, last)| *last);
        for (key, _) in &idle[..idle.len() - IDLE_RENDERERS_KEPT] {
            self.renderers.remove(key);
        }
        self.hub
            .telemetry
            .renderers
            .store(self.renderers.len() as i64, Relaxed);
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
