//! From partition sums to spectra: the ensemble sums of each cell, the
//! regressions over the fit range, the jackknife over images (or tiles),
//! and the Legendre transform.

use super::*;

impl PartitionSums {
    /// The tiles of every image as the images of a new set of sums (the
    /// jackknife groups of an ensemble of fewer than 3 images); `None`
    /// when an image has no tiles or there are fewer than 3 in all.
    pub(super) fn tile_groups(&self) -> Option<PartitionSums> {
        if self.images.iter().any(|im| im.tiles.is_empty()) {
            return None;
        }
        let images: Vec<ImagePartial> = self
            .images
            .iter()
            .flat_map(|im| {
                im.tiles.iter().enumerate().map(|(k, t)| ImagePartial {
                    label: format!("{} tile {k}", im.label),
                    shape: None,
                    missing: 0,
                    lines: t.lines.clone(),
                    sup: t.sup.clone(),
                    plain: t.plain.clone(),
                    tiles: Vec::new(),
                    tile_side: 0,
                    ..Default::default()
                })
            })
            .collect();
        (images.len() >= 3).then(|| PartitionSums {
            version: self.version.clone(),
            analysis: None,
            q: self.q.clone(),
            scales: self.scales.clone(),
            images,
            pixel: self.pixel.clone(),
        })
    }

    /// Annealed ensemble values per cell, leaving out image `skip` if given.
    pub(super) fn ensemble(&self, rule: Rule, skip: Option<usize>) -> Ensemble {
        let ns = self.scales.len();
        let nq = self.q.len();
        let mut out = Ensemble {
            log2_z: vec![f64::NAN; nq * ns],
            h: vec![f64::NAN; nq * ns],
            n_eff: vec![0.0; nq * ns],
            lines: vec![0; ns],
        };
        for (i, im) in self.images.iter().enumerate() {
            if Some(i) == skip {
                continue;
            }
            for (j, &n) in im.lines.iter().enumerate() {
                out.lines[j] += n;
            }
        }
        let mut parts: Vec<Cell> = Vec::with_capacity(self.images.len());
        for c in 0..nq * ns {
            parts.clear();
            for (i, im) in self.images.iter().enumerate() {
                if Some(i) == skip {
                    continue;
                }
                let cell = match rule {
                    Rule::Sup => im.sup[c],
                    Rule::Plain => im.plain[c],
                };
                if !cell.is_empty() {
                    parts.push(cell);
                }
            }
            if parts.is_empty() {
                continue;
            }
            // canonical order: the sum does not depend on merge order
            parts.sort_by(canonical);
            out.set(c, parts.iter());
        }
        out
    }

    /// The values of image `i` alone (its own partition functions).
    pub(super) fn image_ensemble(&self, rule: Rule, i: usize) -> Ensemble {
        let ns = self.scales.len();
        let nq = self.q.len();
        let im = &self.images[i];
        let mut out = Ensemble {
            log2_z: vec![f64::NAN; nq * ns],
            h: vec![f64::NAN; nq * ns],
            n_eff: vec![0.0; nq * ns],
            lines: im.lines.clone(),
        };
        let cells = match rule {
            Rule::Sup => &im.sup,
            Rule::Plain => &im.plain,
        };
        for (c, cell) in cells.iter().enumerate() {
            if !cell.is_empty() {
                out.set(c, std::iter::once(cell));
            }
        }
        out
    }

    /// `ensemble(rule, Some(i))` for each `i` in `skips`, in that order:
    /// the same sums to the bit (the cells left after removing one lie in
    /// the order of all of them sorted), with each cell's parts sorted
    /// once for the whole batch instead of once per replicate. A cell of
    /// more than [`LOO_REFOLD_MAX`] parts (the tiles of a big lone image)
    /// is left out of from running sums from both ends instead of summed
    /// again without each: the same sums to rounding (1e-15), in O(parts)
    /// instead of O(parts x skips).
    pub(super) fn ensembles_leaving_out(
        &self,
        rule: Rule,
        skips: std::ops::Range<usize>,
    ) -> Vec<Ensemble> {
        let ns = self.scales.len();
        let nq = self.q.len();
        let mut total = vec![0u64; ns];
        for im in &self.images {
            for (j, &n) in im.lines.iter().enumerate() {
                total[j] += n;
            }
        }
        let mut outs: Vec<Ensemble> = skips
            .clone()
            .map(|i| Ensemble {
                log2_z: vec![f64::NAN; nq * ns],
                h: vec![f64::NAN; nq * ns],
                n_eff: vec![0.0; nq * ns],
                lines: (0..ns)
                    .map(|j| total[j] - self.images[i].lines[j])
                    .collect(),
            })
            .collect();
        let mut parts: Vec<(usize, Cell)> = Vec::with_capacity(self.images.len());
        let mut place: Vec<usize> = Vec::new();
        for c in 0..nq * ns {
            parts.clear();
            for (i, im) in self.images.iter().enumerate() {
                let cell = match rule {
                    Rule::Sup => im.sup[c],
                    Rule::Plain => im.plain[c],
                };
                if !cell.is_empty() {
                    parts.push((i, cell));
                }
            }
            parts.sort_by(|a, b| canonical(&a.1, &b.1));
            if parts.len() > LOO_REFOLD_MAX {
                let cells: Vec<&Cell> = parts.iter().map(|p| &p.1).collect();
                let total = cells.iter().fold(Cell::EMPTY, |a, c| a.add(c));
                let rest = crate::stats::fit::leave_one_out(&cells, Cell::EMPTY, Cell::add);
                place.clear();
                place.resize(self.images.len(), usize::MAX);
                for (k, p) in parts.iter().enumerate() {
                    place[p.0] = k;
                }
                for (out, skip) in outs.iter_mut().zip(skips.clone()) {
                    let r = match place[skip] {
                        usize::MAX => &total,
                        k => &rest[k],
                    };
                    if !r.is_empty() {
                        out.set(c, std::iter::once(r));
                    }
                }
                continue;
            }
            for (out, skip) in outs.iter_mut().zip(skips.clone()) {
                let mut rest = parts
                    .iter()
                    .filter(|p| p.0 != skip)
                    .map(|p| &p.1)
                    .peekable();
                if rest.peek().is_some() {
                    out.set(c, rest);
                }
            }
        }
        outs
    }

    /// Exponents over the fit range `fit = (lo, hi)` in octaves above the
    /// smallest scale (SPEC §13 `--fit`), for the rule `rule`.
    ///
    /// **Errors** if the sums fail [`PartitionSums::check`] (e.g. a q grid
    /// with NaN or duplicates, no scales), if the fit range is not within
    /// the scales (`0 <= lo < hi <= ` the octaves they span, the last scale
    /// plus one step: 4 for a grid of 4 octaves), if an end lies between
    /// two scales (it would fit from the next one), or if fewer than 3
    /// scales fall in it. [`default_fit`] gives the CLI's range.
    pub fn spectra(&self, rule: Rule, fit: (f64, f64)) -> Result<Spectra> {
        self.check()?;
        let ns = self.scales.len();
        let nq = self.q.len();
        let log2_a: Vec<f64> = self.scales.iter().map(|a| a.log2()).collect();
        let oct0 = log2_a[0];
        check_fit_on_grid(&self.scales, fit)?;
        let in_fit = fit_indices(&self.scales, fit)?;
        let ens = self.ensemble(rule, None);
        let est = Estimates::fit(&ens, &log2_a, &in_fit, &self.q);
        // delete-one jackknife over images: error bars from the ensemble
        // scatter; below 3 images, over the tiles of their domains if they
        // were split (the regression's error otherwise)
        let n_img = self.images.len();
        let tiled = if n_img < 3 { self.tile_groups() } else { None };
        let groups = tiled.as_ref().unwrap_or(self);
        let n_groups = groups.images.len();
        let mut jk_tau = vec![f64::NAN; nq];
        let mut jk_h = vec![f64::NAN; nq];
        let mut jk_d = vec![f64::NAN; nq];
        let mut reps: Vec<Estimates> = Vec::new();
        // the per-scale values of the figures, and their errors, streamed
        // (thousands of tiles' replicates of every cell are not kept)
        let values = scale_values(&ens, &self.q, &log2_a);
        let mut per_scale = values.clone().map(crate::stats::fit::JackknifeStream::new);
        if n_groups >= 3 {
            // in batches: the replicates of a batch share one sort per cell,
            // and memory stays bounded whatever the number of groups
            let batch = loo_batch(n_groups, nq * ns);
            for i0 in (0..n_groups).step_by(batch) {
                let range = i0..(i0 + batch).min(n_groups);
                for e in groups.ensembles_leaving_out(rule, range) {
                    reps.push(Estimates::fit(&e, &log2_a, &in_fit, &self.q));
                    for (acc, v) in per_scale.iter_mut().zip(scale_values(&e, &self.q, &log2_a)) {
                        acc.add(&v);
                    }
                }
            }
            let jk = |get: &dyn Fn(&Estimates) -> f64| -> f64 {
                crate::stats::jackknife_se(&reps.iter().map(get).collect::<Vec<_>>())
            };
            for qi in 0..nq {
                jk_tau[qi] = jk(&|e: &Estimates| e.tau[qi]);
                jk_h[qi] = jk(&|e: &Estimates| e.h[qi]);
                jk_d[qi] = jk(&|e: &Estimates| e.d[qi]);
            }
        }
        let last_fit = *in_fit.last().expect("3 scales");
        // the smallest scale step (octaves): the linking window bounds the
        // local exponent a line follows to log2(ratio) per step
        let step = self
            .scales
            .windows(2)
            .map(|w| (w[1] / w[0]).log2())
            .fold(f64::NAN, f64::min);
        if est.tau.iter().all(|t| !t.is_finite()) {
            // nothing to report: an error, not a file of nulls
            if ens.lines.iter().all(|&n| n == 0) {
                return Err(Error::Input(
                    "no maxima line at any scale: the image is flat (constant), or its \
                     counting domain is empty"
                        .into(),
                ));
            }
            // say how small the domain is and how far the lines do reach,
            // so that the user can pick the options
            let domain = match (
                self.images.iter().filter_map(|im| im.shape).min(),
                self.analysis.as_ref().map(|a| a.margin_px()),
            ) {
                (Some([ny, nx]), Some(m)) => format!(
                    " (the counting domain of the {ny}x{nx} image is {}x{} px inside a \
                     {m} px margin)",
                    ny.saturating_sub(2 * m),
                    nx.saturating_sub(2 * m)
                ),
                _ => String::new(),
            };
            let missing: u64 = self.images.iter().map(|im| im.missing).sum();
            let domain = if missing > 0 {
                format!(
                    "{domain}, less the {missing} missing pixels' surroundings (maxima count only \
                     farther from them than the wavelet's support at the largest scale)"
                )
            } else {
                domain
            };
            let reach = match ens.lines.iter().rposition(|&n| n > 0) {
                Some(j) => format!(
                    "; the longest lines end at a = {:.2} px, {:.2} octaves above the first \
                     scale",
                    self.scales[j],
                    log2_a[j] - oct0
                ),
                None => String::new(),
            };
            // what ends the lines: a domain too small for the scales, or a
            // ratio window too narrow for the scale step (it bounds the
            // local exponents a line can follow, LinkParams::ratio)
            let margin = self.analysis.as_ref().map_or(0, |a| a.margin_px());
            let info = self.info_hint();
            // a domain several wavelet supports wide at the fit's top is
            // not what ends the lines (a step edge's lines die at once in
            // a 184 px domain): said so, not "too small"
            let roomy = match (
                &self.analysis,
                self.images.iter().filter_map(|im| im.shape).min(),
            ) {
                (Some(cfg), Some([ny, nx])) if missing == 0 => {
                    let side = ny.min(nx).saturating_sub(2 * margin) as f64;
                    let across = 2.0 * cfg.wavelet.support_radius() * self.scales[last_fit];
                    (side >= 2.0 * across).then_some((side, across))
                }
                _ => None,
            };
            let cure = if let Some((side, across)) = roomy {
                format!(
                    "; yet the counting domain, {side:.0} px across, holds {:.1} wavelet \
                     supports ({across:.0} px) at the top of the fit, so its size is not what \
                     ends the lines: the image has few singularities that persist across \
                     scales (smooth, piecewise flat or quantised, e.g. a step edge or \
                     terraces), or the linking loses them",
                    side / across
                )
            } else if margin > 0 || missing > 0 {
                format!(
                    "; the counting domain is too small for these scales (use fewer octaves, a \
                     smaller margin, or a lower fit range: --octaves, --margin, --fit{info})"
                )
            } else {
                "; the whole image is counted, so the scales reach too far for its size (use \
                 fewer octaves or a lower fit range: --octaves, --fit)"
                    .to_string()
            };
            // said when the window admits less than h in [-1, n], n the
            // wavelet's order, the exponents it can measure (the default,
            // (0.9, 1.11) at 10 voices, admits +-1.5: enough for gauss, not
            // for the smooth parts of a field seen by mexican, whose
            // modulus can grow up to a^3)
            let window = match self
                .analysis
                .as_ref()
                .map(|a| (a.link.ratio, a.wavelet.order() as f64))
            {
                Some(((lo, hi), order))
                    if step > 0.0 && (hi.log2() / step < order || lo.log2() / step > -1.0) =>
                {
                    format!(
                        ", or the linking: a line follows a local exponent only from {:.2} to {:.2} \
                     per octave at this scale step ({:.3} octave) and --ratio {lo}:{hi}; \
                     lines whose modulus changes faster end (more --voices or a wider --ratio)",
                        lo.log2() / step,
                        hi.log2() / step,
                        step
                    )
                }
                _ => String::new(),
            };
            // a plane can swamp the surface at large scales: said as the
            // likely cause where it is one
            let plane = self
                .plane_warning()
                .map_or(String::new(), |w| format!("; {w}"));
            return Err(Error::Input(format!(
                "no q has a partition function over the fit range: {} maxima lines reach \
                 a = {:.2} px, the top of the fit range, in {} image(s){domain}{reach}{cure}{window}{plane}",
                ens.lines[last_fit], self.scales[last_fit], n_img
            )));
        }
        let (legendre_h, legendre_d) = legendre(&self.q, &est.tau);
        let mut warnings = Vec::new();
        // The transform is periodic (FFT): a wavelet wider than the image
        // sees the image's own periodic copies (a torus) or its opposite
        // edge, not larger structures. The interior margin rules that out;
        // the whole image (--margin 0, a torus) does not.
        let side = self
            .images
            .iter()
            .filter_map(|im| im.shape)
            .map(|[ny, nx]| ny.min(nx))
            .min();
        if let (Some(cfg), Some(side)) = (&self.analysis, side) {
            let r = cfg.wavelet.support_radius();
            let across = 2.0 * r * self.scales[last_fit];
            if across > side as f64 {
                // the cure names scales of the grid, since --fit takes
                // only those (an octave between two is refused above), and
                // keeps the 3 scales a fit needs
                let a_fits = side as f64 / (2.0 * r);
                let first = in_fit[0];
                let cure = match self
                    .scales
                    .iter()
                    .rposition(|&a| a <= a_fits * (1.0 + 1e-12))
                {
                    Some(j) if j >= first + 2 => format!(
                        "fit only up to a = {:.2} px, the largest scale at most {a_fits:.1} px \
                         (--fit {}:{}), or analyse larger images",
                        self.scales[j],
                        octave_arg(log2_a[first] - oct0),
                        octave_arg(log2_a[j] - oct0)
                    ),
                    _ => format!(
                        "fewer than 3 fitted scales are at most {a_fits:.1} px: fit from smaller \
                         scales, or analyse larger images"
                    ),
                };
                warnings.push(format!(
                    "the wavelet's support at the largest fitted scale, a = {:.2} px, is {across:.0} \
                     px across, wider than the smallest image side, {side} px: the transform is \
                     periodic, so there the wavelet sees the image's own copies (or its opposite \
                     edge), not larger structures; {cure}",
                    self.scales[last_fit],
                ));
            }
        }
        // A margin given narrower than the wavelet (0 is the torus, said
        // above when too small): maxima near the border are counted though
        // their wavelet reaches past it, and the transform wraps there.
        if let Some(cfg) = &self.analysis
            && let Some(m) = cfg.margin.filter(|&m| m > 0)
        {
            let reach = cfg.wavelet.support_radius() * self.scales[last_fit];
            if (m as f64) < reach {
                // in whole pixels as the margins are (31.2 px reads 32)
                let reach = reach.ceil();
                warnings.push(format!(
                    "the margin of {m} px (--margin) is narrower than the wavelet's support at \
                     the largest fitted scale, {reach:.0} px at a = {:.2} px: maxima counted \
                     nearer the border see past it, where the periodic transform wraps to the \
                     opposite edge (the default margin, {} px, keeps them out)",
                    self.scales[last_fit],
                    crate::cwt::default_margin(cfg.wavelet, cfg.a_max())
                ));
            }
        }
        for qi in 0..nq {
            if !est.tau[qi].is_finite() {
                warnings.push(format!(
                    "q = {}: tau not estimable (empty partition function in the fit range)",
                    self.q[qi]
                ));
            }
        }
        // the per-q diagnostics below come in runs of neighbouring q (the
        // tails of the q range): one warning per run, not one per q
        let curved: Vec<Option<f64>> = (0..nq)
            .map(|qi| {
                let d = est.slope_change[qi];
                (est.tau[qi].is_finite() && is_curved(d)).then_some(d)
            })
            .collect();
        // a run of several q quotes its extreme value and where it is
        let at = |several: bool, qi: usize, most: &str| {
            if several {
                (format!("{most} "), format!(" (at q = {})", self.q[qi]))
            } else {
                (String::new(), String::new())
            }
        };
        for (run, qi, several) in runs(&self.q, &curved, f64::abs) {
            let (most, where_) = at(several, qi, "up to");
            warnings.push(format!(
                "{run}: log2 Z(q, a) is not a straight line over the fit range: its local slope \
                 changes by {most}{:+.2}{where_} from a = {:.2} to {:.2} px (more than \
                 {SLOPE_CHANGE_WARN}: the local tau(q) strays more than {} either side of the \
                 fitted one)",
                est.slope_change[qi],
                self.scales[in_fit[0]],
                self.scales[last_fit],
                SLOPE_CHANGE_WARN / 2.0
            ));
        }
        let dominated: Vec<Option<f64>> = (0..nq)
            .map(|qi| {
                let worst = in_fit
                    .iter()
                    .map(|&j| ens.n_eff[qi * ns + j])
                    .fold(f64::INFINITY, f64::min);
                (est.tau[qi].is_finite() && worst < N_EFF_WARN).then_some(worst)
            })
            .collect();
        for (run, qi, several) in runs(&self.q, &dominated, |n| -n) {
            let (most, where_) = at(several, qi, "as few as");
            warnings.push(format!(
                "{run}: Z(q, a) is dominated by {most}{:.1} effective maxima lines{where_} at the \
                 largest fitted scales (< {N_EFF_WARN})",
                dominated[qi].unwrap_or(f64::NAN),
            ));
        }
        // II §3.1: a wavelet with n vanishing moments measures exponents
        // below n; where the lines grow like a^n or faster the estimate is
        // not a Hölder exponent (smooth or quantised parts, or too low an
        // order). Within 0.01 of the order, h cannot be told from that
        // saturation (a smooth ramp reads 1 - 3e-11 with gauss; the fit's
        // own error is larger than 0.01)
        if let Some(w) = self.analysis.as_ref().map(|a| a.wavelet) {
            let order = f64::from(w.order());
            let at: Vec<usize> = (0..nq)
                .filter(|&qi| at_wavelet_order(est.h[qi], order))
                .collect();
            if let (Some(&first), Some(&last)) = (at.first(), at.last()) {
                let top = at.iter().map(|&qi| est.h[qi]).fold(f64::MIN, f64::max);
                let moments = if order == 1.0 { "moment" } else { "moments" };
                warnings.push(format!(
                    "h(q) >= {order} (to 0.01) at {} of the q ({}, up to h = {top:.3}): the {} \
                     wavelet has {order} vanishing {moments} and cannot measure exponents of \
                     {order} or more, so these are not Hölder exponents (smooth or quantised \
                     parts of the image, or a wavelet of too low an order{})",
                    at.len(),
                    q_span(self.q[first], self.q[last]),
                    w.name(),
                    if w == crate::cwt::Wavelet::Gauss {
                        ": try the mexican wavelet (--wavelet mexican)"
                    } else {
                        ""
                    }
                ));
            }
        }
        // the ratio window bounds the local exponent a line can follow per
        // scale step (LinkParams::ratio): an estimate beyond that bound
        // comes from lines that end where their modulus grows faster, so the
        // exponents there are under-counted (a DEM's smooth parts seen by
        // mexican: Levi Fell, 3 octaves, reads h(-4) = 2.04 past 1.51)
        if let Some((lo, hi)) = self.analysis.as_ref().map(|a| a.link.ratio)
            && step > 0.0
        {
            let bound = hi.log2() / step;
            let at: Vec<usize> = (0..nq).filter(|&qi| est.h[qi] >= bound).collect();
            if let (Some(&first), Some(&last)) = (at.first(), at.last()) {
                let top = at.iter().map(|&qi| est.h[qi]).fold(f64::MIN, f64::max);
                warnings.push(format!(
                    "h(q) >= {bound:.2} at {} of the q ({}, up to h = {top:.3}): the \
                     linking window --ratio {lo}:{hi} at steps of {step:.3} octave lets a line \
                     follow a local exponent of at most {bound:.2} per octave, so lines whose \
                     modulus grows faster end and these exponents are under-counted (widen \
                     --ratio, e.g. 0.8:1.25)",
                    at.len(),
                    q_span(self.q[first], self.q[last]),
                ));
            }
        }
        if self.q.len() < 2 {
            // a derivative needs two q (SPEC §4: no NaN without a word)
            warnings.push(format!(
                "one q ({}): the Legendre spectrum (legendre_h, legendre_D) needs two or more \
                 and is left empty (null); h(q) and D(q) are those of the canonical sums",
                q_span(self.q[0], self.q[0])
            ));
        }
        warnings.extend(legendre_warnings(&self.q, &est, &reps));
        let holed: Vec<u64> = self
            .images
            .iter()
            .map(|p| p.missing)
            .filter(|&m| m > 0)
            .collect();
        if !holed.is_empty() {
            warnings.push(format!(
                "{} image(s) with missing pixels (NaN, inf or nodata; {} in all): maxima count \
                 only farther from them than the wavelet's support at the largest scale{}",
                holed.len(),
                holed.iter().sum::<u64>(),
                self.counted_note()
            ));
        }
        let image_shapes = self.image_shapes();
        if image_shapes.len() > 1 {
            let list: Vec<String> = image_shapes
                .iter()
                .map(|c| format!("{} of {}x{}", c.images, c.ny, c.nx))
                .collect();
            warnings.push(format!(
                "images of {} sizes ({}): the sums add every image's maxima at the same pixel \
                 scales, so the larger images weigh more",
                image_shapes.len(),
                list.join(", ")
            ));
        }
        let per_image = if n_img >= UNLIKE_MIN_IMAGES {
            self.per_image(rule, &log2_a, &in_fit)
        } else {
            Vec::new()
        };
        let dups = self.duplicate_images();
        warnings.extend(self.duplicate_warning(&dups));
        // copies of an image (said above) would make the others look alike
        // and any distinct image "unlike" them: the test sees each once
        let copies: Vec<usize> = dups.iter().map(|p| p.1).collect();
        let distinct: Vec<ImageExponents> = per_image
            .iter()
            .enumerate()
            .filter(|(i, _)| !copies.contains(i))
            .map(|(_, e)| e.clone())
            .collect();
        warnings.extend(unlike_images(&distinct));
        warnings.extend(self.plane_warning());
        warnings.extend(self.fill_warning());
        warnings.extend(self.quantisation_warnings(self.scales[in_fit[0]]));
        if ens.lines[last_fit] < 100 {
            // the border margin is often why: say how much of the image it
            // leaves (a 400^2 DEM keeps 112^2 px at the default 5 octaves)
            let margin_note = self
                .analysis
                .as_ref()
                .map(|a| {
                    let a_max = a.scale_list().last().copied().unwrap_or(0.0);
                    let why = match a.margin {
                        Some(_) => "as given (--margin)".to_string(),
                        None => format!(
                            "set by the largest analysed scale {a_max:.1} px; fewer --octaves \
                             or a smaller --margin keep more of it{}",
                            self.info_hint()
                        ),
                    };
                    (a.margin_px(), why)
                })
                .filter(|(m, _)| *m > 0)
                .and_then(|(m, why)| {
                    let (ny, nx) = image_shapes
                        .iter()
                        .map(|c| (c.ny, c.nx))
                        .min_by_key(|&(ny, nx)| ny * nx)?;
                    Some(format!(
                        " (the counting domain of a {ny}x{nx} image is {}x{} px: a margin of \
                         {m} px on every side, {why})",
                        ny.saturating_sub(2 * m),
                        nx.saturating_sub(2 * m)
                    ))
                })
                .unwrap_or_default();
            warnings.push(format!(
                "only {} maxima {} alive at the largest fitted scale a = {:.2}{margin_note}",
                ens.lines[last_fit],
                if ens.lines[last_fit] == 1 {
                    "line"
                } else {
                    "lines"
                },
                self.scales[last_fit]
            ));
        }
        // where a leave-one-out sample has no estimate (an image carries
        // every line that reaches the fit's top), the regression error
        // stands in for that q: said, not silent
        let fallback: Vec<String> = (0..nq)
            .filter(|&qi| {
                n_groups >= 3
                    && est.tau[qi].is_finite()
                    && !(jk_tau[qi].is_finite() && jk_h[qi].is_finite() && jk_d[qi].is_finite())
            })
            .map(|qi| format!("q = {}", self.q[qi]))
            .collect();
        let stderr_method = match &tiled {
            Some(t) => crate::stats::fit::stderr_method_tiles(
                n_img,
                t.images.len(),
                &tile_sides(self.images.iter().map(|im| im.tile_side)),
                &fallback,
                &mut warnings,
            ),
            None => {
                let with = self.images.iter().filter(|im| !im.tiles.is_empty()).count();
                let why = crate::stats::fit::no_tiles_why(n_img, with);
                crate::stats::fit::stderr_method_why(n_img, &fallback, &mut warnings, why)
            }
        };
        let cell = |v: &Vec<f64>| -> Vec<Vec<f64>> {
            (0..nq)
                .map(|qi| v[qi * ns..(qi + 1) * ns].to_vec())
                .collect()
        };
        // no jackknife (fewer than 3 groups): no per-scale errors
        let [z_se, h_se, d_se, slope_se] = per_scale.map(|acc| cell(&acc.stderr()));
        let [_, _, d_qa, slopes] = values;
        // one span when every chord has it (a regular grid), else NaN
        let spans: Vec<f64> = local_slope_chords(&log2_a)
            .into_iter()
            .flatten()
            .map(|(i, k)| round9(log2_a[k] - log2_a[i]))
            .collect();
        let local_slope_octaves = match spans.first() {
            Some(&w) if spans.iter().all(|&x| (x - w).abs() <= 1e-6) => w,
            _ => f64::NAN,
        };
        Ok(Spectra {
            rule,
            images: n_img,
            image_shapes,
            q: self.q.clone(),
            fit_octaves: fit,
            fit_octaves_used: (
                round9(log2_a[in_fit[0]] - oct0),
                round9(log2_a[last_fit] - oct0),
            ),
            fit_scales: (self.scales[in_fit[0]], self.scales[last_fit]),
            tau_stderr: pick(&jk_tau, &est.tau_se),
            h_stderr: pick(&jk_h, &est.h_se),
            d_stderr: pick(&jk_d, &est.d_se),
            stderr_method,
            tau: est.tau,
            h: est.h,
            d: est.d,
            tau_r2: est.r2,
            tau_slope_change: est.slope_change,
            legendre_h,
            legendre_d,
            log2_scales: log2_a,
            log2_z: cell(&ens.log2_z),
            h_qa: cell(&ens.h),
            d_qa: cell(&d_qa),
            log2_z_stderr: z_se,
            h_qa_stderr: h_se,
            d_qa_stderr: d_se,
            local_slopes: cell(&slopes),
            local_slopes_stderr: slope_se,
            local_slope_octaves,
            n_eff: cell(&ens.n_eff),
            lines: ens.lines,
            per_image,
            image_records: self.images.iter().map(ImageRecord::of).collect(),
            warnings,
        })
    }

    /// h(q = 0) and tau(q = 2) of each image on its own (NaN where the
    /// q grid lacks the q or the image has no estimate).
    pub(super) fn per_image(
        &self,
        rule: Rule,
        log2_a: &[f64],
        in_fit: &[usize],
    ) -> Vec<ImageExponents> {
        let at = |q0: f64| self.q.iter().position(|&q| (q - q0).abs() < 1e-9);
        let (q0, q2) = (at(0.0), at(2.0));
        (0..self.images.len())
            .map(|i| {
                let e = Estimates::fit(&self.image_ensemble(rule, i), log2_a, in_fit, &self.q);
                ImageExponents {
                    label: self.images[i].label.clone(),
                    h_q0: q0.map_or(f64::NAN, |k| e.h[k]),
                    tau_q2: q2.map_or(f64::NAN, |k| e.tau[k]),
                    shape: self.images[i].shape,
                }
            })
            .collect()
    }
}

/// Runs of neighbouring q (adjacent in the q list) that carry a value:
/// per run its label (`q = a`, `q = a, b`, `q = a .. b`), the index of its
/// most extreme value (the largest `key`) and whether it holds several q.
pub(super) fn runs(
    q: &[f64],
    v: &[Option<f64>],
    key: impl Fn(f64) -> f64,
) -> Vec<(String, usize, bool)> {
    crate::stats::fit::flagged_runs(v, key)
        .into_iter()
        .map(|(start, end, worst)| {
            let label = match end - start {
                0 => format!("q = {}", q[start]),
                1 => format!("q = {}, {}", q[start], q[end]),
                _ => format!("q = {} .. {}", q[start], q[end]),
            };
            (label, worst, end > start)
        })
        .collect()
}

/// Jackknife where available, regression otherwise.
pub(super) fn pick(jk: &[f64], reg: &[f64]) -> Vec<f64> {
    jk.iter()
        .zip(reg)
        .map(|(&a, &b)| if a.is_finite() { a } else { b })
        .collect()
}

/// The cells of every q for one scale. On a uniform q grid the terms are
/// built by recurrence, `2^(q_k l) = 2^(q_0 l) (2^(dq l))^k`, two `exp2` per
/// line instead of one per q (the partition sums were 11 M `exp2` per
/// image); the shift `e = ceil(max q l)` comes from the extreme `l`. Falls
/// back to [`cell`] when the grid is not uniform or `|q l|` could leave the
/// range of f64.
pub(super) fn cells_all_q(log2m: &[f64], q: &[f64]) -> Vec<Cell> {
    let nq = q.len();
    let (lmin, lmax) = log2m
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &l| {
            (a.min(l), b.max(l))
        });
    let dq = if nq > 1 {
        (q[nq - 1] - q[0]) / (nq - 1) as f64
    } else {
        0.0
    };
    let uniform = nq > 2
        && q.iter()
            .enumerate()
            .all(|(k, &v)| (v - (q[0] + k as f64 * dq)).abs() <= 1e-12 * (1.0 + v.abs()));
    let qmax = q.iter().fold(0.0f64, |a, &v| a.max(v.abs()));
    let lbig = lmin.abs().max(lmax.abs());
    if !uniform || !(qmax * lbig < 900.0) {
        return q.iter().map(|&v| cell(log2m, v)).collect();
    }
    let e: Vec<f64> = q
        .iter()
        .map(|&v| (v * if v >= 0.0 { lmax } else { lmin }).ceil())
        .collect();
    let shift: Vec<f64> = e.iter().map(|&x| (-x).exp2()).collect();
    let mut z = vec![0.0; nq];
    let mut zl = vec![0.0; nq];
    let mut z2 = vec![0.0; nq];
    for &l in log2m {
        let mut r = (q[0] * l).exp2();
        let u = (dq * l).exp2();
        for k in 0..nq {
            let t = r * shift[k];
            z[k] += t;
            zl[k] += t * l;
            z2[k] += t * t;
            r *= u;
        }
    }
    (0..nq)
        .map(|k| Cell {
            e: e[k] as i32,
            z: z[k],
            zl: zl[k],
            z2: z2[k],
        })
        .collect()
}

pub(super) fn cell(log2m: &[f64], q: f64) -> Cell {
    let mut mx = f64::NEG_INFINITY;
    for &l in log2m {
        mx = mx.max(q * l);
    }
    let e = mx.ceil();
    let (mut z, mut zl, mut z2) = (0.0, 0.0, 0.0);
    for &l in log2m {
        let t = (q * l - e).exp2();
        z += t;
        zl += t * l;
        z2 += t * t;
    }
    Cell {
        e: e as i32,
        z,
        zl,
        z2,
    }
}

pub(super) struct Ensemble {
    pub(super) log2_z: Vec<f64>,
    pub(super) h: Vec<f64>,
    pub(super) n_eff: Vec<f64>,
    pub(super) lines: Vec<u64>,
}

/// Most parts of an ensemble cell that [`PartitionSums::ensembles_leaving_out`]
/// sums again without each one (bit-identical to [`PartitionSums::ensemble`],
/// so that an ensemble of images gives the same errors however it was
/// merged); beyond, running sums from both ends (2025 tiles of a 2048^2
/// image at 3 octaves: 37 s of refolding).
pub(super) const LOO_REFOLD_MAX: usize = 64;

/// Replicates per batch of [`PartitionSums::ensembles_leaving_out`] when
/// the cells are left out of from running sums ([`LOO_REFOLD_MAX`]): each
/// batch sorts every cell's parts once, so fewer batches cost less; the
/// batch holds `replicates x cells` ensemble cells of 3 values each,
/// bounded here to about 1 M cells (24 MB).
pub(super) fn loo_batch(n_groups: usize, cells: usize) -> usize {
    if n_groups <= LOO_REFOLD_MAX {
        64
    } else {
        ((1usize << 20) / cells.max(1)).clamp(64, 2048)
    }
}

impl Cell {
    /// The sums of both (an empty cell is the identity).
    pub(super) fn add(&self, other: &Cell) -> Cell {
        if other.is_empty() {
            return *self;
        }
        if self.is_empty() {
            return *other;
        }
        let e = self.e.max(other.e);
        let (sa, sb) = (((self.e - e) as f64).exp2(), ((other.e - e) as f64).exp2());
        Cell {
            e,
            z: self.z * sa + other.z * sb,
            zl: self.zl * sa + other.zl * sb,
            z2: self.z2 * sa * sa + other.z2 * sb * sb,
        }
    }
}

impl Ensemble {
    /// Sets cell `c` from its non-empty parts in canonical order
    /// ([`canonical`]; at least one).
    pub(super) fn set<'a>(&mut self, c: usize, parts: impl Iterator<Item = &'a Cell> + Clone) {
        let emax = parts.clone().last().expect("non-empty").e;
        let (mut z, mut zl, mut z2) = (0.0, 0.0, 0.0);
        for p in parts {
            let s = ((p.e - emax) as f64).exp2();
            z += p.z * s;
            zl += p.zl * s;
            z2 += p.z2 * s * s;
        }
        self.log2_z[c] = emax as f64 + z.log2();
        self.h[c] = zl / z;
        self.n_eff[c] = z * z / z2;
    }
}

/// The canonical order of the cells summed into one ensemble cell, so that
/// the sum does not depend on the order of merges.
pub(super) fn canonical(a: &Cell, b: &Cell) -> std::cmp::Ordering {
    a.e.cmp(&b.e)
        .then(a.z.total_cmp(&b.z))
        .then(a.zl.total_cmp(&b.zl))
        .then(a.z2.total_cmp(&b.z2))
}

pub(super) struct Estimates {
    pub(super) tau: Vec<f64>,
    pub(super) tau_se: Vec<f64>,
    pub(super) r2: Vec<f64>,
    pub(super) slope_change: Vec<f64>,
    pub(super) h: Vec<f64>,
    pub(super) h_se: Vec<f64>,
    pub(super) d: Vec<f64>,
    pub(super) d_se: Vec<f64>,
}

impl Estimates {
    pub(super) fn fit(ens: &Ensemble, log2_a: &[f64], in_fit: &[usize], q: &[f64]) -> Self {
        let ns = log2_a.len();
        let x: Vec<f64> = in_fit.iter().map(|&j| log2_a[j]).collect();
        let mut e = Estimates {
            tau: vec![f64::NAN; q.len()],
            tau_se: vec![f64::NAN; q.len()],
            r2: vec![f64::NAN; q.len()],
            slope_change: vec![f64::NAN; q.len()],
            h: vec![f64::NAN; q.len()],
            h_se: vec![f64::NAN; q.len()],
            d: vec![f64::NAN; q.len()],
            d_se: vec![f64::NAN; q.len()],
        };
        for (qi, &qv) in q.iter().enumerate() {
            let z: Vec<f64> = in_fit.iter().map(|&j| ens.log2_z[qi * ns + j]).collect();
            let h: Vec<f64> = in_fit.iter().map(|&j| ens.h[qi * ns + j]).collect();
            if z.iter().any(|v| !v.is_finite()) {
                continue; // a scale without lines: not estimable
            }
            let d: Vec<f64> = z.iter().zip(&h).map(|(zz, hh)| qv * hh - zz).collect();
            if let (Some(fz), Some(fh), Some(fd)) =
                (line_fit(&x, &z), line_fit(&x, &h), line_fit(&x, &d))
            {
                e.tau[qi] = fz.slope;
                e.tau_se[qi] = fz.slope_stderr;
                e.r2[qi] = fz.r2;
                e.slope_change[qi] = slope_change(&x, &z).unwrap_or(f64::NAN);
                e.h[qi] = fh.slope;
                e.h_se[qi] = fh.slope_stderr;
                e.d[qi] = fd.slope;
                e.d_se[qi] = fd.slope_stderr;
            }
        }
        e
    }
}

/// The ends `(i, k)`, `i < j < k`, of the chord behind the local slope at
/// each scale `j` ([`local_slopes`]): the nearest scales at least half an
/// octave below and above it (3 voices per octave take 2 scales either
/// side, 4/3 octave in all; 10 voices 5, one octave; on an irregular list
/// the chord is longer where the scales are sparse, never shorter than an
/// octave). `None` where the grid does not reach half an octave below or
/// above `j`.
pub fn local_slope_chords(log2_a: &[f64]) -> Vec<Option<(usize, usize)>> {
    // half an octave, less a rounding margin (five voices of 0.1 octave
    // may sum to 0.49999999999999994)
    const HALF: f64 = 0.5 - 1e-9;
    let n = log2_a.len();
    (0..n)
        .map(|j| {
            let i = (0..j).rev().find(|&i| log2_a[j] - log2_a[i] >= HALF)?;
            let k = (j + 1..n).find(|&k| log2_a[k] - log2_a[j] >= HALF)?;
            Some((i, k))
        })
        .collect()
}

/// The local slopes of one q's `log2 Z(q, a)` (`log2_z`, one value per
/// scale) against `log2 a`: at scale j the chord between the ends of
/// [`local_slope_chords`], about one octave; NaN where there is none.
///
/// **Panics** if the two differ in length.
pub fn local_slopes(log2_a: &[f64], log2_z: &[f64]) -> Vec<f64> {
    assert_eq!(log2_a.len(), log2_z.len(), "local_slopes: lengths differ");
    slopes_on(&local_slope_chords(log2_a), log2_a, log2_z)
}

/// [`local_slopes`] on chords found once ([`local_slope_chords`]).
fn slopes_on(chords: &[Option<(usize, usize)>], log2_a: &[f64], log2_z: &[f64]) -> Vec<f64> {
    chords
        .iter()
        .map(|c| match *c {
            Some((i, k)) => (log2_z[k] - log2_z[i]) / (log2_a[k] - log2_a[i]),
            None => f64::NAN,
        })
        .collect()
}

/// The per-scale values of an ensemble the figures show, each flat per q
/// then per scale: `log2 Z(q, a)`, `h(q, a)`, `D(q, a) = q h - log2 Z`, and
/// the local slopes of `log2 Z`.
pub(super) fn scale_values(ens: &Ensemble, q: &[f64], log2_a: &[f64]) -> [Vec<f64>; 4] {
    let ns = log2_a.len();
    let d: Vec<f64> = (0..q.len() * ns)
        .map(|c| q[c / ns] * ens.h[c] - ens.log2_z[c])
        .collect();
    let chords = local_slope_chords(log2_a);
    let slopes: Vec<f64> = ens
        .log2_z
        .chunks(ns)
        .flat_map(|z| slopes_on(&chords, log2_a, z))
        .collect();
    [ens.log2_z.clone(), ens.h.clone(), d, slopes]
}

/// Legendre transform of a sampled τ(q): `h = dτ/dq` by finite differences
/// (the slope of the parabola through three neighbouring points, one-sided
/// at the ends, so second-order everywhere on non-uniform grids; two
/// points give their chord), `D = q h - τ` (SPEC §4).
///
/// `q` must be strictly increasing, as [`check_q`] ensures for every grid
/// the crate builds: a repeated q gives a non-finite `h` there. A lone q
/// has no derivative: its `h` and `D` are NaN.
///
/// **Panics** if `q` and `tau` differ in length.
pub fn legendre(q: &[f64], tau: &[f64]) -> (Vec<f64>, Vec<f64>) {
    assert_eq!(q.len(), tau.len(), "legendre: q and tau differ in length");
    let n = q.len();
    let mut h = vec![f64::NAN; n];
    if n == 2 {
        let c = (tau[1] - tau[0]) / (q[1] - q[0]);
        h = vec![c, c];
    } else if n >= 3 {
        for i in 0..n {
            h[i] = if i == 0 {
                // a chord would be off by τ'' dq / 2 (0.01 in h, 0.04 in D
                // at the ends of -4:6:0.5 for the paper cascades)
                parabola_slope(&q[..3], &tau[..3], q[0])
            } else if i == n - 1 {
                parabola_slope(&q[n - 3..], &tau[n - 3..], q[n - 1])
            } else {
                // derivative of the parabola through three points
                let (h1, h2) = (q[i] - q[i - 1], q[i + 1] - q[i]);
                (tau[i + 1] * h1 * h1 - tau[i - 1] * h2 * h2 + tau[i] * (h2 * h2 - h1 * h1))
                    / (h1 * h2 * (h1 + h2))
            };
        }
    }
    let d = (0..n).map(|i| q[i] * h[i] - tau[i]).collect();
    (h, d)
}

/// Slope at `t` of the parabola through three points (`x` distinct): the
/// derivative of the Lagrange interpolant.
pub(super) fn parabola_slope(x: &[f64], y: &[f64], t: f64) -> f64 {
    (0..3)
        .map(|k| {
            let (l, m) = ((k + 1) % 3, (k + 2) % 3);
            y[k] * ((t - x[l]) + (t - x[m])) / ((x[k] - x[l]) * (x[k] - x[m]))
        })
        .sum()
}
