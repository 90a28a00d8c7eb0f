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

mod estimate;
#[cfg(test)]
mod tests;
mod tiles;
mod warnings;

pub use estimate::*;
pub use tiles::*;
pub use warnings::*;

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
/// [`Default`] is an image with no scale and nothing recorded, a base for
/// struct-update syntax.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
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
    /// With missing pixels, the share of the counting domain's rectangle
    /// where maxima count ([`Skeleton::counted_share`]); absent without
    /// missing pixels and in sums written before 2026-11-30.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub counted_share: Option<f64>,
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
                ..Default::default()
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
                ..Default::default()
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
        crate::par::merge_in_order(parts, Self::merge)
    }

    /// Checks sums read from a file before they are trusted (a shard may
    /// be truncated, edited or from a newer version): a non-empty ascending
    /// finite q grid, positive ascending scales, at least one image, array
    /// lengths matching the grids, finite cells with non-negative sums.
    ///
    /// **Errors** ([`Error::Input`]) with what is wrong, as the `check` of
    /// the other mergeable sums ([`read_json`](Self::read_json) names the
    /// file).
    pub fn check(&self) -> Result<()> {
        self.problem().map_err(Error::Input)
    }

    /// [`Self::check`]'s finding, as text.
    fn problem(&self) -> std::result::Result<(), String> {
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
        // a recorded number outside its range, said as what it should be
        let recorded = |name: &str,
                        get: &dyn Fn(&ImagePartial) -> Option<f64>,
                        ok: &dyn Fn(f64) -> bool,
                        what: &str|
         -> std::result::Result<(), String> {
            match (self.images.iter().enumerate()).find(|(_, im)| get(im).is_some_and(|v| !ok(v))) {
                Some((i, im)) => Err(format!(
                    "image {i} ({:?}): {name} {} is {what}",
                    im.label,
                    get(im).unwrap_or(f64::NAN)
                )),
                None => Ok(()),
            }
        };
        let share = |r: f64| (0.0..=1.0).contains(&r);
        recorded(
            "counted_share",
            &|im| im.counted_share,
            &share,
            "no share of a domain (0 to 1)",
        )?;
        recorded(
            "plane_share",
            &|im| im.plane_share,
            &share,
            "no share of a variance (0 to 1)",
        )?;
        recorded(
            "terrace_width",
            &|im| im.terrace_width,
            &|w| (1.0..=1e9).contains(&w),
            "no terrace width in pixels (1 or more)",
        )?;
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
    /// [`ImagePartial::counted_share`]; null without missing pixels or
    /// where the sums do not record it.
    #[serde(default)]
    pub counted_share: Option<f64>,
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
            counted_share: im.counted_share,
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

/// Spectra of older versions lack some numbers: NaN, as a null reads.
fn nan() -> f64 {
    f64::NAN
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
    /// h = dτ/dq, D = q h - τ ([`legendre`]; NaN, null in JSON, when the
    /// grid has one q, which a warning says).
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
    /// Standard error of `log2_z` per q, per scale: the jackknife of
    /// `stderr_method` (over images, or tiles), NaN where there is none
    /// (the regression's errors are of slopes, not of points) or where a
    /// leave-one-out sample has no line at that scale (JSON
    /// `log2_Z_stderr`; empty in spectra of older versions).
    #[serde(
        rename = "log2_Z_stderr",
        default,
        deserialize_with = "crate::nan_null::vec2"
    )]
    pub log2_z_stderr: Vec<Vec<f64>>,
    /// Standard error of `h_qa`, as `log2_z_stderr`.
    #[serde(default, deserialize_with = "crate::nan_null::vec2")]
    pub h_qa_stderr: Vec<Vec<f64>>,
    /// Standard error of `d_qa`, as `log2_z_stderr` (JSON `D_qa_stderr`).
    #[serde(
        rename = "D_qa_stderr",
        default,
        deserialize_with = "crate::nan_null::vec2"
    )]
    pub d_qa_stderr: Vec<Vec<f64>>,
    /// The local slope of `log2 Z(q, a)` against `log2 a` at each scale,
    /// per q: the chord between the scales nearest half an octave either
    /// side ([`local_slopes`], over `local_slope_octaves`); NaN within half
    /// an octave of either end of the grid.
    /// Flat over the fit range where `Z` is a power law; the fitted tau(q)
    /// averages it where it drifts (`tau_slope_change`).
    #[serde(default, deserialize_with = "crate::nan_null::vec2")]
    pub local_slopes: Vec<Vec<f64>>,
    /// Standard error of `local_slopes`, as `log2_z_stderr` (the jackknife
    /// of the slopes, not a combination of the two points' errors, which
    /// are correlated).
    #[serde(default, deserialize_with = "crate::nan_null::vec2")]
    pub local_slopes_stderr: Vec<Vec<f64>>,
    /// The span in octaves of the local slopes' chords (1 at 10 voices per
    /// octave, 4/3 at 3); NaN when there is no chord (a grid of less than
    /// an octave) or when the chords differ (an irregular scale list:
    /// [`local_slope_chords`]).
    #[serde(default = "nan", deserialize_with = "crate::nan_null::f64")]
    pub local_slope_octaves: f64,
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
///
/// This reads the grid's `octaves` and `voices` only: for sums of explicit
/// `AnalysisConfig::scales`, take [`PartitionSums::default_fit`], which
/// reads the scales the sums hold.
pub fn default_fit(octaves: usize, voices: usize) -> (f64, f64) {
    let v = voices.max(1) as f64;
    let hi = (octaves as f64).min(4.0);
    (((0.5 * v - 1e-9).ceil() / v).min(hi), hi)
}

impl PartitionSums {
    /// The octaves the scales span, the last scale plus one step (a grid
    /// of 4 octaves spans 4), and that step in octaves (0 for one scale).
    pub(crate) fn grid_span(&self) -> (f64, f64) {
        grid_span_of(&self.scales)
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
        s.problem()
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
    if s.images[0].missing > 0 {
        s.images[0].counted_share = sk.counted_share();
    }
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

/// The octaves a grid of `scales` spans, its last scale plus one step (4
/// for a grid of 4 octaves), and that step (the first): `(span, step)`.
fn grid_span_of(scales: &[f64]) -> (f64, f64) {
    let step = if scales.len() > 1 {
        (scales[1] / scales[0]).log2()
    } else {
        0.0
    };
    let span = match (scales.first(), scales.last()) {
        (Some(a0), Some(a1)) => (a1 / a0).log2() + step,
        _ => 0.0,
    };
    (span, step)
}

/// Checks a fit range `fit = (lo, hi)` in octaves above the smallest of
/// `scales` (a grid of ratio-spaced scales, the first step its voice):
/// `0 <= lo < hi <= top`, `top` the octaves the grid spans (its last scale
/// plus one step: 4 for a grid of 4 octaves, which fits up to the last
/// scale), and each end on an octave of a scale or at the top, since an
/// end between two scales would fit from the next one and be recorded as
/// given. What [`PartitionSums::spectra`] and the kernel's
/// [`crate::stats::kernel::kernel_estimates`] require; [`fit_indices`] then
/// counts the scales in it.
///
/// **Errors** ([`Error::Param`] `fit`) naming the range and, for an end
/// off the grid, the grid's octaves either side.
pub fn check_fit_on_grid(scales: &[f64], fit: (f64, f64)) -> Result<()> {
    let log2_a: Vec<f64> = scales.iter().map(|a| a.log2()).collect();
    let oct0 = log2_a.first().copied().unwrap_or(0.0);
    let (top, _) = grid_span_of(scales);
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
    Ok(())
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
