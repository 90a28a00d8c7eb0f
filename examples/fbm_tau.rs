use rayon::prelude::*;
use wtmm::Field;
use wtmm::skeleton::AnalysisConfig;
use wtmm::spectra::{PartitionSums, Rule, image_sums};
use wtmm::synth::fbm::{FbmParams, fbm};
fn main() {
    let a: Vec<String> = std::env::args().collect();
    let h: f64 = a[1].parse().unwrap();
    let n: usize = a[2].parse().unwrap();
    let k: usize = a[3].parse().unwrap();
    let q: Vec<f64> = (-8..=12).map(|i| i as f64 * 0.5).collect();
    let mut cfg = AnalysisConfig::default();
    if let Ok(r) = std::env::var("RATIO") {
        let v: Vec<f64> = r.split(',').map(|x| x.parse().unwrap()).collect();
        cfg.link.ratio = (v[0], v[1]);
    }
    if let Ok(r) = std::env::var("PROP") {
        let v: Vec<f64> = r.split(',').map(|x| x.parse().unwrap()).collect();
        cfg.link.radius = wtmm::skeleton::SearchRadius::Proportional {
            factor: v[0],
            min: v[1],
        };
    }
    if let Ok(r) = std::env::var("CAP") {
        cfg.link.radius = wtmm::skeleton::SearchRadius::Reference {
            cap: r.parse().unwrap(),
        };
    }
    let t = std::time::Instant::now();
    let parts: Vec<PartitionSums> = (0..k)
        .into_par_iter()
        .map(|i| {
            let f = Field::new(fbm(FbmParams { hurst: h }, n, n, 42, i as u64).unwrap());
            image_sums(&f, &cfg, &q, format!("{i}")).unwrap()
        })
        .collect();
    eprintln!("{:.1}s", t.elapsed().as_secs_f64());
    let ps = PartitionSums::merge_all(parts).unwrap().unwrap();
    for rule in [Rule::Sup, Rule::Plain] {
        for fit in [(0.0, 4.0), (1.0, 4.0)] {
            let s = ps.spectra(rule, fit).unwrap();
            let dev: f64 =
                s.q.iter()
                    .zip(&s.tau)
                    .filter(|(q, _)| **q >= -4.0 && **q <= 6.0)
                    .map(|(q, t)| (t - (q * h - 2.0)).abs())
                    .fold(0.0, f64::max);
            let i0 = s.q_index(0.0).unwrap();
            println!(
                "{rule:?} fit {fit:?}: max|tau-th| [-4,6] = {dev:.3}  tau(0) {:.3}±{:.3}  h(0) {:.3} D(h0) {:.3}",
                s.tau[i0], s.tau_stderr[i0], s.h[i0], s.d[i0]
            );
            println!(
                "   tau: {}",
                s.q.iter()
                    .zip(&s.tau)
                    .step_by(2)
                    .map(|(q, t)| format!("{q}:{:+.2}({:+.2})", t, t - (q * h - 2.0)))
                    .collect::<Vec<_>>()
                    .join(" ")
            );
        }
    }
    let s = ps.spectra(Rule::Sup, (0.0, 4.0)).unwrap();
    println!(
        "lines per scale: {:?}",
        s.lines.iter().step_by(5).collect::<Vec<_>>()
    );
    let r: Vec<String> = s
        .lines
        .windows(6)
        .step_by(5)
        .map(|w| format!("{:.2}", w[0] as f64 / w[5] as f64))
        .collect();
    println!("death ratio per half octave: {}", r.join(" "));
    let f = Field::new(fbm(FbmParams { hurst: h }, n, n, 42, 0).unwrap());
    let sk = wtmm::skeleton::skeleton(&f, &cfg).unwrap();
    let w: Vec<String> = sk
        .per_scale
        .windows(6)
        .step_by(5)
        .map(|w| format!("{:.2}", w[0].wtmmm as f64 / w[5].wtmmm as f64))
        .collect();
    println!(
        "WTMMM count ratio per half octave (image 0): {}",
        w.join(" ")
    );
    let w: Vec<String> = sk
        .per_scale
        .iter()
        .step_by(5)
        .map(|c| format!("{}/{}/{}", c.wtmm, c.wtmmm, c.chains))
        .collect();
    println!("WTMM/WTMMM/chains (image 0): {}", w.join(" "));
}
#[allow(dead_code)]
fn unused() {}
