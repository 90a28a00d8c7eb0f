//! Kernel estimates: the options, the fitted cumulants `c_n` with their
//! jackknife errors, the `C_n(a, a')` tables and the kernel curves (II
//! eqs 47-49, 57-58; Figs 25-28).

use num_complex::Complex64;
use serde::{Deserialize, Serialize};

use super::{KernelConfig, KernelSums, Moments};
use crate::error::{Error, Result};
use crate::stats::fit::line_fit;
use crate::stats::pdf::WtmmmSet;

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
    /// Delete-one jackknife standard error of `ln |Ĝ_aa'(p)|` over the
    /// images, or with fewer than 3 over the tiles of their domains
    /// ([`KernelSums::from_points_tiled`]; NaN without tiles, see
    /// [`KernelResult::curve_stderr_method`]). Where the characteristic
    /// functions fall to their sampling noise, `Ĝ` is a ratio of noise and
    /// this error grows: the curve there says nothing of the kernel.
    #[serde(default, deserialize_with = "crate::nan_null::vec")]
    pub ln_abs_g_stderr: Vec<f64>,
    /// Jackknife standard error of the phase (as `ln_abs_g_stderr`).
    #[serde(default, deserialize_with = "crate::nan_null::vec")]
    pub phase_stderr: Vec<f64>,
    /// Jackknife standard error of `|C(p, a)|` (as `ln_abs_g_stderr`):
    /// with `1/sqrt(n)`, the sampling error of `n` independent values, the
    /// noise level below which `Ĝ` is a ratio of noise ([`KernelResult::noise`]).
    #[serde(default, deserialize_with = "crate::nan_null::vec")]
    pub cf_abs_stderr: Vec<f64>,
    /// Jackknife standard error of `|C(p, a')|`.
    #[serde(default, deserialize_with = "crate::nan_null::vec")]
    pub cf_ref_abs_stderr: Vec<f64>,
}

/// `ln |Ĝ_aa'(p)|` and its phase unwrapped from `Φ(0) = 0` (II eq 47), from
/// the characteristic functions at `a` and `a'` on `p >= 0`.
fn log_kernel(ca: &[Complex64], cb: &[Complex64]) -> (Vec<f64>, Vec<f64>) {
    let np = ca.len();
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
    (ln_abs, phase)
}

/// `phase` moved by whole turns to the branch of `main` (within pi of it).
/// Each jackknife replicate unwraps its phase from p = 0 on its own: where
/// a characteristic function dips to its noise, one may take the other
/// side of a turn and keep it for every larger p, which is no spread of
/// the estimate (the Levi Fell DEM's quadrants: an error of 4.85 rad at
/// p = 2 from two replicates one turn off, 0.88 on one branch).
pub(super) fn same_branch(phase: f64, main: f64) -> f64 {
    let turn = 2.0 * std::f64::consts::PI;
    phase - turn * ((phase - main) / turn).round()
}

fn none() -> String {
    "none".into()
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
    /// Where the curves' errors come from: "jackknife over images",
    /// "jackknife over N tiles (S px) of 1 image" (with ", K of them holding
    /// WTMMM at A px" when the pairs' scales leave some tiles empty:
    /// [`KernelSums::cf_tile_groups`]), or "none" (fewer than 3 images and
    /// no tiles, or the tiles of older sums, written without their
    /// characteristic functions).
    #[serde(default = "none")]
    pub curve_stderr_method: String,
    /// The curves' jackknife groups: their number (images, or tiles of
    /// fewer than 3 images; 0 without a jackknife) and the fewest of them
    /// holding WTMMM at a scale of a pair (the groups a curve rests on).
    #[serde(default)]
    pub curve_groups: [usize; 2],
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

/// How many standard errors of `|C(p)|` from 0 a characteristic function
/// must be for `Ĝ = C(p, a) / C(p, a')` to be read as the kernel
/// ([`KernelResult::noise`]).
pub const NOISE_SIGMAS: f64 = 3.0;

impl KernelResult {
    /// The p of curve `kc` where `Ĝ` is a ratio of noise (II eq 47): `|C(p)|`
    /// within [`NOISE_SIGMAS`] standard errors of 0 at `a` or `a'`, the
    /// error being the larger of `1/sqrt(n)` (the sampling error of `n`
    /// independent values, `n` the WTMMM at the scale) and the jackknife's
    /// (`cf_abs_stderr`: the WTMMM of a cascade are not independent, and
    /// the jackknife sees it). Never at p = 0 (C = 1 exactly).
    pub fn noise(&self, kc: &KernelCurve) -> Vec<bool> {
        // the curve's scales are grid scales: the nearest is the one
        let n_at = |a: f64| {
            let j = nearest_scale(&self.scales, (a / self.scales[0]).log2());
            self.n_wtmmm.get(j).copied().unwrap_or(0) as f64
        };
        let (na, nb) = (n_at(kc.a), n_at(kc.a_ref));
        let small = |re: f64, im: f64, n: f64, se: Option<&f64>| {
            let sigma = se
                .copied()
                .filter(|e| e.is_finite())
                .unwrap_or(0.0)
                .max(1.0 / n.sqrt());
            (re * re + im * im).sqrt() < NOISE_SIGMAS * sigma
        };
        (0..kc.p.len())
            .map(|i| {
                kc.p[i] != 0.0
                    && (small(kc.cf_re[i], kc.cf_im[i], na, kc.cf_abs_stderr.get(i))
                        || small(
                            kc.cf_ref_re[i],
                            kc.cf_ref_im[i],
                            nb,
                            kc.cf_ref_abs_stderr.get(i),
                        ))
            })
            .collect()
    }
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
    KernelSums::merge_all(parts)?.ok_or_else(|| Error::Input("no field given".into()))
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
/// **Errors** if the fit range is not within the scales or an end lies
/// between two ([`crate::spectra::check_fit_on_grid`], as the spectra),
/// fewer than 3 scales fall in it, an octave is outside the scales, or a
/// pair is not `a < a'`. A fitted scale with
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
    // as the spectra: within the grid, each end on a scale (or the top),
    // else the fit would run over other scales than recorded
    crate::spectra::check_fit_on_grid(&s.scales, opts.fit)?;
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
            let (ln_abs, phase) = log_kernel(&ca, &cb);
            // delete-one jackknife over the images, in the canonical order,
            // or over the tiles of fewer than 3 images
            let (mut se_abs, mut se_phase) = (vec![f64::NAN; np], vec![f64::NAN; np]);
            let (mut se_ca, mut se_cb) = (vec![f64::NAN; np], vec![f64::NAN; np]);
            // the leave-one-out characteristic functions at a and a'
            let reps: Vec<(Vec<Complex64>, Vec<Complex64>)> = if n_img >= 3 {
                order
                    .iter()
                    .map(|&i| {
                        let rest: Vec<usize> = order.iter().copied().filter(|&o| o != i).collect();
                        (s.ensemble_cf(&rest, ja), s.ensemble_cf(&rest, jb))
                    })
                    .collect()
            } else if let (Some(ra), Some(rb)) =
                (s.tile_cf_replicates(ja), s.tile_cf_replicates(jb))
            {
                ra.into_iter().zip(rb).collect()
            } else {
                Vec::new()
            };
            if reps.len() >= 3 {
                let logs: Vec<(Vec<f64>, Vec<f64>)> =
                    reps.iter().map(|(a, b)| log_kernel(a, b)).collect();
                let modulus = |z: &Complex64| (z.re * z.re + z.im * z.im).sqrt();
                for k in 0..np {
                    se_abs[k] = jk(&logs.iter().map(|r| r.0[k]).collect::<Vec<_>>());
                    let turns: Vec<f64> =
                        logs.iter().map(|r| same_branch(r.1[k], phase[k])).collect();
                    se_phase[k] = jk(&turns);
                    se_ca[k] = jk(&reps.iter().map(|r| modulus(&r.0[k])).collect::<Vec<_>>());
                    se_cb[k] = jk(&reps.iter().map(|r| modulus(&r.1[k])).collect::<Vec<_>>());
                }
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
                ln_abs_g_stderr: mirror(&se_abs, false),
                phase_stderr: mirror(&se_phase, false),
                cf_abs_stderr: mirror(&se_ca, false),
                cf_ref_abs_stderr: mirror(&se_cb, false),
            }
        })
        .collect();
    let mut warnings = Vec::new();
    let mut curve_groups = [0; 2];
    let curve_stderr_method = if n_img >= 3 {
        curve_groups = [n_img; 2];
        "jackknife over images".to_string()
    } else if let Some((total, sides, held)) = s.cf_tile_groups() {
        let mut m = format!(
            "jackknife over {total} tiles ({sides} px) of {}",
            if n_img == 1 { "1 image" } else { "2 images" }
        );
        // the fewest tiles holding WTMMM at a scale of a pair: where the
        // rest are empty, the curve rests on those alone
        let fewest = opts
            .pairs
            .iter()
            .flat_map(|&(a, b)| [nearest_scale(&s.scales, a), nearest_scale(&s.scales, b)])
            .min_by_key(|&j| (held[j], std::cmp::Reverse(j)));
        curve_groups = [total, fewest.map_or(total, |j| held[j])];
        if let Some(j) = fewest
            && held[j] < total
        {
            let at = format!("{:.1} px", s.scales[j]);
            m.push_str(&format!(", {} of them holding WTMMM at {at}", held[j]));
            let how = format!(
                "a jackknife over the {} tiles holding WTMMM at {at}",
                held[j]
            );
            if let Some(w) = crate::stats::fit::few_groups_warning(held[j], &how) {
                warnings.push(format!("kernel curves: {w}"));
            }
        } else if let Some(w) = crate::stats::fit::few_groups_warning(total, &format!("a {m}")) {
            warnings.push(format!("kernel curves: {w}"));
        }
        m
    } else {
        "none".to_string()
    };
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
        curve_stderr_method,
        curve_groups,
        warnings,
    })
}
