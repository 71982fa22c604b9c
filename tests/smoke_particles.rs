//! The smoke particles' GPU simulation (issue 15) against its CPU twin, and its stage run
//! once per frame whatever the viewer count.

mod gpu_support;

use fogcast::render::{cpu_particles, Renderer, Settings};
use fogcast::scene::{Camera, Scene};
use glam::Vec3;
use gpu_support::gpu;
use std::path::Path;
use std::sync::Arc;

/// A ground, a sun and three emitters of every shape; the disc's cap is reached.
const SCENE: &str = r#"
name = "smoke-sim"
[render]
near_m = 0.1
far_m = 200.0
[[mesh]]
kind = "box"
min = [-20.0, -0.2, -20.0]
max = [20.0, 0.0, 20.0]
albedo = [0.6, 0.6, 0.6]
[[light]]
kind = "directional"
direction = [0.3, -1.0, 0.2]
color = [1.0, 1.0, 1.0]
intensity = 3.0
[[emitter]]
shape = "disc"
position = [2.0, 6.0, -1.0]
radius = 0.3
rate_per_s = 20.0
lifetime_s = 4.0
velocity = [0.0, 0.5, 0.0]
spread = 0.2
buoyancy = 0.3
wind = [0.8, 0.0, 0.0]
growth = 0.25
falloff_u = 0.4
scattering = [2.0, 2.0, 2.0]
absorption = 0.5
g = 0.3
max_particles = 50
seed = 7
[[emitter]]
shape = "sphere"
position = [-3.0, 2.0, 1.0]
radius = 1.5
rate_per_s = 7.0
lifetime_s = 30.0
spread = 0.05
falloff_u = 0.8
scattering = [1.0, 1.0, 1.0]
max_particles = 1000
seed = 3
[[emitter]]
position = [0.0, 1.0, 5.0]
rate_per_s = 3.0
lifetime_s = 2.0
velocity = [0.0, 1.0, 0.0]
falloff_u = 0.3
scattering = [4.0, 3.0, 2.0]
max_particles = 100
[camera]
path = [[0.0, 3.0, 15.0], [0.0, 3.0, 14.0]]
"#;

fn scene() -> Arc<Scene> {
    Arc::new(Scene::from_toml(SCENE, Path::new("smoke-sim.toml")).expect("valid scene"))
}

fn cameras(n: usize) -> Vec<Camera> {
    (0..n)
        .map(|i| Camera::new(Vec3::new(i as f32, 3.0, 15.0), Vec3::NEG_Z, 1.0))
        .collect()
}

#[test]
fn gpu_particles_match_the_cpu_twin() {
    let scene = scene();
    let mut r = Renderer::new(gpu(), scene.clone(), Settings::default()).unwrap();
    for time_s in [0.0f32, 1.7, 12.25] {
        r.render(&cameras(1), 16, 9, time_s).unwrap();
        let got = r.world().read_particles().unwrap();
        let want = cpu_particles(&scene, time_s);
        assert_eq!(got.len(), want.len(), "t = {time_s}");
        assert!(!want.is_empty());
        let mut worst = 0.0f32;
        for (g, w) in got.iter().zip(&want) {
            assert_eq!((g.emitter, g.index), (w.emitter, w.index), "t = {time_s}");
            let (gc, wc) = (Vec3::from(g.centre), Vec3::from(w.centre));
            worst = worst.max((gc - wc).length() / (1.0 + wc.length()));
            assert!(
                (g.falloff_u - w.falloff_u).abs() <= 1e-5 * (1.0 + w.falloff_u),
                "t = {time_s}: u {} vs {}",
                g.falloff_u,
                w.falloff_u
            );
            assert_eq!(
                (g.scattering, g.absorption, g.g),
                (w.scattering, w.absorption, w.g)
            );
        }
        // f32 on the GPU against f64 on the CPU: birth points, spreads and ages agree to
        // a few ulps of the coordinates.
        assert!(
            worst <= 2e-5,
            "t = {time_s}: worst relative centre error {worst}"
        );
    }
    // Steady state at 12.25 s: the disc at its cap (50 of 80), the sphere all 86 born,
    // the point emitter rate × lifetime = 6.
    let last = r.world().read_particles().unwrap();
    let per = |k: u32| last.iter().filter(|p| p.emitter == k).count();
    assert_eq!((per(0), per(1), per(2)), (50, 86, 6));
}

#[test]
fn particles_are_placed_once_per_frame_whatever_the_viewer_count() {
    let mut r = Renderer::new(gpu(), scene(), Settings::default()).unwrap();
    let mut groups = Vec::new();
    for n in [1, 3] {
        let out = r.render(&cameras(n), 16, 9, 2.0).unwrap();
        let d: Vec<_> = out
            .stats
            .dispatches
            .iter()
            .filter(|(name, _)| name == "smoke_particles")
            .cloned()
            .collect();
        assert_eq!(d.len(), 1, "{n} viewers: {d:?}");
        groups.push(d[0].1);
    }
    assert_eq!(groups[0], groups[1]);
    // No emitter, no pass.
    let plain = Arc::new(Scene::load("colonnade").unwrap());
    let mut r = Renderer::new(gpu(), plain, Settings::default()).unwrap();
    let out = r.render(&cameras(1), 16, 9, 2.0).unwrap();
    assert!(out
        .stats
        .dispatches
        .iter()
        .all(|(n, _)| n != "smoke_particles"));
}
