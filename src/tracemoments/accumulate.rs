//! Accumulating an image: its flux at the finest resolution, the moments
//! of its box means at every resolution (whole image or tiles), its
//! structure functions; merging accumulators.

use super::*;

/// A field's least-squares plane, as the trace moments record it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct FieldPlane {
    /// The share of the raw field's variance the plane explains
    /// ([`Field::plane_share`]); `None` without a plane.
    pub share: Option<f64>,
    /// `ξ(1)` of the raw field and of the field less its plane
    /// (`flux::hurst_sf`), recorded when the share exceeds
    /// [`crate::spectra::PLANE_SHARE_WARN`] and the plane is not removed:
    /// how much the plane moves `H_sf` ([`diagnostics`]).
    pub h_sf: Option<[f64; 2]>,
}

impl FieldPlane {
    pub(super) fn of(field: &Field, config: &TraceMomentConfig) -> Self {
        let share = field.plane_share();
        let h_sf = share
            .filter(|&p| config.detrend == Trend::None && p > crate::spectra::PLANE_SHARE_WARN)
            .and_then(|_| {
                let flat = field.detrended(Trend::Plane).ok()?;
                Some([flux::hurst_sf(field)?, flux::hurst_sf(&flat)?])
            });
        FieldPlane { share, h_sf }
    }
}

impl TraceMomentAccumulator {
    /// **Errors** on an invalid configuration.
    pub fn new(config: TraceMomentConfig) -> Result<Self> {
        config.validate()?;
        Ok(TraceMomentAccumulator {
            images: 0,
            max_side: 0,
            n_valid: 0,
            phi_sum: LogSum::default(),
            eta_sum: vec![LogSum::default(); config.eta.len()],
            box_count: Vec::new(),
            tm: vec![Vec::new(); config.q.len()],
            dtm: vec![vec![Vec::new(); config.dtm_q.len()]; config.eta.len()],
            sf_count: Vec::new(),
            sf: vec![Vec::new(); config.sf_q.len()],
            spectrum: None,
            diff_orders: Vec::new(),
            planes: Vec::new(),
            config,
        })
    }

    /// **Errors** unless the accumulator is whole: valid settings, one
    /// sum list per q, η, DTM order and structure-function order, each as
    /// long as its level or lag counts, no more box levels or lags than
    /// the largest image holds (`log2 max_side + 1`: a level appended to a
    /// shard would shift every `log2 λ`), and at most one plane and one
    /// differentiation order per image. A deserialised shard (truncated,
    /// edited) is checked before it is merged or finished.
    pub fn check(&self) -> Result<()> {
        self.config.validate()?;
        let c = &self.config;
        let bad = |what: String| Err(Error::Input(format!("trace-moment sums: {what}")));
        let (nl, nj) = (self.box_count.len(), self.sf_count.len());
        if self.eta_sum.len() != c.eta.len()
            || self.tm.len() != c.q.len()
            || self.dtm.len() != c.eta.len()
            || self.dtm.iter().any(|e| e.len() != c.dtm_q.len())
            || self.sf.len() != c.sf_q.len()
        {
            return bad(format!(
                "{} eta sums, {} moment lists, {} x {:?} DTM lists, {} structure-function lists \
                 for {} eta, {} q, {} DTM q, {} structure-function q",
                self.eta_sum.len(),
                self.tm.len(),
                self.dtm.len(),
                self.dtm.iter().map(Vec::len).collect::<Vec<_>>(),
                self.sf.len(),
                c.eta.len(),
                c.q.len(),
                c.dtm_q.len(),
                c.sf_q.len()
            ));
        }
        if self
            .tm
            .iter()
            .chain(self.dtm.iter().flatten())
            .any(|v| v.len() != nl)
            || self.sf.iter().any(|v| v.len() != nj)
        {
            return bad(format!(
                "sum lists of other lengths than the {nl} box levels or {nj} lags"
            ));
        }
        let levels = if self.max_side > 0 {
            self.max_side.ilog2() as usize + 1
        } else {
            0
        };
        if nl > levels || nj > levels {
            return bad(format!(
                "{nl} box levels and {nj} lags, but images of at most {} px hold {levels}",
                self.max_side
            ));
        }
        if self.planes.len() > self.images || self.diff_orders.len() > self.images {
            return bad(format!(
                "{} planes and {} differentiation orders for {} images",
                self.planes.len(),
                self.diff_orders.len(),
                self.images
            ));
        }
        Ok(())
    }

    /// Adds one field: flux (after the optional fractional integration),
    /// structure functions and spectrum.
    ///
    /// **Errors** if the field is smaller than 8x8 (16x16 with
    /// [`FluxDiff::Auto`], whose `ξ(1)` needs the lags 2 and 4 px, each at
    /// most a quarter of the side), has no valid pixel or
    /// values beyond [`crate::field::AMPLITUDE_LIMIT`]; the accumulator is
    /// then unchanged (everything that can fail is computed first).
    pub fn add_field(&mut self, field: &Field) -> Result<()> {
        field.check()?;
        if let Some(why) = field.amplitude_problem() {
            return Err(Error::Input(why));
        }
        let plane = FieldPlane::of(field, &self.config);
        let field = &*field.detrended(self.config.detrend)?;
        let fill = self.shared_fill(field)?;
        let ps = match &fill {
            Some(f) => power_spectrum(f.view(), &self.config.spectrum)?,
            None => field_power_spectrum(field, &self.config.spectrum)?,
        };
        let (phi, ok, diff) = self.field_flux(field, fill)?;
        self.accumulate_flux(&phi, &ok)?;
        self.diff_orders.push(diff);
        self.planes.push(plane);
        self.accumulate_sf(field);
        match &mut self.spectrum {
            Some(s) => s.merge(&ps)?,
            None => self.spectrum = Some(ps),
        }
        Ok(())
    }

    /// The harmonic fill of `field`'s holes when the spectrum and the flux's
    /// fractional derivative both take the same one (a harmonic spectrum
    /// fill, wrapped across the borders exactly when the flux is periodic:
    /// [`field_power_spectrum`], [`flux::smooth`]), to be computed once
    /// (on 2048^2 with 30 % missing the fill is about a tenth of `tm`);
    /// `None` otherwise.
    pub(super) fn shared_fill(&self, field: &Field) -> Result<Option<Array2<f64>>> {
        let s = &self.config.spectrum;
        let (ny, nx) = field.dim();
        // too small: field_flux says so, before any fill
        if ny < MIN_SIDE
            || nx < MIN_SIDE
            || field.mask.is_none()
            || s.fill != HoleFill::Harmonic
            || (s.window == Window::None) != self.config.periodic
        {
            return Ok(None);
        }
        field.check()?;
        field.filled_harmonic_on(self.config.periodic).map(Some)
    }

    /// The flux of a field, its validity and the differentiation order
    /// used; `fill`: the field's harmonic fill when already computed
    /// ([`Self::shared_fill`]).
    pub(super) fn field_flux(
        &self,
        field: &Field,
        fill: Option<Array2<f64>>,
    ) -> Result<(Array2<f64>, Array2<bool>, f64)> {
        let (ny, nx) = field.dim();
        if ny < MIN_SIDE || nx < MIN_SIDE {
            return Err(Error::Input(format!(
                "image {ny}x{nx} too small for trace moments ({MIN_SIDE}x{MIN_SIDE})"
            )));
        }
        if field.valid_count() == 0 {
            return Err(Error::Input(
                "every pixel is missing (NaN or nodata)".into(),
            ));
        }
        let mask = field.mask.as_ref().map(|m| m.view());
        let diff = match self.config.diff {
            FluxDiff::None => 0.0,
            FluxDiff::Order(d) => d,
            FluxDiff::Auto => flux::hurst_sf(field).ok_or_else(|| {
                Error::Input(match field.range() {
                    Some((lo, hi)) if lo == hi => "constant image: no fluctuations".into(),
                    // xi(1) is fitted over lags 2 px .. side/4: 2 of them
                    // from 16 px
                    _ if sf_lags(ny.min(nx)) < 3 => format!(
                        "image {ny}x{nx} too small for the automatic derivative order: H = \
                         xi(1) is fitted over lags of 2 px up to a quarter of the side, which \
                         needs 16 px or more; give the order (--diff-order; FluxDiff::Order in \
                         the library)"
                    ),
                    _ => format!(
                        "cannot estimate H = xi(1) for the automatic derivative order \
                         (--diff-order auto) from the structure function of this {ny}x{nx} \
                         image (too few lags, or none with a nonzero increment); give the \
                         order (--diff-order; FluxDiff::Order in the library)"
                    ),
                })
            })?,
        };
        // one Fourier filter |k|^(diff - frac_int) (mirror-extended unless
        // the field is a torus)
        let order = self.config.frac_int.unwrap_or(0.0) - diff;
        let smoothed;
        let f = if order != 0.0 {
            smoothed = match fill {
                Some(f) => flux::smooth_filled(f, order, self.config.periodic)?,
                None => flux::smooth(field, order, self.config.periodic)?,
            };
            smoothed.view()
        } else {
            field.data.view()
        };
        let (phi, ok) = flux::flux(f, mask, self.config.flux, self.config.periodic)?;
        Ok((phi, ok, diff))
    }

    /// One field as a whole (`.0`, identical to [`Self::add_field`] on an
    /// empty accumulator) and as spatial tiles (`.1`) for a block jackknife
    /// of a single image ([`finish_jackknife`]). The tiles are those of
    /// [`tile_bounds`]: as many whole tiles of `tile` px as fit along each
    /// side, stretched to cover the image (sides within 1 px of each other).
    /// Tile `t` keeps, in every window of the box pyramid, the blocks (boxes
    /// of side `2^floor(log2 tile)`, the largest fitted box in the CLI) whose
    /// centre lies in it, with every finer box inside them, coarser boxes by
    /// their own centre; and the increments whose midpoint lies in it. A
    /// block larger than the window (a tile larger than the image's largest
    /// box) can have its centre just past the image's edge: it goes to the
    /// nearest tile ([`crate::spectra::TileGrid::index`]). The flux is
    /// computed once on the whole field, so the tiles' box sums add up
    /// exactly to the whole image's at every level. Each tile carries the
    /// whole field's spectrum (β is not jackknifed). Tiles with no valid
    /// flux pixel are left out; fewer than 2 tiles give one part, the whole
    /// field.
    ///
    /// One accumulator per tile: a tile narrower than the largest fitted
    /// box ([`analyze_tiled`] takes that box, [`tile_side`]) is no
    /// independent sample, and small tiles are many (a 1 px tile of a 256²
    /// field makes 65536 accumulators).
    ///
    /// **Errors** as [`Self::add_field`], or if `tile` is 0.
    pub fn field_tiles(
        config: &TraceMomentConfig,
        field: &Field,
        tile: usize,
    ) -> Result<(TraceMomentAccumulator, Vec<TraceMomentAccumulator>)> {
        if tile == 0 {
            return Err(Error::param("tile", "must be at least 1 px"));
        }
        if let Some(why) = field.amplitude_problem() {
            return Err(Error::Input(why));
        }
        let plane = FieldPlane::of(field, config);
        let field = &*field.detrended(config.detrend)?;
        let mut whole = TraceMomentAccumulator::new(config.clone())?;
        let fill = whole.shared_fill(field)?;
        // the spectrum of a shared fill first: the flux takes the fill
        let shared_ps = fill
            .as_ref()
            .map(|f| power_spectrum(f.view(), &config.spectrum))
            .transpose()?;
        let (phi, ok, diff) = whole.field_flux(field, fill)?;
        let (ny, nx) = field.dim();
        // the tiles of tile_bounds; blocks: the largest power of two <=
        // tile (Self::accumulate_flux_groups)
        let grid = crate::spectra::TileGrid::new((0, ny, 0, nx), tile);
        let kb = tile.ilog2() as usize;
        let table = grid.map(|g| g.table(ny, nx));
        // a block's centre can lie past the image's edge (a tile larger
        // than the boxes); past the domain, which here is the image,
        // `TileGrid::index` takes the last tile, as its last pixel's
        let tile_of = |y: usize, x: usize| {
            table
                .as_ref()
                .map_or(0, |t| t.at(y.min(ny - 1), x.min(nx - 1)))
        };
        let mut parts = (0..grid.map_or(0, |g| g.len()))
            .map(|_| TraceMomentAccumulator::new(config.clone()))
            .collect::<Result<Vec<_>>>()?;
        // the whole and the tiles side by side: a lone image (the reason
        // for tiles) leaves the other cores idle otherwise
        let (done, valid) = rayon::join(
            || -> Result<()> {
                whole.accumulate_flux(&phi, &ok)?;
                whole.accumulate_sf(field);
                whole.spectrum = Some(match shared_ps {
                    Some(ps) => ps,
                    None => field_power_spectrum(field, &config.spectrum)?,
                });
                Ok(())
            },
            || {
                if parts.is_empty() {
                    return Vec::new();
                }
                let valid = Self::accumulate_flux_groups(&mut parts, &phi, &ok, kb, tile_of);
                Self::accumulate_sf_groups(&mut parts, field, tile_of);
                valid
            },
        );
        done?;
        whole.diff_orders.push(diff);
        whole.planes.push(plane);
        if parts.is_empty() {
            return Ok((whole.clone(), vec![whole]));
        }
        // a tile without a valid flux pixel is left out
        let mut parts: Vec<TraceMomentAccumulator> = parts
            .into_iter()
            .zip(valid)
            .filter(|(_, n)| *n > 0)
            .map(|(p, _)| p)
            .collect();
        for p in parts.iter_mut() {
            p.diff_orders.push(diff);
            p.planes.push(plane);
            p.spectrum.clone_from(&whole.spectrum);
        }
        Ok((whole, parts))
    }

    /// Adds a flux given directly (values `>= 0`; `mask` true = missing),
    /// e.g. a cascade measure or [`crate::synth::fif::fif_flux`]. No
    /// structure functions or spectrum.
    ///
    /// **Errors** on a negative or non-finite unmasked value, an image
    /// smaller than 8x8, or a mask of another shape.
    pub fn add_flux(&mut self, phi: ArrayView2<f64>, mask: Option<ArrayView2<bool>>) -> Result<()> {
        let (ny, nx) = phi.dim();
        if ny < MIN_SIDE || nx < MIN_SIDE {
            return Err(Error::Input(format!(
                "flux {ny}x{nx} too small for trace moments ({MIN_SIDE}x{MIN_SIDE})"
            )));
        }
        if let Some(m) = &mask
            && m.dim() != (ny, nx)
        {
            return Err(Error::Input(format!(
                "mask {}x{} for a flux {ny}x{nx}",
                m.dim().0,
                m.dim().1
            )));
        }
        let mut ok = Array2::from_elem((ny, nx), true);
        if let Some(m) = mask {
            ok.zip_mut_with(&m, |o, &mm| *o = !mm);
        }
        let mut p = phi.to_owned();
        for (v, &o) in p.iter_mut().zip(ok.iter()) {
            if o && !(v.is_finite() && *v >= 0.0) {
                return Err(Error::Input(format!(
                    "flux values must be finite and >= 0, got {v_s}",
                    v_s = crate::error::short(*v)
                )));
            }
            if !o {
                *v = 0.0;
            }
        }
        self.accumulate_flux(&p, &ok)?;
        // no field, no plane: the entry keeps the shares one per field
        self.planes.push(FieldPlane::default());
        Ok(())
    }

    /// Adds the box moments of a flux over the windows of
    /// [`flux::windows`] (every box and pixel).
    ///
    /// **Errors** if no flux pixel is valid (nothing is changed).
    pub(super) fn accumulate_flux(&mut self, phi: &Array2<f64>, ok: &Array2<bool>) -> Result<()> {
        let valid = Self::accumulate_flux_groups(std::slice::from_mut(self), phi, ok, 0, |_, _| 0);
        if valid[0] == 0 {
            return Err(Error::Input("no valid flux pixel".into()));
        }
        Ok(())
    }

    /// Adds the box moments of a flux over the windows of
    /// [`flux::windows`] to `accs`, box by box: a box goes to
    /// `accs[group(y, x)]`, `(y, x)` the centre of its block in the image
    /// (the block of side `2^max(k, kb)` holding a box of side `2^k`:
    /// boxes coarser than a block by their own centre; for the tiles of
    /// [`Self::field_tiles`] blocks of side `2^kb`, `group` the tile). The
    /// tiles of an image so share its boxes out exactly, and a tile is the
    /// same region at every level up to the blocks: windows anchored at other corners put their
    /// boxes across any tile border, and a box assigned by its own corner
    /// or centre made a leave-one-tile-out sample a slightly different
    /// region at each level, a spurious change of slope (on 32 topo-fif
    /// fields of 400², tiles of 128 px: DTM α's jackknife error 1.9 times
    /// the scatter between fields by the box centre, 24 times by its
    /// corner; 0.83 by the block, against 0.5-0.6 on 384² and 512² where
    /// boxes never cross).
    ///
    /// One pass for all groups: the box sums, and the powers of φ the
    /// double trace moments take, are the image's whatever the group, so
    /// they are computed once, and each group's boxes (in raster order, as
    /// one accumulator per tile would visit them: the same sums to the
    /// bit) are gathered from them. Until 2026-11-29 each tile took its own
    /// pass over the whole image (2048^2, 4 tiles: 11.2 s against 5.0 s
    /// now, with the threads below).
    ///
    /// Returns the valid flux pixels of each group; a group without one is
    /// left unchanged.
    pub(super) fn accumulate_flux_groups(
        accs: &mut [TraceMomentAccumulator],
        phi: &Array2<f64>,
        ok: &Array2<bool>,
        kb: usize,
        group: impl Fn(usize, usize) -> usize,
    ) -> Vec<u64> {
        let (ny, nx) = phi.dim();
        let ng = accs.len();
        // the group of box (by, bx) of side 2^k in the window at (y0, x0):
        // that of its block's centre
        let group_of = |y0: usize, x0: usize, k: usize, by: usize, bx: usize| {
            let kk = k.max(kb);
            let half = (1usize << kk) / 2;
            let y = y0 + ((by >> (kk - k)) << kk) + half;
            let x = x0 + ((bx >> (kk - k)) << kk) + half;
            group(y, x)
        };
        let wins = flux::windows(ny, nx);
        // valid flux pixels, once per window that holds them: the weights
        // the finest boxes give them, hence the mean that normalises φ
        let mut valid = vec![0u64; ng];
        for &(y0, x0, wy, wx) in &wins {
            for y in y0..y0 + wy {
                for x in x0..x0 + wx {
                    if ok[[y, x]] {
                        valid[group_of(y0, x0, 0, y - y0, x - x0)] += 1;
                    }
                }
            }
        }
        let live: Vec<bool> = valid.iter().map(|&v| v > 0).collect();
        if !live.contains(&true) {
            return valid;
        }
        let cfg = accs[0].config.clone();
        let rule = cfg.box_weights;
        for &(y0, x0, wy, wx) in &wins {
            let okw = ok.slice(ndarray::s![y0..y0 + wy, x0..x0 + wx]);
            let pyr = flux::Pyramid::new(okw);
            let nl = pyr.levels();
            for (acc, _) in accs.iter_mut().zip(&live).filter(|(_, l)| **l) {
                if acc.box_count.len() < nl {
                    acc.box_count.resize(nl, 0);
                    for v in acc.tm.iter_mut() {
                        v.resize(nl, LogSum::default());
                    }
                    for e in acc.dtm.iter_mut() {
                        for v in e.iter_mut() {
                            v.resize(nl, LogSum::default());
                        }
                    }
                }
            }
            let base: Vec<f64> = phi
                .slice(ndarray::s![y0..y0 + wy, x0..x0 + wx])
                .iter()
                .zip(okw.iter())
                .map(|(v, &o)| if o { *v } else { 0.0 })
                .collect();
            // each level's boxes, group by group, and their weights
            let kept: Vec<Vec<Vec<(usize, u32)>>> = (0..nl)
                .map(|k| pyr.kept_by(k, |by, bx| group_of(y0, x0, k, by, bx), rule, ng))
                .collect();
            let weights: Vec<Vec<Option<Vec<f64>>>> = kept
                .iter()
                .enumerate()
                .map(|(k, groups)| {
                    groups
                        .iter()
                        .zip(accs.iter_mut())
                        .zip(&live)
                        .map(|((boxes, acc), &l)| {
                            let (w, total) = flux::Pyramid::weights_of(boxes, k, rule);
                            if l {
                                acc.box_count[k] += total;
                            }
                            w
                        })
                        .collect()
                })
                .collect();
            // plain trace moments (η = 1)
            let sums = pyr.sums(base.clone());
            for (k, sk) in sums.iter().enumerate() {
                for (g, acc) in accs.iter_mut().enumerate().filter(|(g, _)| live[*g]) {
                    let logs = flux::Pyramid::log_means_of(sk, &kept[k][g]);
                    let lmax = logs.iter().copied().fold(f64::NEG_INFINITY, f64::max);
                    if k == 0 {
                        // pixels: every weight is 1
                        acc.phi_sum.add_powers(&logs, lmax, 1.0);
                    }
                    let w = weights[k][g].as_deref();
                    for (iq, (m, s)) in weighted_power_sums(&logs, w, lmax, &cfg.q)
                        .into_iter()
                        .enumerate()
                    {
                        acc.tm[iq][k].add(m, s);
                    }
                }
            }
            // double trace moments. Where the box sums of φ^η could
            // overflow (a field of 1e99 at η = 3.16 lost K(q, η), and its
            // fit said nothing) or underflow, φ / max φ is raised instead
            // (at most 1 for any η) and the logs of the box means shifted
            // back by η ln max φ; elsewhere φ itself, as before (the
            // ratios throughout cost 5 % of tm's time on a 2048^2 field)
            let p_max = base.iter().copied().fold(0.0, f64::max);
            let n_px = base.len() as f64;
            // ln(φ / max φ) once per pixel, then one exp per pixel and η
            // (a powf per pixel and η was a fifth of tm's time). The
            // error is |η ln φ| ulp (the offset η ln max φ included):
            // 1.5e-14 against powf at max φ = 1, 1e-13 at 1e300 or 1e-310
            // (review, 2026-11-29). Divided, not multiplied by 1 / max:
            // that overflows for a subnormal max, a flux given through the
            // library.
            let ln_rel: Vec<f64> = base
                .iter()
                .map(|&p| {
                    if p > 0.0 {
                        (p / p_max).ln()
                    } else {
                        f64::NEG_INFINITY
                    }
                })
                .collect();
            let ln_max = p_max.ln();
            // the η in two halves side by side: each η's terms are computed
            // alone and added below in η order, so the sums are the same to
            // the bit whatever the thread count (a lone 2048^2 image: 7.8 ->
            // 6.3 s on 2 cores). Two, not one task per η: each holds its
            // own powers and box sums (19 B/px), and 16 at once took 1.7 GB
            // at 2048^2 on 16 threads
            type Terms = Vec<(usize, usize, Option<(f64, f64)>, Vec<(f64, f64)>)>;
            // `sums`: the pyramid's levels, `means` its box means, reused
            // from one η to the next
            let one_eta = |&eta: &f64, (sums, means): &mut (Vec<Vec<f64>>, Vec<f64>)| {
                let top = p_max.powf(eta);
                let scaled = p_max > 0.0 && !(top >= 1e-280 && top * n_px <= 1e280);
                // φ^η itself, or (φ / max φ)^η where φ^η could overflow
                let offset = if scaled { 0.0 } else { eta * ln_max };
                if sums.is_empty() {
                    sums.push(Vec::new());
                }
                sums[0].clear();
                sums[0].extend(ln_rel.iter().map(|&l| (eta * l + offset).exp()));
                let shift = if scaled { eta * ln_max } else { 0.0 };
                pyr.sums_in(sums);
                // the box means as values, not logs: for the orders of
                // the DTM (1.5 by default) no ln or exp per box is left
                // (power_sums_of_values); the logs shift by `shift`
                let mut out = Terms::new();
                for (k, sk) in sums.iter().enumerate() {
                    for g in (0..ng).filter(|&g| live[g]) {
                        flux::Pyramid::means_into(sk, &kept[k][g], means);
                        let pixels = (k == 0).then(|| {
                            let (m, s) = power_sums_of_values(means, &[1.0])[0];
                            (m + shift, s)
                        });
                        let w = weights[k][g].as_deref();
                        let dtm = weighted_power_sums_of_values(means, w, &cfg.dtm_q)
                            .into_iter()
                            .zip(&cfg.dtm_q)
                            .map(|((m, s), &q)| (m + q * shift, s))
                            .collect();
                        out.push((k, g, pixels, dtm));
                    }
                }
                out
            };
            let half = cfg.eta.len().div_ceil(2);
            let run = |etas: &[f64]| {
                let mut scratch = (Vec::new(), Vec::new());
                etas.iter()
                    .map(|e| one_eta(e, &mut scratch))
                    .collect::<Vec<Terms>>()
            };
            let (lo, hi) = rayon::join(|| run(&cfg.eta[..half]), || run(&cfg.eta[half..]));
            let terms = lo.into_iter().chain(hi);
            for (ie, t) in terms.into_iter().enumerate() {
                for (k, g, pixels, dtm) in t {
                    if let Some((m, s)) = pixels {
                        accs[g].eta_sum[ie].add(m, s);
                    }
                    for (iq, (m, s)) in dtm.into_iter().enumerate() {
                        accs[g].dtm[ie][iq][k].add(m, s);
                    }
                }
            }
        }
        for (acc, &n) in accs.iter_mut().zip(&valid).filter(|(_, n)| **n > 0) {
            acc.n_valid += n;
            acc.images += 1;
            acc.max_side = acc.max_side.max(ny.min(nx));
        }
        valid
    }

    /// Structure-function sums of `field`.
    pub(super) fn accumulate_sf(&mut self, field: &Field) {
        Self::accumulate_sf_groups(std::slice::from_mut(self), field, |_, _| 0);
    }

    /// Structure-function sums of `field` into `accs`: an increment goes to
    /// `accs[group(y, x)]`, `(y, x)` its midpoint (rounded down); in raster
    /// order within each group, as one pass per group would take them.
    pub(super) fn accumulate_sf_groups(
        accs: &mut [TraceMomentAccumulator],
        field: &Field,
        group: impl Fn(usize, usize) -> usize,
    ) {
        let (ny, nx) = field.dim();
        let f = &field.data;
        let ok = |y: usize, x: usize| !field.is_masked(y, x);
        let sf_q = accs[0].config.sf_q.clone();
        // one buffer per group for every lag: allocated anew per lag, the
        // 2 ny nx increments (64 MB at 2048^2) were page-faulted in again
        // each time
        let mut incs: Vec<Vec<f64>> = vec![Vec::new(); accs.len()];
        if let [one] = incs.as_mut_slice() {
            one.reserve(2 * ny * nx);
        }
        for j in 0..sf_lags(ny.min(nx)) {
            let l = 1usize << j;
            incs.iter_mut().for_each(Vec::clear);
            for y in 0..ny {
                for x in 0..nx {
                    if !ok(y, x) {
                        continue;
                    }
                    if x + l < nx && ok(y, x + l) {
                        incs[group(y, x + l / 2)].push((f[[y, x + l]] - f[[y, x]]).abs());
                    }
                    if y + l < ny && ok(y + l, x) {
                        incs[group(y + l / 2, x)].push((f[[y + l, x]] - f[[y, x]]).abs());
                    }
                }
            }
            for (acc, incs) in accs.iter_mut().zip(&incs) {
                if acc.sf_count.len() <= j {
                    acc.sf_count.resize(j + 1, 0);
                    for v in acc.sf.iter_mut() {
                        v.resize(j + 1, LogSum::default());
                    }
                }
                acc.sf_count[j] += incs.len() as u64;
                for (iq, (m, s)) in power_sums_of_values(incs, &sf_q).into_iter().enumerate() {
                    acc.sf[iq][j].add(m, s);
                }
            }
        }
    }

    /// Adds another accumulator's sums (annealed ensemble). The sums add
    /// in the order of the merges, so the same images grouped otherwise
    /// may differ in the last bits (alpha by 3e-10 relative, 8 images
    /// against 4 + 4); unlike the partition sums
    /// ([`crate::spectra::PartitionSums::merge`]), which are exact.
    ///
    /// **Errors** if the configurations differ, or either fails [`Self::check`].
    pub fn merge(&mut self, o: &TraceMomentAccumulator) -> Result<()> {
        self.check()?;
        o.check()?;
        let differ = self.config.differences(&o.config);
        if !differ.is_empty() {
            return Err(Error::param(
                "config",
                format!(
                    "cannot merge trace moments accumulated with different settings ({}; \
                     settings stored before 2026-11-29 read as box_weights equal and \
                     spectrum fill mean)",
                    differ.join("; ")
                ),
            ));
        }
        // accumulators saved before the planes were recorded have none: pad
        // them with defaults so that the planes stay one per field, in order
        let own = self.images;
        self.planes
            .resize(own.max(self.planes.len()), FieldPlane::default());
        self.images += o.images;
        self.max_side = self.max_side.max(o.max_side);
        self.n_valid += o.n_valid;
        self.phi_sum.merge(&o.phi_sum);
        for (a, b) in self.eta_sum.iter_mut().zip(&o.eta_sum) {
            a.merge(b);
        }
        let nl = self.box_count.len().max(o.box_count.len());
        self.box_count.resize(nl, 0);
        for (k, c) in o.box_count.iter().enumerate() {
            self.box_count[k] += c;
        }
        let merge_vec = |a: &mut Vec<LogSum>, b: &Vec<LogSum>| {
            if a.len() < b.len() {
                a.resize(b.len(), LogSum::default());
            }
            for (x, y) in a.iter_mut().zip(b) {
                x.merge(y);
            }
        };
        for (a, b) in self.tm.iter_mut().zip(&o.tm) {
            merge_vec(a, b);
            a.resize(nl, LogSum::default());
        }
        for (ea, eb) in self.dtm.iter_mut().zip(&o.dtm) {
            for (a, b) in ea.iter_mut().zip(eb) {
                merge_vec(a, b);
                a.resize(nl, LogSum::default());
            }
        }
        let nj = self.sf_count.len().max(o.sf_count.len());
        self.sf_count.resize(nj, 0);
        for (j, c) in o.sf_count.iter().enumerate() {
            self.sf_count[j] += c;
        }
        for (a, b) in self.sf.iter_mut().zip(&o.sf) {
            merge_vec(a, b);
            a.resize(nj, LogSum::default());
        }
        match (&mut self.spectrum, &o.spectrum) {
            (Some(a), Some(b)) => a.merge(b)?,
            (None, Some(b)) => self.spectrum = Some(b.clone()),
            _ => {}
        }
        self.diff_orders.extend_from_slice(&o.diff_orders);
        self.planes.extend_from_slice(&o.planes);
        self.planes.resize(
            (own + o.images).max(self.planes.len()),
            FieldPlane::default(),
        );
        Ok(())
    }

    /// `log2 λ` of each level (`log2 L - k`).
    pub fn log2_lambda(&self) -> Vec<f64> {
        let kmax = self.box_count.len().saturating_sub(1);
        (0..self.box_count.len())
            .map(|k| (kmax - k) as f64)
            .collect()
    }

    /// Normalised `log2 <φ_λ^q>` per level, from sums `s`, for the flux
    /// normalised by the ensemble mean whose natural log is `lnm`.
    pub(super) fn log2_moments(&self, s: &[LogSum], q: f64, lnm: f64) -> Vec<f64> {
        (0..self.box_count.len())
            .map(|k| {
                let c = self.box_count[k];
                if c == 0 || k >= s.len() {
                    return f64::NAN;
                }
                // the sum of the weights: valid pixels / 4^k (exact) with
                // count weights, whose whole boxes weigh 1
                let w = match self.config.box_weights {
                    BoxWeights::Equal => c as f64,
                    BoxWeights::Count => c as f64 / (1u64 << (2 * k)) as f64,
                };
                (s[k].ln() - w.ln() - q * lnm) / std::f64::consts::LN_2
            })
            .collect()
    }
}
