//! `wtmm synth MODEL ...`: synthetic ensembles written as images plus a
//! `synth.json` recording the model, seeds and theory.

use std::path::Path;

use clap::{Args, ValueEnum};
use serde_json::json;

use super::common::{header, make_out_dir, progress, write_json};
use super::model_args::{ModelName, ModelOpts};
use super::{OutDir, Outcome};
use crate::error::{Error, Result};
use crate::io::{write_npy, write_png16, write_tiff_f32};
use crate::theory::TheoryTable;

#[derive(Args, Debug)]
pub struct SynthArgs {
    /// The generator (or use --preset).
    #[arg(value_enum)]
    pub model: Option<ModelName>,
    #[command(flatten)]
    pub model_opts: ModelOpts,
    #[command(flatten)]
    pub common: SynthCommon,
}

#[derive(Args, Debug)]
pub struct SynthCommon {
    /// Image side in pixels.
    #[arg(long)]
    pub size: usize,
    /// Number of images (at most 10000).
    #[arg(long, default_value_t = 1)]
    pub count: usize,
    /// Seed of the ensemble (image i uses a seed derived from it).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    #[command(flatten)]
    pub out: OutDir,
    /// Image format.
    #[arg(long, value_enum, default_value_t = Format::Npy)]
    pub format: Format,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum Format {
    Npy,
    Tiff,
    /// 16-bit PNG with a JSON sidecar giving the scale and offset.
    Png,
}

impl Format {
    fn ext(self) -> &'static str {
        match self {
            Format::Npy => "npy",
            Format::Tiff => "tif",
            Format::Png => "png",
        }
    }
}

fn write_image(path: &Path, a: &ndarray::Array2<f64>, format: Format) -> Result<()> {
    match format {
        Format::Npy => write_npy(path, a),
        Format::Tiff => write_tiff_f32(path, a),
        Format::Png => write_png16(path, a).map(|_| ()),
    }
}

pub fn run(args: SynthArgs, quiet: bool) -> Result<Outcome> {
    let r = args.model_opts.resolve(args.model)?;
    let c = &args.common;
    // fewer images in flight than threads when the memory holds no more
    // (said in a note)
    let limit = check_common(c)?;
    r.model.check_size(c.size)?;
    let t = TheoryTable::new(&r.model, &[-2.0, -1.0, 0.0, 1.0, 2.0, 3.0])?;
    let caveats = r.model.caveats();
    let theory = json!({"beta": t.beta, "beta_convention": t.beta_convention, "h_of_q0": t.h_of_q0,
        "h_min": t.h_min, "h_max": t.h_max, "recommended_wavelet": r.wavelet, "caveats": caveats});
    let params = json!({"model": r.model, "preset": r.preset});
    let model = r.model;
    generate(c, limit, model.name(), params, theory, quiet, |i| {
        model.synthesize(c.size, c.seed, i as u64)
    })
}

/// Most images one `synth` writes: their names carry four digits.
pub const MAX_COUNT: usize = 10_000;

/// The checks of every model's options; `Some(workers)` when the memory
/// holds fewer images in flight than rayon has threads.
fn check_common(c: &SynthCommon) -> Result<Option<usize>> {
    super::common::check_generated_side(c.size)?;
    if c.count == 0 {
        return Err(Error::param("count", "must be >= 1"));
    }
    if c.count > MAX_COUNT {
        return Err(Error::param(
            "count",
            format!(
                "must be at most {MAX_COUNT}, got {}: the files are numbered with four digits \
                 (`{{stem}}_NNNN`); write a larger ensemble \
                 as several directories with different --seed",
                c.count
            ),
        ));
    }
    // an allocation beyond the machine aborts the process (no message, and
    // the directory left behind): estimate first. The fBm is drawn on a
    // grid twice as large in complex f64 (64 N^2 bytes), the largest case.
    super::common::check_memory(c.size, c.count, 64.0, "synth")
}

/// Generates and writes `count` images in parallel, at most `limit` at
/// once; image `i` depends only on `(seed, i)`, so the files are identical
/// whatever the thread count.
fn generate<F>(
    c: &SynthCommon,
    limit: Option<usize>,
    stem: &str,
    params: serde_json::Value,
    theory: serde_json::Value,
    quiet: bool,
    make: F,
) -> Result<Outcome>
where
    F: Fn(usize) -> Result<ndarray::Array2<f64>> + Sync,
{
    make_out_dir(&c.out.out)?;
    let pb = progress(c.count as u64, "synth", quiet);
    // a refused draw is named by its index in order, whatever the scheduling
    let names: Vec<String> = crate::par::try_map_limited(c.count, limit, |i| {
        let img = make(i)?;
        let name = format!("{stem}_{i:04}.{}", c.format.ext());
        write_image(&c.out.out.join(&name), &img, c.format)?;
        pb.inc(1);
        Ok(name)
    })?;
    pb.finish_and_clear();
    let mut p = params;
    p["size"] = json!(c.size);
    p["count"] = json!(c.count);
    p["seed"] = json!(c.seed);
    p["format"] = json!(c.format.ext());
    let mut body = header("synth", p);
    body["theory"] = theory;
    body["files"] = json!(names);
    // older files this run does not rewrite (an earlier, larger run, or
    // another model, into the same directory) would join a `DIR/*.npy`
    // ensemble unnoticed
    let stale = stale_files(&c.out.out, &names);
    if !stale.is_empty() {
        say!(
            "warning: {} holds {} older file(s) this run did not write (e.g. {}): they are not \
             part of this ensemble (synth.json lists its files); remove them or use a fresh \
             --out{}",
            c.out.out.display(),
            stale.len(),
            stale[..stale.len().min(3)].join(", "),
            super::temp_note(stale.iter().map(String::as_str))
        );
        body["stale_files"] = json!(stale);
    }
    write_json(&c.out.out.join("synth.json"), &body)?;
    Ok(Outcome::Ok)
}

/// The files in `dir` (not its subdirectories) other than `written`, their
/// PNG sidecars, synth.json and hidden files (the staged writes of this
/// run among them) except the staged writes of a killed run, sorted: left
/// by an earlier run.
fn stale_files(dir: &std::path::Path, written: &[String]) -> Vec<String> {
    let Ok(rd) = std::fs::read_dir(dir) else {
        return Vec::new();
    };
    let mut keep: std::collections::HashSet<String> = written.iter().cloned().collect();
    for n in written {
        if let Some(stem) = n.strip_suffix(".png") {
            keep.insert(format!("{stem}.json"));
        }
    }
    keep.insert("synth.json".into());
    let mut v: Vec<String> = rd
        .filter_map(|e| {
            let e = e.ok()?;
            e.file_type().ok()?.is_file().then_some(())?;
            e.file_name().into_string().ok()
        })
        .filter(|n| (!n.starts_with('.') || crate::io::is_foreign_temp(n)) && !keep.contains(n))
        .collect();
    v.sort();
    v
}
