//! Closed-form multifractal theory of the generators (SPEC §10): the ground
//! truth every estimate is compared with.
//!
//! For a surface analysed with an L1-normalised wavelet (`M ~ a^h`):
//!
//! - `τ(q)`: `Z(q, a) ~ a^τ(q)`; `τ(0) = -2` for fields singular everywhere.
//! - `h(q) = τ'(q)`, `D(q) = q h(q) - τ(q)`, and `D(h)` the Legendre
//!   transform; `D(h(0)) = 2`.
//! - `[h_min, h_max]`: where `D(h) >= 0` (for FISC the limits of `h(q)` as
//!   `q -> ±∞`, where `D = 1`).
//! - `β = τ(2) + 4`: exponent of the **angle-averaged** spectral density
//!   `S(|k|) ~ |k|^-β` (the angle-integrated spectrum has `β - 1`).
//! - Kernel cumulants `c_k` with `τ(q) = -Σ c_k q^k / k! - 2` (II eq 64).
//!
//! One file per model: [`fbm`], [`fisc`], [`wcascade`], [`fif`] (formulas
//! and paper equations there; the FIF's [`Multifractal`] implementation is
//! below, with its negative-q convention). [`Model`] is the serialisable union the CLI works with,
//! [`Model::preset`] gives the parameter sets of the paper (SPEC §11) and
//! [`TheoryTable`] the JSON of `wtmm theory`.
//!
//! ```
//! use wtmm::theory::Model;
//! let p = Model::preset("paper-lognormal").unwrap();
//! let (h_min, h_max) = p.model.h_range();
//! assert!((h_min - 0.034).abs() < 5e-4 && (h_max - 0.726).abs() < 5e-4);
//! assert!((p.model.beta() - 2.70).abs() < 5e-3);
//! ```

pub mod fbm;
pub mod fif;
pub mod fisc;
pub mod wcascade;

use ndarray::Array2;
use serde::{Deserialize, Serialize};

use crate::cwt::Wavelet;
use crate::error::{Error, Result};
use crate::synth::dwt::Basis;
use crate::synth::fbm::FbmParams;
use crate::synth::fif::FifParams;
use crate::synth::fisc::FiscParams;
use crate::synth::wcascade::{Isotropy, Law, WCascadeParams};

/// Closed forms of one generator. `d_of_q` and `beta` have generic
/// definitions; a model overrides them only with an equivalent closed form.
pub trait Multifractal {
    /// `τ(q)`.
    fn tau(&self, q: f64) -> f64;
    /// `h(q) = τ'(q)`.
    fn h(&self, q: f64) -> f64;
    /// `D(q) = q h(q) - τ(q)`; `-τ(0)` at q = 0, where `q h(q) -> 0` even
    /// when `h(0)` is infinite (FIF with α <= 1: `q K'(q) -> 0`).
    fn d_of_q(&self, q: f64) -> f64 {
        if q == 0.0 {
            return -self.tau(0.0);
        }
        q * self.h(q) - self.tau(q)
    }
    /// The Legendre transform `D(h)` where it is defined (`None` outside the
    /// closure of the range of `h(q)`; a monofractal defines only its `H`).
    fn dh(&self, h: f64) -> Option<f64>;
    /// `(h_min, h_max)`, the support where `D(h) >= 0`.
    fn h_range(&self) -> (f64, f64);
    /// Angle-averaged spectral exponent `β = τ(2) + 4`.
    fn beta(&self) -> f64 {
        self.tau(2.0) + 4.0
    }
    /// Kernel cumulants `[c1, c2, c3]` (II eq 64), where known.
    fn cumulants(&self) -> Option<[f64; 3]> {
        None
    }
    /// Magnitude correlation `C(Δx)` for an integral scale `L` (II eq 76),
    /// where known; valid for `sup(a1, a2) <= Δx < L`.
    fn magnitude_correlation(&self, _dx: f64, _l: f64) -> Option<f64> {
        None
    }
}

/// FIF surfaces (TM eqs 8-11; closed forms in [`fif`]).
///
/// For `q >= 0` (every q at α = 2): `τ(q) = qH - K(q) - 2`,
/// `h(q) = H - K'(q)`, `D(h) = 2 - c(H - h)` with the universal codimension
/// `c(γ)`, so `D(h(q)) = 2 - C1 q^α`.
///
/// **Negative q (α < 2): a convention.** The flux moments of order q < 0
/// diverge (the generator's heavy tail is on the negative side), so K is
/// defined for q >= 0 only. Its Legendre transform reaches `c = 0` at
/// `γ_min = K'(0+) = -C1/(α-1)` (1 < α < 2), i.e. `D = 2` at
/// `h_max = H + C1/(α-1)`; below `γ_min` (above `h_max`) the strict
/// transform gives `c = 0` too (the left tail of the Lévy generator falls
/// off slower than any power of λ), so `D(h) = 2` for every `h >= h_max` and
/// strictly `τ(q < 0) = -∞`. What is reported instead is the spectrum
/// truncated at `h_max`: `τ(q) = q h_max - 2`, `h(q) = h_max`, `D(q) = 2`
/// (linear, C¹ at q = 0), the τ of the singularities the cascade's
/// intermittent part produces. A finite image, analysed with a wavelet of
/// n vanishing moments, shows finite h(q < 0) bounded by n. For α <= 1,
/// `K'(0+) = -∞`: `h_max = +∞` and `τ(q < 0) = -∞`. The kernel cumulants exist only at α = 2 (K is
/// analytic at 0): `c1 = -(H + C1)`, `c2 = 2 C1`, `c3 = 0`.
impl Multifractal for FifParams {
    fn tau(&self, q: f64) -> f64 {
        if q < 0.0 && self.alpha < 2.0 && self.c1 > 0.0 {
            return q * self.h_range().1 - 2.0;
        }
        fif::tau(self, q)
    }

    fn h(&self, q: f64) -> f64 {
        if q < 0.0 && self.alpha < 2.0 && self.c1 > 0.0 {
            return self.h_range().1;
        }
        fif::h(self, q)
    }

    fn dh(&self, h: f64) -> Option<f64> {
        if self.c1 == 0.0 {
            return ((h - self.hurst).abs() <= 1e-12).then_some(2.0);
        }
        let h_max = self.h_range().1;
        if self.alpha < 2.0 && h_max.is_finite() {
            if h > h_max + 1e-12 {
                return None;
            }
            if h >= h_max - 1e-12 {
                return Some(2.0);
            }
        }
        let gamma = self.hurst - h;
        let c = if self.alpha >= 2.0 {
            // both branches (q of either sign): c = C1 q², γ = C1 (2q - 1)
            self.c1 * (gamma / (2.0 * self.c1) + 0.5).powi(2)
        } else {
            fif::UniversalK::new(self.alpha, self.c1).codimension(gamma)
        };
        c.is_finite().then_some(fif::D - c)
    }

    /// `h_min = h(q*)` with `C1 q*^α = 2` (`D = 0`); `h_max` where `D = 2`
    /// (`H + C1/(α-1)`, `+∞` for α <= 1) or, at α = 2, the other zero
    /// `h(-q*)`.
    fn h_range(&self) -> (f64, f64) {
        if self.c1 == 0.0 {
            return (self.hurst, self.hurst);
        }
        let qs = (fif::D / self.c1).powf(1.0 / self.alpha);
        let h_min = fif::h(self, qs);
        let h_max = if self.alpha >= 2.0 {
            fif::h(self, -qs)
        } else if self.alpha > 1.0 && !fif::alpha_is_one(self.alpha) {
            // α within 1e-9 of 1 is α = 1, as in K(q) (fif::alpha_is_one)
            self.hurst + self.c1 / (self.alpha - 1.0)
        } else {
            f64::INFINITY
        };
        (h_min, h_max)
    }

    fn cumulants(&self) -> Option<[f64; 3]> {
        (self.alpha >= 2.0 || self.c1 == 0.0).then_some([
            -(self.hurst + self.c1),
            2.0 * self.c1,
            0.0,
        ])
    }
}

/// A generator with its parameters (the `MODEL` of the CLI).
///
/// The closed forms (`tau`, `h`, `dh`, `beta`, ...) evaluate the formulas
/// of the model's parameters as given and do not check them: call
/// [`Model::validate`] first on parameters from outside
/// ([`TheoryTable::new`], the presets and the command line do), since an
/// fBm with `H = 2` has a formula but is no fBm.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "model", rename_all = "lowercase")]
pub enum Model {
    /// Fractional Brownian surface `B_H` (SPEC §9).
    Fbm(FbmParams),
    /// Fractionally integrated singular cascade (II §2.1).
    Fisc(FiscParams),
    /// Random W-cascade on an orthonormal wavelet basis (II §2.2; JSON `wcascade`).
    WCascade(WCascadeParams),
    /// Universal multifractal FIF surface (TM §3.3; see [`fif`]).
    Fif(FifParams),
}

/// The image side at which [`Model::caveats`] compares a W-cascade's
/// exact finite-size beta with the theory's: the papers' 1024^2.
const CAVEAT_SIZE: usize = 1024;

/// The tolerance on beta of SPEC §11's acceptance (0.05): a generator whose
/// exact expected beta misses the theory by more cannot pass it.
const BETA_TOLERANCE: f64 = 0.05;

/// Names accepted by [`Model::preset`].
pub const PRESET_NAMES: [&str; 5] = [
    "paper-fbm",
    "paper-lognormal",
    "paper-logpoisson",
    "paper-fisc",
    "topo-fif",
];

/// A published parameter set (SPEC §11) with the analysing wavelet the paper
/// used for it.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Preset {
    /// The preset's name, one of [`PRESET_NAMES`].
    pub name: &'static str,
    /// The generator and its parameters.
    pub model: Model,
    /// gauss for fBm, the W-cascades and topo-fif (h in (-0.1, 0.85)); mexican
    /// for FISC, whose `h_max = 1.28 > 1` needs more than one vanishing
    /// moment (II §3.1).
    pub wavelet: Wavelet,
    /// Where the numbers come from.
    pub source: &'static str,
}

impl Model {
    /// `fbm`, `fisc`, `wcascade` or `fif` (the CLI's MODEL).
    pub fn name(&self) -> &'static str {
        match self {
            Model::Fbm(_) => "fbm",
            Model::Fisc(_) => "fisc",
            Model::WCascade(_) => "wcascade",
            Model::Fif(_) => "fif",
        }
    }

    /// True when the generated fields are periodic (W-cascades, FISC and
    /// FIF are built on the torus; fBm is cropped from a larger one), so the
    /// periodic FFT transform is exact over the whole image and no interior
    /// margin is needed (SPEC §1, §14).
    pub fn is_periodic(&self) -> bool {
        !matches!(self, Model::Fbm(_))
    }

    /// **Errors** with the offending parameter named (see each params type).
    pub fn validate(&self) -> Result<()> {
        match self {
            Model::Fbm(p) => p.validate(),
            Model::Fisc(p) => p.validate(),
            Model::WCascade(p) => p.validate(),
            Model::Fif(p) => p.validate(),
        }
    }

    fn theory(&self) -> &dyn Multifractal {
        match self {
            Model::Fbm(p) => p,
            Model::Fisc(p) => p,
            Model::WCascade(p) => p,
            Model::Fif(p) => p,
        }
    }

    /// The flux moment function `K(q)` of a FIF (`None` for the other
    /// models, which are not defined through a flux; `+∞` for q < 0 when
    /// α < 2).
    pub fn k(&self, q: f64) -> Option<f64> {
        match self {
            Model::Fif(p) => Some(fif::k(p, q)),
            _ => None,
        }
    }

    /// `τ(q)`.
    pub fn tau(&self, q: f64) -> f64 {
        self.theory().tau(q)
    }

    /// `h(q) = τ'(q)`.
    pub fn h(&self, q: f64) -> f64 {
        self.theory().h(q)
    }

    /// `D(q) = q h(q) - τ(q)`.
    pub fn d_of_q(&self, q: f64) -> f64 {
        self.theory().d_of_q(q)
    }

    /// `D(h)` where it is defined ([`Multifractal::dh`]): `None` outside
    /// `[h_min, h_max]`, for a NaN `h`, and for a monofractal (fBm) at any
    /// `h` but its `H`, so at an estimated h too. To set an estimate
    /// against the theory at the same q, use [`Model::h`] and
    /// [`Model::d_of_q`].
    pub fn dh(&self, h: f64) -> Option<f64> {
        if h.is_nan() {
            return None;
        }
        self.theory().dh(h)
    }

    /// `(h_min, h_max)`.
    pub fn h_range(&self) -> (f64, f64) {
        self.theory().h_range()
    }

    /// The most frequent Hölder exponent `h(q = 0)`.
    pub fn h_of_q0(&self) -> f64 {
        self.theory().h(0.0)
    }

    /// Angle-averaged spectral exponent `β = τ(2) + 4`.
    pub fn beta(&self) -> f64 {
        self.theory().beta()
    }

    /// Kernel cumulants `[c1, c2, c3]`.
    pub fn cumulants(&self) -> Option<[f64; 3]> {
        self.theory().cumulants()
    }

    /// `C(Δx)` of II eq 76 (W-cascades; 0 for fBm; `None` for FISC and FIF).
    pub fn magnitude_correlation(&self, dx: f64, l: f64) -> Option<f64> {
        self.theory().magnitude_correlation(dx, l)
    }

    /// What the generated surfaces do not deliver of this theory, for the
    /// commands to say beside their outputs (empty when nothing is known).
    /// A W-cascade on the Haar basis: the basis functions are step
    /// functions, so the surface carries steps along the dyadic grid, edges
    /// the analysing wavelet reads as h = 0 singularities on lines, beside
    /// the cascade's own.
    pub fn caveats(&self) -> Vec<String> {
        let mut out = Vec::new();
        if let Model::WCascade(p) = self
            && p.basis == crate::synth::dwt::Basis::Haar
        {
            out.push(
                "the Haar basis functions are discontinuous: the surface carries steps along \
                 the dyadic grid (h = 0 on lines), which the wavelet transform reads beside the \
                 cascade's singularities, so tau(q) at q > 0, the spectral beta and the kernel \
                 cumulants are not the theory's (paper log-normal parameters, 8 x 512^2, \
                 gauss: tau(2) 0.17 below it, c2 0.065 for 0.030); use --basis db4 or db8 \
                 to test an estimator"
                    .to_string(),
            );
        }
        // the spectrum's exponent needs finite second moments, and moments
        // that the exponents of D(h) >= 0 make: else beta = tau(2) + 4
        // belongs to no field
        if let Model::Fif(p) = self
            && p.c1 > 0.0
            && fif::q_divergence(p) <= 2.0
        {
            out.push(format!(
                "the flux's moments of order q >= q_D = {:.3} diverge (K(q_D) = 2 (q_D - 1)), \
                 the second among them: beta = tau(2) + 4 = {:.3} describes no finite field, whose \
                 spectrum is set by its strongest singularity and changes from field to field",
                fif::q_divergence(p),
                self.beta()
            ));
        } else if self.d_of_q(2.0) < -1e-12 {
            out.push(format!(
                "D(q = 2) = {:.3} < 0: the annealed tau(2), and beta = tau(2) + 4 = {:.3} with it, \
                 come from latent singularities (h outside [h_min, h_max]) that an image almost \
                 surely does not hold, so a field's spectral beta does not follow it",
                self.d_of_q(2.0),
                self.beta()
            ));
        }
        // a basis rougher than the cascade can only pull beta down (a finite
        // cascade's beta above the theory is its size, said by validate);
        // up to h(2) = 1 both Daubechies bases keep it within the tolerance
        // (test a_beta_no_field_follows_is_said), so the spectrum is not
        // computed there
        if let Model::WCascade(p) = self
            && p.basis != crate::synth::dwt::Basis::Haar
            && self.beta() > 4.0
            && let Some(b) = self.finite_beta(CAVEAT_SIZE)
            && b < self.beta() - BETA_TOLERANCE
        {
            out.push(format!(
                "the generator's exact expected spectrum at {CAVEAT_SIZE}^2 has beta = {b:.3} over \
                 the default fit range, below the theory's {:.3}: the {} basis functions are \
                 only so smooth, and where the cascade's singularities are smoother (h(2) = \
                 {:.2}) the surface carries the basis's regularity, not the cascade's; the \
                 spectral beta, and WTMM exponents near or above it, are then the basis's{}",
                self.beta(),
                p.basis.name(),
                self.h(2.0),
                if p.basis == crate::synth::dwt::Basis::Db4 {
                    " (the smoother db8 basis goes further)"
                } else {
                    ""
                }
            ));
        }
        out
    }

    /// The spectral exponent of the exact expected spectrum of the finite
    /// `size^2` generator over [`crate::stats::powspec::default_k_range`]
    /// (4 bins per octave), where it is known (W-cascades and FISC);
    /// `None` for other models or if it cannot be computed.
    pub fn finite_beta(&self, size: usize) -> Option<f64> {
        // remembered per model and size: caveats() asks for it several
        // times per command, and a 1024^2 spectrum costs ~50 ms
        type Memo = std::sync::Mutex<Vec<(String, usize, Option<f64>)>>;
        static MEMO: Memo = std::sync::Mutex::new(Vec::new());
        let key = serde_json::to_string(self).ok()?;
        if let Ok(m) = MEMO.lock()
            && let Some(&(_, _, b)) = m.iter().find(|(k, n, _)| *k == key && *n == size)
        {
            return b;
        }
        let b = self.finite_beta_uncached(size);
        if let Ok(mut m) = MEMO.lock() {
            // bounded, for a library caller that scans many models
            if m.len() >= 64 {
                m.remove(0);
            }
            m.push((key, size, b));
        }
        b
    }

    fn finite_beta_uncached(&self, size: usize) -> Option<f64> {
        let d = match self {
            Model::WCascade(p) => wcascade::expected_power(p, size).ok()?,
            Model::Fisc(p) => p.expected_power(size).ok()?,
            _ => return None,
        };
        let ps = crate::stats::powspec::PowerSpectrum::from_density(d.view(), 4).ok()?;
        let (lo, hi) = crate::stats::powspec::default_k_range(size);
        ps.fit(lo, hi).ok().map(|f| f.beta)
    }

    /// True for the generators built on a dyadic grid (FISC's p-model and
    /// the W-cascades' wavelet basis); fBm and FIF take any size.
    pub fn needs_power_of_two(&self) -> bool {
        matches!(self, Model::Fisc(_) | Model::WCascade(_))
    }

    /// **Errors** unless [`Model::synthesize`] can make `size x size`
    /// images: 2 px or more (FIF 4), a power of two for the cascades, at
    /// most 16384^2 pixels.
    pub fn check_size(&self, size: usize) -> Result<()> {
        // the generators' own floors (fbm, fisc::steps_for_size: 2; fif: 4)
        let min = match self {
            Model::Fif(_) => 4,
            _ => 2,
        };
        if size < min {
            return Err(Error::param(
                "size",
                format!("{} needs {min} px or more, got {size}", self.name()),
            ));
        }
        if self.needs_power_of_two() && !size.is_power_of_two() {
            return Err(Error::param(
                "size",
                format!(
                    "the model generated, {}, needs a side that is a power of two (its \
                     construction halves the grid at each step), got {size}",
                    self.name()
                ),
            ));
        }
        crate::synth::check_pixels(size, size)
    }

    /// Image `index` of the ensemble `seed`, `size x size`.
    ///
    /// **Errors** on invalid parameters or size (cascades need a power of two).
    pub fn synthesize(&self, size: usize, seed: u64, index: u64) -> Result<Array2<f64>> {
        match *self {
            Model::Fbm(p) => crate::synth::fbm::fbm(p, size, size, seed, index),
            Model::Fisc(p) => crate::synth::fisc::fisc(p, size, seed, index),
            Model::WCascade(p) => crate::synth::wcascade::wcascade(&p, size, seed, index),
            Model::Fif(p) => crate::synth::fif::fif(&p, size, size, seed, index),
        }
    }

    /// The scale range, in px, of the own-cascade comparisons of a fit over
    /// `(a_lo, a_hi)` px: widened by half an octave each way, so that the
    /// dyadic cells nearest the fit's ends are in.
    pub fn sample_range((a_lo, a_hi): (f64, f64)) -> (f64, f64) {
        (
            a_lo / std::f64::consts::SQRT_2,
            a_hi * std::f64::consts::SQRT_2,
        )
    }

    /// The levels `s` of the generator's own cascade whose cells, `size /
    /// 2^s` px, lie in `[a_lo, a_hi]`, from level 1 down to the finest
    /// (W-cascade amplitudes stop one level above the pixel, at 2 px cells;
    /// the p-model reaches it); `None` for fewer than 3 levels or a model
    /// without a cascade. The levels of [`Model::sample_sums`] and of
    /// `validate`'s own-cascade kernel.
    ///
    /// **Errors** on a size that is not a power of two or a scale range
    /// that is not finite and positive.
    pub fn sample_levels(
        &self,
        size: usize,
        (a_lo, a_hi): (f64, f64),
    ) -> Result<Option<std::ops::Range<usize>>> {
        if !(a_lo > 0.0 && a_hi >= a_lo && a_hi.is_finite()) {
            return Err(Error::param(
                "scales",
                format!(
                    "need finite 0 < a_lo <= a_hi, got {}, {}",
                    crate::error::short(a_lo),
                    crate::error::short(a_hi)
                ),
            ));
        }
        let below_pixel = match self {
            Model::WCascade(_) => 1,
            Model::Fisc(_) => 0,
            Model::Fbm(_) | Model::Fif(_) => return Ok(None),
        };
        let n = crate::synth::fisc::steps_for_size(size)? as i64;
        let finest = n - below_pixel;
        // a_s = 2^(n - s) in [a_lo, a_hi]
        let s_lo = (n as f64 - a_hi.log2() - 1e-9).ceil().max(1.0) as i64;
        let s_hi = ((n as f64 - a_lo.log2() + 1e-9).floor() as i64).min(finest);
        if s_hi - s_lo < 2 {
            return Ok(None);
        }
        Ok(Some(s_lo as usize..(s_hi + 1) as usize))
    }

    /// The partition sums of image `index`'s own multiplicative cascade, on
    /// the dyadic scales `size / 2^s` px that lie in `[a_lo, a_hi]`: a
    /// W-cascade's wavelet amplitudes, a FISC's p-model box masses times
    /// `a^(H* - 2)`. In expectation their τ(q) is the theory's at every scale
    /// (`<Σ d^q> = 4^s <W^q>^s`), so fitting an ensemble of them shows how
    /// far the finite sample itself lies from the theory, and the rest of a
    /// WTMM estimate's distance belongs to the estimator. `None` for the
    /// models without a discrete cascade (fBm, FIF) or fewer than 3 scales.
    ///
    /// **Errors** on invalid parameters, a size that is not a power of two
    /// or an empty scale range.
    pub fn sample_sums(
        &self,
        size: usize,
        seed: u64,
        index: u64,
        q: &[f64],
        (a_lo, a_hi): (f64, f64),
    ) -> Result<Option<crate::spectra::PartitionSums>> {
        let Some(levels) = self.sample_levels(size, (a_lo, a_hi))? else {
            return Ok(None);
        };
        let mut vals = match *self {
            Model::WCascade(p) => crate::synth::wcascade::wcascade_log2_amplitudes(
                &p,
                size,
                seed,
                index,
                levels.clone(),
            )?,
            Model::Fisc(p) => {
                crate::synth::fisc::fisc_log2_amplitudes(p, size, seed, index, levels.clone())?
            }
            Model::Fbm(_) | Model::Fif(_) => return Ok(None),
        };
        // ascending scales: finest level first
        vals.reverse();
        let scales: Vec<f64> = levels.rev().map(|s| (size >> s) as f64).collect();
        crate::spectra::PartitionSums::from_log2_values(
            &scales,
            &vals,
            q,
            format!("image {index} (own cascade)"),
        )
        .map(Some)
    }

    /// The published parameter sets (SPEC §11): `paper-fbm` (H = 1/3),
    /// `paper-lognormal` (m = -0.38 ln2, σ² = 0.03 ln2), `paper-logpoisson`
    /// (γ = -ln2/9, β = (2/3)^(1/3), λ = 2 ln2), both isotropic on db8 (the
    /// paper's "Daubechies 8", see [`crate::synth::dwt`]), and `paper-fisc`
    /// (p = 0.32, H* = 0.638); and `topo-fif`, the FIF with the topography
    /// parameters of TM Tables 4-5 (α = 1.8, C1 = 0.12, H = 0.7).
    ///
    /// **Errors** on an unknown name, listing the known ones.
    pub fn preset(name: &str) -> Result<Preset> {
        let ln2 = std::f64::consts::LN_2;
        let wc = |law| {
            Model::WCascade(WCascadeParams {
                law,
                isotropy: Isotropy::Isotropic,
                basis: Basis::Db8,
            })
        };
        let (name, model, wavelet, source) = match name {
            "paper-fbm" => (
                "paper-fbm",
                Model::Fbm(FbmParams { hurst: 1.0 / 3.0 }),
                Wavelet::Gauss,
                "paper I §5, II Fig 30b",
            ),
            "paper-lognormal" => (
                "paper-lognormal",
                wc(Law::LogNormal {
                    m: -0.38 * ln2,
                    sigma2: 0.03 * ln2,
                }),
                Wavelet::Gauss,
                "II §2.2.3, §3.2.1, Figs 6a, 15-20, 25-26, 30a",
            ),
            "paper-logpoisson" => (
                "paper-logpoisson",
                wc(Law::LogPoisson {
                    gamma: -ln2 / 9.0,
                    beta: (2.0f64 / 3.0).cbrt(),
                    lambda: 2.0 * ln2,
                }),
                Wavelet::Gauss,
                "II §2.2.3, §3.2.2, Figs 6b, 16, 21-24, 27-28",
            ),
            "paper-fisc" => (
                "paper-fisc",
                Model::Fisc(FiscParams {
                    p: 0.32,
                    hstar: 0.638,
                }),
                Wavelet::Mexican,
                "II §2.1, §3.1, Figs 1-3, 9-14",
            ),
            "topo-fif" => (
                "topo-fif",
                Model::Fif(FifParams::TOPO),
                Wavelet::Gauss,
                "TM Tables 4-5 (topography), SIM Fig 1b",
            ),
            other => {
                return Err(Error::param(
                    "preset",
                    format!(
                        "unknown preset `{other}`; known: {}",
                        PRESET_NAMES.join(", ")
                    ),
                ));
            }
        };
        Ok(Preset {
            name,
            model,
            wavelet,
            source,
        })
    }
}

/// Kernel cumulants as named fields (the JSON of `wtmm theory`, like
/// `kernel.json`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Cumulants {
    /// `c1` (`τ(q) = -Σ c_n q^n/n! - 2`, II eq 64).
    pub c1: f64,
    /// `c2`.
    pub c2: f64,
    /// `c3`.
    pub c3: f64,
}

/// Everything `wtmm theory` prints for one model on a q grid. JSON has
/// no infinities nor NaN: both are written `null`, and read back as NaN
/// (the docs below say which fields can be infinite, and of what sign).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TheoryTable {
    /// The model and its parameters.
    pub model: Model,
    /// The q grid.
    pub q: Vec<f64>,
    /// `τ(q)` per q (`-∞`, JSON `null`, for a FIF with α <= 1 at q < 0).
    #[serde(deserialize_with = "crate::nan_null::vec")]
    pub tau: Vec<f64>,
    /// `h(q) = τ'(q)` per q.
    #[serde(deserialize_with = "crate::nan_null::vec")]
    pub h: Vec<f64>,
    /// `D(q) = q h(q) - τ(q)`.
    #[serde(rename = "D", deserialize_with = "crate::nan_null::vec")]
    pub d: Vec<f64>,
    /// Lower end of the support of `D(h)` (where `D(h) >= 0`; for FISC the
    /// limit of h(q) as q → +∞, see the module doc).
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub h_min: f64,
    /// Upper end of the support of `D(h)` (`+∞`, JSON `null`, for a FIF
    /// with α <= 1).
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub h_max: f64,
    /// The most frequent Hölder exponent `h(q = 0)`, where `D = 2`.
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub h_of_q0: f64,
    /// Angle-averaged: `S(|k|) ~ |k|^-β`.
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub beta: f64,
    /// Always `"angle-averaged"`.
    pub beta_convention: String,
    /// Kernel cumulants where known (not for a FIF with α < 2 and C1 > 0);
    /// omitted from the JSON otherwise.
    #[serde(skip_serializing_if = "Option::is_none", default)]
    pub cumulants: Option<Cumulants>,
    /// The flux moment function K(q) (FIF only; `null` where infinite).
    #[serde(
        rename = "K",
        skip_serializing_if = "Option::is_none",
        default,
        deserialize_with = "crate::nan_null::opt_vec"
    )]
    pub k: Option<Vec<f64>>,
    /// The D(h) curve sampled on `[h_min, h_max]` (one point for a
    /// monofractal); where `h_max` is infinite (FIF with α <= 1, D -> 2 as
    /// h -> ∞) up to `h(q = 0.001)`, where `D = 2 - C1 0.001^α`.
    #[serde(deserialize_with = "crate::nan_null::vec")]
    pub dh_h: Vec<f64>,
    /// `D(h)` at each `dh_h` (JSON `dh_D`).
    #[serde(rename = "dh_D", deserialize_with = "crate::nan_null::vec")]
    pub dh_d: Vec<f64>,
}

impl TheoryTable {
    /// Number of points of the D(h) curve.
    pub const DH_POINTS: usize = 101;

    /// The table of `model` on the grid `q`.
    ///
    /// **Errors** on a model whose parameters are out of range
    /// ([`Model::validate`]: its closed forms would be NaN or meaningless),
    /// or a q grid the spectra refuse ([`crate::spectra::check_q`]: a
    /// non-finite or huge q).
    pub fn new(model: &Model, q: &[f64]) -> Result<Self> {
        model.validate()?;
        crate::spectra::check_q(q)?;
        let (h_min, h_max) = model.h_range();
        // an unbounded support (FIF with α <= 1) is sampled up to h(q = 0.001)
        let h_hi = if h_max.is_finite() {
            h_max
        } else {
            model.h(1e-3)
        };
        let (mut dh_h, mut dh_d) = (Vec::new(), Vec::new());
        let n = if h_hi - h_min > 1e-12 {
            Self::DH_POINTS
        } else {
            1
        };
        for i in 0..n {
            let h = if n == 1 {
                h_min
            } else {
                h_min + (h_hi - h_min) * i as f64 / (n - 1) as f64
            };
            if let Some(d) = model.dh(h) {
                dh_h.push(h);
                dh_d.push(d);
            }
        }
        Ok(TheoryTable {
            model: *model,
            q: q.to_vec(),
            tau: q.iter().map(|&v| model.tau(v)).collect(),
            h: q.iter().map(|&v| model.h(v)).collect(),
            d: q.iter().map(|&v| model.d_of_q(v)).collect(),
            h_min,
            h_max,
            h_of_q0: model.h_of_q0(),
            beta: model.beta(),
            beta_convention: crate::stats::powspec::CONVENTION.to_string(),
            cumulants: model
                .cumulants()
                .map(|[c1, c2, c3]| Cumulants { c1, c2, c3 }),
            k: model
                .k(0.0)
                .map(|_| q.iter().map(|&v| model.k(v).unwrap_or(f64::NAN)).collect()),
            dh_h,
            dh_d,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A table with infinities and undefined values (FIF with α = 1: τ =
    /// -∞ at q < 0, h_max = +∞; K undefined at q < 0) reads back from its
    /// JSON, the non-finite values as NaN, the rest exactly.
    #[test]
    fn tables_with_infinities_read_back() {
        let m = Model::Fif(FifParams {
            alpha: 1.0,
            c1: 0.1,
            hurst: 0.5,
        });
        let t = TheoryTable::new(&m, &[-1.0, 0.0, 1.0, 2.0]).unwrap();
        assert!(t.h_max.is_infinite() && t.tau[0] == f64::NEG_INFINITY);
        let back: TheoryTable = serde_json::from_str(&serde_json::to_string(&t).unwrap()).unwrap();
        assert!(back.h_max.is_nan() && back.tau[0].is_nan());
        assert_eq!(back.tau[1..], t.tau[1..]);
        assert_eq!(back.h_min, t.h_min);
        assert_eq!(back.dh_d, t.dh_d);
        let k = back.k.unwrap();
        assert!(k[0].is_nan() && k[3] == t.k.unwrap()[3]);
    }

    /// Parameters out of range give an error naming them, not NaN curves.
    #[test]
    fn a_table_of_an_invalid_model_is_an_error() {
        let bad = Model::Fisc(crate::synth::fisc::FiscParams {
            p: 0.7,
            hstar: 0.638,
        });
        let e = TheoryTable::new(&bad, &[0.0, 1.0]).unwrap_err().to_string();
        assert!(e.contains("`p`") && e.contains("0.7"), "{e}");
        // a q grid the spectra refuse is refused here too (it gave NaN, -inf)
        let good = Model::preset("paper-lognormal").unwrap().model;
        for q in [vec![0.0, f64::NAN], vec![1e308], vec![]] {
            let e = TheoryTable::new(&good, &q).unwrap_err().to_string();
            assert!(e.contains("`q`"), "{q:?}: {e}");
        }
    }

    /// A model the generator refuses has no finite-size beta (`None`), and
    /// its expected spectrum is an error naming the parameter: an isotropic
    /// cascade with tau(2) < -6 (no phi*, II eq 36; only a law that does
    /// not converge has it) panicked in phi_star.
    #[test]
    fn finite_beta_of_an_invalid_model_is_none() {
        use crate::synth::wcascade::{Law, WCascadeParams};
        let p = WCascadeParams {
            law: Law::LogNormal {
                m: -0.01,
                sigma2: 5.0,
            },
            isotropy: Default::default(),
            basis: Default::default(),
        };
        assert!(p.law.tau(2.0) < -6.0);
        assert_eq!(Model::WCascade(p).finite_beta(64), None);
        let e = wcascade::expected_power(&p, 64).unwrap_err().to_string();
        assert!(e.contains("`sigma2`"), "{e}");
        let bad = crate::synth::fisc::FiscParams { p: 0.7, hstar: 0.5 };
        assert_eq!(Model::Fisc(bad).finite_beta(64), None);
        assert!(bad.expected_power(64).is_err());
        // a valid model still has one
        let good = Model::preset("paper-lognormal").unwrap().model;
        assert!(good.finite_beta(256).is_some_and(f64::is_finite));
    }

    #[test]
    fn only_a_haar_cascade_carries_a_caveat() {
        for name in PRESET_NAMES {
            assert!(
                Model::preset(name).unwrap().model.caveats().is_empty(),
                "{name}"
            );
        }
        let Model::WCascade(p) = Model::preset("paper-lognormal").unwrap().model else {
            panic!("paper-lognormal is a W-cascade")
        };
        for (basis, n) in [(Basis::Haar, 1), (Basis::Db4, 0), (Basis::Db8, 0)] {
            let c = Model::WCascade(WCascadeParams { basis, ..p }).caveats();
            assert_eq!(c.len(), n, "{basis:?}");
            assert!(c.iter().all(|w| w.contains("Haar") && w.contains("db8")));
        }
    }

    /// A monofractal W-cascade (sigma^2 = 0, h = -m/ln 2) smoother than its
    /// basis: the exact expected spectrum of the generator at 1024^2 falls
    /// short of beta = 2h + 2 by more than the acceptance's 0.05 (db4 at
    /// h = 2: 5.66 for 6; db8 at h = 4), said; below, nothing is said, nor
    /// above the theory (a finite cascade's own bend). A
    /// FIF whose second moment diverges (q_D <= 2) and a cascade whose
    /// D(q = 2) < 0 have no beta a field follows, said too.
    #[test]
    fn a_beta_no_field_follows_is_said() {
        let ln2 = std::f64::consts::LN_2;
        let mono = |h: f64, basis| {
            Model::WCascade(WCascadeParams {
                law: Law::LogNormal {
                    m: -h * ln2,
                    sigma2: 0.0,
                },
                isotropy: Isotropy::Psi12,
                basis,
            })
        };
        for (h, basis, said) in [
            (1.0, Basis::Db4, false),
            (2.0, Basis::Db4, true),
            (2.0, Basis::Db8, false),
            (4.0, Basis::Db8, true),
        ] {
            let m = mono(h, basis);
            let b = m.finite_beta(1024).unwrap();
            let c = m.caveats();
            assert_eq!(
                c.len(),
                usize::from(said),
                "h {h} {basis:?}: beta {b} {c:?}"
            );
            assert_eq!(b < 2.0 * h + 2.0 - 0.05, said, "h {h} {basis:?}: {b}");
            assert!(c.iter().all(|w| w.contains(basis.name())), "{c:?}");
        }
        // a finite cascade's beta above the theory is its size, not the
        // basis (6.959 for 6.905 here): nothing said
        let above = Model::WCascade(WCascadeParams {
            law: Law::LogNormal {
                m: -2.0,
                sigma2: 0.3,
            },
            isotropy: Isotropy::Isotropic,
            basis: Basis::Db8,
        });
        assert!(above.finite_beta(1024).unwrap() > above.beta() + 0.05);
        assert!(above.caveats().is_empty(), "{:?}", above.caveats());
        let fif = Model::Fif(FifParams {
            alpha: 1.8,
            c1: 1.5,
            hurst: 0.5,
        });
        let c = fif.caveats();
        assert!(c.len() == 1 && c[0].contains("q_D = 1.379"), "{c:?}");
        let wild = Model::WCascade(WCascadeParams {
            law: Law::LogNormal {
                m: -20.0,
                sigma2: 100.0,
            },
            isotropy: Isotropy::Psi3,
            basis: Basis::Db8,
        });
        assert!(wild.d_of_q(2.0) < 0.0);
        let c = wild.caveats();
        assert!(c.iter().any(|w| w.contains("D(q = 2)")), "{c:?}");
    }

    fn models() -> Vec<Model> {
        let ln2 = std::f64::consts::LN_2;
        let mut v: Vec<Model> = PRESET_NAMES
            .iter()
            .map(|n| Model::preset(n).unwrap().model)
            .collect();
        v.push(Model::Fisc(FiscParams { p: 0.2, hstar: 0.9 }));
        v.push(Model::WCascade(WCascadeParams {
            law: Law::LogNormal {
                m: -0.5 * ln2,
                sigma2: 0.05 * ln2,
            },
            isotropy: Isotropy::Psi12,
            basis: Basis::Db4,
        }));
        // λ > 2 ln2: the left end of D(h) >= 0 is a zero, not the asymptote
        v.push(Model::WCascade(WCascadeParams {
            law: Law::LogPoisson {
                gamma: -0.3,
                beta: 0.8,
                lambda: 2.0,
            },
            isotropy: Isotropy::Isotropic,
            basis: Basis::Db8,
        }));
        // a log-normal FIF: analytic τ for every q, both branches of D(h)
        v.push(Model::Fif(FifParams {
            alpha: 2.0,
            c1: 0.1,
            hurst: 0.5,
        }));
        v
    }

    /// h(q) is the derivative of τ: central differences with step 1e-4 have
    /// truncation error τ''' δ²/6 ~ 1e-9 and rounding ~1e-16/1e-4 = 1e-12.
    #[test]
    fn h_is_the_derivative_of_tau() {
        for m in models() {
            for i in -40..=40 {
                let q = i as f64 * 0.25;
                // a FIF with α < 2 has K'' ~ q^(α-2) at 0+ (and the linear
                // branch below 0): τ is C¹ but not C² at q = 0, where the
                // central difference is off by O(δ^(α-1))
                if q == 0.0 && matches!(m, Model::Fif(p) if p.alpha < 2.0) {
                    continue;
                }
                let d = 1e-4;
                let fd = (m.tau(q + d) - m.tau(q - d)) / (2.0 * d);
                assert!(
                    (fd - m.h(q)).abs() < 1e-7,
                    "{m:?} q={q}: {fd} vs {}",
                    m.h(q)
                );
            }
        }
    }

    /// The numerical Legendre transform `D(h) = min_q (q h - τ(q))` of the
    /// analytic τ on a fine q grid reproduces the analytic D(h). For h
    /// strictly inside `h([q_lo, q_hi])` the minimiser is interior and the
    /// grid error is at most `|τ''| δq² / 8 ≈ 0.1 * 1e-6 / 8`.
    #[test]
    fn legendre_transform_of_tau_gives_dh() {
        for m in models() {
            if matches!(m, Model::Fbm(_)) {
                continue;
            }
            let (q_lo, q_hi) = (-30.0, 30.0);
            let qs: Vec<f64> = (0..=60_000).map(|i| q_lo + i as f64 * 1e-3).collect();
            let taus: Vec<f64> = qs.iter().map(|&q| m.tau(q)).collect();
            let (h_lo, h_hi) = (m.h(q_hi), m.h(q_lo));
            let (h_min, h_max) = m.h_range();
            let (a, b) = (h_lo.max(h_min - 0.5), h_hi.min(h_max + 0.5));
            for i in 1..50 {
                let h = a + (b - a) * i as f64 / 50.0;
                let num = qs
                    .iter()
                    .zip(&taus)
                    .map(|(&q, &t)| q * h - t)
                    .fold(f64::INFINITY, f64::min);
                let ana = m.dh(h).expect("inside the range of h(q)");
                assert!((num - ana).abs() < 1e-5, "{m:?} h={h}: {num} vs {ana}");
            }
        }
    }

    /// D(q) and D(h(q)) are the same curve; τ(0) = -2, D(h(0)) = 2.
    #[test]
    fn canonical_and_legendre_agree() {
        for m in models() {
            assert!((m.tau(0.0) + 2.0).abs() < 1e-12, "{m:?}");
            for i in -20..=20 {
                let q = i as f64 * 0.5;
                let via_h = m.dh(m.h(q)).unwrap();
                assert!((via_h - m.d_of_q(q)).abs() < 1e-9, "{m:?} q={q}");
            }
            assert!((m.dh(m.h_of_q0()).unwrap() - 2.0).abs() < 1e-12);
        }
    }

    /// D vanishes at the ends of the W-cascade supports, is 1 at the FISC
    /// ends, and is >= 0 inside.
    #[test]
    fn h_range_ends() {
        for m in models() {
            let (lo, hi) = m.h_range();
            let (dlo, dhi) = (m.dh(lo).unwrap(), m.dh(hi).unwrap());
            match m {
                Model::Fbm(_) => assert_eq!((dlo, dhi), (2.0, 2.0)),
                Model::Fisc(_) => assert!((dlo - 1.0).abs() < 1e-9 && (dhi - 1.0).abs() < 1e-9),
                Model::WCascade(_) => {
                    assert!(dhi.abs() < 1e-9, "{m:?}: D(h_max) = {dhi}");
                    assert!(dlo >= -1e-9, "{m:?}: D(h_min) = {dlo}");
                }
                // α < 2: D rises to 2 at h_max (no right branch); α = 2: a zero
                Model::Fif(p) => {
                    let top = if p.alpha < 2.0 { 2.0 } else { 0.0 };
                    assert!((dhi - top).abs() < 1e-9, "{m:?}: D(h_max) = {dhi}");
                    assert!(dlo.abs() < 1e-9, "{m:?}: D(h_min) = {dlo}");
                }
            }
            for i in 0..=20 {
                let h = lo + (hi - lo) * i as f64 / 20.0;
                assert!(m.dh(h).unwrap() >= -1e-9);
            }
        }
    }

    #[test]
    fn beta_is_tau2_plus_4() {
        for m in models() {
            assert!((m.beta() - (m.tau(2.0) + 4.0)).abs() < 1e-12, "{m:?}");
        }
    }

    /// τ(q) = -Σ c_k q^k/k! - 2 (II eq 64): the cumulants are the Taylor
    /// coefficients of -τ - 2 at 0; check them by finite differences
    /// (steps 1e-2: truncation ~c5 δ² ~ 1e-6; rounding 1e-16/δ³ ~ 1e-10).
    #[test]
    fn cumulants_are_taylor_coefficients() {
        for m in models() {
            let Some(c) = m.cumulants() else {
                // only a FIF with α < 2 (K not analytic at 0) has none
                assert!(matches!(m, Model::Fif(p) if p.alpha < 2.0), "{m:?}");
                continue;
            };
            let f = |q: f64| -m.tau(q) - 2.0;
            let d = 1e-2;
            let c1 = (f(d) - f(-d)) / (2.0 * d);
            let c2 = (f(d) - 2.0 * f(0.0) + f(-d)) / (d * d);
            let c3 = (f(2.0 * d) - 2.0 * f(d) + 2.0 * f(-d) - f(-2.0 * d)) / (2.0 * d * d * d);
            assert!((c1 - c[0]).abs() < 1e-5, "{m:?}: c1 {c1} vs {}", c[0]);
            assert!((c2 - c[1]).abs() < 1e-5, "{m:?}: c2 {c2} vs {}", c[1]);
            assert!((c3 - c[2]).abs() < 1e-4, "{m:?}: c3 {c3} vs {}", c[2]);
        }
    }

    #[test]
    fn unknown_preset_lists_the_known_ones() {
        let e = Model::preset("paper-foo").unwrap_err().to_string();
        assert!(
            e.contains("paper-lognormal") && e.contains("`preset`"),
            "{e}"
        );
    }

    #[test]
    fn table_json_has_the_cli_keys() {
        let m = Model::preset("paper-logpoisson").unwrap().model;
        let t = TheoryTable::new(&m, &[-2.0, 0.0, 2.0]).unwrap();
        let j = serde_json::to_value(&t).unwrap();
        for k in [
            "q",
            "tau",
            "h",
            "D",
            "h_min",
            "h_max",
            "h_of_q0",
            "beta",
            "cumulants",
        ] {
            assert!(j.get(k).is_some(), "missing {k}");
        }
        assert_eq!(j["model"]["model"], "wcascade");
        assert_eq!(j["model"]["law"]["law"], "logpoisson");
        let back: TheoryTable = serde_json::from_value(j).unwrap();
        assert_eq!(back, t);
        assert_eq!(t.dh_h.len(), TheoryTable::DH_POINTS);
        let f = TheoryTable::new(&Model::preset("paper-fbm").unwrap().model, &[0.0]).unwrap();
        assert_eq!((f.dh_h.len(), f.dh_d[0]), (1, 2.0));
        let jf = serde_json::to_value(&f).unwrap();
        assert!(jf.get("K").is_none(), "K is for the FIF only");
        let t = TheoryTable::new(&Model::preset("topo-fif").unwrap().model, &[-1.0, 2.0]).unwrap();
        let j = serde_json::to_value(&t).unwrap();
        assert_eq!(j["model"]["model"], "fif");
        assert!(j["K"][0].is_null(), "K(-1) diverges for α < 2");
        assert!((j["K"][1].as_f64().unwrap() - 0.15 * (2f64.powf(1.8) - 2.0)).abs() < 1e-12);
    }

    /// topo-fif: τ = qH - K(q) - 2 for q >= 0, linear with slope h_max below
    /// (module docs), β = τ(2) + 4 = 2 + 2H - K(2) (angle-averaged).
    #[test]
    fn fif_negative_q_and_beta() {
        let m = Model::preset("topo-fif").unwrap().model;
        let Model::Fif(p) = m else { unreachable!() };
        let (h_min, h_max) = m.h_range();
        assert!((h_max - (0.7 + 0.12 / 0.8)).abs() < 1e-12);
        assert!(h_min < 0.0 && m.dh(h_min).unwrap().abs() < 1e-9);
        assert!((m.tau(-2.0) - (-2.0 * h_max - 2.0)).abs() < 1e-12);
        assert!((m.tau(1.5) - fif::tau(&p, 1.5)).abs() < 1e-15);
        assert!((m.beta() - fif::beta_averaged(&p)).abs() < 1e-12);
        assert_eq!(m.h(-1.0), h_max);
        assert!(m.dh(h_max + 0.01).is_none());
        // α < 1: no finite h_max, τ(q < 0) = -∞, and the table stays finite
        let low = Model::Fif(FifParams {
            alpha: 0.7,
            c1: 0.1,
            hurst: 0.5,
        });
        assert!(low.h_range().1.is_infinite() && low.tau(-1.0) == f64::NEG_INFINITY);
        let t = TheoryTable::new(&low, &[0.5, 1.0]).unwrap();
        assert_eq!(t.dh_h.len(), TheoryTable::DH_POINTS);
        assert!(t.dh_d.iter().all(|d| d.is_finite()));
    }
}
