//! Space-scale correlation (`wtmm correlate`, II Fig 30: scales 1.5, 3 and
//! 6 px, four pairs) of one 1024x1024 image against one CWT scale (the
//! unit of issue 6: "correlate costs no more than a few CWT scales") and
//! against one bare inverse 2D complex FFT, single thread, as the median of
//! interleaved pairs. Two domains: the torus (periodic W-cascade, the
//! paper's case) and the interior of a non-periodic field (fBm; linear
//! correlations on zero-padded FFTs of 1.5x the side).
//! Run: `cargo bench --bench correlate`.

mod common;

use common::{FftFloor, one_thread_pool, paired};
use wtmm::Field;
use wtmm::cwt::{CwtPlan, Wavelet};
use wtmm::stats::correlation::{CorrelationConfig, CorrelationPlan, cwt_correlation};
use wtmm::synth::fbm::{FbmParams, fbm};
use wtmm::theory::Model;

fn main() {
    let n = 1024;
    let reps = 7;
    let floor = FftFloor::new(n, n);
    let pool = one_thread_pool();
    println!(
        "correlate bench: {n}x{n}, scales 1.5/3/6 px, pairs (3,3) (1.5,3) (1.5,6) (3,6), 1 thread"
    );
    let cascade = Model::preset("paper-lognormal")
        .unwrap()
        .model
        .synthesize(n, 1, 0)
        .unwrap();
    let brownian = fbm(FbmParams { hurst: 1.0 / 3.0 }, n, n, 1, 0).unwrap();
    for (name, img, periodic) in [
        ("torus (W-cascade)", cascade, true),
        ("interior (fBm)", brownian, false),
    ] {
        let cfg = CorrelationConfig {
            wavelet: Wavelet::Gauss,
            scales: vec![1.5, 3.0, 6.0],
            pairs: vec![(1, 1), (0, 1), (0, 2), (1, 2)],
            periodic,
            ..Default::default()
        };
        let plan = CorrelationPlan::new(n, n, &cfg).unwrap();
        let field = Field::new(img);
        let cwt = CwtPlan::new(n, n, Wavelet::Gauss, &[1.5]).unwrap();
        let fi = cwt.forward(field.filled().unwrap().view()).unwrap();
        let mut ws = cwt.workspace();
        let (tc, ts, r_scale) = pool.install(|| {
            paired(
                reps,
                || {
                    std::hint::black_box(cwt_correlation(&field, &plan, "b").unwrap());
                },
                || {
                    std::hint::black_box(cwt.scale(&fi, 0, &mut ws));
                },
            )
        });
        let (_, tf, r_fft) = pool.install(|| {
            paired(
                reps,
                || {
                    std::hint::black_box(cwt_correlation(&field, &plan, "b").unwrap());
                },
                floor.runner(),
            )
        });
        let (fy, fx) = plan.fft_shape();
        println!(
            "{name:>18}: correlation {:6.1} ms | one CWT scale {:5.1} ms -> {r_scale:.2} scales | one 2D FFT {:5.1} ms -> {r_fft:.2} FFTs (correlation FFTs {fy}x{fx})",
            1e3 * tc,
            1e3 * ts,
            1e3 * tf
        );
    }
}
