//! The pilot's RC transmitter in the closed loop (`control_core::pilot`, docs/architecture.md, "The pilot's
//! transmitter"): the simulated transmitter's CRSF frames go through the receiver's driver into the flight code,
//! which flies the simulated vehicle. Taking over from the mission in manual, landing by the mode switch, the
//! kill switch, and RC loss, each asserted on the simulated vehicle.
use sim_host::Scenario;
use sim_host::scenario::{FaultConfig, FaultKind};
use sim_host::sil::{CameraMode, Record, RunStats, Sil};
use sim_host::transmitter::{TxEvent, TxMode};

fn at(at_s: f64) -> TxEvent {
    TxEvent { at_s, ..Default::default() }
}

/// The paper scenario with a receiver on board and the pilot doing `script`; the switches start low with the
/// mode switch at auto (the station flies the mission: it arms at 1 s and takes off at 1.5 s).
fn with_pilot(script: Vec<TxEvent>) -> Scenario {
    let mut s = Scenario::paper();
    s.transmitter.enabled = true;
    let mut events =
        vec![TxEvent { mode: Some(TxMode::Auto), ..at(0.0) }, TxEvent { arm: Some(true), ..at(0.8) }];
    events.extend(script);
    s.transmitter.script = events;
    s.validate().unwrap();
    s
}

fn fly(s: &Scenario, seconds: f64) -> (RunStats, Vec<Record>, Vec<[u32; 4]>) {
    let mut sil = Sil::new(s, 1, CameraMode::Analytic).unwrap();
    sil.log_motor_commands();
    let st = sil.run(seconds, |_| {});
    (st, sil.records().to_vec(), sil.motor_commands().unwrap().to_vec())
}

fn first_mode_at(st: &RunStats, mode: &str) -> Option<f64> {
    st.modes.iter().find(|(_, m)| m == mode).map(|(t, _)| *t)
}

#[test]
fn the_pilot_takes_over_in_manual_steers_and_lands_by_the_mode_switch() {
    // The station's mission flies until 14 s; the pilot takes the sticks, rolls left for a second (towards +x
    // facing the wall: the vehicle's left is the world's +x), centres, and lands with the mode switch.
    let s = with_pilot(vec![
        TxEvent { mode: Some(TxMode::Manual), ..at(14.0) },
        TxEvent { roll: Some(-0.6), ..at(15.0) },
        TxEvent { roll: Some(0.0), ..at(16.0) },
        TxEvent { mode: Some(TxMode::Land), ..at(20.0) },
    ]);
    let (st, recs, _) = fly(&s, 35.0);
    assert!(!st.crashed && !st.wall_contact, "{:?} {:?}", st.crash_reason, st.modes);
    let manual = first_mode_at(&st, "Manual").expect("manual");
    assert!((14.0..14.02).contains(&manual), "manual at {manual} s: {:?}", st.modes);
    assert!(first_mode_at(&st, "Tracking").is_some_and(|t| t < 14.0), "{:?}", st.modes);
    // The roll stick moved the vehicle along +x, and the height held within 10 cm while it did.
    let x_at = |t: f64| recs.iter().find(|r| r.t_s >= t).unwrap().true_p;
    let (p15, p19) = (x_at(15.0), x_at(19.0));
    assert!(p19[0] - p15[0] > 0.2, "moved {:.3} m along x", p19[0] - p15[0]);
    assert!((p19[2] - p15[2]).abs() < 0.1, "height {:.3} -> {:.3}", p15[2], p19[2]);
    let land = first_mode_at(&st, "Landing").expect("landing");
    assert!((20.0..20.02).contains(&land), "{:?}", st.modes);
    assert!(st.landed && st.last_motor_cmd == [0.0; 4], "{:?}", st.modes);
    assert!(st.max_touchdown_speed_m_s < 0.6, "{}", st.max_touchdown_speed_m_s);
}

#[test]
fn the_kill_switch_stops_the_motors_within_a_frame_in_flight() {
    let s = with_pilot(vec![TxEvent { kill: Some(true), ..at(10.0) }]);
    let (st, recs, cmds) = fly(&s, 12.0);
    // Flying before: the motors run and the vehicle is at its height.
    let before = recs.iter().rfind(|r| r.t_s < 9.99).unwrap();
    assert!(before.true_p[2] > 0.6, "{:?}", before.true_p);
    // A control step is 2 ms; the transmitter's next frame (150 Hz) reaches the flight code within 6.7 ms.
    let step_of = |t: f64| (t / 0.002).round() as usize;
    assert!(cmds[step_of(9.99)].iter().all(|c| f32::from_bits(*c) > 300.0));
    for (k, c) in cmds.iter().enumerate().skip(step_of(10.0 + 0.008)) {
        assert_eq!(c.map(f32::from_bits), [0.0; 4], "step {k}");
    }
    assert!(
        st.failsafes.iter().any(|(t, f)| f == "Killed" && (10.0..10.008).contains(t)),
        "{:?}",
        st.failsafes
    );
}

#[test]
fn rc_loss_in_manual_holds_then_lands_and_the_station_s_link_loss_does_not_matter_in_manual() {
    let mut s = with_pilot(vec![TxEvent { mode: Some(TxMode::Manual), ..at(10.0) }]);
    // The station's radio drops from 11 s on (in manual the pilot flies: no link-loss landing), and the
    // transmitter from 13 s: the receiver says lost 0.3 s later, the vehicle holds level for rc.loss_hold_s (1 s)
    // and lands.
    s.faults.push(FaultConfig { start_s: 11.0, duration_s: 30.0, kind: FaultKind::LinkLoss });
    s.faults.push(FaultConfig { start_s: 13.0, duration_s: 30.0, kind: FaultKind::RcLoss });
    s.validate().unwrap();
    let (st, _, _) = fly(&s, 30.0);
    assert!(!st.crashed && !st.wall_contact, "{:?} {:?}", st.crash_reason, st.modes);
    let lost = st.failsafes.iter().find(|(_, f)| f == "RcLost").map(|(t, _)| *t).expect("RcLost");
    assert!((13.29..13.32).contains(&lost), "RC lost at {lost}: {:?}", st.failsafes);
    let land = first_mode_at(&st, "Landing").expect("landing");
    assert!((lost + 0.99..lost + 1.01).contains(&land), "landing at {land}: {:?}", st.modes);
    assert!(!st.failsafes.iter().any(|(_, f)| f == "LinkLost"), "{:?}", st.failsafes);
    assert!(st.landed, "{:?}", st.modes);
}

#[test]
fn with_rc_required_the_mission_lands_when_the_transmitter_is_lost() {
    let mut s = with_pilot(vec![]);
    s.rc.required = true;
    s.faults.push(FaultConfig { start_s: 12.0, duration_s: 30.0, kind: FaultKind::RcLoss });
    s.validate().unwrap();
    let (st, _, _) = fly(&s, 30.0);
    assert!(first_mode_at(&st, "Tracking").is_some_and(|t| t < 12.0), "{:?}", st.modes);
    let land = first_mode_at(&st, "Landing").expect("landing");
    assert!((13.29..13.32).contains(&land), "{:?} {:?}", st.modes, st.failsafes);
    assert!(st.landed && !st.crashed, "{:?}", st.modes);
    // Not required: the same loss changes nothing in the automatic mode.
    let mut s = with_pilot(vec![]);
    s.faults.push(FaultConfig { start_s: 12.0, duration_s: 30.0, kind: FaultKind::RcLoss });
    let (st, _, _) = fly(&s, 20.0);
    assert!(first_mode_at(&st, "Landing").is_none(), "{:?}", st.modes);
}
