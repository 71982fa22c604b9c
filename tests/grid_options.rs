//! fogcast's grid options beyond paper 000 (issue "trace only the voxels that are
//! sampled, and re-trace only what changed"): the demand-driven update traces exactly the
//! voxels the froxels read, and temporal caching re-traces only lights that moved.

mod gpu_support;

use fogcast::render::{FrameOutput, Mode, Renderer, Settings};
use fogcast::scene::{Camera, Scene};
use gpu_support::gpu;
use std::sync::Arc;

fn settings(demand: bool, cache: bool) -> Settings {
    Settings {
        mode: Mode::Shared,
        voxel_size_m: 0.25,
        trilinear: true,
        demand,
        cache,
        // Surface shadows by rays unless a test asks for the map.
        shadow_map_px: 0,
        ..Settings::default()
    }
}

/// The 8-bit light mask of every voxel traced this frame, by voxel index.
fn traced_masks(r: &Renderer) -> Vec<(usize, u8)> {
    let (words, touched) = r.read_shared_grid().unwrap().expect("a shared grid");
    let mut out = Vec::new();
    for (w, word) in words.iter().enumerate() {
        let nibble = (touched[w / 8] >> (4 * (w % 8))) & 0xf;
        for i in 0..4 {
            if nibble & (1 << i) != 0 {
                out.push((w * 4 + i, (word >> (8 * i)) as u8));
            }
        }
    }
    out
}

fn render(r: &mut Renderer, cams: &[Camera], t: f32) -> FrameOutput {
    r.render(cams, 128, 72, t).unwrap()
}

#[test]
fn demand_driven_update_traces_fewer_voxels_with_identical_bits_and_image() {
    demand_matches_gated(true);
}

/// Nearest-voxel lookups request one voxel each (trilinear ones the lowest of their 8,
/// shaders/grid_requests.wgsl): both give the frustum-gated picture.
#[test]
fn demand_driven_nearest_lookups_give_the_frustum_gated_image() {
    demand_matches_gated(false);
}

fn demand_matches_gated(trilinear: bool) {
    let scene = Arc::new(Scene::load("colonnade").unwrap());
    let cams = scene.camera.viewers(3, 1.0);
    let with = |demand| Settings {
        trilinear,
        ..settings(demand, false)
    };
    let mut gated = Renderer::new(gpu(), scene.clone(), with(false)).unwrap();
    let mut demand = Renderer::new(gpu(), scene.clone(), with(true)).unwrap();
    let a = render(&mut gated, &cams, 1.0);
    let b = render(&mut demand, &cams, 1.0);
    let gated_bits: std::collections::HashMap<usize, u8> =
        traced_masks(&gated).into_iter().collect();
    let demand_bits = traced_masks(&demand);
    println!(
        "trilinear {trilinear}: frustum-gated: {} voxels, {} grid rays; demand-driven: {} voxels, {} grid rays",
        a.stats.voxels_traced,
        a.stats.rays.shared_grid,
        b.stats.voxels_traced,
        b.stats.rays.shared_grid
    );
    assert!(demand_bits.len() > 1000, "too few voxels to compare");
    for (v, mask) in &demand_bits {
        // Every requested voxel lies in some frustum, and traces the same bits there.
        assert_eq!(gated_bits.get(v), Some(mask), "voxel {v}");
    }
    assert!(
        (b.stats.rays.shared_grid as f64) < 0.8 * a.stats.rays.shared_grid as f64,
        "demand-driven traced {} grid rays, frustum-gated {}",
        b.stats.rays.shared_grid,
        a.stats.rays.shared_grid
    );
    // Every voxel a froxel reads was traced, so the pictures are the same.
    for (i, (x, y)) in a.images.iter().zip(&b.images).enumerate() {
        let differing = x.iter().zip(y).filter(|(p, q)| p.abs_diff(**q) > 1).count();
        assert_eq!(
            differing, 0,
            "viewer {i}: {differing} channels differ by > 1"
        );
    }
}

#[test]
fn cached_grid_traces_under_5_percent_after_the_first_frame_of_a_static_scene() {
    // colonnade without its turning louvre: nothing moves.
    let mut still = Scene::load("colonnade").unwrap();
    still.movers.clear();
    assert!(!still.has_animated_lights());
    let scene = Arc::new(still);
    // With the request pass every voxel is traced by the grid pass, once; with
    // `froxel_requests` the froxels make some in place and the grid traces them again
    // (tests/grid_media.rs covers that).
    let cached = Settings {
        froxel_requests: false,
        ..settings(true, true)
    };
    let mut r = Renderer::new(gpu(), scene.clone(), cached).unwrap();
    let dt = 1.0 / 30.0;
    let mut first = 0;
    for f in 0..6 {
        let t = 1.0 + f as f32 * dt;
        let out = render(&mut r, &scene.camera.viewers(2, t), t);
        let rays = out.stats.rays.shared_grid;
        println!(
            "frame {f}: {rays} grid rays, {} fog rays",
            out.stats.rays.fog_total
        );
        if f == 0 {
            first = rays;
            assert!(first > 10_000);
        } else {
            assert!(
                rays as f64 <= 0.05 * first as f64,
                "frame {f}: {rays} grid rays > 5% of the first frame's {first}"
            );
        }
    }
}

#[test]
fn cached_grid_equals_a_fresh_one_after_a_light_moves() {
    let scene = Arc::new(Scene::load("street").unwrap());
    assert!(scene.has_animated_lights(), "street has a swinging lamp");
    cached_equals_fresh(scene, 0.5, 0.9, 0.5);
}

#[test]
fn cached_grid_equals_a_fresh_one_after_an_occluder_moves() {
    let scene = Arc::new(Scene::load("colonnade").unwrap());
    assert!(!scene.movers.is_empty(), "colonnade has a turning louvre");
    assert!(!scene.has_animated_lights());
    // Only voxels whose sun rays cross the louvre's swept bounds are re-traced.
    cached_equals_fresh(scene, 1.0, 1.0 + 1.0 / 30.0, 0.1);
}

/// Renders `t0` then `t1` with caching, and `t1` fresh: every voxel the fresh update
/// traced has the same bits in the cached grid, the cached frame traced at most
/// `max_ratio` of the fresh frame's grid rays, and the pictures are identical.
fn cached_equals_fresh(scene: Arc<Scene>, t0: f32, t1: f32, max_ratio: f64) {
    let cams = scene.camera.viewers(2, t0);
    let mut cached = Renderer::new(gpu(), scene.clone(), settings(false, true)).unwrap();
    render(&mut cached, &cams, t0);
    let warm = render(&mut cached, &cams, t1);
    let mut fresh = Renderer::new(gpu(), scene.clone(), settings(false, false)).unwrap();
    let cold = render(&mut fresh, &cams, t1);
    println!(
        "{}: after t = {t0} → {t1}: cached traced {} grid rays, fresh {}",
        scene.name, warm.stats.rays.shared_grid, cold.stats.rays.shared_grid
    );
    let (words_cached, _) = cached.read_shared_grid().unwrap().unwrap();
    let fresh_bits = traced_masks(&fresh);
    assert!(fresh_bits.len() > 1000);
    for (v, mask) in fresh_bits {
        let c = (words_cached[v / 4] >> (8 * (v % 4))) as u8;
        assert_eq!(c, mask, "voxel {v}: cached {c:08b}, fresh {mask:08b}");
    }
    // Only what moved was re-traced: far fewer rays than a fresh update.
    assert!(
        warm.stats.rays.shared_grid > 0,
        "something moved, so something re-traced"
    );
    assert!(
        (warm.stats.rays.shared_grid as f64) <= max_ratio * cold.stats.rays.shared_grid as f64,
        "cached {} vs fresh {}",
        warm.stats.rays.shared_grid,
        cold.stats.rays.shared_grid
    );
    for (x, y) in warm.images.iter().zip(&cold.images) {
        assert_eq!(x, y, "cached and fresh frames differ");
    }
}

#[test]
fn sparse_bricks_give_the_dense_demand_driven_image() {
    let scene = Arc::new(Scene::load("colonnade").unwrap());
    let cams = scene.camera.viewers(2, 1.0);
    // The dense grid without the media's density (the sparse grid has none).
    let dense_settings = Settings {
        grid_media: false,
        ..settings(true, false)
    };
    let mut dense = Renderer::new(gpu(), scene.clone(), dense_settings).unwrap();
    let sparse_settings = Settings {
        brick_pool: 4096,
        ..settings(false, false)
    };
    let mut sparse = Renderer::new(gpu(), scene.clone(), sparse_settings).unwrap();
    let a = render(&mut dense, &cams, 1.0);
    let b = render(&mut sparse, &cams, 1.0);
    println!(
        "dense: {} grid rays, {} B; sparse: {} grid rays, {} bricks of {}, {} B",
        a.stats.rays.shared_grid,
        a.stats.memory.shared_total,
        b.stats.rays.shared_grid,
        b.stats.grid_bricks_requested,
        b.stats.grid_pool_bricks,
        b.stats.memory.shared_total
    );
    assert_eq!(a.stats.rays.shared_grid, b.stats.rays.shared_grid);
    assert!(b.stats.grid_bricks_requested > 0 && b.stats.grid_bricks_requested <= 4096);
    assert_eq!(
        b.stats.rays.froxel_lighting, 0,
        "every brick fitted in the pool"
    );
    assert_eq!(a.images, b.images);
}

#[test]
fn islands_at_an_eighth_of_a_metre_fits_only_as_sparse_bricks() {
    let scene = Arc::new(Scene::load("islands").unwrap());
    let dense = Settings {
        voxel_size_m: 0.125,
        ..settings(true, false)
    };
    let err = Renderer::new(gpu(), scene.clone(), dense)
        .err()
        .expect("a dense 0.125 m grid over islands does not fit");
    println!("dense: {err:#}");
    assert!(
        format!("{err:#}").contains("--brick-pool"),
        "the error names the way out"
    );

    let sparse = Settings {
        brick_pool: 65536,
        ..dense
    };
    let cams = scene.camera.viewers(2, 3.0);
    let (w, h) = (96, 54);
    let out = Renderer::new(gpu(), scene.clone(), sparse)
        .unwrap()
        .render(&cams, w, h, 3.0)
        .unwrap();
    let s = &out.stats;
    println!(
        "sparse: {} of {} bricks requested, shared memory {:.1} MiB vs dense masks {:.1} MiB; {} grid rays, {} fallback rays",
        s.grid_bricks_requested,
        s.grid_pool_bricks,
        s.memory.shared_total as f64 / 1048576.0,
        s.grid_dense_bytes as f64 / 1048576.0,
        s.rays.shared_grid,
        s.rays.froxel_lighting
    );
    assert!(
        s.grid_dense_bytes > 512 << 20,
        "the dense grid would be > 512 MiB"
    );
    assert!(
        s.memory.shared_total < 128 << 20,
        "sparse stays under 128 MiB"
    );
    assert!(s.rays.shared_grid > 0);
    let reference = Renderer::new(
        gpu(),
        scene.clone(),
        Settings {
            mode: Mode::Reference,
            ..sparse
        },
    )
    .unwrap()
    .render(&cams, w, h, 3.0)
    .unwrap();
    for (i, (a, b)) in reference.images.iter().zip(&out.images).enumerate() {
        let e = fogcast::metrics::compare(a, b, w, h).unwrap();
        println!("viewer {i}: FLIP vs reference {:.4}", e.flip_mean);
        assert!(e.flip_mean <= 0.05, "viewer {i}: FLIP {}", e.flip_mean);
    }
}

#[test]
fn hidden_froxels_are_culled_without_changing_the_picture() {
    // A viewer 2 m in front of one of colonnade's pillars with a narrow view filled by
    // it: the fog behind the pillar (4 m of it, up to the wall) can never reach the image.
    let scene = Arc::new(Scene::load("colonnade").unwrap());
    let cams = vec![Camera::new(
        glam::Vec3::new(-2.0, 2.0, -1.5),
        glam::Vec3::new(0.0, 0.0, -1.0),
        12f32.to_radians(),
    )];
    let mut gated = Renderer::new(gpu(), scene.clone(), settings(false, false)).unwrap();
    let mut demand = Renderer::new(gpu(), scene.clone(), settings(true, false)).unwrap();
    assert!(demand.settings().culls_hidden_froxels());
    let a = render(&mut gated, &cams, 1.0);
    let b = render(&mut demand, &cams, 1.0);
    println!(
        "froxels lit: frustum-gated {}, demand-driven (culled) {}; grid rays {} vs {}",
        a.stats.froxels_with_media,
        b.stats.froxels_with_media,
        a.stats.rays.shared_grid,
        b.stats.rays.shared_grid
    );
    assert!(
        (b.stats.froxels_with_media as f64) < 0.6 * a.stats.froxels_with_media as f64,
        "culling lit {} of {} froxels",
        b.stats.froxels_with_media,
        a.stats.froxels_with_media
    );
    assert!(b.stats.rays.shared_grid * 4 < a.stats.rays.shared_grid);
    let differing = a.images[0]
        .iter()
        .zip(&b.images[0])
        .filter(|(p, q)| p.abs_diff(**q) > 1)
        .count();
    assert_eq!(differing, 0, "{differing} channels differ by > 1");
}

/// Relative L1 difference of the in-scattered light of two integrated volumes, and the
/// largest transmittance difference.
fn fog_difference(a: &[[f32; 4]], b: &[[f32; 4]]) -> (f64, f64) {
    let (mut diff, mut sum, mut dt) = (0.0f64, 0.0f64, 0.0f64);
    for (x, y) in a.iter().zip(b) {
        for c in 0..3 {
            diff += (x[c] - y[c]).abs() as f64;
            sum += x[c].abs() as f64;
        }
        dt = dt.max((x[3] - y[3]).abs() as f64);
    }
    (diff / sum.max(1e-12), dt)
}

#[test]
fn near_field_fog_reads_the_shadow_map_instead_of_tracing() {
    // Colonnade's sun through the skylights, the louvre turning: the shadow frustum (the
    // first third of the slices, near each eye) looks the sun up in the shared map.
    let scene = Arc::new(Scene::load("colonnade").unwrap());
    let cams = scene.camera.viewers(2, 1.0);
    let mut rays = Renderer::new(gpu(), scene.clone(), settings(true, true)).unwrap();
    // The paper's near field (the frustum), not the grid's edges from the map.
    let map_settings = Settings {
        shadow_map_px: 4096,
        map_edges: false,
        ..settings(true, true)
    };
    let mut map = Renderer::new(gpu(), scene.clone(), map_settings).unwrap();
    for t in [1.0, 1.5] {
        let a = render(&mut rays, &cams, t);
        let b = render(&mut map, &cams, t);
        let (rel, dt) = fog_difference(
            &rays.read_integrated_volume().unwrap(),
            &map.read_integrated_volume().unwrap(),
        );
        println!(
            "t {t}: frustum rays traced {} vs map {}; in-scattered light differs by {:.3} % (L1), transmittance by {dt}",
            a.stats.rays.shadow_frustum,
            b.stats.rays.shadow_frustum,
            rel * 100.0
        );
        assert!(a.stats.rays.shadow_frustum > 1000);
        assert_eq!(b.stats.rays.shadow_frustum, 0, "the sun is the only light");
        // Shadows change where light scatters, never how much the fog absorbs.
        assert_eq!(dt, 0.0);
        assert!(rel > 0.0, "the two near fields are computed differently");
        assert!(
            rel < 0.01,
            "in-scattered light differs by {:.3} %",
            rel * 100.0
        );
    }
}

#[test]
fn shared_shadow_map_replaces_surface_rays_at_small_error() {
    let scene = Arc::new(Scene::load("colonnade").unwrap());
    let cams = scene.camera.viewers(2, 1.0);
    let mut rays = Renderer::new(gpu(), scene.clone(), settings(false, false)).unwrap();
    let map_settings = Settings {
        shadow_map_px: 2048,
        ..settings(false, false)
    };
    let mut map = Renderer::new(gpu(), scene.clone(), map_settings).unwrap();
    let a = render(&mut rays, &cams, 1.0);
    let b = render(&mut map, &cams, 1.0);
    let map_bytes = b
        .stats
        .memory
        .shared
        .iter()
        .find(|(n, _)| n == "shadow_maps")
        .map(|(_, b)| *b);
    println!(
        "surface rays: traced {} vs map {}; map bytes {map_bytes:?}",
        a.stats.rays.surface, b.stats.rays.surface
    );
    assert!(a.stats.rays.surface > 1000);
    assert_eq!(b.stats.rays.surface, 0, "the sun is colonnade's only light");
    // The static scene's map and the turning louvre's own 1024² map.
    assert_eq!(map_bytes, Some(2048 * 2048 * 4 + 1024 * 1024 * 4));
    assert_small_difference(&a.images, &b.images);
    // Street has point and spot lights only: a perspective map per spot and a cube per
    // point light (256² at 2048) take every surface ray away, at a small difference too.
    let street = Arc::new(Scene::load("street").unwrap());
    let cams = street.camera.viewers(1, 1.0);
    let s = Settings {
        shadow_map_px: 2048,
        ..settings(false, false)
    };
    let with = render(
        &mut Renderer::new(gpu(), street.clone(), s).unwrap(),
        &cams,
        1.0,
    );
    let without = render(
        &mut Renderer::new(gpu(), street.clone(), settings(false, false)).unwrap(),
        &cams,
        1.0,
    );
    println!(
        "street surface rays: traced {} vs maps {}",
        without.stats.rays.surface, with.stats.rays.surface
    );
    assert!(without.stats.rays.surface > 1000);
    assert_eq!(with.stats.rays.surface, 0);
    assert_eq!(with.stats.rays.shadow_frustum, 0);
    assert_small_difference(&without.images, &with.images);
}

/// Mean channel difference under 1 of 255 and under 1 % of channels off by more than 24.
fn assert_small_difference(a: &[Vec<u8>], b: &[Vec<u8>]) {
    for (x, y) in a.iter().zip(b) {
        let n = x.len() as f64;
        let mean = x
            .iter()
            .zip(y)
            .map(|(p, q)| p.abs_diff(*q) as f64)
            .sum::<f64>()
            / n;
        let big = x
            .iter()
            .zip(y)
            .filter(|(p, q)| p.abs_diff(**q) > 24)
            .count() as f64
            / n;
        println!(
            "mean |Δ| {mean:.3} of 255, {:.2} % of channels off by > 24",
            big * 100.0
        );
        assert!(mean < 1.0, "mean channel difference {mean}");
        assert!(
            big < 0.01,
            "{:.2} % of channels differ by > 24",
            big * 100.0
        );
    }
}
