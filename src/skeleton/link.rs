//! Linking WTMMM across scales into maxima lines (SPEC §3).
//!
//! From `a_min` upward, each line alive at `a_j` looks for the WTMMM of
//! `a_{j+1}` inside a search box (its half-width evaluated at `a_{j+1}`,
//! the scale looked at; SPEC §3 does not say which) and a modulus-ratio
//! window, takes the nearest; links are one-to-one and when two lines want the same candidate
//! the nearer wins and the other line ends. Ties of distance, common on the
//! pixel grid, go to the modulus closer to the line's (not to the order of
//! a scan, which would make the skeleton depend on the image's
//! orientation), and only exact ties of both to the lower index. Lines
//! are born only at `a_min`. Only the previous scale's line ends and the
//! current scale's WTMMM are needed, so linking streams with the CWT.
//!
//! Optionally (`LinkParams::climb`, off by default) a line left without a
//! WTMMM follows the maxima chain it lands on to that chain's local maximum,
//! wherever along the chain it has moved (README, "Why mexican lines die").

use serde::{Deserialize, Serialize};

use super::maxima::ScaleMaxima;

/// Half-width of the square search box, in pixels, as a function of scale.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "rule", rename_all = "lowercase")]
pub enum SearchRadius {
    /// The reference implementation's box, `min(cap, 2 log2(6.98 a))`
    /// (SPEC §3; about 6.8 px at a = 1.5, capped at 7 px), with candidates
    /// also within the Euclidean distance `d^2 < cap^2 + 1` (xsmurf
    /// `wt2d/chain2.c`: `dist < 50` for the 7 px cap).
    Reference {
        /// Largest half-width, in pixels (7 in the reference; default 12).
        cap: f64,
    },
    /// `max(min, factor * a)`: proportional to scale.
    Proportional {
        /// Half-width per unit scale (px per px of `a`).
        factor: f64,
        /// Smallest half-width, in pixels.
        min: f64,
    },
}

impl Default for SearchRadius {
    /// The reference box with a 12 px cap: with the reference's 7 px, lines
    /// die too fast beyond a ~ 8 px (no candidate in the box) and τ(0)
    /// steepens to -2.07..-2.09 over the fit range; 12 px gives
    /// D(h(0)) = 1.98..2.03 on the presets (README, validation).
    fn default() -> Self {
        SearchRadius::Reference { cap: 12.0 }
    }
}

impl SearchRadius {
    /// Largest accepted squared distance (px^2), whatever the box.
    pub fn max_d2(&self) -> f64 {
        match *self {
            SearchRadius::Reference { cap } => cap * cap + 1.0 - 1e-9,
            SearchRadius::Proportional { .. } => f64::INFINITY,
        }
    }

    /// Half-width in pixels at scale `a`.
    pub fn at(&self, a: f64) -> f64 {
        match *self {
            SearchRadius::Reference { cap } => (2.0 * (6.98 * a).log2()).min(cap).max(1.0),
            SearchRadius::Proportional { factor, min } => (factor * a).max(min),
        }
    }
}

/// One point of a maxima line.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct LinePoint {
    /// Column of the WTMMM.
    pub x: u32,
    /// Row of the WTMMM (0 at the top).
    pub y: u32,
    /// Modulus at this scale.
    pub m: f64,
    /// Running sup of the modulus from `a_min` up to this scale (SPEC §4 sup rule).
    pub sup: f64,
    /// Argument A.
    pub arg: f64,
}

/// A maxima line born at `a_min`: `points[j]` is its WTMMM at scale `j`;
/// it dies after `points.len()` scales. On a torus ([`Linker::periodic`])
/// consecutive points may lie on opposite edges of the image.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct MaximaLine {
    /// The line's WTMMM, one per scale from `a_min` (index = scale index).
    pub points: Vec<LinePoint>,
}

/// Linking parameters.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct LinkParams {
    /// Half-width of the search box per scale (default: reference box, 12 px cap).
    pub radius: SearchRadius,
    /// Accept a candidate only when `lo < M_up / M_down < hi`. This bounds
    /// the local exponents a line can follow: with `v` voices per octave,
    /// `v log2(lo) < h < v log2(hi)` (±1.5 for (0.9, 1.11) and 10 voices:
    /// rough surfaces; smooth regions seen by the mexican wavelet grow as
    /// a^3 and need a wider window).
    pub ratio: (f64, f64),
    /// Second chance along the chain (off by default; README, "Why mexican
    /// lines die"): a line left without a WTMMM lands on the nearest
    /// maxima-chain pixel of the next scale (inside the box), climbs the
    /// modulus along that chain to its local maximum, and takes that WTMMM
    /// when no line takes it and its modulus ratio lies in `ratio`, however
    /// far along the chain it is. Needs the chains and their moduli
    /// ([`Linker::push_with`]). A line kept alive this way competes for the
    /// boxes' candidates at the next scales, so other lines can end sooner
    /// than without the climb (on an isolated cusp, a line of the taper ring
    /// lived 17 scales instead of 28): the climb changes the whole skeleton,
    /// not only the lines it rescues.
    #[serde(default)]
    pub climb: bool,
}

impl Default for LinkParams {
    /// Ratio window (0.9, 1.11): with the plain modulus it gives the best
    /// worst case of τ(q) over the presets (README, validation), as the
    /// prototype of SPEC §14 found.
    fn default() -> Self {
        LinkParams {
            radius: SearchRadius::default(),
            ratio: (0.9, 1.11),
            climb: false,
        }
    }
}

/// Why lines ended at one scale (diagnostics of the linking rules).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Endings {
    /// No WTMMM inside the search box.
    pub no_candidate: usize,
    /// Candidates in the box, none inside the modulus-ratio window.
    pub ratio: usize,
    /// The nearest acceptable candidate went to a nearer line.
    pub contested: usize,
    /// Of the lines counted above, those linked by climbing their chain
    /// (`LinkParams::climb`).
    #[serde(default)]
    pub climb: usize,
}

/// `(x - last.x, y - last.y)`, the shortest way round on a torus of
/// `period = (nx, ny)`.
fn offset(last: &LinePoint, x: u32, y: u32, period: Option<(u32, u32)>) -> (i64, i64) {
    let d = |a: u32, b: u32, n: Option<u32>| {
        let d = a as i64 - b as i64;
        match n {
            // the nearest image: |d| < n as both lie on the torus (no
            // division: this runs for every candidate of every line)
            Some(n) => {
                let n = n as i64;
                if 2 * d > n {
                    d - n
                } else if 2 * d <= -n {
                    d + n
                } else {
                    d
                }
            }
            None => d,
        }
    };
    (
        d(x, last.x, period.map(|p| p.0)),
        d(y, last.y, period.map(|p| p.1)),
    )
}

/// The WTMMM of one scale bucketed on a grid of cells at least `cell`
/// pixels wide.
#[derive(Default)]
struct Buckets {
    cell: u32,
    gx: u32,
    gy: u32,
    /// `(nx, ny)` on a torus: `gx x gy` cells tile it exactly (widths
    /// `nx / gx >= cell`), neighbouring cells and distances wrap.
    period: Option<(u32, u32)>,
    start: Vec<u32>,
    idx: Vec<u32>,
    /// `(x, y, m)` of `idx[i]`, in the same (cell) order: the search reads
    /// its cells' WTMMM contiguously.
    pts: Vec<(u32, u32, f64)>,
}

impl Buckets {
    fn cell_of(&self, x: u32, y: u32) -> (u32, u32) {
        match self.period {
            Some((nx, ny)) => (
                (x as u64 * self.gx as u64 / nx as u64) as u32,
                (y as u64 * self.gy as u64 / ny as u64) as u32,
            ),
            None => (x / self.cell, y / self.cell),
        }
    }

    fn fill(&mut self, sm: &ScaleMaxima, cell: u32, period: Option<(u32, u32)>) {
        self.cell = cell;
        self.period = period;
        (self.gx, self.gy) = match period {
            Some((nx, ny)) => ((nx / cell).max(1), (ny / cell).max(1)),
            None => (
                sm.wtmmm.iter().map(|w| w.x / cell).max().unwrap_or(0) + 1,
                sm.wtmmm.iter().map(|w| w.y / cell).max().unwrap_or(0) + 1,
            ),
        };
        let ncell = (self.gx * self.gy) as usize;
        self.start.clear();
        self.start.resize(ncell + 1, 0);
        for w in &sm.wtmmm {
            let (cx, cy) = self.cell_of(w.x, w.y);
            self.start[(cy * self.gx + cx) as usize + 1] += 1;
        }
        for i in 0..ncell {
            self.start[i + 1] += self.start[i];
        }
        self.idx.clear();
        self.idx.resize(sm.wtmmm.len(), 0);
        self.pts.clear();
        self.pts.resize(sm.wtmmm.len(), (0, 0, 0.0));
        let mut fill = self.start.clone();
        for (k, w) in sm.wtmmm.iter().enumerate() {
            let (cx, cy) = self.cell_of(w.x, w.y);
            let c = (cy * self.gx + cx) as usize;
            self.idx[fill[c] as usize] = k as u32;
            self.pts[fill[c] as usize] = (w.x, w.y, w.m);
            fill[c] += 1;
        }
    }

    /// The cells `c - 1 ..= c + 1` along an axis of `g` cells (wrapped on a
    /// torus, each once).
    fn around(c: u32, g: u32, wrap: bool) -> impl Iterator<Item = u32> {
        let cells: [Option<u32>; 3] = if wrap {
            let (prev, next) = ((c + g - 1) % g, (c + 1) % g);
            [
                Some(prev),
                (c != prev).then_some(c),
                (next != prev && next != c).then_some(next),
            ]
        } else {
            // a line end may lie beyond the last occupied cell
            [c.checked_sub(1), Some(c), Some(c + 1)].map(|c| c.filter(|&c| c < g))
        };
        cells.into_iter().flatten()
    }

    /// The nearest WTMMM to `last` within the box of half-width `ri` (and
    /// `d^2 <= max_d2`) whose modulus ratio lies in `(lo, hi)`: `(index,
    /// d^2)` (`u32::MAX` if none), and whether the box held any WTMMM at
    /// all. `ri` must not exceed the cell size.
    fn nearest(
        &self,
        last: &LinePoint,
        ri: i64,
        max_d2: f64,
        (lo, hi): (f64, f64),
    ) -> (Want, bool) {
        let (cx, cy) = self.cell_of(last.x, last.y);
        let mut best = NO_WANT;
        let mut in_box = false;
        let wrap = self.period.is_some();
        for yy in Self::around(cy, self.gy, wrap) {
            for xx in Self::around(cx, self.gx, wrap) {
                let c = (yy * self.gx + xx) as usize;
                let cell = self.start[c] as usize..self.start[c + 1] as usize;
                for (&k, &(x, y, m)) in self.idx[cell.clone()].iter().zip(&self.pts[cell]) {
                    let (dx, dy) = offset(last, x, y, self.period);
                    if dx.abs() > ri || dy.abs() > ri {
                        continue;
                    }
                    let d2 = (dx * dx + dy * dy) as f64;
                    if d2 > max_d2 {
                        continue;
                    }
                    in_box = true;
                    let ratio = m / last.m;
                    if !(ratio > lo && ratio < hi) {
                        continue;
                    }
                    let w = (k, d2, ratio.max(1.0 / ratio));
                    if closer(w, best) {
                        best = w;
                    }
                }
            }
        }
        (best, in_box)
    }
}

/// A line's choice: `(candidate, d^2, r)` with `r = max(ratio, 1/ratio)`
/// of the moduli (candidate over the line's last), 1 for equal moduli.
type Want = (u32, f64, f64);

/// No candidate.
const NO_WANT: Want = (u32::MAX, f64::INFINITY, f64::INFINITY);

/// `a` goes before `b`: nearer, then (at equal distance, common on the
/// pixel grid) the modulus closer to the line's, then the lower index
/// (exact ties only). Distances and moduli are the same for a flipped,
/// transposed or rotated image, indices are not.
fn closer(a: Want, b: Want) -> bool {
    a.1 < b.1 || (a.1 == b.1 && (a.2 < b.2 || (a.2 == b.2 && a.0 < b.0)))
}

/// One-to-one resolution: `want[i]` is line `ids[i]`'s choice; of the lines
/// wanting one candidate, the nearer wins, then the one whose modulus is
/// closer to the candidate's, then the lower id (exact ties only). Returns,
/// per entry, whether it won.
fn resolve(want: &[Want], ids: &[u32], n: usize, owner: &mut Vec<Want>) -> Vec<bool> {
    owner.clear();
    owner.resize(n, NO_WANT);
    for (i, &(k, d2, r)) in want.iter().enumerate() {
        if k == u32::MAX {
            continue;
        }
        let o = &mut owner[k as usize];
        let w = (ids[i], d2, r);
        if closer(w, *o) {
            *o = w;
        }
    }
    want.iter()
        .enumerate()
        .map(|(i, &(k, ..))| k != u32::MAX && owner[k as usize].0 == ids[i])
        .collect()
}

/// For each line end in `lasts`: the nearest chain pixel inside the box,
/// then the local maximum of the modulus reached by climbing along that
/// chain; `(WTMMM index, d^2 from the line end)` when that maximum is a WTMMM
/// not `taken` with its ratio in `(lo, hi)`, else `(u32::MAX, inf)`.
#[allow(clippy::too_many_arguments)]
fn climb_targets(
    sm: &ScaleMaxima,
    cm: &[Vec<f64>],
    lasts: &[LinePoint],
    ri: i64,
    max_d2: f64,
    (lo, hi): (f64, f64),
    taken: &[bool],
    period: Option<(u32, u32)>,
) -> Vec<Want> {
    let none = NO_WANT;
    let (w, h) = match period {
        Some((nx, ny)) => (nx as usize, ny as usize),
        None => {
            let (w, h) = sm
                .chains
                .iter()
                .flat_map(|c| c.pixels.iter())
                .fold((0u32, 0u32), |(x, y), p| (x.max(p.0), y.max(p.1)));
            (w as usize + 1, h as usize + 1)
        }
    };
    // a box wider than the image searches nothing more (a huge radius
    // looped for ever)
    let ri = ri.min(w.max(h) as i64);
    // chain pixel -> (chain, position along it)
    let mut label = vec![(u32::MAX, 0u32); w * h];
    for (ci, c) in sm.chains.iter().enumerate() {
        for (k, &(x, y)) in c.pixels.iter().enumerate() {
            label[y as usize * w + x as usize] = (ci as u32, k as u32);
        }
    }
    // WTMMM by chain (they come in chain order)
    let mut first = vec![0u32; sm.chains.len() + 1];
    for m in &sm.wtmmm {
        first[m.chain as usize + 1] += 1;
    }
    for i in 0..sm.chains.len() {
        first[i + 1] += first[i];
    }
    lasts
        .iter()
        .map(|last| {
            // the nearest chain pixel; at equal distance the larger modulus
            // (the raster order of the scan would depend on the image's
            // orientation)
            let mut best = (i64::MAX, (u32::MAX, 0u32));
            let m_at = |lb: (u32, u32)| cm[lb.0 as usize][lb.1 as usize];
            for dy in -ri..=ri {
                let mut y = last.y as i64 + dy;
                if period.is_some() {
                    y = y.rem_euclid(h as i64);
                } else if y < 0 || y >= h as i64 {
                    continue;
                }
                for dx in -ri..=ri {
                    let mut x = last.x as i64 + dx;
                    if period.is_some() {
                        x = x.rem_euclid(w as i64);
                    } else if x < 0 || x >= w as i64 {
                        continue;
                    }
                    let d2 = dx * dx + dy * dy;
                    if d2 as f64 > max_d2 || d2 > best.0 {
                        continue;
                    }
                    let lb = label[y as usize * w + x as usize];
                    if lb.0 != u32::MAX && (d2 < best.0 || m_at(lb) > m_at(best.1)) {
                        best = (d2, lb);
                    }
                }
            }
            if best.0 == i64::MAX {
                return none;
            }
            let (ci, k0) = best.1;
            let c = &sm.chains[ci as usize];
            let mv = &cm[ci as usize];
            let n = mv.len();
            let step = |k: usize, fwd: bool| -> Option<usize> {
                if fwd {
                    if k + 1 < n {
                        Some(k + 1)
                    } else if c.closed {
                        Some(0)
                    } else {
                        None
                    }
                } else if k > 0 {
                    Some(k - 1)
                } else if c.closed {
                    Some(n - 1)
                } else {
                    None
                }
            };
            let mut k = k0 as usize;
            for _ in 0..n {
                let up = step(k, true).filter(|&u| mv[u] > mv[k]);
                let dn = step(k, false).filter(|&d| mv[d] > mv[k]);
                k = match (up, dn) {
                    (Some(u), Some(d)) => {
                        if mv[u] >= mv[d] {
                            u
                        } else {
                            d
                        }
                    }
                    (Some(u), None) => u,
                    (None, Some(d)) => d,
                    (None, None) => break,
                };
            }
            let (px, py) = c.pixels[k];
            for m in first[ci as usize]..first[ci as usize + 1] {
                let cand = &sm.wtmmm[m as usize];
                if cand.x == px && cand.y == py {
                    let ratio = cand.m / last.m;
                    if taken[m as usize] || !(ratio > lo && ratio < hi) {
                        return none;
                    }
                    let (dx, dy) = offset(last, px, py, period);
                    return (m, (dx * dx + dy * dy) as f64, ratio.max(1.0 / ratio));
                }
            }
            none
        })
        .collect()
}

/// Streaming linker: feed scales in order with [`Linker::push`].
pub struct Linker {
    params: LinkParams,
    lines: Vec<MaximaLine>,
    /// Lines alive at the last pushed scale, and their last points (kept
    /// contiguous: the search reads them for every line at every scale).
    alive: Vec<u32>,
    last: Vec<LinePoint>,
    next_scale: usize,
    /// `(nx, ny)` when the image is a torus ([`Linker::periodic`]).
    period: Option<(u32, u32)>,
    // reused buffers
    buckets: Buckets,
    want: Vec<Want>,
    owner: Vec<Want>,
}

impl Linker {
    /// An empty linker (plane, not torus); push scale 0 first.
    pub fn new(params: LinkParams) -> Self {
        Linker {
            params,
            lines: Vec::new(),
            alive: Vec::new(),
            last: Vec::new(),
            next_scale: 0,
            period: None,
            buckets: Buckets::default(),
            want: Vec::new(),
            owner: Vec::new(),
        }
    }

    /// Links across the edges of an `nx x ny` torus (distances the shortest
    /// way round), as the chains of a whole periodic domain are traced
    /// ([`super::Domain::is_torus`]); `None` keeps the plane.
    pub fn periodic(mut self, period: Option<(usize, usize)>) -> Self {
        self.period = period.map(|(nx, ny)| (nx as u32, ny as u32));
        self
    }

    /// Lines alive after the last push.
    pub fn alive(&self) -> usize {
        self.alive.len()
    }

    /// Adds the WTMMM of the next scale. At scale 0 every WTMMM starts a line.
    ///
    /// **Panics** if scales are pushed out of order.
    pub fn push(&mut self, sm: &ScaleMaxima) -> Endings {
        self.push_with(sm, None)
    }

    /// [`Linker::push`] with the moduli along `sm.chains` (one vector per
    /// chain, in pixel order), used by the `climb` rule (which is skipped
    /// without them).
    pub fn push_with(&mut self, sm: &ScaleMaxima, chain_m: Option<&[Vec<f64>]>) -> Endings {
        assert_eq!(sm.j, self.next_scale, "scales must be pushed in order");
        let mut ends = Endings::default();
        self.next_scale += 1;
        if sm.j == 0 {
            for w in &sm.wtmmm {
                let p = LinePoint {
                    x: w.x,
                    y: w.y,
                    m: w.m,
                    sup: w.m,
                    arg: w.arg,
                };
                self.alive.push(self.lines.len() as u32);
                self.last.push(p);
                self.lines.push(MaximaLine { points: vec![p] });
            }
            return ends;
        }
        let r = self.params.radius.at(sm.a);
        let max_d2 = self.params.radius.max_d2();
        let (lo, hi) = self.params.ratio;
        // no image is wider than the pixel limit: a larger radius (a huge
        // proportional factor or minimum) reaches as far, and its cell size
        // must stay a u32 (it wrapped to 0, a division by zero)
        let ri = r.min(crate::io::MAX_PIXELS as f64).floor() as i64;
        let cell = (ri.max(1) + 1) as u32;
        self.buckets.fill(sm, cell, self.period);
        // each alive line's nearest acceptable candidate
        self.want.clear();
        for last in &self.last {
            let (best, in_box) = self.buckets.nearest(last, ri, max_d2, (lo, hi));
            if best.0 == u32::MAX {
                if in_box {
                    ends.ratio += 1;
                } else {
                    ends.no_candidate += 1;
                }
            }
            self.want.push(best);
        }
        // resolve contested candidates: the nearer line wins, ties to the
        // closer modulus, then the lower id
        let won = resolve(&self.want, &self.alive, sm.wtmmm.len(), &mut self.owner);
        // the lines left without a WTMMM get a second chance along their chain
        let climb = match chain_m {
            Some(cm) if self.params.climb && !sm.chains.is_empty() => Some(cm),
            _ => None,
        };
        let mut taken = vec![false; if climb.is_some() { sm.wtmmm.len() } else { 0 }];
        let mut next_alive = Vec::with_capacity(self.alive.len());
        let mut next_last = Vec::with_capacity(self.alive.len());
        let mut failed = Vec::new();
        let mut failed_last = Vec::new();
        for (i, &(k, ..)) in self.want.iter().enumerate() {
            let l = self.alive[i];
            if !won[i] {
                if k != u32::MAX {
                    ends.contested += 1;
                }
                if climb.is_some() {
                    failed.push(l);
                    failed_last.push(self.last[i]);
                }
                continue;
            }
            if climb.is_some() {
                taken[k as usize] = true;
            }
            let w = &sm.wtmmm[k as usize];
            let p = LinePoint {
                x: w.x,
                y: w.y,
                m: w.m,
                sup: self.last[i].sup.max(w.m),
                arg: w.arg,
            };
            self.lines[l as usize].points.push(p);
            next_alive.push(l);
            next_last.push(p);
        }
        // climb the chain the line lands on to its maximum
        if let Some(cm) = climb
            && !failed.is_empty()
        {
            let want = climb_targets(
                sm,
                cm,
                &failed_last,
                ri,
                max_d2,
                (lo, hi),
                &taken,
                self.period,
            );
            let won = resolve(&want, &failed, sm.wtmmm.len(), &mut self.owner);
            for (i, &(k, ..)) in want.iter().enumerate() {
                if !won[i] {
                    continue; // the line ends here
                }
                let l = failed[i];
                let w = &sm.wtmmm[k as usize];
                let p = LinePoint {
                    x: w.x,
                    y: w.y,
                    m: w.m,
                    sup: failed_last[i].sup.max(w.m),
                    arg: w.arg,
                };
                self.lines[l as usize].points.push(p);
                next_alive.push(l);
                next_last.push(p);
                ends.climb += 1;
            }
        }
        self.alive = next_alive;
        self.last = next_last;
        ends
    }

    /// The finished lines.
    pub fn finish(self) -> Vec<MaximaLine> {
        self.lines
    }
}

#[cfg(test)]
mod tests {
    //! The linking rules of SPEC §3 on hand-made scales.
    use super::*;

    /// A scale holding WTMMM at `(x, y, M)`.
    fn scale(j: usize, a: f64, pts: &[(u32, u32, f64)]) -> ScaleMaxima {
        ScaleMaxima::from_points(j, a, pts)
    }

    fn link(params: LinkParams, scales: &[ScaleMaxima]) -> (Vec<MaximaLine>, Vec<Endings>) {
        let mut l = Linker::new(params);
        let ends = scales.iter().map(|s| l.push(s)).collect();
        (l.finish(), ends)
    }

    fn xs(line: &MaximaLine) -> Vec<u32> {
        line.points.iter().map(|p| p.x).collect()
    }

    #[test]
    fn the_reference_box_grows_as_two_log2_of_6_98_a_up_to_its_cap() {
        let r = SearchRadius::Reference { cap: 12.0 };
        for a in [1.5, 3.0, 8.0] {
            assert!((r.at(a) - 2.0 * (6.98 * a).log2()).abs() < 1e-12);
        }
        assert!((r.at(1.5) - 6.776).abs() < 1e-3); // about 6.8 px at a_min
        assert_eq!(r.at(100.0), 12.0);
        assert_eq!(SearchRadius::Reference { cap: 7.0 }.at(8.0), 7.0);
        // never below one pixel
        assert_eq!(r.at(0.1), 1.0);
        // xsmurf's Euclidean bound dist^2 < cap^2 + 1 (50 for the 7 px cap)
        let r7 = SearchRadius::Reference { cap: 7.0 };
        assert!(49.0 < r7.max_d2() && r7.max_d2() < 50.0);
        let p = SearchRadius::Proportional {
            factor: 0.5,
            min: 2.0,
        };
        assert_eq!((p.at(1.0), p.at(10.0)), (2.0, 5.0));
        assert_eq!(p.max_d2(), f64::INFINITY);
    }

    #[test]
    fn a_line_takes_the_nearest_candidate_and_keeps_a_running_sup() {
        let s = [
            scale(0, 1.5, &[(50, 50, 1.0)]),
            // 3 px right and 2 px left: the nearer wins
            scale(1, 1.6, &[(53, 50, 1.0), (48, 50, 1.05)]),
            scale(2, 1.7, &[(49, 51, 1.0)]),
        ];
        let (lines, ends) = link(LinkParams::default(), &s);
        assert_eq!(lines.len(), 1);
        assert_eq!(xs(&lines[0]), vec![50, 48, 49]);
        let sup: Vec<f64> = lines[0].points.iter().map(|p| p.sup).collect();
        assert_eq!(sup, vec![1.0, 1.05, 1.05]);
        let m: Vec<f64> = lines[0].points.iter().map(|p| p.m).collect();
        assert_eq!(m, vec![1.0, 1.05, 1.0]);
        assert_eq!(ends[1], Endings::default());
    }

    #[test]
    fn the_euclidean_bound_cuts_the_corners_of_the_box() {
        // 7 px cap at a = 8 (box half-width 7): (7, 0) is inside (d^2 = 49),
        // (5, 5) is in the square box but d^2 = 50 is not below 50
        let params = LinkParams {
            radius: SearchRadius::Reference { cap: 7.0 },
            ..LinkParams::default()
        };
        let s0 = scale(0, 8.0, &[(50, 50, 1.0)]);
        let (lines, _) = link(params, &[s0.clone(), scale(1, 8.5, &[(57, 50, 1.0)])]);
        assert_eq!(xs(&lines[0]), vec![50, 57]);
        let (lines, ends) = link(params, &[s0.clone(), scale(1, 8.5, &[(55, 55, 1.0)])]);
        assert_eq!(lines[0].points.len(), 1);
        assert_eq!(ends[1].no_candidate, 1);
        // and 8 px away along an axis is outside the box
        let (_, ends) = link(params, &[s0, scale(1, 8.5, &[(42, 50, 1.0)])]);
        assert_eq!(ends[1].no_candidate, 1);
    }

    #[test]
    fn the_ratio_window_ends_a_line_whose_candidates_jump() {
        // (0.9, 1.11): a candidate 1 px away with M x 1.3 or x 0.85 is refused,
        // a farther one with M x 1.05 is taken instead
        let s0 = scale(0, 1.5, &[(50, 50, 1.0)]);
        for m in [1.3, 0.85] {
            let (lines, ends) = link(
                LinkParams::default(),
                &[s0.clone(), scale(1, 1.6, &[(51, 50, m)])],
            );
            assert_eq!(lines[0].points.len(), 1, "M ratio {m} accepted");
            assert_eq!(
                ends[1],
                Endings {
                    ratio: 1,
                    ..Endings::default()
                }
            );
        }
        let (lines, _) = link(
            LinkParams::default(),
            &[s0, scale(1, 1.6, &[(51, 50, 1.3), (54, 50, 1.05)])],
        );
        assert_eq!(xs(&lines[0]), vec![50, 54]);
    }

    /// Ties of distance (common on the integer grid) go to the modulus
    /// closer to the line's: a line equidistant from two candidates takes
    /// the one whose modulus is nearer its own (in ratio), and a candidate
    /// equidistant from two lines goes to the line whose modulus is nearer
    /// the candidate's, whatever their order.
    #[test]
    fn distance_ties_go_to_the_closer_modulus() {
        let s0 = scale(0, 1.5, &[(50, 50, 1.0)]);
        // ratios 1.05 and 1 / 0.97 = 1.031
        for (pts, want) in [
            ([(52, 50, 1.05), (48, 50, 0.97)], 48),
            ([(52, 50, 0.97), (48, 50, 1.05)], 52),
        ] {
            let (lines, _) = link(LinkParams::default(), &[s0.clone(), scale(1, 1.6, &pts)]);
            assert_eq!(lines[0].points[1].x, want, "{pts:?}");
        }
        // the candidate (M = 1.06) is 2 px from both lines: ratio 1.06 to
        // the line of M = 1, 1.019 to the line of M = 1.08
        let s1 = scale(1, 1.6, &[(42, 50, 1.06)]);
        for (pts, winner) in [
            ([(40, 50, 1.0), (44, 50, 1.08)], 1),
            ([(40, 50, 1.08), (44, 50, 1.0)], 0),
        ] {
            let (lines, ends) = link(LinkParams::default(), &[scale(0, 1.5, &pts), s1.clone()]);
            assert_eq!(lines[winner].points.len(), 2, "{pts:?}");
            assert_eq!(lines[1 - winner].points.len(), 1, "{pts:?}");
            assert_eq!(ends[1].contested, 1);
        }
    }

    /// Exact ties of distance and modulus are broken by index: a line
    /// equidistant from two equal candidates takes the lower WTMMM index; a
    /// candidate equidistant from two equal lines goes to the lower line id.
    #[test]
    fn ties_go_to_the_lower_index() {
        let s0 = scale(0, 1.5, &[(50, 50, 1.0)]);
        for (pts, want) in [
            ([(52, 50, 1.0), (48, 50, 1.0)], 52),
            ([(48, 50, 1.0), (52, 50, 1.0)], 48),
            ([(50, 52, 1.0), (52, 50, 1.0)], 50),
        ] {
            let (lines, _) = link(LinkParams::default(), &[s0.clone(), scale(1, 1.6, &pts)]);
            assert_eq!(lines[0].points[1].x, want, "{pts:?}");
        }
        let s1 = scale(1, 1.6, &[(42, 50, 1.0)]);
        for (pts, winner) in [
            ([(40, 50, 1.0), (44, 50, 1.0)], 0),
            ([(44, 50, 1.0), (40, 50, 1.0)], 0),
        ] {
            let (lines, ends) = link(LinkParams::default(), &[scale(0, 1.5, &pts), s1.clone()]);
            assert_eq!(lines[winner].points.len(), 2, "{pts:?}");
            assert_eq!(lines[1 - winner].points.len(), 1, "{pts:?}");
            assert_eq!(ends[1].contested, 1);
        }
    }

    #[test]
    fn a_contested_candidate_goes_to_the_nearer_line_and_the_other_ends() {
        // lines at x = 40 and 43; the candidate at 42 is 2 px from the first
        // and 1 px from the second: the second takes it, and the first ends
        // although the candidate at 37 (3 px) was free (one-to-one, no
        // second choice: SPEC §3)
        let s0 = scale(0, 1.5, &[(40, 50, 1.0), (43, 50, 1.0)]);
        let s1 = scale(1, 1.6, &[(42, 50, 1.0), (37, 50, 1.0)]);
        let (lines, ends) = link(LinkParams::default(), &[s0, s1]);
        assert_eq!(xs(&lines[0]), vec![40]);
        assert_eq!(xs(&lines[1]), vec![43, 42]);
        assert_eq!(
            ends[1],
            Endings {
                contested: 1,
                ..Endings::default()
            }
        );
        // equal distances and moduli: the lower line id wins
        let s0 = scale(0, 1.5, &[(40, 50, 1.0), (44, 50, 1.0)]);
        let s1 = scale(1, 1.6, &[(42, 50, 1.0)]);
        let (lines, _) = link(LinkParams::default(), &[s0, s1]);
        assert_eq!((lines[0].points.len(), lines[1].points.len()), (2, 1));
    }

    #[test]
    fn lines_are_born_only_at_the_smallest_scale() {
        // a WTMMM that appears at scale 1 far from every line starts nothing,
        // and a line that has ended is not revived by a later candidate
        let s = [
            scale(0, 1.5, &[(10, 10, 1.0), (80, 80, 1.0)]),
            scale(1, 1.6, &[(10, 11, 1.0), (200, 200, 1.0)]),
            scale(2, 1.7, &[(10, 12, 1.0), (80, 80, 1.0), (200, 200, 1.0)]),
        ];
        let (lines, ends) = link(LinkParams::default(), &s);
        assert_eq!(lines.len(), 2);
        assert_eq!(lines[0].points.len(), 3);
        assert_eq!(lines[1].points.len(), 1);
        assert_eq!(ends[1].no_candidate, 1);
        assert_eq!(ends[2], Endings::default());
    }

    #[test]
    #[should_panic(expected = "scales must be pushed in order")]
    fn scales_out_of_order_panic() {
        let mut l = Linker::new(LinkParams::default());
        l.push(&scale(1, 1.6, &[(1, 1, 1.0)]));
    }
}
