//! `maps` mode (issue 14, what game engines do): froxels and surfaces lit from the shared
//! shadow maps of every light kind. On `street` (four point lights, two spots, buildings
//! and lamp posts casting shadows into low fog) it matches `reference` within a FLIP
//! bound, traces no shadow ray and allocates no grid; `shared` uses the same spot and
//! cube maps for its surfaces and near-field fog, so it traces no surface or frustum ray
//! there either.

mod gpu_support;

use fogcast::metrics::compare;
use fogcast::render::{Mode, Renderer, Settings};
use fogcast::scene::{LightKind, Scene};
use gpu_support::gpu;
use std::sync::Arc;

const SIZE: (u32, u32) = (160, 90);

/// Mean FLIP of `maps` against `reference`, per viewer (measured 0.006–0.007 on these
/// cameras and frames).
const MAX_FLIP: f64 = 0.02;

fn street() -> Arc<Scene> {
    Arc::new(Scene::load("street").expect("built-in scene"))
}

fn settings(scene: &Scene, mode: Mode) -> Settings {
    Settings {
        mode,
        shadow_map_px: if mode == Mode::Reference { 0 } else { 4096 },
        ..Settings::for_scene(scene)
    }
}

#[test]
fn maps_mode_matches_reference_without_rays_or_grid() {
    let scene = street();
    for kind in [LightKind::Point, LightKind::Spot] {
        assert!(scene.lights.iter().any(|l| l.kind == kind), "{kind:?}");
    }
    let cams = scene.camera.viewers(2, 0.0);
    let (w, h) = SIZE;
    let mut reference =
        Renderer::new(gpu(), scene.clone(), settings(&scene, Mode::Reference)).unwrap();
    let mut maps = Renderer::new(gpu(), scene.clone(), settings(&scene, Mode::Maps)).unwrap();
    // Two frames: the second reads maps cached from the first (the swinging lamp's
    // cube is rendered again).
    for t in [0.0, 1.0 / 30.0] {
        let a = reference.render(&cams, w, h, t).unwrap();
        let b = maps.render(&cams, w, h, t).unwrap();
        assert!(a.stats.rays.froxel_lighting > 0 && a.stats.rays.surface > 0);
        assert_eq!(
            b.stats.rays.total, 0,
            "maps traces no ray: {:?}",
            b.stats.rays
        );
        assert!(b.stats.froxels_with_media > 0);
        for (i, (ra, rb)) in a.images.iter().zip(&b.images).enumerate() {
            let e = compare(ra, rb, w, h).unwrap();
            println!(
                "t {t:.3} viewer {i}: maps vs reference FLIP {:.4}, PSNR {:.1} dB",
                e.flip_mean, e.psnr_db
            );
            assert!(e.flip_mean <= MAX_FLIP, "viewer {i}: FLIP {}", e.flip_mean);
            assert!(e.flip_mean > 0.0);
        }
        // No grid: none allocated, none in the memory report, no grid or frustum pass.
        assert!(maps.shared_grid().is_none());
        assert_eq!(b.stats.grid_dims, [0, 0, 0]);
        let names: Vec<&str> = b
            .stats
            .memory
            .shared
            .iter()
            .map(|(n, _)| n.as_str())
            .collect();
        assert!(!names.contains(&"shared_grid"), "{names:?}");
        assert!(names.contains(&"shadow_maps"), "{names:?}");
        for (stage, _) in &b.stats.dispatches {
            assert!(
                !["grid_requests", "shared_grid", "shadow_frustum"].contains(&stage.as_str()),
                "maps ran {stage}"
            );
        }
    }
}

#[test]
fn shared_reads_spot_and_cube_maps_for_surfaces_and_the_near_field() {
    let scene = street();
    let cams = scene.camera.viewers(2, 0.0);
    let (w, h) = SIZE;
    let mut shared = Renderer::new(gpu(), scene.clone(), settings(&scene, Mode::Shared)).unwrap();
    let out = shared.render(&cams, w, h, 0.0).unwrap();
    let r = out.stats.rays;
    assert_eq!((r.surface, r.shadow_frustum), (0, 0), "{r:?}");
    assert!(
        r.shared_grid > 0,
        "the grid still traces beyond the frustum"
    );
}

#[test]
fn maps_mode_needs_shadow_maps() {
    let scene = street();
    let s = Settings {
        shadow_map_px: 0,
        ..settings(&scene, Mode::Maps)
    };
    let e = Renderer::new(gpu(), scene, s).err().expect("rejected");
    assert!(e.to_string().contains("shadow_map_px=0"), "{e}");
}

/// `shared` with `froxel_maps` on street (every light has a map): its froxels read the
/// maps as `maps` does, so it allocates no grid, runs no grid or frustum pass and traces
/// no ray, culls the hidden froxels `maps` lights, and shows the same picture (the
/// hidden froxels never reach the image).
#[test]
fn froxel_maps_light_shared_froxels_without_a_grid() {
    let scene = street();
    let cams = scene.camera.viewers(2, 0.0);
    let (w, h) = SIZE;
    let mut maps = Renderer::new(gpu(), scene.clone(), settings(&scene, Mode::Maps)).unwrap();
    let hybrid = Settings {
        froxel_maps: true,
        ..settings(&scene, Mode::Shared)
    };
    let mut shared = Renderer::new(gpu(), scene.clone(), hybrid).unwrap();
    for t in [0.0, 1.0 / 30.0] {
        let a = maps.render(&cams, w, h, t).unwrap();
        let b = shared.render(&cams, w, h, t).unwrap();
        assert_eq!(b.stats.rays.total, 0, "{:?}", b.stats.rays);
        assert!(shared.shared_grid().is_none());
        assert_eq!(b.stats.grid_dims, [0, 0, 0]);
        let stages: Vec<&str> = b.stats.dispatches.iter().map(|(s, _)| s.as_str()).collect();
        assert!(
            stages.contains(&"grid_requests"),
            "the culling runs: {stages:?}"
        );
        for stage in ["shared_grid", "shadow_frustum"] {
            assert!(!stages.contains(&stage), "{stage} ran: {stages:?}");
        }
        assert!(
            b.stats.froxels_with_media < a.stats.froxels_with_media,
            "hidden froxels culled: {} vs maps' {}",
            b.stats.froxels_with_media,
            a.stats.froxels_with_media
        );
        for (i, (ra, rb)) in a.images.iter().zip(&b.images).enumerate() {
            let e = compare(ra, rb, w, h).unwrap();
            println!(
                "t {t:.3} viewer {i}: froxel_maps vs maps FLIP {:.5}",
                e.flip_mean
            );
            assert!(e.flip_mean <= 0.002, "viewer {i}: FLIP {}", e.flip_mean);
        }
    }
}
