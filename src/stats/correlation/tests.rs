use super::*;

/// The energy box has side `a`: symmetric weights summing to 1, whole
/// pixels for an odd integer side, a spread (second moment) that grows
/// with `a` and is not zero for any `a > 1` (the whole-pixel box was one
/// pixel up to `a = 2`), continuous in `a` (it jumped at even `a`).
#[test]
fn the_energy_box_has_side_a() {
    let close = |a: &[f64], b: &[f64]| {
        assert_eq!(a.len(), b.len(), "{a:?} vs {b:?}");
        a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-12)
    };
    assert!(close(&box_weights(0.5), &[1.0]));
    assert!(close(&box_weights(1.0), &[1.0]));
    assert!(close(
        &box_weights(1.5),
        &[0.25 / 1.5, 1.0 / 1.5, 0.25 / 1.5]
    ));
    assert!(close(&box_weights(3.0), &[1.0 / 3.0; 3]));
    assert!(close(&box_weights(5.0), &[0.2; 5]));
    let mut last = 0.0;
    for a in [1.01, 1.2, 1.5, 2.0, 2.7, 3.9, 4.0, 6.3, 24.0] {
        let w = box_weights(a);
        let r = (w.len() / 2) as f64;
        let sum: f64 = w.iter().sum();
        assert!((sum - 1.0).abs() < 1e-12, "a = {a}: sum {sum}");
        assert!(close(&w, &w.iter().rev().cloned().collect::<Vec<_>>()));
        let m2: f64 = w
            .iter()
            .enumerate()
            .map(|(i, v)| v * (i as f64 - r).powi(2))
            .sum();
        assert!(m2 > last, "a = {a}: spread {m2} after {last}");
        last = m2;
    }
    // continuous across an even side, where the whole-pixel box jumped
    let (lo, hi) = (box_weights(2.0 - 1e-9), box_weights(2.0 + 1e-9));
    let pad = |w: &[f64], n: usize| {
        let k = (n - w.len()) / 2;
        let mut v = vec![0.0; k];
        v.extend_from_slice(w);
        v.extend(vec![0.0; k]);
        v
    };
    let n = lo.len().max(hi.len());
    let (lo, hi) = (pad(&lo, n), pad(&hi, n));
    assert!(lo.iter().zip(&hi).all(|(x, y)| (x - y).abs() < 1e-8));
}

/// The window and both centrings of `compare_theory`, on a result built
/// from eq 76 itself with known offsets.
#[test]
fn theory_check_reads_the_window() {
    let m = crate::theory::Model::preset("paper-lognormal")
        .unwrap()
        .model;
    let l = 1024.0;
    let dx = vec![10.0, 40.0, 60.0, 200.0, 300.0];
    let t: Vec<f64> = dx
        .iter()
        .map(|&d| m.magnitude_correlation(d, l).unwrap())
        .collect();
    let pair = |a2: f64, off: [f64; 5]| PairCorrelation {
        a1: 3.0,
        a2,
        log2_dx: dx.iter().map(|d| d.log2()).collect(),
        dx: dx.clone(),
        c: t.iter().zip(off).map(|(t, o)| t + o).collect(),
        c_stderr: vec![0.0; 5],
        c_ensemble: t.iter().zip(off).map(|(t, o)| t - 2.0 * o).collect(),
        c_ensemble_stderr: vec![0.001, 0.002, 0.003, 0.004, 0.005],
        pairs: vec![1.0; 5],
        c0: 0.0,
        c0_ensemble: 0.0,
    };
    let r = CorrelationResult {
        source: "cwt".into(),
        magnitude: Magnitude::Lnm,
        periodic: true,
        images: 1,
        scales: vec![3.0, 6.0],
        mean: vec![0.0, 0.0],
        // outside the window: dx = 10 (below 8.3 x 6 = 50 or 8.3 x 3 =
        // 25) and 300 (beyond L/4 = 256) carry large offsets
        pairs: vec![
            pair(3.0, [1.0, 0.01, 0.02, -0.005, 1.0]),
            pair(6.0, [1.0, 1.0, 0.003, 0.004, 1.0]),
        ],
        stderr_method: "none".into(),
        warnings: vec![],
    };
    let c = r.compare_theory(&m, l, PAPER_UNIT);
    assert_eq!((c.pairs[0].bins, c.pairs[1].bins, c.bins), (3, 2, 5));
    assert!((c.pairs[0].max_abs_dev - 0.02).abs() < 1e-12);
    assert!((c.pairs[1].max_abs_dev - 0.004).abs() < 1e-12);
    assert!((c.max_abs_dev - 0.02).abs() < 1e-12);
    assert!((c.max_abs_dev_ensemble - 0.04).abs() < 1e-12);
    // the worst ensemble-centred bin, signed, with its error
    let w = c.worst_ensemble.unwrap();
    assert_eq!((w.a1, w.a2, w.dx, w.stderr), (3.0, 3.0, 60.0, Some(0.003)));
    assert!((w.dev + 0.04).abs() < 1e-12);
    // read literally (dx > sup(a1, a2) px) the 10 px bin counts
    assert!((r.compare_theory(&m, l, 1.0).max_abs_dev - 1.0).abs() < 1e-12);
    // a bin without pairs (NaN) in the window is neither compared nor
    // counted; with none left, bins = 0 and the maxima are NaN (no
    // value, not a perfect 0)
    let mut gap = r.clone();
    gap.pairs[0].c[2] = f64::NAN;
    gap.pairs[0].c_ensemble[2] = f64::NAN;
    let c = gap.compare_theory(&m, l, PAPER_UNIT);
    assert_eq!((c.pairs[0].bins, c.bins), (2, 4));
    assert!((c.pairs[0].max_abs_dev - 0.01).abs() < 1e-12);
    for p in gap.pairs.iter_mut() {
        p.c.fill(f64::NAN);
        p.c_ensemble.fill(f64::NAN);
    }
    let c = gap.compare_theory(&m, l, PAPER_UNIT);
    assert_eq!((c.bins, c.worst_ensemble), (0, None));
    assert!(c.max_abs_dev.is_nan() && c.max_abs_dev_ensemble.is_nan());
    assert!(c.pairs.iter().all(|p| p.max_abs_dev.is_nan()));
}

#[test]
fn runs_cover_the_table() {
    let bin = [0u16, 1, 1, UNUSED, 1, 2, 2, 2, UNUSED, UNUSED, 3];
    let runs = runs_of(&bin);
    let mut back = vec![UNUSED; bin.len()];
    for r in &runs {
        for k in r.start..r.start + r.len {
            back[k as usize] = r.bin;
        }
    }
    assert_eq!(back, bin);
    assert_eq!(runs.len(), 5);
    let v: Vec<f64> = (0..11).map(|i| i as f64 * 0.1).collect();
    assert!((slice_sum(&v) - 5.5).abs() < 1e-12);
}

#[test]
fn ln_normal_matches_libm() {
    // every binade of the normal range, and both sides of the √2 split
    let mut worst = 0.0f64;
    let mut x = f64::MIN_POSITIVE;
    let step = 1.0 + std::f64::consts::PI / 1e3;
    while x < f64::MAX / step {
        for t in [
            x,
            x * std::f64::consts::SQRT_2,
            x * 1.000_000_1,
            x * 1.999_999_9,
        ] {
            let (a, b) = (ln_normal(t), t.ln());
            worst = worst.max((a - b).abs() / b.abs().max(1.0));
        }
        x *= step;
    }
    for t in [
        1.0,
        1.0 + 1e-12,
        1.0 - 1e-12,
        std::f64::consts::SQRT_2,
        0.5,
        2.0,
    ] {
        let (a, b) = (ln_normal(t), t.ln());
        worst = worst.max((a - b).abs() / b.abs().max(1.0));
    }
    assert!(worst < 4.0 * f64::EPSILON, "worst relative error {worst:e}");
    let mut v = vec![4.0, 0.0, f64::INFINITY, f64::NAN, 1e-310, 2.5];
    let mx = half_ln_in_place(&mut v);
    assert_eq!(mx, 4.0);
    assert!((v[0] - 2f64.ln()).abs() < 1e-15 && (v[5] - 0.5 * 2.5f64.ln()).abs() < 1e-15);
    assert!(v[1..5].iter().all(|&w| w == f64::NEG_INFINITY));
}

#[test]
fn smooth_sizes() {
    assert_eq!(smooth(1), 1);
    assert_eq!(smooth(11), 12);
    assert_eq!(smooth(1021), 1024);
    assert_eq!(smooth(997), 1000);
}
