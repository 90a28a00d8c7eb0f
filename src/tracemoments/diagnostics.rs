//! The warnings of a trace-moment result: fit ranges, the universal
//! model's bounds, departures between tiles or images.

use super::*;

/// How many standard errors a diagnostic of [`diagnostics`] needs before
/// it speaks: a two-sided false alarm of 0.3 % for normal errors.
pub const WARN_Z: f64 = 3.0;

/// Factor on jackknife errors over the tiles of an image in
/// [`diagnostics`]: tiles are treated as independent and their errors
/// understate, the rms jackknife error over the scatter between single
/// topo-fif fields being 0.36-0.87 (module docs, "Errors"), 0.49-0.75 for
/// the bend of the moment lines at q = 0.5-2 on 400², where the undoubled
/// 3-error rule flagged 3-6 of 24 fields at each q
/// (`experiment_curvature_calibration`). Doubled, they are about the
/// scatter or above it.
pub const TILE_ERROR_FACTOR: f64 = 2.0;

/// The diagnostics of a result `r` (its `warnings`), given the
/// leave-one-out results `loo` of its jackknife and whether its parts were
/// tiles (`None`: no jackknife; the regression errors then stand in). Each
/// speaks beyond [`WARN_Z`] errors (for 2., 3. and 4., tile errors times
/// [`TILE_ERROR_FACTOR`]):
/// 1. the spectral H above what the differentiation resolves: 1 with
///    [`FluxDiff::Auto`] (its order ξ(1) comes from first differences, which
///    saturate at 1, so for H > 1 the excess order falls below 1: module
///    docs, "Which flux"), `1 + order` otherwise (TM §5.2: the flux
///    needs a differentiation of order H or more);
/// 2. else the spectral H and `H_sf = ξ(1)` apart (both estimate H:
///    `ξ(1) = H - K(1) = H`, TM eq 10), the error that of their
///    difference (jackknifed as a difference: the two share the tiles);
///    with 5. said, it names the plane;
/// 3. with a jackknife, moment lines `log2 <φ_λ^q>` curved over the fitted
///    scales, at the q of the universal fit (beyond `q_s/2` the sampling
///    bends them anyway, TM eq 15): the change of their local slope
///    across the fit range ([`crate::stats::fit::slope_change`], as the
///    WTMM spectra's straightness check) against its jackknife error, the
///    false alarm of [`WARN_Z`] shared among the q tested (Bonferroni). The
///    threshold is the statistics' own: the WTMM check's fixed 0.2 is the
///    tolerance of published tau(q), and K(q) has no such scale;
/// 4. with a GLS universal fit, its alpha and the OLS fit's apart, against
///    the jackknife error of their difference: K(q) not of the universal
///    form over the fitted q, so alpha depends on the weighting;
/// 5. (said before 2.) without detrending, fields whose plane explains
///    more than [`crate::spectra::PLANE_SHARE_WARN`] of their variance,
///    whose removal would move `H_sf`
///    ([`TraceMomentResult::h_sf_plane_shift`]) by more than its error
///    (0.01 without one): the numbers, with the spectral H as a guide,
///    not a verdict: a tilt and a rough surface's own large scales both
///    make planes (8 untilted fBm of 512², H = 0.8: `H_sf` 0.776 would
///    drop to about 0.758, away from the spectral 0.823).
///
/// Then the range checks, whatever the errors: alpha at an end of the
/// fit's search interval (no minimum) or outside the universal [0, 2], C1
/// below or indistinguishable from 0, and β, H, the DTM or `H_sf` left
/// without a fit by their ranges.
///
/// Measured (`experiment_lone_image_tiles` in tests/tracemoments.rs): on 24
/// single topo-fif fields, 1, 1 and 2 of them got a straightness warning at
/// 256², 400² and 512², 1, 0 and 1 an H disagreement, none the first; an
/// fBm gets the straightness warning, rightly (its flux is no cascade: box
/// averages converge like sums of nearly independent values, no power law).
pub fn diagnostics(
    r: &TraceMomentResult,
    loo: Option<(&[TraceMomentResult], bool)>,
) -> Vec<String> {
    let mut w = Vec::new();
    let factor = match loo {
        Some((_, true)) => TILE_ERROR_FACTOR,
        _ => 1.0,
    };
    let jk = |f: &dyn Fn(&TraceMomentResult) -> f64| {
        loo.map_or(f64::NAN, |(l, _)| {
            crate::stats::jackknife_se(&l.iter().map(f).collect::<Vec<_>>())
        })
    };
    // 0. no universal fit: say why, as the CLI refuses such a q grid
    if !r.alpha.is_finite() {
        let usable =
            r.q.iter()
                .filter(|&&q| q > 0.0 && q <= FIRST_UNIVERSAL_Q_MAX)
                .count();
        w.push(format!(
            "alpha and C1 are not estimated: the universal fit starts over \
             0 < q <= {FIRST_UNIVERSAL_Q_MAX} and needs 3 or more orders there ({usable} given{})",
            if usable >= 3 {
                "; or fewer than 3 below q_fit_max or q_s/2"
            } else {
                ""
            }
        ));
    }
    let half_beta = r.beta_stderr.map_or(0.0, |b| b / 2.0);
    let d = r.diff_order;
    let fix = |h: f64| format!("--diff-order {h:.2} (FluxDiff::Order in the library)");
    // 1. the differentiation against the spectral H
    let mut too_smooth = false;
    if let Some(h) = r.h {
        // the error as reported, not doubled for tiles: near H = 1 a false
        // alarm costs nothing (the order it advises, H, is the one auto
        // aims at), a missed one biases K; without a jackknife, the
        // spectrum fit's share of the error alone
        let se = r.h_stderr.unwrap_or(half_beta);
        let bound = match r.diff {
            FluxDiff::Auto | FluxDiff::None => 1.0,
            FluxDiff::Order(o) => 1.0 + o,
        };
        let z = (h - bound) / se;
        if se > 0.0 && z > WARN_Z {
            too_smooth = true;
            let hsf = r.h_sf.map_or("n/a".into(), |v| format!("{v:.3}"));
            w.push(match r.diff {
                FluxDiff::Auto => format!(
                    "the spectral H = {h:.3} exceeds 1 by {z:.1} errors of {se:.3}: first \
                     differences cannot resolve H > 1 (H_sf = xi(1) = {hsf} saturates), so the \
                     automatic differentiation (--diff-order auto, of order xi(1) = {d:.3}) is \
                     too low: it leaves the modulus 1 + {d:.3} - H = {e:.2} orders in excess of \
                     H instead of 1 (TM §5.2), which biases K(q), alpha and C1; give the \
                     order: {f}",
                    e = 1.0 + d - h,
                    f = fix(h)
                ),
                _ => format!(
                    "the spectral H = {h:.3} exceeds {bound:.3}, the order of the flux's \
                     differentiation (the modulus' 1 plus {d}), by {z:.1} errors of {se:.3}: \
                     the modulus acts on a fractional integral of the flux, not on the flux \
                     (TM §5.2 asks for an order H or more); give {f}",
                    f = fix(h)
                ),
            });
        }
    }
    // 5. (said first: 2. refers to it) planes that move H_sf by more than
    // its error: the numbers, not a verdict (a tilt and a rough surface's
    // own large scales both make planes, and one image cannot tell them
    // apart; the spectral H, whose spectrum removes a plane, is a guide)
    let plane = match (r.h_sf, r.h_sf_plane_shift) {
        (Some(hsf), Some(e))
            if r.detrend == Trend::None
                && e > r.h_sf_stderr.filter(|s| s.is_finite()).unwrap_or(0.01) =>
        {
            let k = r.planes_over_half;
            w.push(format!(
                "the least-squares plane explains more than half the variance of {}: without \
                 {} H_sf = xi(1) = {hsf:.3} would read about {:.3}{}. A regional slope \
                 c adds c l to every increment at lag l{}, but a rough surface's own large \
                 scales make planes too, and removing those lowers H_sf: for a tilted \
                 surface rerun with --detrend plane (TraceMomentConfig::detrend), otherwise \
                 keep the planes",
                if r.images == 1 {
                    "the image".to_string()
                } else {
                    format!("{k} of the {} images", r.images)
                },
                if r.images == 1 {
                    "its plane"
                } else {
                    "their planes"
                },
                hsf - e,
                r.h.map_or(String::new(), |h| format!(
                    " (the spectral H, whose spectrum removes a plane of its own: {h:.3})"
                )),
                if r.diff == FluxDiff::Auto {
                    " and raises the automatic --diff-order"
                } else {
                    ""
                }
            ));
            true
        }
        _ => false,
    };
    // 2. the two estimates of H (1. already says why they part when H > 1)
    if let (Some(h), Some(hsf), false) = (r.h, r.h_sf, too_smooth) {
        let diff = |x: &TraceMomentResult| x.h.unwrap_or(f64::NAN) - x.h_sf.unwrap_or(f64::NAN);
        let se = factor
            * match loo {
                // tiles share the spectrum: its fit error comes on top
                Some((_, true)) => jk(&diff).hypot(half_beta),
                Some((_, false)) => jk(&diff),
                None => {
                    let i = r.sf_q.iter().position(|&q| (q - 1.0).abs() < 1e-12);
                    i.map_or(f64::NAN, |i| r.xi_stderr[i]).hypot(half_beta)
                }
            };
        let z = (h - hsf) / se;
        if se > 0.0 && z.abs() > WARN_Z {
            let why = if h > hsf && h > 1.0 {
                ": first differences saturate, and H_sf cannot follow an H above 1".to_string()
            } else if plane {
                ": the plane (the warning above) may be why".to_string()
            } else {
                // finite-range biases of the two estimators on FIF fields
                // of 1024^2 (helper study 2026-11-29, 6-12 ensembles per H):
                // the generator's pixel-scale spectrum steepens beta (exact
                // expectation 2.2069 against 2.1777 at H = 0.7), and xi(1)
                // of first differences bends with the lag; neither is a
                // defect, and the jackknife errors resolve them
                ": a fit range misses the scaling of the spectrum or of the structure \
                 functions (--k-range, --lag-fit), or the two estimators' finite-range \
                 biases part them, which no fit range removes (on universal multifractal \
                 fields of 1024^2 the spectral H less H_sf reads -0.01 at H = 0.4, +0.04 \
                 at 0.7, +0.12 at 0.95)"
                    .to_string()
            };
            let auto = if r.diff == FluxDiff::Auto {
                format!(
                    "; the automatic differentiation follows xi(1): if the spectral H is the \
                     right one, give {}",
                    fix(h)
                )
            } else {
                String::new()
            };
            w.push(format!(
                "the spectral H = {h:.3} and H_sf = xi(1) = {hsf:.3} differ by {:+.3}, {:.1} \
                 errors of {se:.3}, though both estimate H (xi(1) = H - K(1) = H, TM eq \
                 10){why}{auto}",
                h - hsf,
                z.abs(),
            ));
        }
    }
    // 3. straightness of the moment lines over the fitted scales
    if let Some((l, _)) = loo {
        let (lo, hi) = r.fit_log2_lambda;
        let change = |x: &TraceMomentResult, iq: usize| {
            let (xs, ys): (Vec<f64>, Vec<f64>) = x
                .log2_lambda
                .iter()
                .zip(&x.log2_moments[iq])
                .filter(|(a, _)| **a >= lo - 1e-9 && **a <= hi + 1e-9)
                .map(|(a, b)| (*a, *b))
                .unzip();
            crate::stats::fit::slope_change(&xs, &ys).unwrap_or(f64::NAN)
        };
        // (change, error) per q of the universal fit
        let tested: Vec<Option<(f64, f64)>> = (0..r.q.len())
            .map(|iq| {
                if !(r.q[iq] > 0.0 && r.q[iq] <= r.universal_q_max + 1e-9) {
                    return None;
                }
                let c = change(r, iq);
                let loo_c: Vec<f64> = l.iter().map(|x| change(x, iq)).collect();
                let se = factor * crate::stats::jackknife_se(&loo_c);
                (c.is_finite() && se > 0.0).then_some((c, se))
            })
            .collect();
        // every q is a test: the false alarm of WARN_Z shared among them
        // (Bonferroni; 3.9 errors for 25 q), else one q in a long grid
        // would speak by chance (the 3-error rule flagged 3-4 of 24 single
        // topo-fif fields)
        let m = tested.iter().flatten().count().max(1) as f64;
        let z_m =
            statrs::distribution::Normal::standard().inverse_cdf(1.0 - normal_tail(WARN_Z) / m);
        let bent: Vec<Option<(f64, f64)>> = tested
            .iter()
            .map(|t| t.and_then(|(c, se)| (c.abs() > z_m * se).then_some((c, c.abs() / se))))
            .collect();
        for (first, last, worst) in
            crate::stats::fit::flagged_runs(&bent, |x: (f64, f64)| x.0.abs())
        {
            let (c, z) = bent[worst].unwrap_or((f64::NAN, f64::NAN));
            // the grid's q to 6 decimals (0.30000000000000004 reads 0.3)
            let qs = |i: usize| format!("{}", (r.q[i] * 1e6).round() / 1e6);
            let (label, most) = if last > first {
                (
                    format!("q = {} .. {}", qs(first), qs(last)),
                    format!("up to {c:+.3} (at q = {}, {z:.1} errors)", qs(worst)),
                )
            } else {
                (
                    format!("q = {}", qs(first)),
                    format!("{c:+.3} ({z:.1} errors)"),
                )
            };
            w.push(format!(
                "{label}: log2 <phi_lambda^q> is not a straight line over the fitted scales \
                 (log2 lambda {lo}..{hi}): its local slope changes by {most} across them, so \
                 K(q), and alpha and C1 with it, depend on the scales fitted (--lambda-fit)"
            ));
        }
    }
    // 4. the GLS and OLS universal fits apart: both fit C1/(α-1) (q^α - q)
    // to the same K(q), so they part beyond their paired error when K(q)
    // departs from that form and the weighting picks which q it follows
    // (Jacksboro DEM, 6 tiles: 10 errors; two-point cascades: 5.0-9.5).
    // On universal fields the difference read -0.6..1.6 errors (6 topo-fif
    // ensembles of 16 x 256^2) and -0.6..2.7 (8 log-normal cascade
    // ensembles, mean +0.8: the two fits' small biases differ, which a very
    // large ensemble would resolve; hence the message's second reading),
    // those with q = 1 still in the GLS fit; after, none of 12 topo-fif
    // ensembles of 16 x 1024^2 reached 3
    if let Some((l, _)) = loo
        && r.universal_fit.starts_with("gls")
        && r.alpha.is_finite()
        && r.alpha_ols.is_finite()
    {
        let d = r.alpha - r.alpha_ols;
        let se = factor
            * crate::stats::jackknife_se(
                &l.iter().map(|x| x.alpha - x.alpha_ols).collect::<Vec<_>>(),
            );
        if se > 0.0 && (d / se).abs() > WARN_Z {
            w.push(format!(
                "the GLS universal fit gives alpha = {:.3}, the unweighted (OLS) one {:.3}, \
                 {:+.3} apart, {:.1} errors of their difference: K(q) departs from the \
                 universal form over the fitted q, so alpha depends on which q the fit weighs \
                 (--universal-fit, --q-fit-max; on a very large ensemble of a universal field \
                 the two fits' small biases can also part)",
                r.alpha,
                r.alpha_ols,
                d,
                (d / se).abs()
            ));
        }
    }
    w.extend(range_warnings(r));
    w
}

/// Estimates outside what the fits can deliver, said in `warnings` after
/// [`diagnostics`]' tests: alpha at an end of the fit's search interval
/// (no minimum: K(q) is not of the universal form, e.g. the flux of a
/// plane) or outside the universal range [0, 2] (TM §6), C1 < 0 or not
/// distinguishable from 0 (then alpha, the shape of K(q), is free), and
/// the estimates a fit range left empty (β and H, the DTM, `H_sf`).
pub(super) fn range_warnings(r: &TraceMomentResult) -> Vec<String> {
    let mut w = Vec::new();
    let (lo, hi) = fit::ALPHA_SEARCH;
    // a NaN alpha is explained by diagnostics' item 0
    if r.alpha.is_finite() && (r.alpha - lo < 1e-3 || hi - r.alpha < 1e-3) {
        w.push(format!(
            "alpha = {:.3} sits at an end of the universal fit's search interval [{lo}, {hi}]: \
             no minimum was found, so K(q) is not of the universal form C1/(alpha-1) \
             (q^alpha - q) over the fitted q (a smooth or planar field, moments beyond the \
             sampling order q_s = {:.2}, too few scales or images): alpha and C1 are not \
             estimates",
            r.alpha, r.q_s
        ));
    } else if outside_universal(r.alpha, r.alpha_stderr) {
        w.push(format!(
            "alpha = {:.3} +- {:.3} lies outside [0, 2], the range of universal \
             multifractals, by more than 2 errors: K(q) is not of the universal form over the \
             fitted q, or too few scales or images for the fit",
            r.alpha, r.alpha_stderr
        ));
    }
    if r.c1.is_finite() && r.c1 < 0.0 {
        w.push(format!(
            "C1 = {:.4} < 0: no intermittency is resolved",
            r.c1
        ));
    } else if r.c1.is_finite()
        && (r.c1 <= 2.0 * r.c1_stderr || r.k.iter().all(|k| !k.is_finite() || k.abs() < 1e-9))
    {
        // K(q) = C1 x shape(alpha): with C1 ~ 0 the shape, alpha, is free
        w.push(format!(
            "C1 = {:.4} +- {:.4} is not distinguishable from 0 (its error is half of it or \
             more: the intermittency is not resolved), so alpha, the shape of K(q), is \
             undetermined: do not quote it",
            r.c1, r.c1_stderr
        ));
    }
    if r.beta.is_none() {
        w.push(
            "beta and H not estimable: fewer than 3 spectrum bins in the k range \
             (images too small for the default range, or a --k-range holding too few)"
                .to_string(),
        );
    }
    for d in r.dtm.iter().filter(|d| d.n < 3) {
        w.push(format!(
            "DTM at q = {}: {} usable eta value(s) (K(q, eta) of the sign of K(q), eta in the \
             fit range, q eta <= q_s/2): {}",
            d.q,
            d.n,
            if d.n < 2 {
                "no fit (--eta, --eta-fit)"
            } else {
                "a line through two points"
            }
        ));
    }
    if outside_universal(r.dtm_alpha, r.dtm_alpha_stderr) {
        w.push(format!(
            "DTM alpha = {:.3} +- {:.3} lies outside [0, 2] by more than 2 errors: too few \
             scales or images",
            r.dtm_alpha, r.dtm_alpha_stderr
        ));
    }
    if r.h_sf.is_none() && r.sf_q.iter().any(|&q| (q - 1.0).abs() < 1e-12) {
        w.push(
            "H_sf = xi(1) not estimable: no line through the structure function of order 1 \
             over the lag fit range (--lag-fit)"
                .to_string(),
        );
    }
    w
}

/// True when `alpha` lies outside the universal [0, 2] (TM §6) by more
/// than 2 of its errors (by any amount without an error): a log-normal
/// field's estimates scatter either side of 2 (6 of 12 single 128^2 FIF
/// with alpha = 2 read 2.005-2.025, within one error, and were warned
/// about before).
pub(super) fn outside_universal(alpha: f64, se: f64) -> bool {
    let se = if se.is_finite() { se } else { 0.0 };
    alpha.is_finite() && (alpha > 2.0 + 2.0 * se || alpha < -2.0 * se)
}

/// `P(Z > z)` for a standard normal `Z`.
pub(super) fn normal_tail(z: f64) -> f64 {
    1.0 - statrs::distribution::Normal::standard().cdf(z)
}
