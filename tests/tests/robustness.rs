//! Robust flight (docs/robustness.md): the paper mission flown by the flight code under model error, a
//! disturbed compass, lost vision and each injected fault, with the documented reaction asserted.
use sim_host::Scenario;
use sim_host::scenario::{FaultConfig, FaultKind};
use sim_host::sil::{CameraMode, Record, RunStats, Sil};
use vision_core::NoTargetReason;

fn fly(s: &Scenario, seed: u64, mode: CameraMode) -> (RunStats, Vec<Record>) {
    let mut sil = Sil::new(s, seed, mode).unwrap();
    let st = sil.run(s.mission.max_duration_s, |_| {});
    (st, sil.records().to_vec())
}

fn fault(start_s: f64, duration_s: f64, kind: FaultKind) -> FaultConfig {
    FaultConfig { start_s, duration_s, kind }
}

fn with_fault(f: FaultConfig) -> Scenario {
    let mut s = Scenario::paper();
    s.faults.push(f);
    s
}

fn failsafes(st: &RunStats) -> Vec<&str> {
    st.failsafes.iter().map(|(_, f)| f.as_str()).collect()
}

fn visited(st: &RunStats, mode: &str) -> bool {
    st.modes.iter().any(|(_, m)| m == mode)
}

/// The run ended on the floor, disarmed, with the motors stopped, and did not crash or touch the wall.
fn assert_landed_safely(st: &RunStats, recs: &[Record], what: &str) {
    assert!(!st.crashed, "{what}: crashed: {:?}", st.crash_reason);
    assert!(!st.wall_contact, "{what}: wall contact (closest {:.3} m)", st.min_wall_distance_m);
    assert!(st.landed, "{what}: did not land and disarm; modes {:?}", st.modes);
    assert!(!recs.is_empty());
    assert_eq!(st.last_motor_cmd, [0.0; 4], "{what}: motors at the end");
}

/// The mission flown to its end: every sweep pass done.
fn assert_completed(st: &RunStats, s: &Scenario, what: &str) {
    assert_eq!(st.passes_done, 2 * s.trajectory.sweeps as u16, "{what}: passes; modes {:?}", st.modes);
}

/// The largest rate at which the reference moved in flight, horizontally and vertically (m/s).
fn max_setpoint_rates(recs: &[Record]) -> (f64, f64) {
    let (mut h, mut v) = (0.0f64, 0.0f64);
    for w in recs.windows(2) {
        let dt = w[1].t_s - w[0].t_s;
        if dt <= 0.0 || !w[0].mode.airborne() || !w[1].mode.airborne() {
            continue;
        }
        let d = |k: usize| (w[1].des_p[k] - w[0].des_p[k]) as f64;
        h = h.max(d(0).hypot(d(1)) / dt);
        v = v.max(d(2).abs() / dt);
    }
    (h, v)
}

#[test]
fn take_off_completes_and_the_vehicle_lands_for_mass_and_thrust_errors() {
    for (what, mass, thrust) in [
        ("mass 0.85", 0.85, 1.0),
        ("mass 1.20", 1.20, 1.0),
        ("thrust 0.90", 1.0, 0.90),
        ("thrust 1.10", 1.0, 1.10),
    ] {
        let mut s = Scenario::paper();
        s.mismatch.mass_scale = mass;
        s.mismatch.thrust_coeff_scale = thrust;
        let (st, recs) = fly(&s, 3, CameraMode::Analytic);
        eprintln!(
            "{what}: modes {:?}, failsafes {:?}, rms {:?}",
            st.modes.iter().map(|(t, m)| format!("{m}@{t:.1}")).collect::<Vec<_>>(),
            failsafes(&st),
            st.rms_error_m
        );
        assert!(!failsafes(&st).contains(&"TakeOffTimeout"), "{what}: take-off timed out");
        assert!(visited(&st, "Hover") && visited(&st, "Tracking"), "{what}: take-off did not complete");
        assert_completed(&st, &s, what);
        assert_landed_safely(&st, &recs, what);
        // The altitude integral takes the thrust error out: the height is held as in the nominal flight.
        assert!(st.rms_error_m[2] <= 0.03, "{what}: z rms {}", st.rms_error_m[2]);
    }
}

#[test]
fn vision_lost_during_take_off_gives_no_setpoint_step() {
    // The line lost for 1.5 s in the middle of the climb, from a pad 1.0 m from the wall (the case that
    // stepped the height reference from 0.18 to 0.80 m), and with a slow camera.
    let (h_limit, v_limit) = {
        let t = Scenario::paper().trajectory;
        let m = control_core::SETPOINT_RATE_MARGIN as f64;
        (
            t.speed_m_s.max(t.takeoff_speed_m_s) as f64 * m,
            t.takeoff_speed_m_s.max(t.landing_speed_m_s) as f64 * m,
        )
    };
    for (what, y0, latency) in [("pad at 1.3 m", 1.3, 0.05), ("pad at 1.0 m, 0.2 s latency", 1.0, 0.2)] {
        let mut s = with_fault(fault(2.0, 1.5, FaultKind::VisionDropout));
        s.model.start_position_m[1] = y0;
        s.forward_camera.latency_s = latency;
        let (st, recs) = fly(&s, 2, CameraMode::Analytic);
        let (h, v) = max_setpoint_rates(&recs);
        eprintln!(
            "{what}: failsafes {:?}, largest setpoint rate {h:.3} m/s horizontal, {v:.3} m/s vertical",
            failsafes(&st)
        );
        // One record period of slack for the rounding of the 10 ms record times.
        assert!(h <= h_limit * 1.02, "{what}: horizontal setpoint rate {h} > {h_limit}");
        assert!(v <= v_limit * 1.02, "{what}: vertical setpoint rate {v} > {v_limit}");
        assert_completed(&st, &s, what);
        assert_landed_safely(&st, &recs, what);
    }
}

#[test]
fn with_the_line_never_visible_the_vehicle_lands_and_disarms_within_10_s() {
    for mode in [CameraMode::Analytic, CameraMode::Rendered] {
        let mut s = Scenario::paper();
        s.scene.line_visible = false;
        let (st, recs) = fly(&s, 1, mode);
        let what = mode.name();
        let lost = st.failsafes.iter().find(|(_, f)| f == "VisionLost").map(|(t, _)| *t).expect("VisionLost");
        let disarmed = st
            .modes
            .iter()
            .rev()
            .find(|(_, m)| m == "Disarmed")
            .map(|(t, _)| *t)
            .expect("disarmed at the end");
        eprintln!("{what}: vision lost at {lost:.2} s, disarmed at {disarmed:.2} s; modes {:?}", st.modes);
        assert!(
            disarmed > lost && disarmed - lost <= 10.0,
            "{what}: disarmed {:.2} s after the failsafe",
            disarmed - lost
        );
        assert_landed_safely(&st, &recs, what);
        assert!(st.sim_time_s < 30.0, "{what}: the run went on to {} s", st.sim_time_s);
        // Every blind frame is counted with its reason: a blank wall has no red pixels at all.
        match mode {
            CameraMode::Rendered => {
                assert_eq!(st.ground_no_target.total(), st.frames as u64, "{what}");
                assert_eq!(st.ground_no_target.get(NoTargetReason::NoRedPixels), st.frames as u64, "{what}");
                assert_eq!(st.analytic_not_in_view, 0, "{what}");
            }
            CameraMode::Analytic => {
                assert_eq!(st.analytic_not_in_view, st.frames as u64, "{what}");
                assert_eq!(st.ground_no_target.total(), 0, "{what}");
            }
        }
    }
}

#[test]
fn a_45_degree_compass_disturbance_in_flight_leaves_the_mission_intact() {
    for offset in [45.0, -45.0] {
        let s = with_fault(fault(
            8.0,
            1000.0,
            FaultKind::MagDisturbance { heading_offset_deg: offset, field_scale: 1.0 },
        ));
        let (st, recs) = fly(&s, 4, CameraMode::Analytic);
        let what = format!("{offset} deg");
        eprintln!(
            "{what}: magnetometer rejected {}, failsafes {:?}",
            st.estimator.mag_rejected,
            failsafes(&st)
        );
        assert!(st.estimator.mag_rejected > 100, "{what}: the compass was not refused");
        assert!(failsafes(&st).is_empty(), "{what}: {:?}", failsafes(&st));
        assert_completed(&st, &s, &what);
        assert_landed_safely(&st, &recs, &what);
        assert!(st.rms_error_m.iter().all(|e| *e <= 0.04), "{what}: rms {:?}", st.rms_error_m);
    }
    // From the pad: the first heading is the compass's, 45 deg off; the vehicle keeps its heading until
    // vision gives it, and the mission completes.
    let s = with_fault(fault(
        0.0,
        1000.0,
        FaultKind::MagDisturbance { heading_offset_deg: 45.0, field_scale: 1.0 },
    ));
    let (st, recs) = fly(&s, 5, CameraMode::Analytic);
    assert_completed(&st, &s, "45 deg from the pad");
    assert_landed_safely(&st, &recs, "45 deg from the pad");
}

#[test]
fn a_short_vision_dropout_holds_then_resumes_the_sweep() {
    let s = with_fault(fault(20.0, 1.5, FaultKind::VisionDropout));
    let (st, recs) = fly(&s, 1, CameraMode::Analytic);
    assert_eq!(failsafes(&st), ["VisionLost"]);
    let hold = st.modes.iter().position(|(_, m)| m == "VisionHold").expect("hold");
    assert_eq!(st.modes[hold + 1].1, "Tracking", "resumed: {:?}", st.modes);
    assert_completed(&st, &s, "dropout 1.5 s");
    assert_landed_safely(&st, &recs, "dropout 1.5 s");
}

#[test]
fn a_long_vision_dropout_lands() {
    let s = with_fault(fault(20.0, 1000.0, FaultKind::VisionDropout));
    let (st, recs) = fly(&s, 1, CameraMode::Analytic);
    assert_eq!(failsafes(&st), ["VisionLost", "VisionLostLanding"]);
    assert_landed_safely(&st, &recs, "vision gone for good");
}

#[test]
fn a_frozen_camera_is_refused_and_held_like_a_lost_one() {
    let s = with_fault(fault(20.0, 2.0, FaultKind::VisionFreeze));
    let (st, recs) = fly(&s, 1, CameraMode::Analytic);
    eprintln!("frozen frames {}, failsafes {:?}", st.frames_frozen, failsafes(&st));
    // About 30 frames per second repeated: all but the first refused.
    assert!(st.frames_frozen >= 50, "frozen frames refused: {}", st.frames_frozen);
    assert_eq!(failsafes(&st), ["VisionLost"]);
    assert_completed(&st, &s, "frozen 2 s");
    assert_landed_safely(&st, &recs, "frozen 2 s");
    assert!(
        st.estimate_rms_error_m.iter().all(|e| *e <= 0.02),
        "no frozen fix was fused: {:?}",
        st.estimate_rms_error_m
    );
}

#[test]
fn without_flow_the_mission_flies_on_vision() {
    let s = with_fault(fault(10.0, 15.0, FaultKind::FlowDropout));
    let (nominal, _) = fly(&Scenario::paper(), 1, CameraMode::Analytic);
    let (st, recs) = fly(&s, 1, CameraMode::Analytic);
    // 15 s at 60 Hz of flow never reached the flight code.
    assert!(nominal.flow.pairs - st.flow.pairs >= 800, "{} vs {}", st.flow.pairs, nominal.flow.pairs);
    assert!(failsafes(&st).is_empty(), "{:?}", failsafes(&st));
    assert_completed(&st, &s, "flow dropout");
    assert_landed_safely(&st, &recs, "flow dropout");
}

#[test]
fn a_short_link_loss_holds_a_long_one_lands() {
    let s = with_fault(fault(20.0, 1.5, FaultKind::LinkLoss));
    let (st, recs) = fly(&s, 1, CameraMode::Analytic);
    assert!(st.link_dropped > 0);
    assert_eq!(failsafes(&st), ["VisionLost"], "the fixes come over the link");
    assert_completed(&st, &s, "link loss 1.5 s");
    assert_landed_safely(&st, &recs, "link loss 1.5 s");
    let s = with_fault(fault(20.0, 1000.0, FaultKind::LinkLoss));
    let (st, recs) = fly(&s, 1, CameraMode::Analytic);
    assert!(failsafes(&st).contains(&"LinkLost"), "{:?}", failsafes(&st));
    assert_landed_safely(&st, &recs, "link lost for good");
}

#[test]
fn corrupted_link_frames_are_dropped_by_their_checksum() {
    let s = with_fault(fault(10.0, 20.0, FaultKind::LinkCorruption { byte_error_rate: 0.01 }));
    let (st, recs) = fly(&s, 1, CameraMode::Analytic);
    eprintln!("link frames dropped {}, failsafes {:?}", st.link_dropped, failsafes(&st));
    assert!(st.link_dropped > 100, "dropped {}", st.link_dropped);
    assert_completed(&st, &s, "1 % byte errors");
    assert_landed_safely(&st, &recs, "1 % byte errors");
}

#[test]
fn imu_spikes_are_removed_and_counted() {
    let s = with_fault(fault(
        10.0,
        20.0,
        FaultKind::ImuSpike { rate_hz: 10.0, accel_m_s2: 80.0, gyro_rad_s: 20.0 },
    ));
    let (st, recs) = fly(&s, 1, CameraMode::Analytic);
    eprintln!(
        "spikes {}, rms {:?}, tilt error rms {:.2} deg",
        st.estimator.imu_spikes, st.rms_error_m, st.tilt_error_rms_deg
    );
    // 10 per second for 20 s.
    assert!(st.estimator.imu_spikes >= 150, "spikes {}", st.estimator.imu_spikes);
    assert_completed(&st, &s, "spikes");
    assert_landed_safely(&st, &recs, "spikes");
    assert!(st.rms_error_m.iter().all(|e| *e <= 0.04), "rms {:?}", st.rms_error_m);
}

#[test]
fn an_imu_bias_step_is_learned() {
    let s = with_fault(fault(
        15.0,
        1000.0,
        FaultKind::ImuBiasStep { gyro_rad_s: [0.02, -0.02, 0.02], accel_m_s2: [0.2, -0.2, 0.2] },
    ));
    let (st, recs) = fly(&s, 1, CameraMode::Analytic);
    eprintln!(
        "rms {:?}, tilt error rms {:.2} deg max {:.2}",
        st.rms_error_m, st.tilt_error_rms_deg, st.max_tilt_error_deg
    );
    assert_completed(&st, &s, "bias step");
    assert_landed_safely(&st, &recs, "bias step");
    assert!(st.rms_error_m.iter().all(|e| *e <= 0.04), "rms {:?}", st.rms_error_m);
}

#[test]
fn a_saturating_gyro_is_counted() {
    // The gyro's range lowered to 0.3 rad/s: the turns at the ends of the sweep exceed it.
    let s = with_fault(fault(10.0, 30.0, FaultKind::GyroSaturation { limit_rad_s: 0.3 }));
    let (st, recs) = fly(&s, 1, CameraMode::Analytic);
    eprintln!("gyro clipped {}", st.estimator.gyro_clipped);
    assert!(st.estimator.gyro_clipped > 0, "no clipping counted");
    assert_landed_safely(&st, &recs, "gyro saturation");
}

#[test]
fn a_weak_rotor_is_taken_by_the_attitude_integrals() {
    let s = with_fault(fault(15.0, 1000.0, FaultKind::MotorDegradation { motor: 1, thrust_scale: 0.8 }));
    let (st, recs) = fly(&s, 1, CameraMode::Analytic);
    eprintln!("rms {:?}", st.rms_error_m);
    assert_completed(&st, &s, "rotor 1 at 80 %");
    assert_landed_safely(&st, &recs, "rotor 1 at 80 %");
    assert!(st.rms_error_m.iter().all(|e| *e <= 0.04), "rms {:?}", st.rms_error_m);
}

#[test]
fn a_lost_rotor_is_a_crash_detected_with_the_motors_cut() {
    let s = with_fault(fault(20.0, 1000.0, FaultKind::MotorLoss { motor: 2 }));
    let (st, recs) = fly(&s, 1, CameraMode::Analytic);
    eprintln!("failsafes {:?}, crash {:?}", st.failsafes, st.crash_reason);
    assert!(failsafes(&st).contains(&"ExcessiveTilt"), "{:?}", failsafes(&st));
    let cut = st.failsafes.iter().find(|(_, f)| f == "ExcessiveTilt").map(|(t, _)| *t).unwrap();
    assert!(cut > 20.0 && cut < 21.0, "cut at {cut} s");
    assert_eq!(st.last_motor_cmd, [0.0; 4], "motors cut");
    assert!(
        recs.iter().filter(|r| r.t_s > cut + 0.01).all(|r| r.motor_cmd == [0.0; 4]),
        "and never restarted"
    );
    assert!(st.modes.last().is_some_and(|(_, m)| m == "Emergency"), "{:?}", st.modes);
}

#[test]
fn the_analytic_camera_refuses_what_it_cannot_model() {
    let mut s = Scenario::paper();
    s.scene.floor_texture_contrast = 0.05;
    s.forward_camera.blur_sigma_px = 1.0;
    let e = Sil::new(&s, 1, CameraMode::Analytic).err().expect("refused").to_string();
    assert!(e.contains("scene.floor_texture_contrast") && e.contains("forward_camera.blur_sigma_px"), "{e}");
    assert!(Sil::new(&s, 1, CameraMode::Rendered).is_ok());
}

/// The largest height error of the estimate between `from_s` and `to_s` (m).
fn max_height_error(recs: &[Record], from_s: f64, to_s: f64) -> f64 {
    recs.iter()
        .filter(|r| r.t_s >= from_s && r.t_s <= to_s)
        .map(|r| (r.est_p[2] as f64 - r.true_p[2]).abs())
        .fold(0.0, f64::max)
}

#[test]
fn the_barometer_holds_the_height_through_a_blind_spell() {
    // Five seconds without vision or flow (a radio loss) on an IMU three times noisier than configured: the
    // accelerometer alone lets the height estimate drift by decimetres (the vehicle climbed away while its
    // estimate held, then landed hard from the height it did not know it had); the barometer bounds it.
    let mut s = with_fault(fault(20.0, 5.0, FaultKind::LinkLoss));
    for v in [&mut s.imu.accel_noise_density, &mut s.imu.gyro_noise_density, &mut s.imu.accel_bias_sigma_m_s2]
    {
        *v *= 3.0;
    }
    let mut worst_with = 0.0f64;
    let mut worst_without = 0.0f64;
    for seed in 1..=4 {
        let (st, recs) = fly(&s, seed, CameraMode::Analytic);
        assert_landed_safely(&st, &recs, &format!("seed {seed} with the barometer"));
        worst_with = worst_with.max(max_height_error(&recs, 20.0, 25.0));
        let mut no_baro = s.clone();
        no_baro.imu.baro_rate_hz = 0.0;
        let (_, recs) = fly(&no_baro, seed, CameraMode::Analytic);
        worst_without = worst_without.max(max_height_error(&recs, 20.0, 25.0));
    }
    eprintln!(
        "largest height error while blind: {worst_with:.3} m with the barometer, {worst_without:.3} m without"
    );
    assert!(worst_with < 0.15, "with the barometer the height estimate was {worst_with:.3} m off");
    assert!(
        worst_without > 1.5 * worst_with,
        "the barometer made no difference ({worst_without:.3} m without)"
    );
}
