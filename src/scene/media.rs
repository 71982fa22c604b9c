//! Media density and phase function: the CPU twin of `shaders/media.wgsl`.
//!
//! Every formula here is mirrored in WGSL; the truth renderer uses these directly.

use super::{Medium, MediumDesc, MediumKind, Noise, Volume, VolumeDesc};
use glam::Vec3;

/// Combined optical properties of all media at one point.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct MediumSample {
    /// σs per channel, m⁻¹.
    pub scattering: Vec3,
    /// Grey extinction σt = mean(σs) + σa, m⁻¹ (one transmittance for all channels,
    /// as the froxel volume stores it).
    pub extinction: f32,
    /// Emitted radiance per metre.
    pub emission: Vec3,
    /// σs-weighted Henyey-Greenstein g.
    pub g: f32,
}

pub(crate) fn bounded_extent(m: &MediumDesc) -> Option<(Vec3, Vec3)> {
    match m.kind {
        MediumKind::Box => Some((Vec3::from(m.min?), Vec3::from(m.max?))),
        MediumKind::Sphere => {
            let c = Vec3::from(m.center?);
            let r = m.radius?;
            Some((c - r, c + r))
        }
        MediumKind::Constant | MediumKind::Height | MediumKind::Volume => None,
    }
}

/// Width of a volume's soft edge as a fraction of its radius: the density falls from 1
/// to 0 over the last `VOLUME_EDGE_FRACTION · r` inside the displaced surface, so that
/// quadrature along a ray converges (a hard edge would make it first order).
pub const VOLUME_EDGE_FRACTION: f32 = 0.05;

/// The volume's centre at time 0 and the displacement and motion, in file coordinates.
fn volume_shape(v: &VolumeDesc) -> Volume {
    let d = v.displacement.unwrap_or(super::Displacement {
        amplitude: 0.0,
        frequency: 1.0,
        octaves: 1,
        seed: 0,
    });
    let (velocity, period_s) = v
        .motion
        .map_or((Vec3::ZERO, 1.0), |m| (Vec3::from(m.velocity), m.period_s));
    // A seed moves the noise by whole lattice cells, so seeds give unrelated shapes;
    // below 251 cells on each axis so that f32 keeps the finest octave's detail (the
    // sixth octave doubles the offset five times: still under 10⁴ cells, ulp 10⁻³).
    let cells = |k: u32| (d.seed * k % 251) as f32;
    Volume {
        center: Vec3::from(v.center),
        radius_m: v.radius,
        amplitude: d.amplitude,
        frequency: d.frequency,
        octaves: d.octaves,
        noise_offset: Vec3::new(cells(17), cells(11), cells(23)),
        velocity,
        period_s,
    }
}

/// Where a volume can have density over its whole motion, file coordinates: the
/// segment its centre travels, grown by r·(1 + amplitude).
pub(crate) fn volume_extent(v: &VolumeDesc) -> (Vec3, Vec3) {
    let shape = volume_shape(v);
    let half_path = shape.velocity * (shape.period_s * 0.5);
    let reach = Vec3::splat(shape.outer_radius_m());
    let (a, b) = (shape.center - half_path, shape.center + half_path);
    (a.min(b) - reach, a.max(b) + reach)
}

/// A `[[volume]]` as the medium the renderers use (kind volume), render space.
pub(crate) fn volume_to_render_space(
    v: &VolumeDesc,
    to_render: &impl Fn([f32; 3]) -> Vec3,
) -> Medium {
    let (min, max) = volume_extent(v);
    let mut shape = volume_shape(v);
    shape.center = to_render(v.center);
    Medium {
        kind: MediumKind::Volume,
        scattering: Vec3::from(v.scattering),
        absorption: v.absorption,
        g: v.g,
        emission: Vec3::from(v.emission),
        min: to_render(min.to_array()),
        max: to_render(max.to_array()),
        radius_or_falloff: v.radius,
        base_y: 0.0,
        noise: v.noise.unwrap_or(NO_NOISE),
        volume: Some(shape),
    }
}

const NO_NOISE: Noise = Noise {
    frequency: 0.0,
    octaves: 1,
    amplitude: 0.0,
    wind: [0.0; 3],
};

pub(crate) fn to_render_space(
    m: &MediumDesc,
    to_render: &impl Fn([f32; 3]) -> Vec3,
    scene_bounds: (Vec3, Vec3),
) -> Medium {
    let (min, max) = match bounded_extent(m) {
        Some((a, b)) => (to_render(a.to_array()), to_render(b.to_array())),
        None => scene_bounds,
    };
    let base_y = m
        .base_y_m
        .map(|y| to_render([0.0, y, 0.0]).y)
        .unwrap_or(0.0);
    Medium {
        kind: m.kind,
        scattering: Vec3::from(m.scattering),
        absorption: m.absorption,
        g: m.g,
        emission: Vec3::from(m.emission),
        min,
        max,
        radius_or_falloff: m.radius.or(m.falloff_m).unwrap_or(1.0),
        base_y,
        noise: m.noise.unwrap_or(NO_NOISE),
        volume: None,
    }
}

/// Integer hash of a lattice point (a 32-bit avalanche), mirrored in WGSL.
fn hash3(x: i32, y: i32, z: i32) -> u32 {
    let mut h = (x as u32).wrapping_mul(0x8da6_b343)
        ^ (y as u32).wrapping_mul(0xd816_3841)
        ^ (z as u32).wrapping_mul(0xcb1a_b31f);
    h ^= h >> 16;
    h = h.wrapping_mul(0x7feb_352d);
    h ^= h >> 15;
    h = h.wrapping_mul(0x846c_a68b);
    h ^= h >> 16;
    h
}

fn lattice(x: i32, y: i32, z: i32) -> f32 {
    (hash3(x, y, z) >> 8) as f32 * (1.0 / 16_777_216.0)
}

/// Trilinear value noise with smoothstep fade, in [0, 1).
fn value_noise(p: Vec3) -> f32 {
    let i = p.floor();
    let f = p - i;
    let u = f * f * (Vec3::splat(3.0) - 2.0 * f);
    let (x, y, z) = (i.x as i32, i.y as i32, i.z as i32);
    let c = |dx: i32, dy: i32, dz: i32| {
        lattice(x.wrapping_add(dx), y.wrapping_add(dy), z.wrapping_add(dz))
    };
    let x00 = c(0, 0, 0) + (c(1, 0, 0) - c(0, 0, 0)) * u.x;
    let x10 = c(0, 1, 0) + (c(1, 1, 0) - c(0, 1, 0)) * u.x;
    let x01 = c(0, 0, 1) + (c(1, 0, 1) - c(0, 0, 1)) * u.x;
    let x11 = c(0, 1, 1) + (c(1, 1, 1) - c(0, 1, 1)) * u.x;
    let y0 = x00 + (x10 - x00) * u.y;
    let y1 = x01 + (x11 - x01) * u.y;
    y0 + (y1 - y0) * u.z
}

/// Fractal sum of value noise, normalised to [0, 1).
fn fbm(p: Vec3, octaves: u32) -> f32 {
    let (mut sum, mut amp, mut norm, mut q) = (0.0, 1.0, 0.0, p);
    for _ in 0..octaves {
        sum += amp * value_noise(q);
        norm += amp;
        amp *= 0.5;
        q *= 2.0;
    }
    sum / norm
}

/// Density multiplier of one medium at render-space point `p` (0 outside it).
pub fn density_at(m: &Medium, p: Vec3, time_s: f32) -> f32 {
    let inside_box = p.cmpge(m.min).all() && p.cmple(m.max).all();
    let mut d = match m.kind {
        MediumKind::Constant => f32::from(inside_box),
        MediumKind::Height => {
            if inside_box {
                (-(p.y - m.base_y).max(0.0) / m.radius_or_falloff).exp()
            } else {
                0.0
            }
        }
        MediumKind::Box => f32::from(inside_box),
        MediumKind::Sphere => {
            let c = (m.min + m.max) * 0.5;
            f32::from(p.distance_squared(c) <= m.radius_or_falloff * m.radius_or_falloff)
        }
        MediumKind::Volume => m.volume.map_or(0.0, |v| volume_density(&v, p, time_s)),
    };
    if d > 0.0 && m.noise.frequency > 0.0 {
        let q = (p - m.min - Vec3::from(m.noise.wind) * time_s) * m.noise.frequency;
        let n = fbm(q, m.noise.octaves);
        d *= (1.0 + m.noise.amplitude * (2.0 * n - 1.0)).max(0.0);
    }
    d
}

/// Density of a displaced-sphere volume at `p` (paper 004 §5.3, common.wgsl
/// `volume_density`). With q = p − centre(t), ρ = |q| and û = q/ρ, the surface lies at
/// R(û) = r·(1 + a·(2·fbm(f·û + offset) − 1)) and the density is
/// smoothstep((R(û) − ρ)/w) with w = [`VOLUME_EDGE_FRACTION`]·r: 1 deeper than w inside
/// the surface, 0 outside it. As in 004, points inside the inner radius r(1 − a) − w are
/// inside without noise, points beyond the outer radius r(1 + a) outside.
fn volume_density(v: &Volume, p: Vec3, time_s: f32) -> f32 {
    let q = p - v.center_at(time_s);
    let rho_sq = q.length_squared();
    let outer = v.outer_radius_m();
    if rho_sq >= outer * outer {
        return 0.0;
    }
    let edge = VOLUME_EDGE_FRACTION * v.radius_m;
    let inner = v.radius_m * (1.0 - v.amplitude) - edge;
    if rho_sq <= inner * inner {
        return 1.0;
    }
    let rho = rho_sq.sqrt();
    let surface = if v.amplitude > 0.0 {
        let n = fbm(q / rho * v.frequency + v.noise_offset, v.octaves);
        v.radius_m * (1.0 + v.amplitude * (2.0 * n - 1.0))
    } else {
        v.radius_m
    };
    let x = ((surface - rho) / edge).clamp(0.0, 1.0);
    x * x * (3.0 - 2.0 * x)
}

/// Sum of all media at `p`.
pub fn sample_media(media: &[Medium], p: Vec3, time_s: f32) -> MediumSample {
    let mut s = MediumSample::default();
    let mut g_weight = 0.0;
    for m in media {
        let d = density_at(m, p, time_s);
        if d <= 0.0 {
            continue;
        }
        let ss = m.scattering * d;
        s.scattering += ss;
        s.extinction += (ss.x + ss.y + ss.z) / 3.0 + m.absorption * d;
        s.emission += m.emission * d;
        let w = ss.x + ss.y + ss.z;
        s.g += m.g * w;
        g_weight += w;
    }
    if g_weight > 0.0 {
        s.g /= g_weight;
    }
    s
}

/// Henyey-Greenstein phase function; `cos_theta` is between the light's direction of
/// travel and the scattered direction. Finite for |g| < 1 (1 − g² formed as (1−g)(1+g)).
/// The denominator 1 + g² − 2g·cosθ is formed as a sum of two non-negative terms,
/// (1 − g)² + 2g(1 − cosθ) for g ≥ 0 and (1 + g)² − 2g(1 + cosθ) for g < 0, so the
/// peak of g → ±1 keeps its precision in f32 (the naive form cancels to 0 or worse).
pub fn hg_phase(g: f32, cos_theta: f32) -> f32 {
    let denom = if g >= 0.0 {
        (1.0 - g) * (1.0 - g) + 2.0 * g * (1.0 - cos_theta)
    } else {
        (1.0 + g) * (1.0 + g) - 2.0 * g * (1.0 + cos_theta)
    }
    .max(1e-12);
    (1.0 - g) * (1.0 + g) / (4.0 * std::f32::consts::PI * denom * denom.sqrt())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hg_integrates_to_one() {
        for g in [-0.999_f32, -0.5, 0.0, 0.3, 0.9] {
            // ∫ p dω = 2π ∫ p(cosθ) dcosθ. The peak at cosθ = sign(g) is only
            // ~(1 − |g|)² wide, so substitute cosθ = sign·(1 − 2s⁴), which crowds the
            // midpoint samples there (dcosθ = 8s³ ds).
            let n = 200_000;
            let sign = if g < 0.0 { -1.0 } else { 1.0 };
            let sum: f64 = (0..n)
                .map(|i| {
                    let s = (i as f64 + 0.5) / n as f64;
                    let c = sign * (1.0 - 2.0 * s.powi(4));
                    hg_phase(g, c as f32) as f64 * 8.0 * s.powi(3) / n as f64
                })
                .sum();
            let total = sum * 2.0 * std::f64::consts::PI;
            let tol = if g.abs() > 0.99 { 0.01 } else { 1e-3 };
            assert!((total - 1.0).abs() < tol, "g={g}: ∫p = {total}");
        }
    }

    #[test]
    fn fbm_is_in_unit_range() {
        for i in 0..1000 {
            let p = Vec3::new(i as f32 * 0.37, -(i as f32) * 0.11, 1e4 + i as f32 * 0.05);
            let n = fbm(p, 4);
            assert!((0.0..1.0).contains(&n), "{n}");
        }
    }
}
