//! One scale: WTMM by non-maximum suppression, maxima chains, WTMMM
//! (SPEC §2; II §3, Figs 9 and 15).

use ndarray::Array2;
use num_complex::Complex64;
use serde::{Deserialize, Serialize};

use crate::cwt::argument;

/// A local maximum of the modulus along a maxima chain (a WTMMM).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Wtmmm {
    /// Column and row of the pixel.
    pub x: u32,
    pub y: u32,
    /// Modulus M.
    pub m: f64,
    /// Argument A = atan2(T2, T1) (radians; y axis pointing down the rows).
    pub arg: f64,
    /// Index of its chain in this scale's chain list.
    pub chain: u32,
}

/// An 8-connected maxima chain, as an ordered list of pixels `(x, y)`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Chain {
    pub pixels: Vec<(u32, u32)>,
    /// The chain closes on itself (last pixel 8-adjacent to the first, no end).
    pub closed: bool,
}

/// Everything found at one scale.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ScaleMaxima {
    pub j: usize,
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

/// Where maxima are looked for: the interior rectangle `[y0, y1) x [x0, x1)`
/// (SPEC §1 margin), minus the pixels too close to a masked pixel.
#[derive(Clone, Debug)]
pub struct Domain {
    pub ny: usize,
    pub nx: usize,
    pub y0: usize,
    pub y1: usize,
    pub x0: usize,
    pub x1: usize,
    /// Euclidean distance (px) from each pixel to the nearest masked pixel;
    /// `None` without a mask.
    pub mask_distance: Option<Array2<f32>>,
    /// A WTMM at scale a is kept only if `mask_distance > support * a`.
    pub support: f64,
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
        }
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
    /// 1 = WTMM pixel not yet chained, 2 = chained.
    flag: Vec<u8>,
    wtmm: Vec<u32>,
    stack: Vec<u32>,
    comp: Vec<u32>,
    order: Vec<u32>,
    mvals: Vec<f64>,
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
    let mut out = ScaleMaxima {
        j,
        a,
        ..Default::default()
    };
    if domain.is_empty() {
        return out;
    }
    let ts = t.as_slice().expect("CWT output is contiguous");
    s.modulus.resize(ny * nx, 0.0);
    for (m, z) in s.modulus.iter_mut().zip(ts) {
        *m = (z.re * z.re + z.im * z.im).sqrt();
    }
    let m = &s.modulus;
    let mut mmax: f64 = 0.0;
    for y in domain.y0..domain.y1 {
        for &v in &m[y * nx + domain.x0..y * nx + domain.x1] {
            mmax = mmax.max(v);
        }
    }
    if mmax <= 0.0 || !mmax.is_finite() {
        return out;
    }
    let thr = eps * mmax;
    let min_dist = (domain.support * a) as f32;

    // 1. non-maximum suppression along the gradient
    s.flag.clear();
    s.flag.resize(ny * nx, 0);
    s.wtmm.clear();
    for y in domain.y0..domain.y1 {
        let ym = if y == 0 { ny - 1 } else { y - 1 };
        let yp = if y + 1 == ny { 0 } else { y + 1 };
        for x in domain.x0..domain.x1 {
            let p = y * nx + x;
            let mp = m[p];
            if mp < thr || mp == 0.0 {
                continue;
            }
            let inv = 1.0 / mp;
            let (u1, u2) = (ts[p].re * inv, ts[p].im * inv);
            let xm = if x == 0 { nx - 1 } else { x - 1 };
            let xp = if x + 1 == nx { 0 } else { x + 1 };
            // forward point p + u: the cell spanned by (x or xm .. x or xp)
            let (cx0, cx1, fx) = if u1 >= 0.0 {
                (x, xp, u1)
            } else {
                (xm, x, 1.0 + u1)
            };
            let (cy0, cy1, fy) = if u2 >= 0.0 {
                (y, yp, u2)
            } else {
                (ym, y, 1.0 + u2)
            };
            let fwd = bilinear(m, nx, cy0, cy1, cx0, cx1, fx, fy);
            if !(mp > fwd) {
                continue;
            }
            let (bx0, bx1, gx) = if u1 > 0.0 {
                (xm, x, 1.0 - u1)
            } else {
                (x, xp, -u1)
            };
            let (by0, by1, gy) = if u2 > 0.0 {
                (ym, y, 1.0 - u2)
            } else {
                (y, yp, -u2)
            };
            let bwd = bilinear(m, nx, by0, by1, bx0, bx1, gx, gy);
            if !(mp >= bwd) {
                continue;
            }
            if let Some(d) = &domain.mask_distance
                && d[[y, x]] <= min_dist
            {
                continue;
            }
            s.flag[p] = 1;
            s.wtmm.push(p as u32);
        }
    }
    out.n_wtmm = s.wtmm.len();

    // 2. chains, 3. WTMMM
    let inside = |x: i64, y: i64| {
        x >= domain.x0 as i64
            && x < domain.x1 as i64
            && y >= domain.y0 as i64
            && y < domain.y1 as i64
    };
    for wi in 0..s.wtmm.len() {
        let seed = s.wtmm[wi];
        if s.flag[seed as usize] != 1 {
            continue;
        }
        // the 8-connected component (flag 1 -> 3 while collecting)
        s.comp.clear();
        s.stack.clear();
        s.stack.push(seed);
        s.flag[seed as usize] = 3;
        while let Some(p) = s.stack.pop() {
            s.comp.push(p);
            let (x, y) = ((p as usize % nx) as i64, (p as usize / nx) as i64);
            for (dx, dy) in NEIGH {
                let (xx, yy) = (x + dx as i64, y + dy as i64);
                if !inside(xx, yy) {
                    continue;
                }
                let q = yy as usize * nx + xx as usize;
                if s.flag[q] == 1 {
                    s.flag[q] = 3;
                    s.stack.push(q as u32);
                }
            }
        }
        // deterministic order: walk from raster-first endpoints
        s.comp.sort_unstable();
        let comp_len = s.comp.len();
        let mut remaining = comp_len;
        let mut first_walk = true;
        while remaining > 0 {
            // start: an unvisited pixel (flag 3) with the fewest unvisited neighbours
            let mut start = u32::MAX;
            let mut best = u32::MAX;
            for &p in &s.comp {
                if s.flag[p as usize] != 3 {
                    continue;
                }
                let c = count_neighbours(&s.flag, nx, p, 3, &inside);
                if c < best {
                    best = c;
                    start = p;
                    if c <= 1 {
                        break;
                    }
                }
            }
            let had_end = best <= 1;
            s.order.clear();
            let mut cur = start;
            loop {
                s.flag[cur as usize] = 2;
                s.order.push(cur);
                remaining -= 1;
                let (x, y) = ((cur as usize % nx) as i64, (cur as usize / nx) as i64);
                let mut next = u32::MAX;
                for (dx, dy) in NEIGH {
                    let (xx, yy) = (x + dx as i64, y + dy as i64);
                    if inside(xx, yy) {
                        let q = yy as usize * nx + xx as usize;
                        if s.flag[q] == 3 {
                            next = q as u32;
                            break;
                        }
                    }
                }
                if next == u32::MAX {
                    break;
                }
                cur = next;
            }
            let n = s.order.len();
            let closed = first_walk
                && !had_end
                && n == comp_len
                && n >= 3
                && adjacent(s.order[0], s.order[n - 1], nx);
            first_walk = false;
            let chain_id = out.n_chains as u32;
            out.n_chains += 1;
            if n >= 3 {
                s.mvals.clear();
                s.mvals.extend(s.order.iter().map(|&p| m[p as usize]));
                for_each_chain_max(&s.mvals, closed, |i| {
                    let p = s.order[i] as usize;
                    out.wtmmm.push(Wtmmm {
                        x: (p % nx) as u32,
                        y: (p / nx) as u32,
                        m: m[p],
                        arg: argument(ts[p]),
                        chain: chain_id,
                    });
                });
            }
            if keep_chains {
                out.chains.push(Chain {
                    pixels: s
                        .order
                        .iter()
                        .map(|&p| ((p as usize % nx) as u32, (p as usize / nx) as u32))
                        .collect(),
                    closed,
                });
            }
        }
    }
    // leave the flags clean for the next scale is not needed: they are reset
    out
}

#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn bilinear(
    m: &[f64],
    nx: usize,
    y0: usize,
    y1: usize,
    x0: usize,
    x1: usize,
    fx: f64,
    fy: f64,
) -> f64 {
    let a = m[y0 * nx + x0] + fx * (m[y0 * nx + x1] - m[y0 * nx + x0]);
    let b = m[y1 * nx + x0] + fx * (m[y1 * nx + x1] - m[y1 * nx + x0]);
    a + fy * (b - a)
}

fn count_neighbours(
    flag: &[u8],
    nx: usize,
    p: u32,
    want: u8,
    inside: &impl Fn(i64, i64) -> bool,
) -> u32 {
    let (x, y) = ((p as usize % nx) as i64, (p as usize / nx) as i64);
    let mut c = 0;
    for (dx, dy) in NEIGH {
        let (xx, yy) = (x + dx as i64, y + dy as i64);
        if inside(xx, yy) && flag[yy as usize * nx + xx as usize] == want {
            c += 1;
        }
    }
    c
}

fn adjacent(p: u32, q: u32, nx: usize) -> bool {
    let (px, py) = ((p as usize % nx) as i64, (p as usize / nx) as i64);
    let (qx, qy) = ((q as usize % nx) as i64, (q as usize / nx) as i64);
    (px - qx).abs() <= 1 && (py - qy).abs() <= 1
}

/// Calls `f(i)` for each local maximum of `v` along a chain: one call per
/// plateau (its middle index). On an open chain the ends count as maxima
/// when they exceed their single neighbour; on a closed chain indices wrap.
/// A chain whose values are all equal yields its middle point.
pub fn for_each_chain_max(v: &[f64], closed: bool, mut f: impl FnMut(usize)) {
    let n = v.len();
    if n == 0 {
        return;
    }
    // runs of equal values
    let mut runs: Vec<(usize, usize)> = Vec::new();
    let mut s = 0;
    for i in 1..=n {
        if i == n || v[i] != v[s] {
            runs.push((s, i - 1));
            s = i;
        }
    }
    if closed && runs.len() > 1 && v[0] == v[n - 1] {
        // the first and last runs are one plateau across the closing point
        let (ls, _) = runs.pop().expect("len > 1");
        runs[0].0 = ls; // start index > end index marks the wrap
    }
    let r = runs.len();
    if r == 1 {
        f(n / 2);
        return;
    }
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
        if left.is_none_or(|l| val > l) && right.is_none_or(|rr| val > rr) {
            let len = if a <= b { b - a + 1 } else { n - a + b + 1 };
            f((a + len / 2) % n);
        }
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
        // ends count on an open chain
        assert_eq!(maxima(&[5.0, 3.0, 2.0, 4.0], false), vec![0, 3]);
        // ends wrap on a closed chain: 5 vs 4 -> only index 0
        assert_eq!(maxima(&[5.0, 3.0, 2.0, 4.0], true), vec![0]);
        // a plateau gives its middle
        assert_eq!(maxima(&[1.0, 3.0, 3.0, 3.0, 1.0], false), vec![2]);
        // a flat chain gives one point
        assert_eq!(maxima(&[2.0; 6], true), vec![3]);
        // a plateau across the closing point of a closed chain
        assert_eq!(maxima(&[3.0, 3.0, 1.0, 2.0, 1.0, 3.0], true), vec![0, 3]);
    }
}
