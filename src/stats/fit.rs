//! Ordinary least squares of `y` on `x`, with the standard error of the slope:
//! the regression behind every exponent (SPEC §4, §7, §8).

use serde::{Deserialize, Serialize};

/// Result of a straight-line fit `y = intercept + slope x`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct LineFit {
    /// Least-squares slope (the exponent, in the units of `y` per unit of `x`).
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub slope: f64,
    /// Value of the fitted line at `x = 0`.
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub intercept: f64,
    /// Standard error of the slope from the residuals (NaN with < 3 points).
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub slope_stderr: f64,
    /// Coefficient of determination (1 for a perfect line; NaN if y is constant).
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub r2: f64,
    /// Number of points used.
    pub n: usize,
}

/// For each `t`, `items` combined without `items[t]` (`add` associative,
/// `zero` its identity), from running sums from both ends: O(n) combines
/// instead of the O(n^2) of refolding each (the 8281 tiles of a 4096^2 lone image: the kernel's tiles, the
/// spectra's cells).
pub(crate) fn leave_one_out<T: Clone>(items: &[&T], zero: T, add: impl Fn(&T, &T) -> T) -> Vec<T> {
    let mut before = Vec::with_capacity(items.len());
    let mut acc = zero.clone();
    for it in items {
        before.push(acc.clone());
        acc = add(&acc, it);
    }
    let mut out = before;
    let mut after = zero;
    for t in (0..items.len()).rev() {
        out[t] = add(&out[t], &after);
        after = add(items[t], &after);
    }
    out
}

/// Delete-one jackknife standard error from the leave-one-out replicates
/// `v` of an estimate: `sqrt((n-1)/n Σ (v_i - mean)²)`. NaN when a
/// replicate is not finite or there is none (callers set their own minimum
/// number of parts).
pub fn jackknife_se(v: &[f64]) -> f64 {
    if v.is_empty() || v.iter().any(|x| !x.is_finite()) {
        return f64::NAN;
    }
    // summed in sorted order: the same bits whatever the order of the parts
    // (a merge of ensembles in either order)
    let mut v = v.to_vec();
    v.sort_unstable_by(f64::total_cmp);
    let n = v.len() as f64;
    let m = v.iter().sum::<f64>() / n;
    ((n - 1.0) / n * v.iter().map(|x| (x - m) * (x - m)).sum::<f64>()).sqrt()
}

/// Delete-one jackknife standard errors of many estimates at once, from
/// replicates streamed one at a time, so that the per-scale values of
/// thousands of tiles need not be kept (what [`jackknife_se`] does for one
/// estimate from all its replicates).
///
/// Each replicate's deviation from the full-sample estimate is rounded to
/// a multiple of 2^-40 and summed in integers: the errors are the same bits
/// in whatever order the replicates come (the images of a merge in either
/// order), which floating sums would not be, and the rounding (1e-12 on
/// each deviation) lies far below any error it measures. Written by hand:
/// no crate streams an order-independent jackknife.
#[derive(Clone, Debug)]
pub(crate) struct JackknifeStream {
    full: Vec<f64>,
    n: i128,
    s1: Vec<i128>,
    s2: Vec<i128>,
    /// A replicate was not finite there, or its deviation did not fit.
    bad: Vec<bool>,
}

/// The unit of [`JackknifeStream`]'s integer deviations: 2^40.
const JK_UNIT: f64 = 1_099_511_627_776.0;
/// Deviations of at least this (2^12) are not summed: the estimate's error
/// is NaN there (a log2 moving by thousands between replicates is no
/// estimate), and the sums stay far from overflow.
const JK_MAX_DEV: f64 = 4096.0;

impl JackknifeStream {
    /// Errors of the estimates `full` (the whole sample's values); a
    /// non-finite one has a NaN error.
    pub(crate) fn new(full: Vec<f64>) -> Self {
        let m = full.len();
        JackknifeStream {
            bad: full.iter().map(|v| !v.is_finite()).collect(),
            full,
            n: 0,
            s1: vec![0; m],
            s2: vec![0; m],
        }
    }

    /// One leave-one-out replicate of every estimate.
    ///
    /// **Panics** if `rep` and the estimates differ in length.
    pub(crate) fn add(&mut self, rep: &[f64]) {
        assert_eq!(rep.len(), self.full.len(), "jackknife: replicate length");
        self.n += 1;
        for (k, &r) in rep.iter().enumerate() {
            if self.bad[k] {
                continue;
            }
            let d = r - self.full[k];
            if !(d.abs() < JK_MAX_DEV) {
                self.bad[k] = true;
                continue;
            }
            // |di| < 2^52 and di^2 < 2^104: 2^23 replicates before overflow
            let di = (d * JK_UNIT).round() as i128;
            match (self.s1[k].checked_add(di), self.s2[k].checked_add(di * di)) {
                (Some(a), Some(b)) => (self.s1[k], self.s2[k]) = (a, b),
                _ => self.bad[k] = true,
            }
        }
    }

    /// `sqrt((n-1)/n Σ (v_i - mean)²)` of each estimate over the `n`
    /// replicates added; NaN where one was not finite, or with fewer than 2.
    pub(crate) fn stderr(&self) -> Vec<f64> {
        let n = self.n;
        (0..self.full.len())
            .map(|k| {
                if self.bad[k] || n < 2 {
                    return f64::NAN;
                }
                // Σ (d - mean)² = s2 - s1²/n, exactly: s1 = m n + r with
                // 0 <= r < n gives s2 - m² n - 2 m r - r²/n, whose integer
                // part cannot overflow where s1² could
                let (m, r) = (self.s1[k].div_euclid(n), self.s1[k].rem_euclid(n));
                let t = self.s2[k] - m * m * n - 2 * m * r;
                let ss = (t as f64 - (r * r) as f64 / n as f64).max(0.0);
                let nf = n as f64;
                ((nf - 1.0) / nf * ss).sqrt() / JK_UNIT
            })
            .collect()
    }
}

/// Below this many images a jackknife error is said to be rough: the
/// standard deviation of n values is itself uncertain by about
/// `1/sqrt(2(n-1))` (normal data), 24 % at 10 images, 41 % at 4.
pub const FEW_IMAGES: usize = 10;

/// The warning for a jackknife over `n` groups (images, tiles) with
/// `2 <= n <` [`FEW_IMAGES`]: its errors are themselves uncertain by about
/// `1/sqrt(2(n-1))`; `how` names the jackknife ("a jackknife over 4
/// images"). `None` otherwise.
pub fn few_groups_warning(n: usize, how: &str) -> Option<String> {
    (2..FEW_IMAGES).contains(&n).then(|| {
        format!(
            "the standard errors come from {how} ({} degree{} of freedom) and are themselves \
             uncertain by about {:.0} %",
            n - 1,
            if n == 2 { "" } else { "s" },
            100.0 / (2.0 * (n - 1) as f64).sqrt()
        )
    })
}

/// The `stderr_method` label of an ensemble estimate: "regression" with
/// fewer than 3 images, else "jackknife over images", naming the entries
/// in `fallback` (e.g. `q = 0, 1`, or `c2`) that kept the regression error
/// because a leave-one-out estimate was not finite; that case also adds a
/// warning, so the substitution is never silent. Regression errors, and
/// jackknife errors over fewer than [`FEW_IMAGES`] images, are flagged
/// too: neither is an error bar to put in a paper as it stands.
pub fn stderr_method(n_img: usize, fallback: &[String], warnings: &mut Vec<String>) -> String {
    stderr_method_why(n_img, fallback, warnings, "")
}

/// Why fewer than 3 images (`n_img`, `with_tiles` of them split into
/// tiles) got no tile jackknife, for [`stderr_method_why`]; empty from 3
/// images on. One text for the spectra and the kernel.
pub fn no_tiles_why(n_img: usize, with_tiles: usize) -> &'static str {
    if n_img >= 3 {
        ""
    } else if with_tiles == 0 {
        ", and the counting domain was not split into jackknife tiles: it holds fewer than 2 \
         tiles of twice the largest scale (fewer --octaves or a smaller --margin leave room), \
         or the sums were made without them"
    } else if with_tiles < n_img {
        ", and only some of the images were split into jackknife tiles"
    } else {
        ", and there are fewer than 3 jackknife tiles"
    }
}

/// [`stderr_method`], `why` (e.g. "; the images were not split into
/// tiles: ...") appended to the warning of fewer than 3 images.
pub fn stderr_method_why(
    n_img: usize,
    fallback: &[String],
    warnings: &mut Vec<String>,
    why: &str,
) -> String {
    if n_img < 3 {
        // The fitted scales of one image see the same structures, so the
        // residuals are correlated and the regression error only measures
        // curvature: on single fBm images of 512^2 (H = 1/2, 24 images)
        // it was 4-7 times below the scatter of tau(q) between images.
        warnings.push(format!(
            "the standard errors are the regression's ({n_img} image{}; a jackknife needs 3 or \
             more{why}): the fitted scales are not independent, so they understate the \
             uncertainty several times over",
            if n_img == 1 { "" } else { "s" }
        ));
        return "regression".into();
    }
    if let Some(w) = few_groups_warning(n_img, &format!("a jackknife over {n_img} images")) {
        warnings.push(w);
    }
    if fallback.is_empty() {
        return "jackknife over images".into();
    }
    let list = fallback.join(", ");
    warnings.push(format!(
        "{list}: a leave-one-image-out estimate is not finite, so the standard error is the \
         regression's"
    ));
    format!("jackknife over images; regression for {list}")
}

/// The `stderr_method` label of the estimates of fewer than 3 images whose
/// jackknife ran over `n_tiles` tiles of side about `side` px of their
/// domains (`PartitionSums::spectra`), with the warning that such errors
/// treat neighbouring tiles as independent, as the trace moments' tiles do.
pub fn stderr_method_tiles(
    n_img: usize,
    n_tiles: usize,
    side: &str,
    fallback: &[String],
    warnings: &mut Vec<String>,
) -> String {
    let what = format!(
        "a jackknife over {n_tiles} tiles of about {side} px of {n_img} image{}",
        if n_img == 1 { "" } else { "s" }
    );
    warnings.push(format!(
        "the standard errors come from {what}: a tile's maxima are counted where they lie at \
         each scale, and tiles are treated as independent, which fields correlated over long \
         distances (cascades) are not, so they may still understate"
    ));
    if let Some(w) = few_groups_warning(n_tiles, &what) {
        warnings.push(w);
    }
    let label = format!("jackknife over {n_tiles} tiles ({side} px)");
    if fallback.is_empty() {
        return label;
    }
    let list = fallback.join(", ");
    warnings.push(format!(
        "{list}: a leave-one-tile-out estimate is not finite, so the standard error is the \
         regression's"
    ));
    format!("{label}; regression for {list}")
}

/// The points `(x, y)` where both are finite.
///
/// **Panics** (naming `who`) if `x` and `y` differ in length.
fn finite_pairs(x: &[f64], y: &[f64], who: &str) -> Vec<(f64, f64)> {
    assert_eq!(x.len(), y.len(), "{who}: x and y lengths differ");
    x.iter()
        .zip(y)
        .filter(|(a, b)| a.is_finite() && b.is_finite())
        .map(|(a, b)| (*a, *b))
        .collect()
}

/// Least-squares fit over the points where both `x` and `y` are finite.
/// Returns `None` with fewer than 2 usable points or when all `x` coincide.
///
/// **Panics** if `x` and `y` differ in length.
pub fn line_fit(x: &[f64], y: &[f64]) -> Option<LineFit> {
    let pts = finite_pairs(x, y, "line_fit");
    let n = pts.len();
    if n < 2 {
        return None;
    }
    let nf = n as f64;
    let mx = pts.iter().map(|p| p.0).sum::<f64>() / nf;
    let my = pts.iter().map(|p| p.1).sum::<f64>() / nf;
    let (mut sxx, mut sxy, mut syy) = (0.0, 0.0, 0.0);
    for &(a, b) in &pts {
        sxx += (a - mx) * (a - mx);
        sxy += (a - mx) * (b - my);
        syy += (b - my) * (b - my);
    }
    if sxx <= 0.0 {
        return None;
    }
    let slope = sxy / sxx;
    let intercept = my - slope * mx;
    let sse = (syy - slope * sxy).max(0.0);
    let slope_stderr = if n > 2 {
        (sse / (nf - 2.0) / sxx).sqrt()
    } else {
        f64::NAN
    };
    let r2 = if syy > 0.0 { 1.0 - sse / syy } else { f64::NAN };
    Some(LineFit {
        slope,
        intercept,
        slope_stderr,
        r2,
        n,
    })
}

/// How much the local slope of `y(x)` changes across the range of `x`:
/// `2 c (x_max - x_min)` for the least-squares parabola `a + b x + c x^2`
/// through the finite points. A straight line gives 0; a fitted slope
/// stands for local slopes within about half this value either side.
/// Unlike R^2 it does not depend on the slope itself, so a flat power law
/// (tau(q) ~ 0) is not taken for a poor one. `None` with fewer than 3
/// usable points or fewer than 3 distinct `x`.
///
/// **Panics** if `x` and `y` differ in length.
pub fn slope_change(x: &[f64], y: &[f64]) -> Option<f64> {
    let pts = finite_pairs(x, y, "slope_change");
    if pts.len() < 3 {
        return None;
    }
    let nf = pts.len() as f64;
    let mx = pts.iter().map(|p| p.0).sum::<f64>() / nf;
    let my = pts.iter().map(|p| p.1).sum::<f64>() / nf;
    let mu = pts.iter().map(|p| (p.0 - mx).powi(2)).sum::<f64>() / nf;
    // Frisch-Waugh: c is the slope of y's residual (after the line in x) on
    // the residual of u = (x - mx)^2 (after the same line)
    let (mut sxx, mut sxu, mut sxy) = (0.0, 0.0, 0.0);
    for &(a, b) in &pts {
        let dx = a - mx;
        sxx += dx * dx;
        sxu += dx * (dx * dx - mu);
        sxy += dx * (b - my);
    }
    if sxx <= 0.0 {
        return None;
    }
    let (bu, by) = (sxu / sxx, sxy / sxx);
    let (mut suu, mut suy) = (0.0, 0.0);
    for &(a, b) in &pts {
        let dx = a - mx;
        let ru = dx * dx - mu - bu * dx;
        suu += ru * ru;
        suy += ru * (b - my - by * dx);
    }
    // two distinct x leave no curvature to fit (ru = 0 up to rounding)
    if suu <= 1e-12 * sxx * sxx / nf {
        return None;
    }
    let (lo, hi) = pts
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), p| {
            (l.min(p.0), h.max(p.0))
        });
    Some(2.0 * suy / suu * (hi - lo))
}

/// Mean and sample standard deviation (NaN for fewer than 2 values).
pub fn mean_std(v: &[f64]) -> (f64, f64) {
    let n = v.len() as f64;
    let m = v.iter().sum::<f64>() / n;
    if v.len() < 2 {
        return (m, f64::NAN);
    }
    let var = v.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / (n - 1.0);
    (m, var.sqrt())
}

/// Runs of neighbouring flagged (`Some`) entries of `v`: `(first, last,
/// index of the largest key)` each. The per-q diagnostics of the spectra
/// and the trace moments come in such runs (the tails of the q range):
/// one warning per run, not one per q.
pub fn flagged_runs<T: Copy>(
    v: &[Option<T>],
    key: impl Fn(T) -> f64,
) -> Vec<(usize, usize, usize)> {
    let mut out = Vec::new();
    let mut i = 0;
    while i < v.len() {
        let Some(first_v) = v[i] else {
            i += 1;
            continue;
        };
        let (first, mut worst, mut best) = (i, i, key(first_v));
        while let Some(Some(x)) = v.get(i + 1) {
            i += 1;
            let k = key(*x);
            if k > best {
                (worst, best) = (i, k);
            }
        }
        out.push((first, i, worst));
        i += 1;
    }
    out
}

#[cfg(test)]
mod tests {

    /// Runs of neighbouring flagged entries, each with its largest key.
    #[test]
    fn flagged_runs_find_each_run_and_its_worst() {
        let v = [
            None,
            Some(1.0),
            Some(-3.0),
            Some(2.0),
            None,
            Some(0.5),
            None,
            Some(f64::NAN),
        ];
        assert_eq!(
            flagged_runs(&v, f64::abs),
            vec![(1, 3, 2), (5, 5, 5), (7, 7, 7)]
        );
        assert!(flagged_runs::<f64>(&[None, None], f64::abs).is_empty());
    }
    use super::*;

    /// The streamed jackknife equals `jackknife_se` of the same replicates
    /// (to its 2^-40 rounding), in any order to the bit; a non-finite
    /// replicate or estimate, or a wild deviation, gives NaN there.
    #[test]
    fn streamed_jackknife_is_the_jackknife_in_any_order() {
        // replicates around three estimates of very different sizes, one
        // shifted far from its full-sample value (a sum left without a part)
        let full = vec![0.3, -250.0, 7.0, f64::NAN, 1.0, 2.0];
        let n = 37;
        let rep = |i: usize| -> Vec<f64> {
            let u = ((i * 7919 + 13) % 101) as f64 / 101.0 - 0.5;
            let w = ((i * 104_729 + 5) % 97) as f64 / 97.0 - 0.5;
            vec![
                0.3 + 1e-3 * u,
                -250.0 + 3.0 * w,
                7.0 - 1.44 / n as f64 + 1e-6 * u * w,
                1.0,
                if i == 5 { f64::NAN } else { 1.0 + u },
                if i == 9 { 2.0 + 5000.0 } else { 2.0 + w },
            ]
        };
        let mut fwd = JackknifeStream::new(full.clone());
        let mut back = JackknifeStream::new(full.clone());
        for i in 0..n {
            fwd.add(&rep(i));
            back.add(&rep(n - 1 - i));
        }
        let (a, b) = (fwd.stderr(), back.stderr());
        assert_eq!(
            a.iter().map(|x| x.to_bits()).collect::<Vec<_>>(),
            b.iter().map(|x| x.to_bits()).collect::<Vec<_>>()
        );
        for (k, &got) in a.iter().enumerate().take(3) {
            let want = jackknife_se(&(0..n).map(|i| rep(i)[k]).collect::<Vec<_>>());
            // each deviation rounded to 2^-40 = 9.1e-13
            assert!(
                (got - want).abs() <= 1e-12 * (n as f64) + 1e-9 * want,
                "{k}: {got} vs {want}"
            );
            assert!(want > 0.0);
        }
        assert!(a[3].is_nan() && a[4].is_nan() && a[5].is_nan(), "{a:?}");
        // one replicate is no jackknife
        let mut one = JackknifeStream::new(vec![1.0]);
        one.add(&[1.5]);
        assert!(one.stderr()[0].is_nan());
    }

    /// Error bars that cannot carry a paper say so: regression errors, and
    /// jackknife errors over fewer than FEW_IMAGES images, with how rough.
    #[test]
    fn weak_error_bars_are_flagged() {
        let said = |n: usize| {
            let mut w = Vec::new();
            let m = stderr_method(n, &[], &mut w);
            (m, w)
        };
        let (m, w) = said(1);
        assert_eq!(m, "regression");
        assert!(w.len() == 1 && w[0].contains("(1 image;") && w[0].contains("understate"));
        let (m, w) = said(4);
        assert_eq!(m, "jackknife over images");
        // 1/sqrt(2 * 3) = 0.408
        assert!(w.len() == 1 && w[0].contains("3 degrees of freedom") && w[0].contains("41 %"));
        let (m, w) = said(FEW_IMAGES);
        assert_eq!(m, "jackknife over images");
        assert!(w.is_empty(), "{w:?}");
        // two groups: one degree of freedom, 1/sqrt(2) = 71 %
        let w = few_groups_warning(2, "a jackknife over 2 tiles").unwrap();
        assert!(
            w.contains("(1 degree of freedom)") && w.contains("71 %"),
            "{w}"
        );
        assert!(few_groups_warning(1, "x").is_none() && few_groups_warning(10, "x").is_none());
    }

    #[test]
    fn exact_line() {
        let x = [0.0, 1.0, 2.0, 3.0];
        let y: Vec<f64> = x.iter().map(|v| 2.0 - 0.5 * v).collect();
        let f = line_fit(&x, &y).unwrap();
        assert!((f.slope + 0.5).abs() < 1e-14 && (f.intercept - 2.0).abs() < 1e-14);
        assert!(f.slope_stderr < 1e-12 && (f.r2 - 1.0).abs() < 1e-12);
    }

    #[test]
    fn stderr_matches_textbook() {
        // y = x + e with e = (+1, -1, -1, +1): slope 1, sse = 4 - 0 (e ⟂ x - mean? no)
        let x = [0.0, 1.0, 2.0, 3.0];
        let e = [1.0, -1.0, -1.0, 1.0];
        let y: Vec<f64> = x.iter().zip(e).map(|(a, b)| a + b).collect();
        let f = line_fit(&x, &y).unwrap();
        // e is orthogonal to (x - 1.5), so the slope is exactly 1 and sse = 4
        assert!((f.slope - 1.0).abs() < 1e-14);
        let expect = (4.0 / 2.0 / 5.0f64).sqrt();
        assert!((f.slope_stderr - expect).abs() < 1e-14);
    }

    /// The change of the local slope is exact on a parabola, 0 on a line
    /// whatever its slope, and undefined without three distinct x.
    #[test]
    fn slope_change_of_a_parabola() {
        let x: Vec<f64> = (0..20).map(|i| 0.6 + 0.1 * f64::from(i)).collect();
        // y' = b + 2 c x goes from b + 2 c 0.6 to b + 2 c 2.5: a change of 3.8 c
        for (b, c) in [(0.0, 0.3), (-2.0, -0.05), (5.0, 0.0)] {
            let y: Vec<f64> = x.iter().map(|v| 1.0 + b * v + c * v * v).collect();
            let d = slope_change(&x, &y).unwrap();
            assert!((d - 3.8 * c).abs() < 1e-12, "b {b} c {c}: {d}");
        }
        assert!(slope_change(&[0.0, 1.0], &[0.0, 1.0]).is_none());
        assert!(slope_change(&[0.0, 1.0, 1.0, 0.0], &[0.0, 1.0, 2.0, 3.0]).is_none());
        assert!(slope_change(&[0.0, 1.0, f64::NAN, 2.0], &[0.0, 1.0, 9.0, 4.0]).is_some());
    }

    #[test]
    fn degenerate() {
        assert!(line_fit(&[1.0], &[2.0]).is_none());
        assert!(line_fit(&[1.0, 1.0], &[2.0, 3.0]).is_none());
        assert!(line_fit(&[0.0, f64::NAN, 1.0], &[0.0, 5.0, 1.0]).is_some());
    }
}
