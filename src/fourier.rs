//! DFT index conventions shared by the wavelet transform, the power
//! spectra, the correlations and the spectral generators: bin `m` of an
//! `n`-point FFT is frequency `m` for `m <= n/2` and `m - n` above (the
//! Nyquist bin of an even `n` counts as positive).

/// The signed frequency index of DFT bin `m` of `n`, in `(-n/2, n/2]`.
#[inline]
pub fn signed_bin(m: usize, n: usize) -> i64 {
    if m <= n / 2 {
        m as i64
    } else {
        m as i64 - n as i64
    }
}

/// Angular frequency of DFT bin `m` of `n` (radians per pixel), in `(-π, π]`.
#[inline]
pub fn angular_freq(m: usize, n: usize) -> f64 {
    2.0 * std::f64::consts::PI * signed_bin(m, n) as f64 / n as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bins_and_frequencies() {
        assert_eq!(
            (0..6).map(|m| signed_bin(m, 6)).collect::<Vec<_>>(),
            [0, 1, 2, 3, -2, -1]
        );
        assert_eq!(
            (0..5).map(|m| signed_bin(m, 5)).collect::<Vec<_>>(),
            [0, 1, 2, -2, -1]
        );
        assert_eq!(angular_freq(2, 4), std::f64::consts::PI);
        assert_eq!(angular_freq(3, 4), -std::f64::consts::FRAC_PI_2);
    }
}
