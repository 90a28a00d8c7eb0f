//! Numerically stable sums and the universal-multifractal fits.

use serde::{Deserialize, Serialize};

/// A sum of positive terms kept as `s · e^m` (log-sum-exp), so that moments
/// of any order neither overflow nor lose the small terms. Starts at
/// `(m, s) = (0, 0)` (always finite, JSON-safe).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct LogSum {
    /// Exponent `m` (natural log) of the scale factor.
    pub m: f64,
    /// Mantissa `s >= 0` (0 when empty).
    pub s: f64,
}

impl LogSum {
    /// Adds `s · e^m`.
    pub fn add(&mut self, m: f64, s: f64) {
        if s <= 0.0 || !m.is_finite() {
            return;
        }
        if self.s <= 0.0 {
            *self = LogSum { m, s };
            return;
        }
        if m > self.m {
            self.s = self.s * (self.m - m).exp() + s;
            self.m = m;
        } else {
            self.s += s * (m - self.m).exp();
        }
    }

    /// Adds the sum `o`.
    pub fn merge(&mut self, o: &LogSum) {
        self.add(o.m, o.s);
    }

    /// `ln` of the sum (`-∞` when empty).
    pub fn ln(&self) -> f64 {
        if self.s > 0.0 {
            self.m + self.s.ln()
        } else {
            f64::NEG_INFINITY
        }
    }

    /// Adds `Σ_i exp(q l_i)` for logs `l` with maximum `lmax` (`q >= 0`).
    pub fn add_powers(&mut self, logs: &[f64], lmax: f64, q: f64) {
        if logs.is_empty() {
            return;
        }
        if q == 0.0 {
            self.add(0.0, logs.len() as f64);
            return;
        }
        if !lmax.is_finite() {
            return; // every term is 0
        }
        let s: f64 = logs.iter().map(|&l| (q * (l - lmax)).exp()).sum();
        self.add(q * lmax, s);
    }
}

/// The largest multiple of the step [`power_sums`] raises by repeated
/// multiplication.
const MAX_POWER_STEPS: usize = 64;

/// The step `δ` (the smallest positive q) and each q's multiple `k` of it
/// (0 for q = 0), when every positive q is a whole multiple `k δ`,
/// `k <= 64`, to 1e-13 of q; `None` otherwise.
fn grid_steps(qs: &[f64]) -> Option<(f64, Vec<usize>)> {
    let delta = qs
        .iter()
        .copied()
        .filter(|&q| q > 0.0)
        .fold(f64::INFINITY, f64::min);
    if !delta.is_finite() {
        return None;
    }
    let ks = qs
        .iter()
        .map(|&q| {
            if q == 0.0 {
                return Some(0);
            }
            let k = (q / delta).round();
            ((1.0..=MAX_POWER_STEPS as f64).contains(&k) && (q - k * delta).abs() <= 1e-13 * q)
                .then_some(k as usize)
        })
        .collect::<Option<Vec<usize>>>()?;
    Some((delta, ks))
}

/// `Σ w x^k` for k = 1..=`kmax` (index k; 0 unused) over pairs `(x, w)`,
/// `x` in [0, 1] and `w > 0`, by repeated multiplication (`w = 1`: the
/// plain powers, bit for bit). No cut-off at underflow: a power that
/// underflowed to 0 adds 0, the same sums, and the branch per power it
/// took cost more than it saved (tm bench, one thread: add_field 815 ->
/// 781 ms, field_tiles 1551 -> 1434 ms); the sums of up to 6 powers (the
/// DTM's one, the structure functions' 6) are held in registers
/// ([`sum_products_fixed`]: 751 and 1376 ms). Four partial sums per
/// power, to break the chain of additions, took 4 % more off but changed
/// the bits.
fn sum_products(xs: impl Iterator<Item = (f64, f64)>, kmax: usize) -> Vec<f64> {
    match kmax {
        1 => return sum_products_fixed::<1>(xs),
        2 => return sum_products_fixed::<2>(xs),
        3 => return sum_products_fixed::<3>(xs),
        4 => return sum_products_fixed::<4>(xs),
        5 => return sum_products_fixed::<5>(xs),
        6 => return sum_products_fixed::<6>(xs),
        _ => {}
    }
    let mut acc = vec![0.0; kmax + 1];
    for (x, w) in xs {
        let mut p = w;
        for a in acc[1..].iter_mut() {
            p *= x;
            *a += p;
        }
    }
    acc
}

/// [`sum_products`] for a `K` known at compile time: the sums stay in
/// registers (the same additions in the same order, so the same bits).
fn sum_products_fixed<const K: usize>(xs: impl Iterator<Item = (f64, f64)>) -> Vec<f64> {
    let mut acc = [0.0; K];
    for (x, w) in xs {
        let mut p = w;
        for a in acc.iter_mut() {
            p *= x;
            *a += p;
        }
    }
    std::iter::once(0.0).chain(acc).collect()
}

/// `(q l_max, Σ_i exp(q (l_i - l_max)))` for every `q` of `qs`: the terms
/// [`LogSum::add`] takes to add `Σ_i exp(q l_i)`, as [`LogSum::add_powers`]
/// would for one `q` at a time (`q = 0`: `(0, n)`; empty `logs` or an
/// infinite `lmax`: a zero sum). When the positive `q` are whole multiples
/// `k δ` of the smallest, `δ`, with `k <= 64` (tm's grids 0.1:4:0.1 and
/// 0.5:3:0.5), each term costs one `exp` and `k` multiplications: `x^k`
/// with `x = exp(δ (l - l_max))`. The product's error, k ulp (4e-15 at
/// k = 40), is that of `exp` itself, whose argument `q (l - l_max)` is
/// already rounded to `|q (l - l_max)|` ulp; the exps, one per term and
/// q, were half of tm's time. Otherwise one `exp` per term and q.
pub fn power_sums(logs: &[f64], lmax: f64, qs: &[f64]) -> Vec<(f64, f64)> {
    weighted_power_sums(logs, None, lmax, qs)
}

/// [`power_sums`] of the weighted terms `w_i exp(q l_i)` (`w_i > 0`, one
/// per log; `None`: all 1, and `q = 0` gives `Σ w_i`): the box moments
/// weighted by the boxes' valid pixels ([`BoxWeights::Count`]).
///
/// [`BoxWeights::Count`]: super::BoxWeights::Count
pub fn weighted_power_sums(
    logs: &[f64],
    weights: Option<&[f64]>,
    lmax: f64,
    qs: &[f64],
) -> Vec<(f64, f64)> {
    debug_assert!(weights.is_none_or(|w| w.len() == logs.len()));
    let w = |i: usize| weights.map_or(1.0, |w| w[i]);
    let mut out = empty_sums(total_weight(logs.len(), weights), lmax, qs);
    if logs.is_empty() || !lmax.is_finite() {
        return out;
    }
    match grid_steps(qs) {
        Some((delta, ks)) => {
            let kmax = ks.iter().copied().max().unwrap_or(0);
            let xs = logs
                .iter()
                .enumerate()
                .map(|(i, &l)| ((delta * (l - lmax)).exp(), w(i)));
            let acc = sum_products(xs, kmax);
            fill(&mut out, &ks, &acc);
        }
        None => {
            for (o, &q) in out.iter_mut().zip(qs) {
                if q != 0.0 {
                    o.1 = logs
                        .iter()
                        .enumerate()
                        .map(|(i, &l)| w(i) * (q * (l - lmax)).exp())
                        .sum();
                }
            }
        }
    }
    out
}

/// [`power_sums`] of values `v >= 0` given as they are, not as logs: the
/// terms for `Σ_i v_i^q`, `(q ln v_max, Σ_i (v_i / v_max)^q)`. On a grid
/// whose step is 1 or a multiple n/2 of 1/2, n <= 8 (the structure
/// functions' 0.5:3:0.5, the DTM's 1.5) no transcendental call is left:
/// `x = v / v_max`, or `x = sqrt(v / v_max)^n` (a correctly rounded sqrt
/// and n - 1 products); another step takes one `powf` per value.
pub fn power_sums_of_values(vals: &[f64], qs: &[f64]) -> Vec<(f64, f64)> {
    weighted_power_sums_of_values(vals, None, qs)
}

/// [`power_sums_of_values`] of the weighted terms `w_i v_i^q`, as
/// [`weighted_power_sums`].
pub fn weighted_power_sums_of_values(
    vals: &[f64],
    weights: Option<&[f64]>,
    qs: &[f64],
) -> Vec<(f64, f64)> {
    debug_assert!(weights.is_none_or(|w| w.len() == vals.len()));
    let w = |i: usize| weights.map_or(1.0, |w| w[i]);
    let vmax = vals.iter().copied().fold(0.0, f64::max);
    let mut out = empty_sums(total_weight(vals.len(), weights), vmax.ln(), qs);
    if vals.is_empty() || !(vmax > 0.0 && vmax.is_finite()) {
        return out;
    }
    match grid_steps(qs) {
        Some((delta, ks)) => {
            let kmax = ks.iter().copied().max().unwrap_or(0);
            let rel = vals.iter().map(|&v| v / vmax);
            let halves = 2.0 * delta;
            let paired = |x: f64, i: usize| (x, w(i));
            let acc = if delta == 1.0 {
                sum_products(rel.enumerate().map(|(i, x)| paired(x, i)), kmax)
            } else if halves == halves.round() && halves <= 8.0 {
                let n = halves as usize;
                let root_power = |r: f64| {
                    let y = r.sqrt();
                    (1..n).fold(y, |p, _| p * y)
                };
                sum_products(rel.enumerate().map(|(i, r)| paired(root_power(r), i)), kmax)
            } else {
                sum_products(rel.enumerate().map(|(i, r)| paired(r.powf(delta), i)), kmax)
            };
            fill(&mut out, &ks, &acc);
        }
        None => {
            for (o, &q) in out.iter_mut().zip(qs) {
                if q != 0.0 {
                    o.1 = vals
                        .iter()
                        .enumerate()
                        .map(|(i, &v)| w(i) * (v / vmax).powf(q))
                        .sum();
                }
            }
        }
    }
    out
}

/// `n`, or the sum of the weights.
fn total_weight(n: usize, weights: Option<&[f64]>) -> f64 {
    weights.map_or(n as f64, |w| w.iter().sum())
}

/// `(0, n)` for q = 0 and `(q lmax, 0)` otherwise.
fn empty_sums(n: f64, lmax: f64, qs: &[f64]) -> Vec<(f64, f64)> {
    qs.iter()
        .map(|&q| if q == 0.0 { (0.0, n) } else { (q * lmax, 0.0) })
        .collect()
}

/// Puts `acc[k]` into the sum of each q of multiple `k > 0`.
fn fill(out: &mut [(f64, f64)], ks: &[usize], acc: &[f64]) {
    for (o, &k) in out.iter_mut().zip(ks) {
        if k > 0 {
            o.1 = acc[k];
        }
    }
}

/// `(q^α - q)/(α - 1)` (`q ln q` at α = 1): the universal K(q) at C1 = 1.
pub fn universal_shape(alpha: f64, q: f64) -> f64 {
    if q <= 0.0 {
        return 0.0;
    }
    if (alpha - 1.0).abs() < 1e-6 {
        // second-order expansion in (α - 1) keeps the fit smooth across 1
        let l = q.ln();
        let e = alpha - 1.0;
        return q * l + 0.5 * e * q * l * l;
    }
    (q.powf(alpha) - q) / (alpha - 1.0)
}

/// Least-squares fit of `K(q) = C1 (q^α - q)/(α - 1)`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct UniversalFit {
    /// Fitted α (searched in `[0.02, 3]`, not clamped to the Lévy range (0, 2]).
    pub alpha: f64,
    /// Standard error of α from the fit's covariance (OLS: Gauss-Newton
    /// `s² (JᵀJ)⁻¹`; GLS: `(J' w J)⁻¹`); NaN when singular.
    pub alpha_stderr: f64,
    /// Fitted C1.
    pub c1: f64,
    /// Standard error of C1, as `alpha_stderr`.
    pub c1_stderr: f64,
    /// Root-mean-square residual.
    pub rms: f64,
    /// Number of points `(q, K)` used (finite, q > 0).
    pub n: usize,
}

/// Fits `(α, C1)` to the points `(q, K)` by unweighted least squares (the
/// OLS fit; [`fit_universal_gls`] weights the points with the covariance of
/// K(q) over the images, which are strongly correlated between
/// neighbouring q, and is the default of an ensemble with images). α is
/// searched in `[0.02, 3]` (values above 2 are not a valid Lévy index but are
/// reported as fitted, not clamped, so the estimator is not biased at 2).
/// For each α the best C1 is linear: `C1 = Σ K f / Σ f²`. Standard errors by
/// the Gauss-Newton covariance `s² (JᵀJ)⁻¹`, `s² = SSE/(n - 2)`.
pub fn fit_universal(q: &[f64], k: &[f64]) -> Option<UniversalFit> {
    let pts: Vec<(f64, f64)> = q
        .iter()
        .zip(k)
        .filter(|(a, b)| **a > 0.0 && a.is_finite() && b.is_finite())
        .map(|(a, b)| (*a, *b))
        .collect();
    if pts.len() < 3 {
        return None;
    }
    let c1_of = |alpha: f64| -> (f64, f64) {
        let (mut kf, mut ff) = (0.0, 0.0);
        for &(qq, kk) in &pts {
            let f = universal_shape(alpha, qq);
            kf += kk * f;
            ff += f * f;
        }
        let c1 = if ff > 0.0 { kf / ff } else { 0.0 };
        let sse: f64 = pts
            .iter()
            .map(|&(qq, kk)| (kk - c1 * universal_shape(alpha, qq)).powi(2))
            .sum();
        (c1, sse)
    };
    let alpha = minimise_alpha(|a| c1_of(a).1);
    let (c1, sse) = c1_of(alpha);
    let n = pts.len();
    // Jacobian of K = C1 f(α, q)
    let e = 1e-5;
    let (mut jaa, mut jac, mut jcc) = (0.0, 0.0, 0.0);
    for &(qq, _) in &pts {
        let da = c1 * (universal_shape(alpha + e, qq) - universal_shape(alpha - e, qq)) / (2.0 * e);
        let dc = universal_shape(alpha, qq);
        jaa += da * da;
        jac += da * dc;
        jcc += dc * dc;
    }
    let det = jaa * jcc - jac * jac;
    let s2 = if n > 2 {
        sse / (n - 2) as f64
    } else {
        f64::NAN
    };
    let (alpha_stderr, c1_stderr) = if det > 0.0 {
        ((s2 * jcc / det).sqrt(), (s2 * jaa / det).sqrt())
    } else {
        (f64::NAN, f64::NAN)
    };
    Some(UniversalFit {
        alpha,
        alpha_stderr,
        c1,
        c1_stderr,
        rms: (sse / n as f64).sqrt(),
        n,
    })
}

/// How the universal fit weights the measured K(q) (module docs of
/// [`crate::tracemoments`], "Universal fit").
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum UniversalWeighting {
    /// Generalised least squares with the jackknife covariance of K(q)
    /// across q (q = 1 left out), its correlations shrunk toward 0 by the
    /// Schäfer-Strimmer intensity (needs at least 5 jackknife parts;
    /// otherwise `ols`).
    #[default]
    Gls,
    /// Unweighted least squares in K (the estimator before GLS).
    Ols,
}

/// A covariance matrix estimated from jackknife leave-one-out replicates,
/// with its correlations shrunk toward 0 (Schäfer & Strimmer 2005, target
/// "D": diagonal, unequal variances).
#[derive(Clone, Debug, PartialEq)]
pub struct ShrunkCovariance {
    /// `(1 - λ) r_ij s_i s_j` off the diagonal, `s_i²` on it; `s_i²` the
    /// jackknife variances `(n-1)/n Σ (x_i - mean)²`.
    pub cov: Vec<Vec<f64>>,
    /// The shrinkage intensity λ in `[0, 1]` (1: diagonal weights only).
    pub lambda: f64,
}

/// The jackknife covariance of the components of `loo` (one vector per
/// left-out part, all of the same length), shrunk toward its diagonal by
/// the analytic Schäfer-Strimmer intensity
/// `λ = Σ_{i≠j} Var(r_ij) / Σ_{i≠j} r_ij²` (estimated from the replicates;
/// the jackknife deviations are, up to a factor `-(n-1)`, the pseudo-values'
/// deviations, so the correlations and λ are those of the pseudo-values).
/// With n parts the raw matrix has rank at most n - 1, so the shrinkage is
/// what makes it invertible when there are more q values than parts.
/// `None` with fewer than 4 replicates, or a component without scatter.
pub fn jackknife_covariance_shrunk(loo: &[Vec<f64>]) -> Option<ShrunkCovariance> {
    let n = loo.len();
    let p = loo.first()?.len();
    if n < 4
        || p == 0
        || loo
            .iter()
            .any(|v| v.len() != p || v.iter().any(|x| !x.is_finite()))
    {
        return None;
    }
    let nf = n as f64;
    let mean: Vec<f64> = (0..p)
        .map(|i| loo.iter().map(|v| v[i]).sum::<f64>() / nf)
        .collect();
    let ss: Vec<f64> = (0..p)
        .map(|i| loo.iter().map(|v| (v[i] - mean[i]).powi(2)).sum::<f64>())
        .collect();
    if ss.iter().any(|s| !(*s > 0.0)) {
        return None;
    }
    // standardised deviations (unit sample variance)
    let sd: Vec<f64> = ss.iter().map(|s| (s / (nf - 1.0)).sqrt()).collect();
    let z: Vec<Vec<f64>> = loo
        .iter()
        .map(|v| (0..p).map(|i| (v[i] - mean[i]) / sd[i]).collect())
        .collect();
    let mut r = vec![vec![1.0; p]; p];
    let (mut num, mut den) = (0.0, 0.0);
    for i in 0..p {
        for j in (i + 1)..p {
            let w: Vec<f64> = z.iter().map(|v| v[i] * v[j]).collect();
            let wb = w.iter().sum::<f64>() / nf;
            let rij = nf / (nf - 1.0) * wb;
            let var = nf / (nf - 1.0).powi(3) * w.iter().map(|a| (a - wb).powi(2)).sum::<f64>();
            r[i][j] = rij;
            r[j][i] = rij;
            num += var;
            den += rij * rij;
        }
    }
    let lambda = if den > 0.0 {
        (num / den).clamp(0.0, 1.0)
    } else {
        1.0
    };
    let var_jk: Vec<f64> = ss.iter().map(|s| (nf - 1.0) / nf * s).collect();
    let cov = (0..p)
        .map(|i| {
            (0..p)
                .map(|j| {
                    if i == j {
                        var_jk[i]
                    } else {
                        (1.0 - lambda) * r[i][j] * (var_jk[i] * var_jk[j]).sqrt()
                    }
                })
                .collect()
        })
        .collect();
    Some(ShrunkCovariance { cov, lambda })
}

/// Inverse of a symmetric positive-definite matrix by Cholesky (`None` if
/// it is not positive definite).
#[allow(clippy::needless_range_loop)] // index form of the textbook algorithm
pub fn spd_inverse(a: &[Vec<f64>]) -> Option<Vec<Vec<f64>>> {
    let n = a.len();
    let mut l = vec![vec![0.0; n]; n];
    for i in 0..n {
        for j in 0..=i {
            let s: f64 = a[i][j] - (0..j).map(|k| l[i][k] * l[j][k]).sum::<f64>();
            if i == j {
                if !(s > 0.0) {
                    return None;
                }
                l[i][i] = s.sqrt();
            } else {
                l[i][j] = s / l[j][j];
            }
        }
    }
    // inverse of L by forward substitution, then A⁻¹ = L⁻ᵀ L⁻¹
    let mut li = vec![vec![0.0; n]; n];
    for c in 0..n {
        for i in c..n {
            let rhs = if i == c { 1.0 } else { 0.0 };
            let s: f64 = (c..i).map(|k| l[i][k] * li[k][c]).sum();
            li[i][c] = (rhs - s) / l[i][i];
        }
    }
    let mut inv = vec![vec![0.0; n]; n];
    for i in 0..n {
        for j in 0..=i {
            let s: f64 = (i..n).map(|k| li[k][i] * li[k][j]).sum();
            inv[i][j] = s;
            inv[j][i] = s;
        }
    }
    Some(inv)
}

/// Generalised least-squares fit of `K(q) = C1 (q^α - q)/(α - 1)` with the
/// inverse covariance `w` of the K values (`w` is p x p for the p points
/// `(q, k)`, all of which must be finite with `q > 0`): minimises
/// `r' w r`, `r = K - C1 f(α, q)`; for each α the best C1 is
/// `f' w K / f' w f`. α is searched in `[0.02, 3]` as in [`fit_universal`].
/// Standard errors from `(J' w J)⁻¹` (w in absolute units: the errors of the
/// covariance model, not rescaled by the residuals). `None` with fewer than
/// 3 points, a size mismatch or a non-finite value. Leave q = 1 out of the
/// points: `f` and its derivatives vanish there, so it could move the fit
/// only through its correlations with the other K (as
/// [`super::finish_jackknife`] does).
pub fn fit_universal_gls(q: &[f64], k: &[f64], w: &[Vec<f64>]) -> Option<UniversalFit> {
    let n = q.len();
    if n < 3
        || k.len() != n
        || w.len() != n
        || w.iter()
            .any(|r| r.len() != n || r.iter().any(|x| !x.is_finite()))
        || q.iter()
            .zip(k)
            .any(|(a, b)| !(*a > 0.0 && a.is_finite() && b.is_finite()))
    {
        return None;
    }
    let quad = |a: &[f64], b: &[f64]| -> f64 {
        (0..n)
            .map(|i| a[i] * (0..n).map(|j| w[i][j] * b[j]).sum::<f64>())
            .sum()
    };
    let eval = |alpha: f64| -> (f64, f64) {
        let f: Vec<f64> = q.iter().map(|&x| universal_shape(alpha, x)).collect();
        let ff = quad(&f, &f);
        let c1 = if ff > 0.0 { quad(&f, k) / ff } else { 0.0 };
        let r: Vec<f64> = (0..n).map(|i| k[i] - c1 * f[i]).collect();
        (c1, quad(&r, &r))
    };
    let alpha = minimise_alpha(|a| eval(a).1);
    let (c1, _) = eval(alpha);
    let e = 1e-5;
    let da: Vec<f64> = q
        .iter()
        .map(|&x| c1 * (universal_shape(alpha + e, x) - universal_shape(alpha - e, x)) / (2.0 * e))
        .collect();
    let dc: Vec<f64> = q.iter().map(|&x| universal_shape(alpha, x)).collect();
    let (jaa, jac, jcc) = (quad(&da, &da), quad(&da, &dc), quad(&dc, &dc));
    let det = jaa * jcc - jac * jac;
    let (alpha_stderr, c1_stderr) = if det > 0.0 {
        ((jcc / det).sqrt(), (jaa / det).sqrt())
    } else {
        (f64::NAN, f64::NAN)
    };
    let sse: f64 = q
        .iter()
        .zip(k)
        .map(|(&x, &y)| (y - c1 * universal_shape(alpha, x)).powi(2))
        .sum();
    Some(UniversalFit {
        alpha,
        alpha_stderr,
        c1,
        c1_stderr,
        rms: (sse / n as f64).sqrt(),
        n,
    })
}

/// The interval the universal fits search alpha in: wider than the
/// universal range [0, 2] (TM §6), so that an estimate beyond 2 shows as
/// one; an alpha at either end is no minimum (`diagnostics` says so).
pub(crate) const ALPHA_SEARCH: (f64, f64) = (0.02, 3.0);

/// The alpha in [`ALPHA_SEARCH`] minimising `obj`: a grid of 150 points,
/// then golden-section refinement around the best one (`obj` need not be
/// unimodal over the whole range, only near its minimum).
fn minimise_alpha(obj: impl Fn(f64) -> f64) -> f64 {
    let (lo, hi) = ALPHA_SEARCH;
    let steps = 149;
    let mut best = (lo, f64::INFINITY);
    for i in 0..=steps {
        let a = lo + (hi - lo) * i as f64 / steps as f64;
        let v = obj(a);
        if v < best.1 {
            best = (a, v);
        }
    }
    let h = (hi - lo) / steps as f64;
    let (mut a, mut b) = ((best.0 - h).max(lo), (best.0 + h).min(hi));
    let g = 0.5 * (5f64.sqrt() - 1.0);
    for _ in 0..80 {
        let x1 = b - g * (b - a);
        let x2 = a + g * (b - a);
        if obj(x1) < obj(x2) {
            b = x2;
        } else {
            a = x1;
        }
    }
    0.5 * (a + b)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The register-held sums of a few powers are those of the general
    /// loop, bit for bit, underflow included (x = 1e-200: x^2 is 0).
    #[test]
    fn fixed_power_sums_are_the_general_ones() {
        let xs: Vec<(f64, f64)> = (0..1000)
            .map(|i| {
                let u = crate::synth::splitmix64(i) as f64 / u64::MAX as f64;
                let x = if i % 97 == 0 { 1e-200 } else { u };
                (x, 0.5 + (i % 7) as f64)
            })
            .collect();
        for kmax in 1..=8 {
            let mut general = vec![0.0; kmax + 1];
            for &(x, w) in &xs {
                let mut p = w;
                for a in general[1..].iter_mut() {
                    p *= x;
                    *a += p;
                }
            }
            let got = sum_products(xs.iter().copied(), kmax);
            let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&got), bits(&general), "kmax {kmax}");
        }
        assert_eq!(sum_products(xs.iter().copied(), 0), vec![0.0]);
    }

    /// The repeated products of `power_sums` against one `exp` per term and
    /// q: tm's grids (products) and an irregular one (exps), with q = 0,
    /// logs spanning 700 (terms down to e^-2800) and the edge cases.
    #[test]
    fn power_sums_match_one_exp_per_q() {
        // a deterministic spread of logs: holes to the maximum
        let logs: Vec<f64> = (0..2000)
            .map(|i| -700.0 * ((i as f64 * 0.618_033_988_75).fract()).powi(3) + 3.0)
            .collect();
        let lmax = logs.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let grids: [Vec<f64>; 4] = [
            (1..=40).map(|i| i as f64 / 10.0).collect(),
            vec![0.5, 1.0, 1.5, 2.0, 2.5, 3.0],
            vec![0.0, 0.3, 1.0, 2.2],
            vec![1.5],
        ];
        for qs in &grids {
            let got = power_sums(&logs, lmax, qs);
            for (&q, &(m, s)) in qs.iter().zip(&got) {
                let mut want = LogSum::default();
                want.add_powers(&logs, lmax, q);
                let mut have = LogSum::default();
                have.add(m, s);
                let rel = (have.ln() - want.ln()).abs();
                assert!(rel < 1e-13, "q {q}: ln {} vs {}", have.ln(), want.ln());
            }
        }
        // the same sums from the values themselves (no logs): grids of step
        // 1/2 (sqrt), 1, 0.1 (powf) and an irregular one
        let vals: Vec<f64> = logs.iter().map(|l| l.exp()).collect();
        let grids_v: [Vec<f64>; 7] = [
            vec![0.5, 1.0, 1.5, 2.0, 2.5, 3.0],
            vec![0.0, 1.0, 2.0, 3.0],
            (1..=40).map(|i| i as f64 / 10.0).collect(),
            vec![0.3, 1.0, 2.2],
            vec![1.5],
            vec![0.5, 1.5],
            vec![2.5, 5.0],
        ];
        for qs in &grids_v {
            for (&q, &(m, s)) in qs.iter().zip(&power_sums_of_values(&vals, qs)) {
                let mut want = LogSum::default();
                want.add_powers(&logs, lmax, q);
                let mut have = LogSum::default();
                have.add(m, s);
                let rel = (have.ln() - want.ln()).abs();
                assert!(
                    rel < 1e-13,
                    "values, q {q}: ln {} vs {}",
                    have.ln(),
                    want.ln()
                );
            }
        }
        let zeros = power_sums_of_values(&[0.0, 0.0], &[0.0, 0.5]);
        assert_eq!(zeros[0], (0.0, 2.0));
        assert_eq!(zeros[1].1, 0.0);
        // an lmax above every log (not their maximum) still sums them
        let q40: Vec<f64> = (1..=40).map(|i| i as f64 / 10.0).collect();
        let small = power_sums(&[-800.0; 10], 0.0, &q40);
        let mut want = LogSum::default();
        want.add_powers(&[-800.0; 10], 0.0, 0.9);
        let mut have = LogSum::default();
        have.add(small[8].0, small[8].1);
        assert!(
            (have.ln() - want.ln()).abs() < 1e-12,
            "{} vs {}",
            have.ln(),
            want.ln()
        );
        assert_eq!(
            power_sums(&[], 0.0, &[0.0, 1.0]),
            vec![(0.0, 0.0), (0.0, 0.0)]
        );
        let lost = power_sums(&[f64::NEG_INFINITY; 3], f64::NEG_INFINITY, &[0.0, 2.0]);
        assert_eq!(lost[0], (0.0, 3.0));
        assert_eq!(lost[1].1, 0.0);
    }

    /// The weighted sums `Σ w exp(q l)` (count box weights) against one
    /// `exp` per term and q with `ln w` added to the log, from logs and from
    /// values, on tm's grids and an irregular one; unit weights give the
    /// unweighted sums bit for bit, and q = 0 the sum of the weights.
    #[test]
    fn weighted_power_sums_match_one_exp_per_term() {
        let logs: Vec<f64> = (0..1500)
            .map(|i| -300.0 * ((i as f64 * 0.618_033_988_75).fract()).powi(3) + 1.0)
            .collect();
        // shares of valid pixels c / 4^k, 1/64 .. 1
        let w: Vec<f64> = (0..logs.len())
            .map(|i| (1 + (i * 37) % 64) as f64 / 64.0)
            .collect();
        let lmax = logs.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let vals: Vec<f64> = logs.iter().map(|l| l.exp()).collect();
        let grids: [Vec<f64>; 4] = [
            (1..=40).map(|i| i as f64 / 10.0).collect(),
            vec![0.0, 0.5, 1.0, 1.5, 2.0],
            vec![0.0, 0.3, 1.0, 2.2],
            vec![1.5],
        ];
        for qs in &grids {
            let from_logs = weighted_power_sums(&logs, Some(&w), lmax, qs);
            let from_vals = weighted_power_sums_of_values(&vals, Some(&w), qs);
            for (iq, &q) in qs.iter().enumerate() {
                let want: f64 = if q == 0.0 {
                    w.iter().sum::<f64>().ln()
                } else {
                    let terms: Vec<f64> =
                        logs.iter().zip(&w).map(|(l, w)| q * l + w.ln()).collect();
                    let top = terms.iter().copied().fold(f64::NEG_INFINITY, f64::max);
                    top + terms.iter().map(|t| (t - top).exp()).sum::<f64>().ln()
                };
                for (what, (m, s)) in [("logs", from_logs[iq]), ("values", from_vals[iq])] {
                    let mut have = LogSum::default();
                    have.add(m, s);
                    assert!(
                        (have.ln() - want).abs() < 1e-13 * want.abs().max(1.0),
                        "{what}, q {q}: ln {} vs {want}",
                        have.ln()
                    );
                }
            }
            let ones = vec![1.0; logs.len()];
            assert_eq!(
                weighted_power_sums(&logs, Some(&ones), lmax, qs),
                power_sums(&logs, lmax, qs)
            );
            assert_eq!(
                weighted_power_sums_of_values(&vals, Some(&ones), qs),
                power_sums_of_values(&vals, qs)
            );
        }
    }

    #[test]
    fn logsum_matches_plain_sum() {
        let mut a = LogSum::default();
        let logs = [0.5f64, -3.0, 2.0, 700.0];
        let lmax = 700.0;
        a.add_powers(&logs, lmax, 1.5);
        // dominated by e^{1050}: ln = 1050 + ln(1 + tiny)
        assert!((a.ln() - 1050.0).abs() < 1e-12);
        let mut b = LogSum::default();
        b.add_powers(&logs[..3], 2.0, 2.0);
        let plain: f64 = logs[..3].iter().map(|l| (2.0 * l).exp()).sum();
        assert!((b.ln() - plain.ln()).abs() < 1e-12);
        let mut c = LogSum::default();
        c.merge(&b);
        c.merge(&b);
        assert!((c.ln() - (2.0 * plain).ln()).abs() < 1e-12);
    }

    #[test]
    fn universal_fit_exact() {
        let q: Vec<f64> = (1..=25).map(|i| i as f64 * 0.1).collect();
        for (alpha, c1) in [(1.8, 0.12), (2.0, 0.1), (1.0, 0.2), (0.6, 0.05)] {
            let k: Vec<f64> = q.iter().map(|&v| c1 * universal_shape(alpha, v)).collect();
            let f = fit_universal(&q, &k).unwrap();
            assert!((f.alpha - alpha).abs() < 1e-4, "{alpha}: {f:?}");
            assert!((f.c1 - c1).abs() < 1e-5, "{c1}: {f:?}");
        }
    }

    #[test]
    fn gls_with_identity_matches_ols_and_recovers_exact_curves() {
        let q: Vec<f64> = (1..=25).map(|i| i as f64 * 0.1).collect();
        let id: Vec<Vec<f64>> = (0..q.len())
            .map(|i| (0..q.len()).map(|j| f64::from(u8::from(i == j))).collect())
            .collect();
        for (alpha, c1) in [(1.8, 0.12), (1.0, 0.2), (0.6, 0.05)] {
            let k: Vec<f64> = q.iter().map(|&v| c1 * universal_shape(alpha, v)).collect();
            let g = fit_universal_gls(&q, &k, &id).unwrap();
            assert!(
                (g.alpha - alpha).abs() < 1e-4 && (g.c1 - c1).abs() < 1e-5,
                "{g:?}"
            );
            // a noisy curve: identity weights give the OLS estimate
            let kn: Vec<f64> = k
                .iter()
                .enumerate()
                .map(|(i, v)| v + 0.003 * ((i * 7919 % 13) as f64 - 6.0) / 6.0)
                .collect();
            let (g, o) = (
                fit_universal_gls(&q, &kn, &id).unwrap(),
                fit_universal(&q, &kn).unwrap(),
            );
            assert!((g.alpha - o.alpha).abs() < 1e-6 && (g.c1 - o.c1).abs() < 1e-8);
        }
    }

    #[test]
    #[allow(clippy::needless_range_loop)]
    fn spd_inverse_inverts() {
        let a = vec![
            vec![4.0, 1.0, 0.5],
            vec![1.0, 3.0, 0.2],
            vec![0.5, 0.2, 2.0],
        ];
        let b = spd_inverse(&a).unwrap();
        for i in 0..3 {
            for j in 0..3 {
                let p: f64 = (0..3).map(|k| a[i][k] * b[k][j]).sum();
                assert!((p - f64::from(u8::from(i == j))).abs() < 1e-12);
            }
        }
        assert!(spd_inverse(&[vec![1.0, 2.0], vec![2.0, 1.0]]).is_none());
    }

    #[test]
    fn shrinkage_is_full_for_independent_and_small_for_collinear_replicates() {
        // independent components (a fixed pseudo-random table): λ large
        let ind: Vec<Vec<f64>> = (0..16)
            .map(|i| {
                (0..6)
                    .map(|j| {
                        // splitmix64 of the index: independent uniforms
                        let mut z = (i * 6 + j) as u64 + 0x9e37_79b9_7f4a_7c15;
                        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
                        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
                        (z ^ (z >> 31)) as f64 / u64::MAX as f64
                    })
                    .collect()
            })
            .collect();
        let s = jackknife_covariance_shrunk(&ind).unwrap();
        assert!(s.lambda > 0.5, "{}", s.lambda);
        let lam_ind = s.lambda;
        // one common factor plus a little independent noise: λ small (not
        // 0: the estimated variance of r_ij is that of the products z_i z_j,
        // which stays finite when r -> 1; measured 0.10 here)
        let col: Vec<Vec<f64>> = ind
            .iter()
            .map(|v| {
                (0..6)
                    .map(|j| v[0] * (1.0 + j as f64) + 0.01 * v[j])
                    .collect()
            })
            .collect();
        let s = jackknife_covariance_shrunk(&col).unwrap();
        assert!(s.lambda < 0.2 && s.lambda < 0.5 * lam_ind, "{}", s.lambda);
        // diagonal = jackknife variances
        let n = 16.0;
        let m = col.iter().map(|v| v[2]).sum::<f64>() / n;
        let v = (n - 1.0) / n * col.iter().map(|x| (x[2] - m).powi(2)).sum::<f64>();
        assert!((s.cov[2][2] - v).abs() < 1e-12 * v);
        assert!(jackknife_covariance_shrunk(&ind[..3]).is_none());
    }
}
