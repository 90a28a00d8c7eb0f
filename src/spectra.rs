//! Partition functions and multifractal spectra over the WT skeleton
//! (SPEC §4; II §3, Figs 10 and 16; paper I eqs 59-63).
//!
//! For each q and scale a, over the maxima lines L alive at a:
//!
//! ```text
//! Z(q, a) = Σ_L M_L(a)^q                      ~ a^τ(q)
//! W_L     = M_L^q / Z
//! h(q, a) = Σ_L W_L log2 M_L                  ~ h(q) log2 a
//! D(q, a) = Σ_L W_L log2 W_L = q h - log2 Z   ~ D(q) log2 a
//! ```
//!
//! `M_L(a)` is the sup rule (`max` of M along L over scales `<= a`) or the
//! plain modulus; both are accumulated, [`Rule`] picks the one reported.
//!
//! **Stability.** Per image and cell (q, a) the sums are taken relative to
//! `2^e`, `e = ceil(max_L q log2 M_L)`, so every term is in (0, 1] whatever
//! q (log-sum-exp); nothing overflows for |q| up to hundreds.
//!
//! **Ensembles.** [`PartitionSums`] keeps one partial per image; the annealed
//! ensemble sum of a cell adds the images' partials in a canonical order
//! (sorted by value), so `a.merge(&b)` is exact and order-independent to the
//! last bit, and a delete-one jackknife over images gives error bars from the
//! ensemble's own scatter.

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result, short};
use crate::skeleton::Skeleton;
use crate::stats::fit::{line_fit, slope_change};

/// Which modulus a line contributes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum Rule {
    /// `M_L(a) = max_{a' <= a} M(a')` along the line (meant to keep q < 0 stable).
    Sup,
    /// The modulus at a: the default of the library and of every command
    /// (README, "How the defaults were chosen").
    #[default]
    Plain,
}

impl Rule {
    /// The name the command line and the outputs use ("sup", "plain").
    pub fn name(self) -> &'static str {
        match self {
            Rule::Sup => "sup",
            Rule::Plain => "plain",
        }
    }
}

/// Sums of one image for one cell (q, a), relative to `2^e`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Cell {
    /// Integer exponent: the true sums are these values times `2^e`.
    pub e: i32,
    /// `Σ 2^(q log2 M - e)`.
    pub z: f64,
    /// `Σ 2^(q log2 M - e) log2 M`.
    pub zl: f64,
    /// `Σ 2^(2 (q log2 M - e))` (for the effective number of lines).
    pub z2: f64,
}

impl Cell {
    const EMPTY: Cell = Cell {
        e: i32::MIN,
        z: 0.0,
        zl: 0.0,
        z2: 0.0,
    };

    fn is_empty(&self) -> bool {
        self.z == 0.0
    }
}

/// The partial sums of one image: `cells[rule][qi * n_scales + j]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ImagePartial {
    /// Free label (file name), for the record.
    pub label: String,
    /// Image size `[ny, nx]` (absent for sums built from bare values, and
    /// in `sums.json` files written before it was recorded).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shape: Option<[usize; 2]>,
    /// Missing pixels (NaN, ±inf or nodata in the file); maxima count only
    /// farther from them than the wavelet's support at the largest scale
    /// ([`Skeleton::counts`](crate::skeleton::Skeleton::counts)).
    #[serde(default)]
    pub missing: u64,
    /// Lines counted per scale (as [`Spectra::lines`]).
    pub lines: Vec<u64>,
    /// Cells of the sup rule ([`Rule::Sup`]), `[qi * n_scales + j]`.
    pub sup: Vec<Cell>,
    /// Cells of the plain modulus ([`Rule::Plain`]), same layout.
    pub plain: Vec<Cell>,
    /// The same sums split over square tiles of the counting domain (each
    /// maximum in the tile holding it at its scale, so the tiles add up to
    /// the image): the jackknife groups of an ensemble of fewer than 3
    /// images ([`PartitionSums::spectra`]). Empty unless asked for
    /// ([`PartitionSums::from_skeleton_tiled`]).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub tiles: Vec<TilePartial>,
    /// Side of the tiles in px (0 without tiles).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub tile_side: usize,
    /// The fraction of the image's variance its least-squares plane
    /// explains ([`crate::Field::plane_share`]), before any detrending:
    /// a large one biases the gauss wavelet, to whose transform a plane
    /// adds a vector growing like the scale (said by
    /// [`PartitionSums::spectra`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub plane_share: Option<f64>,
    /// How wide the terraces of a quantised image are, in px
    /// ([`crate::Field::terrace_width`]; 1 when neighbours differ): wider
    /// than [`TERRACE_SCALES`] times the smallest fitted scale, the
    /// wavelet sees their steps (said by [`PartitionSums::spectra`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub terrace_width: Option<f64>,
    /// The one value that fills flat areas of the image and its share of
    /// the valid pixels ([`crate::Field::flat_value`]): above
    /// [`crate::field::FLAT_SHARE_WARN`], said by [`PartitionSums::spectra`].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub flat: Option<FlatRecord>,
    /// The value read as missing in the image's file besides its declared
    /// nodata (`--nodata`, [`crate::Field::mask_value`]), when one was
    /// given; recorded for the provenance of merged sums (set by the
    /// caller: the library sees only the masked field).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub nodata: Option<f64>,
    /// Missing pixels filled harmonically and counted as data
    /// (`analyze --fill-holes`; set by the caller, as `nodata`).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub filled: usize,
    /// The largest hole filled, in px (with `filled`): holes become smooth
    /// patches, whose bias on tau(q) grows with their size (README,
    /// "Missing pixels").
    #[serde(default, skip_serializing_if = "is_zero")]
    pub largest_filled_hole: usize,
    /// The pixels filled in holes larger than 16 px (with `filled`), the
    /// part that biases tau(q) most.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub in_large_filled_holes: usize,
}

/// [`ImagePartial::flat`]: a value and the share of the valid pixels
/// holding it.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct FlatRecord {
    /// The value.
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub value: f64,
    /// Its share of the image's valid pixels, in (0, 1].
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub share: f64,
}

pub(crate) fn is_zero(n: &usize) -> bool {
    *n == 0
}

/// "180" or "90-180": the tile sides of the images, for the labels.
pub(crate) fn tile_sides(sides: impl Iterator<Item = usize>) -> String {
    let (lo, hi) = sides.fold((usize::MAX, 0), |(a, b), s| (a.min(s), b.max(s)));
    if lo == hi {
        format!("{lo}")
    } else {
        format!("{lo}-{hi}")
    }
}

/// Square tiles of about `side` px over a counting domain `(y0, y1, x0,
/// x1)`: as many whole tiles as fit along each side, stretched to cover it
/// (the jackknife groups of a lone image: [`ImagePartial::tiles`], and the
/// kernel's `KernelImage::tiles`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TileGrid {
    y0: usize,
    x0: usize,
    h: usize,
    w: usize,
    nty: usize,
    ntx: usize,
}

impl TileGrid {
    /// `None` when `side` is 0, the domain is empty or fewer than 2 tiles
    /// fit.
    pub fn new((y0, y1, x0, x1): (usize, usize, usize, usize), side: usize) -> Option<Self> {
        let (h, w) = (y1.saturating_sub(y0), x1.saturating_sub(x0));
        if h == 0 || w == 0 {
            return None;
        }
        let nty = h.checked_div(side)?.max(1);
        let ntx = w.checked_div(side)?.max(1);
        (nty * ntx >= 2).then_some(TileGrid {
            y0,
            x0,
            h,
            w,
            nty,
            ntx,
        })
    }

    /// Number of tiles.
    pub fn len(&self) -> usize {
        self.nty * self.ntx
    }

    /// Always false (a grid has at least 2 tiles).
    pub fn is_empty(&self) -> bool {
        false
    }

    /// Rows `[ya, yb)` and columns `[xa, xb)` of tile `k`: the pixels of
    /// the domain that [`Self::index`] puts in it.
    ///
    /// **Panics** if `k >= self.len()`.
    pub fn bounds(&self, k: usize) -> (usize, usize, usize, usize) {
        // always checked: past the last tile `cut` would recurse without end
        assert!(k < self.len(), "tile {k} of {}", self.len());
        let (ty, tx) = (k / self.ntx, k % self.ntx);
        (
            self.y0 + cut(ty, self.h, self.nty),
            self.y0 + cut(ty + 1, self.h, self.nty),
            self.x0 + cut(tx, self.w, self.ntx),
            self.x0 + cut(tx + 1, self.w, self.ntx),
        )
    }

    /// The tile holding pixel `(x, y)` (row-major; points outside the
    /// domain go to the nearest tile).
    pub fn index(&self, x: u32, y: u32) -> usize {
        self.row_start(y as usize) + self.column(x as usize)
    }

    /// The index of the first tile of the row of tiles holding image row
    /// `y` ([`Self::index`]).
    fn row_start(&self, y: usize) -> usize {
        slot(y.saturating_sub(self.y0), self.h, self.nty) * self.ntx
    }

    /// The column of tiles holding image column `x` ([`Self::index`]).
    fn column(&self, x: usize) -> usize {
        slot(x.saturating_sub(self.x0), self.w, self.ntx)
    }

    /// [`Self::index`] of every pixel of an `ny x nx` image as a table: the
    /// hot loops (tm's structure functions: one lookup per increment, lag
    /// and direction) then take no division.
    pub fn table(&self, ny: usize, nx: usize) -> TileTable {
        TileTable {
            rows: (0..ny).map(|y| self.row_start(y)).collect(),
            cols: (0..nx).map(|x| self.column(x)).collect(),
        }
    }
}

/// [`TileGrid::index`] tabulated over an image ([`TileGrid::table`]).
#[derive(Clone, Debug)]
pub struct TileTable {
    rows: Vec<usize>,
    cols: Vec<usize>,
}

impl TileTable {
    /// The tile of pixel `(y, x)`, as [`TileGrid::index`]`(x, y)`.
    ///
    /// **Panics** if the pixel is outside the tabulated image.
    #[inline]
    pub fn at(&self, y: usize, x: usize) -> usize {
        self.rows[y] + self.cols[x]
    }
}

/// Where tile `t` of `n` begins along a side of `len` px (`t = n`: `len`):
/// `t len / n` rounded half up in the first half of the side, and mirrored
/// in the second (`len - cut(n - t)`), so that a flipped image has the
/// flipped tiles and its single-image jackknife errors are the same (with
/// `ceil(t len / n)` throughout, a flip moved them by 4-6 % on a DEM). The
/// one cut a flip cannot map onto itself is the middle of an odd side
/// split into an even number of tiles: its centre row or column goes to
/// the first half. Cuts lie within half a pixel of `t len / n`, so tiles
/// differ by at most one pixel a side.
fn cut(t: usize, len: usize, n: usize) -> usize {
    if 2 * t <= n {
        (2 * t * len + n) / (2 * n)
    } else {
        len - cut(n - t, len, n)
    }
}

/// The tile `t` of `n` along a side of `len` px that holds offset `v`
/// (`cut(t) <= v < cut(t + 1)`; past the side: the last tile).
fn slot(v: usize, len: usize, n: usize) -> usize {
    // within one of the exact quotient, since the cuts are within half a
    // pixel of t len / n
    let mut t = (v * n / len).min(n - 1);
    while t > 0 && cut(t, len, n) > v {
        t -= 1;
    }
    while t + 1 < n && cut(t + 1, len, n) <= v {
        t += 1;
    }
    t
}

/// The partial sums of one tile of an image ([`ImagePartial::tiles`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TilePartial {
    /// Maxima counted in the tile, per scale.
    pub lines: Vec<u64>,
    /// As [`ImagePartial::sup`].
    pub sup: Vec<Cell>,
    /// As [`ImagePartial::plain`].
    pub plain: Vec<Cell>,
}

/// Mergeable partition sums of an ensemble (one partial per image).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PartitionSums {
    /// Crate version that wrote the sums.
    pub version: String,
    /// The analysis that produced the sums (wavelet, scales, margin,
    /// linking), so that shards of different analyses are not merged;
    /// `None` when unknown (sums of given values, files of older versions).
    #[serde(default)]
    pub analysis: Option<crate::skeleton::AnalysisConfig>,
    /// The q grid.
    pub q: Vec<f64>,
    /// The scales, in pixels, ascending.
    pub scales: Vec<f64>,
    /// One partial per image, in the order added.
    pub images: Vec<ImagePartial>,
    /// The pixel of the images, when the analysis knew it (`analyze` with
    /// `--pixel-size` or a spacing the files declare), so that a later merge
    /// still gives the fit's scales as lengths. Not part of the sums: a
    /// merge of shards whose pixels differ has none.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pixel: Option<PixelRecord>,
}

/// The pixel recorded with partition sums ([`PartitionSums::pixel`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PixelRecord {
    /// Along the columns (x). (JSON null, an edited file's NaN, reads
    /// back as NaN, a record merge does not use.)
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub x: f64,
    /// Along the rows (y).
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub y: f64,
    /// The unit's name.
    pub units: String,
    /// Where it came from (`--pixel-size`, or the file that declared it).
    pub source: String,
}

impl PixelRecord {
    /// The same pixel (sides within 1e-3 relative, in the same unit or in
    /// lengths [`crate::io::unit_metres`] converts: 30 m and 0.03 km),
    /// whatever its source.
    pub fn same(&self, other: &PixelRecord) -> bool {
        crate::io::unit_ratio(Some(&self.units), Some(&other.units)).is_some_and(|k| {
            (k * self.x / other.x - 1.0).abs() <= 1e-3 && (k * self.y / other.y - 1.0).abs() <= 1e-3
        })
    }
}

impl PartitionSums {
    /// [`AnalysisConfig::plane_warning`](crate::skeleton::AnalysisConfig::plane_warning)
    /// of the images' recorded plane shares ([`ImagePartial::plane_share`]).
    fn plane_warning(&self) -> Option<String> {
        let shares: Vec<f64> = self.images.iter().filter_map(|im| im.plane_share).collect();
        self.analysis
            .as_ref()?
            .plane_warning(&shares, self.images.len())
    }

    /// How many images had missing pixels filled and counted as data
    /// ([`ImagePartial::filled`], `analyze --fill-holes`), with the holes'
    /// sizes and the bias they may bring ([`crate::field::HoleSizes::describe`]):
    /// the per-image notes scroll past, and merged sums carry no others.
    fn fill_warning(&self) -> Option<String> {
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
    fn quantisation_warnings(&self, a_fit: f64) -> Vec<String> {
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
    fn info_hint(&self) -> String {
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

    /// The partition sums of one image's skeleton, for the q grid `q`.
    /// The skeleton does not say which analysis made it nor how many
    /// pixels were missing: `analysis` is `None` and `missing` 0 (so merges
    /// cannot check the analysis and the spectra give no missing-pixel or
    /// wavelet-order warnings); [`image_sums`] sets both.
    pub fn from_skeleton(sk: &Skeleton, q: &[f64], label: impl Into<String>) -> Self {
        Self::from_skeleton_tiled(sk, q, label, 0)
    }

    /// [`from_skeleton`](Self::from_skeleton), also split over square
    /// tiles of side about `tile_side` px of the counting domain (as many
    /// whole tiles as fit along each side, stretched to cover it), so that
    /// a lone image has jackknife groups ([`ImagePartial::tiles`]). No
    /// tiles when `tile_side` is 0 or fewer than 2 fit.
    pub fn from_skeleton_tiled(
        sk: &Skeleton,
        q: &[f64],
        label: impl Into<String>,
        tile_side: usize,
    ) -> Self {
        let ns = sk.scales.len();
        let nq = q.len();
        let mut sup = vec![Cell::EMPTY; nq * ns];
        let mut plain = vec![Cell::EMPTY; nq * ns];
        let mut lines = vec![0u64; ns];
        // the tile grid over the counting domain
        let grid = TileGrid::new(sk.domain, tile_side);
        let n_tiles = grid.map_or(0, |g| g.len());
        let mut tiles = vec![
            TilePartial {
                lines: vec![0; ns],
                sup: vec![Cell::EMPTY; nq * ns],
                plain: vec![Cell::EMPTY; nq * ns],
            };
            n_tiles
        ];
        // per tile, the (plain, sup) log2 M of the scale in hand
        let mut by_tile: Vec<(Vec<f64>, Vec<f64>)> = vec![(Vec::new(), Vec::new()); n_tiles];
        // log2 M of the lines alive at each scale (plain, sup)
        let mut lp: Vec<f64> = Vec::new();
        let mut ls: Vec<f64> = Vec::new();
        for j in 0..ns {
            lp.clear();
            ls.clear();
            for t in by_tile.iter_mut() {
                t.0.clear();
                t.1.clear();
            }
            // a WTMMM counts when it is linked to an adjacent scale: lines
            // that never link beyond a_min contribute nothing (xsmurf
            // `efct -vc`, the reference partition function)
            for l in sk.alive_at(j).filter(|l| l.points.len() > 1) {
                let p = l.points[j];
                if !sk.counts(p.x, p.y) {
                    continue; // traced in the guard band, counted only inside
                }
                lp.push(p.m.log2());
                ls.push(p.sup.log2());
                if let Some(g) = &grid {
                    let t = &mut by_tile[g.index(p.x, p.y)];
                    t.0.push(p.m.log2());
                    t.1.push(p.sup.log2());
                }
            }
            lines[j] = lp.len() as u64;
            if lp.is_empty() {
                continue;
            }
            for (logs, cells) in [(&ls, &mut sup), (&lp, &mut plain)] {
                for (qi, c) in cells_all_q(logs, q).into_iter().enumerate() {
                    cells[qi * ns + j] = c;
                }
            }
            for ((tp, ts), tile) in by_tile.iter().zip(tiles.iter_mut()) {
                tile.lines[j] = tp.len() as u64;
                if tp.is_empty() {
                    continue;
                }
                for (logs, cells) in [(ts, &mut tile.sup), (tp, &mut tile.plain)] {
                    for (qi, c) in cells_all_q(logs, q).into_iter().enumerate() {
                        cells[qi * ns + j] = c;
                    }
                }
            }
        }
        PartitionSums {
            version: crate::VERSION.to_string(),
            analysis: None,
            q: q.to_vec(),
            scales: sk.scales.clone(),
            pixel: None,
            images: vec![ImagePartial {
                label: label.into(),
                shape: Some([sk.shape.0, sk.shape.1]),
                missing: 0,
                lines,
                sup,
                plain,
                tile_side: if n_tiles > 0 { tile_side } else { 0 },
                tiles,
                plane_share: None,
                terrace_width: None,
                flat: None,
                nodata: None,
                filled: 0,
                largest_filled_hole: 0,
                in_large_filled_holes: 0,
            }],
        }
    }

    /// The partition sums of values given directly: `log2_values[j]` are the
    /// `log2` moduli counted at `scales[j]` (ascending), one image. Both rules
    /// get the same cells. For the generators' own cascades
    /// ([`crate::theory::Model::sample_sums`]).
    ///
    /// **Errors** if the lengths differ, the scales are not ascending, a
    /// value is not finite, or on a q grid [`check_q`] refuses.
    pub fn from_log2_values(
        scales: &[f64],
        log2_values: &[Vec<f64>],
        q: &[f64],
        label: impl Into<String>,
    ) -> Result<Self> {
        check_q(q)?;
        let ns = scales.len();
        if log2_values.len() != ns || ns == 0 {
            return Err(Error::param(
                "scales",
                format!("{ns} scales for {} value sets", log2_values.len()),
            ));
        }
        if scales.windows(2).any(|w| w[1] <= w[0]) || !scales.iter().all(|a| *a > 0.0) {
            return Err(Error::param("scales", "must be positive and ascending"));
        }
        if log2_values.iter().flatten().any(|l| !l.is_finite()) {
            return Err(Error::Input(
                "a value is zero, negative or not finite".into(),
            ));
        }
        let nq = q.len();
        let mut cells = vec![Cell::EMPTY; nq * ns];
        for (j, logs) in log2_values.iter().enumerate() {
            if logs.is_empty() {
                continue;
            }
            for (qi, c) in cells_all_q(logs, q).into_iter().enumerate() {
                cells[qi * ns + j] = c;
            }
        }
        Ok(PartitionSums {
            version: crate::VERSION.to_string(),
            analysis: None,
            q: q.to_vec(),
            scales: scales.to_vec(),
            pixel: None,
            images: vec![ImagePartial {
                label: label.into(),
                shape: None,
                missing: 0,
                lines: log2_values.iter().map(|v| v.len() as u64).collect(),
                sup: cells.clone(),
                plain: cells,
                tiles: Vec::new(),
                tile_side: 0,
                plane_share: None,
                terrace_width: None,
                flat: None,
                nodata: None,
                filled: 0,
                largest_filled_hole: 0,
                in_large_filled_holes: 0,
            }],
        })
    }

    /// Adds `other`'s images. The result does not depend on the order of
    /// merges (sums are taken in a canonical order when finalised).
    ///
    /// Images are not compared: sums merged twice count as two images, and
    /// their jackknife sees less spread than there is (zero for one image
    /// merged with itself). An image and its negative, or its mirror
    /// image, also give equal sums, so equality alone cannot tell a copy
    /// from a second image; `wtmm merge` refuses equal images from two
    /// different shard files.
    ///
    /// **Errors** if the q grids or the scales differ.
    pub fn merge(&mut self, other: &PartitionSums) -> Result<()> {
        if self.q != other.q {
            return Err(Error::param(
                "q",
                "cannot merge partition sums over different q grids",
            ));
        }
        if !crate::cwt::same_scales(&self.scales, &other.scales) {
            return Err(Error::param(
                "scales",
                "cannot merge partition sums over different scales",
            ));
        }
        match (&self.analysis, &other.analysis) {
            (Some(a), Some(b)) if same_analysis(a) != same_analysis(b) => {
                return Err(Error::param(
                    "analysis",
                    format!(
                        "cannot merge partition sums of different analyses ({})",
                        // margins resolved to pixels ("margin: 36 vs 0")
                        config_difference(&same_analysis(a), &same_analysis(b))
                    ),
                ));
            }
            // one shard of unknown provenance: so is the merge
            (Some(_), None) => self.analysis = None,
            _ => {}
        }
        // shards of different (or unknown) pixels: the merge's is unknown
        if !matches!((&self.pixel, &other.pixel), (Some(a), Some(b)) if a.same(b)) {
            self.pixel = None;
        }
        self.images.extend(other.images.iter().cloned());
        // tiles are the jackknife groups of fewer than 3 images only: from 3
        // on they would never be read again (and would multiply the size
        // of sums.json by the number of tiles)
        if self.images.len() >= 3 {
            for im in &mut self.images {
                im.tiles = Vec::new();
                im.tile_side = 0;
            }
        }
        Ok(())
    }

    /// Merges many; `None` for an empty list.
    pub fn merge_all(
        parts: impl IntoIterator<Item = PartitionSums>,
    ) -> Result<Option<PartitionSums>> {
        let mut it = parts.into_iter();
        let Some(mut acc) = it.next() else {
            return Ok(None);
        };
        for p in it {
            acc.merge(&p)?;
        }
        Ok(Some(acc))
    }

    /// Checks sums read from a file before they are trusted (a shard may
    /// be truncated, edited or from a newer version): a non-empty ascending
    /// finite q grid, positive ascending scales, at least one image, array
    /// lengths matching the grids, finite cells with non-negative sums.
    ///
    /// **Errors** with what is wrong (the caller names the file).
    pub fn check(&self) -> std::result::Result<(), String> {
        // lenient: "1", "v1.2", "1.2.3-rc1"; an unreadable version is let
        // through (it is a record, the content is checked below)
        let major = |v: &str| {
            let d: String = v
                .trim()
                .trim_start_matches('v')
                .chars()
                .take_while(char::is_ascii_digit)
                .collect();
            // all digits but too large for u64: newer than any release
            (!d.is_empty()).then(|| d.parse::<u64>().unwrap_or(u64::MAX))
        };
        if let (Some(file), Some(ours)) = (major(&self.version), major(crate::VERSION))
            && file > ours
        {
            return Err(format!(
                "written by wtmm {}, a newer major version than this {}",
                self.version,
                crate::VERSION
            ));
        }
        let ascending = |v: &[f64]| v.windows(2).all(|w| w[0] < w[1]);
        if self.q.is_empty() || !self.q.iter().all(|x| x.is_finite()) || !ascending(&self.q) {
            return Err("`q` must be a non-empty list of finite values in ascending order".into());
        }
        if self.q.iter().any(|x| x.abs() > MAX_ABS_Q) {
            return Err(format!("`q` must lie within +-{MAX_ABS_Q} (MAX_ABS_Q)"));
        }
        if self.scales.is_empty()
            || !self.scales.iter().all(|a| a.is_finite() && *a > 0.0)
            || !ascending(&self.scales)
        {
            return Err(
                "`scales` must be a non-empty list of finite positive values in ascending order"
                    .into(),
            );
        }
        if self.images.is_empty() {
            return Err("no images".into());
        }
        // the analysis recorded must be the one that made these scales: the
        // warnings derive the margin and the counting domain from it
        if let Some(a) = &self.analysis {
            a.validate()
                .map_err(|e| format!("`analysis` is not a valid analysis: {e}"))?;
            let list = a.scale_list();
            let same = list.len() == self.scales.len()
                && list
                    .iter()
                    .zip(&self.scales)
                    .all(|(x, y)| (x - y).abs() <= 1e-9 * x.abs());
            if !same {
                return Err(format!(
                    "`analysis` (a_min {} px, {} octaves of {} voices: {} scales, {:.3} .. {:.3} \
                     px) does not make the {} `scales` ({:.3} .. {:.3} px) the sums are at",
                    crate::error::short(a.a_min),
                    a.octaves,
                    a.voices,
                    list.len(),
                    list.first().copied().unwrap_or(f64::NAN),
                    list.last().copied().unwrap_or(f64::NAN),
                    self.scales.len(),
                    self.scales[0],
                    self.scales[self.scales.len() - 1],
                ));
            }
        }
        if let Some((i, im)) = self.images.iter().enumerate().find(|(_, im)| {
            im.shape.is_some_and(|[ny, nx]| {
                ny == 0 || nx == 0 || im.missing >= (ny as u64).saturating_mul(nx as u64)
            })
        }) {
            return Err(format!(
                "image {i} ({:?}): shape {:?} with {} missing pixels holds no valid pixel",
                im.label,
                im.shape.unwrap_or_default(),
                im.missing
            ));
        }
        if let Some((i, im)) = self
            .images
            .iter()
            .enumerate()
            .find(|(_, im)| im.plane_share.is_some_and(|r| !(0.0..=1.0).contains(&r)))
        {
            return Err(format!(
                "image {i} ({:?}): plane_share {} is no share of a variance (0 to 1)",
                im.label,
                im.plane_share.unwrap_or(f64::NAN)
            ));
        }
        if let Some((i, im)) = self
            .images
            .iter()
            .enumerate()
            .find(|(_, im)| im.terrace_width.is_some_and(|w| !(1.0..=1e9).contains(&w)))
        {
            return Err(format!(
                "image {i} ({:?}): terrace_width {} is no terrace width in pixels (1 or more)",
                im.label,
                im.terrace_width.unwrap_or(f64::NAN)
            ));
        }
        if let Some((i, im)) = self.images.iter().enumerate().find(|(_, im)| {
            im.flat
                .is_some_and(|f| !(f.value.is_finite() && f.share > 0.0 && f.share <= 1.0))
        }) {
            return Err(format!(
                "image {i} ({:?}): flat {:?} is no finite value with a share of pixels (0 to 1)",
                im.label, im.flat
            ));
        }
        let (ns, nc) = (self.scales.len(), self.q.len() * self.scales.len());
        // tiles partition their image: at least 2, a side, and line counts
        // adding up to the image's at every scale (a tile deleted from the
        // file would change the errors silently)
        for (i, im) in self.images.iter().enumerate() {
            if im.tiles.is_empty() {
                continue;
            }
            let at = format!("image {i} ({:?})", im.label);
            if im.tiles.len() < 2 || im.tile_side == 0 {
                return Err(format!(
                    "{at}: {} tile(s) of side {} px (tiles come at least in pairs, with a side)",
                    im.tiles.len(),
                    im.tile_side
                ));
            }
            if im.lines.len() != ns || im.tiles.iter().any(|t| t.lines.len() != ns) {
                continue; // said below, tile by tile
            }
            let in_tiles = |j: usize| {
                im.tiles
                    .iter()
                    .map(|t| t.lines[j])
                    .fold(0u64, u64::saturating_add)
            };
            if let Some(j) = (0..ns).find(|&j| in_tiles(j) != im.lines[j]) {
                return Err(format!(
                    "{at}: its tiles hold {} maxima at scale {} px, the image {}: the tiles must \
                     cover the image",
                    in_tiles(j),
                    self.scales[j],
                    im.lines[j]
                ));
            }
        }
        // an image and each of its tiles (the jackknife groups of a lone
        // image) hold the same arrays
        let parts = self.images.iter().enumerate().flat_map(|(i, im)| {
            let at = format!("image {i} ({:?})", im.label);
            std::iter::once((at.clone(), &im.lines, &im.plain, &im.sup)).chain(
                im.tiles
                    .iter()
                    .enumerate()
                    .map(move |(k, t)| (format!("{at} tile {k}"), &t.lines, &t.plain, &t.sup)),
            )
        });
        for (at, lines, plain, sup) in parts {
            if lines.len() != ns {
                return Err(format!("{at}: {} line counts for {ns} scales", lines.len()));
            }
            // no image holds 2^40 maxima at one scale (2^28 pixels at most):
            // a larger count is corrupt, and sums of such would overflow
            if lines.iter().any(|&n| n > 1 << 40) {
                return Err(format!("{at}: a line count above 2^40"));
            }
            for (name, cells) in [("plain", plain), ("sup", sup)] {
                if cells.len() != nc {
                    return Err(format!(
                        "{at}: {} `{name}` cells for {} q x {ns} scales",
                        cells.len(),
                        self.q.len()
                    ));
                }
                // |e| bounded so that exponent differences fit an i32
                // (an empty cell keeps e = i32::MIN and is skipped)
                if let Some(k) = cells.iter().position(|c| {
                    ![c.z, c.zl, c.z2].iter().all(|x| x.is_finite())
                        || c.z < 0.0
                        || c.z2 < 0.0
                        || (!c.is_empty() && c.e.unsigned_abs() > 1 << 30)
                }) {
                    let c = &cells[k];
                    return Err(format!(
                        "{at}: `{name}` cell {k} (q = {}, a = {} px) is invalid: e = {}, z = {}, \
                         zl = {}, z2 = {} (need finite sums, z and z2 >= 0, |e| <= 2^30)",
                        crate::error::short(self.q[k / ns]),
                        crate::error::short(self.scales[k % ns]),
                        c.e,
                        c.z,
                        c.zl,
                        c.z2
                    ));
                }
            }
        }
        Ok(())
    }

    /// The tiles of every image as the images of a new set of sums (the
    /// jackknife groups of an ensemble of fewer than 3 images); `None`
    /// when an image has no tiles or there are fewer than 3 in all.
    fn tile_groups(&self) -> Option<PartitionSums> {
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
                    plane_share: None,
                    terrace_width: None,
                    flat: None,
                    nodata: None,
                    filled: 0,
                    largest_filled_hole: 0,
                    in_large_filled_holes: 0,
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
    fn ensemble(&self, rule: Rule, skip: Option<usize>) -> Ensemble {
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
    fn image_ensemble(&self, rule: Rule, i: usize) -> Ensemble {
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
    /// once for the whole batch instead of once per replicate.
    fn ensembles_leaving_out(&self, rule: Rule, skips: std::ops::Range<usize>) -> Vec<Ensemble> {
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
        self.check().map_err(|e| Error::param("sums", e))?;
        let ns = self.scales.len();
        let nq = self.q.len();
        let log2_a: Vec<f64> = self.scales.iter().map(|a| a.log2()).collect();
        let oct0 = log2_a[0];
        // the top of a grid of `octaves` octaves is one voice above its
        // last scale, which the CLI accepts as the fit's end
        let (top, _) = self.grid_span();
        if !(fit.0 >= -1e-9 && fit.0 < fit.1 && fit.1 <= top + 1e-6) {
            return Err(Error::param(
                "fit",
                format!(
                    "{}:{} octaves must satisfy 0 <= lo < hi <= {top:.2}, the octaves the scales span",
                    short(fit.0),
                    short(fit.1)
                ),
            ));
        }
        // an end between two scales would fit from the next one and be
        // recorded as given
        let on_grid =
            |o: f64| (o - top).abs() <= 1e-6 || log2_a.iter().any(|l| (l - oct0 - o).abs() <= 1e-6);
        if let Some(o) = [fit.0, fit.1].into_iter().find(|&o| !on_grid(o)) {
            // the grid's octaves on either side, the top included
            let octs = log2_a.iter().map(|l| l - oct0).chain([top]);
            let below = octs.clone().filter(|&x| x < o).fold(f64::NAN, f64::max);
            let above = octs.filter(|&x| x > o).fold(f64::NAN, f64::min);
            return Err(Error::param(
                "fit",
                format!(
                    "octave {} of {}:{} lies between two scales, {:.2} and {:.2}: the ends \
                     must be octaves of scales of the grid (or the top, {top:.2}, which fits \
                     up to the last scale)",
                    short(o),
                    short(fit.0),
                    short(fit.1),
                    below,
                    above
                ),
            ));
        }
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
        if n_groups >= 3 {
            // in batches: the replicates of a batch share one sort per cell,
            // and memory stays bounded whatever the number of groups
            reps = (0..n_groups)
                .step_by(64)
                .flat_map(|i0| {
                    groups
                        .ensembles_leaving_out(rule, i0..(i0 + 64).min(n_groups))
                        .into_iter()
                        .map(|e| Estimates::fit(&e, &log2_a, &in_fit, &self.q))
                        .collect::<Vec<_>>()
                })
                .collect();
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
            let cure = if margin > 0 || missing > 0 {
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
                 only farther from them than the wavelet's support at the largest scale",
                holed.len(),
                holed.iter().sum::<u64>()
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
        warnings.extend(unlike_images(&per_image));
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
        let d_qa: Vec<f64> = (0..nq * ns)
            .map(|c| self.q[c / ns] * ens.h[c] - ens.log2_z[c])
            .collect();
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
            n_eff: cell(&ens.n_eff),
            lines: ens.lines,
            per_image,
            image_records: self.images.iter().map(ImageRecord::of).collect(),
            warnings,
        })
    }

    /// h(q = 0) and tau(q = 2) of each image on its own (NaN where the
    /// q grid lacks the q or the image has no estimate).
    fn per_image(&self, rule: Rule, log2_a: &[f64], in_fit: &[usize]) -> Vec<ImageExponents> {
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

/// What an ensemble's sums record of one image ([`Spectra::image_records`]):
/// the per-image numbers behind the warnings on missing pixels, planes,
/// terraces and flat areas.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ImageRecord {
    /// The image's label (its file).
    pub label: String,
    /// Its size `[ny, nx]` ([`ImagePartial::shape`]); null where the sums
    /// do not record it.
    #[serde(default)]
    pub shape: Option<[usize; 2]>,
    /// Missing pixels ([`ImagePartial::missing`]).
    pub missing: u64,
    /// [`ImagePartial::plane_share`]; null where the sums do not record it.
    #[serde(default)]
    pub plane_share: Option<f64>,
    /// [`ImagePartial::terrace_width`]; null likewise.
    #[serde(default)]
    pub terrace_width: Option<f64>,
    /// [`ImagePartial::flat`]; null without a flat value or where not
    /// recorded.
    #[serde(default)]
    pub flat: Option<FlatRecord>,
    /// [`ImagePartial::nodata`]; null when none was given or the sums
    /// were written before it was recorded.
    #[serde(default)]
    pub nodata: Option<f64>,
    /// [`ImagePartial::filled`]: missing pixels filled and counted as data
    /// (`missing` then counts those left missing: none).
    #[serde(default)]
    pub filled: usize,
    /// [`ImagePartial::largest_filled_hole`] (0 without a fill).
    #[serde(default)]
    pub largest_filled_hole: usize,
    /// [`ImagePartial::in_large_filled_holes`] (0 without a fill).
    #[serde(default)]
    pub in_large_filled_holes: usize,
}

impl ImageRecord {
    fn of(im: &ImagePartial) -> Self {
        ImageRecord {
            label: im.label.clone(),
            shape: im.shape,
            missing: im.missing,
            plane_share: im.plane_share,
            terrace_width: im.terrace_width,
            flat: im.flat,
            nodata: im.nodata,
            filled: im.filled,
            largest_filled_hole: im.largest_filled_hole,
            in_large_filled_holes: im.in_large_filled_holes,
        }
    }
}

/// One image's own exponents ([`Spectra::per_image`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ImageExponents {
    /// The image's label (its file).
    pub label: String,
    /// h(q = 0) from its own partition functions (null where the q grid
    /// has no 0 or the image no estimate).
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub h_q0: f64,
    /// tau(q = 2) likewise.
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub tau_q2: f64,
    /// The image's size `[ny, nx]` (`None` when the sums do not record it):
    /// images are compared with those of their size.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shape: Option<[usize; 2]>,
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
fn unlike_among(per_image: &[ImageExponents], classed: bool, groups: usize) -> Vec<String> {
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
fn recorded(known: usize, all: usize) -> String {
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

/// Runs of neighbouring q (adjacent in the q list) that carry a value:
/// per run its label (`q = a`, `q = a, b`, `q = a .. b`), the index of its
/// most extreme value (the largest `key`) and whether it holds several q.
fn runs(q: &[f64], v: &[Option<f64>], key: impl Fn(f64) -> f64) -> Vec<(String, usize, bool)> {
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
fn pick(jk: &[f64], reg: &[f64]) -> Vec<f64> {
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
fn cells_all_q(log2m: &[f64], q: &[f64]) -> Vec<Cell> {
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

fn cell(log2m: &[f64], q: f64) -> Cell {
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

struct Ensemble {
    log2_z: Vec<f64>,
    h: Vec<f64>,
    n_eff: Vec<f64>,
    lines: Vec<u64>,
}

impl Ensemble {
    /// Sets cell `c` from its non-empty parts in canonical order
    /// ([`canonical`]; at least one).
    fn set<'a>(&mut self, c: usize, parts: impl Iterator<Item = &'a Cell> + Clone) {
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
fn canonical(a: &Cell, b: &Cell) -> std::cmp::Ordering {
    a.e.cmp(&b.e)
        .then(a.z.total_cmp(&b.z))
        .then(a.zl.total_cmp(&b.zl))
        .then(a.z2.total_cmp(&b.z2))
}

struct Estimates {
    tau: Vec<f64>,
    tau_se: Vec<f64>,
    r2: Vec<f64>,
    slope_change: Vec<f64>,
    h: Vec<f64>,
    h_se: Vec<f64>,
    d: Vec<f64>,
    d_se: Vec<f64>,
}

impl Estimates {
    fn fit(ens: &Ensemble, log2_a: &[f64], in_fit: &[usize], q: &[f64]) -> Self {
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

/// Legendre transform of a sampled τ(q): `h = dτ/dq` by finite differences
/// (the slope of the parabola through three neighbouring points, one-sided
/// at the ends, so second-order everywhere on non-uniform grids; two
/// points give their chord), `D = q h - τ` (SPEC §4).
///
/// `q` must be strictly increasing, as [`check_q`] ensures for every grid
/// the crate builds: a repeated q gives a non-finite `h` there.
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
fn parabola_slope(x: &[f64], y: &[f64], t: f64) -> f64 {
    (0..3)
        .map(|k| {
            let (l, m) = ((k + 1) % 3, (k + 2) % 3);
            y[k] * ((t - x[l]) + (t - x[m])) / ((x[k] - x[l]) * (x[k] - x[m]))
        })
        .sum()
}

/// The spectra of an ensemble, ready for output (SPEC §13 `spectra.json`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Spectra {
    /// Which modulus the lines contributed (sup rule or plain; SPEC §4).
    pub rule: Rule,
    /// Number of images in the ensemble.
    pub images: usize,
    /// The image sizes and how many images have each (empty when the sums
    /// do not record them).
    #[serde(default)]
    pub image_shapes: Vec<ShapeCount>,
    /// The q values.
    #[serde(deserialize_with = "crate::nan_null::vec")]
    pub q: Vec<f64>,
    /// Fit range in octaves above a_min as asked (`--fit`; HI equal to the
    /// octaves the grid spans means its top scale, one voice below).
    #[serde(deserialize_with = "crate::nan_null::pair")]
    pub fit_octaves: (f64, f64),
    /// The octaves above a_min of the first and last fitted scales.
    #[serde(default, deserialize_with = "crate::nan_null::pair")]
    pub fit_octaves_used: (f64, f64),
    /// The smallest and largest scales (px) inside the fit range.
    #[serde(deserialize_with = "crate::nan_null::pair")]
    pub fit_scales: (f64, f64),
    /// τ(q): slope of the annealed `log2 Z(q, a)` against `log2 a` over the
    /// fit range (SPEC §4); NaN where a fitted scale has no line.
    #[serde(deserialize_with = "crate::nan_null::vec")]
    pub tau: Vec<f64>,
    /// Standard error of τ(q): delete-one jackknife over images (>= 3
    /// images), else over the tiles of the counting domains when the sums
    /// were split ([`image_sums_tiled`]), else the regression's; also the
    /// regression's at a q where a leave-one-out sample has no estimate
    /// (`stderr_method` lists them).
    #[serde(deserialize_with = "crate::nan_null::vec")]
    pub tau_stderr: Vec<f64>,
    /// R^2 of the log2 Z fits.
    #[serde(deserialize_with = "crate::nan_null::vec")]
    pub tau_r2: Vec<f64>,
    /// How much the local slope of `log2 Z(q, a)` changes across the fit
    /// range (`stats::slope_change`; 0 for a pure power law); NaN where tau
    /// is. Flagged beyond [`SLOPE_CHANGE_WARN`].
    #[serde(default, deserialize_with = "crate::nan_null::vec")]
    pub tau_slope_change: Vec<f64>,
    /// Canonical h(q) and D(q) (slopes of h(q, a) and D(q, a)).
    #[serde(deserialize_with = "crate::nan_null::vec")]
    pub h: Vec<f64>,
    /// Standard error of h(q), as `tau_stderr`.
    #[serde(deserialize_with = "crate::nan_null::vec")]
    pub h_stderr: Vec<f64>,
    /// Canonical D(q), slope of `D(q, a)` against `log2 a` (JSON `D`).
    #[serde(rename = "D", deserialize_with = "crate::nan_null::vec")]
    pub d: Vec<f64>,
    /// Standard error of D(q), as `tau_stderr` (JSON `D_stderr`).
    #[serde(rename = "D_stderr", deserialize_with = "crate::nan_null::vec")]
    pub d_stderr: Vec<f64>,
    /// "jackknife over images" (>= 3 images), "jackknife over N tiles (S
    /// px)" (fewer than 3 images with tiles),
    /// "regression", or either jackknife followed by "; regression for q =
    /// ..." naming the q where the jackknife had no finite value (also a
    /// warning).
    pub stderr_method: String,
    /// h = dτ/dq, D = q h - τ.
    #[serde(deserialize_with = "crate::nan_null::vec")]
    pub legendre_h: Vec<f64>,
    /// D(h) by the Legendre route, `q h - τ` (JSON `legendre_D`).
    #[serde(rename = "legendre_D", deserialize_with = "crate::nan_null::vec")]
    pub legendre_d: Vec<f64>,
    /// `log2 a` of every scale (a in pixels), not only the fitted ones.
    #[serde(deserialize_with = "crate::nan_null::vec")]
    pub log2_scales: Vec<f64>,
    /// Per q, per scale.
    #[serde(rename = "log2_Z", deserialize_with = "crate::nan_null::vec2")]
    pub log2_z: Vec<Vec<f64>>,
    /// `h(q, a) = Σ_L W_L log2 M_L`, annealed, per q, per scale (NaN where
    /// no line).
    #[serde(deserialize_with = "crate::nan_null::vec2")]
    pub h_qa: Vec<Vec<f64>>,
    /// `D(q, a) = q h(q, a) - log2 Z(q, a)`, per q, per scale (JSON `D_qa`).
    #[serde(rename = "D_qa", deserialize_with = "crate::nan_null::vec2")]
    pub d_qa: Vec<Vec<f64>>,
    /// Effective number of lines `Z^2 / Σ M^2q` per q, per scale.
    #[serde(deserialize_with = "crate::nan_null::vec2")]
    pub n_eff: Vec<Vec<f64>>,
    /// Maxima lines counted per scale (all images): those that reach a
    /// second scale, at their points inside the counting domain, the lines
    /// `Z(q, a)` sums over (the skeleton's [`crate::skeleton::ScaleCounts`]
    /// `lines` counts every line alive, wherever it lies).
    pub lines: Vec<u64>,
    /// Each image's own h(q = 0) and tau(q = 2), from its partition
    /// functions alone, when there are [`UNLIKE_MIN_IMAGES`] or more
    /// (the unlike-image test, [`unlike_images`]); empty otherwise.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub per_image: Vec<ImageExponents>,
    /// What the sums record of each image, in their order: size, missing
    /// pixels, plane share, terrace width, flat value (the numbers behind
    /// the warnings, which name only the worst; `sums.json` holds the same).
    #[serde(default)]
    pub image_records: Vec<ImageRecord>,
    /// Human-readable warnings: q not estimable, curved log2 Z (local slope
    /// changing by more than [`SLOPE_CHANGE_WARN`]), cells dominated by few
    /// lines (below [`N_EFF_WARN`]), runs of neighbouring q in one warning,
    /// missing pixels, mixed image sizes, few lines at the top of the fit.
    pub warnings: Vec<String>,
}

/// A number of images of one size.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct ShapeCount {
    /// Rows.
    pub ny: usize,
    /// Columns.
    pub nx: usize,
    /// Number of images of this size.
    pub images: usize,
}

impl ShapeCount {
    /// The distinct sizes `[ny, nx]` among `shapes`, with their counts,
    /// largest first (outputs record them: an ensemble may mix sizes).
    pub fn tally(shapes: impl IntoIterator<Item = [usize; 2]>) -> Vec<ShapeCount> {
        let mut m = std::collections::BTreeMap::new();
        for s in shapes {
            *m.entry(s).or_insert(0usize) += 1;
        }
        m.into_iter()
            .rev()
            .map(|([ny, nx], images)| ShapeCount { ny, nx, images })
            .collect()
    }
}

/// The default q grid of the CLI (`--q -4:6:0.5`): -4, -3.5, .., 6 (21
/// values), the range over which the published tau(q) are compared with
/// the theory (`wtmm validate` widens it to each model's published range).
pub fn default_q() -> Vec<f64> {
    (-8..=12).map(|i| 0.5 * i as f64).collect()
}

/// The default fit range, in octaves above a_min, for a grid of `octaves`
/// octaves of `voices` voices (the CLI's `--fit` default): from the first
/// scale at or above half an octave to `min(octaves, 4)`, the paper's
/// "first four octaves" (II §3) less the first half octave, where the
/// pixel-sampled transform and the lines born at a_min bias the local
/// slopes (README "How the defaults were chosen"). `(0.5, 4.0)` for the
/// default 5 octaves of 10 voices; `(2/3, 4)` with 3 voices. A grid
/// too short for that gives an empty range, never an inverted one
/// (`(0, 0)` for no octave, `(1, 1)` for one octave of one voice), which
/// the fit refuses as holding too few scales.
pub fn default_fit(octaves: usize, voices: usize) -> (f64, f64) {
    let v = voices.max(1) as f64;
    let hi = (octaves as f64).min(4.0);
    (((0.5 * v - 1e-9).ceil() / v).min(hi), hi)
}

impl PartitionSums {
    /// The octaves the scales span, the last scale plus one step (a grid
    /// of 4 octaves spans 4), and that step in octaves (0 for one scale).
    pub(crate) fn grid_span(&self) -> (f64, f64) {
        let n = self.scales.len();
        let step = if n > 1 {
            (self.scales[1] / self.scales[0]).log2()
        } else {
            0.0
        };
        let span = match (self.scales.first(), self.scales.last()) {
            (Some(a0), Some(a1)) => (a1 / a0).log2() + step,
            _ => 0.0,
        };
        (span, step)
    }

    /// [`default_fit`] for the grid of these sums: its whole octaves and
    /// its voices, read from the scales (the last scale is one voice short
    /// of the grid's octaves). Scales off a regular grid (a list given as
    /// `AnalysisConfig::scales`) get the ends moved onto scales of theirs,
    /// inwards, as [`Self::spectra`] requires: the first scale at or above
    /// the low end, the last at or below the high end.
    ///
    /// **Errors** if the scales span less than one octave, or a sparse
    /// list holds no scale in the range (its ends would cross).
    pub fn default_fit(&self) -> Result<(f64, f64)> {
        let (lo, hi) = self.grid_default_fit()?;
        let (top, _) = self.grid_span();
        let a0 = self.scales[0];
        let octs: Vec<f64> = self.scales.iter().map(|a| (a / a0).log2()).collect();
        let near = |a: f64, b: f64| (a - b).abs() <= 1e-6;
        let lo = octs
            .iter()
            .copied()
            .find(|&o| o >= lo || near(o, lo))
            .map_or(lo, |o| if near(o, lo) { lo } else { o });
        let hi = if near(hi, top) {
            hi
        } else {
            octs.iter()
                .copied()
                .rev()
                .find(|&o| o <= hi || near(o, hi))
                .map_or(hi, |o| if near(o, hi) { hi } else { o })
        };
        // a sparse list can move the ends past each other (an empty range
        // stays a range, refused by the fit as too few scales, as on a grid)
        if lo > hi + 1e-6 {
            return Err(Error::param(
                "fit",
                format!(
                    "the scales hold none in the default fit range (moved onto them it reads \
                     {}:{} octaves above the first): give the range",
                    octave_arg(lo),
                    octave_arg(hi)
                ),
            ));
        }
        Ok((lo, hi))
    }

    /// [`default_fit`] of the regular grid the scales' span and first step
    /// describe.
    fn grid_default_fit(&self) -> Result<(f64, f64)> {
        let (span, step) = self.grid_span();
        let octaves = (span + 1e-6).floor();
        if !(octaves >= 1.0) {
            return Err(Error::param(
                "fit",
                format!("the sums span {span:.3} octaves, less than one: give the range"),
            ));
        }
        let voices = if step > 0.0 {
            (1.0 / step).round().max(1.0)
        } else {
            1.0
        };
        Ok(default_fit(octaves as usize, voices as usize))
    }

    /// Reads sums written by [`PartitionSums::write_json`] (`sums.json` of
    /// `wtmm analyze` and `validate`), checked with [`PartitionSums::check`].
    ///
    /// **Errors** naming the file if it cannot be read, is not a
    /// partition-sums file, or fails the check.
    pub fn read_json(path: impl AsRef<std::path::Path>) -> Result<PartitionSums> {
        let path = path.as_ref();
        let text = std::fs::read_to_string(path).map_err(|source| Error::Read {
            path: path.to_path_buf(),
            source,
        })?;
        let s: PartitionSums = serde_json::from_str(&text)
            .map_err(|e| Error::format(path, format!("not a partition-sums file: {e}")))?;
        s.check()
            .map_err(|e| Error::format(path, format!("invalid partition sums: {e}")))?;
        Ok(s)
    }

    /// Writes the sums as compact JSON (atomically: a complete file or
    /// none), to be merged later with [`PartitionSums::read_json`] and
    /// [`PartitionSums::merge`].
    pub fn write_json(&self, path: impl AsRef<std::path::Path>) -> Result<()> {
        crate::io::write_json_compact(path.as_ref(), self)
    }

    /// The distinct recorded image sizes, with their counts, largest first.
    pub fn image_shapes(&self) -> Vec<ShapeCount> {
        ShapeCount::tally(self.images.iter().filter_map(|p| p.shape))
    }
}

impl Spectra {
    /// Index of q closest to `q0` (`None` for a NaN `q0` or an empty grid).
    pub fn q_index(&self, q0: f64) -> Option<usize> {
        if q0.is_nan() {
            return None;
        }
        (0..self.q.len()).min_by(|&a, &b| (self.q[a] - q0).abs().total_cmp(&(self.q[b] - q0).abs()))
    }
}

/// One image through the pipeline: CWT → skeleton → partition sums.
/// Serial inside (parallelise over images).
///
/// **Errors** on a q grid [`check_q`] refuses, as
/// [`crate::skeleton::skeleton_with`], or when the image has no maxima
/// line at the smallest scale (with its likely cause:
/// [`crate::skeleton::AnalysisConfig::why_no_maxima`]).
pub fn image_sums(
    field: &crate::Field,
    cfg: &crate::skeleton::AnalysisConfig,
    q: &[f64],
    label: impl Into<String>,
) -> Result<PartitionSums> {
    image_sums_with(field, cfg, q, label, crate::skeleton::Parallelism::Serial)
}

/// [`image_sums`] with the scales detected in parallel or not
/// ([`crate::skeleton::Parallelism`]; the sums are the same bits either
/// way): `Scales` for a lone image, `Serial` when images run in parallel.
///
/// **Errors** as [`image_sums`].
pub fn image_sums_with(
    field: &crate::Field,
    cfg: &crate::skeleton::AnalysisConfig,
    q: &[f64],
    label: impl Into<String>,
    par: crate::skeleton::Parallelism,
) -> Result<PartitionSums> {
    image_sums_tiled(field, cfg, q, label, par, 0)
}

/// [`image_sums_with`], the sums also split over tiles of about
/// `tile_side` px of the counting domain
/// ([`PartitionSums::from_skeleton_tiled`]; 0 for none): the jackknife
/// groups when fewer than 3 images make the ensemble
/// ([`default_tile_side`]).
///
/// **Errors** as [`image_sums`], and on tiles narrower than twice the
/// largest scale (the smallest [`default_tile_side`] gives: neighbouring
/// tiles share their maxima lines, and a jackknife over them would
/// understate the errors).
pub fn image_sums_tiled(
    field: &crate::Field,
    cfg: &crate::skeleton::AnalysisConfig,
    q: &[f64],
    label: impl Into<String>,
    par: crate::skeleton::Parallelism,
    tile_side: usize,
) -> Result<PartitionSums> {
    // before the transform, not at the fit: a bad grid costs nothing
    check_q(q)?;
    cfg.validate()?;
    field.check()?;
    check_tile_side(
        tile_side,
        cfg.a_max(),
        "tiles that share their maxima lines are no jackknife groups",
    )?;
    let sk = crate::skeleton::skeleton_with(field, cfg, par, &[])?;
    let sums = skeleton_sums_tiled(&sk, field, cfg, q, label, tile_side);
    // an image with no line adds nothing to an ensemble: said at once, with
    // its likely cause, not as an empty fit later
    if sums.images[0].lines.first().is_none_or(|&n| n == 0) {
        return Err(Error::Input(cfg.why_no_maxima(field)));
    }
    Ok(sums)
}

/// The partition sums of an ensemble of fields held in memory, made as
/// `wtmm analyze` makes them from files: one image at a time in parallel
/// (a lone image's scales in parallel instead), and, with fewer than 3
/// images, each split into the tiles of [`default_tile_side`] so that the
/// jackknife runs over them. `spectra` of the result gives tau(q), h(q),
/// D(q) with the errors `analyze` reports. Image `i` is labelled `image i`.
///
/// **Errors** with no field, or as [`image_sums_tiled`] (naming the image).
pub fn ensemble_sums(
    fields: &[crate::Field],
    cfg: &crate::skeleton::AnalysisConfig,
    q: &[f64],
) -> Result<PartitionSums> {
    check_q(q)?;
    // before sizing tiles from it
    cfg.validate()?;
    let par = if fields.len() == 1 {
        crate::skeleton::Parallelism::Scales
    } else {
        crate::skeleton::Parallelism::Serial
    };
    // the first bad field in order is named, whatever the scheduling
    let parts = crate::par::try_map(fields.len(), |i| {
        let f = &fields[i];
        let side = if fields.len() < 3 {
            let (ny, nx) = f.dim();
            default_tile_side(cfg, ny, nx)
        } else {
            0
        };
        image_sums_tiled(f, cfg, q, format!("image {i}"), par, side).map_err(|e| match e {
            Error::Input(m) => Error::Input(format!("image {i}: {m}")),
            e => e,
        })
    })?;
    PartitionSums::merge_all(parts)?.ok_or_else(|| Error::Input("no field given".into()))
}

/// The tiles of the jackknife of an ensemble of fewer than 3 images of
/// `ny x nx`: 4 times the largest analysed scale, or twice it when fewer
/// than 4 such tiles fit in the counting domain. Measured (24 single
/// images each, `experiment_lone_image_errors` in tests/spectra.rs): the
/// root-mean-square error they report over the scatter of tau(q) between
/// the images, at q = -2, 0, 2, 4, is 0.86 / 1.12 / 0.94 / 0.80 on fBm
/// 1024^2 (16 tiles), 1.16 / 1.12 / 1.21 / 1.15 on paper-lognormal
/// 1024^2 (25 tiles), 0.68 / 0.96 / 1.29 / 1.05 on fBm 512^2 (4 tiles of
/// 2 a_max), where the regression's error was 0.10-0.39 of it.
pub fn default_tile_side(cfg: &crate::skeleton::AnalysisConfig, ny: usize, nx: usize) -> usize {
    // (saturating: an absurd grid or margin is refused by the analysis,
    // with its reason, not by an overflow here)
    let a_max = cfg.a_max();
    let m = cfg.margin_px().saturating_mul(2);
    let (h, w) = (ny.saturating_sub(m), nx.saturating_sub(m));
    let side = (4.0 * a_max).ceil() as usize;
    if side > 0 && (h / side) * (w / side) >= 4 {
        side
    } else {
        (2.0 * a_max).ceil() as usize
    }
}

/// "q = a .. b", or "q = a" when the span is one q.
fn q_span(a: f64, b: f64) -> String {
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
const LEGENDRE_WARN_SE: f64 = 3.0;
/// See [`LEGENDRE_WARN_SE`].
const LEGENDRE_NOTE_SE: f64 = 2.0;

/// How a departure of `k` standard errors reads in [`legendre_warnings`].
fn departure(k: f64) -> String {
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
fn legendre_warnings(q: &[f64], est: &Estimates, reps: &[Estimates]) -> Vec<String> {
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

/// Largest |q| of a partition-sum grid. The sums keep `M^q` as a mantissa
/// and a binary exponent near `q log2 M`, bounded by 2^30 so that exponent
/// differences fit an `i32`; with any modulus an f64 holds (|log2 M| <=
/// 1075) that bounds |q| near 1e6.
/// Published spectra use |q| <= 10, and no finite ensemble resolves
/// moments of order thousands; 1e4 leaves room and the arithmetic exact.
pub const MAX_ABS_Q: f64 = 1e4;

/// A q grid the partition sums can use: non-empty, finite, strictly
/// ascending (the Legendre transform differences neighbours; a repeated q
/// would count twice), |q| <= [`MAX_ABS_Q`].
///
/// **Errors** naming `q`.
pub fn check_q(q: &[f64]) -> Result<()> {
    if q.is_empty() || !q.iter().all(|x| x.is_finite()) || q.windows(2).any(|w| w[0] >= w[1]) {
        return Err(Error::param(
            "q",
            "must be a non-empty list of finite values in ascending order, none twice",
        ));
    }
    if let Some(x) = q.iter().find(|x| x.abs() > MAX_ABS_Q) {
        return Err(Error::param(
            "q",
            format!(
                "{} is beyond +-{MAX_ABS_Q}: moments of such orders overflow the partition \
                 sums' exponents, and no ensemble resolves them (published spectra use |q| <= 10)",
                crate::error::short(*x)
            ),
        ));
    }
    Ok(())
}

/// [`image_sums`] of a skeleton already built from `field` with `cfg` (a
/// pass that wants more than the sums from one transform).
pub fn skeleton_sums(
    sk: &crate::skeleton::Skeleton,
    field: &crate::Field,
    cfg: &crate::skeleton::AnalysisConfig,
    q: &[f64],
    label: impl Into<String>,
) -> PartitionSums {
    skeleton_sums_tiled(sk, field, cfg, q, label, 0)
}

/// An octave for a `--fit` the user may type back: 9 decimals, trailing
/// zeros trimmed (2/3 octave reads 0.666666667, within the 1e-6 the fit
/// ends are matched to; [`short`]'s 6 digits are not).
fn octave_arg(o: f64) -> String {
    let s = format!("{o:.9}");
    s.trim_end_matches('0').trim_end_matches('.').to_string()
}

/// Refuses a jackknife tile side (0: no tiles) narrower than twice the
/// largest scale `a_max`, saying `why` such tiles are no groups.
pub(crate) fn check_tile_side(tile_side: usize, a_max: f64, why: &str) -> Result<()> {
    let min_side = (2.0 * a_max).ceil() as usize;
    if tile_side > 0 && tile_side < min_side {
        return Err(Error::param(
            "tile_side",
            format!(
                "{tile_side} px is narrower than twice the largest scale ({min_side} px at a = \
                 {a_max:.1} px): {why}; give 0 (no tiles) or at least {min_side} \
                 (default_tile_side)"
            ),
        ));
    }
    Ok(())
}

/// [`skeleton_sums`] split over tiles too ([`image_sums_tiled`]). The
/// side is not checked here: [`image_sums_tiled`] refuses one narrower
/// than twice the largest scale, which makes tiles that are no
/// independent samples, and many of them (one set of sums each).
pub fn skeleton_sums_tiled(
    sk: &crate::skeleton::Skeleton,
    field: &crate::Field,
    cfg: &crate::skeleton::AnalysisConfig,
    q: &[f64],
    label: impl Into<String>,
    tile_side: usize,
) -> PartitionSums {
    let mut s = PartitionSums::from_skeleton_tiled(sk, q, label, tile_side);
    s.analysis = Some(cfg.clone());
    let (ny, nx) = field.dim();
    s.images[0].missing = (ny * nx - field.valid_count()) as u64;
    s.images[0].plane_share = field.plane_share();
    (s.images[0].terrace_width, s.images[0].flat) = quantisation(field);
    s
}

/// An image's [`crate::Field::terraces`], the flat value as the record
/// [`ImagePartial`] keeps.
pub(crate) fn quantisation(field: &crate::Field) -> (Option<f64>, Option<FlatRecord>) {
    let (width, flat) = field.terraces();
    (
        width,
        flat.map(|(value, share)| FlatRecord { value, share }),
    )
}

/// An analysis as merging sees it: the scales are compared on their own
/// (explicit scales equal to a grid are that grid), and the margin in the
/// pixels it resolves to (the default for the wavelet and the largest
/// scale, or the same number given explicitly, is one margin).
fn same_analysis(c: &crate::skeleton::AnalysisConfig) -> crate::skeleton::AnalysisConfig {
    let d = crate::skeleton::AnalysisConfig::default();
    crate::skeleton::AnalysisConfig {
        margin: Some(c.margin_px()),
        scales: None,
        a_min: d.a_min,
        octaves: d.octaves,
        voices: d.voices,
        ..c.clone()
    }
}

/// The fields in which two analyses differ, as `key: a vs b`.
fn config_difference(
    a: &crate::skeleton::AnalysisConfig,
    b: &crate::skeleton::AnalysisConfig,
) -> String {
    let (ja, jb) = (serde_json::json!(a), serde_json::json!(b));
    let mut d: Vec<String> = Vec::new();
    if let (Some(ma), Some(mb)) = (ja.as_object(), jb.as_object()) {
        for (k, va) in ma {
            let vb = mb.get(k).unwrap_or(&serde_json::Value::Null);
            if va != vb {
                d.push(format!("{k}: {va} vs {vb}"));
            }
        }
    }
    d.join("; ")
}

/// The indices of the scales inside the fit range `fit` (octaves above the
/// smallest scale), so that a command can refuse a range holding fewer than
/// 3 scales before it analyses anything.
///
/// **Errors** if fewer than 3 scales fall in it.
pub fn fit_indices(scales: &[f64], fit: (f64, f64)) -> Result<Vec<usize>> {
    let ns = scales.len();
    let log2_a: Vec<f64> = scales.iter().map(|a| a.log2()).collect();
    let oct0 = log2_a.first().copied().unwrap_or(0.0);
    let in_fit: Vec<usize> = (0..ns)
        .filter(|&j| {
            let o = log2_a[j] - oct0;
            o >= fit.0 - 1e-9 && o <= fit.1 + 1e-9
        })
        .collect();
    if in_fit.len() < 3 {
        return Err(Error::param(
            "fit",
            format!(
                "only {} scales in the fit range {}:{} octaves, need 3 (the {ns} scales span \
                 {:.2} octaves above the smallest; widen --fit, or give more --voices or \
                 --octaves)",
                in_fit.len(),
                crate::error::short(fit.0),
                crate::error::short(fit.1),
                log2_a.last().map_or(0.0, |l| l - oct0)
            ),
        ));
    }
    Ok(in_fit)
}

/// `x` to 9 decimals: octaves computed as differences of logarithms carry
/// float noise (3.8999999999999995 for 3.9) that would read as a value.
fn round9(x: f64) -> f64 {
    (x * 1e9).round() / 1e9
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The default fit: half an octave (rounded up to a voice) to four
    /// octaves; a grid too short gives an empty range, never an inverted one.
    #[test]
    fn default_fit_is_never_inverted() {
        assert_eq!(default_fit(5, 10), (0.5, 4.0));
        assert_eq!(default_fit(3, 3), (2.0 / 3.0, 3.0));
        assert_eq!(default_fit(0, 10), (0.0, 0.0));
        assert_eq!(default_fit(1, 1), (1.0, 1.0));
        for octaves in 0..7 {
            for voices in 0..13 {
                let (lo, hi) = default_fit(octaves, voices);
                assert!(lo <= hi && hi <= 4.0, "{octaves} {voices}: {lo} {hi}");
            }
        }
    }

    /// h(q) rising with q and D(q) above 2 are said when they exceed their
    /// errors, as real beyond 3 of them, and not for a concave spectrum.
    #[test]
    fn legendre_warnings_read_the_errors() {
        let q = [-2.0, -1.0, 0.0, 1.0, 2.0];
        let est = |h: &[f64], d: &[f64], se: f64| Estimates {
            tau: vec![0.0; 5],
            tau_se: vec![se; 5],
            r2: vec![1.0; 5],
            slope_change: vec![0.0; 5],
            h: h.to_vec(),
            h_se: vec![se; 5],
            d: d.to_vec(),
            d_se: vec![se; 5],
        };
        // concave (h falls) and D <= 2: nothing
        let ok = est(
            &[0.5, 0.45, 0.4, 0.35, 0.3],
            &[1.8, 1.95, 2.0, 1.95, 1.8],
            0.01,
        );
        assert!(legendre_warnings(&q, &ok, &[]).is_empty());
        // h rises by 0.2 from q = -1 to 2, D reaches 2.2: with errors of
        // 0.01 (0.02 for the difference) that is 10 errors, real
        let h = [0.5, 0.3, 0.35, 0.4, 0.5];
        let d = [1.8, 1.95, 2.0, 2.1, 2.2];
        let w = legendre_warnings(&q, &est(&h, &d, 0.01), &[]);
        assert_eq!(w.len(), 2, "{w:?}");
        assert!(
            w[0].starts_with(
                "h(q) rises from 0.300 at q = -1 to 0.500 at q = 2 (+0.200 +- 0.020, \
                 10.0 standard errors)"
            ),
            "{}",
            w[0]
        );
        assert!(
            w[1].starts_with(
                "D(q) > 2 at 2 of the q (most clearly D = 2.200 +- 0.010 at q = 2, 20.0"
            ),
            "{}",
            w[1]
        );
        // errors of 0.04 (0.08 for the difference): the rise is 2.5
        // errors, said as possibly noise; D 5 above 2, real
        let w = legendre_warnings(&q, &est(&h, &d, 0.04), &[]);
        assert!(
            w[0].contains("2.5 standard errors, so it may be noise"),
            "{}",
            w[0]
        );
        assert!(w[1].contains("5.0 standard errors;"), "{}", w[1]);
        // errors of 0.11: the rise within one error, D 1.8 errors above 2:
        // nothing
        assert!(legendre_warnings(&q, &est(&h, &d, 0.11), &[]).is_empty());
        // 3 or more jackknife replicates give the difference's own error:
        // h(2) - h(1) = 0.4 + 0.1 k over 4 replicates, se sqrt(3/4 x 0.05)
        let h = [0.5, 0.45, 0.4, 0.35, 0.75];
        let reps: Vec<Estimates> = (0..4)
            .map(|k| {
                let mut hk = h;
                hk[4] += 0.1 * k as f64;
                est(&hk, &d, 0.01)
            })
            .collect();
        let w = legendre_warnings(&q, &est(&h, &d, 0.01), &reps);
        assert!(
            w[0].contains("from 0.350 at q = 1 to 0.750 at q = 2 (+0.400 +- 0.194, 2.1 standard"),
            "{}",
            w[0]
        );
        // the rise that counts is the largest against its error: 0.05 +-
        // 0.01 from q = 0 to 1, not 0.15 +- 0.4 from q = -3 to -2 (an
        // independent review's probe)
        let q7 = [-4.0, -3.0, -2.0, -1.0, 0.0, 1.0, 2.0];
        let se7 = [0.2, 0.2, 0.005, 0.005, 0.005, 0.005, 0.005];
        let e7 = Estimates {
            tau: vec![0.0; 7],
            tau_se: se7.to_vec(),
            r2: vec![1.0; 7],
            slope_change: vec![0.0; 7],
            h: vec![0.5, 0.6, 0.45, 0.40, 0.35, 0.40, 0.30],
            h_se: se7.to_vec(),
            d: vec![1.9; 7],
            d_se: se7.to_vec(),
        };
        let w = legendre_warnings(&q7, &e7, &[]);
        assert!(
            w[0].starts_with(
                "h(q) rises from 0.350 at q = 0 to 0.400 at q = 1 (+0.050 +- 0.010, 5.0"
            ),
            "{}",
            w[0]
        );
        // the whole fold is said too when it is larger than the most
        // significant rise (and itself beyond its errors), with the D it
        // reaches: +0.04 +- 0.01 from q = -2 to 0 is the clearest, +0.06
        // +- 0.025 to q = 1 the largest, +0.08 +- 0.045 to q = 2 within
        // 2 errors; D reaches 2.2 at q = 1, not 2.1 at q = 0
        let se = [0.005, 0.005, 0.005, 0.005, 0.005, 0.02, 0.04];
        let e = Estimates {
            h: vec![0.5, 0.45, 0.40, 0.42, 0.44, 0.46, 0.48],
            h_se: se.to_vec(),
            d: vec![1.9, 1.95, 2.0, 2.05, 2.1, 2.2, 2.3],
            d_se: vec![0.5; 7],
            ..e7
        };
        let w = legendre_warnings(&q7, &e, &[]);
        assert!(
            w[0].starts_with(
                "h(q) rises from 0.400 at q = -2 to 0.440 at q = 0 (+0.040 +- 0.010, 4.0 \
                 standard errors; in all from 0.400 at q = -2 to 0.460 at q = 1, +0.060 +- \
                 0.025)"
            ),
            "{}",
            w[0]
        );
        assert!(w[0].contains("(D reaches 2.200)"), "{}", w[0]);
        // a D of NaN throughout is not quoted
        let e = Estimates {
            d: vec![f64::NAN; 7],
            ..e
        };
        let w = legendre_warnings(&q7, &e, &[]);
        assert!(w[0].contains("over those q; the fit range"), "{}", w[0]);
    }

    /// A flip maps the tiles onto the tiles (the centre row of an odd side
    /// in an even number of tiles excepted), every cut lies within half a
    /// pixel of `t len / n`, no tile is empty, and `slot` inverts the cuts.
    #[test]
    fn tile_cuts_are_mirror_symmetric() {
        for len in 1..=160usize {
            for n in 1..=len {
                assert_eq!((cut(0, len, n), cut(n, len, n)), (0, len));
                for t in 0..=n {
                    let c = cut(t, len, n);
                    let exact = (t * len) as f64 / n as f64;
                    assert!(
                        (c as f64 - exact).abs() <= 0.5,
                        "{len} {n} {t}: {c} for {exact}"
                    );
                    if t < n {
                        assert!(c < cut(t + 1, len, n), "{len} {n}: tile {t} empty");
                    }
                    let centre = 2 * t == n && len % 2 == 1;
                    assert_eq!(
                        c + cut(n - t, len, n) == len,
                        !centre,
                        "{len} {n} {t}: cuts {c} and {}",
                        cut(n - t, len, n)
                    );
                }
                for v in 0..len + 3 {
                    let t = slot(v, len, n);
                    assert!(t < n, "{len} {n} {v}");
                    assert!(cut(t, len, n) <= v, "{len} {n} {v}");
                    assert!(v < cut(t + 1, len, n) || t == n - 1, "{len} {n} {v}");
                }
            }
        }
    }

    /// A tile's bounds hold exactly the domain's pixels `index` puts in it,
    /// for sides that do and do not divide the domain.
    #[test]
    fn tile_bounds_agree_with_index() {
        for (dom, side) in [
            ((0, 20, 0, 31), 7),
            ((3, 40, 5, 17), 12),
            ((0, 9, 0, 9), 3),
            ((2, 29, 1, 30), 10),
        ] {
            let g = TileGrid::new(dom, side).unwrap();
            let mut seen = 0;
            for k in 0..g.len() {
                let (ya, yb, xa, xb) = g.bounds(k);
                assert!(ya < yb && xa < xb, "{dom:?} {side}: tile {k} empty");
                for y in ya..yb {
                    for x in xa..xb {
                        assert_eq!(g.index(x as u32, y as u32), k, "{dom:?} {side}");
                        seen += 1;
                    }
                }
            }
            assert_eq!(seen, (dom.1 - dom.0) * (dom.3 - dom.2), "{dom:?} {side}");
            // the table, over an image that holds the domain and more
            let (ny, nx) = (dom.1 + 3, dom.3 + 2);
            let t = g.table(ny, nx);
            for y in 0..ny {
                for x in 0..nx {
                    assert_eq!(t.at(y, x), g.index(x as u32, y as u32), "{dom:?} {side}");
                }
            }
        }
        // a domain that is the whole image: past its edge, `index` takes
        // the edge's tile (what tm's clamped lookups rely on)
        let (ny, nx) = (37, 29);
        let g = TileGrid::new((0, ny, 0, nx), 10).unwrap();
        let t = g.table(ny, nx);
        for (y, x) in [(ny, 3), (5, nx + 40), (ny + 100, nx)] {
            let c = t.at(y.min(ny - 1), x.min(nx - 1));
            assert_eq!(c, g.index(x as u32, y as u32), "{y} {x}");
        }
    }

    /// A tile past the last is a panic in every build (it recursed until
    /// the stack overflowed in release builds, an abort no caller can catch).
    #[test]
    #[should_panic(expected = "tile 1000 of 100")]
    fn a_tile_past_the_last_panics() {
        TileGrid::new((0, 100, 0, 100), 10).unwrap().bounds(1000);
    }

    /// The batched leave-one-out ensembles are `ensemble(rule, Some(i))`
    /// to the bit: random cells with repeats (equal cells), empty cells and
    /// exponents far apart, 3-152 images, whole and partial batches (an
    /// independent review's probe).
    #[test]
    fn batched_leave_one_out_is_bit_identical() {
        let mut seed = 7u64;
        let mut next = move || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            seed >> 11
        };
        for _ in 0..60 {
            let n_img = 3 + (next() % 150) as usize;
            let (ns, q) = (4, vec![-2.0, 0.0, 3.0]);
            let nc = q.len() * ns;
            let pool: Vec<Cell> = (0..6)
                .map(|k| Cell {
                    e: (next() % 5) as i32 - 2,
                    z: 0.5 + k as f64 * 0.1 + (next() % 1000) as f64 * 1e-3,
                    zl: (next() % 1000) as f64 * 1e-2 - 5.0,
                    z2: 0.3,
                })
                .collect();
            let mut cell = || match next() % 10 {
                0 | 1 => Cell::EMPTY,
                2..=4 => pool[(next() % 6) as usize],
                _ => Cell {
                    e: (next() % 40) as i32 - 20,
                    z: 1.0 + (next() % 1_000_000) as f64 / 7.0,
                    zl: (next() % 1_000_000) as f64 / 3.0 - 1e5,
                    z2: (next() % 1_000_000) as f64 / 11.0,
                },
            };
            let images: Vec<ImagePartial> = (0..n_img)
                .map(|i| ImagePartial {
                    label: format!("{i}"),
                    shape: None,
                    missing: 0,
                    lines: vec![5; ns],
                    sup: (0..nc).map(|_| cell()).collect(),
                    plain: (0..nc).map(|_| cell()).collect(),
                    tiles: vec![],
                    tile_side: 0,
                    plane_share: None,
                    terrace_width: None,
                    flat: None,
                    nodata: None,
                    filled: 0,
                    largest_filled_hole: 0,
                    in_large_filled_holes: 0,
                })
                .collect();
            let s = PartitionSums {
                version: "1".into(),
                analysis: None,
                q,
                scales: vec![1.0, 2.0, 4.0, 8.0],
                images,
                pixel: None,
            };
            for rule in [Rule::Sup, Rule::Plain] {
                for range in [0..n_img, 1..3] {
                    let batch = s.ensembles_leaving_out(rule, range.clone());
                    for (b, i) in batch.iter().zip(range) {
                        let one = s.ensemble(rule, Some(i));
                        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                        assert_eq!(bits(&one.log2_z), bits(&b.log2_z));
                        assert_eq!(bits(&one.h), bits(&b.h));
                        assert_eq!(bits(&one.n_eff), bits(&b.n_eff));
                        assert_eq!(one.lines, b.lines);
                    }
                }
            }
        }
    }

    /// Lines whose modulus grows like a^h at every q; the sums say which
    /// wavelet made them.
    fn power_law_sums(h: f64, wavelet: crate::cwt::Wavelet) -> PartitionSums {
        let scales: Vec<f64> = (0..41).map(|j| 1.5 * 2f64.powf(j as f64 / 10.0)).collect();
        let values: Vec<Vec<f64>> = scales
            .iter()
            .map(|&a| {
                // whole cycles of the 7 offsets: the same spread at every scale
                let n = 7 * (600.0 / (a / 1.5).powi(2)).ceil() as usize;
                (0..n)
                    .map(|k| h * a.log2() + ((k % 7) as f64 - 3.0) * 0.1)
                    .collect()
            })
            .collect();
        let q: Vec<f64> = (-4..=4).map(f64::from).collect();
        let mut s = PartitionSums::from_log2_values(&scales, &values, &q, "x").unwrap();
        // the analysis that makes these 41 scales
        s.analysis = Some(crate::skeleton::AnalysisConfig {
            wavelet,
            scales: Some(scales),
            ..Default::default()
        });
        s
    }

    /// The fill's warning on an ensemble: the images filled, their pixels,
    /// the share of all the images' pixels and the bias bound; no share
    /// when some image records no size (sums before 2026-11-22: a share of
    /// a missing area read 642800 %), and none without a fill.
    #[test]
    fn the_fill_is_said_for_the_ensemble() {
        let mut a = power_law_sums(0.3, crate::cwt::Wavelet::Gauss);
        let mut b = a.clone();
        assert_eq!(a.fill_warning(), None);
        a.images[0].label = "a".into();
        b.images[0].label = "b".into();
        for s in [&mut a, &mut b] {
            s.images[0].shape = Some([100, 100]);
        }
        // 300 px filled in a, 200 of them in one hole of 200 px
        a.images[0].filled = 300;
        a.images[0].largest_filled_hole = 200;
        a.images[0].in_large_filled_holes = 200;
        let both = PartitionSums::merge_all(vec![a.clone(), b.clone()])
            .unwrap()
            .unwrap();
        let w = both.fill_warning().unwrap();
        // 100 small of 20000 px (0.5 %, 0.0013) and 200 large (1.0 %, 0.0055)
        assert!(
            w.starts_with("1 of the 2 image(s) had missing pixels filled"),
            "{w}"
        );
        assert!(w.contains("300 in all, 1.5 % of the pixels"), "{w}");
        assert!(
            w.contains("(here up to +0.007)") && !w.contains("crop"),
            "{w}"
        );
        b.images[0].shape = None;
        let w = PartitionSums::merge_all(vec![a, b])
            .unwrap()
            .unwrap()
            .fill_warning()
            .unwrap();
        assert!(!w.contains('%') && w.contains("no share"), "{w}");
        assert!(w.contains("200 px lie in holes of more than 16 px"), "{w}");
    }

    /// `per_image` and the unlike-image test through [`PartitionSums::spectra`]:
    /// five images of pure power laws `M = a^h` (h = 0.30, 0.31, 0.29,
    /// 0.30, 0.80, the same counts) give each its own h(q=0) = h and
    /// tau(q=2) = 2h + the counts' exponent, and
    /// the fifth is named (the by-hand t = 54.8 of `unlike_images_by_hand`);
    /// a sixth image whose values stop below the fit's top has no estimate
    /// of its own, is left out and named, and the fifth is still named.
    #[test]
    fn per_image_exponents_and_the_unlike_test() {
        let scales: Vec<f64> = (0..41).map(|j| 1.5 * 2f64.powf(j as f64 / 10.0)).collect();
        let q: Vec<f64> = (-2..=4).map(f64::from).collect();
        let image = |h: f64, top: f64, label: &str| {
            let values: Vec<Vec<f64>> = scales
                .iter()
                .map(|&a| {
                    let n = if a <= top {
                        7 * (600.0 / (a / 1.5).powi(2)).ceil() as usize
                    } else {
                        0
                    };
                    vec![h * a.log2(); n]
                })
                .collect();
            PartitionSums::from_log2_values(&scales, &values, &q, label).unwrap()
        };
        let hs = [0.30, 0.31, 0.29, 0.30, 0.80];
        let mut sums = image(hs[0], 1e9, "a0");
        for (i, &h) in hs.iter().enumerate().skip(1) {
            sums.merge(&image(h, 1e9, &format!("a{i}"))).unwrap();
        }
        let sp = sums.spectra(Rule::Plain, (0.5, 4.0)).unwrap();
        assert_eq!(sp.per_image.len(), 5);
        // the counts n(a) are the same in every image, so tau(2) - 2h is too
        let t0 = sp.per_image[0].tau_q2 - 2.0 * hs[0];
        for (e, &h) in sp.per_image.iter().zip(&hs) {
            assert!((e.h_q0 - h).abs() < 1e-9, "{e:?}");
            assert!((e.tau_q2 - 2.0 * h - t0).abs() < 1e-9, "{e:?}");
        }
        let named: Vec<&String> = sp
            .warnings
            .iter()
            .filter(|w| w.contains("looks unlike"))
            .collect();
        assert!(
            named.len() == 1 && named[0].starts_with("a4 looks unlike"),
            "{named:?}"
        );
        // a sixth image whose lines end at 6 px, below the fit's top
        sums.merge(&image(0.3, 6.0, "short")).unwrap();
        let sp = sums.spectra(Rule::Plain, (0.5, 4.0)).unwrap();
        assert!(sp.per_image[5].h_q0.is_nan() && sp.per_image[5].tau_q2.is_nan());
        // JSON holds the NaN as null, and reads it back as NaN
        let text = serde_json::to_string(&sp).unwrap();
        assert!(text.contains("\"h_q0\":null"), "{text}");
        let back: Spectra = serde_json::from_str(&text).unwrap();
        assert!(back.per_image[5].h_q0.is_nan());
        assert_eq!(serde_json::to_string(&back).unwrap(), text);
        assert!(
            sp.warnings.iter().any(|w| w.starts_with("a4 looks unlike")),
            "{:?}",
            sp.warnings
        );
        assert!(
            sp.warnings
                .iter()
                .any(|w| w.starts_with("short: no h(q=0)")),
            "{:?}",
            sp.warnings
        );
        // below 4 images: no per-image exponents at all
        let three = {
            let mut s = image(0.3, 1e9, "b0");
            s.merge(&image(0.3, 1e9, "b1")).unwrap();
            s.merge(&image(0.8, 1e9, "b2")).unwrap();
            s
        };
        assert!(
            three
                .spectra(Rule::Plain, (0.5, 4.0))
                .unwrap()
                .per_image
                .is_empty()
        );
    }

    /// A power law is flagged by how much its local slope changes, not by
    /// R^2: Z(q, a) ~ a^tau with tau(4) = 0 exactly (h = 1/2) passes at
    /// every q, and log2 M = h L + c L^2 (L = log2 a) is flagged exactly
    /// where the slope of q log2 M changes by 2 c q (L_max - L_min) > 0.2.
    #[test]
    fn curved_partition_functions_are_flagged_flat_ones_not() {
        let sums = |c: f64| {
            let scales: Vec<f64> = (0..41).map(|j| 1.5 * 2f64.powf(j as f64 / 10.0)).collect();
            let values: Vec<Vec<f64>> = scales
                .iter()
                .map(|&a| {
                    // n ~ a^-2 to 0.3 % at the largest fitted scale
                    let n = 7 * (40000.0 / (a / 1.5).powi(2)).round() as usize;
                    let l = a.log2();
                    (0..n)
                        .map(|k| 0.5 * l + c * l * l + ((k % 7) as f64 - 3.0) * 0.1)
                        .collect()
                })
                .collect();
            let q: Vec<f64> = (-4..=4).map(f64::from).collect();
            PartitionSums::from_log2_values(&scales, &values, &q, "x")
                .unwrap()
                .spectra(Rule::Plain, (0.5, 4.0))
                .unwrap()
        };
        let flat = sums(0.0);
        let i4 = flat.q_index(4.0).unwrap();
        assert!(flat.tau[i4].abs() < 0.01, "tau(4) = {}", flat.tau[i4]);
        assert!(
            flat.tau_r2[i4] < 0.5,
            "R^2 {} would have flagged it",
            flat.tau_r2[i4]
        );
        assert!(flat.tau_slope_change.iter().all(|d| d.abs() < 0.01));
        assert!(
            !flat.warnings.iter().any(|w| w.contains("straight line")),
            "{:?}",
            flat.warnings
        );
        let c = 0.02;
        let curved = sums(c);
        let (lo, hi) = (curved.fit_scales.0.log2(), curved.fit_scales.1.log2());
        for (i, &qv) in curved.q.iter().enumerate() {
            let expect = 2.0 * c * qv * (hi - lo);
            assert!(
                (curved.tau_slope_change[i] - expect).abs() < 0.01,
                "q = {qv}: {} for {expect}",
                curved.tau_slope_change[i]
            );
        }
        let said: Vec<&String> = curved
            .warnings
            .iter()
            .filter(|w| w.contains("straight line"))
            .collect();
        assert_eq!(said.len(), 2, "{said:?}");
        assert!(
            said[0].starts_with("q = -4 .. -2: ") && said[0].contains("up to -0.56 (at q = -4)")
        );
        assert!(said[1].starts_with("q = 2 .. 4: ") && said[1].contains("up to +0.56 (at q = 4)"));
    }

    #[test]
    fn exponents_at_the_wavelet_order_are_flagged() {
        use crate::cwt::Wavelet;
        let flagged = |h: f64, w: Wavelet| {
            let sp = power_law_sums(h, w)
                .spectra(Rule::Plain, (0.5, 4.0))
                .unwrap();
            assert!(sp.h.iter().all(|x| (x - h).abs() < 1e-9), "{:?}", sp.h);
            sp.warnings.iter().any(|m| m.starts_with("h(q) >= "))
        };
        assert!(flagged(1.2, Wavelet::Gauss));
        assert!(!flagged(0.8, Wavelet::Gauss));
        // the saturation of a smooth image, read to rounding
        assert!(flagged(1.0 - 3e-11, Wavelet::Gauss));
        assert!(!flagged(0.98, Wavelet::Gauss));
        assert!(!flagged(1.2, Wavelet::Mexican));
        assert!(flagged(3.0, Wavelet::Mexican));
        let sp = power_law_sums(1.2, Wavelet::Gauss)
            .spectra(Rule::Plain, (0.5, 4.0))
            .unwrap();
        let w = sp.warnings.iter().find(|m| m.starts_with("h(q)")).unwrap();
        assert!(
            w.contains("at 9 of the q (q = -4 .. 4, up to h = 1.200)"),
            "{w}"
        );
        assert!(w.contains("try the mexican wavelet"), "{w}");
    }

    /// An estimate at or past the exponent the linking window lets a line
    /// follow (log2(hi) per scale step: 1.51 per octave for (0.9, 1.11) at
    /// 10 voices) is flagged; a wider window lifts the flag.
    #[test]
    fn exponents_past_the_linking_window_are_flagged() {
        use crate::cwt::Wavelet;
        let window = |h: f64, ratio: Option<(f64, f64)>| {
            let mut s = power_law_sums(h, Wavelet::Mexican);
            if let (Some(r), Some(a)) = (ratio, s.analysis.as_mut()) {
                a.link.ratio = r;
            }
            let sp = s.spectra(Rule::Plain, (0.5, 4.0)).unwrap();
            sp.warnings
                .iter()
                .find(|m| m.contains("linking window"))
                .cloned()
        };
        assert!(window(1.2, None).is_none());
        let w = window(2.0, None).expect("h = 2 is past 1.51");
        assert!(
            w.starts_with("h(q) >= 1.51 at 9 of the q (q = -4 .. 4, up to h = 2.000)"),
            "{w}"
        );
        // (0.8, 1.25) at 10 voices: 10 log2(1.25) = 3.22 per octave
        assert!(window(2.0, Some((0.8, 1.25))).is_none());
        assert!(window(3.3, Some((0.8, 1.25))).is_some());
    }

    #[test]
    fn legendre_of_a_parabola_is_exact() {
        // τ(q) = -2 + 0.4 q - 0.05 q^2 on a non-uniform grid
        let q = [-3.0, -2.0, -0.5, 0.0, 1.0, 2.5, 3.0, 4.0];
        let tau: Vec<f64> = q.iter().map(|&x| -2.0 + 0.4 * x - 0.05 * x * x).collect();
        let (h, d) = legendre(&q, &tau);
        // the ends too: one-sided three-point slopes
        for i in 0..q.len() {
            let hx = 0.4 - 0.1 * q[i];
            assert!((h[i] - hx).abs() < 1e-12, "{i}: {} vs {hx}", h[i]);
            assert!((d[i] - (q[i] * hx - tau[i])).abs() < 1e-12);
        }
        // two points: their chord
        let (h, _) = legendre(&q[..2], &tau[..2]);
        assert!((h[0] - (tau[1] - tau[0])).abs() < 1e-12 && h[0] == h[1]);
    }

    #[test]
    fn recurrence_matches_direct_cells() {
        let l: Vec<f64> = (0..500)
            .map(|i| ((i * 37 % 101) as f64 - 50.0) / 7.0)
            .collect();
        let q: Vec<f64> = (0..33).map(|k| -4.0 + 0.3125 * k as f64).collect();
        let fast = cells_all_q(&l, &q);
        for (k, &qv) in q.iter().enumerate() {
            let slow = cell(&l, qv);
            assert_eq!(fast[k].e, slow.e, "q = {qv}");
            for (a, b) in [
                (fast[k].z, slow.z),
                (fast[k].zl, slow.zl),
                (fast[k].z2, slow.z2),
            ] {
                assert!(
                    (a - b).abs() <= 1e-12 * b.abs().max(1.0),
                    "q = {qv}: {a} vs {b}"
                );
            }
        }
        // a non-uniform grid takes the direct path
        let q2 = [-1.0, 0.0, 0.5, 3.0];
        let f2 = cells_all_q(&l, &q2);
        assert_eq!(f2[3], cell(&l, 3.0));
    }

    #[test]
    fn cells_are_stable_at_large_q() {
        // exact against a direct sum where the direct sum is representable
        let l = [-3.0, 1.5, 4.0, -6.0];
        for q in [-20.0, -5.0, 0.0, 5.0, 20.0] {
            let c = cell(&l, q);
            let direct: f64 = l.iter().map(|&x| (q * x).exp2()).sum();
            let got = c.e as f64 + c.z.log2();
            assert!((got - direct.log2()).abs() < 1e-12, "q={q}");
        }
        // finite where a direct sum would overflow (2^1200) or underflow
        let l = [-3.0, 1.5, 40.0, -60.0];
        for q in [-20.0, 20.0] {
            let c = cell(&l, q);
            assert!(c.z >= 1.0 && c.z.is_finite() && c.zl.is_finite() && c.z2.is_finite());
            let want = l.iter().map(|&x| q * x).fold(f64::NEG_INFINITY, f64::max);
            assert!((c.e as f64 + c.z.log2() - want).abs() < 1e-9, "q={q}");
        }
    }

    fn exps(h: &[f64], t: &[f64]) -> Vec<ImageExponents> {
        h.iter()
            .zip(t)
            .enumerate()
            .map(|(i, (&h_q0, &tau_q2))| ImageExponents {
                label: format!("im{i}"),
                h_q0,
                tau_q2,
                shape: None,
            })
            .collect()
    }

    /// The deleted residual by hand: h = 0.30, 0.31, 0.29, 0.30 and 0.80.
    /// For the last, the others' mean is 0.30 and sd 0.008165, so t =
    /// 0.5 / (0.008165 sqrt(1 + 1/4)) = 54.8, beyond the t_3 quantile at
    /// 1 - 0.001/20 (28.0); for the first, with 0.80 among the others, t
    /// = -0.58. Only the last image is named, with its values; tau(q=2),
    /// within 0.015 of each other, flags none. Below 4 images nothing is
    /// tested. An image without estimates is left out (the rest tested) and
    /// named, and when fewer than 4 remain that is said.
    #[test]
    fn unlike_images_by_hand() {
        let tau = [-1.40, -1.41, -1.39, -1.40, -1.405];
        let w = unlike_images(&exps(&[0.30, 0.31, 0.29, 0.30, 0.80], &tau));
        assert_eq!(w.len(), 1, "{w:?}");
        assert!(
            w[0].starts_with("im4 looks unlike") && w[0].contains("h(q=0) = 0.800"),
            "{w:?}"
        );
        assert!(
            w[0].contains("against 0.300 +- 0.008") && w[0].contains("t = 54.8"),
            "{w:?}"
        );
        assert!(!w[0].contains("tau(q=2)"), "{w:?}");
        assert!(unlike_images(&exps(&[0.3, 0.3, 0.9], &[-1.4; 3])).is_empty());
        // a q grid without 0: only tau(q=2) is tested
        let w = unlike_images(&exps(&[f64::NAN; 5], &[-1.4, -1.41, -1.39, -1.4, -0.9]));
        assert!(w.len() == 1 && w[0].contains("tau(q=2) = -0.900"), "{w:?}");
        // an image without estimates (no line at the top of the fit) is
        // left out and named; the others are still tested, over 5
        let mut h = vec![0.30, 0.31, 0.29, 0.30, 0.80, f64::NAN];
        let mut t = vec![-1.40, -1.41, -1.39, -1.40, -1.405, f64::NAN];
        let w = unlike_images(&exps(&h, &t));
        assert_eq!(w.len(), 2, "{w:?}");
        assert!(w[0].starts_with("im4 looks unlike"), "{w:?}");
        assert!(
            w[1].starts_with("im5: no h(q=0)") && w[1].contains("left out"),
            "{w:?}"
        );
        // too few left: nothing tested, and said
        h.truncate(4);
        t.truncate(4);
        h[3] = f64::NAN;
        t[3] = f64::NAN;
        let w = unlike_images(&exps(&h, &t));
        assert!(w.len() == 1 && w[0].contains("too few images"), "{w:?}");
    }

    /// Images of different sizes are compared with their own size class.
    /// Eight 512^2 images at h = 0.30 +- 0.006 and one 128^2 image at 0.45
    /// (a small image's own exponent has its own bias and scatter): as one
    /// ensemble the small one is named; by size it is not tested, and that
    /// is said. With four 128^2 images (0.40-0.50) both classes are tested
    /// and none named; an outlier among the large ones (0.80) is named
    /// against the others of its class. Near-equal sizes (edge-cropped
    /// tiles, 128x128 to 128x121) are one class: an outlier among them is
    /// named (a review found each size alone, so none tested).
    #[test]
    fn unlike_images_by_size() {
        let sized = |h: &[f64], shape: [usize; 2], from: usize| -> Vec<ImageExponents> {
            let mut v = exps(h, &vec![f64::NAN; h.len()]);
            for (i, e) in v.iter_mut().enumerate() {
                e.shape = Some(shape);
                e.label = format!("im{}", from + i);
            }
            v
        };
        let join = |a: &[ImageExponents], b: &[ImageExponents]| -> Vec<ImageExponents> {
            a.iter().chain(b).cloned().collect()
        };
        let big = sized(
            &[0.30, 0.31, 0.29, 0.30, 0.305, 0.295, 0.30, 0.302],
            [512, 512],
            0,
        );
        let one_small = sized(&[0.45], [128, 128], 8);
        let mixed = join(&big, &one_small);
        // as one ensemble (sizes unrecorded) the small one stands out
        let one_size: Vec<ImageExponents> = mixed
            .iter()
            .cloned()
            .map(|e| ImageExponents { shape: None, ..e })
            .collect();
        let w = unlike_images(&one_size);
        assert!(
            w.len() == 1 && w[0].starts_with("im8 looks unlike"),
            "{w:?}"
        );
        let w = unlike_images(&mixed);
        assert!(
            w.len() == 1
                && w[0].contains("2 classes")
                && w[0].contains("not tested, fewer than 4 images with estimates: 1 of 128x128 (1 with estimates)"),
            "{w:?}"
        );
        // four small ones: both classes tested, none named
        let small = sized(&[0.40, 0.45, 0.50, 0.45], [128, 128], 8);
        let w = unlike_images(&join(&big, &small));
        assert!(
            w.len() == 1 && w[0].contains("2 classes") && !w[0].contains("not tested"),
            "{w:?}"
        );
        // an outlier among the large ones is named, against its class
        let mut odd = big.clone();
        odd[4].h_q0 = 0.80;
        let w = unlike_images(&join(&odd, &small));
        assert!(
            w.len() == 2
                && w[0].starts_with("im4 looks unlike")
                && w[0].contains("other 7 of its size class"),
            "{w:?}"
        );
        // near-equal sizes: one class, the outlier named, nothing else said
        let mut tiles = odd.clone();
        for (i, e) in tiles.iter_mut().enumerate() {
            e.shape = Some([128, 128 - i]);
        }
        let w = unlike_images(&tiles);
        assert!(
            w.len() == 1 && w[0].starts_with("im4 looks unlike"),
            "{w:?}"
        );
        assert!(!w[0].contains("size class"), "{w:?}");
        // recorded and unrecorded sizes: two classes
        let mut part = odd.clone();
        for e in &mut part[..4] {
            e.shape = None;
        }
        let w = unlike_images(&part);
        assert!(w.iter().any(|w| w.contains("2 classes")), "{w:?}");
    }

    /// Under the hypothesis it tests (16 images of one normal law per
    /// exponent) the warning is rare: at most 0.1 % of ensembles by the
    /// Bonferroni bound (measured: 47 of 40 000, 0.12 %, within the count's
    /// Poisson scatter), so about 2 of 2000 here (10 or more has
    /// probability 5e-5 at 0.1 %). The threshold at 1 - 0.001/64 of t_14
    /// is 6.0: an image 20 sd off is named in all of 200 ensembles (a miss
    /// needs the other 15 to scatter 3.2 times their sd, chi2_14 > 145),
    /// one 12 sd off in 190 or more (measured 199: the miss had the others'
    /// sd at 1.45 times the law's and the image 2.5 sd back).
    #[test]
    fn unlike_images_false_alarms_and_power() {
        use rand_distr::{Distribution, Normal};
        let law = Normal::new(0.0, 1.0).unwrap();
        let mut rng = crate::synth::rng_for(9, 0);
        let mut draw = |shift: f64| -> Vec<ImageExponents> {
            let mut h: Vec<f64> = (0..16).map(|_| 0.4 + 0.02 * law.sample(&mut rng)).collect();
            let t: Vec<f64> = (0..16)
                .map(|_| -1.3 + 0.03 * law.sample(&mut rng))
                .collect();
            h[7] += shift * 0.02;
            exps(&h, &t)
        };
        let alarms = (0..2000)
            .filter(|_| !unlike_images(&draw(0.0)).is_empty())
            .count();
        assert!(
            alarms < 10,
            "{alarms} of 2000 homogeneous ensembles flagged"
        );
        let mut named = |shift: f64| {
            (0..200)
                .filter(|_| {
                    unlike_images(&draw(shift))
                        .iter()
                        .any(|m| m.starts_with("im7 looks unlike"))
                })
                .count()
        };
        assert_eq!(named(20.0), 200);
        let n12 = named(12.0);
        assert!(n12 >= 190, "12 sd off: named in {n12} of 200");
    }
}
