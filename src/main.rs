//! fogcast command line: `render` (offline frames + stats), `serve` (stream to browsers),
//! `eval` (error vs cost), `bench` (cost vs number of viewers) and `loadgen` (load a
//! running server with WebSocket viewers).

use anyhow::Context as _;
use clap::{Args, Parser, Subcommand};
use fogcast::gpu::GpuContext;
use fogcast::render::{Mode, Renderer, Settings};
use fogcast::scene::{Bvh, Scene};
use fogcast::settings_overrides::SettingsOverrides;
use fogcast::truth::{render_truth, TruthSettings};
use std::path::PathBuf;
use std::sync::Arc;

#[derive(Parser)]
#[command(
    name = "fogcast",
    version,
    about = "Participating media for many viewers of one scene, streamed to browsers"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Render N viewers placed along the scene's camera path; write one PNG per viewer and stats.json.
    Render(RenderArgs),
    /// Stream every viewer's frames to browsers over WebSocket (mono, stereo and split sessions).
    Serve(fogcast::server::ServeArgs),
    /// Measure error and cost: truth, reference and a sweep of shared settings on the same frames.
    Eval(EvalArgs),
    /// Load a running server with N real WebSocket viewers per sweep point; report fps, latency, bandwidth.
    Loadgen(fogcast::loadgen::LoadgenArgs),
    /// Measure how each cost grows with the number of viewers: reference vs shared on the same frames.
    Bench(fogcast::bench::BenchArgs),
}

#[derive(Args)]
struct EvalArgs {
    /// Built-in scene, scene .toml, or .glb/.gltf.
    #[arg(long, default_value = "colonnade")]
    scene: String,
    /// Number of viewers.
    #[arg(long, default_value_t = 2)]
    viewers: usize,
    /// Viewer width in pixels.
    #[arg(long, default_value_t = 320)]
    width: u32,
    /// Viewer height in pixels.
    #[arg(long, default_value_t = 180)]
    height: u32,
    /// Voxel sizes to sweep, metres.
    #[arg(long, value_delimiter = ',', default_value = "4,2,1,0.5,0.25,0.125")]
    voxel_sizes: Vec<f32>,
    /// Walk-in frames per variant (the last one is evaluated).
    #[arg(long, default_value_t = 3)]
    frames: u32,
    /// Ray-march steps per pixel of the truth renderer.
    #[arg(long, default_value_t = TruthSettings::default().steps)]
    truth_steps: u32,
    /// Primary rays per pixel of the truth renderer, stratified over the pixel and
    /// averaged (a box filter, as offline renderers report pixels); 1: the pixel centre.
    /// With `--truth-bounces`: paths per pixel.
    #[arg(long, default_value_t = TruthSettings::default().spp)]
    truth_spp: u32,
    /// Multiple scattering in the truth renderer: path-trace light that scattered up to
    /// this many times (media, smoke, surfaces), the sky as a light and no constant
    /// ambient (0: single scattering).
    #[arg(long, default_value_t = TruthSettings::default().bounces)]
    truth_bounces: u32,
    /// Variable step amplification in the truth renderer's media march (seed 003 Eq.
    /// 4–6): `--truth-steps` becomes the baseline, and segments lengthen (never shorten)
    /// where the density is smooth, the view already dim or the ray far. Fewer samples
    /// for the same steps; per sample more accurate on some scenes, less on others
    /// (docs/decisions.md). Off by default.
    #[arg(long)]
    truth_vsa: bool,
    /// Node spacings of the shared media transmittance volumes to compare besides the
    /// default, metres (0: every froxel and pixel marches its shadow ray).
    #[arg(long, value_delimiter = ',', default_value = "0,0.25,1")]
    transmittance_voxels: Vec<f32>,
    /// Scene time of the evaluated frame, seconds.
    #[arg(long, default_value_t = 2.0)]
    time: f32,
    /// Exponential depth-slice curves to compare besides the default (empty: none).
    #[arg(long, value_delimiter = ',', default_value = "2,6")]
    depth_curves: Vec<f32>,
    /// Smoke scenes only: AVSM node counts to sweep (4, 8, 16) on top of `shared`'s
    /// defaults.
    #[arg(long, value_delimiter = ',', default_value = "4,8,16")]
    avsm_nodes: Vec<u32>,
    /// Smoke scenes only: Simpson steps of the particles' in-scattering to sweep.
    #[arg(long, value_delimiter = ',', default_value = "2,4,8,16")]
    smoke_simpson_steps: Vec<u32>,
    /// Probe spacings of the shared ambient grid to compare, metres, each on top of
    /// `shared`'s defaults (empty: none; issue 16). Against a multiple-scattering truth
    /// (`--truth-bounces`) this measures the grid against the constant `ambient`.
    #[arg(long, value_delimiter = ',')]
    sh_ambient: Vec<f32>,
    /// Output folder (eval.md, eval.csv, eval.json, plots, sample images).
    #[arg(long, default_value = "out/eval")]
    out: PathBuf,
}

/// The renderer's settings: `--mode` (which adds the CPU ground truth) and a flag per
/// setting of `Settings`.
#[derive(Args, Clone)]
struct SettingsArgs {
    /// Rendering mode: the paper's baseline, the paper's method, the engines' shadow-map
    /// froxels (`maps`), or the CPU ground truth.
    #[arg(long, value_enum, default_value_t = Settings::default().mode.into())]
    mode: ModeArg,
    /// Ray-march segments per pixel of mode `truth`.
    #[arg(long, default_value_t = TruthSettings::default().steps)]
    truth_steps: u32,
    /// Primary rays per pixel of mode `truth`, stratified over the pixel and averaged
    /// (with `--truth-bounces`: paths per pixel).
    #[arg(long, default_value_t = TruthSettings::default().spp)]
    truth_spp: u32,
    /// Mode `truth` with multiple scattering: path-trace light that scattered up to this
    /// many times (media, smoke, surfaces), the sky as a light and no constant ambient
    /// (0: single scattering).
    #[arg(long, default_value_t = TruthSettings::default().bounces)]
    truth_bounces: u32,
    /// Mode `truth` with variable step amplification (seed 003 Eq. 4–6): `--truth-steps`
    /// is the baseline segment count and segments lengthen (never shorten) where the
    /// density is smooth, the view already dim or the ray far. Fewer samples for the same
    /// steps; per sample more accurate on some scenes, less on others (stats.json counts
    /// the media samples; docs/decisions.md). Off by default.
    #[arg(long)]
    truth_vsa: bool,
    #[command(flatten)]
    given: SettingsOverrides,
}

#[derive(Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum ModeArg {
    Reference,
    Shared,
    Maps,
    Truth,
}

impl From<Mode> for ModeArg {
    fn from(mode: Mode) -> Self {
        match mode {
            Mode::Reference => ModeArg::Reference,
            Mode::Shared => ModeArg::Shared,
            Mode::Maps => ModeArg::Maps,
        }
    }
}

impl ModeArg {
    /// The renderer's mode (none for `truth`).
    fn renderer(self) -> Option<Mode> {
        match self {
            ModeArg::Reference => Some(Mode::Reference),
            ModeArg::Shared => Some(Mode::Shared),
            ModeArg::Maps => Some(Mode::Maps),
            ModeArg::Truth => None,
        }
    }
}

impl SettingsArgs {
    /// The scene's starting settings with the flags given.
    fn settings(&self, scene: &Scene) -> anyhow::Result<Settings> {
        let mut given = self.given.clone();
        if let Some(mode) = self.mode.renderer() {
            given.set("mode", mode.name())?;
        }
        given.apply(Settings::for_scene(scene))
    }
}

#[derive(Args)]
struct RenderArgs {
    /// Built-in scene (colonnade, street, islands, cloud, chimney, smokehall), a scene .toml, or a .glb/.gltf file.
    #[arg(long, default_value = "colonnade")]
    scene: String,
    /// Number of viewers.
    #[arg(long, default_value_t = 1)]
    viewers: usize,
    /// Viewer width in pixels.
    #[arg(long, default_value_t = 640)]
    width: u32,
    /// Viewer height in pixels.
    #[arg(long, default_value_t = 360)]
    height: u32,
    /// Frames to render (viewers walk along the path); the last one is written.
    #[arg(long, default_value_t = 1)]
    frames: u32,
    /// Scene time of the first frame, seconds.
    #[arg(long, default_value_t = 0.0)]
    time: f32,
    /// Output folder.
    #[arg(long, default_value = "out")]
    out: PathBuf,
    #[command(flatten)]
    settings: SettingsArgs,
}

fn main() {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| "fogcast=info".into()),
        )
        .with_writer(std::io::stderr)
        .init();
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Render(a) => render(a),
        Command::Serve(a) => fogcast::server::serve(&a),
        Command::Eval(a) => eval(a),
        Command::Loadgen(a) => fogcast::loadgen::loadgen(&a),
        Command::Bench(a) => fogcast::bench::bench(&a),
    };
    if let Err(e) = result {
        eprintln!("error: {e:#}");
        std::process::exit(1);
    }
}

fn render(a: RenderArgs) -> anyhow::Result<()> {
    anyhow::ensure!(
        (1..=64).contains(&a.viewers),
        "--viewers {}: must be 1..=64",
        a.viewers
    );
    anyhow::ensure!(a.frames >= 1, "--frames must be at least 1");
    let scene = Arc::new(Scene::load(&a.scene)?);
    if scene.dropped_lights > 0 {
        tracing::warn!(
            dropped = scene.dropped_lights,
            "more than 8 lights: kept the 8 strongest at the scene centre"
        );
    }
    std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    if a.settings.mode == ModeArg::Truth {
        return render_truth_frames(&a, &scene);
    }
    let settings = a.settings.settings(&scene)?;
    let ctx = Arc::new(GpuContext::new()?);
    let mut renderer = Renderer::new(ctx, scene.clone(), settings)?;
    let dt = 1.0 / 30.0;
    let mut last = None;
    for f in 0..a.frames {
        let t = a.time + f as f32 * dt;
        let cameras = scene.camera.viewers(a.viewers, t);
        let frame = renderer.render(&cameras, a.width, a.height, t)?;
        eprintln!(
            "frame {}/{}: {:.0} ms, {} fog rays ({} grid, {} frustum, {} froxel), {} surface rays",
            f + 1,
            a.frames,
            frame.stats.frame_ms,
            frame.stats.rays.fog_total,
            frame.stats.rays.shared_grid,
            frame.stats.rays.shadow_frustum,
            frame.stats.rays.froxel_lighting,
            frame.stats.rays.surface
        );
        last = Some(frame);
    }
    let frame = last.expect("at least one frame");
    for (i, img) in frame.images.iter().enumerate() {
        fogcast::output::write_png(
            &a.out.join(format!("viewer_{i:02}.png")),
            img,
            frame.width,
            frame.height,
        )?;
    }
    fogcast::output::write_json(&a.out.join("stats.json"), &frame.stats)?;
    println!(
        "wrote {} images and stats.json to {}",
        frame.images.len(),
        a.out.display()
    );
    Ok(())
}

/// Prints a progress line to stderr every 2 % (truth renders take minutes).
fn progress_printer(label: &str) -> impl Fn(usize, usize) + Sync + '_ {
    let last = std::sync::atomic::AtomicUsize::new(usize::MAX);
    move |done, total| {
        let pct = done * 50 / total.max(1);
        if last.swap(pct, std::sync::atomic::Ordering::Relaxed) != pct {
            eprint!("\r{}", fogcast::report::progress_line(label, done, total));
            if done == total {
                eprintln!();
            }
        }
    }
}

fn render_truth_frames(a: &RenderArgs, scene: &Scene) -> anyhow::Result<()> {
    let started = std::time::Instant::now();
    let bvh = Bvh::build(&scene.mesh)?;
    let cameras = scene.camera.viewers(a.viewers, a.time);
    let settings = TruthSettings::from_flags(
        a.settings.truth_steps,
        a.settings.truth_spp,
        a.settings.truth_bounces,
        a.settings.truth_vsa,
    );
    settings.validate()?;
    let (images, counts) = render_truth(
        scene,
        &bvh,
        &cameras,
        (a.width, a.height),
        a.time,
        settings,
        &progress_printer("truth"),
    );
    for (i, img) in images.iter().enumerate() {
        fogcast::output::write_png(
            &a.out.join(format!("viewer_{i:02}.png")),
            img,
            a.width,
            a.height,
        )?;
    }
    let stats = serde_json::json!({
        "scene": scene.name, "mode": "truth", "viewers": a.viewers, "width": a.width, "height": a.height,
        "truth": settings, "rays": counts, "frame_ms": started.elapsed().as_secs_f64() * 1e3,
    });
    fogcast::output::write_json(&a.out.join("stats.json"), &stats)?;
    println!(
        "wrote {} images and stats.json to {}",
        images.len(),
        a.out.display()
    );
    Ok(())
}

fn eval(a: EvalArgs) -> anyhow::Result<()> {
    anyhow::ensure!(
        (1..=16).contains(&a.viewers),
        "--viewers {}: must be 1..=16",
        a.viewers
    );
    anyhow::ensure!(
        !a.voxel_sizes.is_empty(),
        "--voxel-sizes needs at least one size"
    );
    let command = std::env::args().collect::<Vec<_>>().join(" ");
    let started = std::time::Instant::now();
    let cfg = fogcast::eval::EvalConfig {
        scene: a.scene,
        viewers: a.viewers,
        width: a.width,
        height: a.height,
        voxel_sizes_m: a.voxel_sizes,
        frames: a.frames,
        truth_steps: a.truth_steps,
        truth_spp: a.truth_spp,
        truth_bounces: a.truth_bounces,
        truth_vsa: a.truth_vsa,
        transmittance_voxels_m: a.transmittance_voxels,
        time_s: a.time,
        depth_curves: a.depth_curves,
        avsm_nodes: a.avsm_nodes,
        smoke_simpson_steps: a.smoke_simpson_steps,
        sh_ambient_m: a.sh_ambient,
        out: a.out.clone(),
        command,
    };
    let rows = fogcast::eval::run(cfg, &|step| {
        eprintln!("eval {:>6.1} s  {step}", started.elapsed().as_secs_f64())
    })?;
    println!(
        "{} variants evaluated in {:.0} s; report in {}",
        rows.len(),
        started.elapsed().as_secs_f64(),
        a.out.join("eval.md").display()
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::CommandFactory as _;

    #[test]
    fn flags_are_consistent() {
        Cli::command().debug_assert();
    }

    #[test]
    fn render_without_flags_renders_the_scenes_settings() {
        let scene = Scene::load("street").unwrap();
        let settings = |args: &[&str]| {
            let cli = Cli::try_parse_from(["fogcast", "render"].iter().chain(args)).unwrap();
            let Command::Render(a) = cli.command else {
                unreachable!("parsed render")
            };
            a.settings.settings(&scene).unwrap()
        };
        assert_eq!(settings(&[]), Settings::for_scene(&scene));
        let mut expected = Settings::for_scene(&scene);
        expected
            .set_all("mode=reference,voxel_size_m=0.5,trilinear=off,parity=on")
            .unwrap();
        assert_eq!(
            settings(&[
                "--mode",
                "reference",
                "--voxel-size",
                "0.5",
                "--lookup",
                "nearest",
                "--parity"
            ]),
            expected
        );
    }
}
