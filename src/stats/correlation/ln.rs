//! A vectorised `½ ln` of the squared moduli (libm's scalar `ln` was a
//! quarter of the correlation's time).

use super::*;

/// `out[i] = ½ ln |z_i|²` (`-inf` where `|z|²` is 0, subnormal or not
/// finite); returns the largest finite `|z|²`.
pub(super) fn half_ln_sq_row(src: &[Complex64], out: &mut [f64]) -> f64 {
    for (o, z) in out.iter_mut().zip(src) {
        *o = z.re * z.re + z.im * z.im;
    }
    half_ln_in_place(out)
}

/// `out[i] = ½ ln q_i` for the energies `q` of `src` (same rules).
pub(super) fn half_ln_row(src: &[f64], out: &mut [f64]) -> f64 {
    out.copy_from_slice(src);
    half_ln_in_place(out)
}

/// `v <- ½ ln v` (`-inf` where `v` is 0, subnormal or not finite); returns
/// the largest finite input. AVX2 when available (the same bits either way:
/// no FMA contraction without `mul_add`).
pub(super) fn half_ln_in_place(v: &mut [f64]) -> f64 {
    #[cfg(target_arch = "x86_64")]
    {
        #[target_feature(enable = "avx2")]
        unsafe fn avx2(v: &mut [f64]) -> f64 {
            half_ln_impl(v)
        }
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2 (checked just above).
            return unsafe { avx2(v) };
        }
    }
    half_ln_impl(v)
}

#[inline(always)]
pub(super) fn half_ln_impl(v: &mut [f64]) -> f64 {
    let ok = |x: f64| (f64::MIN_POSITIVE..=f64::MAX).contains(&x);
    // two simple loops: the max in four lanes, then a pure map (a loop
    // doing both did not vectorise)
    let mut mx = [0.0f64; 4];
    let ch = v.chunks_exact(4);
    for &x in ch.remainder() {
        mx[0] = if ok(x) && x > mx[0] { x } else { mx[0] };
    }
    for c in ch {
        for k in 0..4 {
            mx[k] = if ok(c[k]) && c[k] > mx[k] {
                c[k]
            } else {
                mx[k]
            };
        }
    }
    for q in v.iter_mut() {
        let x = *q;
        let l = 0.5 * ln_normal(if ok(x) { x } else { 1.0 });
        *q = if ok(x) { l } else { f64::NEG_INFINITY };
    }
    mx[0].max(mx[1]).max(mx[2].max(mx[3]))
}

/// Natural log of a positive normal finite `x`, branch-free so that a row
/// loop vectorises (libm's `ln` is a scalar call: it was a quarter of the
/// correlation's time). `x = 2^e m` with `m` in `[1/√2, √2)`;
/// `ln m = 2 atanh(s) = 2 Σ s^(2k+1)/(2k+1)`, `s = (m-1)/(m+1)`,
/// `|s| <= 0.1716`: the terms through `s^21` leave a relative remainder
/// below 1e-17. Accurate to a few ulp (test `ln_normal_matches_libm`).
#[inline(always)]
pub(super) fn ln_normal(x: f64) -> f64 {
    // ln 2 = LN2_HI + LN2_LO, the high part with 32 significant bits so
    // that e * LN2_HI is exact (fdlibm's split)
    const LN2_HI: f64 = f64::from_bits(0x3fe6_2e42_fee0_0000);
    const LN2_LO: f64 = f64::from_bits(0x3dea_39ef_3579_3c76);
    let bits = x.to_bits();
    // the biased exponent as a float, exactly (2^52 + e - 2^52)
    let eb = f64::from_bits((bits >> 52) | 0x4330_0000_0000_0000) - 4_503_599_627_370_496.0;
    let m1 = f64::from_bits((bits & 0x000f_ffff_ffff_ffff) | 0x3ff0_0000_0000_0000);
    let big = m1 > std::f64::consts::SQRT_2;
    let m = if big { 0.5 * m1 } else { m1 };
    let e = eb - 1023.0 + if big { 1.0 } else { 0.0 };
    let s = (m - 1.0) / (m + 1.0);
    let z = s * s;
    let mut p = 1.0 / 21.0;
    for c in [19.0, 17.0, 15.0, 13.0, 11.0, 9.0, 7.0, 5.0, 3.0] {
        p = p * z + 1.0 / c;
    }
    p = p * z + 1.0;
    e * LN2_HI + (e * LN2_LO + 2.0 * s * p)
}
