//! PNG plots for examples, studies and `gpm replay` (feature `cli`): line charts with optional
//! log axes, particle scatter plots coloured by a value (one snapshot, a grid of snapshots on
//! one colour scale, or an animated GIF of them: [`ParticleGif`]). Text is drawn with the
//! embedded DejaVu Sans font (`assets/`, free licence), so no system font is needed.

use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use plotters::style::FontStyle;
use std::io::Write;
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
            // a tick a rounding error away from zero is 0, not -5.55e-17
            let zero = |lo: f64, hi: f64, log: bool| if log { 0.0 } else { 1e-9 * (hi - lo).abs() };
            let (zx, zy) = (zero(x0, x1, chart.log_x), zero(y0, y1, chart.log_y));
            ctx.configure_mesh()
                .x_label_formatter(&|v| tick(if v.abs() < zx { 0.0 } else { *v }))
                .y_label_formatter(&|v| tick(if v.abs() < zy { 0.0 } else { *v }))
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

/// Particles at one time: positions (the x–y plane) and one value each, with the panel's title
/// (`t = 0.25`, say).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Snapshot {
    /// Title of its panel or frame.
    pub title: String,
    /// Positions.
    pub x: Vec<[f64; 2]>,
    /// One value per position (a value that is not finite is drawn grey).
    pub value: Vec<f64>,
}

/// How particle snapshots are drawn: the box (drawn with equal scales on both axes), the colour
/// scale shared by every panel or frame, and its label.
#[derive(Clone, Debug, PartialEq)]
pub struct ParticleView {
    /// Lower corner of the box.
    pub lo: [f64; 2],
    /// Upper corner.
    pub hi: [f64; 2],
    /// Values mapped to the two ends of the colour map (clamped beyond).
    pub scale: (f64, f64),
    /// What the colour shows (`pressure p`).
    pub value_label: String,
    /// How the scale was chosen, written under the colour bar (`min–max over all frames`).
    pub scale_note: String,
    /// Particle spacing in the box's unit: a dot's diameter is about this.
    pub spacing: f64,
}

impl ParticleView {
    /// The box around every position of `snapshots` (padded by one spacing), the range of
    /// their finite values, and the spacing `√(area / n)` of the first snapshot's box.
    pub fn fit(snapshots: &[Snapshot], value_label: &str, scale_note: &str) -> Self {
        let mut b = Bounds::new();
        for s in snapshots {
            b.add(&s.x, &s.value);
        }
        let spacing = snapshots
            .first()
            .map_or(0.0, |s| Bounds::of(&s.x).spacing(s.x.len()));
        b.view(spacing, value_label, scale_note)
    }
}

impl ParticleView {
    /// Sets the colour scale to the `q` and `1 − q` quantiles of every value of `snapshots`
    /// (kept when there is none, or when they are equal).
    pub fn quantile_scale(&mut self, snapshots: &[Snapshot], q: f64) {
        let all: Vec<f64> = snapshots
            .iter()
            .flat_map(|s| s.value.iter().copied())
            .collect();
        if let Some((lo, hi)) = quantile_range(&all, q).filter(|(lo, hi)| lo < hi) {
            self.scale = (lo, hi);
        }
    }

    /// Widens the box to hold `lo..hi` (a tank the particles have not filled yet).
    pub fn include(&mut self, lo: [f64; 2], hi: [f64; 2]) {
        for k in 0..2 {
            self.lo[k] = self.lo[k].min(lo[k]);
            self.hi[k] = self.hi[k].max(hi[k]);
        }
    }
}

/// The `q` and `1 − q` quantiles of the finite `values` (the nearest ranks), `None` without
/// finite values: a colour scale that a few outliers do not stretch.
pub fn quantile_range(values: &[f64], q: f64) -> Option<(f64, f64)> {
    let mut v: Vec<f64> = values.iter().copied().filter(|v| v.is_finite()).collect();
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    let q = q.clamp(0.0, 0.5);
    let last = (v.len() - 1) as f64;
    Some((
        v[(q * last).floor() as usize],
        v[((1.0 - q) * last).ceil() as usize],
    ))
}

/// The box and value range of snapshots seen one at a time (so that a caller streaming them
/// keeps none): [`Bounds::add`] each, then [`Bounds::view`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Bounds {
    /// Lower corner of the positions seen.
    pub lo: [f64; 2],
    /// Upper corner.
    pub hi: [f64; 2],
    /// Smallest and largest finite value seen.
    pub values: (f64, f64),
}

impl Default for Bounds {
    fn default() -> Self {
        Self::new()
    }
}

impl Bounds {
    /// Nothing seen.
    pub fn new() -> Self {
        Bounds {
            lo: [f64::INFINITY; 2],
            hi: [f64::NEG_INFINITY; 2],
            values: (f64::INFINITY, f64::NEG_INFINITY),
        }
    }

    /// The box of `x` (values not looked at).
    pub fn of(x: &[[f64; 2]]) -> Self {
        let mut b = Self::new();
        b.add(x, &[]);
        b
    }

    /// Widens by the finite positions `x` and the finite `value`s.
    pub fn add(&mut self, x: &[[f64; 2]], value: &[f64]) {
        for p in x.iter().filter(|p| p[0].is_finite() && p[1].is_finite()) {
            for k in 0..2 {
                self.lo[k] = self.lo[k].min(p[k]);
                self.hi[k] = self.hi[k].max(p[k]);
            }
        }
        for v in value.iter().filter(|v| v.is_finite()) {
            self.values.0 = self.values.0.min(*v);
            self.values.1 = self.values.1.max(*v);
        }
    }

    /// Merges another.
    pub fn merge(&mut self, o: &Bounds) {
        self.add(&[o.lo, o.hi], &[o.values.0, o.values.1]);
    }

    /// `√(area / n)`: the spacing of `n` particles filling the box (0 without particles).
    pub fn spacing(&self, n: usize) -> f64 {
        let d = [self.hi[0] - self.lo[0], self.hi[1] - self.lo[1]];
        if n == 0 || !(d[0].is_finite() && d[1].is_finite()) {
            return 0.0;
        }
        // a line of particles has no area: its length over n
        let area = (d[0] * d[1]).max(d[0].max(d[1]).powi(2) / n as f64);
        (area / n as f64).sqrt()
    }

    /// The view of this box padded by one `spacing` (or by 1 when empty or flat), and of these
    /// values (widened by ±0.5 when all are equal, 0..1 when none was finite).
    pub fn view(&self, spacing: f64, value_label: &str, scale_note: &str) -> ParticleView {
        let (mut lo, mut hi) = (self.lo, self.hi);
        for k in 0..2 {
            if !(lo[k].is_finite() && hi[k].is_finite()) {
                (lo[k], hi[k]) = (0.0, 1.0);
            }
            let pad = if spacing > 0.0 { spacing } else { 1.0 };
            lo[k] -= pad;
            hi[k] += pad;
        }
        let (a, b) = self.values;
        let scale = if !(a.is_finite() && b.is_finite()) {
            (0.0, 1.0)
        } else if a == b {
            (a - 0.5, b + 0.5)
        } else {
            (a, b)
        };
        ParticleView {
            lo,
            hi,
            scale,
            value_label: value_label.into(),
            scale_note: scale_note.into(),
            spacing,
        }
    }
}

/// Margins of a particle panel (pixels): around it, below it (x labels), left of it (y labels).
const PANEL_MARGIN: u32 = 10;
const PANEL_X_LABELS: u32 = 30;
const PANEL_Y_LABELS: u32 = 48;
/// Height of a panel's title, and width of the colour bar column.
const PANEL_TITLE: u32 = 30;
const COLOUR_BAR: u32 = 140;

/// Width and height in pixels of one particle panel `width` pixels wide whose box keeps its
/// aspect ratio (the height clamped to `[120, 4 width]`).
fn panel_height(view: &ParticleView, width: u32) -> u32 {
    let inner = width
        .saturating_sub(2 * PANEL_MARGIN + PANEL_Y_LABELS)
        .max(1) as f64;
    let aspect = (view.hi[1] - view.lo[1]) / (view.hi[0] - view.lo[0]);
    let h = inner * if aspect.is_finite() { aspect } else { 1.0 };
    (h.round() as u32 + 2 * PANEL_MARGIN + PANEL_X_LABELS + PANEL_TITLE).clamp(120, 4 * width)
}

/// The size of a figure of `panels` snapshots in `columns` columns, each panel `panel_width`
/// pixels wide, plus the colour bar (and a `title` line when not empty).
pub fn particle_figure_size(
    view: &ParticleView,
    panels: usize,
    columns: usize,
    panel_width: u32,
    title: &str,
) -> (u32, u32) {
    let columns = columns.clamp(1, panels.max(1));
    let rows = panels.max(1).div_ceil(columns);
    let top = if title.is_empty() { 0 } else { PANEL_TITLE };
    (
        columns as u32 * panel_width + COLOUR_BAR,
        rows as u32 * panel_height(view, panel_width) + top,
    )
}

/// `lo..hi` widened in one direction so that a unit is as long on both axes in a plot of
/// `w × h` pixels.
fn equal_aspect(lo: [f64; 2], hi: [f64; 2], w: u32, h: u32) -> ([f64; 2], [f64; 2]) {
    let (dx, dy) = (hi[0] - lo[0], hi[1] - lo[1]);
    let (w, h) = (w.max(1) as f64, h.max(1) as f64);
    let mut hi = hi;
    if dx / dy > w / h {
        hi[1] = lo[1] + dx * h / w;
    } else {
        hi[0] = lo[0] + dy * w / h;
    }
    (lo, hi)
}

/// One panel: the particles of `s` in `view`'s box at equal scales, coloured on its scale.
fn draw_panel<DB: DrawingBackend>(
    area: &DrawingArea<DB, plotters::coord::Shift>,
    s: &Snapshot,
    view: &ParticleView,
) -> Result<(), String>
where
    DB::ErrorType: 'static,
{
    let e = |e: &dyn std::fmt::Display| e.to_string();
    let area = area
        .titled(&s.title, ("sans-serif", 18))
        .map_err(|x| e(&x))?;
    let (w, h) = area.dim_in_pixel();
    let pw = w.saturating_sub(2 * PANEL_MARGIN + PANEL_Y_LABELS);
    let ph = h.saturating_sub(2 * PANEL_MARGIN + PANEL_X_LABELS);
    let (lo, hi) = equal_aspect(view.lo, view.hi, pw, ph);
    let mut ctx = ChartBuilder::on(&area)
        .margin(PANEL_MARGIN)
        .x_label_area_size(PANEL_X_LABELS)
        .y_label_area_size(PANEL_Y_LABELS)
        .build_cartesian_2d(lo[0]..hi[0], lo[1]..hi[1])
        .map_err(|x| e(&x))?;
    ctx.configure_mesh()
        .disable_mesh()
        .x_label_formatter(&|v| tick(*v))
        .y_label_formatter(&|v| tick(*v))
        .label_style(("sans-serif", 13))
        .draw()
        .map_err(|x| e(&x))?;
    // a dot is about one spacing across: a circle when that is 8 pixels or more, a square
    // (which tiles without gaps) below
    let across = view.spacing * pw as f64 / (hi[0] - lo[0]);
    let (vmin, vmax) = view.scale;
    let grey = RGBColor(160, 160, 160);
    let colour = |v: f64| {
        if v.is_finite() {
            colormap((v - vmin) / (vmax - vmin))
        } else {
            grey
        }
    };
    let dots = s.x.iter().zip(&s.value);
    if across >= 8.0 {
        let r = (0.55 * across).round().min(10.0) as i32;
        ctx.draw_series(dots.map(|(p, v)| Circle::new((p[0], p[1]), r, colour(*v).filled())))
            .map_err(|x| e(&x))?;
    } else {
        // a little more than one spacing: the water stretches between particles
        let side = (1.2 * across).ceil().max(2.0) as i32;
        let (a, b) = (-side / 2, side - side / 2);
        ctx.draw_series(dots.map(|(p, v)| {
            EmptyElement::at((p[0], p[1])) + Rectangle::new([(a, a), (b, b)], colour(*v).filled())
        }))
        .map_err(|x| e(&x))?;
    }
    Ok(())
}

/// The colour bar of `view`'s scale with its label and note.
fn draw_colour_bar<DB: DrawingBackend>(
    area: &DrawingArea<DB, plotters::coord::Shift>,
    view: &ParticleView,
) -> Result<(), String>
where
    DB::ErrorType: 'static,
{
    let e = |e: &dyn std::fmt::Display| e.to_string();
    let (vmin, vmax) = view.scale;
    let (w, h) = area.dim_in_pixel();
    let text = |t: &str, y: i32, size: u32| {
        area.draw_text(
            t,
            &TextStyle::from(("sans-serif", size).into_font())
                .pos(Pos::new(HPos::Center, VPos::Top)),
            (w as i32 / 2, y),
        )
        .map_err(|x| e(&x))
    };
    text(&view.value_label, 8, 15)?;
    let lines = view.scale_note.lines().count() as i32;
    for (k, line) in view.scale_note.lines().enumerate() {
        text(line, h as i32 - 6 - 14 * (lines - k as i32), 12)?;
    }
    let bar = area.margin(36, 16 + 14 * lines, 8, 35);
    let mut cb = ChartBuilder::on(&bar)
        .y_label_area_size(62)
        .build_cartesian_2d(0.0..1.0, vmin..vmax)
        .map_err(|x| e(&x))?;
    // a tick a rounding error away from zero is 0, not -2.78e-17
    let zero = 1e-9 * (vmax - vmin);
    cb.configure_mesh()
        .disable_mesh()
        .disable_x_axis()
        .y_label_formatter(&|v| tick(if v.abs() < zero { 0.0 } else { *v }))
        .label_style(("sans-serif", 12))
        .draw()
        .map_err(|x| e(&x))?;
    let steps = 100;
    cb.draw_series((0..steps).map(|k| {
        let a = vmin + (vmax - vmin) * k as f64 / steps as f64;
        let b = vmin + (vmax - vmin) * (k + 1) as f64 / steps as f64;
        Rectangle::new(
            [(0.0, a), (1.0, b)],
            colormap((k as f64 + 0.5) / steps as f64).filled(),
        )
    }))
    .map_err(|x| e(&x))?;
    Ok(())
}

/// A figure on `root`: an optional title line, the snapshots in a grid of `columns`, the colour
/// bar on the right.
fn draw_figure<DB: DrawingBackend>(
    root: &DrawingArea<DB, plotters::coord::Shift>,
    title: &str,
    snapshots: &[Snapshot],
    columns: usize,
    view: &ParticleView,
) -> Result<(), String>
where
    DB::ErrorType: 'static,
{
    let e = |e: &dyn std::fmt::Display| e.to_string();
    root.fill(&WHITE).map_err(|x| e(&x))?;
    let (w, _) = root.dim_in_pixel();
    let (panels, bar) = root.split_horizontally(w.saturating_sub(COLOUR_BAR));
    let panels = if title.is_empty() {
        panels
    } else {
        panels
            .titled(title, ("sans-serif", 20))
            .map_err(|x| e(&x))?
    };
    let columns = columns.clamp(1, snapshots.len().max(1));
    let rows = snapshots.len().max(1).div_ceil(columns);
    for (s, area) in snapshots.iter().zip(panels.split_evenly((rows, columns))) {
        draw_panel(&area, s, view)?;
    }
    draw_colour_bar(&bar, view)
}

/// Snapshots side by side in a PNG, `columns` per row, every panel `panel_width` pixels wide
/// with the box at equal scales, one colour bar for all (so that the panels compare).
pub fn particle_panels(
    path: &Path,
    title: &str,
    snapshots: &[Snapshot],
    columns: usize,
    panel_width: u32,
    view: &ParticleView,
) -> Result<(), PlotError> {
    ensure_font();
    let size = particle_figure_size(view, snapshots.len(), columns, panel_width, title);
    let root = BitMapBackend::new(path, size).into_drawing_area();
    draw_figure(&root, title, snapshots, columns, view).map_err(|e| err(path, e))?;
    root.present().map_err(|e| err(path, e))?;
    Ok(())
}

/// Particles as dots coloured by `value` (range `[vmin, vmax]` of the values, padded by 5 %), in
/// the box `lo..hi`.
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
    let view = ParticleView {
        lo,
        hi,
        scale: range(value.iter().copied(), false),
        value_label: value_label.into(),
        scale_note: String::new(),
        spacing: Bounds::of(x).spacing(x.len()),
    };
    let s = Snapshot {
        title: title.into(),
        x: x.to_vec(),
        value: value.to_vec(),
    };
    particle_panels(path, "", &[s], 1, size_px, &view)
}

/// Colours of the GIF palette taken from [`colormap`]; the other entries are greys (white,
/// black and the anti-aliased text between).
const PALETTE_MAP: usize = 200;

/// The fixed palette of [`ParticleGif`]: [`PALETTE_MAP`] colours of [`colormap`] evenly over
/// `[0, 1]`, then greys from black to white (256 RGB triples).
fn gif_palette() -> Vec<[u8; 3]> {
    let greys = 256 - PALETTE_MAP;
    let map = (0..PALETTE_MAP).map(|k| {
        let c = colormap(k as f64 / (PALETTE_MAP - 1) as f64);
        [c.0, c.1, c.2]
    });
    let grey = (0..greys).map(|k| [(255 * k / (greys - 1)) as u8; 3]);
    map.chain(grey).collect()
}

/// Index of the palette entry nearest to `rgb` (squared RGB distance).
fn nearest(palette: &[[u8; 3]], rgb: [u8; 3]) -> u8 {
    let d = |p: &[u8; 3]| -> i32 { (0..3).map(|k| (p[k] as i32 - rgb[k] as i32).pow(2)).sum() };
    let best = (0..palette.len()).min_by_key(|&k| d(&palette[k]));
    best.unwrap_or(0) as u8
}

/// An animated GIF of particle snapshots, one frame each ([`ParticleGif::frame`]), all on one
/// view, looping forever. Frames are drawn by plotters into an RGB buffer and encoded by the
/// `gif` crate with one fixed global palette (200 colours of the colour map and 56 greys, each
/// pixel mapped to the nearest): the colours mean the same in every frame, the colour bar keeps
/// its whole gradient, and the encoding is deterministic.
pub struct ParticleGif<W: Write> {
    encoder: gif::Encoder<W>,
    view: ParticleView,
    size: (u32, u32),
    delay: u16,
    rgb: Vec<u8>,
    palette: Vec<[u8; 3]>,
    /// Palette index of every RGB colour met so far (a frame has few distinct colours).
    index: std::collections::HashMap<[u8; 3], u8>,
    name: String,
    frames: usize,
}

impl<W: Write> ParticleGif<W> {
    /// Starts a GIF on `out` (`name`: the file, for errors) of `width` pixels wide frames, as
    /// high as `height` or (`None`) as the box's aspect ratio asks, at `fps` frames per second
    /// (GIF delays are hundredths of a second: 1 to 50 frames per second).
    pub fn new(
        out: W,
        name: &Path,
        view: ParticleView,
        width: u32,
        height: Option<u32>,
        fps: f64,
    ) -> Result<Self, PlotError> {
        ensure_font();
        let fail = |m: String| err(name, m);
        if !(fps.is_finite() && (1.0..=50.0).contains(&fps)) {
            return Err(fail(format!("{fps} frames per second: must be in 1..=50")));
        }
        let size = match height {
            Some(h) => (width, h),
            None => particle_figure_size(&view, 1, 1, width.saturating_sub(COLOUR_BAR), ""),
        };
        if !(COLOUR_BAR + 100..=4096).contains(&size.0) || !(100..=4096).contains(&size.1) {
            return Err(fail(format!(
                "frames of {} × {} pixels: the width must be in {}..=4096 and the height in \
                 100..=4096",
                size.0,
                size.1,
                COLOUR_BAR + 100
            )));
        }
        let palette = gif_palette();
        let flat: Vec<u8> = palette.iter().flatten().copied().collect();
        let mut encoder = gif::Encoder::new(out, size.0 as u16, size.1 as u16, &flat)
            .map_err(|e| fail(e.to_string()))?;
        encoder
            .set_repeat(gif::Repeat::Infinite)
            .map_err(|e| fail(e.to_string()))?;
        Ok(ParticleGif {
            encoder,
            view,
            size,
            delay: (100.0 / fps).round() as u16,
            rgb: vec![255; 3 * size.0 as usize * size.1 as usize],
            palette,
            index: Default::default(),
            name: name.display().to_string(),
            frames: 0,
        })
    }

    /// Frame width and height in pixels.
    pub fn size(&self) -> (u32, u32) {
        self.size
    }

    /// Frames written so far.
    pub fn frames(&self) -> usize {
        self.frames
    }

    /// Draws `s` (its title is the frame's) and appends it as a frame.
    pub fn frame(&mut self, s: &Snapshot) -> Result<(), PlotError> {
        let fail = |m: String| PlotError {
            path: self.name.clone(),
            message: m,
        };
        {
            let root = BitMapBackend::with_buffer(&mut self.rgb, self.size).into_drawing_area();
            draw_figure(&root, "", std::slice::from_ref(s), 1, &self.view).map_err(fail)?;
            root.present().map_err(|e| fail(e.to_string()))?;
        }
        let (palette, index) = (&self.palette, &mut self.index);
        let pixels: Vec<u8> = self
            .rgb
            .chunks_exact(3)
            .map(|c| {
                let rgb = [c[0], c[1], c[2]];
                *index.entry(rgb).or_insert_with(|| nearest(palette, rgb))
            })
            .collect();
        let (w, h) = (self.size.0 as u16, self.size.1 as u16);
        let mut frame = gif::Frame::from_indexed_pixels(w, h, pixels, None);
        frame.delay = self.delay;
        self.encoder
            .write_frame(&frame)
            .map_err(|e| fail(e.to_string()))?;
        self.frames += 1;
        Ok(())
    }

    /// Ends the GIF and hands back the writer.
    pub fn finish(self) -> Result<W, PlotError> {
        let name = self.name;
        self.encoder.into_inner().map_err(|e| PlotError {
            path: name,
            message: e.to_string(),
        })
    }
}
