//! What the server makes of client messages (`docs/protocol.md`): every text a client
//! sends is parsed here and turned into validated values ([`SessionSpec`],
//! [`CheckedPose`], cameras) or a [`ProtocolError`] that names the field, the value and
//! what to send instead. Nothing in this module panics on input.
//!
//! The wire types themselves are in [`crate::protocol`].

use crate::protocol::{
    clip, ClientMessage, Codec, Configure, ErrorCode, Hello, Layout, PoseUpdate, ViewPose,
    DEFAULT_EYE_DISTANCE_M, FOV_RANGE_DEG, MAX_COORD_M, MAX_EYE_DISTANCE_M, MAX_SPLIT_VIEWS,
    MIN_VIEW_PX,
};
use crate::scene::Camera;
use glam::{DQuat, DVec3, Vec3};

/// A rejected client message: the code and a sentence for the client.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{}: {message}", code.as_str())]
pub(crate) struct ProtocolError {
    /// Machine-readable code.
    pub(crate) code: ErrorCode,
    /// What was wrong and what to send instead.
    pub(crate) message: String,
}

impl ProtocolError {
    /// An error with `code` and `message`.
    pub(crate) fn new(code: ErrorCode, message: impl Into<String>) -> ProtocolError {
        ProtocolError {
            code,
            message: message.into(),
        }
    }
}

const MESSAGE_TYPES: [&str; 5] = ["hello", "pose", "configure", "ack", "keyframe"];

/// Parses one client text message, sorting failures into `bad_json`, `unknown_type` and
/// `invalid_message` (the size limit is checked by the caller, before parsing).
pub(crate) fn parse_client_message(text: &str) -> Result<ClientMessage, ProtocolError> {
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
                "missing \"type\" field (one of hello, pose, configure, ack, keyframe)",
            ))
        }
    };
    if !MESSAGE_TYPES.contains(&ty.as_str()) {
        return Err(ProtocolError::new(
            ErrorCode::UnknownType,
            format!(
                "unknown message type {:?}; expected one of hello, pose, configure, ack, keyframe",
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

/// The limits a hello is checked against.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct SpecLimits {
    /// Largest frame width.
    pub(crate) max_width: u32,
    /// Largest frame height.
    pub(crate) max_height: u32,
    /// Quality used when the client names none.
    pub(crate) default_quality: u8,
    /// Bitrate ceiling, kbit/s (a client may ask for less).
    pub(crate) max_kbps: u32,
    /// Lowest bitrate a client may ask for, kbit/s.
    pub(crate) min_kbps: u32,
    /// Whether `raw_every` is allowed.
    pub(crate) debug_raw_frames: bool,
}

/// A validated session: frame size, layout and how views tile the frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct SessionSpec {
    /// Layout.
    pub(crate) layout: Layout,
    /// Rendered views (mono 1, stereo 2, split 2–4).
    pub(crate) views: u32,
    /// Frame width.
    pub(crate) width: u32,
    /// Frame height.
    pub(crate) height: u32,
    /// Width of one view.
    pub(crate) view_width: u32,
    /// Height of one view.
    pub(crate) view_height: u32,
    /// JPEG quality 1–100.
    pub(crate) quality: u8,
    /// Stereo eye distance, metres.
    pub(crate) eye_distance_m: f64,
    /// Frame codec.
    pub(crate) codec: Codec,
    /// Bitrate ceiling, kbit/s.
    pub(crate) max_kbps: u32,
    /// Every `raw_every`-th frame also goes out raw (0: never; debugging).
    pub(crate) raw_every: u32,
}

impl SessionSpec {
    /// Checks a hello (or a configure merged onto a running spec).
    pub(crate) fn validate(
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
            codec: Codec::Jpeg,
            max_kbps: limits.max_kbps,
            raw_every: 0,
        })
    }

    /// This spec streamed with `codec` at most `max_kbps` (default: the server's), with
    /// raw copies every `raw_every` frames; checked against the frame size and limits.
    pub(crate) fn with_stream(
        mut self,
        codec: Codec,
        max_kbps: Option<u32>,
        raw_every: Option<u32>,
        limits: &SpecLimits,
    ) -> Result<SessionSpec, ProtocolError> {
        let bad = |m: String| Err(ProtocolError::new(ErrorCode::InvalidHello, m));
        if codec == Codec::H264 && (!self.width.is_multiple_of(2) || !self.height.is_multiple_of(2))
        {
            return bad(format!(
                "codec h264 with resolution {}x{}: H.264 (4:2:0) needs an even width and height",
                self.width, self.height
            ));
        }
        let max_kbps = max_kbps.unwrap_or(limits.max_kbps);
        if !(limits.min_kbps..=limits.max_kbps).contains(&max_kbps) {
            return bad(format!(
                "max_kbps {max_kbps}: must be {}..={} (the server's min_kbps..=max_kbps)",
                limits.min_kbps, limits.max_kbps
            ));
        }
        let raw_every = raw_every.unwrap_or(0);
        if raw_every != 0 && !limits.debug_raw_frames {
            return bad(format!(
                "raw_every {raw_every}: raw frames are off on this server (debug_raw_frames = false); omit it"
            ));
        }
        if raw_every > 1000 {
            return bad(format!("raw_every {raw_every}: must be 1..=1000"));
        }
        self.codec = codec;
        self.max_kbps = max_kbps;
        self.raw_every = raw_every;
        Ok(self)
    }

    /// Checks a hello's values (not its version or token).
    pub(crate) fn from_hello(h: &Hello, limits: &SpecLimits) -> Result<SessionSpec, ProtocolError> {
        SessionSpec::validate(
            h.width,
            h.height,
            h.layout,
            h.views,
            h.quality,
            h.eye_distance_m,
            limits,
        )?
        .with_stream(h.codec.unwrap_or_default(), h.max_kbps, h.raw_every, limits)
    }

    /// This spec changed by `c`. Changing the layout resets the view count to the new
    /// layout's default unless `c` names one.
    pub(crate) fn configure(
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
        )?
        .with_stream(
            c.codec.unwrap_or(self.codec),
            Some(c.max_kbps.unwrap_or(self.max_kbps)),
            Some(self.raw_every),
            limits,
        )
    }

    /// Poses a pose message must carry: stereo sends one head pose for both eyes.
    pub(crate) fn pose_count(&self) -> usize {
        match self.layout {
            Layout::Stereo => 1,
            _ => self.views as usize,
        }
    }

    /// Top-left pixel of view `i` in the frame.
    pub(crate) fn tile_origin(&self, i: usize) -> (u32, u32) {
        let cols = if self.layout == Layout::Mono { 1 } else { 2 };
        (
            (i as u32 % cols) * self.view_width,
            (i as u32 / cols) * self.view_height,
        )
    }
}

/// A validated pose: position, rotation, field of view.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct CheckedPose {
    /// Position in the scene file's coordinates (world space), metres.
    pub(crate) position: DVec3,
    /// Unit rotation.
    pub(crate) rotation: DQuat,
    /// Vertical field of view, radians.
    pub(crate) fov_y: f64,
}

impl CheckedPose {
    /// Validates `p` (view `i` of a pose message).
    pub(crate) fn new(p: &ViewPose, i: usize) -> Result<CheckedPose, ProtocolError> {
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

    /// The pose of a camera at `c` in a scene whose render space starts at world point
    /// `origin` (inverse of [`CheckedPose::camera`], roll-free).
    pub(crate) fn from_camera(c: &Camera, origin: DVec3) -> CheckedPose {
        CheckedPose {
            position: c.position.as_dvec3() + origin,
            rotation: c.orientation(),
            fov_y: c.fov_y as f64,
        }
    }

    /// The pose as sent on the wire.
    pub(crate) fn to_view_pose(self) -> ViewPose {
        ViewPose {
            position: self.position.to_array(),
            orientation: self.rotation.to_array(),
            fov_y_deg: self.fov_y.to_degrees(),
        }
    }

    /// A camera at this pose, moved `offset_m` along its right vector (stereo eyes), in
    /// the render space that starts at world point `origin` (the move is made in f64, so
    /// a scene far from the world origin keeps its precision).
    pub(crate) fn camera(&self, offset_m: f64, origin: DVec3) -> Camera {
        let right = self.rotation * DVec3::X;
        let pos = self.position + right * offset_m - origin;
        let forward = self.rotation * DVec3::NEG_Z;
        Camera::new(
            pos.as_vec3(),
            forward.as_vec3().try_normalize().unwrap_or(Vec3::NEG_Z),
            self.fov_y as f32,
        )
    }
}

/// Render-space cameras for every view of `spec` from the session's poses (stereo: 1
/// head → 2 eyes); `origin` is the world point where the scene's render space starts.
pub(crate) fn cameras_for(spec: &SessionSpec, poses: &[CheckedPose], origin: DVec3) -> Vec<Camera> {
    match spec.layout {
        Layout::Stereo => {
            let half = spec.eye_distance_m * 0.5;
            vec![
                poses[0].camera(-half, origin),
                poses[0].camera(half, origin),
            ]
        }
        _ => poses.iter().map(|p| p.camera(0.0, origin)).collect(),
    }
}

/// Validates a pose message against the session's spec.
pub(crate) fn check_pose(
    spec: &SessionSpec,
    p: &PoseUpdate,
) -> Result<Vec<CheckedPose>, ProtocolError> {
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

/// The server's default spec limits, for the validation's and the budget's unit tests.
#[cfg(test)]
pub(crate) const TEST_LIMITS: SpecLimits = SpecLimits {
    max_width: 1920,
    max_height: 1080,
    default_quality: 75,
    max_kbps: 8000,
    min_kbps: 150,
    debug_raw_frames: false,
};

#[cfg(test)]
mod tests {
    use super::*;

    const LIMITS: SpecLimits = TEST_LIMITS;

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
        // Poses are in world space; cameras in the render space that starts at `origin`
        // (a scene 10⁵ m out keeps its precision: the move is made in f64).
        let origin = DVec3::new(1.0e5, -4.0, 0.0);
        let pose = CheckedPose::from_camera(&cam, origin);
        assert_eq!(pose.position, DVec3::new(1.0e5 + 1.0, -2.0, 3.0));
        let back = pose.camera(0.0, origin);
        assert!(
            back.forward.distance(cam.forward) < 1e-5
                && back.position.distance(cam.position) < 1e-5
        );
        let spec =
            SessionSpec::validate(64, 32, Layout::Stereo, None, None, Some(0.5), &LIMITS).unwrap();
        let eyes = cameras_for(&spec, &[pose], origin);
        assert!((eyes[0].position.distance(eyes[1].position) - 0.5).abs() < 1e-5);
    }
}
