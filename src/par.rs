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
    in_order(out)
}

/// The results of indices `0..n` (`None`: skipped), in order, or the
/// lowest failing index's error: an index is skipped only above a failure,
/// whose error comes first in this ordered pass and ends it.
fn in_order<R>(
    results: impl IntoIterator<Item = Option<Result<R>>>,
) -> std::result::Result<Vec<R>, (usize, Error)> {
    let mut v = Vec::new();
    for (i, r) in results.into_iter().enumerate() {
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
#[cfg_attr(not(feature = "cli"), allow(dead_code))] // used by the CLI only
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

/// [`try_map_at_limited`] without the failing index, as [`try_map`].
#[cfg_attr(not(feature = "cli"), allow(dead_code))] // used by the CLI only
pub(crate) fn try_map_limited<R, F>(n: usize, limit: Option<usize>, f: F) -> Result<Vec<R>>
where
    R: Send,
    F: Fn(usize) -> Result<R> + Sync + Send,
{
    try_map_at_limited(n, limit, f).map_err(|(_, e)| e)
}

/// [`try_map_at`] with at most `limit` items in flight (`None`, or a
/// limit of `n` or more: [`try_map_at`] itself). The items run on `limit`
/// threads of their own, their nested rayon work on rayon's pool: inside a
/// rayon pool of `limit` threads a worker waiting in a nested join steals
/// other tasks, another item among them, so a pool of 4 held up to 5
/// images and one of 8 up to 10 (tm, counted by the review of 2026-11-29).
/// Failures as [`try_map_at`]: the lowest failing index, items above a
/// known failure skipped.
#[cfg_attr(not(feature = "cli"), allow(dead_code))] // used by the CLI only
pub(crate) fn try_map_at_limited<R, F>(
    n: usize,
    limit: Option<usize>,
    f: F,
) -> std::result::Result<Vec<R>, (usize, Error)>
where
    R: Send,
    F: Fn(usize) -> Result<R> + Sync + Send,
{
    let Some(workers) = limit.filter(|&w| w < n) else {
        return try_map_at(n, f);
    };
    let (next, first) = (AtomicUsize::new(0), AtomicUsize::new(usize::MAX));
    let slots: Vec<std::sync::Mutex<Option<Result<R>>>> =
        (0..n).map(|_| std::sync::Mutex::new(None)).collect();
    std::thread::scope(|scope| {
        for _ in 0..workers.max(1) {
            scope.spawn(|| {
                loop {
                    // indices are taken in increasing order: one above a
                    // known failure is skipped, and so are all after it
                    let i = next.fetch_add(1, Ordering::Relaxed);
                    if i >= n || i > first.load(Ordering::Relaxed) {
                        break;
                    }
                    let r = f(i);
                    if r.is_err() {
                        first.fetch_min(i, Ordering::Relaxed);
                    }
                    *slots[i].lock().unwrap_or_else(|e| e.into_inner()) = Some(r);
                }
            });
        }
    });
    in_order(
        slots
            .into_iter()
            .map(|slot| slot.into_inner().unwrap_or_else(|e| e.into_inner())),
    )
}

/// [`try_fold`] with at most `limit` items in flight, on `limit` threads
/// of their own as [`try_map_at_limited`]: each folds the indices it takes
/// (in increasing order) into its own accumulator, and the accumulators
/// are merged in thread order (as [`try_fold`]'s runs, whose bounds
/// depend on the scheduling: `merge` must not depend on them).
#[cfg_attr(not(feature = "cli"), allow(dead_code))] // used by the CLI only
pub(crate) fn try_fold_limited<A, I, S, M>(
    n: usize,
    limit: Option<usize>,
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
    let Some(workers) = limit.filter(|&w| w < n) else {
        return try_fold(n, init, step, merge);
    };
    let (next, first) = (AtomicUsize::new(0), AtomicUsize::new(usize::MAX));
    let runs: Vec<(A, Option<(usize, Error)>)> = std::thread::scope(|scope| {
        let handles: Vec<_> = (0..workers.max(1))
            .map(|_| {
                scope.spawn(|| {
                    let mut acc = init();
                    loop {
                        let i = next.fetch_add(1, Ordering::Relaxed);
                        if i >= n || i > first.load(Ordering::Relaxed) {
                            return (acc, None);
                        }
                        if let Err(e) = step(&mut acc, i) {
                            first.fetch_min(i, Ordering::Relaxed);
                            return (acc, Some((i, e)));
                        }
                    }
                })
            })
            .collect();
        handles
            .into_iter()
            .map(|h| h.join().unwrap_or_else(|p| std::panic::resume_unwind(p)))
            .collect()
    });
    // an input's failure before a failed merge (a defect), as try_fold
    let (accs, failures): (Vec<A>, Vec<Option<(usize, Error)>>) = runs.into_iter().unzip();
    if let Some(f) = failures.into_iter().flatten().min_by_key(|(i, _)| *i) {
        return Err(f);
    }
    let mut accs = accs.into_iter();
    let first_acc = accs.next().unwrap_or_else(&init);
    accs.try_fold(first_acc, merge).map_err(|e| (usize::MAX, e))
}

/// `parts` merged in order with `merge`, `None` for none: the `merge_all`
/// of each kind of mergeable sums.
pub(crate) fn merge_in_order<T>(
    parts: impl IntoIterator<Item = T>,
    merge: impl Fn(&mut T, &T) -> Result<()>,
) -> Result<Option<T>> {
    let mut it = parts.into_iter();
    let Some(mut acc) = it.next() else {
        return Ok(None);
    };
    for p in it {
        merge(&mut acc, &p)?;
    }
    Ok(Some(acc))
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

    /// The limited map and fold name the lowest failing index and keep the
    /// order, as the others; and they never hold more than `limit` items,
    /// even when every item waits in a nested join (inside a rayon pool of
    /// `limit` threads a waiting worker steals another item).
    #[test]
    fn limited_passes_bound_the_items_in_flight() {
        use std::sync::atomic::AtomicUsize;
        // (rayon pools of 4 and 8 overshot, by one and two items)
        for limit in [1, 2, 3, 4, 8] {
            let e = try_map_at_limited(40, Some(limit), slow_three).unwrap_err();
            assert_eq!(e.0, 3);
            let f = |acc: &mut usize, i: usize| {
                *acc += slow_three(i)?;
                Ok(())
            };
            let e = try_fold_limited(40, Some(limit), || 0usize, f, |a, b| Ok(a + b));
            assert_eq!(e.unwrap_err().0, 3);
            let v = try_map_at_limited(50, Some(limit), |i| Ok(i * 2)).unwrap();
            assert_eq!(v, (0..50).map(|i| i * 2).collect::<Vec<_>>());
            let add = |a: &mut usize, i: usize| {
                *a += i;
                Ok(())
            };
            let s = try_fold_limited(100, Some(limit), || 0usize, add, |a, b| Ok(a + b));
            assert_eq!(s.unwrap(), 4950);
            let (now, most) = (AtomicUsize::new(0), AtomicUsize::new(0));
            let item = |i: usize| -> Result<usize> {
                let k = now.fetch_add(1, Ordering::SeqCst) + 1;
                most.fetch_max(k, Ordering::SeqCst);
                // nested work that waits: the pattern that let a pooled
                // worker start a second item
                rayon::join(
                    || std::thread::sleep(Duration::from_millis(2)),
                    || std::thread::sleep(Duration::from_millis(3)),
                );
                now.fetch_sub(1, Ordering::SeqCst);
                Ok(i)
            };
            pool(8).install(|| try_map_at_limited(24, Some(limit), item).unwrap());
            assert!(most.load(Ordering::SeqCst) <= limit, "limit {limit}");
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
