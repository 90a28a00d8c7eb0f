//! The image type that flows through the pipeline: values plus a mask of
//! missing pixels (NaN or nodata in the file).

use ndarray::Array2;

use crate::error::{Error, Result};

/// A real 2D field `f[y][x]` with an optional mask (`true` = missing).
#[derive(Clone, Debug, PartialEq)]
pub struct Field {
    /// Values; masked pixels hold NaN.
    pub data: Array2<f64>,
    /// `Some(m)` when at least one pixel is missing; `m[[y, x]] == true` there.
    pub mask: Option<Array2<bool>>,
}

impl Field {
    /// Wraps an array, masking every non-finite value.
    pub fn new(mut data: Array2<f64>) -> Self {
        let mask = data.map(|v| !v.is_finite());
        let any = mask.iter().any(|&m| m);
        if any {
            data.zip_mut_with(&mask, |v, &m| {
                if m {
                    *v = f64::NAN
                }
            });
        }
        Field {
            data,
            mask: any.then_some(mask),
        }
    }

    /// Wraps an array with an explicit mask (`true` = missing); masked values become NaN.
    pub fn with_mask(mut data: Array2<f64>, mut mask: Array2<bool>) -> Self {
        assert_eq!(data.dim(), mask.dim(), "data and mask shapes differ");
        mask.zip_mut_with(&data, |m, v| *m |= !v.is_finite());
        data.zip_mut_with(&mask, |v, &m| {
            if m {
                *v = f64::NAN
            }
        });
        let any = mask.iter().any(|&m| m);
        Field {
            data,
            mask: any.then_some(mask),
        }
    }

    /// `(ny, nx)`.
    pub fn dim(&self) -> (usize, usize) {
        self.data.dim()
    }

    /// Number of valid (unmasked) pixels.
    pub fn valid_count(&self) -> usize {
        match &self.mask {
            None => self.data.len(),
            Some(m) => m.iter().filter(|&&x| !x).count(),
        }
    }

    /// True if pixel `(y, x)` is masked.
    pub fn is_masked(&self, y: usize, x: usize) -> bool {
        self.mask.as_ref().is_some_and(|m| m[[y, x]])
    }

    /// The values with masked pixels replaced by the mean of the valid ones,
    /// ready for the FFT. (The maxima code later drops any WTMM whose wavelet
    /// support, radius `R a`, touches a masked pixel; what the Gaussian's
    /// tail carries beyond it is negligible: a holed fBm ensemble gives the
    /// τ(q) of the unholed one counted on the same domain within 0.003,
    /// `tests/spectra.rs`.)
    ///
    /// **Errors** if no pixel is valid.
    pub fn filled(&self) -> Result<Array2<f64>> {
        let Some(mask) = &self.mask else {
            return Ok(self.data.clone());
        };
        let (mut sum, mut n) = (0.0, 0usize);
        for (v, &m) in self.data.iter().zip(mask.iter()) {
            if !m {
                sum += v;
                n += 1;
            }
        }
        if n == 0 {
            return Err(Error::Input(
                "every pixel is missing (NaN or nodata)".into(),
            ));
        }
        let mean = sum / n as f64;
        let mut out = self.data.clone();
        out.zip_mut_with(mask, |v, &m| {
            if m {
                *v = mean
            }
        });
        Ok(out)
    }

    /// [`amplitude_problem`] of the valid pixels.
    pub fn amplitude_problem(&self) -> Option<String> {
        amplitude_problem(self.data.iter())
    }

    /// Min and max over valid pixels, `None` if every pixel is masked.
    pub fn range(&self) -> Option<(f64, f64)> {
        finite_range(self.data.iter())
    }
}

/// Largest magnitude of a value, and smallest non-zero spread (max - min),
/// that the transforms accept. The moduli are `sqrt(T1^2 + T2^2)` and the
/// power spectrum sums `|f̂|^2` with `f̂` up to `N^2` times the values: at
/// 1e100 (or a spread of 1e-100) and beyond, squares overflow (underflow)
/// for any image a machine holds. The exponents do not depend on a
/// constant factor, so such data only need rescaling.
pub const AMPLITUDE_LIMIT: f64 = 1e100;

/// Why finite `values` cannot be transformed in f64 (see
/// [`AMPLITUDE_LIMIT`]), or `None`. A constant field passes (the commands
/// report it as constant).
pub fn amplitude_problem<'a>(values: impl IntoIterator<Item = &'a f64>) -> Option<String> {
    let (lo, hi) = finite_range(values)?;
    let big = lo.abs().max(hi.abs());
    let spread = hi - lo;
    if big > AMPLITUDE_LIMIT || spread > AMPLITUDE_LIMIT {
        Some(format!(
            "values up to {big:.3e} in magnitude (range {lo:.3e} to {hi:.3e}): beyond \
             {AMPLITUDE_LIMIT:.0e} the squared wavelet moduli and spectra overflow; rescale \
             the image (a constant factor leaves every exponent unchanged)"
        ))
    } else if spread > 0.0 && spread < 1.0 / AMPLITUDE_LIMIT {
        Some(format!(
            "values vary by only {spread:.3e} (range {lo:.3e} to {hi:.3e}): below {:.0e} the \
             squared wavelet moduli and spectra underflow; rescale the image (a constant \
             factor leaves every exponent unchanged)",
            1.0 / AMPLITUDE_LIMIT
        ))
    } else {
        None
    }
}

/// The smallest and largest finite values (`None` if there are none).
pub fn finite_range<'a>(values: impl IntoIterator<Item = &'a f64>) -> Option<(f64, f64)> {
    let mut it = values.into_iter().filter(|v| v.is_finite());
    let first = *it.next()?;
    Some(it.fold((first, first), |(lo, hi), &v| (lo.min(v), hi.max(v))))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn amplitudes_beyond_the_squares_of_f64_are_named() {
        let v = [1.0, -2.0, 3.5];
        assert_eq!(amplitude_problem(&v), None);
        // a constant is left to the commands' own message
        assert_eq!(amplitude_problem(&[7.0, 7.0]), None);
        assert_eq!(amplitude_problem(&[f64::NAN]), None);
        let big = amplitude_problem(&[0.0, 2e100]).unwrap();
        assert!(
            big.contains("2.000e100") && big.contains("overflow"),
            "{big}"
        );
        let tiny = amplitude_problem(&[1e-160, 3e-160]).unwrap();
        assert!(tiny.contains("underflow"), "{tiny}");
        // large but far from overflow, and a large offset with a sane spread
        assert_eq!(amplitude_problem(&[0.0, 1e90]), None);
        assert_eq!(amplitude_problem(&[1e50, 1e50 + 1e40]), None);
    }
}
