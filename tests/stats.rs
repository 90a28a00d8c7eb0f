//! WTMMM statistics: pdfs, the self-similarity kernel and the space-scale
//! correlations (SPEC §5-§6; II §3-§5) against known answers.

use std::f64::consts::{LN_2, PI};

use ndarray::Array2;
use rand::RngExt;
use rand_distr::{Distribution, Normal, Poisson, StandardNormal as StdNormalF};
use wtmm::Field;
use wtmm::cwt::{CwtPlan, Wavelet, modulus};
use wtmm::skeleton::{AnalysisConfig, Parallelism};
use wtmm::stats::correlation::{
    CorrelationConfig, CorrelationPlan, CorrelationSums, Magnitude, correlation_estimates,
    cwt_correlation, cwt_correlation_tiled, field_correlation, wtmmm_correlation,
    wtmmm_correlation_tiled,
};
use wtmm::stats::kernel::{
    KernelConfig, KernelOptions, KernelSums, ensemble_kernel_sums, kernel_estimates, reconstruct,
};
use wtmm::stats::pdf::{
    PdfConfig, PdfOptions, Point, WtmmmHistograms, WtmmmSet, image_wtmmm, wtmmm_pdfs,
};
use wtmm::synth::rng_for;
use wtmm::theory::Model;

// ---------------------------------------------------------------- kernel

/// Scales `a_j = 2^(j/2)`, j = 0..10 (5 octaves, 2 voices).
/// A result reads back from its JSON (NaN entries, null there, as NaN) and
/// writes the same JSON again.
fn json_round_trip<T: serde::Serialize + serde::de::DeserializeOwned>(x: &T) {
    let text = serde_json::to_string(x).unwrap();
    let back: T = serde_json::from_str(&text).unwrap();
    assert_eq!(serde_json::to_string(&back).unwrap(), text);
}

fn half_octave_scales() -> Vec<f64> {
    (0..11).map(|j| 2f64.powf(j as f64 / 2.0)).collect()
}

/// Synthetic WTMMM moduli with exactly known kernel cumulants: at scale a,
/// `ln M = noise + (cascade over t = log2(L/a) steps)` where the noise is a
/// scale-independent N(0.3, 0.2²) (it cancels in every C_n) and the cascade
/// is infinitely divisible so that t may be fractional: log-normal
/// `N(m t, σ² t)`, or log-Poisson `γ t + Y ln β`, `Y ~ Poisson(λ t)`.
/// Then `κ_n(a) - κ_n(a') = κ_n(ln W) log2(a'/a)`: `c_n = κ_n(ln W) / ln 2`.
fn synthetic_sums(law: &str, images: usize, per_scale: usize) -> KernelSums {
    let scales = half_octave_scales();
    let mut acc: Option<KernelSums> = None;
    for (i, vals) in synthetic_ln_m(law, images, per_scale)
        .into_iter()
        .enumerate()
    {
        let s = KernelSums::from_ln_m(
            &scales,
            KernelConfig::default(),
            WtmmmSet::All,
            &vals,
            format!("synthetic {i}"),
        )
        .unwrap();
        match &mut acc {
            None => acc = Some(s),
            Some(a) => a.merge(&s).unwrap(),
        }
    }
    acc.unwrap()
}

/// The values behind [`synthetic_sums`]: `[image][scale][point]`.
fn synthetic_ln_m(law: &str, images: usize, per_scale: usize) -> Vec<Vec<Vec<f64>>> {
    let scales = half_octave_scales();
    let l = 2f64.powi(8);
    let mut out = Vec::with_capacity(images);
    for i in 0..images {
        let mut rng = rng_for(20240601, i as u64);
        let noise = Normal::new(0.3, 0.2).unwrap();
        let vals: Vec<Vec<f64>> = scales
            .iter()
            .map(|&a| {
                let t = (l / a).log2();
                (0..per_scale)
                    .map(|_| {
                        let c = match law {
                            "lognormal" => {
                                let (m, s2) = (-0.38 * LN_2, 0.03 * LN_2);
                                Normal::new(m * t, (s2 * t).sqrt())
                                    .unwrap()
                                    .sample(&mut rng)
                            }
                            _ => {
                                let (g, b, lam) = (-LN_2 / 9.0, (2.0f64 / 3.0).cbrt(), 2.0 * LN_2);
                                let y: f64 = Poisson::new(lam * t).unwrap().sample(&mut rng);
                                g * t + y * b.ln()
                            }
                        };
                        c + noise.sample(&mut rng)
                    })
                    .collect()
            })
            .collect();
        out.push(vals);
    }
    out
}

fn opts_all_scales() -> KernelOptions {
    KernelOptions {
        fit: (0.0, 5.0),
        refs: vec![2.0, 3.0, 4.0, 5.0],
        pairs: vec![(1.0, 4.0), (0.5, 3.5)],
    }
}

/// The kernel on synthetic moduli with exactly known cumulants
/// ([`synthetic_sums`], 8 images of 20 000 points per scale): the fitted
/// c_n, the pooled c_n, the slope of every C_n(a, a') table (n = 1..3), and
/// the collapsed kernel `ln Ĝ(p) / ln(a'/a)` for p in (0, 2] against the
/// exact log characteristic function of one cascade step per ln 2
/// (log-normal `(i m p - σ² p²/2)/ln 2`; log-Poisson `(i γ p + λ (e^(i p
/// ln β) - 1))/ln 2`), all within 4 jackknife standard errors over the 8
/// images, nothing else: the tables' slopes and the kernel's values get
/// their own jackknife here (the library reports errors for the fitted
/// cumulants only). Before, the tables allowed 10 % of c_n + 5 errors of
/// the fitted c_n, and the kernel 2e-3 / 5e-3 around a series truncated
/// after c3.
#[test]
fn kernel_recovers_known_cumulants_lognormal_and_logpoisson() {
    let (lb, lam, gamma) = ((2.0f64 / 3.0).cbrt().ln(), 2.0 * LN_2, -LN_2 / 9.0);
    let (m, s2) = (-0.38 * LN_2, 0.03 * LN_2);
    for (law, th) in [
        ("lognormal", [-0.38, 0.03, 0.0]),
        (
            "logpoisson",
            [
                (gamma + lam * lb) / LN_2,
                lam * lb * lb / LN_2,
                lam * lb.powi(3) / LN_2,
            ],
        ),
    ] {
        // ln Ĝ(p) / ln(a'/a): (real, imaginary)
        let log_cf = |p: f64| -> (f64, f64) {
            if law == "lognormal" {
                (-s2 * p * p / 2.0 / LN_2, m * p / LN_2)
            } else {
                (
                    lam * ((p * lb).cos() - 1.0) / LN_2,
                    (gamma * p + lam * (p * lb).sin()) / LN_2,
                )
            }
        };
        let s = synthetic_sums(law, 8, 20_000);
        let opts = opts_all_scales();
        let k = kernel_estimates(&s, &opts).unwrap();
        assert_eq!(k.stderr_method, "jackknife over images");
        json_round_trip(&k);
        // two images, no tiles: no jackknife, NaN errors (null in JSON)
        let two = KernelSums {
            images: s.images[..2].to_vec(),
            ..s.clone()
        };
        let k2 = kernel_estimates(&two, &opts).unwrap();
        assert!(k2.tables[0].rows[0].c_stderr[0].is_nan());
        json_round_trip(&k2);
        let loo: Vec<_> = (0..s.images.len())
            .map(|i| {
                let mut images = s.images.clone();
                images.remove(i);
                kernel_estimates(
                    &KernelSums {
                        images,
                        ..s.clone()
                    },
                    &opts,
                )
                .unwrap()
            })
            .collect();
        let jk = |f: &dyn Fn(&wtmm::stats::kernel::KernelResult) -> f64| {
            wtmm::stats::jackknife_se(&loo.iter().map(f).collect::<Vec<_>>())
        };
        let got = k.cumulants.values();
        let se = [
            k.cumulants.c1.stderr,
            k.cumulants.c2.stderr,
            k.cumulants.c3.stderr,
        ];
        for n in 0..3 {
            // 4 standard errors from the ensemble's own scatter; the errors
            // themselves must be small enough for the test to mean something
            assert!(
                (got[n] - th[n]).abs() < 4.0 * se[n],
                "{law}: c{} = {} +- {} vs {}",
                n + 1,
                got[n],
                se[n],
                th[n]
            );
        }
        assert!(
            se[0] < 2e-3 && se[1] < 1e-3 && se[2] < 1e-3,
            "{law}: {se:?}"
        );
        // the pooled slope of the tables (II Figs 26, 28 as drawn), with its
        // own jackknife errors
        let pooled = [k.pooled.c1, k.pooled.c2, k.pooled.c3];
        for n in 0..3 {
            assert!(
                (pooled[n].value - th[n]).abs() < 4.0 * pooled[n].stderr,
                "{law}: pooled c{} = {:?} vs {}",
                n + 1,
                pooled[n],
                th[n]
            );
        }
        // every C_n(a, a') table lies on c_n ln(a'/a)
        for (it, t) in k.tables.iter().enumerate() {
            for (n, (&slope, &want)) in t.slope.iter().zip(&th).enumerate() {
                let se_t = jk(&|r| r.tables[it].slope[n]);
                assert!(
                    (slope - want).abs() < 4.0 * se_t,
                    "{law}: ref {} slope C{} = {slope} +- {se_t}, theory {want}",
                    t.octave_ref,
                    n + 1,
                );
            }
        }
        // the collapse ln Ĝ / ln(a'/a) for 0 < p <= 2
        let mut worst: f64 = 0.0;
        for (ic, kc) in k.kernels.iter().enumerate() {
            for (i, &p) in kc.p.iter().enumerate() {
                if p <= 0.0 || p > 2.0 + 1e-9 {
                    continue;
                }
                let (re, im) = log_cf(p);
                let se_re = jk(&|r| r.kernels[ic].ln_abs_g_norm[i]);
                let se_im = jk(&|r| r.kernels[ic].phase_norm[i]);
                let (z_re, z_im) = (
                    (kc.ln_abs_g_norm[i] - re) / se_re,
                    (kc.phase_norm[i] - im) / se_im,
                );
                worst = worst.max(z_re.abs()).max(z_im.abs());
                assert!(
                    z_re.abs() < 4.0 && z_im.abs() < 4.0,
                    "{law}: kernel {ic} at p = {p}: ln|G| {} (theory {re}, se {se_re}), phase {} (theory {im}, se {se_im})",
                    kc.ln_abs_g_norm[i],
                    kc.phase_norm[i]
                );
            }
        }
        println!("{law}: largest |z| of the collapsed kernel over 0 < p <= 2: {worst:.2}");
    }
}

/// The kernel's phase is unwrapped: with `ln M = m log2(L/a) ± δ` (two
/// points per scale, so `C_a(p) = e^(i p m t) cos(p δ)` and `Ĝ(p) =
/// e^(i p m Δt)` exactly) the phase of `Ĝ` over `|p| <= 8` is the straight
/// line `m p Δt`, here up to 3.4π for the 5-octave pair, not folded into
/// (-π, π]. Rounding only: 1e-9.
#[test]
fn kernel_phase_is_unwrapped() {
    let scales = half_octave_scales();
    let (m, delta, l) = (-0.38 * LN_2, 0.01, 2f64.powi(8));
    let vals: Vec<Vec<f64>> = scales
        .iter()
        .map(|&a| {
            let u = m * (l / a).log2();
            vec![u - delta, u + delta]
        })
        .collect();
    let one = |i: usize| {
        KernelSums::from_ln_m(
            &scales,
            KernelConfig::default(),
            WtmmmSet::All,
            &vals,
            format!("line {i}"),
        )
        .unwrap()
    };
    let mut s = one(0);
    s.merge(&one(1)).unwrap();
    let opts = KernelOptions {
        pairs: vec![(0.0, 5.0), (1.0, 4.0)],
        ..opts_all_scales()
    };
    let k = kernel_estimates(&s, &opts).unwrap();
    let mut widest: f64 = 0.0;
    for kc in &k.kernels {
        for (i, &p) in kc.p.iter().enumerate() {
            let want = m * p / LN_2;
            assert!(
                (kc.phase_norm[i] - want).abs() < 1e-9,
                "pair {}-{} at p = {p}: phase/ln(a'/a) {} vs {want}",
                kc.octave,
                kc.octave_ref,
                kc.phase_norm[i]
            );
            widest = widest.max(kc.phase[i].abs());
        }
    }
    assert!(
        widest > 3.0 * PI,
        "largest |phase| {widest}: no wrap tested"
    );
}

/// Plug-in (empirical-distribution) cumulants `κ_1..κ_kmax` of `u`
/// (index n holds κ_n; κ_0 = 0), from the central moments by the recursion
/// `κ_n = μ_n - Σ_{m=2}^{n-1} C(n-1, m-1) κ_m μ_{n-m}` (κ_1 of the centred
/// sample is 0), and the centred sample.
fn plug_in_cumulants(u: &[f64], kmax: usize) -> (Vec<f64>, Vec<f64>) {
    let n = u.len() as f64;
    let mean = u.iter().sum::<f64>() / n;
    let x: Vec<f64> = u.iter().map(|v| v - mean).collect();
    let mu: Vec<f64> = (0..=kmax)
        .map(|j| x.iter().map(|v| v.powi(j as i32)).sum::<f64>() / n)
        .collect();
    let binom =
        |n: usize, k: usize| -> f64 { (0..k).map(|i| (n - i) as f64 / (i + 1) as f64).product() };
    let mut kap = vec![0.0; kmax + 1];
    kap[1] = mean;
    for j in 2..=kmax {
        kap[j] = mu[j]
            - (2..j)
                .map(|m| binom(j - 1, m - 1) * kap[m] * mu[j - m])
                .sum::<f64>();
    }
    (kap, x)
}

/// Cauchy's bound on the log characteristic function `ln φ(p) = Σ_{n>=2}
/// κ_n (ip)^n/n!` of a centred empirical distribution `x`: for complex p,
/// `|p| <= r`, `|φ(p) - 1| = |mean(e^(ipx) - 1 - ipx)|` is at most
/// `mean(e^(r|x|) - 1 - r|x|) = δ(r)`, so if δ < 1, `ln φ` is analytic on
/// the disc with `|ln φ| <= -ln(1 - δ) = M(r)` and `|κ_n|/n! <= M(r)/r^n`
/// for every n. Returns `(δ(r), M(r))` (M infinite when δ >= 1).
fn cauchy_bound(x: &[f64], r: f64) -> (f64, f64) {
    let d = x
        .iter()
        .map(|v| (r * v.abs()).exp_m1() - r * v.abs())
        .sum::<f64>()
        / x.len() as f64;
    let m = if d < 1.0 {
        -(-d).ln_1p()
    } else {
        f64::INFINITY
    };
    (d, m)
}

/// II eqs 57-58: the derivatives at p = 0 of the phase and of ln|Ĝ| are
/// the cumulant differences (up to the sign of eq 58, see the module doc),
/// checked on the centred differences of the kernel curve at the grid step
/// h = dp. `ln Ĝ` is the difference of the logarithms of two *empirical*
/// characteristic functions, so it is exactly `Σ_n C_n (ip)^n/n!` with
/// `C_n` the differences of the plug-in cumulants of the same samples
/// (regenerated here from the seeds and computed by the test to order
/// K = 9). Then, from Φ odd and ln|Ĝ| even,
///
/// * `d1 = Φ(h)/h`:  `d1 - C1 = -C3 h²/6 + C5 h⁴/120 - C7 h⁶/5040 + ...`
/// * `d2 = 2 ln|Ĝ(h)|/h²`:  `-d2 - C2 = -C4 h²/12 + C6 h⁴/360 - ...`
/// * `d3 = (Φ(2h) - 2Φ(h))/h³`:  `-d3 - C3 = -C5 h²/4 + C7 h⁴/40 - ...`
///
/// (the general term of `-d3 - C3` is `-(-1)^((n-1)/2) C_n ((2h)^n -
/// 2h^n)/(n! h³)`). Each difference must equal its series through n = 9
/// within
/// * the remainder n >= 10, bounded rigorously by Cauchy's estimate
///   `|κ_n|/n! <= M(r)/r^n` per scale ([`cauchy_bound`], r chosen on a grid
///   to make the bound smallest): e.g. `|R1| <= Σ_s M_s (h/r_s)^10 / (h (1 -
///   h/r_s))`, with `2h/r` in place of `h/r` for the `Φ(2h)` part of d3;
/// * rounding: each characteristic function is a sum of N unit-modulus
///   terms (cos/sin within an ulp, at most 2 recurrence products), so its
///   real and imaginary parts are within `(N + 16) u` (the bound `(N - 1) u
///   Σ|x_i|` holds for every summation order), `|ΔC| <= √2 (N + 16) u`, and
///   a value of ln|Ĝ| or Φ is within `ε_v = Σ_s √2 (N_s + 16) u / |C_s| +
///   8u` with `|C_s| >= 1 - δ_s(2h)`; d1, d2, d3 combine 2, 4, 6 such
///   values over `2h`, `h²`, `2h³`; the cumulants from the central sums
///   are within `(N + 8) u E|x|^n` (n = 1: `E|u|`).
///
/// The leading terms (`C3 h²/6` etc.) must exceed these bounds, so the
/// check resolves the truncation error rather than hiding it. (Before: bare
/// relative allowances 1e-4, 2e-3 and 0.05.)
#[test]
fn characteristic_function_derivatives_are_the_cumulants() {
    const K: usize = 9;
    let (images, per_scale) = (2, 5_000);
    let s = synthetic_sums("logpoisson", images, per_scale);
    let raw = synthetic_ln_m("logpoisson", images, per_scale);
    let cfg = KernelOptions {
        fit: (0.0, 5.0),
        refs: vec![4.0],
        pairs: vec![(1.0, 4.0)],
    };
    let k = kernel_estimates(&s, &cfg).unwrap();
    let kc = &k.kernels[0];
    let i0 = kc.p.iter().position(|&p| p == 0.0).unwrap();
    let h = kc.p[i0 + 1];
    let row = k.tables[0]
        .rows
        .iter()
        .find(|r| (r.a - kc.a).abs() < 1e-9)
        .unwrap();
    // Φ'(0) = C1, -(ln|Ĝ|)''(0) = C2, -Φ'''(0) = C3 by centred differences
    let phi = |j: isize| kc.phase[(i0 as isize + j) as usize];
    let lg = |j: isize| kc.ln_abs_g[(i0 as isize + j) as usize];
    let d1 = (phi(1) - phi(-1)) / (2.0 * h);
    let d2 = (lg(1) - 2.0 * lg(0) + lg(-1)) / (h * h);
    let d3 = (phi(2) - 2.0 * phi(1) + 2.0 * phi(-1) - phi(-2)) / (2.0 * h.powi(3));

    // the pooled samples at a and a': plug-in cumulants and bounds
    let u = f64::EPSILON / 2.0;
    let scales = half_octave_scales();
    let fact = |n: usize| -> f64 { (1..=n).map(|i| i as f64).product() };
    let sgn = |m: usize| if m.is_multiple_of(2) { 1.0 } else { -1.0 };
    let (mut c, mut eps_v, mut eps_c) = (vec![0.0; K + 1], 8.0 * u, [0.0; 3]);
    // remainder bounds (n > K) of d1, d2, d3
    let mut rem = [0.0; 3];
    for (a, sign) in [(kc.a, 1.0), (kc.a_ref, -1.0)] {
        let j = scales.iter().position(|&b| (b - a).abs() < 1e-9).unwrap();
        let pooled: Vec<f64> = raw.iter().flat_map(|img| img[j].iter().copied()).collect();
        let nf = pooled.len() as f64;
        let (kap, x) = plug_in_cumulants(&pooled, K);
        for n in 1..=K {
            c[n] += sign * kap[n];
        }
        let c_min = 1.0 - cauchy_bound(&x, 2.0 * h).0;
        eps_v += 2f64.sqrt() * (nf + 16.0) * u / c_min;
        let abs_mom = |m: i32| x.iter().map(|v| v.abs().powi(m)).sum::<f64>() / nf;
        eps_c[0] += (nf + 8.0) * u * pooled.iter().map(|v| v.abs()).sum::<f64>() / nf;
        eps_c[1] += (nf + 8.0) * u * abs_mom(2);
        eps_c[2] += (nf + 8.0) * u * abs_mom(3);
        let tail = |q: f64| q.powi(K as i32 + 1) / (1.0 - q);
        let mut best = [f64::INFINITY; 3];
        for ir in 1..=400 {
            let r = ir as f64 * 0.01;
            if 2.0 * h >= r {
                continue;
            }
            let m = cauchy_bound(&x, r).1;
            best[0] = best[0].min(m * tail(h / r) / h);
            best[1] = best[1].min(2.0 * m * tail(h / r) / (h * h));
            best[2] = best[2].min(m * (tail(2.0 * h / r) + 2.0 * tail(h / r)) / h.powi(3));
        }
        for (rm, b) in rem.iter_mut().zip(best) {
            *rm += b;
        }
    }
    // the series of the three differences through n = K
    let t1: Vec<f64> = (3..=K)
        .step_by(2)
        .map(|n| sgn((n - 1) / 2) * c[n] * h.powi(n as i32 - 1) / fact(n))
        .collect();
    let t2: Vec<f64> = (4..=K)
        .step_by(2)
        .map(|n| -2.0 * sgn(n / 2) * c[n] * h.powi(n as i32 - 2) / fact(n))
        .collect();
    let t3: Vec<f64> = (5..=K)
        .step_by(2)
        .map(|n| {
            -sgn((n - 1) / 2) * c[n] * ((2.0 * h).powi(n as i32) - 2.0 * h.powi(n as i32))
                / (fact(n) * h.powi(3))
        })
        .collect();
    let checks = [
        ("d1 - C1", d1 - row.c[0], &t1, d1, 2.0 * eps_v / (2.0 * h)),
        ("-d2 - C2", -d2 - row.c[1], &t2, d2, 4.0 * eps_v / (h * h)),
        (
            "-d3 - C3",
            -d3 - row.c[2],
            &t3,
            d3,
            6.0 * eps_v / (2.0 * h.powi(3)),
        ),
    ];
    for (i, (what, got, t, dval, eps_d)) in checks.into_iter().enumerate() {
        let want: f64 = t.iter().sum();
        let bound = rem[i] + eps_d + eps_c[i] + 4.0 * u * dval.abs();
        println!(
            "{what} = {got:.6e}: series {want:.6e} (leading {:.3e}), |diff| {:.2e} <= {bound:.2e} (remainder {:.1e}, rounding {:.1e})",
            t[0],
            (got - want).abs(),
            rem[i],
            eps_d + eps_c[i]
        );
        // the leading truncation term is resolved
        assert!(
            t[0].abs() > bound,
            "{what}: leading term {} below the bound {bound}",
            t[0]
        );
        assert!(
            (got - want).abs() <= bound,
            "{what} = {got:e}, series {want:e} (terms {t:?}), bound {bound:e}"
        );
    }
    // and the test's own plug-in cumulants are the table's
    for n in 0..3 {
        assert!(
            (c[n + 1] - row.c[n]).abs() <= 2.0 * eps_c[n],
            "C{}: {} vs {}",
            n + 1,
            c[n + 1],
            row.c[n]
        );
    }
}

#[test]
fn kernel_sums_merge_in_any_order() {
    let s = synthetic_sums("lognormal", 4, 500);
    let parts: Vec<KernelSums> = (0..4)
        .map(|i| KernelSums {
            images: vec![s.images[i].clone()],
            ..s.clone()
        })
        .collect();
    let mut rev = parts[3].clone();
    for p in parts[..3].iter().rev() {
        rev.merge(p).unwrap();
    }
    let a = kernel_estimates(&s, &opts_all_scales()).unwrap();
    let b = kernel_estimates(&rev, &opts_all_scales()).unwrap();
    assert_eq!(a, b, "merge order changed the result");
    // merge_all: the parts in order, and nothing for no parts
    let all = KernelSums::merge_all(parts).unwrap().unwrap();
    assert_eq!(kernel_estimates(&all, &opts_all_scales()).unwrap(), a);
    assert!(KernelSums::merge_all(Vec::new()).unwrap().is_none());
}

/// II Fig 29: pushing P_a' through the exact Gaussian kernel reproduces
/// P_a, to the counting noise of the histograms. 400 000 points per scale;
/// the L1 distance `∫ |predicted - measured| d ln M` of a correct kernel is
/// then the mean absolute counting error summed over the bins: with `π_b`
/// the share of bin b (width d), the measured density has variance
/// `π_b (1 - π_b)/(N d²)` and the prediction, the source histogram
/// smoothed by a kernel of width `σ_k = sqrt(c2 ln 4)` = 4 bins, adds at
/// most `d/(2 √π σ_k)` = 7 % of that; so (normal approximation, bins
/// independent) `E L1 = Σ d sqrt(2 v_b/π)` and `sd L1 = sqrt(Σ d² v_b (1 -
/// 2/π))`. The binning itself adds nothing at order d² (the bin averages
/// of the source and of the target carry the same `d²/24` curvature
/// term). Checked: the true kernel's L1 lies within 4 sd of E L1 (0.0086
/// ± 0.0010, measured 0.0075; before: below a bare 0.03), and a kernel whose c1 is
/// off by 0.1 lies far above it (before: 4 times the good L1).
#[test]
fn reconstruction_with_the_true_kernel() {
    let scales = [1.0, 4.0];
    let (c1, c2) = (-0.38, 0.03);
    let s = (4.0f64).ln();
    let big_n = 400_000usize;
    let mut h = WtmmmHistograms::new(&scales, PdfConfig::default()).unwrap();
    let mut rng = rng_for(7, 0);
    let base = Normal::new(1.0, 0.4).unwrap();
    let step = Normal::new(c1 * s, (c2 * s).sqrt()).unwrap();
    for _ in 0..big_n {
        let u: f64 = base.sample(&mut rng);
        h.add(1, u.exp(), 0.0);
        let v = base.sample(&mut rng) + step.sample(&mut rng);
        h.add(0, v.exp(), 0.0);
    }
    let good = reconstruct(&h, 0, &[1], &[c1, c2]).unwrap();
    let bad = reconstruct(&h, 0, &[1], &[c1 + 0.1, c2]).unwrap();
    let d = h.config.dlnm;
    let nf = big_n as f64;
    let smooth = d / (2.0 * PI.sqrt() * (c2 * s).sqrt());
    let (mut mean, mut var) = (0.0, 0.0);
    for &p in &good[0].measured {
        let pi_b = p * d;
        let v = (1.0 + smooth) * pi_b * (1.0 - pi_b) / (nf * d * d);
        mean += d * (2.0 * v / PI).sqrt();
        var += d * d * v * (1.0 - 2.0 / PI);
    }
    let sd = var.sqrt();
    println!(
        "L1: true kernel {:.5}, c1 + 0.1 {:.5}; counting noise {mean:.5} +- {sd:.5}",
        good[0].l1, bad[0].l1
    );
    assert!(
        (good[0].l1 - mean).abs() < 4.0 * sd,
        "l1 = {} vs noise {mean} +- {sd}",
        good[0].l1
    );
    assert!(
        bad[0].l1 > mean + 4.0 * sd,
        "a wrong kernel: l1 = {} vs noise {mean} +- {sd}",
        bad[0].l1
    );
    // with a third cumulant of 0 the result is the same
    let three = reconstruct(&h, 0, &[1], &[c1, c2, 0.0]).unwrap();
    assert!((three[0].l1 - good[0].l1).abs() < 1e-9);
}

/// A monofractal's kernel is a pure shift by c1 (c2 = 0), and a measured c2
/// below 0 (noise, on such data) gives no density: `reconstruct` refuses
/// it (it used to amplify the histogram's noise by up to e^12, L1 ~ 1e5)
/// and the shift alone reproduces P_a to the counting noise. Without
/// smoothing the prediction is the source histogram moved by a non-integer
/// number of bins; a band-limited shift keeps white noise white at the
/// same variance, so the L1 is that of two independent histograms,
/// `v_b = 2 π_b (1 - π_b)/(N d²)` (4 sd as above, one-sided, since the
/// interpolation can only smooth).
#[test]
fn reconstruction_of_a_pure_shift() {
    let scales = [1.0, 4.0];
    let c1 = -0.38;
    let s = (4.0f64).ln();
    let big_n = 400_000usize;
    let mut h = WtmmmHistograms::new(&scales, PdfConfig::default()).unwrap();
    let mut rng = rng_for(8, 0);
    let base = Normal::new(1.0, 0.4).unwrap();
    for _ in 0..big_n {
        let u: f64 = base.sample(&mut rng);
        h.add(1, u.exp(), 0.0);
        let v = base.sample(&mut rng) + c1 * s;
        h.add(0, v.exp(), 0.0);
    }
    let err = reconstruct(&h, 0, &[1], &[c1, -0.004]).unwrap_err();
    assert!(err.to_string().contains("c2 = -0.004 < 0"), "{err}");
    assert!(reconstruct(&h, 0, &[1], &[c1, -0.004, 0.001]).is_err());
    // a kernel moving ln M by e^100 and more is refused, not an FFT grid of
    // 137 GB (c1 = 1e8) or an index wrapped past i64 (1e18, 1e300)
    for big in [1e8, 1e18, 1e300] {
        let err = reconstruct(&h, 0, &[1], &[big]).unwrap_err();
        assert!(err.to_string().contains("moves ln M by"), "{err}");
    }
    let shift = reconstruct(&h, 0, &[1], &[c1]).unwrap();
    let zero_c2 = reconstruct(&h, 0, &[1], &[c1, 0.0]).unwrap();
    assert!((shift[0].l1 - zero_c2[0].l1).abs() < 1e-9);
    let d = h.config.dlnm;
    let nf = big_n as f64;
    let (mut mean, mut var) = (0.0, 0.0);
    for &p in &shift[0].measured {
        let pi_b = p * d;
        let v = 2.0 * pi_b * (1.0 - pi_b) / (nf * d * d);
        mean += d * (2.0 * v / PI).sqrt();
        var += d * d * v * (1.0 - 2.0 / PI);
    }
    let sd = var.sqrt();
    println!(
        "L1 of the shift {:.5}; counting noise {mean:.5} +- {sd:.5}",
        shift[0].l1
    );
    assert!(
        shift[0].l1 < mean + 4.0 * sd,
        "l1 {} vs {mean} +- {sd}",
        shift[0].l1
    );
    let off = reconstruct(&h, 0, &[1], &[c1 + 0.1]).unwrap();
    assert!(
        off[0].l1 > mean + 10.0 * sd,
        "a wrong shift: l1 {}",
        off[0].l1
    );
}

// ---------------------------------------------------------------- pdfs

/// The densities of [`wtmmm_pdfs`] for a known law: `N = 200 000` points
/// with `ln M ~ N(0, 1)` and A uniform, at one scale. Counting errors are
/// multinomial (the points are independent); every statistical bound is k
/// standard errors, k stated; the rest are identities.
/// * P(ln M): the bin [0, 0.05) holds `p0 = Φ(0.05) - Φ(0)` of the points,
///   so its density is `p0 / 0.05` (0.3988, the bin average of
///   1/√(2π) = 0.3989) within 3 binomial standard errors
///   `sqrt(p0 (1 - p0)/N)/0.05 = 0.006` (before: 0.02 around 1/√(2π));
///   and over all bins the goodness of fit to the normal bin
///   probabilities passes the chi-square test at the 0.999 quantile
///   (bins with at least 5 expected points; the tails pooled into one);
/// * P(M) = P(ln M)/M on the centres `m_i = e^(u_i)`: its trapezoid over M
///   is exactly `sinh(d)/d - ((e^d - 1) f_last + (1 - e^-d) f_0)/2` with
///   `d` the bin width and `f` the density of ln M (the sum of
///   `f_i (e^d - 1) + f_(i+1) (1 - e^-d)` telescopes because `Σ f d = 1`),
///   to rounding (before: within 0.01 of 1);
/// * P(A) = 1/(2π): it integrates to 1 (to rounding) and the 64 argument
///   bins pass the chi-square test of uniformity at the 0.999 quantile (63
///   degrees of freedom);
/// * each of the four sectors holds a quarter of the points within 4
///   binomial standard errors `sqrt(3/16/N) = 0.001` (before: 0.01), and
///   its `P(ln M | A)` and `P(M | A)` are those of the law (A independent
///   of M);
/// * the rescaled grid is `M / (a/a_min)^h0` and the (T1, T2) density
///   integrates to the law's expectation for its grid of cells within 4
///   standard deviations of the multinomial counts (before: between 0.9
///   and 1.01).
#[test]
fn pdfs_of_a_known_law() {
    use statrs::distribution::{ChiSquared, ContinuousCDF, Normal as StdNormal};
    let big_n = 200_000usize;
    let mut h = WtmmmHistograms::new(&[1.5, 3.0], PdfConfig::default()).unwrap();
    let mut rng = rng_for(11, 0);
    let n = Normal::new(0.0, 1.0).unwrap();
    for _ in 0..big_n {
        let u: f64 = n.sample(&mut rng);
        let a = rng.random_range(-PI..PI);
        h.add(1, u.exp(), a);
    }
    let p = wtmmm_pdfs(
        &h,
        &PdfOptions {
            show: vec![1],
            h0: 0.5,
            ..Default::default()
        },
    )
    .unwrap();
    let sp = &p[0];
    assert_eq!(sp.n as usize, big_n);
    json_round_trip(sp);
    let nf = big_n as f64;
    let d = h.config.dlnm;
    let phi = StdNormal::new(0.0, 1.0).unwrap();
    let q999 = |dof: usize| ChiSquared::new(dof as f64).unwrap().inverse_cdf(0.999);
    // density of ln M in the bin [0, d)
    // bins [k d, (k + 1) d), reported at their centres
    for &u in &sp.ln_m {
        let k = u / d - 0.5;
        assert!((k - k.round()).abs() < 1e-9, "bin centre {u}");
    }
    let i = sp
        .ln_m
        .iter()
        .position(|&u| (u - 0.5 * d).abs() < 0.5 * d)
        .unwrap();
    let p0 = phi.cdf(d) - phi.cdf(0.0);
    let se = (p0 * (1.0 - p0) / nf).sqrt() / d;
    assert!(
        (sp.p_ln_m[i] - p0 / d).abs() < 3.0 * se,
        "P(ln M) on [0, {d}): {} vs {} +- {se}",
        sp.p_ln_m[i],
        p0 / d
    );
    // goodness of fit of the whole ln M histogram (tails pooled)
    let (mut chi2, mut bins, mut tail_obs, mut tail_exp) = (0.0, 0usize, 0.0, 0.0);
    for (&u, &dens) in sp.ln_m.iter().zip(&sp.p_ln_m) {
        let obs = dens * nf * d;
        let exp = nf * (phi.cdf(u + 0.5 * d) - phi.cdf(u - 0.5 * d));
        if exp < 5.0 {
            tail_obs += obs;
            tail_exp += exp;
            continue;
        }
        chi2 += (obs - exp).powi(2) / exp;
        bins += 1;
    }
    // the probability outside the histogram's range belongs to the tails
    let (lo, hi) = (sp.ln_m[0] - 0.5 * d, sp.ln_m[sp.ln_m.len() - 1] + 0.5 * d);
    tail_exp += nf * (phi.cdf(lo) + 1.0 - phi.cdf(hi));
    chi2 += (tail_obs - tail_exp).powi(2) / tail_exp;
    bins += 1;
    println!(
        "P(ln M): chi2 {chi2:.1} on {} dof (0.999 quantile {:.1})",
        bins - 1,
        q999(bins - 1)
    );
    assert!(
        chi2 < q999(bins - 1),
        "P(ln M) is not N(0, 1): chi2 {chi2:.1}"
    );
    // P(M) = P(ln M)/M: the trapezoid over M of P(M) is, exactly, this
    // function of P(ln M) at its two ends (a density of total mass 1 on
    // bins of width d in ln M); (mass, want)
    let trapezoid = |p_m: &[f64], p_ln_m: &[f64]| {
        let mass: f64 =
            sp.m.windows(2)
                .zip(p_m.windows(2))
                .map(|(m, p)| 0.5 * (p[0] + p[1]) * (m[1] - m[0]))
                .sum();
        let (f0, fl) = (p_ln_m[0], p_ln_m[p_ln_m.len() - 1]);
        let want = d.sinh() / d - 0.5 * ((d.exp() - 1.0) * fl + (1.0 - (-d).exp()) * f0);
        (mass, want)
    };
    let (mass, want) = trapezoid(&sp.p_m, &sp.p_ln_m);
    assert!((mass - want).abs() < 1e-12, "mass {mass} vs {want}");
    // rescaled: x = M / 2^0.5, density multiplied by 2^0.5
    assert!((sp.rescaled_m[i] * 2f64.sqrt() - sp.m[i]).abs() < 1e-12);
    // P(A) uniform, and a density
    let da = sp.arg[1] - sp.arg[0];
    assert!((sp.p_arg.iter().sum::<f64>() * da - 1.0).abs() < 1e-12);
    let e = nf / sp.arg.len() as f64;
    let chi2_a: f64 = sp
        .p_arg
        .iter()
        .map(|&pa| (pa * nf * da - e).powi(2) / e)
        .sum();
    let dof = sp.arg.len() - 1;
    println!(
        "P(A): chi2 {chi2_a:.1} on {dof} dof (0.999 quantile {:.1})",
        q999(dof)
    );
    assert!(chi2_a < q999(dof), "P(A) not uniform: chi2 {chi2_a:.1}");
    // the four sectors have a quarter of the points each
    let se_s = (0.25 * 0.75 / nf).sqrt();
    for s in &sp.sectors {
        assert!(
            (s.n as f64 / nf - 0.25).abs() < 4.0 * se_s,
            "sector {}: {} of {big_n}",
            s.centre,
            s.n
        );
        // A is independent of M here, so P(ln M | A) is the law: a density,
        // N(0, 1) on [0, d) within 4 binomial errors of the sector's count,
        // and P(M | A) = P(ln M | A)/M (the trapezoid identity above)
        let ns = s.n as f64;
        assert_eq!((s.p_ln_m.len(), s.p_m.len()), (sp.m.len(), sp.m.len()));
        assert!((s.p_ln_m.iter().sum::<f64>() * d - 1.0).abs() < 1e-12);
        let se = (p0 * (1.0 - p0) / ns).sqrt() / d;
        assert!(
            (s.p_ln_m[i] - p0 / d).abs() < 4.0 * se,
            "sector {}: P(ln M) on [0, {d}): {} vs {} +- {se}",
            s.centre,
            s.p_ln_m[i],
            p0 / d
        );
        let (mass, want) = trapezoid(&s.p_m, &s.p_ln_m);
        assert!(
            (mass - want).abs() < 1e-12,
            "sector {}: mass {mass} vs {want}",
            s.centre
        );
    }
    // the (T1, T2) density integrates to what this law puts in its cells:
    // a cell at |T| = m holds the count of the (ln M, A) bin of its centre
    // over n d dA m^2, so on this grid the integral is the sum over bins of
    // count(k, b) W(k, b), W the summed dt^2 / (n d dA m^2) of the bin's
    // cells; the counts are multinomial with p(k, b) = P(ln M in bin k) / nb
    // (uniform angle), which gives its mean and standard deviation exactly
    let t = &sp.joint.t;
    let dt = t[1] - t[0];
    let mass2: f64 = sp.joint.density.iter().sum::<f64>() * dt * dt;
    let nb = h.config.arg_bins;
    let da = 2.0 * PI / nb as f64;
    let mut w: std::collections::HashMap<(i64, usize), f64> = Default::default();
    for &t2 in t {
        for &t1 in t {
            let m2 = t1 * t1 + t2 * t2;
            if m2 == 0.0 {
                continue; // the centre cell, of no modulus: density 0
            }
            let k = (0.5 * m2.ln() / d).floor() as i64;
            let b = ((((t2.atan2(t1) + PI) / (2.0 * PI)) * nb as f64).floor() as usize).min(nb - 1);
            *w.entry((k, b)).or_default() += dt * dt / (nf * d * da * m2);
        }
    }
    let p_kb = |k: i64| (phi.cdf((k + 1) as f64 * d) - phi.cdf(k as f64 * d)) / nb as f64;
    let mean: f64 = w.iter().map(|(&(k, _), &wk)| nf * p_kb(k) * wk).sum();
    let second: f64 = w.iter().map(|(&(k, _), &wk)| nf * p_kb(k) * wk * wk).sum();
    let sd = (second - nf * (mean / nf).powi(2)).sqrt();
    println!("(T1, T2) mass {mass2:.5}, law {mean:.5} +- {sd:.5}");
    assert!(
        (mass2 - mean).abs() < 4.0 * sd,
        "(T1, T2) mass {mass2} vs {mean} +- {sd}"
    );
}

/// Pearson's statistic of the homogeneity of two binned samples (a 2 x K
/// contingency table, counts `a[k]` and `b[k]` of totals `na`, `nb`), over
/// the bins whose expected count under homogeneity is at least 5 in both
/// samples (Cochran's rule): `Σ (a - E_a)²/E_a + (b - E_b)²/E_b` with
/// `E_a = na (a + b)/(na + nb)`. Returns (statistic, degrees of freedom =
/// bins used - 1).
fn homogeneity_chi2(a: &[f64], b: &[f64], na: f64, nb: f64) -> (f64, usize) {
    let (mut chi2, mut bins) = (0.0, 0usize);
    for (&x, &y) in a.iter().zip(b) {
        let (ea, eb) = (na * (x + y) / (na + nb), nb * (x + y) / (na + nb));
        if ea.min(eb) < 5.0 {
            continue;
        }
        chi2 += (x - ea).powi(2) / ea + (y - eb).powi(2) / eb;
        bins += 1;
    }
    (chi2, bins.saturating_sub(1))
}

/// II eq 39 (paper I Fig 27, II Fig 14b): for a monofractal of exponent H
/// the pdfs of the WTMMM moduli on the maxima lines, rescaled as `M /
/// (a/a_min)^H` (`PdfOptions::h0`, [`wtmmm_pdfs`]'s `rescaled_m`,
/// `p_rescaled`), coincide at every scale. 16 fBm images of 512² (H = 1/3,
/// gauss, 4 octaves), scales a = 3, 6, 12 px (octaves 1, 2, 3; below the
/// first octave the pixel bends the local exponent, README "Fit range").
/// The ln M bins are `dlnm = H ln2 / 2` wide so that the rescaling moves
/// them by exactly 2 bins per octave, and the rescaled densities of two
/// scales are compared bin by bin:
/// * exactly: the rescaled density integrates to 1 over `ln(M / s)`
///   (`Σ p_rescaled · rescaled_m · dlnm = 1`, to rounding);
/// * statistically: the counts `p_rescaled · rescaled_m · n · dlnm` of
///   each pair of scales pass the chi-square test of homogeneity (binned
///   multinomial counting errors) at the 0.999 quantile, 3 pairs, 0.3 %
///   family-wise. Binomial errors are adequate here: a jackknife over the
///   16 images gives per-bin errors 0.93-1.06 times the binomial ones on
///   average (measured), i.e. the WTMMM of a scale behave as independent
///   draws for their histogram. Measured: chi2 = 26.2, 18.3, 20.2 on 18,
///   15, 16 degrees of freedom (quantiles 42.3, 37.7, 39.3).
/// * power: rescaling with h0 = H + 0.05 (or H - 0.05) instead must fail
///   for at least one pair (measured: chi2 / quantile 1.66, 1.66, 1.12 and
///   0.83, 1.17, 0.76), so the test resolves the exponent of the collapse
///   to 0.05.
#[test]
fn rescaled_pdfs_collapse_for_a_monofractal() {
    use rayon::prelude::*;
    use statrs::distribution::{ChiSquared, ContinuousCDF};
    let h = 1.0 / 3.0;
    let cfg = AnalysisConfig {
        octaves: 4,
        ..Default::default()
    };
    let scales = cfg.scale_list();
    let show = vec![10, 20, 30];
    let images: Vec<wtmm::stats::pdf::ImageWtmmm> = (0..16u64)
        .into_par_iter()
        .map(|i| {
            let f = wtmm::synth::fbm::fbm(wtmm::synth::fbm::FbmParams { hurst: h }, 512, 512, 5, i)
                .unwrap();
            image_wtmmm(&Field::new(f), &cfg, Parallelism::Serial, true).unwrap()
        })
        .collect();
    // the largest chi2 / quantile over the three pairs, for an exponent h0
    let worst = |h0: f64| -> f64 {
        let dl = h0 * LN_2 / 2.0;
        let pc = PdfConfig {
            dlnm: dl,
            arg_bins: 64,
        };
        let mut hist = WtmmmHistograms::new(&scales, pc).unwrap();
        for im in &images {
            hist.merge(&WtmmmHistograms::from_points(&scales, pc, &im.lines).unwrap())
                .unwrap();
        }
        let pdfs = wtmmm_pdfs(
            &hist,
            &PdfOptions {
                show: show.clone(),
                h0,
                ..Default::default()
            },
        )
        .unwrap();
        // counts per rescaled bin, keyed by the bin index of ln(M / s)
        let counts: Vec<std::collections::BTreeMap<i64, f64>> = pdfs
            .iter()
            .map(|sp| {
                let total: f64 = sp
                    .rescaled_m
                    .iter()
                    .zip(&sp.p_rescaled)
                    .map(|(x, p)| p * x * dl)
                    .sum();
                assert!((total - 1.0).abs() < 1e-12, "a = {}: mass {total}", sp.a);
                sp.rescaled_m
                    .iter()
                    .zip(&sp.p_rescaled)
                    .map(|(x, p)| ((x.ln() / dl - 0.5).round() as i64, p * x * dl * sp.n as f64))
                    .collect()
            })
            .collect();
        let mut worst: f64 = 0.0;
        for (i, k) in [(0, 1), (0, 2), (1, 2)] {
            let keys: std::collections::BTreeSet<i64> =
                counts[i].keys().chain(counts[k].keys()).copied().collect();
            let a: Vec<f64> = keys
                .iter()
                .map(|b| *counts[i].get(b).unwrap_or(&0.0))
                .collect();
            let b: Vec<f64> = keys
                .iter()
                .map(|b| *counts[k].get(b).unwrap_or(&0.0))
                .collect();
            let (chi2, dof) = homogeneity_chi2(&a, &b, pdfs[i].n as f64, pdfs[k].n as f64);
            let q = ChiSquared::new(dof as f64).unwrap().inverse_cdf(0.999);
            println!(
                "h0 = {h0:.4}: a = {:.1} vs {:.1} ({} and {} WTMMM): chi2 {chi2:.1} on {dof} dof (0.999 quantile {q:.1})",
                pdfs[i].a, pdfs[k].a, pdfs[i].n, pdfs[k].n
            );
            worst = worst.max(chi2 / q);
        }
        worst
    };
    let w = worst(h);
    assert!(
        w < 1.0,
        "the rescaled pdfs of a monofractal do not collapse: chi2 / quantile {w:.2}"
    );
    for h0 in [h + 0.05, h - 0.05] {
        assert!(worst(h0) > 1.0, "h0 = {h0}: the collapse should fail");
    }
}

// ---------------------------------------------------------------- correlation

/// The slow reference: every pair of points at every lag, binned like the
/// fast path (lags on the torus for periodic, inside the domain otherwise).
struct Brute {
    num: Vec<f64>,
    cnt: Vec<f64>,
    lc: Vec<f64>,
}

fn bin_of(r: f64, bpo: usize) -> usize {
    (bpo as f64 * r.log2() + 0.5).floor() as usize
}

#[allow(clippy::too_many_arguments)]
fn brute_pairs(
    p1: &[(usize, usize, f64)],
    p2: &[(usize, usize, f64)],
    shape: (usize, usize),
    periodic: bool,
    max_dx: f64,
    bpo: usize,
    nbins: usize,
    out: &mut Brute,
) {
    let (ny, nx) = shape;
    for &(y1, x1, w1) in p1 {
        for &(y2, x2, w2) in p2 {
            let (mut sy, mut sx) = (y2 as i64 - y1 as i64, x2 as i64 - x1 as i64);
            if periodic {
                sy = sy.rem_euclid(ny as i64);
                sx = sx.rem_euclid(nx as i64);
                if sy > ny as i64 / 2 {
                    sy -= ny as i64;
                }
                if sx > nx as i64 / 2 {
                    sx -= nx as i64;
                }
            }
            let r = ((sy * sy + sx * sx) as f64).sqrt();
            if r == 0.0 || r > max_dx {
                continue;
            }
            let b = bin_of(r, bpo).min(nbins - 1);
            out.num[b] += w1 * w2;
            out.cnt[b] += 1.0;
            out.lc[b] += r.log2();
        }
    }
}

/// `|T|²` averaged over a periodic square of side `a` centred on each
/// pixel (II eqs 65, 67; SPEC §6 `ε²`), each pixel weighted by the area of
/// it inside the square, written out directly.
fn box_energy_direct(t2: &Array2<f64>, a: f64) -> Array2<f64> {
    let (ny, nx) = t2.dim();
    let h = a / 2.0;
    let r = (h - 0.5).ceil().max(0.0) as i64;
    let inside = |d: i64| ((d as f64 + 0.5).min(h) - (d as f64 - 0.5).max(-h)).max(0.0);
    Array2::from_shape_fn((ny, nx), |(y, x)| {
        let mut s = 0.0;
        for dy in -r..=r {
            for dx in -r..=r {
                let yy = (y as i64 + dy).rem_euclid(ny as i64) as usize;
                let xx = (x as i64 + dx).rem_euclid(nx as i64) as usize;
                s += inside(dy) * inside(dx) * t2[[yy, xx]];
            }
        }
        s / (a * a)
    })
}

/// The magnitude of a field at the given scales over a rectangle (`ln M`,
/// or `½ ln ε²` for [`Magnitude::Energy`]), at the points where the
/// magnitude's own amplitude (M, or ε) is `>= eps` times its maximum over
/// the rectangle at every scale, not centred.
fn magnitude_points(
    img: &Array2<f64>,
    scales: &[f64],
    dom: (usize, usize, usize, usize),
    eps: f64,
    magnitude: Magnitude,
) -> Vec<Vec<(usize, usize, f64)>> {
    let (ny, nx) = img.dim();
    let plan = CwtPlan::new(ny, nx, Wavelet::Gauss, scales).unwrap();
    let fi = plan.forward(img.view()).unwrap();
    let mut ws = plan.workspace();
    // the amplitude whose log is the magnitude: M, or ε = sqrt(box mean |T|²)
    let amps: Vec<Array2<f64>> = (0..scales.len())
        .map(|s| {
            let t = plan.scale(&fi, s, &mut ws);
            match magnitude {
                Magnitude::Lnm => t.map(|&z| modulus(z)),
                Magnitude::Energy => {
                    box_energy_direct(&t.map(|z| z.norm_sqr()), scales[s]).mapv(f64::sqrt)
                }
            }
        })
        .collect();
    let pts = || (dom.0..dom.1).flat_map(|y| (dom.2..dom.3).map(move |x| (y, x)));
    let mx: Vec<f64> = amps
        .iter()
        .map(|m| pts().map(|(y, x)| m[[y, x]]).fold(0.0, f64::max))
        .collect();
    let ok = |y: usize, x: usize| (0..scales.len()).all(|s| amps[s][[y, x]] >= eps * mx[s]);
    amps.iter()
        .map(|m| {
            pts()
                .filter(|&(y, x)| ok(y, x))
                .map(|(y, x)| (y, x, m[[y, x]].ln()))
                .collect()
        })
        .collect()
}

/// Mean of the values of a point list.
fn mean_of(v: &[(usize, usize, f64)]) -> f64 {
    v.iter().map(|p| p.2).sum::<f64>() / v.len() as f64
}

fn noise_field(ny: usize, nx: usize, seed: u64) -> Array2<f64> {
    let mut rng = rng_for(seed, 0);
    let n = Normal::new(0.0, 1.0).unwrap();
    Array2::from_shape_fn((ny, nx), |_| n.sample(&mut rng))
}

/// The correlation FFTs run in f32 (`stats::correlation`), so the binned
/// sums agree with the f64 pair loops to the FFT's rounding, not exactly.
/// The usual bound of a floating-point FFT correlation: per lag at most
/// `c ε log2(N) ||f|| ||g||` (ε the f32 unit, N the FFT size, c = 4),
/// summed over the lags of a bin.
fn f32_fft_bound(norm_fg: f64, n_fft: usize, lags: f64) -> f64 {
    4.0 * f32::EPSILON as f64 * (n_fft as f64).log2() * norm_fg * lags
}

/// Number of lags `(sy, sx)` per log bin, `0 < |d| <= max_dx`.
fn lags_per_bin(max_dx: f64, bpo: usize, nbins: usize) -> Vec<f64> {
    let m = max_dx.floor() as i64;
    let mut n = vec![0.0; nbins];
    for sy in -m..=m {
        for sx in -m..=m {
            let r = ((sy * sy + sx * sx) as f64).sqrt();
            if r > 0.0 && r <= max_dx {
                n[bin_of(r, bpo).min(nbins - 1)] += 1.0;
            }
        }
    }
    n
}

/// Euclidean norm of a point list's values.
fn norm_of(v: &[(usize, usize, f64)]) -> f64 {
    v.iter().map(|p| p.2 * p.2).sum::<f64>().sqrt()
}

/// The FFT correlation (SPEC §6) equals a brute-force loop over every pair
/// of points, binned the same way: pair counts exactly (integers), mean
/// log2 |Δx| to 1e-6, C (per-image and ensemble centring) within the f32
/// FFT's rounding bound. For `ln M` at scales 1.3 and 2.1, and for the box
/// energy `½ ln ε²` (`Magnitude::Energy`, II eqs 65, 67) at 1.5 and 4.2
/// (squares of side a: 3 and 5 px, their edge pixels in part), whose boxes
/// the brute force averages directly ([`box_energy_direct`]).
#[test]
fn fft_correlation_equals_brute_force_pairs() {
    for (magnitude, scales) in [
        (Magnitude::Lnm, vec![1.3, 2.1]),
        (Magnitude::Energy, vec![1.5, 4.2]),
    ] {
        brute_force_check(magnitude, scales);
    }
}

/// `field_correlation` (given magnitude fields, e.g. a generator's own
/// cascade) applies the same centring and binning as `cwt_correlation`:
/// fed ln M of the same transform, it gives the same sums (to rounding:
/// `ln sqrt(x)` against `½ ln x`), on the torus and on an interior domain
/// (whose rows and columns it must copy from the margin on).
#[test]
fn field_correlation_matches_the_cwt_path() {
    let (ny, nx) = (40, 36);
    let scales = vec![1.5, 3.0];
    for (periodic, margin) in [(true, 0), (false, 5)] {
        let cfg = CorrelationConfig {
            scales: scales.clone(),
            pairs: vec![(0, 0), (0, 1), (1, 1)],
            periodic,
            margin: Some(margin),
            ..Default::default()
        };
        let plan = CorrelationPlan::new(ny, nx, &cfg).unwrap();
        let cwt = CwtPlan::new(ny, nx, Wavelet::Gauss, &scales).unwrap();
        for seed in 0..2 {
            let img = noise_field(ny, nx, 7 + seed);
            let want = cwt_correlation(&Field::new(img.clone()), &plan, "a").unwrap();
            let mut lnm = vec![Array2::<f64>::zeros((ny, nx)); scales.len()];
            cwt.for_each_scale(img.view(), |j, _, t| {
                lnm[j] = t.mapv(|c| modulus(c).ln());
            })
            .unwrap();
            let got = field_correlation(&lnm, &plan, "cwt", "a").unwrap();
            let (w, g) = (&want.images[0], &got.images[0]);
            for (a, b) in w.mean.iter().zip(&g.mean) {
                assert!((a - b).abs() < 1e-12, "{periodic}: mean {a} vs {b}");
            }
            assert_eq!(w.n, g.n);
            for (pw, pg) in w.pairs.iter().zip(&g.pairs) {
                for (x, y) in [(&pw.ww, &pg.ww), (&pw.wm, &pg.wm), (&pw.mw, &pg.mw)] {
                    let scale = x.iter().fold(1.0f64, |m, v| m.max(v.abs()));
                    for (a, b) in x.iter().zip(y) {
                        assert!((a - b).abs() < 1e-9 * scale, "{periodic}: {a} vs {b}");
                    }
                }
                assert_eq!(pw.count, pg.count);
            }
        }
        // the number and shape of the fields are checked
        assert!(field_correlation(&[], &plan, "x", "a").is_err());
        let small = vec![Array2::<f64>::zeros((8, 8)); 2];
        assert!(field_correlation(&small, &plan, "x", "a").is_err());
    }
}

fn brute_force_check(magnitude: Magnitude, scales: Vec<f64>) {
    // odd, non-power-of-two sizes; periodic and interior domains
    let (ny, nx) = (23, 29);
    let pairs = vec![(0, 0), (0, 1), (1, 0), (1, 1)];
    let bpo = 3;
    // eps = 0.3 leaves out a share of the points (the masked paths); with
    // the default eps every point is valid (torus and rectangle paths)
    for (periodic, margin, max_dx, eps) in [
        (true, 0, 11.0, 1e-7),
        (false, 4, 9.5, 1e-7),
        (true, 0, 11.0, 0.3),
        (false, 4, 9.5, 0.3),
    ] {
        let cfg = CorrelationConfig {
            scales: scales.clone(),
            pairs: pairs.clone(),
            periodic,
            margin: Some(margin),
            bins_per_octave: bpo,
            max_dx: Some(max_dx),
            eps,
            magnitude,
            ..Default::default()
        };
        let plan = CorrelationPlan::new(ny, nx, &cfg).unwrap();
        let dom = (margin, ny - margin, margin, nx - margin);
        let imgs: Vec<Array2<f64>> = (0..2).map(|i| noise_field(ny, nx, 100 + i)).collect();
        let mut sums: Option<CorrelationSums> = None;
        for (i, img) in imgs.iter().enumerate() {
            let s = cwt_correlation(&Field::new(img.clone()), &plan, format!("{i}")).unwrap();
            match &mut sums {
                None => sums = Some(s),
                Some(a) => a.merge(&s).unwrap(),
            }
        }
        let r = correlation_estimates(&sums.unwrap()).unwrap();
        assert_eq!(r.stderr_method, "none");
        assert!(
            r.warnings[0].contains("no standard errors"),
            "{:?}",
            r.warnings
        );
        let nbins = bin_of(max_dx, bpo) + 1;
        // brute force: per-image centring, and ensemble centring
        let raw: Vec<Vec<Vec<(usize, usize, f64)>>> = imgs
            .iter()
            .map(|im| magnitude_points(im, &scales, dom, eps, magnitude))
            .collect();
        let n_pts = raw[0][0].len();
        assert!(
            n_pts > 0 && (eps < 1e-3) == (n_pts == (ny - 2 * margin) * (nx - 2 * margin)),
            "{magnitude:?} eps = {eps}: {n_pts} valid points"
        );
        // means[s][i]: image i's mean at scale s
        let means: Vec<Vec<f64>> = (0..scales.len())
            .map(|s| raw.iter().map(|im| mean_of(&im[s])).collect())
            .collect();
        let w: Vec<Vec<Vec<(usize, usize, f64)>>> = raw
            .iter()
            .enumerate()
            .map(|(i, im)| {
                im.iter()
                    .enumerate()
                    .map(|(s, v)| v.iter().map(|&(y, x, u)| (y, x, u - means[s][i])).collect())
                    .collect()
            })
            .collect();
        for (p, &(s1, s2)) in pairs.iter().enumerate() {
            let mut b = Brute {
                num: vec![0.0; nbins],
                cnt: vec![0.0; nbins],
                lc: vec![0.0; nbins],
            };
            let mut be = Brute {
                num: vec![0.0; nbins],
                cnt: vec![0.0; nbins],
                lc: vec![0.0; nbins],
            };
            // pooled over points (the images may keep different numbers)
            let pooled = |s: usize| {
                let n: Vec<f64> = raw.iter().map(|im| im[s].len() as f64).collect();
                (means[s][0] * n[0] + means[s][1] * n[1]) / (n[0] + n[1])
            };
            let (mu1, mu2) = (pooled(s1), pooled(s2));
            for i in 0..2 {
                brute_pairs(
                    &w[i][s1],
                    &w[i][s2],
                    (ny, nx),
                    periodic,
                    max_dx,
                    bpo,
                    nbins,
                    &mut b,
                );
                let e1: Vec<_> = w[i][s1]
                    .iter()
                    .map(|&(y, x, v)| (y, x, v + means[s1][i] - mu1))
                    .collect();
                let e2: Vec<_> = w[i][s2]
                    .iter()
                    .map(|&(y, x, v)| (y, x, v + means[s2][i] - mu2))
                    .collect();
                brute_pairs(&e1, &e2, (ny, nx), periodic, max_dx, bpo, nbins, &mut be);
            }
            let pc = &r.pairs[p];
            // f32 FFT bounds (sums over both images) of the values and the
            // ensemble-centred values (triangle inequality over the cross
            // terms `δ Σ w m`); pair counts are rounded per lag, so exact
            let (fy, fx) = plan.fft_shape();
            let (n_fft, lags) = (fy * fx, lags_per_bin(max_dx, bpo, nbins));
            let ones = |i: usize, s: usize| (raw[i][s].len() as f64).sqrt();
            let nw: f64 = (0..2)
                .map(|i| norm_of(&w[i][s1]) * norm_of(&w[i][s2]))
                .sum();
            let ne: f64 = (0..2)
                .map(|i| {
                    let d1 = (means[s1][i] - mu1).abs() * ones(i, s1);
                    let d2 = (means[s2][i] - mu2).abs() * ones(i, s2);
                    (norm_of(&w[i][s1]) + d1) * (norm_of(&w[i][s2]) + d2)
                })
                .sum();
            let keep: Vec<usize> = (0..nbins).filter(|&k| b.cnt[k] > 0.0).collect();
            assert_eq!(
                pc.c.len(),
                keep.len(),
                "{magnitude:?} periodic={periodic} eps={eps} pair {p}"
            );
            for (o, &k) in keep.iter().enumerate() {
                let ctx = format!("{magnitude:?} periodic={periodic} eps={eps} pair {p} bin {k}");
                let tol = |norm: f64| f32_fft_bound(norm, n_fft, lags[k]) / b.cnt[k];
                assert!((pc.pairs[o] - b.cnt[k]).abs() < 1e-6, "{ctx}: count");
                assert!(
                    (pc.log2_dx[o] - b.lc[k] / b.cnt[k]).abs() < 1e-6,
                    "{ctx}: log2_dx"
                );
                assert!(
                    (pc.c[o] - b.num[k] / b.cnt[k]).abs() <= tol(nw),
                    "{ctx}: C {} vs {}",
                    pc.c[o],
                    b.num[k] / b.cnt[k]
                );
                assert!(
                    (pc.c_ensemble[o] - be.num[k] / be.cnt[k]).abs() <= tol(ne),
                    "{ctx}: C_ensemble"
                );
            }
            // lag 0: the covariance of the two scales' values at the same
            // pixel, over the pixels valid at both (one lag of the FFT)
            let lag0 = |pts: &dyn Fn(usize, usize) -> Vec<(usize, usize, f64)>| {
                let (mut num, mut cnt) = (0.0, 0.0);
                for i in 0..2 {
                    let second: std::collections::HashMap<(usize, usize), f64> = pts(i, s2)
                        .into_iter()
                        .map(|(y, x, v)| ((y, x), v))
                        .collect();
                    for (y, x, v) in pts(i, s1) {
                        if let Some(u) = second.get(&(y, x)) {
                            num += v * u;
                            cnt += 1.0;
                        }
                    }
                }
                (num / cnt, cnt)
            };
            let (per_image, cnt0) = lag0(&|i, s| w[i][s].clone());
            let (ensemble, _) = lag0(&|i, s| {
                let mu = if s == s1 { mu1 } else { mu2 };
                w[i][s]
                    .iter()
                    .map(|&(y, x, v)| (y, x, v + means[s][i] - mu))
                    .collect()
            });
            let ctx = format!("{magnitude:?} periodic={periodic} eps={eps} pair {p} lag 0");
            assert!(cnt0 >= 1.0, "{ctx}");
            let tol0 = |norm: f64| f32_fft_bound(norm, n_fft, 1.0) / cnt0;
            assert!(
                (pc.c0 - per_image).abs() <= tol0(nw),
                "{ctx}: c0 {} vs {per_image}",
                pc.c0
            );
            assert!(
                (pc.c0_ensemble - ensemble).abs() <= tol0(ne),
                "{ctx}: c0_ensemble {} vs {ensemble}",
                pc.c0_ensemble
            );
        }
    }
}

/// Delete-one-tile jackknife of the correlation, by brute force: each
/// replicate leaves out the pairs whose first point lies in one tile and
/// centres every point again on the mean of the points outside it (per
/// image for `C`, pooled over the images for `C_ensemble`). `pts[i][s]` are
/// image i's points at scale s (domain coordinates for the tile), not
/// centred. Returns, per pair and bin, the errors of `C` and `C_ensemble`.
/// Points `(y, x, value)` of each image at each scale.
type ImagePoints = Vec<Vec<(usize, usize, f64)>>;

#[allow(clippy::too_many_arguments)]
fn brute_tile_errors(
    pts: &[ImagePoints],
    tile_of: &dyn Fn(usize, usize) -> usize,
    n_tiles: usize,
    pairs: &[(usize, usize)],
    shape: (usize, usize),
    periodic: bool,
    max_dx: f64,
    bpo: usize,
    nbins: usize,
) -> Vec<(Vec<f64>, Vec<f64>)> {
    let ns = pts[0].len();
    let mean = |v: &[&(usize, usize, f64)]| v.iter().map(|p| p.2).sum::<f64>() / v.len() as f64;
    // one replicate per (image, tile): (C, C_ensemble) per pair and bin
    let mut reps: Vec<Vec<(Vec<f64>, Vec<f64>)>> = Vec::new();
    for i in 0..pts.len() {
        for t in 0..n_tiles {
            let out_of = |j: usize, p: &(usize, usize, f64)| j != i || tile_of(p.0, p.1) != t;
            // per image and scale: the mean of the points left
            let own: Vec<Vec<f64>> = (0..pts.len())
                .map(|j| {
                    (0..ns)
                        .map(|s| {
                            let v: Vec<_> = pts[j][s].iter().filter(|p| out_of(j, p)).collect();
                            mean(&v)
                        })
                        .collect()
                })
                .collect();
            let pooled: Vec<f64> = (0..ns)
                .map(|s| {
                    let v: Vec<_> = (0..pts.len())
                        .flat_map(|j| pts[j][s].iter().filter(move |p| out_of(j, p)))
                        .collect();
                    mean(&v)
                })
                .collect();
            let rep = pairs
                .iter()
                .map(|&(s1, s2)| {
                    let mut c = (vec![0.0; nbins], vec![0.0; nbins]);
                    for (which, out) in [&mut c.0, &mut c.1].into_iter().enumerate() {
                        let mut b = Brute {
                            num: vec![0.0; nbins],
                            cnt: vec![0.0; nbins],
                            lc: vec![0.0; nbins],
                        };
                        for j in 0..pts.len() {
                            let m = |s: usize| if which == 0 { own[j][s] } else { pooled[s] };
                            let first: Vec<_> = pts[j][s1]
                                .iter()
                                .filter(|p| out_of(j, p))
                                .map(|&(y, x, v)| (y, x, v - m(s1)))
                                .collect();
                            let second: Vec<_> = pts[j][s2]
                                .iter()
                                .map(|&(y, x, v)| (y, x, v - m(s2)))
                                .collect();
                            brute_pairs(
                                &first, &second, shape, periodic, max_dx, bpo, nbins, &mut b,
                            );
                        }
                        for ((o, n), c) in out.iter_mut().zip(&b.num).zip(&b.cnt) {
                            *o = n / c;
                        }
                    }
                    c
                })
                .collect();
            reps.push(rep);
        }
    }
    let se = |v: Vec<f64>| {
        let n = v.len() as f64;
        let m = v.iter().sum::<f64>() / n;
        ((n - 1.0) / n * v.iter().map(|x| (x - m).powi(2)).sum::<f64>()).sqrt()
    };
    (0..pairs.len())
        .map(|p| {
            let per = |which: usize| -> Vec<f64> {
                (0..nbins)
                    .map(|k| {
                        se(reps
                            .iter()
                            .map(|r| if which == 0 { r[p].0[k] } else { r[p].1[k] })
                            .collect())
                    })
                    .collect()
            };
            (per(0), per(1))
        })
        .collect()
}

/// A lone image's correlation errors (and two images') come from a
/// jackknife over tiles of its domain: the tile sums add up to the image's
/// (pair counts exactly), and the errors equal a brute-force
/// leave-one-tile-out over every pair, re-centred, on the torus and the
/// interior, with every point valid and with a mask (eps), for ln M on the
/// CWT grid and for the skeleton's WTMMM.
#[test]
fn tile_jackknife_of_the_correlation_equals_brute_force() {
    let (ny, nx) = (26, 31);
    let scales = vec![1.3, 2.1];
    let pairs = vec![(0, 0), (1, 0), (0, 1)];
    let bpo = 3;
    for (periodic, margin, max_dx, eps, n_img) in [
        (true, 0, 11.0, 1e-7, 1),
        (false, 3, 9.5, 1e-7, 1),
        (true, 0, 11.0, 0.3, 2),
        (false, 3, 9.5, 0.3, 1),
    ] {
        let ctx = format!("periodic={periodic} eps={eps} images={n_img}");
        let cfg = CorrelationConfig {
            scales: scales.clone(),
            pairs: pairs.clone(),
            periodic,
            margin: Some(margin),
            bins_per_octave: bpo,
            max_dx: Some(max_dx),
            eps,
            ..Default::default()
        };
        let plan = CorrelationPlan::new(ny, nx, &cfg).unwrap();
        let dom = (margin, ny - margin, margin, nx - margin);
        let (dy, dx) = (dom.1 - dom.0, dom.3 - dom.2);
        // 3 x 3 tiles of a domain of 20-31 px
        let side = dy.min(dx) / 3;
        let grid = wtmm::spectra::TileGrid::new((0, dy, 0, dx), side).unwrap();
        let imgs: Vec<Array2<f64>> = (0..n_img)
            .map(|i| noise_field(ny, nx, 300 + i as u64))
            .collect();
        let mut sums: Option<CorrelationSums> = None;
        for (i, img) in imgs.iter().enumerate() {
            let s = cwt_correlation_tiled(&Field::new(img.clone()), &plan, format!("{i}"), side)
                .unwrap();
            let im = &s.images[0];
            assert_eq!((im.tiles.len(), im.tile_side), (grid.len(), side), "{ctx}");
            // the tiles add up to the image
            for (s_, &n) in im.n.iter().enumerate() {
                let tn: f64 = im.tiles.iter().map(|t| t.n[s_]).sum();
                let tw: f64 = im.tiles.iter().map(|t| t.wsum[s_]).sum();
                assert_eq!(tn, n, "{ctx}");
                assert!(tw.abs() < 1e-9 * n, "{ctx}: sum of w̃ {tw}");
            }
            for (p, ps) in im.pairs.iter().enumerate() {
                let add = |f: &dyn Fn(&wtmm::stats::correlation::PairSums) -> &Vec<f64>| {
                    let mut v = vec![0.0; f(ps).len()];
                    for t in &im.tiles {
                        for (a, b) in v.iter_mut().zip(f(&t.pairs[p])) {
                            *a += b;
                        }
                    }
                    v
                };
                assert_eq!(add(&|q| &q.count), ps.count, "{ctx}: counts");
                for (a, b) in add(&|q| &q.lcount).iter().zip(&ps.lcount) {
                    assert!((a - b).abs() < 1e-9 * b.abs().max(1.0), "{ctx}: lcount");
                }
                type Get = fn(&wtmm::stats::correlation::PairSums) -> &Vec<f64>;
                let gets: [Get; 3] = [|q| &q.ww, |q| &q.wm, |q| &q.mw];
                for f in gets {
                    let scale = ps.count.iter().fold(1.0f64, |m, v| m.max(*v));
                    for (a, b) in add(&f).iter().zip(f(ps)) {
                        // f32 FFTs of fields of order 1: 1e-5 of the pair count
                        assert!((a - b).abs() < 1e-5 * scale, "{ctx}: {a} vs {b}");
                    }
                }
            }
            match &mut sums {
                None => sums = Some(s),
                Some(a) => a.merge(&s).unwrap(),
            }
        }
        let r = correlation_estimates(&sums.unwrap()).unwrap();
        assert_eq!(
            r.stderr_method,
            format!("jackknife over {} tiles ({side} px)", n_img * grid.len()),
            "{ctx}"
        );
        let raw: Vec<Vec<Vec<(usize, usize, f64)>>> = imgs
            .iter()
            .map(|im| magnitude_points(im, &scales, dom, eps, Magnitude::Lnm))
            .collect();
        let nbins = bin_of(max_dx, bpo) + 1;
        let tile_of = |y: usize, x: usize| grid.index((x - margin) as u32, (y - margin) as u32);
        let want = brute_tile_errors(
            &raw,
            &tile_of,
            grid.len(),
            &pairs,
            (ny, nx),
            periodic,
            max_dx,
            bpo,
            nbins,
        );
        let mut checked = 0;
        for (p, (se, se_e)) in want.iter().enumerate() {
            let pc = &r.pairs[p];
            let keep: Vec<usize> = (0..nbins).filter(|&k| se[k].is_finite()).collect();
            assert_eq!(pc.c_stderr.len(), keep.len(), "{ctx}");
            for (o, &k) in keep.iter().enumerate() {
                // the replicates' f32 rounding (about 1e-7 of C) against
                // errors of order 1e-2
                let (a, b) = (pc.c_stderr[o], se[k]);
                assert!(
                    (a - b).abs() < 1e-4 * b + 1e-6,
                    "{ctx} pair {p} bin {k}: {a} vs {b}"
                );
                let (a, b) = (pc.c_ensemble_stderr[o], se_e[k]);
                assert!(
                    (a - b).abs() < 1e-4 * b + 1e-6,
                    "{ctx} pair {p} bin {k}: {a} vs {b}"
                );
                checked += (b > 1e-3) as usize;
            }
        }
        assert!(checked > 10, "{ctx}: {checked} bins with an error to check");
    }
    // the skeleton's points (per-scale weights): random WTMMM, one image
    let mut rng = rng_for(9, 0);
    let u = Normal::<f64>::new(0.0, 1.0).unwrap();
    let (ny, nx) = (30, 27);
    let pts: Vec<Vec<Point>> = (0..2)
        .map(|_| {
            (0..160)
                .map(|_| Point {
                    y: ((u.sample(&mut rng).abs() * 1e6) as usize % ny) as u32,
                    x: ((u.sample(&mut rng).abs() * 1e6) as usize % nx) as u32,
                    m: u.sample(&mut rng).exp(),
                    arg: 0.0,
                })
                .collect()
        })
        .collect();
    for periodic in [true, false] {
        let cfg = CorrelationConfig {
            scales: vec![1.5, 3.0],
            pairs: vec![(0, 1), (1, 1)],
            periodic,
            margin: Some(0),
            bins_per_octave: 4,
            max_dx: Some(12.0),
            ..Default::default()
        };
        let plan = CorrelationPlan::new(ny, nx, &cfg).unwrap();
        let refs: Vec<&[Point]> = pts.iter().map(|v| v.as_slice()).collect();
        // tiles over part of the image: the points outside belong to the
        // nearest tile
        let dom = (4, ny - 3, 2, nx);
        let s = wtmmm_correlation_tiled(&refs, &plan, "x", dom, 10).unwrap();
        let grid = wtmm::spectra::TileGrid::new(dom, 10).unwrap();
        assert_eq!(s.images[0].tiles.len(), 4);
        assert!(wtmmm_correlation_tiled(&refs, &plan, "x", (0, ny + 1, 0, nx), 10).is_err());
        let r = correlation_estimates(&s).unwrap();
        let raw = vec![
            pts.iter()
                .map(|v| {
                    v.iter()
                        .map(|q| (q.y as usize, q.x as usize, q.m.ln()))
                        .collect()
                })
                .collect::<Vec<_>>(),
        ];
        let nbins = bin_of(12.0, 4) + 1;
        let tile_of = |y: usize, x: usize| grid.index(x as u32, y as u32);
        let want = brute_tile_errors(
            &raw,
            &tile_of,
            grid.len(),
            &cfg.pairs,
            (ny, nx),
            periodic,
            12.0,
            4,
            nbins,
        );
        for (p, (se, _)) in want.iter().enumerate() {
            let keep: Vec<usize> = (0..nbins).filter(|&k| se[k].is_finite()).collect();
            for (o, &k) in keep.iter().enumerate() {
                let (a, b) = (r.pairs[p].c_stderr[o], se[k]);
                assert!(
                    (a - b).abs() < 1e-4 * b + 1e-6,
                    "wtmmm periodic={periodic} pair {p} bin {k}: {a} vs {b}"
                );
            }
        }
    }
}

#[test]
fn wtmmm_correlation_equals_brute_force_pairs() {
    let (ny, nx) = (40, 33);
    let mut rng = rng_for(5, 0);
    let u = Normal::<f64>::new(0.0, 1.0).unwrap();
    // random points (with repeats on one pixel) at two scales
    let pts: Vec<Vec<Point>> = (0..2)
        .map(|_| {
            (0..150)
                .map(|_| {
                    let y = (u.sample(&mut rng).abs() * 1e6) as usize % ny;
                    let x = (u.sample(&mut rng).abs() * 1e6) as usize % nx;
                    Point {
                        x: x as u32,
                        y: y as u32,
                        m: u.sample(&mut rng).exp(),
                        arg: 0.0,
                    }
                })
                .collect()
        })
        .collect();
    for periodic in [true, false] {
        let max_dx = 15.0;
        let cfg = CorrelationConfig {
            scales: vec![1.5, 3.0],
            pairs: vec![(0, 1), (1, 1)],
            periodic,
            margin: Some(0),
            bins_per_octave: 4,
            max_dx: Some(max_dx),
            ..Default::default()
        };
        let plan = CorrelationPlan::new(ny, nx, &cfg).unwrap();
        let refs: Vec<&[Point]> = pts.iter().map(|v| v.as_slice()).collect();
        let r = correlation_estimates(&wtmmm_correlation(&refs, &plan, "x").unwrap()).unwrap();
        let nbins = bin_of(max_dx, 4) + 1;
        for (p, &(s1, s2)) in cfg.pairs.iter().enumerate() {
            let cen = |s: usize| -> Vec<(usize, usize, f64)> {
                let m = pts[s].iter().map(|q| q.m.ln()).sum::<f64>() / pts[s].len() as f64;
                pts[s]
                    .iter()
                    .map(|q| (q.y as usize, q.x as usize, q.m.ln() - m))
                    .collect()
            };
            let mut b = Brute {
                num: vec![0.0; nbins],
                cnt: vec![0.0; nbins],
                lc: vec![0.0; nbins],
            };
            brute_pairs(
                &cen(s1),
                &cen(s2),
                (ny, nx),
                periodic,
                max_dx,
                4,
                nbins,
                &mut b,
            );
            let keep: Vec<usize> = (0..nbins).filter(|&k| b.cnt[k] > 0.0).collect();
            let pc = &r.pairs[p];
            // f32 FFT bound of the values; pair counts are rounded per lag
            let (fy, fx) = plan.fft_shape();
            let lags = lags_per_bin(max_dx, 4, nbins);
            let nw = norm_of(&cen(s1)) * norm_of(&cen(s2));
            assert_eq!(pc.c.len(), keep.len());
            for (o, &k) in keep.iter().enumerate() {
                let tol_c = f32_fft_bound(nw, fy * fx, lags[k]) / b.cnt[k];
                assert!(
                    (pc.pairs[o] - b.cnt[k]).abs() < 1e-6,
                    "periodic={periodic}: {} vs {}",
                    pc.pairs[o],
                    b.cnt[k]
                );
                assert!(
                    (pc.c[o] - b.num[k] / b.cnt[k]).abs() <= tol_c,
                    "periodic={periodic}: {} vs {}",
                    pc.c[o],
                    b.num[k] / b.cnt[k]
                );
            }
        }
    }
}

#[test]
fn energy_magnitude_runs_and_differs_from_ln_m() {
    let img = noise_field(64, 64, 3);
    let base = CorrelationConfig {
        scales: vec![2.0, 4.0],
        pairs: vec![(0, 1)],
        periodic: true,
        ..Default::default()
    };
    let e = CorrelationConfig {
        magnitude: Magnitude::Energy,
        ..base.clone()
    };
    let f = Field::new(img);
    let a = correlation_estimates(
        &cwt_correlation(&f, &CorrelationPlan::new(64, 64, &base).unwrap(), "a").unwrap(),
    )
    .unwrap();
    let b = correlation_estimates(
        &cwt_correlation(&f, &CorrelationPlan::new(64, 64, &e).unwrap(), "a").unwrap(),
    )
    .unwrap();
    assert!(a.pairs[0].c0.is_finite() && b.pairs[0].c0.is_finite());
    // the box average smooths: its variance is smaller
    assert!(b.pairs[0].c0 < a.pairs[0].c0);
}

// ---------------------------------------------------------------- ensembles

/// Kernel cumulants on the maxima lines (the paper's WTMMM set) of 8
/// W-cascades of 512² (tori, gauss, fit 0.5:3.9 octaves), for a law `(m,
/// σ²)` of `ln W`.
fn lines_cumulants(m: f64, sigma2: f64) -> wtmm::stats::kernel::FittedCumulants {
    lines_cumulants_with(m, sigma2, Wavelet::Gauss)
}

fn lines_cumulants_with(
    m: f64,
    sigma2: f64,
    wavelet: Wavelet,
) -> wtmm::stats::kernel::FittedCumulants {
    let model = Model::WCascade(wtmm::synth::wcascade::WCascadeParams {
        law: wtmm::synth::wcascade::Law::LogNormal { m, sigma2 },
        isotropy: wtmm::synth::wcascade::Isotropy::Isotropic,
        basis: wtmm::synth::dwt::Basis::Db8,
    });
    let cfg = AnalysisConfig {
        wavelet,
        octaves: 4,
        margin: Some(0),
        ..Default::default()
    };
    let scales = cfg.scale_list();
    let mut lines: Option<KernelSums> = None;
    for i in 0..8 {
        let field = Field::new(model.synthesize(512, 42, i).unwrap());
        let w = image_wtmmm(&field, &cfg, Parallelism::Scales, true).unwrap();
        let l = KernelSums::from_points(
            &scales,
            KernelConfig::default(),
            WtmmmSet::Lines,
            &w.lines,
            "",
        )
        .unwrap();
        match &mut lines {
            None => lines = Some(l),
            Some(a) => a.merge(&l).unwrap(),
        }
    }
    let opts = KernelOptions {
        fit: (0.5, 3.9),
        refs: vec![2.0],
        pairs: vec![(1.0, 3.0)],
    };
    kernel_estimates(lines.as_ref().unwrap(), &opts)
        .unwrap()
        .cumulants
}

/// The known-answer control of the kernel: a monofractal W-cascade
/// (σ² = 0: c1 = m/ln2, c2 = c3 = 0, II eq 56). Tolerance: 3 jackknife
/// standard errors over the images, nothing else (the selection of the
/// WTMMM on lines and the linking add no bias; measured on 32 x 1024²:
/// c1 = -0.380 ± 0.002, c2 = 0.002 ± 0.001).
#[test]
fn kernel_monofractal_control() {
    let c = lines_cumulants(-0.38 * LN_2, 0.0);
    eprintln!("monofractal {c:?}");
    assert!(
        (c.c1.value + 0.38).abs() < 3.0 * c.c1.stderr,
        "c1 {:?}",
        c.c1
    );
    assert!(c.c2.value.abs() < 3.0 * c.c2.stderr, "c2 {:?}", c.c2);
    assert!(c.c3.value.abs() < 3.0 * c.c3.stderr, "c3 {:?}", c.c3);
}

/// The paper's log-normal W-cascade (c1 = -0.38, c2 = 0.030, c3 = 0).
/// c2 is asserted one-sided: detected (> 3 standard errors) and not above
/// theory (+ 3 standard errors); with the gauss wavelet the transform
/// itself carries about 85% of it over this range (measured and explained
/// in the doc of `wtmm::stats::kernel`), so a two-sided check would need an
/// allowance that is not statistical.
#[test]
fn kernel_lognormal_cascade() {
    let c = lines_cumulants(-0.38 * LN_2, 0.03 * LN_2);
    eprintln!("log-normal {c:?}");
    assert!(c.c2.value > 3.0 * c.c2.stderr, "c2 {:?}", c.c2);
    assert!(c.c2.value < 0.030 + 3.0 * c.c2.stderr, "c2 {:?}", c.c2);
    assert!(c.c3.value.abs() < 3.0 * c.c3.stderr, "c3 {:?}", c.c3);
    assert!(
        (c.c1.value + 0.38).abs() < 3.0 * c.c1.stderr,
        "c1 {:?}",
        c.c1
    );
}

/// The same cascade with the mexican wavelet (three vanishing moments: the
/// coarse levels above a leak in far less, README "Self-similarity kernel"),
/// where c2 is asserted two-sided against the theory, 3 jackknife standard
/// errors and nothing else: a halving of c2 by the linking (SPEC §14) or a
/// wrong log base would fail here.
#[test]
fn kernel_lognormal_cascade_mexican_two_sided() {
    let c = lines_cumulants_with(-0.38 * LN_2, 0.03 * LN_2, Wavelet::Mexican);
    eprintln!("log-normal, mexican {c:?}");
    // c1 = -h(0) is not asserted here: mexican lines die faster at large
    // scales, which moves h(0) (README, "Why mexican lines die")
    assert!(
        (c.c2.value - 0.030).abs() < 3.0 * c.c2.stderr,
        "c2 {:?}",
        c.c2
    );
    assert!(c.c3.value.abs() < 3.0 * c.c3.stderr, "c3 {:?}", c.c3);
}

/// II eq 76 on the log-normal W-cascade, `C(Δx) = σ² (log2(L/Δx) - 2 +
/// 2Δx/L)` with σ² = Var(ln W), L the image side: the ensemble-centred
/// correlation of ln M on 32 tori of 256², mexican wavelet (the gauss
/// wavelet's coarse-level leak pulls C below eq 76 at these lags, README
/// "Self-similarity kernel and space-scale correlations"), at every lag
/// bin of the paper's window (8.3 sup(a1, a2) < Δx < L/4), within 3
/// jackknife standard errors. A σ² in log2 units would put C 1.44 times
/// higher, 4-5 standard errors off at the smallest lags.
#[test]
fn lognormal_magnitudes_follow_eq_76() {
    let model = Model::preset("paper-lognormal").unwrap().model;
    let n = 256;
    let plan = torus_plan_1_5_and_3(n, Wavelet::Mexican);
    let mut acc: Option<CorrelationSums> = None;
    for i in 0..32 {
        let img = model.synthesize(n, 1, i).unwrap();
        let s = cwt_correlation(&Field::new(img), &plan, format!("{i}")).unwrap();
        match &mut acc {
            None => acc = Some(s),
            Some(a) => a.merge(&s).unwrap(),
        }
    }
    assert_on_eq_76(&acc.unwrap(), &model, n, "CWT");
}

/// The torus plan of the eq 76 checks: scales 1.5 and 3 px, pairs (3, 3)
/// and (1.5, 3).
fn torus_plan_1_5_and_3(n: usize, wavelet: Wavelet) -> CorrelationPlan {
    let cfg = CorrelationConfig {
        wavelet,
        scales: vec![1.5, 3.0],
        pairs: vec![(1, 1), (0, 1)],
        periodic: true,
        ..Default::default()
    };
    CorrelationPlan::new(n, n, &cfg).unwrap()
}

/// Every lag bin of the paper's window (8.3 sup(a1, a2) < Δx < L/4) of the
/// ensemble-centred correlation within 3 jackknife standard errors of II
/// eq 76, and at least 8 such bins.
fn assert_on_eq_76(sums: &CorrelationSums, model: &Model, n: usize, what: &str) {
    let r = correlation_estimates(sums).unwrap();
    json_round_trip(&r);
    let l = n as f64;
    let mut bins = 0;
    for p in &r.pairs {
        let lo = 13.0 / 1.5703 * p.a1.max(p.a2);
        for (o, &dx) in p.dx.iter().enumerate() {
            if dx <= lo || dx >= l / 4.0 {
                continue;
            }
            let t = model.magnitude_correlation(dx, l).unwrap();
            let (c, se) = (p.c_ensemble[o], p.c_ensemble_stderr[o]);
            assert!(
                (c - t).abs() < 3.0 * se,
                "{what} ({}, {}) dx {dx:.1}: C = {c:.4} +- {se:.4}, eq 76 {t:.4}",
                p.a1,
                p.a2
            );
            bins += 1;
        }
    }
    assert!(bins >= 8, "{what}: only {bins} lag bins in the window");
}

/// The ground truth behind the test above: the generator's own
/// log-amplitudes `ln d` (constant over each cell of the levels of 2 and
/// 4 px cells, as `validate` maps the scales 1.5 and 3 px), through the
/// same plan, follow II eq 76 within 3 jackknife standard errors at every
/// lag bin of the paper's window, with no wavelet in between (measured:
/// 0.001-0.002 above it, one standard error). Eq 74 counts the common
/// ancestors of tree positions along x; the direction average differs
/// from it by less than 0.002 at these lags (README), inside these errors.
#[test]
fn own_cascade_magnitudes_follow_eq_76() {
    let pre = Model::preset("paper-lognormal").unwrap().model;
    let Model::WCascade(params) = pre else {
        panic!("a W-cascade preset")
    };
    let n = 256;
    // (the wavelet is unused: the fields are given)
    let plan = torus_plan_1_5_and_3(n, Wavelet::Gauss);
    let mut acc: Option<CorrelationSums> = None;
    for i in 0..32 {
        let levels = wtmm::synth::wcascade::wcascade_moduli(&params, n, 1, i).unwrap();
        let top = levels.len();
        // cells of 2^side px: level top - side
        let fields: Vec<Array2<f64>> = [1usize, 2]
            .iter()
            .map(|&side| {
                let lev = &levels[top - side];
                Array2::from_shape_fn((n, n), |(y, x)| lev[[y >> side, x >> side]].ln())
            })
            .collect();
        let s = field_correlation(&fields, &plan, "own", format!("{i}")).unwrap();
        match &mut acc {
            None => acc = Some(s),
            Some(a) => a.merge(&s).unwrap(),
        }
    }
    assert_on_eq_76(&acc.unwrap(), &pre, n, "own cascade");
}

/// In-place 2D FFT (inverse when `inv`) of an `n x n` row-major array.
fn fft2(buf: &mut [num_complex::Complex64], n: usize, inv: bool) {
    let mut planner = rustfft::FftPlanner::<f64>::new();
    let f = if inv {
        planner.plan_fft_inverse(n)
    } else {
        planner.plan_fft_forward(n)
    };
    f.process(buf);
    let mut t = vec![num_complex::Complex64::default(); n * n];
    for y in 0..n {
        for x in 0..n {
            t[x * n + y] = buf[y * n + x];
        }
    }
    f.process(&mut t);
    for y in 0..n {
        for x in 0..n {
            buf[y * n + x] = t[x * n + y];
        }
    }
}

/// A stationary Gaussian field with the fBm spectrum `|k|^-(2H+2)` (H =
/// 1/3, k = 0 removed) on the `n x n` torus, by Fourier filtering of white
/// noise, so that its spectrum is exactly the filter's; and the gauss CWT
/// of it is a Gaussian 4-vector `T = (T1, T2)` at two points whose
/// covariance is the library's filter `a k_i exp(-a²|k|²/2)` (derivative
/// factors zero at Nyquist) times that spectrum. At one point the two
/// components are independent with equal variances (the square torus's
/// symmetries), so with `X = T(a1, x)/σ1`, `Y = T(a2, x + Δx)/σ2` standard
/// and `R` their cross-correlation matrix, Mehler's expansion of `ln|X|`
/// (even: only even chaoses) gives
///
/// `Cov(ln|X|, ln|Y|) = ‖R‖_F²/8 + r`, `|r| <= ‖R‖_op⁴ (π²/24 - 1/4)`:
///
/// the second chaos of `ln|X|` is `(|X|² - 2)/4` (`E[ln E (E - 1)] = 1`
/// for `E = |X|²/2 ~ Exp(1)`), whose cross moment is `Σ 2 R_ij² / 16`, and
/// the chaoses n >= 4 are bounded by `‖R‖_op^n` times their norms, which
/// sum to `Var ln|X| - 1/4 = π²/24 - 1/4`. Per-image centring on the torus
/// makes the expectation `C(Δx) - C̄` with `C̄` the mean of C over all
/// lags (bounded the same way, lag 0 included).
///
/// Every lag bin of the per-image-centred C of the three pairs of scales
/// (1.5, 1.5), (1.5, 3), (3, 3) must lie within 4 jackknife standard
/// errors (10 images) plus the bin's bound on r and on `C̄` of the
/// bin-averaged prediction. Measured: agreement at every bin; between
/// about 8 and 30 px all three pairs lie below the prediction by 1-3
/// standard errors on these 10 images (e.g. (1.5, 3) at 11.4 px: 0.0070 ±
/// 0.0009 against 0.0101 ± 0.0011), a sample fluctuation shared by the
/// correlated bins (the lowest modes carry much of the covariance there):
/// with `IMAGES=60` the same bin reads 0.0095 ± 0.0004 against 0.0101 ±
/// 0.0011, and every bin up to L/4 lies within 1.5 errors of the
/// prediction plus its bound. (Before: an fBm from the generator, `C > 0.05`
/// at the smallest lag and `|C| < 0.005 + 3 se` beyond `8.3 sup(a1, a2)`,
/// both bare numbers.)
#[test]
fn fbm_magnitudes_decorrelate() {
    use num_complex::Complex64;
    let (n, hurst) = (256usize, 1.0 / 3.0);
    // IMAGES=K: the same check on more images (an experiment)
    let images: u64 = std::env::var("IMAGES").map_or(10, |s| s.parse().unwrap());
    let scales = [1.5, 3.0];
    let cfg = CorrelationConfig {
        scales: scales.to_vec(),
        pairs: vec![(0, 0), (0, 1), (1, 1)],
        periodic: true,
        ..Default::default()
    };
    let plan = CorrelationPlan::new(n, n, &cfg).unwrap();
    let freq = |m: usize| {
        2.0 * PI
            * (if m <= n / 2 {
                m as f64
            } else {
                m as f64 - n as f64
            })
            / n as f64
    };
    let dfreq = |m: usize| if m == n / 2 { 0.0 } else { freq(m) };
    let spec = |ky: usize, kx: usize| -> f64 {
        let k2 = freq(ky).powi(2) + freq(kx).powi(2);
        if k2 == 0.0 {
            0.0
        } else {
            k2.powf(-(hurst + 1.0))
        }
    };
    let mut acc: Option<CorrelationSums> = None;
    for i in 0..images {
        let mut rng = rng_for(777, i);
        let mut buf: Vec<Complex64> = (0..n * n)
            .map(|_| Complex64::new(StdNormalF.sample(&mut rng), 0.0))
            .collect();
        fft2(&mut buf, n, false);
        for ky in 0..n {
            for kx in 0..n {
                buf[ky * n + kx] *= spec(ky, kx).sqrt();
            }
        }
        fft2(&mut buf, n, true);
        let img = Array2::from_shape_fn((n, n), |(y, x)| buf[y * n + x].re);
        let s = cwt_correlation(&Field::new(img), &plan, format!("{i}")).unwrap();
        match &mut acc {
            None => acc = Some(s),
            Some(a) => a.merge(&s).unwrap(),
        }
    }
    let r = correlation_estimates(&acc.unwrap()).unwrap();
    // covariances of the transform's components: Σ_k S D_i D_j g1 g2 e^(ik.d)
    let gauss = |a: f64, ky: usize, kx: usize| {
        a * (-0.5 * a * a * (freq(ky).powi(2) + freq(kx).powi(2))).exp()
    };
    let cov = |a1: f64, a2: f64, ij: (usize, usize)| -> Vec<f64> {
        let d = |c: usize, ky: usize, kx: usize| if c == 0 { dfreq(kx) } else { dfreq(ky) };
        let mut b: Vec<Complex64> = (0..n * n)
            .map(|q| {
                let (ky, kx) = (q / n, q % n);
                Complex64::new(
                    spec(ky, kx)
                        * d(ij.0, ky, kx)
                        * d(ij.1, ky, kx)
                        * gauss(a1, ky, kx)
                        * gauss(a2, ky, kx),
                    0.0,
                )
            })
            .collect();
        fft2(&mut b, n, true);
        b.iter().map(|z| z.re).collect()
    };
    let c_rem = PI * PI / 24.0 - 0.25;
    let mut tested = 0;
    for p in &r.pairs {
        let (a1, a2) = (p.a1, p.a2);
        let v1 = cov(a1, a1, (0, 0))[0];
        let v2 = cov(a2, a2, (0, 0))[0];
        let norm = (v1 * v2).sqrt();
        let (c11, c22, c12) = (
            cov(a1, a2, (0, 0)),
            cov(a1, a2, (1, 1)),
            cov(a1, a2, (0, 1)),
        );
        // lead and remainder bound per lag (index y * n + x)
        let (lead, rem): (Vec<f64>, Vec<f64>) = (0..n * n)
            .map(|q| {
                let (r11, r22, r12) = (c11[q] / norm, c22[q] / norm, c12[q] / norm);
                let fro2 = r11 * r11 + r22 * r22 + 2.0 * r12 * r12;
                let op = 0.5 * (r11 + r22).abs() + (0.25 * (r11 - r22).powi(2) + r12 * r12).sqrt();
                (fro2 / 8.0, c_rem * op.powi(4))
            })
            .unzip();
        let cbar = lead.iter().sum::<f64>() / (n * n) as f64;
        let cbar_err = rem.iter().sum::<f64>() / (n * n) as f64;
        let max_dx = n as f64 / 2.0;
        let nb = (cfg.bins_per_octave as f64 * max_dx.log2() + 0.5).floor() as usize + 1;
        let (mut sl, mut sr, mut cnt) = (vec![0.0; nb], vec![0.0; nb], vec![0.0; nb]);
        for sy in -(n as i64 / 2)..=(n as i64 / 2 - 1) {
            for sx in -(n as i64 / 2)..=(n as i64 / 2 - 1) {
                let rr = ((sy * sy + sx * sx) as f64).sqrt();
                if rr == 0.0 || rr > max_dx {
                    continue;
                }
                let b = bin_of(rr, cfg.bins_per_octave).min(nb - 1);
                let q = sy.rem_euclid(n as i64) as usize * n + sx.rem_euclid(n as i64) as usize;
                sl[b] += lead[q];
                sr[b] += rem[q];
                cnt[b] += 1.0;
            }
        }
        // the reported bins are the non-empty ones
        let keep: Vec<usize> = (0..nb).filter(|&b| cnt[b] > 0.0).collect();
        assert_eq!(keep.len(), p.dx.len());
        for (o, &b) in keep.iter().enumerate() {
            assert_eq!(
                cnt[b] * (images as usize * n * n) as f64,
                p.pairs[o],
                "bin {o}: lags"
            );
            let (sl, sr, cnt) = (sl[b], sr[b], cnt[b]);
            let want = sl / cnt - cbar;
            let bound = sr / cnt + cbar_err;
            let (c, se) = (p.c[o], p.c_stderr[o]);
            println!(
                "({a1}, {a2}) dx {:.1}: C = {c:.5} +- {se:.5}, Gaussian {want:.5} +- {bound:.5}",
                p.dx[o]
            );
            assert!(
                (c - want).abs() < 4.0 * se + bound,
                "({a1}, {a2}) dx {:.1}: C = {c} +- {se}, Gaussian prediction {want} +- {bound}",
                p.dx[o]
            );
            tested += 1;
        }
    }
    assert!(tested >= 30, "{tested} bins");
}

/// Diagnostic behind the kernel's bias analysis (not a check): cumulants
/// of ln M per scale for both WTMMM sets. Environment: PRESET, SIZE, N,
/// MARGIN, RATIO (lo:hi), SIGMA2 and M (a log-normal W-cascade, m in units
/// of ln 2).
#[test]
#[ignore]
#[allow(clippy::needless_range_loop)]
fn experiment_kappa_per_scale() {
    let mut model = Model::preset(&std::env::var("PRESET").unwrap_or("paper-lognormal".into()))
        .unwrap()
        .model;
    if let Ok(s2) = std::env::var("SIGMA2") {
        model = Model::WCascade(wtmm::synth::wcascade::WCascadeParams {
            law: wtmm::synth::wcascade::Law::LogNormal {
                m: std::env::var("M")
                    .map(|v| v.parse::<f64>().unwrap())
                    .unwrap_or(-0.38)
                    * LN_2,
                sigma2: s2.parse().unwrap(),
            },
            isotropy: wtmm::synth::wcascade::Isotropy::Isotropic,
            basis: wtmm::synth::dwt::Basis::Db8,
        });
    }
    let size: usize = std::env::var("SIZE")
        .map(|s| s.parse().unwrap())
        .unwrap_or(512);
    let n: u64 = std::env::var("N").map(|s| s.parse().unwrap()).unwrap_or(4);
    let margin: usize = std::env::var("MARGIN")
        .map(|s| s.parse().unwrap())
        .unwrap_or(0);
    let mut cfg = AnalysisConfig {
        octaves: 5,
        margin: Some(margin),
        ..Default::default()
    };
    if let Ok(r) = std::env::var("RATIO") {
        let v: Vec<f64> = r.split(':').map(|x| x.parse().unwrap()).collect();
        cfg.link.ratio = (v[0], v[1]);
    }
    let scales = cfg.scale_list();
    let mut acc: [Option<KernelSums>; 2] = [None, None];
    for i in 0..n {
        let img = model.synthesize(size, 42, i).unwrap();
        let w = image_wtmmm(&Field::new(img), &cfg, Parallelism::Scales, true).unwrap();
        for (k, set) in [WtmmmSet::All, WtmmmSet::Lines].into_iter().enumerate() {
            let s = KernelSums::from_points(&scales, KernelConfig::default(), set, w.set(set), "")
                .unwrap();
            match &mut acc[k] {
                None => acc[k] = Some(s),
                Some(a) => a.merge(&s).unwrap(),
            }
        }
    }
    for k in 0..2 {
        let s = acc[k].as_ref().unwrap();
        let r = kernel_estimates(
            s,
            &KernelOptions {
                fit: (0.0, 4.0),
                ..Default::default()
            },
        )
        .unwrap();
        println!("set {:?}: c = {:?}", r.set, r.cumulants);
        for j in 0..scales.len() {
            println!(
                "  a {:7.3} n {:8} k1 {:8.4} k2 {:8.4} k3 {:8.4}",
                scales[j], r.n_wtmmm[j], r.kappa1[j], r.kappa2[j], r.kappa3[j]
            );
        }
    }
}

/// Diagnostic: the same over every other pixel of the CWT grid (no WTMMM
/// selection). Environment: SIGMA2 (default 0.03 ln 2, paper-lognormal),
/// M, SIZE, N.
#[test]
#[ignore]
#[allow(clippy::needless_range_loop)]
fn experiment_kappa_cwt_grid() {
    let s2: f64 = std::env::var("SIGMA2")
        .map(|v| v.parse::<f64>().unwrap())
        .unwrap_or(0.03 * LN_2);
    let m: f64 = std::env::var("M")
        .map(|v| v.parse::<f64>().unwrap())
        .unwrap_or(-0.38)
        * LN_2;
    let model = Model::WCascade(wtmm::synth::wcascade::WCascadeParams {
        law: wtmm::synth::wcascade::Law::LogNormal { m, sigma2: s2 },
        isotropy: wtmm::synth::wcascade::Isotropy::Isotropic,
        basis: wtmm::synth::dwt::Basis::Db8,
    });
    let size: usize = std::env::var("SIZE")
        .map(|s| s.parse().unwrap())
        .unwrap_or(512);
    let n: u64 = std::env::var("N").map(|s| s.parse().unwrap()).unwrap_or(4);
    let scales: Vec<f64> = (0..=8).map(|k| 1.5 * 2f64.powf(k as f64 / 2.0)).collect();
    let mut acc: Option<KernelSums> = None;
    for i in 0..n {
        let img = model.synthesize(size, 42, i).unwrap();
        let plan = CwtPlan::new(size, size, Wavelet::Gauss, &scales).unwrap();
        let mut vals = vec![Vec::new(); scales.len()];
        plan.for_each_scale(img.view(), |j, _, t| {
            for y in (0..size).step_by(2) {
                for x in (0..size).step_by(2) {
                    vals[j].push(modulus(t[[y, x]]).ln());
                }
            }
        })
        .unwrap();
        let s = KernelSums::from_ln_m(&scales, KernelConfig::default(), WtmmmSet::All, &vals, "")
            .unwrap();
        match &mut acc {
            None => acc = Some(s),
            Some(a) => a.merge(&s).unwrap(),
        }
    }
    let r = kernel_estimates(
        acc.as_ref().unwrap(),
        &KernelOptions {
            fit: (0.0, 4.0),
            refs: vec![2.0],
            pairs: vec![(1.0, 3.0)],
        },
    )
    .unwrap();
    println!("CWT grid: c = {:?}", r.cumulants);
    for j in 0..scales.len() {
        println!(
            "  a {:7.3} k1 {:8.4} k2 {:8.4} k3 {:8.4}",
            scales[j], r.kappa1[j], r.kappa2[j], r.kappa3[j]
        );
    }
}

/// Diagnostic behind the README's explanation of the low gauss c2 (not a
/// check): how much of each ancestor's multiplier reaches `ln M(x, a)` on
/// the CWT grid. Per scale, `ln M` over every pixel is regressed on the
/// `ln W` of the pixel's ancestors at levels 1 .. N-1 (plus an intercept);
/// the coefficient `b_i` is 1 for a multiplier fully transmitted. The
/// variance explained by the cascade, `σ² Σ b_i²`, grows by `σ²` per octave
/// only if the top multiplier's `b` is 1. Environment: WAVELET
/// (gauss|mexican), LAW (lognormal|logpoisson), SIZE, N.
#[test]
#[ignore]
#[allow(clippy::needless_range_loop)]
fn experiment_ancestor_transmission() {
    use wtmm::synth::wcascade::{WCascadeParams, wcascade, wcascade_moduli};
    let wavelet = match std::env::var("WAVELET").as_deref() {
        Ok("mexican") => Wavelet::Mexican,
        _ => Wavelet::Gauss,
    };
    let preset = match std::env::var("LAW").as_deref() {
        Ok("logpoisson") => "paper-logpoisson",
        _ => "paper-lognormal",
    };
    let model = Model::preset(preset).unwrap().model;
    let Model::WCascade(params) = model else {
        panic!("a W-cascade preset")
    };
    let params: WCascadeParams = params;
    // σ² = Var(ln W) = c2 ln 2
    let sigma2 = model.cumulants().unwrap()[1] * LN_2;
    let size: usize = std::env::var("SIZE")
        .map(|s| s.parse().unwrap())
        .unwrap_or(1024);
    let n: u64 = std::env::var("N").map(|s| s.parse().unwrap()).unwrap_or(8);
    let steps = size.trailing_zeros() as usize;
    let p = steps; // intercept + steps - 1 multipliers
    let scales: Vec<f64> = (0..=10).map(|k| 1.5 * 2f64.powf(k as f64 / 2.0)).collect();
    let plan = CwtPlan::new(size, size, wavelet, &scales).unwrap();
    let mut xtx = vec![vec![0.0; p * p]; scales.len()];
    let mut xty = vec![vec![0.0; p]; scales.len()];
    let mut yty = vec![0.0; scales.len()];
    for i in 0..n {
        let lv = wcascade_moduli(&params, size, 1, i).unwrap();
        let img = wcascade(&params, size, 1, i).unwrap();
        // regressors per pixel: 1, then ln(d_s / d_parent) of the pixel's cell, s = 1..N-1
        let mut xs = vec![0.0; size * size * p];
        for y in 0..size {
            for x in 0..size {
                let r = &mut xs[(y * size + x) * p..(y * size + x + 1) * p];
                r[0] = 1.0;
                for s in 1..steps {
                    let sh = steps - s;
                    r[s] = (lv[s][[y >> sh, x >> sh]] / lv[s - 1][[y >> (sh + 1), x >> (sh + 1)]])
                        .ln();
                }
            }
        }
        plan.for_each_scale(img.view(), |j, _, t| {
            for y in 0..size {
                for x in 0..size {
                    let r = &xs[(y * size + x) * p..(y * size + x + 1) * p];
                    let v = modulus(t[[y, x]]).ln();
                    for u in 0..p {
                        xty[j][u] += r[u] * v;
                        for w in 0..p {
                            xtx[j][u * p + w] += r[u] * r[w];
                        }
                    }
                    yty[j] += v * v;
                }
            }
        })
        .unwrap();
    }
    let mut explained = Vec::new();
    let mut total = Vec::new();
    for j in 0..scales.len() {
        // normal equations by Gaussian elimination with partial pivoting
        let mut a: Vec<Vec<f64>> = (0..p)
            .map(|r| {
                let mut row = xtx[j][r * p..(r + 1) * p].to_vec();
                row.push(xty[j][r]);
                row
            })
            .collect();
        for c in 0..p {
            let piv = (c..p)
                .max_by(|&u, &v| a[u][c].abs().total_cmp(&a[v][c].abs()))
                .unwrap();
            a.swap(c, piv);
            for r in 0..p {
                if r != c {
                    let f = a[r][c] / a[c][c];
                    for k in c..=p {
                        a[r][k] -= f * a[c][k];
                    }
                }
            }
        }
        let b: Vec<f64> = (0..p).map(|r| a[r][p] / a[r][r]).collect();
        let cnt = xtx[j][0];
        let mean = xty[j][0] / cnt;
        total.push(yty[j] / cnt - mean * mean);
        explained.push(sigma2 * b[1..].iter().map(|v| v * v).sum::<f64>());
        println!(
            "a {:6.2}  var {:.4}  cascade part {:.4}  b(level 1..{}) {}",
            scales[j],
            total[j],
            explained[j],
            steps - 1,
            b[1..]
                .iter()
                .map(|v| format!("{v:5.2}"))
                .collect::<Vec<_>>()
                .join(" ")
        );
    }
    // slopes over octaves 0.5..4 (scale indices 1..=8)
    let fit = |v: &[f64]| {
        let x: Vec<f64> = scales[1..=8].iter().map(|a| a.ln()).collect();
        -wtmm::stats::fit::line_fit(&x, &v[1..=8]).unwrap().slope
    };
    println!(
        "-d/d ln a over octaves 0.5-4: var(ln M) {:.4}, cascade part {:.4} (sigma^2/ln2 = {:.4})",
        fit(&total),
        fit(&explained),
        sigma2 / LN_2
    );
}

/// The energy magnitude's default margin covers its box as well as the
/// wavelet: the domain's values do not depend on what lies beyond the
/// image border. The same field, alone (zero padding beyond its border)
/// and at the centre of a larger field with the same domain, must give
/// the same magnitudes up to the wavelet's truncated tail. The domain is
/// an 8 px wide square, so that every point is near its edge. The wavelet's
/// tail beyond its 3.2 a support (1.7 % of its L1 weight) still moves the
/// mean ln M by 6e-4 at a = 6 px; without the box in the margin it moved
/// by 4.5e-3.
#[test]
fn energy_margin_keeps_the_box_inside_the_image() {
    let cfg = CorrelationConfig {
        scales: vec![2.0, 6.0],
        pairs: vec![(0, 1)],
        periodic: false,
        magnitude: Magnitude::Energy,
        ..Default::default()
    };
    let m = CorrelationPlan::new(256, 256, &cfg).unwrap().domain().0;
    let (n, pad) = (2 * m + 8, 32);
    let big = noise_field(n + 2 * pad, n + 2 * pad, 11);
    let small = big
        .slice(ndarray::s![pad..pad + n, pad..pad + n])
        .to_owned();
    let plan = CorrelationPlan::new(n, n, &cfg).unwrap();
    assert_eq!(plan.domain(), (m, m + 8, m, m + 8));
    let cfg_big = CorrelationConfig {
        margin: Some(m + pad),
        ..cfg.clone()
    };
    let plan_big = CorrelationPlan::new(n + 2 * pad, n + 2 * pad, &cfg_big).unwrap();
    let a = cwt_correlation(&Field::new(small), &plan, "alone").unwrap();
    let b = cwt_correlation(&Field::new(big), &plan_big, "embedded").unwrap();
    let (ia, ib) = (&a.images[0], &b.images[0]);
    assert_eq!(ia.n, ib.n);
    for s in 0..2 {
        let d = (ia.mean[s] - ib.mean[s]).abs();
        assert!(
            d < 1e-3,
            "scale {}: mean ln M {} alone, {} embedded",
            cfg.scales[s],
            ia.mean[s],
            ib.mean[s]
        );
    }
}

/// Correlation sums merge only with sums of the same settings: the
/// wavelet, eps and margin included (they change the magnitudes).
#[test]
fn correlation_sums_merge_only_like_with_like() {
    let img = Field::new(noise_field(64, 64, 5));
    let base = CorrelationConfig {
        scales: vec![2.0, 4.0],
        pairs: vec![(0, 1)],
        periodic: false,
        margin: Some(16),
        ..Default::default()
    };
    let sums = |cfg: &CorrelationConfig| {
        cwt_correlation(&img, &CorrelationPlan::new(64, 64, cfg).unwrap(), "x").unwrap()
    };
    let mut a = sums(&base);
    a.merge(&sums(&base)).unwrap();
    assert_eq!(a.images.len(), 2);
    for other in [
        CorrelationConfig {
            wavelet: Wavelet::Mexican,
            ..base.clone()
        },
        CorrelationConfig {
            eps: base.eps * 10.0,
            ..base.clone()
        },
        CorrelationConfig {
            margin: Some(20),
            ..base.clone()
        },
    ] {
        let e = a.merge(&sums(&other)).unwrap_err().to_string();
        assert!(e.contains("different settings"), "{e}");
    }
    assert_eq!(a.images.len(), 2);
}

/// `validate` takes the kernel from the spectra's skeleton cut to the fit
/// range: that must be the WTMMM and lines a skeleton over the cut grid
/// alone gives (linking runs from the smallest scale up and looks no
/// further), on the torus and on an interior domain alike.
#[test]
fn a_skeleton_cut_to_its_first_scales_is_the_skeleton_of_those_scales() {
    let model = Model::WCascade(wtmm::synth::wcascade::WCascadeParams {
        law: wtmm::synth::wcascade::Law::LogNormal {
            m: -0.38 * LN_2,
            sigma2: 0.03 * LN_2,
        },
        isotropy: wtmm::synth::wcascade::Isotropy::Isotropic,
        basis: wtmm::synth::dwt::Basis::Db8,
    });
    let field = Field::new(model.synthesize(256, 7, 0).unwrap());
    for margin in [Some(0), None] {
        let full = AnalysisConfig {
            octaves: 4,
            margin,
            ..Default::default()
        };
        let grid = full.scale_list();
        // one scale (no line links beyond it), two, two octaves of 10 voices
        for (n, link) in [1, 2, 21].into_iter().flat_map(|n| [(n, true), (n, false)]) {
            // the cut analysis keeps the full grid's margin, as validate does
            let cut = AnalysisConfig {
                scales: Some(grid[..n].to_vec()),
                margin: Some(full.margin_px()),
                ..full.clone()
            };
            let alone = image_wtmmm(&field, &cut, Parallelism::Serial, link).unwrap();
            let (sk, all) =
                wtmm::skeleton::skeleton_and_wtmmm(&field, &full, Parallelism::Scales, n, link)
                    .unwrap();
            assert_eq!(sk.scales.len(), grid.len());
            let from_full = wtmm::stats::pdf::ImageWtmmm::from_skeleton(&sk, all);
            assert_eq!(from_full.scales.len(), n);
            assert!(alone.all.iter().all(|s| !s.is_empty()));
            // a single scale holds no line (none links beyond a_min)
            assert_eq!(alone.lines.iter().all(|s| !s.is_empty()), link && n > 1);
            assert_eq!(
                alone, from_full,
                "margin {margin:?}, {n} scales, link {link}"
            );
        }
    }
}

/// Per lone image: its kernel cumulants with the tiles' jackknife error,
/// and the regression's; 3 octaves for 256^2 images, 5 otherwise.
fn lone_image_cumulants(
    model: &Model,
    size: usize,
    seed: u64,
    n: u64,
) -> Vec<[(f64, f64, f64); 3]> {
    use rayon::prelude::*;
    let periodic = !matches!(model, Model::Fbm(_));
    let cfg = AnalysisConfig {
        octaves: if size <= 256 { 3 } else { 5 },
        ..AnalysisConfig::for_field(periodic)
    };
    let scales = cfg.scale_list();
    let side = wtmm::spectra::default_tile_side(&cfg, size, size);
    let fit = (0.5, if size <= 256 { 3.0 } else { 4.0 });
    (0..n)
        .into_par_iter()
        .map(|i| {
            let field = Field::new(model.synthesize(size, seed, i).unwrap());
            let w = image_wtmmm(&field, &cfg, Parallelism::Serial, true).unwrap();
            let est = |side: usize| {
                let s = KernelSums::from_points_tiled(
                    &scales,
                    KernelConfig::default(),
                    WtmmmSet::Lines,
                    &w.lines,
                    "",
                    w.domain,
                    side,
                )
                .unwrap();
                let o = KernelOptions {
                    fit,
                    refs: vec![],
                    pairs: vec![],
                };
                kernel_estimates(&s, &o).unwrap().cumulants
            };
            let (reg, tiles) = (est(0), est(side));
            [
                (tiles.c1.value, tiles.c1.stderr, reg.c1.stderr),
                (tiles.c2.value, tiles.c2.stderr, reg.c2.stderr),
                (tiles.c3.value, tiles.c3.stderr, reg.c3.stderr),
            ]
        })
        .collect()
}

/// (scatter of c_n between the images, rms tiles' error, rms regression
/// error) for n = 1, 2, 3.
fn lone_image_error_ratios(per: &[[(f64, f64, f64); 3]]) -> [(f64, f64, f64); 3] {
    let n = per.len() as f64;
    std::array::from_fn(|k| {
        let v: Vec<f64> = per.iter().map(|p| p[k].0).collect();
        let m = v.iter().sum::<f64>() / n;
        let sd = (v.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / (n - 1.0)).sqrt();
        let rms = |f: &dyn Fn(&(f64, f64, f64)) -> f64| {
            (per.iter().map(|p| f(&p[k]).powi(2)).sum::<f64>() / n).sqrt()
        };
        (sd, rms(&|x| x.1), rms(&|x| x.2))
    })
}

/// Are a lone image's kernel error bars believable? `MODEL=lognormal|fbm
/// N=24 SIZE=512 cargo test --release --test stats
/// experiment_lone_image_kernel_errors -- --ignored --nocapture`.
#[test]
#[ignore]
fn experiment_lone_image_kernel_errors() {
    let env = |k: &str, d: &str| std::env::var(k).unwrap_or_else(|_| d.to_string());
    let n: u64 = env("N", "24").parse().unwrap();
    let size: usize = env("SIZE", "512").parse().unwrap();
    let model = match env("MODEL", "lognormal").as_str() {
        "fbm" => Model::preset("paper-fbm").unwrap().model,
        "lognormal" => Model::preset("paper-lognormal").unwrap().model,
        m => panic!("MODEL {m}"),
    };
    let per = lone_image_cumulants(&model, size, 1, n);
    for (k, (sd, tiles, reg)) in lone_image_error_ratios(&per).iter().enumerate() {
        println!(
            "c{}: scatter {sd:.4}, tiles' error (rms) {tiles:.4} ratio {:.2}, regression's {reg:.4} ratio {:.2}",
            k + 1,
            tiles / sd,
            reg / sd
        );
    }
}

/// A lone image's kernel errors against the truth: 24 paper-lognormal
/// W-cascades of 256^2 (3 octaves, 25 tiles of 45 px each), analysed one
/// by one. The root-mean-square error one image reports for c1, c2, c3
/// must be the scatter of its cumulants between the images within a factor
/// 2 (the scatter is known to about 15 % from 24 images; measured 0.75-1.64
/// on 256^2, 512^2 and 1024^2 log-normal and 1024^2 fBm ensembles,
/// `experiment_lone_image_kernel_errors`), where the regression's error,
/// the only one before, is below half of it (measured 0.16-0.45).
#[test]
fn a_lone_image_reports_believable_kernel_errors() {
    let model = Model::preset("paper-lognormal").unwrap().model;
    let per = lone_image_cumulants(&model, 256, 2, 24);
    for (k, (sd, tiles, reg)) in lone_image_error_ratios(&per).iter().enumerate() {
        eprintln!(
            "c{}: tiles {:.2}, regression {:.2} of the scatter {sd:.4}",
            k + 1,
            tiles / sd,
            reg / sd
        );
        assert!(
            (0.5..2.0).contains(&(tiles / sd)),
            "c{}: {}",
            k + 1,
            tiles / sd
        );
        assert!(reg / sd < 0.5, "c{}: {}", k + 1, reg / sd);
    }
}

/// `ensemble_kernel_sums` is `wtmm kernel`'s recipe in one call: the sums
/// of the hand-wired steps (each field's WTMMM, tiles below 3 fields, the
/// merge) to the bit, in both WTMMM sets; the estimates then carry tile
/// errors; a field with no WTMMM, or no field, is an error that says so.
#[test]
fn ensemble_kernel_sums_is_the_kernel_recipe_in_one_call() {
    let model = Model::preset("paper-lognormal").unwrap().model;
    let cfg = AnalysisConfig {
        octaves: 3,
        ..AnalysisConfig::for_field(true)
    };
    assert_eq!(cfg.wavelet, Wavelet::default());
    let n = 128;
    let fields: Vec<Field> = (0..2)
        .map(|i| Field::new(model.synthesize(n, 5, i).unwrap()))
        .collect();
    let (kcfg, scales) = (KernelConfig::default(), cfg.scale_list());
    let side = wtmm::spectra::default_tile_side(&cfg, n, n);
    for set in [WtmmmSet::Lines, WtmmmSet::All] {
        let got = ensemble_kernel_sums(&fields, &cfg, kcfg, set).unwrap();
        let mut want: Option<KernelSums> = None;
        for (i, f) in fields.iter().enumerate() {
            let w = image_wtmmm(f, &cfg, Parallelism::Serial, true).unwrap();
            let s = KernelSums::from_points_tiled(
                &scales,
                kcfg,
                set,
                w.set(set),
                format!("image {i}"),
                w.domain,
                side,
            )
            .unwrap();
            match want.as_mut() {
                None => want = Some(s),
                Some(x) => x.merge(&s).unwrap(),
            }
        }
        assert_eq!(got, want.unwrap(), "{set:?}");
        assert!(got.images.iter().all(|im| im.tiles.len() >= 2), "{set:?}");
        let k = kernel_estimates(&got, &KernelOptions::for_scales(&scales, (0.5, 3.0))).unwrap();
        assert!(k.stderr_method.contains("tiles"), "{}", k.stderr_method);
        let c = &k.cumulants;
        for e in [c.c1, c.c2, c.c3] {
            assert!(e.stderr.is_finite() && e.stderr > 0.0, "{e:?}");
        }
    }
    let flat = Field::new(Array2::from_elem((n, n), 3.0));
    let e = ensemble_kernel_sums(&[fields[0].clone(), flat], &cfg, kcfg, WtmmmSet::Lines)
        .unwrap_err()
        .to_string();
    assert!(e.contains("image 1") && e.contains("constant"), "{e}");
    let e = ensemble_kernel_sums(&[], &cfg, kcfg, WtmmmSet::Lines)
        .unwrap_err()
        .to_string();
    assert!(e.contains("no field"), "{e}");
}

/// The pdfs' mean of ln M is the WTMMM's own, not the bin centres': `wtmm
/// pdf`'s h0 (the slope of <ln M> against ln a) equals the kernel's -c1 on
/// the same WTMMM (the same regression), where bin centres put it 4e-4 off
/// on the Jacksboro DEM; merges give the same bits in any order; histograms
/// written without the sum fall back to the bin centres; an impossible sum
/// is refused.
#[test]
fn the_pdfs_mean_ln_m_is_exact_and_merges_exactly() {
    let model = Model::preset("paper-lognormal").unwrap().model;
    let cfg = AnalysisConfig {
        octaves: 3,
        ..AnalysisConfig::for_field(true)
    };
    let scales = cfg.scale_list();
    let fit = (0.5, 3.0);
    let fields: Vec<Field> = (0..3)
        .map(|i| Field::new(model.synthesize(128, 9, i).unwrap()))
        .collect();
    let parts: Vec<WtmmmHistograms> = fields
        .iter()
        .map(|f| {
            let w = image_wtmmm(f, &cfg, Parallelism::Serial, true).unwrap();
            // the exact mean of one image at every scale
            let h = WtmmmHistograms::from_points(&scales, PdfConfig::default(), &w.lines).unwrap();
            for (j, pts) in w.lines.iter().enumerate() {
                let exact = pts.iter().map(|p| p.m.ln()).sum::<f64>() / pts.len() as f64;
                assert!((h.mean_ln_m(j) - exact).abs() < 1e-7, "scale {j}");
            }
            h
        })
        .collect();
    let merged = |order: [usize; 3]| {
        let mut h = parts[order[0]].clone();
        h.merge(&parts[order[1]]).unwrap();
        h.merge(&parts[order[2]]).unwrap();
        h
    };
    let (a, b) = (merged([0, 1, 2]), merged([2, 0, 1]));
    assert_eq!(a, b);
    let k = ensemble_kernel_sums(&fields, &cfg, KernelConfig::default(), WtmmmSet::Lines).unwrap();
    let c1 = kernel_estimates(&k, &KernelOptions::for_scales(&scales, fit))
        .unwrap()
        .cumulants
        .c1
        .value;
    let h0 = a.h0(fit, WtmmmSet::Lines).unwrap();
    assert!((h0 + c1).abs() < 1e-6, "h0 {h0}, c1 {c1}");
    // older histograms (no sum): the bin centres, within half a bin
    let mut v = serde_json::to_value(&a).unwrap();
    for h in v["hist"].as_array_mut().unwrap() {
        h.as_object_mut().unwrap().remove("sum_ln_m");
    }
    let old: WtmmmHistograms = serde_json::from_value(v).unwrap();
    let d = PdfConfig::default().dlnm;
    for j in 0..scales.len() {
        assert!(old.hist[j].sum_ln_m.is_none());
        let (e, o) = (a.mean_ln_m(j), old.mean_ln_m(j));
        assert!(e != o && (e - o).abs() <= d / 2.0, "scale {j}: {e} {o}");
    }
    // merging an old shard drops the sum (the mean of both is binned)
    let mut mixed = parts[0].clone();
    mixed.merge(&old).unwrap();
    assert!(mixed.hist.iter().all(|h| h.sum_ln_m.is_none()));
    // except at a scale where the old shard is empty: its sum is 0, in
    // either order of the merge (an independent review's probe)
    let pts = |m: &[f64]| -> Vec<Vec<Point>> {
        m.iter()
            .map(|&m| {
                vec![Point {
                    x: 0,
                    y: 0,
                    m,
                    arg: 0.0,
                }]
            })
            .chain(std::iter::repeat_with(Vec::new))
            .take(2)
            .collect()
    };
    let two = [1.0, 2.0];
    let new = WtmmmHistograms::from_points(&two, PdfConfig::default(), &pts(&[0.4])).unwrap();
    let mut v = serde_json::to_value(
        WtmmmHistograms::from_points(&two, PdfConfig::default(), &pts(&[])).unwrap(),
    )
    .unwrap();
    for h in v["hist"].as_array_mut().unwrap() {
        h.as_object_mut().unwrap().remove("sum_ln_m");
    }
    let old_empty: WtmmmHistograms = serde_json::from_value(v).unwrap();
    let (mut x, mut y) = (new.clone(), old_empty.clone());
    x.merge(&old_empty).unwrap();
    y.merge(&new).unwrap();
    assert_eq!(x, y);
    assert!((x.mean_ln_m(0) - 0.4f64.ln()).abs() < 1e-7);
    let mut bad = a.clone();
    bad.hist[0].sum_ln_m = Some(i64::MAX);
    let e = bad.check().unwrap_err().to_string();
    assert!(e.contains("impossible"), "{e}");
}

/// On an image with missing pixels the WTMMM statistics count the maxima
/// the partition functions count (clear of the holes by the support at
/// the largest scale, at every scale): the pdfs' h0, the kernel's -c1 and
/// the spectra's h(q=0) are one number. (Before, pdf and kernel kept the
/// maxima near the holes that analyze leaves out: on the Jacksboro DEM
/// with two holes, 0.3498 against 0.3460.)
#[test]
fn masked_images_give_one_h0() {
    use wtmm::spectra::{Rule, image_sums};
    use wtmm::synth::fbm::{FbmParams, fbm};
    let n = 256;
    let data = fbm(FbmParams { hurst: 0.4 }, n, n, 12, 0).unwrap();
    let mut mask = Array2::from_elem((n, n), false);
    for y in 100..116 {
        for x in 90..120 {
            mask[[y, x]] = true;
        }
    }
    let field = Field::with_mask(data, mask).unwrap();
    let cfg = AnalysisConfig {
        octaves: 2,
        ..Default::default()
    };
    let scales = cfg.scale_list();
    let fit = (0.5, 2.0);
    let sp = image_sums(&field, &cfg, &[0.0], "m")
        .unwrap()
        .spectra(Rule::Plain, fit)
        .unwrap();
    let w = image_wtmmm(&field, &cfg, Parallelism::Serial, true).unwrap();
    let counted: Vec<u64> = w.lines.iter().map(|v| v.len() as u64).collect();
    assert_eq!(counted, sp.lines, "the same maxima");
    let h = WtmmmHistograms::from_points(&scales, PdfConfig::default(), &w.lines).unwrap();
    let h0 = h.h0(fit, WtmmmSet::Lines).unwrap();
    let k = ensemble_kernel_sums(&[field], &cfg, KernelConfig::default(), WtmmmSet::Lines).unwrap();
    let c1 = kernel_estimates(&k, &KernelOptions::for_scales(&scales, fit))
        .unwrap()
        .cumulants
        .c1
        .value;
    assert!((h0 - sp.h[0]).abs() < 1e-6, "pdf {h0}, spectra {}", sp.h[0]);
    assert!(
        (c1 + sp.h[0]).abs() < 1e-9,
        "kernel {c1}, spectra {}",
        sp.h[0]
    );
    // every WTMMM of both sets lies clear of the hole by the clearance
    let clear = cfg.hole_clearance();
    let dist = |p: &Point| {
        let dx = (p.x as f64).clamp(90.0, 119.0) - p.x as f64;
        let dy = (p.y as f64).clamp(100.0, 115.0) - p.y as f64;
        dx.hypot(dy)
    };
    for set in [&w.all, &w.lines] {
        assert!(set.iter().flatten().all(|p| dist(p) > clear));
    }
    // and the all set is not empty near it: the check has something to see
    assert!(w.all.iter().flatten().any(|p| dist(p) < 2.0 * clear));
}

/// The tiles run in parallel: their sums are the same bits on 1 and 3
/// threads.
#[test]
fn correlation_tiles_do_not_depend_on_the_thread_count() {
    let cfg = CorrelationConfig {
        scales: vec![1.5, 3.0],
        pairs: vec![(0, 0), (0, 1)],
        periodic: false,
        ..Default::default()
    };
    let plan = CorrelationPlan::new(96, 80, &cfg).unwrap();
    let field = Field::new(noise_field(96, 80, 17));
    let run = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| cwt_correlation_tiled(&field, &plan, "x", 16).unwrap())
    };
    let (a, b) = (run(1), run(3));
    assert!(a.images[0].tiles.len() >= 9);
    assert_eq!(a, b);
}

/// A tile holding every point of a scale leaves its replicate without a
/// mean there: the errors of the pairs with that scale are undefined (NaN)
/// for both centrings, as a brute force would give, not a replicate left
/// centred on the old mean (an independent review's probe).
#[test]
fn a_tile_holding_every_point_of_a_scale_gives_no_error() {
    let (ny, nx) = (30, 30);
    let pt = |y: u32, x: u32, m: f64| Point { y, x, m, arg: 0.0 };
    // scale 0 spread over the image, scale 1 only in the first tile
    let s0: Vec<Point> = (0..100u32)
        .map(|i| pt((i * 7) % 30, (i * 11) % 30, 1.0 + (i % 5) as f64))
        .collect();
    let s1: Vec<Point> = (0..6u32).map(|i| pt(i, 2 * i, 2.0 + i as f64)).collect();
    let cfg = CorrelationConfig {
        scales: vec![1.5, 3.0],
        pairs: vec![(0, 0), (0, 1)],
        periodic: true,
        margin: Some(0),
        bins_per_octave: 2,
        max_dx: Some(12.0),
        ..Default::default()
    };
    let plan = CorrelationPlan::new(ny, nx, &cfg).unwrap();
    let s = wtmmm_correlation_tiled(&[&s0, &s1], &plan, "x", (0, ny, 0, nx), 15).unwrap();
    assert_eq!(s.images[0].tiles.len(), 4);
    assert_eq!(s.images[0].tiles[0].n[1], 6.0);
    let r = correlation_estimates(&s).unwrap();
    // the pair of scale 0 alone keeps finite errors
    assert!(r.pairs[0].c_stderr.iter().any(|e| e.is_finite()));
    for e in r.pairs[1]
        .c_stderr
        .iter()
        .chain(&r.pairs[1].c_ensemble_stderr)
    {
        assert!(e.is_nan(), "{:?}", r.pairs[1].c_stderr);
    }
}

/// Per pair of the CLI's default scales (octaves 1:1, 0:1, 0:2, 1:2 above
/// a_min), per lag bin: `(Δx, rms error one image reports, scatter of C
/// between the images)`, each of `n` images of `model` analysed alone with
/// `k x k` jackknife tiles of its domain.
fn lone_image_correlation_errors(
    model: &Model,
    size: usize,
    n: u64,
    k: usize,
) -> Vec<Vec<(f64, f64, f64)>> {
    use rayon::prelude::*;
    let periodic = !matches!(model, Model::Fbm(_));
    let a_min = AnalysisConfig::for_field(periodic).a_min;
    let cfg = CorrelationConfig {
        scales: vec![a_min, 2.0 * a_min, 4.0 * a_min],
        pairs: vec![(1, 1), (0, 1), (0, 2), (1, 2)],
        periodic,
        ..Default::default()
    };
    let plan = CorrelationPlan::new(size, size, &cfg).unwrap();
    let (y0, y1, x0, x1) = plan.domain();
    let side = (y1 - y0).min(x1 - x0) / k;
    let per: Vec<wtmm::stats::correlation::CorrelationResult> = (0..n)
        .into_par_iter()
        .map(|i| {
            let field = Field::new(model.synthesize(size, 1, i).unwrap());
            let s = cwt_correlation_tiled(&field, &plan, "x", side).unwrap();
            correlation_estimates(&s).unwrap()
        })
        .collect();
    let nf = n as f64;
    (0..cfg.pairs.len())
        .map(|p| {
            per[0].pairs[p]
                .dx
                .iter()
                .enumerate()
                .map(|(b, &dx)| {
                    let v: Vec<f64> = per.iter().map(|r| r.pairs[p].c[b]).collect();
                    let m = v.iter().sum::<f64>() / nf;
                    let sd = (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (nf - 1.0)).sqrt();
                    let rms = (per
                        .iter()
                        .map(|r| r.pairs[p].c_stderr[b].powi(2))
                        .sum::<f64>()
                        / nf)
                        .sqrt();
                    (dx, rms, sd)
                })
                .collect()
        })
        .collect()
}

/// Are a lone image's correlation error bars believable? Per image of an
/// ensemble analysed one by one, `C(Δx; a1, a2)` with the jackknife error
/// over `K x K` tiles of its domain, for each `K` of `TILES`; against the
/// scatter of `C` between the images, per lag bin (every other bin
/// printed, `Δx:ratio`). `MODEL=lognormal|fbm N=16 SIZE=512 TILES=3,4,6
/// cargo test --release --test stats
/// experiment_lone_image_correlation_errors -- --ignored --nocapture`.
#[test]
#[ignore]
fn experiment_lone_image_correlation_errors() {
    let env = |k: &str, d: &str| std::env::var(k).unwrap_or_else(|_| d.to_string());
    let n: u64 = env("N", "16").parse().unwrap();
    let size: usize = env("SIZE", "512").parse().unwrap();
    let name = env("MODEL", "lognormal");
    let model = match name.as_str() {
        "fbm" => Model::preset("paper-fbm").unwrap().model,
        "lognormal" => Model::preset("paper-lognormal").unwrap().model,
        m => panic!("MODEL {m}"),
    };
    for k in env("TILES", "3,4,6").split(',') {
        let k: usize = k.parse().unwrap();
        println!("{name} {size}^2, {k} x {k} tiles:");
        for (p, bins) in lone_image_correlation_errors(&model, size, n, k)
            .iter()
            .enumerate()
        {
            let mut line = format!("  pair {p}:");
            for (dx, rms, sd) in bins.iter().step_by(2) {
                line += &format!(" {dx:.0}:{:.2}", rms / sd);
            }
            println!("{line}");
        }
    }
}

/// A lone image's correlation errors against the truth: 24 fBm images of
/// 256² (H = 1/3) analysed one by one, 4 x 4 tiles of the domain. Over the
/// lags up to L/8, the rms error one image reports is, for each pair of
/// scales, the scatter of C between the images within a factor 2 (the
/// scatter is known to about 15 % from 24 images; measured 0.75-1.2 per
/// bin on 16 images, and 0.7-1.1 at 1024²; `experiment_lone_image_correlation_errors`).
#[test]
fn a_lone_image_reports_believable_correlation_errors() {
    let model = Model::preset("paper-fbm").unwrap().model;
    for (p, bins) in lone_image_correlation_errors(&model, 256, 24, 4)
        .iter()
        .enumerate()
    {
        let near: Vec<f64> = bins
            .iter()
            .filter(|b| b.0 <= 256.0 / 8.0)
            .map(|b| b.1 / b.2)
            .collect();
        let mean = near.iter().sum::<f64>() / near.len() as f64;
        eprintln!(
            "pair {p}: errors / scatter {mean:.2} over {} bins",
            near.len()
        );
        assert!(
            near.len() >= 8 && (0.5..2.0).contains(&mean),
            "pair {p}: {mean}"
        );
    }
}

/// Correlation sums that do not hold together (built by hand, or a JSON
/// shard truncated or edited) are an error of `correlation_estimates` and
/// `merge`, not an index panic: a scale's mean, count or pair missing, a
/// pair past the scales, bins of another length, a tile short of a scale.
#[test]
fn inconsistent_correlation_sums_are_refused() {
    let cfg = CorrelationConfig {
        scales: vec![2.0, 4.0],
        pairs: vec![(0, 1)],
        periodic: true,
        ..Default::default()
    };
    let plan = CorrelationPlan::new(64, 64, &cfg).unwrap();
    let good = cwt_correlation(&Field::new(noise_field(64, 64, 5)), &plan, "a").unwrap();
    assert!(good.check().is_ok());
    assert!(correlation_estimates(&good).is_ok());
    type Break = Box<dyn Fn(&mut CorrelationSums)>;
    let breaks: Vec<(&str, Break)> = vec![
        (
            "mean",
            Box::new(|s| {
                s.images[0].mean.pop();
            }),
        ),
        (
            "n",
            Box::new(|s| {
                s.images[0].n.pop();
            }),
        ),
        (
            "pair sums",
            Box::new(|s| {
                s.images[0].pairs.pop();
            }),
        ),
        (
            "scale",
            Box::new(|s| {
                s.scales.pop();
            }),
        ),
        ("pair index", Box::new(|s| s.pairs[0] = (9, 9))),
        (
            "bins",
            Box::new(|s| {
                s.images[0].pairs[0].lcount.pop();
            }),
        ),
        ("scale value", Box::new(|s| s.scales[1] = f64::NAN)),
    ];
    for (what, brk) in &breaks {
        let mut bad = good.clone();
        brk(&mut bad);
        assert!(correlation_estimates(&bad).is_err(), "{what}");
        let mut g = good.clone();
        assert!(g.merge(&bad).is_err(), "{what}");
    }
    // a tile short of a scale (tiles serve lone images)
    let tiled = cwt_correlation_tiled(&Field::new(noise_field(64, 64, 6)), &plan, "t", 16).unwrap();
    assert!(correlation_estimates(&tiled).is_ok());
    let mut bad = tiled.clone();
    bad.images[0].tiles[1].n.pop();
    assert!(correlation_estimates(&bad).is_err());
}

/// A surface has no orientation, so a flipped image must give the same
/// WTMMM statistics, mapped: the pdfs of A and the joint density of (T1,
/// T2) reflected (flip up-down: A -> -A, T2 -> -T2), drawn at the same
/// resolution, and the CWT-grid kernel sums (a sample of every pixel)
/// equal. On a non-square fBm with even sides, where two failed before
/// 2026-11-29: the joint density's grid points on the axes and diagonals,
/// edges of the argument bins, went to the bin on one side, and the grid
/// kernel took every second row counted from the top (a flip samples the
/// other parity). P(A)'s width (the IQR of A on a cut circle drew the
/// Jacksboro DEM flipped in 16 bins against 8) agreed on this field; the
/// unit test `the_iqr_of_a_is_read_on_the_circle` holds it. A transpose
/// too, on 80 argument bins (whose merges to 10 bins, which no transpose
/// maps, `merged_argument_bins_stay_a_multiple_of_8` holds).
#[test]
fn flipped_images_give_mapped_pdfs_and_grid_kernel() {
    let f =
        wtmm::synth::fbm::fbm(wtmm::synth::fbm::FbmParams { hurst: 0.4 }, 160, 224, 21, 0).unwrap();
    let flipped = f.slice(ndarray::s![..;-1, ..]).to_owned();
    let cfg = AnalysisConfig {
        octaves: 3,
        ..Default::default()
    };
    let scales = cfg.scale_list();
    let show = vec![0, scales.len() / 2, scales.len() - 1];
    let pdfs = |data: &Array2<f64>, arg_bins: usize| {
        let im = image_wtmmm(&Field::new(data.clone()), &cfg, Parallelism::Serial, true).unwrap();
        let pc = PdfConfig {
            arg_bins,
            ..Default::default()
        };
        let h = WtmmmHistograms::from_points(&scales, pc, &im.all).unwrap();
        wtmmm_pdfs(
            &h,
            &PdfOptions {
                show: show.clone(),
                ..Default::default()
            },
        )
        .unwrap()
    };
    // `turn` maps an angle of the original to the image's, `cell` a joint
    // density cell (iy, ix) of the image to the original's
    let mapped = |what: &str,
                  a: &[wtmm::stats::pdf::ScalePdf],
                  b: &[wtmm::stats::pdf::ScalePdf],
                  turn: &dyn Fn(f64) -> f64,
                  cell: &dyn Fn(usize, usize, usize) -> (usize, usize)| {
        for (pa, pb) in a.iter().zip(b) {
            assert_eq!(pa.n, pb.n, "{what}, a = {}", pa.a);
            assert_eq!(
                pa.arg.len(),
                pb.arg.len(),
                "{what}, a = {}: P(A) bins",
                pa.a
            );
            for (c, p) in pa.arg.iter().zip(&pa.p_arg) {
                let to = (turn(*c) + PI).rem_euclid(2.0 * PI) - PI;
                let k = pb
                    .arg
                    .iter()
                    .position(|&d| (d - to).abs() < 1e-9)
                    .unwrap_or_else(|| panic!("{what}, a = {}: no bin at {to}", pa.a));
                assert_eq!(*p, pb.p_arg[k], "{what}, a = {}: P(A) at {c}", pa.a);
            }
            let (ja, jb) = (&pa.joint, &pb.joint);
            let nc = ja.t.len();
            assert_eq!(ja.t, jb.t);
            assert!(ja.t.iter().zip(ja.t.iter().rev()).all(|(x, y)| *x == -*y));
            let mut differ = 0;
            for iy in 0..nc {
                for ix in 0..nc {
                    let (oy, ox) = cell(nc, iy, ix);
                    let (x, y) = (ja.density[oy * nc + ox], jb.density[iy * nc + ix]);
                    differ += usize::from((x - y).abs() > 1e-12 * x.abs().max(y.abs()));
                }
            }
            assert_eq!(
                differ, 0,
                "{what}, a = {}: joint density cells not mapped",
                pa.a
            );
        }
    };
    // flip up-down: A -> -A, T2 -> -T2
    mapped(
        "flipped",
        &pdfs(&f, 64),
        &pdfs(&flipped, 64),
        &|c| -c,
        &|nc, iy, ix| (nc - 1 - iy, ix),
    );
    // transpose: A -> pi/2 - A, T1 <-> T2, on 80 argument bins
    mapped(
        "transposed, 80 bins",
        &pdfs(&f, 80),
        &pdfs(&f.t().to_owned(), 80),
        &|c| PI / 2.0 - c,
        &|_, iy, ix| (ix, iy),
    );
    let grid = |data: &Array2<f64>| {
        wtmm::stats::kernel::cwt_grid_sums(
            &Field::new(data.clone()),
            &cfg,
            KernelConfig::default(),
            2,
            "grid",
        )
        .unwrap()
    };
    let (ga, gb) = (grid(&f), grid(&flipped));
    for (j, (ma, mb)) in ga.images[0]
        .moments
        .iter()
        .zip(&gb.images[0].moments)
        .enumerate()
    {
        assert_eq!(ma.n, mb.n, "scale {j}: grid points");
        let close = |x: f64, y: f64| (x - y).abs() <= 1e-9 * x.abs().max(1.0);
        assert!(
            close(ma.mean, mb.mean) && close(ma.m2, mb.m2) && close(ma.m3, mb.m3),
            "scale {j}: grid moments {ma:?} vs {mb:?}"
        );
    }
}
