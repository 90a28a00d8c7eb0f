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

use std::f64::consts::LN_2;

use super::Multifractal;
use crate::synth::fisc::FiscParams;

impl FiscParams {
    /// `log2(p^q + (1-p)^q)` without overflow for large |q|.
    fn log2_s(&self, q: f64) -> f64 {
        let (a, b) = (q * self.p.ln(), q * (1.0 - self.p).ln());
        let (hi, lo) = if a > b { (a, b) } else { (b, a) };
        (hi + (lo - hi).exp().ln_1p()) / LN_2
    }

    /// `w(q) = p^q / (p^q + (1-p)^q)`, the weight of the small multiplier.
    fn w(&self, q: f64) -> f64 {
        let t = q * ((1.0 - self.p) / self.p).ln();
        // 1 / (1 + e^t), written to avoid overflow at both ends
        if t > 0.0 {
            let e = (-t).exp();
            e / (1.0 + e)
        } else {
            1.0 / (1.0 + t.exp())
        }
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
        if h < lo - tol || h > hi + tol {
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
        let c2 = ((1.0 - p) / p).ln().powi(2) / (4.0 * LN_2);
        Some([c1, c2, 0.0])
    }
}
