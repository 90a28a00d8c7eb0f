//! `wtmm tm IMAGE... --out DIR`: trace moments, universal parameters, double
//! trace moments, structure functions and the spectral H of an annealed
//! ensemble (SPEC §8, §13; TM §5.2, §6, Figs 19-20, 25-28), with CSVs
//! and plots.

use std::path::{Path, PathBuf};

use clap::Args;
use serde_json::json;

use super::common::save_chart;
use super::common::{
    available_memory, f, header, make_out_dir, parse_list, parse_q, parse_range, plus_minus,
    progress, write_csv, write_json,
};
use super::{OutDir, Outcome, PixelOpts, PixelSize};
use crate::error::{Error, Result};
use crate::plot::{Chart, Series, Style};
use crate::stats::powspec::{HoleFill, PowerSpectrum, PowerSpectrumConfig, Window};
use crate::tracemoments::{
    BoxWeights, FluxDiff, FluxKind, SurrogateErrors, TraceMomentAccumulator, TraceMomentConfig,
    TraceMomentFitConfig, TraceMomentResult, UniversalWeighting, analyze_tiled, check_ensemble_fit,
    check_surrogate_count, finish_ensemble, surrogate_errors_with_progress, tile_side,
    universal_shape,
};

/// Trace-moment options shared by `tm` and `compare` (everything but the
/// trace-moment q grid).
#[derive(Args, Debug, Clone)]
pub struct TmOpts {
    /// The modulus that turns the (differentiated) field into a flux: of the
    /// finite-difference gradient, or of the finest Haar wavelet coefficients
    /// (both a differentiation of order 1).
    #[arg(long, value_enum, default_value_t = FluxKind::Gradient)]
    pub flux: FluxKind,
    /// Fractional differentiation of the field before the modulus (TM
    /// §5.2: "of order H or greater"): `auto` = order H = xi(1) estimated per
    /// image from its first-order structure function, so the modulus acts on
    /// the flux itself whatever H; `none` = the modulus alone (TM's
    /// estimator: alpha biased high, C1 low when H is well above 1/2); or a
    /// number.
    #[arg(long, default_value = "auto", allow_negative_numbers = true)]
    pub diff_order: String,
    /// Fractional integration of this order before the flux (TM §5.2: it
    /// removes the spurious zero gradients of quantised DEMs); `--frac-int`
    /// alone means 0.1. Applied on top of --diff-order (one Fourier filter of
    /// order diff - frac_int).
    #[arg(long, num_args = 0..=1, default_missing_value = "0.1", allow_negative_numbers = true)]
    pub frac_int: Option<f64>,
    /// Double trace moments: η values, `start:stop:step` or `a,b,c` [default: 16
    /// log-spaced values from 0.1 to 3.16].
    #[arg(long)]
    pub eta: Option<String>,
    /// Double trace moments: orders q (the first one gives dtm_alpha, dtm_C1).
    #[arg(long, default_value = "1.5")]
    pub dtm_q: String,
    /// Structure-function orders (q = 1 gives H_sf).
    #[arg(long, default_value = "0.5,1,1.5,2,2.5,3")]
    pub sf_q: String,
    /// Fit range of K(q) and K(q, η) in log2 λ (λ = L/l), `LO:HI`
    /// [default: 1:log2(L)-1, dropping the finest and the coarsest octave].
    #[arg(long, allow_hyphen_values = true)]
    pub lambda_fit: Option<String>,
    /// η range of the double-trace-moment fit, `LO:HI`.
    #[arg(long, default_value = "0.3:2", allow_hyphen_values = true)]
    pub eta_fit: String,
    /// Structure functions: fit range of log2 lag (px), `LO:HI` [default: 1:log2(L)-3].
    #[arg(long, allow_hyphen_values = true)]
    pub lag_fit: Option<String>,
    /// Power-spectrum fit range in rad/px, `LO:HI` [default: 8 cycles per image to pi/4].
    #[arg(long, allow_hyphen_values = true)]
    pub k_range: Option<String>,
    /// Upper bound on q in the universal fit (on top of the automatic q_s/2).
    #[arg(long)]
    pub q_fit_max: Option<f64>,
    /// Universal fit of (alpha, C1): `gls` = generalised least squares with
    /// the jackknife covariance of K(q) across q, q = 1 left out (correlations
    /// shrunk by the Schäfer-Strimmer intensity; needs >= 5 images or tiles), `ols` =
    /// unweighted least squares in K (the estimator before GLS) [default:
    /// gls for an ensemble of 5 or more images (fewer fall back to ols,
    /// recorded in tm.json), ols for fewer than 3 images, whose jackknife
    /// runs over their tiles: not independent samples for the covariance].
    #[arg(long, value_enum)]
    pub universal_fit: Option<UniversalWeighting>,
    /// Taper before the FFT of the spectrum [default: hann for `tm`, none for
    /// files `wtmm synth` wrote from a periodic model (listed in the synth.json
    /// beside them); none for the periodic models of `compare`, hann for fbm].
    #[arg(long, value_enum)]
    pub window: Option<Window>,
    /// How the boxes of one scale are weighted in the trace moments:
    /// `count` = every box with a valid pixel, by its share of valid pixels
    /// (each valid pixel weighs the same at every scale: the moments of all
    /// scales average over the same region, whatever the holes and
    /// borders); `equal` = the boxes at least half valid, each as a whole
    /// one (the estimator before count weights).
    #[arg(long, value_enum, default_value_t = BoxWeights::Count)]
    pub box_weights: BoxWeights,
    /// How the spectrum (beta, hence H) fills missing pixels before the
    /// FFT: `harmonic` (Laplace's equation inside each hole, its rim as the
    /// boundary: no edge along the rim) or `mean` (the image mean: a step
    /// along every rim, whose power flattens the spectrum; the estimator
    /// before harmonic fills). The flux's fractional derivative always
    /// fills harmonically.
    #[arg(long, value_enum, default_value_t = HoleFill::Harmonic)]
    pub spectrum_fill: HoleFill,
}

impl TmOpts {
    /// The accumulation settings for the trace-moment orders `q`.
    ///
    /// **Errors** naming the flag on a malformed list or an invalid value.
    /// `periodic` fields get the spectrum settings of
    /// [`PowerSpectrumConfig::for_field`] (`--window` overrides the taper)
    /// and the torus flux ([`TraceMomentConfig::periodic`]).
    pub fn config(&self, q: Vec<f64>, periodic: bool) -> Result<TraceMomentConfig> {
        let d = TraceMomentConfig::default();
        let diff = match self.diff_order.trim() {
            "auto" => FluxDiff::Auto,
            "none" => FluxDiff::None,
            v => FluxDiff::Order(v.parse::<f64>().map_err(|_| {
                Error::param(
                    "diff-order",
                    format!("expected auto, none or a number, got {v:?}"),
                )
            })?),
        };
        let cfg = TraceMomentConfig {
            flux: self.flux,
            diff,
            frac_int: self.frac_int,
            q,
            eta: match &self.eta {
                Some(s) => parse_list("eta", s)?,
                None => d.eta,
            },
            dtm_q: parse_q("dtm-q", &self.dtm_q)?,
            sf_q: parse_q("sf-q", &self.sf_q)?,
            spectrum: {
                let s = PowerSpectrumConfig::for_field(periodic);
                PowerSpectrumConfig {
                    window: self.window.unwrap_or(s.window),
                    fill: self.spectrum_fill,
                    ..s
                }
            },
            detrend: crate::field::Trend::None,
            // a torus is filtered (no mirror) and differenced (wrapped) as one
            periodic,
            box_weights: self.box_weights,
        };
        // (the library's checks: --frac-int |order| < 1 among them)
        cfg.validate()?;
        Ok(cfg)
    }

    /// The fit ranges.
    ///
    /// **Errors** naming the flag on a malformed range.
    pub fn fit(&self) -> Result<TraceMomentFitConfig> {
        let opt =
            |flag: &str, s: &Option<String>| s.as_deref().map(|v| parse_range(flag, v)).transpose();
        let fc = TraceMomentFitConfig {
            log2_lambda: opt("lambda-fit", &self.lambda_fit)?,
            eta: parse_range("eta-fit", &self.eta_fit)?,
            log2_lag: opt("lag-fit", &self.lag_fit)?,
            k_range: opt("k-range", &self.k_range)?,
            q_fit_max: self.q_fit_max,
            universal: self.universal_fit.unwrap_or_default(),
        };
        fc.validate()?;
        Ok(fc)
    }
}

#[derive(Args, Debug)]
pub struct TmArgs {
    /// Input images, analysed as one annealed ensemble.
    #[arg(required = true)]
    pub images: Vec<PathBuf>,
    /// Trace-moment orders q >= 0: `start:stop:step` or `a,b,c`.
    #[arg(long, default_value = "0.1:4:0.1", allow_hyphen_values = true)]
    pub q: String,
    #[command(flatten)]
    pub tm: TmOpts,
    /// Trend removed from each image before everything else: `plane`, the
    /// least-squares plane (a DEM's regional slope), which adds `c l` to
    /// every increment at lag l and pulls the structure functions (H_sf,
    /// the automatic --diff-order) toward 1; the spectrum removes a plane of
    /// its own in any case. For tilted surfaces: an untilted rough one
    /// loses part of its own large scales with it (H_sf a little lower).
    #[arg(long, value_enum, default_value_t = crate::field::Trend::None)]
    pub detrend: crate::field::Trend,
    /// The images are periodic (tori, e.g. cascades or simulations with
    /// periodic borders): the spectrum without taper (unless --window) and
    /// with only the mean removed, the flux's fractional derivative on the
    /// torus (no mirror extension) and its gradient wrapped. Automatic for
    /// the files `wtmm synth` wrote from a periodic model (listed in the
    /// synth.json beside them).
    #[arg(long)]
    pub torus: bool,
    /// For one or two images: also draw this many surrogates (universal
    /// multifractal FIF fields with the estimated alpha, C1 and H, the
    /// images' shapes and missing pixels), analyse them the same way, and
    /// report the scatter of their estimates (the error under that model),
    /// the estimator's bias there, and how the tile errors compare
    /// (tm.json `surrogates`, surrogates.csv). K >= 8; 100 or more at low
    /// C1, whose estimates have heavy tails. About K analyses' time.
    #[arg(long, value_name = "K")]
    pub surrogates: Option<usize>,
    /// Seed of the surrogates.
    #[arg(long, default_value_t = 1, requires = "surrogates")]
    pub surrogate_seed: u64,
    #[command(flatten)]
    pub pixel: PixelOpts,
    #[command(flatten)]
    pub read: super::ReadOpts,
    #[command(flatten)]
    pub out: OutDir,
}

/// The fit settings as recorded: `universal` is the weighting the fit
/// used (`universal_fit` of the result starts with it), and
/// `universal_requested` keeps the one asked for (explicitly or by
/// default) when it could not be used (GLS needs 5 jackknife parts).
pub fn fit_record(fc: &TraceMomentFitConfig, used: &str) -> serde_json::Value {
    let mut v = json!(fc);
    let used = if used.starts_with("ols") {
        UniversalWeighting::Ols
    } else {
        UniversalWeighting::Gls
    };
    if used != fc.universal {
        v["universal_requested"] = json!(fc.universal);
        v["universal"] = json!(used);
    }
    v
}

pub fn run(args: TmArgs, quiet: bool) -> Result<Outcome> {
    let q = parse_q("q", &args.q)?;
    let nodata = args.read.value()?;
    let (px, px_warnings) = args.pixel.resolve(&args.images)?;
    // the fit settings first, so that a bad --q-fit-max is named as such
    let mut fc = args.tm.fit()?;
    // files `synth` wrote from a periodic model: the settings compare takes
    // for the model (spectrum: no taper, only the mean removed; flux: its
    // derivative and gradient on the torus)
    let origin = match args.detrend {
        _ if args.torus => None,
        crate::field::Trend::None => super::common::periodic_synth(
            &args.images,
            Some(match args.tm.window {
                None => {
                    "their power spectrum tapered and a plane removed, and the flux's derivative \
                     taken on a mirror extension"
                }
                Some(_) => {
                    "a plane removed from their power spectrum, and the flux's derivative taken \
                     on a mirror extension"
                }
            }),
            false,
        ),
        _ => None,
    };
    let cfg = TraceMomentConfig {
        detrend: args.detrend,
        ..args.tm.config(q, args.torus || origin.is_some())?
    };
    // before any image is read: the library refuses --torus with
    // --detrend plane (a sawtooth across the torus's edges)
    cfg.validate()?;
    if let Some(o) = &origin {
        say!(
            "note: {}: the spectrum (H from beta) with window {} and only the mean removed, and \
             the fractional derivative and the gradient of the flux taken on the torus (no \
             mirror extension; the last row's neighbour is the first), as compare takes the \
             model's (a torus needs no taper, and a plane removed from it is a sawtooth across \
             its edges); --window to choose the taper",
            o.describe(args.images.len()),
            format!("{:?}", cfg.spectrum.window).to_lowercase()
        );
    }
    // fewer than 3 images: a jackknife over the images has 1 degree of
    // freedom at most, so it runs over the tiles of every image, as in
    // `analyze` (tracemoments::pool_tiles)
    let tiled = args.images.len() < 3;
    if let Some(k) = args.surrogates {
        if !tiled {
            return Err(Error::param(
                "surrogates",
                "is for one or two images, whose errors come from tiles; an ensemble's \
                 jackknife over its images already measures the scatter between fields",
            ));
        }
        check_surrogate_count(k)?;
    }
    if tiled {
        // tiles are not independent samples for the covariance
        fc.universal = args
            .tm
            .universal_fit
            .unwrap_or(TraceMomentFitConfig::for_tiles().universal);
    }
    let mut surrogate_failure = None;
    // what the fit selectors select, from the files' headers
    let sizes = args
        .images
        .iter()
        .map(crate::io::read_shape)
        .collect::<Result<Vec<_>>>()?;
    crate::tracemoments::check_fit_selectors(&cfg, &fc, &sizes)?;
    if tiled {
        // one or two images are held whole, with their tiles' sums
        let px = sizes.iter().map(|[ny, nx]| ny * nx).sum();
        if let Some((p, [ny, nx])) = args
            .images
            .iter()
            .zip(&sizes)
            .max_by_key(|(_, [ny, nx])| ny * nx)
        {
            super::common::check_tm_memory((p, *ny, *nx), px)?;
        }
    }
    let (acc, res, shapes) = if tiled {
        let fields = args
            .images
            .iter()
            .map(|p| super::common::read_image(p, nodata))
            .collect::<Result<Vec<_>>>()?;
        // tiles of the largest fitted box (log2 λ = lo) of the ensemble
        let (whole, res) = analyze_tiled(&fields, &cfg, &fc).map_err(|e| {
            // a parameter (a fit range) is no image's fault
            if matches!(e, Error::Param { .. }) {
                return e;
            }
            // name the image at fault when one is
            let side = fields.iter().map(|f| f.dim().0.min(f.dim().1)).max();
            let tile = tile_side(side.unwrap_or(1), &fc);
            fields
                .iter()
                .zip(&args.images)
                .find_map(|(f, p)| {
                    TraceMomentAccumulator::field_tiles(&cfg, f, tile)
                        .err()
                        .map(|e| super::common::in_file(p, e))
                })
                .unwrap_or(e)
        })?;
        let shapes = fields
            .iter()
            .map(|f| ImageInfo::of(f, &cfg.spectrum))
            .collect();
        let mut res = res;
        if let Some(k) = args.surrogates {
            // the data's result stands when no model can be drawn from it
            // (no universal fit, no spectral H) or the draws do not fit in
            // memory: said, as a GLS fallback is
            match draw_surrogates(&fields, &res, &cfg, &fc, k, args.surrogate_seed, quiet) {
                Ok(s) => res.surrogates = Some(s),
                Err(Error::Input(why)) => surrogate_failure = Some(why),
                Err(e) => surrogate_failure = Some(e.to_string()),
            }
        }
        (whole, res, shapes)
    } else {
        // a fit the sizes rule out is said before every image is read
        check_ensemble_fit(&fc, &sizes)?;
        // one image per worker: as many workers as the memory holds images
        let limit = super::common::memory_workers(
            &args.images,
            &sizes,
            super::common::TM_ENSEMBLE_BYTES_PER_PIXEL,
            "the trace moments",
        )?;
        let (parts, shapes) = accumulate_paths(&args.images, nodata, &cfg, quiet, limit)?;
        let (acc, res) = finish_ensemble(&parts, &fc)?;
        (acc, res, shapes)
    };
    // the flux skips missing pixels; the spectrum (beta, H) sees them filled
    // (harmonically by default)
    let missing: Vec<usize> = shapes.iter().map(|s| s.missing).collect();
    let hole_share: Vec<f64> = shapes
        .iter()
        .map(|s| s.largest_hole as f64 / (s.shape[0] * s.shape[1]) as f64)
        .collect();
    let quant: Vec<Option<f64>> = shapes.iter().map(|s| s.equal).collect();
    let flats: Vec<Option<(f64, f64)>> = shapes.iter().map(|s| s.flat).collect();
    let shapes: Vec<[usize; 2]> = shapes.iter().map(|s| s.shape).collect();
    let mut extra = Vec::new();
    // as the other commands: jackknife errors over few images (or tiles of
    // one image) are rough, and say by how much (for tiles the library
    // says it: tracemoments::analyze_tiled)
    if !tiled {
        let n = res.jackknife_groups;
        extra.extend(crate::stats::fit::few_groups_warning(
            n,
            &format!("a jackknife over {n} images"),
        ));
    }
    // TM §5.2: the zero gradients of a quantised DEM; --frac-int is the cure
    if cfg.frac_int.is_none() {
        for ((q, p), flat) in quant.iter().zip(&args.images).zip(&flats) {
            if let Some(eq) = q.filter(|&eq| eq > 0.01) {
                // the flat value's pairs are left out (a warning of their own)
                let off = flat.map_or(String::new(), |(v, _)| {
                    format!(" off the flat value {}", crate::error::short(v))
                });
                extra.push(format!(
                    "{}: {:.0} % of neighbouring pixels{off} are equal: quantised values (a DEM \
                     in whole metres, say), whose zero gradients bias the flux's low moments \
                     (TM §5.2); --frac-int (order 0.1) smooths them (README: Jacksboro's alpha \
                     1.49 -> 1.43)",
                    p.display(),
                    100.0 * eq
                ));
            }
        }
    }
    // a flat area has a flux of about 0, which the coarse-grained moments
    // read as intermittency (README, Conventions: "Flat areas")
    for (f, p) in flats.iter().zip(&args.images) {
        if let Some((v, share)) = f.filter(|f| f.1 > crate::field::FLAT_SHARE_WARN) {
            extra.push(format!(
                "{}: one value, {}, fills {:.0} % of the valid pixels: a flat area (a sea or a \
                 lake at one level, a fill, a nodata value the file does not declare), whose \
                 flux is about 0 and which the moments read as intermittency (alpha and C1 move: \
                 README, Conventions); if it is no data, give it as missing (--nodata {}, NaN, \
                 or the file's nodata value)",
                p.display(),
                crate::error::short(v),
                100.0 * share,
                crate::error::exact(v)
            ));
        }
    }
    for ((n, p), share) in missing.iter().zip(&args.images).zip(&hole_share) {
        if *n > 0 {
            extra.push(format!(
                "{}: {n} missing pixels: left out of the flux (filled harmonically before a \
                 fractional derivative), filled {} for the spectrum (beta, H){}",
                p.display(),
                match cfg.spectrum.fill {
                    HoleFill::Harmonic => "harmonically",
                    HoleFill::Mean => "with the image mean (--spectrum-fill mean)",
                },
                crate::stats::powspec::large_hole_warning(*share)
                    .map(|w| format!("; {w}"))
                    .unwrap_or_default()
            ));
        }
    }
    // an explicit request that could not be honoured is said, not only
    // recorded in tm.json
    if args.tm.universal_fit == Some(UniversalWeighting::Gls)
        && res.universal_fit.starts_with("ols")
    {
        extra.push(format!(
            "--universal-fit gls was not possible; the universal fit is {}",
            res.universal_fit
        ));
    }
    extra.extend(
        px.as_ref()
            .and_then(|p| p.warning(super::Isotropic::BoxesAndSpectrum)),
    );
    extra.extend(px_warnings);
    PixelSize::say_note(px.as_ref(), quiet);
    if let Some(why) = surrogate_failure {
        extra.push(format!("--surrogates: none drawn: {why}"));
    }
    if let Some(sg) = &res.surrogates {
        extra.extend(sg.warnings.iter().map(|w| format!("surrogates: {w}")));
    }
    make_out_dir(&args.out.out)?;
    // box levels are in pixels: images of several sizes weigh by their area
    let shapes = crate::spectra::ShapeCount::tally(shapes);
    let what = super::common::data_label(&args.images, args.images.len(), &shapes)
        + super::common::trend_label(args.detrend);
    let params = json!({"images": super::common::paths_json(&args.images), "image_shapes": shapes, "missing_pixels": missing,
        "flat": flats.iter().map(|f| f.map(|(value, share)| json!({"value": value, "share": share}))).collect::<Vec<_>>(),
        "config": cfg, "fit": fit_record(&fc, &res.universal_fit),
        "plane_shares": acc.planes.iter().map(|p| p.share).collect::<Vec<_>>(),
        "origin": origin.as_ref().map(super::common::PeriodicSynth::json),
        "pixel_size": px.as_ref().map(PixelSize::json), "nodata": nodata});
    write_outputs(
        &args.out.out,
        "tm",
        params,
        &res,
        acc.spectrum.as_ref(),
        &extra,
        &what,
    )?;
    show!("{}", summary(&res));
    if let Some(p) = &px {
        show!("{}\n", lengths_line(&res, p));
    }
    for w in res.warnings.iter().chain(&extra) {
        say!("warning: {w}");
    }
    Ok(Outcome::Ok)
}

/// Peak memory of one surrogate draw in flight, per pixel of the data: the
/// FIF generation and the trace moments of its tiles (peak RSS of `tm` on
/// 1024^2 with 8 surrogates: +169 MB on one thread, +414 MB on two; 2026-11-29,
/// since the tiles are accumulated in one pass, which holds every tile's
/// boxes at once, and beside the whole image: +56 and +197 MB before).
const SURROGATE_BYTES_PER_PIXEL: f64 = 200.0;

/// [`surrogate_errors_with_progress`] with a progress bar, on as many
/// threads as the available memory holds draws (the same bytes on any
/// thread count).
fn draw_surrogates(
    fields: &[crate::Field],
    res: &TraceMomentResult,
    cfg: &TraceMomentConfig,
    fc: &TraceMomentFitConfig,
    count: usize,
    seed: u64,
    quiet: bool,
) -> Result<SurrogateErrors> {
    let px: usize = fields.iter().map(|f| f.dim().0 * f.dim().1).sum();
    let one = SURROGATE_BYTES_PER_PIXEL * px as f64;
    let threads = rayon::current_num_threads().max(1);
    let fit = available_memory().map_or(threads, |avail| (avail / one).floor() as usize);
    if fit == 0 {
        return Err(Error::Input(format!(
            "one draw needs about {:.1} GB of memory, more than is available",
            one / 1e9
        )));
    }
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(fit.min(threads))
        .build()
        .map_err(|e| Error::Input(format!("cannot start the surrogate threads: {e}")))?;
    let pb = progress(count as u64, "surrogates", quiet);
    let out = pool.install(|| {
        surrogate_errors_with_progress(fields, res, cfg, fc, count, seed, &|| pb.inc(1))
    });
    pb.finish_and_clear();
    out
}

/// What the warnings of `tm` need to know of an image.
pub struct ImageInfo {
    /// `[ny, nx]`.
    shape: [usize; 2],
    /// Missing pixels.
    missing: usize,
    /// The largest hole's pixels.
    largest_hole: usize,
    /// On a lattice of values, the fraction of equal neighbours
    /// ([`quantised`]).
    equal: Option<f64>,
    /// The value filling flat areas and its share of the valid pixels
    /// ([`crate::Field::flat_value`]).
    flat: Option<(f64, f64)>,
}

impl ImageInfo {
    /// `f`'s record, its largest hole as the spectrum of `cfg` fills it.
    fn of(f: &crate::Field, cfg: &PowerSpectrumConfig) -> Self {
        let (ny, nx) = f.dim();
        let flat = f.flat_value();
        ImageInfo {
            shape: [ny, nx],
            missing: ny * nx - f.valid_count(),
            largest_hole: crate::stats::powspec::largest_filled_hole(f, cfg),
            equal: quantised(f, flat.map(|(v, _)| v)),
            flat,
        }
    }
}

/// For a field whose valid values lie on a lattice `v0 + k δ` (a DEM in
/// whole metres, or in any other unit: [`lattice_step`]), the fraction of
/// valid neighbour pairs, along rows and columns, that are equal: there
/// the gradient flux is exactly 0 (TM §5.2). Pairs touching the `flat`
/// value (a sea: [`crate::Field::flat_value`]) are left out, since no
/// fractional integration mends those (a warning of their own). Until
/// 2026-11-29 the lattice had to be the integers (the same DEM in
/// kilometres, or a 16-bit PNG decoded through its sidecar's scale, went
/// unnamed) and only the rows were counted (a field with equal
/// neighbours down its columns was named only when transposed). Equal
/// neighbours off a lattice are flat areas (lakes at several levels of a
/// float DEM: Levi Fell's 2 % of equal pairs lie at a few levels), which
/// `--frac-int` does not mend either.
fn quantised(f: &crate::Field, flat: Option<f64>) -> Option<f64> {
    let (pr, er) = f.equal_pairs(ndarray::Axis(1), flat);
    let (pc, ec) = f.equal_pairs(ndarray::Axis(0), flat);
    let (pairs, equal) = (pr + pc, er + ec);
    // the lattice (a sort of the values) only when some pair is equal: a
    // continuous field skips it (1.3 s of tm's 20 s on a 2048^2 field)
    if equal > 0 {
        lattice_step(f)?;
    }
    (pairs > 0).then(|| equal as f64 / pairs as f64)
}

/// The step `δ` of the lattice `v0 + k δ` that holds every valid value,
/// to within a thousandth of a step (the rounding of a scale applied in
/// f64), or `None` (fewer than 2 distinct values, or values off any
/// lattice: a continuous field). `δ` is the range over the whole number
/// of smallest gaps it holds, so that its own rounding does not grow
/// with `k`.
fn lattice_step(f: &crate::Field) -> Option<f64> {
    let mut v: Vec<f64> = f.data.iter().copied().filter(|x| x.is_finite()).collect();
    v.sort_by(f64::total_cmp);
    v.dedup();
    let (lo, hi) = (*v.first()?, *v.last()?);
    let gap = v
        .windows(2)
        .map(|w| w[1] - w[0])
        .fold(f64::INFINITY, f64::min);
    if !(gap > 0.0 && gap.is_finite()) {
        return None;
    }
    let steps = ((hi - lo) / gap).round();
    if !(1.0..1e9).contains(&steps) {
        return None;
    }
    let step = (hi - lo) / steps;
    v.iter()
        .all(|&x| {
            let k = (x - lo) / step;
            (k - k.round()).abs() < 1e-3
        })
        .then_some(step)
}

/// Reads and accumulates every image (in parallel), one accumulator per
/// image in input order (for the jackknife of [`finish_ensemble`]), with
/// the images' sizes `[ny, nx]` and missing-pixel counts; a bad file stops
/// everything before any output is written. `limit`: at most that many
/// images in flight ([`super::common::memory_workers`]).
pub fn accumulate_paths(
    paths: &[PathBuf],
    nodata: Option<f64>,
    cfg: &TraceMomentConfig,
    quiet: bool,
    limit: Option<usize>,
) -> Result<(Vec<TraceMomentAccumulator>, Vec<ImageInfo>)> {
    let pb = progress(paths.len() as u64, "tm", quiet);
    let notes = super::common::OrderedNotes::default();
    let parts = crate::par::try_map_at_limited(paths.len(), limit, |i| {
        let p = &paths[i];
        let field = super::common::read_image_noted(p, nodata, i, &notes)?;
        let mut acc = TraceMomentAccumulator::new(cfg.clone())?;
        acc.add_field(&field)
            .map_err(|e| super::common::in_file(p, e))?;
        pb.inc(1);
        Ok((acc, ImageInfo::of(&field, &cfg.spectrum)))
    });
    pb.finish_and_clear();
    notes.say_upto(parts.as_ref().err().map(|f| f.0));
    Ok(parts.map_err(|f| f.1)?.into_iter().unzip())
}

/// `τ(q) = qH - K(q) - 2` from the measured K(q) and the spectral H (NaN
/// without H).
pub fn tau_from_tm(res: &TraceMomentResult) -> Vec<f64> {
    let h = res.h.unwrap_or(f64::NAN);
    res.q
        .iter()
        .zip(&res.k)
        .map(|(&q, &k)| q * h - k - 2.0)
        .collect()
}

/// The fitted universal K(q) on the grid `q`.
pub fn k_universal(res: &TraceMomentResult, q: &[f64]) -> Vec<f64> {
    q.iter()
        .map(|&v| res.c1 * universal_shape(res.alpha, v))
        .collect()
}

/// Human summary (also the first lines of the report).
pub fn summary(r: &TraceMomentResult) -> String {
    let o = |v: Option<f64>| v.map_or("n/a".to_string(), |x| format!("{x:.4}"));
    let pm = |v: Option<f64>, e: Option<f64>| match (v, e) {
        (Some(v), Some(e)) => format!("{v:.4} +- {e:.4}"),
        (v, _) => o(v),
    };
    let diff = match r.diff {
        FluxDiff::None => String::new(),
        FluxDiff::Auto if r.images > 1 => format!(
            " after differentiation of order xi(1) = {:.3} (mean; sd {:.3} over images)",
            r.diff_order, r.diff_order_sd
        ),
        FluxDiff::Auto => format!(
            " after differentiation of order xi(1) = {:.3}",
            r.diff_order
        ),
        FluxDiff::Order(d) => format!(" after differentiation of order {d}"),
    };
    let mut out = format!(
        "trace moments: {} image(s){}, flux |{}|{}{}, fit log2 lambda {}:{}\n  \
         alpha {:.3} +- {:.3}, C1 {:.4} +- {:.4} ({} universal fit over 0 < q <= {:.2}; q_s {:.2})\n  \
         DTM (q = {}): alpha {:.3} +- {:.3}, C1 {:.4} +- {:.4}\n  \
         beta {} (angle-integrated; se: {}), H {} (spectrum), H_sf {} (structure functions)\n  \
         errors: {} (fit-only: alpha +- {:.3}, C1 +- {:.4})\n",
        r.images,
        super::common::trend_label(r.detrend),
        r.flux.name(),
        diff,
        r.frac_int
            .map_or(String::new(), |h| format!(", fractional integration {h}")),
        r.fit_log2_lambda.0,
        r.fit_log2_lambda.1,
        r.alpha,
        r.alpha_stderr,
        r.c1,
        r.c1_stderr,
        r.universal_fit.split_whitespace().next().unwrap_or("ols"),
        r.universal_q_max,
        r.q_s,
        r.dtm_q.first().copied().unwrap_or(f64::NAN),
        r.dtm_alpha,
        r.dtm_alpha_stderr,
        r.dtm_c1,
        r.dtm_c1_stderr,
        pm(r.beta, r.beta_stderr),
        if r.beta_stderr_method.is_empty() {
            "?"
        } else {
            &r.beta_stderr_method
        },
        pm(r.h, r.h_stderr),
        pm(r.h_sf, r.h_sf_stderr),
        r.stderr_method,
        r.alpha_stderr_fit,
        r.c1_stderr_fit,
    );
    if let Some(s) = &r.surrogates {
        out += &format!(
            "  surrogates ({} of {} FIF draws with alpha {:.3}, C1 {:.4}, H {:.3}; seed {}):\n",
            s.used, s.count, s.params.alpha, s.params.c1, s.params.hurst, s.seed
        );
        for (name, st) in [("alpha", &s.alpha), ("C1", &s.c1), ("H", &s.h)] {
            out += &format!(
                "    {name}: error {:.4} (the surrogates' sd; half their central 68 %: {:.4}; \
                 95 % in [{:.4}, {:.4}]), bias {:+.4} +- {:.4}; their tile errors are {:.2} of \
                 the sd\n",
                st.sd,
                (st.quantiles[2] - st.quantiles[1]) / 2.0,
                st.quantiles[0],
                st.quantiles[3],
                st.bias,
                st.bias_stderr,
                st.stderr_ratio
            );
        }
    }
    out
}

/// The `tm.json` body: the header, every key of [`TraceMomentResult`], and
/// the derived `tau` and `K_universal`.
pub fn result_json(
    command: &str,
    params: serde_json::Value,
    res: &TraceMomentResult,
    extra_warnings: &[String],
) -> Result<serde_json::Value> {
    let mut body = header(command, params);
    let r = serde_json::to_value(res).map_err(|e| Error::Input(e.to_string()))?;
    if let (Some(obj), serde_json::Value::Object(m)) = (body.as_object_mut(), r) {
        for (k, v) in m {
            obj.insert(k, v);
        }
    }
    // the library's diagnostics (the range checks among them), then the
    // command's
    let mut warnings = res.warnings.clone();
    warnings.extend_from_slice(extra_warnings);
    body["warnings"] = json!(warnings);
    body["K_universal"] = json!(k_universal(res, &res.q));
    body["tau"] = json!(tau_from_tm(res));
    body["tau_definition"] =
        json!("tau(q) = q H - K(q) - 2 (measured K, spectral H; WTMM convention for a surface)");
    Ok(body)
}

/// Writes tm.json, the CSVs and the plots.
pub fn write_outputs(
    dir: &Path,
    command: &str,
    params: serde_json::Value,
    res: &TraceMomentResult,
    spectrum: Option<&PowerSpectrum>,
    extra_warnings: &[String],
    what: &str,
) -> Result<()> {
    // the pixel, when given (params.pixel_size): the fit ranges as lengths
    let px = super::params_pixel(&params);
    let mut body = result_json(command, params, res, extra_warnings)?;
    if let Some((side, units)) = &px {
        body["lengths"] = lengths_json(res, *side, units);
    }
    write_json(&dir.join("tm.json"), &body)?;
    if let Some(sg) = &res.surrogates {
        let rows: Vec<Vec<String>> = sg
            .runs
            .iter()
            .map(|r| {
                std::iter::once(r.index.to_string())
                    .chain(
                        [r.alpha, r.alpha_stderr, r.c1, r.c1_stderr, r.h, r.h_stderr]
                            .iter()
                            .map(|v| f(*v)),
                    )
                    .collect()
            })
            .collect();
        write_csv(
            &dir.join("surrogates.csv"),
            &[
                "draw",
                "alpha",
                "alpha_stderr",
                "C1",
                "C1_stderr",
                "H",
                "H_stderr",
            ],
            &rows,
        )?;
    }
    write_csv(
        &dir.join("estimates.csv"),
        &[
            "quantity",
            "method",
            "value",
            "stderr",
            "stderr_method",
            "stderr_surrogates",
            "range",
        ],
        &estimate_rows(res),
    )?;
    let ku = k_universal(res, &res.q);
    let tau = tau_from_tm(res);
    let rows: Vec<Vec<String>> = (0..res.q.len())
        .map(|i| {
            vec![
                f(res.q[i]),
                f(res.k[i]),
                f(res.k_stderr[i]),
                f(res.k_intercept[i]),
                f(ku[i]),
                f(tau[i]),
            ]
        })
        .collect();
    write_csv(
        &dir.join("K.csv"),
        &["q", "K", "K_stderr", "K_intercept", "K_universal", "tau"],
        &rows,
    )?;
    // moments per level
    let mut hdr = vec!["q".to_string()];
    hdr.extend(res.log2_lambda.iter().map(|l| format!("log2lambda={l}")));
    let hdr_ref: Vec<&str> = hdr.iter().map(String::as_str).collect();
    let rows: Vec<Vec<String>> = res
        .q
        .iter()
        .zip(&res.log2_moments)
        .map(|(q, m)| {
            std::iter::once(f(*q))
                .chain(m.iter().map(|v| f(*v)))
                .collect()
        })
        .collect();
    write_csv(&dir.join("moments.csv"), &hdr_ref, &rows)?;
    // double trace moments
    let mut hdr = vec!["eta".to_string()];
    for q in &res.dtm_q {
        hdr.push(format!("K_eta(q={q})"));
        hdr.push(format!("K_eta(q={q})_stderr"));
    }
    let hdr_ref: Vec<&str> = hdr.iter().map(String::as_str).collect();
    let rows: Vec<Vec<String>> = (0..res.eta.len())
        .map(|ie| {
            let mut r = vec![f(res.eta[ie])];
            for iq in 0..res.dtm_q.len() {
                r.push(f(res.k_eta[iq][ie]));
                r.push(f(res.k_eta_stderr[iq][ie]));
            }
            r
        })
        .collect();
    write_csv(&dir.join("dtm.csv"), &hdr_ref, &rows)?;
    // structure functions
    let h = res.h.unwrap_or(f64::NAN);
    let rows: Vec<Vec<String>> = (0..res.sf_q.len())
        .map(|i| {
            let q = res.sf_q[i];
            vec![
                f(q),
                f(res.xi[i]),
                f(res.xi_stderr[i]),
                f(q * h - res.c1 * universal_shape(res.alpha, q)),
            ]
        })
        .collect();
    write_csv(
        &dir.join("sf.csv"),
        &["q", "xi", "xi_stderr", "xi_universal"],
        &rows,
    )?;
    if let Some(ps) = spectrum {
        let rows: Vec<Vec<String>> = ps.points().iter().map(|&(k, s)| vec![f(k), f(s)]).collect();
        write_csv(
            &dir.join("spectrum.csv"),
            &["k_rad_per_px", "S_angle_averaged"],
            &rows,
        )?;
    }
    plot_moments(dir, res, what)?;
    plot_k(dir, res, None, what)?;
    plot_dtm(dir, res, what)?;
    let px = px.as_ref().map(|(side, units)| (*side, units.as_str()));
    plot_sf(dir, res, what, px)?;
    if let Some(ps) = spectrum {
        plot_spectrum(dir, res, ps, what, px)?;
    }
    Ok(())
}

/// The fit ranges as box sizes, lags and wavelengths in px: `(lo, hi)`.
/// Boxes: `l = L / λ` with `log2 L` the largest `log2 λ` (the 1-px boxes).
fn fit_px(r: &TraceMomentResult) -> [(&'static str, (f64, f64)); 4] {
    let top = r.log2_lambda.iter().copied().fold(0.0, f64::max);
    let (lo, hi) = r.fit_log2_lambda;
    let two_pi = 2.0 * std::f64::consts::PI;
    let k = r.k_range.unwrap_or((f64::NAN, f64::NAN));
    [
        ("trace_moment_boxes", ((top - hi).exp2(), (top - lo).exp2())),
        (
            "structure_function_lags",
            (r.fit_log2_lag.0.exp2(), r.fit_log2_lag.1.exp2()),
        ),
        ("spectrum_wavelengths", (two_pi / k.1, two_pi / k.0)),
        ("outer_scale", (r.outer_scale_px, r.outer_scale_px)),
    ]
}

/// tm.json `lengths`: the fit ranges of [`fit_px`] times the pixel's side.
fn lengths_json(r: &TraceMomentResult, side: f64, units: &str) -> serde_json::Value {
    let mut v = json!({"units": units});
    for (name, (a, b)) in fit_px(r) {
        v[name] = if name == "outer_scale" {
            json!(a * side)
        } else {
            json!([a * side, b * side])
        };
    }
    v
}

/// The stdout line of the fit ranges as lengths.
fn lengths_line(r: &TraceMomentResult, p: &PixelSize) -> String {
    let [boxes, lags, waves, outer] = fit_px(r);
    let range = |(a, b): (f64, f64)| format!("{} - {}", p.length(a), p.length(b));
    format!(
        "  lengths: boxes {} (trace moments), lags {} (structure functions), wavelengths {} \
         (spectrum), outer scale {}",
        range(boxes.1),
        range(lags.1),
        range(waves.1),
        p.length(outer.1.0)
    )
}

/// The rows of `estimates.csv`: each exponent by each method, side by side
/// with its error and the range it was fitted over (alpha and C1 by trace
/// and double trace moments, H by the spectrum and by the structure
/// functions, beta). Each row's `stderr_method` says what its `stderr` is
/// (the jackknife of tm.json's `stderr_method`, or a regression's);
/// `stderr_surrogates` is the surrogates' sd where measured; the DTM range
/// is the eta its first fit used.
fn estimate_rows(r: &TraceMomentResult) -> Vec<Vec<String>> {
    let opt = |v: Option<f64>| v.map_or(String::new(), f);
    let sur = r.surrogates.as_ref();
    let lam = format!(
        "log2 lambda {}:{}",
        r.fit_log2_lambda.0, r.fit_log2_lambda.1
    );
    // the eta the first DTM fit used (q eta <= q_s/2 may cut the top)
    let eta = r.dtm.first().map_or_else(
        || format!("eta {}:{}", f(r.dtm_eta_range.0), f(r.dtm_eta_range.1)),
        |d| format!("eta {:.3}:{:.3}", d.eta_used.0, d.eta_used.1),
    );
    let k = r
        .k_range
        .map_or(String::new(), |(a, b)| format!("k {a:.4}:{b:.4} rad/px"));
    let lag = format!("log2 l {}:{} px", r.fit_log2_lag.0, r.fit_log2_lag.1);
    let tm = format!(
        "trace moments, universal fit over 0 < q <= {:.2}",
        r.universal_q_max
    );
    let dtm = format!(
        "double trace moments, q = {}",
        r.dtm_q.first().copied().unwrap_or(f64::NAN)
    );
    // which error each row has: the jackknife's (stderr_method), except
    // beta on the tiles of one image, which share its spectrum and keep the
    // fit's error, and H from it, which then adds half of that
    let jk = r.jackknife_groups >= 2;
    let method = |jackknifed: bool| {
        if jackknifed {
            r.stderr_method.clone()
        } else {
            "regression".to_string()
        }
    };
    let beta_method = r.beta_stderr_method.clone();
    // H = (beta - 1 + K(2))/2: the jackknife's, plus half beta's fit error
    // where the parts share one spectrum (beta then keeps its fit error)
    let h_method = match (jk, beta_method == r.stderr_method) {
        (true, false) => format!(
            "{}, with half the spectrum fit's error of beta",
            r.stderr_method
        ),
        (true, true) => r.stderr_method.clone(),
        (false, _) => "regression".to_string(),
    };
    vec![
        vec![
            "alpha".into(),
            tm.clone(),
            f(r.alpha),
            f(r.alpha_stderr),
            method(jk),
            opt(sur.map(|s| s.alpha.sd)),
            lam.clone(),
        ],
        vec![
            "C1".into(),
            tm,
            f(r.c1),
            f(r.c1_stderr),
            method(jk),
            opt(sur.map(|s| s.c1.sd)),
            lam,
        ],
        vec![
            "alpha".into(),
            dtm.clone(),
            f(r.dtm_alpha),
            f(r.dtm_alpha_stderr),
            method(jk),
            String::new(),
            eta.clone(),
        ],
        vec![
            "C1".into(),
            dtm,
            f(r.dtm_c1),
            f(r.dtm_c1_stderr),
            if jk { method(true) } else { String::new() },
            String::new(),
            eta,
        ],
        vec![
            "H".into(),
            "spectrum, (beta - 1 + K(2))/2".into(),
            opt(r.h),
            opt(r.h_stderr),
            h_method,
            opt(sur.map(|s| s.h.sd)),
            k.clone(),
        ],
        vec![
            "H".into(),
            "structure functions, xi(1)".into(),
            opt(r.h_sf),
            opt(r.h_sf_stderr),
            if r.h_sf_stderr.is_some() {
                method(jk)
            } else {
                String::new()
            },
            String::new(),
            lag,
        ],
        vec![
            "beta".into(),
            "spectrum, angle-integrated".into(),
            opt(r.beta),
            opt(r.beta_stderr),
            beta_method,
            String::new(),
            k,
        ],
    ]
}

const LOG10_2: f64 = std::f64::consts::LOG10_2;

/// The orders shown in TM Figs 19, 25-26 (top to bottom 2.18 ... 0.04),
/// plus 3, snapped to the grid.
fn shown_q(q: &[f64]) -> Vec<usize> {
    let mut v: Vec<usize> = [0.04, 0.12, 0.51, 1.17, 1.44, 1.77, 2.18, 3.0]
        .iter()
        .filter_map(|&t: &f64| {
            (0..q.len()).min_by(|&a, &b| (q[a] - t).abs().total_cmp(&(q[b] - t).abs()))
        })
        .collect();
    v.sort_unstable();
    v.dedup();
    v
}

/// The points `(x scale, y scale)` split into those whose `x` passes
/// `inside` and the others (each drawn as its own series).
fn split_by(
    x: &[f64],
    y: &[f64],
    scale: f64,
    inside: impl Fn(f64) -> bool,
) -> [Vec<(f64, f64)>; 2] {
    let mut out = [Vec::new(), Vec::new()];
    for (&a, &b) in x.iter().zip(y) {
        out[usize::from(!inside(a))].push((a * scale, b * scale));
    }
    out
}

/// Seed 000 Figs 19, 25: `log10 <φ_λ^q>` against `log10 λ` with the fitted
/// lines, extended to their common crossing λ_eff (the effective outer scale).
fn plot_moments(dir: &Path, r: &TraceMomentResult, what: &str) -> Result<()> {
    let mut c = Chart {
        title: format!(
            "trace moments, fit λ = 2^{}..2^{}: {what}",
            r.fit_log2_lambda.0, r.fit_log2_lambda.1
        ),
        x_label: "log10 λ  (λ = L / l; open: scales outside the fit)".into(),
        y_label: "log10 <φ_λ^q>".into(),
        ..Default::default()
    };
    let x_max = r.log2_lambda.iter().copied().fold(0.0, f64::max) * LOG10_2;
    let x_eff = r.log2_lambda_eff * LOG10_2;
    let x_lo = if x_eff.is_finite() {
        x_eff.clamp(-x_max, 0.0)
    } else {
        0.0
    };
    // the scales fitted filled, the others open
    let (flo, fhi) = r.fit_log2_lambda;
    let fitted = |x: f64| x >= flo - 1e-9 && x <= fhi + 1e-9;
    for (n, &i) in shown_q(&r.q).iter().enumerate() {
        let [inside, outside] = split_by(&r.log2_lambda, &r.log2_moments[i], LOG10_2, fitted);
        c.series.push(Series::new(
            format!("q = {:.2}, K = {:.3}", r.q[i], r.k[i]),
            inside,
            Style::Markers,
            n,
        ));
        c.series
            .push(Series::new("", outside, Style::OpenMarkers, n));
        let (k, b) = (r.k[i], r.k_intercept[i] * LOG10_2);
        if k.is_finite() && b.is_finite() {
            c.series.push(Series::new(
                "",
                vec![(x_lo, b + k * x_lo), (x_max, b + k * x_max)],
                Style::Line,
                n,
            ));
        }
    }
    save_chart(&c, &dir.join("moments.png"))
}

/// Seed 000 Figs 20, 27-28: K(q) with the universal fit, the fit range and
/// q_s. `theory`: an optional (name, K(q)) curve on the same grid.
pub fn plot_k(
    dir: &Path,
    r: &TraceMomentResult,
    theory: Option<(&str, &[f64])>,
    what: &str,
) -> Result<()> {
    let mut c = Chart {
        title: format!(
            "K(q): alpha = {}, C1 = {} (fit q <= {:.2}), q_s = {:.2}: {what}",
            plus_minus(r.alpha, r.alpha_stderr, 2),
            plus_minus(r.c1, r.c1_stderr, 3),
            r.universal_q_max,
            r.q_s
        ),
        x_label: "q".into(),
        y_label: "K(q)".into(),
        ..Default::default()
    };
    c.series.push(
        Series::new(
            "K(q), trace moments",
            r.q.iter().copied().zip(r.k.iter().copied()).collect(),
            Style::Markers,
            0,
        )
        .with_errors(r.k_stderr.clone()),
    );
    let q_hi = r.q.iter().copied().fold(0.0, f64::max);
    let grid: Vec<f64> = (0..=200).map(|i| q_hi * i as f64 / 200.0).collect();
    if r.alpha.is_finite() {
        c.series.push(Series::new(
            "universal fit",
            grid.iter().copied().zip(k_universal(r, &grid)).collect(),
            Style::Line,
            1,
        ));
    }
    if let Some((name, k)) = theory {
        c.series.push(Series::new(
            name,
            r.q.iter().copied().zip(k.iter().copied()).collect(),
            Style::Dashed,
            2,
        ));
    }
    let ys: Vec<f64> = r.k.iter().copied().filter(|v| v.is_finite()).collect();
    let (y0, y1) = (
        ys.iter().copied().fold(0.0, f64::min),
        ys.iter().copied().fold(0.0, f64::max),
    );
    for (x, name, col) in [(r.universal_q_max, "fit limit", 3), (r.q_s, "q_s", 4)] {
        if x.is_finite() && x <= q_hi {
            c.series.push(Series::new(
                format!("{name} = {x:.2}"),
                vec![(x, y0), (x, y1)],
                Style::Dashed,
                col,
            ));
        }
    }
    save_chart(&c, &dir.join("K.png"))
}

/// Double trace moments: `log10 |K(q, η)|` against `log10 η` with the
/// fitted line of slope α over the η fit range (K(q, η) < 0 for q < 1: the
/// fit takes |K| there, and so does the plot; values of the other sign are
/// noise and left out, as in the fit).
fn plot_dtm(dir: &Path, r: &TraceMomentResult, what: &str) -> Result<()> {
    let mut c = Chart {
        title: format!(
            "double trace moments{}: alpha = {}, C1 = {:.3}: {what}",
            r.dtm_q
                .first()
                .map_or(String::new(), |q| format!(" (q = {q})")),
            plus_minus(r.dtm_alpha, r.dtm_alpha_stderr, 2),
            r.dtm_c1
        ),
        x_label: "log10 η".into(),
        y_label: "log10 |K(q, η)|".into(),
        ..Default::default()
    };
    for (iq, d) in r.dtm.iter().enumerate() {
        // the error bar of log10 |K|: se / (|K| ln 10)
        let (pts, err): (Vec<(f64, f64)>, Vec<f64>) = r
            .eta
            .iter()
            .zip(&r.k_eta[iq])
            .enumerate()
            .filter(|(_, (_, k))| **k * (d.q - 1.0) > 0.0)
            .map(|(ie, (e, k))| {
                let se = r
                    .k_eta_stderr
                    .get(iq)
                    .and_then(|v| v.get(ie))
                    .copied()
                    .unwrap_or(f64::NAN);
                (
                    (e.log10(), k.abs().log10()),
                    se / (k.abs() * std::f64::consts::LN_10),
                )
            })
            .unzip();
        c.series.push(
            Series::new(format!("q = {}", d.q), pts, Style::Markers, 2 * iq).with_errors(err),
        );
        if d.alpha.is_finite() && d.c1.is_finite() {
            // log K = α log η + log(C1 |shape(α, q)|)
            let b = (d.c1 * universal_shape(d.alpha, d.q).abs()).log10();
            // over the η this q's fit used (qη <= q_s/2 cuts the top)
            let (x0, x1) = (d.eta_used.0.log10(), d.eta_used.1.log10());
            c.series.push(Series::new(
                format!("slope alpha = {:.3}", d.alpha),
                vec![(x0, b + d.alpha * x0), (x1, b + d.alpha * x1)],
                Style::Line,
                2 * iq + 1,
            ));
        }
    }
    save_chart(&c, &dir.join("dtm.png"))
}

/// Generalised structure functions `log2 <|Δf(l)|^q>` against `log2 l`.
fn plot_sf(dir: &Path, r: &TraceMomentResult, what: &str, px: Option<(f64, &str)>) -> Result<()> {
    let mut c = Chart {
        title: format!(
            "structure functions, fit log2 l {}:{}, H_sf = {}: {what}",
            r.fit_log2_lag.0,
            r.fit_log2_lag.1,
            r.h_sf.map_or("n/a".into(), |h| format!("{h:.3}"))
        ),
        x_label: format!(
            "log2 l (px{}; open: lags outside the fit)",
            super::px_is(px)
        ),
        y_label: "log2 <|Δf(l)|^q>".into(),
        ..Default::default()
    };
    let (llo, lhi) = r.fit_log2_lag;
    let fitted = |x: f64| x >= llo - 1e-9 && x <= lhi + 1e-9;
    for (i, q) in r.sf_q.iter().enumerate() {
        let [inside, outside] = split_by(&r.log2_lag, &r.log2_sf[i], 1.0, fitted);
        c.series.push(Series::new(
            format!("q = {q}, xi = {:.3}", r.xi[i]),
            inside,
            Style::Markers,
            i,
        ));
        c.series
            .push(Series::new("", outside, Style::OpenMarkers, i));
        // the fitted line over the lags fitted
        let (k, b) = (r.xi[i], r.xi_intercept.get(i).copied().unwrap_or(f64::NAN));
        if k.is_finite() && b.is_finite() {
            c.series.push(Series::new(
                "",
                vec![(llo, b + k * llo), (lhi, b + k * lhi)],
                Style::Line,
                i,
            ));
        }
    }
    save_chart(&c, &dir.join("sf.png"))
}

/// The ensemble's angle-averaged spectrum with the fitted slope.
fn plot_spectrum(
    dir: &Path,
    r: &TraceMomentResult,
    ps: &PowerSpectrum,
    what: &str,
    px: Option<(f64, &str)>,
) -> Result<()> {
    let pts = ps.points();
    let mut c = Chart {
        title: format!(
            "angle-averaged spectrum: beta = {} (angle-integrated: {}), H = {}: {what}",
            // one slope, one error: the two betas differ by 1 (SPEC §8)
            r.beta_averaged.map_or("n/a".into(), |b| plus_minus(
                b,
                r.beta_stderr.unwrap_or(f64::NAN),
                3
            )),
            r.beta.map_or("n/a".into(), |b| format!("{b:.3}")),
            r.h.map_or("n/a".into(), |h| plus_minus(
                h,
                r.h_stderr.unwrap_or(f64::NAN),
                3
            ))
        ),
        x_label: format!("log2 |k| (rad/px{})", super::px_is(px)),
        y_label: "log2 S(|k|), angle-averaged".into(),
        ..Default::default()
    };
    c.series.push(Series::new(
        "S(|k|)",
        pts.iter()
            .filter(|p| p.1 > 0.0)
            .map(|p| (p.0.log2(), p.1.log2()))
            .collect(),
        Style::Markers,
        0,
    ));
    if let (Some((k0, k1)), Some(b)) = (r.k_range, r.beta_averaged) {
        let sel: Vec<(f64, f64)> = pts
            .iter()
            .filter(|p| p.0 >= k0 && p.0 <= k1 && p.1 > 0.0)
            .map(|p| (p.0.log2(), p.1.log2()))
            .collect();
        if !sel.is_empty() {
            let mx = sel.iter().map(|p| p.0).sum::<f64>() / sel.len() as f64;
            let my = sel.iter().map(|p| p.1).sum::<f64>() / sel.len() as f64;
            let (x0, x1) = (k0.log2(), k1.log2());
            c.series.push(Series::new(
                format!("fit: beta = {b:.3}"),
                vec![(x0, my - b * (x0 - mx)), (x1, my - b * (x1 - mx))],
                Style::Line,
                1,
            ));
        }
    }
    save_chart(&c, &dir.join("spectrum.png"))
}
