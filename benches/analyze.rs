//! Whole `analyze` pipeline for one 1024x1024 image (CWT, maxima, chains,
//! WTMMM, linking, partition sums for 33 values of q and both rules, spectra)
//! against the floor of 50 bare inverse 2D complex FFTs measured in the same
//! run. Run: `cargo bench --bench analyze`. Target (issue 4): <= 1.8x
//! single-threaded.

mod common;

use common::{FftFloor, one_thread_pool, paired};
use wtmm::Field;
use wtmm::skeleton::AnalysisConfig;
use wtmm::spectra::{Rule, image_sums};
use wtmm::synth::fbm::{FbmParams, fbm};

fn main() {
    let n = 1024;
    let field = Field::new(fbm(FbmParams { hurst: 1.0 / 3.0 }, n, n, 1, 0).unwrap());
    let cfg = AnalysisConfig::default();
    let ns = cfg.scale_list().len();
    let q: Vec<f64> = (0..33).map(|i| -4.0 + 0.3125 * i as f64).collect();
    let floor = FftFloor::new(n, n);
    let reps = 7;
    let pool = one_thread_pool();
    let (t_an, t_fft, ratio) = pool.install(|| {
        paired(
            reps,
            || {
                let s = image_sums(&field, &cfg, &q, "bench").unwrap();
                std::hint::black_box(s.spectra(Rule::Plain, (0.5, 4.0)).unwrap());
            },
            floor.serial_runner(ns),
        )
    });
    println!(
        "analyze bench: {n}x{n}, {ns} scales, {} q values, gauss",
        q.len()
    );
    println!(
        "1 thread: FFT floor {:7.1} ms | analyze {:7.1} ms (median ratio of {reps} interleaved pairs {:.3}x)",
        1e3 * t_fft,
        1e3 * t_an,
        ratio
    );
}
