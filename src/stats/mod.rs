//! Statistics: regressions, power spectra, WTMMM pdfs, the self-similarity
//! kernel and space-scale correlations.

pub mod correlation;
pub mod fit;
pub mod kernel;
pub mod pdf;
pub mod powspec;

pub use fit::{LineFit, jackknife_se, line_fit, slope_change};
