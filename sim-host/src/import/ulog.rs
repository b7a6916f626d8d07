//! PX4 ULog files (<https://docs.px4.io/main/en/dev_log/ulog_file_format.html>), read with the `yule_log`
//! crate (a streaming ULog parser; the logs shipped with pyulog read with the same message counts as pyulog).
//!
//! Topics used (the first instance, `multi_id` 0):
//!
//! - IMU: `sensor_combined` (`gyro_rad`, `accelerometer_m_s2`, at `timestamp`), else `sensor_gyro` and
//!   `sensor_accel` paired by time (`x`, `y`, `z`; in the body frame as PX4's drivers publish them since
//!   v1.11, before the in-run calibration);
//! - magnetometer: `vehicle_magnetometer` (`magnetometer_ga`), else the old `sensor_combined`'s
//!   `magnetometer_ga`;
//! - the vehicle's state: `vehicle_land_detected` (`landed`) and `vehicle_status` (`arming_state`, 2 =
//!   armed): a disarmed vehicle is not flying;
//! - the reference: by default the simulator's truth `vehicle_attitude_groundtruth` when the log has it (a
//!   software-in-the-loop log), else `vehicle_attitude` (`q`, PX4's own estimate, EKF2), at
//!   `timestamp_sample` when logged and set, else `timestamp` ([`ReferenceChoice`]);
//! - the parameter `EKF2_MAG_DECL` (deg): the magnetic declination, which sets the world's magnetic field
//!   direction for the flight code's heading.
//!
//! Frames: PX4's body frame is FRD and its world NED; this project's body is FLU, and imported logs use an
//! ENU world (`x` east, `y` north, `z` up): `v_FLU = (x, -y, -z)_FRD`, `R_ENU,FLU = T R_NED,FRD D` with
//! `T = [[0, 1, 0], [1, 0, 0], [0, 0, -1]]` and `D = diag(1, -1, -1)`. The yaw angles of this project are
//! measured from the navigation frame (`x_N = -y_W`): 0 faces south, counter-clockwise positive.
use super::{ImportData, ImportSummary, NoExtras, Window, import_header, write_import};
use crate::flightlog::ReferenceState;
use crate::scenario::Scenario;
use anyhow::{Context, Result, bail};
use control_core::estimator::ImuSample;
use geometry::{Mat3, Quat, Vec3};
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use yule_log::builder::ULogParserBuilder;
use yule_log::model::inst::{FieldValue, Format};
use yule_log::model::msg::UlogMessage;

/// How to import.
#[derive(Clone, Debug)]
pub struct UlogOptions {
    /// The `.ulg` file.
    pub file: PathBuf,
    /// The scenario whose flight parameters replay uses.
    pub scenario: Scenario,
    /// The window to import.
    pub window: Window,
    /// Which attitude the log keeps as the reference.
    pub reference: ReferenceChoice,
}

/// Which of the log's attitudes is the reference the replay is scored against.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum ReferenceChoice {
    /// The truth when the log has one (`vehicle_attitude_groundtruth`, written by PX4's simulators), else
    /// PX4's estimate.
    #[default]
    Auto,
    /// `vehicle_attitude_groundtruth` (refused when the log has none).
    Truth,
    /// `vehicle_attitude`: PX4's own estimate (EKF2).
    Estimator,
}

/// A field as numbers (a scalar gives one), by name.
fn field(f: &Format, name: &str) -> Option<Vec<f64>> {
    let v = &f.fields.iter().find(|x| &*x.name == name)?.value;
    Some(match v {
        FieldValue::ScalarU8(x) => vec![*x as f64],
        FieldValue::ScalarU16(x) => vec![*x as f64],
        FieldValue::ScalarU32(x) => vec![*x as f64],
        FieldValue::ScalarU64(x) => vec![*x as f64],
        FieldValue::ScalarI8(x) => vec![*x as f64],
        FieldValue::ScalarI16(x) => vec![*x as f64],
        FieldValue::ScalarI32(x) => vec![*x as f64],
        FieldValue::ScalarI64(x) => vec![*x as f64],
        FieldValue::ScalarF32(x) => vec![*x as f64],
        FieldValue::ScalarF64(x) => vec![*x],
        FieldValue::ScalarBool(x) => vec![*x as u8 as f64],
        FieldValue::ArrayF32(x) => x.iter().map(|v| *v as f64).collect(),
        FieldValue::ArrayF64(x) => x.clone(),
        FieldValue::ArrayU8(x) => x.iter().map(|v| *v as f64).collect(),
        FieldValue::ArrayI32(x) => x.iter().map(|v| *v as f64).collect(),
        FieldValue::ArrayU32(x) => x.iter().map(|v| *v as f64).collect(),
        _ => return None,
    })
}

fn vec3(f: &Format, name: &str) -> Option<[f64; 3]> {
    let v = field(f, name)?;
    (v.len() >= 3).then(|| [v[0], v[1], v[2]])
}

fn scalar(f: &Format, name: &str) -> Option<f64> {
    field(f, name)?.first().copied()
}

/// FRD body vector to FLU.
fn flu(v: [f64; 3]) -> [f32; 3] {
    [v[0] as f32, -v[1] as f32, -v[2] as f32]
}

/// PX4's attitude (NED from FRD, `[w, x, y, z]`) as this project's world-from-body (ENU from FLU).
pub fn world_from_body(q_ned_frd: [f32; 4]) -> Quat {
    let [w, x, y, z] = q_ned_frd;
    let r = Quat { w, x, y, z }.normalized().to_mat3();
    let t = Mat3 { m: [[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]] };
    let d = Mat3 { m: [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]] };
    Quat::from_mat3(&t.mul_mat(&r).mul_mat(&d))
}

/// A gyro and an accelerometer reading (FLU).
type GyroAccel = ([f32; 3], [f32; 3]);

/// What the file holds, topic by topic.
#[derive(Default)]
struct Raw {
    combined: Vec<(u64, GyroAccel)>,
    combined_mag: Vec<(u64, [f32; 3])>,
    gyro: Vec<(u64, [f32; 3])>,
    accel: Vec<(u64, [f32; 3])>,
    mag: Vec<(u64, [f32; 3])>,
    land: Vec<(u64, bool)>,
    armed: Vec<(u64, bool)>,
    attitude: Vec<(u64, [f32; 4])>,
    attitude_truth: Vec<(u64, [f32; 4])>,
    declination_deg: Option<f64>,
    data_messages: u64,
}

fn read_raw(path: &Path) -> Result<Raw> {
    let file = std::fs::File::open(path).with_context(|| format!("cannot read {}", path.display()))?;
    let parser = ULogParserBuilder::new(std::io::BufReader::new(file))
        .build()
        .map_err(|e| anyhow::anyhow!("{}: not a ULog file: {e}", path.display()))?;
    let mut subs: HashMap<u16, (String, u8)> = HashMap::new();
    let mut raw = Raw::default();
    for m in parser {
        let m = m.map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
        match m {
            UlogMessage::AddSubscription(s) => {
                subs.insert(s.msg_id, (s.message_name, s.multi_id));
            }
            // EKF2's declination, or the older attitude_estimator_q's.
            UlogMessage::Parameter(p)
                if p.key == "EKF2_MAG_DECL" || (p.key == "ATT_MAG_DECL" && raw.declination_deg.is_none()) =>
            {
                raw.declination_deg = Some(match p.value {
                    yule_log::model::inst::ParameterValue::FLOAT(v) => v as f64,
                    yule_log::model::inst::ParameterValue::INT32(v) => v as f64,
                });
            }
            UlogMessage::LoggedData(d) => {
                raw.data_messages += 1;
                let Some((name, multi)) = subs.get(&d.msg_id) else { continue };
                if *multi != 0 {
                    continue;
                }
                let f = &d.data;
                let t = d.timestamp;
                // `timestamp_sample` when set (PX4's simulator leaves it 0 in its ground-truth topics).
                let t_sample = scalar(f, "timestamp_sample").filter(|v| *v > 0.0).map_or(t, |v| v as u64);
                match name.as_str() {
                    "sensor_combined" => {
                        if let (Some(g), Some(a)) = (vec3(f, "gyro_rad"), vec3(f, "accelerometer_m_s2")) {
                            raw.combined.push((t, (flu(g), flu(a))));
                        }
                        if let (Some(m), Some(rel)) =
                            (vec3(f, "magnetometer_ga"), scalar(f, "magnetometer_timestamp_relative"))
                            && rel.abs() < 1e9
                        {
                            raw.combined_mag.push(((t as i64 + rel as i64).max(0) as u64, flu(m)));
                        }
                    }
                    "sensor_gyro" => {
                        if let (Some(x), Some(y), Some(z)) = (scalar(f, "x"), scalar(f, "y"), scalar(f, "z"))
                        {
                            raw.gyro.push((t_sample, flu([x, y, z])));
                        }
                    }
                    "sensor_accel" => {
                        if let (Some(x), Some(y), Some(z)) = (scalar(f, "x"), scalar(f, "y"), scalar(f, "z"))
                        {
                            raw.accel.push((t_sample, flu([x, y, z])));
                        }
                    }
                    "vehicle_magnetometer" => {
                        if let Some(m) = vec3(f, "magnetometer_ga") {
                            raw.mag.push((t_sample, flu(m)));
                        }
                    }
                    "vehicle_land_detected" => {
                        if let Some(l) = scalar(f, "landed") {
                            raw.land.push((t, l != 0.0));
                        }
                    }
                    "vehicle_status" => {
                        if let Some(a) = scalar(f, "arming_state") {
                            raw.armed.push((t, a == 2.0));
                        }
                    }
                    "vehicle_attitude" | "vehicle_attitude_groundtruth" => {
                        if let Some(q) = field(f, "q")
                            && q.len() == 4
                        {
                            let q = (t_sample, [q[0] as f32, q[1] as f32, q[2] as f32, q[3] as f32]);
                            if name == "vehicle_attitude" {
                                raw.attitude.push(q);
                            } else {
                                raw.attitude_truth.push(q);
                            }
                        }
                    }
                    _ => {}
                }
            }
            _ => {}
        }
    }
    Ok(raw)
}

/// Sorts by time and drops repeated timestamps; returns how many were dropped.
fn sort_dedup<T>(v: &mut Vec<(u64, T)>) -> u64 {
    v.sort_by_key(|x| x.0);
    let n = v.len();
    v.dedup_by_key(|x| x.0);
    (n - v.len()) as u64
}

/// The recorded vehicle's "landed" state over time: not flying while disarmed, else its land detector's
/// verdict (unknown without one).
fn land_states(raw: &Raw) -> Vec<(u64, Option<bool>)> {
    let mut events: Vec<(u64, u8, bool)> = raw.armed.iter().map(|(t, a)| (*t, 0, *a)).collect();
    events.extend(raw.land.iter().map(|(t, l)| (*t, 1, *l)));
    events.sort_by_key(|e| (e.0, e.1));
    let (mut armed, mut landed): (Option<bool>, Option<bool>) = (None, None);
    let mut out: Vec<(u64, Option<bool>)> = Vec::new();
    for (t, kind, v) in events {
        if kind == 0 {
            armed = Some(v);
        } else {
            landed = Some(v);
        }
        let state = if armed == Some(false) { Some(true) } else { landed };
        if out.last().is_none_or(|(_, s)| *s != state) {
            out.push((t, state));
        }
    }
    out
}

/// Imports a PX4 ULog file into a flight log at `out`.
pub fn import_ulog(opts: &UlogOptions, out: &Path, progress: impl FnMut(f64)) -> Result<ImportSummary> {
    let mut raw = read_raw(&opts.file)?;
    let mut data = ImportData::default();
    let mut notes = Vec::new();
    let dropped = sort_dedup(&mut raw.combined);
    if dropped > 0 {
        notes.push(format!("{dropped} sensor_combined samples with a repeated timestamp dropped"));
    }
    if !raw.combined.is_empty() {
        data.imu = raw
            .combined
            .iter()
            .map(|(t, (g, a))| ImuSample { time_us: *t, gyro_rad_s: *g, accel_m_s2: *a })
            .collect();
    } else if !raw.gyro.is_empty() && !raw.accel.is_empty() {
        sort_dedup(&mut raw.gyro);
        sort_dedup(&mut raw.accel);
        // Each gyro sample with the accelerometer sample nearest in time.
        let mut k = 0;
        for (t, g) in &raw.gyro {
            while k + 1 < raw.accel.len() && raw.accel[k + 1].0.abs_diff(*t) <= raw.accel[k].0.abs_diff(*t) {
                k += 1;
            }
            data.imu.push(ImuSample { time_us: *t, gyro_rad_s: *g, accel_m_s2: raw.accel[k].1 });
        }
        notes.push("IMU from sensor_gyro and sensor_accel (no sensor_combined): uncalibrated".into());
    } else {
        bail!(
            "{}: no IMU data (neither sensor_combined nor sensor_gyro with sensor_accel) in {} data messages",
            opts.file.display(),
            raw.data_messages
        );
    }
    let mag = if raw.mag.is_empty() { &mut raw.combined_mag } else { &mut raw.mag };
    sort_dedup(mag);
    data.mag = mag.iter().map(|(t, m)| (*t, Vec3::from_array(*m))).collect();
    let lands = land_states(&raw);
    sort_dedup(&mut raw.attitude);
    sort_dedup(&mut raw.attitude_truth);
    let truth = match opts.reference {
        ReferenceChoice::Truth if raw.attitude_truth.is_empty() => bail!(
            "{}: --reference truth, but the log has no vehicle_attitude_groundtruth (only PX4's simulators \
             write it)",
            opts.file.display()
        ),
        ReferenceChoice::Estimator => false,
        _ => !raw.attitude_truth.is_empty(),
    };
    if truth && !raw.attitude.is_empty() {
        notes.push(
            "reference: the simulator's truth (vehicle_attitude_groundtruth); --reference estimator for PX4's EKF2"
                .into(),
        );
    }
    let attitude = if truth { &raw.attitude_truth } else { &raw.attitude };
    let land_at = |t: u64| lands.iter().take_while(|(u, _)| *u <= t).last().and_then(|(_, s)| *s);
    data.reference = attitude
        .iter()
        .map(|(t, q)| {
            let q = world_from_body(*q);
            ReferenceState {
                time_us: *t,
                q_world_body: [q.w, q.x, q.y, q.z],
                position_m: None,
                airborne: land_at(*t).map(|l| !l),
            }
        })
        .collect();
    data.landed = lands.clone();
    let mut scenario = opts.scenario.clone();
    super::recorded_imu_tuning(&mut scenario);
    let decl = raw.declination_deg.unwrap_or(0.0).to_radians();
    // The horizontal field points to magnetic north: north (ENU y) turned east by the declination.
    scenario.estimator.mag_field_world = [decl.sin() as f32, decl.cos() as f32, -0.5];
    if raw.declination_deg.is_none() && !data.mag.is_empty() {
        notes.push("no EKF2_MAG_DECL or ATT_MAG_DECL parameter: magnetic declination taken as 0".into());
    }
    if data.mag.is_empty() {
        notes.push(
            "no magnetometer: yaw is unobservable (the summary compares it after removing the initial offset)"
                .into(),
        );
    }
    if lands.is_empty() {
        notes.push(
            "neither vehicle_status nor vehicle_land_detected: the flight state is the IMU's to tell".into(),
        );
    }
    let header = import_header(
        &scenario,
        format!("sim-host {} import ulog", env!("CARGO_PKG_VERSION")),
        format!("ulog:{}", opts.file.display()),
        if data.reference.is_empty() {
            String::new()
        } else if truth {
            "PX4 vehicle_attitude_groundtruth (the simulator's truth)".into()
        } else {
            "PX4 vehicle_attitude (the recording's own estimator: EKF2, or attitude_estimator_q in older logs)".into()
        },
        !data.mag.is_empty(),
    )?;
    let mut summary = write_import(&data, &opts.window, &scenario, header, out, &mut NoExtras, progress)?;
    summary.notes.extend(notes);
    Ok(summary)
}

#[cfg(test)]
mod tests {
    use super::*;
    use geometry::frames::Attitude;

    #[test]
    fn px4_frames_convert_to_this_projects() {
        // Level and facing north in PX4 (identity NED from FRD): level here, nose north (ENU +y), which is
        // yaw 180 deg from facing south.
        let q = world_from_body([1.0, 0.0, 0.0, 0.0]);
        let a = Attitude::from_world_from_body(&q.to_mat3());
        assert!(a.roll.abs() < 1e-6 && a.pitch.abs() < 1e-6, "{a:?}");
        assert!((a.yaw.abs() - core::f32::consts::PI).abs() < 1e-5, "{a:?}");
        let r = q.to_mat3();
        assert!((r.mul_vec(Vec3::X) - Vec3::new(0.0, 1.0, 0.0)).norm() < 1e-6);
        // PX4 roll +10 deg (right side down) and pitch +5 deg (nose up in FRD): roll +10 here (right side
        // down), pitch -5 (this project's positive pitch is nose down).
        let (r10, p5) = (10f32.to_radians(), 5f32.to_radians());
        let rx = Mat3::rot_x(r10);
        let ry = Mat3::rot_y(p5);
        let q = Quat::from_mat3(&ry.mul_mat(&rx));
        let a = Attitude::from_world_from_body(&world_from_body([q.w, q.x, q.y, q.z]).to_mat3());
        assert!((a.roll - r10).abs() < 1e-5, "roll {}", a.roll.to_degrees());
        assert!((a.pitch + p5).abs() < 1e-5, "pitch {}", a.pitch.to_degrees());
        // Body vectors: FRD (1, 2, 3) is FLU (1, -2, -3).
        assert_eq!(flu([1.0, 2.0, 3.0]), [1.0, -2.0, -3.0]);
    }

    #[test]
    fn disarmed_is_not_flying_and_the_land_detector_decides_when_armed() {
        let raw = Raw {
            armed: vec![(0, false), (10, true), (50, false)],
            land: vec![(5, true), (20, false), (40, true)],
            ..Raw::default()
        };
        let s = land_states(&raw);
        assert_eq!(s, vec![(0, Some(true)), (20, Some(false)), (40, Some(true))]);
        let raw = Raw { armed: vec![(0, true)], ..Raw::default() };
        assert_eq!(land_states(&raw), vec![(0, None)]);
    }
}
