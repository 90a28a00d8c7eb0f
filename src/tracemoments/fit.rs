//! Numerically stable sums and the universal-multifractal fits.

use serde::{Deserialize, Serialize};

/// A sum of positive terms kept as `s · e^m` (log-sum-exp), so that moments
/// of any order neither overflow nor lose the small terms. Starts at
/// `(m, s) = (0, 0)` (always finite, JSON-safe).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct LogSum {
    pub m: f64,
    pub s: f64,
}

impl LogSum {
    /// Adds `s · e^m`.
    pub fn add(&mut self, m: f64, s: f64) {
        if s <= 0.0 || !m.is_finite() {
            return;
        }
        if self.s <= 0.0 {
            *self = LogSum { m, s };
            return;
        }
        if m > self.m {
            self.s = self.s * (self.m - m).exp() + s;
            self.m = m;
        } else {
            self.s += s * (m - self.m).exp();
        }
    }

    pub fn merge(&mut self, o: &LogSum) {
        self.add(o.m, o.s);
    }

    /// `ln` of the sum (`-∞` when empty).
    pub fn ln(&self) -> f64 {
        if self.s > 0.0 {
            self.m + self.s.ln()
        } else {
            f64::NEG_INFINITY
        }
    }

    /// Adds `Σ_i exp(q l_i)` for logs `l` with maximum `lmax` (`q >= 0`).
    pub fn add_powers(&mut self, logs: &[f64], lmax: f64, q: f64) {
        if logs.is_empty() {
            return;
        }
        if q == 0.0 {
            self.add(0.0, logs.len() as f64);
            return;
        }
        if !lmax.is_finite() {
            return; // every term is 0
        }
        let s: f64 = logs.iter().map(|&l| (q * (l - lmax)).exp()).sum();
        self.add(q * lmax, s);
    }
}

/// `(q^α - q)/(α - 1)` (`q ln q` at α = 1): the universal K(q) at C1 = 1.
pub fn universal_shape(alpha: f64, q: f64) -> f64 {
    if q <= 0.0 {
        return 0.0;
    }
    if (alpha - 1.0).abs() < 1e-6 {
        // second-order expansion in (α - 1) keeps the fit smooth across 1
        let l = q.ln();
        let e = alpha - 1.0;
        return q * l + 0.5 * e * q * l * l;
    }
    (q.powf(alpha) - q) / (alpha - 1.0)
}

/// Least-squares fit of `K(q) = C1 (q^α - q)/(α - 1)`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct UniversalFit {
    pub alpha: f64,
    pub alpha_stderr: f64,
    pub c1: f64,
    pub c1_stderr: f64,
    /// Root-mean-square residual.
    pub rms: f64,
    pub n: usize,
}

/// Fits `(α, C1)` to the points `(q, K)` (unweighted least squares: the
/// regression errors of K(q) at neighbouring q are strongly correlated, so
/// weights would only pretend to a precision the data do not have). α is
/// searched in `[0.02, 3]` (values above 2 are not a valid Lévy index but are
/// reported as fitted, not clamped, so the estimator is not biased at 2).
/// For each α the best C1 is linear: `C1 = Σ K f / Σ f²`. Standard errors by
/// the Gauss-Newton covariance `s² (JᵀJ)⁻¹`, `s² = SSE/(n - 2)`.
pub fn fit_universal(q: &[f64], k: &[f64]) -> Option<UniversalFit> {
    let pts: Vec<(f64, f64)> = q
        .iter()
        .zip(k)
        .filter(|(a, b)| **a > 0.0 && a.is_finite() && b.is_finite())
        .map(|(a, b)| (*a, *b))
        .collect();
    if pts.len() < 3 {
        return None;
    }
    let c1_of = |alpha: f64| -> (f64, f64) {
        let (mut kf, mut ff) = (0.0, 0.0);
        for &(qq, kk) in &pts {
            let f = universal_shape(alpha, qq);
            kf += kk * f;
            ff += f * f;
        }
        let c1 = if ff > 0.0 { kf / ff } else { 0.0 };
        let sse: f64 = pts
            .iter()
            .map(|&(qq, kk)| (kk - c1 * universal_shape(alpha, qq)).powi(2))
            .sum();
        (c1, sse)
    };
    // coarse grid then golden-section refinement
    let (lo, hi) = (0.02, 3.0);
    let steps = 149;
    let mut best = (lo, f64::INFINITY);
    for i in 0..=steps {
        let a = lo + (hi - lo) * i as f64 / steps as f64;
        let (_, sse) = c1_of(a);
        if sse < best.1 {
            best = (a, sse);
        }
    }
    let h = (hi - lo) / steps as f64;
    let (mut a, mut b) = ((best.0 - h).max(lo), (best.0 + h).min(hi));
    let g = 0.5 * (5f64.sqrt() - 1.0);
    for _ in 0..80 {
        let x1 = b - g * (b - a);
        let x2 = a + g * (b - a);
        if c1_of(x1).1 < c1_of(x2).1 {
            b = x2;
        } else {
            a = x1;
        }
    }
    let alpha = 0.5 * (a + b);
    let (c1, sse) = c1_of(alpha);
    let n = pts.len();
    // Jacobian of K = C1 f(α, q)
    let e = 1e-5;
    let (mut jaa, mut jac, mut jcc) = (0.0, 0.0, 0.0);
    for &(qq, _) in &pts {
        let da = c1 * (universal_shape(alpha + e, qq) - universal_shape(alpha - e, qq)) / (2.0 * e);
        let dc = universal_shape(alpha, qq);
        jaa += da * da;
        jac += da * dc;
        jcc += dc * dc;
    }
    let det = jaa * jcc - jac * jac;
    let s2 = if n > 2 {
        sse / (n - 2) as f64
    } else {
        f64::NAN
    };
    let (alpha_stderr, c1_stderr) = if det > 0.0 {
        ((s2 * jcc / det).sqrt(), (s2 * jaa / det).sqrt())
    } else {
        (f64::NAN, f64::NAN)
    };
    Some(UniversalFit {
        alpha,
        alpha_stderr,
        c1,
        c1_stderr,
        rms: (sse / n as f64).sqrt(),
        n,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn logsum_matches_plain_sum() {
        let mut a = LogSum::default();
        let logs = [0.5f64, -3.0, 2.0, 700.0];
        let lmax = 700.0;
        a.add_powers(&logs, lmax, 1.5);
        // dominated by e^{1050}: ln = 1050 + ln(1 + tiny)
        assert!((a.ln() - 1050.0).abs() < 1e-12);
        let mut b = LogSum::default();
        b.add_powers(&logs[..3], 2.0, 2.0);
        let plain: f64 = logs[..3].iter().map(|l| (2.0 * l).exp()).sum();
        assert!((b.ln() - plain.ln()).abs() < 1e-12);
        let mut c = LogSum::default();
        c.merge(&b);
        c.merge(&b);
        assert!((c.ln() - (2.0 * plain).ln()).abs() < 1e-12);
    }

    #[test]
    fn universal_fit_exact() {
        let q: Vec<f64> = (1..=25).map(|i| i as f64 * 0.1).collect();
        for (alpha, c1) in [(1.8, 0.12), (2.0, 0.1), (1.0, 0.2), (0.6, 0.05)] {
            let k: Vec<f64> = q.iter().map(|&v| c1 * universal_shape(alpha, v)).collect();
            let f = fit_universal(&q, &k).unwrap();
            assert!((f.alpha - alpha).abs() < 1e-4, "{alpha}: {f:?}");
            assert!((f.c1 - c1).abs() < 1e-5, "{c1}: {f:?}");
        }
    }
}
