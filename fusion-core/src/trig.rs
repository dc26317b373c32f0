//! `sin` and `cos` of an `f32` in `f32` arithmetic alone.
//!
//! libm's `sinf`/`cosf` evaluate their polynomials and their argument reduction in `f64`,
//! which the Cortex-M4F computes in software: with the soft-double routines they pull in
//! about 8 KB of flash (measured with `llvm-nm --size-sort`, issue 18) and cost hundreds of
//! instructions a call. The filter needs sine and cosine only of angles of a few radians
//! (half the yaw at initialisation, the rotation increment of a fast spin), so a Cody-Waite
//! reduction to `[−π/4, π/4]` and two short minimax polynomials do, to within 2 ulp of the
//! exact value, or 10⁻⁹ absolute below 2⁻⁸ (tested against `f64` below).
//!
//! Used by [`crate::Scalar::sin_cos_of`] for `f32` on the PC and on the MCU alike, so that
//! the two builds still agree bit for bit.

/// `π/2` in three parts (Cody-Waite): the first two have 8 and 11 significant bits, so that
/// `x − k π/2` is computed all but exactly for `|x| ≤ 8192` (within the 2 ulp tested below).
const PIO2_1: f32 = 1.570_312_5;
const PIO2_2: f32 = 4.837_513e-4;
const PIO2_3: f32 = 7.549_79e-8;

/// Beyond this the three-part reduction is no longer exact; a larger argument is first
/// reduced by whole turns in plain `f32`, which errs by less than the argument's own spacing
/// there (≥ 2⁻¹⁰ rad): nothing that an `f32` angle that large still says is lost. (The exact
/// remainder, `%`, would add 650 bytes of flash for angles no sensor produces.)
const EXACT_REDUCTION_LIMIT: f32 = 8192.0;

/// Minimax coefficients of `sin r = r + r³ (S1 + r² (S2 + r² S3))` on `[−π/4, π/4]`.
const S1: f32 = -1.666_665_5e-1;
const S2: f32 = 8.332_161e-3;
const S3: f32 = -1.951_529_6e-4;
/// Minimax coefficients of `cos r = 1 − r²/2 + r⁴ (C1 + r² (C2 + r² C3))` on `[−π/4, π/4]`.
const C1: f32 = 4.166_664_6e-2;
const C2: f32 = -1.388_731_6e-3;
const C3: f32 = 2.443_315_7e-5;

/// `(sin x, cos x)`; NaN for a non-finite `x`.
pub fn sin_cos_f32(x: f32) -> (f32, f32) {
    if !x.is_finite() {
        return (f32::NAN, f32::NAN);
    }
    let mut x = x;
    // Each pass leaves at most the rounding of `turns · 2π`, a few ulp of the previous `x`:
    // six passes bring even `f32::MAX` below the limit (and `round` of anything above it is
    // non-zero, so every pass makes progress).
    while x.abs() > EXACT_REDUCTION_LIMIT {
        x -= round(x * (0.5 / core::f32::consts::PI)) * core::f32::consts::TAU;
    }
    let kf = round(x * core::f32::consts::FRAC_2_PI);
    let k = kf as i32;
    let r = ((x - kf * PIO2_1) - kf * PIO2_2) - kf * PIO2_3;
    let z = r * r;
    let s = r + r * z * (S1 + z * (S2 + z * S3));
    let c = 1.0 - 0.5 * z + z * z * (C1 + z * (C2 + z * C3));
    // x = k π/2 + r: rotate (sin r, cos r) by the quadrant.
    match k & 3 {
        0 => (s, c),
        1 => (c, -s),
        2 => (-s, -c),
        _ => (-c, s),
    }
}

/// Nearest integer, halves away from zero (`f32::round` is not in `core`). From 2²³ on,
/// every `f32` is an integer.
fn round(v: f32) -> f32 {
    if v.abs() >= 8_388_608.0 {
        v
    } else {
        (v + if v < 0.0 { -0.5 } else { 0.5 }) as i32 as f32
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Error in units of the last place of the exact value: one f32 ulp at `|v|`, and no
    /// finer than the ulp at 2⁻⁸ (4.7·10⁻¹⁰) near zero crossings, where the reduction's
    /// absolute error is what counts.
    fn ulps(got: f32, exact: f64) -> f64 {
        let scale = exact.abs().max(2f64.powi(-8));
        let ulp = 2f64.powi(scale.log2().floor() as i32 - 23);
        (f64::from(got) - exact).abs() / ulp
    }

    #[test]
    fn within_two_ulp_of_f64_over_many_turns() {
        let mut worst = (0.0f64, 0.0f32);
        let mut x = -EXACT_REDUCTION_LIMIT;
        let mut check = |x: f32| {
            let (s, c) = sin_cos_f32(x);
            let (es, ec) = f64::from(x).sin_cos();
            for e in [ulps(s, es), ulps(c, ec)] {
                if e > worst.0 {
                    worst = (e, x);
                }
            }
        };
        while x <= EXACT_REDUCTION_LIMIT {
            check(x);
            x += 0.0137;
        }
        // Small angles, quadrant edges and the exact multiples of π/2.
        for k in -64..=64 {
            let edge = k as f32 * core::f32::consts::FRAC_PI_2;
            for d in [-1e-3f32, -1e-6, 0.0, 1e-6, 1e-3] {
                check(edge + d);
            }
        }
        for e in -30..0 {
            check(2f32.powi(e));
            check(-(2f32.powi(e)));
        }
        assert!(worst.0 <= 2.0, "{} ulp at x = {}", worst.0, worst.1);
    }

    #[test]
    fn large_and_non_finite_arguments() {
        // Beyond the exact reduction, the result is the sine and cosine of an angle within
        // the argument's own spacing, and a unit pair for every finite argument.
        for x in [1.0e4f32, -3.0e5, 1.0e7] {
            let (s, c) = sin_cos_f32(x);
            let spacing = f64::from(x.abs()) * f64::from(f32::EPSILON);
            let (es, ec) = f64::from(x).sin_cos();
            assert!((f64::from(s) - es).abs() <= spacing + 1e-6, "sin {x}");
            assert!((f64::from(c) - ec).abs() <= spacing + 1e-6, "cos {x}");
        }
        for x in [1.0e4f32, -3.0e5, 1.0e7, 1.0e20, -f32::MAX] {
            let (s, c) = sin_cos_f32(x);
            assert!((s * s + c * c - 1.0).abs() < 1e-6, "{x}");
        }
        for x in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
            let (s, c) = sin_cos_f32(x);
            assert!(s.is_nan() && c.is_nan());
        }
    }
}
