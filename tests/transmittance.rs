//! Light dimmed by the media it crosses (issue 11), on the GPU: `reference` marches every
//! froxel's and pixel's shadow ray through the media, `shared` reads one volume of optical
//! depth per light filled once per frame for every viewer. Both against `truth` on scenes
//! whose single scattering is known in closed form (tests/truth_closed_form.rs checks
//! `truth` itself against it), the shared volume against marching on the built-in scenes,
//! and the stage's cost: once per frame, nothing in a static scene after the first frame,
//! and no opaque shadow ray when wind moves the media.

mod gpu_support;

use fogcast::metrics::compare;
use fogcast::render::{FrameOutput, Mode, Renderer, Settings};
use fogcast::scene::{Bvh, Camera, Scene};
use fogcast::truth::{render_truth, TruthSettings};
use glam::Vec3;
use gpu_support::gpu;
use std::path::Path;
use std::sync::Arc;

fn load(text: &str) -> Scene {
    Scene::from_toml(text, Path::new("inline.toml"))
        .unwrap_or_else(|e| panic!("scene does not load: {e}\n{text}"))
}

fn settings(mode: Mode, scene: &Scene) -> Settings {
    Settings {
        mode,
        voxel_size_m: scene.render.voxel_size_m,
        ..Settings::default()
    }
}

/// `frames` frames of `cameras` at `w × h`, scene time 0.5 s + 0.1 s per frame.
fn render(
    scene: &Arc<Scene>,
    bvh: &Bvh,
    s: Settings,
    cameras: &[Camera],
    (w, h): (u32, u32),
    frames: usize,
) -> Vec<FrameOutput> {
    let mut r = Renderer::with_bvh(gpu(), scene.clone(), bvh, s).expect("renderer");
    (0..frames)
        .map(|i| {
            r.render(cameras, w, h, 0.5 + 0.1 * i as f32)
                .expect("frame renders")
        })
        .collect()
}

fn mean_flip(a: &[Vec<u8>], b: &[Vec<u8>], (w, h): (u32, u32)) -> f64 {
    let sum: f64 = a
        .iter()
        .zip(b)
        .map(|(x, y)| compare(x, y, w, h).unwrap().flip_mean)
        .sum();
    sum / a.len() as f64
}

/// Flat ground under a 6 m slab of homogeneous fog lit by a low sun: the closed-form
/// case of tests/truth_closed_form.rs, seen by two viewers inside the slab.
const SLAB: &str = r#"
name = "slab"
[render]
near_m = 0.1
far_m = 60.0
voxel_size_m = 0.5
sky = [0.0, 0.0, 0.0]
ambient = [0.0, 0.0, 0.0]
[camera]
path = [[-6.0, 1.5, 4.0], [5.0, 2.0, -3.0]]
look_at = [[4.0, 0.0, -6.0], [-8.0, 1.0, 6.0]]
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
[[medium]]
kind = "box"
min = [-20.0, 0.0, -20.0]
max = [20.0, 6.0, 20.0]
scattering = [0.05, 0.05, 0.05]
absorption = 0.01
g = 0.5
"#;

/// A lamp in denser fog over the same ground, seen from outside the fog's core.
const LAMP: &str = r#"
name = "lamp"
[render]
near_m = 0.1
far_m = 40.0
voxel_size_m = 0.5
sky = [0.0, 0.0, 0.0]
ambient = [0.0, 0.0, 0.0]
[camera]
path = [[-7.0, 1.6, 5.0], [6.0, 2.5, 6.0]]
look_at = [[0.0, 1.5, 0.0], [-1.0, 0.5, -2.0]]
fov_deg = 60.0
[[light]]
kind = "point"
position = [0.0, 2.0, 0.0]
intensity = 40.0
[[mesh]]
kind = "box"
min = [-20.0, -0.5, -20.0]
max = [20.0, 0.0, 20.0]
albedo = [0.6, 0.6, 0.6]
[[medium]]
kind = "box"
min = [-10.0, 0.0, -10.0]
max = [10.0, 6.0, 10.0]
scattering = [0.3, 0.3, 0.3]
absorption = 0.1
g = 0.3
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

/// Mean FLIP of `reference` and `shared` against `truth` on `text`'s two viewers.
fn flips_vs_truth(text: &str) -> [f64; 2] {
    // 8 px froxels: at 160×90 the froxels' bilinear steps alone cost ~0.03 of FLIP on
    // these smooth gradients (0.017 with 4 px froxels); at 320×180 they are half as wide.
    const SIZE: (u32, u32) = (320, 180);
    let scene = Arc::new(load(text));
    let bvh = Bvh::build(&scene.mesh).unwrap();
    let cams = cameras(&scene);
    let (truth, _) = render_truth(
        &scene,
        &bvh,
        &cams,
        SIZE,
        0.5,
        TruthSettings {
            steps: 256,
            ..TruthSettings::default()
        },
        &|_, _| {},
    );
    [Mode::Reference, Mode::Shared].map(|mode| {
        let out = render(&scene, &bvh, settings(mode, &scene), &cams, SIZE, 1);
        let f = mean_flip(&truth, &out[0].images, SIZE);
        println!("{}: {mode:?} vs truth mean FLIP {f:.4}", scene.name);
        f
    })
}

#[test]
fn homogeneous_slab_under_a_sun_matches_truth() {
    let [reference, shared] = flips_vs_truth(SLAB);
    assert!(
        reference <= 0.02,
        "reference vs truth {reference:.4} > 0.02"
    );
    assert!(shared <= 0.02, "shared vs truth {shared:.4} > 0.02");
}

#[test]
fn lamp_in_dense_fog_matches_truth() {
    let [reference, shared] = flips_vs_truth(LAMP);
    assert!(
        reference <= 0.02,
        "reference vs truth {reference:.4} > 0.02"
    );
    assert!(shared <= 0.02, "shared vs truth {shared:.4} > 0.02");
}

/// The shared volumes against marching every sample's shadow ray (`transmittance_voxel_m
/// = 0`), all else equal, on a built-in scene.
fn volume_vs_march(name: &str, bound: f64) {
    const SIZE: (u32, u32) = (160, 90);
    let scene = Arc::new(Scene::load(name).unwrap());
    let bvh = Bvh::build(&scene.mesh).unwrap();
    let cams = scene.camera.viewers(2, 1.0);
    let volume = render(&scene, &bvh, settings(Mode::Shared, &scene), &cams, SIZE, 1);
    let marched = Settings {
        transmittance_voxel_m: 0.0,
        ..settings(Mode::Shared, &scene)
    };
    let march = render(&scene, &bvh, marched, &cams, SIZE, 1);
    assert!(volume[0].stats.transmittance_nodes > 0);
    assert_eq!(march[0].stats.transmittance_nodes, 0);
    let f = mean_flip(&march[0].images, &volume[0].images, SIZE);
    println!("{name}: shared volume vs marched mean FLIP {f:.4}");
    assert!(f <= bound, "{name}: volume vs march {f:.4} > {bound}");
}

#[test]
fn shared_volume_matches_marching_under_a_sun() {
    volume_vs_march("colonnade", 0.01);
}

#[test]
fn shared_volume_matches_marching_for_point_and_spot_lights() {
    volume_vs_march("street", 0.01);
}

#[test]
fn a_lamp_10_km_away_is_dimmed_like_a_marched_ray() {
    // The lamp sits 10 km from the fog: its volume maps only the cone around the media,
    // and the 10 km shadow ray is integrated only where the fog is.
    let text = LAMP.replace(
        "position = [0.0, 2.0, 0.0]",
        "position = [0.0, 6000.0, 8000.0]",
    );
    let text = text.replace("intensity = 40.0", "intensity = 9.0e8");
    let scene = Arc::new(load(&text));
    let bvh = Bvh::build(&scene.mesh).unwrap();
    let cams = cameras(&scene);
    let size = (96, 54);
    let volume = render(&scene, &bvh, settings(Mode::Shared, &scene), &cams, size, 1);
    let marched = Settings {
        transmittance_voxel_m: 0.0,
        ..settings(Mode::Shared, &scene)
    };
    let march = render(&scene, &bvh, marched, &cams, size, 1);
    let f = mean_flip(&march[0].images, &volume[0].images, size);
    println!("lamp 10 km away: shared volume vs marched mean FLIP {f:.4}");
    assert!(f <= 0.01, "lamp 10 km away: volume vs march {f:.4}");
}

#[test]
fn the_stage_runs_once_per_frame_whatever_the_viewer_count() {
    let scene = Arc::new(Scene::load("street").unwrap());
    let bvh = Bvh::build(&scene.mesh).unwrap();
    let s = settings(Mode::Shared, &scene);
    let nodes: Vec<u64> = [1, 4]
        .map(|n| {
            let out = render(&scene, &bvh, s, &scene.camera.viewers(n, 0.0), (64, 36), 1);
            let runs = out[0]
                .stats
                .dispatches
                .iter()
                .filter(|(name, _)| name == "media_transmittance")
                .count();
            assert_eq!(runs, 1, "{n} viewers: the stage ran {runs} times");
            out[0].stats.transmittance_nodes
        })
        .into();
    assert!(nodes[0] > 0);
    assert_eq!(nodes[0], nodes[1], "nodes filled for 1 and 4 viewers");
}

#[test]
fn static_media_are_filled_once() {
    let scene = Arc::new(Scene::load("colonnade").unwrap());
    assert!(scene
        .media
        .iter()
        .all(|m| Vec3::from(m.noise.wind) == Vec3::ZERO));
    let bvh = Bvh::build(&scene.mesh).unwrap();
    let s = settings(Mode::Shared, &scene);
    let cams = scene.camera.viewers(2, 0.0);
    let out = render(&scene, &bvh, s, &cams, (64, 36), 4);
    assert!(out[0].stats.transmittance_nodes > 0);
    for (i, f) in out.iter().enumerate().skip(1) {
        assert_eq!(f.stats.transmittance_nodes, 0, "frame {i}");
        assert!(
            f.stats
                .dispatches
                .iter()
                .all(|(n, _)| n != "media_transmittance"),
            "frame {i}: the stage ran"
        );
    }
}

#[test]
fn wind_refills_the_volume_without_opaque_shadow_rays() {
    // colonnade with its dusty air blown by wind; the viewers stand still, so after the
    // first frame the cached grid and the shared shadow maps need no ray at all.
    let mut scene = Scene::load("colonnade").unwrap();
    scene.media[0].noise.wind = [0.8, 0.0, 0.3];
    scene.movers.clear();
    let scene = Arc::new(scene);
    let bvh = Bvh::build(&scene.mesh).unwrap();
    let s = settings(Mode::Shared, &scene);
    let cams = scene.camera.viewers(2, 0.0);
    let out = render(&scene, &bvh, s, &cams, (64, 36), 3);
    let first = out[0].stats.transmittance_nodes;
    assert!(first > 0);
    for (i, f) in out.iter().enumerate().skip(1) {
        assert_eq!(f.stats.transmittance_nodes, first, "frame {i}: refilled");
        assert_eq!(
            f.stats.rays.total, 0,
            "frame {i}: opaque rays {:?}",
            f.stats.rays
        );
    }
    assert_ne!(out[1].images, out[2].images, "the wind moves the fog");
}
