//! The JSON text messages: what a client sends (hello, pose, configure) and what the
//! server answers (welcome, error).

use serde::{Deserialize, Serialize};

/// How a session's views are arranged in its frames.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Layout {
    /// One view fills the frame.
    #[default]
    Mono,
    /// Two eyes side by side (left eye on the left), each half the frame width.
    Stereo,
    /// 2 views side by side, or 3–4 views in a 2×2 grid (row-major; a 3-view frame leaves
    /// the bottom-right tile black), like local split-screen.
    Split,
}

impl Layout {
    /// Code of the layout in the frame header.
    pub fn code(self) -> u8 {
        match self {
            Layout::Mono => 0,
            Layout::Stereo => 1,
            Layout::Split => 2,
        }
    }

    /// The layout with header code `code`.
    pub fn from_code(code: u8) -> Option<Layout> {
        match code {
            0 => Some(Layout::Mono),
            1 => Some(Layout::Stereo),
            2 => Some(Layout::Split),
            _ => None,
        }
    }
}

/// How a session's frames are compressed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Codec {
    /// Every frame a baseline JPEG (the default).
    #[default]
    Jpeg,
    /// An H.264 stream (constrained baseline, Annex B): SPS/PPS and an IDR on key frames,
    /// P frames between them. Width and height must be even.
    H264,
}

impl Codec {
    /// Code of the codec in the frame header.
    pub fn code(self) -> u8 {
        match self {
            Codec::Jpeg => 0,
            Codec::H264 => 1,
        }
    }

    /// The codec's name as sent in JSON.
    pub fn as_str(self) -> &'static str {
        match self {
            Codec::Jpeg => "jpeg",
            Codec::H264 => "h264",
        }
    }
}

/// `{"type":"hello", ...}`: the first message of a session.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Hello {
    /// Protocol version; must be [`PROTOCOL_VERSION`](super::PROTOCOL_VERSION).
    pub version: u32,
    /// Frame width in pixels (the whole frame: both eyes, all tiles).
    pub width: u32,
    /// Frame height in pixels.
    pub height: u32,
    /// View arrangement (default `mono`).
    #[serde(default)]
    pub layout: Layout,
    /// Number of views: `split` only (2–4, default 2).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub views: Option<u32>,
    /// JPEG quality 1–100 (default: the server's).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub quality: Option<u8>,
    /// Stereo eye distance in metres (0–1, default 0.064).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub eye_distance_m: Option<f64>,
    /// Frame codec (default `jpeg`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub codec: Option<Codec>,
    /// Highest bitrate the client wants, kbit/s (default and ceiling: the server's
    /// `max_kbps`). The server adapts below it to what the client's link delivers.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_kbps: Option<u32>,
    /// Debugging (servers with `debug_raw_frames` only): every `raw_every`-th frame is
    /// also sent uncompressed, just before its encoded frame, to measure codec quality.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub raw_every: Option<u32>,
    /// Access token, when the server has one configured.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub token: Option<String>,
}

/// `{"type":"configure", ...}`: changes a running session; absent fields keep their value.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Configure {
    /// New frame width.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub width: Option<u32>,
    /// New frame height.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub height: Option<u32>,
    /// New layout.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub layout: Option<Layout>,
    /// New view count (`split`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub views: Option<u32>,
    /// New JPEG quality.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub quality: Option<u8>,
    /// New eye distance (`stereo`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub eye_distance_m: Option<f64>,
    /// New codec (a key frame follows).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub codec: Option<Codec>,
    /// New bitrate ceiling, kbit/s.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_kbps: Option<u32>,
}

/// `{"type":"ack", "frame": N}`: the client has received (and shown) every frame up to
/// server frame number `frame`. Optional; a client that acks gets flow control — the
/// server keeps only a short queue in flight to it and adapts its bitrate to what
/// arrives — instead of whatever the TCP buffers hold.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Ack {
    /// The header's `frame` of the newest frame received.
    pub frame: u32,
}

/// One camera: position, orientation and vertical field of view.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ViewPose {
    /// Eye position in scene coordinates, metres.
    pub position: [f64; 3],
    /// Unit quaternion `[x, y, z, w]` rotating the camera's −z (forward) into the view
    /// direction; roll is ignored (the renderer keeps +y up).
    pub orientation: [f64; 4],
    /// Vertical field of view, degrees.
    pub fov_y_deg: f64,
}

/// `{"type":"pose", ...}`: the latest camera(s) of a session.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PoseUpdate {
    /// Client sequence number, echoed in the header of the first frame rendered with it.
    pub seq: u32,
    /// One pose per view (`mono`: 1, `stereo`: 1 head pose, `split`: one per view).
    pub views: Vec<ViewPose>,
}

/// A message from a client.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum ClientMessage {
    /// Opens the session.
    Hello(Hello),
    /// New camera pose(s).
    Pose(PoseUpdate),
    /// Changes resolution, layout, quality or codec.
    Configure(Configure),
    /// Frames received (flow control).
    Ack(Ack),
    /// `{"type":"keyframe"}`: the client lost the stream (a decode error); the next
    /// H.264 frame is a key frame.
    Keyframe,
}

impl ClientMessage {
    /// The JSON text of the message.
    pub fn to_json(&self) -> String {
        serde_json::to_string(self).expect("client messages always serialise")
    }
}

/// Server limits a client should respect, sent in the welcome.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Limits {
    /// Largest text message, bytes.
    pub max_message_bytes: usize,
    /// Sustained messages per second before messages are dropped.
    pub max_messages_per_s: f64,
    /// Largest frame width.
    pub max_width: u32,
    /// Largest frame height.
    pub max_height: u32,
    /// Smallest view side, pixels.
    pub min_view_px: u32,
    /// Views the server renders in total.
    pub max_views: usize,
    /// Largest |coordinate| of a position, metres.
    pub max_coord_m: f64,
    /// Field of view range, degrees.
    pub fov_y_deg: [f64; 2],
    /// A session without a pose for this long is closed (`idle`); 0: never.
    #[serde(default)]
    pub idle_timeout_s: f64,
}

/// `{"type":"welcome", ...}`: the session's settings, sent after hello and after each configure.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Welcome {
    /// Session id (for logs).
    pub session: u64,
    /// Protocol version.
    pub version: u32,
    /// Scene name.
    pub scene: String,
    /// Layout.
    pub layout: Layout,
    /// Number of rendered views.
    pub views: u32,
    /// Frame width.
    pub width: u32,
    /// Frame height.
    pub height: u32,
    /// Width of one view.
    pub view_width: u32,
    /// Height of one view.
    pub view_height: u32,
    /// JPEG quality asked for (the ceiling: under congestion the server encodes lower and
    /// each frame's header says what it used).
    pub quality: u8,
    /// Stereo eye distance, metres.
    pub eye_distance_m: f64,
    /// Frame codec.
    #[serde(default)]
    pub codec: Codec,
    /// Bitrate ceiling in force, kbit/s (the client's `max_kbps` or the server's).
    #[serde(default)]
    pub max_kbps: u32,
    /// Why this welcome was sent.
    #[serde(default)]
    pub reason: WelcomeReason,
    /// The server's frame rate cap.
    pub fps: f64,
    /// Bytes of the binary frame header.
    pub header_bytes: usize,
    /// The poses in force (the scene's default viewpoints for a new session), in the
    /// shape a pose message takes.
    pub poses: Vec<ViewPose>,
    /// Limits.
    pub limits: Limits,
}

/// Why a welcome was sent.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum WelcomeReason {
    /// The answer to the hello.
    #[default]
    Hello,
    /// The answer to a configure.
    Configure,
    /// The server changed the frame size itself: the client's link did not carry the
    /// requested size at the lowest bitrate for several seconds (smaller), or carries it
    /// again (back to the requested size).
    Bandwidth,
}

/// What went wrong, as a stable machine-readable code.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ErrorCode {
    /// The text is not valid JSON.
    BadJson,
    /// Valid JSON, but not a message of this protocol (missing or mistyped fields).
    InvalidMessage,
    /// A `type` the server does not know.
    UnknownType,
    /// A text message over the size limit.
    MessageTooLarge,
    /// A binary message (clients send only text).
    BinaryNotSupported,
    /// The first message was not a hello.
    HelloRequired,
    /// No hello within the handshake timeout.
    HelloTimeout,
    /// A protocol version this server does not speak.
    UnsupportedVersion,
    /// A hello or configure with out-of-range values.
    InvalidHello,
    /// A pose with non-finite or out-of-range numbers, or the wrong number of views.
    InvalidPose,
    /// Missing or wrong token.
    Unauthorized,
    /// The server's view limit is reached.
    ServerFull,
    /// Too many messages per second.
    RateLimited,
    /// Too many invalid messages.
    TooManyErrors,
    /// The server is shutting down.
    ShuttingDown,
    /// Rendering this session's views failed on the server (the session is closed; the
    /// server and other sessions go on).
    RenderFailed,
    /// No frame reached the session within the server's frame timeout.
    NoFrames,
    /// The views asked for would exceed what the GPU can bind or the server's
    /// per-frame pixel budget; the message names the limit and the largest size that fits.
    OverBudget,
    /// The session sent no pose within the server's idle timeout.
    Idle,
}

impl ErrorCode {
    /// The code's name as sent in JSON.
    pub fn as_str(self) -> &'static str {
        match self {
            ErrorCode::BadJson => "bad_json",
            ErrorCode::InvalidMessage => "invalid_message",
            ErrorCode::UnknownType => "unknown_type",
            ErrorCode::MessageTooLarge => "message_too_large",
            ErrorCode::BinaryNotSupported => "binary_not_supported",
            ErrorCode::HelloRequired => "hello_required",
            ErrorCode::HelloTimeout => "hello_timeout",
            ErrorCode::UnsupportedVersion => "unsupported_version",
            ErrorCode::InvalidHello => "invalid_hello",
            ErrorCode::InvalidPose => "invalid_pose",
            ErrorCode::Unauthorized => "unauthorized",
            ErrorCode::ServerFull => "server_full",
            ErrorCode::RateLimited => "rate_limited",
            ErrorCode::TooManyErrors => "too_many_errors",
            ErrorCode::ShuttingDown => "shutting_down",
            ErrorCode::RenderFailed => "render_failed",
            ErrorCode::NoFrames => "no_frames",
            ErrorCode::OverBudget => "over_budget",
            ErrorCode::Idle => "idle",
        }
    }

    /// The WebSocket close code used when this error ends a session.
    pub fn close_code(self) -> u16 {
        match self {
            ErrorCode::BinaryNotSupported => 1003,
            ErrorCode::MessageTooLarge => 1009,
            ErrorCode::ServerFull => 1013,
            ErrorCode::ShuttingDown => 1001,
            ErrorCode::RenderFailed | ErrorCode::NoFrames => 1011,
            ErrorCode::OverBudget => 4413,
            ErrorCode::TooManyErrors => 1008,
            ErrorCode::Unauthorized => 4401,
            ErrorCode::HelloTimeout | ErrorCode::Idle => 4408,
            ErrorCode::RateLimited => 4429,
            ErrorCode::BadJson
            | ErrorCode::InvalidMessage
            | ErrorCode::UnknownType
            | ErrorCode::HelloRequired
            | ErrorCode::UnsupportedVersion
            | ErrorCode::InvalidHello
            | ErrorCode::InvalidPose => 4400,
        }
    }
}

/// `{"type":"error", ...}`: a rejected message; `fatal` errors are followed by a close frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ErrorMessage {
    /// Machine-readable code.
    pub code: ErrorCode,
    /// What was wrong and what to send instead.
    pub message: String,
    /// Whether the server closes the session after this message.
    pub fatal: bool,
}

/// A message from the server (text); frames are binary.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum ServerMessage {
    /// Session settings.
    Welcome(Welcome),
    /// A rejected message.
    Error(ErrorMessage),
}

impl ServerMessage {
    /// The JSON text of the message.
    pub fn to_json(&self) -> String {
        serde_json::to_string(self).expect("server messages always serialise")
    }
}

/// At most 64 characters of untrusted text: how error messages (the server's, and a
/// client's reports of what the server sent) quote it.
pub fn clip(s: &str) -> String {
    const MAX: usize = 64;
    if s.chars().count() <= MAX {
        s.to_string()
    } else {
        let mut out: String = s.chars().take(MAX).collect();
        out.push('…');
        out
    }
}
