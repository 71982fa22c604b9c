//! The scene's light count as a pipeline constant (`light_constants`): the stages built
//! with it unroll their loops over the lights, and must render exactly what the same
//! stages built without it (looping up to `frame.light_count`) render. Built inside the
//! crate because the stages are private to the renderer.

use super::{composite, froxel_lighting, shadow_frustum, Mode, Renderer, Settings};
use crate::gpu::GpuContext;
use crate::scene::Scene;
use std::sync::Arc;

const W: u32 = 64;
const H: u32 = 36;

#[test]
fn stages_that_know_the_light_count_render_the_same_picture() {
    let ctx = Arc::new(GpuContext::new().expect("a Vulkan adapter (lavapipe on CI)"));
    let maps = Settings {
        mode: Mode::Maps,
        ..Settings::default()
    };
    // One sun (colonnade, with and without the grid), three point lights (street), seven
    // lights of every kind and smoke (chimney).
    let cases = [
        ("colonnade", Settings::default()),
        ("colonnade", maps),
        ("street", Settings::default()),
        ("chimney", Settings::default()),
    ];
    for (name, settings) in cases {
        let t0 = std::time::Instant::now();
        let scene = Arc::new(Scene::load(name).expect("built-in scene"));
        let cams = scene.camera.viewers(2, 0.5);
        let mut known = Renderer::new(ctx.clone(), scene.clone(), settings).unwrap();
        let mut unknown = Renderer::new(ctx.clone(), scene.clone(), settings).unwrap();
        let layout = &unknown.world.gpu.layout;
        unknown.stages.frustum = shadow_frustum::ShadowFrustum::new(&ctx, layout, &[]);
        unknown.stages.lighting = froxel_lighting::FroxelLighting::new(&ctx, layout, &[]).unwrap();
        unknown.stages.composite = composite::Composite::new(&ctx, layout, &[]);
        // Two frames each: the second reads the first's history and cached grid.
        for t in [0.5, 0.6] {
            let a = known.render(&cams, W, H, t).unwrap();
            let b = unknown.render(&cams, W, H, t).unwrap();
            // Colour channels only (alpha is always 255).
            let lit = a
                .images
                .iter()
                .flat_map(|im| im.iter().enumerate())
                .filter(|(i, &c)| i % 4 != 3 && c > 8)
                .count();
            println!(
                "{name} ({} lights), t {t}: {lit} colour channels above 8 of 255, {:.1} s",
                scene.lights.len(),
                t0.elapsed().as_secs_f64()
            );
            assert!(
                lit > a.images.len() * 1000,
                "{name}: the frame is not black"
            );
            assert_eq!(a.images, b.images, "{name} at t {t}");
            assert_eq!(a.stats.rays, b.stats.rays, "{name} at t {t}");
        }
    }
}
