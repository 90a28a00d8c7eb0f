//! Tiny bench harness: median wall time of repeated runs, and the FFT floor
//! (bare inverse 2D complex FFTs of the image size) measured in the same run,
//! so that ratios stay meaningful on a shared machine.
#![allow(dead_code)]

use std::sync::Arc;
use std::time::Instant;

use num_complex::Complex64;
use rayon::prelude::*;
use rustfft::{Fft, FftPlanner};

/// Median seconds of `reps` runs of `f` (after one warm-up run).
pub fn median_secs<F: FnMut()>(reps: usize, mut f: F) -> f64 {
    f();
    let mut t: Vec<f64> = (0..reps)
        .map(|_| {
            let s = Instant::now();
            f();
            s.elapsed().as_secs_f64()
        })
        .collect();
    t.sort_by(|a, b| a.partial_cmp(b).unwrap());
    t[t.len() / 2]
}

/// Interleaved runs of `a` and `b` (`reps` pairs after one warm-up pair):
/// the median times of each and the median of the per-pair ratios `a/b`.
/// On a shared machine whose load drifts, pairing cancels most of the drift
/// that separate medians would put into the ratio.
pub fn paired<A: FnMut(), B: FnMut()>(reps: usize, mut a: A, mut b: B) -> (f64, f64, f64) {
    a();
    b();
    let mut ta = Vec::with_capacity(reps);
    let mut tb = Vec::with_capacity(reps);
    let mut r = Vec::with_capacity(reps);
    for _ in 0..reps {
        let s = Instant::now();
        a();
        let x = s.elapsed().as_secs_f64();
        let s = Instant::now();
        b();
        let y = s.elapsed().as_secs_f64();
        ta.push(x);
        tb.push(y);
        r.push(x / y);
    }
    let med = |v: &mut Vec<f64>| {
        v.sort_by(|p, q| p.partial_cmp(q).unwrap());
        v[v.len() / 2]
    };
    (med(&mut ta), med(&mut tb), med(&mut r))
}

/// `count` bare inverse 2D complex FFTs of `ny x nx`: batch FFTs along one
/// axis, a blocked transpose, batch FFTs along the other. The cheapest 2D
/// FFT rustfft allows; the CWT cannot do less per scale.
pub struct FftFloor {
    ny: usize,
    nx: usize,
    fy: Arc<dyn Fft<f64>>,
    fx: Arc<dyn Fft<f64>>,
}

impl FftFloor {
    pub fn new(ny: usize, nx: usize) -> Self {
        let mut p = FftPlanner::new();
        FftFloor {
            ny,
            nx,
            fy: p.plan_fft_inverse(ny),
            fx: p.plan_fft_inverse(nx),
        }
    }

    fn one(&self, a: &mut [Complex64], b: &mut [Complex64], scratch: &mut [Complex64]) {
        self.fy.process_with_scratch(a, scratch);
        transpose::transpose(a, b, self.ny, self.nx);
        self.fx.process_with_scratch(b, scratch);
    }

    fn buffers(&self) -> (Vec<Complex64>, Vec<Complex64>, Vec<Complex64>) {
        let n = self.nx * self.ny;
        let s = self
            .fy
            .get_inplace_scratch_len()
            .max(self.fx.get_inplace_scratch_len());
        let a = (0..n)
            .map(|i| Complex64::new((i % 7) as f64, (i % 5) as f64))
            .collect();
        (
            a,
            vec![Complex64::default(); n],
            vec![Complex64::default(); s],
        )
    }

    /// One transform per call on buffers allocated once (a fresh 16 MB
    /// buffer per call would time the page faults too).
    pub fn runner(&self) -> impl FnMut() + '_ {
        let (mut a, mut b, mut s) = self.buffers();
        move || {
            self.one(&mut a, &mut b, &mut s);
            std::hint::black_box(&b);
        }
    }

    /// `count` transforms on the calling thread per call, on buffers
    /// allocated once here: allocating and first touching 32 MB inside the
    /// timed call added 18-21 ms (4-5 %) to a 50-FFT floor.
    pub fn serial_runner(&self, count: usize) -> impl FnMut() + '_ {
        let (mut a, mut b, mut s) = self.buffers();
        move || {
            for _ in 0..count {
                self.one(&mut a, &mut b, &mut s);
            }
            std::hint::black_box(&b);
        }
    }

    /// `count` transforms spread over the rayon pool per call, each thread
    /// on its own buffers, allocated once here (call it inside the pool the
    /// runner is used in).
    pub fn parallel_runner(&self, count: usize) -> impl FnMut() + '_ {
        let threads = rayon::current_num_threads();
        let bufs: Vec<std::sync::Mutex<_>> = (0..threads)
            .map(|_| std::sync::Mutex::new(self.buffers()))
            .collect();
        move || {
            (0..count).into_par_iter().for_each(|_| {
                let i = rayon::current_thread_index().unwrap_or(0) % threads;
                let mut g = bufs[i].lock().unwrap();
                let (a, b, s) = &mut *g;
                self.one(a, b, s);
                std::hint::black_box(&b);
            });
        }
    }
}

pub fn one_thread_pool() -> rayon::ThreadPool {
    rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap()
}
