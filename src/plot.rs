//! PNG plots for examples, studies and `gpm replay` (feature `cli`): line charts with optional
//! log axes, and particle scatter plots coloured by a value. Text is drawn with the embedded
//! DejaVu Sans font (`assets/`, free licence), so no system font is needed.

use plotters::prelude::*;
use plotters::style::FontStyle;
use std::path::Path;
use std::sync::Once;

/// Plot failures (drawing or encoding).
#[derive(Debug, thiserror::Error)]
#[error("plot {path}: {message}")]
pub struct PlotError {
    /// Output file.
    pub path: String,
    /// What went wrong.
    pub message: String,
}

fn err(path: &Path, e: impl std::fmt::Display) -> PlotError {
    PlotError {
        path: path.display().to_string(),
        message: e.to_string(),
    }
}

static FONT: Once = Once::new();

fn ensure_font() {
    FONT.call_once(|| {
        let bytes: &'static [u8] = include_bytes!("../assets/DejaVuSans.ttf");
        // registration only fails for an invalid font file, which the tests would catch
        let _ = plotters::style::register_font("sans-serif", FontStyle::Normal, bytes);
    });
}

/// How a series is drawn.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mark {
    /// A polyline.
    Line,
    /// Circles at the points.
    Points,
    /// Both.
    LinePoints,
}

/// One named series of a line chart.
#[derive(Clone, Debug)]
pub struct Series {
    /// Legend label.
    pub name: String,
    /// `(x, y)` points.
    pub points: Vec<(f64, f64)>,
    /// Drawing style.
    pub mark: Mark,
}

impl Series {
    /// A series drawn as a line.
    pub fn line(name: impl Into<String>, points: Vec<(f64, f64)>) -> Self {
        Series {
            name: name.into(),
            points,
            mark: Mark::Line,
        }
    }
    /// A series drawn as points.
    pub fn points(name: impl Into<String>, points: Vec<(f64, f64)>) -> Self {
        Series {
            name: name.into(),
            points,
            mark: Mark::Points,
        }
    }
    /// A series drawn as a line with points.
    pub fn line_points(name: impl Into<String>, points: Vec<(f64, f64)>) -> Self {
        Series {
            name: name.into(),
            points,
            mark: Mark::LinePoints,
        }
    }
}

/// A chart: title, axis labels, log axes.
#[derive(Clone, Debug, Default)]
pub struct Chart {
    /// Title.
    pub title: String,
    /// x-axis label.
    pub x_label: String,
    /// y-axis label.
    pub y_label: String,
    /// Logarithmic x axis.
    pub log_x: bool,
    /// Logarithmic y axis.
    pub log_y: bool,
}

const PALETTE: [RGBColor; 8] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(255, 127, 14),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(23, 190, 207),
];

fn range(vals: impl Iterator<Item = f64>, log: bool) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in vals {
        if v.is_finite() && (!log || v > 0.0) {
            lo = lo.min(v);
            hi = hi.max(v);
        }
    }
    if !lo.is_finite() {
        return if log { (0.1, 1.0) } else { (0.0, 1.0) };
    }
    if log {
        (lo / 1.3, hi * 1.3)
    } else {
        let pad = if hi > lo { 0.05 * (hi - lo) } else { 0.5 };
        (lo - pad, hi + pad)
    }
}

/// Draws several charts side by side (one row) into one PNG of `width × height` pixels.
pub fn line_charts(
    path: &Path,
    width: u32,
    height: u32,
    charts: &[(Chart, Vec<Series>)],
) -> Result<(), PlotError> {
    ensure_font();
    let root = BitMapBackend::new(path, (width, height)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(path, e))?;
    let areas = root.split_evenly((1, charts.len().max(1)));
    for ((chart, series), area) in charts.iter().zip(areas.iter()) {
        draw_chart(path, area, chart, series)?;
    }
    root.present().map_err(|e| err(path, e))?;
    Ok(())
}

/// One chart into one PNG.
pub fn line_chart(path: &Path, chart: &Chart, series: &[Series]) -> Result<(), PlotError> {
    line_charts(path, 900, 650, &[(chart.clone(), series.to_vec())])
}

/// A compact tick label: `0.25`, `1200`, `1e-7` (log-axis ticks come out of plotters as
/// `1.000000000000001e-7` otherwise).
fn tick(v: f64) -> String {
    let a = v.abs();
    if v == 0.0 {
        "0".into()
    } else if (1e-3..1e5).contains(&a) {
        let s = format!("{v:.4}");
        let s = s.trim_end_matches('0').trim_end_matches('.');
        s.to_string()
    } else {
        let s = format!("{v:.2e}");
        // 1.00e-7 → 1e-7, 2.50e3 → 2.5e3
        match s.split_once('e') {
            Some((m, e)) => {
                let m = m.trim_end_matches('0').trim_end_matches('.');
                format!("{m}e{e}")
            }
            None => s,
        }
    }
}

fn draw_chart<DB: DrawingBackend>(
    path: &Path,
    area: &DrawingArea<DB, plotters::coord::Shift>,
    chart: &Chart,
    series: &[Series],
) -> Result<(), PlotError>
where
    DB::ErrorType: 'static,
{
    let (x0, x1) = range(
        series.iter().flat_map(|s| s.points.iter().map(|p| p.0)),
        chart.log_x,
    );
    let (y0, y1) = range(
        series.iter().flat_map(|s| s.points.iter().map(|p| p.1)),
        chart.log_y,
    );
    let mut builder = ChartBuilder::on(area);
    builder
        .caption(&chart.title, ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(45)
        .y_label_area_size(70);
    macro_rules! body {
        ($ctx:expr) => {{
            let mut ctx = $ctx;
            ctx.configure_mesh()
                .x_label_formatter(&|v| tick(*v))
                .y_label_formatter(&|v| tick(*v))
                .x_desc(chart.x_label.as_str())
                .y_desc(chart.y_label.as_str())
                .label_style(("sans-serif", 14))
                .draw()
                .map_err(|e| err(path, e))?;
            for (k, s) in series.iter().enumerate() {
                let color = PALETTE[k % PALETTE.len()];
                let pts: Vec<(f64, f64)> = s
                    .points
                    .iter()
                    .copied()
                    .filter(|p| {
                        p.0.is_finite()
                            && p.1.is_finite()
                            && (!chart.log_x || p.0 > 0.0)
                            && (!chart.log_y || p.1 > 0.0)
                    })
                    .collect();
                let style = ShapeStyle::from(&color).stroke_width(2);
                if matches!(s.mark, Mark::Line | Mark::LinePoints) {
                    ctx.draw_series(LineSeries::new(pts.clone(), style))
                        .map_err(|e| err(path, e))?
                        .label(s.name.as_str())
                        .legend(move |(x, y)| {
                            PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(2))
                        });
                }
                if matches!(s.mark, Mark::Points | Mark::LinePoints) {
                    let a = ctx
                        .draw_series(pts.iter().map(|&p| Circle::new(p, 4, color.filled())))
                        .map_err(|e| err(path, e))?;
                    if s.mark == Mark::Points {
                        a.label(s.name.as_str())
                            .legend(move |(x, y)| Circle::new((x + 10, y), 4, color.filled()));
                    }
                }
            }
            ctx.configure_series_labels()
                .background_style(WHITE.mix(0.85))
                .border_style(BLACK)
                .label_font(("sans-serif", 14))
                .draw()
                .map_err(|e| err(path, e))?;
        }};
    }
    match (chart.log_x, chart.log_y) {
        (false, false) => body!(builder
            .build_cartesian_2d(x0..x1, y0..y1)
            .map_err(|e| err(path, e))?),
        (true, false) => body!(builder
            .build_cartesian_2d((x0..x1).log_scale(), y0..y1)
            .map_err(|e| err(path, e))?),
        (false, true) => body!(builder
            .build_cartesian_2d(x0..x1, (y0..y1).log_scale())
            .map_err(|e| err(path, e))?),
        (true, true) => body!(builder
            .build_cartesian_2d((x0..x1).log_scale(), (y0..y1).log_scale())
            .map_err(|e| err(path, e))?),
    }
    Ok(())
}

/// A "viridis-like" colour map on `[0, 1]`.
pub fn colormap(t: f64) -> RGBColor {
    let t = if t.is_finite() {
        t.clamp(0.0, 1.0)
    } else {
        0.0
    };
    const STOPS: [(f64, f64, f64); 5] = [
        (68.0, 1.0, 84.0),
        (59.0, 82.0, 139.0),
        (33.0, 145.0, 140.0),
        (94.0, 201.0, 98.0),
        (253.0, 231.0, 37.0),
    ];
    let x = t * 4.0;
    let k = (x.floor() as usize).min(3);
    let f = x - k as f64;
    let (a, b) = (STOPS[k], STOPS[k + 1]);
    RGBColor(
        (a.0 + f * (b.0 - a.0)) as u8,
        (a.1 + f * (b.1 - a.1)) as u8,
        (a.2 + f * (b.2 - a.2)) as u8,
    )
}

/// Particles as dots coloured by `value` (range `[vmin, vmax]`), in the box `lo..hi`.
#[allow(clippy::too_many_arguments)]
pub fn particles(
    path: &Path,
    title: &str,
    x: &[[f64; 2]],
    value: &[f64],
    lo: [f64; 2],
    hi: [f64; 2],
    value_label: &str,
    size_px: u32,
) -> Result<(), PlotError> {
    ensure_font();
    let (vmin, vmax) = range(value.iter().copied(), false);
    let root = BitMapBackend::new(path, (size_px + 120, size_px)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(path, e))?;
    let (main, bar) = root.split_horizontally(size_px);
    let mut ctx = ChartBuilder::on(&main)
        .caption(title, ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(35)
        .y_label_area_size(45)
        .build_cartesian_2d(lo[0]..hi[0], lo[1]..hi[1])
        .map_err(|e| err(path, e))?;
    ctx.configure_mesh()
        .disable_mesh()
        .label_style(("sans-serif", 14))
        .draw()
        .map_err(|e| err(path, e))?;
    let r = ((size_px as f64 / (x.len() as f64).sqrt()) * 0.35).clamp(1.0, 6.0) as i32;
    ctx.draw_series(x.iter().zip(value).map(|(p, v)| {
        let t = (v - vmin) / (vmax - vmin).max(1e-300);
        Circle::new((p[0], p[1]), r, colormap(t).filled())
    }))
    .map_err(|e| err(path, e))?;
    // colour bar
    let mut cb = ChartBuilder::on(&bar)
        .margin_top(40)
        .margin_bottom(40)
        .margin_right(10)
        .y_label_area_size(60)
        .caption(value_label, ("sans-serif", 14))
        .build_cartesian_2d(0.0..1.0, vmin..vmax)
        .map_err(|e| err(path, e))?;
    cb.configure_mesh()
        .disable_mesh()
        .disable_x_axis()
        .label_style(("sans-serif", 12))
        .draw()
        .map_err(|e| err(path, e))?;
    let steps = 100;
    cb.draw_series((0..steps).map(|k| {
        let a = vmin + (vmax - vmin) * k as f64 / steps as f64;
        let b = vmin + (vmax - vmin) * (k + 1) as f64 / steps as f64;
        Rectangle::new(
            [(0.0, a), (1.0, b)],
            colormap(k as f64 / steps as f64).filled(),
        )
    }))
    .map_err(|e| err(path, e))?;
    root.present().map_err(|e| err(path, e))?;
    Ok(())
}
