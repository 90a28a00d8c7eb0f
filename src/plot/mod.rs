//! Plots for people: a consumer of results, never of intermediate state.
//!
//! Rendering goes through plotters with an embedded DejaVu Sans font (its
//! `ab_glyph` feature), so the binary needs no fontconfig and no system font.
//! PNG is encoded by the `png` crate from plotters' RGB buffer; SVG is built
//! in memory. Files are written atomically: nothing half-written on error.
//!
//! Curves go through [`Chart`] and [`save_chart`] (the legend placed off
//! the data); pictures through [`Raster`], bare ([`Raster::save`],
//! [`save_grey`]) or inside axes with an optional colour bar
//! ([`save_raster_chart`]).

use std::path::Path;
use std::sync::Once;

use ndarray::ArrayView2;
use plotters::coord::Shift;
use plotters::coord::types::RangedCoordf64;
use plotters::element::MultiLineText;
use plotters::prelude::*;
use plotters::style::FontStyle;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use crate::error::{Error, Result};
use crate::io::write_atomic;

mod raster;
pub use raster::{
    BACKGROUND_GREY, ColorBar, NO_VALUE, Raster, RasterChart, background_grey, save_grey,
    save_raster_chart,
};

static FONT: &[u8] = include_bytes!("../../assets/DejaVuSans.ttf");
static REGISTER: Once = Once::new();

fn register_font() {
    REGISTER.call_once(|| {
        // the font is compiled in: failure here is a build defect
        plotters::style::register_font("sans-serif", FontStyle::Normal, FONT)
            .map_err(|_| ())
            .expect("embedded DejaVu Sans is a valid font");
    });
}

/// How a series is drawn.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Style {
    /// A solid line through the points.
    Line,
    /// A dashed line (theory curves, reference lines).
    Dashed,
    /// Dots only.
    Markers,
    /// A solid line with a dot at each point.
    LineMarkers,
    /// Open circles only: estimates the analysis flags (drawn beside the
    /// filled ones so that a figure shows what its warnings say).
    OpenMarkers,
}

/// One curve.
#[derive(Clone, Debug)]
pub struct Series {
    /// Legend label; an empty name keeps the series out of the legend.
    pub name: String,
    /// The `(x, y)` points in data coordinates; a non-finite one is not
    /// drawn and breaks the line there (an empty bin, an undefined log).
    pub points: Vec<(f64, f64)>,
    /// Optional symmetric error bar per point (same length as `points`).
    pub y_err: Option<Vec<f64>>,
    /// Optional symmetric horizontal error bar per point (same length as
    /// `points`), for estimates whose abscissa is itself estimated (the
    /// canonical h(q) of a D(h) plot).
    pub x_err: Option<Vec<f64>>,
    /// How the series is drawn.
    pub style: Style,
    /// Index into the palette.
    pub color: usize,
}

impl Series {
    /// A series without error bars.
    pub fn new(
        name: impl Into<String>,
        points: Vec<(f64, f64)>,
        style: Style,
        color: usize,
    ) -> Self {
        Series {
            name: name.into(),
            points,
            y_err: None,
            x_err: None,
            style,
            color,
        }
    }

    /// The same series with the symmetric error bars `err` (one per point).
    pub fn with_errors(mut self, err: Vec<f64>) -> Self {
        self.y_err = Some(err);
        self
    }

    /// The same series with horizontal error bars `err` (one per point).
    pub fn with_x_errors(mut self, err: Vec<f64>) -> Self {
        self.x_err = Some(err);
        self
    }

    /// The finite error bars of the series as segments in data
    /// coordinates: vertical ones from `y_err`, horizontal from `x_err`.
    fn error_bars(&self) -> Vec<((f64, f64), (f64, f64))> {
        let mut out = Vec::new();
        for (i, &(x, y)) in self.points.iter().enumerate() {
            if !(x.is_finite() && y.is_finite()) {
                continue;
            }
            if let Some(d) = self.y_err.as_ref().map(|e| e[i]).filter(|d| d.is_finite()) {
                out.push(((x, y - d), (x, y + d)));
            }
            if let Some(d) = self.x_err.as_ref().map(|e| e[i]).filter(|d| d.is_finite()) {
                out.push(((x - d, y), (x + d, y)));
            }
        }
        out
    }

    /// The points with both coordinates finite (the ones drawn).
    fn finite_points(&self) -> Vec<(f64, f64)> {
        self.points
            .iter()
            .cloned()
            .filter(|p| p.0.is_finite() && p.1.is_finite())
            .collect()
    }

    /// Whether the legend lists the series: it has a name, and something
    /// to draw, or nothing at all (a key: a series without points that
    /// only says what other, unnamed ones are). A series whose every point
    /// is undefined is drawn nowhere, and its entry would point at nothing.
    fn listed(&self) -> bool {
        !self.name.is_empty()
            && (self.points.is_empty()
                || self
                    .points
                    .iter()
                    .any(|p| p.0.is_finite() && p.1.is_finite()))
    }

    /// The line's pieces: runs of consecutive finite points (a non-finite
    /// point ends a run, so no line bridges a gap in the data).
    fn runs(&self) -> Vec<&[(f64, f64)]> {
        self.points
            .split(|p| !(p.0.is_finite() && p.1.is_finite()))
            .filter(|r| !r.is_empty())
            .collect()
    }
}

/// The legend names of one set of estimates drawn in two parts, filled
/// and open (flagged, or noise): `(filled, open)` as given while some
/// filled point is drawn; else the open part takes both ("estimate ± 1 se,
/// all flagged ..."), since the legend lists only series with something
/// drawn ([`Series`] with every point undefined are left out).
pub fn part_names(filled: String, open: String, filled_points: &[(f64, f64)]) -> (String, String) {
    if filled_points
        .iter()
        .any(|p| p.0.is_finite() && p.1.is_finite())
    {
        (filled, open)
    } else if open.is_empty() {
        (String::new(), filled)
    } else {
        (String::new(), format!("{filled}, all {open}"))
    }
}

/// A 2D chart: title, axis labels, series.
#[derive(Clone, Debug, Default)]
pub struct Chart {
    /// Title above the plot (none if empty).
    pub title: String,
    /// Label of the x axis.
    pub x_label: String,
    /// Label of the y axis.
    pub y_label: String,
    /// The curves, drawn in order.
    pub series: Vec<Series>,
    /// Fixed ranges; computed from the data when `None`.
    pub x_range: Option<(f64, f64)>,
    /// Fixed y range; computed from the data when `None`.
    pub y_range: Option<(f64, f64)>,
    /// Where the legend goes; `None` (the default) places it automatically
    /// in the inner corner that covers the least data, adding headroom to
    /// an automatic y range or moving it right of the plot if every corner
    /// would cover data (see [`save_chart`]).
    pub legend: Option<LegendPos>,
}

impl Chart {
    /// The same chart with the legend at `pos` instead of placed automatically.
    pub fn with_legend(mut self, pos: LegendPos) -> Self {
        self.legend = Some(pos);
        self
    }
}

/// Legend positions: an inner corner of the plotting area, or a column
/// right of it (the plotting area shrinks to make room).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LegendPos {
    /// Inside, upper-left corner.
    UpperLeft,
    /// Inside, upper-right corner.
    UpperRight,
    /// Inside, lower-left corner.
    LowerLeft,
    /// Inside, lower-right corner.
    LowerRight,
    /// In a column right of the plotting area.
    OutsideRight,
}

/// A colour from a palette readable on white (tab10-like, then a ramp).
pub fn palette(i: usize) -> RGBColor {
    const P: [(u8, u8, u8); 10] = [
        (31, 119, 180),
        (214, 39, 40),
        (44, 160, 44),
        (255, 127, 14),
        (148, 103, 189),
        (140, 86, 75),
        (227, 119, 194),
        (23, 190, 207),
        (188, 189, 34),
        (80, 80, 80),
    ];
    let (r, g, b) = P[i % P.len()];
    RGBColor(r, g, b)
}

/// A blue-to-red ramp for `t` in [0, 1] (for families of curves, e.g. one per q).
pub fn ramp(t: f64) -> RGBColor {
    let t = t.clamp(0.0, 1.0);
    RGBColor(
        (30.0 + 200.0 * t) as u8,
        (60.0 + 60.0 * (1.0 - (2.0 * t - 1.0).abs())) as u8,
        (220.0 - 190.0 * t) as u8,
    )
}

/// Viridis (matplotlib's default, perceptually uniform and readable in
/// grey and by colour-blind readers) for `t` in [0, 1]: for magnitudes such
/// as a log density, where a diverging map's neutral middle would read as
/// "nothing".
pub fn viridis(t: f64) -> RGBColor {
    use plotters::style::colors::colormaps::{ColorMap, ViridisRGB};
    ViridisRGB.get_color(t.clamp(0.0, 1.0) as f32)
}

fn data_range(chart: &Chart) -> ((f64, f64), (f64, f64)) {
    let mut xs = (f64::INFINITY, f64::NEG_INFINITY);
    let mut ys = (f64::INFINITY, f64::NEG_INFINITY);
    for s in &chart.series {
        for (i, &(x, y)) in s.points.iter().enumerate() {
            if !(x.is_finite() && y.is_finite()) {
                continue;
            }
            let bar = |err: &Option<Vec<f64>>| {
                let e = err.as_ref().map_or(0.0, |e| e[i].abs());
                if e.is_finite() { e } else { 0.0 }
            };
            let (ex, ey) = (bar(&s.x_err), bar(&s.y_err));
            xs = (xs.0.min(x - ex), xs.1.max(x + ex));
            ys = (ys.0.min(y - ey), ys.1.max(y + ey));
        }
    }
    let pad = |r: (f64, f64)| {
        if !r.0.is_finite() {
            return (0.0, 1.0);
        }
        let d = (r.1 - r.0).abs();
        // a single value (one point, a flat line): a span around it, not
        // an axis of one repeated tick label
        let mag = r.0.abs().max(r.1.abs());
        if d <= 1e-9 * mag {
            let c = 0.5 * (r.0 + r.1);
            let half = if mag > 0.0 { 0.1 * mag } else { 0.1 };
            return (c - half, c + half);
        }
        (r.0 - 0.05 * d, r.1 + 0.05 * d)
    };
    (
        chart.x_range.unwrap_or_else(|| pad(xs)),
        chart.y_range.unwrap_or_else(|| pad(ys)),
    )
}

type Ctx<'a, DB> = ChartContext<'a, DB, Cartesian2d<RangedCoordf64, RangedCoordf64>>;

/// Outer margin of a picture, and the sizes of the axis-label areas.
const MARGIN: u32 = 14;
const X_LABEL_AREA: u32 = 44;
const Y_LABEL_AREA: u32 = 64;
/// Legend geometry (plotters' layout): font size, the column of series
/// samples left of the text, the inner margin, and the inset of a corner
/// legend from the edges of the plotting area.
const LEGEND_FONT: u32 = 14;
const LEGEND_GLYPH: i32 = 30;
const LEGEND_MARGIN: i32 = 10;
const LEGEND_INSET: i32 = 5;
/// Ink this close to the legend box counts as covered (marker radius, line width).
const LEGEND_PAD: i32 = 3;
/// The gap either side of a legend right of the plotting area.
const LEGEND_GAP: i32 = 12;
/// The most an automatic y range may grow (relative to itself) to free a corner.
const MAX_HEADROOM: f64 = 0.6;
/// The most of the picture's width a legend right of the plot may take.
const MAX_OUTSIDE: f64 = 0.4;

fn err_str(x: &dyn std::fmt::Display) -> String {
    x.to_string()
}

/// The labels of the legend, in series order.
fn legend_labels(chart: &Chart) -> Vec<&str> {
    chart
        .series
        .iter()
        .filter(|s| s.listed())
        .map(|s| s.name.as_str())
        .collect()
}

/// The legend box (width, height) in pixels, as [`draw_legend`] draws it.
fn legend_size(labels: &[&str]) -> (i32, i32) {
    let mut text = MultiLineText::<_, &str>::new((0, 0), ("sans-serif", LEGEND_FONT));
    for &l in labels {
        text.push_line(l);
    }
    let (w, h) = text.estimate_dimension().unwrap_or_else(|_| {
        // conservative: 0.65 em per character, 1.25 em per line
        let n = labels.iter().map(|l| l.chars().count()).max().unwrap_or(0);
        let em = LEGEND_FONT as f64;
        (
            (0.65 * em * n as f64).ceil() as i32,
            (1.25 * em * labels.len() as f64).ceil() as i32,
        )
    });
    (w + LEGEND_GLYPH + 2 * LEGEND_MARGIN, h + 2 * LEGEND_MARGIN)
}

/// The legend box at an inner corner of the plotting area `(xs, ys)`, in
/// backend pixels: (x0, y0, x1, y1).
fn corner_box(
    (xs, ys): (std::ops::Range<i32>, std::ops::Range<i32>),
    (w, h): (i32, i32),
    pos: LegendPos,
) -> (i32, i32, i32, i32) {
    use LegendPos::*;
    let x0 = match pos {
        UpperLeft | LowerLeft => xs.start + LEGEND_INSET,
        _ => xs.end - w - LEGEND_INSET,
    };
    let y0 = match pos {
        UpperLeft | UpperRight => ys.start + LEGEND_INSET,
        _ => ys.end - h - LEGEND_INSET,
    };
    (x0, y0, x0 + w, y0 + h)
}

/// The chart's area below the title, inside the margin (draws the title).
fn titled_area<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    title: &str,
) -> std::result::Result<DrawingArea<DB, Shift>, String> {
    // a long title (the data it shows: preset, images, size, wavelet) is
    // set smaller until it fits the width, rather than clipped
    let avail = root.dim_in_pixel().0.saturating_sub(2 * MARGIN) as f64;
    let wide = ("sans-serif", 22.0)
        .into_font()
        .box_size(title)
        .map_or(0.0, |(w, _)| w as f64);
    let size = if wide > avail && wide > 0.0 {
        (22.0 * avail / wide).floor().max(12.0)
    } else {
        22.0
    };
    root.margin(MARGIN, MARGIN, MARGIN, MARGIN)
        .titled(title, ("sans-serif", size))
        .map_err(|x| err_str(&x))
}

/// The chart's coordinates on `area`, `right` pixels kept free on the right.
/// Draws nothing: building it again with other ranges is free.
fn build<'a, DB: DrawingBackend>(
    area: &'a DrawingArea<DB, Shift>,
    (x, y): ((f64, f64), (f64, f64)),
    right: u32,
) -> std::result::Result<Ctx<'a, DB>, String> {
    ChartBuilder::on(area)
        .margin_right(right)
        .x_label_area_size(X_LABEL_AREA)
        .y_label_area_size(Y_LABEL_AREA)
        .build_cartesian_2d(x.0..x.1, y.0..y.1)
        .map_err(|x| err_str(&x))
}

/// Where the chart puts ink, in data coordinates: its markers, and points
/// every 2 px along its lines and error bars (so a line crossing a box
/// counts even when none of its vertices is inside).
fn ink<DB: DrawingBackend>(ctx: &Ctx<DB>, chart: &Chart) -> Vec<(f64, f64)> {
    let mut out = Vec::new();
    let segment = |a: (f64, f64), b: (f64, f64), out: &mut Vec<(f64, f64)>| {
        let (pa, pb) = (ctx.backend_coord(&a), ctx.backend_coord(&b));
        let len = (pb.0 as f64 - pa.0 as f64).hypot(pb.1 as f64 - pa.1 as f64);
        let n = ((len / 2.0).ceil() as usize).clamp(1, 100_000);
        for i in 0..=n {
            let t = i as f64 / n as f64;
            out.push((a.0 + t * (b.0 - a.0), a.1 + t * (b.1 - a.1)));
        }
    };
    for s in &chart.series {
        let pts = s.finite_points();
        if !matches!(s.style, Style::Markers | Style::OpenMarkers) {
            for w in s.runs().iter().flat_map(|r| r.windows(2)) {
                segment(w[0], w[1], &mut out);
            }
        }
        out.extend_from_slice(&pts);
        for (a, b) in s.error_bars() {
            segment(a, b, &mut out);
        }
    }
    out
}

/// How many of the `ink` points fall on (or within [`LEGEND_PAD`] of) `b`.
fn covered<DB: DrawingBackend>(
    ctx: &Ctx<DB>,
    ink: &[(f64, f64)],
    b: (i32, i32, i32, i32),
) -> usize {
    ink.iter()
        .filter(|p| {
            let (x, y) = ctx.backend_coord(p);
            x >= b.0 - LEGEND_PAD
                && x <= b.2 + LEGEND_PAD
                && y >= b.1 - LEGEND_PAD
                && y <= b.3 + LEGEND_PAD
        })
        .count()
}

/// The y range, grown at the top (upper corners) or the bottom (lower
/// corners), that leaves the legend box at `pos` free of the ink in its
/// columns; `None` if the box would need most of the height.
fn headroom<DB: DrawingBackend>(
    ctx: &Ctx<DB>,
    ink: &[(f64, f64)],
    pos: LegendPos,
    size: (i32, i32),
    y: (f64, f64),
) -> Option<(f64, f64)> {
    let area = ctx.plotting_area().get_pixel_range();
    let ph = (area.1.end - area.1.start - 1).max(1) as f64;
    let b = corner_box(area, size, pos);
    let cols = (b.0 - LEGEND_PAD)..=(b.2 + LEGEND_PAD);
    let ys = ink
        .iter()
        .filter(|p| cols.contains(&ctx.backend_coord(p).0))
        .map(|p| p.1);
    // the fraction of the height the box needs, with a 2 px cushion
    let f = (LEGEND_INSET + size.1 + LEGEND_PAD + 2) as f64 / ph;
    if f >= 0.9 {
        return None;
    }
    match pos {
        LegendPos::UpperLeft | LegendPos::UpperRight => {
            let top = ys.fold(f64::NEG_INFINITY, f64::max);
            top.is_finite()
                .then(|| (y.0, ((top - f * y.0) / (1.0 - f)).max(y.1)))
        }
        _ => {
            let bottom = ys.fold(f64::INFINITY, f64::min);
            bottom
                .is_finite()
                .then(|| (((bottom - f * y.1) / (1.0 - f)).min(y.0), y.1))
        }
    }
}

/// The ranges and the legend placement of a chart on `area`.
#[derive(Clone, Debug, PartialEq)]
struct Plan {
    x: (f64, f64),
    y: (f64, f64),
    /// `None`: no labelled series.
    legend: Option<LegendPos>,
    /// Pixels kept free right of the plotting area (an outside legend).
    right: u32,
    /// The legend box (width, height) in pixels.
    size: (i32, i32),
}

/// Places the legend: the explicit `chart.legend`, or else the first of
/// UpperRight, UpperLeft, LowerRight, LowerLeft covering the fewest ink
/// points; if all cover some, the corner needing the least headroom on an
/// automatic y range (at most [`MAX_HEADROOM`]); else right of the plot if
/// the legend is narrow enough ([`MAX_OUTSIDE`]); else the least covered corner.
fn plan<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    chart: &Chart,
) -> std::result::Result<Plan, String> {
    use LegendPos::*;
    let (x, y) = data_range(chart);
    let mut plan = Plan {
        x,
        y,
        legend: None,
        right: 0,
        size: (0, 0),
    };
    let labels = legend_labels(chart);
    if labels.is_empty() {
        return Ok(plan);
    }
    let size = legend_size(&labels);
    plan.size = size;
    let outside = (size.0 + 2 * LEGEND_GAP) as u32;
    if let Some(pos) = chart.legend {
        plan.legend = Some(pos);
        if pos == OutsideRight {
            plan.right = outside;
        }
        return Ok(plan);
    }
    let ctx = build(area, (x, y), 0)?;
    let ink = ink(&ctx, chart);
    let corners = [UpperRight, UpperLeft, LowerRight, LowerLeft];
    let range = ctx.plotting_area().get_pixel_range();
    let cost = corners.map(|c| covered(&ctx, &ink, corner_box(range.clone(), size, c)));
    let best = (0..4).min_by_key(|&i| (cost[i], i)).expect("four corners");
    if cost[best] == 0 {
        plan.legend = Some(corners[best]);
        return Ok(plan);
    }
    if chart.y_range.is_none() {
        let mut grown: Vec<(f64, LegendPos, (f64, f64))> = corners
            .iter()
            .filter_map(|&c| {
                let ny = headroom(&ctx, &ink, c, size, y)?;
                let g = (ny.1 - ny.0) / (y.1 - y.0) - 1.0;
                (g.is_finite() && g <= MAX_HEADROOM).then_some((g, c, ny))
            })
            .collect();
        // stable: equal growth keeps the corner order
        grown.sort_by(|a, b| a.0.total_cmp(&b.0));
        for (_, c, ny) in grown {
            let moved = build(area, (x, ny), 0)?;
            let b = corner_box(moved.plotting_area().get_pixel_range(), size, c);
            if covered(&moved, &ink, b) == 0 {
                plan.y = ny;
                plan.legend = Some(c);
                return Ok(plan);
            }
        }
    }
    if outside as f64 <= MAX_OUTSIDE * area.dim_in_pixel().0 as f64 {
        plan.legend = Some(OutsideRight);
        plan.right = outside;
    } else {
        plan.legend = Some(corners[best]);
    }
    Ok(plan)
}

/// Draws the legend of `chart` on `root` (backend pixels), its box's upper
/// left corner at `at`: one line per labelled series, a sample of the
/// series (its line, dashed if dashed, its marker) left of the label.
fn draw_legend<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    chart: &Chart,
    at: (i32, i32),
    (w, h): (i32, i32),
) -> std::result::Result<(), String> {
    let e = err_str;
    let (x0, y0) = at;
    let frame = [(x0, y0), (x0 + w, y0 + h)];
    root.draw(&Rectangle::new(frame, WHITE.mix(0.85).filled()))
        .map_err(|x| e(&x))?;
    root.draw(&Rectangle::new(frame, BLACK))
        .map_err(|x| e(&x))?;
    let named: Vec<&Series> = chart.series.iter().filter(|s| s.listed()).collect();
    let mut text = MultiLineText::<_, &str>::new(
        (x0 + LEGEND_GLYPH + LEGEND_MARGIN, y0 + LEGEND_MARGIN),
        ("sans-serif", LEGEND_FONT),
    );
    for s in &named {
        text.push_line(s.name.as_str());
    }
    root.draw(&text).map_err(|x| e(&x))?;
    let lines = text.compute_line_layout().map_err(|x| e(&x))?;
    for (s, ((_, ya), (_, yb))) in named.iter().zip(lines) {
        let (x, y) = (x0 + LEGEND_MARGIN, (ya + yb) / 2);
        let c = palette(s.color);
        let line =
            |a: i32, b: i32| PathElement::new(vec![(x + a, y), (x + b, y)], c.stroke_width(2));
        let dot = Circle::new((x + 9, y), 3, c.filled());
        let ring = Circle::new((x + 9, y), 3, c.stroke_width(1));
        match s.style {
            Style::Line => root.draw(&line(0, 18)),
            Style::Dashed => root
                .draw(&line(0, 7))
                .and_then(|_| root.draw(&line(11, 18))),
            Style::Markers => root.draw(&dot),
            Style::OpenMarkers => root.draw(&ring),
            Style::LineMarkers => root.draw(&line(0, 18)).and_then(|_| root.draw(&dot)),
        }
        .map_err(|x| e(&x))?;
    }
    Ok(())
}

/// The number of tick labels plotters' mesh asks an axis for (its default).
const TICKS: usize = 11;

/// The tick labels of one axis, all with the same number of decimals: as
/// many as the finest of the axis's tick values needs (at most 6), so
/// integer ticks read "-4", not "-4.0", and a 0.05 step reads "0.10", not
/// "0.1" beside "0.05". plotters prints each value alone, in its shortest
/// form with at least one decimal.
#[derive(Clone, Copy, Debug)]
struct Ticks {
    /// Digits after the point, of the plain number or (`sci`) of the mantissa.
    decimals: usize,
    /// Scientific notation: ticks that would need more than 6 decimals
    /// (a c3 of 1e-6) or 8 digits before the point.
    sci: bool,
    /// A tick this close to 0 is 0 (key points are multiples of the step
    /// computed in floating point: a zero can come out as -2.8e-17).
    zero: f64,
}

impl Ticks {
    /// The labels for an axis spanning `lo..hi`, whose ticks are plotters'
    /// key points of that range (what its mesh draws).
    fn of(lo: f64, hi: f64) -> Ticks {
        use plotters::coord::ranged1d::Ranged;
        let keys = RangedCoordf64::from(lo..hi).key_points(TICKS);
        let step = match keys.as_slice() {
            [a, b, ..] => (b - a).abs(),
            _ => (hi - lo).abs(),
        };
        // rounding errors of the key points are far below their step
        let tol = 1e-6 * step;
        let zero = tol;
        // every tick writable with at most 6 decimals (None if one is not)
        let plain = keys
            .iter()
            .map(|&v| decimals_of(v, tol))
            .collect::<Option<Vec<usize>>>()
            .map(|d| d.into_iter().max().unwrap_or(0));
        let top = keys.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        match plain {
            Some(decimals) if top < 1e7 => Ticks {
                decimals,
                sci: false,
                zero,
            },
            // the mantissa's digits: down to the step between the ticks
            _ if step > 0.0 && top > 0.0 => Ticks {
                decimals: (top.log10().floor() - step.log10().floor()).clamp(0.0, 6.0) as usize,
                sci: true,
                zero,
            },
            _ => Ticks {
                decimals: 6,
                sci: top >= 1e7,
                zero,
            },
        }
    }

    /// `v` with the axis's decimals; a zero is "0" in scientific notation
    /// and has no sign in either.
    fn label(&self, v: f64) -> String {
        let v = if v.abs() <= self.zero { 0.0 } else { v };
        if self.sci {
            return if v == 0.0 {
                "0".to_string()
            } else {
                format!("{v:.*e}", self.decimals)
            };
        }
        let s = format!("{v:.*}", self.decimals);
        match s.strip_prefix('-') {
            Some(rest) if rest.parse::<f64>() == Ok(0.0) => rest.to_string(),
            _ => s,
        }
    }
}

/// The fewest decimals (at most 6) that write `v` to within `tol`; `None`
/// if 6 do not.
fn decimals_of(v: f64, tol: f64) -> Option<usize> {
    (0..=6).find(|&d| {
        let f = 10f64.powi(d as i32);
        ((v * f).round() / f - v).abs() <= tol
    })
}

fn draw<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    chart: &Chart,
) -> std::result::Result<(), String>
where
    DB::ErrorType: 'static,
{
    let e = err_str;
    root.fill(&WHITE).map_err(|x| e(&x))?;
    let area = titled_area(&root, &chart.title)?;
    let plan = plan(&area, chart)?;
    let mut ctx = build(&area, (plan.x, plan.y), plan.right)?;
    let (tx, ty) = (Ticks::of(plan.x.0, plan.x.1), Ticks::of(plan.y.0, plan.y.1));
    let (fx, fy) = (|v: &f64| tx.label(*v), |v: &f64| ty.label(*v));
    ctx.configure_mesh()
        .x_desc(&chart.x_label)
        .y_desc(&chart.y_label)
        .x_labels(TICKS)
        .y_labels(TICKS)
        .x_label_formatter(&fx)
        .y_label_formatter(&fy)
        .label_style(("sans-serif", 15))
        .axis_desc_style(("sans-serif", 17))
        .light_line_style(RGBColor(235, 235, 235))
        .draw()
        .map_err(|x| e(&x))?;
    for s in &chart.series {
        let c = palette(s.color);
        let pts = s.finite_points();
        match s.style {
            // one two-point path per segment: plotters joins a thick
            // polyline with mitres, which shoot far past the data at sharp
            // turns (a noisy pdf tail drew spikes off the plot)
            Style::Line | Style::LineMarkers => ctx
                .draw_series(
                    s.runs()
                        .into_iter()
                        .flat_map(|r| r.windows(2))
                        .map(|w| PathElement::new(vec![w[0], w[1]], c.stroke_width(2))),
                )
                .map(|_| ())
                .map_err(|x| e(&x))?,
            Style::Dashed => {
                for r in s.runs() {
                    ctx.draw_series(DashedLineSeries::new(r.to_vec(), 8, 5, c.stroke_width(2)))
                        .map_err(|x| e(&x))?;
                }
            }
            Style::Markers => ctx
                .draw_series(pts.iter().map(|&p| Circle::new(p, 3, c.filled())))
                .map(|_| ())
                .map_err(|x| e(&x))?,
            Style::OpenMarkers => ctx
                .draw_series(pts.iter().map(|&p| Circle::new(p, 3, c.stroke_width(1))))
                .map(|_| ())
                .map_err(|x| e(&x))?,
        };
        if s.style == Style::LineMarkers {
            ctx.draw_series(pts.iter().map(|&p| Circle::new(p, 3, c.filled())))
                .map_err(|x| e(&x))?;
        } else if matches!(s.style, Style::Line | Style::Dashed) {
            // a point with no defined neighbour is a line of no length:
            // a dot, so that a curve of one scale (or one estimate between
            // undefined ones) is seen
            let lone = s.runs().into_iter().filter(|r| r.len() == 1);
            ctx.draw_series(lone.map(|r| Circle::new(r[0], 3, c.filled())))
                .map_err(|x| e(&x))?;
        }
        let bars = s
            .error_bars()
            .into_iter()
            .map(|(a, b)| PathElement::new(vec![a, b], c.stroke_width(1)));
        ctx.draw_series(bars).map_err(|x| e(&x))?;
    }
    if let Some(pos) = plan.legend {
        let (xs, ys) = ctx.plotting_area().get_pixel_range();
        let at = match pos {
            LegendPos::OutsideRight => (xs.end + LEGEND_GAP, ys.start),
            _ => {
                let b = corner_box((xs, ys), plan.size, pos);
                (b.0, b.1)
            }
        };
        draw_legend(&root, chart, at, plan.size)?;
    }
    root.present().map_err(|x| e(&x))?;
    Ok(())
}

/// Renders `chart` to `path` (`.png` or `.svg`, by extension), 800x600.
///
/// The legend (one line per series with a name) goes where `chart.legend`
/// says, or, by default, where it hides no data: the first of the inner
/// corners upper right, upper left, lower right, lower left whose box
/// covers no marker and no stretch of line or error bar; if every corner
/// covers some, the y range (when automatic) grows at the top or bottom,
/// by at most 60 %, to leave one corner empty; failing that the legend
/// goes in a column right of the plot (if at most 40 % of the width), or,
/// last, in the corner covering the least. Same chart, same picture.
///
/// **Errors** on an unknown extension or a write failure.
pub fn save_chart(chart: &Chart, path: &Path) -> Result<()> {
    register_font();
    let (w, h) = (800u32, 600u32);
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase();
    let fail = |m: String| Error::format(path, format!("cannot render plot: {m}"));
    match ext.as_str() {
        "png" => {
            let mut buf = vec![0u8; (w * h * 3) as usize];
            draw(
                BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area(),
                chart,
            )
            .map_err(fail)?;
            write_atomic(path, &encode_png_rgb8(&buf, w, h))
        }
        "svg" => {
            let mut s = String::new();
            draw(
                SVGBackend::with_string(&mut s, (w, h)).into_drawing_area(),
                chart,
            )
            .map_err(fail)?;
            tag_svg(&mut s);
            write_atomic(path, s.as_bytes())
        }
        _ => Err(Error::format(path, "plots are written as .png or .svg")),
    }
}

fn encode_png_rgb8(buf: &[u8], w: u32, h: u32) -> Vec<u8> {
    let mut out = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut out, w, h);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        // what made the picture (the JSON beside it holds the parameters)
        enc.add_text_chunk(
            "Software".into(),
            format!("wtmm {} ({})", crate::VERSION, crate::BUILD),
        )
        .expect("a Latin-1 keyword and text");
        let mut wr = enc.write_header().expect("in-memory PNG header");
        wr.write_image_data(buf).expect("in-memory PNG data");
    }
    out
}

/// What made the picture, as a comment after the XML declaration (if any);
/// the JSON beside it holds the parameters.
fn tag_svg(s: &mut String) {
    // the viewer sets an SVG's text: ask for the font the layout was
    // measured with (legend boxes, title widths), then Verdana, whose
    // metrics are close (DejaVu Sans descends from Bitstream Vera)
    *s = s.replace(
        "font-family=\"sans-serif\"",
        "font-family=\"DejaVu Sans, Verdana, sans-serif\"",
    );
    let tag = format!("<!-- wtmm {} ({}) -->", crate::VERSION, crate::BUILD);
    match s.find("?>") {
        Some(i) => s.insert_str(i + 2, &format!("\n{tag}")),
        None => s.insert_str(0, &format!("{tag}\n")),
    }
}

#[cfg(test)]
mod tests;
