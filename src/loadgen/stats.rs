//! Per-viewer and per-point numbers from the frame records of one measurement window.

use super::client::ViewerRecord;
use super::{FrameSize, Latency, PointSummary, SizeResult, ViewerStats};
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
    // viewer never got (gaps in the shared frame number), both over the window.
    let dropped_server = match (before.or(inside.first().copied()), inside.last()) {
        (Some(a), Some(b)) => u64::from(b.header.dropped.saturating_sub(a.header.dropped)),
        _ => 0,
    };
    let mut missed_frames = 0u64;
    let mut prev = before;
    let mut max_gap = Duration::ZERO;
    let mut last_at = t0;
    for f in &inside {
        if let Some(p) = prev {
            missed_frames += u64::from(
                f.header
                    .frame
                    .saturating_sub(p.header.frame)
                    .saturating_sub(1),
            );
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
        server_errors: rec.server_errors.clone(),
        ended_early,
        served_throughout,
    }
}

/// The point's numbers over all its viewers; `pooled_ms` are every viewer's latencies.
pub(crate) fn summary(viewers: &[ViewerStats], pooled_ms: Vec<f64>) -> PointSummary {
    let fps: Vec<f64> = viewers.iter().map(|v| v.fps).collect();
    let n = fps.len().max(1) as f64;
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
    }
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
}
