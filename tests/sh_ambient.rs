//! The shared ambient grid (issue 16, `sh_ambient_m`) against what it approximates: the
//! furnace (a non-absorbing fog under a uniform sky looks exactly like the sky: what the
//! fog takes out of the sky it scatters back in), and the multiple-scattering truth
//! (tests/truth_paths.rs checks the path tracer against closed forms) on a sunlit yard in
//! fog, where the grid must come closer than the scene's constant `ambient`.

mod gpu_support;

use fogcast::render::{Renderer, Settings};
use fogcast::scene::{Bvh, Scene};
use fogcast::truth::{render_truth, TruthSettings};
use gpu_support::gpu;
use std::path::Path;
use std::sync::Arc;

fn scene(toml: &str) -> Arc<Scene> {
    Arc::new(Scene::from_toml(toml, Path::new("inline.toml")).expect("test scene is valid"))
}

/// The first camera's image, one frame at `size`, probes every `sh_ambient_m` (0: off).
fn render(scene: &Arc<Scene>, size: (u32, u32), sh_ambient_m: f32) -> Vec<u8> {
    let settings = Settings {
        sh_ambient_m,
        ..Settings::for_scene(scene)
    };
    let mut r = Renderer::new(gpu(), scene.clone(), settings).unwrap();
    let cams = scene.camera.viewers(1, 0.0);
    let out = r.render(&cams, size.0, size.1, 0.0).unwrap();
    if sh_ambient_m > 0.0 {
        let ran: Vec<&str> = out
            .stats
            .stage_gpu_ms
            .iter()
            .map(|s| s.stage.as_str())
            .collect();
        assert!(ran.contains(&"ambient_grid"), "{ran:?}");
    }
    out.images.into_iter().next().unwrap()
}

/// Mean absolute difference of the RGB channels, in 8-bit steps.
fn mae(a: &[u8], b: &[u8]) -> f64 {
    let (sum, n) = a
        .chunks_exact(4)
        .zip(b.chunks_exact(4))
        .flat_map(|(p, q)| (0..3).map(move |c| (f64::from(p[c]) - f64::from(q[c])).abs()))
        .fold((0.0, 0), |(s, n), d| (s + d, n + 1));
    sum / f64::from(n)
}

/// A far-away speck of geometry (a scene needs a mesh), a camera at the origin, no light.
const FURNACE: &str = r#"
name = "furnace"
[render]
near_m = 0.05
far_m = 60.0
sky = [0.3, 0.45, 0.6]
ambient = [0.0, 0.0, 0.0]
[camera]
path = [[0.0, 0.0, 0.0]]
look_at = [[1.0, 0.1, 0.2]]
fov_deg = 70.0
[[mesh]]
kind = "box"
min = [-40.0, -40.0, -40.0]
max = [-39.9, -39.9, -39.9]
"#;

#[test]
fn furnace_a_non_absorbing_fog_under_the_sky_looks_like_the_sky() {
    let sky = render(&scene(FURNACE), (48, 27), 0.0);
    let fog = scene(&format!(
        r#"{FURNACE}
[[medium]]
kind = "sphere"
center = [0.0, 0.0, 0.0]
radius = 25.0
scattering = [0.15, 0.15, 0.15]
g = 0.6
"#
    ));
    let with_grid = render(&fog, (48, 27), 8.0);
    let constant = render(&fog, (48, 27), 0.0);
    let (e_grid, e_const) = (mae(&with_grid, &sky), mae(&constant, &sky));
    eprintln!(
        "furnace: grid {e_grid:.2} vs constant ambient {e_const:.2} (8-bit steps from the sky)"
    );
    // The fog is thick (τ ≈ 3.8 to the sphere's edge): with no ambient it hides the sky.
    assert!(
        e_const > 20.0,
        "the constant-ambient image should be darker: {e_const}"
    );
    assert!(
        e_grid < 1.0,
        "with the grid the fog should give back the sky: {e_grid}"
    );
}

/// A sunlit yard in fog: a ground, a wall casting a shadow toward the eye and a pillar,
/// under a blue sky.
const YARD: &str = r#"
name = "yard"
[render]
near_m = 0.05
far_m = 80.0
sky = [0.35, 0.45, 0.65]
ambient = [0.07, 0.075, 0.085]
[camera]
path = [[0.0, 1.6, -9.0]]
look_at = [[0.0, 1.2, 0.0]]
fov_deg = 70.0
[[light]]
kind = "directional"
direction = [0.35, -0.6, -0.7]
color = [1.0, 0.93, 0.8]
intensity = 6.0
[[mesh]]
kind = "box"
min = [-20.0, -0.2, -20.0]
max = [20.0, 0.0, 20.0]
albedo = [0.55, 0.5, 0.45]
[[mesh]]
kind = "box"
min = [-6.0, 0.0, 2.0]
max = [6.0, 5.0, 2.5]
albedo = [0.75, 0.6, 0.45]
[[mesh]]
kind = "box"
min = [2.0, 0.0, -3.0]
max = [3.0, 4.0, -2.0]
albedo = [0.6, 0.65, 0.7]
[[medium]]
kind = "box"
min = [-20.0, 0.0, -20.0]
max = [20.0, 10.0, 20.0]
scattering = [0.04, 0.04, 0.04]
absorption = 0.005
g = 0.5
"#;

/// Against the path-traced truth (8 bounces, 256 paths a pixel): the grid must come
/// closer than the scene's constant `ambient` does.
#[test]
fn the_grid_is_closer_to_the_multiple_scattering_truth_than_the_constant() {
    let yard = scene(YARD);
    let size = (32, 18);
    let bvh = Bvh::build(&yard.mesh).unwrap();
    let cams = yard.camera.viewers(1, 0.0);
    let truth_settings = TruthSettings {
        bounces: 8,
        spp: 256,
        seed: 1,
        ..TruthSettings::default()
    };
    let (truth, _) = render_truth(&yard, &bvh, &cams, size, 0.0, truth_settings, &|_, _| {});
    let (grid, constant) = (render(&yard, size, 2.0), render(&yard, size, 0.0));
    let (e_grid, e_const) = (mae(&grid, &truth[0]), mae(&constant, &truth[0]));
    eprintln!("yard: grid {e_grid:.2} vs constant ambient {e_const:.2} (8-bit steps from truth)");
    assert!(
        e_grid < 0.7 * e_const,
        "the grid ({e_grid:.2}) should be clearly closer to the truth than the constant ({e_const:.2})"
    );
    assert!(
        e_grid < 5.0,
        "the grid is {e_grid:.2} 8-bit steps from the truth"
    );
}

/// The grid is world work: one dispatch line per frame (trace and blend over the probes)
/// and one buffer, whatever the number of viewers; per-viewer stages grow with them.
#[test]
fn the_grid_runs_once_per_frame_for_any_number_of_viewers() {
    let yard = scene(YARD);
    let settings = Settings {
        sh_ambient_m: 2.0,
        ..Settings::for_scene(&yard)
    };
    let mut per_count = Vec::new();
    for viewers in [1, 4] {
        let mut r = Renderer::new(gpu(), yard.clone(), settings).unwrap();
        let cams = yard.camera.viewers(viewers, 0.0);
        // The first frame reports its 64 warm-up passes, each over every probe.
        let first = r.render(&cams, 24, 14, 0.0).unwrap().stats;
        let warmup: Vec<_> = first
            .dispatches
            .iter()
            .filter(|(s, _)| s == "ambient_grid")
            .collect();
        assert_eq!(warmup.len(), 64, "{warmup:?}");
        let stats = r.render(&cams, 24, 14, 0.1).unwrap().stats;
        let of = |stage: &str| -> Vec<[u32; 3]> {
            stats
                .dispatches
                .iter()
                .filter(|(s, _)| s == stage)
                .map(|(_, g)| *g)
                .collect()
        };
        let grid_bytes = stats
            .memory
            .shared
            .iter()
            .find(|(name, _)| name == "ambient_grid")
            .map(|(_, b)| *b);
        assert!(
            stats
                .memory
                .per_viewer
                .iter()
                .all(|(name, _)| name != "ambient_grid"),
            "{:?}",
            stats.memory.per_viewer
        );
        per_count.push((of("ambient_grid"), of("froxel_lighting"), grid_bytes));
    }
    eprintln!("dispatches at 1 and 4 viewers: {per_count:?}");
    let (one, four) = (&per_count[0], &per_count[1]);
    assert_eq!(one.0.len(), 1, "one ambient grid line per frame");
    assert_eq!(one.0, four.0, "the same grid work at 1 and 4 viewers");
    assert_eq!(one.2, four.2, "the same grid memory");
    assert!(one.2.is_some_and(|b| b > 0));
    let froxel_groups = |g: &[[u32; 3]]| g.iter().map(|w| w[0] * w[1] * w[2]).sum::<u32>();
    assert!(
        froxel_groups(&four.1) > froxel_groups(&one.1),
        "per-viewer work grows"
    );
}
