//! `fogcast bench --repeat N`: the same bench N times, and every acceptance check's value
//! in each run side by side. On a CPU rasteriser one run's frame-time ratios move by
//! ±10–15 % with the machine's load, so a verdict near its bound needs more than one run;
//! the table says how many of the runs pass, not only whether the last one did.

use super::report::{checks, stereo_checks, value_text, within, Check};
use super::{BenchConfig, BenchReport, Spread};
use crate::report::Table;
use std::path::PathBuf;

/// One check over every run.
#[derive(Debug, Clone, PartialEq)]
pub struct RepeatedCheck {
    /// What is checked (as in one run's table).
    pub what: String,
    /// The bound (none: reported only).
    pub bound: Option<f64>,
    /// The measured value of each run, in run order.
    pub values: Vec<f64>,
}

impl RepeatedCheck {
    /// Runs whose value is within the bound (every run without one).
    pub fn passes(&self) -> usize {
        self.values
            .iter()
            .filter(|&&v| within(self.bound, v))
            .count()
    }

    /// Median, smallest and largest value over the runs.
    pub fn spread(&self) -> Spread {
        Spread::of(&self.values)
    }
}

/// Lines up the checks of every run (each run's [`Check`]s, same configuration, so the
/// same checks in the same order); an error names the first run that differs.
pub fn collect(runs: &[Vec<Check>]) -> anyhow::Result<Vec<RepeatedCheck>> {
    let Some(first) = runs.first() else {
        return Ok(Vec::new());
    };
    let mut out: Vec<RepeatedCheck> = first
        .iter()
        .map(|c| RepeatedCheck {
            what: c.what.clone(),
            bound: c.bound,
            values: vec![c.value],
        })
        .collect();
    for (k, run) in runs.iter().enumerate().skip(1) {
        let same = run.len() == out.len() && run.iter().zip(&out).all(|(c, r)| c.what == r.what);
        anyhow::ensure!(
            same,
            "run {} has other checks than run 1 ({} against {})",
            k + 1,
            run.len(),
            out.len()
        );
        for (c, r) in run.iter().zip(&mut out) {
            r.values.push(c.value);
        }
    }
    Ok(out)
}

/// The checks as a markdown table: each run's value, the median and range, the bound and
/// how many runs pass it.
pub fn table(checks: &[RepeatedCheck]) -> Table {
    let runs = checks.first().map_or(0, |c| c.values.len());
    let mut headers = vec!["check".to_string()];
    headers.extend((1..=runs).map(|k| format!("run {k}")));
    headers.extend(["median (range)", "bound", "runs within it"].map(String::from));
    let mut t = Table {
        headers,
        rows: Vec::new(),
    };
    for c in checks {
        let s = c.spread();
        let mut row = vec![c.what.clone()];
        row.extend(c.values.iter().map(|&v| value_text(v)));
        let (median, min, max) = (value_text(s.median), value_text(s.min), value_text(s.max));
        row.push(format!("{median} ({min}–{max})"));
        row.push(c.bound.map_or("–".into(), |b| format!("≤ {b}")));
        row.push(match c.bound {
            None => "reported".into(),
            Some(_) => format!("{} of {}", c.passes(), c.values.len()),
        });
        t.rows.push(row);
    }
    t
}

/// Writes `checks.md` into `cfg.out`: every acceptance check (issues 5, 14 and 16) of
/// each of `runs` (reports of `cfg`, in run order); returns its path and the checks.
pub fn write(
    runs: &[BenchReport],
    cfg: &BenchConfig,
) -> anyhow::Result<(PathBuf, Vec<RepeatedCheck>)> {
    let per_run: Vec<Vec<Check>> = runs
        .iter()
        .map(|r| checks(r).into_iter().chain(stereo_checks(r)).collect())
        .collect();
    let repeated = collect(&per_run)?;
    let Some(first) = runs.first() else {
        anyhow::bail!("no runs to summarise");
    };
    let loads: Vec<String> = runs
        .iter()
        .map(|r| {
            r.load_average
                .map_or("–".into(), |[start, _]| format!("{start:.1}"))
        })
        .collect();
    let md = format!(
        "# bench checks: {}, {} runs\n\n`{}`\n\nEach run is the whole bench, its report in `run-<k>/`, on {} with {} CPU thread(s); the machine's 1-minute load average at the start of each run: {}.\n\n{}",
        first.scene,
        runs.len(),
        cfg.command,
        first.adapter,
        first.cpu_threads,
        loads.join(", "),
        table(&repeated).to_markdown()
    );
    let path = cfg.out.join("checks.md");
    std::fs::write(&path, md).map_err(|e| anyhow::anyhow!("writing {}: {e}", path.display()))?;
    Ok((path, repeated))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn check(what: &str, value: f64, bound: Option<f64>) -> Check {
        Check {
            what: what.into(),
            value,
            bound,
        }
    }

    #[test]
    fn runs_line_up_by_check_and_count_their_passes() {
        let runs = vec![
            vec![check("ratio", 0.30, Some(0.35)), check("rays", 15.7, None)],
            vec![check("ratio", 0.40, Some(0.35)), check("rays", 15.6, None)],
            vec![check("ratio", 0.35, Some(0.35)), check("rays", 15.8, None)],
        ];
        let c = collect(&runs).unwrap();
        assert_eq!(c.len(), 2);
        assert_eq!(c[0].values, vec![0.30, 0.40, 0.35]);
        assert_eq!(c[0].passes(), 2, "0.35 is within ≤ 0.35");
        assert_eq!(c[0].spread().median, 0.35);
        assert_eq!(c[1].passes(), 3, "reported only");
        let t = table(&c);
        assert_eq!(t.headers.len(), 1 + 3 + 3);
        assert_eq!(t.rows[0].last().unwrap(), "2 of 3");
        assert_eq!(t.rows[0][4], "0.350 (0.300–0.400)");
        assert_eq!(t.rows[1].last().unwrap(), "reported");
    }

    #[test]
    fn runs_with_other_checks_are_an_error() {
        let runs = vec![
            vec![check("ratio", 0.30, Some(0.35))],
            vec![check("other", 0.30, Some(0.35))],
        ];
        let e = collect(&runs).unwrap_err().to_string();
        assert!(e.contains("run 2"), "{e}");
        assert!(collect(&[]).unwrap().is_empty());
    }
}
