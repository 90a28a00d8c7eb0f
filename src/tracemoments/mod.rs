//! Trace moments, double trace moments and generalised structure functions
//! (SPEC §8; TM §5.2, §6.2.4-6.2.5, Figs 19-20, 25-28).
//!
//! # Which flux (TM §5.2)
//! A FIF field is its flux fractionally integrated to order H (TM
//! Table 1, eqs 9-10); to get at φ one must differentiate "of order H or
//! greater", and the estimate is the modulus of the result. Two facts fix
//! how much greater:
//! * exactly H is not enough: the integration removed the mean (k = 0), so
//!   `D^H f = φ - <φ>` and `|φ - <φ>|` is not φ (it vanishes where φ = <φ>
//!   and turns the holes of φ into values near <φ>);
//! * an excess order η > 0 turns the flux into a fluctuation field
//!   `D^η φ` whose modulus at the finest scale is φ times a random factor
//!   that the box averages wash out after a few pixels (the "range of scales,
//!   typically a factor of 2-4" of TM §5.2). Scale l contributes to
//!   `D^η φ` with weight `l^-η`, so a small η mixes in ~`1/(η ln 2)` octaves
//!   of coarser fluctuations, down to the mean-removed `φ - <φ>`: the
//!   modulus fills the low values of φ, |K(q)| comes out low, α high.
//!
//! Seed 000 (after Lavallée et al. 1993) takes the gradient modulus, a
//! differentiation of order 1, "sufficient because H ≈ 1/2 in topography":
//! an excess of about 1/2. [`FluxDiff::None`] is that estimator; its excess
//! is `1 - H`, and for H = 0.7 (0.3) it underestimates K: on 4 x 16 x 1024²
//! topo-fif ensembles α 1.98 ± 0.05 (truth 1.8), C1 0.096 (0.12).
//! [`FluxDiff::Auto`] (the default) removes the integration first with a
//! fractional derivative of order `H = ξ(1)` estimated from each image's
//! first-order structure function (no circularity: `K(1) = 0`, so `ξ(1) = H`
//! whatever K, TM eq 10), then takes the gradient modulus: the excess
//! is 1 whatever H, the same as TM's estimator applied to a conserved
//! flux (H = 0). On the same ensembles α 1.82 ± 0.05, C1 0.123. Limits:
//! first differences saturate, so ξ(1) stays in about [0, 1] and for H > 1
//! the excess falls to `2 - H` (give the order by hand then,
//! [`FluxDiff::Order`]); a per-image ξ(1) scatters by ~0.03 on 1024², which
//! moves the excess by as much (negligible next to 1).
//!
//! # Flux and coarse-graining
//! The flux `φ` at the finest resolution is `|∇f|` or the modulus of the
//! finest Haar wavelet coefficients ([`FluxKind`]) of the field after the
//! fractional differentiation of [`FluxDiff`] and an optional fractional
//! integration of order 0.1 (TM §5.2 technical note: it removes the
//! spurious zero gradients of quantised DEMs), both in one Fourier filter
//! on the mirror-extended field (on the field itself, and the gradient
//! wrapped, when it is a torus: [`TraceMomentConfig::periodic`]). It is
//! normalised
//! so that the **ensemble** mean of `φ` at the finest resolution is 1, then
//! averaged over boxes of side `l = 2^k` px; `λ = L/l` with `L` the largest
//! box (`2^floor(log2 min(ny, nx))`). Every level is averaged over the same
//! region: windows whose sides are multiples of L, anchored at the corners
//! of a non-power-of-two image (`flux::windows`; boxes tiled from one
//! corner covered less of the image the larger they were, and K(1) of a
//! conserved flux read -0.055 +- 0.026 on a 511^2 crop). Trace moments (TM eq 7):
//!
//! ```text
//! M(q, λ) = <φ_λ^q> ~ λ^K(q),     K(q) = slope of log M against log λ.
//! ```
//!
//! Masked pixels never enter a box average: a box averages its valid flux
//! pixels (a flux pixel is valid when every pixel of its stencil is; the
//! last row and column have no forward neighbour and are invalid unless the
//! field is a torus), and is weighted as the next section says. Before a fractional derivative
//! (`--diff-order`, `--frac-int`) masked pixels are filled harmonically
//! ([`Field::filled_harmonic`]): the Fourier filter has long tails, and a
//! mean fill's step along a hole's rim reached far into the valid flux (on
//! the Jacksboro DEM with a 40 x 60 lake cut out, alpha read 2.27 against
//! 1.61 for the whole DEM; 1.66 with the harmonic fill; measured with boxes
//! tiled from one corner, before the windows below: now 1.53 with the
//! harmonic fill against 1.49 whole). The spectrum (beta, hence H) fills
//! holes harmonically too ([`crate::stats::powspec::HoleFill`]; the image
//! mean before 2026-11-29, whose step along every rim added `|k|^-3`
//! power: on 6 ensembles of 16 topo-fif planes of 512² with 5 % isolated
//! pixels missing, H moved by -0.127 ± 0.021 with the mean fill and
//! +0.004 ± 0.0003 with the harmonic one; on Levi Fell with 10 % of
//! rectangles -0.37 ± 0.22 and +0.03 ± 0.03). A tilted field's plane can be removed
//! first (`--detrend plane`, [`TraceMomentConfig::detrend`]): it adds `c l`
//! to every increment at lag `l`, pulling `H_sf` (and the automatic
//! derivative order) toward 1; without it, [`diagnostics`] gives `H_sf`
//! without the planes of the images they dominate, beside the spectral H
//! (whose spectrum removes a plane of its own), when that would move
//! `H_sf` by more than its error. Ensembles are annealed: the
//! accumulator adds `Σ_boxes φ_λ^q` over images before any logarithm
//! ([`TraceMomentAccumulator::merge`]), and the normalisation by the ensemble
//! mean is exact afterwards because box averages are linear in `φ`.
//!
//! # Boxes with missing pixels
//! Along holes and the borders of a plane, boxes are partly valid. With
//! [`BoxWeights::Count`] (the default) every box with a valid pixel is kept
//! and weighted by its share of valid pixels, `<φ_λ^q> = Σ_b w_b φ_b^q /
//! Σ_b w_b` with `w_b = n_b / 4^k`: every valid pixel weighs the same at
//! every scale, so all scales average over one region (as the windows do
//! for the image's extent) and `<φ_λ> = <φ>`, K(1) = 0 to rounding, on
//! any image. [`BoxWeights::Equal`], the estimator before, kept the boxes
//! at least half valid and weighted each as a whole one: the pixels along
//! a hole weighed more at coarse scales than at fine ones, a spurious
//! change of slope. Measured on 6 ensembles of 16 topo-fif planes of 512²
//! (seeds 1-6; four masks, a new one per image: a rectangle of 10 %,
//! discs 11 %, a "coast" of 25 %, isolated pixels 5 %), the shift of the
//! holed estimate from the whole one, sd over the ensembles, count /
//! equal: GLS α 0.007 / 0.012 (rectangle), 0.003 / 0.007 (discs), 0.010 /
//! 0.025 (coast); DTM α 0.010 / 0.019, 0.003 / 0.018, 0.007 / 0.111. On
//! the Jacksboro DEM with the 25 % coast (8 masks) α moved 0.000 ± 0.019
//! against +0.054 ± 0.076, its DTM α 0.005 ± 0.007 against 0.24 ± 0.35,
//! and the tile-jackknife error of α no longer grew with the holes (1.03
//! against 3.27 times the whole DEM's). Whole images move by less than
//! their errors (the plane's last row and column; tori not at all).
//! Isolated missing pixels still raise C1 slightly (+0.0012 ± 0.0002 on
//! those planes, 0.3 errors; +0.0008 on Jacksboro; +0.0008 with
//! `--diff-order none`, no fill involved): a box short of a pixel averages
//! over less and is rougher, which weighs most at the finest levels,
//! where most boxes lose one. `experiment_hole_bias` in
//! tests/tracemoments.rs repeats the study on 16 ensembles of 8 planes of
//! 256² (sd of the α shift 0.010-0.027 count, 0.032-0.049 equal), and
//! `holes_move_the_estimates_within_their_scatter` holds a new ensemble
//! to it.
//!
//! # Errors
//! [`finish_ensemble`] replaces the regression errors by jackknife errors
//! over the images (leave one out; [`finish_jackknife`] over the tiles of a
//! single image, or of every image of an ensemble of fewer than 3,
//! [`pool_tiles`]): the errors of K(q), α, C1, DTM α, β and H then reflect the
//! sampling scatter of the ensemble, which the fit residuals do not see
//! (stated 0.003 against a scatter of 0.1 for α on 16 x 1024² topo-fif).
//! Tiles ([`tile_bounds`]) treat neighbours as independent and understate:
//! on 24 single topo-fif fields the rms jackknife error over the scatter
//! between fields was 0.56 (α), 0.38 (C1), 0.50 (DTM α), 0.36 (H) at 512²,
//! 0.87, 0.67, 0.86, 0.59 at 400², 0.62, 1.16, 0.73, 0.66 at 256²
//! (`experiment_lone_image_tiles` in tests/tracemoments.rs).
//!
//! # Diagnostics
//! Results carry `warnings` ([`diagnostics`]): a spectral H beyond what the
//! differentiation resolves, H and H_sf apart beyond their errors, moment
//! lines that bend over the fitted scales.
//!
//! # Universal fit and q_s
//! `K(q) = C1/(α-1) (q^α - q)` (`C1 q ln q` at α = 1, TM eq 8) is fitted
//! by least squares over `0 < q <= q_s/2` (weighting: next section). Rule for `q_s` (TM eq 15 and
//! its sampling interpretation): start from the fit over `0 < q <= 2` (as in
//! TM §6.2.4), then iterate (3 times)
//! `q_s = min(((D + D_s)/C1)^(1/α), q_D)` with the sampling dimension
//! `D_s = ln N_images / ln L` (the largest singularity a sample of
//! `N_images` images of `L x L` pixels can hold), `q_D` the divergence order
//! `K(q_D) = D(q_D - 1)`, and refit over `0 < q <= q_s/2`. The factor 1/2:
//! the sample moments are already biased low well before q_s (on 16
//! log-normal cascades of 256², q_s = 5, K(3.5) is 7 % and K(4) 12 % low,
//! and fitting up to q_s drags α from 2 to 1.65); TM likewise fits
//! `0 < q < 2` with `q_s ≈ 3`. The empirical onset
//! of the linear regime is reported separately (`q_s_empirical`: the first
//! `q > 1` from which on the measured `K''` stays below a quarter of the
//! fitted universal `K''`).
//!
//! # Weighting of the universal fit (GLS)
//! The K(q) of one ensemble are far from independent: they all come from
//! the same few extreme boxes, their sampling errors grow fast with q and
//! are strongly correlated between neighbouring q. Unweighted least
//! squares in K ([`UniversalWeighting::Ols`]) lets the noisiest, largest
//! K(q) near `q_s/2` decide α. With jackknife parts ([`finish_ensemble`],
//! [`finish_jackknife`]) the default ([`UniversalWeighting::Gls`]) fits by
//! generalised least squares with the jackknife covariance of K(q) across
//! the fitted q. With n parts that matrix has rank n - 1 (less than the
//! ~25 fitted q), so its correlations are shrunk toward 0 by the analytic
//! Schäfer-Strimmer intensity ([`jackknife_covariance_shrunk`]; about 0.2-0.5
//! on 16 topo-fif images) — no tuned constant. The q range and `q_s` are
//! those of the OLS iteration, less q = 1, where the universal K and its
//! derivatives vanish (its residual would enter only through the
//! covariance, a control variate on rounding or on edge drift; test
//! `gls_does_not_follow_rounding_at_q_1`). The jackknife error of the GLS α is nested
//! (weights re-estimated inside every leave-one-out sample). Measured
//! (truth α = 1.8, C1 = 0.12): on 11 ensembles of 16 x 1024² topo-fif
//! (seeds 2-12) OLS α 1.827 ± 0.081 (sd over ensembles), GLS 1.821 ±
//! 0.039, mean nested-jackknife error 0.041; on 8 ensembles of 16
//! log-normal cascades of 128² (α = 2) OLS 1.965 ± 0.103, GLS 1.992 ±
//! 0.018. [`TraceMomentAccumulator::finish`] alone has no parts and is OLS.
//!
//! # Outer scale
//! If the cascade starts at an effective outer scale `L_eff`, every moment
//! line passes through `M = 1` at `λ_eff = L/L_eff` (TM Fig 25). With the
//! fitted lines `log2 M = K(q) log2 λ + b(q)`, `log2 λ_eff = -Σ K b / Σ K²` over
//! the fitted q (least-squares common zero).
//!
//! # Double trace moments
//! `φ^(η) = φ^η / <φ^η>` at the finest resolution, then coarse-grained:
//! `<(φ^(η)_λ)^q> ~ λ^K(q,η)`, `K(q, η) = η^α K(q)` for universal
//! multifractals, so `log|K(q, η)| = α log η + log|K(q)|`: α is the slope
//! over a middle range of η (default 0.3..2, and `qη <= q_s/2`, the universal fit's bound), and
//! `C1 = e^intercept / |(q^α - q)/(α - 1)|`.
//!
//! # Structure functions and spectrum
//! `<|Δf(l)|^q> ~ l^ξ(q)` over horizontal and vertical increments at lags
//! `l = 2^j` (pairs with a masked end are skipped), `ξ(q) = qH - K(q)`, so
//! `H = ξ(1)` (TM eq 10). The spectral route (TM eq 11 and §6.1.2):
//! the angle-averaged spectrum of [`crate::stats::powspec`] gives
//! `β_avg`; the angle-integrated `β = β_avg - 1 = 1 + 2H - K(2)` gives
//! `H = (β - 1 + K(2))/2` with `K(2)` from the universal fit.
//!
//! # Example
//!
//! ```
//! use wtmm::Field;
//! use wtmm::synth::fif::{FifParams, fif};
//! use wtmm::tracemoments::{TraceMomentConfig, TraceMomentFitConfig, analyze_tiled};
//! # fn main() -> wtmm::Result<()> {
//! // a universal multifractal with the topography's parameters
//! // (alpha 1.8, C1 0.12, H 0.7; TM Table 3)
//! let p = FifParams::TOPO;
//! let dem = Field::new(fif(&p, 256, 256, 1, 0)?);
//! // as `wtmm tm` on one image: the errors from a jackknife over its tiles
//! let (_, r) = analyze_tiled(
//!     &[dem],
//!     &TraceMomentConfig::default(),
//!     &TraceMomentFitConfig::for_tiles(),
//! )?;
//! assert!(r.alpha.is_finite() && r.alpha_stderr > 0.0);
//! assert!(r.c1 > 0.0 && r.c1_stderr > 0.0);
//! // an ensemble: TraceMomentAccumulator::add_field per image, then
//! // finish_ensemble over the images
//! # Ok(())
//! # }
//! ```

mod accumulate;
mod diagnostics;
mod finish;
mod fit;
mod flux;
mod surrogate;
#[cfg(test)]
mod tests;

pub use accumulate::*;
pub use diagnostics::*;
pub use finish::*;
pub use fit::{
    LogSum, ShrunkCovariance, UniversalFit, UniversalWeighting, fit_universal, fit_universal_gls,
    jackknife_covariance_shrunk, power_sums, power_sums_of_values, spd_inverse, universal_shape,
    weighted_power_sums, weighted_power_sums_of_values,
};
pub use flux::{BoxWeights, FluxDiff, FluxKind};
pub use surrogate::{
    MIN_SURROGATES, SurrogateErrors, SurrogateRun, SurrogateStat, WEAK_C1, analyze_fields,
    check_surrogate_count, surrogate_errors, surrogate_errors_with_progress, surrogate_fif_seed,
    surrogate_params,
};

use ndarray::{Array2, ArrayView2};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use statrs::distribution::ContinuousCDF;

use crate::error::{Error, Result};
use crate::field::{Field, Trend};
use crate::stats::fit::{line_fit, mean_std};
use crate::stats::powspec::{
    HoleFill, PowerSpectrum, PowerSpectrumConfig, Window, bins_in_range, default_k_range,
    field_power_spectrum, power_spectrum,
};
use crate::theory::fif::UniversalK;

/// Dimension of space.
const D: f64 = 2.0;

/// The universal fit starts over `0 < q <= 2` (TM §6.2.4; module
/// docs), before q_s is known: it needs 3 orders there.
pub const FIRST_UNIVERSAL_Q_MAX: f64 = 2.0;

/// What to accumulate (fixed for an ensemble; accumulators merge only when
/// their configurations are equal).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TraceMomentConfig {
    /// How the flux φ is taken from the field (default: gradient modulus).
    pub flux: FluxKind,
    /// Fractional differentiation of the field before the modulus (module
    /// docs, "Which flux"). [`Default`] is `Auto`; a stored config without
    /// this key was written before it existed, with the plain gradient,
    /// hence the serde default `None`.
    #[serde(default = "FluxDiff::none")]
    pub diff: FluxDiff,
    /// Order of the fractional integration applied before the flux (e.g.
    /// `Some(0.1)` for quantised DEMs); mirror-extended to avoid a border jump.
    pub frac_int: Option<f64>,
    /// Trace-moment orders (`q >= 0`).
    pub q: Vec<f64>,
    /// Double-trace-moment powers η (`> 0`).
    pub eta: Vec<f64>,
    /// Orders q of the double trace moments.
    pub dtm_q: Vec<f64>,
    /// Structure-function orders (`> 0`).
    pub sf_q: Vec<f64>,
    /// Spectrum options (the field's spectrum, for H via β). The default
    /// tapers and removes a plane, as a DEM needs; for periodic fields
    /// (the generators' W-cascades, FISC, FIF) use
    /// `PowerSpectrumConfig::for_field(true)`, as the CLI does (`compare`,
    /// and `tm` on periodic `synth` files): a torus needs no taper, and a
    /// plane removed from it without one is a sawtooth across its edges
    /// (`wtmm spectrum`, 8 paper-fisc fields of 512^2, seed 1, theory
    /// 3.100: beta 3.081 with `for_field(true)`, 3.072 with the default,
    /// 3.009 with the plane removed and no taper).
    pub spectrum: PowerSpectrumConfig,
    /// Trend removed from each field before everything else (flux,
    /// structure functions, spectrum). A plane of slope `c` adds `c·l` to
    /// every increment at lag `l`: the structure functions, hence `H_sf`
    /// and the automatic derivative order, drift toward 1 (4 fBm of 512^2,
    /// H = 0.4, tilted by 5 standard deviations: `H_sf` 0.48 for 0.44
    /// untilted); the spectrum removes a plane of its own by default.
    /// Default none (TM's method); stored configs without the key had none.
    #[serde(default)]
    pub detrend: Trend,
    /// The fields are tori (the generators' W-cascades, FISC, FIF; the CLI
    /// sets it for `compare` and for `tm` on periodic `synth` files): the
    /// fractional filter before the flux (`diff`, `frac_int`) acts on the
    /// field as it is, not on its mirror extension, and the last row and
    /// column take the first as their forward neighbour, so every box is
    /// whole and the flux's mean is the same at every scale; missing
    /// pixels are filled across the borders before the filter
    /// ([`Field::filled_harmonic_torus`]; before 2026-11-29 the fill
    /// stopped at them). The mirror,
    /// which a non-periodic field needs against its border jump, fills a
    /// small-alpha flux's holes far from the border (8 FIF fields of 512^2,
    /// alpha 0.5, C1 0.1, order 0.5: C1 read 0.069 mirrored, 0.081
    /// periodic). Default false; stored configs without the key were
    /// mirrored, without the wrap.
    #[serde(default)]
    pub periodic: bool,
    /// How the boxes of one scale are weighted in the trace moments
    /// (module docs, "Boxes with missing pixels"). Stored configs without
    /// the key weighted them equally.
    #[serde(default = "BoxWeights::equal")]
    pub box_weights: BoxWeights,
}

impl Default for TraceMomentConfig {
    fn default() -> Self {
        TraceMomentConfig {
            flux: FluxKind::Gradient,
            diff: FluxDiff::Auto,
            frac_int: None,
            q: (1..=40).map(|i| i as f64 / 10.0).collect(),
            // 16 log-spaced values from 0.1 to 10^0.5
            eta: (0..16)
                .map(|i| 10f64.powf(-1.0 + 1.5 * i as f64 / 15.0))
                .collect(),
            dtm_q: vec![1.5],
            sf_q: vec![0.5, 1.0, 1.5, 2.0, 2.5, 3.0],
            spectrum: PowerSpectrumConfig::default(),
            detrend: Trend::None,
            periodic: false,
            box_weights: BoxWeights::Count,
        }
    }
}

impl TraceMomentConfig {
    /// Equality up to a relative 1e-12 on the grids (a JSON round trip may
    /// move a float by one ulp).
    pub fn same_settings(&self, o: &TraceMomentConfig) -> bool {
        self.differences(o).is_empty()
    }

    /// The settings in which `self` and `o` differ, each as `name: self's
    /// vs o's` (empty when [`Self::same_settings`]), for the message that
    /// refuses a merge.
    pub fn differences(&self, o: &TraceMomentConfig) -> Vec<String> {
        let close = |a: &[f64], b: &[f64]| {
            a.len() == b.len()
                && a.iter()
                    .zip(b)
                    .all(|(x, y)| (x - y).abs() <= 1e-12 * x.abs().max(y.abs()))
        };
        let mut d = Vec::new();
        let mut say = |same: bool, name: &str, a: String, b: String| {
            if !same {
                d.push(format!("{name}: {a} vs {b}"));
            }
        };
        say(
            self.flux == o.flux,
            "flux",
            self.flux.name().into(),
            o.flux.name().into(),
        );
        say(
            match (self.diff, o.diff) {
                (FluxDiff::Order(a), FluxDiff::Order(b)) => close(&[a], &[b]),
                (a, b) => a == b,
            },
            "diff",
            format!("{:?}", self.diff),
            format!("{:?}", o.diff),
        );
        say(
            match (self.frac_int, o.frac_int) {
                (Some(a), Some(b)) => close(&[a], &[b]),
                (a, b) => a == b,
            },
            "frac_int",
            format!("{:?}", self.frac_int),
            format!("{:?}", o.frac_int),
        );
        for (name, a, b) in [
            ("q", &self.q, &o.q),
            ("eta", &self.eta, &o.eta),
            ("dtm_q", &self.dtm_q, &o.dtm_q),
            ("sf_q", &self.sf_q, &o.sf_q),
        ] {
            let list = |v: &[f64]| match v {
                [] => "[]".to_string(),
                [x] => format!("[{x}]"),
                [x, .., y] => format!("{} values {x}..{y}", v.len()),
            };
            say(close(a, b), name, list(a), list(b));
        }
        say(
            self.spectrum == o.spectrum,
            "spectrum",
            format!("{:?}", self.spectrum),
            format!("{:?}", o.spectrum),
        );
        say(
            self.detrend == o.detrend,
            "detrend",
            format!("{:?}", self.detrend),
            format!("{:?}", o.detrend),
        );
        say(
            self.periodic == o.periodic,
            "periodic",
            self.periodic.to_string(),
            o.periodic.to_string(),
        );
        say(
            self.box_weights == o.box_weights,
            "box_weights",
            self.box_weights.name().into(),
            o.box_weights.name().into(),
        );
        d
    }

    /// **Errors** on negative, non-finite, unsorted or repeated q, non-positive η or
    /// structure-function orders, a non-finite fractional-integration order,
    /// or a plane removed from a periodic field.
    pub fn validate(&self) -> Result<()> {
        if self.q.is_empty()
            || self.q.iter().any(|q| !(q.is_finite() && *q >= 0.0))
            || self.q.windows(2).any(|w| w[0] >= w[1])
        {
            return Err(Error::param(
                "q",
                "trace-moment orders must be finite and >= 0, in ascending order, none twice",
            ));
        }
        if self.eta.iter().any(|e| !(e.is_finite() && *e > 0.0))
            || self.eta.windows(2).any(|w| w[0] >= w[1])
        {
            return Err(Error::param(
                "eta",
                "η values must be finite and > 0, in ascending order, none twice",
            ));
        }
        if self.dtm_q.iter().any(|q| !(q.is_finite() && *q > 0.0)) {
            return Err(Error::param(
                "dtm-q",
                "double-trace-moment orders must be > 0",
            ));
        }
        if self.dtm_q.contains(&1.0) {
            // conservation: K(1, η) = η^α K(1) = 0 for every η, nothing to fit
            return Err(Error::param(
                "dtm-q",
                "q = 1 has K(1, η) = 0 for every η (the flux is conserved): give q != 1",
            ));
        }
        if self.sf_q.iter().any(|q| !(q.is_finite() && *q > 0.0)) {
            return Err(Error::param(
                "sf-q",
                "structure-function orders must be > 0",
            ));
        }
        if self.periodic && self.detrend == Trend::Plane {
            return Err(Error::param(
                "detrend",
                "a plane removed from a torus (periodic) leaves a sawtooth across its edges: \
                 detrend a torus by its mean only",
            ));
        }
        if let Some(h) = self.frac_int
            && !(h.is_finite() && h > -1.0 && h < 1.0)
        {
            return Err(Error::param(
                "frac-int",
                format!(
                    "a small smoothing order is expected (|order| < 1, e.g. 0.1), got {h_s}",
                    h_s = crate::error::short(h)
                ),
            ));
        }
        if let FluxDiff::Order(d) = self.diff
            && !(d.is_finite() && d.abs() < 3.0)
        {
            return Err(Error::param(
                "diff-order",
                format!(
                    "must be finite with |order| < 3, got {d_s}",
                    d_s = crate::error::short(d)
                ),
            ));
        }
        Ok(())
    }
}

/// Fit ranges used by [`TraceMomentAccumulator::finish`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TraceMomentFitConfig {
    /// Range of `log2 λ` for K(q) and K(q, η). Default: drop the coarsest
    /// octave (a handful of boxes, and the outer cut-off) and the finest one
    /// (the modulus of a difference breaks the scaling over the first factor
    /// of 2, TM §5.2): `[1, log2 L - 1]`.
    pub log2_lambda: Option<(f64, f64)>,
    /// η range of the DTM fit.
    pub eta: (f64, f64),
    /// Range of `log2 l` (lag in px) for ξ(q). Default `[1, log2 L - 3]`
    /// (lags 2 px to L/8).
    pub log2_lag: Option<(f64, f64)>,
    /// Spectrum fit range (rad/px). Default [`default_k_range`].
    pub k_range: Option<(f64, f64)>,
    /// Upper bound on the q of the universal fit (on top of `q < q_s`).
    pub q_fit_max: Option<f64>,
    /// Weighting of the universal fit (GLS needs jackknife parts:
    /// [`finish_jackknife`]; [`TraceMomentAccumulator::finish`] alone is OLS).
    #[serde(default)]
    pub universal: UniversalWeighting,
}

impl Default for TraceMomentFitConfig {
    fn default() -> Self {
        TraceMomentFitConfig {
            log2_lambda: None,
            eta: (0.3, 2.0),
            log2_lag: None,
            k_range: None,
            q_fit_max: None,
            universal: UniversalWeighting::default(),
        }
    }
}

impl TraceMomentFitConfig {
    /// The settings `wtmm tm` fits one or two images (a DEM) with, through
    /// [`analyze_tiled`]: the defaults with the OLS universal fit, since
    /// tiles are not independent samples for the GLS covariance (README,
    /// "Trace moments: fitting alpha (GLS)"). [`Default`] (GLS) is what an
    /// ensemble of 3 or more images gets.
    pub fn for_tiles() -> Self {
        TraceMomentFitConfig {
            universal: UniversalWeighting::Ols,
            ..Default::default()
        }
    }

    /// The `log2 λ` fit range on box levels `0..=kmax` (`kmax = floor(log2
    /// min(ny, nx))` of the largest field): the one set, or the default
    /// `[1, kmax - 1]` (`[0, kmax]` below 16 px). Known from the image sizes
    /// alone, so callers check it before any moment is accumulated.
    ///
    /// **Errors** (named `lambda-fit`, the CLI flag; `log2_lambda` here)
    /// on a range beyond `[0, kmax]` or holding fewer than 3 levels.
    pub fn lambda_range(&self, kmax: usize) -> Result<(f64, f64)> {
        let top = kmax as f64;
        let (lo, hi) = self.log2_lambda.unwrap_or(if top >= 4.0 {
            (1.0, top - 1.0)
        } else {
            (0.0, top)
        });
        if lo < -1e-9 || hi > top + 1e-9 {
            // a range beyond the data would be recorded as if it were fitted
            return Err(Error::param(
                "lambda-fit",
                format!("[{lo}, {hi}] goes beyond the scales: log2 λ runs from 0 to {top}"),
            ));
        }
        // levels are the integers 0..=kmax
        let levels = (0..=kmax)
            .filter(|&k| (k as f64) >= lo - 1e-9 && (k as f64) <= hi + 1e-9)
            .count();
        if levels < 3 {
            return Err(Error::param(
                "lambda-fit",
                format!("fewer than 3 scales in log2 λ = [{lo}, {hi}] (log2 λ up to {top})"),
            ));
        }
        Ok((lo, hi))
    }

    /// The `log2` lag range of the structure functions on images whose
    /// coarsest box level is `kmax` and which hold `nj` lags (`1, 2, ..,
    /// 2^(nj-1)` px; [`sf_lags`]): the given range or `[1, max(kmax - 3,
    /// 2)]` (lags of 2 px to L/8).
    ///
    /// **Errors** on a given range beyond the lags, or holding fewer than 2.
    pub fn lag_range(&self, kmax: usize, nj: usize) -> Result<(f64, f64)> {
        let (llo, lhi) = self.log2_lag.unwrap_or((1.0, (kmax as f64 - 3.0).max(2.0)));
        if self.log2_lag.is_some() && (llo < -1e-9 || lhi > (nj as f64 - 1.0) + 1e-9) {
            return Err(Error::param(
                "lag-fit",
                format!(
                    "[{llo}, {lhi}] goes beyond the lags: log2 of the lag runs from 0 to {}",
                    nj as f64 - 1.0
                ),
            ));
        }
        // lags are the integers 0..nj in log2: a line needs 2 of them (the
        // default range holds 2 or more whenever the image has lags of 4 px)
        let lags = (0..nj)
            .filter(|&j| (j as f64) >= llo - 1e-9 && (j as f64) <= lhi + 1e-9)
            .count();
        if self.log2_lag.is_some() && lags < 2 {
            return Err(Error::param(
                "lag-fit",
                format!(
                    "[{llo}, {lhi}] holds {lags} lag(s) (log2 of the lag is a whole number, \
                     0 to {}): the structure functions' line needs 2 or more",
                    nj as f64 - 1.0
                ),
            ));
        }
        Ok((llo, lhi))
    }

    /// **Errors** naming the setting: every range `LO < HI` and finite,
    /// η and wavenumbers > 0 (wavenumbers up to π rad/px, the Nyquist
    /// wavenumber), `q_fit_max` finite and > 0.
    pub fn validate(&self) -> Result<()> {
        let range = |name: &str, r: (f64, f64)| {
            if r.0.is_finite() && r.1.is_finite() && r.0 < r.1 {
                Ok(())
            } else {
                Err(Error::param(
                    name,
                    format!("{}:{} must be finite with LO < HI", r.0, r.1),
                ))
            }
        };
        range("eta-fit", self.eta)?;
        if self.eta.0 <= 0.0 {
            return Err(Error::param("eta-fit", "η must be > 0"));
        }
        for (name, r) in [("lambda-fit", self.log2_lambda), ("lag-fit", self.log2_lag)] {
            if let Some(r) = r {
                range(name, r)?;
            }
        }
        if let Some(k) = self.k_range {
            range("k-range", k)?;
            if k.0 <= 0.0 || k.1 > std::f64::consts::PI {
                return Err(Error::param(
                    "k-range",
                    "need 0 < LO < HI <= pi rad/px (the Nyquist wavenumber)",
                ));
            }
        }
        if let Some(q) = self.q_fit_max
            && !(q.is_finite() && q > 0.0)
        {
            return Err(Error::param(
                "q-fit-max",
                format!(
                    "must be a finite number > 0, got {q_s}",
                    q_s = crate::error::short(q)
                ),
            ));
        }
        Ok(())
    }
}

/// Mergeable per-image sums (annealed ensemble averages).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TraceMomentAccumulator {
    /// What is accumulated (equal configurations only merge).
    pub config: TraceMomentConfig,
    /// Number of fields (or fluxes, or tiles of [`Self::field_tiles`])
    /// accumulated.
    pub images: usize,
    /// Largest `min(ny, nx)` seen.
    pub max_side: usize,
    /// Valid flux pixels at the finest resolution.
    pub n_valid: u64,
    /// `Σ φ` over them.
    pub phi_sum: LogSum,
    /// `Σ φ^η` over them, per η.
    pub eta_sum: Vec<LogSum>,
    /// The weight of the boxes kept per level (box side `2^k`): their
    /// number, or with [`BoxWeights::Count`] their valid pixels (the
    /// weights' sum times `4^k`).
    pub box_count: Vec<u64>,
    /// `Σ_boxes φ_box^q`, `[iq][k]`.
    pub tm: Vec<Vec<LogSum>>,
    /// `Σ_boxes (mean_box φ^η)^q`, `[ieta][idq][k]`.
    pub dtm: Vec<Vec<Vec<LogSum>>>,
    /// Increment pairs per lag `2^j`.
    pub sf_count: Vec<u64>,
    /// `Σ |Δf|^q`, `[iq][j]`.
    pub sf: Vec<Vec<LogSum>>,
    /// Merged power spectrum of the fields (none for fluxes given directly).
    pub spectrum: Option<PowerSpectrum>,
    /// Per field, in merge order: the fractional differentiation order
    /// applied before the modulus (the per-image `ξ(1)` with
    /// [`FluxDiff::Auto`]).
    #[serde(default)]
    pub diff_orders: Vec<f64>,
    /// Per field, in merge order: its least-squares plane (default for
    /// fluxes given directly). Empty in accumulators saved before it was
    /// recorded (merging pads them with defaults, one per field).
    #[serde(default)]
    pub planes: Vec<FieldPlane>,
}

/// One double-trace-moment fit at fixed q.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct DtmFit {
    /// The moment order q.
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub q: f64,
    /// α: slope of `ln |K(q, η)|` against `ln η` over the η range (NaN if no fit).
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub alpha: f64,
    /// Its standard error: regression, or jackknife over the parts
    /// ([`finish_ensemble`]).
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub alpha_stderr: f64,
    /// `C1 = e^intercept / |(q^α - q)/(α - 1)|` (JSON `C1`).
    #[serde(rename = "C1", deserialize_with = "crate::nan_null::f64")]
    pub c1: f64,
    /// Number of η values in the fit.
    pub n: usize,
    /// Smallest and largest η the fit used (the η range cut further by
    /// `qη <= q_s/2`; NaN if no fit).
    #[serde(deserialize_with = "crate::nan_null::pair")]
    pub eta_used: (f64, f64),
}

/// Everything [`TraceMomentAccumulator::finish`] computes (the `tm.json`
/// contract of SPEC §13 plus the tables for plots). `log2` everywhere for
/// scales and moments (exponents are base-independent).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TraceMomentResult {
    /// Number of fields in the ensemble.
    pub images: usize,
    /// How the flux was taken from the field.
    pub flux: FluxKind,
    /// The differentiation setting before the modulus.
    pub diff: FluxDiff,
    /// Mean over images of the differentiation order applied (with
    /// [`FluxDiff::Auto`], the mean per-image `ξ(1)`).
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub diff_order: f64,
    /// Its standard deviation over images.
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub diff_order_sd: f64,
    /// Trend removed from each field first ([`TraceMomentConfig::detrend`]).
    #[serde(default)]
    pub detrend: Trend,
    /// Median over the fields of the share of their variance their
    /// least-squares plane explains (before any detrending); `None` when
    /// no field records one (fluxes given directly, older accumulators).
    #[serde(default)]
    pub plane_share: Option<f64>,
    /// Without detrending, the shift of `ξ(1)` (raw less without the
    /// plane, [`FieldPlane::h_sf`]) of the fields whose plane explains more
    /// than half their variance, averaged over all fields with a share (0
    /// for the others): about how much `H_sf` would drop with `--detrend
    /// plane`. `None` when no field records it.
    #[serde(default)]
    pub h_sf_plane_shift: Option<f64>,
    /// How many fields record that shift (their plane explains more than
    /// half their variance, without detrending).
    #[serde(default)]
    pub planes_over_half: usize,
    /// Order of the fractional integration applied before the flux, if any.
    pub frac_int: Option<f64>,
    /// Trace-moment orders q.
    #[serde(deserialize_with = "crate::nan_null::vec")]
    pub q: Vec<f64>,
    /// `K(q)`: slope of `log2 <φ_λ^q>` against `log2 λ` over
    /// `fit_log2_lambda` (TM eq 7; JSON `K`; NaN if no fit).
    #[serde(rename = "K", deserialize_with = "crate::nan_null::vec")]
    pub k: Vec<f64>,
    /// Standard error of K(q): regression, or jackknife over the parts
    /// ([`finish_ensemble`]; JSON `K_stderr`).
    #[serde(rename = "K_stderr", deserialize_with = "crate::nan_null::vec")]
    pub k_stderr: Vec<f64>,
    /// Intercepts `b(q)` of the fitted lines `log2 M = K log2 λ + b`.
    #[serde(rename = "K_intercept", deserialize_with = "crate::nan_null::vec")]
    pub k_intercept: Vec<f64>,
    /// `log2 λ` per level (λ = L/l; finest boxes first, so descending
    /// from `log2 L` to 0).
    #[serde(deserialize_with = "crate::nan_null::vec")]
    pub log2_lambda: Vec<f64>,
    /// `log2 <φ_λ^q>` per q per level.
    #[serde(deserialize_with = "crate::nan_null::vec2")]
    pub log2_moments: Vec<Vec<f64>>,
    /// Range of `log2 λ` over which K(q) and K(q, η) were fitted.
    #[serde(deserialize_with = "crate::nan_null::pair")]
    pub fit_log2_lambda: (f64, f64),
    /// α of the universal fit `K(q) = C1/(α-1) (q^α - q)` over
    /// `0 < q <= universal_q_max` (SPEC §8; NaN if no fit).
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub alpha: f64,
    /// Standard error of α: jackknife over the parts, the images of an
    /// ensemble of 2 or more ([`finish_ensemble`]) or the tiles of one or
    /// two images ([`analyze_tiled`]), else the regression error
    /// (`stderr_method` says which).
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub alpha_stderr: f64,
    /// The Gauss-Newton error of the universal fit alone (residuals of K(q)
    /// about the universal curve; blind to the sampling scatter of K). After
    /// a GLS refit it is the GLS fit's `(J' w J)⁻¹` error instead.
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub alpha_stderr_fit: f64,
    /// C1 of the universal fit (JSON `C1`).
    #[serde(rename = "C1", deserialize_with = "crate::nan_null::f64")]
    pub c1: f64,
    /// Standard error of C1, as `alpha_stderr` (JSON `C1_stderr`).
    #[serde(rename = "C1_stderr", deserialize_with = "crate::nan_null::f64")]
    pub c1_stderr: f64,
    /// The universal fit's own error of C1, as `alpha_stderr_fit` (JSON
    /// `C1_stderr_fit`).
    #[serde(rename = "C1_stderr_fit", deserialize_with = "crate::nan_null::f64")]
    pub c1_stderr_fit: f64,
    /// How `*_stderr` were obtained.
    pub stderr_method: String,
    /// How α and C1 were fitted: `ols`, or `gls` with the jackknife
    /// covariance of K(q) and its shrinkage intensity.
    #[serde(default)]
    pub universal_fit: String,
    /// The Schäfer-Strimmer shrinkage λ of the GLS covariance (None: OLS).
    #[serde(default)]
    pub universal_shrinkage: Option<f64>,
    /// The unweighted (OLS) universal fit over the same q, for comparison.
    #[serde(default, deserialize_with = "crate::nan_null::f64")]
    pub alpha_ols: f64,
    /// C1 of that OLS fit (JSON `C1_ols`).
    #[serde(default, rename = "C1_ols", deserialize_with = "crate::nan_null::f64")]
    pub c1_ols: f64,
    /// Number of jackknife groups (0: none).
    pub jackknife_groups: usize,
    /// Number of q values in the universal fit.
    pub universal_n: usize,
    /// Largest q of the universal fit (`q_s/2`, or `q_fit_max`).
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub universal_q_max: f64,
    /// Sampling phase-transition order `q_s = min(((2 + D_s)/C1)^(1/α), q_D)`,
    /// `D_s = ln N_images / ln L` (TM eq 15; module doc; `+∞`, JSON `null`,
    /// if the universal fit failed).
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub q_s: f64,
    /// The rule used for `q_s`, in words.
    pub q_s_rule: String,
    /// Onset of the linear regime of the measured K(q), if seen.
    pub q_s_empirical: Option<f64>,
    /// Divergence order of the fitted universal K: `K(q_D) = 2(q_D - 1)`.
    #[serde(rename = "q_D", deserialize_with = "crate::nan_null::f64")]
    pub q_d: f64,
    /// Where the moment lines meet (`log2 λ_eff`); the effective outer scale
    /// is `L / λ_eff` px (`λ_eff < 1`: larger than the image).
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub log2_lambda_eff: f64,
    /// `λ_eff = 2^log2_lambda_eff`.
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub lambda_eff: f64,
    /// Effective outer scale `L / λ_eff`, in pixels.
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub outer_scale_px: f64,
    /// Double-trace-moment powers η.
    #[serde(deserialize_with = "crate::nan_null::vec")]
    pub eta: Vec<f64>,
    /// Orders q of the double trace moments.
    #[serde(deserialize_with = "crate::nan_null::vec")]
    pub dtm_q: Vec<f64>,
    /// `K(q, η)` per DTM q per η.
    #[serde(rename = "K_eta", deserialize_with = "crate::nan_null::vec2")]
    pub k_eta: Vec<Vec<f64>>,
    /// Regression standard errors of `K(q, η)` (JSON `K_eta_stderr`).
    #[serde(rename = "K_eta_stderr", deserialize_with = "crate::nan_null::vec2")]
    pub k_eta_stderr: Vec<Vec<f64>>,
    /// `log2 <(φ^(η))_λ^q>` per DTM q, per η, per level.
    #[serde(deserialize_with = "crate::nan_null::vec3")]
    pub log2_moments_eta: Vec<Vec<Vec<f64>>>,
    /// η range of the DTM fits (further limited to `η <= q_s/2`, `qη <= q_s/2`).
    #[serde(deserialize_with = "crate::nan_null::pair")]
    pub dtm_eta_range: (f64, f64),
    /// α from the DTM at the first DTM q.
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub dtm_alpha: f64,
    /// Standard error of `dtm_alpha`, as [`DtmFit::alpha_stderr`].
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub dtm_alpha_stderr: f64,
    /// C1 from the DTM at the first DTM q (JSON `dtm_C1`).
    #[serde(rename = "dtm_C1", deserialize_with = "crate::nan_null::f64")]
    pub dtm_c1: f64,
    /// Jackknife standard error of `dtm_c1` (null without a jackknife; JSON
    /// `dtm_C1_stderr`).
    #[serde(
        rename = "dtm_C1_stderr",
        default = "nan_default",
        deserialize_with = "crate::nan_null::f64"
    )]
    pub dtm_c1_stderr: f64,
    /// Per DTM q.
    pub dtm: Vec<DtmFit>,
    /// Structure-function orders q.
    #[serde(deserialize_with = "crate::nan_null::vec")]
    pub sf_q: Vec<f64>,
    /// Structure-function exponents `ξ(q) = qH - K(q)`.
    #[serde(deserialize_with = "crate::nan_null::vec")]
    pub xi: Vec<f64>,
    /// Standard errors of ξ(q): jackknife over the images or tiles where
    /// [`Self::stderr_method`] says so ([`finish_jackknife`]), else the
    /// regression's.
    #[serde(deserialize_with = "crate::nan_null::vec")]
    pub xi_stderr: Vec<f64>,
    /// Intercepts of the ξ(q) fits (`log2 <|Δf(l)|^q> = ξ log2 l + b`),
    /// for drawing them.
    #[serde(default, deserialize_with = "crate::nan_null::vec")]
    pub xi_intercept: Vec<f64>,
    /// `log2 l` of the lags `l = 2^j` px, `j = 0, 1, ...`.
    #[serde(deserialize_with = "crate::nan_null::vec")]
    pub log2_lag: Vec<f64>,
    /// `log2 <|Δf(l)|^q>` per q per lag.
    #[serde(deserialize_with = "crate::nan_null::vec2")]
    pub log2_sf: Vec<Vec<f64>>,
    /// Range of `log2 l` over which ξ(q) was fitted.
    #[serde(deserialize_with = "crate::nan_null::pair")]
    pub fit_log2_lag: (f64, f64),
    /// H from the spectrum: `(β - 1 + K(2))/2` (TM §6.1.2).
    #[serde(rename = "H")]
    pub h: Option<f64>,
    /// Jackknife standard error of H, over the images or the tiles
    /// (`stderr_method`); `None` without a jackknife ([`analyze`]).
    #[serde(rename = "H_stderr")]
    pub h_stderr: Option<f64>,
    /// H from the structure functions, `ξ(1)`.
    #[serde(rename = "H_sf")]
    pub h_sf: Option<f64>,
    /// Jackknife standard error of `H_sf` (ensembles only; JSON `H_sf_stderr`).
    #[serde(rename = "H_sf_stderr")]
    pub h_sf_stderr: Option<f64>,
    /// Angle-integrated spectral exponent (TM eq 11).
    pub beta: Option<f64>,
    /// Angle-averaged exponent, `beta + 1`.
    pub beta_averaged: Option<f64>,
    /// Standard error of β: the spectrum fit's regression error, or the
    /// jackknife over images ([`finish_ensemble`]).
    pub beta_stderr: Option<f64>,
    /// Which error `beta_stderr` is: the regression's (one part, or parts
    /// that share one spectrum, the tiles of one image) or the jackknife's.
    #[serde(default)]
    pub beta_stderr_method: String,
    /// Says that `beta` is angle-integrated (`beta_averaged = beta + 1`).
    pub beta_convention: String,
    /// Spectrum fit range (rad/px).
    pub k_range: Option<(f64, f64)>,
    /// Diagnostics in words ([`diagnostics`]): a differentiation too low
    /// for the spectral H, H and H_sf apart beyond their errors, moments
    /// that are no power law over the fit range.
    #[serde(default)]
    pub warnings: Vec<String>,
    /// Errors from surrogates ([`surrogate_errors`]), when asked for.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub surrogates: Option<SurrogateErrors>,
}

/// Missing numbers in files of older versions read as NaN (written null).
fn nan_default() -> f64 {
    f64::NAN
}

/// The jackknife tiles of an `ny x nx` image, as `(y0, y1, x0, x1)` (rows
/// `[y0, y1)`, columns `[x0, x1)`, row-major): as many whole tiles of
/// `tile` px as fit along each side, stretched to cover the image
/// ([`crate::spectra::TileGrid`], as the WTMM spectra's tiles); one tile,
/// the image, when fewer than 2 fit. Why stretched: the delete-one
/// jackknife weighs its groups equally, so they must hold equal shares of
/// the data: tiles stepped by `tile` from a corner left slivers (16 px of a
/// 400 px side) that counted as full groups and inflated the errors
/// (levi_fell 400²: DTM α ± 0.52 over 16 tiles, ± 0.06 over the 9 whole
/// tiles of a 384² crop). Dropping the leftover strip would instead either
/// take its data out of the estimate or keep data in the estimate that no
/// group varies; stretched tiles differ by at most 1 px a side, and every
/// pixel counts in the estimate and in exactly one group.
pub fn tile_bounds(ny: usize, nx: usize, tile: usize) -> Vec<(usize, usize, usize, usize)> {
    match crate::spectra::TileGrid::new((0, ny, 0, nx), tile) {
        Some(g) => (0..g.len()).map(|k| g.bounds(k)).collect(),
        None => vec![(0, ny, 0, nx)],
    }
}

/// The tiles of several images ([`TraceMomentAccumulator::field_tiles`] of
/// each, `(whole, tiles)`) as the jackknife groups of one ensemble (fewer
/// than 3 images: a jackknife over the images would have 1 degree of
/// freedom at most): the merged wholes, and all the tiles, each carrying
/// the merged spectrum, so that β keeps its fit error as for one image
/// (a tile's own image's spectrum would make a leave-one-tile-out β differ
/// only by the weight of that image: a meaningless scatter).
///
/// **Errors** with no image or images accumulated with other settings.
pub fn pool_tiles(
    per_image: Vec<(TraceMomentAccumulator, Vec<TraceMomentAccumulator>)>,
) -> Result<(TraceMomentAccumulator, Vec<TraceMomentAccumulator>)> {
    let Some(first) = per_image.first() else {
        return Err(Error::Input("no image accumulated".into()));
    };
    let mut whole = TraceMomentAccumulator::new(first.0.config.clone())?;
    for (w, _) in &per_image {
        whole.merge(w)?;
    }
    let mut tiles = Vec::new();
    for (_, t) in per_image {
        for mut p in t {
            p.spectrum.clone_from(&whole.spectrum);
            tiles.push(p);
        }
    }
    Ok((whole, tiles))
}

/// The side of the jackknife tiles of fields whose smaller sides are at
/// most `min_side` px: the largest fitted box, `2^(floor(log2 min_side) -
/// floor(lo))` with `lo` the start of the `log2 λ` fit range (`fc`, or its
/// default 1; 0 below 16 px), as `wtmm tm` uses for fewer than 3 images.
pub fn tile_side(min_side: usize, fc: &TraceMomentFitConfig) -> usize {
    let kmax = (min_side.max(1) as f64).log2().floor();
    let lo = fc
        .log2_lambda
        .map_or(if kmax >= 4.0 { 1.0 } else { 0.0 }, |r| r.0);
    (kmax - lo.max(0.0).floor()).max(0.0).exp2() as usize
}

/// The `stderr_method` name of tiles with these bounds ([`tile_bounds`])
/// of nominal side `tile`: "tiles of 133-134 px (whole 128-px tiles
/// stretched to cover every pixel)".
pub fn tiles_label(bounds: &[(usize, usize, usize, usize)], tile: usize) -> String {
    let span = |v: Vec<usize>| {
        let (lo, hi) = (v.iter().min().copied(), v.iter().max().copied());
        match (lo, hi) {
            (Some(lo), Some(hi)) if lo < hi => format!("{lo}-{hi}"),
            (Some(lo), _) => format!("{lo}"),
            _ => "?".into(),
        }
    };
    let h = span(bounds.iter().map(|b| b.1 - b.0).collect());
    let w = span(bounds.iter().map(|b| b.3 - b.2).collect());
    let size = if h == w { h } else { format!("{h} x {w}") };
    let how = if bounds
        .iter()
        .all(|b| b.1 - b.0 == tile && b.3 - b.2 == tile)
    {
        "covering every pixel".to_string()
    } else {
        format!("whole {tile}-px tiles stretched to cover every pixel")
    };
    format!("tiles of {size} px ({how})")
}

/// What the errors of a jackknife over the tiles of fewer than 3 images
/// cannot see, measured ("Errors" in the module docs), for the warnings.
pub const TILE_CAVEAT: &str = "the tiles are treated as independent, which fields correlated \
     over long distances (cascades) are not: on single 256^2-512^2 universal multifractal \
     fields these errors were, in rms, 0.56-0.87 of the scatter between fields for alpha, \
     0.38-1.16 for C1, 0.36-0.66 for H, so they may understate up to 3x; surrogates \
     (tm --surrogates K, surrogate_errors) measure the error under the fitted model";

/// Trace moments of one or two fields (a DEM) with errors from a jackknife
/// over tiles of their domains, as `wtmm tm` for fewer than 3 images: tiles
/// of [`tile_side`], every image's pooled ([`pool_tiles`]), then
/// [`finish_jackknife`] with `fc` as given: pass
/// [`TraceMomentFitConfig::for_tiles`] for the numbers of `wtmm tm` (an
/// OLS universal fit; [`Default`] fits by GLS). The result's warnings
/// say how rough the errors are (few tiles) and what tiles cannot see
/// ([`TILE_CAVEAT`]). Returns the merged accumulator too.
///
/// **Errors** with no field, or as [`TraceMomentAccumulator::field_tiles`]
/// and [`finish_jackknife`]; fit settings that fail
/// [`TraceMomentFitConfig::validate`] or
/// [`TraceMomentFitConfig::lambda_range`] on these sizes are refused before
/// any moment is computed.
pub fn analyze_tiled(
    fields: &[Field],
    config: &TraceMomentConfig,
    fc: &TraceMomentFitConfig,
) -> Result<(TraceMomentAccumulator, TraceMomentResult)> {
    let side = fields.iter().map(|f| f.dim().0.min(f.dim().1)).max();
    let Some(side) = side else {
        return Err(Error::Input("no field given".into()));
    };
    // a bad fit range is known from the sizes: said before the moments (a
    // default range fails only on images the moments refuse as too small,
    // which they say better)
    fc.validate()?;
    if fc.log2_lambda.is_some() {
        fc.lambda_range(box_levels(side))?;
    }
    let tile = tile_side(side, fc);
    let per_image = crate::par::try_map(fields.len(), |i| {
        TraceMomentAccumulator::field_tiles(config, &fields[i], tile)
    })?;
    let bounds: Vec<_> = fields
        .iter()
        .flat_map(|f| tile_bounds(f.dim().0, f.dim().1, tile))
        .collect();
    let (whole, tiles) = pool_tiles(per_image)?;
    let mut res = finish_jackknife(&whole, &tiles, fc, &tiles_label(&bounds, tile))?;
    let n = res.jackknife_groups;
    let groups = match fields.len() {
        1 => "tiles of one image".to_string(),
        k => format!("tiles of {k} images"),
    };
    res.warnings.extend(crate::stats::fit::few_groups_warning(
        n,
        &format!("a jackknife over {n} {groups}"),
    ));
    if n >= 2 {
        res.warnings.push(TILE_CAVEAT.to_string());
    }
    Ok((whole, res))
}

/// Trace-moment analysis of one field with the errors of its regressions
/// only, which understate (the fitted scales are not independent): for one
/// image use [`analyze_tiled`], for an ensemble [`finish_ensemble`].
///
/// **Errors** as [`TraceMomentAccumulator::add_field`] and
/// [`TraceMomentAccumulator::finish`]; the fit range is checked first.
pub fn analyze(
    field: &Field,
    config: TraceMomentConfig,
    fit: &TraceMomentFitConfig,
) -> Result<TraceMomentResult> {
    fit.validate()?;
    let (ny, nx) = field.dim();
    if fit.log2_lambda.is_some() {
        fit.lambda_range(box_levels(ny.min(nx)))?;
    }
    let mut acc = TraceMomentAccumulator::new(config)?;
    acc.add_field(field)?;
    acc.finish(fit)
}

/// Checks fit settings against the sizes `[ny, nx]` of the images of an
/// ensemble, before any moment is computed (from headers:
/// [`crate::io::read_shape`]): what [`finish_ensemble`] would refuse
/// after every image had been read. An explicit `log2 λ` range must lie
/// within the boxes ([`TraceMomentFitConfig::lambda_range`]), an
/// explicit lag range within the lags ([`TraceMomentFitConfig::lag_range`]),
/// and, for the jackknife over the images, the largest fitted box and the
/// largest fitted lag must be held by two images or more (as
/// [`finish_jackknife`]'s replicates need). A
/// default range on images too small for it is left to the moments, which
/// name the image.
///
/// **Errors** as [`TraceMomentFitConfig::validate`],
/// [`TraceMomentFitConfig::lambda_range`] and
/// [`TraceMomentFitConfig::lag_range`], and on a fitted box or lag that
/// only one image holds.
pub fn check_ensemble_fit(fc: &TraceMomentFitConfig, shapes: &[[usize; 2]]) -> Result<()> {
    fc.validate()?;
    // an image too small for any moment is named by the moments
    if shapes.iter().any(|s| s[0].min(s[1]) < MIN_SIDE) {
        return Ok(());
    }
    let mut levels: Vec<usize> = shapes.iter().map(|s| box_levels(s[0].min(s[1]))).collect();
    levels.sort_unstable_by(|a, b| b.cmp(a));
    let Some(&kmax) = levels.first() else {
        return Ok(());
    };
    let lo = match fc.lambda_range(kmax) {
        Ok((lo, _)) => lo,
        Err(e) if fc.log2_lambda.is_some() => return Err(e),
        Err(_) => return Ok(()),
    };
    let lags = fc.lag_range(kmax, sf_lags_of(kmax))?;
    match levels.get(1) {
        Some(&next) => {
            lone_box_check(kmax, lo, (kmax - next) as f64, "one image")?;
            match fitted_lags(lags, sf_lags_of(kmax)) {
                Some((_, hi)) => lone_lag_check(hi, sf_lags_of(next), "one image"),
                None => Ok(()),
            }
        }
        None => Ok(()),
    }
}

/// Refuses, before any image is read, fit selectors that select too little
/// to fit: fewer than 3 of `cfg.q` in the first window of the universal fit,
/// `0 < q <= 2` cut by `fc.q_fit_max` (alpha and C1 would be NaN; the
/// data-dependent `q_s/2` bound is checked, with a warning, after the
/// moments), none of `cfg.eta` in the DTM's η range (when there is a DTM; one
/// or two are a choice, `--eta 1` to skip the DTM's cost, and the result's
/// warnings say what the DTM lacks), or a `k_range` holding fewer than 3
/// spectrum bins in the largest of `shapes` (the `spectrum` command refuses
/// the same). A default k range on images too small for it is left to the
/// fit, which says so.
///
/// **Errors** naming the flag, with what it selects.
pub fn check_fit_selectors(
    cfg: &TraceMomentConfig,
    fc: &TraceMomentFitConfig,
    shapes: &[[usize; 2]],
) -> Result<()> {
    let num = crate::error::short;
    let list_of = |v: &[f64]| match v {
        [first, .., last] if v.len() > 6 => {
            format!("{} values, {} .. {}", v.len(), num(*first), num(*last))
        }
        v => v.iter().map(|&e| num(e)).collect::<Vec<_>>().join(", "),
    };
    let cap = fc.q_fit_max.unwrap_or(f64::INFINITY);
    let first = cap.min(FIRST_UNIVERSAL_Q_MAX);
    let usable = cfg.q.iter().filter(|&&v| v > 0.0 && v <= first).count();
    if usable < 3 {
        let capped = cap < FIRST_UNIVERSAL_Q_MAX;
        return Err(Error::param(
            if capped { "q-fit-max" } else { "q" },
            format!(
                "the trace-moment orders ({}) hold {usable} order(s) in 0 < q <= {}{}: the \
                 universal fit of alpha and C1 starts there and needs 3 or more",
                list_of(&cfg.q),
                num(first),
                if capped { " (--q-fit-max)" } else { "" }
            ),
        ));
    }
    let (lo, hi) = fc.eta;
    let in_fit = cfg
        .eta
        .iter()
        .filter(|&&e| e >= lo - 1e-12 && e <= hi + 1e-12)
        .count();
    if !cfg.dtm_q.is_empty() && in_fit == 0 {
        let list = list_of(&cfg.eta);
        return Err(Error::param(
            "eta-fit",
            format!(
                "none of the eta values ({list}) lies in the fit range [{}, {}]: the double trace \
                 moment would have nothing to fit (--eta, --eta-fit)",
                crate::error::short(lo),
                crate::error::short(hi)
            ),
        ));
    }
    if let Some(k) = fc.k_range {
        let mut most = 0;
        for s in shapes {
            most = most.max(bins_in_range(s[0], s[1], cfg.spectrum.bins_per_octave, k)?);
        }
        if !shapes.is_empty() && most < 3 {
            return Err(Error::param(
                "k-range",
                format!(
                    "[{}, {}] rad/px holds {most} spectrum bins of the largest image; the fit of \
                     beta needs 3",
                    crate::error::short(k.0),
                    crate::error::short(k.1)
                ),
            ));
        }
    }
    Ok(())
}

/// The smallest side (px) of an image or flux with trace moments.
pub const MIN_SIDE: usize = 8;

/// [`sf_lags`] from the box level `kmax` of a side.
fn sf_lags_of(kmax: usize) -> usize {
    kmax.saturating_sub(1)
}

/// The error of a jackknife replicate that lacks the `d` coarsest box
/// levels of an ensemble whose range starts at `lo` (log2 λ, boxes of
/// `2^(kmax - lo)` px): only `holder` has the boxes it fits.
fn lone_box_check(kmax: usize, lo: f64, d: f64, holder: &str) -> Result<()> {
    // the fitted levels are the integers from ceil(lo)
    let first = (lo - 1e-9).ceil();
    if first - d < -1e-9 {
        return Err(Error::param(
            "lambda-fit",
            format!(
                "the fit reaches boxes of {} px, which only {holder} holds, so a jackknife \
                 cannot leave it out: fit from log2 λ = {d} (boxes of at most {} px) or analyse \
                 images of one size",
                (kmax as f64 - first).exp2(),
                (kmax as f64 - d).exp2()
            ),
        ));
    }
    Ok(())
}

/// The error of a jackknife replicate that holds `nj` lags when the
/// structure functions are fitted up to `log2 l = hi`: only `holder` has
/// the lags it fits.
fn lone_lag_check(hi: f64, nj: usize, holder: &str) -> Result<()> {
    if hi > nj as f64 - 1.0 + 1e-9 {
        return Err(Error::param(
            "lag-fit",
            format!(
                "the structure functions are fitted up to lags of {} px, which only {holder} \
                 holds, so a jackknife cannot leave it out: fit lags up to log2 l = {} \
                 (--lag-fit) or analyse images of one size",
                hi.exp2(),
                nj as f64 - 1.0
            ),
        ));
    }
    Ok(())
}

/// The number of structure-function lags `1, 2, .., 2^(n-1)` px of fields
/// whose smaller side is `side` px: lags up to a quarter of the side.
pub fn sf_lags(side: usize) -> usize {
    sf_lags_of(box_levels(side))
}

/// The coarsest box level `kmax = floor(log2 side)` of fields whose
/// smaller side is `side` px (0 for an empty side): `log2 λ` runs from 0
/// to it ([`TraceMomentFitConfig::lambda_range`]).
pub fn box_levels(side: usize) -> usize {
    side.max(1).ilog2() as usize
}
