//! WTMMM statistics at each scale (SPEC §5; II §3, Figs 11-14, 17-24).
//!
//! The probability densities of the WTMMM modulus `M` and argument `A` are
//! the "one-point" statistics of the skeleton: how the shape of `P_a(M)`
//! changes with `a` carries the whole multifractal content (II §3.2), while
//! `P_a(A)` should not depend on `a`, and `P_a(M, A) = P_a(M) P_a(A)` when M
//! and A decouple (II eq 40, the working hypothesis of the kernel).
//!
//! **Which WTMMM.** [`image_wtmmm`] returns, per scale, two sets:
//! - [`WtmmmSet::All`]: every WTMMM detected at that scale (local maxima of
//!   M along the maxima chains, SPEC §2) inside the analysis domain;
//! - [`WtmmmSet::Lines`]: only the WTMMM through which a maxima line born at
//!   `a_min` passes (SPEC §3). This set depends on the linking rules: the
//!   modulus-ratio window truncates the per-step changes of `ln M` (SPEC §14).
//!
//! **Accumulator.** [`WtmmmHistograms`] holds, per scale, a 2D histogram of
//! `(ln M, A)`: `ln M` in bins of fixed width `dlnm` indexed from 0 (so two
//! images always share the bin edges), `A` in `arg_bins` bins over
//! `[-π, π)`. Counts are integers: merging images is exact and independent of
//! the order. Every density of II Figs 11-14 is derived from it by
//! [`wtmmm_pdfs`]: `P(ln M)`, `P(M) = P(ln M)/M`, `P(A)`, the pdf of M
//! conditioned on `A mod π` in the four sectors `kπ/4 ± π/8` (Figs 12, 18),
//! the joint density of `(T1, T2) = (M cos A, M sin A)` (Figs 13, 19:
//! `p(T1, T2) = P(ln M, A)/M²`), and the rescaled pdfs of the
//! self-similarity test II eq 39, `M / (a/a_min)^h` (Figs 14b, 20b).
//! The densities are reported on the accumulator's bins
//! ([`DensityBins::Fixed`]) or, per scale, on whole multiples of them sized
//! to the scale's sample ([`DensityBins::Auto`], the Freedman-Diaconis
//! width): a scale with a hundred WTMMM then shows its shape, not a comb.
//!
//! ```
//! use wtmm::stats::pdf::{PdfConfig, PdfOptions, WtmmmHistograms, wtmmm_pdfs};
//! // ln M uniform on [0, 1) at one scale, A = 0.3
//! let mut h = WtmmmHistograms::new(&[2.0], PdfConfig::default()).unwrap();
//! for i in 0..1000 {
//!     h.add(0, ((i as f64 + 0.5) / 1000.0).exp(), 0.3);
//! }
//! let p = wtmmm_pdfs(&h, &PdfOptions { show: vec![0], ..Default::default() }).unwrap();
//! // density 1 on [0, 1)
//! assert!(p[0].p_ln_m.iter().all(|&d| (d - 1.0).abs() < 1e-12));
//! ```

use std::f64::consts::PI;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::field::Field;
use crate::skeleton::{AnalysisConfig, Parallelism, Skeleton, Wtmmm};
use crate::stats::fit::line_fit;

/// Which WTMMM a statistic is taken over.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum WtmmmSet {
    /// Every WTMMM of the scale (independent of the linking).
    #[default]
    All,
    /// The WTMMM on maxima lines born at `a_min` and alive at the scale.
    Lines,
}

impl WtmmmSet {
    /// The set's name in outputs and on the command line (`all`, `lines`).
    pub fn name(self) -> &'static str {
        match self {
            WtmmmSet::All => "all",
            WtmmmSet::Lines => "lines",
        }
    }

    /// The set as messages say it after "WTMMM": `on maxima lines`,
    /// `(all WTMMM)`.
    pub fn phrase(self) -> &'static str {
        match self {
            WtmmmSet::Lines => "on maxima lines",
            WtmmmSet::All => "(all WTMMM)",
        }
    }

    /// The other set.
    pub fn other(self) -> Self {
        match self {
            WtmmmSet::All => WtmmmSet::Lines,
            WtmmmSet::Lines => WtmmmSet::All,
        }
    }
}

/// One WTMMM: pixel, modulus, argument.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Point {
    /// Column of the pixel.
    pub x: u32,
    /// Row of the pixel (0 at the top).
    pub y: u32,
    /// Modulus M (L1 normalisation, SPEC §1).
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub m: f64,
    /// Argument A = atan2(T2, T1), radians in [-π, π].
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub arg: f64,
}

/// The WTMMM of one image, per scale, in both sets.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ImageWtmmm {
    /// The scales, in pixels, smallest first.
    pub scales: Vec<f64>,
    /// `(ny, nx)` of the image.
    pub shape: (usize, usize),
    /// The counting domain `(y0, y1, x0, x1)` of the skeleton.
    pub domain: (usize, usize, usize, usize),
    /// Every WTMMM, per scale.
    pub all: Vec<Vec<Point>>,
    /// The WTMMM on maxima lines, per scale (empty lists without linking).
    pub lines: Vec<Vec<Point>>,
}

impl ImageWtmmm {
    /// The points of one set, per scale. [`WtmmmSet::Lines`] is a list of
    /// empty lists when the lines were not linked ([`image_wtmmm`] with
    /// `link = false`): ask for `link` whenever the lines are wanted.
    pub fn set(&self, s: WtmmmSet) -> &[Vec<Point>] {
        match s {
            WtmmmSet::All => &self.all,
            WtmmmSet::Lines => &self.lines,
        }
    }
}

/// The WTMMM of one image at every scale of `cfg`: CWT, maxima chains and
/// WTMMM (SPEC §2), and with `link` the maxima lines (SPEC §3) whose points
/// give [`WtmmmSet::Lines`]. Chains are not kept, so memory stays at a few
/// numbers per WTMMM.
///
/// **Errors** as [`crate::skeleton::skeleton_with`]: invalid parameters, an
/// image smaller than the wavelet, no valid pixel.
pub fn image_wtmmm(
    field: &Field,
    cfg: &AnalysisConfig,
    par: Parallelism,
    link: bool,
) -> Result<ImageWtmmm> {
    let n = cfg.scale_list().len();
    let (sk, all) = crate::skeleton::skeleton_and_wtmmm(field, cfg, par, n, link)?;
    Ok(ImageWtmmm::from_skeleton(&sk, all))
}

impl ImageWtmmm {
    /// The two sets from a skeleton and the WTMMM of its first `all.len()`
    /// scales ([`crate::skeleton::skeleton_and_wtmmm`], which keeps those of
    /// the counting domain); the lines are cut to those scales. Both sets
    /// hold the points of the counting domain ([`Skeleton::counts`]) at
    /// every scale, as the partition functions do: inside the interior
    /// rectangle and, in an image with missing pixels, farther from them
    /// than the wavelet's support at the largest scale (the detection keeps
    /// only each scale's own support off them; a maximum nearer a hole
    /// counts at small scales while its line dies into the hole at large
    /// ones, which biases a slope over the scales). So the pdfs' h0 and the
    /// kernel's -c1 are `analyze`'s h(q=0) on the same image.
    pub fn from_skeleton(sk: &Skeleton, all: Vec<Vec<Wtmmm>>) -> Self {
        let n = all.len().min(sk.scales.len());
        let inside = |x: u32, y: u32| sk.counts(x, y);
        let mut lines = vec![Vec::new(); n];
        // lines that never link beyond a_min carry no scale information
        // and are left out, as in the partition functions
        // (judged on the cut line: a line of the first n scales alone)
        for l in sk.lines.iter().filter(|l| l.points.len().min(n) > 1) {
            for (j, p) in l.points.iter().take(n).enumerate() {
                if inside(p.x, p.y) {
                    lines[j].push(Point {
                        x: p.x,
                        y: p.y,
                        m: p.m,
                        arg: p.arg,
                    });
                }
            }
        }
        let point = |w: &Wtmmm| Point {
            x: w.x,
            y: w.y,
            m: w.m,
            arg: w.arg,
        };
        ImageWtmmm {
            scales: sk.scales[..n].to_vec(),
            shape: sk.shape,
            domain: sk.domain,
            all: all
                .into_iter()
                .take(n)
                .map(|s| s.iter().map(point).collect())
                .collect(),
            lines,
        }
    }
}

/// Binning of the `(ln M, A)` histograms.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct PdfConfig {
    /// Bin width in `ln M` (bins are `[k dlnm, (k+1) dlnm)`, k integer).
    pub dlnm: f64,
    /// Number of argument bins over `[-π, π)`; a multiple of 16 so that the
    /// four sectors `kπ/4 ± π/8` (mod π) are unions of bins.
    pub arg_bins: usize,
}

/// The span of `ln M` one scale's histogram is sized for (e^60 between
/// the smallest and the largest modulus, beyond any WTMMM of one scale).
const LN_M_SPAN: f64 = 60.0;
/// Most counts one scale's histogram may need over [`LN_M_SPAN`] (2^25:
/// 256 MB).
const MAX_HIST_CELLS: usize = 1 << 25;

impl Default for PdfConfig {
    fn default() -> Self {
        PdfConfig {
            dlnm: 0.05,
            arg_bins: 64,
        }
    }
}

impl PdfConfig {
    /// **Errors** naming the flag (`lnm-bin`, `arg-bins`), also when the
    /// two together would need more than 2^25 counts per scale over a span
    /// of 60 in `ln M`.
    pub fn validate(&self) -> Result<()> {
        if !(self.dlnm > 1e-4 && self.dlnm <= 2.0) {
            return Err(Error::param(
                "lnm-bin",
                format!(
                    "bin width of ln M must be in (1e-4, 2], got {}",
                    crate::error::short(self.dlnm)
                ),
            ));
        }
        if self.arg_bins < 16 || !self.arg_bins.is_multiple_of(16) || self.arg_bins > 4096 {
            return Err(Error::param(
                "arg-bins",
                format!(
                    "must be a multiple of 16 in 16..=4096, got {}",
                    self.arg_bins
                ),
            ));
        }
        // the histogram of one scale holds (span of ln M / bin) x arg-bins
        // counts: a fine bin with many argument bins asked for gigabytes
        // per scale (an abort, not an error)
        let cells = LN_M_SPAN / self.dlnm * self.arg_bins as f64;
        if cells > MAX_HIST_CELLS as f64 {
            return Err(Error::param(
                "lnm-bin",
                format!(
                    "{} with {} argument bins gives {cells:.3e} counts per scale over a span \
                     of {LN_M_SPAN} in ln M, more than {MAX_HIST_CELLS}: use a wider --lnm-bin \
                     or fewer --arg-bins",
                    crate::error::short(self.dlnm),
                    self.arg_bins
                ),
            ));
        }
        Ok(())
    }
}

/// The binning and the scales [`WtmmmHistograms::new`] accepts (shared by
/// [`WtmmmHistograms::check`], which must not build histograms to ask).
fn check_grid(scales: &[f64], config: PdfConfig) -> Result<()> {
    config.validate()?;
    if scales.is_empty() {
        return Err(Error::param("scales", "no scale given"));
    }
    if let Some(a) = scales.iter().find(|a| !(a.is_finite() && **a > 0.0)) {
        return Err(Error::param(
            "scales",
            format!("scales must be > 0, got {}", crate::error::short(*a)),
        ));
    }
    if scales.windows(2).any(|w| w[1] <= w[0]) {
        return Err(Error::param(
            "scales",
            "scales must be increasing (smallest first)",
        ));
    }
    Ok(())
}

/// Fixed-point unit of [`ScaleHist::sum_ln_m`], 2^-24 in `ln M`: integers
/// add exactly in any order, where a float sum would change in its last
/// bits with the order of the merges (hence with the thread count).
/// Rounding each `ln M` to it moves a mean by less than 3e-8.
pub const LN_M_UNIT: f64 = 16_777_216.0;

/// The `(ln M, A)` histogram of one scale: `counts[(k - lo) * arg_bins + b]`
/// for `ln M` bin `k` and argument bin `b`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ScaleHist {
    /// Index of the first `ln M` bin held.
    pub lo: i64,
    /// Number of `ln M` bins held.
    pub rows: usize,
    /// Counts, `rows * arg_bins` of them, laid out as in the type's doc.
    pub counts: Vec<u64>,
    /// Number of WTMMM.
    pub n: u64,
    /// `Σ ln M` in units of [`LN_M_UNIT`] (fixed point, so that merges are
    /// exact), for the mean of `ln M` unbinned (the slope h0 of `wtmm pdf`
    /// then agrees with `analyze`'s h(q=0) and `kernel`'s -c1 on the same
    /// WTMMM). `None` in histograms written before it was kept (0.3.0
    /// builds up to 2026-11-28) or after an overflow (not before 7e8
    /// WTMMM, even at the largest `|ln M|` of an f64, 745): the mean then
    /// comes from the bin centres.
    #[serde(default)]
    pub sum_ln_m: Option<i64>,
}

impl Default for ScaleHist {
    /// No WTMMM (and a sum of 0 to add to).
    fn default() -> Self {
        ScaleHist {
            lo: 0,
            rows: 0,
            counts: Vec::new(),
            n: 0,
            sum_ln_m: Some(0),
        }
    }
}

/// Mergeable `(ln M, A)` histograms of an ensemble, one per scale.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct WtmmmHistograms {
    /// Crate version that wrote the histograms.
    pub version: String,
    /// The binning.
    pub config: PdfConfig,
    /// The scales, in pixels, smallest first.
    pub scales: Vec<f64>,
    /// Number of images merged.
    pub images: usize,
    /// One histogram per scale, in the order of `scales`.
    pub hist: Vec<ScaleHist>,
}

impl WtmmmHistograms {
    /// Empty histograms for the given scales (no image yet).
    ///
    /// **Errors** on an invalid binning, or a scale list that is empty,
    /// holds a non-positive or non-finite scale, or is not increasing (the
    /// kernel and the rescaling test read it as smallest first).
    pub fn new(scales: &[f64], config: PdfConfig) -> Result<Self> {
        check_grid(scales, config)?;
        Ok(WtmmmHistograms {
            version: crate::VERSION.to_string(),
            config,
            scales: scales.to_vec(),
            images: 0,
            hist: vec![ScaleHist::default(); scales.len()],
        })
    }

    /// **Errors** unless the histograms are whole: what [`Self::new`]
    /// checks, one histogram per scale, `rows x arg_bins` counts in each,
    /// summing to its `n`. A deserialised shard (truncated, edited) is
    /// checked before it is merged or read ([`Self::merge`],
    /// [`wtmmm_pdfs`]).
    pub fn check(&self) -> Result<()> {
        check_grid(&self.scales, self.config)?;
        if self.hist.len() != self.scales.len() {
            return Err(Error::Input(format!(
                "{} histograms for {} scales",
                self.hist.len(),
                self.scales.len()
            )));
        }
        let nb = self.config.arg_bins;
        for (j, h) in self.hist.iter().enumerate() {
            if h.rows.checked_mul(nb) != Some(h.counts.len()) {
                return Err(Error::Input(format!(
                    "histogram {j}: {} counts for {} rows of {nb} argument bins",
                    h.counts.len(),
                    h.rows
                )));
            }
            if h.counts.iter().try_fold(0u64, |a, &c| a.checked_add(c)) != Some(h.n) {
                return Err(Error::Input(format!(
                    "histogram {j}: its counts do not sum to its {} WTMMM",
                    h.n
                )));
            }
            // every ln M of a finite positive f64 lies within ±745, so the
            // mean must too (a sum edited or of another unit would not)
            if let Some(s) = h.sum_ln_m
                && (s as f64).abs() > 745.2 * LN_M_UNIT * h.n as f64
            {
                return Err(Error::Input(format!(
                    "histogram {j}: its sum of ln M ({s} x 2^-24) is impossible for {} WTMMM",
                    h.n
                )));
            }
        }
        Ok(())
    }

    /// The histograms of one image's WTMMM (`points[j]` at scale `j`).
    ///
    /// **Errors** if `points` does not have one list per scale.
    pub fn from_points(scales: &[f64], config: PdfConfig, points: &[Vec<Point>]) -> Result<Self> {
        let mut h = Self::new(scales, config)?;
        if points.len() != scales.len() {
            return Err(Error::param(
                "scales",
                format!("{} point lists for {} scales", points.len(), scales.len()),
            ));
        }
        for (j, pts) in points.iter().enumerate() {
            for p in pts {
                h.add(j, p.m, p.arg);
            }
        }
        h.images = 1;
        Ok(h)
    }

    /// Adds one WTMMM at scale index `j`; non-positive or non-finite moduli
    /// and non-finite arguments are ignored.
    ///
    /// **Panics** if `j` is out of range.
    pub fn add(&mut self, j: usize, m: f64, arg: f64) {
        if !(m > 0.0 && m.is_finite() && arg.is_finite()) {
            return;
        }
        let nb = self.config.arg_bins;
        let k = (m.ln() / self.config.dlnm).floor() as i64;
        let b = arg_bin(arg, nb);
        let h = &mut self.hist[j];
        grow(h, k, nb);
        h.counts[(k - h.lo) as usize * nb + b] += 1;
        h.n += 1;
        // |ln M| <= 745 for a finite positive f64: the product fits an i64
        let u = (m.ln() * LN_M_UNIT).round() as i64;
        h.sum_ln_m = h.sum_ln_m.and_then(|s| s.checked_add(u));
    }

    /// Adds `other`'s counts (exact, order-independent).
    ///
    /// **Errors** if the binning or the scales differ, or either fails
    /// [`Self::check`].
    pub fn merge(&mut self, other: &WtmmmHistograms) -> Result<()> {
        self.check()?;
        other.check()?;
        if self.config != other.config {
            return Err(Error::param(
                "lnm-bin",
                "cannot merge histograms with different binnings",
            ));
        }
        if !same_scales(&self.scales, &other.scales) {
            return Err(Error::param(
                "scales",
                "cannot merge histograms over different scales",
            ));
        }
        let nb = self.config.arg_bins;
        // an empty scale sums to 0 whether or not it was written with sums
        // (so that merges of older histograms stay order-independent)
        let sum = |h: &ScaleHist| if h.n == 0 { Some(0) } else { h.sum_ln_m };
        for (h, o) in self.hist.iter_mut().zip(&other.hist) {
            h.sum_ln_m = match (sum(h), sum(o)) {
                (Some(a), Some(b)) => a.checked_add(b),
                _ => None,
            };
            if o.rows == 0 {
                continue;
            }
            grow(h, o.lo, nb);
            grow(h, o.lo + o.rows as i64 - 1, nb);
            let off = (o.lo - h.lo) as usize * nb;
            for (d, s) in h.counts[off..off + o.counts.len()]
                .iter_mut()
                .zip(&o.counts)
            {
                *d += s;
            }
            h.n += o.n;
        }
        self.images += other.images;
        Ok(())
    }

    /// `h(q=0)` estimate of `wtmm pdf`: the slope of `<ln M>` against `ln a`
    /// over the fit range `fit` (octaves above the smallest scale), the WTMMM
    /// being those of `set` (named in the error). With the exact sums
    /// ([`ScaleHist::sum_ln_m`]) it is the regression of `analyze`'s h(q=0)
    /// and of the kernel's -c1 on the same WTMMM.
    ///
    /// **Errors** ([`Error::Input`]) when a scale of the range has no WTMMM
    /// (the fit would skip it unseen, or have nothing to fit).
    pub fn h0(&self, fit: (f64, f64), set: WtmmmSet) -> Result<f64> {
        let oct: Vec<f64> = self
            .scales
            .iter()
            .map(|a| (a / self.scales[0]).log2())
            .collect();
        let in_fit: Vec<usize> = (0..self.scales.len())
            .filter(|&j| oct[j] >= fit.0 - 1e-9 && oct[j] <= fit.1 + 1e-9)
            .collect();
        let empty: Vec<usize> = in_fit
            .iter()
            .copied()
            .filter(|&j| self.hist[j].n == 0)
            .collect();
        if let (Some(&lo), Some(&hi)) = (empty.first(), empty.last()) {
            let set = set.phrase();
            return Err(Error::Input(format!(
                "no WTMMM {set} at {} of the {} scales of the fit range {}:{} octaves (a = {:.2} .. \
                 {:.2} px, {} image(s)) to estimate h0 (the slope of <ln M> against ln a): the \
                 counting domain is too small for these scales (use fewer --octaves, a smaller \
                 --margin, or a lower --fit)",
                empty.len(),
                in_fit.len(),
                fit.0,
                fit.1,
                self.scales[lo],
                self.scales[hi],
                self.images
            )));
        }
        let (x, y): (Vec<f64>, Vec<f64>) = in_fit
            .iter()
            .map(|&j| (self.scales[j].ln(), self.mean_ln_m(j)))
            .unzip();
        line_fit(&x, &y).map(|l| l.slope).ok_or_else(|| {
            Error::Input(format!(
                "h0 cannot be estimated: {} scale(s) in the fit range {}:{} octaves",
                in_fit.len(),
                fit.0,
                fit.1
            ))
        })
    }

    /// Mean of `ln M` at scale `j` (NaN if empty): from the exact sum
    /// ([`ScaleHist::sum_ln_m`], to 3e-8), or from the bin centres when
    /// the histograms have none.
    ///
    /// **Panics** if `j` is not a scale index of the histograms.
    pub fn mean_ln_m(&self, j: usize) -> f64 {
        let h = &self.hist[j];
        if h.n == 0 {
            return f64::NAN;
        }
        if let Some(s) = h.sum_ln_m {
            return s as f64 / LN_M_UNIT / h.n as f64;
        }
        let nb = self.config.arg_bins;
        let mut s = 0.0;
        for r in 0..h.rows {
            let c: u64 = h.counts[r * nb..(r + 1) * nb].iter().sum();
            s += c as f64 * (h.lo + r as i64) as f64;
        }
        (s / h.n as f64 + 0.5) * self.config.dlnm
    }

    /// The density of `ln M` at scale `j` on its bin centres: `(u, P(u))`.
    pub fn ln_m_density(&self, j: usize) -> (Vec<f64>, Vec<f64>) {
        let h = &self.hist[j];
        let nb = self.config.arg_bins;
        let d = self.config.dlnm;
        let u = centres(h, d);
        let p = (0..h.rows)
            .map(|r| {
                let c: u64 = h.counts[r * nb..(r + 1) * nb].iter().sum();
                c as f64 / (h.n.max(1) as f64 * d)
            })
            .collect();
        (u, p)
    }
}

fn same_scales(a: &[f64], b: &[f64]) -> bool {
    a.len() == b.len()
        && a.iter()
            .zip(b)
            .all(|(x, y)| (x - y).abs() <= 1e-9 * x.abs())
}

/// Argument bin of `A` over `[-π, π)` (π itself goes to the first bin, as -π).
fn arg_bin(arg: f64, nb: usize) -> usize {
    let t = (arg + PI).rem_euclid(2.0 * PI) / (2.0 * PI);
    ((t * nb as f64).floor() as usize).min(nb - 1)
}

/// Makes room for `ln M` bin `k`.
fn grow(h: &mut ScaleHist, k: i64, nb: usize) {
    if h.rows == 0 {
        h.lo = k;
        h.rows = 1;
        h.counts = vec![0; nb];
        return;
    }
    if k < h.lo {
        let add = (h.lo - k) as usize;
        let mut c = vec![0; add * nb];
        c.extend_from_slice(&h.counts);
        h.counts = c;
        h.lo = k;
        h.rows += add;
    } else if k >= h.lo + h.rows as i64 {
        let add = (k - h.lo - h.rows as i64 + 1) as usize;
        h.counts.extend(std::iter::repeat_n(0, add * nb));
        h.rows += add;
    }
}

/// What [`wtmmm_pdfs`] reports.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PdfOptions {
    /// Scale indices to report.
    pub show: Vec<usize>,
    /// Exponent of the rescaling test II eq 39: `M / (a/a_min)^h0`.
    pub h0: f64,
    /// Cells per side of the `(T1, T2)` density grid.
    pub joint_cells: usize,
    /// The `(T1, T2)` grid covers `|T_i| <= ` this quantile of M.
    pub joint_quantile: f64,
    /// Width of the `ln M` bins of the densities (the accumulator keeps its
    /// own fixed width `dlnm`).
    pub bins: DensityBins,
}

/// Settings with no scale to show (`show` empty: [`wtmmm_pdfs`] then
/// reports none) and `h0 = 0`: set `show` (`wtmm pdf` shows the scales
/// 0, 1, 2, 3 octaves above a_min) and, for the rescaling test, `h0`.
impl Default for PdfOptions {
    fn default() -> Self {
        PdfOptions {
            show: vec![],
            h0: 0.0,
            joint_cells: 81,
            joint_quantile: 0.99,
            bins: DensityBins::Fixed,
        }
    }
}

/// Width of the `ln M` bins a density is reported on.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum DensityBins {
    /// The accumulator's width `dlnm` at every scale (bins shared by all
    /// scales and images).
    #[default]
    Fixed,
    /// Per scale, the Freedman-Diaconis width `2 IQR n^(-1/3)` of its `ln M`
    /// rounded to a whole number of accumulator bins (at least one): a
    /// scale with few WTMMM gets wider bins instead of a comb of spikes and
    /// empty bins, a large ensemble keeps the fine ones. The four sector
    /// densities share one width, that of the smallest sector's count; the
    /// joint density of `(T1, T2)` merges `ln M` and argument bins by
    /// Scott's bivariate rule `3.5 σ n^(-1/4)`, and P(A) argument bins by
    /// the Freedman-Diaconis width of A (in powers of two, 8 bins at least).
    Auto,
}

/// Density of M conditioned on `A mod π` in `centre ± π/8`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SectorPdf {
    /// Sector centre (radians, mod π): 0, π/4, π/2, 3π/4.
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub centre: f64,
    /// Number of WTMMM in the sector.
    pub n: u64,
    /// `P(M | sector)` on the scale's `sector_m`.
    #[serde(deserialize_with = "crate::nan_null::vec")]
    pub p_m: Vec<f64>,
    /// `P(ln M | sector)` on the scale's `sector_ln_m`.
    #[serde(deserialize_with = "crate::nan_null::vec")]
    pub p_ln_m: Vec<f64>,
}

/// Density of `(T1, T2)` at the WTMMM on a square grid of cell centres
/// `t[i]` (both axes), `density[iy * t.len() + ix]` at `(T1, T2) = (t[ix], t[iy])`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct JointDensity {
    /// Cell centres, the same on both axes (symmetric about 0).
    #[serde(deserialize_with = "crate::nan_null::vec")]
    pub t: Vec<f64>,
    /// `p(T1, T2) = P(ln M, A) / M²`, row-major with T2 along the rows.
    #[serde(deserialize_with = "crate::nan_null::vec")]
    pub density: Vec<f64>,
    /// Width of the `ln M` bins of the polar histogram sampled.
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub lnm_bin_width: f64,
    /// Number of its argument bins over `[-π, π)`.
    pub arg_bins: usize,
}

/// The densities of one scale (II Figs 11-14, 17-20).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ScalePdf {
    /// Scale index.
    pub j: usize,
    /// Scale, in pixels.
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub a: f64,
    /// `log2(a / a_min)`.
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub octave: f64,
    /// Number of WTMMM at this scale (all images).
    pub n: u64,
    /// Width of the `ln M` bins of this scale's densities (the
    /// accumulator's `dlnm` times a whole number, [`DensityBins`]).
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub bin_width: f64,
    /// WTMMM counted in each `ln M` bin (on `ln_m`): the densities are
    /// `count / (n bin_width)`, and the counts give their counting errors.
    pub count: Vec<u64>,
    /// Bin centres of `ln M` and the density of `ln M`.
    #[serde(deserialize_with = "crate::nan_null::vec")]
    pub ln_m: Vec<f64>,
    /// `P(ln M)` (natural log; integrates to 1 over `ln_m`).
    #[serde(deserialize_with = "crate::nan_null::vec")]
    pub p_ln_m: Vec<f64>,
    /// `M = exp(ln_m)` and the density of M, `P(ln M) / M`.
    #[serde(deserialize_with = "crate::nan_null::vec")]
    pub m: Vec<f64>,
    /// `P(M) = P(ln M) / M` on `m`.
    #[serde(deserialize_with = "crate::nan_null::vec")]
    pub p_m: Vec<f64>,
    /// Argument bin centres (the accumulator's `arg_bins`, merged in
    /// groups under [`DensityBins::Auto`]) and the density of A.
    #[serde(deserialize_with = "crate::nan_null::vec")]
    pub arg: Vec<f64>,
    /// `P(A)` (per radian) on `arg`.
    #[serde(deserialize_with = "crate::nan_null::vec")]
    pub p_arg: Vec<f64>,
    /// Width of the `ln M` bins of the sector densities: `bin_width`, or
    /// with [`DensityBins::Auto`] the width for the smallest sector's count.
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub sector_bin_width: f64,
    /// Bin centres of `ln M` of the sector densities.
    #[serde(deserialize_with = "crate::nan_null::vec")]
    pub sector_ln_m: Vec<f64>,
    /// `M = exp(sector_ln_m)`.
    #[serde(deserialize_with = "crate::nan_null::vec")]
    pub sector_m: Vec<f64>,
    /// `P(M | A mod π)` in the four sectors `kπ/4 ± π/8` (II Figs 12, 18),
    /// on `sector_m`.
    pub sectors: Vec<SectorPdf>,
    /// II eq 39: `M / (a/a_min)^h0` and its density `s P(M)`.
    #[serde(deserialize_with = "crate::nan_null::vec")]
    pub rescaled_m: Vec<f64>,
    /// Density of the rescaled modulus on `rescaled_m`.
    #[serde(deserialize_with = "crate::nan_null::vec")]
    pub p_rescaled: Vec<f64>,
    /// Joint density of `(T1, T2)` (II Figs 13, 19).
    pub joint: JointDensity,
}

/// The densities of II Figs 11-14 at the scales `opts.show`, from the
/// ensemble histograms (see the module doc for the formulas).
///
/// **Errors** if a scale index is out of range or a grid option is invalid.
pub fn wtmmm_pdfs(h: &WtmmmHistograms, opts: &PdfOptions) -> Result<Vec<ScalePdf>> {
    h.check()?;
    if let Some(&j) = opts.show.iter().find(|&&j| j >= h.scales.len()) {
        return Err(Error::param(
            "show",
            format!("scale index {j} out of range (0..{})", h.scales.len()),
        ));
    }
    if opts.joint_cells < 3 || opts.joint_cells > 2001 {
        return Err(Error::param(
            "joint-cells",
            format!("must be in 3..=2001, got {}", opts.joint_cells),
        ));
    }
    if !(opts.joint_quantile > 0.0 && opts.joint_quantile <= 1.0) {
        return Err(Error::param(
            "joint-quantile",
            format!(
                "must be in (0, 1], got {}",
                crate::error::short(opts.joint_quantile)
            ),
        ));
    }
    if !opts.h0.is_finite() {
        return Err(Error::param("h0", "must be finite"));
    }
    Ok(opts
        .show
        .par_iter()
        .map(|&j| scale_pdf(h, j, opts))
        .collect())
}

fn scale_pdf(hs: &WtmmmHistograms, j: usize, opts: &PdfOptions) -> ScalePdf {
    let nb = hs.config.arg_bins;
    let k = match opts.bins {
        DensityBins::Fixed => 1,
        DensityBins::Auto => fd_factor(&hs.hist[j], nb, hs.config.dlnm, hs.hist[j].n),
    };
    let h = &coarsen(&hs.hist[j], nb, k);
    let d = width(hs.config.dlnm, k);
    let a = hs.scales[j];
    let a_min = hs.scales[0];
    let n = h.n.max(1) as f64;
    let count: Vec<u64> = h
        .counts
        .chunks_exact(nb)
        .map(|row| row.iter().sum())
        .collect();
    let ln_m = centres(h, d);
    let p_ln_m: Vec<f64> = count.iter().map(|&c| c as f64 / (n * d)).collect();
    let m: Vec<f64> = ln_m.iter().map(|u| u.exp()).collect();
    let p_m: Vec<f64> = p_ln_m.iter().zip(&m).map(|(p, mm)| p / mm).collect();
    // P(A): the argument bins' counts, merged in groups of `ka` under Auto
    let mut arg_counts = vec![0u64; nb];
    for row in h.counts.chunks_exact(nb) {
        for (p, &c) in arg_counts.iter_mut().zip(row) {
            *p += c;
        }
    }
    let ka = match opts.bins {
        DensityBins::Fixed => 1,
        DensityBins::Auto => arg_factor(&arg_counts, h.n),
    };
    let nba = nb / ka;
    let da = 2.0 * PI / nba as f64;
    let arg: Vec<f64> = (0..nba).map(|b| -PI + (b as f64 + 0.5) * da).collect();
    let p_arg: Vec<f64> = arg_counts
        .chunks_exact(ka)
        .map(|c| c.iter().sum::<u64>() as f64 / (n * da))
        .collect();
    let fine = &hs.hist[j];
    let sector_rows = |h: &ScaleHist| sector_counts(h, nb);
    // a sector holds about a quarter of the scale's WTMMM: its own
    // Freedman-Diaconis width (the scale's spread, the smallest sector's n),
    // one grid for the four so that they compare bin by bin
    let ks = match opts.bins {
        DensityBins::Fixed => 1,
        DensityBins::Auto => {
            let n_min = sector_rows(fine)
                .iter()
                .map(|rows| rows.iter().sum::<u64>())
                .min()
                .unwrap_or(0);
            fd_factor(fine, nb, hs.config.dlnm, n_min)
        }
    };
    let hsec = coarsen(fine, nb, ks);
    let ds = width(hs.config.dlnm, ks);
    let sector_ln_m = centres(&hsec, ds);
    let sector_m: Vec<f64> = sector_ln_m.iter().map(|u| u.exp()).collect();
    let sectors = sector_rows(&hsec)
        .into_iter()
        .enumerate()
        .map(|(k, rows)| {
            let ns: u64 = rows.iter().sum();
            let p_ln: Vec<f64> = rows
                .iter()
                .map(|&c| c as f64 / (ns.max(1) as f64 * ds))
                .collect();
            SectorPdf {
                centre: k as f64 * PI / 4.0,
                n: ns,
                p_m: p_ln.iter().zip(&sector_m).map(|(p, mm)| p / mm).collect(),
                p_ln_m: p_ln,
            }
        })
        .collect();
    // the joint density spreads the points over two variables: its own,
    // coarser bins (in both) when asked for
    // the picture's extent from the fine bins, whatever the density's
    let extent = quantile_extent(fine, nb, hs.config.dlnm, opts.joint_quantile);
    let joint = match opts.bins {
        DensityBins::Fixed => joint_density(fine, nb, hs.config.dlnm, extent, opts),
        DensityBins::Auto => {
            let (kj, ka) = joint_factors(fine, nb, hs.config.dlnm);
            let hj = coarsen_args(&coarsen(fine, nb, kj), ka);
            joint_density(&hj, nb / ka, width(hs.config.dlnm, kj), extent, opts)
        }
    };
    // II eq 39 with a in units of a_min (the paper's σ_W units)
    let s = (a / a_min).powf(opts.h0);
    let rescaled_m = m.iter().map(|v| v / s).collect();
    let p_rescaled = p_m.iter().map(|p| p * s).collect();
    ScalePdf {
        j,
        a,
        octave: (a / a_min).log2(),
        n: h.n,
        bin_width: d,
        count,
        sector_bin_width: ds,
        sector_ln_m,
        sector_m,
        joint,
        ln_m,
        p_ln_m,
        m,
        p_m,
        arg,
        p_arg,
        sectors,
        rescaled_m,
        p_rescaled,
    }
}

/// `p(T1, T2) = P(ln M, A) / M²` sampled at the cell centres of a square
/// grid (polar histogram cell containing each point; 0 outside the data),
/// from the histogram `h` of `ln M` bins of width `d` and `nb` argument
/// bins, over `|T_i| <= extent` ([`quantile_extent`]).
fn joint_density(h: &ScaleHist, nb: usize, d: f64, extent: f64, opts: &PdfOptions) -> JointDensity {
    let nc = opts.joint_cells;
    if h.n == 0 {
        return JointDensity {
            t: vec![0.0; nc],
            density: vec![0.0; nc * nc],
            lnm_bin_width: d,
            arg_bins: nb,
        };
    }
    // (2i + 1 - nc) / nc: the grid is exactly symmetric about 0, so that
    // a reflected image samples the mirror points
    let t: Vec<f64> = (0..nc)
        .map(|i| extent * (2.0 * i as f64 + 1.0 - nc as f64) / nc as f64)
        .collect();
    let da = 2.0 * PI / nb as f64;
    let norm = h.n as f64 * d * da;
    let mut density = vec![0.0; nc * nc];
    for (iy, &t2) in t.iter().enumerate() {
        for (ix, &t1) in t.iter().enumerate() {
            let m2 = t1 * t1 + t2 * t2;
            if m2 <= 0.0 {
                continue;
            }
            let k = (0.5 * m2.ln() / d).floor() as i64;
            if k < h.lo || k >= h.lo + h.rows as i64 {
                continue;
            }
            // a point on an edge of the argument bins (the grid's axes and
            // diagonals, for nb a multiple of 8) takes the mean of the two
            // bins it parts: the half-open bins gave it to one side, so a
            // reflected image read the other (25-35 % apart there)
            let row = &h.counts[(k - h.lo) as usize * nb..][..nb];
            let u = (t2.atan2(t1) + PI) / da;
            let c = if (u - u.round()).abs() < 1e-9 {
                let b = (u.round() as usize) % nb;
                0.5 * (row[b] + row[(b + nb - 1) % nb]) as f64
            } else {
                row[arg_bin(t2.atan2(t1), nb)] as f64
            };
            density[iy * nc + ix] = c / norm / m2;
        }
    }
    JointDensity {
        t,
        density,
        lnm_bin_width: d,
        arg_bins: nb,
    }
}

/// The interquartile range of the scale's `ln M` from the cumulative
/// counts of its bins of width `d` (linear within a bin); 0 below 2 points.
fn iqr_ln_m(h: &ScaleHist, nb: usize, d: f64) -> f64 {
    let rows: Vec<u64> = h.counts.chunks_exact(nb).map(|r| r.iter().sum()).collect();
    binned_iqr(&rows) * d
}

/// The interquartile range of counts in unit-width bins, in bins: the
/// quartiles read from the cumulative counts, linear within a bin (0 below
/// 2 points). Where the cumulative count rests on a quartile over empty
/// bins, the quartile is the middle of that run, so that the counts read
/// backwards give the same range (a reflected image's argument bins).
fn binned_iqr(counts: &[u64]) -> f64 {
    let n: u64 = counts.iter().sum();
    if n < 2 {
        return 0.0;
    }
    let quantile = |q: f64| -> f64 {
        let target = q * n as f64;
        let mut acc = 0.0;
        for (b, &c) in counts.iter().enumerate() {
            let next = acc + c as f64;
            if next >= target && c > 0 {
                if next > target {
                    return b as f64 + (target - acc) / c as f64;
                }
                // the target ends this bin: the cumulative count stays on
                // it over the empty bins that follow
                let empty = counts[b + 1..].iter().take_while(|&&c| c == 0).count();
                return (b + 1) as f64 + empty as f64 / 2.0;
            }
            acc = next;
        }
        counts.len() as f64
    };
    quantile(0.75) - quantile(0.25)
}

/// [`binned_iqr`] of counts over the circle (the argument bins over
/// `[-π, π)`): the smallest over the cuts of the circle at each bin edge.
/// A linear range depends on where the circle is cut, so that a flipped
/// image drew its P(A) at another width (the Jacksboro DEM at a = 3 px: 8
/// bins, flipped left to right 16); every symmetry of the grid maps the
/// cuts onto one another.
fn circular_iqr(counts: &[u64]) -> f64 {
    let mut turned = counts.to_vec();
    (0..counts.len())
        .map(|_| {
            turned.rotate_left(1);
            binned_iqr(&turned)
        })
        .fold(f64::INFINITY, f64::min)
}

/// The largest power of two `ka` of argument bins (of `nb`, each `2π/nb`
/// wide) whose merged width stays within `width` and that leaves a
/// multiple of 8 bins: the sectors of A need whole bins, and only then do
/// the symmetries of the grid (quarter turns, flips about the axes and
/// diagonals) map bin edges onto bin edges (`--arg-bins 80` merged to 10
/// bins of 36°, with no edge at ±90°, drew a transposed image's P(A) on
/// other bins).
fn pow2_arg_merge(width: f64, nb: usize) -> usize {
    let da = 2.0 * PI / nb as f64;
    let mut ka = 1;
    while nb.is_multiple_of(16 * ka) && (2 * ka) as f64 * da <= width {
        ka *= 2;
    }
    ka
}

/// A width as a whole number of bins `d`, at least 1 and at most `most`.
fn whole_bins(width: f64, d: f64, most: usize) -> usize {
    ((width / d).round() as usize).clamp(1, most.max(1))
}

/// The Freedman-Diaconis bin width `2 IQR n^(-1/3)` (Freedman & Diaconis
/// 1981: the width that minimises the integrated squared error of a
/// histogram of a smooth density) of the scale's `ln M`, for a sample of
/// `n`, as a whole number of the accumulator's bins `d` (at least 1).
fn fd_factor(h: &ScaleHist, nb: usize, d: f64, n: u64) -> usize {
    if n < 2 {
        return 1;
    }
    let width = 2.0 * iqr_ln_m(h, nb, d) * (n as f64).powf(-1.0 / 3.0);
    whole_bins(width, d, h.rows)
}

/// Bins of the joint density of `(ln M, A)` by Scott's bivariate rule
/// (Scott 1992, *Multivariate density estimation*, eq 3.66: `3.5 σ_i
/// n^(-1/4)` per variable, the n^(-1/4) of two dimensions), with the robust
/// `σ = IQR / 1.349` for `ln M` and `2π/√12` for an `A` spread over the
/// circle: `(k, ka)`, `k` accumulator bins of `ln M` (the nearest whole
/// number) and `ka` argument bins (the largest power of two at or below the
/// width that divides `nb`, at most `nb/8` so that at least eight
/// directions remain: the sectors of A need whole bins).
fn joint_factors(h: &ScaleHist, nb: usize, d: f64) -> (usize, usize) {
    if h.n < 2 {
        return (1, 1);
    }
    let shrink = 3.5 * (h.n as f64).powf(-0.25);
    let k = whole_bins(shrink * iqr_ln_m(h, nb, d) / 1.349, d, h.rows);
    (k, pow2_arg_merge(shrink * 2.0 * PI / 12f64.sqrt(), nb))
}

/// How many neighbouring argument bins (of the `counts.len()` over
/// `[-π, π)`) one bin of P(A) merges: the Freedman-Diaconis width `2 IQR
/// n^(-1/3)` of A (the IQR over the circle, [`circular_iqr`]), rounded
/// down to a power of two that leaves a multiple of 8 bins
/// ([`pow2_arg_merge`]).
fn arg_factor(counts: &[u64], n: u64) -> usize {
    if n < 2 {
        return 1;
    }
    let da = 2.0 * PI / counts.len() as f64;
    let width = 2.0 * circular_iqr(counts) * da * (n as f64).powf(-1.0 / 3.0);
    pow2_arg_merge(width, counts.len())
}

/// The histogram with `ka` neighbouring argument bins merged into one
/// (`nb / ka` bins over `[-π, π)`; `ka` divides `nb`).
fn coarsen_args(h: &ScaleHist, ka: usize) -> ScaleHist {
    if ka <= 1 {
        return h.clone();
    }
    let counts = h.counts.chunks_exact(ka).map(|c| c.iter().sum()).collect();
    ScaleHist {
        counts,
        ..h.clone()
    }
}

/// The `ln M` counts of each of the four sectors of `A mod π` centred on
/// `kπ/4` (`± π/8`): argument bin `b` covers `A` in `[-π + b dA, ...)`, so
/// `A mod π` corresponds to `b mod (nb/2)`, and sector k is centred on
/// bin `k nb/8` of that half.
fn sector_counts(h: &ScaleHist, nb: usize) -> [Vec<u64>; 4] {
    let half = nb / 2;
    let per_sector = nb / 8; // π/4 wide
    std::array::from_fn(|k| {
        let c = k * per_sector;
        let in_sector = |b: usize| (b % half + half - c + per_sector / 2) % half < per_sector;
        h.counts
            .chunks_exact(nb)
            .map(|row| (0..nb).filter(|&b| in_sector(b)).map(|b| row[b]).sum())
            .collect()
    })
}

/// The upper edge, as M, of the `ln M` bin (width `d`) where the
/// cumulative count reaches the quantile `q` of the scale's WTMMM (1 for an
/// empty histogram).
fn quantile_extent(h: &ScaleHist, nb: usize, d: f64, q: f64) -> f64 {
    if h.n == 0 {
        return 1.0;
    }
    let target = (q * h.n as f64).ceil() as u64;
    let mut acc = 0u64;
    let mut r_q = h.rows - 1;
    for (r, row) in h.counts.chunks_exact(nb).enumerate() {
        acc += row.iter().sum::<u64>();
        if acc >= target {
            r_q = r;
            break;
        }
    }
    ((h.lo + r_q as i64 + 1) as f64 * d).exp()
}

/// `k` bins of `d` (the double the densities use, so that they integrate
/// to 1 exactly; 3 x 0.05 prints as 0.15000000000000002).
fn width(d: f64, k: usize) -> f64 {
    d * k as f64
}

/// The `ln M` bin centres of a histogram of bins of width `d`.
fn centres(h: &ScaleHist, d: f64) -> Vec<f64> {
    (0..h.rows)
        .map(|r| (h.lo as f64 + r as f64 + 0.5) * d)
        .collect()
}

/// The histogram with `k` accumulator bins of `ln M` merged into one: the
/// wide bin `K` holds the fine bins `kK .. kK + k - 1`, so its edges are
/// multiples of `k dlnm` (exact sums of counts; `k = 1` is a copy).
fn coarsen(h: &ScaleHist, nb: usize, k: usize) -> ScaleHist {
    if k <= 1 || h.rows == 0 {
        return h.clone();
    }
    let ki = k as i64;
    let lo = h.lo.div_euclid(ki);
    let hi = (h.lo + h.rows as i64 - 1).div_euclid(ki);
    let rows = (hi - lo + 1) as usize;
    let mut counts = vec![0u64; rows * nb];
    for (r, row) in h.counts.chunks_exact(nb).enumerate() {
        let big = ((h.lo + r as i64).div_euclid(ki) - lo) as usize;
        for (c, &v) in counts[big * nb..(big + 1) * nb].iter_mut().zip(row) {
            *c += v;
        }
    }
    ScaleHist {
        lo,
        rows,
        counts,
        n: h.n,
        sum_ln_m: h.sum_ln_m,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every allowed `--arg-bins` merges to a multiple of 8 bins, whose
    /// edges the quarter turns and the flips of the grid map onto edges
    /// (80 merged to 10 before: 36° bins, no edge at ±90°).
    #[test]
    fn merged_argument_bins_stay_a_multiple_of_8() {
        for nb in (16..=4096).step_by(16) {
            for width in [0.01, 0.3, 1.0, 3.0, 7.0] {
                let ka = pow2_arg_merge(width, nb);
                assert!(
                    nb.is_multiple_of(ka) && (nb / ka).is_multiple_of(8),
                    "{nb} bins, ka = {ka}"
                );
            }
        }
        assert_eq!(pow2_arg_merge(7.0, 80), 2);
        assert_eq!(pow2_arg_merge(7.0, 64), 8);
    }

    /// The spread of A does not depend on where the circle is cut: a
    /// distribution across the cut at ±π reads as narrow as the same turned
    /// to 0 (the linear range read it as the whole circle), and the
    /// reversed counts (a reflected image) read the same, also where a
    /// quartile falls on a run of empty bins.
    #[test]
    fn the_iqr_of_a_is_read_on_the_circle() {
        let mut across = vec![0u64; 64];
        for (b, c) in [(62, 5), (63, 20), (0, 20), (1, 5)] {
            across[b] = c;
        }
        assert!(binned_iqr(&across) > 60.0);
        let mut centred = vec![0u64; 64];
        centred[30..34].copy_from_slice(&[5, 20, 20, 5]);
        assert_eq!(circular_iqr(&across), binned_iqr(&centred));
        assert!(circular_iqr(&across) < 2.0);
        // quartiles on empty runs: 4 points over bins 3, 10, 20, 40
        let mut sparse = vec![0u64; 64];
        for b in [3, 10, 20, 40] {
            sparse[b] = 1;
        }
        let reversed: Vec<u64> = sparse.iter().rev().copied().collect();
        assert_eq!(binned_iqr(&sparse), binned_iqr(&reversed));
        assert_eq!(circular_iqr(&sparse), circular_iqr(&reversed));
        for r in [1, 16, 33] {
            let mut turned = sparse.clone();
            turned.rotate_left(r);
            assert_eq!(circular_iqr(&turned), circular_iqr(&sparse));
        }
    }

    /// A fine ln M bin with many argument bins would need gigabytes per
    /// scale (2e-4 x 4096: 226 GB for the moduli 1e-300 and 1e300): refused
    /// up front; the default and the finest bin with few argument bins pass.
    #[test]
    fn histogram_size_is_bounded() {
        PdfConfig::default().validate().unwrap();
        let fine = |arg_bins| PdfConfig {
            dlnm: 1.5e-4,
            arg_bins,
        };
        fine(32).validate().unwrap();
        let e = fine(4096).validate().unwrap_err().to_string();
        assert!(e.contains("`lnm-bin`") && e.contains("per scale"), "{e}");
    }

    /// The scales must be positive, finite and increasing (the kernel and
    /// the rescaling test read them smallest first).
    #[test]
    fn histogram_scales_are_checked() {
        let c = PdfConfig::default();
        WtmmmHistograms::new(&[1.5, 3.0], c).unwrap();
        for bad in [
            &[3.0, 1.5][..],
            &[1.5, 1.5],
            &[f64::NAN, 3.0],
            &[0.0, 1.0],
            &[],
        ] {
            let e = WtmmmHistograms::new(bad, c).unwrap_err().to_string();
            assert!(e.contains("`scales`"), "{bad:?}: {e}");
        }
    }

    #[test]
    fn arg_bins_and_sectors() {
        let nb = 64;
        assert_eq!(arg_bin(-PI, nb), 0);
        assert_eq!(arg_bin(PI, nb), 0);
        assert_eq!(arg_bin(0.0, nb), 32);
        assert_eq!(arg_bin(PI - 1e-9, nb), 63);
        // points at A = kπ/4 + π (same sector mod π) land in sector k
        let mut h = WtmmmHistograms::new(&[1.0], PdfConfig::default()).unwrap();
        for k in 0..4 {
            for _ in 0..(k + 1) * 10 {
                h.add(0, 1.0, k as f64 * PI / 4.0 - PI + 0.01);
                h.add(0, 1.0, k as f64 * PI / 4.0 - 0.01);
            }
        }
        let p = wtmmm_pdfs(
            &h,
            &PdfOptions {
                show: vec![0],
                ..Default::default()
            },
        )
        .unwrap();
        let n: Vec<u64> = p[0].sectors.iter().map(|s| s.n).collect();
        assert_eq!(n, vec![20, 40, 60, 80]);
    }

    #[test]
    fn merge_is_exact_and_grows_both_ways() {
        let s = [1.0, 2.0];
        let mut a = WtmmmHistograms::new(&s, PdfConfig::default()).unwrap();
        let mut b = a.clone();
        a.add(0, 1.0, 0.0);
        a.add(0, 10.0, 1.0);
        b.add(0, 0.01, -1.0);
        b.add(1, 5.0, 2.0);
        let mut ab = a.clone();
        ab.merge(&b).unwrap();
        let mut ba = b.clone();
        ba.merge(&a).unwrap();
        assert_eq!(ab.hist, ba.hist);
        assert_eq!(ab.hist[0].n, 3);
        let (_, p) = ab.ln_m_density(0);
        let total: f64 = p.iter().sum::<f64>() * ab.config.dlnm;
        assert!((total - 1.0).abs() < 1e-12);
    }

    /// Wide bins hold whole accumulator bins: bin K of width k dlnm holds
    /// the fine bins kK .. kK + k - 1, on both sides of ln M = 0, and the
    /// counts are summed exactly (argument bins kept apart).
    #[test]
    fn coarsen_sums_whole_bins() {
        let mut h = WtmmmHistograms::new(&[1.0], PdfConfig::default()).unwrap();
        // one point in each fine bin -7 ..= 4 (ln M from -0.35 to 0.25),
        // the odd bins at A = 1
        for k in -7..=4i64 {
            let arg = if k % 2 == 0 { 0.0 } else { 1.0 };
            h.add(0, ((k as f64 + 0.5) * 0.05).exp(), arg);
        }
        let c = coarsen(&h.hist[0], 64, 3);
        // -7 -> -3; -6..-4 -> -2; -3..-1 -> -1; 0..2 -> 0; 3, 4 -> 1
        assert_eq!((c.lo, c.rows, c.n), (-3, 5, 12));
        let rows: Vec<u64> = c.counts.chunks_exact(64).map(|r| r.iter().sum()).collect();
        assert_eq!(rows, vec![1, 3, 3, 3, 2]);
        assert_eq!(c.counts.iter().sum::<u64>(), 12);
        let at_one = arg_bin(1.0, 64);
        // wide bin -2 holds fine -6 (A = 0), -5 (A = 1), -4 (A = 0)
        assert_eq!(c.counts[64 + at_one], 1);
        assert_eq!(coarsen(&h.hist[0], 64, 1), h.hist[0]);
    }

    /// Merged argument bins hold whole neighbouring bins, so the counts
    /// (and the ln M rows) are kept exactly.
    #[test]
    fn coarsen_args_sums_neighbours() {
        let mut h = WtmmmHistograms::new(&[1.0], PdfConfig::default()).unwrap();
        for b in 0..64 {
            let arg = -PI + (b as f64 + 0.5) * 2.0 * PI / 64.0;
            for _ in 0..b {
                h.add(0, 1.0, arg);
            }
        }
        let c = coarsen_args(&h.hist[0], 4);
        assert_eq!((c.lo, c.rows, c.n), (h.hist[0].lo, 1, h.hist[0].n));
        // bins 4i .. 4i + 3 hold 4i + (4i + 1) + (4i + 2) + (4i + 3) points
        let want: Vec<u64> = (0..16).map(|i| 16 * i + 6).collect();
        assert_eq!(c.counts, want);
    }

    /// The joint density's bins follow Scott's bivariate rule `3.5 σ
    /// n^(-1/4)`: at n = 10 000 the factor is 0.35, so ln M ~ N(0, 1) gets
    /// 0.35 = 7 bins of 0.05 (the sample IQR moves that by 0.06 bin), and A
    /// uniform (σ = 2π/√12 = 1.81) 0.63 rad, whose largest power-of-two
    /// merge of the 64 bins of 0.098 rad is 4: 16 directions. With fixed
    /// bins the accumulator's are used.
    #[test]
    fn joint_bins_follow_scott() {
        use rand::RngExt;
        use rand_distr::{Distribution, Normal};
        let law = Normal::new(0.0, 1.0).unwrap();
        let mut h = WtmmmHistograms::new(&[1.0], PdfConfig::default()).unwrap();
        let mut rng = crate::synth::rng_for(6, 0);
        for _ in 0..10_000 {
            let u: f64 = law.sample(&mut rng);
            h.add(0, u.exp(), rng.random_range(-PI..PI));
        }
        let mut opts = PdfOptions {
            show: vec![0],
            bins: DensityBins::Auto,
            ..Default::default()
        };
        let j = &wtmmm_pdfs(&h, &opts).unwrap()[0].joint;
        assert!(
            (j.lnm_bin_width - 0.35).abs() < 1e-12,
            "{}",
            j.lnm_bin_width
        );
        assert_eq!(j.arg_bins, 16);
        opts.bins = DensityBins::Fixed;
        let j = &wtmmm_pdfs(&h, &opts).unwrap()[0].joint;
        assert_eq!((j.lnm_bin_width, j.arg_bins), (0.05, 64));
    }

    /// `DensityBins::Auto` on a standard normal ln M. The Freedman-Diaconis
    /// width `2 IQR n^(-1/3)` of N(0, 1) (IQR 1.349) is 0.1349 at n = 8000:
    /// 2.70 bins of 0.05, so 3 (the sample IQR's sd, 1.17/sqrt(n) = 0.013,
    /// moves the ratio by 0.026, far from the roundings at 2.5 and 3.5);
    /// at n = 200 000 it is 0.046, one bin. The wide-bin densities
    /// integrate to 1, their counts add up to n, and they fit the normal
    /// bin probabilities (chi-square at the 0.999 quantile, bins with at
    /// least 5 expected points, tails pooled). At n = 8000 the sectors
    /// (about 2000 points each) get 2 x 1.349 x 2000^(-1/3) = 0.214: 4.3
    /// bins, so 4 (the smallest of the four counts, about 1950, moves it
    /// to 4.3, still 4 of the IQR's sd from 4.5), and each sector density
    /// integrates to 1 on that grid.
    #[test]
    fn auto_bins_follow_freedman_diaconis() {
        use rand::RngExt;
        use rand_distr::{Distribution, Normal};
        use statrs::distribution::{ChiSquared, ContinuousCDF, Normal as StdNormal};
        let phi = StdNormal::new(0.0, 1.0).unwrap();
        let law = Normal::new(0.0, 1.0).unwrap();
        for (n, k_expected) in [(8000usize, 3usize), (200_000, 1)] {
            let mut h = WtmmmHistograms::new(&[1.0], PdfConfig::default()).unwrap();
            let mut rng = crate::synth::rng_for(5, n as u64);
            for _ in 0..n {
                let u: f64 = law.sample(&mut rng);
                h.add(0, u.exp(), rng.random_range(-PI..PI));
            }
            let opts = PdfOptions {
                show: vec![0],
                bins: DensityBins::Auto,
                ..Default::default()
            };
            let p = &wtmmm_pdfs(&h, &opts).unwrap()[0];
            let w = p.bin_width;
            assert!(
                (w - 0.05 * k_expected as f64).abs() < 1e-12,
                "n = {n}: width {w}"
            );
            let mass: f64 = p.p_ln_m.iter().sum::<f64>() * w;
            assert!((mass - 1.0).abs() < 1e-12, "n = {n}: mass {mass}");
            assert_eq!(p.count.iter().sum::<u64>(), n as u64);
            if n == 8000 {
                assert!(
                    (p.sector_bin_width - 0.2).abs() < 1e-12,
                    "{}",
                    p.sector_bin_width
                );
                for sec in &p.sectors {
                    assert_eq!(sec.p_ln_m.len(), p.sector_ln_m.len());
                    let mass: f64 = sec.p_ln_m.iter().sum::<f64>() * p.sector_bin_width;
                    assert!((mass - 1.0).abs() < 1e-12, "sector {}: {mass}", sec.centre);
                }
            }
            // bin edges are multiples of the wide width
            for &u in &p.ln_m {
                let e = u / w - 0.5;
                assert!((e - e.round()).abs() < 1e-9, "centre {u}");
            }
            let nf = n as f64;
            let (mut chi2, mut dof, mut t_obs, mut t_exp) = (0.0, 0usize, 0.0, 0.0);
            for (&u, &c) in p.ln_m.iter().zip(&p.count) {
                let exp = nf * (phi.cdf(u + 0.5 * w) - phi.cdf(u - 0.5 * w));
                if exp < 5.0 {
                    t_obs += c as f64;
                    t_exp += exp;
                    continue;
                }
                chi2 += (c as f64 - exp).powi(2) / exp;
                dof += 1;
            }
            t_exp += nf
                - p.ln_m
                    .iter()
                    .map(|&u| nf * (phi.cdf(u + 0.5 * w) - phi.cdf(u - 0.5 * w)))
                    .sum::<f64>();
            chi2 += (t_obs - t_exp).powi(2) / t_exp;
            let q = ChiSquared::new(dof as f64).unwrap().inverse_cdf(0.999);
            assert!(
                chi2 < q,
                "n = {n}: chi2 {chi2:.1} on {dof} dof, quantile {q:.1}"
            );
        }
    }
}
