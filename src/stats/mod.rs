//! Statistics: regressions, power spectra, WTMMM pdfs, the self-similarity
//! kernel and space-scale correlations.

pub mod correlation;
pub mod fit;
pub mod kernel;
pub mod pdf;
pub mod powspec;

pub use fit::{LineFit, line_fit};
