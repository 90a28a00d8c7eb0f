//! Random W-cascades on a separable orthonormal wavelet basis (II §2.2;
//! SPEC §9), periodic, on a `2^N x 2^N` grid.
//!
//! # Construction
//! Level `s = 0 .. N-1` of the periodic DWT ([`crate::synth::dwt`]) has
//! `2^s x 2^s` positions, each with three detail coefficients
//! `(c1, c2, c3)` on `ψ1 = φ(x)ψ(y)`, `ψ2 = ψ(x)φ(y)`, `ψ3 = ψ(x)ψ(y)`
//! (II eq 19). Their modulus `d = |(c1, c2, c3)|` (eq 24) cascades from the
//! single position of level 0 down: each of the four children of a position
//! gets `d_child = M d_parent` with `M` i.i.d. (eq 25), and its own random
//! direction (eq 26):
//!
//! ```text
//! c1 = cos φ cos θ d,   c2 = cos φ sin θ d,   c3 = sin φ d
//! ```
//!
//! The variants of II Fig 5 ([`Isotropy`]):
//! - `Psi12` (case i): start `(1, 1, 0)`, θ uniform on [-π, π], φ = 0.
//! - `Psi3` (case ii): start `(0, 0, 1)`, φ = ±π/2 at random.
//! - `Isotropic` (case iii, eqs 35-36): θ uniform on [-π, π], φ uniform on
//!   `[-φ*, φ*]` with `sin(2φ*)/(4φ*) = r/(1+r) - 1/2`, `r = 2^(τ(2)/2 + 3)`.
//!   That gives `<c3²>/<c1²> = 2/r = 2^(-τ(2)/2 - 2)`: ψ3's energy sits at
//!   the corners of the dyadic band, at `|k|` larger by √2 than ψ1's and
//!   ψ2's, so an isotropic `S ~ |k|^-β` needs it smaller by `(√2)^-β`.
//!   Start: `(1, 1, 2^-(τ(2)/4 + 1))`, the same amplitude ratio, as the
//!   paper's §2.2.1 sentence "(1, 1, 1/2^(τ(2)/4+1))" says. (Eq 35 as
//!   printed, and SPEC §9 after it, read `2^(-τ(2)/4 + 1)`, 16 times more
//!   energy on ψ3 than eq 36 puts there; it is one coefficient at the largest
//!   scale, outside any fit range, and we take the self-consistent form.)
//!
//! # Normalisation
//! The moduli `d` are *amplitudes*: L1-normalised coefficients, which scale
//! like `a^h` at a Hölder-h point, so that `Σ d^q ~ 4^s <M^q>^s` gives
//! `τ(q) = -log2 <M^q> - 2` (II eq 29). The orthonormal inverse DWT takes
//! L2 coefficients. A level-s basis function has scale `2^(N-s)` pixels:
//! `ψ_s(x) = 2^-(N-s) ψ(x / 2^(N-s))` has unit L2 norm in 2D, while the
//! L1-normalised one is `2^-2(N-s) ψ(x / 2^(N-s))`, so
//! `<f, ψ_s^L2> = 2^(N-s) <f, ψ_s^L1>`: **the L2 coefficient is the amplitude
//! times `2^(N-s)`** (= `L 2^-s`; up to the constant `L`, the `2^-j` of a
//! level with `2^j x 2^j` coefficients). Pixel values of `f` are then of the
//! order of the amplitudes. Check: with `M = 2^-H` fixed the amplitudes are
//! `2^-Hs ~ a^H` and the field is a monofractal with `h = H`,
//! `β = 2H + 2` (tested). The approximation coefficient is 0 (zero mean).
//!
//! # Placement
//! Daubechies filters are asymmetric: the basis function of DWT index `k` at
//! scale `2^J` has its energy at `2^J k + c_J` with `c_J` of several cells
//! for db8 (and different for φ and ψ). Indexing the tree directly by DWT
//! index would put children several parent widths away from their parent
//! and spread the three coefficients of one position apart. Each level is
//! therefore shifted (circularly) so that tree position `m` at scale `2^J`
//! is centred on `2^J (m + 1/2)` as in II eq 20. For Haar the shift is 0.
//!
//! # Randomness
//! One [`crate::synth::rng_for`]`(seed, index)` stream per image; children in
//! a fixed order (levels coarse to fine, parents row-major, children
//! `(0,0), (0,1), (1,0), (1,1)`), and per child: `M`, then θ, then φ as the
//! variant needs.

use std::f64::consts::{FRAC_PI_2, LN_2, PI};

use ndarray::Array2;
use rand::RngExt;
use rand_distr::{Distribution, Poisson, StandardNormal};
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
pub use crate::synth::dwt::Basis;
use crate::synth::dwt::{Dwt2, energy_centre};
use crate::synth::fisc::steps_for_size;
use crate::synth::{SynthRng, rng_for};

/// Law of the multiplier `M`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "law", rename_all = "lowercase")]
pub enum Law {
    /// `ln M ~ Normal(m, σ²)` (II eq 29).
    LogNormal {
        /// Mean `m` of `ln M` (natural log; paper preset `-0.38 ln 2`).
        m: f64,
        /// Variance `σ²` of `ln M` (paper preset `0.03 ln 2`).
        sigma2: f64,
    },
    /// `ln M = Y ln β + γ`, `Y ~ Poisson(λ)` (II eq 37); `0 < β < 1`.
    LogPoisson {
        /// Additive constant `γ` of `ln M` (paper preset `-ln2/9`).
        gamma: f64,
        /// Multiplicative jump `β` in (0, 1) (paper preset `(2/3)^(1/3)`).
        beta: f64,
        /// Poisson mean `λ` (paper preset `2 ln 2`).
        lambda: f64,
    },
}

/// How the modulus is spread over ψ1, ψ2, ψ3 (II Fig 5).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum Isotropy {
    /// ψ1, ψ2, ψ3 with the weights of II eqs 35-36 (Fig 5e).
    #[default]
    Isotropic,
    /// ψ1 and ψ2 only (Fig 5a): enhanced `k_x`, `k_y` axes.
    Psi12,
    /// ψ3 only (Fig 5c): diagonal texture.
    Psi3,
}

impl Isotropy {
    /// Lowercase name as on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Isotropy::Isotropic => "isotropic",
            Isotropy::Psi12 => "psi12",
            Isotropy::Psi3 => "psi3",
        }
    }
}

/// Parameters of a W-cascade.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct WCascadeParams {
    /// Law of the multiplier `M`.
    pub law: Law,
    /// How the modulus is spread over ψ1, ψ2, ψ3 (default isotropic).
    #[serde(default)]
    pub isotropy: Isotropy,
    /// Orthonormal wavelet basis of the inverse DWT (default db8).
    #[serde(default)]
    pub basis: Basis,
}

impl Law {
    /// `lognormal` or `logpoisson`, as on the command line (`--law`).
    pub fn name(&self) -> &'static str {
        match self {
            Law::LogNormal { .. } => "lognormal",
            Law::LogPoisson { .. } => "logpoisson",
        }
    }

    /// **Errors** (naming `m`, `sigma2`, `gamma`, `beta` or `lambda`) on
    /// non-finite values, `σ² < 0`, `λ <= 0`, `β` outside (0, 1), or a
    /// cascade that does not converge to a continuous function, i.e.
    /// `h_min <= 0` (II eqs 31-32; for log-normal `m < 0` and
    /// `|m|/σ > 2√ln2`, see [`crate::theory::wcascade`]).
    pub fn validate(&self) -> Result<()> {
        let finite = |name: &str, v: f64| {
            if v.is_finite() {
                Ok(())
            } else {
                Err(Error::param(
                    name,
                    format!("must be finite, got {v_s}", v_s = crate::error::short(v)),
                ))
            }
        };
        match *self {
            Law::LogNormal { m, sigma2 } => {
                finite("m", m)?;
                finite("sigma2", sigma2)?;
                if sigma2 < 0.0 {
                    return Err(Error::param(
                        "sigma2",
                        format!(
                            "the variance of ln M must be >= 0, got {sigma2_s}",
                            sigma2_s = crate::error::short(sigma2)
                        ),
                    ));
                }
                if m >= 0.0 {
                    return Err(Error::param(
                        "m",
                        format!(
                            "need m < 0 (II eq 31; h(0) = -m/ln2 > 0), got {m_s}",
                            m_s = crate::error::short(m)
                        ),
                    ));
                }
                let (h_min, _) = self.h_range();
                if h_min <= 0.0 {
                    return Err(Error::param(
                        "sigma2",
                        format!(
                            "the cascade does not converge: need |m|/sigma > 2 sqrt(ln 2) = {:.4} \
                             (h_min = -m/ln2 - 2 sigma/sqrt(ln2) > 0 by II eq 32; II eq 31 prints sigma^2 \
                             for sigma, which mixes units), \
                             got |m|/sigma = {:.4}, h_min = {h_min:.4}",
                            2.0 * LN_2.sqrt(),
                            -m / sigma2.sqrt(),
                        ),
                    ));
                }
            }
            Law::LogPoisson {
                gamma,
                beta,
                lambda,
            } => {
                finite("gamma", gamma)?;
                finite("beta", beta)?;
                finite("lambda", lambda)?;
                if !(lambda > 0.0 && lambda < Poisson::<f64>::MAX_LAMBDA) {
                    return Err(Error::param(
                        "lambda",
                        format!(
                            "the Poisson mean must be in (0, {:e}), got {lambda_s}",
                            Poisson::<f64>::MAX_LAMBDA,
                            lambda_s = crate::error::short(lambda)
                        ),
                    ));
                }
                if !(beta > 0.0 && beta < 1.0) {
                    return Err(Error::param(
                        "beta",
                        format!(
                            "need 0 < beta < 1 (ln M = Y ln beta + gamma), got {beta_s}",
                            beta_s = crate::error::short(beta)
                        ),
                    ));
                }
                let (h_min, _) = self.h_range();
                if h_min <= 0.0 {
                    // the asymptote -γ/ln2 is γ's; a zero of D inside is λ's
                    let name = if gamma >= 0.0 { "gamma" } else { "lambda" };
                    return Err(Error::param(
                        name,
                        format!(
                            "the cascade does not converge: h_min = {h_min:.4} <= 0 \
                             (need D(h) < 0 for all h <= 0; II eqs 37-38)"
                        ),
                    ));
                }
            }
        }
        Ok(())
    }
}

impl WCascadeParams {
    /// **Errors** on an invalid law (see [`Law::validate`]), or, for the
    /// isotropic variant, `τ(2) < -6` where II eq 36 has no root in
    /// (0, π/2].
    pub fn validate(&self) -> Result<()> {
        self.law.validate()?;
        if self.isotropy == Isotropy::Isotropic && self.law.tau(2.0) < -6.0 {
            return Err(Error::param(
                "isotropy",
                format!(
                    "isotropic weights need tau(2) >= -6 (II eq 36), got {:.4}",
                    self.law.tau(2.0)
                ),
            ));
        }
        Ok(())
    }

    /// `φ*` of II eq 36: the root in (0, π/2] of
    /// `sin(2φ)/(4φ) = r/(1+r) - 1/2`, `r = 2^(τ(2)/2 + 3)`. The left side
    /// falls monotonically from 1/2 (φ -> 0) to 0 (φ = π/2); bisection.
    ///
    /// A very smooth law (`τ(2)` in the thousands) makes `r` infinite: the
    /// right side is then 1/2 and the root its limit `φ* -> 0`.
    ///
    /// **Panics** if `τ(2) < -6` (rejected by [`WCascadeParams::validate`]).
    pub fn phi_star(&self) -> f64 {
        let r = 2f64.powf(self.law.tau(2.0) / 2.0 + 3.0);
        // (inf/inf would be NaN; the finite form is kept for its bits)
        let rhs = if r.is_finite() {
            r / (1.0 + r) - 0.5
        } else {
            0.5
        };
        assert!(rhs >= 0.0, "II eq 36 has no root for tau(2) < -6");
        let f = |phi: f64| (2.0 * phi).sin() / (4.0 * phi) - rhs;
        let (mut lo, mut hi) = (1e-300, FRAC_PI_2);
        if f(hi) >= 0.0 {
            return hi;
        }
        for _ in 0..200 {
            let mid = 0.5 * (lo + hi);
            if mid <= lo || mid >= hi {
                break;
            }
            if f(mid) > 0.0 {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        0.5 * (lo + hi)
    }

    /// Coefficients `(c1, c2, c3)` of the single position of level 0
    /// (II eqs 33-35; see the module doc for eq 35).
    pub fn start_coefficients(&self) -> [f64; 3] {
        match self.isotropy {
            Isotropy::Isotropic => [1.0, 1.0, 2f64.powf(-(self.law.tau(2.0) / 4.0 + 1.0))],
            Isotropy::Psi12 => [1.0, 1.0, 0.0],
            Isotropy::Psi3 => [0.0, 0.0, 1.0],
        }
    }
}

/// A sampler of `ln M` built once (the Poisson set-up is not free).
enum LnM {
    Normal {
        m: f64,
        s: f64,
    },
    Poisson {
        gamma: f64,
        ln_beta: f64,
        y: Poisson<f64>,
    },
}

impl LnM {
    fn new(law: &Law) -> Self {
        match *law {
            Law::LogNormal { m, sigma2 } => LnM::Normal {
                m,
                s: sigma2.sqrt(),
            },
            Law::LogPoisson {
                gamma,
                beta,
                lambda,
            } => LnM::Poisson {
                gamma,
                ln_beta: beta.ln(),
                y: Poisson::new(lambda).expect("lambda validated > 0"),
            },
        }
    }

    fn sample(&self, rng: &mut SynthRng) -> f64 {
        match self {
            LnM::Normal { m, s } => {
                if *s == 0.0 {
                    *m
                } else {
                    let z: f64 = StandardNormal.sample(rng);
                    m + s * z
                }
            }
            LnM::Poisson { gamma, ln_beta, y } => y.sample(rng) * ln_beta + gamma,
        }
    }
}

/// Runs the cascade for `steps` levels (`s = 0 .. steps-1`), calling
/// `visit(s, ty, tx, d, ln d, [c1, c2, c3])` for every position in tree
/// order (amplitudes, not yet L2-scaled). `ln d` is carried as a sum of
/// logs: a product of multipliers can underflow to 0 (two jumps of a
/// log-Poisson law with beta = 1e-200), its log does not.
fn run_cascade(
    params: &WCascadeParams,
    steps: usize,
    rng: &mut SynthRng,
    mut visit: impl FnMut(usize, usize, usize, f64, f64, [f64; 3]),
) {
    let ln_m = LnM::new(&params.law);
    let phi_star = match params.isotropy {
        Isotropy::Isotropic => params.phi_star(),
        _ => 0.0,
    };
    let c0 = params.start_coefficients();
    let d0 = (c0[0] * c0[0] + c0[1] * c0[1] + c0[2] * c0[2]).sqrt();
    visit(0, 0, 0, d0, d0.ln(), c0);
    let n = 1usize << steps.saturating_sub(1);
    let mut cur = vec![0.0; n * n];
    let mut next = vec![0.0; n * n];
    let mut cur_ln = vec![0.0; n * n];
    let mut next_ln = vec![0.0; n * n];
    cur[0] = d0;
    cur_ln[0] = d0.ln();
    for s in 1..steps {
        let (pw, cw) = (1usize << (s - 1), 1usize << s);
        for py in 0..pw {
            for px in 0..pw {
                let (dp, lp) = (cur[py * pw + px], cur_ln[py * pw + px]);
                for (dy, dx) in [(0, 0), (0, 1), (1, 0), (1, 1)] {
                    let (ty, tx) = (2 * py + dy, 2 * px + dx);
                    let x = ln_m.sample(rng);
                    let d = dp * x.exp();
                    let ld = lp + x;
                    let c = match params.isotropy {
                        Isotropy::Isotropic => {
                            let theta = rng.random_range(-PI..PI);
                            let phi = rng.random_range(-phi_star..=phi_star);
                            let (sp, cp) = phi.sin_cos();
                            let (st, ct) = theta.sin_cos();
                            [cp * ct * d, cp * st * d, sp * d]
                        }
                        Isotropy::Psi12 => {
                            let (st, ct) = rng.random_range(-PI..PI).sin_cos();
                            [ct * d, st * d, 0.0]
                        }
                        Isotropy::Psi3 => {
                            // φ = ±π/2 exactly: cos φ is 0, not 6e-17
                            let sign = if rng.random::<bool>() { 1.0 } else { -1.0 };
                            [0.0, 0.0, sign * d]
                        }
                    };
                    next[ty * cw + tx] = d;
                    next_ln[ty * cw + tx] = ld;
                    visit(s, ty, tx, d, ld, c);
                }
            }
        }
        std::mem::swap(&mut cur, &mut next);
        std::mem::swap(&mut cur_ln, &mut next_ln);
    }
}

/// Per level `s` (scale `2^J`, `J = N - s`), the circular index shifts that
/// centre the scaling function and the wavelet of tree position `m` on
/// `2^J (m + 1/2)`: DWT index = `(m - shift) mod 2^s`.
fn level_shifts(basis: Basis, steps: usize) -> Vec<(i64, i64)> {
    (0..steps)
        .map(|s| {
            let j = steps - s;
            let w = (1u64 << j) as f64;
            let target = (w - 1.0) / 2.0;
            let shift = |wavelet| ((energy_centre(basis, j, wavelet) - target) / w).round() as i64;
            (shift(false), shift(true))
        })
        .collect()
}

/// The W-cascade's DWT coefficients (Mallat layout, L2-scaled, approximation
/// 0) of image `index` of the ensemble `seed`: [`wcascade`] is their inverse
/// DWT over `log2 size` levels.
///
/// **Errors** on invalid parameters or a size that is not a power of two.
pub fn wcascade_coefficients(
    params: &WCascadeParams,
    size: usize,
    seed: u64,
    index: u64,
) -> Result<Array2<f64>> {
    params.validate()?;
    let steps = steps_for_size(size)?;
    // the typical coefficient of the finest level is 2^(-h(0) n) of the
    // root's (II eq 27): past ~2^-1000 it underflows double precision and
    // the image holds only the coarse levels
    let h0 = -params.law.cumulants()[0];
    if h0 * steps as f64 > 1000.0 {
        let (name, law) = match params.law {
            Law::LogNormal { .. } => ("m", "m"),
            // the larger of the two terms of h(0) names the flag
            Law::LogPoisson {
                gamma,
                beta,
                lambda,
            } => (
                if -gamma >= -lambda * beta.ln() {
                    "gamma"
                } else {
                    "lambda"
                },
                "gamma + lambda ln beta",
            ),
        };
        return Err(Error::param(
            name,
            format!(
                "h(0) = {h0:.4e} is too large for {steps} cascade steps: the finest \
                 coefficients, about 2^-{:.3e} of the root's, underflow double precision \
                 (need h(0) * steps <= 1000; h(0) = -({law})/ln 2)",
                h0 * steps as f64
            ),
        ));
    }
    let shifts = level_shifts(params.basis, steps);
    let mut coef = Array2::<f64>::zeros((size, size));
    let mut rng = rng_for(seed, index);
    run_cascade(params, steps, &mut rng, |s, ty, tx, _d, _, c| {
        let n = 1i64 << s;
        let l2 = (1u64 << (steps - s)) as f64; // amplitude -> L2: times 2^(N-s)
        let (sh_phi, sh_psi) = shifts[s];
        let wrap = |m: usize, sh: i64| (m as i64 - sh).rem_euclid(n) as usize;
        let nu = n as usize;
        // ψ1 = φ(x)ψ(y): rows y-high, cols x-low
        coef[[nu + wrap(ty, sh_psi), wrap(tx, sh_phi)]] = l2 * c[0];
        // ψ2 = ψ(x)φ(y): rows y-low, cols x-high
        coef[[wrap(ty, sh_phi), nu + wrap(tx, sh_psi)]] = l2 * c[1];
        // ψ3 = ψ(x)ψ(y)
        coef[[nu + wrap(ty, sh_psi), nu + wrap(tx, sh_psi)]] = l2 * c[2];
    });
    Ok(coef)
}

/// The amplitudes `d` of image `index` of the ensemble `seed`, one
/// `2^s x 2^s` array per level `s = 0 .. log2(size) - 1`, in tree order
/// (children of `(y, x)` at `(2y + i, 2x + j)`): for tests of the cascade.
///
/// **Errors** on invalid parameters or a size that is not a power of two.
pub fn wcascade_moduli(
    params: &WCascadeParams,
    size: usize,
    seed: u64,
    index: u64,
) -> Result<Vec<Array2<f64>>> {
    tree_levels(params, size, seed, index, |d, _| d)
}

/// [`wcascade_moduli`] as `ln d`: finite where a product of multipliers
/// underflows `d` to 0 (the log is carried as a sum beside `d`), and
/// `d.ln()` itself wherever `d` is a normal number.
///
/// **Errors** on invalid parameters or a size that is not a power of two.
pub fn wcascade_ln_moduli(
    params: &WCascadeParams,
    size: usize,
    seed: u64,
    index: u64,
) -> Result<Vec<Array2<f64>>> {
    tree_levels(params, size, seed, index, |d, ln_d| {
        if d.is_normal() { d.ln() } else { ln_d }
    })
}

/// One `2^s x 2^s` array per level of `value(d, ln d)`, in tree order.
fn tree_levels(
    params: &WCascadeParams,
    size: usize,
    seed: u64,
    index: u64,
    value: impl Fn(f64, f64) -> f64,
) -> Result<Vec<Array2<f64>>> {
    params.validate()?;
    let steps = steps_for_size(size)?;
    let mut levels: Vec<Array2<f64>> = (0..steps)
        .map(|s| Array2::zeros((1 << s, 1 << s)))
        .collect();
    let mut rng = rng_for(seed, index);
    run_cascade(params, steps, &mut rng, |s, ty, tx, d, ln_d, _| {
        levels[s][[ty, tx]] = value(d, ln_d);
    });
    Ok(levels)
}

/// `log2` of the amplitudes `d` of image `index` of the ensemble `seed` at
/// the levels `levels` (level `s` has `4^s` amplitudes and scale `size / 2^s`
/// px), row-major as in [`wcascade_moduli`]: the generator's own cascade, whose
/// partition function has the theoretical τ(q) in expectation at every level
/// ([`crate::theory::Model::sample_sums`]). Levels at or beyond
/// `log2 size` are empty.
///
/// **Errors** on invalid parameters, a size that is not a power of two, or
/// levels reaching past `log2 size + 1`.
pub fn wcascade_log2_amplitudes(
    params: &WCascadeParams,
    size: usize,
    seed: u64,
    index: u64,
    levels: std::ops::Range<usize>,
) -> Result<Vec<Vec<f64>>> {
    params.validate()?;
    let steps = steps_for_size(size)?;
    super::check_levels(&levels, steps, size)?;
    let mut out: Vec<Vec<f64>> = levels
        .clone()
        .map(|s| {
            if s < steps {
                vec![0.0; 1 << (2 * s)]
            } else {
                Vec::new()
            }
        })
        .collect();
    let mut rng = rng_for(seed, index);
    run_cascade(params, steps, &mut rng, |s, ty, tx, d, ln_d, _| {
        if levels.contains(&s) {
            // log2 of d itself while d is a normal number (as always
            // before), from the carried log where d is subnormal or 0
            out[s - levels.start][(ty << s) + tx] = if d.is_normal() {
                d.abs().log2()
            } else {
                ln_d / std::f64::consts::LN_2
            };
        }
    });
    Ok(out)
}

/// Image `index` of the W-cascade ensemble `seed`, `size x size` (a power of
/// two), periodic.
///
/// **Errors** on invalid parameters or a size that is not a power of two.
pub fn wcascade(
    params: &WCascadeParams,
    size: usize,
    seed: u64,
    index: u64,
) -> Result<Array2<f64>> {
    let mut f = wcascade_coefficients(params, size, seed, index)?;
    let steps = steps_for_size(size)?;
    Dwt2::new(params.basis).inverse(&mut f, steps)?;
    Ok(f)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two jumps of a log-Poisson law with beta = 1e-200 make a product of
    /// multipliers of 1e-400, 0 in double precision: the logs of the
    /// amplitudes stay finite (carried as sums; `validate`'s own-cascade
    /// criteria failed with "a magnitude is not finite"), equal to the
    /// logs of the amplitudes wherever those are normal numbers, and to
    /// the sum of the logs of the multipliers drawn along the path.
    #[test]
    fn log_amplitudes_survive_underflow() {
        let p = WCascadeParams {
            law: Law::LogPoisson {
                gamma: -0.1,
                beta: 1e-200,
                lambda: 0.1,
            },
            isotropy: Isotropy::Isotropic,
            basis: Basis::Db8,
        };
        p.validate().unwrap();
        let d = wcascade_moduli(&p, 256, 1, 0).unwrap();
        let l = wcascade_ln_moduli(&p, 256, 1, 0).unwrap();
        let mut under = 0;
        for (ds, ls) in d.iter().zip(&l) {
            for (&dv, &lv) in ds.iter().zip(ls) {
                assert!(lv.is_finite());
                if dv.is_normal() {
                    assert_eq!(lv, dv.ln());
                } else {
                    under += 1;
                    // at least two jumps of ln(1e-200) below the root
                    assert!(lv < 2.0 * (1e-200f64).ln() + 1.0, "{lv}");
                }
            }
        }
        assert!(
            under > 0,
            "no amplitude underflowed: the case tests nothing"
        );
        let lg = wcascade_log2_amplitudes(&p, 256, 1, 0, 0..8).unwrap();
        assert!(lg.iter().flatten().all(|v| v.is_finite()));
    }

    fn ln(m: f64, sigma2: f64) -> WCascadeParams {
        WCascadeParams {
            law: Law::LogNormal { m, sigma2 },
            isotropy: Isotropy::Isotropic,
            basis: Basis::Db8,
        }
    }

    #[test]
    fn validation_names_the_flag() {
        let l2 = LN_2;
        let e = ln(0.1, 0.01).validate().unwrap_err().to_string();
        assert!(e.contains("`m`"), "{e}");
        let e = ln(-0.3, -0.01).validate().unwrap_err().to_string();
        assert!(e.contains("`sigma2`"), "{e}");
        // |m|/σ² = 12.7 > 2√ln2 but |m|/σ = 0.38 ln2 / 0.2 = 1.3 < 1.67:
        // passes the printed reading of eq 31, fails h_min > 0
        let e = ln(-0.38 * l2, 0.04).validate().unwrap_err().to_string();
        assert!(e.contains("converge") && e.contains("`sigma2`"), "{e}");
        assert!(ln(-0.38 * l2, 0.03 * l2).validate().is_ok());
        assert!(ln(-0.4 * l2, 0.0).validate().is_ok());
        let lp = |gamma, beta, lambda| WCascadeParams {
            law: Law::LogPoisson {
                gamma,
                beta,
                lambda,
            },
            ..ln(-0.3, 0.0)
        };
        let e = lp(-0.1, 1.5, 1.0).validate().unwrap_err().to_string();
        assert!(e.contains("`beta`"), "{e}");
        let e = lp(-0.1, 0.5, 0.0).validate().unwrap_err().to_string();
        assert!(e.contains("`lambda`"), "{e}");
        let e = lp(0.1, 0.5, 1.0).validate().unwrap_err().to_string();
        assert!(e.contains("`gamma`"), "{e}");
        // γ >= 0 converges when λ's zero of D is above 0 (h_min 1.70)
        assert!(lp(0.05, 0.5, 5.0).validate().is_ok());
        // beyond what the Poisson sampler draws: an error, not a panic
        let e = lp(-1.0, 0.9999, 5e19).validate().unwrap_err().to_string();
        assert!(e.contains("`lambda`"), "{e}");
        // h(0) beyond 2^53: h_max is found (a fixed step of 1 never moved)
        for (g, l) in [(-1.0, 1e17), (-1e17, 1.0)] {
            assert!(lp(g, 0.5, l).validate().is_ok());
            let (lo, hi) = lp(g, 0.5, l).law.h_range();
            assert!(lo > 0.0 && hi > lo && hi.is_finite(), "{lo} {hi}");
        }
        let e = wcascade(&ln(-0.3, 0.01), 100, 0, 0)
            .unwrap_err()
            .to_string();
        assert!(e.contains("`size`"), "{e}");
    }

    /// Eq 36 solved: φ* satisfies it, and the resulting mean energy ratio
    /// <sin²φ>/<cos²φ> over U[-φ*, φ*] is 1/r (closed form of the average).
    #[test]
    fn phi_star_solves_eq36() {
        let p = ln(-0.38 * LN_2, 0.03 * LN_2);
        let phi = p.phi_star();
        let r = 2f64.powf(p.law.tau(2.0) / 2.0 + 3.0);
        let lhs = (2.0 * phi).sin() / (4.0 * phi);
        assert!((lhs - (r / (1.0 + r) - 0.5)).abs() < 1e-14);
        let sin2 = 0.5 - lhs;
        let cos2 = 0.5 + lhs;
        assert!((sin2 / cos2 - 1.0 / r).abs() < 1e-12);
        assert!(phi > 0.7 && phi < 0.8, "paper preset φ* = {phi}");
        // start ratio c3/c1 = sqrt(2/r), the mean amplitude ratio of eq 36
        let c = p.start_coefficients();
        assert!((c[2] / c[0] - (2.0 / r).sqrt()).abs() < 1e-12);
    }

    /// A law so smooth that `r = 2^(τ(2)/2 + 3)` overflows (here τ(2) is
    /// about 2300) passes the law's validation; eq 36's root is then its
    /// limit φ* -> 0, not a panic (inf/inf).
    #[test]
    fn phi_star_of_a_very_smooth_law() {
        let p = ln(-800.0, 10.0);
        p.validate().unwrap();
        assert!(!2f64.powf(p.law.tau(2.0) / 2.0 + 3.0).is_finite());
        let phi = p.phi_star();
        assert!(phi > 0.0 && phi < 1e-6, "φ* = {phi}");
        // such a law cannot be synthesised (r overflows only for h(0) >
        // ~1000): a clear error naming the flag, not an image of zeros
        let e = wcascade(&ln(-800.0, 10.0), 64, 1, 0)
            .unwrap_err()
            .to_string();
        assert!(e.contains("`m`") && e.contains("underflow"), "{e}");
        // log-Poisson: the flag of the larger term of h(0)
        let lp = |gamma: f64, lambda: f64| WCascadeParams {
            law: Law::LogPoisson {
                gamma,
                beta: 0.5,
                lambda,
            },
            ..ln(-0.3, 0.01)
        };
        let e = wcascade(&lp(0.0, 2000.0), 64, 1, 0)
            .unwrap_err()
            .to_string();
        assert!(e.contains("`lambda`") && e.contains("underflow"), "{e}");
        let e = wcascade(&lp(-2000.0, 2.0), 64, 1, 0)
            .unwrap_err()
            .to_string();
        assert!(e.contains("`gamma`") && e.contains("underflow"), "{e}");
    }

    /// Placement: the energy of the basis function of tree position m at
    /// level s lies in cell m (within half a cell). Built by inverting a
    /// unit coefficient placed as `wcascade_coefficients` places it.
    #[test]
    fn children_sit_under_their_parent() {
        let steps = 6;
        let size = 1usize << steps;
        for basis in [Basis::Haar, Basis::Db4, Basis::Db8] {
            let shifts = level_shifts(basis, steps);
            let mut dwt = Dwt2::new(basis);
            for (s, &(sh_phi, sh_psi)) in shifts.iter().enumerate().skip(2) {
                let n = 1usize << s;
                let cell = (size / n) as f64;
                let m = n / 2 + 1;
                let wrap = |sh: i64| (m as i64 - sh).rem_euclid(n as i64) as usize;
                // ψ1 = φ(x)ψ(y) at tree (m, m)
                let mut c = Array2::zeros((size, size));
                c[[n + wrap(sh_psi), wrap(sh_phi)]] = 1.0;
                dwt.inverse(&mut c, steps).unwrap();
                // circular mean position along each axis
                let centre = |axis: usize| {
                    let (mut sc, mut ss) = (0.0, 0.0);
                    for ((y, x), v) in c.indexed_iter() {
                        let t = if axis == 0 { y } else { x } as f64;
                        let a = 2.0 * PI * t / size as f64;
                        sc += v * v * a.cos();
                        ss += v * v * a.sin();
                    }
                    ss.atan2(sc).rem_euclid(2.0 * PI) * size as f64 / (2.0 * PI)
                };
                let want = cell * (m as f64 + 0.5) - 0.5;
                for axis in 0..2 {
                    let got = centre(axis);
                    assert!(
                        (got - want).abs() <= 0.5 * cell + 0.5,
                        "{basis} s={s} axis {axis}: centre {got}, cell centre {want}"
                    );
                }
            }
        }
    }

    #[cfg(feature = "cli")]
    #[test]
    fn cli_names_match() {
        use clap::ValueEnum;
        for b in [Basis::Haar, Basis::Db4, Basis::Db8] {
            assert_eq!(Basis::from_str(b.name(), false).unwrap(), b);
        }
        for i in [Isotropy::Isotropic, Isotropy::Psi12, Isotropy::Psi3] {
            assert_eq!(Isotropy::from_str(i.name(), false).unwrap(), i);
        }
    }
}
