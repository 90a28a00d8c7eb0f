//! The image type that flows through the pipeline: values plus a mask of
//! missing pixels (NaN or nodata in the file).
//!
//! # Example
//!
//! ```
//! use ndarray::Array2;
//! use wtmm::Field;
//! # fn main() -> wtmm::Result<()> {
//! let mut a =
//!     Array2::from_shape_fn((64, 64), |(y, x)| (0.3 * x as f64).sin() + (0.2 * y as f64).cos());
//! a[[10, 20]] = f64::NAN;
//! let f = Field::new(a); // non-finite values are masked
//! assert_eq!(f.missing_count(), 1);
//! // a mask of its own (true = missing), e.g. a sea; the NaN stays missing
//! let sea = Array2::from_shape_fn((64, 64), |(y, _)| y < 4);
//! let g = Field::with_mask(f.data.clone(), sea)?;
//! assert_eq!(g.missing_count(), 4 * 64 + 1);
//! // holes filled harmonically and counted as data (`--fill-holes`)
//! let filled = Field::new(f.filled_harmonic()?);
//! assert_eq!(filled.missing_count(), 0);
//! // a mask of the wrong shape is refused
//! assert!(Field::with_mask(f.data.clone(), Array2::from_elem((8, 8), false)).is_err());
//! # Ok(())
//! # }
//! ```

use ndarray::{Array2, Axis};

use crate::error::{Error, Result};

/// A real 2D field `f[y][x]` with an optional mask (`true` = missing).
///
/// The fields are public; [`Field::new`] and [`Field::with_mask`] keep
/// them consistent. A field assembled by hand with a mask of another
/// shape is refused by the analyses ([`Field::check`]), but the `Field`
/// methods assume the shapes agree: **Panics** (or, for counts, wrong
/// answers) there.
#[derive(Clone, Debug, PartialEq)]
pub struct Field {
    /// Values; masked pixels hold NaN.
    pub data: Array2<f64>,
    /// `Some(m)` when at least one pixel is missing; `m[[y, x]] == true` there.
    pub mask: Option<Array2<bool>>,
}

impl Field {
    /// Wraps an array, masking every non-finite value. The values are kept
    /// in row-major order (an array of another layout, e.g. a transposed
    /// view made owned, is copied once).
    pub fn new(data: Array2<f64>) -> Self {
        let mut data = standard(data);
        let mask = data.map(|v| !v.is_finite());
        let any = mask.iter().any(|&m| m);
        if any {
            data.zip_mut_with(&mask, |v, &m| {
                if m {
                    *v = f64::NAN
                }
            });
        }
        Field {
            data,
            mask: any.then_some(mask),
        }
    }

    /// Wraps an array with an explicit mask (`true` = missing); masked values become NaN.
    ///
    /// **Errors** if `data` and `mask` differ in shape (a mask read from
    /// another file, say).
    pub fn with_mask(data: Array2<f64>, mask: Array2<bool>) -> crate::Result<Self> {
        let (mut data, mut mask) = (standard(data), standard(mask));
        if data.dim() != mask.dim() {
            return Err(crate::Error::param(
                "mask",
                format!(
                    "the mask is {}x{} but the data are {}x{}",
                    mask.dim().0,
                    mask.dim().1,
                    data.dim().0,
                    data.dim().1
                ),
            ));
        }
        mask.zip_mut_with(&data, |m, v| *m |= !v.is_finite());
        data.zip_mut_with(&mask, |v, &m| {
            if m {
                *v = f64::NAN
            }
        });
        let any = mask.iter().any(|&m| m);
        Ok(Field {
            data,
            mask: any.then_some(mask),
        })
    }

    /// **Errors** if the mask differs from the data in shape: the fields
    /// are public, so a `Field` can be built without [`Self::with_mask`]'s
    /// check; the analyses call this before reading the mask.
    pub fn check(&self) -> Result<()> {
        match &self.mask {
            Some(m) if m.dim() != self.data.dim() => Err(Error::param(
                "mask",
                format!(
                    "the mask is {}x{} but the data are {}x{}",
                    m.dim().0,
                    m.dim().1,
                    self.data.dim().0,
                    self.data.dim().1
                ),
            )),
            _ => Ok(()),
        }
    }

    /// `(ny, nx)`.
    pub fn dim(&self) -> (usize, usize) {
        self.data.dim()
    }

    /// Masks every valid pixel equal to `value` (`-0.0` equals `0.0`): a
    /// nodata value the file does not declare, such as a sea or a fill set
    /// to 0, or -9999. Returns how many pixels it masked. For a file
    /// stored in 32- or 16-bit floats, give the value as stored
    /// ([`crate::io::as_stored`]).
    pub fn mask_value(&mut self, value: f64) -> usize {
        let mut n = 0;
        let mut mask = self
            .mask
            .take()
            .unwrap_or_else(|| Array2::from_elem(self.data.dim(), false));
        ndarray::Zip::from(&mut self.data)
            .and(&mut mask)
            .for_each(|v, m| {
                if !*m && *v == value {
                    *v = f64::NAN;
                    *m = true;
                    n += 1;
                }
            });
        self.mask = mask.iter().any(|&m| m).then_some(mask);
        n
    }

    /// Number of valid (unmasked) pixels.
    pub fn valid_count(&self) -> usize {
        match &self.mask {
            None => self.data.len(),
            Some(m) => m.iter().filter(|&&x| !x).count(),
        }
    }

    /// Number of missing (masked) pixels.
    pub fn missing_count(&self) -> usize {
        self.data.len() - self.valid_count()
    }

    /// The number of pixels of the largest hole (4-connected masked
    /// pixels; 0 without a mask).
    pub fn largest_hole(&self) -> usize {
        self.hole_sizes(false).into_iter().max().unwrap_or(0)
    }

    /// The pixels of each hole (4-connected masked pixels; on a `torus` a
    /// hole across a border is one with its other side, as
    /// [`Self::filled_harmonic_torus`] fills it), in no particular order;
    /// empty without a mask.
    pub fn hole_sizes(&self, torus: bool) -> Vec<usize> {
        self.mask.as_ref().map_or(Vec::new(), |m| {
            let mut sizes = hole_labels(m, torus).1;
            // label 0 is the valid pixels' (size 0)
            sizes.remove(0);
            sizes
        })
    }

    /// True if pixel `(y, x)` is masked.
    pub fn is_masked(&self, y: usize, x: usize) -> bool {
        self.mask.as_ref().is_some_and(|m| m[[y, x]])
    }

    /// The values with masked pixels filled by a harmonic interpolation of
    /// their surroundings (the solution of Laplace's equation inside each
    /// hole with the valid pixels around it as boundary values), for
    /// filters with long tails: a fractional derivative sees a mean-filled
    /// hole as a step along its rim, whose response decays only like a
    /// power of the distance and so reaches far into the valid data (the
    /// trace moments' flux uses it, and the power spectrum by default,
    /// [`crate::stats::powspec::HoleFill`]). The harmonic fill is continuous at the rim and
    /// smooth inside; a hole away from the image border is filled exactly
    /// where the field is a plane, and where a hole meets the border the
    /// fill has zero gradient across it (nothing is known beyond).
    ///
    /// Written here because no maintained crate does masked Laplace
    /// inpainting on an ndarray: a pyramid of 2x2 means of the valid pixels
    /// is filled coarsest first, each level's fill the first guess of the
    /// next finer one and then relaxed there (successive over-relaxation on
    /// the masked pixels alone, until the largest update falls below 1e-9
    /// of the data's range or 50 sweeps), so large holes cost a few sweeps
    /// per level, not a number growing with their size: a plane is
    /// restored to 5e-8 of its range in a 15 x 25 hole with scattered
    /// pixels, 1e-4 in a disc over 5 % of a 1024^2 image (55 ms) and 4e-4
    /// in one over half of it (0.43 s; 1.7 s at 2048^2).
    ///
    /// **Errors** if no pixel is valid.
    pub fn filled_harmonic(&self) -> Result<Array2<f64>> {
        self.filled_harmonic_on(false)
    }

    /// [`Self::filled_harmonic`] on a torus: the last row's neighbour is the
    /// first, and so for the columns, so a hole across the border is filled
    /// from both sides, continuously across it (a periodic field's
    /// fractional derivative and untapered spectrum see it so). Without the
    /// wrap such a hole has a zero gradient at the border on each side and
    /// a step across it.
    ///
    /// **Errors** if no pixel is valid.
    pub fn filled_harmonic_torus(&self) -> Result<Array2<f64>> {
        self.filled_harmonic_on(true)
    }

    /// [`Self::filled_harmonic_torus`] on a `torus`, else
    /// [`Self::filled_harmonic`].
    ///
    /// **Errors** if no pixel is valid.
    pub fn filled_harmonic_on(&self, torus: bool) -> Result<Array2<f64>> {
        let Some(mask) = &self.mask else {
            return Ok(self.data.clone());
        };
        if mask.iter().all(|&m| m) {
            return Err(Error::Input(
                "every pixel is missing (NaN or nodata)".into(),
            ));
        }
        let span = self
            .range()
            .map(|(lo, hi)| hi - lo)
            .filter(|s| *s > 0.0)
            .unwrap_or(1.0);
        Ok(harmonic_fill(&self.data, mask, 1e-9 * span, torus))
    }

    /// The values with masked pixels replaced by the mean of the valid ones,
    /// ready for the FFT. (The maxima code later drops any WTMM whose wavelet
    /// support, radius `R a`, touches a masked pixel; what the Gaussian's
    /// tail carries beyond it is negligible: a holed fBm ensemble gives the
    /// τ(q) of the unholed one counted on the same domain within 0.003,
    /// `tests/spectra.rs`.)
    ///
    /// Borrowed when nothing is missing (a copy of a large DEM is 8 B/px
    /// for nothing).
    ///
    /// **Errors** if no pixel is valid, or on a mask of another shape
    /// ([`Self::check`]).
    pub fn filled(&self) -> Result<std::borrow::Cow<'_, Array2<f64>>> {
        self.check()?;
        let Some(mask) = &self.mask else {
            return Ok(std::borrow::Cow::Borrowed(&self.data));
        };
        let (mut sum, mut n) = (0.0, 0usize);
        for (v, &m) in self.data.iter().zip(mask.iter()) {
            if !m {
                sum += v;
                n += 1;
            }
        }
        if n == 0 {
            return Err(Error::Input(
                "every pixel is missing (NaN or nodata)".into(),
            ));
        }
        let mean = sum / n as f64;
        let mut out = self.data.clone();
        out.zip_mut_with(mask, |v, &m| {
            if m {
                *v = mean
            }
        });
        Ok(std::borrow::Cow::Owned(out))
    }

    /// The least-squares plane `c0 + cx x + cy y` through the valid pixels
    /// (`x` the column, `y` the row index), or `None` when they do not fix
    /// one (fewer than 3, or all on one line).
    pub fn fit_plane(&self) -> Option<Plane> {
        self.plane_fit().map(|(p, _)| p)
    }

    /// The fraction of the valid pixels' variance that
    /// [`fit_plane`](Self::fit_plane)'s plane explains (its R², in
    /// [0, 1]); `None` without a plane or for a constant field.
    pub fn plane_share(&self) -> Option<f64> {
        self.plane_fit().and_then(|(_, r)| r)
    }

    /// The plane and its R² (`None` for a constant field, a NaN from
    /// values too large to square, or a mask of another shape).
    fn plane_fit(&self) -> Option<(Plane, Option<f64>)> {
        self.check().ok()?;
        // centred on the valid pixels' centroid and mean, the constant
        // decouples and the slopes solve a 2x2 system; the sums run over
        // f - mean, so a DEM's large offset costs no precision
        let (ny, nx) = self.dim();
        let valid = |y: usize, x: usize| !self.is_masked(y, x);
        let (mut n, mut sx, mut sy, mut sf) = (0.0, 0.0, 0.0, 0.0);
        for y in 0..ny {
            for x in 0..nx {
                if valid(y, x) {
                    n += 1.0;
                    sx += x as f64;
                    sy += y as f64;
                    sf += self.data[[y, x]];
                }
            }
        }
        if n < 3.0 {
            return None;
        }
        let (xm, ym, fm) = (sx / n, sy / n, sf / n);
        let (mut xx, mut xy, mut yy, mut fx, mut fy, mut ff) = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
        for y in 0..ny {
            let dy = y as f64 - ym;
            for x in 0..nx {
                if valid(y, x) {
                    let (dx, df) = (x as f64 - xm, self.data[[y, x]] - fm);
                    xx += dx * dx;
                    xy += dx * dy;
                    yy += dy * dy;
                    fx += df * dx;
                    fy += df * dy;
                    ff += df * df;
                }
            }
        }
        let det = xx * yy - xy * xy;
        if !(det > 1e-9 * xx * yy) {
            return None;
        }
        let cx = (fx * yy - fy * xy) / det;
        let cy = (fy * xx - fx * xy) / det;
        // the explained sum of squares of a least-squares fit is b'X'y
        // (checked before `clamp`, which would pass a NaN on; the clamp
        // trims rounding only: b'X'y / y'y lies in [0, 1])
        let r = (cx * fx + cy * fy) / ff;
        let share = (ff > 0.0 && r.is_finite()).then(|| r.clamp(0.0, 1.0));
        Some((
            Plane {
                c0: fm - cx * xm - cy * ym,
                cx,
                cy,
            },
            share,
        ))
    }

    /// What a wavelet transform is computed on: the values with missing
    /// pixels filled ([`filled`](Self::filled)) and, with
    /// [`Trend::Plane`], less the least-squares plane of the valid pixels
    /// (removed before the fill: a mean fill of the tilted image would be
    /// a step at the holes' rims).
    ///
    /// **Errors** if no pixel is valid.
    pub fn transform_input(&self, trend: Trend) -> Result<std::borrow::Cow<'_, Array2<f64>>> {
        match self.detrended(trend)? {
            std::borrow::Cow::Borrowed(f) => f.filled(),
            std::borrow::Cow::Owned(f) if f.mask.is_none() => Ok(std::borrow::Cow::Owned(f.data)),
            std::borrow::Cow::Owned(f) => Ok(std::borrow::Cow::Owned(f.filled()?.into_owned())),
        }
    }

    /// The field less its `trend` (the least-squares plane of the valid
    /// pixels with [`Trend::Plane`]; missing pixels stay missing), or the
    /// field itself when nothing is removed ([`Trend::None`], or no plane
    /// fits).
    ///
    /// **Errors** when the plane explains all but [`PLANE_ONLY`] of the
    /// variance, whatever the trend: removed, what is left is the rounding
    /// of the values, which the analyses would read as a surface; kept, the
    /// gauss wavelet reads the plane as one vector at every point and the
    /// mexican as nothing, and the flux of trace moments is constant (a
    /// plane once read D(q) = 6.1 and h = 1 at every q, and a DTM alpha).
    pub fn detrended(&self, trend: Trend) -> Result<std::borrow::Cow<'_, Field>> {
        self.check()?;
        let Some((p, share)) = self.plane_fit() else {
            return Ok(std::borrow::Cow::Borrowed(self));
        };
        if share.is_some_and(|r| r >= 1.0 - PLANE_ONLY) {
            return Err(Error::Input(format!(
                "the image is a plane: its least-squares plane leaves less than {PLANE_ONLY:e} \
                 of its variance unexplained (a residue below 1e-6 of its standard deviation), \
                 so {}",
                match trend {
                    Trend::Plane =>
                        "nothing but rounding would be analysed once it is removed \
                                     (--detrend plane)",
                    Trend::None =>
                        "there is no rough surface to analyse (a wavelet reads a \
                                    plane as the same vector at every point, or as zero; its \
                                    flux is constant)",
                }
            )));
        }
        if trend == Trend::None {
            return Ok(std::borrow::Cow::Borrowed(self));
        }
        let mut f = self.clone();
        p.subtract(&mut f.data);
        Ok(std::borrow::Cow::Owned(f))
    }

    /// [`amplitude_problem`] of the valid pixels.
    pub fn amplitude_problem(&self) -> Option<String> {
        amplitude_problem(self.data.iter())
    }

    /// Min and max over valid pixels, `None` if every pixel is masked.
    pub fn range(&self) -> Option<(f64, f64)> {
        finite_range(self.data.iter())
    }

    /// How wide, in pixels, the terraces of a quantised image are:
    /// `1 / (1 - f)`, `f` the fraction of the pairs of neighbouring valid
    /// pixels that are equal, along the rows and along the columns, the
    /// smaller of the two (the steps' spacing across the terraces: a ramp
    /// quantised along x has no step down the columns; an axis without
    /// pairs, as the columns of a one-row image, is left out).
    /// 1 for a surface whose neighbours differ; inside terraces `w` px
    /// wide, `(w - 1) / w` of the pairs are equal. Pairs, not runs: a
    /// missing pixel cuts a run in two but leaves the share of equal pairs
    /// as it was (terraces 6.3 px wide with 5 % / 20 % of the pixels
    /// missing at random: mean runs of 4.95 / 3.05 px, 6.32 / 6.33 from
    /// the pairs). Pairs touching the [`flat_value`](Self::flat_value) are
    /// left out like missing ones: a sea set to 0 over half a continuous
    /// DEM would otherwise read as terraces 2 px wide. `None` when no pair
    /// counts, or when every pair that counts is equal (no step seen).
    ///
    /// A wavelet narrower than the terraces sees the steps between them
    /// (h = 0 along their edges) rather than the surface
    /// ([`PartitionSums::spectra`](crate::spectra::PartitionSums::spectra)
    /// warns).
    pub fn terrace_width(&self) -> Option<f64> {
        self.terraces().0
    }

    /// [`terrace_width`](Self::terrace_width) and
    /// [`flat_value`](Self::flat_value) together, the flat value found
    /// once (the width needs it).
    pub fn terraces(&self) -> (Option<f64>, Option<(f64, f64)>) {
        let flat = self.flat_value();
        (self.terrace_width_without(flat.map(|(v, _)| v)), flat)
    }

    /// Every pair of neighbouring pixels along `axis` (`Axis(1)`: along
    /// the rows), missing ones included.
    fn neighbour_pairs(&self, axis: Axis) -> impl Iterator<Item = (f64, f64)> + '_ {
        self.data
            .lanes(axis)
            .into_iter()
            .flat_map(|lane| lane.into_iter().zip(lane.into_iter().skip(1)))
            .map(|(a, b)| (*a, *b))
    }

    /// The pairs of neighbouring valid pixels along `axis`, those holding
    /// `skip` left out, and how many of them are equal.
    pub(crate) fn equal_pairs(&self, axis: Axis, skip: Option<f64>) -> (usize, usize) {
        let counts = |v: f64| v.is_finite() && Some(v) != skip;
        self.neighbour_pairs(axis)
            .filter(|&(a, b)| counts(a) && counts(b))
            .fold((0, 0), |(n, e), (a, b)| (n + 1, e + usize::from(a == b)))
    }

    /// The steps of the image (pairs of unequal valid neighbours, along
    /// rows and columns), each as whether it lies on the rim of `value`
    /// (one of its pixels holds it) and its height.
    fn steps_around(&self, value: f64) -> impl Iterator<Item = (bool, f64)> + '_ {
        [Axis(0), Axis(1)]
            .into_iter()
            .flat_map(|axis| self.neighbour_pairs(axis))
            .filter(|&(a, b)| a.is_finite() && b.is_finite() && a != b)
            .map(move |(a, b)| (a == value || b == value, (a - b).abs()))
    }

    /// How far a flat area's level lies from the surface around it: the
    /// median step across its rim (pairs of neighbours, one holding
    /// `value`, the other valid and not) over the median step of the rest
    /// (pairs of unequal valid neighbours, neither holding `value`). About 1
    /// for a sea at the coast's level, large for a fill far off the surface
    /// (0 below a DEM's land, an undeclared -9999). `None` without a rim or
    /// a step.
    pub fn rim_contrast(&self, value: f64) -> Option<f64> {
        let (mut rim, mut rest) = (Vec::new(), Vec::new());
        for (on_rim, h) in self.steps_around(value) {
            if on_rim { &mut rim } else { &mut rest }.push(h);
        }
        let median = |v: &mut Vec<f64>| -> Option<f64> {
            if v.is_empty() {
                return None;
            }
            let k = v.len() / 2;
            Some(*v.select_nth_unstable_by(k, f64::total_cmp).1)
        };
        Some(median(&mut rim)? / median(&mut rest)?)
    }

    /// The terrace width with the pixels holding `flat` left out.
    fn terrace_width_without(&self, flat: Option<f64>) -> Option<f64> {
        // 1 / (1 - f) = pairs / (pairs - equal)
        let width = |axis: Axis| -> Option<f64> {
            let (pairs, equal) = self.equal_pairs(axis, flat);
            (pairs > 0).then(|| pairs as f64 / (pairs - equal) as f64)
        };
        // lanes along Axis(1) are the rows; an axis without pairs is left out
        let w = [width(Axis(1)), width(Axis(0))]
            .into_iter()
            .flatten()
            .reduce(f64::min)?;
        w.is_finite().then_some(w)
    }

    /// The one value that fills flat areas of the image (a sea or a lake
    /// at one level, a fill, a nodata value the file does not declare),
    /// with its share of the valid pixels: the value held by more than
    /// half of the pixels that equal a horizontal neighbour, and that
    /// borders fewer than half of the image's steps (pairs of unequal
    /// valid neighbours, along rows and columns). `None` when no value
    /// does: a continuous surface has next to no equal neighbours, a
    /// finely quantised one spreads them over its levels, and the one
    /// level that fills most of a coarsely quantised image (an fBm rounded
    /// to 3 levels: 86 % of its pixels) borders nearly every step, so it
    /// is a terrace, not a flat area, where a sea's rim is a small share
    /// of the steps of the surface around it.
    ///
    /// The wavelet sees the rim of a flat area as a step or a kink of the
    /// surface ([`PartitionSums::spectra`](crate::spectra::PartitionSums::spectra)
    /// warns when it holds more than [`FLAT_SHARE_WARN`] of the pixels).
    pub fn flat_value(&self) -> Option<(f64, f64)> {
        // pixels in horizontal runs of 2 or more, by value (one map
        // update per run; -0.0 counted as 0.0)
        let mut by_value: std::collections::HashMap<u64, usize> = Default::default();
        let mut in_runs = 0usize;
        for row in self.data.rows() {
            let mut run = (f64::NAN, 0usize);
            let mut close = |(v, n): (f64, usize)| {
                if n >= 2 {
                    *by_value.entry((v + 0.0).to_bits()).or_default() += n;
                    in_runs += n;
                }
            };
            for &v in row.iter() {
                if v.is_finite() && v == run.0 {
                    run.1 += 1;
                } else {
                    close(run);
                    run = (v, usize::from(v.is_finite()));
                }
            }
            close(run);
        }
        let (bits, n) = by_value.into_iter().max_by_key(|&(b, n)| (n, b))?;
        if 2 * n <= in_runs {
            return None;
        }
        // the share counts every pixel of the value, lone ones too (a
        // coast's pixels between land on either side)
        let value = f64::from_bits(bits);
        // steps, and those on the value's rim
        let (steps, rim) = self
            .steps_around(value)
            .fold((0usize, 0usize), |(n, r), (on_rim, _)| {
                (n + 1, r + usize::from(on_rim))
            });
        if 2 * rim > steps {
            return None;
        }
        let all = self.data.iter().filter(|&&v| v == value).count();
        Some((value, all as f64 / self.valid_count() as f64))
    }
}

/// [`Field::rim_contrast`] above which `spectrum` warns of a flat area: on the
/// Levi Fell DEM (400^2; median step of its upper 70 %, 0.79 m) with its
/// lowest 30 % set below the coast by 3 / 10 / 30 / 100 / 196 m
/// (contrast 4.4 / 13 / 38 / 127 / 248), beta moved from 4.266 by
/// -0.003 / -0.036 / -0.26 / -0.98 / -1.31 (its error 0.08); at the
/// coast's level (contrast 0.6) it did not move.
pub const CLIFF_CONTRAST: f64 = 20.0;

/// A plane `c0 + cx x + cy y` over the pixel grid (`x` the column, `y` the
/// row index, in pixels): an image's least-squares trend
/// ([`Field::fit_plane`]).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Plane {
    /// Value at pixel (0, 0).
    pub c0: f64,
    /// Change per pixel along x (the columns).
    pub cx: f64,
    /// Change per pixel along y (the rows).
    pub cy: f64,
}

impl Plane {
    /// The gradient's magnitude, per pixel: what the gauss wavelet reads
    /// as `T = a (cx, cy)` at every point and scale (`cwt` module docs).
    pub fn slope(&self) -> f64 {
        (self.cx * self.cx + self.cy * self.cy).sqrt()
    }

    /// The plane's value at pixel `(y, x)`.
    pub fn at(&self, y: usize, x: usize) -> f64 {
        self.c0 + self.cx * x as f64 + self.cy * y as f64
    }

    /// Subtracts the plane from `img` (NaN stays NaN).
    pub fn subtract(&self, img: &mut Array2<f64>) {
        for ((y, x), v) in img.indexed_iter_mut() {
            *v -= self.at(y, x);
        }
    }
}

/// Share of an image's valid pixels in one flat value ([`Field::flat_value`])
/// above which the analyses warn: a constant sea over 30 % of the Levi
/// Fell DEM (400^2) moved h(0) from 0.75 (the sea given as missing) to
/// 0.62, over 50 % from 0.90 to 0.35 (README, Conventions).
pub const FLAT_SHARE_WARN: f64 = 0.1;

/// Unexplained share of the variance below which an image is taken for a
/// plane ([`Field::detrended`]; a residue of rms 1e-6 of the image's
/// standard deviation sits on it): far above the 1e-15 to which the share is
/// computed (an exact plane read 1 - 3.4e-15), and above the residue of a
/// plane stored in float32, which is refused too (rounding of 6e-8 of the
/// values: 2e-13 of the variance of a plane spanning a quarter of their
/// magnitude).
pub const PLANE_ONLY: f64 = 1e-12;

/// What is removed from an image before the analysis
/// ([`crate::skeleton::AnalysisConfig::detrend`],
/// [`crate::tracemoments::TraceMomentConfig::detrend`]). A plane of slope
/// `c = (cx, cy)` is added by the gauss wavelet (one vanishing moment) to
/// the transform as the vector `a c` at every point, which grows faster
/// with the scale than any rough surface's modulus and biases the
/// exponents (the mexican wavelet, three, is blind to it); it adds `c l`
/// to the increments at lag `l` of the trace moments' structure functions.
/// (The variants' docs are the command line's help: they say what is
/// removed, each command's option says why.)
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum Trend {
    /// Nothing (the methods as published).
    #[default]
    None,
    /// The least-squares plane through the valid pixels (a regional
    /// slope); missing pixels stay missing.
    Plane,
}

/// Largest magnitude of a value, and smallest non-zero spread (max - min),
/// that the transforms accept. The moduli are `sqrt(T1^2 + T2^2)` and the
/// power spectrum sums `|f̂|^2` with `f̂` up to `N^2` times the values: at
/// 1e100 (or a spread of 1e-100) and beyond, squares overflow (underflow)
/// for any image a machine holds. The exponents do not depend on a
/// constant factor, so such data only need rescaling.
pub const AMPLITUDE_LIMIT: f64 = 1e100;

/// Why finite `values` cannot be transformed in f64 (see
/// [`AMPLITUDE_LIMIT`]), or `None`. A constant field passes (the commands
/// report it as constant).
pub fn amplitude_problem<'a>(values: impl IntoIterator<Item = &'a f64>) -> Option<String> {
    let (lo, hi) = finite_range(values)?;
    let big = lo.abs().max(hi.abs());
    let spread = hi - lo;
    if big > AMPLITUDE_LIMIT || spread > AMPLITUDE_LIMIT {
        Some(format!(
            "values up to {big:.3e} in magnitude (range {lo:.3e} to {hi:.3e}): beyond \
             {AMPLITUDE_LIMIT:.0e} the squared wavelet moduli and spectra overflow; rescale \
             the image (a constant factor leaves every exponent unchanged)"
        ))
    } else if spread > 0.0 && spread < 1.0 / AMPLITUDE_LIMIT {
        Some(format!(
            "values vary by only {spread:.3e} (range {lo:.3e} to {hi:.3e}): below {:.0e} the \
             squared wavelet moduli and spectra underflow; rescale the image (a constant \
             factor leaves every exponent unchanged)",
            1.0 / AMPLITUDE_LIMIT
        ))
    } else {
        None
    }
}

/// `a` in row-major (standard) layout, copied only if it is not: the
/// analyses and transforms read rows as slices.
pub(crate) fn standard<T: Clone>(a: Array2<T>) -> Array2<T> {
    if a.is_standard_layout() {
        a
    } else {
        a.as_standard_layout().into_owned()
    }
}

/// The smallest and largest finite values (`None` if there are none).
pub fn finite_range<'a>(values: impl IntoIterator<Item = &'a f64>) -> Option<(f64, f64)> {
    let mut it = values.into_iter().filter(|v| v.is_finite());
    let first = *it.next()?;
    Some(it.fold((first, first), |(lo, hi), &v| (lo.min(v), hi.max(v))))
}

/// [`Field::filled_harmonic`] at one level of the pyramid: the masked
/// pixels start from the filled 2x2-mean image one level coarser, then are
/// relaxed to `tol`; valid pixels keep their values. `wrap`: on a torus
/// (the coarse levels of an odd side wrap unevenly, but they only give the
/// first guess; the finest level's relaxation wraps exactly).
fn harmonic_fill(data: &Array2<f64>, mask: &Array2<bool>, tol: f64, wrap: bool) -> Array2<f64> {
    let (ny, nx) = data.dim();
    let mut out = data.clone();
    if !mask.iter().any(|&m| m) {
        return out;
    }
    let (cy, cx) = (ny.div_ceil(2), nx.div_ceil(2));
    let mut sum = Array2::<f64>::zeros((cy, cx));
    let mut cnt = Array2::<u32>::zeros((cy, cx));
    for ((y, x), &v) in data.indexed_iter() {
        if !mask[[y, x]] {
            sum[[y / 2, x / 2]] += v;
            cnt[[y / 2, x / 2]] += 1;
        }
    }
    let coarse_mask = cnt.map(|&c| c == 0);
    let coarse = sum / cnt.map(|&c| c.max(1) as f64);
    let filled = if ny == 1 && nx == 1 {
        coarse // a single valid pixel: nothing is masked at this level
    } else {
        harmonic_fill(&coarse, &coarse_mask, tol, wrap)
    };
    // bilinear prolongation: piecewise-constant blocks would leave steps
    // for the relaxation to smooth
    let at = |i: usize, n: usize| -> (usize, usize, f64) {
        let c = (i as f64 + 0.5) / 2.0 - 0.5;
        if wrap {
            let lo = c.floor();
            let l = (lo as isize).rem_euclid(n as isize) as usize;
            return (l, (l + 1) % n, c - lo);
        }
        let c = c.clamp(0.0, (n - 1) as f64);
        let lo = c.floor() as usize;
        (lo, (lo + 1).min(n - 1), c - lo as f64)
    };
    for ((y, x), v) in out.indexed_iter_mut() {
        if mask[[y, x]] {
            let (y0, y1, wy) = at(y, cy);
            let (x0, x1, wx) = at(x, cx);
            let top = filled[[y0, x0]] * (1.0 - wx) + filled[[y0, x1]] * wx;
            let bottom = filled[[y1, x0]] * (1.0 - wx) + filled[[y1, x1]] * wx;
            *v = top * (1.0 - wy) + bottom * wy;
        }
    }
    relax(&mut out, mask, tol, wrap);
    out
}

/// Successive over-relaxation of Laplace's equation on the masked pixels
/// (4 neighbours; at the image border the missing neighbours are left out,
/// a zero-gradient edge, or wrapped with `wrap`) until the largest update
/// is below `tol` or 50 sweeps have run (the level below gave a smooth
/// first guess).
fn relax(out: &mut Array2<f64>, mask: &Array2<bool>, tol: f64, wrap: bool) {
    let (ny, nx) = out.dim();
    // the optimal factor for a square of side n is 2 / (1 + sin(pi / n)),
    // per hole: one factor for all holes, from their total count, left a
    // lone pixel (whose error is multiplied by 1 - omega each sweep) 26 %
    // off its solution after 50 sweeps with 5 % of 1024^2 missing as
    // isolated pixels (review 2026-11-29); omega = 1 solves it in one
    let (labels, sizes) = hole_labels(mask, wrap);
    let holes: Vec<(usize, usize, f64)> = labels
        .indexed_iter()
        .filter(|(_, l)| **l > 0)
        .map(|((y, x), &l)| {
            let side = (sizes[l] as f64).sqrt();
            (
                y,
                x,
                2.0 / (1.0 + (std::f64::consts::PI / (side + 1.0)).sin()),
            )
        })
        .collect();
    for _ in 0..50 {
        let mut worst = 0.0f64;
        for &(y, x, omega) in &holes {
            let (mut s, mut n) = (0.0, 0.0);
            if wrap {
                // (a side of 1 or 2 px counts a neighbour twice: still a
                // mean of the values around)
                s = out[[(y + ny - 1) % ny, x]]
                    + out[[(y + 1) % ny, x]]
                    + out[[y, (x + nx - 1) % nx]]
                    + out[[y, (x + 1) % nx]];
                n = 4.0;
            } else {
                if y > 0 {
                    s += out[[y - 1, x]];
                    n += 1.0;
                }
                if y + 1 < ny {
                    s += out[[y + 1, x]];
                    n += 1.0;
                }
                if x > 0 {
                    s += out[[y, x - 1]];
                    n += 1.0;
                }
                if x + 1 < nx {
                    s += out[[y, x + 1]];
                    n += 1.0;
                }
            }
            if n > 0.0 {
                let d = omega * (s / n - out[[y, x]]);
                out[[y, x]] += d;
                worst = worst.max(d.abs());
            }
        }
        if worst < tol {
            break;
        }
    }
}

/// The 4-connected holes of `mask`: per pixel the label of its hole (0
/// for valid pixels), and per label the hole's size in pixels (`sizes[0]`
/// = 0); `wrap`: connected across the borders.
fn hole_labels(mask: &Array2<bool>, wrap: bool) -> (Array2<usize>, Vec<usize>) {
    let (ny, nx) = mask.dim();
    let mut label = Array2::<usize>::zeros((ny, nx));
    let mut sizes = vec![0usize];
    let mut stack = Vec::new();
    for ((y0, x0), &m) in mask.indexed_iter() {
        if !m || label[[y0, x0]] != 0 {
            continue;
        }
        let id = sizes.len();
        let mut n = 0;
        label[[y0, x0]] = id;
        stack.push((y0, x0));
        while let Some((y, x)) = stack.pop() {
            n += 1;
            let mut visit = |yy: usize, xx: usize| {
                if mask[[yy, xx]] && label[[yy, xx]] == 0 {
                    label[[yy, xx]] = id;
                    stack.push((yy, xx));
                }
            };
            if y > 0 || wrap {
                visit((y + ny - 1) % ny, x);
            }
            if y + 1 < ny || wrap {
                visit((y + 1) % ny, x);
            }
            if x > 0 || wrap {
                visit(y, (x + nx - 1) % nx);
            }
            if x + 1 < nx || wrap {
                visit(y, (x + 1) % nx);
            }
        }
        sizes.push(n);
    }
    (label, sizes)
}

/// The pixels a filled hole may hold before `--fill-holes` names it. In
/// `experiment_filled_dropout` (tests/spectra.rs; 16 fBm of 384^2, H
/// 0.3-0.7, 3 octaves, tau(q) for q in [-2, 3], paired with the full
/// images), with 5-8 % of the pixels missing, scattered pixels and discs
/// of up to 13 px moved tau(q) by at most 0.014 for q >= -1 (0.019 +- 0.008
/// at q = -2); 15 and 30 % of scattered pixels by up to 0.010 and 0.028:
/// tau(3) by up to 0.25 times the share of such pixels. Larger holes raise
/// tau(q) for q > 0 more, tau(3) by 0.2-0.55 times the share they cover
/// (discs of 29-441 px over 4-5 %: +0.009 to +0.024; of 113 px over 14 and
/// 26 %: +0.06 and +0.12): their fill is a smooth patch, of high h. On 16
/// paper-lognormal W-cascades of 512^2 (`PRESET=paper-lognormal`) the
/// factors were 0.13 and 0.5 (README, "Missing pixels").
pub const LARGE_FILLED_HOLE: usize = 16;

/// An image's holes, as `--fill-holes` reports them.
#[derive(Clone, Copy, Debug, Default)]
pub struct HoleSizes {
    /// Missing pixels.
    pub missing: usize,
    /// The largest hole's pixels.
    pub largest: usize,
    /// Pixels in holes larger than [`LARGE_FILLED_HOLE`].
    pub in_large: usize,
    /// The image's pixels.
    pub area: usize,
}

impl HoleSizes {
    /// `field`'s holes (across the borders on a `torus`).
    pub fn of(field: &Field, torus: bool) -> Self {
        let sizes = field.hole_sizes(torus);
        let (ny, nx) = field.dim();
        HoleSizes {
            missing: sizes.iter().sum(),
            largest: sizes.iter().copied().max().unwrap_or(0),
            in_large: sizes.iter().filter(|&&n| n > LARGE_FILLED_HOLE).sum(),
            area: ny * nx,
        }
    }

    /// What `--fill-holes` says of these holes after the count: the
    /// share filled, the largest hole, the share in holes larger than
    /// [`LARGE_FILLED_HOLE`], and the bias of tau(3) the experiment of
    /// [`LARGE_FILLED_HOLE`] implies at most: 0.25 times the share of the
    /// smaller holes and 0.55 times that of the larger ones.
    pub fn describe(&self) -> String {
        let (bias, bias_large) = self.bias();
        let large = self.pct(self.in_large);
        let in_large = if self.in_large > 0 {
            format!(
                "; {large:.1} % of the pixels lie in holes of more than {LARGE_FILLED_HOLE} px, \
                 whose fill is a smooth patch, of high h"
            )
        } else {
            String::new()
        };
        format!(
            "{:.1} % of the pixels; the largest hole holds {} px{in_large}; on fBm the fill \
             raised tau(3) by up to 0.25 times the share of scattered pixels and holes of up to \
             {LARGE_FILLED_HOLE} px and 0.55 times that of larger ones (here {}){}",
            self.pct(self.missing),
            self.largest,
            bias_text(bias),
            crop_advice(bias_large)
        )
    }

    /// [`Self::describe`] in short, for one image of several (the
    /// ensemble's warning explains): the share filled, the largest hole,
    /// the share in large holes, the bound on tau(3)'s bias.
    pub fn brief(&self) -> String {
        let in_large = if self.in_large > 0 {
            format!(
                ", {:.1} % in holes of more than {LARGE_FILLED_HOLE} px",
                self.pct(self.in_large)
            )
        } else {
            String::new()
        };
        let (bias, bias_large) = self.bias();
        format!(
            "{:.1} %, the largest hole {} px{in_large}; tau(3) raised by {}{}",
            self.pct(self.missing),
            self.largest,
            bias_text(bias),
            crop_advice(bias_large)
        )
    }

    /// The share of the pixels `n` are, in %.
    fn pct(&self, n: usize) -> f64 {
        100.0 * n as f64 / self.area.max(1) as f64
    }

    /// The bound on tau(3)'s bias and the large holes' part of it
    /// ([`LARGE_FILLED_HOLE`]'s experiment): 0.25 times the share of the
    /// smaller holes and 0.55 times that of the larger ones.
    fn bias(&self) -> (f64, f64) {
        // saturating: a hand-edited record may hold more pixels in large
        // holes than filled
        let small = self.pct(self.missing.saturating_sub(self.in_large));
        let large = self.pct(self.in_large);
        let bias_large = 0.0055 * large;
        (0.0025 * small + bias_large, bias_large)
    }
}

/// "; crop the large holes out if you can" when their part of the bias
/// bound exceeds 0.01, else nothing.
fn crop_advice(bias_large: f64) -> &'static str {
    if bias_large > 0.01 {
        "; crop the large holes out if you can"
    } else {
        ""
    }
}

/// "up to +0.013", or "under +0.001".
fn bias_text(bias: f64) -> String {
    if bias < 0.001 {
        "under +0.001".to_string()
    } else {
        format!("up to +{bias:.3}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A field keeps its values row-major whatever the array's layout (a
    /// transposed array made owned is column-major, and the power spectrum
    /// of trace moments panicked on it reading rows as slices), with the
    /// same values and mask.
    #[test]
    fn fields_are_row_major() {
        let a = Array2::from_shape_fn((3, 5), |(y, x)| {
            if (y, x) == (1, 2) {
                f64::NAN
            } else {
                (10 * y + x) as f64
            }
        });
        let t = a.t().to_owned();
        assert!(!t.is_standard_layout());
        let f = Field::new(t.clone());
        assert!(f.data.is_standard_layout());
        assert_eq!(f.data.dim(), (5, 3));
        assert_eq!(f.data[[2, 1]].to_bits(), f64::NAN.to_bits());
        assert_eq!(f.data[[4, 0]], 4.0);
        assert_eq!(f.mask.as_ref().map(|m| m[[2, 1]]), Some(true));
        let m = t.map(|v| v.is_nan()).t().to_owned().t().to_owned();
        assert!(!m.is_standard_layout());
        let g = Field::with_mask(t, m).unwrap();
        assert!(g.data.is_standard_layout() && g.mask.as_ref().unwrap().is_standard_layout());
        assert_eq!(g.data[[4, 2]], 24.0);
    }

    /// `mask_value` masks the pixels of one value (-0.0 as 0.0), keeps the
    /// missing ones missing, counts what it masked, and leaves a field
    /// without such pixels unmasked; `as_stored` rounds to the file's floats.
    #[test]
    fn a_value_is_masked_as_the_file_stores_it() {
        let mut f = Field::new(ndarray::array![[0.0, 1.0, -0.0], [f64::NAN, 2.0, 0.0]]);
        assert_eq!(f.mask_value(0.0), 3);
        assert_eq!(f.valid_count(), 2);
        let m = f.mask.as_ref().unwrap();
        assert!(m[[0, 0]] && m[[0, 2]] && m[[1, 0]] && m[[1, 2]] && !m[[0, 1]]);
        assert!(f.data[[0, 0]].is_nan());
        let mut g = Field::new(ndarray::array![[1.0, 2.0], [3.0, 4.0]]);
        assert_eq!(g.mask_value(5.0), 0);
        assert!(g.mask.is_none());
        // a float32 file holds 0.1 as 0.10000000149011612
        let stored = crate::io::as_stored(0.1, "<f4");
        assert_eq!(stored, 0.1f32 as f64);
        assert_ne!(stored, 0.1);
        assert_eq!(crate::io::as_stored(0.1, "f32"), stored);
        assert_eq!(crate::io::as_stored(0.1, "<f8"), 0.1);
        assert_eq!(crate::io::as_stored(-9999.0, "<i2"), -9999.0);
        let mut h = Field::new(ndarray::array![[0.1f32 as f64, 1.0], [2.0, 3.0]]);
        assert_eq!(h.mask_value(stored), 1);
    }

    /// A harmonic function (here a plane) is filled exactly in holes away
    /// from the border, whatever their shape; a hole on the border stays
    /// within the values around it; a constant is filled exactly.
    #[test]
    fn harmonic_fill_restores_a_plane() {
        let plane =
            Array2::from_shape_fn((40, 50), |(y, x)| 3.0 + 0.5 * x as f64 - 0.25 * y as f64);
        let mask = Array2::from_shape_fn((40, 50), |(y, x)| {
            (10..25).contains(&y) && (5..30).contains(&x) // a lake
                || (y * 7 + x * 3) % 29 == 0 && y > 0 && x > 0 && y < 39 && x < 49
        });
        let f = Field::with_mask(plane.clone(), mask.clone()).unwrap();
        let filled = f.filled_harmonic().unwrap();
        let worst = filled
            .iter()
            .zip(&plane)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        // 1.5e-6 measured, 5e-8 of the range (the 50-sweep cap binds
        // before the 1e-9 stop)
        let (lo, hi) = f.range().unwrap();
        assert!(worst < 1e-6 * (hi - lo), "{worst}");
        // a corner hole: zero gradient across the border, bounded by the rim
        let corner = Array2::from_shape_fn((40, 50), |(y, x)| x + y < 6);
        let g = Field::with_mask(plane.clone(), corner.clone())
            .unwrap()
            .filled_harmonic()
            .unwrap();
        let rim = |y: usize, x: usize| x + y == 6 || x + y == 7;
        let (lo, hi) = corner_rim_range(&plane, rim);
        for ((y, x), &m) in corner.indexed_iter() {
            if m {
                assert!(
                    g[[y, x]] >= lo - 1e-9 && g[[y, x]] <= hi + 1e-9,
                    "{y} {x} {}",
                    g[[y, x]]
                );
            }
        }
        // valid pixels untouched
        for ((p, &m), v) in mask.indexed_iter().zip(&filled) {
            if !m {
                assert_eq!(*v, plane[p]);
            }
        }
        let c = Field::with_mask(
            Array2::from_elem((9, 7), 2.5),
            mask.slice(ndarray::s![..9, ..7]).to_owned(),
        )
        .unwrap();
        // a mask of another shape is an error, not a panic
        let e = Field::with_mask(Array2::zeros((3, 3)), Array2::from_elem((3, 4), false));
        assert!(e.unwrap_err().to_string().contains("3x4"));
        assert!(
            c.filled_harmonic()
                .unwrap()
                .iter()
                .all(|&v| (v - 2.5).abs() < 1e-12)
        );
        let none =
            Field::with_mask(Array2::zeros((3, 3)), Array2::from_elem((3, 3), true)).unwrap();
        assert!(none.filled_harmonic().is_err());
    }

    /// On a torus a hole across the border is filled from both sides: a
    /// band of 10 columns straddling the seam (rows 20-39) of a field that
    /// is linear across the seam, `x` for `x < 32` and `x - 64` beyond
    /// (harmonic there; its jump at x = 32 lies far off), is filled as the
    /// plane of `harmonic_fill_restores_a_plane`, to 1e-6 of the range;
    /// the fill without the wrap is flat on each side (zero gradient at the
    /// border) and steps across the seam.
    #[test]
    fn torus_fill_wraps_across_the_border() {
        let n = 64;
        let f = Array2::from_shape_fn((n, n), |(_, x)| {
            if x < n / 2 {
                x as f64
            } else {
                x as f64 - n as f64
            }
        });
        let mask = Array2::from_shape_fn((n, n), |(y, x)| {
            (20..40).contains(&y) && !(5..n - 5).contains(&x)
        });
        let field = Field::with_mask(f.clone(), mask.clone()).unwrap();
        let err = |g: &Array2<f64>| {
            g.iter()
                .zip(&f)
                .zip(&mask)
                .filter(|(_, m)| **m)
                .map(|((a, b), _)| (a - b).abs())
                .fold(0.0, f64::max)
        };
        let (wrapped, flat) = (
            err(&field.filled_harmonic_torus().unwrap()),
            err(&field.filled_harmonic().unwrap()),
        );
        println!("torus fill off by {wrapped:.2e}, plane fill by {flat:.3} (range 63)");
        assert!(wrapped < 1e-6 * 63.0, "wrapped fill off by {wrapped}");
        assert!(flat > 2.0, "the plane's fill off by only {flat}");
        // one hole of 20 rows by 10 columns across the border, two of 5
        // columns on a plane
        assert_eq!(field.hole_sizes(true), [20 * 10]);
        assert_eq!(field.hole_sizes(false), [20 * 5, 20 * 5]);
        // valid pixels untouched; odd sides too
        let g = Field::with_mask(f.slice(ndarray::s![..63, ..61]).to_owned(), {
            mask.slice(ndarray::s![..63, ..61]).to_owned()
        })
        .unwrap();
        let filled = g.filled_harmonic_torus().unwrap();
        for ((p, &m), v) in g.mask.as_ref().unwrap().indexed_iter().zip(&filled) {
            if !m {
                assert_eq!(*v, g.data[p]);
            } else {
                assert!(v.abs() <= 5.0, "{p:?}: {v}");
            }
        }
    }

    /// Isolated missing pixels (every 23rd, none adjacent, 4 % of the
    /// image) beside a large hole: each is filled with the mean of its 4
    /// neighbours, its exact harmonic value, to rounding. With one
    /// over-relaxation factor for all holes, from their total count, they
    /// were left 26 % off it (the error times 1 - omega = -0.97 per sweep,
    /// 50 sweeps).
    #[test]
    fn isolated_holes_are_filled_exactly() {
        let (ny, nx) = (96, 128);
        let f = Array2::from_shape_fn((ny, nx), |(y, x)| {
            ((y * 37 + x * 101) % 53) as f64 + 0.1 * (x as f64 * 0.3).sin()
        });
        let lone = |y: usize, x: usize| {
            y > 0 && x > 0 && y + 1 < ny && x + 1 < nx && (y * nx + x).is_multiple_of(23) && x < 60
        };
        let mask = Array2::from_shape_fn((ny, nx), |(y, x)| {
            lone(y, x) || (x >= 70 && (20..80).contains(&y))
        });
        let holed = Field::with_mask(f.clone(), mask).unwrap();
        // the block: 58 columns by 60 rows
        assert_eq!(holed.largest_hole(), 58 * 60);
        assert_eq!(Field::new(f.clone()).largest_hole(), 0);
        let g = holed.filled_harmonic().unwrap();
        let mut n = 0;
        for y in 0..ny {
            for x in 0..nx {
                if lone(y, x) {
                    let want =
                        (f[[y - 1, x]] + f[[y + 1, x]] + f[[y, x - 1]] + f[[y, x + 1]]) / 4.0;
                    assert!(
                        (g[[y, x]] - want).abs() < 1e-9,
                        "{y} {x}: {} vs {want}",
                        g[[y, x]]
                    );
                    n += 1;
                }
            }
        }
        assert!(n > 200, "{n}");
        assert_eq!(hole_size(&Array2::from_elem((3, 3), true), false, 1, 1), 9);
        let ring = Array2::from_shape_fn((4, 4), |(_, x)| x == 0 || x == 3);
        assert_eq!(hole_size(&ring, false, 0, 0), 4);
        assert_eq!(hole_size(&ring, true, 0, 0), 8);
    }

    /// The size of the hole holding pixel `(y, x)`.
    fn hole_size(mask: &Array2<bool>, wrap: bool, y: usize, x: usize) -> usize {
        let (labels, sizes) = hole_labels(mask, wrap);
        sizes[labels[[y, x]]]
    }

    fn corner_rim_range(a: &Array2<f64>, rim: impl Fn(usize, usize) -> bool) -> (f64, f64) {
        a.indexed_iter()
            .filter(|((y, x), _)| rim(*y, *x))
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), (_, &v)| {
                (lo.min(v), hi.max(v))
            })
    }

    #[test]
    fn amplitudes_beyond_the_squares_of_f64_are_named() {
        let v = [1.0, -2.0, 3.5];
        assert_eq!(amplitude_problem(&v), None);
        // a constant is left to the commands' own message
        assert_eq!(amplitude_problem(&[7.0, 7.0]), None);
        assert_eq!(amplitude_problem(&[f64::NAN]), None);
        let big = amplitude_problem(&[0.0, 2e100]).unwrap();
        assert!(
            big.contains("2.000e100") && big.contains("overflow"),
            "{big}"
        );
        let tiny = amplitude_problem(&[1e-160, 3e-160]).unwrap();
        assert!(tiny.contains("underflow"), "{tiny}");
        // large but far from overflow, and a large offset with a sane spread
        assert_eq!(amplitude_problem(&[0.0, 1e90]), None);
        assert_eq!(amplitude_problem(&[1e50, 1e50 + 1e40]), None);
    }
}
