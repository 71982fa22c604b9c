//! Image error metrics: mean FLIP (LDR, `flip-rs`), PSNR and RMSE.
//! One function, [`compare`], used by tests, `eval` and benchmarks alike.

use serde::{Deserialize, Serialize};

/// Errors of a test image against a reference image.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ImageError {
    /// Mean LDR-FLIP (0 = identical, 1 = maximal).
    pub flip_mean: f64,
    /// Peak signal-to-noise ratio over RGB, dB (infinite for identical images).
    pub psnr_db: f64,
    /// Root-mean-square error over RGB, in 0..1 units.
    pub rmse: f64,
}

/// Compares two RGBA8 sRGB images of `width`×`height` (alpha ignored).
pub fn compare(
    reference: &[u8],
    test: &[u8],
    width: u32,
    height: u32,
) -> anyhow::Result<ImageError> {
    let n = (width * height) as usize;
    anyhow::ensure!(
        reference.len() == n * 4 && test.len() == n * 4,
        "images must both be {width}×{height} RGBA8"
    );
    let rgb = |img: &[u8]| -> Vec<u8> {
        img.chunks_exact(4)
            .flat_map(|p| [p[0], p[1], p[2]])
            .collect()
    };
    let r = flip_rs::RgbImage::new(width as usize, height as usize, rgb(reference))
        .map_err(|e| anyhow::anyhow!("{e:?}"))?;
    let t = flip_rs::RgbImage::new(width as usize, height as usize, rgb(test))
        .map_err(|e| anyhow::anyhow!("{e:?}"))?;
    let flip = flip_rs::ldr_flip(&r, &t, flip_rs::DEFAULT_PPD)
        .map_err(|e| anyhow::anyhow!("FLIP: {e:?}"))?;
    let mse = reference
        .chunks_exact(4)
        .zip(test.chunks_exact(4))
        .map(|(a, b)| {
            (0..3)
                .map(|k| ((a[k] as f64 - b[k] as f64) / 255.0).powi(2))
                .sum::<f64>()
        })
        .sum::<f64>()
        / (n * 3) as f64;
    Ok(ImageError {
        flip_mean: flip.statistics().mean as f64,
        psnr_db: if mse > 0.0 {
            -10.0 * mse.log10()
        } else {
            f64::INFINITY
        },
        rmse: mse.sqrt(),
    })
}

/// The fog contribution of a frame: the frame with media minus the same frame without,
/// per channel, mapped from −255..255 to an RGBA8 image (`(d + 255) / 2`, mid-grey = no
/// fog) so that the image metrics apply to it unchanged.
pub fn fog_contribution(with_media: &[u8], without_media: &[u8]) -> Vec<u8> {
    with_media
        .chunks_exact(4)
        .zip(without_media.chunks_exact(4))
        .flat_map(|(a, b)| {
            let d = |k: usize| ((a[k] as i32 - b[k] as i32 + 255) / 2) as u8;
            [d(0), d(1), d(2), 255]
        })
        .collect()
}

/// Errors over the whole frame and over the fog contribution alone.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FrameError {
    /// Whole frame.
    pub frame: ImageError,
    /// Fog contribution only (see [`fog_contribution`]).
    pub fog: ImageError,
}

/// Compares a test frame with a reference frame, each also rendered without media.
pub fn compare_frames(
    reference: &[u8],
    reference_no_media: &[u8],
    test: &[u8],
    test_no_media: &[u8],
    width: u32,
    height: u32,
) -> anyhow::Result<FrameError> {
    Ok(FrameError {
        frame: compare(reference, test, width, height)?,
        fog: compare(
            &fog_contribution(reference, reference_no_media),
            &fog_contribution(test, test_no_media),
            width,
            height,
        )?,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn identical_images_have_zero_error() {
        let img: Vec<u8> = (0..16 * 16 * 4).map(|i| (i * 7 % 256) as u8).collect();
        let e = compare(&img, &img, 16, 16).unwrap();
        assert_eq!(e.flip_mean, 0.0);
        assert!(e.psnr_db.is_infinite());
        assert_eq!(e.rmse, 0.0);
    }

    #[test]
    fn error_grows_with_difference() {
        let a = vec![100u8; 32 * 32 * 4];
        let small: Vec<u8> = a.iter().map(|v| v + 5).collect();
        let large: Vec<u8> = a.iter().map(|v| v + 60).collect();
        let es = compare(&a, &small, 32, 32).unwrap();
        let el = compare(&a, &large, 32, 32).unwrap();
        assert!(es.flip_mean < el.flip_mean && es.psnr_db > el.psnr_db && es.rmse < el.rmse);
        assert!((es.rmse - 5.0 / 255.0).abs() < 1e-9);
    }

    #[test]
    fn fog_contribution_is_mid_grey_without_fog() {
        let a = vec![80u8; 8];
        assert_eq!(
            fog_contribution(&a, &a),
            vec![127, 127, 127, 255, 127, 127, 127, 255]
        );
    }
}
