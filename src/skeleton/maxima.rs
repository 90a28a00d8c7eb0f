//! One scale: WTMM by non-maximum suppression, maxima chains, WTMMM
//! (SPEC §2; II §3, Figs 9 and 15).

use ndarray::Array2;
use num_complex::Complex64;
use serde::{Deserialize, Serialize};

use crate::cwt::{CwtPlan, CwtWorkspace, FourierImage, argument};

/// A local maximum of the modulus along a maxima chain (a WTMMM).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Wtmmm {
    /// Column of the pixel.
    pub x: u32,
    /// Row of the pixel (0 at the top).
    pub y: u32,
    /// Modulus M.
    pub m: f64,
    /// Argument A = atan2(T2, T1) (radians; y axis pointing down the rows).
    pub arg: f64,
    /// Index of its chain in this scale's chain list.
    pub chain: u32,
}

/// An 8-connected maxima chain, as an ordered list of pixels `(x, y)`; on
/// a torus ([`Domain::is_torus`]) it may cross the image's edges.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Chain {
    /// The pixels `(x, y)` in tracing order.
    pub pixels: Vec<(u32, u32)>,
    /// The chain closes on itself (last pixel 8-adjacent to the first, no end).
    pub closed: bool,
}

/// Everything found at one scale.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ScaleMaxima {
    /// Scale index in the scale list (0 = `a_min`).
    pub j: usize,
    /// Scale, in pixels.
    pub a: f64,
    /// Number of WTMM pixels.
    pub n_wtmm: usize,
    /// Number of chains (of any length).
    pub n_chains: usize,
    /// WTMMM, in chain order.
    pub wtmmm: Vec<Wtmmm>,
    /// The chains, when asked for (pictures); empty otherwise.
    pub chains: Vec<Chain>,
}

impl ScaleMaxima {
    /// A scale `j` (scale `a` px) holding WTMMM at `(x, y, M)`, each on a
    /// chain of its own, with argument 0: maxima found elsewhere, to be
    /// linked by a [`crate::skeleton::Linker`] (and the linking tests).
    pub fn from_points(j: usize, a: f64, pts: &[(u32, u32, f64)]) -> Self {
        ScaleMaxima {
            j,
            a,
            n_wtmm: pts.len(),
            n_chains: pts.len(),
            wtmmm: pts
                .iter()
                .enumerate()
                .map(|(c, &(x, y, m))| Wtmmm {
                    x,
                    y,
                    m,
                    arg: 0.0,
                    chain: c as u32,
                })
                .collect(),
            chains: Vec::new(),
        }
    }
}

/// Where maxima are counted: the interior rectangle `[y0, y1) x [x0, x1)`
/// (SPEC §1 margin, the same at every scale), minus the pixels too close to a
/// masked pixel. With `guard` set, chains are traced (and lines linked) over
/// the wider rectangle where the transform is trusted at the current scale
/// (margin `ceil(support a)`), so that the counting rectangle does not cut
/// chains and end the lines that cross it.
#[derive(Clone, Debug)]
pub struct Domain {
    /// Image height (rows).
    pub ny: usize,
    /// Image width (columns).
    pub nx: usize,
    /// First row of the counting rectangle.
    pub y0: usize,
    /// One past its last row.
    pub y1: usize,
    /// First column of the counting rectangle.
    pub x0: usize,
    /// One past its last column.
    pub x1: usize,
    /// Euclidean distance (px) from each pixel to the nearest masked pixel;
    /// `None` without a mask.
    pub mask_distance: Option<Array2<f32>>,
    /// Radius of the wavelet in units of a (its margin per unit scale).
    pub support: f64,
    /// Trace chains beyond the counting rectangle where the scale allows.
    pub guard: bool,
}

impl Domain {
    /// Interior at distance >= `margin` from every edge.
    pub fn interior(ny: usize, nx: usize, margin: usize) -> Self {
        Domain {
            ny,
            nx,
            y0: margin.min(ny),
            y1: ny.saturating_sub(margin),
            x0: margin.min(nx),
            x1: nx.saturating_sub(margin),
            mask_distance: None,
            support: 0.0,
            guard: false,
        }
    }

    /// The rectangle `(y0, y1, x0, x1)` where chains are traced at scale `a`.
    pub fn detection_rect(&self, a: f64) -> (usize, usize, usize, usize) {
        if !self.guard {
            return (self.y0, self.y1, self.x0, self.x1);
        }
        let m = ((self.support * a).ceil() as usize).max(2);
        (
            m.min(self.y0),
            self.ny.saturating_sub(m).max(self.y1),
            m.min(self.x0),
            self.nx.saturating_sub(m).max(self.x1),
        )
    }

    /// True if the NMS at scale `a` needs periodic indexing: the detection
    /// rectangle comes within two pixels of the border (`p ± u` and the cell
    /// beyond it must stay inside the image otherwise).
    pub fn wraps(&self, a: f64) -> bool {
        let (y0, y1, x0, x1) = self.detection_rect(a);
        y0 < 2 || x0 < 2 || y1 + 2 > self.ny || x1 + 2 > self.nx
    }

    /// True if pixel `(x, y)` is inside the counting rectangle.
    pub fn counts(&self, x: u32, y: u32) -> bool {
        let (x, y) = (x as usize, y as usize);
        x >= self.x0 && x < self.x1 && y >= self.y0 && y < self.y1
    }

    /// True if the counting rectangle is the whole image: the domain is the
    /// torus of the periodic transform, so chains are traced and lines
    /// linked across the image's edges (they would otherwise end there, a
    /// loss that steepens τ(0); README, "Conventions").
    pub fn is_torus(&self) -> bool {
        (self.y0, self.y1, self.x0, self.x1) == (0, self.ny, 0, self.nx)
            && self.ny >= 3
            && self.nx >= 3
    }

    /// True if the interior has no pixel.
    pub fn is_empty(&self) -> bool {
        self.y0 >= self.y1 || self.x0 >= self.x1
    }

    /// Number of pixels of the interior rectangle.
    pub fn area(&self) -> usize {
        (self.y1.saturating_sub(self.y0)) * (self.x1.saturating_sub(self.x0))
    }
}

/// Buffers reused from one scale to the next (one set per worker).
#[derive(Default)]
pub struct DetectScratch {
    modulus: Vec<f64>,
    /// One bit per pixel of the grid padded by one pixel: WTMM or not.
    /// Small enough to stay in cache; the index of a WTMM pixel in `pos` is
    /// the rank of its bit (`prefix` + a popcount).
    bits: Vec<u64>,
    /// Number of set bits before each word of `bits`.
    prefix: Vec<u32>,
    /// Per WTMM pixel: bit i set if `NEIGH[i]` is a WTMM pixel.
    nmask: Vec<u8>,
    /// WTMM test results of one row.
    row_mask: Vec<u8>,
    /// Three rows of M (streaming pass; padded rows on a torus).
    ring: Vec<f64>,
    /// One row of T padded by a wrapped pixel on each side (torus), and
    /// row 0 kept so padded for the end of a streamed torus pass.
    tpad: Vec<Complex64>,
    t0: Vec<Complex64>,
    /// Candidates before the eps threshold, in raster order.
    cand: Vec<Px>,
    /// This scale's WTMM pixels in raster order, as separate arrays so that
    /// the chain tracing's working set stays in cache: positions, moduli,
    /// transforms.
    pos: Vec<(u32, u32)>,
    pm: Vec<f64>,
    pt: Vec<Complex64>,
    /// Per WTMM pixel: 1 = not yet chained, 3 = in the component being
    /// traced, 2 = chained.
    state: Vec<u8>,
    /// Per WTMM pixel: its neighbours not yet walked (kept by the walks).
    unwalked: Vec<u8>,
    stack: Vec<Pix>,
    comp: Vec<Pix>,
    order: Vec<Pix>,
    mvals: Vec<f64>,
    /// Index in `pt` of each WTMMM, and their order by that index.
    maxk: Vec<u32>,
    order_k: Vec<u32>,
}

/// A WTMM pixel while chains are traced: index (raster order), padded
/// column, padded row.
type Pix = [u32; 3];

/// A WTMM pixel (candidate): position, modulus and transform, captured
/// while its row of T is in cache (chains are traced after the whole pass,
/// when T has left the cache).
#[derive(Clone, Copy, Default)]
struct Px {
    x: u32,
    y: u32,
    m: f64,
    t: Complex64,
}

/// 8 neighbours, 4-connected ones first so that tracing follows the curve
/// without cutting corners.
const NEIGH: [(i32, i32); 8] = [
    (1, 0),
    (0, 1),
    (-1, 0),
    (0, -1),
    (1, 1),
    (-1, 1),
    (-1, -1),
    (1, -1),
];
/// Bits of the `NEIGH` mask in the row above and in the row below.
const UP: u8 = 1 << 3 | 1 << 6 | 1 << 7;
const DOWN: u8 = 1 << 1 | 1 << 4 | 1 << 5;

/// Finds WTMM, chains and WTMMM at one scale from `T = T1 + i T2`.
///
/// 1. WTMM: `M(p) > M(p+u)` and `M(p) >= M(p-u)` with `u = T/M` and bilinear
///    interpolation (periodic indexing, as the CWT is periodic), ignoring
///    `M < eps max M` (max over the domain).
/// 2. Chains: 8-connected WTMM pixels traced as ordered lists; a component
///    with branches is split into several chains.
/// 3. WTMMM: local maxima of M along each chain of >= 3 pixels, one per
///    plateau (its middle pixel).
pub fn detect(
    t: &Array2<Complex64>,
    j: usize,
    a: f64,
    domain: &Domain,
    eps: f64,
    keep_chains: bool,
    s: &mut DetectScratch,
) -> ScaleMaxima {
    let (ny, nx) = t.dim();
    assert_eq!(
        (ny, nx),
        (domain.ny, domain.nx),
        "domain and transform shapes differ"
    );
    let out = ScaleMaxima {
        j,
        a,
        ..Default::default()
    };
    if domain.is_empty() {
        return out;
    }
    let ts = t.as_slice().expect("CWT output is contiguous");
    let (dy0, dy1, dx0, dx1) = domain.detection_rect(a);
    s.cand.clear();
    let wraps = domain.wraps(a);
    let mut mmax: f64 = 0.0;

    // 1. non-maximum suppression along the gradient. The eps threshold
    //    needs max M, so candidates are kept with their modulus and
    //    thresholded after the pass.
    if wraps {
        s.modulus.resize(ny * nx, 0.0);
        modulus_into(ts, &mut s.modulus);
        let m = &s.modulus;
        for y in domain.y0..domain.y1 {
            mmax = mmax.max(max_nonneg(&m[y * nx + domain.x0..y * nx + domain.x1]));
        }
        // rows padded by one wrapped pixel on each side, so the vectorised
        // row test of the interior applies (a per-pixel test with periodic
        // index arithmetic was a third of a torus skeleton)
        let w = nx + 2;
        s.ring.resize(3 * w, 0.0);
        s.tpad.resize(w, Complex64::default());
        s.row_mask.resize(w, 0);
        for y in dy0..dy1 {
            let (yu, yd) = ((y + ny - 1) % ny, (y + 1) % ny);
            for (k, yy) in [yu, y, yd].into_iter().enumerate() {
                pad_wrapped(&m[yy * nx..(yy + 1) * nx], &mut s.ring[k * w..(k + 1) * w]);
            }
            pad_wrapped(&ts[y * nx..(y + 1) * nx], &mut s.tpad);
            let (up, rest) = s.ring.split_at(w);
            let (mid, dn) = rest.split_at(w);
            nms_padded_row(
                [up, mid, dn],
                &s.tpad,
                (dx0, dx1),
                y,
                &mut s.row_mask,
                &mut s.cand,
            );
        }
    } else {
        // one streaming pass: M rows in a ring of three, the NMS one row
        // behind, while that row of T is still in cache (the detection was
        // memory-bound with full M arrays)
        let mut nms = NmsStream::new(domain, a, nx, s);
        for r in dy0 - 1..=dy1 {
            nms.feed(s, r, &ts[r * nx..(r + 1) * nx], &ts[(r - 1) * nx..r * nx]);
        }
        mmax = nms.mmax;
    }
    finish(out, mmax, domain, eps, a, keep_chains, s)
}

/// As [`detect`], computing the transform itself: when the domain keeps
/// two pixels from every border the rows of `T` stream from the CWT in
/// blocks ([`CwtPlan::scale_rows`]) and the full transform is never
/// stored. Same result as `detect(plan.scale(fi, j, ws), ...)`, bit for bit.
#[allow(clippy::too_many_arguments)]
pub fn detect_scale(
    plan: &CwtPlan,
    fi: &FourierImage,
    j: usize,
    ws: &mut CwtWorkspace,
    domain: &Domain,
    eps: f64,
    keep_chains: bool,
    s: &mut DetectScratch,
) -> ScaleMaxima {
    let (ny, nx) = plan.dim();
    let a = plan.scales()[j];
    let (dy0, dy1, dx0, dx1) = domain.detection_rect(a);
    let same_shape = (ny, nx) == (domain.ny, domain.nx);
    if same_shape && !domain.is_empty() && (dy0, dy1, dx0, dx1) == (0, ny, 0, nx) && ny >= 3 {
        return detect_torus_streamed(plan, fi, j, ws, domain, eps, keep_chains, s);
    }
    if domain.wraps(a) || domain.is_empty() || !same_shape {
        let t = plan.scale(fi, j, ws);
        return detect(t, j, a, domain, eps, keep_chains, s);
    }
    let out = ScaleMaxima {
        j,
        a,
        ..Default::default()
    };
    s.cand.clear();
    let mut nms = NmsStream::new(domain, a, nx, s);
    plan.scale_rows(fi, j, ws, dy0 - 1..dy1 + 1, |y0, prev, cur| {
        for (i, t_r) in cur.chunks_exact(nx).enumerate() {
            let t_prev = if i > 0 {
                &cur[(i - 1) * nx..i * nx]
            } else {
                // the first block starts at dy0 - 1, whose NMS is not needed
                prev.map_or(&[][..], |p| &p[p.len() - nx..])
            };
            nms.feed(s, y0 + i, t_r, t_prev);
        }
    });
    let mmax = nms.mmax;
    finish(out, mmax, domain, eps, a, keep_chains, s)
}

/// [`detect_scale`] on the whole torus (detection rectangle = the image):
/// rows stream from the CWT once, in order; each is tested when the next
/// arrives, on rows padded by one wrapped pixel, as [`detect`] does. Row 0
/// needs row `ny - 1` above it, so its M rows 0 and 1 and its T row are kept
/// and it is tested last, its candidates put first (raster order).
#[allow(clippy::too_many_arguments)]
fn detect_torus_streamed(
    plan: &CwtPlan,
    fi: &FourierImage,
    j: usize,
    ws: &mut CwtWorkspace,
    domain: &Domain,
    eps: f64,
    keep_chains: bool,
    s: &mut DetectScratch,
) -> ScaleMaxima {
    let (ny, nx) = plan.dim();
    let a = plan.scales()[j];
    let out = ScaleMaxima {
        j,
        a,
        ..Default::default()
    };
    let w = nx + 2;
    s.cand.clear();
    s.ring.resize(3 * w, 0.0);
    s.tpad.resize(w, Complex64::default());
    s.row_mask.resize(w, 0);
    // the current M row, then padded M rows 0 and 1; padded T row 0 (kept
    // for the wrap at the end)
    s.modulus.resize(nx + 2 * w, 0.0);
    let (mrow, first) = s.modulus.split_at_mut(nx);
    s.t0.resize(w, Complex64::default());
    let (cy0, cy1, cx0, cx1) = (domain.y0, domain.y1, domain.x0, domain.x1);
    let mut mmax: f64 = 0.0;
    plan.scale_rows(fi, j, ws, 0..ny, |y0, prev, cur| {
        for (i, t_r) in cur.chunks_exact(nx).enumerate() {
            let r = y0 + i;
            modulus_into(t_r, mrow);
            if r >= cy0 && r < cy1 {
                mmax = mmax.max(max_nonneg(&mrow[cx0..cx1]));
            }
            pad_wrapped(mrow, &mut s.ring[(r % 3) * w..(r % 3 + 1) * w]);
            if r < 2 {
                pad_wrapped(mrow, &mut first[r * w..(r + 1) * w]);
            }
            if r == 0 {
                pad_wrapped(t_r, &mut s.t0);
                continue;
            }
            // test row r - 1 (rows 1 .. ny - 2 here; row 0 last)
            if r >= 2 {
                let t_prev = if i > 0 {
                    &cur[(i - 1) * nx..i * nx]
                } else {
                    prev.map(|p| &p[p.len() - nx..])
                        .expect("row r - 1 came in the previous block")
                };
                pad_wrapped(t_prev, &mut s.tpad);
                let y = r - 1;
                let row = |q: usize| &s.ring[(q % 3) * w..(q % 3 + 1) * w];
                let rows = [row(y - 1), row(y), row(r)];
                nms_padded_row(rows, &s.tpad, (0, nx), y, &mut s.row_mask, &mut s.cand);
            }
            if r == ny - 1 {
                // row ny - 1: row 0 below it
                pad_wrapped(t_r, &mut s.tpad);
                let row = |q: usize| &s.ring[(q % 3) * w..(q % 3 + 1) * w];
                let rows = [row(r - 1), row(r), &first[..w]];
                nms_padded_row(rows, &s.tpad, (0, nx), r, &mut s.row_mask, &mut s.cand);
            }
        }
    });
    // row 0: row ny - 1 above it; its candidates go first (raster order)
    let n_rest = s.cand.len();
    let up = &s.ring[((ny - 1) % 3) * w..((ny - 1) % 3 + 1) * w];
    let rows = [up, &first[..w], &first[w..]];
    nms_padded_row(rows, &s.t0, (0, nx), 0, &mut s.row_mask, &mut s.cand);
    let n0 = s.cand.len() - n_rest;
    s.cand.rotate_right(n0);
    finish(out, mmax, domain, eps, a, keep_chains, s)
}

/// The streaming non-maximum suppression over the detection rectangle
/// (at least two pixels from every border): fed the rows `dy0 - 1 ..= dy1`
/// of `T` in order, it keeps three rows of M and tests row `r - 1` when row
/// `r` arrives, pushing candidates into `s.cand` and tracking max M over
/// the counting rectangle.
struct NmsStream {
    dy0: usize,
    dy1: usize,
    dx0: usize,
    dx1: usize,
    cy0: usize,
    cy1: usize,
    cx0: usize,
    cx1: usize,
    nx: usize,
    mmax: f64,
}

impl NmsStream {
    fn new(domain: &Domain, a: f64, nx: usize, s: &mut DetectScratch) -> Self {
        let (dy0, dy1, dx0, dx1) = domain.detection_rect(a);
        s.ring.resize(3 * nx, 0.0);
        s.row_mask.resize(nx, 0);
        NmsStream {
            dy0,
            dy1,
            dx0,
            dx1,
            cy0: domain.y0,
            cy1: domain.y1,
            cx0: domain.x0,
            cx1: domain.x1,
            nx,
            mmax: 0.0,
        }
    }

    /// Row `r` of `T`; `t_prev` is row `r - 1` (read only when that row is
    /// tested, i.e. for `r > dy0`).
    fn feed(&mut self, s: &mut DetectScratch, r: usize, t_r: &[Complex64], t_prev: &[Complex64]) {
        let nx = self.nx;
        if r + 1 < self.dy0 || r > self.dy1 {
            return;
        }
        let dst = &mut s.ring[(r % 3) * nx..(r % 3 + 1) * nx];
        modulus_into(t_r, dst);
        if r >= self.cy0 && r < self.cy1 {
            self.mmax = self.mmax.max(max_nonneg(&dst[self.cx0..self.cx1]));
        }
        if r <= self.dy0 {
            return;
        }
        let y = r - 1;
        let (dx0, dx1) = (self.dx0, self.dx1);
        let row = |q: usize| &s.ring[(q % 3) * nx..(q % 3 + 1) * nx];
        nms_row(
            row(y - 1),
            row(y),
            row(r),
            t_prev,
            dx0,
            dx1,
            &mut s.row_mask,
        );
        let mid = row(y);
        for_each_set(&s.row_mask[dx0..dx1], |i| {
            let x = dx0 + i;
            s.cand.push(Px {
                x: x as u32,
                y: y as u32,
                m: mid[x],
                t: t_prev[x],
            });
        });
    }
}

/// Threshold, chains and WTMMM from the candidates in `s.cand`.
fn finish(
    out: ScaleMaxima,
    mmax: f64,
    domain: &Domain,
    eps: f64,
    a: f64,
    keep_chains: bool,
    s: &mut DetectScratch,
) -> ScaleMaxima {
    // compiled twice: with the torus's wrapped neighbours folded away the
    // tracing closures inline again (the wrap cost ~10 % of a skeleton on
    // images that never wrap)
    if domain.is_torus() {
        finish_on::<true>(out, mmax, domain, eps, a, keep_chains, s)
    } else {
        finish_on::<false>(out, mmax, domain, eps, a, keep_chains, s)
    }
}

fn finish_on<const TORUS: bool>(
    mut out: ScaleMaxima,
    mmax: f64,
    domain: &Domain,
    eps: f64,
    a: f64,
    keep_chains: bool,
    s: &mut DetectScratch,
) -> ScaleMaxima {
    let (ny, nx) = (domain.ny, domain.nx);
    // a WTMM whose wavelet support reaches a masked pixel is dropped
    let min_dist = (domain.support * a) as f32;
    if mmax <= 0.0 || !mmax.is_finite() {
        return out;
    }
    let thr = eps * mmax;
    s.pos.clear();
    s.pm.clear();
    s.pt.clear();
    for c in &s.cand {
        if c.m < thr {
            continue;
        }
        if let Some(d) = &domain.mask_distance
            && d[[c.y as usize, c.x as usize]] <= min_dist
        {
            continue;
        }
        s.pos.push((c.x, c.y));
        s.pm.push(c.m);
        s.pt.push(c.t);
    }
    s.state.clear();
    s.state.resize(s.pos.len(), 1);
    out.n_wtmm = s.pos.len();

    // 2. chains, 3. WTMMM. Pixels are handled by their index k in raster
    //    order; their 8-neighbourhoods are read once from a bit grid (padded
    //    so that every neighbour of a domain pixel is on it) and kept as a
    //    mask plus the ranks of the rows above and below, so that tracing
    //    touches only small per-pixel arrays.
    let wpr = (nx + 2) / 64 + 2;
    s.bits.clear();
    s.bits.resize((ny + 2) * wpr, 0);
    for &(x, y) in &s.pos {
        let c = x as usize + 1;
        s.bits[(y as usize + 1) * wpr + c / 64] |= 1 << (c % 64);
    }
    s.prefix.clear();
    let mut acc = 0u32;
    s.prefix.extend(s.bits.iter().map(|w| {
        let before = acc;
        acc += w.count_ones();
        before
    }));
    s.nmask.clear();
    // on the torus the neighbours of edge pixels wrap around (the bit grid
    // keeps its zero padding, so ranks count real pixels only)
    let bit_at = {
        let bits = &s.bits;
        move |x: usize, y: usize| -> bool {
            let c = x + 1;
            bits[(y + 1) * wpr + c / 64] >> (c % 64) & 1 == 1
        }
    };
    // padded (column, row) of the neighbour `(dx, dy)` of the padded (c, r), wrapped
    let wrap = move |c: u32, r: u32, (dx, dy): (i32, i32)| -> (u32, u32) {
        let x = (c as i64 - 1 + dx as i64).rem_euclid(nx as i64) as u32;
        let y = (r as i64 - 1 + dy as i64).rem_euclid(ny as i64) as u32;
        (x + 1, y + 1)
    };
    let on_edge =
        move |c: u32, r: u32| TORUS && (c == 1 || c == nx as u32 || r == 1 || r == ny as u32);
    {
        let bits = &s.bits;
        // bits c-1, c, c+1 of padded row r (bit 0 = c-1)
        let row3 = |r: usize, c: usize| -> u32 {
            let i = r * wpr + (c - 1) / 64;
            let w = bits[i] as u128 | (bits[i + 1] as u128) << 64;
            ((w >> ((c - 1) % 64)) & 7) as u32
        };
        s.nmask.extend(s.pos.iter().map(|&(x, y)| {
            if on_edge(x + 1, y + 1) {
                return NEIGH.iter().enumerate().fold(0u8, |m, (i, &d)| {
                    let (c, r) = wrap(x + 1, y + 1, d);
                    m | (bit_at(c as usize - 1, r as usize - 1) as u8) << i
                });
            }
            let (c, r) = (x as usize + 1, y as usize + 1);
            let (u, m, d) = (row3(r - 1, c), row3(r, c), row3(r + 1, c));
            // bit i set: NEIGH[i] is a WTMM pixel
            ((m >> 2 & 1)
                | (d >> 1 & 1) << 1
                | (m & 1) << 2
                | (u >> 1 & 1) << 3
                | (d >> 2 & 1) << 4
                | (d & 1) << 5
                | (u & 1) << 6
                | (u >> 2 & 1) << 7) as u8
        }));
    }
    s.unwalked.clear();
    s.unwalked
        .extend(s.nmask.iter().map(|m| m.count_ones() as u8));
    let (bits, prefix, nmask, state) = (&s.bits, &s.prefix, &s.nmask, &mut s.state);
    let unwalked = &mut s.unwalked;
    // index of the WTMM pixel at padded (c, r): the rank of its bit
    let rank = move |c: u32, r: u32| -> u32 {
        let i = r as usize * wpr + c as usize / 64;
        prefix[i] + (bits[i] & ((1u64 << (c % 64)) - 1)).count_ones()
    };
    // the WTMM neighbours of pixel `p` (index, padded column, padded row), in
    // NEIGH order; the pixel's own coordinates travel with it, so tracing
    // reads only the small per-pixel arrays
    let neighbours = move |p: Pix| {
        let [k, c, r] = p;
        let mask = nmask[k as usize];
        let edge = on_edge(c, r);
        let (up, dn) = if edge {
            (0, 0)
        } else {
            (
                if mask & UP != 0 {
                    rank(c - 1, r - 1)
                } else {
                    0
                },
                if mask & DOWN != 0 {
                    rank(c - 1, r + 1)
                } else {
                    0
                },
            )
        };
        let bit = |i: u32| (mask as u32 >> i) & 1;
        let at = [
            k + 1,
            dn + bit(5),
            k.wrapping_sub(1),
            up + bit(6),
            dn + bit(5) + bit(1),
            dn,
            up,
            up + bit(6) + bit(3),
        ];
        let mut rest = mask;
        std::iter::from_fn(move || {
            (rest != 0).then(|| {
                let i = rest.trailing_zeros() as usize;
                rest &= rest - 1;
                let (dx, dy) = NEIGH[i];
                if edge {
                    let (cw, rw) = wrap(c, r, NEIGH[i]);
                    return [rank(cw, rw), cw, rw];
                }
                [at[i], c.wrapping_add_signed(dx), r.wrapping_add_signed(dy)]
            })
        })
    };
    let unpad = |p: Pix| -> (u32, u32) { (p[1] - 1, p[2] - 1) };
    let period = TORUS.then_some((nx as u32, ny as u32));
    let pm = &s.pm;
    s.maxk.clear();
    for (seed, &(x, y)) in s.pos.iter().enumerate() {
        if state[seed] != 1 {
            continue;
        }
        let seed_px = [seed as u32, x + 1, y + 1];
        // the 8-connected component (state 1 -> 3 while collecting)
        s.comp.clear();
        s.stack.clear();
        s.stack.push(seed_px);
        state[seed] = 3;
        collect(&mut s.stack, &mut s.comp, state, neighbours);
        let comp_len = s.comp.len();
        // The walks of a component start, one after the other, at the
        // unwalked pixel of least `start_key` (fewest unwalked neighbours,
        // then the smallest modulus): chosen by the data, not by the
        // raster, so that a flipped or transposed image gives the same
        // chains (README, Conventions).
        let mut first_walk = true;
        loop {
            if !first_walk {
                s.comp.retain(|p| state[p[0] as usize] == 3);
                if s.comp.is_empty() {
                    break;
                }
            }
            let (key, start) = s
                .comp
                .iter()
                .map(|&p| {
                    let k = p[0] as usize;
                    (start_key(unwalked[k] as u32, pm[k], p[0]), p)
                })
                .min_by_key(|&(k, _)| k)
                .expect("comp is not empty");
            let had_end = key >> 96 <= 1;
            walk(start, state, unwalked, pm, &mut s.order, neighbours);
            let n = s.order.len();
            let closed = first_walk
                && !had_end
                && n == comp_len
                && n >= 3
                && adjacent(unpad(s.order[0]), unpad(s.order[n - 1]), period);
            first_walk = false;
            let chain_id = out.n_chains as u32;
            out.n_chains += 1;
            if n >= 3 {
                s.mvals.clear();
                s.mvals.extend(s.order.iter().map(|p| pm[p[0] as usize]));
                for_each_chain_max(&s.mvals, closed, |i| {
                    let p = s.order[i];
                    let (x, y) = unpad(p);
                    s.maxk.push(p[0]);
                    out.wtmmm.push(Wtmmm {
                        x,
                        y,
                        m: pm[p[0] as usize],
                        arg: 0.0,
                        chain: chain_id,
                    });
                });
            }
            if keep_chains {
                out.chains.push(Chain {
                    pixels: s.order.iter().map(|&p| unpad(p)).collect(),
                    closed,
                });
            }
        }
    }
    // the arguments, read from `pt` in raster order (random reads of it
    // missed the cache once per WTMMM)
    s.order_k.clear();
    s.order_k.extend(0..s.maxk.len() as u32);
    s.order_k.sort_unstable_by_key(|&i| s.maxk[i as usize]);
    for &i in &s.order_k {
        out.wtmmm[i as usize].arg = argument(s.pt[s.maxk[i as usize] as usize]);
    }
    out
}

/// Moves the pixels reached from `stack` through unwalked pixels (state 1)
/// to state 3 and appends them to `comp`, depth first. (A function, not a
/// closure, so that it can be inlined by force: as a closure it was not,
/// and the tracing lost what the collection saved.)
#[inline(always)]
fn collect<I: Iterator<Item = Pix>>(
    stack: &mut Vec<Pix>,
    comp: &mut Vec<Pix>,
    state: &mut [u8],
    neighbours: impl Fn(Pix) -> I,
) {
    while let Some(p) = stack.pop() {
        comp.push(p);
        for q in neighbours(p) {
            if state[q[0] as usize] == 1 {
                state[q[0] as usize] = 3;
                stack.push(q);
            }
        }
    }
}

/// Orders the candidate starts of a walk: fewest unwalked neighbours `c`
/// first, with every end (`c <= 1`) equal, then the smallest modulus `m`
/// (>= 0, whose bits order as the values), then raster order (index `k`,
/// for exact ties only). A chain fades towards its true ends, so the walk
/// starts at the faintest one and, stepping to the larger modulus at a
/// fork, runs along the ridge; the spurs are split off. (Starting at the
/// largest modulus instead read D(h(0)) = 2.10 on 16 fBm of 512²,
/// against 1.99 from the faintest end and 1.98 from the raster-first end
/// before the walks were made orientation-free: README, Conventions.)
fn start_key(c: u32, m: f64, k: u32) -> u128 {
    (c.max(1) as u128) << 96 | (m.to_bits() as u128) << 32 | k as u128
}

/// Walks from `start` through the component's unwalked pixels (state 3),
/// marking them walked (2) and listing them in `order`: each step goes to
/// an unwalked 4-neighbour if there is one, else to a diagonal one (so
/// that the walk follows the curve without cutting corners), and among
/// those to the largest modulus (raster order for exact ties). Both
/// choices are the same for a flipped, transposed or rotated image, as
/// the start's is ([`start_key`]). Keeps `unwalked`, the count of each
/// pixel's unwalked neighbours (each pair is counted down once, when the
/// first of the two is walked).
#[inline(always)]
fn walk<I: Iterator<Item = Pix>>(
    start: Pix,
    state: &mut [u8],
    unwalked: &mut [u8],
    pm: &[f64],
    order: &mut Vec<Pix>,
    neighbours: impl Fn(Pix) -> I,
) {
    order.clear();
    let mut cur = start;
    loop {
        state[cur[0] as usize] = 2;
        order.push(cur);
        // (diagonal, modulus, index, pixel) of the best step so far
        let mut best: Option<(bool, f64, u32, Pix)> = None;
        for q in neighbours(cur) {
            if state[q[0] as usize] != 3 {
                continue;
            }
            unwalked[q[0] as usize] -= 1;
            // padded coordinates: a diagonal step changes both (also
            // across a torus's edge)
            let diag = q[1] != cur[1] && q[2] != cur[2];
            let m = pm[q[0] as usize];
            let better = best.is_none_or(|(bd, bm, bk, _)| {
                (bd && !diag) || (bd == diag && (m > bm || (m == bm && q[0] < bk)))
            });
            if better {
                best = Some((diag, m, q[0], q));
            }
        }
        match best {
            Some((.., q)) => cur = q,
            None => return,
        }
    }
}

/// The largest of `v` (>= 0, no NaN), with eight independent lanes: a plain
/// fold of `f64::max` is a serial dependency chain and cost ~4 % of a
/// skeleton. Max is exact in any order, so the result is the same.
fn max_nonneg(v: &[f64]) -> f64 {
    let mut acc = [0.0f64; 8];
    let mut chunks = v.chunks_exact(8);
    for c in &mut chunks {
        for (a, &x) in acc.iter_mut().zip(c) {
            *a = if x > *a { x } else { *a };
        }
    }
    let mut m = acc.iter().fold(0.0, |m, &x| if x > m { x } else { m });
    for &x in chunks.remainder() {
        m = if x > m { x } else { m };
    }
    m
}

/// Calls `f(i)` for each nonzero byte `mask[i]`, skipping zero words.
fn for_each_set(mask: &[u8], mut f: impl FnMut(usize)) {
    let mut chunks = mask.chunks_exact(8);
    let mut base = 0;
    for c in &mut chunks {
        let w = u64::from_le_bytes(c.try_into().expect("chunk of 8"));
        // the low bit of each byte: set iff the byte is nonzero; visiting
        // the set bits costs no test per byte (those tests mispredicted)
        let mut w = w | w >> 4;
        w |= w >> 2;
        w |= w >> 1;
        w &= 0x0101_0101_0101_0101;
        while w != 0 {
            f(base + w.trailing_zeros() as usize / 8);
            w &= w - 1;
        }
        base += 8;
    }
    for (i, &b) in chunks.remainder().iter().enumerate() {
        if b != 0 {
            f(base + i);
        }
    }
}

/// `M = sqrt(T1^2 + T2^2)` for every pixel (AVX2 when available; same bits).
fn modulus_into(ts: &[Complex64], m: &mut [f64]) {
    #[inline(always)]
    fn imp(ts: &[Complex64], m: &mut [f64]) {
        for (v, z) in m.iter_mut().zip(ts) {
            *v = (z.re * z.re + z.im * z.im).sqrt();
        }
    }
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn avx2(ts: &[Complex64], m: &mut [f64]) {
        imp(ts, m)
    }
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    unsafe fn avx512(ts: &[Complex64], m: &mut [f64]) {
        imp(ts, m)
    }
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx512f") {
            // SAFETY: the CPU supports AVX-512F (checked just above).
            unsafe { avx512(ts, m) };
            return;
        }
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2 (checked just above).
            unsafe { avx2(ts, m) };
            return;
        }
    }
    imp(ts, m)
}

/// The WTMM test for the pixels `x0..x1` of row `y` (at least two pixels
/// from every border), writing 1 or 0 into `mask[x]`.
///
/// With `A = |T1|`, `B = |T2|`, the point `p + u` lies in the quadrant cell
/// `{x, x + sx} x {y, y + sy}` (`s = sign(T)`), with bilinear weights
/// `(M-A)(M-B), A(M-B), (M-A)B, AB` over `M^2`; `p - u` uses the opposite
/// quadrant with the same weights. Multiplying through by `M^2` removes the
/// division, and selects instead of branches let the loop vectorise.
fn nms_row(
    up: &[f64],
    mid: &[f64],
    dn: &[f64],
    trow: &[Complex64],
    x0: usize,
    x1: usize,
    mask: &mut [u8],
) {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx512f") {
            // SAFETY: the CPU supports AVX-512F (checked just above).
            unsafe { nms_row_avx512(up, mid, dn, trow, x0, x1, mask) };
            return;
        }
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2 (checked just above).
            unsafe { nms_row_avx2(up, mid, dn, trow, x0, x1, mask) };
            return;
        }
    }
    nms_row_impl(up, mid, dn, trow, x0, x1, mask)
}

/// The same kernel compiled for AVX2 (4 f64 lanes). No FMA contraction
/// happens without `mul_add`, so both paths give identical bits.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn nms_row_avx2(
    up: &[f64],
    mid: &[f64],
    dn: &[f64],
    trow: &[Complex64],
    x0: usize,
    x1: usize,
    mask: &mut [u8],
) {
    nms_row_impl(up, mid, dn, trow, x0, x1, mask)
}

/// The same kernel compiled for AVX-512 (8 f64 lanes).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn nms_row_avx512(
    up: &[f64],
    mid: &[f64],
    dn: &[f64],
    trow: &[Complex64],
    x0: usize,
    x1: usize,
    mask: &mut [u8],
) {
    nms_row_impl(up, mid, dn, trow, x0, x1, mask)
}

#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn nms_row_impl(
    up: &[f64],
    mid: &[f64],
    dn: &[f64],
    trow: &[Complex64],
    x0: usize,
    x1: usize,
    mask: &mut [u8],
) {
    for x in x0..x1 {
        let mp = mid[x];
        let (t1, t2) = (trow[x].re, trow[x].im);
        let (a, b) = (t1.abs(), t2.abs());
        let (px, py) = (t1 >= 0.0, t2 >= 0.0);
        // neighbours towards +u (f) and -u (b)
        let (hl, hr) = (mid[x - 1], mid[x + 1]);
        let (hf, hb) = if px { (hr, hl) } else { (hl, hr) };
        let (vu, vd) = (up[x], dn[x]);
        let (vf, vb) = if py { (vd, vu) } else { (vu, vd) };
        let (dul, dur, ddl, ddr) = (up[x - 1], up[x + 1], dn[x - 1], dn[x + 1]);
        let d_f = if py {
            if px { ddr } else { ddl }
        } else if px {
            dur
        } else {
            dul
        };
        let d_b = if py {
            if px { dul } else { dur }
        } else if px {
            ddl
        } else {
            ddr
        };
        let (w00, w10, w01, w11) = ((mp - a) * (mp - b), a * (mp - b), (mp - a) * b, a * b);
        let base = w00 * mp;
        let fwd = base + w10 * hf + w01 * vf + w11 * d_f;
        let bwd = base + w10 * hb + w01 * vb + w11 * d_b;
        let m3 = mp * mp * mp;
        mask[x] = ((m3 > fwd) & (m3 >= bwd) & (mp > 0.0)) as u8;
    }
}

/// The WTMM test of row `y`, pixels `x0..x1`, on rows padded by one wrapped
/// pixel on each side (`rows` = M above, at and below `y`; `tp` = T of row
/// `y`, padded likewise), pushing the candidates in raster order.
fn nms_padded_row(
    rows: [&[f64]; 3],
    tp: &[Complex64],
    (x0, x1): (usize, usize),
    y: usize,
    mask: &mut [u8],
    cand: &mut Vec<Px>,
) {
    let [up, mid, dn] = rows;
    nms_row(up, mid, dn, tp, x0 + 1, x1 + 1, mask);
    for_each_set(&mask[x0 + 1..x1 + 1], |i| {
        let x = x0 + i;
        cand.push(Px {
            x: x as u32,
            y: y as u32,
            m: mid[x + 1],
            t: tp[x + 1],
        });
    });
}

/// `dst = [src[n-1], src[0..n], src[0]]`: a row with one wrapped pixel on
/// each side (periodic domains).
fn pad_wrapped<T: Copy>(src: &[T], dst: &mut [T]) {
    let n = src.len();
    dst[0] = src[n - 1];
    dst[1..=n].copy_from_slice(src);
    dst[n + 1] = src[0];
}

fn adjacent(p: (u32, u32), q: (u32, u32), period: Option<(u32, u32)>) -> bool {
    let near = |a: u32, b: u32, n: Option<u32>| {
        let d = (a as i64 - b as i64).abs();
        d <= 1 || n.is_some_and(|n| d == n as i64 - 1)
    };
    near(p.0, q.0, period.map(|p| p.0)) && near(p.1, q.1, period.map(|p| p.1))
}

/// Calls `f(i)` for each local maximum of `v` along a chain: one call per
/// plateau (its middle index), which must be strictly above its neighbours
/// on both sides. On a closed chain indices wrap; on an open chain a plateau
/// that reaches an end is never a maximum (the end points of a chain carry
/// no WTMMM, as in the reference implementation xsmurf, `wt2d/single_max.c`,
/// where a WTMMM needs occupied neighbours on two sides). A chain whose
/// values are all equal yields its middle point.
pub fn for_each_chain_max(v: &[f64], closed: bool, mut f: impl FnMut(usize)) {
    let n = v.len();
    if n == 0 {
        return;
    }
    // runs of equal values, walked without storing them: `run(k)` starts
    // where the previous one ended
    let run_end = |a: usize| {
        let mut b = a;
        while b + 1 < n && v[b + 1] == v[a] {
            b += 1;
        }
        b
    };
    let first_end = run_end(0);
    if first_end == n - 1 {
        f(n / 2); // a flat chain
        return;
    }
    // on a closed chain, the last run joins the first when their values match
    let mut last_start = n - 1;
    while last_start > 0 && v[last_start - 1] == v[n - 1] {
        last_start -= 1;
    }
    let wrap = closed && v[0] == v[n - 1];
    let mut a = if wrap { last_start } else { 0 };
    let mut b = first_end;
    // left neighbour of the first run: wraps on a closed chain
    let mut prev: Option<f64> = match (closed, wrap) {
        (false, _) => None, // the first run touches an end
        (true, false) => Some(v[n - 1]),
        (true, true) => Some(v[last_start - 1]),
    };
    loop {
        let val = v[b];
        let next_start = b + 1;
        let done = next_start >= if wrap { last_start } else { n };
        // right neighbour of the last run: the first run on a closed chain
        let right = if !done {
            Some(v[next_start])
        } else if closed {
            Some(v[0])
        } else {
            None
        };
        if prev.is_some_and(|l| val > l) && right.is_some_and(|r| val > r) {
            let len = if a <= b { b - a + 1 } else { n - a + b + 1 };
            f((a + len / 2) % n);
        }
        if done {
            break;
        }
        prev = Some(val);
        a = next_start;
        b = run_end(a);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn maxima(v: &[f64], closed: bool) -> Vec<usize> {
        let mut out = Vec::new();
        for_each_chain_max(v, closed, |i| out.push(i));
        out
    }

    #[test]
    fn chain_maxima_rules() {
        assert_eq!(maxima(&[1.0, 3.0, 2.0, 5.0, 4.0], false), vec![1, 3]);
        // the ends of an open chain are never maxima
        assert_eq!(maxima(&[5.0, 3.0, 2.0, 4.0], false), Vec::<usize>::new());
        assert_eq!(maxima(&[5.0, 5.0, 2.0, 3.0, 1.0], false), vec![3]);
        // ends wrap on a closed chain: 5 vs 4 -> only index 0
        assert_eq!(maxima(&[5.0, 3.0, 2.0, 4.0], true), vec![0]);
        // a plateau gives its middle
        assert_eq!(maxima(&[1.0, 3.0, 3.0, 3.0, 1.0], false), vec![2]);
        // a flat chain gives one point
        assert_eq!(maxima(&[2.0; 6], true), vec![3]);
        // a plateau across the closing point of a closed chain
        assert_eq!(maxima(&[3.0, 3.0, 1.0, 2.0, 1.0, 3.0], true), vec![0, 3]);
    }

    /// The chain decomposition written plainly: components in raster order
    /// of their first pixel; each walk starts at the unwalked pixel with the
    /// fewest unwalked neighbours (every end equal), then the smallest
    /// modulus, then the first in raster order, and steps to an unwalked
    /// 4-neighbour if there is one, else a diagonal one, of the largest
    /// modulus, then the first in raster order.
    /// Also counts the closed chains, the components split into several
    /// chains, and those of them whose first pixel is an end.
    fn reference_chains(
        pix: &[(u32, u32)],
        m: &[f64],
        ny: u32,
        nx: u32,
        torus: bool,
    ) -> (Vec<Chain>, [usize; 3]) {
        let index: std::collections::HashMap<(u32, u32), usize> =
            pix.iter().enumerate().map(|(i, &p)| (p, i)).collect();
        // (neighbour, diagonal)
        let nbd = |i: usize| -> Vec<(usize, bool)> {
            let (x, y) = pix[i];
            NEIGH
                .iter()
                .filter_map(|&(dx, dy)| {
                    let (mut qx, mut qy) = (x as i64 + dx as i64, y as i64 + dy as i64);
                    if torus {
                        (qx, qy) = (qx.rem_euclid(nx as i64), qy.rem_euclid(ny as i64));
                    }
                    if qx < 0 || qy < 0 {
                        return None;
                    }
                    index
                        .get(&(qx as u32, qy as u32))
                        .map(|&q| (q, dx != 0 && dy != 0))
                })
                .collect()
        };
        let nb = |i: usize| -> Vec<usize> { nbd(i).into_iter().map(|(q, _)| q).collect() };
        let n = pix.len();
        let (mut seen, mut walked) = (vec![false; n], vec![false; n]);
        let mut chains = Vec::new();
        let mut counts = [0; 3];
        for seed in 0..n {
            if seen[seed] {
                continue;
            }
            let mut comp = vec![seed];
            seen[seed] = true;
            let mut i = 0;
            while i < comp.len() {
                for q in nb(comp[i]) {
                    if !seen[q] {
                        seen[q] = true;
                        comp.push(q);
                    }
                }
                i += 1;
            }
            comp.sort();
            let chains_before = chains.len();
            let mut first = true;
            while comp.iter().any(|&p| !walked[p]) {
                let (mut start, mut best) = (0, usize::MAX);
                for &p in &comp {
                    if walked[p] {
                        continue;
                    }
                    let c = nb(p).into_iter().filter(|&q| !walked[q]).count().max(1);
                    if c < best || (c == best && (m[p] < m[start] || m[p] == m[start] && p < start))
                    {
                        (start, best) = (p, c);
                    }
                }
                let mut order = Vec::new();
                let mut cur = start;
                loop {
                    walked[cur] = true;
                    order.push(cur);
                    let next = nbd(cur).into_iter().filter(|&(q, _)| !walked[q]).min_by(
                        |&(q, dq), &(r, dr)| {
                            dq.cmp(&dr).then(m[r].total_cmp(&m[q])).then(q.cmp(&r))
                        },
                    );
                    match next {
                        Some((q, _)) => cur = q,
                        None => break,
                    }
                }
                let m = order.len();
                let closed = first
                    && best > 1
                    && m == comp.len()
                    && m >= 3
                    && adjacent(pix[order[0]], pix[order[m - 1]], torus.then_some((nx, ny)));
                first = false;
                counts[0] += closed as usize;
                chains.push(Chain {
                    pixels: order.iter().map(|&p| pix[p]).collect(),
                    closed,
                });
            }
            if chains.len() > chains_before + 1 {
                counts[1] += 1;
                counts[2] += (nb(comp[0]).len() <= 1) as usize;
            }
        }
        (chains, counts)
    }

    #[test]
    fn chains_match_the_plain_decomposition() {
        // random pixel sets, sparse to dense (dense ones are tangles whose
        // components split into many chains), on the plane and the torus
        let mut rng = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = move || {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            rng
        };
        let mut seen = [0; 3];
        for trial in 0..600 {
            let (ny, nx) = (5 + next() % 20, 5 + next() % 20);
            let density = [0.12, 0.25, 0.4, 0.6][trial % 4];
            let torus = trial % 8 >= 4;
            let pix: Vec<(u32, u32)> = (0..ny * nx)
                .filter(|_| (next() % 1000) as f64 / 1000.0 < density)
                .map(|i| ((i % nx) as u32, (i / nx) as u32))
                .collect();
            // few distinct moduli: ties between them are common
            let m: Vec<f64> = pix.iter().map(|_| 1.0 + (next() % 7) as f64).collect();
            let cand = pix
                .iter()
                .zip(&m)
                .map(|(&(x, y), &m)| Px {
                    x,
                    y,
                    m,
                    t: Complex64::new(1.0, 0.5),
                })
                .collect();
            let mut s = DetectScratch {
                cand,
                ..Default::default()
            };
            let domain = Domain::interior(ny as usize, nx as usize, if torus { 0 } else { 1 });
            assert_eq!(domain.is_torus(), torus);
            let out = finish(ScaleMaxima::default(), 8.0, &domain, 0.0, 1.0, true, &mut s);
            let (want, counts) = reference_chains(&pix, &m, ny as u32, nx as u32, torus);
            assert_eq!(out.chains, want, "trial {trial}: {ny}x{nx}, torus {torus}");
            assert_eq!(out.n_chains, want.len());
            assert_eq!(out.n_wtmm, pix.len());
            for (s, c) in seen.iter_mut().zip(counts) {
                *s += c;
            }
        }
        // closed chains, split components, and split components whose
        // raster-first pixel is an end (whose walk need not start there)
        assert!(seen.iter().all(|&c| c >= 50), "{seen:?}");
    }

    /// The slow reference: list the runs, then test each against its
    /// neighbouring runs.
    fn reference(v: &[f64], closed: bool) -> Vec<usize> {
        let n = v.len();
        let mut runs: Vec<(usize, usize)> = Vec::new();
        let mut s = 0;
        for i in 1..=n {
            if i == n || v[i] != v[s] {
                runs.push((s, i - 1));
                s = i;
            }
        }
        if runs.len() == 1 {
            return vec![n / 2];
        }
        if closed && v[0] == v[n - 1] {
            let (ls, _) = runs.pop().unwrap();
            runs[0].0 = ls;
        }
        let r = runs.len();
        let mut out = Vec::new();
        for k in 0..r {
            let (a, b) = runs[k];
            let val = v[b];
            let left = if k > 0 {
                Some(v[runs[k - 1].1])
            } else if closed {
                Some(v[runs[r - 1].1])
            } else {
                None
            };
            let right = if k + 1 < r {
                Some(v[runs[k + 1].0])
            } else if closed {
                Some(v[runs[0].0])
            } else {
                None
            };
            if left.is_some_and(|l| val > l) && right.is_some_and(|rr| val > rr) {
                let len = if a <= b { b - a + 1 } else { n - a + b + 1 };
                out.push((a + len / 2) % n);
            }
        }
        out
    }

    #[test]
    fn chain_maxima_match_the_reference() {
        // small alphabets make plateaus and wrapped plateaus frequent
        let mut state = 12345u64;
        for _ in 0..20000 {
            state = crate::synth::splitmix64(state);
            let n = 1 + (state % 9) as usize;
            let v: Vec<f64> = (0..n)
                .map(|i| (crate::synth::splitmix64(state ^ i as u64) % 3) as f64)
                .collect();
            for closed in [false, true] {
                let mut got = maxima(&v, closed);
                let mut want = reference(&v, closed);
                got.sort_unstable();
                want.sort_unstable();
                assert_eq!(got, want, "{v:?} closed={closed}");
            }
        }
    }

    /// The tie rule of the NMS (`M(p) > M(p+u)`, `M(p) >= M(p-u)`): on a
    /// ridge two pixels wide, both of equal modulus, exactly one column is
    /// WTMM, the one ahead along `u` (a strict or a loose test on both sides
    /// would keep none or both); a ridge one pixel wide keeps its pixel.
    /// Both NMS paths: the streaming interior and the wrapped torus rows.
    #[test]
    fn ridge_plateau_keeps_one_column() {
        let (ny, nx) = (16, 24);
        for (ridge, sign, want) in [
            (&[10usize, 11][..], 1.0, 11u32),
            (&[10, 11][..], -1.0, 10),
            (&[10][..], 1.0, 10),
            (&[10][..], -1.0, 10),
        ] {
            // M falls by 1 per pixel away from the ridge (>= 8 > 0 on the
            // torus); T real, so u = (sign, 0)
            let t = Array2::from_shape_fn((ny, nx), |(_, x)| {
                let d = ridge.iter().map(|&r| x.abs_diff(r)).min().unwrap();
                Complex64::new(sign * (20.0 - d as f64), 0.0)
            });
            for margin in [3, 0] {
                let dom = Domain::interior(ny, nx, margin);
                assert_eq!(dom.wraps(2.0), margin == 0);
                let mut s = DetectScratch::default();
                let sm = detect(&t, 0, 2.0, &dom, 0.0, true, &mut s);
                let px: Vec<_> = sm.chains.iter().flat_map(|c| c.pixels.clone()).collect();
                let tag = format!("ridge {ridge:?} sign {sign} margin {margin}");
                assert_eq!(sm.n_wtmm, ny - 2 * margin, "{tag}");
                assert_eq!(px.len(), sm.n_wtmm, "{tag}");
                assert!(px.iter().all(|&(x, _)| x == want), "{tag}: {px:?}");
            }
        }
    }

    /// `counts` is the half-open rectangle `[x0, x1) x [y0, y1)` and
    /// `area` its pixel count, by brute force over every pixel.
    #[test]
    fn counting_rectangle_is_half_open() {
        for (ny, nx, margin) in [(9, 13, 2), (8, 8, 0), (6, 11, 3), (4, 4, 2), (5, 7, 9)] {
            let dom = Domain::interior(ny, nx, margin);
            let mut n = 0;
            for y in 0..ny + 2 {
                for x in 0..nx + 2 {
                    let inside = x >= margin && x + margin < nx && y >= margin && y + margin < ny;
                    assert_eq!(
                        dom.counts(x as u32, y as u32),
                        inside,
                        "{ny}x{nx} m{margin} ({x},{y})"
                    );
                    n += inside as usize;
                }
            }
            assert_eq!(dom.area(), n, "{ny}x{nx} m{margin}");
            assert_eq!(dom.is_empty(), n == 0, "{ny}x{nx} m{margin}");
        }
    }
}
