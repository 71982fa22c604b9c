//! The ground-truth renderer as a yardstick: converged, and close to `reference`;
//! `shared`'s error against it falls as the voxels shrink.

mod gpu_support;

use fogcast::metrics::compare;
use fogcast::render::{Mode, Renderer, Settings};
use fogcast::scene::{Bvh, Scene};
use fogcast::truth::{render_truth, TruthSettings};
use gpu_support::gpu;
use std::sync::{Arc, OnceLock};

const W: u32 = 160;
const H: u32 = 90;

struct Fixture {
    scene: Arc<Scene>,
    bvh: Bvh,
    truth: Vec<Vec<u8>>,
}

fn fixture() -> &'static Fixture {
    static F: OnceLock<Fixture> = OnceLock::new();
    F.get_or_init(|| {
        let scene = Arc::new(Scene::load("colonnade").unwrap());
        let bvh = Bvh::build(&scene.mesh).unwrap();
        let cams = scene.camera.viewers(2, 0.0);
        let (truth, _) = render_truth(
            &scene,
            &bvh,
            &cams,
            (W, H),
            0.0,
            TruthSettings::default(),
            &|_, _| {},
        );
        Fixture { scene, bvh, truth }
    })
}

fn mean_flip_vs_truth(settings: Settings) -> f64 {
    let f = fixture();
    let cams = f.scene.camera.viewers(2, 0.0);
    let mut r = Renderer::with_bvh(gpu(), f.scene.clone(), &f.bvh, settings).unwrap();
    let out = r.render(&cams, W, H, 0.0).unwrap();
    let flips: Vec<f64> = out
        .images
        .iter()
        .zip(&f.truth)
        .map(|(img, t)| compare(t, img, W, H).unwrap().flip_mean)
        .collect();
    flips.iter().sum::<f64>() / flips.len() as f64
}

#[test]
fn truth_is_converged() {
    let f = fixture();
    let cams = f.scene.camera.viewers(2, 0.0);
    let doubled = TruthSettings {
        steps: TruthSettings::default().steps * 2,
        ..TruthSettings::default()
    };
    let (fine, _) = render_truth(&f.scene, &f.bvh, &cams, (W, H), 0.0, doubled, &|_, _| {});
    for (a, b) in f.truth.iter().zip(&fine) {
        let e = compare(b, a, W, H).unwrap();
        println!(
            "truth N vs 2N steps: FLIP {:.5}, PSNR {:.1} dB",
            e.flip_mean, e.psnr_db
        );
        assert!(
            e.flip_mean < 0.005,
            "doubling truth steps moved mean FLIP by {}",
            e.flip_mean
        );
    }
}

#[test]
fn reference_is_close_to_truth() {
    let flip = mean_flip_vs_truth(Settings {
        mode: Mode::Reference,
        ..Settings::default()
    });
    println!("reference vs truth: mean FLIP {flip:.4}");
    assert!(flip <= 0.08, "reference vs truth mean FLIP {flip} > 0.08");
}

#[test]
fn shared_error_falls_as_voxels_shrink() {
    let at = |voxel_size_m: f32| {
        let flip = mean_flip_vs_truth(Settings {
            mode: Mode::Shared,
            voxel_size_m,
            frustum_slice_fraction: 0.0,
            ..Settings::default()
        });
        println!(
            "shared, {voxel_size_m} m voxels, no shadow frustum: mean FLIP vs truth {flip:.4}"
        );
        flip
    };
    let coarse = at(4.0);
    let fine = at(0.25);
    assert!(
        coarse > fine + 0.005,
        "4 m voxels ({coarse}) should be clearly worse than 0.25 m ({fine})"
    );
}
