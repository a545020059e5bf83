//! The figures of `lfit bench`, written into `plots/` next to `report.md`, each as PNG and SVG
//! from the same drawing code:
//!
//! - `energy_vs_evaluations`: best energy so far against evaluations at the largest budget,
//!   median and interquartile band over frames × repetitions per method;
//! - `neural_error_per_iteration`: V2V of every iterate of the neural fitter (papers/002 Fig. 4);
//! - `boxplot_energy`, `boxplot_v2v_mm`: per-frame means over repetitions per method and budget.
//!
//! Text is laid out with an embedded DejaVu Sans, so PNGs render the same on machines without
//! system fonts, and the SVGs are byte-identical for the same runs.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use anyhow::{Context, Result, anyhow};
use lfit_model::template::write_atomic;
use plotters::coord::Shift;
use plotters::coord::ranged1d::{AsRangedCoord, DefaultFormatting, KeyPointHint, ValueFormatter};
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use crate::study::bench::{BenchConfig, Run};
use crate::study::report::{label, labels};

const SIZE: (u32, u32) = (1100, 700);
/// The family every text style names; [`ensure_font`] registers DejaVu Sans under it.
const FONT: &str = "sans-serif";
const TITLE_PX: u32 = 22;
const LABEL_PX: u32 = 15;
const DESC_PX: u32 = 17;
/// A log axis cannot show energies of 0 (an exact fit): they are drawn at this floor.
const ENERGY_FLOOR: f64 = 1e-12;
/// Points of the log-spaced evaluation grid the traces are resampled on.
const GRID_POINTS: usize = 160;

/// Tableau 10: distinguishable at a glance and kinder to colour-blind readers than primaries.
const PALETTE: [RGBColor; 10] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(127, 127, 127),
    RGBColor(188, 189, 34),
    RGBColor(23, 190, 207),
];

fn color(i: usize) -> RGBColor {
    PALETTE[i % PALETTE.len()]
}

/// Writes every figure the runs support into `out/plots/` and returns the written paths
/// (PNG then SVG per figure).
pub fn write_plots(config: &BenchConfig, runs: &[Run], out: &Path) -> Result<Vec<PathBuf>> {
    ensure_font()?;
    let dir = out.join("plots");
    std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let mut written = Vec::new();
    if let Some(fig) = energy_figure(config, runs) {
        written.extend(save(&fig, &dir, "energy_vs_evaluations")?);
    }
    match iteration_figure(config, runs) {
        Some(fig) => written.extend(save(&fig, &dir, "neural_error_per_iteration")?),
        // A stale figure from an earlier sweep in the same directory would contradict the runs.
        None => {
            for ext in ["png", "svg"] {
                remove_if_present(&dir.join(format!("neural_error_per_iteration.{ext}")))?;
            }
        }
    }
    for metric in [BoxMetric::Energy, BoxMetric::V2v] {
        if let Some(fig) = box_figure(config, runs, metric) {
            written.extend(save(&fig, &dir, metric.file_name())?);
        }
    }
    Ok(written)
}

fn remove_if_present(path: &Path) -> Result<()> {
    match std::fs::remove_file(path) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
            Err(e).with_context(|| format!("cannot remove stale {}", path.display()))
        }
        _ => Ok(()),
    }
}

/// Registers the embedded font with plotters, once per process: plotters' ab_glyph text
/// backend looks fonts up by family name and has no system fallback.
fn ensure_font() -> Result<()> {
    static REGISTERED: OnceLock<Result<(), String>> = OnceLock::new();
    REGISTERED
        .get_or_init(|| {
            plotters::style::register_font(FONT, FontStyle::Normal, dejavu::sans::regular())
                .map_err(|_| "the embedded DejaVu Sans font could not be parsed".to_string())
        })
        .clone()
        .map_err(|e| anyhow!(e))
}

// ---------------------------------------------------------------------------------------------
// Statistics

/// Quantile `p` of sorted values, interpolating linearly between closest ranks (numpy's default,
/// Hyndman–Fan type 7).
fn quantile(sorted: &[f64], p: f64) -> f64 {
    let Some(last) = sorted.len().checked_sub(1) else {
        return f64::NAN;
    };
    let h = last as f64 * p.clamp(0.0, 1.0);
    let lo = h.floor() as usize;
    let hi = (lo + 1).min(last);
    sorted[lo] + (h - lo as f64) * (sorted[hi] - sorted[lo])
}

#[derive(Debug, Clone, Copy, PartialEq)]
struct Quartiles {
    q1: f64,
    median: f64,
    q3: f64,
}

/// Quartiles of the finite values; `None` when there are none.
fn quartiles(values: &[f64]) -> Option<Quartiles> {
    let mut v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    Some(Quartiles {
        q1: quantile(&v, 0.25),
        median: quantile(&v, 0.5),
        q3: quantile(&v, 0.75),
    })
}

/// Tukey box: quartiles, whiskers at the most extreme values within 1.5 IQR of the box, and the
/// values beyond them.
#[derive(Debug, Clone, PartialEq)]
struct BoxStats {
    q: Quartiles,
    whisker_lo: f64,
    whisker_hi: f64,
    outliers: Vec<f64>,
    n: usize,
}

fn box_stats(values: &[f64]) -> Option<BoxStats> {
    let q = quartiles(values)?;
    let fence = 1.5 * (q.q3 - q.q1);
    let (lo_fence, hi_fence) = (q.q1 - fence, q.q3 + fence);
    let finite: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
    let inside = || {
        finite
            .iter()
            .copied()
            .filter(|x| (lo_fence..=hi_fence).contains(x))
    };
    Some(BoxStats {
        q,
        whisker_lo: inside().fold(q.q1, f64::min),
        whisker_hi: inside().fold(q.q3, f64::max),
        outliers: finite
            .iter()
            .copied()
            .filter(|x| !(lo_fence..=hi_fence).contains(x))
            .collect(),
        n: finite.len(),
    })
}

/// Best energy after `e` evaluations from a trace of `(evaluations, best energy)` in evaluation
/// order: the value of the last point with evaluations ≤ `e`, or the first value before it (the
/// first record is the start, which every run has before any evaluation counts).
fn trace_at(trace: &[(u64, f64)], e: u64) -> Option<f64> {
    let first = trace.first()?;
    let i = trace.partition_point(|&(ev, _)| ev <= e);
    Some(if i == 0 { first.1 } else { trace[i - 1].1 })
}

/// Evaluation counts from 1 to `max`, log-spaced, distinct.
fn log_grid(max: u64, points: usize) -> Vec<u64> {
    let max = max.max(1);
    let steps = points.max(2) - 1;
    let mut grid: Vec<u64> = (0..=steps)
        .map(|i| ((max as f64).powf(i as f64 / steps as f64).round() as u64).clamp(1, max))
        .collect();
    grid.dedup();
    grid
}

fn mean(v: &[f64]) -> f64 {
    if v.is_empty() {
        f64::NAN
    } else {
        v.iter().sum::<f64>() / v.len() as f64
    }
}

/// `1000`, `2.5`, `0.001`, `1e-5`, `3e6`: short tick labels for log and linear axes.
fn fmt_tick(v: &f64) -> String {
    let a = v.abs();
    if a == 0.0 {
        return "0".into();
    }
    if !(1e-3..1e5).contains(&a) {
        return format!("{v:.0e}");
    }
    let decimals = (2 - a.log10().floor() as i32).max(0) as usize;
    let s = format!("{v:.decimals$}");
    if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        s
    }
}

/// A log axis range around the positive values, with a little room on either side.
fn log_range(values: impl IntoIterator<Item = f64>) -> Option<(f64, f64)> {
    let (lo, hi) = values
        .into_iter()
        .filter(|v| v.is_finite() && *v > 0.0)
        .fold((f64::INFINITY, 0.0f64), |(lo, hi), v| {
            (lo.min(v), hi.max(v))
        });
    if !lo.is_finite() {
        return None;
    }
    // At least a factor of 10 shown, so the axis has a labelled power of ten or a few ticks.
    let pad = ((hi / lo).log10() * 0.06).max(0.05);
    let (mut lo, mut hi) = (lo / 10f64.powf(pad), hi * 10f64.powf(pad));
    if hi / lo < 10.0 {
        let widen = (10.0 / (hi / lo)).sqrt();
        (lo, hi) = (lo / widen, hi * widen);
    }
    Some((lo, hi))
}

// ---------------------------------------------------------------------------------------------
// Figure data

/// Median line and interquartile band of one series.
#[derive(Debug, Clone, PartialEq)]
struct Band {
    name: String,
    color: RGBColor,
    points: Vec<(f64, Quartiles)>,
}

impl Band {
    fn polygon(&self) -> Vec<(f64, f64)> {
        let upper = self.points.iter().map(|(x, q)| (*x, q.q3));
        let lower = self.points.iter().rev().map(|(x, q)| (*x, q.q1));
        upper.chain(lower).collect()
    }
}

/// A method without a trace: one point at the median evaluations and energy, with quartile bars.
#[derive(Debug, Clone, PartialEq)]
struct Marker {
    name: String,
    color: RGBColor,
    x: Quartiles,
    y: Quartiles,
}

#[derive(Debug, Clone, PartialEq)]
struct EnergyFigure {
    budget: usize,
    bands: Vec<Band>,
    markers: Vec<Marker>,
}

fn energy_figure(config: &BenchConfig, runs: &[Run]) -> Option<EnergyFigure> {
    let budget = runs.iter().map(|r| r.budget).max()?;
    let grid = log_grid(budget as u64, GRID_POINTS);
    let mut fig = EnergyFigure {
        budget,
        bands: Vec::new(),
        markers: Vec::new(),
    };
    for (i, l) in labels(config, runs).iter().enumerate() {
        let rs: Vec<&Run> = runs
            .iter()
            .filter(|r| r.budget == budget && label(config, r) == *l)
            .collect();
        let traced: Vec<&[(u64, f64)]> = rs
            .iter()
            .map(|r| r.trace.as_slice())
            .filter(|t| !t.is_empty())
            .collect();
        if !traced.is_empty() {
            let points: Vec<(f64, Quartiles)> = grid
                .iter()
                .filter_map(|&e| {
                    let at: Vec<f64> = traced
                        .iter()
                        .filter_map(|t| trace_at(t, e))
                        .map(|v| v.max(ENERGY_FLOOR))
                        .collect();
                    quartiles(&at).map(|q| (e as f64, q))
                })
                .collect();
            if !points.is_empty() {
                fig.bands.push(Band {
                    name: format!("{l} (n = {})", traced.len()),
                    color: color(i),
                    points,
                });
            }
        } else {
            let x = quartiles(
                &rs.iter()
                    .map(|r| r.evaluations.max(1) as f64)
                    .collect::<Vec<_>>(),
            );
            let y = quartiles(
                &rs.iter()
                    .map(|r| r.energy.max(ENERGY_FLOOR))
                    .collect::<Vec<_>>(),
            );
            if let (Some(x), Some(y)) = (x, y) {
                fig.markers.push(Marker {
                    name: format!("{l} (n = {}, no trace)", rs.len()),
                    color: color(i),
                    x,
                    y,
                });
            }
        }
    }
    (!fig.bands.is_empty() || !fig.markers.is_empty()).then_some(fig)
}

#[derive(Debug, Clone, PartialEq)]
struct IterationFigure {
    bands: Vec<Band>,
}

fn iteration_figure(config: &BenchConfig, runs: &[Run]) -> Option<IterationFigure> {
    let mut series: Vec<(String, usize)> = Vec::new();
    for r in runs.iter().filter(|r| !r.v2v_per_iteration.is_empty()) {
        let key = (label(config, r), r.budget);
        if !series.contains(&key) {
            series.push(key);
        }
    }
    series.sort_by_key(|(_, b)| *b);
    let bands: Vec<Band> = series
        .iter()
        .enumerate()
        .map(|(i, (l, b))| {
            let rs: Vec<&Run> = runs
                .iter()
                .filter(|r| {
                    !r.v2v_per_iteration.is_empty() && r.budget == *b && label(config, r) == *l
                })
                .collect();
            let len = rs
                .iter()
                .map(|r| r.v2v_per_iteration.len())
                .max()
                .unwrap_or(0);
            let points = (0..len)
                .filter_map(|k| {
                    quartiles(
                        &rs.iter()
                            .filter_map(|r| r.v2v_per_iteration.get(k).copied())
                            .collect::<Vec<_>>(),
                    )
                    .map(|q| (k as f64, q))
                })
                .collect();
            Band {
                name: format!("{l} @ {b} (n = {})", rs.len()),
                color: color(i),
                points,
            }
        })
        .collect();
    (!bands.is_empty()).then_some(IterationFigure { bands })
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum BoxMetric {
    Energy,
    V2v,
}

impl BoxMetric {
    fn file_name(self) -> &'static str {
        match self {
            Self::Energy => "boxplot_energy",
            Self::V2v => "boxplot_v2v_mm",
        }
    }

    fn value(self, r: &Run) -> f64 {
        match self {
            Self::Energy => r.energy,
            Self::V2v => r.v2v_mm,
        }
    }
}

#[derive(Debug, Clone, PartialEq)]
struct BoxCategory {
    name: String,
    budget: usize,
    color: RGBColor,
    stats: BoxStats,
}

#[derive(Debug, Clone, PartialEq)]
struct BoxFigure {
    metric: BoxMetric,
    repetitions: usize,
    boxes: Vec<BoxCategory>,
}

/// One box per label × budget (budgets ascending, labels in config order) over the per-frame
/// means across repetitions, the unit the report's tests compare.
fn box_figure(config: &BenchConfig, runs: &[Run], metric: BoxMetric) -> Option<BoxFigure> {
    let mut budgets: Vec<usize> = runs.iter().map(|r| r.budget).collect();
    budgets.sort_unstable();
    budgets.dedup();
    let mut boxes = Vec::new();
    for &b in &budgets {
        for (i, l) in labels(config, runs).iter().enumerate() {
            let mut frames: Vec<(usize, Vec<f64>)> = Vec::new();
            for r in runs
                .iter()
                .filter(|r| r.budget == b && label(config, r) == *l)
            {
                let v = metric.value(r);
                let v = if metric == BoxMetric::Energy {
                    v.max(ENERGY_FLOOR)
                } else {
                    v
                };
                match frames.iter_mut().find(|(f, _)| *f == r.frame) {
                    Some((_, vs)) => vs.push(v),
                    None => frames.push((r.frame, vec![v])),
                }
            }
            let means: Vec<f64> = frames.iter().map(|(_, vs)| mean(vs)).collect();
            if let Some(stats) = box_stats(&means) {
                boxes.push(BoxCategory {
                    name: format!("{l} @ {b}"),
                    budget: b,
                    color: color(i),
                    stats,
                });
            }
        }
    }
    (!boxes.is_empty()).then_some(BoxFigure {
        metric,
        repetitions: config.repetitions,
        boxes,
    })
}

// ---------------------------------------------------------------------------------------------
// Drawing

type DrawResult<DB> = Result<(), DrawingAreaErrorKind<<DB as DrawingBackend>::ErrorType>>;

/// A figure drawn the same way on any backend (PNG and SVG).
trait Figure {
    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> DrawResult<DB>;
}

/// Writes `dir/name.svg` and `dir/name.png`, each atomically.
fn save(fig: &impl Figure, dir: &Path, name: &str) -> Result<[PathBuf; 2]> {
    let svg_path = dir.join(format!("{name}.svg"));
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, SIZE).into_drawing_area();
        fig.draw(&root)
            .and_then(|()| root.present())
            .map_err(|e| anyhow!("cannot draw {}: {e}", svg_path.display()))?;
    }
    write_atomic(&svg_path, svg.as_bytes())?;

    let png_path = dir.join(format!("{name}.png"));
    // plotters picks the image encoder from the extension, so the temporary name keeps `.png`.
    let tmp = dir.join(format!(".{name}.tmp{}.png", std::process::id()));
    let drawn = {
        let root = BitMapBackend::new(&tmp, SIZE).into_drawing_area();
        fig.draw(&root).and_then(|()| root.present())
    };
    let result = drawn
        .map_err(|e| anyhow!("cannot draw {}: {e}", png_path.display()))
        .and_then(|()| {
            std::fs::rename(&tmp, &png_path)
                .with_context(|| format!("cannot write {}", png_path.display()))
        });
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result?;
    Ok([png_path, svg_path])
}

fn text(px: u32) -> TextStyle<'static> {
    (FONT, px).into_font().color(&BLACK)
}

/// The series legend in the top right corner, where descending curves leave room.
fn draw_legend<'a, DB: DrawingBackend + 'a, X: Ranged, Y: Ranged>(
    chart: &mut ChartContext<'a, DB, Cartesian2d<X, Y>>,
) -> DrawResult<DB> {
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .background_style(WHITE.mix(0.9))
        .border_style(BLACK.mix(0.4))
        .label_font(text(LABEL_PX))
        .draw()
}

fn legend_line(color: RGBColor) -> impl Fn((i32, i32)) -> PathElement<(i32, i32)> {
    move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(3))
}

impl Figure for EnergyFigure {
    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> DrawResult<DB> {
        root.fill(&WHITE)?;
        let ys = self
            .bands
            .iter()
            .flat_map(|b| b.points.iter().flat_map(|(_, q)| [q.q1, q.q3]))
            .chain(self.markers.iter().flat_map(|m| [m.y.q1, m.y.q3]));
        let (y_lo, y_hi) = log_range(ys).unwrap_or((0.1, 10.0));
        let x_hi = self
            .markers
            .iter()
            .map(|m| m.x.q3 * 1.2)
            .fold(self.budget as f64, f64::max)
            .max(2.0);
        let mut chart = ChartBuilder::on(root)
            .caption(format!("Best energy vs evaluations at budget {} (median, IQR band over frames × repetitions)", self.budget), text(TITLE_PX))
            .margin(20)
            .x_label_area_size(55)
            .y_label_area_size(85)
            .build_cartesian_2d(LogAxis::new(1.0, x_hi), LogAxis::new(y_lo, y_hi))?;
        chart
            .configure_mesh()
            .x_desc("energy evaluations (log scale)")
            .y_desc("best energy so far (log scale)")
            .x_label_formatter(&fmt_tick)
            .y_label_formatter(&fmt_tick)
            .label_style(text(LABEL_PX))
            .axis_desc_style(text(DESC_PX))
            .light_line_style(BLACK.mix(0.04))
            .bold_line_style(BLACK.mix(0.12))
            .draw()?;
        // Fainter bands when many overlap, so the lower ones still show through.
        let alpha = (0.6 / self.bands.len().max(1) as f64).clamp(0.08, 0.2);
        for band in &self.bands {
            chart.draw_series(std::iter::once(Polygon::new(
                band.polygon(),
                band.color.mix(alpha).filled(),
            )))?;
        }
        for band in &self.bands {
            chart
                .draw_series(LineSeries::new(
                    band.points.iter().map(|(x, q)| (*x, q.median)),
                    band.color.stroke_width(2),
                ))?
                .label(band.name.as_str())
                .legend(legend_line(band.color));
        }
        for m in &self.markers {
            let style = m.color.stroke_width(2);
            let bars = [
                PathElement::new(vec![(m.x.q1, m.y.median), (m.x.q3, m.y.median)], style),
                PathElement::new(vec![(m.x.median, m.y.q1), (m.x.median, m.y.q3)], style),
            ];
            chart.draw_series(bars)?;
            let color = m.color;
            chart
                .draw_series(std::iter::once(Circle::new(
                    (m.x.median, m.y.median),
                    5,
                    color.filled(),
                )))?
                .label(m.name.as_str())
                .legend(move |(x, y)| Circle::new((x + 10, y), 5, color.filled()));
        }
        draw_legend(&mut chart)
    }
}

impl Figure for IterationFigure {
    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> DrawResult<DB> {
        root.fill(&WHITE)?;
        let last = self
            .bands
            .iter()
            .flat_map(|b| b.points.iter().map(|(x, _)| *x as u32))
            .max()
            .unwrap_or(0)
            .max(1);
        let y_hi = self
            .bands
            .iter()
            .flat_map(|b| b.points.iter().map(|(_, q)| q.q3))
            .filter(|v| v.is_finite())
            .fold(0.0, f64::max);
        let y_hi = if y_hi > 0.0 { y_hi * 1.1 } else { 1.0 };
        let mut chart = ChartBuilder::on(root)
            .caption(
                "Neural fitter V2V per iteration (median, IQR band over frames × repetitions)",
                text(TITLE_PX),
            )
            .margin(20)
            .x_label_area_size(55)
            .y_label_area_size(85)
            .build_cartesian_2d(0u32..last, 0.0..y_hi)?;
        chart
            .configure_mesh()
            .x_desc("iteration (0 = start)")
            .y_desc("V2V error (mm)")
            .y_label_formatter(&fmt_tick)
            .label_style(text(LABEL_PX))
            .axis_desc_style(text(DESC_PX))
            .light_line_style(BLACK.mix(0.04))
            .bold_line_style(BLACK.mix(0.12))
            .draw()?;
        let at = |x: f64| x as u32;
        for band in &self.bands {
            let poly: Vec<(u32, f64)> = band
                .polygon()
                .into_iter()
                .map(|(x, y)| (at(x), y))
                .collect();
            chart.draw_series(std::iter::once(Polygon::new(
                poly,
                band.color.mix(0.18).filled(),
            )))?;
        }
        for band in &self.bands {
            let color = band.color;
            chart
                .draw_series(
                    LineSeries::new(
                        band.points.iter().map(|(x, q)| (at(*x), q.median)),
                        color.stroke_width(2),
                    )
                    .point_size(3),
                )?
                .label(band.name.as_str())
                .legend(legend_line(color));
        }
        draw_legend(&mut chart)
    }
}

impl Figure for BoxFigure {
    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> DrawResult<DB> {
        root.fill(&WHITE)?;
        let values = || {
            self.boxes.iter().flat_map(|b| {
                [b.stats.whisker_lo, b.stats.whisker_hi]
                    .into_iter()
                    .chain(b.stats.outliers.iter().copied())
            })
        };
        match self.metric {
            BoxMetric::Energy => {
                let (lo, hi) = log_range(values()).unwrap_or((0.1, 10.0));
                self.draw_on(root, LogAxis::new(lo, hi), "final energy (log scale)")
            }
            BoxMetric::V2v => {
                let hi = values().filter(|v| v.is_finite()).fold(0.0, f64::max);
                let hi = if hi > 0.0 { hi * 1.08 } else { 1.0 };
                self.draw_on(root, 0.0..hi, "V2V error (mm)")
            }
        }
    }
}

/// A log axis with ticks at 1-2-5 × 10^k, or at powers of ten when those are too many:
/// plotters' own log axis labels only from the first power of ten inside the range up, so a
/// range such as 0.3–30 would show no label below 1.
struct LogAxis {
    log: LogCoord<f64>,
    lo: f64,
    hi: f64,
}

impl LogAxis {
    fn new(lo: f64, hi: f64) -> Self {
        Self {
            log: (lo..hi).log_scale().into(),
            lo,
            hi,
        }
    }
}

/// Log ticks in `lo..=hi`, at most `max` of them unless even every power of ten is too many, in
/// which case every few powers of ten.
fn log_ticks(lo: f64, hi: f64, max: usize, light: bool) -> Vec<f64> {
    let (k0, k1) = (lo.log10().floor() as i32, hi.log10().ceil() as i32);
    let at = |mantissas: &[f64], step: usize| -> Vec<f64> {
        (k0..=k1)
            .step_by(step)
            .flat_map(|k| mantissas.iter().map(move |m| m * 10f64.powi(k)))
            .filter(|v| (lo..=hi).contains(v))
            .collect()
    };
    let mantissas: &[&[f64]] = if light {
        &[&[1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0], &[1.0]]
    } else {
        &[&[1.0, 2.0, 5.0], &[1.0]]
    };
    for m in mantissas {
        let ticks = at(m, 1);
        if ticks.len() <= max {
            return ticks;
        }
    }
    let step = ((k1 - k0 + 1) as usize).div_ceil(max.max(1));
    at(&[1.0], step)
}

impl Ranged for LogAxis {
    type FormatOption = DefaultFormatting;
    type ValueType = f64;

    fn map(&self, value: &f64, limit: (i32, i32)) -> i32 {
        self.log.map(value, limit)
    }

    fn key_points<Hint: KeyPointHint>(&self, hint: Hint) -> Vec<f64> {
        log_ticks(
            self.lo,
            self.hi,
            hint.max_num_points(),
            hint.weight().allow_light_points(),
        )
    }

    fn range(&self) -> std::ops::Range<f64> {
        self.lo..self.hi
    }
}

/// An x axis of `n` categories at 0, 1, …, n − 1 with a tick and label at each and nothing
/// between; boxes sit at fractional offsets around them. (plotters' `with_key_points` would do
/// but loses the value formatter its mesh needs.)
struct Categories {
    n: usize,
    linear: plotters::coord::types::RangedCoordf64,
}

impl Ranged for Categories {
    type FormatOption = DefaultFormatting;
    type ValueType = f64;

    fn map(&self, value: &f64, limit: (i32, i32)) -> i32 {
        self.linear.map(value, limit)
    }

    fn key_points<Hint: KeyPointHint>(&self, hint: Hint) -> Vec<f64> {
        if hint.weight().allow_light_points() {
            Vec::new()
        } else {
            (0..self.n).map(|i| i as f64).collect()
        }
    }

    fn range(&self) -> std::ops::Range<f64> {
        self.linear.range()
    }
}

impl BoxFigure {
    fn draw_on<DB, Y>(&self, root: &DrawingArea<DB, Shift>, y: Y, y_desc: &str) -> DrawResult<DB>
    where
        DB: DrawingBackend,
        Y: AsRangedCoord<Value = f64>,
        Y::CoordDescType: ValueFormatter<f64>,
    {
        let what = match self.metric {
            BoxMetric::Energy => "Final energy",
            BoxMetric::V2v => "V2V error",
        };
        let n = self.boxes.len();
        let names: Vec<&str> = self.boxes.iter().map(|b| b.name.as_str()).collect();
        // Category names turn vertical when they would overlap side by side.
        let label_style = text(LABEL_PX);
        let mut widest = 0;
        for name in &names {
            widest = widest.max(root.estimate_text_size(name, &label_style)?.0);
        }
        let room = (SIZE.0 - 140) / n.max(1) as u32;
        let vertical = widest + 10 > room;
        let x_area = if vertical { widest + 55 } else { 55 };
        // Vertical names are drawn below instead: the mesh anchors a label before rotating it,
        // which would centre the name on the axis line.
        let x_fmt = |v: &f64| {
            if vertical {
                String::new()
            } else {
                names
                    .get(v.round().max(0.0) as usize)
                    .map_or_else(String::new, |s| (*s).to_string())
            }
        };

        let x = Categories {
            n,
            linear: (-0.5..n as f64 - 0.5).into(),
        };
        let mut chart = ChartBuilder::on(root)
            .caption(format!("{what} per frame, mean over {} repetition(s): box = quartiles, whiskers = 1.5 IQR", self.repetitions), text(TITLE_PX))
            .margin(20)
            .x_label_area_size(x_area)
            .y_label_area_size(85)
            .build_cartesian_2d(x, y)?;
        chart
            .configure_mesh()
            .disable_x_mesh()
            .x_desc("method @ budget (evaluations)")
            .y_desc(y_desc)
            .x_label_formatter(&x_fmt)
            .y_label_formatter(&fmt_tick)
            .label_style(label_style.clone())
            .axis_desc_style(text(DESC_PX))
            .light_line_style(BLACK.mix(0.04))
            .bold_line_style(BLACK.mix(0.12))
            .draw()?;
        let (y_lo, y_hi) = {
            let r = chart.y_range();
            (r.start, r.end)
        };
        if vertical {
            let style = label_style
                .transform(FontTransform::Rotate270)
                .pos(Pos::new(HPos::Right, VPos::Center));
            for (i, name) in names.iter().enumerate() {
                let (px, py) = chart.backend_coord(&(i as f64, y_lo));
                root.draw(&Text::new(*name, (px, py + 10), style.clone()))?;
            }
        }
        // Dashed separators between budget groups.
        for (i, pair) in self.boxes.windows(2).enumerate() {
            if pair[0].budget != pair[1].budget {
                let xs = i as f64 + 0.5;
                chart.draw_series(DashedLineSeries::new(
                    [(xs, y_lo), (xs, y_hi)],
                    6,
                    4,
                    BLACK.mix(0.35).stroke_width(1),
                ))?;
            }
        }
        for (i, b) in self.boxes.iter().enumerate() {
            let (x, s) = (i as f64, &b.stats);
            let (half, cap) = (0.28, 0.14);
            let line = b.color.stroke_width(2);
            chart.draw_series([
                Rectangle::new(
                    [(x - half, s.q.q1), (x + half, s.q.q3)],
                    b.color.mix(0.3).filled(),
                ),
                Rectangle::new([(x - half, s.q.q1), (x + half, s.q.q3)], line),
            ])?;
            chart.draw_series([
                PathElement::new(
                    vec![(x - half, s.q.median), (x + half, s.q.median)],
                    BLACK.stroke_width(2),
                ),
                PathElement::new(vec![(x, s.q.q1), (x, s.whisker_lo)], line),
                PathElement::new(vec![(x, s.q.q3), (x, s.whisker_hi)], line),
                PathElement::new(vec![(x - cap, s.whisker_lo), (x + cap, s.whisker_lo)], line),
                PathElement::new(vec![(x - cap, s.whisker_hi), (x + cap, s.whisker_hi)], line),
            ])?;
            chart.draw_series(
                s.outliers
                    .iter()
                    .map(|&v| Circle::new((x, v), 3, b.color.stroke_width(1))),
            )?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn config(strategies: &str) -> BenchConfig {
        let text = format!(
            "name = \"plots\"\nmethods = [\"cma\", \"pso\", \"neural\"]\nbudgets = [100, 400]\nrepetitions = 2\nstrategies = {strategies}\n[synth]\nmodality = \"markers\"\nframes = 3\n"
        );
        match toml::from_str(&text) {
            Ok(c) => c,
            Err(e) => panic!("test config: {e}"),
        }
    }

    fn run(method: &str, budget: usize, rep: usize, frame: usize) -> Run {
        let k = (rep * 3 + frame) as f64;
        let scale = if method == "cma" { 1.0 } else { 2.5 };
        let trace = match method {
            "neural" => Vec::new(),
            _ => (0..=8)
                .map(|i| {
                    (
                        (i * budget / 8).max(1) as u64,
                        scale * (1.0 + k) * 0.6f64.powi(i as i32),
                    )
                })
                .collect(),
        };
        let energy = trace.last().map_or(0.05 * (1.0 + k), |t| t.1);
        Run {
            method: method.into(),
            strategy: "holistic".into(),
            budget,
            rep,
            frame,
            seed: k as u64,
            energy,
            start_energy: scale * (1.0 + k),
            v2v_mm: 10.0 * scale + k,
            mpjpe_mm: 8.0 + k,
            pa_mpjpe_mm: 5.0 + k,
            hausdorff_mm: 12.0 + k,
            shape_rms: f64::NAN,
            evaluations: budget as u64,
            gradient_evaluations: 0,
            iterations: 8,
            time_s: 0.01,
            trace,
            v2v_per_iteration: if method == "neural" {
                (0..5).map(|i| 40.0 / (1.0 + i as f64) + k).collect()
            } else {
                Vec::new()
            },
            face: None,
            shape_v2v_mm: f64::NAN,
        }
    }

    fn runs(methods: &[&str]) -> Vec<Run> {
        let mut out = Vec::new();
        for &b in &[100, 400] {
            for m in methods {
                for rep in 0..2 {
                    for frame in 0..3 {
                        out.push(run(m, b, rep, frame));
                    }
                }
            }
        }
        out
    }

    fn read(path: &Path) -> Vec<u8> {
        match std::fs::read(path) {
            Ok(b) => b,
            Err(e) => panic!("{}: {e}", path.display()),
        }
    }

    fn png_size(bytes: &[u8]) -> (u32, u32) {
        assert!(bytes.len() > 24, "truncated PNG");
        assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n", "PNG signature");
        assert_eq!(&bytes[12..16], b"IHDR", "PNG starts with IHDR");
        let be = |s: &[u8]| u32::from_be_bytes([s[0], s[1], s[2], s[3]]);
        (be(&bytes[16..20]), be(&bytes[20..24]))
    }

    #[test]
    fn quantiles_match_numpy_linear_interpolation() {
        let q = quartiles(&[10.0, 1.0, 4.0, 3.0, 2.0]).expect("quartiles");
        assert_eq!(
            q,
            Quartiles {
                q1: 2.0,
                median: 3.0,
                q3: 4.0
            }
        );
        // numpy.quantile([1, 2, 3, 4], [0.25, 0.5, 0.75]) = [1.75, 2.5, 3.25].
        let q = quartiles(&[4.0, 2.0, 1.0, 3.0, f64::NAN]).expect("quartiles");
        assert_eq!(
            q,
            Quartiles {
                q1: 1.75,
                median: 2.5,
                q3: 3.25
            }
        );
        assert_eq!(quantile(&[1.0, 2.0, 3.0, 4.0, 10.0], 0.0), 1.0);
        assert_eq!(quantile(&[1.0, 2.0, 3.0, 4.0, 10.0], 1.0), 10.0);
        assert_eq!(
            quartiles(&[7.0]),
            Some(Quartiles {
                q1: 7.0,
                median: 7.0,
                q3: 7.0
            })
        );
        assert_eq!(quartiles(&[]), None);
        assert_eq!(quartiles(&[f64::NAN]), None);
    }

    #[test]
    fn box_whiskers_stop_at_one_and_a_half_iqr() {
        let s = box_stats(&[1.0, 2.0, 3.0, 4.0, 10.0]).expect("box");
        // IQR 2 → fences −1 and 7: 10 is an outlier, the upper whisker ends at 4.
        assert_eq!(
            (s.whisker_lo, s.whisker_hi, s.outliers.clone(), s.n),
            (1.0, 4.0, vec![10.0], 5)
        );
    }

    #[test]
    fn trace_resamples_as_a_step_function() {
        let trace = [(10, 5.0), (20, 3.0), (40, 1.0)];
        let at = |e| trace_at(&trace, e);
        assert_eq!(
            [
                at(1),
                at(9),
                at(10),
                at(19),
                at(20),
                at(39),
                at(40),
                at(1000)
            ],
            [5.0, 5.0, 5.0, 5.0, 3.0, 3.0, 1.0, 1.0].map(Some)
        );
        assert_eq!(trace_at(&[], 5), None);
    }

    #[test]
    fn log_grid_spans_one_to_the_budget() {
        let g = log_grid(600, GRID_POINTS);
        assert_eq!((g.first(), g.last()), (Some(&1), Some(&600)));
        assert!(g.windows(2).all(|w| w[0] < w[1]));
        assert_eq!(log_grid(1, GRID_POINTS), vec![1]);
    }

    #[test]
    fn log_ticks_label_every_decade_part() {
        assert_eq!(
            log_ticks(0.3, 27.0, 10, false),
            vec![0.5, 1.0, 2.0, 5.0, 10.0, 20.0]
        );
        assert_eq!(
            log_ticks(1.0, 600.0, 10, false),
            vec![1.0, 2.0, 5.0, 10.0, 20.0, 50.0, 100.0, 200.0, 500.0]
        );
        assert_eq!(log_ticks(1.0, 1e5, 5, false), vec![1.0, 100.0, 1e4]);
        assert_eq!(log_ticks(1e-12, 30.0, 10, false).len(), 7);
    }

    #[test]
    fn tick_labels_are_short() {
        let t = |v: f64| fmt_tick(&v);
        assert_eq!(
            [
                t(1000.0),
                t(2.5),
                t(0.001),
                t(1e-5),
                t(3e6),
                t(0.0),
                t(100.0)
            ],
            ["1000", "2.5", "0.001", "1e-5", "3e6", "0", "100"]
        );
    }

    #[test]
    fn writes_every_plot_as_png_and_svg() {
        let dir = tempfile::tempdir().expect("tempdir");
        let written = write_plots(
            &config("[\"holistic\"]"),
            &runs(&["cma", "pso", "neural"]),
            dir.path(),
        )
        .expect("plots");
        let names = [
            "energy_vs_evaluations",
            "neural_error_per_iteration",
            "boxplot_energy",
            "boxplot_v2v_mm",
        ];
        let expected: Vec<PathBuf> = names
            .iter()
            .flat_map(|n| ["png", "svg"].map(|e| dir.path().join("plots").join(format!("{n}.{e}"))))
            .collect();
        assert_eq!(written, expected);
        for path in &expected {
            let bytes = read(path);
            if path.extension().is_some_and(|e| e == "png") {
                assert_eq!(png_size(&bytes), SIZE, "{}", path.display());
            } else {
                let svg = String::from_utf8(bytes).expect("UTF-8 SVG");
                assert!(
                    svg.starts_with("<svg") && svg.trim_end().ends_with("</svg>"),
                    "{}",
                    path.display()
                );
                let methods: &[&str] = if path.to_string_lossy().contains("neural_error") {
                    &["neural"]
                } else {
                    &["cma", "pso", "neural"]
                };
                for m in methods {
                    assert!(svg.contains(m), "{} lacks the label {m}", path.display());
                }
            }
        }
        let leftovers: Vec<_> = std::fs::read_dir(dir.path().join("plots"))
            .expect("plots dir")
            .filter_map(|e| e.ok())
            .filter(|e| e.file_name().to_string_lossy().starts_with('.'))
            .collect();
        assert!(leftovers.is_empty(), "temporary files left: {leftovers:?}");
    }

    #[test]
    fn neural_plot_needs_per_iteration_errors() {
        let dir = tempfile::tempdir().expect("tempdir");
        let plots = dir.path().join("plots");
        write_plots(
            &config("[\"holistic\"]"),
            &runs(&["cma", "neural"]),
            dir.path(),
        )
        .expect("plots");
        assert!(plots.join("neural_error_per_iteration.svg").exists());
        // Rewritten without per-iteration errors: no figure, and the stale one is gone.
        let written = write_plots(
            &config("[\"holistic\"]"),
            &runs(&["cma", "pso"]),
            dir.path(),
        )
        .expect("plots");
        assert_eq!(written.len(), 6);
        assert!(!plots.join("neural_error_per_iteration.svg").exists());
        assert!(!plots.join("neural_error_per_iteration.png").exists());
    }

    #[test]
    fn same_runs_give_identical_svgs() {
        let (a, b) = (
            tempfile::tempdir().expect("tempdir"),
            tempfile::tempdir().expect("tempdir"),
        );
        let rs = runs(&["cma", "pso", "neural"]);
        let wa = write_plots(&config("[\"holistic\"]"), &rs, a.path()).expect("plots");
        let wb = write_plots(&config("[\"holistic\"]"), &rs, b.path()).expect("plots");
        for (pa, pb) in wa
            .iter()
            .zip(&wb)
            .filter(|(p, _)| p.extension().is_some_and(|e| e == "svg"))
        {
            assert!(
                read(pa) == read(pb),
                "{} differs between runs",
                pa.display()
            );
        }
    }

    #[test]
    fn crowded_category_names_turn_vertical() {
        let dir = tempfile::tempdir().expect("tempdir");
        let names: Vec<String> = (0..5)
            .map(|i| format!("a-rather-long-method-{i}"))
            .collect();
        let methods: Vec<&str> = names.iter().map(String::as_str).collect();
        write_plots(&config("[\"holistic\"]"), &runs(&methods), dir.path()).expect("plots");
        let svg =
            String::from_utf8(read(&dir.path().join("plots/boxplot_v2v_mm.svg"))).expect("UTF-8");
        assert!(svg.contains("rotate(270"), "vertical category names");
        assert!(names.iter().all(|n| svg.contains(&format!("{n} @ 400"))));
    }

    #[test]
    fn strategy_labels_and_traceless_methods() {
        let dir = tempfile::tempdir().expect("tempdir");
        let mut rs = runs(&["cma", "neural"]);
        for r in rs.iter_mut().filter(|r| r.method == "cma") {
            r.strategy = "hierarchical".into();
        }
        // Exact fits (energy 0) must not break the log axes.
        rs[0].trace = vec![(1, 0.0)];
        rs[0].energy = 0.0;
        write_plots(&config("[\"holistic\", \"hierarchical\"]"), &rs, dir.path()).expect("plots");
        let svg = String::from_utf8(read(&dir.path().join("plots/energy_vs_evaluations.svg")))
            .expect("UTF-8");
        assert!(
            svg.contains("cma (hierarchical)") && svg.contains("no trace"),
            "labels in the energy plot"
        );
    }
}
