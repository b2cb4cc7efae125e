//! Branch-free sine/cosine and decibels for the vector kernels.
//!
//! The C library's `sin_cos` and `log10` are calls the compiler cannot
//! vectorize; in the signature stage (16 microphone phasors and 24 band
//! levels per track and refresh) they were a quarter of its cost. These are
//! plain arithmetic on `f64`/`f32` lanes, so a loop over microphones or bands
//! compiles to vector instructions inside a [`crate::simd`] kernel.
//!
//! **[`sin_cos`].** The angle is reduced to `r ∈ [−π, π]` in `f64`
//! (`x − 2π·round(x/2π)`, exact to ~1e-16·|x|), halved, and `sin`/`cos` of
//! `h = r/2 ∈ [−π/2, π/2]` come from their Taylor series to `h¹³`/`h¹⁴`
//! (next terms below 7e-10 at |h| = π/2); then `sin r = 2 sin h cos h`,
//! `cos r = cos²h − sin²h`. Absolute error ≤ 2e-9 before the result's
//! rounding to `f32` (~6e-8), for |x| up to ~1e6 rad.
//!
//! **[`decibels`].** `10·log10(x)` of a positive `f32`: `x = m·2^e` with the
//! mantissa taken into `[√½, √2)`, `ln m = 2 atanh t = 2(t + t³/3 + … + t⁹/9)`
//! with `t = (m − 1)/(m + 1)`, |t| ≤ 0.172 (next term below 1e-9), then
//! `10·(e·log10 2 + ln m·log10 e)`. Error within 3e-5 dB (the `f32` rounding
//! of values up to ±200 dB). Zero, negative,
//! subnormal and NaN inputs are the caller's to exclude (the signature stage
//! floors its powers at 1e-20 first); +∞ gives ~385 dB.

use std::f64::consts::{LN_2, LN_10, TAU};

/// `(sin x, cos x)` in `f32` (see the module docs).
#[inline(always)]
pub fn sin_cos(x: f64) -> (f32, f32) {
    let r = x - TAU * (x * (1.0 / TAU)).round_ties_even();
    let h = 0.5 * r;
    let h2 = h * h;
    let s = h
        * (1.0
            + h2 * (-1.0 / 6.0
                + h2 * (1.0 / 120.0
                    + h2 * (-1.0 / 5040.0
                        + h2 * (1.0 / 362_880.0
                            + h2 * (-1.0 / 39_916_800.0 + h2 * (1.0 / 6_227_020_800.0)))))));
    let c = 1.0
        + h2 * (-0.5
            + h2 * (1.0 / 24.0
                + h2 * (-1.0 / 720.0
                    + h2 * (1.0 / 40_320.0
                        + h2 * (-1.0 / 3_628_800.0
                            + h2 * (1.0 / 479_001_600.0 + h2 * (-1.0 / 87_178_291_200.0)))))));
    ((2.0 * s * c) as f32, (c * c - s * s) as f32)
}

/// `10·log10(x)` for a positive, normal, finite `x` (see the module docs).
#[inline(always)]
pub fn decibels(x: f32) -> f32 {
    let bits = x.to_bits();
    let exponent = ((bits >> 23) & 0xff) as i32 - 127;
    let mantissa = f32::from_bits((bits & 0x007f_ffff) | 0x3f80_0000);
    // Into [√½, √2): halve the mantissa and raise the exponent above √2.
    let high = mantissa >= std::f32::consts::SQRT_2;
    let m = if high { 0.5 * mantissa } else { mantissa };
    let e = (exponent + i32::from(high)) as f32;
    let t = (m - 1.0) / (m + 1.0);
    let t2 = t * t;
    let ln_m = 2.0 * t * (1.0 + t2 * (1.0 / 3.0 + t2 * (1.0 / 5.0 + t2 * (1.0 / 7.0 + t2 * (1.0 / 9.0)))));
    const TEN_LOG10_2: f32 = (10.0 * LN_2 / LN_10) as f32;
    const TEN_LOG10_E: f32 = (10.0 / LN_10) as f32;
    e * TEN_LOG10_2 + ln_m * TEN_LOG10_E
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sin_cos_matches_the_library_over_many_turns() {
        let mut worst: f64 = 0.0;
        for i in -200_000..=200_000 {
            let x = i as f64 * 1.0e-3 * std::f64::consts::PI + 1e-4;
            let (s, c) = sin_cos(x);
            worst = worst.max((s as f64 - x.sin()).abs()).max((c as f64 - x.cos()).abs());
        }
        assert!(worst < 1.2e-7, "worst error {worst:e}");
        assert_eq!(sin_cos(0.0), (0.0, 1.0));
    }

    #[test]
    fn decibels_match_the_library_from_the_floor_to_the_top() {
        let mut worst: f64 = 0.0;
        let mut x = 1e-20f32;
        while x < 1e30 {
            let want = 10.0 * (x as f64).log10();
            worst = worst.max((decibels(x) as f64 - want).abs());
            x *= 1.0137;
        }
        assert!(worst < 5e-5, "worst error {worst:e} dB");
        assert_eq!(decibels(1.0), 0.0);
        assert!((decibels(2.0) - 3.0103).abs() < 1e-4);
        assert!(decibels(f32::INFINITY) > 200.0);
    }
}
