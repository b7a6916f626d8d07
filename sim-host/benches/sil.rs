//! Real-time factor of the software-in-the-loop simulation: the paper scenario (take-off, two sweeps,
//! landing), one core, for both camera modes. Each mode is flown three times; the median is reported.
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
    println!("paper scenario, seed 1, one core (median of 3 runs):");
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
            "  {:8}  real-time factor {:7.1}  (runs: {})",
            mode.name(),
            rtf[1],
            rtf.iter().map(|r| format!("{r:.1}")).collect::<Vec<_>>().join(", ")
        );
    }
}
