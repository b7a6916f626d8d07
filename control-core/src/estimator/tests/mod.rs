//! Unit tests of the estimator, by topic. The helpers here are shared by the topics' files.
use super::*;
use crate::motion::MotionClass;

mod behaviour;
mod edge;
mod fixes;
mod state;
mod updates;

pub(super) fn level_imu(t_us: u64) -> ImuSample {
    ImuSample { time_us: t_us, gyro_rad_s: [0.0; 3], accel_m_s2: [0.0, 0.0, GRAVITY] }
}

/// Feeds `secs` of 1 kHz samples from `f(t) -> (gyro, accel)` with a 2 ms covariance step and the
/// accelerometer's aiding, as the control core does.
pub(super) fn run(
    e: &mut Estimator,
    t0: u64,
    secs: f32,
    ctx: AccelContext,
    f: impl Fn(f32) -> (Vec3, Vec3),
) -> u64 {
    let n = (secs * 1000.0) as u64;
    let mut t = t0;
    for _ in 0..n {
        t += 1000;
        let (g, a) = f(t as f32 * 1e-6);
        e.predict(&ImuSample { time_us: t, gyro_rad_s: g.to_array(), accel_m_s2: a.to_array() });
        if t.is_multiple_of(2000) {
            e.propagate_covariance(t);
            e.fuse_accel(&ctx);
        }
    }
    t
}

pub(super) const ON_PAD: AccelContext = AccelContext { airborne: None, pad_height_m: Some(0.06) };

pub(super) fn hover_fix(cap: u64, p: Vec3) -> PositionFix {
    PositionFix {
        capture_time_us: cap,
        position_m: p,
        position_std_m: Vec3::new(0.005, 0.005, 0.005),
        x_observed: true,
        yaw_rad: 0.0,
        yaw_std_rad: 0.002,
    }
}

/// A filter hovering at `p` with fixes, up to 2 s.
pub(super) fn hovering_filter(p: Vec3) -> (Estimator, u64) {
    let mut e = Estimator::new(EstimatorParams::default(), p);
    let mut t = 0;
    for k in 1..=2000u64 {
        t = k * 1000;
        e.predict(&level_imu(t));
        if k % 2 == 0 {
            e.propagate_covariance(t);
        }
        if k % 33 == 0 && t > 100_000 {
            e.fuse_fix(&hover_fix(t - 40_000, p), t);
        }
    }
    (e, t)
}

/// A filter with a covariance whose every entry differs (symmetric, positive diagonal), so that reading a
/// wrong entry or combining them wrongly shows.
pub(super) fn with_distinct_covariance() -> Estimator {
    let mut e = Estimator::new(EstimatorParams::default(), Vec3::new(1.0, 1.3, 0.8));
    for i in 0..N {
        for j in 0..N {
            e.cov[i][j] = if i == j { 0.01 * (i + 1) as f32 } else { 1e-4 * ((i * 7 + j * 7) % 11) as f32 };
        }
    }
    e.q = Quat::from_mat3(&Attitude::new(0.2, -0.3, 0.7).world_from_body());
    e
}

pub(super) fn yaw_of(e: &Estimator) -> f32 {
    Attitude::from_world_from_body(&e.q.to_mat3()).yaw
}

/// The body-frame field that reads as compass heading error `raw` (`atan2` of the world field less that of
/// the levelled reading) at the filter's attitude.
pub(super) fn field_reading(e: &Estimator, raw: f32) -> Vec3 {
    let b = Vec3::from_array(e.params.mag_field_world);
    let m_w = Mat3::rot_z(-raw).mul_vec(b);
    e.q.to_mat3().tmul_vec(m_w)
}

/// The state correction an update injected, read back from the filter (position, velocity and attitude
/// through the cumulative corrections, the rest from the states).
pub(super) fn injected(before: &Estimator, after: &Estimator) -> [f32; N] {
    let mut dx = [0.0; N];
    let d = |a: Vec3, b: Vec3| b - a;
    let parts = [
        (IP, d(before.corr.p, after.corr.p)),
        (IV, d(before.corr.v, after.corr.v)),
        (ITH, d(before.corr.th, after.corr.th)),
        (IBG, d(before.bg, after.bg)),
        (IBA, d(before.ba, after.ba)),
    ];
    for (start, v) in parts {
        dx[start..start + 3].copy_from_slice(&v.to_array());
    }
    dx[IW] = after.w.x - before.w.x;
    dx[IW + 1] = after.w.y - before.w.y;
    dx
}

/// Asserts that the correction the update injected (from `before` to `after`) is `want`, each component within
/// `rel` of its size (or of `floor`, for the small ones).
pub(super) fn assert_injected(before: &Estimator, after: &Estimator, want: &[f64; N], rel: f64, floor: f64) {
    let dx = injected(before, after);
    for i in 0..N {
        assert!(
            (dx[i] as f64 - want[i]).abs() < rel * want[i].abs().max(floor),
            "dx[{i}] {} {}",
            dx[i],
            want[i]
        );
    }
}

/// One scalar update by hand (f64): returns the correction and updates `p`.
pub(super) fn kalman_by_hand(p: &mut [[f64; N]; N], h: &[f64; N], innov: f64, var: f64) -> [f64; N] {
    let ph: [f64; N] = core::array::from_fn(|i| (0..N).map(|k| p[i][k] * h[k]).sum());
    let s = var + (0..N).map(|k| h[k] * ph[k]).sum::<f64>();
    for i in 0..N {
        for j in 0..N {
            p[i][j] -= ph[i] * ph[j] / s;
        }
    }
    core::array::from_fn(|i| ph[i] / s * innov)
}

pub(super) fn fix_at(t_us: u64, p: Vec3, yaw: f32) -> PositionFix {
    PositionFix {
        capture_time_us: t_us,
        position_m: p,
        position_std_m: Vec3::new(0.01, 0.002, 0.003),
        x_observed: true,
        yaw_rad: yaw,
        yaw_std_rad: 0.0001,
    }
}

pub(super) fn still_report(gyro: Vec3, accel: Vec3, window: bool) -> MotionReport {
    MotionReport {
        block: crate::motion::Block { end_us: 50_000, samples: 50, mean_gyro: gyro, mean_accel: accel },
        class: MotionClass::Still,
        still_window: window.then_some((gyro, accel)),
        // A rest that has lasted (see `MotionParams::still_confirm_s`).
        rest_confirmed: true,
        moving_class: MotionClass::Unknown,
    }
}

/// [`kalman_by_hand`] with the states in `consider` taken into account but not corrected (their gain zero,
/// their own covariance block unchanged).
pub(super) fn kalman_considering(
    p: &mut [[f64; N]; N],
    h: &[f64; N],
    innov: f64,
    var: f64,
    consider: core::ops::Range<usize>,
) -> [f64; N] {
    let ph: [f64; N] = core::array::from_fn(|i| (0..N).map(|k| p[i][k] * h[k]).sum());
    let s = var + (0..N).map(|k| h[k] * ph[k]).sum::<f64>();
    for i in 0..N {
        for j in 0..N {
            if !(consider.contains(&i) && consider.contains(&j)) {
                p[i][j] -= ph[i] * ph[j] / s;
            }
        }
    }
    core::array::from_fn(|i| if consider.contains(&i) { 0.0 } else { ph[i] / s * innov })
}
