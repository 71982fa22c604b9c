//! One sweep point: open the sessions (the unthrottled ones first when there is a
//! baseline), wait for every viewer's first frames, measure (scraping `/metrics` once a
//! second for the server's memory), stop the viewers, turn their records into the
//! point's numbers, and wait for the server to let the sessions go.

use super::client::{self, Behaviour, Flight, Live, Target, ViewerRecord, Ws};
use super::paths::Paths;
use super::{
    describe, scrape, sessions_count, stats, Baseline, ClassResult, FrameSize, LoadgenConfig,
    PointResult, SessionAccounting, ViewerClass, ViewerStats,
};
use crate::protocol::Welcome;
use anyhow::Context as _;
use std::sync::atomic::Ordering::Relaxed;
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio::sync::watch;

/// Longest wait for the server to let the previous point's sessions go.
const DRAIN_TIMEOUT: Duration = Duration::from_secs(30);

/// A viewer task of a point and what the coordinator needs of it.
struct Running {
    index: usize,
    session: u64,
    views: u32,
    live: Arc<Live>,
    task: tokio::task::JoinHandle<ViewerRecord>,
}

/// What every viewer of a point shares.
struct PointContext<'a> {
    config: &'a LoadgenConfig,
    target: &'a Target,
    paths: &'a Arc<Paths>,
    sessions: usize,
    throttled: usize,
    size_of: Vec<FrameSize>,
    epoch: Instant,
    stop: watch::Receiver<bool>,
}

impl PointContext<'_> {
    /// Opens the sessions `indices` (hello → welcome, one after the other) and starts
    /// their viewers.
    /// Opens viewers `indices`; the first `throttled` of the point read through their
    /// throttle when `throttle` (the baseline phase runs them unthrottled).
    async fn launch(
        &self,
        indices: impl Iterator<Item = usize>,
        throttle: bool,
        slots_per_session: &mut Option<usize>,
    ) -> anyhow::Result<Vec<Running>> {
        let c = self.config;
        let mut opened: Vec<(usize, Ws, Welcome)> = Vec::new();
        let throttle_of = |i: usize| {
            (throttle && i < self.throttled)
                .then_some(c.throttle_kbps)
                .flatten()
        };
        for i in indices {
            let size = self.size_of[i];
            let throttle = throttle_of(i);
            let (ws, welcome) = client::open(self.target, &c.hello(size), throttle)
                .await
                .with_context(|| format!("viewer {i} of {} ({size})", self.sessions))?;
            opened.push((i, ws, welcome));
        }
        let mut running = Vec::with_capacity(opened.len());
        for (i, ws, welcome) in opened {
            let slots = *slots_per_session.get_or_insert(welcome.poses.len().max(1));
            let live = Arc::new(Live::default());
            let flight = Flight {
                paths: self.paths.clone(),
                first_slot: i * slots,
                slots: self.sessions * slots,
                pose_hz: c.pose_hz,
                epoch: self.epoch,
            };
            // Staggered: viewer i of n first churns (i + 1) / n of a period in.
            let churn = c.churn_s.map(|s| {
                let period = Duration::from_secs_f64(s);
                (
                    period.mul_f64((i + 1) as f64 / self.sessions as f64),
                    period,
                )
            });
            let behaviour = Behaviour {
                target: self.target.clone(),
                hello: c.hello(self.size_of[i]),
                throttle_kbps: throttle_of(i),
                ack: c.ack,
                measure_quality: c.raw_every.is_some(),
                churn,
            };
            running.push(Running {
                index: i,
                session: welcome.session,
                views: welcome.views,
                live: live.clone(),
                task: tokio::spawn(client::stream(
                    ws,
                    welcome,
                    flight,
                    behaviour,
                    live,
                    self.stop.clone(),
                )),
            });
        }
        Ok(running)
    }
}

/// Waits until every viewer of `running` has a frame; the error names who ended or waits.
async fn wait_first_frames(running: &[Running], timeout_s: f64) -> anyhow::Result<()> {
    let deadline = Instant::now() + Duration::from_secs_f64(timeout_s);
    loop {
        if let Some((i, why)) = running
            .iter()
            .find_map(|r| Some((r.index, r.live.ended()?)))
        {
            anyhow::bail!("viewer {i} ended before its first frames: {why}");
        }
        if running.iter().all(|r| r.live.frames.load(Relaxed) > 0) {
            return Ok(());
        }
        if Instant::now() > deadline {
            let waiting: Vec<usize> = running
                .iter()
                .filter(|r| r.live.frames.load(Relaxed) == 0)
                .map(|r| r.index)
                .collect();
            anyhow::bail!(
                "viewers {waiting:?} got no frame within {timeout_s} s (--first-frame-timeout)"
            );
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

/// One measured stretch: its ends, `/metrics` at both, and the server's resident memory
/// scraped once a second in between.
struct Measured {
    t0: Instant,
    t1: Instant,
    before: scrape::Scrape,
    after: scrape::Scrape,
    rss_bytes: Vec<(Instant, f64)>,
}

/// Measures `seconds`, printing the frames per viewer of each second.
async fn measure(
    target: &Target,
    running: &[Running],
    seconds: f64,
    label: &str,
    progress: &(dyn Fn(&str) + Sync),
) -> anyhow::Result<Measured> {
    let before = scrape::metrics(&target.authority).await?;
    let t0 = Instant::now();
    let mut rss_bytes = vec![(t0, before.get(RSS, ""))];
    let window = Duration::from_secs_f64(seconds);
    let mut last: Vec<u64> = running
        .iter()
        .map(|r| r.live.frames.load(Relaxed))
        .collect();
    let mut second = 0;
    while t0.elapsed() < window {
        let next = t0 + Duration::from_secs(second + 1);
        let wake = next.min(t0 + window);
        tokio::time::sleep_until(wake.into()).await;
        second += 1;
        let now: Vec<u64> = running
            .iter()
            .map(|r| r.live.frames.load(Relaxed))
            .collect();
        let mut got: Vec<u64> = now.iter().zip(&last).map(|(a, b)| a - b).collect();
        got.sort_unstable();
        last = now;
        if t0.elapsed() < window {
            let m = scrape::metrics(&target.authority).await?;
            rss_bytes.push((m.at, m.get(RSS, "")));
        }
        progress(&format!(
            "loadgen: {label}: {:>4.0} s  frames in the last second per viewer: min {} median {} max {}",
            t0.elapsed().as_secs_f64(),
            got[0],
            got[got.len() / 2],
            got[got.len() - 1]
        ));
    }
    let t1 = Instant::now();
    let after = scrape::metrics(&target.authority).await?;
    rss_bytes.push((after.at, after.get(RSS, "")));
    Ok(Measured {
        t0,
        t1,
        before,
        after,
        rss_bytes,
    })
}

/// The server's resident memory gauge.
const RSS: &str = "fogcast_resident_memory_bytes";
/// Counter of sessions the server opened, and (when the server has it) closed.
const SESSIONS_OPENED: &str = "fogcast_sessions_total";
const SESSIONS_CLOSED: &str = "fogcast_sessions_closed_total";

pub(super) async fn run_point(
    config: &LoadgenConfig,
    target: &Target,
    paths: &Arc<Paths>,
    views: usize,
    progress: &(dyn Fn(&str) + Sync),
) -> anyhow::Result<PointResult> {
    let per = config.views_per_session();
    let sessions = views / per;
    let throttled = config.throttled_of(sessions);
    let start = scrape::metrics(&target.authority).await?;
    let open_before = start.get("fogcast_sessions", "");
    let size_of: Vec<FrameSize> = (0..sessions).map(|i| config.size_of_session(i)).collect();
    progress(&format!(
        "loadgen: {views} views: opening {sessions} sessions ({}){}",
        sessions_per_size(&config.sizes, &size_of),
        match config.throttle_kbps {
            Some(k) if throttled > 0 => format!(", the first {throttled} reading at {k} kbit/s"),
            _ => String::new(),
        }
    ));
    let (stop_tx, stop_rx) = watch::channel(false);
    // Stops the viewers whatever happens below (an error, a timeout).
    let _stop_guard = StopOnDrop(stop_tx.clone());
    let ctx = PointContext {
        config,
        target,
        paths,
        sessions,
        throttled,
        size_of: size_of.clone(),
        epoch: Instant::now(),
        stop: stop_rx,
    };
    let mut slots = None;
    let opened_at = Instant::now();
    let label = format!("{views} views");

    // With a baseline every viewer starts on a fast link — the same views, so the same
    // render cost — and the throttled ones then reconnect through their slow links;
    // without one, everyone starts as they will run.
    let baseline = config.baseline_s.is_some();
    let mut baseline_sessions = 0u64;
    let mut running = ctx.launch(0..sessions, !baseline, &mut slots).await?;
    wait_first_frames(&running, config.first_frame_timeout_s).await?;
    let first_frames_s = opened_at.elapsed().as_secs_f64();
    progress(&format!(
        "loadgen: {label}: every viewer has frames after {first_frames_s:.1} s; warming up {} s",
        config.warmup_s
    ));
    tokio::time::sleep(Duration::from_secs_f64(config.warmup_s)).await;
    let baseline_window = match config.baseline_s {
        Some(b) => {
            let m = measure(target, &running, b, &format!("{label}, baseline"), progress).await?;
            progress(&format!(
                "loadgen: {label}: baseline done; {throttled} viewers reconnect through their throttled links"
            ));
            for r in running.iter().filter(|r| r.index < throttled) {
                r.task.abort();
                baseline_sessions += 1 + r.live.reopened.load(std::sync::atomic::Ordering::Relaxed);
            }
            running.retain(|r| r.index >= throttled);
            running.extend(ctx.launch(0..throttled, true, &mut slots).await?);
            running.sort_by_key(|r| r.index);
            wait_first_frames(&running, config.first_frame_timeout_s).await?;
            tokio::time::sleep(Duration::from_secs_f64(config.warmup_s)).await;
            Some((m.t0, m.t1, scrape::server_stats(&m.before, &m.after).fps))
        }
        None => None,
    };

    let m = measure(target, &running, config.seconds, &label, progress).await?;
    let (t0, t1) = (m.t0, m.t1);
    let load_average_1m = crate::report::load_average();

    let _ = stop_tx.send(true);
    let mut per_viewer = Vec::with_capacity(sessions);
    let mut latencies = Vec::with_capacity(sessions);
    let mut records = Vec::with_capacity(sessions);
    for r in running {
        let rec = r.task.await.context("a viewer task failed")?;
        latencies.push(stats::latencies(&rec, t0, t1));
        let mut v = stats::viewer(
            r.index,
            r.session,
            (r.views, size_of[r.index]),
            &rec,
            (t0, t1),
            r.live.ended(),
        );
        v.throttled = r.index < throttled;
        per_viewer.push(v);
        records.push(rec);
    }
    let summary = stats::summary(&per_viewer, latencies.concat());
    let sizes = stats::per_size(&config.sizes, &per_viewer, &latencies);
    let server = scrape::server_stats(&m.before, &m.after);
    let windows = config.windows();
    let classes: Vec<ClassResult> = [ViewerClass::Unthrottled, ViewerClass::Throttled]
        .into_iter()
        .filter_map(|class| {
            let of: Vec<usize> = (0..per_viewer.len())
                .filter(|&i| per_viewer[i].throttled == (class == ViewerClass::Throttled))
                .collect();
            if of.is_empty() {
                return None;
            }
            let stats: Vec<ViewerStats> = of.iter().map(|&i| per_viewer[i].clone()).collect();
            let pooled = of
                .iter()
                .flat_map(|&i| latencies[i].iter().copied())
                .collect();
            let recs: Vec<&ViewerRecord> = of.iter().map(|&i| &records[i]).collect();
            Some(ClassResult {
                class,
                sessions: of.len(),
                throttle_kbps: config
                    .throttle_kbps
                    .filter(|_| class == ViewerClass::Throttled),
                summary: stats::summary(&stats, pooled),
                windows: stats::windows(&recs, (t0, t1), windows),
            })
        })
        .collect();
    let server_windows = stats::server_windows(&m.rss_bytes, (t0, t1), windows);
    let baseline = baseline_window.map(|(b0, b1, server_fps)| {
        let unthrottled: Vec<usize> = (throttled..sessions).collect();
        let stats: Vec<ViewerStats> = unthrottled
            .iter()
            .map(|&i| {
                stats::viewer(
                    i,
                    per_viewer[i].session,
                    (per_viewer[i].views, size_of[i]),
                    &records[i],
                    (b0, b1),
                    None,
                )
            })
            .collect();
        let pooled = unthrottled
            .iter()
            .flat_map(|&i| stats::latencies(&records[i], b0, b1))
            .collect();
        Baseline {
            seconds: b1.duration_since(b0).as_secs_f64(),
            server_fps,
            sessions: unthrottled.len(),
            summary: stats::summary(&stats, pooled),
        }
    });
    progress(&format!(
        "loadgen: {label}: {}, server {:.1} fps, {:.1} render calls and {:.0} grid rays per frame{}",
        describe(&summary),
        server.fps,
        server.render_calls_per_frame,
        server.grid_rays_per_frame,
        match (summary.every_viewer_every_second, summary.every_viewer_served_throughout) {
            (true, _) => "",
            (false, true) => "; some second had no frame (the server rendered under 1 fps then), but every viewer got every frame",
            (false, false) => "; SOME VIEWER WAS NOT SERVED THROUGHOUT",
        }
    ));
    if sizes.len() > 1 {
        for s in &sizes {
            progress(&format!(
                "loadgen: {label}:   {} ({}): {}",
                s.size,
                sessions_count(s.sessions),
                describe(&s.summary)
            ));
        }
    }
    if classes.len() > 1 || throttled > 0 {
        for c in &classes {
            progress(&format!(
                "loadgen: {label}:   {} ({}): {}",
                c.class.as_str(),
                sessions_count(c.sessions),
                describe(&c.summary)
            ));
        }
    }
    if let Some(q) = summary.quality {
        progress(&format!(
            "loadgen: {label}: {} PSNR mean {:.2} dB, min {:.2} dB over {} frames; {:.0} bytes per encoded frame",
            config.codec.as_str(),
            q.psnr_mean_db,
            q.psnr_min_db,
            q.compared,
            summary.encoded_bytes_per_frame
        ));
    }

    // Let the server release the sessions before the next point asks for views.
    let drained = tokio::time::timeout(DRAIN_TIMEOUT, async {
        loop {
            match scrape::metrics(&target.authority).await {
                Ok(m) if m.get("fogcast_sessions", "") <= open_before => return Ok(m),
                Ok(_) => tokio::time::sleep(Duration::from_millis(50)).await,
                Err(e) => return Err(e),
            }
        }
    })
    .await;
    let mut end = match drained {
        Ok(r) => r?,
        Err(_) => anyhow::bail!(
            "the server still had sessions {} s after the viewers left",
            DRAIN_TIMEOUT.as_secs()
        ),
    };
    // The server unregisters a session a moment before it counts it closed: give the
    // counter that moment before comparing.
    let closed_lags = |m: &scrape::Scrape| {
        m.has(SESSIONS_CLOSED)
            && m.get(SESSIONS_CLOSED, "") - start.get(SESSIONS_CLOSED, "")
                < m.get(SESSIONS_OPENED, "") - start.get(SESSIONS_OPENED, "")
    };
    for _ in 0..20 {
        if !closed_lags(&end) {
            break;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
        end = scrape::metrics(&target.authority).await?;
    }
    let sessions_accounting = account_sessions(&per_viewer, baseline_sessions, &start, &end);
    Ok(PointResult {
        viewers: views,
        sessions,
        first_frames_s,
        window_s: t1.duration_since(t0).as_secs_f64(),
        load_average_1m,
        summary,
        sizes,
        server,
        classes,
        server_windows,
        baseline,
        sessions_accounting,
        per_viewer,
    })
}

/// Sessions loadgen opened against the server's counters from `start` to `end`.
/// `extra`: sessions opened outside the viewers' records (the throttled viewers' fast-link
/// sessions of the baseline phase).
fn account_sessions(
    viewers: &[ViewerStats],
    extra: u64,
    start: &scrape::Scrape,
    end: &scrape::Scrape,
) -> SessionAccounting {
    let delta = |name: &str| (end.get(name, "") - start.get(name, "")).max(0.0) as u64;
    let opened_by_loadgen = viewers.iter().map(|v| v.sessions_opened).sum::<u64>() + extra;
    let server_opened = delta(SESSIONS_OPENED);
    let server_closed = (end.has(SESSIONS_CLOSED)).then(|| delta(SESSIONS_CLOSED));
    let open_before = start.get("fogcast_sessions", "") as u64;
    let open_after = end.get("fogcast_sessions", "") as u64;
    SessionAccounting {
        opened_by_loadgen,
        reopen_failures: viewers.iter().map(|v| v.reopen_failures).sum(),
        server_opened,
        server_closed,
        open_before,
        open_after,
        accounted: server_opened == opened_by_loadgen
            && open_after <= open_before
            && server_closed.is_none_or(|c| c == opened_by_loadgen),
    }
}

/// "320x180: 2, 480x270: 1" — the sessions of each size, in the order of `sizes`.
fn sessions_per_size(sizes: &[FrameSize], size_of: &[FrameSize]) -> String {
    sizes
        .iter()
        .map(|s| format!("{s}: {}", size_of.iter().filter(|t| *t == s).count()))
        .collect::<Vec<_>>()
        .join(", ")
}

struct StopOnDrop(watch::Sender<bool>);

impl Drop for StopOnDrop {
    fn drop(&mut self) {
        let _ = self.0.send(true);
    }
}
