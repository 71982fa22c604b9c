//! The colour convention of H.264 frames: the server converts its RGB frames to YCbCr with
//! BT.601 coefficients in *limited* range (Y 16–235, Cb/Cr 16–240), rounded to nearest,
//! and 4:2:0 chroma (each chroma sample from the mean RGB of a 2×2 block):
//! [`rgba_to_i420`]. A client that shows or measures frames converts back with
//! [`yuv420_to_rgb`] — not the full-range formulas some decoders' helpers use, which shift
//! every colour (about 32 dB PSNR at best). (OpenH264's own RGB converter truncates
//! instead of rounding, which alone held H.264 about a decibel below JPEG at any bitrate.)

/// Rounds and clamps a sample.
fn to_u8(x: f32) -> u8 {
    x.round().clamp(0.0, 255.0) as u8
}

/// The I420 planes of an RGBA8 frame of even `width`×`height` into `out`: Y
/// (`width`×`height`), then Cb and Cr (`width/2`×`height/2` each).
pub fn rgba_to_i420(rgba: &[u8], (width, height): (usize, usize), out: &mut Vec<u8>) {
    out.clear();
    out.resize(width * height * 3 / 2, 0);
    let (y_plane, chroma) = out.split_at_mut(width * height);
    let (u_plane, v_plane) = chroma.split_at_mut(width * height / 4);
    for (y, p) in y_plane.iter_mut().zip(rgba.chunks_exact(4)) {
        let (r, g, b) = (f32::from(p[0]), f32::from(p[1]), f32::from(p[2]));
        *y = to_u8(16.0 + (65.481 * r + 128.553 * g + 24.966 * b) / 255.0);
    }
    let cw = width / 2;
    for cy in 0..height / 2 {
        for cx in 0..cw {
            let mut sum = [0.0f32; 3];
            for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                let p = ((cy * 2 + dy) * width + cx * 2 + dx) * 4;
                for (c, s) in sum.iter_mut().enumerate() {
                    *s += f32::from(rgba[p + c]);
                }
            }
            let [r, g, b] = sum.map(|s| s / 4.0);
            u_plane[cy * cw + cx] = to_u8(128.0 + (-37.797 * r - 74.203 * g + 112.0 * b) / 255.0);
            v_plane[cy * cw + cx] = to_u8(128.0 + (112.0 * r - 93.786 * g - 18.214 * b) / 255.0);
        }
    }
}

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

    #[test]
    fn the_inverse_recovers_rgb_within_rounding() {
        let mut worst = 0i32;
        for r in (0..256).step_by(15) {
            for g in (0..256).step_by(15) {
                for b in (0..256).step_by(15) {
                    // A 2×2 block of one colour: one chroma sample.
                    let rgba: Vec<u8> = [r as u8, g as u8, b as u8, 255].repeat(4);
                    let mut i420 = Vec::new();
                    rgba_to_i420(&rgba, (2, 2), &mut i420);
                    let (y, chroma) = i420.split_at(4);
                    let rgb = yuv420_to_rgb((y, &chroma[..1], &chroma[1..]), (2, 1, 1), (2, 2));
                    for (got, want) in rgb.iter().zip([r, g, b].repeat(4)) {
                        worst = worst.max((i32::from(*got) - want).abs());
                    }
                }
            }
        }
        // 8-bit limited range: about one level either way, not the tens of levels a
        // full-range inverse makes.
        assert!(worst <= 2, "worst channel error {worst}");
    }
}
