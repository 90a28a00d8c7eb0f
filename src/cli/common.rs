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

/// The environment variable that sets the memory wtmm plans for, in GB.
pub const MEMORY_VAR: &str = "WTMM_MEMORY_GB";

/// The memory a command may use, in bytes: `WTMM_MEMORY_GB` when set (a
/// share of a machine others use too), else [`system_memory`]. `None`
/// where neither can be read (not Linux). A bad `WTMM_MEMORY_GB` reads as
/// unset here: [`check_memory_variable`] refuses it when a command starts.
pub fn available_memory() -> Option<f64> {
    match memory_variable() {
        Ok(Some(b)) => Some(b),
        _ => system_memory(),
    }
}

/// `MemAvailable` of /proc/meminfo, within the process's cgroup memory
/// limit when it has one (a container, a batch job: beyond the limit the
/// process is killed with no message, while /proc/meminfo still shows the
/// host's memory), in bytes.
pub fn system_memory() -> Option<f64> {
    memory_sources().0
}

/// [`system_memory`], and whether the cgroup's limit is what bounds it.
fn memory_sources() -> (Option<f64>, bool) {
    let host = std::fs::read_to_string("/proc/meminfo")
        .ok()
        .and_then(|s| meminfo_available(&s));
    match (host, cgroup_headroom()) {
        (Some(h), Some(c)) => (Some(h.min(c)), c < h),
        (h, c) => (h.or(c), h.is_none() && c.is_some()),
    }
}

/// `WTMM_MEMORY_GB` in bytes, `None` when unset (or set empty).
fn memory_variable() -> Result<Option<f64>> {
    let Some(v) = std::env::var_os(MEMORY_VAR) else {
        return Ok(None);
    };
    let s = v.to_string_lossy();
    if s.trim().is_empty() {
        return Ok(None);
    }
    match s.trim().parse::<f64>() {
        Ok(gb) if gb.is_finite() && gb > 0.0 => Ok(Some(gb * 1e9)),
        _ => Err(Error::param(
            MEMORY_VAR,
            format!(
                "the environment variable must be a positive number of GB (unset, the memory \
                 the system reports is used), not `{s}`"
            ),
        )),
    }
}

/// Refuses a `WTMM_MEMORY_GB` that is not a positive number, before a
/// command starts.
pub fn check_memory_variable() -> Result<()> {
    memory_variable().map(|_| ())
}

/// `X GB are available`, `... (the cgroup's limit; WTMM_MEMORY_GB sets
/// another)` when a container's or job's limit bounds it, or `X GB are
/// allowed (WTMM_MEMORY_GB)` when the budget is the variable's, for the
/// memory messages.
pub fn gb_available(avail: f64) -> String {
    let set = matches!(memory_variable(), Ok(Some(_)));
    let why = if set {
        "allowed (WTMM_MEMORY_GB)"
    } else if memory_sources().1 {
        "available (the limit of this process's memory cgroup, a container or a job; \
         WTMM_MEMORY_GB sets another)"
    } else {
        "available"
    };
    format!("{} are {why}", memory_text(avail))
}

/// `bytes` for a memory message: `1.2 GB`, or `350 MB` below 1 GB (where
/// one decimal of a GB would say 0.0).
pub fn memory_text(bytes: f64) -> String {
    if bytes < 0.95e9 {
        format!("{:.0} MB", bytes / 1e6)
    } else {
        format!("{:.1} GB", bytes / 1e9)
    }
}

/// `MemAvailable` of a /proc/meminfo text, in bytes.
fn meminfo_available(meminfo: &str) -> Option<f64> {
    let line = meminfo.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024.0)
}

/// What the memory cgroup of this process leaves before its limit, in
/// bytes: the lowest headroom of its group and their ancestors' (a job's
/// limit binds its steps), each `limit - (usage - file cache)`, the page
/// cache of files counting as free, as `MemAvailable` counts it (re-read
/// files move to the active list, which the kernel reclaims too). `None`
/// without a limit, or where none can be read.
fn cgroup_headroom() -> Option<f64> {
    let own = std::fs::read_to_string("/proc/self/cgroup").ok()?;
    cgroup_headroom_in(&own, Path::new("/sys/fs/cgroup"))
}

/// [`cgroup_headroom`] of the groups `own` (a /proc/self/cgroup text)
/// under the cgroup mount `root`.
fn cgroup_headroom_in(own: &str, root: &Path) -> Option<f64> {
    let read = |p: &Path| std::fs::read_to_string(p).ok();
    // v1: a `memory` hierarchy of its own; v2: the unified one (`0::`)
    let (base, path, files) = match cgroup_path(own, "memory") {
        Some(path) => (
            root.join("memory"),
            path,
            ["memory.limit_in_bytes", "memory.usage_in_bytes"],
        ),
        None => (
            root.to_path_buf(),
            cgroup_path(own, "")?,
            ["memory.max", "memory.current"],
        ),
    };
    // the cache keys of memory.stat: v1 counts the group's subtree in
    // total_*, v2 in the plain keys
    let cache_keys: &[&str] = if files[0] == "memory.max" {
        &["active_file", "inactive_file"]
    } else {
        &["total_active_file", "total_inactive_file"]
    };
    // inside a cgroup namespace the own group is the mount's root, and the
    // path read is not under it
    let own_dir = base.join(path.trim_start_matches('/'));
    let start = if own_dir.exists() {
        own_dir
    } else {
        base.clone()
    };
    let mut best: Option<f64> = None;
    let mut dir = Some(start.as_path());
    while let Some(d) = dir.filter(|d| d.starts_with(&base)) {
        // a level without the files (a v2 group whose parent does not
        // enable the memory controller, the v2 root) is passed over
        if let (Some(limit), Some(usage)) = (read(&d.join(files[0])), read(&d.join(files[1]))) {
            let cache: f64 = read(&d.join("memory.stat")).map_or(0.0, |st| {
                cache_keys.iter().filter_map(|k| stat_value(&st, k)).sum()
            });
            let h = limit
                .trim()
                .parse()
                .ok()
                .and_then(|l: f64| headroom(l, usage.trim().parse().ok()?, cache));
            if let Some(h) = h {
                best = Some(best.map_or(h, |b| b.min(h)));
            }
        }
        dir = d.parent();
    }
    best
}

/// The group's path in a /proc/self/cgroup text for the v1 `controller`
/// (`""`: the v2 unified hierarchy, `0::/path`).
fn cgroup_path<'a>(own: &'a str, controller: &str) -> Option<&'a str> {
    own.lines().find_map(|l| {
        let mut f = l.splitn(3, ':');
        let (_, list, path) = (f.next()?, f.next()?, f.next()?);
        let hit = if controller.is_empty() {
            list.is_empty()
        } else {
            list.split(',').any(|c| c == controller)
        };
        hit.then_some(path)
    })
}

/// The value of `key` in a memory.stat text.
fn stat_value(stat: &str, key: &str) -> Option<f64> {
    stat.lines().find_map(|l| {
        let (k, v) = l.split_once(' ')?;
        (k == key).then(|| v.trim().parse().ok()).flatten()
    })
}

/// A limit's headroom over a usage of which `cache` bytes are
/// reclaimable; `None` for no limit (v1 writes "no limit" as about 2^63,
/// v2 as "max", which does not parse).
fn headroom(limit: f64, usage: f64, cache: f64) -> Option<f64> {
    (limit < 2f64.powi(60)).then(|| (limit - (usage - cache).max(0.0)).max(0.0))
}

/// Bytes per pixel of the WTMM analysis of one image on one thread (the
/// image, the half spectrum, one full-plane transform workspace, the
/// per-scale maxima), what an image with missing pixels adds (its filled
/// copy, the mask and the distance to it: +16 B/px measured with a 200 x
/// 300 hole in 2048^2; without a mask the image itself is transformed), and what each
/// further thread adds when a lone image's scales run in parallel: peak RSS
/// of `analyze` on fBm 2048^2 and 4096^2, 2026-11-26, 52 B/px on one thread
/// (60-62 with the copy every image had before), 76-85 on two.
const ANALYSIS_BYTES_PER_PIXEL: f64 = 54.0;
const ANALYSIS_BYTES_PER_PIXEL_MASKED: f64 = 16.0;
const ANALYSIS_BYTES_PER_PIXEL_PER_THREAD: f64 = 28.0;

/// What each image in flight of an ensemble analysed one image per worker
/// (analyze, pdf, kernel; correlate needs more) needs per pixel, planned from the
/// files' headers before they are read, so counting the masked image's
/// extra: whether an image has missing pixels is known once read.
pub const ENSEMBLE_ANALYSIS_BYTES_PER_PIXEL: f64 =
    ANALYSIS_BYTES_PER_PIXEL + ANALYSIS_BYTES_PER_PIXEL_MASKED;

/// Refuses, before its transform, an image whose analysis cannot fit in
/// the available memory (a 16384^2 DEM needs about 15 GB on one thread):
/// the allocation would abort the process with no message. `lone`: the
/// image is analysed alone, its scales on every thread.
pub fn check_image_memory(path: &Path, field: &Field, lone: bool) -> Result<()> {
    let threads = if lone {
        rayon::current_num_threads().max(1)
    } else {
        1
    };
    let (ny, nx) = field.dim();
    let masked = field.mask.is_some();
    match available_memory().and_then(|avail| image_memory_problem(ny, nx, masked, threads, avail))
    {
        Some(why) => Err(Error::format(path, why)),
        None => Ok(()),
    }
}

/// What [`check_image_memory`] says when `avail` bytes are too few.
fn image_memory_problem(
    ny: usize,
    nx: usize,
    masked: bool,
    threads: usize,
    avail: f64,
) -> Option<String> {
    let px = (ny * nx) as f64;
    let one = ANALYSIS_BYTES_PER_PIXEL
        + if masked {
            ANALYSIS_BYTES_PER_PIXEL_MASKED
        } else {
            0.0
        };
    let per_px = one + ANALYSIS_BYTES_PER_PIXEL_PER_THREAD * (threads - 1) as f64;
    let need = per_px * px;
    (need > avail).then(|| {
        format!(
            "analysing this {ny}x{nx} image needs about {:.1} GB of memory{}",
            need / 1e9,
            memory_tail(threads, avail, one * px)
        )
    })
}

/// What a memory refusal says after the need: ` (N threads), X GB are
/// available`, and with several threads what one would need
/// (`one_thread` bytes).
fn memory_tail(threads: usize, avail: f64, one_thread: f64) -> String {
    format!(
        " ({threads} thread{}), {}{}",
        if threads == 1 { "" } else { "s" },
        gb_available(avail),
        if threads > 1 {
            format!(
                " (on one thread, RAYON_NUM_THREADS=1, about {:.1} GB)",
                one_thread / 1e9
            )
        } else {
            String::new()
        }
    )
}

/// Peak memory of `tm` on one or two images, whose errors come from tiles
/// (the whole image and its tiles, `TraceMomentAccumulator::field_tiles`),
/// per pixel of the images, from peak RSS of `tm` on fBm 2048^2 and
/// 4096^2 (2026-11-29): 141-143 B/px on one thread, 178-179 on two (the
/// whole image beside its tiles, the double trace moments' eta in two
/// halves), 219 on 16 at 2048^2 (those two splits bound the tasks: threads
/// beyond three add nothing); a 200 x 300 hole in 4096^2 changed it by
/// less than 1 B/px.
const TM_TILES_BYTES_PER_PIXEL: f64 = 143.0;
const TM_TILES_BYTES_PER_PIXEL_PER_THREAD: f64 = 38.0;
const TM_TILES_EXTRA_THREADS: usize = 2;

/// Refuses, before any image is read, the trace moments of one or two
/// images (`px` pixels in all; `largest`: the path and shape of the
/// largest, named in the message) that the available memory cannot hold:
/// the allocation would abort the process with no message.
pub fn check_tm_memory(largest: (&Path, usize, usize), px: usize) -> Result<()> {
    let threads = rayon::current_num_threads().max(1);
    let why = available_memory()
        .and_then(|avail| tm_memory_problem(largest.1, largest.2, px, threads, avail));
    why.map_or(Ok(()), |w| Err(Error::format(largest.0, w)))
}

/// What [`check_tm_memory`] says when `avail` bytes are too few.
fn tm_memory_problem(
    ny: usize,
    nx: usize,
    px: usize,
    threads: usize,
    avail: f64,
) -> Option<String> {
    let extra = (threads - 1).min(TM_TILES_EXTRA_THREADS) as f64;
    let need = (TM_TILES_BYTES_PER_PIXEL + TM_TILES_BYTES_PER_PIXEL_PER_THREAD * extra) * px as f64;
    (need > avail).then(|| {
        format!(
            "the trace moments of this {ny}x{nx} image{} need about {:.1} GB of memory{}; crop \
             it, or tile it into several images (an ensemble of three or more is analysed one \
             image per thread)",
            if px > ny * nx { " and the other" } else { "" },
            need / 1e9,
            memory_tail(threads, avail, TM_TILES_BYTES_PER_PIXEL * px as f64)
        )
    })
}

/// Peak memory of `tm` per image in flight in an ensemble of three or more
/// (one image per worker, dropped after its sums), per pixel: peak RSS of
/// `tm` on fBm planes (2026-11-29), 3 x 4096^2: 2.47 GB on one thread
/// (147 B/px), 4.35 GB on two (130 B/px per image in flight); 4 x 2048^2:
/// 0.68 and 1.19 GB (144 and 134 B/px above the 73 MB of the process);
/// one image in flight on two threads, its double trace moments' two
/// halves side by side (a memory-limited run): 0.82 GB, 179 B/px.
pub const TM_ENSEMBLE_BYTES_PER_PIXEL: f64 = 190.0;

/// How many workers, of at most `threads`, can hold images of `px` pixels
/// side by side at `per_px` bytes per pixel within `avail` bytes: the most
/// whose largest images fit together (0 when not even the largest fits).
fn workers_that_fit(px: &[usize], per_px: f64, threads: usize, avail: f64) -> usize {
    let mut px = px.to_vec();
    px.sort_unstable_by(|a, b| b.cmp(a));
    let mut need = 0.0;
    px.iter()
        .take(threads)
        .take_while(|&&p| {
            need += per_px * p as f64;
            need <= avail
        })
        .count()
}

/// How many images of the ensemble `paths` (of sizes `sizes`, from their
/// headers), held one per worker at `per_px` bytes per pixel, the
/// available memory holds side by side (the largest ones): `Some(workers)`
/// when fewer than rayon has threads (said in a note; the caller's pass
/// then runs its images on that many threads,
/// [`crate::par::try_map_at_limited`]), `None` when every thread can hold
/// one: on 16 threads, 16 DEMs of 8192^2 in flight would abort the process
/// with no message. The results do not depend on the thread count. `what`
/// names the pass ("the trace moments").
///
/// **Errors**, before any image is read, when not even the largest image
/// fits alone (the message names it).
pub fn memory_workers(
    paths: &[PathBuf],
    sizes: &[[usize; 2]],
    per_px: f64,
    what: &str,
) -> Result<Option<usize>> {
    let threads = rayon::current_num_threads().max(1);
    let Some(avail) = available_memory() else {
        return Ok(None);
    };
    let px: Vec<usize> = sizes.iter().map(|[ny, nx]| ny * nx).collect();
    let fit = workers_that_fit(&px, per_px, threads, avail);
    if fit >= threads.min(px.len()) {
        return Ok(None);
    }
    let Some(big) = (0..px.len()).max_by_key(|&i| (px[i], std::cmp::Reverse(i))) else {
        return Ok(None);
    };
    let [ny, nx] = sizes[big];
    let one = per_px * px[big] as f64;
    if fit == 0 {
        return Err(Error::format(
            &paths[big],
            format!(
                "this {ny}x{nx} image needs about {} of memory for {what}, {}; crop it, or \
                 tile it into several images",
                memory_text(one),
                gb_available(avail)
            ),
        ));
    }
    say_fewer_workers(what, fit, threads, (ny, nx), one, avail);
    Ok(Some(fit))
}

/// The note of a pass run on `fit` of `threads` threads because an image
/// of `shape` in flight needs `need` bytes of the `avail` available.
fn say_fewer_workers(
    what: &str,
    fit: usize,
    threads: usize,
    (ny, nx): (usize, usize),
    need: f64,
    avail: f64,
) {
    say!(
        "note: {what} on {fit} of {threads} threads: an image of {ny}x{nx} in flight \
         needs about {} of memory and {} (the results are the same on any thread count)",
        memory_text(need),
        gb_available(avail)
    );
}

/// [`memory_workers`] of the image files `paths`, their sizes read from
/// their headers; `None` for fewer than two (a lone image is checked with
/// its threads once read).
pub fn ensemble_memory_workers(
    paths: &[PathBuf],
    per_px: f64,
    what: &str,
) -> Result<Option<usize>> {
    if paths.len() < 2 {
        return Ok(None);
    }
    let sizes = paths
        .iter()
        .map(crate::io::read_shape)
        .collect::<Result<Vec<_>>>()?;
    memory_workers(paths, &sizes, per_px, what)
}

/// Bytes per pixel beyond the images already read: `spectrum` per image in
/// flight (its filled and detrended copies and FFT, one per worker), `cwt`
/// for its one image (the transform's scales in flight and their files'
/// buffers). From peak RSS, 2026-11-26: spectrum 41 B/px in all for one
/// image of 2048^2 or 4096^2, 8 of them the image; 4 x 2048^2 gave 405 MB
/// on two threads and 274 MB on one, as 8 B/px held per image plus 33 per
/// image in flight; cwt 79-85 B/px in all (4 scales at 4096^2, 8 at
/// 2048^2, one or two threads).
const SPECTRUM_BYTES_PER_PIXEL_IN_FLIGHT: f64 = 33.0;
const CWT_BYTES_PER_PIXEL_BEYOND_IMAGE: f64 = 77.0;

/// What the image `path` of `ny x nx` will need beyond what is read, for
/// `what` ("its power spectrum", "its transform") with `copies` in flight
/// (the workers of `spectrum`), against `avail` bytes: the message when it
/// is too much.
fn extra_memory_problem(
    what: &str,
    ny: usize,
    nx: usize,
    per_px: f64,
    copies: usize,
    avail: f64,
) -> Option<String> {
    let need = per_px * (ny * nx) as f64 * copies as f64;
    (need > avail).then(|| {
        format!(
            "{what} of this {ny}x{nx} image needs about {:.1} GB of memory beyond the images \
             read ({copies} in flight), {}{}",
            need / 1e9,
            gb_available(avail),
            if copies > 1 {
                " (one at a time with RAYON_NUM_THREADS=1)"
            } else {
                ""
            }
        )
    })
}

/// Refuses, before its FFTs, the power spectrum of images the available
/// memory cannot hold in flight (`largest`: the path and shape of the
/// largest image; `n`: how many there are): the allocation would abort
/// the process with no message.
pub fn check_spectrum_memory(largest: (&Path, usize, usize), n: usize) -> Result<()> {
    let (path, ny, nx) = largest;
    let copies = rayon::current_num_threads().max(1).min(n.max(1));
    let why = available_memory().and_then(|avail| {
        extra_memory_problem(
            "the power spectrum",
            ny,
            nx,
            SPECTRUM_BYTES_PER_PIXEL_IN_FLIGHT,
            copies,
            avail,
        )
    });
    why.map_or(Ok(()), |w| Err(Error::format(path, w)))
}

/// [`check_spectrum_memory`] for `cwt`'s one image.
pub fn check_cwt_memory(path: &Path, ny: usize, nx: usize) -> Result<()> {
    let why = available_memory().and_then(|avail| {
        extra_memory_problem(
            "the transform",
            ny,
            nx,
            CWT_BYTES_PER_PIXEL_BEYOND_IMAGE,
            1,
            avail,
        )
    });
    why.map_or(Ok(()), |w| Err(Error::format(path, w)))
}

/// Bytes per pixel of one generated image in flight in `validate` or
/// `compare` (generator, power spectrum, transform and skeleton,
/// correlation or trace moments), from peak RSS with two threads,
/// 2026-11-26: validate 114 (log-normal), 184 (fBm) and 200 (FISC) at
/// 2048^2, 139 (FISC) at 4096^2; compare 160 (log-normal, fBm) at 2048^2.
const ENSEMBLE_BYTES_PER_PIXEL: f64 = 200.0;

/// Sizes up front a generated ensemble's images in flight (one per worker)
/// to the available memory: the allocation would abort the process with no
/// message and the output directory half made. `Some(workers)`: run on
/// that many images at once ([`crate::par::try_map_limited`]; said in a
/// note); refused when not even one image fits. For `validate` and
/// `compare`.
pub fn check_ensemble_memory(size: usize, count: usize, what: &str) -> Result<Option<usize>> {
    check_memory(size, count, ENSEMBLE_BYTES_PER_PIXEL, what)
}

/// [`check_memory`] for the generated images of `pdf`, `kernel` and
/// `correlate` with a model: `per_px` for the analysis, at least what
/// `validate` takes per image (generator, transform, skeleton and
/// correlation: [`ENSEMBLE_BYTES_PER_PIXEL`]).
pub fn check_generated_memory(
    size: usize,
    count: usize,
    per_px: f64,
    what: &str,
) -> Result<Option<usize>> {
    check_memory(size, count, per_px.max(ENSEMBLE_BYTES_PER_PIXEL), what)
}

/// Size and count of a generated ensemble (`validate`, `compare`, `demo`,
/// and `pdf`, `kernel`, `correlate` with a model): the sizes `synth`
/// writes, and at most [`super::synth_cmd::MAX_COUNT`] images (the
/// per-image sums of the jackknife grow with the count; a larger study is
/// several runs with different --seed).
pub fn check_generated(size: usize, count: usize) -> Result<()> {
    check_generated_side(size)?;
    let max = super::synth_cmd::MAX_COUNT;
    if count == 0 {
        return Err(Error::param("count", "must be >= 1"));
    }
    if count > max {
        return Err(Error::param(
            "count",
            format!(
                "must be at most {max}, got {count} (a larger study: several runs with \
                 different --seed)"
            ),
        ));
    }
    Ok(())
}

/// The side of a generated image: 16 px (the smallest worth analysing) to
/// 16384 px, the square root of the pixel limit of the readers and
/// generators (`io::MAX_PIXELS`).
pub fn check_generated_side(size: usize) -> Result<()> {
    let max = (crate::io::MAX_PIXELS as f64).sqrt() as usize;
    if !(16..=max).contains(&size) {
        return Err(Error::param(
            "size",
            format!("must be in 16..={max}, got {size}"),
        ));
    }
    Ok(())
}

/// [`check_ensemble_memory`] with `bytes_per_pixel` per image in flight
/// (`synth`: 64, its fBm grid).
pub fn check_memory(
    size: usize,
    count: usize,
    bytes_per_pixel: f64,
    what: &str,
) -> Result<Option<usize>> {
    let per_image = bytes_per_pixel * (size as f64).powi(2);
    let threads = rayon::current_num_threads().max(1);
    let Some(avail) = available_memory() else {
        return Ok(None);
    };
    let fit = (avail / per_image).floor() as usize;
    if fit == 0 {
        return Err(Error::param(
            "size",
            format!(
                "{size} px needs about {} in memory for one image; {} (a smaller --size)",
                memory_text(per_image),
                gb_available(avail)
            ),
        ));
    }
    Ok((fit < count.min(threads)).then(|| {
        say_fewer_workers(what, fit, threads, (size, size), per_image, avail);
        fit
    }))
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

#[cfg(test)]
mod tests {
    use super::*;

    /// `--fill-holes` names the pixels in holes larger than
    /// LARGE_FILLED_HOLE: a 2 x 10 hole across the left and right borders
    /// is one of 20 px on a torus and two of 10 on a plane; scattered
    /// pixels never count as large.
    #[test]
    fn fill_holes_names_large_holes() {
        let (ny, nx) = (40, 50);
        let data = ndarray::Array2::from_shape_fn((ny, nx), |(y, x)| (y * 7 + x * 3) as f64);
        let mask = ndarray::Array2::from_shape_fn((ny, nx), |(y, x)| {
            ((10..20).contains(&y) && (x == 0 || x == nx - 1)) || (y == 30 && x % 5 == 2)
        });
        let f = Field::with_mask(data, mask).unwrap();
        let (plane, torus) = (HoleSizes::of(&f, false), HoleSizes::of(&f, true));
        assert_eq!((plane.missing, plane.largest, plane.in_large), (30, 10, 0));
        assert_eq!((torus.missing, torus.largest, torus.in_large), (30, 20, 20));
        // 30 px of 2000, all in small holes: tau(3) up by at most 0.0038
        let d = plane.describe();
        assert!(!d.contains("more than 16"), "{d}");
        assert!(
            d.contains("(here up to +0.004)") && !d.contains("crop"),
            "{d}"
        );
        // 20 px of 2000 in a large hole, 10 in small ones: tau(3) up by at
        // most 0.0055 + 0.0013
        let d = torus.describe();
        assert!(
            d.starts_with("1.5 % of the pixels; the largest hole holds 20 px; 1.0 %"),
            "{d}"
        );
        assert!(
            d.contains("(here up to +0.007)") && !d.contains("crop"),
            "{d}"
        );
        assert_eq!(
            torus.brief(),
            "1.5 %, the largest hole 20 px, 1.0 % in holes of more than 16 px; tau(3) raised \
             by up to +0.007"
        );
        assert_eq!(
            plane.brief(),
            "1.5 %, the largest hole 10 px; tau(3) raised by up to +0.004"
        );
        // one image with 3 % in a large hole: told to crop it, whatever
        // the ensemble's share
        let big = HoleSizes {
            missing: 300,
            largest: 300,
            in_large: 300,
            area: 10_000,
        };
        assert!(
            big.brief()
                .ends_with("; crop the large holes out if you can")
        );
        // a record holding more in large holes than filled: no underflow
        let odd = HoleSizes {
            missing: 100,
            largest: 200,
            in_large: 200,
            area: 10_000,
        };
        // the large holes' 2 % alone: 0.0055 x 2
        assert!(odd.brief().contains("up to +0.011"), "{}", odd.brief());
    }

    /// An error that would round to zero keeps two significant digits.
    #[test]
    fn no_error_bar_reads_zero() {
        assert_eq!(plus_minus(0.0150, 0.000419, 3), "0.01500 ± 0.00042");
        assert_eq!(plus_minus(1.5, 0.0035, 3), "1.500 ± 0.004");
        assert_eq!(plus_minus(1.5, 0.001, 3), "1.500 ± 0.001");
        assert_eq!(plus_minus(-0.37, 0.0, 3), "-0.370 ± 0.000");
        assert_eq!(plus_minus(0.5, f64::NAN, 2), "0.50");
        assert_eq!(
            plus_minus(0.5, 1e-13, 3),
            format!("{:.12} ± {:.12}", 0.5, 1e-13)
        );
        assert_eq!(
            plus_minus(1.0, 1e-20, 13),
            format!("{:.13} ± {:.13}", 1.0, 1e-20)
        );
    }

    /// Figure titles name the first and last files, with their directories
    /// when there are several; generated labels are not named.
    #[test]
    fn data_labels() {
        use crate::spectra::ShapeCount;
        let sq = [ShapeCount {
            ny: 512,
            nx: 512,
            images: 4,
        }];
        assert_eq!(
            data_label(&["d/a.npy", "d/b.npy"], 2, &sq),
            "a.npy .. b.npy, 2 x 512^2"
        );
        assert_eq!(
            data_label(
                &["big/a.npy", "x/small/b.npy"],
                2,
                &[sq[0], ShapeCount { ny: 256, ..sq[0] }]
            ),
            "big/a.npy .. small/b.npy, 2 x mixed sizes"
        );
        assert_eq!(data_label(&["a.npy"], 1, &sq), "a.npy, 1 x 512^2");
        assert_eq!(data_label(&["image 1", "image 2"], 2, &sq), "2 x 512^2");
    }

    /// A 16384^2 image needs about 14.5 GB on one thread (54 B/px, measured
    /// 52 on 4096^2; 18.8 GB with missing pixels, whose filled copy, mask
    /// and distance map add 16)
    /// and 22 GB on two: refused with 8 GB, not with 32.
    /// `tm` on a lone 16384^2 DEM: 38 GB on one thread, 50 GB on two or
    /// more (the tasks are bounded, so 16 threads need no more than 3).
    #[test]
    fn tm_memory_is_checked_before_reading() {
        let px = 16384 * 16384;
        let w = tm_memory_problem(16384, 16384, px, 1, 32e9).unwrap();
        assert!(w.contains("about 38.4 GB of memory (1 thread)"), "{w}");
        assert!(!w.contains("RAYON_NUM_THREADS"), "{w}");
        assert!(tm_memory_problem(16384, 16384, px, 1, 40e9).is_none());
        let w = tm_memory_problem(16384, 16384, px, 16, 40e9).unwrap();
        assert!(w.contains("about 58.8 GB of memory (16 threads)"), "{w}");
        assert!(w.contains("RAYON_NUM_THREADS=1, about 38.4 GB"), "{w}");
        assert_eq!(
            tm_memory_problem(16384, 16384, px, 3, 1e9),
            tm_memory_problem(16384, 16384, px, 16, 1e9)
                .map(|w| w.replace("16 threads", "3 threads"))
        );
        // two images: the other one's pixels count too
        let w = tm_memory_problem(4096, 4096, 2 * 4096 * 4096, 1, 4e9).unwrap();
        assert!(
            w.contains("4096x4096 image and the other need about 4.8 GB"),
            "{w}"
        );
    }

    #[test]
    fn cgroup_limits_are_read() {
        // v1 (hybrid host): the memory controller's line; v2: `0::`
        let own = "9:name=systemd:/\n4:memory:/job/42\n3:cpu,cpuacct:/\n0::/\n";
        assert_eq!(cgroup_path(own, "memory"), Some("/job/42"));
        assert_eq!(cgroup_path(own, "cpuacct"), Some("/"));
        assert_eq!(cgroup_path(own, ""), Some("/"));
        assert_eq!(cgroup_path("0::/user.slice/x\n", "memory"), None);
        assert_eq!(cgroup_path("0::/user.slice/x\n", ""), Some("/user.slice/x"));
        let stat = "cache 10\nhierarchical_memory_limit 8589934592\ntotal_inactive_file 1000\n\
                    inactive_file 7\n";
        assert_eq!(
            stat_value(stat, "hierarchical_memory_limit"),
            Some(8589934592.0)
        );
        assert_eq!(stat_value(stat, "total_inactive_file"), Some(1000.0));
        assert_eq!(stat_value(stat, "inactive_file"), Some(7.0));
        assert_eq!(stat_value(stat, "missing"), None);
        // 8 GB limit, 3 GB used of which 1 GB reclaimable: 6 GB left
        assert_eq!(headroom(8e9, 3e9, 1e9), Some(6e9));
        assert_eq!(headroom(8e9, 9e9, 0.0), Some(0.0));
        // v1 writes "no limit" as 2^63 rounded down to a page
        assert_eq!(headroom(9223372036854771712.0, 3e9, 0.0), None);
        assert_eq!(
            meminfo_available("MemTotal: 100 kB\nMemAvailable: 2 kB\n"),
            Some(2048.0)
        );
        assert_eq!(memory_text(3.5e8), "350 MB");
        assert_eq!(memory_text(2.26e9), "2.3 GB");
    }

    /// Fake cgroup trees: the lowest headroom up the ancestors, the file
    /// cache (active and inactive) counted as free, levels without the
    /// files passed over, no limit read as none.
    #[test]
    fn cgroup_headroom_walks_the_ancestors() {
        let dir = std::env::temp_dir().join(format!("wtmm_cgroup_{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let put = |rel: &str, name: &str, text: &str| {
            let d = dir.join(rel);
            std::fs::create_dir_all(&d).unwrap();
            std::fs::write(d.join(name), text).unwrap();
        };
        let gb = 1e9;
        // v2: a job of 16 GB holding 12 GB, 10 GB of it active file cache;
        // its step has no memory files (the controller not enabled below)
        put("v2", "cgroup.controllers", "memory\n");
        put("v2/job", "memory.max", "16000000000\n");
        put("v2/job", "memory.current", "12000000000\n");
        put(
            "v2/job",
            "memory.stat",
            "anon 1500000000\nactive_file 10000000000\ninactive_file 500000000\n",
        );
        std::fs::create_dir_all(dir.join("v2/job/step")).unwrap();
        let v2 = dir.join("v2");
        let h = cgroup_headroom_in("0::/job/step\n", &v2).unwrap();
        assert!((h - 14.5 * gb).abs() < 1.0, "{h}");
        // a step limit of its own, lower: it binds
        put("v2/job/step", "memory.max", "3000000000\n");
        put("v2/job/step", "memory.current", "1000000000\n");
        let h = cgroup_headroom_in("0::/job/step\n", &v2).unwrap();
        assert!((h - 2.0 * gb).abs() < 1.0, "{h}");
        // no limit anywhere: none
        assert_eq!(cgroup_headroom_in("0::/\n", &v2), None);
        put("v2/free", "memory.max", "max\n");
        put("v2/free", "memory.current", "5\n");
        assert_eq!(cgroup_headroom_in("0::/free\n", &v2), None);
        // over the limit: nothing left (not negative)
        put("v2/over", "memory.max", "1000\n");
        put("v2/over", "memory.current", "2000\n");
        assert_eq!(cgroup_headroom_in("0::/over\n", &v2), Some(0.0));
        // v1: a job of 16 GB with 15 GB used by other steps binds a step
        // that uses little
        let v1 = dir.join("v1");
        put(
            "v1/memory",
            "memory.limit_in_bytes",
            "9223372036854771712\n",
        );
        put("v1/memory", "memory.usage_in_bytes", "30000000000\n");
        put("v1/memory/job", "memory.limit_in_bytes", "16000000000\n");
        put("v1/memory/job", "memory.usage_in_bytes", "15000000000\n");
        put(
            "v1/memory/job",
            "memory.stat",
            "total_active_file 0\ntotal_inactive_file 0\n",
        );
        put(
            "v1/memory/job/step",
            "memory.limit_in_bytes",
            "9223372036854771712\n",
        );
        put("v1/memory/job/step", "memory.usage_in_bytes", "100000000\n");
        let own = "4:memory:/job/step\n0::/\n";
        let h = cgroup_headroom_in(own, &v1).unwrap();
        assert!((h - 1.0 * gb).abs() < 1.0, "{h}");
        // inside a namespace the own path is not under the mount: the
        // mount's root is the own group
        assert_eq!(cgroup_headroom_in("4:memory:/elsewhere\n", &v1), None);
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn ensembles_run_on_the_workers_the_memory_holds() {
        let gb = 1e9;
        // three images of 100 M px at 150 B/px: 15 GB each in flight
        let px = [100_000_000; 3];
        assert_eq!(workers_that_fit(&px, 150.0, 16, 50.0 * gb), 3);
        assert_eq!(workers_that_fit(&px, 150.0, 16, 44.0 * gb), 2);
        assert_eq!(workers_that_fit(&px, 150.0, 2, 44.0 * gb), 2);
        assert_eq!(workers_that_fit(&px, 150.0, 1, 44.0 * gb), 1);
        assert_eq!(workers_that_fit(&px, 150.0, 16, 14.0 * gb), 0);
        // the largest images are the ones counted, whatever their order
        let px = [10_000_000, 100_000_000, 20_000_000, 100_000_000];
        assert_eq!(workers_that_fit(&px, 150.0, 16, 15.0 * gb), 1);
        assert_eq!(workers_that_fit(&px, 150.0, 16, 30.0 * gb), 2);
        assert_eq!(workers_that_fit(&px, 150.0, 16, 33.0 * gb), 3);
        assert_eq!(workers_that_fit(&px, 150.0, 16, 34.5 * gb), 4);
        assert_eq!(workers_that_fit(&[], 150.0, 16, gb), 0);
    }

    #[test]
    fn large_images_are_refused_before_the_transform() {
        let w = image_memory_problem(16384, 16384, false, 1, 8e9).unwrap();
        assert!(
            w.contains("about 14.5 GB") && w.contains("8.0 GB are available"),
            "{w}"
        );
        let w = image_memory_problem(16384, 16384, true, 1, 8e9).unwrap();
        assert!(w.contains("about 18.8 GB"), "{w}");
        assert!(image_memory_problem(16384, 16384, true, 1, 32e9).is_none());
        let w = image_memory_problem(16384, 16384, false, 2, 20e9).unwrap();
        assert!(
            w.contains("22.0 GB") && w.contains("RAYON_NUM_THREADS=1, about 14.5"),
            "{w}"
        );
        // an ordinary DEM passes anywhere
        assert!(image_memory_problem(4096, 4096, true, 2, 2e9).is_none());
    }

    /// The spectrum and the transform beyond the images read: a 16384^2
    /// DEM's spectrum needs 8.9 GB per image in flight, its transform 20.7.
    #[test]
    fn spectrum_and_cwt_memory_are_checked() {
        let w = extra_memory_problem("the power spectrum", 16384, 16384, 33.0, 2, 8e9).unwrap();
        assert!(
            w.contains("about 17.7 GB") && w.contains("(2 in flight)") && w.contains("RAYON"),
            "{w}"
        );
        assert!(extra_memory_problem("the power spectrum", 16384, 16384, 33.0, 1, 16e9).is_none());
        let w = extra_memory_problem("the transform", 16384, 16384, 77.0, 1, 16e9).unwrap();
        assert!(w.contains("about 20.7 GB") && !w.contains("RAYON"), "{w}");
        assert!(extra_memory_problem("the transform", 4096, 4096, 77.0, 1, 2e9).is_none());
    }

    #[test]
    fn lists_are_parsed_sorted_and_distinct() {
        assert_eq!(
            parse_list("q", "-1:1:0.5").unwrap(),
            vec![-1.0, -0.5, 0.0, 0.5, 1.0]
        );
        // the stop is kept despite rounding of the step
        assert_eq!(parse_list("q", "0:0.3:0.1").unwrap().len(), 4);
        assert_eq!(
            parse_list("q", "2,0,-2, 1").unwrap(),
            vec![-2.0, 0.0, 1.0, 2.0]
        );
        assert_eq!(parse_list("q", "3").unwrap(), vec![3.0]);
        // the decimal grid meant, not the binary sums a + i step
        let v = parse_list("q", "-0.3:3:0.1").unwrap();
        assert_eq!(v[3], 0.0);
        assert_eq!(v[23], 2.0);
        assert_eq!(v[33], 3.0);
        assert!(parse_list("q", "-7.2:8:0.2").unwrap().contains(&2.0));
        for bad in [
            "0,1,1,2",
            "1:0:1",
            "0:1:0",
            "0:1:-1",
            "a,b",
            "1:2",
            "nan",
            "",
            "0:1e9:1e-9",
            "0:nan:1",
            "nan:1:1",
            "0:inf:1",
            "0:1:nan",
        ] {
            let e = parse_list("q", bad).unwrap_err().to_string();
            assert!(e.contains("--q") || e.contains("q"), "{bad}: {e}");
        }
        assert_eq!(parse_q("q", "-1000,1000").unwrap(), vec![-1000.0, 1000.0]);
        // the library's default grids are the CLI's, to the bit
        assert_eq!(
            parse_q("q", "-4:6:0.5").unwrap(),
            crate::spectra::default_q()
        );
        assert_eq!(
            parse_q("q", "0.1:4:0.1").unwrap(),
            crate::tracemoments::TraceMomentConfig::default().q
        );
        for bad in ["1e308", "-1001", "0:2000:1000"] {
            let e = parse_q("q", bad).unwrap_err().to_string();
            assert!(e.contains("beyond |q| = 1000"), "{bad}: {e}");
        }
        assert!(
            parse_list("q", "0,1,1")
                .unwrap_err()
                .to_string()
                .contains("1 is given twice")
        );
        let e = parse_list("q", "0,1e-10").unwrap_err().to_string();
        assert!(e.contains("0 and 0.0000000001 are closer than 1e-9"), "{e}");
    }

    #[test]
    fn csv_fields_with_commas_or_quotes_are_quoted() {
        assert_eq!(csv_field("K(q=1.5,eta)"), "\"K(q=1.5,eta)\"");
        assert_eq!(csv_field("a \"b\""), "\"a \"\"b\"\"\"");
        assert_eq!(csv_field("lnM"), "lnM");
        let dir = std::env::temp_dir().join(format!("wtmm-csv-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("t.csv");
        let rows = vec![vec!["1".to_string(), "x,y.npy".to_string()]];
        write_csv(&p, &["eta", "K(q=0.5,eta)"], &rows).unwrap();
        let text = std::fs::read_to_string(&p).unwrap();
        assert_eq!(text, "eta,\"K(q=0.5,eta)\"\n1,\"x,y.npy\"\n");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn ranges_need_lo_below_hi() {
        assert_eq!(parse_range("fit", "0.5:4").unwrap(), (0.5, 4.0));
        for bad in ["4:0.5", "1:1", "1", "a:2"] {
            assert!(parse_range("fit", bad).is_err(), "{bad}");
        }
    }
}
