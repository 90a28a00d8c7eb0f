//! Ground-truth generators (SPEC §9) and their theory (SPEC §10, §11):
//! every assertion is against mathematics, with the tolerance explained.

use ndarray::Array2;
use num_complex::Complex64;
use rayon::prelude::*;
use rustfft::FftPlanner;

use wtmm::stats::powspec::{
    Detrend, HoleFill, PowerSpectrum, PowerSpectrumConfig, Window, default_k_range, power_spectrum,
};
use wtmm::synth::dwt::{Dwt2, detail_block, max_levels};
use wtmm::synth::fbm::FbmParams;
use wtmm::synth::fisc::{FiscParams, fisc, fisc_measure, pmodel_cascade};
use wtmm::synth::rng_for;
use wtmm::synth::wcascade::{
    Basis, Isotropy, Law, WCascadeParams, wcascade, wcascade_coefficients, wcascade_moduli,
};
use wtmm::theory::{Model, Multifractal, TheoryTable};

const LN2: f64 = std::f64::consts::LN_2;

fn wc(model: Model) -> WCascadeParams {
    match model {
        Model::WCascade(p) => p,
        other => panic!("not a W-cascade: {other:?}"),
    }
}

fn preset(name: &str) -> Model {
    Model::preset(name).unwrap().model
}

/// Mean and standard error of the mean.
fn mean_se(v: &[f64]) -> (f64, f64) {
    let n = v.len() as f64;
    let m = v.iter().sum::<f64>() / n;
    let var = v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0);
    (m, (var / n).sqrt())
}

// ---------------------------------------------------------------- p-model

/// Conservation and multiplier frequencies of the p-model (II eqs 2-3).
/// Mass: each split multiplies by p/2 + p/2 + (1-p)/2 + (1-p)/2 = 1, so the
/// total stays 1 up to a few ulps per step (1e-12 relative is generous).
/// Multipliers: every split gives exactly two children p/2 and two (1-p)/2;
/// the position of the small ones is uniform, so at each of the 4 child
/// positions the count of p/2 over S splits is Binomial(S, 1/2): within
/// 4 standard deviations √S/2. The 6 pairs are uniform: chi-square with 5
/// degrees of freedom below 20.5 (p = 0.001).
#[test]
fn pmodel_conserves_mass_and_draws_fair_pairs() {
    let p = 0.32;
    let steps = 7;
    let mut rng = rng_for(42, 0);
    let mut prev: Option<Array2<f64>> = None;
    let mut splits = 0usize;
    let mut small_at = [0usize; 4];
    let mut pair_count = std::collections::HashMap::new();
    let mut sums = Vec::new();
    let (lo, hi) = (p / 2.0, (1.0 - p) / 2.0);
    let out = pmodel_cascade(p, steps, &mut rng, |s, m| {
        sums.push((s, m.sum()));
        if let Some(parent) = &prev {
            for ((py, px), &pm) in parent.indexed_iter() {
                splits += 1;
                let mut key = 0u8;
                let mut n_small = 0;
                for (i, (dy, dx)) in [(0, 0), (0, 1), (1, 0), (1, 1)].into_iter().enumerate() {
                    let r = m[[2 * py + dy, 2 * px + dx]] / pm;
                    if (r - lo).abs() < 1e-12 {
                        small_at[i] += 1;
                        key |= 1 << i;
                        n_small += 1;
                    } else {
                        assert!(
                            (r - hi).abs() < 1e-12,
                            "ratio {r} is neither p/2 nor (1-p)/2"
                        );
                    }
                }
                assert_eq!(n_small, 2, "exactly two children get p/2");
                *pair_count.entry(key).or_insert(0usize) += 1;
            }
        } else {
            // step 1 from the unit mass
            let mut v: Vec<f64> = m.iter().copied().collect();
            v.sort_by(f64::total_cmp);
            assert!((v[0] - lo).abs() < 1e-15 && (v[1] - lo).abs() < 1e-15);
            assert!((v[2] - hi).abs() < 1e-15 && (v[3] - hi).abs() < 1e-15);
        }
        prev = Some(m.to_owned());
    })
    .unwrap();
    assert_eq!(sums.len(), steps);
    for (s, total) in sums {
        assert!((total - 1.0).abs() < 1e-12, "step {s}: total mass {total}");
    }
    assert!((out.sum() - 1.0).abs() < 1e-12);
    let sd = (splits as f64).sqrt() / 2.0;
    for (i, &c) in small_at.iter().enumerate() {
        let z = (c as f64 - splits as f64 / 2.0) / sd;
        assert!(
            z.abs() < 4.0,
            "position {i}: {c} of {splits} splits, z = {z:.2}"
        );
    }
    assert_eq!(pair_count.len(), 6, "all 6 pairs occur");
    let e = splits as f64 / 6.0;
    let chi2: f64 = pair_count
        .values()
        .map(|&c| (c as f64 - e).powi(2) / e)
        .sum();
    assert!(chi2 < 20.5, "pairs not uniform: chi2 = {chi2:.1} (5 dof)");
}

/// The FISC density has mean 1 and positive values; fisc() integrates the
/// measure of the same seed and index (its spectrum is μ̂ A|k|^-H*).
#[test]
fn fisc_measure_is_a_density() {
    let prm = FiscParams {
        p: 0.32,
        hstar: 0.638,
    };
    let mu = fisc_measure(prm, 64, 9, 3).unwrap();
    assert!((mu.mean().unwrap() - 1.0).abs() < 1e-12);
    assert!(mu.iter().all(|&v| v > 0.0));
    let f = fisc(prm, 64, 9, 3).unwrap();
    assert!(f.mean().unwrap().abs() < 1e-12, "k = 0 is removed");
}

fn paper_fisc() -> FiscParams {
    match preset("paper-fisc") {
        Model::Fisc(p) => p,
        other => panic!("not a FISC: {other:?}"),
    }
}

/// No window (periodic field), mean removed: [`beta_of`]'s settings.
const PERIODIC: PowerSpectrumConfig = PowerSpectrumConfig {
    window: Window::None,
    detrend: Detrend::Mean,
    bins_per_octave: 4,
    fill: HoleFill::Harmonic,
};

/// The exact expected spectrum of the `n x n` FISC, binned like an image's.
fn fisc_expected_spectrum(prm: FiscParams, n: usize) -> PowerSpectrum {
    PowerSpectrum::from_density(prm.expected_power(n).unwrap().view(), 4).unwrap()
}

/// Checks an ensemble of per-image spectra against an exact expectation:
/// the ensemble mean equals it in every |k| bin within 4 standard errors of
/// the mean (from the scatter over the images), and β fitted on the
/// ensemble spectrum equals β fitted on the expectation within 3 jackknife
/// standard errors. A bin whose exact power is zero (ψ3 alone has none on
/// the axes, the only modes of the lowest bin) must hold only rounding
/// (below 1e-20 of the largest bin). Returns (ensemble β, its error, exact β).
fn check_against_expectation(
    label: &str,
    spectra: &[PowerSpectrum],
    exact: &PowerSpectrum,
    n: usize,
) -> (f64, f64, f64) {
    let (lo, hi) = default_k_range(n);
    let want = exact.points();
    let top = want.iter().map(|p| p.1).fold(0.0, f64::max);
    let per: Vec<Vec<(f64, f64)>> = spectra.iter().map(|s| s.points()).collect();
    let mut worst: f64 = 0.0;
    for (b, &(k, s)) in want.iter().enumerate() {
        let v: Vec<f64> = per.iter().map(|p| p[b].1).collect();
        let (m, se) = mean_se(&v);
        if s == 0.0 {
            assert!(
                m.abs() < 1e-20 * top,
                "{label}: |k| = {k:.4}: mean {m:.3e}, exact 0"
            );
            continue;
        }
        let z = (m - s) / se;
        worst = worst.max(z.abs());
        assert!(
            z.abs() < 4.0,
            "{label}: |k| = {k:.4}: mean {m:.4e} +- {se:.2e}, exact {s:.4e}"
        );
    }
    let merged = |skip: Option<usize>| {
        let mut e = PowerSpectrum::default();
        for (i, s) in spectra.iter().enumerate() {
            if Some(i) != skip {
                e.merge(s).unwrap();
            }
        }
        e.fit(lo, hi).unwrap().beta
    };
    let b = merged(None);
    let jk: Vec<f64> = (0..spectra.len()).map(|i| merged(Some(i))).collect();
    let se = wtmm::stats::jackknife_se(&jk);
    let bx = exact.fit(lo, hi).unwrap().beta;
    println!(
        "{label}: worst bin {worst:.2} standard errors; ensemble beta {b:.4} +- {se:.4}, exact {bx:.4}"
    );
    assert!(
        (b - bx).abs() < 3.0 * se,
        "{label}: beta {b:.4} +- {se:.4}, exact {bx:.4}"
    );
    (b, se, bx)
}

/// The generator is the FISC of II eqs 1-7 down to its second moments
/// (24 images of 256² against [`FiscParams::expected_power`]; see
/// [`check_against_expectation`]).
#[test]
fn fisc_spectrum_is_the_exact_expectation() {
    let prm = paper_fisc();
    let (n, count) = (256, 24u64);
    let spectra: Vec<PowerSpectrum> = (0..count)
        .into_par_iter()
        .map(|i| power_spectrum(fisc(prm, n, 5, i).unwrap().view(), &PERIODIC).unwrap())
        .collect();
    check_against_expectation("FISC 256²", &spectra, &fisc_expected_spectrum(prm, n), n);
}

/// β = 3.10 (II eq 11) belongs to the infinite cascade. An image stops it at
/// the pixel, and the exact expected spectrum is flatter near the pixel
/// scale at every size (see [`FiscParams::expected_power`]): fitted over
/// the default range (8 cycles per image to π/4) it gives 3.060 at 256²,
/// 3.074 at 512², 3.082 at 1024², 3.087 at 2048², approaching β from below
/// as the range gains low octaves. Deterministic numbers; the assertions
/// are the qualitative facts, with 1e-3 for rounding.
#[test]
fn fisc_finite_size_spectral_exponent() {
    let prm = paper_fisc();
    let beta = prm.beta();
    let pi = std::f64::consts::PI;
    let mut last = 0.0;
    for n in [256, 512, 1024, 2048] {
        let ps = fisc_expected_spectrum(prm, n);
        let (lo, hi) = default_k_range(n);
        let b = ps.fit(lo, hi).unwrap().beta;
        // the top octave alone, and the range without it
        let top = ps.fit(pi / 8.0, pi / 4.0).unwrap().beta;
        let low = ps.fit(lo, pi / 8.0).unwrap().beta;
        println!(
            "n = {n}: beta {b:.4} (top octave {top:.4}, below pi/8 {low:.4}; theory {beta:.4})"
        );
        assert!(b > last && b < beta, "n = {n}: {b:.4} after {last:.4}");
        assert!(top < low - 1e-3, "n = {n}: the top octave is flatter");
        last = b;
    }
}

// ---------------------------------------------------------------- W-cascades

/// Multiplier moments: the child/parent ratios of the cascade's moduli are
/// the M's, i.i.d. with `<M^q> = 2^-(τ(q)+2) = e^K(q)`. Over n ratios the
/// sample mean of M^q has standard error `sqrt((e^K(2q) - e^2K(q)) / n)`
/// (theoretical variance); allow 4 standard errors.
#[test]
fn wcascade_multiplier_moments_match_the_law() {
    for name in ["paper-lognormal", "paper-logpoisson"] {
        let p = wc(preset(name));
        let levels = wcascade_moduli(&p, 256, 17, 0).unwrap();
        let mut ratios = Vec::new();
        for s in 1..levels.len() {
            for ((y, x), &d) in levels[s].indexed_iter() {
                ratios.push(d / levels[s - 1][[y / 2, x / 2]]);
            }
        }
        let n = ratios.len() as f64;
        for q in [-2.0, -1.0, 1.0, 2.0, 3.0] {
            let want = 2f64.powf(-(p.law.tau(q) + 2.0));
            let got = ratios.iter().map(|r| r.powf(q)).sum::<f64>() / n;
            let var = p.law.ln_moment(2.0 * q).exp() - want * want;
            let se = (var / n).sqrt();
            assert!(
                (got - want).abs() < 4.0 * se,
                "{name} q={q}: <M^q> = {got:.5}, theory {want:.5} +- {se:.5}"
            );
        }
    }
}

/// The coefficients are the moduli rescaled to L2 by `2^(N-s)`: per level,
/// `Σ (c1² + c2² + c3²) / 4^(N-s) = Σ d²`; the inverse DWT reconstructs
/// them: forward(wcascade) = coefficients to 1e-12 of the largest.
#[test]
fn wcascade_coefficients_and_reconstruction() {
    for iso in [Isotropy::Isotropic, Isotropy::Psi12, Isotropy::Psi3] {
        for basis in [Basis::Haar, Basis::Db4, Basis::Db8] {
            let mut p = wc(preset("paper-lognormal"));
            p.isotropy = iso;
            p.basis = basis;
            let size = 128;
            let n = max_levels(size);
            let c = wcascade_coefficients(&p, size, 5, 1).unwrap();
            let d = wcascade_moduli(&p, size, 5, 1).unwrap();
            assert_eq!(d.len(), n);
            for (s, ds) in d.iter().enumerate() {
                let w = 1usize << s;
                let e_c: f64 = (1..=3)
                    .map(|k| {
                        let (rows, cols) = detail_block(w, w, k);
                        c.slice(ndarray::s![rows, cols])
                            .iter()
                            .map(|v| v * v)
                            .sum::<f64>()
                    })
                    .sum();
                let e_d: f64 = ds.iter().map(|v| v * v).sum();
                let l2 = 4f64.powi((n - s) as i32);
                assert!(
                    (e_c / l2 - e_d).abs() < 1e-12 * e_d,
                    "{iso:?} {basis} s={s}"
                );
            }
            assert_eq!(c[[0, 0]], 0.0, "zero mean");
            let f = wcascade(&p, size, 5, 1).unwrap();
            let mut back = f.clone();
            Dwt2::new(basis).forward(&mut back, n).unwrap();
            let big = c.iter().fold(0.0f64, |a, v| a.max(v.abs()));
            let err = c
                .iter()
                .zip(back.iter())
                .fold(0.0f64, |a, (x, y)| a.max((x - y).abs()));
            assert!(
                err < 1e-12 * big,
                "{iso:?} {basis}: reconstruction error {err:e}"
            );
        }
    }
}

/// Normalisation (SPEC §9): a deterministic `M = 2^-H` (σ² = 0) must give a
/// monofractal with h = H, i.e. `β = 2H + 2`. The exact expected spectrum
/// of the finite cascade (whose every bin the generator matches:
/// [`wcascade_spectrum_is_the_exact_expectation`], here again for H = 0.7)
/// has a β fitted over the default range that rises with the size towards
/// 2H + 2 and is within 0.005 of it at 4096² (a wrong level factor is not
/// subtle: each power of 2^(N-s) moves β by 2). At 256² the root and the
/// pixel still bend it by 0.003-0.02.
#[test]
fn deterministic_multiplier_gives_monofractal_beta() {
    for h in [0.4, 0.7] {
        let p = WCascadeParams {
            law: Law::LogNormal {
                m: -h * LN2,
                sigma2: 0.0,
            },
            isotropy: Isotropy::Isotropic,
            basis: Basis::Db8,
        };
        let want = 2.0 * h + 2.0;
        assert!((p.law.tau(2.0) + 4.0 - want).abs() < 1e-12);
        check_exact_beta_converges(&format!("M = 2^-{h}"), &p, want);
    }
    let p = WCascadeParams {
        law: Law::LogNormal {
            m: -0.7 * LN2,
            sigma2: 0.0,
        },
        isotropy: Isotropy::Isotropic,
        basis: Basis::Db8,
    };
    let n = 256;
    let spectra: Vec<PowerSpectrum> = (0..24u64)
        .into_par_iter()
        .map(|i| power_spectrum(wcascade(&p, n, 21, i).unwrap().view(), &PERIODIC).unwrap())
        .collect();
    check_against_expectation(
        "M = 2^-0.7",
        &spectra,
        &wcascade_expected_spectrum(&p, n),
        n,
    );
}

/// β fitted (default range) on the exact expected spectrum of the finite
/// W-cascade at 256² .. 4096²: rises with the size and ends within 0.005
/// of `want`.
fn check_exact_beta_converges(label: &str, p: &WCascadeParams, want: f64) {
    let betas: Vec<f64> = [256usize, 512, 1024, 2048, 4096]
        .iter()
        .map(|&n| {
            let (lo, hi) = default_k_range(n);
            wcascade_expected_spectrum(p, n).fit(lo, hi).unwrap().beta
        })
        .collect();
    println!("{label}: exact finite-size beta at 256..4096: {betas:.4?} (infinite {want:.4})");
    for w in betas.windows(2) {
        assert!(w[1] > w[0] && w[1] < want + 1e-3, "{label}: {betas:?}");
    }
    assert!(
        (betas[4] - want).abs() < 0.005,
        "{label}: {betas:?}, want {want}"
    );
}

/// Mean compensated power `P(k) |k|^β` in 4 angular sectors of width π/4
/// centred on 0 (x axis), π/4, π/2 (y axis), 3π/4, over `k_lo <= |k| <=
/// k_hi`, for a power `power(i, j)` on the `n x n` FFT grid (standard
/// order; the two indices are the two axes, in either order: swapping them
/// swaps the two axis sectors and leaves the diagonal ones).
fn sector_mean(
    n: usize,
    power: impl Fn(usize, usize) -> f64,
    beta: f64,
    k_lo: f64,
    k_hi: f64,
) -> [f64; 4] {
    let pi = std::f64::consts::PI;
    let k = |m: usize| {
        2.0 * pi
            * if m <= n / 2 {
                m as f64
            } else {
                m as f64 - n as f64
            }
            / n as f64
    };
    let (mut s, mut c) = ([0.0; 4], [0usize; 4]);
    for kx in 0..n {
        for ky in 0..n {
            let (fx, fy) = (k(kx), k(ky));
            let r = fx.hypot(fy);
            if r < k_lo || r > k_hi {
                continue;
            }
            let sector = ((fy.atan2(fx).rem_euclid(pi) / (pi / 4.0)) + 0.5).floor() as usize % 4;
            s[sector] += power(kx, ky) * r.powf(beta);
            c[sector] += 1;
        }
    }
    std::array::from_fn(|i| s[i] / c[i] as f64)
}

/// [`sector_mean`] of an image's periodogram `|f̂|²`.
fn sector_power(f: &Array2<f64>, beta: f64, k_lo: f64, k_hi: f64) -> [f64; 4] {
    let n = f.nrows();
    let fft = FftPlanner::new().plan_fft_forward(n);
    let mut a: Vec<Complex64> = f.iter().map(|&v| Complex64::new(v, 0.0)).collect();
    for row in a.chunks_exact_mut(n) {
        fft.process(row);
    }
    let mut t = vec![Complex64::default(); n * n];
    transpose::transpose(&a, &mut t, n, n);
    for row in t.chunks_exact_mut(n) {
        fft.process(row);
    }
    sector_mean(n, |kx, ky| t[kx * n + ky].norm_sqr(), beta, k_lo, k_hi)
}

/// `ln(axis / diagonal)` of summed sector powers `s`.
fn axis_diag(s: &[f64; 4]) -> f64 {
    ((s[0] + s[2]) / (s[1] + s[3])).ln()
}

/// Anisotropy of `count` images of 256² at mid frequencies (0.2-0.8 rad/px,
/// the fit range): the ensemble's `ln(axis / diagonal)` compensated power
/// (sector powers summed over the images) with its jackknife error, and
/// the same for the exact expected spectrum of the generator
/// ([`wtmm::theory::wcascade::expected_power`], linear in the power, so
/// the expectation of the summed sectors). The x and y axes must agree
/// within 4 standard errors (θ is uniform).
fn anisotropy(p: &WCascadeParams, count: u64) -> (f64, f64, f64) {
    let n = 256;
    let beta = p.law.tau(2.0) + 4.0;
    let per: Vec<[f64; 4]> = (0..count)
        .into_par_iter()
        .map(|i| sector_power(&wcascade(p, n, 11, i).unwrap(), beta, 0.2, 0.8))
        .collect();
    let summed = |skip: Option<usize>| -> [f64; 4] {
        std::array::from_fn(|k| {
            per.iter()
                .enumerate()
                .filter(|(i, _)| Some(*i) != skip)
                .map(|(_, s)| s[k])
                .sum()
        })
    };
    let all = summed(None);
    let jk = |f: &dyn Fn(&[f64; 4]) -> f64| {
        wtmm::stats::jackknife_se(
            &(0..per.len())
                .map(|i| f(&summed(Some(i))))
                .collect::<Vec<_>>(),
        )
    };
    let xy = |s: &[f64; 4]| (s[0] / s[2]).ln();
    let xy_se = jk(&xy);
    assert!(
        xy(&all).abs() < 4.0 * xy_se,
        "x and y axes differ: {:.3} +- {xy_se:.3}",
        xy(&all)
    );
    let d = wtmm::theory::wcascade::expected_power(p, n).unwrap();
    let exact = sector_mean(n, |i, j| d[[i, j]], beta, 0.2, 0.8);
    (axis_diag(&all), jk(&axis_diag), axis_diag(&exact))
}

/// Isotropy (II Fig 5; SPEC §9): at mid frequencies the compensated power
/// on the axes against the diagonals, `ln(axis / diagonal)`, of 8 images of
/// 256² per variant equals that of the generator's exact expected spectrum
/// within 4 jackknife standard errors (for all three variants: the
/// isotropic one, ψ1+ψ2 only, ψ3 only). The exact values then say what the
/// variants are, without statistics: the isotropic variant keeps a
/// residual anisotropy (the paper notes that of the square-lattice
/// fragmentation; exact 0.099) that is less than 40 % of the ψ1+ψ2
/// variant's enhancement of the axes (0.547), and ψ3 alone empties them
/// (-4.41). Measured: 0.111 ± 0.023, 0.525 ± 0.033, -4.469 ± 0.027.
/// Before: the ensemble's own values were held to bare bounds (|ln ratio|
/// < 0.2, > 0.4, < -1). The sensitivity to the isotropic variant is about
/// the same (4 se = 0.09 here: a φ range 13 % too narrow, ln ratio 0.205,
/// fails; 8 % too narrow passes), but the ψ1+ψ2 and ψ3 variants are now
/// held to their exact values, not to their sign.
#[test]
fn isotropic_variant_has_an_isotropic_spectrum() {
    let base = wc(preset("paper-lognormal"));
    let with = |isotropy| WCascadeParams { isotropy, ..base };
    let mut exact = Vec::new();
    for iso in [Isotropy::Isotropic, Isotropy::Psi12, Isotropy::Psi3] {
        let (r, se, r_exact) = anisotropy(&with(iso), 8);
        println!("{iso:?}: ln(axis/diagonal) {r:.3} +- {se:.3}, exact {r_exact:.3}");
        assert!(
            (r - r_exact).abs() < 4.0 * se,
            "{iso:?}: ln(axis/diag) = {r:.3} +- {se:.3}, exact expectation {r_exact:.3}"
        );
        exact.push(r_exact);
    }
    let (iso, p12, p3) = (exact[0], exact[1], exact[2]);
    assert!(
        iso.abs() < 0.4 * p12,
        "isotropic {iso:.3} vs psi12 {p12:.3}"
    );
    assert!(p12 > 0.0 && p3 < 0.0, "psi12 {p12:.3}, psi3 {p3:.3}");
}

// ---------------------------------------------------------------- spectra

/// Spectral exponents agree with theory (II eqs 29, 37): W-cascades
/// `β = τ(2) + 4 = 2.70` for both paper laws. The generator's ensemble
/// spectrum is its exact finite-size expectation in every bin and in β
/// ([`wcascade_spectrum_is_the_exact_expectation`]); that expectation's β
/// rises with the size to the theory (2.678 / 2.674 at 256², 2.6945 /
/// 2.6905 at 1024², within 0.005 at 4096²). FISC: see
/// [`fisc_spectrum_is_the_exact_expectation`].
#[test]
fn ensemble_spectral_exponents_match_theory() {
    for (name, published) in [("paper-lognormal", 2.70), ("paper-logpoisson", 2.70)] {
        let model = preset(name);
        assert!(
            (model.beta() - published).abs() < 0.005,
            "{name}: theory {}",
            model.beta()
        );
        check_exact_beta_converges(name, &wc(model), model.beta());
    }
}

// ---------------------------------------------------------------- theory

/// The published numbers of II §2-§4 (SPEC §11) come out of the closed forms.
#[test]
fn published_theory_numbers() {
    let ln = preset("paper-lognormal");
    let (lo, hi) = ln.h_range();
    assert!((lo - 0.034).abs() < 5e-4, "h_min {lo}");
    assert!((hi - 0.726).abs() < 5e-4, "h_max {hi}");
    assert!((ln.h_of_q0() - 0.38).abs() < 1e-12);
    let c = ln.cumulants().unwrap();
    assert!((c[0] + 0.38).abs() < 1e-12 && (c[1] - 0.03).abs() < 1e-12 && c[2] == 0.0);
    assert!((ln.beta() - 2.70).abs() < 1e-12);
    // II eq 30 against the quadratic: D(h(0)) = 2
    assert!((ln.dh(0.38).unwrap() - 2.0).abs() < 1e-12);

    let lp = preset("paper-logpoisson");
    let c = lp.cumulants().unwrap();
    // published to the digits shown, c2 truncated (0.03653 printed 0.036)
    assert!((c[0] + 0.381).abs() < 5e-4, "c1 {}", c[0]);
    assert!((c[1] - 0.036).abs() < 1e-3, "c2 {}", c[1]);
    assert!((c[2] + 0.0049).abs() < 5e-5, "c3 {}", c[2]);
    assert!((lp.h_of_q0() - 0.381).abs() < 5e-4, "h(0) {}", lp.h_of_q0());
    assert!((lp.beta() - 2.70).abs() < 5e-3, "beta {}", lp.beta());
    // λ = 2 ln2: D reaches 0 exactly at the asymptote h = -γ/ln2 = 1/9
    let (lo, _) = lp.h_range();
    assert!((lo - 1.0 / 9.0).abs() < 1e-12, "h_min {lo}");
    // II §5.3 remark: σ² = λ (ln β)² = 0.025 (vs 0.03 ln2 = 0.021);
    // C(Δx = L/4) = σ² (2 - 2 + 1/2)
    let c_lp = lp.magnitude_correlation(1.0, 4.0).unwrap();
    assert!(
        (c_lp / 0.5 - 0.025).abs() < 5e-4,
        "log-Poisson σ² {}",
        c_lp / 0.5
    );

    let fi = preset("paper-fisc");
    assert!((fi.beta() - 3.10).abs() < 5e-3, "beta {}", fi.beta());
    assert!((fi.h_of_q0() - 0.738).abs() < 5e-4, "h(0) {}", fi.h_of_q0());
    assert!((fi.tau(0.0) + 2.0).abs() < 1e-12 && (fi.tau(1.0) - (0.638 - 2.0)).abs() < 1e-12);
    let (lo, hi) = fi.h_range();
    // II §3.1: "h ranges in the interval ~[0.18, 1.30]". The closed forms
    // (h_min = H* - 2 - log2((1-p)/2) = 0.194393, h_max = 1.281856 for
    // p = 0.32, H* = 0.638) checked against the slopes of tau itself at
    // q = +-400, independent of `h_range`: they converge like
    // (p / (1-p))^400 ~ 1e-130, so to rounding
    let slope = |q: f64| fi.tau(q + 1.0) - fi.tau(q);
    assert!(
        (lo - slope(400.0)).abs() < 1e-10 && (hi - slope(-401.0)).abs() < 1e-10,
        "{lo} {hi}: slopes {} {}",
        slope(400.0),
        slope(-401.0)
    );
    assert!((lo - 0.194393).abs() < 1e-6 && (hi - 1.281856).abs() < 1e-6);

    let fb = preset("paper-fbm");
    assert!((fb.tau(3.0) - (3.0 / 3.0 - 2.0)).abs() < 1e-12);
    assert_eq!(fb.magnitude_correlation(10.0, 1024.0), Some(0.0));
}

/// II eq 76 in the paper's setting (σ² = 0.03 ln2, L = 1024): logarithmic
/// decay, zero at Δx = L/2, and equal to the discrete sum of eq 74.
#[test]
fn magnitude_correlation_eq76() {
    let m = preset("paper-lognormal");
    let s2 = 0.03 * LN2;
    let (n_tot, l) = (10i32, 1024.0);
    for p in 0..9 {
        let dx = 2f64.powi(p);
        let got = m.magnitude_correlation(dx, l).unwrap();
        let n = (n_tot - p) as f64; // N - j - p with j = 0
        let eq74 = s2 * (n - 2.0 + 2f64.powf(1.0 - n));
        assert!((got - eq74).abs() < 1e-12, "dx={dx}");
    }
    assert!(m.magnitude_correlation(512.0, l).unwrap().abs() < 1e-15);
    assert!(m.magnitude_correlation(1024.0, l).is_none());
    assert!(preset("paper-fisc").magnitude_correlation(8.0, l).is_none());
}

#[test]
fn theory_table_for_every_preset() {
    let q: Vec<f64> = (-12..=16).map(|i| i as f64 * 0.5).collect();
    for name in wtmm::theory::PRESET_NAMES {
        let t = TheoryTable::new(&preset(name), &q).unwrap();
        assert_eq!(t.tau.len(), q.len());
        let i0 = q.iter().position(|&v| v == 0.0).unwrap();
        assert!(
            (t.tau[i0] + 2.0).abs() < 1e-12 && (t.d[i0] - 2.0).abs() < 1e-12,
            "{name}"
        );
        assert!(t.h_min <= t.h_of_q0 && t.h_of_q0 <= t.h_max, "{name}");
        let json = serde_json::to_string(&t).unwrap();
        assert!(
            json.contains("\"D\"") && json.contains("\"beta\""),
            "{name}"
        );
    }
}

// ---------------------------------------------------------------- seeding

fn bits(a: &Array2<f64>) -> Vec<u64> {
    a.iter().map(|v| v.to_bits()).collect()
}

/// Same seed and index give the same bytes; another index gives another
/// image; generating an ensemble in parallel (rayon) gives the same bytes as
/// serially, in any order.
#[test]
fn seeding_is_reproducible_and_thread_independent() {
    let models = [
        preset("paper-fisc"),
        preset("paper-lognormal"),
        preset("paper-logpoisson"),
        preset("topo-fif"),
        Model::Fbm(FbmParams { hurst: 0.3 }),
    ];
    for m in models {
        let a = m.synthesize(64, 77, 3).unwrap();
        let b = m.synthesize(64, 77, 3).unwrap();
        assert_eq!(bits(&a), bits(&b), "{m:?}: same seed, same bytes");
        let c = m.synthesize(64, 77, 4).unwrap();
        assert_ne!(bits(&a), bits(&c), "{m:?}: another index, another image");
        let d = m.synthesize(64, 78, 3).unwrap();
        assert_ne!(bits(&a), bits(&d), "{m:?}: another seed, another image");
        let serial: Vec<Vec<u64>> = (0..8)
            .map(|i| bits(&m.synthesize(64, 5, i).unwrap()))
            .collect();
        let parallel: Vec<Vec<u64>> = (0..8usize)
            .into_par_iter()
            .rev()
            .map(|i| bits(&m.synthesize(64, 5, i as u64).unwrap()))
            .collect::<Vec<_>>()
            .into_iter()
            .rev()
            .collect();
        assert_eq!(serial, parallel, "{m:?}: parallel == serial");
    }
}

/// Model round-trips through JSON (the CLI stores it in outputs).
#[test]
fn model_serde_round_trip() {
    for name in wtmm::theory::PRESET_NAMES {
        let m = preset(name);
        let s = serde_json::to_string(&m).unwrap();
        let back: Model = serde_json::from_str(&s).unwrap();
        assert_eq!(back, m, "{s}");
    }
    let m: Model = serde_json::from_str(
        r#"{"model":"wcascade","law":{"law":"lognormal","m":-0.3,"sigma2":0.01}}"#,
    )
    .unwrap();
    let p = wc(m);
    assert_eq!(
        (p.isotropy, p.basis),
        (Isotropy::Isotropic, Basis::Db8),
        "defaults"
    );
}

// ------------------------------------------------- W-cascade spectra, exact

/// The exact expected spectrum of the `n x n` W-cascade, binned like an
/// image's.
fn wcascade_expected_spectrum(p: &WCascadeParams, n: usize) -> PowerSpectrum {
    let d = wtmm::theory::wcascade::expected_power(p, n).unwrap();
    PowerSpectrum::from_density(d.view(), 4).unwrap()
}

/// The W-cascade generator down to its second moments: ensembles of 256²
/// images against the exact expectation
/// ([`wtmm::theory::wcascade::expected_power`]) in every |k| bin and in β,
/// for the two paper laws, a deterministic multiplier (monofractal, only
/// the angles random), and the other variants and bases; see
/// [`check_against_expectation`]. 32 images each, 128 for ψ1+ψ2 only: its
/// energy sits on the axes, per-image β scatter more, and the jackknife of
/// 32 images understates it (measured, 256 images of db8: sd of β over 8
/// disjoint groups of 32 is 0.024 against a jackknife error of 0.019).
#[test]
fn wcascade_spectrum_is_the_exact_expectation() {
    let n = 256;
    let mono = WCascadeParams {
        law: Law::LogNormal {
            m: -0.4 * LN2,
            sigma2: 0.0,
        },
        isotropy: Isotropy::Isotropic,
        basis: Basis::Db8,
    };
    let ln = |isotropy, basis| WCascadeParams {
        law: Law::LogNormal {
            m: -0.38 * LN2,
            sigma2: 0.03 * LN2,
        },
        isotropy,
        basis,
    };
    for (label, p, count) in [
        ("paper-lognormal", wc(preset("paper-lognormal")), 32u64),
        ("paper-logpoisson", wc(preset("paper-logpoisson")), 32),
        ("M = 2^-0.4", mono, 32),
        (
            "log-normal, isotropic, db4",
            ln(Isotropy::Isotropic, Basis::Db4),
            32,
        ),
        (
            "log-normal, psi3 only, Haar",
            ln(Isotropy::Psi3, Basis::Haar),
            32,
        ),
        (
            "log-normal, psi1+psi2 only, db8",
            ln(Isotropy::Psi12, Basis::Db8),
            128,
        ),
    ] {
        let spectra: Vec<PowerSpectrum> = (0..count)
            .into_par_iter()
            .map(|i| power_spectrum(wcascade(&p, n, 9, i).unwrap().view(), &PERIODIC).unwrap())
            .collect();
        check_against_expectation(label, &spectra, &wcascade_expected_spectrum(&p, n), n);
    }
}

// ------------------------------------------------------- own cascades

/// The images' own cascades (`Model::sample_sums`, the "sample" column of
/// `validate`) are the generators' amplitudes: the W-cascade's equal
/// `wcascade_moduli`, the FISC's finest level is `fisc_measure` shifted by
/// `(2 - H*) n`; and their annealed partition function has the theory's
/// tau(q) (`<Σ d^q> = 4^s <W^q>^s` exactly): over q in [-3, 5], 16 images of
/// 256^2 on the dyadic scales 2-64 px lie within 4 jackknife standard errors
/// (tau(0) = -2 exactly: every level has 4^s amplitudes). The FISC's sums
/// are deterministic (every split gives two p/2 and two (1-p)/2), so its
/// errors are zero and it must hold the theory to rounding.
#[test]
fn own_cascades_have_the_theoretical_tau() {
    use wtmm::spectra::{PartitionSums, Rule};
    use wtmm::synth::fisc::fisc_log2_amplitudes;
    use wtmm::synth::wcascade::wcascade_log2_amplitudes;
    let n = 256;
    // the values are the generators' own amplitudes
    let p = wc(preset("paper-logpoisson"));
    let lv = wcascade_moduli(&p, n, 9, 2).unwrap();
    let own = wcascade_log2_amplitudes(&p, n, 9, 2, 3..6).unwrap();
    for (k, s) in (3..6).enumerate() {
        let want: Vec<f64> = lv[s].iter().map(|d| d.abs().log2()).collect();
        assert_eq!(own[k], want, "W-cascade level {s}");
    }
    let f = paper_fisc();
    let mu = fisc_measure(f, n, 9, 2).unwrap();
    let own = fisc_log2_amplitudes(f, n, 9, 2, 8..9).unwrap();
    // scale ranges that are not finite are refused (inf wrapped the level
    // arithmetic into a capacity overflow)
    let m = wtmm::theory::Model::preset("paper-lognormal")
        .unwrap()
        .model;
    assert!(m.sample_levels(32, (f64::INFINITY, f64::INFINITY)).is_err());
    assert!(
        m.sample_sums(32, 1, 0, &[1.0], (2.0, f64::INFINITY))
            .is_err()
    );
    // a range far past the cascade is refused, not an unbounded allocation
    assert!(fisc_log2_amplitudes(f, n, 9, 2, 0..usize::MAX).is_err());
    assert!(wcascade_log2_amplitudes(&p, n, 9, 2, 0..usize::MAX).is_err());
    assert_eq!(
        wcascade_log2_amplitudes(&p, n, 9, 2, 8..9).unwrap(),
        vec![Vec::<f64>::new()]
    );
    let shift = (2.0 - f.hstar) * 8.0;
    let area = (n * n) as f64;
    for (v, m) in own[0].iter().zip(mu.iter()) {
        assert!(
            (v - shift - (m / area).log2()).abs() < 1e-9,
            "FISC pixel masses"
        );
    }

    let q: Vec<f64> = (-3..=5).map(|k| k as f64).collect();
    for name in ["paper-lognormal", "paper-logpoisson", "paper-fisc"] {
        let m = preset(name);
        let parts: Vec<PartitionSums> = (0..16u64)
            .into_par_iter()
            .map(|i| m.sample_sums(n, 3, i, &q, (2.0, 64.0)).unwrap().unwrap())
            .collect();
        let sums = PartitionSums::merge_all(parts).unwrap().unwrap();
        assert_eq!(sums.scales, vec![2.0, 4.0, 8.0, 16.0, 32.0, 64.0], "{name}");
        let s = sums.spectra(Rule::Plain, (0.0, 5.0)).unwrap();
        for (i, &qi) in q.iter().enumerate() {
            let th = m.tau(qi);
            let (est, se) = (s.tau[i], s.tau_stderr[i]);
            assert!(
                (est - th).abs() <= 4.0 * se + 1e-9,
                "{name}: q = {qi}: own-cascade tau {est:.4} +- {se:.4}, theory {th:.4}"
            );
        }
    }
    // no discrete cascade: no sample
    assert!(
        Model::Fbm(FbmParams { hurst: 0.3 })
            .sample_sums(n, 1, 0, &q, (2.0, 64.0))
            .unwrap()
            .is_none()
    );
}

/// The p-model refuses a `p` outside (0, 1/2] and a grid too large to
/// allocate with an error naming the parameter (it panicked on `p`).
#[test]
fn pmodel_cascade_refuses_bad_parameters() {
    let mut rng = rng_for(1, 0);
    for p in [0.0, 0.6, f64::NAN] {
        let e = pmodel_cascade(p, 3, &mut rng, |_, _| {})
            .unwrap_err()
            .to_string();
        assert!(e.contains("`p`"), "{p}: {e}");
    }
    for steps in [40, 64, 1000] {
        let e = pmodel_cascade(0.3, steps, &mut rng, |_, _| {})
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("`steps`") || e.contains("`size`"),
            "{steps}: {e}"
        );
    }
    let m = pmodel_cascade(0.3, 0, &mut rng, |_, _| {}).unwrap();
    assert_eq!(m.dim(), (1, 1));
    assert_eq!(m[[0, 0]], 1.0);
}
