//! `sim-host import`: datasets into flight logs.
use super::common::progress_bar;
use super::render::CameraChoice;
use anyhow::{Result, bail};
use clap::{Args, Subcommand};
use sim_host::Scenario;
use sim_host::import::{ImportSummary, Window};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

#[derive(Subcommand, Debug)]
pub(crate) enum ImportCommand {
    /// A dataset in the EuRoC/ASL folder layout: imu0/data.csv (required); optional
    /// state_groundtruth_estimate0/data.csv (the ground truth, kept as the reference), mag0/data.csv, and
    /// cam0/data.csv with cam0/data/*.png and cam0/sensor.yaml for the camera's intrinsics. Without a camera
    /// or a magnetometer yaw is unobservable, and the import says so.
    Euroc(EurocArgs),
    /// A PX4 ULog file: the IMU (sensor_combined), the magnetometer, the landed and armed state, and an
    /// attitude as the reference (the simulator's truth in a software-in-the-loop log, else PX4's estimate
    /// vehicle_attitude; see --reference); PX4's FRD/NED frames converted to FLU/ENU.
    Ulog(UlogArgs),
}

/// The window and resampling options both imports take.
#[derive(Args, Debug)]
pub(crate) struct WindowArgs {
    /// Skip the first SECONDS of the data.
    #[arg(long, value_name = "SECONDS")]
    pub(crate) start: Option<f64>,
    /// Import at most SECONDS of data after the start (a duration beyond the data ends at the data).
    #[arg(long, value_name = "SECONDS")]
    pub(crate) duration: Option<f64>,
    /// Average every N IMU samples into one (a boxcar anti-alias filter). By default an IMU faster than one
    /// control period holds (4 samples) is decimated by the smallest factor that fits.
    #[arg(long, value_name = "N")]
    pub(crate) decimate: Option<u32>,
}

impl WindowArgs {
    fn window(&self) -> Result<Window> {
        let w = Window { start_s: self.start, duration_s: self.duration, decimate: self.decimate };
        w.validate()?;
        Ok(w)
    }
}

#[derive(Args, Debug)]
pub(crate) struct EurocArgs {
    /// The dataset folder (holding imu0/, or mav0/ with it).
    pub(crate) dir: PathBuf,
    /// The flight log to write.
    #[arg(long, value_name = "LOG")]
    pub(crate) out: PathBuf,
    /// The scenario whose flight parameters the replay uses (its camera comes from cam0/sensor.yaml).
    #[arg(long, default_value = "paper")]
    pub(crate) scenario: String,
    /// Which camera cam0 is, if the dataset has one: the forward camera (line detection) or the downward one
    /// (optical flow).
    #[arg(long, value_enum, default_value = "forward")]
    pub(crate) cam0: CameraChoice,
    /// Body axes (x forward, y left, z up) in IMU axes, e.g. the EuRoC MAV's `z,-y,x` (body x = IMU z, ...).
    #[arg(long, default_value = "z,-y,x", value_name = "AXES")]
    pub(crate) imu_axes: String,
    /// Delay from a frame's capture to its measurement reaching the flight code (s).
    #[arg(long, default_value_t = 0.0)]
    pub(crate) latency: f64,
    #[command(flatten)]
    pub(crate) window: WindowArgs,
}

#[derive(Args, Debug)]
pub(crate) struct UlogArgs {
    /// The ULog file (.ulg).
    pub(crate) file: PathBuf,
    /// The flight log to write.
    #[arg(long, value_name = "LOG")]
    pub(crate) out: PathBuf,
    /// The scenario whose flight parameters the replay uses.
    #[arg(long, default_value = "paper")]
    pub(crate) scenario: String,
    /// The attitude the replay is scored against: `auto` takes vehicle_attitude_groundtruth when the log
    /// has it (PX4's simulators write it), else vehicle_attitude (PX4's EKF2).
    #[arg(long, value_enum, default_value = "auto")]
    pub(crate) reference: sim_host::import::ReferenceChoice,
    #[command(flatten)]
    pub(crate) window: WindowArgs,
}

/// Parses `z,-y,x` into body-from-IMU rows.
pub(crate) fn parse_axes(text: &str) -> Result<[[f32; 3]; 3]> {
    let parts: Vec<&str> = text.split(',').map(str::trim).collect();
    let bad = || anyhow::anyhow!("--imu-axes {text}: expected three signed axes such as `z,-y,x`");
    if parts.len() != 3 {
        return Err(bad());
    }
    let mut m = [[0f32; 3]; 3];
    let mut used = [false; 3];
    for (row, p) in parts.iter().enumerate() {
        let (sign, axis) = match p.strip_prefix('-') {
            Some(a) => (-1.0, a),
            None => (1.0, p.strip_prefix('+').unwrap_or(p)),
        };
        let k = match axis {
            "x" => 0,
            "y" => 1,
            "z" => 2,
            _ => return Err(bad()),
        };
        if used[k] {
            bail!("--imu-axes {text}: axis {axis} used twice");
        }
        used[k] = true;
        m[row][k] = sign;
    }
    let det = m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
        - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
        + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
    if det < 0.0 {
        bail!("--imu-axes {text}: a reflection, not a rotation (flip the sign of one axis)");
    }
    Ok(m)
}

fn print_summary(out: &Path, s: &ImportSummary) {
    eprintln!(
        "wrote {}: {:.1} s, {} IMU samples ({} written{}) in {} steps, {} magnetometer readings{}, {} reference \
         states, {} frames ({} measured)",
        out.display(),
        s.seconds,
        s.imu_samples,
        s.imu_written,
        if s.decimation > 1 { format!(", decimated by {}", s.decimation) } else { String::new() },
        s.steps,
        s.mag_samples,
        if s.mag_dropped > 0 {
            format!(" ({} dropped: faster than the control rate)", s.mag_dropped)
        } else {
            String::new()
        },
        s.references,
        s.frames,
        s.measured
    );
    if s.no_target.total() > 0 {
        eprintln!("note: forward frames without the line, by reason: {}", s.no_target.describe());
    }
    if s.imu_gaps > 0 {
        eprintln!("note: {} gaps of more than 10 control periods between IMU samples", s.imu_gaps);
    }
    for n in &s.notes {
        eprintln!("note: {n}");
    }
    eprintln!(
        "next: sim-host replay {} --summary summary.json (attitude against the reference), or --out \
         replayed.log then sim-host export replayed.log --mcap out.mcap",
        out.display()
    );
}

/// Refuses to write over an input.
fn check_output(out: &Path, input: &Path) -> Result<()> {
    sim_host::files::refuse_overwrite(out, &[input])
}

pub(crate) fn import_euroc(a: &EurocArgs) -> Result<ExitCode> {
    if !(a.latency >= 0.0 && a.latency < 10.0) {
        bail!("--latency must be in [0, 10) s");
    }
    check_output(&a.out, &a.dir)?;
    let opts = sim_host::import::EurocOptions {
        dir: a.dir.clone(),
        scenario: Scenario::load(&a.scenario)?,
        cam0: match a.cam0 {
            CameraChoice::Forward => sim_host::flightlog::CameraId::Forward,
            CameraChoice::Down => sim_host::flightlog::CameraId::Downward,
        },
        imu_to_body: parse_axes(&a.imu_axes)?,
        latency_s: a.latency,
        window: a.window.window()?,
    };
    let bar = progress_bar(1000, "{spinner} importing [{bar:40}] ({elapsed} elapsed)");
    let s = sim_host::import::import_euroc(&opts, &a.out, |f| bar.set_position((f * 1000.0) as u64))?;
    bar.finish_and_clear();
    print_summary(&a.out, &s);
    Ok(ExitCode::SUCCESS)
}

pub(crate) fn import_ulog(a: &UlogArgs) -> Result<ExitCode> {
    check_output(&a.out, &a.file)?;
    let opts = sim_host::import::UlogOptions {
        file: a.file.clone(),
        scenario: Scenario::load(&a.scenario)?,
        window: a.window.window()?,
        reference: a.reference,
    };
    let bar = progress_bar(1000, "{spinner} importing [{bar:40}] ({elapsed} elapsed)");
    let s = sim_host::import::import_ulog(&opts, &a.out, |f| bar.set_position((f * 1000.0) as u64))?;
    bar.finish_and_clear();
    print_summary(&a.out, &s);
    Ok(ExitCode::SUCCESS)
}
