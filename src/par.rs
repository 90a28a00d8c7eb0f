//! Parallel maps and folds over an ensemble whose failure does not depend
//! on the scheduling.
//!
//! rayon's `collect::<Result<_>>` and `try_fold` return whichever error
//! came first in time, so with two bad images in an ensemble the message
//! named one or the other depending on the thread count and the load. Here
//! the error is always that of the lowest failing index, as a serial loop
//! would give. Indices above a known failure are skipped (their work is
//! wasted); those below it still run, since one of them may fail too.

use std::sync::atomic::{AtomicUsize, Ordering};

use rayon::prelude::*;

use crate::error::{Error, Result};

/// `f(0), ..., f(n - 1)` in parallel, in order; on failure the error of
/// the lowest failing index.
pub(crate) fn try_map<R, F>(n: usize, f: F) -> Result<Vec<R>>
where
    R: Send,
    F: Fn(usize) -> Result<R> + Sync + Send,
{
    try_map_at(n, f).map_err(|(_, e)| e)
}

/// [`try_map`] with the failing index beside its error (what was noted
/// about later items depends on the scheduling: a caller drops it).
pub(crate) fn try_map_at<R, F>(n: usize, f: F) -> std::result::Result<Vec<R>, (usize, Error)>
where
    R: Send,
    F: Fn(usize) -> Result<R> + Sync + Send,
{
    let first = AtomicUsize::new(usize::MAX);
    let out: Vec<Option<Result<R>>> = (0..n)
        .into_par_iter()
        .map(|i| {
            // a stale read only skips less
            if i > first.load(Ordering::Relaxed) {
                return None;
            }
            let r = f(i);
            if r.is_err() {
                first.fetch_min(i, Ordering::Relaxed);
            }
            Some(r)
        })
        .collect();
    // an index is skipped only above a failure, whose error comes first in
    // this ordered pass and ends it
    let mut v = Vec::with_capacity(n);
    for (i, r) in out.into_iter().enumerate() {
        match r.expect("a skipped index follows a failure") {
            Ok(x) => v.push(x),
            Err(e) => return Err((i, e)),
        }
    }
    Ok(v)
}

/// Folds `0..n` in parallel into accumulators (`init`, then `step` on each
/// index of a contiguous run, in order) merged with `merge`; on failure the
/// error of the lowest failing index (a failed `merge`, a defect rather
/// than an input's fault, counts after every index).
pub(crate) fn try_fold<A, I, S, M>(
    n: usize,
    init: I,
    step: S,
    merge: M,
) -> std::result::Result<A, (usize, Error)>
where
    A: Send,
    I: Fn() -> A + Sync + Send,
    S: Fn(&mut A, usize) -> Result<()> + Sync + Send,
    M: Fn(A, A) -> Result<A> + Sync + Send,
{
    type Failed = Option<(usize, Error)>;
    let first = AtomicUsize::new(usize::MAX);
    let lower = |x: Failed, y: Failed| -> Failed {
        match (x, y) {
            (Some(a), Some(b)) => Some(if b.0 < a.0 { b } else { a }),
            (a, b) => a.or(b),
        }
    };
    let (acc, failed) = (0..n)
        .into_par_iter()
        .fold(
            || (init(), None::<(usize, Error)>),
            |(mut acc, failed), i| {
                // a run is folded in index order: past its own failure, or
                // past a lower one elsewhere, nothing is worth doing
                if failed.is_some() || i > first.load(Ordering::Relaxed) {
                    return (acc, failed);
                }
                match step(&mut acc, i) {
                    Ok(()) => (acc, None),
                    Err(e) => {
                        first.fetch_min(i, Ordering::Relaxed);
                        (acc, Some((i, e)))
                    }
                }
            },
        )
        .reduce(
            || (init(), None),
            |(a, fa), (b, fb)| {
                if fa.is_some() || fb.is_some() {
                    return (a, lower(fa, fb));
                }
                match merge(a, b) {
                    Ok(m) => (m, None),
                    Err(e) => (init(), Some((usize::MAX, e))),
                }
            },
        );
    match failed {
        Some(f) => Err(f),
        None => Ok(acc),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    fn pool(threads: usize) -> rayon::ThreadPool {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
    }

    /// Index 3 fails late, index 33 at once: rayon's own short-circuit
    /// returns 33's error whenever 33 runs before 3 ends; these always 3's.
    fn slow_three(i: usize) -> Result<usize> {
        match i {
            3 => {
                std::thread::sleep(Duration::from_millis(20));
                Err(Error::Input("image 3".into()))
            }
            33 => Err(Error::Input("image 33".into())),
            _ => Ok(i * i),
        }
    }

    #[test]
    fn the_lowest_failing_index_is_named_whatever_the_threads() {
        for threads in [1, 2, 3, 4, 8] {
            pool(threads).install(|| {
                let e = try_map(40, slow_three).unwrap_err();
                assert_eq!(e.to_string(), Error::Input("image 3".into()).to_string());
                assert_eq!(try_map_at(40, slow_three).unwrap_err().0, 3);
                let e = try_fold(
                    40,
                    || 0usize,
                    |acc, i| {
                        *acc += slow_three(i)?;
                        Ok(())
                    },
                    |a, b| Ok(a + b),
                )
                .unwrap_err();
                assert_eq!(e.0, 3);
                assert_eq!(e.1.to_string(), Error::Input("image 3".into()).to_string());
            });
        }
    }

    #[test]
    fn without_failure_every_result_comes_in_order() {
        for threads in [1, 3] {
            pool(threads).install(|| {
                let v = try_map(100, |i| Ok(i * 2)).unwrap();
                assert_eq!(v, (0..100).map(|i| i * 2).collect::<Vec<_>>());
                let add = |a: &mut usize, i: usize| {
                    *a += i;
                    Ok(())
                };
                let s = try_fold(100, || 0usize, add, |a, b| Ok(a + b)).unwrap();
                assert_eq!(s, 4950);
                assert!(try_map(0, Ok).unwrap().is_empty());
            });
        }
    }

    #[test]
    fn a_failed_merge_is_an_error() {
        // 4 threads split 0..64 into at least 4 runs, whose merges fail
        pool(4).install(|| {
            let e = try_fold(
                64,
                || 1usize,
                |_, _| Ok(()),
                |_, _| Err(Error::Input("merge".into())),
            );
            let e = e.unwrap_err();
            assert_eq!(e.0, usize::MAX);
            assert_eq!(e.1.to_string(), Error::Input("merge".into()).to_string());
        });
    }
}
