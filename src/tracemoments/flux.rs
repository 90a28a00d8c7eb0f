//! The flux `φ` estimated from a field (TM §5.2; SPEC §8), and the
//! box pyramid used to coarse-grain it.

use ndarray::{Array2, ArrayView2};
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::field::Field;
use crate::synth::fif::fractional_integrate;

/// How the flux is obtained from the field (a fractional differentiation of
/// order 1, enough for H < 1; TM §5.2).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum FluxKind {
    /// Modulus of the forward-difference gradient, on the 3-point stencil
    /// `φ(y,x) = sqrt((f[y,x+1] - f[y,x])² + (f[y+1,x] - f[y,x])²)`.
    Gradient,
    /// Modulus of the three finest-scale (undecimated) Haar wavelet
    /// coefficients of the 2x2 cell with corners `a = f[y,x], b = f[y,x+1],
    /// c = f[y+1,x], d = f[y+1,x+1]`:
    /// `((b-a+d-c)/2, (c-a+d-b)/2, (a-b-c+d)/2)`.
    Wavelet,
}

impl FluxKind {
    /// The name the command line and the JSON use (`gradient`, `wavelet`).
    pub fn name(self) -> &'static str {
        match self {
            FluxKind::Gradient => "gradient",
            FluxKind::Wavelet => "wavelet",
        }
    }
}

/// How the box means of the flux are averaged over the boxes of one scale
/// into the trace moment `<φ_λ^q>` (module docs of
/// [`crate::tracemoments`], "Boxes with missing pixels").
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum BoxWeights {
    /// Every box with a valid pixel, weighted by its share of valid pixels:
    /// every valid pixel weighs the same at every scale, so the moments of
    /// all scales average over the same region and the flux's mean is the
    /// same at every scale (K(1) = 0) whatever the holes and borders.
    Count,
    /// Every box at least half valid, each weighted as a whole one (the
    /// estimator before count weights): boxes along holes and the borders
    /// weigh more than their pixels.
    Equal,
}

impl BoxWeights {
    /// For `serde(default)`: accumulators saved before this option existed
    /// weighted their boxes equally.
    pub(crate) fn equal() -> Self {
        BoxWeights::Equal
    }

    /// The name the command line and the JSON use.
    pub fn name(self) -> &'static str {
        match self {
            BoxWeights::Count => "count",
            BoxWeights::Equal => "equal",
        }
    }
}

/// Fractional differentiation applied to the field before the modulus
/// (TM §5.2: inverting the fractional integration of order H needs "a
/// fractional differentiation of order H or greater"). The total order of the
/// flux is this order plus the modulus' own order 1 (see the module docs of
/// [`crate::tracemoments`] for the bias of each choice).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum FluxDiff {
    /// None: the modulus alone, a differentiation of order 1 (TM §5.2,
    /// Lavallée et al. 1993). It leaves a derivative of order `1 - H` of the
    /// flux, too little when H is well above 1/2.
    None,
    /// Order `H` estimated per image as `ξ(1)`, the first-order
    /// structure-function exponent of the field (`ξ(1) = H - K(1) = H`, seed
    /// 000 eq 10), so that the modulus then acts on the flux itself (order 1
    /// in excess of H whatever H).
    Auto,
    /// A fixed order (negative: a fractional integration).
    Order(f64),
}

impl FluxDiff {
    /// For `serde(default)`: accumulators saved before this option existed
    /// used no differentiation.
    pub(crate) fn none() -> Self {
        FluxDiff::None
    }
}

/// `H = ξ(1)` of one field: slope of `log2 <|Δf(l)|>` against `log2 l` over
/// horizontal and vertical increments at lags `l = 2^j`, fitted over
/// `j ∈ [1, max(log2 L - 3, 2)]` (the default structure-function range of
/// [`crate::tracemoments::TraceMomentFitConfig`]), with `L` the largest power
/// of two `<= min(ny, nx)`. Pairs with a masked end are skipped. First
/// differences saturate: the estimate stays in about `[0, 1]`. `None` when
/// fewer than 2 lags have increments or the field is constant.
pub(crate) fn hurst_sf(field: &Field) -> Option<f64> {
    let (ny, nx) = field.dim();
    let f = &field.data;
    let kmax = (ny.min(nx) as f64).log2().floor();
    let (lo, hi) = (1.0, (kmax - 3.0).max(2.0));
    let (mut xs, mut ys) = (Vec::new(), Vec::new());
    let mut j = 0usize;
    while (1usize << j) * 4 <= ny.min(nx) {
        let l = 1usize << j;
        let jf = j as f64;
        j += 1;
        if jf < lo || jf > hi {
            continue;
        }
        let (mut s, mut n) = (0.0, 0u64);
        for y in 0..ny {
            for x in 0..nx {
                if field.is_masked(y, x) {
                    continue;
                }
                if x + l < nx && !field.is_masked(y, x + l) {
                    s += (f[[y, x + l]] - f[[y, x]]).abs();
                    n += 1;
                }
                if y + l < ny && !field.is_masked(y + l, x) {
                    s += (f[[y + l, x]] - f[[y, x]]).abs();
                    n += 1;
                }
            }
        }
        if n > 0 && s > 0.0 {
            xs.push(jf);
            ys.push((s / n as f64).log2());
        }
    }
    crate::stats::fit::line_fit(&xs, &ys)
        .map(|f| f.slope)
        .filter(|h| h.is_finite())
}

/// `f` extended to `2ny x 2nx` by mirror symmetry (even, so periodic
/// without a jump at the borders).
fn mirror(f: ArrayView2<f64>) -> Array2<f64> {
    let (ny, nx) = f.dim();
    Array2::from_shape_fn((2 * ny, 2 * nx), |(y, x)| {
        let yy = if y < ny { y } else { 2 * ny - 1 - y };
        let xx = if x < nx { x } else { 2 * nx - 1 - x };
        f[[yy, xx]]
    })
}

/// Fractional integration of order `order` of a field: masked pixels
/// filled harmonically ([`Field::filled_harmonic`]; a mean fill puts a
/// step along every hole's rim, which the filter spreads far into the
/// valid flux), then filter `|k|^-order`, on the field itself when it is
/// `periodic`, otherwise on its mirror extension to twice the size (no
/// border jump for the periodic FFT filter), cropped.
pub(crate) fn smooth(field: &Field, order: f64, periodic: bool) -> Result<Array2<f64>> {
    // a torus's holes are filled across its borders too
    smooth_filled(field.filled_harmonic_on(periodic)?, order, periodic)
}

/// [`smooth`] of a field already filled ([`Field::filled_harmonic_on`]
/// with the same `periodic`).
pub(crate) fn smooth_filled(
    mut filled: Array2<f64>,
    order: f64,
    periodic: bool,
) -> Result<Array2<f64>> {
    // the filter drops the mean (k = 0), so removing it first changes
    // nothing but the rounding: an offset of 1e13 on a field of unit
    // roughness moved alpha by 3e-5 through the FFT of the raw values
    let mean = filled.mean().unwrap_or(0.0);
    filled.mapv_inplace(|v| v - mean);
    if periodic {
        return fractional_integrate(filled.view(), order);
    }
    let (ny, nx) = filled.dim();
    let ext = mirror(filled.view());
    let out = fractional_integrate(ext.view(), order)?;
    Ok(out.slice(ndarray::s![0..ny, 0..nx]).to_owned())
}

/// The flux of `f` on the `ny x nx` grid with its validity (`true` = valid).
/// Every cell touching a masked pixel is invalid, and so are the last row
/// and column (no forward neighbour) unless the field is `periodic`: on a
/// torus the forward neighbour of the last row is the first, every box of
/// the pyramid is whole, and the flux's mean is the same at every scale
/// (K(1) = 0 to rounding).
pub(crate) fn flux(
    f: ArrayView2<f64>,
    mask: Option<ArrayView2<bool>>,
    kind: FluxKind,
    periodic: bool,
) -> Result<(Array2<f64>, Array2<bool>)> {
    let (ny, nx) = f.dim();
    if ny < 2 || nx < 2 {
        return Err(Error::Input(format!(
            "image {ny}x{nx} too small for a flux"
        )));
    }
    let bad = |y: usize, x: usize| mask.as_ref().is_some_and(|m| m[[y, x]]);
    let mut phi = Array2::<f64>::zeros((ny, nx));
    let mut ok = Array2::<bool>::from_elem((ny, nx), false);
    let (ey, ex) = if periodic { (ny, nx) } else { (ny - 1, nx - 1) };
    for y in 0..ey {
        // forward neighbours, wrapped on a torus
        let y1 = (y + 1) % ny;
        for x in 0..ex {
            let x1 = (x + 1) % nx;
            let a = f[[y, x]];
            let b = f[[y, x1]];
            let c = f[[y1, x]];
            let valid = match kind {
                FluxKind::Gradient => !(bad(y, x) || bad(y, x1) || bad(y1, x)),
                FluxKind::Wavelet => !(bad(y, x) || bad(y, x1) || bad(y1, x) || bad(y1, x1)),
            };
            if !valid {
                continue;
            }
            let v = match kind {
                FluxKind::Gradient => ((b - a).powi(2) + (c - a).powi(2)).sqrt(),
                FluxKind::Wavelet => {
                    let d = f[[y1, x1]];
                    let h = 0.5 * (b - a + d - c);
                    let v = 0.5 * (c - a + d - b);
                    let g = 0.5 * (a - b - c + d);
                    (h * h + v * v + g * g).sqrt()
                }
            };
            if !v.is_finite() {
                return Err(Error::Input("non-finite value in the field".into()));
            }
            phi[[y, x]] = v;
            ok[[y, x]] = true;
        }
    }
    Ok((phi, ok))
}

/// The windows every level of the box pyramid is computed on, as `(y0, x0,
/// ny, nx)`: of sides the largest multiples of `L = 2^floor(log2 min(ny,
/// nx))` that fit, anchored at the four corners (the distinct ones; one
/// window, the image, when both sides are multiples of L). Every level must
/// average over the same region: boxes tiled from one corner would cover
/// less and less of a non-power-of-two image as they grow (25 % of a 511^2
/// image at 256 px against all of it at 2 px), so the moments of different
/// scales would see different parts of the field, and a conserved flux
/// would not keep K(1) = 0 (log2 <φ_λ> drifted by +0.36 on a 511^2 FIF).
/// The windows cover every pixel; the overlap weighs the central pixels
/// more, the same at every level.
pub(crate) fn windows(ny: usize, nx: usize) -> Vec<(usize, usize, usize, usize)> {
    let l = 1usize << (ny.min(nx) as f64).log2().floor() as u32;
    let (ry, rx) = (ny / l * l, nx / l * l);
    let mut ys = vec![0, ny - ry];
    let mut xs = vec![0, nx - rx];
    ys.dedup();
    xs.dedup();
    ys.iter()
        .flat_map(|&y| xs.iter().map(move |&x| (y, x, ry, rx)))
        .collect()
}

/// Sums and valid counts over boxes of side `2^k`, `k = 0..=kmax`
/// (`kmax = floor(log2 min(ny, nx))`); boxes tile the array from the
/// top-left corner. Built per window of [`windows`], whose sides are
/// multiples of the largest box, so every level covers the whole window.
pub(crate) struct Pyramid {
    /// Per level: `(ny_k, nx_k)` boxes.
    pub dims: Vec<(usize, usize)>,
    /// Per level: number of valid pixels in each box (row-major).
    pub counts: Vec<Vec<u32>>,
}

impl Pyramid {
    pub(crate) fn new(valid: ArrayView2<bool>) -> Self {
        let (ny, nx) = valid.dim();
        let kmax = (ny.min(nx) as f64).log2().floor() as usize;
        let mut dims = vec![(ny, nx)];
        let mut counts = vec![valid.iter().map(|&v| v as u32).collect::<Vec<u32>>()];
        for k in 1..=kmax {
            let (py, px) = dims[k - 1];
            let (cy, cx) = (py / 2, px / 2);
            let prev = &counts[k - 1];
            let mut c = vec![0u32; cy * cx];
            for y in 0..cy {
                for x in 0..cx {
                    let i = 2 * y * px + 2 * x;
                    c[y * cx + x] = prev[i] + prev[i + 1] + prev[i + px] + prev[i + px + 1];
                }
            }
            dims.push((cy, cx));
            counts.push(c);
        }
        Pyramid { dims, counts }
    }

    pub(crate) fn levels(&self) -> usize {
        self.dims.len()
    }

    /// Box sums of `v` (row-major, `0` where invalid) at every level.
    pub(crate) fn sums(&self, v: Vec<f64>) -> Vec<Vec<f64>> {
        let mut out = vec![v];
        self.sums_in(&mut out);
        out
    }

    /// [`Self::sums`] in `levels`, whose first holds the values: the
    /// coarser levels reuse the vectors already there (the double trace
    /// moments take 16 pyramids of one window; allocated anew, those of a
    /// 2048^2 window were page-faulted in every time).
    pub(crate) fn sums_in(&self, levels: &mut Vec<Vec<f64>>) {
        levels.truncate(self.levels().max(1));
        for k in 1..self.levels() {
            let px = self.dims[k - 1].1;
            let (cy, cx) = self.dims[k];
            if levels.len() <= k {
                levels.push(Vec::new());
            }
            let (done, rest) = levels.split_at_mut(k);
            let (prev, s) = (&done[k - 1], &mut rest[0]);
            s.clear();
            s.resize(cy * cx, 0.0);
            for y in 0..cy {
                for x in 0..cx {
                    let i = 2 * y * px + 2 * x;
                    s[y * cx + x] = prev[i] + prev[i + 1] + prev[i + px] + prev[i + px + 1];
                }
            }
        }
    }

    /// The boxes of level `k` that `rule` keeps (with [`BoxWeights::Equal`]
    /// those at least half valid, with [`BoxWeights::Count`] those with a
    /// valid pixel), as `(index, valid pixels)` in raster order, bucketed
    /// into `n` groups by `group` of their `(row, column)` of boxes (the
    /// tiles of a jackknife; one group for the whole image).
    pub(crate) fn kept_by(
        &self,
        k: usize,
        group: impl Fn(usize, usize) -> usize,
        rule: BoxWeights,
        n: usize,
    ) -> Vec<Vec<(usize, u32)>> {
        // a box with a valid pixel has a mean; the equal rule also wants
        // half of it valid, lest one pixel weigh as a whole box
        let least = match rule {
            BoxWeights::Count => 1,
            BoxWeights::Equal => (1u64 << (2 * k)).div_ceil(2).max(1),
        };
        let cx = self.dims[k].1.max(1);
        let mut out = vec![Vec::new(); n];
        for (i, &c) in self.counts[k].iter().enumerate() {
            if c as u64 >= least {
                out[group(i / cx, i % cx)].push((i, c));
            }
        }
        out
    }

    /// The box averages of `boxes` ([`Self::kept_by`]) from their `sums`.
    pub(crate) fn means_of(sums: &[f64], boxes: &[(usize, u32)]) -> Vec<f64> {
        let mut m = Vec::new();
        Self::means_into(sums, boxes, &mut m);
        m
    }

    /// [`Self::means_of`] into `out` (its vector reused).
    pub(crate) fn means_into(sums: &[f64], boxes: &[(usize, u32)], out: &mut Vec<f64>) {
        out.clear();
        out.extend(boxes.iter().map(|&(i, c)| sums[i] / c as f64));
    }

    /// Natural logs of [`Self::means_of`].
    pub(crate) fn log_means_of(sums: &[f64], boxes: &[(usize, u32)]) -> Vec<f64> {
        let mut m = Self::means_of(sums, boxes);
        for v in m.iter_mut() {
            *v = v.ln();
        }
        m
    }

    /// The weights of `boxes` of level `k` ([`Self::kept_by`]), in their
    /// order, under `rule`: `None` for [`BoxWeights::Equal`] (all 1), the
    /// share of valid pixels `c / 4^k` for [`BoxWeights::Count`] (exact: a
    /// power of 2 divides; whole boxes weigh 1). With their sum in valid
    /// pixels (`Σ c`), or the number of boxes.
    pub(crate) fn weights_of(
        boxes: &[(usize, u32)],
        k: usize,
        rule: BoxWeights,
    ) -> (Option<Vec<f64>>, u64) {
        match rule {
            BoxWeights::Equal => (None, boxes.len() as u64),
            BoxWeights::Count => {
                let full = (1u64 << (2 * k)) as f64;
                let total = boxes.iter().map(|&(_, c)| u64::from(c)).sum();
                let w = boxes.iter().map(|&(_, c)| c as f64 / full).collect();
                (Some(w), total)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The fractional derivative of the flux sees a hole through its fill.
    /// A tilted fBm surface (a DEM's trend: 10 standard deviations across)
    /// with a 40 x 60 lake: beyond 4 px from the lake, the order-0.5
    /// derivative of the holed field departs from that of the whole field
    /// by 0.045 of the latter's standard deviation (rms) with the mean fill
    /// (a step along the rim, whose response decays like a power of the
    /// distance), 0.0015 with the harmonic fill. Asserted: the harmonic
    /// fill leaves less than a third of the mean fill's contamination.
    #[test]
    fn harmonic_fill_keeps_the_hole_out_of_the_derivative() {
        let n = 256;
        let mut f = crate::synth::fbm::fbm(crate::synth::fbm::FbmParams { hurst: 0.6 }, n, n, 3, 0)
            .unwrap();
        let sd = f.std(0.0);
        for ((y, x), v) in f.indexed_iter_mut() {
            *v += 10.0 * sd * (x as f64 + 0.5 * y as f64) / n as f64;
        }
        let hole = |y: usize, x: usize| (100..140).contains(&y) && (90..150).contains(&x);
        let mask = Array2::from_shape_fn((n, n), |(y, x)| hole(y, x));
        let whole = smooth(&Field::new(f.clone()), -0.5, false).unwrap();
        let holed = Field::with_mask(f.clone(), mask).unwrap();
        let far = |y: usize, x: usize| !((96..144).contains(&y) && (86..154).contains(&x));
        let rms = |g: &Array2<f64>| {
            let (mut s, mut k) = (0.0, 0.0);
            for ((y, x), v) in g.indexed_iter() {
                if far(y, x) {
                    s += (v - whole[[y, x]]).powi(2);
                    k += 1.0;
                }
            }
            (s / k).sqrt() / whole.std(0.0)
        };
        let harmonic = rms(&smooth(&holed, -0.5, false).unwrap());
        let mean_fill = {
            let ext = mirror(holed.filled().unwrap().view());
            let out = fractional_integrate(ext.view(), -0.5).unwrap();
            rms(&out.slice(ndarray::s![0..n, 0..n]).to_owned())
        };
        eprintln!("contamination (rms / sd): mean fill {mean_fill:.4}, harmonic {harmonic:.4}");
        assert!(harmonic < mean_fill / 3.0, "{harmonic} vs {mean_fill}");
    }

    #[test]
    fn gradient_of_a_plane() {
        // f = 3x + 4y: |grad| = 5 everywhere valid; Haar: (3, 4, 0) -> 5
        let f = Array2::from_shape_fn((5, 6), |(y, x)| 3.0 * x as f64 + 4.0 * y as f64);
        for kind in [FluxKind::Gradient, FluxKind::Wavelet] {
            let (phi, ok) = flux(f.view(), None, kind, false).unwrap();
            for ((y, x), &v) in ok.indexed_iter() {
                assert_eq!(v, y < 4 && x < 5);
                if v {
                    assert!((phi[[y, x]] - 5.0).abs() < 1e-12);
                }
            }
        }
        // on a torus the last row and column take the first as their
        // forward neighbour: every cell is valid, the wrap a jump
        let (phi, ok) = flux(f.view(), None, FluxKind::Gradient, true).unwrap();
        assert!(ok.iter().all(|&v| v));
        assert_eq!(phi[[1, 2]], 5.0);
        assert_eq!(phi[[0, 5]], (15f64.powi(2) + 4f64.powi(2)).sqrt());
        assert_eq!(phi[[4, 0]], (3f64.powi(2) + 16f64.powi(2)).sqrt());
        // a masked pixel invalidates the cells that reach it across the wrap
        let mut m = Array2::from_elem((5, 6), false);
        m[[0, 0]] = true;
        let (_, ok) = flux(f.view(), Some(m.view()), FluxKind::Gradient, true).unwrap();
        for (y, x) in [(0, 0), (0, 5), (4, 0)] {
            assert!(!ok[[y, x]], "({y}, {x})");
        }
        assert_eq!(ok.iter().filter(|&&v| !v).count(), 3);
    }

    #[test]
    fn pyramid_keeps_and_weights_boxes_by_rule() {
        let mut valid = Array2::from_elem((4, 4), true);
        for y in 0..4 {
            valid[[y, 0]] = false;
            valid[[y, 1]] = false;
            valid[[y, 2]] = false;
        }
        let p = Pyramid::new(valid.view());
        assert_eq!(p.levels(), 3);
        let s = p.sums(valid.iter().map(|&v| v as u8 as f64).collect());
        let all = |k: usize, rule: BoxWeights| p.kept_by(k, |_, _| 0, rule, 1).remove(0);
        // level 1: left boxes empty (dropped), right boxes half valid (kept)
        assert_eq!(
            Pyramid::log_means_of(&s[1], &all(1, BoxWeights::Equal)).len(),
            2
        );
        // level 2: 4 of 16 valid: dropped
        assert!(all(2, BoxWeights::Equal).is_empty());
        // count weights keep every box with a valid pixel, weighted by its
        // share of them: the 4 valid pixels weigh 4 at level 0, 2 x 2/4 at
        // level 1 and 4/16 at level 2, the same 4 pixels throughout
        let weights = |k: usize, rule: BoxWeights| Pyramid::weights_of(&all(k, rule), k, rule);
        assert_eq!(weights(0, BoxWeights::Count), (Some(vec![1.0; 4]), 4));
        assert_eq!(weights(1, BoxWeights::Count), (Some(vec![0.5, 0.5]), 4));
        assert_eq!(weights(2, BoxWeights::Count), (Some(vec![0.25]), 4));
        assert_eq!(
            Pyramid::means_of(&s[2], &all(2, BoxWeights::Count)),
            vec![1.0]
        );
        // equal weights count the boxes they keep
        assert_eq!(weights(1, BoxWeights::Equal), (None, 2));
        assert_eq!(weights(2, BoxWeights::Equal), (None, 0));
        // `group` buckets boxes by (row, column), in raster order, under
        // either rule
        let rows = p.kept_by(1, |by, _| by, BoxWeights::Count, 2);
        assert_eq!(rows, vec![vec![(1, 2)], vec![(3, 2)]]);
        assert_eq!(
            Pyramid::weights_of(&rows[0], 1, BoxWeights::Count),
            (Some(vec![0.5]), 2)
        );
    }
}
