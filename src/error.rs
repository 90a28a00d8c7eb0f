//! One error type for the whole library (ndarray's pattern: one enum, a clear
//! message per kind). Messages name the file or the parameter at fault.

use std::path::PathBuf;

/// Every fallible library call returns this.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// The file could not be opened or read at the OS level.
    #[error("{}: cannot read: {source}", path.display())]
    Read {
        /// The file that could not be read.
        path: PathBuf,
        /// The underlying OS error.
        source: std::io::Error,
    },
    /// The file could not be written.
    #[error("{}: cannot write: {source}", path.display())]
    Write {
        /// The file that could not be written.
        path: PathBuf,
        /// The underlying OS error.
        source: std::io::Error,
    },
    /// The file was read but its content is not what we support.
    #[error("{}: {reason}", path.display())]
    Format {
        /// The file whose content was rejected.
        path: PathBuf,
        /// What is wrong with the content (human-readable).
        reason: String,
    },
    /// A parameter is out of range or inconsistent with another.
    #[error("invalid parameter `{name}`: {reason}")]
    Param {
        /// The parameter at fault (a config field or CLI option name, e.g. `scales`, `max-dx`).
        name: String,
        /// Why the value was rejected (human-readable).
        reason: String,
    },
    /// The data itself cannot be analysed (constant image, too small, ...).
    #[error("invalid input: {0}")]
    Input(String),
}

impl Error {
    /// Shorthand for [`Error::Param`].
    pub fn param(name: impl Into<String>, reason: impl Into<String>) -> Self {
        Error::Param {
            name: name.into(),
            reason: reason.into(),
        }
    }

    /// Shorthand for [`Error::Format`].
    pub fn format(path: impl Into<PathBuf>, reason: impl Into<String>) -> Self {
        Error::Format {
            path: path.into(),
            reason: reason.into(),
        }
    }
}

/// Library result alias.
pub type Result<T> = std::result::Result<T, Error>;

/// A number for a message: as Rust prints it in the usual range, in
/// scientific notation beyond it (`1e-300` printed in full is 300 digits).
/// In the usual range at most 6 significant digits, trailing zeros
/// trimmed: what a user typed reads back as typed (to 6 digits), a sum's
/// rounding (`1.9000000000000001`) does not show, nor pi/4's 16 digits.
pub(crate) fn short(x: f64) -> String {
    if x == 0.0 || !x.is_finite() {
        format!("{x}")
    } else if (1e-3..1e6).contains(&x.abs()) {
        let decimals = (5 - x.abs().log10().floor() as i32).max(0) as usize;
        let s = format!("{x:.decimals$}");
        if s.contains('.') {
            s.trim_end_matches('0').trim_end_matches('.').to_string()
        } else {
            s
        }
    } else {
        format!("{x:.3e}")
    }
}

/// [`short`] for a value refused for lying outside a range: where 6 digits
/// would round it onto one of the range's `bounds` ("must be in (0, 1/2],
/// got 0.5" for 0.5000001), its [`exact`] digits instead.
pub(crate) fn short_outside(x: f64, bounds: &[f64]) -> String {
    let s = short(x);
    match s.parse::<f64>() {
        Ok(r) if bounds.contains(&r) && !bounds.contains(&x) => exact(x),
        _ => s,
    }
}

/// A number for a message that the user may type back (`--nodata VALUE`):
/// the shortest digits that read back as exactly `x` (both Rust formats
/// give them), in Rust's plain notation in the usual range and with an
/// exponent beyond it (`{}` never uses one: 1e-300 would be 300 digits).
pub(crate) fn exact(x: f64) -> String {
    if x == 0.0 || !x.is_finite() || (1e-4..1e16).contains(&x.abs()) {
        format!("{x}")
    } else {
        format!("{x:?}")
    }
}

#[cfg(test)]
mod tests {
    use super::exact;

    /// `exact` reads back as the value, and stays short at the extremes.
    #[test]
    fn exact_numbers_read_back() {
        for x in [
            0.0,
            -9999.0,
            0.1,
            123.456,
            -32768.0,
            1e-300,
            -5e-5,
            f64::MIN_POSITIVE,
            1e20,
            1.7976931348623157e308,
            0.30000000000000004,
        ] {
            let s = exact(x);
            assert_eq!(s.parse::<f64>().unwrap(), x, "{s}");
            assert!(s.len() <= 24, "{s}");
        }
        assert_eq!(exact(-9999.0), "-9999");
        assert_eq!(exact(1e-300), "1e-300");
    }
}
