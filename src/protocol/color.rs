//! The colour convention of H.264 frames: the server converts its RGB frames to YCbCr with
//! BT.601 coefficients in *limited* range (Y 16–235, Cb/Cr 16–240; OpenH264's converter)
//! and 4:2:0 chroma (each chroma sample the mean of a 2×2 block). A client that shows
//! or measures frames converts back with the inverse below — not the full-range formulas
//! some decoders' helpers use, which shift every colour (about 32 dB PSNR at best).

/// RGB8 (row-major, 3 bytes a pixel) of a decoded 4:2:0 picture of `width`×`height`
/// given its planes and their strides (bytes per row).
pub fn yuv420_to_rgb(
    (y, u, v): (&[u8], &[u8], &[u8]),
    (y_stride, u_stride, v_stride): (usize, usize, usize),
    (width, height): (usize, usize),
) -> Vec<u8> {
    let mut rgb = Vec::with_capacity(width * height * 3);
    for row in 0..height {
        for col in 0..width {
            let l = 1.164_383_6 * (f32::from(y[row * y_stride + col]) - 16.0);
            let cb = f32::from(u[(row / 2) * u_stride + col / 2]) - 128.0;
            let cr = f32::from(v[(row / 2) * v_stride + col / 2]) - 128.0;
            let to_u8 = |x: f32| x.round().clamp(0.0, 255.0) as u8;
            rgb.push(to_u8(l + 1.596_026_8 * cr));
            rgb.push(to_u8(l - 0.391_762_3 * cb - 0.812_967_6 * cr));
            rgb.push(to_u8(l + 2.017_232_2 * cb));
        }
    }
    rgb
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The server's forward conversion (OpenH264's `write_yuv_scalar`), per pixel.
    fn forward(r: f32, g: f32, b: f32) -> (u8, u8, u8) {
        (
            (0.257_812_5 * r + 0.503_906_25 * g + 0.097_656_25 * b + 16.0) as u8,
            (-0.148_437_5 * r - 0.289_062_5 * g + 0.4375 * b + 128.0) as u8,
            (0.4375 * r - 0.367_187_5 * g - 0.070_312_5 * b + 128.0) as u8,
        )
    }

    #[test]
    fn the_inverse_recovers_rgb_within_rounding() {
        let mut worst = 0i32;
        for r in (0..256).step_by(15) {
            for g in (0..256).step_by(15) {
                for b in (0..256).step_by(15) {
                    let (y, u, v) = forward(r as f32, g as f32, b as f32);
                    let rgb = yuv420_to_rgb((&[y], &[u], &[v]), (1, 1, 1), (1, 1));
                    for (got, want) in rgb.iter().zip([r, g, b]) {
                        worst = worst.max((i32::from(*got) - want).abs());
                    }
                }
            }
        }
        // The forward conversion truncates to 8 bits: a few levels of error, not the
        // tens of levels a full-range inverse makes.
        assert!(worst <= 4, "worst channel error {worst}");
    }
}
