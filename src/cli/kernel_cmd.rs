//! `wtmm kernel IMAGE... --out DIR`: the self-similarity kernel of the WTMMM
//! moduli (SPEC §5, §13; II §4, Figs 25-29): characteristic functions,
//! `Ĝ_aa'(p)`, its collapse, the cumulants `C_n(a, a')` and the fitted
//! `c_n`, and the reconstruction check of Fig 29.
//!
//! Conventions (see [`crate::stats::kernel`]): natural logarithms
//! throughout, `c_n = dC_n / d ln(a'/a)`, which is the paper's `c_n`
//! (`c1 = m/ln2` for a log-normal W-cascade, as `wtmm theory` prints).
//! Both WTMMM sets are accumulated: `--set` is reported as `cumulants`, the
//! other as `alternate_set`.

use std::f64::consts::LN_2;
use std::path::Path;

use clap::Args;
use num_complex::Complex64;
use serde_json::json;

use super::analyze_cmd::{LineOpts, fit_range};
use super::common::save_chart;
use super::common::{f, header, make_out_dir, write_csv, write_json};
use super::pdf_cmd::{
    StatsInput, check_octaves, grid_top, no_maxima, octaves_or_default, scales_at,
};
use super::{OutDir, Outcome};
use crate::error::{Error, Result};
use crate::plot::{Chart, Series, Style, part_names};
use crate::skeleton::AnalysisConfig;
use crate::stats::kernel::{
    KernelConfig, KernelOptions, KernelResult, KernelSums, NOISE_SIGMAS, Reconstruction,
    check_wtmmm_counts, cwt_grid_sums, kernel_estimates, reconstruct,
};
use crate::stats::pdf::{PdfConfig, WtmmmHistograms, WtmmmSet, image_wtmmm};
use crate::synth::wcascade::Law;
use crate::theory::Model;

#[derive(Args, Debug)]
pub struct KernelArgs {
    #[command(flatten)]
    pub input: StatsInput,
    #[command(flatten)]
    pub opts: LineOpts,
    /// Scales whose cumulants enter the fits of c_n, octaves above a_min
    /// `LO:HI` (default 0.5:min(4, OCTAVES)).
    #[arg(long, allow_hyphen_values = true)]
    pub fit: Option<String>,
    /// WTMMM set reported as `cumulants` (the other is `alternate_set`).
    #[arg(long, value_enum, default_value = "lines")]
    pub set: WtmmmSet,
    /// Reference scales a' of the C_n(a, a') tables, octaves above a_min (II
    /// Fig 26) [default: 0.5,1,1.5,2,2.5,3,3.5, those inside the fit range
    /// above its lower end: 1..3.5 with the default fit 0.5:4].
    #[arg(long)]
    pub refs: Option<String>,
    /// Pairs a:a' of the kernel curves, octaves above a_min, comma-separated
    /// (II Fig 25) [default: 0.5:3.5,1:3.5,1:3,1.5:3, those within --octaves].
    #[arg(long)]
    pub pairs: Option<String>,
    /// Largest p of the characteristic functions.
    #[arg(long, default_value_t = 8.0)]
    pub p_max: f64,
    /// Step of p.
    #[arg(long, default_value_t = 0.05)]
    pub dp: f64,
    /// Fig 29: target scale then source scales, octaves above a_min
    /// [default: 0,1,2,3, those within --octaves].
    #[arg(long)]
    pub reconstruct: Option<String>,
    /// Also the cumulants of ln M over every other CWT pixel (a diagnostic; one more CWT pass).
    #[arg(long)]
    pub cwt_grid: bool,
    #[command(flatten)]
    pub out: OutDir,
}

/// Parses `a:b,c:d` (octaves).
pub fn parse_pairs(flag: &str, s: &str) -> Result<Vec<(f64, f64)>> {
    s.split(',')
        .map(|p| {
            let (a, b) = p.split_once(':').ok_or_else(|| {
                Error::param(flag, format!("`{p}`: use a:b pairs separated by commas"))
            })?;
            let num = |t: &str| {
                t.trim()
                    .parse::<f64>()
                    .map_err(|_| Error::param(flag, format!("`{t}` is not a number")))
            };
            Ok((num(a)?, num(b)?))
        })
        .collect()
}

/// Reference scales of II Fig 26, in octaves above a_min: the library's
/// `DEFAULT_REF_OCTAVES` as the option parser reads them (tested equal).
pub const DEFAULT_REFS: &str = "0.5,1,1.5,2,2.5,3,3.5";
/// Scale pairs of II Fig 25 (the library's `DEFAULT_PAIR_OCTAVES`).
pub const DEFAULT_PAIRS: &str = "0.5:3.5,1:3.5,1:3,1.5:3";

/// The default reference scales on this grid
/// ([`KernelOptions::for_scales`]): a reference needs smaller scales in the
/// fit range (C_n(a, a') has a < a'), so the paper's 0.5 is kept with its
/// --fit 0:3.5 and dropped from the default 0.5:4, where its table would be
/// empty.
///
/// **Errors** when none of the paper's references lies on the grid.
pub fn default_refs(scales: &[f64], fit: (f64, f64)) -> Result<Vec<f64>> {
    // the error of an option with no default on the grid
    octaves_or_default("refs", None, DEFAULT_REFS, scales)?;
    Ok(KernelOptions::for_scales(scales, fit).refs)
}

/// The default pairs on this grid ([`KernelOptions::for_scales`]), their
/// ends lowered onto a shorter grid's top; a pair that collapses there is
/// dropped.
pub fn default_pairs(scales: &[f64]) -> Vec<(f64, f64)> {
    KernelOptions::for_scales(scales, (0.0, 0.0)).pairs
}

/// A pairs option (`a:b,...`, octaves above a_min): the given pairs, each
/// checked against the grid, or without one the pairs of `default` with
/// octaves beyond the grid lowered to its top scale (so a shorter
/// `--octaves` keeps the paper's pairs that fit, and shortens the others),
/// duplicates dropped.
///
/// **Errors** when a given octave is off the grid.
pub fn pairs_or_default(
    flag: &str,
    given: Option<&str>,
    default: &str,
    scales: &[f64],
) -> Result<Vec<(f64, f64)>> {
    if let Some(s) = given {
        let v = parse_pairs(flag, s)?;
        for (i, &(a, b)) in v.iter().enumerate() {
            check_octaves(flag, &[a, b], scales)?;
            // a pair twice would be computed, written and plotted twice
            // (to the tolerance of parse_list's duplicates)
            if v[..i]
                .iter()
                .any(|&(c, d)| (c - a).abs() < 1e-9 && (d - b).abs() < 1e-9)
            {
                return Err(Error::param(flag, format!("`{s}`: {a}:{b} is given twice")));
            }
        }
        return Ok(v);
    }
    let top = grid_top(scales);
    let mut v: Vec<(f64, f64)> = Vec::new();
    for (a, b) in parse_pairs(flag, default)? {
        let p = (a.min(top), b.min(top));
        if !v.contains(&p) {
            v.push(p);
        }
    }
    Ok(v)
}

/// Everything accumulated over the images.
struct Acc {
    main: Option<KernelSums>,
    alt: Option<KernelSums>,
    grid: Option<KernelSums>,
    hist: WtmmmHistograms,
}

fn merge_opt(a: &mut Option<KernelSums>, b: Option<KernelSums>) -> Result<()> {
    match (a.as_mut(), b) {
        (_, None) => Ok(()),
        (None, Some(b)) => {
            *a = Some(b);
            Ok(())
        }
        (Some(x), Some(b)) => x.merge(&b),
    }
}

/// Kernel sums of both WTMMM sets (and histograms of `set`, and optionally
/// the CWT-grid diagnostic) over the input.
fn collect(
    input: &super::pdf_cmd::Input,
    cfg: &AnalysisConfig,
    kcfg: KernelConfig,
    set: WtmmmSet,
    grid: bool,
    quiet: bool,
) -> Result<Acc> {
    let scales = cfg.scale_list();
    let empty = WtmmmHistograms::new(&scales, PdfConfig::default())?;
    // fewer than 3 images: the jackknife runs over tiles of each domain
    let lone = input.len() < 3;
    input.fold(
        quiet,
        "kernel",
        super::common::ENSEMBLE_ANALYSIS_BYTES_PER_PIXEL,
        || Acc {
            main: None,
            alt: None,
            grid: None,
            hist: empty.clone(),
        },
        |acc, field, label, par| {
            let w = image_wtmmm(field, cfg, par, true)?;
            if w.all.first().is_none_or(|v| v.is_empty()) {
                return Err(no_maxima(input, label, field, cfg));
            }
            let side = if lone {
                let (ny, nx) = field.dim();
                crate::spectra::default_tile_side(cfg, ny, nx)
            } else {
                0
            };
            let tiled = |s: WtmmmSet| {
                KernelSums::from_points_tiled(&scales, kcfg, s, w.set(s), label, w.domain, side)
            };
            let (m, o) = (tiled(set)?, tiled(set.other())?);
            merge_opt(&mut acc.main, Some(m))?;
            merge_opt(&mut acc.alt, Some(o))?;
            acc.hist.merge(&WtmmmHistograms::from_points(
                &scales,
                PdfConfig::default(),
                w.set(set),
            )?)?;
            if grid {
                merge_opt(
                    &mut acc.grid,
                    Some(cwt_grid_sums(field, cfg, kcfg, 2, label)?),
                )?;
            }
            Ok(())
        },
        |mut a, b| {
            merge_opt(&mut a.main, b.main)?;
            merge_opt(&mut a.alt, b.alt)?;
            merge_opt(&mut a.grid, b.grid)?;
            a.hist.merge(&b.hist)?;
            Ok(a)
        },
    )
}

/// `ln Ĝ(p)` of the theory per unit `ln(a'/a)` (II eqs 55, 59), where known.
pub fn theory_log_kernel(model: &Model, p: f64) -> Option<Complex64> {
    match model {
        Model::WCascade(w) => Some(match w.law {
            Law::LogNormal { m, sigma2 } => Complex64::new(-sigma2 * p * p / 2.0, m * p) / LN_2,
            Law::LogPoisson {
                gamma,
                beta,
                lambda,
            } => {
                let lb = beta.ln();
                Complex64::new(
                    lambda * ((p * lb).cos() - 1.0),
                    gamma * p + lambda * (p * lb).sin(),
                ) / LN_2
            }
        }),
        // a pure shift: c1 = -H (II eq 64 with τ = qH - 2)
        Model::Fbm(b) => Some(Complex64::new(0.0, -b.hurst * p)),
        Model::Fisc(_) | Model::Fif(_) => None,
    }
}

/// The estimates and everything written.
pub struct KernelOutputs {
    pub main: KernelResult,
    pub alt: KernelResult,
    pub grid: Option<KernelResult>,
    pub recon2: Vec<Reconstruction>,
    pub recon3: Vec<Reconstruction>,
}

pub fn run(args: KernelArgs, quiet: bool) -> Result<Outcome> {
    let input = args.input.resolve(&args.opts)?;
    input.say_pixel(quiet);
    let cfg = input.analysis(&args.opts)?;
    let fit = fit_range(
        args.fit.as_deref(),
        args.opts.cwt.octaves,
        args.opts.cwt.voices,
    )?;
    let scales = cfg.scale_list();
    let refs = match args.refs.as_deref() {
        None => default_refs(&scales, fit)?,
        given => octaves_or_default("refs", given, DEFAULT_REFS, &scales)?,
    };
    if let Some(r) = refs.iter().find(|&&r| r <= fit.0 + 1e-9) {
        return Err(Error::param(
            "refs",
            format!(
                "reference octave {r} has no smaller scale in the fit range {}:{} (C_n(a, a') needs a < a')",
                fit.0, fit.1
            ),
        ));
    }
    let pairs = match args.pairs.as_deref() {
        None => default_pairs(&scales),
        given => pairs_or_default("pairs", given, DEFAULT_PAIRS, &scales)?,
    };
    for &(a, b) in &pairs {
        if !(a < b) {
            return Err(Error::param("pairs", format!("{a}:{b}: need a < a'")));
        }
    }
    let mut rec = octaves_or_default(
        "reconstruct",
        args.reconstruct.as_deref(),
        "0,1,2,3",
        &scales,
    )?;
    // the list comes back sorted: the target must have been given first
    // (a source below it is not the Fig 29 push from larger scales)
    if let Some(given) = args.reconstruct.as_deref()
        && !given.contains(':')
        && let Some(first) = given.split(',').next()
        && first.trim().parse::<f64>().ok() != rec.first().copied()
    {
        return Err(Error::param(
            "reconstruct",
            format!(
                "`{given}`: give the target octave first, then larger source octaves, \
                 e.g. 0,1,2,3"
            ),
        ));
    }
    let top = grid_top(&scales);
    if args.reconstruct.is_none() && rec.len() < 2 && top > 0.0 {
        // a grid shorter than an octave: from its top scale to its first
        rec = vec![0.0, top];
    }
    if rec.len() < 2 || rec[1..].iter().any(|&o| o <= rec[0]) {
        return Err(Error::param(
            "reconstruct",
            "give the target octave then larger source octaves, e.g. 0,1,2,3",
        ));
    }
    let kcfg = KernelConfig {
        p_max: args.p_max,
        dp: args.dp,
    };
    kcfg.validate()?;
    let kopts = KernelOptions { fit, refs, pairs };
    let t0 = std::time::Instant::now();
    let acc = collect(&input, &cfg, kcfg, args.set, args.cwt_grid, quiet)?;
    let wall = t0.elapsed().as_secs_f64();
    let (main_sums, alt_sums) = match (&acc.main, &acc.alt) {
        (Some(m), Some(a)) => (m, a),
        _ => return Err(Error::Input("no image in the input".into())),
    };
    let mut main = kernel_estimates(main_sums, &kopts)?;
    // scales short of WTMMM: an error for the set asked, a note on the other
    check_wtmmm_counts(main_sums, &kopts).map_err(|e| input.blame(e))?;
    // (scales short of WTMMM: a warning of the library's)
    let alt = kernel_estimates(alt_sums, &kopts)?;
    let grid = acc
        .grid
        .as_ref()
        .map(|g| kernel_estimates(g, &kopts))
        .transpose()?;
    let rj = scales_at(&scales, &rec);
    if let Some(w) = input.holes.warning(input.len(), "the WTMMM counted") {
        main.warnings.push(w);
    }
    main.warnings.extend(input.tally.warning(&cfg, input.len()));
    // the cumulants are fitted from `fit.0` octaves up
    let a_top = cfg.scale_list().last().copied().unwrap_or(cfg.a_min);
    main.warnings.extend(input.tally.quantisation_warnings(
        cfg.a_min * 2f64.powf(fit.0),
        "the smallest scale of the cumulants' fit",
        crate::spectra::fit_remedy(cfg.a_min, cfg.voices, a_top),
    ));
    let mut c = main.cumulants.values().to_vec();
    if c[1] < 0.0 {
        // a kernel with c2 < 0 is no density (reconstruct refuses it); the
        // shift by c1 is the kernel of a monofractal, the case this is
        main.warnings.push(format!(
            "c2 = {:.5} < 0 (no intermittency to within the errors, or a bias): the Fig 29 \
             reconstruction uses the shift by c1 alone, for both kernels",
            c[1]
        ));
        c.truncate(1);
    }
    // an empty target or source scale is a fault of the data
    let recon2 = reconstruct(&acc.hist, rj[0], &rj[1..], &c[..c.len().min(2)])
        .map_err(|e| input.blame(e))?;
    let recon3 = reconstruct(&acc.hist, rj[0], &rj[1..], &c).map_err(|e| input.blame(e))?;
    main.warnings.extend(input.pixel_warnings.iter().cloned());
    let out = KernelOutputs {
        main,
        alt,
        grid,
        recon2,
        recon3,
    };
    make_out_dir(&args.out.out)?;
    let params = json!({"input": input.params_json(), "analysis": super::common::analysis_json(&cfg), "set": args.set,
        "kernel": kcfg, "options": kopts});
    write_kernel_outputs(
        &args.out.out,
        "kernel",
        params,
        &out,
        input.model.as_ref(),
        (&input.name, &input.title(&cfg)),
        wall,
    )?;
    // "value +- se", the se spelled out when it cannot be estimated
    let pm = |e: &crate::stats::kernel::Estimate| {
        if !e.value.is_finite() {
            "none".to_string()
        } else if e.stderr.is_finite() {
            format!("{:.4} +- {:.4}", e.value, e.stderr)
        } else {
            format!("{:.4} (no error: fewer than 3 images)", e.value)
        }
    };
    // the reading on stdout, even with --quiet (as analyze and tm give theirs)
    {
        let cu = &out.main.cumulants;
        show!(
            "kernel ({} set, {}, fit {}:{} octaves): c1 = {}, c2 = {}, c3 = {}\n",
            args.set.name(),
            super::common::count_of(out.main.images, "image"),
            fit.0,
            fit.1,
            pm(&cu.c1),
            pm(&cu.c2),
            pm(&cu.c3)
        );
        let pc = &out.main.pooled;
        show!(
            "pooled C_n(a, a') tables (II Figs 26, 28): c1 = {}, c2 = {}, c3 = {}\n",
            pm(&pc.c1),
            pm(&pc.c2),
            pm(&pc.c3)
        );
    }
    for w in &out.main.warnings {
        say!("warning: {w}");
    }
    Ok(Outcome::Ok)
}

fn cumulants_json(k: &KernelResult) -> serde_json::Value {
    json!({"c1": k.cumulants.c1, "c2": k.cumulants.c2, "c3": k.cumulants.c3})
}

fn kappa_json(k: &KernelResult) -> serde_json::Value {
    json!({"scales": k.scales, "octaves": k.octaves, "n_wtmmm": k.n_wtmmm,
        "kappa1": k.kappa1, "kappa2": k.kappa2, "kappa3": k.kappa3})
}

/// Writes kernel.json, the CSVs and the plots of II Figs 25-29.
pub fn write_kernel_outputs(
    dir: &Path,
    command: &str,
    params: serde_json::Value,
    o: &KernelOutputs,
    model: Option<&Model>,
    (name, title): (&str, &str),
    wall: f64,
) -> Result<()> {
    let k = &o.main;
    // the pixel, when known: the figures' scales also as lengths
    let px = super::params_pixel(&params["input"]);
    let mut body = header(command, params);
    super::common::note_caveats(&mut body, model);
    body["set"] = json!(k.set);
    body["images"] = json!(k.images);
    body["fit_octaves"] = json!(k.fit_octaves);
    body["fit_scales"] = json!(k.fit_scales);
    body["convention"] = json!(
        "natural logs: C_n(a, a') = kappa_n(ln M at a) - kappa_n(ln M at a'), c_n = slope of C_n \
         against ln(a'/a) = -d kappa_n / d ln a (II eq 49); for a W-cascade c_n = kappa_n(ln W)/ln 2 \
         (II eqs 56, 60), the same numbers as `wtmm theory`"
    );
    body["cumulants"] = cumulants_json(k);
    body["cumulants_pooled"] = json!({"c1": k.pooled.c1, "c2": k.pooled.c2, "c3": k.pooled.c3,
        "note": "slope through the origin of every C_n(a, a') point of cn_tables (II Figs 26, 28 as drawn); \
         the paper's protocol with the default refs and --fit 0:3.5"});
    body["stderr_method"] = json!(k.stderr_method);
    body["kernels_stderr_method"] = json!(k.curve_stderr_method);
    body["kernels_jackknife_groups"] = json!({"groups": k.curve_groups[0],
        "fewest_holding_wtmmm": k.curve_groups[1],
        "note": "images, or tiles of fewer than 3 images (0: no jackknife); the fewest of them \
                 holding WTMMM at a scale of a pair"});
    body["plugin_tilt"] = json!({"c1": k.plugin_tilt[0], "c2": k.plugin_tilt[1], "c3": k.plugin_tilt[2],
        "note": "bias of the fitted c_n from the plug-in cumulants of few WTMMM (-kappa2/n, -3 kappa3/n per scale, \
         through the same fit): the estimate's expectation is about c_n + tilt; not in the errors"});
    if let Some(c) = model.and_then(|m| m.cumulants()) {
        body["theory"] = json!({"name": name, "cumulants": {"c1": c[0], "c2": c[1], "c3": c[2]}});
    }
    body["cn_tables"] = json!(k.tables);
    body["kernels"] = json!(k.kernels);
    body["kappa"] = kappa_json(k);
    body["alternate_set"] = json!({"set": o.alt.set, "cumulants": cumulants_json(&o.alt),
        "kappa": kappa_json(&o.alt), "warnings": o.alt.warnings});
    if let Some(g) = &o.grid {
        body["cwt_grid"] = json!({"cumulants": cumulants_json(g), "kappa": kappa_json(g),
            "note": "ln M over every other pixel of the CWT grid, rows and columns counted \
                     from the nearer border (the same pixels for a flipped image; no WTMMM \
                     selection)"});
    }
    let rec = |r: &[Reconstruction]| -> serde_json::Value {
        json!(r
            .iter()
            .map(|x| json!({"a_from": x.a_from, "a_to": x.a_to, "ln_ratio": x.ln_ratio, "c": x.c, "l1": x.l1}))
            .collect::<Vec<_>>())
    };
    // validate's kernel pass has no pdfs to push through the kernel
    let reconstructed = !(o.recon2.is_empty() && o.recon3.is_empty());
    body["reconstruction"] = if reconstructed {
        json!({"gaussian_c1_c2": rec(&o.recon2), "with_c3": rec(&o.recon3)})
    } else {
        serde_json::Value::Null
    };
    body["warnings"] = json!(k.warnings);
    body["wall_seconds"] = json!(wall);
    write_json(&dir.join("kernel.json"), &body)?;
    // CSVs
    let rows: Vec<Vec<String>> = (0..k.scales.len())
        .map(|j| {
            vec![
                f(k.scales[j]),
                f(k.octaves[j]),
                k.n_wtmmm[j].to_string(),
                f(k.kappa1[j]),
                f(k.kappa2[j]),
                f(k.kappa3[j]),
                o.alt.n_wtmmm[j].to_string(),
                f(o.alt.kappa1[j]),
                f(o.alt.kappa2[j]),
                f(o.alt.kappa3[j]),
            ]
        })
        .collect();
    let alt = o.alt.set.name();
    write_csv(
        &dir.join("kappa.csv"),
        &[
            "a",
            "octave",
            "n_wtmmm",
            "kappa1",
            "kappa2",
            "kappa3",
            &format!("n_wtmmm_{alt}"),
            &format!("kappa1_{alt}"),
            &format!("kappa2_{alt}"),
            &format!("kappa3_{alt}"),
        ],
        &rows,
    )?;
    let mut rows = Vec::new();
    for t in &k.tables {
        for r in &t.rows {
            rows.push(vec![
                f(t.a_ref),
                f(t.octave_ref),
                f(r.a),
                f(r.octave),
                f(r.ln_ratio),
                f(r.c[0]),
                f(r.c[1]),
                f(r.c[2]),
                f(r.c_stderr[0]),
                f(r.c_stderr[1]),
                f(r.c_stderr[2]),
            ]);
        }
    }
    write_csv(
        &dir.join("cn_tables.csv"),
        &[
            "a_ref",
            "octave_ref",
            "a",
            "octave",
            "ln_ratio",
            "C1",
            "C2",
            "C3",
            "C1_stderr",
            "C2_stderr",
            "C3_stderr",
        ],
        &rows,
    )?;
    let mut rows = Vec::new();
    for kc in &k.kernels {
        let noise = k.noise(kc);
        let g = |v: &[f64], i: usize| f(v.get(i).copied().unwrap_or(f64::NAN));
        for (i, &noisy) in noise.iter().enumerate() {
            rows.push(vec![
                f(kc.a),
                f(kc.a_ref),
                f(kc.p[i]),
                f(kc.cf_re[i]),
                f(kc.cf_im[i]),
                f(kc.cf_ref_re[i]),
                f(kc.cf_ref_im[i]),
                f(kc.ln_abs_g[i]),
                f(kc.phase[i]),
                f(kc.ln_abs_g_norm[i]),
                f(kc.phase_norm[i]),
                g(&kc.ln_abs_g_stderr, i),
                g(&kc.phase_stderr, i),
                g(&kc.cf_abs_stderr, i),
                g(&kc.cf_ref_abs_stderr, i),
                u8::from(noisy).to_string(),
            ]);
        }
    }
    write_csv(
        &dir.join("kernel_curves.csv"),
        &[
            "a",
            "a_ref",
            "p",
            "Re_C_a",
            "Im_C_a",
            "Re_C_ref",
            "Im_C_ref",
            "ln_abs_G",
            "phase",
            "ln_abs_G_norm",
            "phase_norm",
            "ln_abs_G_stderr",
            "phase_stderr",
            "abs_C_a_stderr",
            "abs_C_ref_stderr",
            "noise",
        ],
        &rows,
    )?;
    let mut rows = Vec::new();
    for (kind, rs) in [("c1_c2", &o.recon2), ("c1_c2_c3", &o.recon3)] {
        for r in rs {
            for i in 0..r.ln_m.len() {
                rows.push(vec![
                    kind.to_string(),
                    f(r.a_from),
                    f(r.a_to),
                    f(r.ln_m[i]),
                    f(r.measured[i]),
                    f(r.predicted[i]),
                ]);
            }
        }
    }
    if reconstructed {
        write_csv(
            &dir.join("reconstruction.csv"),
            &[
                "kernel",
                "a_from",
                "a_to",
                "lnM",
                "P_lnM_measured",
                "P_lnM_predicted",
            ],
            &rows,
        )?;
    }
    let px = px.as_ref().map(|(side, units)| (*side, units.as_str()));
    plot_kernel(dir, o, model, title, px)
}

/// Palette index of dark grey: theory, keys, the headline fit, the measured pdf.
const GREY: usize = 9;

/// The kernel figures draw a jackknife bar at every this many p (staggered
/// by pair): 161 bars per curve would hide the curves.
const BAR_EVERY: usize = 8;

/// The step of the kernel curves' p grid.
fn k_dp(k: &crate::stats::kernel::KernelResult) -> f64 {
    k.kernels
        .first()
        .and_then(|kc| (kc.p.len() > 1).then(|| kc.p[1] - kc.p[0]))
        .unwrap_or(f64::NAN)
}

fn plot_kernel(
    dir: &Path,
    o: &KernelOutputs,
    model: Option<&Model>,
    name: &str,
    px: Option<(f64, &str)>,
) -> Result<()> {
    use super::px_eq;
    let k = &o.main;
    let title = |t: &str| {
        if name.is_empty() {
            format!("{t}, WTMMM {}", k.set.phrase())
        } else {
            format!("{name}: {t}, WTMMM {}", k.set.phrase())
        }
    };
    let lab = |kc: &crate::stats::kernel::KernelCurve| {
        format!(
            "a = 2^{:.1}, a' = 2^{:.1} a_min ({:.1}, {:.1} px{})",
            kc.octave,
            kc.octave_ref,
            kc.a,
            kc.a_ref,
            px.map_or(String::new(), |(side, units)| format!(
                " = {}, {} {units}",
                super::short_num(kc.a * side),
                super::short_num(kc.a_ref * side)
            ))
        )
    };
    let mut charts = [
        (
            "kernel_lnG.png",
            "ln |G_aa'(p)| (II Figs 25a, 27a)",
            "ln |G|",
        ),
        (
            "kernel_lnG_collapse.png",
            "ln |G_aa'(p)| / ln(a'/a) (II Figs 25b, 27b)",
            "ln |G| / ln(a'/a)",
        ),
        (
            "kernel_phase.png",
            "phase of G_aa'(p) (II Figs 25c, 27c)",
            "Phi (rad)",
        ),
        (
            "kernel_phase_collapse.png",
            "phase / ln(a'/a) (II Figs 25d, 27d)",
            "Phi / ln(a'/a)",
        ),
    ]
    .map(|(file, t, y)| {
        (
            file,
            Chart {
                title: title(t),
                x_label: "p".into(),
                y_label: y.into(),
                ..Default::default()
            },
        )
    });
    let (mut any_noise, mut any_bars) = (false, false);
    for (c, kc) in k.kernels.iter().enumerate() {
        let noise = k.noise(kc);
        any_noise |= noise.contains(&true);
        // (p, v) split into the points drawn filled and those drawn open
        let s = |v: &[f64], open: bool| -> Vec<(f64, f64)> {
            kc.p.iter()
                .zip(v)
                .zip(&noise)
                .map(|((&p, &y), &n)| {
                    if n == open {
                        (p, y)
                    } else {
                        (f64::NAN, f64::NAN)
                    }
                })
                .collect()
        };
        // jackknife bars at every BAR_EVERY-th p, the pairs' bars staggered
        // so that they do not overlap (up to BAR_EVERY pairs)
        let shift = c * BAR_EVERY / k.kernels.len().max(1);
        let bars = |se: &[f64], scale: f64| -> Vec<f64> {
            (0..kc.p.len())
                .map(|i| match (i + shift) % BAR_EVERY {
                    0 => se.get(i).map_or(f64::NAN, |e| e / scale),
                    _ => f64::NAN,
                })
                .collect()
        };
        any_bars |= kc.ln_abs_g_stderr.iter().any(|e| e.is_finite());
        for (chart, v, se, scale) in [
            (0, &kc.ln_abs_g, &kc.ln_abs_g_stderr, 1.0),
            (1, &kc.ln_abs_g_norm, &kc.ln_abs_g_stderr, kc.ln_ratio),
            (2, &kc.phase, &kc.phase_stderr, 1.0),
            (3, &kc.phase_norm, &kc.phase_stderr, kc.ln_ratio),
        ] {
            let series = &mut charts[chart].1.series;
            let e = bars(se, scale);
            // the pair's name on the filled points, or on the open ones
            // when every point is open (the legend lists only what is drawn)
            let (filled, open) = (s(v, false), s(v, true));
            let (n_filled, n_open) = part_names(lab(kc), String::new(), &filled);
            series.push(Series::new(n_filled, filled, Style::Markers, c).with_errors(e.clone()));
            series.push(Series::new(n_open, open, Style::OpenMarkers, c).with_errors(e));
        }
        if let Some(m) = model
            && theory_log_kernel(m, 0.0).is_some()
        {
            let th: Vec<(f64, Complex64)> =
                kc.p.iter()
                    .map(|&p| (p, theory_log_kernel(m, p).expect("checked")))
                    .collect();
            let r = kc.ln_ratio;
            // one legend line, after the pairs', says what the dashed
            // curves are
            let name = if c + 1 == k.kernels.len() {
                "theory, dashed (each pair's colour)"
            } else {
                ""
            };
            charts[0].1.series.push(Series::new(
                name,
                th.iter().map(|(p, z)| (*p, z.re * r)).collect(),
                Style::Dashed,
                c,
            ));
            charts[2].1.series.push(Series::new(
                name,
                th.iter().map(|(p, z)| (*p, z.im * r)).collect(),
                Style::Dashed,
                c,
            ));
            if c + 1 == k.kernels.len() {
                charts[1].1.series.push(Series::new(
                    "theory",
                    th.iter().map(|(p, z)| (*p, z.re)).collect(),
                    Style::Line,
                    GREY,
                ));
                charts[3].1.series.push(Series::new(
                    "theory",
                    th.iter().map(|(p, z)| (*p, z.im)).collect(),
                    Style::Line,
                    GREY,
                ));
            }
        }
    }
    for (file, chart) in &mut charts {
        // what the bars are, under the axis: a key in the legend drew a
        // line like the theory's
        chart.x_label = if any_bars {
            // the JSON's kernels_stderr_method says it whole
            let [total, held] = k.curve_groups;
            let how = if k.images >= 3 {
                format!("jackknife over {total} images")
            } else {
                let some = if held < total {
                    format!("{held} of ")
                } else {
                    String::new()
                };
                format!(
                    "jackknife over {some}{total} tiles of {}: may understate",
                    super::common::count_of(k.images, "image")
                )
            };
            format!(
                "p   (bars: ± 1 se every {} in p; {how})",
                super::common::fixed(BAR_EVERY as f64 * k_dp(k), 2)
            )
        } else {
            "p   (no error bars: the jackknife needs 3 images, or tiles of fewer)".into()
        };
        if any_noise {
            chart.series.push(Series::new(
                format!(
                    "open: |C(p)| < {NOISE_SIGMAS} se at a or a' (noise; se: max of 1/sqrt(n), \
                     jackknife)"
                ),
                Vec::new(),
                Style::OpenMarkers,
                GREY,
            ));
        }
        save_chart(chart, &dir.join(file))?;
    }
    // II Figs 26, 28: C_n(a, a') against ln(a'/a)
    let th = model.and_then(|m| m.cumulants());
    let est = k.cumulants.values();
    let se = [
        k.cumulants.c1.stderr,
        k.cumulants.c2.stderr,
        k.cumulants.c3.stderr,
    ];
    for n in 0..3 {
        let mut c = Chart {
            title: title(&format!(
                "C{}(a, a'): c{} = {} (II Figs 26{l}, 28{l})",
                n + 1,
                n + 1,
                super::common::plus_minus(est[n], se[n], 4),
                l = ['a', 'b', 'c'][n]
            )),
            x_label: format!(
                "ln(a'/a)   (± and bars: 1 se, {})",
                super::common::se_label(&k.stderr_method, k.images)
            ),
            y_label: format!("C{}(a, a')", n + 1),
            ..Default::default()
        };
        let mut xmax: f64 = 0.0;
        for (i, t) in k.tables.iter().enumerate() {
            let pts: Vec<(f64, f64)> = t.rows.iter().map(|r| (r.ln_ratio, r.c[n])).collect();
            xmax = pts.iter().map(|p| p.0).fold(xmax, f64::max);
            c.series.push(
                Series::new(
                    format!(
                        "a' = 2^{:.1} a_min ({:.1} px{})",
                        t.octave_ref,
                        t.a_ref,
                        px_eq(px, t.a_ref)
                    ),
                    pts,
                    Style::Markers,
                    i,
                )
                .with_errors(t.rows.iter().map(|r| r.c_stderr[n]).collect()),
            );
        }
        // the headline c_n is minus the slope of kappa_n(ln M) against ln a
        // over the fit range (II eq 49: C_n = kappa_n(a) - kappa_n(a')), not
        // a fit to the points drawn; on a cascade the two agree, on other
        // data (a DEM) they need not, so both are drawn
        c.series.push(Series::new(
            format!(
                "c{} = {} (minus the slope of kappa{}(ln M) over ln a; the title's)",
                n + 1,
                super::common::fixed(est[n], 4),
                n + 1
            ),
            vec![(0.0, 0.0), (xmax, est[n] * xmax)],
            Style::Line,
            GREY,
        ));
        let pooled = [&k.pooled.c1, &k.pooled.c2, &k.pooled.c3][n];
        if pooled.value.is_finite() {
            c.series.push(Series::new(
                format!(
                    "fit to these points, through 0: {}",
                    super::common::plus_minus(pooled.value, pooled.stderr, 4)
                ),
                vec![(0.0, 0.0), (xmax, pooled.value * xmax)],
                Style::Line,
                // not the headline's grey, theory's olive, nor a reference
                // scale's colour (0..6)
                7,
            ));
        }
        if let Some(t) = th {
            c.series.push(Series::new(
                format!("theory: {}", super::common::fixed(t[n], 4)),
                vec![(0.0, 0.0), (xmax, t[n] * xmax)],
                Style::Dashed,
                // not the fit's grey, nor a reference scale's colour (0..6)
                8,
            ));
        }
        save_chart(&c, &dir.join(format!("cumulant_C{}.png", n + 1)))?;
    }
    // II Fig 29: pdfs pushed through the estimated kernel
    for (file, rs) in [
        ("reconstruction.png", &o.recon2),
        ("reconstruction_c3.png", &o.recon3),
    ] {
        let Some(first) = rs.first() else { continue };
        // the cumulants actually used (c1 alone where c2 < 0)
        let what = ["c1", "c1, c2", "c1, c2, c3"][first.c.len().clamp(1, 3) - 1];
        let mut c = Chart {
            title: title(&format!(
                "P_a' pushed to a = {:.2} px{}, {what} (II Fig 29)",
                first.a_to,
                px_eq(px, first.a_to)
            )),
            x_label: "M".into(),
            y_label: "ln P_a(M)".into(),
            ..Default::default()
        };
        let to_m = |u: &[f64], p: &[f64]| -> Vec<(f64, f64)> {
            let peak = p.iter().cloned().fold(0.0, f64::max);
            // below 1e-4 of the peak (or a negative predicted density): a
            // gap in the curve, not a line across it
            u.iter()
                .zip(p)
                .map(|(x, &v)| match v > 1e-4 * peak {
                    true => (x.exp(), (v / x.exp()).ln()),
                    false => (x.exp(), f64::NAN),
                })
                .collect()
        };
        c.series.push(Series::new(
            format!(
                "measured at a = {:.2} px{}",
                first.a_to,
                px_eq(px, first.a_to)
            ),
            to_m(&first.ln_m, &first.measured),
            Style::Markers,
            GREY,
        ));
        for (i, r) in rs.iter().enumerate() {
            // the colour of a' in the cumulant figures (C_n(a, a'))
            let colour = k
                .tables
                .iter()
                .position(|t| (t.a_ref - r.a_from).abs() <= 1e-6 * r.a_from)
                .unwrap_or(i);
            c.series.push(Series::new(
                format!(
                    "from a' = {:.2} px{} (L1 distance {:.3})",
                    r.a_from,
                    px_eq(px, r.a_from),
                    r.l1
                ),
                to_m(&r.ln_m, &r.predicted),
                Style::Line,
                colour,
            ));
        }
        save_chart(&c, &dir.join(file))?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stats::kernel::{DEFAULT_PAIR_OCTAVES, DEFAULT_REF_OCTAVES};

    /// The option strings and the library's constants cannot drift apart.
    #[test]
    fn default_strings_are_the_library_constants() {
        let refs = crate::cli::common::parse_list("refs", DEFAULT_REFS).unwrap();
        assert_eq!(refs, DEFAULT_REF_OCTAVES.to_vec());
        assert_eq!(
            parse_pairs("pairs", DEFAULT_PAIRS).unwrap(),
            DEFAULT_PAIR_OCTAVES.to_vec()
        );
    }
}
