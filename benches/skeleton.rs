//! Full skeleton pipeline (CWT + maxima + chains + WTMMM + linking) on a
//! 1024x1024 fBm image, 50 scales, against the floor of 50 bare inverse 2D
//! complex FFTs measured in the same run. Run: `cargo bench --bench skeleton`.
//! Target (issue 3): <= 1.6x the floor single-threaded. "CWT" is the full
//! transform per scale (`for_each_scale`); the skeleton streams it in row
//! blocks (`scale_rows`), also timed, and never stores it whole.

mod common;

use common::{FftFloor, median_secs, one_thread_pool, paired};
use wtmm::Field;
use wtmm::cwt::CwtPlan;
use wtmm::skeleton::{AnalysisConfig, Parallelism, skeleton_with};
use wtmm::synth::fbm::{FbmParams, fbm};

fn main() {
    let n = 1024;
    let field = Field::new(fbm(FbmParams { hurst: 1.0 / 3.0 }, n, n, 1, 0).unwrap());
    let cfg = AnalysisConfig::default();
    let ns = cfg.scale_list().len();
    let floor = FftFloor::new(n, n);
    let plan = CwtPlan::new(n, n, cfg.wavelet, &cfg.scale_list()).unwrap();
    let reps = 3;
    println!(
        "skeleton bench: {n}x{n}, {ns} scales, gauss, margin {} px",
        cfg.margin_px()
    );
    let pool = one_thread_pool();
    let (t_cwt, t_rows, t_sk, t_fft, ratio, lines) = pool.install(|| {
        let c = median_secs(reps, || {
            plan.for_each_scale(field.data.view(), |_, _, t| {
                std::hint::black_box(t);
            })
            .unwrap()
        });
        // the same transform streamed in row blocks, as the skeleton uses it
        let r = median_secs(reps, || {
            let fi = plan.forward(field.data.view()).unwrap();
            let mut ws = plan.workspace();
            for j in 0..ns {
                plan.scale_rows(&fi, j, &mut ws, 0..n, |_, _, t| {
                    std::hint::black_box(t);
                });
            }
        });
        let mut lines = 0;
        let (s, f, ratio) = paired(
            7,
            || {
                lines = skeleton_with(&field, &cfg, Parallelism::Serial, &[])
                    .unwrap()
                    .lines
                    .len();
            },
            floor.serial_runner(ns),
        );
        (c, r, s, f, ratio, lines)
    });
    let t_skn = median_secs(reps, || {
        std::hint::black_box(skeleton_with(&field, &cfg, Parallelism::Scales, &[]).unwrap());
    });
    let t_fftn = median_secs(reps, floor.parallel_runner(ns));
    println!("lines born at a_min: {lines}");
    println!(
        "1 thread : FFT floor {:7.1} ms | CWT {:7.1} ms ({:.3}x), in row blocks {:7.1} ms ({:.3}x) | skeleton {:7.1} ms (median ratio of 7 interleaved pairs {:.3}x)",
        1e3 * t_fft,
        1e3 * t_cwt,
        t_cwt / t_fft,
        1e3 * t_rows,
        t_rows / t_fft,
        1e3 * t_sk,
        ratio
    );
    println!(
        "{} threads: FFT floor {:7.1} ms | skeleton {:7.1} ms ({:.3}x)",
        rayon::current_num_threads(),
        1e3 * t_fftn,
        1e3 * t_skn,
        t_skn / t_fftn
    );
}
