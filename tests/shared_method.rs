//! Paper 000's claims on `colonnade`, at small sizes: `shared` matches `reference`
//! (mean FLIP), traces fewer rays with many viewers, and its world grid does not depend
//! on how many viewers asked for it.

mod gpu_support;

use fogcast::metrics::compare;
use fogcast::render::{Mode, Renderer, Settings};
use gpu_support::{colonnade, gpu};

fn settings(mode: Mode) -> Settings {
    Settings {
        mode,
        voxel_size_m: 0.25,
        trilinear: true,
        ..Settings::default()
    }
}

#[test]
fn shared_matches_reference_within_flip_bound() {
    let scene = colonnade();
    let cams = scene.camera.viewers(3, 0.0);
    let (w, h) = (160, 90);
    let mut reference = Renderer::new(gpu(), scene.clone(), settings(Mode::Reference)).unwrap();
    let mut shared = Renderer::new(gpu(), scene.clone(), settings(Mode::Shared)).unwrap();
    let a = reference.render(&cams, w, h, 0.0).unwrap();
    let b = shared.render(&cams, w, h, 0.0).unwrap();
    for (i, (ra, rb)) in a.images.iter().zip(&b.images).enumerate() {
        let e = compare(ra, rb, w, h).unwrap();
        println!(
            "viewer {i}: FLIP {:.4}, PSNR {:.1} dB",
            e.flip_mean, e.psnr_db
        );
        assert!(
            e.flip_mean <= 0.05,
            "viewer {i}: shared vs reference mean FLIP {} > 0.05",
            e.flip_mean
        );
        // The images are not trivially equal: the comparison measures something.
        assert!(e.flip_mean > 0.0);
    }
}

#[test]
fn shared_traces_fewer_rays_than_reference_with_8_viewers() {
    let scene = colonnade();
    let cams = scene.camera.viewers(8, 0.0);
    let (w, h) = (320, 180);
    let a = Renderer::new(gpu(), scene.clone(), settings(Mode::Reference))
        .unwrap()
        .render(&cams, w, h, 0.0)
        .unwrap();
    let b = Renderer::new(gpu(), scene.clone(), settings(Mode::Shared))
        .unwrap()
        .render(&cams, w, h, 0.0)
        .unwrap();
    let (r, s) = (a.stats.rays, b.stats.rays);
    println!(
        "reference fog rays {}, shared fog rays {} (grid {}, frustum {})",
        r.fog_total, s.fog_total, s.shared_grid, s.shadow_frustum
    );
    assert_eq!(
        r.shared_grid + r.shadow_frustum,
        0,
        "reference traces only per froxel"
    );
    assert_eq!(
        s.froxel_lighting, 0,
        "shared traces no rays in the lighting stage"
    );
    assert!(
        s.fog_total < r.fog_total,
        "shared {} rays ≥ reference {}",
        s.fog_total,
        r.fog_total
    );
    // Surfaces: `reference` traces a ray per pixel towards the sun, `shared` reads its
    // shared shadow map (on by default).
    assert!(r.surface > 0);
    assert_eq!(
        s.surface, 0,
        "the sun's surface shadows come from the shared map"
    );
    // Memory: the grid is shared, the per-viewer volumes are reported per viewer.
    assert!(b
        .stats
        .memory
        .shared
        .iter()
        .any(|(n, bytes)| n == "shared_grid" && *bytes > 0));
    assert_eq!(
        b.stats.memory.total,
        b.stats.memory.shared_total + 8 * b.stats.memory.per_viewer_total
    );
}

/// Voxel `v` of a grid read back as (words, touched nibbles): (mask, traced this frame).
fn voxel(words: &[u32], touched: &[u32], v: usize) -> (u32, bool) {
    let (w, i) = (v / 4, v % 4);
    let mask = (words[w] >> (8 * i)) & 0xff;
    let t = (touched[w / 8] >> (4 * (w % 8) + i)) & 1 == 1;
    (mask, t)
}

#[test]
fn shared_grid_is_identical_for_1_and_16_viewers() {
    let scene = colonnade();
    let cams16 = scene.camera.viewers(16, 0.0);
    let mut many = Renderer::new(gpu(), scene.clone(), settings(Mode::Shared)).unwrap();
    many.render(&cams16, 64, 36, 0.0).unwrap();
    let (w16, t16) = many
        .read_shared_grid()
        .unwrap()
        .expect("shared mode has a grid");
    let mut compared = 0usize;
    let mut lit = 0usize;
    for cam in [cams16[3], cams16[11]] {
        let mut one = Renderer::new(gpu(), scene.clone(), settings(Mode::Shared)).unwrap();
        one.render(&[cam], 64, 36, 0.0).unwrap();
        let (w1, t1) = one.read_shared_grid().unwrap().unwrap();
        assert_eq!(w1.len(), w16.len());
        for v in 0..w1.len() * 4 {
            let (m1, traced1) = voxel(&w1, &t1, v);
            let (m16, traced16) = voxel(&w16, &t16, v);
            if traced1 {
                assert!(
                    traced16,
                    "voxel {v} traced for one viewer but not for all 16"
                );
                assert_eq!(
                    m1, m16,
                    "voxel {v}: mask {m1:#04x} (1 viewer) vs {m16:#04x} (16 viewers)"
                );
                compared += 1;
                lit += (m1 != 0) as usize;
            }
        }
    }
    println!("compared {compared} voxels, {lit} lit");
    assert!(compared > 1000, "too few voxels compared ({compared})");
    assert!(
        lit > 0 && lit < compared,
        "grid should hold both lit and shadowed voxels"
    );
}

#[test]
fn parity_updates_about_half_the_voxels() {
    let scene = colonnade();
    let cams = scene.camera.viewers(4, 0.0);
    let full = Renderer::new(gpu(), scene.clone(), settings(Mode::Shared))
        .unwrap()
        .render(&cams, 64, 36, 0.0)
        .unwrap();
    let mut s = settings(Mode::Shared);
    s.parity = true;
    let half = Renderer::new(gpu(), scene.clone(), s)
        .unwrap()
        .render(&cams, 64, 36, 0.0)
        .unwrap();
    let ratio = half.stats.voxels_traced as f64 / full.stats.voxels_traced as f64;
    println!(
        "parity traced {} of {} voxels ({ratio:.3})",
        half.stats.voxels_traced, full.stats.voxels_traced
    );
    assert!((0.4..0.6).contains(&ratio), "parity ratio {ratio}");
}
