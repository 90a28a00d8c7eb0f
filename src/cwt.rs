//! Continuous 2D wavelet transform (SPEC §1; Decoster, Roux & Arnéodo II §3,
//! eqs 1-3).
//!
//! `T(b, a) = a ∇(φ_a * f)(b)` with `φ_a(x) = a⁻² φ(x/a)`, computed in Fourier
//! space: `T̂_i(k, a) = i a k_i φ̂(a k) f̂(k)`. Both components are real fields,
//! so one inverse complex FFT per scale returns `T1 + i T2` packed:
//! `Ĝ = T̂1 + i T̂2 = a (i k_x - k_y) φ̂(a k) f̂(k)`.
//!
//! Layout: the image is real, so only the half spectrum `kx <= nx/2` is
//! stored, transposed (`[kx][ky]`); the other half is read as conjugates. A
//! scale costs one batch of FFTs along `ky` (contiguous), then the `kx`
//! FFTs: [`CwtPlan::scale`] transposes the whole array between the two,
//! [`CwtPlan::scale_rows`] (what the skeleton and the correlations use)
//! gathers blocks of output rows and hands each block on while it is in
//! cache, so the transform is never stored whole. Rows `kx` where the
//! Gaussian factor `exp(-a² kx²/2)` has fallen below [`PRUNE`] hold only
//! zeros and their FFT is skipped (their contribution is below 1e-24 of the
//! largest filter value).
//!
//! ```
//! use ndarray::Array2;
//! use wtmm::cwt::{CwtPlan, Wavelet};
//! // a linear ramp f = 0.5 x: gauss gives T = (a c, 0) away from the borders
//! let img = Array2::from_shape_fn((64, 64), |(_, x)| 0.5 * x as f64);
//! let plan = CwtPlan::new(64, 64, Wavelet::Gauss, &[2.0]).unwrap();
//! let fi = plan.forward(img.view()).unwrap();
//! let mut ws = plan.workspace();
//! let t = plan.scale(&fi, 0, &mut ws);
//! // the periodic jump at the border spoils the edges; the centre is exact
//! assert!((t[[32, 32]].re - 1.0).abs() < 1e-6 && t[[32, 32]].im.abs() < 1e-6);
//! ```

use std::sync::Arc;

use ndarray::{Array2, ArrayView2};
use num_complex::Complex64;
use rayon::prelude::*;
use realfft::{RealFftPlanner, RealToComplex};
use rustfft::{Fft, FftPlanner};
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};

/// Rows whose Gaussian factor is below this are treated as exactly zero.
pub const PRUNE: f64 = 1e-24;

/// Fraction of the L1 mass of |ψ| that may lie outside the analysis margin:
/// the value for gauss at radius 3.2 (SPEC §1 default `ceil(3.2 a_max)`), so
/// that both wavelets leak the same fraction from the border.
fn gauss_tail_at_3_2() -> f64 {
    Wavelet::Gauss.tail_fraction(3.2)
}

/// The analysing wavelet (SPEC §1). The default is gauss, the paper's
/// (II §2) and [`crate::AnalysisConfig`]'s; fields with h above 1 (FISC)
/// need mexican.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum Wavelet {
    /// First derivatives of a Gaussian: 1 vanishing moment.
    #[default]
    Gauss,
    /// First derivatives of the Mexican hat `-∇²gaussian`: 3 vanishing moments.
    Mexican,
}

impl Wavelet {
    /// Number of vanishing moments (the largest Hölder exponent it can measure).
    pub fn order(self) -> u32 {
        match self {
            Wavelet::Gauss => 1,
            Wavelet::Mexican => 3,
        }
    }

    /// Lowercase name as used on the command line and in outputs.
    pub fn name(self) -> &'static str {
        match self {
            Wavelet::Gauss => "gauss",
            Wavelet::Mexican => "mexican",
        }
    }

    /// Radial profile of |ψ1| integrated over angle, at scale 1, up to a
    /// constant: gauss `ψ1 ∝ x e^{-r²/2}`, mexican `ψ1 ∝ x (r² - 4) e^{-r²/2}`;
    /// the angular integral of |cos θ| is a constant, so the radial density of
    /// the L1 mass is `r · r · |g(r)| e^{-r²/2}`.
    fn radial_l1_density(self, r: f64) -> f64 {
        let g = match self {
            Wavelet::Gauss => 1.0,
            Wavelet::Mexican => (r * r - 4.0).abs(),
        };
        r * r * g * (-0.5 * r * r).exp()
    }

    /// Fraction of the L1 mass of |ψ1| (scale 1) outside radius `r`
    /// (numerical quadrature, Simpson on [0, 20]).
    pub fn tail_fraction(self, r: f64) -> f64 {
        let integrate = |lo: f64, hi: f64| {
            let n = 4000;
            let h = (hi - lo) / n as f64;
            let mut s = self.radial_l1_density(lo) + self.radial_l1_density(hi);
            for i in 1..n {
                let w = if i % 2 == 1 { 4.0 } else { 2.0 };
                s += w * self.radial_l1_density(lo + i as f64 * h);
            }
            s * h / 3.0
        };
        let total = integrate(0.0, 20.0);
        if r >= 20.0 {
            return 0.0;
        }
        integrate(r, 20.0) / total
    }

    /// Smallest scale (px) whose wavelet is resolved by the pixel grid: the
    /// passband peak of `psî(a k)`, at `a|k| = 1` for gauss (`|k| e^{-a²k²/2}`)
    /// and `sqrt 3` for mexican (`|k|³ e^{-a²k²/2}`), must lie below the
    /// Nyquist wavenumber pi. Below it the transform sees only aliased
    /// pixel noise (0.32 px gauss, 0.55 px mexican).
    pub fn min_scale(self) -> f64 {
        let peak = match self {
            Wavelet::Gauss => 1.0,
            Wavelet::Mexican => 3f64.sqrt(),
        };
        peak / std::f64::consts::PI
    }

    /// Radius (in units of a) outside which the wavelet keeps the same L1
    /// fraction as gauss keeps outside 3.2: 3.2 for gauss, about 3.73 for
    /// mexican. The interior margin is `ceil(support_radius * a_max)`.
    pub fn support_radius(self) -> f64 {
        if self == Wavelet::Gauss {
            return 3.2;
        }
        let target = gauss_tail_at_3_2();
        let (mut lo, mut hi) = (2.0, 12.0);
        for _ in 0..60 {
            let mid = 0.5 * (lo + hi);
            if self.tail_fraction(mid) > target {
                lo = mid
            } else {
                hi = mid
            }
        }
        hi
    }
}

impl std::fmt::Display for Wavelet {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// The dyadic scale grid `a_j = a_min 2^(j/voices)`, `j = 0 .. octaves*voices - 1`
/// (SPEC §1; defaults 1.5 px, 5 octaves, 10 voices).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ScaleGrid {
    /// Smallest scale `a_min`, in pixels (std of the Gaussian; default 1.5).
    pub a_min: f64,
    /// Number of octaves (factors of 2) spanned by the grid (default 5).
    pub octaves: usize,
    /// Scales per octave (default 10).
    pub voices: usize,
}

impl Default for ScaleGrid {
    fn default() -> Self {
        ScaleGrid {
            a_min: 1.5,
            octaves: 5,
            voices: 10,
        }
    }
}

impl ScaleGrid {
    /// **Errors** if a parameter is out of range.
    pub fn validate(&self) -> Result<()> {
        if !(self.a_min.is_finite() && self.a_min > 0.0) {
            return Err(Error::param(
                "a-min",
                format!("must be > 0, got {}", crate::error::short(self.a_min)),
            ));
        }
        if self.octaves == 0 || self.octaves > 20 {
            return Err(Error::param(
                "octaves",
                format!("must be in 1..=20, got {}", self.octaves),
            ));
        }
        if self.voices == 0 || self.voices > 64 {
            return Err(Error::param(
                "voices",
                format!("must be in 1..=64, got {}", self.voices),
            ));
        }
        if !(self.a_max() <= MAX_SCALE) {
            return Err(Error::param(
                "a-min",
                format!(
                    "{} px over {} octaves reaches {} px, beyond any image ({} px)",
                    crate::error::short(self.a_min),
                    self.octaves,
                    crate::error::short(self.a_max()),
                    crate::error::short(MAX_SCALE)
                ),
            ));
        }
        Ok(())
    }

    /// The scales, smallest first (`octaves x voices` of them: check the
    /// grid with [`Self::validate`] first, which bounds them to 20 x 64).
    pub fn scales(&self) -> Vec<f64> {
        (0..self.octaves * self.voices)
            .map(|j| self.a_min * 2f64.powf(j as f64 / self.voices as f64))
            .collect()
    }

    /// Largest scale of the grid (`a_min` for an empty one; huge or not
    /// finite for grids [`Self::validate`] refuses, never an overflow).
    pub fn a_max(&self) -> f64 {
        let n = self.octaves.saturating_mul(self.voices).saturating_sub(1);
        self.a_min * 2f64.powf(n as f64 / self.voices.max(1) as f64)
    }
}

/// True if two scale lists are the same grid (to 1e-9 relative): the
/// condition for merging sums computed on different machines.
pub fn same_scales(a: &[f64], b: &[f64]) -> bool {
    a.len() == b.len()
        && a.iter()
            .zip(b)
            .all(|(x, y)| (x - y).abs() <= 1e-9 * x.abs())
}

/// Largest scale accepted (px): the side of the largest image the readers
/// accept (`io::MAX_PIXELS` = 2^28 pixels in one row).
pub const MAX_SCALE: f64 = (1u64 << 28) as f64;

/// Default interior margin for a wavelet and largest scale (SPEC §1):
/// `ceil(R a_max)`. `a_max` is a scale the configs have checked (positive,
/// at most [`MAX_SCALE`]); others saturate (NaN and negatives give 0, a
/// huge scale `usize::MAX`), which no image satisfies.
pub fn default_margin(wavelet: Wavelet, a_max: f64) -> usize {
    (wavelet.support_radius() * a_max).ceil() as usize
}

use crate::fourier::angular_freq as freq;

/// The Fourier transform of one image in `[kx][ky]` layout, ready to be
/// filtered at any scale. Only `kx <= nx/2` is stored: the image is real, so
/// `f̂(kx, ky) = conj f̂(nx - kx, -ky)` gives the rest exactly (half the
/// memory, and half the spectrum traffic per scale).
pub struct FourierImage {
    /// `(nx/2 + 1) * ny` values, row `kx` holds `f̂(kx, ·)` of `f - offset`.
    half: Vec<Complex64>,
    /// The constant taken off before the FFT (the wavelets have no DC).
    offset: f64,
    nx: usize,
    ny: usize,
}

impl FourierImage {
    /// `f̂(kx, ky)` for any `kx < nx`.
    #[inline]
    fn at(&self, kx: usize, ky: usize) -> Complex64 {
        let (nx, ny) = (self.nx, self.ny);
        if kx <= nx / 2 {
            self.half[kx * ny + ky]
        } else {
            self.half[(nx - kx) * ny + (ny - ky) % ny].conj()
        }
    }
}

/// Per-worker buffers for [`CwtPlan::scale`]: allocate once, reuse for every
/// scale and image.
pub struct CwtWorkspace {
    /// Filtered spectrum, `[kx][ky]`.
    tbuf: Vec<Complex64>,
    /// Offset of the first used value of `tbuf`, so that its rows start on
    /// a 64-byte cache line and a block of [`ROW_BLOCK`] values of a row
    /// spans whole lines.
    toff: usize,
    /// Row stride of `tbuf` at the last scale filtered (see
    /// [`CwtPlan::filter_columns`]).
    ts: usize,
    /// Output `T1 + i T2`, `[y][x]` (of [`CwtPlan::scale`]; allocated on first use).
    out: Array2<Complex64>,
    scratch: Vec<Complex64>,
    gx: Vec<f64>,
    gy: Vec<f64>,
    /// Rows of `tbuf` known to hold zeros (pruned at an earlier scale), so
    /// they are not cleared again.
    zero_rows: Vec<bool>,
    /// Two blocks of [`ROW_BLOCK`] output rows for [`CwtPlan::scale_rows`]
    /// (the current one and the previous one), allocated on first use.
    blocks: [Vec<Complex64>; 2],
}

/// Output rows per block in [`CwtPlan::scale_rows`]: 8 rows read two whole
/// cache lines from each row of the spectrum, and the two blocks of a
/// 1024-wide image (256 KB) stay in L2. Measured on 1024² (CWT + detection,
/// 50 scales): 4 rows 745 ms, 8 rows 717 ms, 16 rows 774 ms, 32 rows 752
/// ms, against 863-917 ms for the full transform.
pub const ROW_BLOCK: usize = 8;

/// A resolved CWT: FFT plans and frequency tables for one image size, one
/// wavelet and one list of scales. Cheap to share between threads, and
/// cheap to clone (the FFT plans are shared, the tables copied).
#[derive(Clone)]
pub struct CwtPlan {
    ny: usize,
    nx: usize,
    wavelet: Wavelet,
    scales: Vec<f64>,
    r2c: Arc<dyn RealToComplex<f64>>,
    fwd_y: Arc<dyn Fft<f64>>,
    inv_y: Arc<dyn Fft<f64>>,
    inv_x: Arc<dyn Fft<f64>>,
    /// Angular frequencies; `dkx`, `dky` are the derivative factors, zero at
    /// the Nyquist bin (where `i k` has no real-valued meaning).
    kx: Vec<f64>,
    ky: Vec<f64>,
    dkx: Vec<f64>,
    dky: Vec<f64>,
    scratch_len: usize,
}

/// What a plan is for (the FFT plans and tables are not printed): written
/// by hand because the FFT plan objects have no `Debug`.
impl std::fmt::Debug for CwtPlan {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CwtPlan")
            .field("ny", &self.ny)
            .field("nx", &self.nx)
            .field("wavelet", &self.wavelet)
            .field("scales", &self.scales)
            .finish_non_exhaustive()
    }
}

/// An image of `ny x nx` can be transformed from the scale `smallest`:
/// at least 8x8, and as wide as the wavelet's support there.
///
/// **Errors** saying which it is not.
pub fn check_size(ny: usize, nx: usize, wavelet: Wavelet, smallest: f64) -> Result<()> {
    if ny < 8 || nx < 8 {
        return Err(Error::Input(format!(
            "image {ny}x{nx} is too small (need at least 8x8)"
        )));
    }
    if 2.0 * wavelet.support_radius() * smallest > ny.min(nx) as f64 {
        return Err(Error::Input(format!(
            "image {ny}x{nx} is smaller than the {wavelet} wavelet at its smallest scale {} px \
             (support diameter {} px)",
            crate::error::short(smallest),
            crate::error::short((2.0 * wavelet.support_radius() * smallest).round())
        )));
    }
    Ok(())
}

impl CwtPlan {
    /// Plans the transform of `ny x nx` images at the given scales.
    ///
    /// **Errors** if the image is smaller than 8x8 or a scale is not a
    /// positive finite number.
    pub fn new(ny: usize, nx: usize, wavelet: Wavelet, scales: &[f64]) -> Result<Self> {
        if ny < 8 || nx < 8 {
            return Err(Error::Input(format!(
                "image {ny}x{nx} is too small (need at least 8x8)"
            )));
        }
        if scales.is_empty() {
            return Err(Error::param("scales", "no scale given"));
        }
        if let Some(a) = scales.iter().find(|a| !(a.is_finite() && **a > 0.0)) {
            return Err(Error::param(
                "scales",
                format!(
                    "scales must be > 0, got {a_s}",
                    a_s = crate::error::short(*a)
                ),
            ));
        }
        if let Some(a) = scales.iter().find(|&&a| a < wavelet.min_scale()) {
            return Err(Error::param(
                "scales",
                format!(
                    "scale {} px is below {:.2} px, where the {wavelet} wavelet's passband \
                     passes the Nyquist wavenumber (the pixel grid cannot resolve it)",
                    crate::error::short(*a),
                    wavelet.min_scale()
                ),
            ));
        }
        let smallest = scales.iter().cloned().fold(f64::INFINITY, f64::min);
        check_size(ny, nx, wavelet, smallest)?;
        let mut rp = RealFftPlanner::<f64>::new();
        let r2c = rp.plan_fft_forward(nx);
        let mut cp = FftPlanner::<f64>::new();
        let fwd_y = cp.plan_fft_forward(ny);
        let inv_y = cp.plan_fft_inverse(ny);
        let inv_x = cp.plan_fft_inverse(nx);
        let kx: Vec<f64> = (0..nx).map(|m| freq(m, nx)).collect();
        let ky: Vec<f64> = (0..ny).map(|m| freq(m, ny)).collect();
        let nyq = |k: &Vec<f64>, n: usize| -> Vec<f64> {
            let mut d = k.clone();
            if n.is_multiple_of(2) {
                d[n / 2] = 0.0;
            }
            d
        };
        let dkx = nyq(&kx, nx);
        let dky = nyq(&ky, ny);
        let scratch_len = [
            r2c.get_scratch_len(),
            fwd_y.get_inplace_scratch_len(),
            inv_y.get_inplace_scratch_len(),
            inv_x.get_inplace_scratch_len(),
        ]
        .into_iter()
        .max()
        .unwrap_or(0);
        Ok(CwtPlan {
            ny,
            nx,
            wavelet,
            scales: scales.to_vec(),
            r2c,
            fwd_y,
            inv_y,
            inv_x,
            kx,
            ky,
            dkx,
            dky,
            scratch_len,
        })
    }

    /// `(ny, nx)`.
    pub fn dim(&self) -> (usize, usize) {
        (self.ny, self.nx)
    }

    /// The analysing wavelet of this plan.
    pub fn wavelet(&self) -> Wavelet {
        self.wavelet
    }

    /// The scales, in pixels.
    pub fn scales(&self) -> &[f64] {
        &self.scales
    }

    /// Default interior margin `ceil(R a_max)` (SPEC §1), R from
    /// [`Wavelet::support_radius`].
    pub fn default_margin(&self) -> usize {
        let a_max = self.scales.iter().cloned().fold(0.0, f64::max);
        default_margin(self.wavelet, a_max)
    }

    /// Fresh buffers for one worker.
    pub fn workspace(&self) -> CwtWorkspace {
        let tbuf = vec![Complex64::default(); self.nx * self.padded_stride() + 3];
        let toff = match tbuf.as_ptr().align_offset(64) {
            o if o <= 3 => o,
            _ => 0,
        };
        CwtWorkspace {
            tbuf,
            toff,
            ts: self.ny,
            out: Array2::zeros((0, 0)),
            scratch: vec![Complex64::default(); self.scratch_len],
            gx: vec![0.0; self.nx],
            gy: vec![0.0; self.ny],
            zero_rows: vec![false; self.nx],
            blocks: [Vec::new(), Vec::new()],
        }
    }

    /// Fourier transform of one image (one real-to-complex FFT per image).
    ///
    /// **Errors** if the shape differs from the plan's, a value is not
    /// finite, or the values are too large or vary too little for f64
    /// ([`crate::field::AMPLITUDE_LIMIT`]).
    pub fn forward(&self, img: ArrayView2<f64>) -> Result<FourierImage> {
        let (ny, nx) = (self.ny, self.nx);
        if img.dim() != (ny, nx) {
            return Err(Error::Input(format!(
                "image is {}x{} but the plan is for {ny}x{nx}",
                img.nrows(),
                img.ncols()
            )));
        }
        if img.iter().any(|v| !v.is_finite()) {
            return Err(Error::Input(
                "image has non-finite values (fill masked pixels first)".into(),
            ));
        }
        if let Some(why) = crate::field::amplitude_problem(img.iter()) {
            return Err(Error::Input(why));
        }
        // Centre on the midrange first: the wavelets ignore a constant, and
        // a constant image then transforms to exact zeros (the twiddles of
        // non-power-of-two FFTs leave ~1e-16 of it otherwise, which the
        // relative eps threshold took for maxima); lo/2 + hi/2 is exactly
        // the value of a constant image.
        let (lo, hi) = img
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &v| {
                (l.min(v), h.max(v))
            });
        let offset = lo / 2.0 + hi / 2.0;
        let nh = nx / 2 + 1;
        let mut row = vec![0.0; nx];
        let mut scratch = vec![Complex64::default(); self.scratch_len];
        // half spectrum along x, [y][kx]
        let mut half = vec![Complex64::default(); ny * nh];
        for (y, out) in half.chunks_exact_mut(nh).enumerate() {
            for (x, r) in row.iter_mut().enumerate() {
                *r = img[[y, x]] - offset;
            }
            self.r2c
                .process_with_scratch(&mut row, out, &mut scratch)
                .expect("realfft lengths come from the plan");
        }
        // transpose to [kx][y] and transform along y
        let mut halft = vec![Complex64::default(); ny * nh];
        transpose::transpose(&half, &mut halft, nh, ny);
        self.fwd_y.process_with_scratch(&mut halft, &mut scratch);
        Ok(FourierImage {
            half: halft,
            offset,
            nx,
            ny,
        })
    }

    /// `T1 + i T2` at scale index `j`, in `ws`'s output buffer (`[y][x]`).
    /// Allocates nothing.
    ///
    /// **Panics** if `j` is not an index of [`scales`](Self::scales), or if
    /// `fi` or `ws` were made by a plan of another image size.
    pub fn scale<'w>(
        &self,
        fi: &FourierImage,
        j: usize,
        ws: &'w mut CwtWorkspace,
    ) -> &'w Array2<Complex64> {
        let (ny, nx) = (self.ny, self.nx);
        // compact rows: one whole-array transpose
        self.filter_columns(fi, j, ws, ny);
        // allocated on first use: consumers of `scale_rows` never need it
        if ws.out.dim() != (ny, nx) {
            ws.out = Array2::zeros((ny, nx));
        }
        let out = ws
            .out
            .as_slice_mut()
            .expect("workspace output is contiguous");
        transpose::transpose(&ws.tbuf[ws.toff..ws.toff + nx * ny], out, ny, nx);
        self.inv_x.process_with_scratch(out, &mut ws.scratch);
        &ws.out
    }

    /// Streams the rows `rows` of `T1 + i T2` at scale index `j` in blocks of
    /// [`ROW_BLOCK`] rows (the last one may be shorter), in order:
    /// `f(y0, prev, cur)` where `cur` holds rows `y0..` row-major and `prev`
    /// the block delivered just before (`None` for the first). The values
    /// are bit-identical to [`scale`](Self::scale)'s.
    ///
    /// Why: the full transform is 16 MB at 1024², written by the transpose,
    /// read and written by the last FFT pass, then read again by its
    /// consumer, each time from main memory. Gathering a block of columns
    /// of the filtered spectrum and finishing its FFTs in cache lets a
    /// consumer that needs only neighbouring rows (the WTMM detection) work
    /// while the rows are hot, and rows outside `rows` cost no FFT at all.
    ///
    /// **Panics** as [`scale`](Self::scale) does.
    pub fn scale_rows<F>(
        &self,
        fi: &FourierImage,
        j: usize,
        ws: &mut CwtWorkspace,
        rows: std::ops::Range<usize>,
        mut f: F,
    ) where
        F: FnMut(usize, Option<&[Complex64]>, &[Complex64]),
    {
        let (ny, nx) = (self.ny, self.nx);
        let rows = rows.start.min(ny)..rows.end.min(ny);
        if rows.is_empty() {
            return;
        }
        let ts = self.padded_stride();
        self.filter_columns(fi, j, ws, ts);
        for b in &mut ws.blocks {
            b.resize(ROW_BLOCK * nx, Complex64::default());
        }
        let mut prev_len = 0;
        let mut cur = 0;
        let mut y0 = rows.start;
        while y0 < rows.end {
            // blocks on multiples of ROW_BLOCK (the first may be shorter),
            // so each reads whole cache lines of the aligned rows
            let h = (ROW_BLOCK - y0 % ROW_BLOCK).min(rows.end - y0);
            let [b0, b1] = &mut ws.blocks;
            let (blk, prev) = if cur == 0 { (b0, b1) } else { (b1, b0) };
            let blk = &mut blk[..h * nx];
            // gather columns y0..y0+h of the [kx][y] spectrum: h contiguous
            // values from every kx row (zeros where the row was pruned)
            let next = y0 + h;
            let tb = &ws.tbuf[ws.toff..ws.toff + nx * ts];
            let mut kx = 0;
            while kx < nx {
                if ws.zero_rows[kx] {
                    // pruned rows come in runs (|kx| large): contiguous zeros
                    let end = ws.zero_rows[kx..]
                        .iter()
                        .position(|z| !z)
                        .map_or(nx, |p| kx + p);
                    for yy in 0..h {
                        blk[yy * nx + kx..yy * nx + end].fill(Complex64::default());
                    }
                    kx = end;
                    continue;
                }
                let row = &tb[kx * ts..kx * ts + ny];
                // the next block's two cache lines of this row: rows 16 KB
                // apart defeat the hardware prefetcher
                if next < rows.end {
                    prefetch(&row[next]);
                    prefetch(&row[(next + ROW_BLOCK / 2).min(ny - 1)]);
                }
                for (yy, &v) in row[y0..y0 + h].iter().enumerate() {
                    blk[yy * nx + kx] = v;
                }
                kx += 1;
            }
            self.inv_x.process_with_scratch(blk, &mut ws.scratch);
            let prev = (prev_len > 0).then(|| &prev[..prev_len * nx]);
            f(y0, prev, blk);
            prev_len = h;
            cur ^= 1;
            y0 += h;
        }
    }

    /// Row stride of the filtered spectrum when it is read in row blocks
    /// ([`Self::scale_rows`]): `ny`, plus one cache line when `ny` rows
    /// would lie a multiple of 4 KiB apart. The block gather reads 8 values
    /// from every row; with a power-of-two stride all those rows fall in
    /// the same L1 set and evict each other (streamed CWT of 1024²,
    /// 50 scales: 178-186 ms -> 152-158 ms, 2026-11-26).
    fn padded_stride(&self) -> usize {
        let row_bytes = self.ny * std::mem::size_of::<Complex64>();
        if row_bytes.is_multiple_of(4096) {
            self.ny + 64 / std::mem::size_of::<Complex64>()
        } else {
            self.ny
        }
    }

    /// The first half of a scale: the filtered spectrum `[kx][ky]` with its
    /// FFTs along `ky` done, in `ws.tbuf`, rows `ts` apart (pruned rows
    /// zero, flagged in `ws.zero_rows`).
    fn filter_columns(&self, fi: &FourierImage, j: usize, ws: &mut CwtWorkspace, ts: usize) {
        let (ny, nx) = (self.ny, self.nx);
        if ws.ts != ts {
            // the zeros of earlier scales sat at the other stride
            ws.ts = ts;
            ws.zero_rows.fill(false);
        }
        let a = self.scales[j];
        // separable Gaussian factors: nx + ny exponentials per scale
        for (g, k) in ws.gx.iter_mut().zip(&self.kx) {
            *g = (-0.5 * a * a * k * k).exp();
        }
        for (g, k) in ws.gy.iter_mut().zip(&self.ky) {
            *g = (-0.5 * a * a * k * k).exp();
        }
        // FFT normalisation folded into the filter
        let c = a / (nx * ny) as f64;
        let a2 = a * a;
        let mexican = self.wavelet == Wavelet::Mexican;
        for kx in 0..nx {
            let row = &mut ws.tbuf[ws.toff + kx * ts..ws.toff + kx * ts + ny];
            let gx = ws.gx[kx];
            if gx < PRUNE {
                if !ws.zero_rows[kx] {
                    row.fill(Complex64::default());
                    ws.zero_rows[kx] = true;
                }
                continue;
            }
            ws.zero_rows[kx] = false;
            let (src, mirrored) = if kx <= nx / 2 {
                (&fi.half[kx * ny..(kx + 1) * ny], false)
            } else {
                (&fi.half[(nx - kx) * ny..(nx - kx + 1) * ny], true)
            };
            let rf = RowFilter {
                c: c * gx,
                dkx: self.dkx[kx],
                kx2: self.kx[kx] * self.kx[kx],
                a2: if mexican { a2 } else { 0.0 },
                gy: &ws.gy,
                ky: &self.ky,
                dky: &self.dky,
            };
            rf.apply(row, src, mirrored);
            self.inv_y.process_with_scratch(row, &mut ws.scratch);
        }
    }

    /// The smoothed image `φ_a * f` at scale `a` (the background of II
    /// Fig 9), from the image's spectrum. For pictures: it allocates.
    pub fn smoothed(&self, fi: &FourierImage, a: f64) -> Array2<f64> {
        let (ny, nx) = (self.ny, self.nx);
        let mut buf = vec![Complex64::default(); nx * ny];
        let c = 1.0 / (nx * ny) as f64;
        for kx in 0..nx {
            let gx = (-0.5 * a * a * self.kx[kx] * self.kx[kx]).exp();
            for ky in 0..ny {
                let mut g = c * gx * (-0.5 * a * a * self.ky[ky] * self.ky[ky]).exp();
                if self.wavelet == Wavelet::Mexican {
                    g *= a * a * (self.kx[kx] * self.kx[kx] + self.ky[ky] * self.ky[ky]);
                }
                buf[kx * ny + ky] = fi.at(kx, ky) * g;
            }
        }
        let mut scratch = vec![Complex64::default(); self.scratch_len];
        self.inv_y.process_with_scratch(&mut buf, &mut scratch);
        let mut out = vec![Complex64::default(); nx * ny];
        transpose::transpose(&buf, &mut out, ny, nx);
        self.inv_x.process_with_scratch(&mut out, &mut scratch);
        // the offset taken off in `forward` (phî(0) = 1 for gauss, 0 for mexican)
        let dc = if self.wavelet == Wavelet::Gauss {
            fi.offset
        } else {
            0.0
        };
        Array2::from_shape_vec((ny, nx), out.into_iter().map(|z| z.re + dc).collect())
            .expect("shape from the plan")
    }

    /// Streams the scales of one image in order, serially: `f(j, a, T)` with
    /// `T = T1 + i T2`. Memory: a workspace (two complex images) besides the
    /// image's spectrum, whatever the number of scales.
    pub fn for_each_scale<F>(&self, img: ArrayView2<f64>, mut f: F) -> Result<()>
    where
        F: FnMut(usize, f64, &Array2<Complex64>),
    {
        let fi = self.forward(img)?;
        let mut ws = self.workspace();
        for j in 0..self.scales.len() {
            let t = self.scale(&fi, j, &mut ws);
            f(j, self.scales[j], t);
        }
        Ok(())
    }

    /// Maps every scale through `f` in parallel (rayon) and returns the
    /// results in scale order. Each scale is computed by the same code as
    /// [`for_each_scale`](Self::for_each_scale), so results are bit-identical
    /// to the serial path. Memory: one workspace per worker.
    pub fn par_map_scales<R, F>(&self, img: ArrayView2<f64>, f: F) -> Result<Vec<R>>
    where
        R: Send,
        F: Fn(usize, f64, &Array2<Complex64>) -> R + Sync + Send,
    {
        self.par_map_scales_init(img, || (), |_, j, a, t| f(j, a, t))
    }

    /// As [`par_map_scales`](Self::par_map_scales), with per-worker state
    /// `S` (the consumer's scratch buffers) created by `init`.
    pub fn par_map_scales_init<S, R, I, F>(
        &self,
        img: ArrayView2<f64>,
        init: I,
        f: F,
    ) -> Result<Vec<R>>
    where
        R: Send,
        I: Fn() -> S + Sync + Send,
        F: Fn(&mut S, usize, f64, &Array2<Complex64>) -> R + Sync + Send,
    {
        self.par_map_scales_with(img, init, |st, fi, j, ws| {
            let t = self.scale(fi, j, ws);
            f(st, j, self.scales[j], t)
        })
    }

    /// The most general form: `f(state, spectrum, j, workspace)` computes
    /// what it needs of scale `j` itself (e.g. with
    /// [`scale_rows`](Self::scale_rows)). Results in scale order.
    pub fn par_map_scales_with<S, R, I, F>(
        &self,
        img: ArrayView2<f64>,
        init: I,
        f: F,
    ) -> Result<Vec<R>>
    where
        R: Send,
        I: Fn() -> S + Sync + Send,
        F: Fn(&mut S, &FourierImage, usize, &mut CwtWorkspace) -> R + Sync + Send,
    {
        let fi = self.forward(img)?;
        Ok((0..self.scales.len())
            .into_par_iter()
            .map_init(
                || (self.workspace(), init()),
                |(ws, st), j| f(st, &fi, j, ws),
            )
            .collect())
    }
}

/// One row `kx` of the filter `(i dkx - dky) g(kx, ky)` applied to the
/// spectrum, `g = c gx gy[ky]` (times `a² |k|²` for mexican, when `a2 > 0`).
struct RowFilter<'a> {
    /// `c gx`: normalisation times the Gaussian factor of the row.
    c: f64,
    dkx: f64,
    kx2: f64,
    a2: f64,
    gy: &'a [f64],
    ky: &'a [f64],
    dky: &'a [f64],
}

impl RowFilter<'_> {
    /// `row[ky] = filter * f̂(kx, ky)` from the stored half spectrum: `src`
    /// is row `kx`, or row `nx - kx` read backwards and conjugated
    /// (`mirrored`). AVX2 when available: no FMA contraction happens
    /// without `mul_add`, so both paths give the same bits.
    fn apply(&self, row: &mut [Complex64], src: &[Complex64], mirrored: bool) {
        #[cfg(target_arch = "x86_64")]
        {
            #[target_feature(enable = "avx2")]
            unsafe fn avx2(rf: &RowFilter, row: &mut [Complex64], src: &[Complex64], m: bool) {
                rf.apply_impl(row, src, m)
            }
            #[target_feature(enable = "avx512f")]
            unsafe fn avx512(rf: &RowFilter, row: &mut [Complex64], src: &[Complex64], m: bool) {
                rf.apply_impl(row, src, m)
            }
            if std::arch::is_x86_feature_detected!("avx512f") {
                // SAFETY: the CPU supports AVX-512F (checked just above).
                unsafe { avx512(self, row, src, mirrored) };
                return;
            }
            if std::arch::is_x86_feature_detected!("avx2") {
                // SAFETY: the CPU supports AVX2 (checked just above).
                unsafe { avx2(self, row, src, mirrored) };
                return;
            }
        }
        self.apply_impl(row, src, mirrored)
    }

    #[inline(always)]
    fn apply_impl(&self, row: &mut [Complex64], src: &[Complex64], mirrored: bool) {
        let n = row.len();
        let (gy, ky, dky) = (&self.gy[..n], &self.ky[..n], &self.dky[..n]);
        let body = |i: usize, f: Complex64| {
            let mut g = self.c * gy[i];
            if self.a2 > 0.0 {
                g *= self.a2 * (self.kx2 + ky[i] * ky[i]);
            }
            // (i dkx - dky) * g * f̂
            let (re, im) = (-dky[i] * g, self.dkx * g);
            Complex64::new(re * f.re - im * f.im, re * f.im + im * f.re)
        };
        if !mirrored {
            for (i, (r, &f)) in row.iter_mut().zip(&src[..n]).enumerate() {
                *r = body(i, f);
            }
        } else {
            // f̂(kx, ky) = conj f̂(nx - kx, ny - ky)
            row[0] = body(0, src[0].conj());
            for (i, (r, &f)) in row[1..].iter_mut().zip(src[1..n].iter().rev()).enumerate() {
                *r = body(i + 1, f.conj());
            }
        }
    }
}

/// Hints the CPU to bring `v`'s cache line into L1 (no-op elsewhere).
#[inline(always)]
fn prefetch<T>(v: &T) {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: prefetching is a hint; any address is allowed, and SSE is part
    // of the x86_64 baseline.
    unsafe {
        use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
        _mm_prefetch::<_MM_HINT_T0>(v as *const T as *const i8);
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = v;
}

/// Modulus `M = sqrt(T1² + T2²)` (not `Complex::norm`, which calls hypot and
/// is slow in hot loops).
#[inline]
pub fn modulus(t: Complex64) -> f64 {
    (t.re * t.re + t.im * t.im).sqrt()
}

/// Argument `A = atan2(T2, T1)` in (-π, π].
#[inline]
pub fn argument(t: Complex64) -> f64 {
    t.im.atan2(t.re)
}

/// Modulus and argument images of one scale.
pub fn modulus_argument(t: &Array2<Complex64>) -> (Array2<f64>, Array2<f64>) {
    (t.map(|&z| modulus(z)), t.map(|&z| argument(z)))
}

/// Direct (slow) spatial evaluation of `T` at pixel `(y, x)` with the sampled
/// continuous wavelet, periodic boundary: a reference for tests (SPEC §1).
/// Truncated at radius `10 a` where the Gaussian is below e^-50; costs
/// `(20 a)²` evaluations.
///
/// `(y, x)` outside the image wraps around, as the periodic boundary does.
///
/// **Panics** on an empty image.
pub fn direct_transform_at(
    img: ArrayView2<f64>,
    wavelet: Wavelet,
    a: f64,
    y: usize,
    x: usize,
) -> Complex64 {
    let (ny, nx) = img.dim();
    let r = (10.0 * a).ceil() as isize;
    let (mut t1, mut t2) = (0.0, 0.0);
    for dy in -r..=r {
        for dx in -r..=r {
            // T(b) = a ∫ ∇φ_a(b - x') f(x') dx' ; with u = (b - x')/a,
            // ∇_b φ_a = a⁻³ (∇φ)(u), so T = a⁻² Σ (∇φ)(u) f(x').
            let (ux, uy) = (dx as f64 / a, dy as f64 / a);
            let r2 = ux * ux + uy * uy;
            let e = (-0.5 * r2).exp() / (2.0 * std::f64::consts::PI);
            // ∇φ for gauss: -u e; for mexican φ = (2 - r²) e: ∇φ = u (r² - 4) e
            let (gx, gy) = match wavelet {
                Wavelet::Gauss => (-ux * e, -uy * e),
                Wavelet::Mexican => (ux * (r2 - 4.0) * e, uy * (r2 - 4.0) * e),
            };
            let yy = (y as isize - dy).rem_euclid(ny as isize) as usize;
            let xx = (x as isize - dx).rem_euclid(nx as isize) as usize;
            let f = img[[yy, xx]];
            t1 += gx * f;
            t2 += gy * f;
        }
    }
    Complex64::new(t1 / (a * a), t2 / (a * a))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mexican_margin_is_wider() {
        let r = Wavelet::Mexican.support_radius();
        assert!(r > 3.2 && r < 6.0, "{r}");
        let t = Wavelet::Mexican.tail_fraction(r);
        assert!((t - Wavelet::Gauss.tail_fraction(3.2)).abs() < 1e-9);
    }

    #[test]
    fn scale_grid() {
        let g = ScaleGrid::default();
        let s = g.scales();
        assert_eq!(s.len(), 50);
        assert!((s[10] - 3.0).abs() < 1e-12);
        assert!((g.a_max() - s[49]).abs() < 1e-12);
    }
}
