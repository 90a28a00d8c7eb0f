//! The reconstruction check of II Fig 29: `P_a'` pushed through the
//! estimated kernel and set against the measured `P_a` (II eq 41).

use num_complex::Complex64;
use rustfft::FftPlanner;
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::stats::pdf::WtmmmHistograms;

/// One reconstruction of II Fig 29: `P_a'` pushed through the kernel to `a`,
/// with the measured `P_a`, on the `ln M` bin centres.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Reconstruction {
    /// Source scale `a' > a`, in pixels.
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub a_from: f64,
    /// Target scale `a`, in pixels.
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub a_to: f64,
    /// `ln(a'/a)`.
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub ln_ratio: f64,
    /// Cumulants `c_1..c_n` of the kernel used.
    #[serde(deserialize_with = "crate::nan_null::vec")]
    pub c: Vec<f64>,
    /// Centres of the `ln M` bins at the target scale.
    #[serde(deserialize_with = "crate::nan_null::vec")]
    pub ln_m: Vec<f64>,
    /// Density of `ln M` at `a_to`: measured, and predicted from `a_from`.
    #[serde(deserialize_with = "crate::nan_null::vec")]
    pub measured: Vec<f64>,
    /// The predicted density (same bins).
    #[serde(deserialize_with = "crate::nan_null::vec")]
    pub predicted: Vec<f64>,
    /// `∫ |predicted - measured| d ln M` (0 = perfect, 2 = disjoint).
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub l1: f64,
}

/// Largest shift plus spread of `ln M` a [`reconstruct`] kernel may have.
const MAX_KERNEL_REACH: f64 = 100.0;

/// II eq 41 / Fig 29: the density of `ln M` at each source scale `from[i]`
/// convolved with the kernel `Ĝ_aa'(p) = exp(ln(a'/a) Σ_n c_n (ip)^n/n!)`
/// (the cumulants `c = [c1, c2(, c3 ...)]`; two give the Gaussian kernel of
/// II eq 55), compared with the measured density at `to`. The convolution
/// is done by FFT on the histogram's `ln M` grid, zero-padded so that nothing
/// wraps around.
///
/// **Errors** if a scale index is out of range, a source is not larger than
/// the target, `c` is empty or not finite, the kernel moves `ln M` by more
/// than 100 between the scales, `c2 < 0` (then `|Ĝ|` grows like
/// `exp(|c2| s p^2 / 2)`: no probability density, and the counting noise
/// of the histogram is amplified without bound; a measured c2 below 0, as
/// on a monofractal, calls for the shift `c = [c1]`), or a histogram is
/// empty.
pub fn reconstruct(
    h: &WtmmmHistograms,
    to: usize,
    from: &[usize],
    c: &[f64],
) -> Result<Vec<Reconstruction>> {
    let ns = h.scales.len();
    if c.is_empty() || c.iter().any(|v| !v.is_finite()) {
        return Err(Error::param("cumulants", "need finite c1, c2, ..."));
    }
    if c.len() > 1 && c[1] < 0.0 {
        return Err(Error::param(
            "cumulants",
            format!(
                "c2 = {} < 0 gives no probability density (the kernel would amplify \
                 the histogram's noise without bound); use c1 alone for a shift",
                c[1]
            ),
        ));
    }
    if to >= ns || from.iter().any(|&f| f >= ns || f <= to) {
        return Err(Error::param(
            "scales",
            "need source scales larger than the target, all on the grid",
        ));
    }
    let d = h.config.dlnm;
    let ht = &h.hist[to];
    if ht.n == 0 {
        return Err(Error::Input(format!(
            "no WTMMM at the target scale {:.2}",
            h.scales[to]
        )));
    }
    let (_, p_to) = h.ln_m_density(to);
    let mut out = Vec::with_capacity(from.len());
    for &fr in from {
        let hf = &h.hist[fr];
        if hf.n == 0 {
            return Err(Error::Input(format!(
                "no WTMMM at the source scale {:.2}",
                h.scales[fr]
            )));
        }
        let (_, p_from) = h.ln_m_density(fr);
        let s = (h.scales[fr] / h.scales[to]).ln();
        // kernel extent in bins: shift plus 12 standard deviations
        let var = (c.get(1).copied().unwrap_or(0.0) * s).max(0.0);
        let reach = (c[0] * s).abs() + 12.0 * var.sqrt();
        // a kernel that moves ln M by more than e^100 between two scales of
        // one image is no kernel of these data (and its FFT grid would
        // not fit in memory: c1 = 1e8 asked for 137 GB)
        if !(reach <= MAX_KERNEL_REACH) {
            return Err(Error::param(
                "cumulants",
                format!(
                    "the kernel from a = {:.2} to {:.2} moves ln M by {} (|c1| s + 12 sqrt(c2 s)), \
                     more than {MAX_KERNEL_REACH}: not a kernel of WTMMM moduli",
                    h.scales[fr],
                    h.scales[to],
                    crate::error::short(reach)
                ),
            ));
        }
        let ext = reach / d + 8.0;
        let ext = ext.ceil() as i64;
        let lo = ht.lo.min(hf.lo) - ext;
        let hi = (ht.lo + ht.rows as i64).max(hf.lo + hf.rows as i64) + ext;
        let len = (hi - lo) as usize;
        let nfft = (2 * len).next_power_of_two();
        let mut buf = vec![Complex64::default(); nfft];
        for (r, &v) in p_from.iter().enumerate() {
            buf[(hf.lo - lo) as usize + r] = Complex64::new(v, 0.0);
        }
        let mut planner = FftPlanner::<f64>::new();
        planner.plan_fft_forward(nfft).process(&mut buf);
        // X_k = Σ x_j e^{-2πi jk/N} is the characteristic function at
        // p = -2π k / (N d): multiply by Ĝ there
        for (k, z) in buf.iter_mut().enumerate() {
            let ks = if k <= nfft / 2 {
                k as f64
            } else {
                k as f64 - nfft as f64
            };
            let pp = -2.0 * std::f64::consts::PI * ks / (nfft as f64 * d);
            let mut lg = Complex64::default();
            let mut ip_n = Complex64::new(1.0, 0.0);
            let mut fact = 1.0;
            for (n, &cn) in c.iter().enumerate() {
                ip_n *= Complex64::new(0.0, pp);
                fact *= (n + 1) as f64;
                lg += ip_n * (cn * s / fact);
            }
            *z *= lg.exp();
        }
        planner.plan_fft_inverse(nfft).process(&mut buf);
        let off_t = (ht.lo - lo) as usize;
        let predicted: Vec<f64> = (0..ht.rows)
            .map(|r| buf[off_t + r].re / nfft as f64)
            .collect();
        // mass of the prediction outside the target's bins counts as error
        let total_pred: f64 = buf.iter().map(|z| z.re / nfft as f64).sum::<f64>() * d;
        let inside: f64 = predicted.iter().sum::<f64>() * d;
        let l1 = predicted
            .iter()
            .zip(&p_to)
            .map(|(a, b)| (a - b).abs())
            .sum::<f64>()
            * d
            + (total_pred - inside).abs();
        out.push(Reconstruction {
            a_from: h.scales[fr],
            a_to: h.scales[to],
            ln_ratio: s,
            c: c.to_vec(),
            ln_m: (0..ht.rows)
                .map(|r| (ht.lo as f64 + r as f64 + 0.5) * d)
                .collect(),
            measured: p_to.clone(),
            predicted,
            l1,
        });
    }
    Ok(out)
}
