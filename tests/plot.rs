//! Plots: files of the right kind and size; sample pictures for eyes
//! (`cargo test --release --test plot -- --ignored`, written to
//! `$WTMM_PLOT_SAMPLES` or the system temporary directory's `plot-samples`).

use std::path::PathBuf;

use wtmm::plot::{Chart, Series, Style, save_chart};

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
}
