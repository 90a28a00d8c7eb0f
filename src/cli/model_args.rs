//! `MODEL [model options]` and `--preset NAME` (SPEC §13), shared by
//! `synth`, `theory`, `validate`, `compare`, `pdf`, `kernel`, `correlate`,
//! `analyze --theory` and `merge --theory`.

use clap::{Args, ValueEnum};

use crate::cwt::Wavelet;
use crate::error::{Error, Result};
use crate::synth::dwt::Basis;
use crate::synth::fbm::FbmParams;
use crate::synth::fif::FifParams;
use crate::synth::fisc::FiscParams;
use crate::synth::wcascade::{Isotropy, Law, WCascadeParams};
use crate::theory::{Model, PRESET_NAMES};

/// The generators.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum ModelName {
    Fbm,
    Wcascade,
    Fisc,
    /// Universal multifractal (fractionally integrated flux).
    Fif,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum LawName {
    Lognormal,
    Logpoisson,
}

/// Model parameters; which ones apply depends on the model.
#[derive(Args, Debug, Clone, Default)]
pub struct ModelOpts {
    /// A published parameter set (paper-fbm, paper-lognormal, paper-logpoisson, paper-fisc, topo-fif).
    #[arg(long)]
    pub preset: Option<String>,
    /// fbm: Hurst exponent H in (0, 1); fif: order H of the fractional integration of the flux.
    #[arg(long, allow_negative_numbers = true)]
    pub hurst: Option<f64>,
    /// fif: Lévy index alpha in (0, 2] (2 = log-normal generator).
    #[arg(long, allow_negative_numbers = true)]
    pub alpha: Option<f64>,
    /// fif: codimension of the mean C1 in [0, 2).
    #[arg(long, allow_negative_numbers = true)]
    pub c1: Option<f64>,
    /// wcascade: law of the multipliers.
    #[arg(long, value_enum)]
    pub law: Option<LawName>,
    /// wcascade lognormal: mean of ln M (e.g. -0.2634 = -0.38 ln 2).
    #[arg(long, allow_negative_numbers = true)]
    pub m: Option<f64>,
    /// wcascade lognormal: variance of ln M.
    #[arg(long, allow_negative_numbers = true)]
    pub sigma2: Option<f64>,
    /// wcascade logpoisson: ln M = Y ln beta + gamma.
    #[arg(long, allow_negative_numbers = true)]
    pub gamma: Option<f64>,
    /// wcascade logpoisson: beta in (0, 1).
    #[arg(long, allow_negative_numbers = true)]
    pub beta: Option<f64>,
    /// wcascade logpoisson: Poisson mean lambda.
    #[arg(long, allow_negative_numbers = true)]
    pub lambda: Option<f64>,
    /// wcascade: orthonormal wavelet basis (db8 = 8 vanishing moments, the paper's).
    #[arg(long, value_enum)]
    pub basis: Option<Basis>,
    /// wcascade: which detail coefficients carry the cascade (II Fig 5).
    #[arg(long, value_enum)]
    pub isotropy: Option<Isotropy>,
    /// fisc: p-model weight p in (0, 1/2].
    #[arg(long, allow_negative_numbers = true)]
    pub p: Option<f64>,
    /// fisc: fractional integration order H*.
    #[arg(long, allow_negative_numbers = true)]
    pub hstar: Option<f64>,
}

/// A resolved model, with the wavelet its preset recommends.
pub struct Resolved {
    pub model: Model,
    pub preset: Option<&'static str>,
    pub wavelet: Wavelet,
}

fn need(v: Option<f64>, flag: &str, model: &str) -> Result<f64> {
    v.ok_or_else(|| Error::param(flag, format!("required by the {model} model")))
}

impl ModelOpts {
    fn any_param(&self) -> bool {
        self.hurst.is_some()
            || self.alpha.is_some()
            || self.c1.is_some()
            || self.law.is_some()
            || self.m.is_some()
            || self.sigma2.is_some()
            || self.gamma.is_some()
            || self.beta.is_some()
            || self.lambda.is_some()
            || self.basis.is_some()
            || self.isotropy.is_some()
            || self.p.is_some()
            || self.hstar.is_some()
    }

    /// The model named by `name` with these options, or the preset.
    ///
    /// **Errors** if neither or both are given, a required option is
    /// missing, or a value is out of range (the message names the flag).
    pub fn resolve(&self, name: Option<ModelName>) -> Result<Resolved> {
        if let Some(p) = &self.preset {
            if name.is_some() || self.any_param() {
                return Err(Error::param(
                    "preset",
                    "give either --preset or MODEL with its options, not both",
                ));
            }
            let pr = Model::preset(p)?;
            return Ok(Resolved {
                model: pr.model,
                preset: Some(pr.name),
                wavelet: pr.wavelet,
            });
        }
        let Some(name) = name else {
            return Err(Error::param(
                "MODEL",
                format!(
                    "name a model (fbm, wcascade, fisc, fif) or a --preset ({})",
                    PRESET_NAMES.join(", ")
                ),
            ));
        };
        let model = match name {
            ModelName::Fbm => Model::Fbm(FbmParams {
                hurst: need(self.hurst, "hurst", "fbm")?,
            }),
            ModelName::Fisc => Model::Fisc(FiscParams {
                p: need(self.p, "p", "fisc")?,
                hstar: need(self.hstar, "hstar", "fisc")?,
            }),
            ModelName::Fif => Model::Fif(FifParams {
                alpha: need(self.alpha, "alpha", "fif")?,
                c1: need(self.c1, "c1", "fif")?,
                hurst: need(self.hurst, "hurst", "fif")?,
            }),
            ModelName::Wcascade => {
                let law = match self.law {
                    Some(LawName::Lognormal) => Law::LogNormal {
                        m: need(self.m, "m", "lognormal W-cascade")?,
                        sigma2: need(self.sigma2, "sigma2", "lognormal W-cascade")?,
                    },
                    Some(LawName::Logpoisson) => Law::LogPoisson {
                        gamma: need(self.gamma, "gamma", "logpoisson W-cascade")?,
                        beta: need(self.beta, "beta", "logpoisson W-cascade")?,
                        lambda: need(self.lambda, "lambda", "logpoisson W-cascade")?,
                    },
                    None => {
                        return Err(Error::param(
                            "law",
                            "required by the wcascade model (lognormal or logpoisson)",
                        ));
                    }
                };
                Model::WCascade(WCascadeParams {
                    law,
                    isotropy: self.isotropy.unwrap_or_default(),
                    basis: self.basis.unwrap_or_default(),
                })
            }
        };
        model.validate()?;
        let wavelet = match model {
            // h_max > 1 needs more vanishing moments (II §3.1)
            Model::Fisc(_) => Wavelet::Mexican,
            Model::Fif(_) if model.h_range().1 >= 1.0 => Wavelet::Mexican,
            _ => Wavelet::Gauss,
        };
        Ok(Resolved {
            model,
            preset: None,
            wavelet,
        })
    }
}
