//! Smoke in `truth`: the live particles of every `[[emitter]]` at the render's time, as
//! exact Gaussian densities (001 Eq. 9), with nothing between them and the rays (no
//! tetrahedra, no AVSM, no depth slices).
//!
//! A particle of falloff `u` has `σt(l) = σ e^{−50 l²/u²}` (`l` the distance to its
//! centre) with `σ = mean(σs) + σa` its emitter's coefficients at the centre (grey
//! extinction, as the media: [`crate::scene::sample_media`]), and `σs(l) = σs e^{−50
//! l²/u²}` per channel. Along a ray it is a Gaussian of standard deviation `u/10`.
//!
//! Rays ignore a particle whose centre is farther than [`CUT_FALLOFF`]`·u` from them: its
//! density on the ray is below `e^{−32} ≈ 1.3·10⁻¹⁴` of its peak. Within that distance the
//! optical depth is the closed form of
//! [`GaussianAlongRay::optical_depth`](crate::smoke::interval::GaussianAlongRay::optical_depth)
//! (erf), summed over particles. Each emitter's particles are first culled as a whole by
//! the sphere that holds all their cut-off balls.

use crate::scene::EmitterDesc;
use crate::smoke::emitter::particles_at;
use crate::smoke::interval::GaussianAlongRay;
use glam::DVec3;

/// Rays ignore a particle whose centre is farther than this many falloff distances `u`
/// from them (its density there is `e^{−50·0.64} = e^{−32}` of its peak). A primary ray
/// integrates a particle over the chord of this ball.
pub const CUT_FALLOFF: f64 = 0.8;

/// One live particle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SmokeParticle {
    /// Centre, render space, metres.
    pub centre: DVec3,
    /// Falloff distance `u`, metres (> 0).
    pub falloff_u_m: f64,
    /// Which group (emitter) of [`Smoke`] it belongs to.
    pub group: usize,
}

/// One emitter's particles and optics.
#[derive(Debug, Clone)]
pub struct SmokeGroup {
    /// σs at a particle's centre, per channel, m⁻¹.
    pub scattering: DVec3,
    /// σt = mean(σs) + σa at a particle's centre, m⁻¹ (> 0).
    pub sigma_t: f64,
    /// Henyey-Greenstein asymmetry.
    pub g: f32,
    /// Its particles: `Smoke::particles[range]`.
    range: std::ops::Range<usize>,
    /// A sphere holding every particle's cut-off ball.
    bound_centre: DVec3,
    bound_radius: f64,
}

/// Where a primary ray crosses a particle's cut-off ball.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Window {
    /// Entry and exit along the ray (ray parameter, clipped to the queried range).
    pub lo: f64,
    pub hi: f64,
    /// The particle along the ray, `s` measured from the ray's origin.
    pub along: GaussianAlongRay,
    /// Its group.
    pub group: usize,
}

/// The live particles of a scene's emitters at one time.
#[derive(Debug, Clone, Default)]
pub struct Smoke {
    particles: Vec<SmokeParticle>,
    groups: Vec<SmokeGroup>,
}

impl Smoke {
    /// The particles of `emitters` (render space, as [`crate::scene::Scene::emitters`]) at
    /// `time_s`. Particles of zero size and emitters without extinction are dropped: they
    /// change no ray.
    pub fn new(emitters: &[EmitterDesc], time_s: f64) -> Smoke {
        let mut smoke = Smoke::default();
        for e in emitters {
            let scattering = DVec3::from(e.scattering.map(f64::from));
            let sigma_t = scattering.element_sum() / 3.0 + f64::from(e.absorption);
            if sigma_t.is_nan() || sigma_t <= 0.0 {
                continue;
            }
            let group = smoke.groups.len();
            let start = smoke.particles.len();
            smoke.particles.extend(
                particles_at(e, time_s)
                    .into_iter()
                    .filter(|p| p.falloff_u_m > 0.0 && p.centre.is_finite())
                    .map(|p| SmokeParticle {
                        centre: p.centre,
                        falloff_u_m: p.falloff_u_m,
                        group,
                    }),
            );
            let range = start..smoke.particles.len();
            if range.is_empty() {
                continue;
            }
            let ps = &smoke.particles[range.clone()];
            let (lo, hi) = ps.iter().fold(
                (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
                |(lo, hi), p| (lo.min(p.centre), hi.max(p.centre)),
            );
            let bound_centre = (lo + hi) * 0.5;
            let bound_radius = ps
                .iter()
                .map(|p| (p.centre - bound_centre).length() + CUT_FALLOFF * p.falloff_u_m)
                .fold(0.0, f64::max);
            smoke.groups.push(SmokeGroup {
                scattering,
                sigma_t,
                g: e.g,
                range,
                bound_centre,
                bound_radius,
            });
        }
        smoke
    }

    /// `true` without live particles.
    pub fn is_empty(&self) -> bool {
        self.particles.is_empty()
    }

    /// The live particles, grouped by emitter.
    pub fn particles(&self) -> &[SmokeParticle] {
        &self.particles
    }

    /// The emitters that have live particles (a particle's `group` indexes this).
    pub fn groups(&self) -> &[SmokeGroup] {
        &self.groups
    }

    /// The groups whose bounding sphere comes within reach of the segment `p + s·dir`,
    /// `s ∈ [s0, s1]` (`dir` unit).
    fn groups_near(
        &self,
        p: DVec3,
        dir: DVec3,
        s0: f64,
        s1: f64,
    ) -> impl Iterator<Item = &SmokeGroup> {
        self.groups.iter().filter(move |g| {
            let s = (g.bound_centre - p).dot(dir).clamp(s0, s1);
            (p + dir * s - g.bound_centre).length_squared() <= g.bound_radius * g.bound_radius
        })
    }

    /// Optical depth ∫₀^len σt ds of every particle along `p + s·dir` (`dir` unit), exact
    /// (closed form per particle); stops once it passes `budget`.
    pub fn optical_depth(&self, p: DVec3, dir: DVec3, len_m: f64, budget: f64) -> f64 {
        let mut tau = 0.0;
        if len_m.is_nan() || len_m <= 0.0 {
            return tau;
        }
        for g in self.groups_near(p, dir, 0.0, len_m) {
            for q in &self.particles[g.range.clone()] {
                let to_centre = q.centre - p;
                let s = to_centre.dot(dir).clamp(0.0, len_m);
                let reach = CUT_FALLOFF * q.falloff_u_m;
                if (to_centre - dir * s).length_squared() > reach * reach {
                    continue;
                }
                tau += GaussianAlongRay::from_points(g.sigma_t, q.falloff_u_m, p, dir, q.centre)
                    .optical_depth(0.0, len_m);
                if tau >= budget {
                    return tau;
                }
            }
        }
        tau
    }

    /// Transmittance exp(−τ) of the particles along `p + s·dir`, `s ∈ [0, len_m]`: exactly
    /// 1 where no particle is in reach, 0 once τ reaches [`super::TAU_OPAQUE`].
    pub fn transmittance(&self, p: DVec3, dir: DVec3, len_m: f64) -> f64 {
        let tau = self.optical_depth(p, dir, len_m, super::TAU_OPAQUE);
        if tau >= super::TAU_OPAQUE {
            0.0
        } else {
            (-tau).exp()
        }
    }

    /// Each group's extinction at `p` (the sum of its particles' Gaussians within reach),
    /// for the groups that have some there.
    pub(crate) fn extinction_at(&self, p: DVec3) -> Vec<(usize, f64)> {
        let mut out = Vec::new();
        for (gi, g) in self.groups.iter().enumerate() {
            if (p - g.bound_centre).length_squared() > g.bound_radius * g.bound_radius {
                continue;
            }
            let sigma: f64 = self.particles[g.range.clone()]
                .iter()
                .map(|q| {
                    let l2 = (p - q.centre).length_squared();
                    let reach = CUT_FALLOFF * q.falloff_u_m;
                    if l2 > reach * reach {
                        0.0
                    } else {
                        g.sigma_t * (-50.0 * l2 / (q.falloff_u_m * q.falloff_u_m)).exp()
                    }
                })
                .sum();
            if sigma > 0.0 {
                out.push((gi, sigma));
            }
        }
        out
    }

    /// Where the ray `o + t·dir` (`dir` unit) crosses particles' cut-off balls within
    /// `[t0, t1]`, sorted by entry.
    pub(crate) fn windows(&self, o: DVec3, dir: DVec3, t0: f64, t1: f64) -> Vec<Window> {
        let mut out = Vec::new();
        if t0.is_nan() || t1.is_nan() || t1 <= t0 {
            return out;
        }
        for (gi, g) in self.groups.iter().enumerate() {
            let s = (g.bound_centre - o).dot(dir).clamp(t0, t1);
            if (o + dir * s - g.bound_centre).length_squared() > g.bound_radius * g.bound_radius {
                continue;
            }
            for q in &self.particles[g.range.clone()] {
                let along =
                    GaussianAlongRay::from_points(g.sigma_t, q.falloff_u_m, o, dir, q.centre);
                let reach = CUT_FALLOFF * q.falloff_u_m;
                let half_sq = reach * reach - along.centre_offset_sq_m2;
                if half_sq <= 0.0 {
                    continue;
                }
                let half = half_sq.sqrt();
                let lo = (along.centre_along_m - half).max(t0);
                let hi = (along.centre_along_m + half).min(t1);
                if hi > lo {
                    out.push(Window {
                        lo,
                        hi,
                        along,
                        group: gi,
                    });
                }
            }
        }
        out.sort_by(|a, b| a.lo.total_cmp(&b.lo));
        out
    }
}
