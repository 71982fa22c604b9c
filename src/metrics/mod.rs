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
pub fn compare(reference: &[u8], test: &[u8], width: u32, height: u32) -> anyhow::Result<ImageError> {
    let n = (width * height) as usize;
    anyhow::ensure!(reference.len() == n * 4 && test.len() == n * 4, "images must both be {width}×{height} RGBA8");
    let rgb = |img: &[u8]| -> Vec<u8> { img.chunks_exact(4).flat_map(|p| [p[0], p[1], p[2]]).collect() };
    let r = flip_rs::RgbImage::new(width as usize, height as usize, rgb(reference)).map_err(|e| anyhow::anyhow!("{e:?}"))?;
    let t = flip_rs::RgbImage::new(width as usize, height as usize, rgb(test)).map_err(|e| anyhow::anyhow!("{e:?}"))?;
    let flip = flip_rs::ldr_flip(&r, &t, flip_rs::DEFAULT_PPD).map_err(|e| anyhow::anyhow!("FLIP: {e:?}"))?;
    let mse = reference
        .chunks_exact(4)
        .zip(test.chunks_exact(4))
        .map(|(a, b)| (0..3).map(|k| ((a[k] as f64 - b[k] as f64) / 255.0).powi(2)).sum::<f64>())
        .sum::<f64>()
        / (n * 3) as f64;
    Ok(ImageError {
        flip_mean: flip.statistics().mean as f64,
        psnr_db: if mse > 0.0 { -10.0 * mse.log10() } else { f64::INFINITY },
        rmse: mse.sqrt(),
    })
}
