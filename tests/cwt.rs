//! The CWT against mathematics: a direct spatial convolution with the sampled
//! wavelet, exact polynomial cases, rotation covariance, serial = parallel.

use ndarray::Array2;
use num_complex::Complex64;
use wtmm::cwt::{CwtPlan, ScaleGrid, Wavelet, direct_transform_at, modulus};
use wtmm::skeleton::AnalysisConfig;
use wtmm::synth::fbm::{FbmParams, fbm};

/// Deterministic rough test image (no RNG needed): a sum of incommensurate waves.
fn waves(ny: usize, nx: usize) -> Array2<f64> {
    Array2::from_shape_fn((ny, nx), |(y, x)| {
        let (x, y) = (x as f64, y as f64);
        (0.37 * x + 0.11 * y).sin()
            + 0.5 * (1.3 * x - 0.7 * y).cos()
            + 0.25 * (2.1 * y + 0.2).sin()
            + ((x * 7.3 + y * 3.1).sin() * 1000.0).fract()
    })
}

fn all_scales(plan: &CwtPlan, img: &Array2<f64>) -> Vec<Array2<Complex64>> {
    let mut v = Vec::new();
    plan.for_each_scale(img.view(), |_, _, t| v.push(t.clone()))
        .unwrap();
    v
}

/// FFT CWT = periodic direct convolution with the sampled wavelet. The two
/// differ only by frequency aliasing and the Nyquist convention: a Fourier
/// component's error is at most the wavelet's spectrum at the Nyquist
/// frequency, `|ψ̂(π)|`, against the `max |ψ̂|` that carries the largest
/// values of T (gauss `ψ̂ ∝ ak e^(-(ak)²/2)`, mexican `(ak)³ e^(-(ak)²/2)`):
/// 1.2e-4 (gauss) and 1.4e-3 (mexican) at a = 1.5, where 1.5e-5 and 2.4e-4
/// are seen; below 1e-17 from a = 3, where 1e-9 relative bounds rounding.
#[test]
fn equals_direct_convolution_odd_and_even_sizes() {
    for &(ny, nx) in &[(48, 40), (37, 29)] {
        let img = waves(ny, nx);
        for wavelet in [Wavelet::Gauss, Wavelet::Mexican] {
            let scales = [1.5, 2.0, 3.0, 4.5];
            let plan = CwtPlan::new(ny, nx, wavelet, &scales).unwrap();
            let ts = all_scales(&plan, &img);
            for (j, &a) in scales.iter().enumerate() {
                let (n, peak) = match wavelet {
                    Wavelet::Gauss => (1, 1.0f64),
                    Wavelet::Mexican => (3, 3f64.sqrt()),
                };
                let spec = |u: f64| u.powi(n) * (-0.5 * u * u).exp();
                let tol = (spec(a * std::f64::consts::PI) / spec(peak)).max(1e-9);
                let scale = ts[j].iter().map(|&z| modulus(z)).fold(0.0, f64::max);
                for y in (0..ny).step_by(5) {
                    for x in (0..nx).step_by(3) {
                        let d = direct_transform_at(img.view(), wavelet, a, y, x);
                        let e = modulus(ts[j][[y, x]] - d) / scale;
                        assert!(
                            e < tol,
                            "{wavelet} a={a} ({y},{x}) {ny}x{nx}: rel err {e:e} (bound {tol:e})"
                        );
                    }
                }
            }
        }
    }
}

/// On f = c x, gauss gives T = (a c, 0) and mexican gives 0, away from the
/// periodic jump at the border (12 a keeps its spatial influence below e^-70).
/// The jump (height N c) also leaves a spectral residue of relative size
/// exp(-(a pi)^2 / 2) at the Nyquist frequency, where the discrete derivative
/// is set to zero: 2.7e-9 at a = 2, 1e-34 at a = 4. The tolerance is that
/// bound plus rounding.
#[test]
fn linear_ramp() {
    let (n, c) = (256, 0.3);
    let img = Array2::from_shape_fn((n, n), |(_, x)| c * x as f64);
    let scales = [2.0, 4.0, 8.0];
    for wavelet in [Wavelet::Gauss, Wavelet::Mexican] {
        let plan = CwtPlan::new(n, n, wavelet, &scales).unwrap();
        let ts = all_scales(&plan, &img);
        for (j, &a) in scales.iter().enumerate() {
            let lo = (12.0 * a) as usize;
            let tol = 1e-9 * a * c
                + 4.0 * n as f64 * c * (-(a * std::f64::consts::PI).powi(2) / 2.0).exp();
            for y in (0..n).step_by(17) {
                for x in lo..n - lo {
                    let t = ts[j][[y, x]];
                    let want = if wavelet == Wavelet::Gauss {
                        a * c
                    } else {
                        0.0
                    };
                    assert!(
                        (t.re - want).abs() < tol,
                        "{wavelet} a={a}: T1 {} want {want}",
                        t.re
                    );
                    assert!(t.im.abs() < tol, "{wavelet} a={a}: T2 {}", t.im);
                }
            }
        }
    }
}

/// A quadratic is annihilated by mexican (3 vanishing moments) but not by
/// gauss. The quadratic is built periodic-free by testing far from borders.
#[test]
fn quadratic_mexican_is_blind() {
    let n = 256;
    let img = Array2::from_shape_fn((n, n), |(y, x)| {
        let (u, v) = (x as f64 - 128.0, y as f64 - 128.0);
        1e-3 * (u * u + 0.5 * v * v - u * v)
    });
    let a = 4.0;
    let lo = 90; // > 12 a from both borders at a = 4 ... and the quadratic's jump
    let m = |w| {
        let plan = CwtPlan::new(n, n, w, &[a]).unwrap();
        let t = all_scales(&plan, &img).remove(0);
        let mut mx: f64 = 0.0;
        for y in lo..n - lo {
            for x in lo..n - lo {
                mx = mx.max(modulus(t[[y, x]]));
            }
        }
        mx
    };
    let (g, mex) = (m(Wavelet::Gauss), m(Wavelet::Mexican));
    // gauss sees the gradient: |∇f| a ~ 1e-3 * 2*38*4 = 0.3 at the box corner
    assert!(g > 0.1, "gauss {g}");
    assert!(mex < 1e-9 * g, "mexican {mex} vs gauss {g}");
}

#[test]
fn constant_image_gives_zero() {
    let img = Array2::from_elem((64, 50), 123.456);
    for wavelet in [Wavelet::Gauss, Wavelet::Mexican] {
        let plan = CwtPlan::new(64, 50, wavelet, &[1.5, 3.0, 6.0]).unwrap();
        for t in all_scales(&plan, &img) {
            let mx = t.iter().map(|&z| modulus(z)).fold(0.0, f64::max);
            assert_eq!(mx, 0.0, "{wavelet}: exactly zero");
        }
    }
}

/// The smoothed image keeps the image's level (the transform takes it off
/// before the FFT): a constant stays that constant under the Gaussian, and
/// a smoothed field keeps the field's mean (periodic convolution).
#[test]
fn smoothed_image_keeps_its_level() {
    let plan = CwtPlan::new(64, 50, Wavelet::Gauss, &[2.0]).unwrap();
    let c = Array2::from_elem((64, 50), 123.456);
    let sm = plan.smoothed(&plan.forward(c.view()).unwrap(), 2.0);
    assert!(
        sm.iter().all(|v| (v - 123.456).abs() < 1e-12),
        "{}",
        sm[[0, 0]]
    );
    let w = waves(64, 50) + 1000.0;
    let sm = plan.smoothed(&plan.forward(w.view()).unwrap(), 2.0);
    let mean = sm.mean().unwrap();
    assert!((mean - w.mean().unwrap()).abs() < 1e-9, "{mean}");
}

/// The smoothed image is `φ_a * f` (II Fig 9) with the wavelet's own φ:
/// the Gaussian `e^(-r²/2)/2π`, and for mexican the Mexican hat `(2 - r²)
/// e^(-r²/2)/2π` (`φ̂ = a²|k|² e^(-a²k²/2)`), both scaled as `a⁻² φ(x/a)`;
/// against a periodic direct convolution, to 1e-9 of the largest value
/// (aliasing `exp(-(a π)²/2) < 1e-19` at a = 3, as for the transform).
#[test]
fn smoothed_image_equals_direct_convolution() {
    let (ny, nx) = (48, 40);
    let img = waves(ny, nx);
    for wavelet in [Wavelet::Gauss, Wavelet::Mexican] {
        for a in [3.0, 4.5] {
            let plan = CwtPlan::new(ny, nx, wavelet, &[a]).unwrap();
            let sm = plan.smoothed(&plan.forward(img.view()).unwrap(), a);
            let scale = sm.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            let r = (10.0 * a).ceil() as isize;
            for y in (0..ny).step_by(7) {
                for x in (0..nx).step_by(5) {
                    let mut d = 0.0;
                    for dy in -r..=r {
                        for dx in -r..=r {
                            let (ux, uy) = (dx as f64 / a, dy as f64 / a);
                            let r2 = ux * ux + uy * uy;
                            let g = (-0.5 * r2).exp() / (2.0 * std::f64::consts::PI);
                            let phi = match wavelet {
                                Wavelet::Gauss => g,
                                Wavelet::Mexican => (2.0 - r2) * g,
                            };
                            let yy = (y as isize - dy).rem_euclid(ny as isize) as usize;
                            let xx = (x as isize - dx).rem_euclid(nx as isize) as usize;
                            d += phi * img[[yy, xx]];
                        }
                    }
                    d /= a * a;
                    let e = (sm[[y, x]] - d).abs() / scale;
                    assert!(
                        e < 1e-9,
                        "{wavelet} a={a} ({y},{x}): {} vs {d}, rel err {e:e}",
                        sm[[y, x]]
                    );
                }
            }
        }
    }
}

/// Rotating the image by 90 degrees rotates T: with f2[y][x] = f[n-1-x][y],
/// T1'[y][x] = -T2[n-1-x][y] and T2'[y][x] = T1[n-1-x][y]. Exact on a square
/// periodic grid (the frequency grid and the Nyquist rule are symmetric).
#[test]
fn rotation_covariance() {
    let n = 64;
    let img = waves(n, n);
    let rot = Array2::from_shape_fn((n, n), |(y, x)| img[[n - 1 - x, y]]);
    for wavelet in [Wavelet::Gauss, Wavelet::Mexican] {
        let plan = CwtPlan::new(n, n, wavelet, &[1.5, 5.0]).unwrap();
        let t = all_scales(&plan, &img);
        let r = all_scales(&plan, &rot);
        for j in 0..2 {
            let scale = t[j].iter().map(|&z| modulus(z)).fold(0.0, f64::max);
            for y in 0..n {
                for x in 0..n {
                    let o = t[j][[n - 1 - x, y]];
                    let want = Complex64::new(-o.im, o.re);
                    let e = modulus(r[j][[y, x]] - want) / scale;
                    assert!(e < 1e-12, "{wavelet} ({y},{x}): {e:e}");
                }
            }
        }
    }
}

#[test]
fn parallel_is_bit_identical_to_serial() {
    let img = fbm(FbmParams { hurst: 0.4 }, 96, 80, 7, 0).unwrap();
    let scales: Vec<f64> = (0..12).map(|j| 1.5 * 2f64.powf(j as f64 / 4.0)).collect();
    let plan = CwtPlan::new(96, 80, Wavelet::Mexican, &scales).unwrap();
    let serial = all_scales(&plan, &img);
    let par = plan
        .par_map_scales(img.view(), |_, _, t| t.clone())
        .unwrap();
    assert_eq!(serial.len(), par.len());
    for (a, b) in serial.iter().zip(&par) {
        assert!(
            a.iter()
                .zip(b)
                .all(|(x, y)| x.re.to_bits() == y.re.to_bits() && x.im.to_bits() == y.im.to_bits())
        );
    }
}

#[test]
fn bad_input_is_an_error() {
    assert!(CwtPlan::new(4, 64, Wavelet::Gauss, &[2.0]).is_err());
    assert!(CwtPlan::new(64, 64, Wavelet::Gauss, &[]).is_err());
    assert!(CwtPlan::new(64, 64, Wavelet::Gauss, &[-1.0]).is_err());
    let plan = CwtPlan::new(16, 16, Wavelet::Gauss, &[2.0]).unwrap();
    let mut img = Array2::zeros((16, 16));
    img[[3, 3]] = f64::NAN;
    assert!(plan.forward(img.view()).is_err());
    assert!(plan.forward(Array2::zeros((8, 16)).view()).is_err());
    // scales beyond any image, and numbers short in the messages
    let g = ScaleGrid {
        a_min: 1e300,
        ..Default::default()
    };
    let e = g.validate().unwrap_err().to_string();
    assert!(e.contains("`a-min`") && e.contains("1.000e300"), "{e}");
    assert!(ScaleGrid::default().validate().is_ok());
    let cfg = AnalysisConfig {
        a_min: 1e-300,
        ..Default::default()
    };
    let e = cfg.validate().unwrap_err().to_string();
    assert!(e.contains("`a-min`") && e.len() < 200, "{e}");
}

/// The row-streamed transform equals the full one bit for bit, whatever the
/// row range (aligned or not, a single row, the whole image, an empty one),
/// at scales where rows are pruned and where none is, on a non-square image
/// whose width is no multiple of the block; blocks arrive in order with the
/// previous one alongside. 256 rows of the spectrum lie 4 KiB apart, so
/// the streamed path pads them (`padded_stride`) while the full one does
/// not: one workspace alternating between the two stays exact.
#[test]
fn streamed_rows_equal_the_full_transform() {
    for (ny, nx, wavelet) in [
        (70, 53, Wavelet::Gauss),
        (70, 53, Wavelet::Mexican),
        (256, 53, Wavelet::Gauss),
        (256, 53, Wavelet::Mexican),
    ] {
        let img = waves(ny, nx);
        let plan = CwtPlan::new(ny, nx, wavelet, &[1.2, 4.0, 11.0]).unwrap();
        let fi = plan.forward(img.view()).unwrap();
        let mut ws = plan.workspace();
        for j in 0..3 {
            let full = plan.scale(&fi, j, &mut ws).clone();
            for rows in [0..ny, 3..41, 8..16, 17..18, 60..200, 5..5] {
                let mut got = Vec::new();
                let mut last_end: Option<(usize, Vec<Complex64>)> = None;
                plan.scale_rows(&fi, j, &mut ws, rows.clone(), |y0, prev, cur| {
                    assert_eq!(cur.len() % nx, 0);
                    match (&last_end, prev) {
                        (None, None) => assert_eq!(y0, rows.start),
                        (Some((end, p)), Some(q)) => {
                            assert_eq!(y0, *end);
                            assert_eq!(p.as_slice(), q, "prev is the block delivered before");
                        }
                        _ => panic!("prev given exactly when a block came before"),
                    }
                    got.extend_from_slice(cur);
                    last_end = Some((y0 + cur.len() / nx, cur.to_vec()));
                });
                let want: Vec<Complex64> = full
                    .rows()
                    .into_iter()
                    .skip(rows.start)
                    .take(rows.end.min(ny).saturating_sub(rows.start))
                    .flat_map(|r| r.to_vec())
                    .collect();
                assert!(
                    got.len() == want.len()
                        && got
                            .iter()
                            .zip(&want)
                            .all(|(g, w)| g.re.to_bits() == w.re.to_bits()
                                && g.im.to_bits() == w.im.to_bits()),
                    "{wavelet:?} scale {j} rows {rows:?}"
                );
            }
        }
    }
}

/// L1 tail fractions of `|ψ1|` outside radius `r` (scale 1), in closed form.
/// `|ψ1| = |cos θ| r |φ'(r)|`, so the angle integrates out and the radial
/// L1 density is `r² e^(-r²/2)` (gauss, `φ' ∝ -r e^(-r²/2)`) or `r² |r² - 4|
/// e^(-r²/2)` (mexican, `φ = (2 - r²) e^(-r²/2)/(2π)`, `φ' ∝ r (r² - 4)
/// e^(-r²/2)`). With `s = √(π/2)`, `∫_R^∞ r² e = R e^(-R²/2) + s erfc(R/√2)`,
/// `∫_R^∞ r⁴ e = R³ e^(-R²/2) + 3 ∫_R^∞ r² e`:
/// gauss `T(R) = R e^(-R²/2)/s + erfc(R/√2)`;
/// mexican, R > 2: `T(R) = ((R³ - R) e^(-R²/2) - s erfc(R/√2)) / (s (2 erf(√2) - 1) + 12 e^-2)`.
fn tail_closed_form(wavelet: Wavelet, r: f64) -> f64 {
    use statrs::function::erf::{erf, erfc};
    let s = (std::f64::consts::PI / 2.0).sqrt();
    let e = (-0.5 * r * r).exp();
    match wavelet {
        Wavelet::Gauss => r * e / s + erfc(r / 2f64.sqrt()),
        Wavelet::Mexican => {
            assert!(r > 2.0);
            let total = s * (2.0 * erf(2f64.sqrt()) - 1.0) + 12.0 * (-2.0f64).exp();
            ((r.powi(3) - r) * e - s * erfc(r / 2f64.sqrt())) / total
        }
    }
}

/// The mexican margin (SPEC §1: "a larger one for mexican (its kernel is
/// wider: measure it)"; README: `3.73 a_max`, the radius outside which the
/// mexican wavelet keeps the same L1 fraction of |ψ1| as gauss outside
/// 3.2), checked independently of `Wavelet::tail_fraction`'s quadrature:
/// 1. in closed form ([`tail_closed_form`]): gauss keeps 1.663 % beyond
///    3.2; `support_radius(Mexican)` solves `T_mex(R) = T_gauss(3.2)` to
///    1e-9 (relative; the library bisects to 2^-60 and integrates by
///    Simpson with 4000 panels, error far below); a radius 2 % smaller
///    leaves a tail 15 % larger (the statement is sharp), and the default
///    margin is `ceil(R a_max)`;
/// 2. the wavelet the CWT applies is the one of the closed form: the
///    transform of a unit impulse at a = 16 equals `a^-2 (∇φ)((b - x0)/a)`
///    with `∇φ(u) = u (|u|² - 4) e^(-|u|²/2) / (2π)` at every pixel, to
///    1e-9 of its maximum (aliasing `e^(-(aπ)²/2)` and the periodic wrap
///    `e^(-(128/a)²/2)` are far below);
/// 3. numerically, on that response: the share of `Σ |T1|` beyond `R a`
///    (60 px) is the gauss threshold within 1 %, the accuracy of a lattice
///    sum with a hard circular cut at this radius (the gauss response,
///    whose tail is known in closed form, is checked the same way: its
///    lattice tail beyond 3.2 a is within 0.5 % of 1.663 %).
#[test]
fn mexican_margin_keeps_the_gauss_tail() {
    let thr = tail_closed_form(Wavelet::Gauss, 3.2);
    assert!((thr - Wavelet::Gauss.tail_fraction(3.2)).abs() < 1e-9 * thr);
    assert!(
        (thr - 0.016632).abs() < 1e-6,
        "gauss tail beyond 3.2: {thr}"
    );
    let rm = Wavelet::Mexican.support_radius();
    assert_eq!(Wavelet::Gauss.support_radius(), 3.2);
    let tm = tail_closed_form(Wavelet::Mexican, rm);
    assert!(
        (tm - thr).abs() < 1e-9 * thr,
        "mexican tail beyond R = {rm}: {tm} vs {thr}"
    );
    assert!(tail_closed_form(Wavelet::Mexican, 0.98 * rm) > 1.15 * thr);
    assert!((rm - 3.7275).abs() < 5e-4, "R = {rm} (README: 3.73)");
    for a_max in [10.0, 24.0, 47.5] {
        assert_eq!(
            wtmm::cwt::default_margin(Wavelet::Mexican, a_max),
            (rm * a_max).ceil() as usize
        );
    }
    // the implemented wavelets: impulse responses
    let (n, a, c) = (256usize, 16.0, 128.0);
    let mut img = Array2::<f64>::zeros((n, n));
    img[[128, 128]] = 1.0;
    for (wavelet, r, tol) in [(Wavelet::Mexican, rm, 0.01), (Wavelet::Gauss, 3.2, 0.005)] {
        let plan = CwtPlan::new(n, n, wavelet, &[a]).unwrap();
        let t = all_scales(&plan, &img).remove(0);
        let big = t.iter().map(|&z| modulus(z)).fold(0.0, f64::max);
        let (mut total, mut tail) = (0.0, 0.0);
        for ((y, x), z) in t.indexed_iter() {
            let (ux, uy) = ((x as f64 - c) / a, (y as f64 - c) / a);
            let u2 = ux * ux + uy * uy;
            let e = (-0.5 * u2).exp() / (2.0 * std::f64::consts::PI);
            let g = match wavelet {
                Wavelet::Gauss => -e,
                Wavelet::Mexican => (u2 - 4.0) * e,
            };
            let want = Complex64::new(ux * g, uy * g) / (a * a);
            assert!(
                modulus(*z - want) < 1e-9 * big,
                "{wavelet} ({y},{x}): {z} vs {want}"
            );
            total += z.re.abs();
            if u2.sqrt() > r {
                tail += z.re.abs();
            }
        }
        let frac = tail / total;
        println!("{wavelet}: lattice L1 tail beyond {r:.4} a = {frac:.6} (threshold {thr:.6})");
        assert!(
            (frac / thr - 1.0).abs() < tol,
            "{wavelet}: tail beyond {r:.3} a is {frac:.6}, threshold {thr:.6}"
        );
    }
}
