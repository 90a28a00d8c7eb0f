//! `wtmm info IMAGE...`: what wtmm reads from each file (format, sample
//! type, shape, values, missing pixels, the pixel spacing it declares) and
//! how much of it each number of octaves leaves to count maxima in (the
//! margin of SPEC §1 grows with the largest scale), before an analysis.

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
}

pub fn run(args: InfoArgs, _quiet: bool) -> Result<Outcome> {
    let wavelet = args
        .cwt
        .wavelet
        .unwrap_or(AnalysisConfig::default().wavelet);
    // the planned analysis must be one analyze accepts (a_min above the
    // wavelet's smallest scale, the grid's limits)
    AnalysisConfig {
        wavelet,
        a_min: args.cwt.a_min,
        octaves: args.cwt.octaves,
        voices: args.cwt.voices,
        margin: args.cwt.margin,
        ..Default::default()
    }
    .validate()?;
    let mut out = Vec::new();
    for p in &args.images {
        out.push(describe(p, &args.cwt, wavelet)?);
    }
    if args.json {
        let mut body = header(
            "info",
            json!({"images": args.images, "wavelet": wavelet, "a_min": args.cwt.a_min,
                "octaves": args.cwt.octaves, "voices": args.cwt.voices, "margin": args.cwt.margin}),
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
    Ok(Outcome::Ok)
}

/// One file, as text and as JSON.
struct Described {
    text: String,
    json: serde_json::Value,
}

fn describe(path: &Path, cwt: &CwtOpts, wavelet: crate::cwt::Wavelet) -> Result<Described> {
    let (field, info) = crate::io::read_field_with_info(path)?;
    let (ny, nx) = field.dim();
    let missing = field.missing_count();
    let valid: Vec<f64> = field
        .data
        .iter()
        .copied()
        .filter(|v| v.is_finite())
        .collect();
    let n = valid.len() as f64;
    let mean = valid.iter().sum::<f64>() / n;
    let sd = (valid.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
    let range = field.range();
    let mut text = format!(
        "{}: {ny} x {nx} px (rows x columns), {} {}\n",
        path.display(),
        info.format,
        info.dtype
    );
    let mut notes: Vec<String> = info.warnings.clone();
    match range {
        Some((lo, hi)) => {
            text += &format!(
                "  values {} .. {}, mean {}, sd {}; {missing} missing ({:.2} %)\n",
                f(lo),
                f(hi),
                f(mean),
                f(if sd.is_finite() { sd } else { 0.0 }),
                100.0 * missing as f64 / (ny * nx) as f64
            );
            if lo == hi {
                notes.push("constant: no analysis can use it".into());
            }
        }
        None => notes.push("every pixel is missing (NaN or nodata)".into()),
    }
    notes.extend(field.amplitude_problem());
    // the spacing the file declares (a file wtmm cannot read for it: none)
    let px = crate::io::read_pixel_spacing(path).ok().flatten();
    match &px {
        Some(p) => {
            text += &format!(
                "  pixel {} x {} {} ({})\n",
                f(p.x),
                f(p.y),
                p.units.as_deref().unwrap_or("units unknown"),
                p.source
            );
            notes.extend(p.warnings.iter().cloned());
        }
        None => text += "  pixel: none declared (give --pixel-size for lengths)\n",
    }
    // the counting domain per number of octaves: the default margin grows
    // with the largest scale (SPEC §1), and only that interior is counted
    text += &format!(
        "  counting domain, {wavelet} wavelet from a_min = {} px, {} margin:\n",
        f(cwt.a_min),
        cwt.margin
            .map_or("the default".to_string(), |m| format!("a {m} px"))
    );
    text += "    octaves   a_max (px)   margin (px)   domain (px)   counted\n";
    let mut domains = Vec::new();
    for k in 1..=cwt.octaves.max(1) {
        let cfg = AnalysisConfig {
            wavelet,
            a_min: cwt.a_min,
            octaves: k,
            voices: cwt.voices,
            margin: cwt.margin,
            ..Default::default()
        };
        let a_max = cfg.scale_list().last().copied().unwrap_or(cwt.a_min);
        let margin = cfg.margin_px();
        let counted = cfg.counting_pixels(&field).ok();
        let shape = counted.map(|_| [ny - 2 * margin, nx - 2 * margin]);
        let fraction = counted.map(|(c, _)| c as f64 / (ny * nx) as f64);
        let mark = if k == cwt.octaves { " *" } else { "" };
        text += &format!(
            "    {:<9} {:<12} {:<13} {:<13} {}\n",
            format!("{k}{mark}"),
            format!("{a_max:.1}"),
            margin,
            shape.map_or("none".to_string(), |s| format!("{} x {}", s[0], s[1])),
            fraction.map_or("image too small".to_string(), |fr| format!(
                "{:.1} %",
                100.0 * fr
            ))
        );
        domains.push(
            json!({"octaves": k, "a_max": a_max, "margin": margin, "domain": shape,
            "counted_pixels": counted.map(|c| c.0), "fraction": fraction}),
        );
    }
    // analyze's default fit (spectra::default_fit): its top must be
    // reached by maxima lines inside the domain
    let (lo, hi) = crate::spectra::default_fit(cwt.octaves, cwt.voices);
    text += &format!(
        "    (* --octaves {}: analyze fits {}:{} octaves by default, a = {} .. {} px; a periodic \
         field, such as wtmm's synthetic cascades, is counted whole with --margin 0)\n",
        cwt.octaves,
        f(lo),
        f(hi),
        f(cwt.a_min * lo.exp2()),
        f(cwt.a_min * hi.exp2())
    );
    for n in &notes {
        text += &format!("  note: {n}\n");
    }
    let json = json!({
        "file": path, "format": info.format.name(), "dtype": info.dtype, "shape": [ny, nx],
        "missing": missing, "min": range.map(|r| r.0), "max": range.map(|r| r.1),
        "mean": (n > 0.0).then_some(mean), "sd": (n > 1.0).then_some(sd),
        "pixel_size": px.as_ref().map(|p| json!({"x": p.x, "y": p.y, "units": p.units,
            "source": p.source})),
        "domains": domains, "notes": notes,
    });
    Ok(Described { text, json })
}
