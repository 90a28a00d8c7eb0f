//! The correlation's 2D real FFT in f32, its columns gathered in blocks.

use super::*;

/// Columns gathered per block in the column FFTs: a block of 1024-point
/// columns (512 KB at 32) stays in L2 while it is transformed. Measured on
/// 1024^2 (torus, one thread): 4, 8, 16 or 32 columns, and gathering four
/// rows at a time so that stores fill whole lines, all within the noise of
/// each other (77-97 ms).
pub(super) const COLS: usize = 32;

/// Padding between the spectrum's columns (complex elements; see
/// [`RFft2`]): 64 bytes, one cache line.
pub(super) const COL_PAD: usize = 8;

/// A 2D real-to-complex FFT of size `fy x fx` in f32: realfft along x (half
/// spectrum, `nh = fx/2 + 1` columns), complex FFT along y. The spectrum is
/// kept transposed (`[kx][ky]`, `nh x fy`), as in [`crate::cwt`]; only
/// element-wise products are taken of it, so the layout is free. The column
/// pass gathers [`COLS`] columns at a time and transforms them while they
/// sit in L2, and the inverse forms the cross-spectrum inside the block, so
/// neither a transposed copy nor the product array is stored. (Whole-array
/// transposes were a fifth of the profile on 1024²; the strided gather and
/// scatter that replace them cost nearly as much: 101 -> 97 ms.)
///
/// **Why f32.** The fields are centred magnitudes (|w| of order 1) and the
/// binned sums add 10^4-10^6 lags: the FFT's relative error (about
/// `6e-8 log2 N` of the fields' norms) moves `C` and its errors by less
/// than 1e-6 (8e-7 at most against the f64 version on 4 x 512²), three
/// orders below the statistical error of an ensemble, while an f32 FFT
/// costs half as much time and memory traffic (SPEC §1 allows f32 where a
/// test shows agreement; `tests/stats.rs` checks these sums against a
/// brute-force f64 pair loop). The fields stay f64, converted row by row,
/// and every bin is accumulated in f64.
///
/// Rows known to be zero on input (the zero padding of a linear
/// correlation) cost no row FFT, and output rows whose lags are never
/// binned are not inverted.
///
/// **Column stride.** The columns of the spectrum lie `cs = fy + 8`
/// elements apart, not `fy`: with `fy` a power of two the stride is a
/// multiple of 4 KiB, so the [`COLS`] columns a row is scattered into (and
/// gathered from) all fall in the same L1 set and evict each other. The
/// padding is never read as data (its products are of zeros).
#[derive(Clone)]
pub(super) struct RFft2 {
    pub(super) fy: usize,
    pub(super) fx: usize,
    pub(super) nh: usize,
    /// Column stride of the spectra and of the column block.
    pub(super) cs: usize,
    /// Rows `>= rows_in` of every input field are zero.
    pub(super) rows_in: usize,
    /// Output rows needed: `y <= lag_rows` or `y >= fy - lag_rows`.
    pub(super) lag_rows: usize,
    pub(super) r2c: Arc<dyn RealToComplex<f32>>,
    pub(super) c2r: Arc<dyn ComplexToReal<f32>>,
    pub(super) fwd_y: Arc<dyn Fft<f32>>,
    pub(super) inv_y: Arc<dyn Fft<f32>>,
    pub(super) scratch_len: usize,
}

impl RFft2 {
    pub(super) fn new(fy: usize, fx: usize, rows_in: usize, lag_rows: usize) -> Self {
        let mut rp = RealFftPlanner::<f32>::new();
        let (r2c, c2r) = (rp.plan_fft_forward(fx), rp.plan_fft_inverse(fx));
        let mut p = FftPlanner::<f32>::new();
        let (fwd_y, inv_y) = (p.plan_fft_forward(fy), p.plan_fft_inverse(fy));
        let scratch_len = [
            r2c.get_scratch_len(),
            c2r.get_scratch_len(),
            fwd_y.get_inplace_scratch_len(),
            inv_y.get_inplace_scratch_len(),
        ]
        .into_iter()
        .max()
        .unwrap_or(0);
        RFft2 {
            fy,
            fx,
            nh: fx / 2 + 1,
            cs: fy + COL_PAD,
            rows_in: rows_in.min(fy),
            lag_rows,
            r2c,
            c2r,
            fwd_y,
            inv_y,
            scratch_len,
        }
    }

    /// `field` (`[y][x]`) -> `out` (`[kx][ky]`, columns `cs` apart,
    /// unnormalised); `half` is `fy x nh` scratch, `row` an `fx` row buffer.
    pub(super) fn forward(
        &self,
        field: &[f64],
        half: &mut [Complex32],
        out: &mut [Complex32],
        row: &mut [f32],
        scratch: &mut [Complex32],
    ) {
        self.forward_rows(field, 0..self.rows_in, half, out, row, scratch);
    }

    /// [`Self::forward`] of a field known to be zero outside `rows` (a
    /// tile's band): the other rows cost no row FFT.
    pub(super) fn forward_rows(
        &self,
        field: &[f64],
        rows: std::ops::Range<usize>,
        half: &mut [Complex32],
        out: &mut [Complex32],
        row: &mut [f32],
        scratch: &mut [Complex32],
    ) {
        let (fx, fy, nh, cs) = (self.fx, self.fy, self.nh, self.cs);
        for (y, (src, h)) in field
            .chunks_exact(fx)
            .zip(half.chunks_exact_mut(nh))
            .enumerate()
        {
            if !rows.contains(&y) || y >= self.rows_in {
                h.fill(Complex32::default());
                continue;
            }
            for (d, &v) in row.iter_mut().zip(src) {
                *d = v as f32;
            }
            self.r2c
                .process_with_scratch(row, h, scratch)
                .expect("realfft lengths come from the plan");
        }
        for k0 in (0..nh).step_by(COLS) {
            let c = COLS.min(nh - k0);
            let blk = &mut out[k0 * cs..(k0 + c) * cs];
            for (y, src) in half.chunks_exact(nh).enumerate() {
                for (j, &v) in src[k0..k0 + c].iter().enumerate() {
                    blk[j * cs + y] = v;
                }
            }
            for col in blk.chunks_exact_mut(cs) {
                self.fwd_y.process_with_scratch(&mut col[..fy], scratch);
            }
        }
    }

    /// The circular cross-correlation `r(d) = Σ_x f(x) g(x + d)` of two
    /// real fields from their spectra `fa`, `fb` (`[kx][ky]`, from
    /// [`RFft2::forward`]) into `out` (`[y][x]`; rows of unbinned lags are
    /// left as they were): the inverse transform of `conj(F) G / (fy fx)`,
    /// formed one block of columns at a time (`blk` holds [`COLS`] columns)
    /// and scattered into `half` (`fy x nh`).
    pub(super) fn correlate(
        &self,
        fa: &[Complex32],
        fb: &[Complex32],
        blk: &mut [Complex32],
        half: &mut [Complex32],
        out: &mut [f32],
        scratch: &mut [Complex32],
    ) {
        let (fx, fy, nh, cs) = (self.fx, self.fy, self.nh, self.cs);
        let norm = 1.0 / (fy * fx) as f32;
        for k0 in (0..nh).step_by(COLS) {
            let c = COLS.min(nh - k0);
            let b = &mut blk[..c * cs];
            let (sa, sb) = (&fa[k0 * cs..(k0 + c) * cs], &fb[k0 * cs..(k0 + c) * cs]);
            for ((v, a), g) in b.iter_mut().zip(sa).zip(sb) {
                *v = a.conj() * g * norm;
            }
            for col in b.chunks_exact_mut(cs) {
                self.inv_y.process_with_scratch(&mut col[..fy], scratch);
            }
            for (y, dst) in half.chunks_exact_mut(nh).enumerate() {
                for (j, v) in dst[k0..k0 + c].iter_mut().enumerate() {
                    *v = b[j * cs + y];
                }
            }
        }
        for (y, (h, dst)) in half
            .chunks_exact_mut(nh)
            .zip(out.chunks_exact_mut(fx))
            .enumerate()
        {
            if y > self.lag_rows && y + self.lag_rows < fy {
                continue;
            }
            // real by symmetry: drop the rounding noise where realfft wants 0
            h[0].im = 0.0;
            if fx.is_multiple_of(2) {
                h[nh - 1].im = 0.0;
            }
            self.c2r
                .process_with_scratch(h, dst, scratch)
                .expect("lengths from the plan, zeroed imaginary parts");
        }
    }
}
