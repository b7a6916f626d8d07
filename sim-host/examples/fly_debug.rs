use sim_host::Scenario;
use sim_host::sil::{CameraMode, Sil};
fn main() {
    let mode = if std::env::args().any(|a| a == "rendered") { CameraMode::Rendered } else { CameraMode::Analytic };
    let s = Scenario::paper();
    let mut sil = Sil::new(&s, 1, mode).unwrap();
    let t0 = std::time::Instant::now();
    let stats = sil.run(120.0, |_| {});
    let wall = t0.elapsed().as_secs_f64();
    println!("{stats:#?}");
    println!("wall {wall:.2} s, RTF {:.1}", stats.sim_time_s / wall);
    for r in sil.records().iter().step_by(100) {
        println!("{:6.2} {:?} true {:6.3} {:6.3} {:6.3} est {:6.3} {:6.3} {:6.3} des {:6.3} {:6.3} {:6.3} tilt {:5.2} {:5.2} fix {:.2}",
            r.t_s, r.mode, r.true_p[0], r.true_p[1], r.true_p[2], r.est_p[0], r.est_p[1], r.est_p[2], r.des_p[0], r.des_p[1], r.des_p[2],
            r.true_att[0].to_degrees(), r.true_att[1].to_degrees(), r.fix_age_s);
    }
}
