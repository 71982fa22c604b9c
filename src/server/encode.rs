//! Session frames: JPEG-encode a session's frame (its views already tiled into it by the
//! renderer's composite) behind the frame header. Runs on the encoder pool, never on the
//! render thread.

use super::hub::{EncodedFrame, Hub, SessionShared};
use super::telemetry::DropReason;
use super::validate::SessionSpec;
use crate::protocol::{FrameHeader, FRAME_HEADER_BYTES};
use axum::body::Bytes;
use std::sync::atomic::Ordering::{Relaxed, Release};
use std::sync::Arc;
use std::time::Instant;

/// One session's frame, waiting to be encoded.
pub(crate) struct EncodeJob {
    pub(crate) session: Arc<SessionShared>,
    pub(crate) spec: SessionSpec,
    /// The tightly packed RGBA8 frame, `width`×`height`, every view in its tile.
    pub(crate) image: Vec<u8>,
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
    let rgba: &[u8] = &job.image;
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
        codec: crate::protocol::FrameCodec::Jpeg,
        key: true,
        quality: s.quality,
        target_kbps: 0,
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
