//! The WT skeleton (SPEC §2-§3; II §3): WTMM by non-maximum suppression,
//! maxima chains, their local maxima (WTMMM), and maxima lines linking the
//! WTMMM across scales from `a_min` upward.
//!
//! The skeleton is built while the CWT streams scales: detection at one scale
//! needs only that scale's transform, linking needs only the previous scale's
//! line ends. [`Parallelism::Scales`] detects scales in parallel (one
//! workspace per worker) and links serially; the result is bit-identical to
//! the serial path because each scale is detected by the same code.
//!
//! ```
//! use ndarray::Array2;
//! use wtmm::skeleton::{AnalysisConfig, skeleton};
//! use wtmm::Field;
//! // a disc: at every scale one closed chain around it
//! let img = Array2::from_shape_fn((128, 128), |(y, x)| {
//!     let (dx, dy) = (x as f64 - 64.0, y as f64 - 64.0);
//!     if dx * dx + dy * dy < 400.0 { 1.0 } else { 0.0 }
//! });
//! let cfg = AnalysisConfig { octaves: 2, margin: Some(20), ..Default::default() };
//! let sk = skeleton(&Field::new(img), &cfg).unwrap();
//! assert_eq!(sk.scales.len(), 20);
//! assert!(sk.per_scale.iter().all(|s| s.wtmmm > 0));
//! ```

pub mod link;
pub mod maxima;

use ndarray::Array2;
use serde::{Deserialize, Serialize};

pub use link::{Endings, LinePoint, LinkParams, Linker, MaximaLine, SearchRadius};
pub use maxima::{Chain, DetectScratch, Domain, ScaleMaxima, Wtmmm, detect, detect_scale};

use crate::cwt::{CwtPlan, CwtWorkspace, FourierImage, ScaleGrid, Wavelet, default_margin};
use crate::error::{Error, Result};
use crate::field::Field;

/// How the work of one image is spread.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Parallelism {
    /// Stream the scales on the calling thread (use when images are
    /// processed in parallel).
    Serial,
    /// Detect maxima of all scales in parallel (rayon), link serially.
    Scales,
}

/// Everything that defines the skeleton of an image (serialised into every
/// output).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct AnalysisConfig {
    /// Analysing wavelet (SPEC §1; default gauss).
    pub wavelet: Wavelet,
    /// Smallest scale of the dyadic grid, in pixels (default 1.5; ignored
    /// when `scales` is given).
    pub a_min: f64,
    /// Octaves of the dyadic grid (default 5; ignored when `scales` is given).
    pub octaves: usize,
    /// Scales per octave (default 10; ignored when `scales` is given).
    pub voices: usize,
    /// Explicit scales (pixels) instead of the dyadic grid.
    pub scales: Option<Vec<f64>>,
    /// Interior margin in pixels; `None` = [`default_margin`] for the wavelet
    /// and the largest scale.
    pub margin: Option<usize>,
    /// Moduli below `eps * max M` are ignored (SPEC §2).
    pub eps: f64,
    /// Rules for linking WTMMM across scales into maxima lines (SPEC §3).
    pub link: LinkParams,
    /// Trace chains and link lines beyond the counting domain, wherever the
    /// transform is trusted at each scale (margin `R a`), and count maxima
    /// only inside the domain. Without it (the reference implementation's
    /// behaviour) the domain edge cuts chains and ends lines, a loss that
    /// grows like a / L and steepens τ(0) at large scales.
    #[serde(default = "yes")]
    pub guard: bool,
    /// Trend removed from the image before the transform (default none;
    /// sums of older versions read as none). Not on a torus (`margin`
    /// 0): a periodic field has no planar trend, and the removed plane
    /// would be a jump across its edges.
    #[serde(default)]
    pub detrend: crate::field::Trend,
}

fn yes() -> bool {
    true
}

impl Default for AnalysisConfig {
    fn default() -> Self {
        let g = ScaleGrid::default();
        AnalysisConfig {
            wavelet: Wavelet::default(),
            a_min: g.a_min,
            octaves: g.octaves,
            voices: g.voices,
            scales: None,
            margin: None,
            eps: 1e-7,
            link: LinkParams::default(),
            guard: true,
            detrend: crate::field::Trend::None,
        }
    }
}

/// The median of `values` (plane shares, terrace widths); `None` for none.
pub(crate) fn median(values: &[f64]) -> Option<f64> {
    let mut s = values.to_vec();
    s.sort_by(f64::total_cmp);
    let n = s.len();
    (n > 0).then(|| (s[(n - 1) / 2] + s[n / 2]) / 2.0)
}

/// A share in [0, 1] as a whole percentage, never rounded up to a plane
/// that explains everything ("over 99" for 99-100 %).
pub(crate) fn share_percent(share: f64) -> String {
    let pc = 100.0 * share;
    if pc > 99.0 && pc < 100.0 {
        "over 99".into()
    } else {
        format!("{pc:.0}")
    }
}

/// How much of the images' variance their planes explain, worded for
/// "the least-squares plane explains ...", when the median of the finite
/// `shares` exceeds [`crate::spectra::PLANE_SHARE_WARN`]; `None` below it.
/// `images` is the ensemble's size: fewer shares than images means some
/// sums come from versions that did not record them.
pub(crate) fn plane_dominance(shares: &[f64], images: usize) -> Option<String> {
    let shares: Vec<f64> = shares.iter().copied().filter(|s| s.is_finite()).collect();
    let median = median(&shares)?;
    let n = shares.len();
    if !(median > crate::spectra::PLANE_SHARE_WARN) {
        return None;
    }
    let over = shares
        .iter()
        .filter(|&&s| s > crate::spectra::PLANE_SHARE_WARN)
        .count();
    let pc = share_percent(median);
    Some(if images == 1 {
        format!("{pc} % of the image's variance")
    } else if n == images {
        format!("a median {pc} % of the images' variance (more than half in {over} of {n})")
    } else {
        format!(
            "a median {pc} % of the variance of the {n} of {images} images that record it \
             (sums of older versions do not; more than half in {over})"
        )
    })
}

impl AnalysisConfig {
    /// The defaults for a field of the given kind: a periodic field (the
    /// generators' W-cascades, FISC, FIF) is analysed on the whole torus
    /// (margin 0: the FFT transform is exact everywhere on it, and an
    /// interior would discard half the maxima), any other field inside the
    /// default margin. What the CLI does for generated ensembles; see
    /// [`crate::stats::powspec::PowerSpectrumConfig::for_field`] for the
    /// spectrum.
    pub fn for_field(periodic: bool) -> Self {
        AnalysisConfig {
            margin: periodic.then_some(0),
            ..Default::default()
        }
    }

    /// What the transform is computed on: the image with its missing
    /// pixels filled ([`Field::filled`]) and, with
    /// [`Trend::Plane`](crate::field::Trend::Plane), less the
    /// least-squares plane of its valid pixels (removed before the fill).
    ///
    /// **Errors** if no pixel is valid.
    pub fn input<'a>(&self, field: &'a Field) -> Result<std::borrow::Cow<'a, Array2<f64>>> {
        field.transform_input(self.detrend)
    }

    /// The warning for an ensemble of `images` whose least-squares planes
    /// explain a median share of their variance above
    /// [`crate::spectra::PLANE_SHARE_WARN`] (`shares`: those known, from
    /// [`Field::plane_share`]), when this analysis is biased by them: the
    /// gauss wavelet and no [`detrend`](Self::detrend). The wavelet adds
    /// a plane of slope `c = (cx, cy)` to the transform as the vector `a c`
    /// at every point (`cwt` module docs), which grows with the scale
    /// faster than a rough surface's modulus. On a torus (margin 0) the
    /// plane is a jump across the image's edges instead, which no
    /// detrending mends there (it is refused): the interior is the
    /// remedy. (A periodic field's plane explains next to nothing.)
    pub fn plane_warning(&self, shares: &[f64], images: usize) -> Option<String> {
        if self.wavelet != Wavelet::Gauss || self.detrend != crate::field::Trend::None {
            return None;
        }
        let whose = plane_dominance(shares, images)?;
        if self.margin_px() == 0 {
            return Some(format!(
                "the least-squares plane explains {whose}: analysed whole as a torus (margin \
                 0, which is for periodic fields), the image's plane is a jump across its \
                 edges, which biases every estimate; analyse the interior (the default margin) \
                 with --detrend plane (README, Conventions)"
            ));
        }
        Some(format!(
            "the least-squares plane explains {whose}: the gauss wavelet (one vanishing \
             moment) adds a plane of slope c to the transform as the vector a c at every point, \
             which grows with the scale faster than a rough surface's modulus and biases the \
             estimates (README, Conventions); rerun with --detrend plane, or with the mexican \
             wavelet, blind to planes, and compare"
        ))
    }

    /// **Errors** naming the parameter that is out of range.
    pub fn validate(&self) -> Result<()> {
        if let Some(s) = &self.scales {
            if s.is_empty() {
                return Err(Error::param("scales", "empty list"));
            }
            if s.windows(2).any(|w| !(w[1] > w[0])) || !(s[0] > 0.0) {
                return Err(Error::param("scales", "must be positive and increasing"));
            }
            if !(s[s.len() - 1] <= crate::cwt::MAX_SCALE) {
                return Err(Error::param(
                    "scales",
                    format!(
                        "{} px is beyond any image",
                        crate::error::short(s[s.len() - 1])
                    ),
                ));
            }
        } else {
            self.grid().validate()?;
        }
        let a0 = self.scale_list()[0];
        if a0 < self.wavelet.min_scale() {
            return Err(Error::param(
                if self.scales.is_some() {
                    "scales"
                } else {
                    "a-min"
                },
                format!(
                    "{} px is below {:.2} px, where the {} wavelet's passband passes the \
                     Nyquist wavenumber (the pixel grid cannot resolve it)",
                    crate::error::short(a0),
                    self.wavelet.min_scale(),
                    self.wavelet
                ),
            ));
        }
        if self.detrend != crate::field::Trend::None && self.margin == Some(0) {
            return Err(Error::param(
                "detrend",
                "plane: the image is analysed whole as a torus (margin 0: --margin 0, --domain \
                 torus, or a generated periodic model, which validate, compare, demo and \
                 pdf/kernel/correlate with a preset analyse so by default), which is for \
                 periodic fields, and a periodic field has no planar trend: the removed plane \
                 would be a jump across its edges, which the torus counts. Drop --detrend, or \
                 analyse the interior (no --margin 0, or --margin N), where a non-periodic \
                 image's plane is removed",
            ));
        }
        if !(self.eps >= 0.0 && self.eps < 1.0) {
            return Err(Error::param(
                "eps",
                format!("must be in [0, 1), got {}", crate::error::short(self.eps)),
            ));
        }
        let (lo, hi) = self.link.ratio;
        if !(lo > 0.0 && lo < 1.0 && hi > 1.0 && hi.is_finite()) {
            return Err(Error::param(
                "ratio",
                format!("need 0 < lo < 1 < hi, got ({lo}, {hi})"),
            ));
        }
        match self.link.radius {
            // finite: JSON has no inf, and the recorded analysis must
            // read back (a cap of the image side is no cap)
            SearchRadius::Reference { cap } if !(cap >= 1.0 && cap.is_finite()) => {
                return Err(Error::param(
                    "radius-cap",
                    format!(
                        "the search-box cap must be a finite number of px >= 1, got {cap_s} (for \
                         no cap give the image side)",
                        cap_s = crate::error::short(cap)
                    ),
                ));
            }
            SearchRadius::Proportional { factor, min }
                if !(factor > 0.0 && factor.is_finite() && min >= 1.0 && min.is_finite()) =>
            {
                return Err(Error::param("radius", "need factor > 0 and min >= 1 px"));
            }
            _ => {}
        }
        Ok(())
    }

    /// The dyadic grid of `a_min`, `octaves`, `voices` (whether or not
    /// explicit `scales` override it).
    pub fn grid(&self) -> ScaleGrid {
        ScaleGrid {
            a_min: self.a_min,
            octaves: self.octaves,
            voices: self.voices,
        }
    }

    /// The scales analysed, smallest first.
    pub fn scale_list(&self) -> Vec<f64> {
        self.scales.clone().unwrap_or_else(|| self.grid().scales())
    }

    /// The largest scale analysed (1 px for an empty list), without
    /// building the list: an absurd grid gives a huge or non-finite value
    /// here, for [`Self::validate`] to refuse, not an overflow.
    pub fn a_max(&self) -> f64 {
        match &self.scales {
            Some(s) => s.last().copied().unwrap_or(1.0),
            None => self.grid().a_max(),
        }
    }

    /// The margin actually used.
    pub fn margin_px(&self) -> usize {
        let a_max = self.a_max();
        self.margin
            .unwrap_or_else(|| default_margin(self.wavelet, a_max))
    }

    /// The analysis domain for a field: interior, minus the pixels whose
    /// wavelet support (radius `R a`) reaches a masked pixel.
    ///
    /// **Errors** if the interior is empty (image smaller than the wavelet).
    pub fn domain(&self, field: &Field) -> Result<Domain> {
        let (ny, nx) = field.dim();
        let margin = self.margin_px();
        let mut d = Domain::interior(ny, nx, margin);
        if d.is_empty() {
            return Err(self.no_interior(ny, nx));
        }
        d.support = self.wavelet.support_radius();
        d.guard = self.guard;
        if let Some(mask) = &field.mask {
            d.mask_distance = Some(distance_to_mask(mask));
        }
        Ok(d)
    }

    /// The error of an image with no interior inside the margin.
    fn no_interior(&self, ny: usize, nx: usize) -> Error {
        let margin = self.margin_px();
        let a_max = self.scale_list().last().copied().unwrap_or(0.0);
        if self.margin.is_some() {
            // a margin as given: the margin is at fault, not the image
            return Error::Input(format!(
                "the margin of {margin} px on each side (--margin) leaves no interior in an \
                 image of {ny}x{nx} (give less than {} px)",
                ny.min(nx).div_ceil(2)
            ));
        }
        Error::Input(format!(
            "image {ny}x{nx} is smaller than the wavelet: the interior margin is {margin} px \
             on each side at the largest scale {a_max:.1} px (use fewer octaves or a smaller margin: --octaves, --margin; a periodic image, such as the W-cascades, FISC and FIF fields of `wtmm synth`, is analysed whole as a torus with --margin 0)"
        ))
    }

    /// How far from every missing pixel a maximum must lie to count: the
    /// wavelet's support at the largest scale (px).
    pub fn hole_clearance(&self) -> f64 {
        self.wavelet.support_radius() * self.scale_list().last().copied().unwrap_or(0.0)
    }

    /// Pixels of the counting domain for `field`: `(counted, interior)`,
    /// the interior rectangle's pixels and those of them farther from every
    /// missing pixel than the wavelet's support at the largest scale (where
    /// maxima count, [`Skeleton::counts`]). Says why an image with scattered
    /// holes has no maxima.
    ///
    /// **Errors** as [`Self::domain`].
    pub fn counting_pixels(&self, field: &Field) -> Result<(usize, usize)> {
        let (ny, nx) = field.dim();
        if Domain::interior(ny, nx, self.margin_px()).is_empty() {
            return Err(self.no_interior(ny, nx));
        }
        let dist = field.mask.as_ref().map(distance_to_mask);
        self.counting_pixels_with(field, dist.as_ref())
    }

    /// [`Self::counting_pixels`] with the distance of every pixel to the
    /// missing ones ([`distance_to_mask`] of the field's mask) computed
    /// once for several analyses of one field.
    ///
    /// **Errors** as [`Self::domain`].
    pub fn counting_pixels_with(
        &self,
        field: &Field,
        dist: Option<&Array2<f32>>,
    ) -> Result<(usize, usize)> {
        let (ny, nx) = field.dim();
        let d = Domain::interior(ny, nx, self.margin_px());
        if d.is_empty() {
            return Err(self.no_interior(ny, nx));
        }
        let interior = (d.y1 - d.y0) * (d.x1 - d.x0);
        let clearance = self.hole_clearance() as f32;
        let counted = match dist {
            None => interior,
            Some(dist) => dist
                .slice(ndarray::s![d.y0..d.y1, d.x0..d.x1])
                .iter()
                .filter(|&&r| r > clearance)
                .count(),
        };
        Ok((counted, interior))
    }

    /// Why `field` gave no maxima line at the smallest scale: that it is
    /// constant, if it is; how much of
    /// the counting domain its missing pixels leave when it has some
    /// ([`Self::counting_pixels`]: scattered holes can leave none), else
    /// [`NO_MAXIMA`], the causes seen in practice.
    pub fn why_no_maxima(&self, field: &Field) -> String {
        if let Some((lo, hi)) = field.range()
            && lo == hi
        {
            return format!(
                "constant image (every valid pixel is {}): {CONSTANT}",
                crate::error::short(lo)
            );
        }
        let missing = field.missing_count();
        match self.counting_pixels(field) {
            Ok((counted, interior)) if missing > 0 => {
                let a_max = self.scale_list().last().copied().unwrap_or(0.0);
                let clearance = self.hole_clearance();
                format!(
                    "no maxima to count: the image has {missing} missing pixels (NaN, inf or \
                     nodata), and maxima count only farther from them than the wavelet's \
                     support at the largest scale ({clearance:.0} px at a = {a_max:.1} px), \
                     which leaves {counted} of the {interior} pixels of the counting domain; \
                     fill scattered gaps (--fill-holes), crop to a gap-free region, or \
                     use fewer --octaves"
                )
            }
            _ => NO_MAXIMA.into(),
        }
    }
}

/// Why a constant image has no maxima ([`AnalysisConfig::why_no_maxima`];
/// the WTMM commands of the CLI say it as soon as such an image is read,
/// not as "no maxima" after the transform).
pub const CONSTANT: &str = "its wavelet transform is zero, so it has no maxima";

/// Why an image gave no maxima at the smallest scale (the causes seen in
/// practice, not only a constant image); see
/// [`AnalysisConfig::why_no_maxima`].
pub const NO_MAXIMA: &str = "no maxima (or no maxima line) at the smallest scale: the image is \
     flat (constant, or one extreme value such as an untagged nodata dwarfing the rest), or its \
     few maxima do not link across scales (a lone edge or spike on a smooth background, not a \
     rough surface), or the counting domain left by the margin is too small (try a smaller \
     --margin or fewer --octaves)";

/// Counts at one scale.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ScaleCounts {
    /// Scale, in pixels.
    pub a: f64,
    /// Number of WTMM pixels (over the detection rectangle, wider than the
    /// counting domain when `guard` is on; [`ScaleMaxima::n_wtmm`]).
    pub wtmm: usize,
    /// Number of maxima chains, of any length (same rectangle).
    pub chains: usize,
    /// Number of WTMMM (same rectangle).
    pub wtmmm: usize,
    /// Maxima lines alive at this scale, wherever they lie (those born
    /// and ended at `a_min`, and outside the counting domain, included);
    /// the partition functions count fewer ([`crate::spectra::Spectra::lines`]).
    pub lines: usize,
    /// Why lines ended on the way to this scale.
    pub ended: Endings,
}

/// The WT skeleton of one image.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Skeleton {
    /// The scales analysed, in pixels, smallest first.
    pub scales: Vec<f64>,
    /// Image size `(ny, nx)`.
    pub shape: (usize, usize),
    /// Interior margin used, in pixels.
    pub margin: usize,
    /// The counting domain `(y0, y1, x0, x1)`: maxima count only inside.
    pub domain: (usize, usize, usize, usize),
    /// Distance (px) from each pixel to the nearest missing pixel (`None`
    /// without a mask). Maxima count only farther than `hole_clearance`
    /// from a hole, the same at every scale, as the border's margin is: a
    /// clearance growing with `a` would shrink the counted area as the
    /// scale grows and read every τ(q) low (by 0.13 on holed fBm images,
    /// `tests/spectra.rs`).
    #[serde(skip)]
    pub hole_distance: Option<std::sync::Arc<Array2<f32>>>,
    /// `R a_max` (px): the wavelet's support at the largest scale.
    #[serde(default)]
    pub hole_clearance: f64,
    /// Counts per scale, in the order of `scales`.
    pub per_scale: Vec<ScaleCounts>,
    /// All maxima lines, born at `a_min`; with `guard` their points may lie
    /// outside the counting domain (test them with [`Skeleton::counts`]).
    pub lines: Vec<MaximaLine>,
    /// Chains and WTMMM of the scales asked for in `keep`.
    pub kept: Vec<ScaleMaxima>,
}

impl Skeleton {
    /// The lines alive at scale `j` (length > j).
    pub fn alive_at(&self, j: usize) -> impl Iterator<Item = &MaximaLine> {
        self.lines.iter().filter(move |l| l.points.len() > j)
    }

    /// True if `(x, y)` lies in the counting domain: inside the interior
    /// rectangle and farther than `hole_clearance` from every missing pixel.
    pub fn counts(&self, x: u32, y: u32) -> bool {
        let (y0, y1, x0, x1) = self.domain;
        let (x, y) = (x as usize, y as usize);
        x >= x0
            && x < x1
            && y >= y0
            && y < y1
            && self
                .hole_distance
                .as_ref()
                .is_none_or(|d| d[[y, x]] > self.hole_clearance as f32)
    }

    /// The share of the interior rectangle's pixels that [`Self::counts`]:
    /// those farther from every missing pixel than `hole_clearance` (a few
    /// scattered missing pixels can leave a small part of it). `None`
    /// without missing pixels or an empty rectangle.
    pub fn counted_share(&self) -> Option<f64> {
        let (y0, y1, x0, x1) = self.domain;
        let d = self.hole_distance.as_ref()?;
        let area = (y1 - y0) * (x1 - x0);
        let c = self.hole_clearance as f32;
        let kept = d
            .slice(ndarray::s![y0..y1, x0..x1])
            .iter()
            .filter(|&&r| r > c)
            .count();
        (area > 0).then(|| kept as f64 / area as f64)
    }
}

/// Builds the skeleton of one image with the default options (serial).
///
/// **Errors** if the image has no valid pixels, is smaller than
/// the wavelet, or a parameter is invalid. A constant image gives an empty
/// skeleton (no error).
pub fn skeleton(field: &Field, cfg: &AnalysisConfig) -> Result<Skeleton> {
    skeleton_with(field, cfg, Parallelism::Serial, &[])
}

/// Builds the skeleton, keeping chains and all WTMMM of the scale indices in
/// `keep` (for pictures).
pub fn skeleton_with(
    field: &Field,
    cfg: &AnalysisConfig,
    par: Parallelism,
    keep: &[usize],
) -> Result<Skeleton> {
    build(field, cfg, par, keep, 0, true).map(|(sk, _)| sk)
}

/// The skeleton and, at the first `wtmmm_scales` scales, every WTMMM of the
/// counting domain ([`Skeleton::counts`]; on a line or not; the WTMMM
/// statistics of SPEC §5-§6 want both sets), from one transform: `validate` takes the partition sums
/// and the kernel from the same pass. Without `link` no lines are built
/// (the statistics of all WTMMM need none).
///
/// **Errors** as [`skeleton_with`].
pub fn skeleton_and_wtmmm(
    field: &Field,
    cfg: &AnalysisConfig,
    par: Parallelism,
    wtmmm_scales: usize,
    link: bool,
) -> Result<(Skeleton, Vec<Vec<Wtmmm>>)> {
    build(field, cfg, par, &[], wtmmm_scales, link)
}

fn build(
    field: &Field,
    cfg: &AnalysisConfig,
    par: Parallelism,
    keep: &[usize],
    wtmmm_scales: usize,
    link: bool,
) -> Result<(Skeleton, Vec<Vec<Wtmmm>>)> {
    cfg.validate()?;
    field.check()?;
    let domain = cfg.domain(field)?;
    let img = cfg.input(field)?;
    let scales = cfg.scale_list();
    let (ny, nx) = field.dim();
    let plan = CwtPlan::new(ny, nx, cfg.wavelet, &scales)?;
    let sk = Skeleton {
        scales: scales.clone(),
        shape: (ny, nx),
        margin: cfg.margin_px(),
        domain: (domain.y0, domain.y1, domain.x0, domain.x1),
        hole_distance: domain.mask_distance.clone().map(std::sync::Arc::new),
        hole_clearance: cfg.hole_clearance(),
        ..Default::default()
    };
    let mut asm = Assembler {
        linker: link.then(|| Linker::new(cfg.link).periodic(domain.is_torus().then_some((nx, ny)))),
        sk,
        keep,
        wtmmm: Vec::with_capacity(wtmmm_scales.min(scales.len())),
        wtmmm_scales,
    };
    match par {
        Parallelism::Serial => {
            // streaming: each scale is detected and linked before the next
            let fi = plan.forward(img.view())?;
            let mut ws = plan.workspace();
            let mut scratch = DetectScratch::default();
            for j in 0..scales.len() {
                let keep_j = keep.contains(&j);
                let sm =
                    detect_linkable(&plan, &fi, j, &mut ws, &domain, cfg, keep_j, &mut scratch);
                asm.push(sm);
            }
        }
        Parallelism::Scales => {
            let found =
                plan.par_map_scales_with(img.view(), DetectScratch::default, |s, fi, j, ws| {
                    detect_linkable(&plan, fi, j, ws, &domain, cfg, keep.contains(&j), s)
                })?;
            for sm in found {
                asm.push(sm);
            }
        }
    }
    let mut sk = asm.sk;
    if let Some(linker) = asm.linker {
        sk.lines = linker.finish();
    }
    Ok((sk, asm.wtmmm))
}

/// [`detect`], plus the chains and the moduli along them when the linking
/// rules need them (`LinkParams::climb`).
#[allow(clippy::too_many_arguments)]
pub fn detect_linkable(
    plan: &CwtPlan,
    fi: &FourierImage,
    j: usize,
    ws: &mut CwtWorkspace,
    domain: &Domain,
    cfg: &AnalysisConfig,
    keep_chains: bool,
    scratch: &mut DetectScratch,
) -> (ScaleMaxima, Option<Vec<Vec<f64>>>) {
    if !cfg.link.climb {
        // rows streamed from the CWT; the full transform is never stored
        let sm = detect_scale(plan, fi, j, ws, domain, cfg.eps, keep_chains, scratch);
        return (sm, None);
    }
    let a = plan.scales()[j];
    let t = plan.scale(fi, j, ws);
    let sm = detect(t, j, a, domain, cfg.eps, true, scratch);
    let cm = sm
        .chains
        .iter()
        .map(|c| {
            c.pixels
                .iter()
                .map(|&(x, y)| crate::cwt::modulus(t[[y as usize, x as usize]]))
                .collect()
        })
        .collect();
    (sm, Some(cm))
}

/// Links scales as they arrive and keeps the per-scale counts.
struct Assembler<'k> {
    linker: Option<Linker>,
    sk: Skeleton,
    keep: &'k [usize],
    /// The WTMMM of the counting domain at the first `wtmmm_scales` scales.
    wtmmm: Vec<Vec<Wtmmm>>,
    wtmmm_scales: usize,
}

impl Assembler<'_> {
    fn push(&mut self, (mut sm, chain_m): (ScaleMaxima, Option<Vec<Vec<f64>>>)) {
        let ended = match self.linker.as_mut() {
            Some(l) => l.push_with(&sm, chain_m.as_deref()),
            None => Endings::default(),
        };
        if chain_m.is_some() && !self.keep.contains(&sm.j) {
            sm.chains = Vec::new();
        }
        self.sk.per_scale.push(ScaleCounts {
            ended,
            a: sm.a,
            wtmm: sm.n_wtmm,
            chains: sm.n_chains,
            wtmmm: sm.wtmmm.len(),
            lines: self.linker.as_ref().map_or(0, |l| l.alive()),
        });
        if sm.j < self.wtmmm_scales {
            // chains may be traced in a guard band around the domain; only
            // the WTMMM of the counting domain count, as in the partition
            // functions (Skeleton::counts: also clear of missing pixels by
            // the support at the largest scale, not only at this one)
            let sk = &self.sk;
            let inside: Vec<Wtmmm> = sm
                .wtmmm
                .iter()
                .filter(|w| sk.counts(w.x, w.y))
                .copied()
                .collect();
            self.wtmmm.push(inside);
        }
        if self.keep.contains(&sm.j) {
            self.sk.kept.push(sm);
        }
    }
}

/// Exact Euclidean distance from each pixel to the nearest masked pixel on
/// the torus (the FFT transform is periodic, so a wavelet near one edge
/// reaches pixels at the other), by Felzenszwalb & Huttenlocher (2012): two
/// passes of the 1D squared-distance transform, each over the line repeated
/// three times. On an interior domain whose margin exceeds the wavelet's
/// support this decides as the plane distance would. Written by hand: no
/// maintained crate offers it for ndarray.
pub fn distance_to_mask(mask: &Array2<bool>) -> Array2<f32> {
    let (ny, nx) = mask.dim();
    let inf = 1e20f64;
    let mut g = Array2::<f64>::from_elem((ny, nx), inf);
    for ((y, x), &m) in mask.indexed_iter() {
        if m {
            g[[y, x]] = 0.0;
        }
    }
    let len = 3 * ny.max(nx);
    let mut f = vec![0.0; len];
    let mut d = vec![0.0; len];
    let mut v = vec![0usize; len];
    let mut z = vec![0.0; len + 1];
    for x in 0..nx {
        for i in 0..3 * ny {
            f[i] = g[[i % ny, x]];
        }
        dt1d(&f[..3 * ny], &mut d[..3 * ny], &mut v, &mut z);
        for y in 0..ny {
            g[[y, x]] = d[ny + y];
        }
    }
    for y in 0..ny {
        for i in 0..3 * nx {
            f[i] = g[[y, i % nx]];
        }
        dt1d(&f[..3 * nx], &mut d[..3 * nx], &mut v, &mut z);
        for x in 0..nx {
            g[[y, x]] = d[nx + x];
        }
    }
    g.mapv(|s| s.sqrt() as f32)
}

/// 1D squared-distance transform of the sampled function `f` (lower envelope
/// of parabolas).
fn dt1d(f: &[f64], d: &mut [f64], v: &mut [usize], z: &mut [f64]) {
    let n = f.len();
    if n == 0 {
        return;
    }
    let mut k = 0usize;
    v[0] = 0;
    z[0] = f64::NEG_INFINITY;
    z[1] = f64::INFINITY;
    let inter = |q: usize, p: usize| {
        ((f[q] + (q * q) as f64) - (f[p] + (p * p) as f64)) / (2.0 * (q as f64 - p as f64))
    };
    for q in 1..n {
        let mut s = inter(q, v[k]);
        // z[0] = -inf stops the loop at k = 0
        while s <= z[k] {
            k -= 1;
            s = inter(q, v[k]);
        }
        k += 1;
        v[k] = q;
        z[k] = s;
        z[k + 1] = f64::INFINITY;
    }
    k = 0;
    for (q, dq) in d.iter_mut().enumerate() {
        while z[k + 1] < q as f64 {
            k += 1;
        }
        let p = v[k];
        let dx = q as f64 - p as f64;
        *dq = dx * dx + f[p];
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn distance_transform_matches_brute_force() {
        let (ny, nx) = (23, 31);
        // sparse points, a segment near one edge, and one pixel in the far
        // corner whose nearest pixels lie across the edges
        let mask = Array2::from_shape_fn((ny, nx), |(y, x)| {
            (x * 7 + y * 13) % 29 == 0 && x < 20 || (x == 5 && y > 10) || (y, x) == (22, 30)
        });
        let d = distance_to_mask(&mask);
        for y in 0..ny {
            for x in 0..nx {
                // on the torus: the shortest wrapped offset
                let wrapped = |a: usize, b: usize, n: usize| {
                    let d = a.abs_diff(b);
                    d.min(n - d) as f64
                };
                let mut best = f64::INFINITY;
                for ((yy, xx), &m) in mask.indexed_iter() {
                    if m {
                        let dd = (wrapped(yy, y, ny).powi(2) + wrapped(xx, x, nx).powi(2)).sqrt();
                        best = best.min(dd);
                    }
                }
                assert!(
                    (d[[y, x]] as f64 - best).abs() < 1e-4,
                    "({y},{x}) {} vs {best}",
                    d[[y, x]]
                );
            }
        }
    }
}
