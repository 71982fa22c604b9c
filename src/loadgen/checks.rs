//! `--check-*`: pass/fail verdicts on a run's numbers, each saying which point and class
//! it looked at and the numbers it compared, so a failed soak reads as a sentence.

use super::{ClassResult, PointResult, ViewerClass};
use serde::Serialize;

/// Which checks to run (all off by default).
#[derive(Debug, Clone, Default, Serialize)]
pub struct Checks {
    /// Every class's pooled pose-to-frame p95 at most this, ms.
    pub latency_p95_ms: Option<f64>,
    /// The throttled class's (else every viewer's) last window p95 at most this times
    /// the first window's.
    pub creep: Option<f64>,
    /// The unthrottled viewers' mean fps within this fraction of the baseline's.
    pub fps_within: Option<f64>,
    /// The server's resident memory in the last window at most (1 + this) times the
    /// second window's (the first holds start-up allocations).
    pub memory_growth: Option<f64>,
    /// Every session loadgen opened was counted by the server and closed.
    pub sessions: bool,
}

impl Checks {
    /// Whether any check is on.
    pub fn any(&self) -> bool {
        self.latency_p95_ms.is_some()
            || self.creep.is_some()
            || self.fps_within.is_some()
            || self.memory_growth.is_some()
            || self.sessions
    }

    pub(crate) fn validate(&self) -> anyhow::Result<()> {
        for (flag, v, lo) in [
            ("--check-latency-p95-ms", self.latency_p95_ms, 0.0),
            ("--check-creep", self.creep, 1.0),
            ("--check-fps-within", self.fps_within, 0.0),
            ("--check-memory-growth", self.memory_growth, 0.0),
        ] {
            if let Some(v) = v {
                anyhow::ensure!(
                    v.is_finite() && v >= lo,
                    "{flag} {v}: must be a finite number of at least {lo}"
                );
            }
        }
        Ok(())
    }
}

/// One check of one point.
#[derive(Debug, Clone, Serialize)]
pub struct CheckResult {
    /// The flag, e.g. `--check-creep`.
    pub check: String,
    /// Views of the point it looked at.
    pub views: usize,
    /// Whether it passed.
    pub passed: bool,
    /// What was compared: "throttled p95 412 ms in the last window ≤ 1.2 × 380 ms".
    pub detail: String,
}

/// Every enabled check over every point.
pub(crate) fn evaluate(checks: &Checks, points: &[PointResult]) -> Vec<CheckResult> {
    let mut out = Vec::new();
    for p in points {
        let mut verdict = |check: &str, passed: bool, detail: String| {
            out.push(CheckResult {
                check: check.into(),
                views: p.viewers,
                passed,
                detail,
            })
        };
        if let Some(max) = checks.latency_p95_ms {
            for c in &p.classes {
                let name = c.class.as_str();
                match c.summary.latency {
                    Some(l) => verdict(
                        "--check-latency-p95-ms",
                        l.p95_ms <= max,
                        format!("{name} p95 {:.0} ms ≤ {max} ms", l.p95_ms),
                    ),
                    None => verdict(
                        "--check-latency-p95-ms",
                        false,
                        format!("{name}: no latency samples (no frame showed a pose)"),
                    ),
                }
            }
        }
        if let Some(ratio) = checks.creep {
            let class = p
                .classes
                .iter()
                .find(|c| c.class == ViewerClass::Throttled)
                .or_else(|| p.classes.first());
            let (passed, detail) = creep(class, ratio);
            verdict("--check-creep", passed, detail);
        }
        if let Some(within) = checks.fps_within {
            let now = p
                .classes
                .iter()
                .find(|c| c.class == ViewerClass::Unthrottled);
            let (passed, detail) = match (&p.baseline, now) {
                (Some(b), Some(c)) => {
                    let (base, fps) = (b.summary.fps_mean, c.summary.fps_mean);
                    (
                        // They must not lose fps to the slow client; gaining some (a
                        // CPU renderer freed from encoding frames the slow link skips)
                        // is no failure.
                        base > 0.0 && fps >= (1.0 - within) * base,
                        format!(
                            "unthrottled {fps:.2} fps with the throttled viewers vs {base:.2} fps with every link fast: {:+.1} % (allowed down to −{:.1} %); server render loop {:.1} fps, {:.1} in the baseline",
                            if base > 0.0 { (fps / base - 1.0) * 100.0 } else { f64::NAN },
                            within * 100.0,
                            p.server.fps,
                            b.server_fps
                        ),
                    )
                }
                (None, _) => (false, "no baseline phase (--baseline-s)".into()),
                (_, None) => (false, "no unthrottled viewers".into()),
            };
            verdict("--check-fps-within", passed, detail);
        }
        if let Some(growth) = checks.memory_growth {
            let w = &p.server_windows;
            let (passed, detail) = match (w.get(1).and_then(|w| w.resident_memory_mib), w.last()) {
                (Some(second), Some(last)) if w.len() >= 3 => match last.resident_memory_mib {
                    Some(mib) => (
                        mib <= (1.0 + growth) * second,
                        format!(
                            "server RSS {mib:.0} MiB in the last window ({:.0}–{:.0} s) vs {second:.0} MiB in the second: {:+.1} % (allowed +{:.1} %)",
                            last.start_s,
                            last.end_s,
                            (mib / second - 1.0) * 100.0,
                            growth * 100.0
                        ),
                    ),
                    None => (false, "no fogcast_resident_memory_bytes in the last window".into()),
                },
                _ => (
                    false,
                    format!(
                        "needs 3 windows with fogcast_resident_memory_bytes, have {}",
                        w.iter().filter(|w| w.resident_memory_mib.is_some()).count()
                    ),
                ),
            };
            verdict("--check-memory-growth", passed, detail);
        }
        if checks.sessions {
            let a = &p.sessions_accounting;
            verdict(
                "--check-sessions",
                a.accounted,
                format!(
                    "loadgen opened {} sessions, the server counted {} opened{}; open before {} and after {}",
                    a.opened_by_loadgen,
                    a.server_opened,
                    a.server_closed
                        .map_or_else(String::new, |c| format!(" and {c} closed")),
                    a.open_before,
                    a.open_after
                ),
            );
        }
    }
    out
}

/// Last window's p95 against `ratio` × the first window's.
fn creep(class: Option<&ClassResult>, ratio: f64) -> (bool, String) {
    let Some(c) = class else {
        return (false, "no viewers".into());
    };
    let name = c.class.as_str();
    let (Some(first), Some(last)) = (c.windows.first(), c.windows.last()) else {
        return (false, format!("{name}: no windows"));
    };
    if c.windows.len() < 2 {
        return (false, format!("{name}: one window only; lower --window-s"));
    }
    match (first.latency_p95_ms, last.latency_p95_ms) {
        (Some(a), Some(b)) => (
            b <= ratio * a,
            format!(
                "{name} p95 {b:.0} ms in the last window ({:.0}–{:.0} s) ≤ {ratio} × {a:.0} ms in the first",
                last.start_s, last.end_s
            ),
        ),
        _ => (
            false,
            format!("{name}: a window without latency samples (first {first:?}, last {last:?})", first = first.latency_samples, last = last.latency_samples),
        ),
    }
}
