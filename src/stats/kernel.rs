//! The self-similarity kernel of the WTMMM moduli (SPEC §5; II §4, eqs
//! 41-64, Figs 25-29).
//!
//! Castaing's ansatz on the skeleton (II eq 41): the density of `ln M` at a
//! scale `a` is the density at `a' > a` convolved with a kernel `G_aa'`,
//! `P_a^log = G_aa' * P_a'^log`. With the characteristic function of `ln M`
//! over the WTMMM at `a` (II eq 45),
//!
//! ```text
//! C(p, a) = < exp(i p ln M) >_a            (real and imaginary parts kept apart)
//! Ĝ_aa'(p) = C(p, a) / C(p, a')            (II eq 47)
//! ```
//!
//! and a continuously self-similar, scale-invariant cascade has
//! `Ĝ_aa'(p) = Ĝ(p)^ln(a'/a)` (II eqs 43-44): `ln Ĝ_aa' / ln(a'/a)` collapses
//! onto one curve (Figs 25b, d). Writing `ln Ĝ(p) = Σ c_n (ip)^n / n!`
//! (II eq 48),
//!
//! ```text
//! C_n(a, a') = κ_n(ln M at a) - κ_n(ln M at a') = c_n ln(a'/a)     (II eq 49)
//! ```
//!
//! **Conventions (documented once, used everywhere).** `M` is the L1
//! modulus of SPEC §1, logarithms are natural (`ln M`, `ln(a'/a)`), `κ_n` are
//! the cumulants of `ln M` and `c_n` is the slope of `C_n` against
//! `ln(a'/a)`. These are the paper's `c_n`: II eq 64 gives
//! `τ(q) = -Σ c_n q^n/n! - 2`, and for a W-cascade one dyadic step
//! (`ln(a'/a) = ln 2`) adds one `ln W`, so `c_n = κ_n(ln W) / ln 2`
//! (II eqs 56, 60): log-normal `c1 = m/ln2`, `c2 = σ²/ln2`, exactly
//! [`crate::theory::Model::cumulants`]. "In log2 units" only means that
//! division by ln 2; nothing is measured in log2.
//!
//! **The characteristic-function method (II eqs 57-58).** `C_1 = Φ'(0)`,
//! `C_2 = -(ln|Ĝ|)''(0)`, `C_3 = -Φ'''(0)` with `Φ` the unwrapped phase of
//! `Ĝ`. (Eq 58 as printed, `C_{2n+2} = ∂^{2n+2} ln|Ĝ|`, lacks the sign
//! `(-1)^{n+1}` that its own eq 49 implies.) The derivatives at `p = 0` of
//! the logarithm of the *empirical* characteristic function are exactly the
//! sample (plug-in) cumulants `κ_1 = mean`, `κ_2 = Σ(u - ū)²/n`,
//! `κ_3 = Σ(u - ū)³/n`, so we take them from exact central sums (no
//! numerical differentiation, no choice of p range); a test checks the
//! identity against finite differences of `ln Ĝ`.
//!
//! **Fit.** `C_n(a, a') = κ_n(a) - κ_n(a')` for every pair lies on
//! `c_n ln(a'/a)` iff `κ_n` is linear in `ln a`, so `c_n` is minus the slope
//! of `κ_n(a)` against `ln a` over the fit range (one regression whatever the
//! reference scale); the per-reference tables of II Figs 26, 28 are
//! reported too, with their slopes through the origin.
//!
//! **Ensembles.** [`KernelSums`] keeps one partial per image (central sums
//! and characteristic-function sums per scale). Ensemble values combine the
//! images in a canonical order (so merging is order-independent to the last
//! bit) and a delete-one jackknife over images gives the standard errors, as
//! in [`crate::spectra`] (with fewer than 3 images, over the tiles of their
//! domains when the sums were split: [`KernelSums::from_points_tiled`]).
//!
//! **The paper's protocol (II §4.2, Figs 25-28).** WTMMM of the skeleton
//! (the maxima lines: [`WtmmmSet::Lines`]), the modulus `M` at each WTMMM
//! (not the sup rule of SPEC §4, a partition-function device that would
//! clip the downward steps of `ln M`), the first-order wavelet (gauss),
//! reference scales `a' = 2^0.5 .. 2^3.5` and `a >= 1` in `σ_W` units, i.e.
//! octaves 0 to 3.5 above `a_min` here (`--fit 0:3.5`). Only slopes in
//! `ln a` enter, so the factor between the wavelet scale and the cascade's
//! dyadic scale does not matter.
//!
//! **Measured (32 x 1024², torus, defaults: plain modulus, ratio window
//! (0.9, 1.11), radius cap 12 px, guard band, fit 0.5:4; ± jackknife).**
//! The first row of each cascade is with lines linked across the torus's
//! edges; the other rows were measured before, when the edges ended lines
//! (a change of 0.0002 in c2).
//!
//! | case | set | c1 | c2 | c3 |
//! |---|---|---|---|---|
//! | log-normal (-0.38, 0.030, 0), gauss | lines | -0.373 ± 0.002 | 0.0259 ± 0.0015 | 0.0000 ± 0.0012 |
//! | same, paper protocol (fit 0:3.5, pooled tables) | lines | -0.372 ± 0.002 | 0.0264 ± 0.0013 | -0.0009 ± 0.0010 |
//! | same | CWT grid | -0.372 | 0.0250 | 0.0023 |
//! | same | all WTMMM | -0.296 | -0.003 | 0.023 |
//! | log-Poisson (-0.381, 0.036, -0.0049), gauss | lines | -0.368 ± 0.003 | 0.0268 ± 0.0016 | -0.0039 ± 0.0010 |
//! | same, paper protocol | lines | -0.369 ± 0.002 | 0.0277 ± 0.0013 | -0.0044 ± 0.0008 |
//! | same | CWT grid | -0.364 | 0.0251 | -0.0038 |
//! | monofractal (σ² = 0: -0.38, 0, 0), gauss | lines | -0.380 ± 0.002 | 0.0019 ± 0.0014 | -0.0002 ± 0.0008 |
//! | log-normal, mexican (16 images) | lines | -0.397 ± 0.002 | 0.0289 ± 0.0018 | 0.0001 ± 0.0009 |
//! | log-Poisson, mexican (16 images) | lines | -0.396 ± 0.002 | 0.0339 ± 0.0010 | -0.0031 ± 0.0008 |
//!
//! - *All WTMMM* are biased whatever the cascade: their number falls like
//!   `a^-1.7`, not `a^-2` (weak maxima along ever longer chains).
//! - *Lines* pass the monofractal control (true c2 = c3 = 0): no additive
//!   bias from the selection or the linking; the ratio window no longer
//!   shows (lines and the whole CWT grid agree within 0.002).
//! - *The low c2 with gauss is in the transform itself*: the CWT grid gives
//!   the same 0.025 for 0.030 and 0.036. It is a multiplicative loss
//!   (monofractal control ≈ 0) that shrinks with three vanishing moments
//!   (mexican, octaves 1-4: 0.030 and 0.035). With one vanishing moment the
//!   coarser cascade levels leak into `M(a)` like `(a/s)^(1-h)` (about 0.65
//!   per octave here), so the ancestors' multipliers reach `ln M(a)` only in
//!   part (the ignored test `experiment_ancestor_transmission` measures the
//!   regression coefficients). Measured: with the same seeds and σ², raising
//!   h from 0.38 to 0.6 (leak 0.65 -> 0.76 per octave) lowers the grid c2
//!   by 0.0040 ± 0.0013 with gauss and by 0.0002 ± 0.0002 with mexican; db4
//!   and db8 generators give the same c2; larger images help only slowly
//!   (grid, same pixel scales: 1024² 0.023-0.024, 2048² 0.025-0.028, 4096²
//!   0.026). The same leak bends the correlation functions
//!   ([`crate::stats::correlation`]). See the README's kernel section.
//!
//! ```
//! use wtmm::stats::kernel::{KernelConfig, KernelOptions, KernelSums, kernel_estimates};
//! use wtmm::stats::pdf::WtmmmSet;
//! // ln M at scale a = 2^(j/4): mean -0.4 ln a (c1 = 0.4), symmetric spread
//! let scales: Vec<f64> = (0..9).map(|j| 2f64.powf(j as f64 / 4.0)).collect();
//! let vals: Vec<Vec<f64>> = scales
//!     .iter()
//!     .map(|a| (0..100).map(|i| -0.4 * a.ln() + (i as f64 - 49.5) / 100.0).collect())
//!     .collect();
//! let s = KernelSums::from_ln_m(&scales, KernelConfig::default(), WtmmmSet::All, &vals, "x").unwrap();
//! let opts = KernelOptions { fit: (0.0, 2.0), refs: vec![1.0, 2.0], pairs: vec![(0.5, 2.0)] };
//! let k = kernel_estimates(&s, &opts).unwrap();
//! assert!((k.cumulants.c1.value - 0.4).abs() < 1e-12);
//! assert!(k.cumulants.c2.value.abs() < 1e-12);
//! ```

use num_complex::Complex64;
use rustfft::FftPlanner;
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::stats::fit::line_fit;
use crate::stats::pdf::{Point, WtmmmHistograms, WtmmmSet};

/// The p grid of the characteristic functions: `p_k = k dp`, `k = 0..=p_max/dp`
/// (negative p by symmetry, `C(-p) = conj C(p)`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct KernelConfig {
    /// Largest p (conjugate to `ln M`, dimensionless; default 8).
    pub p_max: f64,
    /// Step of the p grid (default 0.05).
    pub dp: f64,
}

impl Default for KernelConfig {
    fn default() -> Self {
        KernelConfig {
            p_max: 8.0,
            dp: 0.05,
        }
    }
}

impl KernelConfig {
    /// **Errors** naming the flag (`p-max`, `dp`).
    pub fn validate(&self) -> Result<()> {
        if !(self.p_max > 0.0 && self.p_max <= 200.0) {
            return Err(Error::param(
                "p-max",
                format!(
                    "must be in (0, 200], got {}",
                    crate::error::short(self.p_max)
                ),
            ));
        }
        if !(self.dp > 0.0 && self.dp <= self.p_max) || self.p_max / self.dp > 20_000.0 {
            // both values, so that a p-max below the default dp (the one
            // given) is not blamed on dp alone
            return Err(Error::param(
                "dp",
                format!(
                    "must be in (0, p-max] with at most 20000 steps, got dp = {} for p-max = {} \
                     (--dp, --p-max)",
                    crate::error::short(self.dp),
                    crate::error::short(self.p_max)
                ),
            ));
        }
        Ok(())
    }

    /// Number of p values (p >= 0).
    pub fn len(&self) -> usize {
        (self.p_max / self.dp + 1e-9).floor() as usize + 1
    }

    /// Always false (p = 0 is on the grid).
    pub fn is_empty(&self) -> bool {
        false
    }

    /// The grid `p_k = k dp`.
    pub fn grid(&self) -> Vec<f64> {
        (0..self.len()).map(|k| k as f64 * self.dp).collect()
    }
}

/// Count, mean and central sums `Σ(u-ū)²`, `Σ(u-ū)³` of a sample.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Moments {
    /// Number of values.
    pub n: u64,
    /// Mean `ū` (0 when empty).
    pub mean: f64,
    /// Central sum `Σ(u-ū)²` (not divided by n).
    pub m2: f64,
    /// Central sum `Σ(u-ū)³` (not divided by n).
    pub m3: f64,
}

impl Moments {
    /// Exact two-pass central sums of `u`.
    pub fn of(u: &[f64]) -> Self {
        if u.is_empty() {
            return Moments::default();
        }
        let n = u.len() as f64;
        let mean = u.iter().sum::<f64>() / n;
        let (mut m2, mut m3) = (0.0, 0.0);
        for &v in u {
            let d = v - mean;
            m2 += d * d;
            m3 += d * d * d;
        }
        Moments {
            n: u.len() as u64,
            mean,
            m2,
            m3,
        }
    }

    /// The moments of the union of two samples (Chan et al. 1979; Pébay 2008).
    pub fn combine(a: &Moments, b: &Moments) -> Moments {
        if a.n == 0 {
            return *b;
        }
        if b.n == 0 {
            return *a;
        }
        let (na, nb) = (a.n as f64, b.n as f64);
        let n = na + nb;
        let d = b.mean - a.mean;
        Moments {
            n: a.n + b.n,
            mean: a.mean + d * nb / n,
            m2: a.m2 + b.m2 + d * d * na * nb / n,
            m3: a.m3
                + b.m3
                + d * d * d * na * nb * (na - nb) / (n * n)
                + 3.0 * d * (na * b.m2 - nb * a.m2) / n,
        }
    }

    /// Plug-in cumulants `[κ1, κ2, κ3]` (NaN when empty): the derivatives of
    /// the empirical log characteristic function at 0 (II eqs 57-58), so
    /// the kernel curves and the cumulants agree. They are biased by about
    /// `-κ2/n` and `-3κ3/n` against the k-statistics; the bias grows with
    /// the scale as n falls (like a^-2), which tilts c2 up by about 1e-5 at
    /// 32 x 1024^2 (a few thousand WTMMM at the top fitted scale) and by
    /// 0.1 standard error on 4 x 256^2 (28 WTMMM there).
    pub fn cumulants(&self) -> [f64; 3] {
        if self.n == 0 {
            return [f64::NAN; 3];
        }
        let n = self.n as f64;
        [self.mean, self.m2 / n, self.m3 / n]
    }
}

/// The partial sums of one image.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct KernelImage {
    /// Free label (file name), for the record.
    pub label: String,
    /// Per scale.
    pub moments: Vec<Moments>,
    /// `Σ cos(p_k ln M)` and `Σ sin(p_k ln M)`, index `j * n_p + k`.
    pub cf_re: Vec<f64>,
    /// `Σ sin(p_k ln M)`, same layout as `cf_re`.
    pub cf_im: Vec<f64>,
    /// The moments per scale of each tile of the counting domain (each
    /// WTMMM in the tile holding it): the jackknife groups of an ensemble
    /// of fewer than 3 images, as for the spectra
    /// ([`crate::spectra::ImagePartial::tiles`]). Empty unless asked for.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub tiles: Vec<Vec<Moments>>,
    /// Side of the tiles in px (0 without tiles).
    #[serde(default, skip_serializing_if = "crate::spectra::is_zero")]
    pub tile_side: usize,
}

/// Mergeable kernel sums of an ensemble (one partial per image).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct KernelSums {
    /// Crate version that wrote the sums.
    pub version: String,
    /// Which WTMMM were summed (all, or those on maxima lines).
    pub set: WtmmmSet,
    /// The p grid of the characteristic-function sums.
    pub config: KernelConfig,
    /// The scales, in pixels, ascending.
    pub scales: Vec<f64>,
    /// One partial per image, in the order added.
    pub images: Vec<KernelImage>,
}

impl KernelSums {
    /// The sums of one image from the values of `ln M` at each scale
    /// (`ln_m[j]` at `scales[j]`); non-finite values are skipped.
    ///
    /// **Errors** on an invalid p grid, an empty scale list, or a number of
    /// value lists different from the number of scales.
    pub fn from_ln_m(
        scales: &[f64],
        config: KernelConfig,
        set: WtmmmSet,
        ln_m: &[Vec<f64>],
        label: impl Into<String>,
    ) -> Result<Self> {
        config.validate()?;
        if scales.is_empty() {
            return Err(Error::param("scales", "no scale given"));
        }
        if ln_m.len() != scales.len() {
            return Err(Error::param(
                "scales",
                format!("{} value lists for {} scales", ln_m.len(), scales.len()),
            ));
        }
        let np = config.len();
        let mut img = KernelImage {
            label: label.into(),
            moments: Vec::with_capacity(scales.len()),
            cf_re: vec![0.0; np * scales.len()],
            cf_im: vec![0.0; np * scales.len()],
            tiles: Vec::new(),
            tile_side: 0,
        };
        let mut u: Vec<f64> = Vec::new();
        for (j, vals) in ln_m.iter().enumerate() {
            u.clear();
            u.extend(vals.iter().copied().filter(|v| v.is_finite()));
            img.moments.push(Moments::of(&u));
            cf_sums(
                &u,
                config.dp,
                &mut img.cf_re[j * np..(j + 1) * np],
                &mut img.cf_im[j * np..(j + 1) * np],
            );
        }
        Ok(KernelSums {
            version: crate::VERSION.to_string(),
            set,
            config,
            scales: scales.to_vec(),
            images: vec![img],
        })
    }

    /// The sums of one image's WTMMM (`points[j]` at `scales[j]`).
    ///
    /// **Errors** as [`KernelSums::from_ln_m`].
    pub fn from_points(
        scales: &[f64],
        config: KernelConfig,
        set: WtmmmSet,
        points: &[Vec<Point>],
        label: impl Into<String>,
    ) -> Result<Self> {
        let ln_m: Vec<Vec<f64>> = points
            .iter()
            .map(|ps| ps.iter().filter(|p| p.m > 0.0).map(|p| p.m.ln()).collect())
            .collect();
        Self::from_ln_m(scales, config, set, &ln_m, label)
    }

    /// [`from_points`](Self::from_points), also split over tiles of about
    /// `tile_side` px of the counting domain `domain` (`(y0, y1, x0, x1)`,
    /// [`crate::spectra::TileGrid`]; no tiles when fewer than 2 fit): the
    /// jackknife groups of a lone image.
    ///
    /// **Errors** as [`from_points`](Self::from_points).
    pub fn from_points_tiled(
        scales: &[f64],
        config: KernelConfig,
        set: WtmmmSet,
        points: &[Vec<Point>],
        label: impl Into<String>,
        domain: (usize, usize, usize, usize),
        tile_side: usize,
    ) -> Result<Self> {
        let mut s = Self::from_points(scales, config, set, points, label)?;
        if let Some(g) = crate::spectra::TileGrid::new(domain, tile_side) {
            let mut vals: Vec<Vec<f64>> = vec![Vec::new(); g.len()];
            let mut tiles = vec![Vec::with_capacity(scales.len()); g.len()];
            for ps in points {
                vals.iter_mut().for_each(Vec::clear);
                for p in ps.iter().filter(|p| p.m > 0.0 && p.m.is_finite()) {
                    vals[g.index(p.x, p.y)].push(p.m.ln());
                }
                for (t, v) in tiles.iter_mut().zip(&vals) {
                    t.push(Moments::of(v));
                }
            }
            s.images[0].tiles = tiles;
            s.images[0].tile_side = tile_side;
        }
        Ok(s)
    }

    /// The leave-one-out moments per scale over the jackknife groups: the
    /// images when there are 3 or more, else the tiles of every image when
    /// each has them and there are 3 or more in all (`None` otherwise), with
    /// the number of tiles.
    fn tile_replicates(&self) -> Option<Vec<Vec<Moments>>> {
        if self.images.len() >= 3 || self.images.iter().any(|im| im.tiles.is_empty()) {
            return None;
        }
        // in the images' canonical order, tiles in their own order
        let tiles: Vec<&Vec<Moments>> = self
            .canonical()
            .into_iter()
            .flat_map(|i| self.images[i].tiles.iter())
            .collect();
        if tiles.len() < 3 {
            return None;
        }
        Some(
            (0..tiles.len())
                .map(|skip| {
                    (0..self.scales.len())
                        .map(|j| {
                            tiles
                                .iter()
                                .enumerate()
                                .filter(|&(t, _)| t != skip)
                                .fold(Moments::default(), |acc, (_, m)| {
                                    Moments::combine(&acc, &m[j])
                                })
                        })
                        .collect()
                })
                .collect(),
        )
    }

    /// **Errors** unless the sums are whole: a valid p grid, positive
    /// finite ascending scales, and in each image one [`Moments`] per scale
    /// and `scales x p` characteristic-function sums (tiles: one `Moments`
    /// per scale each). A deserialised shard (truncated, edited) is checked
    /// before it is merged or read ([`Self::merge`], [`kernel_estimates`]).
    pub fn check(&self) -> Result<()> {
        self.config.validate()?;
        if self.scales.is_empty()
            || !self.scales.iter().all(|a| a.is_finite() && *a > 0.0)
            || self.scales.windows(2).any(|w| w[0] >= w[1])
        {
            return Err(Error::param(
                "scales",
                "the kernel sums need positive, finite, ascending scales",
            ));
        }
        let (ns, np) = (self.scales.len(), self.config.len());
        for (i, im) in self.images.iter().enumerate() {
            let cells = ns * np;
            if im.moments.len() != ns
                || im.cf_re.len() != cells
                || im.cf_im.len() != cells
                || im.tiles.iter().any(|t| t.len() != ns)
            {
                return Err(Error::Input(format!(
                    "kernel sums of image {i} ({}): {} moments, {} + {} characteristic-function \
                     sums for {ns} scales x {np} p, tiles of {:?} scales",
                    im.label,
                    im.moments.len(),
                    im.cf_re.len(),
                    im.cf_im.len(),
                    im.tiles.iter().map(Vec::len).collect::<Vec<_>>()
                )));
            }
        }
        Ok(())
    }

    /// Adds `other`'s images (order-independent once evaluated).
    ///
    /// **Errors** if the scales, the p grid or the WTMMM set differ, or
    /// either fails [`Self::check`].
    pub fn merge(&mut self, other: &KernelSums) -> Result<()> {
        self.check()?;
        other.check()?;
        if self.config != other.config {
            return Err(Error::param(
                "p-max",
                "cannot merge kernel sums over different p grids",
            ));
        }
        if self.set != other.set {
            return Err(Error::param(
                "set",
                "cannot merge kernel sums over different WTMMM sets",
            ));
        }
        if !crate::cwt::same_scales(&self.scales, &other.scales) {
            return Err(Error::param(
                "scales",
                "cannot merge kernel sums over different scales",
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

    /// Images in the canonical order (by total count, then the bits of the
    /// per-scale means, then label): identical images tie harmlessly.
    fn canonical(&self) -> Vec<usize> {
        let mut idx: Vec<usize> = (0..self.images.len()).collect();
        let key = |i: usize| {
            let im = &self.images[i];
            let n: u64 = im.moments.iter().map(|m| m.n).sum();
            let bits: Vec<u64> = im.moments.iter().map(|m| m.mean.to_bits()).collect();
            (n, bits, im.label.clone())
        };
        idx.sort_by_key(|&i| key(i));
        idx
    }

    /// Ensemble moments per scale, leaving out image `skip`.
    fn ensemble_moments(&self, order: &[usize], skip: Option<usize>) -> Vec<Moments> {
        (0..self.scales.len())
            .map(|j| {
                order
                    .iter()
                    .filter(|&&i| Some(i) != skip)
                    .fold(Moments::default(), |acc, &i| {
                        Moments::combine(&acc, &self.images[i].moments[j])
                    })
            })
            .collect()
    }

    /// Ensemble characteristic function at scale `j`, `p >= 0`.
    fn ensemble_cf(&self, order: &[usize], j: usize) -> Vec<Complex64> {
        let np = self.config.len();
        let mut re = vec![0.0; np];
        let mut im = vec![0.0; np];
        let mut n = 0u64;
        for &i in order {
            let img = &self.images[i];
            n += img.moments[j].n;
            for k in 0..np {
                re[k] += img.cf_re[j * np + k];
                im[k] += img.cf_im[j * np + k];
            }
        }
        let nf = n.max(1) as f64;
        re.iter()
            .zip(&im)
            .map(|(r, i)| Complex64::new(r / nf, i / nf))
            .collect()
    }
}

/// Adds `Σ cos(p_k u)`, `Σ sin(p_k u)` for `p_k = k dp` by the recurrence
/// `e^{i p_{k+1} u} = e^{i p_k u} e^{i dp u}` (one sin/cos per value; the
/// rounding drift after K steps is ~K ulp). The sums over the values run in
/// `LANES` (8) independent partial sums, so that the loop vectorises instead
/// of waiting on one chain of additions (the kernel's share of `validate`
/// went from 7 % to 4 %; 3.8 -> 2.4 ms for 30 000 values and 161 p). The
/// baseline SSE2 build is kept: an AVX2 build of the same loop was slower
/// (3.1 ms) on the EPYC host.
fn cf_sums(u: &[f64], dp: f64, re: &mut [f64], im: &mut [f64]) {
    const LANES: usize = 8;
    const BLOCKS: usize = 32;
    const CHUNK: usize = LANES * BLOCKS;
    // lane blocks, so that each step is a whole-register operation
    let mut cr = [[0.0f64; LANES]; BLOCKS];
    let mut ci = [[0.0f64; LANES]; BLOCKS];
    let mut sr = [[0.0f64; LANES]; BLOCKS];
    let mut si = [[0.0f64; LANES]; BLOCKS];
    for ch in u.chunks(CHUNK) {
        let n = ch.len();
        for (i, &v) in ch.iter().enumerate() {
            let (s, c) = (dp * v).sin_cos();
            let (q, l) = (i / LANES, i % LANES);
            sr[q][l] = c;
            si[q][l] = s;
            cr[q][l] = 1.0;
            ci[q][l] = 0.0;
        }
        let full = n / LANES;
        let rest = n % LANES;
        for k in 0..re.len() {
            let mut a = [0.0f64; LANES];
            let mut b = [0.0f64; LANES];
            for q in 0..full {
                let (xr, xi, yr, yi) = (&mut cr[q], &mut ci[q], &sr[q], &si[q]);
                for l in 0..LANES {
                    a[l] += xr[l];
                    b[l] += xi[l];
                    let r = xr[l] * yr[l] - xi[l] * yi[l];
                    xi[l] = xr[l] * yi[l] + xi[l] * yr[l];
                    xr[l] = r;
                }
            }
            let mut sa = a.iter().sum::<f64>();
            let mut sb = b.iter().sum::<f64>();
            if rest > 0 {
                let (xr, xi, yr, yi) = (&mut cr[full], &mut ci[full], &sr[full], &si[full]);
                for l in 0..rest {
                    sa += xr[l];
                    sb += xi[l];
                    let r = xr[l] * yr[l] - xi[l] * yi[l];
                    xi[l] = xr[l] * yi[l] + xi[l] * yr[l];
                    xr[l] = r;
                }
            }
            re[k] += sa;
            im[k] += sb;
        }
    }
}

/// Diagnostic: the same sums over the `ln M` of every pixel of the CWT
/// grid (every `stride`-th row and column of the analysis domain, counted
/// from the nearer end of each side, so that a flipped or rotated image
/// samples the same pixels), instead of the WTMMM. It separates what the
/// transform itself carries from what the selection of WTMMM does (II
/// §4.1 prefers the skeleton because
/// `C(p, a')` of the grid decays faster with p; the cumulants do not need
/// large p).
///
/// **Errors** as [`crate::skeleton::skeleton_with`], or if `stride` is 0.
pub fn cwt_grid_sums(
    field: &crate::field::Field,
    cfg: &crate::skeleton::AnalysisConfig,
    config: KernelConfig,
    stride: usize,
    label: impl Into<String>,
) -> Result<KernelSums> {
    if stride == 0 {
        return Err(Error::param("grid-stride", "must be >= 1"));
    }
    cfg.validate()?;
    let domain = cfg.domain(field)?;
    let img = cfg.input(field)?;
    let scales = cfg.scale_list();
    let (ny, nx) = field.dim();
    let plan = crate::cwt::CwtPlan::new(ny, nx, cfg.wavelet, &scales)?;
    // rows (columns) whose offset from the nearer end of the domain's side
    // is a multiple of the stride: mirror-symmetric. A lattice from one
    // end is not: a flip of an even side maps it onto the other parity
    // (on a 200 x 300 crop c3 read -0.145 +- 0.018, flipped -0.200)
    let picked = |lo: usize, hi: usize| -> Vec<usize> {
        (lo..hi)
            .filter(|&i| (i - lo).min(hi - 1 - i).is_multiple_of(stride))
            .collect()
    };
    let (rows, cols) = (picked(domain.y0, domain.y1), picked(domain.x0, domain.x1));
    let mut vals: Vec<Vec<f64>> = vec![Vec::new(); scales.len()];
    plan.for_each_scale(img.view(), |j, a, t| {
        for &y in &rows {
            for &x in &cols {
                if let Some(d) = &domain.mask_distance
                    && (d[[y, x]] as f64) <= domain.support * a
                {
                    continue;
                }
                let m = crate::cwt::modulus(t[[y, x]]);
                if m > 0.0 {
                    vals[j].push(m.ln());
                }
            }
        }
    })?;
    KernelSums::from_ln_m(&scales, config, WtmmmSet::All, &vals, label)
}

/// What [`kernel_estimates`] reports; scales are given in octaves above the
/// smallest scale (the paper's `σ_W` units: `a = 2^x` in II Figs 25-28 is
/// octave `x` here), each taken at the nearest scale of the grid.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct KernelOptions {
    /// Fit range of `κ_n` against `ln a`, in octaves (SPEC `--fit`).
    pub fit: (f64, f64),
    /// Reference scales `a'` of the `C_n(a, a')` tables (II Figs 26, 28).
    pub refs: Vec<f64>,
    /// Pairs `(a, a')` of the kernel curves (II Fig 25).
    pub pairs: Vec<(f64, f64)>,
}

/// The CLI's defaults (`wtmm kernel` on a 5-octave grid): fit 0.5:4 as for
/// the spectra, the reference scales of II Fig 26 inside the fit range,
/// above its start (the paper's 0.5 needs its `fit: (0.0, 3.5)`), the
/// pairs of II Fig 25. On another grid (fewer octaves, explicit scales)
/// some of these lie off it and [`kernel_estimates`] refuses them: take
/// [`KernelOptions::for_scales`].
impl Default for KernelOptions {
    fn default() -> Self {
        KernelOptions {
            fit: (0.5, 4.0),
            refs: DEFAULT_REF_OCTAVES[1..].to_vec(),
            pairs: DEFAULT_PAIR_OCTAVES.to_vec(),
        }
    }
}

/// Reference octaves of II Fig 26 (above a_min).
pub const DEFAULT_REF_OCTAVES: [f64; 7] = [0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 3.5];
/// Scale pairs of II Fig 25 (octaves above a_min).
pub const DEFAULT_PAIR_OCTAVES: [(f64, f64); 4] = [(0.5, 3.5), (1.0, 3.5), (1.0, 3.0), (1.5, 3.0)];

impl KernelOptions {
    /// The paper's reference scales and pairs fitted to a grid of `scales`
    /// (ascending), with the fit range `fit` (octaves), as `wtmm kernel`
    /// without `--refs` and `--pairs`: the references of
    /// [`DEFAULT_REF_OCTAVES`] that lie on the grid, inside the fit range
    /// and above its start (`C_n(a, a')` needs a smaller `a` in the fit;
    /// a larger `a'` would reach scales the fit leaves out), the pairs of
    /// [`DEFAULT_PAIR_OCTAVES`] with octaves beyond the grid's top lowered
    /// onto it, duplicates and collapsed pairs dropped. [`Default`] holds
    /// for 3.5 octaves or more (its top reference and pairs); on a shorter
    /// grid they are off the scales and [`kernel_estimates`] refuses them.
    /// An empty grid gets no references and no pairs.
    pub fn for_scales(scales: &[f64], fit: (f64, f64)) -> Self {
        let (Some(&first), Some(&last)) = (scales.first(), scales.last()) else {
            return KernelOptions {
                fit,
                refs: Vec::new(),
                pairs: Vec::new(),
            };
        };
        let top = ((last / first).log2() * 1e9).round() / 1e9;
        let refs = DEFAULT_REF_OCTAVES
            .into_iter()
            .filter(|&o| octave_on_grid(scales, o) && o > fit.0 + 1e-9 && o <= fit.1 + 1e-9)
            .collect();
        let mut pairs: Vec<(f64, f64)> = Vec::new();
        for (a, b) in DEFAULT_PAIR_OCTAVES {
            let p = (a.min(top), b.min(top));
            if p.0 < p.1 && !pairs.contains(&p) {
                pairs.push(p);
            }
        }
        KernelOptions { fit, refs, pairs }
    }
}

/// A fitted cumulant.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Estimate {
    /// The fitted `c_n` (natural-log convention of the module doc).
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub value: f64,
    /// Its standard error: delete-one jackknife over images (>= 3 images),
    /// or over tiles (fewer images, split), else the regression's
    /// (`pooled`: jackknife only, NaN without one).
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub stderr: f64,
    /// R² of the regression of `κ_n` on `ln a`.
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub r2: f64,
}

/// `c1, c2, c3` (the JSON keys of `kernel.json`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct FittedCumulants {
    /// `c1` (II eq 49; `m/ln2` for a log-normal W-cascade, II eq 56).
    pub c1: Estimate,
    /// `c2` (`σ²/ln2` for a log-normal W-cascade).
    pub c2: Estimate,
    /// `c3` (0 for a log-normal W-cascade).
    pub c3: Estimate,
}

impl FittedCumulants {
    /// `[c1, c2, c3]` values.
    pub fn values(&self) -> [f64; 3] {
        [self.c1.value, self.c2.value, self.c3.value]
    }
}

/// One point of a `C_n(a, a')` table.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct CnRow {
    /// Scale `a`, in pixels.
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub a: f64,
    /// `log2(a / a_min)`.
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub octave: f64,
    /// `ln(a'/a)`.
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub ln_ratio: f64,
    /// `[C1, C2, C3]`.
    #[serde(deserialize_with = "crate::nan_null::arr")]
    pub c: [f64; 3],
    /// Jackknife standard errors (NaN with < 3 images).
    #[serde(deserialize_with = "crate::nan_null::arr")]
    pub c_stderr: [f64; 3],
}

/// `C_n(a, a')` for one reference scale `a'` and every grid scale `a < a'`
/// in the fit range.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CnTable {
    /// Reference scale `a'`, in pixels (the grid scale nearest the asked octave).
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub a_ref: f64,
    /// `log2(a' / a_min)`.
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub octave_ref: f64,
    /// One row per grid scale `a < a'` in the fit range, ascending.
    pub rows: Vec<CnRow>,
    /// Least-squares slopes through the origin of `C_n` against `ln(a'/a)`.
    #[serde(deserialize_with = "crate::nan_null::arr")]
    pub slope: [f64; 3],
}

/// `Ĝ_aa'(p)` for one pair, `p` from `-p_max` to `p_max`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct KernelCurve {
    /// Smaller scale `a`, in pixels (the grid scale nearest the asked octave).
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub a: f64,
    /// Larger scale `a'`, in pixels.
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub a_ref: f64,
    /// `log2(a / a_min)`.
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub octave: f64,
    /// `log2(a' / a_min)`.
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub octave_ref: f64,
    /// `ln(a'/a)`.
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub ln_ratio: f64,
    /// The p values, `-p_max ..= p_max` in steps of `dp`.
    #[serde(deserialize_with = "crate::nan_null::vec")]
    pub p: Vec<f64>,
    /// `Re, Im C(p, a)` and `Re, Im C(p, a')` (II eq 45).
    #[serde(deserialize_with = "crate::nan_null::vec")]
    pub cf_re: Vec<f64>,
    /// `Im C(p, a)`.
    #[serde(deserialize_with = "crate::nan_null::vec")]
    pub cf_im: Vec<f64>,
    /// `Re C(p, a')`.
    #[serde(deserialize_with = "crate::nan_null::vec")]
    pub cf_ref_re: Vec<f64>,
    /// `Im C(p, a')`.
    #[serde(deserialize_with = "crate::nan_null::vec")]
    pub cf_ref_im: Vec<f64>,
    /// `ln |Ĝ_aa'(p)|` and the phase unwrapped from `Φ(0) = 0`.
    #[serde(deserialize_with = "crate::nan_null::vec")]
    pub ln_abs_g: Vec<f64>,
    /// Unwrapped phase `Φ(p)` of `Ĝ_aa'(p)` (radians; odd in p).
    #[serde(deserialize_with = "crate::nan_null::vec")]
    pub phase: Vec<f64>,
    /// The collapse `ln Ĝ_aa'^(1/ln(a'/a))`: both divided by `ln(a'/a)`.
    #[serde(deserialize_with = "crate::nan_null::vec")]
    pub ln_abs_g_norm: Vec<f64>,
    /// `phase / ln(a'/a)`.
    #[serde(deserialize_with = "crate::nan_null::vec")]
    pub phase_norm: Vec<f64>,
}

/// Everything [`kernel_estimates`] computes.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct KernelResult {
    /// Which WTMMM were used.
    pub set: WtmmmSet,
    /// Number of images.
    pub images: usize,
    /// The scales, in pixels.
    #[serde(deserialize_with = "crate::nan_null::vec")]
    pub scales: Vec<f64>,
    /// `log2(a / a_min)`.
    #[serde(deserialize_with = "crate::nan_null::vec")]
    pub octaves: Vec<f64>,
    /// WTMMM per scale (all images).
    pub n_wtmmm: Vec<u64>,
    /// Ensemble cumulants of `ln M` per scale.
    #[serde(deserialize_with = "crate::nan_null::vec")]
    pub kappa1: Vec<f64>,
    /// Plug-in variance `κ2` of `ln M` per scale (NaN where no WTMMM).
    #[serde(deserialize_with = "crate::nan_null::vec")]
    pub kappa2: Vec<f64>,
    /// Plug-in third cumulant `κ3` of `ln M` per scale.
    #[serde(deserialize_with = "crate::nan_null::vec")]
    pub kappa3: Vec<f64>,
    /// Fit range, in octaves above `a_min`.
    #[serde(deserialize_with = "crate::nan_null::pair")]
    pub fit_octaves: (f64, f64),
    /// The smallest and largest scales (px) inside the fit range.
    #[serde(deserialize_with = "crate::nan_null::pair")]
    pub fit_scales: (f64, f64),
    /// `c_n = -dκ_n/d ln a` over the fit range (SPEC §5; JSON `cumulants`).
    pub cumulants: FittedCumulants,
    /// "jackknife over images" (>= 3 images), "jackknife over N tiles (S
    /// px)" (fewer, split into tiles), "regression", or either jackknife
    /// followed by "; regression for c2, ..." naming the cumulants whose
    /// leave-one-out fits were not all finite (also a warning).
    pub stderr_method: String,
    /// One `C_n(a, a')` table per reference scale (II Figs 26, 28).
    pub tables: Vec<CnTable>,
    /// The slope through the origin of all the tables' `C_n(a, a')`
    /// points, references pooled (II Figs 26, 28 as drawn; with the default
    /// references and `fit = (0, 3.5)` this is the paper's protocol), with
    /// jackknife errors (NaN with < 3 images); `r2` is the uncentred
    /// `(Σxy)² / (Σx² Σy²)`.
    pub pooled: FittedCumulants,
    /// One kernel curve per pair of scales (II Figs 25, 27).
    pub kernels: Vec<KernelCurve>,
    /// The bias the plug-in cumulants give the fitted `c1, c2, c3`: the
    /// same fit applied to the per-scale biases `0, -κ2/n, -3κ3/n` of the
    /// plug-in `κ_n` of `n` WTMMM. The estimate's expectation is about
    /// `c_n + plugin_tilt[n - 1]`; the jackknife errors do not include it
    /// (every replicate shares it). `c1`'s is 0 (the mean is unbiased); NaN
    /// where `c_n` is not estimable.
    #[serde(default, deserialize_with = "crate::nan_null::arr")]
    pub plugin_tilt: [f64; 3],
    /// Human-readable warnings (few WTMMM at the top of the fit, < 3 images).
    pub warnings: Vec<String>,
}

/// Fewest WTMMM (over the ensemble) each scale read by the kernel needs,
/// see [`check_wtmmm_counts`]: the plug-in `κ_n` of fewer than `n` values is
/// identically 0 (`κ2` of one value, `κ3` of two), a number the fit would
/// take for a measurement, and of none it is NaN, which the fit would skip.
pub const MIN_WTMMM: u64 = 3;

/// The kernel sums of an ensemble of fields held in memory, made as `wtmm
/// kernel` makes them from files: each field's WTMMM of `set`
/// ([`crate::stats::pdf::image_wtmmm`], lines linked only for
/// [`WtmmmSet::Lines`]), one field at a time in parallel (a lone field's
/// scales in parallel instead), and with fewer than 3 fields each split
/// into the tiles of [`crate::spectra::default_tile_side`] so that the
/// jackknife runs over them ([`KernelSums::from_points_tiled`]). Then
/// [`kernel_estimates`] with [`KernelOptions::for_scales`]`(&cfg.scale_list(),
/// fit)` gives c1, c2, c3 with the errors `kernel` reports. Field `i` is
/// labelled `image i`.
///
/// **Errors** with no field, an invalid `cfg` or `kcfg`, or a field that
/// the skeleton refuses or that keeps no WTMMM (naming the field and the
/// likely cause).
pub fn ensemble_kernel_sums(
    fields: &[crate::Field],
    cfg: &crate::skeleton::AnalysisConfig,
    kcfg: KernelConfig,
    set: WtmmmSet,
) -> Result<KernelSums> {
    // before sizing tiles from them
    cfg.validate()?;
    kcfg.validate()?;
    let scales = cfg.scale_list();
    let par = if fields.len() == 1 {
        crate::skeleton::Parallelism::Scales
    } else {
        crate::skeleton::Parallelism::Serial
    };
    let named = |i: usize| {
        move |e: Error| match e {
            Error::Input(m) => Error::Input(format!("image {i}: {m}")),
            e => e,
        }
    };
    // the first bad field in order is named, whatever the scheduling
    let parts = crate::par::try_map(fields.len(), |i| {
        let f = &fields[i];
        let w = crate::stats::pdf::image_wtmmm(f, cfg, par, set == WtmmmSet::Lines)
            .map_err(named(i))?;
        if w.set(set).first().is_none_or(|v| v.is_empty()) {
            return Err(named(i)(Error::Input(cfg.why_no_maxima(f))));
        }
        let side = if fields.len() < 3 {
            let (ny, nx) = f.dim();
            crate::spectra::default_tile_side(cfg, ny, nx)
        } else {
            0
        };
        KernelSums::from_points_tiled(
            &scales,
            kcfg,
            set,
            w.set(set),
            format!("image {i}"),
            w.domain,
            side,
        )
    })?;
    let mut it = parts.into_iter();
    let mut acc = it
        .next()
        .ok_or_else(|| Error::Input("no field given".into()))?;
    for p in it {
        acc.merge(&p)?;
    }
    Ok(acc)
}

/// Grid indices inside the fit range `fit` (octaves above the smallest scale).
fn fit_indices(oct: &[f64], fit: (f64, f64)) -> Vec<usize> {
    (0..oct.len())
        .filter(|&j| oct[j] >= fit.0 - 1e-9 && oct[j] <= fit.1 + 1e-9)
        .collect()
}

/// Checks that every scale [`kernel_estimates`] reads with `opts` (the fit
/// range, the reference scales, both scales of each pair) holds at least
/// [`MIN_WTMMM`] WTMMM over the ensemble, as the spectra refuse a fit range
/// that no maxima line reaches. Call it once `kernel_estimates` accepted
/// `opts` (octaves are taken at the nearest grid scale here).
///
/// **Errors** ([`Error::Input`]) listing the scales short of WTMMM.
pub fn check_wtmmm_counts(s: &KernelSums, opts: &KernelOptions) -> Result<()> {
    if s.scales.is_empty() {
        return Err(Error::param("scales", "no scale given"));
    }
    let oct: Vec<f64> = s.scales.iter().map(|a| (a / s.scales[0]).log2()).collect();
    let mut used = fit_indices(&oct, opts.fit);
    used.extend(opts.refs.iter().map(|&o| nearest_scale(&s.scales, o)));
    for &(a, b) in &opts.pairs {
        used.extend([nearest_scale(&s.scales, a), nearest_scale(&s.scales, b)]);
    }
    used.sort_unstable();
    used.dedup();
    let count = |j: usize| -> u64 { s.images.iter().map(|im| im.moments[j].n).sum() };
    let short: Vec<(usize, u64)> = used
        .into_iter()
        .map(|j| (j, count(j)))
        .filter(|&(_, n)| n < MIN_WTMMM)
        .collect();
    if short.is_empty() {
        return Ok(());
    }
    // the smallest and the largest such scales say enough
    let mut list: Vec<String> = short
        .iter()
        .map(|&(j, n)| format!("{:.2} px ({n})", s.scales[j]))
        .collect();
    if list.len() > 4 {
        list.drain(2..list.len() - 2);
        list.insert(2, "...".into());
    }
    let set = s.set.phrase();
    if s.images
        .iter()
        .all(|im| im.moments.iter().all(|m| m.n == 0))
    {
        return Err(Error::Input(format!(
            "no WTMMM {set} at any scale, over {} image(s): the image is flat (constant), or \
             its counting domain holds no maxima (too small for the scales, or missing pixels \
             near every point)",
            s.images.len()
        )));
    }
    Err(Error::Input(format!(
        "fewer than {MIN_WTMMM} WTMMM {set} at {} of the scales the kernel uses (fit range \
         {}:{} octaves, references, pairs), over {} image(s): a = {}; c1..c3 need {MIN_WTMMM} \
         at each (the plug-in variance of one value and third cumulant of two are identically \
         0); the counting domain is too small for these scales (use fewer octaves, a \
         smaller margin, or a lower fit range: --octaves, --margin, --fit)",
        short.len(),
        opts.fit.0,
        opts.fit.1,
        s.images.len(),
        list.join(", ")
    )))
}

/// Nearest grid index to octave `o` above the smallest scale.
///
/// **Panics** if `scales` is empty.
pub fn nearest_scale(scales: &[f64], o: f64) -> usize {
    let want = scales[0].log2() + o;
    (0..scales.len())
        .min_by(|&a, &b| {
            (scales[a].log2() - want)
                .abs()
                .total_cmp(&(scales[b].log2() - want).abs())
        })
        .expect("non-empty scales")
}

/// True when octave `o` (above the smallest scale) lies on the grid: within
/// half a step of a grid scale (so octave 3 is the top scale 2.9 of a
/// 3-octave grid with 10 voices). False on an empty grid.
pub fn octave_on_grid(scales: &[f64], o: f64) -> bool {
    if scales.is_empty() {
        return false;
    }
    let half = if scales.len() > 1 {
        0.5 * (scales[1] / scales[0]).log2()
    } else {
        0.0
    };
    let top = (scales[scales.len() - 1] / scales[0]).log2();
    o.is_finite() && o >= -half - 1e-9 && o <= top + half + 1e-9
}

/// Cumulants of `ln M` per scale, `C_n(a, a')` tables, fitted `c_n` with
/// jackknife errors, and the kernel curves `Ĝ_aa'(p)` (II eqs 45-49,
/// 57-58; Figs 25-28). See the module doc for the conventions.
///
/// **Errors** if fewer than 3 scales fall in the fit range, an octave is
/// outside the scales, or a pair is not `a < a'`. A fitted scale with
/// fewer than [`MIN_WTMMM`] WTMMM has no cumulants, and the `c_n` are then
/// NaN (not estimable; a fit that skipped the scale would rest on a
/// different range in each jackknife replicate); scales short of WTMMM
/// are said in a warning ([`check_wtmmm_counts`], which a caller that
/// wants them refused calls as well).
pub fn kernel_estimates(s: &KernelSums, opts: &KernelOptions) -> Result<KernelResult> {
    let ns = s.scales.len();
    if s.images.is_empty() {
        return Err(Error::Input("no image in the kernel sums".into()));
    }
    s.check()?;
    let oct: Vec<f64> = s.scales.iter().map(|a| (a / s.scales[0]).log2()).collect();
    let top = oct[ns - 1];
    let in_range = |o: f64| octave_on_grid(&s.scales, o);
    let in_fit = fit_indices(&oct, opts.fit);
    if in_fit.len() < 3 {
        return Err(Error::param(
            "fit",
            format!(
                "only {} scales in the fit range {}:{} octaves, need 3 (the {ns} scales span \
                 {top:.2} octaves above the smallest; widen --fit, or give more --voices or \
                 --octaves)",
                in_fit.len(),
                crate::error::short(opts.fit.0),
                crate::error::short(opts.fit.1)
            ),
        ));
    }
    for &o in &opts.refs {
        if !in_range(o) {
            return Err(Error::param(
                "refs",
                format!("reference octave {o} outside the scales (0..{top:.2})"),
            ));
        }
    }
    for &(a, b) in &opts.pairs {
        if !(in_range(a) && in_range(b) && a < b) {
            return Err(Error::param(
                "pairs",
                format!("pair {a}:{b} must satisfy 0 <= a < a' <= {top:.2} octaves"),
            ));
        }
    }
    let order = s.canonical();
    let ens = s.ensemble_moments(&order, None);
    // fewer than MIN_WTMMM values have no cumulants (the plug-in variance of
    // one value and the third cumulant of two are identically 0): NaN, so
    // that no fit takes them for data, in the leave-one-out samples too
    let cumulants_of = |m: &[Moments]| -> Vec<[f64; 3]> {
        m.iter()
            .map(|mm| {
                if mm.n < MIN_WTMMM {
                    [f64::NAN; 3]
                } else {
                    mm.cumulants()
                }
            })
            .collect()
    };
    let kappa = cumulants_of(&ens);
    let ln_a: Vec<f64> = s.scales.iter().map(|a| a.ln()).collect();
    let fit_c = |kap: &[[f64; 3]]| -> [(f64, f64, f64); 3] {
        let x: Vec<f64> = in_fit.iter().map(|&j| ln_a[j]).collect();
        let mut out = [(f64::NAN, f64::NAN, f64::NAN); 3];
        for (n, o) in out.iter_mut().enumerate() {
            let y: Vec<f64> = in_fit.iter().map(|&j| kap[j][n]).collect();
            if y.iter().any(|v| !v.is_finite()) {
                continue; // a scale without cumulants: not estimable
            }
            if let Some(f) = line_fit(&x, &y) {
                // C_n(a, a') = κ_n(a) - κ_n(a') = c_n ln(a'/a)  =>  c_n = -dκ_n/d ln a
                *o = (-f.slope, f.slope_stderr, f.r2);
            }
        }
        out
    };
    let main = fit_c(&kappa);
    // delete-one jackknife over images
    let n_img = s.images.len();
    let mut reps: Vec<Vec<[f64; 3]>> = Vec::new();
    // fewer than 3 images: over the tiles of their domains, if split
    let tile_reps = s.tile_replicates();
    if n_img >= 3 {
        // in the canonical order, so that the errors do not depend on merges
        for &i in &order {
            reps.push(cumulants_of(&s.ensemble_moments(&order, Some(i))));
        }
    } else if let Some(t) = &tile_reps {
        reps = t.iter().map(|m| cumulants_of(m)).collect();
    }
    let jk = |vals: &[f64]| -> f64 {
        if vals.len() < 3 {
            return f64::NAN;
        }
        crate::stats::jackknife_se(vals)
    };
    let rep_fits: Vec<[(f64, f64, f64); 3]> = reps.iter().map(|k| fit_c(k)).collect();
    let est = |n: usize| -> Estimate {
        let se_jk = jk(&rep_fits.iter().map(|r| r[n].0).collect::<Vec<_>>());
        Estimate {
            value: main[n].0,
            stderr: if se_jk.is_finite() { se_jk } else { main[n].1 },
            r2: main[n].2,
        }
    };
    let cumulants = FittedCumulants {
        c1: est(0),
        c2: est(1),
        c3: est(2),
    };
    // C_n(a, a') tables
    let tables: Vec<CnTable> = opts
        .refs
        .iter()
        .map(|&o| {
            let r = nearest_scale(&s.scales, o);
            let rows: Vec<CnRow> = in_fit
                .iter()
                .copied()
                .filter(|&j| j < r)
                .map(|j| {
                    let mut c = [0.0; 3];
                    let mut c_stderr = [f64::NAN; 3];
                    for n in 0..3 {
                        c[n] = kappa[j][n] - kappa[r][n];
                        let v: Vec<f64> = reps.iter().map(|k| k[j][n] - k[r][n]).collect();
                        c_stderr[n] = jk(&v);
                    }
                    CnRow {
                        a: s.scales[j],
                        octave: oct[j],
                        ln_ratio: ln_a[r] - ln_a[j],
                        c,
                        c_stderr,
                    }
                })
                .collect();
            let mut slope = [f64::NAN; 3];
            let sxx: f64 = rows.iter().map(|w| w.ln_ratio * w.ln_ratio).sum();
            if sxx > 0.0 {
                for (n, sl) in slope.iter_mut().enumerate() {
                    *sl = rows.iter().map(|w| w.ln_ratio * w.c[n]).sum::<f64>() / sxx;
                }
            }
            CnTable {
                a_ref: s.scales[r],
                octave_ref: oct[r],
                rows,
                slope,
            }
        })
        .collect();
    // II Figs 26, 28 read literally: one slope through the origin of every
    // C_n(a, a') point of the tables (all references pooled)
    // [slope, uncentred R² = (Σxy)² / (Σx² Σy²)] per cumulant
    let pooled_of = |kap: &[[f64; 3]]| -> [[f64; 2]; 3] {
        let mut out = [[f64::NAN; 2]; 3];
        let (mut sxx, mut sxy, mut syy) = (0.0, [0.0; 3], [0.0; 3]);
        for t in &tables {
            let r = nearest_scale(&s.scales, t.octave_ref);
            for w in &t.rows {
                let j = nearest_scale(&s.scales, w.octave);
                sxx += w.ln_ratio * w.ln_ratio;
                for n in 0..3 {
                    let y = kap[j][n] - kap[r][n];
                    sxy[n] += w.ln_ratio * y;
                    syy[n] += y * y;
                }
            }
        }
        if sxx > 0.0 {
            for n in 0..3 {
                out[n] = [
                    sxy[n] / sxx,
                    sxy[n] * sxy[n] / (sxx * syy[n]).max(f64::MIN_POSITIVE),
                ];
            }
        }
        out
    };
    let pooled_main = pooled_of(&kappa);
    let pooled_reps: Vec<[[f64; 2]; 3]> = reps.iter().map(|k| pooled_of(k)).collect();
    let pooled_est = |n: usize| Estimate {
        value: pooled_main[n][0],
        stderr: jk(&pooled_reps.iter().map(|r| r[n][0]).collect::<Vec<_>>()),
        r2: pooled_main[n][1],
    };
    let pooled = FittedCumulants {
        c1: pooled_est(0),
        c2: pooled_est(1),
        c3: pooled_est(2),
    };
    // kernel curves
    let p = s.config.grid();
    let np = p.len();
    let kernels = opts
        .pairs
        .iter()
        .map(|&(oa, ob)| {
            let (ja, jb) = (nearest_scale(&s.scales, oa), nearest_scale(&s.scales, ob));
            let ca = s.ensemble_cf(&order, ja);
            let cb = s.ensemble_cf(&order, jb);
            let ln_ratio = ln_a[jb] - ln_a[ja];
            let mut ln_abs = vec![0.0; np];
            let mut phase = vec![0.0; np];
            let mut prev = 0.0;
            for k in 0..np {
                let g = ca[k] / cb[k];
                ln_abs[k] = ca[k].norm().ln() - cb[k].norm().ln();
                let raw = g.arg();
                if k == 0 {
                    phase[0] = 0.0;
                } else {
                    let mut d = raw - prev;
                    d -= (2.0 * std::f64::consts::PI) * (d / (2.0 * std::f64::consts::PI)).round();
                    phase[k] = phase[k - 1] + d;
                }
                prev = raw;
            }
            // mirror to p < 0: ln|Ĝ| even, Φ odd, C(-p) = conj C(p)
            let mirror = |v: &[f64], odd: bool| -> Vec<f64> {
                let sgn = if odd { -1.0 } else { 1.0 };
                v[1..]
                    .iter()
                    .rev()
                    .map(|x| sgn * x)
                    .chain(v.iter().copied())
                    .collect()
            };
            let re_a: Vec<f64> = ca.iter().map(|z| z.re).collect();
            let im_a: Vec<f64> = ca.iter().map(|z| z.im).collect();
            let re_b: Vec<f64> = cb.iter().map(|z| z.re).collect();
            let im_b: Vec<f64> = cb.iter().map(|z| z.im).collect();
            let ln_abs_m = mirror(&ln_abs, false);
            let phase_m = mirror(&phase, true);
            KernelCurve {
                a: s.scales[ja],
                a_ref: s.scales[jb],
                octave: oct[ja],
                octave_ref: oct[jb],
                ln_ratio,
                p: mirror(&p, true),
                cf_re: mirror(&re_a, false),
                cf_im: mirror(&im_a, true),
                cf_ref_re: mirror(&re_b, false),
                cf_ref_im: mirror(&im_b, true),
                ln_abs_g_norm: ln_abs_m.iter().map(|v| v / ln_ratio).collect(),
                phase_norm: phase_m.iter().map(|v| v / ln_ratio).collect(),
                ln_abs_g: ln_abs_m,
                phase: phase_m,
            }
        })
        .collect();
    let mut warnings = Vec::new();
    // scales short of WTMMM (NaN cumulants, and NaN c_n if fitted): said
    // in the result, not only by a check the caller might skip
    if let Err(e) = check_wtmmm_counts(s, opts) {
        let why = match e {
            Error::Input(m) => m,
            e => e.to_string(),
        };
        warnings.push(format!("these c_n are not reliable: {why}"));
    }
    // The plug-in cumulants are biased by about -κ2/n and -3κ3/n
    // (`Moments::cumulants`); n falls like a^-2, so the bias tilts the
    // fitted slopes. Said when the tilt reaches half a standard error (the
    // jackknife does not see it: every replicate shares it).
    let bias: Vec<[f64; 3]> = kappa
        .iter()
        .zip(&ens)
        .map(|(k, m)| {
            let n = m.n as f64;
            [0.0, -k[1] / n, -3.0 * k[2] / n]
        })
        .collect();
    let tilt = fit_c(&bias);
    let last = *in_fit.last().expect("3 scales");
    for (n, &(t, _, _)) in tilt.iter().enumerate().skip(1) {
        let se = est(n).stderr;
        if t.is_finite() && se.is_finite() && se > 0.0 && t.abs() >= 0.5 * se {
            warnings.push(format!(
                "c{}: the plug-in cumulants of the few WTMMM at the largest fitted scales \
                 ({} at a = {:.2}) tilt it by about {:+.2e}, {:.1} of its standard error",
                n + 1,
                ens[last].n,
                s.scales[last],
                t,
                t.abs() / se
            ));
        }
    }
    if tables.iter().all(|t| t.rows.is_empty()) {
        let refs = if opts.refs.is_empty() {
            "no reference scale lies inside the fit range, above its start".to_string()
        } else {
            format!(
                "no reference scale (at {:?} octaves) has a fitted scale below it",
                opts.refs
            )
        };
        warnings.push(format!(
            "the C_n(a, a') tables are empty (pooled c_n: none): {refs} (fit {}:{} octaves); \
             give references inside the fit range or more octaves (--refs, --octaves)",
            opts.fit.0, opts.fit.1
        ));
    }
    // a reference above the fit range brings scales the fitted c_n leave
    // out into the pooled slope (II Fig 26 takes a' inside the range)
    let above: Vec<f64> = opts
        .refs
        .iter()
        .copied()
        .filter(|&r| r > opts.fit.1 + 1e-9)
        .collect();
    if !above.is_empty() {
        warnings.push(format!(
            "reference scale(s) at {above:?} octaves lie above the fit range {}:{}: their \
             C_n(a, a') reach scales the fitted c_n leave out, and the pooled c_n \
             (cumulants_pooled) include them",
            opts.fit.0, opts.fit.1
        ));
    }
    // (fewer than 3 images, or fewer than 10: stderr_method warns)
    // a cumulant whose leave-one-out fits are not all finite keeps the
    // regression error (`est` above): said, not silent
    let fallback: Vec<String> = (0..3)
        .filter(|&n| {
            reps.len() >= 3
                && main[n].0.is_finite()
                && !jk(&rep_fits.iter().map(|r| r[n].0).collect::<Vec<_>>()).is_finite()
        })
        .map(|n| format!("c{}", n + 1))
        .collect();
    let stderr_method = match &tile_reps {
        Some(t) => crate::stats::fit::stderr_method_tiles(
            n_img,
            t.len(),
            &crate::spectra::tile_sides(s.images.iter().map(|im| im.tile_side)),
            &fallback,
            &mut warnings,
        ),
        None => {
            let with = s.images.iter().filter(|im| !im.tiles.is_empty()).count();
            let why = crate::stats::fit::no_tiles_why(n_img, with);
            crate::stats::fit::stderr_method_why(n_img, &fallback, &mut warnings, why)
        }
    };
    Ok(KernelResult {
        set: s.set,
        images: n_img,
        scales: s.scales.clone(),
        octaves: oct,
        n_wtmmm: ens.iter().map(|m| m.n).collect(),
        kappa1: kappa.iter().map(|k| k[0]).collect(),
        kappa2: kappa.iter().map(|k| k[1]).collect(),
        kappa3: kappa.iter().map(|k| k[2]).collect(),
        fit_octaves: opts.fit,
        fit_scales: (s.scales[in_fit[0]], s.scales[last]),
        cumulants,
        plugin_tilt: [0.0, tilt[1].0, tilt[2].0],
        stderr_method,
        tables,
        pooled,
        kernels,
        warnings,
    })
}

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

#[cfg(test)]
mod tests {
    use super::*;
    use rand::RngExt;

    #[test]
    fn moments_combine_exactly() {
        let u: Vec<f64> = (0..37)
            .map(|i| ((i * 7919) % 101) as f64 / 13.0 - 2.0)
            .collect();
        let all = Moments::of(&u);
        let (a, b) = u.split_at(11);
        let c = Moments::combine(&Moments::of(a), &Moments::of(b));
        assert_eq!(c.n, all.n);
        assert!((c.mean - all.mean).abs() < 1e-13);
        assert!((c.m2 - all.m2).abs() < 1e-11 * all.m2.abs());
        assert!((c.m3 - all.m3).abs() < 1e-10 * all.m2.abs().max(1.0));
    }

    #[test]
    fn scales_short_of_wtmmm_are_refused() {
        // octaves 0..2 in quarters: 3 values per scale, 2 at the top (4 px)
        let scales: Vec<f64> = (0..9).map(|j| 2f64.powf(j as f64 / 4.0)).collect();
        let vals: Vec<Vec<f64>> = (0..9)
            .map(|j| [0.1, 0.2, 0.4][..if j == 8 { 2 } else { 3 }].to_vec())
            .collect();
        let cfg = KernelConfig::default();
        let s = KernelSums::from_ln_m(&scales, cfg, WtmmmSet::Lines, &vals, "x").unwrap();
        let opts = KernelOptions {
            fit: (0.0, 1.5),
            refs: vec![1.5],
            pairs: vec![(0.5, 1.5)],
        };
        check_wtmmm_counts(&s, &opts).unwrap();
        // the top scale in the fit range, as a reference, as a pair's end
        let bad = [
            KernelOptions {
                fit: (0.0, 2.0),
                ..opts.clone()
            },
            KernelOptions {
                refs: vec![2.0],
                ..opts.clone()
            },
            KernelOptions {
                pairs: vec![(0.5, 2.0)],
                ..opts.clone()
            },
        ];
        for o in bad {
            let e = check_wtmmm_counts(&s, &o).unwrap_err().to_string();
            assert!(e.contains("fewer than 3 WTMMM on maxima lines"), "{e}");
            assert!(e.contains("a = 4.00 px (2);"), "{e}");
            // the estimates run, and say it
            let r = kernel_estimates(&s, &o).unwrap();
            assert!(
                r.warnings
                    .iter()
                    .any(|w| w.contains("not reliable") && w.contains("a = 4.00 px (2);")),
                "{:?}",
                r.warnings
            );
        }
        assert!(
            !kernel_estimates(&s, &opts)
                .unwrap()
                .warnings
                .iter()
                .any(|w| w.contains("not reliable"))
        );
        // none at all (a flat image): said as such
        let empty: Vec<Vec<f64>> = vec![Vec::new(); 9];
        let s0 = KernelSums::from_ln_m(&scales, cfg, WtmmmSet::Lines, &empty, "x").unwrap();
        let e = check_wtmmm_counts(&s0, &opts).unwrap_err().to_string();
        assert!(e.contains("no WTMMM on maxima lines at any scale"), "{e}");
    }

    /// Three images hold 2, 1 and 1 WTMMM at the top scale: 4 over the
    /// ensemble passes the count check, but leaving out the first leaves 2,
    /// whose plug-in κ3 is 0. That replicate is not estimable: the errors
    /// fall back to the regression's, with the label and a warning.
    #[test]
    fn leave_one_out_samples_short_of_wtmmm_are_not_fitted() {
        let scales: Vec<f64> = (0..9).map(|j| 2f64.powf(j as f64 / 4.0)).collect();
        let cfg = KernelConfig::default();
        let top = [2usize, 1, 1];
        let mut s: Option<KernelSums> = None;
        for (i, &k) in top.iter().enumerate() {
            // ln M spreading more at small scales, different in each image
            let vals: Vec<Vec<f64>> = (0..9)
                .map(|j| {
                    let n = if j == 8 { k } else { 40 };
                    (0..n)
                        .map(|t| {
                            ((t * 37 + i * 11 + j * 5) % 23) as f64 * (0.05 - 0.004 * j as f64)
                        })
                        .collect()
                })
                .collect();
            let one = KernelSums::from_ln_m(&scales, cfg, WtmmmSet::Lines, &vals, format!("{i}"))
                .unwrap();
            match s.as_mut() {
                None => s = Some(one),
                Some(acc) => acc.merge(&one).unwrap(),
            }
        }
        let s = s.unwrap();
        let opts = KernelOptions {
            fit: (0.0, 2.0),
            refs: vec![1.0],
            pairs: vec![(0.0, 1.0)],
        };
        check_wtmmm_counts(&s, &opts).unwrap();
        let r = kernel_estimates(&s, &opts).unwrap();
        for c in [&r.cumulants.c1, &r.cumulants.c2, &r.cumulants.c3] {
            assert!(c.value.is_finite() && c.stderr.is_finite() && c.stderr > 0.0);
        }
        assert_eq!(
            r.stderr_method,
            "jackknife over images; regression for c1, c2, c3"
        );
        assert!(r.warnings.iter().any(|w| w.contains("not finite")));
        // with the top scale left out of the fit every replicate is estimable
        let opts = KernelOptions {
            fit: (0.0, 1.75),
            ..opts
        };
        let r = kernel_estimates(&s, &opts).unwrap();
        assert_eq!(r.stderr_method, "jackknife over images");
    }

    #[test]
    fn cf_recurrence_matches_direct() {
        // 5 values (lanes' remainder only), 16 (whole lanes), 611 (several
        // chunks, a remainder): the error grows as n K ulp at most
        let mut rng = crate::synth::rng_for(3, 0);
        for n in [5, 16, 611] {
            let u: Vec<f64> = (0..n).map(|_| rng.random_range(-6.0..6.0)).collect();
            let dp = 0.05;
            let np = 201;
            let mut re = vec![0.0; np];
            let mut im = vec![0.0; np];
            cf_sums(&u, dp, &mut re, &mut im);
            let tol = 2.2e-16 * (n * np) as f64;
            for k in 0..np {
                let p = k as f64 * dp;
                let (r, i): (f64, f64) = u
                    .iter()
                    .map(|v| ((p * v).cos(), (p * v).sin()))
                    .fold((0.0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1));
                assert!(
                    (re[k] - r).abs() < tol && (im[k] - i).abs() < tol,
                    "n={n} k={k}: {} {}",
                    re[k] - r,
                    im[k] - i
                );
            }
        }
    }

    /// The plug-in bias the warning names: Gaussian ln M with a known c2,
    /// few values at the top scales (n like a^-2). Over many ensembles the
    /// mean fitted c2 leaves the truth by the tilt of `-κ2/n`, within the
    /// Monte Carlo error, and the warning says so when the tilt is half a
    /// standard error or more.
    #[test]
    fn the_plug_in_tilt_of_c2_is_the_bias_the_warning_names() {
        use rand_distr::{Distribution, Normal};
        let scales: Vec<f64> = (0..9).map(|j| 2f64.powf(j as f64 / 4.0)).collect();
        let (k20, c2) = (0.3, 0.03);
        let kap2 = |a: f64| k20 - c2 * a.ln();
        let n_of = |a: f64| (160.0 / (a * a)).round() as usize; // 160 .. 10
        let opts = KernelOptions {
            fit: (0.0, 2.0),
            refs: vec![],
            pairs: vec![],
        };
        let mut rng = crate::synth::rng_for(11, 0);
        let (n_ens, n_img) = (3000, 4);
        let mut est = Vec::with_capacity(n_ens);
        let mut runs = Vec::with_capacity(n_ens);
        for _ in 0..n_ens {
            let mut s: Option<KernelSums> = None;
            for i in 0..n_img {
                let vals: Vec<Vec<f64>> = scales
                    .iter()
                    .map(|&a| {
                        let d = Normal::new(0.0, kap2(a).sqrt()).unwrap();
                        (0..n_of(a)).map(|_| d.sample(&mut rng)).collect()
                    })
                    .collect();
                let one = KernelSums::from_ln_m(
                    &scales,
                    KernelConfig::default(),
                    WtmmmSet::Lines,
                    &vals,
                    format!("{i}"),
                )
                .unwrap();
                match s.as_mut() {
                    None => s = Some(one),
                    Some(acc) => acc.merge(&one).unwrap(),
                }
            }
            let r = kernel_estimates(&s.unwrap(), &opts).unwrap();
            est.push(r.cumulants.c2.value);
            let warned = r.warnings.iter().any(|w| w.starts_with("c2: the plug-in"));
            // this run's tilt, from its own κ2 and counts
            let x: Vec<f64> = scales.iter().map(|a| a.ln()).collect();
            let y: Vec<f64> = r
                .kappa2
                .iter()
                .zip(&r.n_wtmmm)
                .map(|(k, &n)| -k / n as f64)
                .collect();
            let t = -line_fit(&x, &y).unwrap().slope;
            // the result records the same tilt (c1 has none)
            assert!((r.plugin_tilt[1] - t).abs() <= 1e-12 * t.abs().max(1e-6));
            assert_eq!(r.plugin_tilt[0], 0.0);
            runs.push((t, r.cumulants.c2.stderr, warned));
        }
        // the tilt, independently: minus the slope of -κ2/n over ln a
        let x: Vec<f64> = scales.iter().map(|a| a.ln()).collect();
        let y: Vec<f64> = scales
            .iter()
            .map(|&a| -kap2(a) / (n_img * n_of(a)) as f64)
            .collect();
        let tilt = -line_fit(&x, &y).unwrap().slope;
        let mean = est.iter().sum::<f64>() / n_ens as f64;
        let sd = (est.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / (n_ens - 1) as f64).sqrt();
        let mc = sd / (n_ens as f64).sqrt();
        assert!(tilt > 4.0 * mc, "tilt {tilt} vs MC error {mc}");
        assert!(
            (mean - c2 - tilt).abs() < 4.0 * mc,
            "mean c2 {mean}, truth {c2}, predicted tilt {tilt}, MC error {mc}"
        );
        // warned exactly where the run's tilt reaches half its error
        let n_warned = runs.iter().filter(|r| r.2).count();
        for &(t, se, warned) in &runs {
            assert_eq!(warned, t >= 0.5 * se, "tilt {t}, se {se}");
        }
        assert!(n_warned > 0 && n_warned < n_ens, "{n_warned} of {n_ens}");
    }

    /// The paper's references and pairs on a 3-octave grid of 10 voices
    /// (31 scales, top octave 3): `Default` names octaves off it and is
    /// refused; `for_scales` keeps those on it, above the fit's start, and
    /// lowers the pairs onto 3.
    #[test]
    fn default_options_follow_a_short_grid() {
        let scales: Vec<f64> = (0..31).map(|j| 1.5 * 2f64.powf(j as f64 / 10.0)).collect();
        let o = KernelOptions::for_scales(&scales, (0.5, 3.0));
        assert_eq!(o.refs, vec![1.0, 1.5, 2.0, 2.5, 3.0]);
        assert_eq!(o.pairs, vec![(0.5, 3.0), (1.0, 3.0), (1.5, 3.0)]);
        let o = KernelOptions::for_scales(&scales, (0.0, 3.0));
        assert_eq!(o.refs[0], 0.5);
        // on the grid's own data: estimates with for_scales, an error with Default
        let vals: Vec<Vec<f64>> = (0..31)
            .map(|j| {
                (0..50)
                    .map(|t| ((t * 37 + j * 5) % 23) as f64 * 0.05)
                    .collect()
            })
            .collect();
        let s = KernelSums::from_ln_m(
            &scales,
            KernelConfig::default(),
            WtmmmSet::Lines,
            &vals,
            "x",
        )
        .unwrap();
        assert!(kernel_estimates(&s, &KernelOptions::for_scales(&scales, (0.5, 3.0))).is_ok());
        let e = kernel_estimates(&s, &KernelOptions::default()).unwrap_err();
        assert!(e.to_string().contains("outside the scales"), "{e}");
        // 5 octaves: the same as Default
        let long: Vec<f64> = (0..51).map(|j| 1.5 * 2f64.powf(j as f64 / 10.0)).collect();
        assert_eq!(
            KernelOptions::for_scales(&long, (0.5, 4.0)),
            KernelOptions::default()
        );
        // no grid: nothing to name, and no panic
        let o = KernelOptions::for_scales(&[], (0.5, 4.0));
        assert!(o.refs.is_empty() && o.pairs.is_empty());
    }
}
