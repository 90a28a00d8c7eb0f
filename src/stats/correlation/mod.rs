//! Space-scale correlation functions of the magnitudes (SPEC §6; II §5,
//! eqs 65-76, Fig 30).
//!
//! The magnitude at `(x, a)` is `w = ln M(x, a)` on the CWT grid (or
//! `w = ½ ln ε²` with `ε²` the box average of `|T|²` over a window of side
//! about `a`, II eqs 65-67), or `ln M` at the WTMMM of the skeleton (II §5.1
//! remark). Centred, `w̃ = w - <w>`, the two-scale correlation is
//!
//! ```text
//! C(Δx; a1, a2) = < w̃(x, a1) w̃(x + Δx, a2) >       (II eq 68)
//! ```
//!
//! averaged over `x`, over the direction of `Δx` (log-spaced `|Δx|` bins,
//! pair-weighted), then over the ensemble. A random W-cascade gives
//! `σ² (log2(L/Δx) - 2 + 2Δx/L)` for `sup(a1, a2) <= Δx < L` (II eq 76); an
//! fBm gives 0 beyond the analysing scale (Fig 30b).
//!
//! **Algorithm.** Every sum over pairs is an FFT cross-correlation:
//! `Σ_x f(x) g(x + d) = IFFT(conj(F) G)(d)`, O(N log N), never a pair loop.
//! Each real field gets one real-to-complex 2D FFT (half spectrum) and each
//! correlation one complex-to-real inverse. Per image and
//! pair of scales we bin `Σ w̃1 w̃2`, the pair count `Σ m1 m2`, and the two
//! cross terms `Σ w̃1 m2`, `Σ m1 w̃2` (with `m` the indicator of valid
//! points, or the WTMMM count per pixel for the skeleton), which is all the
//! ensemble-centred estimate below needs.
//!
//! **Centring.** SPEC §6 centres per image: `w̃ = w - (mean of w over the
//! image's valid points)`; [`PairCorrelation::c`] is that estimate. II eq 68
//! centres with the ensemble mean; for a cascade whose magnitudes are
//! correlated across the whole image (log-correlated, non-ergodic), per-image
//! centring removes the part of the covariance shared by all points of an
//! image, about `σ² Σ_k 4^-k ≈ σ²/3` for a quaternary W-cascade. With
//! `δ_i = mean_i - <w>` the ensemble-centred sum is
//! `Σ w̃1 w̃2 + δ2 Σ w̃1 m2 + δ1 Σ m1 w̃2 + δ1 δ2 Σ m1 m2`, so both are exact
//! from the same per-image sums; [`PairCorrelation::c_ensemble`] reports the
//! second. Both are mergeable; errors come from a jackknife over images.
//!
//! **Domain.** The CWT is periodic. For a periodic field (W-cascades and
//! FISC are periodic by construction) the whole torus is exact, and lags
//! wrap around: `periodic = true` uses every pixel and circular
//! correlations. Otherwise the transform is trusted only in the interior
//! (SPEC §1 margin, here computed from the largest correlated scale) and the
//! correlations are linear: zero-padded FFTs, pair counts from the mask, so
//! no pair crosses the border.
//!
//! **Measured (32 x 1024², torus; max |C - eq 76| over the four pairs of
//! II Fig 30, `8.3 sup(a1, a2) < Δx < L/4`, i.e. the paper's
//! `Δx > sup(a1, a2)` with `a` in `σ_W` units; ensemble / per-image
//! centring).** Log-normal W-cascade, gauss (the paper's wavelet):
//! 0.017 / 0.023 with `ln M`, 0.016 / 0.023 with the box energy of II
//! eq 65: C falls below eq 76 by up to 0.02 at `Δx ≈ 10-30` px and joins it
//! beyond 100 px (the log-slope is about 60% of σ²). Mexican: 0.0024 /
//! 0.0064. The coarser cascade levels leak into `M(a)` like `(a/s)^(1-h)`
//! with one vanishing moment, `(a/s)^(3-h)` with three; the leak is shared
//! by distant points and anti-correlated with their own multipliers. A
//! control with the same σ² and `h = 0.6` (`m = -0.6 ln 2`), whose leak
//! decays more slowly, dips further out (-0.0075 at 90 px against -0.003;
//! max 0.019), and again not with mexican (0.0023). The
//! direction average itself moves eq 76 (stated along an axis) by only
//! -0.002. Per-image centring sits `σ²/3 ≈ 0.007` lower, as expected. fBm
//! (H = 1/3): |C| <= 0.0028 there; magnitudes decorrelate only beyond the
//! wavelets' support (C ≈ 0.016 at `Δx ≈ 4.6 a`); from `Δx > a` px the
//! wavelets overlap and the deviation is 0.14.
//!
//! **Cost.** Per image: the image FFT, one streamed inverse FFT per scale
//! ([`crate::cwt::CwtPlan::scale_rows`]: `½ ln |T|²` is taken from each row
//! block while it is in cache, with a vectorised `ln`), one real 2D FFT per
//! scale and one real inverse per pair, both in f32 (column FFTs on
//! gathered blocks, the cross-spectrum formed in the block; the padding
//! rows of a linear correlation and the rows of unbinned lags cost no row
//! FFT), and binning by a precomputed table of runs of consecutive lags
//! sharing a bin, in f64. On a rectangle whose every point is valid the
//! pair counts are closed forms and the cross terms come from summed-area
//! tables (no mask FFTs). 1024², one thread: 6.4-6.7 CWT scales on the
//! torus, 11.4-12.6 on a non-periodic interior (8.3 and 14.5 on a host
//! with faster FFTs; `cargo bench --bench
//! correlate`).
//!
//! ```
//! use ndarray::Array2;
//! use wtmm::Field;
//! use wtmm::cwt::Wavelet;
//! use wtmm::stats::correlation::*;
//! let cfg = CorrelationConfig {
//!     scales: vec![2.0],
//!     pairs: vec![(0, 0)],
//!     periodic: true,
//!     ..Default::default()
//! };
//! let plan = CorrelationPlan::new(64, 64, &cfg).unwrap();
//! let img = Array2::from_shape_fn((64, 64), |(y, x)| ((x * 7 + y * 3) % 11) as f64);
//! let s = cwt_correlation(&Field::new(img), &plan, "a").unwrap();
//! let r = correlation_estimates(&s).unwrap();
//! assert!(r.pairs[0].c0 > 0.0); // the variance of ln M
//! ```
//!
//! One image so correlated has no error bars (`stderr_method` "none"):
//! [`ensemble_correlation_sums`] is `correlate`'s recipe on fields in
//! memory, a lone image split into jackknife tiles, or a jackknife over 3
//! images or more.

use std::sync::{Arc, Mutex};

use ndarray::Array2;
use num_complex::{Complex32, Complex64};
use rayon::prelude::*;
use realfft::{ComplexToReal, RealFftPlanner, RealToComplex};
use rustfft::{Fft, FftPlanner};
use serde::{Deserialize, Serialize};

use crate::cwt::{CwtPlan, Wavelet, default_margin};
use crate::error::{Error, Result};
use crate::field::Field;
use crate::skeleton::distance_to_mask;
use crate::stats::pdf::Point;

mod fft;
mod ln;
mod result;
#[cfg(test)]
mod tests;

use fft::*;
use ln::*;
pub use result::*;

/// Which magnitude is correlated.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum Magnitude {
    /// `ln M(x, a)`.
    #[default]
    Lnm,
    /// `½ ln ε²(x, a)`, `ε²` the average of `|T|²` over a square of side
    /// `a` centred on the pixel, pixels cut by its edges weighted by the
    /// part they cover (II eqs 65, 67; SPEC §6's "window of size a").
    Energy,
}

/// Parameters of the correlation of one image.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CorrelationConfig {
    /// Analysing wavelet (SPEC §1; default gauss).
    pub wavelet: Wavelet,
    /// The distinct scales (px) involved.
    pub scales: Vec<f64>,
    /// Pairs `(i1, i2)` of indices into `scales`.
    pub pairs: Vec<(usize, usize)>,
    /// The field is periodic: use the whole torus and circular lags.
    pub periodic: bool,
    /// Interior margin (px) when not periodic; `None` = SPEC §1 default for
    /// the largest scale of `scales` (plus half the energy box with
    /// [`Magnitude::Energy`]).
    pub margin: Option<usize>,
    /// Log-spaced `|Δx|` bins per octave.
    pub bins_per_octave: usize,
    /// Largest `|Δx|` (px); `None` = half the smaller side of the domain.
    pub max_dx: Option<f64>,
    /// Which magnitude is correlated on the CWT grid ([`wtmmm_correlation`]
    /// always uses `ln M`).
    pub magnitude: Magnitude,
    /// Points with `M < eps max M` (at that scale) are left out.
    pub eps: f64,
    /// Trend removed from the image before the transform
    /// ([`crate::skeleton::AnalysisConfig::detrend`]; not with `periodic`).
    #[serde(default)]
    pub detrend: crate::field::Trend,
}

/// Settings with no scales nor pairs, a base for struct-update syntax:
/// the correlation refuses it as it stands. [`CorrelationConfig::fig30`]
/// gives the paper's (and `wtmm correlate`'s) scales and pairs.
impl Default for CorrelationConfig {
    fn default() -> Self {
        CorrelationConfig {
            wavelet: Wavelet::Gauss,
            scales: vec![],
            pairs: vec![],
            periodic: false,
            margin: None,
            bins_per_octave: 4,
            max_dx: None,
            magnitude: Magnitude::Lnm,
            eps: 1e-7,
            detrend: crate::field::Trend::None,
        }
    }
}

/// The scale pairs of II Fig 30 in octaves above `a_min` (the paper's
/// `a1 = a2 = 2`, `(1, 2)`, `(1, 4)`, `(2, 4)` in `σ_W` units), the
/// default of `wtmm correlate`.
pub const FIG30_PAIR_OCTAVES: [(f64, f64); 4] = [(1.0, 1.0), (0.0, 1.0), (0.0, 2.0), (1.0, 2.0)];

/// The distinct scales (px, ascending) of octave pairs above `a_min` and
/// the pairs as indices into them, as [`CorrelationConfig`] takes them.
/// A non-finite octave gives a non-finite scale, which the correlation's
/// checks refuse with a message.
pub fn pair_scales(a_min: f64, pairs: &[(f64, f64)]) -> (Vec<f64>, Vec<(usize, usize)>) {
    let mut oct: Vec<f64> = pairs.iter().flat_map(|&(a, b)| [a, b]).collect();
    oct.sort_by(f64::total_cmp);
    // (a NaN equals itself only under total_cmp)
    let same = |x: f64, o: f64| (x - o).abs() < 1e-9 || x.total_cmp(&o).is_eq();
    oct.dedup_by(|a, b| same(*a, *b));
    let idx = |o: f64| oct.iter().position(|&x| same(x, o)).unwrap_or(0);
    (
        oct.iter().map(|o| a_min * o.exp2()).collect(),
        pairs.iter().map(|&(a, b)| (idx(a), idx(b))).collect(),
    )
}

impl CorrelationConfig {
    /// The correlation `wtmm correlate` computes by default: the
    /// [`FIG30_PAIR_OCTAVES`] above `a_min` with `wavelet`, on the torus
    /// when `periodic` (the generators' cascades), else inside the default
    /// margin of the largest of those scales; other settings as
    /// [`Default`]. (The margin follows the scales correlated, so a pair
    /// alone reads a larger domain than within these four.)
    pub fn fig30(wavelet: Wavelet, a_min: f64, periodic: bool) -> Self {
        let (scales, pairs) = pair_scales(a_min, &FIG30_PAIR_OCTAVES);
        CorrelationConfig {
            wavelet,
            scales,
            pairs,
            periodic,
            ..Default::default()
        }
    }

    /// **Errors** naming the flag at fault.
    pub fn validate(&self) -> Result<()> {
        if self.scales.is_empty() || self.scales.iter().any(|a| !(a.is_finite() && *a > 0.0)) {
            return Err(Error::param("scales", "need positive finite scales"));
        }
        if self.pairs.is_empty() {
            return Err(Error::param("pairs", "no pair of scales given"));
        }
        if self.periodic && self.detrend != crate::field::Trend::None {
            return Err(Error::param(
                "detrend",
                "plane: the field is correlated whole as a torus (periodic), and a periodic \
                 field has no planar trend: the removed plane would be a jump across its \
                 edges. Give --margin N (--domain interior) to correlate the interior, or drop \
                 --detrend",
            ));
        }
        if let Some(&(i, j)) = self
            .pairs
            .iter()
            .find(|&&(i, j)| i >= self.scales.len() || j >= self.scales.len())
        {
            return Err(Error::param(
                "pairs",
                format!("pair ({i}, {j}) refers to a missing scale"),
            ));
        }
        if self.bins_per_octave == 0 || self.bins_per_octave > 64 {
            return Err(Error::param(
                "bins-per-octave",
                format!("must be in 1..=64, got {}", self.bins_per_octave),
            ));
        }
        if let Some(m) = self.max_dx
            && !(m >= 1.0 && m.is_finite())
        {
            return Err(Error::param(
                "max-dx",
                format!("must be >= 1 px, got {m_s}", m_s = crate::error::short(m)),
            ));
        }
        if !(self.eps >= 0.0 && self.eps < 1.0) {
            return Err(Error::param("eps", "must be in [0, 1)"));
        }
        Ok(())
    }

    /// The interior margin used (px): 0 on a torus, else `margin` or its
    /// default, the wavelet's support at the largest correlated scale (plus
    /// the energy box's reach).
    pub fn margin_px(&self) -> usize {
        if self.periodic {
            return 0;
        }
        let a_max = self.scales.iter().cloned().fold(0.0, f64::max);
        self.margin
            .unwrap_or_else(|| default_margin(self.wavelet, a_max) + self.box_reach(a_max))
    }

    /// How far beyond a point its magnitude reads the transform, on top of
    /// the wavelet's support: the box of the energy magnitude (the pixels
    /// it touches, [`box_weights`]), 0 for `ln M`.
    fn box_reach(&self, a: f64) -> usize {
        match self.magnitude {
            Magnitude::Energy => box_weights(a).len() / 2,
            Magnitude::Lnm => 0,
        }
    }
}

/// Marker of lags beyond `max_dx` (or aliased).
const UNUSED: u16 = u16::MAX;

/// Lag indices `start .. start + len` all in bin `bin`.
#[derive(Clone, Copy, Debug)]
struct Run {
    start: u32,
    len: u32,
    bin: u16,
}

/// Run-length encoding of a lag -> bin table, [`UNUSED`] left out.
fn runs_of(bin: &[u16]) -> Vec<Run> {
    let mut runs: Vec<Run> = Vec::new();
    for (k, &b) in bin.iter().enumerate() {
        if b == UNUSED {
            continue;
        }
        match runs.last_mut() {
            Some(r) if r.bin == b && (r.start + r.len) as usize == k => r.len += 1,
            _ => runs.push(Run {
                start: k as u32,
                len: 1,
                bin: b,
            }),
        }
    }
    runs
}

/// `Σ v` in f64 with four accumulators (vectorisable; the order differs
/// from a sequential sum only by rounding).
fn slice_sum<T: Copy + Into<f64>>(v: &[T]) -> f64 {
    let mut acc = [0.0f64; 4];
    let ch = v.chunks_exact(4);
    let rem = ch.remainder();
    for c in ch {
        acc[0] += c[0].into();
        acc[1] += c[1].into();
        acc[2] += c[2].into();
        acc[3] += c[3].into();
    }
    (acc[0] + acc[1]) + (acc[2] + acc[3]) + rem.iter().map(|&x| x.into()).sum::<f64>()
}

/// Calls `f(k, sy, sx, bin)` for every lag index `k` of the runs, with its
/// signed lag (linear correlation: indices above `maxlag` are negative
/// lags; only used lags are in runs).
fn for_each_lag(
    runs: &[Run],
    fy: usize,
    fx: usize,
    maxlag: usize,
    mut f: impl FnMut(usize, i64, i64, usize),
) {
    let signed = |i: usize, n: usize| {
        if i <= maxlag {
            i as i64
        } else {
            i as i64 - n as i64
        }
    };
    for run in runs {
        let k0 = run.start as usize;
        let (mut iy, mut ix) = (k0 / fx, k0 % fx);
        for k in k0..k0 + run.len as usize {
            f(k, signed(iy, fy), signed(ix, fx), run.bin as usize);
            ix += 1;
            if ix == fx {
                ix = 0;
                iy += 1;
            }
        }
    }
}

/// A resolved correlation: domain, FFT plans, the lag -> bin table, and the
/// CWT plan of the scales. Built once per image shape, shared by all images.
pub struct CorrelationPlan {
    cfg: CorrelationConfig,
    ny: usize,
    nx: usize,
    /// Domain `[y0, y1) x [x0, x1)`.
    y0: usize,
    y1: usize,
    x0: usize,
    x1: usize,
    fft: RFft2,
    /// The lag -> bin table as runs of consecutive lag indices (in memory
    /// order) sharing a bin (`0` = lag 0, `b + 1` = log bin b); lags beyond
    /// `max_dx` (or aliased) are in no run. Binning sums contiguous slices.
    runs: Vec<Run>,
    /// `log2 |d|` of each lag index (0 at lag 0), for the weighted sums.
    l2: Vec<f32>,
    n_bins: usize,
    /// Number of lags and `Σ log2|d|` per bin (the uniform-count case).
    lag_n: Vec<f64>,
    lag_l: Vec<f64>,
    /// Pair counts and `Σ log2|d|`-weighted counts per bin when every point
    /// of the (non-periodic) domain is valid: `(dy - |sy|)(dx - |sx|)` pairs
    /// at lag `(sy, sx)`, exact, no FFT.
    rect_n: Vec<f64>,
    rect_l: Vec<f64>,
    /// Largest lag index of the linear correlation.
    maxlag: usize,
    max_dx: f64,
    cwt: CwtPlan,
    /// Workspaces of finished calls (one per thread at most).
    pool: Mutex<Vec<Workspace>>,
}

/// A clone shares the FFT plans and copies the lag tables; the workspaces
/// of finished calls are not copied (the clone grows its own). Written by
/// hand because a `Mutex` is not `Clone`.
impl Clone for CorrelationPlan {
    fn clone(&self) -> Self {
        Self {
            cfg: self.cfg.clone(),
            ny: self.ny,
            nx: self.nx,
            y0: self.y0,
            y1: self.y1,
            x0: self.x0,
            x1: self.x1,
            fft: self.fft.clone(),
            runs: self.runs.clone(),
            l2: self.l2.clone(),
            n_bins: self.n_bins,
            lag_n: self.lag_n.clone(),
            lag_l: self.lag_l.clone(),
            rect_n: self.rect_n.clone(),
            rect_l: self.rect_l.clone(),
            maxlag: self.maxlag,
            max_dx: self.max_dx,
            cwt: self.cwt.clone(),
            pool: Mutex::new(Vec::new()),
        }
    }
}

/// What a plan is for (the FFT plans and lag tables are not printed).
impl std::fmt::Debug for CorrelationPlan {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CorrelationPlan")
            .field("cfg", &self.cfg)
            .field("ny", &self.ny)
            .field("nx", &self.nx)
            .field("domain", &((self.y0, self.y1), (self.x0, self.x1)))
            .finish_non_exhaustive()
    }
}

/// Smallest `n' >= n` whose prime factors are 2, 3, 5, 7 (fast FFT sizes).
fn smooth(n: usize) -> usize {
    let mut m = n.max(1);
    loop {
        let mut r = m;
        for p in [2, 3, 5, 7] {
            while r.is_multiple_of(p) {
                r /= p;
            }
        }
        if r == 1 {
            return m;
        }
        m += 1;
    }
}

impl CorrelationPlan {
    /// Plans the correlation of `ny x nx` images.
    ///
    /// **Errors** on an invalid configuration, an image smaller than 8x8, a
    /// domain with no pixel, or a `max_dx` beyond what the domain holds
    /// (half the torus when periodic).
    pub fn new(ny: usize, nx: usize, cfg: &CorrelationConfig) -> Result<Self> {
        cfg.validate()?;
        // the transform's own limit, said before the domain's lags (a 1-px
        // wide image would otherwise be told about --max-dx)
        if ny < 8 || nx < 8 {
            return Err(Error::Input(format!(
                "image {ny}x{nx} is too small (need at least 8x8)"
            )));
        }
        let margin = cfg.margin_px();
        let (y0, y1, x0, x1) = (
            margin.min(ny),
            ny.saturating_sub(margin),
            margin.min(nx),
            nx.saturating_sub(margin),
        );
        if y0 >= y1 || x0 >= x1 {
            return Err(Error::Input(format!(
                "image {ny}x{nx} has no interior at margin {margin} px (use a smaller margin or smaller scales: --margin, --octaves)"
            )));
        }
        let (dy, dx) = (y1 - y0, x1 - x0);
        let limit = if cfg.periodic {
            (dy.min(dx) / 2) as f64
        } else {
            (dy.min(dx) - 1) as f64
        };
        let max_dx = cfg.max_dx.unwrap_or((dy.min(dx) / 2) as f64);
        if !(max_dx >= 1.0 && max_dx <= limit) {
            return Err(Error::param(
                "max-dx",
                format!(
                    "{} px is outside [1, {limit}] for a {dy}x{dx} domain",
                    crate::error::short(max_dx)
                ),
            ));
        }
        let maxlag = max_dx.floor() as usize;
        let (fy, fx) = if cfg.periodic {
            (ny, nx)
        } else {
            (smooth(dy + maxlag), smooth(dx + maxlag))
        };
        let bpo = cfg.bins_per_octave as f64;
        let n_bins = (bpo * max_dx.log2() + 0.5).floor() as usize + 1;
        let signed = |i: usize, n: usize| -> Option<i64> {
            if cfg.periodic {
                Some(crate::fourier::signed_bin(i, n))
            } else if i <= maxlag {
                Some(i as i64)
            } else if i >= n - maxlag {
                Some(i as i64 - n as i64)
            } else {
                None
            }
        };
        let mut bin = vec![UNUSED; fy * fx];
        let mut l2 = vec![0.0f32; fy * fx];
        for iy in 0..fy {
            let Some(sy) = signed(iy, fy) else { continue };
            for ix in 0..fx {
                let Some(sx) = signed(ix, fx) else { continue };
                let r2 = (sy * sy + sx * sx) as f64;
                let k = iy * fx + ix;
                if r2 == 0.0 {
                    bin[k] = 0;
                    continue;
                }
                let r = r2.sqrt();
                if r > max_dx {
                    continue;
                }
                let lr = r.log2();
                let b = (bpo * lr + 0.5).floor() as usize;
                bin[k] = (b.min(n_bins - 1) + 1) as u16;
                l2[k] = lr as f32;
            }
        }
        let mut lag_n = vec![0.0; n_bins + 1];
        let mut lag_l = vec![0.0; n_bins + 1];
        for (&b, &l) in bin.iter().zip(&l2) {
            if b != UNUSED {
                lag_n[b as usize] += 1.0;
                lag_l[b as usize] += l as f64;
            }
        }
        let runs = runs_of(&bin);
        let (mut rect_n, mut rect_l) = (vec![0.0; n_bins + 1], vec![0.0; n_bins + 1]);
        if !cfg.periodic {
            for_each_lag(&runs, fy, fx, maxlag, |k, sy, sx, b| {
                let (ay, ax) = (sy.unsigned_abs() as usize, sx.unsigned_abs() as usize);
                if ay < dy && ax < dx {
                    let c = ((dy - ay) * (dx - ax)) as f64;
                    rect_n[b] += c;
                    rect_l[b] += c * l2[k] as f64;
                }
            });
        }
        Ok(CorrelationPlan {
            lag_n,
            lag_l,
            rect_n,
            rect_l,
            maxlag,
            cfg: cfg.clone(),
            ny,
            nx,
            y0,
            y1,
            x0,
            x1,
            fft: RFft2::new(fy, fx, dy, maxlag),
            runs,
            l2,
            n_bins,
            max_dx,
            cwt: CwtPlan::new(ny, nx, cfg.wavelet, &cfg.scales)?,
            pool: Mutex::new(Vec::new()),
        })
    }

    /// The configuration.
    pub fn config(&self) -> &CorrelationConfig {
        &self.cfg
    }

    /// FFT size `(fy, fx)` (for cost estimates).
    pub fn fft_shape(&self) -> (usize, usize) {
        (self.fft.fy, self.fft.fx)
    }

    /// The domain `(y0, y1, x0, x1)`.
    pub fn domain(&self) -> (usize, usize, usize, usize) {
        (self.y0, self.y1, self.x0, self.x1)
    }

    fn empty_sums(&self, source: &str) -> CorrelationSums {
        CorrelationSums {
            version: crate::VERSION.to_string(),
            source: source.to_string(),
            scales: self.cfg.scales.clone(),
            pairs: self.cfg.pairs.clone(),
            bins_per_octave: self.cfg.bins_per_octave,
            max_dx: self.max_dx,
            periodic: self.cfg.periodic,
            // the skeleton's magnitudes are always ln M
            magnitude: if source == "wtmmm" {
                Magnitude::Lnm
            } else {
                self.cfg.magnitude
            },
            // the skeleton's points carry their own wavelet and threshold
            wavelet: (source == "cwt").then_some(self.cfg.wavelet),
            eps: (source == "cwt").then_some(self.cfg.eps),
            margin: self.cfg.margin_px(),
            images: vec![],
        }
    }

    /// A workspace from the pool (or a fresh one).
    fn take(&self) -> Workspace {
        self.pool
            .lock()
            .expect("no panic while holding the pool")
            .pop()
            .unwrap_or_default()
    }

    /// Returns a workspace to the pool.
    fn give(&self, ws: Workspace) {
        self.pool
            .lock()
            .expect("no panic while holding the pool")
            .push(ws);
    }

    /// Per bin, `Σ_d Σ_{x ∈ R ∩ (R - d)} v(x)` for a field `v` on the domain
    /// rectangle `R` (at the origin of the FFT grid), from its summed-area
    /// table: O(1) per lag instead of an FFT correlation with the mask.
    fn rect_sums(&self, v: &[f64], sat: &mut Vec<f64>) -> Vec<f64> {
        let (dy, dx, fx) = (self.y1 - self.y0, self.x1 - self.x0, self.fft.fx);
        let w = dx + 1;
        sat.clear();
        sat.resize((dy + 1) * w, 0.0);
        for y in 0..dy {
            let mut run = 0.0;
            for x in 0..dx {
                run += v[y * fx + x];
                sat[(y + 1) * w + x + 1] = sat[y * w + x + 1] + run;
            }
        }
        let mut out = vec![0.0; self.n_bins + 1];
        let (fy, ml) = (self.fft.fy, self.maxlag);
        for_each_lag(&self.runs, fy, fx, ml, |_, sy, sx, b| {
            let (ay, ax) = (sy.unsigned_abs() as usize, sx.unsigned_abs() as usize);
            if ay < dy && ax < dx {
                // rows [max(0, -sy), dy - max(0, sy)), same for columns
                let (ya, yb) = (
                    if sy < 0 { ay } else { 0 },
                    if sy > 0 { dy - ay } else { dy },
                );
                let (xa, xb) = (
                    if sx < 0 { ax } else { 0 },
                    if sx > 0 { dx - ax } else { dx },
                );
                out[b] += sat[yb * w + xb] - sat[ya * w + xb] - sat[yb * w + xa] + sat[ya * w + xa];
            }
        });
        out
    }

    /// Cross-correlations of the real fields `ws.fields[..n]` (each
    /// `fy x fx`, `[y][x]`, destroyed), binned: for each request
    /// `(a, b, counts)`, per bin, `Σ_d Σ_x f_a(x) f_b(x + d)` and, if
    /// `counts`, the same weighted by `log2 |d|` (else empty). `counts`
    /// marks fields of integer weights (masks, WTMMM per pixel): their
    /// correlation is an integer at every lag, so it is rounded there,
    /// which makes the pair counts exact despite the f32 FFT: its error
    /// per lag is about `ε log2(N) ||m1|| ||m2|| / √N <= ε log2(N) √N`
    /// (0.003 on 1024², 0.012 on 4096²), far below ½, and f32 holds every
    /// integer below 2^24 pairs per lag (images up to 4096²; beyond, the
    /// counts carry a relative error of 1e-7).
    fn binned(
        &self,
        ws: &mut Workspace,
        n: usize,
        requests: &[(usize, usize, bool)],
    ) -> Vec<(Vec<f64>, Vec<f64>)> {
        let (fy, fx, nh, cs) = (self.fft.fy, self.fft.fx, self.fft.nh, self.fft.cs);
        let ns = nh * fy;
        let Workspace {
            fields,
            spec,
            half,
            x,
            r,
            row,
            scratch,
            ..
        } = ws;
        scratch.resize(self.fft.scratch_len, Complex32::default());
        half.resize(ns, Complex32::default());
        x.resize(COLS * cs, Complex32::default());
        r.resize(fy * fx, 0.0);
        row.resize(fx, 0.0);
        while spec.len() < n {
            spec.push(Vec::new());
        }
        for (f, sp) in fields[..n].iter_mut().zip(spec.iter_mut()) {
            // (the padding stays zero: resize fills it, nothing writes it)
            sp.resize(nh * cs, Complex32::default());
            self.fft.forward(f, half, sp, row, scratch);
        }
        let mut out = Vec::with_capacity(requests.len());
        for &(a, b, counts) in requests {
            self.fft.correlate(&spec[a], &spec[b], x, half, r, scratch);
            out.push(self.bin(r, counts));
        }
        out
    }

    /// Bins one correlation `r` (lags on the FFT grid): per bin `Σ r` and,
    /// if `counts` (integer weights: `r` is rounded first, see
    /// [`Self::binned`]), `Σ r log2 |d|` (else empty).
    fn bin(&self, r: &mut [f32], counts: bool) -> (Vec<f64>, Vec<f64>) {
        if counts {
            for run in &self.runs {
                let (i, n) = (run.start as usize, run.len as usize);
                r[i..i + n].iter_mut().for_each(|v| *v = v.round());
            }
        }
        let mut s = vec![0.0; self.n_bins + 1];
        let mut sl = Vec::new();
        for run in &self.runs {
            let (i, n) = (run.start as usize, run.len as usize);
            s[run.bin as usize] += slice_sum(&r[i..i + n]);
        }
        if counts {
            sl = vec![0.0; self.n_bins + 1];
            for run in &self.runs {
                let (i, n) = (run.start as usize, run.len as usize);
                sl[run.bin as usize] += r[i..i + n]
                    .iter()
                    .zip(&self.l2[i..i + n])
                    .map(|(&v, &l)| v as f64 * l as f64)
                    .sum::<f64>();
            }
        }
        (s, sl)
    }

    /// Per-image sums from per-scale fields (values `w̃_s m_s` on the FFT
    /// grid, their weights `m_s`, per-scale means and point totals).
    fn sums_from_fields(
        &self,
        ws: &mut Workspace,
        source: &str,
        label: String,
        f: ScaleFields,
    ) -> CorrelationSums {
        let ns = f.n_vals;
        let np = self.cfg.pairs.len();
        let mut requests: Vec<(usize, usize, bool)> =
            self.cfg.pairs.iter().map(|&(a, b)| (a, b, false)).collect();
        // requests after the pairs: counts and cross terms
        let mut count_req = vec![usize::MAX; np];
        let mut wm_req = vec![usize::MAX; np];
        let mut mw_req = vec![usize::MAX; np];
        let wbase = ns;
        let n_fields = match f.weights {
            Weights::Uniform | Weights::Rect => ns,
            Weights::Shared => ns + 1,
            Weights::PerScale => 2 * ns,
        };
        // the rectangle's cross terms, before the FFTs destroy the fields:
        // Σ_x w̃(x) m(x + d) is the sum of w̃ over the sub-rectangle
        // R ∩ (R - d) (and Σ m(x) w̃(x + d) has the same bins)
        let mut rect_wm: Vec<Option<Vec<f64>>> = vec![None; ns];
        if matches!(f.weights, Weights::Rect) {
            for (s, slot) in rect_wm.iter_mut().enumerate() {
                if self.cfg.pairs.iter().any(|p| p.0 == s || p.1 == s) {
                    *slot = Some(self.rect_sums(&ws.fields[s], &mut ws.sat));
                }
            }
        }
        match f.weights {
            Weights::Uniform | Weights::Rect => {}
            Weights::Shared => {
                // one weight field for every scale (the CWT's common mask)
                let c = requests.len();
                requests.push((wbase, wbase, true));
                let mut wm_of = vec![usize::MAX; ns];
                for (s, slot) in wm_of.iter_mut().enumerate() {
                    if self.cfg.pairs.iter().any(|p| p.0 == s || p.1 == s) {
                        *slot = requests.len();
                        requests.push((s, wbase, false));
                    }
                }
                for (p, &(s1, s2)) in self.cfg.pairs.iter().enumerate() {
                    count_req[p] = c;
                    wm_req[p] = wm_of[s1];
                    // Σ m(x) w̃2(x + d) = Σ w̃2(y) m(y - d): same bins as Σ w̃2 m
                    mw_req[p] = wm_of[s2];
                }
            }
            Weights::PerScale => {
                for (p, &(s1, s2)) in self.cfg.pairs.iter().enumerate() {
                    count_req[p] = requests.len();
                    requests.push((wbase + s1, wbase + s2, true));
                    wm_req[p] = requests.len();
                    requests.push((s1, wbase + s2, false));
                    mw_req[p] = requests.len();
                    requests.push((wbase + s1, s2, false));
                }
            }
        }
        let (dy, dx) = (self.y1 - self.y0, self.x1 - self.x0);
        let grid =
            crate::spectra::TileGrid::new(f.tile_domain.unwrap_or((0, dy, 0, dx)), f.tile_side);
        let saved = grid
            .as_ref()
            .map(|g| self.tile_inputs(ws, g, &f.weights, ns, n_fields));
        // a tiled image with uniform weights FFTs its domain's indicator too
        let n_fwd = match (&saved, &f.weights) {
            (Some(_), Weights::Uniform | Weights::Rect) => n_fields + 1,
            _ => n_fields,
        };
        let res = self.binned(ws, n_fwd, &requests);
        let tiles = match (grid, saved) {
            (Some(g), Some(sv)) => {
                let dom = f.tile_domain.unwrap_or((0, dy, 0, dx));
                self.tile_sums(ws, &g, dom, &f.weights, ns, sv)
            }
            _ => Vec::new(),
        };
        let (lag_n, lag_l) = (&self.lag_n, &self.lag_l);
        let nb = self.n_bins + 1;
        let pairs = (0..np)
            .map(|p| {
                let (count, lcount, wm, mw) = match f.weights {
                    // every point valid on the torus: count = N per lag, and
                    // Σ_x w̃(x) = 0 kills the cross terms
                    Weights::Uniform => {
                        let n = f.totals[0];
                        (
                            lag_n.iter().map(|c| c * n).collect(),
                            lag_l.iter().map(|l| l * n).collect(),
                            vec![0.0; nb],
                            vec![0.0; nb],
                        )
                    }
                    Weights::Rect => {
                        let (s1, s2) = self.cfg.pairs[p];
                        let get = |s: usize| rect_wm[s].clone().expect("computed for pair scales");
                        (self.rect_n.clone(), self.rect_l.clone(), get(s1), get(s2))
                    }
                    Weights::Shared | Weights::PerScale => (
                        res[count_req[p]].0.clone(),
                        res[count_req[p]].1.clone(),
                        res[wm_req[p]].0.clone(),
                        res[mw_req[p]].0.clone(),
                    ),
                };
                PairSums {
                    ww: res[p].0.clone(),
                    wm,
                    mw,
                    count,
                    lcount,
                }
            })
            .collect();
        let mut s = self.empty_sums(source);
        s.images.push(CorrelationImage {
            label,
            mean: f.means,
            n: f.totals,
            pairs,
            tile_side: if tiles.is_empty() { 0 } else { f.tile_side },
            tiles,
        });
        s
    }

    /// Before the image's FFTs destroy its fields: per tile and scale the
    /// points and `Σ w̃`, and copies of the fields a tile's first points
    /// need (the values of the pairs' first scales and their weights). With
    /// uniform weights, writes the domain's indicator as field `ns` (which
    /// the image's FFTs then transform).
    fn tile_inputs(
        &self,
        ws: &mut Workspace,
        g: &crate::spectra::TileGrid,
        weights: &Weights,
        ns: usize,
        n_fields: usize,
    ) -> TileInputs {
        let (dy, dx, fx) = (self.y1 - self.y0, self.x1 - self.x0, self.fft.fx);
        let mut firsts: Vec<usize> = self.cfg.pairs.iter().map(|p| p.0).collect();
        firsts.sort_unstable();
        firsts.dedup();
        if matches!(weights, Weights::Uniform | Weights::Rect) {
            while ws.fields.len() <= n_fields {
                ws.fields.push(Vec::new());
            }
            let m = &mut ws.fields[n_fields];
            m.clear();
            m.resize(self.fft.fy * fx, 0.0);
            for y in 0..dy {
                m[y * fx..y * fx + dx].fill(1.0);
            }
        }
        // the weight field of scale s: the domain's indicator (field ns
        // above), the common mask (ns) or the scale's own (ns + s)
        let wf = |s: usize| weights.field_of(ns, s);
        let mut n = vec![vec![0.0; ns]; g.len()];
        let mut wsum = vec![vec![0.0; ns]; g.len()];
        for s in 0..ns {
            let (v, m) = (&ws.fields[s], &ws.fields[wf(s)]);
            for y in 0..dy {
                for x in 0..dx {
                    let k = y * fx + x;
                    let t = g.index(x as u32, y as u32);
                    n[t][s] += m[k];
                    wsum[t][s] += v[k];
                }
            }
        }
        let values = firsts.iter().map(|&s| ws.fields[s].clone()).collect();
        let mut wts: Vec<usize> = firsts.iter().map(|&s| wf(s)).collect();
        wts.dedup();
        let weights = wts.iter().map(|&j| ws.fields[j].clone()).collect();
        TileInputs {
            firsts,
            values,
            weights,
            n,
            wsum,
        }
    }

    /// Per tile, the pair sums whose first point lies in it: the first
    /// scale's values and weights cut to the tile, correlated with the
    /// whole image's spectra (`ws.spec`, left by [`Self::binned`]).
    fn tile_sums(
        &self,
        ws: &mut Workspace,
        g: &crate::spectra::TileGrid,
        grid_domain: (usize, usize, usize, usize),
        weights: &Weights,
        ns: usize,
        inp: TileInputs,
    ) -> Vec<CorrelationTile> {
        let (fy, fx, nh, cs) = (self.fft.fy, self.fft.fx, self.fft.nh, self.fft.cs);
        let full = std::mem::take(&mut ws.spec);
        let wfull = |s: usize| weights.field_of(ns, s);
        let nv = inp.firsts.len();
        let n_tf = nv + inp.weights.len();
        let (dy, dx) = (self.y1 - self.y0, self.x1 - self.x0);
        // the tiles in parallel (a lone image would leave the other cores
        // idle), each worker with its own buffers; the results come back in
        // tile order, the same bits whatever the thread count
        let buffers = || TileBuffers {
            spec: vec![vec![Complex32::default(); nh * cs]; n_tf],
            cut: vec![0.0f64; fy * fx],
            half: vec![Complex32::default(); nh * fy],
            x: vec![Complex32::default(); COLS * cs],
            r: vec![0.0f32; fy * fx],
            row: vec![0.0f32; fx],
            scratch: vec![Complex32::default(); self.fft.scratch_len],
        };
        let out = (0..g.len())
            .into_par_iter()
            .map_init(buffers, |b, t| {
                // the edge tiles reach the domain's edges: a point outside
                // the tiles' domain belongs to the nearest tile, as
                // TileGrid::index
                let (mut ya, mut yb, mut xa, mut xb) = g.bounds(t);
                if ya == grid_domain.0 {
                    ya = 0;
                }
                if yb == grid_domain.1 {
                    yb = dy;
                }
                if xa == grid_domain.2 {
                    xa = 0;
                }
                if xb == grid_domain.3 {
                    xb = dx;
                }
                let TileBuffers {
                    spec,
                    cut,
                    half,
                    x,
                    r,
                    row,
                    scratch,
                } = b;
                for (src, sp) in inp.values.iter().chain(&inp.weights).zip(spec.iter_mut()) {
                    cut.fill(0.0);
                    for y in ya..yb {
                        cut[y * fx + xa..y * fx + xb]
                            .copy_from_slice(&src[y * fx + xa..y * fx + xb]);
                    }
                    self.fft.forward_rows(cut, ya..yb, half, sp, row, scratch);
                }
                let mut done: std::collections::HashMap<(usize, usize), (Vec<f64>, Vec<f64>)> =
                    Default::default();
                let pairs = self
                    .cfg
                    .pairs
                    .iter()
                    .map(|&(s1, s2)| {
                        let jv = inp.firsts.iter().position(|&s| s == s1).expect("listed");
                        // the first scale's weights in the tile
                        let jm = nv + if inp.weights.len() == 1 { 0 } else { jv };
                        // (tile field, whole-image field): pairs sharing a
                        // first or second scale share their weights'
                        // correlations
                        let mut one = |a: usize, bi: usize, counts: bool| {
                            done.entry((a, bi))
                                .or_insert_with(|| {
                                    self.fft.correlate(&spec[a], &full[bi], x, half, r, scratch);
                                    self.bin(r, counts)
                                })
                                .clone()
                        };
                        let ww = one(jv, s2, false).0;
                        let wm = one(jv, wfull(s2), false).0;
                        let mw = one(jm, s2, false).0;
                        let (count, lcount) = one(jm, wfull(s2), true);
                        PairSums {
                            ww,
                            wm,
                            mw,
                            count,
                            lcount,
                        }
                    })
                    .collect();
                CorrelationTile {
                    n: inp.n[t].clone(),
                    wsum: inp.wsum[t].clone(),
                    pairs,
                }
            })
            .collect();
        ws.spec = full;
        out
    }
}

/// One worker's buffers in [`CorrelationPlan::tile_sums`].
struct TileBuffers {
    spec: Vec<Vec<Complex32>>,
    cut: Vec<f64>,
    half: Vec<Complex32>,
    x: Vec<Complex32>,
    r: Vec<f32>,
    row: Vec<f32>,
    scratch: Vec<Complex32>,
}

/// What [`CorrelationPlan::tile_sums`] needs of an image's fields.
struct TileInputs {
    /// The distinct first scales of the pairs.
    firsts: Vec<usize>,
    /// Their value fields, in the order of `firsts`.
    values: Vec<Vec<f64>>,
    /// Their weight fields: one shared, or one per first scale.
    weights: Vec<Vec<f64>>,
    /// Per tile and scale: points and `Σ w̃`.
    n: Vec<Vec<f64>>,
    wsum: Vec<Vec<f64>>,
}

/// Weights `m_s` of the per-scale fields `ws.fields[s]`, `s < n_vals`.
enum Weights {
    /// Every point of the torus, for every scale.
    Uniform,
    /// Every point of the (non-periodic) domain rectangle, for every scale:
    /// pair counts from the plan, cross terms from summed-area tables.
    Rect,
    /// One mask for all scales, in `ws.fields[n_vals]`.
    Shared,
    /// One weight field per scale (WTMMM counts), `ws.fields[n_vals + s]`.
    PerScale,
}

impl Weights {
    /// The field holding scale `s`'s weights among `ns` value fields: the
    /// scale's own (`ns + s`), or the one shared field `ns` (the common
    /// mask, or a tiled image's domain indicator).
    fn field_of(&self, ns: usize, s: usize) -> usize {
        match self {
            Weights::PerScale => ns + s,
            _ => ns,
        }
    }
}

/// Buffers of one image's correlation, reused through the plan's pool.
#[derive(Default)]
struct Workspace {
    fields: Vec<Vec<f64>>,
    spec: Vec<Vec<Complex32>>,
    half: Vec<Complex32>,
    x: Vec<Complex32>,
    r: Vec<f32>,
    row: Vec<f32>,
    scratch: Vec<Complex32>,
    valid: Vec<bool>,
    /// Summed-area table of one field (the rectangle's cross terms).
    sat: Vec<f64>,
    cwt: Option<crate::cwt::CwtWorkspace>,
}

impl Workspace {
    /// Makes `fields[..n]` exist with `len` zeros each.
    fn zero_fields(&mut self, n: usize, len: usize) {
        self.size_fields(n, len, true);
    }

    /// Makes `fields[..n]` exist with `len` values each, zeroed only if
    /// `zero` (otherwise the caller overwrites every value).
    fn size_fields(&mut self, n: usize, len: usize, zero: bool) {
        while self.fields.len() < n {
            self.fields.push(Vec::new());
        }
        for f in &mut self.fields[..n] {
            if zero {
                f.clear();
            }
            f.resize(len, 0.0);
        }
    }
}

/// The per-scale inputs of [`CorrelationPlan::sums_from_fields`].
struct ScaleFields {
    n_vals: usize,
    weights: Weights,
    means: Vec<f64>,
    totals: Vec<f64>,
    /// Side of the jackknife tiles (px; 0: none).
    tile_side: usize,
    /// Where the tiles lie, `(y0, y1, x0, x1)` on the FFT grid (the domain
    /// at its origin); `None`: the whole domain.
    tile_domain: Option<(usize, usize, usize, usize)>,
}

/// Binned sums of one pair of scales for one image; index 0 is lag 0,
/// index `b + 1` the log bin `b` (`|Δx|` in `[2^((b-½)/B), 2^((b+½)/B))`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PairSums {
    /// `Σ w̃1(x) w̃2(x + d)`.
    pub ww: Vec<f64>,
    /// `Σ w̃1(x) m2(x + d)` (a cross term of the ensemble centring; `mw`
    /// is the other).
    pub wm: Vec<f64>,
    /// `Σ m1(x) w̃2(x + d)`.
    pub mw: Vec<f64>,
    /// Number of pairs `Σ m1(x) m2(x + d)`.
    pub count: Vec<f64>,
    /// `Σ m1(x) m2(x + d) log2 |d|` (for the pair-weighted mean lag of a bin).
    pub lcount: Vec<f64>,
}

/// The sums of one image.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CorrelationImage {
    /// Free label (file name), for the record.
    pub label: String,
    /// Per scale: the image's mean magnitude and number of points.
    pub mean: Vec<f64>,
    /// Number of valid points (grid pixels or WTMMM) per scale.
    pub n: Vec<f64>,
    /// One set of binned sums per pair of scales, in the order of `pairs`.
    pub pairs: Vec<PairSums>,
    /// The same sums split by the tile of the pair's first point (the
    /// jackknife groups of fewer than 3 images; empty unless asked for).
    /// They add up to `pairs`, and their `n` to `n`.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub tiles: Vec<CorrelationTile>,
    /// Side of the tiles in px (0 without tiles).
    #[serde(default, skip_serializing_if = "crate::spectra::is_zero")]
    pub tile_side: usize,
}

/// The part of a [`CorrelationImage`] whose first points lie in one tile
/// of the domain. Values are centred with the image's mean, as the image's.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CorrelationTile {
    /// Valid points in the tile, per scale.
    pub n: Vec<f64>,
    /// `Σ w̃` over the tile's points, per scale.
    pub wsum: Vec<f64>,
    /// Per pair of scales, the sums over the pairs whose first point is in
    /// the tile.
    pub pairs: Vec<PairSums>,
}

impl CorrelationImage {
    /// The image without the pairs whose first point lies in tile `k`,
    /// centred again on the mean of the points outside the tile: a
    /// leave-one-tile-out replicate. `pairs` are the sums' scale pairs.
    fn without_tile(&self, k: usize, pairs: &[(usize, usize)]) -> CorrelationImage {
        let t = &self.tiles[k];
        let n: Vec<f64> = self.n.iter().zip(&t.n).map(|(a, b)| a - b).collect();
        // w̃ sums to 0 over the image, so the points left sum to -wsum:
        // their mean is the image's plus e, and w̃ becomes w̃ - e (none
        // left at a scale: no mean, and the replicate is undefined, NaN)
        let e: Vec<f64> = t
            .wsum
            .iter()
            .zip(&n)
            .map(|(w, n)| if *n > 0.0 { -w / n } else { f64::NAN })
            .collect();
        let mean = self.mean.iter().zip(&e).map(|(m, e)| m + e).collect();
        let pairs = self
            .pairs
            .iter()
            .zip(&t.pairs)
            .zip(pairs)
            .map(|((a, b), &(s1, s2))| {
                let (e1, e2) = (e[s1], e[s2]);
                let nb = a.ww.len();
                let mut o = PairSums {
                    ww: vec![0.0; nb],
                    wm: vec![0.0; nb],
                    mw: vec![0.0; nb],
                    count: vec![0.0; nb],
                    lcount: vec![0.0; nb],
                };
                for i in 0..nb {
                    let (ww, wm, mw, c) = (
                        a.ww[i] - b.ww[i],
                        a.wm[i] - b.wm[i],
                        a.mw[i] - b.mw[i],
                        a.count[i] - b.count[i],
                    );
                    o.ww[i] = ww - e2 * wm - e1 * mw + e1 * e2 * c;
                    o.wm[i] = wm - e1 * c;
                    o.mw[i] = mw - e2 * c;
                    o.count[i] = c;
                    o.lcount[i] = a.lcount[i] - b.lcount[i];
                }
                o
            })
            .collect();
        CorrelationImage {
            label: self.label.clone(),
            mean,
            n,
            pairs,
            tiles: Vec::new(),
            tile_side: 0,
        }
    }
}

/// Mergeable correlation sums of an ensemble (one partial per image).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CorrelationSums {
    /// Crate version that wrote the sums.
    pub version: String,
    /// "cwt" (magnitudes on the CWT grid) or "wtmmm" (skeleton).
    pub source: String,
    /// The distinct scales, in pixels.
    pub scales: Vec<f64>,
    /// Pairs `(i1, i2)` of indices into `scales`.
    pub pairs: Vec<(usize, usize)>,
    /// Log-spaced `|Δx|` bins per octave.
    pub bins_per_octave: usize,
    /// Largest `|Δx|` binned, in pixels (the resolved value, not `None`).
    pub max_dx: f64,
    /// Lags wrapped around a torus (circular correlations).
    pub periodic: bool,
    /// The magnitude correlated: the configured one for `source = "cwt"`,
    /// always ln M for `source = "wtmmm"`.
    pub magnitude: Magnitude,
    /// Wavelet of the transform (`source = "cwt"`; `None` for "wtmmm",
    /// whose points come from a skeleton made elsewhere).
    pub wavelet: Option<Wavelet>,
    /// Threshold `eps` of the valid points (`source = "cwt"`).
    pub eps: Option<f64>,
    /// Interior margin in pixels (0 on a torus).
    pub margin: usize,
    /// One partial per image, in the order added.
    pub images: Vec<CorrelationImage>,
}

impl CorrelationSums {
    /// **Errors** unless the sums are whole: positive finite scales, pairs
    /// of indices into them, and in each image (and each of its tiles) one
    /// mean and count per scale and one set of binned sums per pair, all
    /// with the same number of bins. Sums built by hand or deserialised
    /// (truncated, edited) are checked before they are merged or read
    /// ([`Self::merge`], [`correlation_estimates`]).
    pub fn check(&self) -> Result<()> {
        let ns = self.scales.len();
        if ns == 0 || !self.scales.iter().all(|a| a.is_finite() && *a > 0.0) {
            return Err(Error::param(
                "scales",
                "the correlation sums need positive, finite scales",
            ));
        }
        if self.pairs.is_empty() || self.pairs.iter().any(|&(a, b)| a >= ns || b >= ns) {
            return Err(Error::param(
                "pairs",
                format!(
                    "the correlation sums' pairs {:?} must index their {ns} scales",
                    self.pairs
                ),
            ));
        }
        let np = self.pairs.len();
        let nb = self
            .images
            .first()
            .and_then(|im| im.pairs.first())
            .map_or(0, |p| p.ww.len());
        let whole = |p: &PairSums| {
            [&p.ww, &p.wm, &p.mw, &p.count, &p.lcount]
                .iter()
                .all(|v| v.len() == nb)
        };
        for (i, im) in self.images.iter().enumerate() {
            let tiles_ok = im.tiles.iter().all(|t| {
                t.n.len() == ns
                    && t.wsum.len() == ns
                    && t.pairs.len() == np
                    && t.pairs.iter().all(whole)
            });
            if nb == 0
                || im.mean.len() != ns
                || im.n.len() != ns
                || im.pairs.len() != np
                || !im.pairs.iter().all(whole)
                || !tiles_ok
            {
                return Err(Error::Input(format!(
                    "correlation sums of image {i} ({}): {} means and {} counts for {ns} scales, \
                     {} sets of binned sums for {np} pairs, each of {nb} bins (as the first \
                     image's first pair), tiles whole: {tiles_ok}",
                    im.label,
                    im.mean.len(),
                    im.n.len(),
                    im.pairs.len()
                )));
            }
        }
        Ok(())
    }

    /// Merges many, in order ([`Self::merge`]); `None` for an empty list
    /// (as [`crate::spectra::PartitionSums::merge_all`]).
    ///
    /// **Errors** as [`Self::merge`].
    pub fn merge_all(
        parts: impl IntoIterator<Item = CorrelationSums>,
    ) -> Result<Option<CorrelationSums>> {
        crate::par::merge_in_order(parts, Self::merge)
    }

    /// Adds `other`'s images.
    ///
    /// **Errors** if the two were computed with different settings, or
    /// either fails [`Self::check`].
    pub fn merge(&mut self, other: &CorrelationSums) -> Result<()> {
        self.check()?;
        other.check()?;
        let same = self.source == other.source
            && self.pairs == other.pairs
            && self.bins_per_octave == other.bins_per_octave
            && self.max_dx == other.max_dx
            && self.periodic == other.periodic
            && self.magnitude == other.magnitude
            && self.wavelet == other.wavelet
            && self.eps == other.eps
            && self.margin == other.margin
            && crate::cwt::same_scales(&self.scales, &other.scales);
        if !same {
            return Err(Error::param(
                "pairs",
                "cannot merge correlation sums computed with different settings (source, \
                 scales, pairs, bins, max dx, domain, magnitude, wavelet, eps or margin)",
            ));
        }
        self.images.extend(other.images.iter().cloned());
        // tiles serve fewer than 3 images only (as PartitionSums::merge)
        if self.images.len() >= 3 {
            for im in &mut self.images {
                im.tiles = Vec::new();
                im.tile_side = 0;
            }
        }
        Ok(())
    }
}

/// The side of the jackknife tiles of a lone image's correlation: a
/// quarter of the domain's shorter side (4 x 4 tiles). Measured against
/// the scatter of `C` between 16 images analysed one by one (`cargo test
/// --release --test stats experiment_lone_image_correlation_errors --
/// --ignored`), the rms error one image reports is 0.7-1.1 of it for fBm
/// (256² and 1024², lags up to L/8) and 0.75-0.8 for the log-normal
/// W-cascade at 1024² up to L/16, falling to 0.4-0.6 towards L/4, where a
/// tile holds few independent lags and the cascade's coarse levels, shared
/// by every tile, are not resampled. 3 x 3 tiles read 0.7 (log-normal),
/// 6 x 6 0.55: more, smaller tiles see fewer of the large structures.
///
/// On an elongated domain the side grows to keep about 16 tiles by area
/// (each tile costs FFTs of the whole grid): a 192 x 2048 strip gets 13.
pub fn default_tile_side((y0, y1, x0, x1): (usize, usize, usize, usize)) -> usize {
    let (h, w) = (y1.saturating_sub(y0), x1.saturating_sub(x0));
    let by_area = ((h * w) as f64 / 16.0).sqrt().floor() as usize;
    (h.min(w) / 4).max(by_area)
}

/// Magnitudes on the CWT grid of one image (SPEC §6): `ln M` (or `½ ln ε²`)
/// at each scale of the plan, centred per image over the valid points, and
/// the binned cross-correlation sums of every pair. A point is left out at
/// every scale where, at one scale, `M < eps max M` (compared as
/// `½ ln M² < ½ ln(eps² max M²)`), or `M²` is 0, subnormal or not finite.
///
/// **Errors** if the image shape differs from the plan's, no pixel is valid,
/// or a scale has no valid point.
pub fn cwt_correlation(
    field: &Field,
    plan: &CorrelationPlan,
    label: impl Into<String>,
) -> Result<CorrelationSums> {
    cwt_correlation_tiled(field, plan, label, 0)
}

/// [`cwt_correlation`], with the sums also split by the tile of each
/// pair's first point, tiles of about `tile_side` px over the domain
/// ([`crate::spectra::TileGrid`]; none when fewer than 2 fit or the side
/// is 0): the jackknife groups of a lone image
/// ([`correlation_estimates`]). Each tile costs one FFT per distinct first
/// scale plus one, and four inverse FFTs per pair, so the side is a cost:
/// [`default_tile_side`] makes 4 x 4 tiles, and a 1 px side on a 256²
/// image made 65536 (92 s). The side is not bounded by the scales: the
/// default of a small domain is narrower than twice the largest scale.
///
/// **Errors** as [`cwt_correlation`].
pub fn cwt_correlation_tiled(
    field: &Field,
    plan: &CorrelationPlan,
    label: impl Into<String>,
    tile_side: usize,
) -> Result<CorrelationSums> {
    let (ny, nx) = field.dim();
    if (ny, nx) != (plan.ny, plan.nx) {
        return Err(Error::Input(format!(
            "image is {ny}x{nx} but the correlation plan is for {}x{}",
            plan.ny, plan.nx
        )));
    }
    let img = field.transform_input(plan.cfg.detrend)?;
    let fi = plan.cwt.forward(img.view())?;
    let mut ws = plan.take();
    let out = cwt_correlation_in(field, &fi, plan, &mut ws, label.into(), tile_side);
    plan.give(ws);
    out
}

/// The CWT correlation sums of an ensemble of fields held in memory, made
/// as `wtmm correlate` makes them from files: one plan for their size,
/// each field's sums ([`cwt_correlation_tiled`]), with fewer than 3
/// fields each split into the tiles of [`default_tile_side`] so that the
/// jackknife runs over them (an untiled lone image has no errors), merged
/// in order; fields in parallel, as many at a time as there are threads
/// (each holds a workspace of the one plan). Then [`correlation_estimates`] gives
/// `C(Δx; a1, a2)` with the errors `correlate` reports. Field `i` is
/// labelled `image i`.
///
/// **Errors** with no field, fields of different sizes (as `correlate`:
/// the lag bins follow the size), an invalid `cfg`, or a field the plan
/// refuses (naming its index: no valid pixel, a scale with no valid
/// point, an image smaller than the margin).
pub fn ensemble_correlation_sums(
    fields: &[Field],
    cfg: &CorrelationConfig,
) -> Result<CorrelationSums> {
    cfg.validate()?;
    let named = |i: usize| {
        move |e: Error| match e {
            Error::Input(m) => Error::Input(format!("image {i}: {m}")),
            e => e,
        }
    };
    let Some(first) = fields.first() else {
        return Err(Error::Input("no field given".into()));
    };
    // as `correlate`: the lag bins (max_dx) and the domain follow the size
    let (ny, nx) = first.dim();
    if let Some((i, f)) = fields.iter().enumerate().find(|(_, f)| f.dim() != (ny, nx)) {
        let (fy, fx) = f.dim();
        return Err(Error::Input(format!(
            "image {i} is {fy}x{fx}, but image 0 is {ny}x{nx}: a correlation ensemble needs \
             one image size"
        )));
    }
    let plan = CorrelationPlan::new(ny, nx, cfg).map_err(named(0))?;
    let tiles = fields.len() < 3;
    let parts = crate::par::try_map(fields.len(), |i| {
        let f = &fields[i];
        let plan = &plan;
        let side = if tiles {
            default_tile_side(plan.domain())
        } else {
            0
        };
        cwt_correlation_tiled(f, plan, format!("image {i}"), side).map_err(named(i))
    })?;
    Ok(CorrelationSums::merge_all(parts)?.expect("one field at least"))
}

fn cwt_correlation_in(
    field: &Field,
    fi: &crate::cwt::FourierImage,
    plan: &CorrelationPlan,
    ws: &mut Workspace,
    label: String,
    tile_side: usize,
) -> Result<CorrelationSums> {
    let nx = plan.nx;
    let cfg = &plan.cfg;
    let (y0, y1, x0, x1) = (plan.y0, plan.y1, plan.x0, plan.x1);
    let (dy, dx) = (y1 - y0, x1 - x0);
    let (fy, fx) = (plan.fft.fy, plan.fft.fx);
    let ns = cfg.scales.len();
    // valid: inside the domain, away from masked pixels by the wavelet support
    let a_max = cfg.scales.iter().cloned().fold(0.0, f64::max);
    let mut valid = std::mem::take(&mut ws.valid);
    valid.clear();
    valid.resize(dy * dx, true);
    if let Some(mask) = &field.mask {
        let dist = distance_to_mask(mask);
        let r = cfg.wavelet.support_radius() * a_max + cfg.box_reach(a_max) as f64;
        for y in 0..dy {
            for x in 0..dx {
                valid[y * dx + x] = dist[[y + y0, x + x0]] as f64 > r;
            }
        }
        if !valid.contains(&true) {
            ws.valid = valid;
            let missing = field.missing_count();
            return Err(Error::Input(format!(
                "no valid point for the correlation: the image has {missing} missing pixels \
                 (NaN, inf or nodata), and points count only farther from them than the \
                 wavelet's support at the largest scale ({r:.0} px at a = {a_max:.1} px), \
                 which leaves none of the {dy}x{dx} domain; fill scattered gaps \
                 (--fill-holes) or crop to a gap-free region"
            )));
        }
    }
    // fields 0..ns: the magnitudes on the FFT grid (domain at the origin);
    // field ns: the mask, if needed. Outside the domain the fields must be
    // 0 (zero padding); when the domain fills the FFT grid (the torus)
    // every value is overwritten below and nothing needs clearing.
    let full = dy == fy && dx == fx;
    ws.size_fields(ns + 1, fy * fx, !full);
    let mut cws = ws.cwt.take().unwrap_or_else(|| plan.cwt.workspace());
    // per scale, one pass over the transform: w = ½ ln |T|² (or ½ ln ε²,
    // II eqs 65, 67) into the field, -inf where the squared magnitude is 0,
    // subnormal or not finite; and the max of the squared magnitude
    let mut half_ln_thr = Vec::with_capacity(ns);
    for (s, &a) in cfg.scales.iter().enumerate() {
        let w = &mut ws.fields[s];
        let mut mx = 0.0f64;
        if cfg.magnitude == Magnitude::Energy {
            let t = plan.cwt.scale(fi, s, &mut cws);
            let e = box_energy(t, a);
            let e = e.as_slice().expect("contiguous");
            for y in 0..dy {
                let row = &mut w[y * fx..y * fx + dx];
                let i0 = (y + y0) * nx + x0;
                mx = mx.max(half_ln_row(&e[i0..i0 + dx], row));
            }
        } else {
            // rows streamed from the transform while they are in cache
            // (the 16 MB transform is never stored)
            plan.cwt.scale_rows(fi, s, &mut cws, y0..y1, |yb, _, cur| {
                for (r, src) in cur.chunks_exact(nx).enumerate() {
                    let y = yb + r - y0;
                    let row = &mut w[y * fx..y * fx + dx];
                    mx = mx.max(half_ln_sq_row(&src[x0..x0 + dx], row));
                }
            });
        }
        // M < eps max M  <=>  ½ ln M² < ½ ln (eps² max M²): such points
        // are invalid at every scale (compared in the log domain)
        let thr = cfg.eps * cfg.eps * mx;
        half_ln_thr.push(if thr >= f64::MIN_POSITIVE {
            0.5 * thr.ln()
        } else {
            f64::NEG_INFINITY
        });
    }
    ws.cwt = Some(cws);
    // validity: one pass per scale (the min of each row against the
    // threshold; rows with a failing point are marked pointwise)
    for (w, &h) in ws.fields[..ns].iter().zip(&half_ln_thr) {
        for y in 0..dy {
            let row = &w[y * fx..y * fx + dx];
            let lo = row
                .iter()
                .fold(f64::INFINITY, |m, &v| if v < m { v } else { m });
            if !(lo > h) {
                for (v, o) in row.iter().zip(&mut valid[y * dx..(y + 1) * dx]) {
                    if !(*v > h) {
                        *o = false;
                    }
                }
            }
        }
    }
    let n_valid = valid.iter().filter(|&&v| v).count();
    if n_valid == 0 {
        ws.valid = valid;
        return Err(Error::Input(
            "no valid point for the correlation: every point is below eps times the largest \
             modulus at some scale (a flat image?)"
                .into(),
        ));
    }
    Ok(centred_sums(
        plan, ws, valid, n_valid, "cwt", label, tile_side,
    ))
}

/// The tail of [`cwt_correlation_in`] and [`field_correlation`]: the
/// magnitudes `ws.fields[..ns]` (domain at the origin of the FFT grid)
/// centred over the `n_valid > 0` valid points, zero elsewhere, then the
/// binned sums of every pair.
fn centred_sums(
    plan: &CorrelationPlan,
    ws: &mut Workspace,
    valid: Vec<bool>,
    n_valid: usize,
    source: &str,
    label: String,
    tile_side: usize,
) -> CorrelationSums {
    let cfg = &plan.cfg;
    let (dy, dx) = (plan.y1 - plan.y0, plan.x1 - plan.x0);
    let fx = plan.fft.fx;
    let ns = cfg.scales.len();
    let all_valid = n_valid == dy * dx;
    let uniform = cfg.periodic && all_valid;
    // centre per image over the common valid points, zero elsewhere
    let mut means = Vec::with_capacity(ns);
    for w in ws.fields[..ns].iter_mut() {
        let mut sum = 0.0;
        for y in 0..dy {
            let row = &w[y * fx..y * fx + dx];
            if all_valid {
                sum += slice_sum(row);
            } else {
                let ok = &valid[y * dx..(y + 1) * dx];
                sum += row
                    .iter()
                    .zip(ok)
                    .filter(|(_, o)| **o)
                    .map(|(v, _)| v)
                    .sum::<f64>();
            }
        }
        let mean = sum / n_valid as f64;
        for y in 0..dy {
            let row = &mut w[y * fx..y * fx + dx];
            if all_valid {
                for v in row.iter_mut() {
                    *v -= mean;
                }
            } else {
                let ok = &valid[y * dx..(y + 1) * dx];
                for (v, o) in row.iter_mut().zip(ok) {
                    *v = if *o { *v - mean } else { 0.0 };
                }
            }
        }
        means.push(mean);
    }
    let weights = if uniform {
        Weights::Uniform
    } else if all_valid && !cfg.periodic {
        Weights::Rect
    } else {
        let m = &mut ws.fields[ns];
        for y in 0..dy {
            for x in 0..dx {
                m[y * fx + x] = if valid[y * dx + x] { 1.0 } else { 0.0 };
            }
        }
        Weights::Shared
    };
    ws.valid = valid;
    let fields = ScaleFields {
        n_vals: ns,
        weights,
        means,
        totals: vec![n_valid as f64; ns],
        tile_side,
        tile_domain: None,
    };
    plan.sums_from_fields(ws, source, label, fields)
}

/// The correlation sums of given magnitude fields, one `ny x nx` field per
/// scale of the plan (e.g. the log-amplitudes of a generator's own cascade
/// at the level each scale sees), every point valid: the same centring and
/// binning as [`cwt_correlation`] applies to `ln M`, recorded as source
/// `source` (sums merge only with sums of the same source).
///
/// **Errors** if the number or shape of the fields differs from the
/// plan's, or a value is not finite.
pub fn field_correlation(
    fields: &[Array2<f64>],
    plan: &CorrelationPlan,
    source: &str,
    label: impl Into<String>,
) -> Result<CorrelationSums> {
    let ns = plan.cfg.scales.len();
    if fields.len() != ns {
        return Err(Error::param(
            "scales",
            format!("{} fields for {ns} scales", fields.len()),
        ));
    }
    for f in fields {
        if f.dim() != (plan.ny, plan.nx) {
            return Err(Error::Input(format!(
                "field is {}x{} but the correlation plan is for {}x{}",
                f.nrows(),
                f.ncols(),
                plan.ny,
                plan.nx
            )));
        }
        if f.iter().any(|v| !v.is_finite()) {
            return Err(Error::Input("a magnitude is not finite".into()));
        }
    }
    let (y0, y1, x0, x1) = (plan.y0, plan.y1, plan.x0, plan.x1);
    let (dy, dx) = (y1 - y0, x1 - x0);
    let (fy, fx) = (plan.fft.fy, plan.fft.fx);
    let mut ws = plan.take();
    ws.size_fields(ns + 1, fy * fx, !(dy == fy && dx == fx));
    for (w, f) in ws.fields[..ns].iter_mut().zip(fields) {
        for y in 0..dy {
            let row = f.row(y + y0);
            for (o, v) in w[y * fx..y * fx + dx].iter_mut().zip(row.iter().skip(x0)) {
                *o = *v;
            }
        }
    }
    let mut valid = std::mem::take(&mut ws.valid);
    valid.clear();
    valid.resize(dy * dx, true);
    let out = centred_sums(plan, &mut ws, valid, dy * dx, source, label.into(), 0);
    plan.give(ws);
    Ok(out)
}

/// The weights of a box of side `a` px centred on a pixel, for the offsets
/// `-r..=r` of the pixels it touches: the length of `[d - ½, d + ½]`
/// inside `[-a/2, a/2]`, over `a` (their sum is 1). II eq 65's window
/// `χ(x/a)` read as the unit square on the pixels' piecewise-constant
/// `|T|²`: `ε²` then varies continuously with `a`. (A box of whole pixels,
/// `2 floor(a/2) + 1` on a side, was one pixel, `ln M` itself, for every
/// `a < 2`, and jumped at each even `a`.)
fn box_weights(a: f64) -> Vec<f64> {
    let h = 0.5 * a;
    let r = (h - 0.5).ceil().max(0.0) as i64;
    let w: Vec<f64> = (-r..=r)
        .map(|d| {
            let d = d as f64;
            ((d + 0.5).min(h) - (d - 0.5).max(-h)).max(0.0)
        })
        .collect();
    let sum: f64 = w.iter().sum();
    w.into_iter().map(|v| v / sum).collect()
}

/// `ε²` of II eq 65 with a square box of side `a` ([`box_weights`],
/// periodic, separable); the magnitude is `½ ln ε²`.
fn box_energy(t: &Array2<Complex64>, a: f64) -> Array2<f64> {
    let (ny, nx) = t.dim();
    let wts = box_weights(a);
    let r = wts.len() / 2;
    let e = t.map(|z| z.re * z.re + z.im * z.im);
    let mut h = Array2::<f64>::zeros((ny, nx));
    for y in 0..ny {
        for x in 0..nx {
            let mut s = 0.0;
            for (d, w) in wts.iter().enumerate() {
                s += w * e[[y, (x + nx * (r + 1) + d - r) % nx]];
            }
            h[[y, x]] = s;
        }
    }
    let mut out = Array2::<f64>::zeros((ny, nx));
    for y in 0..ny {
        for x in 0..nx {
            let mut s = 0.0;
            for (d, w) in wts.iter().enumerate() {
                s += w * h[[(y + ny * (r + 1) + d - r) % ny, x]];
            }
            out[[y, x]] = s;
        }
    }
    out
}

/// The same correlation from the skeleton (II §5.1 remark): `w = ln M` at
/// the WTMMM, `points[s]` at the plan's scale `s`, centred per image over
/// the WTMMM of each scale; pairs of WTMMM at lag `d` are counted by FFT
/// (the WTMMM are rasterised as value and count per pixel). Build the plan
/// with the whole image as domain (`margin = Some(0)`): the points already
/// lie in the analysis domain. With `periodic`, lags wrap around.
///
/// **Errors** if the number of point lists differs from the plan's scales,
/// a point lies outside the image, or a scale has no WTMMM.
pub fn wtmmm_correlation(
    points: &[&[Point]],
    plan: &CorrelationPlan,
    label: impl Into<String>,
) -> Result<CorrelationSums> {
    wtmmm_sums(points, plan, label.into(), 0, None)
}

/// [`wtmmm_correlation`], split by tiles as [`cwt_correlation_tiled`],
/// the tiles over `domain` `(y0, y1, x0, x1)` in image pixels (where the
/// points lie: the skeleton's counting domain, [`crate::stats::pdf::ImageWtmmm::domain`]).
///
/// **Errors** as [`wtmmm_correlation`], and if `domain` is not inside the
/// plan's.
pub fn wtmmm_correlation_tiled(
    points: &[&[Point]],
    plan: &CorrelationPlan,
    label: impl Into<String>,
    domain: (usize, usize, usize, usize),
    tile_side: usize,
) -> Result<CorrelationSums> {
    let (py0, py1, px0, px1) = plan.domain();
    let (y0, y1, x0, x1) = domain;
    if !(py0 <= y0 && y0 <= y1 && y1 <= py1 && px0 <= x0 && x0 <= x1 && x1 <= px1) {
        return Err(Error::param(
            "domain",
            format!(
                "the tiles' domain {y0}..{y1} x {x0}..{x1} is not inside the correlation's \
                 {py0}..{py1} x {px0}..{px1}"
            ),
        ));
    }
    let tile_domain = Some((y0 - py0, y1 - py0, x0 - px0, x1 - px0));
    wtmmm_sums(points, plan, label.into(), tile_side, tile_domain)
}

fn wtmmm_sums(
    points: &[&[Point]],
    plan: &CorrelationPlan,
    label: String,
    tile_side: usize,
    tile_domain: Option<(usize, usize, usize, usize)>,
) -> Result<CorrelationSums> {
    let cfg = &plan.cfg;
    if points.len() != cfg.scales.len() {
        return Err(Error::param(
            "scales",
            format!(
                "{} point lists for {} scales",
                points.len(),
                cfg.scales.len()
            ),
        ));
    }
    let (y0, y1, x0, x1) = (plan.y0, plan.y1, plan.x0, plan.x1);
    let (fy, fx) = (plan.fft.fy, plan.fft.fx);
    let ns = points.len();
    let mut means = Vec::with_capacity(ns);
    let mut totals = Vec::with_capacity(ns);
    for (s, pts) in points.iter().enumerate() {
        if let Some(p) = pts.iter().find(|p| {
            (p.y as usize) < y0
                || (p.y as usize) >= y1
                || (p.x as usize) < x0
                || (p.x as usize) >= x1
        }) {
            return Err(Error::Input(format!(
                "WTMMM at ({}, {}) lies outside the correlation domain",
                p.x, p.y
            )));
        }
        let (mut sum, mut n) = (0.0, 0usize);
        for p in pts.iter().filter(|p| p.m > 0.0 && p.m.is_finite()) {
            sum += p.m.ln();
            n += 1;
        }
        if n == 0 {
            return Err(Error::Input(format!(
                "no WTMMM at scale {:.2} for the correlation",
                cfg.scales[s]
            )));
        }
        means.push(sum / n as f64);
        totals.push(n as f64);
    }
    // fields 0..ns: Σ w̃ per pixel; ns..2ns: WTMMM count per pixel
    let mut ws = plan.take();
    ws.zero_fields(2 * ns, fy * fx);
    for (s, pts) in points.iter().enumerate() {
        for p in pts.iter().filter(|p| p.m > 0.0 && p.m.is_finite()) {
            let k = (p.y as usize - y0) * fx + (p.x as usize - x0);
            ws.fields[s][k] += p.m.ln() - means[s];
            ws.fields[ns + s][k] += 1.0;
        }
    }
    let fields = ScaleFields {
        n_vals: ns,
        weights: Weights::PerScale,
        means,
        totals,
        tile_side,
        tile_domain,
    };
    let out = plan.sums_from_fields(&mut ws, "wtmmm", label, fields);
    plan.give(ws);
    Ok(out)
}
