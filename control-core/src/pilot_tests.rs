//! Host tests of the pilot's transmitter (`pilot.rs`): the kill switch, the arm switch, the mode switch, manual
//! flight and RC loss, on the kinematic harness of the mode tests (`test_harness.rs`).
use super::*;
use crate::pilot::{ModeSwitch, PilotInput, RcLink};
use crate::test_harness::Harness;

/// Sticks centred, throttle at the centre, the arm switch `arm`, the mode switch `mode`, the link up.
fn sticks(arm: bool, mode: ModeSwitch) -> PilotInput {
    PilotInput { link: RcLink::Ok, roll: 0.0, pitch: 0.0, yaw: 0.0, throttle: 0.5, arm, mode, kill: false }
}

/// Armed by the switch (low, then high) with the mode switch at `mode`, after the estimator's alignment.
fn armed_by_switch(mode: ModeSwitch) -> Harness {
    let mut h = Harness::new();
    h.pilot = Some(sticks(false, mode));
    h.run(1.0);
    assert_eq!(h.mode(), FlightMode::Disarmed);
    h.pilot = Some(sticks(true, mode));
    h.step(None);
    h
}

/// Manual, in the air at about 0.8 m: armed in manual, the throttle up until then, then centred.
fn manual_in_the_air() -> Harness {
    let mut h = armed_by_switch(ModeSwitch::Manual);
    assert_eq!(h.mode(), FlightMode::Manual);
    h.pilot = Some(PilotInput { throttle: 1.0, ..sticks(true, ModeSwitch::Manual) });
    for _ in 0..5000 {
        if h.step(None).estimate.position_m.z > 0.8 {
            break;
        }
    }
    h.pilot = Some(sticks(true, ModeSwitch::Manual));
    h.run(1.0);
    let z = h.out.unwrap().estimate.position_m.z;
    assert!(z > 0.7 && z < 1.2, "{z}");
    h
}

/// `h` with the receiver's switches high in auto, armed and taken off by the station, hovering.
fn hovering_on_the_mission(mut h: Harness) -> Harness {
    h.pilot = Some(sticks(true, ModeSwitch::Auto));
    h.run(1.0);
    assert_eq!(h.command(Command::Arm), Some(CommandResult::Accepted(Command::Arm)));
    assert_eq!(h.command(Command::TakeOff), Some(CommandResult::Accepted(Command::TakeOff)));
    h.run_until(FlightMode::Hover, 20.0);
    h
}

#[test]
fn the_arm_switch_arms_on_its_rising_edge_only_and_disarms_when_low() {
    // High when the receiver is first heard (after the estimator has aligned, so that an arm would be
    // taken): nothing arms, and the station may arm (the switch is high).
    let mut h = Harness::new();
    h.run(1.0);
    h.pilot = Some(sticks(true, ModeSwitch::Auto));
    h.run(0.5);
    assert_eq!(h.mode(), FlightMode::Disarmed);
    // Low: the station's arm is refused; the pilot has the last word.
    h.pilot = Some(sticks(false, ModeSwitch::Auto));
    assert_eq!(h.command(Command::Arm), Some(CommandResult::Refused(Command::Arm, Refusal::ArmSwitchOff)));
    // Low to high arms, in the automatic mode: armed on the ground, waiting for the station's take-off.
    h.pilot = Some(sticks(true, ModeSwitch::Auto));
    let out = h.step(None);
    assert_eq!(out.status.mode, FlightMode::Armed);
    // High to low disarms.
    h.pilot = Some(sticks(false, ModeSwitch::Auto));
    assert_eq!(h.step(None).status.mode, FlightMode::Disarmed);
    // Without a receiver nothing of this applies: the station arms.
    let mut h = Harness::new();
    h.run(1.0);
    assert_eq!(h.command(Command::Arm), Some(CommandResult::Accepted(Command::Arm)));
}

#[test]
fn the_kill_switch_stops_the_motors_in_every_mode_and_keeps_them_stopped() {
    for mode in [ModeSwitch::Auto, ModeSwitch::Manual] {
        let mut h = if mode == ModeSwitch::Auto {
            hovering_on_the_mission(Harness::new())
        } else {
            manual_in_the_air()
        };
        assert!(h.out.unwrap().motors_rad_s.iter().all(|w| *w > 300.0));
        // Killed: the motors stop in that very step.
        h.pilot = Some(PilotInput { kill: true, ..sticks(true, mode) });
        let out = h.step(None);
        assert_eq!((out.status.mode, out.status.failsafe), (FlightMode::Disarmed, Some(Failsafe::Killed)));
        assert_eq!(out.motors_rad_s, [0.0; 4]);
        // While it is high nothing arms: not the arm switch cycled, not the station.
        h.pilot = Some(PilotInput { kill: true, ..sticks(false, mode) });
        h.run(0.2);
        h.pilot = Some(PilotInput { kill: true, ..sticks(true, mode) });
        h.run(0.2);
        assert_eq!(h.mode(), FlightMode::Disarmed);
        assert_eq!(h.command(Command::Arm), Some(CommandResult::Refused(Command::Arm, Refusal::KillSwitch)));
        // A lost link does not unlatch it: the last frame said kill.
        h.pilot = Some(PilotInput { link: RcLink::Lost, ..sticks(true, mode) });
        assert_eq!(h.command(Command::Arm), Some(CommandResult::Refused(Command::Arm, Refusal::KillSwitch)));
        // Kill low: the arm switch, cycled, arms again.
        h.pilot = Some(sticks(false, mode));
        h.run(0.2);
        h.pilot = Some(sticks(true, mode));
        assert_ne!(h.step(None).status.mode, FlightMode::Disarmed);
    }
}

#[test]
fn manual_mode_takes_off_holds_and_turns_on_the_sticks() {
    let mut h = armed_by_switch(ModeSwitch::Manual);
    // On the ground with the throttle at the centre: idle, as armed.
    let idle = h.params_idle();
    for _ in 0..250 {
        let out = h.step(None);
        assert_eq!(out.status.mode, FlightMode::Manual);
        assert_eq!(out.motors_rad_s, [idle; 4]);
    }
    // Throttle up: it climbs at about rc.max_climb_m_s (0.5 m/s).
    h.pilot = Some(PilotInput { throttle: 1.0, ..sticks(true, ModeSwitch::Manual) });
    h.run(1.0);
    let z0 = h.out.unwrap().estimate.position_m.z;
    h.run(1.0);
    let climb = h.out.unwrap().estimate.position_m.z - z0;
    assert!((climb - 0.5).abs() < 0.1, "{climb} m in 1 s");
    // Centred: the height holds.
    h.pilot = Some(sticks(true, ModeSwitch::Manual));
    h.run(1.0);
    let z1 = h.out.unwrap().estimate.position_m.z;
    h.run(2.0);
    assert!((h.out.unwrap().estimate.position_m.z - z1).abs() < 0.03);
    // The sticks' tilt is the attitude reference (rc.max_tilt_rad 0.25 at full stick, the dead band 0.05
    // taken out): half right and a quarter forward.
    h.pilot = Some(PilotInput { roll: 0.5, pitch: 0.25, ..sticks(true, ModeSwitch::Manual) });
    let out = h.step(None);
    let d = |v: f32| (v - 0.05) / 0.95 * 0.25;
    let [r, p] = out.status.law.commanded_tilt_rad;
    assert!((r - d(0.5)).abs() < 1e-5 && (p - d(0.25)).abs() < 1e-5, "{r} {p}");
    // The yaw stick right turns clockwise (the yaw reference falls) at up to rc.max_yaw_rate_rad_s.
    h.pilot = Some(PilotInput { yaw: 1.0, ..sticks(true, ModeSwitch::Manual) });
    let y0 = h.step(None).setpoint.yaw_rad;
    h.run(0.5);
    let dy = geometry::wrap_pi(h.out.unwrap().setpoint.yaw_rad - y0);
    assert!((dy + 0.5).abs() < 0.01, "{dy} rad in 0.5 s");
    // Vision lost for long: no vision failsafe in manual (the pilot flies).
    h.pilot = Some(sticks(true, ModeSwitch::Manual));
    h.vision_on = false;
    h.run(5.0);
    assert_eq!(h.mode(), FlightMode::Manual);
}

#[test]
fn the_mode_switch_hands_over_to_the_mission_and_lands() {
    let mut h = manual_in_the_air();
    let before = h.out.unwrap().estimate.position_m;
    // Auto: the vehicle holds where it is; the station's commands go on from there.
    h.pilot = Some(sticks(true, ModeSwitch::Auto));
    let out = h.step(None);
    assert_eq!(out.status.mode, FlightMode::Hover);
    assert!((out.setpoint.position_m - before).norm() < 0.05, "{:?} {before:?}", out.setpoint.position_m);
    assert_eq!(h.command(Command::StartTracking), Some(CommandResult::Accepted(Command::StartTracking)));
    // Back to manual at once, from any automatic mode.
    h.pilot = Some(sticks(true, ModeSwitch::Manual));
    assert_eq!(h.step(None).status.mode, FlightMode::Manual);
    // In manual the station's mission commands are refused, its land is taken.
    assert_eq!(
        h.command(Command::TakeOff),
        Some(CommandResult::Refused(Command::TakeOff, Refusal::WrongMode))
    );
    // Land: it lands and disarms.
    h.pilot = Some(sticks(true, ModeSwitch::Land));
    assert_eq!(h.step(None).status.mode, FlightMode::Landing);
    h.run_until(FlightMode::Disarmed, 20.0);
    // The arm switch still high arms nothing (no edge).
    h.run(1.0);
    assert_eq!(h.mode(), FlightMode::Disarmed);
}

#[test]
fn rc_loss_in_manual_holds_level_then_lands() {
    let mut h = manual_in_the_air();
    h.pilot = Some(PilotInput { roll: 1.0, ..sticks(true, ModeSwitch::Manual) });
    h.run(0.1);
    // Lost with the stick over: level at once, the height held, for rc.loss_hold_s (1 s).
    h.pilot = Some(PilotInput { link: RcLink::Lost, roll: 1.0, ..sticks(true, ModeSwitch::Manual) });
    let out = h.step(None);
    assert_eq!((out.status.mode, out.status.failsafe), (FlightMode::Manual, Some(Failsafe::RcLost)));
    assert_eq!(out.status.law.commanded_tilt_rad, [0.0, 0.0]);
    h.run(0.9);
    assert_eq!(h.mode(), FlightMode::Manual);
    h.run(0.2);
    assert_eq!(h.mode(), FlightMode::Landing);
    h.run_until(FlightMode::Disarmed, 20.0);
}

#[test]
fn rc_back_within_the_hold_gives_the_vehicle_back_to_the_pilot() {
    let mut h = manual_in_the_air();
    // A receiver that goes quiet (no input at all) counts as lost too.
    h.pilot = None;
    h.run(0.5);
    assert_eq!(h.out.unwrap().status.failsafe, Some(Failsafe::RcLost));
    h.pilot = Some(sticks(true, ModeSwitch::Manual));
    h.run(2.0);
    assert_eq!(h.mode(), FlightMode::Manual);
}

#[test]
fn with_rc_required_arming_needs_the_link_and_losing_it_lands_or_disarms() {
    let required = |p: &mut FlightParams| p.rc.required = true;
    // No receiver: the station's arm is refused.
    let mut h = Harness::with(required);
    h.run(1.0);
    assert_eq!(h.command(Command::Arm), Some(CommandResult::Refused(Command::Arm, Refusal::NoRc)));
    // Armed on the ground, then lost: disarmed at once.
    h.pilot = Some(sticks(true, ModeSwitch::Auto));
    h.run(0.1);
    assert_eq!(h.command(Command::Arm), Some(CommandResult::Accepted(Command::Arm)));
    h.pilot = Some(PilotInput { link: RcLink::Lost, ..sticks(true, ModeSwitch::Auto) });
    let out = h.step(None);
    assert_eq!((out.status.mode, out.status.failsafe), (FlightMode::Disarmed, Some(Failsafe::RcLost)));
    // Hovering on the station's mission: lost, it holds for rc.loss_hold_s and lands.
    let mut h = hovering_on_the_mission(Harness::with(required));
    h.pilot = Some(PilotInput { link: RcLink::Lost, ..sticks(true, ModeSwitch::Auto) });
    h.run(0.9);
    assert_eq!(h.mode(), FlightMode::Hover);
    h.run(0.2);
    assert_eq!(h.mode(), FlightMode::Landing);
    // Not required: losing the transmitter in the automatic mode changes nothing (the station flies).
    let mut h = hovering_on_the_mission(Harness::new());
    h.pilot = Some(PilotInput { link: RcLink::Lost, ..sticks(true, ModeSwitch::Auto) });
    h.run(3.0);
    assert_eq!(h.mode(), FlightMode::Hover);
}

#[test]
fn the_channel_map_and_the_manual_tilt_are_checked() {
    let mut p = FlightParams::paper();
    p.rc.channel_map[6] = 4;
    assert_eq!(p.validate().unwrap_err().field, "rc.channel_map");
    let mut p = FlightParams::paper();
    p.rc.channel_map[0] = 16;
    assert_eq!(p.validate().unwrap_err().field, "rc.channel_map");
    let mut p = FlightParams::paper();
    p.rc.max_tilt_rad = p.gains.max_tilt_rad + 0.01;
    assert_eq!(p.validate().unwrap_err().field, "rc.max_tilt_rad");
    assert_eq!(crate::pilot::deadband(0.04, 0.05), 0.0);
    assert_eq!(crate::pilot::deadband(1.0, 0.05), 1.0);
    assert_eq!(crate::pilot::deadband(-1.0, 0.05), -1.0);
    assert!((crate::pilot::deadband(0.525, 0.05) - 0.5).abs() < 1e-6);
}

/// The battery ([`crate::battery`]) with the mode logic: a 4-cell pack monitored, read every step.
fn with_battery(volts: f32) -> Harness {
    let mut h = Harness::with(|p| p.battery.cells = 4);
    h.battery = Some(crate::battery::BatteryReading { voltage_v: volts, current_a: None });
    h
}

#[test]
fn a_low_battery_refuses_arming_and_a_critical_one_lands_once() {
    // 3.4 V a cell at rest: low, arming refused.
    let mut h = with_battery(13.6);
    h.run(1.0);
    assert_eq!(h.command(Command::Arm), Some(CommandResult::Refused(Command::Arm, Refusal::BatteryLow)));
    // Full: flies; then the pack falls to 3.2 V a cell in the air: after the 2 s low-pass a landing.
    let mut h = with_battery(16.4);
    h.run(1.0);
    assert_eq!(h.command(Command::Arm), Some(CommandResult::Accepted(Command::Arm)));
    assert_eq!(h.command(Command::TakeOff), Some(CommandResult::Accepted(Command::TakeOff)));
    h.run_until(FlightMode::Hover, 20.0);
    h.battery = Some(crate::battery::BatteryReading { voltage_v: 12.8, current_a: None });
    h.run(1.0);
    assert_eq!(h.mode(), FlightMode::Hover, "a short sag is not a landing");
    h.run_until(FlightMode::Landing, 5.0);
    assert_eq!(h.out.unwrap().status.failsafe, Some(Failsafe::BatteryCritical));
    // The landing's lighter load lets the voltage recover: it goes on landing.
    h.battery = Some(crate::battery::BatteryReading { voltage_v: 15.0, current_a: None });
    h.run(1.0);
    assert_eq!(h.mode(), FlightMode::Landing);
    h.run_until(FlightMode::Disarmed, 20.0);
    // Unmonitored (0 cells, the paper's vehicle): the same readings do nothing.
    let mut h = Harness::new();
    h.battery = Some(crate::battery::BatteryReading { voltage_v: 1.0, current_a: None });
    h.run(1.0);
    assert_eq!(h.command(Command::Arm), Some(CommandResult::Accepted(Command::Arm)));
}

#[test]
fn the_pilot_may_take_over_from_a_battery_landing() {
    let mut h = with_battery(16.4);
    h.pilot = Some(sticks(false, ModeSwitch::Auto));
    h.run(1.0);
    h.pilot = Some(sticks(true, ModeSwitch::Auto));
    h.step(None);
    assert_eq!(h.command(Command::TakeOff), Some(CommandResult::Accepted(Command::TakeOff)));
    h.run_until(FlightMode::Hover, 20.0);
    h.battery = Some(crate::battery::BatteryReading { voltage_v: 12.8, current_a: None });
    h.run_until(FlightMode::Landing, 10.0);
    // Manual: the pilot flies (and lands) it; the battery does not take it back.
    h.pilot = Some(sticks(true, ModeSwitch::Manual));
    h.run(2.0);
    assert_eq!(h.mode(), FlightMode::Manual);
}

#[test]
fn manual_demand_scales_each_stick_past_the_dead_band_to_its_limit() {
    let rc = crate::params::RcParams {
        deadband: 0.1,
        max_tilt_rad: 0.3,
        max_climb_m_s: 0.7,
        max_yaw_rate_rad_s: 1.5,
        ..Default::default()
    };
    let full =
        PilotInput { roll: 1.0, pitch: -1.0, yaw: 1.0, throttle: 1.0, ..sticks(true, ModeSwitch::Manual) };
    assert_eq!(crate::pilot::manual_demand(&full, &rc), ([0.3, -0.3], 0.7, -1.5));
    // Half-way past the dead band is half the limit; within it, nothing.
    let half = PilotInput { roll: 0.55, pitch: 0.05, yaw: -0.55, throttle: 0.225, ..full };
    let ([roll, pitch], climb, yaw) = crate::pilot::manual_demand(&half, &rc);
    assert!((roll - 0.15).abs() < 1e-6 && pitch == 0.0, "{roll} {pitch}");
    assert!((climb + 0.35).abs() < 1e-6 && (yaw - 0.75).abs() < 1e-6, "{climb} {yaw}");
}

/// Disarmed on the ground after the estimator's alignment with the arm switch at `arm`, then the kill switch
/// thrown for `steps` control steps.
fn killed_on_the_ground(arm: bool, steps: usize) -> Harness {
    let mut h = Harness::new();
    h.pilot = Some(sticks(arm, ModeSwitch::Auto));
    h.run(1.0);
    h.pilot = Some(PilotInput { kill: true, ..sticks(arm, ModeSwitch::Auto) });
    for _ in 0..steps {
        h.step(None);
    }
    h
}

#[test]
fn the_kill_switch_on_the_ground_latches_too() {
    let out = killed_on_the_ground(false, 1).out.unwrap();
    assert_eq!((out.status.mode, out.status.failsafe), (FlightMode::Disarmed, Some(Failsafe::Killed)));
}

#[test]
fn auto_after_manual_on_the_ground_is_armed_not_hovering() {
    let mut h = armed_by_switch(ModeSwitch::Manual);
    h.run(0.5);
    assert_eq!(h.mode(), FlightMode::Manual);
    h.pilot = Some(sticks(true, ModeSwitch::Auto));
    assert_eq!(h.step(None).status.mode, FlightMode::Armed);
}

#[test]
fn manual_mode_ends_an_rc_loss_failsafe_once_the_link_is_back() {
    let mut h = hovering_on_the_mission(Harness::with(|p| p.rc.required = true));
    h.pilot = Some(PilotInput { link: RcLink::Lost, ..sticks(true, ModeSwitch::Auto) });
    assert_eq!(h.step(None).status.failsafe, Some(Failsafe::RcLost));
    // Back, and the pilot takes over: the failsafe is over.
    h.pilot = Some(sticks(true, ModeSwitch::Manual));
    let out = h.step(None);
    assert_eq!((out.status.mode, out.status.failsafe), (FlightMode::Manual, None));
}

#[test]
fn a_second_kill_after_re_arming_stops_the_motors_again() {
    let mut h = manual_in_the_air();
    h.pilot = Some(PilotInput { kill: true, ..sticks(true, ModeSwitch::Manual) });
    assert_eq!(h.step(None).status.failsafe, Some(Failsafe::Killed));
    // Released, the arm switch cycled: armed again, in manual on the ground, the throttle up.
    h.pilot = Some(sticks(false, ModeSwitch::Manual));
    h.run(0.2);
    h.pilot = Some(PilotInput { throttle: 1.0, ..sticks(true, ModeSwitch::Manual) });
    h.run(1.0);
    assert_eq!(h.mode(), FlightMode::Manual);
    assert!(h.out.unwrap().motors_rad_s.iter().all(|w| *w > 300.0));
    // Flying again: the kill is history, not a failsafe in force (the status had still said `Killed`).
    assert_eq!(h.out.unwrap().status.failsafe, None);
    // Killed again: stopped again in that step.
    h.pilot = Some(PilotInput { kill: true, throttle: 1.0, ..sticks(true, ModeSwitch::Manual) });
    let out = h.step(None);
    assert_eq!((out.status.mode, out.motors_rad_s), (FlightMode::Disarmed, [0.0; 4]));
}

#[test]
fn the_arm_switch_falling_on_a_disarmed_vehicle_changes_nothing() {
    // Disarmed by the kill switch, which is then released with the arm switch still high: the falling arm
    // switch is no disarm command (which would clear the failsafe the kill left).
    let mut h = killed_on_the_ground(true, 50);
    h.pilot = Some(sticks(true, ModeSwitch::Auto));
    let before = h.step(None).status;
    h.pilot = Some(sticks(false, ModeSwitch::Auto));
    let after = h.step(None).status;
    assert_eq!((after.mode, after.failsafe), (FlightMode::Disarmed, before.failsafe));
    assert_eq!(before.failsafe, Some(Failsafe::Killed));
}
