//! The viewer protocol (`docs/protocol.md`): JSON text messages both ways, binary frames
//! from the server with a fixed 32-byte header followed by one JPEG.
//!
//! Everything a client sends is parsed here and turned into validated values
//! ([`SessionSpec`], cameras) or a [`ProtocolError`] that names the field, the value and
//! what to send instead. Nothing in this module panics on input.

use crate::scene::Camera;
use glam::{DQuat, DVec3, Vec3};
use serde::{Deserialize, Serialize};

/// Version a client names in its hello.
pub const PROTOCOL_VERSION: u32 = 1;
/// First four bytes of every binary frame.
pub const FRAME_MAGIC: [u8; 4] = *b"FCF1";
/// Bytes of the binary frame header; the JPEG starts right after it.
pub const FRAME_HEADER_BYTES: usize = 32;
/// Largest |coordinate| of a viewer position, metres.
pub const MAX_COORD_M: f64 = 1.0e5;
/// Vertical field of view range, degrees.
pub const FOV_RANGE_DEG: (f64, f64) = (1.0, 170.0);
/// Smallest view (one eye, one split tile), pixels per side.
pub const MIN_VIEW_PX: u32 = 16;
/// Largest stereo eye distance, metres.
pub const MAX_EYE_DISTANCE_M: f64 = 1.0;
/// Default stereo eye distance (a typical adult interpupillary distance), metres.
pub const DEFAULT_EYE_DISTANCE_M: f64 = 0.064;
/// Most views one split-screen session may have.
pub const MAX_SPLIT_VIEWS: u32 = 4;

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

/// `{"type":"hello", ...}`: the first message of a session.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Hello {
    /// Protocol version; must be [`PROTOCOL_VERSION`].
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
    /// Changes resolution, layout or quality.
    Configure(Configure),
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
    /// JPEG quality.
    pub quality: u8,
    /// Stereo eye distance, metres.
    pub eye_distance_m: f64,
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
            ErrorCode::HelloTimeout => 4408,
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

/// A rejected client message: the code and a sentence for the client.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{}: {message}", code.as_str())]
pub struct ProtocolError {
    /// Machine-readable code.
    pub code: ErrorCode,
    /// What was wrong and what to send instead.
    pub message: String,
}

impl ProtocolError {
    /// An error with `code` and `message`.
    pub fn new(code: ErrorCode, message: impl Into<String>) -> ProtocolError {
        ProtocolError {
            code,
            message: message.into(),
        }
    }
}

const MESSAGE_TYPES: [&str; 3] = ["hello", "pose", "configure"];

/// Parses one client text message, sorting failures into `bad_json`, `unknown_type` and
/// `invalid_message` (the size limit is checked by the caller, before parsing).
pub fn parse_client_message(text: &str) -> Result<ClientMessage, ProtocolError> {
    // Syntax first (any JSON value), then shape: so "not JSON" and "not our message"
    // get different codes.
    let value: serde_json::Value = serde_json::from_str(text).map_err(|e| {
        ProtocolError::new(
            ErrorCode::BadJson,
            format!("not valid JSON ({e}); NaN and Infinity are not JSON numbers"),
        )
    })?;
    let Some(object) = value.as_object() else {
        return Err(ProtocolError::new(
            ErrorCode::InvalidMessage,
            format!(
                "expected a JSON object with a \"type\" field, got {}",
                clip(&value.to_string())
            ),
        ));
    };
    let ty = match object.get("type") {
        Some(serde_json::Value::String(s)) => s.clone(),
        Some(other) => {
            return Err(ProtocolError::new(
                ErrorCode::InvalidMessage,
                format!(
                    "\"type\" must be a string, got {}",
                    clip(&other.to_string())
                ),
            ))
        }
        None => {
            return Err(ProtocolError::new(
                ErrorCode::InvalidMessage,
                "missing \"type\" field (one of hello, pose, configure)",
            ))
        }
    };
    if !MESSAGE_TYPES.contains(&ty.as_str()) {
        return Err(ProtocolError::new(
            ErrorCode::UnknownType,
            format!(
                "unknown message type {:?}; expected one of hello, pose, configure",
                clip(&ty)
            ),
        ));
    }
    serde_json::from_value(value).map_err(|e| {
        ProtocolError::new(
            ErrorCode::InvalidMessage,
            format!("invalid {ty} message: {e}"),
        )
    })
}

/// At most 64 characters of untrusted text, for error messages.
pub(crate) fn clip(s: &str) -> String {
    const MAX: usize = 64;
    if s.chars().count() <= MAX {
        s.to_string()
    } else {
        let mut out: String = s.chars().take(MAX).collect();
        out.push('…');
        out
    }
}

/// The limits a hello is checked against.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SpecLimits {
    /// Largest frame width.
    pub max_width: u32,
    /// Largest frame height.
    pub max_height: u32,
    /// Quality used when the client names none.
    pub default_quality: u8,
}

/// A validated session: frame size, layout and how views tile the frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SessionSpec {
    /// Layout.
    pub layout: Layout,
    /// Rendered views (mono 1, stereo 2, split 2–4).
    pub views: u32,
    /// Frame width.
    pub width: u32,
    /// Frame height.
    pub height: u32,
    /// Width of one view.
    pub view_width: u32,
    /// Height of one view.
    pub view_height: u32,
    /// JPEG quality 1–100.
    pub quality: u8,
    /// Stereo eye distance, metres.
    pub eye_distance_m: f64,
}

impl SessionSpec {
    /// Checks a hello (or a configure merged onto a running spec).
    pub fn validate(
        width: u32,
        height: u32,
        layout: Layout,
        views: Option<u32>,
        quality: Option<u8>,
        eye_distance_m: Option<f64>,
        limits: &SpecLimits,
    ) -> Result<SessionSpec, ProtocolError> {
        let bad = |m: String| Err(ProtocolError::new(ErrorCode::InvalidHello, m));
        let views = match (layout, views) {
            (Layout::Mono, None | Some(1)) => 1,
            (Layout::Stereo, None | Some(2)) => 2,
            (Layout::Split, None) => 2,
            (Layout::Split, Some(n)) if (2..=MAX_SPLIT_VIEWS).contains(&n) => n,
            (Layout::Split, Some(n)) => {
                return bad(format!(
                    "split layout with {n} views: must be 2 to {MAX_SPLIT_VIEWS}"
                ))
            }
            (l, Some(n)) => {
                return bad(format!(
                    "{l:?} layout with {n} views: mono has 1 view and stereo 2; omit \"views\""
                )
                .to_lowercase())
            }
        };
        if !(1..=limits.max_width).contains(&width) || !(1..=limits.max_height).contains(&height) {
            return bad(format!(
                "resolution {width}x{height} out of bounds: width must be {}..={}, height {}..={}",
                MIN_VIEW_PX, limits.max_width, MIN_VIEW_PX, limits.max_height
            ));
        }
        let (cols, rows) = match (layout, views) {
            (Layout::Mono, _) => (1, 1),
            (Layout::Stereo, _) | (Layout::Split, 2) => (2, 1),
            _ => (2, 2),
        };
        if !width.is_multiple_of(cols) || !height.is_multiple_of(rows) {
            return bad(format!("resolution {width}x{height} does not split into {cols}x{rows} equal tiles: use a width divisible by {cols} and a height divisible by {rows}"));
        }
        let (view_width, view_height) = (width / cols, height / rows);
        if view_width < MIN_VIEW_PX || view_height < MIN_VIEW_PX {
            return bad(format!("resolution {width}x{height} gives {view_width}x{view_height} views: each view needs at least {MIN_VIEW_PX} pixels per side"));
        }
        let quality = quality.unwrap_or(limits.default_quality);
        if !(1..=100).contains(&quality) {
            return bad(format!("quality {quality}: must be 1..=100"));
        }
        let eye_distance_m = eye_distance_m.unwrap_or(DEFAULT_EYE_DISTANCE_M);
        if !(eye_distance_m.is_finite() && (0.0..=MAX_EYE_DISTANCE_M).contains(&eye_distance_m)) {
            return bad(format!(
                "eye_distance_m {eye_distance_m}: must be 0..={MAX_EYE_DISTANCE_M} metres"
            ));
        }
        Ok(SessionSpec {
            layout,
            views,
            width,
            height,
            view_width,
            view_height,
            quality,
            eye_distance_m,
        })
    }

    /// Checks a hello's values (not its version or token).
    pub fn from_hello(h: &Hello, limits: &SpecLimits) -> Result<SessionSpec, ProtocolError> {
        SessionSpec::validate(
            h.width,
            h.height,
            h.layout,
            h.views,
            h.quality,
            h.eye_distance_m,
            limits,
        )
    }

    /// This spec changed by `c`. Changing the layout resets the view count to the new
    /// layout's default unless `c` names one.
    pub fn configure(
        &self,
        c: &Configure,
        limits: &SpecLimits,
    ) -> Result<SessionSpec, ProtocolError> {
        let layout = c.layout.unwrap_or(self.layout);
        let views = c
            .views
            .or((layout == self.layout && layout == Layout::Split).then_some(self.views));
        SessionSpec::validate(
            c.width.unwrap_or(self.width),
            c.height.unwrap_or(self.height),
            layout,
            views,
            Some(c.quality.unwrap_or(self.quality)),
            Some(c.eye_distance_m.unwrap_or(self.eye_distance_m)),
            limits,
        )
    }

    /// Poses a pose message must carry: stereo sends one head pose for both eyes.
    pub fn pose_count(&self) -> usize {
        match self.layout {
            Layout::Stereo => 1,
            _ => self.views as usize,
        }
    }

    /// Top-left pixel of view `i` in the frame.
    pub fn tile_origin(&self, i: usize) -> (u32, u32) {
        let cols = if self.layout == Layout::Mono { 1 } else { 2 };
        (
            (i as u32 % cols) * self.view_width,
            (i as u32 / cols) * self.view_height,
        )
    }
}

/// A validated pose: position, rotation, field of view.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CheckedPose {
    /// Position, metres.
    pub position: DVec3,
    /// Unit rotation.
    pub rotation: DQuat,
    /// Vertical field of view, radians.
    pub fov_y: f64,
}

impl CheckedPose {
    /// Validates `p` (view `i` of a pose message).
    pub fn new(p: &ViewPose, i: usize) -> Result<CheckedPose, ProtocolError> {
        let bad = |m: String| {
            Err(ProtocolError::new(
                ErrorCode::InvalidPose,
                format!("views[{i}].{m}"),
            ))
        };
        let pos = DVec3::from_array(p.position);
        if !pos.is_finite() || pos.abs().max_element() > MAX_COORD_M {
            return bad(format!(
                "position {:?}: each coordinate must be finite and within ±{MAX_COORD_M} m",
                p.position
            ));
        }
        let [x, y, z, w] = p.orientation;
        let q = DQuat::from_xyzw(x, y, z, w);
        if !q.is_finite() {
            return bad(format!(
                "orientation {:?}: must be four finite numbers [x, y, z, w]",
                p.orientation
            ));
        }
        let len = q.length();
        if !(1e-3..=1e3).contains(&len) {
            return bad(format!("orientation {:?}: length {len:e} is not a rotation; send a unit quaternion [x, y, z, w]", p.orientation));
        }
        let (lo, hi) = FOV_RANGE_DEG;
        if !(p.fov_y_deg.is_finite() && (lo..=hi).contains(&p.fov_y_deg)) {
            return bad(format!(
                "fov_y_deg {}: must be {lo}..={hi} degrees",
                p.fov_y_deg
            ));
        }
        Ok(CheckedPose {
            position: pos,
            rotation: q / len,
            fov_y: p.fov_y_deg.to_radians(),
        })
    }

    /// The pose seen by a camera at `c` (inverse of [`CheckedPose::camera`], roll-free).
    pub fn from_camera(c: &Camera) -> CheckedPose {
        let f = c.forward.as_dvec3().normalize();
        let up = c.up().as_dvec3();
        let right = f.cross(up).normalize();
        let up = right.cross(f);
        let rotation = DQuat::from_mat3(&glam::DMat3::from_cols(right, up, -f)).normalize();
        CheckedPose {
            position: c.position.as_dvec3(),
            rotation,
            fov_y: c.fov_y as f64,
        }
    }

    /// The pose as sent on the wire.
    pub fn to_view_pose(&self) -> ViewPose {
        ViewPose {
            position: self.position.to_array(),
            orientation: self.rotation.to_array(),
            fov_y_deg: self.fov_y.to_degrees(),
        }
    }

    /// A camera at this pose, moved `offset_m` along its right vector (stereo eyes).
    pub fn camera(&self, offset_m: f64) -> Camera {
        let right = self.rotation * DVec3::X;
        let pos = self.position + right * offset_m;
        let forward = self.rotation * DVec3::NEG_Z;
        Camera::new(
            pos.as_vec3(),
            forward.as_vec3().try_normalize().unwrap_or(Vec3::NEG_Z),
            self.fov_y as f32,
        )
    }
}

/// Cameras for every view of `spec` from the session's poses (stereo: 1 head → 2 eyes).
pub fn cameras_for(spec: &SessionSpec, poses: &[CheckedPose]) -> Vec<Camera> {
    match spec.layout {
        Layout::Stereo => {
            let half = spec.eye_distance_m * 0.5;
            vec![poses[0].camera(-half), poses[0].camera(half)]
        }
        _ => poses.iter().map(|p| p.camera(0.0)).collect(),
    }
}

/// Validates a pose message against the session's spec.
pub fn check_pose(spec: &SessionSpec, p: &PoseUpdate) -> Result<Vec<CheckedPose>, ProtocolError> {
    let want = spec.pose_count();
    if p.views.len() != want {
        let what = match spec.layout {
            Layout::Stereo => "a stereo session sends 1 head pose".to_string(),
            _ => format!("this session has {want} view(s)"),
        };
        return Err(ProtocolError::new(
            ErrorCode::InvalidPose,
            format!("pose has {} views but {what}", p.views.len()),
        ));
    }
    p.views
        .iter()
        .enumerate()
        .map(|(i, v)| CheckedPose::new(v, i))
        .collect()
}

/// The fixed header in front of every frame's JPEG (little-endian; see `docs/protocol.md`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FrameHeader {
    /// Layout of the frame.
    pub layout: Layout,
    /// Number of views in the frame.
    pub views: u8,
    /// Frame width, pixels.
    pub width: u16,
    /// Frame height, pixels.
    pub height: u16,
    /// Server frame number (one per render-loop iteration).
    pub frame: u32,
    /// Sequence number of the last pose applied before this frame was rendered (0: none yet).
    pub pose_seq: u32,
    /// Host time of the render call that made the views, microseconds.
    pub render_us: u32,
    /// JPEG encode time, microseconds.
    pub encode_us: u32,
    /// Frames dropped for this session so far (saturating).
    pub dropped: u32,
}

impl FrameHeader {
    /// Byte offset of `encode_us`, patched in after encoding.
    pub const ENCODE_US_OFFSET: usize = 24;

    /// Appends the 32 header bytes to `out`.
    pub fn write(&self, out: &mut Vec<u8>) {
        out.extend_from_slice(&FRAME_MAGIC);
        out.extend_from_slice(&(FRAME_HEADER_BYTES as u16).to_le_bytes());
        out.push(self.layout.code());
        out.push(self.views);
        out.extend_from_slice(&self.width.to_le_bytes());
        out.extend_from_slice(&self.height.to_le_bytes());
        out.extend_from_slice(&self.frame.to_le_bytes());
        out.extend_from_slice(&self.pose_seq.to_le_bytes());
        out.extend_from_slice(&self.render_us.to_le_bytes());
        out.extend_from_slice(&self.encode_us.to_le_bytes());
        out.extend_from_slice(&self.dropped.to_le_bytes());
    }

    /// Splits a binary frame into its header and JPEG bytes.
    pub fn parse(bytes: &[u8]) -> Option<(FrameHeader, &[u8])> {
        if bytes.len() < FRAME_HEADER_BYTES || bytes[..4] != FRAME_MAGIC {
            return None;
        }
        let u16_at = |o: usize| u16::from_le_bytes([bytes[o], bytes[o + 1]]);
        let u32_at =
            |o: usize| u32::from_le_bytes([bytes[o], bytes[o + 1], bytes[o + 2], bytes[o + 3]]);
        let header_len = u16_at(4) as usize;
        if header_len < FRAME_HEADER_BYTES || header_len > bytes.len() {
            return None;
        }
        let header = FrameHeader {
            layout: Layout::from_code(bytes[6])?,
            views: bytes[7],
            width: u16_at(8),
            height: u16_at(10),
            frame: u32_at(12),
            pose_seq: u32_at(16),
            render_us: u32_at(20),
            encode_us: u32_at(24),
            dropped: u32_at(28),
        };
        Some((header, &bytes[header_len..]))
    }
}

/// The server's default spec limits, for the protocol's and the budget's unit tests.
#[cfg(test)]
pub(crate) const TEST_LIMITS: SpecLimits = SpecLimits {
    max_width: 1920,
    max_height: 1080,
    default_quality: 75,
};

#[cfg(test)]
mod tests {
    use super::*;

    const LIMITS: SpecLimits = TEST_LIMITS;

    #[test]
    fn header_round_trips() {
        let h = FrameHeader {
            layout: Layout::Split,
            views: 3,
            width: 640,
            height: 360,
            frame: 7,
            pose_seq: 42,
            render_us: 1234,
            encode_us: 99,
            dropped: 5,
        };
        let mut out = Vec::new();
        h.write(&mut out);
        assert_eq!(out.len(), FRAME_HEADER_BYTES);
        out.extend_from_slice(b"jpeg");
        let (back, rest) = FrameHeader::parse(&out).unwrap();
        assert_eq!(back, h);
        assert_eq!(rest, b"jpeg");
        assert!(FrameHeader::parse(&out[..20]).is_none());
    }

    #[test]
    fn messages_sort_into_codes() {
        let code = |t: &str| parse_client_message(t).unwrap_err().code;
        assert_eq!(code("{"), ErrorCode::BadJson);
        assert_eq!(
            code("{\"type\":\"pose\",\"seq\":1,\"views\":[NaN]}"),
            ErrorCode::BadJson
        );
        assert_eq!(code("[1,2]"), ErrorCode::InvalidMessage);
        assert_eq!(code("{\"seq\":1}"), ErrorCode::InvalidMessage);
        assert_eq!(code("{\"type\":\"dance\"}"), ErrorCode::UnknownType);
        assert_eq!(
            code("{\"type\":\"hello\",\"version\":1,\"width\":64}"),
            ErrorCode::InvalidMessage
        );
        assert_eq!(
            code("{\"type\":\"hello\",\"version\":1,\"width\":64,\"height\":36,\"extra\":1}"),
            ErrorCode::InvalidMessage
        );
        let ok = parse_client_message(
            "{\"type\":\"hello\",\"version\":1,\"width\":64,\"height\":36,\"layout\":\"stereo\"}",
        )
        .unwrap();
        assert!(matches!(
            ok,
            ClientMessage::Hello(Hello {
                layout: Layout::Stereo,
                ..
            })
        ));
    }

    #[test]
    fn specs_tile_the_frame() {
        let s =
            SessionSpec::validate(128, 72, Layout::Split, Some(4), None, None, &LIMITS).unwrap();
        assert_eq!((s.view_width, s.view_height, s.quality), (64, 36, 75));
        assert_eq!(s.tile_origin(3), (64, 36));
        let st = SessionSpec::validate(128, 36, Layout::Stereo, None, Some(90), Some(0.1), &LIMITS)
            .unwrap();
        assert_eq!((st.views, st.view_width, st.pose_count()), (2, 64, 1));
        for (w, h, l, v) in [
            (0, 36, Layout::Mono, None),
            (99999, 36, Layout::Mono, None),
            (65, 36, Layout::Stereo, None),
            (64, 36, Layout::Split, Some(5)),
            (16, 8, Layout::Mono, None),
        ] {
            assert_eq!(
                SessionSpec::validate(w, h, l, v, None, None, &LIMITS)
                    .unwrap_err()
                    .code,
                ErrorCode::InvalidHello,
                "{w}x{h} {l:?} {v:?}"
            );
        }
        assert!(
            SessionSpec::validate(64, 36, Layout::Stereo, None, None, Some(f64::NAN), &LIMITS)
                .is_err()
        );
    }

    #[test]
    fn poses_are_checked_and_round_trip() {
        let good = ViewPose {
            position: [1.0, 2.0, 3.0],
            orientation: [0.0, 0.0, 0.0, 2.0],
            fov_y_deg: 60.0,
        };
        let p = CheckedPose::new(&good, 0).unwrap();
        assert!((p.rotation.length() - 1.0).abs() < 1e-12);
        for bad in [
            ViewPose {
                orientation: [0.0; 4],
                ..good
            },
            ViewPose {
                position: [f64::INFINITY, 0.0, 0.0],
                ..good
            },
            ViewPose {
                position: [1e39, 0.0, 0.0],
                ..good
            },
            ViewPose {
                fov_y_deg: 0.0,
                ..good
            },
            ViewPose {
                fov_y_deg: 500.0,
                ..good
            },
            ViewPose {
                orientation: [1e300, 1e300, 0.0, 0.0],
                ..good
            },
        ] {
            assert_eq!(
                CheckedPose::new(&bad, 0).unwrap_err().code,
                ErrorCode::InvalidPose,
                "{bad:?}"
            );
        }
        let cam = Camera::new(Vec3::new(1.0, 2.0, 3.0), Vec3::new(0.3, -0.2, -1.0), 1.0);
        let back = CheckedPose::from_camera(&cam).camera(0.0);
        assert!(
            back.forward.distance(cam.forward) < 1e-5
                && back.position.distance(cam.position) < 1e-5
        );
        let spec =
            SessionSpec::validate(64, 32, Layout::Stereo, None, None, Some(0.5), &LIMITS).unwrap();
        let eyes = cameras_for(&spec, &[CheckedPose::from_camera(&cam)]);
        assert!((eyes[0].position.distance(eyes[1].position) - 0.5).abs() < 1e-5);
    }
}
