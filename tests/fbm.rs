//! fBm surfaces (SPEC §9): spectral exponent and reproducibility.

use rayon::prelude::*;
use wtmm::stats::fit::mean_std;
use wtmm::stats::powspec::{PowerSpectrumConfig, default_k_range, power_spectrum};
use wtmm::synth::fbm::{FbmParams, fbm};

/// 16 images of 256x256 per H: the mean of the per-image spectral exponents
/// is within 3 standard errors of the mean (sd / 4, from the ensemble's own
/// scatter) plus 0.03 of β = 2H + 2. The 0.03 allows for the residual
/// leakage of the Hann window on a cropped (non-periodic) field, largest for
/// the steepest spectrum (H = 0.8, β = 3.6).
#[test]
fn spectral_exponent_is_2h_plus_2() {
    let n = 256;
    let cfg = PowerSpectrumConfig::default();
    let (lo, hi) = default_k_range(n);
    for h in [0.2, 0.5, 0.8] {
        let p = FbmParams { hurst: h };
        let betas: Vec<f64> = (0..16u64)
            .into_par_iter()
            .map(|i| {
                let img = fbm(p, n, n, 2024, i).unwrap();
                power_spectrum(img.view(), &cfg)
                    .unwrap()
                    .fit(lo, hi)
                    .unwrap()
                    .beta
            })
            .collect();
        let (m, sd) = mean_std(&betas);
        let tol = 3.0 * sd / 4.0 + 0.03;
        eprintln!(
            "H={h}: beta {m:.3} +- {:.3} (theory {:.3}, tol {tol:.3})",
            sd / 4.0,
            p.beta()
        );
        assert!(
            (m - p.beta()).abs() < tol,
            "H={h}: beta {m:.3} +- {:.3}, theory {}, tol {tol:.3}",
            sd / 4.0,
            p.beta()
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
