//! Unit tests of the estimator.
use super::*;
use crate::motion::MotionClass;

fn level_imu(t_us: u64) -> ImuSample {
    ImuSample { time_us: t_us, gyro_rad_s: [0.0; 3], accel_m_s2: [0.0, 0.0, GRAVITY] }
}

#[test]
fn stationary_imu_keeps_the_state() {
    let mut e = Estimator::new(EstimatorParams::default(), Vec3::new(1.0, 1.3, 0.06));
    for k in 0..1000u64 {
        e.predict(&level_imu(k * 1000));
        if k % 2 == 1 {
            e.propagate_covariance(k * 1000);
        }
    }
    let s = e.estimate(999_000);
    assert!((s.position_m - Vec3::new(1.0, 1.3, 0.06)).norm() < 1e-5);
    assert!(s.velocity_m_s.norm() < 1e-5);
    // Uncertainty grows without measurements.
    assert!(s.velocity_std_m_s.x > 0.05);
}

#[test]
fn delayed_fixes_correct_a_drifting_state() {
    // The vehicle hovers at (1, 1.3, 0.8); the accelerometer has a 0.05 m/s^2 bias along body x (forward,
    // i.e. toward -y world when facing the wall). Fixes arrive 50 ms late at 30 Hz.
    let truth = Vec3::new(1.0, 1.3, 0.8);
    let mut e = Estimator::new(EstimatorParams::default(), Vec3::new(0.8, 1.2, 0.8));
    let mut t = 0u64;
    let mut next_frame = 0u64;
    let mut queue: Vec<(u64, u64)> = Vec::new();
    for _ in 0..20_000 {
        t += 1000;
        let s = ImuSample { time_us: t, gyro_rad_s: [0.0; 3], accel_m_s2: [0.05, 0.0, GRAVITY] };
        e.predict(&s);
        if t.is_multiple_of(2000) {
            e.propagate_covariance(t);
        }
        if t >= next_frame {
            queue.push((t, t + 50_000));
            next_frame += 33_333;
        }
        while let Some(&(cap, due)) = queue.first() {
            if due > t {
                break;
            }
            queue.remove(0);
            let fix = PositionFix {
                capture_time_us: cap,
                position_m: truth,
                position_std_m: Vec3::new(0.005, 0.005, 0.005),
                x_observed: true,
                yaw_rad: 0.0,
                yaw_std_rad: 0.002,
            };
            e.fuse_fix(&fix, t);
        }
    }
    let s = e.estimate(t);
    assert!((s.position_m - truth).norm() < 0.005, "{:?}", s.position_m);
    assert!(s.velocity_m_s.norm() < 0.01, "{:?}", s.velocity_m_s);
    assert!(e.yaw_initialised());
    let c = e.counters();
    assert!(c.fixes_accepted > 500 && c.fixes_rejected < 5, "{c:?}");
}

#[test]
fn stale_and_invalid_fixes_are_refused() {
    let mut e = Estimator::new(EstimatorParams::default(), Vec3::ZERO);
    for k in 1..=500u64 {
        e.predict(&level_imu(k * 1000));
        e.propagate_covariance(k * 1000);
    }
    let mut fix = PositionFix {
        capture_time_us: 100_000,
        position_m: Vec3::ZERO,
        position_std_m: Vec3::new(0.01, 0.01, 0.01),
        x_observed: true,
        yaw_rad: 0.0,
        yaw_std_rad: 0.01,
    };
    assert_eq!(e.fuse_fix(&fix, 500_000), FuseOutcome::Stale);
    fix.capture_time_us = 600_000;
    assert_eq!(e.fuse_fix(&fix, 500_000), FuseOutcome::Stale);
    fix.capture_time_us = 480_000;
    fix.position_m.x = f32::NAN;
    assert_eq!(e.fuse_fix(&fix, 500_000), FuseOutcome::Invalid);
    let bad = ImuSample { time_us: 501_000, gyro_rad_s: [f32::NAN, 0.0, 0.0], accel_m_s2: [0.0; 3] };
    assert!(!e.predict(&bad));
    assert!(e.is_healthy());
}

/// Feeds `secs` of 1 kHz samples from `f(t) -> (gyro, accel)` with a 2 ms covariance step and the
/// accelerometer's aiding, as the control core does.
fn run(e: &mut Estimator, t0: u64, secs: f32, ctx: AccelContext, f: impl Fn(f32) -> (Vec3, Vec3)) -> u64 {
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

const ON_PAD: AccelContext = AccelContext { airborne: None, pad_height_m: Some(0.06) };

#[test]
fn ground_alignment_finds_the_tilt() {
    // Resting with 3 degrees of roll: the accelerometer sees gravity tilted.
    let roll = 3f32.to_radians();
    let f = Vec3::new(0.0, GRAVITY * roll.sin(), GRAVITY * roll.cos());
    let mut e = Estimator::new(EstimatorParams::default(), Vec3::new(0.0, 1.3, 0.06));
    run(&mut e, 0, 1.0, ON_PAD, |_| (Vec3::ZERO, f));
    assert_eq!(e.motion_class(), MotionClass::Still);
    let s = e.estimate(1_000_000);
    // Roll and accelerometer bias share the offset; their sum must explain it.
    let explained = s.attitude.roll * GRAVITY + s.accel_bias_m_s2.y;
    assert!((explained - GRAVITY * roll.sin()).abs() < 0.02, "{explained}");
    assert!((s.attitude.roll - roll).abs() < 0.6f32.to_radians(), "{}", s.attitude.roll.to_degrees());
    assert!(e.counters().still_blocks > 5);
}

#[test]
fn initial_alignment_from_a_tilted_start() {
    // Resting tilted by 12 deg roll and -20 deg pitch, with a gyro bias: after one second the tilt is within
    // 0.5 deg and the gyro bias is found from the still window.
    let truth = Attitude::new(12f32.to_radians(), -20f32.to_radians(), 0.0);
    let f = truth.world_from_body().tmul_vec(Vec3::new(0.0, 0.0, GRAVITY));
    let bias = Vec3::new(0.02, -0.03, 0.05);
    let mut e = Estimator::new(EstimatorParams::default(), Vec3::new(0.0, 1.3, 0.06));
    run(&mut e, 0, 1.0, ON_PAD, |_| (bias, f));
    let s = e.estimate(1_000_000);
    let (dr, dp) = ((s.attitude.roll - truth.roll).abs(), (s.attitude.pitch - truth.pitch).abs());
    assert!(dr.to_degrees() < 0.5 && dp.to_degrees() < 0.5, "roll {dr} pitch {dp}");
    assert!((s.gyro_bias_rad_s - bias).norm() < 0.005, "{:?}", s.gyro_bias_rad_s);
    // The first block (50 ms) alone already gives the tilt (no start from level).
    let mut e = Estimator::new(EstimatorParams::default(), Vec3::ZERO);
    for k in 1..=51u64 {
        e.predict(&ImuSample { time_us: k * 1000, gyro_rad_s: [0.0; 3], accel_m_s2: f.to_array() });
    }
    let s = e.estimate(51_000);
    assert!((s.attitude.pitch - truth.pitch).abs() < 1e-4 && (s.attitude.roll - truth.roll).abs() < 1e-4);
}

#[test]
fn handling_is_not_taken_for_rest() {
    // Rocked by hand (8 deg at 1 Hz in roll) after a still second: no zero-velocity or gyro-bias update
    // while it moves, so the bias found at rest survives and the tilt follows the gyro.
    let bias = Vec3::new(0.01, 0.0, 0.0);
    let mut e = Estimator::new(EstimatorParams::default(), Vec3::new(0.0, 1.3, 0.06));
    let t = run(&mut e, 0, 1.0, ON_PAD, |_| (bias, Vec3::new(0.0, 0.0, GRAVITY)));
    let still = e.counters().still_blocks;
    let amp = 8f32.to_radians();
    let w = core::f32::consts::TAU;
    let t1 = t as f32 * 1e-6;
    let att = |t: f32| Attitude::new(amp * libm::sinf(w * (t - t1)), 0.0, 0.0);
    let t = run(&mut e, t, 3.0, ON_PAD, |t| {
        let g = Vec3::new(amp * w * libm::cosf(w * (t - t1)), 0.0, 0.0) + bias;
        (g, att(t).world_from_body().tmul_vec(Vec3::new(0.0, 0.0, GRAVITY)))
    });
    assert_eq!(e.motion_class(), MotionClass::GravityDominated);
    assert!(e.counters().still_blocks <= still + 8, "{} -> {}", still, e.counters().still_blocks);
    let s = e.estimate(t);
    let truth = att(t as f32 * 1e-6);
    assert!(
        (s.attitude.roll - truth.roll).abs() < 0.5f32.to_radians(),
        "{} vs {}",
        s.attitude.roll,
        truth.roll
    );
    assert!((s.gyro_bias_rad_s - bias).norm() < 0.003, "{:?}", s.gyro_bias_rad_s);
}

#[test]
fn gaps_are_integrated_in_sub_steps_and_long_ones_counted() {
    // A steady 0.5 rad/s yaw rotation sampled with a 60 ms gap: the rotation across the gap is kept.
    let rate = 0.5;
    let mut e = Estimator::new(EstimatorParams::default(), Vec3::ZERO);
    let yaw0 = e.estimate(0).attitude.yaw;
    let g = [0.0, 0.0, rate];
    let a = [0.0, 0.0, GRAVITY];
    // (The state runs one sample behind the newest, see `predict`: after 64 ms it is at 63 ms.)
    for t in [1000u64, 2000, 62_000, 63_000, 64_000] {
        e.predict(&ImuSample { time_us: t, gyro_rad_s: g, accel_m_s2: a });
    }
    let turned = e.estimate(63_000).attitude.yaw - yaw0;
    assert!((turned - rate * 0.062).abs() < 1e-4, "turned {turned}");
    assert_eq!(e.counters().imu_gaps, 0);
    // A gap beyond max_imu_gap_s is counted and not integrated.
    e.predict(&ImuSample { time_us: 64_000 + 1_000_000, gyro_rad_s: g, accel_m_s2: a });
    let before = e.estimate(64_000).attitude.yaw;
    e.predict(&ImuSample { time_us: 65_000 + 1_000_000, gyro_rad_s: g, accel_m_s2: a });
    assert_eq!(e.counters().imu_gaps, 1);
    assert!((e.estimate(0).attitude.yaw - before).abs() < 1e-6);
    // The covariance grows over the gap.
    let sd = e.estimate(0).velocity_std_m_s.x;
    e.propagate_covariance(1_063_000);
    assert!(e.estimate(0).velocity_std_m_s.x > sd + 0.05);
}

#[test]
fn the_drag_model_corrects_a_tilt_error_in_flight() {
    // Hovering level in still air with a 3 deg roll error in the estimate: the accelerometer reads the
    // thrust along body z and no drag. With the drag model the estimate returns to level; the gravity model
    // would be right here too, but not while accelerating (below).
    let params = EstimatorParams::default();
    let mut e = Estimator::new(params, Vec3::new(1.0, 1.3, 0.8));
    // (The first block aligns the tilt; the error is set after it.)
    e.tilt_aligned = true;
    e.q = Quat::from_mat3(&Attitude::new(3f32.to_radians(), 0.0, 0.0).world_from_body());
    let fly = AccelContext { airborne: Some(true), pad_height_m: None };
    let t = run(&mut e, 0, 20.0, fly, |_| (Vec3::ZERO, Vec3::new(0.0, 0.0, GRAVITY)));
    let s = e.estimate(t);
    assert!(s.attitude.roll.abs() < 0.5f32.to_radians(), "roll {}", s.attitude.roll.to_degrees());
    assert!(e.counters().drag_blocks > 300, "{:?}", e.counters());
    // Accelerating forward tilted 5.7 deg nose down, truly: the thrust still reads along body z, with the
    // drag of the growing velocity across it. The drag model keeps the estimated pitch near the truth; the
    // gravity model would pull it to level.
    let pitch = libm::atanf(1.0 / GRAVITY);
    let truth = Attitude::new(0.0, pitch, 0.0);
    let r = truth.world_from_body();
    let k = params.drag_coeff_per_s;
    let thrust = GRAVITY / libm::cosf(pitch);
    // The truth, integrated at 1 kHz: v' = R f - g with f = (-k v_b,x, -k v_b,y, thrust).
    let mut v = Vec3::ZERO;
    let mut forces = std::vec::Vec::new();
    for _ in 0..2000 {
        let vb = r.tmul_vec(v);
        let f = Vec3::new(-k * vb.x, -k * vb.y, thrust);
        forces.push(f);
        v += (r.mul_vec(f) - Vec3::new(0.0, 0.0, GRAVITY)) * 0.001;
    }
    let mut e = Estimator::new(params, Vec3::new(1.0, 1.3, 0.8));
    e.tilt_aligned = true;
    e.q = Quat::from_mat3(&r);
    let t = run(&mut e, 0, 2.0, fly, |t| (Vec3::ZERO, forces[((t * 1000.0).round() as usize - 1).min(1999)]));
    let s = e.estimate(t);
    assert!(v.norm() > 1.5, "the vehicle accelerated: {v:?}");
    assert!(
        (s.attitude.pitch - pitch).abs() < 0.5f32.to_radians(),
        "pitch {}",
        s.attitude.pitch.to_degrees()
    );
    // The gravity model on the same samples: pulled toward level.
    let mut g = Estimator::new(params, Vec3::new(1.0, 1.3, 0.8));
    g.tilt_aligned = true;
    g.q = Quat::from_mat3(&r);
    let carried = AccelContext { airborne: Some(false), pad_height_m: None };
    let t =
        run(&mut g, 0, 2.0, carried, |t| (Vec3::ZERO, forces[((t * 1000.0).round() as usize - 1).min(1999)]));
    let s = g.estimate(t);
    assert!(
        (s.attitude.pitch - pitch).abs() > 1f32.to_radians(),
        "gravity pitch {}",
        s.attitude.pitch.to_degrees()
    );
}

#[test]
fn a_single_sample_spike_is_removed_and_counted_and_a_real_step_passes() {
    let run = |spike: Option<(u64, [f32; 3], [f32; 3])>| {
        let mut e = Estimator::new(EstimatorParams::default(), Vec3::new(1.0, 1.3, 0.06));
        for k in 0..400u64 {
            let mut s = level_imu(k * 1000);
            if let Some((at, g, a)) = spike
                && k == at
            {
                s.gyro_rad_s = g;
                s.accel_m_s2 = [a[0], a[1], a[2] + GRAVITY];
            }
            e.predict(&s);
        }
        e
    };
    let clean = run(None);
    // 20 rad/s on roll and 80 m/s^2 forward in one 1 ms sample: unfiltered, 1.1 deg of roll and 8 cm/s.
    let spiked = run(Some((200, [20.0, 0.0, 0.0], [80.0, 0.0, 0.0])));
    assert_eq!(spiked.counters().imu_spikes, 1);
    assert_eq!(clean.counters().imu_spikes, 0);
    let (c, s) = (clean.estimate(0), spiked.estimate(0));
    assert!((c.attitude.roll - s.attitude.roll).abs() < 1e-6, "{} {}", c.attitude.roll, s.attitude.roll);
    assert!((c.velocity_m_s - s.velocity_m_s).norm() < 1e-6);
    // A real change (a steady rate from sample 200 on) is not a spike: it is integrated from its first sample.
    let mut e = Estimator::new(EstimatorParams::default(), Vec3::ZERO);
    let yaw0 = e.estimate(0).attitude.yaw;
    for k in 0..=300u64 {
        let mut s = level_imu(k * 1000);
        if k >= 200 {
            s.gyro_rad_s = [0.0, 0.0, 2.0];
        }
        e.predict(&s);
    }
    assert_eq!(e.counters().imu_spikes, 0);
    // Samples 200..=299 are integrated (the newest waits for its successor): about 0.1 s at 2 rad/s.
    let turned = e.estimate(0).attitude.yaw - yaw0;
    assert!((turned - 0.2).abs() < 0.005, "turned {turned}");
}

fn hover_fix(cap: u64, p: Vec3) -> PositionFix {
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
fn hovering_filter(p: Vec3) -> (Estimator, u64) {
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

#[test]
fn a_fix_with_one_axis_outside_its_gate_is_refused_whole() {
    let p = Vec3::new(1.0, 1.3, 0.8);
    let (mut e, t) = hovering_filter(p);
    let before = e.estimate(t);
    let rejected = e.counters().fixes_rejected;
    // Height 0.5 m off (outside the gate), x 1 cm off (inside): nothing of it is used.
    let o = e.fuse_fix(&hover_fix(t - 40_000, p + Vec3::new(0.01, 0.0, 0.5)), t);
    assert_eq!(o, FuseOutcome::Rejected);
    assert_eq!(e.counters().fixes_rejected, rejected + 1);
    let after = e.estimate(t);
    assert_eq!(after.position_m, before.position_m, "no axis of a refused fix is fused");
}

#[test]
fn consistent_refusals_reset_the_position_to_vision() {
    // The estimate drifted 0.4 m in height while vision was out; vision returns and agrees with itself.
    let p = Vec3::new(1.0, 1.3, 0.8);
    let (mut e, mut t) = hovering_filter(p);
    let truth = p + Vec3::new(0.0, 0.0, 0.4);
    let n = EstimatorParams::default().vision_position_reset_after as u64;
    for k in 0..n {
        t += 33_000;
        e.predict(&level_imu(t));
        e.propagate_covariance(t);
        let o = e.fuse_fix(&hover_fix(t - 20_000, truth), t);
        if k + 1 < n {
            assert_eq!(o, FuseOutcome::Rejected, "fix {k}");
            assert!((e.estimate(t).position_m.z - 0.8).abs() < 0.05);
        }
    }
    assert_eq!(e.counters().position_resets, 1);
    // The IMU states start again from their initial uncertainty (a bias step is what breaks the model
    // silently), uncorrelated with the rest.
    let prm = EstimatorParams::default();
    for (first, sigma) in [
        (ITH, prm.initial_tilt_sigma_rad),
        (IBG, prm.initial_gyro_bias_sigma_rad_s),
        (IBA, prm.initial_accel_bias_sigma_m_s2),
    ] {
        for k in first..first + 3 {
            assert_eq!(e.cov[k][k], sigma * sigma, "state {k}");
            assert!((0..N).filter(|&i| i != k).all(|i| e.cov[k][i] == 0.0), "state {k} correlated");
        }
    }
    assert!(
        (e.estimate(t).position_m.z - 1.2).abs() < 0.01,
        "reset to vision: {}",
        e.estimate(t).position_m.z
    );
    // And the next fix is fused.
    t += 33_000;
    e.predict(&level_imu(t));
    e.propagate_covariance(t);
    assert_eq!(e.fuse_fix(&hover_fix(t - 20_000, truth), t), FuseOutcome::Accepted);
}

#[test]
fn the_compass_sets_the_heading_only_once_the_tilt_is_known() {
    // Resting tilted (15 deg roll, -10 deg pitch) with a heading of 30 deg. A compass reading before the
    // first accelerometer block would be levelled with the starting (level) attitude, and the heading
    // it gives would be off by degrees; it must wait for the tilt.
    let truth = Attitude::new(15f32.to_radians(), -10f32.to_radians(), 30f32.to_radians());
    let r = truth.world_from_body();
    let f = r.tmul_vec(Vec3::new(0.0, 0.0, GRAVITY));
    let params = EstimatorParams::default();
    let b = params.mag_field_world;
    let m_body = r.tmul_vec(Vec3::new(b[0], b[1], b[2]));
    let mut e = Estimator::new(params, Vec3::ZERO);
    e.predict(&ImuSample { time_us: 1000, gyro_rad_s: [0.0; 3], accel_m_s2: f.to_array() });
    assert_eq!(e.fuse_mag(m_body), FuseOutcome::Stale);
    assert!(!e.yaw_initialised());
    for k in 2..=60u64 {
        e.predict(&ImuSample { time_us: k * 1000, gyro_rad_s: [0.0; 3], accel_m_s2: f.to_array() });
    }
    assert_eq!(e.fuse_mag(m_body), FuseOutcome::Initialised);
    let s = e.estimate(60_000);
    assert!((s.attitude.yaw - truth.yaw).abs() < 0.1f32.to_radians(), "yaw {}", s.attitude.yaw.to_degrees());
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

#[test]
fn the_estimate_reports_the_covariance_it_holds() {
    let e = with_distinct_covariance();
    let s = e.estimate(42);
    let sd = |i: usize| e.cov[i][i].sqrt();
    assert_eq!(s.time_us, 42);
    assert_eq!(s.position_std_m, Vec3::new(sd(IP), sd(IP + 1), sd(IP + 2)));
    assert_eq!(s.velocity_std_m_s, Vec3::new(sd(IV), sd(IV + 1), sd(IV + 2)));
    assert_eq!(s.wind_std_m_s, [sd(IW), sd(IW + 1)]);
    // Yaw: the attitude error (body frame) projected on the world's vertical, u^T P u with u = R^T z.
    let r = e.q.to_mat3();
    let u = [r.m[2][0], r.m[2][1], r.m[2][2]];
    let mut var = 0.0f64;
    for a in 0..3 {
        for b in 0..3 {
            var += u[a] as f64 * e.cov[ITH + a][ITH + b] as f64 * u[b] as f64;
        }
    }
    assert!((s.yaw_std_rad as f64 - var.sqrt()).abs() < 1e-6, "{} {}", s.yaw_std_rad, var.sqrt());
    // Tilt: the larger of roll (its variance plus the bias across body y over g^2) and pitch (bias along x).
    let g2 = (GRAVITY * GRAVITY) as f64;
    let roll = e.cov[ITH][ITH] as f64 + e.cov[IBA + 1][IBA + 1] as f64 / g2;
    let pitch = e.cov[ITH + 1][ITH + 1] as f64 + e.cov[IBA][IBA] as f64 / g2;
    assert!((s.tilt_std_rad as f64 - roll.max(pitch).sqrt()).abs() < 1e-6);
    assert_eq!(s.tilt_std_rad, e.tilt_std_rad());
    // With roll's variance the larger one, the roll pair decides.
    let mut e2 = with_distinct_covariance();
    e2.cov[ITH][ITH] = 0.5;
    let roll = 0.5 + e2.cov[IBA + 1][IBA + 1] as f64 / g2;
    assert!((e2.tilt_std_rad() as f64 - roll.sqrt()).abs() < 1e-6);
}

#[test]
fn health_needs_every_state_and_variance_finite() {
    let e = with_distinct_covariance();
    assert!(e.is_healthy());
    let broken: [fn(&mut Estimator); 9] = [
        |e| e.p.y = f32::NAN,
        |e| e.v.z = f32::INFINITY,
        |e| e.q = Quat { w: f32::NAN, ..e.q },
        |e| e.bg.x = f32::NAN,
        |e| e.ba.y = f32::NAN,
        |e| e.w.x = f32::NAN,
        |e| e.cov[IV][IV] = f32::NAN,
        |e| e.cov[IW + 1][IW + 1] = -1e-6,
        |e| e.cov[IP][IP] = f32::INFINITY,
    ];
    for (k, f) in broken.iter().enumerate() {
        let mut b = with_distinct_covariance();
        f(&mut b);
        assert!(!b.is_healthy(), "case {k}");
    }
}

#[test]
fn the_history_keeps_one_snapshot_per_period_and_interpolates_between_them() {
    let mut e = Estimator::new(EstimatorParams::default(), Vec3::ZERO);
    assert!(e.state_at(0).is_none(), "an empty history");
    // Snapshots every 1 ms are offered: one per 2 ms is kept (a step within 1 % early counts as due).
    for k in 0..20u64 {
        e.p = Vec3::new(k as f32, 0.0, 0.0);
        e.v = Vec3::new(0.0, 2.0 * k as f32, 0.0);
        e.push_history(1000 + k * 1000);
    }
    assert_eq!(e.hist_len, 10);
    let times: std::vec::Vec<u64> = (0..e.hist_len).map(|k| e.history[k].time_us).collect();
    assert_eq!(times, (0..10).map(|k| 1000 + 2000 * k).collect::<std::vec::Vec<_>>());
    // 1 % early is due, 2 % early is not.
    let mut e2 = Estimator::new(EstimatorParams::default(), Vec3::ZERO);
    e2.push_history(10_000);
    e2.push_history(10_000 + 2000 - 20);
    assert_eq!(e2.hist_len, 2);
    e2.push_history(10_000 + 2000 - 20 + 2000 - 40);
    assert_eq!(e2.hist_len, 2);
    // Exact times read the snapshot; between two, position and velocity are interpolated linearly and the
    // attitude is the nearer one's.
    let s = e.state_at(5000).unwrap();
    assert_eq!((s.time_us, s.p.x, s.v.y), (5000, 4.0, 8.0));
    let s = e.state_at(5500).unwrap();
    assert_eq!(s.time_us, 5500);
    assert!((s.p.x - 4.5).abs() < 1e-6 && (s.v.y - 9.0).abs() < 1e-6, "{:?} {:?}", s.p, s.v);
    // Later than the newest, or earlier than the oldest: nothing.
    assert!(e.state_at(19_001).is_none());
    assert!(e.state_at(999).is_none());
    assert!(e.state_at(19_000).is_some() && e.state_at(1000).is_some());
    // Corrections made since a snapshot was stored apply to it when read.
    e.corr.p = Vec3::new(0.0, 0.0, 0.25);
    e.corr.v = Vec3::new(0.5, 0.0, 0.0);
    let s = e.state_at(5000).unwrap();
    assert_eq!((s.p.z, s.v.x), (0.25, 0.5));
}

#[test]
fn the_history_is_a_ring_of_its_newest_snapshots() {
    let mut e = Estimator::new(EstimatorParams::default(), Vec3::ZERO);
    let n = HISTORY_LEN as u64 + 30;
    for k in 0..n {
        e.p = Vec3::new(k as f32, 0.0, 0.0);
        e.q = Quat::from_mat3(&Attitude::new(0.0, 0.0, k as f32 * 0.01).world_from_body());
        e.push_history(k * SNAPSHOT_EVERY_US);
    }
    assert_eq!(e.hist_len, HISTORY_LEN);
    let oldest = (n - HISTORY_LEN as u64) * SNAPSHOT_EVERY_US;
    assert!(e.state_at(oldest - 1).is_none());
    assert_eq!(e.state_at(oldest).unwrap().p.x, (n - HISTORY_LEN as u64) as f32);
    let newest = (n - 1) * SNAPSHOT_EVERY_US;
    assert_eq!(e.state_at(newest).unwrap().p.x, (n - 1) as f32);
    // Between two snapshots: the attitude of the nearer one.
    let t = 100 * SNAPSHOT_EVERY_US;
    let yaw = |t_us: u64| Attitude::from_world_from_body(&e.state_at(t_us).unwrap().q.to_mat3()).yaw;
    assert!((yaw(t + 900) - 1.00).abs() < 1e-5, "{}", yaw(t + 900));
    assert!((yaw(t + 1100) - 1.01).abs() < 1e-5, "{}", yaw(t + 1100));
    assert_eq!(e.attitude_at(t).map(|a| (a.yaw - 1.0).abs() < 1e-5), Some(true));
    let past = e.past_state(t + 1000).unwrap();
    assert_eq!(past.time_us, t + 1000);
    assert!((past.position_m.x - 100.5).abs() < 1e-5);
}

#[test]
fn a_snapshot_takes_only_the_corrections_made_after_it() {
    let mut e = Estimator::new(EstimatorParams::default(), Vec3::ZERO);
    // Corrections made before the snapshot are in its state already.
    e.corr = Corrections {
        p: Vec3::new(1.0, 0.0, 0.0),
        v: Vec3::new(0.0, 2.0, 0.0),
        th: Vec3::new(0.0, 0.0, 0.3),
    };
    e.push_history(1000);
    e.push_history(3000);
    e.corr.p.x += 0.25;
    e.corr.v.y += 0.5;
    e.corr.th.z += 0.1;
    let s = e.state_at(1000).unwrap();
    assert_eq!((s.p.x, s.v.y), (0.25, 0.5));
    let yaw = Attitude::from_world_from_body(&s.q.to_mat3()).yaw;
    let yaw0 = Attitude::from_world_from_body(&e.q.to_mat3()).yaw;
    assert!((wrap_pi(yaw - yaw0) - 0.1).abs() < 1e-5, "{}", wrap_pi(yaw - yaw0));
    // Exactly midway between two snapshots: the later one's attitude.
    e.q = Quat::from_mat3(&Attitude::new(0.0, 0.0, 0.5).world_from_body());
    e.corr = Corrections::default();
    e.push_history(5000);
    let mid = Attitude::from_world_from_body(&e.state_at(4000).unwrap().q.to_mat3()).yaw;
    assert!((mid - 0.5).abs() < 1e-5, "{mid}");
}

/// The covariance propagation written out densely: `P' = P + dt (F P + P F^T) + dt^2 F P F^T + Q dt`, then the
/// wind's walk and its cap (row and column scaled), in f64.
fn propagated_by_hand(e: &Estimator, dt: f64) -> [[f64; N]; N] {
    let r = e.q.to_mat3();
    let ra = r.mul_mat(&Mat3::skew(e.last_accel));
    let w = e.last_omega;
    let mut f = [[0.0f64; N]; N];
    for i in 0..3 {
        f[IP + i][IV + i] = 1.0;
        for k in 0..3 {
            f[IV + i][ITH + k] = -ra.m[i][k] as f64;
            f[IV + i][IBA + k] = -r.m[i][k] as f64;
        }
        f[ITH + i][IBG + i] = -1.0;
    }
    let (wx, wy, wz) = (w.x as f64, w.y as f64, w.z as f64);
    let minus_wx = [[0.0, wz, -wy], [-wz, 0.0, wx], [wy, -wx, 0.0]];
    for i in 0..3 {
        for k in 0..3 {
            f[ITH + i][ITH + k] = minus_wx[i][k];
        }
    }
    let p: [[f64; N]; N] = core::array::from_fn(|i| core::array::from_fn(|j| e.cov[i][j] as f64));
    let mul = |a: &[[f64; N]; N], b: &[[f64; N]; N]| -> [[f64; N]; N] {
        core::array::from_fn(|i| core::array::from_fn(|j| (0..N).map(|k| a[i][k] * b[k][j]).sum()))
    };
    let ft: [[f64; N]; N] = core::array::from_fn(|i| core::array::from_fn(|j| f[j][i]));
    let fp = mul(&f, &p);
    let pft = mul(&p, &ft);
    let fpft = mul(&fp, &ft);
    let mut out: [[f64; N]; N] = core::array::from_fn(|i| {
        core::array::from_fn(|j| p[i][j] + dt * (fp[i][j] + pft[i][j]) + dt * dt * fpft[i][j])
    });
    let pr = &e.params;
    for (start, sigma) in
        [(IV, pr.accel_noise), (ITH, pr.gyro_noise), (IBG, pr.gyro_bias_walk), (IBA, pr.accel_bias_walk)]
    {
        for k in 0..3 {
            out[start + k][start + k] += (sigma as f64).powi(2) * dt;
        }
    }
    let cap = (pr.initial_wind_sigma_m_s as f64).powi(2);
    for k in 0..2 {
        let i = IW + k;
        out[i][i] += (pr.wind_walk_m_s as f64).powi(2) * dt;
        if out[i][i] > cap {
            let s = (cap / out[i][i]).sqrt();
            for j in 0..N {
                out[i][j] *= s;
                out[j][i] *= s;
            }
        }
    }
    out
}

#[test]
fn the_covariance_propagates_as_the_error_dynamics_state() {
    for case in 0..3 {
        let mut e = with_distinct_covariance();
        e.last_accel = Vec3::new(0.4, -0.7, 9.6);
        e.last_omega = Vec3::new(0.3, -0.5, 0.8);
        if case == 1 {
            // The wind's variance beyond its cap after the walk: scaled back to it.
            e.params.initial_wind_sigma_m_s = 1.5;
            let cap = e.params.initial_wind_sigma_m_s * e.params.initial_wind_sigma_m_s;
            e.cov[IW][IW] = cap * 0.999;
            e.cov[IW + 1][IW + 1] = cap * 1.5;
        }
        if case == 2 {
            e.q = Quat::from_mat3(&Attitude::new(-0.4, 0.1, -2.0).world_from_body());
        }
        let dt = 0.02;
        e.pending_dt = dt;
        let want = propagated_by_hand(&e, dt as f64);
        let len = e.hist_len;
        e.propagate_covariance(20_000);
        for i in 0..N {
            for j in 0..N {
                let tol = 1e-6 * want[i][j].abs().max(1e-3);
                assert!(
                    (e.cov[i][j] as f64 - want[i][j]).abs() < tol,
                    "case {case}: P[{i}][{j}] {} want {}",
                    e.cov[i][j],
                    want[i][j]
                );
            }
        }
        assert_eq!(e.hist_len, len + 1, "the state is stored");
        // The step is spent: another call adds nothing.
        let before = e.cov;
        e.propagate_covariance(22_000);
        assert_eq!(e.cov, before);
    }
}

#[test]
fn symmetrising_takes_the_mean_and_floors_the_variances() {
    let mut e = with_distinct_covariance();
    e.cov[IP][IV] = 0.3;
    e.cov[IV][IP] = 0.1;
    e.cov[IBA][IBA] = 0.0;
    e.cov[IW][IW] = -1.0;
    e.cov[IBG][IBG] = f32::NAN;
    let keep = e.cov[ITH][ITH];
    e.symmetrise();
    assert!((e.cov[IP][IV] - 0.2).abs() < 1e-7 && e.cov[IP][IV] == e.cov[IV][IP]);
    assert_eq!((e.cov[IBA][IBA], e.cov[IW][IW], e.cov[IBG][IBG]), (1e-12, 1e-12, 1e-12));
    assert_eq!(e.cov[ITH][ITH], keep);
}

/// The gyro x value the filter integrates for the middle of three samples (x, y, z at 1 ms), and whether it
/// counted a spike.
fn cleaned_middle(x: f32, y: f32, z: f32) -> (f32, bool) {
    let mut e = Estimator::new(EstimatorParams::default(), Vec3::ZERO);
    for (k, g) in [x, y, z].into_iter().enumerate() {
        let s = ImuSample {
            time_us: 1000 * (k as u64 + 1),
            gyro_rad_s: [g, 0.0, 0.0],
            accel_m_s2: [0.0, 0.0, GRAVITY],
        };
        assert!(e.predict(&s));
    }
    (e.last_omega.x, e.counters().imu_spikes == 1)
}

#[test]
fn a_spike_is_a_middle_sample_that_stands_out_from_two_agreeing_neighbours() {
    let lim = SPIKE_GYRO_RAD_S;
    // Above both, below both: replaced by the neighbours' mean, counted.
    assert_eq!(cleaned_middle(0.0, 1.0, 0.0), (0.0, true));
    assert_eq!(cleaned_middle(0.0, -1.0, 0.0), (0.0, true));
    assert_eq!(cleaned_middle(0.0, 1.0, 0.4), (0.2, true));
    // Neighbours that disagree by more than the threshold: a real change, passed.
    assert_eq!(cleaned_middle(0.0, 1.0, 0.6), (1.0, false));
    assert_eq!(cleaned_middle(0.6, 1.2, 0.0), (1.2, false));
    // At the thresholds: neighbours exactly `lim` apart agree; a sample exactly `lim` off is no spike.
    assert_eq!(cleaned_middle(0.0, 1.25, lim), (0.25, true));
    assert_eq!(cleaned_middle(0.0, lim, 0.0), (lim, false));
    assert_eq!(cleaned_middle(0.0, 1.0, 1.0 - lim), (1.0, false));
    // Measured from each neighbour: standing out from one only is no spike.
    assert_eq!(cleaned_middle(0.3, 0.75, 0.0), (0.75, false));
    assert_eq!(cleaned_middle(0.0, 0.75, 0.3), (0.75, false));
    assert_eq!(cleaned_middle(-0.3, -0.75, 0.0), (-0.75, false));
    // The accelerometer's own threshold, on its own axis.
    let mut e = Estimator::new(EstimatorParams::default(), Vec3::ZERO);
    for (k, az) in [GRAVITY, GRAVITY + 2.0 * SPIKE_ACCEL_M_S2, GRAVITY].into_iter().enumerate() {
        e.predict(&ImuSample {
            time_us: 1000 * (k as u64 + 1),
            gyro_rad_s: [0.0; 3],
            accel_m_s2: [0.0, 0.0, az],
        });
    }
    assert_eq!(e.counters().imu_spikes, 1);
    assert_eq!(e.last_accel.z, GRAVITY);
}

#[test]
fn samples_that_are_not_finite_or_not_newer_are_refused_and_a_held_gyro_is_counted() {
    let mut e = Estimator::new(EstimatorParams::default(), Vec3::ZERO);
    let at = |t: u64, g: [f32; 3], a: [f32; 3]| ImuSample { time_us: t, gyro_rad_s: g, accel_m_s2: a };
    let level = [0.0, 0.0, GRAVITY];
    assert!(e.predict(&at(1000, [0.0; 3], level)));
    assert!(!e.predict(&at(2000, [f32::NAN, 0.0, 0.0], level)), "a gyro NaN");
    assert!(!e.predict(&at(2000, [0.0; 3], [0.0, f32::INFINITY, 9.8])), "an accelerometer infinity");
    assert!(!e.predict(&at(1000, [0.0; 3], level)), "not newer");
    assert!(e.predict(&at(2000, [0.0; 3], level)));
    // A gyro axis held at exactly the same large value on consecutive samples (a saturated sensor) counts;
    // the same small value does not (a still gyro repeats its quantum), nor does a large one that changes.
    let big = CLIP_MIN_RATE_RAD_S * 2.0;
    assert!(e.predict(&at(3000, [0.0, big, 0.0], level)));
    assert!(e.predict(&at(4000, [0.0, big, 0.0], level)));
    assert_eq!(e.counters().gyro_clipped, 1);
    assert!(e.predict(&at(5000, [0.0, big, 0.0], level)));
    assert_eq!(e.counters().gyro_clipped, 2);
    assert!(e.predict(&at(6000, [0.0, big * 0.99, 0.0], level)));
    assert!(e.predict(&at(7000, [0.01, 0.0, 0.0], level)));
    assert!(e.predict(&at(8000, [0.01, 0.0, 0.0], level)));
    assert_eq!(e.counters().gyro_clipped, 2);
}

pub(super) fn yaw_of(e: &Estimator) -> f32 {
    Attitude::from_world_from_body(&e.q.to_mat3()).yaw
}

#[test]
fn a_yaw_reset_turns_the_state_and_its_history_and_sets_the_yaw_variance_alone() {
    let mut e = with_distinct_covariance();
    e.push_history(1000);
    let (yaw0, hist_yaw0) = (yaw_of(&e), Attitude::from_world_from_body(&e.history[0].q.to_mat3()).yaw);
    let tilt_var = e.cov[ITH][ITH].max(e.cov[ITH + 1][ITH + 1]);
    let untouched = e.cov[IV][IBA];
    e.reset_yaw(0.4, 0.09);
    assert!((wrap_pi(yaw_of(&e) - yaw0) - 0.4).abs() < 1e-5);
    let hist_yaw = Attitude::from_world_from_body(&e.history[0].q.to_mat3()).yaw;
    assert!((wrap_pi(hist_yaw - hist_yaw0) - 0.4).abs() < 1e-5);
    let up = e.q.to_mat3().m[2];
    for k in 0..3 {
        let want = tilt_var + (0.09 - tilt_var) * up[k] * up[k];
        assert!(
            (e.cov[ITH + k][ITH + k] - want).abs() < 1e-7,
            "axis {k}: {} {want}",
            e.cov[ITH + k][ITH + k]
        );
        for i in (0..N).filter(|&i| i != ITH + k) {
            assert_eq!((e.cov[i][ITH + k], e.cov[ITH + k][i]), (0.0, 0.0), "{i} {k}");
        }
    }
    assert_eq!(e.cov[IV][IBA], untouched);
    assert!((e.estimate(0).yaw_std_rad - 0.3).abs() < 0.02, "{}", e.estimate(0).yaw_std_rad);
    assert!(e.yaw_initialised());
}

/// The body-frame field that reads as compass heading error `raw` (`atan2` of the world field less that of
/// the levelled reading) at the filter's attitude.
pub(super) fn field_reading(e: &Estimator, raw: f32) -> Vec3 {
    let b = Vec3::from_array(e.params.mag_field_world);
    let m_w = Mat3::rot_z(-raw).mul_vec(b);
    e.q.to_mat3().tmul_vec(m_w)
}

#[test]
fn the_compass_initialises_then_corrects_and_learns_its_offset_while_vision_holds_the_heading() {
    let p = EstimatorParams { mag_heading_sigma_rad: 1e-3, ..EstimatorParams::default() };
    let mut e = Estimator::new(p, Vec3::ZERO);
    e.q = Quat::from_mat3(&Attitude::new(0.1, -0.05, 0.5).world_from_body());
    assert_eq!(e.fuse_mag(Vec3::new(f32::NAN, 0.0, 0.0)), FuseOutcome::Invalid);
    assert_eq!(e.fuse_mag(field_reading(&e, 0.3)), FuseOutcome::Stale, "before the tilt is aligned");
    e.tilt_aligned = true;
    // A field with (almost) no horizontal part tells no heading; a weak one does.
    let r = e.q.to_mat3();
    assert_eq!(e.fuse_mag(r.tmul_vec(Vec3::new(1e-7, 0.0, -0.4))), FuseOutcome::Invalid);
    let weak = e.clone().fuse_mag(r.tmul_vec(Vec3::new(2e-6, 0.0, -0.4)));
    assert_ne!(weak, FuseOutcome::Invalid);
    // The first reading sets the heading.
    assert_eq!(e.fuse_mag(field_reading(&e, 0.3)), FuseOutcome::Initialised);
    assert!((wrap_pi(yaw_of(&e) - 0.8)).abs() < 1e-4, "{}", yaw_of(&e));
    // Then a reading 0.05 rad off (no vision) pulls the yaw almost all the way (its sigma is 1 mrad against
    // the reset's).
    e.cov[ITH + 2][ITH + 2] = 0.01;
    let y = yaw_of(&e);
    assert_eq!(e.fuse_mag(field_reading(&e, 0.05)), FuseOutcome::Accepted);
    assert!((wrap_pi(yaw_of(&e) - y) - 0.05).abs() < 2e-3, "{}", wrap_pi(yaw_of(&e) - y));
    assert_eq!(e.counters().mag_accepted, 1);
    // Vision holds the heading: the offset is learned from the readings; one beyond mag_consistency_rad is
    // refused (and still teaches the offset).
    e.last_imu_us = Some(10_000_000);
    e.last_vision_yaw_us = Some(10_000_000 - (e.params.mag_vision_window_s * 1e6) as u64);
    e.cov[ITH + 2][ITH + 2] = 0.01;
    let y = yaw_of(&e);
    assert_eq!(
        e.fuse_mag(field_reading(&e, 0.1)),
        FuseOutcome::Accepted,
        "vision exactly window old is fresh"
    );
    assert!((e.mag_offset.unwrap() - 0.1).abs() < 1e-5, "{:?}", e.mag_offset);
    assert!((wrap_pi(yaw_of(&e) - y) - 0.1).abs() < 2e-3);
    let rate = e.params.mag_offset_learn_rate;
    let raw = e.params.mag_consistency_rad + 0.05;
    let before = e.counters().mag_rejected;
    assert_eq!(e.fuse_mag(field_reading(&e, raw)), FuseOutcome::Rejected);
    assert_eq!(e.counters().mag_rejected, before + 1);
    let off = 0.1 + rate * (raw - 0.1);
    assert!((e.mag_offset.unwrap() - off).abs() < 1e-5, "{:?} {off}", e.mag_offset);
    // Vision gone stale: the compass holds the heading, less the learned offset.
    e.last_vision_yaw_us = Some(10_000_000 - (e.params.mag_vision_window_s * 1e6) as u64 - 1000);
    e.cov[ITH + 2][ITH + 2] = 0.01;
    let y = yaw_of(&e);
    assert_eq!(e.fuse_mag(field_reading(&e, off + 0.04)), FuseOutcome::Accepted);
    assert!((wrap_pi(yaw_of(&e) - y) - 0.04).abs() < 2e-3, "{}", wrap_pi(yaw_of(&e) - y));
}

/// The state correction an update injected, read back from the filter (position, velocity and attitude
/// through the cumulative corrections, the rest from the states).
fn injected(before: &Estimator, after: &Estimator) -> [f32; N] {
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
fn assert_injected(before: &Estimator, after: &Estimator, want: &[f64; N], rel: f64, floor: f64) {
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

#[test]
fn a_scalar_update_is_the_kalman_update_with_considered_states_left_alone() {
    let rows: [&[(usize, f32)]; 3] = [
        &[(IP + 1, 1.0), (IV + 1, -0.05)],
        &[(IV, -0.3), (IV + 2, 0.1), (ITH, 0.2), (ITH + 1, -0.4), (IBA, 1.0), (IW, 0.3)],
        &[(ITH + 2, 0.9), (IBG + 1, 0.5), (IBA + 2, -0.7)],
    ];
    for (case, row) in rows.iter().enumerate() {
        for consider in [0..0, IBA..IBA + 3] {
            let mut h = [0.0f32; N];
            for &(k, v) in row.iter() {
                h[k] = v;
            }
            let e0 = with_distinct_covariance();
            let mut e = e0.clone();
            let (innov, var) = (0.03, 0.002);
            assert!(e.update_considering(&h, innov, var, true, consider.clone()));
            // By hand in f64: s = h P h' + var, K = P h' / s, dx = K innov (0 for considered states),
            // P' = P - K (P h')' except the considered block, variances floored.
            let p = |i: usize, j: usize| e0.cov[i][j] as f64;
            let ph: [f64; N] = core::array::from_fn(|i| (0..N).map(|k| p(i, k) * h[k] as f64).sum());
            let s = var as f64 + (0..N).map(|k| h[k] as f64 * ph[k]).sum::<f64>();
            let dx = injected(&e0, &e);
            for i in 0..N {
                let want = if consider.contains(&i) { 0.0 } else { ph[i] / s * innov as f64 };
                assert!(
                    (dx[i] as f64 - want).abs() < 1e-6,
                    "case {case} {consider:?}: dx[{i}] {} {want}",
                    dx[i]
                );
                for j in 0..N {
                    let want = if consider.contains(&i) && consider.contains(&j) {
                        p(i, j)
                    } else {
                        p(i, j) - ph[i] * ph[j] / s
                    };
                    let want = if i == j { want.max(1e-12) } else { want };
                    assert!(
                        (e.cov[i][j] as f64 - want).abs() < 1e-6 * want.abs().max(1e-3),
                        "case {case}: P[{i}][{j}]"
                    );
                }
            }
            // Gated: an innovation beyond gate_sigma standard deviations is refused, nothing changed; the same
            // without the gate is taken.
            let big = (e0.params.gate_sigma as f64 * s.sqrt() * 1.01) as f32;
            let mut g = e0.clone();
            assert!(!g.update_considering(&h, big, var, true, consider.clone()));
            assert_eq!((g.cov, g.p, g.v, g.ba), (e0.cov, e0.p, e0.v, e0.ba));
            let inside = (e0.params.gate_sigma as f64 * s.sqrt() * 0.99) as f32;
            assert!(e0.clone().update_considering(&h, inside, var, true, consider.clone()));
            assert!(e0.clone().update_considering(&h, big, var, false, consider.clone()));
            // No variance to divide by, or no finite innovation: refused.
            assert!(!e0.clone().update_considering(&h, innov, -(s as f32) - 1.0, false, consider.clone()));
            assert!(!e0.clone().update_considering(&h, f32::NAN, var, false, consider.clone()));
        }
    }
}

/// One scalar update by hand (f64): returns the correction and updates `p`.
fn kalman_by_hand(p: &mut [[f64; N]; N], h: &[f64; N], innov: f64, var: f64) -> [f64; N] {
    let ph: [f64; N] = core::array::from_fn(|i| (0..N).map(|k| p[i][k] * h[k]).sum());
    let s = var + (0..N).map(|k| h[k] * ph[k]).sum::<f64>();
    for i in 0..N {
        for j in 0..N {
            p[i][j] -= ph[i] * ph[j] / s;
        }
    }
    core::array::from_fn(|i| ph[i] / s * innov)
}

#[test]
fn a_body_velocity_updates_as_its_measurement_model_states() {
    let mut e = with_distinct_covariance();
    e.v = Vec3::new(0.3, -0.2, 0.1);
    e.push_history(1_000_000);
    // The vehicle has turned since (the current attitude differs from the past one the prediction uses).
    let past = e.state_at(1_000_000).unwrap();
    e.q = Quat::from_mat3(&Attitude::new(0.25, -0.3, 0.9).world_from_body());
    // Small innovations (0.01 m/s), so that the second axis's row, formed after the first axis's correction,
    // is the first-order one the check below uses.
    let body_past = past.q.to_mat3().tmul_vec(past.v);
    let m = BodyVelocity {
        time_us: 1_000_000,
        velocity_m_s: [body_past.x + 0.01, body_past.y - 0.008],
        std_m_s: 0.05,
    };
    let e0 = e.clone();
    assert_eq!(e.fuse_body_velocity(&m, 1_040_000), FuseOutcome::Accepted);
    assert_eq!(e.counters().flow_accepted, 1);
    // By hand: for each body axis a, the row v -> (R^T v)_a at the current attitude, theta -> [R^T v]x row a;
    // the innovation against the past state's body velocity.
    let mut p: [[f64; N]; N] = core::array::from_fn(|i| core::array::from_fn(|j| e0.cov[i][j] as f64));
    let rp = past.q.to_mat3();
    let mut total = [0.0f64; N];
    // The second axis's row is formed at the state the first axis's correction left.
    let (mut q, mut v) = (e0.q, e0.v);
    for axis in 0..2 {
        let r = q.to_mat3();
        let mut h = [0.0f64; N];
        for k in 0..3 {
            h[IV + k] = r.m[k][axis] as f64;
        }
        let vb = r.tmul_vec(v);
        let sk = Mat3::skew(vb);
        for k in 0..3 {
            h[ITH + k] = sk.m[axis][k] as f64;
        }
        let pred: f64 = (0..3).map(|k| rp.m[k][axis] as f64 * past.v[k] as f64).sum();
        let dx = kalman_by_hand(&mut p, &h, m.velocity_m_s[axis] as f64 - pred, 0.05 * 0.05);
        for i in 0..N {
            total[i] += dx[i];
        }
        let d3 = |k: usize| Vec3::new(dx[k] as f32, dx[k + 1] as f32, dx[k + 2] as f32);
        v += d3(IV);
        q = q.mul(&Quat::from_rotvec(d3(ITH))).normalized();
    }
    assert_injected(&e0, &e, &total, 2e-3, 1e-3);
    for i in 0..N {
        assert!((e.cov[i][i] as f64 - p[i][i]).abs() < 1e-4 * p[i][i], "P[{i}][{i}]");
    }
    // Refused: not finite, no standard deviation, from the future, too old; and one outside its gate counts.
    let mut e = e0.clone();
    let bad = |v: [f32; 2], sd: f32| BodyVelocity { time_us: 1_000_000, velocity_m_s: v, std_m_s: sd };
    assert_eq!(e.fuse_body_velocity(&bad([f32::NAN, 0.0], 0.05), 1_040_000), FuseOutcome::Invalid);
    assert_eq!(e.fuse_body_velocity(&bad([0.0, f32::INFINITY], 0.05), 1_040_000), FuseOutcome::Invalid);
    assert_eq!(e.fuse_body_velocity(&bad([0.0, 0.0], 0.0), 1_040_000), FuseOutcome::Invalid);
    assert_eq!(e.fuse_body_velocity(&m, 999_999), FuseOutcome::Stale);
    let max_age = (e.params.max_fix_age_s * 1e6) as u64;
    assert_eq!(e.fuse_body_velocity(&m, 1_000_000 + max_age + 1), FuseOutcome::Stale);
    assert_ne!(e.clone().fuse_body_velocity(&m, 1_000_000 + max_age), FuseOutcome::Stale);
    assert_eq!(e.cov, e0.cov, "refusals change nothing");
    let far = BodyVelocity { velocity_m_s: [30.0, 0.0], std_m_s: 0.001, ..m };
    assert_eq!(e.fuse_body_velocity(&far, 1_040_000), FuseOutcome::Rejected);
    assert_eq!(e.counters().flow_rejected, 1);
}

fn fix_at(t_us: u64, p: Vec3, yaw: f32) -> PositionFix {
    PositionFix {
        capture_time_us: t_us,
        position_m: p,
        position_std_m: Vec3::new(0.01, 0.002, 0.003),
        x_observed: true,
        yaw_rad: yaw,
        yaw_std_rad: 0.0001,
    }
}

#[test]
fn a_first_fix_sets_the_heading_and_the_position_from_where_the_vehicle_was() {
    let mut e = with_distinct_covariance();
    e.push_history(1_000_000);
    let past = e.state_at(1_000_000).unwrap();
    // The vehicle moved and turned since the frame was captured.
    e.p += Vec3::new(0.01, -0.02, 0.005);
    e.q = Quat::from_rotvec(Vec3::new(0.0, 0.0, 0.05)).mul(&e.q).normalized();
    let now = 1_040_000;
    let f = fix_at(1_000_000, Vec3::new(1.5, 1.2, 0.7), 0.2);
    // Refused before anything: not finite, from the future, too old, older than the history.
    assert_eq!(e.fuse_fix(&PositionFix { yaw_rad: f32::NAN, ..f }, now), FuseOutcome::Invalid);
    assert_eq!(
        e.fuse_fix(&PositionFix { position_m: Vec3::new(f32::NAN, 0.0, 0.0), ..f }, now),
        FuseOutcome::Invalid
    );
    assert_eq!(e.fuse_fix(&f, 999_999), FuseOutcome::Stale);
    let max_age = (e.params.max_fix_age_s * 1e6) as u64;
    assert_eq!(e.fuse_fix(&f, 1_000_000 + max_age + 1), FuseOutcome::Stale);
    assert_eq!(e.fuse_fix(&PositionFix { capture_time_us: 999_000, ..f }, 1_000_000), FuseOutcome::Stale);
    assert_eq!(e.counters().fixes_stale, 3);
    let (p_before, yaw_before) = (e.p, yaw_of(&e));
    let yaw_past = Attitude::from_world_from_body(&past.q.to_mat3()).yaw;
    assert_eq!(e.fuse_fix(&f, now), FuseOutcome::Initialised);
    assert!(e.yaw_from_vision());
    // The heading turned by what the fix says the past heading was off.
    let turned = wrap_pi(yaw_of(&e) - yaw_before);
    assert!((turned - wrap_pi(0.2 - yaw_past)).abs() < 1e-4, "{turned}");
    // x and y: the fix plus the motion since; z left to the fixes that follow; the variances the fix's.
    let moved = p_before - past.p;
    assert!((e.p.x - (1.5 + moved.x)).abs() < 1e-6 && (e.p.y - (1.2 + moved.y)).abs() < 1e-6, "{:?}", e.p);
    assert_eq!(e.p.z, p_before.z);
    assert!((e.cov[IP][IP] - 1e-4).abs() < 1e-9);
    let floor = e.params.vision_position_floor_m;
    assert!((e.cov[IP + 1][IP + 1] - floor * floor).abs() < 1e-9, "the floor under a smaller std");
    assert_eq!(e.counters().fixes_accepted, 1);
    // An unobserved x stays uninitialised.
    let mut e2 = with_distinct_covariance();
    e2.push_history(1_000_000);
    let px = e2.p.x;
    e2.fuse_fix(&PositionFix { x_observed: false, ..f }, now);
    assert_eq!(e2.p.x, px);
    assert!((e2.p.y - 1.2).abs() < 1e-6);
}

#[test]
fn a_fix_updates_heading_then_each_axis_against_the_past_state() {
    let mut e = with_distinct_covariance();
    e.yaw_from_vision = true;
    e.xy_initialised = [true; 2];
    e.v = Vec3::new(0.2, -0.1, 0.05);
    e.push_history(1_000_000);
    let past = e.state_at(1_000_000).unwrap();
    e.p += Vec3::new(0.008, -0.004, 0.002);
    let age = 0.04f32;
    let yaw_past = Attitude::from_world_from_body(&past.q.to_mat3()).yaw;
    let f = PositionFix {
        position_std_m: Vec3::new(0.03, 0.02, 0.04),
        yaw_std_rad: 0.05,
        ..fix_at(1_000_000, past.p + Vec3::new(0.004, -0.003, 0.002), yaw_past + 0.01)
    };
    let e0 = e.clone();
    assert_eq!(e.fuse_fix(&f, 1_040_000), FuseOutcome::Accepted);
    // By hand: the yaw row at the current attitude, then x, y, z with rows p - age v, each innovation against
    // the past position plus what the earlier axes' updates moved it.
    let mut p: [[f64; N]; N] = core::array::from_fn(|i| core::array::from_fn(|j| e0.cov[i][j] as f64));
    let r = e0.q.to_mat3();
    let mut h = [0.0f64; N];
    for k in 0..3 {
        h[ITH + k] = r.m[2][k] as f64;
    }
    let mut total = kalman_by_hand(&mut p, &h, 0.01, 0.05 * 0.05);
    let mut corr = [0.0f64; 3];
    for axis in 0..3 {
        let mut h = [0.0f64; N];
        h[IP + axis] = 1.0;
        h[IV + axis] = -age as f64;
        let innov = f.position_m[axis] as f64 - (past.p[axis] as f64 + corr[axis]);
        let sd = f.position_std_m[axis] as f64;
        let dx = kalman_by_hand(&mut p, &h, innov, sd * sd);
        for k in 0..3 {
            corr[k] += dx[IP + k] - dx[IV + k] * age as f64;
        }
        for i in 0..N {
            total[i] += dx[i];
        }
    }
    assert_injected(&e0, &e, &total, 1e-4, 1e-4);
    for i in 0..N {
        assert!((e.cov[i][i] as f64 - p[i][i]).abs() < 1e-4 * p[i][i], "P[{i}][{i}]");
    }
    assert_eq!(e.counters().fixes_accepted, 1);
}

#[test]
fn fixes_refused_in_a_row_reset_the_position_and_reopen_the_imu_states() {
    let mut e = with_distinct_covariance();
    e.yaw_from_vision = true;
    e.xy_initialised = [true; 2];
    e.push_history(1_000_000);
    let yaw_past = yaw_of(&e);
    let far = PositionFix {
        position_std_m: Vec3::new(0.01, 0.01, 0.01),
        ..fix_at(1_000_000, e.p + Vec3::new(2.0, 0.0, 0.0), yaw_past)
    };
    let n = e.params.vision_position_reset_after as u32;
    for k in 1..n {
        assert_eq!(e.fuse_fix(&far, 1_010_000), FuseOutcome::Rejected);
        assert_eq!(e.counters().fixes_rejected, k);
        assert_eq!(e.counters().position_resets, 0);
    }
    e.fuse_fix(&far, 1_010_000);
    assert_eq!(e.counters().position_resets, 1);
    assert!((e.p.x - far.position_m.x).abs() < 1e-5, "{:?}", e.p);
    let p = e.params;
    let near = |a: f32, b: f32| (a - b).abs() < 1e-6 * b.max(1e-6);
    assert!(near(e.cov[IV][IV], p.reset_velocity_sigma_m_s * p.reset_velocity_sigma_m_s));
    assert!(near(e.cov[ITH][ITH], p.initial_tilt_sigma_rad * p.initial_tilt_sigma_rad));
    assert!(near(e.cov[IBG + 1][IBG + 1], p.initial_gyro_bias_sigma_rad_s * p.initial_gyro_bias_sigma_rad_s));
    assert!(near(e.cov[IBA + 2][IBA + 2], p.initial_accel_bias_sigma_m_s2 * p.initial_accel_bias_sigma_m_s2));
    // A yaw refused in a row resets the heading to vision's.
    let mut e = with_distinct_covariance();
    e.yaw_from_vision = true;
    e.xy_initialised = [true; 2];
    e.push_history(1_000_000);
    let off = PositionFix { yaw_std_rad: 0.001, ..fix_at(1_000_000, e.p, wrap_pi(yaw_of(&e) + 2.5)) };
    let n = e.params.vision_yaw_reset_after as u32;
    for k in 1..n {
        e.fuse_fix(&off, 1_010_000);
        assert_eq!(e.counters().vision_yaw_rejected, k);
    }
    e.fuse_fix(&off, 1_010_000);
    assert_eq!(e.counters().yaw_resets, 1);
    assert!((wrap_pi(yaw_of(&e) - off.yaw_rad)).abs() < 1e-3, "{}", yaw_of(&e));
}

#[test]
fn gravity_corrects_the_tilt_across_the_predicted_vertical() {
    let mut e = with_distinct_covariance();
    e.ba = Vec3::new(0.02, -0.03, 0.01);
    let r = e.q.to_mat3();
    let g_b = r.tmul_vec(Vec3::new(0.0, 0.0, GRAVITY));
    // A specific force slightly off the predicted gravity (plus bias): the tilt is corrected toward it.
    let f = g_b + e.ba + Vec3::new(0.015, -0.01, 0.02);
    let e0 = e.clone();
    assert!(e.fuse_gravity(f, 0.1, true));
    // By hand: two rows across the predicted vertical `n` (e1 = n x X, or n x Y near X; e2 = n x e1),
    // d(e.f)/dtheta = [g_b]x^T e, innovation e.(f - g_b - b_a), variance sigma^2 each.
    let up = g_b * (1.0 / GRAVITY);
    let e1 = up.cross(if up.x.abs() < 0.8 { Vec3::X } else { Vec3::Y }).normalized().unwrap();
    let e2 = up.cross(e1);
    let mut p: [[f64; N]; N] = core::array::from_fn(|i| core::array::from_fn(|j| e0.cov[i][j] as f64));
    let mut total = [0.0f64; N];
    // Each row is formed at the state the previous one left (attitude and bias).
    let (mut q, mut ba) = (e0.q, e0.ba);
    for d in [e1, e2] {
        let g_b = q.to_mat3().tmul_vec(Vec3::new(0.0, 0.0, GRAVITY));
        let row = Mat3::skew(g_b).tmul_vec(d);
        let mut h = [0.0f64; N];
        for k in 0..3 {
            h[ITH + k] = row[k] as f64;
        }
        let innov = d.dot(f - g_b - ba) as f64;
        let dx = kalman_by_hand(&mut p, &h, innov, 0.01);
        for i in 0..N {
            total[i] += dx[i];
        }
        let d3 = |k: usize| Vec3::new(dx[k] as f32, dx[k + 1] as f32, dx[k + 2] as f32);
        q = q.mul(&Quat::from_rotvec(d3(ITH))).normalized();
        ba += d3(IBA);
    }
    assert_injected(&e0, &e, &total, 2e-3, 1e-4);
    // Refused: a force whose magnitude is far from gravity (more than 3 sigma, at least 0.9 m/s^2), or not
    // finite; nothing changes.
    let mut e = e0.clone();
    assert!(!e.fuse_gravity(f * 1.2, 0.1, true));
    assert!(!e.fuse_gravity(Vec3::new(f32::NAN, 0.0, 9.8), 0.1, true));
    assert_eq!(e.cov, e0.cov);
    let n = f.normalized().unwrap();
    assert!(e.clone().fuse_gravity(n * (GRAVITY + 0.85), 0.1, false), "within 0.9 m/s^2");
    assert!(!e.clone().fuse_gravity(n * (GRAVITY - 0.95), 0.1, false));
    assert!(e.clone().fuse_gravity(n * (GRAVITY + 2.9), 1.0, false), "within 3 sigma");
    assert!(!e.clone().fuse_gravity(n * (GRAVITY + 3.1), 1.0, false));
}

fn still_report(gyro: Vec3, accel: Vec3, window: bool) -> MotionReport {
    MotionReport {
        block: crate::motion::Block { end_us: 50_000, samples: 50, mean_gyro: gyro, mean_accel: accel },
        class: MotionClass::Still,
        still_window: window.then_some((gyro, accel)),
    }
}

#[test]
fn at_rest_the_first_window_sets_the_gyro_bias_and_each_block_holds_velocity_height_and_rate() {
    let p = EstimatorParams::default();
    let mut e = Estimator::new(p, Vec3::new(1.0, 1.3, 0.1));
    e.v = Vec3::new(0.1, -0.2, 0.05);
    let gyro = Vec3::new(0.01, -0.02, 0.005);
    let (pv, pz) = (e.cov[IV][IV], e.cov[IP + 2][IP + 2]);
    e.motion_report = Some(still_report(gyro, Vec3::new(0.0, 0.0, GRAVITY), true));
    assert_eq!(
        e.fuse_accel(&AccelContext { airborne: Some(false), pad_height_m: Some(0.06) }),
        Some(AccelAiding::Still)
    );
    assert_eq!(e.counters().still_blocks, 1);
    // The gyro bias: the window's mean rate, with the window's variance (the per-block sigma over the blocks),
    // then the block's own rate as a measurement of it (the same value: no change, the variance combined).
    assert_eq!(e.bg, gyro);
    let blocks = p.motion.window_blocks as f32;
    let bv = p.still_gyro_sigma_rad_s * p.still_gyro_sigma_rad_s / blocks;
    let gv = p.still_gyro_sigma_rad_s * p.still_gyro_sigma_rad_s;
    for k in 0..3 {
        let want = bv * gv / (bv + gv);
        assert!(
            (e.cov[IBG + k][IBG + k] - want).abs() < 1e-6 * want,
            "{k}: {} {want}",
            e.cov[IBG + k][IBG + k]
        );
    }
    // Zero velocity, each axis (uncorrelated in a new filter): v' = v vv / (P + vv).
    let vv = p.still_velocity_sigma_m_s * p.still_velocity_sigma_m_s;
    for (k, v0) in [0.1f32, -0.2, 0.05].into_iter().enumerate() {
        let want = v0 * vv / (pv + vv);
        assert!((e.v[k] - want).abs() < 1e-6, "v[{k}] {} {want}", e.v[k]);
    }
    // The pad's height.
    let hv = p.ground_height_sigma_m * p.ground_height_sigma_m;
    let want = 0.1 + pz / (pz + hv) * (0.06 - 0.1);
    assert!((e.p.z - want).abs() < 1e-6, "{} {want}", e.p.z);
    // The next window does not reset the bias: a block whose rate differs moves it by the update's gain.
    let bg0 = e.bg;
    let pb = e.cov[IBG][IBG];
    e.motion_report =
        Some(still_report(gyro + Vec3::new(0.004, 0.0, 0.0), Vec3::new(0.0, 0.0, GRAVITY), true));
    e.fuse_accel(&AccelContext { airborne: Some(false), pad_height_m: None });
    let want = bg0.x + pb / (pb + gv) * 0.004;
    assert!((e.bg.x - want).abs() < 1e-6, "{} {want}", e.bg.x);
    assert_eq!(e.counters().still_blocks, 2);
}

/// [`kalman_by_hand`] with the states in `consider` taken into account but not corrected (their gain zero,
/// their own covariance block unchanged).
fn kalman_considering(
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

#[test]
fn the_drag_model_updates_across_the_thrust_axis_with_the_bias_considered() {
    let mut e = with_distinct_covariance();
    e.v = Vec3::new(0.4, -0.3, 0.05);
    e.w = Vec3::new(0.2, 0.1, 0.0);
    e.ba = Vec3::new(0.03, -0.02, 0.01);
    let k = e.params.drag_coeff_per_s;
    let r = e.q.to_mat3();
    let vb = r.tmul_vec(e.v - e.w);
    // The measured specific force: thrust along body z, the modelled drag across it plus the bias, a little off.
    let f = Vec3::new(0.0, 0.0, 9.6) + vb * (-k) + e.ba + Vec3::new(0.02, -0.015, 0.0);
    let f = Vec3::new(f.x, f.y, 9.6);
    let e0 = e.clone();
    let report = MotionReport {
        block: crate::motion::Block { end_us: 50_000, samples: 50, mean_gyro: Vec3::ZERO, mean_accel: f },
        class: MotionClass::ThrustBorne,
        still_window: None,
    };
    e.motion_report = Some(report);
    assert_eq!(
        e.fuse_accel(&AccelContext { airborne: Some(true), pad_height_m: None }),
        Some(AccelAiding::Drag)
    );
    assert_eq!(e.counters().drag_blocks, 1);
    // By hand: rows e1 = z x X = y and e2 = z x y = -x of the body; f_perp = -k R^T (v - w) + b_a.
    let mut p: [[f64; N]; N] = core::array::from_fn(|i| core::array::from_fn(|j| e0.cov[i][j] as f64));
    let mut total = [0.0f64; N];
    let (mut q, mut v, mut w) = (e0.q, e0.v, e0.w);
    for d in [Vec3::Y, -Vec3::X] {
        let r = q.to_mat3();
        let vb = r.tmul_vec(v - w);
        let row_v = r.mul_vec(d) * (-k);
        let row_th = Mat3::skew(vb).tmul_vec(d) * (-k);
        let mut h = [0.0f64; N];
        for i in 0..3 {
            h[IV + i] = row_v[i] as f64;
            h[ITH + i] = row_th[i] as f64;
            h[IBA + i] = d[i] as f64;
        }
        h[IW] = -row_v.x as f64;
        h[IW + 1] = -row_v.y as f64;
        let innov = (d.dot(f) - d.dot(vb * (-k) + e0.ba)) as f64;
        let s = e0.params.drag_sigma_m_s2 as f64;
        let dx = kalman_considering(&mut p, &h, innov, s * s, IBA..IBA + 3);
        for i in 0..N {
            total[i] += dx[i];
        }
        let d3 = |k: usize| Vec3::new(dx[k] as f32, dx[k + 1] as f32, dx[k + 2] as f32);
        q = q.mul(&Quat::from_rotvec(d3(ITH))).normalized();
        v += d3(IV);
        w += Vec3::new(dx[IW] as f32, dx[IW + 1] as f32, 0.0);
    }
    assert_injected(&e0, &e, &total, 1e-4, 1e-4);
    assert_eq!(e.ba, e0.ba, "the bias is considered, not corrected");
    // With the model off (coefficient 0) nothing is fused.
    let mut off = e0.clone();
    off.params.drag_coeff_per_s = 0.0;
    off.motion_report = Some(report);
    assert_eq!(
        off.fuse_accel(&AccelContext { airborne: Some(true), pad_height_m: None }),
        Some(AccelAiding::None)
    );
    assert_eq!(off.cov, e0.cov);
    // Not known to fly, but the block says thrust-borne: the drag model too.
    let mut unknown = e0.clone();
    unknown.motion_report = Some(report);
    assert_eq!(
        unknown.fuse_accel(&AccelContext { airborne: None, pad_height_m: None }),
        Some(AccelAiding::Drag)
    );
}

#[test]
fn carried_by_hand_gravity_is_fused_loosely_and_a_bad_block_is_counted() {
    let mut e = with_distinct_covariance();
    let report = |f: Vec3| MotionReport {
        block: crate::motion::Block { end_us: 50_000, samples: 50, mean_gyro: Vec3::ZERO, mean_accel: f },
        class: MotionClass::GravityDominated,
        still_window: None,
    };
    let g_b = e.q.to_mat3().tmul_vec(Vec3::new(0.0, 0.0, GRAVITY));
    e.motion_report = Some(report(g_b + Vec3::new(0.3, 0.0, 0.0)));
    let ctx = AccelContext { airborne: None, pad_height_m: None };
    let before = e.cov;
    assert_eq!(e.fuse_accel(&ctx), Some(AccelAiding::Gravity));
    assert_eq!(e.counters().accel_rejected, 0);
    assert_ne!(e.cov, before);
    // A block far from gravity's magnitude (beyond 3 handheld sigmas) is refused and counted.
    e.motion_report = Some(report(g_b * 2.0));
    assert_eq!(e.fuse_accel(&ctx), Some(AccelAiding::Gravity));
    assert_eq!(e.counters().accel_rejected, 1);
    // No block finished: nothing.
    assert_eq!(e.fuse_accel(&ctx), None);
}

#[test]
fn the_tilt_alignment_reads_roll_and_pitch_from_one_force_and_keeps_the_yaw() {
    let mut e = with_distinct_covariance();
    let yaw = yaw_of(&e);
    let att = Attitude::new(0.2, -0.15, yaw);
    let f = att.world_from_body().tmul_vec(Vec3::new(0.0, 0.0, GRAVITY));
    e.align_tilt(f);
    let got = Attitude::from_world_from_body(&e.q.to_mat3());
    assert!((got.roll - 0.2).abs() < 1e-5 && (got.pitch + 0.15).abs() < 1e-5, "{got:?}");
    assert!((wrap_pi(got.yaw - yaw)).abs() < 1e-5);
    let var = e.params.initial_tilt_sigma_rad * e.params.initial_tilt_sigma_rad;
    assert_eq!((e.cov[ITH][ITH], e.cov[ITH + 1][ITH + 1]), (var, var));
    assert_eq!((e.cov[ITH][IV], e.cov[IBA][ITH + 1]), (0.0, 0.0));
    // A force too far from gravity (more than 2 m/s^2), or not finite, changes nothing.
    for bad in [f * 1.25, f * 0.75, Vec3::new(f32::NAN, 0.0, 9.8)] {
        let mut b = with_distinct_covariance();
        let (q, cov) = (b.q, b.cov);
        b.align_tilt(bad);
        assert_eq!((b.q, b.cov), (q, cov), "{bad:?}");
    }
    let mut near = with_distinct_covariance();
    let q0 = near.q;
    near.align_tilt(f * (1.0 + 1.9 / GRAVITY));
    assert_ne!(near.q, q0, "within 2 m/s^2");
}
