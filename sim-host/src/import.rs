//! Import of recorded datasets into flight logs.
//!
//! EuRoC / ASL folder layout (Burri et al., "The EuRoC micro aerial vehicle datasets", IJRR 2016):
//!
//! ```text
//! DIR/imu0/data.csv         #timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y,w_RS_S_z,a_RS_S_x [m s^-2],a_RS_S_y,a_RS_S_z
//! DIR/cam0/data.csv         #timestamp [ns],filename
//! DIR/cam0/data/*.png       the frames
//! DIR/cam0/sensor.yaml      optional: resolution, intrinsics [fu, fv, cu, cv], distortion_coefficients, rate_hz
//! ```
//!
//! The IMU samples become the logged sensors of control steps at the scenario's control rate (times rebased
//! to the first IMU sample, in us); each frame becomes a `Frame` record (its PNG bytes kept as they are) and
//! the ground station's measurement of it (`vision-core`'s line detector for a forward camera, its optical
//! flow for a downward one) a `Link` record delivered after the configured latency. The log has no reports:
//! `sim-host replay LOG --out REPLAYED.log` runs the flight code on it and writes them, `sim-host export` then
//! plots them.
use crate::downward::GroundFlow;
use crate::flightlog::{CameraFrame, CameraId, FrameEncoding, LogHeader, LogRecord, LogWriter};
use crate::scenario::Scenario;
use crate::vision::GroundVision;
use anyhow::{Context, Result, bail};
use control_core::estimator::ImuSample;
use flight_core::fil::SensorStep;
use protocol::{FlowMeasurement, Uplink, VisionMeasurement};
use std::path::{Path, PathBuf};

/// The EuRoC MAV's IMU axes in the body frame (x forward, y left, z up): the ADIS16448's x points up, y to
/// the right and z forward (cam0's optical axis), from the dataset's `T_BS` of cam0. Row i: body axis i in
/// IMU axes.
pub const EUROC_IMU_TO_BODY: [[f32; 3]; 3] = [[0.0, 0.0, 1.0], [0.0, -1.0, 0.0], [1.0, 0.0, 0.0]];

/// How to import.
#[derive(Clone, Debug)]
pub struct EurocOptions {
    /// The dataset folder (the one holding `imu0` and `cam0`; an `mav0` inside it is found too).
    pub dir: PathBuf,
    /// The scenario whose flight parameters replay uses; its camera is replaced by `cam0/sensor.yaml`'s.
    pub scenario: Scenario,
    /// Which camera `cam0` is.
    pub cam0: CameraId,
    /// Body axes from IMU axes (rows).
    pub imu_to_body: [[f32; 3]; 3],
    /// Delay from capture to the measurement reaching the vehicle (s).
    pub latency_s: f64,
    /// Import only the first seconds.
    pub max_seconds: Option<f64>,
}

/// What an import wrote.
#[derive(Clone, Debug, Default)]
pub struct ImportSummary {
    /// IMU samples.
    pub imu_samples: u64,
    /// Control steps.
    pub steps: u64,
    /// Frames.
    pub frames: u64,
    /// Forward frames in which the line was found, or flow pairs that gave a flow.
    pub measured: u64,
    /// Seconds of data.
    pub seconds: f64,
}

fn dataset_root(dir: &Path) -> Result<PathBuf> {
    for d in [dir.to_path_buf(), dir.join("mav0")] {
        if d.join("imu0").join("data.csv").is_file() {
            return Ok(d);
        }
    }
    bail!("{}: not a EuRoC/ASL dataset folder (no imu0/data.csv in it or in mav0/)", dir.display())
}

/// Parses an ASL CSV: `#` comment lines, comma-separated numeric columns (the last may be a file name).
fn read_csv(path: &Path, columns: usize) -> Result<Vec<(usize, Vec<String>)>> {
    let text = std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    let mut rows = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let cells: Vec<String> = line.split(',').map(|c| c.trim().to_string()).collect();
        if cells.len() != columns {
            bail!("{}:{}: {} columns, {columns} expected", path.display(), i + 1, cells.len());
        }
        rows.push((i + 1, cells));
    }
    Ok(rows)
}

fn num<T: std::str::FromStr>(path: &Path, line: usize, cell: &str, what: &str) -> Result<T> {
    cell.parse().map_err(|_| anyhow::anyhow!("{}:{line}: {what} `{cell}` is not a number", path.display()))
}

/// Reads a flat YAML list value `key: [a, b, c]` (the form of the ASL sensor files).
fn yaml_list(text: &str, key: &str) -> Option<Vec<f64>> {
    let line = text.lines().find(|l| l.trim_start().starts_with(&format!("{key}:")))?;
    let inner = line.split_once('[')?.1.split_once(']')?.0;
    inner.split(',').map(|v| v.trim().parse().ok()).collect()
}

fn yaml_number(text: &str, key: &str) -> Option<f64> {
    let line = text.lines().find(|l| l.trim_start().starts_with(&format!("{key}:")))?;
    line.split_once(':')?.1.split('#').next()?.trim().parse().ok()
}

/// Imports a EuRoC/ASL dataset into a flight log at `out`.
pub fn import_euroc(opts: &EurocOptions, out: &Path, mut progress: impl FnMut(f64)) -> Result<ImportSummary> {
    let root = dataset_root(&opts.dir)?;
    let mut scenario = opts.scenario.clone();
    let cam_dir = root.join("cam0");
    let yaml_path = cam_dir.join("sensor.yaml");
    if let Ok(yaml) = std::fs::read_to_string(&yaml_path) {
        let res = yaml_list(&yaml, "resolution");
        let k = yaml_list(&yaml, "intrinsics");
        let d = yaml_list(&yaml, "distortion_coefficients");
        let rate = yaml_number(&yaml, "rate_hz");
        match opts.cam0 {
            CameraId::Forward => {
                let c = &mut scenario.forward_camera;
                if let (Some(r), Some(k)) = (&res, &k)
                    && r.len() == 2
                    && k.len() == 4
                {
                    (c.width_px, c.height_px) = (r[0] as u16, r[1] as u16);
                    (c.fx_px, c.fy_px, c.cx_px, c.cy_px) = (k[0], k[1], k[2], k[3]);
                }
                if let Some(d) = &d
                    && d.len() >= 4
                {
                    // radial-tangential k1, k2, p1, p2 (OpenCV order).
                    c.distortion = [d[0], d[1], d[2], d[3], d.get(4).copied().unwrap_or(0.0)];
                }
                if let Some(r) = rate {
                    c.rate_hz = r;
                }
                c.latency_s = opts.latency_s;
                c.latency_jitter_s = 0.0;
            }
            CameraId::Downward => {
                let c = &mut scenario.down_camera;
                if let (Some(r), Some(k)) = (&res, &k)
                    && r.len() == 2
                    && k.len() == 4
                {
                    (c.width_px, c.height_px) = (r[0] as u16, r[1] as u16);
                    (c.fx_px, c.fy_px, c.cx_px, c.cy_px) = (k[0], k[1], k[2], k[3]);
                }
                if let Some(r) = rate {
                    c.rate_hz = r;
                }
                c.enabled = true;
                c.latency_s = opts.latency_s;
            }
        }
        scenario.validate().with_context(|| format!("the camera of {}", yaml_path.display()))?;
    }

    let imu_path = root.join("imu0").join("data.csv");
    let imu_rows = read_csv(&imu_path, 7)?;
    if imu_rows.is_empty() {
        bail!("{}: no IMU samples", imu_path.display());
    }
    let t0: u64 = num(&imu_path, imu_rows[0].0, &imu_rows[0].1[0], "timestamp")?;
    let to_us = |ns: u64| (ns.saturating_sub(t0) + 500) / 1000;
    let m = opts.imu_to_body;
    let rot = |v: [f32; 3]| [0, 1, 2].map(|i| m[i][0] * v[0] + m[i][1] * v[1] + m[i][2] * v[2]);
    let mut imu = Vec::with_capacity(imu_rows.len());
    let mut last_ns = None;
    for (line, c) in &imu_rows {
        let ns: u64 = num(&imu_path, *line, &c[0], "timestamp")?;
        if last_ns.is_some_and(|l| ns <= l) {
            bail!("{}:{line}: timestamp {ns} is not after the previous one", imu_path.display());
        }
        last_ns = Some(ns);
        let mut v = [0f32; 6];
        for k in 0..6 {
            v[k] = num(&imu_path, *line, &c[k + 1], "value")?;
        }
        imu.push(ImuSample {
            time_us: to_us(ns),
            gyro_rad_s: rot([v[0], v[1], v[2]]),
            accel_m_s2: rot([v[3], v[4], v[5]]),
        });
    }
    let end_us = match opts.max_seconds {
        Some(s) => (s * 1e6) as u64,
        None => imu.last().map(|s| s.time_us).unwrap_or(0),
    };

    let cam_csv = cam_dir.join("data.csv");
    let cam_rows = if cam_csv.is_file() { read_csv(&cam_csv, 2)? } else { Vec::new() };
    let mut frames = Vec::with_capacity(cam_rows.len());
    for (line, c) in &cam_rows {
        let ns: u64 = num(&cam_csv, *line, &c[0], "timestamp")?;
        if ns < t0 {
            continue;
        }
        let t = to_us(ns);
        if t <= end_us {
            frames.push((t, cam_dir.join("data").join(&c[1])));
        }
    }

    let header = LogHeader {
        format_version: crate::flightlog::LOG_FORMAT_VERSION,
        schema_hash: crate::flightlog::schema_hash(),
        wire_version: protocol::frame::WIRE_VERSION,
        writer: format!("sim-host {} import euroc", env!("CARGO_PKG_VERSION")),
        scenario_toml: toml::to_string(&scenario).context("the scenario as TOML")?,
        seed: 0,
        camera: format!("euroc:{}", root.display()),
        flight_computer: "none (imported dataset)".into(),
    };
    let mut w = LogWriter::create(out, &header)?;
    let mut vision = GroundVision::new(&scenario);
    let mut flow = GroundFlow::new(&scenario);
    let latency_us = (opts.latency_s.max(0.0) * 1e6).round() as u64;
    let period_us = (1e6 / scenario.mission.control_rate_hz).round().max(1.0) as u64;
    let mut summary = ImportSummary::default();
    let mut pending: Vec<(u64, Uplink)> = Vec::new();
    let (mut next_imu, mut next_frame) = (0usize, 0usize);
    let mut prev_frame_us: Option<u64> = None;
    let mut t = period_us;
    while t <= end_us + period_us {
        // The frames captured up to this step: stored, measured, their results queued for delivery.
        while next_frame < frames.len() && frames[next_frame].0 <= t {
            let (ft, path) = &frames[next_frame];
            let seq = next_frame as u32;
            next_frame += 1;
            let bytes =
                std::fs::read(path).with_context(|| format!("cannot read frame {}", path.display()))?;
            let probe = crate::imageio::gray_from_png(&bytes)
                .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
            let rgb = crate::imageio::rgb_from_png(&bytes).is_ok();
            let frame = CameraFrame {
                camera: opts.cam0,
                seq,
                capture_time_us: *ft,
                width: probe.width as u16,
                height: probe.height as u16,
                channels: if rgb { 3 } else { 1 },
                encoding: FrameEncoding::Png,
                rotation_hint_cam: [0.0; 3],
                data: bytes,
            };
            let msg = match opts.cam0 {
                CameraId::Forward => {
                    let observation = vision.detect(&frame.to_rgb()?).ok();
                    summary.measured += observation.is_some() as u64;
                    Some(Uplink::Vision(VisionMeasurement {
                        capture_time_us: *ft,
                        frame_seq: seq,
                        observation,
                    }))
                }
                CameraId::Downward => {
                    let r = flow.add(&probe, geometry::Vec3::ZERO);
                    let m = match (r, prev_frame_us) {
                        (Some(result), Some(tp)) => {
                            summary.measured += result.is_ok() as u64;
                            Some(Uplink::Flow(FlowMeasurement {
                                t_prev_us: tp,
                                t_next_us: *ft,
                                frame_seq: seq,
                                result,
                            }))
                        }
                        _ => None,
                    };
                    prev_frame_us = Some(*ft);
                    m
                }
            };
            w.write(&LogRecord::Frame(frame))?;
            summary.frames += 1;
            if let Some(m) = msg {
                // Not before the IMU has covered the capture time: the stack solves the frame with the attitude
                // at that time.
                let covered = imu.get(imu.partition_point(|s| s.time_us < *ft)).map_or(*ft, |s| s.time_us);
                pending.push(((*ft + latency_us).max(covered), m));
            }
        }
        for (_, m) in pending.iter().filter(|(at, _)| *at <= t) {
            w.write(&LogRecord::Link(*m))?;
        }
        pending.retain(|(at, _)| *at > t);
        let mut step = SensorStep { time_us: t, imu: heapless::Vec::new(), mag: None, landed: None };
        while next_imu < imu.len() && imu[next_imu].time_us <= t {
            if step.imu.push(imu[next_imu]).is_err() {
                bail!(
                    "{}: more than {} IMU samples within one {period_us} us control period at t = {} us",
                    imu_path.display(),
                    step.imu.capacity(),
                    t
                );
            }
            next_imu += 1;
            summary.imu_samples += 1;
        }
        w.write(&LogRecord::Step(step))?;
        summary.steps += 1;
        summary.seconds = t as f64 * 1e-6;
        if summary.steps.is_multiple_of(500) {
            progress(t as f64 / end_us.max(1) as f64);
        }
        t += period_us;
    }
    w.finish()?;
    Ok(summary)
}
