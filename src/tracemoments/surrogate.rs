//! Errors of a lone field's universal estimates from surrogates: a
//! parametric bootstrap (Efron & Tibshirani 1993, §6.5).
//!
//! The tile jackknife of [`super::analyze_tiled`] treats the tiles of one
//! image as independent, which a cascade correlated over the whole image is
//! not ([`super::TILE_CAVEAT`]: 0.36-1.17 of the true scatter). Surrogates
//! answer the question directly, under a model: draw fields of the universal
//! model the data were fitted to (FIF, [`crate::synth::fif`], with the
//! estimated α, C1 and spectral H), of the data's shapes and missing pixels,
//! analyse each exactly as the data were, and read the scatter of their
//! estimates (the error of one analysis of such data), their mean minus the
//! parameters drawn with (the estimator's bias there), and how the
//! surrogates' own jackknife errors compare with their scatter (the
//! calibration of the errors printed for the data).
//!
//! What it cannot see: departures of the data from the universal FIF model
//! (a K(q) of another form, anisotropy, trends, quantisation). The errors
//! are those of the model at the estimated parameters, not of the data's
//! process; the tm diagnostics say when the model does not hold.
//!
//! Measured against the truth (`experiment_surrogate_coverage` in
//! tests/tracemoments.rs; README "Surrogate errors for one DEM"): on single
//! 256^2 fields with the topo-fif parameters the truth lies within 2
//! surrogate errors for 23-24 of 24 fields (tiles: 13-19); at C1 = 0.04
//! the estimates of α and C1 have heavy tails and the surrogate errors are
//! too small, by up to 2x (55 and 61 of 72; [`WEAK_C1`]).

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::{
    TraceMomentAccumulator, TraceMomentConfig, TraceMomentFitConfig, TraceMomentResult,
    analyze_tiled, finish_ensemble,
};
use crate::error::{Error, Result};
use crate::field::Field;
use crate::synth::fif::{FifParams, fif};

/// Fewest surrogates: a standard deviation of fewer is not an error bar.
pub const MIN_SURROGATES: usize = 8;

/// Below this C1 the surrogate errors of alpha and C1 were measured to
/// understate (a warning says so).
pub const WEAK_C1: f64 = 0.06;

/// Mixed into the seed of the surrogates' generator, so that surrogates
/// never reuse the noise of a field made by `wtmm synth` with the same seed
/// (image `i` of `synth --seed S` is FIF image `i` of seed `S`; a surrogate
/// drawn from it would share the data's errors: correlations 0.88 / 1.00 /
/// 0.43 for alpha / C1 / H measured on 12 fields).
const SURROGATE_STREAM: u64 = 0x5355_5252_4f47_4154; // "SURROGAT"

/// The FIF seed of the surrogates of `seed`.
pub fn surrogate_fif_seed(seed: u64) -> u64 {
    crate::synth::splitmix64(seed ^ SURROGATE_STREAM)
}

/// One surrogate ensemble's estimates and their reported (jackknife) errors.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SurrogateRun {
    /// Which draw (`0..count`); draws that failed are left out of the list.
    pub index: usize,
    /// α.
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub alpha: f64,
    /// Reported error of α.
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub alpha_stderr: f64,
    /// C1.
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub c1: f64,
    /// Reported error of C1.
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub c1_stderr: f64,
    /// Spectral H (NaN without it).
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub h: f64,
    /// Reported error of H (NaN without it).
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub h_stderr: f64,
}

/// A bias larger than the error (and resolved by the draws) moves the
/// estimate by more than its error bar: a warning saying so beside the
/// estimate. It is reported, not removed: removing it did not improve the
/// coverage on fields of known parameters (README, "Trace moments: which
/// flux, and honest errors").
fn bias_warning(name: &str, st: &SurrogateStat) -> Option<String> {
    (st.bias.abs() > st.sd && st.bias.abs() > 2.0 * st.bias_stderr).then(|| {
        format!(
            "{name}: biased: under the fitted model the estimator reads {:+.4} +- {:.4} off the \
             value it was drawn with, {:.1} times the error {:.4}; the estimate {name} = {:.4} \
             likely reads {} by about as much (not removed from it)",
            st.bias,
            st.bias_stderr,
            st.bias.abs() / st.sd,
            st.sd,
            st.input,
            if st.bias > 0.0 { "high" } else { "low" }
        )
    })
}

/// What the surrogates say of one estimate.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SurrogateStat {
    /// The value the surrogates were drawn with: the data's estimate (α
    /// capped at 2, the model's bound).
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub input: f64,
    /// Mean of the surrogates' estimates.
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub mean: f64,
    /// Standard deviation of the surrogates' estimates: the error of one
    /// analysis of data like these, if the model holds.
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub sd: f64,
    /// The central 68 % and 95 % of the surrogates' estimates (linear
    /// interpolation between order statistics): `[q2.5, q16, q84, q97.5]`.
    /// Half of `q84 - q16` is a scale that a few draws far off do not move;
    /// when `sd` is much larger the estimator has heavy tails here.
    #[serde(deserialize_with = "crate::nan_null::arr")]
    pub quantiles: [f64; 4],
    /// `mean - input`: the estimator's bias at these parameters.
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub bias: f64,
    /// Standard error of the bias, `sd / sqrt(n)`.
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub bias_stderr: f64,
    /// The rms of the surrogates' own reported errors over `sd`: 1 when the
    /// errors printed for the data are right, below 1 when they understate.
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub stderr_ratio: f64,
}

/// The surrogate errors of a trace-moment result ([`surrogate_errors`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SurrogateErrors {
    /// The model drawn from: `fif` (universal multifractal FIF).
    pub model: String,
    /// Its parameters (α, C1, H).
    pub params: FifParams,
    /// Surrogate ensembles drawn (each of the data's image count).
    pub count: usize,
    /// Of them, those with a universal fit (α, C1 and H finite).
    pub used: usize,
    /// The seed (surrogate ensemble `r`, image `i` is FIF image
    /// `r * images + i` of the seed [`surrogate_fif_seed`]`(seed)`).
    pub seed: u64,
    /// α.
    pub alpha: SurrogateStat,
    /// C1.
    pub c1: SurrogateStat,
    /// Spectral H.
    pub h: SurrogateStat,
    /// The estimates of each draw that gave a universal fit, in order.
    pub runs: Vec<SurrogateRun>,
    /// What the numbers mean and what they cannot see.
    pub notes: Vec<String>,
    /// What limits these numbers here: heavy tails, a weakly intermittent
    /// model, draws left out, alpha capped.
    pub warnings: Vec<String>,
}

/// **Errors** (named `surrogates`) below [`MIN_SURROGATES`]: callers can
/// refuse a count before any analysis.
pub fn check_surrogate_count(count: usize) -> Result<()> {
    if count < MIN_SURROGATES {
        return Err(Error::param(
            "surrogates",
            format!("need at least {MIN_SURROGATES}, got {count}"),
        ));
    }
    Ok(())
}

/// Analyses `fields` as `wtmm tm` does: over the tiles of every image
/// ([`analyze_tiled`]) for fewer than 3, else a jackknife over the images
/// ([`finish_ensemble`]).
pub fn analyze_fields(
    fields: &[Field],
    config: &TraceMomentConfig,
    fc: &TraceMomentFitConfig,
) -> Result<TraceMomentResult> {
    if fields.len() < 3 {
        return analyze_tiled(fields, config, fc).map(|r| r.1);
    }
    let parts = crate::par::try_map(fields.len(), |i| {
        let mut a = TraceMomentAccumulator::new(config.clone())?;
        a.add_field(&fields[i])?;
        Ok(a)
    })?;
    finish_ensemble(&parts, fc).map(|r| r.1)
}

/// The FIF parameters of a result's universal fit: α (capped at 2), C1 and
/// the spectral H.
///
/// **Errors** when the result has no universal fit or no spectral H, or
/// when they lie outside the model (α <= 0, C1 outside (0, 2), H outside
/// [0, 3)).
pub fn surrogate_params(res: &TraceMomentResult) -> Result<FifParams> {
    let h = res.h.unwrap_or(f64::NAN);
    if !(res.alpha.is_finite() && res.c1.is_finite() && h.is_finite()) {
        let v = |x: f64| {
            if x.is_finite() {
                format!("{x:.4}")
            } else {
                "not estimable".into()
            }
        };
        return Err(Error::Input(format!(
            "surrogates need the universal fit and the spectral H (alpha {}, C1 {}, H {})",
            v(res.alpha),
            v(res.c1),
            v(h)
        )));
    }
    let p = FifParams {
        alpha: res.alpha.min(2.0),
        c1: res.c1,
        hurst: h,
    };
    let outside = || {
        Error::Input(format!(
            "the estimates lie outside the universal model the surrogates are drawn from \
             (need alpha > 0 (above 2 it is drawn at 2), 0 < C1 < 2, 0 <= H < 3; got alpha \
             {:.3}, C1 {:.4}, H {:.3})",
            res.alpha, res.c1, h
        ))
    };
    // C1 = 0 has no cascade to draw (the generator refuses it)
    if !(p.alpha > 0.0 && p.c1 > 0.0 && p.c1 < 2.0 && (0.0..3.0).contains(&p.hurst)) {
        return Err(outside());
    }
    // the generator's own limits are the estimates' problem, not a
    // parameter the user gave
    p.validate().map_err(|_| outside())?;
    Ok(p)
}

/// Surrogate errors of `res`, the result of [`analyze_fields`] on `fields`
/// with `config` and `fc`: `count` ensembles of FIF fields with the
/// parameters of [`surrogate_params`], each of the data's image shapes and
/// missing pixels, analysed the same way. Deterministic for a `seed`
/// whatever the thread count. Costs `count` analyses of the data.
///
/// **Errors** as [`surrogate_params`], with `count` below
/// [`MIN_SURROGATES`], no field, or fewer than [`MIN_SURROGATES`]
/// surrogates with a universal fit.
pub fn surrogate_errors(
    fields: &[Field],
    res: &TraceMomentResult,
    config: &TraceMomentConfig,
    fc: &TraceMomentFitConfig,
    count: usize,
    seed: u64,
) -> Result<SurrogateErrors> {
    surrogate_errors_with_progress(fields, res, config, fc, count, seed, &|| {})
}

/// [`surrogate_errors`], calling `tick` once per draw analysed (from any
/// thread), for a progress bar.
pub fn surrogate_errors_with_progress(
    fields: &[Field],
    res: &TraceMomentResult,
    config: &TraceMomentConfig,
    fc: &TraceMomentFitConfig,
    count: usize,
    seed: u64,
    tick: &(dyn Fn() + Sync),
) -> Result<SurrogateErrors> {
    check_surrogate_count(count)?;
    if fields.is_empty() {
        return Err(Error::Input("no field given".into()));
    }
    let params = surrogate_params(res)?;
    let n_img = fields.len() as u64;
    let fif_seed = surrogate_fif_seed(seed);
    // a draw the generator or the analysis refuses (a field too
    // intermittent to simulate, no universal fit) is counted out, not
    // fatal: it is a draw of the model
    let runs: Vec<std::result::Result<SurrogateRun, String>> = (0..count)
        .into_par_iter()
        .map(|r| {
            let draw = || -> Result<SurrogateRun> {
                let set = fields
                    .iter()
                    .enumerate()
                    .map(|(i, f)| {
                        let (ny, nx) = f.dim();
                        let a = fif(&params, ny, nx, fif_seed, r as u64 * n_img + i as u64)?;
                        match &f.mask {
                            Some(m) => Field::with_mask(a, m.clone()),
                            None => Ok(Field::new(a)),
                        }
                    })
                    .collect::<Result<Vec<_>>>()?;
                let s = analyze_fields(&set, config, fc)?;
                Ok(SurrogateRun {
                    index: r,
                    alpha: s.alpha,
                    alpha_stderr: s.alpha_stderr,
                    c1: s.c1,
                    c1_stderr: s.c1_stderr,
                    h: s.h.unwrap_or(f64::NAN),
                    h_stderr: s.h_stderr.unwrap_or(f64::NAN),
                })
            };
            let out = match draw() {
                Ok(run) if run.alpha.is_finite() && run.c1.is_finite() && run.h.is_finite() => {
                    Ok(run)
                }
                Ok(_) => Err("no universal fit or no spectral H".to_string()),
                Err(e) => Err(e.to_string()),
            };
            tick();
            out
        })
        .collect();
    let good: Vec<SurrogateRun> = runs
        .iter()
        .filter_map(|r| r.as_ref().ok())
        .copied()
        .collect();
    let failures: Vec<&String> = runs.iter().filter_map(|r| r.as_ref().err()).collect();
    if good.len() < MIN_SURROGATES {
        return Err(Error::Input(format!(
            "only {} of {count} surrogates could be drawn and analysed (need {MIN_SURROGATES}){}",
            good.len(),
            failures
                .first()
                .map_or(String::new(), |e| format!("; the first failure: {e}"))
        )));
    }
    let stat = |input: f64, get: fn(&SurrogateRun) -> (f64, f64)| {
        let (v, se): (Vec<f64>, Vec<f64>) = good.iter().map(get).unzip();
        let n = v.len() as f64;
        let (mean, sd) = crate::stats::fit::mean_std(&v);
        let mut sorted = v;
        sorted.sort_by(f64::total_cmp);
        let quantile = |p: f64| {
            // type 7 of Hyndman & Fan (R's default)
            let h = p * (sorted.len() - 1) as f64;
            let (i, f) = (h.floor() as usize, h - h.floor());
            let next = sorted[(i + 1).min(sorted.len() - 1)];
            sorted[i] + f * (next - sorted[i])
        };
        let quantiles = [0.025, 0.16, 0.84, 0.975].map(quantile);
        let se: Vec<f64> = se.into_iter().filter(|s| s.is_finite()).collect();
        let rms = (se.iter().map(|s| s * s).sum::<f64>() / se.len().max(1) as f64).sqrt();
        SurrogateStat {
            input,
            mean,
            sd,
            quantiles,
            bias: mean - input,
            bias_stderr: sd / n.sqrt(),
            stderr_ratio: if se.is_empty() || sd == 0.0 {
                f64::NAN
            } else {
                rms / sd
            },
        }
    };
    let alpha = stat(params.alpha, |r| (r.alpha, r.alpha_stderr));
    let c1 = stat(params.c1, |r| (r.c1, r.c1_stderr));
    let h = stat(params.hurst, |r| (r.h, r.h_stderr));
    let notes = vec![
        "sd is the error of one analysis of data like these if they were a universal \
         multifractal (FIF) with these parameters; it cannot see departures from that model"
            .to_string(),
        "bias = mean - input is the estimator's bias at these parameters (not removed from \
         the estimates)"
            .to_string(),
    ];
    let mut warnings = Vec::new();
    if res.alpha > 2.0 {
        warnings.push(format!(
            "alpha {:.3} lies above the model's bound; the surrogates use alpha = 2, so their \
             K(2), hence their spectrum, differs from the K(2) the data's H was computed with",
            res.alpha
        ));
    }
    for (name, st) in [("alpha", &alpha), ("C1", &c1), ("H", &h)] {
        let half = (st.quantiles[2] - st.quantiles[1]) / 2.0;
        if st.sd > 1.5 * half {
            warnings.push(format!(
                "{name}: heavy tails: the surrogates' sd {:.4} is {:.1} times half their central \
                 68 % range ({:.4}); a few draws lie far off, so one analysis can too, and the \
                 sd itself varies between sets of draws",
                st.sd,
                st.sd / half,
                half
            ));
        }
    }
    warnings.extend(
        [("alpha", &alpha), ("C1", &c1), ("H", &h)]
            .into_iter()
            .filter_map(|(name, st)| bias_warning(name, st)),
    );
    if params.c1 < WEAK_C1 {
        warnings.push(format!(
            "C1 = {:.4} is below {WEAK_C1}: on weakly intermittent fields (alpha 1.5, C1 0.04, \
             H 0.5, 256^2) the estimates of alpha and C1 have heavy tails, and the truth lay \
             within 2 surrogate errors for only 55 (alpha) and 61 (C1) of 72 fields (68.7 \
             expected; rms z 1.4-2.9): read the errors of alpha and C1 as too small by up to 2x",
            params.c1
        ));
    }
    if !failures.is_empty() {
        warnings.push(format!(
            "{} of {count} surrogates could not be drawn or analysed and are left out (the \
             first: {})",
            failures.len(),
            failures[0]
        ));
    }
    Ok(SurrogateErrors {
        model: "fif".into(),
        params,
        count,
        used: good.len(),
        seed,
        alpha,
        c1,
        h,
        runs: good,
        notes,
        warnings,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Jacksboro's alpha (16 draws: bias +0.207 +- 0.017, sd 0.067) is
    /// warned of, high; a bias within the error, or not resolved by the
    /// draws, is not.
    #[test]
    fn a_bias_beyond_the_error_is_named() {
        let st = |bias: f64, sd: f64, n: f64| SurrogateStat {
            input: 1.494,
            mean: 1.494 + bias,
            sd,
            quantiles: [0.0; 4],
            bias,
            bias_stderr: sd / n.sqrt(),
            stderr_ratio: f64::NAN,
        };
        let w = bias_warning("alpha", &st(0.207, 0.067, 16.0)).expect("3 errors off");
        assert!(w.contains("3.1 times the error 0.0670"), "{w}");
        assert!(w.contains("alpha = 1.4940 likely reads high"), "{w}");
        let low = bias_warning("H", &st(-0.1, 0.05, 16.0)).expect("2 errors off");
        assert!(low.contains("reads low"), "{low}");
        assert_eq!(bias_warning("alpha", &st(0.05, 0.067, 16.0)), None);
        // 1.2 errors off, but 2 draws cannot tell it from 0 (bias se 0.85 sd)
        assert_eq!(bias_warning("alpha", &st(0.08, 0.067, 2.0)), None);
    }
}
