//! `wtmm spectrum IMAGE... --out DIR`: ensemble-averaged isotropic power
//! spectrum, fitted beta, CSV and a log-log plot with the fitted line.

use std::path::PathBuf;

use clap::Args;
use serde_json::json;

use super::common::save_chart;
use super::common::{f, header, make_out_dir, parse_range, read_all, write_csv, write_json};
use super::{OutDir, Outcome, PixelOpts, PixelSize};
use crate::error::{Error, Result};
use crate::plot::{Chart, Series, Style};
use crate::stats::fit::mean_std;
use crate::stats::powspec::{
    CONVENTION, Detrend, HoleFill, PowerSpectrum, PowerSpectrumConfig, Window, bins_in_range,
    default_k_range, field_power_spectrum, jackknife_beta_se, large_hole_warning,
    largest_filled_hole,
};

#[derive(Args, Debug)]
pub struct SpectrumArgs {
    /// Input images (analysed as one ensemble).
    #[arg(required = true)]
    pub images: Vec<PathBuf>,
    /// Fit range in rad/px, `LO:HI` (default: 8 cycles per image to pi/4).
    #[arg(long, allow_hyphen_values = true)]
    pub k_range: Option<String>,
    /// Taper before the FFT (hann for non-periodic fields, none for periodic ones)
    /// [default: hann; none for files `wtmm synth` wrote from a periodic model,
    /// listed in the synth.json beside them].
    #[arg(long, value_enum)]
    pub window: Option<Window>,
    /// Trend removed before the FFT [default: plane; mean for files `wtmm synth`
    /// wrote from a periodic model: a plane removed from a torus is a sawtooth
    /// across its edges; `plane` given, such files take the non-periodic
    /// defaults (a taper), as with the other commands' --detrend plane].
    #[arg(long, value_enum)]
    pub detrend: Option<Detrend>,
    /// Log-spaced bins per octave of |k|.
    #[arg(long, default_value_t = 4)]
    pub bins_per_octave: usize,
    /// How missing pixels are filled before the FFT: `harmonic` (Laplace's
    /// equation inside each hole, its rim as the boundary: no edge along
    /// the rim) or `mean` (the image mean: a step along every rim, whose
    /// power flattens the spectrum; the estimator before harmonic fills).
    #[arg(long, value_enum, default_value_t = HoleFill::Harmonic)]
    pub fill: HoleFill,
    /// Theoretical beta to draw (angle-averaged), if known.
    #[arg(long)]
    pub theory_beta: Option<f64>,
    #[command(flatten)]
    pub pixel: PixelOpts,
    #[command(flatten)]
    pub read: super::ReadOpts,
    #[command(flatten)]
    pub out: OutDir,
}

pub fn run(args: SpectrumArgs, quiet: bool) -> Result<Outcome> {
    let (px, px_warnings) = args.pixel.resolve(&args.images)?;
    if args.bins_per_octave == 0 {
        return Err(crate::Error::param("bins-per-octave", "must be >= 1"));
    }
    // as --h0 of pdf: a line far outside the data is a typo, not a model
    // (beta = 2h + 2 for a surface of exponent h)
    if let Some(b) = args.theory_beta
        && !(b.abs() <= 10.0)
    {
        return Err(crate::Error::param(
            "theory-beta",
            format!(
                "must be a finite exponent in [-10, 10], got {b_s}",
                b_s = crate::error::short(b)
            ),
        ));
    }
    let k_range = args
        .k_range
        .as_deref()
        .map(|s| parse_range("k-range", s))
        .transpose()?;
    if let Some((lo, hi)) = k_range
        && !(lo > 0.0 && hi <= std::f64::consts::PI)
    {
        // beyond pi the bins are the corners of the spectrum only
        return Err(crate::Error::param(
            "k-range",
            format!("[{lo}, {hi}] rad/px: need 0 < LO < HI <= pi (the Nyquist wavenumber)"),
        ));
    }
    let nodata = args.read.value()?;
    let fields = read_all(&args.images, nodata)?;
    for (fl, p) in fields.iter().zip(&args.images) {
        super::common::refuse_constant(fl, p, "its spectrum is zero")?;
        // an exact plane, as every analysis refuses (with --window none
        // --detrend mean it read beta 1.7 +- 0.8)
        fl.detrended(crate::field::Trend::None)
            .map_err(|e| super::common::in_file(p, e))?;
    }
    if let Some((fl, p)) = fields
        .iter()
        .zip(&args.images)
        .max_by_key(|(f, _)| f.dim().0 * f.dim().1)
    {
        let (ny, nx) = fl.dim();
        super::common::check_spectrum_memory((p, ny, nx), fields.len())?;
    }
    // periodic synth files: the settings validate uses for their model
    // (PowerSpectrumConfig::for_field), unless given
    // (--detrend plane asks for the non-periodic treatment, as in the
    // other commands: no origin then)
    let origin = match (args.window, args.detrend) {
        (Some(_), Some(_)) | (_, Some(Detrend::Plane)) => None,
        _ => super::common::periodic_synth(
            &args.images,
            match (args.window, args.detrend) {
                (None, None) => Some(
                    "tapered, a plane removed: --window none --detrend mean are the periodic \
                     settings",
                ),
                (None, Some(_)) => Some("tapered: --window none is the periodic setting"),
                (Some(_), None) => Some("a plane removed: --detrend mean is the periodic setting"),
                (Some(_), Some(_)) => None,
            },
            false,
        ),
    };
    let base = PowerSpectrumConfig::for_field(origin.is_some());
    let cfg = PowerSpectrumConfig {
        window: args.window.unwrap_or(base.window),
        detrend: args.detrend.unwrap_or(base.detrend),
        bins_per_octave: args.bins_per_octave,
        fill: args.fill,
    };
    if let Some(o) = &origin {
        say!(
            "note: {}: by default without a taper and with only the mean removed, as validate \
             takes the model's spectrum (a torus needs no taper, and a plane removed from it is \
             a sawtooth across its edges); here window {}, detrend {}",
            o.describe(args.images.len()),
            format!("{:?}", cfg.window).to_lowercase(),
            format!("{:?}", cfg.detrend).to_lowercase()
        );
    }
    let nmin = fields
        .iter()
        .map(|f| f.dim().0.min(f.dim().1))
        .min()
        .unwrap_or(0);
    let (k_lo, k_hi) = match k_range {
        Some(r) => r,
        None => {
            let r = default_k_range(nmin);
            if bins_in_range(nmin, nmin, args.bins_per_octave, r)? < 3 {
                let small = fields
                    .iter()
                    .zip(&args.images)
                    .find(|(f, _)| f.dim().0.min(f.dim().1) == nmin)
                    .map(|(_, p)| p.clone())
                    .unwrap_or_default();
                return Err(crate::Error::format(
                    small,
                    format!(
                        "a side of {nmin} px is too small for the default fit range \
                         (8 cycles per image up to pi/4 rad/px holds fewer than the 3 bins a fit \
                         needs); give --k-range or more --bins-per-octave"
                    ),
                ));
            }
            r
        }
    };
    let spectra: Vec<PowerSpectrum> = crate::par::try_map(fields.len(), |i| {
        field_power_spectrum(&fields[i], &cfg)
            .map_err(|e| super::common::in_file(&args.images[i], e))
    })?;
    let mut ens = PowerSpectrum::default();
    for s in &spectra {
        ens.merge(s)?;
    }
    // a fault of the data names the image(s)
    let fit = ens
        .fit(k_lo, k_hi)
        .map_err(|e| match (e, args.images.as_slice()) {
            (Error::Input(m), [one]) => Error::format(one, m),
            (Error::Input(m), many) => Error::Input(format!("{} images: {m}", many.len())),
            (e, _) => e,
        })?;
    let (per_image, per_image_se): (Vec<f64>, Vec<f64>) = spectra
        .iter()
        .map(|s| {
            s.fit(k_lo, k_hi)
                .map(|f| (f.beta, f.beta_stderr))
                .unwrap_or((f64::NAN, f64::NAN))
        })
        .unzip();
    let (m, sd) = mean_std(&per_image);
    make_out_dir(&args.out.out)?;
    let pts = ens.points();
    let mut body = header(
        "spectrum",
        json!({"images": super::common::paths_json(&args.images), "window": cfg.window, "detrend": cfg.detrend, "bins_per_octave": cfg.bins_per_octave, "fill": cfg.fill,
            "pixel_size": px.as_ref().map(PixelSize::json),
            "origin": origin.as_ref().map(super::common::PeriodicSynth::json), "nodata": nodata}),
    );
    body["images"] = json!(fields.len());
    body["image_shapes"] = json!(crate::spectra::ShapeCount::tally(fields.iter().map(|f| {
        let (ny, nx) = f.dim();
        [ny, nx]
    })));
    body["beta"] = json!(fit.beta);
    // as tau_stderr: a jackknife over the images when there are 3 or more,
    // the regression's error otherwise. Unlike the partition functions'
    // (whose scales see the same structures), the |k| bins average
    // independent Fourier modes, so a lone image's regression error is near
    // the sampling error: 0.76 (fBm, H = 1/3) and 0.98 (paper-lognormal) of
    // the scatter of beta between 24 lone 512^2 images (2026-11-26)
    let jk = jackknife_beta_se(&spectra, k_lo, k_hi)?;
    let (beta_se, se_method) = if jk.is_finite() {
        (jk, "jackknife over images")
    } else {
        (fit.beta_stderr, "regression")
    };
    body["beta_stderr"] = json!(beta_se);
    body["beta_stderr_method"] = json!(se_method);
    body["beta_stderr_regression"] = json!(fit.beta_stderr);
    body["r2"] = json!(fit.line.r2);
    body["k_range"] = json!([k_lo, k_hi]);
    // the fit range as wavelengths 2 pi / k, in px (JSON and summary)
    let wavelengths_px = [
        2.0 * std::f64::consts::PI / k_hi,
        2.0 * std::f64::consts::PI / k_lo,
    ];
    body["k_units"] = json!("rad/px");
    if let Some(p) = &px {
        // the fit range in the pixel's units: wavenumbers and wavelengths
        let side = p.side();
        body["k_range_physical"] = json!([k_lo / side, k_hi / side]);
        body["k_physical_units"] = json!(format!("rad/{}", p.units));
        body["wavelength_range"] = json!(wavelengths_px.map(|l| l * side));
    }
    body["convention"] = json!(CONVENTION);
    // missing pixels were filled before the FFT: say how
    let missing: Vec<usize> = fields
        .iter()
        .map(|f| f.dim().0 * f.dim().1 - f.valid_count())
        .collect();
    let mut warnings: Vec<String> = px
        .as_ref()
        .and_then(|p| p.warning(super::Isotropic::Spectrum))
        .into_iter()
        .chain(px_warnings)
        .collect();
    PixelSize::say_note(px.as_ref(), quiet);
    for ((n, p), fl) in missing.iter().zip(&args.images).zip(&fields) {
        if *n > 0 {
            let (ny, nx) = fl.dim();
            let share = largest_filled_hole(fl, &cfg) as f64 / (ny * nx) as f64;
            warnings.push(format!(
                "{}: {n} missing pixels filled {} before the FFT{} (README \"Spectra of images \
                 with holes\")",
                p.display(),
                match cfg.fill {
                    HoleFill::Harmonic => "harmonically (--fill)",
                    HoleFill::Mean => "with the image mean (--fill)",
                },
                large_hole_warning(share)
                    .map(|w| format!("; {w}"))
                    .unwrap_or_default()
            ));
        }
    }
    // a flat area far off the surface (a fill at 0 or -9999): its rim is a
    // cliff, whose spectrum swamps the surface's (Field::rim_contrast, field::CLIFF_CONTRAST)
    for (fl, p) in fields.iter().zip(&args.images) {
        let Some((v, share)) = fl.flat_value() else {
            continue;
        };
        if share <= crate::field::FLAT_SHARE_WARN {
            continue;
        }
        if let Some(c) = fl
            .rim_contrast(v)
            .filter(|&c| c > crate::field::CLIFF_CONTRAST)
        {
            warnings.push(format!(
                "{}: one value, {}, fills {:.0} % of the valid pixels and lies far off the \
                 surface around it (the median difference across its rim is {c:.0} times the \
                 median step between the other neighbours): its rim is a cliff, whose spectrum \
                 swamps the surface's (on Levi Fell, 30 % set 30 m below the coast moved beta \
                 by -0.26, 100 m by -0.98); if it is no data, give it as missing (--nodata {}, \
                 NaN, or the file's nodata value)",
                p.display(),
                crate::error::short(v),
                100.0 * share,
                crate::error::exact(v)
            ));
        }
    }
    if !jk.is_finite() {
        warnings.push(format!(
            "beta's standard error is the regression's over the |k| bins ({}; a jackknife \
             needs 3 or more): the bins average independent Fourier modes, so it is near the \
             sampling error (0.76 of the scatter of beta between lone 512^2 fBm images, 0.98 \
             for the log-normal W-cascade), but it cannot see how the image's parts differ",
            super::common::count_of(fields.len(), "image")
        ));
    }
    // two images that do not share one spectrum: the regression error sees
    // neither their difference nor that the pooled spectrum weighs each by
    // its power. Their own errors, widened to the scatter they understate
    // (0.76 of it, above), make a difference of 3 of them rare (~0.3 %)
    if let ([b0, b1], [s0, s1]) = (per_image.as_slice(), per_image_se.as_slice())
        && !jk.is_finite()
    {
        let z = (b0 - b1).abs() / (s0.hypot(*s1) / 0.76);
        if z > 3.0 {
            warnings.push(format!(
                "the images' own betas, {b0:.3} +- {s0:.3} and {b1:.3} +- {s1:.3}, differ by \
                 {z:.1} times their combined error: they do not look like one process, and \
                 the pooled spectrum weighs each image by its power, so beta = {:.3} may \
                 describe mostly one of them; analyse them apart",
                fit.beta
            ));
        }
    }
    body["missing_pixels"] = json!(missing);
    body["warnings"] = json!(warnings);
    body["per_image_beta"] = json!(per_image);
    body["per_image_beta_mean"] = json!(m);
    body["per_image_beta_std"] = json!(sd);
    if let Some(b) = args.theory_beta {
        body["theory_beta"] = json!(b);
    }
    body["k"] = json!(pts.iter().map(|p| p.0).collect::<Vec<_>>());
    body["S"] = json!(pts.iter().map(|p| p.1).collect::<Vec<_>>());
    write_json(&args.out.out.join("spectrum.json"), &body)?;
    let rows: Vec<Vec<String>> = pts.iter().map(|p| vec![f(p.0), f(p.1)]).collect();
    write_csv(
        &args.out.out.join("spectrum.csv"),
        &["k_rad_per_px", "S"],
        &rows,
    )?;
    let mut chart = Chart {
        title: {
            // what the figure shows: the file (or how many), and the size
            let what = match args.images.as_slice() {
                [one] => one
                    .file_name()
                    .map_or_else(|| one.display().to_string(), |n| n.to_string_lossy().into()),
                many => super::common::count_of(many.len(), "image"),
            };
            let dims: Vec<(usize, usize)> = fields.iter().map(|f| f.dim()).collect();
            let size = if dims.iter().all(|d| *d == dims[0]) {
                format!("{}x{}", dims[0].0, dims[0].1)
            } else {
                "mixed sizes".into()
            };
            // the figure says what the warnings do: gaps were filled
            let filled = match (missing.iter().sum::<usize>(), cfg.fill) {
                (0, _) => "",
                (_, HoleFill::Harmonic) => ", gaps filled harmonically",
                (_, HoleFill::Mean) => ", gaps filled with the mean",
            };
            format!(
                "Angle-averaged power spectrum of {what} ({size}{filled}): beta = {} ({se_method})",
                super::common::plus_minus(fit.beta, beta_se, 3)
            )
        },
        x_label: format!(
            "log2 |k| (rad/px{})",
            super::px_is(px.as_ref().map(PixelSize::plot))
        ),
        y_label: "log2 S(|k|)".into(),
        ..Default::default()
    };
    chart.series.push(Series::new(
        "S(|k|), angle-averaged",
        pts.iter().map(|p| (p.0.log2(), p.1.log2())).collect(),
        Style::Markers,
        0,
    ));
    let line = |b: f64, c: f64| {
        vec![
            (k_lo.log2(), c - b * k_lo.log2()),
            (k_hi.log2(), c - b * k_hi.log2()),
        ]
    };
    chart.series.push(Series::new(
        format!(
            "fit over [{k_lo:.3}, {k_hi:.3}] rad/px: beta = {:.3}",
            fit.beta
        ),
        line(fit.beta, fit.line.intercept),
        Style::Line,
        1,
    ));
    if let Some(b) = args.theory_beta {
        // theory line through the fit's centre
        let xc = 0.5 * (k_lo.log2() + k_hi.log2());
        let yc = fit.line.intercept + fit.line.slope * xc;
        chart.series.push(Series::new(
            format!("theory beta = {b:.3}"),
            line(b, yc + b * xc),
            Style::Dashed,
            2,
        ));
    }
    save_chart(&chart, &args.out.out.join("spectrum.png"))?;
    // the reading on stdout, as analyze and tm give theirs; warnings after it
    let mut line = format!(
        "spectrum: {}, beta = {:.3} +- {:.3} ({se_method}; angle-averaged), k = {k_lo:.3}-{k_hi:.3} \
         rad/px",
        super::common::count_of(fields.len(), "image"),
        fit.beta,
        beta_se
    );
    if let Some(p) = &px {
        line += &format!(
            " (wavelengths {} - {})",
            p.length(wavelengths_px[0]),
            p.length(wavelengths_px[1])
        );
    }
    if fields.len() > 1 {
        line += &format!("; per image {m:.3} +- {sd:.3} (mean +- sd)");
    }
    if let Some(b) = args.theory_beta {
        line += &format!("; theory {b:.3}");
    }
    show!("{line}\n");
    for w in &warnings {
        say!("warning: {w}");
    }
    Ok(Outcome::Ok)
}
