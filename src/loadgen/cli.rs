//! `fogcast loadgen` flags.

use super::{
    describe, run, sessions_count, write_report, FrameSize, LoadgenConfig, DEFAULT_SIZE,
    DEFAULT_VIEWERS, MIXED_SWEEP_SIZES, MIXED_SWEEP_VIEWERS,
};
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

/// Which sweep to run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum SweepArg {
    /// Every session at one frame size (--width x --height), over --viewers.
    Uniform,
    /// A third of the sessions at each of 320x180, 480x270 and 640x360, over 3, 6, 9,
    /// 12 and 15 views (--mix and --viewers replace either).
    Mixed,
}

/// Flags of `fogcast loadgen`.
#[derive(Debug, Clone, clap::Args)]
pub struct LoadgenArgs {
    /// WebSocket URL of a running `fogcast serve`.
    #[arg(long, default_value = "ws://127.0.0.1:8080/ws")]
    pub url: String,
    /// Views per sweep point, comma-separated (a stereo session has 2, a split one
    /// --split-views) [default: 1,4,8,16; with --sweep mixed: 3,6,9,12,15].
    #[arg(long, value_delimiter = ',')]
    pub viewers: Option<Vec<usize>>,
    /// The sweep: uniform (one frame size) or mixed (three sizes at once).
    #[arg(long, value_enum, default_value = "uniform")]
    pub sweep: SweepArg,
    /// Frame sizes to split each point's sessions over as evenly as possible,
    /// comma-separated WIDTHxHEIGHT, instead of --width and --height [default with
    /// --sweep mixed: 320x180,480x270,640x360].
    #[arg(long, value_delimiter = ',', conflicts_with_all = ["width", "height"])]
    pub mix: Option<Vec<FrameSize>>,
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
    /// Frame width each session asks for [default: 256].
    #[arg(long)]
    pub width: Option<u32>,
    /// Frame height each session asks for [default: 144].
    #[arg(long)]
    pub height: Option<u32>,
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
        let mixed = self.sweep == SweepArg::Mixed;
        let sizes = match &self.mix {
            Some(mix) => mix.clone(),
            None if mixed => {
                anyhow::ensure!(
                    self.width.is_none() && self.height.is_none(),
                    "--width/--height with --sweep mixed: the mixed sweep has its own sizes; choose them with --mix"
                );
                MIXED_SWEEP_SIZES.to_vec()
            }
            None => vec![FrameSize {
                width: self.width.unwrap_or(DEFAULT_SIZE.width),
                height: self.height.unwrap_or(DEFAULT_SIZE.height),
            }],
        };
        let viewers = match &self.viewers {
            Some(v) => v.clone(),
            None if mixed => MIXED_SWEEP_VIEWERS.to_vec(),
            None => DEFAULT_VIEWERS.to_vec(),
        };
        let c = LoadgenConfig {
            url: self.url.clone(),
            viewers,
            seconds: self.seconds,
            warmup_s: self.warmup,
            first_frame_timeout_s: self.first_frame_timeout,
            pose_hz: self.pose_hz,
            sizes,
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
            "{:>3} views: {}, frames every second: {}, served throughout: {}; server {:.1} render calls and {:.0} grid rays per frame",
            p.viewers,
            describe(s),
            if s.every_viewer_every_second { "yes" } else { "no" },
            if s.every_viewer_served_throughout { "yes" } else { "NO" },
            p.server.render_calls_per_frame,
            p.server.grid_rays_per_frame
        );
        if p.sizes.len() > 1 {
            for size in &p.sizes {
                println!(
                    "      {:>9} ({}): {}",
                    size.size.to_string(),
                    sessions_count(size.sessions),
                    describe(&size.summary)
                );
            }
        }
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

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser as _;

    #[derive(clap::Parser)]
    struct Cli {
        #[command(flatten)]
        args: LoadgenArgs,
    }

    fn config(flags: &[&str]) -> anyhow::Result<LoadgenConfig> {
        let cli = Cli::try_parse_from(std::iter::once("loadgen").chain(flags.iter().copied()))?;
        cli.args.config()
    }

    fn size(width: u32, height: u32) -> FrameSize {
        FrameSize { width, height }
    }

    #[test]
    fn sweeps_and_sizes_come_from_the_flags() {
        let c = config(&[]).unwrap();
        assert_eq!(
            (c.viewers, c.sizes),
            (DEFAULT_VIEWERS.to_vec(), vec![DEFAULT_SIZE])
        );
        let c = config(&["--width", "320"]).unwrap();
        assert_eq!(c.sizes, vec![size(320, DEFAULT_SIZE.height)]);
        let c = config(&["--sweep", "mixed"]).unwrap();
        assert_eq!(
            (c.viewers, c.sizes),
            (MIXED_SWEEP_VIEWERS.to_vec(), MIXED_SWEEP_SIZES.to_vec())
        );
        let c = config(&[
            "--sweep",
            "mixed",
            "--viewers",
            "6",
            "--mix",
            "64x36,128X72",
        ])
        .unwrap();
        assert_eq!(
            (c.viewers, c.sizes),
            (vec![6], vec![size(64, 36), size(128, 72)])
        );
        let c = config(&["--mix", "64x36,96x54"]).unwrap();
        assert_eq!(c.viewers, DEFAULT_VIEWERS.to_vec());
        assert_eq!(
            c.size_of_session(3),
            size(96, 54),
            "sessions take the sizes in turn"
        );

        let error = |flags: &[&str]| format!("{:#}", config(flags).unwrap_err());
        let e = error(&["--mix", "64x36", "--width", "320"]);
        assert!(e.contains("--width"), "{e}");
        let e = error(&["--sweep", "mixed", "--height", "100"]);
        assert!(e.contains("--mix"), "{e}");
        let e = error(&["--mix", "64by36"]);
        assert!(e.contains("WIDTHxHEIGHT"), "{e}");
        let e = error(&["--mix", "64x36,64x36"]);
        assert!(e.contains("64x36 is given twice"), "{e}");
        let e = error(&["--mix", "8x8"]);
        assert!(e.contains("8x8") && e.contains("16..=8192"), "{e}");
    }
}
