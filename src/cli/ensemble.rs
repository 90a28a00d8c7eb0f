//! Synthetic ensembles analysed in memory, streamed: image `i` is generated,
//! analysed and dropped inside one parallel task, so at most one image per
//! worker is alive whatever the count.

use ndarray::Array2;
use rayon::prelude::*;

use crate::error::Result;
use crate::field::Field;
use crate::skeleton::AnalysisConfig;
use crate::spectra::{PartitionSums, image_sums};
use crate::stats::powspec::{PowerSpectrum, PowerSpectrumConfig, power_spectrum};

/// Partition sums and power spectrum of an ensemble.
pub struct EnsembleResult {
    pub sums: PartitionSums,
    pub spectrum: PowerSpectrum,
    /// Per-image power spectra (for the scatter of beta).
    pub spectra: Vec<PowerSpectrum>,
}

/// Generates `count` images with `make(i)` and analyses them; `tick` is
/// called once per finished image (progress bars).
pub fn analyse_generated<G>(
    count: usize,
    make: G,
    cfg: &AnalysisConfig,
    q: &[f64],
    ps_cfg: &PowerSpectrumConfig,
    tick: &(dyn Fn() + Sync),
) -> Result<EnsembleResult>
where
    G: Fn(usize) -> Result<Array2<f64>> + Sync,
{
    let parts: Vec<(PartitionSums, PowerSpectrum)> = (0..count)
        .into_par_iter()
        .map(|i| {
            let img = make(i)?;
            let ps = power_spectrum(img.view(), ps_cfg)?;
            let sums = image_sums(&Field::new(img), cfg, q, format!("image {i}"))?;
            tick();
            Ok((sums, ps))
        })
        .collect::<Result<_>>()?;
    let mut spectrum = PowerSpectrum::default();
    let mut spectra = Vec::with_capacity(count);
    let mut sums = Vec::with_capacity(count);
    for (s, p) in parts {
        spectrum.merge(&p)?;
        spectra.push(p);
        sums.push(s);
    }
    Ok(EnsembleResult {
        sums: PartitionSums::merge_all(sums)?.expect("count >= 1"),
        spectrum,
        spectra,
    })
}
