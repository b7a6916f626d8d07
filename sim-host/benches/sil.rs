//! Real-time factor of the software-in-the-loop simulation: the paper scenario (take-off, two sweeps,
//! landing), for both camera modes, on one thread and on the machine's cores (the forward renderer draws bands
//! of rows in parallel, and both cameras' frames are rendered and measured on the pool while the simulation
//! steps on: `sim_host::camera_worker`). Each is flown three times; the median is reported.
//!
//! Each thread count runs in a child process of this bench with `RAYON_NUM_THREADS` set, flying on its main
//! thread with rayon's global pool, as `sim-host fly` does (a flight started on a pool's own thread measures
//! its frames at once instead, as a sweep's runs do).
//!
//! `cargo bench -p sim-host --bench sil`
use sim_host::Scenario;
use sim_host::sil::{CameraMode, Sil};
use std::time::Instant;

/// The argument that makes this bench the child that measures.
const CHILD: &str = "--measure-with-global-pool";

fn main() {
    // `cargo test --benches` runs bench targets with `--test`-like flags; only measure under `cargo bench`.
    if std::env::args().any(|a| a == "--list" || a == "--test") {
        return;
    }
    if std::env::args().any(|a| a == CHILD) {
        measure();
        return;
    }
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    println!("paper scenario, seed 1 (median of 3 runs):");
    for threads in [1, cores] {
        let exe = std::env::current_exe().expect("the bench's own path");
        let status = std::process::Command::new(exe)
            .arg(CHILD)
            .env("RAYON_NUM_THREADS", threads.to_string())
            .status()
            .expect("the bench's child");
        assert!(status.success(), "the measurement with {threads} thread(s) failed: {status}");
    }
}

fn measure() {
    let scenario = Scenario::paper();
    let threads = rayon::current_num_threads();
    for mode in [CameraMode::Analytic, CameraMode::Rendered] {
        let mut rtf: Vec<f64> = (0..3)
            .map(|_| {
                let mut sil = Sil::new(&scenario, 1, mode).expect("scenario");
                let t0 = Instant::now();
                let st = sil.run(120.0, |_| {});
                let wall = t0.elapsed().as_secs_f64();
                assert!(!st.crashed);
                st.sim_time_s / wall
            })
            .collect();
        rtf.sort_by(f64::total_cmp);
        println!(
            "  {threads} thread(s)  {:8}  real-time factor {:7.1}  (runs: {})",
            mode.name(),
            rtf[1],
            rtf.iter().map(|r| format!("{r:.1}")).collect::<Vec<_>>().join(", ")
        );
    }
}
