//! Real-time factor of the firmware in the loop: the paper scenario (analytic camera, seed 3) flown by the
//! firmware's ELF in QEMU, beside the same flight with the flight code in this process, three times each
//! (medians reported). Needs `qemu-system-arm` and the ELF built with `cd firmware && cargo build --release
//! --features fil --target-dir target/fil` (or `FIL_ELF`); without them it says what is missing.
//!
//! `cargo bench -p sim-host --bench fil`
use sim_host::Scenario;
use sim_host::fil::{QEMU, QemuOptions};
use sim_host::sil::{CameraMode, FcChoice, Sil};
use std::path::PathBuf;
use std::time::Instant;

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    if std::env::args().any(|a| a == "--list" || a == "--test") {
        return;
    }
    let elf = std::env::var_os("FIL_ELF").map(PathBuf::from).unwrap_or_else(|| {
        PathBuf::from(env!("CARGO_MANIFEST_DIR"))
            .join("../firmware/target/fil/thumbv7em-none-eabihf/release/firmware")
    });
    if !elf.exists() {
        println!("no firmware ELF at {}: build it with --features fil (see docs/firmware.md)", elf.display());
        return;
    }
    if !std::process::Command::new(QEMU).arg("--version").output().is_ok_and(|o| o.status.success()) {
        println!("{QEMU} is not installed");
        return;
    }
    let scenario = Scenario::paper();
    let fly = |fc: &FcChoice| {
        let mut sil = Sil::with_fc(&scenario, 3, CameraMode::Analytic, fc).expect("scenario");
        let t0 = Instant::now();
        let st = sil.run(scenario.mission.max_duration_s, |_| {});
        let wall = t0.elapsed().as_secs_f64();
        assert!(st.fc_error.is_none() && !st.crashed, "{:?}", st.fc_error);
        (st.sim_time_s, wall)
    };
    let (mut fil, mut sil) = (Vec::new(), Vec::new());
    for run in 1..=3 {
        let (t, w) = fly(&FcChoice::Qemu(QemuOptions::new(&elf)));
        let (ts, ws) = fly(&FcChoice::Sil);
        println!(
            "run {run}: {t:.1} s of flight in {w:.2} s with the firmware in QEMU ({:.1}x real time), {ws:.3} s with \
             the flight code in this process ({:.0}x)",
            t / w,
            ts / ws
        );
        fil.push(t / w);
        sil.push(ts / ws);
    }
    println!(
        "firmware in the loop: real-time factor {:.1} (median of 3; the simulator alone {:.0})",
        median(fil),
        median(sil)
    );
}
