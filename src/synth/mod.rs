//! Synthetic fields with known multifractal spectra (SPEC §9): the ground
//! truth every estimator is validated against. Every generator takes a seed;
//! image `i` of an ensemble uses [`image_seed`]`(seed, i)`, so the same seed
//! gives the same bytes whatever the thread count or the order of generation.
//!
//! # Example
//!
//! ```
//! use wtmm::synth::fbm::{FbmParams, fbm};
//! use wtmm::synth::fif::{FifParams, fif};
//! use wtmm::theory::Model;
//! # fn main() -> wtmm::Result<()> {
//! // image 3 of the paper's log-normal W-cascade ensemble of seed 1
//! // (SPEC §11): the same bytes on any machine and thread count
//! let model = Model::preset("paper-lognormal")?.model;
//! let img = model.synthesize(128, 1, 3)?;
//! assert_eq!(img, model.synthesize(128, 1, 3)?);
//! // and what the theory says of it: beta = tau(2) + 4
//! assert!((model.beta() - (model.tau(2.0) + 4.0)).abs() < 1e-12);
//! // the generators by name: an fBm of H = 1/3 (any size), a universal
//! // multifractal (FIF) with the topography's parameters
//! let f = fbm(FbmParams { hurst: 1.0 / 3.0 }, 96, 128, 1, 0)?;
//! assert_eq!(f.dim(), (96, 128));
//! let u = fif(&FifParams::TOPO, 64, 64, 1, 0)?;
//! assert!(u.iter().all(|v| v.is_finite()));
//! // parameters out of range are errors naming them
//! let e = fbm(FbmParams { hurst: 1.5 }, 64, 64, 1, 0).unwrap_err();
//! assert!(e.to_string().contains("hurst"));
//! # Ok(())
//! # }
//! ```

pub mod dwt;
pub mod fbm;
pub mod fif;
pub mod fisc;
pub mod levy;
pub mod wcascade;

use crate::error::{Error, Result};
use rand::SeedableRng;
use rand::rngs::Xoshiro256PlusPlus;

/// The generator behind every synthetic field: xoshiro256++, a documented
/// algorithm whose output does not change between rand versions (unlike
/// `StdRng`).
pub type SynthRng = Xoshiro256PlusPlus;

/// An error unless a generated `ny x nx` image is at most
/// [`crate::io`]'s limit of 2^28 pixels (16384^2): beyond it the product
/// may wrap or the allocation abort the process instead of failing.
pub(crate) fn check_pixels(ny: usize, nx: usize) -> Result<()> {
    match ny.checked_mul(nx) {
        Some(n) if n <= crate::io::MAX_PIXELS => Ok(()),
        _ => Err(Error::param(
            "size",
            format!(
                "{ny}x{nx} is over the limit of {} M pixels (16384^2)",
                crate::io::MAX_PIXELS >> 20
            ),
        )),
    }
}

/// An error unless `levels` stays within a cascade of `steps` steps (up
/// to `steps + 1`, the levels past the last being empty): the own-cascade
/// functions return one (possibly empty) list per level asked, and a range
/// far past the cascade would allocate without bound.
pub(crate) fn check_levels(
    levels: &std::ops::Range<usize>,
    steps: usize,
    size: usize,
) -> Result<()> {
    if levels.end > steps + 1 {
        return Err(Error::param(
            "levels",
            format!(
                "{}..{} reaches past the {steps} steps of a {size} px cascade",
                levels.start, levels.end
            ),
        ));
    }
    Ok(())
}

/// SplitMix64 finaliser (Steele, Lea & Flood 2014), used to derive
/// well-separated seeds.
pub fn splitmix64(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Seed of image `index` in an ensemble started with `seed`.
pub fn image_seed(seed: u64, index: u64) -> u64 {
    splitmix64(seed ^ splitmix64(index.wrapping_add(0x5851_F42D_4C95_7F2D)))
}

/// A generator seeded for image `index` of the ensemble `seed`.
pub fn rng_for(seed: u64, index: u64) -> SynthRng {
    SynthRng::seed_from_u64(image_seed(seed, index))
}
