//! CWT of a 1024x1024 image at 50 scales (5 octaves x 10 voices) against the
//! floor of 50 bare inverse 2D complex FFTs, single thread and all threads.
//! Run: `cargo bench --bench cwt`. Target (issue 2): ratio <= 1.25 single-threaded.

mod common;

use common::{FftFloor, median_secs, one_thread_pool, paired};
use wtmm::cwt::{CwtPlan, ScaleGrid, Wavelet};
use wtmm::synth::fbm::{FbmParams, fbm};

fn main() {
    let n = 1024;
    let img = fbm(FbmParams { hurst: 1.0 / 3.0 }, n, n, 1, 0).unwrap();
    let scales = ScaleGrid::default().scales();
    let ns = scales.len();
    let floor = FftFloor::new(n, n);
    let reps = 5;
    println!(
        "CWT bench: {n}x{n}, {ns} scales, f64, threads available: {}",
        rayon::current_num_threads()
    );
    for wavelet in [Wavelet::Gauss, Wavelet::Mexican] {
        let plan = CwtPlan::new(n, n, wavelet, &scales).unwrap();
        let pool = one_thread_pool();
        // interleaved pairs, as the other benches: separate medians moved
        // the ratio by 0.93-1.10 from one run to the next
        let (t_cwt1, t_fft1, ratio1) = pool.install(|| {
            paired(
                7,
                || {
                    plan.for_each_scale(img.view(), |_, _, t| {
                        std::hint::black_box(t);
                    })
                    .unwrap()
                },
                floor.serial_runner(ns),
            )
        });
        let t_cwtn = median_secs(reps, || {
            plan.par_map_scales(img.view(), |_, _, t| std::hint::black_box(t[[0, 0]]))
                .unwrap();
        });
        let t_fftn = median_secs(reps, floor.parallel_runner(ns));
        println!(
            "{wavelet:>8} 1 thread : CWT {:7.1} ms | FFT floor {:7.1} ms | median ratio of 7 interleaved pairs {:.3}",
            1e3 * t_cwt1,
            1e3 * t_fft1,
            ratio1
        );
        println!(
            "{wavelet:>8} {} threads: CWT {:7.1} ms | FFT floor {:7.1} ms | ratio {:.3}",
            rayon::current_num_threads(),
            1e3 * t_cwtn,
            1e3 * t_fftn,
            t_cwtn / t_fftn
        );
    }
}
