//! Fractional Brownian surfaces B_H (SPEC §9; paper I §5): monofractal,
//! `τ(q) = qH - 2`, `h(q) = H`, `D(q) = 2`, `D(H) = 2` (a single point),
//! `β = 2H + 2`. Through II eq 64 the kernel is a pure shift: `c1 = -H`,
//! `c_k = 0` for `k >= 2`. The magnitudes are uncorrelated beyond the
//! analysing scale (II Fig 30b): `C(Δx) = 0`.

use super::Multifractal;
use crate::synth::fbm::FbmParams;

impl Multifractal for FbmParams {
    fn tau(&self, q: f64) -> f64 {
        q * self.hurst - 2.0
    }

    fn h(&self, _q: f64) -> f64 {
        self.hurst
    }

    /// `Some(2)` at `h = H` (to 1e-12), `None` elsewhere.
    fn dh(&self, h: f64) -> Option<f64> {
        ((h - self.hurst).abs() <= 1e-12).then_some(2.0)
    }

    fn h_range(&self) -> (f64, f64) {
        (self.hurst, self.hurst)
    }

    fn cumulants(&self) -> Option<[f64; 3]> {
        Some([-self.hurst, 0.0, 0.0])
    }

    fn magnitude_correlation(&self, dx: f64, l: f64) -> Option<f64> {
        (dx > 0.0 && dx < l).then_some(0.0)
    }
}
