use ndarray::Array2;
use wtmm::Field;
use wtmm::skeleton::{AnalysisConfig, Parallelism, skeleton_with};
fn main() {
    let aa: bool = std::env::args().nth(1).is_some();
    let n = 256;
    let (cx, cy, r) = (128.0, 128.0, 40.0);
    let img = Array2::from_shape_fn((n, n), |(y, x)| {
        let d = ((x as f64 - cx).powi(2) + (y as f64 - cy).powi(2)).sqrt();
        if aa {
            (r - d + 0.5).clamp(0.0, 1.0)
        } else if d < r {
            1.0
        } else {
            0.0
        }
    });
    let c = AnalysisConfig {
        octaves: 3,
        margin: Some(40),
        ..Default::default()
    };
    let keep: Vec<usize> = (0..30).step_by(5).collect();
    let sk = skeleton_with(&Field::new(img), &c, Parallelism::Serial, &keep).unwrap();
    for sm in &sk.kept {
        let mut l: Vec<usize> = sm.chains.iter().map(|c| c.pixels.len()).collect();
        l.sort();
        l.reverse();
        println!(
            "a {:.2} wtmm {} chains {} lens {:?} closed {:?}",
            sm.a,
            sm.n_wtmm,
            sm.chains.len(),
            &l[..l.len().min(12)],
            sm.chains.iter().filter(|c| c.closed).count()
        );
    }
    // print a small patch of WTMM flags at a=1.5 around (168,128)
    let sm = &sk.kept[0];
    let mut grid = vec![vec!['.'; 30]; 30];
    for ch in &sm.chains {
        for &(x, y) in &ch.pixels {
            if (150..180).contains(&x) && (100..130).contains(&y) {
                grid[(y - 100) as usize][(x - 150) as usize] = '#';
            }
        }
    }
    for row in grid {
        println!("{}", row.into_iter().collect::<String>());
    }
}
