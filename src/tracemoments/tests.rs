use super::*;

/// alpha is warned about beyond [0, 2] only by more than 2 of its
/// errors (a log-normal field's 2.013 +- 0.139 is no anomaly), by any
/// amount without an error.
#[test]
fn alpha_beyond_the_universal_range_by_its_errors() {
    assert!(!outside_universal(2.013, 0.139));
    assert!(!outside_universal(1.0, 0.1));
    assert!(outside_universal(2.5, 0.1));
    assert!(outside_universal(2.01, f64::NAN));
    assert!(outside_universal(-0.3, 0.1));
    assert!(!outside_universal(f64::NAN, 0.1));
}

/// A q grid the universal fit cannot use gives K(q), no alpha, and a
/// warning saying why; an unsorted or repeated grid is refused.
#[test]
fn q_grids_the_universal_fit_cannot_use_are_said() {
    let f = Field::new(
        crate::synth::fbm::fbm(crate::synth::fbm::FbmParams { hurst: 0.5 }, 64, 64, 1, 0).unwrap(),
    );
    let cfg = TraceMomentConfig {
        q: vec![0.5, 2.5, 3.0],
        ..Default::default()
    };
    let mut acc = TraceMomentAccumulator::new(cfg).unwrap();
    acc.add_field(&f).unwrap();
    let r = acc.finish(&TraceMomentFitConfig::default()).unwrap();
    assert!(r.k.iter().all(|k| k.is_finite()));
    assert!(r.alpha.is_nan());
    assert!(
        r.warnings
            .iter()
            .any(|w| w.contains("needs 3 or more orders there (1 given)")),
        "{:?}",
        r.warnings
    );
    for q in [vec![1.0, 0.5, 2.0], vec![0.5, 0.5, 1.0]] {
        let cfg = TraceMomentConfig {
            q,
            ..Default::default()
        };
        let e = TraceMomentAccumulator::new(cfg).unwrap_err().to_string();
        assert!(e.contains("ascending"), "{e}");
    }
}

/// `analyze_tiled` is the tile recipe written out: tiles of the largest
/// fitted box, pooled, jackknifed; with the warnings a lone image needs.
#[test]
fn analyze_tiled_is_the_tile_recipe() {
    let f = Field::new(
        crate::synth::fif::fif(&crate::synth::fif::FifParams::TOPO, 256, 256, 5, 0).unwrap(),
    );
    let cfg = TraceMomentConfig::default();
    let fc = TraceMomentFitConfig {
        universal: UniversalWeighting::Ols,
        ..Default::default()
    };
    // 256 px, fit from log2 λ = 1: blocks of 128 px
    assert_eq!(tile_side(256, &fc), 128);
    assert_eq!(tile_side(8, &fc), 8);
    let (whole, res) = analyze_tiled(std::slice::from_ref(&f), &cfg, &fc).unwrap();
    let (w, t) = TraceMomentAccumulator::field_tiles(&cfg, &f, 128).unwrap();
    let (w, t) = pool_tiles(vec![(w, t)]).unwrap();
    let label = tiles_label(&tile_bounds(256, 256, 128), 128);
    assert_eq!(label, "tiles of 128 px (covering every pixel)");
    let mut want = finish_jackknife(&w, &t, &fc, &label).unwrap();
    assert_eq!(whole.images, w.images);
    assert_eq!(res.k, want.k);
    assert_eq!(res.alpha_stderr, want.alpha_stderr);
    assert_eq!(res.stderr_method, want.stderr_method);
    // 4 tiles: 3 degrees of freedom, and what tiles cannot see
    want.warnings.extend(crate::stats::fit::few_groups_warning(
        4,
        "a jackknife over 4 tiles of one image",
    ));
    want.warnings.push(TILE_CAVEAT.to_string());
    assert_eq!(res.warnings, want.warnings);
    assert!(analyze_tiled(&[], &cfg, &fc).is_err());
}

/// A fit range beyond the image's scales is refused from the sizes,
/// before any moment: a constant image, which the moments would refuse,
/// gets the range error, and an accepted range is the one `finish` uses.
#[test]
fn lambda_fit_is_checked_before_the_moments() {
    let flat = Field::new(Array2::from_elem((256, 256), 1.0));
    assert_eq!(box_levels(256), 8);
    assert_eq!(box_levels(300), 8);
    assert_eq!(box_levels(0), 0);
    let cfg = TraceMomentConfig::default();
    for (r, why) in [
        ((0.0, 9.0), "goes beyond the scales"),
        ((-1.0, 4.0), "goes beyond the scales"),
        ((6.5, 8.0), "fewer than 3 scales"),
    ] {
        let fc = TraceMomentFitConfig {
            log2_lambda: Some(r),
            ..Default::default()
        };
        for e in [
            analyze_tiled(std::slice::from_ref(&flat), &cfg, &fc).unwrap_err(),
            analyze(&flat, cfg.clone(), &fc).unwrap_err(),
        ] {
            assert!(
                matches!(e, Error::Param { .. }) && e.to_string().contains(why),
                "{r:?}: {e}"
            );
        }
    }
    // the default and a valid range pass the check; the constant image
    // is then refused by the moments
    let fc = TraceMomentFitConfig::default();
    assert_eq!(fc.lambda_range(8).unwrap(), (1.0, 7.0));
    assert_eq!(fc.lambda_range(3).unwrap(), (0.0, 3.0));
    assert!(fc.lambda_range(1).is_err());
    let e = analyze(&flat, cfg.clone(), &fc).unwrap_err();
    assert!(matches!(e, Error::Input(_)), "{e}");
    // an image too small for any moment is said to be so, not blamed on
    // a fit range nobody gave
    let tiny = Field::new(Array2::from_shape_fn((3, 64), |(y, x)| (x * y) as f64));
    for e in [
        analyze(&tiny, cfg.clone(), &fc).unwrap_err(),
        analyze_tiled(std::slice::from_ref(&tiny), &cfg, &fc).unwrap_err(),
    ] {
        assert!(e.to_string().contains("too small"), "{e}");
    }
    // non-square, and two sizes: the larger's smaller side sets kmax
    let wide = Field::new(Array2::from_shape_fn((40, 300), |(y, x)| {
        ((x * 7 + y * 3) % 11) as f64
    }));
    let fc9 = TraceMomentFitConfig {
        log2_lambda: Some((0.0, 6.0)),
        ..Default::default()
    };
    // 40 px: log2 λ up to 5
    let e = analyze(&wide, cfg.clone(), &fc9).unwrap_err();
    assert!(e.to_string().contains("runs from 0 to 5"), "{e}");
    let big = Field::new(Array2::from_shape_fn((70, 64), |(y, x)| {
        ((x * 5 + y * 9) % 13) as f64
    }));
    // (0, 6) passes the sizes (64 px), but only the 70 x 64 image holds
    // 64-px boxes: its replicate cannot leave it out
    let e = analyze_tiled(&[wide.clone(), big.clone()], &cfg, &fc9).unwrap_err();
    assert!(
        e.to_string().contains("so a jackknife cannot leave it out"),
        "{e}"
    );
    let fc7 = TraceMomentFitConfig {
        log2_lambda: Some((0.0, 7.0)),
        ..Default::default()
    };
    let e = analyze_tiled(&[wide, big], &cfg, &fc7).unwrap_err();
    assert!(e.to_string().contains("runs from 0 to 6"), "{e}");
}

/// The check from the sizes alone refuses exactly the fits that
/// [`finish_ensemble`] refuses after the moments, with the same reason.
#[test]
fn ensemble_fit_is_checked_from_the_sizes() {
    let cfg = TraceMomentConfig::default();
    let field = |side: usize, i: u64| {
        let p = crate::synth::fbm::FbmParams { hurst: 0.5 };
        Field::new(crate::synth::fbm::fbm(p, side, side, 7, i).unwrap())
    };
    let mut refused = 0;
    for sides in [
        vec![64, 64, 64],
        vec![64, 64, 128],
        vec![32, 32, 128],
        vec![32, 128, 128],
        vec![16, 16, 16, 16, 16, 128],
    ] {
        let parts: Vec<TraceMomentAccumulator> = sides
            .iter()
            .enumerate()
            .map(|(i, &n)| {
                let mut a = TraceMomentAccumulator::new(cfg.clone()).unwrap();
                a.add_field(&field(n, i as u64)).unwrap();
                a
            })
            .collect();
        let shapes: Vec<[usize; 2]> = sides.iter().map(|&n| [n, n]).collect();
        let ranges = [None, Some((0.0, 4.0)), Some((1.0, 5.0)), Some((2.0, 5.0))];
        let lags = [None, Some((1.0, 2.0)), Some((0.0, 5.0))];
        for (range, lag) in ranges.into_iter().flat_map(|r| lags.map(|l| (r, l))) {
            for universal in [UniversalWeighting::Ols, UniversalWeighting::Gls] {
                let fc = TraceMomentFitConfig {
                    log2_lambda: range,
                    log2_lag: lag,
                    universal,
                    ..Default::default()
                };
                let early = check_ensemble_fit(&fc, &shapes);
                let late = finish_ensemble(&parts, &fc);
                let what = format!("{sides:?} {range:?} {lag:?} {universal:?}");
                match (early, late) {
                    (Ok(()), Ok(_)) => {}
                    (Err(e), Err(l)) => {
                        refused += 1;
                        let (e, l) = (e.to_string(), l.to_string());
                        // the same reason (the late one names the part)
                        let tail = |m: &str| m.split(" holds").last().unwrap().to_string();
                        assert_eq!(tail(&e), tail(&l), "{what}: {e} / {l}");
                    }
                    (e, l) => panic!("{what}: early {e:?}, late {:?}", l.err()),
                }
            }
        }
    }
    // lone largest boxes (64 px of 128 under the default range, and
    // explicit ranges from 0 or 1 with 32-px neighbours), lone lags
    // (16 px under the default lag range beside 32-px images, whose
    // lags end at 8 px) and ranges beyond the data are among them;
    // lags up to 4 px pass there
    assert!(refused >= 8, "{refused}");
    let fc = |lag| TraceMomentFitConfig {
        log2_lambda: Some((2.0, 5.0)),
        log2_lag: lag,
        ..Default::default()
    };
    let mixed = [[32, 32], [32, 32], [128, 128]];
    let e = check_ensemble_fit(&fc(None), &mixed).unwrap_err();
    assert!(e.to_string().contains("lags of 16 px"), "{e}");
    assert!(check_ensemble_fit(&fc(Some((1.0, 2.0))), &mixed).is_ok());
    let e = check_ensemble_fit(&fc(Some((0.0, 6.0))), &mixed).unwrap_err();
    assert!(e.to_string().contains("goes beyond the lags"), "{e}");
    // no size, nothing to check; a bad range still is
    assert!(check_ensemble_fit(&TraceMomentFitConfig::default(), &[]).is_ok());
    // review cases: images of 12 px (lags 1 and 2 px; the default lag
    // range reaches 4 px, which no image holds: no lone lag), a
    // fractional start (log2 λ = 0.5 fits levels 1.., which every image
    // holds), an image too small for any moment (named by the moments)
    let accs = |sides: &[usize], cfg: &TraceMomentConfig| -> Vec<TraceMomentAccumulator> {
        sides
            .iter()
            .enumerate()
            .map(|(i, &n)| {
                let mut a = TraceMomentAccumulator::new(cfg.clone()).unwrap();
                a.add_field(&field(n, 20 + i as u64)).unwrap();
                a
            })
            .collect()
    };
    let order1 = TraceMomentConfig {
        diff: FluxDiff::Order(1.0),
        ..cfg.clone()
    };
    let fc = TraceMomentFitConfig::for_tiles();
    check_ensemble_fit(&fc, &[[12, 12]; 3]).unwrap();
    finish_ensemble(&accs(&[12, 12, 12], &order1), &fc).unwrap();
    let half = TraceMomentFitConfig {
        log2_lambda: Some((0.5, 5.0)),
        ..TraceMomentFitConfig::for_tiles()
    };
    check_ensemble_fit(&half, &[[128, 128], [64, 64], [64, 64]]).unwrap();
    finish_ensemble(&accs(&[128, 64, 64], &cfg), &half).unwrap();
    let e = check_ensemble_fit(&half, &[[128, 128], [32, 32], [32, 32]]).unwrap_err();
    assert!(e.to_string().contains("boxes of 64 px"), "{e}");
    check_ensemble_fit(
        &TraceMomentFitConfig::default(),
        &[[6, 6], [64, 64], [64, 64]],
    )
    .unwrap();
    // two images hold the largest boxes: the plain jackknife runs, the
    // GLS fit's nested one (two parts left out) cannot and falls back to
    // OLS, saying why
    let sides = [16, 16, 16, 16, 128, 128];
    let parts: Vec<TraceMomentAccumulator> = sides
        .iter()
        .enumerate()
        .map(|(i, &n)| {
            let mut a = TraceMomentAccumulator::new(cfg.clone()).unwrap();
            a.add_field(&field(n, 10 + i as u64)).unwrap();
            a
        })
        .collect();
    let fc = TraceMomentFitConfig {
        log2_lambda: Some((1.0, 5.0)),
        log2_lag: Some((1.0, 2.0)),
        universal: UniversalWeighting::Gls,
        ..Default::default()
    };
    let shapes: Vec<[usize; 2]> = sides.iter().map(|&n| [n, n]).collect();
    check_ensemble_fit(&fc, &shapes).unwrap();
    let (_, r) = finish_ensemble(&parts, &fc).unwrap();
    assert!(
        r.universal_fit.starts_with("ols") && r.universal_fit.contains("lacks the fitted boxes"),
        "{}",
        r.universal_fit
    );
    assert!(r.alpha_stderr.is_finite(), "{}", r.alpha_stderr);
}
