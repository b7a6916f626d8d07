//! Sine and cosine in f32 arithmetic only.
//!
//! `libm`'s `sinf` and `cosf` (after musl) evaluate their polynomials in f64, which the Cortex-M4F does in
//! software: about 3 k instructions a call, where these take about 40. The flight code calls them in every
//! attitude update and every step of the pose solver, so they alone made a pose solve cost half a million
//! instructions. Both host and firmware use these, so they still compute the same bits.
//!
//! Method: Cody-Waite reduction by pi/2 (pi/2 split into three parts whose products with the quadrant number
//! are exact), then minimax polynomials on [-pi/4, pi/4] (the coefficients of Cephes' single-precision `sinf`
//! and `cosf`, S. L. Moshier). Absolute error below 2.5e-7 for |x| <= 1000 (tested against f64); larger
//! arguments fall back to `libm`.

/// pi/2 in three parts: `PIO2_1` has 8 significant bits and `PIO2_2` 16, so `k * PIO2_1` and `k * PIO2_2`
/// are exact for the quadrant numbers of |x| <= 1000.
const PIO2_1: f32 = 1.570_312_5;
const PIO2_2: f32 = 4.837_513e-4;
const PIO2_3: f32 = 7.549_79e-8;
const FAST_LIMIT: f32 = 1000.0;

/// Sine and cosine of `r` in [-pi/4, pi/4].
#[inline]
fn kernel(r: f32) -> (f32, f32) {
    let z = r * r;
    let s = ((-1.951_529_6e-4 * z + 8.332_161e-3) * z - 1.666_665_5e-1) * z * r + r;
    let c = ((2.443_315_7e-5 * z - 1.388_731_6e-3) * z + 4.166_664_6e-2) * z * z - 0.5 * z + 1.0;
    (s, c)
}

/// `(sin x, cos x)`.
pub fn sin_cos(x: f32) -> (f32, f32) {
    if !(x.abs() <= FAST_LIMIT) {
        return (libm::sinf(x), libm::cosf(x));
    }
    // Nearest quadrant; |k| <= 637.
    let kf = x * core::f32::consts::FRAC_2_PI;
    let k = if kf >= 0.0 { (kf + 0.5) as i32 } else { (kf - 0.5) as i32 };
    let kf = k as f32;
    let r = ((x - kf * PIO2_1) - kf * PIO2_2) - kf * PIO2_3;
    let (s, c) = kernel(r);
    match k & 3 {
        0 => (s, c),
        1 => (c, -s),
        2 => (-s, -c),
        _ => (-c, s),
    }
}

/// `sin x`.
pub fn sin(x: f32) -> f32 {
    sin_cos(x).0
}

/// `cos x`.
pub fn cos(x: f32) -> f32 {
    sin_cos(x).1
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matches_f64_over_the_fast_range() {
        let mut worst = 0.0f64;
        let n = 400_000;
        for i in 0..=n {
            // Dense near zero, where the flight code lives, and out to the limit.
            let u = i as f64 / n as f64 * 2.0 - 1.0;
            let x = (u * u * u * FAST_LIMIT as f64) as f32;
            let (s, c) = sin_cos(x);
            let xd = x as f64;
            worst = worst.max((s as f64 - xd.sin()).abs()).max((c as f64 - xd.cos()).abs());
        }
        assert!(worst < 2.5e-7, "worst absolute error {worst:e}");
        // Exact where it matters.
        assert_eq!(sin_cos(0.0), (0.0, 1.0));
        // Small angles keep their relative precision.
        for &x in &[1e-3f32, 1e-6, 1e-20, -3e-5] {
            assert!(((sin(x) as f64 - (x as f64).sin()) / (x as f64)).abs() < 1e-7, "{x}");
        }
    }

    #[test]
    fn beyond_the_fast_range_and_non_finite() {
        for &x in &[1000.5f32, -2.0e4, 1.0e7] {
            assert_eq!(sin_cos(x), (libm::sinf(x), libm::cosf(x)));
        }
        assert!(sin(f32::NAN).is_nan() && cos(f32::INFINITY).is_nan());
    }
}
