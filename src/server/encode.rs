//! Session frames: encode a session's frame (its views already tiled into it by the
//! renderer's composite) behind the frame header — a JPEG, or the next access unit of the
//! session's H.264 stream — plus, for sessions that asked for `raw_every`, a raw copy.
//! Runs on the encoder pool, never on the render thread.

use super::hub::{EncodedFrame, Hub, SessionShared};
use super::stream::H264Stream;
use super::telemetry::DropReason;
use super::validate::SessionSpec;
use crate::protocol::{Codec, FrameCodec, FrameHeader, FRAME_HEADER_BYTES};
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
        let result = self.encode(hub);
        let ms = started.elapsed().as_secs_f64() * 1e3;
        match result {
            Ok(None) => {
                // The H.264 rate control skipped the frame: the bitrate is spent.
                self.session
                    .count_drop(&hub.telemetry, DropReason::RateControl);
            }
            Ok(Some(frame)) => {
                hub.telemetry.encode_seconds.observe_ms(ms);
                if self.session.slot.publish(frame) {
                    self.session
                        .count_drop(&hub.telemetry, DropReason::ClientSlow);
                    self.session.stream.skipped.fetch_add(1, Relaxed);
                    if self.spec.codec == Codec::H264 {
                        // The replaced access unit never reaches the decoder: start over.
                        self.session.stream.key_request.store(true, Relaxed);
                    }
                }
            }
            Err(e) => {
                tracing::error!(session = self.session.id, codec = self.spec.codec.as_str(), error = %e, "encoding failed");
                // A stream that failed mid-way restarts with a key frame.
                *self
                    .session
                    .stream
                    .h264
                    .lock()
                    .unwrap_or_else(|e| e.into_inner()) = None;
            }
        }
        self.session.encoding.store(false, Release);
    }

    fn header(&self, codec: FrameCodec, key: bool, quality: u8, target_kbps: u32) -> FrameHeader {
        let s = &self.spec;
        FrameHeader {
            layout: s.layout,
            views: s.views as u8,
            width: s.width as u16,
            height: s.height as u16,
            frame: self.frame,
            pose_seq: self.pose_seq,
            render_us: self.render_us,
            encode_us: 0,
            dropped: self.session.dropped.load(Relaxed).min(u32::MAX as u64) as u32,
            codec,
            key,
            quality,
            target_kbps,
        }
    }

    /// Header + payload of the job's frame, and its raw copy when due.
    fn encode(&self, hub: &Hub) -> anyhow::Result<Option<EncodedFrame>> {
        let started = Instant::now();
        let stream = &self.session.stream;
        let target_kbps = stream.target_kbps.load(Relaxed);
        // A 4:2:0 JPEG of a rendered frame is rarely above 1/4 of the raw bytes.
        let mut out = Vec::with_capacity(FRAME_HEADER_BYTES + self.image.len() / 4);
        match self.spec.codec {
            Codec::Jpeg => {
                let quality = stream.jpeg_quality.load(Relaxed).min(self.spec.quality);
                self.header(FrameCodec::Jpeg, true, quality, target_kbps)
                    .write(&mut out);
                jpeg_encoder::Encoder::new(&mut out, quality).encode(
                    &self.image,
                    self.spec.width as u16,
                    self.spec.height as u16,
                    jpeg_encoder::ColorType::Rgba,
                )?;
                hub.telemetry.frames_jpeg.fetch_add(1, Relaxed);
            }
            Codec::H264 => {
                let Some(au) = self.encode_h264(hub, target_kbps)? else {
                    return Ok(None);
                };
                self.header(FrameCodec::H264, au.key, 0, target_kbps)
                    .write(&mut out);
                out.extend_from_slice(&au.bytes);
                hub.telemetry.frames_h264.fetch_add(1, Relaxed);
                if au.key {
                    hub.telemetry.key_frames.fetch_add(1, Relaxed);
                }
            }
        }
        let encode_us = started.elapsed().as_micros().min(u32::MAX as u128) as u32;
        let o = FrameHeader::ENCODE_US_OFFSET;
        out[o..o + 4].copy_from_slice(&encode_us.to_le_bytes());
        let raw = (self.spec.raw_every > 0 && self.frame.is_multiple_of(self.spec.raw_every)).then(
            || {
                let mut raw = Vec::with_capacity(FRAME_HEADER_BYTES + self.image.len());
                self.header(FrameCodec::Raw, true, 0, target_kbps)
                    .write(&mut raw);
                raw.extend_from_slice(&self.image);
                Bytes::from(raw)
            },
        );
        Ok(Some(EncodedFrame {
            bytes: Bytes::from(out),
            frame: self.frame,
            raw,
            spec: self.spec,
        }))
    }

    /// The next access unit of the session's stream (a new stream — and a key frame —
    /// when there is none or the frame size changed).
    fn encode_h264(
        &self,
        hub: &Hub,
        kbps: u32,
    ) -> anyhow::Result<Option<super::stream::AccessUnit>> {
        let stream = &self.session.stream;
        let mut h264 = stream.h264.lock().unwrap_or_else(|e| e.into_inner());
        let size = (self.spec.width, self.spec.height);
        let encoder = match &mut *h264 {
            Some(s) if s.size() == size => s,
            slot => slot.insert(H264Stream::new(size.0, size.1, kbps, hub.config.fps)?),
        };
        let force_key = stream.key_request.swap(false, Relaxed);
        let time_ms = hub.started.elapsed().as_millis() as u64;
        let au = encoder.encode(&self.image, kbps, force_key, hub.config.gop_frames, time_ms)?;
        if au.is_none() && force_key {
            // The skipped frame was to be the key frame: the next one is.
            stream.key_request.store(true, Relaxed);
        }
        Ok(au)
    }
}
