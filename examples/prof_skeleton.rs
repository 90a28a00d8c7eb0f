use wtmm::Field;
use wtmm::skeleton::{AnalysisConfig, Parallelism, skeleton_with};
use wtmm::synth::fbm::{FbmParams, fbm};
fn main() {
    let n = 512;
    let f = Field::new(fbm(FbmParams { hurst: 1.0 / 3.0 }, n, n, 1, 0).unwrap());
    let cfg = AnalysisConfig {
        octaves: 4,
        ..Default::default()
    };
    let sk = skeleton_with(&f, &cfg, Parallelism::Serial, &[]).unwrap();
    println!("{}", sk.lines.len());
}
