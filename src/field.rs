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
    /// support touches a masked pixel, so the fill value never reaches a result.)
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

    /// Min and max over valid pixels, `None` if every pixel is masked.
    pub fn range(&self) -> Option<(f64, f64)> {
        finite_range(self.data.iter())
    }
}

/// The smallest and largest finite values (`None` if there are none).
pub fn finite_range<'a>(values: impl IntoIterator<Item = &'a f64>) -> Option<(f64, f64)> {
    let mut it = values.into_iter().filter(|v| v.is_finite());
    let first = *it.next()?;
    Some(it.fold((first, first), |(lo, hi), &v| (lo.min(v), hi.max(v))))
}
