//! The loadgen report: loadgen.json (everything), loadgen.csv (one row per viewer per
//! point), loadgen.md (tables; per frame size too when the sweep mixes sizes; viewer
//! classes, windows, image quality, sessions and checks when the run has them) and PNG
//! plots of fps, latency and the largest point's per-second timeline.

use super::{size_list, Latency, LoadgenReport, PointResult, PointSummary};
use crate::report::{plot, Series, Table};
use anyhow::Context as _;
use std::path::{Path, PathBuf};

fn f1(v: f64) -> String {
    format!("{v:.1}")
}

fn opt_ms(v: Option<f64>) -> String {
    v.map_or_else(|| "–".into(), |v| format!("{v:.1}"))
}

fn lat(l: &Option<Latency>, pick: fn(&Latency) -> f64) -> String {
    l.as_ref()
        .map_or_else(|| "–".into(), |l| format!("{:.0}", pick(l)))
}

fn kib(bytes_per_s: f64) -> String {
    format!("{:.0}", bytes_per_s / 1024.0)
}

fn served(s: &PointSummary) -> String {
    if s.every_viewer_served_throughout {
        "yes".into()
    } else {
        format!("**no** ({} ended early)", s.viewers_ended_early)
    }
}

/// Writes the report's files into `out` (created if missing); returns their paths.
pub fn write_report(report: &LoadgenReport, out: &Path) -> anyhow::Result<Vec<PathBuf>> {
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let mut written = Vec::new();
    let mut write = |name: &str, text: String| -> anyhow::Result<()> {
        let path = out.join(name);
        std::fs::write(&path, text).with_context(|| format!("writing {}", path.display()))?;
        written.push(path);
        Ok(())
    };
    write("loadgen.json", serde_json::to_string_pretty(report)? + "\n")?;
    write("loadgen.csv", viewer_table(&report.points).to_csv())?;
    write("loadgen.md", markdown(report))?;
    for name in plots(report, out)? {
        written.push(out.join(name));
    }
    Ok(written)
}

/// Every viewer of `points`, one row each.
fn viewer_table(points: &[PointResult]) -> Table {
    let mut t = Table::new(&[
        "views",
        "viewer",
        "session",
        "size",
        "fps",
        "frames",
        "latency_p50_ms",
        "latency_p95_ms",
        "latency_p99_ms",
        "latency_samples",
        "kib_per_s",
        "dropped_server",
        "missed_frames",
        "longest_gap_ms",
        "seconds_without_frames",
        "served_throughout",
        "class",
        "encoded_bytes_per_frame",
        "key_frames",
        "psnr_mean_db",
        "psnr_min_db",
        "psnr_frames",
        "decode_errors",
        "sessions_opened",
        "frames_per_second",
    ]);
    for p in points {
        for v in &p.per_viewer {
            t.push(vec![
                p.viewers.to_string(),
                v.index.to_string(),
                v.session.to_string(),
                v.size.to_string(),
                f1(v.fps),
                v.frames.to_string(),
                lat(&v.latency, |l| l.p50_ms),
                lat(&v.latency, |l| l.p95_ms),
                lat(&v.latency, |l| l.p99_ms),
                v.latency.map_or(0, |l| l.samples).to_string(),
                kib(v.bytes_per_s),
                v.dropped_server.to_string(),
                v.missed_frames.to_string(),
                format!("{:.0}", v.max_gap_ms),
                v.seconds_without_frames.to_string(),
                v.served_throughout.to_string(),
                if v.throttled {
                    "throttled"
                } else {
                    "unthrottled"
                }
                .into(),
                format!("{:.0}", v.encoded_bytes_per_frame),
                v.key_frames.to_string(),
                v.quality
                    .map_or_else(|| "–".into(), |q| format!("{:.2}", q.psnr_mean_db)),
                v.quality
                    .map_or_else(|| "–".into(), |q| format!("{:.2}", q.psnr_min_db)),
                v.quality.map_or(0, |q| q.compared).to_string(),
                v.decode_errors.to_string(),
                v.sessions_opened.to_string(),
                v.timeline
                    .iter()
                    .map(u32::to_string)
                    .collect::<Vec<_>>()
                    .join(" "),
            ]);
        }
    }
    t
}

fn markdown(r: &LoadgenReport) -> String {
    let c = &r.config;
    let mut md = String::from("# fogcast loadgen\n\n");
    if !r.command.is_empty() {
        md += &format!("Command: `{}`\n\n", r.command);
    }
    md += &format!(
        "Server `{}`, scene `{}` (at most {} views). Machine: {}. The whole run took {:.0} s.\n\n\
         Each session asks for {} frames at {}, JPEG quality {}, and sends a pose {} times a second; \
         camera paths: {}. Each point is measured for {} s after every viewer has frames and a {} s warm-up.\n\n",
        c.url, r.scene, r.server_max_viewers, r.machine, r.duration_s,
        format!("{:?}", c.layout).to_lowercase(), size_list(&c.sizes),
        c.quality, c.pose_hz, r.camera_paths, c.seconds, c.warmup_s
    );
    let mixed = c.sizes.len() > 1;
    md += "## Per point\n\nfps and bandwidth per viewer (one session); latency is pose-to-frame over every viewer's samples; \
           *dropped* are frames the server replaced or skipped for a session (its header counter), *missed* the \
           render-loop frames a session did not receive; *every second* says every viewer received frames in every \
           second of the window; *served throughout* says every viewer stayed connected and either had frames in every \
           second or received every frame the server rendered (below 1 server fps some seconds have no frame for \
           anyone); *load avg* is this machine's 1-minute load average at the end of the window (other work competes \
           with the CPU renderer).\n\n";
    let mut headers = vec!["views"];
    if mixed {
        headers.push("sessions per size");
    }
    headers.extend([
        "fps/viewer mean",
        "min",
        "max",
        "server fps",
        "frame ms",
        "latency p50 ms",
        "p95 ms",
        "p99 ms",
        "KiB/s per viewer",
        "MiB/s total",
        "dropped",
        "missed",
        "longest gap ms",
        "every second",
        "served throughout",
        "load avg",
    ]);
    let mut t = Table::new(&headers);
    for p in &r.points {
        let s = &p.summary;
        let mut row = vec![p.viewers.to_string()];
        if mixed {
            row.push(
                p.sizes
                    .iter()
                    .map(|z| format!("{}: {}", z.size, z.sessions))
                    .collect::<Vec<_>>()
                    .join(", "),
            );
        }
        row.extend([
            f1(s.fps_mean),
            f1(s.fps_min),
            f1(s.fps_max),
            f1(p.server.fps),
            opt_ms(p.server.frame_ms),
            lat(&s.latency, |l| l.p50_ms),
            lat(&s.latency, |l| l.p95_ms),
            lat(&s.latency, |l| l.p99_ms),
            kib(s.bytes_per_s_per_viewer),
            format!("{:.2}", s.bytes_per_s_total / (1024.0 * 1024.0)),
            s.dropped_server_total.to_string(),
            s.missed_frames_total.to_string(),
            format!("{:.0}", s.max_gap_ms),
            if s.every_viewer_every_second {
                "yes".into()
            } else {
                "no".into()
            },
            served(s),
            p.load_average_1m.map_or_else(|| "–".into(), f1),
        ]);
        t.push(row);
    }
    md += &t.to_markdown();
    md += &streaming_sections(r);

    if mixed {
        md += "\n## Per frame size\n\nThe viewers of each size within each point: fps and bandwidth per viewer, \
               latency over that size's samples.\n\n";
        let mut t = Table::new(&[
            "views",
            "size",
            "sessions",
            "fps/viewer mean",
            "min",
            "max",
            "latency p50 ms",
            "p95 ms",
            "p99 ms",
            "KiB/s per viewer",
            "dropped",
            "missed",
            "served throughout",
        ]);
        for p in &r.points {
            for z in &p.sizes {
                let s = &z.summary;
                t.push(vec![
                    p.viewers.to_string(),
                    z.size.to_string(),
                    z.sessions.to_string(),
                    f1(s.fps_mean),
                    f1(s.fps_min),
                    f1(s.fps_max),
                    lat(&s.latency, |l| l.p50_ms),
                    lat(&s.latency, |l| l.p95_ms),
                    lat(&s.latency, |l| l.p99_ms),
                    kib(s.bytes_per_s_per_viewer),
                    s.dropped_server_total.to_string(),
                    s.missed_frames_total.to_string(),
                    served(s),
                ]);
            }
        }
        md += &t.to_markdown();
    }

    md += "\n## Server per point (`/metrics` over the window)\n\nframe: one render-loop iteration; render: one render \
           call, upload to readback; encode: JPEG of one session frame; GPU ms per stage from \
           timestamp queries; rays per frame over all stages; *render calls/frame*: render calls per \
           render-loop frame (1: every session of every size in one call on one world; a server with a \
           renderer per view size makes one per size); *grid rays/frame*: rays traced into the shared \
           world-space shadow grid per render-loop frame (one grid's worth when every view size shares the \
           grid, times the number of sizes when each render call fills its own), and per render call.\n\n";
    let stages: Vec<String> = {
        let mut s: Vec<String> = r
            .points
            .iter()
            .flat_map(|p| p.server.stage_gpu_ms.keys().cloned())
            .collect();
        s.sort();
        s.dedup();
        s
    };
    let mut headers: Vec<String> = ["views", "frames", "frame ms", "render ms", "encode ms"]
        .iter()
        .map(|s| s.to_string())
        .collect();
    headers.extend(stages.iter().map(|s| format!("{s} GPU ms")));
    headers.extend(
        [
            "rays/frame",
            "render calls/frame",
            "grid rays/frame",
            "grid rays/call",
            "dropped slow",
            "dropped busy",
            "RSS MiB",
        ]
        .iter()
        .map(|s| s.to_string()),
    );
    let mut t = Table {
        headers,
        rows: Vec::new(),
    };
    for p in &r.points {
        let s = &p.server;
        let mut row = vec![
            p.viewers.to_string(),
            s.frames.to_string(),
            opt_ms(s.frame_ms),
            opt_ms(s.render_ms),
            opt_ms(s.encode_ms),
        ];
        row.extend(
            stages
                .iter()
                .map(|st| opt_ms(s.stage_gpu_ms.get(st).copied())),
        );
        row.push(format!("{:.0}", s.rays_per_frame.values().sum::<f64>()));
        row.push(format!("{:.2}", s.render_calls_per_frame));
        row.push(format!("{:.0}", s.grid_rays_per_frame));
        row.push(format!("{:.0}", s.grid_rays_per_render_call));
        row.push(s.dropped_client_slow.to_string());
        row.push(s.dropped_encoder_busy.to_string());
        row.push(format!("{:.0}", s.resident_memory_mib));
        t.push(row);
    }
    md += &t.to_markdown();

    if let Some(p) = r.points.iter().max_by_key(|p| p.viewers) {
        md += &format!(
            "\n## Every viewer at {} views\n\nThe last column is the frames each viewer received in each second of the {:.0} s window.\n\n",
            p.viewers, p.window_s
        );
        let full = viewer_table(std::slice::from_ref(p));
        // The markdown keeps the columns the heading does not already give.
        let mut columns = vec!["viewer"];
        if mixed {
            columns.push("size");
        }
        columns.extend([
            "fps",
            "frames",
            "latency_p50_ms",
            "latency_p95_ms",
            "latency_p99_ms",
            "kib_per_s",
            "dropped_server",
            "missed_frames",
            "longest_gap_ms",
            "frames_per_second",
        ]);
        let keep: Vec<usize> = columns
            .iter()
            .filter_map(|name| full.headers.iter().position(|h| h == name))
            .collect();
        let t = Table {
            headers: keep.iter().map(|&i| full.headers[i].clone()).collect(),
            rows: full
                .rows
                .iter()
                .map(|row| keep.iter().map(|&i| row[i].clone()).collect())
                .collect(),
        };
        md += &t.to_markdown();
        let errors: Vec<String> = p
            .per_viewer
            .iter()
            .flat_map(|v| {
                v.server_errors
                    .iter()
                    .map(move |e| format!("- viewer {}: {e}", v.index))
                    .chain(
                        v.ended_early
                            .iter()
                            .map(move |e| format!("- viewer {} ended early: {e}", v.index)),
                    )
            })
            .collect();
        if !errors.is_empty() {
            md += &format!("\nServer errors and early ends:\n\n{}\n", errors.join("\n"));
        }
    }
    md += "\n![fps vs viewers](loadgen_fps.png)\n\n![latency vs viewers](loadgen_latency.png)\n\n\
           ![frames per second of the largest point](loadgen_timeline.png)\n";
    if r.points.iter().any(|p| p.server_windows.len() > 1) {
        md += "\n![p95 latency per window](loadgen_windows.png)\n";
    }
    md
}

/// The streaming scenario's sections (issue 17): viewer classes and baseline, windows
/// over time, image quality, sessions, checks — each only when the run has it.
fn streaming_sections(r: &LoadgenReport) -> String {
    let c = &r.config;
    let mut md = format!(
        "\nCodec {}, acks {}{}{}.\n",
        c.codec.as_str(),
        match (c.ack, refused(r)) {
            (false, _) => "off",
            (true, false) => "on",
            (true, true) => "on (but the server did not know them: `unknown_type`; those viewers stopped acking)",
        },
        c.max_kbps
            .map_or_else(String::new, |k| format!(", at most {k} kbit/s")),
        c.churn_s.map_or_else(String::new, |s| format!(
            ", every session closed and reopened every {s} s (staggered)"
        )),
    );
    let throttled = r
        .points
        .iter()
        .any(|p| p.classes.len() > 1 || p.baseline.is_some());
    if throttled {
        md += &format!(
            "\n## Viewer classes\n\nThe first {} viewer(s) of each point read their socket at {} kbit/s (*throttled*); \
             *baseline* is the unthrottled viewers measured while every viewer had a fast link, before the throttled ones reconnected through theirs.\n\n",
            c.throttled,
            c.throttle_kbps.map_or_else(|| "–".into(), |k| k.to_string())
        );
        let mut t = Table::new(&[
            "views",
            "class",
            "sessions",
            "fps/viewer mean",
            "min",
            "latency p50 ms",
            "p95 ms",
            "p99 ms",
            "KiB/s per viewer",
            "dropped",
            "bytes/frame",
        ]);
        for p in &r.points {
            let rows = p
                .baseline
                .iter()
                .map(|b| {
                    (
                        "baseline (every link fast)".to_string(),
                        b.sessions,
                        &b.summary,
                    )
                })
                .chain(
                    p.classes
                        .iter()
                        .map(|k| (k.class.as_str().to_string(), k.sessions, &k.summary)),
                );
            for (name, sessions, s) in rows {
                t.push(vec![
                    p.viewers.to_string(),
                    name,
                    sessions.to_string(),
                    f1(s.fps_mean),
                    f1(s.fps_min),
                    lat(&s.latency, |l| l.p50_ms),
                    lat(&s.latency, |l| l.p95_ms),
                    lat(&s.latency, |l| l.p99_ms),
                    kib(s.bytes_per_s_per_viewer),
                    s.dropped_server_total.to_string(),
                    format!("{:.0}", s.encoded_bytes_per_frame),
                ]);
            }
        }
        md += &t.to_markdown();
    }
    if r.points.iter().any(|p| p.server_windows.len() > 1) {
        md += &format!(
            "\n## Over time\n\nThe measured run in windows of about {} s: each class's mean fps per viewer and pooled \
             p95 latency, and the server's largest resident memory, per window (creep shows as the last window \
             against the first).\n\n",
            c.window_s
        );
        let mut t = Table::new(&[
            "views",
            "window s",
            "class",
            "fps/viewer",
            "p95 ms",
            "samples",
            "server RSS MiB",
        ]);
        for p in &r.points {
            for (i, w) in p.server_windows.iter().enumerate() {
                for k in &p.classes {
                    let Some(kw) = k.windows.get(i) else { continue };
                    t.push(vec![
                        p.viewers.to_string(),
                        format!("{:.0}–{:.0}", w.start_s, w.end_s),
                        k.class.as_str().into(),
                        f1(kw.fps_mean),
                        opt_ms(kw.latency_p95_ms),
                        kw.latency_samples.to_string(),
                        w.resident_memory_mib
                            .map_or_else(|| "–".into(), |m| format!("{m:.0}")),
                    ]);
                }
            }
        }
        md += &t.to_markdown();
    }
    if r.points
        .iter()
        .any(|p| p.summary.quality.is_some() || p.summary.decode_errors > 0)
    {
        md += &format!(
            "\n## Image quality\n\nEach viewer decoded its {} frames and compared every one that had a raw frame \
             (one in {}) with it: PSNR over R, G and B of every pixel (identical pictures count as {} dB); \
             bytes per frame are the encoded payload alone.\n\n",
            c.codec.as_str(),
            c.raw_every.map_or_else(|| "–".into(), |n| n.to_string()),
            crate::loadgen::quality::PSNR_CAP_DB
        );
        let mut t = Table::new(&[
            "views",
            "viewer",
            "compared",
            "PSNR mean dB",
            "PSNR min dB",
            "bytes/frame",
            "key frames",
            "decode errors",
        ]);
        for p in &r.points {
            for v in &p.per_viewer {
                t.push(vec![
                    p.viewers.to_string(),
                    v.index.to_string(),
                    v.quality.map_or(0, |q| q.compared).to_string(),
                    v.quality
                        .map_or_else(|| "–".into(), |q| format!("{:.2}", q.psnr_mean_db)),
                    v.quality
                        .map_or_else(|| "–".into(), |q| format!("{:.2}", q.psnr_min_db)),
                    format!("{:.0}", v.encoded_bytes_per_frame),
                    v.key_frames.to_string(),
                    v.decode_errors.to_string(),
                ]);
            }
            let s = &p.summary;
            t.push(vec![
                p.viewers.to_string(),
                "all".into(),
                s.quality.map_or(0, |q| q.compared).to_string(),
                s.quality
                    .map_or_else(|| "–".into(), |q| format!("{:.2}", q.psnr_mean_db)),
                s.quality
                    .map_or_else(|| "–".into(), |q| format!("{:.2}", q.psnr_min_db)),
                format!("{:.0}", s.encoded_bytes_per_frame),
                s.key_frames.to_string(),
                s.decode_errors.to_string(),
            ]);
        }
        md += &t.to_markdown();
    }
    md += "\n## Sessions\n\nSessions loadgen opened (churn included) against the server's `fogcast_sessions_total` \
           (and `fogcast_sessions_closed_total` where the server has it) from before the first hello to after the \
           server let the last session go, and its open sessions before and after.\n\n";
    let mut t = Table::new(&[
        "views",
        "opened by loadgen",
        "reopen failures",
        "server opened",
        "server closed",
        "open before",
        "open after",
        "accounted",
    ]);
    for p in &r.points {
        let a = &p.sessions_accounting;
        t.push(vec![
            p.viewers.to_string(),
            a.opened_by_loadgen.to_string(),
            a.reopen_failures.to_string(),
            a.server_opened.to_string(),
            a.server_closed
                .map_or_else(|| "–".into(), |n| n.to_string()),
            a.open_before.to_string(),
            a.open_after.to_string(),
            if a.accounted {
                "yes".into()
            } else {
                "**no**".into()
            },
        ]);
    }
    md += &t.to_markdown();
    if !r.checks.is_empty() {
        md += "\n## Checks\n\n";
        for k in &r.checks {
            md += &format!(
                "- {} `{}` at {} views: {}\n",
                if k.passed { "pass" } else { "**FAIL**" },
                k.check,
                k.views,
                k.detail
            );
        }
    }
    md
}

/// Whether some viewer's acks were refused by a server from before acks.
fn refused(r: &LoadgenReport) -> bool {
    r.points
        .iter()
        .any(|p| p.per_viewer.iter().any(|v| v.acks_refused))
}

/// Writes the plots; returns their file names.
fn plots(r: &LoadgenReport, out: &Path) -> anyhow::Result<Vec<&'static str>> {
    let x = |p: &PointResult| p.viewers as f64;
    let series = |name: &str, f: &dyn Fn(&PointResult) -> Option<f64>| Series {
        name: name.into(),
        points: r
            .points
            .iter()
            .filter_map(|p| Some((x(p), f(p)?)))
            .collect(),
    };
    // A mixed sweep adds one line per frame size.
    let per_size = |pick: fn(&PointSummary) -> Option<f64>, what: &str| -> Vec<Series> {
        if r.config.sizes.len() < 2 {
            return Vec::new();
        }
        r.config
            .sizes
            .iter()
            .map(|&size| {
                series(&format!("{size}, {what}"), &|p| {
                    pick(&p.sizes.iter().find(|z| z.size == size)?.summary)
                })
            })
            .collect()
    };
    let mut fps = vec![
        series("per viewer, mean", &|p| Some(p.summary.fps_mean)),
        series("per viewer, lowest", &|p| Some(p.summary.fps_min)),
        series("server render loop", &|p| Some(p.server.fps)),
    ];
    fps.extend(per_size(|s| Some(s.fps_mean), "mean per viewer"));
    plot(
        &out.join("loadgen_fps.png"),
        "Delivered frame rate vs viewers",
        "viewers (views)",
        "frames per second",
        &fps,
        true,
        false,
        false,
    )?;
    let l = |pick: fn(&Latency) -> f64| move |p: &PointResult| p.summary.latency.as_ref().map(pick);
    let mut latency = vec![
        series("p50", &l(|l| l.p50_ms)),
        series("p95", &l(|l| l.p95_ms)),
        series("p99", &l(|l| l.p99_ms)),
    ];
    latency.extend(per_size(|s| Some(s.latency?.p50_ms), "p50"));
    plot(
        &out.join("loadgen_latency.png"),
        "Pose-to-frame latency vs viewers",
        "viewers (views)",
        "latency, ms",
        &latency,
        true,
        false,
        false,
    )?;
    let mut names = vec!["loadgen_fps.png", "loadgen_latency.png"];
    let largest = r
        .points
        .iter()
        .filter(|p| !p.per_viewer.is_empty())
        .max_by_key(|p| p.viewers);
    if let Some(p) = largest {
        let seconds = p
            .per_viewer
            .iter()
            .map(|v| v.timeline.len())
            .max()
            .unwrap_or(0);
        let at = |i: usize, pick: fn(&[u32]) -> u32| {
            let mut v: Vec<u32> = p
                .per_viewer
                .iter()
                .map(|v| v.timeline.get(i).copied().unwrap_or(0))
                .collect();
            v.sort_unstable();
            f64::from(pick(&v))
        };
        let line = |name: &str, pick: fn(&[u32]) -> u32| Series {
            name: name.into(),
            points: (0..seconds)
                .map(|i| (i as f64 + 0.5, at(i, pick)))
                .collect(),
        };
        plot(
            &out.join("loadgen_timeline.png"),
            &format!(
                "Frames each viewer received per second, {} views",
                p.viewers
            ),
            "second of the measured window",
            "frames in that second",
            &[
                line("most", |v| v[v.len() - 1]),
                line("median", |v| v[v.len() / 2]),
                line("fewest", |v| v[0]),
            ],
            true,
            false,
            false,
        )?;
        names.push("loadgen_timeline.png");
    }
    // Creep: p95 latency per window of each class of the largest point with windows.
    let windowed = r
        .points
        .iter()
        .filter(|p| p.server_windows.len() > 1)
        .max_by_key(|p| p.viewers);
    if let Some(p) = windowed {
        let lines: Vec<Series> = p
            .classes
            .iter()
            .map(|c| Series {
                name: format!("{} p95", c.class.as_str()),
                points: c
                    .windows
                    .iter()
                    .filter_map(|w| Some(((w.start_s + w.end_s) / 2.0, w.latency_p95_ms?)))
                    .collect(),
            })
            .collect();
        plot(
            &out.join("loadgen_windows.png"),
            &format!("p95 pose-to-frame latency per window, {} views", p.viewers),
            "seconds into the measured run (window middle)",
            "p95 latency, ms",
            &lines,
            true,
            false,
            false,
        )?;
        names.push("loadgen_windows.png");
    }
    Ok(names)
}
