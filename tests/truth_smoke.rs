//! Smoke in the ground-truth renderer against what can be computed without it (issue 15):
//! one Gaussian particle under a sun against an f64 quadrature whose transmittances are
//! brute-force sums of the density (not the erf closed form truth uses), a sun straight
//! behind the eye against the closed form `ϖ·E·p·(1 − T²)/2` at densities up to 10⁴ m⁻¹,
//! a lamp inside a particle against a quadrature, shadow rays through a cluster of
//! particles against a brute-force sum, and the degenerate cases (no particles, zero
//! size, far away, eye inside). Images are 1×1 pixels of linear radiance.

use fogcast::scene::{Bvh, Camera, Scene};
use fogcast::smoke::emitter::particles_at;
use fogcast::truth::{render_truth_radiance, Smoke, TruthSettings};
use glam::{DVec3, Vec3};
use std::f64::consts::PI;
use std::path::Path;

fn scene(toml: &str) -> Scene {
    Scene::from_toml(toml, Path::new("inline.toml")).expect("test scene is valid")
}

/// Linear radiance of each camera's single pixel (its ray is the camera's forward).
fn render_1px(scene: &Scene, cams: &[Camera]) -> Vec<Vec3> {
    let bvh = Bvh::build(&scene.mesh).unwrap();
    let (img, _) = render_truth_radiance(
        scene,
        &bvh,
        cams,
        (1, 1),
        0.0,
        TruthSettings::default(),
        &|_, _| {},
    );
    img.into_iter().map(|v| v[0]).collect()
}

/// Henyey-Greenstein phase in f64; `cos` between the light's travel and the way to the eye.
fn hg(g: f64, cos: f64) -> f64 {
    (1.0 - g * g) / (4.0 * PI * (1.0 + g * g - 2.0 * g * cos).powf(1.5))
}

fn rel_err(got: Vec3, want: DVec3) -> f64 {
    ((got.as_dvec3() - want) / want).abs().max_element()
}

fn finite(v: Vec3) -> bool {
    v.is_finite() && v.min_element() >= 0.0
}

/// One particle of falloff `u` at world `centre` (a point emitter seen at time 0 holds
/// exactly its first particle, at the emitter, of falloff `u`), ground far below out of
/// every ray's way, black sky and ambient, and `light` (TOML).
fn one_particle(
    centre: [f64; 3],
    u: f64,
    sigma_s: [f64; 3],
    sigma_a: f64,
    g: f64,
    light: &str,
) -> Scene {
    scene(&format!(
        r#"
        name = "particle"
        [render]
        near_m = 0.01
        far_m = 20000.0
        sky = [0.0, 0.0, 0.0]
        ambient = [0.0, 0.0, 0.0]
        [camera]
        path = [[0.0, 0.0, 0.0]]
        {light}
        [[mesh]]
        kind = "box"
        min = [-50.0, -30.0, -50.0]
        max = [50.0, -20.0, 50.0]
        [[emitter]]
        shape = "point"
        position = {centre:?}
        rate_per_s = 1.0
        lifetime_s = 100.0
        falloff_u = {u}
        scattering = {sigma_s:?}
        absorption = {sigma_a}
        g = {g}
        max_particles = 1
        "#
    ))
}

/// σt(x) = σ·exp(−50|x − c|²/u²), written out again.
fn density(sigma_t: f64, c: DVec3, u: f64, x: DVec3) -> f64 {
    sigma_t * (-50.0 * (x - c).length_squared() / (u * u)).exp()
}

/// ∫₀^len σt along `p + s·dir` by an `n`-point midpoint sum.
fn brute_depth(f: &dyn Fn(DVec3) -> f64, p: DVec3, dir: DVec3, len: f64, n: u32) -> f64 {
    let h = len / f64::from(n);
    (0..n)
        .map(|i| f(p + dir * ((f64::from(i) + 0.5) * h)))
        .sum::<f64>()
        * h
}

/// Single scattering of one particle along the camera's ray by a midpoint rule over
/// `[b − u, b + u]` (b: closest approach; the density beyond is below e^{−50} of its
/// peak), view transmittance by the running midpoint sum of the same density, light
/// transmittance from `light_t(x)`, in-scattered `σs(x)·light(x)`.
fn quadrature(
    o: DVec3,
    d: DVec3,
    c: DVec3,
    u: f64,
    sigma_t: f64,
    sigma_s: DVec3,
    light: &dyn Fn(DVec3) -> DVec3,
) -> DVec3 {
    let b = (c - o).dot(d);
    let (s0, s1) = (b - u, b + u);
    let n = 4000;
    let h = (s1 - s0) / f64::from(n);
    let (mut tau, mut sum) = (0.0, DVec3::ZERO);
    for i in 0..n {
        let x = o + d * (s0 + (f64::from(i) + 0.5) * h);
        let st = density(sigma_t, c, u, x);
        let t_view = (-(tau + 0.5 * st * h)).exp();
        sum += sigma_s * (st / sigma_t) * light(x) * t_view * h;
        tau += st * h;
    }
    sum
}

/// (a) One particle under a sun from above, seen from the side through its centre and
/// 0.3u and 0.6u off it: truth's pixel against the f64 quadrature whose sun and view
/// transmittances are brute-force sums of the density.
#[test]
fn one_particle_under_a_sun_matches_a_brute_force_quadrature() {
    let (u, g, e) = (1.0, 0.4, 5.0);
    let (sigma_s, sigma_a) = ([3.0, 2.5, 2.0], 0.5);
    let sigma_t = 2.5 + sigma_a;
    let sun = DVec3::new(0.3, -1.0, 0.45).normalize();
    let s = one_particle(
        [0.0, 0.0, 6.0],
        u,
        sigma_s,
        sigma_a,
        g,
        &format!(
            "[[light]]\nkind = \"directional\"\ndirection = [0.3, -1.0, 0.45]\nintensity = {e}"
        ),
    );
    let c = DVec3::from(s.emitters[0].position.map(f64::from));
    let offsets = [0.0, 0.1, 0.3, 0.6];
    let cams: Vec<Camera> = offsets
        .iter()
        .map(|h| Camera::new((c + DVec3::new(h * u, 0.0, -6.0)).as_vec3(), Vec3::Z, 1.0))
        .collect();
    let got = render_1px(&s, &cams);
    let mut worst = 0.0f64;
    for ((h, cam), got) in offsets.iter().zip(&cams).zip(got) {
        let o = cam.position.as_dvec3();
        let d = cam.ray_dir(0.5, 0.5, 1, 1).as_dvec3().normalize();
        let f = |x: DVec3| density(sigma_t, c, u, x);
        let light = |x: DVec3| {
            // Toward the sun: 2u is past the particle's reach from any x within u of it.
            let t = (-brute_depth(&f, x, -sun, 2.0 * u, 2000)).exp();
            DVec3::splat(e * hg(g, sun.dot(-d)) * t)
        };
        let want = quadrature(o, d, c, u, sigma_t, DVec3::from(sigma_s), &light);
        let err = rel_err(got, want);
        println!(
            "ray {h}u off the centre: quadrature {:.7e} {:.7e} {:.7e}, truth {:.7e} {:.7e} {:.7e}, rel err {err:.2e}",
            want.x, want.y, want.z, got.x, got.y, got.z
        );
        // 0.6u off, the density on the ray peaks at e^{−18} of the centre's: faint, but
        // far above f32's smallest normals.
        assert!(want.min_element() > 1e-12, "the reference is not vacuous");
        worst = worst.max(err);
    }
    assert!(worst < 1e-3, "worst relative error {worst:.2e} > 0.1 %");
}

/// With the sun exactly behind the eye, light reaching a point has crossed the same smoke
/// as the light leaving it towards the eye: `T_light = T_view`, so the single scattering
/// is `ϖ·E·p(−1)·∫σt·T² ds = ϖ·E·p(−1)·(1 − T²)/2`, `T = exp(−τ)` of the whole ray, for
/// any density profile: `τ = σ·u·√(π/50)·e^{−50h²/u²}` (h: the ray's distance from the
/// centre). This holds at σt = 10⁴ m⁻¹ (τ ≈ 2500) as at 0.3 m⁻¹.
#[test]
fn sun_behind_the_eye_matches_the_closed_form_at_any_density() {
    let (u, g, e) = (1.0, 0.6, 4.0);
    let mut worst = 0.0f64;
    for sigma_t in [0.3, 3.0, 30.0, 1e4] {
        // ϖ = 0.8, 0.7, 0.6 per channel.
        let sigma_s = [0.8 * sigma_t, 0.7 * sigma_t, 0.6 * sigma_t];
        let sigma_a = sigma_t - 0.7 * sigma_t;
        for z in [6.0, 1e4] {
            if z > 10.0 && sigma_t != 3.0 {
                continue;
            }
            let s = one_particle(
                [0.0, 0.0, z],
                u,
                sigma_s,
                sigma_a,
                g,
                &format!("[[light]]\nkind = \"directional\"\ndirection = [0.0, 0.0, 1.0]\nintensity = {e}"),
            );
            let c = DVec3::from(s.emitters[0].position.map(f64::from));
            let offsets = [0.0, 0.25, 0.5];
            let cams: Vec<Camera> = offsets
                .iter()
                .map(|h| {
                    // A particle 10 km away is seen from the origin (the camera path);
                    // a near one from 6 m.
                    let back = if z > 10.0 { z } else { 6.0 };
                    Camera::new((c + DVec3::new(h * u, 0.0, -back)).as_vec3(), Vec3::Z, 1.0)
                })
                .collect();
            let got = render_1px(&s, &cams);
            for ((h, cam), got) in offsets.iter().zip(&cams).zip(got) {
                // The ray's actual distance from the centre, in f64.
                let o = cam.position.as_dvec3();
                let d = cam.ray_dir(0.5, 0.5, 1, 1).as_dvec3().normalize();
                let to_c = c - o;
                let h2 = (to_c - d * to_c.dot(d)).length_squared();
                let tau = sigma_t * u * (PI / 50.0).sqrt() * (-50.0 * h2 / (u * u)).exp();
                let albedo = DVec3::new(0.8, 0.7, 0.6);
                let want = albedo * e * hg(g, -1.0) * -(-2.0 * tau).exp_m1() / 2.0;
                assert!(finite(got), "σt {sigma_t}: {got}");
                let err = rel_err(got, want);
                let tol = if z > 10.0 { 1e-2 } else { 1e-3 };
                println!(
                    "σt {sigma_t:7}, {z:5} m away, {h}u off: τ {tau:9.3e}, closed form {:.6} {:.6} {:.6}, truth {:.6} {:.6} {:.6}, rel err {err:.2e}",
                    want.x, want.y, want.z, got.x, got.y, got.z
                );
                assert!(err < tol, "σt {sigma_t}, {z} m, {h}u: rel err {err:.2e}");
                if z < 10.0 {
                    worst = worst.max(err);
                }
            }
        }
    }
    println!("worst relative error (near particles): {worst:.2e}");
}

/// The eye at a particle's centre, the sun behind it: light reaching the point s ahead has
/// crossed the half of the particle behind the near plane and then the same smoke as the
/// view ray, so `L = ϖ·E·p(−1)·e^{−τ_b}·(1 − e^{−2τ_f})/2` with `τ_b`, `τ_f` the optical
/// depths behind and beyond the near plane (erf of the Gaussian). At σt = 10⁴ the sun is
/// gone: black, and finite.
#[test]
fn eye_inside_the_smoke() {
    let (u, g, e, near) = (1.0, 0.2, 3.0, 0.01);
    for sigma_t in [0.3, 3.0, 30.0, 1e4] {
        let s = one_particle(
            [0.0, 0.0, 6.0],
            u,
            [sigma_t; 3],
            0.0,
            g,
            &format!(
                "[[light]]\nkind = \"directional\"\ndirection = [0.0, 0.0, 1.0]\nintensity = {e}"
            ),
        );
        let c = DVec3::from(s.emitters[0].position.map(f64::from));
        let cam = Camera::new(c.as_vec3(), Vec3::Z, 1.0);
        let got = render_1px(&s, &[cam])[0];
        let k = 50f64.sqrt() / u;
        let half = sigma_t * PI.sqrt() / (2.0 * k);
        let (tau_b, tau_f) = (
            half * (1.0 + libm::erf(k * near)),
            half * libm::erfc(k * near),
        );
        let want = DVec3::splat(e * hg(g, -1.0) * (-tau_b).exp() * -(-2.0 * tau_f).exp_m1() / 2.0);
        println!(
            "σt {sigma_t:7}: closed form {:.6e}, truth {:.6e} {:.6e} {:.6e}",
            want.x, got.x, got.y, got.z
        );
        assert!(finite(got), "σt {sigma_t}: {got}");
        if want.x > 1e-30 {
            let err = rel_err(got, want);
            assert!(err < 1e-3, "σt {sigma_t}: rel err {err:.2e}");
        } else {
            assert!(got.max_element() < 1e-20, "σt {sigma_t}: {got}");
        }
    }
}

/// A point lamp at a particle's centre, seen along rays 0.3u and 0.6u from it (the lamp's
/// 1/r² stays smooth there): truth against an f64 quadrature of
/// `σs·p·I/r²·T_lamp·T_view`, both transmittances brute-force sums. And with σt = 10⁴ the
/// lamp is buried: finite, not negative, and dimmer.
#[test]
fn lamp_inside_a_particle_matches_a_brute_force_quadrature() {
    let (u, g, intensity) = (1.0, 0.3, 2.0);
    let mut worst = 0.0f64;
    for (sigma_t, check) in [(2.0, true), (1e4, false)] {
        let s = one_particle(
            [0.0, 0.0, 6.0],
            u,
            [0.9 * sigma_t, 0.8 * sigma_t, 0.7 * sigma_t],
            0.2 * sigma_t,
            g,
            &format!(
                "[[light]]\nkind = \"point\"\nposition = [0.0, 0.0, 6.0]\nintensity = {intensity}"
            ),
        );
        let c = DVec3::from(s.emitters[0].position.map(f64::from));
        let lamp = s.lights[0].position.as_dvec3();
        let offsets = [0.15, 0.3, 0.6];
        let cams: Vec<Camera> = offsets
            .iter()
            .map(|h| Camera::new((c + DVec3::new(0.0, h * u, -6.0)).as_vec3(), Vec3::Z, 1.0))
            .collect();
        let got = render_1px(&s, &cams);
        for ((h, cam), got) in offsets.iter().zip(&cams).zip(got) {
            assert!(finite(got), "σt {sigma_t}, {h}u: {got}");
            let o = cam.position.as_dvec3();
            let d = cam.ray_dir(0.5, 0.5, 1, 1).as_dvec3().normalize();
            let f = |x: DVec3| density(sigma_t, c, u, x);
            let light = |x: DVec3| {
                let to = lamp - x;
                let r = to.length();
                let t = (-brute_depth(&f, x, to / r, r, 2000)).exp();
                DVec3::splat(intensity / (r * r).max(0.01) * hg(g, (x - lamp).dot(-d) / r) * t)
            };
            let want = quadrature(
                o,
                d,
                c,
                u,
                sigma_t,
                DVec3::new(0.9, 0.8, 0.7) * sigma_t,
                &light,
            );
            let err = rel_err(got, want);
            println!(
                "σt {sigma_t:7}, {h}u off the lamp: quadrature {:.6e} {:.6e} {:.6e}, truth {:.6e} {:.6e} {:.6e}, rel err {err:.2e}",
                want.x, want.y, want.z, got.x, got.y, got.z
            );
            if check {
                assert!(want.min_element() > 1e-12, "the reference is not vacuous");
                worst = worst.max(err);
            }
        }
    }
    assert!(worst < 1e-3, "worst relative error {worst:.2e} > 0.1 %");
}

/// A cluster of particles (sphere emitter, growing, drifting) at time 4 s.
fn cluster_scene(extra: &str) -> Scene {
    scene(&format!(
        r#"
        name = "cluster"
        [render]
        near_m = 0.01
        far_m = 200.0
        sky = [0.0, 0.0, 0.0]
        ambient = [0.0, 0.0, 0.0]
        [camera]
        path = [[0.0, 2.0, 0.0]]
        [[mesh]]
        kind = "box"
        min = [-30.0, -1.0, -30.0]
        max = [30.0, 0.0, 30.0]
        albedo = [0.6, 0.6, 0.6]
        [[emitter]]
        shape = "sphere"
        position = [1.5, 5.0, 2.25]
        radius = 1.2
        rate_per_s = 10.0
        lifetime_s = 100.0
        velocity = [0.0, 0.1, 0.0]
        spread = 0.3
        growth = 0.1
        falloff_u = 0.5
        scattering = [1.5, 1.5, 1.5]
        absorption = 0.5
        g = 0.5
        max_particles = 1000
        seed = 11
        {extra}
        "#
    ))
}

/// (b) Shadow rays through a cluster of 40 particles: `Smoke::optical_depth` (closed form per
/// particle, with the cut-off) against a 10⁶-point midpoint sum of every particle's
/// density (taken from the emitter simulation directly); and the ground lit by a sun
/// through the cluster against `albedo/π·E·cosθ·T` with that brute-force T.
#[test]
fn shadow_rays_through_particles_match_a_brute_force_sum() {
    let time_s = 3.95;
    let s = cluster_scene(
        "[[light]]\nkind = \"directional\"\ndirection = [-0.3, -1.0, -0.45]\nintensity = 5.0",
    );
    let smoke = Smoke::new(&s.emitters, time_s);
    let e = &s.emitters[0];
    let live = particles_at(e, time_s);
    assert_eq!(live.len(), 40);
    assert_eq!(smoke.particles().len(), 40);
    let sigma_t = 1.5 + 0.5;
    let field = |x: DVec3| {
        live.iter()
            .map(|p| density(sigma_t, p.centre, p.falloff_u_m, x))
            .sum::<f64>()
    };
    let c = DVec3::from(e.position.map(f64::from));
    let rays = [
        ("through the middle", c - DVec3::X * 5.0, DVec3::X, 10.0),
        (
            "diagonal",
            c - DVec3::new(3.0, 4.0, 2.0),
            DVec3::new(3.0, 4.0, 2.0).normalize(),
            10.0,
        ),
        ("from inside, upwards", c, DVec3::Y, 8.0),
        (
            "grazing the top",
            c + DVec3::new(-5.0, 1.4, 0.0),
            DVec3::X,
            10.0,
        ),
        ("ending inside", c - DVec3::Z * 5.0, DVec3::Z, 5.0),
        (
            "missing it",
            c + DVec3::Y * 6.0 - DVec3::X * 5.0,
            DVec3::X,
            10.0,
        ),
    ];
    let mut worst = 0.0f64;
    for (name, p, dir, len) in rays {
        let got = smoke.optical_depth(p, dir, len, f64::INFINITY);
        let want = brute_depth(&field, p, dir, len, 1_000_000);
        let t_got = smoke.transmittance(p, dir, len);
        println!("{name:22}: brute-force τ {want:.9}, truth τ {got:.9}, T {t_got:.6}");
        if want > 1e-6 {
            let err = (got - want).abs() / want;
            worst = worst.max(err);
            assert!((t_got - (-want).exp()).abs() < 1e-6 * (-want).exp().max(1e-3));
        } else {
            // Next to nothing on this ray: absolute agreement (the 0.8 u cut drops at most
            // ~1e-14 of a particle's peak density per particle).
            assert!(
                (got - want).abs() < 1e-9 && (t_got - (-want).exp()).abs() < 1e-9,
                "{name}: τ {got} vs {want}"
            );
        }
    }
    println!("worst relative error of τ: {worst:.2e}");
    assert!(worst < 1e-6, "worst relative error {worst:.2e}");

    // The ground at P, whose sun ray passes through the centre of the particle nearest the
    // cluster's centroid; the eye sees P from the other side.
    let sun = DVec3::new(-0.3, -1.0, -0.45).normalize();
    let centroid = live.iter().map(|q| q.centre).sum::<DVec3>() / live.len() as f64;
    let through = live
        .iter()
        .map(|q| q.centre)
        .min_by(|a, b| {
            (*a - centroid)
                .length()
                .total_cmp(&(*b - centroid).length())
        })
        .unwrap();
    let ground_y = -s.origin.y;
    let p = through + sun * ((through.y - ground_y) / sun.y.abs());
    let eye = p + DVec3::new(-6.0, 3.0, 4.0);
    let cam = Camera::new(eye.as_vec3(), (p - eye).as_vec3(), 1.0);
    let bvh = Bvh::build(&s.mesh).unwrap();
    let (img, _) = render_truth_radiance(
        &s,
        &bvh,
        &[cam],
        (1, 1),
        time_s as f32,
        TruthSettings::default(),
        &|_, _| {},
    );
    let got = img[0][0];
    let d = cam.ray_dir(0.5, 0.5, 1, 1).as_dvec3().normalize();
    let hit = eye + d * (-eye.y - s.origin.y) / d.y;
    let view_tau = brute_depth(&field, hit, -d, (eye - hit).length(), 100_000);
    let max_ray = f64::from((s.bounds.1 - s.bounds.0).length() + 1.0);
    let sun_tau = brute_depth(&field, hit, -sun, max_ray, 1_000_000);
    let want = DVec3::splat(0.6 / PI * 5.0 * -sun.y * (-sun_tau).exp());
    let err = rel_err(got, want);
    println!(
        "ground through the cluster: sun τ {sun_tau:.4}, view τ {view_tau:.2e}, expected {:.6}, truth {:.6}, rel err {err:.2e}",
        want.x, got.x
    );
    assert!(
        sun_tau > 0.01,
        "the sun ray crosses the cluster: τ {sun_tau}"
    );
    assert!(
        view_tau < 1e-9,
        "the view ray misses the cluster: τ {view_tau}"
    );
    assert!(err < 1e-4, "rel err {err:.2e}");
}

/// Zero particles (max_particles 0), particles of zero size (u = 0, set after loading:
/// the scene format refuses it) and emitters without extinction render exactly as the
/// scene without emitters; the real particle does not.
#[test]
fn empty_smoke_changes_nothing() {
    let s = one_particle(
        [0.0, 0.0, 6.0],
        1.0,
        [2.0; 3],
        0.5,
        0.3,
        "[[light]]\nkind = \"directional\"\ndirection = [0.3, -1.0, 0.45]\nintensity = 5.0",
    );
    let c = s.emitters[0].position;
    // Through the particle's centre, then down to the ground.
    let cam = Camera::new(
        Vec3::from(c) + Vec3::new(0.0, 3.0, -6.0),
        Vec3::new(0.0, -1.0, 2.0),
        1.0,
    );
    let with = render_1px(&s, &[cam])[0];
    let mut none = s.clone();
    none.emitters.clear();
    let without = render_1px(&none, &[cam])[0];
    assert!(finite(with) && finite(without));
    assert!(
        (with.x - without.x).abs() > 1e-3,
        "the particle shows: {with} vs {without}"
    );
    let variants: [(&str, EditEmitter); 3] = [
        ("max_particles 0", |e| e.max_particles = 0),
        ("u = 0", |e| {
            e.falloff_u = 0.0;
            e.growth = 0.0;
        }),
        ("no extinction", |e| {
            e.scattering = [0.0; 3];
            e.absorption = 0.0;
        }),
    ];
    for (name, change) in variants {
        let mut v = s.clone();
        change(&mut v.emitters[0]);
        assert!(Smoke::new(&v.emitters, 0.0).is_empty(), "{name}");
        let got = render_1px(&v, &[cam])[0];
        println!("{name}: {got} (no emitters: {without})");
        assert_eq!(got, without, "{name}");
    }
}

/// A dense particle (σt = 10⁴ m⁻¹) lit by a sun from above, seen from the side: finite,
/// lit, and within the bound `ϖ·E·p` that single scattering of one light cannot exceed
/// (`∫σs·T_view·T_light·E·p ds ≤ ϖ·E·p·∫σt·T_view ds ≤ ϖ·E·p`).
#[test]
fn dense_particle_is_finite_lit_and_bounded() {
    let (e, g) = (5.0, 0.3);
    let s = one_particle(
        [0.0, 0.0, 6.0],
        1.0,
        [8000.0; 3],
        2000.0,
        g,
        &format!(
            "[[light]]\nkind = \"directional\"\ndirection = [0.3, -1.0, 0.45]\nintensity = {e}"
        ),
    );
    let c = DVec3::from(s.emitters[0].position.map(f64::from));
    let sun = DVec3::new(0.3, -1.0, 0.45).normalize();
    for h in [0.0, 0.3, 0.45, 0.6] {
        let cam = Camera::new((c + DVec3::new(0.0, h, -6.0)).as_vec3(), Vec3::Z, 1.0);
        let got = render_1px(&s, &[cam])[0];
        let bound = 0.8 * e * hg(g, sun.dot(-DVec3::Z));
        println!("σt 1e4, {h}u above the centre: truth {got}, bound {bound:.6}");
        assert!(finite(got), "{got}");
        assert!(
            f64::from(got.max_element()) <= bound * (1.0 + 1e-4),
            "{got} > {bound}"
        );
        if h < 0.5 {
            // Dense where the ray passes (0.45u off: σt 0.4 m⁻¹ at the closest point)
            // and lit from above.
            assert!(
                f64::from(got.min_element()) > 0.05 * bound,
                "{got}: black where lit"
            );
        } else {
            // 0.6u off: σt 1.5e-4 m⁻¹ on the ray, optically thin: faint, not zero.
            assert!(got.min_element() > 0.0, "{got}");
        }
    }
}

/// A change to a loaded emitter (what the format itself would refuse).
type EditEmitter = fn(&mut fogcast::scene::EmitterDesc);
