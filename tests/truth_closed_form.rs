//! The ground-truth renderer against what can be computed without it (DESIGN.md §2: it
//! must agree with closed forms before it may judge anything): a sun over a homogeneous
//! slab of fog, a point lamp inside a fog sphere against an independent f64 quadrature,
//! the shadow rays' transmittance against a brute-force sum of the density, and the
//! pixel box filter. Images are 1×1 to 12×6 pixels of linear radiance.

mod gpu_support;

use fogcast::scene::{density_at, Bvh, Camera, LightKind, Medium, MediumKind, Noise, Scene};
use fogcast::truth::{render_truth_radiance, ShadowMedia, TruthSettings};
use glam::{DVec3, Vec3};
use gpu_support::unit_points;
use std::f64::consts::PI;
use std::path::Path;

/// The default `TruthSettings::shadow_segments_per_feature`.
const SEGMENTS: u32 = 2;

fn scene(toml: &str) -> Scene {
    Scene::from_toml(toml, Path::new("inline.toml")).expect("test scene is valid")
}

/// Linear radiance of each camera's single pixel (its ray is the camera's forward), and
/// the media samples the render took.
fn render_1px_counted(scene: &Scene, cams: &[Camera], settings: TruthSettings) -> (Vec<Vec3>, u64) {
    let bvh = Bvh::build(&scene.mesh).unwrap();
    let (img, counts) = render_truth_radiance(scene, &bvh, cams, (1, 1), 0.0, settings, &|_, _| {});
    (
        img.into_iter().map(|v| v[0]).collect(),
        counts.media_samples,
    )
}

fn render_1px(scene: &Scene, cams: &[Camera], settings: TruthSettings) -> Vec<Vec3> {
    render_1px_counted(scene, cams, settings).0
}

/// Camera at world position `pos` looking along `dir` (world = render space + origin).
fn camera(scene: &Scene, pos: DVec3, dir: DVec3) -> Camera {
    Camera::new((pos - scene.origin).as_vec3(), dir.as_vec3(), 1.0)
}

/// Henyey-Greenstein phase written out again in f64 (independent of `hg_phase`); `cos`
/// is between the light's direction of travel and the direction towards the eye.
fn hg(g: f64, cos: f64) -> f64 {
    (1.0 - g * g) / (4.0 * PI * (1.0 + g * g - 2.0 * g * cos).powf(1.5))
}

fn rel_err(got: Vec3, want: DVec3) -> f64 {
    ((got.as_dvec3() - want) / want).abs().max_element()
}

fn mean(v: [f64; 3]) -> f64 {
    (v[0] + v[1] + v[2]) / 3.0
}

/// A homogeneous box of fog from the ground (y = 0) to y = H, wide in x and z, over an
/// opaque ground, lit by a sun of irradiance E travelling along L (L_y < 0); sky and
/// ambient black. The eye is at height y0 inside the slab and looks along the unit
/// direction d; the renderer's fog starts at the near plane t_n (nothing between the eye
/// and it), so measure u from there: the point at t_n + u is at height y_n + d_y·u,
/// y_n = y0 + d_y·t_n. Sunlight reaches it through (H − y_n − d_y·u)/|L_y| metres of fog
/// and its light reaches the eye through u metres, so with σt = mean(σs) + σa (grey
/// extinction) and cosθ = L·(−d):
///
/// L_s = σs·p_HG(cosθ)·E·exp(−σt(H − y_n)/|L_y|)·∫₀^span exp(−k·u) du,
///       k = σt(1 − d_y/|L_y|),  ∫ = (1 − exp(−k·span))/k  (→ span as k → 0),
///
/// where span = s − t_n and s is the distance to the ground (d_y < 0: y0/|d_y|) or to the
/// slab's top (d_y > 0: (H − y0)/d_y). A ray that hits the ground adds the Lambertian
/// ground lit through the whole slab:
///
/// L_g = albedo/π·E·|L_y|·exp(−σt·H/|L_y|)·exp(−σt·span).
///
/// The albedos are multiples of 1/255: the mesh stores albedo in 8 bits.
///
/// The same closed form judges seed 003's variable step amplification
/// (`TruthSettings::step_amplification`, issue 16) at the default 512 baseline steps and
/// at 64, which must take fewer media samples than fixed steps do.
#[test]
fn homogeneous_slab_under_a_sun_matches_the_closed_form() {
    let (h_m, y0, near_m, e, g) = (4.0, 1.5, 0.01, 6.0, 0.6);
    let albedo = [0.6, 0.4, 0.2];
    let light = DVec3::new(0.5, -0.8, 0.3).normalize();
    let ly = -light.y;
    let dir = |elev_deg: f64, azim_deg: f64| {
        let (el, az) = (elev_deg.to_radians(), azim_deg.to_radians());
        DVec3::new(el.cos() * az.cos(), el.sin(), el.cos() * az.sin())
    };
    let views = [
        ("down 20°", dir(-20.0, 0.0)),
        ("down 45°", dir(-45.0, 120.0)),
        ("down 80°", dir(-80.0, 250.0)),
        ("at the sun (k = 0)", -light),
        (
            "10° off the sun",
            (-light + DVec3::new(0.0, 0.0, 0.18)).normalize(),
        ),
        ("with the sun (back-scatter)", light),
        ("up 15°, away from the sun", dir(15.0, 31.0)),
    ];
    // (what, settings, bound on the worst relative error)
    let vsa = |steps| TruthSettings {
        steps,
        step_amplification: true,
        ..TruthSettings::default()
    };
    let runs = [
        ("fixed, 512 steps", TruthSettings::default(), 1e-3),
        ("VSA, 512 baseline steps", vsa(512), 5e-5),
        ("VSA, 64 baseline steps", vsa(64), 1.5e-3),
    ];
    let mut worst = [0.0f64; 3];
    for (sigma_s, sigma_a) in [([0.03, 0.04, 0.05], 0.01), ([0.7, 0.8, 0.9], 0.2)] {
        let sigma_t: f64 = mean(sigma_s) + sigma_a;
        let s = scene(&format!(
            r#"
            name = "slab"
            [render]
            near_m = {near_m}
            far_m = 1000.0
            sky = [0.0, 0.0, 0.0]
            ambient = [0.0, 0.0, 0.0]
            [camera]
            path = [[0.0, {y0}, 0.0]]
            [[light]]
            kind = "directional"
            direction = [0.5, -0.8, 0.3]
            intensity = {e}
            [[mesh]]
            kind = "box"
            min = [-400.0, -1.0, -400.0]
            max = [400.0, 0.0, 400.0]
            albedo = {albedo:?}
            [[medium]]
            kind = "box"
            min = [-400.0, 0.0, -400.0]
            max = [400.0, {h_m}, 400.0]
            scattering = {sigma_s:?}
            absorption = {sigma_a}
            g = {g}
            "#
        ));
        let cams: Vec<Camera> = views
            .iter()
            .map(|(_, d)| camera(&s, DVec3::new(0.0, y0, 0.0), *d))
            .collect();
        for (run, (what, settings, _)) in runs.iter().enumerate() {
            let (got, samples) = render_1px_counted(&s, &cams, *settings);
            if settings.step_amplification {
                // No ray here reaches the 1e-7 cut-off: fixed steps sample every segment.
                let fixed = u64::from(settings.steps) * cams.len() as u64;
                println!("σt {sigma_t:.2}, {what}: {samples} media samples, fixed steps {fixed}");
                assert!(
                    samples < fixed,
                    "{what}: {samples} samples, fixed steps {fixed}"
                );
            }
            for (((name, _), cam), got) in views.iter().zip(&cams).zip(got) {
                // The closed form for the ray the renderer actually traces.
                let d = cam.ray_dir(0.5, 0.5, 1, 1).as_dvec3();
                let t_n = near_m;
                let (s_m, hits_ground) = if d.y < 0.0 {
                    (y0 / -d.y, true)
                } else {
                    ((h_m - y0) / d.y, false)
                };
                let k = sigma_t * (1.0 - d.y / ly);
                let span = s_m - t_n;
                let integral = if (k * span).abs() < 1e-12 {
                    span
                } else {
                    -(-k * span).exp_m1() / k
                };
                let sun_at_near = (-sigma_t * (h_m - (y0 + d.y * t_n)) / ly).exp();
                let in_scatter =
                    DVec3::from(sigma_s) * hg(g, light.dot(-d)) * e * sun_at_near * integral;
                let ground = if hits_ground {
                    DVec3::from(albedo) / PI
                        * e
                        * ly
                        * (-sigma_t * h_m / ly).exp()
                        * (-sigma_t * span).exp()
                } else {
                    DVec3::ZERO
                };
                let want = in_scatter + ground;
                let err = rel_err(got, want);
                println!(
                "σt {sigma_t:.2}, {what}, {name:28}: closed form {:.6} {:.6} {:.6}, truth {:.6} {:.6} {:.6}, rel err {err:.2e}",
                want.x, want.y, want.z, got.x, got.y, got.z
            );
                worst[run] = worst[run].max(err);
            }
        }
    }
    for ((what, _, bound), worst) in runs.iter().zip(worst) {
        println!("{what}: worst relative error {worst:.2e}");
        assert!(
            worst < *bound,
            "{what}: worst relative error {worst:.2e} > {bound:.1e}"
        );
    }
}

/// Length of the segment a→b inside the sphere |x| ≤ r.
fn chord_in_sphere(a: DVec3, b: DVec3, r: f64) -> f64 {
    let len = (b - a).length();
    if len == 0.0 {
        return 0.0;
    }
    let u = (b - a) / len;
    let half = a.dot(u);
    let disc = half * half - (a.length_squared() - r * r);
    if disc <= 0.0 {
        return 0.0;
    }
    let (t0, t1) = (-half - disc.sqrt(), -half + disc.sqrt());
    (t1.min(len) - t0.max(0.0)).max(0.0)
}

/// A point lamp at the centre of a homogeneous fog sphere (σt = 0.4 m⁻¹) over a ground
/// below it, against the single-scattering integral evaluated by a fine f64 midpoint
/// rule: ∫ σs·p_HG(θ(t))·I/max(r(t)², 0.01)·exp(−σt·r_in(t))·exp(−σt·t_in) dt along the
/// view ray (r_in, t_in: the lamp and view paths' lengths inside the sphere), plus the
/// Lambertian ground, when the ray reaches it, lit and seen through the sphere (its
/// albedo a multiple of 1/255, as the mesh stores it).
#[test]
fn point_lamp_in_fog_matches_a_fine_quadrature() {
    let (radius, near_m, g) = (6.0, 0.01, 0.3);
    let (sigma_s, sigma_a) = ([0.25, 0.3, 0.35], 0.1);
    let sigma_t = mean(sigma_s) + sigma_a;
    let (ground_y, albedo) = (-7.0, [0.6, 0.6, 0.6]);
    let intensity = DVec3::new(1.0, 0.8, 0.6) * 5.0;
    let s = scene(&format!(
        r#"
        name = "lamp"
        [render]
        near_m = {near_m}
        far_m = 100.0
        sky = [0.0, 0.0, 0.0]
        ambient = [0.0, 0.0, 0.0]
        [camera]
        path = [[0.0, 0.0, 0.0]]
        [[light]]
        kind = "point"
        position = [0.0, 0.0, 0.0]
        color = [1.0, 0.8, 0.6]
        intensity = 5.0
        [[mesh]]
        kind = "box"
        min = [-20.0, -8.0, -20.0]
        max = [20.0, {ground_y}, 20.0]
        albedo = {albedo:?}
        [[medium]]
        kind = "sphere"
        center = [0.0, 0.0, 0.0]
        radius = {radius}
        scattering = {sigma_s:?}
        absorption = {sigma_a}
        g = {g}
        "#
    ));
    let views = [
        (
            "passes 0.25 m from the lamp",
            DVec3::new(0.25, 0.0, -4.0),
            DVec3::Z,
        ),
        (
            "passes 1 m from the lamp",
            DVec3::new(0.0, 1.0, -4.0),
            DVec3::Z,
        ),
        (
            "passes 3 m from the lamp",
            DVec3::new(3.0, 0.0, -4.0),
            DVec3::Z,
        ),
        (
            "looks away from the lamp",
            DVec3::new(0.0, 0.0, -2.0),
            DVec3::NEG_Z,
        ),
        (
            "looks down to the ground",
            DVec3::new(0.0, 0.0, -4.0),
            DVec3::new(0.3, -1.0, 0.5),
        ),
    ];
    let cams: Vec<Camera> = views.iter().map(|(_, o, d)| camera(&s, *o, *d)).collect();
    let got = render_1px(&s, &cams, TruthSettings::default());
    let mut worst = 0.0f64;
    for (((name, o, _), cam), got) in views.iter().zip(&cams).zip(got) {
        let d = cam.ray_dir(0.5, 0.5, 1, 1).as_dvec3();
        let start = *o + d * near_m;
        let t_ground = if d.y < 0.0 {
            (o.y - ground_y) / -d.y
        } else {
            f64::INFINITY
        };
        let half = o.dot(d);
        let t_exit = -half + (half * half - (o.length_squared() - radius * radius)).sqrt();
        let t_end = t_ground.min(t_exit);
        let n = 400_000;
        let h = (t_end - near_m) / n as f64;
        let mut in_scatter = DVec3::ZERO;
        for i in 0..n {
            let t = near_m + (i as f64 + 0.5) * h;
            let x = *o + d * t;
            let r = x.length();
            let lamp = intensity / (r * r).max(0.01)
                * (-sigma_t * chord_in_sphere(x, DVec3::ZERO, radius)).exp();
            let view = (-sigma_t * chord_in_sphere(start, x, radius)).exp();
            in_scatter += DVec3::from(sigma_s) * hg(g, (x / r).dot(-d)) * lamp * view * h;
        }
        let ground = if t_ground.is_finite() {
            let p = *o + d * t_ground;
            let r = p.length();
            let ndl = (-p.y / r).max(0.0);
            DVec3::from(albedo) / PI * intensity / (r * r).max(0.01)
                * ndl
                * (-sigma_t * chord_in_sphere(p, DVec3::ZERO, radius)).exp()
                * (-sigma_t * chord_in_sphere(start, p, radius)).exp()
        } else {
            DVec3::ZERO
        };
        let want = in_scatter + ground;
        let err = rel_err(got, want);
        println!(
            "{name:28}: quadrature {:.6} {:.6} {:.6}, truth {:.6} {:.6} {:.6}, rel err {err:.2e}",
            want.x, want.y, want.z, got.x, got.y, got.z
        );
        worst = worst.max(err);
    }
    assert!(worst < 1e-3, "worst relative error {worst:.2e} > 0.1 %");
}

/// σt at density 1 of a medium (grey: mean(σs) + σa, as `sample_media`).
fn sigma_t(m: &Medium) -> f64 {
    m.scattering.as_dvec3().element_sum() / 3.0 + f64::from(m.absorption)
}

/// exp(−∫σt) along `p + s·dir`, s in [0, len], by a midpoint sum of `density_at` with `n`
/// points over the whole ray (no clipping: outside the medium the density is 0).
fn brute_transmittance(m: &Medium, p: Vec3, dir: Vec3, len_m: f64, time_s: f32, n: u32) -> f64 {
    let h = len_m / f64::from(n);
    let (p, d) = (p.as_dvec3(), dir.as_dvec3());
    let sum: f64 = (0..n)
        .map(|i| {
            let s = (f64::from(i) + 0.5) * h;
            f64::from(density_at(m, (p + d * s).as_vec3(), time_s))
        })
        .sum();
    (-sigma_t(m) * sum * h).exp()
}

fn noise(frequency: f32, octaves: u32, amplitude: f32) -> Noise {
    Noise {
        frequency,
        octaves,
        amplitude,
        wind: [1.0, 0.0, 0.5],
    }
}

fn medium(kind: MediumKind, min: Vec3, max: Vec3, radius_or_falloff: f32, noise: Noise) -> Medium {
    Medium {
        kind,
        scattering: Vec3::new(0.08, 0.1, 0.12),
        absorption: 0.02,
        g: 0.0,
        emission: Vec3::ZERO,
        min,
        max,
        radius_or_falloff,
        base_y: 0.0,
        noise,
        volume: None,
    }
}

/// Origin, unit direction and length of a shadow ray.
type ShadowRay = (Vec3, Vec3, f32);

/// Shadow-ray transmittance against a brute-force sum of `density_at` (10⁶ points per
/// ray), and converged: doubling the quadrature segments moves it by < 1e-4 relative.
/// Every medium kind, with and without noise, at σt = 0.12 m⁻¹ along 40 m rays (T down
/// to ~0.01); and the built-in scenes' media along rays towards their own lights.
#[test]
fn shadow_transmittance_matches_brute_force_and_is_converged() {
    let (lo, hi) = (Vec3::new(-30.0, -5.0, -30.0), Vec3::new(30.0, 20.0, 30.0));
    let no_noise = noise(0.0, 1, 0.0);
    let synthetic = [
        ("box", medium(MediumKind::Box, lo, hi, 1.0, no_noise)),
        (
            "box, noise",
            medium(MediumKind::Box, lo, hi, 1.0, noise(0.35, 3, 0.5)),
        ),
        (
            "sphere, noise",
            medium(
                MediumKind::Sphere,
                Vec3::splat(-12.0),
                Vec3::splat(12.0),
                12.0,
                noise(0.2, 4, 0.8),
            ),
        ),
        ("height", medium(MediumKind::Height, lo, hi, 3.0, no_noise)),
        (
            "height, noise",
            medium(MediumKind::Height, lo, hi, 3.0, noise(0.35, 4, 0.8)),
        ),
        (
            "constant, noise",
            medium(MediumKind::Constant, lo, hi, 1.0, noise(0.5, 2, 0.7)),
        ),
    ];
    let points = unit_points(16);
    let random_rays: Vec<ShadowRay> = points
        .chunks(2)
        .map(|pair| {
            let p = Vec3::new(-20.0, -3.0, -20.0) + pair[0] * Vec3::new(40.0, 8.0, 40.0);
            (p, (pair[1] - Vec3::new(0.5, 0.2, 0.5)).normalize(), 40.0)
        })
        .collect();
    let mut cases: Vec<(String, Medium, Vec<ShadowRay>)> = synthetic
        .iter()
        .map(|(name, m)| (name.to_string(), *m, random_rays.clone()))
        .collect();
    for name in ["colonnade", "street", "islands"] {
        let s = Scene::load(name).unwrap();
        let lights = s.lights_at(0.0);
        for (i, m) in s.media.iter().enumerate() {
            let rays = points
                .iter()
                .zip(lights.iter().cycle())
                .map(|(u, l)| {
                    let p = m.min + (m.max - m.min) * *u * Vec3::new(1.0, 0.5, 1.0);
                    if l.kind == LightKind::Directional {
                        (p, -l.direction, 200.0)
                    } else {
                        let d = l.position - p;
                        (p, d.normalize(), d.length())
                    }
                })
                .collect();
            cases.push((format!("{name} medium {i}"), *m, rays));
        }
    }
    for (name, m, rays) in cases {
        let shadow = ShadowMedia::new(&[m], SEGMENTS);
        let doubled = ShadowMedia::new(&[m], 2 * SEGMENTS);
        let (mut worst_brute, mut worst_doubled, mut lowest) = (0.0f64, 0.0f64, 1.0f64);
        for (p, dir, len_m) in rays {
            let t = f64::from(shadow.transmittance(p, dir, len_m, 1.3));
            let t2 = f64::from(doubled.transmittance(p, dir, len_m, 1.3));
            let brute = brute_transmittance(&m, p, dir, f64::from(len_m), 1.3, 1_000_000);
            worst_brute = worst_brute.max((t - brute).abs() / brute);
            worst_doubled = worst_doubled.max((t - t2).abs() / t2);
            lowest = lowest.min(brute);
        }
        println!(
            "{name:18}: T vs brute force {worst_brute:.1e}, vs doubled segments {worst_doubled:.1e} (T down to {lowest:.3})"
        );
        assert!(
            worst_brute < 1e-4 && worst_doubled < 1e-4,
            "{name}: {worst_brute:.1e} vs brute force, {worst_doubled:.1e} vs doubled"
        );
    }
}

/// The limits: σt = 0 leaves T = 1 exactly, σt = 10⁴ m⁻¹ makes it exactly 0 (and the
/// renderer's radiance stays finite), and a 10 km sun ray 10⁵ m from the origin through
/// noisy height fog clips to the fog and stays finite and accurate.
#[test]
fn shadow_transmittance_limits() {
    let (lo, hi) = (Vec3::splat(-10.0), Vec3::splat(10.0));
    let (p, dir) = (
        Vec3::new(1.0, 2.0, 3.0),
        Vec3::new(0.3, 0.8, 0.2).normalize(),
    );
    let mut clear = medium(MediumKind::Box, lo, hi, 1.0, noise(0.3, 3, 0.5));
    clear.scattering = Vec3::ZERO;
    clear.absorption = 0.0;
    clear.emission = Vec3::ONE;
    assert_eq!(
        ShadowMedia::new(&[clear], 4).transmittance(p, dir, 1e4, 0.0),
        1.0
    );
    assert_eq!(
        ShadowMedia::new(&[], 4).transmittance(p, dir, 1e4, 0.0),
        1.0
    );
    let missed = medium(
        MediumKind::Box,
        lo + 100.0,
        hi + 100.0,
        1.0,
        noise(0.0, 1, 0.0),
    );
    assert_eq!(
        ShadowMedia::new(&[missed], 4).transmittance(p, dir, 1e4, 0.0),
        1.0
    );
    for n in [noise(0.0, 1, 0.0), noise(0.3, 3, 0.5)] {
        let mut thick = medium(MediumKind::Box, lo, hi, 1.0, n);
        thick.scattering = Vec3::splat(1e4);
        assert_eq!(
            ShadowMedia::new(&[thick], 4).transmittance(p, dir, 1e4, 0.0),
            0.0
        );
    }

    let s = scene(
        r#"
        name = "thick"
        [camera]
        path = [[0.0, 1.0, -3.0]]
        [[light]]
        kind = "directional"
        direction = [0.2, -1.0, 0.1]
        intensity = 10.0
        [[light]]
        kind = "point"
        position = [0.5, 1.0, 0.0]
        intensity = 10.0
        [[mesh]]
        kind = "box"
        min = [-5.0, -1.0, -5.0]
        max = [5.0, 0.0, 5.0]
        [[medium]]
        kind = "box"
        min = [-2.0, 0.0, -2.0]
        max = [2.0, 2.0, 2.0]
        scattering = [10000.0, 10000.0, 10000.0]
        noise = { frequency = 0.5, octaves = 3, amplitude = 0.5 }
        "#,
    );
    let bvh = Bvh::build(&s.mesh).unwrap();
    let cams = s.camera.viewers(1, 0.0);
    let settings = TruthSettings {
        steps: 64,
        ..TruthSettings::default()
    };
    let (img, _) = render_truth_radiance(&s, &bvh, &cams, (6, 4), 0.0, settings, &|_, _| {});
    for c in &img[0] {
        assert!(c.is_finite() && c.min_element() >= 0.0, "radiance {c}");
    }

    // 10 km from 10⁵ m off the origin: up towards a sun and almost level, through height
    // fog (falloff 50 m) with noise of 10 m finest wavelength spanning 12 km.
    let centre = Vec3::new(1e5, 0.0, 1e5);
    let mut far = medium(
        MediumKind::Height,
        centre - Vec3::new(6e3, 100.0, 6e3),
        centre + Vec3::new(6e3, 6e3, 6e3),
        50.0,
        noise(0.05, 2, 0.5),
    );
    far.scattering = Vec3::splat(0.002);
    far.absorption = 0.0005;
    let shadow = ShadowMedia::new(&[far], SEGMENTS);
    let from = centre + Vec3::new(37.0, 2.0, -12.0);
    for dir in [Vec3::new(-0.3, 1.0, -0.45), Vec3::new(1.0, 0.02, 0.3)] {
        let dir = dir.normalize();
        let t = shadow.transmittance(from, dir, 1e4, 2.0);
        let brute = brute_transmittance(&far, from, dir, 1e4, 2.0, 4_000_000);
        let err = (f64::from(t) - brute).abs() / brute;
        println!("10 km at 1e5 m, dir {dir}: T {t:.6}, brute force {brute:.6}, rel err {err:.1e}");
        assert!(t.is_finite() && (0.0..=1.0).contains(&t), "T = {t}");
        assert!(err < 1e-4, "T {t} vs brute force {brute}: {err:.1e}");
    }
}

/// `spp`: the box filter over each pixel. A wall's edge crosses the view; sky (radiance 1)
/// on one side, a lit wall on the other, no media. 1 spp is the pixel centre (the same
/// ray as the centre pixel of a 3× finer image, to the bit), 9 spp without jitter is the
/// mean of the 3×3 finer pixels it covers, and a pixel the edge crosses lies strictly
/// between the two sides, as does its jittered estimate.
#[test]
fn spp_box_filters_the_pixel() {
    let s = scene(
        r#"
        name = "edge"
        [render]
        sky = [1.0, 1.0, 1.0]
        ambient = [0.0, 0.0, 0.0]
        [camera]
        path = [[0.2, 0.0, 0.0]]
        [[light]]
        kind = "directional"
        direction = [0.2, -0.3, -1.0]
        intensity = 3.0
        [[mesh]]
        kind = "box"
        min = [-20.0, -20.0, -5.001]
        max = [0.0, 20.0, -5.0]
        albedo = [0.2, 0.2, 0.2]
        "#,
    );
    let bvh = Bvh::build(&s.mesh).unwrap();
    let cam = Camera::new(
        Vec3::new(0.2, 0.0, 0.0) - s.origin.as_vec3(),
        Vec3::NEG_Z,
        1.0,
    );
    let (w, h) = (12, 6);
    let render = |size: (u32, u32), spp: u32, seed: u32| {
        let settings = TruthSettings {
            spp,
            seed,
            ..TruthSettings::default()
        };
        let (img, _) = render_truth_radiance(&s, &bvh, &[cam], size, 0.0, settings, &|_, _| {});
        img.into_iter().next().unwrap()
    };
    let one = render((w, h), 1, 0);
    let fine = render((3 * w, 3 * h), 1, 0);
    let nine = render((w, h), 9, 0);
    let jittered = render((w, h), 9, 17);
    let five = render((w, h), 5, 0);
    let fine_at = |x: u32, y: u32| fine[(y * 3 * w + x) as usize];
    let (sky, wall) = (one[(w - 1) as usize].x, one[0].x);
    assert!(
        sky == 1.0 && wall > 0.0 && wall < 0.5,
        "sky {sky}, wall {wall}"
    );
    let mut straddling = 0;
    for y in 0..h {
        for x in 0..w {
            let i = (y * w + x) as usize;
            assert_eq!(one[i], fine_at(3 * x + 1, 3 * y + 1), "1 spp at ({x}, {y})");
            let block = (0..9)
                .map(|k| fine_at(3 * x + k % 3, 3 * y + k / 3))
                .fold(Vec3::ZERO, |a, c| a + c)
                / 9.0;
            assert!(
                (nine[i] - block).abs().max_element() <= 1e-5,
                "9 spp at ({x}, {y}): {} vs the 3×3 finer pixels' mean {block}",
                nine[i]
            );
            for c in [nine[i], jittered[i], five[i]] {
                assert!(c.x >= wall - 1e-6 && c.x <= sky + 1e-6, "({x}, {y}): {c}");
            }
            let (lo, hi) = (block.x.min(one[i].x), block.x.max(one[i].x));
            if block.x > wall + 0.01 && block.x < sky - 0.01 {
                straddling += 1;
                println!(
                    "edge pixel ({x}, {y}): 1 spp {:.4}, 9 spp {:.4} (jittered {:.4}), 5 spp {:.4}, sides {wall:.4} / {sky:.4}",
                    one[i].x, nine[i].x, jittered[i].x, five[i].x
                );
                for c in [nine[i], jittered[i]] {
                    assert!(c.x > wall && c.x < sky, "({x}, {y}): {c}");
                }
            } else {
                assert!(
                    hi - lo <= 1e-5 && (jittered[i] - one[i]).abs().max_element() <= 1e-5,
                    "pixel ({x}, {y}) on one side changed with spp: {} vs {}",
                    jittered[i],
                    one[i]
                );
            }
        }
    }
    assert_eq!(straddling, h, "the edge crosses one pixel per row");
}
