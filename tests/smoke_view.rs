//! Smoke per viewer (issue 15, paper 001): the GPU's back-to-front sort, the interval
//! integral's alpha against the CPU twin (`fogcast::smoke::interval`), the smoke in the
//! image and inside the fog, and the hard inputs (near plane, eye inside the smoke, σ 10⁴,
//! tiny and far particles, a light inside the smoke, no particles).

mod gpu_support;

use fogcast::render::{Renderer, Settings};
use fogcast::scene::{Camera, Scene};
use fogcast::smoke::emitter::particles_at;
use fogcast::smoke::interval::GaussianAlongRay;
use glam::{DVec3, Vec3};
use gpu_support::gpu;
use std::path::Path;
use std::sync::Arc;

const W: u32 = 64;
const H: u32 = 36;
const FOV: f32 = std::f32::consts::FRAC_PI_3; // 60°
const NEAR: f32 = 0.1;

fn load(text: &str) -> Arc<Scene> {
    Arc::new(
        Scene::from_toml(text, Path::new("inline.toml"))
            .unwrap_or_else(|e| panic!("scene does not load: {e}\n{text}")),
    )
}

/// Ground, a sun straight down, an absorbing fog box between viewer 1 and the lone
/// particle (z from 2 to 4), and `extra` (emitters).
fn scene(extra: &str) -> Arc<Scene> {
    load(&format!(
        "name = \"smoke\"\n[camera]\npath = [[0.0, 2.0, 6.0], [0.0, 2.0, 5.0]]\n\
         [render]\nnear_m = {NEAR}\nfar_m = 60.0\nambient = [0.05, 0.05, 0.05]\n\
         [[mesh]]\nkind = \"box\"\nmin = [-20.0, -0.5, -20.0]\nmax = [20.0, 0.0, 20.0]\n\
         [[light]]\nkind = \"directional\"\ndirection = [0.0, -1.0, 0.0]\nintensity = 3.0\n\
         [[medium]]\nkind = \"box\"\nmin = [-2.0, 0.0, 2.0]\nmax = [2.0, 4.0, 4.0]\n\
         scattering = [0.0, 0.0, 0.0]\nabsorption = 0.5\n{extra}"
    ))
}

/// One static particle at (0, 2, 0): σ = σa + mean σs = 1.5 m⁻¹, u = 3 m, g = 0.
const LONE: &str =
    "[[emitter]]\nposition = [0.0, 2.0, 0.0]\nrate_per_s = 1.0\nlifetime_s = 10000.0\n\
     falloff_u = 3.0\nscattering = [1.0, 1.0, 1.0]\nabsorption = 0.5\nmax_particles = 1\n";
const SIGMA: f64 = 1.5;
/// A static cloud of 21 particles at (−8, 2, −8), off viewer 0's view, beside viewer 1's
/// particle.
const CLOUD: &str = "[[emitter]]\nshape = \"sphere\"\nposition = [-8.0, 2.0, -8.0]\nradius = 1.5\n\
     rate_per_s = 40.0\nlifetime_s = 10000.0\nfalloff_u = 0.5\nscattering = [1.5, 1.5, 1.5]\n\
     absorption = 0.2\nmax_particles = 64\n";

/// A camera at world point `at` (the scene's render space is world − origin).
fn camera(scene: &Scene, at: Vec3, forward: Vec3) -> Camera {
    Camera::new(at - scene.origin.as_vec3(), forward, FOV)
}

/// Viewer 0 looks at the lone particle along +x through clear air, viewer 1 along −z
/// through the fog box; both 10 m from it.
fn cameras(scene: &Scene) -> [Camera; 2] {
    [
        camera(scene, Vec3::new(-10.0, 2.0, 0.0), Vec3::X),
        camera(scene, Vec3::new(0.0, 2.0, 10.0), Vec3::NEG_Z),
    ]
}

/// The eye ray through pixel (x, y)'s centre (`view_ray` in common.wgsl), f64.
fn pixel_ray(c: &Camera, x: u32, y: u32) -> DVec3 {
    let right = c.forward.cross(c.up()).normalize();
    let up = right.cross(c.forward);
    let tan_y = (c.fov_y * 0.5).tan();
    let tan_x = tan_y * W as f32 / H as f32;
    let ndc = (
        2.0 * (x as f32 + 0.5) / W as f32 - 1.0,
        1.0 - 2.0 * (y as f32 + 0.5) / H as f32,
    );
    (c.forward + right * (ndc.0 * tan_x) + up * (ndc.1 * tan_y))
        .as_dvec3()
        .normalize()
}

/// Every emitter's live particles, in the GPU's slot order: (centre, u).
fn live(scene: &Scene, time_s: f64) -> Vec<(DVec3, f64)> {
    scene
        .emitters
        .iter()
        .flat_map(|e| particles_at(e, time_s))
        .map(|p| (p.centre, p.falloff_u_m))
        .collect()
}

fn renderer(scene: Arc<Scene>) -> Renderer {
    Renderer::new(gpu(), scene, Settings::default()).expect("renderer")
}

#[test]
fn smoke_sorts_integrates_and_sits_inside_the_fog() {
    let t = 0.5;
    let with = scene(&format!("{LONE}{CLOUD}"));
    let without = scene("");
    let cams = cameras(&with);
    let mut r = renderer(with.clone());
    let mut bare = renderer(without);

    // (6) No live particle yet (before the emitters start): bit-identical to no emitters.
    let before = r.render(&cams, W, H, -1.0).unwrap();
    assert_eq!(r.particle_count(), 0);
    let bare_before = bare.render(&cams, W, H, -1.0).unwrap();
    assert!(!before
        .stats
        .stage_gpu_ms
        .iter()
        .any(|s| s.stage.starts_with("smoke")));
    for v in 0..2 {
        assert!(
            before.images[v] == bare_before.images[v],
            "viewer {v}: zero particles change the image"
        );
    }

    let out = r.render(&cams, W, H, t as f32).unwrap();
    let bare_out = bare.render(&cams, W, H, t as f32).unwrap();
    let particles = live(&with, t);
    assert_eq!(r.particle_count() as usize, particles.len());
    assert!(particles.len() > 16, "{} particles", particles.len());
    for s in &out.stats.stage_gpu_ms {
        if s.stage.starts_with("smoke") {
            println!("stage {} {:.3} ms", s.stage, s.gpu_ms);
        }
    }

    // (1) The GPU's order is the CPU's sort of the same keys (back to front, ties by slot),
    // and its keys are the CPU's distances.
    let order = r.read_smoke_order().unwrap();
    assert_eq!(order.len(), 2);
    let mut worst_key = 0f64;
    for (v, list) in order.iter().enumerate() {
        let eye = cams[v].position.as_dvec3();
        let mut slots: Vec<u32> = list.iter().map(|(s, _)| *s).collect();
        slots.sort_unstable();
        assert_eq!(
            slots,
            (0..particles.len() as u32).collect::<Vec<_>>(),
            "viewer {v}"
        );
        let mut cpu: Vec<(u32, f32)> = list.clone();
        cpu.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
        assert_eq!(&cpu, list, "viewer {v}: not sorted back to front");
        for (slot, key) in list {
            let d = (particles[*slot as usize].0 - eye).length();
            worst_key = worst_key.max((f64::from(*key) - d).abs() / d);
        }
        // The CPU's own keys give the same order wherever they are not a near tie.
        let mut by_cpu: Vec<u32> = (0..particles.len() as u32).collect();
        by_cpu.sort_by(|a, b| {
            let da = (particles[*a as usize].0 - eye).length();
            let db = (particles[*b as usize].0 - eye).length();
            db.total_cmp(&da).then(a.cmp(b))
        });
        let gpu_order: Vec<u32> = list.iter().map(|(s, _)| *s).collect();
        let moved = by_cpu
            .iter()
            .zip(&gpu_order)
            .filter(|(a, b)| a != b)
            .count();
        println!(
            "viewer {v}: {} particles, {moved} placed differently from the f64 sort",
            list.len()
        );
        assert!(moved <= 2, "viewer {v}: {moved} out of place");
    }
    println!("sort keys: worst relative difference from f64 {worst_key:.2e}");
    assert!(worst_key < 1e-5);

    // (2) The lone particle's alpha per pixel against 1 − e^{−τ} of the CPU twin.
    let layers = r.read_smoke_layers().unwrap();
    let (lone, u) = particles[0];
    let mut worst = 0f64;
    let mut peak = 0f64;
    for v in 0..2 {
        let c = &cams[v];
        let eye = c.position.as_dvec3();
        for y in 0..H {
            for x in 0..W {
                let dir = pixel_ray(c, x, y);
                let gpu_a = f64::from(layers[v][(x + y * W) as usize][3]);
                let t0 = f64::from(NEAR) / dir.dot(c.forward.as_dvec3());
                let ground = -with.origin.y;
                let t1 = if dir.y < 0.0 {
                    (eye.y - ground) / -dir.y
                } else {
                    1e3
                };
                let g = GaussianAlongRay::from_points(SIGMA, u, eye, dir, lone);
                let cpu_a = -(-g.optical_depth(t0, t1)).exp_m1();
                // The cloud is beside viewer 1's particle: compare where the lone one is.
                if v == 1 && (lone - eye).normalize().dot(dir) < 0.97 {
                    continue;
                }
                worst = worst.max((gpu_a - cpu_a).abs());
                peak = peak.max(cpu_a);
            }
        }
    }
    println!("alpha: peak {peak:.4}, worst |GPU − CPU| {worst:.2e}");
    assert!(peak > 0.4, "peak alpha {peak}");
    assert!(worst < 1e-3, "alpha off by {worst}");

    // (3) Smoke changes the pixels it covers; elsewhere only its shadow darkens.
    for (v, layer) in layers.iter().enumerate() {
        let (mut covered, mut changed, mut clear, mut shadowed) = (0, 0, 0, 0);
        for (i, s) in layer.iter().enumerate() {
            let a = &out.images[v][i * 4..i * 4 + 4];
            let b = &bare_out.images[v][i * 4..i * 4 + 4];
            if s[3] == 0.0 {
                // Where no particle is drawn the smoke can only take light away: its
                // shadow (the shared smoke shadow maps) on the ground and the fog.
                clear += 1;
                shadowed += usize::from(a != b);
                assert!(
                    a.iter().zip(b).all(|(x, y)| x <= y),
                    "viewer {v} pixel {i}: brighter without smoke in front ({a:?} vs {b:?})"
                );
            } else if s[3] > 0.1 {
                covered += 1;
                changed += usize::from(a != b);
            }
        }
        println!("viewer {v}: {covered} pixels under smoke (α > 0.1), {changed} changed; {clear} clear, {shadowed} of them in its shadow (darker)");
        assert!(
            covered >= 8 && clear > 500,
            "{covered} covered, {clear} clear"
        );
        assert!(changed * 10 >= covered * 9);
    }

    // (4) Through 2 m of absorbing fog (σa 0.5) the smoke's premultiplied colour is the
    // clear view's times the fog's transmittance in front of it (g = 0 and a sun from
    // straight above: the particle looks the same from either side).
    // Per pixel the two views cross the particle along different rays, and the smoke's
    // self-shadowing (the shared smoke shadow maps) differs along them; summed over the
    // particle the views match (the sun is straight above, the views mirror each other).
    let (mut n, mut clear_sum, mut fog_sum, mut expect_sum) = (0, 0f64, 0f64, 0f64);
    for y in 0..H {
        for x in 0..W {
            let i = (x + y * W) as usize;
            let (clear_s, fog_s) = (layers[0][i], layers[1][i]);
            if clear_s[3] < 0.1 {
                continue;
            }
            let dir = pixel_ray(&cams[1], x, y);
            let expect = (-0.5 * 2.0 / dir.z.abs()).exp();
            clear_sum += f64::from(clear_s[1]);
            fog_sum += f64::from(fog_s[1]);
            expect_sum += expect * f64::from(clear_s[1]);
            n += 1;
            assert!(
                (fog_s[3] - clear_s[3]).abs() < 2e-3,
                "alpha differs at {x},{y}"
            );
        }
    }
    let worst_t = (fog_sum / expect_sum - 1.0).abs();
    println!(
        "fog in front: {n} pixels, transmittance e^-1 ≈ 0.368, summed colour ratio {:.4}, relative error {worst_t:.3}",
        fog_sum / clear_sum
    );
    assert!(n >= 8, "{n} pixels");
    assert!(worst_t < 0.05, "smoke behind fog off by {worst_t}");

    // Timing of the smoke stages at 1 and 4 viewers (22 particles, 64×36; the second
    // frame of each count, after the sets' reallocation).
    for n in [1usize, 4] {
        let cams: Vec<Camera> = (0..n).map(|k| cams[k % 2]).collect();
        r.render(&cams, W, H, t as f32).unwrap();
        let out = r.render(&cams, W, H, t as f32).unwrap();
        for s in &out.stats.stage_gpu_ms {
            if s.stage.starts_with("smoke") || s.stage == "composite" {
                println!("{n} viewer(s): {} {:.3} ms", s.stage, s.gpu_ms);
            }
        }
    }
}

#[test]
fn smoke_hard_inputs_stay_finite() {
    // A particle across the near plane of viewer 0, a big particle around viewer 1's eye
    // with a point light inside it, σ = 10⁴ m⁻¹, u = 1 mm, a particle 10⁴ m away, and a
    // cloud at its cap.
    let emitters =
        "[[emitter]]\nposition = [0.0, 2.0, 5.95]\nrate_per_s = 1.0\nlifetime_s = 10000.0\n\
         falloff_u = 2.0\nscattering = [3.0, 3.0, 3.0]\nmax_particles = 1\n\
         [[emitter]]\nposition = [10.0, 2.0, 0.0]\nrate_per_s = 1.0\nlifetime_s = 10000.0\n\
         falloff_u = 4.0\nscattering = [0.5, 0.5, 0.5]\nabsorption = 0.1\nmax_particles = 1\n\
         [[emitter]]\nposition = [1.0, 1.5, -2.0]\nrate_per_s = 1.0\nlifetime_s = 10000.0\n\
         falloff_u = 0.8\nscattering = [10000.0, 10000.0, 10000.0]\nmax_particles = 1\n\
         [[emitter]]\nposition = [-1.0, 1.5, -2.0]\nrate_per_s = 1.0\nlifetime_s = 10000.0\n\
         falloff_u = 0.001\nscattering = [10000.0, 10000.0, 10000.0]\nmax_particles = 1\n\
         [[emitter]]\nposition = [0.0, 2.0, -10000.0]\nrate_per_s = 1.0\nlifetime_s = 10000.0\n\
         falloff_u = 50.0\nscattering = [1.0, 1.0, 1.0]\nmax_particles = 1\n\
         [[emitter]]\nshape = \"sphere\"\nposition = [3.0, 2.0, -3.0]\nradius = 1.0\n\
         rate_per_s = 1000.0\nlifetime_s = 10000.0\nfalloff_u = 0.3\n\
         scattering = [2.0, 2.0, 2.0]\nmax_particles = 50\n\
         [[light]]\nkind = \"point\"\nposition = [10.0, 2.0, 0.0]\nintensity = 20.0\n";
    let s = scene(emitters);
    let mut r = renderer(s.clone());
    let cams = [
        camera(&s, Vec3::new(0.0, 2.0, 6.0), Vec3::NEG_Z),
        camera(&s, Vec3::new(10.0, 2.0, 0.0), Vec3::NEG_X),
    ];
    let out = r.render(&cams, W, H, 0.5).unwrap();
    assert_eq!(r.particle_count(), 55, "the cloud at its cap of 50");
    let layers = r.read_smoke_layers().unwrap();
    for (v, layer) in layers.iter().enumerate() {
        assert!(
            layer.iter().flatten().all(|x| x.is_finite() && *x >= 0.0),
            "viewer {v}: a smoke texel is not finite"
        );
        assert!(layer.iter().all(|p| p[3] <= 1.0));
        let mean: f64 = out.images[v]
            .chunks_exact(4)
            .map(|p| f64::from(p[0]) + f64::from(p[1]) + f64::from(p[2]))
            .sum::<f64>()
            / (3 * W * H) as f64;
        println!("viewer {v}: mean pixel {mean:.1}");
        assert!(mean > 5.0, "viewer {v}: black frame");
    }
    let centre = (W / 2 + (H / 2) * W) as usize;
    // The particle 5 cm in front of viewer 0, half of it behind the near plane.
    let near = layers[0][centre];
    println!("across the near plane: {near:?}");
    assert!(
        near[3] > 0.2,
        "the near-plane particle was dropped: {near:?}"
    );
    // Viewer 1 inside a particle of u = 4 m, a light at its centre: smoke everywhere.
    let inside = layers[1][centre];
    let least = layers[1].iter().map(|p| p[3]).fold(f32::MAX, f32::min);
    println!("eye inside the smoke: centre {inside:?}, least alpha {least:.3}");
    assert!(least > 0.05 && inside.iter().take(3).any(|c| *c > 0.0));
    // σ 10⁴: opaque where the ray crosses its core.
    let dense = layers[0].iter().map(|p| p[3]).fold(0f32, f32::max);
    assert!(dense > 0.99, "σ = 10⁴ not opaque: {dense}");
}
