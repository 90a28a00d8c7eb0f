//! The skeleton against exact local behaviours of the WTMM (II §3; SPEC §2-§3).

use ndarray::Array2;
use wtmm::Field;
use wtmm::cwt::Wavelet;
use wtmm::skeleton::{
    AnalysisConfig, Chain, LinkParams, Linker, MaximaLine, Parallelism, ScaleMaxima, Skeleton,
    Wtmmm, skeleton, skeleton_with,
};
use wtmm::stats::line_fit;

fn cfg(wavelet: Wavelet, octaves: usize, margin: usize) -> AnalysisConfig {
    AnalysisConfig {
        wavelet,
        octaves,
        margin: Some(margin),
        ..Default::default()
    }
}

/// Slope of log2 M against log2 a along a line, over scale indices [j0, j1].
fn slope(sk: &Skeleton, line: &MaximaLine, j0: usize, j1: usize) -> f64 {
    let (x, y): (Vec<f64>, Vec<f64>) = (j0..=j1)
        .map(|j| (sk.scales[j].log2(), line.points[j].m.log2()))
        .unzip();
    line_fit(&x, &y).unwrap().slope
}

/// Smooth radial taper: 1 inside r0, 0 beyond r1.
fn taper(r: f64, r0: f64, r1: f64) -> f64 {
    if r < r0 {
        1.0
    } else if r > r1 {
        0.0
    } else {
        ((r - r0) / (r1 - r0) * std::f64::consts::FRAC_PI_2)
            .cos()
            .powi(2)
    }
}

/// Unit roundoff of f64.
const U: f64 = f64::EPSILON / 2.0;

/// Largest modulus of the filter `H(k) = a k φ̂(a|k|)` over the
/// wavenumbers: `max_t t e^(-t²/2) = e^(-1/2)` for gauss, `max_t t³
/// e^(-t²/2) = 3^(3/2) e^(-3/2)` for mexican (SPEC §1).
fn filter_max(wavelet: Wavelet) -> f64 {
    match wavelet {
        Wavelet::Gauss => (-0.5f64).exp(),
        Wavelet::Mexican => 3f64.powf(1.5) * (-1.5f64).exp(),
    }
}

/// Bound on the rounding error of the library's transform of `img` at any
/// one pixel (absolute, in units of M). The transform is a 2D FFT of
/// `f - offset`, a pointwise filter and an inverse 2D FFT. For a power-of-two
/// length n the computed FFT of y is within `log2(n) η / (1 - log2(n) η)
/// ||F y||_2` of the exact one, `η = μ + γ4 (√2 + μ) ≈ (4√2 + 1) u` for
/// twiddles accurate to `μ ≈ u` (Higham, Accuracy and Stability of
/// Numerical Algorithms, 2nd ed., Thm 24.2; the real-input first pass, the
/// radix-4 and mixed-radix passes are made of the same butterflies and
/// twiddles). Rows then columns add their levels, so the forward and the
/// inverse transforms make `t = 2 log2(nx ny)` levels. The offset, the FFT
/// scaling and the filter (two exponentials, about ten products) add at
/// most 24 u to each spectral value. An error of the spectrum passes the
/// filter amplified by at most `max|H|` ([`filter_max`]) and Parseval gives
/// the same 2-norm over the pixels, which bounds the error at any one pixel:
/// `|δT(b)| ≤ (t η + 24 u) / (1 - t η - 24 u) max|H| ||f - offset||_2`.
fn fft_rounding_bound(img: &Array2<f64>, wavelet: Wavelet) -> f64 {
    let (ny, nx) = img.dim();
    assert!(nx.is_power_of_two() && ny.is_power_of_two());
    let (lo, hi) = img
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &v| {
            (l.min(v), h.max(v))
        });
    let offset = lo / 2.0 + hi / 2.0;
    let norm = img
        .iter()
        .map(|v| (v - offset) * (v - offset))
        .sum::<f64>()
        .sqrt();
    let eta = (4.0 * 2f64.sqrt() + 1.0) * U;
    let e = 2.0 * ((nx * ny) as f64).log2() * eta + 24.0 * U;
    e / (1.0 - e) * filter_max(wavelet) * norm
}

/// Bound on `|s_lib - s_ref|` for two least-squares slopes of `log2 M`
/// against `log2 a` over the same scales, when `|M_lib,j - M_ref,j| ≤
/// beta[j]`: the slope is `Σ w_j y_j` with `w_j = (x_j - x̄) / Sxx`, so it
/// moves by at most `Σ |w_j| |log2(M_lib,j / M_ref,j)| ≤ Σ |w_j| (-log2(1 -
/// beta_j / M_ref,j))`; plus the rounding of the two fits (sums of n terms:
/// at most `(2n + 8) u` relative to `Σ |w_j| (|y_j| + |ȳ|)` each).
fn slope_bound(x: &[f64], y_ref: &[f64], m_ref: &[f64], beta: &[f64]) -> f64 {
    let n = x.len() as f64;
    let mx = x.iter().sum::<f64>() / n;
    let sxx: f64 = x.iter().map(|v| (v - mx) * (v - mx)).sum();
    let ybar = (y_ref.iter().sum::<f64>() / n).abs();
    let mut b = 0.0;
    let mut round = 0.0;
    for j in 0..x.len() {
        let w = ((x[j] - mx) / sxx).abs();
        assert!(
            beta[j] < m_ref[j],
            "bound {} beyond M {}",
            beta[j],
            m_ref[j]
        );
        b += w * -(1.0 - beta[j] / m_ref[j]).log2();
        // both fits; |y_lib,j| < |y_ref,j| + 1 (the bounds are far below M)
        round += 2.0 * w * (y_ref[j].abs() + ybar + 1.0);
    }
    b + (2.0 * n + 8.0) * U * round
}

/// Kummer's function ₁F₁(α; β; z) for α, β, z ≥ 0 by its series: the terms
/// are positive and, once `k > 2z`, fall by more than half from one to the
/// next, so stopping at a term below u of the sum leaves less than 2 u.
fn hyp1f1(al: f64, be: f64, z: f64) -> f64 {
    let (mut t, mut s) = (1.0, 1.0);
    let mut k = 0.0;
    while !(t < U * s && k > 2.0 * z) {
        t *= (al + k) / (be + k) * z / (k + 1.0);
        s += t;
        k += 1.0;
    }
    s
}

/// The upper incomplete gamma function Γ(s, x) for x > 0 and s > -2 not an
/// integer ≤ 0: statrs's regularised Q(s, x) Γ(s) for s > 0, and
/// `Γ(s, x) = (Γ(s + 1, x) - x^s e^(-x)) / s` below.
fn upper_gamma(s: f64, x: f64) -> f64 {
    use statrs::function::gamma::{gamma, gamma_ur};
    if s > 0.0 {
        gamma_ur(s, x) * gamma(s)
    } else {
        (upper_gamma(s + 1.0, x) - x.powf(s) * (-x).exp()) / s
    }
}

/// The Epstein zeta function of the square lattice with a phase, `Z(σ; c) =
/// Σ_{n ∈ Z² \ 0} |n|^(-σ) cos(2π n·c)`, and its gradient in c, for σ > 2
/// (not an even integer) and c off the lattice. Ewald's split: with
/// `|n|^(-σ) = π^(σ/2) / Γ(σ/2) ∫_0^∞ t^(σ/2 - 1) e^(-π t |n|²) dt`, the
/// part t > 1 sums directly, and Poisson's formula `Σ_n e^(2πi n·c)
/// e^(-π t |n|²) = t^(-1) Σ_m e^(-π |m - c|² / t)` turns the part t < 1
/// (less its n = 0 term, 1) into
/// `Z = π^(σ/2) / Γ(σ/2) [Σ_{n≠0} cos(2π n·c) (π|n|²)^(-σ/2) Γ(σ/2, π|n|²)
///      + Σ_m G(π|m - c|²) - 2/σ]`, `G(x) = x^(σ/2 - 1) Γ(1 - σ/2, x)`,
/// `G'(x) = (σ/2 - 1) x^(σ/2 - 2) Γ(1 - σ/2, x) - e^(-x)/x`. Both sums fall
/// off like `e^(-π r²)`: |i|, |j| ≤ 8 leaves below e^(-170).
fn epstein(sigma: f64, c: [f64; 2]) -> (f64, [f64; 2]) {
    use statrs::function::gamma::gamma;
    use std::f64::consts::PI;
    let (mut z, mut g) = (0.0, [0.0; 2]);
    for i in -8i32..=8 {
        for j in -8i32..=8 {
            let n = [i as f64, j as f64];
            let n2 = n[0] * n[0] + n[1] * n[1];
            if n2 > 0.0 {
                let ph = 2.0 * PI * (n[0] * c[0] + n[1] * c[1]);
                let w = (PI * n2).powf(-sigma / 2.0) * upper_gamma(sigma / 2.0, PI * n2);
                z += ph.cos() * w;
                for k in 0..2 {
                    g[k] -= 2.0 * PI * n[k] * ph.sin() * w;
                }
            }
            let d = [n[0] - c[0], n[1] - c[1]];
            let x = PI * (d[0] * d[0] + d[1] * d[1]);
            let gam = upper_gamma(1.0 - sigma / 2.0, x);
            z += x.powf(sigma / 2.0 - 1.0) * gam;
            let dg = (sigma / 2.0 - 1.0) * x.powf(sigma / 2.0 - 2.0) * gam - (-x).exp() / x;
            for k in 0..2 {
                g[k] -= 2.0 * PI * d[k] * dg;
            }
        }
    }
    let k = PI.powf(sigma / 2.0) / gamma(sigma / 2.0);
    (k * (z - 2.0 / sigma), [k * g[0], k * g[1]])
}

/// The gauss-wavelet transform of the sampled cusp `f(x) = |x - x0|^h`
/// (SPEC §1: `T = a ∇(g_a * f)`, `g_a` the unit Gaussian of std a),
/// with a bound on what it leaves out.
///
/// Continuous transform. `(g_a * f)(b) = a^h Φ(|b - x0| / a)` with `Φ(ρ) =
/// E|ρ e + Z|^h`, Z a standard 2D normal: the h/2-th moment of a
/// non-central χ²₂, `Φ(ρ) = 2^(h/2) Γ(1 + h/2) ₁F₁(-h/2; 1; -ρ²/2)`. So
/// `T_c(b) = a^h Φ'(ρ) (b - x0)/|b - x0|`, and with `d₁F₁(α; β; z)/dz =
/// (α/β) ₁F₁(α + 1; β + 1; z)` and Kummer's `₁F₁(α; β; -z) = e^(-z)
/// ₁F₁(β - α; β; z)`: `Φ'(ρ) = 2^(h/2) Γ(1 + h/2) (h/2) ρ e^(-ρ²/2)
/// ₁F₁(1 + h/2; 2; ρ²/2)`. M = a^h Φ'(ρ): exactly a^h along any line at a
/// fixed ρ, the WTMM property.
///
/// Pixel term. The image samples f on Z², so the library transforms the
/// samples' spectrum `Σ_n f̂(k + 2πn)`, `f̂(k) = C |k|^(-2-h) e^(-ik·x0)`,
/// `C = 2^(2+h) π Γ(1 + h/2) / Γ(-h/2)`, through its filter `H(k) = a i k
/// e^(-a²|k|²/2)` inside the band |k|∞ < π. Against `T_c` it adds
/// `(2π)^-2 ∫_band H(k) e^(ik·(b - x0)) A(k) dk` with the alias sum `A(k) =
/// Σ_{n≠0} C |k + 2πn|^(-2-h) e^(-2πi n·x0)`, smooth on the band (|k +
/// 2πn| ≥ π there). Taylor at k = 0: `A(0) = S = C (2π)^(-2-h) Z(2 + h;
/// x0)` multiplies the wavelet itself, `S ψ_a(b - x0)` with `ψ_a(d) = a
/// ∇g_a(d)` (a point mass at x0: the sum of the samples of a cusp is not
/// its integral); `∇A(0) = i V`, `V = -C (2 + h) (2π)^(-4-h) ∇_c Z(4 + h;
/// x0)` (only the fractional part of x0 matters), gives `V·∇ψ_a(b - x0)`.
/// These two are in [`Self::model`]; they are O(a^(-2-h)) and
/// O(a^(-3-h)) relative to `T_c`.
///
/// Bound ([`Self::pixel_bound`]). (1) Taylor remainder: `|A(k) - S - i V·k|
/// ≤ |k|²/2 sup ‖∇²A‖` on the segment, and `‖∇²|k|^(-s)‖ = s (s + 1)
/// |k|^(-s-2)`, `|k' + 2πn| ≥ 2π|n| - |k|`, so with the band inside the
/// disc |k| ≤ π√2, `R2 = |C| (2+h)(3+h)/2 (a/2π) ∫_0^(π√2) κ⁴ e^(-a²κ²/2)
/// L(κ) dκ`, `L(κ) = Σ_{n≠0} (2π|n| - κ)^(-4-h)` (|n| ≤ 20 summed, the
/// rest bounded by the integral over the unit cells beyond |n| - √2/2;
/// Simpson on 400 panels). It is O(a^(-4-h)) relative. (2) Out of band:
/// the S and V terms, taken over the whole plane, exceed the band by at
/// most `|S| I1 + |V| I2`, and the part of `T_c` beyond the band is at most
/// `|C| π^(-2-h) I1`, `I1 = (2π)^-2 ∫_{|k|>π} |H|`, `I2 = (2π)^-2
/// ∫_{|k|>π} |H| |k|` (closed forms below; e^(-a²π²/2) = 5e-8 at a =
/// 1.85). (3) Far field, estimated rather than bounded: the taper changes
/// f only 180 px or more from x0, beyond 9 a of every line point at a ≤ 15
/// (the Gaussian there is below e^(-40)); the band-limited filter's
/// ringing (weight e^(-a²π²/2), alternating in sign from pixel to pixel)
/// reaches it and the periodic images (the image vanishes at its edges)
/// only through the image's content near the Nyquist wavenumber, which the
/// 60 px taper hardly has. Measured once: the library's M differs from
/// the direct spatial sum of the sampled wavelet truncated at 10 a (no far
/// field at all) by 2e-7 of M at a = 1.5 and 2e-10 at a = 1.85, against R2 =
/// 3e-2 and 1e-2 of M.
struct CuspRef {
    h: f64,
    x0: [f64; 2],
    c_h: f64,
    s: f64,
    v: [f64; 2],
    /// `L(κ)` on the Simpson grid of [0, π√2].
    lk: Vec<f64>,
}

const R2_PANELS: usize = 400;

impl CuspRef {
    fn new(h: f64, x0: [f64; 2]) -> Self {
        use statrs::function::gamma::gamma;
        use std::f64::consts::PI;
        let c_h = 2f64.powf(2.0 + h) * PI * gamma(1.0 + h / 2.0) / gamma(-h / 2.0);
        let frac = [x0[0].rem_euclid(1.0), x0[1].rem_euclid(1.0)];
        let s = c_h * (2.0 * PI).powf(-2.0 - h) * epstein(2.0 + h, frac).0;
        let gz = epstein(4.0 + h, frac).1;
        let vk = -c_h * (2.0 + h) * (2.0 * PI).powf(-4.0 - h);
        // lattice radii |n| <= 20 with their multiplicities
        let l0 = 20i32;
        let mut radii: Vec<(i32, f64)> = Vec::new();
        for i in -l0..=l0 {
            for j in -l0..=l0 {
                let r2 = i * i + j * j;
                if r2 > 0 && r2 <= l0 * l0 {
                    match radii.iter_mut().find(|p| p.0 == r2) {
                        Some(p) => p.1 += 1.0,
                        None => radii.push((r2, 1.0)),
                    }
                }
            }
        }
        let p = 4.0 + h;
        let half_diag = 0.5 * 2f64.sqrt();
        let kmax = PI * 2f64.sqrt();
        let lk = (0..=R2_PANELS)
            .map(|i| {
                let kap = kmax * i as f64 / R2_PANELS as f64;
                let near: f64 = radii
                    .iter()
                    .map(|&(r2, m)| m * (2.0 * PI * (r2 as f64).sqrt() - kap).powf(-p))
                    .sum();
                // |n| > l0: each term is below the integrand over its unit
                // cell, which lies beyond r0 = l0 - √2/2, with the radius
                // lowered by √2/2: ∫_{r0}^∞ 2π r (2π (r - √2/2) - κ)^-p dr
                let u0 = 2.0 * PI * (l0 as f64 - 2.0 * half_diag) - kap;
                let tail = u0.powf(2.0 - p) / (2.0 * PI * (p - 2.0))
                    + (kap / (2.0 * PI) + half_diag) * u0.powf(1.0 - p) / (p - 1.0);
                near + tail
            })
            .collect();
        CuspRef {
            h,
            x0,
            c_h,
            s,
            v: [vk * gz[0], vk * gz[1]],
            lk,
        }
    }

    /// `T_c`, the continuous transform at pixel (x, y).
    fn continuous(&self, x: u32, y: u32, a: f64) -> [f64; 2] {
        use statrs::function::gamma::gamma;
        let h = self.h;
        let d = [x as f64 - self.x0[0], y as f64 - self.x0[1]];
        let r = d[0].hypot(d[1]);
        let rho = r / a;
        let dphi = 2f64.powf(h / 2.0)
            * gamma(1.0 + h / 2.0)
            * (h / 2.0)
            * rho
            * (-rho * rho / 2.0).exp()
            * hyp1f1(1.0 + h / 2.0, 2.0, rho * rho / 2.0);
        let m = a.powf(h) * dphi;
        [m * d[0] / r, m * d[1] / r]
    }

    /// `T_c + S ψ_a(d) + V·∇ψ_a(d)`, d = (x, y) - x0: `ψ_a,i = -(d_i/a)
    /// g_a(d)`, `∂_j ψ_a,i = a (d_i d_j / a⁴ - δ_ij / a²) g_a(d)`.
    fn model(&self, x: u32, y: u32, a: f64) -> [f64; 2] {
        use std::f64::consts::PI;
        let t = self.continuous(x, y, a);
        let d = [x as f64 - self.x0[0], y as f64 - self.x0[1]];
        let g = (-(d[0] * d[0] + d[1] * d[1]) / (2.0 * a * a)).exp() / (2.0 * PI * a * a);
        let mut out = t;
        for i in 0..2 {
            out[i] += -self.s * d[i] / a * g;
            for j in 0..2 {
                let delta = if i == j { 1.0 } else { 0.0 };
                out[i] += self.v[j] * a * (d[i] * d[j] / a.powi(4) - delta / (a * a)) * g;
            }
        }
        out
    }

    /// Bound on `|T_lib - model|` at scale a, rounding of the FFTs aside:
    /// `R2 + (|S| + |C| π^(-2-h)) I1 + |V| I2` (see the type), with `I1 =
    /// (a/2π) ∫_π^∞ κ² e^(-a²κ²/2) dκ = (a/2π) [π e^(-a²π²/2) / a² + √(π/2)
    /// erfc(aπ/√2) / a³]` and `I2 = (a/2π) ∫_π^∞ κ³ e^(-a²κ²/2) dκ = (a/2π)
    /// e^(-a²π²/2) (π²/a² + 2/a⁴)`.
    fn pixel_bound(&self, a: f64) -> f64 {
        use statrs::function::erf::erfc;
        use std::f64::consts::PI;
        let h = self.h;
        let kmax = PI * 2f64.sqrt();
        let dk = kmax / R2_PANELS as f64;
        let mut q = 0.0;
        for (i, l) in self.lk.iter().enumerate() {
            let k = i as f64 * dk;
            let w = if i == 0 || i == R2_PANELS {
                1.0
            } else if i % 2 == 1 {
                4.0
            } else {
                2.0
            };
            q += w * k.powi(4) * (-a * a * k * k / 2.0).exp() * l;
        }
        let r2 = self.c_h.abs() * (2.0 + h) * (3.0 + h) / 2.0 * a / (2.0 * PI) * q * dk / 3.0;
        let e = (-a * a * PI * PI / 2.0).exp();
        let i1 = a / (2.0 * PI)
            * (PI * e / (a * a) + (PI / 2.0).sqrt() * erfc(a * PI / 2f64.sqrt()) / a.powi(3));
        let i2 = a / (2.0 * PI) * e * (PI * PI / (a * a) + 2.0 / a.powi(4));
        let oob = (self.s.abs() + self.c_h.abs() * PI.powf(-2.0 - h)) * i1
            + self.v[0].hypot(self.v[1]) * i2;
        r2 + oob
    }
}

/// The references compute M to about 1e-13 relative. [`CuspRef`]: Γ and
/// the regularised incomplete Γ of statrs to about 1e-15, the ₁F₁ series
/// to 2 u, the Ewald sums with terms of either sign to some 1e-14, and S,
/// V weigh below 1 % of M at the scales checked. The bump: a few
/// exponentials of arguments below 40 and a dozen products, some 1e-14.
const REF_REL: f64 = 1e-13;

/// Checks the lines of `sk` born within 5 px of the cusp that live past
/// scale `j1`: they stay within 2.5 a + 3 px of x0; at every scale up to
/// j1 M is the model's within its bound (plus the FFTs' rounding `round`);
/// and the slope of log2 M over [j0, j1] is the model's within the
/// propagated bound. Returns the number of lines checked.
fn check_cusp_lines(sk: &Skeleton, cusp: &CuspRef, round: f64, j0: usize, j1: usize) -> usize {
    let h = cusp.h;
    let [x0, y0] = cusp.x0;
    let near: Vec<&MaximaLine> = sk
        .lines
        .iter()
        .filter(|l| {
            let p = l.points[0];
            ((p.x as f64 - x0).powi(2) + (p.y as f64 - y0).powi(2)).sqrt() < 5.0
                && l.points.len() > j1
        })
        .collect();
    for l in &near {
        let (mut x, mut y_ref, mut m_ref, mut beta, mut y_c) =
            (vec![], vec![], vec![], vec![], vec![]);
        let mut worst: f64 = 0.0;
        for (j, p) in l.points.iter().enumerate().take(j1 + 1) {
            let a = sk.scales[j];
            // the line converges to x0
            let d = ((p.x as f64 - x0).powi(2) + (p.y as f64 - y0).powi(2)).sqrt();
            assert!(
                d < 2.5 * a + 3.0,
                "h={h}: line strays to {d:.1} px at a={a:.2}"
            );
            let t = cusp.model(p.x, p.y, a);
            let m = t[0].hypot(t[1]);
            let b = cusp.pixel_bound(a) + round + REF_REL * m;
            assert!(
                (p.m - m).abs() <= b,
                "h={h} a={a:.3} ({},{}): M = {} vs model {m} (bound {b:.2e})",
                p.x,
                p.y,
                p.m
            );
            worst = worst.max((p.m - m).abs() / b);
            if j >= j0 {
                let tc = cusp.continuous(p.x, p.y, a);
                x.push(a.log2());
                y_ref.push(m.log2());
                m_ref.push(m);
                beta.push(b);
                y_c.push(tc[0].hypot(tc[1]).log2());
            }
        }
        let s = slope(sk, l, j0, j1);
        let s_ref = line_fit(&x, &y_ref).unwrap().slope;
        let s_c = line_fit(&x, &y_c).unwrap().slope;
        let sb = slope_bound(&x, &y_ref, &m_ref, &beta);
        println!(
            "h={h}: slope {s:.6}, model {s_ref:.6} (bound {sb:.1e}), continuous {s_c:.6}; \
             largest |M - model| / bound {worst:.1e}"
        );
        assert!(
            (s - s_ref).abs() <= sb,
            "h={h}: slope {s} vs model {s_ref} (bound {sb:.2e})"
        );
    }
    near.len()
}

/// The Ewald sums of [`epstein`] against the plain lattice sums where
/// those converge fast (σ = 6.3, |i|, |j| ≤ 150: the rest is below
/// `2π 149^(2-σ) / (σ - 2) < 2e-9` for Z and `2π 149^(3-σ)/(σ - 3) 2π <
/// 1e-5` for its gradient), at the fractional offset of the cusp tests and
/// at another one.
#[test]
fn epstein_sums_match_the_lattice_sums() {
    use std::f64::consts::PI;
    let sigma = 6.3;
    for c in [[0.3, 0.6], [0.85, 0.1]] {
        let (mut z, mut g) = (0.0, [0.0; 2]);
        for i in -150i32..=150 {
            for j in -150i32..=150 {
                let n = [i as f64, j as f64];
                let n2 = n[0] * n[0] + n[1] * n[1];
                if n2 > 0.0 {
                    let ph = 2.0 * PI * (n[0] * c[0] + n[1] * c[1]);
                    let w = n2.powf(-sigma / 2.0);
                    z += w * ph.cos();
                    for k in 0..2 {
                        g[k] -= 2.0 * PI * n[k] * w * ph.sin();
                    }
                }
            }
        }
        let (ze, ge) = epstein(sigma, c);
        println!(
            "{c:?}: Z {:.1e}, grad {:.1e} {:.1e}",
            ze - z,
            ge[0] - g[0],
            ge[1] - g[1]
        );
        assert!((ze - z).abs() < 2e-9, "{c:?}: Z {ze} vs {z}");
        for k in 0..2 {
            assert!((ge[k] - g[k]).abs() < 1e-5, "{c:?}: dZ/dc {ge:?} vs {g:?}");
        }
    }
}

/// The tapered cusp of the tests: `|x - x0|^h` up to r = 180, tapered to 0
/// at r = 240 (the image's edges are farther from x0).
fn cusp_image(n: usize, x0: [f64; 2], h: f64) -> Array2<f64> {
    Array2::from_shape_fn((n, n), |(y, x)| {
        let r = (x as f64 - x0[0]).hypot(y as f64 - x0[1]);
        r.powf(h) * taper(r, 180.0, 240.0)
    })
}

/// f = |x - x0|^h near an isolated point: the maxima lines that converge to
/// x0 have M ~ a^h (the WTMM property). Over 3 octaves (a = 1.85 .. 14.8)
/// the kernel (3.2 a) plus the WTMMM's distance to x0 (~1.8 a for h = 0.3,
/// ~2.4 a for 0.7) stay inside the flat part of the taper (r < 180), so the
/// field is an exact cusp there. Checked against [`CuspRef`], the exact
/// continuous transform `a^h Φ'(ρ)` plus the sampling's pixel term to
/// O(a^(-3-h)): M at every line point up to a = 14.8 within the derived
/// bound (R2 dominates: 1e-2 of M at a = 1.85 for h = 0.3, falling as
/// a^(-4-h); the pixel term itself is 6e-3 there), and the slope over a =
/// 1.85 .. 14.8 within the bound propagated from those.
#[test]
fn isolated_cusp_gives_its_holder_exponent() {
    let n = 512;
    let x0 = [256.3, 255.6];
    for h in [0.3, 0.7] {
        let img = cusp_image(n, x0, h);
        let round = fft_rounding_bound(&img, Wavelet::Gauss);
        let sk = skeleton(&Field::new(img), &cfg(Wavelet::Gauss, 4, 40)).unwrap();
        let cusp = CuspRef::new(h, x0);
        let lines = check_cusp_lines(&sk, &cusp, round, 3, 33);
        assert!(
            lines > 0,
            "h={h}: no maxima line converging to x0 survives 3 octaves"
        );
    }
}

/// A straight step edge: one chain along the edge at every scale, and one
/// maxima line along it. (Its modulus, scale-independent as h = 0, is
/// checked exactly on the same image and scales, with the pixel term
/// bounded, by `step_edge_modulus_is_calibrated`.)
#[test]
fn step_edge() {
    let n = 256;
    // the edge sits on column 128 (half value), so the WTMM column is exact
    let img = Array2::from_shape_fn((n, n), |(_, x)| match x.cmp(&128) {
        std::cmp::Ordering::Less => 0.0,
        std::cmp::Ordering::Equal => 0.5,
        std::cmp::Ordering::Greater => 1.0,
    });
    let c = cfg(Wavelet::Gauss, 3, 40);
    let keep: Vec<usize> = (0..30).collect();
    let sk = skeleton_with(&Field::new(img), &c, Parallelism::Serial, &keep).unwrap();
    for sm in &sk.kept {
        // chains are traced beyond the counting domain (guard band): look at
        // the ones that enter it
        let inside: Vec<_> = sm
            .chains
            .iter()
            .filter(|ch| ch.pixels.len() >= 3 && ch.pixels.iter().any(|&(x, y)| sk.counts(x, y)))
            .collect();
        assert_eq!(inside.len(), 1, "a={:.2}: {} chains", sm.a, inside.len());
        assert!(
            inside[0].pixels.iter().all(|&(x, _)| x == 128),
            "a={:.2}: chain leaves the edge",
            sm.a
        );
        let n_in = inside[0]
            .pixels
            .iter()
            .filter(|&&(x, y)| sk.counts(x, y))
            .count();
        assert_eq!(n_in, n - 80, "the chain spans the interior");
    }
    let full: Vec<&MaximaLine> = sk.lines.iter().filter(|l| l.points.len() == 30).collect();
    assert_eq!(full.len(), 1, "one maxima line along the edge");
    assert!(
        full[0].points.iter().all(|p| p.x == 128),
        "the line leaves the edge"
    );
}

/// The N-periodic Gaussian `Σ_p e^(-(x - c + p n)² / (2σ²))` over |p| ≤ 2
/// (for 0 ≤ x < n the next images lie 2.5 n away at least: below
/// e^(-220) for n = 512, σ ≤ 61) and its first three derivatives in x.
fn periodic_gauss(x: f64, c: f64, n: usize, sigma: f64) -> [f64; 4] {
    let mut d = [0.0; 4];
    let s2 = sigma * sigma;
    for p in -2i32..=2 {
        let u = x - c + (p * n as i32) as f64;
        let g = (-u * u / (2.0 * s2)).exp();
        d[0] += g;
        d[1] += -u / s2 * g;
        d[2] += (u * u / (s2 * s2) - 1.0 / s2) * g;
        d[3] += (-u * u * u / (s2 * s2 * s2) + 3.0 * u / (s2 * s2)) * g;
    }
    d
}

/// A smooth wide bump: where the bump (std 60 px along x, 49 along y) is
/// much wider than a, the field is locally a polynomial and M grows like
/// a^n with n the number of vanishing moments (1 for gauss, 3 for
/// mexican). Slightly elliptical so the WTMMM sit on the short axis (the
/// steeper side), not anywhere along a circle.
///
/// The bump is the periodic Gaussian `u(x) v(y)` ([`periodic_gauss`], std
/// s = 60 and s/√1.5), so its transform is exact: `g_a * u` is `(s/σ)`
/// times the periodic Gaussian of std `σ = √(s² + a²)`, and `T = a ∇(u_a
/// v_a)` for gauss, `T = -a³ ∇∇²(u_a v_a)` for mexican (`φ̂ = a²|k|²
/// ĝ`). The samples of a periodic Gaussian of std 49 carry nothing beyond
/// the Nyquist wavenumber (e^(-49² π²/2) < 1e-5000), so the discrete
/// transform is the continuous one at the pixels, up to the rounding of
/// the FFTs ([`fft_rounding_bound`]: at a = 1.5, 2.3e-10 of M for gauss,
/// 1e-6 for mexican, whose M is small there) and of the reference
/// ([`REF_REL`]). Checked: M along every line that lives 2
/// octaves (a = 1.5 .. 5.7) within that bound of the exact value at its
/// pixel, and the slope of log2 M within the propagated bound of the exact
/// values' slope, which lies below n by the (a/σ)² terms (0.989 for
/// gauss, 2.98 for mexican).
#[test]
fn smooth_bump_gives_the_wavelet_order() {
    let n = 512;
    let c = 256.0;
    let (sx, sy) = (60.0f64, 60.0 / 1.5f64.sqrt());
    let img = Array2::from_shape_fn((n, n), |(y, x)| {
        periodic_gauss(x as f64, c, n, sx)[0] * periodic_gauss(y as f64, c, n, sy)[0]
    });
    for (wavelet, order) in [(Wavelet::Gauss, 1.0), (Wavelet::Mexican, 3.0)] {
        let round = fft_rounding_bound(&img, wavelet);
        // a^3 over a tenth of an octave is a ratio of 1.23: the linking
        // window must admit it (the default admits |h| < 1.5)
        let mut cf = cfg(wavelet, 2, 30);
        cf.link.ratio = (0.8, 1.3);
        let sk = skeleton(&Field::new(img.clone()), &cf).unwrap();
        let full: Vec<&MaximaLine> = sk.lines.iter().filter(|l| l.points.len() == 20).collect();
        assert!(!full.is_empty(), "{wavelet}: no line survives 2 octaves");
        for l in full {
            let (mut x, mut y_ref, mut m_ref, mut beta) = (vec![], vec![], vec![], vec![]);
            let mut worst: f64 = 0.0;
            for (j, p) in l.points.iter().enumerate() {
                let a = sk.scales[j];
                let (gx, gy) = ((sx * sx + a * a).sqrt(), (sy * sy + a * a).sqrt());
                let u = periodic_gauss(p.x as f64, c, n, gx).map(|v| v * sx / gx);
                let v = periodic_gauss(p.y as f64, c, n, gy).map(|w| w * sy / gy);
                let t = match wavelet {
                    Wavelet::Gauss => [a * u[1] * v[0], a * u[0] * v[1]],
                    Wavelet::Mexican => [
                        -a.powi(3) * (u[3] * v[0] + u[1] * v[2]),
                        -a.powi(3) * (u[2] * v[1] + u[0] * v[3]),
                    ],
                };
                let m = t[0].hypot(t[1]);
                let b = round + REF_REL * m;
                assert!(
                    (p.m - m).abs() <= b,
                    "{wavelet} a={a:.3} ({},{}): M = {} vs exact {m} (bound {b:.1e})",
                    p.x,
                    p.y,
                    p.m
                );
                worst = worst.max((p.m - m).abs() / b);
                x.push(a.log2());
                y_ref.push(m.log2());
                m_ref.push(m);
                beta.push(b);
            }
            let s = slope(&sk, l, 0, 19);
            let s_ref = line_fit(&x, &y_ref).unwrap().slope;
            let sb = slope_bound(&x, &y_ref, &m_ref, &beta);
            let p0 = l.points[0];
            println!(
                "{wavelet} line at ({},{}): slope {s:.10}, exact {s_ref:.10} (bound {sb:.1e}, \
                 order {order}); largest |M - exact| / bound {worst:.1e}",
                p0.x, p0.y
            );
            assert!(
                (s - s_ref).abs() <= sb,
                "{wavelet}: slope {s} vs exact {s_ref} (bound {sb:.1e})"
            );
        }
    }
}

/// The only chain of a scale, which must be closed.
fn one_closed_chain(sm: &ScaleMaxima) -> &Chain {
    assert_eq!(
        sm.chains.len(),
        1,
        "a={:.2}: {} chains",
        sm.a,
        sm.chains.len()
    );
    let ch = &sm.chains[0];
    assert!(ch.closed, "a={:.2}: chain not closed", sm.a);
    ch
}

/// A disc: one closed chain per scale, concentric with the disc.
/// From a = 2 up: at a = 1.5 the Gaussian filter is still 1.5e-5 at the
/// Nyquist frequency, so the transform of a binary disc rings (Gibbs) above
/// eps = 1e-7 far from the edge and adds tiny spurious chains; at a = 2 the
/// filter is 2.7e-9 there, below eps.
#[test]
fn disc_gives_one_closed_concentric_chain() {
    let n = 256;
    let (cx, cy, r) = (128.0, 128.0, 40.0);
    let img = Array2::from_shape_fn((n, n), |(y, x)| {
        let (dx, dy) = (x as f64 - cx, y as f64 - cy);
        if dx * dx + dy * dy < r * r { 1.0 } else { 0.0 }
    });
    let c = AnalysisConfig {
        a_min: 2.0,
        ..cfg(Wavelet::Gauss, 3, 40)
    };
    let keep: Vec<usize> = (0..30).collect();
    let sk = skeleton_with(&Field::new(img), &c, Parallelism::Serial, &keep).unwrap();
    for sm in &sk.kept {
        let ch = one_closed_chain(sm);
        let k = ch.pixels.len() as f64;
        let mx = ch.pixels.iter().map(|p| p.0 as f64).sum::<f64>() / k;
        let my = ch.pixels.iter().map(|p| p.1 as f64).sum::<f64>() / k;
        assert!(
            (mx - cx).abs() < 1.0 && (my - cy).abs() < 1.0,
            "a={:.2}: centre ({mx},{my})",
            sm.a
        );
        for &(x, y) in &ch.pixels {
            let d = ((x as f64 - cx).powi(2) + (y as f64 - cy).powi(2)).sqrt();
            assert!(
                (d - r).abs() < 2.0 + 0.2 * sm.a,
                "a={:.2}: chain pixel at radius {d}",
                sm.a
            );
        }
    }
}

#[test]
fn constant_image_gives_an_empty_skeleton() {
    // non-power-of-two sizes too: their FFTs leave ~1e-16 of a constant,
    // which the relative eps threshold took for maxima
    for (n, v) in [(128, 3.25), (96, 3.25), (100, 1.0), (48, 0.1)] {
        let img = Array2::from_elem((n, n), v);
        for (wavelet, margin) in [(Wavelet::Gauss, 20), (Wavelet::Mexican, 0)] {
            let sk = skeleton(&Field::new(img.clone()), &cfg(wavelet, 1, margin)).unwrap();
            assert!(sk.lines.is_empty(), "{n}^2 {wavelet}");
            assert!(
                sk.per_scale.iter().all(|s| s.wtmm == 0 && s.wtmmm == 0),
                "{n}^2 {wavelet}"
            );
        }
    }
}

#[test]
fn all_nan_image_is_a_clear_error() {
    let img = Array2::from_elem((128, 128), f64::NAN);
    let e = skeleton(&Field::new(img), &cfg(Wavelet::Gauss, 2, 20)).unwrap_err();
    assert!(e.to_string().contains("missing"), "{e}");
}

#[test]
fn image_smaller_than_the_wavelet_is_a_clear_error() {
    let img = Array2::from_shape_fn((64, 64), |(y, x)| (x * y) as f64);
    let e = skeleton(&Field::new(img.clone()), &AnalysisConfig::default()).unwrap_err();
    assert!(e.to_string().contains("smaller than the wavelet"), "{e}");
    // a margin as given is named as the fault, with the largest it can be
    let cfg = AnalysisConfig {
        margin: Some(32),
        ..Default::default()
    };
    let e = skeleton(&Field::new(img.clone()), &cfg).unwrap_err();
    assert!(
        e.to_string()
            .contains("the margin of 32 px on each side (--margin) leaves no interior in an image of 64x64 (give less than 32 px)"),
        "{e}"
    );
    let ok = AnalysisConfig {
        margin: Some(31),
        octaves: 1,
        ..Default::default()
    };
    assert!(skeleton(&Field::new(img), &ok).is_ok());
}

/// No WTMM whose wavelet support (R a) touches a masked pixel.
#[test]
fn masked_pixels_keep_maxima_away() {
    let n = 256;
    let mut img = Array2::from_shape_fn((n, n), |(y, x)| {
        ((x as f64) * 0.21).sin() + ((y as f64) * 0.13 + (x as f64) * 0.05).cos()
    });
    for y in 100..120 {
        for x in 90..140 {
            img[[y, x]] = f64::NAN;
        }
    }
    let c = cfg(Wavelet::Gauss, 2, 20);
    let keep: Vec<usize> = (0..20).collect();
    let sk = skeleton_with(&Field::new(img), &c, Parallelism::Serial, &keep).unwrap();
    let support = Wavelet::Gauss.support_radius();
    let mut total = 0;
    for sm in &sk.kept {
        for w in &sm.wtmmm {
            let dx = (w.x as f64 - (w.x as f64).clamp(90.0, 139.0)).abs();
            let dy = (w.y as f64 - (w.y as f64).clamp(100.0, 119.0)).abs();
            assert!(
                (dx * dx + dy * dy).sqrt() > support * sm.a,
                "WTMMM too close to the hole"
            );
            total += 1;
        }
    }
    assert!(
        total > 100,
        "the rest of the image still has maxima ({total})"
    );
}

#[test]
fn serial_and_parallel_skeletons_are_identical() {
    let img =
        wtmm::synth::fbm::fbm(wtmm::synth::fbm::FbmParams { hurst: 0.5 }, 160, 144, 11, 0).unwrap();
    let c = cfg(Wavelet::Gauss, 3, 40);
    let f = Field::new(img);
    let a = skeleton_with(&f, &c, Parallelism::Serial, &[0, 15]).unwrap();
    let b = skeleton_with(&f, &c, Parallelism::Scales, &[0, 15]).unwrap();
    assert!(!a.lines.is_empty());
    assert_eq!(a, b);
}

/// Detection on row-streamed transforms (`detect_scale`) equals detection on
/// the full transform, with a margin (streamed) and without one (periodic
/// indexing, full transform), with and without chains kept.
#[test]
fn streamed_detection_equals_full_detection() {
    use wtmm::cwt::CwtPlan;
    use wtmm::skeleton::{DetectScratch, detect, detect_scale};
    // margin 0 is the whole torus (streamed with wrapped rows); 83 x 70 has
    // a last row block shorter than the others
    for (ny, nx, margin) in [(96, 96, 0), (96, 96, 4), (96, 96, 20), (83, 70, 0)] {
        let f = Field::new(
            wtmm::synth::fbm::fbm(wtmm::synth::fbm::FbmParams { hurst: 0.4 }, ny, nx, 3, 0)
                .unwrap(),
        );
        let c = AnalysisConfig {
            octaves: 3,
            ..cfg(Wavelet::Gauss, 3, margin)
        };
        let dom = c.domain(&f).unwrap();
        let scales = c.scale_list();
        let plan = CwtPlan::new(ny, nx, c.wavelet, &scales).unwrap();
        let fi = plan.forward(f.data.view()).unwrap();
        let (mut ws, mut s1, mut s2) = (
            plan.workspace(),
            DetectScratch::default(),
            DetectScratch::default(),
        );
        let mut total = 0;
        for (j, &a) in scales.iter().enumerate() {
            let keep = j % 2 == 0;
            let t = plan.scale(&fi, j, &mut ws).clone();
            let want = detect(&t, j, a, &dom, c.eps, keep, &mut s1);
            let got = detect_scale(&plan, &fi, j, &mut ws, &dom, c.eps, keep, &mut s2);
            assert_eq!(got, want, "{ny}x{nx} margin {margin} scale {j}");
            total += got.wtmmm.len();
        }
        assert!(total > 100, "a rough image has maxima ({total})");
    }
}

/// One scale of WTMMM on one open chain along the row y = 50, with the
/// modulus `m(x)` at every chain pixel; WTMMM where `m` has a strict local
/// maximum along the chain (chain ends carry none, as in `detect`).
fn one_chain_scale(
    j: usize,
    a: f64,
    xs: std::ops::Range<u32>,
    m: impl Fn(u32) -> f64,
) -> (ScaleMaxima, Vec<Vec<f64>>) {
    let pixels: Vec<(u32, u32)> = xs.clone().map(|x| (x, 50)).collect();
    let mv: Vec<f64> = xs.clone().map(&m).collect();
    let wtmmm = (1..mv.len() - 1)
        .filter(|&i| mv[i] > mv[i - 1] && mv[i] >= mv[i + 1])
        .map(|i| Wtmmm {
            x: pixels[i].0,
            y: 50,
            m: mv[i],
            arg: 0.0,
            chain: 0,
        })
        .collect();
    let sm = ScaleMaxima {
        j,
        a,
        n_wtmm: pixels.len(),
        n_chains: 1,
        wtmmm,
        chains: vec![Chain {
            pixels,
            closed: false,
        }],
    };
    (sm, vec![mv])
}

fn point_scale(j: usize, a: f64, pts: &[(u32, f64)]) -> ScaleMaxima {
    let pts: Vec<(u32, u32, f64)> = pts.iter().map(|&(x, m)| (x, 50, m)).collect();
    ScaleMaxima::from_points(j, a, &pts)
}

/// The maximum of a chain slides along it, 40 px between two voices (far
/// outside the 12 px box), while the modulus at the line's own position
/// barely changes: the box rule ends the line for want of a candidate, the
/// climb follows the chain to its new maximum (a modulus ratio of 1.05).
#[test]
fn climbing_follows_a_chain_maximum_that_slides_beyond_the_box() {
    let s0 = point_scale(0, 10.0, &[(20, 1.0)]);
    // M rises gently from x = 10 to its maximum at x = 60, then falls
    let (s1, m1) = one_chain_scale(1, 10.7, 10..80, |x| {
        if x <= 60 {
            0.99 + 0.06 * (x - 10) as f64 / 50.0
        } else {
            1.05 - 0.01 * (x - 60) as f64
        }
    });
    for climb in [false, true] {
        let mut lk = Linker::new(LinkParams {
            climb,
            ..Default::default()
        });
        lk.push(&s0);
        let e = lk.push_with(&s1, Some(&m1));
        let lines = lk.finish();
        if climb {
            assert_eq!(e.climb, 1);
            assert_eq!(lines[0].points.len(), 2);
            assert_eq!((lines[0].points[1].x, lines[0].points[1].y), (60, 50));
        } else {
            assert_eq!((e.no_candidate, e.climb), (1, 0));
            assert_eq!(lines[0].points.len(), 1);
        }
    }
}

/// The climb keeps the linking one-to-one and inside the ratio window: a
/// chain maximum already taken by a line that reached it through the box
/// is not taken twice, and one outside the window is not taken at all.
#[test]
fn climbing_respects_links_and_the_ratio_window() {
    let params = LinkParams {
        climb: true,
        ..Default::default()
    };
    // line 0 at x = 20 (lands on the chain), line 1 at x = 58 (its maximum in the box)
    let s0 = point_scale(0, 10.0, &[(20, 1.0), (58, 1.0)]);
    let (s1, m1) = one_chain_scale(1, 10.7, 10..80, |x| {
        if x <= 60 {
            0.99 + 0.06 * (x - 10) as f64 / 50.0
        } else {
            1.05 - 0.01 * (x - 60) as f64
        }
    });
    let mut lk = Linker::new(params);
    lk.push(&s0);
    let e = lk.push_with(&s1, Some(&m1));
    assert_eq!((e.no_candidate, e.climb), (1, 0));
    let lines = lk.finish();
    assert_eq!(lines[0].points.len(), 1);
    assert_eq!((lines[1].points[1].x, lines[1].points.len()), (60, 2));
    // the chain's maximum doubles the modulus: outside (0.9, 1.11)
    let s0 = point_scale(0, 10.0, &[(20, 1.0)]);
    let (s1, m1) = one_chain_scale(1, 10.7, 10..80, |x| {
        if x <= 60 {
            1.0 + (x - 10) as f64 / 50.0
        } else {
            2.0 - 0.01 * (x - 60) as f64
        }
    });
    let mut lk = Linker::new(params);
    lk.push(&s0);
    let e = lk.push_with(&s1, Some(&m1));
    assert_eq!(e.climb, 0);
    assert_eq!(lk.finish()[0].points.len(), 1);
}

/// Climbing along the chains leaves the exact local behaviour alone. The
/// climb (`LinkParams::climb`) only acts on a line left without a WTMMM,
/// after the box links of the scale are made, and takes only a WTMMM no
/// line took; a climbed line then competes in the box at the next scales.
/// With the default box every line of the cusp (h = 0.5) reaches the top
/// scale without climbing; with a box capped at 3 px the four lines born
/// near x0 outgrow it and end after a = 18-21 px, and the climb carries them
/// on to the top (a = 22.4 px), taking no WTMMM from the others: every
/// line born near x0 is, point for point, a prefix of its climbing run,
/// and the lines that reach a = 14.8 match [`CuspRef`] as in
/// `isolated_cusp_gives_its_holder_exponent` (M within the derived bound
/// at every scale, the slope within the propagated bound). (Far from x0,
/// in the taper, climbed lines do take WTMMM that box links took without
/// the climb.)
#[test]
fn climbing_keeps_the_cusp_exponent() {
    let x0 = [256.3, 255.6];
    let h = 0.5;
    let img = cusp_image(512, x0, h);
    let round = fft_rounding_bound(&img, Wavelet::Gauss);
    let field = Field::new(img);
    let mut c = cfg(Wavelet::Gauss, 4, 40);
    c.link.radius = wtmm::skeleton::SearchRadius::Reference { cap: 3.0 };
    let plain = skeleton(&field, &c).unwrap();
    c.link.climb = true;
    let sk = skeleton(&field, &c).unwrap();
    // lines are born at a_min, in the same order in both runs
    assert_eq!(plain.lines.len(), sk.lines.len());
    let (j0, j1) = (3, 33);
    let mut longer = 0;
    for (p, q) in plain.lines.iter().zip(&sk.lines) {
        let b = p.points[0];
        if (b.x as f64 - x0[0]).hypot(b.y as f64 - x0[1]) >= 5.0 {
            continue;
        }
        assert!(
            q.points.starts_with(&p.points),
            "a line born at ({},{}) changed with the climb",
            b.x,
            b.y
        );
        longer += usize::from(q.points.len() > p.points.len());
    }
    assert!(longer > 0, "no line near x0 climbed");
    let n_near = check_cusp_lines(&sk, &CuspRef::new(h, x0), round, j0, j1);
    assert!(n_near > 0, "no line converging to x0 survives 3 octaves");
}

/// On the whole torus (margin 0) the chains and lines wrap across the
/// image's edges, as the periodic transform does: a disc centred on the
/// corner of the image is one closed chain per scale, the same as the
/// disc in the middle, not four arcs cut by the edges.
#[test]
fn disc_across_the_edges_of_the_torus_is_one_closed_chain() {
    let n = 256;
    let r = 40.0;
    let disc = |cx: f64, cy: f64| {
        Array2::from_shape_fn((n, n), |(y, x)| {
            // torus distance to the centre
            let d = |a: f64, c: f64| {
                let d = (a - c).abs();
                d.min(n as f64 - d)
            };
            let (dx, dy) = (d(x as f64, cx), d(y as f64, cy));
            if dx * dx + dy * dy < r * r { 1.0 } else { 0.0 }
        })
    };
    let c = AnalysisConfig {
        a_min: 2.0,
        ..cfg(Wavelet::Gauss, 3, 0)
    };
    let keep: Vec<usize> = (0..30).collect();
    let corner =
        skeleton_with(&Field::new(disc(0.0, 0.0)), &c, Parallelism::Serial, &keep).unwrap();
    let middle = skeleton_with(
        &Field::new(disc(128.0, 128.0)),
        &c,
        Parallelism::Serial,
        &keep,
    )
    .unwrap();
    for (sm, sm_mid) in corner.kept.iter().zip(&middle.kept) {
        let ch = one_closed_chain(sm);
        assert_eq!(
            ch.pixels.len(),
            sm_mid.chains[0].pixels.len(),
            "a={:.2}",
            sm.a
        );
        // every pixel of the chain is at the disc's edge, the short way round
        for &(x, y) in &ch.pixels {
            let d = |a: u32| (a as f64).min(n as f64 - a as f64);
            let rad = d(x).hypot(d(y));
            assert!(
                (rad - r).abs() < 2.0 + 0.2 * sm.a,
                "a={:.2}: pixel ({x},{y})",
                sm.a
            );
        }
        assert!(!sm.wtmmm.is_empty(), "a={:.2}: no WTMMM", sm.a);
    }
    // the lines born on the edge survive to the largest scale in both
    let last = corner.per_scale.len() - 1;
    assert!(corner.per_scale[last].lines > 0);
    assert_eq!(corner.per_scale[last].lines, middle.per_scale[last].lines);
}

/// The linker on a torus measures distances the short way round: a line
/// at the right edge links to a WTMMM at the left edge (and prefers it to
/// a farther one inside the image); on the plane it cannot.
#[test]
fn lines_link_across_the_edge_of_a_torus() {
    let s0 = point_scale(0, 3.0, &[(99, 1.0)]);
    // x = 1 is 2 px away round the edge of a 100 px torus, x = 94 is 5 px away
    let s1 = point_scale(1, 3.2, &[(1, 1.0), (94, 1.0)]);
    let mut torus = Linker::new(LinkParams::default()).periodic(Some((100, 100)));
    torus.push(&s0);
    torus.push(&s1);
    let lines = torus.finish();
    assert_eq!(lines[0].points.len(), 2);
    assert_eq!(lines[0].points[1].x, 1);
    let mut plane = Linker::new(LinkParams::default());
    plane.push(&s0);
    plane.push(&s1);
    assert_eq!(plane.finish()[0].points[1].x, 94);
    // beyond the box both ways round: no link
    let s1 = point_scale(1, 3.2, &[(40, 1.0)]);
    let mut torus = Linker::new(LinkParams::default()).periodic(Some((100, 100)));
    torus.push(&s0);
    let e = torus.push(&s1);
    assert_eq!(e.no_candidate, 1);
}

/// `T1` at column `x0` of an image `f(x)` constant along y, by the 1D
/// discrete Fourier sum of SPEC §1's `T̂1(k) = i a kx φ̂(a|k|) f̂(k)` (only
/// ky = 0 carries power): `T1(x0) = (1/N) Σ_m i a k_m φ̂(a |k_m|) f̂[m]
/// e^(i k_m x0)`, `k_m = 2π m/N` folded into (-π, π], with the derivative
/// set to 0 at the Nyquist mode m = N/2 (a real field's derivative there is
/// ambiguous; the CWT uses the same convention). Written out directly,
/// O(N²), independent of the library's FFTs and filters.
fn dft_t1(f: &[f64], wavelet: Wavelet, a: f64, x0: usize) -> f64 {
    use std::f64::consts::PI;
    let n = f.len();
    let mut t = 0.0;
    for m in 0..n {
        if 2 * m == n {
            continue;
        }
        let k = 2.0
            * PI
            * if 2 * m < n {
                m as f64
            } else {
                m as f64 - n as f64
            }
            / n as f64;
        let (mut re, mut im) = (0.0, 0.0);
        for (x, v) in f.iter().enumerate() {
            let ph = -k * x as f64;
            re += v * ph.cos();
            im += v * ph.sin();
        }
        let g = (-0.5 * a * a * k * k).exp()
            * match wavelet {
                Wavelet::Gauss => 1.0,
                Wavelet::Mexican => a * a * k * k,
            };
        // Re[i a k g F e^(i k x0)] = -a k g Im[F e^(i k x0)]
        let ph = k * x0 as f64;
        t -= a * k * g * (re * ph.sin() + im * ph.cos());
    }
    t / n as f64
}

/// Absolute calibration (SPEC §1, L1 normalisation). On a unit step edge
/// `f = H(x - x0)` the transform is `T1(x) = a ∂x (φ_a * H)(x) = a
/// (marginal of φ_a)(x - x0)`: for gauss the marginal is the 1D Gaussian of
/// standard deviation a, so on the edge `M = a · 1/(a √(2π)) = 1/√(2π)`
/// at every scale; for mexican `φ = -∇²g`, the marginal of `φ_a` is
/// `-(1/a) g1''(u/a)`, `T1 = (1 - u²/a²) g1(u/a)` and again `M(x0) =
/// 1/√(2π)`. A prefactor `a^p` with p ≠ 1, a Gaussian of width other than
/// a (M = a/σ √(2π)) or a lost 2π all move this number.
///
/// The image samples the step (0, then 1/2 on the edge column, then 1), so
/// the discrete transform differs from the continuous one by the pixel:
/// the step's difference has the spectrum `e^(-ik/2) cos(k/2)` per unit
/// jump against `(ik)^-1`, which multiplies the integrand by `(k/2)
/// cot(k/2) = 1 - k²/12 - k⁴/720 - ...`, so `M √(2π) = 1 - c1/a² - r`,
/// with the Gaussian moments `c1 = 1/12` (gauss; `<k²> = 1/a²`) and `1/4`
/// (mexican, weight `k² e^(-a²k²/2)`: `<k²> = 3/a²`), and a remainder `r`
/// between `c2/a⁴` and `2 c2/a⁴` (all terms of the cot series are negative
/// and fall off by `(a 2π)^-2` per order), `c2 = 1/240` and `1/48`.
/// Checked: along the maxima line on the edge, at every scale,
/// (1) M equals the direct discrete Fourier sum [`dft_t1`] to 1e-12
///     relative (rounding of the FFTs);
/// (2) M √(2π) lies in `[1 - c1/a² - 2 c2/a⁴, 1 - c1/a² - c2/a⁴]` (plus
///     1e-12), which pins the normalisation to about 1e-4 at a = 3.
#[test]
fn step_edge_modulus_is_calibrated() {
    let n = 256;
    let row: Vec<f64> = (0..n)
        .map(|x| match x.cmp(&128) {
            std::cmp::Ordering::Less => 0.0,
            std::cmp::Ordering::Equal => 0.5,
            std::cmp::Ordering::Greater => 1.0,
        })
        .collect();
    let img = Array2::from_shape_fn((n, n), |(_, x)| row[x]);
    let s2pi = (2.0 * std::f64::consts::PI).sqrt();
    for (wavelet, c1, c2) in [
        (Wavelet::Gauss, 1.0 / 12.0, 1.0 / 240.0),
        (Wavelet::Mexican, 0.25, 1.0 / 48.0),
    ] {
        let sk = skeleton(&Field::new(img.clone()), &cfg(wavelet, 3, 40)).unwrap();
        let ns = sk.scales.len();
        let on_edge: Vec<&MaximaLine> = sk
            .lines
            .iter()
            .filter(|l| l.points.len() == ns && l.points.iter().all(|p| p.x == 128))
            .collect();
        assert_eq!(on_edge.len(), 1, "{wavelet}: one line along the edge");
        for (j, p) in on_edge[0].points.iter().enumerate() {
            let a = sk.scales[j];
            let want = dft_t1(&row, wavelet, a, 128);
            assert!(
                (p.m - want).abs() < 1e-12 * want,
                "{wavelet} a={a:.3}: M = {} vs direct sum {want}",
                p.m
            );
            let x = p.m * s2pi;
            let (hi, lo) = (
                1.0 - c1 / (a * a) - c2 / a.powi(4),
                1.0 - c1 / (a * a) - 2.0 * c2 / a.powi(4),
            );
            if j % 10 == 0 || j == ns - 1 {
                println!(
                    "{wavelet} a={a:6.3}: M sqrt(2 pi) = {x:.8} in [{lo:.8}, {hi:.8}], |M - direct| / M = {:.1e}",
                    (p.m - want).abs() / want
                );
            }
            assert!(
                x <= hi + 1e-12 && x >= lo - 1e-12,
                "{wavelet} a={a:.3}: M sqrt(2 pi) = {x:.8}, expected in [{lo:.8}, {hi:.8}]"
            );
        }
    }
}

/// Diagnostic behind the README's "Not spurious chain maxima" (not a check;
/// `cargo test --release --test skeleton experiment_chain_maxima_spacing --
/// --ignored --nocapture`, env PRESET (default paper-fisc), WAVELET = gauss
/// | mexican (default: the preset's), N images of 1024^2 (default 2)). At
/// every fifth scale, over the chains of the whole torus: the number of
/// WTMMM, the chains' length in pixels times a (constant for a
/// self-similar field), the distance along the chain between neighbouring
/// WTMMM in units of a (quantiles, and the share below 0.5 a), and the
/// share whose dip between them is below 0.1 % of the lower one.
#[test]
#[ignore]
fn experiment_chain_maxima_spacing() {
    use wtmm::cwt::CwtPlan;
    use wtmm::skeleton::maxima::{DetectScratch, detect, for_each_chain_max};
    use wtmm::theory::Model;
    let name = std::env::var("PRESET").unwrap_or_else(|_| "paper-fisc".into());
    let preset = Model::preset(&name).unwrap();
    let wavelet = match std::env::var("WAVELET").as_deref() {
        Ok("gauss") => Wavelet::Gauss,
        Ok("mexican") => Wavelet::Mexican,
        _ => preset.wavelet,
    };
    let n: u64 = std::env::var("N").map(|s| s.parse().unwrap()).unwrap_or(2);
    let size = 1024;
    let c = cfg(wavelet, 5, 0);
    let scales = c.scale_list();
    let plan = CwtPlan::new(size, size, wavelet, &scales).unwrap();
    let images: Vec<Field> = (0..n)
        .map(|i| Field::new(preset.model.synthesize(size, 1, i).unwrap()))
        .collect();
    println!("{name}, {wavelet:?}, {n} x {size}^2");
    println!("     a  WTMMM  chain px * a | gap / a: q10  q25  q50  < 0.5 | dip < 0.1 %");
    for j in (5..scales.len()).step_by(5) {
        let a = scales[j];
        let (mut count, mut len) = (0usize, 0usize);
        let (mut gaps, mut dips) = (Vec::new(), Vec::new());
        for field in &images {
            let domain = c.domain(field).unwrap();
            let fi = plan.forward(field.filled().unwrap().view()).unwrap();
            let mut ws = plan.workspace();
            let t = plan.scale(&fi, j, &mut ws).to_owned();
            let sm = detect(
                &t,
                j,
                a,
                &domain,
                c.eps,
                true,
                &mut DetectScratch::default(),
            );
            count += sm.wtmmm.len();
            for ch in &sm.chains {
                len += ch.pixels.len();
                let m: Vec<f64> = ch
                    .pixels
                    .iter()
                    .map(|&(x, y)| t[[y as usize, x as usize]].norm())
                    .collect();
                let mut idx = Vec::new();
                for_each_chain_max(&m, ch.closed, |k| idx.push(k));
                for w in idx.windows(2) {
                    gaps.push((w[1] - w[0]) as f64 / a);
                    let low = m[w[0]..=w[1]].iter().copied().fold(f64::INFINITY, f64::min);
                    let top = m[w[0]].min(m[w[1]]);
                    dips.push((top - low) / top);
                }
            }
        }
        gaps.sort_by(f64::total_cmp);
        let q = |f: f64| gaps[((gaps.len() - 1) as f64 * f) as usize];
        let share =
            |v: &[f64], t: f64| v.iter().filter(|&&x| x < t).count() as f64 / v.len() as f64;
        println!(
            "{a:6.2} {count:6} {:13.0} |        {:.2} {:.2} {:.2} {:.2}  | {:.2}",
            len as f64 * a,
            q(0.1),
            q(0.25),
            q(0.5),
            share(&gaps, 0.5),
            share(&dips, 0.001)
        );
    }
}

/// A search radius larger than any image (a huge proportional factor or
/// minimum, which validation accepts) links as the whole image would: no
/// division by zero in the bucket grid (its cell size wrapped to 0), and
/// with `climb` no search over a box of 2e9 px a side (it never ended).
#[test]
fn a_radius_beyond_the_image_links_as_the_whole_image() {
    use wtmm::skeleton::SearchRadius;
    let img =
        wtmm::synth::fbm::fbm(wtmm::synth::fbm::FbmParams { hurst: 0.4 }, 48, 48, 3, 0).unwrap();
    let field = Field::new(img);
    for (radius, climb) in [
        (
            SearchRadius::Proportional {
                factor: 1e300,
                min: 1.0,
            },
            false,
        ),
        (
            SearchRadius::Proportional {
                factor: 1.0,
                min: 4294967295.0,
            },
            false,
        ),
        (
            SearchRadius::Proportional {
                factor: 1.0,
                min: 1e9,
            },
            true,
        ),
    ] {
        for margin in [0, 4] {
            let mut c = cfg(Wavelet::Gauss, 2, margin);
            c.link = LinkParams {
                radius,
                climb,
                ..Default::default()
            };
            c.validate().unwrap();
            let sk = skeleton_with(&field, &c, Parallelism::Serial, &[]).unwrap();
            assert!(!sk.lines.is_empty(), "{radius:?} climb {climb}");
        }
    }
}

/// The seven symmetries of the square grid other than the identity (flips,
/// transposes, quarter turns), with the map taking a pixel `(x, y)` of the transformed image of
/// an `ny x nx` original back to the original's.
#[allow(clippy::type_complexity)]
fn grid_symmetries(
    img: &Array2<f64>,
) -> Vec<(
    &'static str,
    Array2<f64>,
    Box<dyn Fn(u32, u32) -> (u32, u32)>,
)> {
    use ndarray::s;
    let (ny, nx) = img.dim();
    let (ly, lx) = (ny as u32 - 1, nx as u32 - 1);
    vec![
        (
            "fliplr",
            img.slice(s![.., ..;-1]).to_owned(),
            Box::new(move |x, y| (lx - x, y)),
        ),
        (
            "flipud",
            img.slice(s![..;-1, ..]).to_owned(),
            Box::new(move |x, y| (x, ly - y)),
        ),
        (
            "rot180",
            img.slice(s![..;-1, ..;-1]).to_owned(),
            Box::new(move |x, y| (lx - x, ly - y)),
        ),
        ("transpose", img.t().to_owned(), Box::new(|x, y| (y, x))),
        (
            "antitranspose",
            img.t().slice(s![..;-1, ..;-1]).to_owned(),
            Box::new(move |x, y| (lx - y, ly - x)),
        ),
        (
            "rot90",
            img.t().slice(s![.., ..;-1]).to_owned(),
            Box::new(move |x, y| (y, ly - x)),
        ),
        (
            "rot270",
            img.t().slice(s![..;-1, ..]).to_owned(),
            Box::new(move |x, y| (lx - y, x)),
        ),
    ]
}

/// A surface has no up, down, left or right: the skeleton of a flipped,
/// transposed or rotated image is the original's, moved (the same WTMMM at
/// every scale, the same lines), and so are its partition sums, up to the
/// FFT's rounding, and the errors of its jackknife over tiles. The chain
/// walks and the linking's ties are decided by distances and moduli, never
/// by the raster order, and the tiles are cut symmetrically (README,
/// Conventions); before that, transposing 16 fBm of 512² moved D(h(0)) by
/// 0.015, and a flip the tile errors by up to 7 %.
#[test]
fn the_skeleton_does_not_depend_on_the_image_orientation() {
    use std::collections::BTreeSet;
    use wtmm::skeleton::skeleton_and_wtmmm;
    use wtmm::synth::fbm::{FbmParams, fbm};
    // not square, not a power of two
    let img = fbm(FbmParams { hurst: 0.4 }, 190, 150, 5, 0).unwrap();
    let q = [-3.0, -1.0, 0.0, 1.0, 2.0, 4.0];
    for (wavelet, margin) in [
        (Wavelet::Gauss, None),
        (Wavelet::Gauss, Some(0)),
        (Wavelet::Mexican, Some(0)),
    ] {
        let c = AnalysisConfig {
            wavelet,
            octaves: 3,
            margin,
            ..Default::default()
        };
        let ns = c.scale_list().len();
        let run = |im: &Array2<f64>| {
            let f = Field::new(im.clone());
            let (sk, w) = skeleton_and_wtmmm(&f, &c, Parallelism::Serial, ns, true).unwrap();
            let (ny, nx) = im.dim();
            let side = wtmm::default_tile_side(&c, ny, nx);
            // the jackknife tiles: a flip maps them onto each other unless
            // an odd side is cut into an even number of tiles (its centre
            // row goes to one half), which this image and analysis avoid
            let (y0, y1, x0, x1) = sk.domain;
            for len in [y1 - y0, x1 - x0] {
                assert!(
                    len % 2 == 0 || (len / side).max(1) % 2 == 1,
                    "{len} px in {side} px tiles"
                );
            }
            let sums =
                wtmm::image_sums_tiled(&f, &c, &q, "img", Parallelism::Serial, side).unwrap();
            assert!(
                sums.images[0].tiles.len() >= 4,
                "{} tiles",
                sums.images[0].tiles.len()
            );
            (sk, w, sums)
        };
        let (sk0, w0, z0) = run(&img);
        let total: usize = w0.iter().map(Vec::len).sum();
        assert!(total > 1500, "{wavelet:?} {margin:?}: only {total} WTMMM");
        for (name, im, back) in grid_symmetries(&img) {
            let (sk, w, z) = run(&im);
            let what = format!("{name}, {wavelet:?}, margin {margin:?}");
            for j in 0..ns {
                let a: BTreeSet<(u32, u32)> = w0[j].iter().map(|p| (p.x, p.y)).collect();
                let b: BTreeSet<(u32, u32)> = w[j].iter().map(|p| back(p.x, p.y)).collect();
                let moved = a.symmetric_difference(&b).count();
                assert_eq!(moved, 0, "{what}: {moved} WTMMM of scale {j} differ");
                let (c0, c1) = (&sk0.per_scale[j], &sk.per_scale[j]);
                assert_eq!(
                    (c0.wtmm, c0.chains, c0.wtmmm, c0.lines),
                    (c1.wtmm, c1.chains, c1.wtmmm, c1.lines),
                    "{what}: the counts of scale {j}"
                );
            }
            // the lines themselves, point by point (born in another order)
            let path = |l: &MaximaLine, f: &dyn Fn(u32, u32) -> (u32, u32)| {
                l.points.iter().map(|p| f(p.x, p.y)).collect::<Vec<_>>()
            };
            let l0: BTreeSet<_> = sk0.lines.iter().map(|l| path(l, &|x, y| (x, y))).collect();
            let l1: BTreeSet<_> = sk.lines.iter().map(|l| path(l, &*back)).collect();
            assert_eq!(l0.len(), sk0.lines.len(), "{what}: two lines on one path");
            assert!(l0 == l1, "{what}: the maxima lines differ");
            let (p0, p1) = (&z0.images[0], &z.images[0]);
            assert_eq!(p0.lines, p1.lines, "{what}");
            for (c0, c1) in p0
                .plain
                .iter()
                .chain(&p0.sup)
                .zip(p1.plain.iter().chain(&p1.sup))
            {
                // M differs by the FFT's rounding (~1e-15 relative), which
                // M^q multiplies by |q| <= 4
                let (v0, v1) = (c0.z * 2f64.powi(c0.e), c1.z * 2f64.powi(c1.e));
                assert!(
                    (v0 - v1).abs() <= 1e-12 * v0.abs(),
                    "{what}: Z {v0} against {v1}"
                );
            }
            // the single-image jackknife over the tiles: the same errors
            let fit = z0.default_fit().unwrap();
            let (s0, s1) = (
                z0.spectra(wtmm::Rule::Plain, fit).unwrap(),
                z.spectra(wtmm::Rule::Plain, fit).unwrap(),
            );
            for (k, (e0, e1)) in s0.tau_stderr.iter().zip(&s1.tau_stderr).enumerate() {
                assert!(
                    (e0 - e1).abs() <= 1e-9 * e0.abs(),
                    "{what}: tau({}) stderr {e0} against {e1}",
                    q[k]
                );
            }
        }
    }
}
