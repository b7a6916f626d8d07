//! Unit tests of the estimator's limits, counters and less-travelled paths: the time limits of delayed
//! measurements at their exact bounds, the fix's consistency gate against its variance written out, the
//! position reset after refusals, the floor, the compass's two refusals, the learned thrust axis, the
//! integration of biased samples and long intervals. Each holds a behaviour that the other tests' files
//! reached only through a closed loop (found by mutation testing, docs/mutation-testing.md).
use super::with_distinct_covariance as distinct;
use super::*;
use crate::motion::Block;

const STD1CM: Vec3 = Vec3::new(0.01, 0.01, 0.01);

fn fix(t_us: u64, p: Vec3, yaw: f32, std: Vec3) -> PositionFix {
    PositionFix {
        capture_time_us: t_us,
        position_m: p,
        position_std_m: std,
        x_observed: true,
        yaw_rad: yaw,
        yaw_std_rad: 0.01,
    }
}

/// A filter whose heading and position are already initialised from vision, with one snapshot at 1 s.
fn initialised() -> Estimator {
    let mut e = distinct();
    e.yaw_from_vision = true;
    e.xy_initialised = [true; 2];
    e.push_history(1_000_000);
    e
}

#[test]
fn the_history_reaches_back_its_declared_length() {
    // Fill the ring at 1 kHz: its oldest snapshot is HISTORY_S less one snapshot period before the newest.
    let mut e = Estimator::new(EstimatorParams::default(), Vec3::ZERO);
    let end = 2_000_000u64;
    for t in (2000..=end).step_by(2000) {
        e.push_history(t);
    }
    let span_us = (0..=end).find(|t| e.state_at(*t).is_some()).map(|t| end - t).unwrap();
    let declared = (span_us + SNAPSHOT_EVERY_US) as f32 * 1e-6;
    assert!((HISTORY_S - declared).abs() < 1e-6, "HISTORY_S {HISTORY_S}, the ring spans {declared} s");
    // The parameters may ask for fixes as old as that, not older: the declared bound is the history's.
    let spec = EstimatorParams::SPECS[0].iter().find(|s| s.name.ends_with("max_fix_age_s")).unwrap();
    assert_eq!(spec.range.unwrap().hi, HISTORY_S);
    let ok = EstimatorParams { max_fix_age_s: HISTORY_S, ..EstimatorParams::default() };
    assert!(ok.validate().is_ok());
    let too_old = EstimatorParams { max_fix_age_s: HISTORY_S * 1.01, ..EstimatorParams::default() };
    let err = too_old.validate().unwrap_err();
    assert_eq!(err.field, "estimator.max_fix_age_s");
}

#[test]
fn the_accessors_report_the_state_they_hold() {
    let mut e = distinct();
    assert!(!e.yaw_from_vision(), "a new filter has no heading from vision");
    assert_eq!(e.thrust_axis(), Vec3::Z, "the configured thrust axis");
    e.push_history(1_000_000);
    let yaw = yaw_of(&e);
    e.fuse_fix(&fix(1_000_000, e.p, yaw, STD1CM), 1_000_000);
    assert!(e.yaw_from_vision());
    e.thrust_axis = Vec3::new(0.6, 0.0, 0.8);
    assert_eq!(e.thrust_axis(), Vec3::new(0.6, 0.0, 0.8));
}

#[test]
fn a_measurement_is_fresh_from_its_capture_time_up_to_the_maximum_age_inclusive() {
    let max_age = (EstimatorParams::default().max_fix_age_s * 1e6) as u64;
    let mut e = initialised();
    let f = fix(1_000_000, e.p, yaw_of(&e), STD1CM);
    assert_eq!(e.clone().fuse_fix(&f, 1_000_000), FuseOutcome::Accepted, "received when captured");
    assert_eq!(e.clone().fuse_fix(&f, 1_000_000 + max_age), FuseOutcome::Accepted, "exactly the maximum age");
    assert_eq!(e.fuse_fix(&f, 1_000_000 + max_age + 1), FuseOutcome::Stale);
    let mut e = initialised();
    let past = e.state_at(1_000_000).unwrap();
    let body = past.q.to_mat3().tmul_vec(past.v);
    let m = BodyVelocity { time_us: 1_000_000, velocity_m_s: [body.x, body.y], std_m_s: 0.05 };
    assert_eq!(e.fuse_body_velocity(&m, 1_000_000), FuseOutcome::Accepted, "received when measured");
}

#[test]
fn the_fix_gate_is_the_innovation_against_the_variance_of_position_less_age_times_velocity() {
    // For each axis alone: an innovation just inside the gate is fused, just outside it refused. The variance
    // is that of p - age v (its cross term included) plus the fix's own.
    let age_us = 40_000u64;
    let age = age_us as f64 * 1e-6;
    for axis in 0..3 {
        for (scale, want) in [(0.999, FuseOutcome::Accepted), (1.001, FuseOutcome::Rejected)] {
            let mut e = initialised();
            let (ip, iv) = (IP + axis, IV + axis);
            // A strong position-velocity correlation, so that leaving out or flipping the cross term matters.
            e.cov[ip][iv] = 0.6 * (e.cov[ip][ip] * e.cov[iv][iv]).sqrt();
            e.cov[iv][ip] = e.cov[ip][iv];
            let past = e.state_at(1_000_000).unwrap();
            let std = Vec3::new(0.01, 0.02, 0.03);
            let c = |i: usize, j: usize| e.cov[i][j] as f64;
            let s = c(ip, ip) - 2.0 * age * c(ip, iv) + age * age * c(iv, iv) + (std[axis] as f64).powi(2);
            let g = e.params.gate_sigma as f64;
            let mut p = past.p.to_array();
            p[axis] += (scale * g * s.sqrt()) as f32;
            let p = Vec3::from_array(p);
            let f = PositionFix { yaw_std_rad: 10.0, ..fix(1_000_000, p, yaw_of(&e), std) };
            assert_eq!(e.fuse_fix(&f, 1_000_000 + age_us), want, "axis {axis}, {scale} of the gate");
        }
    }
}

#[test]
fn a_position_reset_takes_the_fix_plus_the_motion_since_and_opens_every_velocity_axis() {
    let mut e = initialised();
    e.v = Vec3::new(0.1, 0.2, -0.1);
    let past = e.state_at(1_000_000).unwrap();
    // The vehicle moved since the frame was taken.
    let moved = Vec3::new(0.03, -0.02, 0.01);
    e.p += moved;
    let far = fix(1_000_000, past.p + Vec3::new(1.5, -1.0, 0.8), yaw_of(&e), STD1CM);
    for _ in 0..e.params.vision_position_reset_after {
        e.fuse_fix(&far, 1_010_000);
    }
    assert_eq!(e.counters().position_resets, 1);
    let sv = e.params.reset_velocity_sigma_m_s;
    for axis in 0..3 {
        let want = far.position_m[axis] + moved[axis];
        assert!((e.p[axis] - want).abs() < 1e-5, "axis {axis}: {} {want}", e.p[axis]);
        assert!((e.cov[IV + axis][IV + axis] - sv * sv).abs() < 1e-6 * sv * sv, "velocity variance {axis}");
        assert!((0..N).filter(|&i| i != IV + axis).all(|i| e.cov[IV + axis][i] == 0.0), "{axis} correlated");
    }
}

#[test]
fn the_floor_lifts_a_height_below_it_alone_and_leaves_one_at_or_above_it() {
    let mut e = distinct();
    e.p.z = 0.02;
    let (v, cov) = (e.v, e.cov);
    assert!(e.constrain_above_floor(0.06));
    assert_eq!(e.counters().floor_constraints, 1);
    assert!((e.p.z - 0.06).abs() < 1e-6, "{}", e.p.z);
    assert_eq!(e.v, v, "the velocity is left to the IMU");
    let s = e.params.ground_height_sigma_m;
    let z = IP + 2;
    assert_eq!(e.cov[z][z], cov[z][z].max(s * s));
    for i in (0..N).filter(|&i| i != z) {
        assert_eq!((e.cov[z][i], e.cov[i][z]), (0.0, 0.0), "{i}");
        assert_eq!(e.cov[i][IV], cov[i][IV], "the rest untouched ({i})");
    }
    // A height exactly at the floor, or above it, is not constrained.
    let before = e.cov;
    assert!(!e.constrain_above_floor(0.06));
    assert!(!e.constrain_above_floor(0.01));
    assert_eq!(e.counters().floor_constraints, 1);
    assert_eq!(e.cov, before);
    // A small variance is raised to the constraint's.
    let mut e = distinct();
    e.p.z = 0.0;
    e.cov[z][z] = 1e-8;
    e.constrain_above_floor(0.06);
    assert!((e.cov[z][z] - s * s).abs() < 1e-9);
}

#[test]
fn the_compass_reads_a_field_pointing_along_world_y() {
    // A levelled field along y has a horizontal part (x^2 + y^2, not x^2 - y^2, is tested against zero).
    let mut e = distinct();
    e.tilt_aligned = true;
    let f = field_reading(&e, core::f32::consts::FRAC_PI_2);
    let m_w = e.q.to_mat3().mul_vec(f);
    assert!(m_w.x * m_w.x < 0.1 * m_w.y * m_w.y, "{m_w:?}");
    assert_eq!(e.fuse_mag(f), FuseOutcome::Initialised);
}

#[test]
fn the_compass_is_refused_for_disagreeing_with_vision_or_for_its_gate_and_each_is_counted() {
    let mut e = distinct();
    e.tilt_aligned = true;
    e.yaw_initialised = true;
    // Vision holds the heading; the yaw is so uncertain that the gate would pass anything: a reading beyond
    // mag_consistency_rad is refused for the disagreement alone.
    e.last_imu_us = Some(5_000_000);
    e.last_vision_yaw_us = Some(5_000_000);
    e.cov[ITH + 2][ITH + 2] = 100.0;
    let raw = e.params.mag_consistency_rad * 1.5;
    let yaw = yaw_of(&e);
    assert_eq!(e.fuse_mag(field_reading(&e, raw)), FuseOutcome::Rejected);
    assert_eq!(e.counters().mag_rejected, 1);
    assert_eq!(yaw_of(&e), yaw);
    // Without vision: a reading far outside a confident yaw's gate is refused by the update and counted.
    let mut e = distinct();
    e.tilt_aligned = true;
    e.yaw_initialised = true;
    e.cov[ITH + 2][ITH + 2] = 1e-6;
    e.params.mag_heading_sigma_rad = 1e-3;
    let yaw = yaw_of(&e);
    for k in 1..=3 {
        assert_eq!(e.fuse_mag(field_reading(&e, 1.0)), FuseOutcome::Rejected);
        assert_eq!(e.counters().mag_rejected, k);
    }
    assert_eq!(e.counters().mag_accepted, 0);
    assert_eq!(yaw_of(&e), yaw);
}

fn block(accel: Vec3, class: MotionClass, window: bool) -> MotionReport {
    MotionReport {
        block: Block { end_us: 50_000, samples: 50, mean_gyro: Vec3::ZERO, mean_accel: accel },
        class,
        still_window: window.then_some((Vec3::ZERO, accel)),
        rest_confirmed: class == MotionClass::Still,
        moving_class: if class == MotionClass::Still { MotionClass::Unknown } else { class },
    }
}

#[test]
fn the_first_still_window_levels_the_force_less_the_accelerometer_bias() {
    let mut e = Estimator::new(EstimatorParams::default(), Vec3::new(1.0, 1.3, 0.06));
    e.ba = Vec3::new(0.3, -0.2, 0.1);
    let att = Attitude::new(0.05, -0.08, 0.0);
    let f = att.world_from_body().tmul_vec(Vec3::new(0.0, 0.0, GRAVITY)) + e.ba;
    e.motion_report = Some(block(f, MotionClass::Still, true));
    e.fuse_accel(&AccelContext { airborne: Some(false), pad_height_m: Some(0.06) });
    let got = Attitude::from_world_from_body(&e.q.to_mat3());
    assert!((got.roll - 0.05).abs() < 2e-3 && (got.pitch + 0.08).abs() < 2e-3, "{got:?}");
}

#[test]
fn a_gravity_block_reports_a_gated_refusal() {
    let mut e = distinct();
    for k in ITH..ITH + 3 {
        for i in 0..N {
            e.cov[k][i] = 0.0;
            e.cov[i][k] = 0.0;
        }
        e.cov[k][k] = 1e-8;
    }
    // The right magnitude, 40 degrees off the predicted vertical: both directions outside a confident gate.
    let g_b = e.q.to_mat3().tmul_vec(Vec3::new(0.0, 0.0, GRAVITY));
    let turned = Quat::from_rotvec(Vec3::new(0.7, 0.0, 0.0)).to_mat3().mul_vec(g_b);
    assert!(e.clone().fuse_gravity(g_b, 0.05, true));
    assert!(!e.fuse_gravity(turned, 0.05, true));
}

#[test]
fn a_learned_thrust_axis_is_the_mean_force_of_the_first_blocks_then_follows_it() {
    let p = EstimatorParams { thrust_axis_learn_s: 0.2, ..EstimatorParams::default() };
    let mut e = Estimator::new(p, Vec3::new(1.0, 1.3, 0.8));
    let ctx = AccelContext { airborne: Some(true), pad_height_m: None };
    let u1 = Vec3::new(0.1, -0.05, 1.0).normalized().unwrap();
    e.motion_report = Some(block(u1 * 9.7, MotionClass::ThrustBorne, false));
    e.fuse_accel(&ctx);
    assert!((e.thrust_axis() - u1).norm() < 1e-6, "{:?}", e.thrust_axis());
    // The first blocks are averaged alike (one block's vibration and accelerations would set the axis
    // wrong by degrees), until the learning time's share of a block is the larger.
    let u2 = Vec3::new(-0.1, 0.08, 1.0).normalized().unwrap();
    e.motion_report = Some(block(u2 * 9.7, MotionClass::ThrustBorne, false));
    e.fuse_accel(&ctx);
    let want = (u1 + (u2 - u1) * 0.5).normalized().unwrap();
    assert!((e.thrust_axis() - want).norm() < 1e-6, "{:?} {want:?}", e.thrust_axis());
    let mut axis = want;
    for n in 3..=6 {
        e.motion_report = Some(block(u1 * 9.7, MotionClass::ThrustBorne, false));
        e.fuse_accel(&ctx);
        // block_s / learn_s = 0.25: 1/3 then 0.25 from the fourth block on.
        let a = (1.0 / n as f32).max(p.motion.block_s / p.thrust_axis_learn_s);
        axis = (axis + (u1 - axis) * a).normalized().unwrap();
        assert!((e.thrust_axis() - axis).norm() < 1e-6, "block {n}: {:?} {axis:?}", e.thrust_axis());
    }
    // Not learning (the default): the configured axis stays.
    let mut e = Estimator::new(EstimatorParams::default(), Vec3::new(1.0, 1.3, 0.8));
    e.motion_report = Some(block(u2 * 9.7, MotionClass::ThrustBorne, false));
    e.fuse_accel(&ctx);
    assert_eq!(e.thrust_axis(), Vec3::Z);
}

#[test]
fn a_still_stretch_too_short_for_a_rest_keeps_the_model_of_the_motion_before_it() {
    // A flying vehicle's IMU can look still for a moment (a glide at steady velocity): when the flight code
    // cannot tell whether it flies, only a confirmed rest gets the ground constraint; until then the model
    // of the class before applies. Known to be on the ground, still is still at once.
    let unknown = AccelContext { airborne: None, pad_height_m: Some(0.06) };
    let ground = AccelContext { airborne: Some(false), pad_height_m: Some(0.06) };
    let g = Vec3::new(0.0, 0.0, GRAVITY);
    let still = |moving_class, rest_confirmed| MotionReport {
        moving_class,
        rest_confirmed,
        ..block(g, MotionClass::Still, true)
    };
    for (report, ctx, want) in [
        (still(MotionClass::ThrustBorne, false), unknown, AccelAiding::Drag),
        (still(MotionClass::Unknown, false), unknown, AccelAiding::Gravity),
        (still(MotionClass::GravityDominated, false), unknown, AccelAiding::Gravity),
        (still(MotionClass::ThrustBorne, true), unknown, AccelAiding::Still),
        (still(MotionClass::ThrustBorne, false), ground, AccelAiding::Still),
        // On the ground and moving (carried to the pad): gravity, not a rest.
        (block(g, MotionClass::GravityDominated, false), ground, AccelAiding::Gravity),
    ] {
        let mut e = Estimator::new(EstimatorParams::default(), Vec3::new(1.0, 1.3, 0.06));
        e.v = Vec3::new(0.5, 0.0, 0.0);
        e.motion_report = Some(report);
        assert_eq!(e.fuse_accel(&ctx), Some(want), "{report:?} {ctx:?}");
        // Only a rest stops the vehicle and counts a still block.
        let rest = want == AccelAiding::Still;
        assert_eq!(e.counters().still_blocks, rest as u32);
        assert_eq!(e.v.x < 0.1, rest, "{:?}", e.v);
    }
}

#[test]
fn a_drag_block_outside_its_gate_is_counted_as_refused() {
    let mut e = distinct();
    e.v = Vec3::new(0.2, 0.1, 0.0);
    // Confident and uncorrelated (positive definite).
    e.cov = core::array::from_fn(|i| core::array::from_fn(|j| if i == j { 1e-8 } else { 0.0 }));
    let ctx = AccelContext { airborne: Some(true), pad_height_m: None };
    // 3 m/s^2 across the thrust axis: no drag of a 0.2 m/s velocity comes near.
    e.motion_report = Some(block(Vec3::new(3.0, 0.0, 9.3), MotionClass::ThrustBorne, false));
    assert_eq!(e.fuse_accel(&ctx), Some(AccelAiding::Drag));
    assert_eq!((e.counters().accel_rejected, e.counters().drag_blocks), (1, 0));
    e.motion_report = Some(block(Vec3::new(3.0, 0.0, 9.3), MotionClass::ThrustBorne, false));
    e.fuse_accel(&ctx);
    assert_eq!(e.counters().accel_rejected, 2);
}

#[test]
fn samples_are_integrated_less_their_biases_from_the_first_one_on() {
    // Level and still, with known gyro and accelerometer biases along z (a z force aligns level): the
    // readings are the biases plus gravity, and nothing moves.
    let mut e = Estimator::new(EstimatorParams::default(), Vec3::ZERO);
    e.bg = Vec3::new(0.0, 0.0, 0.2);
    e.ba = Vec3::new(0.0, 0.0, 0.4);
    let (yaw0, p0) = (yaw_of(&e), e.p);
    for k in 1..=20u64 {
        e.integrate(&ImuSample {
            time_us: k * 1000,
            gyro_rad_s: [0.0, 0.0, 0.2],
            accel_m_s2: [0.0, 0.0, GRAVITY + 0.4],
        });
    }
    assert!(e.v.norm() < 1e-6, "{:?}", e.v);
    assert!((e.p - p0).norm() < 1e-8, "{:?}", e.p);
    assert!(wrap_pi(yaw_of(&e) - yaw0).abs() < 1e-6);
    // And a horizontal bias, once level: removed from every later sample.
    e.ba = Vec3::new(0.3, -0.1, 0.4);
    for k in 21..=40u64 {
        e.integrate(&ImuSample {
            time_us: k * 1000,
            gyro_rad_s: [0.0, 0.0, 0.2],
            accel_m_s2: [0.3, -0.1, GRAVITY + 0.4],
        });
    }
    assert!(e.v.norm() < 1e-5, "{:?}", e.v);
}

#[test]
fn a_constant_acceleration_moves_the_position_by_half_a_t_squared() {
    let mut e = Estimator::new(EstimatorParams::default(), Vec3::ZERO);
    let a = [1.5, 0.0, GRAVITY];
    for k in 0..=500u64 {
        e.integrate(&ImuSample { time_us: k * 1000, gyro_rad_s: [0.0; 3], accel_m_s2: a });
    }
    // Level (the first sample's force has a forward part: the alignment reads it as a small pitch; undo it
    // by reading the position along the vehicle's own axes is not needed: compare with the state's own tilt).
    let r = e.q.to_mat3();
    let a_w = r.mul_vec(Vec3::from_array(a)) - Vec3::new(0.0, 0.0, GRAVITY);
    let t = 0.5f32;
    let want = a_w * (0.5 * t * t);
    assert!((e.p - want).norm() < 2e-5, "{:?} {want:?}", e.p);
    assert!((e.v - a_w * t).norm() < 2e-5, "{:?}", e.v);
}

/// Yaw turning at `w` about world z with body force `f` (level), over `t` s from yaw 0 and rest: the velocity
/// the estimator's sub-stepped trapezoid gives with `steps` sub-steps (f64).
fn yaw_turn_velocity(w: f64, f: [f64; 2], t: f64, steps: u32) -> [f64; 2] {
    let dt = t / steps as f64;
    let rot = |psi: f64| [psi.cos() * f[0] - psi.sin() * f[1], psi.sin() * f[0] + psi.cos() * f[1]];
    let mut v = [0.0; 2];
    for k in 0..steps {
        let (a0, a1) = (rot(w * dt * k as f64), rot(w * dt * (k + 1) as f64));
        for i in 0..2 {
            v[i] += 0.5 * (a0[i] + a1[i]) * dt;
        }
    }
    v
}

#[test]
fn a_long_interval_is_integrated_in_sub_steps_of_at_most_20_ms() {
    // 90 ms between two samples while turning at 6 rad/s with a forward force: 5 sub-steps, whose result
    // differs clearly from one trapezoid over the whole interval.
    let (w, f, gap_us) = (6.0f32, [2.0f32, 0.0], 90_000u64);
    let mut e = Estimator::new(EstimatorParams::default(), Vec3::ZERO);
    e.tilt_aligned = true;
    e.last_imu_us = Some(0);
    e.last_omega = Vec3::new(0.0, 0.0, w);
    e.last_accel = Vec3::new(f[0], f[1], GRAVITY);
    let r0 = e.q.to_mat3();
    e.integrate(&ImuSample { time_us: gap_us, gyro_rad_s: [0.0, 0.0, w], accel_m_s2: [f[0], f[1], GRAVITY] });
    let t = gap_us as f64 * 1e-6;
    let steps = (t / MAX_PREDICT_STEP_S as f64).ceil() as u32;
    assert_eq!(steps, 5);
    let fd = [f[0] as f64, f[1] as f64];
    // The oracle turns in the starting body frame (level: its z is world z); the filter's starting attitude
    // takes it to the world.
    let rotate = |v: [f64; 2]| {
        let w = r0.mul_vec(Vec3::new(v[0] as f32, v[1] as f32, 0.0));
        [w.x as f64, w.y as f64]
    };
    let want = rotate(yaw_turn_velocity(w as f64, fd, t, steps));
    let one = rotate(yaw_turn_velocity(w as f64, fd, t, 1));
    let err = ((e.v.x as f64 - want[0]).powi(2) + (e.v.y as f64 - want[1]).powi(2)).sqrt();
    let apart = ((one[0] - want[0]).powi(2) + (one[1] - want[1]).powi(2)).sqrt();
    assert!(apart > 1e-4, "the test tells the schedules apart: {apart}");
    assert!(err < apart / 20.0, "velocity {:?}, sub-stepped {want:?}, one step {one:?}", e.v);
}

#[test]
fn an_interval_of_exactly_the_longest_gap_is_still_integrated() {
    let mut e = Estimator::new(EstimatorParams::default(), Vec3::ZERO);
    let gap_us = 80_000u64;
    e.params.max_imu_gap_s = gap_us as f32 * 1e-6;
    let g = [0.0, 0.0, 0.5];
    let a = [0.0, 0.0, GRAVITY];
    e.integrate(&ImuSample { time_us: 1000, gyro_rad_s: g, accel_m_s2: a });
    let yaw0 = yaw_of(&e);
    e.integrate(&ImuSample { time_us: 1000 + gap_us, gyro_rad_s: g, accel_m_s2: a });
    assert_eq!(e.counters().imu_gaps, 0);
    assert!((wrap_pi(yaw_of(&e) - yaw0) - 0.04).abs() < 1e-5);
    e.integrate(&ImuSample { time_us: 1001 + 2 * gap_us, gyro_rad_s: g, accel_m_s2: a });
    assert_eq!(e.counters().imu_gaps, 1, "a microsecond longer is a gap");
}
