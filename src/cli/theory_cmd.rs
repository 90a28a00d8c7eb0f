//! `wtmm theory MODEL [options] [--q LIST] [--out DIR]`: the closed forms
//! (SPEC §10) as JSON on stdout (and in DIR/theory.json with a plot).

use std::path::PathBuf;

use clap::Args;
use serde_json::json;

use super::Outcome;
use super::common::save_chart;
use super::common::{header, make_out_dir, parse_q, write_json};
use super::model_args::{ModelName, ModelOpts};
use crate::error::{Error, Result};
use crate::plot::{Chart, Series, Style};
use crate::theory::{Model, TheoryTable};

#[derive(Args, Debug)]
pub struct TheoryArgs {
    #[arg(value_enum)]
    pub model: Option<ModelName>,
    #[command(flatten)]
    pub model_opts: ModelOpts,
    /// q values: `start:stop:step` or `a,b,c`.
    #[arg(long, default_value = "-6:8:0.5", allow_hyphen_values = true)]
    pub q: String,
    /// Also write theory.json, tau.png and dh.png here.
    #[arg(long)]
    pub out: Option<PathBuf>,
}

pub fn run(args: TheoryArgs, _quiet: bool) -> Result<Outcome> {
    let r = args.model_opts.resolve(args.model)?;
    let q = parse_q("q", &args.q)?;
    let t = TheoryTable::new(&r.model, &q)?;
    let mut body = header(
        "theory",
        json!({"model": r.model, "preset": r.preset, "q": q}),
    );
    if let (Some(o), serde_json::Value::Object(m)) = (
        body.as_object_mut(),
        serde_json::to_value(&t).map_err(|e| Error::Input(e.to_string()))?,
    ) {
        for (k, v) in m {
            o.insert(k, v);
        }
    }
    body["recommended_wavelet"] = json!(r.wavelet);
    // the angle-integrated exponent of TM eq 11 and `tm` (E(k) ~ k S(k) for
    // an isotropic field), beside the angle-averaged `beta` = tau(2) + 4
    body["beta_integrated"] = json!(r.model.beta() - 1.0);
    let mut notes = Vec::new();
    if let Model::Fif(p) = r.model
        && p.alpha < 2.0
        && p.c1 > 0.0
    {
        notes.push(
            if p.alpha > 1.0 && !crate::theory::fif::alpha_is_one(p.alpha) {
                "q < 0: tau(q) = q h_max - 2 is the spectrum truncated at h_max, where D = 2; \
             the strict Legendre transform of K (defined for q >= 0 only) gives D = 2 for every \
             h >= h_max and tau(q < 0) = -inf (src/theory/mod.rs)"
            } else {
                "q < 0: for alpha <= 1, K'(0+) = -inf, so h_max = +inf and tau(q < 0) = -inf: \
             written as null (src/theory/mod.rs); the D(h) curve stops at h(q = 0.001), \
             where D = 2 - C1 0.001^alpha"
            }
            .to_string(),
        );
    }
    // D(q) < 0: the q where the annealed tau(q) is set by latent
    // singularities (h outside [h_min, h_max], the exponents of D(h) >= 0),
    // named as runs of the list (D > 0 between two runs)
    let mut runs: Vec<(f64, f64)> = Vec::new();
    let mut n_neg = 0;
    let mut open = false;
    for (&v, &d) in q.iter().zip(&t.d) {
        if d < -1e-12 {
            n_neg += 1;
            match runs.last_mut() {
                Some(r) if open => r.1 = v,
                _ => runs.push((v, v)),
            }
            open = true;
        } else {
            open = false;
        }
    }
    if !runs.is_empty() {
        let where_ = runs
            .iter()
            .map(|&(a, b)| {
                if a == b {
                    format!("{a}")
                } else {
                    format!("{a} to {b}")
                }
            })
            .collect::<Vec<_>>()
            .join(", ");
        notes.push(format!(
            "D(q) < 0 at {n_neg} of the q ({where_}): there the annealed tau(q) comes from \
             latent singularities, h outside [h_min, h_max] = [{:.4}, {:.4}] where D(h) >= 0, \
             which an image almost surely does not hold; an ensemble's estimate bends toward a \
             straight line there (finite size and statistics), so these q are not a test of \
             the estimator",
            t.h_min, t.h_max
        ));
    }
    // the other nulls: a tau beyond f64 (a log-Poisson beta^q at q = -700)
    let fif_q_neg = matches!(r.model, Model::Fif(p) if p.alpha < 2.0 && p.c1 > 0.0);
    let beyond: Vec<String> = q
        .iter()
        .zip(&t.tau)
        .filter(|&(&v, tau)| {
            let noted = fif_q_neg && v < 0.0;
            !tau.is_finite() && !noted
        })
        .map(|(v, _)| v.to_string())
        .collect();
    if !beyond.is_empty() {
        notes.push(format!(
            "tau(q) is beyond the range of a double at {} of the q ({}): written as null, \
             with h and D there",
            beyond.len(),
            beyond.join(", ")
        ));
    }
    notes.extend(r.model.caveats());
    if !notes.is_empty() {
        body["notes"] = json!(notes);
    }
    let text = serde_json::to_string_pretty(&body).map_err(|e| Error::Input(e.to_string()))?;
    {
        use std::io::Write as _;
        match writeln!(std::io::stdout(), "{text}") {
            // the reader has seen what it wanted (`wtmm theory ... | head`)
            Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => {}
            r => r.map_err(|source| Error::Write {
                path: "standard output".into(),
                source,
            })?,
        }
    }
    if let Some(dir) = &args.out {
        make_out_dir(dir)?;
        write_json(&dir.join("theory.json"), &body)?;
        let name = r.preset.unwrap_or(r.model.name());
        let params = super::common::model_params_label(&r.model);
        let tc = Chart {
            title: format!("tau(q): {name} ({params})"),
            x_label: "q".into(),
            y_label: "tau(q)".into(),
            series: vec![Series::new(
                name,
                q.iter().cloned().zip(t.tau.iter().cloned()).collect(),
                Style::Line,
                1,
            )],
            ..Default::default()
        };
        save_chart(&tc, &dir.join("tau.png"))?;
        let style = if t.dh_h.len() > 1 {
            Style::Line
        } else {
            Style::Markers
        };
        let dc = Chart {
            title: format!("D(h): {name} ({params})"),
            x_label: "h".into(),
            y_label: "D(h)".into(),
            series: vec![Series::new(
                name,
                t.dh_h.iter().cloned().zip(t.dh_d.iter().cloned()).collect(),
                style,
                1,
            )],
            ..Default::default()
        };
        save_chart(&dc, &dir.join("dh.png"))?;
    }
    Ok(Outcome::Ok)
}
