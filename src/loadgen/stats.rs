//! Per-viewer and per-point numbers from the frame records of one measurement window.

use super::client::ViewerRecord;
use super::{
    FrameSize, Latency, PointSummary, Quality, ServerWindow, SizeResult, ViewerStats, WindowStats,
};
use crate::protocol::FrameHeader;
use std::time::{Duration, Instant};

/// Nearest-rank percentile `p` (0–100) of sorted `v`.
fn percentile(sorted: &[f64], p: f64) -> f64 {
    let rank = (p / 100.0 * sorted.len() as f64).ceil() as usize;
    sorted[rank.clamp(1, sorted.len()) - 1]
}

/// Percentiles of `samples_ms` (`None` when there are none).
pub(crate) fn latency(mut samples_ms: Vec<f64>) -> Option<Latency> {
    samples_ms.retain(|v| v.is_finite());
    if samples_ms.is_empty() {
        return None;
    }
    samples_ms.sort_by(f64::total_cmp);
    Some(Latency {
        samples: samples_ms.len(),
        p50_ms: percentile(&samples_ms, 50.0),
        p95_ms: percentile(&samples_ms, 95.0),
        p99_ms: percentile(&samples_ms, 99.0),
        mean_ms: samples_ms.iter().sum::<f64>() / samples_ms.len() as f64,
        max_ms: *samples_ms.last().expect("not empty"),
    })
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

/// Pose-to-frame latencies (ms) of the frames that arrived in `[t0, t1)`: for each frame
/// that is the first to echo a pose sequence number, the time since that pose was sent.
pub(crate) fn latencies(rec: &ViewerRecord, t0: Instant, t1: Instant) -> Vec<f64> {
    let mut last_seq = 0;
    let mut out = Vec::new();
    for f in &rec.frames {
        let seq = f.header.pose_seq;
        if seq != last_seq {
            last_seq = seq;
            let sent = (seq as usize)
                .checked_sub(1)
                .and_then(|i| rec.pose_sent.get(i));
            if let (Some(sent), true) = (sent, f.at >= t0 && f.at < t1) {
                out.push(ms(f.at.saturating_duration_since(*sent)));
            }
        }
    }
    out
}

/// One viewer's numbers over the window `[t0, t1)`; `views` and `size` are its session's.
pub(crate) fn viewer(
    index: usize,
    session: u64,
    (views, size): (u32, FrameSize),
    rec: &ViewerRecord,
    (t0, t1): (Instant, Instant),
    ended_early: Option<String>,
) -> ViewerStats {
    let window_s = t1.duration_since(t0).as_secs_f64().max(1e-9);
    let inside: Vec<_> = rec
        .frames
        .iter()
        .filter(|f| f.at >= t0 && f.at < t1)
        .collect();
    let before = rec.frames.iter().rev().find(|f| f.at < t0);
    let frames = inside.len() as u64;
    let bytes: u64 = inside.iter().map(|f| u64::from(f.bytes)).sum();

    // Server-side drops (the header's per-session counter) and render-loop frames this
    // viewer never got (gaps in the shared frame number), both over the window. A new
    // session (churn) starts its counter at 0, and the frames between two sessions are
    // not missed.
    let mut dropped_server = 0u64;
    let mut missed_frames = 0u64;
    let mut prev = before;
    let mut max_gap = Duration::ZERO;
    let mut last_at = t0;
    for f in &inside {
        match prev {
            Some(p) if p.session_no == f.session_no => {
                missed_frames += u64::from(
                    f.header
                        .frame
                        .saturating_sub(p.header.frame)
                        .saturating_sub(1),
                );
                dropped_server += u64::from(f.header.dropped.saturating_sub(p.header.dropped));
            }
            Some(_) => dropped_server += u64::from(f.header.dropped),
            None => {}
        }
        max_gap = max_gap.max(f.at.duration_since(last_at));
        last_at = f.at;
        prev = Some(f);
    }
    max_gap = max_gap.max(t1.saturating_duration_since(last_at));

    let buckets = (window_s.round() as usize).max(1);
    let mut timeline = vec![0u32; buckets];
    for f in &inside {
        let i = (f.at.duration_since(t0).as_secs_f64() as usize).min(buckets - 1);
        timeline[i] += 1;
    }
    // Mean of a header field in µs, as ms.
    let header_ms = |field: fn(&FrameHeader) -> u32| {
        (!inside.is_empty()).then(|| {
            inside
                .iter()
                .map(|f| f64::from(field(&f.header)))
                .sum::<f64>()
                / inside.len() as f64
                / 1e3
        })
    };
    let seconds_without_frames = timeline.iter().filter(|n| **n == 0).count();
    let payload: u64 = inside.iter().map(|f| u64::from(f.payload_bytes)).sum();
    let psnr: Vec<f64> = rec
        .psnr
        .iter()
        .filter(|(at, _)| *at >= t0 && *at < t1)
        .map(|(_, db)| *db)
        .collect();
    let served_throughout =
        ended_early.is_none() && frames > 0 && (seconds_without_frames == 0 || missed_frames == 0);
    ViewerStats {
        index,
        session,
        views,
        size,
        frames,
        fps: frames as f64 / window_s,
        bytes,
        bytes_per_s: bytes as f64 / window_s,
        mean_frame_bytes: if frames > 0 {
            bytes as f64 / frames as f64
        } else {
            0.0
        },
        latency: latency(latencies(rec, t0, t1)),
        poses_sent: rec
            .pose_sent
            .iter()
            .filter(|t| **t >= t0 && **t < t1)
            .count() as u64,
        dropped_server,
        missed_frames,
        max_gap_ms: ms(max_gap),
        seconds_without_frames,
        timeline,
        header_render_ms: header_ms(|h| h.render_us),
        header_encode_ms: header_ms(|h| h.encode_us),
        bad_frames: rec.bad_frames,
        throttled: false,
        encoded_bytes_per_frame: if frames > 0 {
            payload as f64 / frames as f64
        } else {
            0.0
        },
        key_frames: inside.iter().filter(|f| f.header.key).count() as u64,
        raw_frames: rec.raw_frames,
        decode_errors: rec.decode_errors,
        quality: quality(&psnr),
        sessions_opened: rec.sessions_opened,
        reopen_failures: rec.reopen_failures,
        bandwidth_welcomes: rec.bandwidth_welcomes,
        acks_refused: rec.acks_refused,
        server_errors: rec.server_errors.clone(),
        ended_early,
        served_throughout,
    }
}

/// Mean and minimum of PSNR samples (`None` without samples).
fn quality(psnr_db: &[f64]) -> Option<Quality> {
    (!psnr_db.is_empty()).then(|| Quality {
        compared: psnr_db.len(),
        psnr_mean_db: psnr_db.iter().sum::<f64>() / psnr_db.len() as f64,
        psnr_min_db: psnr_db.iter().copied().fold(f64::INFINITY, f64::min),
    })
}

/// Viewers' qualities pooled: the mean over every compared frame, the lowest of all.
fn pooled_quality(viewers: &[ViewerStats]) -> Option<Quality> {
    let qs: Vec<Quality> = viewers.iter().filter_map(|v| v.quality).collect();
    let compared: usize = qs.iter().map(|q| q.compared).sum();
    (compared > 0).then(|| Quality {
        compared,
        psnr_mean_db: qs
            .iter()
            .map(|q| q.psnr_mean_db * q.compared as f64)
            .sum::<f64>()
            / compared as f64,
        psnr_min_db: qs
            .iter()
            .map(|q| q.psnr_min_db)
            .fold(f64::INFINITY, f64::min),
    })
}

/// The point's numbers over all its viewers; `pooled_ms` are every viewer's latencies.
pub(crate) fn summary(viewers: &[ViewerStats], pooled_ms: Vec<f64>) -> PointSummary {
    let fps: Vec<f64> = viewers.iter().map(|v| v.fps).collect();
    let n = fps.len().max(1) as f64;
    let frames: u64 = viewers.iter().map(|v| v.frames).sum();
    let payload: f64 = viewers
        .iter()
        .map(|v| v.encoded_bytes_per_frame * v.frames as f64)
        .sum();
    PointSummary {
        fps_mean: fps.iter().sum::<f64>() / n,
        fps_min: fps
            .iter()
            .copied()
            .fold(f64::INFINITY, f64::min)
            .min(f64::MAX),
        fps_max: fps.iter().copied().fold(0.0, f64::max),
        latency: latency(pooled_ms),
        bytes_per_s_total: viewers.iter().map(|v| v.bytes_per_s).sum(),
        bytes_per_s_per_viewer: viewers.iter().map(|v| v.bytes_per_s).sum::<f64>() / n,
        frames_total: viewers.iter().map(|v| v.frames).sum(),
        dropped_server_total: viewers.iter().map(|v| v.dropped_server).sum(),
        missed_frames_total: viewers.iter().map(|v| v.missed_frames).sum(),
        max_gap_ms: viewers.iter().map(|v| v.max_gap_ms).fold(0.0, f64::max),
        every_viewer_every_second: !viewers.is_empty()
            && viewers
                .iter()
                .all(|v| v.seconds_without_frames == 0 && v.ended_early.is_none()),
        every_viewer_served_throughout: !viewers.is_empty()
            && viewers.iter().all(|v| v.served_throughout),
        viewers_ended_early: viewers.iter().filter(|v| v.ended_early.is_some()).count(),
        bad_frames: viewers.iter().map(|v| v.bad_frames).sum(),
        encoded_bytes_per_frame: if frames > 0 {
            payload / frames as f64
        } else {
            0.0
        },
        key_frames: viewers.iter().map(|v| v.key_frames).sum(),
        decode_errors: viewers.iter().map(|v| v.decode_errors).sum(),
        quality: pooled_quality(viewers),
    }
}

/// `[t0, t1)` cut into `n` equal windows: (start, end) of each.
fn cut(t0: Instant, t1: Instant, n: usize) -> Vec<(Instant, Instant)> {
    let len = t1.duration_since(t0).div_f64(n.max(1) as f64);
    (0..n.max(1))
        .map(|i| {
            let a = t0 + len.mul_f64(i as f64);
            let b = if i + 1 == n.max(1) {
                t1
            } else {
                t0 + len.mul_f64((i + 1) as f64)
            };
            (a, b)
        })
        .collect()
}

/// Per window of `[t0, t1)` (`n` equal ones), over the viewers `recs`: their mean fps
/// and the 95th percentile of their pooled latencies.
pub(crate) fn windows(
    recs: &[&ViewerRecord],
    (t0, t1): (Instant, Instant),
    n: usize,
) -> Vec<WindowStats> {
    cut(t0, t1, n)
        .into_iter()
        .map(|(a, b)| {
            let len_s = b.duration_since(a).as_secs_f64().max(1e-9);
            let fps_sum: f64 = recs
                .iter()
                .map(|r| r.frames.iter().filter(|f| f.at >= a && f.at < b).count() as f64 / len_s)
                .sum();
            let pooled: Vec<f64> = recs.iter().flat_map(|r| latencies(r, a, b)).collect();
            let l = latency(pooled);
            WindowStats {
                start_s: a.duration_since(t0).as_secs_f64(),
                end_s: b.duration_since(t0).as_secs_f64(),
                fps_mean: fps_sum / recs.len().max(1) as f64,
                latency_p95_ms: l.map(|l| l.p95_ms),
                latency_samples: l.map_or(0, |l| l.samples),
            }
        })
        .collect()
}

/// Per window of `[t0, t1)` (`n` equal ones): the largest resident memory sample in it
/// (samples at the windows' edges count for both).
pub(crate) fn server_windows(
    rss_bytes: &[(Instant, f64)],
    (t0, t1): (Instant, Instant),
    n: usize,
) -> Vec<ServerWindow> {
    // Scrapes land a little after the second they were taken for.
    let slack = Duration::from_millis(500);
    cut(t0, t1, n)
        .into_iter()
        .map(|(a, b)| {
            let max = rss_bytes
                .iter()
                .filter(|(at, v)| *at + slack >= a && *at <= b + slack && *v > 0.0)
                .map(|(_, v)| *v)
                .fold(None, |m: Option<f64>, v| Some(m.map_or(v, |m| m.max(v))));
            ServerWindow {
                start_s: a.duration_since(t0).as_secs_f64(),
                end_s: b.duration_since(t0).as_secs_f64(),
                resident_memory_mib: max.map(|v| v / (1024.0 * 1024.0)),
            }
        })
        .collect()
}

/// The numbers of each frame size's viewers (in the order of `sizes`, those that had
/// any); `latencies_ms[i]` are viewer `i`'s samples.
pub(crate) fn per_size(
    sizes: &[FrameSize],
    viewers: &[ViewerStats],
    latencies_ms: &[Vec<f64>],
) -> Vec<SizeResult> {
    sizes
        .iter()
        .filter_map(|&size| {
            let of_size: Vec<usize> = (0..viewers.len())
                .filter(|&i| viewers[i].size == size)
                .collect();
            let first = *of_size.first()?;
            let pooled = of_size
                .iter()
                .flat_map(|&i| latencies_ms[i].iter().copied())
                .collect();
            let stats: Vec<ViewerStats> = of_size.iter().map(|&i| viewers[i].clone()).collect();
            Some(SizeResult {
                size,
                sessions: of_size.len(),
                views: of_size.len() * viewers[first].views as usize,
                summary: summary(&stats, pooled),
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::loadgen::client::FrameRecord;
    use crate::protocol::Layout;

    const SIZE: FrameSize = FrameSize {
        width: 64,
        height: 36,
    };

    fn frame(at: Instant, frame: u32, pose_seq: u32, dropped: u32) -> FrameRecord {
        FrameRecord {
            at,
            bytes: 1000,
            payload_bytes: 960,
            session_no: 0,
            header: FrameHeader {
                layout: Layout::Mono,
                views: 1,
                width: 64,
                height: 36,
                frame,
                pose_seq,
                render_us: 2000,
                encode_us: 500,
                dropped,
                codec: crate::protocol::FrameCodec::Jpeg,
                key: true,
                quality: 75,
                target_kbps: 0,
            },
        }
    }

    #[test]
    fn percentiles_are_nearest_rank_and_ordered() {
        let l = latency((1..=100).map(f64::from).collect()).unwrap();
        assert_eq!(
            (l.p50_ms, l.p95_ms, l.p99_ms, l.max_ms),
            (50.0, 95.0, 99.0, 100.0)
        );
        let one = latency(vec![7.0, f64::NAN]).unwrap();
        assert_eq!((one.samples, one.p50_ms, one.p99_ms), (1, 7.0, 7.0));
        assert!(latency(vec![]).is_none());
    }

    #[test]
    fn a_viewer_window_counts_frames_gaps_and_latency() {
        let t0 = Instant::now();
        let at = |ms: u64| t0 + Duration::from_millis(ms);
        let rec = ViewerRecord {
            // Poses 1..=4 sent at 0, 100, 200, 300 ms.
            pose_sent: (0..4).map(|i| at(i * 100)).collect(),
            frames: vec![
                frame(at(50), 10, 1, 0),
                // Window starts at 100 ms.
                frame(at(150), 11, 1, 0),
                frame(at(420), 13, 3, 1), // frame 12 missed, pose 2 never shown
                frame(at(1500), 14, 4, 1),
                frame(at(2500), 15, 4, 1), // after the window
            ],
            ..ViewerRecord::default()
        };
        let v = viewer(0, 1, (1, SIZE), &rec, (at(100), at(2100)), None);
        assert_eq!(
            (v.frames, v.bytes, v.missed_frames, v.dropped_server),
            (3, 3000, 1, 1)
        );
        assert!((v.fps - 1.5).abs() < 1e-9);
        assert_eq!(v.timeline, vec![2, 1]);
        assert_eq!(v.seconds_without_frames, 0);
        // Pose 3: 420 - 200 ms; pose 4: 1500 - 300 ms; pose 1's first frame was before the window.
        let l = v.latency.unwrap();
        assert_eq!(l.samples, 2);
        assert!((l.p50_ms - 220.0).abs() < 1e-6 && (l.p99_ms - 1200.0).abs() < 1e-6);
        assert!((v.max_gap_ms - 1080.0).abs() < 1e-6);
        assert_eq!(v.header_render_ms, Some(2.0));
        let s = summary(&[v], vec![220.0, 1200.0]);
        assert!(s.every_viewer_every_second && s.every_viewer_served_throughout);
        assert_eq!(s.frames_total, 3);
        // A slow server: a second without frames, but every rendered frame arrived.
        let slow = ViewerRecord {
            pose_sent: vec![at(0)],
            frames: vec![frame(at(200), 1, 1, 0), frame(at(2300), 2, 1, 0)],
            ..ViewerRecord::default()
        };
        let v = viewer(0, 1, (1, SIZE), &slow, (at(100), at(3100)), None);
        assert_eq!((v.seconds_without_frames, v.missed_frames), (1, 0));
        assert!(v.served_throughout);
        let s = summary(&[v], vec![]);
        assert!(!s.every_viewer_every_second && s.every_viewer_served_throughout);
        // Missing a second and a rendered frame, or leaving early, is not being served.
        let starved = ViewerRecord {
            frames: vec![frame(at(200), 1, 0, 0), frame(at(2300), 3, 0, 1)],
            ..ViewerRecord::default()
        };
        assert!(!viewer(0, 1, (1, SIZE), &starved, (at(100), at(3100)), None).served_throughout);
        let left = viewer(
            0,
            1,
            (1, SIZE),
            &rec,
            (at(100), at(2100)),
            Some("gone".into()),
        );
        assert!(!left.served_throughout);
    }

    #[test]
    fn sizes_are_summarised_apart() {
        let t0 = Instant::now();
        let at = |ms: u64| t0 + Duration::from_millis(ms);
        let big = FrameSize {
            width: 128,
            height: 72,
        };
        let unused = FrameSize {
            width: 32,
            height: 18,
        };
        // Viewers 0 and 2 small (4 and 2 frames), viewer 1 big (1 frame).
        let rec = |n: u32| ViewerRecord {
            pose_sent: vec![at(0)],
            frames: (0..n)
                .map(|i| frame(at(100 + 200 * u64::from(i)), i + 1, 1, 0))
                .collect(),
            ..ViewerRecord::default()
        };
        let window = (at(0), at(1000));
        let viewers = [
            viewer(0, 1, (1, SIZE), &rec(4), window, None),
            viewer(1, 2, (1, big), &rec(1), window, None),
            viewer(2, 3, (1, SIZE), &rec(2), window, None),
        ];
        let latencies = [vec![100.0], vec![500.0], vec![300.0]];
        let sizes = per_size(&[SIZE, unused, big], &viewers, &latencies);
        assert_eq!(sizes.len(), 2, "a size without sessions is left out");
        let (small, large) = (&sizes[0], &sizes[1]);
        assert_eq!((small.size, small.sessions, small.views), (SIZE, 2, 2));
        assert_eq!((large.size, large.sessions, large.views), (big, 1, 1));
        assert!((small.summary.fps_mean - 3.0).abs() < 1e-9);
        assert_eq!(small.summary.frames_total, 6);
        assert_eq!(small.summary.latency.unwrap().samples, 2);
        assert_eq!(large.summary.latency.unwrap().p50_ms, 500.0);
    }

    #[test]
    fn windows_show_creep_and_sessions_restart_their_counters() {
        let t0 = Instant::now();
        let at = |ms: u64| t0 + Duration::from_millis(ms);
        // Two windows of 1 s: 4 frames 10 ms after their poses, then 2 frames 300 ms after.
        let mut frames: Vec<FrameRecord> = (0..4)
            .map(|i| frame(at(100 + 200 * i + 10), i as u32 + 1, i as u32 + 1, 0))
            .collect();
        frames.push(frame(at(1400), 5, 5, 2));
        // A new session: its drop counter starts again; its first frame 1 after.
        let mut f = frame(at(1800), 9, 6, 1);
        f.session_no = 1;
        frames.push(f);
        let rec = ViewerRecord {
            pose_sent: [100, 300, 500, 700, 1100, 1500].map(at).to_vec(),
            frames,
            sessions_opened: 2,
            psnr: vec![(at(150), 40.0), (at(900), 30.0), (at(2500), 10.0)],
            ..ViewerRecord::default()
        };
        let w = windows(&[&rec], (at(0), at(2000)), 2);
        assert_eq!(w.len(), 2);
        assert!((w[0].fps_mean - 4.0).abs() < 1e-9 && (w[1].fps_mean - 2.0).abs() < 1e-9);
        assert_eq!(w[0].latency_p95_ms, Some(10.0));
        assert_eq!(
            (w[1].latency_p95_ms, w[1].latency_samples),
            (Some(300.0), 2)
        );
        let v = viewer(0, 1, (1, SIZE), &rec, (at(0), at(2000)), None);
        // Session 0: 0 → 2 dropped; session 1 starts at 1; frames 6–8 fall between sessions.
        assert_eq!((v.dropped_server, v.missed_frames), (3, 0));
        assert_eq!((v.sessions_opened, v.key_frames), (2, 6));
        assert!((v.encoded_bytes_per_frame - 960.0).abs() < 1e-9);
        let q = v.quality.expect("two PSNR samples in the window");
        assert_eq!((q.compared, q.psnr_min_db), (2, 30.0));
        assert!((q.psnr_mean_db - 35.0).abs() < 1e-9);
        let s = summary(&[v.clone(), v], vec![]);
        assert_eq!(s.quality.map(|q| q.compared), Some(4));
        let rss = [
            (at(0), 100.0),
            (at(400), 300.0),
            (at(1500), 200.0),
            (at(2000), 0.0),
        ];
        let sw = server_windows(&rss, (at(0), at(2000)), 2);
        assert_eq!(
            sw.iter()
                .map(|w| w.resident_memory_mib.map(|m| m * 1048576.0))
                .collect::<Vec<_>>(),
            vec![Some(300.0), Some(200.0)]
        );
    }
}
