//! Where `shared` and its variants differ from `maps` against `truth`, per viewer.
//!
//! `cargo run --release --example truth_probe -- SCENE VIEWERS TIME OUTDIR [SETTINGS…]`
//!
//! Renders `truth` and, at 320×180, `mode=maps`, the default settings (`-`) and each
//! SETTINGS string (`key=value,…` as `fogcast bench --variant` takes them); prints mean FLIP
//! against `truth` per viewer and writes each variant's image and a difference map against
//! `maps`' FLIP to OUTDIR (red: the variant is further from `truth`, green: closer).
use fogcast::gpu::GpuContext;
use fogcast::render::{Renderer, Settings};
use fogcast::scene::{Bvh, Scene};
use fogcast::truth::{render_truth, TruthSettings};
use std::sync::Arc;

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    anyhow::ensure!(
        args.len() >= 4,
        "usage: truth_probe SCENE VIEWERS TIME OUTDIR [SETTINGS…]"
    );
    let scene = Arc::new(Scene::load(&args[0])?);
    let n: usize = args[1].parse()?;
    let t: f32 = args[2].parse()?;
    let out = std::path::PathBuf::from(&args[3]);
    std::fs::create_dir_all(&out)?;
    let (w, h) = (320u32, 180u32);
    let cams = scene.camera.viewers(n, t);
    let bvh = Bvh::build(&scene.mesh)?;
    let (truth, _) = render_truth(
        &scene,
        &bvh,
        &cams,
        (w, h),
        t,
        TruthSettings::default(),
        &|_, _| {},
    );
    let ctx = Arc::new(GpuContext::new()?);
    let mut variants: Vec<String> = vec!["mode=maps".into(), "-".into()];
    variants.extend(args[4..].iter().cloned());
    let mut maps_flip: Vec<Vec<f32>> = Vec::new();
    for v in &variants {
        let mut s = Settings::default();
        if v != "-" {
            s.set_all(v)?;
        }
        let mut r = Renderer::new(ctx.clone(), scene.clone(), s)?;
        r.render(&cams, w, h, t)?;
        let o = r.render(&cams, w, h, t)?;
        let mut line = format!("{v:40}");
        let mut tot = 0.0;
        for k in 0..n {
            let im = o.images[k].clone();
            let f = fogcast::metrics::flip_map(&truth[k], &im, w, h)?
                .pixels()
                .to_vec();
            let m = f.iter().map(|&x| x as f64).sum::<f64>() / f.len() as f64;
            tot += m;
            line += &format!(" {m:.6}");
            if maps_flip.len() <= k {
                maps_flip.push(f.clone());
            } else {
                // write |flip − maps' flip| as a grey image: brighter = this variant worse
                let img: Vec<u8> = f
                    .iter()
                    .zip(&maps_flip[k])
                    .flat_map(|(a, b)| {
                        let d = a - b;
                        let p = (d.max(0.0) * 2550.0).min(255.0) as u8;
                        let q = ((-d).max(0.0) * 2550.0).min(255.0) as u8;
                        [p, q, 0, 255]
                    })
                    .collect();
                let name = format!("diff_{}_{k}.png", v.replace(['=', ','], "_"));
                fogcast::output::write_png(&out.join(name), &img, w, h)?;
                fogcast::output::write_png(
                    &out.join(format!("img_{}_{k}.png", v.replace(['=', ','], "_"))),
                    &im,
                    w,
                    h,
                )?;
            }
        }
        println!("{line}  mean {:.6}", tot / n as f64);
    }
    Ok(())
}
