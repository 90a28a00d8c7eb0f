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

mod fit;
mod flux;
mod surrogate;

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

/// A field's least-squares plane, as the trace moments record it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct FieldPlane {
    /// The share of the raw field's variance the plane explains
    /// ([`Field::plane_share`]); `None` without a plane.
    pub share: Option<f64>,
    /// `ξ(1)` of the raw field and of the field less its plane
    /// (`flux::hurst_sf`), recorded when the share exceeds
    /// [`crate::spectra::PLANE_SHARE_WARN`] and the plane is not removed:
    /// how much the plane moves `H_sf` ([`diagnostics`]).
    pub h_sf: Option<[f64; 2]>,
}

impl FieldPlane {
    fn of(field: &Field, config: &TraceMomentConfig) -> Self {
        let share = field.plane_share();
        let h_sf = share
            .filter(|&p| config.detrend == Trend::None && p > crate::spectra::PLANE_SHARE_WARN)
            .and_then(|_| {
                let flat = field.detrended(Trend::Plane).ok()?;
                Some([flux::hurst_sf(field)?, flux::hurst_sf(&flat)?])
            });
        FieldPlane { share, h_sf }
    }
}

impl TraceMomentAccumulator {
    /// **Errors** on an invalid configuration.
    pub fn new(config: TraceMomentConfig) -> Result<Self> {
        config.validate()?;
        Ok(TraceMomentAccumulator {
            images: 0,
            max_side: 0,
            n_valid: 0,
            phi_sum: LogSum::default(),
            eta_sum: vec![LogSum::default(); config.eta.len()],
            box_count: Vec::new(),
            tm: vec![Vec::new(); config.q.len()],
            dtm: vec![vec![Vec::new(); config.dtm_q.len()]; config.eta.len()],
            sf_count: Vec::new(),
            sf: vec![Vec::new(); config.sf_q.len()],
            spectrum: None,
            diff_orders: Vec::new(),
            planes: Vec::new(),
            config,
        })
    }

    /// **Errors** unless the accumulator is whole: valid settings, one
    /// sum list per q, η, DTM order and structure-function order, each as
    /// long as its level or lag counts, no more box levels or lags than
    /// the largest image holds (`log2 max_side + 1`: a level appended to a
    /// shard would shift every `log2 λ`), and at most one plane and one
    /// differentiation order per image. A deserialised shard (truncated,
    /// edited) is checked before it is merged or finished.
    pub fn check(&self) -> Result<()> {
        self.config.validate()?;
        let c = &self.config;
        let bad = |what: String| Err(Error::Input(format!("trace-moment sums: {what}")));
        let (nl, nj) = (self.box_count.len(), self.sf_count.len());
        if self.eta_sum.len() != c.eta.len()
            || self.tm.len() != c.q.len()
            || self.dtm.len() != c.eta.len()
            || self.dtm.iter().any(|e| e.len() != c.dtm_q.len())
            || self.sf.len() != c.sf_q.len()
        {
            return bad(format!(
                "{} eta sums, {} moment lists, {} x {:?} DTM lists, {} structure-function lists \
                 for {} eta, {} q, {} DTM q, {} structure-function q",
                self.eta_sum.len(),
                self.tm.len(),
                self.dtm.len(),
                self.dtm.iter().map(Vec::len).collect::<Vec<_>>(),
                self.sf.len(),
                c.eta.len(),
                c.q.len(),
                c.dtm_q.len(),
                c.sf_q.len()
            ));
        }
        if self
            .tm
            .iter()
            .chain(self.dtm.iter().flatten())
            .any(|v| v.len() != nl)
            || self.sf.iter().any(|v| v.len() != nj)
        {
            return bad(format!(
                "sum lists of other lengths than the {nl} box levels or {nj} lags"
            ));
        }
        let levels = if self.max_side > 0 {
            self.max_side.ilog2() as usize + 1
        } else {
            0
        };
        if nl > levels || nj > levels {
            return bad(format!(
                "{nl} box levels and {nj} lags, but images of at most {} px hold {levels}",
                self.max_side
            ));
        }
        if self.planes.len() > self.images || self.diff_orders.len() > self.images {
            return bad(format!(
                "{} planes and {} differentiation orders for {} images",
                self.planes.len(),
                self.diff_orders.len(),
                self.images
            ));
        }
        Ok(())
    }

    /// Adds one field: flux (after the optional fractional integration),
    /// structure functions and spectrum.
    ///
    /// **Errors** if the field is smaller than 8x8 (16x16 with
    /// [`FluxDiff::Auto`], whose `ξ(1)` needs the lags 2 and 4 px, each at
    /// most a quarter of the side), has no valid pixel or
    /// values beyond [`crate::field::AMPLITUDE_LIMIT`]; the accumulator is
    /// then unchanged (everything that can fail is computed first).
    pub fn add_field(&mut self, field: &Field) -> Result<()> {
        field.check()?;
        if let Some(why) = field.amplitude_problem() {
            return Err(Error::Input(why));
        }
        let plane = FieldPlane::of(field, &self.config);
        let field = &*field.detrended(self.config.detrend)?;
        let fill = self.shared_fill(field)?;
        let ps = match &fill {
            Some(f) => power_spectrum(f.view(), &self.config.spectrum)?,
            None => field_power_spectrum(field, &self.config.spectrum)?,
        };
        let (phi, ok, diff) = self.field_flux(field, fill)?;
        self.accumulate_flux(&phi, &ok)?;
        self.diff_orders.push(diff);
        self.planes.push(plane);
        self.accumulate_sf(field);
        match &mut self.spectrum {
            Some(s) => s.merge(&ps)?,
            None => self.spectrum = Some(ps),
        }
        Ok(())
    }

    /// The harmonic fill of `field`'s holes when the spectrum and the flux's
    /// fractional derivative both take the same one (a harmonic spectrum
    /// fill, wrapped across the borders exactly when the flux is periodic:
    /// [`field_power_spectrum`], [`flux::smooth`]), to be computed once
    /// (on 2048^2 with 30 % missing the fill is about a tenth of `tm`);
    /// `None` otherwise.
    fn shared_fill(&self, field: &Field) -> Result<Option<Array2<f64>>> {
        let s = &self.config.spectrum;
        let (ny, nx) = field.dim();
        // too small: field_flux says so, before any fill
        if ny < MIN_SIDE
            || nx < MIN_SIDE
            || field.mask.is_none()
            || s.fill != HoleFill::Harmonic
            || (s.window == Window::None) != self.config.periodic
        {
            return Ok(None);
        }
        field.check()?;
        field.filled_harmonic_on(self.config.periodic).map(Some)
    }

    /// The flux of a field, its validity and the differentiation order
    /// used; `fill`: the field's harmonic fill when already computed
    /// ([`Self::shared_fill`]).
    fn field_flux(
        &self,
        field: &Field,
        fill: Option<Array2<f64>>,
    ) -> Result<(Array2<f64>, Array2<bool>, f64)> {
        let (ny, nx) = field.dim();
        if ny < MIN_SIDE || nx < MIN_SIDE {
            return Err(Error::Input(format!(
                "image {ny}x{nx} too small for trace moments ({MIN_SIDE}x{MIN_SIDE})"
            )));
        }
        if field.valid_count() == 0 {
            return Err(Error::Input(
                "every pixel is missing (NaN or nodata)".into(),
            ));
        }
        let mask = field.mask.as_ref().map(|m| m.view());
        let diff = match self.config.diff {
            FluxDiff::None => 0.0,
            FluxDiff::Order(d) => d,
            FluxDiff::Auto => flux::hurst_sf(field).ok_or_else(|| {
                Error::Input(match field.range() {
                    Some((lo, hi)) if lo == hi => "constant image: no fluctuations".into(),
                    // xi(1) is fitted over lags 2 px .. side/4: 2 of them
                    // from 16 px
                    _ if sf_lags(ny.min(nx)) < 3 => format!(
                        "image {ny}x{nx} too small for the automatic derivative order: H = \
                         xi(1) is fitted over lags of 2 px up to a quarter of the side, which \
                         needs 16 px or more; give the order (--diff-order; FluxDiff::Order in \
                         the library)"
                    ),
                    _ => format!(
                        "cannot estimate H = xi(1) for the automatic derivative order \
                         (--diff-order auto) from the structure function of this {ny}x{nx} \
                         image (too few lags, or none with a nonzero increment); give the \
                         order (--diff-order; FluxDiff::Order in the library)"
                    ),
                })
            })?,
        };
        // one Fourier filter |k|^(diff - frac_int) (mirror-extended unless
        // the field is a torus)
        let order = self.config.frac_int.unwrap_or(0.0) - diff;
        let smoothed;
        let f = if order != 0.0 {
            smoothed = match fill {
                Some(f) => flux::smooth_filled(f, order, self.config.periodic)?,
                None => flux::smooth(field, order, self.config.periodic)?,
            };
            smoothed.view()
        } else {
            field.data.view()
        };
        let (phi, ok) = flux::flux(f, mask, self.config.flux, self.config.periodic)?;
        Ok((phi, ok, diff))
    }

    /// One field as a whole (`.0`, identical to [`Self::add_field`] on an
    /// empty accumulator) and as spatial tiles (`.1`) for a block jackknife
    /// of a single image ([`finish_jackknife`]). The tiles are those of
    /// [`tile_bounds`]: as many whole tiles of `tile` px as fit along each
    /// side, stretched to cover the image (sides within 1 px of each other).
    /// Tile `t` keeps, in every window of the box pyramid, the blocks (boxes
    /// of side `2^floor(log2 tile)`, the largest fitted box in the CLI) whose
    /// centre lies in it, with every finer box inside them, coarser boxes by
    /// their own centre; and the increments whose midpoint lies in it. A
    /// block larger than the window (a tile larger than the image's largest
    /// box) can have its centre just past the image's edge: it goes to the
    /// nearest tile ([`crate::spectra::TileGrid::index`]). The flux is
    /// computed once on the whole field, so the tiles' box sums add up
    /// exactly to the whole image's at every level. Each tile carries the
    /// whole field's spectrum (β is not jackknifed). Tiles with no valid
    /// flux pixel are left out; fewer than 2 tiles give one part, the whole
    /// field.
    ///
    /// One accumulator per tile: a tile narrower than the largest fitted
    /// box ([`analyze_tiled`] takes that box, [`tile_side`]) is no
    /// independent sample, and small tiles are many (a 1 px tile of a 256²
    /// field makes 65536 accumulators).
    ///
    /// **Errors** as [`Self::add_field`], or if `tile` is 0.
    pub fn field_tiles(
        config: &TraceMomentConfig,
        field: &Field,
        tile: usize,
    ) -> Result<(TraceMomentAccumulator, Vec<TraceMomentAccumulator>)> {
        if tile == 0 {
            return Err(Error::param("tile", "must be at least 1 px"));
        }
        if let Some(why) = field.amplitude_problem() {
            return Err(Error::Input(why));
        }
        let plane = FieldPlane::of(field, config);
        let field = &*field.detrended(config.detrend)?;
        let mut whole = TraceMomentAccumulator::new(config.clone())?;
        let fill = whole.shared_fill(field)?;
        // the spectrum of a shared fill first: the flux takes the fill
        let shared_ps = fill
            .as_ref()
            .map(|f| power_spectrum(f.view(), &config.spectrum))
            .transpose()?;
        let (phi, ok, diff) = whole.field_flux(field, fill)?;
        let (ny, nx) = field.dim();
        // the tiles of tile_bounds; blocks: the largest power of two <=
        // tile (Self::accumulate_flux_groups)
        let grid = crate::spectra::TileGrid::new((0, ny, 0, nx), tile);
        let kb = tile.ilog2() as usize;
        let table = grid.map(|g| g.table(ny, nx));
        // a block's centre can lie past the image's edge (a tile larger
        // than the boxes); past the domain, which here is the image,
        // `TileGrid::index` takes the last tile, as its last pixel's
        let tile_of = |y: usize, x: usize| {
            table
                .as_ref()
                .map_or(0, |t| t.at(y.min(ny - 1), x.min(nx - 1)))
        };
        let mut parts = (0..grid.map_or(0, |g| g.len()))
            .map(|_| TraceMomentAccumulator::new(config.clone()))
            .collect::<Result<Vec<_>>>()?;
        // the whole and the tiles side by side: a lone image (the reason
        // for tiles) leaves the other cores idle otherwise
        let (done, valid) = rayon::join(
            || -> Result<()> {
                whole.accumulate_flux(&phi, &ok)?;
                whole.accumulate_sf(field);
                whole.spectrum = Some(match shared_ps {
                    Some(ps) => ps,
                    None => field_power_spectrum(field, &config.spectrum)?,
                });
                Ok(())
            },
            || {
                if parts.is_empty() {
                    return Vec::new();
                }
                let valid = Self::accumulate_flux_groups(&mut parts, &phi, &ok, kb, tile_of);
                Self::accumulate_sf_groups(&mut parts, field, tile_of);
                valid
            },
        );
        done?;
        whole.diff_orders.push(diff);
        whole.planes.push(plane);
        if parts.is_empty() {
            return Ok((whole.clone(), vec![whole]));
        }
        // a tile without a valid flux pixel is left out
        let mut parts: Vec<TraceMomentAccumulator> = parts
            .into_iter()
            .zip(valid)
            .filter(|(_, n)| *n > 0)
            .map(|(p, _)| p)
            .collect();
        for p in parts.iter_mut() {
            p.diff_orders.push(diff);
            p.planes.push(plane);
            p.spectrum.clone_from(&whole.spectrum);
        }
        Ok((whole, parts))
    }

    /// Adds a flux given directly (values `>= 0`; `mask` true = missing),
    /// e.g. a cascade measure or [`crate::synth::fif::fif_flux`]. No
    /// structure functions or spectrum.
    ///
    /// **Errors** on a negative or non-finite unmasked value, an image
    /// smaller than 8x8, or a mask of another shape.
    pub fn add_flux(&mut self, phi: ArrayView2<f64>, mask: Option<ArrayView2<bool>>) -> Result<()> {
        let (ny, nx) = phi.dim();
        if ny < MIN_SIDE || nx < MIN_SIDE {
            return Err(Error::Input(format!(
                "flux {ny}x{nx} too small for trace moments ({MIN_SIDE}x{MIN_SIDE})"
            )));
        }
        if let Some(m) = &mask
            && m.dim() != (ny, nx)
        {
            return Err(Error::Input(format!(
                "mask {}x{} for a flux {ny}x{nx}",
                m.dim().0,
                m.dim().1
            )));
        }
        let mut ok = Array2::from_elem((ny, nx), true);
        if let Some(m) = mask {
            ok.zip_mut_with(&m, |o, &mm| *o = !mm);
        }
        let mut p = phi.to_owned();
        for (v, &o) in p.iter_mut().zip(ok.iter()) {
            if o && !(v.is_finite() && *v >= 0.0) {
                return Err(Error::Input(format!(
                    "flux values must be finite and >= 0, got {v_s}",
                    v_s = crate::error::short(*v)
                )));
            }
            if !o {
                *v = 0.0;
            }
        }
        self.accumulate_flux(&p, &ok)?;
        // no field, no plane: the entry keeps the shares one per field
        self.planes.push(FieldPlane::default());
        Ok(())
    }

    /// Adds the box moments of a flux over the windows of
    /// [`flux::windows`] (every box and pixel).
    ///
    /// **Errors** if no flux pixel is valid (nothing is changed).
    fn accumulate_flux(&mut self, phi: &Array2<f64>, ok: &Array2<bool>) -> Result<()> {
        let valid = Self::accumulate_flux_groups(std::slice::from_mut(self), phi, ok, 0, |_, _| 0);
        if valid[0] == 0 {
            return Err(Error::Input("no valid flux pixel".into()));
        }
        Ok(())
    }

    /// Adds the box moments of a flux over the windows of
    /// [`flux::windows`] to `accs`, box by box: a box goes to
    /// `accs[group(y, x)]`, `(y, x)` the centre of its block in the image
    /// (the block of side `2^max(k, kb)` holding a box of side `2^k`:
    /// boxes coarser than a block by their own centre; for the tiles of
    /// [`Self::field_tiles`] blocks of side `2^kb`, `group` the tile). The
    /// tiles of an image so share its boxes out exactly, and a tile is the
    /// same region at every level up to the blocks: windows anchored at other corners put their
    /// boxes across any tile border, and a box assigned by its own corner
    /// or centre made a leave-one-tile-out sample a slightly different
    /// region at each level, a spurious change of slope (on 32 topo-fif
    /// fields of 400², tiles of 128 px: DTM α's jackknife error 1.9 times
    /// the scatter between fields by the box centre, 24 times by its
    /// corner; 0.83 by the block, against 0.5-0.6 on 384² and 512² where
    /// boxes never cross).
    ///
    /// One pass for all groups: the box sums, and the powers of φ the
    /// double trace moments take, are the image's whatever the group, so
    /// they are computed once, and each group's boxes (in raster order, as
    /// one accumulator per tile would visit them: the same sums to the
    /// bit) are gathered from them. Until 2026-11-29 each tile took its own
    /// pass over the whole image (2048^2, 4 tiles: 11.2 s against 5.0 s
    /// now, with the threads below).
    ///
    /// Returns the valid flux pixels of each group; a group without one is
    /// left unchanged.
    fn accumulate_flux_groups(
        accs: &mut [TraceMomentAccumulator],
        phi: &Array2<f64>,
        ok: &Array2<bool>,
        kb: usize,
        group: impl Fn(usize, usize) -> usize,
    ) -> Vec<u64> {
        let (ny, nx) = phi.dim();
        let ng = accs.len();
        // the group of box (by, bx) of side 2^k in the window at (y0, x0):
        // that of its block's centre
        let group_of = |y0: usize, x0: usize, k: usize, by: usize, bx: usize| {
            let kk = k.max(kb);
            let half = (1usize << kk) / 2;
            let y = y0 + ((by >> (kk - k)) << kk) + half;
            let x = x0 + ((bx >> (kk - k)) << kk) + half;
            group(y, x)
        };
        let wins = flux::windows(ny, nx);
        // valid flux pixels, once per window that holds them: the weights
        // the finest boxes give them, hence the mean that normalises φ
        let mut valid = vec![0u64; ng];
        for &(y0, x0, wy, wx) in &wins {
            for y in y0..y0 + wy {
                for x in x0..x0 + wx {
                    if ok[[y, x]] {
                        valid[group_of(y0, x0, 0, y - y0, x - x0)] += 1;
                    }
                }
            }
        }
        let live: Vec<bool> = valid.iter().map(|&v| v > 0).collect();
        if !live.contains(&true) {
            return valid;
        }
        let cfg = accs[0].config.clone();
        let rule = cfg.box_weights;
        for &(y0, x0, wy, wx) in &wins {
            let okw = ok.slice(ndarray::s![y0..y0 + wy, x0..x0 + wx]);
            let pyr = flux::Pyramid::new(okw);
            let nl = pyr.levels();
            for (acc, _) in accs.iter_mut().zip(&live).filter(|(_, l)| **l) {
                if acc.box_count.len() < nl {
                    acc.box_count.resize(nl, 0);
                    for v in acc.tm.iter_mut() {
                        v.resize(nl, LogSum::default());
                    }
                    for e in acc.dtm.iter_mut() {
                        for v in e.iter_mut() {
                            v.resize(nl, LogSum::default());
                        }
                    }
                }
            }
            let base: Vec<f64> = phi
                .slice(ndarray::s![y0..y0 + wy, x0..x0 + wx])
                .iter()
                .zip(okw.iter())
                .map(|(v, &o)| if o { *v } else { 0.0 })
                .collect();
            // each level's boxes, group by group, and their weights
            let kept: Vec<Vec<Vec<(usize, u32)>>> = (0..nl)
                .map(|k| pyr.kept_by(k, |by, bx| group_of(y0, x0, k, by, bx), rule, ng))
                .collect();
            let weights: Vec<Vec<Option<Vec<f64>>>> = kept
                .iter()
                .enumerate()
                .map(|(k, groups)| {
                    groups
                        .iter()
                        .zip(accs.iter_mut())
                        .zip(&live)
                        .map(|((boxes, acc), &l)| {
                            let (w, total) = flux::Pyramid::weights_of(boxes, k, rule);
                            if l {
                                acc.box_count[k] += total;
                            }
                            w
                        })
                        .collect()
                })
                .collect();
            // plain trace moments (η = 1)
            let sums = pyr.sums(base.clone());
            for (k, sk) in sums.iter().enumerate() {
                for (g, acc) in accs.iter_mut().enumerate().filter(|(g, _)| live[*g]) {
                    let logs = flux::Pyramid::log_means_of(sk, &kept[k][g]);
                    let lmax = logs.iter().copied().fold(f64::NEG_INFINITY, f64::max);
                    if k == 0 {
                        // pixels: every weight is 1
                        acc.phi_sum.add_powers(&logs, lmax, 1.0);
                    }
                    let w = weights[k][g].as_deref();
                    for (iq, (m, s)) in weighted_power_sums(&logs, w, lmax, &cfg.q)
                        .into_iter()
                        .enumerate()
                    {
                        acc.tm[iq][k].add(m, s);
                    }
                }
            }
            // double trace moments. Where the box sums of φ^η could
            // overflow (a field of 1e99 at η = 3.16 lost K(q, η), and its
            // fit said nothing) or underflow, φ / max φ is raised instead
            // (at most 1 for any η) and the logs of the box means shifted
            // back by η ln max φ; elsewhere φ itself, as before (the
            // ratios throughout cost 5 % of tm's time on a 2048^2 field)
            let p_max = base.iter().copied().fold(0.0, f64::max);
            let n_px = base.len() as f64;
            // ln(φ / max φ) once per pixel, then one exp per pixel and η
            // (a powf per pixel and η was a fifth of tm's time). The
            // error is |η ln φ| ulp (the offset η ln max φ included):
            // 1.5e-14 against powf at max φ = 1, 1e-13 at 1e300 or 1e-310
            // (review, 2026-11-29). Divided, not multiplied by 1 / max:
            // that overflows for a subnormal max, a flux given through the
            // library.
            let ln_rel: Vec<f64> = base
                .iter()
                .map(|&p| {
                    if p > 0.0 {
                        (p / p_max).ln()
                    } else {
                        f64::NEG_INFINITY
                    }
                })
                .collect();
            let ln_max = p_max.ln();
            // the η in two halves side by side: each η's terms are computed
            // alone and added below in η order, so the sums are the same to
            // the bit whatever the thread count (a lone 2048^2 image: 7.8 ->
            // 6.3 s on 2 cores). Two, not one task per η: each holds its
            // own powers and box sums (19 B/px), and 16 at once took 1.7 GB
            // at 2048^2 on 16 threads
            type Terms = Vec<(usize, usize, Option<(f64, f64)>, Vec<(f64, f64)>)>;
            // `sums`: the pyramid's levels, `means` its box means, reused
            // from one η to the next
            let one_eta = |&eta: &f64, (sums, means): &mut (Vec<Vec<f64>>, Vec<f64>)| {
                let top = p_max.powf(eta);
                let scaled = p_max > 0.0 && !(top >= 1e-280 && top * n_px <= 1e280);
                // φ^η itself, or (φ / max φ)^η where φ^η could overflow
                let offset = if scaled { 0.0 } else { eta * ln_max };
                if sums.is_empty() {
                    sums.push(Vec::new());
                }
                sums[0].clear();
                sums[0].extend(ln_rel.iter().map(|&l| (eta * l + offset).exp()));
                let shift = if scaled { eta * ln_max } else { 0.0 };
                pyr.sums_in(sums);
                // the box means as values, not logs: for the orders of
                // the DTM (1.5 by default) no ln or exp per box is left
                // (power_sums_of_values); the logs shift by `shift`
                let mut out = Terms::new();
                for (k, sk) in sums.iter().enumerate() {
                    for g in (0..ng).filter(|&g| live[g]) {
                        flux::Pyramid::means_into(sk, &kept[k][g], means);
                        let pixels = (k == 0).then(|| {
                            let (m, s) = power_sums_of_values(means, &[1.0])[0];
                            (m + shift, s)
                        });
                        let w = weights[k][g].as_deref();
                        let dtm = weighted_power_sums_of_values(means, w, &cfg.dtm_q)
                            .into_iter()
                            .zip(&cfg.dtm_q)
                            .map(|((m, s), &q)| (m + q * shift, s))
                            .collect();
                        out.push((k, g, pixels, dtm));
                    }
                }
                out
            };
            let half = cfg.eta.len().div_ceil(2);
            let run = |etas: &[f64]| {
                let mut scratch = (Vec::new(), Vec::new());
                etas.iter()
                    .map(|e| one_eta(e, &mut scratch))
                    .collect::<Vec<Terms>>()
            };
            let (lo, hi) = rayon::join(|| run(&cfg.eta[..half]), || run(&cfg.eta[half..]));
            let terms = lo.into_iter().chain(hi);
            for (ie, t) in terms.into_iter().enumerate() {
                for (k, g, pixels, dtm) in t {
                    if let Some((m, s)) = pixels {
                        accs[g].eta_sum[ie].add(m, s);
                    }
                    for (iq, (m, s)) in dtm.into_iter().enumerate() {
                        accs[g].dtm[ie][iq][k].add(m, s);
                    }
                }
            }
        }
        for (acc, &n) in accs.iter_mut().zip(&valid).filter(|(_, n)| **n > 0) {
            acc.n_valid += n;
            acc.images += 1;
            acc.max_side = acc.max_side.max(ny.min(nx));
        }
        valid
    }

    /// Structure-function sums of `field`.
    fn accumulate_sf(&mut self, field: &Field) {
        Self::accumulate_sf_groups(std::slice::from_mut(self), field, |_, _| 0);
    }

    /// Structure-function sums of `field` into `accs`: an increment goes to
    /// `accs[group(y, x)]`, `(y, x)` its midpoint (rounded down); in raster
    /// order within each group, as one pass per group would take them.
    fn accumulate_sf_groups(
        accs: &mut [TraceMomentAccumulator],
        field: &Field,
        group: impl Fn(usize, usize) -> usize,
    ) {
        let (ny, nx) = field.dim();
        let f = &field.data;
        let ok = |y: usize, x: usize| !field.is_masked(y, x);
        let sf_q = accs[0].config.sf_q.clone();
        // one buffer per group for every lag: allocated anew per lag, the
        // 2 ny nx increments (64 MB at 2048^2) were page-faulted in again
        // each time
        let mut incs: Vec<Vec<f64>> = vec![Vec::new(); accs.len()];
        if let [one] = incs.as_mut_slice() {
            one.reserve(2 * ny * nx);
        }
        for j in 0..sf_lags(ny.min(nx)) {
            let l = 1usize << j;
            incs.iter_mut().for_each(Vec::clear);
            for y in 0..ny {
                for x in 0..nx {
                    if !ok(y, x) {
                        continue;
                    }
                    if x + l < nx && ok(y, x + l) {
                        incs[group(y, x + l / 2)].push((f[[y, x + l]] - f[[y, x]]).abs());
                    }
                    if y + l < ny && ok(y + l, x) {
                        incs[group(y + l / 2, x)].push((f[[y + l, x]] - f[[y, x]]).abs());
                    }
                }
            }
            for (acc, incs) in accs.iter_mut().zip(&incs) {
                if acc.sf_count.len() <= j {
                    acc.sf_count.resize(j + 1, 0);
                    for v in acc.sf.iter_mut() {
                        v.resize(j + 1, LogSum::default());
                    }
                }
                acc.sf_count[j] += incs.len() as u64;
                for (iq, (m, s)) in power_sums_of_values(incs, &sf_q).into_iter().enumerate() {
                    acc.sf[iq][j].add(m, s);
                }
            }
        }
    }

    /// Adds another accumulator's sums (annealed ensemble).
    ///
    /// **Errors** if the configurations differ, or either fails [`Self::check`].
    pub fn merge(&mut self, o: &TraceMomentAccumulator) -> Result<()> {
        self.check()?;
        o.check()?;
        let differ = self.config.differences(&o.config);
        if !differ.is_empty() {
            return Err(Error::param(
                "config",
                format!(
                    "cannot merge trace moments accumulated with different settings ({}; \
                     settings stored before 2026-11-29 read as box_weights equal and \
                     spectrum fill mean)",
                    differ.join("; ")
                ),
            ));
        }
        // accumulators saved before the planes were recorded have none: pad
        // them with defaults so that the planes stay one per field, in order
        let own = self.images;
        self.planes
            .resize(own.max(self.planes.len()), FieldPlane::default());
        self.images += o.images;
        self.max_side = self.max_side.max(o.max_side);
        self.n_valid += o.n_valid;
        self.phi_sum.merge(&o.phi_sum);
        for (a, b) in self.eta_sum.iter_mut().zip(&o.eta_sum) {
            a.merge(b);
        }
        let nl = self.box_count.len().max(o.box_count.len());
        self.box_count.resize(nl, 0);
        for (k, c) in o.box_count.iter().enumerate() {
            self.box_count[k] += c;
        }
        let merge_vec = |a: &mut Vec<LogSum>, b: &Vec<LogSum>| {
            if a.len() < b.len() {
                a.resize(b.len(), LogSum::default());
            }
            for (x, y) in a.iter_mut().zip(b) {
                x.merge(y);
            }
        };
        for (a, b) in self.tm.iter_mut().zip(&o.tm) {
            merge_vec(a, b);
            a.resize(nl, LogSum::default());
        }
        for (ea, eb) in self.dtm.iter_mut().zip(&o.dtm) {
            for (a, b) in ea.iter_mut().zip(eb) {
                merge_vec(a, b);
                a.resize(nl, LogSum::default());
            }
        }
        let nj = self.sf_count.len().max(o.sf_count.len());
        self.sf_count.resize(nj, 0);
        for (j, c) in o.sf_count.iter().enumerate() {
            self.sf_count[j] += c;
        }
        for (a, b) in self.sf.iter_mut().zip(&o.sf) {
            merge_vec(a, b);
            a.resize(nj, LogSum::default());
        }
        match (&mut self.spectrum, &o.spectrum) {
            (Some(a), Some(b)) => a.merge(b)?,
            (None, Some(b)) => self.spectrum = Some(b.clone()),
            _ => {}
        }
        self.diff_orders.extend_from_slice(&o.diff_orders);
        self.planes.extend_from_slice(&o.planes);
        self.planes.resize(
            (own + o.images).max(self.planes.len()),
            FieldPlane::default(),
        );
        Ok(())
    }

    /// `log2 λ` of each level (`log2 L - k`).
    pub fn log2_lambda(&self) -> Vec<f64> {
        let kmax = self.box_count.len().saturating_sub(1);
        (0..self.box_count.len())
            .map(|k| (kmax - k) as f64)
            .collect()
    }

    /// Normalised `log2 <φ_λ^q>` per level, from sums `s`, for the flux
    /// normalised by the ensemble mean whose natural log is `lnm`.
    fn log2_moments(&self, s: &[LogSum], q: f64, lnm: f64) -> Vec<f64> {
        (0..self.box_count.len())
            .map(|k| {
                let c = self.box_count[k];
                if c == 0 || k >= s.len() {
                    return f64::NAN;
                }
                // the sum of the weights: valid pixels / 4^k (exact) with
                // count weights, whose whole boxes weigh 1
                let w = match self.config.box_weights {
                    BoxWeights::Equal => c as f64,
                    BoxWeights::Count => c as f64 / (1u64 << (2 * k)) as f64,
                };
                (s[k].ln() - w.ln() - q * lnm) / std::f64::consts::LN_2
            })
            .collect()
    }

    /// Exponents, fits and tables from the accumulated sums.
    ///
    /// **Errors** with no image, a flux identically 0 (constant field),
    /// fewer than 3 levels in the fit range, or settings that fail
    /// [`TraceMomentFitConfig::validate`].
    pub fn finish(&self, fc: &TraceMomentFitConfig) -> Result<TraceMomentResult> {
        let mut r = self.finish_inner(fc, None)?;
        r.warnings = diagnostics(&r, None);
        Ok(r)
    }

    /// [`Self::finish`], optionally with the universal-fit bound and `q_s`
    /// pinned to `pin = (q_hi, q_s)` (the jackknife keeps the full
    /// ensemble's q range: the rule for q_s depends on the image count).
    fn finish_inner(
        &self,
        fc: &TraceMomentFitConfig,
        pin: Option<(f64, f64)>,
    ) -> Result<TraceMomentResult> {
        fc.validate()?;
        self.check()?;
        if self.images == 0 || self.n_valid == 0 {
            return Err(Error::Input("no image accumulated".into()));
        }
        let lnm = self.phi_sum.ln() - (self.n_valid as f64).ln();
        if !lnm.is_finite() {
            return Err(Error::Input(
                "the flux is 0 everywhere (constant field?)".into(),
            ));
        }
        let log2_lambda = self.log2_lambda();
        let (lo, hi) = fc.lambda_range(self.box_count.len().saturating_sub(1))?;
        let kmax = log2_lambda.first().copied().unwrap_or(0.0);
        let in_range: Vec<bool> = log2_lambda
            .iter()
            .map(|&x| x >= lo - 1e-9 && x <= hi + 1e-9)
            .collect();
        let fit_line = |y: &[f64]| {
            let xs: Vec<f64> = log2_lambda
                .iter()
                .zip(&in_range)
                .filter(|(_, b)| **b)
                .map(|(x, _)| *x)
                .collect();
            let ys: Vec<f64> = y
                .iter()
                .zip(&in_range)
                .filter(|(_, b)| **b)
                .map(|(v, _)| *v)
                .collect();
            line_fit(&xs, &ys)
        };
        // trace moments
        let q = self.config.q.clone();
        let mut log2_m = Vec::with_capacity(q.len());
        let (mut kq, mut kse, mut kb) = (Vec::new(), Vec::new(), Vec::new());
        for (iq, &qq) in q.iter().enumerate() {
            let m = self.log2_moments(&self.tm[iq], qq, lnm);
            let f = fit_line(&m);
            kq.push(f.map_or(f64::NAN, |f| f.slope));
            kse.push(f.map_or(f64::NAN, |f| f.slope_stderr));
            kb.push(f.map_or(f64::NAN, |f| f.intercept));
            log2_m.push(m);
        }
        // universal fit and q_s (module docs)
        let lambda_max = 2f64.powf(kmax);
        let qcap = fc.q_fit_max.unwrap_or(f64::INFINITY);
        let fit_below = |qhi: f64| {
            let (qs_, ks_): (Vec<f64>, Vec<f64>) = q
                .iter()
                .zip(&kq)
                .filter(|(a, _)| **a > 0.0 && **a < qhi + 1e-12 && **a <= qcap + 1e-12)
                .map(|(a, b)| (*a, *b))
                .unzip();
            fit_universal(&qs_, &ks_)
        };
        let mut uni = fit_below(pin.map_or(FIRST_UNIVERSAL_Q_MAX, |p| p.0));
        let mut q_s = pin.map_or(f64::INFINITY, |p| p.1);
        let mut q_d = f64::INFINITY;
        let mut q_hi = pin.map_or(FIRST_UNIVERSAL_Q_MAX, |p| p.0);
        for _ in 0..3 {
            let Some(u) = uni else { break };
            let uk = UniversalK::new(u.alpha.min(2.0), u.c1.max(0.0));
            q_d = uk.q_divergence(D);
            if pin.is_some() {
                break;
            }
            q_s = uk.q_sampling(D, self.images as f64, lambda_max).min(q_d);
            q_hi = 0.5 * q_s;
            uni = fit_below(q_hi).or(uni);
        }
        let q_hi = q_hi.min(qcap).min(q.iter().copied().fold(0.0, f64::max));
        let q_s_empirical = uni.and_then(|u| linear_onset(&q, &kq, &u));
        // effective outer scale: common zero of the fitted lines
        let (mut skb, mut skk) = (0.0, 0.0);
        for ((&qq, &k), &b) in q.iter().zip(&kq).zip(&kb) {
            if qq > 0.0 && qq < q_s && k.is_finite() && b.is_finite() {
                skb += k * b;
                skk += k * k;
            }
        }
        let log2_lambda_eff = if skk > 0.0 { -skb / skk } else { f64::NAN };
        // double trace moments
        let eta = self.config.eta.clone();
        let mut k_eta = vec![vec![f64::NAN; eta.len()]; self.config.dtm_q.len()];
        let mut k_eta_se = k_eta.clone();
        let mut log2_m_eta = vec![vec![Vec::new(); eta.len()]; self.config.dtm_q.len()];
        for ie in 0..eta.len() {
            let lnm_e = self.eta_sum[ie].ln() - (self.n_valid as f64).ln();
            for (iq, &qq) in self.config.dtm_q.iter().enumerate() {
                let m = self.log2_moments(&self.dtm[ie][iq], qq, lnm_e);
                if let Some(f) = fit_line(&m) {
                    k_eta[iq][ie] = f.slope;
                    k_eta_se[iq][ie] = f.slope_stderr;
                }
                log2_m_eta[iq][ie] = m;
            }
        }
        let mut dtm = Vec::new();
        for (iq, &qq) in self.config.dtm_q.iter().enumerate() {
            let (xs, ys): (Vec<f64>, Vec<f64>) = eta
                .iter()
                .zip(&k_eta[iq])
                .filter(|(e, k)| {
                    **e >= fc.eta.0 - 1e-12
                        && **e <= fc.eta.1 + 1e-12
                        // the moments of φ^η are of order qη (and η
                        // for its normalisation): the same q_s/2 bound as
                        // the universal fit, below which they are unbiased
                        && qq * **e <= 0.5 * q_s
                        && **e <= 0.5 * q_s
                        // K(q, η) has the sign of K(q): negative for q < 1
                        // (conservation makes K(1) = 0); a value of the
                        // other sign is noise, not a point of the power law
                        && k.is_finite()
                        && **k * (qq - 1.0) > 0.0
                })
                .map(|(e, k)| (e.ln(), k.abs().ln()))
                .unzip();
            let f = line_fit(&xs, &ys);
            let used = |pick: fn(f64, f64) -> f64| xs.iter().copied().reduce(pick).map(f64::exp);
            let eta_used = (
                used(f64::min).unwrap_or(f64::NAN),
                used(f64::max).unwrap_or(f64::NAN),
            );
            dtm.push(match f {
                Some(f) => {
                    let shape = universal_shape(f.slope, qq).abs();
                    DtmFit {
                        q: qq,
                        alpha: f.slope,
                        alpha_stderr: f.slope_stderr,
                        c1: if shape > 0.0 {
                            f.intercept.exp() / shape
                        } else {
                            f64::NAN
                        },
                        n: f.n,
                        eta_used,
                    }
                }
                None => DtmFit {
                    q: qq,
                    alpha: f64::NAN,
                    alpha_stderr: f64::NAN,
                    c1: f64::NAN,
                    n: 0,
                    eta_used: (f64::NAN, f64::NAN),
                },
            });
        }
        // structure functions
        let nj = self.sf_count.len();
        let log2_lag: Vec<f64> = (0..nj).map(|j| j as f64).collect();
        let (llo, lhi) = fc.lag_range(kmax as usize, nj)?;
        let mut log2_sf = Vec::new();
        let (mut xi, mut xi_se, mut xi_b) = (Vec::new(), Vec::new(), Vec::new());
        for (iq, _) in self.config.sf_q.iter().enumerate() {
            let s: Vec<f64> = (0..nj)
                .map(|j| {
                    let c = self.sf_count[j];
                    if c == 0 {
                        f64::NAN
                    } else {
                        (self.sf[iq][j].ln() - (c as f64).ln()) / std::f64::consts::LN_2
                    }
                })
                .collect();
            let (xs, ys): (Vec<f64>, Vec<f64>) = log2_lag
                .iter()
                .zip(&s)
                .filter(|(x, _)| **x >= llo - 1e-9 && **x <= lhi + 1e-9)
                .map(|(x, y)| (*x, *y))
                .unzip();
            let f = line_fit(&xs, &ys);
            xi.push(f.map_or(f64::NAN, |f| f.slope));
            xi_se.push(f.map_or(f64::NAN, |f| f.slope_stderr));
            xi_b.push(f.map_or(f64::NAN, |f| f.intercept));
            log2_sf.push(s);
        }
        let h_sf = self
            .config
            .sf_q
            .iter()
            .position(|&v| (v - 1.0).abs() < 1e-12)
            .map(|i| xi[i])
            .filter(|v| v.is_finite());
        // spectrum -> β -> H
        let k2 = uni.map(|u| u.c1 * universal_shape(u.alpha, 2.0));
        let spec = match &self.spectrum {
            Some(ps) => {
                let (klo, khi) = fc.k_range.unwrap_or_else(|| default_k_range(self.max_side));
                ps.fit(klo, khi).ok()
            }
            None => None,
        };
        let beta_averaged = spec.map(|s| s.beta);
        let beta = beta_averaged.map(|b| b - 1.0);
        let h_spec = match (beta, k2) {
            (Some(b), Some(k2)) => Some((b - 1.0 + k2) / 2.0),
            _ => None,
        };
        let nan = f64::NAN;
        let (do_mean, do_sd) = mean_std(&self.diff_orders);
        Ok(TraceMomentResult {
            images: self.images,
            flux: self.config.flux,
            diff: self.config.diff,
            diff_order: do_mean,
            diff_order_sd: do_sd,
            detrend: self.config.detrend,
            plane_share: crate::skeleton::median(
                &self.planes.iter().filter_map(|p| p.share).collect::<Vec<_>>(),
            ),
            h_sf_plane_shift: {
                // over every field with a share (the pooled structure
                // functions average them all), 0 for those at or below half
                let n = self.planes.iter().filter(|p| p.share.is_some()).count();
                let d: Vec<f64> = self
                    .planes
                    .iter()
                    .filter_map(|p| p.h_sf.map(|[raw, flat]| raw - flat))
                    .collect();
                (!d.is_empty()).then(|| d.iter().sum::<f64>() / n.max(d.len()) as f64)
            },
            planes_over_half: self.planes.iter().filter(|p| p.h_sf.is_some()).count(),
            frac_int: self.config.frac_int,
            q,
            k: kq,
            k_stderr: kse,
            k_intercept: kb,
            log2_lambda,
            log2_moments: log2_m,
            fit_log2_lambda: (lo, hi),
            alpha: uni.map_or(nan, |u| u.alpha),
            alpha_stderr: uni.map_or(nan, |u| u.alpha_stderr),
            alpha_stderr_fit: uni.map_or(nan, |u| u.alpha_stderr),
            c1: uni.map_or(nan, |u| u.c1),
            c1_stderr: uni.map_or(nan, |u| u.c1_stderr),
            c1_stderr_fit: uni.map_or(nan, |u| u.c1_stderr),
            stderr_method: "regression residuals only (no ensemble scatter)".into(),
            universal_fit: "ols (unweighted least squares in K)".into(),
            universal_shrinkage: None,
            alpha_ols: uni.map_or(nan, |u| u.alpha),
            c1_ols: uni.map_or(nan, |u| u.c1),
            jackknife_groups: 0,
            universal_n: uni.map_or(0, |u| u.n),
            q_s,
            q_s_rule: "q_s = min(((2 + D_s)/C1)^(1/alpha), q_D), D_s = ln(images)/ln(L); universal fit over 0 < q <= q_s/2".into(),
            universal_q_max: q_hi,
            q_s_empirical,
            q_d,
            log2_lambda_eff,
            lambda_eff: log2_lambda_eff.exp2(),
            outer_scale_px: (kmax - log2_lambda_eff).exp2(),
            eta,
            dtm_q: self.config.dtm_q.clone(),
            k_eta,
            k_eta_stderr: k_eta_se,
            log2_moments_eta: log2_m_eta,
            dtm_eta_range: fc.eta,
            dtm_alpha: dtm.first().map_or(nan, |d| d.alpha),
            dtm_alpha_stderr: dtm.first().map_or(nan, |d| d.alpha_stderr),
            dtm_c1: dtm.first().map_or(nan, |d| d.c1),
            dtm_c1_stderr: nan,
            dtm,
            sf_q: self.config.sf_q.clone(),
            xi,
            xi_stderr: xi_se,
            xi_intercept: xi_b,
            log2_lag,
            log2_sf,
            fit_log2_lag: (llo, lhi),
            h: h_spec,
            h_stderr: None,
            h_sf,
            h_sf_stderr: None,
            beta,
            beta_averaged,
            beta_stderr: spec.map(|s| s.beta_stderr),
            beta_stderr_method: "regression (the spectrum's fit)".into(),
            beta_convention: "angle-integrated (beta_averaged = beta + 1)".into(),
            k_range: spec.map(|s| s.k_range),
            warnings: Vec::new(),
            surrogates: None,
        })
    }
}

/// First grid `q > 1` from which on the measured `K''` stays below a
/// quarter of the universal fit's `K''` (TM eq 15: K linear beyond q_s).
fn linear_onset(q: &[f64], k: &[f64], u: &UniversalFit) -> Option<f64> {
    let pts: Vec<(f64, f64)> = q
        .iter()
        .zip(k)
        .filter(|(_, b)| b.is_finite())
        .map(|(a, b)| (*a, *b))
        .collect();
    if pts.len() < 4 {
        return None;
    }
    let model_d2 = |x: f64| {
        if (u.alpha - 1.0).abs() < 1e-6 {
            u.c1 / x
        } else {
            u.c1 * u.alpha * x.powf(u.alpha - 2.0)
        }
    };
    let mut onset = None;
    for i in 1..pts.len() - 1 {
        let (q0, k0) = pts[i - 1];
        let (q1, k1) = pts[i];
        let (q2, k2) = pts[i + 1];
        let d2 = ((k2 - k1) / (q2 - q1) - (k1 - k0) / (q1 - q0)) / (0.5 * (q2 - q0));
        let linear = d2 < 0.25 * model_d2(q1);
        if q1 > 1.0 && linear {
            if onset.is_none() {
                onset = Some(q1);
            }
        } else {
            onset = None;
        }
    }
    onset
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

/// Merges per-image (or per-group) accumulators into the annealed ensemble
/// and finishes it, with **jackknife** standard errors over the parts when
/// there are at least 2: each part is left out in turn (same fit ranges,
/// same q range and q_s as the full ensemble), and for every estimate θ
/// `se² = (n-1)/n Σ (θ_(i) - mean θ_(.))²` (Efron & Tibshirani 1993, §11).
/// The regression errors of a single ensemble fit only see the residuals
/// of K(q) about the universal curve, whereas the K(q) of neighbouring q are
/// almost perfectly correlated and share the sampling fluctuations of the
/// ensemble: on 4 independent 16 x 1024² topo-fif ensembles α scattered by
/// 0.1 for a stated fit error of 0.003. The jackknife sees that scatter.
/// Replaced: `alpha_stderr`, `C1_stderr`, `K_stderr`, `xi_stderr`, `dtm_alpha_stderr`
/// (and the first DTM fit's), `beta_stderr`; added `H_stderr`,
/// `H_sf_stderr`. With one part the regression errors are kept and
/// `stderr_method` says so.
///
/// **Errors** with no part, parts with different settings, or as
/// [`TraceMomentAccumulator::finish`].
pub fn finish_ensemble(
    parts: &[TraceMomentAccumulator],
    fc: &TraceMomentFitConfig,
) -> Result<(TraceMomentAccumulator, TraceMomentResult)> {
    let Some(first) = parts.first() else {
        return Err(Error::Input("no image accumulated".into()));
    };
    let mut all = TraceMomentAccumulator::new(first.config.clone())?;
    for p in parts {
        all.merge(p)?;
    }
    let res = finish_jackknife(&all, parts, fc, "images")?;
    Ok((all, res))
}

/// The result of `whole` with jackknife errors over `parts` (whose merge
/// must reproduce `whole` over the fitted scales: the images of an
/// ensemble, or the tiles of [`TraceMomentAccumulator::field_tiles`];
/// `what` names them in `stderr_method`). See [`finish_ensemble`]. A block
/// jackknife over the tiles of one image treats the tiles as independent;
/// the long-range correlations of a cascade make that an underestimate of
/// the error of the single image, though far closer than the regression.
/// The universal fit is `fc.universal` (GLS by default); the `tm` command
/// fits tiles by OLS unless told otherwise (README, "Trace moments: fitting
/// alpha (GLS)": on a real DEM the two fits part by 6 errors, while on
/// synthetic universal multifractals both tile errors are about the
/// scatter).
///
/// **Errors** as [`TraceMomentAccumulator::finish`] or on parts with other
/// settings.
pub fn finish_jackknife(
    whole: &TraceMomentAccumulator,
    parts: &[TraceMomentAccumulator],
    fc: &TraceMomentFitConfig,
    what: &str,
) -> Result<TraceMomentResult> {
    let mut res = whole.finish(fc)?;
    let n = parts.len();
    if n < 2 {
        res.stderr_method = "regression residuals only (one part: no ensemble scatter; \
                             understates the error)"
            .into();
        if fc.universal == UniversalWeighting::Gls {
            res.universal_fit =
                "ols (unweighted least squares in K; gls not possible: one part)".into();
        }
        return Ok(res);
    }
    let pin = Some((res.universal_q_max, res.q_s));
    let mut loo = Vec::with_capacity(n);
    for i in 0..n {
        let mut a = TraceMomentAccumulator::new(whole.config.clone())?;
        for (j, p) in parts.iter().enumerate() {
            if j != i {
                a.merge(p)?;
            }
        }
        let fc_rep = replicate_fit(
            fc,
            &res,
            whole,
            &a,
            &format!("part {} of {n} ({what})", i + 1),
        )?;
        loo.push(a.finish_inner(&fc_rep, pin)?);
    }
    if fc.universal == UniversalWeighting::Gls {
        gls_refit(&mut res, &mut loo, whole, parts, fc, pin, what)?;
    }
    let jk = |f: &dyn Fn(&TraceMomentResult) -> f64| -> f64 {
        crate::stats::jackknife_se(&loo.iter().map(f).collect::<Vec<_>>())
    };
    res.alpha_stderr = jk(&|r| r.alpha);
    res.c1_stderr = jk(&|r| r.c1);
    res.dtm_alpha_stderr = jk(&|r| r.dtm_alpha);
    res.dtm_c1_stderr = jk(&|r| r.dtm_c1);
    for (id, d) in res.dtm.iter_mut().enumerate() {
        d.alpha_stderr = jk(&|r| r.dtm[id].alpha);
    }
    for (iq, se) in res.k_stderr.iter_mut().enumerate() {
        *se = jk(&|r| r.k[iq]);
    }
    // the structure functions' exponents likewise (a fit of 2 lags has no
    // regression error, and the printed H_sf had its jackknife one)
    for (iq, se) in res.xi_stderr.iter_mut().enumerate() {
        *se = jk(&|r| r.xi[iq]);
    }
    let opt = |f: &dyn Fn(&TraceMomentResult) -> Option<f64>| {
        let s = jk(&|r| f(r).unwrap_or(f64::NAN));
        s.is_finite().then_some(s)
    };
    // the tiles of one image share its spectrum: beta has no scatter over
    // them (only rounding), so it keeps its fit error, and H = (beta - 1 +
    // K(2)) / 2 gets half of it on top of its scatter, which is K(2)'s alone
    let shared = parts.iter().all(|p| p.spectrum == parts[0].spectrum);
    if shared {
        res.h_stderr = match res.beta_stderr {
            Some(b) => opt(&|r| r.h).map(|h| h.hypot(b / 2.0)),
            None => opt(&|r| r.h),
        };
    } else {
        res.beta_stderr = opt(&|r| r.beta);
        res.h_stderr = opt(&|r| r.h);
    }
    res.h_sf_stderr = opt(&|r| r.h_sf);
    res.stderr_method = format!("jackknife over {n} {what} (leave one out)");
    if !shared {
        res.beta_stderr_method = res.stderr_method.clone();
    }
    res.jackknife_groups = n;
    res.warnings = diagnostics(&res, Some((&loo, shared)));
    Ok(res)
}

/// The fit settings of a jackknife replicate `rep` of `whole`, whose
/// result is `res`: the whole's boxes, lags and wavenumbers. A part left out
/// may hold the only boxes of the largest size (images of several sizes),
/// and log2 λ counts from a replicate's own largest box, so its range
/// shifts by the levels it lacks; a default range would otherwise follow
/// the replicate's sizes and fit other scales.
///
/// **Errors** when the fitted boxes are missing from `rep` (`left_out`
/// names the part left out).
fn replicate_fit(
    fc: &TraceMomentFitConfig,
    res: &TraceMomentResult,
    whole: &TraceMomentAccumulator,
    rep: &TraceMomentAccumulator,
    left_out: &str,
) -> Result<TraceMomentFitConfig> {
    let kmax = whole.box_count.len().saturating_sub(1);
    let (lo, hi) = res.fit_log2_lambda;
    let d = kmax.saturating_sub(rep.box_count.len().saturating_sub(1)) as f64;
    lone_box_check(kmax, lo, d, left_out)?;
    // the lags the whole fitted (fluxes given directly have no structure
    // functions; a range reaching beyond the whole's lags fits those it has,
    // and one holding fewer than 2 fits none, which pins nothing)
    let log2_lag = match fitted_lags(res.fit_log2_lag, whole.sf_count.len()) {
        Some(r) if !res.log2_lag.is_empty() => {
            lone_lag_check(r.1, rep.sf_count.len(), left_out)?;
            Some(r)
        }
        _ => fc.log2_lag,
    };
    Ok(TraceMomentFitConfig {
        // levels below 0 do not exist: a fractional start stays on the same
        // integer levels
        log2_lambda: Some(((lo - d).max(0.0), hi - d)),
        log2_lag,
        k_range: res.k_range.or(fc.k_range),
        ..fc.clone()
    })
}

/// The part of a lag range `(lo, hi)` (log2 l) on the `nj` lags `0..nj`
/// that holds 2 lags or more, `None` if it holds fewer.
fn fitted_lags((lo, hi): (f64, f64), nj: usize) -> Option<(f64, f64)> {
    let hi = hi.min(nj as f64 - 1.0);
    ((hi - lo.ceil()) >= 1.0 - 1e-9).then_some((lo, hi))
}

/// How many standard errors a diagnostic of [`diagnostics`] needs before
/// it speaks: a two-sided false alarm of 0.3 % for normal errors.
pub const WARN_Z: f64 = 3.0;

/// Factor on jackknife errors over the tiles of an image in
/// [`diagnostics`]: tiles are treated as independent and their errors
/// understate, the rms jackknife error over the scatter between single
/// topo-fif fields being 0.36-0.87 (module docs, "Errors"), 0.49-0.75 for
/// the bend of the moment lines at q = 0.5-2 on 400², where the undoubled
/// 3-error rule flagged 3-6 of 24 fields at each q
/// (`experiment_curvature_calibration`). Doubled, they are about the
/// scatter or above it.
pub const TILE_ERROR_FACTOR: f64 = 2.0;

/// The diagnostics of a result `r` (its `warnings`), given the
/// leave-one-out results `loo` of its jackknife and whether its parts were
/// tiles (`None`: no jackknife; the regression errors then stand in). Each
/// speaks beyond [`WARN_Z`] errors (for 2., 3. and 4., tile errors times
/// [`TILE_ERROR_FACTOR`]):
/// 1. the spectral H above what the differentiation resolves: 1 with
///    [`FluxDiff::Auto`] (its order ξ(1) comes from first differences, which
///    saturate at 1, so for H > 1 the excess order falls below 1: module
///    docs, "Which flux"), `1 + order` otherwise (TM §5.2: the flux
///    needs a differentiation of order H or more);
/// 2. else the spectral H and `H_sf = ξ(1)` apart (both estimate H:
///    `ξ(1) = H - K(1) = H`, TM eq 10), the error that of their
///    difference (jackknifed as a difference: the two share the tiles);
///    with 5. said, it names the plane;
/// 3. with a jackknife, moment lines `log2 <φ_λ^q>` curved over the fitted
///    scales, at the q of the universal fit (beyond `q_s/2` the sampling
///    bends them anyway, TM eq 15): the change of their local slope
///    across the fit range ([`crate::stats::fit::slope_change`], as the
///    WTMM spectra's straightness check) against its jackknife error, the
///    false alarm of [`WARN_Z`] shared among the q tested (Bonferroni). The
///    threshold is the statistics' own: the WTMM check's fixed 0.2 is the
///    tolerance of published tau(q), and K(q) has no such scale;
/// 4. with a GLS universal fit, its alpha and the OLS fit's apart, against
///    the jackknife error of their difference: K(q) not of the universal
///    form over the fitted q, so alpha depends on the weighting;
/// 5. (said before 2.) without detrending, fields whose plane explains
///    more than [`crate::spectra::PLANE_SHARE_WARN`] of their variance,
///    whose removal would move `H_sf`
///    ([`TraceMomentResult::h_sf_plane_shift`]) by more than its error
///    (0.01 without one): the numbers, with the spectral H as a guide,
///    not a verdict: a tilt and a rough surface's own large scales both
///    make planes (8 untilted fBm of 512², H = 0.8: `H_sf` 0.776 would
///    drop to about 0.758, away from the spectral 0.823).
///
/// Then the range checks, whatever the errors: alpha at an end of the
/// fit's search interval (no minimum) or outside the universal [0, 2], C1
/// below or indistinguishable from 0, and β, H, the DTM or `H_sf` left
/// without a fit by their ranges.
///
/// Measured (`experiment_lone_image_tiles` in tests/tracemoments.rs): on 24
/// single topo-fif fields, 1, 1 and 2 of them got a straightness warning at
/// 256², 400² and 512², 1, 0 and 1 an H disagreement, none the first; an
/// fBm gets the straightness warning, rightly (its flux is no cascade: box
/// averages converge like sums of nearly independent values, no power law).
pub fn diagnostics(
    r: &TraceMomentResult,
    loo: Option<(&[TraceMomentResult], bool)>,
) -> Vec<String> {
    let mut w = Vec::new();
    let factor = match loo {
        Some((_, true)) => TILE_ERROR_FACTOR,
        _ => 1.0,
    };
    let jk = |f: &dyn Fn(&TraceMomentResult) -> f64| {
        loo.map_or(f64::NAN, |(l, _)| {
            crate::stats::jackknife_se(&l.iter().map(f).collect::<Vec<_>>())
        })
    };
    // 0. no universal fit: say why, as the CLI refuses such a q grid
    if !r.alpha.is_finite() {
        let usable =
            r.q.iter()
                .filter(|&&q| q > 0.0 && q <= FIRST_UNIVERSAL_Q_MAX)
                .count();
        w.push(format!(
            "alpha and C1 are not estimated: the universal fit starts over \
             0 < q <= {FIRST_UNIVERSAL_Q_MAX} and needs 3 or more orders there ({usable} given{})",
            if usable >= 3 {
                "; or fewer than 3 below q_fit_max or q_s/2"
            } else {
                ""
            }
        ));
    }
    let half_beta = r.beta_stderr.map_or(0.0, |b| b / 2.0);
    let d = r.diff_order;
    let fix = |h: f64| format!("--diff-order {h:.2} (FluxDiff::Order in the library)");
    // 1. the differentiation against the spectral H
    let mut too_smooth = false;
    if let Some(h) = r.h {
        // the error as reported, not doubled for tiles: near H = 1 a false
        // alarm costs nothing (the order it advises, H, is the one auto
        // aims at), a missed one biases K; without a jackknife, the
        // spectrum fit's share of the error alone
        let se = r.h_stderr.unwrap_or(half_beta);
        let bound = match r.diff {
            FluxDiff::Auto | FluxDiff::None => 1.0,
            FluxDiff::Order(o) => 1.0 + o,
        };
        let z = (h - bound) / se;
        if se > 0.0 && z > WARN_Z {
            too_smooth = true;
            let hsf = r.h_sf.map_or("n/a".into(), |v| format!("{v:.3}"));
            w.push(match r.diff {
                FluxDiff::Auto => format!(
                    "the spectral H = {h:.3} exceeds 1 by {z:.1} errors of {se:.3}: first \
                     differences cannot resolve H > 1 (H_sf = xi(1) = {hsf} saturates), so the \
                     automatic differentiation (--diff-order auto, of order xi(1) = {d:.3}) is \
                     too low: it leaves the modulus 1 + {d:.3} - H = {e:.2} orders in excess of \
                     H instead of 1 (TM §5.2), which biases K(q), alpha and C1; give the \
                     order: {f}",
                    e = 1.0 + d - h,
                    f = fix(h)
                ),
                _ => format!(
                    "the spectral H = {h:.3} exceeds {bound:.3}, the order of the flux's \
                     differentiation (the modulus' 1 plus {d}), by {z:.1} errors of {se:.3}: \
                     the modulus acts on a fractional integral of the flux, not on the flux \
                     (TM §5.2 asks for an order H or more); give {f}",
                    f = fix(h)
                ),
            });
        }
    }
    // 5. (said first: 2. refers to it) planes that move H_sf by more than
    // its error: the numbers, not a verdict (a tilt and a rough surface's
    // own large scales both make planes, and one image cannot tell them
    // apart; the spectral H, whose spectrum removes a plane, is a guide)
    let plane = match (r.h_sf, r.h_sf_plane_shift) {
        (Some(hsf), Some(e))
            if r.detrend == Trend::None
                && e > r.h_sf_stderr.filter(|s| s.is_finite()).unwrap_or(0.01) =>
        {
            let k = r.planes_over_half;
            w.push(format!(
                "the least-squares plane explains more than half the variance of {}: without \
                 {} H_sf = xi(1) = {hsf:.3} would read about {:.3}{}. A regional slope \
                 c adds c l to every increment at lag l{}, but a rough surface's own large \
                 scales make planes too, and removing those lowers H_sf: for a tilted \
                 surface rerun with --detrend plane (TraceMomentConfig::detrend), otherwise \
                 keep the planes",
                if r.images == 1 {
                    "the image".to_string()
                } else {
                    format!("{k} of the {} images", r.images)
                },
                if r.images == 1 {
                    "its plane"
                } else {
                    "their planes"
                },
                hsf - e,
                r.h.map_or(String::new(), |h| format!(
                    " (the spectral H, whose spectrum removes a plane of its own: {h:.3})"
                )),
                if r.diff == FluxDiff::Auto {
                    " and raises the automatic --diff-order"
                } else {
                    ""
                }
            ));
            true
        }
        _ => false,
    };
    // 2. the two estimates of H (1. already says why they part when H > 1)
    if let (Some(h), Some(hsf), false) = (r.h, r.h_sf, too_smooth) {
        let diff = |x: &TraceMomentResult| x.h.unwrap_or(f64::NAN) - x.h_sf.unwrap_or(f64::NAN);
        let se = factor
            * match loo {
                // tiles share the spectrum: its fit error comes on top
                Some((_, true)) => jk(&diff).hypot(half_beta),
                Some((_, false)) => jk(&diff),
                None => {
                    let i = r.sf_q.iter().position(|&q| (q - 1.0).abs() < 1e-12);
                    i.map_or(f64::NAN, |i| r.xi_stderr[i]).hypot(half_beta)
                }
            };
        let z = (h - hsf) / se;
        if se > 0.0 && z.abs() > WARN_Z {
            let why = if h > hsf && h > 1.0 {
                ": first differences saturate, and H_sf cannot follow an H above 1".to_string()
            } else if plane {
                ": the plane (the warning above) may be why".to_string()
            } else {
                // finite-range biases of the two estimators on FIF fields
                // of 1024^2 (helper study 2026-11-29, 6-12 ensembles per H):
                // the generator's pixel-scale spectrum steepens beta (exact
                // expectation 2.2069 against 2.1777 at H = 0.7), and xi(1)
                // of first differences bends with the lag; neither is a
                // defect, and the jackknife errors resolve them
                ": a fit range misses the scaling of the spectrum or of the structure \
                 functions (--k-range, --lag-fit), or the two estimators' finite-range \
                 biases part them, which no fit range removes (on universal multifractal \
                 fields of 1024^2 the spectral H less H_sf reads -0.01 at H = 0.4, +0.04 \
                 at 0.7, +0.12 at 0.95)"
                    .to_string()
            };
            let auto = if r.diff == FluxDiff::Auto {
                format!(
                    "; the automatic differentiation follows xi(1): if the spectral H is the \
                     right one, give {}",
                    fix(h)
                )
            } else {
                String::new()
            };
            w.push(format!(
                "the spectral H = {h:.3} and H_sf = xi(1) = {hsf:.3} differ by {:+.3}, {:.1} \
                 errors of {se:.3}, though both estimate H (xi(1) = H - K(1) = H, TM eq \
                 10){why}{auto}",
                h - hsf,
                z.abs(),
            ));
        }
    }
    // 3. straightness of the moment lines over the fitted scales
    if let Some((l, _)) = loo {
        let (lo, hi) = r.fit_log2_lambda;
        let change = |x: &TraceMomentResult, iq: usize| {
            let (xs, ys): (Vec<f64>, Vec<f64>) = x
                .log2_lambda
                .iter()
                .zip(&x.log2_moments[iq])
                .filter(|(a, _)| **a >= lo - 1e-9 && **a <= hi + 1e-9)
                .map(|(a, b)| (*a, *b))
                .unzip();
            crate::stats::fit::slope_change(&xs, &ys).unwrap_or(f64::NAN)
        };
        // (change, error) per q of the universal fit
        let tested: Vec<Option<(f64, f64)>> = (0..r.q.len())
            .map(|iq| {
                if !(r.q[iq] > 0.0 && r.q[iq] <= r.universal_q_max + 1e-9) {
                    return None;
                }
                let c = change(r, iq);
                let loo_c: Vec<f64> = l.iter().map(|x| change(x, iq)).collect();
                let se = factor * crate::stats::jackknife_se(&loo_c);
                (c.is_finite() && se > 0.0).then_some((c, se))
            })
            .collect();
        // every q is a test: the false alarm of WARN_Z shared among them
        // (Bonferroni; 3.9 errors for 25 q), else one q in a long grid
        // would speak by chance (the 3-error rule flagged 3-4 of 24 single
        // topo-fif fields)
        let m = tested.iter().flatten().count().max(1) as f64;
        let z_m =
            statrs::distribution::Normal::standard().inverse_cdf(1.0 - normal_tail(WARN_Z) / m);
        let bent: Vec<Option<(f64, f64)>> = tested
            .iter()
            .map(|t| t.and_then(|(c, se)| (c.abs() > z_m * se).then_some((c, c.abs() / se))))
            .collect();
        for (first, last, worst) in
            crate::stats::fit::flagged_runs(&bent, |x: (f64, f64)| x.0.abs())
        {
            let (c, z) = bent[worst].unwrap_or((f64::NAN, f64::NAN));
            // the grid's q to 6 decimals (0.30000000000000004 reads 0.3)
            let qs = |i: usize| format!("{}", (r.q[i] * 1e6).round() / 1e6);
            let (label, most) = if last > first {
                (
                    format!("q = {} .. {}", qs(first), qs(last)),
                    format!("up to {c:+.3} (at q = {}, {z:.1} errors)", qs(worst)),
                )
            } else {
                (
                    format!("q = {}", qs(first)),
                    format!("{c:+.3} ({z:.1} errors)"),
                )
            };
            w.push(format!(
                "{label}: log2 <phi_lambda^q> is not a straight line over the fitted scales \
                 (log2 lambda {lo}..{hi}): its local slope changes by {most} across them, so \
                 K(q), and alpha and C1 with it, depend on the scales fitted (--lambda-fit)"
            ));
        }
    }
    // 4. the GLS and OLS universal fits apart: both fit C1/(α-1) (q^α - q)
    // to the same K(q), so they part beyond their paired error when K(q)
    // departs from that form and the weighting picks which q it follows
    // (Jacksboro DEM, 6 tiles: 10 errors; two-point cascades: 5.0-9.5).
    // On universal fields the difference read -0.6..1.6 errors (6 topo-fif
    // ensembles of 16 x 256^2) and -0.6..2.7 (8 log-normal cascade
    // ensembles, mean +0.8: the two fits' small biases differ, which a very
    // large ensemble would resolve; hence the message's second reading),
    // those with q = 1 still in the GLS fit; after, none of 12 topo-fif
    // ensembles of 16 x 1024^2 reached 3
    if let Some((l, _)) = loo
        && r.universal_fit.starts_with("gls")
        && r.alpha.is_finite()
        && r.alpha_ols.is_finite()
    {
        let d = r.alpha - r.alpha_ols;
        let se = factor
            * crate::stats::jackknife_se(
                &l.iter().map(|x| x.alpha - x.alpha_ols).collect::<Vec<_>>(),
            );
        if se > 0.0 && (d / se).abs() > WARN_Z {
            w.push(format!(
                "the GLS universal fit gives alpha = {:.3}, the unweighted (OLS) one {:.3}, \
                 {:+.3} apart, {:.1} errors of their difference: K(q) departs from the \
                 universal form over the fitted q, so alpha depends on which q the fit weighs \
                 (--universal-fit, --q-fit-max; on a very large ensemble of a universal field \
                 the two fits' small biases can also part)",
                r.alpha,
                r.alpha_ols,
                d,
                (d / se).abs()
            ));
        }
    }
    w.extend(range_warnings(r));
    w
}

/// Estimates outside what the fits can deliver, said in `warnings` after
/// [`diagnostics`]' tests: alpha at an end of the fit's search interval
/// (no minimum: K(q) is not of the universal form, e.g. the flux of a
/// plane) or outside the universal range [0, 2] (TM §6), C1 < 0 or not
/// distinguishable from 0 (then alpha, the shape of K(q), is free), and
/// the estimates a fit range left empty (β and H, the DTM, `H_sf`).
fn range_warnings(r: &TraceMomentResult) -> Vec<String> {
    let mut w = Vec::new();
    let (lo, hi) = fit::ALPHA_SEARCH;
    // a NaN alpha is explained by diagnostics' item 0
    if r.alpha.is_finite() && (r.alpha - lo < 1e-3 || hi - r.alpha < 1e-3) {
        w.push(format!(
            "alpha = {:.3} sits at an end of the universal fit's search interval [{lo}, {hi}]: \
             no minimum was found, so K(q) is not of the universal form C1/(alpha-1) \
             (q^alpha - q) over the fitted q (a smooth or planar field, moments beyond the \
             sampling order q_s = {:.2}, too few scales or images): alpha and C1 are not \
             estimates",
            r.alpha, r.q_s
        ));
    } else if outside_universal(r.alpha, r.alpha_stderr) {
        w.push(format!(
            "alpha = {:.3} +- {:.3} lies outside [0, 2], the range of universal \
             multifractals, by more than 2 errors: K(q) is not of the universal form over the \
             fitted q, or too few scales or images for the fit",
            r.alpha, r.alpha_stderr
        ));
    }
    if r.c1.is_finite() && r.c1 < 0.0 {
        w.push(format!(
            "C1 = {:.4} < 0: no intermittency is resolved",
            r.c1
        ));
    } else if r.c1.is_finite()
        && (r.c1 <= 2.0 * r.c1_stderr || r.k.iter().all(|k| !k.is_finite() || k.abs() < 1e-9))
    {
        // K(q) = C1 x shape(alpha): with C1 ~ 0 the shape, alpha, is free
        w.push(format!(
            "C1 = {:.4} +- {:.4} is not distinguishable from 0 (its error is half of it or \
             more: the intermittency is not resolved), so alpha, the shape of K(q), is \
             undetermined: do not quote it",
            r.c1, r.c1_stderr
        ));
    }
    if r.beta.is_none() {
        w.push(
            "beta and H not estimable: fewer than 3 spectrum bins in the k range \
             (images too small for the default range, or a --k-range holding too few)"
                .to_string(),
        );
    }
    for d in r.dtm.iter().filter(|d| d.n < 3) {
        w.push(format!(
            "DTM at q = {}: {} usable eta value(s) (K(q, eta) of the sign of K(q), eta in the \
             fit range, q eta <= q_s/2): {}",
            d.q,
            d.n,
            if d.n < 2 {
                "no fit (--eta, --eta-fit)"
            } else {
                "a line through two points"
            }
        ));
    }
    if outside_universal(r.dtm_alpha, r.dtm_alpha_stderr) {
        w.push(format!(
            "DTM alpha = {:.3} +- {:.3} lies outside [0, 2] by more than 2 errors: too few \
             scales or images",
            r.dtm_alpha, r.dtm_alpha_stderr
        ));
    }
    if r.h_sf.is_none() && r.sf_q.iter().any(|&q| (q - 1.0).abs() < 1e-12) {
        w.push(
            "H_sf = xi(1) not estimable: no line through the structure function of order 1 \
             over the lag fit range (--lag-fit)"
                .to_string(),
        );
    }
    w
}

/// True when `alpha` lies outside the universal [0, 2] (TM §6) by more
/// than 2 of its errors (by any amount without an error): a log-normal
/// field's estimates scatter either side of 2 (6 of 12 single 128^2 FIF
/// with alpha = 2 read 2.005-2.025, within one error, and were warned
/// about before).
fn outside_universal(alpha: f64, se: f64) -> bool {
    let se = if se.is_finite() { se } else { 0.0 };
    alpha.is_finite() && (alpha > 2.0 + 2.0 * se || alpha < -2.0 * se)
}

/// `P(Z > z)` for a standard normal `Z`.
fn normal_tail(z: f64) -> f64 {
    1.0 - statrs::distribution::Normal::standard().cdf(z)
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

/// The q indices of the universal fit: `0 < q <= q_hi` (and `q_fit_max`),
/// as in [`TraceMomentAccumulator::finish`].
fn universal_indices(q: &[f64], q_hi: f64, fc: &TraceMomentFitConfig) -> Vec<usize> {
    let qcap = fc.q_fit_max.unwrap_or(f64::INFINITY);
    q.iter()
        .enumerate()
        .filter(|(_, a)| **a > 0.0 && **a < q_hi + 1e-12 && **a <= qcap + 1e-12)
        .map(|(i, _)| i)
        .collect()
}

/// Sets α and C1 of `r` (and what follows from them: the spectral H, q_D,
/// the empirical q_s) from the universal fit `u`.
fn apply_universal(r: &mut TraceMomentResult, u: &UniversalFit) {
    r.alpha = u.alpha;
    r.c1 = u.c1;
    r.alpha_stderr_fit = u.alpha_stderr;
    r.c1_stderr_fit = u.c1_stderr;
    r.universal_n = u.n;
    r.q_d = UniversalK::new(u.alpha.min(2.0), u.c1.max(0.0)).q_divergence(D);
    r.q_s_empirical = linear_onset(&r.q, &r.k, u);
    let k2 = u.c1 * universal_shape(u.alpha, 2.0);
    r.h = r.beta.map(|b| (b - 1.0 + k2) / 2.0);
}

/// Inverse of the shrunk jackknife covariance of K over `idx`, from the
/// leave-one-out results `reps` (`(W, λ)`; `Err` says why not).
fn gls_weights(
    reps: &[TraceMomentResult],
    idx: &[usize],
) -> std::result::Result<(Vec<Vec<f64>>, f64), &'static str> {
    let v: Vec<Vec<f64>> = reps
        .iter()
        .map(|r| idx.iter().map(|&i| r.k[i]).collect())
        .collect();
    let sc = jackknife_covariance_shrunk(&v).ok_or("K(q) without jackknife scatter")?;
    let w = spd_inverse(&sc.cov).ok_or("covariance not positive definite")?;
    Ok((w, sc.lambda))
}

/// The generalised-least-squares universal fit (module docs, "Universal
/// fit"). The weight matrix is the inverse of the jackknife covariance of
/// K(q) over the fitted q, correlations shrunk by the Schäfer-Strimmer
/// intensity; the whole ensemble is fitted with the one from the
/// leave-one-out results `loo`. For honest errors the weights are
/// re-estimated inside every leave-one-out sample from its own n - 1
/// leave-one-out samples (a nested jackknife, n(n-1) finishes): held fixed,
/// they would be tuned to the very fluctuations the jackknife should see
/// (on 11 topo-fif ensembles the fixed-weight error was 0.027 against a
/// scatter of 0.043, nested 0.047, with q = 1 still in the fit and the
/// mirrored flux; now nested 0.041 against 0.039). Keeps the OLS fit (and says why in
/// `universal_fit`) with fewer than 5 parts, fewer than 3 q values besides q = 1, or a
/// covariance that cannot be inverted.
fn gls_refit(
    res: &mut TraceMomentResult,
    loo: &mut [TraceMomentResult],
    whole: &TraceMomentAccumulator,
    parts: &[TraceMomentAccumulator],
    fc: &TraceMomentFitConfig,
    pin: Option<(f64, f64)>,
    what: &str,
) -> Result<()> {
    let n = parts.len();
    // q = 1 is left out: the universal K and both its derivatives vanish
    // there (TM eq 8), so its only effect would be through the covariance,
    // as a control variate on K(1) - 0. That residual is no fluctuation of
    // the fitted parameters: rounding on a torus, where K(1) = 0 in every
    // sample (its variance ~1e-33 got weights ~1e33; alpha moved by 0.009
    // when the fields were scaled), and the edge boxes' drift on a plane.
    // OLS is unchanged by the point (zero Jacobian).
    let fitted = universal_indices(&res.q, res.universal_q_max, fc);
    let is_one = |i: usize| (res.q[i] - 1.0).abs() <= 1e-9;
    let without_one = if fitted.iter().any(|&i| is_one(i)) {
        ", q = 1 left out"
    } else {
        ""
    };
    let idx: Vec<usize> = fitted
        .into_iter()
        .filter(|&i| !is_one(i))
        .filter(|&i| res.k[i].is_finite() && loo.iter().all(|r| r.k[i].is_finite()))
        .collect();
    let fallback = |res: &mut TraceMomentResult, why: &str| {
        res.universal_fit = format!("ols (unweighted least squares in K; gls not possible: {why})");
        Ok(())
    };
    if n < 5 {
        return fallback(res, "fewer than 5 jackknife parts");
    }
    if idx.len() < 3 {
        return fallback(res, &format!("fewer than 3 fitted q values{without_one}"));
    }
    let q: Vec<f64> = idx.iter().map(|&i| res.q[i]).collect();
    let fit = |r: &TraceMomentResult, w: &[Vec<f64>]| {
        let k: Vec<f64> = idx.iter().map(|&i| r.k[i]).collect();
        fit_universal_gls(&q, &k, w)
    };
    let (w, lambda) = match gls_weights(loo, &idx) {
        Ok(x) => x,
        Err(why) => return fallback(res, why),
    };
    let Some(u) = fit(res, &w) else {
        return fallback(res, "fit failed");
    };
    // nested: the weights of leave-one-out sample i from its own jackknife
    let inner: Vec<Result<Vec<TraceMomentResult>>> = (0..n)
        .into_par_iter()
        .map(|i| {
            let mut out = Vec::with_capacity(n - 1);
            for j in (0..n).filter(|&j| j != i) {
                let mut a = TraceMomentAccumulator::new(whole.config.clone())?;
                for (m, p) in parts.iter().enumerate() {
                    if m != i && m != j {
                        a.merge(p)?;
                    }
                }
                let fc_rep = replicate_fit(
                    fc,
                    res,
                    whole,
                    &a,
                    &format!("parts {} and {} of {n}", i + 1, j + 1),
                )?;
                out.push(a.finish_inner(&fc_rep, pin)?);
            }
            Ok(out)
        })
        .collect();
    let mut lu = Vec::with_capacity(n);
    for (r, inn) in loo.iter().zip(inner) {
        let inn = match inn {
            // two parts left out may take every box of the fitted range
            // (replicate_fit): the plain jackknife stands, unweighted
            Err(Error::Param { .. }) => {
                return fallback(
                    res,
                    "a nested jackknife sample lacks the fitted boxes or lags",
                );
            }
            inn => inn?,
        };
        let x = gls_weights(&inn, &idx).ok().and_then(|(wi, _)| fit(r, &wi));
        match x {
            Some(x) => lu.push(x),
            None => return fallback(res, "no fit on a jackknife sample"),
        }
    }
    apply_universal(res, &u);
    for (r, x) in loo.iter_mut().zip(&lu) {
        apply_universal(r, x);
    }
    res.universal_fit = format!(
        "gls (jackknife covariance of K(q) over {n} {what}, {} q values{without_one}, correlations shrunk by lambda = {lambda:.3}; errors by a nested jackknife)",
        idx.len(),
    );
    res.universal_shrinkage = Some(lambda);
    Ok(())
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

#[cfg(test)]
mod tests {
    use super::*;

    /// alpha is warned about beyond [0, 2] only by more than 2 of its
    /// errors (a log-normal field's 2.013 +- 0.139 is no anomaly), by any
    /// amount without an error.
    #[test]
    fn alpha_beyond_the_universal_range_by_its_errors() {
        assert!(!outside_universal(2.013, 0.139));
        assert!(!outside_universal(1.0, 0.1));
        assert!(outside_universal(2.5, 0.1));
        assert!(outside_universal(2.01, f64::NAN));
        assert!(outside_universal(-0.3, 0.1));
        assert!(!outside_universal(f64::NAN, 0.1));
    }

    /// A q grid the universal fit cannot use gives K(q), no alpha, and a
    /// warning saying why; an unsorted or repeated grid is refused.
    #[test]
    fn q_grids_the_universal_fit_cannot_use_are_said() {
        let f = Field::new(
            crate::synth::fbm::fbm(crate::synth::fbm::FbmParams { hurst: 0.5 }, 64, 64, 1, 0)
                .unwrap(),
        );
        let cfg = TraceMomentConfig {
            q: vec![0.5, 2.5, 3.0],
            ..Default::default()
        };
        let mut acc = TraceMomentAccumulator::new(cfg).unwrap();
        acc.add_field(&f).unwrap();
        let r = acc.finish(&TraceMomentFitConfig::default()).unwrap();
        assert!(r.k.iter().all(|k| k.is_finite()));
        assert!(r.alpha.is_nan());
        assert!(
            r.warnings
                .iter()
                .any(|w| w.contains("needs 3 or more orders there (1 given)")),
            "{:?}",
            r.warnings
        );
        for q in [vec![1.0, 0.5, 2.0], vec![0.5, 0.5, 1.0]] {
            let cfg = TraceMomentConfig {
                q,
                ..Default::default()
            };
            let e = TraceMomentAccumulator::new(cfg).unwrap_err().to_string();
            assert!(e.contains("ascending"), "{e}");
        }
    }

    /// `analyze_tiled` is the tile recipe written out: tiles of the largest
    /// fitted box, pooled, jackknifed; with the warnings a lone image needs.
    #[test]
    fn analyze_tiled_is_the_tile_recipe() {
        let f = Field::new(
            crate::synth::fif::fif(&crate::synth::fif::FifParams::TOPO, 256, 256, 5, 0).unwrap(),
        );
        let cfg = TraceMomentConfig::default();
        let fc = TraceMomentFitConfig {
            universal: UniversalWeighting::Ols,
            ..Default::default()
        };
        // 256 px, fit from log2 λ = 1: blocks of 128 px
        assert_eq!(tile_side(256, &fc), 128);
        assert_eq!(tile_side(8, &fc), 8);
        let (whole, res) = analyze_tiled(std::slice::from_ref(&f), &cfg, &fc).unwrap();
        let (w, t) = TraceMomentAccumulator::field_tiles(&cfg, &f, 128).unwrap();
        let (w, t) = pool_tiles(vec![(w, t)]).unwrap();
        let label = tiles_label(&tile_bounds(256, 256, 128), 128);
        assert_eq!(label, "tiles of 128 px (covering every pixel)");
        let mut want = finish_jackknife(&w, &t, &fc, &label).unwrap();
        assert_eq!(whole.images, w.images);
        assert_eq!(res.k, want.k);
        assert_eq!(res.alpha_stderr, want.alpha_stderr);
        assert_eq!(res.stderr_method, want.stderr_method);
        // 4 tiles: 3 degrees of freedom, and what tiles cannot see
        want.warnings.extend(crate::stats::fit::few_groups_warning(
            4,
            "a jackknife over 4 tiles of one image",
        ));
        want.warnings.push(TILE_CAVEAT.to_string());
        assert_eq!(res.warnings, want.warnings);
        assert!(analyze_tiled(&[], &cfg, &fc).is_err());
    }

    /// A fit range beyond the image's scales is refused from the sizes,
    /// before any moment: a constant image, which the moments would refuse,
    /// gets the range error, and an accepted range is the one `finish` uses.
    #[test]
    fn lambda_fit_is_checked_before_the_moments() {
        let flat = Field::new(Array2::from_elem((256, 256), 1.0));
        assert_eq!(box_levels(256), 8);
        assert_eq!(box_levels(300), 8);
        assert_eq!(box_levels(0), 0);
        let cfg = TraceMomentConfig::default();
        for (r, why) in [
            ((0.0, 9.0), "goes beyond the scales"),
            ((-1.0, 4.0), "goes beyond the scales"),
            ((6.5, 8.0), "fewer than 3 scales"),
        ] {
            let fc = TraceMomentFitConfig {
                log2_lambda: Some(r),
                ..Default::default()
            };
            for e in [
                analyze_tiled(std::slice::from_ref(&flat), &cfg, &fc).unwrap_err(),
                analyze(&flat, cfg.clone(), &fc).unwrap_err(),
            ] {
                assert!(
                    matches!(e, Error::Param { .. }) && e.to_string().contains(why),
                    "{r:?}: {e}"
                );
            }
        }
        // the default and a valid range pass the check; the constant image
        // is then refused by the moments
        let fc = TraceMomentFitConfig::default();
        assert_eq!(fc.lambda_range(8).unwrap(), (1.0, 7.0));
        assert_eq!(fc.lambda_range(3).unwrap(), (0.0, 3.0));
        assert!(fc.lambda_range(1).is_err());
        let e = analyze(&flat, cfg.clone(), &fc).unwrap_err();
        assert!(matches!(e, Error::Input(_)), "{e}");
        // an image too small for any moment is said to be so, not blamed on
        // a fit range nobody gave
        let tiny = Field::new(Array2::from_shape_fn((3, 64), |(y, x)| (x * y) as f64));
        for e in [
            analyze(&tiny, cfg.clone(), &fc).unwrap_err(),
            analyze_tiled(std::slice::from_ref(&tiny), &cfg, &fc).unwrap_err(),
        ] {
            assert!(e.to_string().contains("too small"), "{e}");
        }
        // non-square, and two sizes: the larger's smaller side sets kmax
        let wide = Field::new(Array2::from_shape_fn((40, 300), |(y, x)| {
            ((x * 7 + y * 3) % 11) as f64
        }));
        let fc9 = TraceMomentFitConfig {
            log2_lambda: Some((0.0, 6.0)),
            ..Default::default()
        };
        // 40 px: log2 λ up to 5
        let e = analyze(&wide, cfg.clone(), &fc9).unwrap_err();
        assert!(e.to_string().contains("runs from 0 to 5"), "{e}");
        let big = Field::new(Array2::from_shape_fn((70, 64), |(y, x)| {
            ((x * 5 + y * 9) % 13) as f64
        }));
        // (0, 6) passes the sizes (64 px), but only the 70 x 64 image holds
        // 64-px boxes: its replicate cannot leave it out
        let e = analyze_tiled(&[wide.clone(), big.clone()], &cfg, &fc9).unwrap_err();
        assert!(
            e.to_string().contains("so a jackknife cannot leave it out"),
            "{e}"
        );
        let fc7 = TraceMomentFitConfig {
            log2_lambda: Some((0.0, 7.0)),
            ..Default::default()
        };
        let e = analyze_tiled(&[wide, big], &cfg, &fc7).unwrap_err();
        assert!(e.to_string().contains("runs from 0 to 6"), "{e}");
    }

    /// The check from the sizes alone refuses exactly the fits that
    /// [`finish_ensemble`] refuses after the moments, with the same reason.
    #[test]
    fn ensemble_fit_is_checked_from_the_sizes() {
        let cfg = TraceMomentConfig::default();
        let field = |side: usize, i: u64| {
            let p = crate::synth::fbm::FbmParams { hurst: 0.5 };
            Field::new(crate::synth::fbm::fbm(p, side, side, 7, i).unwrap())
        };
        let mut refused = 0;
        for sides in [
            vec![64, 64, 64],
            vec![64, 64, 128],
            vec![32, 32, 128],
            vec![32, 128, 128],
            vec![16, 16, 16, 16, 16, 128],
        ] {
            let parts: Vec<TraceMomentAccumulator> = sides
                .iter()
                .enumerate()
                .map(|(i, &n)| {
                    let mut a = TraceMomentAccumulator::new(cfg.clone()).unwrap();
                    a.add_field(&field(n, i as u64)).unwrap();
                    a
                })
                .collect();
            let shapes: Vec<[usize; 2]> = sides.iter().map(|&n| [n, n]).collect();
            let ranges = [None, Some((0.0, 4.0)), Some((1.0, 5.0)), Some((2.0, 5.0))];
            let lags = [None, Some((1.0, 2.0)), Some((0.0, 5.0))];
            for (range, lag) in ranges.into_iter().flat_map(|r| lags.map(|l| (r, l))) {
                for universal in [UniversalWeighting::Ols, UniversalWeighting::Gls] {
                    let fc = TraceMomentFitConfig {
                        log2_lambda: range,
                        log2_lag: lag,
                        universal,
                        ..Default::default()
                    };
                    let early = check_ensemble_fit(&fc, &shapes);
                    let late = finish_ensemble(&parts, &fc);
                    let what = format!("{sides:?} {range:?} {lag:?} {universal:?}");
                    match (early, late) {
                        (Ok(()), Ok(_)) => {}
                        (Err(e), Err(l)) => {
                            refused += 1;
                            let (e, l) = (e.to_string(), l.to_string());
                            // the same reason (the late one names the part)
                            let tail = |m: &str| m.split(" holds").last().unwrap().to_string();
                            assert_eq!(tail(&e), tail(&l), "{what}: {e} / {l}");
                        }
                        (e, l) => panic!("{what}: early {e:?}, late {:?}", l.err()),
                    }
                }
            }
        }
        // lone largest boxes (64 px of 128 under the default range, and
        // explicit ranges from 0 or 1 with 32-px neighbours), lone lags
        // (16 px under the default lag range beside 32-px images, whose
        // lags end at 8 px) and ranges beyond the data are among them;
        // lags up to 4 px pass there
        assert!(refused >= 8, "{refused}");
        let fc = |lag| TraceMomentFitConfig {
            log2_lambda: Some((2.0, 5.0)),
            log2_lag: lag,
            ..Default::default()
        };
        let mixed = [[32, 32], [32, 32], [128, 128]];
        let e = check_ensemble_fit(&fc(None), &mixed).unwrap_err();
        assert!(e.to_string().contains("lags of 16 px"), "{e}");
        assert!(check_ensemble_fit(&fc(Some((1.0, 2.0))), &mixed).is_ok());
        let e = check_ensemble_fit(&fc(Some((0.0, 6.0))), &mixed).unwrap_err();
        assert!(e.to_string().contains("goes beyond the lags"), "{e}");
        // no size, nothing to check; a bad range still is
        assert!(check_ensemble_fit(&TraceMomentFitConfig::default(), &[]).is_ok());
        // review cases: images of 12 px (lags 1 and 2 px; the default lag
        // range reaches 4 px, which no image holds: no lone lag), a
        // fractional start (log2 λ = 0.5 fits levels 1.., which every image
        // holds), an image too small for any moment (named by the moments)
        let accs = |sides: &[usize], cfg: &TraceMomentConfig| -> Vec<TraceMomentAccumulator> {
            sides
                .iter()
                .enumerate()
                .map(|(i, &n)| {
                    let mut a = TraceMomentAccumulator::new(cfg.clone()).unwrap();
                    a.add_field(&field(n, 20 + i as u64)).unwrap();
                    a
                })
                .collect()
        };
        let order1 = TraceMomentConfig {
            diff: FluxDiff::Order(1.0),
            ..cfg.clone()
        };
        let fc = TraceMomentFitConfig::for_tiles();
        check_ensemble_fit(&fc, &[[12, 12]; 3]).unwrap();
        finish_ensemble(&accs(&[12, 12, 12], &order1), &fc).unwrap();
        let half = TraceMomentFitConfig {
            log2_lambda: Some((0.5, 5.0)),
            ..TraceMomentFitConfig::for_tiles()
        };
        check_ensemble_fit(&half, &[[128, 128], [64, 64], [64, 64]]).unwrap();
        finish_ensemble(&accs(&[128, 64, 64], &cfg), &half).unwrap();
        let e = check_ensemble_fit(&half, &[[128, 128], [32, 32], [32, 32]]).unwrap_err();
        assert!(e.to_string().contains("boxes of 64 px"), "{e}");
        check_ensemble_fit(
            &TraceMomentFitConfig::default(),
            &[[6, 6], [64, 64], [64, 64]],
        )
        .unwrap();
        // two images hold the largest boxes: the plain jackknife runs, the
        // GLS fit's nested one (two parts left out) cannot and falls back to
        // OLS, saying why
        let sides = [16, 16, 16, 16, 128, 128];
        let parts: Vec<TraceMomentAccumulator> = sides
            .iter()
            .enumerate()
            .map(|(i, &n)| {
                let mut a = TraceMomentAccumulator::new(cfg.clone()).unwrap();
                a.add_field(&field(n, 10 + i as u64)).unwrap();
                a
            })
            .collect();
        let fc = TraceMomentFitConfig {
            log2_lambda: Some((1.0, 5.0)),
            log2_lag: Some((1.0, 2.0)),
            universal: UniversalWeighting::Gls,
            ..Default::default()
        };
        let shapes: Vec<[usize; 2]> = sides.iter().map(|&n| [n, n]).collect();
        check_ensemble_fit(&fc, &shapes).unwrap();
        let (_, r) = finish_ensemble(&parts, &fc).unwrap();
        assert!(
            r.universal_fit.starts_with("ols")
                && r.universal_fit.contains("lacks the fitted boxes"),
            "{}",
            r.universal_fit
        );
        assert!(r.alpha_stderr.is_finite(), "{}", r.alpha_stderr);
    }
}
