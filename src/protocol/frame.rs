//! The binary frame: a fixed little-endian header, then the payload (one JPEG, one H.264
//! access unit, or — debugging only — the raw RGBA pixels).

use super::{Layout, FRAME_HEADER_BYTES, FRAME_MAGIC};

/// What follows a frame header.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrameCodec {
    /// One baseline JPEG.
    Jpeg,
    /// One H.264 access unit, Annex B (start codes); key frames carry SPS and PPS.
    H264,
    /// `width`×`height` RGBA8 pixels, row-major: the frame as rendered, before encoding
    /// (sent only to sessions that asked for `raw_every` on a `debug_raw_frames` server).
    Raw,
}

impl FrameCodec {
    /// Code in the header.
    pub fn code(self) -> u8 {
        match self {
            FrameCodec::Jpeg => 0,
            FrameCodec::H264 => 1,
            FrameCodec::Raw => 2,
        }
    }

    /// The codec with header code `code`.
    pub fn from_code(code: u8) -> Option<FrameCodec> {
        match code {
            0 => Some(FrameCodec::Jpeg),
            1 => Some(FrameCodec::H264),
            2 => Some(FrameCodec::Raw),
            _ => None,
        }
    }
}

/// The fixed header in front of every frame's payload (little-endian; see
/// `docs/protocol.md`).
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
    /// Encode time, microseconds.
    pub encode_us: u32,
    /// Frames dropped for this session so far (saturating).
    pub dropped: u32,
    /// What the payload is.
    pub codec: FrameCodec,
    /// A key frame: decodable on its own (every JPEG and raw frame; an H.264 IDR).
    pub key: bool,
    /// JPEG quality this frame was encoded at (0 for other codecs).
    pub quality: u8,
    /// The session's target bitrate when this frame was encoded, kbit/s.
    pub target_kbps: u32,
}

/// Bit 0 of the header's flags byte.
const FLAG_KEY: u8 = 1;

impl FrameHeader {
    /// Byte offset of `encode_us`, patched in after encoding.
    pub const ENCODE_US_OFFSET: usize = 24;

    /// Appends the header bytes to `out`.
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
        out.push(self.codec.code());
        out.push(if self.key { FLAG_KEY } else { 0 });
        out.push(self.quality);
        out.push(0);
        out.extend_from_slice(&self.target_kbps.to_le_bytes());
    }

    /// Splits a binary frame into its header and payload. A version-1 header of 32 bytes
    /// (no codec fields) reads as a JPEG key frame.
    pub fn parse(bytes: &[u8]) -> Option<(FrameHeader, &[u8])> {
        const V1_BYTES: usize = 32;
        if bytes.len() < V1_BYTES || bytes[..4] != FRAME_MAGIC {
            return None;
        }
        let u16_at = |o: usize| u16::from_le_bytes([bytes[o], bytes[o + 1]]);
        let u32_at =
            |o: usize| u32::from_le_bytes([bytes[o], bytes[o + 1], bytes[o + 2], bytes[o + 3]]);
        let header_len = u16_at(4) as usize;
        if header_len < V1_BYTES || header_len > bytes.len() {
            return None;
        }
        let extended = header_len >= FRAME_HEADER_BYTES;
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
            codec: if extended {
                FrameCodec::from_code(bytes[32])?
            } else {
                FrameCodec::Jpeg
            },
            key: !extended || bytes[33] & FLAG_KEY != 0,
            quality: if extended { bytes[34] } else { 0 },
            target_kbps: if extended { u32_at(36) } else { 0 },
        };
        Some((header, &bytes[header_len..]))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
            codec: FrameCodec::H264,
            key: false,
            quality: 0,
            target_kbps: 1500,
        };
        let mut out = Vec::new();
        h.write(&mut out);
        assert_eq!(out.len(), FRAME_HEADER_BYTES);
        out.extend_from_slice(b"h264");
        let (back, rest) = FrameHeader::parse(&out).unwrap();
        assert_eq!(back, h);
        assert_eq!(rest, b"h264");
        assert!(FrameHeader::parse(&out[..20]).is_none());
        // An unknown codec code is not a frame this client can show.
        out[32] = 9;
        assert!(FrameHeader::parse(&out).is_none());
    }

    #[test]
    fn a_version_1_header_reads_as_a_jpeg_key_frame() {
        let mut out = Vec::new();
        FrameHeader {
            layout: Layout::Mono,
            views: 1,
            width: 64,
            height: 36,
            frame: 1,
            pose_seq: 0,
            render_us: 0,
            encode_us: 0,
            dropped: 0,
            codec: FrameCodec::H264,
            key: false,
            quality: 0,
            target_kbps: 0,
        }
        .write(&mut out);
        out.truncate(32);
        out[4..6].copy_from_slice(&32u16.to_le_bytes());
        out.extend_from_slice(b"jpeg");
        let (h, rest) = FrameHeader::parse(&out).unwrap();
        assert_eq!(
            (h.codec, h.key, rest),
            (FrameCodec::Jpeg, true, &b"jpeg"[..])
        );
    }
}
