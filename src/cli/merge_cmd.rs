//! `wtmm merge SUMS.json... --out DIR`: combine partition sums saved by
//! `analyze`/`validate`/`demo`/`merge`/`compare` (shards of an ensemble
//! analysed anywhere) and recompute the spectra, for any rule and fit
//! range, without redoing the wavelet transforms.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use clap::Args;
use serde_json::json;

use super::analyze_cmd::{check_fit, theory_curves, write_outputs};
use super::common::{make_out_dir, parse_range};
use super::model_args::{ModelName, ModelOpts};
use super::{OutDir, Outcome, PixelOpts, PixelSize};
use crate::error::{Error, Result};
use crate::spectra::{ImagePartial, PartitionSums, Rule, same_cells};

#[derive(Args, Debug)]
pub struct MergeArgs {
    /// `sums.json` files written by analyze, validate, demo, merge, or
    /// compare (in its wtmm/).
    #[arg(required = true)]
    pub sums: Vec<PathBuf>,
    /// Fit range in octaves above a_min, `LO:HI`. Default 0.5:4, or
    /// 0.5:OCTAVES when the sums span fewer than 4 octaves (as analyze).
    #[arg(long, allow_hyphen_values = true)]
    pub fit: Option<String>,
    /// Modulus along a maxima line: plain or sup.
    #[arg(long, value_enum, default_value_t = Rule::Plain)]
    pub rule: Rule,
    /// Theory to draw and compare with (MODEL with its options, or --preset).
    #[arg(long, value_enum)]
    pub theory: Option<ModelName>,
    #[command(flatten)]
    pub model_opts: ModelOpts,
    // the pixel of the images the sums came from (PixelOpts' help says
    // merge's default: the pixel the sums record, analyze's)
    #[command(flatten)]
    pub pixel: PixelOpts,
    #[command(flatten)]
    pub out: OutDir,
}

pub fn run(args: MergeArgs, quiet: bool) -> Result<Outcome> {
    // writing sums.json over an input would count that shard twice on the
    // next merge (a file given twice is refused with the other inputs);
    // the output file may not exist yet
    if let Ok(dir) = std::fs::canonicalize(&args.out.out) {
        let target = dir.join("sums.json");
        if let Some(p) = args
            .sums
            .iter()
            .find(|p| std::fs::canonicalize(p).is_ok_and(|c| c == target))
        {
            return Err(Error::param(
                "out",
                format!(
                    "{} would overwrite the input {}",
                    args.out.out.join("sums.json").display(),
                    p.display()
                ),
            ));
        }
    }
    let mut sums: Option<PartitionSums> = None;
    // the pixel each file records (the merge drops pixels that differ)
    let mut recorded = Vec::new();
    // the file of each image, in the order merged
    let mut owner: Vec<usize> = Vec::new();
    for (f, p) in args.sums.iter().enumerate() {
        let s = read_sums(p)?;
        recorded.push(s.pixel.clone());
        // a shard of unknown analysis cannot be checked against the others
        // (the merge keeps the analysis all shards share)
        if let Some(acc) = &sums
            && s.analysis.is_some() != acc.analysis.is_some()
        {
            let first = args.sums[0].display();
            let what = if s.analysis.is_some() {
                format!("records its analysis and {first} does not (sums of an older version)")
            } else {
                format!("records no analysis (sums of an older version) and {first} does")
            };
            return Err(Error::format(
                p,
                format!(
                    "{what}: cannot check that they come from the same analysis; merge only \
                     shards without the record, or re-analyse"
                ),
            ));
        }
        owner.extend(std::iter::repeat_n(f, s.images.len()));
        match &mut sums {
            None => sums = Some(s),
            Some(acc) => acc.merge(&s).map_err(|e| {
                Error::format(p, format!("does not match {}: {e}", args.sums[0].display()))
            })?,
        }
    }
    let mut sums = sums.expect("at least one file");
    let (px, px_warnings) = args.pixel.resolve_recorded(&recorded, &args.sums)?;
    sums.pixel = px.as_ref().map(PixelSize::record);
    check_duplicate_images(&args.sums, &owner, &sums)?;
    // the grid's octaves (its last scale is one voice short of them), as
    // `analyze --fit` is checked
    let (span, step) = sums.grid_span();
    let fit = match &args.fit {
        Some(f) => parse_range("fit", f)?,
        // analyze's default for the whole octaves and the voices of the sums
        None => sums.default_fit()?,
    };
    // older sums.json record no voices: the grid step is the scales' ratio
    check_fit(
        fit,
        (span * 1e6).round() / 1e6,
        step,
        ", the scales of these sums",
    )?;
    // the preset's name when one is given, as analyze labels it
    let theory = args
        .model_opts
        .resolve_optional(args.theory)?
        .map(|r| (r.model, r.preset.unwrap_or(r.model.name())));
    let rule = args.rule;
    let other = if rule == Rule::Plain {
        Rule::Sup
    } else {
        Rule::Plain
    };
    let mut s = sums.spectra(rule, fit)?;
    let o = sums.spectra(other, fit)?;
    let mut warnings = Vec::new();
    if sums.analysis.is_none() {
        warnings.push(
            "no shard records its analysis (sums of an older version): the shards' analyses \
             (wavelet, scales, margin, linking) cannot be compared"
                .to_string(),
        );
    }
    warnings.extend(
        px.as_ref()
            .and_then(|p| p.warning(super::Isotropic::Wavelet)),
    );
    warnings.extend(px_warnings);
    // recorded in spectra.json with the fit's warnings
    s.warnings.extend(warnings);
    PixelSize::say_note(px.as_ref(), quiet);
    make_out_dir(&args.out.out)?;
    let curves = theory
        .map(|(m, name)| theory_curves(&m, name, &s.q))
        .transpose()?;
    // the analysis the shards share (null when no shard records it)
    let params = json!({"sums": super::common::paths_json(&args.sums), "analysis": sums.analysis, "fit_octaves": fit,
        "rule": rule, "theory": theory.map(|(m, _)| m), "pixel_size": px.as_ref().map(PixelSize::json)});
    write_outputs(
        &args.out.out,
        "merge",
        params,
        &sums,
        &s,
        &o,
        curves.as_ref(),
    )?;
    show!(
        "{}",
        super::analyze_cmd::summary("merge", &s, &sums, px.as_ref())
    );
    // the fit's warnings too (poor fits, too few lines), as analyze prints them
    for w in &s.warnings {
        say!("warning: {w}");
    }
    if !quiet {
        say!(
            "merged {} from {} into {}",
            super::common::count_of(s.images, "image"),
            super::common::count_of(args.sums.len(), "file"),
            args.out.out.display()
        );
    }
    Ok(Outcome::Ok)
}

/// What `merge` reads, for the message about a file that is not one.
const SUMS_FILES: &str = "merge reads the sums.json (partition sums) that analyze, validate, \
demo and merge write, and compare in its wtmm/";

/// [`PartitionSums::read_json`], whose refusal of a file that is no
/// partition sums at all (another output of wtmm, often) says which file
/// that is and which merge wants, serde's detail last.
fn read_sums(p: &Path) -> Result<PartitionSums> {
    PartitionSums::read_json(p).map_err(|e| match e {
        Error::Format { path, reason } => {
            match reason.strip_prefix("not a partition-sums file: ") {
                Some(detail) => Error::format(&path, not_sums(&path, detail)),
                None => Error::Format { path, reason },
            }
        }
        e => e,
    })
}

/// "not a partition-sums file (the spectra.json of `wtmm analyze`): merge
/// reads ...; DIR/sums.json is beside it; the JSON reader said: DETAIL".
fn not_sums(path: &Path, detail: &str) -> String {
    let json = std::fs::read_to_string(path)
        .ok()
        .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok());
    // no JSON at all: a file cut short (a copy interrupted) or damaged
    let Some(json) = json else {
        return format!(
            "not valid JSON (cut short or damaged?): {SUMS_FILES}; the JSON reader said: {detail}"
        );
    };
    // another output of wtmm carries the command that wrote it
    let command = json["command"].as_str().map(String::from);
    let file = path.file_name().map(|f| f.to_string_lossy().into_owned());
    let what = match (command, file) {
        (Some(c), Some(f)) => format!(" (the {f} of `wtmm {c}`)"),
        _ => String::new(),
    };
    let beside = path.with_file_name("sums.json");
    let beside = if beside.is_file() && path.file_name() != beside.file_name() {
        format!("; {} is beside it", beside.display())
    } else {
        String::new()
    };
    format!("not a partition-sums file{what}: {SUMS_FILES}{beside}; the JSON reader said: {detail}")
}

/// The same image in two shards (the same line counts and sums, whatever
/// its label: a copy analysed under another name, as analyze refuses for
/// files of the same content) would be counted twice: an error naming both
/// files. Labels alone may repeat (they are free file names); images that
/// kept no line are not compared, nor images of one file (analyze has
/// compared their files; an image and its negative have the same sums).
/// `owner[i]` is the file of image `i`.
fn check_duplicate_images(paths: &[PathBuf], owner: &[usize], sums: &PartitionSums) -> Result<()> {
    let mut seen: HashMap<&[u64], Vec<(usize, &ImagePartial)>> = HashMap::new();
    for (&f, im) in owner.iter().zip(&sums.images) {
        if im.lines.iter().all(|&n| n == 0) {
            continue;
        }
        let same = seen.entry(im.lines.as_slice()).or_default();
        if let Some((g, o)) = same.iter().find(|(g, o)| {
            *g != f && same_cells(&o.plain, &im.plain) && same_cells(&o.sup, &im.sup)
        }) {
            let label = if o.label == im.label {
                format!("image {:?}", im.label)
            } else {
                format!("image {:?} (as {:?} there)", im.label, o.label)
            };
            let there = format!("also in {}", paths[*g].display());
            return Err(Error::format(
                &paths[f],
                format!(
                    "{label} is {there}, with the same line counts and sums (to 1e-9: a copy, \
                     or the image flipped or transposed): one image twice would pass for two \
                     independent samples and shrink the error bars"
                ),
            ));
        }
        same.push((f, im));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use crate::spectra::{Cell, same_cells};

    fn cell(e: i32, z: f64, zl: f64, z2: f64) -> Cell {
        Cell { e, z, zl, z2 }
    }

    /// Rounding of a `zl` that cancels (log2 M straddling 0) is no
    /// difference: measured against `z`, not against `zl` itself.
    #[test]
    fn a_cancelled_log_sum_rounds_alike() {
        let a = [cell(3, 1.5, 2.0e-15, 0.9)];
        let b = [cell(3, 1.5, -1.0e-15, 0.9)];
        assert!(same_cells(&a, &b));
        // an exponent one apart, values halved/doubled to match
        let c = [cell(4, 0.75, 0.5e-15, 0.225)];
        assert!(same_cells(&a, &c));
        // weighted means of log2 M 1e-6 apart are two images
        let d = [cell(3, 1.5, 1.5e-6, 0.9)];
        assert!(!same_cells(&a, &d));
        // and so are sums 1e-6 apart
        let f = [cell(3, 1.5 * (1.0 + 1e-6), 2.0e-15, 0.9)];
        assert!(!same_cells(&a, &f));
    }
}
