//! Writes a [`BenchReport`]: `bench.json` (everything), `bench.csv` (a row per point),
//! `bench.md` (tables in the shape of paper 000's Tables 1–3, the stage breakdown, the
//! issue-5 checks, the fixed-overlap results) and PNG plots (`overlap_time_<config>.png`
//! and `overlap_rays_<config>.png` per configuration compared with `reference`).

use super::{BenchPoint, BenchReport, Scenario};
use crate::render::{Settings, Stage};
use crate::report::{plot, stacked_bars, Bar, BarGroup, Series, Table};
use std::path::Path;

const MIB: f64 = 1048576.0;

/// Issue 5's bounds: shared frame time at the most viewers ≤ 0.6 × reference's there,
/// shared rays at the most viewers ≤ 6 × its rays at one viewer, FLIP ≤ 0.05 everywhere.
pub const MAX_TIME_RATIO: f64 = 0.6;
/// See [`MAX_TIME_RATIO`].
pub const MAX_RAY_GROWTH: f64 = 6.0;
/// See [`MAX_TIME_RATIO`].
pub const MAX_FLIP: f64 = 0.05;
/// Issue 14's bound on `shared`'s frame time against `reference`'s at the most viewers.
pub const MAX_TIME_RATIO_14: f64 = 0.35;
/// Issue 14's bound on each viewer beyond the first, against one `reference` viewer.
pub const MAX_MARGINAL_VIEWER: f64 = 0.25;
/// Issue 14's bound on `shared`'s frame time against `maps`' at the most viewers.
pub const MAX_TIME_VS_MAPS: f64 = 0.8;
/// Issue 16's bounds: one stereo session's frame time against one mono view of one
/// eye's size, and each coupled eye's mean FLIP against that eye rendered alone.
pub const MAX_STEREO_COST: f64 = 1.3;
/// See [`MAX_STEREO_COST`].
pub const MAX_STEREO_FLIP: f64 = 0.02;

/// One of issue 5's acceptance checks, evaluated on a report.
#[derive(Debug, Clone, PartialEq)]
pub struct Check {
    /// What is checked, with the viewer counts used.
    pub what: String,
    /// The measured value.
    pub value: f64,
    /// The bound it must stay at or under (none: reported only).
    pub bound: Option<f64>,
}

impl Check {
    /// The value as the tables print it: 3 decimals, or 5 where that would hide it (a
    /// FLIP difference of a few 10⁻⁵ is not 0.000).
    pub fn value_text(&self) -> String {
        value_text(self.value)
    }

    /// Whether the value is within the bound (always true without one).
    pub fn passed(&self) -> bool {
        within(self.bound, self.value)
    }
}

/// Whether `v` is at or under `bound` (always true without one).
pub fn within(bound: Option<f64>, v: f64) -> bool {
    bound.is_none_or(|b| v <= b)
}

/// See [`Check::value_text`].
pub fn value_text(v: f64) -> String {
    if v != 0.0 && v.abs() < 0.01 {
        format!("{v:.5}")
    } else {
        format!("{v:.3}")
    }
}

/// Points of one scenario and configuration, by viewer count.
fn series_of<'a>(r: &'a BenchReport, scenario: Scenario, config: &str) -> Vec<&'a BenchPoint> {
    let mut v: Vec<&BenchPoint> = r
        .points
        .iter()
        .filter(|p| p.scenario == scenario && p.config == config)
        .collect();
    v.sort_by_key(|p| p.viewers);
    v
}

fn point<'a>(
    r: &'a BenchReport,
    scenario: Scenario,
    config: &str,
    viewers: usize,
) -> Option<&'a BenchPoint> {
    r.points
        .iter()
        .find(|p| p.scenario == scenario && p.config == config && p.viewers == viewers)
}

fn viewer_counts(r: &BenchReport, scenario: Scenario) -> Vec<usize> {
    let mut v: Vec<usize> = r
        .points
        .iter()
        .filter(|p| p.scenario == scenario)
        .map(|p| p.viewers)
        .collect();
    v.sort_unstable();
    v.dedup();
    v
}

fn overlaps(r: &BenchReport) -> Vec<f32> {
    let mut v: Vec<f32> = Vec::new();
    for p in &r.points {
        if let Scenario::Overlap { overlap_pct } = p.scenario {
            if !v.contains(&overlap_pct) {
                v.push(overlap_pct);
            }
        }
    }
    v
}

fn has_reference(r: &BenchReport) -> bool {
    r.configs.iter().any(|c| c.name == "reference")
}

/// The configurations compared against `reference` (all but it).
fn challengers(r: &BenchReport) -> Vec<&str> {
    r.configs
        .iter()
        .map(|c| c.name.as_str())
        .filter(|n| *n != "reference")
        .collect()
}

/// Stage names in pipeline order: the longest stage list of any point (shared runs them
/// all, in order), then any stage it lacks.
fn stage_names(r: &BenchReport) -> Vec<String> {
    let mut names: Vec<String> = r
        .points
        .iter()
        .max_by_key(|p| p.stages.len())
        .map(|p| p.stages.iter().map(|s| s.stage.clone()).collect())
        .unwrap_or_default();
    for p in &r.points {
        for s in &p.stages {
            if !names.contains(&s.stage) {
                names.push(s.stage.clone());
            }
        }
    }
    names
}

fn stage_ms(p: &BenchPoint, stage: &str) -> f64 {
    p.stages
        .iter()
        .find(|s| s.stage == stage)
        .map_or(0.0, |s| s.gpu_ms.median)
}

fn tag(r: &BenchReport, config: &str) -> String {
    match config {
        "reference" => "R".into(),
        "shared" => "S".into(),
        "maps" => "M".into(),
        _ => {
            let i = r
                .configs
                .iter()
                .filter(|c| !["reference", "shared", "maps"].contains(&c.name.as_str()))
                .position(|c| c.name == config)
                .unwrap_or(0);
            format!("V{}", i + 1)
        }
    }
}

/// Issue 5's checks for every configuration other than `reference`, on the path
/// scenario's fewest and most viewers.
pub fn checks(r: &BenchReport) -> Vec<Check> {
    let counts = viewer_counts(r, Scenario::Path);
    let (Some(&lo), Some(&hi)) = (counts.first(), counts.last()) else {
        return Vec::new();
    };
    let mut out = Vec::new();
    let reference_hi = point(r, Scenario::Path, "reference", hi);
    if let (Some(a), Some(b)) = (point(r, Scenario::Path, "reference", lo), reference_hi) {
        out.push(Check {
            what: format!(
                "reference fog rays at {hi} viewers / at {lo} (about linear: ≈ {:.0})",
                hi as f64 / lo as f64
            ),
            value: ratio(b.rays.fog_total as f64, a.rays.fog_total as f64),
            bound: None,
        });
    }
    for c in challengers(r) {
        if let (Some(reference), Some(p)) = (reference_hi, point(r, Scenario::Path, c, hi)) {
            out.push(Check {
                what: format!(
                    "{c}: frame GPU ms at {hi} viewers / reference's (median of per-frame ratios)"
                ),
                value: paired_ratio(p, reference),
                bound: Some(MAX_TIME_RATIO),
            });
            out.push(Check {
                what: format!("{c}: the same, as the ratio of the two medians"),
                value: ratio(p.frame_gpu_ms.median, reference.frame_gpu_ms.median),
                bound: Some(MAX_TIME_RATIO),
            });
            out.push(Check {
                what: format!(
                    "{c}: fog stages only ({}) at {hi} viewers / reference's",
                    super::fog_stage_list()
                ),
                value: ratio(p.fog_gpu_ms.median, reference.fog_gpu_ms.median),
                bound: None,
            });
            let grid_and_frustum = [Stage::GridRequests, Stage::SharedGrid, Stage::ShadowFrustum]
                .into_iter()
                .map(|s| stage_ms(p, s.name()))
                .sum::<f64>();
            out.push(Check {
                what: format!(
                    "{c}: frame at {hi} viewers / reference's if its grid and frustum stages took no time (the floor the other stages set)"
                ),
                value: ratio(p.frame_gpu_ms.median - grid_and_frustum, reference.frame_gpu_ms.median),
                bound: None,
            });
        }
        if let (Some(a), Some(b)) = (
            point(r, Scenario::Path, c, lo),
            point(r, Scenario::Path, c, hi),
        ) {
            // `maps` traces none: nothing grows.
            if a.rays.fog_total + b.rays.fog_total > 0 {
                out.push(Check {
                    what: format!("{c}: fog rays at {hi} viewers / at {lo}"),
                    value: ratio(b.rays.fog_total as f64, a.rays.fog_total as f64),
                    bound: Some(MAX_RAY_GROWTH),
                });
            }
        }
        let worst = r
            .points
            .iter()
            .filter(|p| p.config == c)
            .filter_map(|p| p.flip_vs_reference)
            .map(|f| f.mean)
            .fold(None, |m: Option<f64>, v| Some(m.map_or(v, |m| m.max(v))));
        if let Some(worst) = worst {
            out.push(Check {
                what: format!("{c}: largest mean FLIP vs reference over all points"),
                value: worst,
                bound: Some(MAX_FLIP),
            });
        }
    }
    // Issue 14: `shared` against `reference` at its tighter bound, the cost of each
    // viewer beyond the first against one `reference` viewer, and against `maps`; the
    // same for every `froxel_maps` variant of it (shared froxels lit from the maps).
    let truth_of = |c: &str| {
        r.truth
            .as_ref()
            .and_then(|t| t.flip.iter().find(|(n, _)| n == c).map(|(_, f)| *f))
    };
    let contenders = r
        .configs
        .iter()
        .filter(|v| v.name == "shared" || (v.settings.froxel_maps && v.name != "reference"))
        .map(|v| v.name.as_str());
    for c in contenders {
        out.extend(issue_14_checks(r, c, lo, hi, reference_hi));
        if let (Some(s), Some(m)) = (truth_of(c), truth_of("maps")) {
            out.push(Check {
                what: format!("{c}: FLIP vs truth − maps' FLIP vs truth (the one truth image)"),
                value: s - m,
                bound: Some(0.0),
            });
        }
    }
    out
}

/// Issue 14's cost checks of configuration `c`: its frame at `hi` viewers against
/// `reference`'s and `maps`', and its marginal viewer against one `reference` viewer.
fn issue_14_checks(
    r: &BenchReport,
    c: &str,
    lo: usize,
    hi: usize,
    reference_hi: Option<&BenchPoint>,
) -> Vec<Check> {
    let mut out = Vec::new();
    if let (Some(s_lo), Some(s_hi), Some(r_lo), Some(r_hi)) = (
        point(r, Scenario::Path, c, lo),
        point(r, Scenario::Path, c, hi),
        point(r, Scenario::Path, "reference", lo),
        reference_hi,
    ) {
        out.push(Check {
            what: format!(
                "{c}: frame GPU ms at {hi} viewers / reference's (median of per-frame ratios; issue 14)"
            ),
            value: paired_ratio(s_hi, r_hi),
            bound: Some(MAX_TIME_RATIO_14),
        });
        if hi > lo {
            let marginal = (s_hi.frame_gpu_ms.median - s_lo.frame_gpu_ms.median) / (hi - lo) as f64;
            out.push(Check {
                what: format!(
                    "{c}: marginal viewer (T{hi} − T{lo}) / {} / reference's {lo}-viewer frame",
                    hi - lo
                ),
                value: ratio(marginal, r_lo.frame_gpu_ms.median),
                bound: Some(MAX_MARGINAL_VIEWER),
            });
        }
    }
    if let (Some(s), Some(m)) = (
        point(r, Scenario::Path, c, hi),
        point(r, Scenario::Path, "maps", hi),
    ) {
        out.push(Check {
            what: format!("{c}: frame GPU ms at {hi} viewers / maps' (ratio of the medians)"),
            value: ratio(s.frame_gpu_ms.median, m.frame_gpu_ms.median),
            bound: Some(MAX_TIME_VS_MAPS),
        });
    }
    out
}

/// Every configuration's FLIP against `truth` on the one image it was measured on.
fn truth_section(r: &BenchReport) -> String {
    let Some(t) = &r.truth else {
        return String::new();
    };
    let mut table = Table::new(&["configuration", "mean FLIP vs truth"]);
    for (name, flip) in &t.flip {
        table.push(vec![name.clone(), format!("{flip:.4}")]);
    }
    format!(
        "\n## Mean FLIP against truth (the CPU renderer)\n\nOne image, kept small so that \
         the CPU renderer stays quick: the path's first viewer at scene time {time} s, \
         {w}×{h} pixels, `truth` with {steps} segments and 1 ray per pixel ({secs:.1} s on \
         the CPU); each configuration's second frame there.\n\n{}",
        table.to_markdown(),
        time = t.time_s,
        w = t.width,
        h = t.height,
        steps = t.steps,
        secs = t.truth_s,
    )
}

/// `p`'s frame GPU time relative to `reference`'s point `q`: the median of the per-frame
/// ratios when they were measured, else the ratio of the medians.
fn paired_ratio(p: &BenchPoint, q: &BenchPoint) -> f64 {
    p.frame_gpu_vs_reference.map_or_else(
        || ratio(p.frame_gpu_ms.median, q.frame_gpu_ms.median),
        |s| s.median,
    )
}

fn ratio(a: f64, b: f64) -> f64 {
    if b > 0.0 {
        a / b
    } else {
        f64::NAN
    }
}

fn ms(s: &super::Spread) -> String {
    format!("{:.1} ({:.1}–{:.1})", s.median, s.min, s.max)
}

fn csv(r: &BenchReport) -> Table {
    let stages = stage_names(r);
    let mut headers: Vec<String> = [
        "scenario",
        "overlap_pct",
        "eye_distance_m",
        "viewers",
        "config",
        "mode",
        "frames",
        "frame_gpu_ms_median",
        "frame_gpu_ms_min",
        "frame_gpu_ms_max",
        "frame_host_ms_median",
        "frame_gpu_vs_reference_median",
        "fog_gpu_ms_median",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    headers.extend(stages.iter().map(|s| format!("{s}_gpu_ms_median")));
    headers.extend(
        [
            "rays_shared_grid",
            "rays_shadow_frustum",
            "rays_froxel_lighting",
            "rays_surface",
            "rays_fog_total",
            "rays_total",
            "voxels_updated",
            "grid_dims",
            "memory_shared_bytes",
            "memory_per_viewer_bytes",
            "memory_total_bytes",
            "flip_mean",
            "flip_max",
            "flip_vs_eyes_alone_mean",
            "flip_vs_eyes_alone_max",
        ]
        .iter()
        .map(|s| s.to_string()),
    );
    let mut t = Table {
        headers,
        rows: Vec::new(),
    };
    for p in &r.points {
        let (scenario, overlap, eye) = match p.scenario {
            Scenario::Path => ("path", String::new(), String::new()),
            Scenario::Overlap { overlap_pct } => {
                ("overlap", overlap_pct.to_string(), String::new())
            }
            Scenario::Stereo { eye_distance_m } => {
                ("stereo", String::new(), eye_distance_m.to_string())
            }
            Scenario::StereoEyesAlone { eye_distance_m } => {
                ("eyes_alone", String::new(), eye_distance_m.to_string())
            }
        };
        let mut row = vec![
            scenario.to_string(),
            overlap,
            eye,
            p.viewers.to_string(),
            p.config.clone(),
            p.mode.name().into(),
            p.frames.to_string(),
            format!("{:.3}", p.frame_gpu_ms.median),
            format!("{:.3}", p.frame_gpu_ms.min),
            format!("{:.3}", p.frame_gpu_ms.max),
            format!("{:.3}", p.frame_host_ms.median),
            p.frame_gpu_vs_reference
                .map_or(String::new(), |s| format!("{:.4}", s.median)),
            format!("{:.3}", p.fog_gpu_ms.median),
        ];
        row.extend(stages.iter().map(|s| format!("{:.3}", stage_ms(p, s))));
        let [gx, gy, gz] = p.grid_dims;
        row.extend([
            p.rays.shared_grid.to_string(),
            p.rays.shadow_frustum.to_string(),
            p.rays.froxel_lighting.to_string(),
            p.rays.surface.to_string(),
            p.rays.fog_total.to_string(),
            p.rays.total.to_string(),
            p.voxels_updated.to_string(),
            format!("{gx}x{gy}x{gz}"),
            p.memory.shared.to_string(),
            p.memory.per_viewer.to_string(),
            p.memory.total.to_string(),
            p.flip_vs_reference
                .map_or(String::new(), |f| format!("{:.5}", f.mean)),
            p.flip_vs_reference
                .map_or(String::new(), |f| format!("{:.5}", f.max)),
            p.flip_vs_eyes_alone
                .map_or(String::new(), |f| format!("{:.5}", f.mean)),
            p.flip_vs_eyes_alone
                .map_or(String::new(), |f| format!("{:.5}", f.max)),
        ]);
        t.push(row);
    }
    t
}

/// A value of a point relative to the `reference` point beside it.
type PairRatio = dyn Fn(&BenchPoint, &BenchPoint) -> f64;

/// A table with a row per viewer count and, per configuration, `cell(point)` and (for
/// all but `reference`, when `ratio_of` is given) `ratio_of(point, reference point)`.
fn per_config_table(
    r: &BenchReport,
    scenario: Scenario,
    cell: &dyn Fn(&BenchPoint) -> String,
    ratio_of: Option<&PairRatio>,
) -> Table {
    let with_ratio = |name: &str| name != "reference" && has_reference(r) && ratio_of.is_some();
    let mut headers = vec!["cameras".to_string()];
    for c in &r.configs {
        headers.push(c.name.clone());
        if with_ratio(&c.name) {
            headers.push(format!("{} / reference", c.name));
        }
    }
    let mut t = Table {
        headers,
        rows: Vec::new(),
    };
    for n in viewer_counts(r, scenario) {
        let reference = point(r, scenario, "reference", n);
        let mut row = vec![n.to_string()];
        for c in &r.configs {
            let p = point(r, scenario, &c.name, n);
            row.push(p.map_or("–".into(), cell));
            if let (true, Some(f)) = (with_ratio(&c.name), ratio_of) {
                row.push(match (p, reference) {
                    (Some(p), Some(q)) => format!("{:.2}", f(p, q)),
                    _ => "–".into(),
                });
            }
        }
        t.push(row);
    }
    t
}

fn configs_table(r: &BenchReport) -> Table {
    let mut t = Table::new(&[
        "tag",
        "configuration",
        "voxel m",
        "grid",
        "settings (over `shared`'s defaults)",
    ]);
    for c in &r.configs {
        let s = &c.settings;
        let grid = r
            .points
            .iter()
            .find(|p| p.config == c.name)
            .map(|p| p.grid_dims)
            .filter(|d| d[0] > 0)
            .map_or("–".into(), |[x, y, z]| format!("{x}×{y}×{z}"));
        let defaults = Settings {
            voxel_size_m: s.voxel_size_m,
            ..Settings::default()
        };
        let changes = s.changes_from(&defaults);
        t.push(vec![
            tag(r, &c.name),
            c.name.clone(),
            format!("{}", s.voxel_size_m),
            grid,
            if changes.is_empty() {
                "–".into()
            } else {
                format!("`{changes}`")
            },
        ]);
    }
    t
}

fn stage_table(r: &BenchReport, scenario: Scenario) -> Table {
    let stages = stage_names(r);
    let mut headers = vec!["cameras".to_string(), "configuration".to_string()];
    headers.extend(stages.iter().cloned());
    headers.push("frame".into());
    let mut t = Table {
        headers,
        rows: Vec::new(),
    };
    for n in viewer_counts(r, scenario) {
        for c in &r.configs {
            if let Some(p) = point(r, scenario, &c.name, n) {
                let mut row = vec![n.to_string(), c.name.clone()];
                row.extend(stages.iter().map(|s| {
                    if p.stages.iter().any(|x| x.stage == *s) {
                        format!("{:.1}", stage_ms(p, s))
                    } else {
                        "–".into()
                    }
                }));
                row.push(format!("{:.1}", p.frame_gpu_ms.median));
                t.push(row);
            }
        }
    }
    t
}

fn overlap_tables(r: &BenchReport) -> String {
    let overlaps = overlaps(r);
    if overlaps.is_empty() {
        return String::new();
    }
    let mut md = String::from(
        "\n## Fixed overlap (paper Figure 12)\n\nOne camera on the path, duplicated and yawed \
         in place about the vertical axis through its eye; neighbours are (1 − overlap) × \
         the horizontal field of view apart, so each pair of neighbours shares `overlap` \
         of its horizontal view angle (100 %: all cameras identical). Cells: frame GPU ms \
         of the configuration / reference's, and fog rays likewise.\n",
    );
    let counts: Vec<usize> = {
        let mut v: Vec<usize> = r
            .points
            .iter()
            .filter(|p| matches!(p.scenario, Scenario::Overlap { .. }))
            .map(|p| p.viewers)
            .collect();
        v.sort_unstable();
        v.dedup();
        v
    };
    for c in challengers(r) {
        for (what, value) in [
            (
                "frame GPU ms",
                (&|p: &BenchPoint| p.frame_gpu_ms.median) as &dyn Fn(&BenchPoint) -> f64,
            ),
            ("fog rays", &|p: &BenchPoint| p.rays.fog_total as f64),
        ] {
            let mut headers = vec!["cameras".to_string()];
            headers.extend(overlaps.iter().map(|o| format!("{o} %")));
            let mut t = Table {
                headers,
                rows: Vec::new(),
            };
            for &n in &counts {
                let mut row = vec![n.to_string()];
                for &overlap_pct in &overlaps {
                    let s = Scenario::Overlap { overlap_pct };
                    row.push(match (point(r, s, c, n), point(r, s, "reference", n)) {
                        (Some(p), Some(q)) => {
                            let (a, b) = (value(p), value(q));
                            if what == "fog rays" {
                                format!("{a:.0} / {b:.0} ({:.2})", ratio(a, b))
                            } else {
                                format!("{a:.1} / {b:.1} ({:.2})", paired_ratio(p, q))
                            }
                        }
                        (Some(p), None) => format!("{:.1}", value(p)),
                        _ => "–".into(),
                    });
                }
                t.push(row);
            }
            md += &format!(
                "\n### {c}: {what} / reference's (ratio)\n\n{}",
                t.to_markdown()
            );
        }
    }
    md
}

fn markdown(r: &BenchReport) -> String {
    let path = Scenario::Path;
    let mut md = format!(
        "# bench: {scene}\n\n`{cmd}`\n\n{w}×{h} per viewer; at each point {warm} warm-up and \
         {frames} measured frame(s), scene time from {t0} s in steps of {dt:.4} s, each \
         measured frame right after an unmeasured lead-in frame of its own renderer one \
         step earlier (so each renderer walks unbroken steps); the configurations take \
         turns frame by frame on the same cameras. Times are GPU \
         timestamp queries on `{adapter}` with {threads} CPU thread(s): the median over the \
         measured frames, the range in brackets; a frame's time is the sum of its stages. \
         Rays and voxels are means per frame. Ratios of times to `reference` are medians of \
         per-frame ratios (the two ran back to back on the same cameras). FLIP against \
         `reference`: {flip}. The run took {elapsed:.0} s; {load}.\n\n{configs}",
        scene = r.scene,
        cmd = r.command,
        w = r.width,
        h = r.height,
        warm = r.warmup,
        frames = r.frames,
        t0 = r.time_s,
        dt = r.frame_dt_s,
        adapter = r.adapter,
        threads = r.cpu_threads,
        flip = r.flip_frames,
        elapsed = r.elapsed_s,
        load = r
            .load_average
            .map_or("load average unknown".into(), |[a, b]| format!(
            "the machine's 1-minute load average was {a:.1} at the start and {b:.1} at the end \
             (above {} other processes competed for the CPU lavapipe renders on)",
            r.cpu_threads
        )),
        configs = configs_table(r).to_markdown(),
    );
    if !viewer_counts(r, path).is_empty() {
        let time = per_config_table(
            r,
            path,
            &|p| ms(&p.frame_gpu_ms),
            Some(&|p, q| paired_ratio(p, q)),
        );
        let fog = per_config_table(
            r,
            path,
            &|p| ms(&p.fog_gpu_ms),
            Some(&|p, q| ratio(p.fog_gpu_ms.median, q.fog_gpu_ms.median)),
        );
        let rays = per_config_table(
            r,
            path,
            &|p| {
                let first = series_of(r, path, &p.config)
                    .first()
                    .map_or(0, |f| f.rays.fog_total);
                format!(
                    "{} (×{:.2})",
                    p.rays.fog_total,
                    ratio(p.rays.fog_total as f64, first as f64)
                )
            },
            Some(&|p, q| ratio(p.rays.fog_total as f64, q.rays.fog_total as f64)),
        );
        let memory = per_config_table(
            r,
            path,
            &|p| {
                format!(
                    "{:.1} ({:.1} + {}×{:.2})",
                    p.memory.total as f64 / MIB,
                    p.memory.shared as f64 / MIB,
                    p.viewers,
                    p.memory.per_viewer as f64 / MIB
                )
            },
            Some(&|p, q| ratio(p.memory.total as f64, q.memory.total as f64)),
        );
        let voxels = per_config_table(r, path, &|p| p.voxels_updated.to_string(), None);
        let triangles = per_config_table(
            r,
            path,
            &|p| {
                let (drawn, in_clusters) = p.raster_triangles;
                format!("{drawn} of {in_clusters}")
            },
            None,
        );
        let mut flip = Table::new(&["cameras"]);
        let challengers = challengers(r);
        flip.headers.extend(
            challengers
                .iter()
                .map(|c| format!("{c}: mean (worst image)")),
        );
        for n in viewer_counts(r, path) {
            let mut row = vec![n.to_string()];
            row.extend(challengers.iter().map(|c| {
                point(r, path, c, n)
                    .and_then(|p| p.flip_vs_reference)
                    .map_or("–".into(), |f| format!("{:.4} ({:.4})", f.mean, f.max))
            }));
            flip.push(row);
        }
        md += &format!(
            "\n## Frame time, GPU ms (viewers spread along the camera path; paper Tables 1–3)\n\n{}\
             \n## Fog stages only ({fog_stages}), GPU ms\n\n{}\
             \n## Shadow rays per frame, fog stages (× its own fewest-viewer count; paper Figure 11)\n\n{}\
             \n## Memory, MiB: total (shared + viewers × per viewer; paper Figure 14)\n\n{}\
             \n## Shared-grid voxels updated per frame\n\n{}\
             \n## G-buffer triangles drawn per frame, of those in the clusters the frustums touch (all views)\n\n{}\
             \n## Where the time goes: GPU ms per stage, median (paper Figure 13)\n\n{}\
             \n## Mean FLIP against reference on the same frames\n\n{}",
            time.to_markdown(),
            fog.to_markdown(),
            rays.to_markdown(),
            memory.to_markdown(),
            voxels.to_markdown(),
            triangles.to_markdown(),
            stage_table(r, path).to_markdown(),
            flip.to_markdown(),
            fog_stages = super::fog_stage_list(),
        );
        md += &truth_section(r);
        let checks = checks(r);
        if !checks.is_empty() {
            let mut t = Table::new(&["check", "measured", "bound", "result"]);
            for c in &checks {
                t.push(vec![
                    c.what.clone(),
                    c.value_text(),
                    c.bound.map_or("–".into(), |b| format!("≤ {b}")),
                    match c.bound {
                        None => "reported".into(),
                        Some(_) if c.passed() => "pass".into(),
                        Some(_) => "**fail**".into(),
                    },
                ]);
            }
            md += &format!(
                "\n## Acceptance checks (issues 5 and 14)\n\n{}",
                t.to_markdown()
            );
        }
    }
    md + &overlap_tables(r) + &stereo_tables(r)
}

/// The stereo scenario's eye distance, if it ran.
fn stereo_scenarios(r: &BenchReport) -> Option<(Scenario, Scenario)> {
    r.points.iter().find_map(|p| match p.scenario {
        Scenario::Stereo { eye_distance_m } => {
            Some((p.scenario, Scenario::StereoEyesAlone { eye_distance_m }))
        }
        _ => None,
    })
}

/// Issue 16's checks, per configuration: one stereo session's frame time against one
/// path viewer's (a mono view of one eye's size), and the worst coupled eye's FLIP
/// against that eye alone.
pub fn stereo_checks(r: &BenchReport) -> Vec<Check> {
    let Some((stereo, _)) = stereo_scenarios(r) else {
        return Vec::new();
    };
    let mut out = Vec::new();
    for c in &r.configs {
        let c = c.name.as_str();
        if let Some(s) = point(r, stereo, c, 2).and_then(|p| p.frame_gpu_vs_one_eye) {
            out.push(Check {
                what: format!(
                    "{c}: one stereo session's frame GPU ms / one eye's alone (median of \
                     per-frame ratios)"
                ),
                value: s.median,
                bound: Some(MAX_STEREO_COST),
            });
        }
        // Issue 16 bounds each eye's image: the worst eye of every session count and
        // measured frame.
        let worst = series_of(r, stereo, c)
            .iter()
            .filter_map(|p| p.flip_vs_eyes_alone.map(|f| (p.viewers, f.max)))
            .reduce(|a, b| if b.1 > a.1 { b } else { a });
        if let Some((eyes, flip)) = worst {
            out.push(Check {
                what: format!(
                    "{c}: the worst coupled eye's mean FLIP against that eye alone (every \
                     session count and frame; worst at {eyes} eyes)"
                ),
                value: flip,
                bound: Some(MAX_STEREO_FLIP),
            });
        }
    }
    out
}

fn stereo_tables(r: &BenchReport) -> String {
    let Some((stereo, alone)) = stereo_scenarios(r) else {
        return String::new();
    };
    let Scenario::Stereo { eye_distance_m } = stereo else {
        return String::new();
    };
    let mut t = Table::new(&[
        "sessions (eyes)",
        "configuration",
        "stereo frame GPU ms",
        "eyes as mono views",
        "stereo / mono",
        "stereo / one eye alone",
        "froxels lit: stereo / mono",
        "FLIP against eyes alone: mean (worst eye)",
    ]);
    for n in viewer_counts(r, stereo) {
        for c in &r.configs {
            let (Some(s), Some(a)) = (point(r, stereo, &c.name, n), point(r, alone, &c.name, n))
            else {
                continue;
            };
            t.push(vec![
                format!("{} ({n})", n / 2),
                c.name.clone(),
                ms(&s.frame_gpu_ms),
                ms(&a.frame_gpu_ms),
                format!("{:.2}", ratio(s.frame_gpu_ms.median, a.frame_gpu_ms.median)),
                s.frame_gpu_vs_one_eye
                    .map_or("–".into(), |v| format!("{:.2}", v.median)),
                format!("{} / {}", s.froxels_with_media, a.froxels_with_media),
                s.flip_vs_eyes_alone
                    .map_or("–".into(), |f| format!("{:.4} ({:.4})", f.mean, f.max)),
            ]);
        }
    }
    let mut checks = Table::new(&["check", "measured", "bound", "result"]);
    for c in stereo_checks(r) {
        checks.push(vec![
            c.what.clone(),
            c.value_text(),
            c.bound.map_or("–".into(), |b| format!("≤ {b}")),
            if c.passed() {
                "pass".into()
            } else {
                "**fail**".into()
            },
        ]);
    }
    format!(
        "\n## Stereo sessions (issue 16)\n\nHeads spread along the path as in the path \
         scenario; each is a stereo session, its two eyes {eye_distance_m} m apart side by \
         side in one frame (coupled stereo shares one froxel volume when the eyes are at \
         most `stereo_share_m` apart). On the same frame every eye is rendered again as a \
         mono view of its own: the cost two independent views would have, and the image \
         the coupled eye is compared with; and the left eye once more alone, as one mono \
         view of one eye's size. Ratios are medians of per-frame ratios (rendered back to \
         back).\n\n{}\n### Acceptance checks (issue 16)\n\n{}",
        t.to_markdown(),
        checks.to_markdown()
    )
}

fn plots(r: &BenchReport, out: &Path) -> anyhow::Result<()> {
    let path = Scenario::Path;
    let counts = viewer_counts(r, path);
    if !counts.is_empty() {
        let by_config = |y: &dyn Fn(&BenchPoint) -> f64| -> Vec<Series> {
            r.configs
                .iter()
                .map(|c| Series {
                    name: c.name.clone(),
                    points: series_of(r, path, &c.name)
                        .into_iter()
                        .map(|p| (p.viewers as f64, y(p)))
                        .collect(),
                })
                .collect()
        };
        let line = |file: &str, title: &str, y_label: &str, y: &dyn Fn(&BenchPoint) -> f64| {
            plot(
                &out.join(file),
                &format!("{}: {title}", r.scene),
                "viewers",
                y_label,
                &by_config(y),
                true,
                false,
                false,
            )
        };
        line(
            "frame_time.png",
            &format!("frame GPU time, {}×{} per viewer", r.width, r.height),
            "GPU ms per frame (median)",
            &|p| p.frame_gpu_ms.median,
        )?;
        line(
            "rays.png",
            "fog shadow rays per frame",
            "thousand shadow rays (fog stages)",
            &|p| p.rays.fog_total as f64 / 1e3,
        )?;
        line("memory.png", "GPU memory", "MiB", &|p| {
            p.memory.total as f64 / MIB
        })?;
        let stages = stage_names(r);
        let groups: Vec<BarGroup> = counts
            .iter()
            .map(|&n| BarGroup {
                label: n.to_string(),
                bars: r
                    .configs
                    .iter()
                    .filter_map(|c| point(r, path, &c.name, n))
                    .map(|p| Bar {
                        tag: tag(r, &p.config),
                        segments: stages.iter().map(|s| stage_ms(p, s)).collect(),
                    })
                    .collect(),
            })
            .collect();
        let legend: Vec<String> = r
            .configs
            .iter()
            .map(|c| format!("{} = {}", tag(r, &c.name), c.name))
            .collect();
        stacked_bars(
            &out.join("stages.png"),
            &format!("{}: GPU ms per stage ({})", r.scene, legend.join(", ")),
            "viewers",
            "GPU ms per frame (median)",
            &stages,
            &groups,
        )?;
    }
    let overlaps = overlaps(r);
    if overlaps.is_empty() || !has_reference(r) {
        return Ok(());
    }
    // One pair of plots per configuration: five overlaps each fit the palette.
    for c in challengers(r) {
        let ratio_series = |of: &PairRatio| -> Vec<Series> {
            let mut series: Vec<Series> = overlaps
                .iter()
                .map(|&overlap_pct| {
                    let s = Scenario::Overlap { overlap_pct };
                    Series {
                        name: format!("{overlap_pct} % overlap"),
                        points: series_of(r, s, c)
                            .into_iter()
                            .filter_map(|p| {
                                point(r, s, "reference", p.viewers)
                                    .map(|q| (p.viewers as f64, of(p, q)))
                            })
                            .collect(),
                    }
                })
                .collect();
            let xs = series.iter().flat_map(|s| s.points.iter().map(|p| p.0));
            let (lo, hi) = xs.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), x| {
                (a.min(x), b.max(x))
            });
            if lo.is_finite() {
                series.push(Series {
                    name: "break-even (= reference)".into(),
                    points: vec![(lo, 1.0), (hi, 1.0)],
                });
            }
            series
        };
        let file = file_safe(c);
        plot(
            &out.join(format!("overlap_time_{file}.png")),
            &format!(
                "{}: fixed overlap, {c} frame GPU time / reference's",
                r.scene
            ),
            "viewers",
            "frame GPU ms / reference (median per-frame ratio)",
            &ratio_series(&paired_ratio),
            true,
            false,
            false,
        )?;
        plot(
            &out.join(format!("overlap_rays_{file}.png")),
            &format!("{}: fixed overlap, {c} fog rays / reference's", r.scene),
            "viewers",
            "fog shadow rays / reference",
            &ratio_series(&|p, q| ratio(p.rays.fog_total as f64, q.rays.fog_total as f64)),
            true,
            false,
            false,
        )?;
    }
    Ok(())
}

/// A configuration name as a file-name part: anything but letters, digits, `-` and `_`
/// becomes `_`.
fn file_safe(name: &str) -> String {
    name.chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                c
            } else {
                '_'
            }
        })
        .collect()
}

/// Writes `bench.json`, `bench.csv`, `bench.md` and the plots into `out`.
pub fn write(r: &BenchReport, out: &Path) -> anyhow::Result<()> {
    crate::output::write_json(&out.join("bench.json"), r)?;
    let write = |name: &str, text: String| {
        std::fs::write(out.join(name), text)
            .map_err(|e| anyhow::anyhow!("writing {}: {e}", out.join(name).display()))
    };
    write("bench.csv", csv(r).to_csv())?;
    write("bench.md", markdown(r))?;
    plots(r, out)
}
