//! One WebSocket connection: handshake (hello → welcome), then a reader that validates
//! every client message and a writer that sends the latest frame, in one task so that
//! any end — close, error, stall, shutdown, a dropped TCP connection mid-handshake or
//! mid-frame — drops the session guard and frees everything the session held.

use super::hub::{layout_name, ConnectionGuard, Hub, SessionShared};
use super::listen::Slot;
use super::stream::{Flow, FlowConfig, Resize, MIN_ADAPTED_VIEW_PX, TICK};
use super::telemetry::DropReason;
use super::validate::{check_pose, parse_client_message, CheckedPose, ProtocolError, SessionSpec};
use crate::protocol::{
    clip, ClientMessage, Codec, ErrorCode, ErrorMessage, Hello, Layout, Limits, ServerMessage,
    Welcome, WelcomeReason, FOV_RANGE_DEG, FRAME_HEADER_BYTES, MAX_COORD_M, MIN_VIEW_PX,
    PROTOCOL_VERSION,
};
use axum::extract::ws::{CloseFrame, Message, Utf8Bytes, WebSocket};
use futures_util::stream::{SplitSink, SplitStream};
use futures_util::{SinkExt as _, StreamExt as _};
use std::net::{IpAddr, SocketAddr};
use std::sync::atomic::Ordering::Relaxed;
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio::sync::{mpsc, watch};

/// How long a closing session waits for the client's close reply.
const CLOSE_GRACE: Duration = Duration::from_secs(2);
/// Non-fatal errors a session may cause per [`ERROR_WINDOW`] before it is closed.
const MAX_ERRORS_PER_WINDOW: u32 = 20;
const ERROR_WINDOW: Duration = Duration::from_secs(10);
/// Control messages (welcomes, errors) waiting for the writer. They are never dropped:
/// a client that leaves this many replies unread is closed for flooding instead.
const CONTROL_QUEUE: usize = 32;
/// A sleep that never ends in practice (a disabled timer's placeholder).
const FAR_FUTURE: Duration = Duration::from_secs(365 * 86_400);
/// Configures a session may send in a burst (then `max_configures_per_s`).
const CONFIGURE_BURST: f64 = 4.0;

type Sink = SplitSink<WebSocket, Message>;
type Stream = SplitStream<WebSocket>;

/// A message for the writer.
enum Control {
    Text(String),
    /// A welcome for `spec`: from now on only frames of its size are sent.
    Welcome(String, SessionSpec),
    /// Send this fatal error and a close frame, then stop.
    Close(ProtocolError),
}

/// Token bucket over every client message (text, binary, ping): `rate` per second
/// sustained, bursts of one second's worth; the balance may go one second into debt
/// (messages dropped with a warning) before the session counts as a flood.
struct RateLimiter {
    rate: f64,
    tokens: f64,
    last: Instant,
    last_warning: Option<Instant>,
}

enum Rate {
    Ok,
    /// Drop the message; `warn` when the client should be told (at most once a second).
    Drop {
        warn: bool,
    },
    Flood,
}

impl RateLimiter {
    fn new(rate: f64) -> RateLimiter {
        RateLimiter {
            rate,
            tokens: rate,
            last: Instant::now(),
            last_warning: None,
        }
    }

    fn check(&mut self) -> Rate {
        let now = Instant::now();
        self.tokens =
            (self.tokens + now.duration_since(self.last).as_secs_f64() * self.rate).min(self.rate);
        self.last = now;
        self.tokens -= 1.0;
        if self.tokens >= 0.0 {
            Rate::Ok
        } else if self.tokens >= -self.rate {
            let warn = self
                .last_warning
                .is_none_or(|t| now.duration_since(t) >= Duration::from_secs(1));
            if warn {
                self.last_warning = Some(now);
            }
            Rate::Drop { warn }
        } else {
            Rate::Flood
        }
    }
}

/// Token bucket for `configure` (each may build a renderer on the render thread).
struct ConfigureLimiter {
    rate: f64,
    tokens: f64,
    last: Instant,
}

impl ConfigureLimiter {
    fn new(rate: f64) -> ConfigureLimiter {
        ConfigureLimiter {
            rate,
            tokens: CONFIGURE_BURST,
            last: Instant::now(),
        }
    }

    fn take(&mut self) -> bool {
        let now = Instant::now();
        self.tokens = (self.tokens + now.duration_since(self.last).as_secs_f64() * self.rate)
            .min(CONFIGURE_BURST);
        self.last = now;
        if self.tokens >= 1.0 {
            self.tokens -= 1.0;
            true
        } else {
            false
        }
    }
}

fn error_json(e: &ProtocolError, fatal: bool) -> String {
    ServerMessage::Error(ErrorMessage {
        code: e.code,
        message: e.message.clone(),
        fatal,
    })
    .to_json()
}

/// An error for the log: its message may quote client text (a type name, a version),
/// so newlines, ANSI escapes and other control characters are escaped, never written raw.
fn for_log(e: &ProtocolError) -> String {
    e.to_string().escape_debug().to_string()
}

/// Close reasons are limited to 123 bytes by RFC 6455.
fn close_reason(e: &ProtocolError) -> Utf8Bytes {
    let mut reason = format!("{}: {}", e.code.as_str(), e.message);
    if reason.len() > 123 {
        let mut cut = 120;
        while !reason.is_char_boundary(cut) {
            cut -= 1;
        }
        reason.truncate(cut);
        reason.push('…');
    }
    Utf8Bytes::from(reason)
}

/// Sends a fatal error and a close frame, then waits briefly for the client's close
/// reply so the close frame is not lost to a TCP reset.
async fn close_with(sink: &mut Sink, stream: &mut Stream, hub: &Hub, e: ProtocolError) {
    if send_close(sink, hub, e).await {
        let _ = tokio::time::timeout(CLOSE_GRACE, async {
            while let Some(Ok(_)) = stream.next().await {}
        })
        .await;
    }
}

/// Sends a fatal error and a close frame (bounded by [`CLOSE_GRACE`]); whether both
/// went out in time.
async fn send_close(sink: &mut Sink, hub: &Hub, e: ProtocolError) -> bool {
    hub.telemetry.client_error(e.code, true);
    let frame = CloseFrame {
        code: e.code.close_code(),
        reason: close_reason(&e),
    };
    let send = async {
        sink.send(Message::Text(error_json(&e, true).into()))
            .await?;
        sink.send(Message::Close(Some(frame))).await
    };
    matches!(tokio::time::timeout(CLOSE_GRACE, send).await, Ok(Ok(())))
}

/// Runs a session to its end. `shutdown` turns true when the server stops.
pub(crate) async fn run(
    socket: WebSocket,
    hub: Arc<Hub>,
    peer: SocketAddr,
    shutdown: watch::Receiver<bool>,
    pending: Option<Slot>,
) {
    let (mut sink, mut stream) = socket.split();
    let mut limiter = RateLimiter::new(hub.config.max_messages_per_s);
    let hello_timeout = Duration::from_secs_f64(hub.config.hello_timeout_s);
    let spec = match tokio::time::timeout(
        hello_timeout,
        handshake(&mut stream, &hub, peer, &mut limiter),
    )
    .await
    {
        Ok(Ok(spec)) => spec,
        Ok(Err(Some(e))) => {
            tracing::info!(%peer, error = %for_log(&e), "handshake refused");
            return close_with(&mut sink, &mut stream, &hub, e).await;
        }
        Ok(Err(None)) => return,
        Err(_) => {
            let e = ProtocolError::new(
                ErrorCode::HelloTimeout,
                format!(
                    "no hello within {} s of connecting",
                    hub.config.hello_timeout_s
                ),
            );
            return close_with(&mut sink, &mut stream, &hub, e).await;
        }
    };
    // Past the hello: the connection no longer counts as pending against its address,
    // and now counts against the server's sessions.
    drop(pending);
    let Some(_conn) = ConnectionGuard::try_new(&hub.telemetry, hub.config.max_connections) else {
        let e = ProtocolError::new(
            ErrorCode::ServerFull,
            format!(
                "the server serves at most {} sessions; try again later",
                hub.config.max_connections
            ),
        );
        return close_with(&mut sink, &mut stream, &hub, e).await;
    };
    let guard = match hub.register(spec) {
        Ok(g) => g,
        Err(e) => {
            tracing::info!(%peer, error = %for_log(&e), "session refused");
            return close_with(&mut sink, &mut stream, &hub, e).await;
        }
    };
    let id = guard.session.id;
    tracing::info!(%peer, session = id, layout = layout_name(spec.layout), width = spec.width, height = spec.height, views = spec.views, "session opened");
    let welcome = welcome(&hub, &guard.session, WelcomeReason::Hello);
    if sink.send(Message::Text(welcome.into())).await.is_err() {
        return;
    }
    let (ctl_tx, ctl_rx) = mpsc::channel(CONTROL_QUEUE);
    let session = guard.session.clone();
    let mut writer = std::pin::pin!(write_loop(sink, &hub, &session, spec, ctl_rx, shutdown));
    let mut reader = std::pin::pin!(read_loop(stream, &hub, &session, ctl_tx, limiter));
    let end = tokio::select! {
        end = &mut writer => end,
        () = &mut reader => "client gone",
    };
    // The session's views stop being rendered now, not after the close handshake.
    drop(guard);
    if !matches!(end, "client gone" | "send failed" | "stalled") {
        // After a close frame went out, let the reader take the client's reply.
        let _ = tokio::time::timeout(CLOSE_GRACE, &mut reader).await;
    }
    tracing::info!(
        session = id,
        sent = session.sent.load(Relaxed),
        dropped = session.dropped.load(Relaxed),
        end,
        "session closed"
    );
}

/// Reads until a valid hello; `Err(None)` when the client left, `Err(Some(e))` to refuse.
async fn handshake(
    stream: &mut Stream,
    hub: &Hub,
    peer: SocketAddr,
    limiter: &mut RateLimiter,
) -> Result<SessionSpec, Option<ProtocolError>> {
    loop {
        let msg = match stream.next().await {
            Some(Ok(m)) => m,
            None | Some(Err(_)) => return Err(None),
        };
        if let Rate::Flood | Rate::Drop { .. } = limiter.check() {
            return Err(Some(ProtocolError::new(
                ErrorCode::RateLimited,
                "too many messages before the hello",
            )));
        }
        let text = match msg {
            Message::Text(t) => t,
            Message::Binary(b) => return Err(Some(binary_error(b.len()))),
            Message::Ping(_) | Message::Pong(_) => continue,
            Message::Close(_) => return Err(None),
        };
        if text.len() > hub.config.max_message_bytes {
            return Err(Some(too_large(text.len(), hub.config.max_message_bytes)));
        }
        let hello = match parse_client_message(&text) {
            Ok(ClientMessage::Hello(h)) => h,
            Ok(_) => {
                return Err(Some(ProtocolError::new(
                    ErrorCode::HelloRequired,
                    "the first message must be {\"type\":\"hello\", ...}",
                )))
            }
            Err(e) => return Err(Some(e)),
        };
        return check_hello(&hello, hub, peer.ip()).map_err(Some);
    }
}

fn check_hello(h: &Hello, hub: &Hub, ip: IpAddr) -> Result<SessionSpec, ProtocolError> {
    if h.version != PROTOCOL_VERSION {
        return Err(ProtocolError::new(
            ErrorCode::UnsupportedVersion,
            format!(
                "protocol version {}: this server speaks version {PROTOCOL_VERSION}",
                h.version
            ),
        ));
    }
    if let Some(want) = &hub.config.token {
        if let Err(wait) = hub.token_backoff.check(ip) {
            return Err(ProtocolError::new(
                ErrorCode::Unauthorized,
                format!(
                    "too many wrong tokens from this address: retry in {:.1} s",
                    wait.as_secs_f64()
                ),
            ));
        }
        match &h.token {
            None => {
                return Err(ProtocolError::new(
                    ErrorCode::Unauthorized,
                    "this server needs a token: add \"token\" to the hello",
                ))
            }
            Some(t) if !constant_time_eq(t.as_bytes(), want.as_bytes()) => {
                let wait = hub.token_backoff.failed(ip);
                tracing::info!(%ip, backoff_s = wait.as_secs_f64(), "wrong token");
                return Err(ProtocolError::new(ErrorCode::Unauthorized, "wrong token"));
            }
            Some(_) => hub.token_backoff.succeeded(ip),
        }
    }
    SessionSpec::from_hello(h, &hub.config.spec_limits())
}

/// Compares without an early exit, so response time does not leak the token's prefix.
pub(crate) fn constant_time_eq(a: &[u8], b: &[u8]) -> bool {
    a.len() == b.len() && a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}

fn binary_error(len: usize) -> ProtocolError {
    ProtocolError::new(
        ErrorCode::BinaryNotSupported,
        format!("got a {len}-byte binary message; clients send only JSON text messages"),
    )
}

fn too_large(len: usize, max: usize) -> ProtocolError {
    ProtocolError::new(
        ErrorCode::MessageTooLarge,
        format!("a {len}-byte message; the limit is {max} bytes"),
    )
}

fn welcome(hub: &Hub, session: &SessionShared, reason: WelcomeReason) -> String {
    let v = session.view();
    let c = &hub.config;
    ServerMessage::Welcome(Welcome {
        session: session.id,
        version: PROTOCOL_VERSION,
        scene: hub.scene.name.clone(),
        layout: v.spec.layout,
        views: v.spec.views,
        width: v.spec.width,
        height: v.spec.height,
        view_width: v.spec.view_width,
        view_height: v.spec.view_height,
        quality: v.spec.quality,
        eye_distance_m: v.spec.eye_distance_m,
        codec: v.spec.codec,
        max_kbps: v.spec.max_kbps,
        reason,
        fps: c.fps,
        header_bytes: FRAME_HEADER_BYTES,
        poses: v
            .poses
            .iter()
            .copied()
            .map(CheckedPose::to_view_pose)
            .collect(),
        limits: Limits {
            max_message_bytes: c.max_message_bytes,
            max_messages_per_s: c.max_messages_per_s,
            max_width: c.max_width,
            max_height: c.max_height,
            min_view_px: MIN_VIEW_PX,
            max_views: c.max_views,
            max_coord_m: MAX_COORD_M,
            fov_y_deg: [FOV_RANGE_DEG.0, FOV_RANGE_DEG.1],
            idle_timeout_s: c.idle_timeout_s,
        },
    })
    .to_json()
}

/// Sends control messages and the latest frame; returns why it stopped.
async fn write_loop(
    mut sink: Sink,
    hub: &Hub,
    session: &SessionShared,
    mut announced: SessionSpec,
    mut ctl: mpsc::Receiver<Control>,
    mut shutdown: watch::Receiver<bool>,
) -> &'static str {
    let stall = Duration::from_secs_f64(hub.config.stall_timeout_s);
    let frame_timeout = Duration::from_secs_f64(hub.config.frame_timeout_s);
    let idle_timeout = Duration::from_secs_f64(hub.config.idle_timeout_s);
    let mut last_frame = tokio::time::Instant::now();
    // What the client asked for (hello or configure); `announced` may be smaller while
    // its link does not carry this.
    let mut requested = announced;
    let mut flow = Flow::new(
        FlowConfig {
            min_kbps: hub.config.min_kbps,
            max_queue: Duration::from_secs_f64(hub.config.max_queue_ms / 1e3),
        },
        session.stream.target_kbps.load(Relaxed),
        announced.max_kbps,
        announced.quality,
        announced.codec == Codec::Jpeg,
    );
    let _target = TargetGauge::new(hub, flow.target_kbps());
    loop {
        let now = Instant::now();
        if flow.tick_due(now) {
            flow.skipped(session.stream.skipped.swap(0, Relaxed));
            let shrinkable = scaled(&requested, flow.shrink_level + 1, hub).is_some();
            let resize = flow.tick(now, shrinkable);
            _target.set(hub, flow.target_kbps());
            session
                .stream
                .target_kbps
                .store(flow.target_kbps(), Relaxed);
            session.stream.jpeg_quality.store(flow.quality(), Relaxed);
            if let Some(r) = resize {
                if let Some(spec) = adapt_size(hub, session, &requested, &mut flow, r) {
                    announced = spec;
                    let text = welcome(hub, session, WelcomeReason::Bandwidth);
                    if let Err(end) =
                        send_timed(&mut sink, hub, Message::Text(text.into()), stall).await
                    {
                        return end;
                    }
                }
            }
        }
        let can_send = flow.can_send(now);
        session.stream.ready.store(can_send, Relaxed);
        let idle_left = (!idle_timeout.is_zero())
            .then(|| idle_timeout.saturating_sub(session.stream.since_last_pose()));
        let msg = tokio::select! {
            biased;
            c = ctl.recv() => match c {
                Some(Control::Text(t)) => Message::Text(t.into()),
                Some(Control::Welcome(t, spec)) => {
                    announced = spec;
                    requested = spec;
                    flow.shrink_level = 0;
                    flow.set_limits(spec.max_kbps, spec.quality, spec.codec == Codec::Jpeg);
                    Message::Text(t.into())
                }
                Some(Control::Close(e)) => {
                    let code = e.code.as_str();
                    send_close(&mut sink, hub, e).await;
                    return code;
                }
                None => return "reader ended",
            },
            _ = async { shutdown.wait_for(|stop| *stop).await.is_ok() } => {
                let e = ProtocolError::new(ErrorCode::ShuttingDown, "the server is shutting down");
                let frame = CloseFrame { code: e.code.close_code(), reason: close_reason(&e) };
                let _ = tokio::time::timeout(CLOSE_GRACE, sink.send(Message::Close(Some(frame)))).await;
                return "shutdown";
            }
            e = session.failure() => {
                let code = e.code.as_str();
                send_close(&mut sink, hub, e).await;
                return code;
            }
            () = tokio::time::sleep_until(last_frame + frame_timeout) => {
                // Never leave a session hanging without frames: whatever kept them from
                // it, the client learns it and can reconnect.
                hub.telemetry.sessions_starved.fetch_add(1, Relaxed);
                let e = ProtocolError::new(
                    ErrorCode::NoFrames,
                    format!("no frame could be delivered for {} s", hub.config.frame_timeout_s),
                );
                tracing::warn!(session = session.id, error = %e, "closing a starved session");
                send_close(&mut sink, hub, e).await;
                return "no_frames";
            }
            () = tokio::time::sleep(idle_left.unwrap_or(FAR_FUTURE)), if idle_left.is_some() => {
                if session.stream.since_last_pose() < idle_timeout {
                    continue;
                }
                hub.telemetry.sessions_idle.fetch_add(1, Relaxed);
                let e = ProtocolError::new(
                    ErrorCode::Idle,
                    format!("no pose for {} s (idle_timeout_s); reconnect to resume", hub.config.idle_timeout_s),
                );
                tracing::info!(session = session.id, "closing an idle session");
                send_close(&mut sink, hub, e).await;
                return "idle";
            }
            () = session.stream.ack_notify.notified() => {
                flow.acked(session.stream.acked.load(Relaxed), Instant::now());
                continue;
            }
            () = session.slot.ready(), if can_send => match session.slot.take() {
                Some(frame) if !same_size(&frame.spec, &announced) => {
                    session.count_drop(&hub.telemetry, DropReason::Resized);
                    if frame.spec.codec == Codec::H264 {
                        session.stream.key_request.store(true, Relaxed);
                    }
                    continue;
                }
                Some(frame) => {
                    let started = Instant::now();
                    let len = frame.bytes.len() as u64;
                    let mut total = len;
                    if let Some(raw) = frame.raw {
                        total += raw.len() as u64;
                        if let Err(end) = send_timed(&mut sink, hub, Message::Binary(raw), stall).await {
                            return end;
                        }
                        hub.telemetry.raw_frames.fetch_add(1, Relaxed);
                    }
                    if let Err(end) = send_timed(&mut sink, hub, Message::Binary(frame.bytes), stall).await {
                        return end;
                    }
                    let done = Instant::now();
                    flow.sent(frame.frame, total, done - started, done);
                    last_frame = tokio::time::Instant::now();
                    session.sent.fetch_add(1, Relaxed);
                    hub.telemetry.frames_sent.fetch_add(1, Relaxed);
                    hub.telemetry.bytes_sent.fetch_add(len, Relaxed);
                    continue;
                }
                None => continue,
            },
            // Wake for the adaptation's ticks (and to re-check the flow window).
            () = tokio::time::sleep(TICK) => continue,
        };
        if let Err(end) = send_timed(&mut sink, hub, msg, stall).await {
            return end;
        }
    }
}

/// Sends one message within `stall`; the end reason when it cannot.
async fn send_timed(
    sink: &mut Sink,
    hub: &Hub,
    msg: Message,
    stall: Duration,
) -> Result<(), &'static str> {
    match tokio::time::timeout(stall, sink.send(msg)).await {
        Ok(Ok(())) => Ok(()),
        Ok(Err(_)) => Err("send failed"),
        Err(_) => {
            hub.telemetry.sessions_stalled.fetch_add(1, Relaxed);
            Err("stalled")
        }
    }
}

/// This session's share of `fogcast_target_kbps`, removed when the writer ends.
struct TargetGauge {
    kbps: std::cell::Cell<u32>,
    telemetry: Arc<super::telemetry::Telemetry>,
}

impl TargetGauge {
    fn new(hub: &Hub, kbps: u32) -> TargetGauge {
        hub.telemetry
            .target_kbps_sum
            .fetch_add(i64::from(kbps), Relaxed);
        TargetGauge {
            kbps: std::cell::Cell::new(kbps),
            telemetry: hub.telemetry.clone(),
        }
    }

    fn set(&self, hub: &Hub, kbps: u32) {
        let delta = i64::from(kbps) - i64::from(self.kbps.replace(kbps));
        hub.telemetry.target_kbps_sum.fetch_add(delta, Relaxed);
    }
}

impl Drop for TargetGauge {
    fn drop(&mut self) {
        self.telemetry
            .target_kbps_sum
            .fetch_sub(i64::from(self.kbps.get()), Relaxed);
    }
}

/// `requested` with its views halved `level` times (even sides, tiles kept), or `None`
/// below [`MIN_ADAPTED_VIEW_PX`].
fn scaled(requested: &SessionSpec, level: u32, hub: &Hub) -> Option<SessionSpec> {
    if level == 0 {
        return Some(*requested);
    }
    let div = 1u32.checked_shl(level)?;
    let vw = (requested.view_width / div) & !1;
    let vh = (requested.view_height / div) & !1;
    if vw < MIN_ADAPTED_VIEW_PX || vh < MIN_ADAPTED_VIEW_PX {
        return None;
    }
    let (cols, rows) = match (requested.layout, requested.views) {
        (Layout::Mono, _) => (1, 1),
        (Layout::Stereo, _) | (Layout::Split, 2) => (2, 1),
        _ => (2, 2),
    };
    let limits = hub.config.spec_limits();
    SessionSpec::validate(
        vw * cols,
        vh * rows,
        requested.layout,
        Some(requested.views),
        Some(requested.quality),
        Some(requested.eye_distance_m),
        &limits,
    )
    .and_then(|s| {
        s.with_stream(
            requested.codec,
            Some(requested.max_kbps),
            Some(requested.raw_every),
            &limits,
        )
    })
    .ok()
}

/// Applies a bandwidth resize (the flow's level already moved); the new spec, or `None`
/// (level restored) when it cannot be applied.
fn adapt_size(
    hub: &Hub,
    session: &SessionShared,
    requested: &SessionSpec,
    flow: &mut Flow,
    resize: Resize,
) -> Option<SessionSpec> {
    let undo = |flow: &mut Flow| match resize {
        Resize::Down => flow.shrink_level -= 1,
        Resize::Up => flow.shrink_level += 1,
    };
    let Some(spec) = scaled(requested, flow.shrink_level, hub) else {
        undo(flow);
        return None;
    };
    if let Err(e) = hub.reconfigure(session, spec) {
        tracing::info!(session = session.id, error = %for_log(&e), "bandwidth resize not applied");
        undo(flow);
        return None;
    }
    session.stream.key_request.store(true, Relaxed);
    let counter = match resize {
        Resize::Down => &hub.telemetry.resized_down,
        Resize::Up => &hub.telemetry.resized_up,
    };
    counter.fetch_add(1, Relaxed);
    tracing::info!(
        session = session.id,
        ?resize,
        width = spec.width,
        height = spec.height,
        target_kbps = flow.target_kbps(),
        "frame size adapted to the client's bandwidth"
    );
    Some(spec)
}

/// Whether frames of spec `a` have the size and tiling the client was told in `b`.
fn same_size(a: &SessionSpec, b: &SessionSpec) -> bool {
    (a.layout, a.views, a.width, a.height) == (b.layout, b.views, b.width, b.height)
}

/// Queues a control message; a client that leaves [`CONTROL_QUEUE`] replies unread is
/// flooding, and is closed rather than have a reply dropped.
fn push(ctl: &mpsc::Sender<Control>, c: Control) -> Result<(), ProtocolError> {
    match ctl.try_send(c) {
        Ok(()) | Err(mpsc::error::TrySendError::Closed(_)) => Ok(()),
        Err(mpsc::error::TrySendError::Full(_)) => Err(ProtocolError::new(
            ErrorCode::RateLimited,
            format!("{CONTROL_QUEUE} replies unread: the client sends faster than it reads"),
        )),
    }
}

/// Validates and applies client messages until the client leaves or a fatal error.
async fn read_loop(
    mut stream: Stream,
    hub: &Hub,
    session: &SessionShared,
    ctl: mpsc::Sender<Control>,
    mut limiter: RateLimiter,
) {
    let mut errors = 0u32;
    let mut window_start = Instant::now();
    let mut configures = ConfigureLimiter::new(hub.config.max_configures_per_s);
    let fatal = loop {
        let msg = match stream.next().await {
            Some(Ok(m)) => m,
            // A message over the WebSocket layer's own limit ends the stream with an
            // error; the connection is unusable after it.
            None | Some(Err(_)) => return,
        };
        match limiter.check() {
            Rate::Ok => {}
            Rate::Drop { warn } => {
                hub.telemetry.client_error(ErrorCode::RateLimited, false);
                if warn {
                    let e = ProtocolError::new(
                        ErrorCode::RateLimited,
                        format!(
                            "more than {} messages per second: messages are being dropped",
                            hub.config.max_messages_per_s
                        ),
                    );
                    if let Err(e) = push(&ctl, Control::Text(error_json(&e, false))) {
                        break e;
                    }
                }
                continue;
            }
            Rate::Flood => {
                break ProtocolError::new(
                    ErrorCode::RateLimited,
                    format!(
                        "message flood: over {} messages per second",
                        2.0 * hub.config.max_messages_per_s
                    ),
                );
            }
        }
        let result = match msg {
            Message::Text(t) if t.len() > hub.config.max_message_bytes => {
                break too_large(t.len(), hub.config.max_message_bytes)
            }
            Message::Text(t) => handle_text(&t, hub, session, &mut configures),
            Message::Binary(b) => break binary_error(b.len()),
            // Pings are answered by the WebSocket layer; a close is answered there too,
            // and the stream then ends.
            Message::Ping(_) | Message::Pong(_) | Message::Close(_) => Ok(None),
        };
        match result {
            Ok(Some(reply)) => {
                if let Err(e) = push(&ctl, reply) {
                    break e;
                }
            }
            Ok(None) => {}
            Err(e) => {
                hub.telemetry.client_error(e.code, false);
                if window_start.elapsed() > ERROR_WINDOW {
                    window_start = Instant::now();
                    errors = 0;
                }
                errors += 1;
                if errors > MAX_ERRORS_PER_WINDOW {
                    break ProtocolError::new(
                        ErrorCode::TooManyErrors,
                        format!(
                            "more than {MAX_ERRORS_PER_WINDOW} invalid messages in {} s; last: {e}",
                            ERROR_WINDOW.as_secs()
                        ),
                    );
                }
                if let Err(e) = push(&ctl, Control::Text(error_json(&e, false))) {
                    break e;
                }
            }
        }
    };
    tracing::info!(session = session.id, error = %for_log(&fatal), "closing session");
    // The writer sends the error and the close frame; keep reading so the client's
    // close reply is consumed (the caller bounds how long).
    if ctl.send(Control::Close(fatal)).await.is_ok() {
        while let Some(Ok(_)) = stream.next().await {}
    }
}

/// Applies one text message; `Ok(Some(reply))` is a reply to send.
fn handle_text(
    text: &str,
    hub: &Hub,
    session: &SessionShared,
    configures: &mut ConfigureLimiter,
) -> Result<Option<Control>, ProtocolError> {
    match parse_client_message(text)? {
        ClientMessage::Pose(p) => {
            let spec = session.view().spec;
            let poses = check_pose(&spec, &p)?;
            session.set_poses(p.seq, poses, hub.scene.origin);
            Ok(None)
        }
        ClientMessage::Configure(c) => {
            if !configures.take() {
                return Err(ProtocolError::new(
                    ErrorCode::RateLimited,
                    format!(
                        "configure is limited to {} per second (bursts of {CONFIGURE_BURST}); this one was not applied",
                        hub.config.max_configures_per_s
                    ),
                ));
            }
            let spec = session.view().spec;
            let new = spec.configure(&c, &hub.config.spec_limits())?;
            hub.reconfigure(session, new)?;
            tracing::info!(session = session.id, layout = layout_name(new.layout), width = new.width, height = new.height, quality = new.quality, "session reconfigured");
            // A key frame follows every configure (the codec or size may have changed).
            session.stream.key_request.store(true, Relaxed);
            Ok(Some(Control::Welcome(
                welcome(hub, session, WelcomeReason::Configure),
                new,
            )))
        }
        ClientMessage::Ack(a) => {
            session.stream.ack(a.frame);
            Ok(None)
        }
        ClientMessage::Keyframe => {
            if session.view().spec.codec == Codec::H264 {
                session.stream.key_request.store(true, Relaxed);
            }
            Ok(None)
        }
        ClientMessage::Hello(h) => Err(ProtocolError::new(
            ErrorCode::InvalidMessage,
            format!("hello (version {}) after the session started: send {{\"type\":\"configure\", ...}} to change it", clip(&h.version.to_string())),
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rate_limiter_warns_then_closes() {
        let mut r = RateLimiter::new(10.0);
        let mut kinds = Vec::new();
        for _ in 0..25 {
            kinds.push(match r.check() {
                Rate::Ok => 'o',
                Rate::Drop { warn: true } => 'W',
                Rate::Drop { warn: false } => 'd',
                Rate::Flood => 'F',
            });
        }
        let s: String = kinds.into_iter().collect();
        assert!(s.starts_with("oooooooooo"), "{s}");
        assert_eq!(s.matches('W').count(), 1, "{s}");
        assert!(s.ends_with('F'), "{s}");
    }

    #[test]
    fn client_text_is_escaped_in_logs() {
        // serde quotes an unknown enum variant raw.
        let e = parse_client_message(
            r#"{"type":"hello","version":1,"width":64,"height":36,"layout":"x\n\u001b[31mFAKE LOG LINE"}"#,
        )
        .unwrap_err();
        assert!(
            e.message.contains('\n') && e.message.contains('\u{1b}'),
            "{e:?}"
        );
        let line = for_log(&e);
        assert!(!line.chars().any(|c| c.is_control()), "{line}");
        assert!(line.contains("\\n") && line.contains("\\u{1b}"), "{line}");
    }

    #[test]
    fn close_reasons_fit_a_control_frame() {
        let e = ProtocolError::new(ErrorCode::InvalidHello, "é".repeat(200));
        assert!(close_reason(&e).len() <= 123);
        assert!(
            constant_time_eq(b"abc", b"abc")
                && !constant_time_eq(b"abc", b"abd")
                && !constant_time_eq(b"abc", b"ab")
        );
    }
}
