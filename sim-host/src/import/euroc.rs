//! EuRoC / ASL folder layout (Burri et al., "The EuRoC micro aerial vehicle datasets", IJRR 2016):
//!
//! ```text
//! DIR/imu0/data.csv         #timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y,w_RS_S_z,a_RS_S_x [m s^-2],a_RS_S_y,a_RS_S_z
//! DIR/state_groundtruth_estimate0/data.csv   optional: timestamp [ns], p_RS_R xyz [m], q_RS wxyz (8 or more columns)
//! DIR/mag0/data.csv         optional: timestamp [ns], magnetic field x, y, z in the IMU's axes (any unit)
//! DIR/cam0/data.csv         optional: #timestamp [ns],filename
//! DIR/cam0/data/*.png       the frames
//! DIR/cam0/sensor.yaml      optional: resolution, intrinsics [fu, fv, cu, cv], distortion_coefficients, rate_hz
//! ```
//!
//! The IMU's axes become the body axes with `imu_to_body`; the ground truth (the IMU's pose in the
//! dataset's world, whose `z` is up) becomes the `Reference` records with the same rotation. Each frame
//! becomes a `Frame` record (its PNG bytes kept as they are) and the ground station's measurement of it
//! (`vision-core`'s line detector for a forward camera, its optical flow for a downward one) a `Link` record
//! delivered after the configured latency, and not before the IMU has covered its capture time. Without a
//! camera or a magnetometer, yaw is unobservable and the import says so. The recorded vehicle's IMU
//! mounting relative to its rotors is unknown, so the flight code learns the thrust axis in flight
//! (`estimator.thrust_axis_learn_s`, set to 30 s when the scenario leaves it at 0).
use super::{ExtraRecords, ImportData, ImportSummary, Window, import_header, write_import};
use crate::downward::GroundFlow;
use crate::flightlog::{CameraFrame, CameraId, FrameEncoding, LogRecord, ReferenceState};
use crate::imageio::FrameImages;
use crate::scenario::Scenario;
use crate::vision::GroundVision;
use anyhow::{Context, Result, bail};
use control_core::estimator::ImuSample;
use geometry::{Mat3, Quat, Vec3};
use protocol::{FlowMeasurement, Uplink, VisionMeasurement};
use std::path::{Path, PathBuf};

/// The EuRoC MAV's IMU axes in the body frame (x forward, y left, z up): the ADIS16448's x points up, y to
/// the right and z forward (cam0's optical axis), from the dataset's `T_BS` of cam0. Row i: body axis i in
/// IMU axes.
pub const EUROC_IMU_TO_BODY: [[f32; 3]; 3] = [[0.0, 0.0, 1.0], [0.0, -1.0, 0.0], [1.0, 0.0, 0.0]];

/// The time constant with which the flight code learns an imported vehicle's thrust axis (s).
pub const IMPORT_THRUST_AXIS_LEARN_S: f32 = 30.0;

/// How to import.
#[derive(Clone, Debug)]
pub struct EurocOptions {
    /// The dataset folder (the one holding `imu0`; an `mav0` inside it is found too).
    pub dir: PathBuf,
    /// The scenario whose flight parameters replay uses; its camera is replaced by `cam0/sensor.yaml`'s.
    pub scenario: Scenario,
    /// Which camera `cam0` is.
    pub cam0: CameraId,
    /// Body axes from IMU axes (rows).
    pub imu_to_body: [[f32; 3]; 3],
    /// Delay from capture to the measurement reaching the vehicle (s).
    pub latency_s: f64,
    /// The window to import.
    pub window: Window,
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
    read_csv_at_least(path, columns, columns)
}

/// [`read_csv`] for files whose rows may carry more columns than the `min` that are read.
fn read_csv_at_least(path: &Path, min: usize, max: usize) -> Result<Vec<(usize, Vec<String>)>> {
    let text = std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    let mut rows = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let cells: Vec<String> = line.split(',').map(|c| c.trim().to_string()).collect();
        if cells.len() < min || cells.len() > max {
            let want = if min == max { format!("{min}") } else { format!("{min} to {max}") };
            bail!("{}:{}: {} columns, {want} expected", path.display(), i + 1, cells.len());
        }
        rows.push((i + 1, cells));
    }
    Ok(rows)
}

fn num<T: std::str::FromStr>(path: &Path, line: usize, cell: &str, what: &str) -> Result<T> {
    cell.parse().map_err(|_| anyhow::anyhow!("{}:{line}: {what} `{cell}` is not a number", path.display()))
}

/// Reads a flat YAML list value `key: [a, b, c]` (the form of the ASL sensor files).
/// Reads the dataset into this project's frames (times in us since the first IMU sample's
/// nanosecond timestamp, which is returned too).
fn read(root: &Path, m: &[[f32; 3]; 3]) -> Result<(ImportData, u64)> {
    let imu_path = root.join("imu0").join("data.csv");
    let imu_rows = read_csv(&imu_path, 7)?;
    if imu_rows.is_empty() {
        bail!("{}: no IMU samples", imu_path.display());
    }
    let t0: u64 = num(&imu_path, imu_rows[0].0, &imu_rows[0].1[0], "timestamp")?;
    let to_us = |ns: u64| (ns.saturating_sub(t0) + 500) / 1000;
    let rot = |v: [f32; 3]| [0, 1, 2].map(|i| m[i][0] * v[0] + m[i][1] * v[1] + m[i][2] * v[2]);
    let mut data = ImportData::default();
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
        data.imu.push(ImuSample {
            time_us: to_us(ns),
            gyro_rad_s: rot([v[0], v[1], v[2]]),
            accel_m_s2: rot([v[3], v[4], v[5]]),
        });
    }
    let mag_path = root.join("mag0").join("data.csv");
    if mag_path.is_file() {
        for (line, c) in read_csv(&mag_path, 4)? {
            let ns: u64 = num(&mag_path, line, &c[0], "timestamp")?;
            let mut v = [0f32; 3];
            for k in 0..3 {
                v[k] = num(&mag_path, line, &c[k + 1], "value")?;
            }
            if ns >= t0 {
                data.mag.push((to_us(ns), Vec3::from_array(rot(v))));
            }
        }
    }
    let gt_path = root.join("state_groundtruth_estimate0").join("data.csv");
    if gt_path.is_file() {
        // Body from IMU: rows of `m`; R_WB = R_WI * R_IB with R_IB = m^T.
        let r_ib = Mat3 { m: *m }.transpose();
        for (line, c) in read_csv_at_least(&gt_path, 8, 64)? {
            let ns: u64 = num(&gt_path, line, &c[0], "timestamp")?;
            let mut v = [0f32; 7];
            for k in 0..7 {
                v[k] = num(&gt_path, line, &c[k + 1], "value")?;
            }
            if ns < t0 {
                continue;
            }
            let q_wi = Quat { w: v[3], x: v[4], y: v[5], z: v[6] }.normalized();
            if !q_wi.is_finite() {
                bail!("{}:{line}: the quaternion is not a rotation", gt_path.display());
            }
            let q = Quat::from_mat3(&q_wi.to_mat3().mul_mat(&r_ib));
            data.reference.push(ReferenceState {
                time_us: to_us(ns),
                q_world_body: [q.w, q.x, q.y, q.z],
                position_m: Some([v[0], v[1], v[2]]),
                airborne: None,
            });
        }
    }
    Ok((data, t0))
}

/// The camera frames: read, measured by the ground station, delivered after the latency.
struct Frames {
    cam0: CameraId,
    frames: Vec<(u64, PathBuf)>,
    next: usize,
    vision: GroundVision,
    flow: GroundFlow,
    prev_frame_us: Option<u64>,
    pending: Vec<(u64, Uplink)>,
    imu_times: Vec<u64>,
    latency_us: u64,
}

impl ExtraRecords for Frames {
    fn due(
        &mut self,
        t: u64,
        origin: u64,
        out: &mut Vec<LogRecord>,
        summary: &mut ImportSummary,
    ) -> Result<()> {
        let rebase = |x: u64| x.saturating_sub(origin);
        while self.next < self.frames.len() && self.frames[self.next].0 <= t {
            let (ft, path) = self.frames[self.next].clone();
            let seq = self.next as u32;
            self.next += 1;
            if ft < origin {
                continue;
            }
            let bytes =
                std::fs::read(&path).with_context(|| format!("cannot read frame {}", path.display()))?;
            let probe = crate::imageio::gray_from_png(&bytes)
                .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
            let rgb = crate::imageio::rgb_from_png(&bytes).is_ok();
            let frame = CameraFrame {
                camera: self.cam0,
                seq,
                capture_time_us: rebase(ft),
                width: probe.width as u16,
                height: probe.height as u16,
                channels: if rgb { 3 } else { 1 },
                encoding: FrameEncoding::Png,
                rotation_hint_cam: [0.0; 3],
                data: bytes,
            };
            let msg = match self.cam0 {
                CameraId::Forward => {
                    let observation = summary.no_target.record(self.vision.detect(&frame.to_rgb()?));
                    summary.measured += observation.is_some() as u64;
                    Some(Uplink::Vision(VisionMeasurement {
                        capture_time_us: rebase(ft),
                        frame_seq: seq,
                        observation,
                    }))
                }
                CameraId::Downward => {
                    let r = self.flow.add(&probe, Vec3::ZERO);
                    let m = match (r, self.prev_frame_us) {
                        (Some(result), Some(tp)) => {
                            summary.measured += result.is_ok() as u64;
                            Some(Uplink::Flow(FlowMeasurement {
                                t_prev_us: rebase(tp),
                                t_next_us: rebase(ft),
                                frame_seq: seq,
                                result,
                            }))
                        }
                        _ => None,
                    };
                    self.prev_frame_us = Some(ft);
                    m
                }
            };
            out.push(LogRecord::Frame(frame));
            summary.frames += 1;
            if let Some(m) = msg {
                // Not before the IMU has covered the capture time: the stack solves the frame with the attitude
                // at that time.
                let covered =
                    self.imu_times.get(self.imu_times.partition_point(|s| *s < ft)).map_or(ft, |s| *s);
                self.pending.push(((ft + self.latency_us).max(covered), m));
            }
        }
        for (_, m) in self.pending.iter().filter(|(at, _)| *at <= t) {
            out.push(LogRecord::Link(*m));
        }
        self.pending.retain(|(at, _)| *at > t);
        Ok(())
    }
}

/// Imports a EuRoC/ASL dataset into a flight log at `out`.
pub fn import_euroc(opts: &EurocOptions, out: &Path, progress: impl FnMut(f64)) -> Result<ImportSummary> {
    let root = dataset_root(&opts.dir)?;
    let mut scenario = opts.scenario.clone();
    super::recorded_imu_tuning(&mut scenario);
    let cam_dir = root.join("cam0");
    let yaml_path = cam_dir.join("sensor.yaml");
    let mut camera_notes = Vec::new();
    if yaml_path.is_file() {
        // The same reader as the ground station's `--calib-*` (a malformed file is refused, naming the field).
        let cal = ground_station::calib::load(&yaml_path).map_err(anyhow::Error::msg)?;
        let k = cal.camera;
        let (w, h) = (k.width, k.height);
        let [fx, fy, cx, cy] = cal.intrinsics_px;
        match opts.cam0 {
            CameraId::Forward => {
                let c = &mut scenario.forward_camera;
                (c.width_px, c.height_px) = (w, h);
                (c.fx_px, c.fy_px, c.cx_px, c.cy_px) = (fx, fy, cx, cy);
                c.distortion = cal.distortion;
                if let Some(r) = cal.rate_hz {
                    c.rate_hz = r;
                }
                c.latency_s = opts.latency_s;
                c.latency_jitter_s = 0.0;
            }
            CameraId::Downward => {
                let c = &mut scenario.down_camera;
                if !k.distortion.is_zero() {
                    camera_notes.push(format!(
                        "{}: the downward camera's lens distortion is not modelled by the flow (its \
                         intrinsics are used, its distortion coefficients are not)",
                        yaml_path.display()
                    ));
                }
                (c.width_px, c.height_px) = (w, h);
                (c.fx_px, c.fy_px, c.cx_px, c.cy_px) = (fx, fy, cx, cy);
                if let Some(r) = cal.rate_hz {
                    c.rate_hz = r;
                }
                c.enabled = true;
                c.latency_s = opts.latency_s;
            }
        }
        scenario.validate().with_context(|| format!("the camera of {}", yaml_path.display()))?;
    }

    if scenario.estimator.thrust_axis_learn_s == 0.0 {
        scenario.estimator.thrust_axis_learn_s = IMPORT_THRUST_AXIS_LEARN_S;
    }
    let (data, t0) = read(&root, &opts.imu_to_body)?;
    let cam_csv = cam_dir.join("data.csv");
    let cam_rows = if cam_csv.is_file() { read_csv(&cam_csv, 2)? } else { Vec::new() };
    let mut frames = Vec::with_capacity(cam_rows.len());
    for (line, c) in &cam_rows {
        let ns: u64 = num(&cam_csv, *line, &c[0], "timestamp")?;
        if ns >= t0 {
            frames.push(((ns - t0 + 500) / 1000, cam_dir.join("data").join(&c[1])));
        }
    }
    let mut notes = camera_notes;
    if frames.is_empty() && data.mag.is_empty() {
        notes.push(
            "neither a camera nor a magnetometer: yaw is unobservable (the summary compares it after removing \
             the initial offset)"
                .to_string(),
        );
    }
    if data.reference.is_empty() {
        notes.push(format!(
            "no ground truth ({} missing): replay --summary has nothing to compare with",
            Path::new("state_groundtruth_estimate0/data.csv").display()
        ));
    }
    let header = import_header(
        &scenario,
        format!("sim-host {} import euroc", env!("CARGO_PKG_VERSION")),
        format!("euroc:{}", root.display()),
        if data.reference.is_empty() {
            String::new()
        } else {
            "EuRoC ground truth (state_groundtruth_estimate0)".into()
        },
        false,
    )?;
    let mut extras = Frames {
        cam0: opts.cam0,
        frames,
        next: 0,
        vision: GroundVision::new(&scenario),
        flow: GroundFlow::new(&scenario),
        prev_frame_us: None,
        pending: Vec::new(),
        imu_times: data.imu.iter().map(|s| s.time_us).collect(),
        latency_us: (opts.latency_s.max(0.0) * 1e6).round() as u64,
    };
    let mut summary = write_import(&data, &opts.window, &scenario, header, out, &mut extras, progress)?;
    summary.notes.extend(notes);
    Ok(summary)
}
