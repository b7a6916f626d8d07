//! Flies the paper scenario over several seeds and prints the tracking errors, for tuning.
//!
//! `cargo run --release -p sim-host --example seed_sweep -- [rendered] [n=10] [wp=2.5] [ki=0.05]`
//! (`wp`: position pole in rad/s, `ki`: trim gain; analytic camera unless `rendered`).
use sim_host::Scenario;
use sim_host::sil::{CameraMode, Sil};
fn main() {
    let args: Vec<String> = std::env::args().collect();
    let mode = if args.iter().any(|a| a == "rendered") { CameraMode::Rendered } else { CameraMode::Analytic };
    let n: u64 = args.iter().find_map(|a| a.strip_prefix("n=").and_then(|v| v.parse().ok())).unwrap_or(5);
    let mut s = Scenario::paper();
    for a in &args {
        if let Some(v) = a.strip_prefix("wp=") {
            let w: f32 = v.parse().unwrap();
            for g in [&mut s.gains.roll, &mut s.gains.pitch] {
                *g = control_core::params::SaturatedAxisGains::from_poles(
                    10.0,
                    0.8,
                    w,
                    0.9,
                    g.b,
                    g.trim_gain,
                    g.trim_limit_rad,
                );
            }
        }
        if let Some(v) = a.strip_prefix("ki=") {
            let k: f32 = v.parse().unwrap();
            s.gains.roll.trim_gain = k;
            s.gains.pitch.trim_gain = k;
        }
    }
    s.validate().unwrap();
    let mut worst = [0.0f64; 3];
    for seed in 1..=n {
        let mut sil = Sil::new(&s, seed, mode).unwrap();
        let st = sil.run(120.0, |_| {});
        println!(
            "seed {seed:2}: rms x {:5.1} y {:5.1} z {:5.1} mm | est {:4.1} {:4.1} {:4.1} mm | tilt {:.2} | crashed {} landed {} passes {}",
            1e3 * st.rms_error_m[0],
            1e3 * st.rms_error_m[1],
            1e3 * st.rms_error_m[2],
            1e3 * st.estimate_rms_error_m[0],
            1e3 * st.estimate_rms_error_m[1],
            1e3 * st.estimate_rms_error_m[2],
            st.max_tilt_deg,
            st.crashed,
            st.landed,
            st.passes_done
        );
        for (w, e) in worst.iter_mut().zip(st.rms_error_m) {
            *w = w.max(e);
        }
    }
    println!("worst: x {:.1} y {:.1} z {:.1} mm", 1e3 * worst[0], 1e3 * worst[1], 1e3 * worst[2]);
}
