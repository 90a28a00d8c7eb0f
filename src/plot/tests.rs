use super::raster::{CAPTION_HEIGHT, base64, draw_raster, raster_layout, resample};
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
    let px = |x: usize, y: usize| &buf[3 * (y * w1 as usize + x)..3 * (y * w1 as usize + x) + 3];
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
        ((r.rgb[i] as u32 + r.rgb[i + 3] as u32 + r.rgb[i + 12] as u32 + r.rgb[i + 15] as u32 + 2)
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
