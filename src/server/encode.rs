//! Session frames: tile a session's views into one image, JPEG-encode it behind the
//! frame header. Runs on the encoder pool, never on the render thread.

use super::hub::{EncodedFrame, Hub, SessionShared};
use super::telemetry::DropReason;
use super::validate::SessionSpec;
use crate::protocol::{FrameHeader, FRAME_HEADER_BYTES};
use axum::body::Bytes;
use std::sync::atomic::Ordering::{Relaxed, Release};
use std::sync::Arc;
use std::time::Instant;

/// One session's views of one frame, waiting to be encoded.
pub(crate) struct EncodeJob {
    pub(crate) session: Arc<SessionShared>,
    pub(crate) spec: SessionSpec,
    /// One tightly packed RGBA8 image per view, `view_width`×`view_height`.
    pub(crate) images: Vec<Vec<u8>>,
    pub(crate) frame: u32,
    pub(crate) pose_seq: u32,
    pub(crate) render_us: u32,
}

impl EncodeJob {
    /// Encodes and publishes the frame, then frees the session's encoder flag.
    pub(crate) fn run(self, hub: &Hub) {
        let started = Instant::now();
        let result = encode(&self);
        let ms = started.elapsed().as_secs_f64() * 1e3;
        match result {
            Ok(bytes) => {
                hub.telemetry.encode_seconds.observe_ms(ms);
                hub.telemetry.frames_encoded.fetch_add(1, Relaxed);
                if self.session.slot.publish(EncodedFrame {
                    bytes,
                    spec: self.spec,
                }) {
                    self.session
                        .count_drop(&hub.telemetry, DropReason::ClientSlow);
                }
            }
            Err(e) => {
                tracing::error!(session = self.session.id, error = %e, "JPEG encoding failed")
            }
        }
        self.session.encoding.store(false, Release);
    }
}

/// Header + JPEG of the job's frame.
fn encode(job: &EncodeJob) -> anyhow::Result<Bytes> {
    let started = Instant::now();
    let s = &job.spec;
    let composed;
    let rgba: &[u8] = if job.images.len() == 1 && s.views == 1 {
        &job.images[0]
    } else {
        composed = compose(s, &job.images);
        &composed
    };
    let header = FrameHeader {
        layout: s.layout,
        views: s.views as u8,
        width: s.width as u16,
        height: s.height as u16,
        frame: job.frame,
        pose_seq: job.pose_seq,
        render_us: job.render_us,
        encode_us: 0,
        dropped: job.session.dropped.load(Relaxed).min(u32::MAX as u64) as u32,
    };
    // A 4:2:0 JPEG of a rendered frame is rarely above 1/4 of the raw bytes.
    let mut out = Vec::with_capacity(FRAME_HEADER_BYTES + rgba.len() / 4);
    header.write(&mut out);
    let encoder = jpeg_encoder::Encoder::new(&mut out, s.quality);
    encoder.encode(
        rgba,
        s.width as u16,
        s.height as u16,
        jpeg_encoder::ColorType::Rgba,
    )?;
    let encode_us = started.elapsed().as_micros().min(u32::MAX as u128) as u32;
    let o = FrameHeader::ENCODE_US_OFFSET;
    out[o..o + 4].copy_from_slice(&encode_us.to_le_bytes());
    Ok(Bytes::from(out))
}

/// The session's frame: views copied into their tiles (unused tiles stay black).
pub(crate) fn compose(s: &SessionSpec, images: &[Vec<u8>]) -> Vec<u8> {
    let (w, vw, vh) = (
        s.width as usize,
        s.view_width as usize,
        s.view_height as usize,
    );
    let mut frame = vec![0u8; w * s.height as usize * 4];
    for px in frame.chunks_exact_mut(4) {
        px[3] = 255;
    }
    for (i, img) in images.iter().enumerate() {
        let (x0, y0) = s.tile_origin(i);
        for row in 0..vh {
            let src = &img[row * vw * 4..(row + 1) * vw * 4];
            let dst = ((y0 as usize + row) * w + x0 as usize) * 4;
            frame[dst..dst + vw * 4].copy_from_slice(src);
        }
    }
    frame
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::protocol::Layout;
    use crate::server::validate::SpecLimits;

    #[test]
    fn split_views_land_in_their_tiles() {
        let limits = SpecLimits {
            max_width: 256,
            max_height: 256,
            default_quality: 80,
        };
        let s = SessionSpec::validate(32, 32, Layout::Split, Some(3), None, None, &limits).unwrap();
        let images: Vec<Vec<u8>> = (0..3u8)
            .map(|i| [10 * (i + 1), 0, 0, 255].repeat(16 * 16))
            .collect();
        let f = compose(&s, &images);
        let px = |x: usize, y: usize| f[(y * 32 + x) * 4];
        assert_eq!(
            (px(0, 0), px(16, 0), px(0, 16), px(16, 16)),
            (10, 20, 30, 0)
        );
        assert_eq!((px(15, 15), px(31, 15), px(15, 31)), (10, 20, 30));
    }
}
