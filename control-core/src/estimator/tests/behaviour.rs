//! Behaviour over seconds of samples: a still filter, delayed fixes on a drifting state, alignment at rest
//! and from a tilted start, handling taken for motion, gaps, the drag model's tilt correction in flight, spikes.
use super::*;

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

#[test]
fn ground_alignment_finds_the_tilt() {
    // Resting with 3 degrees of roll: the accelerometer sees gravity tilted.
    let roll = 3f32.to_radians();
    let f = Vec3::new(0.0, GRAVITY * roll.sin(), GRAVITY * roll.cos());
    let mut e = Estimator::new(EstimatorParams::default(), Vec3::new(0.0, 1.3, 0.06));
    // 1.5 s: the window fills in 0.4 s, the rest is confirmed 0.5 s later (`still_confirm_s`).
    run(&mut e, 0, 1.5, ON_PAD, |_| (Vec3::ZERO, f));
    assert_eq!(e.motion_class(), MotionClass::Still);
    let s = e.estimate(1_500_000);
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
fn a_first_sample_shaken_by_vibration_leaves_the_tilt_unknown_until_the_first_block() {
    // Pitched 20 deg on a pad with the rotors running: the first sample reads 6.6 m/s^2 (vibration), too far
    // from gravity to give the tilt (EuRoC MH_01 at 45 s). Until the first block's mean gives it, the
    // estimate is the level starting guess, and its reported uncertainty must cover the 20 deg it may be off.
    let truth = Attitude::new(0.0, -20f32.to_radians(), 0.0);
    let f = truth.world_from_body().tmul_vec(Vec3::new(0.0, 0.0, GRAVITY));
    let mut e = Estimator::new(EstimatorParams::default(), Vec3::ZERO);
    e.predict(&ImuSample { time_us: 1000, gyro_rad_s: [0.0; 3], accel_m_s2: (f * 0.67).to_array() });
    for k in 2..=30u64 {
        e.predict(&ImuSample { time_us: k * 1000, gyro_rad_s: [0.0; 3], accel_m_s2: f.to_array() });
        e.propagate_covariance(k * 1000);
    }
    let s = e.estimate(30_000);
    let err = (s.attitude.pitch - truth.pitch).abs();
    assert!(err > 0.3, "the starting guess is level: {err}");
    assert!(e.tilt_std_rad() >= err, "reported {} rad against an error of {err} rad", e.tilt_std_rad());
    // The first block (50 ms) aligns: the tilt is known, and its uncertainty is the alignment's.
    for k in 31..=60u64 {
        e.predict(&ImuSample { time_us: k * 1000, gyro_rad_s: [0.0; 3], accel_m_s2: f.to_array() });
        e.propagate_covariance(k * 1000);
    }
    let s = e.estimate(60_000);
    assert!((s.attitude.pitch - truth.pitch).abs() < 1e-3, "{}", s.attitude.pitch);
    assert!(e.tilt_std_rad() < 0.1, "{}", e.tilt_std_rad());
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
