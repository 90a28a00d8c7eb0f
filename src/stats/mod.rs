//! Statistics: regressions, power spectra (and later pdfs, kernel, correlations).

pub mod fit;
pub mod powspec;

pub use fit::{LineFit, line_fit};
