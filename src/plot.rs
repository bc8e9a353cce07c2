//! The PNG of `amstack compare --plot`: per signal, A and B over time, their difference
//! below, the intervals shaded on both; axes with units, a legend.
//!
//! Text is drawn with DejaVu Sans embedded in the binary (plotters' `ab_glyph` feature: no
//! system font library needed).

use std::path::Path;

use plotters::prelude::*;
use plotters::style::FontStyle;
use policy_runtime::validation::{CompareReport, SignalReport};

/// DejaVu Sans (Bitstream Vera licence, see `assets/fonts/DejaVuSans-LICENSE.txt`).
pub(crate) static FONT: &[u8] = include_bytes!("../assets/fonts/DejaVuSans.ttf");

/// Signals drawn at most (one panel each).
const MAX_PANELS: usize = 8;
const WIDTH_PX: u32 = 1400;
const PANEL_HEIGHT_PX: u32 = 560;

const A_COLOR: RGBColor = RGBColor(31, 119, 180);
const B_COLOR: RGBColor = RGBColor(214, 39, 40);
const DIFF_COLOR: RGBColor = RGBColor(44, 140, 44);
const INTERVAL_COLORS: [RGBColor; 4] = [
    RGBColor(255, 170, 60),
    RGBColor(120, 170, 255),
    RGBColor(170, 220, 120),
    RGBColor(220, 140, 220),
];

type PlotResult<T> = Result<T, Box<dyn std::error::Error>>;

/// Contiguous runs of `mask` as time spans [first, last] over `times`.
fn runs(times: &[f64], mask: &[bool]) -> Vec<(f64, f64)> {
    let mut out = Vec::new();
    let mut start: Option<usize> = None;
    for i in 0..=mask.len() {
        let on = mask.get(i).copied().unwrap_or(false);
        match (on, start) {
            (true, None) => start = Some(i),
            (false, Some(s)) => {
                out.push((times[s], times[i - 1]));
                start = None;
            }
            _ => {}
        }
    }
    out
}

fn range(values: impl Iterator<Item = f64>) -> (f64, f64) {
    let (lo, hi) = values
        .filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
            (lo.min(v), hi.max(v))
        });
    if !lo.is_finite() {
        return (-1.0, 1.0);
    }
    let pad = ((hi - lo) * 0.08).max(1e-6 * (1.0 + lo.abs().max(hi.abs())));
    (lo - pad, hi + pad)
}

fn file_name(path: &Path) -> String {
    path.file_name().map_or_else(
        || path.display().to_string(),
        |n| n.to_string_lossy().into_owned(),
    )
}

/// Tick labels that stay distinct for the axis span `(lo, hi)`: enough decimals for about
/// three significant digits of the span, scientific notation for tiny or huge values.
fn tick_label(lo: f64, hi: f64) -> impl Fn(&f64) -> String {
    let span = (hi - lo).abs().max(f64::MIN_POSITIVE);
    let magnitude = lo.abs().max(hi.abs());
    let scientific = span < 1e-3 || magnitude >= 1e6;
    let decimals = (2.0 - span.log10().floor()).clamp(0.0, 9.0) as usize;
    move |v: &f64| {
        // A tick at zero computed as lo + k·step lands a rounding error away from it.
        if v.abs() <= span * 1e-9 {
            "0".to_owned()
        } else if scientific {
            format!("{v:.2e}")
        } else {
            format!("{v:.decimals$}")
        }
    }
}

fn with_unit(label: &str, unit: &str) -> String {
    if unit.is_empty() {
        label.to_owned()
    } else {
        format!("{label} ({unit})")
    }
}

fn shade<DB: DrawingBackend>(
    chart: &mut ChartContext<
        '_,
        DB,
        Cartesian2d<plotters::coord::types::RangedCoordf64, plotters::coord::types::RangedCoordf64>,
    >,
    report: &CompareReport,
    signal: &SignalReport,
    (y0, y1): (f64, f64),
    legend: bool,
) -> PlotResult<()>
where
    DB::ErrorType: 'static,
{
    for (k, mask) in signal.masks.iter().enumerate() {
        let color = INTERVAL_COLORS[k % INTERVAL_COLORS.len()];
        let spans = runs(&signal.aligned.times_s, mask);
        let series = chart.draw_series(
            spans
                .into_iter()
                .map(|(a, b)| Rectangle::new([(a, y0), (b, y1)], color.mix(0.25).filled())),
        )?;
        if legend {
            series
                .label(format!("interval {}", report.intervals[k]))
                .legend(move |(x, y)| {
                    Rectangle::new([(x, y - 6), (x + 20, y + 6)], color.mix(0.4).filled())
                });
        }
    }
    Ok(())
}

fn panel<DB: DrawingBackend>(
    area: &DrawingArea<DB, plotters::coord::Shift>,
    report: &CompareReport,
    signal: &SignalReport,
) -> PlotResult<()>
where
    DB::ErrorType: 'static,
{
    let al = &signal.aligned;
    let (t0, t1) = (
        al.times_s.first().copied().unwrap_or(0.0),
        al.times_s.last().copied().unwrap_or(1.0),
    );
    let t1 = if t1 > t0 { t1 } else { t0 + 1.0 };
    let (top, bottom) = area.split_vertically(PANEL_HEIGHT_PX * 60 / 100);
    let y = range(al.a.iter().chain(&al.b).copied());
    let stats = &signal.whole;
    let caption = format!(
        "{}   (whole overlap: RMSE {}, max |B-A| {}, bias {}{})",
        signal.signal,
        fmt(stats.rmse),
        fmt(stats.max_abs),
        fmt(stats.bias),
        if signal.unit.is_empty() {
            String::new()
        } else {
            format!(" {}", signal.unit)
        }
    );
    let mut chart = ChartBuilder::on(&top)
        .caption(caption, ("sans-serif", 20))
        .margin(8)
        .x_label_area_size(36)
        .y_label_area_size(95)
        .build_cartesian_2d(t0..t1, y.0..y.1)?;
    chart
        .configure_mesh()
        .x_desc("time (s)")
        .y_desc(with_unit("value", &signal.unit))
        .y_label_formatter(&tick_label(y.0, y.1))
        .axis_desc_style(("sans-serif", 16))
        .label_style(("sans-serif", 14))
        .draw()?;
    shade(&mut chart, report, signal, y, true)?;
    let pairs = |v: &[f64]| -> Vec<(f64, f64)> {
        al.times_s
            .iter()
            .zip(v)
            .filter(|(_, y)| y.is_finite())
            .map(|(&t, &y)| (t, y))
            .collect()
    };
    chart
        // A wide and pale under B: where the two agree, A shows as a halo around B.
        .draw_series(LineSeries::new(
            pairs(&al.a),
            A_COLOR.mix(0.6).stroke_width(6),
        ))?
        .label(format!("A: {}", file_name(&report.a)))
        .legend(|(x, y)| {
            PathElement::new(vec![(x, y), (x + 20, y)], A_COLOR.mix(0.6).stroke_width(6))
        });
    chart
        .draw_series(LineSeries::new(pairs(&al.b), B_COLOR.stroke_width(2)))?
        .label(format!(
            "B: {} (interpolated at A's times)",
            file_name(&report.b)
        ))
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], B_COLOR.stroke_width(2)));
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .label_font(("sans-serif", 14))
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()?;

    let diff: Vec<f64> = al.b.iter().zip(&al.a).map(|(b, a)| b - a).collect();
    let dy = range(diff.iter().copied().chain([0.0]));
    let mut chart = ChartBuilder::on(&bottom)
        .margin(8)
        .x_label_area_size(40)
        .y_label_area_size(95)
        .build_cartesian_2d(t0..t1, dy.0..dy.1)?;
    chart
        .configure_mesh()
        .x_desc("time (s)")
        .y_desc(with_unit("B - A", &signal.unit))
        .y_label_formatter(&tick_label(dy.0, dy.1))
        .axis_desc_style(("sans-serif", 16))
        .label_style(("sans-serif", 14))
        .draw()?;
    shade(&mut chart, report, signal, dy, false)?;
    chart.draw_series(LineSeries::new(
        [(t0, 0.0), (t1, 0.0)],
        BLACK.mix(0.5).stroke_width(1),
    ))?;
    chart
        .draw_series(LineSeries::new(pairs(&diff), DIFF_COLOR.stroke_width(2)))?
        .label("B - A")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], DIFF_COLOR.stroke_width(2)));
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .label_font(("sans-serif", 14))
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()?;
    Ok(())
}

fn fmt(x: Option<f64>) -> String {
    x.filter(|v| v.is_finite())
        .map_or_else(|| "N/A".to_owned(), crate::output::significant)
}

/// Draws `report` into the PNG `path` (the first [`MAX_PANELS`] signals).
pub fn draw(path: &Path, report: &CompareReport) -> PlotResult<()> {
    // Registering twice (a second plot in one process) keeps the first: harmless.
    let _ = plotters::style::register_font("sans-serif", FontStyle::Normal, FONT);
    let signals: Vec<&SignalReport> = report.signals.iter().take(MAX_PANELS).collect();
    let panels = u32::try_from(signals.len().max(1)).unwrap_or(1);
    let root = BitMapBackend::new(path, (WIDTH_PX, PANEL_HEIGHT_PX * panels)).into_drawing_area();
    root.fill(&WHITE)?;
    let areas = root.split_evenly((signals.len().max(1), 1));
    for (area, signal) in areas.iter().zip(signals) {
        panel(area, report, signal)?;
    }
    root.present()?;
    Ok(())
}
