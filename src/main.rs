//! fogcast command line: `render` (offline frames + stats).

use anyhow::Context as _;
use clap::{Args, Parser, Subcommand};
use fogcast::gpu::GpuContext;
use fogcast::render::{Mode, Renderer, Settings};
use fogcast::scene::Scene;
use std::path::PathBuf;
use std::sync::Arc;

#[derive(Parser)]
#[command(name = "fogcast", version, about = "Participating media for many viewers of one scene, streamed to browsers")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Render N viewers placed along the scene's camera path; write one PNG per viewer and stats.json.
    Render(RenderArgs),
}

/// Paper 000's parameters (defaults: the paper's, with trilinear lookup).
#[derive(Args, Clone)]
struct SettingsArgs {
    /// Rendering mode.
    #[arg(long, value_enum, default_value = "shared")]
    mode: Mode,
    /// Shared grid voxel size in metres (default: the scene's).
    #[arg(long)]
    voxel_size: Option<f32>,
    /// Pixels per froxel of the lighting volume.
    #[arg(long, default_value_t = 8)]
    froxel_px: u32,
    /// Depth slices of the lighting volume.
    #[arg(long, default_value_t = 128)]
    slices: u32,
    /// Pixels per froxel of the per-viewer shadow frustum.
    #[arg(long, default_value_t = 16)]
    frustum_px: u32,
    /// Fraction of the depth slices covered by the shadow frustum (0 disables it).
    #[arg(long, default_value_t = 1.0 / 3.0)]
    frustum_fraction: f32,
    /// Update only half the grid per frame (alternating z parity).
    #[arg(long)]
    parity: bool,
    /// Grid lookup: nearest voxel or 8-voxel trilinear.
    #[arg(long, value_enum, default_value = "trilinear")]
    lookup: Lookup,
    /// Temporal jitter + reprojection.
    #[arg(long)]
    temporal: bool,
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum Lookup {
    Nearest,
    Trilinear,
}

impl SettingsArgs {
    fn settings(&self, scene: &Scene) -> Settings {
        Settings {
            mode: self.mode,
            voxel_size_m: self.voxel_size.unwrap_or(scene.render.voxel_size_m),
            froxel_px: self.froxel_px,
            slices: self.slices,
            frustum_px: self.frustum_px,
            frustum_slice_fraction: self.frustum_fraction,
            parity: self.parity,
            trilinear: matches!(self.lookup, Lookup::Trilinear),
            temporal: self.temporal,
        }
    }
}

#[derive(Args)]
struct RenderArgs {
    /// Built-in scene (colonnade, street, islands), a scene .toml, or a .glb/.gltf file.
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
        .with_env_filter(tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "fogcast=info".into()))
        .with_writer(std::io::stderr)
        .init();
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Render(a) => render(a),
    };
    if let Err(e) = result {
        eprintln!("error: {e:#}");
        std::process::exit(1);
    }
}

fn render(a: RenderArgs) -> anyhow::Result<()> {
    anyhow::ensure!((1..=64).contains(&a.viewers), "--viewers {}: must be 1..=64", a.viewers);
    anyhow::ensure!(a.frames >= 1, "--frames must be at least 1");
    let scene = Arc::new(Scene::load(&a.scene)?);
    if scene.dropped_lights > 0 {
        tracing::warn!(dropped = scene.dropped_lights, "more than 8 lights: kept the 8 strongest at the scene centre");
    }
    let settings = a.settings.settings(&scene);
    let ctx = Arc::new(GpuContext::new()?);
    let mut renderer = Renderer::new(ctx, scene.clone(), settings)?;
    std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
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
        fogcast::output::write_png(&a.out.join(format!("viewer_{i:02}.png")), img, frame.width, frame.height)?;
    }
    fogcast::output::write_json(&a.out.join("stats.json"), &frame.stats)?;
    println!("wrote {} images and stats.json to {}", frame.images.len(), a.out.display());
    Ok(())
}
