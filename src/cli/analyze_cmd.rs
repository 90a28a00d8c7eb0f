//! `wtmm analyze IMAGE...`: the WTMM spectra of an annealed ensemble
//! (SPEC §4, §13), with CSVs and the four plots of II Fig 10.

use std::path::{Path, PathBuf};

use clap::Args;
use serde_json::json;

use super::common::{PeriodicSynth, save_chart};
use super::common::{f, header, make_out_dir, parse_q, parse_range, progress, write_csv};
use super::model_args::{ModelName, ModelOpts};
use super::{CwtOpts, OutDir, Outcome, PixelOpts, PixelSize};
use crate::cwt::Wavelet;
use crate::error::{Error, Result};
use crate::plot::{Chart, Series, Style, part_names};
use crate::skeleton::{AnalysisConfig, LinkParams, Parallelism, SearchRadius};
use crate::spectra::{
    PartitionSums, Rule, Spectra, at_wavelet_order, default_tile_side, image_sums_tiled, is_curved,
    local_slope_chords,
};
use crate::theory::{Model, TheoryTable};

/// Options of every command that builds maxima lines: the scale grid and
/// the linking (`skeleton`, `pdf`, `kernel`, `correlate`, and the spectra).
#[derive(Args, Debug, Clone)]
pub struct LineOpts {
    #[command(flatten)]
    pub cwt: CwtOpts,
    /// Linking: modulus-ratio window `LO:HI` between successive scales.
    #[arg(long, default_value = "0.9:1.11")]
    pub ratio: String,
    /// Linking: cap (px) of the search box half-width min(cap, 2 log2(6.98 a)).
    #[arg(long, default_value_t = 12.0, allow_negative_numbers = true)]
    pub radius_cap: f64,
    /// Linking: a line left without a WTMMM climbs the maxima chain it lands
    /// on to its maximum and takes it when free and inside the ratio window
    /// (see the README, "Why mexican lines die").
    #[arg(long)]
    pub link_climb: bool,
    /// Cut chains at the analysis domain, as the reference implementation
    /// does, instead of tracing them in the guard band outside it.
    #[arg(long)]
    pub no_guard: bool,
    /// Trend removed from each image before the transform: `plane`, the
    /// least-squares plane (a DEM's regional slope), which the gauss
    /// wavelet's transform gains as a vector growing like the scale and
    /// which biases h upwards; the mexican wavelet is blind to it. Not on a torus
    /// (--margin 0; --domain torus of pdf, kernel and correlate; the
    /// generated periodic models by default): give --margin N there.
    #[arg(long, value_enum, default_value_t = crate::field::Trend::None)]
    pub detrend: crate::field::Trend,
}

impl LineOpts {
    pub fn analysis(&self) -> Result<AnalysisConfig> {
        let g = self.cwt.grid()?;
        let ratio = parse_range("ratio", &self.ratio)?;
        let cfg = AnalysisConfig {
            wavelet: self.cwt.wavelet.unwrap_or(Wavelet::Gauss),
            a_min: g.a_min,
            octaves: g.octaves,
            voices: g.voices,
            scales: None,
            margin: self.cwt.margin,
            eps: 1e-7,
            link: LinkParams {
                radius: SearchRadius::Reference {
                    cap: self.radius_cap,
                },
                ratio,
                climb: self.link_climb,
            },
            guard: !self.no_guard,
            detrend: self.detrend,
        };
        cfg.validate()?;
        Ok(cfg)
    }
}

/// `--fit LO:HI` (octaves above a_min), or the default
/// [`crate::spectra::default_fit`] (0.5:min(4, octaves) when the voices
/// divide half an octave), checked against the grid of `octaves` x
/// `voices` scales.
pub fn fit_range(fit: Option<&str>, octaves: usize, voices: usize) -> Result<(f64, f64)> {
    // the grid's own checks first (they name --octaves or --voices), before
    // a grid of octaves x voices scales is built below
    crate::cwt::ScaleGrid {
        a_min: 1.0,
        octaves,
        voices,
    }
    .validate()?;
    let r = match fit {
        Some(f) => parse_range("fit", f)?,
        None => crate::spectra::default_fit(octaves, voices),
    };
    check_fit(r, octaves as f64, 1.0 / voices as f64, "")?;
    // fewer than 3 scales is refused here, before any image is analysed
    // (one scale has no linked maxima, which read as a flat image)
    let grid: Vec<f64> = (0..octaves * voices)
        .map(|j| (j as f64 / voices as f64).exp2())
        .collect();
    crate::spectra::fit_indices(&grid, r)?;
    Ok(r)
}

/// A fit range must lie within `0:span` octaves (`span` = the grid's
/// octaves; HI = span runs to the top scale, one voice below it) and both
/// ends on the grid: an end between two voices would fit from the next
/// scale and be recorded as given. `what` ends the range message.
pub fn check_fit(r: (f64, f64), span: f64, step: f64, what: &str) -> Result<()> {
    if r.0 < 0.0 || r.1 > span + 1e-6 {
        return Err(Error::param(
            "fit",
            format!(
                "{}:{} must lie within 0:{span} octaves (HI = {span} fits up to the top \
                 scale, {} octaves above a_min){what}",
                crate::error::short(r.0),
                crate::error::short(r.1),
                crate::error::short(span - step)
            ),
        ));
    }
    if let Some(o) = [r.0, r.1]
        .into_iter()
        .find(|&o| ((o / step).round() - o / step).abs() > 1e-6)
    {
        return Err(Error::param(
            "fit",
            format!(
                "octave {o} of {}:{} lies between two scales: use a multiple of the voice step {step:.4} octave",
                r.0, r.1
            ),
        ));
    }
    Ok(())
}

/// Options shared by every command that builds spectra.
#[derive(Args, Debug, Clone)]
pub struct SpectraOpts {
    #[command(flatten)]
    pub line: LineOpts,
    /// q values: `start:stop:step` or `a,b,c`.
    #[arg(long, default_value = "-4:6:0.5", allow_hyphen_values = true)]
    pub q: String,
    /// Fit range in octaves above a_min, `LO:HI` (the first half octave is
    /// left out: see the README, "How the defaults were chosen"). Default
    /// 0.5:4, or 0.5:OCTAVES with fewer than 4 octaves (from the first scale
    /// above half an octave when the voices are odd: 0.667 with 3).
    #[arg(long, allow_hyphen_values = true)]
    pub fit: Option<String>,
    /// Modulus along a maxima line: plain (M at a) or sup (max of M over scales <= a).
    #[arg(long, value_enum, default_value_t = Rule::Plain)]
    pub rule: Rule,
    /// Same as `--rule plain`, the default: changes nothing (kept for
    /// scripts that name it).
    #[arg(long, conflicts_with = "rule")]
    pub plain: bool,
}

impl SpectraOpts {
    /// The options as the command line leaves them by default (taken from
    /// the clap definitions, so the defaults live in one place).
    pub fn defaults() -> Self {
        use clap::{Args as _, FromArgMatches as _};
        let cmd = SpectraOpts::augment_args(clap::Command::new("defaults"));
        SpectraOpts::from_arg_matches(&cmd.get_matches_from(["defaults"])).expect("defaults parse")
    }

    pub fn analysis(&self) -> Result<AnalysisConfig> {
        self.line.analysis()
    }

    pub fn q(&self) -> Result<Vec<f64>> {
        parse_q("q", &self.q)
    }

    pub fn fit(&self) -> Result<(f64, f64)> {
        fit_range(
            self.fit.as_deref(),
            self.line.cwt.octaves,
            self.line.cwt.voices,
        )
    }

    pub fn rule(&self) -> Rule {
        if self.plain { Rule::Plain } else { self.rule }
    }
}

#[derive(Args, Debug)]
pub struct AnalyzeArgs {
    /// Input images, analysed as one annealed ensemble.
    #[arg(required = true)]
    pub images: Vec<PathBuf>,
    #[command(flatten)]
    pub opts: SpectraOpts,
    /// Theory to draw over the estimates: MODEL with its options (or --preset).
    #[arg(long, value_enum)]
    pub theory: Option<ModelName>,
    #[command(flatten)]
    pub model_opts: ModelOpts,
    #[command(flatten)]
    pub pixel: PixelOpts,
    #[command(flatten)]
    pub read: super::ReadOpts,
    /// Fill missing pixels harmonically (Laplace's equation inside each
    /// hole, its rim as the boundary) and count them as data. Without it
    /// maxima count only farther from a hole than the wavelet's support, so
    /// scattered voids leave nothing to count. On fBm (H 0.3-0.7) with 5 %
    /// of scattered pixels or small holes (up to 13 px) missing, the filled
    /// images kept the tau(q) of the full ones within 0.014 for q >= -1
    /// (the mean fill biased it by up to -0.13), with 30 % within 0.028.
    /// Larger holes become smooth patches, of high h, and raise tau(3) by
    /// 0.2-0.55 times the share they cover: crop them instead. The fill
    /// stops at the image's borders, except on a torus (--margin 0), where
    /// a hole across a border is filled from both sides.
    #[arg(long)]
    pub fill_holes: bool,
    #[command(flatten)]
    pub out: OutDir,
}

/// Closed-form curves drawn over estimates.
pub struct TheoryCurves {
    pub name: String,
    /// The name with the model's parameters, for the legends.
    pub label: String,
    pub tau: Box<dyn Fn(f64) -> f64>,
    /// (h, D(h)) samples.
    pub dh: Vec<(f64, f64)>,
    /// (q, tau) of the images' own cascades, where the generator has one
    /// (`validate`; [`Model::sample_sums`]).
    pub sample: Option<Vec<(f64, f64)>>,
}

/// The closed-form curves of a resolved model.
pub fn theory_curves(model: &Model, name: &str, q: &[f64]) -> Result<TheoryCurves> {
    let t = TheoryTable::new(model, q)?;
    let m = *model;
    Ok(TheoryCurves {
        name: name.to_string(),
        label: format!("{name} ({})", super::common::model_params_label(model)),
        tau: Box::new(move |qq| m.tau(qq)),
        dh: t.dh_h.iter().cloned().zip(t.dh_d.iter().cloned()).collect(),
        sample: None,
    })
}

pub fn run(args: AnalyzeArgs, quiet: bool) -> Result<Outcome> {
    let q = args.opts.q()?;
    let fit = args.opts.fit()?;
    let nodata = args.read.value()?;
    let (px, px_warnings) = args.pixel.resolve(&args.images)?;
    let resolved = args.model_opts.resolve_optional(args.theory)?;
    // the preset's wavelet unless --wavelet (paper-fisc: mexican), as in
    // pdf, kernel and correlate
    let mut opts = args.opts.clone();
    if let Some(r) = &resolved
        && opts.line.cwt.wavelet.is_none()
    {
        opts.line.cwt.wavelet = Some(r.wavelet);
        // the overlay changes the measurement itself: said, not only recorded
        if r.wavelet != crate::skeleton::AnalysisConfig::default().wavelet {
            say!(
                "note: analysing with the {} wavelet, the one {} recommends (the default without \
                 a theory is {}); give --wavelet to choose",
                r.wavelet,
                r.preset.unwrap_or(r.model.name()),
                crate::skeleton::AnalysisConfig::default().wavelet
            );
        }
    }
    let origin = torus_for_synth(&mut opts.line, &args.images);
    let cfg = opts.analysis()?;
    let (theory, theory_model) = match resolved {
        Some(r) => {
            let name = r.preset.unwrap_or(r.model.name());
            (
                Some(theory_curves(&r.model, name, &q)?),
                Some(json!({"name": name, "model": r.model})),
            )
        }
        None => (None, None),
    };
    let mut sums = analyze_paths(&args.images, nodata, args.fill_holes, &cfg, &q, quiet)?;
    // recorded in sums.json, for merge
    sums.pixel = px.as_ref().map(PixelSize::record);
    let mut spectra = sums.spectra(args.opts.rule(), fit).map_err(|e| match e {
        // name the input: "nothing estimable" is about these images
        Error::Input(m) if args.images.len() == 1 => {
            Error::Input(format!("{}: {m}", args.images[0].display()))
        }
        e => e,
    })?;
    let other_rule = match args.opts.rule() {
        Rule::Sup => Rule::Plain,
        Rule::Plain => Rule::Sup,
    };
    let other = sums.spectra(other_rule, fit)?;
    spectra.warnings.extend(
        px.as_ref()
            .and_then(|p| p.warning(super::Isotropic::Wavelet)),
    );
    spectra.warnings.extend(px_warnings);
    PixelSize::say_note(px.as_ref(), quiet);
    make_out_dir(&args.out.out)?;
    let params = json!({
        "images": super::common::paths_json(&args.images), "analysis": super::common::analysis_json(&cfg), "q": q, "fit_octaves": fit,
        "rule": args.opts.rule(), "theory": theory_model,
        "pixel_size": px.as_ref().map(PixelSize::json),
        "origin": origin.as_ref().map(PeriodicSynth::json), "nodata": nodata,
        "fill_holes": args.fill_holes,
    });
    write_outputs(
        &args.out.out,
        "analyze",
        params,
        &sums,
        &spectra,
        &other,
        theory.as_ref(),
    )?;
    show!("{}", summary("analyze", &spectra, &sums, px.as_ref()));
    for w in &spectra.warnings {
        say!("warning: {w}");
    }
    Ok(Outcome::Ok)
}

/// What `validate` takes for the model of files `wtmm synth` wrote from a
/// periodic one ([`super::common::periodic_synth`]): margin 0 (the whole
/// torus) unless `--margin` or `--detrend` was given (a plane is removed
/// inside a margin only), and the wavelet its record recommends (mexican
/// for FISC) unless `--wavelet` or a theory named one; said in a note.
pub(super) fn torus_for_synth(line: &mut LineOpts, images: &[PathBuf]) -> Option<PeriodicSynth> {
    let torus = line.cwt.margin.is_none() && line.detrend == crate::field::Trend::None;
    let wavelet_open = line.cwt.wavelet.is_none();
    if !torus && !wavelet_open {
        return None;
    }
    let origin = super::common::periodic_synth(
        images,
        torus.then_some("analysed inside the margin: --margin 0 takes tori whole"),
        wavelet_open,
    )?;
    let mut took = Vec::new();
    if torus {
        line.cwt.margin = Some(0);
        took.push("analysed whole, as a torus (--margin 0)".to_string());
    }
    if let Some(w) = origin
        .wavelet
        .filter(|&w| wavelet_open && w != Wavelet::Gauss)
    {
        line.cwt.wavelet = Some(w);
        took.push(format!(
            "with the {w} wavelet its synth.json recommends (--wavelet)"
        ));
    }
    if took.is_empty() {
        return None;
    }
    say!(
        "note: {}: {}, as validate analyses the model; give the flags to choose otherwise",
        origin.describe(images.len()),
        took.join(", ")
    );
    Some(origin)
}

/// The answer in a few lines (stdout, as `tm`'s): what was fitted, the
/// numbers a paper quotes (h(0), D(h(0)), tau(2) and the beta it implies,
/// the range of h), with their errors, and which q the warnings flag.
/// The reading of a spectra result on stdout, headed by the command that
/// made it (`analyze`, `merge`).
pub(super) fn summary(
    cmd: &str,
    s: &Spectra,
    sums: &PartitionSums,
    px: Option<&PixelSize>,
) -> String {
    let pm = |i: usize, v: &[f64], e: &[f64]| match e[i].is_finite() {
        true => format!("{:.3} +- {:.3}", v[i], e[i]),
        false => format!("{:.3}", v[i]),
    };
    let at = |q0: f64| s.q_index(q0).filter(|&i| (s.q[i] - q0).abs() < 1e-9);
    let flag = flagged_q(s, wavelet_order(sums));
    let lengths = px.map_or(String::new(), |p| {
        format!(
            " ({} - {})",
            p.length(s.fit_scales.0),
            p.length(s.fit_scales.1)
        )
    });
    let mut out = format!(
        "{cmd}: {}, fit a = {:.1}-{:.1} px{lengths}; errors: {}\n",
        describe(s, sums),
        s.fit_scales.0,
        s.fit_scales.1,
        s.stderr_method
    );
    if let Some(i) = at(0.0) {
        out += &format!(
            "  h(q=0) = {}, D(h(q=0)) = {}\n",
            pm(i, &s.h, &s.h_stderr),
            pm(i, &s.d, &s.d_stderr)
        );
    }
    if let Some(i) = at(2.0) {
        out += &format!(
            "  tau(2) = {} (beta = tau(2) + 4 = {:.3}, angle-averaged)\n",
            pm(i, &s.tau, &s.tau_stderr),
            s.tau[i] + 4.0
        );
    }
    // the h the fitted q span, over the q the warnings do not flag
    let kept: Vec<usize> = (0..s.q.len())
        .filter(|&i| !flag[i] && s.h[i].is_finite())
        .collect();
    let hs = kept.iter().map(|&i| s.h[i]);
    let (lo, hi) = (
        hs.clone().fold(f64::INFINITY, f64::min),
        hs.fold(f64::NEG_INFINITY, f64::max),
    );
    if lo <= hi {
        out += &format!(
            "  h(q) spans {lo:.3} .. {hi:.3} over the {} of {} q not flagged\n",
            kept.len(),
            s.q.len()
        );
    }
    let flagged: Vec<String> = (0..s.q.len())
        .filter(|&i| flag[i])
        .map(|i| s.q[i].to_string())
        .collect();
    if !flagged.is_empty() {
        out += &format!(
            "  flagged (open circles in tau.png and dh.png; see the warnings): q = {}\n",
            flagged.join(", ")
        );
    }
    out
}

/// Reads and analyses every image (in parallel over images; `nodata` as
/// [`super::common::read_image`]; `fill`: missing pixels filled
/// harmonically and analysed as data, `--fill-holes`,
/// [`super::common::fill_holes_noted`]); a bad or constant
/// image stops everything before any output is written.
pub fn analyze_paths(
    paths: &[PathBuf],
    nodata: Option<f64>,
    fill: bool,
    cfg: &AnalysisConfig,
    q: &[f64],
    quiet: bool,
) -> Result<PartitionSums> {
    // an ensemble: one image per worker, as many workers as the memory
    // holds images (a lone image is checked with its threads once read)
    let limit = super::common::ensemble_memory_workers(
        paths,
        super::common::ENSEMBLE_ANALYSIS_BYTES_PER_PIXEL,
        "the analysis",
    )?;
    let pb = progress(paths.len() as u64, "analyze", quiet);
    // a lone image (a DEM) would leave all but one core idle: detect its
    // scales in parallel instead (the same sums to the bit)
    let par = if paths.len() == 1 {
        Parallelism::Scales
    } else {
        Parallelism::Serial
    };
    let notes = super::common::OrderedNotes::default();
    // margin 0: the images are tori, and so is their fill
    let torus = cfg.margin == Some(0);
    // the first bad image in input order is named, whatever the scheduling
    let parts = crate::par::try_map_at_limited(paths.len(), limit, |i| {
        let p = &paths[i];
        let field = super::common::read_image_noted(p, nodata, i, &notes)?;
        let (field, filled) = if fill {
            let (f, h) =
                super::common::fill_holes_noted(field, p, torus, (i, paths.len() == 1), &notes)?;
            (f, Some(h))
        } else {
            (field, None)
        };
        super::common::refuse_constant(&field, p, crate::skeleton::CONSTANT)?;
        super::common::check_image_memory(p, &field, paths.len() == 1)?;
        // fewer than 3 images: the jackknife runs over tiles
        let side = if paths.len() < 3 {
            let (ny, nx) = field.dim();
            default_tile_side(cfg, ny, nx)
        } else {
            0
        };
        // (an image without maxima lines is an error of the library's)
        let mut s = image_sums_tiled(&field, cfg, q, p.display().to_string(), par, side)
            .map_err(|e| super::common::in_file(p, e))?;
        // recorded per image, so that merged sums still say it
        s.images[0].nodata = nodata;
        if let Some(h) = filled {
            s.images[0].filled = h.missing;
            s.images[0].largest_filled_hole = h.largest;
            s.images[0].in_large_filled_holes = h.in_large;
        }
        pb.inc(1);
        Ok(s)
    });
    pb.finish_and_clear();
    notes.say_upto(parts.as_ref().err().map(|f| f.0));
    let parts = parts.map_err(|f| f.1)?;
    Ok(PartitionSums::merge_all(parts)?.expect("at least one image"))
}

fn spectra_json(s: &Spectra) -> serde_json::Value {
    serde_json::to_value(s).expect("spectra serialise")
}

/// Writes spectra.json, sums.json, the CSVs and the four plots.
pub fn write_outputs(
    dir: &Path,
    command: &str,
    params: serde_json::Value,
    sums: &PartitionSums,
    s: &Spectra,
    other: &Spectra,
    theory: Option<&TheoryCurves>,
) -> Result<()> {
    // the pixel, when given (params.pixel_size): the fit's scales as lengths
    let px = super::params_pixel(&params);
    let mut body = header(command, params);
    if let (Some(obj), serde_json::Value::Object(sp)) = (body.as_object_mut(), spectra_json(s)) {
        for (k, v) in sp {
            obj.insert(k, v);
        }
    }
    body["alternate_rule"] = json!({
        "rule": other.rule, "tau": other.tau, "tau_stderr": other.tau_stderr,
        "h": other.h, "D": other.d, "legendre_h": other.legendre_h, "legendre_D": other.legendre_d,
    });
    let i0 = s.q_index(0.0);
    if let Some(i0) = i0.filter(|&i| s.q[i] == 0.0) {
        body["h_q0"] = json!(s.h[i0]);
        body["D_h_q0"] = json!(s.d[i0]);
        body["tau_q0"] = json!(s.tau[i0]);
        // the errors the summary prints beside them (stderr_method)
        body["h_q0_stderr"] = json!(s.h_stderr[i0]);
        body["D_h_q0_stderr"] = json!(s.d_stderr[i0]);
        body["tau_q0_stderr"] = json!(s.tau_stderr[i0]);
    }
    let (mut dl_max, mut n_cmp) = (0.0f64, 0);
    for i in 1..s.q.len().saturating_sub(1) {
        if s.h[i].is_finite() && s.legendre_h[i].is_finite() {
            dl_max = dl_max.max((s.h[i] - s.legendre_h[i]).abs());
            n_cmp += 1;
        }
    }
    body["canonical_vs_legendre_max_abs_dh"] = json!(if n_cmp > 0 { dl_max } else { f64::NAN });
    if let Some(t) = theory {
        let th: Vec<f64> = s.q.iter().map(|&q| (t.tau)(q)).collect();
        let dev: Vec<f64> = s.tau.iter().zip(&th).map(|(a, b)| a - b).collect();
        body["theory"] = json!({"name": t.name, "tau": th, "tau_minus_theory": dev});
    }
    if let Some((side, units)) = &px {
        body["fit_lengths"] = json!([s.fit_scales.0 * side, s.fit_scales.1 * side]);
        body["length_units"] = json!(units);
    }
    crate::cli::common::write_json(&dir.join("spectra.json"), &body)?;
    sums.write_json(dir.join("sums.json"))?;
    let rows: Vec<Vec<String>> = (0..s.q.len())
        .map(|i| {
            vec![
                f(s.q[i]),
                f(s.tau[i]),
                f(s.tau_stderr[i]),
                f(s.tau_r2[i]),
                f(s.tau_slope_change.get(i).copied().unwrap_or(f64::NAN)),
                f(s.h[i]),
                f(s.h_stderr[i]),
                f(s.d[i]),
                f(s.d_stderr[i]),
                f(s.legendre_h[i]),
                f(s.legendre_d[i]),
            ]
        })
        .collect();
    write_csv(
        &dir.join("tau.csv"),
        &[
            "q",
            "tau",
            "tau_stderr",
            "tau_r2",
            "tau_slope_change",
            "h",
            "h_stderr",
            "D",
            "D_stderr",
            "legendre_h",
            "legendre_D",
        ],
        &rows,
    )?;
    let mut hdr = vec!["q".to_string()];
    hdr.extend(s.log2_scales.iter().map(|l| format!("log2a={l:.4}")));
    let hdr_ref: Vec<&str> = hdr.iter().map(|x| x.as_str()).collect();
    for (name, table) in [
        ("logZ.csv", &s.log2_z),
        ("hqa.csv", &s.h_qa),
        ("Dqa.csv", &s.d_qa),
    ] {
        let rows: Vec<Vec<String>> =
            s.q.iter()
                .zip(table)
                .map(|(q, r)| {
                    std::iter::once(f(*q))
                        .chain(r.iter().map(|v| f(*v)))
                        .collect()
                })
                .collect();
        write_csv(&dir.join(name), &hdr_ref, &rows)?;
    }
    write_per_scale_csv(&dir.join("per_scale.csv"), s)?;
    let px = px.as_ref().map(|(side, units)| (*side, units.as_str()));
    plot_spectra(dir, s, &describe(s, sums), theory, wavelet_order(sums), px)
}

/// per_scale.csv: one row per q and scale, the values of logZ.csv, hqa.csv
/// and Dqa.csv with their errors, and the local slopes (slopes.png): a
/// long table, for spreadsheets and data frames.
fn write_per_scale_csv(path: &Path, s: &Spectra) -> Result<()> {
    let at = |t: &Vec<Vec<f64>>, qi: usize, j: usize| {
        f(t.get(qi)
            .and_then(|r| r.get(j))
            .copied()
            .unwrap_or(f64::NAN))
    };
    let mut rows = Vec::with_capacity(s.q.len() * s.log2_scales.len());
    for (qi, &q) in s.q.iter().enumerate() {
        for (j, &l) in s.log2_scales.iter().enumerate() {
            rows.push(vec![
                f(q),
                f(l),
                at(&s.log2_z, qi, j),
                at(&s.log2_z_stderr, qi, j),
                at(&s.h_qa, qi, j),
                at(&s.h_qa_stderr, qi, j),
                at(&s.d_qa, qi, j),
                at(&s.d_qa_stderr, qi, j),
                at(&s.local_slopes, qi, j),
                at(&s.local_slopes_stderr, qi, j),
                at(&s.n_eff, qi, j),
            ]);
        }
    }
    write_csv(
        path,
        &[
            "q",
            "log2a",
            "log2_Z",
            "log2_Z_stderr",
            "h_qa",
            "h_qa_stderr",
            "D_qa",
            "D_qa_stderr",
            "local_slope",
            "local_slope_stderr",
            "n_eff",
        ],
        &rows,
    )
}

/// The legend line of the per-scale figures' bars: the errors they are,
/// or why there are none (the regression's errors are of slopes, not of
/// the points: fewer than 3 images and no tiles).
fn per_scale_bars(s: &Spectra, errors: &[&Vec<Vec<f64>>]) -> String {
    let any = errors
        .iter()
        .copied()
        .flatten()
        .flatten()
        .any(|e| e.is_finite());
    if any {
        format!(
            "bars: ± 1 se ({})",
            super::common::se_label(&s.stderr_method, s.images)
        )
    } else {
        "no error bars: a jackknife needs 3 images, or tiles".into()
    }
}

/// `series` with the errors `err[qi]` when they are there (spectra of
/// older versions have none).
fn with_row_errors(series: Series, err: &[Vec<f64>], qi: usize) -> Series {
    match err.get(qi) {
        Some(e) if e.len() == series.points.len() => series.with_errors(e.clone()),
        _ => series,
    }
}

/// The vanishing moments of the wavelet the sums were made with (`None`
/// for sums that do not record their analysis).
fn wavelet_order(sums: &PartitionSums) -> Option<f64> {
    sums.analysis.as_ref().map(|a| f64::from(a.wavelet.order()))
}

/// The local slopes of `log2 Z(q, a)`, over about one octave around each
/// scale, against `log2 a`, with each fitted tau(q) drawn over the fit
/// range: where a curve is flat and on its line the partition function is a
/// power law; where it drifts, the fitted tau(q) is an average of slopes
/// (what the curvature warning measures, `tau_slope_change`).
fn local_slopes(s: &Spectra, shown: &[usize], what: &str, px: Option<(f64, &str)>) -> Chart {
    let l = &s.log2_scales;
    let (lo, hi) = (s.fit_scales.0.log2(), s.fit_scales.1.log2());
    // chords of an octave or more (spectra::local_slope_chords): a grid of
    // less (`--octaves 1` at 10 voices gives 10 scales) leaves no slope to
    // draw, which the title says
    let any = local_slope_chords(l).iter().any(|c| c.is_some());
    let span = s.local_slope_octaves;
    let title = if any {
        let over = if (span - 1.0).abs() < 1e-6 {
            "one octave".to_string()
        } else if span.is_finite() {
            format!("{span:.2} octaves")
        } else {
            "an octave or more (uneven scales)".to_string()
        };
        format!("local slopes of log2 Z(q, a), over {over}: {what}")
    } else {
        format!(
            "local slopes of log2 Z(q, a): none, {} scales span less than an octave: {what}",
            l.len()
        )
    };
    let mut c = Chart {
        title,
        x_label: format!("log2 a  (a in px{})", super::px_is(px)),
        y_label: "d log2 Z / d log2 a".into(),
        ..Default::default()
    };
    // the slopes of older spectra (read back without them) from log2 Z
    let slopes = |qi: usize| match s.local_slopes.get(qi) {
        Some(v) if v.len() == l.len() => v.clone(),
        _ => crate::spectra::local_slopes(l, &s.log2_z[qi]),
    };
    for (k, &qi) in shown.iter().enumerate() {
        let pts: Vec<(f64, f64)> = l.iter().cloned().zip(slopes(qi)).collect();
        let none = pts.iter().all(|p| !p.1.is_finite());
        // the q named on its curve, or on its fitted line when it has none
        let name = format!("q = {}", s.q[qi]);
        let (curve, line) = if none {
            (String::new(), name)
        } else {
            (name, String::new())
        };
        if !none {
            let curve = Series::new(curve, pts, Style::Line, k);
            c.series
                .push(with_row_errors(curve, &s.local_slopes_stderr, qi));
        }
        if s.tau[qi].is_finite() {
            c.series.push(Series::new(
                line,
                vec![(lo, s.tau[qi]), (hi, s.tau[qi])],
                Style::Dashed,
                k,
            ));
        }
    }
    c.series.push(Series::new(
        format!(
            "dashed: fitted tau(q) over a = {:.1}-{:.1} px{}",
            s.fit_scales.0,
            s.fit_scales.1,
            super::px_span(px, s.fit_scales.0, s.fit_scales.1)
        ),
        Vec::new(),
        Style::Dashed,
        THEORY_COLOR,
    ));
    if any {
        c.series.push(Series::new(
            per_scale_bars(s, &[&s.local_slopes_stderr]),
            Vec::new(),
            Style::Line,
            THEORY_COLOR,
        ));
    }
    c
}

/// The q whose estimate the warnings flag as no exponent: a curved log2 Z
/// ([`is_curved`]) or an h at the wavelet's order ([`at_wavelet_order`]),
/// the tests [`Spectra`]'s warnings use.
fn flagged_q(s: &Spectra, order: Option<f64>) -> Vec<bool> {
    (0..s.q.len())
        .map(|i| {
            let curved = s.tau_slope_change.get(i).is_some_and(|&c| is_curved(c));
            let beyond = order.is_some_and(|o| at_wavelet_order(s.h[i], o));
            curved || beyond
        })
        .collect()
}

/// `points` split by `flag`: (unflagged, flagged), NaN where the other is.
fn split_points(points: &[(f64, f64)], flag: &[bool]) -> [Vec<(f64, f64)>; 2] {
    let nan = (f64::NAN, f64::NAN);
    [false, true].map(|want| {
        points
            .iter()
            .zip(flag)
            .map(|(&p, &f)| if f == want { p } else { nan })
            .collect()
    })
}

/// What the figures show, for their titles: images and sizes, wavelet, rule.
fn describe(s: &Spectra, sums: &PartitionSums) -> String {
    let wavelet = sums.analysis.as_ref().map_or(String::new(), |a| {
        format!(
            ", {}{}",
            a.wavelet.name(),
            super::common::trend_label(a.detrend)
        )
    });
    let labels: Vec<&str> = sums.images.iter().map(|i| i.label.as_str()).collect();
    format!(
        "{}{wavelet}, {} rule",
        super::common::data_label(&labels, s.images, &s.image_shapes),
        s.rule.name()
    )
}

/// Palette index of the theory curves (dark grey).
const THEORY_COLOR: usize = 9;

/// II Fig 10: (a) log2 Z vs log2 a, (b) h(q, a) vs log2 a, (c) tau(q), (d) D(h).
pub fn plot_spectra(
    dir: &Path,
    s: &Spectra,
    what: &str,
    theory: Option<&TheoryCurves>,
    wavelet_order: Option<f64>,
    px: Option<(f64, &str)>,
) -> Result<()> {
    let nq = s.q.len();
    // estimates the warnings call no exponent are drawn open, so that the
    // figures say what the warnings do
    let flag = flagged_q(s, wavelet_order);
    let flag_name = "flagged (open): curved log2 Z or h at the wavelet's order; see the warnings";
    // a readable subset of q: at most 9 curves (palette colours 0-8; 9 is
    // the theory's grey), counted back from the last q so that both ends
    // of the grid are drawn (and q = 0 on a grid like -6:8:0.5). A step
    // that does not divide the grid leaves at most 8 before the first q.
    let step = nq.saturating_sub(1).div_ceil(8).max(1);
    let mut shown: Vec<usize> = (0..nq).rev().step_by(step).collect();
    if shown.last() != Some(&0) && nq > 0 {
        shown.push(0);
    }
    shown.reverse();
    let (lo, hi) = (s.fit_scales.0.log2(), s.fit_scales.1.log2());
    let mut za = Chart {
        title: format!("(a) partition functions: {what}"),
        x_label: format!("log2 a  (a in px{})", super::px_is(px)),
        y_label: "log2 Z(q, a)".into(),
        ..Default::default()
    };
    let mut hb = Chart {
        // the level is a weighted mean of log2 M, not an exponent: the
        // slope is h(q) (SPEC §4), as tau(q) is that of log2 Z
        title: format!("(b) h(q, a), slopes h(q): {what}"),
        x_label: format!("log2 a  (a in px{})", super::px_is(px)),
        y_label: "h(q, a) = Σ W log2 M".into(),
        ..Default::default()
    };
    for (k, &qi) in shown.iter().enumerate() {
        let c = k;
        let pts: Vec<(f64, f64)> = s
            .log2_scales
            .iter()
            .cloned()
            .zip(s.log2_z[qi].iter().cloned())
            .collect();
        za.series.push(with_row_errors(
            Series::new(format!("q = {}", s.q[qi]), pts, Style::Markers, c),
            &s.log2_z_stderr,
            qi,
        ));
        let pts_h: Vec<(f64, f64)> = s
            .log2_scales
            .iter()
            .cloned()
            .zip(s.h_qa[qi].iter().cloned())
            .collect();
        hb.series.push(with_row_errors(
            Series::new(format!("q = {}", s.q[qi]), pts_h, Style::Markers, c),
            &s.h_qa_stderr,
            qi,
        ));
        // fitted lines over the fit range, through the mean of the fitted points
        for (chart, slope, vals) in [
            (&mut za, s.tau[qi], &s.log2_z[qi]),
            (&mut hb, s.h[qi], &s.h_qa[qi]),
        ] {
            let sel: Vec<(f64, f64)> = s
                .log2_scales
                .iter()
                .cloned()
                .zip(vals.iter().cloned())
                .filter(|(x, y)| *x >= lo - 1e-9 && *x <= hi + 1e-9 && y.is_finite())
                .collect();
            if sel.is_empty() || !slope.is_finite() {
                continue;
            }
            let mx = sel.iter().map(|p| p.0).sum::<f64>() / sel.len() as f64;
            let my = sel.iter().map(|p| p.1).sum::<f64>() / sel.len() as f64;
            chart.series.push(Series::new(
                "",
                vec![(lo, my + slope * (lo - mx)), (hi, my + slope * (hi - mx))],
                Style::Line,
                c,
            ));
        }
    }
    // one legend line for the fitted lines: what they are and where
    for (chart, errors) in [(&mut za, &s.log2_z_stderr), (&mut hb, &s.h_qa_stderr)] {
        chart.series.push(Series::new(
            format!(
                "lines: fits over a = {:.1}-{:.1} px{}",
                s.fit_scales.0,
                s.fit_scales.1,
                super::px_span(px, s.fit_scales.0, s.fit_scales.1)
            ),
            Vec::new(),
            Style::Line,
            THEORY_COLOR,
        ));
        chart.series.push(Series::new(
            per_scale_bars(s, &[errors]),
            Vec::new(),
            Style::Markers,
            THEORY_COLOR,
        ));
    }
    save_chart(&za, &dir.join("logZ.png"))?;
    save_chart(&hb, &dir.join("hqa.png"))?;
    save_chart(&local_slopes(s, &shown, what, px), &dir.join("slopes.png"))?;
    let mut tc = Chart {
        title: format!(
            "(c) tau(q), fit {:.1}-{:.1} px{}: {what}",
            s.fit_scales.0,
            s.fit_scales.1,
            super::px_span(px, s.fit_scales.0, s.fit_scales.1)
        ),
        x_label: "q".into(),
        y_label: "tau(q)".into(),
        ..Default::default()
    };
    // which errors the bars are (the method's details are in spectra.json)
    let how = super::common::se_label(&s.stderr_method, s.images);
    let tau_pts: Vec<(f64, f64)> = s.q.iter().cloned().zip(s.tau.iter().cloned()).collect();
    let [good, bad] = split_points(&tau_pts, &flag);
    let (name, flagged) = part_names(format!("estimate ± 1 se ({how})"), flag_name.into(), &good);
    tc.series
        .push(Series::new(name, good, Style::Markers, 0).with_errors(s.tau_stderr.clone()));
    if flag.contains(&true) {
        tc.series.push(
            Series::new(flagged, bad, Style::OpenMarkers, 0).with_errors(s.tau_stderr.clone()),
        );
    }
    let mut dc = Chart {
        title: format!("(d) D(h): {what}"),
        x_label: "h".into(),
        y_label: "D(h)".into(),
        ..Default::default()
    };
    // both coordinates are estimates: jackknife errors of h(q) and D(q)
    let dh_pts: Vec<(f64, f64)> = s.h.iter().cloned().zip(s.d.iter().cloned()).collect();
    let [good, bad] = split_points(&dh_pts, &flag);
    let (name, flagged) = part_names(
        format!("canonical h(q), D(q) ± 1 se ({how})"),
        flag_name.into(),
        &good,
    );
    dc.series.push(
        Series::new(name, good, Style::Markers, 0)
            .with_errors(s.d_stderr.clone())
            .with_x_errors(s.h_stderr.clone()),
    );
    if flag.contains(&true) {
        dc.series.push(
            Series::new(flagged, bad, Style::OpenMarkers, 0)
                .with_errors(s.d_stderr.clone())
                .with_x_errors(s.h_stderr.clone()),
        );
    }
    // a line, so that it hides neither the canonical points nor their bars;
    // on a coarse q grid (steps over 0.5) with its points, since a line
    // between finite differences that far apart looks like a curve the
    // estimates do not give
    let coarse = s.q.windows(2).any(|w| w[1] - w[0] > 0.5 + 1e-9);
    dc.series.push(Series::new(
        if coarse {
            "Legendre of tau(q), at the q (coarse grid)"
        } else {
            "Legendre of tau(q)"
        },
        s.legendre_h
            .iter()
            .cloned()
            .zip(s.legendre_d.iter().cloned())
            .collect(),
        if coarse {
            Style::LineMarkers
        } else {
            Style::Line
        },
        3,
    ));
    // D = 2, the dimension of the support: an estimate above it is a bias
    // (or mixed regimes), not a dimension (see the Legendre warnings)
    let finite_h = || s.h.iter().chain(&s.legendre_h).filter(|h| h.is_finite());
    let (h_lo, h_hi) = (
        finite_h().copied().fold(f64::INFINITY, f64::min),
        finite_h().copied().fold(f64::NEG_INFINITY, f64::max),
    );
    if h_lo < h_hi {
        dc.series.push(Series::new(
            "D = 2 (the support)",
            vec![(h_lo, 2.0), (h_hi, 2.0)],
            Style::Dashed,
            THEORY_COLOR,
        ));
    }
    if let Some(t) = theory {
        let qs: Vec<f64> = (0..=200)
            .map(|i| s.q[0] + (s.q[nq - 1] - s.q[0]) * i as f64 / 200.0)
            .collect();
        tc.series.push(Series::new(
            format!("theory: {}", t.label),
            qs.iter().map(|&q| (q, (t.tau)(q))).collect(),
            Style::Line,
            // dark grey, as compare's and kernel's theory: red is trace
            // moments in compare, and too near the Legendre line's orange
            THEORY_COLOR,
        ));
        // a monofractal's D(h) is the one point (H, 2), which a dot would
        // hide on the D = 2 line: a vertical line at h = H, down through
        // the estimates, says where the theory puts every h(q)
        let dh = match t.dh[..] {
            [(h, d)] => {
                // to just below the lowest estimate's bar
                let low = (s.d.iter().zip(&s.d_stderr))
                    .map(|(v, e)| v - e.max(0.0))
                    .filter(|v| v.is_finite());
                let d_lo = low.fold(d - 0.05, f64::min) - 0.02;
                vec![(h, d_lo), (h, d)]
            }
            _ => t.dh.clone(),
        };
        let name = match t.dh[..] {
            [(h, d)] => format!("theory: {}: D = {d} at h = {h:.3} only", t.label),
            _ => format!("theory: {}", t.label),
        };
        dc.series
            .push(Series::new(name, dh, Style::Line, THEORY_COLOR));
        if let Some(pts) = &t.sample {
            tc.series.push(Series::new(
                "images' own cascades",
                pts.clone(),
                Style::Dashed,
                2,
            ));
        }
    }
    // the estimates (and the flagged ones) last, on top of the curves
    let n_est = 1 + usize::from(flag.contains(&true));
    tc.series.rotate_left(n_est);
    dc.series.rotate_left(n_est);
    save_chart(&tc, &dir.join("tau.png"))?;
    save_chart(&dc, &dir.join("dh.png"))
}
