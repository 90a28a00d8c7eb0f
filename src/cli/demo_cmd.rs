//! `wtmm demo`: the README's main command. Generates a small ensemble of a
//! model with a known spectrum, analyses it, compares with the theory and
//! writes a report and the plots into `./wtmm-demo/`.

use std::fmt::Write as _;
use std::path::PathBuf;

use clap::Args;
use serde_json::json;

use super::Outcome;
use super::analyze_cmd::{TheoryCurves, write_outputs};
use super::common::{make_out_dir, progress};
use super::ensemble::analyse_generated;
use crate::error::Result;
use crate::io::write_atomic;
use crate::skeleton::AnalysisConfig;
use crate::spectra::Rule;
use crate::stats::powspec::{PowerSpectrumConfig, default_k_range};
use crate::synth::fbm::{FbmParams, fbm};

#[derive(Args, Debug)]
pub struct DemoArgs {
    /// Output directory.
    #[arg(long, default_value = "wtmm-demo")]
    pub out: PathBuf,
    /// Number of images.
    #[arg(long, default_value_t = 8)]
    pub count: usize,
    /// Image side.
    #[arg(long, default_value_t = 512)]
    pub size: usize,
    #[arg(long, default_value_t = 2026)]
    pub seed: u64,
}

pub fn run(args: DemoArgs, quiet: bool) -> Result<Outcome> {
    let t0 = std::time::Instant::now();
    let h = 1.0 / 3.0;
    let model = FbmParams { hurst: h };
    let cfg = AnalysisConfig {
        octaves: 4,
        ..Default::default()
    };
    let q: Vec<f64> = (-8..=12).map(|i| 0.5 * i as f64).collect();
    let fit = (0.0, 3.0);
    let n = args.size;
    let ps_cfg = PowerSpectrumConfig::default();
    let pb = progress(args.count as u64, "demo: fBm H = 1/3", quiet);
    let ens = analyse_generated(
        args.count,
        |i| fbm(model, n, n, args.seed, i as u64),
        &cfg,
        &q,
        &ps_cfg,
        &|| pb.inc(1),
    )?;
    pb.finish_and_clear();
    let s = ens.sums.spectra(Rule::Sup, fit)?;
    let other = ens.sums.spectra(Rule::Plain, fit)?;
    let (k_lo, k_hi) = default_k_range(n);
    let beta = ens.spectrum.fit(k_lo, k_hi)?;
    make_out_dir(&args.out)?;
    let theory = TheoryCurves {
        name: "fBm H = 1/3".into(),
        tau: Box::new(move |q| q * h - 2.0),
        dh: vec![(h, 2.0)],
    };
    let params = json!({"model": "fbm", "hurst": h, "count": args.count, "size": n, "seed": args.seed, "analysis": cfg, "fit_octaves": fit, "rule": "sup"});
    write_outputs(
        &args.out,
        "demo",
        params,
        &ens.sums,
        &s,
        &other,
        Some(&theory),
    )?;
    // the report
    let mut r = String::new();
    let _ = writeln!(
        r,
        "wtmm {} demo: {} fBm images {n}x{n}, H = 1/3, seed {}",
        crate::VERSION,
        args.count,
        args.seed
    );
    let _ = writeln!(
        r,
        "WTMM: gauss wavelet, a = {:.2}..{:.2} px, fit over {:.1}-{:.1} px, sup rule, margin {} px",
        cfg.a_min,
        cfg.grid().a_max(),
        s.fit_scales.0,
        s.fit_scales.1,
        cfg.margin_px()
    );
    let _ = writeln!(
        r,
        "Error bars: {} ({} images).\n",
        s.stderr_method, s.images
    );
    let _ = writeln!(
        r,
        "{:>6} {:>9} {:>8} {:>9} {:>8} {:>8} {:>9}",
        "q", "tau", "stderr", "theory", "diff", "|z|", "plain"
    );
    let mut worst: f64 = 0.0;
    for i in 0..s.q.len() {
        let th = s.q[i] * h - 2.0;
        let d = s.tau[i] - th;
        if (-4.0..=6.0).contains(&s.q[i]) {
            worst = worst.max(d.abs());
        }
        let _ = writeln!(
            r,
            "{:>6.1} {:>9.4} {:>8.4} {:>9.4} {:>+8.4} {:>8.2} {:>9.4}",
            s.q[i],
            s.tau[i],
            s.tau_stderr[i],
            th,
            d,
            (d / s.tau_stderr[i]).abs(),
            other.tau[i]
        );
    }
    let i0 = s.q_index(0.0).expect("q grid has 0");
    let _ = writeln!(r, "\nmax |tau - theory| over -4 <= q <= 6: {worst:.3}");
    let _ = writeln!(
        r,
        "tau(0) = {:.3} ± {:.3} (theory -2)",
        s.tau[i0], s.tau_stderr[i0]
    );
    let _ = writeln!(
        r,
        "h(q=0) = {:.3} ± {:.3} (theory {h:.3}); D(h(0)) = {:.3} (theory 2)",
        s.h[i0], s.h_stderr[i0], s.d[i0]
    );
    let _ = writeln!(
        r,
        "power spectrum: beta = {:.3} ± {:.3} (theory {:.3}, angle-averaged)",
        beta.beta,
        beta.beta_stderr,
        model.beta()
    );
    if !s.warnings.is_empty() {
        let _ = writeln!(r, "\nwarnings:");
        for w in &s.warnings {
            let _ = writeln!(r, "  {w}");
        }
    }
    let _ = writeln!(
        r,
        "\nplots: logZ.png (a), hqa.png (b), tau.png (c), dh.png (d); data: spectra.json, tau.csv"
    );
    let _ = writeln!(r, "wall time: {:.1} s", t0.elapsed().as_secs_f64());
    write_atomic(&args.out.join("report.txt"), r.as_bytes())?;
    print!("{r}");
    println!("\nwrote the report and plots to {}/", args.out.display());
    Ok(Outcome::Ok)
}
