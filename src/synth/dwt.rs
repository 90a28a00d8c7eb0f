//! Periodic separable 2D orthonormal wavelet transform (Daubechies family),
//! the basis the W-cascades of II §2.2 are built on.
//!
//! Written by hand: the Rust wavelet crates we looked at either do 1D only,
//! pad or reflect at the borders instead of wrapping (so the transform is not
//! orthonormal on the torus), or are unmaintained; the W-cascade needs exactly
//! an orthonormal basis of periodic functions on a `2^N x 2^N` grid, which is
//! 200 lines.
//!
//! # Naming
//! `dbN` has **N vanishing moments and 2N taps** (the PyWavelets/MATLAB
//! naming, and Daubechies' *Ten Lectures* index N, table 6.1): `Haar` = db1
//! (2 taps), [`Basis::Db4`] = 8 taps, [`Basis::Db8`] = 16 taps. The paper's
//! "Daubechies 8" cites *Ten Lectures* (ref. 74), hence our `Db8`. (WaveLab's
//! `MakeONFilter('Daubechies', 8)` would be 8 taps, our `Db4`.) The filters
//! are the extremal-phase (minimum-phase) ones, computed to 25 digits by
//! spectral factorisation and rounded to the nearest double.
//!
//! # Convention
//! One analysis level on a periodic signal `x` of even length `n`, lowpass
//! `h` of length `L`, highpass `g[i] = (-1)^i h[L-1-i]`:
//!
//! ```text
//! a[k] = Σ_i h[i] x[(2k+i) mod n],   d[k] = Σ_i g[i] x[(2k+i) mod n],   k < n/2
//! ```
//!
//! stored as `[a | d]`. The periodised filter bank is orthogonal for every even
//! `n`, even when `L > n` (the double-shift orthogonality of `h` survives
//! wrapping), so the transform can go down to a single coefficient.
//!
//! In 2D a level transforms the rows (x), then the columns (y) of the
//! current top-left block, giving the Mallat layout for a block of size
//! `2h x 2w` at that level:
//!
//! ```text
//!            x low        x high
//! y low   [ approx   |  ψ2 = ψ(x)φ(y) ]
//! y high  [ ψ1 = φ(x)ψ(y) | ψ3 = ψ(x)ψ(y) ]
//! ```
//!
//! with ψ1, ψ2, ψ3 named as in II eq 19 (`f[y][x]`, rows are y).

use std::ops::Range;

use ndarray::Array2;
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};

/// Haar (db1) lowpass filter.
const HAAR: [f64; 2] = [
    std::f64::consts::FRAC_1_SQRT_2,
    std::f64::consts::FRAC_1_SQRT_2,
];

/// db4: 4 vanishing moments, 8 taps (extremal phase).
const DB4: [f64; 8] = [
    0.2303778133088965,
    0.7148465705529157,
    0.6308807679298589,
    -0.027983769416859854,
    -0.18703481171909309,
    0.030841381835560764,
    0.0328830116668852,
    -0.010597401785069032,
];

/// db8: 8 vanishing moments, 16 taps (extremal phase).
const DB8: [f64; 16] = [
    0.05441584224310401,
    0.31287159091429995,
    0.6756307362972898,
    0.5853546836542067,
    -0.015829105256349306,
    -0.2840155429615469,
    0.0004724845739132828,
    0.12874742662047847,
    -0.017369301001807547,
    -0.044088253930794755,
    0.013981027917398282,
    0.008746094047405777,
    -0.004870352993451574,
    -0.00039174037337694705,
    0.0006754494064505693,
    -0.00011747678412476953,
];

/// An orthonormal compactly supported 1D wavelet (separable products make
/// the 2D basis). See the module doc for the naming.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum Basis {
    /// db1: 1 vanishing moment, 2 taps; discontinuous basis functions.
    Haar,
    /// 4 vanishing moments, 8 taps.
    Db4,
    /// 8 vanishing moments, 16 taps: the paper's "Daubechies 8".
    #[default]
    Db8,
}

impl Basis {
    /// Lowercase name as on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Basis::Haar => "haar",
            Basis::Db4 => "db4",
            Basis::Db8 => "db8",
        }
    }

    /// Scaling (lowpass) filter `h`, `Σ h = √2`, `Σ h² = 1`.
    pub fn lowpass(self) -> &'static [f64] {
        match self {
            Basis::Haar => &HAAR,
            Basis::Db4 => &DB4,
            Basis::Db8 => &DB8,
        }
    }

    /// Wavelet (highpass) filter `g[i] = (-1)^i h[L-1-i]`.
    pub fn highpass(self) -> Vec<f64> {
        let h = self.lowpass();
        let l = h.len();
        (0..l)
            .map(|i| {
                if i % 2 == 0 {
                    h[l - 1 - i]
                } else {
                    -h[l - 1 - i]
                }
            })
            .collect()
    }

    /// Number of vanishing moments of the wavelet.
    pub fn vanishing_moments(self) -> usize {
        self.lowpass().len() / 2
    }
}

impl std::fmt::Display for Basis {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// How many levels a length `n` allows (the number of times it halves
/// evenly); 0 for `n = 0`.
pub fn max_levels(n: usize) -> usize {
    if n == 0 {
        0
    } else {
        n.trailing_zeros() as usize
    }
}

/// Rows and columns, in the Mallat layout, of the detail block `k` (1, 2 or 3
/// for ψ1, ψ2, ψ3) of the level whose detail blocks are `ny x nx`
/// (a square `2^s x 2^s` level of a W-cascade has `ny = nx = 2^s`).
///
/// **Panics** unless `k` is 1, 2 or 3.
pub fn detail_block(ny: usize, nx: usize, k: usize) -> (Range<usize>, Range<usize>) {
    match k {
        1 => (ny..2 * ny, 0..nx),
        2 => (0..ny, nx..2 * nx),
        3 => (ny..2 * ny, nx..2 * nx),
        _ => panic!("detail block index must be 1, 2 or 3, got {k}"),
    }
}

/// A reusable periodic 2D DWT for one basis; owns its scratch, so repeated
/// transforms of the same size allocate nothing.
#[derive(Clone, Debug)]
pub struct Dwt2 {
    basis: Basis,
    h: Vec<f64>,
    g: Vec<f64>,
    line: Vec<f64>,
    block: Vec<f64>,
}

impl Dwt2 {
    /// A transform for `basis`.
    pub fn new(basis: Basis) -> Self {
        Dwt2 {
            basis,
            h: basis.lowpass().to_vec(),
            g: basis.highpass(),
            line: Vec::new(),
            block: Vec::new(),
        }
    }

    /// The basis.
    pub fn basis(&self) -> Basis {
        self.basis
    }

    fn check(a: &Array2<f64>, levels: usize) -> Result<()> {
        let (ny, nx) = a.dim();
        let most = max_levels(ny).min(max_levels(nx));
        if levels > most {
            return Err(Error::param(
                "levels",
                format!(
                    "{levels} levels need both sides divisible by 2^{levels}; {ny}x{nx} allows {most}"
                ),
            ));
        }
        Ok(())
    }

    /// In-place forward transform over `levels` levels (Mallat layout).
    ///
    /// **Errors** if a side is not divisible by `2^levels`.
    pub fn forward(&mut self, a: &mut Array2<f64>, levels: usize) -> Result<()> {
        Self::check(a, levels)?;
        make_standard(a);
        let (ny, nx) = a.dim();
        self.line.resize(nx.max(ny), 0.0);
        self.block.resize(nx * ny, 0.0);
        let data = a.as_slice_mut().expect("standard layout");
        let (mut bh, mut bw) = (ny, nx);
        for _ in 0..levels {
            // rows (x)
            for y in 0..bh {
                let row = &mut data[y * nx..y * nx + bw];
                self.line[..bw].copy_from_slice(row);
                analysis(&self.h, &self.g, &self.line[..bw], row);
            }
            // columns (y), whole rows at a time so the inner loop is contiguous
            copy_block_out(data, nx, bh, bw, &mut self.block);
            let half = bh / 2;
            for k in 0..half {
                for (filter, out_row) in [(&self.h, k), (&self.g, half + k)] {
                    let dst = &mut data[out_row * nx..out_row * nx + bw];
                    dst.fill(0.0);
                    for (i, &c) in filter.iter().enumerate() {
                        let r = (2 * k + i) % bh;
                        let src = &self.block[r * bw..(r + 1) * bw];
                        for (d, s) in dst.iter_mut().zip(src) {
                            *d += c * s;
                        }
                    }
                }
            }
            bh /= 2;
            bw /= 2;
        }
        Ok(())
    }

    /// In-place inverse of [`Dwt2::forward`] with the same `levels`.
    ///
    /// **Errors** if a side is not divisible by `2^levels`.
    pub fn inverse(&mut self, a: &mut Array2<f64>, levels: usize) -> Result<()> {
        Self::check(a, levels)?;
        make_standard(a);
        let (ny, nx) = a.dim();
        self.line.resize(nx.max(ny), 0.0);
        self.block.resize(nx * ny, 0.0);
        let data = a.as_slice_mut().expect("standard layout");
        for level in (0..levels).rev() {
            let (bh, bw) = (ny >> level, nx >> level);
            // columns (y): the adjoint of the analysis, scatter-add whole rows
            copy_block_out(data, nx, bh, bw, &mut self.block);
            for y in 0..bh {
                data[y * nx..y * nx + bw].fill(0.0);
            }
            let half = bh / 2;
            for k in 0..half {
                for (filter, in_row) in [(&self.h, k), (&self.g, half + k)] {
                    let src = &self.block[in_row * bw..(in_row + 1) * bw];
                    for (i, &c) in filter.iter().enumerate() {
                        let r = (2 * k + i) % bh;
                        let dst = &mut data[r * nx..r * nx + bw];
                        for (d, s) in dst.iter_mut().zip(src) {
                            *d += c * s;
                        }
                    }
                }
            }
            // rows (x)
            for y in 0..bh {
                let row = &mut data[y * nx..y * nx + bw];
                self.line[..bw].copy_from_slice(row);
                synthesis(&self.h, &self.g, &self.line[..bw], row);
            }
        }
        Ok(())
    }
}

/// Owned arrays are normally in standard (row-major, contiguous) layout;
/// a transposed or sliced one is copied once.
fn make_standard(a: &mut Array2<f64>) {
    *a = crate::field::standard(std::mem::take(a));
}

fn copy_block_out(data: &[f64], nx: usize, bh: usize, bw: usize, out: &mut [f64]) {
    for y in 0..bh {
        out[y * bw..(y + 1) * bw].copy_from_slice(&data[y * nx..y * nx + bw]);
    }
}

/// One periodic analysis level: `out = [a | d]`. `x.len()` must be even.
fn analysis(h: &[f64], g: &[f64], x: &[f64], out: &mut [f64]) {
    let n = x.len();
    let half = n / 2;
    let l = h.len();
    for k in 0..half {
        let (mut a, mut d) = (0.0, 0.0);
        let start = 2 * k;
        if start + l <= n {
            // no wrap: the common case, without the modulo
            for ((&hc, &gc), &v) in h.iter().zip(g).zip(&x[start..start + l]) {
                a += hc * v;
                d += gc * v;
            }
        } else {
            for i in 0..l {
                let v = x[(start + i) % n];
                a += h[i] * v;
                d += g[i] * v;
            }
        }
        out[k] = a;
        out[half + k] = d;
    }
}

/// One periodic synthesis level, the transpose of [`analysis`].
fn synthesis(h: &[f64], g: &[f64], c: &[f64], out: &mut [f64]) {
    let n = c.len();
    let half = n / 2;
    let l = h.len();
    out.fill(0.0);
    for k in 0..half {
        let (a, d) = (c[k], c[half + k]);
        let start = 2 * k;
        if start + l <= n {
            for ((&hc, &gc), o) in h.iter().zip(g).zip(&mut out[start..start + l]) {
                *o += hc * a + gc * d;
            }
        } else {
            for i in 0..l {
                out[(start + i) % n] += h[i] * a + g[i] * d;
            }
        }
    }
}

/// In-place periodic 1D forward transform over `levels` levels
/// (`[a_J | d_J | d_{J-1} | ... | d_1]`).
///
/// **Errors** if the length is not divisible by `2^levels`.
pub fn dwt1_forward(x: &mut [f64], basis: Basis, levels: usize) -> Result<()> {
    let n = x.len();
    if levels > max_levels(n) {
        return Err(Error::param(
            "levels",
            format!("{levels} levels need a length divisible by 2^{levels}, got {n}"),
        ));
    }
    let (h, g) = (basis.lowpass(), basis.highpass());
    let mut buf = vec![0.0; n];
    let mut len = n;
    for _ in 0..levels {
        buf[..len].copy_from_slice(&x[..len]);
        analysis(h, &g, &buf[..len], &mut x[..len]);
        len /= 2;
    }
    Ok(())
}

/// In-place inverse of [`dwt1_forward`].
///
/// **Errors** if the length is not divisible by `2^levels`.
pub fn dwt1_inverse(x: &mut [f64], basis: Basis, levels: usize) -> Result<()> {
    let n = x.len();
    if levels > max_levels(n) {
        return Err(Error::param(
            "levels",
            format!("{levels} levels need a length divisible by 2^{levels}, got {n}"),
        ));
    }
    let (h, g) = (basis.lowpass(), basis.highpass());
    let mut buf = vec![0.0; n];
    for level in (0..levels).rev() {
        let len = n >> level;
        buf[..len].copy_from_slice(&x[..len]);
        synthesis(h, &g, &buf[..len], &mut x[..len]);
    }
    Ok(())
}

/// Energy centre `Σ t u[t]² / Σ u[t]²` (in samples, on the infinite line,
/// no wrapping) of the basis function of coefficient 0 at level `j`
/// (scale `2^j` samples): the scaling function if `wavelet` is false, else
/// the wavelet. Coefficient `k` sits at `2^j k +` this.
///
/// Used by the W-cascade to put each child under its parent: Daubechies
/// filters are asymmetric, and the raw index of a 16-tap basis function is
/// several cells away from where its energy lies.
pub fn energy_centre(basis: Basis, j: usize, wavelet: bool) -> f64 {
    if j == 0 {
        return 0.0;
    }
    let h = basis.lowpass();
    let g = basis.highpass();
    // synthesis of a unit coefficient through j levels, non-periodic:
    // u_{i-1}[2k + t] += filter[t] u_i[k]
    let mut u = vec![1.0];
    for step in 0..j {
        let filter: &[f64] = if step == 0 && wavelet { &g } else { h };
        let mut v = vec![0.0; 2 * (u.len() - 1) + filter.len()];
        for (k, &c) in u.iter().enumerate() {
            for (t, &f) in filter.iter().enumerate() {
                v[2 * k + t] += f * c;
            }
        }
        u = v;
    }
    let (mut s, mut st) = (0.0, 0.0);
    for (t, &v) in u.iter().enumerate() {
        s += v * v;
        st += t as f64 * v * v;
    }
    st / s
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::rng_for;
    use rand::RngExt;

    const ALL: [Basis; 3] = [Basis::Haar, Basis::Db4, Basis::Db8];

    /// Orthonormality conditions of the filters (Daubechies, Ten Lectures
    /// ch. 6): Σh = √2, Σh² = 1, Σ h[i] h[i+2m] = 0 (m ≠ 0), Σg = 0 and
    /// vanishing moments Σ i^p g[i] = 0 for p < N. Tolerances: the
    /// coefficients are correctly rounded doubles, so sums of ≤ 16 products
    /// are exact to a few 1e-16; the moment sums grow like 15^p, so they are
    /// checked relative to Σ i^p |g[i]|.
    #[test]
    fn filters_are_orthonormal_with_vanishing_moments() {
        for b in ALL {
            let h = b.lowpass();
            let g = b.highpass();
            let l = h.len();
            assert_eq!(l, 2 * b.vanishing_moments());
            let s: f64 = h.iter().sum();
            assert!((s - 2f64.sqrt()).abs() < 1e-15, "{b}: Σh = {s}");
            for m in 0..l / 2 {
                let c: f64 = (0..l - 2 * m).map(|i| h[i] * h[i + 2 * m]).sum();
                let want = if m == 0 { 1.0 } else { 0.0 };
                assert!((c - want).abs() < 1e-15, "{b}: shift {m}: {c}");
                // h ⟂ g at every even shift, both ways
                let hg: f64 = (0..l - 2 * m).map(|i| h[i] * g[i + 2 * m]).sum();
                let gh: f64 = (0..l - 2 * m).map(|i| g[i] * h[i + 2 * m]).sum();
                assert!(hg.abs() < 1e-15 && gh.abs() < 1e-15, "{b}: h.g shift {m}");
            }
            for p in 0..b.vanishing_moments() as i32 {
                let mom: f64 = g
                    .iter()
                    .enumerate()
                    .map(|(i, &v)| (i as f64).powi(p) * v)
                    .sum();
                let scale: f64 = g
                    .iter()
                    .enumerate()
                    .map(|(i, &v)| (i as f64).powi(p) * v.abs())
                    .sum();
                assert!(mom.abs() < 1e-13 * scale, "{b}: moment {p} = {mom}");
            }
            // the next moment does not vanish (N is exactly the count)
            let p = b.vanishing_moments() as i32;
            let mom: f64 = g
                .iter()
                .enumerate()
                .map(|(i, &v)| (i as f64).powi(p) * v)
                .sum();
            assert!(mom.abs() > 1e-3, "{b}: moment {p} should not vanish");
        }
    }

    /// A slow reference: the periodic 1D analysis as an explicit matrix with
    /// periodised filters, built independently of `analysis`.
    #[test]
    fn one_level_matches_periodised_matrix() {
        let mut rng = rng_for(1, 0);
        for b in ALL {
            for n in [2usize, 4, 6, 8, 16, 32] {
                let h = b.lowpass();
                let g = b.highpass();
                let x: Vec<f64> = (0..n).map(|_| rng.random::<f64>() - 0.5).collect();
                let mut hp = vec![0.0; n];
                let mut gp = vec![0.0; n];
                for i in 0..h.len() {
                    hp[i % n] += h[i];
                    gp[i % n] += g[i];
                }
                let mut y = x.clone();
                dwt1_forward(&mut y, b, 1).unwrap();
                for k in 0..n / 2 {
                    let a: f64 = (0..n).map(|m| hp[m] * x[(2 * k + m) % n]).sum();
                    let d: f64 = (0..n).map(|m| gp[m] * x[(2 * k + m) % n]).sum();
                    assert!((a - y[k]).abs() < 1e-13 && (d - y[n / 2 + k]).abs() < 1e-13);
                }
            }
        }
    }

    /// Perfect reconstruction and energy conservation (Parseval) on random
    /// data, every basis, square and rectangular sizes, full depth included
    /// (filters longer than the signal wrap several times). 1e-12 relative:
    /// a level costs ~L roundings of 1e-16 per value.
    #[test]
    fn perfect_reconstruction_2d() {
        let mut rng = rng_for(2, 0);
        for b in ALL {
            let mut dwt = Dwt2::new(b);
            for (ny, nx, levels) in [
                (2, 2, 1),
                (8, 8, 3),
                (16, 32, 4),
                (64, 64, 6),
                (128, 128, 7),
                (48, 80, 4),
                (256, 256, 8),
            ] {
                let x = Array2::from_shape_fn((ny, nx), |_| rng.random::<f64>() * 2.0 - 1.0);
                let mut c = x.clone();
                dwt.forward(&mut c, levels).unwrap();
                let e0: f64 = x.iter().map(|v| v * v).sum();
                let e1: f64 = c.iter().map(|v| v * v).sum();
                assert!((e0 - e1).abs() < 1e-12 * e0, "{b} {ny}x{nx}: energy");
                dwt.inverse(&mut c, levels).unwrap();
                let err = x
                    .iter()
                    .zip(c.iter())
                    .map(|(a, b)| (a - b).abs())
                    .fold(0.0, f64::max);
                assert!(err < 1e-12, "{b} {ny}x{nx} L{levels}: max error {err}");
            }
        }
    }

    /// The inverse transform's columns are an orthonormal basis: the Gram
    /// matrix of the 64 basis functions of an 8x8 grid is the identity.
    #[test]
    fn basis_functions_are_orthonormal() {
        for b in ALL {
            let n = 8;
            let mut dwt = Dwt2::new(b);
            let funcs: Vec<Array2<f64>> = (0..n * n)
                .map(|i| {
                    let mut c = Array2::zeros((n, n));
                    c[[i / n, i % n]] = 1.0;
                    dwt.inverse(&mut c, 3).unwrap();
                    c
                })
                .collect();
            for i in 0..n * n {
                for j in 0..n * n {
                    let dot: f64 = funcs[i]
                        .iter()
                        .zip(funcs[j].iter())
                        .map(|(a, b)| a * b)
                        .sum();
                    let want = if i == j { 1.0 } else { 0.0 };
                    assert!((dot - want).abs() < 1e-13, "{b}: <{i},{j}> = {dot}");
                }
            }
        }
    }

    #[test]
    fn too_many_levels_is_an_error() {
        let mut a = Array2::zeros((24, 32));
        let err = Dwt2::new(Basis::Db4).forward(&mut a, 4).unwrap_err();
        assert!(err.to_string().contains("levels"), "{err}");
        assert!(Dwt2::new(Basis::Db4).forward(&mut a, 3).is_ok());
    }

    /// The 2D transform of a separable field `u(y) v(x)` is the outer
    /// product of the 1D transforms (one level): rows and columns agree with
    /// [`dwt1_forward`].
    #[test]
    fn separable_product() {
        let mut rng = rng_for(3, 0);
        let n = 16;
        for b in ALL {
            let u: Vec<f64> = (0..n).map(|_| rng.random::<f64>()).collect();
            let v: Vec<f64> = (0..n).map(|_| rng.random::<f64>()).collect();
            let mut a = Array2::from_shape_fn((n, n), |(y, x)| u[y] * v[x]);
            Dwt2::new(b).forward(&mut a, 1).unwrap();
            let (mut tu, mut tv) = (u.clone(), v.clone());
            dwt1_forward(&mut tu, b, 1).unwrap();
            dwt1_forward(&mut tv, b, 1).unwrap();
            for y in 0..n {
                for x in 0..n {
                    assert!((a[[y, x]] - tu[y] * tv[x]).abs() < 1e-14);
                }
            }
        }
    }

    /// Energy centres: Haar functions are centred on their cell; for
    /// Daubechies the wavelet sits near (L-1)/2 cells and the scaling
    /// function in the first third of its support (extremal phase).
    #[test]
    fn energy_centres() {
        for j in 1..6 {
            let w = (1usize << j) as f64;
            assert!((energy_centre(Basis::Haar, j, false) - (w - 1.0) / 2.0).abs() < 1e-12);
            assert!((energy_centre(Basis::Haar, j, true) - (w - 1.0) / 2.0).abs() < 1e-12);
        }
        let c = energy_centre(Basis::Db8, 6, true) / 64.0;
        assert!(c > 5.0 && c < 10.0, "db8 wavelet centre {c} cells");
        let c = energy_centre(Basis::Db8, 6, false) / 64.0;
        assert!(c > 1.0 && c < 5.0, "db8 scaling centre {c} cells");
    }
}
