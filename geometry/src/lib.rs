//! Small, deterministic f32 geometry for the flight crates.
//!
//! Every transcendental function goes through [`libm`] or [`trig`] (sine and cosine in f32 only), so the host
//! (simulation, replay) and the Cortex-M4F firmware compute the same bits for the same inputs. Nothing here
//! allocates.
//!
//! - [`Vec2`], [`Vec3`]: plain vectors with the usual operators.
//! - [`Mat3`]: row-major 3x3 matrices, rotations, Euler angles (ZYX), polar re-orthonormalisation.
//! - [`Quat`]: unit quaternions (Hamilton, `w` first) for attitude integration.
//! - [`frames`]: the project's fixed frame conventions (world, wall-facing navigation frame, body, camera).
//! - [`solve`]: symmetric positive-definite solves and a 2x2 symmetric eigen decomposition.
#![cfg_attr(not(test), no_std)]
#![forbid(unsafe_code)]
#![warn(missing_docs)]
#![cfg_attr(not(test), deny(clippy::unwrap_used, clippy::expect_used, clippy::panic))]
// Index loops read naturally in small dense linear algebra; `!(x > 0.0)` deliberately rejects NaN.
#![allow(clippy::needless_range_loop, clippy::neg_cmp_op_on_partial_ord)]

pub mod frames;
mod mat;
mod quat;
pub mod solve;
pub mod trig;
mod vec;

pub use mat::Mat3;
pub use quat::Quat;
pub use vec::{Vec2, Vec3};

/// Wraps an angle to (-pi, pi].
pub fn wrap_pi(a: f32) -> f32 {
    let two_pi = 2.0 * core::f32::consts::PI;
    let mut r = libm::remainderf(a, two_pi);
    if r <= -core::f32::consts::PI {
        r += two_pi;
    }
    r
}

/// Clamps `x` to `[lo, hi]`; a NaN input returns `lo` so that downstream math never sees NaN.
pub fn clamp_finite(x: f32, lo: f32, hi: f32) -> f32 {
    if x.is_nan() || x < lo {
        lo
    } else if x > hi {
        hi
    } else {
        x
    }
}

/// Degrees to radians.
pub fn deg(x: f32) -> f32 {
    x * (core::f32::consts::PI / 180.0)
}

/// Radians to degrees.
pub fn to_deg(x: f32) -> f32 {
    x * (180.0 / core::f32::consts::PI)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wrap_pi_range() {
        for i in -20..20 {
            let a = i as f32 * 0.9;
            let w = wrap_pi(a);
            assert!(w > -core::f32::consts::PI - 1e-6 && w <= core::f32::consts::PI + 1e-6);
            assert!((libm::sinf(w) - libm::sinf(a)).abs() < 1e-5);
            assert!((libm::cosf(w) - libm::cosf(a)).abs() < 1e-5);
        }
    }

    #[test]
    fn clamp_nan_is_low() {
        assert_eq!(clamp_finite(f32::NAN, -1.0, 1.0), -1.0);
        assert_eq!(clamp_finite(3.0, -1.0, 1.0), 1.0);
    }
}
