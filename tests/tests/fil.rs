//! Firmware in the loop: the firmware's ELF in QEMU flies the paper scenario in lockstep with the simulator, and
//! its motor commands are those of the flight code compiled into the simulator, bit for bit.
//!
//! Needs `qemu-system-arm` and the firmware built with `cd firmware && cargo build --release --features fil
//! --target-dir target/fil` (`.ci/run` does both). Without them the test says what is missing and passes,
//! unless `REQUIRE_QEMU=1` (set in CI), which makes a missing piece a failure.
use sim_host::Scenario;
use sim_host::fil::{QEMU, QemuOptions, STEP_BUDGET_INSTRUCTIONS};
use sim_host::sil::{CameraMode, FcChoice, Sil};
use std::path::PathBuf;
use system_tests::{check_flight, check_partial_flight};

/// The tests that start QEMU run one at a time (one checks that its run leaves no pipe directory behind).
static QEMU_RUNS: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn elf() -> PathBuf {
    match std::env::var_os("FIL_ELF") {
        Some(p) => PathBuf::from(p),
        None => PathBuf::from(env!("CARGO_MANIFEST_DIR"))
            .join("../firmware/target/fil/thumbv7em-none-eabihf/release/firmware"),
    }
}

/// Whether the test can run here; panics when `REQUIRE_QEMU=1` and it cannot.
fn available() -> bool {
    let required = std::env::var("REQUIRE_QEMU").is_ok_and(|v| v == "1");
    let qemu = std::process::Command::new(QEMU).arg("--version").output().is_ok_and(|o| o.status.success());
    let missing = if !qemu {
        Some(format!("{QEMU} is not installed"))
    } else if !elf().exists() {
        Some(format!("no firmware ELF at {} (build it with --features fil)", elf().display()))
    } else {
        None
    };
    match missing {
        None => true,
        Some(why) if required => panic!("REQUIRE_QEMU=1 but {why}"),
        Some(why) => {
            eprintln!("skipped: {why}");
            false
        }
    }
}

/// How long to fly: `FIL_SECONDS` (seconds, or `full`); the whole paper flight by default (since the firmware
/// in the loop talks over semihosting pipes it runs several times faster than real time).
fn seconds(scenario: &Scenario) -> (f64, bool) {
    match std::env::var("FIL_SECONDS").ok().as_deref() {
        Some("full") | None => (scenario.mission.max_duration_s, true),
        Some(v) => (v.parse().expect("FIL_SECONDS: seconds or `full`"), false),
    }
}

#[test]
fn firmware_in_qemu_flies_like_the_simulator_bit_for_bit() {
    if !available() {
        return;
    }
    let _one = QEMU_RUNS.lock().unwrap_or_else(|e| e.into_inner());
    let scenario = Scenario::paper();
    let (seconds, full) = seconds(&scenario);
    let fly = |fc: &FcChoice| {
        let mut sil = Sil::with_fc(&scenario, 3, CameraMode::Analytic, fc).unwrap();
        sil.log_motor_commands();
        let st = sil.run(seconds, |_| {});
        (st, sil.motor_commands().unwrap().to_vec())
    };
    let (host, host_cmds) = fly(&FcChoice::Sil);
    let t0 = std::time::Instant::now();
    let (fw, fw_cmds) = fly(&FcChoice::Qemu(QemuOptions::new(elf())));
    let wall = t0.elapsed().as_secs_f64();
    assert!(fw.fc_error.is_none(), "{:?}", fw.fc_error);
    let cost = fw.fc_cost.clone().expect("the firmware's step costs");
    eprintln!(
        "{} control steps over {:.1} s in {wall:.1} s of wall time ({:.1}x real time); firmware step mean {:.0} \
         instructions, max {} at {:.2} s; {} pose solves, mean {:.0} instructions, {:.1} % of the core; {}",
        fw_cmds.len(),
        fw.sim_time_s,
        fw.sim_time_s / wall,
        cost.mean_instructions,
        cost.max_instructions,
        cost.max_at_s,
        cost.solves,
        cost.solve_mean_instructions,
        100.0 * cost.background_cpu_share,
        cost.stack_report.as_deref().unwrap_or("no stack report")
    );
    assert_eq!(host_cmds.len(), fw_cmds.len(), "both ran the same number of steps");
    if let Some(k) = host_cmds.iter().zip(&fw_cmds).position(|(a, b)| a != b) {
        panic!(
            "motor commands differ first at control step {k} (t = {:.3} s): simulator {:?}, firmware {:?}",
            (k + 1) as f64 * 0.002,
            host_cmds[k].map(f32::from_bits),
            fw_cmds[k].map(f32::from_bits)
        );
    }
    // The same commands fly the same flight, within the closed-loop issue's bounds.
    assert_eq!(host.rms_error_m, fw.rms_error_m);
    assert!(cost.solves > 0 && fw.frames_solved as u64 >= cost.solves - 1, "{cost:?} {fw:?}");
    if full {
        check_flight(&fw, &scenario, "firmware in QEMU, seed 3");
        assert!(fw.landed);
    } else {
        check_partial_flight(&fw, &scenario, "firmware in QEMU, seed 3");
        assert!(fw.passes_done >= 1, "the first sweep is flown: {fw:?}");
    }
    assert!(
        cost.max_instructions <= STEP_BUDGET_INSTRUCTIONS,
        "the step's worst case {} instructions exceeds the budget {STEP_BUDGET_INSTRUCTIONS}",
        cost.max_instructions
    );
    assert!(cost.stack_report.is_some_and(|s| s.contains("free=")));
}

/// The keyed link's cost on the Cortex-M4 (docs/security.md): instructions per frame of each kind, and what
/// the default rates take of the core.
#[test]
fn the_keyed_link_costs_per_frame_in_qemu() {
    if !available() {
        return;
    }
    let _one = QEMU_RUNS.lock().unwrap_or_else(|e| e.into_inner());
    let mut fc = sim_host::fil::QemuFc::start(&QemuOptions::new(elf())).unwrap();
    let c = fc.auth_cost().unwrap();
    fc.finish().unwrap();
    // A second at the default rates: 30 line and 60 flow measurements and about 12 other frames (time sync,
    // heartbeats) opened; 25 telemetry messages and 10 time-sync answers sealed.
    let per_s = 30 * c.open[0] as u64
        + 60 * c.open[1] as u64
        + 12 * c.open[2] as u64
        + 25 * c.seal[0] as u64
        + 10 * c.seal[1] as u64;
    let share = per_s as f64 / 168e6;
    eprintln!(
        "keyed link on the Cortex-M4, instructions per frame: handshake {}, open vision {} flow {} command {}, seal \
         telemetry {} ack {}; {per_s} a second at the default rates, {:.2} % of the core",
        c.handshake,
        c.open[0],
        c.open[1],
        c.open[2],
        c.seal[0],
        c.seal[1],
        100.0 * share
    );
    assert_eq!(c.failures, 0, "{c:?}");
    // The most one control period can bring (a line and a flow measurement arrive, telemetry leaves) is
    // within one step's budget (STEP_BUDGET_INSTRUCTIONS, 20 % of the period) on its own; with the step's own
    // worst case beside it, it would not be, so the firmware must authenticate outside the timed step
    // (docs/security.md).
    let worst_period = c.open[0] + c.open[1] + c.seal[0];
    assert!(worst_period < STEP_BUDGET_INSTRUCTIONS, "{worst_period} instructions in one period");
}

/// A firmware that never answers on the pipes (the `qemu` variant, which runs its own loop and exits) stops the
/// run with an error quoting QEMU's output, and the run's directory with its pipes is removed.
#[test]
fn a_firmware_that_does_not_speak_the_lockstep_is_an_error_and_leaves_nothing() {
    if !available() {
        return;
    }
    let _one = QEMU_RUNS.lock().unwrap_or_else(|e| e.into_inner());
    let qemu_elf = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../firmware/target/qemu/thumbv7em-none-eabihf/release/firmware");
    if !qemu_elf.exists() {
        assert!(std::env::var("REQUIRE_QEMU").is_err(), "REQUIRE_QEMU=1 but no {}", qemu_elf.display());
        eprintln!("skipped: no {} (build it with --features qemu)", qemu_elf.display());
        return;
    }
    let pipes = || -> Vec<_> {
        std::fs::read_dir(std::env::temp_dir())
            .unwrap()
            .filter_map(|e| e.ok())
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .filter(|n| n.starts_with(&format!("wlq-fil-{}-", std::process::id())))
            .collect()
    };
    let err = match sim_host::fil::QemuFc::start(&QemuOptions::new(&qemu_elf)) {
        Ok(_) => panic!("the qemu variant answered the lockstep"),
        Err(e) => format!("{e:#}"),
    };
    assert!(err.contains("the firmware stopped answering") && err.contains("qemu variant"), "{err}");
    assert_eq!(pipes(), Vec::<String>::new(), "the run's directory is removed");
}

/// A scenario whose flight configuration differs from the firmware's built-in one in every part (gains, the
/// estimator, the trajectory, the failsafes, the line, the camera) flies in QEMU after the upload, bit for bit
/// as the flight code in this process flies it.
#[test]
fn a_scenario_with_other_gains_flies_in_qemu_after_the_upload() {
    if !available() {
        return;
    }
    let _one = QEMU_RUNS.lock().unwrap_or_else(|e| e.into_inner());
    let mut s = Scenario::paper();
    s.name = "other-gains".into();
    s.gains.altitude.a_z1 *= 1.2;
    s.gains.altitude.a_z2 *= 1.1;
    s.gains.roll.b[2] *= 0.9;
    s.gains.pitch.b[2] *= 0.9;
    s.estimator.accel_noise *= 1.5;
    s.trajectory.speed_m_s = 0.2;
    s.trajectory.y_d_m = 1.2;
    s.trajectory.z_d_m = 0.85;
    s.failsafe.vision_land_after_s = 4.0;
    s.scene.line_x_end_m = 2.0;
    s.trajectory.x_range_m = [0.0, 2.0];
    s.forward_camera.fx_px = 330.0;
    s.forward_camera.fy_px = 330.0;
    s.validate().unwrap();
    assert_ne!(s.flight_config(), flight_core::FlightConfig::paper());
    let seconds = 30.0;
    let fly = |fc: &FcChoice| {
        let mut sil = Sil::with_fc(&s, 5, CameraMode::Analytic, fc).unwrap();
        sil.log_motor_commands();
        let st = sil.run(seconds, |_| {});
        (st, sil.motor_commands().unwrap().to_vec())
    };
    let (host, host_cmds) = fly(&FcChoice::Sil);
    let (fw, fw_cmds) = fly(&FcChoice::Qemu(QemuOptions::new(elf())));
    assert!(fw.fc_error.is_none(), "{:?}", fw.fc_error);
    assert_eq!(host_cmds.len(), fw_cmds.len());
    if let Some(k) = host_cmds.iter().zip(&fw_cmds).position(|(a, b)| a != b) {
        panic!("motor commands differ first at control step {k}");
    }
    assert_eq!(host.rms_error_m, fw.rms_error_m);
    check_partial_flight(&fw, &s, "firmware in QEMU, other gains");
    assert!(fw.passes_done >= 1, "{fw:?}");
    eprintln!("other gains in QEMU: {} steps bit for bit, rms {:?}", fw_cmds.len(), fw.rms_error_m);
}

/// The pilot's transmitter and the battery through the firmware: the mission, the pilot's manual take-over with
/// a stick input, and the landing by the mode switch, on a simulated battery, bit for bit with the flight code
/// in this process.
#[test]
fn the_pilot_s_transmitter_flies_the_firmware_as_it_flies_the_simulator() {
    use sim_host::transmitter::{TxEvent, TxMode};
    if !available() {
        return;
    }
    let _one = QEMU_RUNS.lock().unwrap_or_else(|e| e.into_inner());
    let mut s = Scenario::paper();
    s.transmitter.enabled = true;
    let at = |at_s: f64| TxEvent { at_s, ..Default::default() };
    s.transmitter.script = vec![
        TxEvent { mode: Some(TxMode::Auto), ..at(0.0) },
        TxEvent { arm: Some(true), ..at(0.8) },
        TxEvent { mode: Some(TxMode::Manual), ..at(12.0) },
        TxEvent { roll: Some(-0.5), throttle: Some(0.7), ..at(13.0) },
        TxEvent { roll: Some(0.0), throttle: Some(0.5), ..at(14.0) },
        TxEvent { mode: Some(TxMode::Land), ..at(16.0) },
    ];
    // On a simulated battery read by the flight code (its readings go to the firmware too), charged so that
    // it warns but does not land.
    s.battery_model.enabled = true;
    s.battery_model.initial_charge = 0.3;
    s.battery.cells = 3;
    s.validate().unwrap();
    let fly = |fc: &FcChoice| {
        let mut sil = Sil::with_fc(&s, 2, CameraMode::Analytic, fc).unwrap();
        sil.log_motor_commands();
        let st = sil.run(25.0, |_| {});
        (st, sil.motor_commands().unwrap().to_vec())
    };
    let (host, host_cmds) = fly(&FcChoice::Sil);
    let (fw, fw_cmds) = fly(&FcChoice::Qemu(QemuOptions::new(elf())));
    assert!(fw.fc_error.is_none(), "{:?}", fw.fc_error);
    assert!(host.modes.iter().any(|(_, m)| m == "Manual") && host.landed, "{:?}", host.modes);
    assert_eq!(host_cmds.len(), fw_cmds.len());
    if let Some(k) = host_cmds.iter().zip(&fw_cmds).position(|(a, b)| a != b) {
        panic!("motor commands differ first at control step {k}");
    }
    assert_eq!(host.modes, fw.modes);
}
