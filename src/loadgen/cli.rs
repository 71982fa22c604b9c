//! `fogcast loadgen` flags.

use super::{run, write_report, LoadgenConfig};
use crate::protocol::Layout;
use std::path::PathBuf;

/// Session layout of the simulated viewers.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum LayoutArg {
    /// One view per session.
    Mono,
    /// Two eyes per session (2 views).
    Stereo,
    /// `--split-views` tiles per session.
    Split,
}

/// Flags of `fogcast loadgen`.
#[derive(Debug, Clone, clap::Args)]
pub struct LoadgenArgs {
    /// WebSocket URL of a running `fogcast serve`.
    #[arg(long, default_value = "ws://127.0.0.1:8080/ws")]
    pub url: String,
    /// Views per sweep point, comma-separated (a stereo session has 2, a split one --split-views).
    #[arg(long, value_delimiter = ',', default_value = "1,4,8,16")]
    pub viewers: Vec<usize>,
    /// Measured seconds per point.
    #[arg(long, default_value_t = LoadgenConfig::default().seconds)]
    pub seconds: f64,
    /// Seconds between every viewer having frames and the measured window.
    #[arg(long, default_value_t = LoadgenConfig::default().warmup_s)]
    pub warmup: f64,
    /// Longest wait for every viewer's first frame, seconds.
    #[arg(long, default_value_t = LoadgenConfig::default().first_frame_timeout_s)]
    pub first_frame_timeout: f64,
    /// Pose messages each session sends per second.
    #[arg(long, default_value_t = LoadgenConfig::default().pose_hz)]
    pub pose_hz: f64,
    /// Frame width each session asks for.
    #[arg(long, default_value_t = LoadgenConfig::default().width)]
    pub width: u32,
    /// Frame height each session asks for.
    #[arg(long, default_value_t = LoadgenConfig::default().height)]
    pub height: u32,
    /// JPEG quality each session asks for.
    #[arg(long, default_value_t = LoadgenConfig::default().quality)]
    pub quality: u8,
    /// Session layout.
    #[arg(long, value_enum, default_value = "mono")]
    pub layout: LayoutArg,
    /// Views per split session (2–4).
    #[arg(long, default_value_t = 2)]
    pub split_views: u32,
    /// Token, for servers started with one.
    #[arg(long)]
    pub token: Option<String>,
    /// Scene whose camera loop the viewers fly [default: the server's, from /healthz].
    #[arg(long)]
    pub scene: Option<String>,
    /// Output folder (loadgen.json, loadgen.csv, loadgen.md, PNG plots).
    #[arg(long, default_value = "out/loadgen")]
    pub out: PathBuf,
}

impl LoadgenArgs {
    /// The run these flags ask for, checked.
    pub fn config(&self) -> anyhow::Result<LoadgenConfig> {
        let c = LoadgenConfig {
            url: self.url.clone(),
            viewers: self.viewers.clone(),
            seconds: self.seconds,
            warmup_s: self.warmup,
            first_frame_timeout_s: self.first_frame_timeout,
            pose_hz: self.pose_hz,
            width: self.width,
            height: self.height,
            quality: self.quality,
            layout: match self.layout {
                LayoutArg::Mono => Layout::Mono,
                LayoutArg::Stereo => Layout::Stereo,
                LayoutArg::Split => Layout::Split,
            },
            split_views: self.split_views,
            token: self.token.clone(),
            scene: self.scene.clone(),
        };
        c.validate()?;
        Ok(c)
    }
}

/// Runs `fogcast loadgen`: the sweep, then the report; progress on stderr.
pub fn loadgen(args: &LoadgenArgs) -> anyhow::Result<()> {
    let config = args.config()?;
    let command = std::env::args().collect::<Vec<_>>().join(" ");
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .thread_name("fogcast-loadgen")
        .build()?;
    let report = runtime.block_on(run(&config, &command, &|line| eprintln!("{line}")))?;
    let files = write_report(&report, &args.out)?;
    for p in &report.points {
        let s = &p.summary;
        println!(
            "{:>3} views: {:5.1} fps per viewer (min {:.1}), latency p50/p95/p99 {}, {:.0} KiB/s per viewer, frames every second: {}, served throughout: {}",
            p.viewers,
            s.fps_mean,
            s.fps_min,
            s.latency.map_or_else(
                || "–".into(),
                |l| format!("{:.0}/{:.0}/{:.0} ms", l.p50_ms, l.p95_ms, l.p99_ms)
            ),
            s.bytes_per_s_per_viewer / 1024.0,
            if s.every_viewer_every_second { "yes" } else { "no" },
            if s.every_viewer_served_throughout { "yes" } else { "NO" }
        );
    }
    println!(
        "wrote {} files to {} ({})",
        files.len(),
        args.out.display(),
        files
            .iter()
            .filter_map(|f| f.file_name()?.to_str())
            .collect::<Vec<_>>()
            .join(", ")
    );
    Ok(())
}
