//! `sim-host fly`, run as a user would.
use serde_json::Value;
use std::process::Command;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_sim-host"))
}

#[test]
fn fly_writes_summary_trajectory_and_plots() {
    let out = std::env::temp_dir().join(format!("sim-host-fly-{}", std::process::id()));
    let r = bin()
        .args(["fly", "--camera", "analytic", "--seed", "4", "--duration", "60", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    assert_eq!(r.status.code(), Some(0), "{}", String::from_utf8_lossy(&r.stderr));
    let s: Value = serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    for key in [
        "scenario",
        "seed",
        "sim_time_s",
        "wall_time_s",
        "real_time_factor",
        "crashed",
        "rms_error_m",
        "estimate_rms_error_m",
        "max_tilt_deg",
    ] {
        assert!(s.get(key).is_some(), "summary.json lacks {key}: {s}");
    }
    assert_eq!(s["scenario"], "paper");
    assert_eq!(s["seed"], 4);
    assert_eq!(s["crashed"], false);
    for axis in ["x", "y", "z"] {
        assert!(s["rms_error_m"][axis].as_f64().unwrap() < 0.05);
        assert!(s["estimate_rms_error_m"][axis].as_f64().unwrap() < 0.02);
    }
    // The ground station's blind frames (analytic: out of view or outside the detector's limits) are the
    // vehicle's "no target" frames, but for the frames still on the radio at the end (latency 50 ms).
    let v = &s["vision"];
    let (blind, no_target) = (v["analytic_not_in_view"].as_i64().unwrap(), v["no_target"].as_i64().unwrap());
    assert!(blind > 0 && (blind - no_target).abs() <= 2, "{v}");
    let reasons = v["ground_station_no_target"].as_object().unwrap();
    assert_eq!(reasons.len(), 8, "{v}");
    assert!(reasons.values().all(|n| n == 0), "no detector ran on analytic frames: {v}");
    let csv = std::fs::read_to_string(out.join("trajectory.csv")).unwrap();
    let mut lines = csv.lines();
    let header = lines.next().unwrap();
    assert!(header.starts_with("t_s,true_x_m,true_y_m,true_z_m"));
    let cols = header.split(',').count();
    assert!(lines.clone().count() > 4000);
    assert!(lines.all(|l| l.split(',').count() == cols));
    for p in ["x.png", "y.png", "z.png", "vx.png", "vy.png"] {
        let bytes = std::fs::read(out.join(p)).unwrap();
        assert_eq!(&bytes[1..4], b"PNG", "{p}");
    }
    let stderr = String::from_utf8_lossy(&r.stderr);
    assert!(stderr.contains("x.png"), "the command says where the plots are: {stderr}");
}

#[test]
fn fly_rejects_bad_scenarios_and_options_with_exit_1() {
    let dir = std::env::temp_dir().join(format!("sim-host-fly-bad-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let base = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/scenarios/paper.toml")).unwrap();
    let cases = [
        (base.replace("mass_kg = 0.38", "mass_kg = 0.38\nmass_lb = 1.0"), "mass_lb"),
        (
            base.replacen(
                "k = [178.25, 20.5, 63.73226, 56.084393]",
                "k = [178.25, 20.5, 63.73226, 560.0]",
                1,
            ),
            "gains.roll",
        ),
        (base.replace("y_d_m = 1.30", "y_d_m = -1.0"), "trajectory.y_d_m"),
        (base.replace("latency_s = 0.05", "latency_s = 0.9"), "forward_camera.latency_s"),
    ];
    for (i, (text, field)) in cases.iter().enumerate() {
        assert_ne!(text, &base, "case `{field}` no longer edits the scenario");
        let path = dir.join(format!("bad{i}.toml"));
        std::fs::write(&path, text).unwrap();
        let r = bin()
            .args(["fly", "--camera", "analytic", "--out"])
            .arg(dir.join("o"))
            .arg("--scenario")
            .arg(&path)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&r.stderr);
        assert_eq!(r.status.code(), Some(1), "{field}: {err}");
        assert!(err.contains(field), "the error should name `{field}`: {err}");
    }
    let r = bin().args(["fly", "--camera", "sideways", "--out", "x"]).output().unwrap();
    assert_eq!(r.status.code(), Some(1));
    let r = bin().args(["fly", "--duration", "-3", "--out", "x"]).output().unwrap();
    assert_eq!(r.status.code(), Some(1));
}

#[test]
fn fly_writes_a_log_that_replay_matches_bit_for_bit() {
    let dir = std::env::temp_dir().join(format!("sim-host-replay-{}", std::process::id()));
    let r = bin()
        .args(["fly", "--camera", "analytic", "--duration", "6", "--no-plots", "--seed", "4", "--out"])
        .arg(&dir)
        .output()
        .unwrap();
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let log = dir.join("flight.log");
    let r = bin().arg("replay").arg(&log).output().unwrap();
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(0), "{err}");
    assert!(err.contains("3000 steps") && err.contains("identical"), "{err}");
    // A changed parameter: the differences are reported, not a failure.
    let r = bin().arg("replay").arg(&log).args(["--set", "gains.altitude.a_z1=3"]).output().unwrap();
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(0), "{err}");
    assert!(err.contains("first difference: record"), "{err}");
    // A damaged log: the replay of the intact records runs, the damage is named and it exits 1.
    let mut bytes = std::fs::read(&log).unwrap();
    let n = bytes.len();
    bytes[n - 1000] ^= 0x21;
    let bad = dir.join("bad.log");
    std::fs::write(&bad, &bytes).unwrap();
    let r = bin().arg("replay").arg(&bad).output().unwrap();
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(1), "{err}");
    assert!(err.contains("damaged record at byte"), "{err}");
    // Cut exactly at a record boundary (half the log gone, every remaining record intact): it used to replay
    // as an identical shorter flight with exit 0.
    let whole = std::fs::read(&log).unwrap();
    let cut_at = whole.iter().enumerate().skip(whole.len() / 2).find(|(_, b)| **b == 0).unwrap().0 + 1;
    let cut = dir.join("cut.log");
    std::fs::write(&cut, &whole[..cut_at]).unwrap();
    let r = bin().arg("replay").arg(&cut).output().unwrap();
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(1), "{err}");
    assert!(err.contains("no end-of-log record"), "{err}");
    // Bad options.
    let r = bin().arg("replay").arg(&log).args(["--set", "no.such.param=1"]).output().unwrap();
    assert_eq!(r.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&r.stderr).contains("unknown parameter"));
    // An analytic-camera log has no frames to replay from: refused with the reason.
    let r = bin().arg("replay").arg(&log).arg("--from-frames").output().unwrap();
    assert_eq!(r.status.code(), Some(1));
    assert!(
        String::from_utf8_lossy(&r.stderr).contains("no camera frames"),
        "{}",
        String::from_utf8_lossy(&r.stderr)
    );
    // Replay --out writes a log that replays identically itself.
    let again = dir.join("again.log");
    let r = bin().arg("replay").arg(&log).arg("--out").arg(&again).output().unwrap();
    assert_eq!(r.status.code(), Some(0), "{}", String::from_utf8_lossy(&r.stderr));
    let r = bin().arg("replay").arg(&again).output().unwrap();
    assert_eq!(r.status.code(), Some(0), "{}", String::from_utf8_lossy(&r.stderr));
    // Export: MCAP and CSV, with the topic counts printed.
    let r = bin()
        .arg("export")
        .arg(&log)
        .arg("--mcap")
        .arg(dir.join("f.mcap"))
        .arg("--csv")
        .arg(dir.join("csv"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(0), "{err}");
    assert!(err.contains("/estimate/pose") && err.contains("3000"), "{err}");
    assert!(std::fs::read(dir.join("f.mcap")).unwrap().starts_with(b"\x89MCAP0\r\n"));
    assert!(dir.join("csv").join("motors.csv").is_file());
    let r = bin().arg("export").arg(&log).output().unwrap();
    assert_eq!(r.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&r.stderr).contains("nothing to export"));
    // Import of a folder that is not a dataset.
    let r = bin().args(["import", "euroc"]).arg(&dir).arg("--out").arg(dir.join("x.log")).output().unwrap();
    assert_eq!(r.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&r.stderr).contains("not a EuRoC/ASL dataset folder"));
    let r = bin().args(["import", "euroc", ".", "--out", "x.log", "--imu-axes", "x,x,z"]).output().unwrap();
    assert_eq!(r.status.code(), Some(1));
}

#[test]
fn fly_keeps_no_camera_frames_in_its_log_unless_asked() {
    // The default log holds the vision results, not the frames (a rendered flight with PNG frames writes about
    // 17 MB per simulated second and flies several times slower).
    let dir = std::env::temp_dir().join(format!("sim-host-frames-{}", std::process::id()));
    let r = bin()
        .args(["fly", "--camera", "rendered", "--duration", "1", "--no-plots", "--out"])
        .arg(&dir)
        .output()
        .unwrap();
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let log = sim_host::flightlog::read_log(&dir.join("flight.log")).unwrap();
    assert!(log.damage.is_empty());
    let frames =
        log.records.iter().filter(|(_, r)| matches!(r, sim_host::flightlog::LogRecord::Frame(_))).count();
    let vision = log
        .records
        .iter()
        .filter(|(_, r)| matches!(r, sim_host::flightlog::LogRecord::Link(m) if m.vision().is_some()))
        .count();
    assert_eq!(frames, 0);
    assert!(vision >= 25, "{vision} vision results in 1 s at 30 Hz");
    // Asked for, they are there.
    let r = bin()
        .args(["fly", "--camera", "rendered", "--duration", "1", "--no-plots", "--frames", "png", "--out"])
        .arg(&dir)
        .output()
        .unwrap();
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let log = sim_host::flightlog::read_log(&dir.join("flight.log")).unwrap();
    let frames =
        log.records.iter().filter(|(_, r)| matches!(r, sim_host::flightlog::LogRecord::Frame(_))).count();
    assert!(frames >= 80, "{frames} frames (forward 30 Hz and downward 60 Hz)");
    let _ = std::fs::remove_dir_all(&dir);
}
