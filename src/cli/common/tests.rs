use super::memory::*;
use super::*;

/// `--fill-holes` names the pixels in holes larger than
/// LARGE_FILLED_HOLE: a 2 x 10 hole across the left and right borders
/// is one of 20 px on a torus and two of 10 on a plane; scattered
/// pixels never count as large.
#[test]
fn fill_holes_names_large_holes() {
    let (ny, nx) = (40, 50);
    let data = ndarray::Array2::from_shape_fn((ny, nx), |(y, x)| (y * 7 + x * 3) as f64);
    let mask = ndarray::Array2::from_shape_fn((ny, nx), |(y, x)| {
        ((10..20).contains(&y) && (x == 0 || x == nx - 1)) || (y == 30 && x % 5 == 2)
    });
    let f = Field::with_mask(data, mask).unwrap();
    let (plane, torus) = (HoleSizes::of(&f, false), HoleSizes::of(&f, true));
    assert_eq!((plane.missing, plane.largest, plane.in_large), (30, 10, 0));
    assert_eq!((torus.missing, torus.largest, torus.in_large), (30, 20, 20));
    // 30 px of 2000, all in small holes: tau(3) up by at most 0.0038
    let d = plane.describe();
    assert!(!d.contains("more than 16"), "{d}");
    assert!(
        d.contains("(here up to +0.004)") && !d.contains("crop"),
        "{d}"
    );
    // 20 px of 2000 in a large hole, 10 in small ones: tau(3) up by at
    // most 0.0055 + 0.0013
    let d = torus.describe();
    assert!(
        d.starts_with("1.5 % of the pixels; the largest hole holds 20 px; 1.0 %"),
        "{d}"
    );
    assert!(
        d.contains("(here up to +0.007)") && !d.contains("crop"),
        "{d}"
    );
    assert_eq!(
        torus.brief(),
        "1.5 %, the largest hole 20 px, 1.0 % in holes of more than 16 px; tau(3) raised \
         by up to +0.007"
    );
    assert_eq!(
        plane.brief(),
        "1.5 %, the largest hole 10 px; tau(3) raised by up to +0.004"
    );
    // one image with 3 % in a large hole: told to crop it, whatever
    // the ensemble's share
    let big = HoleSizes {
        missing: 300,
        largest: 300,
        in_large: 300,
        area: 10_000,
    };
    assert!(
        big.brief()
            .ends_with("; crop the large holes out if you can")
    );
    // a record holding more in large holes than filled: no underflow
    let odd = HoleSizes {
        missing: 100,
        largest: 200,
        in_large: 200,
        area: 10_000,
    };
    // the large holes' 2 % alone: 0.0055 x 2
    assert!(odd.brief().contains("up to +0.011"), "{}", odd.brief());
}

/// An error that would round to zero keeps two significant digits.
#[test]
fn no_error_bar_reads_zero() {
    assert_eq!(plus_minus(0.0150, 0.000419, 3), "0.01500 ± 0.00042");
    assert_eq!(plus_minus(1.5, 0.0035, 3), "1.500 ± 0.004");
    assert_eq!(plus_minus(1.5, 0.001, 3), "1.500 ± 0.001");
    assert_eq!(plus_minus(-0.37, 0.0, 3), "-0.370 ± 0.000");
    assert_eq!(plus_minus(0.5, f64::NAN, 2), "0.50");
    assert_eq!(
        plus_minus(0.5, 1e-13, 3),
        format!("{:.12} ± {:.12}", 0.5, 1e-13)
    );
    assert_eq!(
        plus_minus(1.0, 1e-20, 13),
        format!("{:.13} ± {:.13}", 1.0, 1e-20)
    );
}

/// Figure titles name the first and last files, with their directories
/// when there are several; generated labels are not named.
#[test]
fn data_labels() {
    use crate::spectra::ShapeCount;
    let sq = [ShapeCount {
        ny: 512,
        nx: 512,
        images: 4,
    }];
    assert_eq!(
        data_label(&["d/a.npy", "d/b.npy"], 2, &sq),
        "a.npy .. b.npy, 2 x 512^2"
    );
    assert_eq!(
        data_label(
            &["big/a.npy", "x/small/b.npy"],
            2,
            &[sq[0], ShapeCount { ny: 256, ..sq[0] }]
        ),
        "big/a.npy .. small/b.npy, 2 x mixed sizes"
    );
    assert_eq!(data_label(&["a.npy"], 1, &sq), "a.npy, 1 x 512^2");
    assert_eq!(data_label(&["image 1", "image 2"], 2, &sq), "2 x 512^2");
}

/// A 16384^2 image needs about 14.5 GB on one thread (54 B/px, measured
/// 52 on 4096^2; 18.8 GB with missing pixels, whose filled copy, mask
/// and distance map add 16)
/// and 22 GB on two: refused with 8 GB, not with 32.
/// `tm` on a lone 16384^2 DEM: 38 GB on one thread, 50 GB on two or
/// more (the tasks are bounded, so 16 threads need no more than 3).
#[test]
fn tm_memory_is_checked_before_reading() {
    let px = 16384 * 16384;
    let w = tm_memory_problem(16384, 16384, px, 1, 32e9).unwrap();
    assert!(w.contains("about 38.4 GB of memory (1 thread)"), "{w}");
    assert!(!w.contains("RAYON_NUM_THREADS"), "{w}");
    assert!(tm_memory_problem(16384, 16384, px, 1, 40e9).is_none());
    let w = tm_memory_problem(16384, 16384, px, 16, 40e9).unwrap();
    assert!(w.contains("about 58.8 GB of memory (16 threads)"), "{w}");
    assert!(w.contains("RAYON_NUM_THREADS=1, about 38.4 GB"), "{w}");
    assert_eq!(
        tm_memory_problem(16384, 16384, px, 3, 1e9),
        tm_memory_problem(16384, 16384, px, 16, 1e9).map(|w| w.replace("16 threads", "3 threads"))
    );
    // two images: the other one's pixels count too
    let w = tm_memory_problem(4096, 4096, 2 * 4096 * 4096, 1, 4e9).unwrap();
    assert!(
        w.contains("4096x4096 image and the other need about 4.8 GB"),
        "{w}"
    );
}

#[test]
fn cgroup_limits_are_read() {
    // v1 (hybrid host): the memory controller's line; v2: `0::`
    let own = "9:name=systemd:/\n4:memory:/job/42\n3:cpu,cpuacct:/\n0::/\n";
    assert_eq!(cgroup_path(own, "memory"), Some("/job/42"));
    assert_eq!(cgroup_path(own, "cpuacct"), Some("/"));
    assert_eq!(cgroup_path(own, ""), Some("/"));
    assert_eq!(cgroup_path("0::/user.slice/x\n", "memory"), None);
    assert_eq!(cgroup_path("0::/user.slice/x\n", ""), Some("/user.slice/x"));
    let stat = "cache 10\nhierarchical_memory_limit 8589934592\ntotal_inactive_file 1000\n\
                inactive_file 7\n";
    assert_eq!(
        stat_value(stat, "hierarchical_memory_limit"),
        Some(8589934592.0)
    );
    assert_eq!(stat_value(stat, "total_inactive_file"), Some(1000.0));
    assert_eq!(stat_value(stat, "inactive_file"), Some(7.0));
    assert_eq!(stat_value(stat, "missing"), None);
    // 8 GB limit, 3 GB used of which 1 GB reclaimable: 6 GB left
    assert_eq!(headroom(8e9, 3e9, 1e9), Some(6e9));
    assert_eq!(headroom(8e9, 9e9, 0.0), Some(0.0));
    // v1 writes "no limit" as 2^63 rounded down to a page
    assert_eq!(headroom(9223372036854771712.0, 3e9, 0.0), None);
    assert_eq!(
        meminfo_available("MemTotal: 100 kB\nMemAvailable: 2 kB\n"),
        Some(2048.0)
    );
    assert_eq!(memory_text(3.5e8), "350 MB");
    assert_eq!(memory_text(2.26e9), "2.3 GB");
}

/// Fake cgroup trees: the lowest headroom up the ancestors, the file
/// cache (active and inactive) counted as free, levels without the
/// files passed over, no limit read as none.
#[test]
fn cgroup_headroom_walks_the_ancestors() {
    let dir = std::env::temp_dir().join(format!("wtmm_cgroup_{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let put = |rel: &str, name: &str, text: &str| {
        let d = dir.join(rel);
        std::fs::create_dir_all(&d).unwrap();
        std::fs::write(d.join(name), text).unwrap();
    };
    let gb = 1e9;
    // v2: a job of 16 GB holding 12 GB, 10 GB of it active file cache;
    // its step has no memory files (the controller not enabled below)
    put("v2", "cgroup.controllers", "memory\n");
    put("v2/job", "memory.max", "16000000000\n");
    put("v2/job", "memory.current", "12000000000\n");
    put(
        "v2/job",
        "memory.stat",
        "anon 1500000000\nactive_file 10000000000\ninactive_file 500000000\n",
    );
    std::fs::create_dir_all(dir.join("v2/job/step")).unwrap();
    let v2 = dir.join("v2");
    let h = cgroup_headroom_in("0::/job/step\n", &v2).unwrap();
    assert!((h - 14.5 * gb).abs() < 1.0, "{h}");
    // a step limit of its own, lower: it binds
    put("v2/job/step", "memory.max", "3000000000\n");
    put("v2/job/step", "memory.current", "1000000000\n");
    let h = cgroup_headroom_in("0::/job/step\n", &v2).unwrap();
    assert!((h - 2.0 * gb).abs() < 1.0, "{h}");
    // no limit anywhere: none
    assert_eq!(cgroup_headroom_in("0::/\n", &v2), None);
    put("v2/free", "memory.max", "max\n");
    put("v2/free", "memory.current", "5\n");
    assert_eq!(cgroup_headroom_in("0::/free\n", &v2), None);
    // over the limit: nothing left (not negative)
    put("v2/over", "memory.max", "1000\n");
    put("v2/over", "memory.current", "2000\n");
    assert_eq!(cgroup_headroom_in("0::/over\n", &v2), Some(0.0));
    // v1: a job of 16 GB with 15 GB used by other steps binds a step
    // that uses little
    let v1 = dir.join("v1");
    put(
        "v1/memory",
        "memory.limit_in_bytes",
        "9223372036854771712\n",
    );
    put("v1/memory", "memory.usage_in_bytes", "30000000000\n");
    put("v1/memory/job", "memory.limit_in_bytes", "16000000000\n");
    put("v1/memory/job", "memory.usage_in_bytes", "15000000000\n");
    put(
        "v1/memory/job",
        "memory.stat",
        "total_active_file 0\ntotal_inactive_file 0\n",
    );
    put(
        "v1/memory/job/step",
        "memory.limit_in_bytes",
        "9223372036854771712\n",
    );
    put("v1/memory/job/step", "memory.usage_in_bytes", "100000000\n");
    let own = "4:memory:/job/step\n0::/\n";
    let h = cgroup_headroom_in(own, &v1).unwrap();
    assert!((h - 1.0 * gb).abs() < 1.0, "{h}");
    // inside a namespace the own path is not under the mount: the
    // mount's root is the own group
    assert_eq!(cgroup_headroom_in("4:memory:/elsewhere\n", &v1), None);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn ensembles_run_on_the_workers_the_memory_holds() {
    let gb = 1e9;
    // three images of 100 M px at 150 B/px: 15 GB each in flight
    let px = [100_000_000; 3];
    assert_eq!(workers_that_fit(&px, 150.0, 16, 50.0 * gb), 3);
    assert_eq!(workers_that_fit(&px, 150.0, 16, 44.0 * gb), 2);
    assert_eq!(workers_that_fit(&px, 150.0, 2, 44.0 * gb), 2);
    assert_eq!(workers_that_fit(&px, 150.0, 1, 44.0 * gb), 1);
    assert_eq!(workers_that_fit(&px, 150.0, 16, 14.0 * gb), 0);
    // the largest images are the ones counted, whatever their order
    let px = [10_000_000, 100_000_000, 20_000_000, 100_000_000];
    assert_eq!(workers_that_fit(&px, 150.0, 16, 15.0 * gb), 1);
    assert_eq!(workers_that_fit(&px, 150.0, 16, 30.0 * gb), 2);
    assert_eq!(workers_that_fit(&px, 150.0, 16, 33.0 * gb), 3);
    assert_eq!(workers_that_fit(&px, 150.0, 16, 34.5 * gb), 4);
    assert_eq!(workers_that_fit(&[], 150.0, 16, gb), 0);
}

#[test]
fn large_images_are_refused_before_the_transform() {
    let w = image_memory_problem(16384, 16384, false, 1, 8e9).unwrap();
    assert!(
        w.contains("about 14.5 GB") && w.contains("8.0 GB are available"),
        "{w}"
    );
    let w = image_memory_problem(16384, 16384, true, 1, 8e9).unwrap();
    assert!(w.contains("about 18.8 GB"), "{w}");
    assert!(image_memory_problem(16384, 16384, true, 1, 32e9).is_none());
    let w = image_memory_problem(16384, 16384, false, 2, 20e9).unwrap();
    assert!(
        w.contains("22.0 GB") && w.contains("RAYON_NUM_THREADS=1, about 14.5"),
        "{w}"
    );
    // an ordinary DEM passes anywhere
    assert!(image_memory_problem(4096, 4096, true, 2, 2e9).is_none());
}

/// The spectrum and the transform beyond the images read: a 16384^2
/// DEM's spectrum needs 8.9 GB per image in flight, its transform 20.7.
#[test]
fn spectrum_and_cwt_memory_are_checked() {
    let w = extra_memory_problem("the power spectrum", 16384, 16384, 33.0, 2, 8e9).unwrap();
    assert!(
        w.contains("about 17.7 GB") && w.contains("(2 in flight)") && w.contains("RAYON"),
        "{w}"
    );
    assert!(extra_memory_problem("the power spectrum", 16384, 16384, 33.0, 1, 16e9).is_none());
    let w = extra_memory_problem("the transform", 16384, 16384, 77.0, 1, 16e9).unwrap();
    assert!(w.contains("about 20.7 GB") && !w.contains("RAYON"), "{w}");
    assert!(extra_memory_problem("the transform", 4096, 4096, 77.0, 1, 2e9).is_none());
}

#[test]
fn lists_are_parsed_sorted_and_distinct() {
    assert_eq!(
        parse_list("q", "-1:1:0.5").unwrap(),
        vec![-1.0, -0.5, 0.0, 0.5, 1.0]
    );
    // the stop is kept despite rounding of the step
    assert_eq!(parse_list("q", "0:0.3:0.1").unwrap().len(), 4);
    assert_eq!(
        parse_list("q", "2,0,-2, 1").unwrap(),
        vec![-2.0, 0.0, 1.0, 2.0]
    );
    assert_eq!(parse_list("q", "3").unwrap(), vec![3.0]);
    // the decimal grid meant, not the binary sums a + i step
    let v = parse_list("q", "-0.3:3:0.1").unwrap();
    assert_eq!(v[3], 0.0);
    assert_eq!(v[23], 2.0);
    assert_eq!(v[33], 3.0);
    assert!(parse_list("q", "-7.2:8:0.2").unwrap().contains(&2.0));
    for bad in [
        "0,1,1,2",
        "1:0:1",
        "0:1:0",
        "0:1:-1",
        "a,b",
        "1:2",
        "nan",
        "",
        "0:1e9:1e-9",
        "0:nan:1",
        "nan:1:1",
        "0:inf:1",
        "0:1:nan",
    ] {
        let e = parse_list("q", bad).unwrap_err().to_string();
        assert!(e.contains("--q") || e.contains("q"), "{bad}: {e}");
    }
    assert_eq!(parse_q("q", "-1000,1000").unwrap(), vec![-1000.0, 1000.0]);
    // the library's default grids are the CLI's, to the bit
    assert_eq!(
        parse_q("q", "-4:6:0.5").unwrap(),
        crate::spectra::default_q()
    );
    assert_eq!(
        parse_q("q", "0.1:4:0.1").unwrap(),
        crate::tracemoments::TraceMomentConfig::default().q
    );
    for bad in ["1e308", "-1001", "0:2000:1000"] {
        let e = parse_q("q", bad).unwrap_err().to_string();
        assert!(e.contains("beyond |q| = 1000"), "{bad}: {e}");
    }
    assert!(
        parse_list("q", "0,1,1")
            .unwrap_err()
            .to_string()
            .contains("1 is given twice")
    );
    let e = parse_list("q", "0,1e-10").unwrap_err().to_string();
    assert!(e.contains("0 and 0.0000000001 are closer than 1e-9"), "{e}");
}

#[test]
fn csv_fields_with_commas_or_quotes_are_quoted() {
    assert_eq!(csv_field("K(q=1.5,eta)"), "\"K(q=1.5,eta)\"");
    assert_eq!(csv_field("a \"b\""), "\"a \"\"b\"\"\"");
    assert_eq!(csv_field("lnM"), "lnM");
    let dir = std::env::temp_dir().join(format!("wtmm-csv-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let p = dir.join("t.csv");
    let rows = vec![vec!["1".to_string(), "x,y.npy".to_string()]];
    write_csv(&p, &["eta", "K(q=0.5,eta)"], &rows).unwrap();
    let text = std::fs::read_to_string(&p).unwrap();
    assert_eq!(text, "eta,\"K(q=0.5,eta)\"\n1,\"x,y.npy\"\n");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn ranges_need_lo_below_hi() {
    assert_eq!(parse_range("fit", "0.5:4").unwrap(), (0.5, 4.0));
    for bad in ["4:0.5", "1:1", "1", "a:2"] {
        assert!(parse_range("fit", bad).is_err(), "{bad}");
    }
}

#[test]
fn error_bar_labels_carry_their_caveat() {
    assert_eq!(
        se_label("jackknife over images", 32),
        "jackknife over 32 images"
    );
    assert_eq!(
        se_label("jackknife over images; regression for q = 0", 32),
        "jackknife over 32 images, regression for some (understates)"
    );
    assert_eq!(
        se_label("jackknife over 49 tiles (45 px)", 1),
        "jackknife over 49 tiles of 1 image: may understate"
    );
    assert_eq!(se_label("regression", 1), "regression: understates");
    assert_eq!(se_label("none", 1), "none");
}
