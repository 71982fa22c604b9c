//! Image error metrics: mean FLIP (LDR, `flip-rs`), PSNR, RMSE and SSIM.
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
    /// Mean structural similarity over RGB ([`ssim`]; 1 = identical). Reports from before
    /// it existed read as 0.
    #[serde(default)]
    pub ssim: f64,
}

/// Per-pixel LDR-FLIP of `test` against `reference`, two RGBA8 sRGB images of
/// `width`×`height` (alpha ignored); [`compare`] reports its mean.
pub fn flip_map(
    reference: &[u8],
    test: &[u8],
    width: u32,
    height: u32,
) -> anyhow::Result<flip_rs::ErrorMap> {
    let rgb = |img: &[u8]| -> Vec<u8> {
        img.chunks_exact(4)
            .flat_map(|p| [p[0], p[1], p[2]])
            .collect()
    };
    let r = flip_rs::RgbImage::new(width as usize, height as usize, rgb(reference))
        .map_err(|e| anyhow::anyhow!("{e:?}"))?;
    let t = flip_rs::RgbImage::new(width as usize, height as usize, rgb(test))
        .map_err(|e| anyhow::anyhow!("{e:?}"))?;
    flip_rs::ldr_flip(&r, &t, flip_rs::DEFAULT_PPD).map_err(|e| anyhow::anyhow!("FLIP: {e:?}"))
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
    let flip = flip_map(reference, test, width, height)?;
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
        ssim: ssim(reference, test, width as usize, height as usize),
    })
}

/// Side of the SSIM window and its Gaussian's σ, pixels (Wang et al. 2004).
const SSIM_WINDOW: usize = 11;
const SSIM_SIGMA: f64 = 1.5;

/// Mean structural similarity of two RGBA8 images (alpha ignored), as Wang, Bovik,
/// Sheikh and Simoncelli define it (IEEE TIP 2004): per channel and pixel,
/// `(2μxμy + C1)(2σxy + C2) / ((μx² + μy² + C1)(σx² + σy² + C2))` over an 11×11 Gaussian
/// window of σ = 1.5 px (cut at the image's edges and renormalised there), C1 = (0.01·255)²,
/// C2 = (0.03·255)²; the mean over pixels and the three channels (as seed 003 reports it
/// for colour images, next to PSNR).
pub fn ssim(reference: &[u8], test: &[u8], width: usize, height: usize) -> f64 {
    let n = width * height;
    if n == 0 {
        return 1.0;
    }
    let half = (SSIM_WINDOW / 2) as isize;
    let kernel: Vec<f64> = (-half..=half)
        .map(|k| (-((k * k) as f64) / (2.0 * SSIM_SIGMA * SSIM_SIGMA)).exp())
        .collect();
    // Separable Gaussian mean of `f` over the window, renormalised where it is cut.
    let blur = |f: &[f64]| -> Vec<f64> {
        let pass = |src: &[f64], step: usize, len: usize, lines: usize, across: usize| {
            let mut out = vec![0.0; n];
            for line in 0..lines {
                for i in 0..len {
                    let (mut acc, mut wsum) = (0.0, 0.0);
                    for (j, w) in kernel.iter().enumerate() {
                        let at = i as isize + j as isize - half;
                        if (0..len as isize).contains(&at) {
                            acc += w * src[line * across + at as usize * step];
                            wsum += w;
                        }
                    }
                    out[line * across + i * step] = acc / wsum;
                }
            }
            out
        };
        let rows = pass(f, 1, width, height, width);
        pass(&rows, width, height, width, 1)
    };
    let (c1, c2) = ((0.01f64 * 255.0).powi(2), (0.03f64 * 255.0).powi(2));
    let mut total = 0.0;
    for channel in 0..3 {
        let x: Vec<f64> = reference
            .chunks_exact(4)
            .map(|p| p[channel] as f64)
            .collect();
        let y: Vec<f64> = test.chunks_exact(4).map(|p| p[channel] as f64).collect();
        let products =
            |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(a, b)| a * b).collect::<Vec<_>>();
        let (mx, my) = (blur(&x), blur(&y));
        let (xx, yy, xy) = (
            blur(&products(&x, &x)),
            blur(&products(&y, &y)),
            blur(&products(&x, &y)),
        );
        for i in 0..n {
            let (vx, vy, cxy) = (
                xx[i] - mx[i] * mx[i],
                yy[i] - my[i] * my[i],
                xy[i] - mx[i] * my[i],
            );
            total += ((2.0 * mx[i] * my[i] + c1) * (2.0 * cxy + c2))
                / ((mx[i] * mx[i] + my[i] * my[i] + c1) * (vx + vy + c2));
        }
    }
    total / (3 * n) as f64
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
        assert!((e.ssim - 1.0).abs() < 1e-12, "{}", e.ssim);
    }

    #[test]
    fn ssim_of_flat_images_is_its_luminance_term() {
        // Two flat images have no variance: SSIM is (2μxμy + C1)/(μx² + μy² + C1).
        let (a, b) = (vec![100u8; 24 * 20 * 4], vec![105u8; 24 * 20 * 4]);
        let c1 = (0.01f64 * 255.0).powi(2);
        let want = (2.0 * 100.0 * 105.0 + c1) / (100.0f64.powi(2) + 105.0f64.powi(2) + c1);
        let got = ssim(&a, &b, 24, 20);
        assert!((got - want).abs() < 1e-9, "{got} vs {want}");
        // Structure lost: a checkerboard against its mean is far from 1; against its
        // inverse, negative.
        let checker: Vec<u8> = (0..24 * 20)
            .flat_map(|i| {
                let v = if (i % 24 + i / 24) % 2 == 0 { 50 } else { 200 };
                [v, v, v, 255]
            })
            .collect();
        let inverse: Vec<u8> = checker
            .iter()
            .map(|&v| if v == 255 { 255 } else { 250 - v })
            .collect();
        let grey = vec![125u8; 24 * 20 * 4];
        assert!(ssim(&checker, &grey, 24, 20) < 0.1);
        assert!(ssim(&checker, &inverse, 24, 20) < -0.9);
    }

    #[test]
    fn error_grows_with_difference() {
        let a = vec![100u8; 32 * 32 * 4];
        let small: Vec<u8> = a.iter().map(|v| v + 5).collect();
        let large: Vec<u8> = a.iter().map(|v| v + 60).collect();
        let es = compare(&a, &small, 32, 32).unwrap();
        let el = compare(&a, &large, 32, 32).unwrap();
        assert!(es.flip_mean < el.flip_mean && es.psnr_db > el.psnr_db && es.rmse < el.rmse);
        assert!(es.ssim > el.ssim && es.ssim <= 1.0);
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
