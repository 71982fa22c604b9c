//! Reports: markdown and CSV tables, and PNG plots (plotters, bitmap backend).
//!
//! Text in plots is drawn with DejaVu Sans loaded at run time (Debian's
//! `fonts-dejavu-core`, installed by `make deps`), so no font library is linked.

use anyhow::Context as _;
use plotters::prelude::*;
use std::path::Path;

/// A table written both as markdown (for docs) and CSV (for tools).
#[derive(Debug, Clone, Default)]
pub struct Table {
    /// Column names.
    pub headers: Vec<String>,
    /// Rows of cells, each as long as `headers`.
    pub rows: Vec<Vec<String>>,
}

impl Table {
    /// A table with these columns.
    pub fn new(headers: &[&str]) -> Table {
        Table {
            headers: headers.iter().map(|h| h.to_string()).collect(),
            rows: Vec::new(),
        }
    }

    /// Appends a row.
    pub fn push(&mut self, row: Vec<String>) {
        debug_assert_eq!(row.len(), self.headers.len());
        self.rows.push(row);
    }

    /// GitHub-flavoured markdown.
    pub fn to_markdown(&self) -> String {
        let mut s = format!(
            "| {} |\n|{}|\n",
            self.headers.join(" | "),
            vec!["---"; self.headers.len()].join("|")
        );
        for r in &self.rows {
            s += &format!("| {} |\n", r.join(" | "));
        }
        s
    }

    /// RFC 4180 CSV.
    pub fn to_csv(&self) -> String {
        let cell = |c: &String| {
            if c.contains([',', '"', '\n']) {
                format!("\"{}\"", c.replace('"', "\"\""))
            } else {
                c.clone()
            }
        };
        let line = |r: &Vec<String>| r.iter().map(cell).collect::<Vec<_>>().join(",");
        std::iter::once(line(&self.headers))
            .chain(self.rows.iter().map(line))
            .collect::<Vec<_>>()
            .join("\n")
            + "\n"
    }
}

/// Indices of the points no other point beats on both axes (lower is better on both).
pub fn pareto_front(points: &[(f64, f64)]) -> Vec<usize> {
    let mut order: Vec<usize> = (0..points.len()).collect();
    order.sort_by(|&a, &b| {
        points[a]
            .0
            .total_cmp(&points[b].0)
            .then(points[a].1.total_cmp(&points[b].1))
    });
    let mut front = Vec::new();
    let mut best_y = f64::INFINITY;
    for i in order {
        if points[i].1 < best_y {
            best_y = points[i].1;
            front.push(i);
        }
    }
    front
}

fn ensure_font() -> anyhow::Result<()> {
    static FONT: std::sync::OnceLock<Result<(), String>> = std::sync::OnceLock::new();
    FONT.get_or_init(|| {
        let candidates = ["/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf", "/usr/share/fonts/TTF/DejaVuSans.ttf"];
        let bytes = candidates.iter().find_map(|p| std::fs::read(p).ok()).ok_or_else(|| {
            "no DejaVuSans.ttf for plot labels: install Debian's fonts-dejavu-core (`make deps`)".to_string()
        })?;
        let leaked: &'static [u8] = Box::leak(bytes.into_boxed_slice());
        plotters::style::register_font("sans-serif", FontStyle::Normal, leaked).map_err(|_| "DejaVuSans.ttf is not a usable font".to_string())
    })
    .clone()
    .map_err(anyhow::Error::msg)
}

/// A named series of (x, y) points.
pub struct Series {
    /// Legend label.
    pub name: String,
    /// Points.
    pub points: Vec<(f64, f64)>,
}

fn palette(i: usize) -> RGBColor {
    const C: [RGBColor; 8] = [
        RGBColor(31, 119, 180),
        RGBColor(255, 127, 14),
        RGBColor(44, 160, 44),
        RGBColor(214, 39, 40),
        RGBColor(148, 103, 189),
        RGBColor(140, 86, 75),
        RGBColor(227, 119, 194),
        RGBColor(127, 127, 127),
    ];
    C[i % C.len()]
}

fn range(values: impl Iterator<Item = f64>, log: bool) -> (f64, f64) {
    let (lo, hi) = values.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
        (a.min(v), b.max(v))
    });
    if !lo.is_finite() {
        return (0.0, 1.0);
    }
    if log {
        (lo.max(1e-9) / 1.5, hi.max(1e-9) * 1.5)
    } else {
        let pad = ((hi - lo) * 0.08).max(1e-6);
        ((lo - pad).min(0.0_f64.max(lo - pad)), hi + pad)
    }
}

/// Draws series as lines with markers (`lines`) or as scatter points, optionally with
/// the Pareto front of all points drawn as a dashed grey line. `log_x` uses a log axis.
#[allow(clippy::too_many_arguments)]
pub fn plot(
    path: &Path,
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[Series],
    lines: bool,
    log_x: bool,
    pareto: bool,
) -> anyhow::Result<()> {
    ensure_font()?;
    let all: Vec<(f64, f64)> = series
        .iter()
        .flat_map(|s| s.points.iter().copied())
        .collect();
    let (x0, x1) = range(all.iter().map(|p| p.0), log_x);
    let (y0, y1) = range(all.iter().map(|p| p.1), false);
    let root = BitMapBackend::new(path, (900, 560)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| anyhow::anyhow!("{e:?}"))?;
    let mut builder = ChartBuilder::on(&root);
    builder
        .caption(title, ("sans-serif", 22))
        .margin(14)
        .x_label_area_size(44)
        .y_label_area_size(64);
    macro_rules! draw {
        ($chart:expr) => {{
            let mut chart = $chart;
            chart
                .configure_mesh()
                .x_desc(x_label)
                .y_desc(y_label)
                .label_style(("sans-serif", 14))
                .draw()
                .map_err(|e| anyhow::anyhow!("{e:?}"))?;
            for (i, s) in series.iter().enumerate() {
                let color = palette(i);
                if lines {
                    chart
                        .draw_series(LineSeries::new(
                            s.points.iter().copied(),
                            color.stroke_width(2),
                        ))
                        .map_err(|e| anyhow::anyhow!("{e:?}"))?;
                }
                chart
                    .draw_series(s.points.iter().map(|&p| Circle::new(p, 4, color.filled())))
                    .map_err(|e| anyhow::anyhow!("{e:?}"))?
                    .label(s.name.clone())
                    .legend(move |(x, y)| Circle::new((x, y), 5, color.filled()));
            }
            if pareto && all.len() > 1 {
                let front: Vec<(f64, f64)> =
                    pareto_front(&all).into_iter().map(|i| all[i]).collect();
                chart
                    .draw_series(LineSeries::new(
                        front.iter().copied(),
                        BLACK.mix(0.5).stroke_width(1),
                    ))
                    .map_err(|e| anyhow::anyhow!("{e:?}"))?
                    .label("Pareto front")
                    .legend(|(x, y)| PathElement::new([(x - 8, y), (x + 8, y)], BLACK.mix(0.5)));
            }
            chart
                .configure_series_labels()
                .background_style(WHITE.mix(0.85))
                .border_style(BLACK.mix(0.3))
                .label_font(("sans-serif", 13))
                .position(SeriesLabelPosition::UpperRight)
                .draw()
                .map_err(|e| anyhow::anyhow!("{e:?}"))?;
        }};
    }
    if log_x {
        draw!(builder
            .build_cartesian_2d((x0..x1).log_scale(), y0..y1)
            .map_err(|e| anyhow::anyhow!("{e:?}"))?);
    } else {
        draw!(builder
            .build_cartesian_2d(x0..x1, y0..y1)
            .map_err(|e| anyhow::anyhow!("{e:?}"))?);
    }
    root.present()
        .with_context(|| format!("writing plot {}", path.display()))?;
    Ok(())
}

/// One bar of a stacked-bar chart: a short tag printed above it and one value per segment.
pub struct Bar {
    /// Printed above the bar (e.g. "R" for reference).
    pub tag: String,
    /// Segment heights, bottom first, in the order of the chart's segment names.
    pub segments: Vec<f64>,
}

/// Bars side by side above one x-axis label.
pub struct BarGroup {
    /// The x-axis label of the group.
    pub label: String,
    /// Its bars, left to right.
    pub bars: Vec<Bar>,
}

/// Draws groups of stacked bars (paper 000 Figure 13's shape): each segment a colour
/// named in the legend, each bar tagged above, each group labelled on the x axis.
pub fn stacked_bars(
    path: &Path,
    title: &str,
    x_label: &str,
    y_label: &str,
    segment_names: &[String],
    groups: &[BarGroup],
) -> anyhow::Result<()> {
    use plotters::style::text_anchor::{HPos, Pos, VPos};
    ensure_font()?;
    let err = |e: &dyn std::fmt::Debug| anyhow::anyhow!("plot {}: {e:?}", path.display());
    let per_group = groups
        .iter()
        .map(|g| g.bars.len())
        .max()
        .unwrap_or(1)
        .max(1);
    let top = groups
        .iter()
        .flat_map(|g| &g.bars)
        .map(|b| b.segments.iter().sum::<f64>())
        .fold(0.0, f64::max);
    let y1 = if top > 0.0 { top * 1.12 } else { 1.0 };
    let x1 = groups.len() as f64 - 0.5;
    let root = BitMapBackend::new(path, (900, 560)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(&e))?;
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 22))
        .margin(14)
        .x_label_area_size(44)
        .y_label_area_size(64)
        .build_cartesian_2d(-0.5..x1, 0.0..y1)
        .map_err(|e| err(&e))?;
    let group_label = |x: &f64| {
        let i = x.round();
        if (x - i).abs() < 1e-6 && i >= 0.0 && (i as usize) < groups.len() {
            groups[i as usize].label.clone()
        } else {
            String::new()
        }
    };
    chart
        .configure_mesh()
        .disable_x_mesh()
        .x_labels(4 * groups.len() + 2)
        .x_label_formatter(&group_label)
        .x_desc(x_label)
        .y_desc(y_label)
        .label_style(("sans-serif", 14))
        .draw()
        .map_err(|e| err(&e))?;
    let width = 0.8 / per_group as f64;
    let tag_style =
        TextStyle::from(("sans-serif", 12).into_font()).pos(Pos::new(HPos::Center, VPos::Bottom));
    for (gi, g) in groups.iter().enumerate() {
        for (bi, bar) in g.bars.iter().enumerate() {
            let x0 = gi as f64 - 0.4 + bi as f64 * width + 0.05 * width;
            let x1 = x0 + 0.9 * width;
            let mut y = 0.0;
            for (si, &v) in bar.segments.iter().enumerate() {
                chart
                    .draw_series(std::iter::once(Rectangle::new(
                        [(x0, y), (x1, y + v)],
                        palette(si).filled(),
                    )))
                    .map_err(|e| err(&e))?;
                y += v;
            }
            chart
                .draw_series(std::iter::once(Text::new(
                    bar.tag.clone(),
                    ((x0 + x1) * 0.5, y),
                    tag_style.clone(),
                )))
                .map_err(|e| err(&e))?;
        }
    }
    for (si, name) in segment_names.iter().enumerate() {
        let color = palette(si);
        chart
            .draw_series(std::iter::empty::<Rectangle<(f64, f64)>>())
            .map_err(|e| err(&e))?
            .label(name.clone())
            .legend(move |(x, y)| Rectangle::new([(x - 6, y - 6), (x + 6, y + 6)], color.filled()));
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK.mix(0.3))
        .label_font(("sans-serif", 13))
        .position(SeriesLabelPosition::UpperLeft)
        .draw()
        .map_err(|e| err(&e))?;
    root.present()
        .with_context(|| format!("writing plot {}", path.display()))?;
    Ok(())
}

/// `label [#####     ]  40%`: a 50-character progress bar for stderr.
pub fn progress_line(label: &str, done: usize, total: usize) -> String {
    let pct = (done.min(total) * 50).checked_div(total).unwrap_or(50);
    format!("{label} [{:<50}] {:3}%", "#".repeat(pct), pct * 2)
}

/// The machine's 1-minute load average (`/proc/loadavg`), where there is one: reports
/// print it beside every time, since these machines are shared.
pub fn load_average() -> Option<f64> {
    std::fs::read_to_string("/proc/loadavg")
        .ok()?
        .split_whitespace()
        .next()?
        .parse()
        .ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pareto_front_keeps_only_undominated_points() {
        let pts = [(1.0, 5.0), (2.0, 3.0), (3.0, 4.0), (4.0, 1.0), (2.5, 3.0)];
        assert_eq!(pareto_front(&pts), vec![0, 1, 3]);
    }

    #[test]
    fn progress_line_fills_in_proportion() {
        assert!(progress_line("x", 0, 10).ends_with("]   0%"));
        assert!(progress_line("x", 5, 10).contains(&format!(
            "[{}{}]",
            "#".repeat(25),
            " ".repeat(25)
        )));
        assert!(progress_line("x", 10, 10).ends_with("] 100%"));
        assert!(progress_line("x", 0, 0).ends_with("] 100%"));
    }

    #[test]
    fn csv_quotes_commas() {
        let mut t = Table::new(&["a", "b"]);
        t.push(vec!["x,y".into(), "1".into()]);
        assert_eq!(t.to_csv(), "a,b\n\"x,y\",1\n");
        assert!(t.to_markdown().contains("| x,y | 1 |"));
    }
}
