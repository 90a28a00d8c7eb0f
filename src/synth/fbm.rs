//! Fractional Brownian surfaces by Fourier filtering (SPEC §9):
//! `f̂(k) = |k|^-(H+1) ŵ(k)` with `w` white Gaussian noise (so `ŵ` is complex
//! Gaussian and Hermitian), `k = 0` set to 0, synthesised on a grid twice as
//! large in each direction and cropped at the centre to limit the periodic
//! artefacts. Theory: `τ(q) = qH - 2`, `h(q) = H`, `D(H) = 2`,
//! `β = 2H + 2` (angle-averaged spectrum).

use ndarray::Array2;
use num_complex::Complex64;
use rand_distr::{Distribution, StandardNormal};
use realfft::RealFftPlanner;
use rustfft::FftPlanner;

use crate::error::{Error, Result};
use crate::synth::rng_for;

/// Parameters of an fBm surface.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FbmParams {
    /// Hurst exponent H in (0, 1).
    pub hurst: f64,
}

impl FbmParams {
    /// **Errors** unless `0 < H < 1`.
    pub fn validate(&self) -> Result<()> {
        if !(self.hurst > 0.0 && self.hurst < 1.0) {
            return Err(Error::param(
                "hurst",
                format!(
                    "H must be in (0, 1), got {}",
                    crate::error::short_outside(self.hurst, &[0.0, 1.0])
                ),
            ));
        }
        Ok(())
    }

    /// `τ(q) = qH - 2`.
    pub fn tau(&self, q: f64) -> f64 {
        q * self.hurst - 2.0
    }

    /// Spectral exponent of the angle-averaged spectrum, `β = 2H + 2`.
    pub fn beta(&self) -> f64 {
        2.0 * self.hurst + 2.0
    }
}

/// Image `index` of the fBm ensemble `seed`, size `ny x nx`.
///
/// **Errors** on an invalid H or a size below 2.
pub fn fbm(params: FbmParams, ny: usize, nx: usize, seed: u64, index: u64) -> Result<Array2<f64>> {
    params.validate()?;
    if ny < 2 || nx < 2 {
        return Err(Error::param(
            "size",
            format!("must be at least 2, got {ny}x{nx}"),
        ));
    }
    super::check_pixels(ny, nx)?;
    let (my, mx) = (2 * ny, 2 * nx);
    let mut rng = rng_for(seed, index);
    // white noise in space; its DFT is Hermitian complex Gaussian noise
    let mut w: Vec<f64> = (0..my * mx)
        .map(|_| StandardNormal.sample(&mut rng))
        .collect();
    let nh = mx / 2 + 1;
    let mut rp = RealFftPlanner::<f64>::new();
    let r2c = rp.plan_fft_forward(mx);
    let c2r = rp.plan_fft_inverse(mx);
    let mut cp = FftPlanner::<f64>::new();
    let fy = cp.plan_fft_forward(my);
    let iy = cp.plan_fft_inverse(my);
    let mut half = vec![Complex64::default(); my * nh];
    for (row, out) in w.chunks_exact_mut(mx).zip(half.chunks_exact_mut(nh)) {
        r2c.process(row, out).expect("lengths from plan");
    }
    let mut t = vec![Complex64::default(); my * nh];
    transpose::transpose(&half, &mut t, nh, my);
    fy.process(&mut t);
    // filter |k|^-(H+1) (k in rad/px), k = 0 -> 0
    let two_pi = 2.0 * std::f64::consts::PI;
    let expo = -(params.hurst + 1.0) / 2.0;
    for kx in 0..nh {
        let fx = two_pi * kx as f64 / mx as f64;
        for ky in 0..my {
            let m = if ky <= my / 2 {
                ky as f64
            } else {
                ky as f64 - my as f64
            };
            let fyv = two_pi * m / my as f64;
            let k2 = fx * fx + fyv * fyv;
            let g = if k2 > 0.0 { k2.powf(expo) } else { 0.0 };
            t[kx * my + ky] *= g;
        }
    }
    iy.process(&mut t);
    transpose::transpose(&t, &mut half, my, nh);
    // c2r needs exactly real DC and Nyquist bins; they are real up to rounding
    let mut out = Array2::<f64>::zeros((ny, nx));
    let mut row = vec![0.0; mx];
    let (y0, x0) = (ny / 2, nx / 2);
    let norm = 1.0 / ((mx * my) as f64).sqrt();
    for y in 0..ny {
        let spec = &mut half[(y0 + y) * nh..(y0 + y + 1) * nh];
        spec[0].im = 0.0;
        if mx % 2 == 0 {
            spec[nh - 1].im = 0.0;
        }
        c2r.process(spec, &mut row).expect("lengths from plan");
        for x in 0..nx {
            out[[y, x]] = row[x0 + x] * norm;
        }
    }
    Ok(out)
}
