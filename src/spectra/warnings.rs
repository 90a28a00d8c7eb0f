//! The warnings of the spectra: images unlike the others, curved partition
//! functions, terraces, flat areas, planes, filled holes, and departures
//! from a Legendre spectrum.

use super::*;

impl PartitionSums {
    /// Pairs of images `(i, j)`, `i < j`, with the same line counts and
    /// sums (to 1e-9, both rules): one image twice (a copy, or the
    /// image flipped, transposed or negated, whose maxima are the same),
    /// which would pass for two independent samples and shrink the error
    /// bars. Images that kept no line are not compared.
    pub fn duplicate_images(&self) -> Vec<(usize, usize)> {
        let mut seen: std::collections::HashMap<&[u64], Vec<usize>> = Default::default();
        let mut out = Vec::new();
        for (j, im) in self.images.iter().enumerate() {
            if im.lines.iter().all(|&n| n == 0) {
                continue;
            }
            let same = seen.entry(im.lines.as_slice()).or_default();
            for &i in same.iter() {
                let o = &self.images[i];
                if same_cells(&o.plain, &im.plain) && same_cells(&o.sup, &im.sup) {
                    out.push((i, j));
                }
            }
            same.push(j);
        }
        out.sort_unstable();
        out
    }

    /// The warning on the pairs of [`Self::duplicate_images`], naming the
    /// first.
    pub(super) fn duplicate_warning(&self, pairs: &[(usize, usize)]) -> Option<String> {
        let &(i, j) = pairs.first()?;
        let more = match pairs.len() - 1 {
            0 => String::new(),
            n => format!(" ({n} more pair{} alike)", if n == 1 { "" } else { "s" }),
        };
        Some(format!(
            "images {:?} and {:?}{more} have the same line counts and sums (to 1e-9): one image \
             twice (a copy, or the image flipped, transposed or negated) passes for two \
             independent samples, so the ensemble is smaller than it says and its error bars \
             too small; leave the copies out",
            self.images[i].label, self.images[j].label
        ))
    }

    /// What the missing pixels leave of the counting domains (the images'
    /// recorded [`ImagePartial::counted_share`]): ", which leaves 35 % of
    /// the counting domain", the least image's share when they differ, and
    /// advice below half. Empty when no image records a share.
    pub(super) fn counted_note(&self) -> String {
        let shares: Vec<(f64, &str)> = self
            .images
            .iter()
            .filter_map(|im| im.counted_share.map(|r| (r, im.label.as_str())))
            .collect();
        let Some(&(least, who)) = shares.iter().min_by(|a, b| a.0.total_cmp(&b.0)) else {
            return String::new();
        };
        let pct = |r: f64| format!("{:.0} %", 100.0 * r);
        let most = shares.iter().map(|s| s.0).fold(least, f64::max);
        // sums written before 2026-11-30 record no share
        let holed = self.images.iter().filter(|im| im.missing > 0).count();
        let of = if shares.len() < holed {
            format!(" ({} of the {holed} record it)", shares.len())
        } else {
            String::new()
        };
        let mut o = if shares.len() == 1 {
            format!(", which leaves {} of the counting domain{of}", pct(least))
        } else {
            let mean = shares.iter().map(|s| s.0).sum::<f64>() / shares.len() as f64;
            format!(
                ", which leaves {} of the counting domains on average{of} ({} to {}, the least \
                 in {who})",
                pct(mean),
                pct(least),
                pct(most)
            )
        };
        if least < 0.5 {
            o.push_str(
                "; to keep more, fill scattered gaps (--fill-holes), crop to a gap-free \
                 region, or use fewer --octaves",
            );
        }
        o
    }

    /// [`AnalysisConfig::plane_warning`](crate::skeleton::AnalysisConfig::plane_warning)
    /// of the images' recorded plane shares ([`ImagePartial::plane_share`]).
    pub(super) fn plane_warning(&self) -> Option<String> {
        let shares: Vec<f64> = self.images.iter().filter_map(|im| im.plane_share).collect();
        self.analysis
            .as_ref()?
            .plane_warning(&shares, self.images.len())
    }

    /// How many images had missing pixels filled and counted as data
    /// ([`ImagePartial::filled`], `analyze --fill-holes`), with the holes'
    /// sizes and the bias they may bring ([`crate::field::HoleSizes::describe`]):
    /// the per-image notes scroll past, and merged sums carry no others.
    pub(super) fn fill_warning(&self) -> Option<String> {
        let with: Vec<&ImagePartial> = self.images.iter().filter(|im| im.filled > 0).collect();
        if with.is_empty() {
            return None;
        }
        // every image's pixels (the share of the ensemble filled); sums
        // written before 2026-11-22 record no shape
        let area: Option<usize> = self
            .images
            .iter()
            .map(|im| im.shape.map(|[ny, nx]| ny * nx))
            .sum();
        let holes = crate::field::HoleSizes {
            missing: with.iter().map(|im| im.filled).sum(),
            largest: with
                .iter()
                .map(|im| im.largest_filled_hole)
                .max()
                .unwrap_or(0),
            in_large: with.iter().map(|im| im.in_large_filled_holes).sum(),
            area: area.unwrap_or(0),
        };
        let what = match area {
            Some(_) => holes.describe(),
            None => format!(
                "the largest hole holds {} px, {} px lie in holes of more than {} px; no share \
                 or bound on the bias: some of the sums record no image size",
                holes.largest,
                holes.in_large,
                crate::field::LARGE_FILLED_HOLE
            ),
        };
        Some(format!(
            "{} of the {} image(s) had missing pixels filled harmonically and counted as data \
             (--fill-holes; {} in all, {what})",
            with.len(),
            self.images.len(),
            holes.missing,
        ))
    }

    /// [`terrace_warning`] of the images' recorded terrace widths
    /// ([`ImagePartial::terrace_width`]), against `a_fit`, the smallest
    /// fitted scale, and [`flat_warning`] of their flat values.
    pub(super) fn quantisation_warnings(&self, a_fit: f64) -> Vec<String> {
        let widths: Vec<Option<f64>> = self.images.iter().map(|im| im.terrace_width).collect();
        let voices = self.analysis.as_ref().map_or(10, |a| a.voices);
        let top = self.scales.last().copied().unwrap_or(a_fit);
        let terraces = terrace_warning(
            &widths,
            a_fit,
            "the smallest fitted scale",
            ", which lowers h(q) and raises D",
            fit_remedy(self.scales[0], voices, top),
        );
        let flats: Vec<Option<FlatRecord>> = self.images.iter().map(|im| im.flat).collect();
        terraces.into_iter().chain(flat_warning(&flats)).collect()
    }

    /// "; `wtmm info IMAGE --octaves 5` lists the domain each number of
    /// octaves leaves", with this analysis's options (its table is that
    /// of the wavelet, a_min, voices and margin used here); empty when
    /// the sums record no analysis.
    pub(super) fn info_hint(&self) -> String {
        self.analysis.as_ref().map_or(String::new(), |a| {
            let d = crate::skeleton::AnalysisConfig::default();
            let mut o = String::new();
            if a.wavelet != d.wavelet {
                o += &format!(" --wavelet {}", a.wavelet);
            }
            if a.a_min != d.a_min {
                o += &format!(" --a-min {}", a.a_min);
            }
            if a.voices != d.voices {
                o += &format!(" --voices {}", a.voices);
            }
            if let Some(m) = a.margin {
                o += &format!(" --margin {m}");
            }
            format!(
                "; `wtmm info IMAGE{o} --octaves {}` lists the domain each number of \
                 octaves leaves",
                a.octaves
            )
        })
    }
}

/// Fewest images for the unlike-image test: the t law of a deleted
/// residual has K - 2 degrees of freedom, and below 2 its quantiles are
/// too wide to flag anything.
pub const UNLIKE_MIN_IMAGES: usize = 4;

/// Family-wise false-alarm rate of the unlike-image test over the images
/// and the two exponents.
pub const UNLIKE_ALPHA: f64 = 0.001;

/// Smallest side, relative to the largest, of the images of one size
/// class in the unlike-image test: a 10 % smaller side changes a lone
/// image's scatter by far less than the factor 2.2 measured between 384^2
/// and 512^2 images.
pub const SIZE_CLASS: f64 = 0.9;

/// Images whose own h(q = 0) or tau(q = 2) stands apart from the others'
/// (one warning each). For image i, the studentized deleted residual `t =
/// (x_i - mean_-i) / (s_-i sqrt(1 + 1/(K-1)))`, mean and sd of the other
/// K - 1 images, follows Student's t with K - 2 degrees of freedom when
/// the K values are independent draws of one normal law (an ensemble of
/// one process); it is flagged beyond the quantile `1 - α/(2 K m G)`
/// (two-sided, Bonferroni over the K images, the m exponents and the G
/// size classes tested), so that a homogeneous ensemble raises a warning
/// in about 0.1 % of runs. Images are compared within their size class
/// (sides within [`SIZE_CLASS`] of the class's largest), as a smaller
/// image's own exponents scatter more; a class with fewer than
/// [`UNLIKE_MIN_IMAGES`] estimates is not tested, and that is said.
/// An image without its own estimate (NaN: no line at the top of the fit
/// in it alone) is left out of that exponent's test and named in a warning
/// of its own; an exponent with fewer than [`UNLIKE_MIN_IMAGES`] estimates
/// is not tested.
pub fn unlike_images(per_image: &[ImageExponents]) -> Vec<String> {
    if per_image.len() < UNLIKE_MIN_IMAGES {
        return Vec::new();
    }
    // images of different sizes scatter differently (a small image's own
    // exponents have the larger error), so that a small one would pass for
    // unlike large ones: each size class (sides within SIZE_CLASS of its
    // largest image's) is tested on its own, Bonferroni over the classes
    // tested too
    let side = |e: &ImageExponents| e.shape.map(|[ny, nx]| ((ny * nx) as f64).sqrt());
    let mut order: Vec<&ImageExponents> = per_image.iter().collect();
    order.sort_by(|a, b| side(b).unwrap_or(-1.0).total_cmp(&side(a).unwrap_or(-1.0)));
    // (largest side of the class, or None: sizes unrecorded; its images)
    let mut classes: Vec<(Option<f64>, Vec<ImageExponents>)> = Vec::new();
    for e in order {
        let s = side(e);
        match classes.last_mut() {
            Some((Some(top), v)) if s.is_some_and(|s| s >= SIZE_CLASS * *top) => v.push(e.clone()),
            Some((None, v)) if s.is_none() => v.push(e.clone()),
            _ => classes.push((s, vec![e.clone()])),
        }
    }
    let estimates = |v: &[ImageExponents]| {
        v.iter()
            .filter(|e| e.h_q0.is_finite())
            .count()
            .max(v.iter().filter(|e| e.tau_q2.is_finite()).count())
    };
    let testable = |v: &[ImageExponents]| estimates(v) >= UNLIKE_MIN_IMAGES;
    let groups = classes.iter().filter(|(_, v)| testable(v)).count().max(1);
    let mut out: Vec<String> = Vec::new();
    for (_, v) in &classes {
        out.extend(unlike_among(v, classes.len() > 1, groups));
    }
    if classes.len() > 1 {
        let sizes = |v: &[ImageExponents]| -> String {
            let shapes: Vec<[usize; 2]> = v.iter().filter_map(|e| e.shape).collect();
            match (shapes.first(), shapes.last()) {
                (Some([a, b]), Some([c, d])) if (a, b) != (c, d) => format!("{a}x{b} .. {c}x{d}"),
                (Some([a, b]), _) => format!("{a}x{b}"),
                _ => "unrecorded size".into(),
            }
        };
        let untested: Vec<String> = classes
            .iter()
            .filter(|(_, v)| !testable(v))
            .map(|(_, v)| {
                format!(
                    "{} of {} ({} with estimates)",
                    v.len(),
                    sizes(v),
                    estimates(v)
                )
            })
            .collect();
        out.push(format!(
            "the unlike-image test compares each image with those of its size class (sides \
             within {:.0} % of the class's largest; smaller images' own exponents scatter more): \
             {} classes{}",
            100.0 * (1.0 - SIZE_CLASS),
            classes.len(),
            if untested.is_empty() {
                String::new()
            } else {
                format!(
                    "; not tested, fewer than {UNLIKE_MIN_IMAGES} images with estimates: {}",
                    untested.join(", ")
                )
            }
        ));
    }
    // NaN in an exponent some images have (a whole NaN series is a q the
    // grid lacks, not a shortage of lines)
    let some = |f: fn(&ImageExponents) -> f64| per_image.iter().any(|e| f(e).is_finite());
    let (some_h, some_t) = (some(|e| e.h_q0), some(|e| e.tau_q2));
    let missing: Vec<&str> = per_image
        .iter()
        .filter(|e| (!e.h_q0.is_finite() && some_h) || (!e.tau_q2.is_finite() && some_t))
        .map(|e| e.label.as_str())
        .collect();
    if !missing.is_empty() {
        let list = match missing.len() {
            0..=3 => missing.join(", "),
            n => format!("{}, ... ({n} images)", missing[..2].join(", ")),
        };
        let have = if missing.len() == 1 {
            "no h(q=0) or tau(q=2) of its own"
        } else {
            "no h(q=0) or tau(q=2) of their own"
        };
        out.push(format!(
            "{list}: {have} (no maxima line at the top of the fit in the image alone), left out \
             of the unlike-image test{}",
            if classes.iter().any(|(_, v)| testable(v)) {
                ""
            } else {
                ", which then had too few images to run"
            }
        ));
    }
    out
}

/// [`unlike_images`] among images of one size class (`classed`: among
/// several), at the family-wise level shared by `groups` such tests: the
/// warnings naming images.
pub(super) fn unlike_among(
    per_image: &[ImageExponents],
    classed: bool,
    groups: usize,
) -> Vec<String> {
    use statrs::distribution::{ContinuousCDF, StudentsT};
    let series: [(&str, Vec<f64>); 2] = [
        ("h(q=0)", per_image.iter().map(|e| e.h_q0).collect()),
        ("tau(q=2)", per_image.iter().map(|e| e.tau_q2).collect()),
    ];
    // an image without an estimate of its own (no line at the top of the
    // fit, common for images smaller than the others) is left out of that
    // exponent's test, not the whole test
    let finite = |v: &[f64]| -> Vec<usize> { (0..v.len()).filter(|&i| v[i].is_finite()).collect() };
    let tested: Vec<(&str, &Vec<f64>, Vec<usize>)> = series
        .iter()
        .map(|(name, v)| (*name, v, finite(v)))
        .filter(|(_, _, idx)| idx.len() >= UNLIKE_MIN_IMAGES)
        .collect();
    let mut said: Vec<Vec<String>> = vec![Vec::new(); per_image.len()];
    for (name, v, idx) in &tested {
        let k = idx.len();
        let t_law = StudentsT::new(0.0, 1.0, (k - 2) as f64).expect("k >= 4");
        let level = UNLIKE_ALPHA / (2.0 * k as f64 * tested.len() as f64 * groups as f64);
        let limit = t_law.inverse_cdf(1.0 - level);
        for &i in idx {
            let rest: Vec<f64> = idx.iter().filter(|&&j| j != i).map(|&j| v[j]).collect();
            let m = rest.iter().sum::<f64>() / (k - 1) as f64;
            let var = rest.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (k - 2) as f64;
            let t = (v[i] - m) / (var * (1.0 + 1.0 / (k - 1) as f64)).sqrt();
            // identical others (sd 0) with a different value: t is infinite
            if t.abs() > limit {
                said[i].push(format!(
                    "{name} = {:.3} against {m:.3} +- {:.3} (mean and sd of the other {}{}), t = \
                     {t:.1} beyond {limit:.1}",
                    v[i],
                    var.sqrt(),
                    k - 1,
                    if classed { " of its size class" } else { "" }
                ));
            }
        }
    }
    said.iter()
        .zip(per_image)
        .filter(|(s, _)| !s.is_empty())
        .map(|(s, e)| {
            format!(
                "{} looks unlike the others: {} (the {} % family-wise threshold of the \
                 studentized deleted residual): the ensemble may mix processes (per_image lists \
                 each image's exponents), and its jackknife errors then measure the mix",
                e.label,
                s.join("; "),
                UNLIKE_ALPHA * 100.0
            )
        })
        .collect()
}

/// Change of the local slope of `log2 Z(q, a)` across the fit range above
/// which a fit is flagged as no power law: the fitted tau(q) then stands for
/// local slopes more than 0.1 either side of it, the size of the tau
/// tolerances of SPEC §11. (R^2 was the test before; it calls every flat
/// power law, tau ~ 0, a poor one and passes strong curvature where tau is
/// steep.)
pub const SLOPE_CHANGE_WARN: f64 = 0.2;
/// Whether a slope change of log2 Z over the fit (`tau_slope_change`) is
/// flagged as no power law (beyond [`SLOPE_CHANGE_WARN`] either way).
pub fn is_curved(slope_change: f64) -> bool {
    slope_change.abs() > SLOPE_CHANGE_WARN
}

/// Whether h is flagged as at or beyond what a wavelet with `order`
/// vanishing moments can measure (II §3.1): within 0.01 of the order or
/// above (the warnings of [`Spectra`] say why 0.01).
pub fn at_wavelet_order(h: f64, order: f64) -> bool {
    h >= order - 0.01
}

/// Median share of the images' variance explained by their least-squares
/// plane above which the gauss wavelet's analysis is warned about
/// ([`ImagePartial::plane_share`]): more than half, the images are mostly
/// a tilted plane.
pub const PLANE_SHARE_WARN: f64 = 0.5;

/// The warning for images quantised into terraces (`widths`: each image's
/// [`crate::Field::terrace_width`], `None` where not recorded) wider than
/// [`TERRACE_SCALES`] times `a`, the smallest scale that counts (`what_a`
/// names it; `effect` is added to what the steps do; `remedy` says how to
/// start at a given scale). A wavelet narrower than the terraces sees the
/// steps between them, edges with h = 0, rather than the surface.
pub(crate) fn terrace_warning(
    widths: &[Option<f64>],
    a: f64,
    what_a: &str,
    effect: &str,
    remedy: impl Fn(f64) -> String,
) -> Option<String> {
    let known: Vec<f64> = widths.iter().flatten().copied().collect();
    let over = known.iter().filter(|&&w| w > TERRACE_SCALES * a).count();
    let widest = known.iter().copied().fold(f64::NAN, f64::max);
    if over == 0 {
        return None;
    }
    let run = "1 / (1 - f), f the share of equal neighbour pairs along rows or columns; 1 where \
               neighbours differ";
    let k = TERRACE_SCALES;
    let whose = if widths.len() == 1 {
        format!(
            "the image's values are quantised into terraces {widest:.1} px wide ({run}), more \
             than {k} times {what_a}, a = {a:.2} px"
        )
    } else {
        format!(
            "{over} of {} images{} are quantised into terraces more than {k} times as wide as \
             {what_a}, a = {a:.2} px (up to {widest:.1} px: {run})",
            widths.len(),
            recorded(known.len(), widths.len()),
        )
    };
    Some(format!(
        "{whose}: a wavelet that narrow sees the steps between the terraces (h = 0 along their \
         edges) rather than the surface{effect} (README, Conventions); {}, or analyse values \
         quantised more finely",
        remedy(widest / k)
    ))
}

/// " (of the 3 with a width: ...)" when only `known` of `all` images
/// record a terrace width; empty when all do.
pub(super) fn recorded(known: usize, all: usize) -> String {
    if known == all {
        String::new()
    } else {
        format!(
            " (of the {known} with a width: sums of older versions record none, nor does an \
             image in which no step between neighbours is seen)"
        )
    }
}

/// What [`terrace_warning`] advises for a WTMM analysis on scales from
/// `a_min` up to `top` px at `voices` per octave: the `--fit` start, in
/// octaves above `a_min` on the grid, that clears the terraces, and
/// whether it leaves an octave to fit.
pub(crate) fn fit_remedy(a_min: f64, voices: usize, top: f64) -> impl Fn(f64) -> String {
    move |a: f64| {
        let v = voices.max(1) as f64;
        let lo = ((a / a_min).log2() * v - 1e-9).ceil().max(0.0) / v;
        let span = (top / a_min).log2() - lo;
        let short = if span < 1.0 {
            format!(
                ", which leaves less than an octave below the largest scale, {top:.1} px: \
                 the quantisation is too coarse for the image size"
            )
        } else {
            String::new()
        };
        format!(
            "fit from a >= {a:.1} px (--fit {}:HI, octaves above a_min = {} px){short}",
            crate::error::short(lo),
            crate::error::short(a_min)
        )
    }
}

/// The warning for images holding one value in more than
/// [`crate::field::FLAT_SHARE_WARN`] of their valid pixels (`flats`: each
/// image's [`ImagePartial::flat`], `None` without a flat value or where
/// not recorded): a sea, a lake, a fill or an undeclared nodata value,
/// whose rim the wavelet sees as a step or a kink of the surface.
pub(crate) fn flat_warning(flats: &[Option<FlatRecord>]) -> Option<String> {
    let big: Vec<FlatRecord> = flats
        .iter()
        .flatten()
        .filter(|f| f.share > crate::field::FLAT_SHARE_WARN)
        .copied()
        .collect();
    let most = big
        .iter()
        .copied()
        .max_by(|a, b| a.share.total_cmp(&b.share))?;
    let pc = 100.0 * crate::field::FLAT_SHARE_WARN;
    let whose = if flats.len() == 1 {
        format!(
            "the image holds one value, {}, in {:.0} % of its valid pixels",
            crate::error::short(most.value),
            100.0 * most.share
        )
    } else {
        format!(
            "{} of {} images hold one value in more than {pc:.0} % of their valid pixels (up to \
             {:.0} %, the value {})",
            big.len(),
            flats.len(),
            100.0 * most.share,
            crate::error::short(most.value)
        )
    };
    // the value exactly, for --nodata to match it
    let value = if big.iter().all(|f| f.value == most.value) {
        crate::error::exact(most.value)
    } else {
        "VALUE".to_string()
    };
    Some(format!(
        "{whose}: flat areas (a sea or a lake at one level, a fill, a nodata value the file does \
         not declare), whose rim the wavelet sees as a step or a kink, not the roughness of the \
         surface (README, Conventions); if they are no data, give them as missing (--nodata \
         {value}, NaN, or the file's nodata value)"
    ))
}

/// How many times the smallest fitted scale the terraces of a quantised
/// image ([`crate::Field::terrace_width`]) may be wide before the spectra
/// are warned about. Measured on 4 fBm of 512^2 (H = 0.7, gauss) rounded
/// into terraces 12.6 px wide: fitted over 2 octaves from 8.5 px (1.48
/// times) they read as unquantised (h(0) 0.582 against 0.586), from 6 px
/// (2.1 times) 3 errors low (0.628 against 0.700). Over the default fit
/// (2.1-24 px) the lowest scales weigh less: terraces 5 px wide (2.4 times)
/// moved h(0) by half an error, 6.3 px (3.0 times) D by 1.8 (README,
/// Conventions).
pub const TERRACE_SCALES: f64 = 1.5;

/// Effective number of lines below which a cell is flagged as dominated.
pub const N_EFF_WARN: f64 = 10.0;

/// "q = a .. b", or "q = a" when the span is one q.
pub(super) fn q_span(a: f64, b: f64) -> String {
    if a == b {
        format!("q = {a}")
    } else {
        format!("q = {a} .. {b}")
    }
}

/// Standard errors (as multiples) beyond which [`legendre_warnings`] calls
/// a departure real: the largest of many q (or pairs of q) is taken, so
/// two standard errors would be crossed by chance too often. Between
/// [`LEGENDRE_NOTE_SE`] and this many, the warning says the departure may
/// be noise; below, nothing is said (one error is crossed by chance at
/// some q of most spectra: on 32 fBm images of 1024^2, h(q) rose by 1.6
/// errors between two q and D(q) stood 2.0 errors above 2).
pub(super) const LEGENDRE_WARN_SE: f64 = 3.0;
/// See [`LEGENDRE_WARN_SE`].
pub(super) const LEGENDRE_NOTE_SE: f64 = 2.0;

/// How a departure of `k` standard errors reads in [`legendre_warnings`].
pub(super) fn departure(k: f64) -> String {
    if k > LEGENDRE_WARN_SE {
        format!("{k:.1} standard errors")
    } else {
        format!("{k:.1} standard errors, so it may be noise, but the plotted spectrum shows it")
    }
}

/// Warnings where the spectra cannot be a Legendre spectrum of a surface:
/// h(q) rising with q (tau(q) not concave, so D(h) folds back) or D(q)
/// above 2, the dimension of the support, each by more than
/// [`LEGENDRE_NOTE_SE`] jackknife errors (`reps`: the replicates; without
/// them the regression errors, summed for a difference), said as real
/// beyond [`LEGENDRE_WARN_SE`].
pub(super) fn legendre_warnings(q: &[f64], est: &Estimates, reps: &[Estimates]) -> Vec<String> {
    let nq = q.len();
    let jk = |get: &dyn Fn(&Estimates) -> f64| -> f64 {
        if reps.len() >= 3 {
            crate::stats::jackknife_se(&reps.iter().map(get).collect::<Vec<_>>())
        } else {
            f64::NAN
        }
    };
    let mut out = Vec::new();
    // the rise h(q_j) - h(q_i), i < j, largest against its error (a small
    // rise can be real where a larger one is noise), and the largest of
    // those beyond their errors (the whole fold the plotted D(h) shows)
    let mut rise: Option<(usize, usize, f64, f64)> = None;
    let mut widest: Option<(usize, usize, f64, f64)> = None;
    for j in 0..nq {
        for i in 0..j {
            let r = est.h[j] - est.h[i];
            if !(r > 0.0) {
                continue;
            }
            let se = jk(&|e: &Estimates| e.h[j] - e.h[i]);
            let se = if se.is_finite() {
                se
            } else {
                est.h_se[i] + est.h_se[j]
            };
            if !(r > LEGENDRE_NOTE_SE * se) {
                continue;
            }
            if rise.is_none_or(|(_, _, r0, se0)| r / se > r0 / se0) {
                rise = Some((i, j, r, se));
            }
            if widest.is_none_or(|(_, _, r0, _)| r > r0) {
                widest = Some((i, j, r, se));
            }
        }
    }
    if let (Some((i, j, r, se)), Some((wi, wj, wr, wse))) = (rise, widest) {
        let all = if (wi, wj) == (i, j) {
            String::new()
        } else {
            format!(
                "; in all from {:.3} at q = {} to {:.3} at q = {}, {wr:+.3} +- {wse:.3}",
                est.h[wi], q[wi], est.h[wj], q[wj]
            )
        };
        // (a D that is NaN throughout, of a broken fit, is not quoted)
        let dmax = (i.min(wi)..=j.max(wj))
            .map(|k| est.d[k])
            .filter(|d| d.is_finite())
            .fold(f64::NEG_INFINITY, f64::max);
        let reaches = if dmax.is_finite() {
            format!(" (D reaches {dmax:.3})")
        } else {
            String::new()
        };
        out.push(format!(
            "h(q) rises from {:.3} at q = {} to {:.3} at q = {} ({r:+.3} +- {se:.3}, {}{all}): \
             tau(q) is not concave there, so D(h) folds back and is not a Legendre spectrum \
             over those q{reaches}; the fit range often mixes two scaling \
             regimes (see the straight-line warnings) or a few lines dominate: narrow --fit \
             or --q",
            est.h[i],
            q[i],
            est.h[j],
            q[j],
            departure(r / se)
        ));
    }
    // D(q) above 2 by more than its error
    let above: Vec<(usize, f64, f64)> = (0..nq)
        .filter_map(|k| {
            let se = jk(&|e: &Estimates| e.d[k]);
            let se = if se.is_finite() { se } else { est.d_se[k] };
            (est.d[k] - 2.0 > LEGENDRE_NOTE_SE * se).then_some((k, est.d[k], se))
        })
        .collect();
    // quoted where it is most significant, with the largest D
    let ratio = |&(_, d, se): &(usize, f64, f64)| (d - 2.0) / se;
    if let Some(&(k, d, se)) = above.iter().max_by(|a, b| ratio(a).total_cmp(&ratio(b))) {
        let top = above.iter().map(|a| a.1).fold(f64::MIN, f64::max);
        out.push(format!(
            "D(q) > 2 at {} of the q (most clearly D = {d:.3} +- {se:.3} at q = {}, {}; up to \
             {top:.3}): a dimension above that of the image's support, so there D is not the \
             dimension of a set of singularities (a bias of the estimator, or a fit over mixed \
             regimes)",
            above.len(),
            q[k],
            departure((d - 2.0) / se)
        ));
    }
    out
}

/// Cells of the same sums to 1e-9 relative: the same image, or the image
/// flipped or transposed (the same maxima, summed in another order, so
/// equal only to the FFT's rounding). Distinct images never come so near.
/// `zl` (weights times log2 M) nearly cancels where log2 M straddles 0, so
/// its rounding is measured against `z` too: the weighted means of log2 M,
/// `zl / z`, then agree to 1e-9 (in log2 units).
pub(crate) fn same_cells(a: &[Cell], b: &[Cell]) -> bool {
    let near = |x: f64, y: f64| (x - y).abs() <= 1e-9 * x.abs().max(y.abs());
    let near_mean = |x: f64, y: f64, z: f64| (x - y).abs() <= 1e-9 * x.abs().max(y.abs()).max(z);
    a.len() == b.len()
        && a.iter().zip(b).all(|(c, d)| {
            if c.z == 0.0 || d.z == 0.0 {
                return c.z == d.z;
            }
            // the exponents of a value near a power of two may differ by one
            let k = match d.e.checked_sub(c.e) {
                Some(k) if k.abs() <= 1 => (k as f64).exp2(),
                _ => return false,
            };
            near(c.z, d.z * k) && near_mean(c.zl, d.zl * k, c.z) && near(c.z2, d.z2 * k * k)
        })
}
