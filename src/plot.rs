//! Plots for people: a consumer of results, never of intermediate state.
//!
//! Rendering goes through plotters with an embedded DejaVu Sans font (its
//! `ab_glyph` feature), so the binary needs no fontconfig and no system font.
//! PNG is encoded by the `png` crate from plotters' RGB buffer; SVG is built
//! in memory. Files are written atomically: nothing half-written on error.

use std::path::Path;
use std::sync::Once;

use ndarray::ArrayView2;
use plotters::prelude::*;
use plotters::style::FontStyle;

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
    Line,
    Dashed,
    Markers,
    LineMarkers,
}

/// One curve.
#[derive(Clone, Debug)]
pub struct Series {
    pub name: String,
    pub points: Vec<(f64, f64)>,
    /// Optional symmetric error bar per point (same length as `points`).
    pub y_err: Option<Vec<f64>>,
    pub style: Style,
    /// Index into the palette.
    pub color: usize,
}

impl Series {
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
            style,
            color,
        }
    }

    pub fn with_errors(mut self, err: Vec<f64>) -> Self {
        self.y_err = Some(err);
        self
    }
}

/// A 2D chart: title, axis labels, series.
#[derive(Clone, Debug, Default)]
pub struct Chart {
    pub title: String,
    pub x_label: String,
    pub y_label: String,
    pub series: Vec<Series>,
    /// Fixed ranges; computed from the data when `None`.
    pub x_range: Option<(f64, f64)>,
    pub y_range: Option<(f64, f64)>,
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

fn data_range(chart: &Chart) -> ((f64, f64), (f64, f64)) {
    let mut xs = (f64::INFINITY, f64::NEG_INFINITY);
    let mut ys = (f64::INFINITY, f64::NEG_INFINITY);
    for s in &chart.series {
        for (i, &(x, y)) in s.points.iter().enumerate() {
            if !(x.is_finite() && y.is_finite()) {
                continue;
            }
            let e = s.y_err.as_ref().map_or(0.0, |e| e[i].abs());
            let e = if e.is_finite() { e } else { 0.0 };
            xs = (xs.0.min(x), xs.1.max(x));
            ys = (ys.0.min(y - e), ys.1.max(y + e));
        }
    }
    let pad = |r: (f64, f64)| {
        if !r.0.is_finite() {
            return (0.0, 1.0);
        }
        let d = (r.1 - r.0).abs().max(1e-9);
        (r.0 - 0.05 * d, r.1 + 0.05 * d)
    };
    (
        chart.x_range.unwrap_or_else(|| pad(xs)),
        chart.y_range.unwrap_or_else(|| pad(ys)),
    )
}

fn draw<DB: DrawingBackend>(
    root: DrawingArea<DB, plotters::coord::Shift>,
    chart: &Chart,
) -> std::result::Result<(), String>
where
    DB::ErrorType: 'static,
{
    let e = |x: &dyn std::fmt::Display| x.to_string();
    root.fill(&WHITE).map_err(|x| e(&x))?;
    let (xr, yr) = data_range(chart);
    let mut ctx = ChartBuilder::on(&root)
        .caption(&chart.title, ("sans-serif", 22))
        .margin(14)
        .x_label_area_size(44)
        .y_label_area_size(64)
        .build_cartesian_2d(xr.0..xr.1, yr.0..yr.1)
        .map_err(|x| e(&x))?;
    ctx.configure_mesh()
        .x_desc(&chart.x_label)
        .y_desc(&chart.y_label)
        .label_style(("sans-serif", 15))
        .axis_desc_style(("sans-serif", 17))
        .light_line_style(RGBColor(235, 235, 235))
        .draw()
        .map_err(|x| e(&x))?;
    let mut legend = false;
    for s in &chart.series {
        let c = palette(s.color);
        let pts: Vec<(f64, f64)> = s
            .points
            .iter()
            .cloned()
            .filter(|p| p.0.is_finite() && p.1.is_finite())
            .collect();
        let anno = match s.style {
            Style::Line | Style::LineMarkers => ctx
                .draw_series(LineSeries::new(pts.clone(), c.stroke_width(2)))
                .map_err(|x| e(&x))?,
            Style::Dashed => ctx
                .draw_series(DashedLineSeries::new(pts.clone(), 8, 5, c.stroke_width(2)))
                .map_err(|x| e(&x))?,
            Style::Markers => ctx
                .draw_series(pts.iter().map(|&p| Circle::new(p, 3, c.filled())))
                .map_err(|x| e(&x))?,
        };
        if !s.name.is_empty() {
            legend = true;
            anno.label(&s.name).legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 18, y)], c.stroke_width(2))
            });
        }
        if s.style == Style::LineMarkers {
            ctx.draw_series(pts.iter().map(|&p| Circle::new(p, 3, c.filled())))
                .map_err(|x| e(&x))?;
        }
        if let Some(err) = &s.y_err {
            let bars = s
                .points
                .iter()
                .zip(err)
                .filter(|&(&(x, y), &d)| x.is_finite() && y.is_finite() && d.is_finite())
                .map(|(&(x, y), &d)| {
                    PathElement::new(vec![(x, y - d), (x, y + d)], c.stroke_width(1))
                });
            ctx.draw_series(bars).map_err(|x| e(&x))?;
        }
    }
    if legend {
        ctx.configure_series_labels()
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .label_font(("sans-serif", 14))
            .draw()
            .map_err(|x| e(&x))?;
    }
    root.present().map_err(|x| e(&x))?;
    Ok(())
}

/// Renders `chart` to `path` (`.png` or `.svg`, by extension), 800x600.
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
        let mut wr = enc.write_header().expect("in-memory PNG header");
        wr.write_image_data(buf).expect("in-memory PNG data");
    }
    out
}

/// Writes a grey-level PNG of a field, linearly mapped from its finite
/// min..max to 0..255 (NaN black). For eyes, not for data.
pub fn save_grey(img: ArrayView2<f64>, path: &Path) -> Result<()> {
    let (ny, nx) = img.dim();
    let (lo, hi) = img
        .iter()
        .filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| {
            (a.min(v), b.max(v))
        });
    let d = if hi > lo { hi - lo } else { 1.0 };
    let mut buf = Vec::with_capacity(nx * ny * 3);
    for &v in img.iter() {
        let g = if v.is_finite() {
            (255.0 * (v - lo) / d).round() as u8
        } else {
            0
        };
        buf.extend_from_slice(&[g, g, g]);
    }
    write_atomic(path, &encode_png_rgb8(&buf, nx as u32, ny as u32))
}

/// An RGB raster that callers draw on (skeleton pictures), saved as PNG.
pub struct Raster {
    pub width: usize,
    pub height: usize,
    pub rgb: Vec<u8>,
}

impl Raster {
    /// Grey background from a field (as [`save_grey`]).
    pub fn from_grey(img: ArrayView2<f64>) -> Self {
        let (ny, nx) = img.dim();
        let (lo, hi) = img
            .iter()
            .filter(|v| v.is_finite())
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| {
                (a.min(v), b.max(v))
            });
        let d = if hi > lo { hi - lo } else { 1.0 };
        let mut rgb = Vec::with_capacity(nx * ny * 3);
        for &v in img.iter() {
            let g = if v.is_finite() {
                (60.0 + 170.0 * (v - lo) / d).round() as u8
            } else {
                0
            };
            rgb.extend_from_slice(&[g, g, g]);
        }
        Raster {
            width: nx,
            height: ny,
            rgb,
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
