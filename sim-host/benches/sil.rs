//! Real-time factor of the software-in-the-loop simulation: the paper scenario (take-off, two sweeps,
//! landing), for both camera modes, on one thread and on the machine's cores (the forward renderer draws bands
//! of rows in parallel; nothing else of a flight does). Each is flown three times; the median is reported.
//!
//! `cargo bench -p sim-host --bench sil`
use sim_host::Scenario;
use sim_host::sil::{CameraMode, Sil};
use std::time::Instant;

fn main() {
    // `cargo test --benches` runs bench targets with `--test`-like flags; only measure under `cargo bench`.
    if std::env::args().any(|a| a == "--list" || a == "--test") {
        return;
    }
    let scenario = Scenario::paper();
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    println!("paper scenario, seed 1 (median of 3 runs):");
    for threads in [1, cores] {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("thread pool");
        for mode in [CameraMode::Analytic, CameraMode::Rendered] {
            let mut rtf: Vec<f64> = (0..3)
                .map(|_| {
                    let mut sil = Sil::new(&scenario, 1, mode).expect("scenario");
                    let t0 = Instant::now();
                    let st = pool.install(|| sil.run(120.0, |_| {}));
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
}
