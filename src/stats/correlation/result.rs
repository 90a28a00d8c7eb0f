//! The correlation functions of an ensemble from its sums: the estimates,
//! their jackknife errors, and the check against II eq 76.

use super::*;

/// The correlation of one pair of scales over the ensemble.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PairCorrelation {
    /// First scale `a1`, in pixels.
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub a1: f64,
    /// Second scale `a2`, in pixels.
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub a2: f64,
    /// Pair-weighted mean of `log2 |Δx|` in each non-empty bin, and `2^` it.
    #[serde(deserialize_with = "crate::nan_null::vec")]
    pub log2_dx: Vec<f64>,
    /// `2^log2_dx`, in pixels (lag 0 excluded; see `c0`).
    #[serde(deserialize_with = "crate::nan_null::vec")]
    pub dx: Vec<f64>,
    /// `C(Δx; a1, a2)`, centred per image (SPEC §6), with jackknife errors.
    #[serde(rename = "C", deserialize_with = "crate::nan_null::vec")]
    pub c: Vec<f64>,
    /// Jackknife standard error of `c`: over images, or with fewer than 3
    /// over the tiles of their domains (NaN without either).
    #[serde(rename = "C_stderr", deserialize_with = "crate::nan_null::vec")]
    pub c_stderr: Vec<f64>,
    /// The same centred with the ensemble mean (II eq 68).
    #[serde(rename = "C_ensemble", deserialize_with = "crate::nan_null::vec")]
    pub c_ensemble: Vec<f64>,
    /// Jackknife standard error of `c_ensemble` (as `c_stderr`).
    #[serde(
        rename = "C_ensemble_stderr",
        deserialize_with = "crate::nan_null::vec"
    )]
    pub c_ensemble_stderr: Vec<f64>,
    /// Number of pairs per bin (all images).
    #[serde(deserialize_with = "crate::nan_null::vec")]
    pub pairs: Vec<f64>,
    /// Covariance at `Δx = 0`, per-image centring (JSON `C0`, as
    /// correlation.json; `c0` read too, as written before 2026-11-30).
    #[serde(rename = "C0", alias = "c0", deserialize_with = "crate::nan_null::f64")]
    pub c0: f64,
    /// Covariance at `Δx = 0`, ensemble centring (JSON `C0_ensemble`).
    #[serde(
        rename = "C0_ensemble",
        alias = "c0_ensemble",
        deserialize_with = "crate::nan_null::f64"
    )]
    pub c0_ensemble: f64,
}

/// Everything [`correlation_estimates`] computes.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CorrelationResult {
    /// "cwt" or "wtmmm", as [`CorrelationSums::source`].
    pub source: String,
    /// The magnitude correlated: the configured one for `source = "cwt"`,
    /// always ln M for `source = "wtmmm"`.
    pub magnitude: Magnitude,
    /// Lags wrapped around a torus.
    pub periodic: bool,
    /// Number of images.
    pub images: usize,
    /// The distinct scales, in pixels.
    #[serde(deserialize_with = "crate::nan_null::vec")]
    pub scales: Vec<f64>,
    /// Ensemble mean magnitude per scale.
    #[serde(deserialize_with = "crate::nan_null::vec")]
    pub mean: Vec<f64>,
    /// One correlation function per pair of scales, in the order of the sums.
    pub pairs: Vec<PairCorrelation>,
    /// "jackknife over images" (>= 3 images), "jackknife over N tiles (S
    /// px)" (fewer, split into tiles) or "none".
    pub stderr_method: String,
    /// What the reader should know (few images for the error bars).
    #[serde(default)]
    pub warnings: Vec<String>,
}

/// `σ_W / σ_min` of the reference implementation, 13 px / 1.5703 px (II §3;
/// SPEC §1, §12): the paper's scale unit in units of the Gaussian's
/// standard deviation. II eq 76 holds for `Δx > sup(a1, a2)` in `σ_W`
/// units, i.e. `Δx > PAPER_UNIT sup(a1, a2)` with `a` in pixels.
pub const PAPER_UNIT: f64 = 13.0 / 1.5703;

/// How far one pair's correlation lies from the theory in a window of lags.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PairCheck {
    /// The pair's scales, in pixels.
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub a1: f64,
    /// See `a1`.
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub a2: f64,
    /// The window: `factor sup(a1, a2) < Δx < L/4` px.
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub dx_min: f64,
    /// See `dx_min`.
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub dx_max: f64,
    /// Lag bins in the window with a theoretical value.
    pub bins: usize,
    /// Largest `|C - theory|` there, per-image centring
    /// ([`PairCorrelation::c`]); NaN (`null`) without a bin.
    #[serde(rename = "max_abs_dev_C", deserialize_with = "crate::nan_null::f64")]
    pub max_abs_dev: f64,
    /// The same with ensemble centring ([`PairCorrelation::c_ensemble`]).
    #[serde(
        rename = "max_abs_dev_C_ensemble",
        deserialize_with = "crate::nan_null::f64"
    )]
    pub max_abs_dev_ensemble: f64,
}

/// [`CorrelationResult::compare_theory`]: the largest deviations from the
/// model's magnitude correlation (II eq 76; 0 for fBm) over all pairs.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TheoryCheck {
    /// The window starts at `factor sup(a1, a2)` px: 1 for eq 76 read
    /// literally in pixels, [`PAPER_UNIT`] for the paper's `σ_W` units
    /// (`wtmm validate` judges the latter).
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub factor: f64,
    /// Lag bins compared, over all pairs; 0 means no value (the maxima
    /// below are then NaN, `null` in JSON).
    pub bins: usize,
    /// Largest deviation over the pairs, per-image centring.
    #[serde(rename = "max_abs_dev_C", deserialize_with = "crate::nan_null::f64")]
    pub max_abs_dev: f64,
    /// Largest deviation over the pairs, ensemble centring (II eq 68).
    #[serde(
        rename = "max_abs_dev_C_ensemble",
        deserialize_with = "crate::nan_null::f64"
    )]
    pub max_abs_dev_ensemble: f64,
    /// Per pair.
    pub pairs: Vec<PairCheck>,
    /// Where the ensemble-centred deviation is largest, with its jackknife
    /// error there (`None` without a bin in the window).
    #[serde(default)]
    pub worst_ensemble: Option<WorstBin>,
}

/// One lag bin of a [`TheoryCheck`]: where the deviation from the theory
/// is largest, whether that is beyond the noise.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct WorstBin {
    /// The pair's scales, in pixels.
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub a1: f64,
    /// See `a1`.
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub a2: f64,
    /// The bin's lag, in pixels.
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub dx: f64,
    /// `C - theory` there (signed).
    #[serde(deserialize_with = "crate::nan_null::f64")]
    pub dev: f64,
    /// Jackknife standard error of `C` there (`None` with < 3 images).
    pub stderr: Option<f64>,
}

impl CorrelationResult {
    /// Compares each pair with `model`'s magnitude correlation for an
    /// integral scale `l` px (the image side for a W-cascade, II eq 76)
    /// over `factor sup(a1, a2) < Δx < l/4`, the window of the issue's
    /// acceptance with `factor = PAPER_UNIT`. Bins where the model gives no
    /// value (e.g. a model without a closed form), or the data none (a bin
    /// without pairs), are skipped, and not counted in `bins`.
    pub fn compare_theory(&self, model: &crate::theory::Model, l: f64, factor: f64) -> TheoryCheck {
        let mut out = TheoryCheck {
            factor,
            bins: 0,
            // NaN until a bin is compared (f64::max skips NaN): an empty
            // window is no value, not a perfect agreement
            max_abs_dev: f64::NAN,
            max_abs_dev_ensemble: f64::NAN,
            pairs: Vec::with_capacity(self.pairs.len()),
            worst_ensemble: None,
        };
        for p in &self.pairs {
            let lo = factor * p.a1.max(p.a2);
            let mut pc = PairCheck {
                a1: p.a1,
                a2: p.a2,
                dx_min: lo,
                dx_max: l / 4.0,
                bins: 0,
                max_abs_dev: f64::NAN,
                max_abs_dev_ensemble: f64::NAN,
            };
            for (i, &dx) in p.dx.iter().enumerate() {
                // a bin without pairs (NaN) is no comparison: f64::max
                // would skip it silently while it was counted
                if dx > lo
                    && dx < l / 4.0
                    && p.c[i].is_finite()
                    && p.c_ensemble[i].is_finite()
                    && let Some(t) = model.magnitude_correlation(dx, l)
                {
                    pc.max_abs_dev = pc.max_abs_dev.max((p.c[i] - t).abs());
                    pc.max_abs_dev_ensemble =
                        pc.max_abs_dev_ensemble.max((p.c_ensemble[i] - t).abs());
                    pc.bins += 1;
                    let dev = p.c_ensemble[i] - t;
                    if dev.is_finite() && out.worst_ensemble.is_none_or(|w| dev.abs() > w.dev.abs())
                    {
                        let se = p.c_ensemble_stderr[i];
                        out.worst_ensemble = Some(WorstBin {
                            a1: p.a1,
                            a2: p.a2,
                            dx,
                            dev,
                            stderr: se.is_finite().then_some(se),
                        });
                    }
                }
            }
            out.max_abs_dev = out.max_abs_dev.max(pc.max_abs_dev);
            out.max_abs_dev_ensemble = out.max_abs_dev_ensemble.max(pc.max_abs_dev_ensemble);
            out.bins += pc.bins;
            out.pairs.push(pc);
        }
        out
    }
}

/// Ensemble correlation functions from the per-image sums: per bin, sums
/// over images in a canonical order (sorted by label and means, so merging
/// is order-independent), both centrings, delete-one jackknife errors.
///
/// **Errors** if the sums hold no image or fail [`CorrelationSums::check`].
pub fn correlation_estimates(s: &CorrelationSums) -> Result<CorrelationResult> {
    if s.images.is_empty() {
        return Err(Error::Input("no image in the correlation sums".into()));
    }
    s.check()?;
    let mut order: Vec<usize> = (0..s.images.len()).collect();
    order.sort_by(|&a, &b| {
        let (ia, ib) = (&s.images[a], &s.images[b]);
        ia.mean
            .iter()
            .zip(&ib.mean)
            .map(|(x, y)| x.total_cmp(y))
            .find(|o| o.is_ne())
            .unwrap_or(std::cmp::Ordering::Equal)
            .then(ia.label.cmp(&ib.label))
    });
    let ns = s.scales.len();
    // ensemble mean per scale, pooled over points
    let pooled = |imgs: &[&CorrelationImage]| -> Vec<f64> {
        (0..ns)
            .map(|k| {
                let (mut sw, mut sn) = (0.0, 0.0);
                for im in imgs {
                    sw += im.mean[k] * im.n[k];
                    sn += im.n[k];
                }
                sw / sn
            })
            .collect()
    };
    let all: Vec<&CorrelationImage> = order.iter().map(|&i| &s.images[i]).collect();
    let mu = pooled(&all);
    let nb = s.images[0].pairs[0].ww.len();
    // per pair, per bin: (C, C_ens, count, lcount) of the images `imgs`
    let eval = |p: usize, imgs: &[&CorrelationImage]| -> (Vec<f64>, Vec<f64>, Vec<f64>, Vec<f64>) {
        let mu = pooled(imgs);
        let (s1, s2) = s.pairs[p];
        let (mut ww, mut ens, mut cnt, mut lc) =
            (vec![0.0; nb], vec![0.0; nb], vec![0.0; nb], vec![0.0; nb]);
        for im in imgs {
            let ps = &im.pairs[p];
            let (d1, d2) = (im.mean[s1] - mu[s1], im.mean[s2] - mu[s2]);
            for b in 0..nb {
                ww[b] += ps.ww[b];
                ens[b] += ps.ww[b] + d2 * ps.wm[b] + d1 * ps.mw[b] + d1 * d2 * ps.count[b];
                cnt[b] += ps.count[b];
                lc[b] += ps.lcount[b];
            }
        }
        let c = ww.iter().zip(&cnt).map(|(w, n)| w / n).collect();
        let ce = ens.iter().zip(&cnt).map(|(w, n)| w / n).collect();
        (c, ce, cnt, lc)
    };
    let n_img = s.images.len();
    // the jackknife's replicates: leave one image out (3 or more images),
    // else one tile of one image (its pairs' first points), re-centred
    let n_tiles: usize = s.images.iter().map(|im| im.tiles.len()).sum();
    let tiled = n_img < 3 && s.images.iter().all(|im| !im.tiles.is_empty()) && n_tiles >= 3;
    // (image, that image without one tile), in the images' order
    let replicates: Vec<(usize, CorrelationImage)> = if tiled {
        order
            .iter()
            .flat_map(|&i| {
                let im = &s.images[i];
                (0..im.tiles.len()).map(move |k| (i, im.without_tile(k, &s.pairs)))
            })
            .collect()
    } else {
        Vec::new()
    };
    let reps_of = |p: usize| -> Vec<(Vec<f64>, Vec<f64>)> {
        let one = |skip: usize, with: Option<&CorrelationImage>| {
            let imgs: Vec<&CorrelationImage> = order
                .iter()
                .filter_map(|&j| match (j == skip, with) {
                    (false, _) => Some(&s.images[j]),
                    (true, w) => w,
                })
                .collect();
            let e = eval(p, &imgs);
            (e.0, e.1)
        };
        if n_img >= 3 {
            order.iter().map(|&i| one(i, None)).collect()
        } else {
            replicates
                .iter()
                .map(|(i, rep)| one(*i, Some(rep)))
                .collect()
        }
    };
    let jk = |vals: &[f64]| -> f64 {
        if vals.len() < 3 {
            return f64::NAN;
        }
        crate::stats::jackknife_se(vals)
    };
    let pairs = (0..s.pairs.len())
        .map(|p| {
            let (c, ce, cnt, lc) = eval(p, &all);
            let reps = reps_of(p);
            let keep: Vec<usize> = (1..nb).filter(|&b| cnt[b] > 0.0).collect();
            let err = |which: usize, b: usize| -> f64 {
                let v: Vec<f64> = reps
                    .iter()
                    .map(|r| if which == 0 { r.0[b] } else { r.1[b] })
                    .collect();
                jk(&v)
            };
            let log2_dx: Vec<f64> = keep.iter().map(|&b| lc[b] / cnt[b]).collect();
            PairCorrelation {
                a1: s.scales[s.pairs[p].0],
                a2: s.scales[s.pairs[p].1],
                dx: log2_dx.iter().map(|l| l.exp2()).collect(),
                log2_dx,
                c: keep.iter().map(|&b| c[b]).collect(),
                c_stderr: keep.iter().map(|&b| err(0, b)).collect(),
                c_ensemble: keep.iter().map(|&b| ce[b]).collect(),
                c_ensemble_stderr: keep.iter().map(|&b| err(1, b)).collect(),
                pairs: keep.iter().map(|&b| cnt[b]).collect(),
                c0: c[0],
                c0_ensemble: ce[0],
            }
        })
        .collect();
    let mut warnings = Vec::new();
    let stderr_method = if n_img >= 3 {
        // flags jackknife errors over few images, as the spectra do
        crate::stats::fit::stderr_method(n_img, &[], &mut warnings)
    } else if tiled {
        let sides: Vec<usize> = s.images.iter().map(|im| im.tile_side).collect();
        let (lo, hi) = (
            sides.iter().copied().min().unwrap_or(0),
            sides.iter().copied().max().unwrap_or(0),
        );
        let side = if lo == hi {
            lo.to_string()
        } else {
            format!("{lo}-{hi}")
        };
        let what = format!(
            "a jackknife over {n_tiles} tiles of about {side} px of {n_img} image{}",
            if n_img == 1 { "" } else { "s" }
        );
        warnings.push(format!(
            "the standard errors come from {what}: a replicate leaves out the pairs whose \
             first point lies in one tile and centres the rest again; tiles are treated as \
             independent, which fields correlated over long distances (cascades) are not, and \
             a lag longer than a tile reaches into the others, so the errors of the longest \
             lags are the least reliable"
        ));
        if let Some(w) = crate::stats::fit::few_groups_warning(n_tiles, &what) {
            warnings.push(w);
        }
        format!("jackknife over {n_tiles} tiles ({side} px)")
    } else {
        let with = s.images.iter().filter(|im| !im.tiles.is_empty()).count();
        let why = if with == 0 {
            ", and the domain was not split into jackknife tiles"
        } else if with < n_img {
            ", and only some of the images were split into jackknife tiles"
        } else {
            ", and there are fewer than 3 jackknife tiles"
        };
        warnings.push(format!(
            "no standard errors: {n_img} image{} (a jackknife needs 3 or more{why})",
            if n_img == 1 { "" } else { "s" }
        ));
        "none".into()
    };
    Ok(CorrelationResult {
        source: s.source.clone(),
        magnitude: s.magnitude,
        periodic: s.periodic,
        images: n_img,
        scales: s.scales.clone(),
        mean: mu,
        pairs,
        stderr_method,
        warnings,
    })
}
