//! The skeleton against exact local behaviours of the WTMM (II §3; SPEC §2-§3).

use ndarray::Array2;
use wtmm::Field;
use wtmm::cwt::Wavelet;
use wtmm::skeleton::{
    AnalysisConfig, Chain, LinkParams, Linker, MaximaLine, Parallelism, ScaleMaxima, Skeleton,
    Wtmmm, skeleton, skeleton_with,
};
use wtmm::stats::line_fit;

fn cfg(wavelet: Wavelet, octaves: usize, margin: usize) -> AnalysisConfig {
    AnalysisConfig {
        wavelet,
        octaves,
        margin: Some(margin),
        ..Default::default()
    }
}

/// Slope of log2 M against log2 a along a line, over scale indices [j0, j1].
fn slope(sk: &Skeleton, line: &MaximaLine, j0: usize, j1: usize) -> f64 {
    let (x, y): (Vec<f64>, Vec<f64>) = (j0..=j1)
        .map(|j| (sk.scales[j].log2(), line.points[j].m.log2()))
        .unzip();
    line_fit(&x, &y).unwrap().slope
}

/// Smooth radial taper: 1 inside r0, 0 beyond r1.
fn taper(r: f64, r0: f64, r1: f64) -> f64 {
    if r < r0 {
        1.0
    } else if r > r1 {
        0.0
    } else {
        ((r - r0) / (r1 - r0) * std::f64::consts::FRAC_PI_2)
            .cos()
            .powi(2)
    }
}

/// f = |x - x0|^h near an isolated point: the maxima lines that converge to
/// x0 have M ~ a^h (the WTMM property). Over 3 octaves (a = 1.85 .. 14.8)
/// the kernel (3.2 a) plus the WTMMM's distance to x0 (~1.5 a) stay inside
/// the flat part of the taper (r < 180), so the field is an exact cusp there.
#[test]
fn isolated_cusp_gives_its_holder_exponent() {
    let n = 512;
    let (x0, y0) = (256.3, 255.6);
    for h in [0.3, 0.7] {
        let img = Array2::from_shape_fn((n, n), |(y, x)| {
            let (dx, dy) = (x as f64 - x0, y as f64 - y0);
            let r = (dx * dx + dy * dy).sqrt();
            r.powf(h) * taper(r, 180.0, 240.0)
        });
        let sk = skeleton(&Field::new(img), &cfg(Wavelet::Gauss, 4, 40)).unwrap();
        let (j0, j1) = (3, 33);
        let near: Vec<&MaximaLine> = sk
            .lines
            .iter()
            .filter(|l| {
                let p = l.points[0];
                ((p.x as f64 - x0).powi(2) + (p.y as f64 - y0).powi(2)).sqrt() < 5.0
                    && l.points.len() > j1
            })
            .collect();
        assert!(
            !near.is_empty(),
            "h={h}: no maxima line converging to x0 survives 3 octaves"
        );
        for l in near {
            // the line stays within ~2 a of x0 at every scale: it converges to x0
            for (j, p) in l.points.iter().enumerate().take(j1 + 1) {
                let d = ((p.x as f64 - x0).powi(2) + (p.y as f64 - y0).powi(2)).sqrt();
                assert!(
                    d < 2.5 * sk.scales[j] + 3.0,
                    "h={h}: line strays to {d:.1} px at a={:.2}",
                    sk.scales[j]
                );
            }
            let s = slope(&sk, l, j0, j1);
            assert!((s - h).abs() < 0.03, "h={h}: slope {s}");
        }
    }
}

/// A straight step edge: one chain along the edge at every scale, and M is
/// scale-independent (h = 0): T1 = a (step * g_a)' = jump / sqrt(2 pi).
#[test]
fn step_edge() {
    let n = 256;
    // the edge sits on column 128 (half value), so the WTMM column is exact
    let img = Array2::from_shape_fn((n, n), |(_, x)| match x.cmp(&128) {
        std::cmp::Ordering::Less => 0.0,
        std::cmp::Ordering::Equal => 0.5,
        std::cmp::Ordering::Greater => 1.0,
    });
    let c = cfg(Wavelet::Gauss, 3, 40);
    let keep: Vec<usize> = (0..30).collect();
    let sk = skeleton_with(&Field::new(img), &c, Parallelism::Serial, &keep).unwrap();
    for sm in &sk.kept {
        // chains are traced beyond the counting domain (guard band): look at
        // the ones that enter it
        let inside: Vec<_> = sm
            .chains
            .iter()
            .filter(|ch| ch.pixels.len() >= 3 && ch.pixels.iter().any(|&(x, y)| sk.counts(x, y)))
            .collect();
        assert_eq!(inside.len(), 1, "a={:.2}: {} chains", sm.a, inside.len());
        assert!(
            inside[0].pixels.iter().all(|&(x, _)| x == 128),
            "a={:.2}: chain leaves the edge",
            sm.a
        );
        let n_in = inside[0]
            .pixels
            .iter()
            .filter(|&&(x, y)| sk.counts(x, y))
            .count();
        assert_eq!(n_in, n - 80, "the chain spans the interior");
    }
    let full: Vec<&MaximaLine> = sk.lines.iter().filter(|l| l.points.len() == 30).collect();
    assert_eq!(full.len(), 1, "one maxima line along the edge");
    let s = slope(&sk, full[0], 0, 29);
    assert!(s.abs() < 0.03, "slope {s}");
    let m = full[0].points[20].m;
    assert!(
        (m - 1.0 / (2.0 * std::f64::consts::PI).sqrt()).abs() < 1e-3,
        "M = {m}"
    );
}

/// A smooth wide bump: where the bump (std 60 px) is much wider than a, the
/// field is locally a polynomial and M grows like a^n with n the number of
/// vanishing moments (1 for gauss, 3 for mexican); the correction is of
/// relative order (a/60)^2 < 1% over a = 1.5 .. 6. Slightly elliptical so
/// the WTMMM sit on the long axis.
#[test]
fn smooth_bump_gives_the_wavelet_order() {
    let n = 512;
    let s2 = 60.0f64 * 60.0;
    let img = Array2::from_shape_fn((n, n), |(y, x)| {
        let (dx, dy) = (x as f64 - 256.0, y as f64 - 256.0);
        (-(dx * dx + 1.5 * dy * dy) / (2.0 * s2)).exp()
    });
    for (wavelet, order) in [(Wavelet::Gauss, 1.0), (Wavelet::Mexican, 3.0)] {
        // a^3 over a tenth of an octave is a ratio of 1.23: the linking
        // window must admit it (the default admits |h| < 1.5)
        let mut c = cfg(wavelet, 2, 30);
        c.link.ratio = (0.8, 1.3);
        let sk = skeleton(&Field::new(img.clone()), &c).unwrap();
        let full: Vec<&MaximaLine> = sk.lines.iter().filter(|l| l.points.len() == 20).collect();
        assert!(!full.is_empty(), "{wavelet}: no line survives 2 octaves");
        for l in full {
            let s = slope(&sk, l, 0, 19);
            assert!((s - order).abs() < 0.1, "{wavelet}: slope {s}");
        }
    }
}

/// The only chain of a scale, which must be closed.
fn one_closed_chain(sm: &ScaleMaxima) -> &Chain {
    assert_eq!(
        sm.chains.len(),
        1,
        "a={:.2}: {} chains",
        sm.a,
        sm.chains.len()
    );
    let ch = &sm.chains[0];
    assert!(ch.closed, "a={:.2}: chain not closed", sm.a);
    ch
}

/// A disc: one closed chain per scale, concentric with the disc.
/// From a = 2 up: at a = 1.5 the Gaussian filter is still 1.5e-5 at the
/// Nyquist frequency, so the transform of a binary disc rings (Gibbs) above
/// eps = 1e-7 far from the edge and adds tiny spurious chains; at a = 2 the
/// filter is 2.7e-9 there, below eps.
#[test]
fn disc_gives_one_closed_concentric_chain() {
    let n = 256;
    let (cx, cy, r) = (128.0, 128.0, 40.0);
    let img = Array2::from_shape_fn((n, n), |(y, x)| {
        let (dx, dy) = (x as f64 - cx, y as f64 - cy);
        if dx * dx + dy * dy < r * r { 1.0 } else { 0.0 }
    });
    let c = AnalysisConfig {
        a_min: 2.0,
        ..cfg(Wavelet::Gauss, 3, 40)
    };
    let keep: Vec<usize> = (0..30).collect();
    let sk = skeleton_with(&Field::new(img), &c, Parallelism::Serial, &keep).unwrap();
    for sm in &sk.kept {
        let ch = one_closed_chain(sm);
        let k = ch.pixels.len() as f64;
        let mx = ch.pixels.iter().map(|p| p.0 as f64).sum::<f64>() / k;
        let my = ch.pixels.iter().map(|p| p.1 as f64).sum::<f64>() / k;
        assert!(
            (mx - cx).abs() < 1.0 && (my - cy).abs() < 1.0,
            "a={:.2}: centre ({mx},{my})",
            sm.a
        );
        for &(x, y) in &ch.pixels {
            let d = ((x as f64 - cx).powi(2) + (y as f64 - cy).powi(2)).sqrt();
            assert!(
                (d - r).abs() < 2.0 + 0.2 * sm.a,
                "a={:.2}: chain pixel at radius {d}",
                sm.a
            );
        }
    }
}

#[test]
fn constant_image_gives_an_empty_skeleton() {
    // non-power-of-two sizes too: their FFTs leave ~1e-16 of a constant,
    // which the relative eps threshold took for maxima
    for (n, v) in [(128, 3.25), (96, 3.25), (100, 1.0), (48, 0.1)] {
        let img = Array2::from_elem((n, n), v);
        for (wavelet, margin) in [(Wavelet::Gauss, 20), (Wavelet::Mexican, 0)] {
            let sk = skeleton(&Field::new(img.clone()), &cfg(wavelet, 1, margin)).unwrap();
            assert!(sk.lines.is_empty(), "{n}^2 {wavelet}");
            assert!(
                sk.per_scale.iter().all(|s| s.wtmm == 0 && s.wtmmm == 0),
                "{n}^2 {wavelet}"
            );
        }
    }
}

#[test]
fn all_nan_image_is_a_clear_error() {
    let img = Array2::from_elem((128, 128), f64::NAN);
    let e = skeleton(&Field::new(img), &cfg(Wavelet::Gauss, 2, 20)).unwrap_err();
    assert!(e.to_string().contains("missing"), "{e}");
}

#[test]
fn image_smaller_than_the_wavelet_is_a_clear_error() {
    let img = Array2::from_shape_fn((64, 64), |(y, x)| (x * y) as f64);
    let e = skeleton(&Field::new(img), &AnalysisConfig::default()).unwrap_err();
    assert!(e.to_string().contains("smaller than the wavelet"), "{e}");
}

/// No WTMM whose wavelet support (R a) touches a masked pixel.
#[test]
fn masked_pixels_keep_maxima_away() {
    let n = 256;
    let mut img = Array2::from_shape_fn((n, n), |(y, x)| {
        ((x as f64) * 0.21).sin() + ((y as f64) * 0.13 + (x as f64) * 0.05).cos()
    });
    for y in 100..120 {
        for x in 90..140 {
            img[[y, x]] = f64::NAN;
        }
    }
    let c = cfg(Wavelet::Gauss, 2, 20);
    let keep: Vec<usize> = (0..20).collect();
    let sk = skeleton_with(&Field::new(img), &c, Parallelism::Serial, &keep).unwrap();
    let support = Wavelet::Gauss.support_radius();
    let mut total = 0;
    for sm in &sk.kept {
        for w in &sm.wtmmm {
            let dx = (w.x as f64 - (w.x as f64).clamp(90.0, 139.0)).abs();
            let dy = (w.y as f64 - (w.y as f64).clamp(100.0, 119.0)).abs();
            assert!(
                (dx * dx + dy * dy).sqrt() > support * sm.a,
                "WTMMM too close to the hole"
            );
            total += 1;
        }
    }
    assert!(
        total > 100,
        "the rest of the image still has maxima ({total})"
    );
}

#[test]
fn serial_and_parallel_skeletons_are_identical() {
    let img =
        wtmm::synth::fbm::fbm(wtmm::synth::fbm::FbmParams { hurst: 0.5 }, 160, 144, 11, 0).unwrap();
    let c = cfg(Wavelet::Gauss, 3, 40);
    let f = Field::new(img);
    let a = skeleton_with(&f, &c, Parallelism::Serial, &[0, 15]).unwrap();
    let b = skeleton_with(&f, &c, Parallelism::Scales, &[0, 15]).unwrap();
    assert!(!a.lines.is_empty());
    assert_eq!(a, b);
}

/// Detection on row-streamed transforms (`detect_scale`) equals detection on
/// the full transform, with a margin (streamed) and without one (periodic
/// indexing, full transform), with and without chains kept.
#[test]
fn streamed_detection_equals_full_detection() {
    use wtmm::cwt::CwtPlan;
    use wtmm::skeleton::{DetectScratch, detect, detect_scale};
    // margin 0 is the whole torus (streamed with wrapped rows); 83 x 70 has
    // a last row block shorter than the others
    for (ny, nx, margin) in [(96, 96, 0), (96, 96, 4), (96, 96, 20), (83, 70, 0)] {
        let f = Field::new(
            wtmm::synth::fbm::fbm(wtmm::synth::fbm::FbmParams { hurst: 0.4 }, ny, nx, 3, 0)
                .unwrap(),
        );
        let c = AnalysisConfig {
            octaves: 3,
            ..cfg(Wavelet::Gauss, 3, margin)
        };
        let dom = c.domain(&f).unwrap();
        let scales = c.scale_list();
        let plan = CwtPlan::new(ny, nx, c.wavelet, &scales).unwrap();
        let fi = plan.forward(f.data.view()).unwrap();
        let (mut ws, mut s1, mut s2) = (
            plan.workspace(),
            DetectScratch::default(),
            DetectScratch::default(),
        );
        let mut total = 0;
        for (j, &a) in scales.iter().enumerate() {
            let keep = j % 2 == 0;
            let t = plan.scale(&fi, j, &mut ws).clone();
            let want = detect(&t, j, a, &dom, c.eps, keep, &mut s1);
            let got = detect_scale(&plan, &fi, j, &mut ws, &dom, c.eps, keep, &mut s2);
            assert_eq!(got, want, "{ny}x{nx} margin {margin} scale {j}");
            total += got.wtmmm.len();
        }
        assert!(total > 100, "a rough image has maxima ({total})");
    }
}

/// One scale of WTMMM on one open chain along the row y = 50, with the
/// modulus `m(x)` at every chain pixel; WTMMM where `m` has a strict local
/// maximum along the chain (chain ends carry none, as in `detect`).
fn one_chain_scale(
    j: usize,
    a: f64,
    xs: std::ops::Range<u32>,
    m: impl Fn(u32) -> f64,
) -> (ScaleMaxima, Vec<Vec<f64>>) {
    let pixels: Vec<(u32, u32)> = xs.clone().map(|x| (x, 50)).collect();
    let mv: Vec<f64> = xs.clone().map(&m).collect();
    let wtmmm = (1..mv.len() - 1)
        .filter(|&i| mv[i] > mv[i - 1] && mv[i] >= mv[i + 1])
        .map(|i| Wtmmm {
            x: pixels[i].0,
            y: 50,
            m: mv[i],
            arg: 0.0,
            chain: 0,
        })
        .collect();
    let sm = ScaleMaxima {
        j,
        a,
        n_wtmm: pixels.len(),
        n_chains: 1,
        wtmmm,
        chains: vec![Chain {
            pixels,
            closed: false,
        }],
    };
    (sm, vec![mv])
}

fn point_scale(j: usize, a: f64, pts: &[(u32, f64)]) -> ScaleMaxima {
    let pts: Vec<(u32, u32, f64)> = pts.iter().map(|&(x, m)| (x, 50, m)).collect();
    ScaleMaxima::from_points(j, a, &pts)
}

/// The maximum of a chain slides along it, 40 px between two voices (far
/// outside the 12 px box), while the modulus at the line's own position
/// barely changes: the box rule ends the line for want of a candidate, the
/// climb follows the chain to its new maximum (a modulus ratio of 1.05).
#[test]
fn climbing_follows_a_chain_maximum_that_slides_beyond_the_box() {
    let s0 = point_scale(0, 10.0, &[(20, 1.0)]);
    // M rises gently from x = 10 to its maximum at x = 60, then falls
    let (s1, m1) = one_chain_scale(1, 10.7, 10..80, |x| {
        if x <= 60 {
            0.99 + 0.06 * (x - 10) as f64 / 50.0
        } else {
            1.05 - 0.01 * (x - 60) as f64
        }
    });
    for climb in [false, true] {
        let mut lk = Linker::new(LinkParams {
            climb,
            ..Default::default()
        });
        lk.push(&s0);
        let e = lk.push_with(&s1, Some(&m1));
        let lines = lk.finish();
        if climb {
            assert_eq!(e.climb, 1);
            assert_eq!(lines[0].points.len(), 2);
            assert_eq!((lines[0].points[1].x, lines[0].points[1].y), (60, 50));
        } else {
            assert_eq!((e.no_candidate, e.climb), (1, 0));
            assert_eq!(lines[0].points.len(), 1);
        }
    }
}

/// The climb keeps the linking one-to-one and inside the ratio window: a
/// chain maximum already taken by a line that reached it through the box
/// is not taken twice, and one outside the window is not taken at all.
#[test]
fn climbing_respects_links_and_the_ratio_window() {
    let params = LinkParams {
        climb: true,
        ..Default::default()
    };
    // line 0 at x = 20 (lands on the chain), line 1 at x = 58 (its maximum in the box)
    let s0 = point_scale(0, 10.0, &[(20, 1.0), (58, 1.0)]);
    let (s1, m1) = one_chain_scale(1, 10.7, 10..80, |x| {
        if x <= 60 {
            0.99 + 0.06 * (x - 10) as f64 / 50.0
        } else {
            1.05 - 0.01 * (x - 60) as f64
        }
    });
    let mut lk = Linker::new(params);
    lk.push(&s0);
    let e = lk.push_with(&s1, Some(&m1));
    assert_eq!((e.no_candidate, e.climb), (1, 0));
    let lines = lk.finish();
    assert_eq!(lines[0].points.len(), 1);
    assert_eq!((lines[1].points[1].x, lines[1].points.len()), (60, 2));
    // the chain's maximum doubles the modulus: outside (0.9, 1.11)
    let s0 = point_scale(0, 10.0, &[(20, 1.0)]);
    let (s1, m1) = one_chain_scale(1, 10.7, 10..80, |x| {
        if x <= 60 {
            1.0 + (x - 10) as f64 / 50.0
        } else {
            2.0 - 0.01 * (x - 60) as f64
        }
    });
    let mut lk = Linker::new(params);
    lk.push(&s0);
    let e = lk.push_with(&s1, Some(&m1));
    assert_eq!(e.climb, 0);
    assert_eq!(lk.finish()[0].points.len(), 1);
}

/// Climbing along the chains leaves the exact local behaviour alone: the
/// lines converging to a cusp |x - x0|^h still give h over 3 octaves.
#[test]
fn climbing_keeps_the_cusp_exponent() {
    let n = 512;
    let (x0, y0) = (256.3, 255.6);
    let h = 0.5;
    let img = Array2::from_shape_fn((n, n), |(y, x)| {
        let (dx, dy) = (x as f64 - x0, y as f64 - y0);
        let r = (dx * dx + dy * dy).sqrt();
        r.powf(h) * taper(r, 180.0, 240.0)
    });
    let mut c = cfg(Wavelet::Gauss, 4, 40);
    c.link.climb = true;
    let sk = skeleton(&Field::new(img), &c).unwrap();
    let (j0, j1) = (3, 33);
    let mut n_near = 0;
    for l in sk.lines.iter().filter(|l| {
        let p = l.points[0];
        ((p.x as f64 - x0).powi(2) + (p.y as f64 - y0).powi(2)).sqrt() < 5.0 && l.points.len() > j1
    }) {
        n_near += 1;
        let s = slope(&sk, l, j0, j1);
        assert!((s - h).abs() < 0.03, "slope {s}");
    }
    assert!(n_near > 0, "no line converging to x0 survives 3 octaves");
}

/// On the whole torus (margin 0) the chains and lines wrap across the
/// image's edges, as the periodic transform does: a disc centred on the
/// corner of the image is one closed chain per scale, the same as the
/// disc in the middle, not four arcs cut by the edges.
#[test]
fn disc_across_the_edges_of_the_torus_is_one_closed_chain() {
    let n = 256;
    let r = 40.0;
    let disc = |cx: f64, cy: f64| {
        Array2::from_shape_fn((n, n), |(y, x)| {
            // torus distance to the centre
            let d = |a: f64, c: f64| {
                let d = (a - c).abs();
                d.min(n as f64 - d)
            };
            let (dx, dy) = (d(x as f64, cx), d(y as f64, cy));
            if dx * dx + dy * dy < r * r { 1.0 } else { 0.0 }
        })
    };
    let c = AnalysisConfig {
        a_min: 2.0,
        ..cfg(Wavelet::Gauss, 3, 0)
    };
    let keep: Vec<usize> = (0..30).collect();
    let corner =
        skeleton_with(&Field::new(disc(0.0, 0.0)), &c, Parallelism::Serial, &keep).unwrap();
    let middle = skeleton_with(
        &Field::new(disc(128.0, 128.0)),
        &c,
        Parallelism::Serial,
        &keep,
    )
    .unwrap();
    for (sm, sm_mid) in corner.kept.iter().zip(&middle.kept) {
        let ch = one_closed_chain(sm);
        assert_eq!(
            ch.pixels.len(),
            sm_mid.chains[0].pixels.len(),
            "a={:.2}",
            sm.a
        );
        // every pixel of the chain is at the disc's edge, the short way round
        for &(x, y) in &ch.pixels {
            let d = |a: u32| (a as f64).min(n as f64 - a as f64);
            let rad = d(x).hypot(d(y));
            assert!(
                (rad - r).abs() < 2.0 + 0.2 * sm.a,
                "a={:.2}: pixel ({x},{y})",
                sm.a
            );
        }
        assert!(!sm.wtmmm.is_empty(), "a={:.2}: no WTMMM", sm.a);
    }
    // the lines born on the edge survive to the largest scale in both
    let last = corner.per_scale.len() - 1;
    assert!(corner.per_scale[last].lines > 0);
    assert_eq!(corner.per_scale[last].lines, middle.per_scale[last].lines);
}

/// The linker on a torus measures distances the short way round: a line
/// at the right edge links to a WTMMM at the left edge (and prefers it to
/// a farther one inside the image); on the plane it cannot.
#[test]
fn lines_link_across_the_edge_of_a_torus() {
    let s0 = point_scale(0, 3.0, &[(99, 1.0)]);
    // x = 1 is 2 px away round the edge of a 100 px torus, x = 94 is 5 px away
    let s1 = point_scale(1, 3.2, &[(1, 1.0), (94, 1.0)]);
    let mut torus = Linker::new(LinkParams::default()).periodic(Some((100, 100)));
    torus.push(&s0);
    torus.push(&s1);
    let lines = torus.finish();
    assert_eq!(lines[0].points.len(), 2);
    assert_eq!(lines[0].points[1].x, 1);
    let mut plane = Linker::new(LinkParams::default());
    plane.push(&s0);
    plane.push(&s1);
    assert_eq!(plane.finish()[0].points[1].x, 94);
    // beyond the box both ways round: no link
    let s1 = point_scale(1, 3.2, &[(40, 1.0)]);
    let mut torus = Linker::new(LinkParams::default()).periodic(Some((100, 100)));
    torus.push(&s0);
    let e = torus.push(&s1);
    assert_eq!(e.no_candidate, 1);
}

/// `T1` at column `x0` of an image `f(x)` constant along y, by the 1D
/// discrete Fourier sum of SPEC §1's `T̂1(k) = i a kx φ̂(a|k|) f̂(k)` (only
/// ky = 0 carries power): `T1(x0) = (1/N) Σ_m i a k_m φ̂(a |k_m|) f̂[m]
/// e^(i k_m x0)`, `k_m = 2π m/N` folded into (-π, π], with the derivative
/// set to 0 at the Nyquist mode m = N/2 (a real field's derivative there is
/// ambiguous; the CWT uses the same convention). Written out directly,
/// O(N²), independent of the library's FFTs and filters.
fn dft_t1(f: &[f64], wavelet: Wavelet, a: f64, x0: usize) -> f64 {
    use std::f64::consts::PI;
    let n = f.len();
    let mut t = 0.0;
    for m in 0..n {
        if 2 * m == n {
            continue;
        }
        let k = 2.0
            * PI
            * if 2 * m < n {
                m as f64
            } else {
                m as f64 - n as f64
            }
            / n as f64;
        let (mut re, mut im) = (0.0, 0.0);
        for (x, v) in f.iter().enumerate() {
            let ph = -k * x as f64;
            re += v * ph.cos();
            im += v * ph.sin();
        }
        let g = (-0.5 * a * a * k * k).exp()
            * match wavelet {
                Wavelet::Gauss => 1.0,
                Wavelet::Mexican => a * a * k * k,
            };
        // Re[i a k g F e^(i k x0)] = -a k g Im[F e^(i k x0)]
        let ph = k * x0 as f64;
        t -= a * k * g * (re * ph.sin() + im * ph.cos());
    }
    t / n as f64
}

/// Absolute calibration (SPEC §1, L1 normalisation). On a unit step edge
/// `f = H(x - x0)` the transform is `T1(x) = a ∂x (φ_a * H)(x) = a
/// (marginal of φ_a)(x - x0)`: for gauss the marginal is the 1D Gaussian of
/// standard deviation a, so on the edge `M = a · 1/(a √(2π)) = 1/√(2π)`
/// at every scale; for mexican `φ = -∇²g`, the marginal of `φ_a` is
/// `-(1/a) g1''(u/a)`, `T1 = (1 - u²/a²) g1(u/a)` and again `M(x0) =
/// 1/√(2π)`. A prefactor `a^p` with p ≠ 1, a Gaussian of width other than
/// a (M = a/σ √(2π)) or a lost 2π all move this number.
///
/// The image samples the step (0, then 1/2 on the edge column, then 1), so
/// the discrete transform differs from the continuous one by the pixel:
/// the step's difference has the spectrum `e^(-ik/2) cos(k/2)` per unit
/// jump against `(ik)^-1`, which multiplies the integrand by `(k/2)
/// cot(k/2) = 1 - k²/12 - k⁴/720 - ...`, so `M √(2π) = 1 - c1/a² - r`,
/// with the Gaussian moments `c1 = 1/12` (gauss; `<k²> = 1/a²`) and `1/4`
/// (mexican, weight `k² e^(-a²k²/2)`: `<k²> = 3/a²`), and a remainder `r`
/// between `c2/a⁴` and `2 c2/a⁴` (all terms of the cot series are negative
/// and fall off by `(a 2π)^-2` per order), `c2 = 1/240` and `1/48`.
/// Checked: along the maxima line on the edge, at every scale,
/// (1) M equals the direct discrete Fourier sum [`dft_t1`] to 1e-12
///     relative (rounding of the FFTs);
/// (2) M √(2π) lies in `[1 - c1/a² - 2 c2/a⁴, 1 - c1/a² - c2/a⁴]` (plus
///     1e-12), which pins the normalisation to about 1e-4 at a = 3.
#[test]
fn step_edge_modulus_is_calibrated() {
    let n = 256;
    let row: Vec<f64> = (0..n)
        .map(|x| match x.cmp(&128) {
            std::cmp::Ordering::Less => 0.0,
            std::cmp::Ordering::Equal => 0.5,
            std::cmp::Ordering::Greater => 1.0,
        })
        .collect();
    let img = Array2::from_shape_fn((n, n), |(_, x)| row[x]);
    let s2pi = (2.0 * std::f64::consts::PI).sqrt();
    for (wavelet, c1, c2) in [
        (Wavelet::Gauss, 1.0 / 12.0, 1.0 / 240.0),
        (Wavelet::Mexican, 0.25, 1.0 / 48.0),
    ] {
        let sk = skeleton(&Field::new(img.clone()), &cfg(wavelet, 3, 40)).unwrap();
        let ns = sk.scales.len();
        let on_edge: Vec<&MaximaLine> = sk
            .lines
            .iter()
            .filter(|l| l.points.len() == ns && l.points.iter().all(|p| p.x == 128))
            .collect();
        assert_eq!(on_edge.len(), 1, "{wavelet}: one line along the edge");
        for (j, p) in on_edge[0].points.iter().enumerate() {
            let a = sk.scales[j];
            let want = dft_t1(&row, wavelet, a, 128);
            assert!(
                (p.m - want).abs() < 1e-12 * want,
                "{wavelet} a={a:.3}: M = {} vs direct sum {want}",
                p.m
            );
            let x = p.m * s2pi;
            let (hi, lo) = (
                1.0 - c1 / (a * a) - c2 / a.powi(4),
                1.0 - c1 / (a * a) - 2.0 * c2 / a.powi(4),
            );
            if j % 10 == 0 || j == ns - 1 {
                println!(
                    "{wavelet} a={a:6.3}: M sqrt(2 pi) = {x:.8} in [{lo:.8}, {hi:.8}], |M - direct| / M = {:.1e}",
                    (p.m - want).abs() / want
                );
            }
            assert!(
                x <= hi + 1e-12 && x >= lo - 1e-12,
                "{wavelet} a={a:.3}: M sqrt(2 pi) = {x:.8}, expected in [{lo:.8}, {hi:.8}]"
            );
        }
    }
}

/// Diagnostic behind the README's "Not spurious chain maxima" (not a check;
/// `cargo test --release --test skeleton experiment_chain_maxima_spacing --
/// --ignored --nocapture`, env PRESET (default paper-fisc), WAVELET = gauss
/// | mexican (default: the preset's), N images of 1024^2 (default 2)). At
/// every fifth scale, over the chains of the whole torus: the number of
/// WTMMM, the chains' length in pixels times a (constant for a
/// self-similar field), the distance along the chain between neighbouring
/// WTMMM in units of a (quantiles, and the share below 0.5 a), and the
/// share whose dip between them is below 0.1 % of the lower one.
#[test]
#[ignore]
fn experiment_chain_maxima_spacing() {
    use wtmm::cwt::CwtPlan;
    use wtmm::skeleton::maxima::{DetectScratch, detect, for_each_chain_max};
    use wtmm::theory::Model;
    let name = std::env::var("PRESET").unwrap_or_else(|_| "paper-fisc".into());
    let preset = Model::preset(&name).unwrap();
    let wavelet = match std::env::var("WAVELET").as_deref() {
        Ok("gauss") => Wavelet::Gauss,
        Ok("mexican") => Wavelet::Mexican,
        _ => preset.wavelet,
    };
    let n: u64 = std::env::var("N").map(|s| s.parse().unwrap()).unwrap_or(2);
    let size = 1024;
    let c = cfg(wavelet, 5, 0);
    let scales = c.scale_list();
    let plan = CwtPlan::new(size, size, wavelet, &scales).unwrap();
    let images: Vec<Field> = (0..n)
        .map(|i| Field::new(preset.model.synthesize(size, 1, i).unwrap()))
        .collect();
    println!("{name}, {wavelet:?}, {n} x {size}^2");
    println!("     a  WTMMM  chain px * a | gap / a: q10  q25  q50  < 0.5 | dip < 0.1 %");
    for j in (5..scales.len()).step_by(5) {
        let a = scales[j];
        let (mut count, mut len) = (0usize, 0usize);
        let (mut gaps, mut dips) = (Vec::new(), Vec::new());
        for field in &images {
            let domain = c.domain(field).unwrap();
            let fi = plan.forward(field.filled().unwrap().view()).unwrap();
            let mut ws = plan.workspace();
            let t = plan.scale(&fi, j, &mut ws).to_owned();
            let sm = detect(
                &t,
                j,
                a,
                &domain,
                c.eps,
                true,
                &mut DetectScratch::default(),
            );
            count += sm.wtmmm.len();
            for ch in &sm.chains {
                len += ch.pixels.len();
                let m: Vec<f64> = ch
                    .pixels
                    .iter()
                    .map(|&(x, y)| t[[y as usize, x as usize]].norm())
                    .collect();
                let mut idx = Vec::new();
                for_each_chain_max(&m, ch.closed, |k| idx.push(k));
                for w in idx.windows(2) {
                    gaps.push((w[1] - w[0]) as f64 / a);
                    let low = m[w[0]..=w[1]].iter().copied().fold(f64::INFINITY, f64::min);
                    let top = m[w[0]].min(m[w[1]]);
                    dips.push((top - low) / top);
                }
            }
        }
        gaps.sort_by(f64::total_cmp);
        let q = |f: f64| gaps[((gaps.len() - 1) as f64 * f) as usize];
        let share =
            |v: &[f64], t: f64| v.iter().filter(|&&x| x < t).count() as f64 / v.len() as f64;
        println!(
            "{a:6.2} {count:6} {:13.0} |        {:.2} {:.2} {:.2} {:.2}  | {:.2}",
            len as f64 * a,
            q(0.1),
            q(0.25),
            q(0.5),
            share(&gaps, 0.5),
            share(&dips, 0.001)
        );
    }
}

/// A search radius larger than any image (a huge proportional factor or
/// minimum, which validation accepts) links as the whole image would: no
/// division by zero in the bucket grid (its cell size wrapped to 0), and
/// with `climb` no search over a box of 2e9 px a side (it never ended).
#[test]
fn a_radius_beyond_the_image_links_as_the_whole_image() {
    use wtmm::skeleton::SearchRadius;
    let img =
        wtmm::synth::fbm::fbm(wtmm::synth::fbm::FbmParams { hurst: 0.4 }, 48, 48, 3, 0).unwrap();
    let field = Field::new(img);
    for (radius, climb) in [
        (
            SearchRadius::Proportional {
                factor: 1e300,
                min: 1.0,
            },
            false,
        ),
        (
            SearchRadius::Proportional {
                factor: 1.0,
                min: 4294967295.0,
            },
            false,
        ),
        (
            SearchRadius::Proportional {
                factor: 1.0,
                min: 1e9,
            },
            true,
        ),
    ] {
        for margin in [0, 4] {
            let mut c = cfg(Wavelet::Gauss, 2, margin);
            c.link = LinkParams {
                radius,
                climb,
                ..Default::default()
            };
            c.validate().unwrap();
            let sk = skeleton_with(&field, &c, Parallelism::Serial, &[]).unwrap();
            assert!(!sk.lines.is_empty(), "{radius:?} climb {climb}");
        }
    }
}
