//! `fogcast loadgen` flags.

use super::{
    describe, run, sessions_count, write_report, Checks, FrameSize, LoadgenConfig, DEFAULT_SIZE,
    DEFAULT_VIEWERS, MIXED_SWEEP_SIZES, MIXED_SWEEP_VIEWERS,
};
use crate::protocol::{Codec, Layout};
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

/// Frame codec the viewers ask for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum CodecArg {
    /// Every frame a JPEG.
    Jpeg,
    /// An H.264 stream.
    H264,
}

/// Whether the viewers ack their frames.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum AckArg {
    /// Ack every frame (the server's flow control and bitrate adaptation use the acks).
    On,
    /// Never ack (the server paces by TCP back-pressure alone).
    Off,
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
    /// Frame codec each session asks for (h264 needs even frame sizes).
    #[arg(long, value_enum, default_value = "jpeg")]
    pub codec: CodecArg,
    /// Ack every frame received (`{"type":"ack"}`), which turns on the server's flow control.
    #[arg(long, value_enum, default_value = "on")]
    pub ack: AckArg,
    /// Bitrate ceiling each session asks for, kbit/s [default: the server's].
    #[arg(long)]
    pub max_kbps: Option<u32>,
    /// Image quality: ask for a raw frame every N frames (the server needs
    /// --debug-raw-frames), decode the encoded frames and report their PSNR.
    #[arg(long, value_name = "N")]
    pub raw_every: Option<u32>,
    /// Slow clients: the throttled viewers read their socket at K kbit/s.
    #[arg(long, value_name = "K")]
    pub throttle_kbps: Option<u32>,
    /// How many viewers of each point are throttled (the first ones) [default: 1 with
    /// --throttle-kbps].
    #[arg(long, value_name = "N")]
    pub throttled: Option<usize>,
    /// Cut the measured run into windows of W seconds (latency, fps and server memory per
    /// window, to show creep).
    #[arg(long, value_name = "W", default_value_t = LoadgenConfig::default().window_s)]
    pub window_s: f64,
    /// Churn: every viewer closes and reopens its session every S seconds (staggered).
    #[arg(long, value_name = "S")]
    pub churn_s: Option<f64>,
    /// Measure the unthrottled viewers alone for B seconds first (the reference of
    /// --check-fps-within); the throttled viewers join afterwards.
    #[arg(long, value_name = "B")]
    pub baseline_s: Option<f64>,
    /// Check: every class's pose-to-frame p95 at most X ms.
    #[arg(long, value_name = "X")]
    pub check_latency_p95_ms: Option<f64>,
    /// Check: the throttled class's p95 in the last window at most R × the first window's.
    #[arg(long, value_name = "R")]
    pub check_creep: Option<f64>,
    /// Check: the unthrottled viewers' fps at least (1 − F) × the baseline's (F a
    /// fraction, 0.1 = 10 %): a slow client costs the others no more than that.
    #[arg(long, value_name = "F")]
    pub check_fps_within: Option<f64>,
    /// Check: the server's RSS in the last window at most (1 + G) × the second window's.
    #[arg(long, value_name = "G")]
    pub check_memory_growth: Option<f64>,
    /// Check: every session loadgen opened was counted by the server and closed.
    #[arg(long)]
    pub check_sessions: bool,
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
            codec: match self.codec {
                CodecArg::Jpeg => Codec::Jpeg,
                CodecArg::H264 => Codec::H264,
            },
            ack: self.ack == AckArg::On,
            max_kbps: self.max_kbps,
            raw_every: self.raw_every,
            throttle_kbps: self.throttle_kbps,
            throttled: match (self.throttle_kbps, self.throttled) {
                (_, Some(n)) => n,
                (Some(_), None) => 1,
                (None, None) => 0,
            },
            window_s: self.window_s,
            churn_s: self.churn_s,
            baseline_s: self.baseline_s,
            checks: Checks {
                latency_p95_ms: self.check_latency_p95_ms,
                creep: self.check_creep,
                fps_within: self.check_fps_within,
                memory_growth: self.check_memory_growth,
                sessions: self.check_sessions,
            },
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
        for c in p.classes.iter().filter(|_| p.classes.len() > 1) {
            println!(
                "      {} ({}): {}",
                c.class.as_str(),
                sessions_count(c.sessions),
                describe(&c.summary)
            );
        }
        if let Some(q) = s.quality {
            println!(
                "      PSNR mean {:.2} dB, min {:.2} dB over {} frames; {:.0} bytes per encoded frame, {} key frames, {} decode errors",
                q.psnr_mean_db, q.psnr_min_db, q.compared, s.encoded_bytes_per_frame, s.key_frames, s.decode_errors
            );
        }
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
    for c in &report.checks {
        println!(
            "check {} at {} views: {}: {}",
            c.check,
            c.views,
            if c.passed { "pass" } else { "FAIL" },
            c.detail
        );
    }
    let failed = report.failed_checks();
    if !failed.is_empty() {
        anyhow::bail!(
            "{} of {} checks failed: {}",
            failed.len(),
            report.checks.len(),
            failed
                .iter()
                .map(|c| format!("{} at {} views ({})", c.check, c.views, c.detail))
                .collect::<Vec<_>>()
                .join("; ")
        );
    }
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

    #[test]
    fn streaming_flags_and_their_errors() {
        let c = config(&[]).unwrap();
        assert_eq!(
            (c.codec, c.ack, c.throttled, c.raw_every),
            (Codec::Jpeg, true, 0, None)
        );
        let c = config(&[
            "--codec",
            "h264",
            "--ack",
            "off",
            "--throttle-kbps",
            "1000",
            "--raw-every",
            "5",
            "--viewers",
            "4",
            "--baseline-s",
            "30",
            "--check-fps-within",
            "0.1",
            "--seconds",
            "300",
            "--window-s",
            "60",
            "--check-creep",
            "1.2",
            "--check-sessions",
        ])
        .unwrap();
        assert_eq!(
            (c.codec, c.ack, c.throttle_kbps, c.throttled),
            (Codec::H264, false, Some(1000), 1)
        );
        assert_eq!((c.raw_every, c.windows()), (Some(5), 5));
        assert!(c.checks.sessions && c.checks.any());
        let hello = c.hello(c.sizes[0]);
        assert_eq!((hello.codec, hello.raw_every), (Some(Codec::H264), Some(5)));

        let error = |flags: &[&str]| format!("{:#}", config(flags).unwrap_err());
        let e = error(&["--codec", "h264", "--width", "255"]);
        assert!(e.contains("even"), "{e}");
        let e = error(&["--throttled", "2"]);
        assert!(e.contains("--throttle-kbps"), "{e}");
        let e = error(&[
            "--throttle-kbps",
            "500",
            "--throttled",
            "3",
            "--viewers",
            "2",
        ]);
        assert!(e.contains("only 2 sessions"), "{e}");
        let e = error(&[
            "--throttle-kbps",
            "500",
            "--viewers",
            "1",
            "--baseline-s",
            "5",
        ]);
        assert!(e.contains("unthrottled"), "{e}");
        let e = error(&["--check-fps-within", "0.1"]);
        assert!(e.contains("--baseline-s"), "{e}");
        let e = error(&[
            "--check-memory-growth",
            "0.1",
            "--seconds",
            "60",
            "--window-s",
            "30",
        ]);
        assert!(e.contains("makes 2"), "{e}");
        let e = error(&["--raw-every", "0"]);
        assert!(e.contains("--raw-every 0"), "{e}");
        let e = error(&[
            "--check-creep",
            "0.5",
            "--seconds",
            "30",
            "--window-s",
            "10",
        ]);
        assert!(e.contains("--check-creep 0.5"), "{e}");
    }
}
