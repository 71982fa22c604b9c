//! Two settings against each other, frame by frame: two renderers take turns on the same
//! targets, and each stage's ratio is the median of the per-frame ratios of neighbouring
//! frames (B over A). Lavapipe's frame times drift by ±10 % between runs; frames rendered
//! back to back drift together, so a few percent show where two separate runs cannot.
//!
//! `cargo run --example ab_settings -- SCENE A B [FRAMES] [HEADS] [mono|one-eye|stereo] [DT]`
//!
//! A and B are `key=value,…` over `shared`'s defaults (`-`: the defaults), as a bench
//! `--variant` takes them. The targets are HEADS stereo sessions (320×180 per eye, eyes
//! 6.4 cm apart) at the heads of the scene's camera path at t = 0, or HEADS mono viewers
//! with `mono`. With `one-eye`, A renders the stereo sessions and B each session's
//! first eye alone as a mono view (issue 16's "stereo session / one eye", paired frame
//! by frame). Two warm-up frames each; FRAMES (default 12) measured frames each. With
//! DT the heads move along the path, the n-th pair of frames at scene time n·DT seconds
//! (default 0: every frame at t = 0); the fog stages' rays, the froxels with media and
//! the frames whose froxels requested the grid's voxels (`froxel_requests`) are
//! reported too. With `FOGCAST_AB_BLOCK=n` in the environment each renderer draws n
//! frames in a row and only the last is measured, so that every measured frame follows
//! its own renderer's frame (as in `fogcast bench`; docs/decisions.md, "Each measured
//! frame follows its own renderer's"). `FOGCAST_AB_SLEEP_MS=ms` pauses that long before
//! every frame.
//! Example: `cargo run --example ab_settings -- colonnade - stereo_head=on 20 2`.

use anyhow::Context as _;
use fogcast::gpu::GpuContext;
use fogcast::render::{stereo_eyes, FrameTarget, Renderer, Settings};
use fogcast::scene::Scene;
use std::collections::BTreeMap;
use std::sync::Arc;

const WARMUP: usize = 2;

fn settings(overrides: &str) -> anyhow::Result<Settings> {
    let mut s = Settings::default();
    if overrides != "-" && !overrides.is_empty() {
        s.set_all(overrides)?;
    }
    Ok(s)
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [scene_name, a, b, rest @ ..] = args.as_slice() else {
        anyhow::bail!("usage: ab_settings SCENE A B [FRAMES] [HEADS] [mono|one-eye|stereo] [DT]");
    };
    let frames: usize = rest
        .first()
        .map_or(Ok(12), |s| s.parse())
        .context("FRAMES")?;
    let heads: usize = rest.get(1).map_or(Ok(1), |s| s.parse()).context("HEADS")?;
    let mono = rest.get(2).is_some_and(|s| s == "mono");
    let one_eye = rest.get(2).is_some_and(|s| s == "one-eye");
    let dt: f32 = rest.get(3).map_or(Ok(0.0), |s| s.parse()).context("DT")?;
    anyhow::ensure!(
        frames > 0 && heads > 0,
        "FRAMES and HEADS must be at least 1"
    );
    let ctx = Arc::new(GpuContext::new()?);
    let scene = Arc::new(Scene::load(scene_name)?);
    let renderer = |o: &str| Renderer::new(ctx.clone(), scene.clone(), settings(o)?);
    let mut renderers = [renderer(a)?, renderer(b)?];
    let target = |i: usize, c, mono| {
        if mono {
            FrameTarget::single(i as u64, c, 320, 180)
        } else {
            FrameTarget::stereo(2 * i as u64, c, 0.064, 320, 180)
        }
    };
    // Per renderer: stage → GPU ms of each measured frame (and rays, as "rays: …").
    let mut ms: [BTreeMap<String, Vec<f64>>; 2] = Default::default();
    let env = |name: &str| std::env::var(name).ok().and_then(|s| s.parse::<u64>().ok());
    // FOGCAST_AB_BLOCK=n: each renderer renders n frames in a row, the last measured.
    let block = env("FOGCAST_AB_BLOCK").unwrap_or(1).max(1) as usize;
    let pause = env("FOGCAST_AB_SLEEP_MS").map(std::time::Duration::from_millis);
    for g in 0..2 * (WARMUP + frames) * block {
        let f = g / block;
        let (k, t) = (f % 2, (f / 2) as f32 * dt);
        let heads = scene.camera.viewers(heads, t);
        let which: Vec<FrameTarget> = heads
            .iter()
            .enumerate()
            .map(|(i, &c)| {
                if one_eye && k == 1 {
                    target(i, stereo_eyes(c, 0.064)[0], true)
                } else {
                    target(i, c, mono)
                }
            })
            .collect();
        if let Some(pause) = pause {
            std::thread::sleep(pause);
        }
        let out = renderers[k].render_targets(&which, t)?;
        if f < 2 * WARMUP || g % block != block - 1 {
            continue;
        }
        let stages = &out.stats.stage_gpu_ms;
        for s in stages {
            ms[k].entry(s.stage.clone()).or_default().push(s.gpu_ms);
        }
        let frame = stages.iter().map(|s| s.gpu_ms).sum();
        ms[k].entry("frame".into()).or_default().push(frame);
        let r = &out.stats.rays;
        for (name, n) in [
            ("rays: shared_grid", r.shared_grid),
            ("rays: froxel_lighting", r.froxel_lighting),
            ("froxels with media", out.stats.froxels_with_media),
            (
                "frames without a request pass",
                u64::from(out.stats.froxel_requests),
            ),
        ] {
            ms[k].entry(name.into()).or_default().push(n as f64);
        }
    }
    println!("{scene_name}: A = {a}, B = {b}; {frames} frames each, GPU ms (medians)");
    println!("| stage | A | B | B / A, median of per-frame ratios |");
    println!("|---|---|---|---|");
    for (stage, va) in &ms[0] {
        let Some(vb) = ms[1].get(stage) else { continue };
        if stage.starts_with("frames") {
            let (na, nb) = (va.iter().sum::<f64>(), vb.iter().sum::<f64>());
            println!("| {stage} | {na} | {nb} | |");
            continue;
        }
        let ratios = va.iter().zip(vb).map(|(x, y)| y / x.max(1e-9)).collect();
        println!(
            "| {stage} | {:.2} | {:.2} | {:.3} |",
            median(va.clone()),
            median(vb.clone()),
            median(ratios)
        );
    }
    Ok(())
}
