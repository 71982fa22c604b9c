//! `fogcast eval`: `truth`, `reference`, a sweep of `shared` settings and `maps` (the
//! engines' shadow-map froxels) on the same frames; a table of time, rays and error, and
//! speed-vs-error plots with the Pareto front. Errors are measured against `truth` and, as paper 000 reports them, against
//! `reference`.

use crate::gpu::GpuContext;
use crate::metrics::{compare_frames, FrameError};
use crate::render::{FrameOutput, Mode, Renderer, Settings};
use crate::report::{plot, Series, Table};
use crate::scene::{Bvh, Scene};
use crate::truth::{render_truth, TruthSettings};
use serde::{Deserialize, Serialize};
use std::path::PathBuf;
use std::sync::Arc;

/// What to evaluate.
#[derive(Debug, Clone)]
pub struct EvalConfig {
    /// Scene name or path.
    pub scene: String,
    /// Viewers (placed along the scene's camera path).
    pub viewers: usize,
    /// Viewer width, pixels.
    pub width: u32,
    /// Viewer height, pixels.
    pub height: u32,
    /// Shared grid voxel sizes to sweep, metres.
    pub voxel_sizes_m: Vec<f32>,
    /// Extra depth-slice curvatures to evaluate (reference and default shared each).
    pub depth_curves: Vec<f32>,
    /// Frames per variant: cameras walk into the evaluated pose over these frames, so
    /// parity updates and stale voxels are measured as they are in motion.
    pub frames: u32,
    /// Ray-march steps of `truth`.
    pub truth_steps: u32,
    /// Primary rays per pixel of `truth` (box filter over the pixel); paths per pixel
    /// with `truth_bounces`.
    pub truth_spp: u32,
    /// Multiple scattering in `truth` (issue 16): path-trace up to this many
    /// scatterings, the sky as a light and no ambient (0: single scattering).
    pub truth_bounces: u32,
    /// Variable step amplification in `truth`'s media march (seed 003 Eq. 4–6).
    pub truth_vsa: bool,
    /// Node spacings of the media transmittance volumes to compare besides `shared`'s
    /// default, metres (0: marched per sample).
    pub transmittance_voxels_m: Vec<f32>,
    /// Scene time of the evaluated frame, seconds.
    pub time_s: f32,
    /// AVSM node counts to sweep on smoke scenes (issue 15).
    pub avsm_nodes: Vec<u32>,
    /// Simpson steps of the smoke's in-scattering to sweep on smoke scenes.
    pub smoke_simpson_steps: Vec<u32>,
    /// Probe spacings of the shared ambient grid, each a `shared` variant (issue 16).
    pub sh_ambient_m: Vec<f32>,
    /// Output folder.
    pub out: PathBuf,
    /// The command line, recorded in the report.
    pub command: String,
}

/// One evaluated configuration.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct EvalRow {
    /// Short name of the variant.
    pub variant: String,
    /// Renderer settings (`None` for truth).
    pub settings: Option<Settings>,
    /// Shared grid dimensions.
    pub grid_dims: [u32; 3],
    /// Shadow rays of the fog stages in the evaluated frame.
    pub fog_rays: u64,
    /// All shadow rays (fog + surfaces).
    pub total_rays: u64,
    /// GPU time of the fog stages (grid, frustum, lighting, integration), median, ms.
    pub fog_gpu_ms: f64,
    /// GPU time of the whole frame, median, ms.
    pub frame_gpu_ms: f64,
    /// GPU memory, shared + all viewers, bytes.
    pub memory_bytes: u64,
    /// Error against `truth` (mean over viewers).
    pub vs_truth: FrameError,
    /// Error against `reference` (mean over viewers).
    pub vs_reference: Option<FrameError>,
}

fn mean_error(errors: &[FrameError]) -> FrameError {
    let n = errors.len().max(1) as f64;
    let avg = |f: &dyn Fn(&FrameError) -> f64| errors.iter().map(f).sum::<f64>() / n;
    let img = |sel: fn(&FrameError) -> &crate::metrics::ImageError| crate::metrics::ImageError {
        flip_mean: avg(&|e| sel(e).flip_mean),
        psnr_db: avg(&|e| sel(e).psnr_db.min(99.0)),
        rmse: avg(&|e| sel(e).rmse),
        ssim: avg(&|e| sel(e).ssim),
    };
    FrameError {
        frame: img(|e| &e.frame),
        fog: img(|e| &e.fog),
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

struct Frames<'a> {
    images: &'a [Vec<u8>],
    no_media: &'a [Vec<u8>],
}

fn errors(reference: &Frames<'_>, test: &Frames<'_>, w: u32, h: u32) -> anyhow::Result<FrameError> {
    let e: anyhow::Result<Vec<FrameError>> = (0..reference.images.len())
        .map(|i| {
            compare_frames(
                &reference.images[i],
                &reference.no_media[i],
                &test.images[i],
                &test.no_media[i],
                w,
                h,
            )
        })
        .collect();
    Ok(mean_error(&e?))
}

struct Runner {
    ctx: Arc<GpuContext>,
    scene: Arc<Scene>,
    bvh: Bvh,
    cfg: EvalConfig,
}

impl Runner {
    /// Renders the walk-in frames; returns the last frame and the median GPU times
    /// (fog stages, whole frame) over the frames after the first (which compiles shaders).
    fn run(
        &self,
        scene: &Arc<Scene>,
        settings: Settings,
    ) -> anyhow::Result<(FrameOutput, f64, f64)> {
        let mut r = Renderer::with_bvh(self.ctx.clone(), scene.clone(), &self.bvh, settings)?;
        let dt = 1.0 / 30.0;
        let n = self.cfg.frames.max(1);
        let (mut fog_ms, mut frame_ms) = (Vec::new(), Vec::new());
        let mut last = None;
        for k in 0..n {
            let t = self.cfg.time_s - (n - 1 - k) as f32 * dt;
            let cams = scene.camera.viewers(self.cfg.viewers, t);
            let out = r.render(&cams, self.cfg.width, self.cfg.height, t)?;
            if k > 0 || n == 1 {
                let sum = |pred: &dyn Fn(&str) -> bool| {
                    out.stats
                        .stage_gpu_ms
                        .iter()
                        .filter(|s| pred(&s.stage))
                        .map(|s| s.gpu_ms)
                        .sum::<f64>()
                };
                fog_ms.push(sum(&crate::bench::is_fog_stage));
                frame_ms.push(if out.stats.timestamps {
                    sum(&|_| true)
                } else {
                    out.stats.frame_ms
                });
            }
            last = Some(out);
        }
        Ok((
            last.expect("at least one frame"),
            median(fog_ms),
            median(frame_ms),
        ))
    }
}

/// A variant's name: its mode, then its settings that differ from `base` as
/// `key=value,…`, the spelling of flags, config files and bench variants.
fn variant_name(s: &Settings, base: &Settings) -> String {
    let changes = s.changes_from(&Settings {
        mode: s.mode,
        ..*base
    });
    if changes.is_empty() {
        s.mode.name().into()
    } else {
        format!("{} {changes}", s.mode.name())
    }
}

/// Runs the whole evaluation and writes `eval.md`, `eval.csv`, `eval.json` and plots.
pub fn run(cfg: EvalConfig, progress: &(dyn Fn(&str) + Sync)) -> anyhow::Result<Vec<EvalRow>> {
    let ts = TruthSettings::from_flags(
        cfg.truth_steps,
        cfg.truth_spp,
        cfg.truth_bounces,
        cfg.truth_vsa,
    );
    ts.validate()?;
    std::fs::create_dir_all(&cfg.out)?;
    let scene = Arc::new(Scene::load(&cfg.scene)?);
    // The frame without fog or smoke: what the fog-region error masks are made from.
    let mut bare = (*scene).clone();
    bare.media.clear();
    bare.emitters.clear();
    let bare = Arc::new(bare);
    let bvh = Bvh::build(&scene.mesh)?;
    let ctx = Arc::new(GpuContext::new()?);
    let (w, h) = (cfg.width, cfg.height);
    let cams = scene.camera.viewers(cfg.viewers, cfg.time_s);

    progress("truth (CPU): with media");
    let truth_started = std::time::Instant::now();
    let (truth, truth_counts) =
        render_truth(&scene, &bvh, &cams, (w, h), cfg.time_s, ts, &|_, _| {});
    let truth_ms = truth_started.elapsed().as_secs_f64() * 1e3;
    // The fog's contribution (with minus without) is compared too, so the frame without
    // media is rendered by the same truth, path-traced when the one above is.
    progress("truth (CPU): without media");
    let (truth_bare, _) = render_truth(&bare, &bvh, &cams, (w, h), cfg.time_s, ts, &|_, _| {});
    let truth_frames = Frames {
        images: &truth,
        no_media: &truth_bare,
    };

    let runner = Runner {
        ctx,
        scene: scene.clone(),
        bvh,
        cfg: cfg.clone(),
    };
    // The sweep runs the paper's method as published; fogcast's options follow it.
    let base = Settings {
        voxel_size_m: scene.render.voxel_size_m,
        demand: false,
        cache: false,
        shadow_map_px: 0,
        ..Settings::default()
    };
    progress("GPU without media");
    let (gpu_bare, _, _) = runner.run(
        &bare,
        Settings {
            mode: Mode::Reference,
            ..base
        },
    )?;

    let mut rows = Vec::new();
    let mut variants = vec![Settings {
        mode: Mode::Reference,
        ..base
    }];
    for &voxel_size_m in &cfg.voxel_sizes_m {
        for trilinear in [false, true] {
            for parity in [false, true] {
                for frustum in [true, false] {
                    variants.push(Settings {
                        mode: Mode::Shared,
                        voxel_size_m,
                        trilinear,
                        parity,
                        frustum_slice_fraction: if frustum {
                            base.frustum_slice_fraction
                        } else {
                            0.0
                        },
                        ..base
                    });
                }
            }
        }
    }
    // fogcast's options beyond the paper, at the default voxel size: the demand-driven
    // grid, then with the shared surface shadow maps, then cached (`shared`'s defaults).
    let maps = Settings::default().shadow_map_px;
    for (demand, cache, shadow_map_px) in
        [(true, false, 0), (true, false, maps), (true, true, maps)]
    {
        variants.push(Settings {
            mode: Mode::Shared,
            demand,
            cache,
            shadow_map_px,
            ..base
        });
    }
    // The engines' way (`maps`): every froxel lit from the shared shadow maps and
    // transmittance volumes, no grid.
    variants.push(Settings {
        mode: Mode::Maps,
        shadow_map_px: maps,
        ..base
    });
    // `shared` with its froxels lit from those maps (`froxel_maps`: no grid, no frustum,
    // hidden froxels culled), from `shared`'s defaults.
    variants.push(Settings {
        mode: Mode::Shared,
        froxel_maps: true,
        voxel_size_m: base.voxel_size_m,
        ..Settings::default()
    });
    // The media transmittance toward the lights at other node spacings, or marched per
    // froxel and pixel (0), on top of `shared`'s defaults.
    for &transmittance_voxel_m in &cfg.transmittance_voxels_m {
        if transmittance_voxel_m != Settings::default().transmittance_voxel_m {
            variants.push(Settings {
                mode: Mode::Shared,
                transmittance_voxel_m,
                ..Settings {
                    voxel_size_m: base.voxel_size_m,
                    ..Settings::default()
                }
            });
        }
    }
    // Smoke (issue 15): the shadow maps' node count and the interval's Simpson steps, one
    // at a time from `shared`'s defaults (time against error: eval's plots).
    if !scene.emitters.is_empty() {
        let defaults = Settings {
            mode: Mode::Shared,
            voxel_size_m: base.voxel_size_m,
            ..Settings::default()
        };
        let mut sweep: Vec<Settings> = Vec::new();
        for &avsm_nodes in &cfg.avsm_nodes {
            sweep.push(Settings {
                avsm_nodes,
                ..defaults
            });
        }
        for &smoke_simpson_steps in &cfg.smoke_simpson_steps {
            sweep.push(Settings {
                smoke_simpson_steps,
                ..defaults
            });
        }
        for s in sweep {
            if !variants.contains(&s) {
                variants.push(s);
            }
        }
    }
    // The shared ambient grid (issue 16) in place of the constant `ambient`, on top of
    // `shared`'s defaults.
    for &sh_ambient_m in &cfg.sh_ambient_m {
        variants.push(Settings {
            mode: Mode::Shared,
            voxel_size_m: base.voxel_size_m,
            sh_ambient_m,
            ..Settings::default()
        });
    }
    for &depth_curve in &cfg.depth_curves {
        if depth_curve != base.depth_curve {
            variants.push(Settings {
                mode: Mode::Reference,
                depth_curve,
                ..base
            });
            variants.push(Settings {
                mode: Mode::Shared,
                depth_curve,
                ..base
            });
        }
    }
    let mut reference_images: Option<Vec<Vec<u8>>> = None;
    for (i, settings) in variants.iter().enumerate() {
        let name = variant_name(settings, &base);
        progress(&format!("[{}/{}] {name}", i + 1, variants.len()));
        let (out, fog_ms, frame_ms) = match runner.run(&runner.scene, *settings) {
            Ok(r) => r,
            Err(e) => {
                tracing::warn!("{name}: skipped: {e:#}");
                continue;
            }
        };
        // The ambient grid lights the surfaces too: its fog contribution is measured
        // against its own frame without media.
        let own_bare = if settings.sh_ambient_m > 0.0 {
            Some(runner.run(&bare, *settings)?.0)
        } else {
            None
        };
        let test = Frames {
            images: &out.images,
            no_media: own_bare.as_ref().map_or(&gpu_bare.images, |b| &b.images),
        };
        let vs_truth = errors(&truth_frames, &test, w, h)?;
        let vs_reference = match &reference_images {
            Some(r) => Some(errors(
                &Frames {
                    images: r,
                    no_media: &gpu_bare.images,
                },
                &test,
                w,
                h,
            )?),
            None => None,
        };
        if settings.mode == Mode::Reference {
            reference_images = Some(out.images.clone());
            crate::output::write_png(&cfg.out.join("reference_00.png"), &out.images[0], w, h)?;
        }
        if settings.mode == Mode::Shared
            && settings.voxel_size_m == base.voxel_size_m
            && settings.trilinear
            && !settings.parity
            && settings.frustum_slice_fraction > 0.0
        {
            crate::output::write_png(&cfg.out.join("shared_00.png"), &out.images[0], w, h)?;
        }
        if settings.mode == Mode::Maps {
            crate::output::write_png(&cfg.out.join("maps_00.png"), &out.images[0], w, h)?;
        }
        rows.push(EvalRow {
            variant: name,
            settings: Some(*settings),
            grid_dims: out.stats.grid_dims,
            fog_rays: out.stats.rays.fog_total,
            total_rays: out.stats.rays.total,
            fog_gpu_ms: fog_ms,
            frame_gpu_ms: frame_ms,
            memory_bytes: out.stats.memory.total,
            vs_truth,
            vs_reference,
        });
    }
    crate::output::write_png(&cfg.out.join("truth_00.png"), &truth[0], w, h)?;
    write_report(&cfg, &scene, &base, &rows, truth_ms, truth_counts)?;
    Ok(rows)
}

fn write_report(
    cfg: &EvalConfig,
    scene: &Scene,
    base: &Settings,
    rows: &[EvalRow],
    truth_ms: f64,
    truth_counts: crate::truth::TruthCounts,
) -> anyhow::Result<()> {
    let truth_rays = truth_counts.media_rays + truth_counts.surface_rays;
    let truth_samples = truth_counts.media_samples;
    let mut t = Table::new(&[
        "variant",
        "grid",
        "fog rays",
        "fog GPU ms",
        "frame GPU ms",
        "memory MiB",
        "FLIP vs truth",
        "PSNR vs truth dB",
        "SSIM vs truth",
        "fog FLIP vs truth",
        "FLIP vs reference",
    ]);
    for r in rows {
        t.push(vec![
            r.variant.clone(),
            if r.grid_dims[0] > 0 {
                format!("{}×{}×{}", r.grid_dims[0], r.grid_dims[1], r.grid_dims[2])
            } else {
                "–".into()
            },
            r.fog_rays.to_string(),
            format!("{:.1}", r.fog_gpu_ms),
            format!("{:.1}", r.frame_gpu_ms),
            format!("{:.1}", r.memory_bytes as f64 / 1048576.0),
            format!("{:.4}", r.vs_truth.frame.flip_mean),
            format!("{:.1}", r.vs_truth.frame.psnr_db),
            format!("{:.4}", r.vs_truth.frame.ssim),
            format!("{:.4}", r.vs_truth.fog.flip_mean),
            r.vs_reference
                .map_or("–".into(), |e| format!("{:.4}", e.frame.flip_mean)),
        ]);
    }
    std::fs::write(cfg.out.join("eval.csv"), t.to_csv())?;
    crate::output::write_json(&cfg.out.join("eval.json"), &rows)?;
    let md = format!(
        "# eval: {scene}\n\n`{cmd}`\n\n{n} viewer(s) at {w}×{h}, evaluated frame at t = {t:.2} s after {f} walk-in frame(s); \
         truth: {kind}, {truth_rays} shadow rays, {truth_samples} media samples, {truth_s:.1} s on the CPU. Times are GPU timestamps \
         (median over the walk-in frames after the first) on `{adapter}`.\n\n\
         A variant is its mode and its settings that differ from the paper's method as published \
         (`{paper}` over `shared`'s defaults, {voxel} m voxels), as config files and bench \
         variants key them (flags: `--` and the key with `-` for `_`).\n\n{table}",
        paper = base.changes_from(&Settings::for_scene(scene)),
        voxel = base.voxel_size_m,
        scene = scene.name,
        cmd = cfg.command,
        n = cfg.viewers,
        w = cfg.width,
        h = cfg.height,
        t = cfg.time_s,
        f = cfg.frames,
        kind = if cfg.truth_bounces > 0 {
            format!(
                "path-traced, up to {} scatterings (sky as a light, no ambient), {} paths/pixel",
                cfg.truth_bounces, cfg.truth_spp
            )
        } else {
            format!(
                "{} {} and {} ray(s)/pixel",
                cfg.truth_steps,
                if cfg.truth_vsa {
                    "baseline steps with step amplification (seed 003)"
                } else {
                    "steps"
                },
                cfg.truth_spp
            )
        },
        truth_s = truth_ms / 1e3,
        adapter = GpuContext::last_adapter_name(),
        table = t.to_markdown()
    );
    std::fs::write(cfg.out.join("eval.md"), md)?;

    // A colour per combination of the sweep's lookup, parity and shadow frustum; the
    // other settings' variants share their combination's colour.
    let group = |r: &EvalRow| -> String {
        r.settings.map_or(r.variant.clone(), |s| {
            let swept = Settings {
                mode: s.mode,
                trilinear: s.trilinear,
                parity: s.parity,
                frustum_slice_fraction: s.frustum_slice_fraction,
                ..*base
            };
            variant_name(&swept, base)
        })
    };
    let mut groups: Vec<String> = rows.iter().map(group).collect();
    groups.dedup();
    let series = |x: &dyn Fn(&EvalRow) -> f64| -> Vec<Series> {
        let mut names: Vec<String> = Vec::new();
        for g in &groups {
            if !names.contains(g) {
                names.push(g.clone());
            }
        }
        names
            .into_iter()
            .map(|g| Series {
                points: rows
                    .iter()
                    .filter(|r| group(r) == g)
                    .map(|r| (x(r), r.vs_truth.frame.flip_mean))
                    .collect(),
                name: g,
            })
            .collect()
    };
    plot(
        &cfg.out.join("pareto_time.png"),
        &format!("{}: fog GPU time vs error (lavapipe)", scene.name),
        "fog stages GPU ms (log)",
        "mean FLIP vs truth",
        &series(&|r| r.fog_gpu_ms.max(0.01)),
        false,
        true,
        true,
    )?;
    plot(
        &cfg.out.join("pareto_rays.png"),
        &format!("{}: fog shadow rays vs error", scene.name),
        "fog shadow rays per frame (log)",
        "mean FLIP vs truth",
        &series(&|r| r.fog_rays.max(1) as f64),
        false,
        true,
        true,
    )?;
    Ok(())
}
