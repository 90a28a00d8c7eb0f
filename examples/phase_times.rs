use std::time::Instant;
use wtmm::Field;
use wtmm::cwt::CwtPlan;
use wtmm::skeleton::{AnalysisConfig, DetectScratch, Linker, detect};
use wtmm::synth::fbm::{FbmParams, fbm};
fn main() {
    let n = 1024;
    let f = Field::new(fbm(FbmParams { hurst: 1.0 / 3.0 }, n, n, 1, 0).unwrap());
    let cfg = AnalysisConfig::default();
    let scales = cfg.scale_list();
    let plan = CwtPlan::new(n, n, cfg.wavelet, &scales).unwrap();
    let dom = cfg.domain(&f).unwrap();
    let fi = plan.forward(f.data.view()).unwrap();
    let mut ws = plan.workspace();
    let mut sc = DetectScratch::default();
    micro(plan.scale(&fi, 20, &mut ws));
    for rep in 0..2 {
        let (mut tc, mut td, mut tl) = (0.0, 0.0, 0.0);
        let mut linker = Linker::new(cfg.link);
        let mut nw = 0;
        for j in 0..scales.len() {
            let t0 = Instant::now();
            let t = plan.scale(&fi, j, &mut ws);
            let t1 = Instant::now();
            let sm = detect(t, j, scales[j], &dom, cfg.eps, false, &mut sc);
            let t2 = Instant::now();
            nw += sm.n_wtmm;
            linker.push(&sm);
            let t3 = Instant::now();
            tc += (t1 - t0).as_secs_f64();
            td += (t2 - t1).as_secs_f64();
            tl += (t3 - t2).as_secs_f64();
        }
        println!(
            "rep {rep}: cwt {:.0} ms, detect {:.0} ms, link {:.0} ms, wtmm px {nw}",
            tc * 1e3,
            td * 1e3,
            tl * 1e3
        );
    }
}
#[allow(dead_code)]
pub fn micro(t: &ndarray::Array2<num_complex::Complex64>) {
    let ts = t.as_slice().unwrap();
    let (ny, nx) = t.dim();
    let mut m = vec![0.0f64; ny * nx];
    let t0 = Instant::now();
    for _ in 0..10 {
        for (mm, z) in m.iter_mut().zip(ts) {
            *mm = (z.re * z.re + z.im * z.im).sqrt();
        }
    }
    let t1 = Instant::now();
    let mut cnt = 0usize;
    for _ in 0..10 {
        for y in 144..nx - 144 {
            for x in 144..nx - 144 {
                let p = y * nx + x;
                let mp = m[p];
                let inv = 1.0 / mp;
                let (u1, u2) = (ts[p].re * inv, ts[p].im * inv);
                let at = |px: f64, py: f64| {
                    let (x0, y0) = (px.floor(), py.floor());
                    let (fx, fy) = (px - x0, py - y0);
                    let i = y0 as usize * nx + x0 as usize;
                    let a = m[i] + fx * (m[i + 1] - m[i]);
                    let b = m[i + nx] + fx * (m[i + nx + 1] - m[i + nx]);
                    a + fy * (b - a)
                };
                let f = at(x as f64 + u1, y as f64 + u2);
                let b = at(x as f64 - u1, y as f64 - u2);
                cnt += ((mp > f) & (mp >= b)) as usize;
            }
        }
    }
    let t2 = Instant::now();
    println!(
        "modulus {:.2} ms/scale, nms {:.2} ms/scale ({} max)",
        (t1 - t0).as_secs_f64() * 100.0,
        (t2 - t1).as_secs_f64() * 100.0,
        cnt / 10
    );
}
