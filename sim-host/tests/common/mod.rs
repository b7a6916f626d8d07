//! What the end-to-end tests share: processes that are killed when the test ends (also when it fails), the
//! virtual vehicle started on ports of its choosing, JSON outputs.
#![allow(dead_code)]
use serde_json::Value;
use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// A child process, killed when dropped unless it has ended.
pub struct Killed(pub Child);

impl Drop for Killed {
    fn drop(&mut self) {
        if self.0.try_wait().ok().flatten().is_none() {
            self.0.kill().ok();
            self.0.wait().ok();
        }
    }
}

/// Waits for `child` to end, at most `limit`; fails naming `what`.
pub fn wait(child: &mut Killed, limit: Duration, what: &str) -> std::process::ExitStatus {
    let end = Instant::now() + limit;
    loop {
        if let Some(s) = child.0.try_wait().expect("waiting") {
            return s;
        }
        assert!(Instant::now() < end, "{what} did not end within {limit:?}");
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// Starts the virtual vehicle on ports of its choosing (`--serve-* tcp:127.0.0.1:0`) with `args`, writing into
/// `out`; returns it and the ports it printed (`link`, `forward`, `down`).
pub fn start_vehicle(out: &Path, args: &[&str]) -> (Killed, std::collections::HashMap<String, String>) {
    let mut vehicle = Killed(
        Command::new(env!("CARGO_BIN_EXE_sim-host"))
            // No host: the loopback interface only (docs/security.md), checked below.
            .args(["fly", "--serve-link", "tcp:0", "--serve-forward", "tcp:0", "--serve-down", "tcp:0"])
            .args(args)
            .args(if args.contains(&"--key") { &[][..] } else { &["--no-key"][..] })
            .arg("--out")
            .arg(out)
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .expect("starting the virtual vehicle"),
    );
    let mut ports = std::collections::HashMap::new();
    let mut lines = BufReader::new(vehicle.0.stdout.take().unwrap()).lines();
    while ports.len() < 3 {
        let line = lines.next().expect("the vehicle printed its ports").unwrap();
        let mut w = line.split_whitespace();
        if let (Some("serving"), Some(k), Some(v)) = (w.next(), w.next(), w.next()) {
            assert!(v.starts_with("tcp:127.0.0.1:"), "{k} bound {v}, not the loopback interface");
            ports.insert(k.to_string(), v.to_string());
        }
    }
    (vehicle, ports)
}

/// The JSON file at `p`.
pub fn read_json(p: &Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(p).unwrap_or_else(|e| panic!("{}: {e}", p.display())))
        .unwrap()
}
