//! Isotropic power spectrum (SPEC §7).
//!
//! `S(|k|)` is the angle-averaged spectral density `|f̂(k)|²` in log-spaced
//! `|k|` bins; for an isotropic field `S ~ |k|^-β`. The angle-integrated
//! spectrum `2π|k| S(|k|)` has exponent `β - 1`; every output says which
//! convention it prints ([`CONVENTION`]).
//!
//! Bins are anchored at the Nyquist frequency: bin `b` holds
//! `π 2^-(b+1)/bpo < |k| <= π 2^-b/bpo` (rad/px), so spectra of images of
//! different sizes share bins and can be merged into one ensemble average.

use ndarray::{Array2, ArrayView2};
use num_complex::Complex64;
use realfft::RealFftPlanner;
use rustfft::FftPlanner;
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::fourier::angular_freq;
use crate::stats::fit::{LineFit, line_fit};

/// The convention of β printed by this module.
pub const CONVENTION: &str = "angle-averaged";

/// Taper applied before the FFT.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum Window {
    /// No taper: right for periodic fields (cascades on a torus).
    None,
    /// Separable Hann window: limits the leakage from the border jump of a
    /// non-periodic field, which would otherwise add a `|k|^-2` background.
    Hann,
}

/// What is removed before the FFT.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum Detrend {
    /// Nothing removed (the `k = 0` mode is left out of the bins anyway).
    None,
    /// The mean (enough for periodic fields).
    Mean,
    /// Least-squares plane `c0 + c1 x + c2 y`. Not for periodic fields
    /// without a window: the removed plane is a jump across the border (a
    /// sawtooth, power ~ |k|^-2 on the axes) that flattens steep spectra
    /// (FISC preset, 1024²: β 3.03 instead of 3.08 with the mean removed).
    Plane,
}

/// How [`field_power_spectrum`] fills missing pixels before the FFT.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum HoleFill {
    /// Laplace's equation inside each hole, its valid rim as the boundary
    /// (Field::filled_harmonic): continuous across the rim, so a hole adds
    /// no edge to the spectrum; smoother than the surface inside.
    Harmonic,
    /// The mean of the valid pixels: a step along every hole's rim, whose
    /// `|k|^-3` power flattens steep spectra (the estimator before
    /// harmonic fills).
    Mean,
}

impl HoleFill {
    /// For `serde(default)`: configurations saved before this option
    /// existed filled with the mean.
    pub(crate) fn mean() -> Self {
        HoleFill::Mean
    }

    /// The name the command line and the JSON use.
    pub fn name(self) -> &'static str {
        match self {
            HoleFill::Harmonic => "harmonic",
            HoleFill::Mean => "mean",
        }
    }
}

/// The share of an image one hole may cover before the spectrum's warnings
/// say that beta is then uncertain beyond its error, whatever the fill
/// ([`large_hole_warning`]).
pub const LARGE_HOLE_SHARE: f64 = 0.05;

/// What a hole covering `share` of an image does to its spectrum,
/// measured, for the warnings of `spectrum` and `tm`: `None` up to
/// [`LARGE_HOLE_SHARE`].
pub fn large_hole_warning(share: f64) -> Option<String> {
    (share > LARGE_HOLE_SHARE).then(|| format!(
        "one hole covers {:.0} % of it: inside, a harmonic fill is smoother than the surface and \
         a mean fill a step along the rim, so beta is uncertain beyond its error whatever the fill \
         (topo-fif fields of 1024^2, beta 3.26 +- 0.04, with one disc or irregular hole of 5, \
         16, 36 %: \
         harmonic +0.05, -0.03 to +0.15, +0.10 to +0.22; mean -0.03, -0.18 to -0.41, -0.21 to \
         -0.58); crop to a region without it if you can",
        100.0 * share
    ))
}

/// Options of [`power_spectrum`] and [`field_power_spectrum`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct PowerSpectrumConfig {
    /// Taper before the FFT (default Hann).
    pub window: Window,
    /// What is removed before the taper (default the plane).
    pub detrend: Detrend,
    /// Log-spaced bins per octave of |k|.
    pub bins_per_octave: usize,
    /// How [`field_power_spectrum`] fills missing pixels (default
    /// harmonic: on 32 topo-fif planes of 512^2 with 5 % isolated pixels
    /// missing, beta moved by +0.006 +- 0.003 harmonic, -0.34 +- 0.22
    /// with the mean; README "Spectra of images with holes"). Stored
    /// configurations without the key filled with the mean.
    #[serde(default = "HoleFill::mean")]
    pub fill: HoleFill,
}

impl PowerSpectrumConfig {
    /// The settings for a field of the given kind: a periodic field needs no
    /// taper and only its mean removed (removing a plane would add a sawtooth
    /// across the border, hence power at high k: paper-fisc's beta came out
    /// 3.016 instead of 3.080); any other field is tapered and detrended.
    pub fn for_field(periodic: bool) -> Self {
        if periodic {
            PowerSpectrumConfig {
                window: Window::None,
                detrend: Detrend::Mean,
                ..Self::default()
            }
        } else {
            Self::default()
        }
    }
}

impl Default for PowerSpectrumConfig {
    fn default() -> Self {
        PowerSpectrumConfig {
            window: Window::Hann,
            detrend: Detrend::Plane,
            bins_per_octave: 4,
            fill: HoleFill::Harmonic,
        }
    }
}

/// A binned, angle-averaged power spectrum; sums are kept so that spectra of
/// several images merge exactly into an ensemble average.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PowerSpectrum {
    /// Log-spaced bins per octave of |k|, anchored at Nyquist (module doc).
    pub bins_per_octave: usize,
    /// Per bin: sum of |f̂|² (normalised per pixel and window energy).
    #[serde(deserialize_with = "crate::nan_null::vec")]
    pub sum_s: Vec<f64>,
    /// Per bin: sum of ln|k| over the modes in it (for the bin's centre).
    #[serde(deserialize_with = "crate::nan_null::vec")]
    pub sum_lnk: Vec<f64>,
    /// Per bin: number of Fourier modes.
    pub count: Vec<u64>,
    /// Number of images merged.
    pub images: usize,
}

impl PowerSpectrum {
    /// Adds another spectrum's sums.
    ///
    /// **Errors** if the two were binned with different `bins_per_octave`.
    pub fn merge(&mut self, other: &PowerSpectrum) -> Result<()> {
        if self.images == 0 {
            *self = other.clone();
            return Ok(());
        }
        if self.bins_per_octave != other.bins_per_octave {
            return Err(Error::param(
                "bins-per-octave",
                format!(
                    "cannot merge spectra binned with {} and {} bins per octave",
                    self.bins_per_octave, other.bins_per_octave
                ),
            ));
        }
        let n = self.sum_s.len().max(other.sum_s.len());
        self.sum_s.resize(n, 0.0);
        self.sum_lnk.resize(n, 0.0);
        self.count.resize(n, 0);
        for b in 0..other.sum_s.len() {
            self.sum_s[b] += other.sum_s[b];
            self.sum_lnk[b] += other.sum_lnk[b];
            self.count[b] += other.count[b];
        }
        self.images += other.images;
        Ok(())
    }

    /// `(|k|, S)` per non-empty bin, |k| ascending (rad/px; `|k|` is the
    /// geometric mean of the modes in the bin).
    pub fn points(&self) -> Vec<(f64, f64)> {
        let mut v: Vec<(f64, f64)> = (0..self.sum_s.len())
            .filter(|&b| self.count[b] > 0)
            .map(|b| {
                let c = self.count[b] as f64;
                ((self.sum_lnk[b] / c).exp(), self.sum_s[b] / c)
            })
            .collect();
        v.reverse();
        v
    }

    /// Fits `log S = c - β log |k|` over bins with `k_lo <= |k| <= k_hi`
    /// (rad/px). The returned fit's slope is `-β`.
    ///
    /// **Errors** unless `0 < k_lo < k_hi <= π` (beyond the Nyquist
    /// wavenumber the bins are the spectrum's corners only, and the range
    /// recorded would not be the one fitted), or if fewer than 3 bins fall
    /// in the range.
    pub fn fit(&self, k_lo: f64, k_hi: f64) -> Result<SpectrumFit> {
        if !(k_lo > 0.0 && k_lo < k_hi && k_hi <= std::f64::consts::PI) {
            return Err(Error::param(
                "k-range",
                format!(
                    "[{}, {}] rad/px: need 0 < LO < HI <= pi (the Nyquist wavenumber)",
                    crate::error::short(k_lo),
                    crate::error::short(k_hi)
                ),
            ));
        }
        let pts: Vec<(f64, f64)> = self
            .points()
            .into_iter()
            .filter(|&(k, s)| k >= k_lo && k <= k_hi && s > 0.0 && s.is_finite())
            .collect();
        let in_range = self
            .points()
            .iter()
            .filter(|&&(k, _)| k >= k_lo && k <= k_hi)
            .count();
        if pts.len() < 3 && in_range >= 3 {
            // the bins are there but hold no power: the data's fault
            return Err(Error::Input(format!(
                "the power spectrum is 0 at {} of the {in_range} bins in [{}, {}] rad/px: once \
                 the mean (or the plane, for non-periodic images) is removed nothing is left \
                 there (a constant or planar image?)",
                in_range - pts.len(),
                crate::error::short(k_lo),
                crate::error::short(k_hi)
            )));
        }
        if pts.len() < 3 {
            return Err(Error::param(
                "k-range",
                format!(
                    "only {} spectrum bins in [{}, {}] rad/px; need 3",
                    pts.len(),
                    crate::error::short(k_lo),
                    crate::error::short(k_hi)
                ),
            ));
        }
        let x: Vec<f64> = pts.iter().map(|p| p.0.log2()).collect();
        let y: Vec<f64> = pts.iter().map(|p| p.1.log2()).collect();
        let line = line_fit(&x, &y).expect("3 distinct bins");
        Ok(SpectrumFit {
            beta: -line.slope,
            beta_stderr: line.slope_stderr,
            k_range: (k_lo, k_hi),
            line,
        })
    }
}

/// Delete-one jackknife standard error of the ensemble β: the fit to the
/// pooled sums of `parts` (one spectrum per image), redone with each image
/// left out. The regression error of [`SpectrumFit::beta_stderr`] measures
/// how far the bins stray from a line, not how much β would move with
/// another sample; this does. NaN below 3 images or when a leave-one-out
/// fit fails.
pub fn jackknife_beta_se(parts: &[PowerSpectrum], k_lo: f64, k_hi: f64) -> Result<f64> {
    if parts.len() < 3 {
        return Ok(f64::NAN);
    }
    let mut total = PowerSpectrum::default();
    for p in parts {
        total.merge(p)?;
    }
    // each leave-one-out spectrum is the total minus one image's sums
    // (counts exactly; the power sums to rounding, far below the error)
    let loo: Vec<f64> = parts
        .iter()
        .map(|p| {
            let mut t = total.clone();
            for b in 0..p.sum_s.len() {
                t.sum_s[b] -= p.sum_s[b];
                t.sum_lnk[b] -= p.sum_lnk[b];
                t.count[b] -= p.count[b];
            }
            t.images -= p.images;
            t.fit(k_lo, k_hi).map_or(f64::NAN, |f| f.beta)
        })
        .collect();
    Ok(crate::stats::fit::jackknife_se(&loo))
}

/// A fitted spectral exponent.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SpectrumFit {
    /// `S ~ |k|^-β`, angle-averaged.
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub beta: f64,
    /// Standard error of β from the regression residuals (not a jackknife).
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub beta_stderr: f64,
    /// Fit range in rad/px.
    #[serde(deserialize_with = "crate::nan_null::pair")]
    pub k_range: (f64, f64),
    /// The regression of log2 S on log2 |k|.
    pub line: LineFit,
}

/// |k| (rad/px) of the DFT mode `(kx, ky)` of an `ny x nx` image (FFT
/// order: indices above n/2 are negative frequencies).
fn mode_k(kx: usize, nx: usize, ky: usize, ny: usize) -> f64 {
    let (fx, fy) = (angular_freq(kx, nx), angular_freq(ky, ny));
    (fx * fx + fy * fy).sqrt()
}

impl PowerSpectrum {
    /// Adds `w` modes of density `s` at `|k|` to their bin (`k = 0` and the
    /// corners beyond Nyquist are left out).
    fn add(&mut self, k: f64, s: f64, w: u64) {
        let pi = std::f64::consts::PI;
        if k == 0.0 || k > pi {
            return;
        }
        let b = ((pi / k).log2() * self.bins_per_octave as f64).floor() as usize;
        if b >= self.sum_s.len() {
            self.sum_s.resize(b + 1, 0.0);
            self.sum_lnk.resize(b + 1, 0.0);
            self.count.resize(b + 1, 0);
        }
        self.sum_s[b] += w as f64 * s;
        self.sum_lnk[b] += w as f64 * k.ln();
        self.count[b] += w;
    }

    /// Bins a spectral density given at every DFT mode of an image,
    /// `s[[ky, kx]]` in FFT order (e.g. a model's expected `|f̂|²` per pixel,
    /// [`crate::theory`]), exactly as [`power_spectrum`] bins an image's, so
    /// that the two can be fitted alike. Counts as one image.
    ///
    /// **Errors** if `bins_per_octave` is not in 1..=64.
    pub fn from_density(s: ArrayView2<f64>, bins_per_octave: usize) -> Result<Self> {
        check_bins(bins_per_octave)?;
        let (ny, nx) = s.dim();
        let mut ps = PowerSpectrum {
            bins_per_octave,
            images: 1,
            ..Default::default()
        };
        for ((ky, kx), &v) in s.indexed_iter() {
            ps.add(mode_k(kx, nx, ky, ny), v, 1);
        }
        Ok(ps)
    }
}

/// Default fit range for an image whose smaller side is `n` pixels:
/// from 8 cycles per image (the first few modes are too few and too
/// affected by the window) to a quarter of Nyquist (above it the
/// grid's anisotropy and any aliasing bend the spectrum). Empty
/// (`lo >= hi`) for `n <= 64`: a fit there finds no bins and says so
/// ([`bins_in_range`] lets callers refuse such a size up front).
pub fn default_k_range(n: usize) -> (f64, f64) {
    let pi = std::f64::consts::PI;
    (2.0 * pi * 8.0 / n as f64, pi / 4.0)
}

/// The number of spectrum bins of an `ny x nx` image that fall in
/// `[k_lo, k_hi]` rad/px ([`PowerSpectrum::fit`] needs 3), so that a size
/// too small for a fit range is refused before any image is analysed.
///
/// Allocates nothing of the image's size: only the modes with
/// `|k| <= 2 k_hi` are binned. That is exact, because a bin spans at most an
/// octave: a bin whose mean `|k|` is at most `k_hi` has every mode below
/// twice its lower edge, so below `2 k_hi`, and a bin holding a mode above
/// `2 k_hi` starts above `k_hi`, so its mean lies outside the range
/// whichever of its modes are binned.
///
/// **Errors** if `bins_per_octave` is not in 1..=64.
pub fn bins_in_range(
    ny: usize,
    nx: usize,
    bins_per_octave: usize,
    (k_lo, k_hi): (f64, f64),
) -> Result<usize> {
    check_bins(bins_per_octave)?;
    let mut ps = PowerSpectrum {
        bins_per_octave,
        images: 1,
        ..Default::default()
    };
    let cap = 2.0 * k_hi;
    for ky in 0..ny {
        if angular_freq(ky, ny).abs() > cap {
            continue;
        }
        for kx in 0..nx {
            let k = mode_k(kx, nx, ky, ny);
            if k <= cap {
                ps.add(k, 1.0, 1);
            }
        }
    }
    Ok(ps
        .points()
        .iter()
        .filter(|&&(k, _)| k >= k_lo && k <= k_hi)
        .count())
}

/// Removes a mean or a least-squares plane in place.
fn detrend(img: &mut Array2<f64>, how: Detrend) {
    let (ny, nx) = img.dim();
    match how {
        Detrend::None => {}
        Detrend::Mean => {
            let m = img.mean().unwrap_or(0.0);
            img.mapv_inplace(|v| v - m);
        }
        Detrend::Plane => {
            // centred coordinates make the normal equations diagonal; the
            // mean goes first, so that a large offset does not round the
            // slopes' sums (1e13 on a field of unit roughness moved beta
            // by 5e-5)
            let c0 = img.mean().unwrap_or(0.0);
            img.mapv_inplace(|v| v - c0);
            let (cx, cy) = ((nx as f64 - 1.0) / 2.0, (ny as f64 - 1.0) / 2.0);
            let (mut sx, mut sy, mut sxx, mut syy) = (0.0, 0.0, 0.0, 0.0);
            for ((y, x), &v) in img.indexed_iter() {
                let (u, w) = (x as f64 - cx, y as f64 - cy);
                sx += u * v;
                sy += w * v;
                sxx += u * u;
                syy += w * w;
            }
            let c1 = if sxx > 0.0 { sx / sxx } else { 0.0 };
            let c2 = if syy > 0.0 { sy / syy } else { 0.0 };
            for ((y, x), v) in img.indexed_iter_mut() {
                *v -= c1 * (x as f64 - cx) + c2 * (y as f64 - cy);
            }
        }
    }
}

/// The power spectrum of a field, its missing pixels filled as `cfg.fill`
/// says ([`HoleFill`]; the harmonic fill wraps around the borders without
/// a taper, [`Window::None`], whose FFT takes the field for a torus), as
/// `wtmm spectrum` and the trace moments compute it.
///
/// **Errors** as [`crate::Field::filled`] and [`power_spectrum`].
pub fn field_power_spectrum(
    field: &crate::Field,
    cfg: &PowerSpectrumConfig,
) -> Result<PowerSpectrum> {
    field.check()?;
    match (cfg.fill, field.mask.is_some()) {
        // an untapered FFT takes the field for a torus: so does the fill
        (HoleFill::Harmonic, true) => {
            let torus = cfg.window == Window::None;
            power_spectrum(field.filled_harmonic_on(torus)?.view(), cfg)
        }
        _ => power_spectrum(field.filled()?.view(), cfg),
    }
}

/// The pixels of `field`'s largest hole as [`field_power_spectrum`] fills
/// it: across the borders without a taper (a torus), for
/// [`large_hole_warning`].
pub fn largest_filled_hole(field: &crate::Field, cfg: &PowerSpectrumConfig) -> usize {
    let torus = cfg.window == Window::None;
    field.hole_sizes(torus).into_iter().max().unwrap_or(0)
}

/// Angle-averaged power spectrum of one image (finite values only; fill masked
/// pixels first, or use [`field_power_spectrum`]).
///
/// **Errors** if a value is not finite, the values are beyond
/// [`crate::field::AMPLITUDE_LIMIT`], or the image is smaller than 4x4.
pub fn power_spectrum(img: ArrayView2<f64>, cfg: &PowerSpectrumConfig) -> Result<PowerSpectrum> {
    let (ny, nx) = img.dim();
    if ny < 4 || nx < 4 {
        return Err(Error::Input(format!(
            "image {ny}x{nx} too small for a spectrum"
        )));
    }
    if img.iter().any(|v| !v.is_finite()) {
        return Err(Error::Input("non-finite values in the image".into()));
    }
    if let Some(why) = crate::field::amplitude_problem(img.iter()) {
        return Err(Error::Input(why));
    }
    check_bins(cfg.bins_per_octave)?;
    // (row-major whatever the view's layout: the rows are read as slices)
    let mut f = img.as_standard_layout().into_owned();
    detrend(&mut f, cfg.detrend);
    let mut wsum2 = (nx * ny) as f64;
    if cfg.window == Window::Hann {
        let hann = |i: usize, n: usize| {
            let t = std::f64::consts::PI * (i as f64 + 0.5) / n as f64;
            t.sin().powi(2)
        };
        let wx: Vec<f64> = (0..nx).map(|x| hann(x, nx)).collect();
        let wy: Vec<f64> = (0..ny).map(|y| hann(y, ny)).collect();
        for ((y, x), v) in f.indexed_iter_mut() {
            *v *= wx[x] * wy[y];
        }
        wsum2 = wx.iter().map(|w| w * w).sum::<f64>() * wy.iter().map(|w| w * w).sum::<f64>();
    }
    // FFT (real rows, then complex columns) of the half plane kx >= 0
    let nh = nx / 2 + 1;
    let r2c = RealFftPlanner::<f64>::new().plan_fft_forward(nx);
    let fy = FftPlanner::<f64>::new().plan_fft_forward(ny);
    let mut half = vec![Complex64::default(); ny * nh];
    let mut row = vec![0.0; nx];
    for (y, out) in half.chunks_exact_mut(nh).enumerate() {
        row.copy_from_slice(f.row(y).as_slice().expect("standard layout"));
        r2c.process(&mut row, out).expect("lengths from plan");
    }
    let mut t = vec![Complex64::default(); ny * nh];
    transpose::transpose(&half, &mut t, nh, ny);
    fy.process(&mut t);
    let mut ps = PowerSpectrum {
        bins_per_octave: cfg.bins_per_octave,
        images: 1,
        ..Default::default()
    };
    for kx in 0..nh {
        // modes kx and nx - kx are conjugate twins: count the half plane once,
        // with weight 2 for the kx that have a twin (an average is unchanged)
        let w = if kx == 0 || (nx % 2 == 0 && kx == nx / 2) {
            1
        } else {
            2
        };
        for ky in 0..ny {
            let s = t[kx * ny + ky].norm_sqr() / wsum2;
            ps.add(mode_k(kx, nx, ky, ny), s, w);
        }
    }
    Ok(ps)
}

/// `bins_per_octave` in 1..=64: at 1024 px the modes of the last
/// octave are 1/512 octave apart, so 64 bins already leave most empty, and
/// a larger number only overflows the bin index.
fn check_bins(b: usize) -> Result<()> {
    if !(1..=64).contains(&b) {
        return Err(Error::param(
            "bins-per-octave",
            format!("must be in 1..=64, got {b}"),
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The large-hole warning speaks above 5 % of the image only, and
    /// gives the share.
    #[test]
    fn large_holes_are_said() {
        assert!(large_hole_warning(0.05).is_none());
        assert!(
            large_hole_warning(0.16)
                .unwrap()
                .starts_with("one hole covers 16 %")
        );
    }

    /// A view of any layout (here a transposed one, column-major) gives the
    /// spectrum of its values: the rows used to be read as slices of the
    /// copied view, which panicked on such a layout.
    #[test]
    fn any_layout_gives_the_same_spectrum() {
        let a = Array2::from_shape_fn((40, 48), |(y, x)| {
            ((y * 7 + x * 3) % 11) as f64 + (0.3 * x as f64).sin() * (0.2 * y as f64).cos()
        });
        let cfg = PowerSpectrumConfig::default();
        let t = power_spectrum(a.t(), &cfg).unwrap();
        let s = power_spectrum(a.t().as_standard_layout().view(), &cfg).unwrap();
        assert_eq!(format!("{t:?}"), format!("{s:?}"));
    }

    /// A field with an exact power law: sum of cosines with amplitudes
    /// |k|^-β/2 on the modes of one quadrant (deterministic phases). Its
    /// binned spectrum is the exact periodogram of those modes to rounding
    /// (no window, periodic field), and the binned fit of the law on the
    /// whole plane gives the β put in.
    #[test]
    fn recovers_exact_power_law() {
        let n = 128;
        let beta = 3.0;
        let mut f = Array2::<f64>::zeros((n, n));
        let two_pi = 2.0 * std::f64::consts::PI;
        for p in 0..n / 2 {
            for q in 0..n / 2 {
                if p + q == 0 {
                    continue;
                }
                let k = two_pi * ((p * p + q * q) as f64).sqrt() / n as f64;
                let amp = k.powf(-beta / 2.0);
                let ph = (p * 7 + q * 13) as f64;
                for ((y, x), v) in f.indexed_iter_mut() {
                    *v += amp * (two_pi * (p * x + q * y) as f64 / n as f64 + ph).cos();
                }
            }
        }
        let cfg = PowerSpectrumConfig {
            window: Window::None,
            detrend: Detrend::Mean,
            bins_per_octave: 4,
            ..Default::default()
        };
        let ps = power_spectrum(f.view(), &cfg).unwrap();
        let fit = ps.fit(0.1, 1.5).unwrap();
        // ranges that are no fit range: refused, not recorded as asked
        for (lo, hi) in [
            (0.1, 4.0),
            (0.0, 1.0),
            (1.0, 0.5),
            (f64::NAN, 1.0),
            (0.1, f64::INFINITY),
        ] {
            let e = ps.fit(lo, hi).unwrap_err().to_string();
            assert!(e.contains("k-range") && e.contains("Nyquist"), "{e}");
        }
        // the exact periodogram of these modes: each cosine of amplitude A
        // puts |F|^2 / n^2 = A^2 n^2 / 4 on its mode and on its twin
        let mut dens = Array2::<f64>::zeros((n, n));
        for p in 0..n / 2 {
            for q in 0..n / 2 {
                if p + q == 0 {
                    continue;
                }
                let k = two_pi * ((p * p + q * q) as f64).sqrt() / n as f64;
                let v = k.powf(-beta) * (n * n) as f64 / 4.0;
                dens[[q, p]] += v;
                dens[[(n - q) % n, (n - p) % n]] += v;
            }
        }
        let exact = PowerSpectrum::from_density(dens.view(), 4).unwrap();
        assert_eq!(ps.count, exact.count);
        for (b, (a, e)) in ps.sum_s.iter().zip(&exact.sum_s).enumerate() {
            // FFT rounding: 1e-12 of the bin's power is ample for n = 128
            assert!(
                (a - e).abs() <= 1e-12 * e.abs().max(1e-300) + 1e-18,
                "bin {b}: {a} vs {e}"
            );
        }
        let fe = exact.fit(0.1, 1.5).unwrap();
        assert!(
            (fit.beta - fe.beta).abs() < 1e-9,
            "beta {} vs {}",
            fit.beta,
            fe.beta
        );
        // the binned fit of the power law itself, on every mode of the
        // plane: the lattice and the log bins leave it 0.004 off (these
        // cosines fill one quadrant of each bin, whose uneven coverage of
        // the small-k shells gives 3.036 above, exactly as their density)
        let full = Array2::from_shape_fn((n, n), |(ky, kx)| {
            let k = mode_k(kx, n, ky, n);
            if k == 0.0 { 0.0 } else { k.powf(-beta) }
        });
        let ff = PowerSpectrum::from_density(full.view(), 4)
            .unwrap()
            .fit(0.1, 1.5)
            .unwrap();
        assert!((ff.beta - beta).abs() < 0.005, "beta {}", ff.beta);
    }

    /// The jackknife of β equals leave-one-out fits of the other images'
    /// merged spectra, and estimates the same sampling error as the spread
    /// of the per-image fits (fBm, H = 0.4, 16 images of 128²).
    #[test]
    fn jackknife_beta_is_the_leave_one_out_spread() {
        let cfg = PowerSpectrumConfig::for_field(false);
        let params = crate::synth::fbm::FbmParams { hurst: 0.4 };
        let parts: Vec<PowerSpectrum> = (0..16)
            .map(|i| {
                let f = crate::synth::fbm::fbm(params, 128, 128, 7, i).unwrap();
                power_spectrum(f.view(), &cfg).unwrap()
            })
            .collect();
        let (lo, hi) = default_k_range(128);
        let se = jackknife_beta_se(&parts, lo, hi).unwrap();
        // brute force: merge the others
        let loo: Vec<f64> = (0..parts.len())
            .map(|i| {
                let mut t = PowerSpectrum::default();
                for (j, p) in parts.iter().enumerate() {
                    if j != i {
                        t.merge(p).unwrap();
                    }
                }
                t.fit(lo, hi).unwrap().beta
            })
            .collect();
        let brute = crate::stats::fit::jackknife_se(&loo);
        assert!((se - brute).abs() < 1e-9 * brute, "{se} vs {brute}");
        // the per-image spread / sqrt(n) estimates the same error; with 16
        // images each estimate is uncertain by about a fifth, so within 2x
        let per: Vec<f64> = parts.iter().map(|p| p.fit(lo, hi).unwrap().beta).collect();
        let m = per.iter().sum::<f64>() / 16.0;
        let sd = (per.iter().map(|b| (b - m) * (b - m)).sum::<f64>() / 15.0).sqrt();
        let ratio = se / (sd / 4.0);
        assert!(
            (0.5..2.0).contains(&ratio),
            "jackknife {se}, sd/sqrt(n) {}",
            sd / 4.0
        );
        // too few images: no error
        assert!(jackknife_beta_se(&parts[..2], lo, hi).unwrap().is_nan());
    }

    /// `from_density` of an image's own `|f̂|²/(nx ny)` (direct DFT) bins it
    /// exactly as `power_spectrum` does, on an odd, non-square grid.
    #[test]
    fn from_density_bins_like_power_spectrum() {
        let (ny, nx) = (9, 12);
        let f = Array2::from_shape_fn((ny, nx), |(y, x)| ((3 * x + 7 * y * y) % 11) as f64);
        let two_pi = 2.0 * std::f64::consts::PI;
        let s = Array2::from_shape_fn((ny, nx), |(ky, kx)| {
            let mut z = Complex64::default();
            for ((y, x), &v) in f.indexed_iter() {
                let ph =
                    two_pi * (kx as f64 * x as f64 / nx as f64 + ky as f64 * y as f64 / ny as f64);
                z += Complex64::from_polar(v, -ph);
            }
            z.norm_sqr() / (nx * ny) as f64
        });
        let cfg = PowerSpectrumConfig {
            window: Window::None,
            detrend: Detrend::None,
            bins_per_octave: 4,
            ..Default::default()
        };
        let a = power_spectrum(f.view(), &cfg).unwrap().points();
        let b = PowerSpectrum::from_density(s.view(), 4).unwrap().points();
        assert_eq!(a.len(), b.len());
        for (p, q) in a.iter().zip(&b) {
            assert!(
                (p.0 - q.0).abs() < 1e-12 && (p.1 - q.1).abs() < 1e-9 * q.1,
                "{p:?} vs {q:?}"
            );
        }
    }

    /// The bins by brute force: bin b of `B` per octave holds the modes with
    /// `π 2^-(b+1)/B < |k| <= π 2^-b/B` (k = 0 and the corners beyond
    /// Nyquist left out), reported at the geometric mean of their |k| with
    /// the mean of their densities; |k| from the signed DFT frequencies.
    #[test]
    fn bins_hold_their_modes_at_the_geometric_mean() {
        let pi = std::f64::consts::PI;
        for &(ny, nx, bpo) in &[(9, 12, 4), (16, 16, 1), (20, 7, 3)] {
            let s = Array2::from_shape_fn((ny, nx), |(ky, kx)| 1.0 + (ky * 31 + kx * 7) as f64);
            let got = PowerSpectrum::from_density(s.view(), bpo).unwrap().points();
            let mut want: std::collections::BTreeMap<i64, (f64, f64, f64)> = Default::default();
            for ((ky, kx), &v) in s.indexed_iter() {
                // signed frequency index written out, not `fourier::signed_bin`:
                // the reference must not share the code it checks
                let sk = |m: usize, n: usize| {
                    let m = m as f64;
                    let n = n as f64;
                    if m <= n / 2.0 { m } else { m - n }
                };
                let (fx, fy) = (
                    2.0 * pi * sk(kx, nx) / nx as f64,
                    2.0 * pi * sk(ky, ny) / ny as f64,
                );
                let k = fx.hypot(fy);
                if k == 0.0 || k > pi {
                    continue;
                }
                let b = ((pi / k).log2() * bpo as f64).floor() as i64;
                let lo = pi * 2f64.powf(-((b + 1) as f64) / bpo as f64);
                let hi = pi * 2f64.powf(-(b as f64) / bpo as f64);
                assert!(k > lo * (1.0 - 1e-12) && k <= hi * (1.0 + 1e-12));
                let e = want.entry(-b).or_default();
                *e = (e.0 + k.ln(), e.1 + v, e.2 + 1.0);
            }
            assert_eq!(got.len(), want.len(), "{ny}x{nx} {bpo}");
            for (g, (_, &(lk, sv, c))) in got.iter().zip(&want) {
                let (k, sm) = ((lk / c).exp(), sv / c);
                assert!(
                    (g.0 - k).abs() < 1e-12 * k && (g.1 - sm).abs() < 1e-12 * sm,
                    "{ny}x{nx} {bpo}: {g:?} vs ({k}, {sm})"
                );
            }
        }
    }

    /// `bins_in_range`, which bins only the modes below `2 k_hi`, counts
    /// the bins of the whole spectrum: square and not, odd sizes, one to
    /// eight bins per octave, ranges ending on bin edges and at Nyquist.
    #[test]
    fn bins_in_range_counts_the_whole_spectrum() {
        let pi = std::f64::consts::PI;
        for &(ny, nx) in &[(16, 16), (17, 40), (64, 64), (100, 37), (256, 200)] {
            for bpo in [1, 2, 4, 8] {
                let full = PowerSpectrum::from_density(Array2::ones((ny, nx)).view(), bpo)
                    .unwrap()
                    .points();
                let edge = |b: f64| pi * 2f64.powf(-b / bpo as f64);
                let n = ny.min(nx);
                for r in [
                    default_k_range(n),
                    (0.0, pi),
                    (edge(3.0), edge(1.0)),
                    (0.1, edge(2.0)),
                    (2.0 * pi / n as f64, 0.3),
                ] {
                    let want = full.iter().filter(|&&(k, _)| k >= r.0 && k <= r.1).count();
                    assert_eq!(
                        bins_in_range(ny, nx, bpo, r).unwrap(),
                        want,
                        "{ny}x{nx}, {bpo} bins per octave, {r:?}"
                    );
                }
            }
        }
        assert!(bins_in_range(8, 8, 0, (0.1, 1.0)).is_err());
    }
}
