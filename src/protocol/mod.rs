//! The viewer protocol's wire types (`docs/protocol.md`): JSON text messages both ways
//! ([`messages`]) and binary frames from the server, a fixed 40-byte header followed by
//! one JPEG or one H.264 access unit ([`frame`]).
//!
//! This module is what a client needs to speak to `fogcast serve` and nothing more: it
//! depends on neither the scene nor the server. The server parses and validates what
//! clients send in `server::validate`; `fogcast loadgen`, an outside client, uses only
//! these types.

mod color;
mod frame;
mod messages;

pub use color::{rgba_to_i420, yuv420_to_rgb};
pub use frame::{FrameCodec, FrameHeader};
pub use messages::{
    clip, Ack, ClientMessage, Codec, Configure, ErrorCode, ErrorMessage, Hello, Layout, Limits,
    PoseUpdate, ServerMessage, ViewPose, Welcome, WelcomeReason,
};

/// Version a client names in its hello.
pub const PROTOCOL_VERSION: u32 = 1;
/// First four bytes of every binary frame.
pub const FRAME_MAGIC: [u8; 4] = *b"FCF1";
/// Bytes of the binary frame header; the payload starts right after it. (32 before the
/// codec fields were added; clients skip `header_len` bytes, so both parse.)
pub const FRAME_HEADER_BYTES: usize = 40;
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
