//! One session's stream: its codec state (the H.264 encoder, the JPEG quality in force),
//! flow control from the client's acks, and the adaptive bitrate that follows what the
//! client's link delivers (`docs/protocol.md`, "Streaming").
//!
//! [`StreamState`] is what the render loop, the encoder job and the session's writer
//! share; [`Flow`] is the writer's own bookkeeping and decisions, a pure function of the
//! sends, acks and skips it is told about and the time, so it is tested without sockets.

use openh264::encoder::{Encoder, EncoderConfig, FrameType, RateControlMode, UsageType};
use openh264::formats::YUVSlices;
use openh264::{OpenH264API, Timestamp};
use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, AtomicU32, AtomicU8, Ordering::Relaxed};
use std::sync::Mutex;
use std::time::{Duration, Instant};
use tokio::sync::Notify;

/// Lowest JPEG quality the adaptation goes to.
pub(crate) const MIN_JPEG_QUALITY: u8 = 20;
/// Smallest view side the bandwidth adaptation shrinks to, pixels.
pub(crate) const MIN_ADAPTED_VIEW_PX: u32 = 64;

/// What the render loop, the encoder and the writer share about one session's stream.
pub(crate) struct StreamState {
    /// The session's H.264 encoder (only the one encoder job at a time touches it).
    pub(crate) h264: Mutex<Option<H264Stream>>,
    /// The next H.264 frame must be a key frame (a client request, a configure, a frame
    /// the client never got).
    pub(crate) key_request: AtomicBool,
    /// Target bitrate, kbit/s (set by the writer's adaptation).
    pub(crate) target_kbps: AtomicU32,
    /// JPEG quality in force (≤ the session's requested quality).
    pub(crate) jpeg_quality: AtomicU8,
    /// Whether the writer can take a frame now (its flow window is open); while false the
    /// render loop skips the session before encoding.
    pub(crate) ready: AtomicBool,
    /// Frames skipped for this client since the writer last looked (counted by the
    /// render loop and the latest-frame slot; the adaptation reads them as congestion).
    pub(crate) skipped: AtomicU32,
    /// Newest frame the client acked, and a wake-up for the writer.
    pub(crate) acked: AtomicU32,
    pub(crate) ack_seen: AtomicBool,
    pub(crate) ack_notify: Notify,
    /// When the client last sent a pose (the idle timeout counts from it).
    pub(crate) last_pose: Mutex<Instant>,
}

impl StreamState {
    pub(crate) fn new(start_kbps: u32, quality: u8) -> StreamState {
        StreamState {
            h264: Mutex::new(None),
            key_request: AtomicBool::new(false),
            target_kbps: AtomicU32::new(start_kbps),
            jpeg_quality: AtomicU8::new(quality),
            ready: AtomicBool::new(true),
            skipped: AtomicU32::new(0),
            acked: AtomicU32::new(0),
            ack_seen: AtomicBool::new(false),
            ack_notify: Notify::new(),
            last_pose: Mutex::new(Instant::now()),
        }
    }

    /// Records an ack for `frame` (newer than any before) and wakes the writer.
    pub(crate) fn ack(&self, frame: u32) {
        self.acked.fetch_max(frame, Relaxed);
        self.ack_seen.store(true, Relaxed);
        self.ack_notify.notify_one();
    }

    pub(crate) fn touch_pose(&self) {
        *self.last_pose.lock().unwrap_or_else(|e| e.into_inner()) = Instant::now();
    }

    pub(crate) fn since_last_pose(&self) -> Duration {
        self.last_pose
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .elapsed()
    }
}

/// One H.264 stream: OpenH264 (constrained baseline, single-threaded — sessions encode in
/// parallel on the encoder pool instead) at one frame size.
pub(crate) struct H264Stream {
    encoder: Encoder,
    size: (u32, u32),
    /// The bitrate the encoder was last told, kbit/s (the target scaled by
    /// `max_fps × frame interval`, see [`H264Stream::encode`]).
    bitrate_kbps: u32,
    /// The frame rate the encoder was configured for, and the stream's measured frame
    /// interval (exponential average, seconds) with the last frame's time.
    max_fps: f64,
    interval_s: f64,
    last_ms: Option<u64>,
    frames_since_key: u32,
    /// The frame in I420, converted as `protocol::rgba_to_i420` documents.
    i420: Vec<u8>,
}

/// An encoded access unit.
pub(crate) struct AccessUnit {
    pub(crate) bytes: Vec<u8>,
    pub(crate) key: bool,
}

impl H264Stream {
    /// A stream of `width`×`height` (both even) frames at `kbps`, paced for `fps`.
    pub(crate) fn new(width: u32, height: u32, kbps: u32, fps: f64) -> anyhow::Result<H264Stream> {
        let config = EncoderConfig::new()
            .set_bitrate_bps(kbps.saturating_mul(1000))
            .max_frame_rate(fps as f32)
            .rate_control_mode(RateControlMode::Bitrate)
            // OpenH264 holds a bitrate only when it may skip frames (it says so when
            // asked not to); a skipped frame is simply not sent — no reference is lost.
            .enable_skip_frame(true)
            .usage_type(UsageType::CameraVideoRealTime)
            .set_multiple_thread_idc(1);
        let encoder = Encoder::with_api_config(OpenH264API::from_source(), config)
            .map_err(|e| anyhow::anyhow!("starting the H.264 encoder: {e}"))?;
        Ok(H264Stream {
            encoder,
            size: (width, height),
            bitrate_kbps: kbps,
            max_fps: fps,
            interval_s: 1.0 / fps,
            last_ms: None,
            frames_since_key: 0,
            i420: Vec::with_capacity(width as usize * height as usize * 3 / 2),
        })
    }

    pub(crate) fn size(&self) -> (u32, u32) {
        self.size
    }

    /// Encodes one RGBA8 frame at `kbps`; a key frame when `force_key`, on the stream's
    /// first frame, or after `gop` frames. `None`: the rate control skipped this frame
    /// (the bitrate is spent); nothing is sent for it.
    pub(crate) fn encode(
        &mut self,
        rgba: &[u8],
        kbps: u32,
        force_key: bool,
        gop: u32,
        time_ms: u64,
    ) -> anyhow::Result<Option<AccessUnit>> {
        // OpenH264's bitrate mode budgets `bitrate / max_fps` per frame; a server frame
        // rate below its cap (a slow GPU, skipped frames) would under-spend the target by
        // that ratio, so the encoder is told the target scaled by it.
        if let Some(last) = self.last_ms {
            let dt = (time_ms.saturating_sub(last) as f64 / 1e3).clamp(1e-3, 1.0);
            self.interval_s += 0.2 * (dt - self.interval_s);
        }
        self.last_ms = Some(time_ms);
        let scale = (self.max_fps * self.interval_s).clamp(1.0, 10.0);
        let wanted = (f64::from(kbps) * scale).round() as u32;
        if wanted.abs_diff(self.bitrate_kbps) * 20 > self.bitrate_kbps {
            self.set_bitrate(wanted);
        }
        if force_key || self.frames_since_key >= gop {
            self.encoder.force_intra_frame();
        }
        let (w, h) = (self.size.0 as usize, self.size.1 as usize);
        anyhow::ensure!(
            rgba.len() == w * h * 4,
            "an RGBA frame of {} bytes for a {w}x{h} stream",
            rgba.len()
        );
        crate::protocol::rgba_to_i420(rgba, (w, h), &mut self.i420);
        let (y, chroma) = self.i420.split_at(w * h);
        let (u, v) = chroma.split_at(w * h / 4);
        let picture = YUVSlices::new((y, u, v), (w, h), (w, w / 2, w / 2));
        let stream = self
            .encoder
            .encode_at(&picture, Timestamp::from_millis(time_ms))
            .map_err(|e| anyhow::anyhow!("H.264 encoding: {e}"))?;
        if stream.frame_type() == FrameType::Skip {
            return Ok(None);
        }
        let key = matches!(stream.frame_type(), FrameType::IDR | FrameType::I);
        let bytes = stream.to_vec();
        anyhow::ensure!(
            !bytes.is_empty(),
            "the H.264 encoder produced no data ({:?})",
            stream.frame_type()
        );
        self.frames_since_key = if key { 1 } else { self.frames_since_key + 1 };
        Ok(Some(AccessUnit { bytes, key }))
    }

    /// Changes the target bitrate of the running encoder (no key frame). The only
    /// `unsafe` in fogcast: the safe wrapper has no runtime bitrate setter, and
    /// re-creating the encoder would cost a key frame at every adaptation step — the
    /// moment the link is already congested.
    #[allow(unsafe_code)]
    fn set_bitrate(&mut self, kbps: u32) {
        let mut info = openh264_sys2::SBitrateInfo {
            iLayer: openh264_sys2::SPATIAL_LAYER_ALL,
            iBitrate: kbps.saturating_mul(1000).min(i32::MAX as u32) as i32,
        };
        // SAFETY: the encoder is initialised (it has encoded a frame, or the option is
        // applied before the first frame's own initialisation, which overrides it), and
        // ENCODER_OPTION_BITRATE takes a pointer to an SBitrateInfo that outlives the
        // call — exactly what OpenH264's own SetOption documentation prescribes.
        let rc = unsafe {
            self.encoder.raw_api().set_option(
                openh264_sys2::ENCODER_OPTION_BITRATE,
                std::ptr::addr_of_mut!(info).cast(),
            )
        };
        if rc == 0 {
            self.bitrate_kbps = kbps;
        } else {
            tracing::warn!(kbps, rc, "OpenH264 refused a bitrate change");
        }
    }
}

/// A frame sent and not yet acked.
#[derive(Debug, Clone, Copy)]
struct InFlight {
    frame: u32,
    bytes: u64,
    at: Instant,
    /// Bytes acked in all when it was sent (its ack's delivery-rate sample counts what
    /// arrived in between).
    acked_before: u64,
}

/// What the writer's adaptation decided at a tick.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Resize {
    /// Halve the frame size: the link does not carry it even at the floor.
    Down,
    /// One step back toward the requested size: the link carries it again.
    Up,
}

/// Tunables of [`Flow`] (from the server config).
#[derive(Debug, Clone, Copy)]
pub(crate) struct FlowConfig {
    pub(crate) min_kbps: u32,
    pub(crate) max_queue: Duration,
}

/// How often the adaptation decides.
pub(crate) const TICK: Duration = Duration::from_millis(500);
/// Uncongested time before the target is raised.
const PROBE_AFTER: Duration = Duration::from_secs(2);
/// Congested time at the floor before the frame is made smaller.
const SHRINK_AFTER: Duration = Duration::from_secs(3);
/// Uncongested time before a shrunk frame grows back one step.
const GROW_AFTER: Duration = Duration::from_secs(10);
/// A new session's first frame waits this long for its ack before the client counts as
/// one that does not ack (paced by TCP alone). Until then one frame at a time is in
/// flight, so a slow link's TCP buffers are not filled before its first ack returns.
const FIRST_ACK_GRACE: Duration = Duration::from_secs(1);
/// An acking client with frames in flight and no ack for this long is sent one frame
/// (a probe) per this interval — congested, never stuck — whatever the reason: a link
/// slower than one frame per interval, or a client that stopped acking.
const ACK_TIMEOUT: Duration = Duration::from_secs(1);

/// Whether the client acks.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Acks {
    /// Not known yet: one frame in flight until its ack or [`FIRST_ACK_GRACE`].
    Unknown,
    /// It acks: flow control by what is in flight.
    Yes,
    /// It has not acked within the grace: paced by the WebSocket send (TCP) alone,
    /// until an ack arrives.
    No,
}
/// The delivered rate is measured over this window.
const RATE_WINDOW: Duration = Duration::from_secs(1);

/// The writer's flow control and bitrate adaptation for one session.
#[derive(Debug)]
pub(crate) struct Flow {
    config: FlowConfig,
    /// Frames sent and not yet acked, oldest first.
    in_flight: VecDeque<InFlight>,
    in_flight_bytes: u64,
    /// (when, bytes) of each ack (or, for a client that does not ack, each send) in the
    /// last [`RATE_WINDOW`].
    delivered: VecDeque<(Instant, u64)>,
    /// Bytes acked in all.
    acked_total: u64,
    /// (when, bytes/s) delivery-rate samples of the last [`RATE_WINDOW`]: each ack's
    /// bytes delivered since its frame was sent over the time it took. Their maximum is
    /// the link's capacity estimate — a low-rate stream on a fast link delivers little
    /// per second but each frame quickly, and must not look like a slow link.
    rate_samples: VecDeque<(Instant, f64)>,
    /// Whether the client acks (flow control applies only then), when it last did, and
    /// when the last frame went out.
    acks: Acks,
    last_ack: Instant,
    last_send: Option<Instant>,
    /// Shortest send-to-ack time seen, less the frame's own transmission time: the
    /// path's base delay, which is not queueing. Kept for the session's life — a minimum
    /// that were allowed to forget could learn a standing queue as "base" and let the
    /// queue creep up window after window.
    base_rtt: Option<Duration>,
    /// Time the last sends spent blocked (clients without acks: congestion from TCP).
    blocked: Duration,
    /// Frames skipped for this client since the last tick.
    skipped: u32,
    /// The target, kbit/s, and its ceiling.
    target_kbps: f64,
    max_kbps: f64,
    /// Whether the stream is JPEG (its lever is the quality) or H.264 (the bitrate).
    jpeg: bool,
    /// JPEG quality in force and the requested one.
    quality: u8,
    max_quality: u8,
    /// Since when the link has been congested / clear without a break.
    congested_since: Option<Instant>,
    clear_since: Instant,
    /// How many times the frame has been halved.
    pub(crate) shrink_level: u32,
    last_tick: Instant,
}

impl Flow {
    pub(crate) fn new(
        config: FlowConfig,
        start_kbps: u32,
        max_kbps: u32,
        quality: u8,
        jpeg: bool,
    ) -> Flow {
        let now = Instant::now();
        Flow {
            config,
            in_flight: VecDeque::new(),
            in_flight_bytes: 0,
            delivered: VecDeque::new(),
            acked_total: 0,
            rate_samples: VecDeque::new(),
            acks: Acks::Unknown,
            last_ack: now,
            last_send: None,
            base_rtt: None,
            blocked: Duration::ZERO,
            skipped: 0,
            target_kbps: f64::from(start_kbps.min(max_kbps)),
            max_kbps: f64::from(max_kbps),
            jpeg,
            quality,
            max_quality: quality,
            congested_since: None,
            clear_since: now,
            shrink_level: 0,
            last_tick: now,
        }
    }

    /// The client asked for a new ceiling and quality (a configure).
    pub(crate) fn set_limits(&mut self, max_kbps: u32, quality: u8, jpeg: bool) {
        self.jpeg = jpeg;
        self.max_kbps = f64::from(max_kbps);
        self.target_kbps = self.target_kbps.min(self.max_kbps);
        self.max_quality = quality;
        self.quality = self.quality.min(quality);
    }

    pub(crate) fn target_kbps(&self) -> u32 {
        self.target_kbps.round() as u32
    }

    pub(crate) fn quality(&self) -> u8 {
        self.quality
    }

    #[cfg(test)]
    pub(crate) fn in_flight_bytes(&self) -> u64 {
        self.in_flight_bytes
    }

    /// Bytes per second the client took over the last second (acked bytes; for a
    /// client without acks, bytes the socket accepted).
    pub(crate) fn delivered_bps(&self, now: Instant) -> f64 {
        let bytes: u64 = self
            .delivered
            .iter()
            .filter(|(t, _)| now.duration_since(*t) <= RATE_WINDOW)
            .map(|(_, b)| b)
            .sum();
        bytes as f64 / RATE_WINDOW.as_secs_f64()
    }

    /// The path's base round-trip time (zero before the first ack).
    fn base_rtt(&self) -> Duration {
        self.base_rtt.unwrap_or(Duration::ZERO)
    }

    /// Whether another frame may go out now: always for clients that do not ack; for
    /// those that do, while what is in flight stays under what the delivered rate
    /// drains in the base round trip plus `max_queue` (one frame may always be in flight).
    pub(crate) fn can_send(&mut self, now: Instant) -> bool {
        if self.in_flight.is_empty() {
            return true;
        }
        let since_send = self
            .last_send
            .map_or(Duration::MAX, |t| now.duration_since(t));
        match self.acks {
            Acks::No => return true,
            Acks::Unknown if since_send > FIRST_ACK_GRACE => {
                tracing::debug!("no ack within {FIRST_ACK_GRACE:?}: paced by TCP alone");
                self.acks = Acks::No;
                self.in_flight.clear();
                self.in_flight_bytes = 0;
                return true;
            }
            Acks::Unknown => return false,
            Acks::Yes
                if now.duration_since(self.last_ack) > ACK_TIMEOUT && since_send > ACK_TIMEOUT =>
            {
                // A probe: the link (or the client) is far behind.
                self.skipped += 1;
                return true;
            }
            Acks::Yes => {}
        }
        let budget =
            self.capacity_bps(now) * (self.base_rtt() + self.config.max_queue).as_secs_f64();
        (self.in_flight_bytes as f64) < budget
    }

    /// The link's capacity estimate, bytes/s: the largest delivery-rate sample of the
    /// last [`RATE_WINDOW`] (the delivered rate before there is one).
    fn capacity_bps(&self, now: Instant) -> f64 {
        self.rate_samples
            .iter()
            .filter(|(t, _)| now.duration_since(*t) <= RATE_WINDOW)
            .map(|(_, r)| *r)
            .fold(self.delivered_bps(now), f64::max)
    }

    /// Seconds of queue beyond the base round trip that what is in flight represents.
    fn queue_s(&self, now: Instant) -> f64 {
        let drain = self.in_flight_bytes as f64 / self.capacity_bps(now).max(1.0);
        (drain - self.base_rtt().as_secs_f64()).max(0.0)
    }

    /// A frame of `bytes` went out; the send took `took` (blocked on the socket).
    pub(crate) fn sent(&mut self, frame: u32, bytes: u64, took: Duration, now: Instant) {
        self.in_flight.push_back(InFlight {
            frame,
            bytes,
            at: now,
            acked_before: self.acked_total,
        });
        self.in_flight_bytes += bytes;
        self.last_send = Some(now);
        if self.acks == Acks::No {
            self.delivered.push_back((now, bytes));
            self.blocked += took;
            // Nobody acks: what the socket took counts as delivered.
            self.in_flight.clear();
            self.in_flight_bytes = 0;
        }
        self.trim(now);
    }

    /// The client has every frame up to `frame`.
    pub(crate) fn acked(&mut self, frame: u32, now: Instant) {
        self.last_ack = now;
        if self.acks != Acks::Yes {
            // From now on the delivered rate is what the client confirms.
            self.acks = Acks::Yes;
            self.delivered.clear();
        }
        while let Some(f) = self.in_flight.front() {
            if f.frame > frame {
                break;
            }
            self.in_flight_bytes -= f.bytes;
            self.acked_total += f.bytes;
            self.delivered.push_back((now, f.bytes));
            let took = now.duration_since(f.at).max(Duration::from_micros(100));
            let sample = (self.acked_total - f.acked_before) as f64 / took.as_secs_f64();
            self.rate_samples.push_back((now, sample));
            let transmit =
                Duration::from_secs_f64(f.bytes as f64 / self.capacity_bps(now).max(1.0));
            let rtt = took.saturating_sub(transmit);
            self.base_rtt = Some(self.base_rtt.map_or(rtt, |b| b.min(rtt)));
            self.in_flight.pop_front();
        }
        self.trim(now);
    }

    /// `n` frames were skipped for this client (its window was full, or it had not
    /// taken the previous frame).
    pub(crate) fn skipped(&mut self, n: u32) {
        self.skipped += n;
    }

    fn trim(&mut self, now: Instant) {
        let old = |t: &Instant| now.duration_since(*t) > RATE_WINDOW;
        while self.delivered.front().is_some_and(|(t, _)| old(t)) {
            self.delivered.pop_front();
        }
        while self.rate_samples.front().is_some_and(|(t, _)| old(t)) {
            self.rate_samples.pop_front();
        }
    }

    /// Whether a tick is due.
    pub(crate) fn tick_due(&self, now: Instant) -> bool {
        now.duration_since(self.last_tick) >= TICK
    }

    /// Decides the target bitrate / quality and whether to resize, from what happened
    /// since the last tick.
    pub(crate) fn tick(&mut self, now: Instant, shrinkable: bool) -> Option<Resize> {
        let elapsed = now
            .duration_since(self.last_tick)
            .max(Duration::from_millis(1));
        self.last_tick = now;
        self.trim(now);
        let oldest_wait = if self.acks == Acks::Yes {
            self.queue_s(now)
        } else {
            self.blocked.as_secs_f64() / elapsed.as_secs_f64() * TICK.as_secs_f64()
        };
        let congested = self.skipped > 0 || oldest_wait > self.config.max_queue.as_secs_f64();
        self.skipped = 0;
        self.blocked = Duration::ZERO;
        let floor = f64::from(self.config.min_kbps);
        if congested {
            self.clear_since = now;
            let since = *self.congested_since.get_or_insert(now);
            let delivered_kbps = self.delivered_bps(now) * 8.0 / 1000.0;
            if delivered_kbps > 0.0 {
                self.target_kbps = (0.85 * delivered_kbps).min(self.target_kbps);
            } else {
                self.target_kbps *= 0.85;
            }
            self.target_kbps = self.target_kbps.clamp(floor, self.max_kbps);
            self.quality = self.quality.saturating_sub(10).max(MIN_JPEG_QUALITY);
            // Nothing left to lower: H.264 at the floor bitrate, JPEG at the floor quality.
            let at_floor = if self.jpeg {
                self.quality <= MIN_JPEG_QUALITY
            } else {
                self.target_kbps <= floor * 1.01
            };
            if at_floor && shrinkable && now.duration_since(since) >= SHRINK_AFTER {
                self.congested_since = None;
                self.shrink_level += 1;
                return Some(Resize::Down);
            }
            return None;
        }
        self.congested_since = None;
        let clear_for = now.duration_since(self.clear_since);
        if clear_for >= PROBE_AFTER {
            self.target_kbps = (self.target_kbps * 1.1).min(self.max_kbps);
            self.quality = (self.quality + 5).min(self.max_quality);
        }
        if self.shrink_level > 0 && clear_for >= GROW_AFTER && self.target_kbps >= 2.0 * floor {
            self.shrink_level -= 1;
            self.clear_since = now;
            return Some(Resize::Up);
        }
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn flow() -> Flow {
        Flow::new(
            FlowConfig {
                min_kbps: 150,
                max_queue: Duration::from_millis(150),
            },
            2000,
            8000,
            75,
            false,
        )
    }

    /// A link of `kbps` and a sender offering `frame_bytes(target)` at 30 fps for
    /// `secs`: the flow control skips what the link cannot take, acks arrive as the link
    /// delivers. Returns the bytes sent in the second half and the longest queue (s).
    fn simulate(
        f: &mut Flow,
        kbps: f64,
        secs: f64,
        fps: f64,
        frame_bytes: impl Fn(u32) -> u64,
    ) -> (u64, f64) {
        let start = Instant::now();
        let mut link_free_at = 0.0f64; // seconds from start
        let mut pending: VecDeque<(f64, u32)> = VecDeque::new(); // (ack time, frame)
        let mut late_bytes = 0;
        let mut worst_queue_s: f64 = 0.0;
        let mut frame = 0u32;
        let mut next_frame = 0.0;
        // 1 ms steps: acks are taken when they arrive, frames come at `fps`.
        for ms in 0..(secs * 1000.0) as u64 {
            let t = ms as f64 / 1000.0;
            let now = start + Duration::from_millis(ms);
            while pending.front().is_some_and(|(at, _)| *at <= t) {
                let (_, fr) = pending.pop_front().unwrap();
                f.acked(fr, now);
            }
            if t >= next_frame {
                next_frame += 1.0 / fps;
                frame += 1;
                if f.can_send(now) {
                    let bytes = frame_bytes(f.target_kbps());
                    let begin = link_free_at.max(t);
                    link_free_at = begin + bytes as f64 * 8.0 / (kbps * 1000.0);
                    worst_queue_s = worst_queue_s.max(link_free_at - t);
                    pending.push_back((link_free_at, frame));
                    f.sent(frame, bytes, Duration::ZERO, now);
                    if t >= secs / 2.0 {
                        late_bytes += bytes;
                    }
                } else {
                    f.skipped(1);
                }
            }
            if f.tick_due(now) {
                f.tick(now, false);
            }
        }
        (late_bytes, worst_queue_s)
    }

    #[test]
    fn a_slow_link_gets_fewer_bytes_not_a_growing_queue() {
        let mut f = flow();
        // The first frame is sent before any ack: the client is paced by acks from its
        // first ack on.
        f.acked(0, Instant::now());
        // An encoder that hits its target: target/30 fps per frame.
        let (bytes, worst) = simulate(&mut f, 1000.0, 40.0, 30.0, |kbps| {
            kbps as u64 * 1000 / 8 / 30
        });
        let kbps = bytes as f64 * 8.0 / 1000.0 / 20.0;
        assert!(
            kbps <= 1000.0 && kbps > 600.0,
            "sent {kbps} kbit/s over a 1000 kbit/s link"
        );
        // The target saws around the link's rate (probing up, cut on congestion).
        assert!(f.target_kbps() < 1500, "target {}", f.target_kbps());
        assert!(worst < 0.5, "longest queue {worst} s");
    }

    #[test]
    fn a_fast_link_probes_up_to_the_ceiling() {
        let mut f = flow();
        simulate(&mut f, 100_000.0, 30.0, 30.0, |kbps| {
            kbps as u64 * 1000 / 8 / 30
        });
        assert_eq!(f.target_kbps(), 8000);
        assert_eq!(f.quality(), 75);
    }

    #[test]
    fn a_small_stream_on_a_fast_link_is_never_congested() {
        // 2 KB frames at 5 fps: one frame is 0.2 s of the delivered *rate*, which must
        // not read as a 0.2 s queue; the capacity estimate comes from how fast each
        // frame arrives instead.
        let mut f = flow();
        f.acked(0, Instant::now());
        simulate(&mut f, 50_000.0, 20.0, 5.0, |_| 2_000);
        assert_eq!((f.target_kbps(), f.quality()), (8000, 75));
    }

    #[test]
    fn congestion_at_the_floor_shrinks_then_recovery_grows_back() {
        let mut f = flow();
        let t0 = Instant::now();
        f.acked(0, t0);
        let mut resized = Vec::new();
        for i in 0..40 {
            let now = t0 + TICK * (i + 1);
            f.skipped(1);
            if let Some(r) = f.tick(now, true) {
                resized.push((i, r));
            }
        }
        assert_eq!(f.target_kbps(), 150);
        assert_eq!(f.quality(), MIN_JPEG_QUALITY);
        assert!(resized.iter().all(|(_, r)| *r == Resize::Down) && !resized.is_empty());
        let level = f.shrink_level;
        let t1 = t0 + TICK * 41;
        let mut grew = 0;
        for i in 0..200 {
            // Clear: everything acked at once, the target climbs back.
            let now = t1 + TICK * i;
            f.sent(i, 1000, Duration::ZERO, now);
            f.acked(i, now);
            if f.tick(now, true) == Some(Resize::Up) {
                grew += 1;
            }
        }
        assert_eq!(grew, level, "grew {grew} of {level} steps back");
        assert_eq!(f.shrink_level, 0);
    }

    #[test]
    fn the_first_frame_waits_for_its_ack_then_a_client_without_acks_is_paced_by_tcp() {
        let mut f = flow();
        let t0 = Instant::now();
        assert!(f.can_send(t0));
        f.sent(1, 1_000_000, Duration::ZERO, t0);
        // One frame in flight until its ack or the grace...
        assert!(!f.can_send(t0 + Duration::from_millis(500)));
        // ... after which every frame may go.
        let later = t0 + FIRST_ACK_GRACE + Duration::from_millis(1);
        assert!(f.can_send(later));
        for i in 2..100 {
            f.sent(i, 1_000_000, Duration::ZERO, later);
            assert!(f.can_send(later));
        }
        assert_eq!(f.in_flight_bytes(), 0);
    }

    #[test]
    fn a_client_that_stops_acking_gets_a_probe_a_second() {
        let mut f = flow();
        let t0 = Instant::now();
        f.sent(1, 1000, Duration::ZERO, t0);
        f.acked(1, t0 + Duration::from_millis(5));
        let mut sent = 0;
        for ms in (10..10_000).step_by(10) {
            let now = t0 + Duration::from_millis(ms);
            if f.can_send(now) {
                sent += 1;
                f.sent(1 + sent, 50_000, Duration::ZERO, now);
            }
        }
        // The window lets a few frames go at first, then one probe per ACK_TIMEOUT.
        assert!(
            (9..=15).contains(&sent),
            "{sent} frames in 10 s without an ack"
        );
    }

    #[test]
    fn h264_round_trip_decodes_and_keys_on_request() {
        let (w, h) = (64u32, 48u32);
        let mut s = H264Stream::new(w, h, 500, 30.0).unwrap();
        let mut decoder = openh264::decoder::Decoder::new().unwrap();
        let mut keys = Vec::new();
        for i in 0..12u32 {
            let rgba: Vec<u8> = (0..w * h)
                .flat_map(|p| {
                    let (x, y) = (p % w, p / w);
                    [(x * 4 + i * 3) as u8, (y * 5) as u8, 128, 255]
                })
                .collect();
            let au = s
                .encode(&rgba, 500, i == 7, 60, u64::from(i) * 33)
                .unwrap()
                .expect("500 kbit/s is plenty for 64x48: no frame skipped");
            keys.push(au.key);
            let yuv = decoder
                .decode(&au.bytes)
                .unwrap()
                .expect("a picture per access unit");
            use openh264::formats::YUVSource as _;
            let rgb = crate::protocol::yuv420_to_rgb(
                (yuv.y(), yuv.u(), yuv.v()),
                yuv.strides(),
                (w as usize, h as usize),
            );
            let mse: f64 = rgb
                .chunks(3)
                .zip(rgba.chunks(4))
                .map(|(a, b)| {
                    (0..3)
                        .map(|c| (f64::from(a[c]) - f64::from(b[c])).powi(2))
                        .sum::<f64>()
                })
                .sum::<f64>()
                / f64::from(w * h * 3);
            let psnr = 10.0 * (255.0f64 * 255.0 / mse.max(1e-9)).log10();
            assert!(psnr > 25.0, "frame {i}: PSNR {psnr:.1} dB");
        }
        assert!(keys[0] && keys[7], "{keys:?}");
        assert_eq!(keys.iter().filter(|k| **k).count(), 2, "{keys:?}");
    }
}
