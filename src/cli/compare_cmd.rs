//! `wtmm compare MODEL|--preset NAME --count K --size N --out DIR`: the
//! scaling function τ(q) of one generated ensemble estimated two ways, both
//! against the closed form:
//!
//! * **WTMM**: partition functions over the wavelet skeleton (SPEC §4).
//! * **Trace moments + spectrum** (SPEC §8): K(q) of the flux and the
//!   spectral H, hence `τ(q) = qH - K(q) - 2` for a surface (q >= 0 only:
//!   trace moments of negative order are not defined for α < 2).
//!
//! **What the TM route should give.** With `ξ(q) = τ(q) + 2` the
//! structure-function exponents of the surface, `H = ξ(1)` and
//! `K(q) = q ξ(1) - ξ(q)` for every model whose gradient flux, averaged over
//! boxes of side l, scales like the cascade quantity behind the field:
//! exactly a FIF (`K` universal); a W-cascade (box averages of the finest
//! coefficients are the coarse coefficient times a converging "dressing"
//! factor, so `K(q) = log2 <M^q> - q log2 <M>`: universal with α = 2,
//! `C1 = σ²/(2 ln 2)` for the log-normal law); FISC (`K` of the p-model,
//! `H = H*`, not universal); fBm (`K = 0`, `H` = Hurst). These targets are
//! what the TM estimates are compared with; `alpha_target`/`C1_target` fit
//! the universal form to the target K(q) over the same q range as the
//! estimate (for a non-universal K they are the best universal description,
//! not parameters of the model).
//!
//! **Bias and scatter.** The ensemble is split into `--groups` sub-ensembles
//! of consecutive images; each method is also run on every sub-ensemble.
//! bias = full-ensemble estimate - theory; sd = standard deviation of the
//! sub-ensemble estimates; the standard error of the full estimate is
//! `sd / sqrt(groups)`, given only from [`MIN_SE_GROUPS`] groups up: the
//! spread of two is `|t1 - t2| / sqrt 2`, one degree of freedom, which falls
//! to 0 wherever their τ(q) cross, so `bias / se` took any size there
//! (1177 at q = 5 for 2 fBm images of 512², whose WTMM jackknife error is
//! 0.13); with three or more, a zero needs all to meet at the same q.
//!
//! **Timing.** Each image is generated, then analysed by both methods in the
//! same task (streamed: one image per worker alive); the per-method times
//! are thread-seconds summed over images.

use std::fmt::Write as _;
use std::path::Path;
use std::time::Instant;

use clap::Args;
use serde::Serialize;
use serde_json::json;

use super::analyze_cmd::{SpectraOpts, theory_curves};
use super::common::reason;
use super::common::save_chart;
use super::common::{f, header, make_out_dir, parse_range, progress, write_csv, write_json};
use super::model_args::{ModelName, ModelOpts};
use super::tm_cmd::{TmOpts, plot_k, tau_from_tm};
use super::validate_cmd::{distinct, warnings_section};
use super::{OutDir, Outcome};
use crate::error::{Error, Result};
use crate::field::Field;
use crate::io::write_atomic;
use crate::plot::{Chart, Series, Style};
use crate::skeleton::Parallelism;
use crate::spectra::{PartitionSums, Rule, Spectra, default_tile_side, image_sums_tiled};
use crate::stats::fit::mean_std;
use crate::theory::{Model, TheoryTable};
use crate::tracemoments::{
    TraceMomentAccumulator, TraceMomentConfig, TraceMomentResult, finish_ensemble, fit_universal,
};

#[derive(Args, Debug)]
pub struct CompareArgs {
    /// The generator (or use --preset).
    #[arg(value_enum)]
    pub model: Option<ModelName>,
    #[command(flatten)]
    pub model_opts: ModelOpts,
    /// Number of images.
    #[arg(long, default_value_t = 16)]
    pub count: usize,
    /// Image side (a power of two for the cascades).
    #[arg(long, default_value_t = 1024)]
    pub size: usize,
    /// Seed of the ensemble: image i is the same as `synth --seed S` image i,
    /// whatever the thread count.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Number of sub-ensembles (of consecutive images) for the scatter
    /// [default: 4, or the image count when it is smaller].
    #[arg(long)]
    pub groups: Option<usize>,
    /// q range of the bias/scatter summary, `LO:HI`.
    #[arg(long, default_value = "0:3")]
    pub summary_q: String,
    #[command(flatten)]
    pub opts: SpectraOpts,
    #[command(flatten)]
    pub tm: TmOpts,
    #[command(flatten)]
    pub out: OutDir,
}

impl CompareArgs {
    /// `--groups`, or its default: 4, fewer with fewer images.
    pub fn groups(&self) -> usize {
        self.groups.unwrap_or(self.count.min(4))
    }
}

/// Fewest sub-ensembles giving a value at a q for a standard error there
/// (module docs): below it `se` is NaN (null) and so is `bias / se`.
pub const MIN_SE_GROUPS: usize = 3;

/// Everything one image contributes.
struct ImageOut {
    sums: PartitionSums,
    acc: TraceMomentAccumulator,
    t_gen: f64,
    t_wtmm: f64,
    t_tm: f64,
}

/// One method's τ(q) on the compare grid.
#[derive(Clone, Debug, Serialize)]
pub struct MethodTau {
    pub method: String,
    pub tau: Vec<f64>,
    /// `tau - theory`.
    pub bias: Vec<f64>,
    /// Standard deviation of the sub-ensemble estimates.
    pub sd_groups: Vec<f64>,
    /// `sd_groups / sqrt(groups)`; NaN (null) where fewer than
    /// [`MIN_SE_GROUPS`] sub-ensembles give a value.
    pub se: Vec<f64>,
    /// Per sub-ensemble.
    pub groups: Vec<Vec<f64>>,
}

/// Bias and scatter of one method over a q range.
#[derive(Clone, Debug, Serialize)]
pub struct Summary {
    pub method: String,
    pub q_range: (f64, f64),
    pub n_q: usize,
    pub max_abs_bias: f64,
    pub q_of_max_abs_bias: f64,
    pub rms_bias: f64,
    /// Root mean square over q of the sub-ensemble standard deviations.
    pub rms_sd_groups: f64,
    /// Largest `|bias| / se` over the q that have an `se`; NaN (null)
    /// where none has (fewer than [`MIN_SE_GROUPS`] sub-ensembles).
    pub max_abs_bias_over_se: f64,
}

/// A scalar estimate with its sub-ensemble scatter and target.
#[derive(Clone, Debug, Serialize)]
pub struct Scalar {
    pub value: f64,
    pub sd_groups: f64,
    pub target: f64,
}

fn scalar(value: f64, groups: &[f64], target: f64) -> Scalar {
    let v: Vec<f64> = groups.iter().copied().filter(|x| x.is_finite()).collect();
    Scalar {
        value,
        sd_groups: mean_std(&v).1,
        target,
    }
}

fn method_tau(name: &str, tau: Vec<f64>, groups: Vec<Vec<f64>>, theory: &[f64]) -> MethodTau {
    let (mut sd, mut se) = (Vec::with_capacity(tau.len()), Vec::with_capacity(tau.len()));
    for i in 0..tau.len() {
        let v: Vec<f64> = groups
            .iter()
            .map(|t| t[i])
            .filter(|x| x.is_finite())
            .collect();
        // NaN with fewer than 2 finite groups; the error of the mean over
        // the groups that gave a value, from 3 of them (module docs)
        let s = mean_std(&v).1;
        sd.push(s);
        se.push(if v.len() >= MIN_SE_GROUPS {
            s / (v.len() as f64).sqrt()
        } else {
            f64::NAN
        });
    }
    MethodTau {
        method: name.into(),
        bias: tau.iter().zip(theory).map(|(a, b)| a - b).collect(),
        se,
        sd_groups: sd,
        tau,
        groups,
    }
}

fn summarise(m: &MethodTau, q: &[f64], range: (f64, f64)) -> Summary {
    let idx: Vec<usize> = (0..q.len())
        .filter(|&i| q[i] >= range.0 - 1e-12 && q[i] <= range.1 + 1e-12 && m.bias[i].is_finite())
        .collect();
    let n = idx.len();
    let (mut worst, mut q_worst, mut ss) = (0.0f64, f64::NAN, 0.0);
    // the scatter only over the q where the groups gave one (a single
    // group, or groups without a value, have none: NaN, not 0)
    let (mut sds, mut n_sd, mut z, mut n_z) = (0.0, 0usize, 0.0f64, 0usize);
    for &i in &idx {
        let b = m.bias[i].abs();
        if b >= worst {
            worst = b;
            q_worst = q[i];
        }
        ss += b * b;
        if m.sd_groups[i].is_finite() {
            sds += m.sd_groups[i].powi(2);
            n_sd += 1;
        }
        if m.se[i] > 0.0 {
            z = z.max(b / m.se[i]);
            n_z += 1;
        }
    }
    let nan_if_none = |v: f64, k: usize| if k == 0 { f64::NAN } else { v };
    Summary {
        method: m.method.clone(),
        q_range: range,
        n_q: n,
        max_abs_bias: nan_if_none(worst, n),
        q_of_max_abs_bias: q_worst,
        rms_bias: nan_if_none((ss / n.max(1) as f64).sqrt(), n),
        rms_sd_groups: nan_if_none((sds / n_sd.max(1) as f64).sqrt(), n_sd),
        max_abs_bias_over_se: nan_if_none(z, n_z),
    }
}

/// Index of `v` in `grid` (exact up to 1e-9).
fn find(grid: &[f64], v: f64) -> Option<usize> {
    grid.iter().position(|&g| (g - v).abs() < 1e-9)
}

pub fn run(args: CompareArgs, quiet: bool) -> Result<Outcome> {
    // arguments -> typed options (every check before any work)
    let r = args.model_opts.resolve(args.model)?;
    let model = r.model;
    let mut opts = args.opts.clone();
    if opts.line.cwt.wavelet.is_none() {
        opts.line.cwt.wavelet = Some(r.wavelet);
    }
    if opts.line.detrend != crate::field::Trend::None {
        // the trace moments would see the raw fields: no comparison (said
        // before the torus's refusal, whose way out would lead here)
        return Err(Error::param(
            "detrend",
            "compare analyses generated fields, which are not tilted (the planes an fBm \
             shows are its own large scales, and a plane removed from a periodic model is \
             a jump across its edges): drop --detrend; analyze and tm take it for tilted \
             images",
        ));
    }
    opts.line.cwt.torus_for(&model);
    let cfg = opts.analysis()?;
    let fit = opts.fit()?;
    // H = tau(1) + 2 and beta = tau(2) + 4 need q = 1 and 2 on the grid
    let mut q = opts.q()?;
    for need in [1.0, 2.0] {
        if find(&q, need).is_none() {
            q.push(need);
        }
    }
    q.sort_by(f64::total_cmp);
    let rule = opts.rule();
    super::common::check_generated(args.size, args.count)?;
    if args.groups() == 0 || args.groups() > args.count {
        return Err(Error::param(
            "groups",
            format!(
                "must be in 1..={} (the image count), got {}",
                args.count,
                args.groups()
            ),
        ));
    }
    model.check_size(args.size)?;
    super::common::check_generated_size(&cfg, args.size)?;
    // fewer images in flight than threads when the memory holds no more
    // (said in a note)
    let limit = super::common::check_ensemble_memory(args.size, args.count, "compare")?;
    let summary_q = parse_range("summary-q", &args.summary_q)?;
    if !q.iter().any(|&v| v >= summary_q.0 && v <= summary_q.1) {
        return Err(Error::param(
            "summary-q",
            format!(
                "{}:{} holds none of the q of --q ({} to {})",
                summary_q.0,
                summary_q.1,
                q[0],
                q[q.len() - 1]
            ),
        ));
    }
    // trace moments on a fine grid (for the universal fit) plus the q >= 0 of --q
    let mut tm_q = TraceMomentConfig::default().q;
    tm_q.extend(q.iter().copied().filter(|&v| v >= 0.0));
    tm_q.sort_by(f64::total_cmp);
    tm_q.dedup_by(|a, b| (*a - *b).abs() < 1e-9);
    let tm_cfg = args.tm.config(tm_q.clone(), model.is_periodic())?;
    let tm_fit = args.tm.fit()?;
    let shapes = vec![[args.size; 2]; args.count];
    crate::tracemoments::check_ensemble_fit(&tm_fit, &shapes)?;
    crate::tracemoments::check_fit_selectors(&tm_cfg, &tm_fit, &shapes)?;
    let name = r.preset.unwrap_or(model.name()).to_string();

    // library: stream the ensemble through both methods
    let t0 = Instant::now();
    let pb = progress(args.count as u64, "compare", quiet);
    // a refused draw is named by its index in order, whatever the scheduling
    let parts: Vec<ImageOut> = crate::par::try_map_limited(args.count, limit, |i| {
        let t = Instant::now();
        let field = Field::new(model.synthesize(args.size, args.seed, i as u64)?);
        let t_gen = t.elapsed().as_secs_f64();
        let t = Instant::now();
        // fewer than 3 images: the jackknife runs over tiles
        let side = if args.count < 3 {
            let (ny, nx) = field.dim();
            default_tile_side(&cfg, ny, nx)
        } else {
            0
        };
        let sums = image_sums_tiled(
            &field,
            &cfg,
            &q,
            format!("{name} image {i}"),
            Parallelism::Serial,
            side,
        )?;
        let t_wtmm = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let mut acc = TraceMomentAccumulator::new(tm_cfg.clone())?;
        acc.add_field(&field)?;
        let t_tm = t.elapsed().as_secs_f64();
        pb.inc(1);
        Ok(ImageOut {
            sums,
            acc,
            t_gen,
            t_wtmm,
            t_tm,
        })
    })?;
    pb.finish_and_clear();
    let wall = t0.elapsed().as_secs_f64();
    let member = |i: usize| i * args.groups() / args.count;
    let wtmm_of = |sel: &dyn Fn(usize) -> bool| -> Result<Spectra> {
        let s = PartitionSums::merge_all(
            parts
                .iter()
                .enumerate()
                .filter(|(i, _)| sel(*i))
                .map(|(_, p)| p.sums.clone()),
        )?
        .expect("non-empty selection");
        s.spectra(rule, fit)
    };
    let tm_of =
        |sel: &dyn Fn(usize) -> bool| -> Result<(TraceMomentAccumulator, TraceMomentResult)> {
            let mut acc = TraceMomentAccumulator::new(tm_cfg.clone())?;
            for (_, p) in parts.iter().enumerate().filter(|(i, _)| sel(*i)) {
                acc.merge(&p.acc)?;
            }
            let res = acc.finish(&tm_fit)?;
            Ok((acc, res))
        };
    let all_sums =
        PartitionSums::merge_all(parts.iter().map(|p| p.sums.clone()))?.expect("count >= 1");
    let w_all = all_sums.spectra(rule, fit)?;
    let w_other = all_sums.spectra(
        if rule == Rule::Sup {
            Rule::Plain
        } else {
            Rule::Sup
        },
        fit,
    )?;
    // full ensemble with jackknife errors over images
    let accs: Vec<TraceMomentAccumulator> = parts.iter().map(|p| p.acc.clone()).collect();
    let (tm_acc, t_all) = finish_ensemble(&accs, &tm_fit)?;
    let mut w_groups = Vec::with_capacity(args.groups());
    let mut t_groups = Vec::with_capacity(args.groups());
    for g in 0..args.groups() {
        // a sub-ensemble's failure names its images (the whole ensemble fitted)
        let images: Vec<usize> = (0..args.count).filter(|&i| member(i) == g).collect();
        let blame = |e: Error| -> Error {
            let which = match images.as_slice() {
                [one] => format!("image {one}"),
                [a, .., b] => format!("images {a}-{b}"),
                [] => "no image".into(),
            };
            let m = format!(
                "sub-ensemble {} of {} ({which} of {name}): {} (fewer --groups give each \
                 sub-ensemble more images)",
                g + 1,
                args.groups(),
                reason(e)
            );
            Error::Input(m)
        };
        w_groups.push(wtmm_of(&|i| member(i) == g).map_err(blame)?);
        t_groups.push(tm_of(&|i| member(i) == g).map_err(blame)?.1);
    }

    // theory and the TM targets (module docs)
    let th = TheoryTable::new(&model, &q)?;
    let xi = |v: f64| model.tau(v) + 2.0;
    let h_target = xi(1.0);
    let k_target: Vec<f64> = tm_q.iter().map(|&v| v * h_target - xi(v)).collect();
    let (alpha_target, c1_target) = {
        let (qs, ks): (Vec<f64>, Vec<f64>) = tm_q
            .iter()
            .zip(&k_target)
            .filter(|(v, _)| **v > 0.0 && **v <= t_all.universal_q_max + 1e-9)
            .map(|(a, b)| (*a, *b))
            .unzip();
        match model {
            Model::Fif(p) => (p.alpha, p.c1),
            _ if ks.iter().all(|k| k.abs() < 1e-12) => (f64::NAN, 0.0),
            _ => fit_universal(&qs, &ks).map_or((f64::NAN, f64::NAN), |u| (u.alpha, u.c1)),
        }
    };

    // τ(q) of both methods on the compare grid
    let tm_tau_on_grid = |res: &TraceMomentResult| -> Vec<f64> {
        let t = tau_from_tm(res);
        q.iter()
            .map(|&v| find(&res.q, v).map_or(f64::NAN, |j| t[j]))
            .collect()
    };
    let wtmm = method_tau(
        "WTMM",
        w_all.tau.clone(),
        w_groups.iter().map(|s| s.tau.clone()).collect(),
        &th.tau,
    );
    let tm = method_tau(
        "TM",
        tm_tau_on_grid(&t_all),
        t_groups.iter().map(&tm_tau_on_grid).collect(),
        &th.tau,
    );
    let q_lo = q.iter().copied().fold(f64::INFINITY, f64::min);
    let q_hi = q.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let summaries = vec![
        summarise(&wtmm, &q, summary_q),
        summarise(&tm, &q, summary_q),
        summarise(&wtmm, &q, (q_lo, q_hi)),
    ];

    // scalars: H, beta, alpha, C1
    let at = |s: &Spectra, v: f64| find(&s.q, v).map_or(f64::NAN, |i| s.tau[i]);
    let gvals = |fun: &dyn Fn(usize) -> f64| -> Vec<f64> { (0..args.groups()).map(fun).collect() };
    let beta_th = model.beta();
    let scalars: Vec<(&str, Scalar)> = vec![
        (
            "H_wtmm = tau(1) + 2",
            scalar(
                at(&w_all, 1.0) + 2.0,
                &gvals(&|g| at(&w_groups[g], 1.0) + 2.0),
                h_target,
            ),
        ),
        (
            "H_tm (spectrum)",
            scalar(
                t_all.h.unwrap_or(f64::NAN),
                &gvals(&|g| t_groups[g].h.unwrap_or(f64::NAN)),
                h_target,
            ),
        ),
        (
            "H_sf = xi(1)",
            scalar(
                t_all.h_sf.unwrap_or(f64::NAN),
                &gvals(&|g| t_groups[g].h_sf.unwrap_or(f64::NAN)),
                h_target,
            ),
        ),
        (
            "beta_wtmm = tau(2) + 4",
            scalar(
                at(&w_all, 2.0) + 4.0,
                &gvals(&|g| at(&w_groups[g], 2.0) + 4.0),
                beta_th,
            ),
        ),
        (
            "beta_spectrum (angle-averaged)",
            scalar(
                t_all.beta_averaged.unwrap_or(f64::NAN),
                &gvals(&|g| t_groups[g].beta_averaged.unwrap_or(f64::NAN)),
                beta_th,
            ),
        ),
        (
            "alpha (TM)",
            scalar(t_all.alpha, &gvals(&|g| t_groups[g].alpha), alpha_target),
        ),
        (
            "C1 (TM)",
            scalar(t_all.c1, &gvals(&|g| t_groups[g].c1), c1_target),
        ),
        (
            "alpha (DTM)",
            scalar(
                t_all.dtm_alpha,
                &gvals(&|g| t_groups[g].dtm_alpha),
                alpha_target,
            ),
        ),
        (
            "C1 (DTM)",
            scalar(t_all.dtm_c1, &gvals(&|g| t_groups[g].dtm_c1), c1_target),
        ),
    ];
    let sum_t = |fun: &dyn Fn(&ImageOut) -> f64| parts.iter().map(fun).sum::<f64>();
    let (s_gen, s_wtmm, s_tm) = (
        sum_t(&|p| p.t_gen),
        sum_t(&|p| p.t_wtmm),
        sum_t(&|p| p.t_tm),
    );
    let timing = json!({
        "wall_seconds": wall,
        "threads": rayon::current_num_threads(),
        // fewer than the threads when the memory holds no more images
        "images_in_flight": limit.unwrap_or(rayon::current_num_threads()).min(args.count),
        "generate_thread_seconds": s_gen,
        "wtmm_thread_seconds": s_wtmm,
        "tm_thread_seconds": s_tm,
        "wtmm_seconds_per_image": s_wtmm / args.count as f64,
        "tm_seconds_per_image": s_tm / args.count as f64,
        "note": "thread-seconds summed over images (each image is analysed by both methods in one task); wall_seconds covers generation and both analyses",
    });

    // writers
    let dir = &args.out.out;
    make_out_dir(dir)?;
    let params = json!({
        "model": model, "preset": r.preset, "count": args.count, "size": args.size,
        "seed": args.seed, "groups": args.groups(), "summary_q": summary_q,
        "wtmm": {"analysis": super::common::analysis_json(&cfg), "q": q, "fit_octaves": fit, "rule": rule},
        "tm": {"config": tm_cfg, "fit": super::tm_cmd::fit_record(&tm_fit, &t_all.universal_fit)},
    });
    let mut body = header("compare", params.clone());
    super::common::note_caveats(&mut body, Some(&r.model));
    body["model"] = json!(name);
    body["q"] = json!(q);
    body["theory"] = json!({
        "tau": th.tau, "beta": beta_th, "beta_convention": "angle-averaged",
        "H": h_target, "tm_q": tm_q, "K": k_target,
        "alpha": alpha_target, "C1": c1_target,
        "K_rule": "K(q) = q xi(1) - xi(q), xi = tau + 2 (exact for FIF; see the compare docs for the other models)",
    });
    body["wtmm"] = json!(wtmm);
    body["tm"] = json!(tm);
    body["summary"] = json!(summaries);
    body["scalars"] = serde_json::Value::Object(
        scalars
            .iter()
            .map(|(k, v)| (k.to_string(), json!(v)))
            .collect(),
    );
    body["timing"] = timing.clone();
    body["wtmm_fit_scales_px"] = json!(w_all.fit_scales);
    body["tm_fit_log2_lambda"] = json!(t_all.fit_log2_lambda);
    body["tm_universal_q_max"] = json!(t_all.universal_q_max);
    body["tm_q_s"] = json!(t_all.q_s);
    // the warnings of both full-ensemble estimates (tm/tm.json's as `tm`
    // words them)
    let tm_warnings: Vec<String> = t_all.warnings.clone();
    body["warnings"] = json!(w_all.warnings);
    body["tm_warnings"] = json!(tm_warnings);
    write_json(&dir.join("compare.json"), &body)?;
    let rows: Vec<Vec<String>> = (0..q.len())
        .map(|i| {
            vec![
                f(q[i]),
                f(th.tau[i]),
                f(wtmm.tau[i]),
                f(wtmm.bias[i]),
                f(wtmm.sd_groups[i]),
                f(wtmm.se[i]),
                f(tm.tau[i]),
                f(tm.bias[i]),
                f(tm.sd_groups[i]),
                f(tm.se[i]),
            ]
        })
        .collect();
    write_csv(
        &dir.join("compare.csv"),
        &[
            "q",
            "tau_theory",
            "tau_wtmm",
            "bias_wtmm",
            "sd_groups_wtmm",
            "se_wtmm",
            "tau_tm",
            "bias_tm",
            "sd_groups_tm",
            "se_tm",
        ],
        &rows,
    )?;
    let label = format!(
        "{name} ({}), {} of {s}x{s}",
        super::common::model_params_label(&model),
        super::common::count_of(args.count, "image"),
        s = args.size
    );
    plot_tau(dir, &label, &model, &q, &wtmm, &tm)?;
    plot_k(
        dir,
        &t_all,
        Some(("theory: K(q) = q xi(1) - xi(q), xi = tau + 2", &k_target)),
        &label,
    )?;
    // the full-ensemble outputs of each method, as `analyze` and `tm` write them
    let wdir = dir.join("wtmm");
    make_out_dir(&wdir)?;
    let curves = theory_curves(&model, &name, &q)?;
    super::analyze_cmd::write_outputs(
        &wdir,
        "compare",
        params.clone(),
        &all_sums,
        &w_all,
        &w_other,
        Some(&curves),
    )?;
    let tdir = dir.join("tm");
    make_out_dir(&tdir)?;
    super::tm_cmd::write_outputs(
        &tdir,
        "compare",
        params,
        &t_all,
        tm_acc.spectrum.as_ref(),
        &[],
        &label,
    )?;

    let text = table(
        &args,
        &name,
        &cfg.wavelet,
        rule,
        &w_all,
        &t_all,
        &q,
        &th.tau,
        &wtmm,
        &tm,
        &summaries,
        &scalars,
        &timing,
    );
    let warnings = distinct(
        w_all
            .warnings
            .iter()
            .map(|w| format!("WTMM: {w}"))
            .chain(tm_warnings.iter().map(|w| format!("trace moments: {w}"))),
    );
    // compare.txt has them at its end; stdout leaves them to stderr, where
    // they come after the report, even with --quiet (as analyze's)
    let file = format!("{text}{}", warnings_section(&warnings));
    write_atomic(&dir.join("compare.txt"), file.as_bytes())?;
    show!("{text}");
    for w in &warnings {
        say!("warning: {w}");
    }
    Ok(Outcome::Ok)
}

/// The printed report (markdown tables).
#[allow(clippy::too_many_arguments)]
fn table(
    args: &CompareArgs,
    name: &str,
    wavelet: &crate::cwt::Wavelet,
    rule: Rule,
    w: &Spectra,
    t: &TraceMomentResult,
    q: &[f64],
    theory: &[f64],
    wtmm: &MethodTau,
    tm: &MethodTau,
    summaries: &[Summary],
    scalars: &[(&str, Scalar)],
    timing: &serde_json::Value,
) -> String {
    let mut s = String::new();
    // image i is in group i * groups / count: sizes differ by at most one
    let (lo, hi) = (
        args.count / args.groups(),
        args.count.div_ceil(args.groups()),
    );
    let per = if lo == hi {
        format!("{lo}")
    } else {
        format!("{lo}-{hi}")
    };
    let _ = writeln!(
        s,
        "compare {name}: {} {}x{}, seed {}, {} sub-ensembles of {per}; wall {:.1} s",
        super::common::count_of(args.count, "image"),
        args.size,
        args.size,
        args.seed,
        args.groups(),
        timing["wall_seconds"].as_f64().unwrap_or(f64::NAN)
    );
    let _ = writeln!(
        s,
        "WTMM: {} wavelet, {} rule, fit {:.2}-{:.2} px; TM: {} flux after differentiation {} (mean order {:.3}), fit log2 lambda {}:{}, universal fit q <= {:.2} (q_s {:.2}); TM alpha {} +- {}, C1 {} +- {} ({})\n",
        wavelet.name(),
        rule.name(),
        w.fit_scales.0,
        w.fit_scales.1,
        t.flux.name(),
        match t.diff {
            crate::tracemoments::FluxDiff::None => "none".to_string(),
            crate::tracemoments::FluxDiff::Auto => "auto".to_string(),
            crate::tracemoments::FluxDiff::Order(d) => format!("of order {d}"),
        },
        t.diff_order,
        t.fit_log2_lambda.0,
        t.fit_log2_lambda.1,
        t.universal_q_max,
        t.q_s,
        cell(t.alpha, 3),
        cell(t.alpha_stderr, 3),
        cell(t.c1, 4),
        cell(t.c1_stderr, 4),
        t.stderr_method
    );
    let _ = writeln!(
        s,
        "| method | q range | max abs(bias) (at q) | rms bias | rms sd (sub-ens.) | max abs(bias)/se | s/image |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|---|---|");
    for m in summaries {
        let secs = if m.method == "WTMM" {
            timing["wtmm_seconds_per_image"].as_f64()
        } else {
            timing["tm_seconds_per_image"].as_f64()
        }
        .unwrap_or(f64::NAN);
        let _ = writeln!(
            s,
            "| {} | [{}, {}] | {} ({}) | {} | {} | {} | {} |",
            m.method,
            m.q_range.0,
            m.q_range.1,
            cell(m.max_abs_bias, 3),
            if m.q_of_max_abs_bias.is_finite() {
                m.q_of_max_abs_bias.to_string()
            } else {
                "-".into()
            },
            cell(m.rms_bias, 3),
            cell(m.rms_sd_groups, 3),
            cell(m.max_abs_bias_over_se, 1),
            cell(secs, 2)
        );
    }
    if summaries
        .iter()
        .any(|m| m.max_abs_bias.is_finite() && !m.max_abs_bias_over_se.is_finite())
    {
        let _ = writeln!(
            s,
            "\nmax abs(bias)/se: '-' without a standard error, which the scatter of fewer \
             than {MIN_SE_GROUPS} sub-ensembles does not give (the spread of two is 0 wherever \
             their tau(q) cross; --groups {MIN_SE_GROUPS} or more needs as many images); \
             the full ensemble's own errors are in wtmm/spectra.json (tau_stderr, \
             {}) and tm/tm.json (K_stderr, H_stderr)",
            w.stderr_method
        );
    }
    let _ = writeln!(s, "\n| quantity | estimate | sd (sub-ens.) | target |");
    let _ = writeln!(s, "|---|---|---|---|");
    for (k, v) in scalars {
        let _ = writeln!(
            s,
            "| {k} | {} | {} | {} |",
            cell(v.value, 4),
            cell(v.sd_groups, 4),
            cell(v.target, 4)
        );
    }
    let _ = writeln!(s, "\n| q | theory | WTMM | sd | TM | sd |");
    let _ = writeln!(s, "|---|---|---|---|---|---|");
    for i in 0..q.len() {
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {} | {} |",
            q[i],
            cell(theory[i], 4),
            cell(wtmm.tau[i], 4),
            cell(wtmm.sd_groups[i], 4),
            cell(tm.tau[i], 4),
            cell(tm.sd_groups[i], 4),
        );
    }
    s
}

/// A number of the report with `prec` decimals; `-` for a value that is
/// not available (NaN, null in the JSON).
fn cell(v: f64, prec: usize) -> String {
    if v.is_finite() {
        format!("{v:.prec$}")
    } else {
        "-".into()
    }
}

/// τ(q) of both methods over the theory, and their deviations.
fn plot_tau(
    dir: &Path,
    name: &str,
    model: &Model,
    q: &[f64],
    wtmm: &MethodTau,
    tm: &MethodTau,
) -> Result<()> {
    let lo = q.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = q.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let grid: Vec<f64> = (0..=200)
        .map(|i| lo + (hi - lo) * i as f64 / 200.0)
        .collect();
    let pts = |v: &[f64]| -> Vec<(f64, f64)> { q.iter().copied().zip(v.iter().copied()).collect() };
    let bars = if wtmm.se.iter().chain(&tm.se).any(|e| e.is_finite()) {
        "bars: se from sub-ensembles".to_string()
    } else {
        format!("no bars: fewer than {MIN_SE_GROUPS} sub-ensembles")
    };
    let mut c = Chart {
        title: format!("tau(q): {name} ({bars})"),
        x_label: "q".into(),
        y_label: "tau(q)".into(),
        ..Default::default()
    };
    c.series.push(Series::new(
        "theory",
        grid.iter()
            .map(|&v| (v, model.tau(v)))
            .filter(|p| p.1.is_finite())
            .collect(),
        Style::Line,
        9,
    ));
    c.series
        .push(Series::new("WTMM", pts(&wtmm.tau), Style::Markers, 0).with_errors(wtmm.se.clone()));
    c.series.push(
        Series::new(
            "trace moments: qH - K(q) - 2",
            pts(&tm.tau),
            Style::Markers,
            1,
        )
        .with_errors(tm.se.clone()),
    );
    save_chart(&c, &dir.join("tau.png"))?;
    let mut d = Chart {
        title: format!("tau(q) - theory: {name} ({bars})"),
        x_label: "q".into(),
        y_label: "tau(q) - theory".into(),
        ..Default::default()
    };
    d.series.push(Series::new(
        "",
        vec![(lo, 0.0), (hi, 0.0)],
        Style::Dashed,
        9,
    ));
    d.series.push(
        Series::new("WTMM", pts(&wtmm.bias), Style::LineMarkers, 0).with_errors(wtmm.se.clone()),
    );
    d.series.push(
        Series::new("trace moments", pts(&tm.bias), Style::LineMarkers, 1)
            .with_errors(tm.se.clone()),
    );
    save_chart(&d, &dir.join("tau_bias.png"))
}

#[cfg(test)]
mod tests {
    use super::{MIN_SE_GROUPS, cell, method_tau, summarise};

    /// Two sub-ensembles whose τ(q) cross between q = 4 and 5 (the review's
    /// 2 fBm images: sd 0.0003 at q = 5 against a jackknife error of 0.13):
    /// their spread vanishes there and bias/se was 1000 and more; no se from
    /// fewer than 3 groups, so the ratio is NaN (null). A third group gives
    /// both back, and its spread no longer vanishes at the crossing.
    #[test]
    fn no_standard_error_from_two_groups() {
        let q = [3.0, 4.0, 5.0, 6.0];
        let theory = [-1.0, -0.6667, -0.3333, 0.0];
        let a = vec![-1.06, -0.80, -0.5789, -0.36];
        let b = vec![-1.04, -0.82, -0.5785, -0.34];
        let tau: Vec<f64> = a.iter().zip(&b).map(|(x, y)| 0.5 * (x + y)).collect();
        let two = method_tau("WTMM", tau.clone(), vec![a.clone(), b.clone()], &theory);
        assert!(two.se.iter().all(|s| s.is_nan()), "{:?}", two.se);
        // the spread is still reported: |a - b| / sqrt 2
        assert!((two.sd_groups[2] - 0.0004 / 2f64.sqrt()).abs() < 1e-12);
        let s = summarise(&two, &q, (3.0, 6.0));
        assert!(s.max_abs_bias_over_se.is_nan());
        assert!((s.max_abs_bias - 0.35).abs() < 1e-12, "{}", s.max_abs_bias);
        // what the old se made of q = 5: 0.2454 / 0.0002
        let old = (tau[2] - theory[2]).abs() / (two.sd_groups[2] / 2f64.sqrt());
        assert!(old > 1000.0, "{old}");
        assert_eq!(cell(s.max_abs_bias_over_se, 1), "-");
        // three groups: an se at every q, a finite ratio
        let c = vec![-1.02, -0.78, -0.62, -0.40];
        let groups = vec![a, b, c];
        assert_eq!(groups.len(), MIN_SE_GROUPS);
        let three = method_tau("WTMM", tau, groups, &theory);
        assert!(three.se.iter().all(|s| s.is_finite() && *s > 0.0));
        let s = summarise(&three, &q, (3.0, 6.0));
        assert!(s.max_abs_bias_over_se.is_finite() && s.max_abs_bias_over_se < 100.0);
        assert_eq!(cell(1.26, 1), "1.3");
        assert_eq!(cell(f64::NAN, 4), "-");
    }
}
