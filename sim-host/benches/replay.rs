//! Replay speed: the whole paper flight's log (analytic camera, seed 1) replayed through the flight stack from
//! the logged vision results, as `sim-host replay` runs it: read from the file record by record, step, background
//! solve, compare every report and downlink. Also the same flight logged with PNG frames (rendered camera),
//! replayed from vision results (frames skipped unread) and from the frames (vision-core re-run). Median of
//! 5 runs each; the figure is simulated seconds per wall-clock second (the real-time factor).
//!
//! `cargo bench -p sim-host --bench replay`
use sim_host::Scenario;
use sim_host::flightlog::{FramePolicy, LOG_FILE, open_log};
use sim_host::fly::{FlyOptions, fly};
use sim_host::replay::{ReplayOptions, VisionSource, replay_stream};
use sim_host::sil::{CameraMode, FcChoice};
use std::path::Path;
use std::time::Instant;

fn flight_log(
    dir: &Path,
    camera: CameraMode,
    frames: FramePolicy,
    duration_s: Option<f64>,
) -> std::path::PathBuf {
    let opts = FlyOptions {
        scenario: Scenario::paper(),
        seed: 1,
        duration_s,
        camera,
        out: dir.to_path_buf(),
        plots: false,
        fc: FcChoice::Sil,
        log: true,
        frames,
        serve: None,
        mavlink: None,
        live: None,
        real_time: None,
    };
    fly(&opts, |_, _| {}).expect("flight");
    dir.join(LOG_FILE)
}

fn measure(log: &Path, vision: VisionSource, skip_frames: bool, runs: usize) -> (f64, f64, u64) {
    let mut rtf = Vec::new();
    let mut sim = 0.0;
    let mut steps = 0;
    for _ in 0..runs {
        let t0 = Instant::now();
        let reader = open_log(log).expect("log").skip_frames(skip_frames);
        let header = reader.header.clone();
        let opts = ReplayOptions { vision, ..ReplayOptions::default() };
        let s = replay_stream(&header, reader, &opts, None).expect("replay");
        let wall = t0.elapsed().as_secs_f64();
        assert!(s.identical(), "the replay differs: {:?}", s.first);
        sim = s.sim_time_s;
        steps = s.steps;
        rtf.push(s.sim_time_s / wall);
    }
    rtf.sort_by(f64::total_cmp);
    (rtf[rtf.len() / 2], sim, steps)
}

fn main() {
    if std::env::args().any(|a| a == "--list" || a == "--test") {
        return;
    }
    let dir = std::env::temp_dir().join(format!("replay-bench-{}", std::process::id()));
    let analytic = flight_log(&dir.join("analytic"), CameraMode::Analytic, FramePolicy::Drop, None);
    let (rtf, sim, steps) = measure(&analytic, VisionSource::Logged, true, 5);
    let mb = std::fs::metadata(&analytic).map(|m| m.len()).unwrap_or(0) as f64 / 1e6;
    println!("paper flight, seed 1, one core, median of 5 runs:");
    println!(
        "  from logged vision results, no frames ({sim:.1} s, {steps} steps, {mb:.1} MB): real-time factor {rtf:.0}"
    );
    let rendered = flight_log(&dir.join("rendered"), CameraMode::Rendered, FramePolicy::Png, Some(20.0));
    let mb = std::fs::metadata(&rendered).map(|m| m.len()).unwrap_or(0) as f64 / 1e6;
    let (rtf, sim, _) = measure(&rendered, VisionSource::Logged, true, 5);
    println!(
        "  from logged vision results, PNG frames skipped ({sim:.1} s, {mb:.0} MB): real-time factor {rtf:.0}"
    );
    let (rtf, sim, _) = measure(&rendered, VisionSource::Frames, false, 3);
    println!("  from the frames, vision-core re-run ({sim:.1} s): real-time factor {rtf:.1}");
    let _ = std::fs::remove_dir_all(&dir);
}
