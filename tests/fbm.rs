//! fBm surfaces (SPEC §9): spectral exponent, the exact expected spectrum,
//! and reproducibility.

use ndarray::Array2;
use num_complex::Complex64;
use rayon::prelude::*;
use wtmm::fourier::angular_freq;
use wtmm::stats::fit::mean_std;
use wtmm::stats::powspec::{
    Detrend, HoleFill, PowerSpectrum, PowerSpectrumConfig, Window, default_k_range,
    jackknife_beta_se, power_spectrum,
};
use wtmm::synth::fbm::{FbmParams, fbm};

/// Spectral exponent of each image of `count` fBm images of 256^2,
/// default spectrum and fit range.
fn betas(h: f64, count: u64, seed: u64) -> Vec<f64> {
    let n = 256;
    let cfg = PowerSpectrumConfig::default();
    let (lo, hi) = default_k_range(n);
    (0..count)
        .into_par_iter()
        .map(|i| {
            let img = fbm(FbmParams { hurst: h }, n, n, seed, i).unwrap();
            power_spectrum(img.view(), &cfg)
                .unwrap()
                .fit(lo, hi)
                .unwrap()
                .beta
        })
        .collect()
}

/// β = 2H + 2 (SPEC §9), absolutely at H = 0.5 and in its dependence on H.
///
/// * H = 0.5, 192 images of 256^2: the mean of the per-image exponents is
///   within 3.5 standard errors of the mean (sd / √192 ≈ 0.013, from the
///   ensemble's own scatter) of 3. No allowance for the Hann window's
///   leakage on the cropped (non-periodic) field: measured on 512 images
///   per H (seed 99, `experiment_beta_bias`) the mean departs from 2H + 2
///   by -0.012 ± 0.007, -0.006 ± 0.007 and +0.000 ± 0.007 at H = 0.2,
///   0.5, 0.8, none significant, all below a third of the tolerance.
/// * H = 0.2 and 0.8 against 0.5 on the same 64 noises (same seed and
///   index: the per-image β of the three share their sampling error): the
///   mean per-image difference β(H) - β(0.5) is 2 (H - 0.5) = ∓0.6 plus
///   the estimator's measured bias `PAIRED_BIAS` (the same 512 images:
///   -0.0053 and +0.0067, the spectral estimate steepens 1 % faster than
///   2H), within 3.5 standard errors of the difference, `3.5 sqrt(se² +
///   se_bias²)`, se the scatter of the paired differences (about 5e-4, a
///   fiftieth of the unpaired error).
///
/// k = 3.5: two-sided 5e-4 per assertion. (Before: 16 images per H plus a
/// bare 0.03, a tolerance of 0.20 that let a generator exponent off by
/// 0.05, β off by 0.1, pass.)
/// `(H, bias, se)` of β(H) - β(0.5) - 2 (H - 0.5) for the same noises,
/// measured by `experiment_beta_bias` (512 images, seed 99).
const PAIRED_BIAS: [(f64, f64, f64); 2] = [(0.2, -0.00530, 0.00019), (0.8, 0.00665, 0.00019)];

#[test]
fn spectral_exponent_is_2h_plus_2() {
    let half = betas(0.5, 192, 2024);
    let (m, sd) = mean_std(&half);
    let se = sd / (half.len() as f64).sqrt();
    eprintln!(
        "H=0.5: beta {m:.4} +- {se:.4} (theory 3, tol {:.4})",
        3.5 * se
    );
    assert!(
        (m - 3.0).abs() < 3.5 * se,
        "H=0.5: beta {m:.4} +- {se:.4}, theory 3"
    );
    for (h, bias, se_bias) in PAIRED_BIAS {
        let d: Vec<f64> = betas(h, 64, 2024)
            .iter()
            .zip(&half)
            .map(|(b, b5)| b - b5)
            .collect();
        let (md, sdd) = mean_std(&d);
        let se = sdd / (d.len() as f64).sqrt();
        let want = FbmParams { hurst: h }.beta() - 3.0 + bias;
        let tol = 3.5 * se.hypot(se_bias);
        eprintln!(
            "H={h}: beta(H) - beta(0.5) = {md:.5} +- {se:.5} (theory + bias {want:.5}, tol {tol:.5})"
        );
        assert!(
            (md - want).abs() < tol,
            "H={h}: beta(H) - beta(0.5) = {md:.5} +- {se:.5}, theory + bias {want:.5}"
        );
    }
}

/// The measurements behind the tolerances above (not a check; `cargo test
/// --release --test fbm experiment_beta_bias -- --ignored --nocapture`,
/// env N (default 512), SEED (default 99); about 10 s).
#[test]
#[ignore]
fn experiment_beta_bias() {
    let n: u64 = std::env::var("N").map_or(512, |s| s.parse().unwrap());
    let seed: u64 = std::env::var("SEED").map_or(99, |s| s.parse().unwrap());
    let rn = (n as f64).sqrt();
    let half = betas(0.5, n, seed);
    for h in [0.2, 0.5, 0.8] {
        let b = if h == 0.5 {
            half.clone()
        } else {
            betas(h, n, seed)
        };
        let (m, sd) = mean_std(&b);
        let want = FbmParams { hurst: h }.beta();
        let d: Vec<f64> = b.iter().zip(&half).map(|(x, y)| x - y).collect();
        let (md, sdd) = mean_std(&d);
        println!(
            "H = {h}: beta - (2H + 2) = {:+.4} +- {:.4}; beta(H) - beta(0.5) - 2 (H - 0.5) = {:+.5} +- {:.5}",
            m - want,
            sd / rn,
            md - (want - 3.0),
            sdd / rn
        );
    }
}

/// Tapered with the library's Hann window, only the mean removed: the
/// settings of [`fbm_expected_density`] (a removed plane would couple every
/// mode to the plane's fit and break the closed form).
const HANN_MEAN: PowerSpectrumConfig = PowerSpectrumConfig {
    window: Window::Hann,
    detrend: Detrend::Mean,
    bins_per_octave: 4,
    fill: HoleFill::Harmonic,
};

/// In-place 2D DFT (rows, then columns), unnormalised.
fn fft2(a: &mut Array2<Complex64>, inverse: bool) {
    let (ny, nx) = a.dim();
    let mut planner = rustfft::FftPlanner::<f64>::new();
    let plan = |p: &mut rustfft::FftPlanner<f64>, n| {
        if inverse {
            p.plan_fft_inverse(n)
        } else {
            p.plan_fft_forward(n)
        }
    };
    let (fx, fy) = (plan(&mut planner, nx), plan(&mut planner, ny));
    for mut row in a.rows_mut() {
        let mut v = row.to_vec();
        fx.process(&mut v);
        row.assign(&ndarray::Array1::from(v));
    }
    for mut col in a.columns_mut() {
        let mut v = col.to_vec();
        fy.process(&mut v);
        col.assign(&ndarray::Array1::from(v));
    }
}

/// The exact expected spectral density `E|F(k)|²/Σw²` of an `n x n` fBm
/// image of exponent H as [`power_spectrum`] computes it with [`HANN_MEAN`],
/// in FFT order (for [`PowerSpectrum::from_density`]).
///
/// The generator (SPEC §9, `synth::fbm`) filters white noise on the
/// `2n x 2n` torus and keeps the centre `n x n`, so the image is
/// `f(x) = Σ_k' c(k') e^{ik'x}` over the `2n` grid with uncorrelated `c` of
/// variance `P(k') = |k'|^-(2H+2)` (`P(0) = 0`; the noise has unit
/// variance and the transforms are normalised by `1/2n`). The periodic
/// field's spectrum is not exposed, only this crop: it is not periodic,
/// and its spectrum is `P` seen through the window. With the crop mean
/// removed and the Hann taper `w`, the DFT at `k = 2πj/n` is
/// `F(k) = Σ_k' c(k') [W(k - k') - W(k) M(k')]`, `W` the transform of `w`
/// and `M(k')` the crop mean of `e^{ik'x}`, hence exactly
/// `E|F(k)|² = Σ_k' P(k') |W(k - k') - W(k) M(k')|²`. `k - k'` is a multiple
/// of `2π/2n`, where `W` is the 2n-point DFT of the zero-padded window.
/// Where `W(k) = 0` (all but the 8 modes next to k = 0: the half-pixel Hann
/// is a sum of 3 exponentials) this is the circular convolution of `P`
/// with `|W|²` at `2j`, done by FFT; at the others it is summed directly.
fn fbm_expected_density(h: f64, n: usize) -> Array2<f64> {
    let big = 2 * n;
    let p = Array2::from_shape_fn((big, big), |(y, x)| {
        let k2 = angular_freq(x, big).powi(2) + angular_freq(y, big).powi(2);
        if k2 > 0.0 { k2.powf(-(h + 1.0)) } else { 0.0 }
    });
    // the library's window (`stats::powspec`): sin²(π(i + 1/2)/n)
    let w: Vec<f64> = (0..n)
        .map(|i| {
            (std::f64::consts::PI * (i as f64 + 0.5) / n as f64)
                .sin()
                .powi(2)
        })
        .collect();
    let dft = |v: &[f64], m: usize| -> Complex64 {
        v.iter()
            .enumerate()
            .map(|(x, &a)| {
                a * Complex64::from_polar(
                    1.0,
                    -2.0 * std::f64::consts::PI * ((m * x) % big) as f64 / big as f64,
                )
            })
            .sum()
    };
    let wf: Vec<Complex64> = (0..big).map(|m| dft(&w, m)).collect();
    let df: Vec<Complex64> = (0..big).map(|m| dft(&vec![1.0; n], m)).collect();
    let mut conv = p.mapv(|v| Complex64::new(v, 0.0));
    let mut kern = Array2::from_shape_fn((big, big), |(y, x)| {
        Complex64::new(wf[y].norm_sqr() * wf[x].norm_sqr(), 0.0)
    });
    fft2(&mut conv, false);
    fft2(&mut kern, false);
    conv *= &kern;
    fft2(&mut conv, true);
    let wsum2 = w.iter().map(|v| v * v).sum::<f64>().powi(2);
    let w00 = wf[0].norm_sqr().powi(2);
    Array2::from_shape_fn((n, n), |(jy, jx)| {
        let (my, mx) = (2 * jy, 2 * jx);
        let wk = wf[my] * wf[mx];
        let e = if wk.norm_sqr() > 1e-20 * w00 {
            p.indexed_iter()
                .map(|((y, x), &pv)| {
                    let a = wf[(my + big - y) % big] * wf[(mx + big - x) % big];
                    let b = wk * (df[y] * df[x]).conj() / (n * n) as f64;
                    pv * (a - b).norm_sqr()
                })
                .sum()
        } else {
            conv[[my, mx]].re / (big * big) as f64
        };
        e / wsum2
    })
}

/// The generator's filter, `|k|^-(H+1)` (SPEC §9), in every |k| bin: the
/// mean spectrum of 192 images of 128² equals the exact expectation of
/// [`fbm_expected_density`] within 4 standard errors of the mean (the
/// scatter over the images, which are i.i.d.; 23 bins per H, so a
/// 4-error false alarm in any of the 46 has odds of 0.3 %), and β fitted
/// over all bins from 4 cycles per image to Nyquist on the ensemble equals
/// β fitted on the expectation within 3 jackknife errors
/// (`jackknife_beta_se`), at H = 0.2 and 0.8 (the two share their noises).
///
/// No allowance: the expectation is exact for the cropped, windowed image.
/// Measured (seed 7): the worst bin is 1.9 errors from it (χ² 12.6 and
/// 13.1 on 23 bins), β 2.4150 ± 0.0070 against 2.4153 and 3.6360 ±
/// 0.0069 against 3.6361. A filter exponent off by 0.01 (`H + 1.01`, β
/// off by 0.02, which the 0.044 tolerance of
/// `spectral_exponent_is_2h_plus_2` lets pass) tilts the spectrum by
/// `|k|^-0.02` about 1 rad/px: -2.1 % in the top bin, where the error is
/// 0.3 %; measured with that mutation, the worst bin is 6.8 errors off
/// (the first to fail, at |k| = 2.43, 4.3), while
/// `spectral_exponent_is_2h_plus_2` passes. About 1 s.
#[test]
fn spectrum_is_the_exact_expectation_in_every_bin() {
    let (n, count) = (128, 192u64);
    let (lo, hi) = (
        2.0 * std::f64::consts::PI * 4.0 / n as f64,
        std::f64::consts::PI,
    );
    for h in [0.2, 0.8] {
        let spectra: Vec<PowerSpectrum> = (0..count)
            .into_par_iter()
            .map(|i| {
                let img = fbm(FbmParams { hurst: h }, n, n, 7, i).unwrap();
                power_spectrum(img.view(), &HANN_MEAN).unwrap()
            })
            .collect();
        let exact = PowerSpectrum::from_density(fbm_expected_density(h, n).view(), 4).unwrap();
        let per: Vec<Vec<(f64, f64)>> = spectra.iter().map(|s| s.points()).collect();
        let mut worst: f64 = 0.0;
        for (b, &(k, s)) in exact.points().iter().enumerate() {
            let v: Vec<f64> = per.iter().map(|p| p[b].1).collect();
            let (m, sd) = mean_std(&v);
            let se = sd / (count as f64).sqrt();
            let z = (m - s) / se;
            worst = worst.max(z.abs());
            assert!(
                z.abs() < 4.0,
                "H = {h}, |k| = {k:.4}: mean {m:.5e} +- {se:.2e}, exact {s:.5e} ({z:+.2} errors)"
            );
        }
        let mut total = PowerSpectrum::default();
        for s in &spectra {
            total.merge(s).unwrap();
        }
        let b = total.fit(lo, hi).unwrap().beta;
        let se = jackknife_beta_se(&spectra, lo, hi).unwrap();
        let bx = exact.fit(lo, hi).unwrap().beta;
        eprintln!("H = {h}: worst bin {worst:.2} errors; beta {b:.4} +- {se:.4}, exact {bx:.4}");
        assert!(
            (b - bx).abs() < 3.0 * se,
            "H = {h}: beta {b:.4} +- {se:.4}, exact {bx:.4}"
        );
    }
}

#[test]
fn same_seed_same_bytes_different_seed_differs() {
    let p = FbmParams { hurst: 0.4 };
    let a = fbm(p, 64, 48, 9, 3).unwrap();
    let b = fbm(p, 64, 48, 9, 3).unwrap();
    assert!(a.iter().zip(&b).all(|(x, y)| x.to_bits() == y.to_bits()));
    let c = fbm(p, 64, 48, 10, 3).unwrap();
    let d = fbm(p, 64, 48, 9, 4).unwrap();
    assert!(a.iter().zip(&c).any(|(x, y)| x != y));
    assert!(a.iter().zip(&d).any(|(x, y)| x != y));
    // generating inside a parallel pool of another size gives the same bytes
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(3)
        .build()
        .unwrap();
    let e = pool.install(|| fbm(p, 64, 48, 9, 3).unwrap());
    assert!(a.iter().zip(&e).all(|(x, y)| x.to_bits() == y.to_bits()));
}

#[test]
fn bad_parameters_are_errors() {
    assert!(fbm(FbmParams { hurst: 0.0 }, 64, 64, 1, 0).is_err());
    assert!(fbm(FbmParams { hurst: 1.0 }, 64, 64, 1, 0).is_err());
    assert!(fbm(FbmParams { hurst: f64::NAN }, 64, 64, 1, 0).is_err());
    assert!(fbm(FbmParams { hurst: 0.5 }, 1, 64, 1, 0).is_err());
}
