//! The state the render thread and the session tasks share: the session table (view
//! accounting, latest poses) and each session's latest-frame slot.
//!
//! Locks here are held for a copy or an insert, never across I/O or a render.

use super::admission::{Pending, TokenBackoff};
use super::budget::{Budget, Usage};
use super::config::ServerConfig;
use super::stream::StreamState;
use super::telemetry::{DropReason, Telemetry};
use super::validate::{cameras_for, CheckedPose, ProtocolError, SessionSpec};
use crate::protocol::{ErrorCode, Layout};
use crate::scene::{Camera, Scene};
use axum::body::Bytes;
use glam::DVec3;
use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering::Relaxed};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::time::{Duration, Instant};
use tokio::sync::Notify;

/// One encoded frame: header + payload, ready to send.
#[derive(Debug, Clone)]
pub(crate) struct EncodedFrame {
    pub(crate) bytes: Bytes,
    /// Server frame number (what the client acks).
    pub(crate) frame: u32,
    /// The raw copy sent just before it (`raw_every`), if this frame has one.
    pub(crate) raw: Option<Bytes>,
    /// The session spec it was rendered for (the writer sends only frames of the size
    /// the client was last told).
    pub(crate) spec: SessionSpec,
}

impl EncodedFrame {
    /// Bytes held, raw copy included.
    pub(crate) fn len(&self) -> usize {
        self.bytes.len() + self.raw.as_ref().map_or(0, |r| r.len())
    }
}

/// Latest-frame-wins mailbox between the encoders and one session's writer: holds at
/// most one frame; publishing over an unsent frame drops the old one (counted).
pub(crate) struct FrameSlot {
    frame: Mutex<Option<EncodedFrame>>,
    ready: Notify,
    telemetry: Arc<Telemetry>,
}

impl FrameSlot {
    fn new(telemetry: Arc<Telemetry>) -> FrameSlot {
        FrameSlot {
            frame: Mutex::new(None),
            ready: Notify::new(),
            telemetry,
        }
    }

    /// Stores `frame`; returns whether it replaced one the client had not taken.
    pub(crate) fn publish(&self, frame: EncodedFrame) -> bool {
        let add = frame.len() as i64;
        let old = lock(&self.frame).replace(frame);
        let removed = old.as_ref().map_or(0, |f| f.len() as i64);
        self.telemetry.slot_bytes.fetch_add(add - removed, Relaxed);
        self.ready.notify_one();
        old.is_some()
    }

    pub(crate) fn take(&self) -> Option<EncodedFrame> {
        let f = lock(&self.frame).take();
        if let Some(f) = &f {
            self.telemetry.slot_bytes.fetch_sub(f.len() as i64, Relaxed);
        }
        f
    }

    /// Whether a frame is waiting for the writer.
    pub(crate) fn is_full(&self) -> bool {
        lock(&self.frame).is_some()
    }

    /// Resolves when a frame has been published since the last call.
    pub(crate) async fn ready(&self) {
        self.ready.notified().await
    }
}

impl Drop for FrameSlot {
    fn drop(&mut self) {
        self.take();
    }
}

/// Mutable state of a session, read by the render thread once per frame.
#[derive(Debug, Clone)]
pub(crate) struct SessionView {
    pub(crate) spec: SessionSpec,
    /// The poses in force, world space (as the welcome reports them).
    pub(crate) poses: Vec<CheckedPose>,
    /// The render-space cameras of every view, made from `poses` and `spec` once, when
    /// either changes (not once per frame).
    cameras: Vec<Camera>,
    /// Sequence number of the last pose message applied (0 before the first).
    pub(crate) pose_seq: u32,
}

impl SessionView {
    /// Sets the poses (or the spec) in force and makes their cameras.
    fn place(&mut self, spec: SessionSpec, poses: Vec<CheckedPose>, origin: DVec3) {
        self.cameras = cameras_for(&spec, &poses, origin);
        self.spec = spec;
        self.poses = poses;
    }
}

/// One session as the render loop and encoders see it.
pub(crate) struct SessionShared {
    pub(crate) id: u64,
    view: Mutex<SessionView>,
    pub(crate) slot: FrameSlot,
    /// Set while an encoder works on this session's frame (at most one at a time).
    pub(crate) encoding: AtomicBool,
    pub(crate) dropped: AtomicU64,
    pub(crate) sent: AtomicU64,
    /// Codec state, flow control and bitrate shared with the encoder and the writer.
    pub(crate) stream: StreamState,
    /// Set once when the server cannot serve this session any more (a failed render);
    /// the writer then sends it as a fatal error and closes.
    failure: Mutex<Option<ProtocolError>>,
    failed: Notify,
}

impl SessionShared {
    /// Marks the session failed (the first failure wins) and wakes its writer.
    pub(crate) fn fail(&self, e: ProtocolError) {
        let mut f = lock(&self.failure);
        if f.is_none() {
            *f = Some(e);
            self.failed.notify_one();
        }
    }

    pub(crate) fn is_failed(&self) -> bool {
        lock(&self.failure).is_some()
    }

    /// Resolves with the failure once the session is marked failed.
    pub(crate) async fn failure(&self) -> ProtocolError {
        loop {
            if let Some(e) = lock(&self.failure).clone() {
                return e;
            }
            self.failed.notified().await;
        }
    }

    pub(crate) fn view(&self) -> SessionView {
        lock(&self.view).clone()
    }

    /// Applies a validated pose message: its cameras are made here, once, in the render
    /// space that starts at world point `origin`.
    pub(crate) fn set_poses(&self, seq: u32, poses: Vec<CheckedPose>, origin: DVec3) {
        let mut v = lock(&self.view);
        let spec = v.spec;
        v.place(spec, poses, origin);
        v.pose_seq = seq;
        drop(v);
        self.stream.touch_pose();
    }

    pub(crate) fn count_drop(&self, telemetry: &Telemetry, reason: DropReason) {
        self.dropped.fetch_add(1, Relaxed);
        telemetry.dropped(reason);
    }
}

/// What the render thread takes from one session for one frame.
pub(crate) struct SessionSnapshot {
    pub(crate) session: Arc<SessionShared>,
    pub(crate) spec: SessionSpec,
    pub(crate) cameras: Vec<Camera>,
    pub(crate) pose_seq: u32,
}

/// The shared server state.
pub(crate) struct Hub {
    pub(crate) config: ServerConfig,
    budget: Budget,
    /// Connections that have not completed a hello, per address.
    pub(crate) pending: Arc<Pending>,
    /// Failed tokens per address.
    pub(crate) token_backoff: TokenBackoff,
    pub(crate) scene: Arc<Scene>,
    pub(crate) telemetry: Arc<Telemetry>,
    sessions: Mutex<BTreeMap<u64, Arc<SessionShared>>>,
    next_id: AtomicU64,
    /// Wakes the render thread when the first session arrives or on shutdown.
    wake: Condvar,
    pub(crate) shutdown: AtomicBool,
    pub(crate) started: Instant,
    /// Milliseconds since `started` when the render loop last went round (heartbeat).
    render_heartbeat_ms: AtomicU64,
    /// Set when the render thread has exited.
    render_stopped: AtomicBool,
    /// The last render failure or caught panic, and when.
    last_failure: Mutex<Option<(Instant, String)>>,
    /// Set (with wgpu's message) when the GPU device is lost: nothing renders any more.
    device_lost: Mutex<Option<String>>,
}

/// Recent failures keep `/healthz` degraded this long.
const FAILURE_MEMORY: Duration = Duration::from_secs(30);
/// A render loop that has not gone round for this long counts as stopped.
const HEARTBEAT_STALE: Duration = Duration::from_secs(10);

/// What `/healthz` reports.
pub(crate) struct Health {
    /// Whether the render loop is advancing (false: nobody gets frames).
    pub(crate) rendering: bool,
    /// Why the server is degraded; empty when it is healthy.
    pub(crate) reasons: Vec<String>,
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    // A panic while holding one of these locks cannot leave the data half-written
    // (every critical section is a plain copy or insert), so poisoning is ignored.
    m.lock().unwrap_or_else(|e| e.into_inner())
}

fn views_of(sessions: &BTreeMap<u64, Arc<SessionShared>>) -> usize {
    sessions
        .values()
        .map(|s| lock(&s.view).spec.views as usize)
        .sum()
}

impl Hub {
    pub(crate) fn new(config: ServerConfig, scene: Arc<Scene>, budget: Budget) -> Hub {
        Hub {
            pending: Pending::new(config.max_pending_per_ip, config.max_pending),
            token_backoff: TokenBackoff::default(),
            config,
            budget,
            scene,
            telemetry: Arc::new(Telemetry::default()),
            sessions: Mutex::new(BTreeMap::new()),
            next_id: AtomicU64::new(1),
            wake: Condvar::new(),
            shutdown: AtomicBool::new(false),
            started: Instant::now(),
            render_heartbeat_ms: AtomicU64::new(0),
            render_stopped: AtomicBool::new(false),
            last_failure: Mutex::new(None),
            device_lost: Mutex::new(None),
        }
    }

    /// Records the loss of the GPU device (from wgpu's device-lost callback).
    pub(crate) fn lose_device(&self, why: String) {
        tracing::error!(reason = %why, "the GPU device was lost: every session is closed, restart the server");
        self.record_failure(format!("the GPU device was lost: {why}"));
        *lock(&self.device_lost) = Some(why);
    }

    /// Why the GPU device was lost, if it was.
    pub(crate) fn device_lost(&self) -> Option<String> {
        lock(&self.device_lost).clone()
    }

    /// Called by the render loop every time round (frame or idle wait).
    pub(crate) fn heartbeat(&self) {
        self.render_heartbeat_ms
            .store(self.started.elapsed().as_millis() as u64, Relaxed);
    }

    pub(crate) fn render_stopped(&self) {
        self.render_stopped.store(true, Relaxed);
    }

    /// Records a render failure or caught panic for `/healthz`.
    pub(crate) fn record_failure(&self, what: String) {
        *lock(&self.last_failure) = Some((Instant::now(), what));
    }

    pub(crate) fn health(&self) -> Health {
        let mut reasons = Vec::new();
        let now_ms = self.started.elapsed().as_millis() as u64;
        let beat_age_ms = now_ms.saturating_sub(self.render_heartbeat_ms.load(Relaxed));
        let lost = self.device_lost();
        let rendering = if let Some(why) = &lost {
            reasons.push(format!(
                "the GPU device was lost ({why}); restart the server"
            ));
            false
        } else if self.render_stopped.load(Relaxed) {
            reasons.push("the render loop has stopped".to_string());
            false
        } else if beat_age_ms > HEARTBEAT_STALE.as_millis() as u64 {
            reasons.push(format!(
                "the render loop has not advanced for {:.1} s",
                beat_age_ms as f64 / 1e3
            ));
            false
        } else {
            true
        };
        if let Some((at, what)) = lock(&self.last_failure).as_ref() {
            let age = at.elapsed();
            if age < FAILURE_MEMORY {
                reasons.push(format!("{what} ({:.1} s ago)", age.as_secs_f64()));
            }
        }
        Health { rendering, reasons }
    }

    /// The scene's default viewpoints for a new session of `spec`.
    pub(crate) fn default_poses(&self, spec: &SessionSpec) -> Vec<CheckedPose> {
        let n = spec.pose_count();
        let t = self.started.elapsed().as_secs_f32();
        self.scene
            .camera
            .viewers(n, t)
            .iter()
            .map(|c| CheckedPose::from_camera(c, self.scene.origin))
            .collect()
    }

    /// Adds a session if its views fit under `max_views`; the guard removes it on drop.
    pub(crate) fn register(
        self: &Arc<Hub>,
        spec: SessionSpec,
    ) -> Result<SessionGuard, ProtocolError> {
        let poses = self.default_poses(&spec);
        if let Some(why) = self.device_lost() {
            return Err(ProtocolError::new(
                ErrorCode::RenderFailed,
                format!(
                    "the server's GPU device was lost ({why}); it cannot render until restarted"
                ),
            ));
        }
        let mut sessions = lock(&self.sessions);
        let used = views_of(&sessions);
        if used + spec.views as usize > self.config.max_views {
            return Err(full_error(spec.views, used, self.config.max_views));
        }
        self.admit(sessions.values().map(|s| s.view().spec), &spec)?;
        let id = self.next_id.fetch_add(1, Relaxed);
        let shared = Arc::new(SessionShared {
            id,
            view: Mutex::new(SessionView {
                cameras: cameras_for(&spec, &poses, self.scene.origin),
                spec,
                poses,
                pose_seq: 0,
            }),
            slot: FrameSlot::new(self.telemetry.clone()),
            encoding: AtomicBool::new(false),
            dropped: AtomicU64::new(0),
            sent: AtomicU64::new(0),
            stream: StreamState::new(self.config.start_kbps.min(spec.max_kbps), spec.quality),
            failure: Mutex::new(None),
            failed: Notify::new(),
        });
        sessions.insert(id, shared.clone());
        drop(sessions);
        self.telemetry.sessions_total.fetch_add(1, Relaxed);
        self.wake.notify_all();
        Ok(SessionGuard {
            hub: self.clone(),
            session: shared,
        })
    }

    /// Changes a session's spec if the new view count fits; poses are kept when the
    /// layout's pose count is unchanged, else reset to the scene's defaults.
    pub(crate) fn reconfigure(
        &self,
        session: &SessionShared,
        spec: SessionSpec,
    ) -> Result<SessionView, ProtocolError> {
        let defaults = self.default_poses(&spec);
        let sessions = lock(&self.sessions);
        let mut view = lock(&session.view);
        let others = sessions
            .values()
            .filter(|s| s.id != session.id)
            .map(|s| lock(&s.view).spec.views as usize)
            .sum::<usize>();
        if others + spec.views as usize > self.config.max_views {
            return Err(full_error(spec.views, others, self.config.max_views));
        }
        self.admit(
            sessions
                .values()
                .filter(|s| s.id != session.id)
                .map(|s| lock(&s.view).spec),
            &spec,
        )?;
        let poses = if view.spec.pose_count() == spec.pose_count() {
            std::mem::take(&mut view.poses)
        } else {
            defaults
        };
        view.place(spec, poses, self.scene.origin);
        Ok(view.clone())
    }

    /// Checks `spec` against the cost budget next to the `others` already admitted.
    fn admit(
        &self,
        others: impl Iterator<Item = SessionSpec>,
        spec: &SessionSpec,
    ) -> Result<(), ProtocolError> {
        let mut used = Usage::default();
        for s in others {
            used.add(&s);
        }
        self.budget.admit(&used, spec, &self.config.spec_limits())
    }

    /// Sessions and views now.
    pub(crate) fn counts(&self) -> (usize, usize) {
        let sessions = lock(&self.sessions);
        (sessions.len(), views_of(&sessions))
    }

    /// Every session's spec, cameras and pose sequence number, in session order.
    pub(crate) fn snapshot(&self) -> Vec<SessionSnapshot> {
        let sessions: Vec<Arc<SessionShared>> = lock(&self.sessions).values().cloned().collect();
        sessions
            .into_iter()
            .map(|session| {
                let v = session.view();
                SessionSnapshot {
                    cameras: v.cameras,
                    spec: v.spec,
                    pose_seq: v.pose_seq,
                    session,
                }
            })
            .collect()
    }

    /// Blocks the render thread until a session exists, shutdown, or `timeout`.
    pub(crate) fn wait_for_sessions(&self, timeout: Duration) {
        let sessions = lock(&self.sessions);
        if sessions.is_empty() && !self.shutdown.load(Relaxed) {
            let _ = self.wake.wait_timeout(sessions, timeout);
        }
    }

    pub(crate) fn begin_shutdown(&self) {
        self.shutdown.store(true, Relaxed);
        let _guard = lock(&self.sessions);
        self.wake.notify_all();
    }
}

fn full_error(asked: u32, used: usize, max: usize) -> ProtocolError {
    ProtocolError::new(
        ErrorCode::ServerFull,
        format!("the server renders at most {max} views and {used} are in use; this session needs {asked}. Try again later or ask for fewer views"),
    )
}

/// Keeps a session registered; dropping it (session end, any way) unregisters it.
pub(crate) struct SessionGuard {
    hub: Arc<Hub>,
    pub(crate) session: Arc<SessionShared>,
}

impl Drop for SessionGuard {
    fn drop(&mut self) {
        lock(&self.hub.sessions).remove(&self.session.id);
        self.hub.telemetry.sessions_closed.fetch_add(1, Relaxed);
        // Free the frame waiting for this client now rather than when the last
        // encoder job lets go of the session.
        self.session.slot.take();
    }
}

/// Counts an open connection; dropping it releases the slot.
pub(crate) struct ConnectionGuard {
    telemetry: Arc<Telemetry>,
}

impl ConnectionGuard {
    /// A guard if fewer than `max` connections are open.
    pub(crate) fn try_new(telemetry: &Arc<Telemetry>, max: usize) -> Option<ConnectionGuard> {
        let prev = telemetry.connections.fetch_add(1, Relaxed);
        if prev >= max as i64 {
            telemetry.connections.fetch_sub(1, Relaxed);
            telemetry.connections_refused.fetch_add(1, Relaxed);
            return None;
        }
        Some(ConnectionGuard {
            telemetry: telemetry.clone(),
        })
    }
}

impl Drop for ConnectionGuard {
    fn drop(&mut self) {
        self.telemetry.connections.fetch_sub(1, Relaxed);
    }
}

/// Layout name for logs.
pub(crate) fn layout_name(l: Layout) -> &'static str {
    match l {
        Layout::Mono => "mono",
        Layout::Stereo => "stereo",
        Layout::Split => "split",
    }
}
