//! From accumulated moments to K(q), alpha, C1, H: the regressions over
//! the scale ratios, the universal fit (plain or GLS), the ensemble and
//! jackknife finishes.

use super::*;

impl TraceMomentAccumulator {
    /// Exponents, fits and tables from the accumulated sums.
    ///
    /// **Errors** with no image, a flux identically 0 (constant field),
    /// fewer than 3 levels in the fit range, or settings that fail
    /// [`TraceMomentFitConfig::validate`].
    ///
    /// The universal fit is OLS here: GLS, the default
    /// [`TraceMomentFitConfig::universal`], needs the jackknife parts of
    /// [`finish_jackknife`] (or [`analyze_tiled`], [`finish_ensemble`]);
    /// `universal_fit` then says so.
    pub fn finish(&self, fc: &TraceMomentFitConfig) -> Result<TraceMomentResult> {
        let mut r = self.finish_inner(fc, None)?;
        if fc.universal == UniversalWeighting::Gls {
            r.universal_fit = "ols (unweighted least squares in K; gls needs jackknife parts: \
                               finish_jackknife)"
                .into();
        }
        r.warnings = diagnostics(&r, None);
        Ok(r)
    }

    /// [`Self::finish`], optionally with the universal-fit bound and `q_s`
    /// pinned to `pin = (q_hi, q_s)` (the jackknife keeps the full
    /// ensemble's q range: the rule for q_s depends on the image count).
    pub(super) fn finish_inner(
        &self,
        fc: &TraceMomentFitConfig,
        pin: Option<(f64, f64)>,
    ) -> Result<TraceMomentResult> {
        fc.validate()?;
        self.check()?;
        if self.images == 0 || self.n_valid == 0 {
            return Err(Error::Input("no image accumulated".into()));
        }
        let lnm = self.phi_sum.ln() - (self.n_valid as f64).ln();
        if !lnm.is_finite() {
            return Err(Error::Input(
                "the flux is 0 everywhere (constant field?)".into(),
            ));
        }
        let log2_lambda = self.log2_lambda();
        let (lo, hi) = fc.lambda_range(self.box_count.len().saturating_sub(1))?;
        let kmax = log2_lambda.first().copied().unwrap_or(0.0);
        let in_range: Vec<bool> = log2_lambda
            .iter()
            .map(|&x| x >= lo - 1e-9 && x <= hi + 1e-9)
            .collect();
        let fit_line = |y: &[f64]| {
            let xs: Vec<f64> = log2_lambda
                .iter()
                .zip(&in_range)
                .filter(|(_, b)| **b)
                .map(|(x, _)| *x)
                .collect();
            let ys: Vec<f64> = y
                .iter()
                .zip(&in_range)
                .filter(|(_, b)| **b)
                .map(|(v, _)| *v)
                .collect();
            line_fit(&xs, &ys)
        };
        // trace moments
        let q = self.config.q.clone();
        let mut log2_m = Vec::with_capacity(q.len());
        let (mut kq, mut kse, mut kb) = (Vec::new(), Vec::new(), Vec::new());
        for (iq, &qq) in q.iter().enumerate() {
            let m = self.log2_moments(&self.tm[iq], qq, lnm);
            let f = fit_line(&m);
            kq.push(f.map_or(f64::NAN, |f| f.slope));
            kse.push(f.map_or(f64::NAN, |f| f.slope_stderr));
            kb.push(f.map_or(f64::NAN, |f| f.intercept));
            log2_m.push(m);
        }
        // universal fit and q_s (module docs)
        let lambda_max = 2f64.powf(kmax);
        let qcap = fc.q_fit_max.unwrap_or(f64::INFINITY);
        let fit_below = |qhi: f64| {
            let (qs_, ks_): (Vec<f64>, Vec<f64>) = q
                .iter()
                .zip(&kq)
                .filter(|(a, _)| **a > 0.0 && **a < qhi + 1e-12 && **a <= qcap + 1e-12)
                .map(|(a, b)| (*a, *b))
                .unzip();
            fit_universal(&qs_, &ks_)
        };
        let mut uni = fit_below(pin.map_or(FIRST_UNIVERSAL_Q_MAX, |p| p.0));
        let mut q_s = pin.map_or(f64::INFINITY, |p| p.1);
        let mut q_d = f64::INFINITY;
        let mut q_hi = pin.map_or(FIRST_UNIVERSAL_Q_MAX, |p| p.0);
        for _ in 0..3 {
            let Some(u) = uni else { break };
            let uk = UniversalK::new(u.alpha.min(2.0), u.c1.max(0.0));
            q_d = uk.q_divergence(D);
            if pin.is_some() {
                break;
            }
            q_s = uk.q_sampling(D, self.images as f64, lambda_max).min(q_d);
            q_hi = 0.5 * q_s;
            uni = fit_below(q_hi).or(uni);
        }
        let q_hi = q_hi.min(qcap).min(q.iter().copied().fold(0.0, f64::max));
        let q_s_empirical = uni.and_then(|u| linear_onset(&q, &kq, &u));
        // effective outer scale: common zero of the fitted lines
        let (mut skb, mut skk) = (0.0, 0.0);
        for ((&qq, &k), &b) in q.iter().zip(&kq).zip(&kb) {
            if qq > 0.0 && qq < q_s && k.is_finite() && b.is_finite() {
                skb += k * b;
                skk += k * k;
            }
        }
        let log2_lambda_eff = if skk > 0.0 { -skb / skk } else { f64::NAN };
        // double trace moments
        let eta = self.config.eta.clone();
        let mut k_eta = vec![vec![f64::NAN; eta.len()]; self.config.dtm_q.len()];
        let mut k_eta_se = k_eta.clone();
        let mut log2_m_eta = vec![vec![Vec::new(); eta.len()]; self.config.dtm_q.len()];
        for ie in 0..eta.len() {
            let lnm_e = self.eta_sum[ie].ln() - (self.n_valid as f64).ln();
            for (iq, &qq) in self.config.dtm_q.iter().enumerate() {
                let m = self.log2_moments(&self.dtm[ie][iq], qq, lnm_e);
                if let Some(f) = fit_line(&m) {
                    k_eta[iq][ie] = f.slope;
                    k_eta_se[iq][ie] = f.slope_stderr;
                }
                log2_m_eta[iq][ie] = m;
            }
        }
        let mut dtm = Vec::new();
        for (iq, &qq) in self.config.dtm_q.iter().enumerate() {
            let (xs, ys): (Vec<f64>, Vec<f64>) = eta
                .iter()
                .zip(&k_eta[iq])
                .filter(|(e, k)| {
                    **e >= fc.eta.0 - 1e-12
                        && **e <= fc.eta.1 + 1e-12
                        // the moments of φ^η are of order qη (and η
                        // for its normalisation): the same q_s/2 bound as
                        // the universal fit, below which they are unbiased
                        && qq * **e <= 0.5 * q_s
                        && **e <= 0.5 * q_s
                        // K(q, η) has the sign of K(q): negative for q < 1
                        // (conservation makes K(1) = 0); a value of the
                        // other sign is noise, not a point of the power law
                        && k.is_finite()
                        && **k * (qq - 1.0) > 0.0
                })
                .map(|(e, k)| (e.ln(), k.abs().ln()))
                .unzip();
            let f = line_fit(&xs, &ys);
            let used = |pick: fn(f64, f64) -> f64| xs.iter().copied().reduce(pick).map(f64::exp);
            let eta_used = (
                used(f64::min).unwrap_or(f64::NAN),
                used(f64::max).unwrap_or(f64::NAN),
            );
            dtm.push(match f {
                Some(f) => {
                    let shape = universal_shape(f.slope, qq).abs();
                    DtmFit {
                        q: qq,
                        alpha: f.slope,
                        alpha_stderr: f.slope_stderr,
                        c1: if shape > 0.0 {
                            f.intercept.exp() / shape
                        } else {
                            f64::NAN
                        },
                        n: f.n,
                        eta_used,
                    }
                }
                None => DtmFit {
                    q: qq,
                    alpha: f64::NAN,
                    alpha_stderr: f64::NAN,
                    c1: f64::NAN,
                    n: 0,
                    eta_used: (f64::NAN, f64::NAN),
                },
            });
        }
        // structure functions
        let nj = self.sf_count.len();
        let log2_lag: Vec<f64> = (0..nj).map(|j| j as f64).collect();
        let (llo, lhi) = fc.lag_range(kmax as usize, nj)?;
        let mut log2_sf = Vec::new();
        let (mut xi, mut xi_se, mut xi_b) = (Vec::new(), Vec::new(), Vec::new());
        for (iq, _) in self.config.sf_q.iter().enumerate() {
            let s: Vec<f64> = (0..nj)
                .map(|j| {
                    let c = self.sf_count[j];
                    if c == 0 {
                        f64::NAN
                    } else {
                        (self.sf[iq][j].ln() - (c as f64).ln()) / std::f64::consts::LN_2
                    }
                })
                .collect();
            let (xs, ys): (Vec<f64>, Vec<f64>) = log2_lag
                .iter()
                .zip(&s)
                .filter(|(x, _)| **x >= llo - 1e-9 && **x <= lhi + 1e-9)
                .map(|(x, y)| (*x, *y))
                .unzip();
            let f = line_fit(&xs, &ys);
            xi.push(f.map_or(f64::NAN, |f| f.slope));
            xi_se.push(f.map_or(f64::NAN, |f| f.slope_stderr));
            xi_b.push(f.map_or(f64::NAN, |f| f.intercept));
            log2_sf.push(s);
        }
        let h_sf = self
            .config
            .sf_q
            .iter()
            .position(|&v| (v - 1.0).abs() < 1e-12)
            .map(|i| xi[i])
            .filter(|v| v.is_finite());
        // spectrum -> β -> H
        let k2 = uni.map(|u| u.c1 * universal_shape(u.alpha, 2.0));
        let spec = match &self.spectrum {
            Some(ps) => {
                let (klo, khi) = fc.k_range.unwrap_or_else(|| default_k_range(self.max_side));
                ps.fit(klo, khi).ok()
            }
            None => None,
        };
        let beta_averaged = spec.map(|s| s.beta);
        let beta = beta_averaged.map(|b| b - 1.0);
        let h_spec = match (beta, k2) {
            (Some(b), Some(k2)) => Some((b - 1.0 + k2) / 2.0),
            _ => None,
        };
        let nan = f64::NAN;
        let (do_mean, do_sd) = mean_std(&self.diff_orders);
        Ok(TraceMomentResult {
            images: self.images,
            flux: self.config.flux,
            diff: self.config.diff,
            diff_order: do_mean,
            diff_order_sd: do_sd,
            detrend: self.config.detrend,
            plane_share: crate::skeleton::median(
                &self.planes.iter().filter_map(|p| p.share).collect::<Vec<_>>(),
            ),
            h_sf_plane_shift: {
                // over every field with a share (the pooled structure
                // functions average them all), 0 for those at or below half
                let n = self.planes.iter().filter(|p| p.share.is_some()).count();
                let d: Vec<f64> = self
                    .planes
                    .iter()
                    .filter_map(|p| p.h_sf.map(|[raw, flat]| raw - flat))
                    .collect();
                (!d.is_empty()).then(|| d.iter().sum::<f64>() / n.max(d.len()) as f64)
            },
            planes_over_half: self.planes.iter().filter(|p| p.h_sf.is_some()).count(),
            frac_int: self.config.frac_int,
            q,
            k: kq,
            k_stderr: kse,
            k_intercept: kb,
            log2_lambda,
            log2_moments: log2_m,
            fit_log2_lambda: (lo, hi),
            alpha: uni.map_or(nan, |u| u.alpha),
            alpha_stderr: uni.map_or(nan, |u| u.alpha_stderr),
            alpha_stderr_fit: uni.map_or(nan, |u| u.alpha_stderr),
            c1: uni.map_or(nan, |u| u.c1),
            c1_stderr: uni.map_or(nan, |u| u.c1_stderr),
            c1_stderr_fit: uni.map_or(nan, |u| u.c1_stderr),
            stderr_method: "regression residuals only (no ensemble scatter)".into(),
            universal_fit: "ols (unweighted least squares in K)".into(),
            universal_shrinkage: None,
            alpha_ols: uni.map_or(nan, |u| u.alpha),
            c1_ols: uni.map_or(nan, |u| u.c1),
            jackknife_groups: 0,
            universal_n: uni.map_or(0, |u| u.n),
            q_s,
            q_s_rule: "q_s = min(((2 + D_s)/C1)^(1/alpha), q_D), D_s = ln(images)/ln(L); universal fit over 0 < q <= q_s/2".into(),
            universal_q_max: q_hi,
            q_s_empirical,
            q_d,
            log2_lambda_eff,
            lambda_eff: log2_lambda_eff.exp2(),
            outer_scale_px: (kmax - log2_lambda_eff).exp2(),
            eta,
            dtm_q: self.config.dtm_q.clone(),
            k_eta,
            k_eta_stderr: k_eta_se,
            log2_moments_eta: log2_m_eta,
            dtm_eta_range: fc.eta,
            dtm_alpha: dtm.first().map_or(nan, |d| d.alpha),
            dtm_alpha_stderr: dtm.first().map_or(nan, |d| d.alpha_stderr),
            dtm_c1: dtm.first().map_or(nan, |d| d.c1),
            dtm_c1_stderr: nan,
            dtm,
            sf_q: self.config.sf_q.clone(),
            xi,
            xi_stderr: xi_se,
            xi_intercept: xi_b,
            log2_lag,
            log2_sf,
            fit_log2_lag: (llo, lhi),
            h: h_spec,
            h_stderr: None,
            h_sf,
            h_sf_stderr: None,
            beta,
            beta_averaged,
            beta_stderr: spec.map(|s| s.beta_stderr),
            beta_stderr_method: "regression (the spectrum's fit)".into(),
            beta_convention: "angle-integrated (beta_averaged = beta + 1)".into(),
            k_range: spec.map(|s| s.k_range),
            warnings: Vec::new(),
            surrogates: None,
        })
    }
}

/// First grid `q > 1` from which on the measured `K''` stays below a
/// quarter of the universal fit's `K''` (TM eq 15: K linear beyond q_s).
pub(super) fn linear_onset(q: &[f64], k: &[f64], u: &UniversalFit) -> Option<f64> {
    let pts: Vec<(f64, f64)> = q
        .iter()
        .zip(k)
        .filter(|(_, b)| b.is_finite())
        .map(|(a, b)| (*a, *b))
        .collect();
    if pts.len() < 4 {
        return None;
    }
    let model_d2 = |x: f64| {
        if (u.alpha - 1.0).abs() < 1e-6 {
            u.c1 / x
        } else {
            u.c1 * u.alpha * x.powf(u.alpha - 2.0)
        }
    };
    let mut onset = None;
    for i in 1..pts.len() - 1 {
        let (q0, k0) = pts[i - 1];
        let (q1, k1) = pts[i];
        let (q2, k2) = pts[i + 1];
        let d2 = ((k2 - k1) / (q2 - q1) - (k1 - k0) / (q1 - q0)) / (0.5 * (q2 - q0));
        let linear = d2 < 0.25 * model_d2(q1);
        if q1 > 1.0 && linear {
            if onset.is_none() {
                onset = Some(q1);
            }
        } else {
            onset = None;
        }
    }
    onset
}

/// Merges per-image (or per-group) accumulators into the annealed ensemble
/// and finishes it, with **jackknife** standard errors over the parts when
/// there are at least 2: each part is left out in turn (same fit ranges,
/// same q range and q_s as the full ensemble), and for every estimate θ
/// `se² = (n-1)/n Σ (θ_(i) - mean θ_(.))²` (Efron & Tibshirani 1993, §11).
/// The regression errors of a single ensemble fit only see the residuals
/// of K(q) about the universal curve, whereas the K(q) of neighbouring q are
/// almost perfectly correlated and share the sampling fluctuations of the
/// ensemble: on 4 independent 16 x 1024² topo-fif ensembles α scattered by
/// 0.1 for a stated fit error of 0.003. The jackknife sees that scatter.
/// Replaced: `alpha_stderr`, `C1_stderr`, `K_stderr`, `xi_stderr`, `dtm_alpha_stderr`
/// (and the first DTM fit's), `beta_stderr`; added `H_stderr`,
/// `H_sf_stderr`. With one part the regression errors are kept and
/// `stderr_method` says so.
///
/// **Errors** with no part, parts with different settings, or as
/// [`TraceMomentAccumulator::finish`].
pub fn finish_ensemble(
    parts: &[TraceMomentAccumulator],
    fc: &TraceMomentFitConfig,
) -> Result<(TraceMomentAccumulator, TraceMomentResult)> {
    let Some(first) = parts.first() else {
        return Err(Error::Input("no image accumulated".into()));
    };
    let mut all = TraceMomentAccumulator::new(first.config.clone())?;
    for p in parts {
        all.merge(p)?;
    }
    let res = finish_jackknife(&all, parts, fc, "images")?;
    Ok((all, res))
}

/// The result of `whole` with jackknife errors over `parts` (whose merge
/// must reproduce `whole` over the fitted scales: the images of an
/// ensemble, or the tiles of [`TraceMomentAccumulator::field_tiles`];
/// `what` names them in `stderr_method`). See [`finish_ensemble`]. A block
/// jackknife over the tiles of one image treats the tiles as independent;
/// the long-range correlations of a cascade make that an underestimate of
/// the error of the single image, though far closer than the regression.
/// The universal fit is `fc.universal` (GLS by default); the `tm` command
/// fits tiles by OLS unless told otherwise (README, "Trace moments: fitting
/// alpha (GLS)": on a real DEM the two fits part by 6 errors, while on
/// synthetic universal multifractals both tile errors are about the
/// scatter).
///
/// **Errors** as [`TraceMomentAccumulator::finish`] or on parts with other
/// settings.
pub fn finish_jackknife(
    whole: &TraceMomentAccumulator,
    parts: &[TraceMomentAccumulator],
    fc: &TraceMomentFitConfig,
    what: &str,
) -> Result<TraceMomentResult> {
    let mut res = whole.finish(fc)?;
    let n = parts.len();
    if n < 2 {
        res.stderr_method = "regression residuals only (one part: no ensemble scatter; \
                             understates the error)"
            .into();
        if fc.universal == UniversalWeighting::Gls {
            res.universal_fit =
                "ols (unweighted least squares in K; gls not possible: one part)".into();
        }
        return Ok(res);
    }
    let pin = Some((res.universal_q_max, res.q_s));
    let mut loo = Vec::with_capacity(n);
    for i in 0..n {
        let mut a = TraceMomentAccumulator::new(whole.config.clone())?;
        for (j, p) in parts.iter().enumerate() {
            if j != i {
                a.merge(p)?;
            }
        }
        let fc_rep = replicate_fit(
            fc,
            &res,
            whole,
            &a,
            &format!("part {} of {n} ({what})", i + 1),
        )?;
        loo.push(a.finish_inner(&fc_rep, pin)?);
    }
    if fc.universal == UniversalWeighting::Gls {
        gls_refit(&mut res, &mut loo, whole, parts, fc, pin, what)?;
    }
    let jk = |f: &dyn Fn(&TraceMomentResult) -> f64| -> f64 {
        crate::stats::jackknife_se(&loo.iter().map(f).collect::<Vec<_>>())
    };
    res.alpha_stderr = jk(&|r| r.alpha);
    res.c1_stderr = jk(&|r| r.c1);
    res.dtm_alpha_stderr = jk(&|r| r.dtm_alpha);
    res.dtm_c1_stderr = jk(&|r| r.dtm_c1);
    for (id, d) in res.dtm.iter_mut().enumerate() {
        d.alpha_stderr = jk(&|r| r.dtm[id].alpha);
    }
    for (iq, se) in res.k_stderr.iter_mut().enumerate() {
        *se = jk(&|r| r.k[iq]);
    }
    // the structure functions' exponents likewise (a fit of 2 lags has no
    // regression error, and the printed H_sf had its jackknife one)
    for (iq, se) in res.xi_stderr.iter_mut().enumerate() {
        *se = jk(&|r| r.xi[iq]);
    }
    let opt = |f: &dyn Fn(&TraceMomentResult) -> Option<f64>| {
        let s = jk(&|r| f(r).unwrap_or(f64::NAN));
        s.is_finite().then_some(s)
    };
    // the tiles of one image share its spectrum: beta has no scatter over
    // them (only rounding), so it keeps its fit error, and H = (beta - 1 +
    // K(2)) / 2 gets half of it on top of its scatter, which is K(2)'s alone
    let shared = parts.iter().all(|p| p.spectrum == parts[0].spectrum);
    if shared {
        res.h_stderr = match res.beta_stderr {
            Some(b) => opt(&|r| r.h).map(|h| h.hypot(b / 2.0)),
            None => opt(&|r| r.h),
        };
    } else {
        res.beta_stderr = opt(&|r| r.beta);
        res.h_stderr = opt(&|r| r.h);
    }
    res.h_sf_stderr = opt(&|r| r.h_sf);
    res.stderr_method = format!("jackknife over {n} {what} (leave one out)");
    if !shared {
        res.beta_stderr_method = res.stderr_method.clone();
    }
    res.jackknife_groups = n;
    res.warnings = diagnostics(&res, Some((&loo, shared)));
    Ok(res)
}

/// The fit settings of a jackknife replicate `rep` of `whole`, whose
/// result is `res`: the whole's boxes, lags and wavenumbers. A part left out
/// may hold the only boxes of the largest size (images of several sizes),
/// and log2 λ counts from a replicate's own largest box, so its range
/// shifts by the levels it lacks; a default range would otherwise follow
/// the replicate's sizes and fit other scales.
///
/// **Errors** when the fitted boxes are missing from `rep` (`left_out`
/// names the part left out).
pub(super) fn replicate_fit(
    fc: &TraceMomentFitConfig,
    res: &TraceMomentResult,
    whole: &TraceMomentAccumulator,
    rep: &TraceMomentAccumulator,
    left_out: &str,
) -> Result<TraceMomentFitConfig> {
    let kmax = whole.box_count.len().saturating_sub(1);
    let (lo, hi) = res.fit_log2_lambda;
    let d = kmax.saturating_sub(rep.box_count.len().saturating_sub(1)) as f64;
    lone_box_check(kmax, lo, d, left_out)?;
    // the lags the whole fitted (fluxes given directly have no structure
    // functions; a range reaching beyond the whole's lags fits those it has,
    // and one holding fewer than 2 fits none, which pins nothing)
    let log2_lag = match fitted_lags(res.fit_log2_lag, whole.sf_count.len()) {
        Some(r) if !res.log2_lag.is_empty() => {
            lone_lag_check(r.1, rep.sf_count.len(), left_out)?;
            Some(r)
        }
        _ => fc.log2_lag,
    };
    Ok(TraceMomentFitConfig {
        // levels below 0 do not exist: a fractional start stays on the same
        // integer levels
        log2_lambda: Some(((lo - d).max(0.0), hi - d)),
        log2_lag,
        k_range: res.k_range.or(fc.k_range),
        ..fc.clone()
    })
}

/// The part of a lag range `(lo, hi)` (log2 l) on the `nj` lags `0..nj`
/// that holds 2 lags or more, `None` if it holds fewer.
pub(super) fn fitted_lags((lo, hi): (f64, f64), nj: usize) -> Option<(f64, f64)> {
    let hi = hi.min(nj as f64 - 1.0);
    ((hi - lo.ceil()) >= 1.0 - 1e-9).then_some((lo, hi))
}

/// The q indices of the universal fit: `0 < q <= q_hi` (and `q_fit_max`),
/// as in [`TraceMomentAccumulator::finish`].
pub(super) fn universal_indices(q: &[f64], q_hi: f64, fc: &TraceMomentFitConfig) -> Vec<usize> {
    let qcap = fc.q_fit_max.unwrap_or(f64::INFINITY);
    q.iter()
        .enumerate()
        .filter(|(_, a)| **a > 0.0 && **a < q_hi + 1e-12 && **a <= qcap + 1e-12)
        .map(|(i, _)| i)
        .collect()
}

/// Sets α and C1 of `r` (and what follows from them: the spectral H, q_D,
/// the empirical q_s) from the universal fit `u`.
pub(super) fn apply_universal(r: &mut TraceMomentResult, u: &UniversalFit) {
    r.alpha = u.alpha;
    r.c1 = u.c1;
    r.alpha_stderr_fit = u.alpha_stderr;
    r.c1_stderr_fit = u.c1_stderr;
    r.universal_n = u.n;
    r.q_d = UniversalK::new(u.alpha.min(2.0), u.c1.max(0.0)).q_divergence(D);
    r.q_s_empirical = linear_onset(&r.q, &r.k, u);
    let k2 = u.c1 * universal_shape(u.alpha, 2.0);
    r.h = r.beta.map(|b| (b - 1.0 + k2) / 2.0);
}

/// Inverse of the shrunk jackknife covariance of K over `idx`, from the
/// leave-one-out results `reps` (`(W, λ)`; `Err` says why not).
pub(super) fn gls_weights(
    reps: &[TraceMomentResult],
    idx: &[usize],
) -> std::result::Result<(Vec<Vec<f64>>, f64), &'static str> {
    let v: Vec<Vec<f64>> = reps
        .iter()
        .map(|r| idx.iter().map(|&i| r.k[i]).collect())
        .collect();
    let sc = jackknife_covariance_shrunk(&v).ok_or("K(q) without jackknife scatter")?;
    let w = spd_inverse(&sc.cov).ok_or("covariance not positive definite")?;
    Ok((w, sc.lambda))
}

/// The generalised-least-squares universal fit (module docs, "Universal
/// fit"). The weight matrix is the inverse of the jackknife covariance of
/// K(q) over the fitted q, correlations shrunk by the Schäfer-Strimmer
/// intensity; the whole ensemble is fitted with the one from the
/// leave-one-out results `loo`. For honest errors the weights are
/// re-estimated inside every leave-one-out sample from its own n - 1
/// leave-one-out samples (a nested jackknife, n(n-1) finishes): held fixed,
/// they would be tuned to the very fluctuations the jackknife should see
/// (on 11 topo-fif ensembles the fixed-weight error was 0.027 against a
/// scatter of 0.043, nested 0.047, with q = 1 still in the fit and the
/// mirrored flux; now nested 0.041 against 0.039). Keeps the OLS fit (and says why in
/// `universal_fit`) with fewer than 5 parts, fewer than 3 q values besides q = 1, or a
/// covariance that cannot be inverted.
pub(super) fn gls_refit(
    res: &mut TraceMomentResult,
    loo: &mut [TraceMomentResult],
    whole: &TraceMomentAccumulator,
    parts: &[TraceMomentAccumulator],
    fc: &TraceMomentFitConfig,
    pin: Option<(f64, f64)>,
    what: &str,
) -> Result<()> {
    let n = parts.len();
    // q = 1 is left out: the universal K and both its derivatives vanish
    // there (TM eq 8), so its only effect would be through the covariance,
    // as a control variate on K(1) - 0. That residual is no fluctuation of
    // the fitted parameters: rounding on a torus, where K(1) = 0 in every
    // sample (its variance ~1e-33 got weights ~1e33; alpha moved by 0.009
    // when the fields were scaled), and the edge boxes' drift on a plane.
    // OLS is unchanged by the point (zero Jacobian).
    let fitted = universal_indices(&res.q, res.universal_q_max, fc);
    let is_one = |i: usize| (res.q[i] - 1.0).abs() <= 1e-9;
    let without_one = if fitted.iter().any(|&i| is_one(i)) {
        ", q = 1 left out"
    } else {
        ""
    };
    let idx: Vec<usize> = fitted
        .into_iter()
        .filter(|&i| !is_one(i))
        .filter(|&i| res.k[i].is_finite() && loo.iter().all(|r| r.k[i].is_finite()))
        .collect();
    let fallback = |res: &mut TraceMomentResult, why: &str| {
        res.universal_fit = format!("ols (unweighted least squares in K; gls not possible: {why})");
        Ok(())
    };
    if n < 5 {
        return fallback(res, "fewer than 5 jackknife parts");
    }
    if idx.len() < 3 {
        return fallback(res, &format!("fewer than 3 fitted q values{without_one}"));
    }
    let q: Vec<f64> = idx.iter().map(|&i| res.q[i]).collect();
    let fit = |r: &TraceMomentResult, w: &[Vec<f64>]| {
        let k: Vec<f64> = idx.iter().map(|&i| r.k[i]).collect();
        fit_universal_gls(&q, &k, w)
    };
    let (w, lambda) = match gls_weights(loo, &idx) {
        Ok(x) => x,
        Err(why) => return fallback(res, why),
    };
    let Some(u) = fit(res, &w) else {
        return fallback(res, "fit failed");
    };
    // nested: the weights of leave-one-out sample i from its own jackknife
    let inner: Vec<Result<Vec<TraceMomentResult>>> = (0..n)
        .into_par_iter()
        .map(|i| {
            let mut out = Vec::with_capacity(n - 1);
            for j in (0..n).filter(|&j| j != i) {
                let mut a = TraceMomentAccumulator::new(whole.config.clone())?;
                for (m, p) in parts.iter().enumerate() {
                    if m != i && m != j {
                        a.merge(p)?;
                    }
                }
                let fc_rep = replicate_fit(
                    fc,
                    res,
                    whole,
                    &a,
                    &format!("parts {} and {} of {n}", i + 1, j + 1),
                )?;
                out.push(a.finish_inner(&fc_rep, pin)?);
            }
            Ok(out)
        })
        .collect();
    let mut lu = Vec::with_capacity(n);
    for (r, inn) in loo.iter().zip(inner) {
        let inn = match inn {
            // two parts left out may take every box of the fitted range
            // (replicate_fit): the plain jackknife stands, unweighted
            Err(Error::Param { .. }) => {
                return fallback(
                    res,
                    "a nested jackknife sample lacks the fitted boxes or lags",
                );
            }
            inn => inn?,
        };
        let x = gls_weights(&inn, &idx).ok().and_then(|(wi, _)| fit(r, &wi));
        match x {
            Some(x) => lu.push(x),
            None => return fallback(res, "no fit on a jackknife sample"),
        }
    }
    apply_universal(res, &u);
    for (r, x) in loo.iter_mut().zip(&lu) {
        apply_universal(r, x);
    }
    res.universal_fit = format!(
        "gls (jackknife covariance of K(q) over {n} {what}, {} q values{without_one}, correlations shrunk by lambda = {lambda:.3}; errors by a nested jackknife)",
        idx.len(),
    );
    res.universal_shrinkage = Some(lambda);
    Ok(())
}
