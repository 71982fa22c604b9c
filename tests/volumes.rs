//! `[[volume]]` primitives (issue 14, paper 004's displaced spheres): `truth` integrates
//! them exactly enough (a shadow ray's optical depth against a dense sum of the density,
//! convergence in the quadrature's segments), and `reference` and `shared` evaluate the
//! same density in WGSL (its CPU twin is `fogcast::scene::density_at`) and agree with
//! `truth` on a small scene.

mod gpu_support;

use fogcast::metrics::compare;
use fogcast::render::{Mode, Renderer, Settings};
use fogcast::scene::{density_at, Bvh, Camera, Medium, Scene};
use fogcast::truth::{render_truth, ShadowMedia, TruthSettings};
use glam::{DVec3, Vec3};
use gpu_support::{gpu, unit_points};
use std::path::Path;
use std::sync::Arc;

fn load(text: &str) -> Scene {
    Scene::from_toml(text, Path::new("inline.toml"))
        .unwrap_or_else(|e| panic!("scene does not load: {e}\n{text}"))
}

/// A scene of one `[[volume]]` table (`volume`, its keys after the header) over a floor.
fn volume_scene(volume: &str) -> Scene {
    load(&format!(
        "name = \"volume\"\n[camera]\npath = [[0.0, 1.0, 8.0], [1.0, 1.0, -8.0]]\n\
         [[mesh]]\nkind = \"box\"\nmin = [-10.0, -0.5, -10.0]\nmax = [10.0, 0.0, 10.0]\n\
         [[volume]]\n{volume}\n"
    ))
}

/// The volumes the quadrature is checked on: displaced and moving, a plain soft sphere,
/// displaced with density noise inside, very small and very large.
fn volumes() -> Vec<(&'static str, Medium)> {
    let v = |text: &str| volume_scene(text).media[0];
    vec![
        (
            "displaced, moving",
            v(
                "center = [0.0, 2.0, 0.0]\nradius = 2.0\nscattering = [0.4, 0.5, 0.6]\n\
               absorption = 0.1\ndisplacement = { amplitude = 0.4, frequency = 3.0, octaves = 3 }\n\
               motion = { velocity = [0.5, 0.0, 0.25], period_s = 8.0 }",
            ),
        ),
        (
            "soft sphere",
            v("center = [0.0, 2.0, 0.0]\nradius = 2.0\nscattering = [0.8, 0.8, 0.8]"),
        ),
        (
            "displaced, noisy density",
            v(
                "center = [1.0, 2.0, 0.0]\nradius = 3.0\nscattering = [0.3, 0.3, 0.3]\n\
               displacement = { amplitude = 0.25, frequency = 2.0, octaves = 4, seed = 7 }\n\
               noise = { frequency = 0.8, octaves = 3, amplitude = 0.6, wind = [1.0, 0.0, 0.0] }",
            ),
        ),
        (
            "radius 1 mm",
            v(
                "center = [0.0, 1.0, 0.0]\nradius = 0.001\nscattering = [500.0, 500.0, 500.0]\n\
               displacement = { amplitude = 0.3 }",
            ),
        ),
        (
            "radius 10 km",
            v(
                "center = [0.0, 1.0, 0.0]\nradius = 1.0e4\nscattering = [1.0e-4, 1.0e-4, 1.0e-4]\n\
               displacement = { amplitude = 0.3, frequency = 4.0 }",
            ),
        ),
    ]
}

/// Rays from points spread around the volume's centre (at `time_s`), some starting
/// inside it, in directions spread over the sphere, each `2.5·r` long.
fn rays(m: &Medium, time_s: f32) -> Vec<(Vec3, Vec3, f32)> {
    let v = m.volume.expect("a volume");
    let c = v.center_at(time_s);
    let r = v.radius_m;
    unit_points(24)
        .chunks(2)
        .map(|pair| {
            let p = c + (pair[0] - 0.5) * 3.0 * r;
            let dir = (pair[1] - 0.5).normalize();
            // Aim half the rays back through the centre so that most cross the volume.
            let dir = if pair[1].x < 0.5 {
                dir
            } else {
                (c - p).normalize()
            };
            (p, dir, 2.5 * r)
        })
        .collect()
}

/// ∫ density over the ray by a midpoint sum of `n` points over the part of the ray
/// inside the volume's outer ball (outside it the density is 0).
fn dense_sum(m: &Medium, p: Vec3, dir: Vec3, len_m: f32, time_s: f32, n: u32) -> f64 {
    let v = m.volume.unwrap();
    let (p64, d64) = (p.as_dvec3(), dir.as_dvec3());
    let oc: DVec3 = p64 - v.center_at(time_s).as_dvec3();
    let b = oc.dot(d64);
    let disc = b * b - (oc.length_squared() - f64::from(v.outer_radius_m()).powi(2));
    if disc <= 0.0 {
        return 0.0;
    }
    let (s0, s1) = (
        (-b - disc.sqrt()).max(0.0),
        (-b + disc.sqrt()).min(f64::from(len_m)),
    );
    if s1 <= s0 {
        return 0.0;
    }
    let h = (s1 - s0) / f64::from(n);
    (0..n)
        .map(|i| {
            let s = s0 + (f64::from(i) + 0.5) * h;
            f64::from(density_at(m, (p64 + d64 * s).as_vec3(), time_s))
        })
        .sum::<f64>()
        * h
}

/// Truth's shadow-ray optical depth through a volume matches a 10⁶-point sum of the
/// density within 1e-3 relative, and doubling its quadrature segments per feature
/// (halving the step) changes the transmittance by less than 1e-4.
#[test]
fn shadow_optical_depth_through_volumes_matches_a_dense_sum() {
    const TIME_S: f32 = 2.7;
    let segments = TruthSettings::default().shadow_segments_per_feature;
    for (name, m) in volumes() {
        let sigma_t = f64::from(m.scattering.element_sum() / 3.0 + m.absorption);
        let shadow = ShadowMedia::new(&[m], segments);
        let doubled = ShadowMedia::new(&[m], 2 * segments);
        let (mut worst_sum, mut worst_t, mut crossed) = (0.0f64, 0.0f64, 0);
        for (p, dir, len_m) in rays(&m, TIME_S) {
            let tau = shadow.optical_depth(p, dir, len_m, TIME_S);
            let dense = sigma_t * dense_sum(&m, p, dir, len_m, TIME_S, 1_000_000);
            if dense > 0.0 {
                crossed += 1;
                worst_sum = worst_sum.max((tau - dense).abs() / dense);
            } else {
                assert_eq!(tau, 0.0, "{name}: τ {tau} where the density is 0");
            }
            let t = f64::from(shadow.transmittance(p, dir, len_m, TIME_S));
            let t2 = f64::from(doubled.transmittance(p, dir, len_m, TIME_S));
            worst_t = worst_t.max((t - t2).abs());
        }
        println!(
            "{name:26}: τ vs dense sum {worst_sum:.1e} relative ({crossed} rays cross it), \
             T vs doubled segments {worst_t:.1e}"
        );
        assert!(crossed >= 6, "{name}: only {crossed} rays cross the volume");
        assert!(worst_sum <= 1e-3, "{name}: τ vs dense sum {worst_sum:.1e}");
        assert!(
            worst_t < 1e-4,
            "{name}: T vs doubled segments {worst_t:.1e}"
        );
    }
}

/// A displaced, drifting cloud over a floor, lit by a low sun, seen by two viewers (one
/// looking through its edge against the sky). Density scale and size like a thick dust
/// cloud: τ ≈ 2 across the middle.
const CLOUD: &str = r#"
name = "cloud"
[render]
near_m = 0.1
far_m = 40.0
voxel_size_m = 0.5
sky = [0.3, 0.4, 0.55]
ambient = [0.05, 0.05, 0.06]
[camera]
path = [[-7.0, 1.6, 6.0], [6.0, 2.5, 5.0]]
look_at = [[0.0, 2.0, 0.0], [-0.5, 3.0, -1.0]]
fov_deg = 60.0
[[light]]
kind = "directional"
direction = [0.5, -0.6, 0.3]
intensity = 6.0
[[mesh]]
kind = "box"
min = [-20.0, -0.5, -20.0]
max = [20.0, 0.0, 20.0]
albedo = [0.6, 0.6, 0.6]
[[volume]]
center = [0.0, 2.5, 0.0]
radius = 2.5
scattering = [0.35, 0.35, 0.35]
absorption = 0.05
g = 0.4
displacement = { amplitude = 0.3, frequency = 2.0, octaves = 3 }
motion = { velocity = [0.4, 0.0, 0.2], period_s = 10.0 }
"#;

fn cameras(scene: &Scene) -> Vec<Camera> {
    scene
        .camera
        .path
        .iter()
        .zip(&scene.camera.look_at)
        .map(|(p, t)| {
            let (p, t) = (Vec3::from(*p), Vec3::from(*t));
            Camera::new(p, t - p, scene.camera.fov_deg.to_radians())
        })
        .collect()
}

/// `reference` and `shared` render the volume as `truth` does: mean FLIP over two
/// 320×180 viewers at most 0.05.
#[test]
fn gpu_modes_match_truth_on_a_displaced_moving_volume() {
    const SIZE: (u32, u32) = (320, 180);
    const TIME_S: f32 = 1.5;
    let scene = Arc::new(load(CLOUD));
    let bvh = Bvh::build(&scene.mesh).unwrap();
    let cams = cameras(&scene);
    let started = std::time::Instant::now();
    let (truth, _) = render_truth(
        &scene,
        &bvh,
        &cams,
        SIZE,
        TIME_S,
        TruthSettings {
            steps: 256,
            ..TruthSettings::default()
        },
        &|_, _| {},
    );
    println!("truth: {:.1} s", started.elapsed().as_secs_f64());
    for mode in [Mode::Reference, Mode::Shared] {
        let settings = Settings {
            mode,
            voxel_size_m: scene.render.voxel_size_m,
            ..Settings::default()
        };
        let mut r = Renderer::with_bvh(gpu(), scene.clone(), &bvh, settings).unwrap();
        let out = r.render(&cams, SIZE.0, SIZE.1, TIME_S).unwrap();
        if let Some(dir) = std::env::var_os("FOGCAST_VOLUME_OUT") {
            let dir = std::path::PathBuf::from(dir);
            std::fs::create_dir_all(&dir).unwrap();
            for (v, (img, t)) in out.images.iter().zip(&truth).enumerate() {
                let png = |name: String, px: &[u8]| {
                    fogcast::output::write_png(&dir.join(name), px, SIZE.0, SIZE.1).unwrap()
                };
                png(format!("{mode:?}_{v}.png"), img);
                png(format!("truth_{v}.png"), t);
            }
        }
        let flip = out
            .images
            .iter()
            .zip(&truth)
            .map(|(img, t)| compare(t, img, SIZE.0, SIZE.1).unwrap().flip_mean)
            .sum::<f64>()
            / truth.len() as f64;
        println!("cloud: {mode:?} vs truth mean FLIP {flip:.4}");
        assert!(flip <= 0.05, "{mode:?} vs truth mean FLIP {flip:.4} > 0.05");
    }
}

/// A moving volume refills `shared`'s transmittance volumes every frame and moves in the
/// image; the same volume standing still is filled once.
#[test]
fn a_moving_volume_refills_the_shared_transmittance_every_frame() {
    const SIZE: (u32, u32) = (64, 36);
    let still = CLOUD.replace(
        "motion = { velocity = [0.4, 0.0, 0.2], period_s = 10.0 }",
        "",
    );
    for (text, moving) in [(CLOUD.to_string(), true), (still, false)] {
        let scene = Arc::new(load(&text));
        let bvh = Bvh::build(&scene.mesh).unwrap();
        let cams = cameras(&scene);
        let settings = Settings {
            mode: Mode::Shared,
            voxel_size_m: scene.render.voxel_size_m,
            ..Settings::default()
        };
        let mut r = Renderer::with_bvh(gpu(), scene.clone(), &bvh, settings).unwrap();
        let frames: Vec<_> = (0..3)
            .map(|i| r.render(&cams, SIZE.0, SIZE.1, 0.5 * i as f32).unwrap())
            .collect();
        let first = frames[0].stats.transmittance_nodes;
        assert!(first > 0);
        for f in &frames[1..] {
            let refilled = f.stats.transmittance_nodes;
            assert_eq!(refilled, if moving { first } else { 0 }, "moving {moving}");
        }
        assert_eq!(
            frames[1].images != frames[2].images,
            moving,
            "moving {moving}: whether the image changes"
        );
    }
}

/// The world media layer (issue 14): `shared` reads the volume's density from bricks
/// filled once per frame instead of evaluating noise per froxel and pixel. The image
/// stays what per-sample evaluation gives; the fill is the same work for one viewer as
/// for four looking the same way; moving media refill what is seen every frame, static
/// ones only new bricks; the bricks in use take less memory than a dense grid.
#[test]
fn the_media_layer_is_filled_once_per_frame_for_every_viewer() {
    const SIZE: (u32, u32) = (160, 90);
    let scene = Arc::new(load(CLOUD));
    let bvh = Bvh::build(&scene.mesh).unwrap();
    let cams = cameras(&scene);
    let with = |media_voxel_m: f32| Settings {
        mode: Mode::Shared,
        voxel_size_m: scene.render.voxel_size_m,
        media_voxel_m,
        ..Settings::default()
    };
    let render = |settings: Settings, cams: &[Camera], times: &[f32]| {
        let mut r = Renderer::with_bvh(gpu(), scene.clone(), &bvh, settings).unwrap();
        times
            .iter()
            .map(|&t| r.render(cams, SIZE.0, SIZE.1, t).unwrap())
            .collect::<Vec<_>>()
    };
    let layer = render(with(0.25), &cams, &[1.5, 1.6]);
    let analytic = render(with(0.0), &cams, &[1.5]);
    let s = &layer[0].stats;
    assert!(s.layer_bricks_filled > 0 && s.layer_nodes_filled == s.layer_bricks_filled * 729);
    assert_eq!(
        analytic[0].stats.layer_pool_bricks, 0,
        "media_voxel_m=0: no layer"
    );
    assert!(
        s.layer_bytes_in_use < s.layer_dense_bytes,
        "bricks in use {} B vs dense {} B",
        s.layer_bytes_in_use,
        s.layer_dense_bytes
    );
    // The volume moves: the second frame refills what is seen.
    assert!(layer[1].stats.layer_bricks_filled > 0);
    for (a, b) in layer[0].images.iter().zip(&analytic[0].images) {
        let flip = compare(b, a, SIZE.0, SIZE.1).unwrap().flip_mean;
        println!("layer vs analytic: mean FLIP {flip:.4}");
        assert!(flip <= 0.02, "layer vs analytic mean FLIP {flip:.4}");
    }
    // One viewer or four with the same view: the same bricks, one mark and one fill.
    let one = render(with(0.25), &cams[..1], &[1.5]);
    let four = render(with(0.25), &[cams[0]; 4], &[1.5]);
    assert_eq!(
        one[0].stats.layer_bricks_filled,
        four[0].stats.layer_bricks_filled
    );
    for f in [&one[0], &four[0]] {
        let passes = f
            .stats
            .dispatches
            .iter()
            .filter(|(n, _)| n == "media_layer");
        assert_eq!(passes.count(), 2, "mark and fill once per frame");
    }
    // Standing still, the layer keeps its bricks: the second frame fills none.
    let still = Arc::new(load(&CLOUD.replace(
        "motion = { velocity = [0.4, 0.0, 0.2], period_s = 10.0 }",
        "",
    )));
    let bvh_still = Bvh::build(&still.mesh).unwrap();
    let mut r = Renderer::with_bvh(gpu(), still.clone(), &bvh_still, with(0.25)).unwrap();
    // The pool starts small and grows to what is seen (refilled once more then).
    let frames: Vec<_> = (0..3)
        .map(|i| {
            r.render(&cams, SIZE.0, SIZE.1, 0.1 * i as f32)
                .unwrap()
                .stats
        })
        .collect();
    assert!(frames[0].layer_bricks_filled > 0);
    let last = &frames[2];
    assert_eq!(last.layer_bricks_filled, 0, "a static layer is filled once");
    assert_eq!(last.layer_bricks_in_use, frames[1].layer_bricks_in_use);
    assert!(last.layer_bricks_in_use <= last.layer_pool_bricks);
    println!(
        "static cloud: {} bricks in use of a {}-brick pool: {} B vs {} B dense",
        last.layer_bricks_in_use,
        last.layer_pool_bricks,
        last.layer_bytes_in_use,
        last.layer_dense_bytes
    );
}

/// The volume hard cases of tests/hard_inputs.rs with the media layer on: every froxel
/// finite, the image within mean FLIP 0.05 of evaluating the media per sample, and the
/// media the layer must not smear (a 1 mm puff, σt 10⁴) left analytic.
#[test]
fn the_media_layer_survives_the_volume_hard_cases() {
    const SIZE: (u32, u32) = (64, 36);
    let base = |light: &str, voxel: f32, volume: &str| {
        format!(
            "name = \"hard\"\n[render]\nnear_m = 0.1\nfar_m = 30.0\nvoxel_size_m = {voxel:?}\n\
             [camera]\npath = [[-4.0, 1.5, 6.0], [4.0, 1.75, 6.0]]\n\
             look_at = [[0.0, 1.0, 0.0], [0.5, 1.25, -1.0]]\nfov_deg = 60.0\n{light}\n\
             [[mesh]]\nkind = \"box\"\nmin = [-10.0, -0.25, -10.0]\nmax = [10.0, 0.0, 10.0]\n\
             [[volume]]\n{volume}\n"
        )
    };
    let sun = "[[light]]\nkind = \"directional\"\ndirection = [0.3, -1.0, 0.2]\nintensity = 5.0";
    let lamp = "[[light]]\nkind = \"point\"\nposition = [0.0, 2.0, 2.0]\nintensity = 20.0";
    // (case, scene, whether the volume goes in the layer: the 10 km cloud's layer would
    // need ~50 m voxels, τ 3 across each, so it stays analytic like the dense one)
    let cases = [
        ("radius 1 mm", base(sun, 0.5, "center = [0.0, 1.0, 0.0]\nradius = 0.001\nscattering = [1000.0, 1000.0, 1000.0]\ndisplacement = { amplitude = 0.3, frequency = 2.0 }"), false),
        ("radius 10 km", base(sun, 100.0, "center = [0.0, 2.0, 0.0]\nradius = 1.0e4\nscattering = [0.05, 0.05, 0.05]\nabsorption = 0.01\ng = 0.3\ndisplacement = { amplitude = 0.3, frequency = 3.0 }"), false),
        ("density 0", base(sun, 0.5, "center = [0.0, 1.5, 0.0]\nradius = 2.0\nscattering = [0.0, 0.0, 0.0]\ndisplacement = { amplitude = 0.5 }"), true),
        ("density 1e4", base(sun, 0.5, "center = [0.0, 1.5, 0.0]\nradius = 2.0\nscattering = [10000.0, 10000.0, 10000.0]\ndisplacement = { amplitude = 0.5, frequency = 4.0, octaves = 5 }"), false),
        ("light inside", base(lamp, 0.5, "center = [0.0, 2.0, 2.0]\nradius = 1.5\nscattering = [2.0, 1.8, 1.6]\nabsorption = 0.1\ng = 0.5\ndisplacement = { amplitude = 0.4, frequency = 3.0, octaves = 3 }\nmotion = { velocity = [0.2, 0.0, 0.0], period_s = 4.0 }"), true),
        ("crossing the bounds", base(sun, 0.5, "center = [10.0, 2.0, -24.0]\nradius = 8.0\nscattering = [0.3, 0.3, 0.3]\ndisplacement = { amplitude = 0.3 }\nmotion = { velocity = [-2.0, 0.0, 0.0], period_s = 5.0 }"), true),
        ("camera inside", base(sun, 0.5, "center = [0.0, 1.5, 6.0]\nradius = 6.0\nscattering = [0.4, 0.4, 0.4]\nabsorption = 0.05\ng = 0.4\ndisplacement = { amplitude = 0.2, frequency = 2.0 }"), true),
    ];
    for (case, text, in_layer) in cases {
        let scene = Arc::new(load(&text));
        let bvh = Bvh::build(&scene.mesh).unwrap();
        let cams = cameras(&scene);
        let mut frames = Vec::new();
        for media_voxel_m in [0.25, 0.0] {
            let settings = Settings {
                mode: Mode::Shared,
                voxel_size_m: scene.render.voxel_size_m,
                media_voxel_m,
                ..Settings::default()
            };
            let mut r = Renderer::with_bvh(gpu(), scene.clone(), &bvh, settings).unwrap();
            // Two frames: the layer's pool may grow after the first.
            r.render(&cams, SIZE.0, SIZE.1, 0.4).unwrap();
            let out = r.render(&cams, SIZE.0, SIZE.1, 0.5).unwrap();
            let froxels = r.read_integrated_volume().unwrap();
            assert!(
                froxels.iter().flatten().all(|v| v.is_finite()),
                "{case}: a froxel is not finite (media_voxel_m {media_voxel_m})"
            );
            frames.push(out);
        }
        assert_eq!(
            frames[0].stats.layer_pool_bricks > 0,
            in_layer,
            "{case}: whether the volume is in the layer"
        );
        let flip = frames[0]
            .images
            .iter()
            .zip(&frames[1].images)
            .map(|(a, b)| compare(b, a, SIZE.0, SIZE.1).unwrap().flip_mean)
            .fold(0.0, f64::max);
        println!("{case}: layer vs analytic, worst mean FLIP {flip:.4}");
        assert!(
            flip <= 0.05,
            "{case}: layer vs analytic mean FLIP {flip:.4}"
        );
    }
}
