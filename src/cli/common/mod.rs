//! Shared CLI plumbing: lists of numbers, output directories, JSON headers,
//! progress bars that stay quiet in scripts.

use std::io::IsTerminal;
use std::path::{Path, PathBuf};

use indicatif::{ProgressBar, ProgressStyle};

use crate::error::{Error, Result};
use crate::field::Field;
pub use crate::field::HoleSizes;
pub use crate::io::write_json;
use crate::io::{ReadInfo, read_field_with_info, write_atomic};

mod memory;
pub use memory::{
    ENSEMBLE_ANALYSIS_BYTES_PER_PIXEL, TM_ENSEMBLE_BYTES_PER_PIXEL, available_memory,
    check_cwt_memory, check_ensemble_memory, check_generated, check_generated_memory,
    check_generated_side, check_image_memory, check_memory, check_memory_variable,
    check_spectrum_memory, check_tm_memory, ensemble_memory_workers, memory_workers,
};

/// Most values a list option takes. Each value costs a pass over the data
/// (a moment order, a scale) and a column of every output: 100 001 orders
/// of `analyze --q` on two 128^2 images took 3.2 GB and 41 s, and 10 000
/// structure-function orders of `tm` 40 s on a 128^2 DEM. The published
/// grids hold 31 (q in [-6, 9] by 0.5); 2000 is -100:100:0.1.
pub const MAX_LIST: usize = 2001;

/// Parses `start:stop:step` (inclusive) or `a,b,c`, returned ascending;
/// a value given twice is an error, and so are more than [`MAX_LIST`].
pub fn parse_list(flag: &str, s: &str) -> Result<Vec<f64>> {
    let bad = |why: &str| Error::param(flag, format!("`{s}`: {why}"));
    let num = |t: &str| t.trim().parse::<f64>().map_err(|_| bad("not a number"));
    let parts: Vec<&str> = s.split(':').collect();
    let v = match parts.len() {
        1 => s.split(',').map(num).collect::<Result<Vec<f64>>>()?,
        3 => {
            let (a, b, st) = (num(parts[0])?, num(parts[1])?, num(parts[2])?);
            if ![a, b, st].iter().all(|v| v.is_finite()) {
                return Err(bad("start, stop and step must be finite"));
            }
            if !(st > 0.0) || b < a {
                return Err(bad("need start <= stop and step > 0"));
            }
            let n = ((b - a) / st + 1e-9).floor();
            if n + 1.0 > MAX_LIST as f64 {
                return Err(bad(&format!(
                    "{} values, at most {MAX_LIST} (each costs a pass over the data): use a \
                     larger step",
                    crate::error::short(n + 1.0)
                )));
            }
            let n = n as usize;
            // a + i st is inexact in binary (-0.3 + 3 x 0.1 = 5.6e-17, not
            // 0): rounded to 12 significant digits, the decimal grid meant
            (0..=n)
                .map(|i| {
                    let x = a + i as f64 * st;
                    if x.abs() < 1e-9 * st {
                        0.0
                    } else {
                        format!("{x:.11e}").parse().expect("a formatted f64")
                    }
                })
                .collect()
        }
        _ => return Err(bad("use start:stop:step or a,b,c")),
    };
    if v.is_empty() || v.iter().any(|x| !x.is_finite()) {
        return Err(bad("empty or non-finite"));
    }
    if v.len() > MAX_LIST {
        return Err(bad(&format!("{} values, at most {MAX_LIST}", v.len())));
    }
    // ascending and distinct: the Legendre transform takes differences of
    // neighbouring q, and a repeated value would count twice
    let mut v = v;
    v.sort_by(f64::total_cmp);
    if let Some(w) = v.windows(2).find(|w| w[1] - w[0] < 1e-9) {
        return Err(bad(&if w[1] == w[0] {
            format!("{} is given twice", w[0])
        } else {
            format!(
                "{} and {} are closer than 1e-9 (the Legendre transform divides by their \
                 difference)",
                w[0], w[1]
            )
        }));
    }
    Ok(v)
}

/// Largest |q| a moment order may have. `q log2 M` with `|log2 M|` up to
/// ~1000 stays far inside f64 for any |q| below it, and no ensemble of
/// images resolves moments anywhere near it (the spectra warn from
/// |q| ~ 5-10 on 32 images of 1024^2); larger values only overflow.
pub const Q_LIMIT: f64 = 1000.0;

/// [`parse_list`] for moment orders: |q| <= [`Q_LIMIT`].
pub fn parse_q(flag: &str, s: &str) -> Result<Vec<f64>> {
    let v = parse_list(flag, s)?;
    if let Some(q) = v.iter().find(|q| q.abs() > Q_LIMIT) {
        return Err(Error::param(
            flag,
            format!(
                "`{s}`: {} is beyond |q| = {Q_LIMIT} (moments that far only overflow)",
                crate::error::short(*q)
            ),
        ));
    }
    Ok(v)
}

/// Parses `LO:HI` into two numbers with LO < HI.
pub fn parse_range(flag: &str, s: &str) -> Result<(f64, f64)> {
    let bad = || Error::param(flag, format!("`{s}`: use LO:HI with LO < HI"));
    let (a, b) = s.split_once(':').ok_or_else(bad)?;
    let (a, b) = (
        a.trim().parse::<f64>().map_err(|_| bad())?,
        b.trim().parse::<f64>().map_err(|_| bad())?,
    );
    if !(a < b) {
        return Err(bad());
    }
    Ok((a, b))
}

/// Reads every image up front, so that a bad file stops the command before
/// anything is written.
pub fn read_all(paths: &[PathBuf], nodata: Option<f64>) -> Result<Vec<Field>> {
    if paths.is_empty() {
        return Err(Error::param("IMAGE", "no image given"));
    }
    paths.iter().map(|p| read_image(p, nodata)).collect()
}

/// The message of an error about the data, without the `invalid input: `
/// prefix (for a message that names the input itself).
pub fn reason(e: Error) -> String {
    match e {
        Error::Input(m) => m,
        other => other.to_string(),
    }
}

/// An error met while working on the file `path`, named by it:
/// `path: why` (one form for every command).
pub fn in_file(path: &Path, e: Error) -> Error {
    Error::format(path, reason(e))
}

/// Image files that `wtmm synth` wrote from a periodic model (W-cascade,
/// FISC, FIF): the tori `validate` analyses whole.
#[derive(Clone, Debug, PartialEq)]
pub struct PeriodicSynth {
    /// The `synth.json` files that list the images.
    pub records: Vec<PathBuf>,
    /// The models' names, each once ("wcascade").
    pub models: Vec<String>,
    /// The wavelet the records recommend for their models (mexican for
    /// FISC, as `validate` uses), when they all agree.
    pub wavelet: Option<crate::cwt::Wavelet>,
}

impl PeriodicSynth {
    /// What `params` records about the inputs' origin.
    pub fn json(&self) -> serde_json::Value {
        serde_json::json!({"periodic": true, "synth_json": paths_json(&self.records), "models": self.models,
            "recommended_wavelet": self.wavelet})
    }

    /// "the 8 images are periodic wcascade fields written by `wtmm synth`
    /// (wc/synth.json)", for a note.
    pub fn describe(&self, n: usize) -> String {
        let recs: Vec<String> = self
            .records
            .iter()
            .map(|p| p.display().to_string())
            .collect();
        format!(
            "{} periodic {} {} written by `wtmm synth` ({})",
            if n == 1 {
                "the image is a".to_string()
            } else {
                format!("the {n} images are")
            },
            self.models.join(" and "),
            if n == 1 { "field" } else { "fields" },
            recs.join(", ")
        )
    }
}

/// The periodic `synth` origin of `paths`, when every one of them is listed
/// in the `synth.json` beside it, that record names a periodic model
/// ([`crate::theory::Model::is_periodic`]), and the file is not newer than
/// the record (`synth` writes its record last: a file changed since is no
/// longer what the record describes). `None` otherwise, and for any file
/// or record that cannot be read: the commands then keep the defaults of
/// non-periodic data, which are valid on a torus too, only wasteful. When
/// some inputs qualify and one does not (a stale file of an earlier run, a
/// file changed since, another model), a note names it, since the others
/// then lose their periodic defaults too: `lost` says what they get
/// instead and the flags that choose otherwise (`None`: the caller's flags
/// already chose them), and with `wavelet_open` (no `--wavelet`) the
/// wavelet a qualifying record recommends, when not gauss, is named too.
///
/// Why: analysed inside the margin, a periodic field loses half its maxima
/// and its spectrum a taper's worth of power (SPEC §1, §14), and the same
/// files then read differently from `validate`'s in-memory ensemble.
///
/// Trusted, not verified: the record's file list, size and times (a file
/// of the recorded shape put in place with an older time, `cp -p`,
/// passes; a file of another shape does not).
pub fn periodic_synth(
    paths: &[PathBuf],
    lost: Option<&str>,
    wavelet_open: bool,
) -> Option<PeriodicSynth> {
    use std::collections::BTreeMap;
    struct Record {
        shown: PathBuf,
        files: Vec<String>,
        model: crate::theory::Model,
        wavelet: Option<crate::cwt::Wavelet>,
        time: std::time::SystemTime,
        /// The side of the square fields (`params.size`).
        size: Option<usize>,
    }
    let read = |rec: &Path| -> Option<Record> {
        let time = std::fs::metadata(rec).ok()?.modified().ok()?;
        let v: serde_json::Value = serde_json::from_slice(&std::fs::read(rec).ok()?).ok()?;
        if v["command"] != "synth" {
            return None;
        }
        let files = v["files"]
            .as_array()?
            .iter()
            .map(|f| f.as_str().map(str::to_string))
            .collect::<Option<Vec<_>>>()?;
        let model = serde_json::from_value(v["params"]["model"].clone()).ok()?;
        let wavelet = serde_json::from_value(v["theory"]["recommended_wavelet"].clone()).ok();
        let size = v["params"]["size"].as_u64().map(|n| n as usize);
        Some(Record {
            shown: rec.to_path_buf(),
            files,
            model,
            wavelet,
            time,
            size,
        })
    };
    // one record per directory (however its path is spelled), read once
    let mut records: BTreeMap<PathBuf, Option<Record>> = BTreeMap::new();
    let mut used: Vec<PathBuf> = Vec::new();
    let (mut ok, mut broken): (usize, Option<String>) = (0, None);
    for p in paths {
        let dir = match p.parent() {
            Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
            _ => PathBuf::from("."),
        };
        let rec = dir.join("synth.json");
        let key = std::fs::canonicalize(&dir)
            .unwrap_or(dir)
            .join("synth.json");
        let entry = records.entry(key.clone()).or_insert_with(|| read(&rec));
        let name = p.file_name().and_then(|n| n.to_str()).unwrap_or("");
        let why = (|| {
            let Some(r) = entry.as_ref() else {
                return Some("without a synth.json of `wtmm synth` beside it".to_string());
            };
            if !r.files.iter().any(|f| f == name) {
                return Some(format!(
                    "not listed in {} (left by an earlier run?)",
                    r.shown.display()
                ));
            }
            if !r.model.is_periodic() {
                return Some(format!("from a non-periodic model ({})", r.model.name()));
            }
            // a file of another shape is not the recorded torus (cropped,
            // or put in place with an older time); unreadable ones are
            // refused later, by the command's own reading
            if let Some(n) = r.size {
                match crate::io::read_shape(p) {
                    Ok(s) if s == [n, n] => {}
                    Ok([ny, nx]) => {
                        return Some(format!(
                            "{ny} x {nx} px, not the {n} x {n} its {} records",
                            r.shown.display()
                        ));
                    }
                    Err(_) => return Some("unreadable".to_string()),
                }
            }
            let newer = std::fs::metadata(p)
                .and_then(|m| m.modified())
                .map_or(true, |t| t > r.time);
            newer.then(|| {
                format!(
                    "newer than {} (changed since synth wrote it?)",
                    r.shown.display()
                )
            })
        })();
        match why {
            None => {
                ok += 1;
                if !used.contains(&key) {
                    used.push(key);
                }
            }
            Some(w) => {
                broken.get_or_insert_with(|| format!("{} is {w}", p.display()));
            }
        }
    }
    if let Some(b) = broken {
        // the wavelet the qualifying inputs' records recommend (mexican for
        // FISC), lost with them
        let wavelet = used
            .iter()
            .filter_map(|k| records[k].as_ref().and_then(|r| r.wavelet))
            .find(|&w| wavelet_open && w != crate::cwt::Wavelet::Gauss)
            .map(|w| {
                format!("the gauss wavelet, not the {w} their synth.json recommends: --wavelet {w}")
            });
        let lost: Vec<String> = lost
            .map(str::to_string)
            .into_iter()
            .chain(wavelet)
            .collect();
        if ok > 0 && !lost.is_empty() {
            say!(
                "note: {b}, so all {} inputs are read as non-periodic data ({}), though {ok} of \
                 them {} of `wtmm synth`",
                paths.len(),
                lost.join("; "),
                if ok == 1 {
                    "is a periodic field"
                } else {
                    "are periodic fields"
                }
            );
        }
        return None;
    }
    if paths.is_empty() {
        return None;
    }
    let recs: Vec<&Record> = used.iter().filter_map(|k| records[k].as_ref()).collect();
    let mut models: Vec<String> = Vec::new();
    for r in &recs {
        if !models.contains(&r.model.name().to_string()) {
            models.push(r.model.name().to_string());
        }
    }
    let wavelet = recs[0]
        .wavelet
        .filter(|w| recs.iter().all(|r| r.wavelet == Some(*w)));
    Some(PeriodicSynth {
        records: recs.iter().map(|r| r.shown.clone()).collect(),
        models,
        wavelet,
    })
}

/// Refuses, before any image is generated, a `size` whose interior at the
/// analysis margin is empty (`validate`, `compare`: the images are made
/// for the analysis, so `--size` is what to change).
pub fn check_generated_size(cfg: &crate::skeleton::AnalysisConfig, size: usize) -> Result<()> {
    let margin = cfg.margin_px();
    if 2 * margin >= size {
        let a_max = cfg.scale_list().last().copied().unwrap_or(0.0);
        return Err(Error::param(
            "size",
            format!(
                "{size} px is too small for the analysis: the interior margin is {margin} px on \
                 each side at the largest scale {a_max:.1} px, so the images need more than {} px \
                 (or fewer --octaves)",
                2 * margin
            ),
        ));
    }
    Ok(())
}

/// `--nodata` ([`super::ReadOpts`]): masks the pixels equal to `nodata`
/// as the file stores it; what to say when none is.
pub fn apply_nodata(field: &mut Field, info: &ReadInfo, nodata: Option<f64>) -> Option<String> {
    let v = nodata?;
    (field.mask_value(crate::io::as_stored(v, &info.dtype)) == 0).then(|| {
        format!(
            "no pixel equals --nodata {} (as the file stores it)",
            crate::error::short(v)
        )
    })
}

/// An image for analysis: [`read_field_with_info`], its warnings (a colour
/// image converted to luminance, an unreadable nodata tag, pages or bytes
/// not read) said on stderr with the file's name, the pixels equal to
/// `nodata` (`--nodata`, [`super::ReadOpts`]) masked, with a warning when
/// none is, and an error naming the file when every pixel is missing (the library accepts such a field; no
/// command can use it) or the values are beyond f64's squares.
pub fn read_image(path: &Path, nodata: Option<f64>) -> Result<Field> {
    read_image_with(path, nodata, &mut |w| say!("{w}"))
}

/// [`read_image`] of image `i` of several read in parallel: its warnings
/// go to `notes`, said in input order once all are read.
pub fn read_image_noted(
    path: &Path,
    nodata: Option<f64>,
    i: usize,
    notes: &OrderedNotes,
) -> Result<Field> {
    read_image_with(path, nodata, &mut |w| notes.push(i, w))
}

/// `--fill-holes` (analyze, pdf, kernel, correlate): `field` with its
/// missing pixels filled harmonically ([`Field::filled_harmonic`]; across
/// the borders on a `torus`, [`Field::filled_harmonic_torus`]) and the
/// number filled, with a warning for image `i` in `notes` naming `path`,
/// the count, the share, the largest hole and the bound on tau(3)'s bias
/// ([`HoleSizes::brief`]: the command's warning on the ensemble explains,
/// [`HoleSizes::describe`]); with its holes as counted, so that a tally
/// need not label them again. A field without holes passes unchanged.
/// A lone image (`alone`) gets no note: the ensemble's warning says the
/// same of it, with the explanation.
///
/// **Errors** naming the file if no pixel is valid.
pub fn fill_holes_noted(
    field: Field,
    path: &Path,
    torus: bool,
    (i, alone): (usize, bool),
    notes: &OrderedNotes,
) -> Result<(Field, HoleSizes)> {
    let holes = HoleSizes::of(&field, torus);
    if holes.missing == 0 {
        return Ok((field, holes));
    }
    if !alone {
        notes.push(
            i,
            format!(
                "warning: {}: {} missing pixels filled harmonically{} and counted as data \
                 (--fill-holes; {})",
                path.display(),
                holes.missing,
                if torus {
                    " across the borders (a torus)"
                } else {
                    ""
                },
                holes.brief()
            ),
        );
    }
    let data = field
        .filled_harmonic_on(torus)
        .map_err(|e| in_file(path, e))?;
    Ok((Field::new(data), holes))
}

/// Warnings of images read in parallel, held back and said in the order
/// of the images (not the order the threads happened to finish in), so
/// that two runs print the same log.
#[derive(Default)]
pub struct OrderedNotes(std::sync::Mutex<Vec<(usize, String)>>);

impl OrderedNotes {
    /// Notes `w` for image `i`.
    pub fn push(&self, i: usize, w: String) {
        self.0
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .push((i, w));
    }

    /// Says every note, image by image (each image's in the order noted).
    pub fn say(self) {
        self.say_upto(None)
    }

    /// Says the notes of images up to `last` (all with `None`): after a
    /// failure at `last`, whether later images ran, and so noted, depends
    /// on the scheduling.
    pub fn say_upto(self, last: Option<usize>) {
        let mut v = self.0.into_inner().unwrap_or_else(|e| e.into_inner());
        v.sort_by_key(|&(i, _)| i);
        for (_, w) in v.into_iter().filter(|(i, _)| last.is_none_or(|l| *i <= l)) {
            say!("{w}");
        }
    }
}

/// [`read_image`] with its warnings (whole lines) given to `note`.
fn read_image_with(
    path: &Path,
    nodata: Option<f64>,
    note: &mut dyn FnMut(String),
) -> Result<Field> {
    let (mut field, info) = read_field_with_info(path)?;
    for w in &info.warnings {
        note(format!("warning: {}: {w}", path.display()));
    }
    if let Some(w) = apply_nodata(&mut field, &info, nodata) {
        note(format!("warning: {}: {w}", path.display()));
    }
    if field.valid_count() == 0 {
        return Err(Error::format(
            path,
            "every pixel is missing (NaN or nodata)",
        ));
    }
    if let Some(why) = field.amplitude_problem() {
        return Err(Error::format(path, why));
    }
    Ok(field)
}

/// An error naming `path` when every valid pixel of `field` has the same
/// value (`what` says what that makes zero).
pub fn refuse_constant(field: &Field, path: &Path, what: &str) -> Result<()> {
    match field.range() {
        Some((lo, hi)) if lo == hi => Err(Error::format(path, format!("constant image: {what}"))),
        _ => Ok(()),
    }
}

/// Creates the output directory (and parents), noting the ones it created
/// so that a failed or interrupted command removes them again if empty.
pub fn make_out_dir(dir: &Path) -> Result<()> {
    let created: Vec<PathBuf> = dir
        .ancestors()
        .take_while(|a| !a.as_os_str().is_empty() && !a.exists())
        .map(Path::to_path_buf)
        .collect();
    std::fs::create_dir_all(dir).map_err(|source| Error::Write {
        path: dir.into(),
        source,
    })?;
    super::note_created(created);
    Ok(())
}

/// The analysis configuration as recorded in the outputs, with the margin
/// resolved to the pixels used (`margin_default` says it was the default
/// for the wavelet and the largest scale) instead of `null`.
pub fn analysis_json(cfg: &crate::skeleton::AnalysisConfig) -> serde_json::Value {
    let mut v = serde_json::json!(cfg);
    v["margin_default"] = serde_json::json!(cfg.margin.is_none());
    v["margin"] = serde_json::json!(cfg.margin_px());
    v
}

/// CSV from a header and rows, written atomically.
pub fn write_csv(path: &Path, header: &[&str], rows: &[Vec<String>]) -> Result<()> {
    let line = |fields: &mut dyn Iterator<Item = &str>| -> String {
        fields.map(csv_field).collect::<Vec<_>>().join(",")
    };
    let mut s = line(&mut header.iter().copied());
    s.push('\n');
    for r in rows {
        s.push_str(&line(&mut r.iter().map(String::as_str)));
        s.push('\n');
    }
    write_atomic(path, s.as_bytes())
}

/// A CSV field, quoted as RFC 4180 says when it holds a comma, a quote or a
/// line break (file names, methods such as `spectrum, angle-integrated`).
fn csv_field(v: &str) -> std::borrow::Cow<'_, str> {
    if v.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", v.replace('"', "\"\"")).into()
    } else {
        v.into()
    }
}

/// Formats a float for CSV (full precision, `nan` for NaN).
pub fn f(v: f64) -> String {
    if v.is_finite() {
        format!("{v}")
    } else {
        "nan".into()
    }
}

/// A progress bar on a terminal, hidden in scripts or with `--quiet`.
pub fn progress(len: u64, msg: &str, quiet: bool) -> ProgressBar {
    if quiet || !std::io::stderr().is_terminal() {
        return ProgressBar::hidden();
    }
    let pb = ProgressBar::new(len);
    pb.set_style(
        ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} {elapsed_precise} eta {eta}")
            .expect("static template")
            .progress_chars("=> "),
    );
    pb.set_message(msg.to_string());
    *ACTIVE_BAR.lock().unwrap_or_else(|e| e.into_inner()) = Some(pb.downgrade());
    pb
}

/// The progress bar drawn last ([`progress`]), while it lives: messages
/// are written above it ([`super::emit`]).
static ACTIVE_BAR: std::sync::Mutex<Option<indicatif::WeakProgressBar>> =
    std::sync::Mutex::new(None);

/// [`ACTIVE_BAR`] if it is still drawn.
pub(crate) fn active_bar() -> Option<ProgressBar> {
    let bar = ACTIVE_BAR
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .as_ref()?
        .upgrade()?;
    (!bar.is_finished()).then_some(bar)
}

/// A file's name without its directories, for titles.
pub fn file_label(p: &std::path::Path) -> String {
    p.file_name()
        .map_or_else(|| p.display().to_string(), |f| f.to_string_lossy().into())
}

/// ", plane removed" after a title's data when `--detrend plane` was
/// given (the figure is then not of the method as published), else "".
pub fn trend_label(t: crate::field::Trend) -> &'static str {
    match t {
        crate::field::Trend::None => "",
        crate::field::Trend::Plane => ", plane removed",
    }
}

/// The data behind a figure, for its title: the file (or first .. last
/// files) when the images are files, their number and size
/// ("levi_fell_dem.npy, 1 x 400^2"; "a.npy .. d.npy, 4 x 512^2"; "big/a.npy
/// .. small/b.npy, 6 x mixed sizes" from two directories; generated images
/// have labels without an extension and are not named).
pub fn data_label(
    labels: &[impl AsRef<std::path::Path>],
    images: usize,
    shapes: &[crate::spectra::ShapeCount],
) -> String {
    let sizes = match shapes {
        [one] if one.ny == one.nx => format!("{}^2", one.nx),
        [one] => format!("{}x{}", one.ny, one.nx),
        _ => "mixed sizes".into(),
    };
    let file = |l: &dyn AsRef<std::path::Path>| {
        let p = l.as_ref();
        p.extension().map(|_| file_label(p))
    };
    // files from more than one directory: each named with its directory,
    // as "fbm_0000.npy .. fbm_0001.npy" would pass for one run of files
    let dirs = labels
        .iter()
        .map(|l| l.as_ref().parent())
        .collect::<std::collections::HashSet<_>>()
        .len();
    let with_dir = |l: &dyn AsRef<std::path::Path>| {
        let p = l.as_ref();
        let name = file(l)?;
        Some(match p.parent().and_then(|d| d.file_name()) {
            Some(d) if dirs > 1 => format!("{}/{name}", d.to_string_lossy()),
            _ => name,
        })
    };
    let files = match labels {
        [one] => file(one).map(|f| format!("{f}, ")),
        [first, .., last] => with_dir(first)
            .zip(with_dir(last))
            .map(|(a, b)| format!("{a} .. {b}, ")),
        [] => None,
    }
    .unwrap_or_default();
    format!("{files}{images} x {sizes}")
}

thread_local! {
    /// The command line being run (set by `run_from` on the thread that
    /// parses it and writes the outputs; tests run commands in parallel
    /// threads, so it is not process-wide).
    static COMMAND_LINE: std::cell::RefCell<Option<Vec<String>>> =
        const { std::cell::RefCell::new(None) };
}

/// Records `args` as the command line of the outputs this thread writes
/// until the guard drops.
pub(super) fn record_command_line(args: Vec<String>) -> CommandLineGuard {
    COMMAND_LINE.with(|c| *c.borrow_mut() = Some(args));
    CommandLineGuard
}

/// Clears the recorded command line when dropped.
pub(super) struct CommandLineGuard;

impl Drop for CommandLineGuard {
    fn drop(&mut self) {
        COMMAND_LINE.with(|c| *c.borrow_mut() = None);
    }
}

thread_local! {
    /// `--svg`: every plot also as SVG beside its PNG (per thread, as the
    /// command line: the plots are drawn on the thread that runs the
    /// command).
    static ALSO_SVG: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

/// Makes this thread's plots also SVG (`--svg`) until the guard drops.
pub(super) fn also_svg(on: bool) -> AlsoSvgGuard {
    ALSO_SVG.with(|c| c.set(on));
    AlsoSvgGuard
}

/// Turns `--svg` off again when dropped.
pub(super) struct AlsoSvgGuard;

impl Drop for AlsoSvgGuard {
    fn drop(&mut self) {
        ALSO_SVG.with(|c| c.set(false));
    }
}

/// Whether `--svg` is on for this thread's plots.
pub fn svg_too() -> bool {
    ALSO_SVG.with(|c| c.get())
}

/// [`crate::plot::save_chart`] to `path` (a `.png`), and with `--svg` the
/// same chart as vector graphics beside it (`.svg`), for a paper's figures.
pub fn save_chart(chart: &crate::plot::Chart, path: &Path) -> Result<()> {
    crate::plot::save_chart(chart, path)?;
    if svg_too() {
        crate::plot::save_chart(chart, &path.with_extension("svg"))?;
    }
    Ok(())
}

/// [`crate::plot::save_raster_chart`] as [`save_chart`]: with `--svg`
/// also an SVG (axes and text as vectors, the raster embedded).
pub fn save_raster_chart(
    raster: &crate::plot::Raster,
    spec: &crate::plot::RasterChart,
    path: &Path,
) -> Result<()> {
    crate::plot::save_raster_chart(raster, spec, path)?;
    if svg_too() {
        crate::plot::save_raster_chart(raster, spec, &path.with_extension("svg"))?;
    }
    Ok(())
}

/// A path for a JSON record: as text, lossily (U+FFFD) where it is not
/// UTF-8. serde refuses such a `Path`, and `json!` would panic on it.
pub fn path_json(p: &Path) -> serde_json::Value {
    serde_json::Value::String(p.to_string_lossy().into_owned())
}

/// [`path_json`] of each path.
pub fn paths_json<P: AsRef<Path>>(ps: &[P]) -> serde_json::Value {
    ps.iter().map(|p| path_json(p.as_ref())).collect()
}

/// The provenance every JSON output starts with: version, build, the
/// command and its parameters, and the command line as typed (`demo` runs
/// `validate`, whose parameters it records; the command line says so).
pub fn header(command: &str, params: serde_json::Value) -> serde_json::Value {
    let mut h = serde_json::json!({"version": crate::VERSION, "build": crate::BUILD, "command": command, "params": params});
    if let Some(cl) = COMMAND_LINE.with(|c| c.borrow().clone()) {
        h["command_line"] = serde_json::json!(cl);
    }
    h
}

/// Writes `caveats` ([`crate::theory::Model::caveats`]) into an output's
/// JSON when the model has any.
pub fn note_caveats(body: &mut serde_json::Value, model: Option<&crate::theory::Model>) {
    let caveats = model.map(|m| m.caveats()).unwrap_or_default();
    if !caveats.is_empty() {
        body["caveats"] = serde_json::json!(caveats);
    }
}

/// `v ± se` with `prec` decimals, or `v` alone when the error is unknown
/// (a jackknife needs 3 images), for figure titles. An error below one
/// unit of the last decimal gets the decimals for two significant digits
/// (both numbers, up to 12 decimals), so no error bar of 1e-12 or more
/// reads "± 0.000".
pub fn plus_minus(v: f64, se: f64, prec: usize) -> String {
    if se.is_finite() {
        let prec = if se > 0.0 && se < 10f64.powi(-(prec as i32)) {
            // at most 12: an error of 1e-300 is not worth 300 digits
            ((-se.log10()).ceil() as usize + 1).clamp(prec, prec.max(12))
        } else {
            prec
        };
        format!("{} ± {se:.prec$}", fixed(v, prec))
    } else {
        fixed(v, prec)
    }
}

/// `v` with `prec` decimals, for figures: a value that rounds to zero
/// reads "0.0000", not "-0.0000" (as the axes' ticks do).
pub fn fixed(v: f64, prec: usize) -> String {
    let s = format!("{v:.prec$}");
    match s.strip_prefix('-') {
        Some(rest) if rest.chars().all(|c| c == '0' || c == '.') => rest.to_string(),
        _ => s,
    }
}

/// A model's parameters for a figure's legend or title ("H = 0.33",
/// "α = 1.8, C1 = 0.12, H = 0.7"): a theory curve says which theory.
pub fn model_params_label(model: &crate::theory::Model) -> String {
    use crate::synth::wcascade::Law;
    use crate::theory::Model;
    // up to 4 decimals, trailing zeros dropped
    let n = |v: f64| {
        let s = format!("{v:.4}");
        let s = s.trim_end_matches('0').trim_end_matches('.');
        if s == "-0" {
            "0".to_string()
        } else {
            s.to_string()
        }
    };
    match model {
        Model::Fbm(p) => format!("H = {}", n(p.hurst)),
        Model::Fif(p) => format!("α = {}, C1 = {}, H = {}", n(p.alpha), n(p.c1), n(p.hurst)),
        Model::Fisc(p) => format!("p = {}, H* = {}", n(p.p), n(p.hstar)),
        Model::WCascade(p) => match p.law {
            Law::LogNormal { m, sigma2 } => format!("m = {}, σ² = {}", n(m), n(sigma2)),
            Law::LogPoisson {
                gamma,
                beta,
                lambda,
            } => format!("γ = {}, β = {}, λ = {}", n(gamma), n(beta), n(lambda)),
        },
    }
}

/// `n` and the word, in the plural unless `n` is 1 ("1 image", "3 images").
pub fn count_of(n: usize, word: &str) -> String {
    if n == 1 {
        format!("1 {word}")
    } else {
        format!("{n} {word}s")
    }
}

/// What a figure says of its error bars, from an estimate's
/// `stderr_method` and its number of images: short, with the caveat the
/// warnings give at length ("jackknife over 32 images", "jackknife over 49
/// tiles of 1 image: may understate", "regression: understates").
pub fn se_label(method: &str, images: usize) -> String {
    let head = method.split([';', '(']).next().unwrap_or("").trim();
    // "...; regression for q = 0, c2": some entries kept the regression's
    let some = if method.contains("; regression") {
        ", regression for some (understates)"
    } else {
        ""
    };
    if head.starts_with("regression") {
        "regression: understates".into()
    } else if head.contains("tiles") {
        format!(
            "{head} of {}{some}: may understate",
            count_of(images, "image")
        )
    } else if head == "jackknife over images" {
        format!("jackknife over {images} images{some}")
    } else {
        format!("{head}{some}")
    }
}

#[cfg(test)]
mod tests;
