//! `wtmm info IMAGE...`: what wtmm reads from each file (format, sample
//! type, shape, values, missing pixels, the least-squares plane, the pixel
//! spacing it declares) and
//! how much of it each number of octaves leaves to count maxima in (the
//! margin of SPEC §1 grows with the largest scale), before an analysis.
//! Exits 1 when an image cannot be analysed (a script's pre-check).

use std::path::{Path, PathBuf};

use clap::Args;
use serde_json::json;

use super::common::header;
use super::short_num as f;
use super::{CwtOpts, Outcome};
use crate::error::Result;
use crate::skeleton::AnalysisConfig;

#[derive(Args, Debug)]
pub struct InfoArgs {
    /// Input images.
    #[arg(required = true)]
    pub images: Vec<PathBuf>,
    /// The analysis planned: its wavelet, smallest scale, voices and margin
    /// set the counting domain of each number of octaves (1 to --octaves).
    #[command(flatten)]
    pub cwt: CwtOpts,
    /// JSON on stdout instead of the text.
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub read: super::ReadOpts,
}

pub fn run(args: InfoArgs, _quiet: bool) -> Result<Outcome> {
    let wavelet = args
        .cwt
        .wavelet
        .unwrap_or(AnalysisConfig::default().wavelet);
    // the planned analysis must be one analyze accepts (a_min above the
    // wavelet's smallest scale, the grid's limits, a default fit of at
    // least 3 scales)
    let plan = AnalysisConfig {
        wavelet,
        a_min: args.cwt.a_min,
        octaves: args.cwt.octaves,
        voices: args.cwt.voices,
        margin: args.cwt.margin,
        ..Default::default()
    };
    plan.validate()?;
    let fit = super::analyze_cmd::fit_range(None, args.cwt.octaves, args.cwt.voices)?;
    let grid = plan.scale_list();
    let idx = crate::spectra::fit_indices(&grid, fit)?;
    let fit_scales = (grid[idx[0]], grid[idx[idx.len() - 1]]);
    let nodata = args.read.value()?;
    let mut out = Vec::new();
    for p in &args.images {
        out.push(describe(
            p,
            nodata,
            &plan,
            args.cwt.wavelet.is_some(),
            fit,
            fit_scales,
        )?);
    }
    if args.json {
        let mut body = header(
            "info",
            json!({"images": super::common::paths_json(&args.images), "wavelet": wavelet, "a_min": args.cwt.a_min,
                "octaves": args.cwt.octaves, "voices": args.cwt.voices, "margin": args.cwt.margin,
                "default_fit_octaves": fit, "default_fit_scales": fit_scales, "nodata": nodata}),
        );
        body["images"] = json!(out.iter().map(|d| &d.json).collect::<Vec<_>>());
        show!(
            "{}\n",
            serde_json::to_string_pretty(&body).expect("JSON values")
        );
    } else {
        for d in &out {
            show!("{}", d.text);
        }
    }
    // a script's pre-check: exit 1 when an image cannot be analysed
    Ok(if out.iter().all(|d| d.usable) {
        Outcome::Ok
    } else {
        Outcome::CheckFailed
    })
}

/// One file, as text and as JSON, and whether analyze can use it.
struct Described {
    text: String,
    json: serde_json::Value,
    usable: bool,
}

fn describe(
    path: &Path,
    nodata: Option<f64>,
    plan: &AnalysisConfig,
    wavelet_given: bool,
    fit: (f64, f64),
    fit_scales: (f64, f64),
) -> Result<Described> {
    let (mut field, info) = crate::io::read_field_with_info(path)?;
    // --nodata, as the analyses read it (common::read_image)
    let unmatched = super::common::apply_nodata(&mut field, &info, nodata);
    // a periodic synth field is counted whole by default, as analyze does
    // (looked up while the margin or the wavelet is open, as analyze does)
    let origin = if plan.margin.is_none() || !wavelet_given {
        super::common::periodic_synth(&[path.to_path_buf()], None, false)
    } else {
        None
    };
    let margin_given = plan.margin.is_some();
    let torus;
    let plan = match origin {
        Some(_) => {
            // and the wavelet its record recommends, as analyze takes
            torus = AnalysisConfig {
                margin: plan.margin.or(Some(0)),
                wavelet: match origin.as_ref().and_then(|o| o.wavelet) {
                    Some(w) if !wavelet_given => w,
                    _ => plan.wavelet,
                },
                ..plan.clone()
            };
            &torus
        }
        None => plan,
    };
    let (ny, nx) = field.dim();
    let missing = field.missing_count();
    // mean and sd of the valid pixels, in two passes (no copy), on the
    // values divided by the largest magnitude: sums of values near 1e308
    // overflow, squares of values near 1e-300 underflow (both read sd 0)
    let range = field.range();
    let s = range
        .map(|(lo, hi)| lo.abs().max(hi.abs()))
        .filter(|&s| s > 0.0)
        .unwrap_or(1.0);
    let valid = || field.data.iter().filter(|v| v.is_finite()).map(|v| v / s);
    let n = field.valid_count() as f64;
    let m = valid().sum::<f64>() / n;
    let mean = m * s;
    let sd = (valid().map(|v| (v - m).powi(2)).sum::<f64>() / (n - 1.0)).sqrt() * s;
    let mut text = format!(
        "{}: {ny} x {nx} px (rows x columns), {} {}\n",
        path.display(),
        info.format,
        info.dtype
    );
    text += &format!(
        "  {missing} missing pixels ({:.2} %)",
        100.0 * missing as f64 / (ny * nx) as f64
    );
    if let Some((lo, hi)) = range {
        text += &format!(
            "; values {} .. {}, mean {}, sd {}",
            f(lo),
            f(hi),
            f(mean),
            f(if sd.is_finite() { sd } else { 0.0 })
        );
    }
    text += "\n";
    let mut notes: Vec<String> = info.warnings.clone();
    notes.extend(unmatched);
    // the least-squares plane: a regional slope adds to the gauss
    // wavelet's transform a vector growing like the scale (analyze warns
    // above half)
    let plane = field.fit_plane();
    let share = field.plane_share();
    if let (Some(p), Some(r)) = (plane, share) {
        text += &format!(
            "  trend: least-squares plane of slope {} per px ({} along x, {} along y), {:.1} % of \
             the variance\n",
            f(p.slope()),
            f(p.cx),
            f(p.cy),
            100.0 * r
        );
        // mexican (3 vanishing moments) is blind to planes
        if r > crate::spectra::PLANE_SHARE_WARN
            && r < 1.0 - crate::field::PLANE_ONLY
            && plan.wavelet == crate::cwt::Wavelet::Gauss
        {
            notes.push(format!(
                "the least-squares plane explains {:.0} % of the variance: the gauss wavelet \
                 adds a plane to its transform as a vector growing like the scale, which \
                 biases h and D (analyze warns when half an ensemble's images are so); give \
                 --detrend plane, or use --wavelet mexican",
                100.0 * r
            ));
        }
    }
    // quantised values and flat areas: terraces wider than
    // TERRACE_SCALES times the smallest fitted scale, one value over
    // FLAT_SHARE_WARN of the pixels (analyze warns: spectra::terrace_warning,
    // flat_warning); a line of their own from 1.5 px (a continuous surface
    // reads 1) and from 1 % of the pixels
    let (terrace, flat) = crate::spectra::quantisation(&field);
    if let Some(w) = terrace.filter(|&w| w >= 1.5) {
        text += &format!(
            "  quantised: terraces {w:.1} px wide (1 / (1 - f), f the share of equal neighbour \
             pairs; 1 where neighbours differ)\n"
        );
    }
    let top = plan.scale_list().last().copied().unwrap_or(plan.a_min);
    notes.extend(crate::spectra::terrace_warning(
        &[terrace],
        fit_scales.0,
        "the smallest scale analyze fits by default",
        ", which lowers h(q) and raises D",
        crate::spectra::fit_remedy(plan.a_min, plan.voices, top),
    ));
    // (a constant image is one flat value: said below as not usable)
    let flat = flat.filter(|_| range.is_some_and(|(lo, hi)| lo < hi));
    if let Some(fl) = flat.filter(|f| f.share >= 0.01) {
        text += &format!(
            "  flat: the value {} fills {:.1} % of the valid pixels\n",
            f(fl.value),
            100.0 * fl.share
        );
    }
    notes.extend(crate::spectra::flat_warning(&[flat]));
    // what analyze refuses, the reason it would give
    let mut problems: Vec<String> = Vec::new();
    match range {
        Some((lo, hi)) if lo == hi => problems.push("constant: no maxima to analyse".into()),
        Some(_) => {}
        None => problems.push("every pixel is missing (NaN or nodata)".into()),
    }
    problems.extend(field.amplitude_problem());
    // a plane: what analyze refuses whatever the trend
    if let Err(e) = field.detrended(crate::field::Trend::None) {
        problems.push(super::common::reason(e));
    }
    if let Err(e) = crate::cwt::check_size(ny, nx, plan.wavelet, plan.a_min) {
        problems.push(e.to_string());
    }
    // the spacing the file declares (a file wtmm cannot read for it: none)
    let px = crate::io::read_pixel_spacing(path).ok().flatten();
    match &px {
        Some(p) => {
            let u = p.units.as_deref().unwrap_or("units unknown");
            text += &format!(
                "  pixel {} {u} along x (columns), {} {u} along y (rows): {}\n",
                f(p.x),
                f(p.y),
                p.source
            );
            // the warning the analysing commands give for this pixel
            let as_used = super::PixelSize {
                x: p.x,
                y: p.y,
                units: u.to_string(),
                source: p.source.clone(),
            };
            notes.extend(as_used.warning(super::Isotropic::Wavelet));
            notes.extend(p.warnings.iter().cloned());
        }
        None => text += "  pixel: none declared (give --pixel-size for lengths)\n",
    }
    // the counting domain per number of octaves: the default margin grows
    // with the largest scale (SPEC §1), and only that interior, away from
    // missing pixels, is counted
    text += &format!(
        "  counting domain, {} wavelet from a_min = {} px, {} margin:\n",
        plan.wavelet,
        f(plan.a_min),
        plan.margin
            .map_or("the default".to_string(), |m| format!("a {m} px"))
    );
    text += "    octaves   a_max (px)   margin (px)   domain (px)   counted\n";
    let dist = field.mask.as_ref().map(crate::skeleton::distance_to_mask);
    let mut domains = Vec::new();
    let mut counted_at_plan = None;
    for k in 1..=plan.octaves.max(1) {
        let cfg = AnalysisConfig {
            octaves: k,
            ..plan.clone()
        };
        let a_max = cfg.scale_list().last().copied().unwrap_or(plan.a_min);
        let margin = cfg.margin_px();
        let counted = cfg.counting_pixels_with(&field, dist.as_ref()).ok();
        let shape = counted.map(|_| [ny - 2 * margin, nx - 2 * margin]);
        let fraction = counted.map(|(c, _)| c as f64 / (ny * nx) as f64);
        if k == plan.octaves {
            counted_at_plan = counted.map(|c| c.0);
        }
        let mark = if k == plan.octaves { " *" } else { "" };
        text += &format!(
            "    {:<9} {:<12} {:<13} {:<13} {}\n",
            format!("{k}{mark}"),
            format!("{a_max:.1}"),
            margin,
            shape.map_or("none".to_string(), |s| format!("{} x {}", s[0], s[1])),
            match (counted, fraction) {
                (Some((c, _)), Some(fr)) => format!("{c} px ({:.1} %)", 100.0 * fr),
                _ => "image too small".to_string(),
            }
        );
        domains.push(
            json!({"octaves": k, "a_max": a_max, "margin": margin, "domain": shape,
            "counted_pixels": counted.map(|c| c.0), "fraction": fraction}),
        );
    }
    if counted_at_plan.unwrap_or(0) == 0 {
        problems.push(format!(
            "no pixel to count maxima in at --octaves {} (a smaller margin or fewer octaves)",
            plan.octaves
        ));
    }
    // analyze's default fit (spectra::default_fit): its top must be
    // reached by maxima lines inside the domain
    text += &format!(
        "    (* --octaves {}: analyze fits {}:{} octaves by default, a = {} .. {} px{})\n",
        plan.octaves,
        f(fit.0),
        f(fit.1),
        f(fit_scales.0),
        f(fit_scales.1),
        if plan.margin.is_none() {
            "; a periodic field, such as wtmm's synthetic cascades, is counted whole with \
             --margin 0"
        } else {
            ""
        }
    );
    if let Some(o) = &origin {
        notes.push(format!(
            "{}: analyze, skeleton, pdf, kernel and correlate take it whole (margin 0{}) unless \
             given --margin, --domain or --detrend{}, and spectrum and tm neither taper it nor \
             remove a plane from its spectrum",
            o.describe(1),
            if margin_given {
                "; the domains above are at the --margin given"
            } else {
                ", the domains above"
            },
            o.wavelet
                .filter(|w| *w != crate::cwt::Wavelet::Gauss)
                .map_or(String::new(), |w| format!(
                    ", with the {w} wavelet it recommends unless given --wavelet"
                ))
        ));
    }
    for n in &notes {
        text += &format!("  note: {n}\n");
    }
    for p in &problems {
        text += &format!("  not usable: {p}\n");
    }
    let json = json!({
        "file": super::common::path_json(path), "format": info.format.name(), "dtype": info.dtype, "shape": [ny, nx],
        "missing": missing, "min": range.map(|r| r.0), "max": range.map(|r| r.1),
        "mean": (n > 0.0).then_some(mean), "sd": (n > 1.0).then_some(sd),
        "pixel_size": px.as_ref().map(|p| json!({"x": p.x, "y": p.y, "units": p.units,
            "source": p.source})),
        "plane": plane.map(|p| json!({"c0": p.c0, "cx": p.cx, "cy": p.cy, "slope": p.slope(),
            "variance_share": share})),
        "terrace_width": terrace, "flat": flat,
        "wavelet": plan.wavelet, "margin": plan.margin, "domains": domains, "origin": origin.as_ref().map(super::common::PeriodicSynth::json),
        "notes": notes, "usable": problems.is_empty(), "problems": problems,
    });
    Ok(Described {
        text,
        json,
        usable: problems.is_empty(),
    })
}
