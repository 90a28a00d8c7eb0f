//! # wtmm — multifractal analysis of images
//!
//! The 2D wavelet transform modulus maxima (WTMM) method of Arnéodo, Decoster
//! and Roux (Eur. Phys. J. B 15, 2000; the method paper is seed 002 in
//! `shared/seeds`), with the synthetic generators that validate it.
//!
//! Data flows one way: image ([`io`], [`field::Field`]) → continuous wavelet
//! transform ([`cwt`]) → maxima, chains, WTMMM and maxima lines
//! ([`skeleton`]) → partition sums → spectra τ(q), h(q), D(q), D(h)
//! (`spectra`). The library never prints; the `wtmm` binary ([`cli`]) formats.

// `!(x > 0.0)` is how we reject NaN together with out-of-range values.
#![allow(clippy::neg_cmp_op_on_partial_ord)]
// Every public item is documented; keep it so.
#![warn(missing_docs)]

pub mod cli;
pub mod cwt;
pub mod error;
pub mod field;
pub mod fourier;
pub mod io;
pub mod plot;
pub mod skeleton;
pub mod spectra;
pub mod stats;
pub mod synth;
pub mod theory;
pub mod tracemoments;

pub use error::{Error, Result};
pub use field::Field;

/// The crate version, recorded in every output.
pub const VERSION: &str = env!("CARGO_PKG_VERSION");
