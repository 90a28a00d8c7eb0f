//! Extremal (maximally skewed) Lévy-stable variables, the sub-generator of
//! universal multifractals (TM §3.2-3.3, SIM Table 1).
//!
//! # Convention
//! [`extremal_levy`] returns the *unit extremal* variable `Y` of index
//! `α ∈ (0, 2]` whose second characteristic function (log-Laplace transform)
//! is, for every real `s >= 0`,
//!
//! ```text
//! ln <exp(s Y)> = (s^α - s) / (α - 1)     (α != 1)
//! ln <exp(s Y)> = s ln s                  (α  = 1, the limit of the line above)
//! ```
//!
//! so `<exp(Y)> = 1` and `<exp(qY)> = exp(K(q))` with the universal
//! `K(q) = (q^α - q)/(α - 1)` at `C1 = 1`. This is the skewness that makes
//! the exponential of the noise have finite positive moments: in the
//! Samorodnitsky-Taqqu parametrisation `Y ~ S_α(σ, β = -1, μ)` (heavy tail on
//! the *negative* side only, `P(Y < -x) ~ x^-α`), with scale
//! `σ^α = cos(πα/2)/(1 - α)` (`σ = π/2` at α = 1, `σ = 1` at α = 2) and shift
//! `μ = -1/(α - 1)` (`0` at α = 1). For α < 1 the variable is bounded above
//! (`Y <= 1/(1 - α)`).
//!
//! At α = 2, `Y ~ N(-1, 2)`: the *variance convention* of stable laws
//! (`S_2(σ) = N(0, 2σ²)`), which is also the universal-multifractal one
//! (a log-normal generator with `<exp(qY)> = exp(q² - q)`).
//!
//! Characteristic function (the same formula at `s = it`, on the boundary of
//! its half-plane of analyticity `Re s > 0`):
//! `<exp(itY)> = exp(((it)^α - it)/(α - 1))`, `(it)^α = |t|^α e^{iπα sgn(t)/2}`
//! (α != 1); `exp(it ln(it)) = exp(-|t|π/2 + it ln|t|)` at α = 1.
//!
//! # Algorithm
//! Chambers, Mallows & Stuck (1976) in Weron's (1996) form, with
//! `V ~ U(-π/2, π/2)` and `W ~ Exp(1)`:
//!
//! ```text
//! α != 1:  X = |α-1|^(-1/α) sin(α(V + B)) / cos(V)^(1/α) · (cos(V - α(V + B)) / W)^((1-α)/α),
//!          B = arctan(-tan(πα/2)) / α,          Y = X - 1/(α - 1)
//! α  = 1:  Y = (π/2 - V) tan V + ln(W cos V / (π/2 - V))
//! ```
//!
//! (`|α-1|^(-1/α)` is `σ (1 + tan²(πα/2))^(1/2α)` for the σ above.) Within
//! `1e-9` of α = 1 the α = 1 formula is used: the general one loses about
//! `log10(1/|α-1|)` digits to the cancellation of `X` against `1/(α-1)`.

use rand::{Rng, RngExt};
use rand_distr::{Distribution, Exp1};

use crate::error::{Error, Result};

use std::f64::consts::FRAC_PI_2;

/// Within this distance of 1, α is treated as exactly 1.
const ALPHA_ONE_EPS: f64 = 1e-9;

/// Whether α is taken as 1 (the α = 1 forms of the generator and of the
/// closed forms in [`crate::theory::fif`]: one test for both, so that no α
/// gets the α = 1 form in one quantity and the α ≠ 1 form in another).
pub(crate) fn alpha_is_one(alpha: f64) -> bool {
    (alpha - 1.0).abs() <= ALPHA_ONE_EPS
}

/// **Errors** unless `0 < α <= 2`.
pub fn validate_alpha(alpha: f64) -> Result<()> {
    if !(alpha > 0.0 && alpha <= 2.0) {
        return Err(Error::param(
            "alpha",
            format!(
                "the Lévy index must be in (0, 2], got {alpha_s}",
                alpha_s = crate::error::short(alpha)
            ),
        ));
    }
    Ok(())
}

/// A sampler of the unit extremal Lévy variable of index α (module docs),
/// with the constants of the Chambers-Mallows-Stuck formula precomputed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ExtremalLevy {
    alpha: f64,
    /// `B = arctan(-tan(πα/2))/α` (unused at α = 1).
    b: f64,
    /// `|α-1|^(-1/α)`.
    scale: f64,
    /// `-1/(α-1)`.
    shift: f64,
    one: bool,
}

impl ExtremalLevy {
    /// **Errors** unless `0 < α <= 2`.
    pub fn new(alpha: f64) -> Result<Self> {
        validate_alpha(alpha)?;
        let one = alpha_is_one(alpha);
        let (b, scale, shift) = if one {
            (0.0, 1.0, 0.0)
        } else {
            // α in (1, 2]: tan(πα/2) <= 0 and arctan(-tan) = π - πα/2 (0 at α = 2);
            // α < 1: arctan(-tan(πα/2)) = -πα/2
            let b = if alpha > 1.0 {
                (std::f64::consts::PI - FRAC_PI_2 * alpha) / alpha
            } else {
                -FRAC_PI_2
            };
            (
                b,
                (alpha - 1.0).abs().powf(-1.0 / alpha),
                -1.0 / (alpha - 1.0),
            )
        };
        Ok(ExtremalLevy {
            alpha,
            b,
            scale,
            shift,
            one,
        })
    }

    /// The index α.
    pub fn alpha(&self) -> f64 {
        self.alpha
    }

    /// One sample of `Y`.
    #[inline]
    pub fn sample<R: Rng + ?Sized>(&self, rng: &mut R) -> f64 {
        // V in (-π/2, π/2): reject the endpoint, where cos V = 0
        let v = loop {
            let u: f64 = rng.random::<f64>();
            if u > 0.0 {
                break FRAC_PI_2 * (2.0 * u - 1.0);
            }
        };
        let w: f64 = loop {
            let w: f64 = Exp1.sample(rng);
            if w > 0.0 {
                break w;
            }
        };
        if self.one {
            let a = FRAC_PI_2 - v;
            return a * v.tan() + (w * v.cos() / a).ln();
        }
        let a = self.alpha;
        let vb = a * (v + self.b);
        let x = self.scale * vb.sin() / v.cos().powf(1.0 / a)
            * ((v - vb).cos() / w).powf((1.0 - a) / a);
        x + self.shift
    }

    /// `ln <exp(sY)>` for `s >= 0` (module docs).
    pub fn log_laplace(&self, s: f64) -> f64 {
        if s == 0.0 {
            return 0.0;
        }
        if self.one {
            s * s.ln()
        } else {
            (s.powf(self.alpha) - s) / (self.alpha - 1.0)
        }
    }
}

/// One unit extremal Lévy sample of index α (module docs). For many samples
/// build an [`ExtremalLevy`] once.
///
/// **Errors** unless `0 < α <= 2`.
pub fn extremal_levy<R: Rng + ?Sized>(alpha: f64, rng: &mut R) -> Result<f64> {
    Ok(ExtremalLevy::new(alpha)?.sample(rng))
}

/// `n` unit extremal Lévy samples of index α drawn from `rng`.
///
/// **Errors** unless `0 < α <= 2`.
pub fn extremal_levy_vec<R: Rng + ?Sized>(alpha: f64, n: usize, rng: &mut R) -> Result<Vec<f64>> {
    let d = ExtremalLevy::new(alpha)?;
    Ok((0..n).map(|_| d.sample(rng)).collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::rng_for;
    use num_complex::Complex64;

    /// Sample mean of `exp(sY)` against `exp(ln<exp(sY)>)`. The standard error
    /// of the mean of `exp(sY)` is `sqrt((<e^{2sY}> - <e^{sY}>²)/n)`, known in
    /// closed form; we allow 5 of them (a false alarm once in ~2 million runs
    /// for a Gaussian mean; the draws are fixed by the seed anyway).
    fn check_laplace(alpha: f64, s: f64, y: &[f64]) {
        let d = ExtremalLevy::new(alpha).unwrap();
        let n = y.len() as f64;
        let m = y.iter().map(|v| (s * v).exp()).sum::<f64>() / n;
        let th = d.log_laplace(s).exp();
        let var = d.log_laplace(2.0 * s).exp() - th * th;
        let se = (var / n).sqrt();
        assert!(
            (m - th).abs() < 5.0 * se,
            "alpha {alpha} s {s}: <e^sY> = {m}, theory {th} +- {se}"
        );
    }

    /// Empirical characteristic function against the closed form. Each of the
    /// real and imaginary parts is a mean of bounded variables with variance
    /// <= 1/2 (cos² + sin² = 1), so 5 sqrt(1/(2n)) bounds the error.
    fn check_cf(alpha: f64, t: f64, y: &[f64]) {
        let n = y.len() as f64;
        let (mut re, mut im) = (0.0, 0.0);
        for &v in y {
            re += (t * v).cos();
            im += (t * v).sin();
        }
        let emp = Complex64::new(re / n, im / n);
        let it = Complex64::new(0.0, t);
        let th = if alpha_is_one(alpha) {
            (it * it.ln()).exp()
        } else {
            // (it)^α on the principal branch: |t|^α e^{iπα sgn(t)/2}
            let p = Complex64::from_polar(t.abs().powf(alpha), FRAC_PI_2 * alpha * t.signum());
            ((p - it) / (alpha - 1.0)).exp()
        };
        let tol = 5.0 * (0.5 / n).sqrt();
        assert!(
            (emp.re - th.re).abs() < tol && (emp.im - th.im).abs() < tol,
            "alpha {alpha} t {t}: cf {emp}, theory {th}, tol {tol}"
        );
    }

    fn draws(alpha: f64, n: usize, index: u64) -> Vec<f64> {
        let mut rng = rng_for(0x1e_57, index);
        extremal_levy_vec(alpha, n, &mut rng).unwrap()
    }

    #[test]
    fn gaussian_at_alpha_two() {
        // Y ~ N(-1, 2): mean -1, variance 2, excess kurtosis 0. Standard
        // errors for n Gaussian draws: mean sqrt(2/n); variance 2 sqrt(2/n);
        // kurtosis sqrt(24/n). Tolerance 5 standard errors.
        let n = 200_000;
        let y = draws(2.0, n, 1);
        let nf = n as f64;
        let m = y.iter().sum::<f64>() / nf;
        let v = y.iter().map(|a| (a - m).powi(2)).sum::<f64>() / nf;
        let k = y.iter().map(|a| (a - m).powi(4)).sum::<f64>() / nf / (v * v);
        assert!((m + 1.0).abs() < 5.0 * (2.0 / nf).sqrt(), "mean {m}");
        assert!((v - 2.0).abs() < 5.0 * 2.0 * (2.0 / nf).sqrt(), "var {v}");
        assert!((k - 3.0).abs() < 5.0 * (24.0 / nf).sqrt(), "kurtosis {k}");
        check_laplace(2.0, 1.0, &y);
    }

    #[test]
    fn laplace_and_cf_match_alpha() {
        let n = 200_000;
        for (i, &alpha) in [1.5, 1.8, 1.0, 0.6].iter().enumerate() {
            let y = draws(alpha, n, 10 + i as u64);
            // <e^{sY}> needs <e^{2sY}> finite for its error bar: every s > 0 is fine
            for s in [0.5, 1.0, 1.5] {
                check_laplace(alpha, s, &y);
            }
            for t in [-2.0, -0.5, 0.3, 1.0, 3.0] {
                check_cf(alpha, t, &y);
            }
        }
    }

    #[test]
    fn alpha_near_one_is_continuous() {
        // the general formula just off α = 1 must agree with the limit law
        let y = draws(1.0 + 1e-6, 100_000, 30);
        check_laplace(1.0, 1.0, &y);
        check_cf(1.0, 1.0, &y);
    }

    #[test]
    fn left_tail_exponent() {
        // P(Y < -x) ~ c x^-α: the Hill estimator on the k largest values of
        // -Y has standard error α/sqrt(k); the second-order term of stable
        // tails biases it upward, by little at α = 1.5 for the top 0.5%.
        // Allow 4 standard errors plus 0.05 for that bias. (At α = 1.8 the
        // Pareto regime starts much further out: Hill gives 2.14 on the top
        // 0.5% of 400k draws, so the exponent is checked through the Laplace
        // transform and the characteristic function instead.)
        let n = 400_000;
        for (i, &alpha) in [1.5].iter().enumerate() {
            let mut z: Vec<f64> = draws(alpha, n, 40 + i as u64)
                .into_iter()
                .map(|v| -v)
                .collect();
            z.sort_by(|a, b| b.total_cmp(a));
            let k = n / 200;
            let xk = z[k];
            let hill = k as f64 / z[..k].iter().map(|v| (v / xk).ln()).sum::<f64>();
            let tol = 4.0 * alpha / (k as f64).sqrt() + 0.05;
            assert!(
                (hill - alpha).abs() < tol,
                "alpha {alpha}: hill {hill} tol {tol}"
            );
            // and the right side is light: no sample far above the mean
            assert!(z[n - 1] > -10.0, "right tail too heavy: {}", -z[n - 1]);
        }
    }

    #[test]
    fn bounded_above_for_alpha_below_one() {
        let y = draws(0.5, 50_000, 50);
        assert!(y.iter().all(|&v| v <= 1.0 / (1.0 - 0.5) + 1e-9));
    }

    #[test]
    fn rejects_bad_alpha() {
        for a in [0.0, -1.0, 2.1, f64::NAN] {
            let e = ExtremalLevy::new(a).unwrap_err().to_string();
            assert!(e.contains("alpha"), "{e}");
        }
    }
}
