//! Linking WTMMM across scales into maxima lines (SPEC §3).
//!
//! From `a_min` upward, each line alive at `a_j` looks for the WTMMM of
//! `a_{j+1}` inside a search box and a modulus-ratio window, takes the
//! nearest; links are one-to-one and when two lines want the same candidate
//! the nearer wins (ties: the lower line id) and the other line ends. Lines
//! are born only at `a_min`. Only the previous scale's line ends and the
//! current scale's WTMMM are needed, so linking streams with the CWT.

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
    Reference { cap: f64 },
    /// `max(min, factor * a)`: proportional to scale.
    Proportional { factor: f64, min: f64 },
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
    pub x: u32,
    pub y: u32,
    /// Modulus at this scale.
    pub m: f64,
    /// Running sup of the modulus from `a_min` up to this scale (SPEC §4 sup rule).
    pub sup: f64,
    /// Argument A.
    pub arg: f64,
}

/// A maxima line born at `a_min`: `points[j]` is its WTMMM at scale `j`;
/// it dies after `points.len()` scales.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct MaximaLine {
    pub points: Vec<LinePoint>,
}

/// Linking parameters.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct LinkParams {
    pub radius: SearchRadius,
    /// Accept a candidate only when `lo < M_up / M_down < hi`. This bounds
    /// the local exponents a line can follow: with `v` voices per octave,
    /// `v log2(lo) < h < v log2(hi)` (±1.5 for (0.9, 1.11) and 10 voices:
    /// rough surfaces; smooth regions seen by the mexican wavelet grow as
    /// a^3 and need a wider window).
    pub ratio: (f64, f64),
}

impl Default for LinkParams {
    /// Ratio window (0.9, 1.11): with the plain modulus it gives the best
    /// worst case of τ(q) over the presets (README, validation), as the
    /// prototype of SPEC §14 found.
    fn default() -> Self {
        LinkParams {
            radius: SearchRadius::default(),
            ratio: (0.9, 1.11),
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
    // reused buffers
    grid: Vec<u32>,
    grid_start: Vec<u32>,
    want: Vec<(u32, f64)>,
    owner: Vec<(u32, f64)>,
}

impl Linker {
    pub fn new(params: LinkParams) -> Self {
        Linker {
            params,
            lines: Vec::new(),
            alive: Vec::new(),
            last: Vec::new(),
            next_scale: 0,
            grid: Vec::new(),
            grid_start: Vec::new(),
            want: Vec::new(),
            owner: Vec::new(),
        }
    }

    /// Lines alive after the last push.
    pub fn alive(&self) -> usize {
        self.alive.len()
    }

    /// Adds the WTMMM of the next scale. At scale 0 every WTMMM starts a line.
    ///
    /// **Panics** if scales are pushed out of order.
    pub fn push(&mut self, sm: &ScaleMaxima) -> Endings {
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
        let ri = r.floor() as i64;
        // bucket the candidates on a grid of cell size `cell`
        let cell = (ri.max(1) + 1) as u32;
        let gx = sm.wtmmm.iter().map(|w| w.x / cell).max().unwrap_or(0) + 1;
        let gy = sm.wtmmm.iter().map(|w| w.y / cell).max().unwrap_or(0) + 1;
        let ncell = (gx * gy) as usize;
        self.grid_start.clear();
        self.grid_start.resize(ncell + 1, 0);
        for w in &sm.wtmmm {
            self.grid_start[((w.y / cell) * gx + w.x / cell) as usize + 1] += 1;
        }
        for i in 0..ncell {
            self.grid_start[i + 1] += self.grid_start[i];
        }
        self.grid.clear();
        self.grid.resize(sm.wtmmm.len(), 0);
        let mut fill = self.grid_start.clone();
        for (k, w) in sm.wtmmm.iter().enumerate() {
            let c = ((w.y / cell) * gx + w.x / cell) as usize;
            self.grid[fill[c] as usize] = k as u32;
            fill[c] += 1;
        }
        // each alive line's nearest acceptable candidate
        self.want.clear();
        for last in &self.last {
            let (cx, cy) = (last.x / cell, last.y / cell);
            let mut best = (u32::MAX, f64::INFINITY);
            let mut in_box = false;
            for yy in cy.saturating_sub(1)..=(cy + 1).min(gy - 1) {
                for xx in cx.saturating_sub(1)..=(cx + 1).min(gx - 1) {
                    let c = (yy * gx + xx) as usize;
                    for &k in
                        &self.grid[self.grid_start[c] as usize..self.grid_start[c + 1] as usize]
                    {
                        let w = &sm.wtmmm[k as usize];
                        let (dx, dy) = (w.x as i64 - last.x as i64, w.y as i64 - last.y as i64);
                        if dx.abs() > ri || dy.abs() > ri {
                            continue;
                        }
                        let d2 = (dx * dx + dy * dy) as f64;
                        if d2 > max_d2 {
                            continue;
                        }
                        in_box = true;
                        let ratio = w.m / last.m;
                        if !(ratio > lo && ratio < hi) {
                            continue;
                        }
                        if d2 < best.1 || (d2 == best.1 && k < best.0) {
                            best = (k, d2);
                        }
                    }
                }
            }
            if best.0 == u32::MAX {
                if in_box {
                    ends.ratio += 1;
                } else {
                    ends.no_candidate += 1;
                }
            }
            self.want.push(best);
        }
        // resolve contested candidates: the nearer line wins, ties to the lower id
        self.owner.clear();
        self.owner.resize(sm.wtmmm.len(), (u32::MAX, f64::INFINITY));
        for (i, &(k, d2)) in self.want.iter().enumerate() {
            if k == u32::MAX {
                continue;
            }
            let o = &mut self.owner[k as usize];
            let l = self.alive[i];
            if d2 < o.1 || (d2 == o.1 && l < o.0) {
                *o = (l, d2);
            }
        }
        let mut next_alive = Vec::with_capacity(self.alive.len());
        let mut next_last = Vec::with_capacity(self.alive.len());
        for (i, &(k, _)) in self.want.iter().enumerate() {
            let l = self.alive[i];
            if k == u32::MAX {
                continue; // the line ends here (counted above)
            }
            if self.owner[k as usize].0 != l {
                ends.contested += 1;
                continue;
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
        self.alive = next_alive;
        self.last = next_last;
        ends
    }

    /// The finished lines.
    pub fn finish(self) -> Vec<MaximaLine> {
        self.lines
    }
}
