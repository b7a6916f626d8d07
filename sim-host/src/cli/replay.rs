//! `sim-host replay`: the flight stack re-run on a log.
use super::common::{ProgressItems, progress_bar, rtf_text};
use anyhow::{Result, bail};
use clap::Args;
use sim_host::replay::{ReplayOptions, VisionSource, replay_stream};
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Args, Debug)]
pub(crate) struct ReplayArgs {
    /// The flight log (`flight.log` written by `sim-host fly`, or `sim-host import`).
    pub(crate) log: PathBuf,
    /// Re-run the ground station's vision (vision-core's line detector and optical flow) on the logged camera
    /// frames and compare each measurement with the logged one, instead of feeding the logged measurements.
    #[arg(long)]
    pub(crate) from_frames: bool,
    /// Write the replayed flight (inputs, recomputed measurements, reports, downlinks) as a new log, e.g. to
    /// export the estimates of an imported dataset.
    #[arg(long, value_name = "LOG")]
    pub(crate) out: Option<PathBuf>,
    /// Change a parameter before the first step, e.g. `--set trajectory.speed_m_s=0.3` (repeatable); the replay
    /// then reports the differences instead of failing on them.
    #[arg(long = "set", value_name = "NAME=VALUE")]
    pub(crate) set: Vec<String>,
    /// Write the flight code's attitude against the log's reference (an imported dataset's ground truth or
    /// its recorded estimator) as JSON: RMS and largest errors of roll, pitch and yaw (deg), per segment, with
    /// a Mahony filter run on the same samples beside it.
    #[arg(long, value_name = "FILE.json")]
    pub(crate) summary: Option<PathBuf>,
}
pub(crate) fn replay(a: &ReplayArgs) -> Result<ExitCode> {
    use control_core::params::ParamId;
    let mut overrides = Vec::new();
    for kv in &a.set {
        let Some((name, value)) = kv.split_once('=') else { bail!("--set {kv}: expected NAME=VALUE") };
        let Some(id) = ParamId::from_name(name.trim()) else {
            let names: Vec<&str> = ParamId::ALL.iter().map(|p| p.name()).collect();
            bail!("--set {kv}: unknown parameter `{name}`; known: {}", names.join(", "));
        };
        let v: f32 =
            value.trim().parse().map_err(|_| anyhow::anyhow!("--set {kv}: `{value}` is not a number"))?;
        overrides.push((id, v));
    }
    let outputs: Vec<&std::path::Path> = a.out.iter().chain(a.summary.iter()).map(|p| p.as_path()).collect();
    sim_host::files::refuse_overwrites(&outputs, &[&a.log])?;
    // Replaying from vision results without writing a new log never looks at the frames: skip them unread.
    let reader = sim_host::flightlog::open_log(&a.log)?.skip_frames(!a.from_frames && a.out.is_none());
    let header = reader.header.clone();
    let file_len = std::fs::metadata(&a.log).map(|m| m.len()).unwrap_or(0);
    let opts = ReplayOptions {
        overrides: overrides.clone(),
        vision: if a.from_frames { VisionSource::Frames } else { VisionSource::Logged },
    };
    let mut writer = match &a.out {
        Some(p) => {
            let mut h = header.clone();
            h.writer = format!("sim-host {} replay of {}", env!("CARGO_PKG_VERSION"), a.log.display());
            Some(sim_host::flightlog::LogWriter::create(p, &h)?)
        }
        None => None,
    };
    let bar = progress_bar(
        file_len.max(1),
        "{spinner} replaying [{bar:40}] {bytes}/{total_bytes} ({elapsed} elapsed)",
    );
    let t0 = std::time::Instant::now();
    let mut count = 0u64;
    let mut items = ProgressItems { inner: reader, bar: &bar, count: &mut count };
    let s = replay_stream(&header, &mut items, &opts, writer.as_mut())?;
    let skipped = items.inner.frames_skipped;
    bar.finish_and_clear();
    if s.steps == 0 && s.station_records > 0 {
        bail!(
            "{}: a ground station's recording ({} records of what crossed the radio, on the station's clock) \
             holds no sensor steps to re-run; `sim-host export` turns it into MCAP or CSV",
            a.log.display(),
            s.station_records
        );
    }
    let wall = t0.elapsed().as_secs_f64();
    if let Some(w) = writer {
        w.finish()?;
    }
    eprintln!(
        "{}: {} steps ({:.1} s of flight) replayed in {:.2} s ({} real time){}; {} reports compared, {} differ; \
         {} downlinks compared, {} differ",
        a.log.display(),
        s.steps,
        s.sim_time_s,
        wall,
        rtf_text(s.sim_time_s / wall.max(1e-9)),
        if a.from_frames { " from frames" } else { "" },
        s.compared,
        s.differing,
        s.downlinks_compared,
        s.downlinks_differing,
    );
    if skipped > 0 {
        eprintln!(
            "{skipped} camera frames skipped (replayed from the logged vision results; --from-frames uses them)"
        );
    }
    if a.from_frames {
        eprintln!(
            "{} frames; {} measurements recomputed from frames, {} differ, {} without their frame",
            s.frames, s.measurements_compared, s.measurements_differing, s.measurements_without_frame
        );
        if s.no_target.total() > 0 {
            eprintln!("forward frames without the line, by reason: {}", s.no_target.describe());
        }
    }
    if let Some(p) = &a.out {
        eprintln!("wrote {}", p.display());
    }
    for d in &s.damage {
        eprintln!("damaged record {d}");
    }
    if s.reports_without_step > 0 {
        eprintln!(
            "{} logged reports lost their step to the damage (not compared; the replay missed those steps)",
            s.reports_without_step
        );
    }
    if let Some(r) = &s.reference {
        print_reference(r);
    }
    if let Some(p) = &a.summary {
        let Some(r) = &s.reference else {
            bail!("--summary: the log has no reference to compare with (only imported datasets have one)")
        };
        let text = serde_json::to_string_pretty(r)?;
        sim_host::files::write_atomic(p, text.as_bytes())?;
        eprintln!("wrote {}", p.display());
    }
    if !s.has_outputs {
        // An imported dataset: nothing to compare bit for bit; what was computed is the result.
        eprintln!(
            "the log holds no reports to compare (an imported dataset): the flight code ran on its inputs"
        );
        for d in &s.damage {
            eprintln!("damaged record {d}");
        }
        return Ok(if s.damage.is_empty() { ExitCode::SUCCESS } else { ExitCode::from(1) });
    }
    match (&s.first, overrides.is_empty()) {
        (None, _) if s.damage.is_empty() => {
            eprintln!("identical: every output matches the log bit for bit");
            Ok(ExitCode::SUCCESS)
        }
        (None, _) => {
            eprintln!("the intact records match, but {} were damaged", s.damage.len());
            Ok(ExitCode::from(1))
        }
        (Some(d), true) => {
            eprintln!("first difference: {d}");
            Ok(ExitCode::from(1))
        }
        (Some(d), false) => {
            eprintln!("with the changed parameters, first difference: {d}");
            Ok(ExitCode::SUCCESS)
        }
    }
}

/// Prints the attitude errors against the reference, the flight code's beside the Mahony filter's.
fn print_reference(r: &serde_json::Value) {
    eprintln!(
        "attitude against the reference ({}; yaw {}):",
        r["reference"].as_str().unwrap_or(""),
        r["yaw"].as_str().unwrap_or("")
    );
    eprintln!(
        "  {:<24} {:>8} {:>32} {:>32}",
        "segment", "samples", "RMS roll / pitch / yaw (deg)", "max roll / pitch / yaw (deg)"
    );
    let f = |v: &serde_json::Value| v.as_f64().map_or("-".to_string(), |x| format!("{x:.2}"));
    let three = |v: &serde_json::Value| format!("{} / {} / {}", f(&v["roll"]), f(&v["pitch"]), f(&v["yaw"]));
    for seg in r["segments"].as_array().into_iter().flatten() {
        eprintln!(
            "  {:<24} {:>8} {:>32} {:>32}",
            seg["name"].as_str().unwrap_or(""),
            seg["samples"],
            three(&seg["attitude_rms_error_deg"]),
            three(&seg["attitude_max_error_deg"])
        );
        eprintln!(
            "  {:<24} {:>8} {:>32} {:>32}",
            "  Mahony reference",
            "",
            three(&seg["mahony"]["attitude_rms_error_deg"]),
            three(&seg["mahony"]["attitude_max_error_deg"])
        );
    }
}
