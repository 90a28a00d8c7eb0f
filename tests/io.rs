//! Image readers and writers against fixtures made by an independent tool
//! (`fixtures/make_fixtures.py`: numpy, tifffile, Pillow).

use std::path::{Path, PathBuf};

use ndarray::{Array2, array};
use wtmm::Error;
use wtmm::field::Field;
use wtmm::io::{
    ImageFormat, read_field, read_field_with_info, read_shape, write_field, write_npy, write_png16,
    write_tiff_f32,
};

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fixtures")
        .join(name)
}

/// A fresh, empty scratch directory per test.
fn scratch(name: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR"))
        .join("io-tests")
        .join(name);
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn read(name: &str) -> Field {
    read_field(fixture(name)).unwrap_or_else(|e| panic!("{name}: {e}"))
}

/// The pixels `make_fixtures.py` leaves missing in the DEM crop.
const HOLES: [(usize, usize); 3] = [(0, 0), (7, 13), (39, 55)];

#[test]
fn jacksboro_crop_reads_the_same_in_every_format() {
    let reference = read("dem_f8.npy");
    assert_eq!(reference.dim(), (40, 56));
    let mask = reference.mask.as_ref().expect("reference has holes");
    assert_eq!(mask.iter().filter(|&&m| m).count(), HOLES.len());
    for &(y, x) in &HOLES {
        assert!(reference.is_masked(y, x));
    }
    let (lo, hi) = reference.range().unwrap();
    assert!((300.0..400.0).contains(&lo) && (800.0..900.0).contains(&hi));

    // (file, tolerance, whether the format carries the holes, dtype)
    let cases = [
        ("dem_f4.npy", 0.0, true, "<f4"),
        ("dem_f8_be.npy", 0.0, true, ">f8"),
        ("dem_f4_fortran.npy", 0.0, true, "<f4"),
        ("dem_i2.npy", 0.0, false, "<i2"),
        ("dem_u2_be.npy", 0.0, false, ">u2"),
        ("dem_f32.tif", 0.0, true, "f32"),
        ("dem_f32_tiled_deflate.tif", 0.0, true, "f32"),
        ("dem_f32_zstd.tif", 0.0, true, "f32"),
        ("dem_i16_geo_nodata.tif", 0.0, true, "i16"),
        // 16-bit PNG: quantisation step `scale` = 0.5 (from its sidecar).
        ("dem_u16.png", 0.25, true, "u16"),
        ("dem_u16.pgm", 0.0, false, "u16"),
        ("dem.asc", 0.0, true, "text"),
    ];
    for (name, tol, holes, dtype) in cases {
        let (f, info) = read_field_with_info(fixture(name)).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(f.dim(), (40, 56), "{name}");
        assert_eq!(info.dtype, dtype, "{name}");
        assert!(info.warnings.is_empty(), "{name}: {:?}", info.warnings);
        for ((y, x), &r) in reference.data.indexed_iter() {
            let v = f.data[[y, x]];
            if mask[[y, x]] {
                if holes {
                    assert!(
                        f.is_masked(y, x) && v.is_nan(),
                        "{name} ({y},{x}) not masked"
                    );
                } else {
                    assert!(!f.is_masked(y, x) && v.is_finite(), "{name} ({y},{x})");
                }
            } else {
                assert!(!f.is_masked(y, x), "{name} ({y},{x}) wrongly masked");
                assert!((v - r).abs() <= tol, "{name} ({y},{x}): {v} vs {r}");
            }
        }
        if holes {
            assert_eq!(f.mask.as_ref(), Some(mask), "{name}");
        } else {
            assert_eq!(f.mask, None, "{name}");
        }
    }
    let (_, info) = read_field_with_info(fixture("dem_u16.png")).unwrap();
    assert_eq!(info.format, ImageFormat::Png);
    assert_eq!(info.sidecar, Some(fixture("dem_u16.json")));
}

#[test]
fn small_png_files() {
    let g = read("grey8.png");
    let expect = Array2::from_shape_fn((4, 5), |(y, x)| ((y * 5 + x) * 13) as f64);
    assert_eq!(g.data, expect);
    assert_eq!(g.mask, None);

    // Alpha 0 marks missing pixels: odd grey values were written transparent.
    let ga = read("grey_alpha.png");
    assert_eq!(ga.valid_count(), 10);
    for ((y, x), &e) in expect.indexed_iter() {
        assert_eq!(ga.is_masked(y, x), e as u32 % 2 == 1);
        if (e as u32).is_multiple_of(2) {
            assert_eq!(ga.data[[y, x]], e);
        }
    }

    let (rgb, info) = read_field_with_info(fixture("rgb.png")).unwrap();
    let lum = |r: f64, g: f64, b: f64| 0.2126 * r + 0.7152 * g + 0.0722 * b;
    let want = array![
        [lum(255., 0., 0.), lum(0., 255., 0.), lum(0., 0., 255.)],
        [lum(255., 255., 255.), 0.0, lum(10., 20., 30.)]
    ];
    assert!((&rgb.data - &want).iter().all(|d| d.abs() < 1e-9));
    assert!(
        info.warnings[0].contains("luminance"),
        "{:?}",
        info.warnings
    );

    let (pal, info) = read_field_with_info(fixture("palette.png")).unwrap();
    let (r, g, b) = (lum(255., 0., 0.), lum(0., 255., 0.), lum(0., 0., 255.));
    assert!(
        (&pal.data - &array![[r, g], [b, g]])
            .iter()
            .all(|d| d.abs() < 1e-9)
    );
    assert!(info.warnings[0].contains("palette"), "{:?}", info.warnings);

    // a sidecar nodata on a colour PNG matches its grey pixels exactly (the
    // Rec. 709 sum of (255, 255, 255) is 254.99999999999997)
    let nd = read("rgb_grey_nodata.png");
    let masked: Vec<(usize, usize)> = nd
        .data
        .indexed_iter()
        .filter(|&((y, x), _)| nd.is_masked(y, x))
        .map(|(p, _)| p)
        .collect();
    assert_eq!(masked, vec![(1, 2), (1, 3), (2, 2), (2, 3)]);
    assert_eq!(nd.data[[0, 1]], lum(15.0, 5.0, 200.0));
}

#[test]
fn small_pgm_and_tiff_files() {
    assert_eq!(
        read("p2.pgm").data,
        array![[0., 1., 2.], [253., 254., 255.]]
    );
    assert_eq!(
        read("p5_8bit.pgm").data,
        array![[0., 50., 100., 150.], [200., 0., 1., 2.]]
    );
    // a comment after maxval (netpbm allows one before the delimiting
    // whitespace; its own newline does not delimit the raster)
    let dir = scratch("pgm_comment");
    let mut bytes = b"P5 3 2 255#a comment\n\n".to_vec();
    bytes.extend([1u8, 2, 3, 10, 35, 32]);
    std::fs::write(dir.join("c.pgm"), &bytes).unwrap();
    let (c, info) = read_field_with_info(dir.join("c.pgm")).unwrap();
    assert_eq!(c.data, array![[1., 2., 3.], [10., 35., 32.]]);
    assert!(info.warnings.is_empty(), "{:?}", info.warnings);

    let i32 = read("i32.tif");
    assert_eq!(i32.data, array![[-2e9, 0., 7.], [1., 2., 2e9]]);

    let (f64t, info) = read_field_with_info(fixture("f64.tif")).unwrap();
    assert_eq!(info.dtype, "f64");
    assert!(f64t.is_masked(0, 1));
    assert_eq!(f64t.valid_count(), 5);
    assert_eq!(f64t.data[[0, 2]], 1e300);
    assert_eq!(f64t.data[[1, 2]], 1e-300);
    assert_eq!(f64t.data[[0, 0]], 0.1);

    assert_eq!(read("u8.tif").data, read("grey8.png").data);
}

#[test]
fn bad_files_give_typed_errors_naming_file_and_problem() {
    let cases = [
        ("missing.npy", "cannot read"),
        ("unknown.dat", "unknown image format"),
        ("bad_3d.npy", "expected a 2D array, got shape (2, 3, 4)"),
        ("bad_1d.npy", "got shape (5,)"),
        ("bad_complex.npy", "complex"),
        ("bad_bool.npy", "bool"),
        ("bad_str.npy", "string"),
        ("bad_empty.npy", "empty"),
        ("bad_truncated.npy", "truncated"),
        ("bad_magic.npy", "not a .npy file"),
        ("bad_truncated.png", "truncated"),
        ("bad_zero_bytes.png", "empty"),
        ("bad_empty.png", "empty image (3 x 0)"),
        ("bad_huge.png", "too large"),
        ("bad_huge.npy", "truncated"),
        ("bad_2band.tif", "2 bands"),
        ("bad_rgb.tif", "3 bands"),
        ("bad_garbage.tif", "corrupt"),
        ("bad_count.asc", "wrong value count: expected 6"),
        ("bad_header.asc", "lacks nrows"),
        ("bad_p6.pgm", "colour"),
        ("bad_truncated.pgm", "truncated"),
    ];
    for (name, word) in cases {
        let path = fixture(name);
        let err = read_field(&path).expect_err(name);
        let msg = err.to_string();
        assert!(msg.contains(name), "{name}: message lacks the file: {msg}");
        assert!(
            msg.to_lowercase().contains(&word.to_lowercase()),
            "{name}: message lacks `{word}`: {msg}"
        );
        assert!(
            matches!(err, Error::Format { .. } | Error::Read { .. }),
            "{name}: {err:?}"
        );
    }
}

/// Truncated and bit-flipped copies of every good fixture: errors, never panics.
#[test]
fn corrupt_inputs_never_panic() {
    let dir = scratch("corrupt");
    let goods = [
        "dem_f8.npy",
        "dem_f4_fortran.npy",
        "dem_i2.npy",
        "dem_f32.tif",
        "dem_f32_tiled_deflate.tif",
        "dem_i16_geo_nodata.tif",
        "f64.tif",
        "dem_u16.png",
        "grey8.png",
        "palette.png",
        "grey_alpha.png",
        "dem_u16.pgm",
        "p2.pgm",
        "dem.asc",
    ];
    let mut seed = 0x2545_f491_4f6c_dd1du64;
    let mut rand = move || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        seed
    };
    let mut errors = 0;
    for name in goods {
        let bytes = std::fs::read(fixture(name)).unwrap();
        let mut variants: Vec<Vec<u8>> = (0..24)
            .map(|k| bytes[..bytes.len() * k / 24].to_vec())
            .collect();
        for _ in 0..48 {
            let mut b = bytes.clone();
            // Corrupt mostly the header, where a bad byte does the most harm.
            let span = if rand() % 2 == 0 {
                b.len().min(200)
            } else {
                b.len()
            };
            for _ in 0..1 + rand() % 3 {
                let i = (rand() as usize) % span;
                b[i] = rand() as u8;
            }
            variants.push(b);
        }
        for (k, v) in variants.into_iter().enumerate() {
            let path = dir.join(format!("x_{k}_{name}"));
            // A new file each time: overwriting one on ext4 costs a flush.
            std::fs::write(&path, &v).unwrap();
            // the header-only size never refuses a file that reads, and
            // agrees with it
            let shape = read_shape(&path);
            match read_field(&path) {
                Err(e) => {
                    errors += 1;
                    assert!(e.to_string().contains("x_"), "{e}");
                }
                Ok(f) => {
                    let (ny, nx) = f.dim();
                    assert_eq!(shape.as_ref().ok(), Some(&[ny, nx]), "{}", path.display());
                }
            }
            if let Err(e) = shape {
                assert!(e.to_string().contains("x_"), "{e}");
            }
        }
    }
    assert!(errors > 100, "only {errors} corrupt files were rejected");
}

/// `read_shape` reads the size from the header alone: the size
/// `read_field` gives on every good fixture, the same errors on a bad
/// header, and a pass on files whose values only are bad.
#[test]
fn read_shape_reads_the_header_alone() {
    let mut goods = 0;
    for entry in std::fs::read_dir(fixture("")).unwrap() {
        let path = entry.unwrap().path();
        let name = path.file_name().unwrap().to_string_lossy().to_string();
        if name.starts_with("bad_") || ImageFormat::from_path(&path).is_none() {
            continue;
        }
        let f = read_field(&path).unwrap_or_else(|e| panic!("{e}"));
        let (ny, nx) = f.dim();
        assert_eq!(read_shape(&path).unwrap(), [ny, nx], "{name}");
        goods += 1;
    }
    assert!(goods >= 20, "{goods}");
    for (name, word) in [
        ("missing.npy", "cannot read"),
        ("unknown.dat", "unknown image format"),
        ("bad_3d.npy", "got shape (2, 3, 4)"),
        ("bad_1d.npy", "got shape (5,)"),
        ("bad_complex.npy", "complex"),
        ("bad_bool.npy", "bool"),
        ("bad_str.npy", "string"),
        ("bad_empty.npy", "empty"),
        ("bad_magic.npy", "not a .npy file"),
        ("bad_zero_bytes.png", "empty"),
        ("bad_empty.png", "empty image (3 x 0)"),
        ("bad_huge.png", "too large"),
        ("bad_garbage.tif", "corrupt"),
        ("bad_header.asc", "lacks nrows"),
        ("bad_p6.pgm", "colour"),
    ] {
        let e = read_shape(fixture(name)).expect_err(name).to_string();
        assert!(e.contains(name) && e.contains(word), "{name}: {e}");
    }
    // the values are what is wrong: only reading them says so
    for name in [
        "bad_truncated.npy",
        "bad_huge.npy",
        "bad_truncated.png",
        "bad_count.asc",
        "bad_truncated.pgm",
    ] {
        assert!(read_shape(fixture(name)).is_ok(), "{name}");
        assert!(read_field(fixture(name)).is_err(), "{name}");
    }
    // text headers read from the first 64 KiB of files far longer
    let dir = scratch("shape");
    let (ny, nx) = (230, 310);
    let values = |sep: &str| {
        (0..ny)
            .map(|y| {
                (0..nx)
                    .map(|x| ((y * 31 + x * 17) % 1000).to_string())
                    .collect::<Vec<_>>()
                    .join(sep)
            })
            .collect::<Vec<_>>()
            .join("\n")
    };
    let asc = dir.join("big.asc");
    let body = format!("ncols {nx}\nnrows {ny}\ncellsize 30\n{}\n", values(" "));
    assert!(body.len() > 1 << 17);
    std::fs::write(&asc, body).unwrap();
    let pgm = dir.join("big.pgm");
    std::fs::write(
        &pgm,
        format!("P2\n# a comment\n{nx} {ny}\n999\n{}\n", values(" ")),
    )
    .unwrap();
    // headers the first 64 KiB do not hold in whole lines: a P5 header
    // ended by spaces before a raster without a newline byte, lines ended
    // by CR only, an ASC header line longer than 64 KiB
    let p5 = dir.join("spaces.pgm");
    let mut b = format!("P5 {nx} {ny} 255 ").into_bytes();
    b.extend((0..nx * ny).map(|i| [0u8, 1, 2, 3, 5, 9, 11, 20, 40][i % 9]));
    std::fs::write(&p5, b).unwrap();
    let cr = dir.join("cr.pgm");
    std::fs::write(
        &cr,
        format!("P2\r{nx} {ny}\r999\r{}\r", values(" ")).replace('\n', "\r"),
    )
    .unwrap();
    let long = dir.join("long.asc");
    let pad = " ".repeat(70_000);
    std::fs::write(
        &long,
        format!(
            "ncols {nx}{pad}\nnrows {ny}\ncellsize 30\n{}\n",
            values(" ")
        ),
    )
    .unwrap();
    for p in [asc, pgm, p5, cr, long] {
        assert_eq!(read_shape(&p).unwrap(), [ny, nx], "{}", p.display());
        assert_eq!(read_field(&p).unwrap().dim(), (ny, nx), "{}", p.display());
    }
}

#[test]
fn extension_is_case_insensitive() {
    let dir = scratch("case");
    let p = dir.join("DEM.TIFF");
    std::fs::copy(fixture("dem_f32.tif"), &p).unwrap();
    assert_eq!(read_field(&p).unwrap().dim(), (40, 56));
}

fn test_array() -> Array2<f64> {
    let mut a = Array2::from_shape_fn((13, 17), |(y, x)| {
        (y as f64 * 0.37).sin() * 100.0 + x as f64 * 1.5 - 20.0
    });
    a[[3, 4]] = f64::NAN;
    a[[12, 16]] = f64::NAN;
    a
}

fn same_with_nan(a: &Array2<f64>, b: &Array2<f64>, tol: f64) {
    assert_eq!(a.dim(), b.dim());
    for (x, y) in a.iter().zip(b.iter()) {
        assert!(
            (x.is_nan() && y.is_nan()) || (x - y).abs() <= tol,
            "{x} vs {y}"
        );
    }
}

#[test]
fn writers_round_trip_with_nan() {
    let dir = scratch("roundtrip");
    let a = test_array();

    let p = dir.join("a.npy");
    write_npy(&p, &a).unwrap();
    let f = read_field(&p).unwrap();
    same_with_nan(&f.data, &a, 0.0);
    assert!(f.is_masked(3, 4) && f.is_masked(12, 16));

    let p = dir.join("a.tif");
    write_tiff_f32(&p, &a).unwrap();
    let (f, info) = read_field_with_info(&p).unwrap();
    assert_eq!(info.dtype, "f32");
    same_with_nan(&f.data, &a.mapv(|v| v as f32 as f64), 0.0);
    assert_eq!(f.valid_count(), a.len() - 2);

    let p = dir.join("a.png");
    let m = write_png16(&p, &a).unwrap();
    let (lo, hi) = Field::new(a.clone()).range().unwrap();
    assert_eq!((m.min, m.max, m.nodata), (Some(lo), Some(hi), 65535));
    assert!((m.scale - (hi - lo) / 65534.0).abs() < 1e-12 && m.offset == lo);
    let sidecar: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("a.json")).unwrap()).unwrap();
    assert_eq!(sidecar["scale"].as_f64(), Some(m.scale));
    assert_eq!(sidecar["offset"].as_f64(), Some(m.offset));
    assert_eq!(sidecar["nodata"].as_u64(), Some(65535));
    let (f, info) = read_field_with_info(&p).unwrap();
    assert_eq!(info.dtype, "u16");
    same_with_nan(&f.data, &a, m.scale / 2.0 * (1.0 + 1e-9));
    assert_eq!(f.valid_count(), a.len() - 2);
    // min and max land exactly on codes 0 and 65534.
    assert!((f.range().unwrap().0 - lo).abs() < 1e-9 && (f.range().unwrap().1 - hi).abs() < 1e-9);

    // Degenerate images: constant, and all missing.
    for (name, arr) in [
        ("const.png", Array2::from_elem((2, 3), 7.5)),
        ("nan.png", Array2::from_elem((2, 3), f64::NAN)),
    ] {
        let p = dir.join(name);
        write_png16(&p, &arr).unwrap();
        same_with_nan(&read_field(&p).unwrap().data, &arr, 0.0);
    }
}

/// An empty array is refused by every writer, as by every reader, and no
/// file is left behind (write_npy wrote a 0x0 file the reader refused).
#[test]
fn writers_refuse_an_empty_array() {
    let dir = scratch("empty");
    let e = Array2::<f64>::zeros((0, 0));
    let p = dir.join("e.npy");
    let err = write_npy(&p, &e).unwrap_err().to_string();
    assert!(err.contains("e.npy") && err.contains("empty"), "{err}");
    assert!(write_tiff_f32(dir.join("e.tif"), &e).is_err());
    assert!(write_png16(dir.join("e.png"), &e).is_err());
    assert!(write_npy(&p, &Array2::<f64>::zeros((0, 5))).is_err());
    assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 0);
}

#[test]
fn write_field_dispatches_and_writes_masks() {
    let dir = scratch("write_field");
    let data = array![[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]];
    let mask = array![[false, true, false], [false, false, false]];
    let field = Field::with_mask(data, mask).unwrap();
    for name in ["f.npy", "f.tif", "f.tiff", "f.png"] {
        let p = dir.join(name);
        write_field(&p, &field).unwrap();
        let back = read_field(&p).unwrap();
        assert_eq!(back.mask, field.mask, "{name}");
        same_with_nan(&back.data, &field.data, 1e-3);
    }
    let err = write_field(dir.join("f.pgm"), &field).unwrap_err();
    assert!(err.to_string().contains("f.pgm") && err.to_string().contains("cannot write"));
    let err = write_tiff_f32(dir.join("e.tif"), &Array2::zeros((0, 3))).unwrap_err();
    assert!(err.to_string().contains("empty"));
    // float32 would turn these into inf (read back as missing) or all zeros
    for v in [1e40, -1e39, 1e-300] {
        let a = Array2::from_elem((2, 3), v);
        let err = write_tiff_f32(dir.join("r.tif"), &a).unwrap_err();
        assert!(err.to_string().contains("float32"), "{v}: {err}");
        assert!(!dir.join("r.tif").exists());
    }
    let err = write_png16(dir.join("e.png"), &Array2::zeros((3, 0))).unwrap_err();
    assert!(err.to_string().contains("empty"));
}

#[test]
fn nothing_half_written() {
    let dir = scratch("atomic");
    let a = test_array();
    let missing = dir.join("no_such_dir");
    assert!(write_npy(missing.join("a.npy"), &a).is_err());
    assert!(write_tiff_f32(missing.join("a.tif"), &a).is_err());
    assert!(write_png16(missing.join("a.png"), &a).is_err());
    assert!(!missing.exists());

    // The PNG target is a directory: the PNG write fails after the sidecar
    // was written, and the sidecar must go too.
    std::fs::create_dir(dir.join("b.png")).unwrap();
    let err = write_png16(dir.join("b.png"), &a).unwrap_err();
    assert!(err.to_string().contains("b.png"), "{err}");
    let left: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .collect();
    assert_eq!(left, vec!["b.png".to_string()], "left behind: {left:?}");
}

/// ESRI ASCII grids: values are one stream (wrapped rows are fine), but a
/// data line across the end of a row is named; a byte-order mark is skipped;
/// a data line that does not start with a number is not taken as a header.
#[test]
fn asc_rows_and_headers() {
    let dir = scratch("asc_rows");
    let read_asc = |name: &str, text: &str| {
        let p = dir.join(name);
        std::fs::write(&p, text).unwrap();
        read_field_with_info(&p)
    };
    let want = array![[1., 2., 3., 4.], [5., 6., 7., 8.], [9., 10., 11., 12.]];
    let head = "ncols 4\nnrows 3\nxllcorner 0\nyllcorner 0\ncellsize 1\n";
    for (name, body, warns) in [
        ("rows.asc", "1 2 3 4\n5 6 7 8\n9 10 11 12\n", false),
        ("wrapped.asc", "1 2 3\n4\n5 6 7\n8\n9 10 11\n12\n", false),
        ("one_line.asc", "1 2 3 4 5 6 7 8 9 10 11 12\n", false),
        ("swapped.asc", "1 2 3\n4 5 6\n7 8 9\n10 11 12\n", true),
        ("ragged.asc", "1 2 3 4 5\n6 7 8\n9 10 11 12\n", true),
    ] {
        let (f, info) = read_asc(name, &format!("{head}{body}")).unwrap();
        assert_eq!(f.data, want, "{name}");
        let named = info
            .warnings
            .iter()
            .any(|w| w.contains("across the end of a row"));
        assert_eq!(named, warns, "{name}: {:?}", info.warnings);
    }
    let (f, _) = read_asc(
        "bom.asc",
        &format!("\u{feff}{head}1 2 3 4\n5 6 7 8\n9 10 11 12\n"),
    )
    .unwrap();
    assert_eq!(f.data, want);
    let err = read_asc(
        "comma.asc",
        &format!("{head}1,5 2 3 4\n5 6 7 8\n9 10 11 12\n"),
    )
    .unwrap_err()
    .to_string();
    assert!(
        err.contains("comma.asc") && err.contains("value 1 is not a number: `1,5`"),
        "{err}"
    );
}

/// A one-strip, uncompressed, one-band classic TIFF written by hand
/// (independent of the `tiff` crate): `data` holds the samples as stored.
fn tiff_by_hand(
    le: bool,
    (w, h): (u32, u32),
    photometric: u16,
    bits: u16,
    format: u16,
    data: &[u8],
    nodata: Option<&str>,
) -> Vec<u8> {
    let u16b = |v: u16| if le { v.to_le_bytes() } else { v.to_be_bytes() };
    let u32b = |v: u32| if le { v.to_le_bytes() } else { v.to_be_bytes() };
    let mut out = if le { b"II".to_vec() } else { b"MM".to_vec() };
    out.extend(u16b(42));
    out.extend(u32b(8));
    let nodata = nodata.map(|t| format!("{t}\0"));
    let mut entries: Vec<(u16, u16, u32, u32)> = vec![
        (256, 4, 1, w),
        (257, 4, 1, h),
        (258, 3, 1, bits as u32),
        (259, 3, 1, 1),
        (262, 3, 1, photometric as u32),
        (273, 4, 1, 0), // strip offset, filled below
        (277, 3, 1, 1),
        (278, 4, 1, h),
        (279, 4, 1, data.len() as u32),
        (339, 3, 1, format as u32),
    ];
    if let Some(t) = &nodata {
        entries.push((42113, 2, t.len() as u32, 0)); // text, offset filled below
    }
    let ifd_len = 2 + 12 * entries.len() + 4;
    let text_at = 8 + ifd_len;
    let text_len = nodata
        .as_ref()
        .map_or(0, |t| if t.len() > 4 { t.len() } else { 0 });
    let data_at = text_at + text_len;
    for e in &mut entries {
        match e.0 {
            273 => e.3 = data_at as u32,
            42113 => e.3 = text_at as u32,
            _ => {}
        }
    }
    out.extend(u16b(entries.len() as u16));
    for (tag, typ, count, value) in entries {
        out.extend(u16b(tag));
        out.extend(u16b(typ));
        out.extend(u32b(count));
        if typ == 3 && count == 1 {
            out.extend(u16b(value as u16));
            out.extend([0, 0]);
        } else if typ == 2 && count <= 4 {
            // a text of up to 4 bytes sits in the entry itself
            let mut v = [0u8; 4];
            let t = nodata.as_ref().unwrap().as_bytes();
            v[..t.len()].copy_from_slice(t);
            out.extend(v);
        } else {
            out.extend(u32b(value));
        }
    }
    out.extend(u32b(0));
    if let Some(t) = nodata.as_ref().filter(|t| t.len() > 4) {
        out.extend(t.as_bytes());
    }
    out.extend(data);
    out
}

/// The samples `words` (each little-endian) in the byte order `le` says.
fn ordered<const N: usize>(le: bool, words: &[[u8; N]]) -> Vec<u8> {
    words
        .iter()
        .flat_map(|w| {
            let mut w = *w;
            if !le {
                w.reverse();
            }
            w
        })
        .collect()
}

/// WhiteIsZero TIFFs are read as stored (the decoder would invert them,
/// and refuse signed ones); a 16-bit float file's nodata is matched at
/// 16-bit precision; a small file declaring a huge image is refused before
/// decoding.
#[test]
fn tiff_photometric_nodata_and_size() {
    let dir = scratch("tiff_by_hand");
    let read_tiff = |name: &str, bytes: Vec<u8>| {
        let p = dir.join(name);
        std::fs::write(&p, bytes).unwrap();
        read_field_with_info(&p)
    };
    for le in [true, false] {
        let (u8f, info) = read_tiff(
            "wiz_u8.tif",
            tiff_by_hand(le, (3, 2), 0, 8, 1, &[0, 1, 2, 250, 254, 255], Some("0")),
        )
        .unwrap();
        assert_eq!(
            u8f.data.as_slice().unwrap()[1..],
            [1., 2., 250., 254., 255.],
            "le {le}"
        );
        assert!(u8f.is_masked(0, 0), "nodata 0 is the stored 0");
        assert!(
            info.warnings.iter().any(|w| w.contains("WhiteIsZero")),
            "{:?}",
            info.warnings
        );

        let i16s = ordered(
            le,
            &[-300i16, -1, 0, 7, 1000, i16::MIN].map(i16::to_le_bytes),
        );
        let (i16f, _) = read_tiff(
            "wiz_i16.tif",
            tiff_by_hand(le, (3, 2), 0, 16, 2, &i16s, None),
        )
        .unwrap();
        assert_eq!(i16f.data, array![[-300., -1., 0.], [7., 1000., -32768.]]);

        let f32s = ordered(
            le,
            &[1234.567f32, -0.001, 0.0, 1e-30, -9999.0, 3.0].map(f32::to_le_bytes),
        );
        let (f32f, _) = read_tiff(
            "wiz_f32.tif",
            tiff_by_hand(le, (3, 2), 0, 32, 3, &f32s, Some("-9999")),
        )
        .unwrap();
        let want = [1234.567f32 as f64, -0.001f32 as f64, 0.0, 1e-30f32 as f64];
        assert_eq!(f32f.data.as_slice().unwrap()[..4], want);
        assert!(f32f.is_masked(1, 1));

        // f16: -9999 is stored as -10000 (11 significant bits)
        let f16s = ordered(
            le,
            &[0x3c00u16, 0xf0e2, 0x0000, 0x4000, 0xf0e2, 0x3c00].map(u16::to_le_bytes),
        );
        let (f16f, _) = read_tiff(
            "nodata_f16.tif",
            tiff_by_hand(le, (3, 2), 1, 16, 3, &f16s, Some("-9999")),
        )
        .unwrap();
        assert_eq!(f16f.data[[0, 0]], 1.0);
        assert_eq!(f16f.data[[1, 0]], 2.0);
        assert!(f16f.is_masked(0, 1) && f16f.is_masked(1, 1), "-9999 as f16");
        assert_eq!(f16f.valid_count(), 4);

        // 30000^2 declared, 6 bytes given: refused by size, before decoding
        let err = read_tiff(
            "huge.tif",
            tiff_by_hand(le, (30000, 30000), 1, 8, 1, &[0; 6], None),
        )
        .unwrap_err()
        .to_string();
        assert!(
            err.contains("huge.tif") && err.contains("too large: over the limit"),
            "{err}"
        );
    }
}

/// A GDAL nodata tag that cannot be read (its byte count corrupt: 768 MiB
/// claimed in a 100-byte file, or text running past the end of the file)
/// is said in a warning, not dropped in silence, and its claimed size is
/// not allocated.
#[test]
fn tiff_unreadable_nodata_tag_is_said() {
    let dir = scratch("tiff_nodata_tag");
    for le in [true, false] {
        let i16s = ordered(le, &[-9999i16, 1, 2, 3, 4, 5].map(i16::to_le_bytes));
        let good = tiff_by_hand(le, (3, 2), 1, 16, 2, &i16s, Some("-9999"));
        // the nodata entry is the last of 11 (tags in order)
        let e = 8 + 2 + 12 * 10;
        assert_eq!(good[e..e + 2], ordered(le, &[42113u16.to_le_bytes()]));
        for (name, count, word) in [
            ("huge_count.tif", 0x3000_0006u32, "805306374 bytes"),
            ("past_eof.tif", 200, "cannot be read"),
        ] {
            let mut b = good.clone();
            b[e + 4..e + 8].copy_from_slice(&ordered(le, &[count.to_le_bytes()]));
            let p = dir.join(name);
            std::fs::write(&p, b).unwrap();
            let (f, info) = read_field_with_info(&p).unwrap();
            assert!(!f.is_masked(0, 0), "{name}: no nodata known");
            assert!(
                info.warnings
                    .iter()
                    .any(|w| w.contains("GDAL nodata tag") && w.contains(word)),
                "{name}: {:?}",
                info.warnings
            );
        }
    }
}

/// A corrupt tag the decoder quotes whole (a sample format tag of 1000
/// values) gives an error of a few lines, not kilobytes.
#[test]
fn tiff_decoder_errors_are_short() {
    let dir = scratch("tiff_long_error");
    let pixels = vec![7u8; 2000];
    let mut b = tiff_by_hand(true, (50, 40), 1, 8, 1, &pixels, None);
    // SampleFormat (339), the 10th entry: 1000 SHORTs read from offset 0
    let e = 8 + 2 + 12 * 9;
    assert_eq!(b[e..e + 2], 339u16.to_le_bytes());
    b[e + 4..e + 8].copy_from_slice(&1000u32.to_le_bytes());
    b[e + 8..e + 12].copy_from_slice(&0u32.to_le_bytes());
    let p = dir.join("long_error.tif");
    std::fs::write(&p, b).unwrap();
    for err in [
        read_field(&p).unwrap_err().to_string(),
        read_shape(&p).unwrap_err().to_string(),
    ] {
        assert!(
            err.contains("long_error.tif") && err.contains("sample format"),
            "{err}"
        );
        assert!(err.len() < 400, "{} chars: {err}", err.len());
    }
}

/// LZW-tiled TIFFs that the tiff crate's LZW reader fails ("no lzw end
/// code found", image-rs/image-tiff#395) read through wtmm's own LZW
/// decoder, value for value, and say so; one it reads itself (the
/// floating-point predictor) reads without the warning. When a new `tiff`
/// release reads the first two itself, this fails on purpose: the fallback
/// may then go.
#[test]
fn lzw_tiles_read_where_the_tiff_crate_fails() {
    let reference = read("dem_f8.npy");
    for (name, dtype, fallback) in [
        ("dem_u16_tiled_lzw.tif", "u16", true),
        ("dem_i16_tiled_lzw_pred.tif", "i16", true),
        ("dem_f32_tiled_lzw_fpred.tif", "f32", false),
    ] {
        let (f, info) = read_field_with_info(fixture(name)).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(info.dtype, dtype, "{name}");
        let said = info.warnings.iter().any(|w| w.contains("image-tiff#395"));
        assert_eq!(said, fallback, "{name}: {:?}", info.warnings);
        assert_eq!(f.dim(), (40, 56), "{name}");
        for ((y, x), &r) in reference.data.indexed_iter() {
            if r.is_finite() {
                assert_eq!(f.data[[y, x]], r, "{name} ({y},{x})");
            }
        }
    }
}

/// A tag the decoder reads whose values run past the end of the file (a
/// corrupt count made the decoder allocate 128-255 MiB for a 300-byte
/// file), and an image larger than the file's strips can hold, are refused
/// as corrupt before the decoder sizes anything by them, by both readers.
#[test]
fn tiff_header_larger_than_the_file_is_refused() {
    let dir = scratch("tiff_layout");
    let pixels: Vec<u8> = (0..6).collect();
    for le in [true, false] {
        let good = tiff_by_hand(le, (3, 2), 1, 8, 1, &pixels, None);
        let len = good.len();
        // StripOffsets, the 6th entry: 2^25 LONGs from byte 8
        let e = 8 + 2 + 12 * 5;
        assert_eq!(good[e..e + 2], ordered(le, &[273u16.to_le_bytes()]));
        let mut offsets = good.clone();
        offsets[e + 4..e + 8].copy_from_slice(&ordered(le, &[(1u32 << 25).to_le_bytes()]));
        offsets[e + 8..e + 12].copy_from_slice(&ordered(le, &[8u32.to_le_bytes()]));
        // 3000 x 2000 bytes declared, uncompressed, in a file of ~150 bytes
        let mut big = tiff_by_hand(le, (3000, 2000), 1, 8, 1, &pixels, None);
        let big_len = big.len();
        let rows = 8 + 2 + 12 * 7; // RowsPerStrip: one strip, as written
        assert_eq!(big[rows..rows + 2], ordered(le, &[278u16.to_le_bytes()]));
        big[rows + 8..rows + 12].copy_from_slice(&ordered(le, &[2000u32.to_le_bytes()]));
        for (name, bytes, words) in [
            (
                "offsets.tif",
                offsets,
                vec![
                    "StripOffsets (273)".to_string(),
                    format!("33554432 values at byte 8, past the end of the file ({len} bytes)"),
                ],
            ),
            (
                "big.tif",
                big,
                vec![
                    "declares 2000 x 3000 samples of 8 bits".to_string(),
                    format!("a file of {big_len} bytes can hold (uncompressed)"),
                ],
            ),
        ] {
            let p = dir.join(name);
            std::fs::write(&p, bytes).unwrap();
            for err in [
                read_field(&p).unwrap_err().to_string(),
                read_shape(&p).unwrap_err().to_string(),
            ] {
                assert!(
                    err.contains(name) && err.contains("truncated or corrupt"),
                    "{err}"
                );
                for w in &words {
                    assert!(err.contains(w.as_str()), "{name}: {err}");
                }
            }
        }
        // a compression the decoder cannot read: said before it sizes the
        // image's buffer (5 x 16 M float32 had been 310 MiB)
        let mut odd = good.clone();
        let c = 8 + 2 + 12 * 3;
        assert_eq!(odd[c..c + 2], ordered(le, &[259u16.to_le_bytes()]));
        odd[c + 8..c + 10].copy_from_slice(&ordered(le, &[163u16.to_le_bytes()]));
        // an entry of 8-byte values with a count of 0 (had panicked)
        let mut empty = good.clone();
        let f = 8 + 2 + 12 * 9; // SampleFormat
        empty[f + 2..f + 4].copy_from_slice(&ordered(le, &[12u16.to_le_bytes()]));
        empty[f + 4..f + 8].copy_from_slice(&[0; 4]);
        for (name, bytes, word) in [
            ("odd.tif", odd, "compression method 163 is not supported"),
            (
                "empty.tif",
                empty,
                "`SampleFormat` did not have the expected value type",
            ),
        ] {
            let p = dir.join(name);
            std::fs::write(&p, bytes).unwrap();
            for err in [
                read_field(&p).unwrap_err().to_string(),
                read_shape(&p).unwrap_err().to_string(),
            ] {
                assert!(err.contains(name) && err.contains(word), "{err}");
            }
        }
        // the same file with its pixels all there reads
        let whole = tiff_by_hand(le, (300, 200), 1, 8, 1, &vec![5u8; 60_000], None);
        let p = dir.join("whole.tif");
        std::fs::write(&p, whole).unwrap();
        assert_eq!(read_field(&p).unwrap().data.dim(), (200, 300));
    }
}

/// CRC-32 of PNG chunks (ISO 3309, as the PNG spec's annex D), bit by bit.
fn png_crc(data: &[u8]) -> u32 {
    let mut c = !0u32;
    for &b in data {
        c ^= b as u32;
        for _ in 0..8 {
            c = if c & 1 == 1 {
                0xedb8_8320 ^ (c >> 1)
            } else {
                c >> 1
            };
        }
    }
    !c
}

/// A PNG whose IHDR declares more pixels than its file can inflate to
/// (zlib: at most 1032-fold) is refused before the decoder sizes its buffer
/// by the header (an 89-byte file had declared 510 MiB).
#[test]
fn png_header_larger_than_the_file_is_refused() {
    let dir = scratch("png_layout");
    let p = dir.join("small.png");
    write_png16(
        &p,
        &Array2::from_shape_fn((3, 4), |(i, j)| (i * 4 + j) as f64),
    )
    .unwrap();
    let mut b = std::fs::read(&p).unwrap();
    // IHDR data at bytes 16..29, its CRC after it
    assert_eq!(&b[12..16], b"IHDR");
    b[16..20].copy_from_slice(&5000u32.to_be_bytes());
    b[20..24].copy_from_slice(&4000u32.to_be_bytes());
    let crc = png_crc(&b[12..29]);
    b[29..33].copy_from_slice(&crc.to_be_bytes());
    let q = dir.join("liar.png");
    std::fs::write(&q, &b).unwrap();
    // 16-bit grey: 4000 rows of 1 + 10000 bytes
    let want = format!(
        "declares 4000 x 5000 pixels (40004000 bytes of image data), more than a file of {} \
         bytes can hold",
        b.len()
    );
    for err in [
        read_field(&q).unwrap_err().to_string(),
        read_shape(&q).unwrap_err().to_string(),
    ] {
        assert!(
            err.contains("liar.png") && err.contains("truncated or corrupt") && err.contains(&want),
            "{err}"
        );
    }
    // the same header with its data in the file reads (checked: the
    // small original still does)
    assert_eq!(read_field(&p).unwrap().data.dim(), (3, 4));
}

#[test]
fn png_sidecar_rules() {
    let dir = scratch("sidecar");
    let png = dir.join("s.png");
    std::fs::copy(fixture("dem_u16.png"), &png).unwrap();
    let raw = read_field(&png).unwrap();
    // No sidecar: raw integers, 65535 is just a value.
    assert_eq!(raw.mask, None);
    assert_eq!(raw.data[[0, 0]], 65535.0);

    // The shared/data convention: nodata stated only in `png_decode`.
    let json = r#"{"png_decode": "value = png*scale + offset; png==65535 -> NaN", "scale": 0.5, "offset": 100}"#;
    std::fs::write(dir.join("s.json"), json).unwrap();
    let f = read_field(&png).unwrap();
    assert_eq!(f.mask, read("dem_f8.npy").mask);

    std::fs::write(dir.join("s.json"), r#"{"units": "m"}"#).unwrap();
    let (f, info) = read_field_with_info(&png).unwrap();
    assert_eq!(f.data[[0, 0]], 65535.0);
    assert!(
        info.warnings[0].contains("no `scale`"),
        "{:?}",
        info.warnings
    );

    // nodata alone masks, values stay raw
    std::fs::write(dir.join("s.json"), r#"{"nodata": 65535, "units": "m"}"#).unwrap();
    let (f, info) = read_field_with_info(&png).unwrap();
    assert!(f.is_masked(0, 0), "nodata alone must mask");
    assert_eq!(f.mask, read("dem_f8.npy").mask);
    assert!(info.warnings.is_empty(), "{:?}", info.warnings);

    // a near miss of a key that changes the values is refused (the values
    // would be misread), and named beside the key itself
    for (text, key) in [
        (r#"{"scale": 0.5, "offest": 100}"#, "offest"),
        (r#"{"scale": 1, "offset": 0, "nodat": 65535}"#, "nodat"),
    ] {
        std::fs::write(dir.join("s.json"), text).unwrap();
        let err = read_field(&png).unwrap_err().to_string();
        assert!(
            err.contains("s.json") && err.contains(&format!("`{key}`")),
            "{err}"
        );
    }
    // provenance keys that only look alike are read past, with a word
    std::fs::write(
        dir.join("s.json"),
        r#"{"scale": 0.5, "data": "SRTM", "scale_x": 30}"#,
    )
    .unwrap();
    let (_, info) = read_field_with_info(&png).unwrap();
    assert_eq!(info.warnings.len(), 2, "{:?}", info.warnings);
    std::fs::write(
        dir.join("s.json"),
        r#"{"scale": 0.5, "offset": 1, "offest": 100}"#,
    )
    .unwrap();
    let (_, info) = read_field_with_info(&png).unwrap();
    assert!(
        info.warnings
            .iter()
            .any(|w| w.contains("`offest`") && w.contains("`offset`")),
        "{:?}",
        info.warnings
    );

    std::fs::write(dir.join("s.json"), "{not json").unwrap();
    let err = read_field(&png).unwrap_err().to_string();
    assert!(
        err.contains("s.json") && err.contains("invalid JSON"),
        "{err}"
    );
}

/// A value of a hand-written GeoTIFF tag.
enum TagVal {
    Short(Vec<u16>),
    Double(Vec<f64>),
}

/// A 4 x `h` float32 TIFF with `extra` tags, by hand (values longer than
/// the entry after the directory), in either byte order.
fn geotiff_by_hand(le: bool, h: u32, extra: Vec<(u16, TagVal)>) -> Vec<u8> {
    let w = 4u32;
    let u16b = |v: u16| if le { v.to_le_bytes() } else { v.to_be_bytes() };
    let u32b = |v: u32| if le { v.to_le_bytes() } else { v.to_be_bytes() };
    let f32b = |v: f32| if le { v.to_le_bytes() } else { v.to_be_bytes() };
    let f64b = |v: f64| if le { v.to_le_bytes() } else { v.to_be_bytes() };
    let data: Vec<u8> = (0..w * h).flat_map(|i| f32b(i as f32)).collect();
    // (tag, type, count, value bytes)
    let mut entries: Vec<(u16, u16, u32, Vec<u8>)> = vec![
        (256, 4, 1, u32b(w).to_vec()),
        (257, 4, 1, u32b(h).to_vec()),
        (258, 3, 1, u16b(32).to_vec()),
        (259, 3, 1, u16b(1).to_vec()),
        (262, 3, 1, u16b(1).to_vec()),
        (273, 4, 1, vec![]), // strip offset, filled below
        (277, 3, 1, u16b(1).to_vec()),
        (278, 4, 1, u32b(h).to_vec()),
        (279, 4, 1, u32b(data.len() as u32).to_vec()),
        (339, 3, 1, u16b(3).to_vec()),
    ];
    for (tag, v) in extra {
        entries.push(match v {
            TagVal::Short(v) => (
                tag,
                3,
                v.len() as u32,
                v.iter().flat_map(|&x| u16b(x)).collect(),
            ),
            TagVal::Double(v) => (
                tag,
                12,
                v.len() as u32,
                v.iter().flat_map(|&x| f64b(x)).collect(),
            ),
        });
    }
    entries.sort_by_key(|e| e.0);
    let mut after = 8 + 2 + 12 * entries.len() + 4;
    let mut tail: Vec<u8> = Vec::new();
    let mut ifd = u16b(entries.len() as u16).to_vec();
    let data_at = after
        + entries
            .iter()
            .filter(|e| e.3.len() > 4)
            .map(|e| e.3.len())
            .sum::<usize>();
    for (tag, typ, count, bytes) in &entries {
        ifd.extend(u16b(*tag));
        ifd.extend(u16b(*typ));
        ifd.extend(u32b(*count));
        if *tag == 273 {
            ifd.extend(u32b(data_at as u32));
        } else if bytes.len() <= 4 {
            let mut v = bytes.clone();
            v.resize(4, 0);
            ifd.extend(v);
        } else {
            ifd.extend(u32b(after as u32));
            after += bytes.len();
            tail.extend(bytes);
        }
    }
    ifd.extend(u32b(0));
    let mut out = if le { b"II".to_vec() } else { b"MM".to_vec() };
    out.extend(u16b(42));
    out.extend(u32b(8));
    out.extend(ifd);
    out.extend(tail);
    out.extend(data);
    out
}

/// GeoKeyDirectory words: version 1.1.0 and the keys, all inline.
fn geo_keys(keys: &[(u16, u16)]) -> TagVal {
    let mut w = vec![1, 1, 0, keys.len() as u16];
    for &(k, v) in keys {
        w.extend([k, 0, 1, v]);
    }
    TagVal::Short(w)
}

/// The pixel spacing GeoTIFFs and ESRI grids declare: projected units
/// named, geographic degrees made metres at the middle latitude (3 arc
/// seconds at 36 N: 75.136 x 92.466 m on WGS84), an affine transformation's
/// column lengths, Web Mercator shrunk by cos(latitude); plain files and
/// corrupt tags give none, and the image still reads.
#[test]
fn declared_pixel_spacing() {
    use wtmm::io::read_pixel_spacing;
    let dir = scratch("pixel_spacing");
    let s3 = 3.0 / 3600.0;
    for le in [true, false] {
        let get = |name: &str, h: u32, extra: Vec<(u16, TagVal)>| {
            let p = dir.join(format!("{name}-{le}.tif"));
            std::fs::write(&p, geotiff_by_hand(le, h, extra)).unwrap();
            let f = read_field(&p).unwrap();
            assert_eq!(f.dim(), (h as usize, 4), "{name}");
            assert_eq!(f.range(), Some((0.0, (4 * h - 1) as f64)), "{name}");
            read_pixel_spacing(&p).unwrap()
        };
        let utm = get(
            "utm",
            4,
            vec![
                (33550, TagVal::Double(vec![30.0, 30.0, 0.0])),
                (34735, geo_keys(&[(1024, 1), (3072, 32633)])),
            ],
        )
        .unwrap();
        assert_eq!(
            (utm.x, utm.y, utm.units.as_deref()),
            (30.0, 30.0, Some("m"))
        );
        let geo = get(
            "geo",
            40,
            vec![
                (33550, TagVal::Double(vec![s3, s3, 0.0])),
                (
                    33922,
                    TagVal::Double(vec![0.0, 0.0, 0.0, -97.0, 36.0 + 20.0 * s3, 0.0]),
                ),
                (34735, geo_keys(&[(1024, 2), (2054, 9102)])),
            ],
        )
        .unwrap();
        assert!(
            (geo.x - 75.136).abs() < 0.001 && (geo.y - 92.466).abs() < 0.001,
            "{geo:?}"
        );
        assert_eq!(geo.units.as_deref(), Some("m"));
        assert!(geo.source.contains("latitude 36.000"), "{}", geo.source);
        // arc seconds as the angular unit
        let arcsec = get(
            "arcsec",
            40,
            vec![
                (33550, TagVal::Double(vec![3.0, 3.0, 0.0])),
                (
                    33922,
                    TagVal::Double(vec![0.0, 20.0, 0.0, 0.0, 36.0 * 3600.0, 0.0]),
                ),
                (34735, geo_keys(&[(1024, 2), (2054, 9104)])),
            ],
        )
        .unwrap();
        assert!((arcsec.x - geo.x).abs() < 1e-9 && (arcsec.y - geo.y).abs() < 1e-9);
        // affine: 10 ft columns, rotated by 30 degrees
        let (c, s) = (30f64.to_radians().cos(), 30f64.to_radians().sin());
        let mut m = vec![0.0; 16];
        (m[0], m[1], m[4], m[5], m[15]) = (10.0 * c, 20.0 * s, 10.0 * s, -20.0 * c, 1.0);
        let aff = get(
            "affine",
            4,
            vec![
                (34264, TagVal::Double(m)),
                (34735, geo_keys(&[(1024, 1), (3076, 9002)])),
            ],
        )
        .unwrap();
        assert!((aff.x - 10.0).abs() < 1e-12 && (aff.y - 20.0).abs() < 1e-12);
        assert_eq!(aff.units.as_deref(), Some("ft"));
        // Web Mercator at 60 N: ground = map / 2
        let y60 = 6_378_137.0 * (60f64.to_radians().tan()).asinh();
        let merc = get(
            "merc",
            4,
            vec![
                (33550, TagVal::Double(vec![100.0, 100.0, 0.0])),
                (33922, TagVal::Double(vec![0.0, 2.0, 0.0, 0.0, y60, 0.0])),
                (34735, geo_keys(&[(1024, 1), (3072, 3857), (3076, 9001)])),
            ],
        )
        .unwrap();
        assert!(
            (merc.x - 50.0).abs() < 1e-6 && (merc.y - 50.0).abs() < 1e-6,
            "{merc:?}"
        );
        // EPSG 4326's angular unit 9122 is degrees; a negative scale
        // (south-up writers) is a spacing too
        let g9122 = get(
            "g9122",
            40,
            vec![
                (33550, TagVal::Double(vec![s3, -s3, 0.0])),
                (
                    33922,
                    TagVal::Double(vec![0.0, 0.0, 0.0, -97.0, 36.0 - 20.0 * s3, 0.0]),
                ),
                (34735, geo_keys(&[(1024, 2), (2054, 9122)])),
            ],
        )
        .unwrap();
        assert!((g9122.x - geo.x).abs() < 1e-9, "{g9122:?}");
        // projected systems named by their EPSG code alone: metres for the
        // well-known metre grids (NAD83 UTM, Lambert-93), unknown for a
        // state plane in US feet (NAD83 / Texas Central ftUS, 2277)
        let by_code = |code: u16| {
            get(
                &format!("code{code}"),
                4,
                vec![
                    (33550, TagVal::Double(vec![10.0, 10.0, 0.0])),
                    (34735, geo_keys(&[(1024, 1), (3072, code)])),
                ],
            )
            .unwrap()
        };
        for code in [26915, 2154, 27700, 3067, 32760] {
            assert_eq!(by_code(code).units.as_deref(), Some("m"), "{code}");
        }
        let ftus = by_code(2277);
        assert_eq!((ftus.x, ftus.units), (10.0, None));
        assert!(
            ftus.source.contains("units not understood"),
            "{}",
            ftus.source
        );
        // a user-defined unit (32767) whose size sits in GeoDoubleParams:
        // feet are named, fathoms (1.8288 m) become metres
        let user = |name: &str, metres: f64| {
            let mut w: Vec<u16> = vec![1, 1, 0, 3];
            w.extend([1024, 0, 1, 1, 3076, 0, 1, 32767, 3077, 34736, 1, 1]);
            get(
                name,
                4,
                vec![
                    (33550, TagVal::Double(vec![5.0, 5.0, 0.0])),
                    (34735, TagVal::Short(w)),
                    (34736, TagVal::Double(vec![7.0, metres])),
                ],
            )
            .unwrap()
        };
        let ft = user("userft", 0.3048);
        assert_eq!((ft.x, ft.units.as_deref()), (5.0, Some("ft")));
        let fathom = user("userfathom", 1.8288);
        assert!((fathom.x - 9.144).abs() < 1e-12, "{fathom:?}");
        assert_eq!(fathom.units.as_deref(), Some("m"));
        assert!(
            fathom.source.contains("a unit of 1.8288 m"),
            "{}",
            fathom.source
        );
        // the size missing (no GeoDoubleParams), or not positive: unknown
        let mut w: Vec<u16> = vec![1, 1, 0, 3];
        w.extend([1024, 0, 1, 1, 3076, 0, 1, 32767, 3077, 34736, 1, 1]);
        let nosize = get(
            "usernosize",
            4,
            vec![
                (33550, TagVal::Double(vec![5.0, 5.0, 0.0])),
                (34735, TagVal::Short(w)),
            ],
        )
        .unwrap();
        assert_eq!(nosize.units, None);
        assert_eq!(user("userzero", 0.0).units, None);
        // no GeoKeys: the spacing, units unknown
        let bare = get(
            "bare",
            4,
            vec![(33550, TagVal::Double(vec![2.0, 3.0, 0.0]))],
        )
        .unwrap();
        assert_eq!((bare.x, bare.y, bare.units), (2.0, 3.0, None));
        assert_eq!(get("plain", 4, vec![]), None);
        // a scale tag that says 3 doubles and holds garbage: none, no panic
        let p = dir.join(format!("bad-{le}.tif"));
        let mut b = geotiff_by_hand(le, 4, vec![(33550, TagVal::Double(vec![0.0, -1.0, 0.0]))]);
        std::fs::write(&p, &b).unwrap();
        assert_eq!(read_pixel_spacing(&p).unwrap(), None);
        b.truncate(60);
        std::fs::write(&p, &b).unwrap();
        assert_eq!(read_pixel_spacing(&p).unwrap(), None);
    }
    // ESRI grids: cellsize, dx/dy, a .prj's units, geographic made metres
    let grid = |name: &str, head: &str, prj: Option<&str>| {
        let p = dir.join(format!("{name}.asc"));
        std::fs::write(&p, format!("ncols 2\nnrows 2\n{head}\n1 2\n3 4\n")).unwrap();
        if let Some(t) = prj {
            std::fs::write(p.with_extension("prj"), t).unwrap();
        }
        read_pixel_spacing(&p).unwrap()
    };
    let g = grid("plain", "xllcorner 0\nyllcorner 0\ncellsize 25", None).unwrap();
    assert_eq!((g.x, g.y, g.units.as_deref()), (25.0, 25.0, None));
    assert!(g.source.contains("no .prj"), "{}", g.source);
    let g = grid(
        "dxdy",
        "dx 10\ndy 20",
        Some("PROJCS[\"x\",UNIT[\"Meter\",1.0]]"),
    )
    .unwrap();
    assert_eq!((g.x, g.y, g.units.as_deref()), (10.0, 20.0, Some("m")));
    let g = grid(
        "geo",
        &format!("xllcorner -97\nyllcorner {}\ncellsize {s3}", 36.0 - s3),
        Some("GEOGCS[\"WGS 84\",UNIT[\"degree\",0.0174532925199433]]"),
    )
    .unwrap();
    assert!(
        (g.x - 75.136).abs() < 0.001 && (g.y - 92.466).abs() < 0.001,
        "{g:?}"
    );
    assert_eq!(grid("none", "xllcorner 0", None), None);
    // a cell size that is no size: none, and said by the reader
    for (name, head) in [("zero", "cellsize 0"), ("neg", "dx 10\ndy -20")] {
        assert_eq!(grid(name, head, None), None, "{name}");
        let (_, info) = wtmm::io::read_field_with_info(dir.join(format!("{name}.asc"))).unwrap();
        assert!(
            info.warnings.iter().any(|w| w.contains("is no pixel size")),
            "{name}: {:?}",
            info.warnings
        );
    }
    // Web Mercator grid at 60 N: 100 m of map are 50 m of ground, as in
    // the GeoTIFF above
    let y60 = 6_378_137.0 * (60f64.to_radians().tan()).asinh();
    let g = grid(
        "merc",
        &format!("xllcorner 0\nyllcorner {}\ncellsize 100", y60 - 100.0),
        Some("PROJCS[\"WGS_1984_Web_Mercator_Auxiliary_Sphere\",UNIT[\"Meter\",1.0]]"),
    )
    .unwrap();
    assert!(
        (g.x - 50.0).abs() < 1e-6 && (g.y - 50.0).abs() < 1e-6,
        "{g:?}"
    );
    // a unit wtmm does not name: converted to metres by its factor
    let g = grid(
        "half",
        "cellsize 10",
        Some("PROJCS[\"x\",UNIT[\"half\",0.5]]"),
    )
    .unwrap();
    assert_eq!((g.x, g.units.as_deref()), (5.0, Some("m")));
    // world files beside a TIFF without GeoTIFF tags and a PNG
    let p = dir.join("w.tif");
    std::fs::write(&p, geotiff_by_hand(true, 4, vec![])).unwrap();
    std::fs::write(dir.join("w.tfw"), "30\n0\n0\n-30\n500000\n4000000\n").unwrap();
    std::fs::write(dir.join("w.prj"), "PROJCS[\"UTM\",UNIT[\"Meter\",1.0]]").unwrap();
    let g = read_pixel_spacing(&p).unwrap().unwrap();
    assert_eq!((g.x, g.y, g.units.as_deref()), (30.0, 30.0, Some("m")));
    assert!(g.source.contains("world file w.tfw"), "{}", g.source);
    let png = dir.join("wg.png");
    write_png16(&png, &ndarray::Array2::from_elem((40, 4), 1.0)).unwrap();
    // 3 arc seconds, first row's centre so that the middle row is at 36 N
    std::fs::write(
        dir.join("wg.pgw"),
        format!("{s3}\n0\n0\n{}\n-97\n{}\n", -s3, 36.0 + 19.5 * s3),
    )
    .unwrap();
    std::fs::write(
        dir.join("wg.prj"),
        "GEOGCS[\"WGS 84\",UNIT[\"degree\",0.0174532925199433]]",
    )
    .unwrap();
    let g = read_pixel_spacing(&png).unwrap().unwrap();
    assert!(
        (g.x - 75.136).abs() < 0.001 && (g.y - 92.466).abs() < 0.001,
        "{g:?}"
    );
    // a world file that is not six numbers: none
    std::fs::write(dir.join("w.tfw"), "30\n0\n0\n").unwrap();
    assert_eq!(read_pixel_spacing(&p).unwrap(), None);
    for f in ["a.npy", "a.png", "a.pgm"] {
        let p = dir.join(f);
        std::fs::write(&p, b"x").unwrap();
        assert_eq!(read_pixel_spacing(&p).unwrap(), None);
    }
    assert!(read_pixel_spacing(dir.join("missing.tif")).is_err());
}
