//! `fogcast bench` flags and the progress bar.

use super::{configurations, BenchConfig, Progress};
use crate::render::{Mode, Settings};
use crate::scene::Scene;
use std::io::{IsTerminal as _, Write as _};
use std::path::{Path, PathBuf};

/// Flags of `fogcast bench`.
#[derive(Debug, Clone, clap::Args)]
pub struct BenchArgs {
    /// Built-in scene (colonnade, street, islands, cloud, chimney, smokehall), a scene .toml, or a .glb/.gltf file.
    #[arg(long, default_value = "colonnade")]
    pub scene: String,
    /// Viewer counts of the path scenario (viewers spread along the scene's camera loop).
    #[arg(long, value_delimiter = ',', default_value = "1,2,3,4,6,8,12,16")]
    pub viewers: Vec<usize>,
    /// Modes to run, each with the paper's defaults and the scene's voxel size.
    #[arg(
        long,
        value_enum,
        value_delimiter = ',',
        default_value = "reference,shared,maps"
    )]
    pub modes: Vec<Mode>,
    /// A further `shared` configuration, `name:key=value,…` over its defaults, keyed as
    /// the settings' flags are named (without `--`, `_` for `-`); repeatable.
    #[arg(long = "variant", long_help = variant_help())]
    pub variants: Vec<String>,
    /// Viewer width in pixels.
    #[arg(long, default_value_t = 320)]
    pub width: u32,
    /// Viewer height in pixels.
    #[arg(long, default_value_t = 180)]
    pub height: u32,
    /// Frames rendered at each point before measuring.
    #[arg(long, default_value_t = 2)]
    pub warmup: u32,
    /// Frames measured at each point.
    #[arg(long, default_value_t = 5)]
    pub frames: u32,
    /// Scene time of each point's first frame, seconds.
    #[arg(long, default_value_t = 0.0)]
    pub time: f32,
    /// Fixed-overlap scenario (paper Figure 12): overlaps of neighbouring frustums in
    /// percent, e.g. 10,25,50,75,100 (default: none, skip the scenario).
    #[arg(long, value_delimiter = ',')]
    pub overlap: Vec<f32>,
    /// Viewer counts of the fixed-overlap scenario.
    #[arg(long, value_delimiter = ',', default_value = "2,4,8,16")]
    pub overlap_viewers: Vec<usize>,
    /// Stereo scenario: stereo sessions per point, e.g. 1,2,4,8 (2..16 eyes), heads
    /// along the path; every eye is also rendered as a mono view on the same frame
    /// (default: none, skip the scenario).
    #[arg(long, value_delimiter = ',')]
    pub stereo: Vec<usize>,
    /// Eye distance of the stereo scenario, metres.
    #[arg(long, default_value_t = 0.064)]
    pub eye_distance: f32,
    /// Every configuration's mean FLIP against `truth` (the CPU renderer) on one image:
    /// the path's first viewer at `--time`, at the viewer size divided by this (0: skip).
    ///
    /// `truth` costs pixels × segments × lights shadow rays through the media: at 320×180
    /// street takes 15 minutes on 2 cores, at the default 80×45 about a minute.
    #[arg(long, value_name = "DIVISOR", default_value_t = 4)]
    pub truth: u32,
    /// Output folder [default: out/bench/<scene file stem>].
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Run the whole bench this many times, each run's report in `run-<k>/` of the
    /// output folder, and every acceptance check's value per run in its `checks.md`
    /// (how many runs pass each bound; one run's time ratios move with the machine's load).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=50))]
    pub repeat: u32,
    /// Measure nothing: rewrite the tables and plots of an earlier run from its
    /// `bench.json` in this folder.
    #[arg(long, value_name = "DIR", conflicts_with = "out")]
    pub replot: Option<PathBuf>,
}

fn variant_help() -> String {
    let keys: Vec<&str> = Settings::keys().collect();
    format!(
        "A further `shared` configuration, `name:key=value,…` over its defaults; repeatable.\n\
         Keys: {}.\n\
         Example: --variant 'paper-fast:voxel_size_m=0.5,trilinear=off,parity=on'.",
        keys.join(", ")
    )
}

impl BenchArgs {
    /// The benchmark these flags describe (loads the scene for its voxel size).
    pub fn config(&self, command: String) -> anyhow::Result<BenchConfig> {
        let scene = Scene::load(&self.scene)?;
        let configs = configurations(&self.modes, &self.variants, scene.render.voxel_size_m)?;
        let out = self.out.clone().unwrap_or_else(|| {
            let stem = Path::new(&self.scene)
                .file_stem()
                .map_or_else(|| "scene".into(), |s| s.to_string_lossy().into_owned());
            Path::new("out/bench").join(stem)
        });
        Ok(BenchConfig {
            scene: self.scene.clone(),
            viewers: self.viewers.clone(),
            configs,
            width: self.width,
            height: self.height,
            warmup: self.warmup,
            frames: self.frames,
            time_s: self.time,
            overlaps_pct: self.overlap.clone(),
            overlap_viewers: self.overlap_viewers.clone(),
            stereo_sessions: self.stereo.clone(),
            eye_distance_m: self.eye_distance,
            truth: self.truth,
            out,
            command,
        })
    }
}

/// Runs `fogcast bench` with a progress bar on stderr; prints where the report went.
pub fn bench(args: &BenchArgs) -> anyhow::Result<()> {
    if let Some(dir) = &args.replot {
        let path = dir.join("bench.json");
        let text = std::fs::read_to_string(&path).map_err(|e| {
            anyhow::anyhow!(
                "--replot {}: cannot read {}: {e}",
                dir.display(),
                path.display()
            )
        })?;
        let report: super::BenchReport = serde_json::from_str(&text).map_err(|e| {
            anyhow::anyhow!(
                "--replot {}: {} is not a bench report: {e}",
                dir.display(),
                path.display()
            )
        })?;
        super::report::write(&report, dir)?;
        println!("rewrote the tables and plots in {}", dir.display());
        return Ok(());
    }
    let command = std::env::args().collect::<Vec<_>>().join(" ");
    let cfg = args.config(command)?;
    if args.repeat == 1 {
        run_with_progress(&cfg)?;
        return Ok(());
    }
    let mut runs = Vec::new();
    for k in 1..=args.repeat {
        eprintln!("run {k} of {}", args.repeat);
        let mut c = cfg.clone();
        c.out = cfg.out.join(format!("run-{k}"));
        runs.push(run_with_progress(&c)?);
    }
    let (path, checks) = super::repeat::write(&runs, &cfg)?;
    for (c, bound) in checks.iter().filter_map(|c| Some((c, c.bound?))) {
        let (n, of) = (c.passes(), c.values.len());
        println!("{n} of {of} runs within ≤ {bound}: {}", c.what);
    }
    println!("checks of {} runs in {}", runs.len(), path.display());
    Ok(())
}

/// One bench run of `cfg` with a progress bar on stderr; prints where the report went.
fn run_with_progress(cfg: &BenchConfig) -> anyhow::Result<super::BenchReport> {
    let started = std::time::Instant::now();
    let tty = std::io::stderr().is_terminal();
    let last_step = std::sync::atomic::AtomicUsize::new(usize::MAX);
    let report = super::run(cfg, &|p: &Progress| {
        // On a terminal the bar redraws in place; in a log, a line every 5 %.
        let step = p.done * 20 / p.total.max(1);
        if !tty && last_step.swap(step, std::sync::atomic::Ordering::Relaxed) == step {
            return;
        }
        let elapsed = started.elapsed().as_secs_f64();
        let eta = if p.done > 0 {
            format!(
                "{:.0} s left",
                elapsed / p.done as f64 * (p.total - p.done) as f64
            )
        } else {
            String::new()
        };
        let line = format!(
            "{} {eta:<12} {:<52}",
            crate::report::progress_line("bench", p.done, p.total),
            p.label
        );
        if tty {
            eprint!("\r{line}");
        } else {
            eprintln!("{}", line.trim_end());
        }
        let _ = std::io::stderr().flush();
    })?;
    if tty {
        eprintln!();
    }
    println!(
        "{} points on {} in {:.0} s; report in {}",
        report.points.len(),
        report.adapter,
        report.elapsed_s,
        cfg.out.join("bench.md").display()
    );
    Ok(report)
}
