//! The jackknife tiles of a lone image: a grid of square tiles over the
//! counting domain, and the checks on their side.

use super::*;

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
    pub(super) fn row_start(&self, y: usize) -> usize {
        slot(y.saturating_sub(self.y0), self.h, self.nty) * self.ntx
    }

    /// The column of tiles holding image column `x` ([`Self::index`]).
    pub(super) fn column(&self, x: usize) -> usize {
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
pub(super) fn cut(t: usize, len: usize, n: usize) -> usize {
    if 2 * t <= n {
        (2 * t * len + n) / (2 * n)
    } else {
        len - cut(n - t, len, n)
    }
}

/// The tile `t` of `n` along a side of `len` px that holds offset `v`
/// (`cut(t) <= v < cut(t + 1)`; past the side: the last tile).
pub(super) fn slot(v: usize, len: usize, n: usize) -> usize {
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
