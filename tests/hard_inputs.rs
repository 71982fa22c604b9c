//! Extreme but valid scenes render sensibly in both modes: no NaN or inf anywhere in the
//! integrated froxel volume (the RGBA8 clamp would hide them), transmittance in [0, 1],
//! and a frame that is not black. Each scene is TOML text, as a user would write it.

use fogcast::gpu::GpuContext;
use fogcast::render::{FrameOutput, Mode, Renderer, Settings};
use fogcast::scene::{Camera, LightDesc, MediumDesc, MeshDesc, Scene, SceneDesc};
use glam::Vec3;
use std::path::Path;
use std::sync::{Arc, OnceLock};

const WIDTH: u32 = 64;
const HEIGHT: u32 = 36;
const VIEWERS: usize = 2;
/// Mean sRGB luminance a frame must exceed: the scenes have a bright sky and ambient
/// light, so anything darker means pixels went black.
const MIN_MEAN_LUMA: f64 = 2.0 / 255.0;

fn gpu() -> Arc<GpuContext> {
    static CTX: OnceLock<Arc<GpuContext>> = OnceLock::new();
    CTX.get_or_init(|| Arc::new(GpuContext::new().expect("a Vulkan adapter (lavapipe on CI)")))
        .clone()
}

/// Floor, a back wall, a pillar and a roof slab that casts a shadow into the fog; two
/// viewers at either end of the camera path. Coordinates are multiples of 1/4 m so that
/// the scene moved by 10⁵ m is exactly representable in f32.
const GEOMETRY: &str = r#"
[render]
near_m = 0.1
far_m = 30.0
voxel_size_m = 0.5
sky = [0.5, 0.6, 0.8]
ambient = [0.1, 0.1, 0.12]

[[mesh]]
kind = "box"
min = [-10.0, -0.25, -10.0]
max = [10.0, 0.0, 10.0]
albedo = [0.5, 0.5, 0.5]
[[mesh]]
kind = "box"
min = [-6.0, 0.0, -6.0]
max = [6.0, 5.0, -5.5]
[[mesh]]
kind = "cylinder"
base = [2.0, 0.0, 0.0]
radius = 0.5
height = 4.0
[[mesh]]
kind = "box"
min = [-3.0, 4.0, -3.0]
max = [3.0, 4.25, 1.0]
"#;

const CAMERA_LOOKING_IN: &str = r#"
[camera]
path = [[-4.0, 1.5, 6.0], [4.0, 1.75, 6.0]]
look_at = [[0.0, 1.0, 0.0], [0.5, 1.25, -1.0]]
fov_deg = 60.0
"#;

const SUN: &str = r#"
[[light]]
kind = "directional"
direction = [0.3, -1.0, 0.2]
intensity = 5.0
"#;

/// Moderate dusty air around everything, the camera included.
const FOG: &str = r#"
[[medium]]
kind = "box"
min = [-8.0, 0.0, -8.0]
max = [8.0, 6.0, 8.0]
scattering = [0.1, 0.1, 0.1]
absorption = 0.01
g = 0.3
noise = { frequency = 0.5, octaves = 3, amplitude = 0.5 }
"#;

fn scene_text(parts: &[&str]) -> String {
    let mut text = String::from("name = \"hard\"\n");
    for p in parts {
        text.push_str(p);
    }
    text
}

fn load(text: &str) -> Scene {
    Scene::from_toml(text, Path::new("inline.toml"))
        .unwrap_or_else(|e| panic!("scene does not load: {e}\n{text}"))
}

/// One mode's frame and its integrated volume.
struct Rendered {
    mode: Mode,
    frame: FrameOutput,
    integrated: Vec<[f32; 4]>,
}

/// Renders `scene` in both modes and checks what must hold for any scene; returns the
/// frames for case-specific checks.
fn render_both(case: &str, scene: &Scene) -> Vec<Rendered> {
    let scene = Arc::new(scene.clone());
    let cameras = cameras(&scene);
    [Mode::Reference, Mode::Shared]
        .into_iter()
        .map(|mode| {
            let settings = Settings {
                mode,
                voxel_size_m: scene.render.voxel_size_m,
                ..Settings::default()
            };
            let mut renderer = Renderer::new(gpu(), scene.clone(), settings).expect("renderer");
            let frame = renderer
                .render(&cameras, WIDTH, HEIGHT, 0.5)
                .expect("frame renders");
            let integrated = renderer
                .read_integrated_volume()
                .expect("integrated volume reads back");
            check_frame(case, mode, &scene, &frame, &integrated);
            Rendered {
                mode,
                frame,
                integrated,
            }
        })
        .collect()
}

/// One viewer at each point of the camera path, looking at its `look_at` point (placed
/// explicitly, so that the cases do not depend on how viewers walk along paths).
fn cameras(scene: &Scene) -> Vec<Camera> {
    let path = &scene.camera.path;
    assert_eq!(
        (path.len(), scene.camera.look_at.len()),
        (VIEWERS, VIEWERS),
        "one path and look_at point per viewer"
    );
    path.iter()
        .zip(&scene.camera.look_at)
        .map(|(p, target)| {
            let (p, target) = (Vec3::from(*p), Vec3::from(*target));
            Camera::new(p, target - p, scene.camera.fov_deg.to_radians())
        })
        .collect()
}

fn check_frame(
    case: &str,
    mode: Mode,
    scene: &Scene,
    frame: &FrameOutput,
    integrated: &[[f32; 4]],
) {
    let what = format!("{case} ({mode:?})");
    assert_eq!(frame.images.len(), VIEWERS, "{what}: one image per viewer");
    for (v, img) in frame.images.iter().enumerate() {
        assert_eq!(
            img.len(),
            (WIDTH * HEIGHT * 4) as usize,
            "{what}, viewer {v}: image size"
        );
        let mut luma = 0.0;
        for (i, px) in img.chunks_exact(4).enumerate() {
            assert_eq!(px[3], 255, "{what}, viewer {v}: pixel {i} alpha {}", px[3]);
            // Every scene has sky and ambient light; exact black is what NaN turns into.
            assert!(
                px[..3] != [0, 0, 0],
                "{what}, viewer {v}: pixel ({}, {}) is black",
                i as u32 % WIDTH,
                i as u32 / WIDTH
            );
            luma += (0.2126 * px[0] as f64 + 0.7152 * px[1] as f64 + 0.0722 * px[2] as f64) / 255.0;
        }
        let mean = luma / (WIDTH * HEIGHT) as f64;
        println!("{what}, viewer {v}: mean luma {mean:.3}");
        assert!(
            mean > MIN_MEAN_LUMA,
            "{what}, viewer {v}: mean luma {mean:.4} ≤ {MIN_MEAN_LUMA:.4}: the frame is black"
        );
    }
    if scene.media.is_empty() {
        return;
    }
    let froxels = (WIDTH.div_ceil(8) * HEIGHT.div_ceil(8) * 128) as usize * VIEWERS;
    assert_eq!(integrated.len(), froxels, "{what}: integrated volume size");
    for (i, [r, g, b, t]) in integrated.iter().copied().enumerate() {
        assert!(
            [r, g, b, t].iter().all(|x| x.is_finite()) && r >= 0.0 && g >= 0.0 && b >= 0.0,
            "{what}: integrated froxel {i} is {:?}",
            [r, g, b, t]
        );
        assert!(
            (0.0..=1.0).contains(&t),
            "{what}: integrated froxel {i} has transmittance {t}"
        );
    }
}

fn min_transmittance(r: &Rendered) -> f32 {
    r.integrated.iter().map(|f| f[3]).fold(1.0, f32::min)
}

fn max_scattered(r: &Rendered) -> f32 {
    r.integrated
        .iter()
        .map(|f| f[0].max(f[1]).max(f[2]))
        .fold(0.0, f32::max)
}

#[test]
fn zero_extinction_is_clear_air() {
    let medium = r#"
[[medium]]
kind = "box"
min = [-8.0, 0.0, -8.0]
max = [8.0, 6.0, 8.0]
scattering = [0.0, 0.0, 0.0]
absorption = 0.0
"#;
    let scene = load(&scene_text(&[GEOMETRY, CAMERA_LOOKING_IN, SUN, medium]));
    for r in render_both("extinction 0", &scene) {
        // σt = 0 takes the S·d limit with S = 0: nothing scattered, nothing absorbed.
        assert!(
            r.integrated.iter().all(|f| *f == [0.0, 0.0, 0.0, 1.0]),
            "{:?}: clear air is not transparent",
            r.mode
        );
    }
}

#[test]
fn extinction_1e4_is_opaque_and_finite() {
    // A dense block of fog in front of the viewers (σt = 10⁴ m⁻¹: a 1 mm mean free path).
    let medium = r#"
[[medium]]
kind = "box"
min = [-2.0, 0.0, -2.0]
max = [2.0, 3.0, 2.0]
scattering = [10000.0, 10000.0, 10000.0]
absorption = 0.0
"#;
    let scene = load(&scene_text(&[GEOMETRY, CAMERA_LOOKING_IN, SUN, medium]));
    for r in render_both("extinction 1e4", &scene) {
        let t = min_transmittance(&r);
        assert!(t < 1e-3, "{:?}: the dense block lets {t} through", r.mode);
    }
}

#[test]
fn camera_inside_dense_fog() {
    let medium = r#"
[[medium]]
kind = "box"
min = [-6.0, 0.0, 4.0]
max = [6.0, 3.0, 8.0]
scattering = [10000.0, 10000.0, 10000.0]
absorption = 0.0
g = 0.5
"#;
    let scene = load(&scene_text(&[GEOMETRY, CAMERA_LOOKING_IN, SUN, medium]));
    for r in render_both("camera inside σt = 1e4 fog", &scene) {
        // Opaque from the first slice on: every column ends at zero transmittance.
        let t = min_transmittance(&r);
        assert!(
            t < 1e-3,
            "{:?}: transmittance {t} inside an opaque medium",
            r.mode
        );
    }
}

#[test]
fn camera_inside_fog_volume() {
    let medium = r#"
[[medium]]
kind = "box"
min = [-6.0, 0.0, 3.0]
max = [6.0, 4.0, 8.0]
scattering = [0.5, 0.45, 0.4]
absorption = 0.05
g = 0.6
noise = { frequency = 0.8, octaves = 4, amplitude = 1.0, wind = [0.5, 0.0, 0.25] }
"#;
    let scene = load(&scene_text(&[
        GEOMETRY,
        CAMERA_LOOKING_IN,
        SUN,
        FOG,
        medium,
    ]));
    for r in render_both("camera inside fog", &scene) {
        assert!(
            min_transmittance(&r) < 0.5,
            "{:?}: no visible fog around the camera",
            r.mode
        );
        assert!(
            max_scattered(&r) > 0.01,
            "{:?}: the fog scatters no light",
            r.mode
        );
    }
}

/// The camera looks straight along the light's path into it, where HG peaks for g → 1.
fn hg_case(case: &str, g: f32, light: &str, look_at: &str) {
    let medium = format!(
        r#"
[[medium]]
kind = "box"
min = [-8.0, 0.0, -8.0]
max = [8.0, 6.0, 8.0]
scattering = [0.3, 0.3, 0.3]
absorption = 0.01
g = {g}
"#
    );
    let camera = format!(
        r#"
[camera]
path = [[-4.0, 1.5, 6.0], [4.0, 1.75, 6.0]]
look_at = {look_at}
fov_deg = 60.0
"#
    );
    let scene = load(&scene_text(&[GEOMETRY, &camera, light, &medium]));
    for r in render_both(case, &scene) {
        assert!(
            max_scattered(&r) > 0.01,
            "{case} ({:?}): the fog scatters no light",
            r.mode
        );
    }
}

// look_at − path = −10 × direction: each viewer looks exactly against the light's travel.
const SUN_LOOK_AT: &str = "[[-7.0, 11.5, 4.0], [1.0, 11.75, 4.0]]";
const POINT_LIGHT: &str = r#"
[[light]]
kind = "point"
position = [0.0, 2.0, 2.0]
intensity = 20.0
"#;
const POINT_LOOK_AT: &str = "[[0.0, 2.0, 2.0], [0.0, 2.0, 2.0]]";

#[test]
fn hg_forward_099_into_the_sun() {
    hg_case("g = +0.99, looking into the sun", 0.99, SUN, SUN_LOOK_AT);
}

#[test]
fn hg_backward_099_into_the_sun() {
    hg_case("g = -0.99, looking into the sun", -0.99, SUN, SUN_LOOK_AT);
}

#[test]
fn hg_forward_099_into_a_point_light() {
    hg_case(
        "g = +0.99, looking into a point light",
        0.99,
        POINT_LIGHT,
        POINT_LOOK_AT,
    );
}

#[test]
fn hg_backward_099_into_a_point_light() {
    hg_case(
        "g = -0.99, looking into a point light",
        -0.99,
        POINT_LIGHT,
        POINT_LOOK_AT,
    );
}

#[test]
fn sun_overhead_camera_looking_straight_up() {
    // forward ∥ world up: the camera basis must switch its up vector, not go NaN.
    let sun = r#"
[[light]]
kind = "directional"
direction = [0.0, -1.0, 0.0]
intensity = 5.0
"#;
    let camera = r#"
[camera]
path = [[-4.0, 1.5, 6.0], [4.0, 1.75, 6.0]]
look_at = [[-4.0, 11.5, 6.0], [4.0, 11.75, 6.0]]
fov_deg = 60.0
"#;
    let scene = load(&scene_text(&[GEOMETRY, camera, sun, FOG]));
    render_both("sun overhead, looking straight up", &scene);
}

/// Moves every position in the scene by `offset` metres (directions stay).
fn translated(text: &str, offset: f32) -> String {
    let mut desc: SceneDesc = toml::from_str(text).expect("scene text parses");
    let shift = |p: &mut [f32; 3]| p.iter_mut().for_each(|x| *x += offset);
    for m in &mut desc.meshes {
        match m {
            MeshDesc::Gltf { translate, .. } => shift(translate),
            MeshDesc::Box { min, max, .. } => {
                shift(min);
                shift(max);
            }
            MeshDesc::Cylinder { base, .. } => shift(base),
        }
    }
    for l in &mut desc.lights {
        match l {
            LightDesc::Directional { .. } => {}
            LightDesc::Point { position, .. } | LightDesc::Spot { position, .. } => shift(position),
        }
    }
    for m in &mut desc.media {
        let MediumDesc {
            min,
            max,
            center,
            base_y_m,
            ..
        } = m;
        for p in [min, max, center].into_iter().flatten() {
            shift(p);
        }
        if let Some(y) = base_y_m {
            *y += offset;
        }
    }
    desc.camera.path.iter_mut().for_each(shift);
    desc.camera.look_at.iter_mut().for_each(shift);
    toml::to_string(&desc).expect("scene serialises")
}

#[test]
fn scene_far_from_the_origin_renders_as_at_the_origin() {
    let text = scene_text(&[GEOMETRY, CAMERA_LOOKING_IN, SUN, POINT_LIGHT, FOG]);
    let near = load(&text);
    let far_text = translated(&text, 1e5);
    let far = load(&far_text);
    assert!(
        far.origin.min_element() > 0.99e5,
        "render-space origin {:?}: the scene did not move",
        far.origin
    );
    let near_frames = render_both("at the origin", &near);
    let far_frames = render_both("moved 1e5 m", &far);
    // Render space is the scene minus the rounded centre of its bounds, so the same scene
    // anywhere renders the same (coordinates are exact in f32 at 1e5 m).
    for (a, b) in near_frames.iter().zip(&far_frames) {
        for (v, (ia, ib)) in a.frame.images.iter().zip(&b.frame.images).enumerate() {
            let max_diff = ia
                .iter()
                .zip(ib)
                .map(|(x, y)| x.abs_diff(*y))
                .max()
                .unwrap_or(0);
            assert!(
                max_diff <= 2,
                "{:?}, viewer {v}: moving the scene by 1e5 m changes a pixel by {max_diff}/255",
                a.mode
            );
        }
    }
}

#[test]
fn no_lights() {
    let scene = load(&scene_text(&[GEOMETRY, CAMERA_LOOKING_IN, FOG]));
    assert!(scene.lights.is_empty());
    for r in render_both("no lights", &scene) {
        assert_eq!(
            r.frame.stats.rays.total, 0,
            "{:?}: shadow rays traced without lights",
            r.mode
        );
        assert!(
            max_scattered(&r) > 1e-3,
            "{:?}: ambient light is not scattered",
            r.mode
        );
    }
}

/// `n` lights of every kind spread over the scene.
fn many_lights(n: usize) -> String {
    (0..n)
        .map(|i| {
            let x = -6.0 + 1.5 * i as f32;
            match i % 3 {
                0 => format!("[[light]]\nkind = \"directional\"\ndirection = [{}, -1.0, 0.25]\nintensity = {}\n", 0.1 * i as f32, 1.0 + i as f32 * 0.25),
                1 => format!("[[light]]\nkind = \"point\"\nposition = [{x}, 2.5, 1.0]\ncolor = [1.0, 0.8, 0.6]\nintensity = {}\n", 5.0 + i as f32),
                _ => format!(
                    "[[light]]\nkind = \"spot\"\nposition = [{x}, 3.5, 3.0]\ndirection = [0.0, -1.0, -0.5]\nintensity = 30.0\ninner_deg = 15.0\nouter_deg = 30.0\n"
                ),
            }
        })
        .collect()
}

#[test]
fn eight_lights() {
    let scene = load(&scene_text(&[
        GEOMETRY,
        CAMERA_LOOKING_IN,
        FOG,
        &many_lights(8),
    ]));
    assert_eq!((scene.lights.len(), scene.dropped_lights), (8, 0));
    for r in render_both("8 lights", &scene) {
        assert!(
            r.frame.stats.rays.total > 0,
            "{:?}: no shadow rays with 8 lights",
            r.mode
        );
    }
}

#[test]
fn ten_lights_keep_the_strongest_eight() {
    let scene = load(&scene_text(&[
        GEOMETRY,
        CAMERA_LOOKING_IN,
        FOG,
        &many_lights(10),
    ]));
    assert_eq!(scene.dropped_lights, 2, "10 lights: 2 must be dropped");
    assert_eq!(scene.lights.len(), 8);
    for r in render_both("10 lights", &scene) {
        assert_eq!(r.frame.stats.lights, 8, "{:?}", r.mode);
    }
}
