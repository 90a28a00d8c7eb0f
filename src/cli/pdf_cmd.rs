//! `wtmm pdf IMAGE... --out DIR`: the WTMMM pdfs of II Figs 11-14 and 17-20
//! (SPEC §5, §13), and the input handling shared by `pdf`, `kernel` and
//! `correlate`.
//!
//! **Inputs.** Either image files, or no image and a model (`--preset NAME`
//! or `--theory MODEL` with its options), of which `--count` images of
//! `--size` are generated in memory and streamed (generate, analyse, drop;
//! in parallel over images), as `validate` does. The model, when named, is
//! also the theory drawn over the estimates.
//!
//! **Domain.** `--domain torus` analyses the whole periodic image (margin 0,
//! correlations wrap around); `interior` uses the SPEC §1 margin. `auto` =
//! torus for generated W-cascades, FISC and FIF (periodic by construction)
//! and for the files `synth` wrote from them
//! ([`super::common::periodic_synth`]), interior otherwise (other files,
//! fBm).

use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};

use clap::{Args, ValueEnum};
use serde_json::json;

use super::analyze_cmd::{LineOpts, fit_range};
use super::common::{f, header, make_out_dir, parse_list, progress, write_csv, write_json};
use super::common::{save_chart, save_raster_chart};
use super::model_args::{ModelName, ModelOpts};
use super::{OutDir, Outcome};
use crate::cwt::Wavelet;
use crate::error::{Error, Result};
use crate::field::Field;
use crate::plot::{Chart, ColorBar, Raster, RasterChart, Series, Style, viridis};
use crate::skeleton::{AnalysisConfig, Parallelism};
use crate::stats::kernel::{nearest_scale, octave_on_grid};
use crate::stats::pdf::{
    DensityBins, PdfConfig, PdfOptions, ScalePdf, WtmmmHistograms, WtmmmSet, image_wtmmm,
    wtmmm_pdfs,
};
use crate::theory::Model;

/// Analysis domain.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum DomainChoice {
    /// Torus for the generated models that are periodic (W-cascades, FISC, FIF)
    /// and for the files `wtmm synth` wrote from them (listed in the synth.json
    /// beside them, not changed since; not with --detrend), interior otherwise.
    Auto,
    /// Interior: leaves out a margin where the wavelet at the largest scale
    /// reaches the border (non-periodic data; its width: --margin).
    Interior,
    /// The whole image, periodic (margin 0, lags wrap around).
    Torus,
}

/// Images or a generated ensemble, and the theory (shared by pdf, kernel,
/// correlate).
#[derive(Args, Debug, Clone)]
pub struct StatsInput {
    /// Input images, one ensemble. Omit them to generate `--count` images of the
    /// model named by `--preset` or `--theory`.
    pub images: Vec<PathBuf>,
    /// Model drawn over the estimates (with its options, as for `synth`); without
    /// IMAGE also the model generated. `--preset NAME` names one too.
    #[arg(long, value_enum)]
    pub theory: Option<ModelName>,
    #[command(flatten)]
    pub model: ModelOpts,
    /// Generated ensemble: number of images [default: 32].
    #[arg(long)]
    pub count: Option<usize>,
    /// Generated ensemble: image side (a power of two for the cascades) [default: 1024].
    #[arg(long)]
    pub size: Option<usize>,
    /// Generated ensemble: seed (image i is the same as `synth --seed S` image
    /// i) [default: 1].
    #[arg(long)]
    pub seed: Option<u64>,
    /// Analysis domain: torus (periodic images) or interior (inside the margin
    /// where the wavelet reaches the border).
    #[arg(long, value_enum, default_value = "auto")]
    pub domain: DomainChoice,
    #[command(flatten)]
    pub pixel: super::PixelOpts,
    #[command(flatten)]
    pub read: super::ReadOpts,
    /// Fill missing pixels harmonically and count them as data, as `analyze
    /// --fill-holes` (across the borders under --domain torus). Without it
    /// the WTMMM and the correlations leave out every point whose wavelet
    /// reaches a missing pixel, so scattered voids leave little to count. A
    /// large hole becomes a smooth patch, of high h: crop such holes
    /// instead.
    #[arg(long)]
    pub fill_holes: bool,
}

/// A resolved input.
pub struct Input {
    pub images: Vec<PathBuf>,
    /// The theory (and the generated model when `images` is empty).
    pub model: Option<Model>,
    /// Preset or model name, for titles.
    pub name: String,
    pub count: usize,
    pub size: usize,
    pub seed: u64,
    pub periodic: bool,
    /// The `synth` record whose defaults (the torus, the wavelet) the image
    /// files took.
    pub origin: Option<super::common::PeriodicSynth>,
    /// The wavelet the preset recommends (gauss without a model).
    pub wavelet: Wavelet,
    /// Missing pixels met by [`Input::fold`], so that an ensemble-level
    /// shortage of maxima can name them as its likely cause.
    pub holes: HoleTally,
    /// The images' least-squares plane shares ([`Field::plane_share`]) and
    /// terrace widths ([`Field::terrace_width`]) met by [`Input::fold`],
    /// for the planar-trend and quantisation warnings.
    pub tally: FieldTally,
    /// The pixel (`--pixel-size`, or what the files declare): scales also
    /// as lengths.
    pub pixel: Option<super::PixelSize>,
    /// What [`super::PixelOpts::resolve`] had to say, and the non-square
    /// warning.
    pub pixel_warnings: Vec<String>,
    /// `--nodata`: a value read as missing ([`super::common::read_image`]).
    pub nodata: Option<f64>,
    /// `--fill-holes`: missing pixels filled harmonically and counted as
    /// data ([`super::common::fill_holes_noted`]).
    pub fill_holes: bool,
}

/// Images with missing pixels (NaN, inf, nodata) and their holes, tallied
/// while folding (shared across the rayon workers); `filled` when
/// `--fill-holes` filled them.
#[derive(Debug, Default)]
pub struct HoleTally {
    images: AtomicUsize,
    pixels: AtomicUsize,
    largest: AtomicUsize,
    in_large: AtomicUsize,
    /// Every image's pixels, with holes or not.
    area: AtomicUsize,
    filled: bool,
    /// The holes are counted, and filled, across the borders.
    torus: bool,
}

impl HoleTally {
    /// An empty tally; `filled`: the holes are filled (`--fill-holes`);
    /// `torus`: the images are tori, and their holes are counted (and
    /// filled) across the borders.
    pub fn new(filled: bool, torus: bool) -> Self {
        HoleTally {
            filled,
            torus,
            ..Default::default()
        }
    }

    /// Tallies an image's holes (counted as [`Self::new`]'s `torus` says).
    fn add(&self, h: &super::common::HoleSizes) {
        self.area.fetch_add(h.area, Ordering::Relaxed);
        if h.missing > 0 {
            self.images.fetch_add(1, Ordering::Relaxed);
            self.pixels.fetch_add(h.missing, Ordering::Relaxed);
            self.largest.fetch_max(h.largest, Ordering::Relaxed);
            self.in_large.fetch_add(h.in_large, Ordering::Relaxed);
        }
    }

    /// The tally as one [`super::common::HoleSizes`] of all the images.
    fn sizes(&self) -> super::common::HoleSizes {
        super::common::HoleSizes {
            missing: self.pixels.load(Ordering::Relaxed),
            largest: self.largest.load(Ordering::Relaxed),
            in_large: self.in_large.load(Ordering::Relaxed),
            area: self.area.load(Ordering::Relaxed),
        }
    }

    /// `{images, pixels, largest_hole, in_large_holes, filled}`: the
    /// images with missing pixels, their count, the largest hole's pixels,
    /// the pixels in holes larger than
    /// [`crate::field::LARGE_FILLED_HOLE`] and whether they were filled
    /// (recorded with the inputs; zeros when there were none).
    pub fn json(&self) -> serde_json::Value {
        let h = self.sizes();
        json!({"images": self.images.load(Ordering::Relaxed), "pixels": h.missing,
            "largest_hole": h.largest, "in_large_holes": h.in_large, "filled": self.filled})
    }

    /// A warning saying how many images had missing pixels, which leave out
    /// of `what` every point the wavelet reaches from them, or which were
    /// filled and counted as data; `None` without.
    pub fn warning(&self, of: usize, what: &str) -> Option<String> {
        let (k, n) = (
            self.images.load(Ordering::Relaxed),
            self.pixels.load(Ordering::Relaxed),
        );
        if self.filled {
            return (k > 0).then(|| {
                format!(
                    "{k} of the {of} image(s) have missing pixels (NaN, inf or nodata; {n} in \
                     all): filled harmonically{} and counted as data (--fill-holes; {})",
                    if self.torus {
                        " across the borders (tori)"
                    } else {
                        ""
                    },
                    self.sizes().describe()
                )
            });
        }
        (k > 0).then(|| {
            format!(
                "{k} of the {of} image(s) have missing pixels (NaN, inf or nodata; {n} in all): \
                 {what} leave out every point whose wavelet reaches one"
            )
        })
    }

    /// What to add to a "too few maxima" message when images had holes
    /// (not filled).
    pub fn note(&self, of: usize) -> Option<String> {
        let (k, n) = (
            self.images.load(Ordering::Relaxed),
            self.pixels.load(Ordering::Relaxed),
        );
        (k > 0 && !self.filled).then(|| {
            format!(
                "; {k} of the {of} image(s) have missing pixels (NaN, inf or nodata; {n} in \
                 all), and maxima count only farther from them than the wavelet's support at \
                 each scale, so scattered gaps leave few maxima at the larger scales: fill the \
                 gaps (--fill-holes) or crop to a gap-free region"
            )
        })
    }
}

/// The share of each image's variance its least-squares plane explains,
/// and its terraces and flat value, collected while folding (shared across
/// the rayon workers).
#[derive(Debug, Default)]
pub struct FieldTally(Mutex<Vec<f64>>, Mutex<Vec<Quantisation>>);

/// One image's [`crate::spectra::quantisation`]: terrace width and flat value.
type Quantisation = (Option<f64>, Option<crate::spectra::FlatRecord>);

impl FieldTally {
    fn add(&self, field: &Field) {
        if let Some(r) = field.plane_share() {
            self.0.lock().unwrap_or_else(|e| e.into_inner()).push(r);
        }
        self.1
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .push(crate::spectra::quantisation(field));
    }

    /// [`crate::spectra::terrace_warning`] of the terraces met, against
    /// `a`, the smallest scale that counts (`what_a`; `remedy` as there),
    /// and [`crate::spectra::flat_warning`] of the flat values.
    pub fn quantisation_warnings(
        &self,
        a: f64,
        what_a: &str,
        remedy: impl Fn(f64) -> String,
    ) -> Vec<String> {
        let q = self.1.lock().unwrap_or_else(|e| e.into_inner()).clone();
        let widths: Vec<Option<f64>> = q.iter().map(|x| x.0).collect();
        let flats: Vec<Option<crate::spectra::FlatRecord>> = q.iter().map(|x| x.1).collect();
        crate::spectra::terrace_warning(&widths, a, what_a, "", remedy)
            .into_iter()
            .chain(crate::spectra::flat_warning(&flats))
            .collect()
    }

    /// What to add to a "too few maxima" message when the median image is
    /// mostly a plane (which, under the gauss wavelet undetrended, swamps
    /// the surface at large scales).
    pub fn note(&self) -> Option<String> {
        let s = self.0.lock().unwrap_or_else(|e| e.into_inner()).clone();
        let median = crate::skeleton::median(&s)?;
        let whose = if s.len() == 1 {
            format!("{:.0} % of the image's variance", 100.0 * median)
        } else {
            format!("a median {:.0} % of the images' variance", 100.0 * median)
        };
        (median > crate::spectra::PLANE_SHARE_WARN).then(|| {
            format!(
                "; the least-squares plane explains {whose}: under the gauss wavelet without \
                 --detrend plane it swamps the surface at large scales (see wtmm info)"
            )
        })
    }

    /// [`AnalysisConfig::plane_warning`] of the shares met, for `images`.
    pub fn warning(&self, cfg: &AnalysisConfig, images: usize) -> Option<String> {
        let shares = self.0.lock().unwrap_or_else(|e| e.into_inner()).clone();
        cfg.plane_warning(&shares, images)
    }
}

impl StatsInput {
    /// Refuses a model name given where a file goes (`kernel wcascade ...`
    /// as `synth wcascade ...`: here a model is named by --theory, the
    /// positional arguments are files), before a missing file is blamed.
    pub fn refuse_model_names(&self) -> Result<()> {
        for p in &self.images {
            let name = p.to_string_lossy();
            if !p.exists() && ModelName::from_str(&name, true).is_ok() {
                return Err(Error::param(
                    "IMAGE",
                    format!(
                        "`{name}` is a model, not a file: name the model to generate or draw \
                         with --theory {name} (with its options), or use --preset NAME"
                    ),
                ));
            }
        }
        Ok(())
    }

    /// Checks the flags and resolves the model.
    /// `line.cwt.margin` is `--margin`: it must agree with `--domain`
    /// (margin 0 is the torus), and under `auto` it decides. Without it,
    /// `auto` takes the torus for a generated periodic model, and for
    /// files `wtmm synth` wrote from one
    /// ([`super::common::periodic_synth`]) unless `--detrend` is given (a
    /// plane is removed inside a margin only).
    ///
    /// **Errors** naming the flag: neither images nor a model, a model option
    /// without a model, `--count 0`. (A model name where a file goes is
    /// refused before, with the inputs: `refuse_model_names`.)
    pub fn resolve(&self, line: &LineOpts) -> Result<Input> {
        let margin = line.cwt.margin;
        let resolved = self.model.resolve_optional(self.theory)?;
        if self.images.is_empty() && resolved.is_none() {
            return Err(Error::param(
                "IMAGE",
                "give image files, or a model to generate (--preset NAME, or --theory MODEL with its options)",
            ));
        }
        let nodata = self.read.value()?;
        for (set, flag) in [
            (nodata.is_some(), "nodata"),
            (self.fill_holes, "fill-holes"),
        ] {
            if self.images.is_empty() && set {
                return Err(Error::param(
                    flag,
                    "applies to image files, not to a generated ensemble",
                ));
            }
        }
        if !self.images.is_empty() {
            // generator options with files would be dropped without a word
            for (set, flag) in [
                (self.count.is_some(), "count"),
                (self.size.is_some(), "size"),
                (self.seed.is_some(), "seed"),
            ] {
                if set {
                    return Err(Error::param(
                        flag,
                        "applies to a generated ensemble, not to image files",
                    ));
                }
            }
        }
        let (count, size, seed) = (
            self.count.unwrap_or(32),
            self.size.unwrap_or(1024),
            self.seed.unwrap_or(1),
        );
        let generated = self.images.is_empty();
        if generated {
            super::common::check_generated(size, count)?;
        }
        if let Some(r) = resolved.as_ref().filter(|_| generated) {
            r.model.check_size(size)?;
        }
        let (pixel, mut pixel_warnings) = self.pixel.resolve(&self.images)?;
        pixel_warnings.extend(
            pixel
                .as_ref()
                .and_then(|p| p.warning(super::Isotropic::Wavelet)),
        );
        let periodic = match (self.domain, margin) {
            (DomainChoice::Torus, Some(m)) if m != 0 => {
                return Err(Error::param(
                    "margin",
                    format!(
                        "--domain torus analyses the whole periodic image (margin 0), not a \
                         {m} px margin: drop --margin or use --domain interior"
                    ),
                ));
            }
            (DomainChoice::Interior, Some(0)) => {
                return Err(Error::param(
                    "margin",
                    "margin 0 is the whole image taken as a torus: use --domain torus",
                ));
            }
            (DomainChoice::Torus, _) => true,
            (DomainChoice::Interior, _) => false,
            // what is computed: margin 0 is the torus
            (DomainChoice::Auto, Some(m)) => m == 0,
            (DomainChoice::Auto, None) => {
                generated && resolved.as_ref().is_some_and(|r| r.model.is_periodic())
            }
        };
        // files synth wrote from a periodic model: validate's torus (when
        // the domain is left to auto) and its wavelet (when neither
        // --wavelet nor a theory names one)
        let torus_open = matches!(
            (self.domain, margin, line.detrend),
            (DomainChoice::Auto, None, crate::field::Trend::None)
        );
        let wavelet_open = line.cwt.wavelet.is_none() && resolved.is_none();
        let origin = if !generated && (torus_open || wavelet_open) {
            super::common::periodic_synth(
                &self.images,
                torus_open.then_some("inside the margin: --domain torus takes tori whole"),
                wavelet_open,
            )
        } else {
            None
        };
        let origin_wavelet = origin
            .as_ref()
            .and_then(|o| o.wavelet)
            .filter(|_| wavelet_open);
        let origin =
            origin.filter(|_| torus_open || origin_wavelet.is_some_and(|w| w != Wavelet::Gauss));
        if let Some(o) = origin.as_ref().filter(|_| torus_open) {
            say!(
                "note: {}: analysed whole, as a torus (--domain torus), as validate analyses \
                 the model; give --domain interior for the interior",
                o.describe(self.images.len())
            );
        }
        let periodic = periodic || (torus_open && origin.is_some());
        Ok(Input {
            images: self.images.clone(),
            name: resolved
                .as_ref()
                .map(|r| r.preset.unwrap_or(r.model.name()).to_string())
                .unwrap_or_default(),
            model: resolved.as_ref().map(|r| r.model),
            wavelet: resolved
                .as_ref()
                .map(|r| r.wavelet)
                .or(origin_wavelet)
                .unwrap_or(Wavelet::Gauss),
            count,
            size,
            seed,
            periodic,
            origin,
            holes: HoleTally::new(self.fill_holes, periodic),
            tally: FieldTally::default(),
            pixel,
            pixel_warnings,
            nodata,
            fill_holes: self.fill_holes,
        })
    }
}

impl Input {
    /// True when the images are generated.
    pub fn generated(&self) -> bool {
        self.images.is_empty()
    }

    /// Number of images.
    pub fn len(&self) -> usize {
        if self.generated() {
            self.count
        } else {
            self.images.len()
        }
    }

    /// Always false (resolve refuses an empty input).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The analysis configuration: the preset's wavelet unless `--wavelet`,
    /// margin 0 on the torus unless `--margin`.
    pub fn analysis(&self, opts: &LineOpts) -> Result<AnalysisConfig> {
        let mut o = opts.clone();
        if o.cwt.wavelet.is_none() {
            o.cwt.wavelet = Some(self.wavelet);
            // on the user's images the theory overlay changes the
            // measurement itself: said, not only recorded (as in analyze)
            let default = AnalysisConfig::default().wavelet;
            if !self.generated() && self.wavelet != default {
                say!(
                    "note: analysing with the {} wavelet, the one {} recommends (the default \
                     without a theory is {default}); give --wavelet to choose",
                    self.wavelet,
                    if self.name.is_empty() {
                        "the synth.json beside the files"
                    } else {
                        &self.name
                    }
                );
            }
        }
        if self.periodic && o.cwt.margin.is_none() {
            o.cwt.margin = Some(0);
        }
        o.analysis()
    }

    /// Image `i` and its label.
    pub fn load(&self, i: usize) -> Result<(Field, String)> {
        let notes = super::common::OrderedNotes::default();
        let r = self.load_noted(i, &notes, None);
        notes.say();
        r
    }

    /// [`Self::load`] of an image already loaded (and warned about) once:
    /// its read warnings are not said again.
    pub fn reload(&self, i: usize) -> Result<(Field, String)> {
        self.load_noted(i, &super::common::OrderedNotes::default(), None)
    }

    /// Image `i`'s `(ny, nx)`, read without its warnings and without
    /// `--fill-holes`' fill.
    pub fn dims(&self, i: usize) -> Result<(usize, usize)> {
        if self.generated() {
            return Ok((self.size, self.size));
        }
        let notes = super::common::OrderedNotes::default();
        Ok(super::common::read_image_noted(&self.images[i], self.nodata, i, &notes)?.dim())
    }

    /// [`Self::load`] with the read's warnings held in `notes` (images
    /// loaded in parallel say theirs in input order), the holes tallied in
    /// `holes` when given (before `--fill-holes` fills them).
    fn load_noted(
        &self,
        i: usize,
        notes: &super::common::OrderedNotes,
        holes: Option<&HoleTally>,
    ) -> Result<(Field, String)> {
        if self.generated() {
            let model = self.model.expect("generated inputs have a model");
            let img = model.synthesize(self.size, self.seed, i as u64)?;
            Ok((Field::new(img), format!("{} image {i}", self.name)))
        } else {
            let p = &self.images[i];
            let field = super::common::read_image_noted(p, self.nodata, i, notes)?;
            // the holes are labelled once, for the fill and the tally
            let (field, sizes) = if self.fill_holes {
                let (f, h) = super::common::fill_holes_noted(
                    field,
                    p,
                    self.periodic,
                    (i, self.images.len() == 1),
                    notes,
                )?;
                (f, Some(h))
            } else {
                let h = holes.map(|_| super::common::HoleSizes::of(&field, self.periodic));
                (field, h)
            };
            if let (Some(t), Some(h)) = (holes, sizes) {
                t.add(&h);
            }
            super::common::refuse_constant(&field, p, crate::skeleton::CONSTANT)?;
            super::common::check_image_memory(p, &field, self.images.len() == 1)?;
            Ok((field, p.display().to_string()))
        }
    }

    /// Runs `step` on every image (in parallel over images, each image
    /// analysed serially unless there is only one) folding into accumulators
    /// merged with `merge`; files of an ensemble on as many threads as the
    /// memory holds their images at `per_px` bytes per pixel each
    /// ([`super::common::memory_workers`]). Errors name the image.
    pub fn fold<A, I, S, M>(
        &self,
        quiet: bool,
        msg: &str,
        per_px: f64,
        init: I,
        step: S,
        merge: M,
    ) -> Result<A>
    where
        A: Send,
        I: Fn() -> A + Sync + Send,
        S: Fn(&mut A, &Field, &str, Parallelism) -> Result<()> + Sync + Send,
        M: Fn(A, A) -> Result<A> + Sync + Send,
    {
        let n = self.len();
        let par = if n == 1 {
            Parallelism::Scales
        } else {
            Parallelism::Serial
        };
        // an ensemble: one image per worker, as many workers as the memory
        // holds images (a lone file is checked with its threads once read)
        let limit = if self.generated() {
            super::common::check_generated_memory(self.size, n, per_px, "the analysis")?
        } else {
            super::common::ensemble_memory_workers(&self.images, per_px, "the analysis")?
        };
        let pb = progress(n as u64, msg, quiet);
        let notes = super::common::OrderedNotes::default();
        // the first bad image in input order is named, whatever the scheduling
        let out = crate::par::try_fold_limited(
            n,
            limit,
            &init,
            |acc, i| -> Result<()> {
                let (field, label) = self.load_noted(i, &notes, Some(&self.holes))?;
                self.tally.add(&field);
                step(acc, &field, &label, par).map_err(|e| {
                    if self.generated() {
                        e
                    } else {
                        super::common::in_file(&self.images[i], e)
                    }
                })?;
                pb.inc(1);
                Ok(())
            },
            &merge,
        );
        pb.finish_and_clear();
        notes.say_upto(out.as_ref().err().map(|f| f.0));
        out.map_err(|f| f.1)
    }

    /// The input in a message: the file, the files, or the generated
    /// ensemble as `--preset NAME` (or `--theory MODEL`).
    pub fn describe(&self) -> String {
        if self.generated() {
            let model = self.model.map_or("", |m| m.name());
            let flag = if self.name == model {
                "--theory"
            } else {
                "--preset"
            };
            let (n, s) = (self.count, self.size);
            let n = super::common::count_of(n, "image");
            return format!("{flag} {} ({n} of {s}x{s})", self.name);
        }
        let names: Vec<String> = self
            .images
            .iter()
            .map(|p| p.display().to_string())
            .collect();
        match names.len() {
            0..=3 => names.join(", "),
            n => format!("{}, ... ({n} images)", names[..2].join(", ")),
        }
    }

    /// A fault of the data ([`Error::Input`]) found in the ensemble as a
    /// whole (not one image), naming the input: a single file as the file at
    /// fault, else in the message. Other errors pass unchanged.
    /// Missing pixels met while folding are named as the likely cause.
    pub fn blame(&self, e: Error) -> Error {
        let Error::Input(mut msg) = e else { return e };
        if let Some(note) = self.holes.note(self.len()) {
            msg.push_str(&note);
        }
        if let Some(note) = self.tally.note() {
            msg.push_str(&note);
        }
        match self.images.as_slice() {
            [one] => Error::format(one, msg),
            _ => Error::Input(format!("{}: {msg}", self.describe())),
        }
    }

    /// What a figure's title says of its data: the preset (or files), the
    /// images and their size, the wavelet, and a plane removed (`--detrend`).
    pub fn title(&self, cfg: &AnalysisConfig) -> String {
        let w = format!(
            "{}{}",
            cfg.wavelet.name(),
            super::common::trend_label(cfg.detrend)
        );
        if self.generated() {
            let (n, s) = (self.count, self.size);
            let n = super::common::count_of(n, "image");
            return format!("{}, {n} of {s}x{s}, {w}", self.name);
        }
        let what = match self.images.as_slice() {
            [one] => super::common::file_label(one),
            many => format!("{} images", many.len()),
        };
        if self.name.is_empty() {
            format!("{what}, {w}")
        } else {
            format!("{what} ({}), {w}", self.name)
        }
    }

    /// What goes into `params` of every output.
    pub fn params_json(&self) -> serde_json::Value {
        if self.generated() {
            json!({"generated": {"model": self.model, "name": self.name, "count": self.count,
                "size": self.size, "seed": self.seed}, "periodic": self.periodic,
                "pixel_size": self.pixel.as_ref().map(super::PixelSize::json)})
        } else {
            json!({"images": super::common::paths_json(&self.images), "theory": self.model, "periodic": self.periodic,
                "origin": self.origin.as_ref().map(super::common::PeriodicSynth::json),
                "missing_pixels": self.holes.json(), "nodata": self.nodata,
                "pixel_size": self.pixel.as_ref().map(super::PixelSize::json)})
        }
    }

    /// Says where the pixel size came from (unless `quiet`), on stderr;
    /// the pixel warnings go with each command's own (JSON and stderr).
    pub fn say_pixel(&self, quiet: bool) {
        super::PixelSize::say_note(self.pixel.as_ref(), quiet);
    }

    /// `values` px as lengths in the pixel's units (`null` without a
    /// pixel), for the JSON beside the pixel values.
    pub fn lengths(&self, values: &[f64]) -> serde_json::Value {
        match &self.pixel {
            Some(p) => json!(values.iter().map(|v| v * p.side()).collect::<Vec<_>>()),
            None => serde_json::Value::Null,
        }
    }

    /// The unit of [`Input::lengths`] (`null` without a pixel).
    pub fn length_units(&self) -> serde_json::Value {
        json!(self.pixel.as_ref().map(|p| &p.units))
    }
}

/// Why an image gave no maxima: [`Input::fold`] names a file itself, a
/// generated image is named here.
pub fn no_maxima(input: &Input, label: &str, field: &Field, cfg: &AnalysisConfig) -> Error {
    let why = cfg.why_no_maxima(field);
    if input.generated() {
        Error::Input(format!("{label}: {why}"))
    } else {
        Error::Input(why)
    }
}

/// Scale indices nearest to octaves above a_min, deduplicated.
pub fn scales_at(scales: &[f64], octaves: &[f64]) -> Vec<usize> {
    let mut v: Vec<usize> = octaves.iter().map(|&o| nearest_scale(scales, o)).collect();
    v.dedup();
    v
}

/// Octaves spanned by the grid above its smallest scale, rounded to 1e-9
/// (`log2` of a ratio: 2.9 would print as 2.9000000000000004).
pub fn grid_top(scales: &[f64]) -> f64 {
    ((scales[scales.len() - 1] / scales[0]).log2() * 1e9).round() / 1e9
}

/// Checks that octaves lie on the scale grid.
pub fn check_octaves(flag: &str, octaves: &[f64], scales: &[f64]) -> Result<()> {
    let top = grid_top(scales);
    if let Some(o) = octaves.iter().find(|&&o| !octave_on_grid(scales, o)) {
        return Err(Error::param(
            flag,
            format!(
                "octave {} is outside the scales (0..{top:.2} octaves above a_min)",
                crate::error::short(*o)
            ),
        ));
    }
    // between two voices: the value would be read at the nearest scale and
    // recorded as given
    let step = if scales.len() > 1 {
        (scales[1] / scales[0]).log2()
    } else {
        1.0
    };
    if let Some(o) = octaves
        .iter()
        .find(|&&o| ((o / step).round() - o / step).abs() > 1e-6)
    {
        return Err(Error::param(
            flag,
            format!(
                "octave {} lies between two scales: use a multiple of the voice step {step:.4} octave",
                crate::error::short(*o)
            ),
        ));
    }
    Ok(())
}

/// An option listing octaves above a_min: the given values, each checked
/// against the grid, or without one the values of `default` that lie on the
/// grid (so the paper's defaults follow a shorter `--octaves`).
///
/// **Errors** when a given octave is off the grid, or no default one is on it.
pub fn octaves_or_default(
    flag: &str,
    given: Option<&str>,
    default: &str,
    scales: &[f64],
) -> Result<Vec<f64>> {
    if let Some(s) = given {
        let v = parse_list(flag, s)?;
        check_octaves(flag, &v, scales)?;
        return Ok(v);
    }
    let top = grid_top(scales);
    let v: Vec<f64> = parse_list(flag, default)?
        .into_iter()
        .filter(|&o| octave_on_grid(scales, o))
        .collect();
    if v.is_empty() {
        return Err(Error::param(
            flag,
            format!(
                "none of the default octaves {default} lies on the scales (0..{top:.2} octaves above a_min): give --{flag}"
            ),
        ));
    }
    Ok(v)
}

#[derive(Args, Debug)]
pub struct PdfArgs {
    #[command(flatten)]
    pub input: StatsInput,
    #[command(flatten)]
    pub opts: LineOpts,
    /// Fit range of the h(q=0) estimate for the rescaling test, octaves above
    /// a_min `LO:HI` (default 0.5:min(4, OCTAVES)).
    #[arg(long, allow_hyphen_values = true)]
    pub fit: Option<String>,
    /// Which WTMMM: those on maxima lines (the skeleton) or all WTMMM of each scale.
    #[arg(long, value_enum, default_value = "lines")]
    pub set: WtmmmSet,
    /// Scales shown, in octaves above a_min (II Figs 17, 20: a = 1, 2, 4, 8)
    /// [default: 0,1,2,3, those within --octaves].
    #[arg(long)]
    pub show: Option<String>,
    /// Scales of the pdfs conditioned on A (II Fig 18: a = 2^0.1, 2^1.1), in
    /// octaves [default: 0.1,1.1, those within --octaves].
    #[arg(long)]
    pub sectors_at: Option<String>,
    /// Exponent of the rescaling test II eq 39 (default: the theory's h(q=0), else
    /// the slope of <ln M> against ln a over the fit range).
    #[arg(long, allow_negative_numbers = true)]
    pub h0: Option<f64>,
    /// Bin width of ln M in the accumulated histograms (the finest the pdfs
    /// can be drawn on).
    #[arg(long, default_value_t = 0.05)]
    pub lnm_bin: f64,
    /// Bins of the pdfs drawn and written: auto = per scale, the
    /// Freedman-Diaconis width 2 IQR n^(-1/3) of its ln M as a whole number of
    /// --lnm-bin (wider where a scale has few WTMMM), of A for P(A) in merged
    /// --arg-bins, and Scott's rule for the joint density; fixed = --lnm-bin
    /// and --arg-bins everywhere.
    #[arg(long, value_enum, default_value = "auto")]
    pub bins: DensityBins,
    /// Number of bins of the argument A over [-pi, pi) (a multiple of 16).
    #[arg(long, default_value_t = 64)]
    pub arg_bins: usize,
    #[command(flatten)]
    pub out: OutDir,
}

/// Histograms of the chosen WTMMM set over the input.
pub fn collect_histograms(
    input: &Input,
    cfg: &AnalysisConfig,
    set: WtmmmSet,
    pcfg: PdfConfig,
    quiet: bool,
) -> Result<WtmmmHistograms> {
    let scales = cfg.scale_list();
    let empty = WtmmmHistograms::new(&scales, pcfg)?;
    input.fold(
        quiet,
        "pdf",
        super::common::ENSEMBLE_ANALYSIS_BYTES_PER_PIXEL,
        || empty.clone(),
        |acc, field, label, par| {
            let w = image_wtmmm(field, cfg, par, set == WtmmmSet::Lines)?;
            if w.all.first().is_none_or(|v| v.is_empty()) {
                return Err(no_maxima(input, label, field, cfg));
            }
            acc.merge(&WtmmmHistograms::from_points(&scales, pcfg, w.set(set))?)
        },
        |mut a, b| {
            a.merge(&b)?;
            Ok(a)
        },
    )
}

pub fn run(args: PdfArgs, quiet: bool) -> Result<Outcome> {
    let input = args.input.resolve(&args.opts)?;
    input.say_pixel(quiet);
    let cfg = input.analysis(&args.opts)?;
    let fit = fit_range(
        args.fit.as_deref(),
        args.opts.cwt.octaves,
        args.opts.cwt.voices,
    )?;
    let scales = cfg.scale_list();
    let show_oct = octaves_or_default("show", args.show.as_deref(), "0,1,2,3", &scales)?;
    let sec_oct = octaves_or_default("sectors-at", args.sectors_at.as_deref(), "0.1,1.1", &scales)?;
    let pcfg = PdfConfig {
        dlnm: args.lnm_bin,
        arg_bins: args.arg_bins,
    };
    pcfg.validate()?;
    // a Hölder exponent: |h0| beyond 10 only rescales the pdfs out of f64
    // (a^h0 with a up to 2^octaves) and is no surface's
    if let Some(h) = args.h0
        && !(h.is_finite() && h.abs() <= 10.0)
    {
        return Err(Error::param(
            "h0",
            format!(
                "must be a finite exponent in [-10, 10], got {h_s}",
                h_s = crate::error::short(h)
            ),
        ));
    }
    let t0 = std::time::Instant::now();
    let hist = collect_histograms(&input, &cfg, args.set, pcfg, quiet)?;
    let wall = t0.elapsed().as_secs_f64();
    // the estimate is also recorded when --h0 or the theory gives h0
    let mut warning = None;
    // the theory's h(q=0) is infinite for some models (FIF with alpha <= 1,
    // whose K(q) has no finite derivative at 0): the data's slope then
    let theory_h0 = input
        .model
        .as_ref()
        .map(|m| m.h_of_q0())
        .filter(|h| h.is_finite());
    let h_est = match hist.h0(fit, args.set) {
        Ok(h) => h,
        Err(e) if args.h0.is_none() && theory_h0.is_none() => {
            let m = format!("{}, or give --h0", super::common::reason(e));
            return Err(input.blame(Error::Input(m)));
        }
        Err(e) => {
            warning = Some(super::common::reason(e));
            f64::NAN
        }
    };
    let slope = "slope of <ln M> against ln a over the fit range";
    let (h0, h0_source) = match (args.h0, theory_h0) {
        (Some(h), _) => (h, "--h0".to_string()),
        (None, Some(h)) => (h, "theory h(q=0)".to_string()),
        (None, None) if input.model.is_some() => (
            h_est,
            format!("{slope} (the theory's h(q=0) is not finite)"),
        ),
        (None, None) => (h_est, slope.to_string()),
    };
    let show = scales_at(&scales, &show_oct);
    let sec = scales_at(&scales, &sec_oct);
    let few = check_shown_counts(&hist, &show, &sec, args.set).map_err(|e| input.blame(e))?;
    let mut all: Vec<usize> = show.iter().chain(&sec).copied().collect();
    all.sort_unstable();
    all.dedup();
    let pdfs = wtmmm_pdfs(
        &hist,
        &PdfOptions {
            show: all,
            h0,
            bins: args.bins,
            ..Default::default()
        },
    )?;
    let get = |j: usize| pdfs.iter().find(|p| p.j == j).expect("computed");
    make_out_dir(&args.out.out)?;
    let dir = &args.out.out;
    let mut body = header(
        "pdf",
        json!({"input": input.params_json(), "analysis": super::common::analysis_json(&cfg), "set": args.set,
            "fit_octaves": fit, "binning": pcfg, "bins": args.bins}),
    );
    super::common::note_caveats(&mut body, input.model.as_ref());
    body["set"] = json!(args.set);
    body["images"] = json!(hist.images);
    body["h0"] = json!({"value": h0, "source": h0_source, "estimate_from_data": h_est,
        "convention": "M / (a/a_min)^h0, a/a_min = the paper's sigma_W units (II eq 39)",
        "stderr": "not computed here: on the lines set the same slope over the same fit range \
                   is -c1 of `wtmm kernel` and h(q=0) of `wtmm analyze`, which give it with \
                   jackknife errors"});
    body["n_wtmmm"] = json!(hist.hist.iter().map(|h| h.n).collect::<Vec<_>>());
    body["scales"] = json!(scales);
    body["scale_lengths"] = input.lengths(&scales);
    body["length_units"] = input.length_units();
    body["pdfs"] = json!(show.iter().map(|&j| get(j)).collect::<Vec<_>>());
    body["sectors"] = json!(
        sec.iter()
            .map(|&j| {
                let p = get(j);
                json!({"a": p.a, "octave": p.octave, "m": p.sector_m,
                    "lnM_bin_width": p.sector_bin_width, "sectors": p.sectors})
            })
            .collect::<Vec<_>>()
    );
    body["wall_seconds"] = json!(wall);
    let holes = input.holes.warning(input.len(), "the WTMMM counted");
    let planes = input.tally.warning(&cfg, input.len());
    let terraces = input.tally.quantisation_warnings(
        cfg.scale_list()[0],
        "the smallest scale analysed",
        |a| format!("read the pdfs from a >= {a:.1} px, or start the scales there (--a-min)"),
    );
    body["warnings"] = json!(
        warning
            .iter()
            .chain(&few)
            .chain(&holes)
            .chain(&planes)
            .chain(&terraces)
            .chain(&input.pixel_warnings)
            .collect::<Vec<_>>()
    );
    write_json(&dir.join("pdf.json"), &body)?;
    write_pdf_csvs(
        dir,
        &show.iter().map(|&j| get(j)).collect::<Vec<_>>(),
        &sec.iter().map(|&j| get(j)).collect::<Vec<_>>(),
    )?;
    plot_pdfs(
        dir,
        &input.title(&cfg),
        &show.iter().map(|&j| get(j)).collect::<Vec<_>>(),
        &sec.iter().map(|&j| get(j)).collect::<Vec<_>>(),
        h0,
        input.pixel.as_ref().map(super::PixelSize::plot),
    )?;
    // the reading on stdout, even with --quiet (as analyze and tm give theirs)
    show!(
        "pdf: {}, {} set, h0 = {h0:.3} ({h0_source})\n",
        super::common::count_of(hist.images, "image"),
        args.set.name(),
    );
    if let Some(w) = warning {
        say!("warning: h0 not estimated from the data (estimate_from_data is null): {w}");
    }
    if let Some(w) = few {
        say!("warning: {}: {w}", input.describe());
    }
    for w in holes
        .iter()
        .chain(&planes)
        .chain(&terraces)
        .chain(&input.pixel_warnings)
    {
        say!("warning: {w}");
    }
    Ok(Outcome::Ok)
}

/// Below this many WTMMM a pdf rests on few points: drawn, but flagged.
pub const FEW_WTMMM: u64 = 100;

/// The scales a pdf is drawn at (`--show`, `--sectors-at`) need WTMMM: an
/// empty histogram has no density (it drew empty curves, or failed in the
/// plot with a message about an axis range).
///
/// **Errors** ([`Error::Input`]) when one of them has none; returns a
/// warning when one has fewer than [`FEW_WTMMM`].
pub fn check_shown_counts(
    h: &WtmmmHistograms,
    show: &[usize],
    sec: &[usize],
    set: WtmmmSet,
) -> Result<Option<String>> {
    let mut used: Vec<usize> = show.iter().chain(sec).copied().collect();
    used.sort_unstable();
    used.dedup();
    let set = set.phrase();
    let at = |js: &[usize]| -> String {
        js.iter()
            .map(|&j| format!("{:.2} px ({})", h.scales[j], h.hist[j].n))
            .collect::<Vec<_>>()
            .join(", ")
    };
    let empty: Vec<usize> = used.iter().copied().filter(|&j| h.hist[j].n == 0).collect();
    if !empty.is_empty() {
        return Err(Error::Input(format!(
            "no WTMMM {set} at a = {} (--show / --sectors-at), over {} image(s): there is no pdf \
             to draw; the counting domain is too small for these scales (show smaller scales, \
             use a smaller --margin or larger images)",
            at(&empty),
            h.images
        )));
    }
    let few: Vec<usize> = used
        .into_iter()
        .filter(|&j| h.hist[j].n < FEW_WTMMM)
        .collect();
    Ok((!few.is_empty()).then(|| {
        format!(
            "fewer than {FEW_WTMMM} WTMMM {set} at a = {}: those pdfs rest on few points (a \
             few spikes on fixed bins, a few wide bins on auto ones)",
            at(&few)
        )
    }))
}

/// pdf_M.csv, pdf_A.csv and joint_T.csv at the `--show` scales `p`,
/// pdf_M_sectors.csv at the `--sectors-at` scales `sec` (as the figures).
fn write_pdf_csvs(dir: &Path, p: &[&ScalePdf], sec: &[&ScalePdf]) -> Result<()> {
    let mut rows = Vec::new();
    for s in p {
        for i in 0..s.m.len() {
            rows.push(vec![
                f(s.a),
                f(s.octave),
                f(s.ln_m[i]),
                f(s.p_ln_m[i]),
                f(s.m[i]),
                f(s.p_m[i]),
                f(s.rescaled_m[i]),
                f(s.p_rescaled[i]),
                f(s.bin_width),
                s.count[i].to_string(),
            ]);
        }
    }
    write_csv(
        &dir.join("pdf_M.csv"),
        &[
            "a",
            "octave",
            "lnM",
            "P_lnM",
            "M",
            "P_M",
            "M_rescaled",
            "P_M_rescaled",
            "lnM_bin_width",
            "count",
        ],
        &rows,
    )?;
    let mut rows = Vec::new();
    for s in p {
        for i in 0..s.arg.len() {
            rows.push(vec![f(s.a), f(s.octave), f(s.arg[i]), f(s.p_arg[i])]);
        }
    }
    write_csv(&dir.join("pdf_A.csv"), &["a", "octave", "A", "P_A"], &rows)?;
    let mut rows = Vec::new();
    for s in sec {
        for sec in &s.sectors {
            for i in 0..s.sector_m.len() {
                rows.push(vec![
                    f(s.a),
                    f(s.octave),
                    f(sec.centre),
                    f(s.sector_m[i]),
                    f(sec.p_m[i]),
                    f(s.sector_bin_width),
                ]);
            }
        }
    }
    write_csv(
        &dir.join("pdf_M_sectors.csv"),
        &[
            "a",
            "octave",
            "sector_centre",
            "M",
            "P_M_given_sector",
            "lnM_bin_width",
        ],
        &rows,
    )?;
    let mut rows = Vec::new();
    for s in p {
        let t = &s.joint.t;
        for (iy, &t2) in t.iter().enumerate() {
            for (ix, &t1) in t.iter().enumerate() {
                rows.push(vec![
                    f(s.a),
                    f(t1),
                    f(t2),
                    f(s.joint.density[iy * t.len() + ix]),
                ]);
            }
        }
    }
    write_csv(
        &dir.join("joint_T.csv"),
        &["a", "T1", "T2", "density"],
        &rows,
    )
}

/// Plot points of a density: an empty bin is 0 on a linear axis; on a log
/// axis it (or a bin below 1e-4 of the peak) is a gap, not a line across.
fn pts(x: &[f64], y: &[f64], log: bool) -> Vec<(f64, f64)> {
    let peak = y.iter().cloned().fold(0.0, f64::max);
    x.iter()
        .zip(y)
        .map(|(&a, &v)| match log {
            false => (a, v),
            true if v > 1e-4 * peak => (a, v.ln()),
            true => (a, f64::NAN),
        })
        .collect()
}

fn plot_pdfs(
    dir: &Path,
    name: &str,
    show: &[&ScalePdf],
    sec: &[&ScalePdf],
    h0: f64,
    px: Option<(f64, &str)>,
) -> Result<()> {
    // a scale with few WTMMM says so in the figure too (not only on stderr)
    let label_w = |s: &ScalePdf, width: f64| {
        // the sample behind each curve: a histogram of 125 maxima is noisy
        let few = if s.n < 100 {
            format!(", only {} WTMMM", s.n)
        } else {
            format!(", {} WTMMM", s.n)
        };
        format!(
            "a = 2^{:.1} a_min ({:.1} px{}){few}, bins {width:.2} in ln M",
            s.octave,
            s.a,
            super::px_eq(px, s.a)
        )
    };
    let label = |s: &ScalePdf| label_w(s, s.bin_width);
    // P(A) has its own bins: their number, not the width in ln M
    let label_a = |s: &ScalePdf| {
        let few = if s.n < 100 { "only " } else { "" };
        format!(
            "a = 2^{:.1} a_min ({:.1} px{}), {few}{} WTMMM, {} bins in A",
            s.octave,
            s.a,
            super::px_eq(px, s.a),
            s.n,
            s.arg.len()
        )
    };
    let title = |t: &str| {
        if name.is_empty() {
            t.to_string()
        } else {
            format!("{name}: {t}")
        }
    };
    // M range shown: up to the 99.9% point of the largest scale shown
    let m_hi = show
        .iter()
        .map(|s| {
            let mut acc = 0.0;
            for (i, p) in s.p_ln_m.iter().enumerate() {
                acc += p * s.bin_width;
                if acc > 0.999 {
                    return s.m[i];
                }
            }
            s.m.last().copied().unwrap_or(1.0)
        })
        .fold(0.0, f64::max);
    let clip =
        |v: Vec<(f64, f64)>| -> Vec<(f64, f64)> { v.into_iter().filter(|p| p.0 <= m_hi).collect() };
    let chart = |title: String, x: &str, y: &str| Chart {
        title,
        x_label: x.into(),
        y_label: y.into(),
        ..Default::default()
    };
    let mut c = chart(title("(a) P_a(M) at the WTMMM (II Fig 17a)"), "M", "P_a(M)");
    let mut ca = chart(title("(b) P_a(A) (II Fig 17b)"), "A (rad)", "P_a(A)");
    let mut cl = chart(title("ln P_a(M) vs M (II Fig 20a)"), "M", "ln P_a(M)");
    // y: the density of the rescaled modulus (stats::pdf: P_a(M) times the
    // factor), which is what collapses
    let mut cr = chart(
        title(&format!(
            "ln P_a(M) vs M / (a/a_min)^h, h = {h0:.3} (II eq 39, Fig 20b)"
        )),
        "M / (a/a_min)^h",
        "ln [(a/a_min)^h P_a(M)]",
    );
    // the density of ln M on its own axis: every WTMMM in view whatever
    // the spread of M (a DEM's M spans decades, which the linear M axes of
    // the paper's figures squeeze against 0); the kernel's variable
    let mut cu = chart(
        title("P_a(ln M) at the WTMMM (the kernel's variable, II §4)"),
        "ln M",
        "P_a(ln M)",
    );
    for (k, s) in show.iter().enumerate() {
        cu.series.push(Series::new(
            label(s),
            pts(&s.ln_m, &s.p_ln_m, false),
            Style::LineMarkers,
            k,
        ));
        c.series.push(Series::new(
            label(s),
            clip(pts(&s.m, &s.p_m, false)),
            Style::LineMarkers,
            k,
        ));
        ca.series.push(Series::new(
            label_a(s),
            pts(&s.arg, &s.p_arg, false),
            Style::LineMarkers,
            k,
        ));
        cl.series.push(Series::new(
            label(s),
            clip(pts(&s.m, &s.p_m, true)),
            Style::LineMarkers,
            k,
        ));
        let r: Vec<(f64, f64)> = pts(&s.rescaled_m, &s.p_rescaled, true);
        cr.series.push(Series::new(
            label(s),
            r.into_iter().filter(|p| p.0 <= m_hi).collect(),
            Style::LineMarkers,
            k,
        ));
    }
    save_chart(&c, &dir.join("pdf_M.png"))?;
    save_chart(&cu, &dir.join("pdf_lnM.png"))?;
    let top = ca
        .series
        .iter()
        .flat_map(|s| s.points.iter().map(|p| p.1))
        .fold(0.0, f64::max);
    ca.y_range = Some((0.0, 1.15 * top.max(1e-9)));
    save_chart(&ca, &dir.join("pdf_A.png"))?;
    save_chart(&cl, &dir.join("lnpdf_M.png"))?;
    save_chart(&cr, &dir.join("lnpdf_rescaled.png"))?;
    for (n, s) in sec.iter().enumerate() {
        let mut cs = chart(
            title(&format!(
                "P(M | A mod pi), {} (II Fig 18)",
                label_w(s, s.sector_bin_width)
            )),
            "M",
            "ln P_a(M | A)",
        );
        for (k, q) in s.sectors.iter().enumerate() {
            let deg = q.centre.to_degrees();
            cs.series.push(Series::new(
                format!("A = {deg:.0} ± 22.5° (n = {})", q.n),
                pts(&s.sector_m, &q.p_m, true),
                Style::LineMarkers,
                k,
            ));
        }
        save_chart(&cs, &dir.join(format!("pdf_M_sectors_{n}.png")))?;
    }
    for (n, s) in show.iter().enumerate() {
        joint_picture(
            s,
            title(&format!(
                "joint density of (T1, T2), central 99 %, {} x {} in A (II Fig 19)",
                label_w(s, s.joint.lnm_bin_width),
                s.joint.arg_bins
            )),
            &dir.join(format!("joint_T_{n}.png")),
        )?;
    }
    Ok(())
}

/// II Figs 13, 19: the density of (T1, T2) at the WTMMM, log colour scale
/// over 4 decades (white = no WTMMM), T2 upwards, with axes and a colour bar.
fn joint_picture(s: &ScalePdf, title: String, path: &Path) -> Result<()> {
    let t = &s.joint.t;
    let n = t.len();
    let d = &s.joint.density;
    let peak = d.iter().cloned().fold(0.0, f64::max);
    let mut r = Raster {
        width: n,
        height: n,
        rgb: vec![255; n * n * 3],
    };
    for iy in 0..n {
        for ix in 0..n {
            let v = d[iy * n + ix];
            if !(v > 0.0 && peak > 0.0) {
                continue;
            }
            // a sequential map for a magnitude; empty cells stay white
            let c = viridis((((v / peak).log10() + 4.0) / 4.0).clamp(0.0, 1.0));
            // row 0 at the top: the largest T2
            r.put(ix as isize, (n - 1 - iy) as isize, (c.0, c.1, c.2));
        }
    }
    // cell centres t[i]: the picture spans half a cell beyond them
    let w = if n > 1 { t[1] - t[0] } else { 1.0 };
    let range = (t[0] - 0.5 * w, t[n - 1] + 0.5 * w);
    save_raster_chart(
        &r,
        &RasterChart {
            title,
            x_label: "T1".into(),
            y_label: "T2".into(),
            x_range: range,
            y_range: range,
            y_up: true,
            colorbar: Some(ColorBar::viridis("log10 density / peak", (-4.0, 0.0))),
            size: None,
            caption: "white: no WTMMM in the cell (or below 1e-4 of the peak)".into(),
        },
        path,
    )
}

/// Shared by the kernel command: a mutex-guarded cache is not needed here,
/// but the correlation plans are per image shape.
pub type ShapeCache<T> = Mutex<Vec<((usize, usize), std::sync::Arc<T>)>>;
