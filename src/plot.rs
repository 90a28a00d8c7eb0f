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

static FONT: &[u8] = include_bytes!("../assets/DejaVuSans.ttf");
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

/// Writes a grey-level PNG of a field, linearly mapped from its finite
/// min..max to 0..255 (NaN in [`NO_VALUE`]). For eyes, not for data.
pub fn save_grey(img: ArrayView2<f64>, path: &Path) -> Result<()> {
    Raster::grey(img, (0, 255)).save(path)
}

/// An RGB raster that callers draw on (skeleton pictures), saved as PNG
/// as it is ([`Raster::save`]) or inside axes ([`save_raster_chart`]).
/// Row 0 is the top row; `rgb` holds `3 * width * height` bytes, row-major.
pub struct Raster {
    /// Width in pixels (columns).
    pub width: usize,
    /// Height in pixels (rows).
    pub height: usize,
    /// RGB bytes, row-major from the top row, 3 per pixel.
    pub rgb: Vec<u8>,
}

/// The colour of a pixel without a value in a grey raster: teal, apart
/// from the greys and from the skeleton's red, green, blue and yellow.
pub const NO_VALUE: [u8; 3] = [0, 128, 128];

impl Raster {
    /// A field's finite min..max mapped linearly to the grey levels
    /// `levels.0..=levels.1`; a non-finite value (a missing pixel) in
    /// [`NO_VALUE`], which no grey level and no mark uses.
    pub fn grey(img: ArrayView2<f64>, levels: (u8, u8)) -> Self {
        let range = crate::field::finite_range(img.iter()).unwrap_or((0.0, 0.0));
        Raster::grey_in(img, levels, range)
    }

    /// As [`Raster::grey`] with the values `range.0 ..= range.1` spread over
    /// the levels, values beyond them at the ends.
    pub fn grey_in(img: ArrayView2<f64>, levels: (u8, u8), range: (f64, f64)) -> Self {
        let (ny, nx) = img.dim();
        let (lo, hi) = range;
        let d = if hi > lo { hi - lo } else { 1.0 };
        let (g0, span) = (levels.0 as f64, levels.1 as f64 - levels.0 as f64);
        let mut rgb = Vec::with_capacity(nx * ny * 3);
        for &v in img.iter() {
            if v.is_finite() {
                let g = (g0 + span * ((v - lo) / d).clamp(0.0, 1.0)).round() as u8;
                rgb.extend_from_slice(&[g, g, g]);
            } else {
                rgb.extend_from_slice(&NO_VALUE);
            }
        }
        Raster {
            width: nx,
            height: ny,
            rgb,
        }
    }

    /// Grey background for drawing on: levels 60..230 ([`BACKGROUND_GREY`]),
    /// so that marks in colour stand out at both ends.
    pub fn from_grey(img: ArrayView2<f64>) -> Self {
        Raster::grey(img, BACKGROUND_GREY)
    }

    /// Outlines the rectangle `margin` px inside the border (an analysis
    /// domain) in `c`.
    pub fn frame(&mut self, margin: usize, c: (u8, u8, u8)) {
        let m = margin as f64;
        let (x1, y1) = (self.width as f64 - 1.0 - m, self.height as f64 - 1.0 - m);
        for (a, b, x, y) in [
            (m, m, x1, m),
            (x1, m, x1, y1),
            (x1, y1, m, y1),
            (m, y1, m, m),
        ] {
            self.line(a, b, x, y, c);
        }
    }

    /// Sets one pixel (ignored outside).
    pub fn put(&mut self, x: isize, y: isize, c: (u8, u8, u8)) {
        if x < 0 || y < 0 || x >= self.width as isize || y >= self.height as isize {
            return;
        }
        let i = 3 * (y as usize * self.width + x as usize);
        self.rgb[i..i + 3].copy_from_slice(&[c.0, c.1, c.2]);
    }

    /// A straight segment (DDA).
    pub fn line(&mut self, x0: f64, y0: f64, x1: f64, y1: f64, c: (u8, u8, u8)) {
        let n = ((x1 - x0).abs().max((y1 - y0).abs()).ceil() as usize).max(1);
        for i in 0..=n {
            let t = i as f64 / n as f64;
            self.put(
                (x0 + t * (x1 - x0)).round() as isize,
                (y0 + t * (y1 - y0)).round() as isize,
                c,
            );
        }
    }

    /// Writes the raster as PNG.
    pub fn save(&self, path: &Path) -> Result<()> {
        write_atomic(
            path,
            &encode_png_rgb8(&self.rgb, self.width as u32, self.height as u32),
        )
    }
}

/// A colour bar beside a raster chart: the colours `colors(t)`, t from 0
/// (bottom) to 1 (top), labelled with the values they stand for, linearly
/// from `range.0` (t = 0) to `range.1` (t = 1). For a density coloured
/// with `viridis((log10(v / peak) + 4) / 4)`, say, the bar is
/// `ColorBar::viridis("log10 density / peak", (-4.0, 0.0))`.
#[derive(Clone, Debug)]
pub struct ColorBar {
    /// Label along the bar (what the colours stand for).
    pub label: String,
    /// The values at the bottom (t = 0) and the top (t = 1) of the bar.
    pub range: (f64, f64),
    /// The colour at t in [0, 1].
    pub colors: fn(f64) -> RGBColor,
}

impl ColorBar {
    /// A bar of [`ramp`] from `range.0` to `range.1`.
    pub fn ramp(label: impl Into<String>, range: (f64, f64)) -> Self {
        ColorBar {
            label: label.into(),
            range,
            colors: ramp,
        }
    }

    /// A bar of the grey of [`Raster::from_grey`] from `range.0` (its
    /// darkest) to `range.1`.
    pub fn background_grey(label: impl Into<String>, range: (f64, f64)) -> Self {
        ColorBar {
            label: label.into(),
            range,
            colors: background_grey,
        }
    }

    /// A bar of [`viridis`] from `range.0` to `range.1`.
    pub fn viridis(label: impl Into<String>, range: (f64, f64)) -> Self {
        ColorBar {
            label: label.into(),
            range,
            colors: viridis,
        }
    }
}

/// The grey levels of [`Raster::from_grey`] (the lowest value, the highest).
pub const BACKGROUND_GREY: (u8, u8) = (60, 230);

/// The colour of [`Raster::from_grey`] at `t` in [0, 1] (for its colour bar).
pub fn background_grey(t: f64) -> RGBColor {
    let (g0, g1) = (BACKGROUND_GREY.0 as f64, BACKGROUND_GREY.1 as f64);
    let g = (g0 + (g1 - g0) * t.clamp(0.0, 1.0)).round() as u8;
    RGBColor(g, g, g)
}

/// The axes around a [`Raster`] (see [`save_raster_chart`]): the raster
/// fills the plotting area, its pixels square, its edges at the ends of
/// the physical ranges.
#[derive(Clone, Debug)]
pub struct RasterChart {
    /// Title above the plot (none if empty).
    pub title: String,
    /// Label of the x axis.
    pub x_label: String,
    /// Label of the y axis.
    pub y_label: String,
    /// Physical x at the left edge of column 0 and at the right edge of the
    /// last column (increasing).
    pub x_range: (f64, f64),
    /// Physical y from the lowest to the highest value (increasing); which
    /// of them is row 0 depends on `y_up`.
    pub y_range: (f64, f64),
    /// `true`: y grows upwards, the top edge of row 0 is at `y_range.1`
    /// (maps, densities); `false`: y grows downwards, the top edge of row 0
    /// is at `y_range.0` (pictures in pixel coordinates, row 0 at the top).
    pub y_up: bool,
    /// A colour bar right of the plot.
    pub colorbar: Option<ColorBar>,
    /// The picture's (width, height) in pixels, the raster scaled to fit;
    /// `None`: the raster at an integer zoom (its longest side about 600
    /// px; 1:1 from 600 to 1000 px, shrunk beyond) with the axes around it.
    pub size: Option<(u32, u32)>,
    /// Lines under the axes (none if empty; one per `\n`): a key to the
    /// picture's colours, set smaller if wider than the picture, so that
    /// the axis labels keep their size.
    pub caption: String,
}

impl Default for RasterChart {
    /// No titles, the unit square, y downwards, no colour bar, automatic size.
    fn default() -> Self {
        RasterChart {
            title: String::new(),
            x_label: String::new(),
            y_label: String::new(),
            x_range: (0.0, 1.0),
            y_range: (0.0, 1.0),
            y_up: false,
            colorbar: None,
            size: None,
            caption: String::new(),
        }
    }
}

/// Raster chart layout: a colour bar's gap from the plot, its width, and
/// the room for its ticks and label; the smallest automatic picture.
const BAR_GAP: u32 = 16;
const BAR_WIDTH: u32 = 18;
const BAR_LABELS: u32 = 72;
const MIN_WIDTH: u32 = 320;
/// A filled rectangle of this colour in the SVG is replaced by the raster.
const SENTINEL: RGBColor = RGBColor(0xFE, 0x01, 0xFD);

/// Checks a raster and the chart's ranges.
fn check_raster(raster: &Raster, spec: &RasterChart) -> Result<()> {
    if raster.width == 0 || raster.height == 0 {
        return Err(Error::param("raster", "empty raster"));
    }
    if raster.rgb.len() != 3 * raster.width * raster.height {
        return Err(Error::param(
            "raster",
            format!(
                "{} bytes of RGB for {} x {} pixels (needs {})",
                raster.rgb.len(),
                raster.width,
                raster.height,
                3 * raster.width * raster.height
            ),
        ));
    }
    let increasing = |r: (f64, f64)| r.0.is_finite() && r.1.is_finite() && r.0 < r.1;
    for (name, r) in [("x_range", spec.x_range), ("y_range", spec.y_range)]
        .into_iter()
        .chain(spec.colorbar.as_ref().map(|c| ("colorbar.range", c.range)))
    {
        if !increasing(r) {
            return Err(Error::param(
                name,
                format!("({}, {}) is not a finite increasing range", r.0, r.1),
            ));
        }
    }
    Ok(())
}

/// The caption's font size, and the strip it takes under the axes.
const CAPTION_FONT: f64 = 15.0;
const CAPTION_HEIGHT: u32 = 24;

/// The strip [`RasterChart::caption`] takes (nothing if empty).
fn caption_height(caption: &str) -> u32 {
    if caption.is_empty() {
        0
    } else {
        CAPTION_HEIGHT * caption.lines().count().max(1) as u32
    }
}

/// The height [`DrawingArea::titled`] takes for `title` (nothing if empty).
fn title_height(title: &str) -> u32 {
    if title.is_empty() {
        return 0;
    }
    let h = ("sans-serif", 22)
        .into_font()
        .box_size(title)
        .map_or(30, |(_, h)| h);
    h + 2 * (h / 2).min(5)
}

/// The picture's size and the plotting area's (width, height), in pixels.
fn raster_layout(raster: &Raster, spec: &RasterChart) -> Result<((u32, u32), (u32, u32))> {
    let (w, h) = (raster.width as f64, raster.height as f64);
    let bar = if spec.colorbar.is_some() {
        BAR_GAP + BAR_WIDTH + BAR_LABELS
    } else {
        0
    };
    let title = title_height(&spec.title);
    let frame_w = 2 * MARGIN + Y_LABEL_AREA + bar;
    let frame_h = 2 * MARGIN + title + X_LABEL_AREA + caption_height(&spec.caption);
    match spec.size {
        Some((pw, ph)) => {
            let (aw, ah) = (pw.saturating_sub(frame_w), ph.saturating_sub(frame_h));
            if aw < 8 || ah < 8 {
                return Err(Error::param(
                    "size",
                    format!(
                        "{pw} x {ph} leaves no room for the raster inside the axes \
                         (at least {} x {})",
                        frame_w + 8,
                        frame_h + 8
                    ),
                ));
            }
            let s = (aw as f64 / w).min(ah as f64 / h);
            let fit = |n: f64| ((n * s).round() as u32).max(1);
            Ok(((pw, ph), (fit(w).min(aw), fit(h).min(ah))))
        }
        None => {
            let long = w.max(h);
            let s = if long <= 600.0 {
                (600.0 / long).floor()
            } else {
                (1000.0 / long).min(1.0)
            };
            let (pw, ph) = (
                ((w * s).round() as u32).max(1),
                ((h * s).round() as u32).max(1),
            );
            let title_w = ("sans-serif", 22)
                .into_font()
                .box_size(&spec.title)
                .map_or(0, |(w, _)| w);
            // a long title is set smaller (titled_area), down to 16 pt,
            // before the picture is widened for it
            let title_min = (title_w as f64 * 16.0 / 22.0).ceil() as u32;
            let width = (frame_w + pw).max(title_min + 2 * MARGIN).max(MIN_WIDTH);
            Ok(((width, frame_h + ph), (pw, ph)))
        }
    }
}

/// `raster` scaled to `w` x `h`: nearest pixel where it grows, the mean of
/// the covered pixels where it shrinks.
fn resample(raster: &Raster, w: usize, h: usize) -> Vec<u8> {
    let (sw, sh) = (raster.width, raster.height);
    if (w, h) == (sw, sh) {
        return raster.rgb.clone();
    }
    // the source span [lo, hi) of output index i along an axis of n -> m
    let span = |i: usize, n: usize, m: usize| -> (usize, usize) {
        if m >= n {
            let j = ((i as f64 + 0.5) * n as f64 / m as f64) as usize;
            (j.min(n - 1), j.min(n - 1) + 1)
        } else {
            let lo = i * n / m;
            let hi = ((i + 1) * n).div_ceil(m).clamp(lo + 1, n);
            (lo, hi)
        }
    };
    let cols: Vec<(usize, usize)> = (0..w).map(|i| span(i, sw, w)).collect();
    let mut out = Vec::with_capacity(w * h * 3);
    for oy in 0..h {
        let (y0, y1) = span(oy, sh, h);
        for &(x0, x1) in &cols {
            let mut sum = [0u32; 3];
            for y in y0..y1 {
                for x in x0..x1 {
                    let i = 3 * (y * sw + x);
                    for (s, &v) in sum.iter_mut().zip(&raster.rgb[i..i + 3]) {
                        *s += v as u32;
                    }
                }
            }
            let n = ((y1 - y0) * (x1 - x0)) as u32;
            out.extend(sum.iter().map(|&s| ((s + n / 2) / n) as u8));
        }
    }
    out
}

/// Standard base64 (RFC 4648, padded).
fn base64(bytes: &[u8]) -> String {
    const A: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut s = String::with_capacity(bytes.len().div_ceil(3) * 4);
    for c in bytes.chunks(3) {
        let n = (c[0] as u32) << 16
            | (*c.get(1).unwrap_or(&0) as u32) << 8
            | *c.get(2).unwrap_or(&0) as u32;
        for k in 0..4 {
            if k <= c.len() {
                s.push(A[(n >> (18 - 6 * k) & 63) as usize] as char);
            } else {
                s.push('=');
            }
        }
    }
    s
}

/// A plotting area: its upper left corner and its size, in backend pixels.
type PlotRect = ((i32, i32), (u32, u32));

/// Draws the raster chart; the raster itself is blitted (`blit`) or left as
/// a [`SENTINEL`] rectangle (for SVG). Returns the plotting area's upper
/// left corner and size in backend pixels.
fn draw_raster<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    raster: &Raster,
    spec: &RasterChart,
    plot: (u32, u32),
    blit: bool,
) -> std::result::Result<PlotRect, String>
where
    DB::ErrorType: 'static,
{
    let e = err_str;
    root.fill(&WHITE).map_err(|x| e(&x))?;
    // the caption's strip at the bottom, the chart above it
    let cap = caption_height(&spec.caption);
    let (root, strip) = if cap > 0 {
        let h = root.dim_in_pixel().1;
        let (top, bottom) = root.split_vertically(h.saturating_sub(cap));
        (top, Some(bottom))
    } else {
        (root, None)
    };
    if let Some(strip) = &strip {
        // one line per caption line, centred, all set smaller (down to
        // 10 pt) when the widest is wider than the picture
        let avail = strip.dim_in_pixel().0.saturating_sub(2 * MARGIN) as f64;
        let font = ("sans-serif", CAPTION_FONT).into_font();
        let wide = spec
            .caption
            .lines()
            .map(|l| font.box_size(l).map_or(0.0, |(w, _)| w as f64))
            .fold(0.0, f64::max);
        let size = if wide > avail && wide > 0.0 {
            (CAPTION_FONT * avail / wide).floor().max(10.0)
        } else {
            CAPTION_FONT
        };
        let style = TextStyle::from(("sans-serif", size).into_font())
            .pos(Pos::new(HPos::Center, VPos::Top));
        let (w, _) = strip.dim_in_pixel();
        for (i, line) in spec.caption.lines().enumerate() {
            let y = (i as u32 * CAPTION_HEIGHT) as i32;
            strip
                .draw(&Text::new(line, ((w / 2) as i32, y), style.clone()))
                .map_err(|x| e(&x))?;
        }
    }
    let area = if spec.title.is_empty() {
        root.margin(MARGIN, MARGIN, MARGIN, MARGIN)
    } else {
        titled_area(&root, &spec.title)?
    };
    let (aw, ah) = area.dim_in_pixel();
    let bar = if spec.colorbar.is_some() {
        BAR_GAP + BAR_WIDTH + BAR_LABELS
    } else {
        0
    };
    let (bw, bh) = (Y_LABEL_AREA + plot.0 + bar, plot.1 + X_LABEL_AREA);
    let (ox, oy) = (aw.saturating_sub(bw) / 2, ah.saturating_sub(bh) / 2);
    let main = area.clone().shrink((ox, oy), (Y_LABEL_AREA + plot.0, bh));
    // y downwards: the chart runs on -y, labelled with y
    let (y_lo, y_hi, sign) = if spec.y_up {
        (spec.y_range.0, spec.y_range.1, 1.0)
    } else {
        (-spec.y_range.1, -spec.y_range.0, -1.0)
    };
    let mut ctx = ChartBuilder::on(&main)
        .x_label_area_size(X_LABEL_AREA)
        .y_label_area_size(Y_LABEL_AREA)
        .build_cartesian_2d(spec.x_range.0..spec.x_range.1, y_lo..y_hi)
        .map_err(|x| e(&x))?;
    let pa = ctx.plotting_area().strip_coord_spec();
    let (pw, ph) = pa.dim_in_pixel();
    let base = pa.get_base_pixel();
    if blit {
        let buf = resample(raster, pw as usize, ph as usize);
        let img = BitMapElement::with_owned_buffer((0, 0), (pw, ph), buf)
            .ok_or("raster buffer of the wrong size")?;
        pa.draw(&img).map_err(|x| e(&x))?;
    } else {
        pa.draw(&Rectangle::new(
            [(0, 0), (pw as i32, ph as i32)],
            SENTINEL.filled(),
        ))
        .map_err(|x| e(&x))?;
    }
    // ticks as the charts write them (no signed zero); y flipped when down
    let (tx, ty) = (
        Ticks::of(spec.x_range.0, spec.x_range.1),
        Ticks::of(y_lo, y_hi),
    );
    let fmt_x = |v: &f64| tx.label(*v);
    let fmt_y = |v: &f64| ty.label(sign * v);
    // a long x label (a picture's colour key) is set smaller until it fits
    // under the raster, as a long title is (titled_area); plotters styles
    // both axis descriptions alike, so the y label follows
    let wide = ("sans-serif", 17.0)
        .into_font()
        .box_size(&spec.x_label)
        .map_or(0.0, |(w, _)| w as f64);
    let desc = if wide > pw as f64 && wide > 0.0 {
        (17.0 * pw as f64 / wide).floor().max(10.0)
    } else {
        17.0
    };
    ctx.configure_mesh()
        .disable_mesh()
        .x_desc(&spec.x_label)
        .y_desc(&spec.y_label)
        .x_labels(TICKS)
        .y_labels(TICKS)
        .x_label_formatter(&fmt_x)
        .y_label_formatter(&fmt_y)
        .label_style(("sans-serif", 15))
        .axis_desc_style(("sans-serif", desc))
        .draw()
        .map_err(|x| e(&x))?;
    // a frame just outside the raster
    root.draw(&Rectangle::new(
        [
            (base.0 - 1, base.1 - 1),
            (base.0 + pw as i32, base.1 + ph as i32),
        ],
        BLACK,
    ))
    .map_err(|x| e(&x))?;
    if let Some(cb) = &spec.colorbar {
        let column = area.clone().shrink(
            (ox + Y_LABEL_AREA + pw + BAR_GAP, oy),
            (BAR_WIDTH + BAR_LABELS, bh),
        );
        let (lo, hi) = cb.range;
        let mut bar = ChartBuilder::on(&column)
            .margin_bottom(X_LABEL_AREA)
            .right_y_label_area_size(BAR_LABELS)
            .build_cartesian_2d(0.0..1.0, lo..hi)
            .map_err(|x| e(&x))?;
        let n = ph.clamp(2, 256);
        bar.draw_series((0..n).map(|i| {
            let (t0, t1) = (i as f64 / n as f64, (i + 1) as f64 / n as f64);
            let c = (cb.colors)(0.5 * (t0 + t1));
            Rectangle::new(
                [(0.0, lo + t0 * (hi - lo)), (1.0, lo + t1 * (hi - lo))],
                c.filled(),
            )
        }))
        .map_err(|x| e(&x))?;
        // the same tick labels as the axes (500, not 500.0)
        let tb = Ticks::of(lo, hi);
        let fb = |v: &f64| tb.label(*v);
        bar.configure_mesh()
            .disable_mesh()
            .y_labels(TICKS)
            .y_label_formatter(&fb)
            .y_desc(&cb.label)
            .label_style(("sans-serif", 15))
            .axis_desc_style(("sans-serif", 17))
            .draw()
            .map_err(|x| e(&x))?;
        let bp = bar.plotting_area().strip_coord_spec();
        let (w, h) = bp.dim_in_pixel();
        bp.draw(&Rectangle::new(
            [(0, 0), (w as i32 - 1, h as i32 - 1)],
            BLACK,
        ))
        .map_err(|x| e(&x))?;
    }
    root.present().map_err(|x| e(&x))?;
    Ok((base, (pw, ph)))
}

/// Renders `raster` inside axes: `spec`'s title, axis labels and tick
/// values for its physical ranges, and optionally a colour bar, to `path`
/// (`.png` or `.svg`, by extension), written atomically as [`save_chart`].
/// The raster's pixels stay square: it is scaled (nearest pixel up, mean
/// down) to the largest size that fits, centred. In SVG it is embedded
/// once at its own resolution (a PNG, drawn pixelated).
///
/// **Errors** on an unknown extension, a raster whose `rgb` is not
/// `3 width height` bytes, empty or non-finite ranges, a `size` too small
/// for the axes, or a write failure.
pub fn save_raster_chart(raster: &Raster, spec: &RasterChart, path: &Path) -> Result<()> {
    register_font();
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase();
    if ext != "png" && ext != "svg" {
        return Err(Error::format(path, "plots are written as .png or .svg"));
    }
    check_raster(raster, spec)?;
    let ((w, h), plot) = raster_layout(raster, spec)?;
    let fail = |m: String| Error::format(path, format!("cannot render plot: {m}"));
    if ext == "png" {
        let mut buf = vec![0u8; (w * h * 3) as usize];
        draw_raster(
            BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area(),
            raster,
            spec,
            plot,
            true,
        )
        .map_err(fail)?;
        return write_atomic(path, &encode_png_rgb8(&buf, w, h));
    }
    let mut s = String::new();
    let ((x, y), (pw, ph)) = draw_raster(
        SVGBackend::with_string(&mut s, (w, h)).into_drawing_area(),
        raster,
        spec,
        plot,
        false,
    )
    .map_err(fail)?;
    let png = encode_png_rgb8(&raster.rgb, raster.width as u32, raster.height as u32);
    // SVG 1.1's xlink:href: read by older converters as by SVG 2 viewers
    // (SVG 2's plain href is not; both would hold the raster twice)
    let image = format!(
        "<image x=\"{x}\" y=\"{y}\" width=\"{pw}\" height=\"{ph}\" \
         preserveAspectRatio=\"none\" style=\"image-rendering:pixelated\" \
         xlink:href=\"data:image/png;base64,{}\"/>",
        base64(&png)
    );
    let fill = format!(
        "fill=\"#{:02X}{:02X}{:02X}\"",
        SENTINEL.0, SENTINEL.1, SENTINEL.2
    );
    let at = s
        .find(&fill)
        .and_then(|i| {
            let start = s[..i].rfind("<rect")?;
            let end = i + s[i..].find("/>")? + 2;
            Some(start..end)
        })
        .ok_or_else(|| fail("no place for the raster in the SVG".into()))?;
    s.replace_range(at, &image);
    if let Some(i) = s.find("xmlns=\"http://www.w3.org/2000/svg\"") {
        s.insert_str(i, "xmlns:xlink=\"http://www.w3.org/1999/xlink\" ");
    }
    tag_svg(&mut s);
    write_atomic(path, s.as_bytes())
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
mod tests {
    use super::*;

    /// The plan of `chart` on an 800x600 picture, as `save_chart` makes it.
    fn plan_of(chart: &Chart) -> Plan {
        register_font();
        let (w, h) = (800u32, 600u32);
        let mut buf = vec![0u8; (w * h * 3) as usize];
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        let area = titled_area(&root, &chart.title).unwrap();
        plan(&area, chart).unwrap()
    }

    /// A dense line through the unit square from `a` to `b`.
    fn line(name: &str, a: (f64, f64), b: (f64, f64)) -> Series {
        let pts = (0..=20)
            .map(|i| {
                let t = i as f64 / 20.0;
                (a.0 + t * (b.0 - a.0), a.1 + t * (b.1 - a.1))
            })
            .collect();
        Series::new(name, pts, Style::Line, 0)
    }

    fn unit_chart(series: Vec<Series>) -> Chart {
        Chart {
            title: "legend".into(),
            series,
            x_range: Some((0.0, 1.0)),
            y_range: Some((0.0, 1.0)),
            ..Default::default()
        }
    }

    #[test]
    fn legend_avoids_the_data() {
        // data only in the upper right: the first free corner in the order
        let c = unit_chart(vec![
            line("q = 1", (0.5, 0.5), (1.0, 1.0)),
            line("q = 2", (0.5, 1.0), (1.0, 0.5)),
            line("q = 3", (0.5, 0.98), (1.0, 0.98)),
        ]);
        let p = plan_of(&c);
        assert_eq!(p.legend, Some(LegendPos::UpperLeft));
        assert_eq!((p.y, p.right), ((0.0, 1.0), 0));
        assert_eq!(plan_of(&c), p, "deterministic");
        // along the top: a lower corner
        let c = unit_chart(vec![line("top", (0.0, 0.96), (1.0, 0.96))]);
        assert_eq!(plan_of(&c).legend, Some(LegendPos::LowerRight));
        // a line crossing a corner with no vertex in it still covers it
        let c = unit_chart(vec![
            line("bottom", (0.0, 0.02), (1.0, 0.02)),
            line("upper left", (0.0, 0.97), (0.3, 0.97)),
            Series::new("crossing", vec![(0.5, 0.99), (1.5, 0.93)], Style::Dashed, 1),
        ]);
        let p = plan_of(&c);
        assert_eq!(p.legend, Some(LegendPos::OutsideRight), "{p:?}");
        assert!(p.right > 0);
        // unlabelled series: no legend
        let c = unit_chart(vec![line("", (0.0, 0.0), (1.0, 1.0))]);
        assert_eq!(plan_of(&c).legend, None);
    }

    #[test]
    fn legend_gets_headroom_on_an_automatic_range() {
        // an X through all four corners
        let mut c = unit_chart(vec![
            line("rising", (0.0, 0.0), (1.0, 1.0)),
            line("falling", (0.0, 1.0), (1.0, 0.0)),
        ]);
        c.y_range = None;
        let auto = data_range(&c).1;
        let p = plan_of(&c);
        let pos = p.legend.expect("a legend");
        assert_eq!(p.right, 0);
        match pos {
            LegendPos::UpperLeft | LegendPos::UpperRight => {
                assert!(p.y.1 > auto.1 && p.y.0 == auto.0, "{p:?}")
            }
            LegendPos::LowerLeft | LegendPos::LowerRight => {
                assert!(p.y.0 < auto.0 && p.y.1 == auto.1, "{p:?}")
            }
            LegendPos::OutsideRight => panic!("headroom expected: {p:?}"),
        }
        assert!((p.y.1 - p.y.0) / (auto.1 - auto.0) <= 1.0 + MAX_HEADROOM);
        assert_eq!(plan_of(&c), p, "deterministic");
        // a fixed y range is kept: the legend goes right of the plot
        c.y_range = Some((0.0, 1.0));
        let p = plan_of(&c);
        assert_eq!((p.legend, p.y), (Some(LegendPos::OutsideRight), (0.0, 1.0)));
    }

    #[test]
    fn error_bars_in_both_directions_set_the_range() {
        // a cross of half-width 0.25 around the middle: the automatic range
        // covers the bars; non-finite bars and points draw nothing
        let s = Series::new(
            "estimate",
            vec![(0.5, 0.5), (f64::NAN, 0.5), (0.7, 0.2)],
            Style::Markers,
            0,
        )
        .with_errors(vec![0.25, 1.0, f64::INFINITY])
        .with_x_errors(vec![0.25, 1.0, f64::NAN]);
        assert_eq!(
            s.error_bars(),
            vec![((0.5, 0.25), (0.5, 0.75)), ((0.25, 0.5), (0.75, 0.5))]
        );
        let mut c = unit_chart(vec![s]);
        c.x_range = None;
        c.y_range = None;
        let (x, y) = data_range(&c);
        assert!(x.0 < 0.25 && x.1 > 0.75, "{x:?}");
        assert!(y.0 < 0.2 && y.1 > 0.75, "{y:?}");
        // without the bars the range is that of the two finite points
        let mut bare = unit_chart(vec![Series::new(
            "estimate",
            vec![(0.5, 0.5), (0.7, 0.2)],
            Style::Markers,
            0,
        )]);
        bare.x_range = None;
        bare.y_range = None;
        let (bx, _) = data_range(&bare);
        assert!(bx.0 > 0.4 && bx.1 < 0.8, "{bx:?}");
        assert!(x.0 < bx.0 - 0.1, "the horizontal bar widens the range");
    }

    /// A non-finite point breaks a line (no segment bridges an empty bin);
    /// a tick at a rounding step below zero reads "0".
    #[test]
    fn gaps_break_lines_and_zero_has_no_sign() {
        let nan = f64::NAN;
        let s = Series::new(
            "",
            vec![
                (0.0, 1.0),
                (1.0, 2.0),
                (2.0, nan),
                (3.0, 1.0),
                (nan, 0.0),
                (5.0, 1.0),
                (6.0, 2.0),
            ],
            Style::Line,
            0,
        );
        let runs = s.runs();
        assert_eq!(runs.len(), 3);
        assert_eq!(runs.iter().map(|r| r.len()).collect::<Vec<_>>(), [2, 1, 2]);
        assert_eq!(runs[2], [(5.0, 1.0), (6.0, 2.0)]);
        let t = Ticks::of(-1.0, 1.0);
        assert_eq!(t.label(-1e-17), t.label(0.0));
        assert!(!t.label(-1e-17).starts_with('-'), "{}", t.label(-1e-17));
        assert!(t.label(-0.5).starts_with('-'));
    }

    /// Every label of an axis has the decimals its finest tick needs:
    /// integer steps print no ".0", a 0.05 step prints two decimals on all.
    #[test]
    fn tick_labels_share_their_decimals() {
        use plotters::coord::ranged1d::Ranged;
        let labels = |lo: f64, hi: f64| {
            let t = Ticks::of(lo, hi);
            RangedCoordf64::from(lo..hi)
                .key_points(TICKS)
                .iter()
                .map(|&v| t.label(v))
                .collect::<Vec<_>>()
        };
        let q = labels(-6.6, 9.6);
        assert!(q.contains(&"-4".to_string()), "{q:?}");
        assert!(q.iter().all(|l| !l.contains('.')), "{q:?}");
        let h = labels(0.0, 0.5);
        assert!(h.contains(&"0.05".to_string()), "{h:?}");
        assert!(h.contains(&"0.10".to_string()), "{h:?}");
        assert!(
            h.iter()
                .all(|l| l.split('.').nth(1).map(str::len) == Some(2)),
            "{h:?}"
        );
        let d = labels(1.9, 2.1);
        assert!(
            d.iter()
                .all(|l| l.split('.').nth(1).map(str::len) == Some(2)),
            "{d:?}"
        );
        let px = labels(0.0, 1024.0);
        assert!(px.contains(&"200".to_string()), "{px:?}");
        // tiny and huge values: a mantissa down to the step, not "0.000000"
        let c3 = labels(1.0e-6, 1.5e-6);
        assert!(c3.contains(&"1.20e-6".to_string()), "{c3:?}");
        let e7 = labels(0.0, 4e-7);
        assert!(
            e7.contains(&"0".to_string()) && e7.contains(&"1.0e-7".to_string()),
            "{e7:?}"
        );
        // a zero key point computed as -2.8e-17 is a plain 0
        let mixed = labels(-0.17, 0.19);
        assert!(mixed.contains(&"0.00".to_string()), "{mixed:?}");
        let t = Ticks::of(-0.17, 0.19);
        assert_eq!(t.label(-2.8e-17), "0.00");
        let big = labels(0.0, 5e8);
        assert!(big.contains(&"1.0e8".to_string()), "{big:?}");
    }

    #[test]
    fn legend_position_can_be_fixed() {
        let c = unit_chart(vec![line("q = 1", (0.7, 0.95), (0.95, 0.7))])
            .with_legend(LegendPos::UpperRight);
        let p = plan_of(&c);
        assert_eq!((p.legend, p.right), (Some(LegendPos::UpperRight), 0));
        let p = plan_of(&c.with_legend(LegendPos::OutsideRight));
        assert!(p.right > 0);
    }

    #[test]
    fn raster_fills_the_plotting_area_unobstructed() {
        register_font();
        let (nx, ny) = (10, 6);
        let rgb = (0..nx * ny)
            .flat_map(|i| [(i * 4) as u8, (255 - i * 3) as u8, (i % 7 * 30) as u8])
            .collect();
        let r = Raster {
            width: nx,
            height: ny,
            rgb,
        };
        for y_up in [false, true] {
            let spec = RasterChart {
                title: "t".into(),
                x_label: "x".into(),
                y_label: "y".into(),
                y_up,
                colorbar: Some(ColorBar::ramp("c", (0.0, 1.0))),
                ..Default::default()
            };
            let ((w, h), plot) = raster_layout(&r, &spec).unwrap();
            assert_eq!(plot, (600, 360), "integer zoom 60");
            let mut buf = vec![0u8; (w * h * 3) as usize];
            let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
            let (base, dims) = draw_raster(root, &r, &spec, plot, true).unwrap();
            assert_eq!(dims, plot);
            let want = resample(&r, plot.0 as usize, plot.1 as usize);
            for y in 0..plot.1 as usize {
                let row = 3 * ((base.1 as usize + y) * w as usize + base.0 as usize);
                let n = 3 * plot.0 as usize;
                assert_eq!(buf[row..row + n], want[y * n..y * n + n], "row {y}");
            }
        }
    }

    /// A caption takes a strip under the axes: the picture grows by it,
    /// the raster is drawn unobstructed, and the caption's ink lies in the
    /// strip.
    #[test]
    fn a_caption_has_its_own_strip() {
        register_font();
        let r = Raster {
            width: 10,
            height: 6,
            rgb: vec![40; 10 * 6 * 3],
        };
        let bare = RasterChart {
            title: "t".into(),
            x_label: "x (px)".into(),
            y_label: "y (px)".into(),
            ..Default::default()
        };
        let keyed = RasterChart {
            caption: "red: chains, green: WTMMM, blue: M along A, yellow: domain".into(),
            ..bare.clone()
        };
        let ((w0, h0), p0) = raster_layout(&r, &bare).unwrap();
        let ((w1, h1), p1) = raster_layout(&r, &keyed).unwrap();
        assert_eq!((w1, h1, p1), (w0, h0 + CAPTION_HEIGHT, p0));
        let mut buf = vec![0u8; (w1 * h1 * 3) as usize];
        let root = BitMapBackend::with_buffer(&mut buf, (w1, h1)).into_drawing_area();
        let (base, dims) = draw_raster(root, &r, &keyed, p1, true).unwrap();
        assert_eq!(dims, p1);
        let px =
            |x: usize, y: usize| &buf[3 * (y * w1 as usize + x)..3 * (y * w1 as usize + x) + 3];
        assert_eq!(px(base.0 as usize, base.1 as usize), [40, 40, 40]);
        let strip = (h1 - CAPTION_HEIGHT) as usize..h1 as usize;
        let inked = strip
            .flat_map(|y| (0..w1 as usize).map(move |x| (x, y)))
            .filter(|&(x, y)| px(x, y) != [255, 255, 255])
            .count();
        assert!(
            inked > 100,
            "the caption is drawn in its strip ({inked} px)"
        );
    }

    /// A point with no defined neighbour on a line is drawn as a dot; the
    /// legend lists series with something to draw and keys (no points),
    /// not those whose every point is undefined.
    #[test]
    fn lone_points_are_drawn_and_empty_series_unlisted() {
        let nan = f64::NAN;
        let lone = Series::new("one scale", vec![(0.5, 0.5)], Style::Line, 0);
        let none = Series::new("undefined", vec![(nan, 1.0), (0.2, nan)], Style::Line, 1);
        let key = Series::new("lines: fits", Vec::new(), Style::Line, 2);
        let c = unit_chart(vec![lone, none, key]);
        assert_eq!(legend_labels(&c), ["one scale", "lines: fits"]);
        // a set drawn in two parts keeps its name on the part drawn
        let (est, flag) = ("estimate".to_string(), "flagged".to_string());
        let some = [(nan, 1.0), (0.5, 0.5)];
        assert_eq!(
            part_names(est.clone(), flag.clone(), &some),
            (est.clone(), flag.clone())
        );
        let none = [(nan, 1.0), (0.5, nan)];
        assert_eq!(
            part_names(est.clone(), flag, &none),
            (String::new(), "estimate, all flagged".into())
        );
        assert_eq!(
            part_names(est, String::new(), &none),
            (String::new(), "estimate".into())
        );
        // unlabelled, so that the legend's swatch adds no blue
        register_font();
        let (w, h) = (200u32, 150u32);
        let mut buf = vec![0u8; (w * h * 3) as usize];
        let alone = unit_chart(vec![Series::new("", vec![(0.5, 0.5)], Style::Line, 0)]);
        draw(
            BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area(),
            &alone,
        )
        .unwrap();
        let blue = palette(0);
        let dots = buf
            .chunks(3)
            .filter(|p| p == &[blue.0, blue.1, blue.2])
            .count();
        assert!(dots >= 9, "a dot drawn for the lone point ({dots} px)");
    }

    #[test]
    fn resample_and_base64() {
        let r = Raster {
            width: 4,
            height: 2,
            rgb: (0..24).map(|i| i as u8 * 10).collect(),
        };
        // shrinking: the mean of 2 x 2 blocks
        let m = |i: usize| {
            ((r.rgb[i] as u32
                + r.rgb[i + 3] as u32
                + r.rgb[i + 12] as u32
                + r.rgb[i + 15] as u32
                + 2)
                / 4) as u8
        };
        assert_eq!(resample(&r, 2, 1), vec![m(0), m(1), m(2), m(6), m(7), m(8)]);
        // growing: nearest pixel
        let g = resample(&r, 8, 4);
        assert_eq!(g[..6], [0, 10, 20, 0, 10, 20]);
        assert_eq!(g[3 * (3 * 8 + 7)..3 * (3 * 8 + 8)], r.rgb[21..24]);
        assert_eq!(base64(b"Man"), "TWFu");
        assert_eq!(base64(b"Ma"), "TWE=");
        assert_eq!(base64(b"M"), "TQ==");
        assert_eq!(base64(b""), "");
    }
}
