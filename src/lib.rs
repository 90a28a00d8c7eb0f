//! # wtmm — multifractal analysis of images
//!
//! The 2D wavelet transform modulus maxima (WTMM) method of Arnéodo, Decoster
//! and Roux (paper II below), with the synthetic generators that validate it.
//!
//! Data flows one way: image ([`io`], [`field::Field`]) → continuous wavelet
//! transform ([`cwt`]) → maxima, chains, WTMMM and maxima lines
//! ([`skeleton`]) → partition sums → spectra τ(q), h(q), D(q), D(h)
//! ([`spectra`]). The library never prints; the `wtmm` binary (module `cli`)
//! formats.
//!
//! # Features
//!
//! `cli` (default) builds the `wtmm` command line (clap, progress bars,
//! Ctrl-C cleanup) and enables `plot`, the PNG/SVG figures (plotters with an
//! embedded font). A program that only computes spectra can do without
//! both: `wtmm = { version = "0.3", default-features = false }` builds the
//! analysis, the generators, the theory and the readers alone.
//!
//! # Quick start
//!
//! The spectra of a small fBm ensemble (H = 1/2), one image at a time: each
//! image gives its partition sums, the sums of an ensemble merge (exactly,
//! in any order), and the merged sums give τ(q), h(q), D(q) with jackknife
//! errors over the images, and warnings saying what limits them.
//! [`io::read_field`] reads an image from a file instead (npy, TIFF, PNG,
//! PGM, ESRI ASCII; nodata becomes a mask).
//!
//! ```
//! use wtmm::Field;
//! use wtmm::skeleton::AnalysisConfig;
//! use wtmm::spectra::{PartitionSums, Rule, image_sums};
//! use wtmm::synth::fbm::{FbmParams, fbm};
//!
//! # fn main() -> wtmm::Result<()> {
//! let q = [-2.0, 0.0, 2.0];
//! // scales 1.5-22.4 px (4 octaves of 10 voices); maxima count only at
//! // ceil(3.2 a_max) = 72 px or more from the border, 368^2 px of 512^2
//! let cfg = AnalysisConfig { octaves: 4, ..Default::default() };
//! assert_eq!(cfg.margin_px(), 72);
//! let mut parts = Vec::new();
//! for i in 0..4 {
//!     let img = fbm(FbmParams { hurst: 0.5 }, 512, 512, 1, i)?;
//!     parts.push(image_sums(&Field::new(img), &cfg, &q, format!("fbm {i}"))?);
//! }
//! let sums = PartitionSums::merge_all(parts)?.expect("four images");
//! // the default fit range: octaves 0.5-4 above a_min
//! let sp = sums.spectra(Rule::Plain, (0.5, 4.0))?;
//! for (k, q) in sp.q.iter().enumerate() {
//!     // theory q/2 - 2; one image's tau(±2) scatters by 0.08-0.11, so a
//!     // four-image mean is within 0.2 (tests/ judges the estimator)
//!     assert!((sp.tau[k] - (q / 2.0 - 2.0)).abs() < 0.2);
//!     assert!(sp.tau_stderr[k] > 0.0 && sp.h[k].is_finite() && sp.d[k].is_finite());
//! }
//! // four images make rough error bars, and the spectra say so
//! assert!(sp.warnings.iter().any(|w| w.contains("jackknife over 4 images")));
//! # Ok(())
//! # }
//! ```
//!
//! # One image (a DEM)
//!
//! A jackknife over one image has nothing to leave out, and the regression
//! errors of the fit understate (its scales are not independent). Split the
//! counting domain into tiles instead, as the `wtmm analyze` command does
//! for fewer than 3 images: the errors then come from a jackknife over the
//! tiles (which treats them as independent, and says so in the warnings).
//!
//! ```
//! use wtmm::Field;
//! use wtmm::skeleton::{AnalysisConfig, Parallelism};
//! use wtmm::spectra::{Rule, default_tile_side, image_sums_tiled};
//! use wtmm::synth::fbm::{FbmParams, fbm};
//!
//! # fn main() -> wtmm::Result<()> {
//! // a file would be `wtmm::io::read_field(Path::new("dem.npy"))?`
//! let dem = Field::new(fbm(FbmParams { hurst: 0.5 }, 384, 384, 7, 0)?);
//! let cfg = AnalysisConfig { octaves: 3, ..Default::default() };
//! let (ny, nx) = dem.dim();
//! let side = default_tile_side(&cfg, ny, nx);
//! // one image: its scales run in parallel
//! let sums = image_sums_tiled(&dem, &cfg, &[0.0, 2.0], "dem", Parallelism::Scales, side)?;
//! let sp = sums.spectra(Rule::Plain, (0.5, 3.0))?;
//! assert!(sp.stderr_method.contains("tiles"));
//! assert!(sp.tau_stderr.iter().all(|e| *e > 0.0));
//! # Ok(())
//! # }
//! ```
//!
//! The self-similarity kernel's cumulants of the same DEM over the same
//! tiles, as `wtmm kernel` computes them (an ensemble of fields in memory
//! works the same way, with errors over the fields from 3 on):
//!
//! ```
//! # use wtmm::Field;
//! # use wtmm::skeleton::AnalysisConfig;
//! # use wtmm::synth::fbm::{FbmParams, fbm};
//! use wtmm::stats::kernel::{KernelConfig, KernelOptions, ensemble_kernel_sums, kernel_estimates};
//! use wtmm::stats::pdf::WtmmmSet;
//!
//! # fn main() -> wtmm::Result<()> {
//! # let dem = Field::new(fbm(FbmParams { hurst: 0.5 }, 384, 384, 7, 0)?);
//! # let cfg = AnalysisConfig { octaves: 3, ..Default::default() };
//! // the WTMMM of the maxima lines (II §4.2)
//! let sums = ensemble_kernel_sums(&[dem], &cfg, KernelConfig::default(), WtmmmSet::Lines)?;
//! // the paper's reference scales and pairs that this grid holds
//! let opts = KernelOptions::for_scales(&cfg.scale_list(), (0.5, 3.0));
//! let k = kernel_estimates(&sums, &opts)?;
//! // c1, c2, c3 in natural logs (fBm: c1 = -H, c2 = c3 = 0)
//! assert!(k.stderr_method.contains("tiles"));
//! assert!(k.cumulants.c1.value.is_finite() && k.cumulants.c1.stderr > 0.0);
//! # Ok(())
//! # }
//! ```
//!
//! Tiles of one cascade are not independent, so those errors understate.
//! For the trace moments of a DEM,
//! [`tracemoments::surrogate_errors`] measures the errors instead on
//! universal multifractal fields drawn with the DEM's estimates, shape and
//! missing pixels (a parametric bootstrap; `wtmm tm --surrogates K`).
//!
//! # Messages name the command line's flags
//!
//! Errors and warnings are written for the people who read them, most of
//! whom run the `wtmm` command: where a message advises a change ("fewer
//! --octaves or a smaller --margin"), it names the flag. The same knobs in
//! the library:
//!
//! | flag | library |
//! |---|---|
//! | `--wavelet`, `--octaves`, `--voices`, `--margin` | [`AnalysisConfig`] `wavelet`, `octaves`, `voices`, `margin` (and the same fields of [`stats::correlation::CorrelationConfig`]) |
//! | `--ratio` | [`skeleton::LinkParams`] `ratio` (`AnalysisConfig::link`) |
//! | `--detrend` | [`AnalysisConfig`] `detrend`, [`stats::correlation::CorrelationConfig`] `detrend`, [`tracemoments::TraceMomentConfig`] `detrend` ([`field::Trend`]) |
//! | `--fit` | the `fit` argument of [`PartitionSums::spectra`]; [`stats::kernel::KernelOptions`] `fit` |
//! | `--refs`, `--pairs` (kernel) | [`stats::kernel::KernelOptions`] `refs`, `pairs` |
//! | `--pairs`, `--max-dx` (correlate) | [`stats::correlation::CorrelationConfig`] `pairs`, `max_dx` |
//! | `--lnm-bin`, `--arg-bins` | [`stats::pdf::PdfConfig`] `dlnm`, `arg_bins` |
//! | `--bins` (pdf) | [`stats::pdf::PdfOptions`] `bins` |
//! | `--diff-order`, `--frac-int` | [`tracemoments::TraceMomentConfig`] `diff` ([`tracemoments::FluxDiff`]), `frac_int` |
//! | `--lambda-fit`, `--lag-fit`, `--k-range`, `--q-fit-max`, `--universal-fit` | [`tracemoments::TraceMomentFitConfig`] `log2_lambda`, `log2_lag`, `k_range`, `q_fit_max`, `universal` |
//! | `--flux`, `--q`, `--eta`, `--dtm-q`, `--sf-q`, `--box-weights` (tm) | [`tracemoments::TraceMomentConfig`] `flux`, `q`, `eta`, `dtm_q`, `sf_q`, `box_weights` |
//! | `--torus` (tm) | [`tracemoments::TraceMomentConfig`] `periodic: true` and `spectrum: PowerSpectrumConfig::for_field(true)` (no taper, only the mean removed) |
//! | `--eta-fit` | [`tracemoments::TraceMomentFitConfig`] `eta` |
//! | `--window`, `--spectrum-fill` | [`stats::powspec::PowerSpectrumConfig`] `window`, `fill` (`TraceMomentConfig::spectrum`) |
//! | `--surrogates K` | [`tracemoments::surrogate_errors`] |
//! | `--domain torus` (pdf, kernel, correlate) | `margin: Some(0)`: the whole image as a torus |
//! | `--fill-holes` | `Field::new(field.filled_harmonic()?)` ([`Field::filled_harmonic_on`] for a torus); the spectra's fill warning reads [`spectra::ImagePartial`] `filled`, `largest_filled_hole`, `in_large_filled_holes` ([`field::HoleSizes::of`] counts them), which the caller sets |
//! | `--nodata V` | [`Field::mask_value`] (a file's own nodata tag is read by [`io`]) |
//! | `--pixel-size`, `--units` | none: the library works in pixels; the CLI converts its outputs' scales to lengths |
//! | `--out` | the directory a caller writes to ([`io::write_atomic`] refuses to overwrite a file registered with [`io::protect`]) |
//!
//! # References
//!
//! The docs cite: **II** (e.g. "II §3.2", "II eq 76"), the method paper:
//! N. Decoster, S. G. Roux and A. Arnéodo, "A
//! wavelet-based method for multifractal image analysis. II. Applications to
//! synthetic multifractal rough surfaces", Eur. Phys. J. B 15, 739
//! (2000). **TM**: J.-S. Gagnon, S. Lovejoy and D. Schertzer, "Multifractal
//! earth topography", Nonlin. Processes Geophys. 13, 541-570 (2006) (trace
//! moments, FIF topography). **SIM**: S. Lovejoy, D. Schertzer and J.-S.
//! Gagnon, "Multifractal simulations of the Earth's surface and interior:
//! anisotropic singularities and morphology". **SPEC §n**: the sections of
//! the project's original technical specification, `docs/SPEC.md` in the
//! repository (the definitions, generators, closed forms and published
//! numbers; where the code departs from it, its docs and the README say
//! so).

// `!(x > 0.0)` is how we reject NaN together with out-of-range values.
#![allow(clippy::neg_cmp_op_on_partial_ord)]
// Every public item is documented; keep it so.
#![warn(missing_docs)]

#[cfg(feature = "cli")]
pub mod cli;
pub mod cwt;
pub mod error;
pub mod field;
pub mod fourier;
pub mod io;
mod nan_null;
mod par;
#[cfg(feature = "plot")]
pub mod plot;
pub mod skeleton;
pub mod spectra;
pub mod stats;
pub mod synth;
pub mod theory;
pub mod tracemoments;

pub use error::{Error, Result};
pub use field::Field;
pub use skeleton::{AnalysisConfig, Skeleton};
pub use spectra::{
    PartitionSums, Rule, Spectra, default_fit, default_q, default_tile_side, ensemble_sums,
    image_sums, image_sums_tiled,
};
pub use theory::Model;

/// The crate version, recorded in every output.
pub const VERSION: &str = env!("CARGO_PKG_VERSION");

/// The git commit the crate was built from (12 hex digits), or "unknown"
/// outside a repository; recorded beside [`VERSION`] in every output.
pub const BUILD: &str = env!("WTMM_BUILD");
