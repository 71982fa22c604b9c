//! The binary frame: a fixed little-endian header, then one JPEG.

use super::{Layout, FRAME_HEADER_BYTES, FRAME_MAGIC};

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
}
