//! The command line (SPEC §13): clap definitions in one place, one file per
//! command. Each command is arguments -> typed options -> library -> writers;
//! `run` only maps errors to exit codes (0 ok, 1 a check failed, 2 bad usage
//! or bad input).

/// `eprintln!` that never panics: a closed stderr (`wtmm ... 2>&1 | head`)
/// must not abort a command whose results go to files. Warnings, notes
/// and errors are wrapped to a terminal's width ([`for_stderr`]).
macro_rules! say {
    ($($t:tt)*) => {{
        $crate::cli::emit(format!($($t)*));
    }};
}

/// Writes `text` and a newline on stderr ([`say!`]): wrapped on a
/// terminal ([`for_stderr`]), above the progress bar when one is drawn
/// (the bar is cleared, the text written, the bar redrawn), never
/// panicking.
pub(crate) fn emit(text: String) {
    use std::io::Write as _;
    let text = for_stderr(text);
    let write = || {
        let _ = writeln!(std::io::stderr(), "{text}");
    };
    match common::active_bar() {
        Some(bar) => bar.suspend(write),
        None => write(),
    }
}

/// `text` as stderr shows it: on a terminal, each `warning: `, `note: `
/// or `error: ` line wrapped to the terminal's width (at most 100
/// columns), continued with an indent; elsewhere (scripts, logs, tests)
/// one line per message, for grep.
pub(crate) fn for_stderr(text: String) -> String {
    use std::io::IsTerminal;
    if !std::io::stderr().is_terminal() {
        return text;
    }
    match console::Term::stderr().size_checked() {
        // narrower than 40 columns the terminal's own wrapping reads better
        Some((_, cols)) if cols >= 40 => wrap_messages(&text, usize::from(cols).min(100)),
        _ => text,
    }
}

/// The message lines of `text` (`warning: `, `note: `, `error: `) wrapped
/// at spaces to `width` display columns, continuation lines indented by 2;
/// words longer than a line (paths) are not broken; other lines as they
/// are.
fn wrap_messages(text: &str, width: usize) -> String {
    const INDENT: &str = "  ";
    // "q = -4", "0.36 +- 0.06", "-4 .. 6", "344 x 403" stay on one line
    const GLUE: [&str; 5] = ["=", "+-", "..", "x", "±"];
    // and a unit with its number
    const AFTER: [&str; 2] = ["px", "%"];
    let columns = console::measure_text_width;
    let mut out: Vec<String> = Vec::new();
    for line in text.split('\n') {
        let message = ["warning: ", "note: ", "error: "]
            .iter()
            .any(|p| line.starts_with(p));
        if !message || columns(line) <= width {
            out.push(line.to_string());
            continue;
        }
        let mut units: Vec<String> = Vec::new();
        let mut glued = false;
        for word in line.split(' ').filter(|w| !w.is_empty()) {
            let glue = GLUE.contains(&word);
            match units.last_mut() {
                Some(last)
                    if glue
                        || glued
                        || AFTER
                            .contains(&word.trim_end_matches([',', '.', ';', ':', ')', ']'])) =>
                {
                    last.push(' ');
                    last.push_str(word);
                }
                _ => units.push(word.to_string()),
            }
            // the prefix ("warning:") holds on to the next word
            glued = glue || (units.len() == 1 && word.ends_with(':'));
        }
        let mut cur = String::new();
        let mut cur_len = 0;
        for word in &units {
            let n = columns(word);
            if cur_len > INDENT.len() && cur_len + 1 + n > width {
                out.push(std::mem::take(&mut cur));
                cur.push_str(INDENT);
                cur_len = INDENT.len();
            } else if !cur.is_empty() {
                cur.push(' ');
                cur_len += 1;
            }
            cur.push_str(word);
            cur_len += n;
        }
        out.push(cur);
    }
    out.join("\n")
}

/// `print!` of a summary that never panics (a closed stdout loses only the
/// summary; the files are the results).
macro_rules! show {
    ($($t:tt)*) => {{
        use std::io::Write as _;
        let _ = write!(std::io::stdout(), $($t)*);
    }};
}

mod analyze_cmd;
mod common;
mod compare_cmd;
mod correlate_cmd;
mod cwt_cmd;
mod demo_cmd;
mod ensemble;
mod info_cmd;
mod kernel_cmd;
mod merge_cmd;
mod model_args;
mod pdf_cmd;
mod skeleton_cmd;
mod spectrum_cmd;
mod synth_cmd;
mod theory_cmd;
mod tm_cmd;
mod validate_cmd;

use std::path::{Path, PathBuf};

use clap::{Args, Parser, Subcommand};

use crate::cwt::{ScaleGrid, Wavelet};
use crate::error::{Error, Result};

/// Multifractal analysis of images: 2D WTMM, trace moments, generators.
#[derive(Parser, Debug)]
#[command(name = "wtmm", version, about, long_about = None)]
pub struct Cli {
    /// No progress bars (they are also hidden when stderr is not a terminal).
    #[arg(long, global = true)]
    pub quiet: bool,
    /// Also write every plot as SVG beside its PNG (vector graphics for a
    /// paper's figures; rasters such as skeleton pictures are embedded).
    #[arg(long, global = true)]
    pub svg: bool,
    /// The subcommand to run.
    #[command(subcommand)]
    pub command: Command,
}

/// The subcommands of `wtmm` (SPEC §13), one variant per command.
#[derive(Subcommand, Debug)]
pub enum Command {
    /// Generate synthetic fields with known spectra.
    Synth(synth_cmd::SynthArgs),
    /// Continuous wavelet transform: modulus and argument images per scale.
    Cwt(cwt_cmd::CwtArgs),
    /// Isotropic power spectrum and its slope beta.
    Spectrum(spectrum_cmd::SpectrumArgs),
    /// Closed-form spectra of a model or preset (JSON on stdout).
    Theory(theory_cmd::TheoryArgs),
    /// Generate an ensemble of a model, analyse it, check against the theory.
    ///
    /// The q grid (--q) gets every half integer of the model's published q
    /// range added, so that each tau criterion is judged over its whole range
    /// and h, D at q = 0 exactly.
    Validate(validate_cmd::ValidateArgs),
    /// Generate a small ensemble with a known spectrum, analyse it, compare with theory.
    Demo(demo_cmd::DemoArgs),
    /// Merge saved partition sums (ensemble shards) and recompute the spectra.
    Merge(merge_cmd::MergeArgs),
    /// WT skeleton: WTMMM, maxima lines and pictures of chosen scales.
    Skeleton(skeleton_cmd::SkeletonArgs),
    /// WTMM multifractal spectra tau(q), h(q), D(q), D(h) of an ensemble.
    Analyze(analyze_cmd::AnalyzeArgs),
    /// Trace moments K(q), universal alpha and C1, double trace moments, H.
    Tm(tm_cmd::TmArgs),
    /// WTMM against trace moments on one generated ensemble, both against the theory.
    ///
    /// q = 1 and 2 join any --q grid: H = tau(1) + 2 and beta = tau(2) + 4 need them.
    Compare(Box<compare_cmd::CompareArgs>),
    /// Pdfs of the WTMMM modulus and argument per scale (II Figs 11-14, 17-20).
    Pdf(pdf_cmd::PdfArgs),
    /// Self-similarity kernel and its cumulants c1, c2, c3 (II Figs 25-29).
    Kernel(kernel_cmd::KernelArgs),
    /// Space-scale correlation of the magnitudes ln M (II Fig 30).
    Correlate(correlate_cmd::CorrelateArgs),
    /// What wtmm reads from images, and the counting domain each number of octaves leaves.
    ///
    /// Exits 1 when an image cannot be analysed (constant, every pixel missing, too small for
    /// the wavelet, or no counting domain at --octaves), each said under "not usable".
    Info(info_cmd::InfoArgs),
}

/// Wavelet and scale-grid options shared by the analysis commands.
#[derive(Args, Debug, Clone)]
pub struct CwtOpts {
    /// Analysing wavelet (gauss: 1 vanishing moment; mexican: 3) [default: gauss; where a
    /// command takes a model (--preset, --theory, MODEL), the wavelet of the paper's
    /// results for it, e.g. mexican for FISC].
    #[arg(long, value_enum)]
    pub wavelet: Option<Wavelet>,
    /// Smallest scale in pixels (std of the Gaussian).
    #[arg(long, default_value_t = 1.5, allow_negative_numbers = true)]
    pub a_min: f64,
    /// Number of octaves of scales.
    #[arg(long, default_value_t = 5)]
    pub octaves: usize,
    /// Scales per octave.
    #[arg(long, default_value_t = 10)]
    pub voices: usize,
    /// Interior margin in pixels (default: computed from the wavelet and the
    /// largest scale; 0, the whole torus, for the periodic models generated
    /// by validate, compare, pdf, kernel and correlate, and for the files
    /// `wtmm synth` wrote from them, listed in the synth.json beside them,
    /// unless --detrend plane is given, in the commands that have it).
    #[arg(long)]
    pub margin: Option<usize>,
}

impl CwtOpts {
    /// The scale grid `a_j = a_min 2^(j / voices)` (SPEC §1) of these options.
    /// **Errors** if a parameter is out of range ([`ScaleGrid::validate`]).
    pub fn grid(&self) -> Result<ScaleGrid> {
        let g = ScaleGrid {
            a_min: self.a_min,
            octaves: self.octaves,
            voices: self.voices,
        };
        g.validate()?;
        Ok(g)
    }

    /// Margin 0 (the whole torus) for a generated periodic model unless
    /// `--margin` was given: the periodic FFT transform is exact everywhere
    /// on such fields, so an interior would only discard half the maxima.
    pub fn torus_for(&mut self, model: &crate::theory::Model) {
        if self.margin.is_none() {
            self.margin = crate::skeleton::AnalysisConfig::for_field(model.is_periodic()).margin;
        }
    }
}

/// Exit code of a finished command.
pub enum Outcome {
    /// The command succeeded (exit code 0).
    Ok,
    /// The command ran but a `--check` criterion failed (exit code 1).
    CheckFailed,
}

/// The files a command reads (images, or `merge`'s sums) and the directory
/// it writes, checked before any computing starts.
fn io_of(cmd: &Command) -> (Vec<&Path>, bool, Option<&Path>) {
    fn v(p: &[PathBuf]) -> Vec<&Path> {
        p.iter().map(|p| p.as_path()).collect()
    }
    match cmd {
        Command::Synth(a) => (vec![], true, Some(&a.common.out.out)),
        Command::Cwt(a) => (vec![&a.image], true, Some(&a.out.out)),
        Command::Spectrum(a) => (v(&a.images), true, Some(&a.out.out)),
        Command::Analyze(a) => (v(&a.images), true, Some(&a.out.out)),
        Command::Skeleton(a) => (vec![&a.image], true, Some(&a.out.out)),
        Command::Demo(a) => (vec![], true, Some(&a.out)),
        Command::Merge(a) => (v(&a.sums), false, Some(&a.out.out)),
        Command::Theory(a) => (vec![], true, a.out.as_deref()),
        Command::Validate(a) => (vec![], true, Some(&a.out.out)),
        Command::Tm(a) => (v(&a.images), true, Some(&a.out.out)),
        Command::Compare(a) => (vec![], true, Some(&a.out.out)),
        Command::Pdf(a) => (v(&a.input.images), true, Some(&a.out.out)),
        Command::Kernel(a) => (v(&a.input.images), true, Some(&a.out.out)),
        Command::Correlate(a) => (v(&a.input.images), true, Some(&a.out.out)),
        Command::Info(a) => (v(&a.images), true, None),
    }
}

/// Checks every input before computing (a missing file at the end of a
/// 32-image ensemble used to surface after the whole analysis): it must be a
/// readable regular file, and an image must have a known extension.
fn check_inputs(paths: &[&Path], images: bool) -> Result<()> {
    // an ensemble counts each image once: a repeated file would pass for an
    // independent sample and shrink the jackknife errors
    let mut seen: std::collections::HashMap<(u64, u64, PathBuf), &Path> = Default::default();
    for &p in paths {
        if let Some(key) = crate::io::file_identity(p)
            && let Some(first) = seen.insert(key, p)
        {
            return Err(Error::Input(format!(
                "{} and {} are the same file: give each input once",
                first.display(),
                p.display()
            )));
        }
    }
    let mut by_len: std::collections::BTreeMap<u64, Vec<&Path>> = Default::default();
    for &p in paths {
        let meta = std::fs::metadata(p).map_err(|source| Error::Read {
            path: p.into(),
            source,
        })?;
        if !meta.is_file() {
            return Err(Error::format(p, "not a regular file"));
        }
        by_len.entry(meta.len()).or_default().push(p);
        std::fs::File::open(p).map_err(|source| Error::Read {
            path: p.into(),
            source,
        })?;
        if images && crate::io::ImageFormat::from_path(p).is_none() {
            // read_field names the supported formats
            crate::io::read_field(p)?;
        }
    }
    if images {
        // a copy of an image under another name is the same sample too:
        // files of one length are compared by their first MiB, and in full
        // only where that agrees (different images differ at once)
        for group in by_len.values().filter(|g| g.len() > 1) {
            let mut first_of: std::collections::BTreeMap<u64, Vec<&Path>> = Default::default();
            for &p in group {
                let h = prefix_hash(p)?;
                let same = first_of.get(&h).and_then(|qs| {
                    qs.iter().copied().find(|q| {
                        matches!((std::fs::read(q), std::fs::read(p)), (Ok(a), Ok(b)) if a == b)
                    })
                });
                if let Some(q) = same {
                    return Err(Error::Input(format!(
                        "{} and {} have the same content: one image twice would pass for two \
                         independent samples and shrink the error bars; give each image once",
                        q.display(),
                        p.display()
                    )));
                }
                first_of.entry(h).or_default().push(p);
            }
        }
    }
    Ok(())
}

/// A hash of a file's first MiB (to find copies among the inputs).
fn prefix_hash(p: &Path) -> Result<u64> {
    use std::hash::Hasher;
    use std::io::Read;
    let read_err = |source| Error::Read {
        path: p.into(),
        source,
    };
    let f = std::fs::File::open(p).map_err(read_err)?;
    let mut buf = Vec::with_capacity(1 << 20);
    f.take(1 << 20).read_to_end(&mut buf).map_err(read_err)?;
    let mut h = std::collections::hash_map::DefaultHasher::new();
    h.write(&buf);
    Ok(h.finish())
}

/// Whether the JSON file `p` is an output of a wtmm command (a top-level
/// `command` with a `version`, or the partition sums' `scales`, `q` and
/// `images`), not a sidecar or a user's record. Files beyond 64 MiB are
/// taken as outputs unread (a sidecar is a few hundred bytes).
fn is_wtmm_output(p: &Path) -> bool {
    if std::fs::metadata(p).is_ok_and(|m| m.len() > 64 << 20) {
        return true;
    }
    let Ok(v) = std::fs::read(p).map(|b| serde_json::from_slice::<serde_json::Value>(&b)) else {
        return false;
    };
    let Ok(serde_json::Value::Object(o)) = v else {
        return false;
    };
    o.contains_key("version")
        && (o.contains_key("command")
            || ["scales", "q", "images"].iter().all(|k| o.contains_key(*k)))
}

/// Creates the output directory before computing, so that an unwritable
/// one fails at once (the directories created are noted, to be removed
/// again, if still empty, when the command fails).
fn prepare_out(dir: &Path) -> Result<()> {
    if dir.exists() && !dir.is_dir() {
        return Err(Error::Input(format!(
            "{}: exists and is not a directory",
            dir.display()
        )));
    }
    common::make_out_dir(dir).map_err(|e| match e {
        Error::Write { source, .. } => {
            Error::format(dir, format!("cannot create the output directory: {source}"))
        }
        e => e,
    })?;
    // writable? (an existing directory may not be; /proc refuses new files
    // as "no such file")
    let probe = dir.join(format!(".wtmm-probe-{}", std::process::id()));
    std::fs::write(&probe, b"").map_err(|source| {
        Error::format(
            dir,
            format!(
                "the output directory does not take new files (a test file could not be \
                 created: {source})"
            ),
        )
    })?;
    let _ = std::fs::remove_file(&probe);
    Ok(())
}

fn dispatch(cli: Cli) -> Result<Outcome> {
    // a bad memory budget is refused before anything is made
    common::check_memory_variable()?;
    let _svg = common::also_svg(cli.svg);
    let (inputs, images, out) = io_of(&cli.command);
    // --svg is global; a command that writes no plot would drop it unsaid
    if cli.svg && (out.is_none() || matches!(cli.command, Command::Info(_) | Command::Synth(_))) {
        say!(
            "warning: --svg has no effect here: this command writes no plot (theory writes its \
             plots with --out)"
        );
    }
    if let Command::Pdf(pdf_cmd::PdfArgs { input, .. })
    | Command::Kernel(kernel_cmd::KernelArgs { input, .. })
    | Command::Correlate(correlate_cmd::CorrelateArgs { input, .. }) = &cli.command
    {
        input.refuse_model_names()?;
    }
    check_inputs(&inputs, images)?;
    // and the JSON beside each image: a PNG's decoding (scale, offset,
    // nodata), a DEM's provenance and pixel; an output of that name
    // (spectra.json beside an input spectra.png) would silently change how
    // the image reads next time. An output of an earlier wtmm run is not
    // one (a second run into the image's directory rewrites it).
    let sidecars: Vec<PathBuf> = if images {
        inputs
            .iter()
            .map(|p| p.with_extension("json"))
            .filter(|j| j.is_file() && !is_wtmm_output(j))
            .collect()
    } else {
        Vec::new()
    };
    let guarded: Vec<&Path> = inputs
        .iter()
        .copied()
        .chain(sidecars.iter().map(PathBuf::as_path))
        .collect();
    let _inputs = crate::io::protect(&guarded);
    let out: Option<PathBuf> = out.map(Path::to_path_buf);
    // a panic (a bug) unwinds past the clean-up below: this removes the
    // directories made for it, after the batch (declared later, dropped
    // first) has removed its temporaries
    let _on_panic = PanicCleanup(out.as_deref());
    if let Some(dir) = &out
        && let Err(e) = prepare_out(dir)
    {
        release_created(Some(dir), true);
        return Err(e);
    }
    // nothing half-written: the files appear together when the command
    // succeeds (an existing directory keeps its older files otherwise)
    let batch = match out
        .as_deref()
        .map(crate::io::OutputBatch::begin)
        .transpose()
    {
        Ok(b) => b,
        Err(e) => {
            release_created(out.as_deref(), true);
            return Err(e);
        }
    };
    // files already there (synth says which of its own are left over)
    // (not the inputs, their sidecars or the synth.json beside them: the
    // warning must not tell the user to remove the images read)
    let read: Vec<PathBuf> = guarded
        .iter()
        .map(|p| p.to_path_buf())
        .chain(
            inputs
                .iter()
                .filter_map(|p| Some(p.parent()?.join("synth.json"))),
        )
        .filter_map(|p| p.canonicalize().ok())
        .collect();
    // (only the files of those names are resolved: a large --out stays cheap)
    let names: std::collections::HashSet<&std::ffi::OsStr> =
        read.iter().filter_map(|p| p.file_name()).collect();
    let is_read = |f: &Path| {
        f.file_name().is_some_and(|n| names.contains(n))
            && f.canonicalize().is_ok_and(|c| read.contains(&c))
    };
    let before = match (&out, &cli.command) {
        (Some(dir), c) if !matches!(c, Command::Synth(_)) => files_under(dir)
            .into_iter()
            .filter(|f| !is_read(f))
            .collect(),
        _ => Vec::new(),
    };
    let quiet = cli.quiet;
    let r = run_command(cli).and_then(|o| {
        let written = batch.map(|b| b.commit_files()).transpose()?;
        if let (Some(dir), Some(written)) = (&out, written) {
            // said once the files are there (not before the commit, which
            // can still fail)
            if !quiet && !written.is_empty() {
                say!("wrote {} file(s) to {}", written.len(), dir.display());
            }
            warn_stale(dir, &before, &written);
        }
        Ok(o)
    });
    release_created(out.as_deref(), r.is_err());
    r
}

/// Removes, when dropped during a panic, the still-empty directories
/// created for the output directory it holds.
struct PanicCleanup<'a>(Option<&'a Path>);

impl Drop for PanicCleanup<'_> {
    fn drop(&mut self) {
        if std::thread::panicking() {
            release_created(self.0, true);
        }
    }
}

/// Most files [`files_under`] lists (an --out pointed at a large tree is
/// not walked whole).
const STALE_SCAN: usize = 10_000;

/// The files under `dir`, recursively (at most [`STALE_SCAN`]).
fn files_under(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        let Ok(rd) = std::fs::read_dir(&d) else {
            continue;
        };
        for e in rd.flatten() {
            let Ok(t) = e.file_type() else { continue };
            if t.is_dir() {
                stack.push(e.path());
            } else if !e.file_name().to_string_lossy().starts_with(".wtmm-") {
                out.push(e.path());
            }
            if out.len() >= STALE_SCAN {
                return out;
            }
        }
    }
    out
}

/// What a stale-file warning adds when some of `names` (file names, no
/// directories) are the staged
/// writes of a killed run ([`crate::io::is_foreign_temp`]).
fn temp_note<'a>(mut names: impl Iterator<Item = &'a str>) -> &'static str {
    if names.any(crate::io::is_foreign_temp) {
        " (.NAME.tmpPID files are the unfinished writes of a run that was killed: safe to \
         delete)"
    } else {
        ""
    }
}

/// Warns when the output directory still holds files of an earlier run
/// that this command did not rewrite (they would pass for its results).
fn warn_stale(dir: &Path, before: &[PathBuf], written: &[PathBuf]) {
    let written: std::collections::HashSet<&Path> = written.iter().map(PathBuf::as_path).collect();
    let stale: Vec<&PathBuf> = before
        .iter()
        .filter(|p| !written.contains(p.as_path()))
        .collect();
    if stale.is_empty() {
        return;
    }
    let show: Vec<String> = stale
        .iter()
        .take(4)
        .map(|p| p.strip_prefix(dir).unwrap_or(p).display().to_string())
        .collect();
    say!(
        "warning: {} holds {} older file(s) this command did not write ({}{}): they are not \
         results of this run; remove them or use a fresh --out{}",
        dir.display(),
        stale.len(),
        show.join(", "),
        if stale.len() > show.len() {
            ", ..."
        } else {
            ""
        },
        temp_note(
            stale
                .iter()
                .filter_map(|p| p.file_name().and_then(|n| n.to_str()))
        )
    );
}

fn run_command(cli: Cli) -> Result<Outcome> {
    let quiet = cli.quiet;
    match cli.command {
        Command::Synth(a) => synth_cmd::run(a, quiet),
        Command::Cwt(a) => cwt_cmd::run(a, quiet),
        Command::Spectrum(a) => spectrum_cmd::run(a, quiet),
        Command::Analyze(a) => analyze_cmd::run(a, quiet),
        Command::Skeleton(a) => skeleton_cmd::run(a, quiet),
        Command::Demo(a) => demo_cmd::run(a, quiet),
        Command::Merge(a) => merge_cmd::run(a, quiet),
        Command::Theory(a) => theory_cmd::run(a, quiet),
        Command::Validate(a) => validate_cmd::run(a, quiet),
        Command::Tm(a) => tm_cmd::run(a, quiet),
        Command::Compare(a) => compare_cmd::run(*a, quiet),
        Command::Pdf(a) => pdf_cmd::run(a, quiet),
        Command::Kernel(a) => kernel_cmd::run(a, quiet),
        Command::Correlate(a) => correlate_cmd::run(a, quiet),
        Command::Info(a) => info_cmd::run(a, quiet),
    }
}

/// The directories the running command created (removed on a failure or
/// an interrupt if still empty).
static CREATED: std::sync::Mutex<Vec<PathBuf>> = std::sync::Mutex::new(Vec::new());

/// Records directories the command created ([`common::make_out_dir`]).
fn note_created(dirs: Vec<PathBuf>) {
    CREATED
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .extend(dirs);
}

/// Forgets the directories created for the output directory `root` (under
/// it, or its new parents; all of them when `None`) and, with `remove`,
/// removes those that are empty, deepest first: their files went with the
/// batch's temporaries. Keyed by `root` because commands may run
/// concurrently in one process (the tests).
fn release_created(root: Option<&Path>, remove: bool) {
    let mut created = CREATED.lock().unwrap_or_else(|e| e.into_inner());
    let mut mine: Vec<PathBuf> = Vec::new();
    created.retain(|d| {
        let ours = root.is_none_or(|r| d.starts_with(r) || r.starts_with(d));
        if ours {
            mine.push(d.clone());
        }
        !ours
    });
    if !remove {
        return;
    }
    mine.sort_by_key(|d| std::cmp::Reverse(d.components().count()));
    for d in mine {
        let _ = std::fs::remove_dir(d);
    }
}

/// Parses the process arguments, runs the command, returns the exit code.
///
/// Ctrl-C (or SIGTERM) removes the temporary files of the outputs, and the
/// directories the command created if still empty, then exits with 130:
/// an interrupted command leaves the output directory as it was (or, if
/// the interrupt came after the batch was committed, complete).
pub fn run() -> i32 {
    // the handler can be installed once per process; failing to install it
    // only loses the clean-up, so the command runs anyway
    let _ = ctrlc::set_handler(|| {
        // the bar goes, so that the message is the last line (emit would
        // redraw it)
        if let Some(bar) = common::active_bar() {
            bar.finish_and_clear();
        }
        crate::io::remove_temporaries();
        if !crate::io::outputs_committed() {
            release_created(None, true);
        }
        if crate::io::outputs_committed() {
            // the renames had finished (the clean-up waits for them)
            say!("interrupted after the outputs were written");
        } else {
            say!("interrupted: no output written");
        }
        std::process::exit(130);
    });
    run_from(std::env::args_os())
}

/// As [`run`], from explicit arguments (for tests).
pub fn run_from<I, T>(args: I) -> i32
where
    I: IntoIterator<Item = T>,
    T: Into<std::ffi::OsString> + Clone,
{
    // options take negative numbers as values, so that `--octaves -1` is
    // refused by its parser, naming the option ("invalid value '-1' for
    // '--octaves'"), rather than read as an unknown flag with clap's tip
    // of `-- -1`, which would not help (clap sets this per argument only)
    let cmd = negative_values(<Cli as clap::CommandFactory>::command());
    let args: Vec<std::ffi::OsString> = args.into_iter().map(Into::into).collect();
    // as typed, with the program's path reduced to its name
    let typed = args
        .iter()
        .enumerate()
        .map(|(i, a)| match i {
            0 => Path::new(a)
                .file_name()
                .unwrap_or(a)
                .to_string_lossy()
                .into_owned(),
            _ => a.to_string_lossy().into_owned(),
        })
        .collect();
    let _typed = common::record_command_line(typed);
    let parsed = cmd
        .try_get_matches_from(args)
        .and_then(|m| <Cli as clap::FromArgMatches>::from_arg_matches(&m));
    let cli = match parsed {
        Ok(c) => c,
        Err(e) => {
            let code = if e.use_stderr() { 2 } else { 0 };
            let _ = e.print();
            return code;
        }
    };
    match dispatch(cli) {
        Ok(Outcome::Ok) => 0,
        Ok(Outcome::CheckFailed) => 1,
        Err(e) => {
            say!("error: {e}");
            2
        }
    }
}

/// `cmd` and its subcommands with every value-taking option accepting a
/// negative number as its value, and every option that always takes one
/// value (not `--out`) any value that starts with a hyphen: ranges, lists
/// and `-inf` ("-2:3", "-1,2"), which clap's negative numbers do not cover
/// (it told the user to write `-- -2`, which no option reads). An option
/// whose value may be left out (`--frac-int`) keeps clap's rule, or it
/// would swallow the next flag.
fn negative_values(cmd: clap::Command) -> clap::Command {
    let ids: Vec<(clap::Id, bool)> = cmd
        .get_arguments()
        .filter(|a| !a.is_positional() && a.get_action().takes_values())
        .map(|a| {
            let always_one = a
                .get_num_args()
                .is_none_or(|r| r.min_values() == 1 && r.max_values() == 1);
            // a named value (--wavelet gauss) never starts with a hyphen:
            // `--law --basis db4` keeps clap's "a value is required"
            let named = !a.get_possible_values().is_empty();
            (
                a.get_id().clone(),
                always_one && !named && a.get_id() != "out",
            )
        })
        .collect();
    let cmd = ids.into_iter().fold(cmd, |c, (id, hyphen)| {
        c.mut_arg(id, |a| {
            a.allow_negative_numbers(true).allow_hyphen_values(hyphen)
        })
    });
    cmd.mut_subcommands(negative_values)
}

/// Output directory argument shared by every command.
#[derive(Args, Debug, Clone)]
pub struct OutDir {
    /// Output directory (created if missing; written only after the inputs are checked).
    #[arg(long)]
    pub out: PathBuf,
}

/// The physical size of a pixel (analyze, spectrum, tm, merge, pdf,
/// kernel, correlate): the exponents do not depend on it, but the scales
/// a paper quotes do.
#[derive(Args, Debug, Clone, Default)]
pub struct PixelOpts {
    /// Size of a pixel in physical units, S or SX:SY (SX along the columns, SY
    /// along the rows): scales, lags and wavenumbers are also given in these
    /// units. Non-square pixels are warned about. Default: the spacing the
    /// inputs declare when they all declare the same one (images: GeoTIFF tags,
    /// an ESRI grid's cellsize and .prj, a world file; merge: the pixel the
    /// sums.json record).
    #[arg(long)]
    pub pixel_size: Option<String>,
    /// Name of the unit of --pixel-size (e.g. m, km) [default: units].
    #[arg(long, requires = "pixel_size")]
    pub units: Option<String>,
}

/// How the images are read (analyze, skeleton, cwt, spectrum, tm, info,
/// pdf, kernel, correlate).
#[derive(Args, Debug, Clone, Default)]
pub struct ReadOpts {
    /// A value that marks missing pixels in every image read, beside NaN and
    /// the nodata a file declares: a sea or a fill set to 0, an undeclared
    /// -9999. Compared with the values as the file stores them (rounded to
    /// float32 or float16 for such files; after a PNG sidecar's scale and
    /// offset).
    #[arg(long, allow_hyphen_values = true, value_name = "VALUE")]
    pub nodata: Option<f64>,
}

impl ReadOpts {
    /// The value, refused when not finite (NaN is missing already).
    pub fn value(&self) -> Result<Option<f64>> {
        match self.nodata {
            Some(v) if !v.is_finite() => Err(Error::param(
                "nodata",
                format!("{v} is not a finite number (NaN and infinities are missing already)"),
            )),
            v => Ok(v),
        }
    }
}

/// A resolved [`PixelOpts`].
#[derive(Clone, Debug, PartialEq)]
pub struct PixelSize {
    /// Along the columns (x).
    pub x: f64,
    /// Along the rows (y).
    pub y: f64,
    /// The unit's name.
    pub units: String,
    /// `--pixel-size`, or the file that declared it and how.
    pub source: String,
}

/// Pixels whose sides differ by more than this (relative) are warned about.
const NON_SQUARE: f64 = 0.01;

/// Declared spacings closer than this (relative) are the same.
const SAME_SPACING: f64 = 1e-3;

/// The unit's name when none is given.
const UNNAMED: &str = "units";

/// Who declares a pixel spacing, in [`PixelOpts::resolve_from`]'s messages.
struct Declarers {
    /// "images".
    noun: &'static str,
    /// "declare".
    verb: &'static str,
    /// "declares".
    verbs: &'static str,
    /// "declared by".
    past: &'static str,
    /// Why some may declare none (said after "the others none").
    none: &'static str,
}

/// The first origin of a recorded pixel's `source`: "recorded in F: recorded
/// in G: declared by H: ..." becomes "declared by H: ...", so that merges of
/// merges do not nest it.
fn first_origin(source: &str) -> &str {
    if !source.starts_with("recorded in ") {
        return source;
    }
    ["declared by ", "--pixel-size"]
        .iter()
        .filter_map(|k| source.find(k))
        .min()
        .map_or(source, |i| &source[i..])
}

const IMAGES: Declarers = Declarers {
    noun: "images",
    verb: "declare",
    verbs: "declares",
    past: "declared by",
    none: "",
};

const SUMS: Declarers = Declarers {
    noun: "sums files",
    verb: "record",
    verbs: "records",
    past: "recorded in",
    none: " (validate, demo and compare, and analyze before 0.3, record none)",
};

/// [`SUMS`] when some record a pixel that is not one.
const SUMS_BAD: Declarers = Declarers {
    none: " or one that is not a pixel size (said above)",
    ..SUMS
};

/// The pixel sizes taken, given or declared, in any unit: no unit makes a
/// pixel of 1e-300 or 1e300 (a typo, a corrupt header), and the lengths and
/// wavenumbers derived from one would underflow or overflow.
const PIXEL_SIZES: std::ops::RangeInclusive<f64> = 1e-30..=1e30;

impl PixelOpts {
    /// The pixel: `--pixel-size`, else the spacing every one of `images`
    /// declares ([`crate::io::read_pixel_spacing`]), with the warnings to
    /// say: images that declare different spacings (an ensemble that
    /// mixes ground scales), some that declare none, a `--pixel-size` that
    /// contradicts a file, a geographic pixel whose width changes across
    /// the image.
    ///
    /// **Errors** naming `--pixel-size` unless it is one or two finite
    /// positive numbers.
    pub fn resolve(&self, images: &[PathBuf]) -> Result<(Option<PixelSize>, Vec<String>)> {
        // a file that cannot be read declares nothing here: its reader
        // says why when the command reads it
        // a declared size beyond the bounds of --pixel-size (an ESRI
        // cellsize 1e-310) is none, said: its lengths would overflow
        let mut odd = Vec::new();
        let declared: Vec<Option<crate::io::PixelSpacing>> = images
            .iter()
            .map(|p| {
                let s = crate::io::read_pixel_spacing(p).ok().flatten()?;
                if [s.x, s.y].iter().all(|v| PIXEL_SIZES.contains(v)) {
                    return Some(s);
                }
                odd.push(format!(
                    "{} declares a pixel of {} x {}, outside 1e-30 .. 1e30: no pixel is taken \
                     from it (give --pixel-size)",
                    p.display(),
                    short_num(s.x),
                    short_num(s.y)
                ));
                None
            })
            .collect();
        let (px, mut warnings) = self.resolve_from(&declared, images, &IMAGES)?;
        odd.append(&mut warnings);
        Ok((px, odd))
    }

    /// [`resolve`](Self::resolve) for `merge`: the pixel each sums file
    /// records ([`crate::spectra::PartitionSums::pixel`]) in place of the
    /// images' declared spacings, with its first origin (`--pixel-size`,
    /// or the image that declared it), not the merges it went through.
    /// A record that is not a pixel (a side not finite and positive, in
    /// an edited file) counts as none, with a warning.
    pub fn resolve_recorded(
        &self,
        recorded: &[Option<crate::spectra::PixelRecord>],
        files: &[PathBuf],
    ) -> Result<(Option<PixelSize>, Vec<String>)> {
        let mut bad = Vec::new();
        let declared: Vec<Option<crate::io::PixelSpacing>> = recorded
            .iter()
            .zip(files)
            .map(|(r, p)| {
                let r = r.as_ref()?;
                if !(r.x.is_finite() && r.x > 0.0 && r.y.is_finite() && r.y > 0.0) {
                    bad.push(format!(
                        "{} records a pixel of {} x {} {}, not a pixel size: not used",
                        p.display(),
                        r.x,
                        r.y,
                        r.units
                    ));
                    return None;
                }
                Some(crate::io::PixelSpacing {
                    x: r.x,
                    y: r.y,
                    // PixelSize's name for unnamed units
                    units: (r.units != UNNAMED).then(|| r.units.clone()),
                    source: first_origin(&r.source).to_string(),
                    warnings: Vec::new(),
                })
            })
            .collect();
        let by = if bad.is_empty() { &SUMS } else { &SUMS_BAD };
        let (px, mut warnings) = self.resolve_from(&declared, files, by)?;
        bad.append(&mut warnings);
        Ok((px, bad))
    }

    /// [`resolve`](Self::resolve) from the spacings `declared` by `files`,
    /// said in the words of `by`.
    fn resolve_from(
        &self,
        declared: &[Option<crate::io::PixelSpacing>],
        images: &[PathBuf],
        by: &Declarers,
    ) -> Result<(Option<PixelSize>, Vec<String>)> {
        let Declarers {
            noun,
            verb,
            verbs,
            past,
            none,
        } = by;
        let mut warnings: Vec<String> = Vec::new();
        let spacing = |x: f64, y: f64, u: &str| {
            if x == y {
                format!("{} {u}", short_num(x))
            } else {
                format!("{} x {} {u}", short_num(x), short_num(y))
            }
        };
        let file_units = |d: &crate::io::PixelSpacing| d.units.clone().unwrap_or(UNNAMED.into());
        let differ = |a: (f64, f64), b: (f64, f64)| {
            (a.0 / b.0 - 1.0).abs() > SAME_SPACING || (a.1 / b.1 - 1.0).abs() > SAME_SPACING
        };
        if let Some(given) = self.given()? {
            for (d, p) in declared.iter().zip(images) {
                let Some(d) = d else { continue };
                let theirs = spacing(d.x, d.y, &file_units(d));
                let ours = spacing(given.x, given.y, &given.units);
                let at = format!("{} {verbs} ({})", p.display(), d.source);
                // numbers as they are when either unit is unnamed, else in
                // metres when both are lengths wtmm knows
                match crate::io::unit_ratio(self.units.as_deref(), d.units.as_deref()) {
                    Some(k) if differ((k * given.x, k * given.y), (d.x, d.y)) => {
                        warnings.push(format!(
                            "--pixel-size {ours} differs from the {theirs} {at}; the lengths \
                             use --pixel-size"
                        ));
                    }
                    Some(_) => {
                        if let (None, Some(u)) = (&self.units, &d.units) {
                            warnings.push(format!(
                                "--pixel-size {ours} has no --units; the {theirs} {at}: the \
                                 lengths are in unnamed units (give --units {u})"
                            ));
                        }
                    }
                    None => warnings.push(format!(
                        "--pixel-size {ours} cannot be compared with the {theirs} {at} (units \
                         wtmm does not know as lengths); the lengths use --pixel-size"
                    )),
                }
            }
            return Ok((Some(given), warnings));
        }
        let known: Vec<(&crate::io::PixelSpacing, &PathBuf)> = declared
            .iter()
            .zip(images)
            .filter_map(|(d, p)| d.as_ref().map(|d| (d, p)))
            .collect();
        let Some(&(first, first_path)) = known.first() else {
            return Ok((None, warnings));
        };
        // the same pixel: the same numbers in unnamed units on both, or
        // in units wtmm can convert (30 m and 0.03 km); `None` when the
        // units cannot be compared (one unnamed, or unknown names)
        let same = |d: &crate::io::PixelSpacing| match (&d.units, &first.units) {
            (None, None) => Some(!differ((d.x, d.y), (first.x, first.y))),
            (Some(a), Some(b)) => crate::io::unit_ratio(Some(a), Some(b))
                .map(|k| !differ((k * d.x, k * d.y), (first.x, first.y))),
            _ => None,
        };
        if let Some((d, p)) = known.iter().find(|(d, _)| same(d) != Some(true)) {
            let why = if same(d).is_some() {
                "at one wavelet scale in pixels the ensemble mixes different ground scales; no \
                 lengths are given (resample to one spacing, or give --pixel-size)"
            } else {
                "in units that cannot be compared (one unnamed, or not lengths wtmm knows); no \
                 lengths are given (give --pixel-size and --units)"
            };
            warnings.push(format!(
                "the {noun} {verb} different pixel spacings ({} in {}, {} in {}): {why}",
                spacing(first.x, first.y, &file_units(first)),
                first_path.display(),
                spacing(d.x, d.y, &file_units(d)),
                p.display()
            ));
            return Ok((None, warnings));
        }
        if known.len() < images.len() {
            warnings.push(format!(
                "{} of {} {noun} {verb} a pixel spacing ({} in {}), the others none{none}: no \
                 lengths are given (give --pixel-size)",
                known.len(),
                images.len(),
                spacing(first.x, first.y, &file_units(first)),
                first_path.display()
            ));
            return Ok((None, warnings));
        }
        // the files' own warnings (a geographic pixel's width changing
        // across the image) when their spacing is the one used
        for d in declared.iter().flatten() {
            for w in &d.warnings {
                if !warnings.contains(w) {
                    warnings.push(w.clone());
                }
            }
        }
        let what = if images.len() == 1 {
            format!("{}: {}", first_path.display(), first.source)
        } else {
            format!(
                "all {} {noun}, e.g. {}: {}",
                images.len(),
                first_path.display(),
                first.source
            )
        };
        Ok((
            Some(PixelSize {
                x: first.x,
                y: first.y,
                units: file_units(first),
                source: format!("{past} {what}"),
            }),
            warnings,
        ))
    }

    /// `--pixel-size` (and `--units`) alone.
    fn given(&self) -> Result<Option<PixelSize>> {
        let Some(s) = &self.pixel_size else {
            return Ok(None);
        };
        let bad = |why: &str| Error::param("pixel-size", format!("{why}, got `{s}`"));
        let parts: Vec<&str> = s.split(':').collect();
        if parts.len() > 2 {
            return Err(bad("give S or SX:SY"));
        }
        let v: Vec<f64> = parts
            .iter()
            .map(|p| p.trim().parse::<f64>())
            .collect::<std::result::Result<_, _>>()
            .map_err(|_| bad("give S or SX:SY, numbers"))?;
        if v.iter().any(|x| !(x.is_finite() && *x > 0.0)) {
            return Err(bad("sizes must be finite and > 0"));
        }
        if v.iter().any(|x| !PIXEL_SIZES.contains(x)) {
            return Err(bad(
                "sizes must lie within 1e-30 .. 1e30 (choose --units to match)",
            ));
        }
        Ok(Some(PixelSize {
            x: v[0],
            y: *v.last().expect("one at least"),
            units: self.units.clone().unwrap_or_else(|| UNNAMED.into()),
            source: "--pixel-size".into(),
        }))
    }
}

impl PixelSize {
    /// The side of a square pixel of the same area, `sqrt(x y)`: what a
    /// scale in px is multiplied by (x itself for square pixels).
    pub fn side(&self) -> f64 {
        // as two roots: x y itself can underflow or overflow
        if self.x == self.y {
            self.x
        } else {
            self.x.sqrt() * self.y.sqrt()
        }
    }

    /// As recorded with the partition sums (`sums.json`), for `merge`.
    pub fn record(&self) -> crate::spectra::PixelRecord {
        crate::spectra::PixelRecord {
            x: self.x,
            y: self.y,
            units: self.units.clone(),
            source: self.source.clone(),
        }
    }

    /// `{x, y, units, side, source}` for the outputs' `params`.
    pub fn json(&self) -> serde_json::Value {
        serde_json::json!({"x": self.x, "y": self.y, "units": self.units, "side": self.side(),
            "source": self.source,
            "note": "lengths in these units are px times side = sqrt(x y); wavenumbers are rad/px divided by it"})
    }

    /// Says [`note`](Self::note) of `px` on stderr, unless `quiet`.
    pub fn say_note(px: Option<&PixelSize>, quiet: bool) {
        if let Some(n) = px.and_then(PixelSize::note).filter(|_| !quiet) {
            say!("{n}");
        }
    }

    /// The line that says where a pixel size the files declared comes
    /// from (nothing for `--pixel-size`).
    pub fn note(&self) -> Option<String> {
        (self.source != "--pixel-size").then(|| {
            format!(
                "note: pixel {} x {} {}, {}",
                short_num(self.x),
                short_num(self.y),
                self.units,
                self.source
            )
        })
    }

    /// `a` px as a length: "190 m".
    pub fn length(&self, px: f64) -> String {
        format!("{} {}", short_num(px * self.side()), self.units)
    }

    /// The side and units the figures' labels use (`px_is`, `px_span`).
    pub fn plot(&self) -> (f64, &str) {
        (self.side(), &self.units)
    }

    /// A warning for non-square pixels, which the analyses isotropic in
    /// pixels (`tools`: the wavelet, the angle-averaged spectrum, the
    /// trace moments' square boxes) see as a stretched surface.
    pub fn warning(&self, tools: Isotropic) -> Option<String> {
        let r = self.x / self.y;
        ((r - 1.0).abs() > NON_SQUARE).then(|| {
            format!(
                "the pixels are not square ({} x {} {}, x/y = {r:.3}): in pixels, ground \
                 distances along y are scaled by {r:.3} relative to x, and {}, isotropic in \
                 pixels, {} directions at different ground scales; resample to square pixels \
                 for an isotropic analysis (lengths here use the side sqrt(x y))",
                short_num(self.x),
                short_num(self.y),
                self.units,
                tools.what(),
                tools.verb()
            )
        })
    }
}

/// What a command analyses isotropically in pixels, for
/// [`PixelSize::warning`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Isotropic {
    /// The 2D wavelet (analyze, merge, skeleton, pdf, kernel, correlate).
    Wavelet,
    /// The angle-averaged power spectrum (spectrum).
    Spectrum,
    /// The trace moments' square boxes and the spectrum (tm).
    BoxesAndSpectrum,
}

impl Isotropic {
    fn what(self) -> &'static str {
        match self {
            Isotropic::Wavelet => "the wavelet",
            Isotropic::Spectrum => "the angle-averaged spectrum",
            Isotropic::BoxesAndSpectrum => {
                "the trace moments' square boxes and the angle-averaged spectrum"
            }
        }
    }

    fn verb(self) -> &'static str {
        match self {
            Isotropic::BoxesAndSpectrum => "mix",
            _ => "mixes",
        }
    }
}

/// For a figure's axis label in px: "; 1 px = 10 m" when the pixel is
/// known (`--pixel-size`, or declared by the files), else nothing. The
/// axes stay in px, the unit of the analysis and of the JSON's scales;
/// the label says what one is on the ground.
pub(crate) fn px_is(px: Option<(f64, &str)>) -> String {
    px.map_or(String::new(), |(side, units)| {
        format!("; 1 px = {} {units}", short_num(side))
    })
}

/// For a figure's title or legend after a range `lo-hi px`: " (21.2-112 m)"
/// when the pixel is known, else nothing.
pub(crate) fn px_span(px: Option<(f64, &str)>, lo: f64, hi: f64) -> String {
    px.map_or(String::new(), |(side, units)| {
        format!(
            " ({}-{} {units})",
            short_num(lo * side),
            short_num(hi * side)
        )
    })
}

/// For a figure's label after a scale `a px`: " = 21.2 m" when the pixel
/// is known, else nothing.
pub(crate) fn px_eq(px: Option<(f64, &str)>, a: f64) -> String {
    px.map_or(String::new(), |(side, units)| {
        format!(" = {} {units}", short_num(a * side))
    })
}

/// The pixel recorded in an output's `params.pixel_size` (`side`, `units`),
/// for the figures drawn from it.
pub(crate) fn params_pixel(params: &serde_json::Value) -> Option<(f64, String)> {
    let p = &params["pixel_size"];
    p["side"]
        .as_f64()
        .zip(p["units"].as_str().map(str::to_string))
}

/// A length for a message: 4 significant digits, no trailing zeros.
pub(crate) fn short_num(v: f64) -> String {
    if v == 0.0 || !v.is_finite() {
        return format!("{v}");
    }
    // in full, 1e308 is 309 digits and 1e-300 300 zeros
    if !(1e-4..1e9).contains(&v.abs()) {
        return format!("{v:.3e}");
    }
    let digits = (3 - v.abs().log10().floor() as i32).max(0) as usize;
    let s = format!("{v:.digits$}");
    if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        s
    }
}

#[cfg(test)]
mod tests {
    /// Numbers in messages: 4 significant digits in the usual range, 3
    /// after the point in scientific notation beyond it (1e308 in full is
    /// 309 digits); the library's `short` reads typed values back as typed
    /// and hides a sum's rounding.
    #[test]
    fn numbers_in_messages_are_short() {
        use crate::error::short;
        assert_eq!(super::short_num(1e308), "1.000e308");
        assert_eq!(super::short_num(-3.6e-299), "-3.600e-299");
        assert_eq!(super::short_num(65536.0), "65536");
        assert_eq!(super::short_num(0.1234567), "0.1235");
        assert_eq!(short(2.0 - 0.1), "1.9");
        assert_eq!(short(0.1), "0.1");
        assert_eq!(short(1.0 + 1e-10), "1");
        assert_eq!(short(123456.789), "123457");
        assert_eq!(short(std::f64::consts::FRAC_PI_4), "0.785398");
        assert_eq!(short(1e-9), "1.000e-9");
        // a value refused for leaving a range does not read as its bound
        use crate::error::short_outside;
        assert_eq!(short_outside(0.5000001, &[0.0, 0.5]), "0.5000001");
        assert_eq!(short_outside(0.7, &[0.0, 0.5]), "0.7");
        assert_eq!(short_outside(0.5, &[0.0, 0.5]), "0.5");
        let e = crate::synth::fbm::FbmParams { hurst: 1.0000001 }
            .validate()
            .unwrap_err();
        assert!(e.to_string().contains("got 1.0000001"), "{e}");
    }

    /// Messages wrap at spaces to the width with a 2-space indent, words
    /// stay whole, other lines and short messages are untouched, and the
    /// words come back in order.
    #[test]
    fn messages_wrap_to_the_terminal() {
        let long = format!(
            "warning: {} /a/very/long/path/{}.npy end",
            "word ".repeat(30).trim_end(),
            "x".repeat(60)
        );
        let text = format!("{long}\ntable  row {}\nnote: short", "y ".repeat(40));
        let w = super::wrap_messages(&text, 50);
        let lines: Vec<&str> = w.lines().collect();
        assert!(lines[0].starts_with("warning: word"));
        // no line starts or ends inside "q = -4"
        for pad in 0..50 {
            let text = format!(
                "warning: {}q = -4 end",
                "a".repeat(pad) + " b c d e f g h i j k"
            );
            let q = super::wrap_messages(&text, 40);
            assert!(q.lines().any(|l| l.contains("q = -4")), "{q}");
        }
        let path = lines.iter().position(|l| l.contains("/a/very")).unwrap();
        for (i, l) in lines.iter().enumerate() {
            // only the unbreakable path exceeds the width
            if i != path && !l.starts_with("table") {
                assert!(l.chars().count() <= 50, "{l:?}");
            }
        }
        assert!(
            lines[1..=path]
                .iter()
                .all(|l| l.starts_with("  ") && !l.starts_with("   "))
        );
        // the table line (no message prefix) stays whole, the note too
        assert!(lines.contains(&format!("table  row {}", "y ".repeat(40)).as_str()));
        assert_eq!(lines.last(), Some(&"note: short"));
        // the same words in the same order
        let words = |t: &str| t.split_whitespace().map(String::from).collect::<Vec<_>>();
        assert_eq!(words(&w), words(&text));
        // the prefix never stands alone; a length stays with its unit
        let e = super::wrap_messages(&format!("error: /{}/x.npy: bad", "p".repeat(60)), 40);
        assert!(e.starts_with("error: /ppp"), "{e}");
        for pad in 0..30 {
            let t = format!("warning: {} at a = 11.20 px (< 10 %) end", "w".repeat(pad));
            let q = super::wrap_messages(&t, 40);
            assert!(q.contains("11.20 px") && q.contains("10 %"), "{q}");
        }
        // wide characters count two columns each
        let cjk = format!("warning: {} {}", "字".repeat(15), "字".repeat(15));
        let w = super::wrap_messages(&cjk, 40);
        assert_eq!(w.lines().count(), 2, "{w}");
    }

    use super::*;

    /// `--pixel-size`: one or two positive numbers; lengths and the
    /// non-square warning.
    #[test]
    fn pixel_size_parses_and_speaks() {
        let p = |s: &str, u: Option<&str>| PixelOpts {
            pixel_size: Some(s.into()),
            units: u.map(str::to_string),
        };
        let given = |o: PixelOpts| {
            o.resolve(&[]).map(|(p, w)| {
                assert!(w.is_empty());
                p
            })
        };
        let sq = given(p("90", Some("m"))).unwrap().unwrap();
        assert_eq!((sq.x, sq.y, sq.side()), (90.0, 90.0, 90.0));
        assert_eq!(sq.length(2.125), "191.2 m");
        assert!(sq.warning(Isotropic::Wavelet).is_none());
        let r = given(p("77.5:92.6", None)).unwrap().unwrap();
        assert_eq!(r.units, "units");
        assert!((r.side() - (77.5f64 * 92.6).sqrt()).abs() < 1e-12);
        // x y would underflow (and overflow for the reciprocal pixel)
        let tiny = PixelSize {
            x: 1e-200,
            y: 4e-200,
            ..r.clone()
        };
        assert!(
            (tiny.side() / 2e-200 - 1.0).abs() < 1e-12,
            "{}",
            tiny.side()
        );
        let w = r.warning(Isotropic::Wavelet).unwrap();
        assert!(
            w.contains("and the wavelet, isotropic in pixels, mixes"),
            "{w}"
        );
        let t = r.warning(Isotropic::BoxesAndSpectrum).unwrap();
        assert!(
            t.contains(
                "square boxes and the angle-averaged spectrum, isotropic in pixels, mix directions"
            ),
            "{t}"
        );
        assert!(
            w.contains("77.5 x 92.6 units") && w.contains("0.837"),
            "{w}"
        );
        for bad in ["0", "-1", "nan", "1:2:3", "a", "1:"] {
            let e = given(p(bad, None)).unwrap_err().to_string();
            assert!(e.contains("`pixel-size`"), "{bad}: {e}");
        }
        assert_eq!(given(PixelOpts::default()).unwrap(), None);
        assert_eq!(sq.note(), None);
    }

    /// Without `--pixel-size`, the spacing all the images declare; images
    /// that disagree or declare none give no lengths and a warning, as does
    /// a `--pixel-size` that contradicts a file.
    #[test]
    fn pixel_size_from_the_files() {
        let dir = std::env::temp_dir().join(format!("wtmm-pixel-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let grid = |name: &str, cell: Option<f64>| {
            let p = dir.join(format!("{name}.asc"));
            let head = cell.map_or(String::new(), |c| format!("cellsize {c}\n"));
            std::fs::write(&p, format!("ncols 2\nnrows 2\n{head}1 2\n3 4\n")).unwrap();
            std::fs::write(p.with_extension("prj"), "PROJCS[\"u\",UNIT[\"Meter\",1.0]]").unwrap();
            p
        };
        let (a, b, c, d) = (
            grid("a", Some(30.0)),
            grid("b", Some(30.0)),
            grid("c", Some(10.0)),
            grid("d", None),
        );
        let auto = PixelOpts::default();
        let (px, w) = auto.resolve(&[a.clone(), b.clone()]).unwrap();
        let px = px.unwrap();
        assert_eq!((px.x, px.y, px.units.as_str()), (30.0, 30.0, "m"));
        assert!(w.is_empty(), "{w:?}");
        let n = px.note().unwrap();
        assert!(n.contains("30 x 30 m") && n.contains("all 2 images"), "{n}");
        assert_eq!(px.json()["source"], px.source.as_str());
        let (px, w) = auto.resolve(&[a.clone(), c.clone()]).unwrap();
        assert!(
            px.is_none() && w[0].contains("different pixel spacings"),
            "{w:?}"
        );
        assert!(
            w[0].contains("30 m in") && w[0].contains("10 m in"),
            "{w:?}"
        );
        let (px, w) = auto.resolve(&[a.clone(), d.clone()]).unwrap();
        assert!(px.is_none() && w[0].starts_with("1 of 2 images"), "{w:?}");
        assert_eq!(
            auto.resolve(std::slice::from_ref(&d)).unwrap(),
            (None, vec![])
        );
        // --pixel-size wins, and says so when a file disagrees
        let opts = |s: &str, u: Option<&str>| PixelOpts {
            pixel_size: Some(s.into()),
            units: u.map(str::to_string),
        };
        let (px, w) = opts("90", Some("m"))
            .resolve(std::slice::from_ref(&a))
            .unwrap();
        assert_eq!(px.unwrap().x, 90.0);
        assert!(w[0].contains("differs from the 30 m"), "{w:?}");
        // the same number without --units: used, and the file's unit named
        let (px, w) = opts("30", None).resolve(std::slice::from_ref(&a)).unwrap();
        assert_eq!(px.unwrap().units, "units");
        assert!(
            w.len() == 1 && w[0].contains("has no --units") && w[0].contains("--units m"),
            "{w:?}"
        );
        // units wtmm knows are compared in metres: 0.03 km is the file's
        // 30 m, 0.09 km or 20 metres are not; unknown units cannot be
        // compared, and that is said
        let warnings = |v: &str, u: &str| {
            opts(v, Some(u))
                .resolve(std::slice::from_ref(&a))
                .unwrap()
                .1
        };
        assert!(warnings("0.03", "km").is_empty());
        for (v, u) in [("0.09", "km"), ("20", "metres")] {
            let w = warnings(v, u);
            assert!(
                w.len() == 1 && w[0].contains("differs from the 30 m"),
                "{u}: {w:?}"
            );
        }
        let w = warnings("7", "cubits");
        assert!(
            w.len() == 1 && w[0].contains("cannot be compared with the 30 m"),
            "{w:?}"
        );
        // the same number, one without units: said as such
        let bare = dir.join("bare.asc");
        std::fs::write(&bare, "ncols 2\nnrows 2\ncellsize 30\n1 2\n3 4\n").unwrap();
        let (px, w) = auto.resolve(&[a.clone(), bare]).unwrap();
        assert!(
            px.is_none() && w[0].contains("in units that cannot be compared (one unnamed"),
            "{w:?}"
        );
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// A panic during a command removes the (empty) output directories the
    /// command created; a normal drop leaves them to the explicit clean-up.
    #[test]
    fn a_panic_removes_the_directories_it_created() {
        let root = std::env::temp_dir().join(format!("wtmm-panic-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&root);
        let deep = root.join("x").join("y");
        std::fs::create_dir_all(&deep).unwrap();
        note_created(vec![root.clone(), root.join("x"), deep.clone()]);
        {
            let _g = PanicCleanup(Some(&root));
        }
        assert!(deep.exists(), "no panic: nothing removed");
        let hook = std::panic::take_hook();
        std::panic::set_hook(Box::new(|_| {}));
        let r = std::panic::catch_unwind(|| {
            // as in `dispatch`: the guard before the batch, so that the
            // batch removes its pending temporary first and the directory
            // is empty when the guard removes it
            let _g = PanicCleanup(Some(&root));
            let _batch = crate::io::OutputBatch::begin(&deep).unwrap();
            crate::io::write_atomic(&deep.join("a.txt"), b"a").unwrap();
            assert!(std::fs::read_dir(&deep).unwrap().next().is_some());
            panic!("a bug");
        });
        std::panic::set_hook(hook);
        assert!(r.is_err());
        assert!(!root.exists(), "{} left behind", root.display());
    }
}
