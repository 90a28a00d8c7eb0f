//! The library's contract on bad input: an `Err` naming the problem, never
//! a panic or a silent wrong number (found by a review that drove the
//! public API as a user's program would).

use ndarray::Array2;
use wtmm::Field;
use wtmm::skeleton::{AnalysisConfig, LinkParams, SearchRadius, skeleton};
use wtmm::spectra::{PartitionSums, Rule, default_fit, image_sums};
use wtmm::stats::powspec::{PowerSpectrumConfig, power_spectrum};
use wtmm::synth::fbm::{FbmParams, fbm};
use wtmm::synth::fif::{FifParams, fif};
use wtmm::synth::wcascade::{Basis, Isotropy, Law, WCascadeParams, wcascade};
use wtmm::tracemoments::{TraceMomentAccumulator, TraceMomentConfig, TraceMomentFitConfig};

fn surface(n: usize) -> Field {
    Field::new(fbm(FbmParams { hurst: 0.5 }, n, n, 1, 0).unwrap())
}

/// The default analysis over `octaves` octaves on the whole torus.
fn torus(octaves: usize) -> AnalysisConfig {
    AnalysisConfig {
        octaves,
        margin: Some(0),
        ..Default::default()
    }
}

fn err<T: std::fmt::Debug>(r: wtmm::Result<T>, needle: &str) {
    let e = r.expect_err("bad input accepted").to_string();
    assert!(e.contains(needle), "{e:?} does not mention {needle:?}");
}

#[test]
fn a_proportional_box_must_be_finite() {
    for (factor, min) in [(f64::INFINITY, 1.0), (1.0, f64::INFINITY), (f64::NAN, 1.0)] {
        let cfg = AnalysisConfig {
            octaves: 2,
            margin: Some(0),
            link: LinkParams {
                radius: SearchRadius::Proportional { factor, min },
                ..Default::default()
            },
            ..Default::default()
        };
        err(skeleton(&surface(64), &cfg), "radius");
    }
}

#[test]
fn spectra_refuse_bad_q_and_fit_ranges() {
    let cfg = torus(3);
    let f = surface(128);
    for q in [
        vec![0.0, f64::NAN, 2.0],
        vec![0.0, 1.0, 1.0],
        vec![2.0, 0.0],
    ] {
        // refused before the transform; and sums carrying such a grid
        // (edited, or built from a skeleton) are refused at the fit
        err(image_sums(&f, &cfg, &q, "x"), "`q`");
        let mut s = image_sums(&f, &cfg, &[0.0, 2.0], "x").unwrap();
        if q.len() == 2 {
            s.q = q.clone();
            err(s.spectra(Rule::Plain, (0.5, 3.0)), "`q`");
        }
    }
    let s = image_sums(&f, &cfg, &[0.0, 2.0], "x").unwrap();
    // 3 octaves of 10 voices: 0 <= lo < hi <= 3
    for fit in [(-5.0, 0.5), (0.5, 100.0), (2.0, 1.0), (f64::NAN, 2.0)] {
        err(s.spectra(Rule::Plain, fit), "fit");
    }
    assert!(s.spectra(Rule::Plain, (0.5, 3.0)).is_ok());
    // an end between two voices would fit from the next scale and be
    // recorded as given
    err(s.spectra(Rule::Plain, (0.55, 3.0)), "between two scales");
    let mut empty = s.clone();
    empty.scales.clear();
    err(empty.spectra(Rule::Plain, (0.5, 3.0)), "scales");
}

#[test]
fn power_spectra_refuse_bad_bins_and_mixed_merges() {
    let img = surface(64).data;
    let bad = PowerSpectrumConfig {
        bins_per_octave: usize::MAX,
        ..Default::default()
    };
    err(power_spectrum(img.view(), &bad), "bins-per-octave");
    let four = power_spectrum(img.view(), &PowerSpectrumConfig::default()).unwrap();
    let eight = power_spectrum(
        img.view(),
        &PowerSpectrumConfig {
            bins_per_octave: 8,
            ..Default::default()
        },
    )
    .unwrap();
    let mut m = four.clone();
    err(m.merge(&eight), "bins");
    assert_eq!(m, four, "a refused merge changes nothing");
}

#[test]
fn trace_moments_refuse_bad_masks_and_fit_settings() {
    let mut acc = TraceMomentAccumulator::new(TraceMomentConfig::default()).unwrap();
    let phi = Array2::from_elem((16, 16), 1.0);
    let mask = Array2::from_elem((8, 8), false);
    err(acc.add_flux(phi.view(), Some(mask.view())), "mask");
    acc.add_field(&surface(64)).unwrap();
    assert!(acc.finish(&TraceMomentFitConfig::default()).is_ok());
    for q in [0.0, -1.0, f64::NAN] {
        let fc = TraceMomentFitConfig {
            q_fit_max: Some(q),
            ..Default::default()
        };
        err(acc.finish(&fc), "q-fit-max");
    }
    let fc = TraceMomentFitConfig {
        eta: (5.0, 1.0),
        ..Default::default()
    };
    err(acc.finish(&fc), "eta-fit");
    // a refused field leaves the accumulator as it was (it used to add the
    // flux, then fail on the spectrum, and a later finish had no beta)
    let before = acc.clone();
    let huge = surface(64).data.mapv(|v| (v + 5.0) * 1e100);
    err(acc.add_field(&Field::new(huge)), "1e100");
    assert_eq!(acc, before);
}

#[test]
fn generators_refuse_sizes_beyond_the_pixel_limit() {
    err(fbm(FbmParams { hurst: 0.5 }, usize::MAX, 2, 1, 0), "limit");
    err(fif(&FifParams::TOPO, 1 << 40, 1 << 40, 1, 0), "limit");
    let p = WCascadeParams {
        law: Law::LogNormal {
            m: -0.38 * std::f64::consts::LN_2,
            sigma2: 0.03 * std::f64::consts::LN_2,
        },
        isotropy: Isotropy::Isotropic,
        basis: Basis::Db8,
    };
    err(wcascade(&p, 1 << 40, 1, 0), "limit");
}

/// Sums of the same analysis merge however it was written down (explicit
/// scales equal to the grid, the default margin given as its pixels);
/// another margin or wavelet does not.
#[test]
fn merging_compares_analyses_by_what_they_do() {
    let f = surface(96);
    let q = [0.0, 2.0];
    let grid = AnalysisConfig {
        octaves: 2,
        ..Default::default()
    };
    let spelled = AnalysisConfig {
        scales: Some(grid.scale_list()),
        margin: Some(grid.margin_px()),
        ..grid.clone()
    };
    let a = image_sums(&f, &grid, &q, "a").unwrap();
    let mut m = a.clone();
    m.merge(&image_sums(&f, &spelled, &q, "b").unwrap())
        .unwrap();
    assert_eq!(m.images.len(), 2);
    let other = AnalysisConfig {
        margin: Some(grid.margin_px() + 2),
        ..grid.clone()
    };
    err(
        a.clone().merge(&image_sums(&f, &other, &q, "c").unwrap()),
        "margin",
    );
}

/// A constant image has no maxima at all, and the error says it is
/// constant rather than blaming the counting domain, as soon as its sums
/// are made; one whose scattered holes leave no pixel to count says that
/// instead. Sums without lines made otherwise (from a skeleton) fail at
/// the fit, calling the image flat.
#[test]
fn a_constant_image_is_called_constant() {
    let cfg = torus(2);
    let flat = Field::new(Array2::from_elem((64, 64), 3.0));
    err(
        image_sums(&flat, &cfg, &[0.0], "c"),
        "constant image (every valid pixel is 3)",
    );
    let sk = wtmm::skeleton::skeleton(&flat, &cfg).unwrap();
    let s = wtmm::spectra::skeleton_sums(&sk, &flat, &cfg, &[0.0], "c");
    err(s.spectra(Rule::Plain, (0.5, 2.0)), "flat");
    // 2 % of the pixels missing, scattered: no pixel far enough from them
    let mut f =
        wtmm::synth::fbm::fbm(wtmm::synth::fbm::FbmParams { hurst: 0.4 }, 128, 128, 1, 0).unwrap();
    let mut x = 0x9e37_79b9_7f4a_7c15u64;
    for _ in 0..328 {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        f[[(x % 128) as usize, ((x >> 32) % 128) as usize]] = f64::NAN;
    }
    err(
        image_sums(&Field::new(f), &torus(3), &[0.0], "h"),
        "missing pixels",
    );
    // a step edge: its lines die at once in a domain wide enough for the
    // scales, which is said (helper-79: "the counting domain is too
    // small" for a 184 px domain), while a domain too small still is
    let step = Array2::from_shape_fn((256, 256), |(_, x)| f64::from(u8::from(x >= 128)));
    let three = AnalysisConfig {
        octaves: 3,
        ..Default::default()
    };
    let s = image_sums(&Field::new(step), &three, &[0.0, 2.0], "step").unwrap();
    let e = s.spectra(Rule::Plain, (0.5, 3.0)).unwrap_err().to_string();
    assert!(
        e.contains("184 px across, holds 2.6 wavelet supports"),
        "{e}"
    );
    assert!(!e.contains("too small"), "{e}");
    let small = fbm(FbmParams { hurst: 0.4 }, 300, 300, 6, 0).unwrap();
    let five = AnalysisConfig::default();
    let s = image_sums(&Field::new(small), &five, &[0.0, 2.0], "small").unwrap();
    err(
        s.spectra(Rule::Plain, default_fit(5, 10)),
        "the counting domain is too small for these scales",
    );
}

/// Periodic fields are analysed on the whole torus, others inside the
/// default margin; the main types are reachable from the crate root.
#[test]
fn analysis_defaults_follow_the_kind_of_field() {
    assert_eq!(wtmm::AnalysisConfig::for_field(true).margin_px(), 0);
    let plain = wtmm::AnalysisConfig::for_field(false);
    assert_eq!(plain, AnalysisConfig::default());
    assert_eq!(
        plain.margin_px(),
        (3.2f64 * 1.5 * 2f64.powf(4.9)).ceil() as usize
    );
}

#[test]
fn the_default_fit_lies_on_every_grid() {
    assert_eq!(default_fit(5, 10), (0.5, 4.0));
    assert_eq!(default_fit(3, 10), (0.5, 3.0));
    // odd voices have no scale at half an octave: the first one above it
    // (the CLI's default failed with --voices 3 before)
    for (voices, lo) in [(3, 2.0 / 3.0), (1, 1.0), (5, 0.6), (4, 0.5)] {
        let (l, h) = default_fit(5, voices);
        assert!((l - lo).abs() < 1e-12 && h == 4.0, "{voices}: {l}");
        let cfg = AnalysisConfig { voices, ..torus(3) };
        let s = image_sums(&surface(128), &cfg, &[0.0, 2.0], "x").unwrap();
        let fit = s.default_fit().unwrap();
        assert_eq!(fit, default_fit(3, voices));
        if voices > 1 {
            let sp = s.spectra(Rule::Plain, fit).unwrap();
            assert!((sp.fit_scales.0 / 1.5 - lo.exp2()).abs() < 1e-9);
        }
    }
}

#[test]
fn sums_round_trip_through_json() {
    let dir = std::env::temp_dir().join(format!("wtmm-sums-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("sums.json");
    let s = image_sums(&surface(128), &torus(3), &[-1.0, 0.0, 2.0], "x").unwrap();
    s.write_json(&path).unwrap();
    let back = PartitionSums::read_json(&path).unwrap();
    let fit = s.default_fit().unwrap();
    let (a, b) = (
        s.spectra(Rule::Plain, fit).unwrap(),
        back.spectra(Rule::Plain, fit).unwrap(),
    );
    assert_eq!(a.tau, b.tau);
    assert_eq!(back.analysis, s.analysis);
    std::fs::write(&path, "{\"q\": [1]}").unwrap();
    err(PartitionSums::read_json(&path), "sums.json");
    err(PartitionSums::read_json(dir.join("none.json")), "none.json");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Tiles narrower than twice the largest scale share their maxima lines:
/// refused as jackknife groups; the default side passes.
#[test]
fn tiles_narrower_than_the_lines_are_refused() {
    let f = Field::new(
        wtmm::synth::fbm::fbm(wtmm::synth::fbm::FbmParams { hurst: 0.4 }, 128, 128, 2, 0).unwrap(),
    );
    let cfg = torus(2);
    let par = wtmm::skeleton::Parallelism::Serial;
    // a_max = 1.5 * 2^(2 - 1/10) = 5.57 px: tiles from 12 px
    err(
        wtmm::spectra::image_sums_tiled(&f, &cfg, &[0.0], "t", par, 11),
        "narrower than twice the largest scale",
    );
    let side = wtmm::spectra::default_tile_side(&cfg, 128, 128);
    assert!(side >= 12, "{side}");
    wtmm::spectra::image_sums_tiled(&f, &cfg, &[0.0], "t", par, side).unwrap();
}

/// `ensemble_sums` is `analyze`'s recipe on fields in memory: tiles for a
/// lone image, one part per image from 3 images; an image without lines
/// is named by its index.
#[test]
fn ensemble_sums_is_the_recipe_of_analyze() {
    use wtmm::skeleton::Parallelism;
    use wtmm::spectra::{default_tile_side, ensemble_sums, image_sums_tiled};
    let cfg = torus(2);
    let q = [-1.0, 0.0, 2.0];
    let fields: Vec<Field> = (0..3)
        .map(|i| {
            Field::new(
                wtmm::synth::fbm::fbm(wtmm::synth::fbm::FbmParams { hurst: 0.4 }, 96, 96, 5, i)
                    .unwrap(),
            )
        })
        .collect();
    let bits = |s: &wtmm::Spectra| {
        (s.tau.iter().chain(&s.tau_stderr))
            .map(|x| x.to_bits())
            .collect::<Vec<_>>()
    };
    // one image: tiles
    let one = ensemble_sums(&fields[..1], &cfg, &q).unwrap();
    let side = default_tile_side(&cfg, 96, 96);
    let by_hand =
        image_sums_tiled(&fields[0], &cfg, &q, "image 0", Parallelism::Scales, side).unwrap();
    let (a, b) = (
        one.spectra(Rule::Plain, (0.5, 1.5)).unwrap(),
        by_hand.spectra(Rule::Plain, (0.5, 1.5)).unwrap(),
    );
    assert_eq!(bits(&a), bits(&b));
    assert!(a.stderr_method.contains("tiles"), "{}", a.stderr_method);
    // three: over the images
    let three = ensemble_sums(&fields, &cfg, &q).unwrap();
    let merged = PartitionSums::merge_all(
        fields
            .iter()
            .enumerate()
            .map(|(i, f)| image_sums(f, &cfg, &q, format!("image {i}")).unwrap()),
    )
    .unwrap()
    .unwrap();
    let (a, b) = (
        three.spectra(Rule::Plain, (0.5, 1.5)).unwrap(),
        merged.spectra(Rule::Plain, (0.5, 1.5)).unwrap(),
    );
    assert_eq!(bits(&a), bits(&b));
    assert_eq!(a.stderr_method, "jackknife over images");
    let mut bad = fields.clone();
    bad[2] = Field::new(Array2::from_elem((96, 96), 1.0));
    err(ensemble_sums(&bad, &cfg, &q), "image 2: ");
    err(ensemble_sums(&[], &cfg, &q), "no field");
}

/// `ensemble_correlation_sums` is `correlate`'s recipe on fields in
/// memory: a lone image split into the tiles of `default_tile_side` (so
/// that it has errors), one part per image from 3 images, in order; a bad
/// image is named by its index (found by helper-79's library-user review:
/// the obvious route, `cwt_correlation` on a lone DEM, gives no errors).
#[test]
fn ensemble_correlation_sums_is_the_recipe_of_correlate() {
    use wtmm::stats::correlation::{
        CorrelationConfig, CorrelationPlan, CorrelationSums, correlation_estimates,
        cwt_correlation, cwt_correlation_tiled, default_tile_side, ensemble_correlation_sums,
    };
    let cfg = CorrelationConfig {
        scales: vec![2.0, 4.0],
        pairs: vec![(0, 1), (1, 1)],
        ..Default::default()
    };
    let fields: Vec<Field> = (0..3)
        .map(|i| Field::new(fbm(FbmParams { hurst: 0.4 }, 128, 128, 9, i).unwrap()))
        .collect();
    let bits = |s: &CorrelationSums| {
        let r = correlation_estimates(s).unwrap();
        let v: Vec<u64> = r
            .pairs
            .iter()
            .flat_map(|p| p.c.iter().chain(&p.c_stderr).map(|x| x.to_bits()))
            .collect();
        (v, r.stderr_method)
    };
    let plan = CorrelationPlan::new(128, 128, &cfg).unwrap();
    // one image: tiles, and errors
    let one = ensemble_correlation_sums(&fields[..1], &cfg).unwrap();
    let side = default_tile_side(plan.domain());
    let by_hand = cwt_correlation_tiled(&fields[0], &plan, "image 0", side).unwrap();
    let (a, b) = (bits(&one), bits(&by_hand));
    assert_eq!(a, b);
    assert!(a.1.contains("tiles"), "{}", a.1);
    let r = correlation_estimates(&one).unwrap();
    assert!(
        r.pairs[0]
            .c_stderr
            .iter()
            .any(|e| e.is_finite() && *e > 0.0)
    );
    // three: over the images, the merge of each image's sums
    let three = ensemble_correlation_sums(&fields, &cfg).unwrap();
    let mut merged = cwt_correlation(&fields[0], &plan, "image 0").unwrap();
    for (i, f) in fields.iter().enumerate().skip(1) {
        merged
            .merge(&cwt_correlation(f, &plan, format!("image {i}")).unwrap())
            .unwrap();
    }
    let (a, b) = (bits(&three), bits(&merged));
    assert_eq!(a, b);
    assert_eq!(a.1, "jackknife over images");
    // images of two sizes: refused, as correlate refuses them
    let mut mixed = fields.clone();
    mixed[1] = Field::new(fbm(FbmParams { hurst: 0.4 }, 96, 128, 9, 1).unwrap());
    err(
        ensemble_correlation_sums(&mixed, &cfg),
        "image 1 is 96x128, but image 0 is 128x128",
    );
    let mut bad = fields.clone();
    bad[2] = Field::new(Array2::from_elem((128, 128), 1.0));
    err(ensemble_correlation_sums(&bad, &cfg), "image 2: ");
    err(ensemble_correlation_sums(&[], &cfg), "no field");
    assert!(CorrelationSums::merge_all(Vec::new()).unwrap().is_none());
}

/// Found by helper-41's external-consumer review: absurd grids and margins,
/// a mask of another shape built through the public fields, and |q| beyond
/// what the sums' exponents hold are errors naming the problem (before:
/// overflow panics in debug builds, index panics, or an internal message),
/// and the small helpers answer `None` or an error where they used to
/// answer a plausible number.
#[test]
fn absurd_settings_are_errors_not_panics() {
    let f = surface(128);
    let q = [0.0, 1.0];
    for (cfg, needle) in [
        (
            AnalysisConfig {
                octaves: 100,
                ..Default::default()
            },
            "octaves",
        ),
        (
            AnalysisConfig {
                octaves: usize::MAX,
                ..Default::default()
            },
            "octaves",
        ),
        (
            AnalysisConfig {
                voices: usize::MAX,
                ..Default::default()
            },
            "voices",
        ),
        (
            AnalysisConfig {
                a_min: 1e300,
                ..Default::default()
            },
            "a-min",
        ),
        (
            AnalysisConfig {
                a_min: f64::INFINITY,
                ..Default::default()
            },
            "a-min",
        ),
    ] {
        err(image_sums(&f, &cfg, &q, "x"), needle);
        err(
            wtmm::spectra::ensemble_sums(std::slice::from_ref(&f), &cfg, &q),
            needle,
        );
        // sizing tiles from such a grid saturates instead of overflowing
        let _ = wtmm::spectra::default_tile_side(&cfg, 128, 128);
    }
    let huge = AnalysisConfig {
        margin: Some(usize::MAX),
        ..Default::default()
    };
    assert!(wtmm::spectra::ensemble_sums(std::slice::from_ref(&f), &huge, &q).is_err());
    assert_eq!(
        wtmm::cwt::ScaleGrid {
            octaves: 0,
            ..Default::default()
        }
        .a_max(),
        1.5
    );
    // a mask of another shape, set through the public fields
    let bad = Field {
        data: f.data.clone(),
        mask: Some(Array2::from_elem((10, 10), false)),
    };
    err(bad.check(), "the mask is 10x10 but the data are 128x128");
    err(image_sums(&bad, &torus(3), &q, "x"), "mask");
    err(skeleton(&bad, &torus(3)), "mask");
    let mut acc = TraceMomentAccumulator::new(TraceMomentConfig::default()).unwrap();
    err(acc.add_field(&bad), "mask");
    assert_eq!(bad.plane_share(), None);
    // |q| beyond MAX_ABS_Q: named, the value short
    err(
        image_sums(&f, &torus(3), &[-3e8, 0.0, 3e8], "x"),
        "beyond +-10000",
    );
    err(
        image_sums(&f, &torus(3), &[0.0, 1e300], "x"),
        "1.000e300 is beyond",
    );
    // helpers
    let (scales, pairs) = wtmm::stats::correlation::pair_scales(1.5, &[(f64::NAN, 1.0)]);
    assert!(scales.iter().any(|a| a.is_nan()) && pairs.len() == 1);
    let fbm_model = wtmm::Model::preset("paper-fbm").unwrap().model;
    err(fbm_model.check_size(0), "size");
    err(fbm_model.check_size(1), "size");
    assert!(fbm_model.check_size(2).is_ok() && fbm_model.synthesize(2, 1, 0).is_ok());
    let fif_model = wtmm::Model::preset("topo-fif").unwrap().model;
    err(fif_model.check_size(3), "size");
    assert!(fif_model.check_size(4).is_ok() && fif_model.synthesize(4, 1, 0).is_ok());
    let fisc = wtmm::Model::preset("paper-fisc").unwrap().model;
    assert_eq!(fisc.dh(f64::NAN), None);
    assert_eq!(fbm_model.dh(f64::NAN), None);
    let sums = image_sums(&f, &torus(3), &[-1.0, 0.0, 1.0], "x").unwrap();
    let sp = sums.spectra(Rule::Plain, default_fit(3, 10)).unwrap();
    assert_eq!(sp.q_index(f64::NAN), None);
    assert_eq!(sp.q_index(0.1), Some(1));
    // trace-moment settings the CLI refused and the library took
    for (cfg, needle) in [
        (
            TraceMomentConfig {
                eta: vec![2.0, 1.0],
                ..Default::default()
            },
            "ascending",
        ),
        (
            TraceMomentConfig {
                eta: vec![1.0, 1.0],
                ..Default::default()
            },
            "none twice",
        ),
        (
            TraceMomentConfig {
                frac_int: Some(-10.0),
                ..Default::default()
            },
            "|order| < 1",
        ),
    ] {
        err(cfg.validate(), needle);
    }
}

/// Deserialised shards are checked before they are merged or read (before:
/// a truncated list panicked on an index, and two box levels appended to
/// trace-moment sums moved alpha from 1.908 to 1.899 and H_sf from 0.615
/// to 0.571 without a word).
#[test]
fn edited_shards_are_refused() {
    use serde_json::{Value, from_value, json, to_value};
    use wtmm::stats::kernel::{KernelConfig, KernelOptions, KernelSums, kernel_estimates};
    use wtmm::stats::pdf::{PdfConfig, PdfOptions, WtmmmHistograms, WtmmmSet, wtmmm_pdfs};
    // edits `v` at the pointer `at` and reads the type back
    fn edited<T: serde::de::DeserializeOwned>(v: &Value, at: &str, new: Value) -> T {
        let mut v = v.clone();
        *v.pointer_mut(at).unwrap_or_else(|| panic!("{at}")) = new;
        from_value(v).unwrap()
    }
    // pdf histograms
    let mut h = WtmmmHistograms::new(&[1.5, 3.0], PdfConfig::default()).unwrap();
    for (j, m) in [(0, 1.0), (0, 2.0), (1, 3.0)] {
        h.add(j, m, 0.3);
    }
    h.check().unwrap();
    let v = to_value(&h).unwrap();
    let rows = v["hist"][0]["rows"].as_u64().unwrap();
    let bad: WtmmmHistograms = edited(&v, "/hist/0/rows", json!(rows + 9));
    err(bad.check(), "counts for");
    err(wtmmm_pdfs(&bad, &PdfOptions::default()), "counts for");
    let mut good = h.clone();
    err(good.merge(&bad), "counts for");
    let bad: WtmmmHistograms = edited(&v, "/hist/1/n", json!(7));
    err(bad.check(), "do not sum");
    let mut short = v.clone();
    short["hist"].as_array_mut().unwrap().pop();
    err(
        from_value::<WtmmmHistograms>(short).unwrap().check(),
        "1 histograms for 2 scales",
    );
    // kernel sums
    let k = KernelSums::from_ln_m(
        &[1.5, 3.0, 6.0],
        KernelConfig::default(),
        WtmmmSet::Lines,
        &[vec![0.1, 0.2], vec![0.3, 0.5], vec![0.7, 0.6]],
        "a",
    )
    .unwrap();
    k.check().unwrap();
    let v = to_value(&k).unwrap();
    let mut short = v.clone();
    short["images"][0]["moments"].as_array_mut().unwrap().pop();
    let bad: KernelSums = from_value(short).unwrap();
    err(bad.check(), "2 moments");
    err(
        kernel_estimates(&bad, &KernelOptions::default()),
        "2 moments",
    );
    let mut good = k.clone();
    err(good.merge(&bad), "2 moments");
    // trace-moment sums
    let cfg = TraceMomentConfig::default();
    let mut acc = TraceMomentAccumulator::new(cfg).unwrap();
    acc.add_field(&surface(64)).unwrap();
    acc.check().unwrap();
    let v = to_value(&acc).unwrap();
    let mut longer = v.clone();
    longer["box_count"]
        .as_array_mut()
        .unwrap()
        .extend([json!(1), json!(1)]);
    let grow = |l: &mut Value| {
        let x = l[0].clone();
        l.as_array_mut().unwrap().extend([x.clone(), x]);
    };
    longer["tm"]
        .as_array_mut()
        .unwrap()
        .iter_mut()
        .for_each(grow);
    for e in longer["dtm"].as_array_mut().unwrap() {
        e.as_array_mut().unwrap().iter_mut().for_each(grow);
    }
    let bad: TraceMomentAccumulator = from_value(longer).unwrap();
    err(bad.check(), "but images of at most 64 px hold 7");
    err(bad.finish(&TraceMomentFitConfig::for_tiles()), "box levels");
    let mut short = v.clone();
    short["tm"].as_array_mut().unwrap().pop();
    let bad: TraceMomentAccumulator = from_value(short).unwrap();
    err(bad.check(), "moment lists");
    let mut good = acc.clone();
    err(good.merge(&bad), "moment lists");
}

/// Shards of an interior and a torus analysis are refused, with the
/// margins in pixels (before: "margin: null vs 0").
#[test]
fn margins_that_differ_are_named_in_pixels() {
    let f = surface(128);
    let interior = AnalysisConfig {
        octaves: 3,
        ..Default::default()
    };
    let px = interior.margin_px();
    let mut a = image_sums(&f, &interior, &[0.0, 1.0], "i").unwrap();
    let b = image_sums(&f, &torus(3), &[0.0, 1.0], "t").unwrap();
    err(a.merge(&b), &format!("margin: {px} vs 0"));
}

/// A program's own structs holding the plans can derive `Debug`: the plans
/// print what they are for.
#[test]
fn plans_print_what_they_are_for() {
    use wtmm::cwt::{CwtPlan, Wavelet};
    use wtmm::stats::correlation::{CorrelationConfig, CorrelationPlan};
    let p = CwtPlan::new(64, 32, Wavelet::Gauss, &[1.5, 3.0]).unwrap();
    let s = format!("{p:?}");
    assert!(
        s.contains("ny: 64") && s.contains("nx: 32") && s.contains("scales: [1.5, 3.0]"),
        "{s}"
    );
    let c = CorrelationPlan::new(
        128,
        128,
        &CorrelationConfig::fig30(Wavelet::Gauss, 1.5, true),
    )
    .unwrap();
    let s = format!("{c:?}");
    assert!(
        s.starts_with("CorrelationPlan") && s.contains("ny: 128"),
        "{s}"
    );
    // Clones compute what their originals compute, the correlation plan's
    // cloned after a call has left a workspace in its pool.
    let f = surface(128);
    let cwt = |p: &CwtPlan| {
        let fi = p.forward(f.data.view()).unwrap();
        let mut ws = p.workspace();
        p.scale(&fi, 1, &mut ws).clone()
    };
    let p64 = CwtPlan::new(128, 128, Wavelet::Gauss, &[1.5, 3.0]).unwrap();
    assert_eq!(cwt(&p64), cwt(&p64.clone()));
    let first = wtmm::stats::correlation::cwt_correlation(&f, &c, "f").unwrap();
    let again = wtmm::stats::correlation::cwt_correlation(&f, &c.clone(), "f").unwrap();
    assert_eq!(first, again);
}
