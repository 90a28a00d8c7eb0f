//! Pictures: rasters, bare or inside axes with a colour bar and a caption.

use super::*;

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
pub(super) const CAPTION_HEIGHT: u32 = 24;

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
pub(super) fn raster_layout(
    raster: &Raster,
    spec: &RasterChart,
) -> Result<((u32, u32), (u32, u32))> {
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
pub(super) fn resample(raster: &Raster, w: usize, h: usize) -> Vec<u8> {
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
pub(super) fn base64(bytes: &[u8]) -> String {
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
pub(super) fn draw_raster<DB: DrawingBackend>(
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
