use super::*;
use crate::stats::fit::line_fit;
use rand::RngExt;

#[test]
fn moments_combine_exactly() {
    let u: Vec<f64> = (0..37)
        .map(|i| ((i * 7919) % 101) as f64 / 13.0 - 2.0)
        .collect();
    let all = Moments::of(&u);
    let (a, b) = u.split_at(11);
    let c = Moments::combine(&Moments::of(a), &Moments::of(b));
    assert_eq!(c.n, all.n);
    assert!((c.mean - all.mean).abs() < 1e-13);
    assert!((c.m2 - all.m2).abs() < 1e-11 * all.m2.abs());
    assert!((c.m3 - all.m3).abs() < 1e-10 * all.m2.abs().max(1.0));
}

#[test]
fn scales_short_of_wtmmm_are_refused() {
    // octaves 0..2 in quarters: 3 values per scale, 2 at the top (4 px)
    let scales: Vec<f64> = (0..9).map(|j| 2f64.powf(j as f64 / 4.0)).collect();
    let vals: Vec<Vec<f64>> = (0..9)
        .map(|j| [0.1, 0.2, 0.4][..if j == 8 { 2 } else { 3 }].to_vec())
        .collect();
    let cfg = KernelConfig::default();
    let s = KernelSums::from_ln_m(&scales, cfg, WtmmmSet::Lines, &vals, "x").unwrap();
    let opts = KernelOptions {
        fit: (0.0, 1.5),
        refs: vec![1.5],
        pairs: vec![(0.5, 1.5)],
    };
    check_wtmmm_counts(&s, &opts).unwrap();
    // the top scale in the fit range, as a reference, as a pair's end
    let bad = [
        KernelOptions {
            fit: (0.0, 2.0),
            ..opts.clone()
        },
        KernelOptions {
            refs: vec![2.0],
            ..opts.clone()
        },
        KernelOptions {
            pairs: vec![(0.5, 2.0)],
            ..opts.clone()
        },
    ];
    for o in bad {
        let e = check_wtmmm_counts(&s, &o).unwrap_err().to_string();
        assert!(e.contains("fewer than 3 WTMMM on maxima lines"), "{e}");
        assert!(e.contains("a = 4.00 px (2);"), "{e}");
        // the estimates run, and say it
        let r = kernel_estimates(&s, &o).unwrap();
        assert!(
            r.warnings
                .iter()
                .any(|w| w.contains("not reliable") && w.contains("a = 4.00 px (2);")),
            "{:?}",
            r.warnings
        );
    }
    assert!(
        !kernel_estimates(&s, &opts)
            .unwrap()
            .warnings
            .iter()
            .any(|w| w.contains("not reliable"))
    );
    // none at all (a flat image): said as such
    let empty: Vec<Vec<f64>> = vec![Vec::new(); 9];
    let s0 = KernelSums::from_ln_m(&scales, cfg, WtmmmSet::Lines, &empty, "x").unwrap();
    let e = check_wtmmm_counts(&s0, &opts).unwrap_err().to_string();
    assert!(e.contains("no WTMMM on maxima lines at any scale"), "{e}");
}

/// Three images hold 2, 1 and 1 WTMMM at the top scale: 4 over the
/// ensemble passes the count check, but leaving out the first leaves 2,
/// whose plug-in κ3 is 0. That replicate is not estimable: the errors
/// fall back to the regression's, with the label and a warning.
#[test]
fn leave_one_out_samples_short_of_wtmmm_are_not_fitted() {
    let scales: Vec<f64> = (0..9).map(|j| 2f64.powf(j as f64 / 4.0)).collect();
    let cfg = KernelConfig::default();
    let top = [2usize, 1, 1];
    let mut s: Option<KernelSums> = None;
    for (i, &k) in top.iter().enumerate() {
        // ln M spreading more at small scales, different in each image
        let vals: Vec<Vec<f64>> = (0..9)
            .map(|j| {
                let n = if j == 8 { k } else { 40 };
                (0..n)
                    .map(|t| ((t * 37 + i * 11 + j * 5) % 23) as f64 * (0.05 - 0.004 * j as f64))
                    .collect()
            })
            .collect();
        let one =
            KernelSums::from_ln_m(&scales, cfg, WtmmmSet::Lines, &vals, format!("{i}")).unwrap();
        match s.as_mut() {
            None => s = Some(one),
            Some(acc) => acc.merge(&one).unwrap(),
        }
    }
    let s = s.unwrap();
    let opts = KernelOptions {
        fit: (0.0, 2.0),
        refs: vec![1.0],
        pairs: vec![(0.0, 1.0)],
    };
    check_wtmmm_counts(&s, &opts).unwrap();
    let r = kernel_estimates(&s, &opts).unwrap();
    for c in [&r.cumulants.c1, &r.cumulants.c2, &r.cumulants.c3] {
        assert!(c.value.is_finite() && c.stderr.is_finite() && c.stderr > 0.0);
    }
    assert_eq!(
        r.stderr_method,
        "jackknife over images; regression for c1, c2, c3"
    );
    assert!(r.warnings.iter().any(|w| w.contains("not finite")));
    // with the top scale left out of the fit every replicate is estimable
    let opts = KernelOptions {
        fit: (0.0, 1.75),
        ..opts
    };
    let r = kernel_estimates(&s, &opts).unwrap();
    assert_eq!(r.stderr_method, "jackknife over images");
}

#[test]
fn cf_recurrence_matches_direct() {
    // 5 values (lanes' remainder only), 16 (whole lanes), 611 (several
    // chunks, a remainder): the error grows as n K ulp at most
    let mut rng = crate::synth::rng_for(3, 0);
    for n in [5, 16, 611] {
        let u: Vec<f64> = (0..n).map(|_| rng.random_range(-6.0..6.0)).collect();
        let dp = 0.05;
        let np = 201;
        let mut re = vec![0.0; np];
        let mut im = vec![0.0; np];
        cf_sums(&u, dp, &mut re, &mut im);
        let tol = 2.2e-16 * (n * np) as f64;
        for k in 0..np {
            let p = k as f64 * dp;
            let (r, i): (f64, f64) = u
                .iter()
                .map(|v| ((p * v).cos(), (p * v).sin()))
                .fold((0.0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1));
            assert!(
                (re[k] - r).abs() < tol && (im[k] - i).abs() < tol,
                "n={n} k={k}: {} {}",
                re[k] - r,
                im[k] - i
            );
        }
    }
}

/// The plug-in bias the warning names: Gaussian ln M with a known c2,
/// few values at the top scales (n like a^-2). Over many ensembles the
/// mean fitted c2 leaves the truth by the tilt of `-κ2/n`, within the
/// Monte Carlo error, and the warning says so when the tilt is half a
/// standard error or more.
#[test]
fn the_plug_in_tilt_of_c2_is_the_bias_the_warning_names() {
    use rand_distr::{Distribution, Normal};
    let scales: Vec<f64> = (0..9).map(|j| 2f64.powf(j as f64 / 4.0)).collect();
    let (k20, c2) = (0.3, 0.03);
    let kap2 = |a: f64| k20 - c2 * a.ln();
    let n_of = |a: f64| (160.0 / (a * a)).round() as usize; // 160 .. 10
    let opts = KernelOptions {
        fit: (0.0, 2.0),
        refs: vec![],
        pairs: vec![],
    };
    let mut rng = crate::synth::rng_for(11, 0);
    let (n_ens, n_img) = (3000, 4);
    let mut est = Vec::with_capacity(n_ens);
    let mut runs = Vec::with_capacity(n_ens);
    for _ in 0..n_ens {
        let mut s: Option<KernelSums> = None;
        for i in 0..n_img {
            let vals: Vec<Vec<f64>> = scales
                .iter()
                .map(|&a| {
                    let d = Normal::new(0.0, kap2(a).sqrt()).unwrap();
                    (0..n_of(a)).map(|_| d.sample(&mut rng)).collect()
                })
                .collect();
            let one = KernelSums::from_ln_m(
                &scales,
                KernelConfig::default(),
                WtmmmSet::Lines,
                &vals,
                format!("{i}"),
            )
            .unwrap();
            match s.as_mut() {
                None => s = Some(one),
                Some(acc) => acc.merge(&one).unwrap(),
            }
        }
        let r = kernel_estimates(&s.unwrap(), &opts).unwrap();
        est.push(r.cumulants.c2.value);
        let warned = r.warnings.iter().any(|w| w.starts_with("c2: the plug-in"));
        // this run's tilt, from its own κ2 and counts
        let x: Vec<f64> = scales.iter().map(|a| a.ln()).collect();
        let y: Vec<f64> = r
            .kappa2
            .iter()
            .zip(&r.n_wtmmm)
            .map(|(k, &n)| -k / n as f64)
            .collect();
        let t = -line_fit(&x, &y).unwrap().slope;
        // the result records the same tilt (c1 has none)
        assert!((r.plugin_tilt[1] - t).abs() <= 1e-12 * t.abs().max(1e-6));
        assert_eq!(r.plugin_tilt[0], 0.0);
        runs.push((t, r.cumulants.c2.stderr, warned));
    }
    // the tilt, independently: minus the slope of -κ2/n over ln a
    let x: Vec<f64> = scales.iter().map(|a| a.ln()).collect();
    let y: Vec<f64> = scales
        .iter()
        .map(|&a| -kap2(a) / (n_img * n_of(a)) as f64)
        .collect();
    let tilt = -line_fit(&x, &y).unwrap().slope;
    let mean = est.iter().sum::<f64>() / n_ens as f64;
    let sd = (est.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / (n_ens - 1) as f64).sqrt();
    let mc = sd / (n_ens as f64).sqrt();
    assert!(tilt > 4.0 * mc, "tilt {tilt} vs MC error {mc}");
    assert!(
        (mean - c2 - tilt).abs() < 4.0 * mc,
        "mean c2 {mean}, truth {c2}, predicted tilt {tilt}, MC error {mc}"
    );
    // warned exactly where the run's tilt reaches half its error
    let n_warned = runs.iter().filter(|r| r.2).count();
    for &(t, se, warned) in &runs {
        assert_eq!(warned, t >= 0.5 * se, "tilt {t}, se {se}");
    }
    assert!(n_warned > 0 && n_warned < n_ens, "{n_warned} of {n_ens}");
}

/// The paper's references and pairs on a 3-octave grid of 10 voices
/// (31 scales, top octave 3): `Default` names octaves off it and is
/// refused; `for_scales` keeps those on it, above the fit's start, and
/// lowers the pairs onto 3.
#[test]
fn default_options_follow_a_short_grid() {
    let scales: Vec<f64> = (0..31).map(|j| 1.5 * 2f64.powf(j as f64 / 10.0)).collect();
    let o = KernelOptions::for_scales(&scales, (0.5, 3.0));
    assert_eq!(o.refs, vec![1.0, 1.5, 2.0, 2.5, 3.0]);
    assert_eq!(o.pairs, vec![(0.5, 3.0), (1.0, 3.0), (1.5, 3.0)]);
    let o = KernelOptions::for_scales(&scales, (0.0, 3.0));
    assert_eq!(o.refs[0], 0.5);
    // on the grid's own data: estimates with for_scales, an error with Default
    let vals: Vec<Vec<f64>> = (0..31)
        .map(|j| {
            (0..50)
                .map(|t| ((t * 37 + j * 5) % 23) as f64 * 0.05)
                .collect()
        })
        .collect();
    let s = KernelSums::from_ln_m(
        &scales,
        KernelConfig::default(),
        WtmmmSet::Lines,
        &vals,
        "x",
    )
    .unwrap();
    assert!(kernel_estimates(&s, &KernelOptions::for_scales(&scales, (0.5, 3.0))).is_ok());
    // Default's fit, 0.5:4, runs past the grid's top (3.1: the last
    // scale and one voice), which is refused before its references
    let e = kernel_estimates(&s, &KernelOptions::default()).unwrap_err();
    assert!(e.to_string().contains("<= 3.10, the octaves"), "{e}");
    let within = KernelOptions {
        fit: (0.5, 3.0),
        ..KernelOptions::default()
    };
    let e = kernel_estimates(&s, &within).unwrap_err();
    assert!(e.to_string().contains("outside the scales"), "{e}");
    // fit ranges the spectra refuse, refused alike (they were fitted over
    // other scales than recorded): past the top, below 0, an end off the
    // grid; the top itself fits up to the last scale
    for (fit, says) in [
        ((0.5, 9.0), "must satisfy 0 <= lo < hi <= 3.10"),
        ((-5.0, 3.0), "must satisfy 0 <= lo < hi <= 3.10"),
        ((3.0, 0.5), "must satisfy 0 <= lo < hi <= 3.10"),
        (
            (0.55, 3.0),
            "octave 0.55 of 0.55:3 lies between two scales, 0.50 and 0.60",
        ),
    ] {
        let o = KernelOptions::for_scales(&scales, fit);
        let e = kernel_estimates(&s, &o).unwrap_err().to_string();
        assert!(e.contains(says), "{fit:?}: {e}");
        assert_eq!(
            e,
            crate::spectra::check_fit_on_grid(&scales, fit)
                .unwrap_err()
                .to_string()
        );
    }
    let top = kernel_estimates(&s, &KernelOptions::for_scales(&scales, (0.5, 3.1))).unwrap();
    assert_eq!(top.fit_scales.1, scales[30]);
    // 5 octaves: the same as Default
    let long: Vec<f64> = (0..51).map(|j| 1.5 * 2f64.powf(j as f64 / 10.0)).collect();
    assert_eq!(
        KernelOptions::for_scales(&long, (0.5, 4.0)),
        KernelOptions::default()
    );
    // no grid: nothing to name, and no panic
    let o = KernelOptions::for_scales(&[], (0.5, 4.0));
    assert!(o.refs.is_empty() && o.pairs.is_empty());
}

/// The kernel curves' jackknife errors over images: 0 at p = 0, the
/// delete-one spread of the curves recomputed without each image, NaN with
/// fewer than 3 images; and on Gaussian ln M (a known kernel,
/// `ln |Ĝ| = -(κ2(a) - κ2(a')) p² / 2`) the curve lies within a few of
/// them of the theory where the characteristic functions are well above
/// their noise.
#[test]
fn kernel_curves_carry_jackknife_errors() {
    use rand_distr::{Distribution, Normal};
    let (scales, opts) = gaussian_setup();
    let mut rng = crate::synth::rng_for(5, 0);
    let images: Vec<KernelSums> = (0..8)
        .map(|i| {
            let vals: Vec<Vec<f64>> = scales
                .iter()
                .map(|&a| {
                    let d = Normal::new(-0.4 * a.ln(), kap2(a).sqrt()).unwrap();
                    (0..2000).map(|_| d.sample(&mut rng)).collect()
                })
                .collect();
            let cfg = KernelConfig::default();
            KernelSums::from_ln_m(&scales, cfg, WtmmmSet::Lines, &vals, format!("{i}")).unwrap()
        })
        .collect();
    let merged = |skip: Option<usize>| {
        let mut it = (0..images.len()).filter(|&i| Some(i) != skip);
        let mut s = images[it.next().unwrap()].clone();
        for i in it {
            s.merge(&images[i]).unwrap();
        }
        s
    };
    let r = kernel_estimates(&merged(None), &opts).unwrap();
    let kc = &r.kernels[0];
    let mid = kc.p.len() / 2;
    assert_eq!(kc.p[mid], 0.0);
    assert_eq!(kc.ln_abs_g_stderr[mid], 0.0);
    assert_eq!(kc.phase_stderr[mid], 0.0);
    // by hand: the curves without each image
    let reps: Vec<KernelCurve> = (0..images.len())
        .map(|i| kernel_estimates(&merged(Some(i)), &opts).unwrap().kernels[0].clone())
        .collect();
    errors_are_the_jackknife_of(kc, &reps, 1e-9);
    // against the theory, where |C| is well above 1/sqrt(n) (p <= 2.5):
    // within 5 jackknife errors (8 images: t with 7 degrees of freedom)
    within_five_errors_of_gaussian(kc, kap2);
    // two images without tiles: no jackknife
    let mut two = images[0].clone();
    two.merge(&images[1]).unwrap();
    let r2 = kernel_estimates(&two, &opts).unwrap();
    assert!(r2.kernels[0].ln_abs_g_stderr.iter().all(|e| e.is_nan()));
    assert_eq!(r2.curve_stderr_method, "none");
    assert_eq!(r.curve_stderr_method, "jackknife over images");
}

/// A jackknife replicate's phase one or more turns off the main curve's
/// branch is brought back onto it before the spread is taken.
#[test]
fn phase_replicates_are_taken_on_the_main_branch() {
    use std::f64::consts::PI;
    let f = super::estimate::same_branch;
    assert_eq!(f(-8.04, -8.04), -8.04);
    for (phase, main) in [(-1.74, -8.04), (-7.93 + 4.0 * PI, -8.04), (3.0, -3.2)] {
        let b = f(phase, main);
        assert!((b - main).abs() <= PI, "{phase} -> {b} for {main}");
        let turns = (phase - b) / (2.0 * PI);
        assert!(
            (turns - turns.round()).abs() < 1e-12,
            "whole turns: {turns}"
        );
    }
}

/// A lone image split into tiles: the kernel curves' errors are the
/// leave-one-tile-out jackknife (each replicate the curve of the image's
/// WTMMM outside one tile), and on independent Gaussian `ln M` the curve
/// lies within them of the closed form.
#[test]
fn a_lone_image_has_tile_jackknife_curve_errors() {
    use crate::stats::pdf::Point;
    use rand_distr::{Distribution, Normal};
    let (scales, opts) = gaussian_setup();
    let mut rng = crate::synth::rng_for(6, 0);
    let (domain, side) = ((0, 400, 0, 400), 100); // 4 x 4 tiles
    let points: Vec<Vec<Point>> = scales
        .iter()
        .map(|&a| {
            let d = Normal::new(-0.4 * a.ln(), kap2(a).sqrt()).unwrap();
            (0..16000)
                .map(|_| Point {
                    x: rng.random_range(0..400),
                    y: rng.random_range(0..400),
                    m: d.sample(&mut rng).exp(),
                    arg: 0.0,
                })
                .collect()
        })
        .collect();
    let cfg = KernelConfig::default();
    let tiled = |ps: &[Vec<Point>], side: usize| {
        KernelSums::from_points_tiled(&scales, cfg, WtmmmSet::Lines, ps, "x", domain, side).unwrap()
    };
    let s = tiled(&points, side);
    let im = &s.images[0];
    let cft = im.cf_tiles.as_ref().unwrap();
    assert_eq!((im.tiles.len(), cft.len(), cft.side), (16, 16, 100));
    // the tiles' sums add up to the image's
    for (c, whole) in [(&cft.re, &im.cf_re), (&cft.im, &im.cf_im)] {
        for (k, w) in whole.iter().enumerate() {
            let sum: f64 = c.iter().map(|t| t[k]).sum();
            assert!((sum - w).abs() <= 1e-9 * 16000.0, "cell {k}: {sum} vs {w}");
        }
    }
    let r = kernel_estimates(&s, &opts).unwrap();
    assert_eq!(
        r.curve_stderr_method,
        "jackknife over 16 tiles (100 px) of 1 image"
    );
    let kc = &r.kernels[0];
    let mid = kc.p.len() / 2;
    assert_eq!(kc.ln_abs_g_stderr[mid], 0.0);
    // by hand: the curve of the WTMMM outside each tile
    let g = crate::spectra::TileGrid::new(domain, side).unwrap();
    let reps: Vec<KernelCurve> = (0..g.len())
        .map(|t| {
            let rest: Vec<Vec<Point>> = points
                .iter()
                .map(|ps| {
                    ps.iter()
                        .filter(|p| g.index(p.x, p.y) != t)
                        .copied()
                        .collect()
                })
                .collect();
            kernel_estimates(&tiled(&rest, 0), &opts).unwrap().kernels[0].clone()
        })
        .collect();
    errors_are_the_jackknife_of(kc, &reps, 1e-6);
    // the noise flags: |C| within 3 errors of 0 at a or a', the error the
    // larger of 1/sqrt(n) and the jackknife's; never at p = 0
    let n = 16000f64;
    let by_hand = |c: &KernelCurve| -> Vec<bool> {
        (0..c.p.len())
            .map(|i| {
                let sig = |e: f64| e.max(1.0 / n.sqrt()) * NOISE_SIGMAS;
                c.p[i] != 0.0
                    && (c.cf_re[i].hypot(c.cf_im[i]) < sig(c.cf_abs_stderr[i])
                        || c.cf_ref_re[i].hypot(c.cf_ref_im[i]) < sig(c.cf_ref_abs_stderr[i]))
            })
            .collect()
    };
    let flags = r.noise(kc);
    assert_eq!(flags, by_hand(kc));
    assert!(!flags[mid] && flags.contains(&true) && flags.contains(&false));
    let mut wide = kc.clone();
    wide.cf_ref_abs_stderr.iter_mut().for_each(|e| *e = 1.0);
    let all = r.noise(&wide);
    assert!(all.iter().enumerate().all(|(i, &f)| f == (i != mid)));
    let mut none = kc.clone();
    none.cf_abs_stderr.iter_mut().for_each(|e| *e = f64::NAN);
    none.cf_ref_abs_stderr
        .iter_mut()
        .for_each(|e| *e = f64::NAN);
    let iid: Vec<bool> = (0..kc.p.len())
        .map(|i| {
            let small = |re: f64, im: f64| re.hypot(im) * n.sqrt() < NOISE_SIGMAS;
            i != mid && (small(kc.cf_re[i], kc.cf_im[i]) || small(kc.cf_ref_re[i], kc.cf_ref_im[i]))
        })
        .collect();
    assert_eq!(r.noise(&none), iid);
    within_five_errors_of_gaussian(kc, kap2);
    // sums without the tiles' characteristic functions (written before
    // them): no curve errors, and said
    let mut old = s.clone();
    old.images[0].cf_tiles = None;
    let r0 = kernel_estimates(&old, &opts).unwrap();
    assert_eq!(r0.curve_stderr_method, "none");
    assert!(r0.kernels[0].ln_abs_g_stderr.iter().all(|e| e.is_nan()));
    // the cumulants keep their tile jackknife either way
    assert_eq!(r0.cumulants.c2.stderr, r.cumulants.c2.stderr);
    // ... and such sums read back, the method of an older result as "none"
    let text = serde_json::to_string(&old).unwrap();
    assert!(!text.contains("cf_tiles"));
    let back: KernelSums = serde_json::from_str(&text).unwrap();
    assert_eq!(back, old);
    let mut res = serde_json::to_value(&r0).unwrap();
    res.as_object_mut().unwrap().remove("curve_stderr_method");
    let res: KernelResult = serde_json::from_value(res).unwrap();
    assert_eq!(res.curve_stderr_method, "none");
    // two images: a jackknife over the tiles of both; three: over images
    let mut two = s.clone();
    two.merge(&s).unwrap();
    let r2 = kernel_estimates(&two, &opts).unwrap();
    assert_eq!(
        r2.curve_stderr_method,
        "jackknife over 32 tiles (100 px) of 2 images"
    );
    let mut three = two.clone();
    three.merge(&s).unwrap();
    assert!(
        three
            .images
            .iter()
            .all(|im| im.cf_tiles.is_none() && im.tiles.is_empty())
    );
    assert_eq!(
        kernel_estimates(&three, &opts).unwrap().curve_stderr_method,
        "jackknife over images"
    );
    // sums of the wrong shape are refused
    for cut in 0..3 {
        let mut bad = s.clone();
        let c = bad.images[0].cf_tiles.as_mut().unwrap();
        match cut {
            0 => c.re[3].pop().map(drop).unwrap(),
            1 => c.im.truncate(15),
            _ => c.n[0].push(1),
        }
        assert!(bad.check().is_err(), "cut {cut}");
    }
}

/// The leave-one-out combines from running sums from both ends equal the
/// refold without each item (here exact: small integers), and the
/// characteristic-function tiles of a big domain are coarsened to at most
/// 16 a side.
#[test]
fn leave_one_out_sums_and_coarse_cf_tiles() {
    let items: Vec<u64> = (1..=9).map(|i| i * i).collect();
    let refs: Vec<&u64> = items.iter().collect();
    let loo = crate::stats::fit::leave_one_out(&refs, 0u64, |a, b| a + b);
    let total: u64 = items.iter().sum();
    assert_eq!(loo, items.iter().map(|i| total - i).collect::<Vec<_>>());
    // order kept: string concatenation is associative, not commutative
    let words: Vec<String> = ["a", "b", "c", "d"].map(String::from).to_vec();
    let refs: Vec<&String> = words.iter().collect();
    let loo = crate::stats::fit::leave_one_out(&refs, String::new(), |a, b| format!("{a}{b}"));
    assert_eq!(loo, ["bcd", "acd", "abd", "abc"]);
    assert_eq!(cf_tile_side((0, 400, 0, 400), 100), 100);
    assert_eq!(cf_tile_side((144, 3952, 144, 3952), 45), 238);
    let g = crate::spectra::TileGrid::new((144, 3952, 144, 3952), 238).unwrap();
    assert_eq!(g.len(), 256);
}

/// The scales (octaves 0-2 in quarters) and options (fit 0-2, one pair
/// 0:2) of the Gaussian `ln M` tests, whose `κ2(a)` is [`kap2`].
fn gaussian_setup() -> (Vec<f64>, KernelOptions) {
    let scales = (0..9).map(|j| 2f64.powf(j as f64 / 4.0)).collect();
    let opts = KernelOptions {
        fit: (0.0, 2.0),
        refs: vec![],
        pairs: vec![(0.0, 2.0)],
    };
    (scales, opts)
}

/// `κ2(a)` of the Gaussian `ln M` tests: `c2 = 0.03`.
fn kap2(a: f64) -> f64 {
    0.3 - 0.03 * a.ln()
}

/// `ln |Ĝ|` within 5 jackknife errors of the Gaussian kernel
/// `-(κ2(a) - κ2(a')) p² / 2` where `|C|` is well above `1/sqrt(n)` (p <=
/// 2.5; t with 7 or 15 degrees of freedom).
fn within_five_errors_of_gaussian(kc: &KernelCurve, kap2: fn(f64) -> f64) {
    let (a, b) = (kc.a, kc.a_ref);
    for (k, &p) in
        kc.p.iter()
            .enumerate()
            .filter(|(_, p)| **p > 0.0 && **p <= 2.5)
    {
        let theory = -(kap2(a) - kap2(b)) * p * p / 2.0;
        let (v, se) = (kc.ln_abs_g[k], kc.ln_abs_g_stderr[k]);
        assert!(
            (v - theory).abs() < 5.0 * se,
            "p = {p}: {v} vs {theory} +- {se}"
        );
    }
}

/// The curve's four errors (ln|G|, phase, |C| at a and a') at a few p are
/// the jackknife of the curves `reps` recomputed without each group, to
/// `tol` relative (the running sums of tiles add in another order).
fn errors_are_the_jackknife_of(kc: &KernelCurve, reps: &[KernelCurve], tol: f64) {
    let mid = kc.p.len() / 2;
    let abs = |re: f64, im: f64| re.hypot(im);
    for k in [mid + 10, mid + 40, mid + 80, mid - 60] {
        for (se, v) in [
            (
                kc.ln_abs_g_stderr[k],
                reps.iter().map(|c| c.ln_abs_g[k]).collect::<Vec<_>>(),
            ),
            (
                kc.phase_stderr[k],
                reps.iter().map(|c| c.phase[k]).collect(),
            ),
            (
                kc.cf_abs_stderr[k],
                reps.iter().map(|c| abs(c.cf_re[k], c.cf_im[k])).collect(),
            ),
            (
                kc.cf_ref_abs_stderr[k],
                reps.iter()
                    .map(|c| abs(c.cf_ref_re[k], c.cf_ref_im[k]))
                    .collect(),
            ),
        ] {
            let want = crate::stats::jackknife_se(&v);
            assert!(
                se > 0.0 && (se - want).abs() <= tol * want,
                "p = {}: {se} vs {want}",
                kc.p[k]
            );
        }
    }
}
