//! Random W-cascades on separable orthonormal wavelet bases (II §2.2).
//!
//! The moduli multiply by i.i.d. `M` from one dyadic level to the next, so
//! (II eq 29, 64) with `K(q) = ln <M^q>` the cumulant generating function of
//! `ln M`:
//!
//! ```text
//! τ(q) = -log2 <M^q> - 2 = -K(q)/ln 2 - 2,   h(q) = -K'(q)/ln 2
//! c_k  = κ_k(ln M) / ln 2                     (II eqs 49, 56, 60, 64)
//! β    = τ(2) + 4
//! ```
//!
//! **Log-normal** (`m`, `σ²` mean and variance of `ln M`): `K(q) = mq + σ²q²/2`,
//! `τ(q) = -σ²q²/(2 ln2) - mq/ln2 - 2` (eq 29),
//! `D(h) = 2 - (h + m/ln2)² / (2σ²/ln2)` (eq 30),
//! `h_min, h_max = -m/ln2 ∓ 2σ/√ln2` (eq 32, the zeros of D),
//! `c1 = m/ln2`, `c2 = σ²/ln2`, `c_k = 0` for k >= 3 (eq 56).
//!
//! **Log-Poisson** (`ln M = Y ln β + γ`, `Y ~ Poisson(λ)`):
//! `K(q) = γq + λ(β^q - 1)`, `τ(q) = (λ(1 - β^q) - γq)/ln2 - 2` (eq 37),
//! `h(q) = -(γ + λβ^q ln β)/ln2`, D(h) of eq 38 for `h >= -γ/ln2`
//! (with `0 < β < 1`, `h(q) -> -γ/ln2` as `q -> +∞` where
//! `D -> 2 - λ/ln2`), `c1 = (γ + λ ln β)/ln2`, `c_k = λ (ln β)^k / ln2` (eq 60).
//! `h_min` is `-γ/ln2` when `λ <= 2 ln2` (D stays >= 0 up to the asymptote:
//! for the paper's `λ = 2 ln2` it ends exactly at D = 0), else the zero of D;
//! `h_max` is the zero of D on the right branch (found by bisection).
//!
//! **Convergence (II eq 31).** The paper prints `m < 0` and
//! `|m|/σ² > 2√ln2`. That reading mixes units (m and σ are in units of
//! `ln M`, σ² in their square) and is not the natural condition: the sum
//! over levels of the synthesised function converges to a continuous
//! function when every Hölder exponent it carries is positive,
//! `h_min > 0`. With eq 32, `h_min > 0` ⇔ `-m/ln2 > 2σ/√ln2` ⇔
//! `|m|/σ > 2√ln2` (and `m < 0`): the reading with σ, which we enforce
//! (for both laws, as `h_min > 0`). The paper's parameters satisfy both
//! readings (`|m|/σ = 1.83 > 1.67`).
//!
//! **Magnitude correlation (II eqs 71-76).** With `σ² = Var(ln M)` (natural
//! logarithm; `λ (ln β)²` for log-Poisson, II §5.3 remark), two coefficients
//! whose last common ancestor is `l` levels below the root have
//! `Cov(ln d1, ln d2) = σ² l` (eq 71); averaging over positions at distance
//! `Δx` on an `L`-periodic tree gives (eq 74 -> 76)
//! `C(Δx) = σ² (log2(L/Δx) - 2 + 2Δx/L)` for `sup(a1, a2) <= Δx < L`: the
//! covariance of natural-log magnitudes `ln M` (II eq 67), log2 because the
//! number of shared cascade steps is a dyadic count.

use std::f64::consts::LN_2;

use ndarray::Array2;
use num_complex::Complex64;
use rustfft::FftPlanner;

use super::Multifractal;
use crate::error::Result;
use crate::synth::dwt::dwt1_inverse;
use crate::synth::fisc::steps_for_size;
use crate::synth::wcascade::{Isotropy, Law, WCascadeParams};

impl Law {
    /// `K(q) = ln <M^q>`.
    pub fn ln_moment(&self, q: f64) -> f64 {
        match *self {
            Law::LogNormal { m, sigma2 } => m * q + 0.5 * sigma2 * q * q,
            Law::LogPoisson {
                gamma,
                beta,
                lambda,
            } => gamma * q + lambda * (beta.powf(q) - 1.0),
        }
    }

    /// `τ(q) = -log2 <M^q> - 2` (II eq 29).
    pub fn tau(&self, q: f64) -> f64 {
        -self.ln_moment(q) / LN_2 - 2.0
    }

    /// `h(q) = τ'(q)`.
    pub fn h(&self, q: f64) -> f64 {
        match *self {
            Law::LogNormal { m, sigma2 } => -(m + sigma2 * q) / LN_2,
            Law::LogPoisson {
                gamma,
                beta,
                lambda,
            } => -(gamma + lambda * beta.powf(q) * beta.ln()) / LN_2,
        }
    }

    /// The Legendre transform `D(h)` (II eqs 30, 38) where it is defined;
    /// it can be negative (latent exponents) outside [`Law::h_range`].
    pub fn dh(&self, h: f64) -> Option<f64> {
        match *self {
            Law::LogNormal { m, sigma2 } => {
                let h0 = -m / LN_2;
                if sigma2 == 0.0 {
                    return ((h - h0).abs() <= 1e-12).then_some(2.0);
                }
                Some(2.0 - (h - h0).powi(2) / (2.0 * sigma2 / LN_2))
            }
            Law::LogPoisson {
                gamma,
                beta,
                lambda,
            } => {
                let lb = beta.ln();
                let u = h + gamma / LN_2;
                // x = β^q at the q where h(q) = h
                let x = u / (-(lambda / LN_2) * lb);
                if x < 0.0 {
                    return None;
                }
                if x == 0.0 {
                    return Some(2.0 - lambda / LN_2);
                }
                Some(u / lb * (x.ln() - 1.0) - lambda / LN_2 + 2.0)
            }
        }
    }

    /// `(h_min, h_max)`: the interval where `D(h) >= 0`.
    pub fn h_range(&self) -> (f64, f64) {
        match *self {
            Law::LogNormal { m, sigma2 } => {
                let (h0, w) = (-m / LN_2, 2.0 * sigma2.sqrt() / LN_2.sqrt());
                (h0 - w, h0 + w)
            }
            Law::LogPoisson { gamma, lambda, .. } => {
                let d = |h: f64| self.dh(h).unwrap_or(f64::NEG_INFINITY);
                let h0 = self.h(0.0);
                let h_asym = -gamma / LN_2;
                // left branch: D rises from 2 - λ/ln2 at the asymptote to 2
                let h_min = if 2.0 - lambda / LN_2 >= 0.0 {
                    h_asym
                } else {
                    bisect_zero(&d, h_asym, h0)
                };
                // right branch: D falls from 2 to -∞
                // (steps relative to h0: a fixed step is lost in h0's
                // rounding when h0 is huge, and the search never ended)
                let mut step = h0.abs().max(1.0);
                let mut hi = h0 + step;
                while d(hi) >= 0.0 && hi.is_finite() {
                    step *= 2.0;
                    hi = h0 + step;
                }
                if !hi.is_finite() {
                    return (h_min, f64::INFINITY);
                }
                (h_min, bisect_zero(&d, h0, hi))
            }
        }
    }

    /// `[c1, c2, c3]`, `c_k = κ_k(ln M)/ln 2` (II eqs 56, 60).
    pub fn cumulants(&self) -> [f64; 3] {
        match *self {
            Law::LogNormal { m, sigma2 } => [m / LN_2, sigma2 / LN_2, 0.0],
            Law::LogPoisson {
                gamma,
                beta,
                lambda,
            } => {
                let lb = beta.ln();
                [
                    (gamma + lambda * lb) / LN_2,
                    lambda * lb * lb / LN_2,
                    lambda * lb.powi(3) / LN_2,
                ]
            }
        }
    }

    /// `Var(ln M)`, natural logarithm.
    pub fn ln_variance(&self) -> f64 {
        match *self {
            Law::LogNormal { sigma2, .. } => sigma2,
            Law::LogPoisson { beta, lambda, .. } => lambda * beta.ln().powi(2),
        }
    }
}

/// Zero of a function that changes sign once on `[a, b]` (bisection to the
/// last bit).
fn bisect_zero(f: &impl Fn(f64) -> f64, mut a: f64, mut b: f64) -> f64 {
    let fa_neg = f(a) < 0.0;
    for _ in 0..200 {
        let mid = 0.5 * (a + b);
        if mid <= a || mid >= b {
            break;
        }
        if (f(mid) < 0.0) == fa_neg {
            a = mid;
        } else {
            b = mid;
        }
    }
    0.5 * (a + b)
}

/// II eq 76: `σ² (log2(L/Δx) - 2 + 2Δx/L)` for `0 < Δx < L`, with
/// `σ² = Var(ln M)`; the caller keeps `Δx >= sup(a1, a2)`.
pub fn magnitude_correlation(ln_variance: f64, dx: f64, l: f64) -> Option<f64> {
    (dx > 0.0 && dx < l).then(|| ln_variance * ((l / dx).log2() - 2.0 + 2.0 * dx / l))
}

/// The exact expected power spectrum of an `n x n` W-cascade image of the
/// generator ([`crate::synth::wcascade::wcascade`]), as a density on the
/// FFT grid in standard order, normalised like
/// [`crate::stats::powspec::power_spectrum`] without a window (`k = 0` is
/// 0: the mean is removed).
///
/// Derivation. The image is `f = Σ c B` over the periodic orthonormal basis
/// images `B`, separable: `B = φ_j(x) ψ_j(y)`, `ψ_j(x) φ_j(y)`,
/// `ψ_j(x) ψ_j(y)` for the three detail types at scale `2^j`, tree level
/// `s = N - j` (`N = log2 n`), `4^s` positions, coefficient `2^j w d` with
/// `w` = (cos φ cos θ, cos φ sin θ, sin φ). Below the root the angles are
/// independent and symmetric (θ uniform, φ uniform on `[-φ*, φ*]`, or the
/// fixed choices of the anisotropic variants with a random sign), so
/// distinct coefficients are uncorrelated and
///
/// ```text
/// E|f̂(k)|² = |f̂_0(k)|² + Σ_{s>=1} 4^s 4^j E[d_s²] Σ_t E[w_t²] |B̂_{s,t}(k)|²,
/// E[d_s²] = d_0² E[M²]^s,   E[M²] = 2^(-τ(2)-2)
/// ```
///
/// with `f̂_0` the deterministic root term and `|B̂|² = |û(kx)|² |v̂(ky)|²`
/// from the 1D periodic functions (inverse DWT of a unit coefficient). The
/// infinite cascade has `|k|^-β`, `β = τ(2) + 4`, up to a dyadic modulation;
/// the finite one bends near the root and the pixel (tests/generators.rs).
///
/// **Errors** unless `n` is a power of two >= 2, and on parameters
/// [`WCascadeParams::validate`] refuses (an isotropic law with `τ(2) < -6`
/// has no φ*, II eq 36).
pub fn expected_power(params: &WCascadeParams, n: usize) -> Result<Array2<f64>> {
    params.validate()?;
    let steps = steps_for_size(n)?;
    let fft = FftPlanner::<f64>::new().plan_fft_forward(n);
    // the 1D periodic scaling function and wavelet of scale 2^j, position 0,
    // and their DFTs
    let basis_dft = |j: usize, wavelet: bool| -> Result<Vec<Complex64>> {
        let mut u = vec![0.0; n];
        u[if wavelet { n >> j } else { 0 }] = 1.0;
        dwt1_inverse(&mut u, params.basis, j)?;
        let mut z: Vec<Complex64> = u.iter().map(|&v| Complex64::new(v, 0.0)).collect();
        fft.process(&mut z);
        Ok(z)
    };
    let c0 = params.start_coefficients();
    let d0_2 = c0.iter().map(|c| c * c).sum::<f64>();
    let m2 = 2f64.powf(-params.law.tau(2.0) - 2.0);
    // E[w_t²] below the root
    let ew = match params.isotropy {
        Isotropy::Isotropic => {
            let p = params.phi_star();
            let c2 = 0.5 + (2.0 * p).sin() / (4.0 * p);
            [c2 / 2.0, c2 / 2.0, 1.0 - c2]
        }
        Isotropy::Psi12 => [0.5, 0.5, 0.0],
        Isotropy::Psi3 => [0.0, 0.0, 1.0],
    };
    let mut out = Array2::<f64>::zeros((n, n));
    for s in 0..steps {
        let j = steps - s;
        let phi = basis_dft(j, false)?;
        let psi = basis_dft(j, true)?;
        let l2 = (1u64 << j) as f64;
        if s == 0 {
            // one deterministic coefficient per type: amplitudes add
            for ((ky, kx), v) in out.indexed_iter_mut() {
                let z = (phi[kx] * psi[ky]) * c0[0]
                    + (psi[kx] * phi[ky]) * c0[1]
                    + (psi[kx] * psi[ky]) * c0[2];
                *v += l2 * l2 * z.norm_sqr();
            }
        } else {
            let w = 4f64.powi(s as i32) * l2 * l2 * d0_2 * m2.powi(s as i32);
            let p_phi: Vec<f64> = phi.iter().map(|z| z.norm_sqr()).collect();
            let p_psi: Vec<f64> = psi.iter().map(|z| z.norm_sqr()).collect();
            for ((ky, kx), v) in out.indexed_iter_mut() {
                *v += w
                    * (ew[0] * p_phi[kx] * p_psi[ky]
                        + ew[1] * p_psi[kx] * p_phi[ky]
                        + ew[2] * p_psi[kx] * p_psi[ky]);
            }
        }
    }
    out.mapv_inplace(|v| v / (n * n) as f64);
    out[[0, 0]] = 0.0;
    Ok(out)
}

impl Multifractal for WCascadeParams {
    fn tau(&self, q: f64) -> f64 {
        self.law.tau(q)
    }

    fn h(&self, q: f64) -> f64 {
        self.law.h(q)
    }

    fn dh(&self, h: f64) -> Option<f64> {
        self.law.dh(h)
    }

    fn h_range(&self) -> (f64, f64) {
        self.law.h_range()
    }

    fn cumulants(&self) -> Option<[f64; 3]> {
        Some(self.law.cumulants())
    }

    fn magnitude_correlation(&self, dx: f64, l: f64) -> Option<f64> {
        magnitude_correlation(self.law.ln_variance(), dx, l)
    }
}
