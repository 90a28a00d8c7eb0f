//! Plots: files of the right kind and size; sample pictures for eyes
//! (`cargo test --release --test plot -- --ignored`, written to
//! `$WTMM_PLOT_SAMPLES` or the system temporary directory's `plot-samples`).

use std::path::PathBuf;

use ndarray::Array2;
use wtmm::plot::{
    Chart, ColorBar, Raster, RasterChart, Series, Style, ramp, save_chart, save_raster_chart,
};

fn samples_dir() -> PathBuf {
    let d = std::env::var_os("WTMM_PLOT_SAMPLES")
        .map(PathBuf::from)
        .unwrap_or_else(|| std::env::temp_dir().join("plot-samples"));
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// Partition-function-like fans: log2 Z(q, a) = tau(q) log2 a + c(q),
/// markers plus fitted lines, one series per q.
fn fan_chart() -> Chart {
    let mut c = Chart {
        title: "(a) partition functions, 8 image(s), Plain rule".into(),
        x_label: "log2 a".into(),
        y_label: "log2 Z(q, a)".into(),
        ..Default::default()
    };
    let qs = [-3.0, -2.0, -1.0, 0.0, 1.0, 2.0, 3.0, 4.0, 5.0];
    for (k, &q) in qs.iter().enumerate() {
        let tau = 0.5 * q - 2.0 - 0.05 * q * q;
        let c0 = 14.0 - 1.2 * q;
        let pts: Vec<(f64, f64)> = (0..25)
            .map(|i| {
                let x = 1.0 + 0.25 * i as f64;
                (x, c0 + tau * x + 0.1 * ((i * 7 + k) % 5) as f64)
            })
            .collect();
        c.series
            .push(Series::new(format!("q = {q}"), pts, Style::Markers, k));
        c.series.push(Series::new(
            "",
            vec![(1.5, c0 + tau * 1.5 + 0.2), (6.5, c0 + tau * 6.5 + 0.2)],
            Style::Line,
            k,
        ));
    }
    c
}

/// D(h): a parabola with the Legendre transform, two series.
fn dh_chart() -> Chart {
    let mut c = Chart {
        title: "(d) D(h)".into(),
        x_label: "h".into(),
        y_label: "D(h)".into(),
        ..Default::default()
    };
    let para = |h: f64| 2.0 - (h - 0.4) * (h - 0.4) / (2.0 * 0.05);
    c.series.push(Series::new(
        "canonical h(q), D(q)",
        (0..30)
            .map(|i| 0.1 + 0.02 * i as f64)
            .map(|h| (h, para(h)))
            .collect(),
        Style::Markers,
        0,
    ));
    c.series.push(Series::new(
        "Legendre of tau(q)",
        (0..60)
            .map(|i| 0.08 + 0.011 * i as f64)
            .map(|h| (h, para(h) + 0.01))
            .collect(),
        Style::Dashed,
        3,
    ));
    c
}

/// Trace moments: lines of all slopes meeting at one point, long labels.
fn moments_chart() -> Chart {
    let mut c = Chart {
        title: "trace moments, 4 image(s), fit log2 λ 1:7".into(),
        x_label: "log10 λ  (λ = L / l)".into(),
        y_label: "log10 <φ_λ^q>".into(),
        ..Default::default()
    };
    for (n, q) in [0.2, 0.5, 0.8, 1.2, 1.5, 2.0, 2.5, 3.0].iter().enumerate() {
        let k = 0.1 * (q * q - q);
        let pts = (0..9)
            .map(|i| {
                let x = 0.301 * i as f64;
                (x, k * (x + 0.3))
            })
            .collect();
        c.series.push(Series::new(
            format!("q = {q:.2}, K = {k:.3}"),
            pts,
            Style::LineMarkers,
            n,
        ));
    }
    c
}

/// Data in all four corners: headroom on an automatic y range, else the
/// legend right of the plot.
fn crowded_chart(fixed: bool) -> Chart {
    let mut c = Chart {
        title: format!(
            "crowded corners, {} y range",
            if fixed { "fixed" } else { "automatic" }
        ),
        x_label: "x".into(),
        y_label: "y".into(),
        y_range: fixed.then_some((-1.1, 1.1)),
        ..Default::default()
    };
    for (k, f) in [1.0, 2.0, 3.0].iter().enumerate() {
        c.series.push(Series::new(
            format!("cos({f} x)"),
            (0..200)
                .map(|i| 0.05 * i as f64)
                .map(|x| (x, (f * x).cos()))
                .collect(),
            Style::Line,
            k,
        ));
    }
    c
}

/// A joint density of (T1, T2) as `pdf` draws it: n x n cells of 4 px,
/// T2 upwards, log colour scale over 4 decades, white where empty.
fn density_raster(n: usize) -> Raster {
    let px = 4;
    let mut r = Raster {
        width: n * px,
        height: n * px,
        rgb: vec![255; n * px * n * px * 3],
    };
    let c = (n as f64 - 1.0) / 2.0;
    for iy in 0..n {
        for ix in 0..n {
            let (x, y) = ((ix as f64 - c) / c, (iy as f64 - c) / c);
            let v = (-(x * x + 4.0 * y * y + 2.0 * x * y) * 6.0).exp();
            if v < 1e-4 {
                continue;
            }
            let t = (v.log10() + 4.0) / 4.0;
            let k = ramp(t);
            for dy in 0..px {
                for dx in 0..px {
                    r.put(
                        (ix * px + dx) as isize,
                        ((n - 1 - iy) * px + dy) as isize,
                        (k.0, k.1, k.2),
                    );
                }
            }
        }
    }
    r
}

fn density_spec() -> RasterChart {
    RasterChart {
        title: "joint density of (T1, T2), a = 4.0 px".into(),
        x_label: "T1".into(),
        y_label: "T2".into(),
        x_range: (-2.5, 2.5),
        y_range: (-2.5, 2.5),
        y_up: true,
        colorbar: Some(ColorBar::ramp("log10 density / peak", (-4.0, 0.0))),
        ..Default::default()
    }
}

/// A skeleton-like picture: a grey field with red chains, row 0 at the top.
fn skeleton_raster(nx: usize, ny: usize) -> Raster {
    let f = Array2::from_shape_fn((ny, nx), |(y, x)| {
        ((x as f64) * 0.05).sin() * ((y as f64) * 0.08).cos()
    });
    let mut r = Raster::from_grey(f.view());
    for k in 0..6 {
        let y0 = 10.0 + 25.0 * k as f64;
        r.line(5.0, y0, nx as f64 - 5.0, y0 + 30.0, (220, 30, 30));
    }
    r.line(0.0, 0.0, 30.0, 0.0, (30, 90, 255));
    r
}

fn skeleton_spec() -> RasterChart {
    RasterChart {
        title: "skeleton, j = 3, a = 2.83 px".into(),
        x_label: "x (px)".into(),
        y_label: "y (px)".into(),
        x_range: (0.0, 256.0),
        y_range: (0.0, 192.0),
        ..Default::default()
    }
}

/// The (width, height) in a PNG's header.
fn png_size(bytes: &[u8]) -> (u32, u32) {
    assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n", "PNG signature");
    let be = |i: usize| u32::from_be_bytes(bytes[i..i + 4].try_into().unwrap());
    (be(16), be(20))
}

/// The value of `name="..."` in the root `<svg` tag.
fn svg_attr(svg: &str, name: &str) -> String {
    let root = &svg[svg.find("<svg").unwrap()..];
    let root = &root[..root.find('>').unwrap()];
    let at = root.find(&format!(" {name}=\"")).unwrap() + name.len() + 3;
    root[at..at + root[at..].find('"').unwrap()].to_string()
}

#[test]
fn raster_chart_png_and_svg_of_the_requested_size() {
    let d = tempdir("sizes");
    let r = density_raster(16);
    let spec = RasterChart {
        size: Some((500, 420)),
        ..density_spec()
    };
    let png = d.join("density.png");
    save_raster_chart(&r, &spec, &png).unwrap();
    assert_eq!(png_size(&std::fs::read(&png).unwrap()), (500, 420));
    let svg = d.join("density.svg");
    save_raster_chart(&r, &spec, &svg).unwrap();
    let s = std::fs::read_to_string(&svg).unwrap();
    assert_eq!(
        (svg_attr(&s, "width"), svg_attr(&s, "height")),
        ("500".into(), "420".into())
    );
    assert_eq!(s.matches("<image ").count(), 1, "the raster, embedded once");
    assert!(s.contains("xlink:href=\"data:image/png;base64,iVBORw0KGgo"));
    assert!(s.contains("xmlns:xlink=\"http://www.w3.org/1999/xlink\""));
    assert!(s.trim_end().ends_with("</svg>"));
    // the version that drew them: a PNG text chunk, an SVG comment
    // with the commit built from (12 hex digits, "-dirty" when the sources
    // differ from it, or "unknown" outside git)
    let commit = wtmm::BUILD.strip_suffix("-dirty").unwrap_or(wtmm::BUILD);
    assert!(
        wtmm::BUILD == "unknown"
            || (commit.len() == 12 && commit.bytes().all(|b| b.is_ascii_hexdigit())),
        "{}",
        wtmm::BUILD
    );
    let version = format!("wtmm {} ({})", env!("CARGO_PKG_VERSION"), wtmm::BUILD);
    let bytes = std::fs::read(&png).unwrap();
    let reader = png::Decoder::new(std::io::Cursor::new(bytes))
        .read_info()
        .unwrap();
    let texts = &reader.info().uncompressed_latin1_text;
    assert!(
        texts
            .iter()
            .any(|t| t.keyword == "Software" && t.text == version),
        "{texts:?}"
    );
    assert!(s.contains(&format!("<!-- {version} -->")));
    let chart_svg = d.join("fan.svg");
    save_chart(&fan_chart(), &chart_svg).unwrap();
    let c = std::fs::read_to_string(&chart_svg).unwrap();
    assert!(c.contains(&format!("<!-- {version} -->")) && c.trim_end().ends_with("</svg>"));
    // the text asks for the font its layout was measured with
    assert!(c.contains("font-family=\"DejaVu Sans, Verdana, sans-serif\""));
    assert!(!c.contains("font-family=\"sans-serif\""));
    // automatic size: the axes around an integer zoom of the raster
    let sk = d.join("skeleton.png");
    save_raster_chart(&skeleton_raster(256, 192), &skeleton_spec(), &sk).unwrap();
    let (w, h) = png_size(&std::fs::read(&sk).unwrap());
    assert!(w > 512 && h > 384 && w < 800 && h < 600, "{w} x {h}");
    std::fs::remove_dir_all(&d).unwrap();
}

#[test]
fn raster_chart_errors() {
    let d = tempdir("errors");
    let r = density_raster(4);
    let spec = density_spec();
    for name in ["density.jpg", "density"] {
        let p = d.join(name);
        let e = save_raster_chart(&r, &spec, &p).unwrap_err();
        assert!(e.to_string().contains(".png or .svg"), "{e}");
        assert!(!p.exists());
    }
    let bad = Raster {
        width: 3,
        height: 2,
        rgb: vec![0; 17],
    };
    assert!(save_raster_chart(&bad, &spec, &d.join("bad.png")).is_err());
    let flat = RasterChart {
        x_range: (1.0, 1.0),
        ..density_spec()
    };
    assert!(save_raster_chart(&r, &flat, &d.join("flat.png")).is_err());
    let tiny = RasterChart {
        size: Some((100, 80)),
        ..density_spec()
    };
    assert!(save_raster_chart(&r, &tiny, &d.join("tiny.png")).is_err());
    assert_eq!(std::fs::read_dir(&d).unwrap().count(), 0, "nothing written");
    std::fs::remove_dir_all(&d).unwrap();
}

fn tempdir(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("wtmm-plot-{tag}-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

#[test]
#[ignore = "writes sample pictures for eyes"]
fn render_samples() {
    let d = samples_dir();
    save_chart(&fan_chart(), &d.join("legend_fan.png")).unwrap();
    save_chart(&dh_chart(), &d.join("legend_dh.png")).unwrap();
    save_chart(&moments_chart(), &d.join("legend_moments.png")).unwrap();
    save_chart(&moments_chart(), &d.join("legend_moments.svg")).unwrap();
    save_chart(&crowded_chart(false), &d.join("legend_headroom.png")).unwrap();
    save_chart(&crowded_chart(true), &d.join("legend_outside.png")).unwrap();
    let r = density_raster(64);
    save_raster_chart(&r, &density_spec(), &d.join("raster_density.png")).unwrap();
    save_raster_chart(&r, &density_spec(), &d.join("raster_density.svg")).unwrap();
    let sized = RasterChart {
        size: Some((800, 500)),
        ..density_spec()
    };
    save_raster_chart(&r, &sized, &d.join("raster_density_800x500.png")).unwrap();
    let sk = skeleton_raster(256, 192);
    save_raster_chart(&sk, &skeleton_spec(), &d.join("raster_skeleton.png")).unwrap();
    save_raster_chart(&sk, &skeleton_spec(), &d.join("raster_skeleton.svg")).unwrap();
    // shrunk: a 1500 x 1200 picture
    let big = skeleton_raster(1500, 1200);
    let spec = RasterChart {
        x_range: (0.0, 1500.0),
        y_range: (0.0, 1200.0),
        ..skeleton_spec()
    };
    save_raster_chart(&big, &spec, &d.join("raster_skeleton_big.png")).unwrap();
}
