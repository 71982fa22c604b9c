//! Multiple scattering in `truth` (issue 16): a CPU volumetric path tracer, the reference
//! that shared ambient light is measured against.
//!
//! The single-scattering truth (the rest of this module) lights every point by the scene's
//! lights and adds a constant `ambient` radiance, neither occluded nor dimmed. Here light
//! may scatter up to `bounces` times, in the media, the smoke and off surfaces, and the
//! sky is a light: the `sky` colour is the radiance arriving from every direction a path
//! escapes in (occluded by geometry, dimmed by the media), and `ambient` is not used.
//!
//! One path per sample, from the eye:
//! - **Free flight** by inverting the exact optical depth: a target `τ* = −ln(1 − ξ)` and
//!   bisection on the segment's optical depth (the media's closed forms and quadratures of
//!   [`ShadowMedia`](super::ShadowMedia), the particles' closed form), so an event at `s`
//!   has density `σt(s)·T(s)` and a path leaves the segment with probability `T`.
//! - **At a medium event** after `k` scatterings: the emission `β·ε/σt` is added; if
//!   `k < bounces`, next-event estimation to every light (`V·T·L`, the mixed phase
//!   `Σ σs_i·p_i / σt` of the media and each emitter's particles), then a new direction
//!   from one lobe chosen by its share of σs, weighted by the mixture's value over its pdf.
//! - **At a surface** (Lambertian, the truth's albedo): if `k < bounces`, next-event
//!   estimation (`albedo/π·Σ L·cos·V·T`) and a cosine-distributed new direction, weight
//!   `albedo`.
//! - **Escaping** (no event and no surface up to the scene's size, or the camera ray's far
//!   plane): `β·sky`.
//!
//! So light that scattered at most `bounces` times reaches the eye, every order once:
//! `bounces = 1` is the single-scattering truth with `ambient = 0`, plus the sky seen
//! through one scattering. Emission of a medium where it does not extinguish (`σt = 0`)
//! is not sampled (no scene uses it).
//!
//! Checked against closed forms in `tests/truth_paths.rs`: a non-absorbing medium under a
//! uniform sky (the furnace: every path returns the sky), an emitting medium of albedo ω
//! (`L = ε/σt·Σ_{k≤B} ω^k`), a sunlit ground under the sky (`albedo·(sky + E·cos/π)`),
//! and `bounces = 1` against the single-scattering truth.

use super::PixelContext;
use crate::scene::{hg_phase, sample_media, Ray};
use glam::{DVec3, Vec3};
use std::f64::consts::PI;

/// A small deterministic generator (SplitMix64), one per path.
pub(crate) struct PathRng(u64);

impl PathRng {
    pub(crate) fn new(seed: u64) -> PathRng {
        PathRng(seed)
    }

    /// Uniform in [0, 1).
    pub(crate) fn unit(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// An orthonormal pair across unit `n`.
fn basis(n: DVec3) -> (DVec3, DVec3) {
    let helper = if n.y.abs() < 0.9 { DVec3::Y } else { DVec3::X };
    let ex = n.cross(helper).normalize();
    (ex, n.cross(ex))
}

/// The cosine of a scattering angle drawn from Henyey-Greenstein `g` (inverse CDF; the
/// isotropic draw for |g| < 1e-3).
pub fn sample_hg_cos(g: f64, xi: f64) -> f64 {
    if g.abs() < 1e-3 {
        return 1.0 - 2.0 * xi;
    }
    let s = (1.0 - g * g) / (1.0 - g + 2.0 * g * xi);
    ((1.0 + g * g - s * s) / (2.0 * g)).clamp(-1.0, 1.0)
}

/// A unit direction at angle `acos(cos)` from unit `axis`, azimuth `2π·xi`.
fn around(axis: DVec3, cos: f64, xi: f64) -> DVec3 {
    let sin = (1.0 - cos * cos).max(0.0).sqrt();
    let (ex, ey) = basis(axis);
    let phi = 2.0 * PI * xi;
    (axis * cos + (ex * phi.cos() + ey * phi.sin()) * sin).normalize()
}

/// One scattering lobe at a medium event: σs per channel and HG `g`.
#[derive(Debug, Clone, Copy)]
struct Lobe {
    sigma_s: DVec3,
    g: f64,
}

/// What the media and the particles hold at a point.
struct Event {
    sigma_t: f64,
    emission: DVec3,
    lobes: Vec<Lobe>,
}

impl Event {
    /// `Σ σs_i·p_i(cos)` per channel.
    fn phase_weighted(&self, cos: f64) -> DVec3 {
        self.lobes
            .iter()
            .map(|l| l.sigma_s * f64::from(hg_phase(l.g as f32, cos as f32)))
            .sum()
    }
}

impl PixelContext<'_> {
    /// The media and particles at `p`.
    fn event_at(&self, p: DVec3) -> Event {
        let m = sample_media(&self.scene.media, p.as_vec3(), self.time_s);
        let mut e = Event {
            sigma_t: f64::from(m.extinction),
            emission: m.emission.as_dvec3(),
            lobes: Vec::new(),
        };
        if m.scattering != Vec3::ZERO {
            e.lobes.push(Lobe {
                sigma_s: m.scattering.as_dvec3(),
                g: f64::from(m.g),
            });
        }
        for (group, sigma_t) in self.smoke.extinction_at(p) {
            let g = &self.smoke.groups()[group];
            e.sigma_t += sigma_t;
            e.lobes.push(Lobe {
                sigma_s: g.scattering * (sigma_t / g.sigma_t),
                g: f64::from(g.g),
            });
        }
        e
    }

    /// Optical depth of the media and the particles over `[0, len]` of `o + s·dir`.
    fn path_optical_depth(&self, o: DVec3, dir: DVec3, len: f64) -> f64 {
        if len.is_nan() || len <= 0.0 {
            return 0.0;
        }
        let media = self.shadow_media.optical_depth(
            o.as_vec3(),
            dir.as_vec3(),
            len.min(f64::from(f32::MAX)) as f32,
            self.time_s,
        );
        media + self.smoke.optical_depth(o, dir, len, f64::INFINITY)
    }

    /// Where along `o + s·dir`, `s ∈ [0, len]`, the optical depth reaches `target`
    /// (bisection to 10⁻⁹ of the length: a mean free path of 0.1 mm at σt 10⁴ m⁻¹ on a
    /// 500 m segment); `None` if the whole segment holds less.
    fn free_flight(&self, o: DVec3, dir: DVec3, len: f64, target: f64) -> Option<f64> {
        if self.path_optical_depth(o, dir, len) <= target {
            return None;
        }
        let (mut lo, mut hi, mut left) = (0.0, len, target);
        while hi - lo > 1e-9 * len.max(1e-3) {
            let mid = 0.5 * (lo + hi);
            let tau = self.path_optical_depth(o + dir * lo, dir, mid - lo);
            if tau < left {
                left -= tau;
                lo = mid;
            } else {
                hi = mid;
            }
        }
        Some(0.5 * (lo + hi))
    }

    /// Linear radiance along one path from the eye through pixel direction `dir`; the
    /// next-event shadow rays are counted in `rays` (from media and smoke events, from
    /// surfaces).
    pub(super) fn trace_path(
        &self,
        cam_pos: Vec3,
        cam_forward: Vec3,
        dir: Vec3,
        bounces: u32,
        rng: &mut PathRng,
        rays: (&mut u64, &mut u64),
    ) -> Vec3 {
        let (media_rays, surface_rays) = rays;
        let r = &self.scene.render;
        let sky = Vec3::from(r.sky).as_dvec3();
        let cos = dir.dot(cam_forward).max(1e-6);
        let mut o = cam_pos.as_dvec3();
        let mut d = dir.as_dvec3();
        let (mut t_min, mut t_max) = (f64::from(r.near_m / cos), f64::from(r.far_m / cos));
        let mut beta = DVec3::ONE;
        let mut radiance = DVec3::ZERO;
        let mut scatterings = 0;
        loop {
            let ray = Ray {
                origin: o.as_vec3(),
                dir: d.as_vec3(),
                t_min: t_min as f32,
                t_max: t_max as f32,
            };
            // The segment from the eye is a camera ray (it passes the culled side of a
            // surface); after a scattering, light meets both sides.
            let hit = if scatterings == 0 {
                self.bvh.closest_camera_hit(&ray)
            } else {
                self.bvh.closest_hit(&ray)
            };
            let t_end = hit.map_or(t_max, |(t, _)| f64::from(t));
            let start = o + d * t_min;
            let target = -(1.0 - rng.unit()).ln();
            if let Some(s) = self.free_flight(start, d, t_end - t_min, target) {
                let p = start + d * s;
                let e = self.event_at(p);
                if e.sigma_t <= 0.0 {
                    break;
                }
                radiance += beta * e.emission / e.sigma_t;
                if scatterings == bounces || e.lobes.is_empty() {
                    break;
                }
                scatterings += 1;
                let q = p.as_vec3();
                self.for_each_light(q, q, media_rays, |ld, light| {
                    let ld = ld.as_dvec3();
                    radiance += beta * e.phase_weighted(ld.dot(d)) * light.as_dvec3() / e.sigma_t;
                });
                // A lobe by its share of σs, then the mixture's value over its pdf.
                let shares: Vec<f64> = e.lobes.iter().map(|l| l.sigma_s.element_sum()).collect();
                let total: f64 = shares.iter().sum();
                let mut pick = rng.unit() * total;
                let mut lobe = e.lobes[e.lobes.len() - 1];
                for (l, share) in e.lobes.iter().zip(&shares) {
                    if pick < *share {
                        lobe = *l;
                        break;
                    }
                    pick -= share;
                }
                let (xi_a, xi_b) = (rng.unit(), rng.unit());
                let next = around(d, sample_hg_cos(lobe.g, xi_a), xi_b);
                let c = next.dot(d);
                let pdf: f64 = e
                    .lobes
                    .iter()
                    .zip(&shares)
                    .map(|(l, share)| share / total * f64::from(hg_phase(l.g as f32, c as f32)))
                    .sum();
                if pdf <= 0.0 || !pdf.is_finite() {
                    break;
                }
                beta *= e.phase_weighted(c) / (e.sigma_t * pdf);
                o = p;
                d = next;
                t_min = 0.0;
                t_max = f64::from(self.max_ray_m);
                continue;
            }
            let Some((t, tri)) = hit else {
                radiance += beta * sky;
                break;
            };
            if scatterings == bounces {
                break;
            }
            scatterings += 1;
            let p = o + d * f64::from(t);
            let [a, b, c] = self.mesh.triangle(tri);
            let mut n = (b - a).cross(c - a).normalize_or(Vec3::Y).as_dvec3();
            if n.dot(d) > 0.0 {
                n = -n;
            }
            let packed = self.mesh.albedo[self.mesh.indices[tri][0] as usize];
            let albedo = DVec3::new(
                f64::from(packed & 255),
                f64::from((packed >> 8) & 255),
                f64::from((packed >> 16) & 255),
            ) / 255.0;
            let lift = n * (2e-3 + f64::from(t) * 2e-4);
            let offset = (p + lift).as_vec3();
            self.for_each_light(p.as_vec3(), offset, surface_rays, |ld, light| {
                let ndl = n.dot(ld.as_dvec3());
                if ndl > 0.0 {
                    radiance += beta * albedo / PI * light.as_dvec3() * ndl;
                }
            });
            // Cosine-distributed: the Lambertian weight albedo·cos/π over pdf cos/π.
            let (xi_a, xi_b) = (rng.unit(), rng.unit());
            d = around(n, xi_a.sqrt(), xi_b);
            beta *= albedo;
            o = p + lift;
            t_min = 0.0;
            t_max = f64::from(self.max_ray_m);
            if beta == DVec3::ZERO {
                break;
            }
        }
        if radiance.is_finite() {
            radiance.as_vec3()
        } else {
            Vec3::ZERO
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hg_draws_have_the_phase_functions_mean_cosine_and_shape() {
        for g in [-0.9, -0.3, 0.0, 0.5, 0.95, 0.999] {
            let n = 200_000;
            let mut rng = PathRng::new(7);
            let mut bins = [0u32; 20];
            let mut mean = 0.0;
            for _ in 0..n {
                let c = sample_hg_cos(g, rng.unit());
                assert!((-1.0..=1.0).contains(&c), "{c}");
                mean += c;
                bins[(((c + 1.0) * 10.0) as usize).min(19)] += 1;
            }
            mean /= f64::from(n);
            assert!((mean - g).abs() < 0.005, "g {g}: mean cosine {mean}");
            // Each bin's share against HG's closed-form distribution of cosθ:
            // P(cos ≤ c) = (1 − g²)/(2g)·(1/√(1 + g² − 2gc) − 1/(1 + g)), (c + 1)/2 at g = 0.
            let cdf = |c: f64| {
                if g == 0.0 {
                    (c + 1.0) / 2.0
                } else {
                    (1.0 - g * g) / (2.0 * g)
                        * (1.0 / (1.0 + g * g - 2.0 * g * c).sqrt() - 1.0 / (1.0 + g))
                }
            };
            for (k, count) in bins.iter().enumerate() {
                let (a, b) = (-1.0 + 0.1 * k as f64, -1.0 + 0.1 * (k + 1) as f64);
                let integral = cdf(b) - cdf(a);
                let share = f64::from(*count) / f64::from(n);
                let sigma = (integral * (1.0 - integral) / f64::from(n)).sqrt();
                assert!(
                    (share - integral).abs() <= 5.0 * sigma + 2e-4,
                    "g {g} bin {k}: {share} vs {integral}"
                );
            }
        }
    }
}
