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
    #[arg(long, allow_hyphen_values = true)]
    pub hurst: Option<f64>,
    /// fif: Lévy index alpha in (0, 2] (2 = log-normal generator).
    #[arg(long, allow_hyphen_values = true)]
    pub alpha: Option<f64>,
    /// fif: codimension of the mean C1 in [0, 2) (`synth` needs C1 > 0: C1 = 0 is a
    /// constant flux, a zero field).
    #[arg(long, allow_hyphen_values = true)]
    pub c1: Option<f64>,
    /// wcascade: law of the multipliers.
    #[arg(long, value_enum)]
    pub law: Option<LawName>,
    /// wcascade lognormal: mean of ln M (e.g. -0.2634 = -0.38 ln 2).
    #[arg(long, allow_hyphen_values = true)]
    pub m: Option<f64>,
    /// wcascade lognormal: variance of ln M.
    #[arg(long, allow_hyphen_values = true)]
    pub sigma2: Option<f64>,
    /// wcascade logpoisson: ln M = Y ln beta + gamma.
    #[arg(long, allow_hyphen_values = true)]
    pub gamma: Option<f64>,
    /// wcascade logpoisson: beta in (0, 1).
    #[arg(long, allow_hyphen_values = true)]
    pub beta: Option<f64>,
    /// wcascade logpoisson: Poisson mean lambda.
    #[arg(long, allow_hyphen_values = true)]
    pub lambda: Option<f64>,
    /// wcascade: orthonormal wavelet basis (db8 = 8 vanishing moments, the paper's).
    #[arg(long, value_enum)]
    pub basis: Option<Basis>,
    /// wcascade: which detail coefficients carry the cascade (II Fig 5).
    #[arg(long, value_enum)]
    pub isotropy: Option<Isotropy>,
    /// fisc: p-model weight p in (0, 1/2] (`synth` needs p < 1/2: p = 1/2 is a uniform
    /// measure, a zero field).
    #[arg(long, allow_hyphen_values = true)]
    pub p: Option<f64>,
    /// fisc: fractional integration order H*.
    #[arg(long, allow_hyphen_values = true)]
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
    /// The model options given on the command line, by flag name.
    fn given(&self) -> Vec<&'static str> {
        let mut v = Vec::new();
        let mut add = |set: bool, flag: &'static str| {
            if set {
                v.push(flag);
            }
        };
        add(self.hurst.is_some(), "hurst");
        add(self.alpha.is_some(), "alpha");
        add(self.c1.is_some(), "c1");
        add(self.law.is_some(), "law");
        add(self.m.is_some(), "m");
        add(self.sigma2.is_some(), "sigma2");
        add(self.gamma.is_some(), "gamma");
        add(self.beta.is_some(), "beta");
        add(self.lambda.is_some(), "lambda");
        add(self.basis.is_some(), "basis");
        add(self.isotropy.is_some(), "isotropy");
        add(self.p.is_some(), "p");
        add(self.hstar.is_some(), "hstar");
        v
    }

    /// Refuses options that the model ignores (a `--p` given to fbm would
    /// otherwise be dropped without a word).
    fn check_applicable(&self, name: ModelName) -> Result<()> {
        let (model, allowed): (&str, &[&str]) = match (name, self.law) {
            (ModelName::Fbm, _) => ("fbm", &["hurst"]),
            (ModelName::Fisc, _) => ("fisc", &["p", "hstar"]),
            (ModelName::Fif, _) => ("fif", &["alpha", "c1", "hurst"]),
            (ModelName::Wcascade, Some(LawName::Logpoisson)) => (
                "logpoisson W-cascade",
                &["law", "gamma", "beta", "lambda", "basis", "isotropy"],
            ),
            (ModelName::Wcascade, _) => (
                "lognormal W-cascade",
                &["law", "m", "sigma2", "basis", "isotropy"],
            ),
        };
        match self.given().into_iter().find(|f| !allowed.contains(f)) {
            Some(f) => Err(Error::param(
                f,
                format!(
                    "does not apply to the {model} model (its options: {})",
                    allowed
                        .iter()
                        .map(|a| format!("--{a}"))
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
            )),
            None => Ok(()),
        }
    }

    /// As [`ModelOpts::resolve`] where the model is optional (a theory drawn
    /// over estimates): `None` when neither MODEL nor `--preset` is given.
    ///
    /// **Errors** as `resolve`, and when model options come without a model.
    pub fn resolve_optional(&self, name: Option<ModelName>) -> Result<Option<Resolved>> {
        if name.is_some() || self.preset.is_some() {
            return self.resolve(name).map(Some);
        }
        if let Some(f) = self.given().first() {
            return Err(Error::param(
                *f,
                "model options need a model: --theory MODEL (or use --preset NAME)",
            ));
        }
        Ok(None)
    }

    /// The model named by `name` with these options, or the preset.
    ///
    /// **Errors** if neither or both are given, a required option is
    /// missing, or a value is out of range (the message names the flag).
    pub fn resolve(&self, name: Option<ModelName>) -> Result<Resolved> {
        if let Some(p) = &self.preset {
            let pr = Model::preset(p)?;
            // MODEL may name the preset's own model (`synth wcascade --preset
            // paper-lognormal`, as SPEC §13 reads); options may not change it
            if let Some(f) = self.given().first() {
                return Err(Error::param(
                    *f,
                    format!(
                        "--preset {} fixes every model option; give MODEL with all its options \
                         instead of the preset to change one",
                        pr.name
                    ),
                ));
            }
            if let Some(n) = name {
                let named = n.to_possible_value().map(|v| v.get_name().to_string());
                if named.as_deref() != Some(pr.model.name()) {
                    return Err(Error::param(
                        "preset",
                        format!(
                            "{} is a preset of the {} model, not of {}: drop MODEL (the preset \
                             names it)",
                            pr.name,
                            pr.model.name(),
                            named.unwrap_or_default()
                        ),
                    ));
                }
            }
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
        self.check_applicable(name)?;
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
        warn_caveats(&model);
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

/// Says on stderr, once per process, what the model's surfaces do not
/// deliver of its theory ([`Model::caveats`]): every command that names a
/// model resolves it, some more than once (`validate --replicates`).
fn warn_caveats(model: &Model) {
    static ONCE: std::sync::Once = std::sync::Once::new();
    // the caveats only once too (a W-cascade's cost a spectrum)
    ONCE.call_once(|| {
        for w in &model.caveats() {
            say!("warning: {w}");
        }
    });
}
