//! Image quality of the encoded stream (`--raw-every`): each viewer decodes its encoded
//! frames (JPEG with `image`, H.264 with one OpenH264 decoder per stream) and compares
//! the picture with the raw RGBA frame the server sent just before it, by PSNR.

use crate::protocol::{FrameCodec, FrameHeader};
use anyhow::Context as _;

/// PSNR reported for two identical pictures (the formula gives +∞, which JSON cannot
/// carry), dB.
pub const PSNR_CAP_DB: f64 = 100.0;

/// Peak signal-to-noise ratio of 8-bit RGB `decoded` against 8-bit RGBA `raw` (alpha
/// ignored): 10·log10(255² / MSE), MSE over every pixel's R, G and B; identical
/// pictures give [`PSNR_CAP_DB`]. `None` when the two are not the same number of pixels.
pub fn psnr(decoded_rgb: &[u8], raw_rgba: &[u8]) -> Option<f64> {
    let pixels = decoded_rgb.len() / 3;
    if pixels == 0 || !decoded_rgb.len().is_multiple_of(3) || raw_rgba.len() != pixels * 4 {
        return None;
    }
    let sum_sq: u64 = decoded_rgb
        .chunks_exact(3)
        .zip(raw_rgba.chunks_exact(4))
        .map(|(d, r)| {
            (0..3)
                .map(|c| {
                    let e = u64::from(d[c].abs_diff(r[c]));
                    e * e
                })
                .sum::<u64>()
        })
        .sum();
    if sum_sq == 0 {
        return Some(PSNR_CAP_DB);
    }
    let mse = sum_sq as f64 / (pixels * 3) as f64;
    Some((10.0 * (255.0f64 * 255.0 / mse).log10()).min(PSNR_CAP_DB))
}

/// One viewer's decoders: JPEG needs none, H.264 one per stream, made anew when the
/// frame size changes (a configure or a `bandwidth` welcome starts a new stream).
#[derive(Default)]
pub(crate) struct StreamDecoder {
    h264: Option<(openh264::decoder::Decoder, (u16, u16))>,
}

impl StreamDecoder {
    /// The RGB8 picture of one encoded frame; `Ok(None)` when the H.264 decoder has no
    /// picture yet. An error is a frame that does not decode (ask for a key frame).
    pub(crate) fn decode(
        &mut self,
        header: &FrameHeader,
        payload: &[u8],
    ) -> anyhow::Result<Option<Vec<u8>>> {
        let size = (header.width, header.height);
        let want = (usize::from(size.0), usize::from(size.1));
        let rgb = match header.codec {
            FrameCodec::Jpeg => {
                let img = image::load_from_memory_with_format(payload, image::ImageFormat::Jpeg)
                    .context("JPEG does not decode")?
                    .to_rgb8();
                let got = (img.width() as usize, img.height() as usize);
                anyhow::ensure!(
                    got == want,
                    "JPEG is {got:?} pixels, the header says {want:?}"
                );
                img.into_raw()
            }
            FrameCodec::H264 => {
                if self.h264.as_ref().is_none_or(|(_, s)| *s != size) {
                    let d = openh264::decoder::Decoder::new()
                        .context("cannot create an OpenH264 decoder")?;
                    self.h264 = Some((d, size));
                }
                let (decoder, _) = self.h264.as_mut().expect("made above");
                let Some(yuv) = decoder
                    .decode(payload)
                    .map_err(|e| anyhow::anyhow!("H.264 does not decode: {e}"))?
                else {
                    return Ok(None);
                };
                use openh264::formats::YUVSource as _;
                let got = yuv.dimensions();
                anyhow::ensure!(
                    got == want,
                    "H.264 picture is {got:?} pixels, the header says {want:?}"
                );
                // Limited-range BT.601, as the server converted it (OpenH264's own
                // `write_rgb8` assumes full range and shifts every colour).
                crate::protocol::yuv420_to_rgb((yuv.y(), yuv.u(), yuv.v()), yuv.strides(), want)
            }
            FrameCodec::Raw => anyhow::bail!("a raw frame is not encoded"),
        };
        Ok(Some(rgb))
    }

    /// Forgets the H.264 stream (after a decode error the next frame is a key frame).
    pub(crate) fn reset(&mut self) {
        self.h264 = None;
    }
}

/// Whether an encoded payload looks like its codec: a JPEG from `FF D8` to `FF D9`, an
/// H.264 access unit starting with an Annex B start code.
pub(crate) fn payload_looks_valid(codec: FrameCodec, payload: &[u8]) -> bool {
    match codec {
        FrameCodec::Jpeg => payload.starts_with(&[0xFF, 0xD8]) && payload.ends_with(&[0xFF, 0xD9]),
        FrameCodec::H264 => {
            payload.len() > 4
                && (payload.starts_with(&[0, 0, 0, 1]) || payload.starts_with(&[0, 0, 1]))
        }
        FrameCodec::Raw => !payload.is_empty(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::protocol::Layout;

    fn header(codec: FrameCodec, width: u16, height: u16) -> FrameHeader {
        FrameHeader {
            layout: Layout::Mono,
            views: 1,
            width,
            height,
            frame: 1,
            pose_seq: 0,
            render_us: 0,
            encode_us: 0,
            dropped: 0,
            codec,
            key: true,
            quality: 0,
            target_kbps: 0,
        }
    }

    /// A smooth test picture, RGBA.
    fn picture(w: usize, h: usize) -> Vec<u8> {
        (0..w * h)
            .flat_map(|i| {
                let (x, y) = (i % w, i / w);
                [
                    (x * 255 / w) as u8,
                    (y * 255 / h) as u8,
                    ((x + y) % 256) as u8,
                    255,
                ]
            })
            .collect()
    }

    fn rgb_of(rgba: &[u8]) -> Vec<u8> {
        rgba.chunks_exact(4)
            .flat_map(|p| [p[0], p[1], p[2]])
            .collect()
    }

    #[test]
    fn psnr_follows_the_formula() {
        let raw = picture(16, 8);
        assert_eq!(psnr(&rgb_of(&raw), &raw), Some(PSNR_CAP_DB));
        // Every channel off by 5: MSE 25.
        let off: Vec<u8> = rgb_of(&raw)
            .iter()
            .map(|v| v.saturating_add(5).max(5))
            .collect();
        let mse = off
            .iter()
            .zip(rgb_of(&raw))
            .map(|(a, b)| f64::from(a.abs_diff(b)).powi(2))
            .sum::<f64>()
            / off.len() as f64;
        let want = 10.0 * (255.0f64.powi(2) / mse).log10();
        assert!((psnr(&off, &raw).unwrap() - want).abs() < 1e-9);
        assert_eq!(psnr(&off[3..], &raw), None, "pixel counts differ");
    }

    #[test]
    fn a_jpeg_frame_decodes_close_to_its_raw_picture() {
        let (w, h) = (64u16, 32u16);
        let raw = picture(w.into(), h.into());
        let mut jpeg = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 90)
            .encode(
                &rgb_of(&raw),
                w.into(),
                h.into(),
                image::ExtendedColorType::Rgb8,
            )
            .unwrap();
        assert!(payload_looks_valid(FrameCodec::Jpeg, &jpeg));
        let mut d = StreamDecoder::default();
        let rgb = d
            .decode(&header(FrameCodec::Jpeg, w, h), &jpeg)
            .unwrap()
            .unwrap();
        let db = psnr(&rgb, &raw).unwrap();
        assert!(db > 30.0 && db < PSNR_CAP_DB, "JPEG q90 PSNR {db} dB");
        let e = d
            .decode(&header(FrameCodec::Jpeg, w, h + 2), &jpeg)
            .unwrap_err();
        assert!(format!("{e:#}").contains("the header says"), "{e:#}");
        assert!(d.decode(&header(FrameCodec::Jpeg, w, h), b"junk").is_err());
    }

    #[test]
    fn an_h264_stream_decodes_close_to_its_raw_picture() {
        use openh264::encoder::Encoder;
        use openh264::formats::{RgbSliceU8, YUVBuffer};
        let (w, h) = (64u16, 48u16);
        let raw = picture(w.into(), h.into());
        let rgb = rgb_of(&raw);
        let yuv = YUVBuffer::from_rgb8_source(RgbSliceU8::new(&rgb, (w.into(), h.into())));
        let mut encoder = Encoder::new().unwrap();
        let mut d = StreamDecoder::default();
        let hd = header(FrameCodec::H264, w, h);
        let mut decoded = 0;
        for _ in 0..3 {
            let au = encoder.encode(&yuv).unwrap().to_vec();
            assert!(payload_looks_valid(FrameCodec::H264, &au));
            if let Some(pic) = d.decode(&hd, &au).unwrap() {
                let db = psnr(&pic, &raw).unwrap();
                assert!(db > 25.0, "H.264 PSNR {db} dB");
                decoded += 1;
            }
        }
        assert!(decoded > 0, "the decoder gave no picture");
        assert!(!payload_looks_valid(FrameCodec::H264, b"\xFF\xD8"));
    }
}
