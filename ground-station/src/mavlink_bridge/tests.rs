use super::*;
use control_core::Refusal;
use control_core::estimator::StateEstimate;
use control_core::laws::Setpoint;
use geometry::Mat3;
use geometry::frames::Attitude;

fn telemetry(mode: FlightMode, att: Attitude, pos: Vec3) -> Telemetry {
    let r_wb = att.world_from_body();
    let estimate = StateEstimate {
        time_us: 12_345_678,
        position_m: pos,
        velocity_m_s: Vec3::new(0.3, -0.1, 0.05),
        attitude: att,
        q: Quat::from_mat3(&r_wb),
        rates_rad_s: Vec3::new(0.01, 0.02, 0.03),
        ..Default::default()
    };
    Telemetry {
        time_us: 12_345_678,
        mode,
        failsafe: None,
        estimate,
        setpoint: Setpoint::default(),
        motors_rad_s: [0.0; 4],
        fix_age_s: 0.0,
        step_cost: 0,
    }
}

/// The rotation of a quaternion applied to `v`.
fn rotate(q: Quat, v: [f32; 3]) -> [f32; 3] {
    q.to_mat3().mul_vec(Vec3::from_array(v)).to_array()
}

/// `Rx(pi)`: NED from our navigation frame, FRD from FLU.
const FLIP_YZ: Mat3 = Mat3 { m: [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]] };

fn q_of(att: Attitude) -> Quat {
    Quat::from_mat3(&att.world_from_body())
}

fn close(a: f32, b: f32) -> bool {
    (a - b).abs() < 1e-5
}

#[test]
fn level_facing_the_wall_is_level_facing_north() {
    let q = frd_in_ned(q_of(Attitude::default()));
    assert!(close(q.w, 1.0) && close(q.x, 0.0) && close(q.y, 0.0) && close(q.z, 0.0), "{q:?}");
}

#[test]
fn roll_keeps_its_sign_pitch_and_yaw_change_theirs() {
    for (att, want) in [
        (Attitude::new(0.2, 0.0, 0.0), (0.2, 0.0, 0.0)),
        (Attitude::new(0.0, 0.15, 0.0), (0.0, -0.15, 0.0)),
        (Attitude::new(0.0, 0.0, 10f32.to_radians()), (0.0, 0.0, -(10f32.to_radians()))),
        (Attitude::new(0.1, -0.2, 0.3), (0.1, 0.2, -0.3)),
    ] {
        let (r, p, y) = euler_ned(q_of(att));
        assert!(close(r, want.0) && close(p, want.1) && close(y, want.2), "{att:?}: {r} {p} {y}");
    }
}

#[test]
fn the_quaternion_rotates_body_vectors_as_ours_does() {
    // For a spread of attitudes: a body vector, taken to the world frame by our attitude and then to NED,
    // equals the same vector in FRD taken to NED by the MAVLink quaternion.
    let mut s = 0x2545_f491_u32;
    let mut next = || {
        s ^= s << 13;
        s ^= s >> 17;
        s ^= s << 5;
        (s as f32 / u32::MAX as f32) * 2.0 - 1.0
    };
    for _ in 0..200 {
        let att = Attitude::new(next() * 1.5, next() * 1.5, next() * 3.1);
        let q_wb = q_of(att);
        let q = frd_in_ned(q_wb);
        assert!(q.w >= 0.0);
        let v = Vec3::new(next(), next(), next());
        let via_ours = ned_from_world(q_wb.rotate(v));
        let via_mav = rotate(q, frd_from_flu(v));
        for k in 0..3 {
            assert!((via_ours[k] - via_mav[k]).abs() < 1e-5, "{att:?} {v:?}: {via_ours:?} vs {via_mav:?}");
        }
        // And the frame flip is the same as FLIP_YZ on both sides.
        let flipped = FLIP_YZ
            .mul_mat(&geometry::frames::WORLD_FROM_NAV.transpose())
            .mul_mat(&q_wb.to_mat3())
            .mul_mat(&FLIP_YZ);
        let m = q.to_mat3();
        for i in 0..3 {
            for j in 0..3 {
                assert!((flipped.m[i][j] - m.m[i][j]).abs() < 1e-5);
            }
        }
    }
}

#[test]
fn position_and_velocity_in_ned() {
    assert_eq!(ned_from_world(Vec3::new(1.0, 1.3, 0.8)), [-1.3, -1.0, -0.8]);
    assert_eq!(frd_from_flu(Vec3::new(0.1, 0.2, 0.3)), [0.1, -0.2, -0.3]);
    let mut b = Bridge::new();
    let out =
        b.telemetry(&telemetry(FlightMode::Hover, Attitude::new(0.0, 0.0, 0.1), Vec3::new(1.0, 1.3, 0.8)));
    let lp = out
        .iter()
        .find_map(|m| if let MavMessage::LOCAL_POSITION_NED(d) = m { Some(d.clone()) } else { None })
        .unwrap();
    assert_eq!((lp.time_boot_ms, lp.x, lp.y, lp.z), (12_345, -1.3, -1.0, -0.8));
    assert_eq!((lp.vx, lp.vy, lp.vz), (0.1, -0.3, -0.05));
    let at = out
        .iter()
        .find_map(|m| if let MavMessage::ATTITUDE(d) = m { Some(d.clone()) } else { None })
        .unwrap();
    assert!(close(at.yaw, -0.1), "{at:?}");
    assert_eq!((at.rollspeed, at.pitchspeed, at.yawspeed), (0.01, -0.02, -0.03));
    assert!(out.iter().any(|m| matches!(m, MavMessage::ATTITUDE_QUATERNION(_))));
}

#[test]
fn heartbeat_carries_the_mode_and_the_armed_flag() {
    let mut b = Bridge::new();
    let MavMessage::HEARTBEAT(h) = b.heartbeat() else { panic!() };
    assert_eq!(h.system_status, mav::MavState::MAV_STATE_BOOT);
    assert_eq!(h.mavtype, mav::MavType::MAV_TYPE_QUADROTOR);
    b.telemetry(&telemetry(FlightMode::Disarmed, Attitude::default(), Vec3::ZERO));
    let MavMessage::HEARTBEAT(h) = b.heartbeat() else { panic!() };
    assert!(!h.base_mode.contains(mav::MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED));
    assert_eq!((h.custom_mode, h.system_status), (0, mav::MavState::MAV_STATE_STANDBY));
    let out = b.telemetry(&telemetry(FlightMode::Tracking, Attitude::default(), Vec3::ZERO));
    assert!(out.iter().any(|m| matches!(m, MavMessage::STATUSTEXT(_))), "mode change announced");
    let MavMessage::HEARTBEAT(h) = b.heartbeat() else { panic!() };
    assert!(h.base_mode.contains(mav::MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED));
    assert!(h.base_mode.contains(mav::MavModeFlag::MAV_MODE_FLAG_CUSTOM_MODE_ENABLED));
    assert_eq!((h.custom_mode, h.system_status), (4, mav::MavState::MAV_STATE_ACTIVE));
    let mut t = telemetry(FlightMode::VisionHold, Attitude::default(), Vec3::ZERO);
    t.failsafe = Some(Failsafe::VisionLost);
    let out = b.telemetry(&t);
    let texts: Vec<_> = out.iter().filter(|m| matches!(m, MavMessage::STATUSTEXT(_))).collect();
    assert_eq!(texts.len(), 2, "failsafe and mode change: {out:?}");
    let MavMessage::HEARTBEAT(h) = b.heartbeat() else { panic!() };
    assert_eq!(h.system_status, mav::MavState::MAV_STATE_CRITICAL);
    // The same failsafe again is not announced again.
    assert!(!b.telemetry(&t).iter().any(|m| matches!(m, MavMessage::STATUSTEXT(_))));
    for (m, n) in [
        (FlightMode::Disarmed, 0),
        (FlightMode::Armed, 1),
        (FlightMode::TakeOff, 2),
        (FlightMode::Hover, 3),
        (FlightMode::Tracking, 4),
        (FlightMode::VisionHold, 5),
        (FlightMode::Landing, 6),
        (FlightMode::Emergency, 7),
    ] {
        assert_eq!(custom_mode(m), n);
    }
}

#[test]
fn heartbeat_and_status_once_a_second() {
    let mut b = Bridge::new();
    assert_eq!(b.tick(0).len(), 2);
    assert!(b.tick(999_999).is_empty());
    let out = b.tick(1_000_000);
    assert!(matches!(out[0], MavMessage::HEARTBEAT(_)) && matches!(out[1], MavMessage::SYS_STATUS(_)));
    b.set_link_errors(7);
    let out = b.tick(2_000_000);
    let MavMessage::SYS_STATUS(s) = &out[1] else { panic!() };
    assert_eq!(s.errors_comm, 7);
    assert_eq!(s.onboard_control_sensors_health, s.onboard_control_sensors_present);
}

fn long(command: mav::MavCmd, p1: f32, p2: f32) -> MavMessage {
    MavMessage::COMMAND_LONG(mav::COMMAND_LONG_DATA {
        target_system: 1,
        target_component: 1,
        command,
        param1: p1,
        param2: p2,
        ..Default::default()
    })
}

fn acks(out: &[MavMessage]) -> Vec<(mav::MavCmd, mav::MavResult)> {
    out.iter()
        .filter_map(|m| if let MavMessage::COMMAND_ACK(a) = m { Some((a.command, a.result)) } else { None })
        .collect()
}

#[test]
fn commands_map_to_ours_and_are_acknowledged_with_the_vehicle_s_answer() {
    use mav::MavCmd as C;
    let mut b = Bridge::new();
    for (m, want) in [
        (long(C::MAV_CMD_COMPONENT_ARM_DISARM, 1.0, 0.0), Request::Command(Command::Arm)),
        (long(C::MAV_CMD_COMPONENT_ARM_DISARM, 0.0, 0.0), Request::Command(Command::Disarm)),
        (long(C::MAV_CMD_NAV_TAKEOFF, 0.0, 0.0), Request::Command(Command::TakeOff)),
        (long(C::MAV_CMD_NAV_LAND, 0.0, 0.0), Request::Command(Command::Land)),
        (long(C::MAV_CMD_DO_SET_MODE, 1.0, 4.0), Request::Command(Command::StartTracking)),
        (long(C::MAV_CMD_DO_SET_MODE, 1.0, 3.0), Request::Command(Command::StopTracking)),
        (long(C::MAV_CMD_DO_SET_MODE, 1.0, 6.0), Request::Command(Command::Land)),
    ] {
        let (req, replies) = b.take(255, &m, 0);
        assert_eq!(req, vec![want], "{m:?}");
        assert!(replies.is_empty(), "acknowledged only when the vehicle answers: {replies:?}");
    }
    // The vehicle accepts the take-off: the ack names MAV_CMD_NAV_TAKEOFF.
    let out = b.command_result(CommandResult::Accepted(Command::TakeOff));
    assert_eq!(acks(&out), vec![(C::MAV_CMD_NAV_TAKEOFF, mav::MavResult::MAV_RESULT_ACCEPTED)]);
    // A second answer for the same command has nothing to acknowledge.
    assert!(acks(&b.command_result(CommandResult::Accepted(Command::TakeOff))).is_empty());
    // Refusals: mode-dependent ones are temporary, the others denied, each with a STATUSTEXT.
    let out = b.command_result(CommandResult::Refused(Command::Arm, Refusal::NotLevel));
    assert_eq!(
        acks(&out),
        vec![(C::MAV_CMD_COMPONENT_ARM_DISARM, mav::MavResult::MAV_RESULT_TEMPORARILY_REJECTED)]
    );
    assert!(out.iter().any(|m| matches!(m, MavMessage::STATUSTEXT(_))));
    let out = b.command_result(CommandResult::Refused(Command::Disarm, Refusal::NoLink));
    assert_eq!(acks(&out), vec![(C::MAV_CMD_COMPONENT_ARM_DISARM, mav::MavResult::MAV_RESULT_DENIED)]);
    // Land was asked twice (NAV_LAND, then DO_SET_MODE 6): the later request is the one acknowledged.
    let out = b.command_result(CommandResult::Accepted(Command::Land));
    assert_eq!(acks(&out), vec![(C::MAV_CMD_DO_SET_MODE, mav::MavResult::MAV_RESULT_ACCEPTED)]);
    // Unanswered commands are given up after ACK_WAIT_US and counted.
    assert!(b.tick(ACK_WAIT_US - 1).iter().all(|m| !matches!(m, MavMessage::COMMAND_ACK(_))));
    assert_eq!(b.counters().unanswered_commands, 0);
    b.tick(ACK_WAIT_US);
    assert_eq!(b.counters().unanswered_commands, 2, "StartTracking and StopTracking");
    assert_eq!(b.counters().taken, 7);
}

#[test]
fn force_disarm_is_the_kill_and_unknown_commands_are_unsupported() {
    use mav::MavCmd as C;
    let mut b = Bridge::new();
    let (req, out) = b.take(255, &long(C::MAV_CMD_COMPONENT_ARM_DISARM, 0.0, FORCE_DISARM_MAGIC), 0);
    assert_eq!(req, vec![Request::Kill]);
    assert_eq!(acks(&out), vec![(C::MAV_CMD_COMPONENT_ARM_DISARM, mav::MavResult::MAV_RESULT_ACCEPTED)]);
    for m in [
        long(C::MAV_CMD_NAV_RETURN_TO_LAUNCH, 0.0, 0.0),
        long(C::MAV_CMD_DO_SET_MODE, 1.0, 7.0),
        long(C::MAV_CMD_DO_SET_MODE, 0.0, 4.0),
    ] {
        let (req, out) = b.take(255, &m, 0);
        assert!(req.is_empty());
        assert_eq!(acks(&out).len(), 1);
        assert_eq!(acks(&out)[0].1, mav::MavResult::MAV_RESULT_UNSUPPORTED);
    }
    assert_eq!(b.counters().unsupported_commands, 3);
    // Another system's command and a heartbeat are ignored, not acted on.
    let mut other = long(C::MAV_CMD_NAV_LAND, 0.0, 0.0);
    if let MavMessage::COMMAND_LONG(c) = &mut other {
        c.target_system = 2;
    }
    let (req, out) = b.take(255, &other, 0);
    assert!(req.is_empty() && out.is_empty());
    let hb = Bridge::new().heartbeat();
    assert!(b.take(255, &hb, 0).0.is_empty());
    assert_eq!(b.counters().ignored, 2);
}

fn name16(s: &str) -> mavlink::types::CharArray<16> {
    let mut b = [0u8; 16];
    b[..s.len()].copy_from_slice(s.as_bytes());
    b.into()
}

#[test]
fn parameters_by_short_name_and_index() {
    let mut b = Bridge::new();
    let list = MavMessage::PARAM_REQUEST_LIST(mav::PARAM_REQUEST_LIST_DATA {
        target_system: 1,
        target_component: 1,
    });
    let (req, _) = b.take(255, &list, 0);
    assert_eq!(req.len(), ParamId::ALL.len());
    assert!(req.iter().zip(ParamId::ALL).all(|(r, id)| *r == Request::ParamGet(id)));
    let read = |index: i16, name: &str| {
        MavMessage::PARAM_REQUEST_READ(mav::PARAM_REQUEST_READ_DATA {
            param_index: index,
            target_system: 1,
            target_component: 1,
            param_id: name16(name),
        })
    };
    assert_eq!(b.take(255, &read(-1, "TrajectoryYd"), 0).0, vec![Request::ParamGet(ParamId::TrajectoryYd)]);
    assert_eq!(b.take(255, &read(2, ""), 0).0, vec![Request::ParamGet(ParamId::ALL[2])]);
    assert!(b.take(255, &read(-1, "NoSuchParam"), 0).0.is_empty());
    assert!(b.take(255, &read(500, ""), 0).0.is_empty());
    assert_eq!(b.counters().unknown_params, 2);
    let set = |name: &str, v: f32| {
        MavMessage::PARAM_SET(mav::PARAM_SET_DATA {
            param_value: v,
            target_system: 1,
            target_component: 1,
            param_id: name16(name),
            param_type: mav::MavParamType::MAV_PARAM_TYPE_REAL32,
        })
    };
    assert_eq!(
        b.take(255, &set("TrajectorySpeed", 0.2), 0).0,
        vec![Request::ParamSet(ParamId::TrajectorySpeed, 0.2)]
    );
    let (req, out) = b.take(255, &set("Bogus", 1.0), 0);
    assert!(req.is_empty() && matches!(out[..], [MavMessage::STATUSTEXT(_)]));
    assert_eq!(b.counters().unknown_params, 3);
    assert_eq!(b.counters().taken, 7, "a list, four reads and two sets, each taken");
    // The vehicle's reply: PARAM_VALUE with the name, index and count; a refusal adds a STATUSTEXT.
    let out =
        b.param_reply(ParamReply { id: ParamId::TrajectorySpeed, value: 0.2, outcome: ParamOutcome::Ok });
    let [MavMessage::PARAM_VALUE(v)] = &out[..] else { panic!("{out:?}") };
    assert_eq!(param_id_str(&v.param_id), "TrajectorySpeed");
    assert_eq!(
        v.param_index as usize,
        ParamId::ALL.iter().position(|&p| p == ParamId::TrajectorySpeed).unwrap()
    );
    assert_eq!((v.param_count as usize, v.param_value), (ParamId::ALL.len(), 0.2));
    let out = b.param_reply(ParamReply {
        id: ParamId::TrajectorySpeed,
        value: 0.25,
        outcome: ParamOutcome::Refused,
    });
    assert!(matches!(out[..], [MavMessage::STATUSTEXT(_), MavMessage::PARAM_VALUE(_)]));
}

#[test]
fn parameter_requests_go_one_at_a_time_with_retries() {
    let mut q = ParamQueue::default();
    assert_eq!(q.next(0), None);
    for id in [ParamId::TrajectoryYd, ParamId::TrajectoryZd, ParamId::TrajectoryYd] {
        q.push(Request::ParamGet(id));
    }
    q.push(Request::Kill);
    assert_eq!(q.len(), 2, "duplicates and non-parameter requests are not queued");
    assert!(!q.is_empty());
    assert_eq!(q.next(0), Some(Uplink::ParamGet(ParamId::TrajectoryYd)));
    assert_eq!(q.len(), 2, "one in flight, one waiting");
    assert_eq!(q.next(1000), None, "waits for the answer");
    q.answered(ParamId::TrajectoryZd);
    assert_eq!(q.next(2000), None, "another parameter's answer does not count");
    q.answered(ParamId::TrajectoryYd);
    assert_eq!(q.next(3000), Some(Uplink::ParamGet(ParamId::TrajectoryZd)));
    // Unanswered: sent again after PARAM_RETRY_US, given up after PARAM_TRIES.
    assert_eq!(q.next(3000 + PARAM_RETRY_US - 1), None);
    assert_eq!(q.next(3000 + PARAM_RETRY_US), Some(Uplink::ParamGet(ParamId::TrajectoryZd)));
    assert_eq!(q.next(3000 + 2 * PARAM_RETRY_US), Some(Uplink::ParamGet(ParamId::TrajectoryZd)));
    assert_eq!((q.resent, q.given_up), (2, 0));
    assert_eq!(q.next(3000 + 3 * PARAM_RETRY_US), None);
    assert_eq!((q.given_up, q.len()), (1, 0));
    q.push(Request::ParamSet(ParamId::TrajectorySpeed, 0.2));
    assert_eq!(q.next(10_000_000), Some(Uplink::ParamSet { id: ParamId::TrajectorySpeed, value: 0.2 }));
    q.answered(ParamId::TrajectorySpeed);
    assert!(q.is_empty());
}

#[test]
fn status_names_the_sensors_and_what_a_failsafe_took() {
    use mav::MavSysStatusSensor as S;
    let status = |b: &mut Bridge| match b.tick(u64::MAX / 2).pop() {
        Some(MavMessage::SYS_STATUS(s)) => s,
        other => panic!("{other:?}"),
    };
    let mut b = Bridge::new();
    let s = status(&mut b);
    for sensor in [
        S::MAV_SYS_STATUS_SENSOR_3D_GYRO,
        S::MAV_SYS_STATUS_SENSOR_3D_ACCEL,
        S::MAV_SYS_STATUS_SENSOR_VISION_POSITION,
        S::MAV_SYS_STATUS_SENSOR_OPTICAL_FLOW,
        S::MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION,
        S::MAV_SYS_STATUS_SENSOR_Z_ALTITUDE_CONTROL,
        S::MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL,
        S::MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS,
    ] {
        assert!(s.onboard_control_sensors_present.contains(sensor), "{sensor:?}");
        assert!(s.onboard_control_sensors_health.contains(sensor), "{sensor:?}");
    }
    // No battery monitoring: the "not sent" values.
    assert_eq!((s.voltage_battery, s.current_battery, s.battery_remaining), (u16::MAX, -1, -1));
    for (f, lost) in [
        (Failsafe::VisionLost, S::MAV_SYS_STATUS_SENSOR_VISION_POSITION),
        (Failsafe::ImuFault, S::MAV_SYS_STATUS_SENSOR_3D_GYRO | S::MAV_SYS_STATUS_SENSOR_3D_ACCEL),
        (Failsafe::EstimatorFault, S::MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION),
    ] {
        let mut b = Bridge::new();
        let mut t = telemetry(FlightMode::Hover, Attitude::default(), Vec3::ZERO);
        t.failsafe = Some(f);
        b.telemetry(&t);
        let s = status(&mut b);
        assert_eq!(s.onboard_control_sensors_present - s.onboard_control_sensors_health, lost, "{f:?}");
    }
    // A failsafe on the ground is not critical: standby.
    let mut b = Bridge::new();
    let mut t = telemetry(FlightMode::Disarmed, Attitude::default(), Vec3::ZERO);
    t.failsafe = Some(Failsafe::VisionLost);
    b.telemetry(&t);
    let MavMessage::HEARTBEAT(h) = b.heartbeat() else { panic!() };
    assert_eq!(h.system_status, mav::MavState::MAV_STATE_STANDBY);
}

#[test]
fn requests_for_another_system_are_ignored_and_odd_arm_values_unsupported() {
    use mav::MavCmd as C;
    let mut b = Bridge::new();
    let other = [
        MavMessage::PARAM_REQUEST_LIST(mav::PARAM_REQUEST_LIST_DATA {
            target_system: 9,
            target_component: 1,
        }),
        MavMessage::PARAM_REQUEST_READ(mav::PARAM_REQUEST_READ_DATA {
            param_index: 0,
            target_system: 9,
            target_component: 1,
            param_id: name16(""),
        }),
        MavMessage::PARAM_SET(mav::PARAM_SET_DATA {
            param_value: 0.2,
            target_system: 9,
            target_component: 1,
            param_id: name16("TrajectorySpeed"),
            param_type: mav::MavParamType::MAV_PARAM_TYPE_REAL32,
        }),
    ];
    for m in &other {
        assert_eq!(b.take(255, m, 0), (vec![], vec![]), "{m:?}");
    }
    assert_eq!((b.counters().ignored, b.counters().taken), (3, 0));
    // Broadcast (target 0) is ours.
    let list = MavMessage::PARAM_REQUEST_LIST(mav::PARAM_REQUEST_LIST_DATA {
        target_system: 0,
        target_component: 0,
    });
    assert_eq!(b.take(255, &list, 0).0.len(), ParamId::ALL.len());
    // ARM_DISARM with param1 neither 0 nor 1 is not a command, whatever param2 says.
    let (req, out) = b.take(255, &long(C::MAV_CMD_COMPONENT_ARM_DISARM, 0.5, FORCE_DISARM_MAGIC), 0);
    assert!(req.is_empty());
    assert_eq!(acks(&out), vec![(C::MAV_CMD_COMPONENT_ARM_DISARM, mav::MavResult::MAV_RESULT_UNSUPPORTED)]);
    assert_eq!(b.counters().taken, 2);
}

#[test]
fn the_battery_report_fills_sys_status_and_a_falling_level_is_announced() {
    use control_core::battery::{BatteryLevel, BatteryStatus};
    let mut b = Bridge::new();
    let sys = |b: &Bridge| match b.sys_status() {
        MavMessage::SYS_STATUS(s) => (s.voltage_battery, s.current_battery),
        other => panic!("{other:?}"),
    };
    assert_eq!(sys(&b), (u16::MAX, -1), "no report yet: not sent");
    let ok =
        BatteryStatus { voltage_v: 11.84, cell_v: 3.95, current_a: Some(12.345), level: BatteryLevel::Ok };
    assert!(b.battery(&ok).is_empty());
    assert_eq!(sys(&b), (11_840, 1_235));
    let low = BatteryStatus { voltage_v: 10.6, cell_v: 3.55, current_a: None, level: BatteryLevel::Low };
    let texts = b.battery(&low);
    assert_eq!(texts.len(), 1);
    assert!(
        matches!(&texts[0], MavMessage::STATUSTEXT(t) if t.severity == mav::MavSeverity::MAV_SEVERITY_WARNING)
    );
    assert!(b.battery(&low).is_empty(), "said once");
    assert_eq!(sys(&b), (10_600, -1));
    let critical = BatteryStatus { level: BatteryLevel::Critical, ..low };
    let texts = b.battery(&critical);
    assert!(
        matches!(&texts[0], MavMessage::STATUSTEXT(t) if t.severity == mav::MavSeverity::MAV_SEVERITY_CRITICAL)
    );
}
