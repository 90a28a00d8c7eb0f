//! Fractionally integrated singular cascades (II §2.1).
//!
//! With `S(q) = p^q + (1-p)^q` and `w(q) = p^q / S(q)`:
//!
//! ```text
//! τ(q) = -1 - q(1-H*) - log2 S(q)                          (II eq 8)
//! h(q) = τ'(q) = H* - 1 - w log2 p - (1-w) log2(1-p)
//! D(h) = 1 + H2(w),  w = (H* - 1 - h - log2(1-p)) / log2(p/(1-p))
//! β    = τ(2) + 4 = 1 + 2H* - log2(2p² - 2p + 1)           (II eq 11)
//! h_min = H* - 1 - log2(1-p),  h_max = H* - 1 - log2 p     (II eqs 12-13)
//! ```
//!
//! `H2(w) = -w log2 w - (1-w) log2(1-w)` is the binary entropy: `D(h)` runs
//! from 1 at both ends of `[h_min, h_max]` (two of the four children carry
//! each weight, a set of dimension 1) to 2 at `h(0)`.
//!
//! Kernel cumulants through II eq 64 (`τ(q) = -Σ c_k q^k/k! - 2`): with `X`
//! equal to `p` or `1-p` with probability 1/2, `-(τ(q) + 2) = q(1-H*) +
//! log2 <X^q>`, so `c1 = 1 - H* + (log2 p + log2(1-p))/2`,
//! `c2 = (ln((1-p)/p))² / (4 ln 2)`, `c3 = 0` (symmetric two-point law).
//! They describe τ(q) exactly; the WTMM self-similarity kernel of a FISC is a
//! discrete-cascade kernel blurred by the fractional integration, so expect
//! agreement only in the mean behaviour.
//!
//! β is the exponent of the infinite cascade. An image stops the cascade at
//! the pixel: [`FiscParams::expected_power`] gives its exact expected
//! spectrum, whose local slope falls below β near the pixel scale (the
//! finest levels alias into a nearly white floor; see its docs).

use std::f64::consts::LN_2;

use ndarray::Array2;

use super::Multifractal;
use crate::error::Result;
use crate::synth::fisc::{FiscParams, steps_for_size};

impl FiscParams {
    /// `log2(p^q + (1-p)^q)` without overflow for large |q|.
    fn log2_s(&self, q: f64) -> f64 {
        let (a, b) = (q * self.p.ln(), q * (1.0 - self.p).ln());
        let (hi, lo) = if a > b { (a, b) } else { (b, a) };
        (hi + (lo - hi).exp().ln_1p()) / LN_2
    }

    /// `w(q) = p^q / (p^q + (1-p)^q)`, the weight of the small multiplier.
    fn w(&self, q: f64) -> f64 {
        // the log of the ratio, not of (1-p)/p: that overflows for a subnormal p
        let t = q * ((1.0 - self.p).ln() - self.p.ln());
        // 1 / (1 + e^t), written to avoid overflow at both ends
        if t > 0.0 {
            let e = (-t).exp();
            e / (1.0 + e)
        } else {
            1.0 / (1.0 + t.exp())
        }
    }
}

impl FiscParams {
    /// Exact expected power `E|f̂(k)|² / n²` of the `n x n` FISC of
    /// [`crate::synth::fisc::fisc`] at every DFT mode, `[ky, kx]` in FFT
    /// order, normalised like [`crate::stats::powspec::power_spectrum`]
    /// without a window (`k = 0` is 0: the filter removes it).
    ///
    /// Derivation (II eqs 1-3, 6). The density is `ρ(x) = Π_i m_i` with
    /// multipliers `m ∈ {2p, 2(1-p)}`, two of each per split, uniform over
    /// the 6 pairs. Two pixels whose last common cell is at level `L` have
    /// `E[ρ(x)ρ(y)] = v_L`: `v_L = g^L c` (`L < n`), `v_n = g^n`, with
    /// `g = E[m²] = 2(p² + (1-p)²)` and, for two distinct siblings,
    /// `c = E[m_a m_b] = (16 - 4g)/12` (from `Σ m = 4`). Writing
    /// `v_L = Σ_{j<=L} a_j` and summing over the `4^j` cells of side
    /// `s = n/2^j`, each with the Dirichlet kernel
    /// `D_s(k) = sin²(ks/2)/sin²(k/2)` per axis:
    ///
    /// ```text
    /// E|μ̂(k)|² = Σ_j a_j 4^j D_s(kx) D_s(ky),   E|f̂|² = A² |k|^-2H* E|μ̂|²
    /// ```
    ///
    /// The infinite cascade has `S ~ |k|^-β` (II eq 11), up to a dyadic
    /// modulation of the local slope of about ±0.6 within each octave. The
    /// pixel grid ends the cascade: the finest levels have a flat `D_s` and
    /// act as a nearly white floor, so the octave-averaged local slope falls
    /// below β near the pixel scale (paper preset: 2.93 at |k| = 1, 3.01 at
    /// 0.72, 3.055 at 0.51, 3.09 at 0.2 rad/px), the same at every `n`.
    ///
    /// **Errors** unless `n` is a power of two >= 2, and on parameters
    /// [`FiscParams::validate`] refuses.
    pub fn expected_power(&self, n: usize) -> Result<Array2<f64>> {
        self.validate()?;
        let steps = steps_for_size(n)?;
        let p = self.p;
        let g = 2.0 * (p * p + (1.0 - p) * (1.0 - p));
        let c = (16.0 - 4.0 * g) / 12.0;
        let v = |l: usize| {
            if l < steps {
                g.powi(l as i32) * c
            } else {
                g.powi(steps as i32)
            }
        };
        // a_j 4^j, and the 1D kernels D_s per level at the n frequencies
        let w: Vec<f64> = (0..=steps)
            .map(|j| {
                let a = if j == 0 { v(0) } else { v(j) - v(j - 1) };
                a * 4f64.powi(j as i32)
            })
            .collect();
        let k1: Vec<f64> = (0..n).map(|m| crate::fourier::angular_freq(m, n)).collect();
        let d: Vec<Vec<f64>> = (0..=steps)
            .map(|j| {
                let s = (n >> j) as f64;
                k1.iter()
                    .map(|&k| {
                        let den = (k / 2.0).sin();
                        if den.abs() < 1e-12 {
                            s * s
                        } else {
                            ((k * s / 2.0).sin() / den).powi(2)
                        }
                    })
                    .collect()
            })
            .collect();
        let amp2 = self.amplitude().powi(2) / (n * n) as f64;
        Ok(Array2::from_shape_fn((n, n), |(y, x)| {
            let k2 = k1[x] * k1[x] + k1[y] * k1[y];
            if k2 == 0.0 {
                return 0.0;
            }
            let mu2: f64 = (0..=steps).map(|j| w[j] * d[j][x] * d[j][y]).sum();
            amp2 * k2.powf(-self.hstar) * mu2
        }))
    }
}

impl Multifractal for FiscParams {
    fn tau(&self, q: f64) -> f64 {
        -1.0 - q * (1.0 - self.hstar) - self.log2_s(q)
    }

    fn h(&self, q: f64) -> f64 {
        let w = self.w(q);
        self.hstar - 1.0 - w * self.p.log2() - (1.0 - w) * (1.0 - self.p).log2()
    }

    /// `1 + H2(w(h))` on `[h_min, h_max]` (to 1e-12), `None` outside; at
    /// `p = 1/2` only `D(H*) = 2`.
    fn dh(&self, h: f64) -> Option<f64> {
        let (lo, hi) = self.h_range();
        let tol = 1e-12;
        if hi - lo < tol {
            return ((h - self.hstar).abs() <= tol).then_some(2.0);
        }
        // (written so that a NaN h is outside too)
        if !(h >= lo - tol && h <= hi + tol) {
            return None;
        }
        let w = ((self.hstar - 1.0 - h - (1.0 - self.p).log2())
            / (self.p.log2() - (1.0 - self.p).log2()))
        .clamp(0.0, 1.0);
        let xlx = |x: f64| if x > 0.0 { x * x.log2() } else { 0.0 };
        Some(1.0 - xlx(w) - xlx(1.0 - w))
    }

    fn h_range(&self) -> (f64, f64) {
        (
            self.hstar - 1.0 - (1.0 - self.p).log2(),
            self.hstar - 1.0 - self.p.log2(),
        )
    }

    fn beta(&self) -> f64 {
        let p = self.p;
        1.0 + 2.0 * self.hstar - (2.0 * p * p - 2.0 * p + 1.0).log2()
    }

    fn cumulants(&self) -> Option<[f64; 3]> {
        let p = self.p;
        let c1 = 1.0 - self.hstar + 0.5 * (p.log2() + (1.0 - p).log2());
        let c2 = ((1.0 - p).ln() - p.ln()).powi(2) / (4.0 * LN_2);
        Some([c1, c2, 0.0])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A subnormal p is a valid model (the generator draws it): the
    /// weights and c2 use the log of the ratio, since `(1-p)/p` overflows
    /// (h(0) was NaN, c2 null). h(0) = H* - 1 - ½ log2(p(1-p)), c2 =
    /// ln²((1-p)/p) / (4 ln 2), here with 1 - p = 1.
    #[test]
    fn subnormal_p_gives_finite_spectra() {
        let prm = FiscParams {
            p: 1e-310,
            hstar: 0.5,
        };
        prm.validate().unwrap();
        let m = crate::theory::Model::Fisc(prm);
        let lp = prm.p.ln();
        let h0 = m.h_of_q0();
        let want = prm.hstar - 1.0 - 0.5 * lp / LN_2;
        assert!((h0 - want).abs() < 1e-9 * want, "{h0} vs {want}");
        let c = m.cumulants().unwrap();
        assert!((c[1] - lp * lp / (4.0 * LN_2)).abs() < 1e-9 * c[1], "{c:?}");
        for q in [-4.0, -1.0, 0.0, 1.0, 4.0] {
            assert!(m.tau(q).is_finite() && m.h(q).is_finite(), "q = {q}");
        }
    }

    /// p = 1/2 is the uniform measure: no power off k = 0.
    #[test]
    fn uniform_measure_has_no_power() {
        let prm = FiscParams { p: 0.5, hstar: 0.6 };
        let s = prm.expected_power(16).unwrap();
        assert!(s.iter().all(|v| v.abs() < 1e-12), "{s:?}");
    }

    /// Brute force on 4x4 (two steps): average `|f̂|²/n²` over all 6^5
    /// equally likely choices of the pairs, each transformed by a direct DFT.
    #[test]
    fn matches_enumeration_on_4x4() {
        let prm = FiscParams { p: 0.3, hstar: 0.6 };
        let n = 4usize;
        let pairs: Vec<[f64; 4]> = (0..4)
            .flat_map(|a| (a + 1..4).map(move |b| (a, b)))
            .map(|(a, b)| {
                let mut m = [2.0 * (1.0 - prm.p); 4];
                m[a] = 2.0 * prm.p;
                m[b] = 2.0 * prm.p;
                m
            })
            .collect();
        assert_eq!(pairs.len(), 6);
        let two_pi = 2.0 * std::f64::consts::PI;
        let mut mean = Array2::<f64>::zeros((n, n));
        let configs = 6usize.pow(5);
        for cfg in 0..configs {
            let (top, mut rest) = (cfg % 6, cfg / 6);
            let mut rho = Array2::<f64>::zeros((n, n));
            for parent in 0..4 {
                let (py, px) = (parent / 2, parent % 2);
                let sub = &pairs[rest % 6];
                rest /= 6;
                for (child, &m) in sub.iter().enumerate() {
                    let (y, x) = (2 * py + child / 2, 2 * px + child % 2);
                    rho[[y, x]] = pairs[top][parent] * m;
                }
            }
            for ((ky, kx), acc) in mean.indexed_iter_mut() {
                let (mut re, mut im) = (0.0, 0.0);
                for ((y, x), &r) in rho.indexed_iter() {
                    let ph = two_pi * (kx * x + ky * y) as f64 / n as f64;
                    re += r * ph.cos();
                    im -= r * ph.sin();
                }
                *acc += (re * re + im * im) / configs as f64;
            }
        }
        let got = prm.expected_power(n).unwrap();
        let amp2 = prm.amplitude().powi(2) / (n * n) as f64;
        for ((ky, kx), &g) in got.indexed_iter() {
            let f = |m: usize| two_pi * (if m <= n / 2 { m as f64 } else { m as f64 - 4.0 }) / 4.0;
            let k2 = f(kx).powi(2) + f(ky).powi(2);
            let want = if k2 == 0.0 {
                0.0
            } else {
                amp2 * k2.powf(-prm.hstar) * mean[[ky, kx]]
            };
            assert!(
                (g - want).abs() <= 1e-12 * want.abs().max(1.0),
                "({ky}, {kx}): {g} vs {want}"
            );
        }
    }
}
