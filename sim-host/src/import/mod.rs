//! Import of recorded datasets into flight logs: EuRoC / ASL folders ([`euroc`]) and PX4 ULog files
//! ([`ulog`]).
//!
//! Each reader turns its source into [`ImportData`] in this project's frames (body FLU, world with `z` up,
//! times in us); [`write_import`] then writes the log: a `Step` record per control period with the IMU
//! samples, the magnetometer and the recorded vehicle's land state of that period, `Reference` records (the
//! dataset's ground truth or the recording's own estimate) at their times, and, for datasets with camera
//! frames, the frames and the ground station's measurements of them. The log has no reports:
//! `sim-host replay LOG --summary FILE.json` runs the flight code on it and compares its attitude with the
//! reference; `--out` writes the replayed log for `sim-host export`.
//!
//! - `--start` and `--duration` select a window; a window beyond the data ends at the data (the log never
//!   holds more than the dataset).
//! - An IMU faster than a control period holds ([`MAX_IMU_PER_STEP`] samples) is decimated: `N` consecutive
//!   samples are averaged into one at their mean time (a boxcar anti-alias filter: the rates and specific
//!   forces a rate-integrating IMU would report), with `N` the smallest that fits unless `--decimate N` sets it.
pub mod euroc;
pub mod ulog;

use crate::flightlog::{LogHeader, LogRecord, LogWriter, ReferenceState};
use crate::scenario::Scenario;
use anyhow::{Result, bail};
use control_core::estimator::ImuSample;
use flight_core::fil::{MAX_IMU_PER_STEP, SensorStep};
use geometry::Vec3;

pub use euroc::{EUROC_IMU_TO_BODY, EurocOptions, import_euroc};
pub use ulog::{ReferenceChoice, UlogOptions, import_ulog};

/// The gyro-bias random walk the flight code assumes for a recorded IMU (rad/s per sqrt(s)), unless the
/// scenario sets its own.
///
/// The built-in scenario's walks (PX4's EKF2 defaults, 1e-3 and 3e-3) are tuned for the simulated vehicle,
/// whose IMU also suffers bias steps (`imu_bias_step` faults) that the filter must follow within seconds. A
/// recorded flight without vision has only the rotor-drag model to tell the tilt from the gyro bias, and a
/// slowly drifting bias (an IMU at its operating temperature) is followed best with a small walk: on EuRoC
/// MH_01 the flight's roll and pitch errors are 0.6 deg with these values and 2.3 deg with the simulator's.
pub const RECORDED_GYRO_BIAS_WALK: f32 = 3e-5;
/// The accelerometer-bias random walk for a recorded IMU (m/s^2 per sqrt(s)); see [`RECORDED_GYRO_BIAS_WALK`].
pub const RECORDED_ACCEL_BIAS_WALK: f32 = 3e-4;

/// The estimator's bias walks for a recording: [`RECORDED_GYRO_BIAS_WALK`] and [`RECORDED_ACCEL_BIAS_WALK`]
/// where the scenario keeps the built-in scenario's values, the scenario's own otherwise.
pub fn recorded_imu_tuning(scenario: &mut Scenario) {
    let built_in = Scenario::paper().estimator;
    let e = &mut scenario.estimator;
    if e.gyro_bias_walk == built_in.gyro_bias_walk {
        e.gyro_bias_walk = RECORDED_GYRO_BIAS_WALK;
    }
    if e.accel_bias_walk == built_in.accel_bias_walk {
        e.accel_bias_walk = RECORDED_ACCEL_BIAS_WALK;
    }
}

/// The window and resampling of an import.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Window {
    /// Skip the first seconds of the data.
    pub start_s: Option<f64>,
    /// Import at most this many seconds (from the start).
    pub duration_s: Option<f64>,
    /// Average this many IMU samples into one (`None`: the smallest factor a control period can hold).
    pub decimate: Option<u32>,
}

impl Window {
    /// Checks the values (the CLI's and any caller's).
    pub fn validate(&self) -> Result<()> {
        if let Some(s) = self.start_s
            && !(s.is_finite() && s >= 0.0)
        {
            bail!("--start must be a finite number of seconds >= 0 (got {s})");
        }
        if let Some(d) = self.duration_s
            && !(d.is_finite() && d > 0.0)
        {
            bail!("--duration must be a finite number of seconds > 0 (got {d})");
        }
        if let Some(n) = self.decimate
            && !(1..=64).contains(&n)
        {
            bail!("--decimate must lie in 1..=64 (got {n})");
        }
        Ok(())
    }
}

/// A recorded dataset in this project's frames, before it is cut into control steps.
#[derive(Clone, Debug, Default)]
pub struct ImportData {
    /// IMU samples, body frame, time-ordered (us on the dataset's clock).
    pub imu: Vec<ImuSample>,
    /// Magnetometer readings, body frame (any unit), time-ordered.
    pub mag: Vec<(u64, Vec3)>,
    /// The recorded vehicle's land state: `(time, landed)` at each change (`None`: unknown), time-ordered.
    pub landed: Vec<(u64, Option<bool>)>,
    /// The reference states, time-ordered.
    pub reference: Vec<ReferenceState>,
}

/// What an import wrote.
#[derive(Clone, Debug, Default)]
pub struct ImportSummary {
    /// IMU samples in the dataset's window (before decimation).
    pub imu_samples: u64,
    /// IMU samples written (after decimation).
    pub imu_written: u64,
    /// The decimation factor used (1: none).
    pub decimation: u32,
    /// Control steps.
    pub steps: u64,
    /// Magnetometer readings written.
    pub mag_samples: u64,
    /// Magnetometer readings dropped because a faster one arrived within the same control period.
    pub mag_dropped: u64,
    /// Reference states written.
    pub references: u64,
    /// Frames.
    pub frames: u64,
    /// Forward frames in which the line was found, or flow pairs that gave a flow.
    pub measured: u64,
    /// Forward frames in which the detector found no line, by its reason.
    pub no_target: crate::vision::NoTargetCounts,
    /// Seconds of data.
    pub seconds: f64,
    /// Gaps between IMU samples longer than 10 control periods (the flight code integrates or counts them).
    pub imu_gaps: u64,
    /// Notes for the user (yaw observability, decimation).
    pub notes: Vec<String>,
}

/// Something that becomes log records between steps: camera frames and their measurements.
pub trait ExtraRecords {
    /// Records due at or before `t_us` on the dataset's clock (written before that step's `Step` record),
    /// with their times rebased by `origin_us` (the window's start).
    fn due(
        &mut self,
        t_us: u64,
        origin_us: u64,
        out: &mut Vec<LogRecord>,
        summary: &mut ImportSummary,
    ) -> Result<()>;
}

/// No extra records.
pub struct NoExtras;

impl ExtraRecords for NoExtras {
    fn due(&mut self, _: u64, _: u64, _: &mut Vec<LogRecord>, _: &mut ImportSummary) -> Result<()> {
        Ok(())
    }
}

/// Averages groups of `n` samples (boxcar anti-alias filter) at their mean time.
pub fn decimate(imu: &[ImuSample], n: usize) -> Vec<ImuSample> {
    if n <= 1 {
        return imu.to_vec();
    }
    imu.chunks_exact(n)
        .map(|c| {
            let k = c.len() as f32;
            let mut g = [0f32; 3];
            let mut a = [0f32; 3];
            let mut t = 0u128;
            for s in c {
                for i in 0..3 {
                    g[i] += s.gyro_rad_s[i];
                    a[i] += s.accel_m_s2[i];
                }
                t += s.time_us as u128;
            }
            ImuSample {
                time_us: (t / c.len() as u128) as u64,
                gyro_rad_s: g.map(|v| v / k),
                accel_m_s2: a.map(|v| v / k),
            }
        })
        .collect()
}

/// The smallest decimation factor with which no control period of `period_us` (the first ending one period
/// after the first sample) holds more than [`MAX_IMU_PER_STEP`] samples.
pub fn needed_decimation(imu: &[ImuSample], period_us: u64) -> u32 {
    let origin = imu.first().map_or(0, |s| s.time_us);
    (1..=64u32)
        .find(|&n| {
            let d = decimate(imu, n as usize);
            let mut k = 0;
            let mut worst = 0;
            let mut t = origin + period_us;
            while k < d.len() {
                let start = k;
                while k < d.len() && d[k].time_us <= t {
                    k += 1;
                }
                worst = worst.max(k - start);
                t += period_us;
            }
            worst <= MAX_IMU_PER_STEP
        })
        .unwrap_or(64)
}

/// Writes an import as a log: steps at the scenario's control rate over the window, with the references,
/// the land state and the extra records in time order. Times are rebased so that the window starts at 0.
pub fn write_import(
    data: &ImportData,
    window: &Window,
    scenario: &Scenario,
    header: LogHeader,
    out: &std::path::Path,
    extras: &mut dyn ExtraRecords,
    progress: impl FnMut(f64),
) -> Result<ImportSummary> {
    window.validate()?;
    let file = crate::files::AtomicFile::create(out)?;
    write_import_on(data, window, scenario, header, file, extras, progress)
}

/// [`write_import`] into `file` (renamed into place when complete). A failed write (a full disk) keeps what
/// was written as `NAME.partial`, a log that reads as truncated after its last whole record, and says so.
pub fn write_import_on(
    data: &ImportData,
    window: &Window,
    scenario: &Scenario,
    header: LogHeader,
    file: crate::files::AtomicFile,
    extras: &mut dyn ExtraRecords,
    mut progress: impl FnMut(f64),
) -> Result<ImportSummary> {
    window.validate()?;
    let Some(first) = data.imu.first() else { bail!("the dataset has no IMU samples") };
    let last = data.imu.last().map_or(first.time_us, |s| s.time_us);
    let t_start = first.time_us + window.start_s.map_or(0, |s| (s * 1e6).round() as u64);
    if t_start > last {
        bail!(
            "--start {:.3} s is past the end of the data ({:.3} s of IMU samples)",
            window.start_s.unwrap_or(0.0),
            (last - first.time_us) as f64 * 1e-6
        );
    }
    // The window ends at the data's end, whatever the duration asked for.
    let t_end = match window.duration_s {
        Some(d) => last.min(t_start.saturating_add((d * 1e6).round() as u64)),
        None => last,
    };
    let in_window: Vec<ImuSample> =
        data.imu.iter().filter(|s| s.time_us >= t_start && s.time_us <= t_end).copied().collect();
    let period_us = (1e6 / scenario.mission.control_rate_hz).round().max(1.0) as u64;
    let mut summary = ImportSummary { imu_samples: in_window.len() as u64, ..ImportSummary::default() };
    let n = match window.decimate {
        Some(n) => n,
        None => needed_decimation(&in_window, period_us),
    };
    summary.decimation = n;
    let imu = decimate(&in_window, n as usize);
    if n > 1 {
        summary.notes.push(format!(
            "the IMU is faster than a {period_us} us control period holds: every {n} samples averaged into one"
        ));
    }
    for w in imu.windows(2) {
        if w[1].time_us - w[0].time_us > 10 * period_us {
            summary.imu_gaps += 1;
        }
    }
    let rebase = |t: u64| t.saturating_sub(t_start);
    let mut w = LogWriter::create_on(file, &header)?;
    let (mut next_imu, mut next_mag, mut next_ref, mut next_land) = (0usize, 0usize, 0usize, 0usize);
    while next_mag < data.mag.len() && data.mag[next_mag].0 < t_start {
        next_mag += 1;
    }
    while next_ref < data.reference.len() && data.reference[next_ref].time_us < t_start {
        next_ref += 1;
    }
    let mut landed: Option<bool> = None;
    let mut records = Vec::new();
    let span = (t_end - t_start).max(1);
    let mut t = t_start + period_us;
    loop {
        records.clear();
        extras.due(t, t_start, &mut records, &mut summary)?;
        while next_ref < data.reference.len() && data.reference[next_ref].time_us <= t.min(t_end) {
            let mut r = data.reference[next_ref];
            r.time_us = rebase(r.time_us);
            records.push(LogRecord::Reference(r));
            summary.references += 1;
            next_ref += 1;
        }
        while next_land < data.landed.len() && data.landed[next_land].0 <= t {
            landed = data.landed[next_land].1;
            next_land += 1;
        }
        let mut step =
            SensorStep { time_us: rebase(t), imu: heapless::Vec::new(), mag: None, baro_m: None, landed };
        while next_imu < imu.len() && imu[next_imu].time_us <= t {
            let mut s = imu[next_imu];
            s.time_us = rebase(s.time_us);
            if step.imu.push(s).is_err() {
                bail!(
                    "more than {MAX_IMU_PER_STEP} IMU samples within the {period_us} us control period ending at \
                     {:.6} s even after decimating by {n}: give a larger --decimate",
                    rebase(t) as f64 * 1e-6
                );
            }
            next_imu += 1;
        }
        summary.imu_written += step.imu.len() as u64;
        while next_mag < data.mag.len() && data.mag[next_mag].0 <= t {
            if step.mag.is_some() {
                summary.mag_dropped += 1;
            } else {
                summary.mag_samples += 1;
            }
            step.mag = Some(data.mag[next_mag].1);
            next_mag += 1;
        }
        records.push(LogRecord::Step(step));
        for r in &records {
            if let Err(e) = w.write(r) {
                // A full disk: what was written is kept and named.
                return Err(w.give_up(e));
            }
        }
        summary.steps += 1;
        summary.seconds = rebase(t) as f64 * 1e-6;
        if summary.steps.is_multiple_of(500) {
            progress((t - t_start) as f64 / span as f64);
        }
        if t >= t_end {
            break;
        }
        t += period_us;
    }
    w.finish()?;
    progress(1.0);
    Ok(summary)
}

/// The header of an imported log.
pub fn import_header(
    scenario: &Scenario,
    writer: String,
    source: String,
    reference: String,
    yaw_absolute: bool,
) -> Result<LogHeader> {
    use anyhow::Context;
    Ok(LogHeader {
        format_version: crate::flightlog::LOG_FORMAT_VERSION,
        schema_hash: crate::flightlog::schema_hash(),
        wire_version: protocol::frame::WIRE_VERSION,
        writer,
        scenario_toml: toml::to_string(scenario).context("the scenario as TOML")?,
        seed: 0,
        camera: source,
        flight_computer: "none (imported dataset)".into(),
        reference,
        reference_yaw_absolute: yaw_absolute,
        link_security: String::new(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn s(t: u64, v: f32) -> ImuSample {
        ImuSample { time_us: t, gyro_rad_s: [v; 3], accel_m_s2: [v, 0.0, 9.8] }
    }

    #[test]
    fn decimation_averages_groups_at_their_mean_time() {
        let imu: Vec<_> = (0..8u64).map(|k| s(1000 + k * 250, k as f32)).collect();
        let d = decimate(&imu, 4);
        assert_eq!(d.len(), 2);
        assert_eq!(d[0].time_us, 1375);
        assert_eq!(d[0].gyro_rad_s, [1.5; 3]);
        assert_eq!(d[1].accel_m_s2[0], 5.5);
        // 4 kHz into 2 ms periods (8 samples each): a factor of 2 fits four per period.
        let fast: Vec<_> = (0..4000u64).map(|k| s(k * 250, 0.0)).collect();
        assert_eq!(needed_decimation(&fast, 2000), 2);
        let slow: Vec<_> = (0..200u64).map(|k| s(k * 5000, 0.0)).collect();
        assert_eq!(needed_decimation(&slow, 2000), 1);
    }

    #[test]
    fn a_full_disk_keeps_what_the_import_wrote_and_says_so() {
        let dir = std::env::temp_dir().join(format!("wlq-import-full-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let out = dir.join("imported.log");
        // 4 s of a still IMU at 1 kHz: about 200 kB of steps, on a disk with room for 20 kB.
        let data =
            ImportData { imu: (1..4000u64).map(|k| s(k * 1000, 0.0)).collect(), ..ImportData::default() };
        let scenario = Scenario::paper();
        let header = import_header(&scenario, "test".into(), "none".into(), String::new(), false).unwrap();
        let file = crate::files::AtomicFile::create_with_space(&out, 20_000).unwrap();
        let e = write_import_on(&data, &Window::default(), &scenario, header, file, &mut NoExtras, |_| {})
            .unwrap_err();
        let msg = format!("{e:#}");
        let kept = crate::files::AtomicFile::partial_path(&out);
        assert!(msg.contains("imported.log") && msg.contains(&*kept.to_string_lossy()), "{msg}");
        assert!(msg.contains("records had been written") && msg.contains("no space left"), "{msg}");
        assert!(!out.exists(), "no file under the final name");
        // What was kept reads as a log truncated after its last whole record, every record before it intact.
        let log = crate::flightlog::read_log(&kept).unwrap();
        assert!(log.records.len() > 50, "{} records kept", log.records.len());
        assert!(!log.damage.is_empty());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn windows_are_checked() {
        assert!(Window { duration_s: Some(-3.0), ..Window::default() }.validate().is_err());
        assert!(Window { duration_s: Some(f64::NAN), ..Window::default() }.validate().is_err());
        assert!(Window { start_s: Some(f64::INFINITY), ..Window::default() }.validate().is_err());
        assert!(Window { decimate: Some(0), ..Window::default() }.validate().is_err());
        assert!(Window { start_s: Some(2.0), duration_s: Some(1e12), decimate: Some(2) }.validate().is_ok());
    }
}
