//! Trace moments against mathematics (SPEC §8-§9): a discrete log-normal
//! cascade with exactly known K(q), and small FIF ensembles.
//!
//! Tolerances: every estimate is compared with its theory within `4 σ`,
//! where σ is the standard error of the ensemble estimate, a jackknife over
//! the images ([`finish_ensemble`], or computed in the test where the
//! library reports none) or the scatter of the per-image estimates
//! (`std / sqrt(n)`). Where an estimator bias `b ± se_b` was measured on
//! independent ensembles (the `experiment_*` functions) and resolved
//! (beyond 2 of its se_b), the check is a regression check on that
//! documented bias, theory + b within `4 sqrt(σ² + se_b²)`, and says so;
//! an unresolved bias is not used. The jackknife errors of tiles are
//! checked against a brute-force jackknife, to rounding.

use ndarray::Array2;
use rand_distr::{Distribution, StandardNormal};
use wtmm::Field;
use wtmm::stats::fit::mean_std;
use wtmm::synth::fif::{FifParams, fif, fif_with_flux};
use wtmm::synth::rng_for;
use wtmm::theory::fif as th;
use wtmm::tracemoments::*;

/// 2D log-normal multiplicative cascade on `2^n x 2^n`: at each of `n`
/// steps every square splits in 4 and each child's density is the parent's
/// times `W = exp(μ + s Z)`, `Z ~ N(0, 1)`, `μ = -s²/2` so that `<W> = 1`.
/// With `λ = 2^k`: `<φ_λ^q> = <W^q>^k`, `<W^q> = exp(q μ + q² s²/2)`, so
/// `K(q) = log2 <W^q> = (q² - q) s² / (2 ln 2)`: universal with α = 2 and
/// `C1 = K'(1) = s²/(2 ln 2)`.
fn cascade(n: usize, s: f64, seed: u64, index: u64) -> Array2<f64> {
    let mut rng = rng_for(seed, index);
    let mu = -s * s / 2.0;
    let mut a = Array2::<f64>::from_elem((1, 1), 1.0);
    for _ in 0..n {
        let m = a.nrows();
        let b = Array2::from_shape_fn((2 * m, 2 * m), |(y, x)| {
            let z: f64 = StandardNormal.sample(&mut rng);
            a[[y / 2, x / 2]] * (mu + s * z).exp()
        });
        a = b;
    }
    a
}

/// Ensemble result and per-image results.
fn ensemble(
    accs: &[TraceMomentAccumulator],
    fc: &TraceMomentFitConfig,
) -> (TraceMomentResult, Vec<TraceMomentResult>) {
    let mut all = accs[0].clone();
    for a in &accs[1..] {
        all.merge(a).unwrap();
    }
    let per = accs.iter().map(|a| a.finish(fc).unwrap()).collect();
    (all.finish(fc).unwrap(), per)
}

/// `K_a(q) - K_b(q)` of two accumulator lists over the same images (merged
/// each), with its delete-one jackknife error: paired, so the sampling
/// fluctuations the two share cancel.
fn paired_k_difference(
    a: &[TraceMomentAccumulator],
    b: &[TraceMomentAccumulator],
    q: f64,
    fc: &TraceMomentFitConfig,
) -> (f64, f64) {
    let k_at = |v: &[TraceMomentAccumulator], skip: Option<usize>| {
        let mut m = TraceMomentAccumulator::new(v[0].config.clone()).unwrap();
        for (j, x) in v.iter().enumerate() {
            if Some(j) != skip {
                m.merge(x).unwrap();
            }
        }
        let r = m.finish(fc).unwrap();
        r.k[r.q.iter().position(|&v| (v - q).abs() < 1e-9).unwrap()]
    };
    let d = |skip| k_at(a, skip) - k_at(b, skip);
    let loo: Vec<f64> = (0..a.len()).map(|i| d(Some(i))).collect();
    (d(None), wtmm::stats::jackknife_se(&loo))
}

/// Standard error of the ensemble estimate from the per-image scatter.
fn se(per: &[TraceMomentResult], f: impl Fn(&TraceMomentResult) -> f64) -> f64 {
    let v: Vec<f64> = per.iter().map(f).filter(|v| v.is_finite()).collect();
    mean_std(&v).1 / (v.len() as f64).sqrt()
}

/// The delete-one jackknife standard error written out from its definition
/// (Efron & Tibshirani 1993 §11; the formula `wtmm::stats::jackknife_se`
/// documents): `sqrt((n-1)/n Σ (x_i - mean)²)` over the leave-one-out
/// replicates `x`.
fn jackknife_by_definition(x: &[f64]) -> f64 {
    let n = x.len() as f64;
    let m = x.iter().sum::<f64>() / n;
    ((n - 1.0) / n * x.iter().map(|v| (v - m).powi(2)).sum::<f64>()).sqrt()
}

/// `a == b` to rounding: the same quantity computed twice, by the library
/// and here, through the same operations up to order (a few ulp, 1e-16
/// relative; 1e-10 leaves a wide margin and still fails on any real
/// difference, e.g. another q range or another leave-one-out sample). The
/// absolute 1e-14 covers the errors that are pure rounding scatter
/// themselves (K(0), K(1): 1e-17 to 1e-16).
fn assert_rounding(what: &str, a: f64, b: f64) {
    assert!(
        (a - b).abs() <= 1e-10 * a.abs().max(b.abs()) + 1e-14,
        "{what}: library {a} vs brute force {b}"
    );
}

/// The merge of `parts` without the indices in `skip`.
fn merge_except(parts: &[TraceMomentAccumulator], skip: &[usize]) -> TraceMomentAccumulator {
    let mut m = TraceMomentAccumulator::new(parts[0].config.clone()).unwrap();
    for (j, p) in parts.iter().enumerate() {
        if !skip.contains(&j) {
            m.merge(p).unwrap();
        }
    }
    m
}

/// A leave-one-part-out jackknife done by brute force, for
/// [`finish_jackknife`]'s errors to be checked against.
struct BruteJackknife {
    /// α and C1 of the whole (refitted by GLS when the fit config asks).
    alpha: f64,
    c1: f64,
    /// Jackknife errors of K(q) (per q), α, C1 and of the universal
    /// `K(2) = C1 (2^α - 2)/(α - 1)` that enters the spectral H.
    k_se: Vec<f64>,
    alpha_se: f64,
    c1_se: f64,
    k2_se: f64,
}

/// For each part: merge all the others and finish them with `fc`, then the
/// jackknife formula over these replicates. The library keeps the whole's
/// q range for the universal fit in every replicate (`finish_jackknife`
/// docs: a replicate's own q_s, from its own α, C1 and image count, would
/// move the range), so α and C1 of a replicate are refitted here to its
/// K(q) over the whole's range, `0 < q <= universal_q_max`: by
/// [`fit_universal`] (OLS), or with [`UniversalWeighting::Gls`] by
/// generalised least squares as the module docs describe (q = 1 left out), the whole with
/// the inverse of the shrunk jackknife covariance of K(q) over the fitted
/// q, each replicate with the one from its own n - 1 replicates (nested).
fn brute_jackknife(
    whole: &TraceMomentAccumulator,
    parts: &[TraceMomentAccumulator],
    fc: &TraceMomentFitConfig,
) -> BruteJackknife {
    use rayon::prelude::*;
    assert!(fc.q_fit_max.is_none());
    let rw = whole.finish(fc).unwrap();
    let n = parts.len();
    let loo: Vec<TraceMomentResult> = (0..n)
        .into_par_iter()
        .map(|i| merge_except(parts, &[i]).finish(fc).unwrap())
        .collect();
    let in_range = |i: usize| rw.q[i] > 0.0 && rw.q[i] < rw.universal_q_max + 1e-12;
    let (alpha, c1, a, c): (f64, f64, Vec<f64>, Vec<f64>) =
        if fc.universal == UniversalWeighting::Gls {
            // the fitted q where every K is finite, less q = 1 (where the
            // universal K and its derivatives vanish; module docs)
            let idx: Vec<usize> = (0..rw.q.len())
                .filter(|&i| {
                    in_range(i)
                        && (rw.q[i] - 1.0).abs() > 1e-9
                        && rw.k[i].is_finite()
                        && loo.iter().all(|r| r.k[i].is_finite())
                })
                .collect();
            let q: Vec<f64> = idx.iter().map(|&i| rw.q[i]).collect();
            let ks = |r: &TraceMomentResult| idx.iter().map(|&i| r.k[i]).collect::<Vec<f64>>();
            let weights = |reps: &[TraceMomentResult]| {
                let v: Vec<Vec<f64>> = reps.iter().map(ks).collect();
                spd_inverse(&jackknife_covariance_shrunk(&v).unwrap().cov).unwrap()
            };
            let u = fit_universal_gls(&q, &ks(&rw), &weights(&loo)).unwrap();
            let nested: Vec<(f64, f64)> = (0..n)
                .into_par_iter()
                .map(|i| {
                    let inner: Vec<TraceMomentResult> = (0..n)
                        .filter(|&j| j != i)
                        .map(|j| merge_except(parts, &[i, j]).finish(fc).unwrap())
                        .collect();
                    let u = fit_universal_gls(&q, &ks(&loo[i]), &weights(&inner)).unwrap();
                    (u.alpha, u.c1)
                })
                .collect();
            let (a, c): (Vec<f64>, Vec<f64>) = nested.into_iter().unzip();
            (u.alpha, u.c1, a, c)
        } else {
            let idx: Vec<usize> = (0..rw.q.len()).filter(|&i| in_range(i)).collect();
            let q: Vec<f64> = idx.iter().map(|&i| rw.q[i]).collect();
            let fit = |r: &TraceMomentResult| {
                let k: Vec<f64> = idx.iter().map(|&i| r.k[i]).collect();
                let u = fit_universal(&q, &k).unwrap();
                (u.alpha, u.c1)
            };
            let (a, c): (Vec<f64>, Vec<f64>) = loo.iter().map(fit).unzip();
            let (alpha, c1) = fit(&rw);
            (alpha, c1, a, c)
        };
    let k2: Vec<f64> = a
        .iter()
        .zip(&c)
        .map(|(&a, &c)| c * universal_shape(a, 2.0))
        .collect();
    BruteJackknife {
        alpha,
        c1,
        k_se: (0..rw.q.len())
            .map(|iq| jackknife_by_definition(&loo.iter().map(|r| r.k[iq]).collect::<Vec<_>>()))
            .collect(),
        alpha_se: jackknife_by_definition(&a),
        c1_se: jackknife_by_definition(&c),
        k2_se: jackknife_by_definition(&k2),
    }
}

/// The library's α, C1, K(q) and their errors (`r`, from
/// [`finish_jackknife`]) against the brute force `b`, to rounding.
fn assert_brute_jackknife(r: &TraceMomentResult, b: &BruteJackknife) {
    println!(
        "alpha {:.4} +- {:.3e} (brute force {:.3e}), C1 {:.5} +- {:.3e} ({:.3e})",
        r.alpha, r.alpha_stderr, b.alpha_se, r.c1, r.c1_stderr, b.c1_se
    );
    assert_rounding("alpha", r.alpha, b.alpha);
    assert_rounding("C1", r.c1, b.c1);
    assert_rounding("alpha_stderr", r.alpha_stderr, b.alpha_se);
    assert_rounding("C1_stderr", r.c1_stderr, b.c1_se);
    // a jackknife over parts that differ: errors well above rounding
    assert!(
        b.alpha_se > 1e-6 && b.c1_se > 1e-8,
        "no scatter over the parts?"
    );
    assert_eq!(r.k_stderr.len(), b.k_se.len());
    for (iq, (x, y)) in r.k_stderr.iter().zip(&b.k_se).enumerate() {
        assert_rounding(&format!("K_stderr at q = {}", r.q[iq]), *x, *y);
    }
}

#[test]
fn lognormal_cascade_recovers_k_alpha_c1() {
    let c1 = 0.1;
    let s = (c1 * 2.0 * std::f64::consts::LN_2).sqrt();
    let n_img = 16;
    // the DTM at the default q = 1.5 (the headline) and at q = 0.5, where
    // K(q, eta) < 0
    let config = TraceMomentConfig {
        dtm_q: vec![1.5, 0.5],
        ..Default::default()
    };
    let accs: Vec<TraceMomentAccumulator> = (0..n_img)
        .map(|i| {
            let mut acc = TraceMomentAccumulator::new(config.clone()).unwrap();
            acc.add_flux(cascade(8, s, 11, i).view(), None).unwrap();
            acc
        })
        .collect();
    let fc = TraceMomentFitConfig::default();
    let (res, per) = ensemble(&accs, &fc);
    println!(
        "cascade: alpha {:.3} (se {:.3}) C1 {:.4} dtm_alpha {:.3} dtm_C1 {:.4} q_s {:.2} K(2) {:.4}",
        res.alpha,
        se(&per, |r| r.alpha),
        res.c1,
        res.dtm_alpha,
        res.dtm_c1,
        res.q_s,
        res.k[19]
    );
    // K(q) for q in [0, 2.5]. The box average of a cascade carries a
    // "dressing" factor that converges geometrically with the number of
    // levels inside the box; the default fit range drops the finest octave,
    // leaving a bias below 2 % of K (measured 1.6 % at q = 2): b = 0.02 |K|.
    for (i, &q) in res.q.iter().enumerate() {
        if q > 2.5 + 1e-9 {
            break;
        }
        let kth = c1 * (q * q - q);
        let sig = se(&per, |r| r.k[i]);
        let tol = 4.0 * sig + 0.02 * kth.abs() + 1e-4;
        assert!(
            (res.k[i] - kth).abs() < tol,
            "q {q}: K {} theory {kth} tol {tol}",
            res.k[i]
        );
    }
    // At q = 2 the dressing is exact: the box of level k (λ = 2^k) holds
    // the bare product of k multipliers times the mean Z_m of the 4^m
    // products below it (m = n - k levels), and with <W> = 1,
    // <Z_m²> = <W²> <Z_(m-1)²>/4 + 3/4, Z_0 = 1 (the 4 children: 4 squared
    // terms, 12 independent cross terms). So E log2 <φ_λ²> =
    // k log2 <W²> + log2 <Z_(n-k)²>, and its slope over the fitted levels
    // is the K(2) the estimator expects (0.1973 against the undressed 0.2
    // here, -1.35 %): K(2) within 4σ of it, no allowance.
    {
        let n_steps = 8;
        let w2 = (s * s).exp();
        let mut z2 = vec![1.0f64];
        for m in 1..=n_steps {
            z2.push(w2 * z2[m - 1] / 4.0 + 0.75);
        }
        let (lo, hi) = res.fit_log2_lambda;
        let (x, y): (Vec<f64>, Vec<f64>) = (0..=n_steps)
            .filter(|&k| k as f64 >= lo - 1e-9 && k as f64 <= hi + 1e-9)
            .map(|k| (k as f64, k as f64 * w2.log2() + z2[n_steps - k].log2()))
            .unzip();
        let dressed = wtmm::stats::line_fit(&x, &y).unwrap().slope;
        let i2 = res.q.iter().position(|&q| (q - 2.0).abs() < 1e-9).unwrap();
        let sig = se(&per, |r| r.k[i2]);
        println!(
            "K(2) {:.4} +- {sig:.4}, dressed expectation {dressed:.4} (fit log2 lambda {lo}..{hi})",
            res.k[i2]
        );
        assert!(
            (res.k[i2] - dressed).abs() < 4.0 * sig,
            "K(2) {} vs the dressed expectation {dressed} +- {sig}",
            res.k[i2]
        );
    }
    // The universal fit, DTM and q_s: regression checks on documented
    // estimator biases. `experiment_cascade_bias` measured on 32
    // independent ensembles of the same 16 x 256² (seeds 2024..2055)
    // `(b, se_b, sd)` = mean minus theory, its standard error, and the sd
    // of one ensemble's estimate; every b is resolved, 2.6 (α) to 6.4
    // (DTM C1 at q = 0.5) of its se_b, so the check is that this ensemble
    // lies within 4 sqrt(sd² + se_b²) of theory + b, not of the theory.
    // That sd, not the per-image scatter / sqrt(16), is this estimate's
    // error: the fit is nonlinear in the pooled moments, and the per-image
    // se of α (0.023) is a third of the spread between ensembles (0.066).
    // (Before: 4 per-image se plus bare allowances 0.08, 0.01, 0.05, 0.01,
    // and q_s within 0.5 of 5.)
    let check = |name: &str, v: f64, want: f64, (b, se_b, sd): (f64, f64, f64)| {
        let tol = 4.0 * sd.hypot(se_b);
        println!("{name}: {v:.4} (theory {want} + bias {b:+.4}, tol {tol:.4})");
        assert!(
            (v - want - b).abs() < tol,
            "{name}: {v} vs theory {want} + documented bias {b}, tol {tol}"
        );
    };
    check("alpha", res.alpha, 2.0, (-0.0304, 0.0116, 0.0656));
    check("C1", res.c1, c1, (-0.00115, 0.00035, 0.00197));
    check(
        "DTM alpha",
        res.dtm_alpha,
        2.0,
        (-0.00928, 0.00330, 0.01870),
    );
    check("DTM C1", res.dtm_c1, c1, (-0.00192, 0.00039, 0.00220));
    assert_eq!((res.dtm_alpha, res.dtm[0].q), (res.dtm[0].alpha, 1.5));
    check(
        "DTM alpha, q = 0.5",
        res.dtm[1].alpha,
        2.0,
        (-0.00609, 0.00123, 0.00694),
    );
    check(
        "DTM C1, q = 0.5",
        res.dtm[1].c1,
        c1,
        (-0.00199, 0.00031, 0.00178),
    );
    // q_s = ((2 + ln 16 / ln 256)/C1)^(1/α) = 5 at the true α, C1
    check("q_s", res.q_s, 5.0, (0.212, 0.043, 0.245));
    // the moment at q = 1 is exactly 1 at every scale (box averages preserve the mean)
    let i1 = res.q.iter().position(|&q| (q - 1.0).abs() < 1e-9).unwrap();
    assert!(res.log2_moments[i1].iter().all(|v| v.abs() < 1e-9));
    // JSON contract keys
    let js = serde_json::to_value(&res).unwrap();
    for key in [
        "q",
        "K",
        "K_stderr",
        "alpha",
        "C1",
        "H",
        "q_s",
        "dtm_alpha",
        "dtm_C1",
        "beta",
        "lambda_eff",
        "xi",
    ] {
        assert!(js.get(key).is_some(), "missing {key}");
    }
}

/// The FIF flux ensemble of the tests below: 32 images of 256² of
/// topo-fif (α = 1.8, C1 = 0.12), seed 2024, one accumulator per image
/// (built once, shared).
fn fif_flux_parts() -> &'static [TraceMomentAccumulator] {
    use rayon::prelude::*;
    static PARTS: std::sync::OnceLock<Vec<TraceMomentAccumulator>> = std::sync::OnceLock::new();
    PARTS.get_or_init(|| {
        (0..32u64)
            .into_par_iter()
            .map(|i| {
                let phi = wtmm::synth::fif::fif_flux(&FifParams::TOPO, 256, 256, 2024, i).unwrap();
                let mut a = TraceMomentAccumulator::new(TraceMomentConfig::default()).unwrap();
                a.add_flux(phi.view(), None).unwrap();
                a
            })
            .collect()
    })
}

/// Trace moments of the simulated FIF flux against the universal theory
/// (seed 000 eq 8; SPEC §8-§9), 32 images of 256² (`fif_flux_parts`):
/// K(q) for 0 < q <= 2, the universal fit's α and C1, the DTM α. Every
/// estimate within 4 jackknife standard errors (over the images,
/// [`finish_ensemble`]) of the theory, with no allowance: the generator
/// follows λ^K(q) over the fitted boxes. Measured on an independent
/// ensemble of 64 images (seed 4242, `experiment_fif_bias`): K(q) -
/// K_theory within 2.2 % ± 2.4 % for 0 < q <= 2 (at q = 2: -1.0 % ±
/// 2.7 %), α 1.770 ± 0.031, C1 0.1211 ± 0.0026, DTM α 1.778 ± 0.015, none
/// beyond 1.5 se. (The "lattice kernel" excess of a few % that the module
/// docs of `synth::fif` compute for <φ_l²> at α = 2 is not resolved at
/// this size.) Before: 8 images and `4 σ + 0.08 |K| + 1e-3` on K, `+ 0.1`
/// on α and DTM α, `+ 0.2 C1` on C1; with 32 images and no allowance the
/// tolerance on K(2) is 0.028 (was 0.046), on C1 0.009 (was about 0.037).
#[test]
fn fif_ensemble_matches_theory() {
    let p = FifParams::TOPO;
    let fc = TraceMomentFitConfig::default();
    let (_, res) = finish_ensemble(fif_flux_parts(), &fc).unwrap();
    assert_eq!(res.jackknife_groups, 32);
    println!(
        "fif flux: alpha {:.3} +- {:.3} C1 {:.4} +- {:.4} dtm_alpha {:.3} +- {:.3} dtm_C1 {:.4} q_s {:.2} K(0.5) {:.4} K(1.5) {:.4} K(2) {:.4} +- {:.4} log2 lambda_eff {:.2}",
        res.alpha,
        res.alpha_stderr,
        res.c1,
        res.c1_stderr,
        res.dtm_alpha,
        res.dtm_alpha_stderr,
        res.dtm_c1,
        res.q_s,
        res.k[4],
        res.k[14],
        res.k[19],
        res.k_stderr[19],
        res.log2_lambda_eff
    );
    for (i, &q) in res.q.iter().enumerate() {
        if q > 2.0 + 1e-9 {
            break;
        }
        let kth = th::k(&p, q);
        // K(1) = 0 exactly (the ensemble mean of φ is 1 at every box
        // size): its jackknife error is rounding, hence the 1e-12
        let tol = 4.0 * res.k_stderr[i] + 1e-12;
        assert!(
            (res.k[i] - kth).abs() < tol,
            "q {q}: K {} theory {kth} tol {tol}",
            res.k[i]
        );
    }
    for (name, v, se, want) in [
        ("alpha", res.alpha, res.alpha_stderr, p.alpha),
        ("C1", res.c1, res.c1_stderr, p.c1),
        ("dtm alpha", res.dtm_alpha, res.dtm_alpha_stderr, p.alpha),
    ] {
        assert!(
            (v - want).abs() < 4.0 * se,
            "{name} {v} +- {se}, theory {want}"
        );
    }
}

/// Double trace moments (seed 000 §6; SPEC §8) on the 32 FIF fluxes
/// (`fif_flux_parts`; truth α = 1.8, C1 = 0.12; DTM at q = 1.5, fitted
/// over η in [0.3, 2]). For a universal multifractal `K(q, η) = η^α
/// K(q)`, so the intercept of `log K(q, η)` against `log η` is `log K(q) =
/// log(C1 (q^α - q)/(α - 1))`, which gives C1 with the fitted α.
/// * `K(1.5, η)` at every η of the fit range equals `η^α K(1.5)` of the
///   theory within 4 jackknife standard errors;
/// * at η = 1 the double trace moment is the trace moment: `K(1.5, 1) =
///   K(1.5)` to rounding;
/// * the DTM C1 equals 0.12 within 4 jackknife standard errors.
///
/// The jackknife (leave one image out) is computed here: the library
/// reports none for `K(q, η)` or the DTM C1. No allowance: measured on 64
/// independent images (seed 4242) the DTM C1 is 0.1198, and 0.120 ± 0.006
/// (sd) over 8 groups of 8.
#[test]
fn fif_double_trace_moments() {
    let p = FifParams::TOPO;
    let parts = fif_flux_parts();
    let merged = |skip: Option<usize>| {
        let mut m = TraceMomentAccumulator::new(parts[0].config.clone()).unwrap();
        for (j, a) in parts.iter().enumerate() {
            if Some(j) != skip {
                m.merge(a).unwrap();
            }
        }
        m.finish(&TraceMomentFitConfig::default()).unwrap()
    };
    let all = merged(None);
    let loo: Vec<TraceMomentResult> = (0..parts.len()).map(|i| merged(Some(i))).collect();
    let jk = |f: &dyn Fn(&TraceMomentResult) -> f64| {
        wtmm::stats::jackknife_se(&loo.iter().map(f).collect::<Vec<_>>())
    };
    assert_eq!(all.dtm_q, vec![1.5]);
    let q = 1.5;
    let k_q = th::k(&p, q);
    let iq = all.q.iter().position(|&v| (v - q).abs() < 1e-9).unwrap();
    let (lo, hi) = all.dtm_eta_range;
    let mut fitted = 0;
    for (ie, &eta) in all.eta.iter().enumerate() {
        if (eta - 1.0).abs() < 1e-9 {
            assert!(
                (all.k_eta[0][ie] - all.k[iq]).abs() < 1e-12,
                "K(1.5, 1) = {} vs K(1.5) = {}",
                all.k_eta[0][ie],
                all.k[iq]
            );
        }
        if eta < lo - 1e-12 || eta > hi + 1e-12 || q * eta > all.q_s {
            continue;
        }
        fitted += 1;
        let want = eta.powf(p.alpha) * k_q;
        let se = jk(&|r| r.k_eta[0][ie]);
        println!(
            "eta {eta:.3}: K(1.5, eta) {:.4} +- {se:.4}, theory {want:.4}",
            all.k_eta[0][ie]
        );
        assert!(
            (all.k_eta[0][ie] - want).abs() < 4.0 * se,
            "eta {eta:.3}: K(1.5, eta) = {} +- {se}, theory {want}",
            all.k_eta[0][ie]
        );
    }
    assert!(fitted >= 5, "{fitted} eta in the fit range");
    let se = jk(&|r| r.dtm_c1);
    println!(
        "DTM C1 {:.4} +- {se:.4} (theory {}), DTM alpha {:.3}",
        all.dtm_c1, p.c1, all.dtm_alpha
    );
    assert!(se > 0.0 && se < 0.25 * p.c1, "jackknife error {se}");
    assert!(
        (all.dtm_c1 - p.c1).abs() < 4.0 * se,
        "DTM C1 {} +- {se}, theory {}",
        all.dtm_c1,
        p.c1
    );
}

/// The surface of 8 topo-fif fields of 256² (seed 2024: the fields whose
/// fluxes are `fif_flux_parts()[..8]`) with seed 000's estimator, the
/// gradient modulus alone (`FluxDiff::None`): the spectrum, the structure
/// functions and the gradient flux, each against the theory within 4
/// standard errors σ of this ensemble's estimate (the per-image scatter,
/// `std / sqrt(8)`).
///
/// Finite-size biases were measured on an independent ensemble of 64 images
/// of 256² (seed 4242, jackknife errors, `experiment_fif_bias`). Where that
/// bias is within 2 of its own error it is not resolved, and the bare
/// theory is asserted: β 2.2665 ± 0.047 against 2.1777 (+1.9 errors; seed
/// 001 Fig 5 notes that the spectrum of a finite FIF falls too fast at high
/// wavenumbers, not resolved here), the spectral H 0.7243 ± 0.0245 (+1.0),
/// ξ(2) 1.1629 ± 0.023 against 1.1777 (-0.6). (Before: theory + bias within
/// `4 sqrt(σ² + se_b²)`; earlier still, bare allowances 0.15, 0.05, 0.1.)
/// H_sf is biased by -0.0388 ± 0.0056 (7 errors: increments at lags 2-32
/// px of a periodic 256² surface read ξ(1) 0.661 for H = 0.7): for it the
/// check is a regression check on that documented estimator bias, theory +
/// bias within `4 sqrt(σ² + se_b²)`.
///
/// The gradient flux against the generator's flux of the same images
/// (paired, `paired_k_difference`: the sampling fluctuations they share
/// cancel; σ its jackknife error over the images): |∇| is a
/// differentiation of order 1 > H = 0.7, so the modulus is that of a
/// fractional derivative of order 0.3 of φ, which fills the low values of
/// φ (module docs of `tracemoments`, "Which flux"): |K(q)| lower than the
/// flux's, at q = 0.5 and 2, by more than 3 σ. (Before: K(2) within 30 %
/// of the theory, an allowance.)
#[test]
fn fif_field_matches_theory() {
    let p = FifParams::TOPO;
    let (n, n_img) = (256, 8);
    let flux = &fif_flux_parts()[..n_img as usize];
    let mut field_accs = Vec::new();
    for i in 0..n_img {
        let (f, phi) = fif_with_flux(&p, n, n, 2024, i).unwrap();
        // the pairing below: the shared flux accumulators hold these φ
        // (their sum of φ over the 65536 pixels, to rounding: below
        // 65536 x 1.1e-16 = 7e-12 relative however summed; the sums of
        // two images differ by percents)
        let ln_sum = flux[i as usize].phi_sum.ln();
        assert!((ln_sum - phi.sum().ln()).abs() < 1e-10, "image {i}");
        // seed 000's estimator: the gradient modulus alone
        let mut b = TraceMomentAccumulator::new(TraceMomentConfig {
            diff: FluxDiff::None,
            ..Default::default()
        })
        .unwrap();
        b.add_field(&Field::new(f)).unwrap();
        field_accs.push(b);
    }
    let fc = TraceMomentFitConfig::default();
    // the surface: spectrum, structure functions, gradient flux
    let (fres, fper) = ensemble(&field_accs, &fc);
    println!(
        "fif field: beta {:?} (se {:.3}, theory {:.4}) H {:?} H_sf {:?} (se {:.3}) xi {:?} grad K(2) {:.4} alpha {:.3} C1 {:.4} dtm_alpha {:.3}",
        fres.beta,
        se(&fper, |r| r.beta.unwrap()),
        th::beta_integrated(&p),
        fres.h,
        fres.h_sf,
        se(&fper, |r| r.h_sf.unwrap()),
        fres.xi,
        fres.k[19],
        fres.alpha,
        fres.c1,
        fres.dtm_alpha
    );
    let check = |name: &str, v: f64, sig: f64, want: f64| {
        let tol = 4.0 * sig;
        println!("{name}: {v:.4} (theory {want:.4}, tol {tol:.4})");
        assert!(
            (v - want).abs() < tol,
            "{name}: {v} vs theory {want}, tol {tol}"
        );
    };
    // angle-integrated β = 1 + 2H - K(2) (seed 000 eq 11)
    let beta = fres.beta.unwrap();
    check(
        "beta",
        beta,
        se(&fper, |r| r.beta.unwrap()),
        th::beta_integrated(&p),
    );
    assert!((fres.beta_averaged.unwrap() - beta - 1.0).abs() < 1e-12);
    // H = ξ(1) from the structure functions: regression check on the
    // documented bias (b, se_b)
    {
        let (v, sig, (b, se_b)) = (
            fres.h_sf.unwrap(),
            se(&fper, |r| r.h_sf.unwrap()),
            (-0.0388, 0.0056),
        );
        let tol = 4.0 * sig.hypot(se_b);
        println!(
            "H_sf: {v:.4} (theory {} + bias {b:+.4}, tol {tol:.4})",
            p.hurst
        );
        assert!(
            (v - p.hurst - b).abs() < tol,
            "H_sf: {v} vs theory {} + documented bias {b}, tol {tol}",
            p.hurst
        );
    }
    // H from the spectrum, (β - 1 + K(2))/2 (seed 000 §6.1.2; the `H` key
    // of tm.json), with the gradient flux's K(2)
    check("H", fres.h.unwrap(), se(&fper, |r| r.h.unwrap()), p.hurst);
    // ξ(q) = qH - K(q) at q = 2
    let i2 = fres.sf_q.iter().position(|&q| q == 2.0).unwrap();
    check(
        "xi(2)",
        fres.xi[i2],
        se(&fper, |r| r.xi[i2]),
        th::xi(&p, 2.0),
    );
    // the gradient flux against the true flux of the same images
    for q in [0.5, 2.0] {
        let (d, sig) = paired_k_difference(&field_accs, flux, q, &fc);
        let kth = th::k(&p, q);
        println!(
            "q {q}: K gradient - K flux {d:+.4} +- {sig:.4} ({:.1} errors; theory K {kth:.4})",
            d / sig
        );
        // |K| lower: d has the sign opposite to K's
        assert!(
            d * kth.signum() < -3.0 * sig,
            "q {q}: K gradient - K flux = {d} +- {sig}: |K| of the gradient flux not below the flux's"
        );
    }
}

#[test]
fn same_seed_same_bytes() {
    let p = FifParams::TOPO;
    let a = fif(&p, 64, 64, 9, 3).unwrap();
    let b = fif(&p, 64, 64, 9, 3).unwrap();
    let bytes = |m: &Array2<f64>| m.iter().flat_map(|v| v.to_le_bytes()).collect::<Vec<u8>>();
    assert_eq!(bytes(&a), bytes(&b));
    // image 3 does not depend on images 0-2 being generated first
    for i in 0..3 {
        let _ = fif(&p, 64, 64, 9, i).unwrap();
    }
    let c = fif(&p, 64, 64, 9, 3).unwrap();
    assert_eq!(bytes(&a), bytes(&c));
}

#[test]
fn merge_is_annealed_and_serialisable() {
    let p = FifParams::TOPO;
    let fields: Vec<Field> = (0..4)
        .map(|i| Field::new(fif(&p, 64, 64, 1, i).unwrap()))
        .collect();
    let cfg = TraceMomentConfig::default();
    let mut seq = TraceMomentAccumulator::new(cfg.clone()).unwrap();
    for f in &fields {
        seq.add_field(f).unwrap();
    }
    let mut a = TraceMomentAccumulator::new(cfg.clone()).unwrap();
    let mut b = TraceMomentAccumulator::new(cfg.clone()).unwrap();
    a.add_field(&fields[0]).unwrap();
    a.add_field(&fields[1]).unwrap();
    b.add_field(&fields[2]).unwrap();
    b.add_field(&fields[3]).unwrap();
    // through JSON, as per-image sums saved by separate processes would be
    let b: TraceMomentAccumulator =
        serde_json::from_str(&serde_json::to_string(&b).unwrap()).unwrap();
    a.merge(&b).unwrap();
    let fc = TraceMomentFitConfig::default();
    let (r1, r2) = (seq.finish(&fc).unwrap(), a.finish(&fc).unwrap());
    for (x, y) in r1.k.iter().zip(&r2.k) {
        assert!((x - y).abs() < 1e-10);
    }
    assert!((r1.alpha - r2.alpha).abs() < 1e-6);
    // the result reads back from its JSON, NaN entries (null there) too
    let text = serde_json::to_string(&r2).unwrap();
    assert!(
        text.contains("\"H\":null"),
        "64^2 images: no spectrum fit, H is NaN"
    );
    let back: TraceMomentResult = serde_json::from_str(&text).unwrap();
    assert_eq!(serde_json::to_string(&back).unwrap(), text);
    // different settings do not merge
    let other = TraceMomentAccumulator::new(TraceMomentConfig {
        flux: FluxKind::Wavelet,
        ..cfg
    })
    .unwrap();
    assert!(a.merge(&other).is_err());
}

#[test]
fn masked_pixels_are_excluded() {
    // A flux of 1 everywhere with a masked block of huge values: the block
    // must not reach any moment, so K(q) = 0 and every moment is 1.
    let n = 64;
    let mut phi = Array2::from_elem((n, n), 1.0);
    let mut mask = Array2::from_elem((n, n), false);
    for y in 10..30 {
        for x in 5..20 {
            phi[[y, x]] = 1e6;
            mask[[y, x]] = true;
        }
    }
    let mut acc = TraceMomentAccumulator::new(TraceMomentConfig::default()).unwrap();
    acc.add_flux(phi.view(), Some(mask.view())).unwrap();
    let r = acc.finish(&TraceMomentFitConfig::default()).unwrap();
    for m in r.log2_moments.iter().flatten() {
        assert!(m.abs() < 1e-9, "{m}");
    }
    // a field with a NaN hole analyses without error and the hole's
    // neighbourhood is dropped from the gradient flux
    let mut f = fif(&FifParams::TOPO, 128, 128, 4, 0).unwrap();
    for y in 0..16 {
        for x in 0..128 {
            f[[y, x]] = f64::NAN;
        }
    }
    let r = analyze(
        &Field::new(f),
        TraceMomentConfig::default(),
        &TraceMomentFitConfig::default(),
    )
    .unwrap();
    assert!(r.k.iter().all(|k| k.is_finite()));
    assert!(r.beta.is_some_and(|b| b.is_finite()));
}

#[test]
fn rejects_bad_input() {
    let bad = TraceMomentConfig {
        q: vec![-1.0],
        ..Default::default()
    };
    assert!(
        TraceMomentAccumulator::new(bad)
            .unwrap_err()
            .to_string()
            .contains("q")
    );
    // K(1, eta) = 0 for every eta: no double trace moment at q = 1
    let bad = TraceMomentConfig {
        dtm_q: vec![1.5, 1.0],
        ..Default::default()
    };
    let e = TraceMomentAccumulator::new(bad).unwrap_err().to_string();
    assert!(e.contains("dtm-q") && e.contains("conserved"), "{e}");
    // a plane removed from a torus is a sawtooth across its edges
    let bad = TraceMomentConfig {
        periodic: true,
        detrend: wtmm::field::Trend::Plane,
        ..Default::default()
    };
    let e = TraceMomentAccumulator::new(bad).unwrap_err().to_string();
    assert!(e.contains("detrend") && e.contains("sawtooth"), "{e}");
    let flat = Field::new(Array2::from_elem((32, 32), 3.0));
    // a constant field has no H = ξ(1) to differentiate by (default flux) ...
    let mut acc = TraceMomentAccumulator::new(TraceMomentConfig::default()).unwrap();
    assert!(
        acc.add_field(&flat)
            .unwrap_err()
            .to_string()
            .contains("constant image")
    );
    // ... and a zero gradient flux: no normalisation possible
    let mut acc = TraceMomentAccumulator::new(TraceMomentConfig {
        diff: FluxDiff::None,
        ..Default::default()
    })
    .unwrap();
    acc.add_field(&flat).unwrap();
    assert!(acc.finish(&TraceMomentFitConfig::default()).is_err());
    assert!(
        acc.add_flux(Array2::from_elem((16, 16), -1.0).view(), None)
            .is_err()
    );
}

/// What the fits cannot deliver is said in the library's warnings, not
/// only by the CLI: the flux of a plane (a constant gradient with rounding
/// noise) has no universal K(q), and its alpha lands on an end of the
/// search interval; a `--lag-fit` holding one lag is refused; an eta or
/// k range holding no point leaves the DTM or H without a fit, said.
#[test]
fn what_a_fit_cannot_deliver_is_said() {
    // a plane with a faint ripple (an exact plane is refused outright),
    // with equal box weights: count weights give the same flux an alpha of
    // 2.10 +- 0.03, said too, as outside [0, 2]
    let plane = Field::new(Array2::from_shape_fn((64, 64), |(y, x)| {
        (x + y) as f64 + 1e-4 * ((x * 7 + y * 13) % 17) as f64
    }));
    let equal = TraceMomentConfig {
        box_weights: BoxWeights::Equal,
        ..Default::default()
    };
    let (_, r) = analyze_tiled(&[plane], &equal, &TraceMomentFitConfig::for_tiles()).unwrap();
    // (alpha 3 +- 0.79, C1 0.26 before, with no warning)
    assert!(r.alpha > 2.999, "alpha {}", r.alpha);
    assert!(
        has(&r, "sits at an end of the universal fit's search"),
        "{:?}",
        r.warnings
    );
    let fif = Field::new(
        fif(
            &FifParams {
                alpha: 1.8,
                c1: 0.12,
                hurst: 0.7,
            },
            128,
            128,
            3,
            0,
        )
        .unwrap(),
    );
    let cfg = TraceMomentConfig {
        spectrum: wtmm::stats::powspec::PowerSpectrumConfig::for_field(true),
        ..Default::default()
    };
    let fit = |fc: TraceMomentFitConfig| analyze_tiled(std::slice::from_ref(&fif), &cfg, &fc);
    let e = fit(TraceMomentFitConfig {
        log2_lag: Some((1.0, 1.5)),
        ..TraceMomentFitConfig::for_tiles()
    })
    .unwrap_err()
    .to_string();
    assert!(e.contains("lag-fit") && e.contains("holds 1 lag"), "{e}");
    let (_, r) = fit(TraceMomentFitConfig {
        eta: (50.0, 100.0),
        ..TraceMomentFitConfig::for_tiles()
    })
    .unwrap();
    assert!(r.dtm_alpha.is_nan());
    assert!(has(&r, "usable eta value(s)"), "{:?}", r.warnings);
    let (_, r) = fit(TraceMomentFitConfig {
        k_range: Some((3.0, 3.1)),
        ..TraceMomentFitConfig::for_tiles()
    })
    .unwrap();
    assert!(r.h.is_none());
    assert!(has(&r, "beta and H not estimable"), "{:?}", r.warnings);
    // the default fit on the same field: none of these
    let (_, r) = fit(TraceMomentFitConfig::for_tiles()).unwrap();
    for w in ["search interval", "usable eta", "not estimable"] {
        assert!(!has(&r, w), "{w}: {:?}", r.warnings);
    }
}

/// K(q) of the default (auto) flux minus K(q) of the generator's flux on
/// the same images, and its jackknife error, measured by
/// `experiment_fif_bias` on 64 topo-fif images of 256² (seed 4242): the
/// estimated flux scales a little less intermittently (|K(0.5)| 0.0322,
/// 4 % less, 20 errors; K(2) 0.222, 1 %, 2.2 errors, the same sign). Both
/// are resolved estimator biases, and `auto_flux_tracks_the_true_flux`
/// is a regression check on them, not a check against the theory (which
/// would be a difference of 0).
const BIAS_AUTO_K05: f64 = 0.00122;
const SE_AUTO_K05: f64 = 0.00006;
const BIAS_AUTO_K2: f64 = 0.00238;
const SE_AUTO_K2: f64 = 0.00106;

/// The default flux (`FluxDiff::Auto`: fractional differentiation of order
/// `ξ(1)` per image, then the gradient modulus) against the generator's own
/// flux on the same images, and against the gradient alone.
///
/// On 8 FIF images of 256² (topo-fif: α = 1.8, C1 = 0.12, H = 0.7):
/// * each image's order is its own `ξ(1)` (the same estimator as `H_sf`, so
///   equal to it on a single image up to rounding);
/// * `K(q)` of the estimated flux minus `K(q)` of the true flux at q = 0.5
///   and 2 (paired: the same images; σ its jackknife error) equals the
///   difference measured on 64 other images within `4 sqrt(σ² + se_b²)`
///   (a regression check on the documented estimator bias `BIAS_AUTO_K05`,
///   `BIAS_AUTO_K2`; before: `4 σ + 0.08 |K|`, an allowance no
///   measurement stated);
/// * the gradient alone underestimates |K| at both orders, below the auto
///   flux's by more than 3 errors of their paired difference (its residual
///   derivative of order 1 - H = 0.3 fills the low values of φ; TM §5.2
///   assumed H ≈ 1/2).
#[test]
fn auto_flux_tracks_the_true_flux() {
    let p = FifParams::TOPO;
    let (n, n_img) = (256, 8);
    let none = TraceMomentConfig {
        diff: FluxDiff::None,
        ..Default::default()
    };
    let (mut fl, mut au, mut gr) = (Vec::new(), Vec::new(), Vec::new());
    for i in 0..n_img {
        let (f, phi) = fif_with_flux(&p, n, n, 77, i).unwrap();
        let field = Field::new(f);
        let mut a = TraceMomentAccumulator::new(TraceMomentConfig::default()).unwrap();
        a.add_flux(phi.view(), None).unwrap();
        fl.push(a);
        let mut b = TraceMomentAccumulator::new(TraceMomentConfig::default()).unwrap();
        b.add_field(&field).unwrap();
        // single image: the order is that image's ξ(1)
        let r1 = b.finish(&TraceMomentFitConfig::default()).unwrap();
        assert!((r1.diff_order - r1.h_sf.unwrap()).abs() < 1e-9, "{r1:?}");
        au.push(b);
        let mut c = TraceMomentAccumulator::new(none.clone()).unwrap();
        c.add_field(&field).unwrap();
        gr.push(c);
    }
    let fc = TraceMomentFitConfig::default();
    let (_, r_fl) = finish_ensemble(&fl, &fc).unwrap();
    let (_, r_au) = finish_ensemble(&au, &fc).unwrap();
    let (_, r_gr) = finish_ensemble(&gr, &fc).unwrap();
    // paired jackknife of K_auto(q) - K_flux(q)
    let k_at = |r: &TraceMomentResult, q: f64| {
        r.k[r.q.iter().position(|&v| (v - q).abs() < 1e-9).unwrap()]
    };
    // (b, se_b) of `experiment_fif_bias` (64 other images, seed 4242)
    for (q, (b, se_b)) in [
        (0.5, (BIAS_AUTO_K05, SE_AUTO_K05)),
        (2.0, (BIAS_AUTO_K2, SE_AUTO_K2)),
    ] {
        let (d, sig) = paired_k_difference(&au, &fl, q, &fc);
        let (ka, kf, kg) = (k_at(&r_au, q), k_at(&r_fl, q), k_at(&r_gr, q));
        let tol = 4.0 * sig.hypot(se_b);
        println!(
            "q {q}: K auto {ka:.4} flux {kf:.4} gradient {kg:.4}, auto - flux {d:+.4} +- {sig:.4} (bias {b:+.4}, tol {tol:.4})"
        );
        assert!(
            (d - b).abs() < tol,
            "q {q}: K auto {ka} - true flux {kf} = {d}, measured bias {b}, tol {tol}"
        );
        // the gradient alone: |K| below the auto flux's by more than 3
        // errors of their paired difference (same images)
        let (dg, sig_g) = paired_k_difference(&gr, &au, q, &fc);
        println!("q {q}: gradient - auto {dg:+.4} +- {sig_g:.4}");
        assert!(
            -dg * kf.signum() > 3.0 * sig_g && kg.abs() < kf.abs(),
            "q {q}: gradient {kg} - auto {ka} = {dg} +- {sig_g}: |K| should fall (true {kf})"
        );
    }
    println!(
        "auto: alpha {:.3} +- {:.3} C1 {:.4} +- {:.4}; flux: alpha {:.3} C1 {:.4}; gradient: alpha {:.3} C1 {:.4}; order {:.3} (sd {:.3})",
        r_au.alpha,
        r_au.alpha_stderr,
        r_au.c1,
        r_au.c1_stderr,
        r_fl.alpha,
        r_fl.c1,
        r_gr.alpha,
        r_gr.c1,
        r_au.diff_order,
        r_au.diff_order_sd
    );
}

/// Jackknife errors: the exact two-part formula, zero for identical parts,
/// and on 16 log-normal cascades of 128² (exact K) an error of α of the
/// size of the per-image scatter, not of the regression residuals (OLS
/// universal fit, the estimator of the per-image α; the GLS errors are
/// checked against the scatter between ensembles below).
#[test]
fn jackknife_errors_reflect_the_ensemble_scatter() {
    let c1 = 0.1;
    let s = (c1 * 2.0 * std::f64::consts::LN_2).sqrt();
    let fc = TraceMomentFitConfig {
        universal: UniversalWeighting::Ols,
        ..Default::default()
    };
    let one = |i: u64| {
        let mut a = TraceMomentAccumulator::new(TraceMomentConfig::default()).unwrap();
        a.add_flux(cascade(7, s, 5, i).view(), None).unwrap();
        a
    };
    // n = 2: se = |θ(part 1) - θ(part 2)| / 2 exactly, with the q range pinned
    let (a, b) = (one(0), one(1));
    let (_, r) = finish_ensemble(&[a.clone(), b.clone()], &fc).unwrap();
    assert_eq!(r.jackknife_groups, 2);
    let (ka, kb) = (a.finish(&fc).unwrap(), b.finish(&fc).unwrap());
    for i in [4, 19] {
        let want = (ka.k[i] - kb.k[i]).abs() / 2.0;
        assert!(
            (r.k_stderr[i] - want).abs() < 1e-12,
            "{} vs {want}",
            r.k_stderr[i]
        );
    }
    // identical parts: no scatter
    let (_, r) = finish_ensemble(&[a.clone(), a.clone(), a.clone()], &fc).unwrap();
    assert!(r.alpha_stderr.abs() < 1e-12 && r.c1_stderr.abs() < 1e-12);
    assert!(r.alpha_stderr_fit > 0.0);
    // 16 images: the jackknife and std/√n of the per-image α both estimate
    // the standard error of α, each with ~1/√(2(n-1)) = 18 % relative
    // error; 4σ of their log-ratio (√2 · 0.18 · 4 ≈ 1) allows a factor e.
    let parts: Vec<_> = (0..16).map(one).collect();
    let (_, r) = finish_ensemble(&parts, &fc).unwrap();
    let per: Vec<TraceMomentResult> = parts.iter().map(|p| p.finish(&fc).unwrap()).collect();
    let s_img = se(&per, |r| r.alpha);
    println!(
        "alpha {:.3}: jackknife {:.4}, per-image {:.4}, fit-only {:.4}",
        r.alpha, r.alpha_stderr, s_img, r.alpha_stderr_fit
    );
    let ratio = r.alpha_stderr / s_img;
    assert!(
        ratio > (-1.0f64).exp() && ratio < 1.0f64.exp(),
        "jackknife {} vs per-image {s_img}",
        r.alpha_stderr
    );
    assert!(r.stderr_method.contains("jackknife"));
}

/// Every level of the box pyramid averages over the same region, so a
/// conserved flux keeps `<φ_λ> = 1` at every λ (K(1) = 0 up to rounding)
/// on images whose sides are not powers of two. Boxes tiled from one
/// corner used to cover less of the image the larger they were: on the
/// 511^2 crop of this log-normal cascade (σ² of ln W = 0.14) log2 <φ_λ>
/// drifted by 0.76 from the finest to the largest box. A power-of-two
/// image is one window and unchanged.
#[test]
fn box_moments_see_the_same_region_at_every_scale() {
    let phi = cascade(9, 0.37, 11, 0);
    let cfg = TraceMomentConfig::default();
    let fc = TraceMomentFitConfig {
        log2_lambda: Some((0.0, 7.0)),
        ..Default::default()
    };
    let i1 = cfg.q.iter().position(|&q| q == 1.0).unwrap();
    for (ny, nx) in [(511, 511), (300, 300), (200, 330), (512, 512)] {
        let crop = phi.slice(ndarray::s![0..ny, 0..nx]);
        let mut acc = TraceMomentAccumulator::new(cfg.clone()).unwrap();
        acc.add_flux(crop, None).unwrap();
        let r = acc.finish(&fc).unwrap();
        let drift = r.log2_moments[i1]
            .iter()
            .filter(|v| v.is_finite())
            .fold(0.0f64, |m, v| m.max(v.abs()));
        assert!(
            drift < 1e-12,
            "{ny}x{nx}: log2 <phi_lambda> off 0 by {drift}"
        );
        assert!(r.k[i1].abs() < 1e-12, "{ny}x{nx}: K(1) = {}", r.k[i1]);
    }
}

/// The tiles of one field add up to the whole field at every fitted box
/// size: identical K(q). The block-jackknife errors of α, C1 and K(q) are
/// those of a leave-one-tile-out jackknife done by brute force
/// (`brute_jackknife`: each tile left out in turn, the others merged and
/// finished, the delete-one formula), to rounding, with the OLS universal
/// fit and with the default GLS one (α and C1 refitted, nested jackknife).
#[test]
fn tiles_reproduce_the_whole_field() {
    let f = Field::new(fif(&FifParams::TOPO, 96, 128, 3, 0).unwrap());
    let cfg = TraceMomentConfig::default();
    let fc = TraceMomentFitConfig::default();
    // L = 64, default fit log2 λ in [1, 5]: boxes 2..32 px
    let (whole, tiles) = TraceMomentAccumulator::field_tiles(&cfg, &f, 32).unwrap();
    assert_eq!(tiles.len(), 3 * 4);
    let mut direct = TraceMomentAccumulator::new(cfg.clone()).unwrap();
    direct.add_field(&f).unwrap();
    let (rw, rd) = (whole.finish(&fc).unwrap(), direct.finish(&fc).unwrap());
    assert_eq!(rw.k, rd.k);
    let mut merged = TraceMomentAccumulator::new(cfg).unwrap();
    for t in &tiles {
        merged.merge(t).unwrap();
    }
    let rm = merged.finish(&fc).unwrap();
    for (a, b) in rm.k.iter().zip(&rw.k) {
        assert!((a - b).abs() < 1e-10, "{a} vs {b}");
    }
    for (a, b) in rm.xi.iter().zip(&rw.xi) {
        assert!((a - b).abs() < 1e-10, "xi {a} vs {b}");
    }
    // OLS: the jackknife only adds errors; GLS (default, 12 tiles >= 5)
    // refits α from the same K(q)
    let ols = TraceMomentFitConfig {
        universal: UniversalWeighting::Ols,
        ..Default::default()
    };
    let r = finish_jackknife(&whole, &tiles, &ols, "tiles").unwrap();
    assert_eq!(r.alpha, rw.alpha);
    assert!(r.stderr_method.contains("12 tiles"));
    assert_brute_jackknife(&r, &brute_jackknife(&whole, &tiles, &ols));
    let r = finish_jackknife(&whole, &tiles, &fc, "tiles").unwrap();
    assert_eq!(r.k, rw.k);
    assert_eq!(r.alpha_ols, rw.alpha);
    assert!(r.universal_fit.starts_with("gls"), "{}", r.universal_fit);
    assert_brute_jackknife(&r, &brute_jackknife(&whole, &tiles, &fc));
}

/// Tiles larger than the image's largest box (two images of different
/// sizes share one tile side in `tm`): a 200 x 1000 field's boxes of 128
/// px, in windows anchored at its corners, go to 256 px tiles by the
/// centre of their 256 px block, which for the bottom windows lies on the
/// image's last row + 1; such boxes go to the nearest tile, so the tiles
/// still share out every box and pixel. Until 2026-11-29 they went to none,
/// and the merged tiles missed them.
#[test]
fn tiles_larger_than_the_boxes_keep_every_box() {
    let f = Field::new(fif(&FifParams::TOPO, 200, 1000, 5, 0).unwrap());
    let cfg = TraceMomentConfig::default();
    let (whole, tiles) = TraceMomentAccumulator::field_tiles(&cfg, &f, 256).unwrap();
    assert!(tiles.len() >= 2, "{} tiles", tiles.len());
    assert_tiles_add_up(&whole, &tiles);
}

/// The tiles of one image, merged, are the whole image: its valid pixels,
/// box and increment counts, and K(q) to rounding.
fn assert_tiles_add_up(whole: &TraceMomentAccumulator, tiles: &[TraceMomentAccumulator]) {
    let mut merged = TraceMomentAccumulator::new(whole.config.clone()).unwrap();
    for t in tiles {
        merged.merge(t).unwrap();
    }
    assert_eq!(merged.n_valid, whole.n_valid);
    assert_eq!(merged.box_count, whole.box_count);
    assert_eq!(merged.sf_count, whole.sf_count);
    let fc = TraceMomentFitConfig::default();
    let (rm, rw) = (merged.finish(&fc).unwrap(), whole.finish(&fc).unwrap());
    for (a, b) in rm.k.iter().zip(&rw.k) {
        assert!((a - b).abs() < 1e-10, "{a} vs {b}");
    }
}

/// The tiles of one image share its spectrum, so β has no scatter over
/// them (a 1e-15 rounding scatter was reported once) and keeps its fit
/// error, and `H = (β - 1 + K(2))/2` carries half of it on top of the
/// tiles' scatter of the universal K(2) (`finish_jackknife`:
/// `H_stderr = hypot(jackknife error of H, β_stderr/2)`). Checked to
/// rounding against computations done here: β and its error are the OLS
/// line `log2 S = c - β_avg log2 |k|` through the whole image's binned
/// spectrum over the default k range (slope error `sqrt(Σ r² / (n-2) /
/// Σ (x - x̄)²)` from the residuals r), minus 1 for the angle-integrated β;
/// the jackknife error of the universal K(2) comes from `brute_jackknife`
/// (default GLS fit, 16 tiles).
#[test]
fn one_image_h_error_includes_the_spectrum_fit() {
    let f = Field::new(fif(&FifParams::TOPO, 256, 256, 3, 1).unwrap());
    let cfg = TraceMomentConfig::default();
    let fc = TraceMomentFitConfig::default();
    let (whole, tiles) = TraceMomentAccumulator::field_tiles(&cfg, &f, 64).unwrap();
    assert_eq!(tiles.len(), 16);
    let r = finish_jackknife(&whole, &tiles, &fc, "tiles").unwrap();
    assert!(r.universal_fit.starts_with("gls"), "{}", r.universal_fit);
    // the spectrum fit, by hand
    let ps =
        wtmm::stats::powspec::power_spectrum(f.filled().unwrap().view(), &cfg.spectrum).unwrap();
    let (klo, khi) = wtmm::stats::powspec::default_k_range(256);
    let (x, y): (Vec<f64>, Vec<f64>) = ps
        .points()
        .into_iter()
        .filter(|&(k, s)| k >= klo && k <= khi && s > 0.0)
        .map(|(k, s)| (k.log2(), s.log2()))
        .unzip();
    let m = x.len() as f64;
    assert!(m >= 3.0, "{m} spectrum bins");
    let (mx, my) = (x.iter().sum::<f64>() / m, y.iter().sum::<f64>() / m);
    let sxx: f64 = x.iter().map(|a| (a - mx).powi(2)).sum();
    let slope = x
        .iter()
        .zip(&y)
        .map(|(a, b)| (a - mx) * (b - my))
        .sum::<f64>()
        / sxx;
    let sse: f64 = x
        .iter()
        .zip(&y)
        .map(|(a, b)| (b - my - slope * (a - mx)).powi(2))
        .sum();
    let beta_se = (sse / (m - 2.0) / sxx).sqrt();
    let beta = r.beta.expect("beta of a 256^2 field");
    let b = r.beta_stderr.expect("beta of a 256^2 field");
    assert_rounding("beta", beta, -slope - 1.0);
    assert_rounding("beta_stderr", b, beta_se);
    // H and its error from the brute-force jackknife of the universal K(2)
    let bj = brute_jackknife(&whole, &tiles, &fc);
    assert_brute_jackknife(&r, &bj);
    let k2 = bj.c1 * universal_shape(bj.alpha, 2.0);
    assert_rounding("H", r.h.unwrap(), (beta - 1.0 + k2) / 2.0);
    let h_se = r.h_stderr.expect("H error of a 256^2 field");
    println!(
        "beta {beta:.4} +- {b:.4}; H {:.4} +- {h_se:.4} = hypot({:.4} (K(2) scatter / 2), {:.4} (beta fit / 2))",
        r.h.unwrap(),
        bj.k2_se / 2.0,
        b / 2.0
    );
    assert_rounding("H_stderr", h_se, (bj.k2_se / 2.0).hypot(b / 2.0));
}

/// The GLS universal fit (default) against the OLS one on m = 8
/// independent ensembles of 16 log-normal cascades of 128² (exact K: α = 2,
/// C1 = 0.1): the mean over the ensembles of each estimate against the
/// theory; the GLS nested-jackknife error of the size of the scatter
/// between ensembles (within a factor e), and a scatter no larger than that
/// of OLS (measured: sd 0.018 against 0.103).
///
/// `experiment_cascade_bias` (`LEVELS=7 R=64 SEED=3000`: 64 other
/// ensembles of the same size) measured the biases `(b, se_b)` and the sd
/// of one ensemble's estimate: GLS α -0.0023 ± 0.0021 and OLS α -0.018 ±
/// 0.013 are not resolved (1.1 and 1.5 errors), so the mean α is checked
/// against the bare theory, within 4 standard errors `sd_m/√m` from this
/// test's own scatter sd_m between its m ensembles (7 degrees of freedom:
/// 4 such errors are exceeded with probability 0.005). GLS C1 -0.0023 ±
/// 0.00035 is resolved (6.6 errors): there the check is a regression check
/// on that documented estimator bias, theory + b within
/// `4 sqrt(sd²/m + se_b²)`.
#[test]
fn gls_universal_fit_on_cascade_ensembles() {
    let c1 = 0.1;
    let s = (c1 * 2.0 * std::f64::consts::LN_2).sqrt();
    let (m, n_img) = (8u64, 16u64);
    let gls = TraceMomentFitConfig::default();
    assert_eq!(gls.universal, UniversalWeighting::Gls);
    let ols = TraceMomentFitConfig {
        universal: UniversalWeighting::Ols,
        ..Default::default()
    };
    let (mut ag, mut ao, mut jg, mut cg) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for e in 0..m {
        let parts: Vec<TraceMomentAccumulator> = (0..n_img)
            .map(|i| {
                let mut a = TraceMomentAccumulator::new(TraceMomentConfig::default()).unwrap();
                a.add_flux(cascade(7, s, 100 + e, i).view(), None).unwrap();
                a
            })
            .collect();
        let (_, rg) = finish_ensemble(&parts, &gls).unwrap();
        let (_, ro) = finish_ensemble(&parts, &ols).unwrap();
        assert!(rg.universal_fit.starts_with("gls"), "{}", rg.universal_fit);
        assert!(
            rg.universal_shrinkage
                .is_some_and(|l| (0.0..=1.0).contains(&l))
        );
        assert!(ro.universal_fit.starts_with("ols"));
        assert_eq!(rg.alpha_ols, ro.alpha);
        assert_eq!(rg.k, ro.k);
        ag.push(rg.alpha);
        ao.push(ro.alpha);
        jg.push(rg.alpha_stderr);
        cg.push(rg.c1);
    }
    let (mg, sg) = mean_std(&ag);
    let (mo, so) = mean_std(&ao);
    let (mc, sc) = mean_std(&cg);
    let mj = jg.iter().sum::<f64>() / m as f64;
    println!(
        "cascades 16 x 128², {m} ensembles: GLS alpha {mg:.3} sd {sg:.3} (mean jackknife {mj:.3}); OLS alpha {mo:.3} sd {so:.3}; GLS C1 {mc:.4} sd {sc:.4}"
    );
    // (before: theory + the unresolved biases on α; earlier, 4 sd/√m plus
    // bare allowances 0.08 on α and 0.01 on C1)
    let rm = (m as f64).sqrt();
    for (name, v, sd) in [("GLS alpha", mg, sg), ("OLS alpha", mo, so)] {
        let tol = 4.0 * sd / rm;
        println!("{name}: mean {v:.4} (theory 2, tol {tol:.4})");
        assert!(
            (v - 2.0).abs() < tol,
            "{name}: mean {v} vs theory 2, tol {tol}"
        );
    }
    // (b, se_b, sd) of `experiment_cascade_bias` at 16 x 128², seeds 3000..3063
    // (re-measured 2026-11-29 with q = 1 out of the GLS fit; before,
    // -0.00234, 0.00035, 0.00281)
    let (b, se_b, sd) = (-0.00232, 0.00035, 0.00280);
    let tol = 4.0 * (sd / rm).hypot(se_b);
    println!("GLS C1: mean {mc:.4} (theory {c1} + bias {b:+.4}, tol {tol:.4})");
    assert!(
        (mc - c1 - b).abs() < tol,
        "GLS C1: mean {mc} vs theory {c1} + documented bias {b}, tol {tol}"
    );
    assert!(
        mj / sg > (-1.0f64).exp() && mj / sg < 1.0f64.exp(),
        "jackknife {mj} vs sd {sg}"
    );
    assert!(sg <= so, "GLS sd {sg} vs OLS sd {so}");
}

/// The measurements behind the FIF tolerances above (not a check; `cargo
/// test --release --test tracemoments experiment_fif_bias -- --ignored
/// --nocapture`, env N images of 256² (default 64), SEED (default 4242)):
/// the flux's K(q), α, C1, DTM α and C1 (jackknife errors; the DTM C1's
/// computed here), and the surface's β, H_sf, ξ(2) and gradient K(2)
/// (`FluxDiff::None`), against the theory.
#[test]
#[ignore]
fn experiment_fif_bias() {
    use rayon::prelude::*;
    let p = FifParams::TOPO;
    let n: u64 = std::env::var("N").map_or(64, |s| s.parse().unwrap());
    let seed: u64 = std::env::var("SEED").map_or(4242, |s| s.parse().unwrap());
    let fc = TraceMomentFitConfig::default();
    let triples: Vec<_> = (0..n)
        .into_par_iter()
        .map(|i| {
            let (f, phi) = fif_with_flux(&p, 256, 256, seed, i).unwrap();
            let mut a = TraceMomentAccumulator::new(TraceMomentConfig::default()).unwrap();
            a.add_flux(phi.view(), None).unwrap();
            let field = Field::new(f);
            let mut b = TraceMomentAccumulator::new(TraceMomentConfig {
                diff: FluxDiff::None,
                ..Default::default()
            })
            .unwrap();
            b.add_field(&field).unwrap();
            let mut c = TraceMomentAccumulator::new(TraceMomentConfig::default()).unwrap();
            c.add_field(&field).unwrap();
            (a, b, c)
        })
        .collect();
    let flux: Vec<_> = triples.iter().map(|t| t.0.clone()).collect();
    let field: Vec<_> = triples.iter().map(|t| t.1.clone()).collect();
    let auto: Vec<_> = triples.iter().map(|t| t.2.clone()).collect();
    // the default (auto) flux against the true one, paired on the same
    // images (the bias term of `auto_flux_tracks_the_true_flux`)
    for q in [0.5, 2.0] {
        let (d, sig) = paired_k_difference(&auto, &flux, q, &fc);
        println!("K auto - K flux at q {q}: {d:+.5} +- {sig:.5}");
    }
    let (_, r) = finish_ensemble(&flux, &fc).unwrap();
    for (i, &q) in r.q.iter().enumerate().filter(|(_, q)| **q <= 3.0 + 1e-9) {
        let kth = th::k(&p, q);
        println!(
            "q {q:.1}: K {:.4} +- {:.4}, theory {kth:.4}, relative {:+.3} +- {:.3}",
            r.k[i],
            r.k_stderr[i],
            (r.k[i] - kth) / kth,
            r.k_stderr[i] / kth.abs()
        );
    }
    let loo: Vec<f64> = (0..flux.len())
        .map(|i| {
            let mut m = TraceMomentAccumulator::new(flux[0].config.clone()).unwrap();
            for (j, a) in flux.iter().enumerate() {
                if j != i {
                    m.merge(a).unwrap();
                }
            }
            m.finish(&fc).unwrap().dtm_c1
        })
        .collect();
    println!(
        "alpha {:.4} +- {:.4}, C1 {:.4} +- {:.4}, DTM alpha {:.4} +- {:.4}, DTM C1 {:.4} +- {:.4} (theory {}, {})",
        r.alpha,
        r.alpha_stderr,
        r.c1,
        r.c1_stderr,
        r.dtm_alpha,
        r.dtm_alpha_stderr,
        r.dtm_c1,
        wtmm::stats::jackknife_se(&loo),
        p.alpha,
        p.c1
    );
    let (_, f) = finish_ensemble(&field, &fc).unwrap();
    let i2 = f.sf_q.iter().position(|&q| q == 2.0).unwrap();
    let k2 = f.q.iter().position(|&q| (q - 2.0).abs() < 1e-9).unwrap();
    println!(
        "surface: beta {:.4} +- {:.4} (theory {:.4}), H_sf {:.4} +- {:.4} ({}), xi(2) {:.4} +- {:.4} ({:.4}), gradient K(2) / K(2) {:.3} +- {:.3}",
        f.beta.unwrap(),
        f.beta_stderr.unwrap(),
        th::beta_integrated(&p),
        f.h_sf.unwrap(),
        f.h_sf_stderr.unwrap(),
        p.hurst,
        f.xi[i2],
        f.xi_stderr[i2],
        th::xi(&p, 2.0),
        f.k[k2] / th::k(&p, 2.0),
        f.k_stderr[k2] / th::k(&p, 2.0)
    );
    println!(
        "surface: H (spectrum, (beta - 1 + K(2))/2 with the gradient K(2)) {:.4} +- {:.4} ({})",
        f.h.unwrap(),
        f.h_stderr.unwrap(),
        p.hurst
    );
}

/// The measurement behind the bias terms of
/// `lognormal_cascade_recovers_k_alpha_c1` and
/// `gls_universal_fit_on_cascade_ensembles` (not a check; `cargo test
/// --release --test tracemoments experiment_cascade_bias -- --ignored
/// --nocapture`, env R ensembles (default 32) of N images (default 16, the
/// tests': q_s, hence the q range of the universal fit, depends on the
/// image count, so the bias does too) of 2^LEVELS squared (default 8, the
/// first test's 256²; 7 for the GLS test's 128²), seeds SEED.. (default
/// 2024.., independent of the tests' seeds 11 and 100..107). Prints the
/// mean over the ensembles of each estimate minus theory, with the
/// standard error of that mean and the sd of one ensemble's estimate.
#[test]
#[ignore]
fn experiment_cascade_bias() {
    use rayon::prelude::*;
    let n: u64 = std::env::var("N").map_or(16, |s| s.parse().unwrap());
    let r: u64 = std::env::var("R").map_or(32, |s| s.parse().unwrap());
    let seed: u64 = std::env::var("SEED").map_or(2024, |s| s.parse().unwrap());
    let levels: usize = std::env::var("LEVELS").map_or(8, |s| s.parse().unwrap());
    let c1 = 0.1;
    let s = (c1 * 2.0 * std::f64::consts::LN_2).sqrt();
    let ols = TraceMomentFitConfig {
        universal: UniversalWeighting::Ols,
        ..Default::default()
    };
    // the DTM at q = 1.5 (the default, first: the headline) and q = 0.5
    let config = TraceMomentConfig {
        dtm_q: vec![1.5, 0.5],
        ..Default::default()
    };
    let runs: Vec<[f64; 10]> = (0..r)
        .into_par_iter()
        .map(|k| {
            let accs: Vec<TraceMomentAccumulator> = (0..n)
                .map(|i| {
                    let mut acc = TraceMomentAccumulator::new(config.clone()).unwrap();
                    acc.add_flux(cascade(levels, s, seed + k, i).view(), None)
                        .unwrap();
                    acc
                })
                .collect();
            // the first test's pooled fit (no per-image covariance) ...
            let (res, _) = ensemble(&accs, &TraceMomentFitConfig::default());
            // ... and the GLS test's, with the images' covariance
            let (_, gls) = finish_ensemble(&accs, &TraceMomentFitConfig::default()).unwrap();
            let (_, res_ols) = finish_ensemble(&accs, &ols).unwrap();
            [
                res.alpha - 2.0,
                res.c1 - c1,
                res.dtm_alpha - 2.0,
                res.dtm_c1 - c1,
                res.q_s,
                gls.alpha - 2.0,
                gls.c1 - c1,
                res_ols.alpha - 2.0,
                res.dtm[1].alpha - 2.0,
                res.dtm[1].c1 - c1,
            ]
        })
        .collect();
    let side = 1usize << levels;
    for (j, name) in [
        "alpha - 2",
        "C1 - 0.1",
        "DTM alpha - 2",
        "DTM C1 - 0.1",
        "q_s",
        "GLS alpha - 2 (finish_ensemble)",
        "GLS C1 - 0.1 (finish_ensemble)",
        "OLS alpha - 2 (finish_ensemble)",
        "DTM alpha - 2 at q = 0.5",
        "DTM C1 - 0.1 at q = 0.5",
    ]
    .iter()
    .enumerate()
    {
        let v: Vec<f64> = runs.iter().map(|x| x[j]).collect();
        let (m, sd) = mean_std(&v);
        println!(
            "{r} ensembles of {n} x {side}^2 (seeds {seed}..): {name} {m:+.5} +- {:.5} (sd {sd:.5})",
            sd / (r as f64).sqrt()
        );
    }
}

/// A 400² field (the levi_fell DEM's size) with tiles of the largest fitted
/// box, 128 px: 3 x 3 whole tiles fit, stretched to 133-134 px so that they
/// cover every pixel once, and no 16-px sliver becomes a jackknife group of
/// its own (16 groups before, 7 of them slivers). Each tile is the same
/// region at every level up to the tile side (the block rule of
/// `field_tiles`): with every pixel valid, its boxes of side 2^k cover
/// `box_count[k] 4^k` px, the same for k = 2..=7 (the last row and column
/// have no forward difference: level 0 drops them, and level 1 the corner
/// box, 1 of 4 pixels valid) with equal box weights; with count weights,
/// which keep that corner box, `box_count[k]` counts the same valid pixels
/// at every level k = 0..=7.
#[test]
fn lone_image_tiles_are_whole_and_cover_the_image() {
    let (n, tile) = (400, 128);
    let b = tile_bounds(n, n, tile);
    assert_eq!(b.len(), 9);
    let mut cover = Array2::<u8>::zeros((n, n));
    for &(y0, y1, x0, x1) in &b {
        for side in [y1 - y0, x1 - x0] {
            assert!((133..=134).contains(&side), "tile {y0}..{y1} x {x0}..{x1}");
        }
        cover
            .slice_mut(ndarray::s![y0..y1, x0..x1])
            .map_inplace(|c| *c += 1);
    }
    assert!(
        cover.iter().all(|&c| c == 1),
        "tiles overlap or leave pixels out"
    );
    // a power-of-two side: the plain grid
    assert_eq!(tile_bounds(384, 384, 128).len(), 9);
    assert!(tile_bounds(384, 384, 128).iter().all(|t| t.1 - t.0 == 128));
    let f = Field::new(fif(&FifParams::TOPO, n, n, 3, 0).unwrap());
    let equal = TraceMomentConfig {
        box_weights: BoxWeights::Equal,
        ..Default::default()
    };
    let (_, tiles) = TraceMomentAccumulator::field_tiles(&equal, &f, tile).unwrap();
    for (i, t) in tiles.iter().enumerate() {
        let area: Vec<u64> = (2..=7).map(|k| t.box_count[k] << (2 * k)).collect();
        assert!(
            area.iter().all(|&a| a == area[0] && a > 0),
            "tile {i}: area per level {area:?}"
        );
    }
    let cfg = TraceMomentConfig::default();
    assert_eq!(cfg.box_weights, BoxWeights::Count);
    let (whole, tiles) = TraceMomentAccumulator::field_tiles(&cfg, &f, tile).unwrap();
    assert_eq!(tiles.len(), 9);
    for (i, t) in tiles.iter().enumerate() {
        let px = &t.box_count[..=7];
        assert!(
            px.iter().all(|&a| a == px[0] && a > 0),
            "tile {i}: valid pixels per level {px:?}"
        );
    }
    assert_tiles_add_up(&whole, &tiles);
    let fc = TraceMomentFitConfig::default();
    let r = finish_jackknife(&whole, &tiles, &fc, "tiles").unwrap();
    assert_eq!(r.jackknife_groups, 9);
}

/// Fewer than 3 images: the tiles of every image make the jackknife groups
/// (`pool_tiles`); the merged tiles are the merged images, and every tile
/// carries the merged spectrum, so beta keeps the fit error of the merged
/// spectrum (as for one image) instead of a scatter from the images'
/// weights; the errors of α, C1, K(q) and H are those of a brute-force
/// leave-one-tile-out jackknife over the 32 tiles (`brute_jackknife`), to
/// rounding.
#[test]
fn two_images_pool_their_tiles() {
    let cfg = TraceMomentConfig::default();
    let fields: Vec<Field> = (0..2)
        .map(|i| Field::new(fif(&FifParams::TOPO, 256, 256, 5, i).unwrap()))
        .collect();
    let per: Vec<_> = fields
        .iter()
        .map(|f| TraceMomentAccumulator::field_tiles(&cfg, f, 64).unwrap())
        .collect();
    let (whole, tiles) = pool_tiles(per).unwrap();
    assert_eq!(tiles.len(), 32);
    assert_eq!(whole.images, 2);
    let mut direct = TraceMomentAccumulator::new(cfg.clone()).unwrap();
    for f in &fields {
        direct.add_field(f).unwrap();
    }
    let fc = TraceMomentFitConfig {
        universal: UniversalWeighting::Ols,
        ..Default::default()
    };
    let (rw, rd) = (whole.finish(&fc).unwrap(), direct.finish(&fc).unwrap());
    assert_eq!(rw.k, rd.k);
    assert_eq!(rw.beta, rd.beta);
    let r = finish_jackknife(&whole, &tiles, &fc, "tiles of 2 images").unwrap();
    assert_eq!(r.jackknife_groups, 32);
    assert!(
        r.stderr_method.contains("32 tiles of 2 images"),
        "{}",
        r.stderr_method
    );
    assert_eq!(r.beta_stderr, rw.beta_stderr);
    // the errors of α, C1, K(q) against a brute-force leave-one-tile-out
    // jackknife over the 32 tiles, and H's as for one image: the tiles
    // share the merged spectrum, so hypot(K(2) scatter / 2, β fit error / 2)
    let bj = brute_jackknife(&whole, &tiles, &fc);
    assert_brute_jackknife(&r, &bj);
    let b = r.beta_stderr.expect("beta of 256^2 fields");
    assert_rounding(
        "H_stderr",
        r.h_stderr.unwrap(),
        (bj.k2_se / 2.0).hypot(b / 2.0),
    );
    assert!(pool_tiles(Vec::new()).is_err());
}

/// A periodic fractional Brownian surface of exponent `h` on `n x n`
/// (the fBm recipe of SPEC §9, `|k|^-(h+1)` on white noise, without the
/// crop, so any h > 0: the crate's `fbm` stops at 1), and the settings for
/// a periodic field.
fn periodic_fbm(h: f64, n: usize, seed: u64) -> (Field, TraceMomentConfig) {
    let mut rng = rng_for(seed, 0);
    let w = Array2::from_shape_fn((n, n), |_| {
        let z: f64 = StandardNormal.sample(&mut rng);
        z
    });
    let f = wtmm::synth::fif::fractional_integrate(w.view(), h + 1.0).unwrap();
    let cfg = TraceMomentConfig {
        spectrum: wtmm::stats::powspec::PowerSpectrumConfig::for_field(true),
        ..Default::default()
    };
    (Field::new(f), cfg)
}

/// The lone-image result of `f` (tiles of 64 px, as the CLI for 256²).
fn lone(f: &Field, cfg: &TraceMomentConfig) -> TraceMomentResult {
    let (whole, tiles) = TraceMomentAccumulator::field_tiles(cfg, f, 64).unwrap();
    finish_jackknife(&whole, &tiles, &TraceMomentFitConfig::default(), "tiles").unwrap()
}

fn has(r: &TraceMomentResult, what: &str) -> bool {
    r.warnings.iter().any(|w| w.contains(what))
}

/// The H diagnostics on surfaces of known H. H = 1.3: first differences
/// saturate (H_sf near 1), so the automatic order is too low, and said,
/// naming --diff-order with the spectral H; the plain gradient (order 1) is
/// said to act on an integral of the flux; an order given by hand (1.3)
/// silences that, but H_sf still cannot follow H, said as a disagreement.
/// H = 0.4 (the periodic surface and the crate's fBm with its default,
/// tapered spectrum): none of these (the straightness check does speak on
/// an fBm, rightly: its flux has no cascade, and box averages of it
/// converge like sums of nearly independent values, `1 + O(l^-2)`, no power
/// law). The spectral H is checked against the truth within 4 of its
/// errors (measured 1.292 +- 0.027, 0.392 +- 0.028, 0.372 +- 0.082).
#[test]
fn h_diagnostics_on_surfaces_of_known_h() {
    let (smooth, cfg) = periodic_fbm(1.3, 256, 21);
    let r = lone(&smooth, &cfg);
    let (h, se) = (r.h.unwrap(), r.h_stderr.unwrap());
    println!("H = 1.3: H {h:.3} +- {se:.3}, H_sf {:?}", r.h_sf);
    assert!((h - 1.3).abs() < 4.0 * se, "H {h} +- {se}");
    assert!(r.h_sf.unwrap() < 1.05, "H_sf {:?}", r.h_sf);
    assert!(has(&r, "exceeds 1 by"), "{:?}", r.warnings);
    assert!(has(&r, &format!("--diff-order {h:.2}")), "{:?}", r.warnings);
    for (diff, first, second) in [
        (FluxDiff::None, true, false),
        (FluxDiff::Order(1.3), false, true),
    ] {
        let c = TraceMomentConfig {
            diff,
            ..cfg.clone()
        };
        let r = lone(&smooth, &c);
        assert_eq!(
            has(&r, "not on the flux"),
            first,
            "{diff:?}: {:?}",
            r.warnings
        );
        assert_eq!(
            has(&r, "cannot follow"),
            second,
            "{diff:?}: {:?}",
            r.warnings
        );
    }
    let (rough, cfg) = periodic_fbm(0.4, 256, 21);
    let crate_fbm = Field::new(
        wtmm::synth::fbm::fbm(wtmm::synth::fbm::FbmParams { hurst: 0.4 }, 256, 256, 21, 0).unwrap(),
    );
    for (f, c) in [(&rough, cfg), (&crate_fbm, TraceMomentConfig::default())] {
        let r = lone(f, &c);
        let (h, se) = (r.h.unwrap(), r.h_stderr.unwrap());
        println!("H = 0.4: H {h:.3} +- {se:.3}, H_sf {:?}", r.h_sf);
        assert!((h - 0.4).abs() < 4.0 * se, "H {h} +- {se}");
        assert!(!has(&r, "spectral H"), "{:?}", r.warnings);
    }
}

/// `detrend: Plane` removes a tilt before everything: a tilted fBm (H =
/// 0.4, 256², tilted by 10 standard deviations along each axis) gives
/// the untilted surface's results to rounding (the least-squares plane of
/// f + P is that of f plus P), and the raw tilt pulls `H_sf` toward 1 (a
/// plane of slope c adds c l to the increments at lag l; measured 0.618
/// against 0.470 +- 0.014 untilted, 0.470 detrended) while the spectral
/// H, whose spectrum removes a plane of its own, stays within 4 errors of
/// the truth (0.372 +- 0.082). The share of the variance the plane
/// explains is recorded per image, before detrending; a plane of more
/// than half the variance is said with H_sf without it and the spectral
/// H, tilted or not (an untilted smooth fBm with a plane of 91 %: H_sf
/// 0.751 would read 0.682, further from the spectral 0.811). Fluxes given
/// directly and older accumulators keep one entry per field; an exact
/// plane is refused.
#[test]
fn a_plane_is_removed_before_the_moments() {
    let f =
        wtmm::synth::fbm::fbm(wtmm::synth::fbm::FbmParams { hurst: 0.4 }, 256, 256, 21, 0).unwrap();
    let sd = f.std(0.0);
    let mut t = f.clone();
    for ((y, x), v) in t.indexed_iter_mut() {
        *v += 10.0 * sd * (x + y) as f64 / 256.0;
    }
    let (f, t) = (Field::new(f), Field::new(t));
    let plane = TraceMomentConfig {
        detrend: wtmm::field::Trend::Plane,
        ..Default::default()
    };
    let (a, b) = (lone(&f, &plane), lone(&t, &plane));
    for (what, x, y) in [
        ("H_sf", a.h_sf.unwrap(), b.h_sf.unwrap()),
        ("H", a.h.unwrap(), b.h.unwrap()),
        ("alpha", a.alpha, b.alpha),
        ("C1", a.c1, b.c1),
    ] {
        // rounding of the two detrended fields (1e-16 of the tilt),
        // amplified in alpha by K(q)'s small values at small q (2e-9 seen)
        assert!(
            (x - y).abs() <= 1e-6 * x.abs().max(1.0),
            "{what}: {x} vs {y}"
        );
    }
    let raw = TraceMomentConfig::default();
    let (u, r) = (lone(&f, &raw), lone(&t, &raw));
    let (hu, hr) = (u.h_sf.unwrap(), r.h_sf.unwrap());
    let se = u.h_sf_stderr.unwrap();
    // xi(1) is H_sf, and its error in the result is the same jackknife's
    // (it was the regression's: NaN for a fit of 2 lags)
    let i1 = u.sf_q.iter().position(|&q| q == 1.0).unwrap();
    assert_eq!((u.xi[i1], u.xi_stderr[i1]), (hu, se));
    println!(
        "H_sf untilted {hu:.3} +- {se:.3}, tilted {hr:.3}, detrended {:.3}; spectral H tilted {:.3} +- {:.3}",
        a.h_sf.unwrap(),
        r.h.unwrap(),
        r.h_stderr.unwrap()
    );
    assert!(hr - hu > 4.0 * se, "H_sf {hr} vs {hu} +- {se}");
    // the disagreement of the two H names the plane, raw only
    assert!(has(&r, "plane explains"), "{:?}", r.warnings);
    assert!(!has(&b, "plane explains"), "{:?}", b.warnings);
    assert_eq!(r.plane_share, t.plane_share());
    assert_eq!(b.detrend, wtmm::field::Trend::Plane);
    // an untilted smooth fBm (H = 0.8, 512^2) whose own large scales make
    // a plane of 91 %: the same numbers are given (removing it would take
    // H_sf further from the spectral H: the reader can tell), not a verdict
    let smooth = Field::new(
        wtmm::synth::fbm::fbm(wtmm::synth::fbm::FbmParams { hurst: 0.8 }, 512, 512, 1, 0).unwrap(),
    );
    let s8 = lone(&smooth, &raw);
    println!(
        "H = 0.8: share {:?}, H {:?}, H_sf {:?}, shift {:?}",
        s8.plane_share, s8.h, s8.h_sf, s8.h_sf_plane_shift
    );
    assert!(s8.plane_share.unwrap() > 0.5 && s8.h_sf_plane_shift.unwrap() > 0.0);
    let (h8, e8) = (s8.h.unwrap(), s8.h_sf_plane_shift.unwrap());
    let hsf8 = s8.h_sf.unwrap();
    assert!((hsf8 - e8 - h8).abs() > (hsf8 - h8).abs());
    assert!(
        has(&s8, &format!("would read about {:.3}", hsf8 - e8)),
        "{:?}",
        s8.warnings
    );
    assert!(
        has(&s8, &format!("of its own: {h8:.3}")),
        "{:?}",
        s8.warnings
    );
    let (h, se_h) = (r.h.unwrap(), r.h_stderr.unwrap());
    assert!((h - 0.4).abs() < 4.0 * se_h, "H {h} +- {se_h}");
    // the share is of the raw image, whatever is removed
    let (whole, _) = TraceMomentAccumulator::field_tiles(&plane, &t, 64).unwrap();
    let share = whole.planes[0].share.unwrap();
    assert_eq!(Some(share), t.plane_share());
    assert!(share > 0.5, "{share}");
    // a flux given directly has no plane: its entry keeps one per field,
    // as merging with an accumulator that records none does
    let mut flux = TraceMomentAccumulator::new(plane.clone()).unwrap();
    flux.add_flux(Array2::from_elem((16, 16), 1.0).view(), None)
        .unwrap();
    let mut old = whole.clone();
    old.planes.clear();
    let mut m = flux.clone();
    m.merge(&old).unwrap();
    m.merge(&whole).unwrap();
    assert_eq!(m.images, 3);
    let shares: Vec<_> = m.planes.iter().map(|p| p.share).collect();
    assert_eq!(shares, vec![None, None, Some(share)]);
    // an image that is a plane leaves only rounding: refused
    let exact = Field::new(Array2::from_shape_fn((64, 64), |(y, x)| {
        1000.0 + 0.37 * x as f64 + 0.11 * y as f64
    }));
    let e = TraceMomentAccumulator::new(plane.clone())
        .unwrap()
        .add_field(&exact)
        .unwrap_err()
        .to_string();
    assert!(e.contains("the image is a plane"), "{e}");
    // and kept: its gradient flux is constant (a DTM alpha was read from it)
    let kept = TraceMomentConfig {
        detrend: wtmm::field::Trend::None,
        ..plane.clone()
    };
    let e = TraceMomentAccumulator::new(kept)
        .unwrap()
        .add_field(&exact)
        .unwrap_err()
        .to_string();
    assert!(e.contains("no rough surface"), "{e}");
}

/// The straightness diagnostic on ensembles of 16 log-normal cascades of
/// 128² (jackknife over images): with one C1 at every step the moments are
/// exact power laws and nothing is said; with no intermittency over the
/// first 3 steps (coarse scales) and C1 = 0.2 over the last 4, K(q) is 0
/// over log2 λ 1..3 and C1 (q² - q) over 4..6, a kink of 0.4 in the local
/// slope at q = 2 within the fit range [1, 6]: said (the parabola's measure
/// of the bend reads +0.56 at q = 2.1, 13 errors), naming --lambda-fit.
#[test]
fn straightness_diagnostic_on_cascades() {
    let run = |s_coarse: f64, s_fine: f64| {
        let parts: Vec<TraceMomentAccumulator> = (0..16)
            .map(|i| {
                let mut rng = rng_for(31, i);
                let mut a = Array2::<f64>::from_elem((1, 1), 1.0);
                for step in 0..7 {
                    let s = if step < 3 { s_coarse } else { s_fine };
                    let m = a.nrows();
                    a = Array2::from_shape_fn((2 * m, 2 * m), |(y, x)| {
                        let z: f64 = StandardNormal.sample(&mut rng);
                        a[[y / 2, x / 2]] * (-s * s / 2.0 + s * z).exp()
                    });
                }
                let mut acc = TraceMomentAccumulator::new(TraceMomentConfig::default()).unwrap();
                acc.add_flux(a.view(), None).unwrap();
                acc
            })
            .collect();
        finish_ensemble(&parts, &TraceMomentFitConfig::default())
            .unwrap()
            .1
    };
    let s = (0.2 * 2.0 * std::f64::consts::LN_2).sqrt();
    let straight = run(s, s);
    assert!(!has(&straight, "straight line"), "{:?}", straight.warnings);
    let bent = run(0.0, s);
    assert!(has(&bent, "straight line"), "{:?}", bent.warnings);
    assert!(has(&bent, "--lambda-fit"), "{:?}", bent.warnings);
}

/// Calibration of the lone-image (tile) jackknife and of the diagnostics
/// (not a check; `cargo test --release --test tracemoments
/// experiment_lone_image_tiles -- --ignored --nocapture`, env R fields
/// (default 24) of SIZE² (default 400), SEED (777), MODEL fif (topo-fif) or
/// fbm (H = 0.4), FIT ols (default) or gls): per estimate the scatter between the fields and the rms
/// of their jackknife errors, and per diagnostic the fields it speaks on.
#[test]
#[ignore]
fn experiment_lone_image_tiles() {
    use rayon::prelude::*;
    let env = |k: &str, d: u64| std::env::var(k).map_or(d, |s| s.parse().unwrap());
    let (r, n, seed) = (env("R", 24), env("SIZE", 400) as usize, env("SEED", 777));
    let model = std::env::var("MODEL").unwrap_or("fif".into());
    let cfg = TraceMomentConfig::default();
    // FIT=gls: the GLS universal fit over the tiles
    let fc = TraceMomentFitConfig {
        universal: match std::env::var("FIT").as_deref() {
            Ok("gls") => UniversalWeighting::Gls,
            _ => UniversalWeighting::Ols,
        },
        ..Default::default()
    };
    let tile = 1usize << ((n as f64).log2().floor() as u32 - 1);
    let runs: Vec<TraceMomentResult> = (0..r)
        .into_par_iter()
        .map(|i| {
            let a = match model.as_str() {
                "fbm" => {
                    let p = wtmm::synth::fbm::FbmParams { hurst: 0.4 };
                    wtmm::synth::fbm::fbm(p, n, n, seed, i).unwrap()
                }
                _ => fif(&FifParams::TOPO, n, n, seed, i).unwrap(),
            };
            let (w, t) = TraceMomentAccumulator::field_tiles(&cfg, &Field::new(a), tile).unwrap();
            finish_jackknife(&w, &t, &fc, "tiles").unwrap()
        })
        .collect();
    type Get = fn(&TraceMomentResult) -> (f64, f64);
    let stats: [(&str, Get); 4] = [
        ("alpha", |x| (x.alpha, x.alpha_stderr)),
        ("C1", |x| (x.c1, x.c1_stderr)),
        ("DTM alpha", |x| (x.dtm_alpha, x.dtm_alpha_stderr)),
        ("H", |x| (x.h.unwrap(), x.h_stderr.unwrap())),
    ];
    for (name, get) in stats {
        let (v, se): (Vec<f64>, Vec<f64>) = runs.iter().map(get).unzip();
        let (m, sd) = mean_std(&v);
        let rms = (se.iter().map(|s| s * s).sum::<f64>() / se.len() as f64).sqrt();
        println!(
            "{name}: mean {m:.4}, sd over fields {sd:.4}, rms jackknife error {rms:.4}, ratio {:.2}",
            rms / sd
        );
    }
    for k in ["straight line", "H_sf = xi(1)", "exceeds"] {
        let n = runs.iter().filter(|x| has(x, k)).count();
        println!("fields with a warning holding {k:?}: {n} of {}", runs.len());
    }
}

/// The error of the straightness diagnostic (not a check; as
/// `experiment_lone_image_tiles`, env R, SIZE, SEED): on single topo-fif
/// fields with tiles, per q the change of the local slope of the moment
/// lines across the fit range, its mean and scatter between fields, and the
/// rms of its (undoubled) tile-jackknife error.
#[test]
#[ignore]
fn experiment_curvature_calibration() {
    use rayon::prelude::*;
    let env = |k: &str, d: u64| std::env::var(k).map_or(d, |s| s.parse().unwrap());
    let (r, n, seed) = (env("R", 24), env("SIZE", 400) as usize, env("SEED", 777));
    let cfg = TraceMomentConfig::default();
    let fc = TraceMomentFitConfig {
        universal: UniversalWeighting::Ols,
        ..Default::default()
    };
    let tile = 1usize << ((n as f64).log2().floor() as u32 - 1);
    let qs = [0.5, 1.5, 2.0, 2.5, 3.0, 4.0];
    let change = |x: &TraceMomentResult, q: f64| {
        let iq = x.q.iter().position(|v| (v - q).abs() < 1e-9).unwrap();
        let (lo, hi) = x.fit_log2_lambda;
        let (xs, ys): (Vec<f64>, Vec<f64>) = x
            .log2_lambda
            .iter()
            .zip(&x.log2_moments[iq])
            .filter(|(a, _)| **a >= lo - 1e-9 && **a <= hi + 1e-9)
            .map(|(a, b)| (*a, *b))
            .unzip();
        wtmm::stats::fit::slope_change(&xs, &ys).unwrap()
    };
    // per field, per q: (change, jackknife error)
    let runs: Vec<Vec<(f64, f64)>> = (0..r)
        .into_par_iter()
        .map(|i| {
            let f = Field::new(fif(&FifParams::TOPO, n, n, seed, i).unwrap());
            let (w, t) = TraceMomentAccumulator::field_tiles(&cfg, &f, tile).unwrap();
            let whole = w.finish(&fc).unwrap();
            let loo: Vec<TraceMomentResult> = (0..t.len())
                .map(|i| {
                    let mut m = TraceMomentAccumulator::new(cfg.clone()).unwrap();
                    for (_, p) in t.iter().enumerate().filter(|(j, _)| *j != i) {
                        m.merge(p).unwrap();
                    }
                    m.finish(&fc).unwrap()
                })
                .collect();
            qs.iter()
                .map(|&q| {
                    let l: Vec<f64> = loo.iter().map(|x| change(x, q)).collect();
                    (change(&whole, q), wtmm::stats::jackknife_se(&l))
                })
                .collect()
        })
        .collect();
    for (j, q) in qs.iter().enumerate() {
        let (c, se): (Vec<f64>, Vec<f64>) = runs.iter().map(|x| x[j]).unzip();
        let (m, sd) = mean_std(&c);
        let rms = (se.iter().map(|s| s * s).sum::<f64>() / se.len() as f64).sqrt();
        let over3 = c
            .iter()
            .zip(&se)
            .filter(|(c, s)| c.abs() > 3.0 * **s)
            .count();
        println!(
            "q {q}: change {m:+.4} +- {:.4} (sd {sd:.4}), rms jackknife error {rms:.4}, ratio \
             {:.2}; beyond 3 errors in {over3} of {}",
            sd / (c.len() as f64).sqrt(),
            rms / sd,
            c.len()
        );
    }
}

/// The GLS and OLS universal fits part where K(q) leaves the universal
/// form: on 32 cascades of 256^2 with a two-point multiplier (W = 0.6 or
/// 1.4, equally likely: `K(q) = log2((0.6^q + 1.4^q)/2)`, not of the form
/// `C1/(α-1) (q^α - q)`) the diagnostic speaks (GLS 1.90, OLS 1.47, 9.5
/// errors of their difference; 5.0-9.5 on seeds 31-35). Its silence on
/// universal fields is measured, not asserted (in `diagnostics`).
#[test]
fn gls_and_ols_apart_where_k_is_not_universal() {
    let two_point = |seed: u64, index: u64| {
        let mut rng = rng_for(seed, index);
        let mut a = Array2::<f64>::from_elem((1, 1), 1.0);
        for _ in 0..8 {
            let m = a.nrows();
            a = Array2::from_shape_fn((2 * m, 2 * m), |(y, x)| {
                let w = if rand::RngExt::random_bool(&mut rng, 0.5) {
                    0.6
                } else {
                    1.4
                };
                a[[y / 2, x / 2]] * w
            });
        }
        a
    };
    let parts: Vec<TraceMomentAccumulator> = (0..32)
        .map(|i| {
            let mut a = TraceMomentAccumulator::new(TraceMomentConfig::default()).unwrap();
            a.add_flux(two_point(31, i).view(), None).unwrap();
            a
        })
        .collect();
    let (_, r) = finish_ensemble(&parts, &TraceMomentFitConfig::default()).unwrap();
    println!(
        "two-point: GLS alpha {:.3}, OLS {:.3}; {:?}",
        r.alpha, r.alpha_ols, r.warnings
    );
    assert!(r.universal_fit.starts_with("gls"));
    assert!(
        has(&r, "the GLS universal fit gives alpha"),
        "{:?}",
        r.warnings
    );
}

/// Surrogate errors are what they say: the scatter of the analyses of FIF
/// draws with the stated parameters, the data's shape and missing pixels
/// and the stated seeds (recomputed here one by one), the same bytes on
/// one thread as on several, refused below 8 draws or without a universal
/// fit.
#[test]
fn surrogate_errors_are_the_scatter_of_fif_draws_analysed_alike() {
    let (n, seed) = (128, 3);
    let a = fif(&FifParams::TOPO, n, n, 5, 0).unwrap();
    let mut mask = Array2::from_elem((n, n), false);
    mask.slice_mut(ndarray::s![10..30, 40..60]).fill(true);
    let f = Field::with_mask(a, mask.clone()).unwrap();
    let cfg = TraceMomentConfig::default();
    let fc = TraceMomentFitConfig {
        universal: UniversalWeighting::Ols,
        ..Default::default()
    };
    let res = analyze_fields(std::slice::from_ref(&f), &cfg, &fc).unwrap();
    let sg = surrogate_errors(std::slice::from_ref(&f), &res, &cfg, &fc, 8, seed).unwrap();
    assert_eq!(
        (sg.params.alpha, sg.params.c1, sg.params.hurst),
        (res.alpha.min(2.0), res.c1, res.h.unwrap())
    );
    assert_eq!((sg.count, sg.used, sg.runs.len()), (8, 8, 8));
    // reads back from its JSON (NaN entries, null there, as NaN)
    let text = serde_json::to_string(&sg).unwrap();
    let back: SurrogateErrors = serde_json::from_str(&text).unwrap();
    assert_eq!(serde_json::to_string(&back).unwrap(), text);
    // the draws, one by one
    let alphas: Vec<f64> = (0..8)
        .map(|r| {
            let s = fif(&sg.params, n, n, surrogate_fif_seed(seed), r).unwrap();
            let s = Field::with_mask(s, mask.clone()).unwrap();
            assert_eq!(s.valid_count(), f.valid_count());
            analyze_fields(&[s], &cfg, &fc).unwrap().alpha
        })
        .collect();
    let got: Vec<f64> = sg.runs.iter().map(|r| r.alpha).collect();
    assert_eq!(got, alphas);
    assert!(sg.runs.iter().enumerate().all(|(i, r)| r.index == i));
    // never the noise of the data: `synth --seed S` draws FIF image i of S
    assert_ne!(surrogate_fif_seed(seed), seed);
    assert_ne!(
        fif(&sg.params, n, n, seed, 0).unwrap(),
        fif(&sg.params, n, n, surrogate_fif_seed(seed), 0).unwrap()
    );
    let (m, sd) = mean_std(&alphas);
    assert!((sg.alpha.mean - m).abs() < 1e-12 && (sg.alpha.sd - sd).abs() < 1e-12);
    assert!((sg.alpha.bias - (m - sg.params.alpha)).abs() < 1e-12);
    assert!((sg.alpha.bias_stderr - sd / 8f64.sqrt()).abs() < 1e-12);
    let rms = (sg.runs.iter().map(|r| r.alpha_stderr.powi(2)).sum::<f64>() / 8.0).sqrt();
    assert!((sg.alpha.stderr_ratio - rms / sd).abs() < 1e-12);
    // a bias beyond the error is a warning naming it, and only then
    for (name, st) in [("alpha", &sg.alpha), ("C1", &sg.c1), ("H", &sg.h)] {
        let warned = sg
            .warnings
            .iter()
            .any(|w| w.starts_with(&format!("{name}: biased")));
        let big = st.bias.abs() > st.sd && st.bias.abs() > 2.0 * st.bias_stderr;
        assert_eq!(warned, big, "{name}: {st:?} {:?}", sg.warnings);
    }
    // thread count
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap()
        .install(|| surrogate_errors(std::slice::from_ref(&f), &res, &cfg, &fc, 8, seed))
        .unwrap();
    assert_eq!(
        serde_json::to_string(&one).unwrap(),
        serde_json::to_string(&sg).unwrap()
    );
    // refused
    let e = surrogate_errors(std::slice::from_ref(&f), &res, &cfg, &fc, 7, seed).unwrap_err();
    assert!(e.to_string().contains("at least 8"), "{e}");
    let mut no_fit = res.clone();
    no_fit.alpha = f64::NAN;
    let e = surrogate_errors(std::slice::from_ref(&f), &no_fit, &cfg, &fc, 8, seed).unwrap_err();
    assert!(e.to_string().contains("universal fit"), "{e}");
    // estimates the generator cannot draw from are the data's problem
    // (Input), not a parameter the user gave
    let mut weak = res.clone();
    weak.c1 = 0.0;
    let e = surrogate_params(&weak).unwrap_err();
    assert!(
        matches!(e, wtmm::Error::Input(_)) && e.to_string().contains("outside the universal model"),
        "{e}"
    );
}

/// Do surrogate errors cover the truth? (Not a check: `cargo test --release
/// --test tracemoments experiment_surrogate_coverage -- --ignored
/// --nocapture`, env R fields (default 24) of SIZE² (256), K surrogates
/// each (16), SEED (901), the truth ALPHA, C1, H (topo-fif).) On single fields: per estimate the rms
/// over fields of (estimate - truth) in units of the surrogate error, of
/// the tile error, and of the surrogate error after removing the surrogate
/// bias; 1 is right, above 1 the errors understate.
#[test]
#[ignore]
fn experiment_surrogate_coverage() {
    use rayon::prelude::*;
    let env = |k: &str, d: u64| std::env::var(k).map_or(d, |s| s.parse().unwrap());
    let (r, n, k, seed) = (
        env("R", 24),
        env("SIZE", 256) as usize,
        env("K", 16) as usize,
        env("SEED", 901),
    );
    let cfg = TraceMomentConfig::default();
    let fc = TraceMomentFitConfig {
        universal: UniversalWeighting::Ols,
        ..Default::default()
    };
    let envf = |k: &str, d: f64| std::env::var(k).map_or(d, |s| s.parse().unwrap());
    let truth = FifParams {
        alpha: envf("ALPHA", FifParams::TOPO.alpha),
        c1: envf("C1", FifParams::TOPO.c1),
        hurst: envf("H", FifParams::TOPO.hurst),
    };
    let runs: Vec<(TraceMomentResult, SurrogateErrors)> = (0..r)
        .into_par_iter()
        .filter_map(|i| {
            let f = Field::new(fif(&truth, n, n, seed, i).unwrap());
            let res = analyze_fields(std::slice::from_ref(&f), &cfg, &fc).ok()?;
            let sg = surrogate_errors(std::slice::from_ref(&f), &res, &cfg, &fc, k, seed + 1 + i)
                .ok()?;
            Some((res, sg))
        })
        .collect();
    println!("{} of {r} fields with surrogates", runs.len());
    type Get = fn(&TraceMomentResult, &SurrogateErrors) -> (f64, f64, SurrogateStat);
    let stats: [(&str, f64, Get); 3] = [
        ("alpha", truth.alpha, |x, s| {
            (x.alpha, x.alpha_stderr, s.alpha)
        }),
        ("C1", truth.c1, |x, s| (x.c1, x.c1_stderr, s.c1)),
        ("H", truth.hurst, |x, s| {
            (x.h.unwrap(), x.h_stderr.unwrap(), s.h)
        }),
    ];
    for (name, t, get) in stats {
        let v: Vec<(f64, f64, SurrogateStat)> = runs.iter().map(|(x, s)| get(x, s)).collect();
        let rms = |z: Vec<f64>| (z.iter().map(|z| z * z).sum::<f64>() / z.len() as f64).sqrt();
        let est: Vec<f64> = v.iter().map(|x| x.0).collect();
        let (m, sd) = mean_std(&est);
        let z_sur = rms(v.iter().map(|(e, _, s)| (e - t) / s.sd).collect());
        let z_tile = rms(v.iter().map(|(e, se, _)| (e - t) / se).collect());
        let z_corr = rms(v.iter().map(|(e, _, s)| (e - s.bias - t) / s.sd).collect());
        let within = |z: Vec<f64>| z.iter().filter(|z| z.abs() <= 2.0).count();
        let c_sur = within(v.iter().map(|(e, _, s)| (e - t) / s.sd).collect());
        let c_tile = within(v.iter().map(|(e, se, _)| (e - t) / se).collect());
        let half = |s: &SurrogateStat| (s.quantiles[2] - s.quantiles[1]) / 2.0;
        let c_half = within(v.iter().map(|(e, _, s)| (e - t) / half(s)).collect());
        let sds: Vec<f64> = v.iter().map(|x| x.2.sd).collect();
        let biases: Vec<f64> = v.iter().map(|x| x.2.bias).collect();
        println!(
            "{name}: truth {t}, estimates {m:.4} (sd over fields {sd:.4}); surrogate sd mean {:.4}, \
             surrogate bias mean {:+.4}; rms z: surrogate {z_sur:.2}, tile {z_tile:.2}, \
             bias-corrected {z_corr:.2}; truth within 2 errors: surrogate {c_sur}, tile {c_tile}, \
             2 central-68 % half-widths {c_half} of {}",
            mean_std(&sds).0,
            mean_std(&biases).0,
            v.len()
        );
    }
}

/// A lone image that cannot give trace moments is named for what it is,
/// through the tiles as through the whole: all pixels missing, or too
/// small for the automatic derivative order (H = xi(1) over lags of 2 px
/// to a quarter of the side: 16 px or more).
#[test]
fn unusable_lone_images_say_why() {
    use wtmm::tracemoments::{TraceMomentFitConfig, analyze, analyze_tiled};
    let cfg = TraceMomentConfig::default();
    let fc = TraceMomentFitConfig::for_tiles();
    let nan = Field::new(Array2::from_elem((64, 64), f64::NAN));
    for e in [
        analyze_tiled(std::slice::from_ref(&nan), &cfg, &fc).unwrap_err(),
        analyze(&nan, cfg.clone(), &fc).unwrap_err(),
    ] {
        assert!(e.to_string().contains("every pixel is missing"), "{e}");
    }
    for n in [8usize, 12] {
        let f = Field::new(Array2::from_shape_fn((n, n), |(y, x)| {
            ((x * 7 + y * 13) % 17) as f64
        }));
        for e in [
            analyze_tiled(std::slice::from_ref(&f), &cfg, &fc).unwrap_err(),
            analyze(&f, cfg.clone(), &fc).unwrap_err(),
        ] {
            assert!(e.to_string().contains("needs 16 px or more"), "{n}: {e}");
        }
    }
    let f = Field::new(Array2::from_shape_fn((16, 16), |(y, x)| {
        ((x * 7 + y * 13) % 17) as f64
    }));
    analyze(&f, cfg, &fc).unwrap();
}

// ------------------------------------ normalisation by the ensemble mean

/// Every normalised output of the trace moments is blind to the field's
/// units (SPEC §8: φ is normalised so that its ensemble mean is 1): 4
/// topo-fif fields of 128² and the same fields times 3, through the whole
/// default chain (auto fractional derivative, gradient modulus, DTM, the
/// spectrum), give the same moment tables `log2 <φ_λ^q>` at every q and
/// level, and hence the same K(q), intercepts, log2 λ_eff, K(q, η), α, C1,
/// q_s, H and β. `log2 <φ_λ^q>` is `log2 Σ φ_λ^q - log2 count - q log2 <φ>`;
/// the last term is what cancels the `3^q`. Only the structure functions
/// are of the field itself: `log2 S_q` moves by `q log2 3` exactly.
///
/// Tolerance: the scaled fields differ by one rounding per pixel (1e-16
/// relative), which the filters (the fractional derivative's estimated
/// order too), log-sums and line fits carry at a few hundred ulp (measured:
/// 2e-12 at most on the moment tables), so `1e-9` relative (plus `1e-12`
/// absolute for the values that are 0 up to rounding, at q = 1) leaves a
/// margin of 500 while any error in the normalisation's power of the mean
/// shows at `|q - 1| log2 3`, 0.16 already at q = 0.9. (The slopes K(q)
/// cannot see such an error: it is the same at every level; the
/// intercepts and λ_eff do.) α, C1, q_s and H come from the universal
/// fit, whose α is the argmin of a least-squares sum by golden section: a
/// minimum pins its argument only to `sqrt(ε) ≈ 1.5e-8` relative
/// (measured here: α 5e-11, q_s 1.1e-9), so those get `1e-6`.
#[test]
fn normalised_trace_moments_ignore_the_field_scale() {
    let arrays: Vec<Array2<f64>> = (0..4)
        .map(|i| fif(&FifParams::TOPO, 128, 128, 21, i).unwrap())
        .collect();
    let run = |scale: f64| {
        let parts: Vec<TraceMomentAccumulator> = arrays
            .iter()
            .map(|a| {
                let mut acc = TraceMomentAccumulator::new(TraceMomentConfig::default()).unwrap();
                acc.add_field(&Field::new(a.mapv(|v| scale * v))).unwrap();
                acc
            })
            .collect();
        merge_except(&parts, &[])
            .finish(&TraceMomentFitConfig::default())
            .unwrap()
    };
    let (a, b) = (run(1.0), run(3.0));
    let close = |what: &str, x: f64, y: f64, rel: f64| {
        assert!(
            x == y
                || (x.is_nan() && y.is_nan())
                || (x - y).abs() <= rel * x.abs().max(y.abs()) + 1e-12,
            "{what}: {x} for the field, {y} for 3 x the field"
        );
    };
    let same = |what: &str, x: f64, y: f64| close(what, x, y, 1e-9);
    let all = |what: &str, x: &[f64], y: &[f64]| {
        assert_eq!(x.len(), y.len(), "{what}");
        for (i, (u, v)) in x.iter().zip(y).enumerate() {
            same(&format!("{what}[{i}]"), *u, *v);
        }
    };
    for (iq, q) in a.q.iter().enumerate() {
        all(
            &format!("log2 moments at q = {q}"),
            &a.log2_moments[iq],
            &b.log2_moments[iq],
        );
    }
    for (iq, q) in a.dtm_q.iter().enumerate() {
        for (ie, eta) in a.eta.iter().enumerate() {
            all(
                &format!("DTM moments at q = {q}, eta = {eta}"),
                &a.log2_moments_eta[iq][ie],
                &b.log2_moments_eta[iq][ie],
            );
        }
    }
    all("K", &a.k, &b.k);
    all("K intercept", &a.k_intercept, &b.k_intercept);
    for (iq, (x, y)) in a.k_eta.iter().zip(&b.k_eta).enumerate() {
        all(&format!("K(q, eta) at dtm q {}", a.dtm_q[iq]), x, y);
    }
    all("xi", &a.xi, &b.xi);
    for (what, x, y) in [
        ("log2 lambda_eff", a.log2_lambda_eff, b.log2_lambda_eff),
        ("DTM alpha", a.dtm_alpha, b.dtm_alpha),
        ("DTM C1", a.dtm_c1, b.dtm_c1),
        ("diff order", a.diff_order, b.diff_order),
        ("beta", a.beta.unwrap(), b.beta.unwrap()),
    ] {
        same(what, x, y);
    }
    for (what, x, y) in [
        ("alpha", a.alpha, b.alpha),
        ("C1", a.c1, b.c1),
        ("q_s", a.q_s, b.q_s),
        ("H", a.h.unwrap(), b.h.unwrap()),
    ] {
        close(what, x, y, 1e-6);
    }
    // the moments are not trivially flat: the check has something to see
    let i2 = a.q.iter().position(|&q| (q - 2.0).abs() < 1e-9).unwrap();
    assert!(
        a.log2_lambda_eff.is_finite() && a.k[i2] > 0.05,
        "log2 lambda_eff {}, K(2) {}",
        a.log2_lambda_eff,
        a.k[i2]
    );
    let shift = 3f64.log2();
    for (iq, q) in a.sf_q.iter().enumerate() {
        let moved: Vec<f64> = a.log2_sf[iq].iter().map(|v| v + q * shift).collect();
        all(&format!("log2 S_q at q = {q}"), &moved, &b.log2_sf[iq]);
    }
}

/// `(what, z)` for the normalised moments of 64 log-normal [`cascade`]s of
/// 64² (6 steps, C1 = 0.1, seed `seed`) multiplied by 3: z is the estimate
/// minus its exact expectation over its jackknife error (over the images,
/// computed here: the library reports none for the moments). Exact (the
/// cascade's multipliers have `<W> = 1`, so `<φ> = 3`, and the
/// normalisation must remove `3^q`): at the pixels (log2 λ = 6) the bare
/// `log2 <φ^q> = 6 K(q)` for every q, tested at 0 < q <= 2, q != 1 (where
/// it is 0 with no error); at every level, q = 2, the dressed
/// `k log2 <W²> + log2 <Z²_(6-k)>` of `lognormal_cascade_recovers_k_alpha_c1`.
fn scaled_cascade_moment_z(seed: u64) -> Vec<(String, f64)> {
    use rayon::prelude::*;
    let (steps, c1) = (6, 0.1);
    let s = (c1 * 2.0 * std::f64::consts::LN_2).sqrt();
    let parts: Vec<TraceMomentAccumulator> = (0..64u64)
        .into_par_iter()
        .map(|i| {
            let mut a = TraceMomentAccumulator::new(TraceMomentConfig::default()).unwrap();
            a.add_flux((cascade(steps, s, seed, i) * 3.0).view(), None)
                .unwrap();
            a
        })
        .collect();
    let fc = TraceMomentFitConfig::default();
    let res = merge_except(&parts, &[]).finish(&fc).unwrap();
    let loo: Vec<TraceMomentResult> = (0..parts.len())
        .into_par_iter()
        .map(|i| merge_except(&parts, &[i]).finish(&fc).unwrap())
        .collect();
    let z = |iq: usize, lev: usize, want: f64| {
        let v: Vec<f64> = loo.iter().map(|r| r.log2_moments[iq][lev]).collect();
        (res.log2_moments[iq][lev] - want) / wtmm::stats::jackknife_se(&v)
    };
    let mut out = Vec::new();
    let w2 = (s * s).exp();
    let mut z2 = vec![1.0f64];
    for m in 1..=steps {
        z2.push(w2 * z2[m - 1] / 4.0 + 0.75);
    }
    let i2 = res.q.iter().position(|&q| (q - 2.0).abs() < 1e-9).unwrap();
    for (lev, &x) in res.log2_lambda.iter().enumerate() {
        let k = x as usize;
        let want = k as f64 * w2.log2() + z2[steps - k].log2();
        out.push((format!("q = 2, log2 lambda = {k}"), z(i2, lev, want)));
    }
    assert_eq!(res.log2_lambda[0], steps as f64, "level 0 is the pixel");
    for (iq, &q) in res.q.iter().enumerate() {
        if q <= 2.0 + 1e-9 && (q - 1.0).abs() > 1e-9 {
            let want = steps as f64 * c1 * (q * q - q);
            out.push((format!("pixels, q = {q}"), z(iq, 0, want)));
        }
    }
    out
}

/// The normalised moment tables are the theory's values, not only their
/// slopes (SPEC §8): on a cascade multiplied by 3 (`scaled_cascade_moment_z`)
/// every tested `log2 <φ_λ^q>` lies within 4 jackknife errors of its exact
/// expectation. Honest errors: over 32 independent ensembles (seeds
/// 200-231, `experiment_scaled_cascade_moments`) the z of every tested
/// moment had sd 0.73-1.06 and lay within [-2.79, 1.87] (with 16 images of
/// 128² instead the sampling distribution was skewed, z down to -4.0,
/// hence 64 images).
/// A normalisation by `<φ>` instead of `<φ>^q` would move every value by
/// `(q - 1) log2 3`: 1.58 at q = 2, where the error is about 0.1-0.2.
/// About 0.5 s.
#[test]
fn normalised_moments_of_a_scaled_cascade_are_exact() {
    let zs = scaled_cascade_moment_z(12);
    assert!(zs.len() >= 25, "{} values tested", zs.len());
    let worst = zs.iter().map(|(_, z)| z.abs()).fold(0.0, f64::max);
    println!(
        "scaled cascade: worst of {} moments {worst:.2} errors",
        zs.len()
    );
    for (what, z) in zs {
        assert!(z.abs() < 4.0, "{what}: {z:+.2} jackknife errors from exact");
    }
}

/// The calibration of `normalised_moments_of_a_scaled_cascade_are_exact`
/// (not a check; `cargo test --release --test tracemoments
/// experiment_scaled_cascade_moments -- --ignored --nocapture`, env SEEDS
/// (default 32) ensembles from seed 200; about 15 s): the mean, sd and range
/// of z per tested moment.
#[test]
#[ignore]
fn experiment_scaled_cascade_moments() {
    let seeds: u64 = std::env::var("SEEDS").map_or(32, |s| s.parse().unwrap());
    let runs: Vec<Vec<(String, f64)>> = (200..200 + seeds).map(scaled_cascade_moment_z).collect();
    for (j, (what, _)) in runs[0].iter().enumerate() {
        let v: Vec<f64> = runs.iter().map(|r| r[j].1).collect();
        let (m, sd) = mean_std(&v);
        let (lo, hi) = v
            .iter()
            .fold((f64::MAX, f64::MIN), |(a, b), &x| (a.min(x), b.max(x)));
        println!("{what}: z mean {m:+.2} sd {sd:.2} in [{lo:+.2}, {hi:+.2}]");
    }
}

// ------------------------------------------- FIF at other Lévy indices

/// `<φ_l²>` exactly, for the FIF flux of `p` on `n x n` (n a power of two)
/// and boxes of side `l = 2^k`, k = 0..=log2 n, as the trace moments tile
/// them. From the recipe of `synth::fif` (SPEC §9): `Γ(x) = c Σ_r g(r)
/// Y(x - r) + d` on the torus, `g(0) = G^(1/α)`, `g(r) = |r|^(-2/α)` for
/// `0 < |r| <= n/2` (minimum image), `c^α = C1/2π`, Y i.i.d. unit extremal
/// Lévy (`ln <e^{sY}> = (s^α - s)/(α - 1)`, `s ln s` at α = 1) and the
/// drift `d` making `<φ> = 1`. Then `Γ(x) + Γ(x + δ)` is the positive
/// combination `w_r = g(r) + g(r + δ)` of the same independent Y, so
/// `ln <φ(x) φ(x + δ)> = c^α (Σ w^α - 2 S_α)/(α - 1)` (`c Σ (w ln w - 2 g
/// ln g)` at α = 1, `S_α = Σ g^α`) for every δ, not only asymptotically;
/// `<φ_l²> = l^-4 Σ_δ (l - |δx|)(l - |δy|) <φ(x) φ(x + δ)>`. At l = 1 this
/// is the pixel moment `λ_eff^K(2)`. The kernel is rebuilt here and its
/// sums checked against the generator's [`FifKernel`] to rounding.
fn fif_exact_box_m2(p: &FifParams, n: usize) -> Vec<f64> {
    use rayon::prelude::*;
    use wtmm::fourier::signed_bin;
    use wtmm::synth::fif::{FifKernel, SELF_WEIGHT};
    let a = p.alpha;
    let sb = |i: usize| signed_bin(i, n) as f64;
    let mut g = vec![0.0; n * n];
    g[0] = SELF_WEIGHT.powf(1.0 / a);
    let r2max = (n as f64 / 2.0).powi(2);
    for y in 0..n {
        for x in 0..n {
            let r2 = sb(y).powi(2) + sb(x).powi(2);
            if r2 > 0.0 && r2 <= r2max {
                g[y * n + x] = r2.powf(-1.0 / a);
            }
        }
    }
    let xlnx = |v: f64| if v > 0.0 { v * v.ln() } else { 0.0 };
    let s_alpha: f64 = g.iter().map(|v| v.powf(a)).sum();
    let s_glng: f64 = g.iter().map(|&v| xlnx(v)).sum();
    let kern = FifKernel::new(p, n, n).unwrap();
    let s_one: f64 = g.iter().sum();
    for (what, mine, lib) in [
        ("S_alpha", s_alpha, kern.s_alpha),
        ("S_1", s_one, kern.s_one),
        ("sum g ln g", s_glng, kern.s_glng),
    ] {
        assert!(
            (mine - lib).abs() < 1e-10 * lib.abs(),
            "{what}: {mine} rebuilt, {lib} in the generator"
        );
    }
    let one = (a - 1.0).abs() < 1e-9;
    let c = (p.c1 / (2.0 * std::f64::consts::PI)).powf(1.0 / a);
    // g is symmetric under reflections and the swap of the axes, so the
    // pair moment depends on (|δy|, |δx|) sorted: 0 <= δy <= δx <= n/2
    let h = n / 2;
    let pairs: Vec<(usize, usize)> = (0..=h)
        .flat_map(|dx| (0..=dx).map(move |dy| (dy, dx)))
        .collect();
    let ln_pair: Vec<f64> = pairs
        .par_iter()
        .map(|&(dy, dx)| {
            let mut s = 0.0;
            for y in 0..n {
                let (row, row2) = (&g[y * n..(y + 1) * n], &g[(y + dy) % n * n..]);
                for (x, gv) in row.iter().enumerate() {
                    let w = gv + row2[(x + dx) % n];
                    s += if one { xlnx(w) } else { w.powf(a) };
                }
            }
            if one {
                c * (s - 2.0 * s_glng)
            } else {
                c.powf(a) * (s - 2.0 * s_alpha) / (a - 1.0)
            }
        })
        .collect();
    let mut pair = vec![0.0; (h + 1) * (h + 1)];
    for (&(dy, dx), v) in pairs.iter().zip(&ln_pair) {
        pair[dy * (h + 1) + dx] = v.exp();
        pair[dx * (h + 1) + dy] = v.exp();
    }
    let fold = |d: i64| signed_bin(d.rem_euclid(n as i64) as usize, n).unsigned_abs() as usize;
    (0..=n.trailing_zeros())
        .map(|k| {
            let l = 1i64 << k;
            let mut s = 0.0;
            for dy in 1 - l..l {
                for dx in 1 - l..l {
                    let w = ((l - dy.abs()) * (l - dx.abs())) as f64;
                    s += w * pair[fold(dy) * (h + 1) + fold(dx)];
                }
            }
            s / (l as f64).powi(4)
        })
        .collect()
}

/// What [`fif_flux_check`] measures on one ensemble.
struct FifFluxCheck {
    /// K(2) of the trace moments and its jackknife error over the images.
    k2: f64,
    k2_se: f64,
    /// K(2) the exact box moments give over the same fit range, and the
    /// universal `C1 (2^α - 2)/(α - 1)`.
    k2_dressed: f64,
    k2_universal: f64,
    /// The pixel means of φ and φ² over the images, with their standard
    /// errors from the per-image scatter, and the exact `<φ²>`.
    mean: (f64, f64),
    mean2: (f64, f64),
    mean2_exact: f64,
}

/// 128 FIF fluxes of 64² at (α, C1 = 0.1), seed `seed`: their trace
/// moments' K(2) (jackknife error of [`finish_ensemble`], OLS universal fit:
/// only K(2) is used) and their raw pixel moments, with the exact values
/// of [`fif_exact_box_m2`].
fn fif_flux_check(alpha: f64, seed: u64) -> FifFluxCheck {
    use rayon::prelude::*;
    let (n, count) = (64, 128u64);
    let p = FifParams {
        alpha,
        c1: 0.1,
        hurst: 0.5,
    };
    let config = TraceMomentConfig {
        q: vec![0.5, 1.0, 1.5, 2.0],
        eta: vec![0.5, 1.0, 2.0],
        ..Default::default()
    };
    let per: Vec<(TraceMomentAccumulator, f64, f64)> = (0..count)
        .into_par_iter()
        .map(|i| {
            let phi = wtmm::synth::fif::fif_flux(&p, n, n, seed, i).unwrap();
            let mut a = TraceMomentAccumulator::new(config.clone()).unwrap();
            a.add_flux(phi.view(), None).unwrap();
            let m2 = phi.iter().map(|v| v * v).sum::<f64>() / (n * n) as f64;
            (a, phi.mean().unwrap(), m2)
        })
        .collect();
    let parts: Vec<TraceMomentAccumulator> = per.iter().map(|t| t.0.clone()).collect();
    let fc = TraceMomentFitConfig {
        universal: UniversalWeighting::Ols,
        ..Default::default()
    };
    let (_, res) = finish_ensemble(&parts, &fc).unwrap();
    let i2 = res.q.iter().position(|&q| q == 2.0).unwrap();
    let m2 = fif_exact_box_m2(&p, n);
    // the expected moment line over the fitted levels (log2 λ = log2 n - k)
    let (lo, hi) = res.fit_log2_lambda;
    let (x, y): (Vec<f64>, Vec<f64>) = m2
        .iter()
        .enumerate()
        .map(|(k, v)| (res.log2_lambda[k], v.log2()))
        .filter(|(x, _)| *x >= lo - 1e-9 && *x <= hi + 1e-9)
        .unzip();
    let stats = |v: Vec<f64>| {
        let (m, sd) = mean_std(&v);
        (m, sd / (v.len() as f64).sqrt())
    };
    FifFluxCheck {
        k2: res.k[i2],
        k2_se: res.k_stderr[i2],
        k2_dressed: wtmm::stats::line_fit(&x, &y).unwrap().slope,
        k2_universal: th::k(&p, 2.0),
        mean: stats(per.iter().map(|t| t.1).collect()),
        mean2: stats(per.iter().map(|t| t.2).collect()),
        mean2_exact: m2[0],
    }
}

/// The FIF flux at Lévy index `alpha` (SPEC §9; TM §3.3) against what its
/// recipe fixes exactly, each within 4 standard errors of this ensemble
/// ([`fif_flux_check`], seed 7):
/// * K(2) of the trace moments against the slope of the exact box
///   moments over the fitted boxes (2-32 px), not the bare universal K(2):
///   the boxes are "dressed" (module docs of `synth::fif`: pixel moments
///   follow `λ_eff ≈ 5.4 L`, box slopes run a few % above K), and on 64²
///   the exact slope is 0.1298 against 0.1211 at α = 0.6, 0.1480 against
///   0.1386 at α = 1, 0.2035 against 0.2 at α = 2. Error: the jackknife
///   of [`finish_ensemble`];
/// * `<φ> = 1` (conservation; the drift d of each α branch sets it) and,
///   with `second`, `<φ²> = λ_eff^K(2)` (`fif_lambda_eff`), errors from the
///   scatter of the i.i.d. image means.
///
/// Calibration (`experiment_fif_other_alpha`, 24 ensembles, seeds
/// 100-123): K(2) - exact slope = +0.0006 ± 0.0006, -0.0002 ± 0.0007,
/// -0.0014 ± 0.0014 (α = 0.6, 1, 2: unbiased), its sd over the ensembles
/// 0.0029, 0.0033, 0.0069 against mean jackknife errors 0.0031, 0.0031,
/// 0.0074 (honest), while the bare universal K(2) was 1.2-4.6 errors away
/// at α <= 1 in every ensemble. The z of `<φ>` lay in [-2.3, 2.0] (α <= 1)
/// and [-2.7, 1.9] (α = 2), that of `<φ²>` in [-2.4, 2.0] for α <= 1;
/// at α = 2 (log-normal φ with ln-variance 1.17 at the pixel, so φ² has
/// 4.7) it reached -4.6: the image means of φ² are too skewed for a
/// normal error, and that check is left out there.
fn assert_fif_flux(alpha: f64, second: bool) {
    let r = fif_flux_check(alpha, 7);
    println!(
        "alpha {alpha}: K(2) {:.4} +- {:.4}, exact box slope {:.4}, universal {:.4}; <phi> {:.4} +- {:.4}; <phi^2> {:.4} +- {:.4}, exact {:.4}",
        r.k2,
        r.k2_se,
        r.k2_dressed,
        r.k2_universal,
        r.mean.0,
        r.mean.1,
        r.mean2.0,
        r.mean2.1,
        r.mean2_exact
    );
    assert!(
        (r.k2 - r.k2_dressed).abs() < 4.0 * r.k2_se,
        "alpha {alpha}: K(2) {} +- {}, exact box slope {}",
        r.k2,
        r.k2_se,
        r.k2_dressed
    );
    assert!(
        (r.mean.0 - 1.0).abs() < 4.0 * r.mean.1,
        "alpha {alpha}: <phi> = {} +- {}, conservation wants 1",
        r.mean.0,
        r.mean.1
    );
    // the exact pixel moment is the documented λ_eff^K(2), to rounding
    let le = wtmm::synth::fif::fif_lambda_eff(64, 64).unwrap();
    let want = le.powf(r.k2_universal);
    assert!(
        (r.mean2_exact - want).abs() < 1e-9 * want,
        "alpha {alpha}: exact <phi^2> {} vs lambda_eff^K(2) {want}",
        r.mean2_exact
    );
    if second {
        assert!(
            (r.mean2.0 - want).abs() < 4.0 * r.mean2.1,
            "alpha {alpha}: <phi^2> = {} +- {}, lambda_eff^K(2) = {want}",
            r.mean2.0,
            r.mean2.1
        );
    }
}

/// α < 1: the noise is bounded above with a heavy left tail (module docs of
/// `synth::fif`); see [`assert_fif_flux`]. About 0.3 s.
#[test]
fn fif_flux_alpha_0_6_has_its_exact_moments() {
    assert_fif_flux(0.6, true);
}

/// α = 1, the branch with its own noise formula and drift `d = -c (S_1 ln
/// c + Σ g ln g)`; see [`assert_fif_flux`]. A wrong drift multiplies φ by
/// a constant, which the normalised trace moments cannot see but `<φ> = 1`
/// does (d = 3.1 here: 1.5 d gives `<φ>` 4.8, -d gives 0.002). About 0.3 s.
#[test]
fn fif_flux_alpha_1_has_its_exact_moments() {
    assert_fif_flux(1.0, true);
}

/// α = 2, the log-normal generator; see [`assert_fif_flux`] (without the
/// `<φ²>` check). About 0.3 s.
#[test]
fn fif_flux_alpha_2_has_its_exact_moments() {
    assert_fif_flux(2.0, false);
}

/// The calibration behind [`assert_fif_flux`] (not a check; `cargo test
/// --release --test tracemoments experiment_fif_other_alpha -- --ignored
/// --nocapture`, env SEEDS (default 24) ensembles from seed 100; about
/// 15 s): per α, K(2) minus the exact box slope (mean ± se over the
/// ensembles), its sd against the mean jackknife error, the z against
/// the universal K(2), and the range of the z of `<φ>` and `<φ²>`.
#[test]
#[ignore]
fn experiment_fif_other_alpha() {
    let seeds: u64 = std::env::var("SEEDS").map_or(24, |s| s.parse().unwrap());
    let range = |v: &[f64]| {
        v.iter()
            .fold((f64::MAX, f64::MIN), |(a, b), &x| (a.min(x), b.max(x)))
    };
    for alpha in [0.6, 1.0, 2.0] {
        let runs: Vec<FifFluxCheck> = (100..100 + seeds)
            .map(|s| fif_flux_check(alpha, s))
            .collect();
        let d: Vec<f64> = runs.iter().map(|r| r.k2 - r.k2_dressed).collect();
        let (md, sd) = mean_std(&d);
        let (jk, _) = mean_std(&runs.iter().map(|r| r.k2_se).collect::<Vec<_>>());
        let zu: Vec<f64> = runs
            .iter()
            .map(|r| (r.k2 - r.k2_universal) / r.k2_se)
            .collect();
        let z1: Vec<f64> = runs.iter().map(|r| (r.mean.0 - 1.0) / r.mean.1).collect();
        let z2: Vec<f64> = runs
            .iter()
            .map(|r| (r.mean2.0 - r.mean2_exact) / r.mean2.1)
            .collect();
        println!(
            "alpha {alpha}: K(2) - exact slope {md:+.4} +- {:.4} (sd {sd:.4}, mean jackknife {jk:.4}); z vs universal {:?}; z <phi> {:?}; z <phi^2> {:?}",
            sd / (seeds as f64).sqrt(),
            range(&zu),
            range(&z1),
            range(&z2)
        );
    }
}

/// The structure-function lines drawn in `sf.png` are the fits that gave
/// xi(q): over the lags fitted, the residuals about `xi log2 l +
/// xi_intercept` sum to zero and are orthogonal to `log2 l` (the normal
/// equations of least squares), to rounding. (And a lone image's beta
/// error is named as the fit's.)
#[test]
fn sf_fit_lines_are_the_least_squares_lines() {
    let (f, cfg) = periodic_fbm(0.4, 128, 5);
    let r = lone(&f, &cfg);
    // the tiles of one image share its spectrum: beta keeps the fit's
    // error, and says so (estimates.csv reads it)
    assert!(
        r.stderr_method.starts_with("jackknife over"),
        "{}",
        r.stderr_method
    );
    assert_eq!(r.beta_stderr_method, "regression (the spectrum's fit)");
    let (lo, hi) = r.fit_log2_lag;
    assert_eq!(r.xi_intercept.len(), r.sf_q.len());
    for (i, q) in r.sf_q.iter().enumerate() {
        let (mut s0, mut s1, mut n) = (0.0, 0.0, 0);
        for (&x, &y) in r.log2_lag.iter().zip(&r.log2_sf[i]) {
            if x >= lo - 1e-9 && x <= hi + 1e-9 {
                let e = y - (r.xi[i] * x + r.xi_intercept[i]);
                s0 += e;
                s1 += e * x;
                n += 1;
            }
        }
        assert!(n >= 3, "q = {q}: {n} lags fitted");
        assert!(s0.abs() < 1e-9 && s1.abs() < 1e-9, "q = {q}: {s0} {s1}");
    }
}

/// Every number of two results within `rel` of each other (relative, or
/// absolute below 1), strings and nulls equal; `path` names the first
/// that differs.
fn assert_json_close(a: &serde_json::Value, b: &serde_json::Value, rel: f64, path: &str) {
    use serde_json::Value;
    match (a, b) {
        (Value::Number(x), Value::Number(y)) => {
            let (x, y) = (x.as_f64().unwrap(), y.as_f64().unwrap());
            assert!(
                (x - y).abs() <= rel * x.abs().max(y.abs()).max(1.0),
                "{path}: {x} against {y}"
            );
        }
        (Value::Array(x), Value::Array(y)) => {
            assert_eq!(x.len(), y.len(), "{path}: lengths");
            for (i, (u, v)) in x.iter().zip(y).enumerate() {
                assert_json_close(u, v, rel, &format!("{path}[{i}]"));
            }
        }
        (Value::Object(x), Value::Object(y)) => {
            let keys = |o: &serde_json::Map<String, Value>| o.keys().cloned().collect::<Vec<_>>();
            assert_eq!(keys(x), keys(y), "{path}: keys");
            for (k, u) in x {
                assert_json_close(u, &y[k], rel, &format!("{path}.{k}"));
            }
        }
        _ => assert_eq!(a, b, "{path}"),
    }
}

/// A transposed image gives the same trace moments, universal fit, DTM,
/// structure functions, spectrum and tile errors (to rounding: the box
/// sums add in another order): the gradient stencil, box windows, tiles,
/// increments and isotropic spectrum all treat x and y alike. (A flip
/// does not: the forward-difference gradient sees a flipped field through
/// other pixel triangles; README, Conventions, "Orientation".) Non-square
/// and not a power of two, so the windows are anchored at the corners.
#[test]
fn trace_moments_do_not_depend_on_a_transpose() {
    let img = fif(&FifParams::TOPO, 150, 200, 9, 0).unwrap();
    let cfg = TraceMomentConfig::default();
    let fc = TraceMomentFitConfig::default();
    let run = |a: Array2<f64>| {
        let (_, r) = analyze_tiled(&[Field::new(a)], &cfg, &fc).unwrap();
        serde_json::to_value(&r).unwrap()
    };
    let (a, mut b) = (run(img.clone()), run(img.t().to_owned()));
    assert!(
        a["stderr_method"].as_str().unwrap().contains("tiles"),
        "{}",
        a["stderr_method"]
    );
    assert!(a["alpha"].as_f64().unwrap().is_finite());
    // the tiles are described by their sides, which a transpose swaps
    for key in ["stderr_method", "universal_fit"] {
        let t = b[key]
            .as_str()
            .unwrap()
            .replace("66-67 x 75 px", "75 x 66-67 px");
        assert_ne!(Some(t.as_str()), b[key].as_str(), "{key}: {}", b[key]);
        b[key] = t.into();
    }
    // The box sums add in another order (rounding of 1e-16); the GLS
    // errors by a nested jackknife over 6 tiles, through a covariance of
    // 26 K(q) from 5 tiles, amplify it to 5e-9 (alpha_stderr), the rest
    // stays within 1e-12. An asymmetry of the method moves results by far
    // more: a flip, which the gradient stencil does not treat alike,
    // moves alpha by 0.004-0.03 on the DEMs.
    assert_json_close(&a, &b, 1e-7, "result");
}

/// Trace moments measure the flux's variability, not its units: a field
/// multiplied by any factor, or moved by any offset, gives the same K(q),
/// K(q, η), α, C1 and H. Scale: the field brought to a maximum of 1e99
/// (inside the documented amplitude limit of 1e100), where the raw φ^η of
/// the double trace moments overflowed at η = 3.16 and 10 (K(q, η) was
/// lost, and left out of the DTM fit without a word). Offset: 1e13 on a
/// field of unit roughness against the same rounded values without it,
/// `(f + c) - c`: the data's own rounding is then the same, and what is
/// left is the code's (the FFT of the raw field in the fractional
/// derivative, the raw sums of the plane fit: on this field 3.6e-4 in α,
/// 6e-4 in the DTM α, 4.5e-5 in H).
#[test]
fn scale_and_offset_leave_trace_moments_alone() {
    let (f, _) = periodic_fbm(0.4, 128, 77);
    let mut cfg = TraceMomentConfig::default();
    cfg.eta.push(10.0);
    let run = |data: Array2<f64>| {
        let mut acc = TraceMomentAccumulator::new(cfg.clone()).unwrap();
        acc.add_field(&Field::new(data)).unwrap();
        acc.finish(&TraceMomentFitConfig::default()).unwrap()
    };
    let close = |what: &str, a: &TraceMomentResult, b: &TraceMomentResult, tol: f64| {
        let pairs = [
            ("alpha", a.alpha, b.alpha),
            ("C1", a.c1, b.c1),
            ("H", a.h.unwrap(), b.h.unwrap()),
            ("dtm alpha", a.dtm_alpha, b.dtm_alpha),
            ("beta", a.beta.unwrap(), b.beta.unwrap()),
        ];
        for (name, x, y) in pairs {
            assert!(
                x.is_finite() && (x - y).abs() <= tol,
                "{what}: {name} {x} vs {y}"
            );
        }
        for (x, y) in a.k.iter().zip(&b.k) {
            assert!((x - y).abs() <= tol, "{what}: K {x} vs {y}");
        }
        for (ie, (x, y)) in a.k_eta[0].iter().zip(&b.k_eta[0]).enumerate() {
            assert!(
                x.is_finite() && y.is_finite() && (x - y).abs() <= tol,
                "{what}: K(1.5, η = {}) {x} vs {y}",
                cfg.eta[ie]
            );
        }
    };
    let base = run(f.data.clone());
    let peak = f.data.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    // a power of two: the scaled values are exact, only the code rounds
    let s = 2f64.powi((1e99 / peak).log2().floor() as i32);
    close(
        "x 2^k up to 1e99",
        &base,
        &run(f.data.mapv(|v| v * s)),
        1e-9,
    );
    let c = 1e13;
    let shifted = f.data.mapv(|v| v + c);
    let back = shifted.mapv(|v| v - c);
    close("offset 1e13", &run(back), &run(shifted), 1e-11);
}

/// A torus is differentiated as one (`periodic`): on FIF fields integrated
/// to order H, a derivative of order H gives back the generator's flux
/// (less its mean) to rounding, so the trace moments equal those of the
/// fields generated with H = 0 (the same noise). The mirror extension a
/// non-periodic field needs does not: at alpha = 0.5 it fills the flux's
/// holes and moves K(q) (8 x 512^2: C1 0.069 mirrored, 0.081 periodic).
/// On the torus the gradient wraps, so the flux is conserved exactly.
#[test]
fn a_torus_is_differentiated_as_one() {
    let (n, n_img, seed) = (128, 4, 11);
    let fields = |h: f64| -> Vec<Field> {
        let p = FifParams {
            alpha: 0.5,
            c1: 0.1,
            hurst: h,
        };
        (0..n_img)
            .map(|i| Field::new(fif(&p, n, n, seed, i).unwrap()))
            .collect()
    };
    let k = |fs: &[Field], diff: f64, periodic: bool| -> Vec<f64> {
        let mut a = TraceMomentAccumulator::new(TraceMomentConfig {
            diff: FluxDiff::Order(diff),
            periodic,
            ..Default::default()
        })
        .unwrap();
        for f in fs {
            a.add_field(f).unwrap();
        }
        a.finish(&TraceMomentFitConfig::default()).unwrap().k
    };
    let (integrated, flux) = (fields(0.5), fields(0.0));
    let exact = k(&flux, 0.0, true);
    let max_gap = |x: &[f64]| {
        x.iter()
            .zip(&exact)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max)
    };
    let kt = k(&integrated, 0.5, true);
    let (torus, mirrored) = (max_gap(&kt), max_gap(&k(&integrated, 0.5, false)));
    let at_q1 = (kt[9] - exact[9]).abs();
    println!(
        "max |K - K(flux)|: periodic {torus:.2e} (q = 1: {at_q1:.2e}), mirrored {mirrored:.2e}"
    );
    // the holes of an alpha = 0.5 flux (values down to 1e-100) lie below
    // the rounding of either route's FFTs (1e-16 of the field), which sets
    // their box means and so the smallest moments: the two agree to that
    // rounding, not to 1e-12; at q = 1 the holes weigh nothing
    assert!(
        at_q1 < 1e-9,
        "periodic derivative: K(1) off the flux's by {at_q1}"
    );
    assert!(
        torus < 0.05 * mirrored,
        "periodic derivative: K off the flux's by {torus}, mirrored by {mirrored}"
    );
    assert!(mirrored > 1e-3, "mirrored: K off by only {mirrored}");
    // on the torus every box is whole (the last row's forward neighbour is
    // the first), so the flux's mean is the same at every scale: K(1) = 0
    // to rounding; the plane's last row and column have no flux, and the
    // boxes along them weigh as whole ones
    let plane = k(&flux, 0.0, false);
    println!("K(1): torus {:.1e}, plane {:.1e}", exact[9], plane[9]);
    assert!(exact[9].abs() < 1e-12, "K(1) on the torus {}", exact[9]);
    assert!(kt[9].abs() < 1e-12, "K(1) on the torus {}", kt[9]);
    // a periodic accumulator does not merge with a mirrored one, and a
    // stored config without the key was mirrored
    let cfg = TraceMomentConfig {
        periodic: true,
        ..Default::default()
    };
    assert!(!cfg.same_settings(&TraceMomentConfig::default()));
    let mut v = serde_json::to_value(&cfg).unwrap();
    v.as_object_mut().unwrap().remove("periodic");
    let old: TraceMomentConfig = serde_json::from_value(v).unwrap();
    assert!(!old.periodic);
}

/// The universal K(q) and both its derivatives vanish at q = 1, so that
/// point carries nothing on alpha or C1; GLS would still use its residual
/// through the covariance (a control variate). On a torus K(1) = 0 in every
/// jackknife sample and its variance is rounding, so the fit would follow
/// the rounding; here the same fields scaled by a constant (K(q) unchanged
/// but for rounding) must give the same GLS fit to rounding.
#[test]
fn gls_does_not_follow_rounding_at_q_1() {
    let (n, n_img, seed) = (128, 8, 21);
    let p = FifParams {
        alpha: 1.8,
        c1: 0.12,
        hurst: 0.7,
    };
    let raw: Vec<Array2<f64>> = (0..n_img)
        .map(|i| fif(&p, n, n, seed, i).unwrap())
        .collect();
    let fit = |scale: f64| -> TraceMomentResult {
        let cfg = TraceMomentConfig {
            periodic: true,
            ..Default::default()
        };
        let mut whole = TraceMomentAccumulator::new(cfg.clone()).unwrap();
        let mut parts = Vec::new();
        for f in &raw {
            let mut a = TraceMomentAccumulator::new(cfg.clone()).unwrap();
            a.add_field(&Field::new(f.mapv(|v| v * scale + 0.25)))
                .unwrap();
            whole.merge(&a).unwrap();
            parts.push(a);
        }
        finish_jackknife(&whole, &parts, &TraceMomentFitConfig::default(), "images").unwrap()
    };
    let (a, b) = (fit(1.0), fit(1.7));
    let q1 = a.q.iter().position(|q| (q - 1.0).abs() < 1e-9).unwrap();
    println!(
        "K(1) {:.1e} / {:.1e}; alpha {} / {}; C1 {} / {}; {}",
        a.k[q1], b.k[q1], a.alpha, b.alpha, a.c1, b.c1, a.universal_fit
    );
    assert!(a.universal_fit.starts_with("gls"), "{}", a.universal_fit);
    assert!(a.k[q1].abs() < 1e-12 && b.k[q1].abs() < 1e-12);
    assert!(
        (a.alpha - b.alpha).abs() < 1e-8,
        "alpha {} / {}",
        a.alpha,
        b.alpha
    );
    assert!((a.c1 - b.c1).abs() < 1e-9, "C1 {} / {}", a.c1, b.c1);
    let e = |x: f64, y: f64| (x - y).abs() < 1e-8;
    assert!(e(a.alpha_stderr, b.alpha_stderr) && e(a.c1_stderr, b.c1_stderr));
}

/// Count box weights (the default) weigh every valid flux pixel the same at
/// every scale, so the moments of all scales average over one region and
/// the flux's mean is the same at every scale: `log2 <φ_λ>` is 0 at every
/// level to rounding on a plane (the last row and column have no forward
/// difference) with holes (a disc, a cut corner, scattered pixels) and on
/// 300 x 200 (four windows). Equal weights, which count the boxes along a
/// hole or border as whole ones, drift there; on a torus with no hole
/// every box is whole and the two rules agree exactly.
#[test]
fn count_weights_conserve_the_flux_over_holes_and_borders() {
    let p = FifParams {
        alpha: 1.8,
        c1: 0.12,
        hurst: 0.7,
    };
    let level_means = |cfg: &TraceMomentConfig, fields: &[Field]| -> Vec<f64> {
        let mut acc = TraceMomentAccumulator::new(cfg.clone()).unwrap();
        for f in fields {
            acc.add_field(f).unwrap();
        }
        let r = acc.finish(&TraceMomentFitConfig::default()).unwrap();
        let q1 = r.q.iter().position(|q| (q - 1.0).abs() < 1e-9).unwrap();
        r.log2_moments[q1].clone()
    };
    let equal = TraceMomentConfig {
        box_weights: BoxWeights::Equal,
        ..Default::default()
    };
    let count = TraceMomentConfig::default();
    assert_eq!(count.box_weights, BoxWeights::Count);
    for (ny, nx) in [(128, 128), (300, 200)] {
        let fields: Vec<Field> = (0..2)
            .map(|i| {
                let f = fif(&p, ny.max(nx), ny.max(nx), 31, i).unwrap();
                let f = f.slice(ndarray::s![..ny, ..nx]).to_owned();
                let mask = Array2::from_shape_fn((ny, nx), |(y, x)| {
                    let (dy, dx) = (y as f64 - 0.4 * ny as f64, x as f64 - 0.6 * nx as f64);
                    dy * dy + dx * dx < (0.15 * nx as f64).powi(2)
                        || y + x < ny / 5
                        || (y * 131 + x * 71 + i as usize * 7).is_multiple_of(97)
                });
                Field::with_mask(f, mask).unwrap()
            })
            .collect();
        let c = level_means(&count, &fields);
        let e = level_means(&equal, &fields);
        let worst = |v: &[f64]| v.iter().fold(0.0f64, |m, x| m.max(x.abs()));
        println!("{ny}x{nx}: log2 <phi_lambda> count {c:?}, equal {e:?}");
        assert!(worst(&c) < 1e-12, "count {c:?}");
        assert!(worst(&e) > 1e-4, "equal {e:?}");
    }
    // a torus: both rules keep and weigh the same whole boxes
    let torus = |w: BoxWeights| {
        let cfg = TraceMomentConfig {
            periodic: true,
            box_weights: w,
            ..Default::default()
        };
        let mut acc = TraceMomentAccumulator::new(cfg).unwrap();
        for i in 0..2 {
            acc.add_field(&Field::new(fif(&p, 128, 128, 31, i).unwrap()))
                .unwrap();
        }
        acc.finish(&TraceMomentFitConfig::default()).unwrap()
    };
    let (a, b) = (torus(BoxWeights::Count), torus(BoxWeights::Equal));
    assert_eq!(a.log2_moments, b.log2_moments);
    assert_eq!(a.dtm_alpha.to_bits(), b.dtm_alpha.to_bits());
    // the two rules never merge, and the refusal names what differs
    let mut e = TraceMomentAccumulator::new(equal.clone()).unwrap();
    let c = TraceMomentAccumulator::new(count).unwrap();
    let msg = e.merge(&c).unwrap_err().to_string();
    assert!(msg.contains("box_weights: equal vs count"), "{msg}");
    assert_eq!(equal.differences(&equal), Vec::<String>::new());
}

/// A hole mask of `kind` for image `index` of an `n x n` ensemble: `rect`
/// (one rectangle, ~10 % of the area), `discs` (30 discs of radius
/// `n/128 .. 6n/128` px, ~10 %), `coast` (an fBm of H 0.8 below its 25th
/// percentile: 25 %, irregular, touching the borders, like sea on a DEM),
/// `dropout` (5 % isolated pixels).
fn hole_mask(kind: &str, n: usize, seed: u64, index: u64) -> Array2<bool> {
    use rand::RngExt;
    let mut rng = rng_for(seed ^ 0x401e, index);
    let mut mask = Array2::from_elem((n, n), false);
    let mut uni = |lo: f64, hi: f64| lo + (hi - lo) * rng.random::<f64>();
    match kind {
        "rect" => {
            let aspect = uni(0.5, 2.0);
            let h = ((0.1 * aspect).sqrt() * n as f64) as usize;
            let w = ((0.1 / aspect).sqrt() * n as f64) as usize;
            let (y0, x0) = (
                uni(0.0, (n - h) as f64) as usize,
                uni(0.0, (n - w) as f64) as usize,
            );
            mask.slice_mut(ndarray::s![y0..y0 + h, x0..x0 + w])
                .fill(true);
        }
        "discs" => {
            for _ in 0..30 {
                let (cy, cx) = (uni(0.0, n as f64), uni(0.0, n as f64));
                let r = n as f64 / 128.0 * (1.0 + 5.0 * uni(0.0, 1.0).sqrt());
                mask.indexed_iter_mut().for_each(|((y, x), m)| {
                    let (dy, dx) = (y as f64 - cy, x as f64 - cx);
                    *m |= dy * dy + dx * dx < r * r;
                });
            }
        }
        "coast" => {
            let g = wtmm::synth::fbm::fbm(
                wtmm::synth::fbm::FbmParams { hurst: 0.8 },
                n,
                n,
                seed ^ 0xc0a5,
                index,
            )
            .unwrap();
            let mut v: Vec<f64> = g.iter().copied().collect();
            v.sort_by(f64::total_cmp);
            let cut = v[v.len() / 4];
            mask.zip_mut_with(&g, |m, &x| *m = x < cut);
        }
        "dropout" => mask.iter_mut().for_each(|m| *m = uni(0.0, 1.0) < 0.05),
        _ => panic!("unknown mask {kind}"),
    }
    mask
}

/// How holes move the estimates, by box weighting: `R` ensembles (seeds
/// SEED..) of `N` topo-fif planes of `SIZE`² (default 8, 8, 256, 700),
/// each analysed whole and with the four masks of `hole_mask` (a new mask
/// per image), with count and with equal box weights; printed: the shift
/// holed - whole of alpha, C1 and DTM alpha, mean and sd over the
/// ensembles, and the mean jackknife error of the whole runs. Run with
/// `cargo test --release --test tracemoments experiment_hole_bias --
/// --ignored --nocapture`.
#[test]
#[ignore = "experiment: minutes"]
fn experiment_hole_bias() {
    use rayon::prelude::*;
    let env = |k: &str, d: u64| std::env::var(k).map_or(d, |s| s.parse().unwrap());
    let (r, n_img, size, seed0) = (
        env("R", 8),
        env("N", 8),
        env("SIZE", 256) as usize,
        env("SEED", 700),
    );
    let fc = TraceMomentFitConfig::default();
    let kinds = ["none", "rect", "discs", "coast", "dropout"];
    let rules = [BoxWeights::Count, BoxWeights::Equal];
    // [ensemble][rule][kind] -> (alpha, C1, DTM alpha, alpha error)
    let res: Vec<Vec<Vec<[f64; 4]>>> = (0..r)
        .into_par_iter()
        .map(|e| {
            let seed = seed0 + e;
            let raw: Vec<Array2<f64>> = (0..n_img)
                .map(|i| fif(&FifParams::TOPO, size, size, seed, i).unwrap())
                .collect();
            rules
                .iter()
                .map(|&w| {
                    let cfg = TraceMomentConfig {
                        box_weights: w,
                        ..Default::default()
                    };
                    kinds
                        .iter()
                        .map(|&kind| {
                            let parts: Vec<_> = raw
                                .iter()
                                .enumerate()
                                .map(|(i, f)| {
                                    let field = if kind == "none" {
                                        Field::new(f.clone())
                                    } else {
                                        let m = hole_mask(kind, size, seed, i as u64);
                                        Field::with_mask(f.clone(), m).unwrap()
                                    };
                                    let mut a = TraceMomentAccumulator::new(cfg.clone()).unwrap();
                                    a.add_field(&field).unwrap();
                                    a
                                })
                                .collect();
                            let (_, t) = finish_ensemble(&parts, &fc).unwrap();
                            [t.alpha, t.c1, t.dtm_alpha, t.alpha_stderr]
                        })
                        .collect()
                })
                .collect()
        })
        .collect();
    println!(
        "{r} ensembles of {n_img} topo-fif planes of {size}^2, seeds {seed0}..; holed - whole"
    );
    for (iw, w) in rules.iter().enumerate() {
        let whole: Vec<[f64; 4]> = res.iter().map(|e| e[iw][0]).collect();
        let (ea, _) = mean_std(&whole.iter().map(|v| v[3]).collect::<Vec<_>>());
        println!("{}: whole-run alpha jackknife error {ea:.4}", w.name());
        for (ik, kind) in kinds.iter().enumerate().skip(1) {
            let line: Vec<String> = ["alpha", "C1", "DTM alpha"]
                .iter()
                .enumerate()
                .map(|(j, name)| {
                    let d: Vec<f64> = res.iter().map(|e| e[iw][ik][j] - e[iw][0][j]).collect();
                    let (m, s) = mean_std(&d);
                    format!("{name} {m:+.4} sd {s:.4}")
                })
                .collect();
            println!("  {kind:8} {}", line.join("   "));
        }
    }
}

/// Holes move the estimates of an ensemble by no more than the scatter of
/// that shift between ensembles: 8 topo-fif planes of 256² (seed 800), each
/// mask of `hole_mask` against the whole fields, with count box weights
/// (the default). The shift's mean and sd for alpha, C1 and DTM alpha
/// come from `experiment_hole_bias` (R=16: 16 other ensembles, seeds
/// 700-715); the bound is |mean| + 4 sd (12 checks). Equal weights
/// scattered 2-3 times more there (alpha sd 0.037-0.049, DTM alpha up to
/// 0.18 with the coast), count weights 0.010-0.027 and 0.005-0.015.
#[test]
fn holes_move_the_estimates_within_their_scatter() {
    let (n_img, size, seed) = (8u64, 256, 800);
    // (mask, [(mean, sd) of alpha, C1, DTM alpha]), experiment_hole_bias
    let expected: [(&str, [(f64, f64); 3]); 4] = [
        (
            "rect",
            [(-0.0002, 0.0140), (-0.0011, 0.0020), (0.0031, 0.0139)],
        ),
        (
            "discs",
            [(0.0095, 0.0213), (0.0004, 0.0014), (0.0050, 0.0153)],
        ),
        (
            "coast",
            [(-0.0106, 0.0265), (-0.0023, 0.0039), (-0.0015, 0.0113)],
        ),
        (
            "dropout",
            [(0.0001, 0.0101), (0.0017, 0.0009), (0.0005, 0.0048)],
        ),
    ];
    let raw: Vec<Array2<f64>> = (0..n_img)
        .map(|i| fif(&FifParams::TOPO, size, size, seed, i).unwrap())
        .collect();
    let fit = |kind: Option<&str>| {
        let parts: Vec<_> = raw
            .iter()
            .enumerate()
            .map(|(i, f)| {
                let field = match kind {
                    None => Field::new(f.clone()),
                    Some(k) => {
                        Field::with_mask(f.clone(), hole_mask(k, size, seed, i as u64)).unwrap()
                    }
                };
                let mut a = TraceMomentAccumulator::new(TraceMomentConfig::default()).unwrap();
                a.add_field(&field).unwrap();
                a
            })
            .collect();
        let (_, r) = finish_ensemble(&parts, &TraceMomentFitConfig::default()).unwrap();
        [r.alpha, r.c1, r.dtm_alpha]
    };
    let whole = fit(None);
    for (kind, stats) in expected {
        let holed = fit(Some(kind));
        for (j, name) in ["alpha", "C1", "DTM alpha"].iter().enumerate() {
            let (m, sd) = stats[j];
            let d = holed[j] - whole[j];
            println!(
                "{kind}: {name} {:.4} -> {:.4} ({d:+.4}; bound {:.4})",
                whole[j],
                holed[j],
                m.abs() + 4.0 * sd
            );
            assert!(
                d.abs() <= m.abs() + 4.0 * sd,
                "{kind}: {name} moved by {d:+.4} ({:.4} whole), beyond |{m}| + 4 x {sd}",
                whole[j]
            );
        }
    }
}

/// How holes move the spectral beta (and so H = (beta - 1 + K(2))/2) by
/// the fill the spectrum sees (not a check; `cargo test --release --test
/// tracemoments experiment_spectrum_holes -- --ignored --nocapture`, env
/// R fields of SIZE² (default 16 of 256), SEED (900)): per mask of
/// `hole_mask`, beta of the holed field filled with the image mean and
/// harmonically, minus beta of the whole field, mean and sd over fields
/// (Hann window and plane removed, tm's settings for a plane; default k
/// range).
#[test]
#[ignore = "experiment"]
fn experiment_spectrum_holes() {
    use rayon::prelude::*;
    use wtmm::stats::powspec::{PowerSpectrumConfig, default_k_range, power_spectrum};
    let env = |k: &str, d: u64| std::env::var(k).map_or(d, |s| s.parse().unwrap());
    let (r, size, seed) = (env("R", 16), env("SIZE", 256) as usize, env("SEED", 900));
    let cfg = PowerSpectrumConfig::default();
    let (klo, khi) = default_k_range(size);
    let beta = |a: &Array2<f64>| {
        power_spectrum(a.view(), &cfg)
            .unwrap()
            .fit(klo, khi)
            .unwrap()
            .beta
    };
    let kinds = ["rect", "discs", "coast", "dropout"];
    // [field][kind] -> (mean fill - whole, harmonic fill - whole)
    let d: Vec<Vec<(f64, f64)>> = (0..r)
        .into_par_iter()
        .map(|i| {
            let f = fif(&FifParams::TOPO, size, size, seed, i).unwrap();
            let b0 = beta(&f);
            kinds
                .iter()
                .map(|&k| {
                    let field = Field::with_mask(f.clone(), hole_mask(k, size, seed, i)).unwrap();
                    let bm = beta(&field.filled().unwrap());
                    let bh = beta(&field.filled_harmonic().unwrap());
                    (bm - b0, bh - b0)
                })
                .collect()
        })
        .collect();
    println!("{r} topo-fif planes of {size}^2, seed {seed}: beta holed - whole");
    for (j, k) in kinds.iter().enumerate() {
        let (m, h): (Vec<f64>, Vec<f64>) = d.iter().map(|v| v[j]).unzip();
        let (mm, ms) = mean_std(&m);
        let (hm, hs) = mean_std(&h);
        println!("  {k:8} mean fill {mm:+.4} sd {ms:.4}   harmonic {hm:+.4} sd {hs:.4}");
    }
}

/// The spectrum fills holes harmonically by default: 5 % isolated pixels
/// missing leave beta within |mean| + 4 sd of its shift measured by
/// `experiment_spectrum_holes` (`R=64`: 64 other planes of 256², seed
/// 900: +0.0070 sd 0.0050) on 4 topo-fif planes of 256² (seed 901); the
/// mean fill, whose spikes add white power, moved it by -0.31 sd 0.21
/// there, and must move it by more than the bound here too. A field without holes has one
/// spectrum whatever the fill.
#[test]
fn spectrum_fills_holes_without_edges() {
    use wtmm::stats::powspec::{
        HoleFill, PowerSpectrumConfig, default_k_range, field_power_spectrum,
    };
    let (size, seed) = (256, 901);
    let (klo, khi) = default_k_range(size);
    let harmonic = PowerSpectrumConfig::default();
    assert_eq!(harmonic.fill, HoleFill::Harmonic);
    let mean = PowerSpectrumConfig {
        fill: HoleFill::Mean,
        ..harmonic
    };
    let beta = |f: &Field, c: &PowerSpectrumConfig| {
        field_power_spectrum(f, c)
            .unwrap()
            .fit(klo, khi)
            .unwrap()
            .beta
    };
    let bound = 0.0070 + 4.0 * 0.0050;
    for i in 0..4 {
        let raw = fif(&FifParams::TOPO, size, size, seed, i).unwrap();
        let whole = Field::new(raw.clone());
        let b0 = beta(&whole, &harmonic);
        assert_eq!(b0, beta(&whole, &mean));
        let holed = Field::with_mask(raw, hole_mask("dropout", size, seed, i)).unwrap();
        let (bh, bm) = (beta(&holed, &harmonic), beta(&holed, &mean));
        println!("field {i}: beta {b0:.4} whole, {bh:.4} harmonic, {bm:.4} mean fill");
        assert!((bh - b0).abs() <= bound, "harmonic: {bh} vs {b0}");
        assert!((bm - b0).abs() > bound, "mean fill: {bm} vs {b0}");
    }
}
