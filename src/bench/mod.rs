//! `fogcast bench`: how each cost grows with the number of viewers (paper 000 §4.2,
//! Tables 1–3, Figures 11–14).
//!
//! For every viewer count, every configuration (`reference`, `shared`, `maps`, variants)
//! renders the same cameras at the same scene times; the configurations take turns frame
//! by frame (the order reversed every other frame) so that noise from other processes
//! falls on all of them alike. Each measured frame comes right after an unmeasured
//! lead-in frame of the same renderer one time step earlier, so that it follows its own
//! renderer's frame as in a server, not another configuration's (after a `reference`
//! frame, lavapipe ran the next frame's G-buffer up to 1.3× slower). Before the first
//! point every renderer draws the widest point's cameras for the warm-up steps,
//! unmeasured, so that every point finds its world's caches as a running server would,
//! not still filling them. Camera scenarios:
//!
//! - **path**: viewers spread evenly along the scene's camera loop, all walking it, as
//!   players spread over a level would be ([`crate::scene::CameraPath::viewers`]);
//! - **overlap** (paper Figure 12): one camera on the path, duplicated and yawed in place
//!   so that neighbouring frustums share a fixed fraction of their field of view
//!   ([`fixed_overlap`]);
//! - **stereo** (issue 16): heads along the path, each a stereo session of two eyes in
//!   one frame, and the same eyes again as mono views on the same frame, for the cost
//!   and the error of coupled stereo.
//!
//! Per point it records the median and range of each stage's GPU time and of the whole
//! frame, shadow rays per stage, grid voxels updated, memory, and the mean FLIP of every
//! other configuration against `reference` on the same frames, and (on one image, so that
//! the CPU renderer stays quick) every configuration's FLIP against `truth`; [`report`]
//! writes JSON, CSV, markdown and plots.

mod cli;
pub mod repeat;
pub mod report;
mod variant;

pub use cli::{bench, BenchArgs};
pub use variant::{configurations, mode_variants, parse_variant, BenchVariant};

use crate::gpu::GpuContext;
use crate::metrics::compare;
use crate::render::{
    stereo_eyes, FrameOutput, FrameTarget, Mode, RayCounts, Renderer, Stage, ViewerId,
};
use crate::scene::{Bvh, Camera, Scene};
use crate::truth::{render_truth, TruthSettings};
use glam::{Quat, Vec3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::path::PathBuf;
use std::sync::Arc;

/// Whether the stage called `name` is one of paper 000 §3.1's fog stages (what its
/// tables time; [`Stage::is_fog`]). The others (`gbuffer`, `shadow_maps`, `composite`)
/// cost the same in every mode.
pub fn is_fog_stage(name: &str) -> bool {
    Stage::from_name(name).is_some_and(Stage::is_fog)
}

/// The fog stages' names, comma-separated (for reports).
pub fn fog_stage_list() -> String {
    Stage::fog_names().collect::<Vec<_>>().join(", ")
}

/// Scene time between consecutive frames: a 30 fps stream.
pub const FRAME_DT_S: f32 = 1.0 / 30.0;

/// What to measure.
#[derive(Debug, Clone)]
pub struct BenchConfig {
    /// Scene name or path.
    pub scene: String,
    /// Viewer counts of the path scenario (empty: skip it).
    pub viewers: Vec<usize>,
    /// Configurations, each rendered at every point; FLIP is measured against the one
    /// named `reference` when there is one.
    pub configs: Vec<BenchVariant>,
    /// Viewer width, pixels.
    pub width: u32,
    /// Viewer height, pixels.
    pub height: u32,
    /// Frames rendered before measuring at each point (shader compilation, parity).
    pub warmup: u32,
    /// Frames measured at each point.
    pub frames: u32,
    /// Scene time of the first frame of every point, seconds.
    pub time_s: f32,
    /// Overlaps of the fixed-overlap scenario, percent (empty: skip it).
    pub overlaps_pct: Vec<f32>,
    /// Viewer counts of the fixed-overlap scenario.
    pub overlap_viewers: Vec<usize>,
    /// Stereo sessions of the stereo scenario (empty: skip it): heads spread along the
    /// path, two eyes each, every eye also rendered as a mono view (issue 16).
    pub stereo_sessions: Vec<usize>,
    /// Eye distance of the stereo scenario, metres.
    pub eye_distance_m: f32,
    /// Measure every configuration's error against `truth` (src/truth/, on the CPU) on
    /// one image, the path's first viewer at `time_s`, of `width / truth` ×
    /// `height / truth` pixels (0: not at all). At full size `truth` takes 15 minutes on
    /// street (six lights in windy fog) on 2 cores.
    pub truth: u32,
    /// Output folder.
    pub out: PathBuf,
    /// The command line, recorded in the report.
    pub command: String,
}

/// How the cameras of a point are placed.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", tag = "kind")]
pub enum Scenario {
    /// Viewers spread evenly along the scene's camera loop, walking it.
    Path,
    /// One camera on the loop duplicated and yawed in place; neighbours share
    /// `overlap_pct` % of the horizontal field of view.
    Overlap {
        /// Overlap of neighbouring frustums, percent.
        overlap_pct: f32,
    },
    /// Stereo sessions: heads spread along the loop as in `Path`, each a frame of two
    /// eyes `eye_distance_m` apart (coupled stereo shares their froxel volume).
    Stereo {
        /// Eye distance, metres.
        eye_distance_m: f32,
    },
    /// The `Stereo` scenario's eyes, each rendered as a mono view of its own.
    StereoEyesAlone {
        /// Eye distance, metres.
        eye_distance_m: f32,
    },
}

impl Scenario {
    /// The cameras of `n` viewers at scene time `time_s` (stereo: `n` eyes, left and
    /// right of each head in turn).
    pub fn cameras(&self, scene: &Scene, n: usize, time_s: f32, aspect: f32) -> Vec<Camera> {
        match *self {
            Scenario::Path => scene.camera.viewers(n, time_s),
            Scenario::Stereo { eye_distance_m } | Scenario::StereoEyesAlone { eye_distance_m } => {
                scene
                    .camera
                    .viewers(n / 2, time_s)
                    .into_iter()
                    .flat_map(|head| stereo_eyes(head, eye_distance_m))
                    .collect()
            }
            Scenario::Overlap { overlap_pct } => {
                let base = scene.camera.viewers(1, time_s)[0];
                fixed_overlap(base, n, overlap_pct / 100.0, aspect)
            }
        }
    }

    fn label(&self) -> String {
        match self {
            Scenario::Path => "path".into(),
            Scenario::Overlap { overlap_pct } => format!("overlap {overlap_pct}%"),
            Scenario::Stereo { eye_distance_m } => format!("stereo {eye_distance_m} m"),
            Scenario::StereoEyesAlone { eye_distance_m } => {
                format!("eyes alone {eye_distance_m} m")
            }
        }
    }
}

/// `n` copies of `base` yawed about the world up axis through its eye, `Δ = (1 − overlap)
/// · H` apart (H: horizontal field of view) and centred on `base`'s direction. Two
/// neighbours then share the fraction `overlap` of their horizontal view angle: with
/// 1.0 all cameras coincide, with 0.0 their frustums only touch. With many cameras and a
/// small overlap the fan wraps past 360° and non-neighbours overlap too, as they would in
/// paper 000's Figure 12 setup.
pub fn fixed_overlap(base: Camera, n: usize, overlap: f32, aspect: f32) -> Vec<Camera> {
    let horizontal_fov = 2.0 * ((base.fov_y * 0.5).tan() * aspect).atan();
    let step = (1.0 - overlap.clamp(0.0, 1.0)) * horizontal_fov;
    (0..n)
        .map(|i| {
            // Camera i + 1 is to the right of camera i (a negative turn about +y).
            let yaw = (i as f32 - (n as f32 - 1.0) * 0.5) * step;
            Camera::new(
                base.position,
                Quat::from_axis_angle(Vec3::Y, -yaw) * base.forward,
                base.fov_y,
            )
        })
        .collect()
}

/// Median and range of a measured quantity over the measured frames.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Spread {
    /// Median (the upper one of an even count).
    pub median: f64,
    /// Smallest value.
    pub min: f64,
    /// Largest value.
    pub max: f64,
}

impl Spread {
    /// The spread of `values` (all zero when empty).
    pub fn of(values: &[f64]) -> Spread {
        if values.is_empty() {
            return Spread {
                median: 0.0,
                min: 0.0,
                max: 0.0,
            };
        }
        let mut v = values.to_vec();
        v.sort_by(f64::total_cmp);
        Spread {
            median: v[v.len() / 2],
            min: v[0],
            max: v[v.len() - 1],
        }
    }
}

/// GPU time of one stage over the measured frames.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StageSpread {
    /// Stage name (`gbuffer`, `shared_grid`, `shadow_frustum`, `froxel_lighting`,
    /// `volume_integration`, `composite`).
    pub stage: String,
    /// GPU milliseconds.
    pub gpu_ms: Spread,
}

/// GPU memory of a point, bytes.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct MemoryBytes {
    /// Resources every viewer shares (scene, BVH, shared grid).
    pub shared: u64,
    /// Resources of one viewer (froxel volumes, shadow frustum, G-buffer, image).
    pub per_viewer: u64,
    /// shared + viewers × per_viewer.
    pub total: u64,
}

/// Mean FLIP against `reference` over every viewer of every measured frame.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FlipSummary {
    /// Mean over all images of the per-image mean FLIP.
    pub mean: f64,
    /// Largest per-image mean FLIP (the worst viewer in the worst frame).
    pub max: f64,
    /// Images compared (viewers × measured frames).
    pub images: usize,
}

/// Everything measured for one configuration at one viewer count of one scenario.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BenchPoint {
    /// Camera placement.
    pub scenario: Scenario,
    /// Number of viewers.
    pub viewers: usize,
    /// Configuration name.
    pub config: String,
    /// Its rendering mode.
    pub mode: Mode,
    /// Frames measured.
    pub frames: u32,
    /// GPU time of the whole frame: the sum of the stage times.
    pub frame_gpu_ms: Spread,
    /// GPU time of the fog stages ([`is_fog_stage`]) alone.
    pub fog_gpu_ms: Spread,
    /// Host time from upload to readback (includes the readback and any stall).
    pub frame_host_ms: Spread,
    /// This frame's GPU time / `reference`'s on the same frame, over the measured frames
    /// (paired, so load from other processes that drifts over a point cancels out).
    pub frame_gpu_vs_reference: Option<Spread>,
    /// GPU time of every stage that ran.
    pub stages: Vec<StageSpread>,
    /// Shadow rays per stage, mean per measured frame.
    pub rays: RayCounts,
    /// Shared-grid voxels traced (updated), mean per measured frame.
    pub voxels_updated: u64,
    /// Froxels lit with media, mean per measured frame (a coupled stereo pair lights one
    /// volume).
    #[serde(default)]
    pub froxels_with_media: u64,
    /// G-buffer triangles drawn, summed over views, and those in the clusters the views'
    /// frustums touch (what an unculled draw rasterises); means per measured frame.
    #[serde(default)]
    pub raster_triangles: (u64, u64),
    /// Shared grid dimensions (zero without a grid).
    pub grid_dims: [u32; 3],
    /// GPU memory.
    pub memory: MemoryBytes,
    /// Against `reference` on the same frames (none for `reference` itself, or when
    /// `reference` is not run).
    pub flip_vs_reference: Option<FlipSummary>,
    /// Stereo points: each eye against the same eye rendered as a mono view by the same
    /// configuration on the same frame (issue 16's coupled-stereo bound).
    #[serde(default)]
    pub flip_vs_eyes_alone: Option<FlipSummary>,
    /// Stereo points: this frame's GPU time / that of the first eye rendered alone as
    /// one mono view, back to back on the same frame (paired, as
    /// `frame_gpu_vs_reference`; issue 16 bounds it at one session).
    #[serde(default)]
    pub frame_gpu_vs_one_eye: Option<Spread>,
}

/// A finished benchmark: what ran, where, and every point.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BenchReport {
    /// Scene name.
    pub scene: String,
    /// Adapter name and driver that rendered.
    pub adapter: String,
    /// CPU threads available to this process.
    pub cpu_threads: usize,
    /// The machine's 1-minute load average when the benchmark started and ended (Linux;
    /// above `cpu_threads` other processes were competing for the CPU lavapipe runs on).
    pub load_average: Option<[f64; 2]>,
    /// Viewer width, pixels.
    pub width: u32,
    /// Viewer height, pixels.
    pub height: u32,
    /// Warm-up frames per point.
    pub warmup: u32,
    /// Measured frames per point.
    pub frames: u32,
    /// Scene time of each point's first frame, seconds.
    pub time_s: f32,
    /// Scene time between frames, seconds.
    pub frame_dt_s: f32,
    /// Whether the GPU times come from timestamp queries (else they are empty).
    pub timestamps: bool,
    /// Which frames FLIP is measured on.
    pub flip_frames: String,
    /// Every configuration against `truth` on one image (none: not measured).
    #[serde(default)]
    pub truth: Option<TruthComparison>,
    /// The configurations, in the order they were run.
    pub configs: Vec<BenchVariant>,
    /// Every point, the path scenario first.
    pub points: Vec<BenchPoint>,
    /// The command line.
    pub command: String,
    /// Wall time of the whole benchmark, seconds.
    pub elapsed_s: f64,
}

/// Where a running benchmark is.
#[derive(Debug, Clone)]
pub struct Progress {
    /// Viewer-frames rendered so far (a frame of n viewers counts n).
    pub done: usize,
    /// Viewer-frames in the whole benchmark.
    pub total: usize,
    /// What is rendering now.
    pub label: String,
}

/// The frames one configuration rendered at one point, reduced as they arrive.
#[derive(Default)]
struct Samples {
    frame_gpu_ms: Vec<f64>,
    fog_gpu_ms: Vec<f64>,
    frame_host_ms: Vec<f64>,
    stage_ms: Vec<(String, Vec<f64>)>,
    rays: Vec<RayCounts>,
    voxels: Vec<u64>,
    froxels: Vec<u64>,
    triangles: Vec<(u64, u64)>,
    flip: Vec<f64>,
    flip_alone: Vec<f64>,
    vs_one_eye: Vec<f64>,
    vs_reference: Vec<f64>,
    last: Option<FrameOutput>,
}

impl Samples {
    fn add(&mut self, out: FrameOutput) {
        let s = &out.stats;
        self.frame_gpu_ms.push(frame_gpu_ms(&out));
        self.fog_gpu_ms.push(
            s.stage_gpu_ms
                .iter()
                .filter(|t| is_fog_stage(&t.stage))
                .map(|t| t.gpu_ms)
                .sum(),
        );
        self.frame_host_ms.push(s.frame_ms);
        for t in &s.stage_gpu_ms {
            match self.stage_ms.iter_mut().find(|(n, _)| *n == t.stage) {
                Some((_, v)) => v.push(t.gpu_ms),
                None => self.stage_ms.push((t.stage.clone(), vec![t.gpu_ms])),
            }
        }
        self.rays.push(s.rays);
        self.voxels.push(s.voxels_traced);
        self.froxels.push(s.froxels_with_media);
        self.triangles
            .push((s.raster_triangles, s.raster_triangles_in_clusters));
        self.last = Some(out);
    }

    fn point(self, scenario: Scenario, viewers: usize, v: &BenchVariant) -> BenchPoint {
        let n = self.rays.len().max(1) as u64;
        let mean = |f: fn(&RayCounts) -> u64| self.rays.iter().map(f).sum::<u64>() / n;
        let stats = self.last.as_ref().map(|o| &o.stats);
        BenchPoint {
            scenario,
            viewers,
            config: v.name.clone(),
            mode: v.settings.mode,
            frames: self.rays.len() as u32,
            frame_gpu_ms: Spread::of(&self.frame_gpu_ms),
            fog_gpu_ms: Spread::of(&self.fog_gpu_ms),
            frame_host_ms: Spread::of(&self.frame_host_ms),
            frame_gpu_vs_reference: (!self.vs_reference.is_empty())
                .then(|| Spread::of(&self.vs_reference)),
            stages: self
                .stage_ms
                .iter()
                .map(|(stage, ms)| StageSpread {
                    stage: stage.clone(),
                    gpu_ms: Spread::of(ms),
                })
                .collect(),
            rays: RayCounts {
                shared_grid: mean(|r| r.shared_grid),
                shadow_frustum: mean(|r| r.shadow_frustum),
                froxel_lighting: mean(|r| r.froxel_lighting),
                surface: mean(|r| r.surface),
                fog_total: mean(|r| r.fog_total),
                total: mean(|r| r.total),
            },
            voxels_updated: self.voxels.iter().sum::<u64>() / n,
            froxels_with_media: self.froxels.iter().sum::<u64>() / n,
            raster_triangles: (
                self.triangles.iter().map(|t| t.0).sum::<u64>() / n,
                self.triangles.iter().map(|t| t.1).sum::<u64>() / n,
            ),
            grid_dims: stats.map_or([0; 3], |s| s.grid_dims),
            memory: stats.map_or(
                MemoryBytes {
                    shared: 0,
                    per_viewer: 0,
                    total: 0,
                },
                |s| MemoryBytes {
                    shared: s.memory.shared_total,
                    per_viewer: s.memory.per_viewer_total,
                    total: s.memory.total,
                },
            ),
            flip_vs_reference: FlipSummary::of(&self.flip),
            flip_vs_eyes_alone: FlipSummary::of(&self.flip_alone),
            frame_gpu_vs_one_eye: (!self.vs_one_eye.is_empty())
                .then(|| Spread::of(&self.vs_one_eye)),
        }
    }
}

impl FlipSummary {
    /// The summary of per-image means (none when empty).
    fn of(flip: &[f64]) -> Option<FlipSummary> {
        (!flip.is_empty()).then(|| FlipSummary {
            mean: flip.iter().sum::<f64>() / flip.len() as f64,
            max: flip.iter().copied().fold(0.0, f64::max),
            images: flip.len(),
        })
    }
}

/// The time step (in frames of [`FRAME_DT_S`]) of a point's `k`-th frame: warm-up frames
/// take one step each, every measured frame two, its lead-in frame the first of them.
fn frame_step(k: usize, warmup: usize) -> usize {
    if k < warmup {
        k
    } else {
        warmup + 2 * (k - warmup) + 1
    }
}

/// One frame of `cams` under `scenario`: stereo pairs as one frame of two eyes each
/// (split back into one image per eye), every other camera as a mono view.
fn render_point(
    r: &mut Renderer,
    scenario: Scenario,
    cams: &[Camera],
    (width, height): (u32, u32),
    time_s: f32,
) -> anyhow::Result<FrameOutput> {
    let Scenario::Stereo { .. } = scenario else {
        return r.render(cams, width, height, time_s);
    };
    let targets: Vec<FrameTarget> = cams
        .chunks(2)
        .enumerate()
        .map(|(i, eyes)| FrameTarget::tiled(2 * i as ViewerId, eyes, (width, height), 2))
        .collect();
    let out = r.render_targets(&targets, time_s)?;
    let images = targets
        .iter()
        .zip(&out.images)
        .flat_map(|(t, frame)| (0..t.views.len()).map(|k| t.tile(frame, k)))
        .collect();
    Ok(FrameOutput {
        width,
        height,
        images,
        stats: out.stats,
    })
}

/// Every configuration's error against `truth` on one image.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TruthComparison {
    /// Image width, pixels (the bench's divided by `--truth`).
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Scene time, seconds (the path's first viewer).
    pub time_s: f32,
    /// Ray-march segments of `truth`.
    pub steps: u32,
    /// CPU seconds `truth` took.
    pub truth_s: f64,
    /// Per configuration, in run order: (name, mean FLIP against `truth`) of its second
    /// frame at that time (the first warms caches at the new size).
    pub flip: Vec<(String, f64)>,
}

/// Renders the path's first viewer at `cfg.time_s` with `truth` and with every
/// configuration, at the bench's size divided by `cfg.truth`; runs after every point,
/// so the new view size disturbs no measurement.
fn against_truth(
    cfg: &BenchConfig,
    scene: &Arc<Scene>,
    bvh: &Bvh,
    renderers: &mut [Renderer],
) -> anyhow::Result<TruthComparison> {
    let (w, h) = (
        (cfg.width / cfg.truth).max(8),
        (cfg.height / cfg.truth).max(8),
    );
    let cams = Scenario::Path.cameras(scene, 1, cfg.time_s, w as f32 / h as f32);
    let settings = TruthSettings::default();
    let started = std::time::Instant::now();
    let (truth, _) = render_truth(scene, bvh, &cams, (w, h), cfg.time_s, settings, &|_, _| {});
    let truth_s = started.elapsed().as_secs_f64();
    let mut flip = Vec::new();
    for (r, v) in renderers.iter_mut().zip(&cfg.configs) {
        r.render(&cams, w, h, cfg.time_s)?;
        let out = r.render(&cams, w, h, cfg.time_s)?;
        flip.push((
            v.name.clone(),
            compare(&truth[0], &out.images[0], w, h)?.flip_mean,
        ));
    }
    Ok(TruthComparison {
        width: w,
        height: h,
        time_s: cfg.time_s,
        steps: settings.steps,
        truth_s,
        flip,
    })
}

/// Every configuration's frame `outputs` (all rendered) against configuration `r`'s,
/// into `samples`: FLIP per viewer and the paired time ratio.
fn against_reference(
    r: usize,
    outputs: &[Option<FrameOutput>],
    samples: &mut [Samples],
) -> anyhow::Result<()> {
    let ref_out = outputs[r].as_ref().expect("rendered");
    for (i, o) in outputs.iter().enumerate() {
        if i != r {
            let o = o.as_ref().expect("rendered");
            samples[i].flip.extend(flip_per_viewer(ref_out, o)?);
            let base = frame_gpu_ms(ref_out);
            if base > 0.0 {
                samples[i].vs_reference.push(frame_gpu_ms(o) / base);
            }
        }
    }
    Ok(())
}

/// A frame's GPU time: the sum of its stages.
fn frame_gpu_ms(out: &FrameOutput) -> f64 {
    out.stats.stage_gpu_ms.iter().map(|t| t.gpu_ms).sum()
}

/// Per-image mean FLIP of `test` against `reference`, viewer by viewer.
fn flip_per_viewer(reference: &FrameOutput, test: &FrameOutput) -> anyhow::Result<Vec<f64>> {
    reference
        .images
        .par_iter()
        .zip(&test.images)
        .map(|(r, t)| Ok(compare(r, t, reference.width, reference.height)?.flip_mean))
        .collect()
}

fn check(cfg: &BenchConfig) -> anyhow::Result<()> {
    let counts = |flag: &str, v: &[usize]| -> anyhow::Result<()> {
        for (i, &n) in v.iter().enumerate() {
            anyhow::ensure!((1..=64).contains(&n), "{flag} {n}: must be 1..=64");
            anyhow::ensure!(!v[..i].contains(&n), "{flag}: {n} is given twice");
        }
        Ok(())
    };
    counts("--viewers", &cfg.viewers)?;
    counts("--overlap-viewers", &cfg.overlap_viewers)?;
    anyhow::ensure!(
        (8..=4096).contains(&cfg.width) && (8..=4096).contains(&cfg.height),
        "--width {} --height {}: each must be 8..=4096",
        cfg.width,
        cfg.height
    );
    anyhow::ensure!(
        (1..=10_000).contains(&cfg.frames),
        "--frames {}: must be 1..=10000",
        cfg.frames
    );
    anyhow::ensure!(
        cfg.warmup <= 10_000,
        "--warmup {}: must be at most 10000",
        cfg.warmup
    );
    anyhow::ensure!(
        cfg.time_s.is_finite(),
        "--time {}: must be finite",
        cfg.time_s
    );
    for (i, &o) in cfg.overlaps_pct.iter().enumerate() {
        anyhow::ensure!(
            o.is_finite() && (0.0..=100.0).contains(&o),
            "--overlap {o}: must be a percentage, 0..=100"
        );
        anyhow::ensure!(
            !cfg.overlaps_pct[..i].contains(&o),
            "--overlap: {o} is given twice"
        );
    }
    anyhow::ensure!(
        cfg.overlaps_pct.is_empty() || !cfg.overlap_viewers.is_empty(),
        "--overlap-viewers: give at least one viewer count for --overlap"
    );
    counts("--stereo", &cfg.stereo_sessions)?;
    anyhow::ensure!(
        cfg.stereo_sessions.iter().all(|&n| n <= 32),
        "--stereo: at most 32 sessions (64 eyes)"
    );
    anyhow::ensure!(
        cfg.eye_distance_m.is_finite() && (0.0..=1.0).contains(&cfg.eye_distance_m),
        "--eye-distance {}: must be 0..=1 metres",
        cfg.eye_distance_m
    );
    anyhow::ensure!(
        !cfg.viewers.is_empty() || !cfg.overlaps_pct.is_empty() || !cfg.stereo_sessions.is_empty(),
        "nothing to measure: --viewers is empty and no --overlap or --stereo is given"
    );
    anyhow::ensure!(!cfg.configs.is_empty(), "no configuration to run");
    for v in &cfg.configs {
        v.settings
            .validate()
            .map_err(|e| anyhow::anyhow!("configuration '{}': {e:#}", v.name))?;
    }
    Ok(())
}

/// Runs the benchmark, writes `bench.json`, `bench.csv`, `bench.md` and the plots to
/// `cfg.out`, and returns the report.
pub fn run(cfg: &BenchConfig, progress: &dyn Fn(&Progress)) -> anyhow::Result<BenchReport> {
    check(cfg)?;
    let started = std::time::Instant::now();
    let load_at_start = crate::report::load_average();
    let scene = Arc::new(Scene::load(&cfg.scene)?);
    std::fs::create_dir_all(&cfg.out)
        .map_err(|e| anyhow::anyhow!("--out {}: cannot create it: {e}", cfg.out.display()))?;
    let ctx = Arc::new(GpuContext::new()?);
    let bvh = Bvh::build(&scene.mesh)?;
    let renderers_for = |what: &str| {
        cfg.configs
            .iter()
            .map(|v| {
                Renderer::with_bvh(ctx.clone(), scene.clone(), &bvh, v.settings)
                    .map_err(|e| e.context(format!("configuration '{}'{what}", v.name)))
            })
            .collect::<anyhow::Result<Vec<_>>>()
    };
    let mut renderers = renderers_for("")?;
    // The stereo scenario's baselines walk the path in renderers of their own, so that
    // each world's caches hold what its own viewers saw (a renderer that had just drawn
    // the stereo frame would find this frame's grid already traced).
    let (mut alone_renderers, mut one_eye_renderers) = if cfg.stereo_sessions.is_empty() {
        (Vec::new(), Vec::new())
    } else {
        (renderers_for(", eyes alone")?, renderers_for(", one eye")?)
    };
    let reference = cfg.configs.iter().position(|v| v.name == "reference");

    let mut plan: Vec<(Scenario, usize)> =
        cfg.viewers.iter().map(|&n| (Scenario::Path, n)).collect();
    for &overlap_pct in &cfg.overlaps_pct {
        for &n in &cfg.overlap_viewers {
            plan.push((Scenario::Overlap { overlap_pct }, n));
        }
    }
    let stereo = Scenario::Stereo {
        eye_distance_m: cfg.eye_distance_m,
    };
    let eyes_alone = Scenario::StereoEyesAlone {
        eye_distance_m: cfg.eye_distance_m,
    };
    for &sessions in &cfg.stereo_sessions {
        plan.push((stereo, 2 * sessions));
    }
    let frames_per_point = (cfg.warmup + cfg.frames) as usize;
    // Every renderer first walks the widest point's path cameras through the warm-up
    // steps, unmeasured, so that every point finds its world as a server that has been
    // streaming finds it: its caches holding what viewers along the path saw. Without
    // it the first point (one viewer, or the stereo scenario's baselines) measured a
    // world still filling its cache while later points measured a full one, which made
    // the marginal viewer and the stereo ratio look cheaper than they are
    // (docs/decisions.md, "Every renderer starts from a primed world").
    let prime_viewers = plan.iter().map(|&(_, n)| n).max().unwrap_or(0);
    let prime_renderers = renderers.len() + alone_renderers.len() + one_eye_renderers.len();
    let total: usize = plan
        .iter()
        .map(|(s, n)| {
            // Coupled, each eye alone, and the first eye alone once more.
            let viewer_renders = if *s == stereo { 2 * n + 1 } else { *n };
            // Every measured frame follows a lead-in frame of its own renderer.
            viewer_renders * (frames_per_point + cfg.frames as usize) * cfg.configs.len()
        })
        .sum::<usize>()
        + prime_renderers * prime_viewers * cfg.warmup as usize;
    let aspect = cfg.width as f32 / cfg.height as f32;
    let mut done = 0;
    let size = (cfg.width, cfg.height);
    for r in renderers
        .iter_mut()
        .chain(&mut alone_renderers)
        .chain(&mut one_eye_renderers)
    {
        for k in 0..cfg.warmup as usize {
            progress(&Progress {
                done,
                total,
                label: format!(
                    "priming the world: {prime_viewers} viewer(s), frame {}",
                    k + 1
                ),
            });
            let t = cfg.time_s + k as f32 * FRAME_DT_S;
            let cams = Scenario::Path.cameras(&scene, prime_viewers, t, aspect);
            render_point(r, Scenario::Path, &cams, size, t)
                .map_err(|e| e.context("priming the world"))?;
            done += prime_viewers;
        }
    }
    let mut points = Vec::new();
    for &(scenario, n) in &plan {
        let mut samples: Vec<Samples> = cfg.configs.iter().map(|_| Samples::default()).collect();
        let mut alone_samples: Vec<Samples> =
            cfg.configs.iter().map(|_| Samples::default()).collect();
        for k in 0..frames_per_point {
            // A measured frame follows a frame of its own renderer one step earlier,
            // as in a server, where one renderer draws frame after frame: the frame
            // before it, not the other configuration's, is what it inherits
            // (docs/decisions.md, "Each measured frame follows its own renderer's").
            // Each renderer sees one unbroken 30 fps walk: the warm-up frames, then
            // lead-in and measured frames in turn.
            let measured = k >= cfg.warmup as usize;
            let t = cfg.time_s + frame_step(k, cfg.warmup as usize) as f32 * FRAME_DT_S;
            let cams = scenario.cameras(&scene, n, t, aspect);
            let t_before = t - FRAME_DT_S;
            let cams_before = scenario.cameras(&scene, n, t_before, aspect);
            let lead_in = |r: &mut Renderer, scenario: Scenario, cams: &[Camera]| {
                if measured {
                    render_point(r, scenario, cams, size, t_before)?;
                }
                anyhow::Ok(())
            };
            let mut order: Vec<usize> = (0..cfg.configs.len()).collect();
            if k % 2 == 1 {
                order.reverse();
            }
            let mut outputs: Vec<Option<FrameOutput>> = cfg.configs.iter().map(|_| None).collect();
            let mut alone: Vec<Option<FrameOutput>> = cfg.configs.iter().map(|_| None).collect();
            let mut one_eye = vec![0.0; cfg.configs.len()];
            for i in order {
                progress(&Progress {
                    done,
                    total,
                    label: format!(
                        "{} {n} viewer(s), {} frame {}/{frames_per_point}",
                        scenario.label(),
                        cfg.configs[i].name,
                        k + 1
                    ),
                });
                let out = lead_in(&mut renderers[i], scenario, &cams_before)
                    .and_then(|()| render_point(&mut renderers[i], scenario, &cams, size, t))
                    .map_err(|e| {
                        e.context(format!(
                            "{} with {n} viewer(s), configuration '{}'",
                            scenario.label(),
                            cfg.configs[i].name
                        ))
                    })?;
                outputs[i] = Some(out);
                done += if measured { 2 * n } else { n };
                if scenario == stereo {
                    let alone_r = &mut alone_renderers[i];
                    lead_in(alone_r, eyes_alone, &cams_before)?;
                    alone[i] = Some(render_point(alone_r, eyes_alone, &cams, size, t)?);
                    let one_r = &mut one_eye_renderers[i];
                    lead_in(one_r, eyes_alone, &cams_before[..1])?;
                    let one = render_point(one_r, eyes_alone, &cams[..1], size, t)?;
                    one_eye[i] = frame_gpu_ms(&one);
                    done += if measured { 2 * (n + 1) } else { n + 1 };
                }
            }
            if k < cfg.warmup as usize {
                continue;
            }
            if let Some(r) = reference {
                against_reference(r, &outputs, &mut samples)?;
                if scenario == stereo {
                    against_reference(r, &alone, &mut alone_samples)?;
                }
            }
            for (((s, o), (a, sa)), one) in samples
                .iter_mut()
                .zip(outputs)
                .zip(alone.into_iter().zip(alone_samples.iter_mut()))
                .zip(one_eye)
            {
                let o = o.expect("rendered above");
                if one > 0.0 {
                    s.vs_one_eye.push(frame_gpu_ms(&o) / one);
                }
                if let Some(a) = a {
                    s.flip_alone.extend(flip_per_viewer(&a, &o)?);
                    sa.add(a);
                }
                s.add(o);
            }
        }
        for (s, v) in samples.into_iter().zip(&cfg.configs) {
            points.push(s.point(scenario, n, v));
        }
        if scenario == stereo {
            for (s, v) in alone_samples.into_iter().zip(&cfg.configs) {
                points.push(s.point(eyes_alone, n, v));
            }
        }
    }
    let truth = if cfg.truth > 0 {
        progress(&Progress {
            done,
            total,
            label: "truth (CPU), one image".into(),
        });
        Some(against_truth(cfg, &scene, &bvh, &mut renderers)?)
    } else {
        None
    };
    progress(&Progress {
        done,
        total,
        label: "writing the report".into(),
    });
    let report = BenchReport {
        scene: scene.name.clone(),
        adapter: GpuContext::last_adapter_name(),
        cpu_threads: std::thread::available_parallelism().map_or(1, |n| n.get()),
        load_average: load_at_start
            .zip(crate::report::load_average())
            .map(|(a, b)| [a, b]),
        width: cfg.width,
        height: cfg.height,
        warmup: cfg.warmup,
        frames: cfg.frames,
        time_s: cfg.time_s,
        frame_dt_s: FRAME_DT_S,
        timestamps: ctx.has_timestamps,
        flip_frames: "every measured frame (warm-up frames excluded), every viewer".into(),
        truth,
        configs: cfg.configs.clone(),
        points,
        command: cfg.command.clone(),
        elapsed_s: started.elapsed().as_secs_f64(),
    };
    report::write(&report, &cfg.out)?;
    Ok(report)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_renderer_walks_unbroken_steps_through_lead_ins() {
        for warmup in [0, 1, 2] {
            // What one renderer draws, in order: each warm-up frame, then each measured
            // frame's lead-in (one step before it) and the measured frame.
            let mut steps = Vec::new();
            for k in 0..warmup + 4 {
                let step = frame_step(k, warmup);
                if k >= warmup {
                    steps.push(step - 1);
                }
                steps.push(step);
            }
            let unbroken: Vec<usize> = (0..warmup + 8).collect();
            assert_eq!(steps, unbroken, "warm-up {warmup}");
        }
    }

    #[test]
    fn fixed_overlap_spaces_cameras_by_the_unshared_angle() {
        let base = Camera::new(Vec3::new(1.0, 2.0, 3.0), Vec3::new(0.0, -0.3, -1.0), 1.2);
        let aspect = 16.0 / 9.0;
        let h = 2.0 * ((0.6f32).tan() * aspect).atan();
        let yaw = |c: &Camera| c.forward.x.atan2(-c.forward.z);
        for overlap in [0.1, 0.25, 0.5, 0.75] {
            let cams = fixed_overlap(base, 4, overlap, aspect);
            for pair in cams.windows(2) {
                let d = yaw(&pair[1]) - yaw(&pair[0]);
                assert!((d - (1.0 - overlap) * h).abs() < 1e-4, "{overlap}: {d}");
                assert_eq!(pair[0].position, base.position);
                assert!(
                    (pair[1].forward.y - base.forward.y).abs() < 1e-6,
                    "pitch kept"
                );
            }
            // Centred on the base direction.
            assert!((yaw(&cams[0]) + yaw(&cams[3]) - 2.0 * yaw(&base)).abs() < 1e-4);
        }
        let same = fixed_overlap(base, 3, 1.0, aspect);
        assert!(same
            .iter()
            .all(|c| (c.forward - base.forward).length() < 1e-6));
    }

    #[test]
    fn spread_takes_median_and_range() {
        let s = Spread::of(&[3.0, 1.0, 2.0, 10.0]);
        assert_eq!((s.median, s.min, s.max), (3.0, 1.0, 10.0));
        assert_eq!(Spread::of(&[]).median, 0.0);
    }
}
