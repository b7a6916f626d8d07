//! The flight battery in the closed loop (`control_core::battery`, docs/architecture.md, "The battery"): the
//! simulated pack (`[battery_model]`) sags under the rotors' load and drains; the flight code reads it at 50 Hz,
//! warns when low and lands when critical.
use sim_host::Scenario;
use sim_host::flightlog::LogRecord;
use sim_host::sil::{CameraMode, RunStats, Sil};

/// The paper scenario on a 3-cell 1300 mAh pack charged to `charge`, monitored by the flight code with the
/// sag added back from the measured current.
fn on_battery(charge: f64) -> Scenario {
    let mut s = Scenario::paper();
    s.battery_model.enabled = true;
    s.battery_model.initial_charge = charge;
    s.battery.cells = 3;
    s.battery.resistance_ohm = s.battery_model.resistance_ohm as f32;
    s.validate().unwrap();
    s
}

fn fly(s: &Scenario) -> RunStats {
    let mut sil = Sil::new(s, 1, CameraMode::Analytic).unwrap();
    sil.run(s.mission.max_duration_s, |_| {})
}

#[test]
fn a_full_pack_flies_the_mission_and_the_vehicle_reports_it() {
    let s = on_battery(1.0);
    let out = std::env::temp_dir().join(format!("wlq-battery-{}", std::process::id()));
    let opts = sim_host::fly::FlyOptions {
        scenario: s.clone(),
        seed: 1,
        duration_s: None,
        camera: CameraMode::Analytic,
        out: out.clone(),
        plots: false,
        fc: sim_host::sil::FcChoice::Sil,
        log: true,
        frames: sim_host::flightlog::FramePolicy::Drop,
        serve: None,
        mavlink: None,
        live: None,
        real_time: None,
    };
    let st = sim_host::fly::fly(&opts, |_, _| {}).unwrap().stats;
    let log = out.join(sim_host::flightlog::LOG_FILE);
    system_tests::check_flight(&st, &s, "on a full battery");
    assert!(st.landed);
    assert!(!st.failsafes.iter().any(|(_, f)| f.starts_with("Battery")), "{:?}", st.failsafes);
    let b = st.battery.unwrap();
    // About 12 A for the minute of flight: some 15 % of 1300 mAh; the sag under load below the 12.6 V of a
    // full pack at rest.
    assert!(b.final_charge > 0.8 && b.final_charge < 0.9, "{b:?}");
    assert!(b.min_voltage_v < 12.3 && b.min_voltage_v > 11.0, "{b:?}");
    // The log holds the readings the flight code stepped on and the vehicle's once-a-second reports.
    let read = sim_host::flightlog::read_log(&log).unwrap();
    let readings = read.records.iter().filter(|(_, r)| matches!(r, LogRecord::Battery(_))).count();
    let reports: Vec<_> = read
        .records
        .iter()
        .filter_map(|(_, r)| match r {
            LogRecord::Downlink(protocol::Downlink::Battery(b)) => Some(*b),
            _ => None,
        })
        .collect();
    let t = st.sim_time_s;
    assert!((readings as f64 - 50.0 * t).abs() < 3.0, "{readings} readings in {t} s");
    assert!((reports.len() as f64 - t).abs() < 2.0, "{} reports in {t} s", reports.len());
    assert!(reports.iter().all(|b| b.level == control_core::battery::BatteryLevel::Ok));
    // It replays bit for bit (the readings go back into the flight code).
    let r = sim_host::replay::replay(&read, &sim_host::replay::ReplayOptions::default()).unwrap();
    assert!(r.identical(), "{r:?}");
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn a_pack_that_runs_low_lands_the_vehicle_before_it_sags_out_of_the_air() {
    // 12 % left at take-off: critical (3.3 V a cell with the sag added back) about half a minute later.
    let s = on_battery(0.12);
    let st = fly(&s);
    let critical = st.failsafes.iter().find(|(_, f)| f == "BatteryCritical").map(|(t, _)| *t);
    let critical = critical.unwrap_or_else(|| panic!("no battery landing: {:?}", st.failsafes));
    let tracking = st.modes.iter().find(|(_, m)| m == "Tracking").map(|(t, _)| *t).unwrap();
    assert!(critical > tracking, "{critical} {tracking}");
    assert!(st.modes.iter().any(|(t, m)| m == "Landing" && (*t - critical).abs() < 0.01), "{:?}", st.modes);
    assert!(st.landed && !st.crashed && !st.wall_contact, "{:?} {:?}", st.modes, st.crash_reason);
    assert!(st.passes_done < 2 * s.trajectory.sweeps as u16, "the mission was cut short");
    let b = st.battery.unwrap();
    eprintln!("critical at {critical:.2} s; modes {:?}; {b:?}; end {:.2} s", st.modes, st.sim_time_s);
    assert!(b.final_charge > 0.0, "{b:?}");
    // A pack this low refuses to arm: the station's arm at 1 s is refused, nothing flies.
    let st = fly(&on_battery(0.03));
    assert!(!st.modes.iter().any(|(_, m)| m == "Armed"), "{:?}", st.modes);
}
