//! The vision fix and the compass: the whole-fix gate, refusals in a row and the reset they cause, the first
//! fix, the heading's resets, the compass's initialisation, correction and learned offset.
use super::*;

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

#[test]
fn the_compass_initialises_then_corrects_and_learns_its_offset_while_vision_holds_the_heading() {
    let p = EstimatorParams { mag_heading_sigma_rad: 1e-3, ..EstimatorParams::default() };
    let mut e = Estimator::new(p, Vec3::ZERO);
    e.q = Quat::from_mat3(&Attitude::new(0.1, -0.05, 0.5).world_from_body());
    assert_eq!(e.fuse_mag(Vec3::new(f32::NAN, 0.0, 0.0)), FuseOutcome::Invalid);
    assert_eq!(e.fuse_mag(field_reading(&e, 0.3)), FuseOutcome::Stale, "before the tilt is aligned");
    // Aligned as the accelerometer's first block does it (the same tilt, its uncertainty the alignment's).
    e.align_tilt(e.q.to_mat3().tmul_vec(Vec3::new(0.0, 0.0, GRAVITY)));
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
