//! Fractionally integrated singular cascades, FISC (II §2.1; SPEC §9).
//!
//! 1. A conservative p-model on a `2^n x 2^n` grid, `n = log2 L` steps
//!    (II eqs 1-3): at each step every square splits into 4; two of the
//!    children, chosen at random among the 6 pairs, receive the fraction
//!    `p/2` of the parent's measure, the two others `(1-p)/2`. The measure is
//!    conserved exactly at every step; the density multipliers are `2p` and
//!    `2(1-p)`. Theory of the measure: `τ_μ(q) = -(q+1) - log2(p^q + (1-p)^q)`
//!    (II eq 4).
//! 2. Fractional integration of order H* in Fourier space (II eqs 5-7):
//!    `f̂(k) = A(H*) μ̂(k) |k|^-H*`, `A(H*) = √(2/π) cos(πH*/2) Γ(H*)`,
//!    `k` in rad/px, `k = 0` set to 0 (zero-mean field). The cascade lives on
//!    the torus, so the filter is applied periodically with no padding.
//!
//! Theory (II eqs 8, 11-13; see [`crate::theory::fisc`]):
//! `τ(q) = -1 - q(1-H*) - log2(p^q + (1-p)^q)`,
//! `β = 1 + 2H* - log2(2p² - 2p + 1)`, `h_min = H* - 1 - log2(1-p)`,
//! `h_max = H* - 1 - log2 p`. β is the infinite cascade's: the exact
//! spectrum of an image, flatter near the pixel scale, is
//! [`FiscParams::expected_power`].

use ndarray::{Array2, ArrayView2};
use num_complex::Complex64;
use rand::RngExt;
use realfft::RealFftPlanner;
use rustfft::FftPlanner;
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::synth::{SynthRng, rng_for};

/// Parameters of a FISC surface.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct FiscParams {
    /// p-model weight, `0 < p <= 1/2` (`p = 1/2`: uniform measure, monofractal).
    pub p: f64,
    /// Order of fractional integration H*, `0 < H* < 1` (II eq 5).
    pub hstar: f64,
}

impl FiscParams {
    /// **Errors** unless `0 < p <= 1/2` and `0 < H* < 1`.
    ///
    /// H* is limited to (0, 1) as in II eq 5: the constant `A(H*)` of II eq 7
    /// vanishes at H* = 1 and changes sign beyond.
    ///
    /// Unlike the W-cascades (whose wavelet series must converge, II eq 31),
    /// a negative `h_min = H* - 1 - log2(1-p)` is accepted (e.g. p = 0.1,
    /// H* = 0.1): the field, a Riesz potential of order H* > 0 of a finite
    /// measure, is still locally integrable, only unbounded at its
    /// strongest singularities, and the WTMM resolves negative exponents as
    /// it does for measures.
    pub fn validate(&self) -> Result<()> {
        if !(self.p > 0.0 && self.p <= 0.5) {
            return Err(Error::param(
                "p",
                format!(
                    "p must be in (0, 1/2] (two children get p/2, two get (1-p)/2), got {}",
                    crate::error::short_outside(self.p, &[0.0, 0.5])
                ),
            ));
        }
        if !(self.hstar > 0.0 && self.hstar < 1.0) {
            return Err(Error::param(
                "hstar",
                format!(
                    "H* must be in (0, 1) (II eq 5; A(H*) of eq 7 vanishes at 1), got {}",
                    crate::error::short_outside(self.hstar, &[0.0, 1.0])
                ),
            ));
        }
        Ok(())
    }

    /// The normalising constant `A(H*) = √(2/π) cos(πH*/2) Γ(H*)` of II eq 7.
    pub fn amplitude(&self) -> f64 {
        let h = self.hstar;
        (2.0 / std::f64::consts::PI).sqrt()
            * (std::f64::consts::FRAC_PI_2 * h).cos()
            * statrs::function::gamma::gamma(h)
    }
}

/// Number of cascade steps for a `size x size` image.
///
/// **Errors** unless `size` is a power of two, at least 2.
pub fn steps_for_size(size: usize) -> Result<usize> {
    if size < 2 || !size.is_power_of_two() {
        return Err(Error::param(
            "size",
            format!("cascades need a power of two >= 2, got {size}"),
        ));
    }
    super::check_pixels(size, size)?;
    Ok(size.trailing_zeros() as usize)
}

/// The 6 ways to choose the two children (0 = (2y, 2x), 1 = (2y, 2x+1),
/// 2 = (2y+1, 2x), 3 = (2y+1, 2x+1)) that receive `p/2`.
const PAIRS: [[bool; 4]; 6] = [
    [true, true, false, false],
    [true, false, true, false],
    [true, false, false, true],
    [false, true, true, false],
    [false, true, false, true],
    [false, false, true, true],
];

/// The conservative p-model: `steps` steps from a unit mass, returning the
/// masses of the `2^steps x 2^steps` cells (they sum to 1). `on_step(s, m)` is
/// called after every step `s = 1..=steps` with the `2^s x 2^s` masses (for
/// tests and diagnostics). One `random_range(0..6)` per split, parents in
/// row-major order, so a seed fixes the measure.
///
/// **Errors** if `p` is outside (0, 1/2] (as [`FiscParams::validate`]) or
/// `2^steps` cells a side exceed the generators' limit of 2^28 pixels.
pub fn pmodel_cascade(
    p: f64,
    steps: usize,
    rng: &mut SynthRng,
    mut on_step: impl FnMut(usize, ArrayView2<f64>),
) -> Result<Array2<f64>> {
    FiscParams { p, hstar: 0.5 }.validate()?;
    let too_many = || Error::param("steps", format!("2^{steps} cells a side is too many"));
    let n = 1usize
        .checked_shl(steps as u32)
        .filter(|_| steps < usize::BITS as usize)
        .ok_or_else(too_many)?;
    super::check_pixels(n, n).map_err(|_| too_many())?;
    let (lo, hi) = (0.5 * p, 0.5 * (1.0 - p));
    let mut cur = vec![0.0; n * n];
    let mut next = vec![0.0; n * n];
    cur[0] = 1.0;
    for s in 1..=steps {
        let (pw, cw) = (1usize << (s - 1), 1usize << s);
        for y in 0..pw {
            for x in 0..pw {
                let m = cur[y * pw + x];
                let pair = &PAIRS[rng.random_range(0..6usize)];
                let w = |i: usize| if pair[i] { lo } else { hi };
                let (r0, r1) = (2 * y * cw, (2 * y + 1) * cw);
                next[r0 + 2 * x] = m * w(0);
                next[r0 + 2 * x + 1] = m * w(1);
                next[r1 + 2 * x] = m * w(2);
                next[r1 + 2 * x + 1] = m * w(3);
            }
        }
        std::mem::swap(&mut cur, &mut next);
        on_step(
            s,
            ArrayView2::from_shape((cw, cw), &cur[..cw * cw]).expect("cw*cw cells"),
        );
    }
    Ok(Array2::from_shape_vec((n, n), cur).expect("n*n cells"))
}

/// The p-model measure underlying image `index` of the FISC ensemble `seed`,
/// as a density (mass per pixel times `size²`, so its mean is 1).
/// [`fisc`] with the same arguments integrates exactly this measure.
///
/// **Errors** on invalid parameters or a size that is not a power of two.
pub fn fisc_measure(params: FiscParams, size: usize, seed: u64, index: u64) -> Result<Array2<f64>> {
    params.validate()?;
    let steps = steps_for_size(size)?;
    let mut rng = rng_for(seed, index);
    let mut mu = pmodel_cascade(params.p, steps, &mut rng, |_, _| {})?;
    let area = (size * size) as f64;
    mu.mapv_inplace(|m| m * area);
    Ok(mu)
}

/// `log2` of the p-model box masses of image `index` of the FISC ensemble
/// `seed` at the cascade steps `levels` (step `s` has `4^s` boxes of side
/// `size / 2^s` px), shifted by `(2 - H*) s`: the fractionally integrated
/// field's amplitude at scale `a` is `μ(box) a^(H* - 2)` (SPEC §9), so the
/// partition function of these values has the field's τ(q) in expectation
/// ([`crate::theory::Model::sample_sums`]). Steps beyond `log2 size` are
/// empty.
///
/// **Errors** on invalid parameters, a size that is not a power of two, or
/// steps reaching past `log2 size + 1`.
pub fn fisc_log2_amplitudes(
    params: FiscParams,
    size: usize,
    seed: u64,
    index: u64,
    levels: std::ops::Range<usize>,
) -> Result<Vec<Vec<f64>>> {
    params.validate()?;
    let steps = steps_for_size(size)?;
    super::check_levels(&levels, steps, size)?;
    let mut out: Vec<Vec<f64>> = levels.clone().map(|_| Vec::new()).collect();
    let shift = 2.0 - params.hstar;
    let mut rng = rng_for(seed, index);
    // the same draws as [`fisc_measure`]: the same boxes
    pmodel_cascade(params.p, steps, &mut rng, |s, m| {
        if levels.contains(&s) {
            let off = shift * s as f64;
            out[s - levels.start].extend(m.iter().map(|&v| v.log2() + off));
        }
    })?;
    Ok(out)
}

/// Image `index` of the FISC ensemble `seed`, `size x size` (a power of two).
///
/// **Errors** on invalid parameters or a size that is not a power of two.
pub fn fisc(params: FiscParams, size: usize, seed: u64, index: u64) -> Result<Array2<f64>> {
    if params.p == 0.5 {
        // every split is even: μ is uniform, its only Fourier mode is k = 0,
        // which the integration sets to 0 (the theory's monofractal h = H*
        // describes the limit p -> 1/2, not this image)
        return Err(Error::param(
            "p",
            "p = 1/2 gives a uniform measure, so the integrated field is identically 0: use p < 1/2",
        ));
    }
    let mu = fisc_measure(params, size, seed, index)?;
    let f = fractional_integration(&mu, params.hstar, params.amplitude());
    // A(H*) grows like Γ(H*) ~ 1/H*: near H* = 0 the field leaves double
    // precision, or the amplitudes every analysis reads
    let top = f.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    if !(top <= crate::field::AMPLITUDE_LIMIT) {
        return Err(Error::param(
            "hstar",
            format!(
                "H* = {} gives values up to {} (beyond the {:e} that the analyses read): the \
                 normalisation A(H*) of II eq 7 grows like 1/H* (A = {})",
                crate::error::short(params.hstar),
                crate::error::short(top),
                crate::field::AMPLITUDE_LIMIT,
                crate::error::short(params.amplitude())
            ),
        ));
    }
    Ok(f)
}

/// Periodic fractional integration `f̂ = amp μ̂ |k|^-order`, k in rad/px,
/// `k = 0` set to 0. Real FFT along x, complex FFT along y.
fn fractional_integration(mu: &Array2<f64>, order: f64, amp: f64) -> Array2<f64> {
    let (ny, nx) = mu.dim();
    let nh = nx / 2 + 1;
    let mut rp = RealFftPlanner::<f64>::new();
    let r2c = rp.plan_fft_forward(nx);
    let c2r = rp.plan_fft_inverse(nx);
    let mut cp = FftPlanner::<f64>::new();
    let fy = cp.plan_fft_forward(ny);
    let iy = cp.plan_fft_inverse(ny);
    let mut half = vec![Complex64::default(); ny * nh];
    let mut row = vec![0.0; nx];
    for (y, out) in half.chunks_exact_mut(nh).enumerate() {
        row.copy_from_slice(mu.row(y).as_slice().expect("owned array is contiguous"));
        r2c.process(&mut row, out).expect("lengths from plan");
    }
    let mut t = vec![Complex64::default(); ny * nh];
    transpose::transpose(&half, &mut t, nh, ny);
    fy.process(&mut t);
    let expo = -order / 2.0;
    // 1/(nx ny) undoes the unnormalised forward + inverse FFT pair
    let norm = amp / (nx * ny) as f64;
    let ky2: Vec<f64> = (0..ny)
        .map(|ky| crate::fourier::angular_freq(ky, ny).powi(2))
        .collect();
    for kx in 0..nh {
        let fx2 = crate::fourier::angular_freq(kx, nx).powi(2);
        for (ky, &fy2) in ky2.iter().enumerate() {
            let k2 = fx2 + fy2;
            let g = if k2 > 0.0 { norm * k2.powf(expo) } else { 0.0 };
            t[kx * ny + ky] *= g;
        }
    }
    iy.process(&mut t);
    transpose::transpose(&t, &mut half, ny, nh);
    let mut out = Array2::<f64>::zeros((ny, nx));
    for (y, spec) in half.chunks_exact_mut(nh).enumerate() {
        // c2r needs exactly real DC and Nyquist bins; they are real up to rounding
        spec[0].im = 0.0;
        if nx % 2 == 0 {
            spec[nh - 1].im = 0.0;
        }
        c2r.process(spec, &mut row).expect("lengths from plan");
        out.row_mut(y)
            .as_slice_mut()
            .expect("owned array is contiguous")
            .copy_from_slice(&row);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Near H* = 0 the normalisation A(H*) ~ 1/H* leaves double precision:
    /// an error naming H*, not a field of inf and NaN (before: 60 NaN and
    /// 92 inf of 4096 pixels at H* = 1e-308, exit 0), nor values no
    /// analysis reads (beyond 1e100).
    #[test]
    fn an_overflowing_hstar_is_refused() {
        let p = FiscParams {
            p: 0.32,
            hstar: 1e-308,
        };
        p.validate().unwrap();
        let e = fisc(p, 64, 1, 0).unwrap_err().to_string();
        assert!(
            e.contains("`hstar`") && e.contains("grows like 1/H*"),
            "{e}"
        );
        // finite but beyond what the analyses read (5e300 at 1e-300)
        let e = fisc(FiscParams { hstar: 1e-300, ..p }, 64, 1, 0)
            .unwrap_err()
            .to_string();
        assert!(e.contains("`hstar`") && e.contains("beyond"), "{e}");
        let f = fisc(FiscParams { hstar: 1e-3, ..p }, 64, 1, 0).unwrap();
        assert!(f.iter().all(|v| v.is_finite()));
    }

    #[test]
    fn p_one_half_is_refused_by_the_generator() {
        // a valid model (the theory's monofractal limit), but every split is
        // even and the image would be identically 0
        let p = FiscParams { p: 0.5, hstar: 0.5 };
        assert!(p.validate().is_ok());
        let e = fisc(p, 16, 1, 0).unwrap_err().to_string();
        assert!(e.contains("`p`") && e.contains("uniform"), "{e}");
        assert!(
            fisc(
                FiscParams {
                    p: 0.49,
                    hstar: 0.5
                },
                16,
                1,
                0
            )
            .is_ok()
        );
    }

    #[test]
    fn validation_names_the_flag() {
        let e = FiscParams { p: 0.6, hstar: 0.5 }.validate().unwrap_err();
        assert!(e.to_string().contains("`p`"), "{e}");
        let e = FiscParams { p: 0.0, hstar: 0.5 }.validate().unwrap_err();
        assert!(e.to_string().contains("`p`"), "{e}");
        let e = FiscParams { p: 0.3, hstar: 1.0 }.validate().unwrap_err();
        assert!(e.to_string().contains("`hstar`"), "{e}");
        let e = FiscParams {
            p: 0.3,
            hstar: f64::NAN,
        }
        .validate()
        .unwrap_err();
        assert!(e.to_string().contains("`hstar`"), "{e}");
        assert!(FiscParams { p: 0.5, hstar: 0.5 }.validate().is_ok());
        let e = fisc(FiscParams { p: 0.3, hstar: 0.5 }, 48, 0, 0).unwrap_err();
        assert!(e.to_string().contains("`size`"), "{e}");
    }

    /// p = 1/2 is the uniform measure: the density is exactly 1 everywhere
    /// and the integrated field is 0 (only k = 0 carries energy).
    #[test]
    fn uniform_measure() {
        let prm = FiscParams { p: 0.5, hstar: 0.5 };
        let mu = fisc_measure(prm, 32, 1, 0).unwrap();
        assert!(mu.iter().all(|&v| (v - 1.0).abs() < 1e-12));
        // why `fisc` refuses p = 1/2: the integrated field is 0
        let f = fractional_integration(&mu, prm.hstar, prm.amplitude());
        assert!(f.iter().all(|v| v.abs() < 1e-12));
    }

    /// The filter against a direct evaluation: a single cosine mode
    /// `cos(k0 x)` comes out as `A k0^-H* cos(k0 x)`.
    #[test]
    fn fractional_integration_of_a_cosine() {
        let n = 64;
        let k0 = 2.0 * std::f64::consts::PI * 5.0 / n as f64;
        let mu = Array2::from_shape_fn((n, n), |(_, x)| (k0 * x as f64).cos());
        let f = fractional_integration(&mu, 0.6, 2.0);
        for ((_, x), &v) in f.indexed_iter() {
            let want = 2.0 * k0.powf(-0.6) * (k0 * x as f64).cos();
            assert!((v - want).abs() < 1e-12, "{v} vs {want}");
        }
    }

    #[test]
    fn amplitude_matches_eq7() {
        // A(1/2) = √(2/π) cos(π/4) Γ(1/2) = √(2/π) (1/√2) √π = 1
        let a = FiscParams { p: 0.3, hstar: 0.5 }.amplitude();
        assert!((a - 1.0).abs() < 1e-12, "{a}");
        // at H* = 1/2 cos = sin and Γ(H) = Γ(1 - H): also H* = 1/3, with
        // Γ(1/3) = 2.678938534707747 (tabulated), cos(π/6) = √3/2
        let a = FiscParams {
            p: 0.3,
            hstar: 1.0 / 3.0,
        }
        .amplitude();
        let want = (2.0 / std::f64::consts::PI).sqrt() * 3f64.sqrt() / 2.0 * 2.678938534707747;
        assert!((a - want).abs() < 1e-12, "{a} vs {want}");
    }
}
