//! A MAVLink ground control station (pymavlink, `tests/peers/mavlink_gcs.py`) commands the virtual vehicle
//! through `sim-host station --mavlink udp:127.0.0.1:PORT`: heartbeat, telemetry converted to NED / FRD and
//! compared with the vehicle's own telemetry in the station's flight log, the parameter list, a parameter set
//! and read back, arm, take-off and land by COMMAND_LONG with their COMMAND_ACKs.
//!
//! Needs a Python with pymavlink: `WLQ_PYTHON` (default `python3`). Without it the test skips with the reason,
//! unless `REQUIRE_PYMAVLINK=1` (set by CI), which makes it a failure.
mod common;

use common::{Killed, read_json, start_vehicle, wait};
use std::collections::HashMap;
use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::Duration;

/// The tests here fly in real time: one at a time, so that they do not slow each other down.
static REAL_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn one_at_a_time() -> std::sync::MutexGuard<'static, ()> {
    REAL_TIME.lock().unwrap_or_else(|e| e.into_inner())
}

/// The Python to run the peer with, or why there is none.
fn python() -> Option<String> {
    let py = std::env::var("WLQ_PYTHON").unwrap_or_else(|_| "python3".into());
    let ok = Command::new(&py)
        .args(["-c", "import pymavlink"])
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success());
    if ok {
        return Some(py);
    }
    let why = format!("{py} has no pymavlink (pip install pymavlink; set WLQ_PYTHON)");
    if std::env::var("REQUIRE_PYMAVLINK").is_ok_and(|v| v == "1") {
        panic!("REQUIRE_PYMAVLINK=1 but {why}");
    }
    eprintln!("SKIPPED: {why}");
    None
}

/// The rows of a CSV export by column name.
fn csv(path: &Path) -> Vec<HashMap<String, String>> {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut lines = text.lines();
    let head: Vec<String> = lines.next().unwrap().split(',').map(String::from).collect();
    lines.map(|l| head.iter().cloned().zip(l.split(',').map(String::from)).collect()).collect()
}

fn wrap(a: f64) -> f64 {
    (a + std::f64::consts::PI).rem_euclid(2.0 * std::f64::consts::PI) - std::f64::consts::PI
}

#[test]
fn pymavlink_sees_and_commands_the_virtual_vehicle_through_the_station() {
    let Some(py) = python() else { return };
    let _serial = one_at_a_time();
    let dir = std::env::temp_dir().join(format!("mavlink-gcs-{}", std::process::id()));
    std::fs::remove_dir_all(&dir).ok();
    std::fs::create_dir_all(&dir).unwrap();
    let (mut vehicle, ports) = start_vehicle(
        &dir.join("vehicle"),
        &["--no-plots", "--duration", "90", "--seed", "2", "--connect-timeout", "30"],
    );
    let seen_path = dir.join("gcs.json");
    let (mut gcs, port) = start_peer(&py, &seen_path);
    let mut station = Killed(
        Command::new(env!("CARGO_BIN_EXE_sim-host"))
            .args([
                "station",
                "--link",
                &ports["link"],
                "--forward",
                &ports["forward"],
                "--down",
                &ports["down"],
            ])
            .args(["--no-key", "--script", "manual", "--duration", "80"])
            .args(["--mavlink", &format!("udp:127.0.0.1:{port}")])
            .arg("--out")
            .arg(dir.join("station"))
            .stdout(Stdio::null())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("starting the station"),
    );
    let g = wait(&mut gcs, Duration::from_secs(120), "the pymavlink peer");
    let seen = read_json(&seen_path);
    // A peer that failed fails the test at once (the station and the vehicle are killed on the way out).
    assert!(g.success(), "the peer: {}", seen["error"]);
    let st = wait(&mut station, Duration::from_secs(30), "the station");
    let vs = wait(&mut vehicle, Duration::from_secs(30), "the virtual vehicle");
    assert!(st.success() && vs.success(), "station {st}, vehicle {vs}");
    let s = read_json(&dir.join("station").join("station.json"));
    let v = read_json(&dir.join("vehicle").join("summary.json"));
    assert_eq!(s["ended"], "the vehicle landed and disarmed");
    check(
        &seen,
        &v,
        &s["mavlink"],
        &dir.join("station").join("station.log"),
        "station_downlink_telemetry.csv",
        &dir,
    );
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn pymavlink_flies_the_simulated_vehicle_of_fly_mavlink() {
    let Some(py) = python() else { return };
    let _serial = one_at_a_time();
    let dir = std::env::temp_dir().join(format!("mavlink-fly-{}", std::process::id()));
    std::fs::remove_dir_all(&dir).ok();
    std::fs::create_dir_all(&dir).unwrap();
    let seen_path = dir.join("gcs.json");
    let (mut gcs, port) = start_peer(&py, &seen_path);
    let mut fly = Killed(
        Command::new(env!("CARGO_BIN_EXE_sim-host"))
            .args(["fly", "--no-plots", "--seed", "3", "--duration", "80"])
            .args(["--mavlink", &format!("udp:127.0.0.1:{port}")])
            .arg("--out")
            .arg(dir.join("fly"))
            .stdout(Stdio::null())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("starting sim-host fly"),
    );
    let g = wait(&mut gcs, Duration::from_secs(120), "the pymavlink peer");
    let seen = read_json(&seen_path);
    assert!(g.success(), "the peer: {}", seen["error"]);
    let f = wait(&mut fly, Duration::from_secs(30), "sim-host fly");
    assert!(f.success(), "fly {f}");
    let v = read_json(&dir.join("fly").join("summary.json"));
    // Paced to the wall clock: about real time.
    let rtf = v["real_time_factor"].as_f64().unwrap();
    assert!((0.8..1.05).contains(&rtf), "real-time factor {rtf}");
    check(&seen, &v, &v["mavlink"], &dir.join("fly").join("flight.log"), "downlink_telemetry.csv", &dir);
    std::fs::remove_dir_all(&dir).ok();
}

/// Starts the pymavlink peer writing what it saw to `seen`; returns it and the port it listens on.
fn start_peer(py: &str, seen: &Path) -> (Killed, String) {
    let mut gcs = Killed(
        Command::new(py)
            .arg(Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/peers/mavlink_gcs.py"))
            .arg(seen)
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("starting the pymavlink ground control station"),
    );
    let line = BufReader::new(gcs.0.stdout.take().unwrap()).lines().next().expect("the peer's port").unwrap();
    let port = line.strip_prefix("port ").unwrap_or_else(|| panic!("the peer printed {line:?}")).to_string();
    (gcs, port)
}

/// What the peer saw (`seen`), against the vehicle's summary `v`, the endpoint's counters `m` and the
/// telemetry in the flight log `log` (exported to CSV under `dir`, its telemetry topic `telemetry_csv`).
fn check(
    seen: &serde_json::Value,
    v: &serde_json::Value,
    m: &serde_json::Value,
    log: &Path,
    telemetry_csv: &str,
    dir: &Path,
) {
    eprintln!("mavlink: {m}\npeer: {} s", seen["seconds"]);

    // The heartbeat within 2 s of the station's start: a quadrotor, system 1, component 1.
    let first_hb = seen["first_heartbeat_s"].as_f64().unwrap();
    // Measured by the peer from before the station started: an upper bound.
    assert!(first_hb < 2.0, "first heartbeat {first_hb} s");
    assert_eq!(seen["vehicle"], serde_json::json!([1, 1, 2, 0]), "MAV_TYPE_QUADROTOR, MAV_AUTOPILOT_GENERIC");
    assert!(seen["sys_status"].as_u64().unwrap() >= 5);
    assert!(seen["attitude_quaternion"].as_u64().unwrap() > 100);

    // Arm, take-off and land were acknowledged as accepted (MAV_RESULT_ACCEPTED = 0) after any temporary
    // refusal; the modes went disarmed, armed, take-off, hover, landing, disarmed (custom modes 0-3, 6).
    for k in ["arm_results", "takeoff_results", "land_results"] {
        let r = seen[k].as_array().unwrap();
        assert_eq!(r.last().and_then(|x| x.as_u64()), Some(0), "{k}: {r:?}");
    }
    let modes: Vec<u64> = seen["modes"].as_array().unwrap().iter().map(|m| m[0].as_u64().unwrap()).collect();
    let mut distinct = modes.clone();
    distinct.dedup();
    for m in [0, 1, 2, 3, 6] {
        assert!(distinct.contains(&m), "custom mode {m} missing from {distinct:?}");
    }
    assert_eq!(distinct.last(), Some(&0), "{distinct:?}");
    let last = seen["modes"].as_array().unwrap().last().unwrap();
    assert_eq!(last[1], false, "disarmed at the end: {last}");
    // The vehicle's own account: it flew, landed and disarmed; the station says the same.
    assert_eq!((v["landed"].as_bool(), v["crashed"].as_bool()), (Some(true), Some(false)), "{v}");
    let texts: Vec<&str> =
        seen["statustext"].as_array().unwrap().iter().map(|t| t.as_str().unwrap()).collect();
    assert!(texts.iter().any(|t| t.contains("mode: Hover")), "{texts:?}");

    // The parameter list in full: every parameter of ours by its short name, indexes 0..n.
    let listed = seen["params_listed"].as_object().unwrap();
    let n = control_core::params::ParamId::ALL.len();
    assert_eq!(seen["param_count"].as_u64(), Some(n as u64));
    assert_eq!(listed.len(), n, "{listed:?}");
    for (i, id) in control_core::params::ParamId::ALL.iter().enumerate() {
        let p = &listed[id.short_name()];
        assert_eq!(p[0].as_u64(), Some(i as u64), "{}", id.short_name());
    }
    // One set and read back.
    let ps = &seen["param_set"];
    let wanted = ps["wanted"].as_f64().unwrap();
    assert!(wanted != ps["before"].as_f64().unwrap());
    assert!((ps["echo"].as_f64().unwrap() - wanted).abs() < 1e-6, "{ps}");
    assert!((ps["read"].as_f64().unwrap() - wanted).abs() < 1e-6, "{ps}");

    // ATTITUDE and LOCAL_POSITION_NED equal the vehicle's telemetry as the station logged it, in NED / FRD:
    // north = -y_W, east = -x_W, down = -z_W; roll as ours, pitch and yaw negated (docs/mavlink.md).
    let out = Command::new(env!("CARGO_BIN_EXE_sim-host"))
        .arg("export")
        .arg(log)
        .arg("--csv")
        .arg(dir.join("csv"))
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let rows = csv(&dir.join("csv").join(telemetry_csv));
    let f = |r: &HashMap<String, String>, k: &str| -> f64 {
        r.get(k).unwrap_or_else(|| panic!("no column {k}: {:?}", r.keys())).parse().unwrap()
    };
    let by_ms: HashMap<u64, &HashMap<String, String>> =
        rows.iter().map(|r| ((f(r, "time_us") / 1000.0) as u64, r)).collect();
    let mut matched = [0usize; 2];
    let mut worst = [0f64; 2];
    for a in seen["attitude"].as_array().unwrap() {
        let a: Vec<f64> = a.as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect();
        let Some(r) = by_ms.get(&(a[0] as u64)) else { continue };
        let want = [
            f(r, "estimate.attitude.roll"),
            -f(r, "estimate.attitude.pitch"),
            -f(r, "estimate.attitude.yaw"),
        ];
        for k in 0..3 {
            worst[0] = worst[0].max(wrap(a[k + 1] - want[k]).abs());
        }
        matched[0] += 1;
    }
    for p in seen["local_position_ned"].as_array().unwrap() {
        let p: Vec<f64> = p.as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect();
        let Some(r) = by_ms.get(&(p[0] as u64)) else { continue };
        let want = [
            -f(r, "estimate.position_m.y"),
            -f(r, "estimate.position_m.x"),
            -f(r, "estimate.position_m.z"),
            -f(r, "estimate.velocity_m_s.y"),
            -f(r, "estimate.velocity_m_s.x"),
            -f(r, "estimate.velocity_m_s.z"),
        ];
        for k in 0..6 {
            worst[1] = worst[1].max((p[k + 1] - want[k]).abs());
        }
        matched[1] += 1;
    }
    eprintln!(
        "matched {matched:?} of {} telemetry rows; worst attitude {:.2e} rad, position/velocity {:.2e}",
        rows.len(),
        worst[0],
        worst[1]
    );
    // Every telemetry the GCS received has its row (UDP on loopback loses none here).
    assert_eq!(matched[0], seen["attitude"].as_array().unwrap().len());
    assert_eq!(matched[1], seen["local_position_ned"].as_array().unwrap().len());
    assert!(matched[0] * 10 >= rows.len() * 9, "{matched:?} of {}", rows.len());
    assert!(worst[0] <= 1e-4 && worst[1] <= 1e-4, "{worst:?}");
    // What the station counted: the commands and parameter requests it carried, nothing unparsable.
    assert_eq!(m["udp"]["unparsable"], 0, "{m}");
    assert!(m["commands"].as_u64().unwrap() >= 3, "{m}");
    assert!(m["param_requests"].as_u64().unwrap() > n as u64, "{m}");
    assert!(m["local"].as_str().unwrap().starts_with("127.0.0.1:"), "{m}");
}
