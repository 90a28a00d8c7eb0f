//! The analysis commands end to end on small inputs (SPEC §13): inputs and
//! the output directory are checked before computing, bad input exits 2 and
//! leaves nothing behind, and the outputs say what they were made from.

use std::path::{Path, PathBuf};

use ndarray::Array2;
use serde_json::Value;
use wtmm::cli::run_from;
use wtmm::io::{read_field, write_npy};
use wtmm::synth::fbm::{FbmParams, fbm};

/// A fresh, empty scratch directory per test.
fn scratch(name: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR"))
        .join("cli-tests")
        .join(name);
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn run(args: &[&str]) -> i32 {
    let mut v = vec!["wtmm", "--quiet"];
    v.extend_from_slice(args);
    run_from(v)
}

fn json(path: &Path) -> Value {
    let s = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    serde_json::from_str(&s).unwrap()
}

fn fbm_npy(dir: &Path, name: &str, n: usize, seed: u64) -> String {
    let p = dir.join(name);
    write_npy(&p, &fbm(FbmParams { hurst: 0.4 }, n, n, seed, 0).unwrap()).unwrap();
    p.display().to_string()
}

/// A missing image at the end of the list fails at once, before the others
/// are analysed, and the output directory it would have created is gone.
#[test]
fn inputs_are_checked_before_computing_and_nothing_is_left() {
    let dir = scratch("inputs");
    let a = fbm_npy(&dir, "a.npy", 128, 1);
    let missing = dir.join("missing.npy").display().to_string();
    let out = dir.join("out").join("deeper");
    let o = out.display().to_string();
    let t = std::time::Instant::now();
    assert_eq!(
        run(&["analyze", &a, &missing, "--octaves", "2", "--out", &o]),
        2
    );
    assert!(t.elapsed().as_secs_f64() < 0.5, "failed late");
    assert!(!dir.join("out").exists(), "output directory left behind");
    // a directory is not an image
    let d = dir.display().to_string();
    assert_eq!(run(&["spectrum", &a, &d, "--out", &o]), 2);
    assert!(!dir.join("out").exists());
    // an output path that is a regular file
    assert_eq!(run(&["spectrum", &a, "--out", &a]), 2);
}

/// `merge` names the shard that does not match and refuses a fit range
/// beyond the scales of the sums.
#[test]
fn merge_names_the_mismatched_file_and_checks_the_fit() {
    let dir = scratch("merge");
    let a = fbm_npy(&dir, "a.npy", 128, 2);
    let s2 = dir.join("o2");
    let s3 = dir.join("o3");
    for (oct, fit, out) in [("2", "0.5:2", &s2), ("3", "0.5:2.9", &s3)] {
        let o = out.display().to_string();
        let code = run(&[
            "analyze",
            &a,
            "--octaves",
            oct,
            "--fit",
            fit,
            "--q",
            "-2:2:1",
            "--out",
            &o,
        ]);
        assert_eq!(code, 0);
    }
    let j2 = s2.join("sums.json").display().to_string();
    let j3 = s3.join("sums.json").display().to_string();
    let m = dir.join("m").display().to_string();
    assert_eq!(run(&["merge", &j2, &j3, "--out", &m]), 2);
    assert_eq!(run(&["merge", &j2, "--fit", "0:9", "--out", &m]), 2);
    assert!(!dir.join("m").exists());
    assert_eq!(run(&["merge", &j2, "--fit", "0:2", "--out", &m]), 0);
    let s = json(&dir.join("m").join("spectra.json"));
    assert_eq!(s["params"]["fit_octaves"], serde_json::json!([0.0, 2.0]));
}

/// The theory an analysis is drawn against is recorded with its parameters.
#[test]
fn analyze_records_the_theory_parameters() {
    let dir = scratch("theory");
    let a = fbm_npy(&dir, "a.npy", 128, 3);
    let o = dir.join("o").display().to_string();
    let code = run(&[
        "analyze",
        &a,
        "--octaves",
        "2",
        "--theory",
        "fbm",
        "--hurst",
        "0.4",
        "--out",
        &o,
    ]);
    assert_eq!(code, 0);
    let s = json(&dir.join("o").join("spectra.json"));
    assert_eq!(s["params"]["theory"]["model"]["hurst"].as_f64(), Some(0.4));
    // the default fit range follows --octaves (0.5:2 here)
    assert_eq!(s["params"]["fit_octaves"], serde_json::json!([0.5, 2.0]));
}

/// A correlation ensemble needs one image size: the odd one out is named
/// and nothing is written.
#[test]
fn correlate_refuses_mixed_sizes() {
    let dir = scratch("correlate");
    let a = fbm_npy(&dir, "a.npy", 128, 4);
    let b = fbm_npy(&dir, "b.npy", 96, 5);
    let o = dir.join("o").display().to_string();
    assert_eq!(run(&["correlate", &a, &b, "--out", &o]), 2);
    assert!(!dir.join("o").exists());
}

/// Where the wavelet's support reaches a missing pixel the transform is
/// not trusted: `cwt` writes NaN there, finite values beyond.
#[test]
fn cwt_is_nan_where_the_wavelet_reaches_missing_pixels() {
    let dir = scratch("cwt");
    let mut img = fbm(FbmParams { hurst: 0.4 }, 128, 128, 6, 0).unwrap();
    for y in 0..128 {
        for x in 0..30 {
            img[[y, x]] = f64::NAN;
        }
    }
    let p = dir.join("half.npy");
    write_npy(&p, &img).unwrap();
    let o = dir.join("o");
    let code = run(&[
        "cwt",
        &p.display().to_string(),
        "--scales",
        "2",
        "--out",
        &o.display().to_string(),
    ]);
    assert_eq!(code, 0);
    let m: Array2<f64> = read_field(&o.join("modulus_00.npy")).unwrap().data;
    // gauss support 3.2 a = 6.4 px: NaN up to x = 36, finite from x = 37
    let r = 3.2 * 2.0;
    for x in 0..128 {
        let d = if x < 30 { 0.0 } else { (x - 29) as f64 };
        let v = m[[64, x]];
        assert_eq!(v.is_nan(), d <= r, "x = {x}: {v}");
    }
}

/// paper-fbm's published range is the core range [-4, 6]: one criterion.
#[test]
fn validate_judges_the_fbm_range_once() {
    let dir = scratch("validate");
    let o = dir.join("o");
    let code = run(&[
        "validate",
        "--preset",
        "paper-fbm",
        "--count",
        "1",
        "--size",
        "512",
        "--octaves",
        "3",
        "--out",
        &o.display().to_string(),
    ]);
    assert_eq!(code, 0);
    let v = json(&o.join("validation.json"));
    let n = v["criteria"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|c| {
            c["name"]
                .as_str()
                .unwrap()
                .starts_with("max |tau - theory|")
        })
        .count();
    assert_eq!(n, 1);
}
