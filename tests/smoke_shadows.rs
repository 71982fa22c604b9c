//! The smoke's shared shadow maps (issue 15, seed 002): the GPU AVSM against its CPU twin
//! (`fogcast::smoke::avsm`) and against exact transmittance; built once per frame whatever
//! the viewer count and cached while nothing moves; the smoke's shadow on the ground and
//! in the fog matches the exact transmittance; no particles, no stage and the same image as a scene
//! without emitters.

mod gpu_support;

use fogcast::render::{Renderer, Settings, SmokeMapKind, SmokeShadowMap};
use fogcast::scene::{Camera, LightKind, Scene};
use fogcast::smoke::avsm::{LightRayCrossing, TransmittanceCurve};
use fogcast::smoke::emitter::particles_at;
use fogcast::smoke::interval::GaussianAlongRay;
use glam::{DVec3, Vec3};
use gpu_support::gpu;
use std::path::Path;
use std::sync::Arc;

/// A particle as the GPU holds it (f32 centre and u, scalar σ = mean(σs) + σa), in f64.
struct Blob {
    centre: DVec3,
    u: f64,
    sigma: f64,
}

fn blobs(scene: &Scene, time_s: f32) -> Vec<Blob> {
    let mut out = Vec::new();
    for e in &scene.emitters {
        let sigma = f64::from((e.scattering.iter().sum::<f32>()) / 3.0 + e.absorption);
        for p in particles_at(e, f64::from(time_s)) {
            out.push(Blob {
                centre: p.centre.as_vec3().as_dvec3(),
                u: f64::from(p.falloff_u_m as f32),
                sigma,
            });
        }
    }
    out
}

/// Exact transmittance of the smoke from `p` along unit `dir` over `dist` metres: the sum of
/// every particle's closed-form optical depth (001 Eq. 10).
fn exact_transmittance(blobs: &[Blob], p: DVec3, dir: DVec3, dist: f64) -> f64 {
    let tau: f64 = blobs
        .iter()
        .map(|b| {
            GaussianAlongRay::from_points(b.sigma, b.u, p, dir, b.centre).optical_depth(0.0, dist)
        })
        .sum();
    (-tau).exp()
}

/// The direction from `p` toward light `li` and the distance to it.
fn toward_light(scene: &Scene, li: usize, p: DVec3) -> (DVec3, f64) {
    let l = &scene.lights[li];
    if l.kind == LightKind::Directional {
        return (-l.direction.as_dvec3().normalize(), 1e4);
    }
    let d = l.position.as_dvec3() - p;
    (d.normalize(), d.length())
}

/// The crossings of one texel's light ray (as `smoke_avsm.wgsl` finds them; proxy radius
/// 1.5 u, clipped at the ray's start, none whose line integral is below 1e-4), in f64.
fn crossings(blobs: &[Blob], start: DVec3, dir: DVec3) -> Vec<LightRayCrossing> {
    let mut out = Vec::new();
    for (i, b) in blobs.iter().enumerate() {
        let r = 1.5 * b.u;
        let to_centre = b.centre - start;
        let along = to_centre.dot(dir);
        let h2 = (to_centre.length_squared() - along * along).max(0.0);
        if h2 >= r * r {
            continue;
        }
        let k = 50f64.sqrt() / b.u;
        if b.sigma * std::f64::consts::PI.sqrt() / k * (-k * k * h2).exp() < 1e-4 {
            continue;
        }
        let half_chord = (r * r - h2).sqrt();
        if along + half_chord <= 0.0 {
            continue;
        }
        let entry = (along - half_chord).max(0.0);
        out.push(LightRayCrossing {
            particle_index: i as u32,
            entry_m: entry,
            exit_m: along + half_chord,
            particle: GaussianAlongRay {
                sigma_per_m: b.sigma,
                falloff_u_m: b.u,
                centre_along_m: along - entry,
                centre_offset_sq_m2: h2,
            },
        });
    }
    out
}

/// A GPU curve's value at `depth` (as `smoke_curve_at` in common.wgsl).
fn gpu_curve_at(nodes: &[[f32; 2]], depth: f64) -> f64 {
    let d = |k: usize| f64::from(nodes[k][0]);
    let t = |k: usize| f64::from(nodes[k][1]);
    if depth < d(0) {
        return 1.0;
    }
    for k in 1..nodes.len() {
        if d(k) > depth {
            return t(k - 1) + (depth - d(k - 1)) * (t(k) - t(k - 1)) / (d(k) - d(k - 1));
        }
    }
    t(nodes.len() - 1)
}

/// A small deterministic generator (SplitMix64).
struct Rng(u64);

impl Rng {
    fn unit(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    }

    fn in_ball(&mut self, centre: DVec3, radius: f64) -> DVec3 {
        loop {
            let v = DVec3::new(self.unit(), self.unit(), self.unit()) * 2.0 - 1.0;
            if v.length_squared() <= 1.0 {
                return centre + v * radius;
            }
        }
    }
}

fn load(text: &str) -> Arc<Scene> {
    Arc::new(Scene::from_toml(text, Path::new("inline.toml")).expect("scene"))
}

/// A static cloud (no velocity, spread, buoyancy or growth: the particles alive at a time
/// stay where they are born) under a sun and a spot, with a lamp inside it (a cube map),
/// no media.
const CLOUD: &str = r#"
name = "smoke cloud"
[render]
near_m = 0.1
far_m = 30.0
ambient = [0.0, 0.0, 0.0]
[camera]
path = [[-6.0, 2.0, 0.0]]
look_at = [[0.0, 2.0, 0.0]]
[[light]]
kind = "directional"
direction = [0.3, -1.0, 0.2]
intensity = 3.0
[[light]]
kind = "spot"
position = [4.0, 5.0, 2.0]
direction = [-4.0, -3.0, -2.0]
intensity = 60.0
inner_deg = 30.0
outer_deg = 40.0
[[light]]
kind = "point"
position = [0.4, 2.3, -0.2]
intensity = 5.0
[[mesh]]
kind = "box"
min = [-10.0, -0.5, -10.0]
max = [10.0, 0.0, 10.0]
albedo = [0.5, 0.5, 0.5]
[[emitter]]
shape = "sphere"
position = [0.0, 2.0, 0.0]
radius = 1.5
rate_per_s = 40.0
lifetime_s = 100.0
falloff_u = 0.8
scattering = [8.0, 8.0, 8.0]
absorption = 2.0
max_particles = 1000
seed = 3
"#;

/// GPU curves against the CPU twin `TransmittanceCurve::from_crossings` on ~300 texels of
/// each light's map (each face of the lamp's cube), GPU lookups (`smoke_transmittance`) against exact transmittance on
/// 1,000 random light rays per light, then the stage's schedule: once per frame at 1 and
/// 4 viewers with the same dispatch, none while nothing moved.
#[test]
fn avsm_matches_cpu_twin_and_exact_transmittance_once_per_frame() {
    const TIME_S: f32 = 1.5;
    let scene = load(CLOUD);
    let settings = Settings::for_scene(&scene);
    let nodes = settings.avsm_nodes as usize;
    let mut r = Renderer::new(gpu(), scene.clone(), settings).unwrap();
    let cams = scene.camera.viewers(1, 0.0);
    let out = r.render(&cams, 64, 36, TIME_S).unwrap();
    let runs = |o: &fogcast::render::FrameOutput| {
        o.stats
            .dispatches
            .iter()
            .filter(|(s, _)| s == "smoke_shadows")
            .map(|(_, g)| *g)
            .collect::<Vec<_>>()
    };
    assert_eq!(runs(&out).len(), 1, "{:?}", out.stats.dispatches);
    let blobs = blobs(&scene, TIME_S);
    assert!(blobs.len() > 40, "{} particles", blobs.len());
    let maps = r.read_smoke_shadows().unwrap();
    assert_eq!(maps.len(), 3);
    let kinds: Vec<Vec<_>> = maps
        .iter()
        .map(|m| m.iter().map(|m| m.kind).collect())
        .collect();
    assert_eq!(
        kinds,
        [
            vec![SmokeMapKind::Orthographic],
            vec![SmokeMapKind::Perspective],
            vec![SmokeMapKind::Perspective; 6],
        ],
        "a sun, a spot, a lamp inside the cloud (a cube)"
    );
    // 1. Node for node against the CPU twin.
    for (li, faces) in maps.iter().enumerate() {
        let (mut max_diff, mut sum, mut n) = (0.0_f64, 0.0, 0);
        let mut diffs = Vec::new();
        let mut texels = 0;
        for map in faces {
            let map: &SmokeShadowMap = map;
            let covered: Vec<(u32, u32)> = (0..map.px)
                .flat_map(|y| (0..map.px).map(move |x| (x, y)))
                .filter(|(x, y)| map.curve(*x, *y)[0][0] < 1e30)
                .collect();
            texels += covered.len();
            let step = (covered.len() * faces.len() / 300).max(1);
            for &(x, y) in covered.iter().step_by(step) {
                let (start, dir) = map.texel_ray(x, y);
                let hits = crossings(&blobs, start.as_dvec3(), dir.as_dvec3());
                let cpu = TransmittanceCurve::from_crossings(nodes, &hits);
                let gpu_nodes = map.curve(x, y);
                let cn = cpu.nodes();
                assert!(
                    !cn.is_empty(),
                    "light {li} texel {x},{y}: GPU has nodes, CPU none"
                );
                let (near, far) = (cn[0].depth_m - 0.1, cn[cn.len() - 1].depth_m + 0.1);
                for k in 0..=16 {
                    let depth = near + (far - near) * f64::from(k) / 16.0;
                    let d = (gpu_curve_at(gpu_nodes, depth) - cpu.transmittance_at(depth)).abs();
                    max_diff = max_diff.max(d);
                    diffs.push(d);
                    sum += d;
                    n += 1;
                }
            }
        }
        assert!(texels > 300, "light {li}: {texels} texels");
        println!(
            "light {li}: {texels} covered texels, GPU vs CPU twin on {n} samples: max {max_diff:.2e}, mean {:.2e}",
            sum / f64::from(n)
        );
        diffs.sort_by(f64::total_cmp);
        let p99 = diffs[diffs.len() * 99 / 100];
        println!("light {li}: 99th percentile {p99:.2e}");
        // f32 against f64: most samples agree to ~1e-5; where two nodes' triangles nearly
        // tie, f32 rounding can remove the other one, and the curves then differ by up to
        // a few hundredths on that texel. The particles themselves are placed by the GPU
        // pass in f32 (smoke_particles.wgsl), the twin's in f64, which moves such ties
        // (measured on this cloud, sun / spot / lamp's cube: mean 5.1e-6 / 1.8e-5 /
        // 2.6e-7, 99th percentile 3.6e-5 / 1.3e-4 / 3.9e-6, max 3.5e-3 / 2.2e-4 / 1.1e-5;
        // before negligible crossings were skipped, max 0.030 / 0.081 on one texel).
        assert!(
            sum / f64::from(n) <= 1e-3,
            "light {li}: mean |GPU − CPU twin| {}",
            sum / f64::from(n)
        );
        assert!(
            p99 <= 1e-2,
            "light {li}: 99th percentile |GPU − CPU twin| {p99}"
        );
        assert!(
            max_diff <= 0.1,
            "light {li}: max |GPU − CPU twin| {max_diff}"
        );
    }
    // 2. Lookups against exact transmittance: random points in the cloud's ball.
    let centre = blobs.iter().map(|b| b.centre).sum::<DVec3>() / blobs.len() as f64;
    let mut rng = Rng(15_002);
    for li in 0..3 {
        let points: Vec<DVec3> = (0..1000).map(|_| rng.in_ball(centre, 1.5)).collect();
        let probe: Vec<(u32, Vec3)> = points.iter().map(|p| (li as u32, p.as_vec3())).collect();
        let got = r.probe_smoke_transmittance(&probe).unwrap();
        let (mut sum, mut max, mut mean_t) = (0.0, 0.0_f64, 0.0);
        for (p, g) in points.iter().zip(&got) {
            let (dir, dist) = toward_light(&scene, li, *p);
            let exact = exact_transmittance(&blobs, *p, dir, dist);
            let e = (f64::from(*g) - exact).abs();
            sum += e;
            max = max.max(e);
            mean_t += exact;
        }
        let mae = sum / 1000.0;
        println!(
            "light {li}: lookup vs exact on 1000 rays: MAE {mae:.4}, max {max:.3}, mean exact T {:.3}",
            mean_t / 1000.0
        );
        assert!(mae <= 0.02, "light {li}: MAE {mae}");
        assert!(mean_t / 1000.0 < 0.9, "the rays cross smoke");
    }
    // 3. Nothing moved: cached, no dispatch. A new time at 4 viewers: once, the same size.
    let again = r.render(&cams, 64, 36, TIME_S).unwrap();
    assert!(runs(&again).is_empty(), "{:?}", again.stats.dispatches);
    let four = scene.camera.viewers(4, 0.0);
    let out4 = r.render(&four, 64, 36, TIME_S + 0.5).unwrap();
    assert_eq!(
        runs(&out4),
        runs(&out),
        "once per frame whatever the viewers"
    );
    let out1 = r.render(&cams, 64, 36, TIME_S + 1.0).unwrap();
    assert_eq!(runs(&out1), runs(&out));
    for o in [&out, &out4] {
        let ms: Vec<_> = o
            .stats
            .stage_gpu_ms
            .iter()
            .filter(|s| s.stage == "smoke_shadows")
            .collect();
        println!("viewers {}: smoke_shadows {ms:?}", o.images.len());
    }
    assert!(out
        .stats
        .memory
        .shared
        .iter()
        .any(|(n, b)| n == "smoke_shadows" && *b > 0));
}

/// Ground, sun and thin fog, with and without a static smoke ball above the ground.
fn ground_scene(with_smoke: bool) -> String {
    let mut s = String::from(
        r#"
name = "smoke shadow"
[render]
near_m = 0.1
far_m = 30.0
sky = [0.0, 0.0, 0.0]
ambient = [0.0, 0.0, 0.0]
[camera]
path = [[-5.0, 3.0, 0.0]]
look_at = [[0.5, 0.0, 0.0]]
fov_deg = 50.0
[[light]]
kind = "directional"
direction = [-0.5, -1.0, 0.0]
intensity = 3.0
[[mesh]]
kind = "box"
min = [-20.0, -0.5, -20.0]
max = [20.0, 0.0, 20.0]
albedo = [0.5, 0.5, 0.5]
[[medium]]
kind = "box"
min = [-20.0, 0.0, -20.0]
max = [20.0, 6.0, 20.0]
scattering = [0.01, 0.01, 0.01]
"#,
    );
    if with_smoke {
        s.push_str(
            r#"
[[emitter]]
shape = "sphere"
position = [1.5, 2.0, 0.0]
radius = 0.8
rate_per_s = 6.0
lifetime_s = 100.0
falloff_u = 1.5
scattering = [0.8, 0.8, 0.8]
absorption = 0.2
max_particles = 100
seed = 5
"#,
        );
    }
    s
}

/// Linear radiance × exposure from an 8-bit channel: the sRGB transfer and the ACES
/// curve (composite.wgsl's `aces`) inverted.
fn linear(byte: u8) -> f64 {
    let v = f64::from(byte) / 255.0;
    let y = if v <= 0.04045 {
        v / 12.92
    } else {
        ((v + 0.055) / 1.055).powf(2.4)
    };
    // y = x(2.51x + 0.03)/(x(2.43x + 0.59) + 0.14), solved for x ≥ 0.
    let (a, b, c) = (2.43 * y - 2.51, 0.59 * y - 0.03, 0.14 * y);
    if a.abs() < 1e-12 {
        return -c / b;
    }
    let disc = (b * b - 4.0 * a * c).max(0.0);
    (-b - disc.sqrt()) / (2.0 * a)
}

/// The smoke darkens the ground under it by the exact transmittance (±10 %); with no
/// particle alive (before the emitter starts) the stage does not run and the image is the
/// scene's without an emitter, byte for byte.
#[test]
fn smoke_shadow_on_the_ground_matches_exact_transmittance() {
    const SIZE: (u32, u32) = (64, 36);
    const TIME_S: f32 = 2.0;
    let smoke = load(&ground_scene(true));
    let plain = load(&ground_scene(false));
    let cams = smoke.camera.viewers(1, 0.0);
    let mut rs = Renderer::new(gpu(), smoke.clone(), Settings::for_scene(&smoke)).unwrap();
    let mut rp = Renderer::new(gpu(), plain.clone(), Settings::for_scene(&plain)).unwrap();
    // No particle alive before time 0.
    let a = rs.render(&cams, SIZE.0, SIZE.1, -1.0).unwrap();
    let b = rp.render(&cams, SIZE.0, SIZE.1, -1.0).unwrap();
    assert!(a.stats.dispatches.iter().all(|(s, _)| s != "smoke_shadows"));
    assert_eq!(
        a.images[0], b.images[0],
        "no particles: the plain scene's image"
    );
    let a = rs.render(&cams, SIZE.0, SIZE.1, TIME_S).unwrap();
    let b = rp.render(&cams, SIZE.0, SIZE.1, TIME_S).unwrap();
    let blobs = blobs(&smoke, TIME_S);
    assert!(blobs.len() >= 12, "{}", blobs.len());
    let cam: Camera = cams[0];
    let sun = -smoke.lights[0].direction.as_dvec3().normalize();
    // The ground's top in render space (the scene is moved by its rounded centre).
    let ground_y = f64::from(
        smoke
            .mesh
            .positions
            .iter()
            .map(|p| p.y)
            .fold(f32::MIN, f32::max),
    );
    let (mut n, mut sum, mut max, mut min_t) = (0, 0.0, 0.0_f64, 1.0_f64);
    let mut errors = Vec::new();
    for y in 0..SIZE.1 {
        for x in 0..SIZE.0 {
            let dir = cam
                .ray_dir(x as f32 + 0.5, y as f32 + 0.5, SIZE.0, SIZE.1)
                .as_dvec3();
            let eye = cam.position.as_dvec3();
            if dir.y >= -1e-3 {
                continue;
            }
            let ground = eye + dir * ((ground_y - eye.y) / dir.y);
            let exact = exact_transmittance(&blobs, ground, sun, 1e4);
            if exact > 0.9 {
                continue;
            }
            let i = ((x + SIZE.0 * y) * 4) as usize;
            let (with, without) = (linear(a.images[0][i + 1]), linear(b.images[0][i + 1]));
            assert!(without > 0.05, "the lit ground is bright enough: {without}");
            let rel = (with / without - exact).abs() / exact;
            errors.push(rel);
            sum += rel;
            max = max.max(rel);
            min_t = min_t.min(exact);
            n += 1;
        }
    }
    assert!(n >= 20, "{n} shadow pixels");
    errors.sort_by(f64::total_cmp);
    let p90 = errors[errors.len() * 9 / 10];
    println!(
        "{n} ground pixels in the smoke's shadow (exact T down to {min_t:.3}): |darkening − T|/T mean {:.4}, 90th percentile {p90:.4}, max {max:.4}",
        sum / f64::from(n)
    );
    assert!(min_t < 0.6, "a real shadow: {min_t}");
    assert!(
        sum / f64::from(n) <= 0.10,
        "mean relative error {}",
        sum / f64::from(n)
    );
    assert!(p90 <= 0.10, "90th percentile {p90}");
}

/// Dense fog in a box, a sun from above and a smoke ball over the camera's line of sight,
/// with and without the ball; no surface in view (a black sky), so every pixel is fog.
fn fog_scene(with_smoke: bool) -> String {
    let mut s = String::from(
        r#"
name = "smoke shadow in fog"
[render]
near_m = 0.1
far_m = 30.0
sky = [0.0, 0.0, 0.0]
ambient = [0.0, 0.0, 0.0]
[camera]
path = [[-4.0, 1.5, 0.0]]
look_at = [[0.0, 1.5, 0.0]]
fov_deg = 50.0
[[light]]
kind = "directional"
direction = [-0.3, -1.0, 0.0]
intensity = 12.0
[[mesh]]
kind = "box"
min = [-30.0, -40.0, -30.0]
max = [30.0, -39.0, 30.0]
[[medium]]
kind = "box"
min = [-20.0, -10.0, -20.0]
max = [20.0, 9.0, 20.0]
scattering = [0.3, 0.3, 0.3]
"#,
    );
    if with_smoke {
        s.push_str(
            r#"
[[emitter]]
shape = "sphere"
position = [0.5, 6.5, 0.0]
radius = 1.5
rate_per_s = 20.0
lifetime_s = 100.0
falloff_u = 1.0
scattering = [3.0, 3.0, 3.0]
absorption = 0.5
max_particles = 100
seed = 5
"#,
        );
    }
    s
}

/// The smoke's shadow in the fog: every pixel sees only the fog's single scattering of
/// the sun; with the ball its in-scattering at each point is darkened by the smoke's
/// transmittance toward the sun. The reference is a converged 1-D quadrature along each
/// pixel's ray of `e^{−σt·s}` (the view) × `e^{−σt·d_top}` (the sun through the fog) ×
/// the exact smoke transmittance toward the sun (closed-form optical depths), with
/// against without the smoke. Pixels whose ray passes within 2 u of a particle (the smoke
/// itself in view) are left out. The renderer's darkening (with / without, linear) must
/// match within 10 % (mean and 90th percentile where the reference darkens by ≥ 10 %),
/// and the total light the shadow removes within 10 %.
#[test]
fn smoke_shadow_in_the_fog_matches_exact_transmittance() {
    const SIZE: (u32, u32) = (96, 54);
    const TIME_S: f32 = 2.0;
    const SIGMA_T: f64 = 0.3;
    const STEPS: usize = 1500;
    let smoke = load(&fog_scene(true));
    let plain = load(&fog_scene(false));
    let cams = smoke.camera.viewers(1, 0.0);
    let mut rs = Renderer::new(gpu(), smoke.clone(), Settings::for_scene(&smoke)).unwrap();
    let mut rp = Renderer::new(gpu(), plain.clone(), Settings::for_scene(&plain)).unwrap();
    let a = rs.render(&cams, SIZE.0, SIZE.1, TIME_S).unwrap();
    let b = rp.render(&cams, SIZE.0, SIZE.1, TIME_S).unwrap();
    let blobs = blobs(&smoke, TIME_S);
    assert!(blobs.len() >= 10, "{}", blobs.len());
    let cam: Camera = cams[0];
    let eye = cam.position.as_dvec3();
    // The scene is moved into render space by its rounded centre: the fog's top there.
    let top_y = 9.0 + (eye.y - 1.5);
    let sun = -smoke.lights[0].direction.as_dvec3().normalize();
    let far = f64::from(smoke.render.far_m);
    let (mut n, mut sum, mut max, mut min_ref) = (0, 0.0, 0.0_f64, 1.0_f64);
    let (mut removed, mut removed_ref) = (0.0, 0.0);
    let mut errors = Vec::new();
    for y in 0..SIZE.1 {
        for x in 0..SIZE.0 {
            let dir = cam
                .ray_dir(x as f32 + 0.5, y as f32 + 0.5, SIZE.0, SIZE.1)
                .as_dvec3();
            let near_smoke = blobs.iter().any(|bl| {
                let to = bl.centre - eye;
                let s = to.dot(dir).max(0.0);
                (to - dir * s).length() < 2.0 * bl.u
            });
            if near_smoke {
                continue;
            }
            let (mut lit, mut shadowed) = (0.0, 0.0);
            let ds = far / STEPS as f64;
            for k in 0..STEPS {
                let s = (k as f64 + 0.5) * ds;
                let p = eye + dir * s;
                let w = (-SIGMA_T * (s + (top_y - p.y).max(0.0) / sun.y)).exp();
                lit += w;
                shadowed += w * exact_transmittance(&blobs, p, sun, 1e4);
            }
            let reference = shadowed / lit;
            min_ref = min_ref.min(reference);
            let i = ((x + SIZE.0 * y) * 4) as usize;
            let (with, without) = (linear(a.images[0][i + 1]), linear(b.images[0][i + 1]));
            assert!(
                without > 0.02,
                "the fog is bright enough: {without} at {x},{y}"
            );
            removed += without - with;
            removed_ref += without * (1.0 - reference);
            if reference > 0.9 {
                continue;
            }
            let rel = (with / without - reference).abs() / reference;
            errors.push(rel);
            sum += rel;
            max = max.max(rel);
            n += 1;
        }
    }
    assert!(n >= 100, "{n} fog pixels in the smoke's shadow");
    errors.sort_by(f64::total_cmp);
    let p90 = errors[errors.len() * 9 / 10];
    let removed_err = (removed - removed_ref).abs() / removed_ref;
    println!(
        "{n} fog pixels darkened ≥ 10 % (reference down to {min_ref:.3}): |darkening − reference|/reference mean {:.4}, 90th percentile {p90:.4}, max {max:.4}; light the shadow removes: {removed:.2} vs {removed_ref:.2} ({:.1} %)",
        sum / f64::from(n),
        removed_err * 100.0
    );
    assert!(
        sum / f64::from(n) <= 0.10,
        "mean relative error {}",
        sum / f64::from(n)
    );
    assert!(p90 <= 0.10, "90th percentile {p90}");
    assert!(removed_err <= 0.10, "removed light off by {removed_err}");
}

/// chimney's plume at t = 77.7 s: 300 particles up to u = 6.3 m whose proxies overlap
/// tens deep along most light rays, and seven lights — four lamps and a spot beside or
/// inside it (cubes), a spot and the moon. At points inside 100 of its particles (0.1–0.2
/// u from the centre) the lookups must match exact transmittance for every light. Before
/// the maps skipped crossings of negligible optical depth, the grazing crossings of big
/// old proxies filled the 64 slots and the lower plume was lit through (MAE 0.21–0.63).
#[test]
fn a_dense_plume_shadows_itself_for_every_light() {
    const TIME_S: f32 = 77.7;
    let scene = Arc::new(Scene::load("chimney").unwrap());
    let mut r = Renderer::new(gpu(), scene.clone(), Settings::for_scene(&scene)).unwrap();
    let cams = scene.camera.viewers(1, TIME_S);
    r.render(&cams, 32, 18, TIME_S).unwrap();
    let blobs = blobs(&scene, TIME_S);
    assert_eq!(blobs.len(), 300);
    let lights = scene.lights_at(TIME_S);
    let maps = r.read_smoke_shadows().unwrap();
    let faces: Vec<usize> = maps.iter().map(Vec::len).collect();
    println!("maps per light: {faces:?}");
    assert!(faces.iter().any(|&n| n > 1), "some lamp gets a cube");
    let points: Vec<DVec3> = blobs
        .iter()
        .step_by(3)
        .map(|b| b.centre + DVec3::new(0.1, 0.2, -0.1) * b.u)
        .collect();
    let mut worst_mae = 0.0_f64;
    for (li, l) in lights.iter().enumerate() {
        let probe: Vec<(u32, Vec3)> = points.iter().map(|p| (li as u32, p.as_vec3())).collect();
        let got = r.probe_smoke_transmittance(&probe).unwrap();
        let (mut sum, mut max, mut mean_t) = (0.0, 0.0_f64, 0.0);
        for (p, g) in points.iter().zip(&got) {
            let (dir, dist) = if l.kind == LightKind::Directional {
                (-l.direction.as_dvec3().normalize(), 1e4)
            } else {
                let d = l.position.as_dvec3() - *p;
                (d.normalize(), d.length())
            };
            let exact = exact_transmittance(&blobs, *p, dir, dist);
            let e = (f64::from(*g) - exact).abs();
            sum += e;
            max = max.max(e);
            mean_t += exact;
        }
        let n = points.len() as f64;
        println!(
            "light {li} ({:?}): MAE {:.4}, max {max:.3}, mean exact T {:.3} over {n} points",
            l.kind,
            sum / n,
            mean_t / n
        );
        worst_mae = worst_mae.max(sum / n);
    }
    assert!(worst_mae <= 0.04, "worst light's MAE {worst_mae}");
}
