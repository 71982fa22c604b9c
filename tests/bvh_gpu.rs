//! The WGSL BVH traversal (`occluded()` in shaders/bvh.wgsl, the one every stage traces)
//! against two CPU answers on Sponza: every triangle tested (the yardstick) and `obvhs`'
//! own traversal. A disagreement is excused only when the ray is numerically ambiguous:
//! it passes within a hair of a triangle edge, ends within a hair of a surface, or
//! grazes a triangle's plane. Excused rays must stay rare.

use fogcast::gpu::GpuContext;
use fogcast::render::trace_shadow_rays;
use fogcast::scene::{Bvh, LightKind, Ray, Scene};
use glam::{DVec3, Vec3};
use rayon::prelude::*;
use std::path::Path;
use std::time::Instant;

const SPONZA_GLB: &str = "../shared/scenes/sponza.glb";
const RAYS: usize = 12_288;
/// Barycentric distance from an edge below which f32 evaluation order decides (1e-4 of
/// the triangle, the brief's bound).
const EDGE_EPS: f64 = 1e-4;
/// |cos| between a ray and a triangle's plane below which u, v and t are ill-conditioned.
const GRAZING_COS: f64 = 1e-4;

/// SplitMix64: deterministic, dependency-free.
struct Rng(u64);

impl Rng {
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    fn unit(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 / (1u64 << 24) as f32
    }

    fn range(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.unit()
    }

    /// Uniform on the unit sphere.
    fn direction(&mut self) -> Vec3 {
        let z = self.range(-1.0, 1.0);
        let phi = self.range(0.0, std::f32::consts::TAU);
        let r = (1.0 - z * z).max(0.0).sqrt();
        Vec3::new(r * phi.cos(), r * phi.sin(), z)
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Kind {
    /// Random direction, 5 cm to 4 m: mostly visible.
    Short,
    /// Random direction across the whole scene: mostly blocked.
    Long,
    /// Towards the scene's sun (jittered by a few degrees), across the scene.
    Sun,
    /// Along ±x, ±y or ±z: parallel to Sponza's walls and floors, the slab test's hard case.
    AxisAligned,
    /// Random direction of length 0.1–10 m with t scaled to match (no unit-length assumption).
    Unnormalised,
}

const KINDS: [Kind; 5] = [
    Kind::Short,
    Kind::Long,
    Kind::Sun,
    Kind::AxisAligned,
    Kind::Unnormalised,
];

fn make_rays(scene: &Scene, n: usize) -> Vec<(Kind, Ray)> {
    let (lo, hi) = scene.bounds;
    let diagonal = (hi - lo).length();
    let to_sun = -scene
        .lights
        .iter()
        .find(|l| l.kind == LightKind::Directional)
        .expect("sponza.toml has a sun")
        .direction;
    let mut rng = Rng(0x5eed_f0c4_57a1_2345);
    (0..n)
        .map(|i| {
            let origin = Vec3::new(
                rng.range(lo.x, hi.x),
                rng.range(lo.y, hi.y),
                rng.range(lo.z, hi.z),
            );
            let t_min = if i % 4 == 0 { 0.0 } else { 1e-4 };
            // 35 % short, 25 % long, 25 % sun, 7.5 % axis-aligned, 7.5 % unnormalised.
            let pick = rng.unit();
            let (kind, dir, t_max) = if pick < 0.35 {
                (Kind::Short, rng.direction(), rng.range(0.05, 4.0))
            } else if pick < 0.60 {
                (Kind::Long, rng.direction(), diagonal)
            } else if pick < 0.85 {
                (
                    Kind::Sun,
                    (to_sun + rng.direction() * 0.05).normalize(),
                    diagonal,
                )
            } else if pick < 0.925 {
                let axis = Vec3::AXES[(rng.next_u64() % 3) as usize];
                let sign = if rng.unit() < 0.5 { -1.0 } else { 1.0 };
                (Kind::AxisAligned, axis * sign, rng.range(0.05, diagonal))
            } else {
                let scale = rng.range(0.1, 10.0);
                (
                    Kind::Unnormalised,
                    rng.direction() * scale,
                    rng.range(0.05, diagonal) / scale,
                )
            };
            (
                kind,
                Ray {
                    origin,
                    dir,
                    t_min,
                    t_max,
                },
            )
        })
        .collect()
}

/// Why a ray's answer may legitimately depend on f32 evaluation order, or `None`.
///
/// Recomputes, in f64, where the ray meets the plane of every triangle it comes near:
/// ambiguous if it meets one within `EDGE_EPS` of an edge (barycentrics), or within a
/// relative 1e-4 of either end of the segment, or runs nearly parallel to a triangle's
/// plane while passing over it.
fn ambiguity(ray: &Ray, triangles: &[[Vec3; 3]]) -> Option<String> {
    let o = ray.origin.as_dvec3();
    let d = ray.dir.as_dvec3();
    let d_len = d.length();
    let (t0, t1) = (ray.t_min as f64, ray.t_max as f64);
    let t_eps = 1e-4 * (1.0 + t1 * d_len) / d_len;
    let mut reasons = Vec::new();
    for (index, [a, b, c]) in triangles.iter().enumerate() {
        let (a, b, c) = (a.as_dvec3(), b.as_dvec3(), c.as_dvec3());
        let (e1, e2) = (b - a, c - a);
        let normal = e1.cross(e2);
        let cos = normal.dot(d) / (normal.length() * d_len);
        let p = d.cross(e2);
        let det = e1.dot(p);
        let s = o - a;
        if cos.abs() < GRAZING_COS {
            // Parallel: does the segment pass over the triangle within a hair of its plane?
            let plane_dist = (s.dot(normal) / normal.length()).abs();
            let scale = e1.length().max(e2.length());
            if plane_dist < 1e-4 * (1.0 + scale)
                && segment_near_triangle(o, d, t0, t1, [a, b, c], 1e-3 * (1.0 + scale))
            {
                reasons.push(format!(
                    "grazes triangle {index} (cos {cos:.1e}, {plane_dist:.1e} m from its plane)"
                ));
            }
            continue;
        }
        let inv = 1.0 / det;
        let u = s.dot(p) * inv;
        let q = s.cross(e1);
        let v = d.dot(q) * inv;
        let w = 1.0 - u - v;
        let t = e2.dot(q) * inv;
        let min_bary = u.min(v).min(w);
        if min_bary < -EDGE_EPS || t < t0 - t_eps || t > t1 + t_eps {
            continue;
        }
        if min_bary < EDGE_EPS {
            reasons.push(format!(
                "passes {min_bary:.1e} from an edge of triangle {index} at t = {t:.4}"
            ));
        } else if (t - t1).abs() < t_eps || (t - t0).abs() < t_eps {
            reasons.push(format!(
                "ends {:.1e} from triangle {index}",
                (t - t1).abs().min((t - t0).abs())
            ));
        }
    }
    (!reasons.is_empty()).then(|| reasons.join("; "))
}

/// Whether some point of the segment lies within `tol` (metres) of the triangle,
/// sampled finely enough for a nearly parallel segment (the caller checked the plane).
fn segment_near_triangle(
    o: DVec3,
    d: DVec3,
    t0: f64,
    t1: f64,
    [a, b, c]: [DVec3; 3],
    tol: f64,
) -> bool {
    // Closest approach of the segment to the triangle's centroid-bounding sphere first.
    let centre = (a + b + c) / 3.0;
    let radius = (a - centre)
        .length()
        .max((b - centre).length())
        .max((c - centre).length());
    let t_closest = ((centre - o).dot(d) / d.length_squared()).clamp(t0, t1);
    (o + d * t_closest - centre).length() <= radius + tol
}

#[test]
fn gpu_bvh_traversal_matches_brute_force_on_sponza() {
    assert!(
        Path::new(SPONZA_GLB).exists(),
        "{SPONZA_GLB} is missing: this test needs the shared Sponza mesh (run tests from the repository root, \
         with the shared scenes checked out beside it)"
    );
    let t = Instant::now();
    let scene = Scene::load("scenes/sponza.toml").expect("scenes/sponza.toml loads");
    let bvh = Bvh::build(&scene.mesh).expect("BVH builds");
    assert!(
        bvh.triangle_count() > 250_000,
        "Sponza has {} triangles, expected ~262k",
        bvh.triangle_count()
    );
    println!(
        "load + BVH: {} triangles, depth {}, {:.2} s",
        bvh.triangle_count(),
        bvh.depth,
        t.elapsed().as_secs_f64()
    );

    let rays = make_rays(&scene, RAYS);
    let plain: Vec<Ray> = rays.iter().map(|(_, r)| *r).collect();

    let t = Instant::now();
    let ctx = GpuContext::new().expect("a Vulkan adapter (lavapipe on CI)");
    let gpu = trace_shadow_rays(&ctx, &bvh, &plain).expect("GPU ray query");
    assert_eq!(gpu.len(), plain.len());
    println!(
        "GPU ({}): {:.2} s",
        ctx.adapter_info.name,
        t.elapsed().as_secs_f64()
    );

    let t = Instant::now();
    let brute: Vec<bool> = plain
        .par_iter()
        .map(|r| bvh.occluded_brute_force(r))
        .collect();
    println!("brute force: {:.2} s", t.elapsed().as_secs_f64());
    let tree: Vec<bool> = plain.iter().map(|r| bvh.occluded(r)).collect();

    // Both categories must be well populated, or agreement proves nothing.
    let occluded = brute.iter().filter(|b| **b).count();
    let fraction = occluded as f64 / RAYS as f64;
    println!("occluded {occluded} / {RAYS} ({:.1} %)", fraction * 100.0);
    assert!(
        (0.2..=0.8).contains(&fraction),
        "occluded fraction {fraction:.3}: the ray mix no longer tests both answers"
    );
    for kind in KINDS {
        let (n, blocked) = rays
            .iter()
            .zip(&brute)
            .filter(|((k, _), _)| *k == kind)
            .fold((0, 0), |(n, b), (_, o)| (n + 1, b + usize::from(*o)));
        println!("  {kind:?}: {n} rays, {blocked} occluded");
        assert!(n >= RAYS / 20, "{kind:?}: only {n} rays");
        if kind != Kind::Long {
            assert!(
                blocked > n / 20 && blocked < n - n / 20,
                "{kind:?}: {blocked} of {n} occluded; expected a mix"
            );
        }
    }

    let mut excused = 0;
    let mut failures = Vec::new();
    for (name, answers) in [("GPU", &gpu), ("obvhs", &tree)] {
        let mut disagree = 0;
        for (i, ((kind, ray), (&got, &want))) in
            rays.iter().zip(answers.iter().zip(&brute)).enumerate()
        {
            if got == want {
                continue;
            }
            disagree += 1;
            match ambiguity(ray, bvh.triangles()) {
                Some(why) => {
                    excused += 1;
                    println!("  {name} ray {i} ({kind:?}) excused: {why}");
                }
                None => failures.push(format!(
                    "{name} says occluded={got}, brute force {want}: ray {i} ({kind:?}) {ray:?}"
                )),
            }
        }
        println!("{name} vs brute force: {disagree} disagreements");
    }
    println!("excused (numerically ambiguous) rays: {excused}");
    assert!(
        failures.is_empty(),
        "{} unexcused disagreements:\n{}",
        failures.len(),
        failures.join("\n")
    );
    assert!(
        (excused as f64) < 0.005 * RAYS as f64,
        "{excused} excused disagreements out of {RAYS} rays: more than 0.5 %, the traversal is suspect"
    );
}

#[test]
fn ambiguity_detector_flags_edges_and_endpoints_only() {
    // A unit right triangle in the z = 0 plane; rays come down -z.
    let tri = [[Vec3::ZERO, Vec3::X, Vec3::Y]];
    let down = |x: f32, y: f32, t_max: f32| Ray {
        origin: Vec3::new(x, y, 1.0),
        dir: Vec3::NEG_Z,
        t_min: 0.0,
        t_max,
    };
    assert!(ambiguity(&down(0.3, 0.3, 2.0), &tri).is_none(), "clear hit");
    assert!(
        ambiguity(&down(2.0, 2.0, 2.0), &tri).is_none(),
        "clear miss"
    );
    assert!(
        ambiguity(&down(0.3, 0.3, 0.5), &tri).is_none(),
        "ends well before the plane"
    );
    assert!(
        ambiguity(&down(0.5, 0.5, 2.0), &tri).is_some(),
        "on the hypotenuse"
    );
    assert!(
        ambiguity(&down(0.3, 0.0, 2.0), &tri).is_some(),
        "on an edge"
    );
    assert!(
        ambiguity(&down(0.3, 0.3, 1.0), &tri).is_some(),
        "ends on the surface"
    );
    let grazing = Ray {
        origin: Vec3::new(-1.0, 0.2, 1e-6),
        dir: Vec3::X,
        t_min: 0.0,
        t_max: 3.0,
    };
    assert!(ambiguity(&grazing, &tri).is_some(), "skims the plane");
    let parallel_far = Ray {
        origin: Vec3::new(-1.0, 0.2, 0.5),
        dir: Vec3::X,
        t_min: 0.0,
        t_max: 3.0,
    };
    assert!(
        ambiguity(&parallel_far, &tri).is_none(),
        "parallel, half a metre above"
    );
}
