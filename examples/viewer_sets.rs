//! One viewer set per view size, or every size in one set? (issue 12, docs/decisions.md)
//!
//! Renders 16 viewers of four view sizes as fogcast does (one set per size, each stage one
//! dispatch per set) and, as the cost of the alternative, the same 16 viewers as one set
//! at the largest size: a set's stacked dispatches and G-buffer layers cover the largest
//! view, so that is what mixing sizes in one set would pay. Two mixes: sizes a froxel
//! apart (what the per-set dispatches cost) and sizes 4× apart.
//!
//! `cargo run --example viewer_sets -- [scene] [frames]` (defaults: colonnade, 5).

use fogcast::gpu::GpuContext;
use fogcast::render::{FrameTarget, Renderer, Settings};
use fogcast::scene::Scene;
use std::sync::Arc;

fn main() -> anyhow::Result<()> {
    let mut args = std::env::args().skip(1);
    let scene_name = args.next().unwrap_or_else(|| "colonnade".into());
    let frames: usize = args.next().map_or(Ok(5), |s| s.parse())?;
    let ctx = Arc::new(GpuContext::new()?);
    let scene = Arc::new(Scene::load(&scene_name)?);
    let mixes: [(&str, [(u32, u32); 4]); 2] = [
        (
            "sizes a froxel apart",
            [(320, 180), (312, 180), (320, 172), (312, 172)],
        ),
        (
            "sizes 4x apart",
            [(640, 360), (320, 180), (160, 90), (160, 90)],
        ),
    ];
    println!("{scene_name}, 16 viewers (4 of each size), median of {frames} frames after 2 warm-up frames");
    println!("| mix | layout | viewer sets | frame ms | GPU ms (sum of stages) |");
    println!("|---|---|---|---|---|");
    for (label, sizes) in mixes {
        let largest = sizes[0];
        for (layout, per_viewer) in [
            ("one set per size", sizes),
            ("one set at the largest size", [largest; 4]),
        ] {
            let mut r = Renderer::new(ctx.clone(), scene.clone(), Settings::default())?;
            let (mut wall, mut gpu) = (Vec::new(), Vec::new());
            for f in 0..frames + 2 {
                let t = f as f32 / 30.0;
                let cams = scene.camera.viewers(16, t);
                let targets: Vec<FrameTarget> = cams
                    .iter()
                    .enumerate()
                    .map(|(i, c)| {
                        let (w, h) = per_viewer[i % 4];
                        FrameTarget::single(i as u64, *c, w, h)
                    })
                    .collect();
                let out = r.render_targets(&targets, t)?;
                if f >= 2 {
                    wall.push(out.stats.frame_ms);
                    gpu.push(out.stats.stage_gpu_ms.iter().map(|s| s.gpu_ms).sum::<f64>());
                }
            }
            println!(
                "| {label} | {layout} | {} | {:.1} | {:.1} |",
                r.view_sizes().len(),
                median(&mut wall),
                median(&mut gpu)
            );
        }
    }
    Ok(())
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}
