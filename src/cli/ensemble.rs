//! Synthetic ensembles analysed in memory, streamed: image `i` is generated,
//! analysed and dropped inside one parallel task, so at most one image per
//! worker is alive whatever the count.

use ndarray::Array2;

use crate::error::Result;
use crate::field::Field;
use crate::skeleton::{AnalysisConfig, Parallelism, Skeleton, Wtmmm, skeleton_and_wtmmm};
use crate::spectra::{PartitionSums, default_tile_side, skeleton_sums_tiled};
use crate::stats::powspec::{PowerSpectrum, PowerSpectrumConfig, power_spectrum};

/// Partition sums and power spectrum of an ensemble.
pub struct EnsembleResult {
    pub sums: PartitionSums,
    pub spectrum: PowerSpectrum,
    /// Per-image power spectra (for the scatter of beta).
    pub spectra: Vec<PowerSpectrum>,
}

/// Generates `count` images with `make(i)` and analyses them, also running
/// `extra(i, field, skeleton, wtmmm)` on each image's skeleton and its
/// WTMMM at the first `wtmmm_scales` scales ([`skeleton_and_wtmmm`]), so
/// that statistics beyond the partition sums cost no second transform. The
/// results come back in image order; `tick` is called once per finished
/// image (progress bars). At most `limit` images are in flight (`None`:
/// one per rayon thread), from [`super::common::check_ensemble_memory`].
#[allow(clippy::too_many_arguments)]
pub fn analyse_generated<G, X, F>(
    count: usize,
    limit: Option<usize>,
    make: G,
    cfg: &AnalysisConfig,
    q: &[f64],
    ps_cfg: &PowerSpectrumConfig,
    wtmmm_scales: usize,
    extra: F,
    tick: &(dyn Fn() + Sync),
) -> Result<(EnsembleResult, Vec<X>)>
where
    G: Fn(usize) -> Result<Array2<f64>> + Sync,
    X: Send,
    F: Fn(usize, &Field, &Skeleton, Vec<Vec<Wtmmm>>) -> Result<X> + Sync,
{
    // a refused draw is named by its index in order, whatever the scheduling
    let parts: Vec<(PartitionSums, PowerSpectrum, X)> =
        crate::par::try_map_limited(count, limit, |i| {
            let img = make(i)?;
            let ps = power_spectrum(img.view(), ps_cfg)?;
            let field = Field::new(img);
            let (sk, wtmmm) =
                skeleton_and_wtmmm(&field, cfg, Parallelism::Serial, wtmmm_scales, true)?;
            // fewer than 3 images: the jackknife runs over tiles
            let side = if count < 3 {
                let (ny, nx) = field.dim();
                default_tile_side(cfg, ny, nx)
            } else {
                0
            };
            let sums = skeleton_sums_tiled(&sk, &field, cfg, q, format!("image {i}"), side);
            let x = extra(i, &field, &sk, wtmmm)?;
            tick();
            Ok((sums, ps, x))
        })?;
    let mut spectrum = PowerSpectrum::default();
    let mut spectra = Vec::with_capacity(count);
    let mut sums = Vec::with_capacity(count);
    let mut extras = Vec::with_capacity(count);
    for (s, p, x) in parts {
        spectrum.merge(&p)?;
        spectra.push(p);
        sums.push(s);
        extras.push(x);
    }
    let ens = EnsembleResult {
        sums: PartitionSums::merge_all(sums)?.expect("count >= 1"),
        spectrum,
        spectra,
    };
    Ok((ens, extras))
}
