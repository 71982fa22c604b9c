//! Mode `truth`: the ground-truth renderer, on the CPU, independent of every shader.
//!
//! It shares only the scene description (and the media formulas in
//! [`crate::scene::sample_media`]) with the GPU path, so a bug in a WGSL helper cannot
//! hide on both sides of a comparison. Per pixel it traces the primary ray through the
//! BVH, shades the surface with exact shadow rays, and ray-marches the media from the
//! near plane to the surface (or the far plane) with `steps` stratified segments and an
//! exact shadow ray to every light at every step: single scattering, the same
//! Henyey-Greenstein phase and the same light model as `reference` and `shared`.
//!
//! The model (DESIGN.md §4): light reaching a scattering point or a surface is
//! `V · T(x → l) · L_l`, where `V` is the 0/1 occlusion by geometry and
//! `T(x → l) = exp(−∫σt ds)` the transmittance of every medium along the shadow ray
//! (towards a point or spot light, or `max_ray_m` against a directional light's travel).
//! [`ShadowMedia`] computes T only where V = 1: in closed form for homogeneous media and
//! noise-free height fog, by Gauss-Legendre quadrature of the density for noisy media
//! and `[[volume]]` primitives (their analytic displaced-sphere density, at the ray's
//! time, clipped to the ball of their outer radius).
//! Ambient light is a constant, neither occluded nor dimmed. With
//! [`TruthSettings::bounces`] > 0 the renderer path-traces multiple scattering instead,
//! the sky as a light and no ambient ([`paths`]).
//!
//! The march covers only the part of that range inside the media's bounding box (no
//! medium has density outside it), split into `steps` equal segments; each is sampled
//! once (at its midpoint, or at a jittered position with a seed) and integrated with
//! the energy-conserving form
//! `S·(1 − exp(−σt·d))/σt`. With more steps the estimate converges (see
//! `tests/truth.rs`); the default of 512 steps changes the image by less than 0.005
//! mean FLIP when doubled on the built-in scenes. `spp` primary rays per pixel average
//! the radiance over the pixel's footprint (default 1: the pixel centre).
//!
//! With [`TruthSettings::step_amplification`] (`--truth-vsa`, off by default) the
//! segments follow seed 003's variable step amplification (Eq. 4–6, [`VSA_K_A`]): `steps`
//! is the baseline, and a segment is lengthened by up to `max(3t/t_max, f_λ·f_T·f_A)`
//! from what the samples before it saw; never shortened, the last one clipped to the
//! march's end. [`TruthCounts::media_samples`] counts the samples either way
//! (`tests/truth_vsa.rs`: the slab's closed form within 2.5e-5 at 512 baseline steps,
//! and its cost and error against fixed steps).
//!
//! Agreement with what is computed without it (`tests/truth_closed_form.rs`, default
//! settings, 1×1-pixel images of linear radiance): a sun over a homogeneous slab of fog
//! matches the closed form within 8e-5 relative (σt 0.05 and 1 m⁻¹, seven view
//! directions from down at the ground to straight at the sun); a point lamp inside a fog
//! sphere (σt 0.4 m⁻¹) matches an independent f64 quadrature within 1e-5 (rays passing
//! 0.25 to 3 m from it, one looking away, one ending on the lit ground); a shadow ray's
//! transmittance matches a 10⁶-point sum of the density within 8e-5 (every medium kind,
//! the built-in scenes' media within 2e-5). The transmittance costs little where the
//! media are homogeneous or light only reaches part of them (colonnade: 1.3× the time
//! without it, islands 1.8×) and much where long shadow rays to many lamps cross noisy
//! fog (street: 43×, six lights through 60 m of noisy height fog).
//!
//! Smoke (issue 15, [`Smoke`]): the live particles of every `[[emitter]]` at the render's
//! time (`crate::smoke::emitter::particles_at`), each the Gaussian `σt(l) = σ e^{−50l²/u²}`
//! of paper 001 Eq. 9, summed exactly: no tetrahedra, no shadow maps. Extinction is grey
//! as for the media (`σ = mean(σs) + σa` of its emitter), σs per channel, each emitter's
//! HG `g`. Rays ignore a particle farther than [`CUT_FALLOFF`]`·u = 0.8u` from them (its
//! density there is below e^{−32} ≈ 1e-14 of its peak); each emitter is first culled by a
//! sphere around all its particles.
//! - Every shadow ray (surfaces, media samples, smoke samples) multiplies its
//!   transmittance by `exp(−Σ τ_p)`, `τ_p` the particle's optical depth along the segment
//!   in closed form (erf, `GaussianAlongRay::optical_depth`).
//! - A primary ray that crosses particles (within 0.8u of their centres) is cut at every
//!   particle's entry and exit and at every media segment's edge. Pieces inside no
//!   particle are integrated as the media march does (the segment's one sample, the
//!   energy-conserving form). Pieces inside particles are cut into panels of at most half
//!   a standard deviation (u/20) of the narrowest particle, and halved while a panel's
//!   optical depth exceeds [`SMOKE_PANEL_TAU`]; each panel adds `T₀·(1 − e^{−Δτ})·N/D`
//!   with `Δτ` exact (closed form plus the media's σt·length) and `N = ∫T·S`,
//!   `D = ∫σt·T` by 4-point Gauss-Legendre, `T` exact at each node and `S` the media
//!   segment's source plus each emitter's `σs(s)·(ambient + Σ L·V·T_shadow·p_HG(g))` (one
//!   shadow ray per light and node, shared by the emitters; mixed media and smoke weight
//!   their phases by their σs). This is exact wherever the source per extinction is
//!   constant over a panel, so it cannot exceed the light even at σt = 10⁴ m⁻¹, and the
//!   march stops once the transmittance is below 1e-7 (eye inside dense smoke). Particles
//!   behind the near plane or straddling it are integrated from the near plane.
//!
//! Agreement with what is computed without it (`tests/truth_smoke.rs`, 1×1-pixel images,
//! `cargo test --test truth_smoke -- --nocapture`): one particle (u = 1 m, σt 3 m⁻¹)
//! under a sun matches an f64 quadrature whose sun and view transmittances are
//! brute-force sums of the density within 3.3e-7 relative (rays 0, 0.1u, 0.3u, 0.6u
//! from its centre); with the sun behind the eye (`T_light = T_view`, so
//! `L = ϖ·E·p·(1 − T²)/2` exactly) within 2.6e-7 at σt 0.3 to 10⁴ m⁻¹ (τ up to 2500),
//! 1.6e-5 for a particle 10 km away; the eye inside a particle within 2e-7; a lamp
//! inside a particle within 2.2e-7; shadow rays through 40 particles match a 10⁶-point
//! sum within 4e-11 in τ, and the ground lit through them within 3e-8.

use crate::scene::{
    density_at, hg_phase, sample_media, Bvh, Camera, Light, LightKind, Medium, MediumKind, Ray,
    Scene, Volume, VOLUME_EDGE_FRACTION,
};
use glam::{DVec3, Vec3};
use rayon::prelude::*;
use std::sync::atomic::{AtomicUsize, Ordering};

pub mod paths;
mod smoke;

use smoke::Window;
pub use smoke::{Smoke, SmokeGroup, SmokeParticle, CUT_FALLOFF};

/// Gauss-Legendre 4-point nodes on [−1, 1] and their weights (smoke panels).
const GL4: [(f64, f64); 4] = [
    (-0.861_136_311_594_052_6, 0.347_854_845_137_453_9),
    (-0.339_981_043_584_856_3, 0.652_145_154_862_546_1),
    (0.339_981_043_584_856_3, 0.652_145_154_862_546_1),
    (0.861_136_311_594_052_6, 0.347_854_845_137_453_9),
];

/// A primary ray integrates smoke on panels no longer than this many standard deviations
/// (`u/10`) of the narrowest particle it is inside, four Gauss-Legendre nodes each.
pub const SMOKE_PANEL_STD: f64 = 0.5;

/// A smoke panel whose optical depth exceeds this is halved (up to [`SMOKE_MAX_HALVINGS`]
/// times), so that the light's variation within a panel stays small however dense the
/// smoke.
pub const SMOKE_PANEL_TAU: f64 = 0.1;

/// How often a smoke panel may be halved (a panel of one standard deviation down to
/// 2⁻²⁰ of it).
pub const SMOKE_MAX_HALVINGS: u32 = 20;

/// A primary ray's integration stops once its transmittance falls below this (the media
/// march's cut-off).
const T_CUTOFF: f64 = 1e-7;

// Variable step amplification (seed 003 §3.1.3, Eq. 4–6; [`TruthSettings::step_amplification`]):
// with h = (t₁ − t₀)/N the baseline segment over the march's interval [t₀, t₁] (t from
// the eye, t_max = t₁), each segment is
//   Δt(t) = h · max(k_a·t/t₁, f_λ^{w_λ}·f_T^{w_T}·f_A^{w_A}, 1),
//   f_λ = min(k_b/|ρ'|, f_λ^max),  f_T = 1 − σ̃t·h,  f_A = 1 − T(t),
// from what the march knows at t: ρ' is the backward difference of the last two samples'
// extinction (Bergner et al.), expressed as the relative change over one baseline segment,
// |Δσt/Δs|·h / max(σt of the two) (003's densities are normalised and its ρ' is per step);
// σ̃t = σt + σt'·h is the extinction predicted one segment ahead, so that f_T is that
// segment's inverted opacity (clamped to [0, 1]); T is the view transmittance so far.
// k_a and f_λ^max are 003's values; 003 gives neither k_b nor the weights. They were
// tuned on colonnade and cloud at 64×36 against 4096 fixed steps (docs/decisions.md):
// with k_a = 3 the distance term decides almost every segment there, and k_b from 0.02
// to 0.5, w_T 0 or 1, w_A 0.5 to 2 and w_λ 0.5 left the samples and the error within
// about 1 %; w_A = 0.25 and w_λ = 2 were worse (up to 15 % and 6 % more error). k_b = 0.02
// was the best with f_λ alone (k_a = 0): 5–14 % less error per sample than fixed steps on
// colonnade, where k_b ≥ 0.2 lets f_λ reach 2 everywhere (fixed steps of 2h).
/// Seed 003's distance coefficient k_a (its value).
pub const VSA_K_A: f64 = 3.0;
/// Seed 003's wave-length coefficient k_b: the relative change of the extinction over one
/// baseline segment below which f_λ > 1 (tuned, see above).
pub const VSA_K_B: f64 = 0.02;
/// Seed 003's bound f_λ^max on the wave-length factor (its value).
pub const VSA_F_LAMBDA_MAX: f64 = 2.0;
/// Exponent w_λ of the wave-length factor (tuned, see above).
pub const VSA_W_LAMBDA: f64 = 1.0;
/// Exponent w_T of the transparency factor (tuned, see above).
pub const VSA_W_T: f64 = 1.0;
/// Exponent w_A of the attenuation factor (tuned, see above).
pub const VSA_W_A: f64 = 1.0;

/// Seed 003's step amplification (Eq. 4) at ray length `t` of a march ending at `t_max`,
/// baseline segment `h`: `sigma` the last sample's extinction, `slope` the extinction's
/// derivative along the ray (per metre) and `rel` the same as a relative change per
/// baseline segment, `transmittance` the view transmittance so far. At least 1, finite.
fn step_amplification(
    (t, t_max, h): (f64, f64, f64),
    (sigma, slope, rel): (f64, f64, f64),
    transmittance: f64,
) -> f64 {
    let distance = VSA_K_A * t / t_max;
    // min(k_b/|ρ'|, f_max) without dividing by 0: ρ' = 0 gives f_max.
    let f_lambda = if rel * VSA_F_LAMBDA_MAX <= VSA_K_B {
        VSA_F_LAMBDA_MAX
    } else {
        VSA_K_B / rel
    };
    let predicted = (sigma + slope * h).max(0.0);
    let f_t = (1.0 - predicted * h).clamp(0.0, 1.0);
    let f_a = (1.0 - transmittance).clamp(0.0, 1.0);
    let product = f_lambda.powf(VSA_W_LAMBDA) * f_t.powf(VSA_W_T) * f_a.powf(VSA_W_A);
    let amp = distance.max(product).max(1.0);
    if amp.is_finite() {
        amp
    } else {
        1.0
    }
}

/// Parameters of the ground-truth renderer.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct TruthSettings {
    /// Ray-march segments per pixel.
    pub steps: u32,
    /// Seed of the stratified jitter; 0 samples every segment at its midpoint (and every
    /// sub-pixel cell at its centre).
    pub seed: u32,
    /// Primary rays per pixel, averaged in linear radiance before tone mapping: a box
    /// filter over the pixel, as offline renderers report pixels. 1 is the pixel centre.
    /// `n` rays stratify the pixel into ⌊√n⌋ rows of equal height, the rows holding
    /// ⌊n/rows⌋ or one more equal cells, one ray per cell, weighted by its cell's area
    /// (n = k² is the usual k×k grid). A ray sits at its cell's centre with seed 0 and at
    /// a hash-jittered position within it otherwise. Old settings files without the field
    /// read as 1.
    #[serde(default = "one")]
    pub spp: u32,
    /// Quadrature segments per feature length on a shadow ray through a noisy medium
    /// (see [`ShadowMedia`]); the feature length is the finest noise octave's wavelength
    /// 1/(frequency·2^(octaves−1)), or the falloff length of height fog if shorter. At
    /// the default of 2, doubling it changes a shadow ray's transmittance by < 1e-4
    /// relative on the built-in scenes' media and on noisy media of σt 0.12 m⁻¹ over 40 m
    /// (`tests/truth_closed_form.rs`; much denser noise, τ ≫ 1, needs more). Homogeneous
    /// media and noise-free height fog are integrated in closed form and ignore it. Old
    /// settings files read as 2.
    #[serde(default = "default_shadow_segments")]
    pub shadow_segments_per_feature: u32,
    /// Multiple scattering (issue 16): 0 is the single-scattering truth above (lights and
    /// a constant `ambient`); `n > 0` path-traces light that scattered up to `n` times in
    /// the media, the smoke and off surfaces, with the sky as a light and no `ambient`
    /// ([`paths`]). Then `spp` is the paths per pixel (uniformly jittered over it) and
    /// `seed` seeds their random numbers; `steps` is not used. Old settings files read
    /// as 0.
    #[serde(default)]
    pub bounces: u32,
    /// Variable step amplification (issue 16, seed 003 Eq. 4–6, [`VSA_K_A`] and the
    /// constants after it): the media march lengthens its segments where the density is
    /// smooth, the view transmittance already low or the ray far from the eye, never
    /// shortening them below the `steps` equal segments (`steps` is the baseline N). Off
    /// by default: per media sample it is more accurate on some scenes and less on others
    /// (cloud: fewer samples than the default's for 0.63× its error; colonnade: more than
    /// 1.4× the samples for its error; `tests/truth_vsa.rs`, docs/decisions.md). Rays that cross smoke particles keep
    /// equal segments. Old settings files read as off.
    #[serde(default)]
    pub step_amplification: bool,
}

fn one() -> u32 {
    1
}

fn default_shadow_segments() -> u32 {
    2
}

/// A shadow ray integrates at most this many quadrature segments per medium, however long
/// the ray or fine the noise (a 10 km ray through 1000-per-metre noise would otherwise
/// take 10⁸): beyond that the segments grow and average the noise.
pub const MAX_SHADOW_SEGMENTS: u32 = 1 << 14;

/// Optical depth beyond which a shadow ray is opaque: exp(−110) underflows f32 to 0, so
/// the integration stops there and the transmittance is exactly 0.
pub const TAU_OPAQUE: f64 = 110.0;

impl Default for TruthSettings {
    fn default() -> Self {
        TruthSettings {
            steps: 512,
            seed: 0,
            spp: 1,
            shadow_segments_per_feature: default_shadow_segments(),
            bounces: 0,
            step_amplification: false,
        }
    }
}

impl TruthSettings {
    /// The settings for `--truth-steps`, `--truth-spp`, `--truth-bounces` and
    /// `--truth-vsa`: seeded (paths jittered) when path tracing, the pixel-centre rays
    /// otherwise.
    pub fn from_flags(steps: u32, spp: u32, bounces: u32, vsa: bool) -> TruthSettings {
        TruthSettings {
            steps,
            spp,
            bounces,
            seed: u32::from(bounces > 0),
            step_amplification: vsa,
            ..TruthSettings::default()
        }
    }

    /// An error naming the flag and value when a setting is out of range: steps
    /// 1..=65536, bounces 0..=1024, and spp 1..=1024 (rays per pixel) or 1..=2²⁰ (paths);
    /// step amplification only without bounces (paths do not march).
    pub fn validate(&self) -> anyhow::Result<()> {
        anyhow::ensure!(
            !(self.step_amplification && self.bounces > 0),
            "--truth-vsa with --truth-bounces {}: path tracing does not march, use one or the other",
            self.bounces
        );
        anyhow::ensure!(
            (1..=65536).contains(&self.steps),
            "--truth-steps {}: must be 1..=65536",
            self.steps
        );
        anyhow::ensure!(
            self.bounces <= 1024,
            "--truth-bounces {}: must be 0..=1024",
            self.bounces
        );
        let max_spp = if self.bounces > 0 { 1 << 20 } else { 1024 };
        anyhow::ensure!(
            (1..=max_spp).contains(&self.spp),
            "--truth-spp {}: must be 1..={max_spp}",
            self.spp
        );
        Ok(())
    }
}

/// Shadow rays and media samples of one truth render.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct TruthCounts {
    /// Shadow rays from media samples.
    pub media_rays: u64,
    /// Shadow rays from surfaces.
    pub surface_rays: u64,
    /// Points where the primary rays' media march sampled the media (one per segment it
    /// reached, found medium or not; the smoke's Gauss-Legendre nodes are not counted):
    /// the march's cost as a deterministic number, for fixed against amplified steps.
    /// Path tracing (`bounces` > 0) does not march and leaves it 0. Old files read as 0.
    #[serde(default)]
    pub media_samples: u64,
}

/// Direction from `p` towards the light and the shadow-ray length (common.wgsl `to_light`).
fn to_light(l: &Light, p: Vec3, max_ray_m: f32) -> (Vec3, f32) {
    if l.kind == LightKind::Directional {
        return (-l.direction, max_ray_m);
    }
    let d = l.position - p;
    let dist = d.length();
    (d / dist.max(1e-6), dist)
}

/// Radiance arriving at `p`, ignoring occlusion (common.wgsl `light_radiance`).
fn light_radiance(l: &Light, p: Vec3) -> Vec3 {
    if l.kind == LightKind::Directional {
        return l.radiance;
    }
    let d = l.position - p;
    let mut r = l.radiance / d.length_squared().max(0.01);
    if l.kind == LightKind::Spot {
        let c = (-d / d.length().max(1e-6)).dot(l.direction);
        let t = ((c - l.cos_outer) / (l.cos_inner - l.cos_outer)).clamp(0.0, 1.0);
        r *= t * t * (3.0 - 2.0 * t);
    }
    r
}

fn visible(bvh: &Bvh, l: &Light, p: Vec3, max_ray_m: f32) -> bool {
    let (dir, dist) = to_light(l, p, max_ray_m);
    let eps = 1e-4 * (1.0 + p.length() * 0.01);
    !bvh.occluded(&Ray {
        origin: p,
        dir,
        t_min: eps,
        t_max: dist - eps,
    })
}

/// Where a medium has density, in f64 so that a shadow ray far from the origin or
/// kilometres long clips exactly.
#[derive(Debug, Clone, Copy)]
enum Extent {
    /// Axis-aligned box (box media; constant and height fog fill the scene bounds).
    Slab { lo: DVec3, hi: DVec3 },
    /// Sphere media.
    Ball { centre: DVec3, radius_sq: f64 },
    /// A volume primitive: the ball of its outer radius around its centre at the ray's time.
    Volume(Volume),
}

impl Extent {
    /// The part of `[0, len]` on the ray `p + s·dir` (`dir` unit) inside the extent at
    /// scene time `time_s`.
    fn clip(&self, p: DVec3, dir: DVec3, len: f64, time_s: f32) -> Option<(f64, f64)> {
        let (mut enter, mut exit) = (0.0f64, len);
        let (centre, radius_sq) = match *self {
            Extent::Slab { lo, hi } => {
                for k in 0..3 {
                    let (o, d) = (p[k], dir[k]);
                    if d == 0.0 {
                        if o < lo[k] || o > hi[k] {
                            return None;
                        }
                        continue;
                    }
                    let (a, b) = ((lo[k] - o) / d, (hi[k] - o) / d);
                    enter = enter.max(a.min(b));
                    exit = exit.min(a.max(b));
                }
                return (enter < exit).then_some((enter, exit));
            }
            Extent::Ball { centre, radius_sq } => (centre, radius_sq),
            Extent::Volume(v) => (
                v.center_at(time_s).as_dvec3(),
                f64::from(v.outer_radius_m()).powi(2),
            ),
        };
        let oc = p - centre;
        let b = oc.dot(dir);
        let disc = b * b - (oc.length_squared() - radius_sq);
        if disc < 0.0 {
            return None;
        }
        let root = disc.sqrt();
        enter = enter.max(-b - root);
        exit = exit.min(-b + root);
        (enter < exit).then_some((enter, exit))
    }
}

/// How one medium's density varies along a shadow ray.
#[derive(Debug, Clone, Copy)]
enum Profile {
    /// Density 1 over the extent: τ = σt · overlap length.
    Homogeneous,
    /// Noise-free height fog: 1 below `base_y`, exp(−(y − base_y)/falloff) above,
    /// integrated in closed form.
    Height { base_y: f64, falloff_m: f64 },
    /// fbm noise (and possibly height): two-point Gauss-Legendre on segments of at most
    /// `step_m` of [`density_at`] itself; `base_y` is height fog's base, where its density
    /// has a kink.
    Noise { step_m: f64, base_y: Option<f64> },
}

#[derive(Debug, Clone, Copy)]
struct ShadowMedium {
    medium: Medium,
    /// Grey extinction at density 1, σt = mean(σs) + σa (as [`sample_media`]).
    sigma_t: f64,
    extent: Extent,
    profile: Profile,
}

/// The media as shadow rays see them: each medium's extinction, extent and integration
/// rule, worked out once per render so that a shadow ray only clips and sums.
///
/// The optical depth τ = ∫σt ds along a ray is the sum over media (extinction is linear
/// in density). Each medium contributes only over the part of the ray inside its extent
/// (box: slab test; sphere: ray-sphere; constant and height fog: their box, the scene
/// bounds), so a 10 km sun ray costs no more than the medium it crosses. Homogeneous media
/// and noise-free height fog are integrated in closed form; noisy media by two-point
/// Gauss-Legendre on segments of their feature length divided by
/// [`TruthSettings::shadow_segments_per_feature`] (split at height fog's base, where the
/// density has a kink).
#[derive(Debug, Clone)]
pub struct ShadowMedia {
    media: Vec<ShadowMedium>,
}

impl ShadowMedia {
    /// Prepares `media` (render space, as in [`Scene::media`]) for shadow rays, with
    /// `segments_per_feature` quadrature segments per feature length of noisy media (at
    /// least 1). Media without extinction are dropped: they leave T = 1 exactly.
    pub fn new(media: &[Medium], segments_per_feature: u32) -> ShadowMedia {
        let per_feature = f64::from(segments_per_feature.max(1));
        let media = media
            .iter()
            .filter_map(|m| {
                let s = m.scattering.as_dvec3();
                let sigma_t = (s.x + s.y + s.z) / 3.0 + f64::from(m.absorption);
                if sigma_t <= 0.0 {
                    return None;
                }
                let extent = match (m.kind, m.volume) {
                    (MediumKind::Volume, Some(v)) => Extent::Volume(v),
                    (MediumKind::Sphere, _) => Extent::Ball {
                        centre: ((m.min + m.max) * 0.5).as_dvec3(),
                        radius_sq: f64::from(m.radius_or_falloff).powi(2),
                    },
                    _ => Extent::Slab {
                        lo: m.min.as_dvec3(),
                        hi: m.max.as_dvec3(),
                    },
                };
                let height = (m.kind == MediumKind::Height)
                    .then(|| (f64::from(m.base_y), f64::from(m.radius_or_falloff)));
                let n = &m.noise;
                let noisy = n.frequency > 0.0 && n.amplitude > 0.0;
                let profile = if noisy || m.volume.is_some() {
                    let finest_m = if noisy {
                        1.0 / (f64::from(n.frequency) * 2f64.powi(n.octaves.max(1) as i32 - 1))
                    } else {
                        f64::INFINITY
                    };
                    let feature_m = height
                        .map_or(finest_m, |(_, falloff_m)| finest_m.min(falloff_m))
                        .min(m.volume.map_or(f64::INFINITY, |v| volume_feature_m(&v)));
                    Profile::Noise {
                        step_m: feature_m / per_feature,
                        base_y: height.map(|(base_y, _)| base_y),
                    }
                } else if let Some((base_y, falloff_m)) = height {
                    Profile::Height { base_y, falloff_m }
                } else {
                    Profile::Homogeneous
                };
                Some(ShadowMedium {
                    medium: *m,
                    sigma_t,
                    extent,
                    profile,
                })
            })
            .collect();
        ShadowMedia { media }
    }

    /// Optical depth ∫₀^len σt ds along `p + s·dir` (`dir` unit), at scene time `time_s`.
    /// At least [`TAU_OPAQUE`] means opaque: the integration stops there.
    pub fn optical_depth(&self, p: Vec3, dir: Vec3, len_m: f32, time_s: f32) -> f64 {
        let (p, dir) = (p.as_dvec3(), dir.as_dvec3());
        let mut tau = 0.0;
        for m in &self.media {
            let Some((s0, s1)) = m.extent.clip(p, dir, f64::from(len_m), time_s) else {
                continue;
            };
            tau += m.sigma_t
                * match m.profile {
                    Profile::Homogeneous => s1 - s0,
                    Profile::Height { base_y, falloff_m } => height_integral(
                        p.y + dir.y * s0,
                        p.y + dir.y * s1,
                        s1 - s0,
                        base_y,
                        falloff_m,
                    ),
                    Profile::Noise { step_m, base_y } => {
                        let ray = (&m.medium, p, dir, time_s);
                        let budget = (TAU_OPAQUE - tau) / m.sigma_t;
                        // Height fog's density has a kink at its base: split there.
                        let split = base_y
                            .filter(|_| dir.y != 0.0)
                            .map(|base_y| (base_y - p.y) / dir.y)
                            .filter(|s| *s > s0 && *s < s1);
                        match split {
                            Some(sb) => {
                                let below = quadrature(ray, (s0, sb), step_m, budget);
                                below + quadrature(ray, (sb, s1), step_m, budget - below)
                            }
                            None => quadrature(ray, (s0, s1), step_m, budget),
                        }
                    }
                };
            if tau >= TAU_OPAQUE {
                break;
            }
        }
        tau
    }

    /// Transmittance exp(−τ) along `p + s·dir`, `s` in `[0, len_m]`: exactly 1 without
    /// extinction on the way, exactly 0 when τ reaches [`TAU_OPAQUE`], never NaN.
    pub fn transmittance(&self, p: Vec3, dir: Vec3, len_m: f32, time_s: f32) -> f32 {
        let tau = self.optical_depth(p, dir, len_m, time_s);
        if tau >= TAU_OPAQUE {
            0.0
        } else {
            (-tau).exp() as f32
        }
    }
}

/// The shortest length over which a volume's density changes along a ray: its soft
/// edge w = [`VOLUME_EDGE_FRACTION`]·r, shortened where the displaced surface is steep.
/// The surface R(û) = r·(1 + a·(2·fbm − 1)) has features of the finest octave's
/// wavelength 1/(f·2^(octaves−1)) in û, so a ray grazing the shell crosses the edge
/// within about w / (1 + a·f·2^(octaves−1)). (Measured in `tests/volumes.rs`: with 2
/// segments per such length, doubling them changes T by < 1e-4.)
fn volume_feature_m(v: &Volume) -> f64 {
    let edge_m = f64::from(VOLUME_EDGE_FRACTION * v.radius_m);
    if v.amplitude <= 0.0 {
        return edge_m;
    }
    let finest = f64::from(v.frequency) * 2f64.powi(v.octaves.max(1) as i32 - 1);
    let slope = f64::from(v.amplitude) * finest;
    edge_m / (1.0 + slope)
}

/// ∫ of the noise-free height-fog density over a straight path of length `len` from
/// height `y0` to `y1`: density 1 below `base_y`, exp(−(y − base_y)/falloff) above.
fn height_integral(y0: f64, y1: f64, len: f64, base_y: f64, falloff_m: f64) -> f64 {
    let (lo, hi) = (y0.min(y1), y0.max(y1));
    let rise = hi - lo;
    if rise <= 0.0 {
        return len * (-(lo - base_y).max(0.0) / falloff_m).exp();
    }
    // The length below the base is dense; above it the density falls off from the lower
    // end, ∫ exp(−u) over u ∈ [u0, u0 + x] scaled by len/rise·falloff (x ≥ 0, no overflow).
    let below = ((base_y.min(hi) - lo) / rise).max(0.0) * len;
    let start = lo.max(base_y);
    let x = (hi - start) / falloff_m;
    let above = if x <= 0.0 {
        0.0
    } else {
        let u0 = (start - base_y) / falloff_m;
        (-u0).exp() * -(-x).exp_m1() * (len / rise) * falloff_m
    };
    below + above
}

/// ∫ density over `[s0, s1]` of the ray `p + s·dir` through medium `m` at `time_s`:
/// two-point Gauss-Legendre on equal segments no longer than `step_m` (at most
/// [`MAX_SHADOW_SEGMENTS`]); stops once the integral passes `budget`.
fn quadrature(
    (m, p, dir, time_s): (&Medium, DVec3, DVec3, f32),
    (s0, s1): (f64, f64),
    step_m: f64,
    budget: f64,
) -> f64 {
    let n = ((s1 - s0) / step_m)
        .ceil()
        .clamp(1.0, f64::from(MAX_SHADOW_SEGMENTS)) as u32;
    let h = (s1 - s0) / f64::from(n);
    // Nodes at the segment's centre ± h/(2√3), weights h/2.
    let off = h * (0.5 / 3f64.sqrt());
    let at = |s: f64| f64::from(density_at(m, (p + dir * s).as_vec3(), time_s));
    let mut sum = 0.0;
    for i in 0..n {
        let c = s0 + (f64::from(i) + 0.5) * h;
        sum += (at(c - off) + at(c + off)) * (0.5 * h);
        if sum >= budget {
            break;
        }
    }
    sum
}

fn hash(mut h: u32) -> u32 {
    h ^= h >> 16;
    h = h.wrapping_mul(0x7feb_352d);
    h ^= h >> 15;
    h = h.wrapping_mul(0x846c_a68b);
    h ^ (h >> 16)
}

fn unit_float(h: u32) -> f32 {
    (h >> 8) as f32 * (1.0 / 16_777_216.0)
}

/// Sub-pixel position (x, y in [0, 1)) and weight of primary ray `i` of `spp`
/// ([`TruthSettings::spp`]): ⌊√spp⌋ rows of equal height, the last `spp mod rows` of them
/// holding one cell more, each ray in its own cell, weighted by the cell's area. Cell centres
/// with `seed` 0, hash-jittered within the cell otherwise; 1 spp is always the centre.
fn subpixel(i: u32, spp: u32, seed: u32) -> (f32, f32, f32) {
    let rows = spp.isqrt();
    let (per_row, wide_rows) = (spp / rows, spp % rows);
    let narrow = (rows - wide_rows) * per_row;
    let (row, col, cells) = if i < narrow {
        (i / per_row, i % per_row, per_row)
    } else {
        let j = i - narrow;
        (
            rows - wide_rows + j / (per_row + 1),
            j % (per_row + 1),
            per_row + 1,
        )
    };
    let (jx, jy) = if seed == 0 || spp == 1 {
        (0.5, 0.5)
    } else {
        let h = hash(seed ^ hash(i ^ 0x5bd1_e995));
        (unit_float(h), unit_float(hash(h)))
    };
    (
        (col as f32 + jx) / cells as f32,
        (row as f32 + jy) / rows as f32,
        1.0 / (rows * cells) as f32,
    )
}

/// ACES-fitted tone curve (Narkowicz 2015) and the sRGB transfer, as composite.wgsl.
pub fn tone_map(c: Vec3, exposure: f32) -> [u8; 4] {
    let x = c * exposure;
    let aces =
        ((x * (2.51 * x + 0.03)) / (x * (2.43 * x + 0.59) + 0.14)).clamp(Vec3::ZERO, Vec3::ONE);
    let srgb = |v: f32| {
        if v <= 0.003_130_8 {
            v * 12.92
        } else {
            1.055 * v.powf(1.0 / 2.4) - 0.055
        }
    };
    let q = |v: f32| (srgb(v).clamp(0.0, 1.0) * 255.0).round() as u8;
    [q(aces.x), q(aces.y), q(aces.z), 255]
}

/// One image of linear radiance (as [`render_truth_radiance`] returns) to RGBA8 with
/// [`tone_map`].
pub fn tone_map_image(radiance: &[Vec3], exposure: f32) -> Vec<u8> {
    radiance
        .iter()
        .flat_map(|c| tone_map(*c, exposure))
        .collect()
}

struct PixelContext<'a> {
    scene: &'a Scene,
    /// The scene's triangles at `time_s`: its static mesh, plus the movers where it
    /// has any (then `bvh` is built over this mesh).
    mesh: &'a crate::scene::TriangleMesh,
    /// The scene's lights at `time_s` (animated lights moved).
    lights: Vec<crate::scene::Light>,
    /// Bounds of all media (`Scene::media_bounds`), `None` without media.
    media_bounds: Option<(Vec3, Vec3)>,
    /// The media's extinction toward the lights.
    shadow_media: ShadowMedia,
    /// The emitters' live particles at `time_s`.
    smoke: Smoke,
    bvh: &'a Bvh,
    max_ray_m: f32,
    time_s: f32,
    steps: u32,
    /// [`TruthSettings::step_amplification`].
    vsa: bool,
}

impl PixelContext<'_> {
    /// Linear radiance of one pixel, the shadow rays it traced (media, surface) and its
    /// media samples.
    fn shade(&self, cam: &Camera, dir: Vec3, jitter_seed: u32) -> (Vec3, u64, u64, u64) {
        let r = &self.scene.render;
        let cos = dir.dot(cam.forward).max(1e-6);
        let t_near = r.near_m / cos;
        let t_far = r.far_m / cos;
        // A camera ray passes through the side of a surface the scene culls.
        let hit = self.bvh.closest_camera_hit(&Ray {
            origin: cam.position,
            dir,
            t_min: t_near,
            t_max: t_far,
        });
        let (mut color, t_end) = (Vec3::from(r.sky), t_far);
        let mut surface_rays = 0;
        let (color, t_end) = match hit {
            Some((t, tri)) => {
                let p = cam.position + dir * t;
                let [a, b, c] = self.mesh.triangle(tri);
                let mut n = (b - a).cross(c - a).normalize_or(Vec3::Y);
                if n.dot(dir) > 0.0 {
                    n = -n;
                }
                let packed = self.mesh.albedo[self.mesh.indices[tri][0] as usize];
                let albedo = Vec3::new(
                    (packed & 255) as f32,
                    ((packed >> 8) & 255) as f32,
                    ((packed >> 16) & 255) as f32,
                ) / 255.0;
                let depth = t * cos;
                let origin = p + n * (2e-3 + depth * 2e-4);
                let mut irradiance = Vec3::from(r.ambient) * std::f32::consts::PI;
                for l in &self.lights {
                    let (ld, _) = to_light(l, origin, self.max_ray_m);
                    let ndl = n.dot(ld);
                    if ndl <= 0.0 {
                        continue;
                    }
                    let radiance = light_radiance(l, origin);
                    if radiance == Vec3::ZERO {
                        continue;
                    }
                    surface_rays += 1;
                    if visible(self.bvh, l, origin, self.max_ray_m) {
                        // The media dim the light from the surface point itself: the
                        // offset `origin` only keeps the occlusion test off the surface.
                        let (ld, dist) = to_light(l, p, self.max_ray_m);
                        irradiance += radiance * ndl * self.shadow_transmittance(p, ld, dist);
                    }
                }
                color = albedo / std::f32::consts::PI * irradiance;
                (color, t)
            }
            None => (color, t_end),
        };
        // Slab test: march only where media can be (a sky pixel with far = 10 km would
        // otherwise spend its steps tens of metres apart, mostly outside the fog).
        let media = self.media_bounds.and_then(|(lo, hi)| {
            let inv = dir.recip();
            let (a, b) = ((lo - cam.position) * inv, (hi - cam.position) * inv);
            let enter = a.min(b).max_element().max(t_near);
            let exit = a.max(b).min_element().min(t_end);
            (enter < exit).then_some((enter, exit))
        });
        let windows = if self.smoke.is_empty() {
            Vec::new()
        } else {
            self.smoke.windows(
                cam.position.as_dvec3(),
                dir.as_dvec3(),
                f64::from(t_near),
                f64::from(t_end),
            )
        };
        let (scattered, transmittance, media_rays, samples) = match (media, windows.is_empty()) {
            (None, true) => return (color, 0, surface_rays, 0),
            (Some((enter, exit)), true) if self.vsa => {
                self.march_vsa(cam.position, dir, enter, exit, jitter_seed)
            }
            (Some((enter, exit)), true) => self.march(cam.position, dir, enter, exit, jitter_seed),
            (media, false) => self.march_smoke(cam.position, dir, media, &windows, jitter_seed),
        };
        (
            color * transmittance + scattered,
            media_rays,
            surface_rays,
            samples,
        )
    }

    /// Transmittance of the media and the smoke from `p` along `ld` over `dist` metres.
    fn shadow_transmittance(&self, p: Vec3, ld: Vec3, dist: f32) -> f32 {
        if self.smoke.is_empty() {
            return self.shadow_media.transmittance(p, ld, dist, self.time_s);
        }
        let tau = self.shadow_media.optical_depth(p, ld, dist, self.time_s);
        if tau >= TAU_OPAQUE {
            return 0.0;
        }
        let tau = tau
            + self.smoke.optical_depth(
                p.as_dvec3(),
                ld.as_dvec3(),
                f64::from(dist),
                TAU_OPAQUE - tau,
            );
        if tau >= TAU_OPAQUE {
            0.0
        } else {
            (-tau).exp() as f32
        }
    }

    /// The media at `p`: extinction and source `σs·L_in + emission` (in-scattered light
    /// from every light with a shadow ray, plus ambient), `None` where the media neither
    /// extinguish nor emit. Counts its shadow rays in `rays`.
    fn media_source(&self, p: Vec3, dir: Vec3, rays: &mut u64) -> Option<(f32, Vec3)> {
        let m = sample_media(&self.scene.media, p, self.time_s);
        if m.extinction <= 0.0 && m.emission == Vec3::ZERO {
            return None;
        }
        let mut l_in = Vec3::from(self.scene.render.ambient);
        if m.scattering != Vec3::ZERO {
            self.for_each_light(p, p, rays, |ld, light| {
                l_in += light * hg_phase(m.g, ld.dot(dir));
            });
        }
        Some((m.extinction, m.scattering * l_in + m.emission))
    }

    /// The smoke's source at `x` on a ray along `dir`: `Σ_groups σs_g·(ambient + Σ_lights
    /// L·V·T·p_HG(g_g))`, `sigma_s[g]` the scattering of group g at `x`. Each light's
    /// shadow ray is traced once for every group.
    fn smoke_source(&self, x: Vec3, dir: Vec3, sigma_s: &[DVec3], rays: &mut u64) -> DVec3 {
        let total: DVec3 = sigma_s.iter().sum();
        if total == DVec3::ZERO {
            return DVec3::ZERO;
        }
        let mut s = total * Vec3::from(self.scene.render.ambient).as_dvec3();
        self.for_each_light(x, x, rays, |ld, light| {
            let (cos, light) = (ld.dot(dir), light.as_dvec3());
            for (g, sg) in self.smoke.groups().iter().zip(sigma_s) {
                if *sg != DVec3::ZERO {
                    s += *sg * light * f64::from(hg_phase(g.g, cos));
                }
            }
        });
        s
    }

    /// Calls `f(direction to the light, V·T·L)` for every light that reaches `p` (its
    /// radiance there, occlusion tested from `offset`, dimmed by the media and the smoke
    /// from `p`), counting a shadow ray in `rays` for each light that could.
    fn for_each_light(&self, p: Vec3, offset: Vec3, rays: &mut u64, mut f: impl FnMut(Vec3, Vec3)) {
        for l in &self.lights {
            let radiance = light_radiance(l, p);
            if radiance == Vec3::ZERO {
                continue;
            }
            *rays += 1;
            if !visible(self.bvh, l, offset, self.max_ray_m) {
                continue;
            }
            let (ld, dist) = to_light(l, p, self.max_ray_m);
            let t = self.shadow_transmittance(p, ld, dist);
            if t > 0.0 {
                f(ld, radiance * t);
            }
        }
    }

    /// Single scattering along a ray that crosses smoke particles (`windows`, sorted by
    /// entry) and possibly the media (`media`: the range of the media march). The ray is
    /// cut at every window edge and every media segment edge; each medium segment keeps
    /// the one sample of [`march`](Self::march) (the same sample point), and pieces
    /// inside particles are integrated on Gauss-Legendre panels with the particles'
    /// exact optical depth ([`smoke_panel`](Self::smoke_panel)). Returns in-scattered
    /// radiance, transmittance, shadow rays and media samples.
    fn march_smoke(
        &self,
        o: Vec3,
        dir: Vec3,
        media: Option<(f32, f32)>,
        windows: &[Window],
        seed: u32,
    ) -> (Vec3, f32, u64, u64) {
        let n = self.steps;
        let (m0, m1) = media.map_or((f64::INFINITY, f64::NEG_INFINITY), |(a, b)| {
            (f64::from(a), f64::from(b))
        });
        let edge = |k: u32| {
            if k >= n {
                m1
            } else {
                m0 + (m1 - m0) * (f64::from(k) / f64::from(n))
            }
        };
        let start = windows.iter().map(|w| w.lo).fold(m0, f64::min);
        let end = windows.iter().map(|w| w.hi).fold(m1, f64::max);
        let mut closes: Vec<(f64, usize)> =
            windows.iter().enumerate().map(|(i, w)| (w.hi, i)).collect();
        closes.sort_by(|a, b| a.0.total_cmp(&b.0));
        let mut st = SmokeMarch {
            o: o.as_dvec3(),
            dir: dir.as_dvec3(),
            scattered: DVec3::ZERO,
            transmittance: 1.0,
            rays: 0,
            sigma_s: vec![DVec3::ZERO; self.smoke.groups().len()],
        };
        // Indices into `windows` of the particles the ray is inside.
        let mut active: Vec<usize> = Vec::new();
        let (mut opened, mut closed) = (0, 0);
        // The media segment last sampled: (index, extinction, source).
        let mut segment: Option<(u32, f64, DVec3)> = None;
        let mut samples = 0u64;
        let mut cur = start;
        while cur < end && st.transmittance >= T_CUTOFF {
            while opened < windows.len() && windows[opened].lo <= cur {
                active.push(opened);
                opened += 1;
            }
            while closed < closes.len() && closes[closed].0 <= cur {
                if let Some(i) = active.iter().position(|a| *a == closes[closed].1) {
                    active.swap_remove(i);
                }
                closed += 1;
            }
            let mut next = end;
            if let Some(w) = windows.get(opened) {
                next = next.min(w.lo);
            }
            if let Some(c) = closes.get(closed) {
                next = next.min(c.0);
            }
            let mut medium = (0.0, DVec3::ZERO);
            if cur < m1 {
                if cur < m0 {
                    next = next.min(m0);
                } else {
                    let mut k = (((cur - m0) / (m1 - m0)) * f64::from(n))
                        .floor()
                        .clamp(0.0, f64::from(n - 1)) as u32;
                    while k + 1 < n && edge(k + 1) <= cur {
                        k += 1;
                    }
                    while k > 0 && edge(k) > cur {
                        k -= 1;
                    }
                    next = next.min(edge(k + 1));
                    if segment.is_none_or(|(j, _, _)| j != k) {
                        let (a, b) = (edge(k), edge(k + 1));
                        let u = f64::from(segment_jitter(seed, k));
                        let p = (st.o + st.dir * (a + u * (b - a))).as_vec3();
                        samples += 1;
                        let (ext, src) = self
                            .media_source(p, dir, &mut st.rays)
                            .map_or((0.0, DVec3::ZERO), |(e, s)| (f64::from(e), s.as_dvec3()));
                        segment = Some((k, ext, src));
                    }
                    let (_, ext, src) = segment.expect("sampled above");
                    medium = (ext, src);
                }
            }
            if next.is_nan() || next <= cur {
                break;
            }
            if active.is_empty() {
                // Media only: constant over the piece, the march's energy-conserving form.
                let (ext, src) = medium;
                let d = next - cur;
                let tau = ext * d;
                let (s_int, t_step) = if tau < 1e-9 {
                    (src * d, 1.0 - tau)
                } else {
                    let t_step = (-tau).exp();
                    (src * (-(-tau).exp_m1() / ext), t_step)
                };
                st.scattered += st.transmittance * s_int;
                st.transmittance *= t_step;
            } else {
                let inside: Vec<Window> = active.iter().map(|i| windows[*i]).collect();
                let std_min = inside
                    .iter()
                    .map(|w| w.along.falloff_u_m)
                    .fold(f64::INFINITY, f64::min)
                    * 0.1;
                let panels = ((next - cur) / (std_min * SMOKE_PANEL_STD))
                    .ceil()
                    .clamp(1.0, 1e7) as u32;
                for i in 0..panels {
                    let p0 = cur + (next - cur) * (f64::from(i) / f64::from(panels));
                    let p1 = if i + 1 == panels {
                        next
                    } else {
                        cur + (next - cur) * (f64::from(i + 1) / f64::from(panels))
                    };
                    self.smoke_panel(&mut st, (p0, p1), medium, &inside, 0);
                    if st.transmittance < T_CUTOFF {
                        break;
                    }
                }
            }
            cur = next;
        }
        (
            st.scattered.as_vec3(),
            st.transmittance as f32,
            st.rays,
            samples,
        )
    }

    /// One panel `[p0, p1]` of a ray inside smoke (`active` particles, `medium` the media
    /// segment's constant extinction and source). With exact optical depths `τ(s)` from
    /// `p0` (closed form per particle), four Gauss-Legendre nodes estimate
    /// `N = ∫ T(s)·S(s) ds` and `D = ∫ σt(s)·T(s) ds`; the panel adds
    /// `T₀·N·(1 − e^{−Δτ})/D`, the source per extinction averaged with the weight
    /// `σt·T` times the exact fraction the panel absorbs. That is exact for any density
    /// profile where `S/σt` is constant, and never more than the light can give, however
    /// dense the smoke. A panel of `Δτ >` [`SMOKE_PANEL_TAU`] is halved.
    fn smoke_panel(
        &self,
        st: &mut SmokeMarch,
        (p0, p1): (f64, f64),
        (ext, src): (f64, DVec3),
        active: &[Window],
        depth: u32,
    ) {
        let tau_to = |s: f64| {
            ext * (s - p0)
                + active
                    .iter()
                    .map(|w| w.along.optical_depth(p0, s))
                    .sum::<f64>()
        };
        let dtau = tau_to(p1);
        if dtau > SMOKE_PANEL_TAU && depth < SMOKE_MAX_HALVINGS {
            let mid = 0.5 * (p0 + p1);
            self.smoke_panel(st, (p0, mid), (ext, src), active, depth + 1);
            if st.transmittance >= T_CUTOFF {
                self.smoke_panel(st, (mid, p1), (ext, src), active, depth + 1);
            }
            return;
        }
        let (mid, half) = (0.5 * (p0 + p1), 0.5 * (p1 - p0));
        let (mut num, mut den) = (DVec3::ZERO, 0.0);
        for (x, w) in GL4 {
            let s = mid + half * x;
            let weight = w * half;
            let mut sigma_t = ext;
            st.sigma_s.fill(DVec3::ZERO);
            for a in active {
                let e = a.along.extinction_per_m(s);
                sigma_t += e;
                let g = &self.smoke.groups()[a.group];
                st.sigma_s[a.group] += g.scattering * (e / g.sigma_t);
            }
            let t = (-tau_to(s)).exp();
            let pos = (st.o + st.dir * s).as_vec3();
            let sigma_s = std::mem::take(&mut st.sigma_s);
            let source = src + self.smoke_source(pos, st.dir.as_vec3(), &sigma_s, &mut st.rays);
            st.sigma_s = sigma_s;
            num += source * (weight * t);
            den += sigma_t * weight * t;
        }
        let contribution = if den > 0.0 {
            num * (-(-dtau).exp_m1() / den)
        } else {
            num
        };
        st.scattered += st.transmittance * contribution;
        st.transmittance *= (-dtau).exp();
    }

    /// Single-scattering ray march from `t0` to `t1` (equal segments, each sampled once).
    /// Returns in-scattered radiance, transmittance, shadow rays and media samples.
    fn march(&self, o: Vec3, dir: Vec3, t0: f32, t1: f32, seed: u32) -> (Vec3, f32, u64, u64) {
        let mut scattered = Vec3::ZERO;
        let mut transmittance = 1.0f32;
        let mut rays = 0u64;
        let mut samples = 0u64;
        if t1 <= t0 {
            return (scattered, transmittance, rays, samples);
        }
        let n = self.steps;
        let mut a = t0;
        for k in 0..n {
            let b = t0 + (t1 - t0) * ((k + 1) as f32 / n as f32);
            let d = b - a;
            let u = segment_jitter(seed, k);
            let p = o + dir * (a + u * d);
            a = b;
            samples += 1;
            let Some((extinction, s)) = self.media_source(p, dir, &mut rays) else {
                continue;
            };
            if !add_segment(&mut scattered, &mut transmittance, extinction, s, d) {
                break;
            }
        }
        (scattered, transmittance, rays, samples)
    }

    /// As [`march`](Self::march), with seed 003's variable step amplification
    /// ([`step_amplification`]): segment `k` starts where segment `k − 1` ended and is
    /// `h·amplification` long (the last one clipped to `t1`), sampled once at its midpoint
    /// or at the same hash-jittered fraction of it as `march`'s segment `k`.
    fn march_vsa(&self, o: Vec3, dir: Vec3, t0: f32, t1: f32, seed: u32) -> (Vec3, f32, u64, u64) {
        let mut scattered = Vec3::ZERO;
        let mut transmittance = 1.0f32;
        let (mut rays, mut samples) = (0u64, 0u64);
        if t1 <= t0 || !(t1 - t0).is_finite() {
            return (scattered, transmittance, rays, samples);
        }
        let (t0, t1) = (f64::from(t0), f64::from(t1));
        let h = (t1 - t0) / f64::from(self.steps);
        // The last sample (position along the ray, extinction) and the extinction's
        // derivative along the ray, per metre and relative per baseline segment.
        let mut last: Option<(f64, f64)> = None;
        let (mut slope, mut rel) = (0.0f64, 0.0f64);
        let mut a = t0;
        let mut k = 0u32;
        while a < t1 {
            let sigma = last.map_or(0.0, |(_, s)| s);
            let amp = step_amplification((a, t1, h), (sigma, slope, rel), f64::from(transmittance));
            let mut b = a + h * amp;
            // The last segment ends at t1; one within a millionth of h of it is merged.
            if b >= t1 - h * 1e-6 {
                b = t1;
            }
            let d = b - a;
            let u = f64::from(segment_jitter(seed, k));
            let at = a + u * d;
            let p = o + dir * at as f32;
            let d = d as f32;
            a = b;
            k = k.wrapping_add(1);
            samples += 1;
            let sample = self.media_source(p, dir, &mut rays);
            let extinction = sample.map_or(0.0, |(e, _)| e);
            let e = f64::from(extinction);
            if let Some((s_at, s_prev)) = last {
                let ds = at - s_at;
                if ds > 0.0 {
                    slope = (e - s_prev) / ds;
                    let scale = e.max(s_prev);
                    rel = if scale > 0.0 {
                        slope.abs() * h / scale
                    } else {
                        0.0
                    };
                }
            }
            last = Some((at, e));
            let Some((extinction, s)) = sample else {
                continue;
            };
            if !add_segment(&mut scattered, &mut transmittance, extinction, s, d) {
                break;
            }
        }
        (scattered, transmittance, rays, samples)
    }
}

/// Where within segment `k` of a primary ray's march its one sample lies, as a fraction:
/// the midpoint with seed 0, else hash-jittered.
fn segment_jitter(seed: u32, k: u32) -> f32 {
    if seed == 0 {
        0.5
    } else {
        unit_float(hash(seed ^ hash(k.wrapping_mul(0x9e37_79b9))))
    }
}

/// Adds one segment of a primary ray's march, `d` metres through a medium of extinction
/// `extinction` and source `s` (σs·L_in + emission), to the ray's in-scattered radiance
/// and transmittance: it scatters `S·(1 − exp(−σt·d))/σt` towards the eye (`S·d` as
/// σt·d → 0), seen through the transmittance so far. Whether the ray goes on (its
/// transmittance is still above the cut-off).
fn add_segment(
    scattered: &mut Vec3,
    transmittance: &mut f32,
    extinction: f32,
    s: Vec3,
    d: f32,
) -> bool {
    let tau = extinction * d;
    let (s_int, t_step) = if tau < 1e-6 {
        (s * d, 1.0 - tau)
    } else {
        let t_step = (-tau).exp();
        (s * ((1.0 - t_step) / extinction), t_step)
    };
    *scattered += *transmittance * s_int;
    *transmittance *= t_step;
    *transmittance >= T_CUTOFF as f32
}

/// The running state of [`PixelContext::march_smoke`].
struct SmokeMarch {
    /// The ray, in f64.
    o: DVec3,
    dir: DVec3,
    scattered: DVec3,
    transmittance: f64,
    rays: u64,
    /// Scratch: each group's σs at a node.
    sigma_s: Vec<DVec3>,
}

/// Renders every camera at `(width, height)` pixels; returns one RGBA8 image per camera and the
/// rays traced. `progress` is called with (rows done, rows total) as rows finish.
pub fn render_truth(
    scene: &Scene,
    bvh: &Bvh,
    cameras: &[Camera],
    size: (u32, u32),
    time_s: f32,
    settings: TruthSettings,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> (Vec<Vec<u8>>, TruthCounts) {
    let (radiance, counts) =
        render_truth_radiance(scene, bvh, cameras, size, time_s, settings, progress);
    let images = radiance
        .iter()
        .map(|img| tone_map_image(img, scene.render.exposure))
        .collect();
    (images, counts)
}

/// As [`render_truth`], but returns each pixel's linear radiance before exposure and
/// tone mapping (row-major, one `Vec` per camera), so that tests can check it is finite:
/// the RGBA8 tone map turns NaN and inf into black.
pub fn render_truth_radiance(
    scene: &Scene,
    bvh: &Bvh,
    cameras: &[Camera],
    (width, height): (u32, u32),
    time_s: f32,
    settings: TruthSettings,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> (Vec<Vec<Vec3>>, TruthCounts) {
    let (lo, hi) = scene.bounds;
    // Movers: one tree over the static mesh and the movers where they are at `time_s`.
    let with_movers = (!scene.movers.is_empty()).then(|| {
        let mut mesh = scene.mesh.clone();
        mesh.append(&crate::scene::movers_mesh_at(&scene.movers, time_s));
        let bvh =
            Bvh::build(&mesh).expect("the static mesh built a BVH; boxes add 12 triangles each");
        (mesh, bvh)
    });
    let (mesh, bvh) = match &with_movers {
        Some((m, b)) => (m, b),
        None => (&scene.mesh, bvh),
    };
    let ctx = PixelContext {
        scene,
        mesh,
        lights: scene.lights_at(time_s),
        bvh,
        max_ray_m: (hi - lo).length() + 1.0,
        media_bounds: scene.media_bounds(),
        shadow_media: ShadowMedia::new(&scene.media, settings.shadow_segments_per_feature),
        smoke: Smoke::new(&scene.emitters, f64::from(time_s)),
        time_s,
        steps: settings.steps.max(1),
        vsa: settings.step_amplification,
    };
    let spp = settings.spp.max(1);
    let rows_total = cameras.len() * height as usize;
    let rows_done = AtomicUsize::new(0);
    let media_rays = std::sync::atomic::AtomicU64::new(0);
    let surface_rays = std::sync::atomic::AtomicU64::new(0);
    let media_samples = std::sync::atomic::AtomicU64::new(0);
    let images = cameras
        .iter()
        .enumerate()
        .map(|(vi, cam)| {
            let rows: Vec<Vec<Vec3>> = (0..height)
                .into_par_iter()
                .map(|y| {
                    let mut row = Vec::with_capacity(width as usize);
                    let (mut mr, mut sr, mut ms) = (0, 0, 0);
                    for x in 0..width {
                        let seed = if settings.seed == 0 {
                            0
                        } else {
                            hash(settings.seed ^ hash(x ^ hash(y ^ hash(vi as u32)))) | 1
                        };
                        let mut c = Vec3::ZERO;
                        if settings.bounces > 0 {
                            // Paths: jittered over the pixel, one generator each.
                            let pixel = (vi as u64) << 40 | u64::from(y) << 20 | u64::from(x);
                            for i in 0..spp {
                                let mut rng = paths::PathRng::new(
                                    u64::from(hash(settings.seed ^ hash(i))) << 32
                                        ^ pixel.wrapping_mul(0x9E37_79B9_7F4A_7C15),
                                );
                                let (dx, dy) = (rng.unit() as f32, rng.unit() as f32);
                                let dir = cam.ray_dir(x as f32 + dx, y as f32 + dy, width, height);
                                c += ctx.trace_path(
                                    cam.position,
                                    cam.forward,
                                    dir,
                                    settings.bounces,
                                    &mut rng,
                                    (&mut mr, &mut sr),
                                );
                            }
                            row.push(c / spp as f32);
                            continue;
                        }
                        for i in 0..spp {
                            let (dx, dy, weight) = subpixel(i, spp, seed);
                            let dir = cam.ray_dir(x as f32 + dx, y as f32 + dy, width, height);
                            // Ray 0 marches with the pixel's seed, so 1 spp is unchanged.
                            let march_seed = if seed == 0 || i == 0 {
                                seed
                            } else {
                                hash(seed ^ hash(i)) | 1
                            };
                            let (ci, m, s, n) = ctx.shade(cam, dir, march_seed);
                            c += ci * weight;
                            mr += m;
                            sr += s;
                            ms += n;
                        }
                        row.push(c);
                    }
                    media_rays.fetch_add(mr, Ordering::Relaxed);
                    surface_rays.fetch_add(sr, Ordering::Relaxed);
                    media_samples.fetch_add(ms, Ordering::Relaxed);
                    progress(rows_done.fetch_add(1, Ordering::Relaxed) + 1, rows_total);
                    row
                })
                .collect();
            rows.concat()
        })
        .collect();
    let counts = TruthCounts {
        media_rays: media_rays.into_inner(),
        surface_rays: surface_rays.into_inner(),
        media_samples: media_samples.into_inner(),
    };
    (images, counts)
}
