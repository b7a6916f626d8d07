//! Scoring an attitude estimate against a log's reference (`Reference` records: an imported dataset's
//! ground truth, or the recording's own estimator), with a reference filter run on the same samples beside
//! it.
//!
//! - The errors are those of the roll, pitch and yaw angles (this project's convention, `docs/frames.md`),
//!   each wrapped to +-180 deg. Without an absolute heading (no magnetometer) yaw is compared after removing
//!   the offset at the first compared sample.
//! - Each reference is compared with the estimate interpolated (normalised linear interpolation of the
//!   quaternions) between the two control steps around its time.
//! - Comparisons start at the flight code's first attitude: it integrates an IMU sample when the next one
//!   arrives (its spike filter looks one sample ahead), and it has a tilt once an accelerometer sample or
//!   block of samples has given it (its reported tilt standard deviation falls below half of
//!   `UNALIGNED_TILT_SIGMA_RAD`; a first sample shaken by rotor vibration leaves the level starting guess
//!   for the first block, 50 ms). The references before that step are counted
//!   (`not_compared_before_first_attitude`) and compared for neither filter. (A recording whose reference
//!   starts before its IMU, as PX4's logs can, would otherwise score the level initial state.)
//! - Segments: the whole log; where the reference says whether the vehicle flew (a land detector), the
//!   airborne and the grounded samples; else, where the reference has positions, the longest stretch in
//!   which it stood still (speed below 0.05 m/s for 2 s or more) and the flight after it (from take-off to
//!   the end of the log).
//!
//! The reference filter is a Mahony complementary filter (Mahony, Hamel and Pflimlin, "Nonlinear
//! complementary filters on the special orthogonal group", IEEE TAC 53(5), 2008): the gyro corrected by
//! `kp e + integral(ki e)`, where `e` is the cross product of the measured and the predicted gravity
//! directions (and, with a magnetometer, the heading error about the vertical). Gains: `kp = 0.5`, the
//! proportional gain of the widely used reference implementation (x-io's MahonyAHRS), and `ki = 0.05`, so
//! that it tracks a gyro bias; it starts from the first accelerometer sample, as the flight code does.
use crate::flightlog::ReferenceState;
use control_core::estimator::ImuSample;
use geometry::frames::Attitude;
use geometry::{Quat, Vec3};
use serde_json::{Value, json};

/// Mahony's proportional gain (rad/s per unit error).
pub const MAHONY_KP: f32 = 0.5;
/// Mahony's integral gain (rad/s^2 per unit error).
pub const MAHONY_KI: f32 = 0.05;

/// The Mahony complementary filter (gravity, optionally a magnetometer's heading).
#[derive(Clone, Debug)]
pub struct Mahony {
    /// World from body.
    pub q: Quat,
    bias: Vec3,
    kp: f32,
    ki: f32,
    last_us: Option<u64>,
    mag_world_heading: Option<f32>,
    mag_error: Vec3,
    heading_set: bool,
}

impl Mahony {
    /// A filter with the given gains; `mag_field_world` gives the heading of the world's field when a
    /// magnetometer is used.
    pub fn new(kp: f32, ki: f32, mag_field_world: Option<[f32; 3]>) -> Self {
        Self {
            q: Quat::IDENTITY,
            bias: Vec3::ZERO,
            kp,
            ki,
            last_us: None,
            mag_world_heading: mag_field_world.map(|m| (m[1]).atan2(m[0])),
            mag_error: Vec3::ZERO,
            heading_set: false,
        }
    }

    /// A magnetometer reading (body): the first sets the heading, later ones' heading error about the
    /// vertical enters the next updates.
    pub fn mag(&mut self, m: Vec3) {
        let Some(h) = self.mag_world_heading else { return };
        if self.last_us.is_none() {
            return;
        }
        let w = self.q.rotate(m);
        if w.x * w.x + w.y * w.y < 1e-12 {
            return;
        }
        let err = geometry::wrap_pi(h - (w.y).atan2(w.x));
        if !self.heading_set {
            self.q = Quat::from_rotvec(Vec3::new(0.0, 0.0, err)).mul(&self.q).normalized();
            self.heading_set = true;
            return;
        }
        self.mag_error = self.q.inverse_rotate(Vec3::Z) * err;
    }

    /// One IMU sample.
    pub fn update(&mut self, s: &ImuSample) {
        let w = Vec3::from_array(s.gyro_rad_s);
        let a = Vec3::from_array(s.accel_m_s2);
        let Some(last) = self.last_us else {
            let roll = (a.y).atan2(a.z);
            let pitch = (-a.x).atan2((a.y * a.y + a.z * a.z).sqrt());
            self.q = Quat::from_mat3(&Attitude::new(roll, pitch, 0.0).world_from_body());
            self.last_us = Some(s.time_us);
            return;
        };
        if s.time_us <= last {
            return;
        }
        let dt = ((s.time_us - last) as f32 * 1e-6).min(0.1);
        self.last_us = Some(s.time_us);
        let up = self.q.inverse_rotate(Vec3::Z);
        let mut e = a.normalized().map_or(Vec3::ZERO, |f| f.cross(up));
        e += self.mag_error;
        self.bias -= e * (self.ki * dt);
        self.q = self.q.mul(&Quat::from_rotvec((w - self.bias + e * self.kp) * dt)).normalized();
    }
}

/// Squared-error sums, sums and maxima of roll, pitch and yaw (deg).
#[derive(Clone, Copy, Debug, Default)]
struct Errors {
    n: [u64; 3],
    sum_sq: [f64; 3],
    sum: [f64; 3],
    max: [f64; 3],
}

impl Errors {
    /// Adds the errors; yaw only when it is known (`None` before the estimate has a heading).
    fn add(&mut self, e: [f64; 3], yaw_known: bool) {
        for i in 0..3 {
            if i == 2 && !yaw_known {
                continue;
            }
            self.n[i] += 1;
            self.sum_sq[i] += e[i] * e[i];
            self.sum[i] += e[i];
            self.max[i] = self.max[i].max(e[i].abs());
        }
    }
    /// RMS, largest and mean errors.
    fn json(&self) -> (Value, Value, Value) {
        let f = |i: usize, v: f64| if self.n[i] == 0 { Value::Null } else { json!(v) };
        let rms = |i: usize| f(i, (self.sum_sq[i] / self.n[i].max(1) as f64).sqrt());
        let max = |i: usize| f(i, self.max[i]);
        let mean = |i: usize| f(i, self.sum[i] / self.n[i].max(1) as f64);
        (
            json!({"roll": rms(0), "pitch": rms(1), "yaw": rms(2)}),
            json!({"roll": max(0), "pitch": max(1), "yaw": max(2)}),
            json!({"roll": mean(0), "pitch": mean(1), "yaw": mean(2)}),
        )
    }
}

/// One compared sample.
#[derive(Clone, Copy, Debug)]
struct Sample {
    time_us: u64,
    ours: [f64; 3],
    mahony: [f64; 3],
    airborne: Option<bool>,
    position: Option<[f32; 3]>,
    yaw_known: bool,
}

fn angles(q: &Quat) -> [f64; 3] {
    let a = Attitude::from_world_from_body(&q.to_mat3());
    [a.roll as f64, a.pitch as f64, a.yaw as f64].map(f64::to_degrees)
}

fn wrap180(d: f64) -> f64 {
    (d + 180.0).rem_euclid(360.0) - 180.0
}

fn nlerp(a: &Quat, b: &Quat, f: f32) -> Quat {
    let s = if a.w * b.w + a.x * b.x + a.y * b.y + a.z * b.z < 0.0 { -1.0 } else { 1.0 };
    Quat {
        w: a.w + (s * b.w - a.w) * f,
        x: a.x + (s * b.x - a.x) * f,
        y: a.y + (s * b.y - a.y) * f,
        z: a.z + (s * b.z - a.z) * f,
    }
    .normalized()
}

/// The score of a replay against the log's reference.
pub struct ReferenceScore {
    what: String,
    yaw_absolute: bool,
    mahony: Mahony,
    pending: std::collections::VecDeque<ReferenceState>,
    /// The previous step: time, our attitude, Mahony's, and whether ours had a heading.
    prev: Option<(u64, Quat, Quat, bool)>,
    samples: Vec<Sample>,
    yaw_offset: Option<[f64; 2]>,
    /// IMU samples seen so far.
    imu_seen: usize,
    /// The first step after which the flight code had an attitude from the IMU: it integrates a sample when
    /// the next one arrives (its spike filter looks one sample ahead), so from the second sample's step.
    first_attitude_us: Option<u64>,
    /// Reference states before it (not compared: neither filter is scored before the flight code has an
    /// attitude).
    before_first_attitude: usize,
}

impl ReferenceScore {
    /// A score for a log whose reference is `what`; `mag_field_world` (the flight code's) lets the
    /// reference filter use the magnetometer when the yaw is absolute.
    pub fn new(what: &str, yaw_absolute: bool, mag_field_world: [f32; 3]) -> Self {
        Self {
            what: what.to_string(),
            yaw_absolute,
            mahony: Mahony::new(MAHONY_KP, MAHONY_KI, yaw_absolute.then_some(mag_field_world)),
            pending: Default::default(),
            prev: None,
            samples: Vec::new(),
            yaw_offset: None,
            imu_seen: 0,
            first_attitude_us: None,
            before_first_attitude: 0,
        }
    }

    /// A reference record.
    pub fn reference(&mut self, r: &ReferenceState) {
        self.pending.push_back(*r);
    }

    /// A step: its IMU samples and magnetometer (fed to the reference filter), the flight code's attitude
    /// after it, whether that attitude has a tilt (comparisons start there: before it the flight code holds
    /// its level starting guess and says so with its tilt uncertainty) and whether it has a heading (yaw is
    /// compared from then on when it is absolute).
    pub fn step(
        &mut self,
        time_us: u64,
        imu: &[ImuSample],
        mag: Option<Vec3>,
        estimate: &Quat,
        tilt_known: bool,
        yaw_known: bool,
    ) {
        if let Some(m) = mag {
            self.mahony.mag(m);
        }
        for s in imu {
            self.mahony.update(s);
        }
        self.imu_seen += imu.len();
        if self.first_attitude_us.is_none() {
            if self.imu_seen < 2 || !tilt_known {
                return;
            }
            self.first_attitude_us = Some(time_us);
            // Everything before this step is from before the flight code's first attitude.
            while self.pending.front().is_some_and(|r| r.time_us < time_us) {
                self.pending.pop_front();
                self.before_first_attitude += 1;
            }
        }
        let yaw_known = yaw_known || !self.yaw_absolute;
        let now = (time_us, *estimate, self.mahony.q, yaw_known);
        while let Some(r) = self.pending.front().copied() {
            if r.time_us > time_us {
                break;
            }
            self.pending.pop_front();
            // Between the previous step and this one.
            let (ours, mahony) = match self.prev {
                Some((t0, q0, m0, known0)) if r.time_us >= t0 && time_us > t0 => {
                    let f = (r.time_us - t0) as f32 / (time_us - t0) as f32;
                    // Not across the heading's first fix: the attitude before it has no heading, and a
                    // blend of the two would be scored as a heading error of up to the whole correction.
                    let ours = if known0 == yaw_known { nlerp(&q0, estimate, f) } else { *estimate };
                    (ours, nlerp(&m0, &self.mahony.q, f))
                }
                Some((t0, _, _, _)) if r.time_us < t0 => continue,
                _ => (*estimate, self.mahony.q),
            };
            let [w, x, y, z] = r.q_world_body;
            let truth = angles(&Quat { w, x, y, z });
            let (a, m) = (angles(&ours), angles(&mahony));
            let off = *self.yaw_offset.get_or_insert([wrap180(a[2] - truth[2]), wrap180(m[2] - truth[2])]);
            let err = |e: [f64; 3], k: usize| {
                let yaw = if self.yaw_absolute { e[2] - truth[2] } else { e[2] - truth[2] - off[k] };
                [wrap180(e[0] - truth[0]), wrap180(e[1] - truth[1]), wrap180(yaw)]
            };
            self.samples.push(Sample {
                time_us: r.time_us,
                ours: err(a, 0),
                mahony: err(m, 1),
                airborne: r.airborne,
                position: r.position_m,
                yaw_known,
            });
        }
        self.prev = Some(now);
    }

    /// Samples compared so far.
    pub fn len(&self) -> usize {
        self.samples.len()
    }

    /// Whether nothing was compared.
    pub fn is_empty(&self) -> bool {
        self.samples.is_empty()
    }

    /// The segments: name and sample index range.
    fn segments(&self) -> Vec<(&'static str, usize, usize)> {
        let n = self.samples.len();
        let mut out = vec![("whole", 0, n)];
        if self.samples.iter().any(|s| s.airborne.is_some()) {
            let air: Vec<usize> = (0..n).filter(|&i| self.samples[i].airborne == Some(true)).collect();
            if let (Some(&a), Some(&b)) = (air.first(), air.last()) {
                out.push(("airborne", a, b + 1));
            }
            if let Some(first) = (0..n).find(|&i| self.samples[i].airborne == Some(false)) {
                let end = air.first().copied().unwrap_or(n).max(first + 1);
                out.push(("ground_before_take_off", first, end));
            }
        } else if self.samples.iter().all(|s| s.position.is_some()) && n > 1 {
            // The longest still stretch: speed below 0.05 m/s over 2 s or more.
            let mut best: Option<(usize, usize)> = None;
            let mut start = 0;
            for i in 1..=n {
                let moving = i == n || {
                    let (a, b) = (&self.samples[i - 1], &self.samples[i]);
                    let dt = (b.time_us.saturating_sub(a.time_us)) as f64 * 1e-6;
                    let (pa, pb) = (a.position.unwrap_or_default(), b.position.unwrap_or_default());
                    let d = ((0..3).map(|k| (pb[k] - pa[k]) as f64).map(|x| x * x).sum::<f64>()).sqrt();
                    dt > 0.0 && d / dt > 0.05
                };
                if moving {
                    let span = self.samples[i - 1].time_us.saturating_sub(self.samples[start].time_us);
                    if span >= 2_000_000 && best.is_none_or(|(a, b)| b - a < i - start) {
                        best = Some((start, i));
                    }
                    start = i;
                }
            }
            if let Some((a, b)) = best {
                out.push(("still", a, b));
                if b < n {
                    out.push(("flight", b, n));
                }
            }
        }
        out
    }

    /// The summary (`replay --summary`).
    pub fn json(&self) -> Value {
        let seg = |name: &str, a: usize, b: usize| {
            let (mut ours, mut mahony) = (Errors::default(), Errors::default());
            for s in &self.samples[a..b] {
                ours.add(s.ours, s.yaw_known);
                mahony.add(s.mahony, s.yaw_known);
            }
            let (rms, max, mean) = ours.json();
            let (mrms, mmax, mmean) = mahony.json();
            let t = |i: usize| self.samples.get(i).map_or(0.0, |s| s.time_us as f64 * 1e-6);
            json!({
                "name": name,
                "start_s": t(a),
                "end_s": t(b.saturating_sub(1)),
                "samples": b - a,
                "attitude_rms_error_deg": rms,
                "attitude_max_error_deg": max,
                "attitude_mean_error_deg": mean,
                "mahony": {"attitude_rms_error_deg": mrms, "attitude_max_error_deg": mmax,
                           "attitude_mean_error_deg": mmean},
            })
        };
        let segments: Vec<Value> = self.segments().iter().map(|(n, a, b)| seg(n, *a, *b)).collect();
        let whole = seg("whole", 0, self.samples.len());
        json!({
            "reference": self.what,
            "yaw": if self.yaw_absolute { "absolute" } else { "relative: the offset at the first sample removed" },
            "samples": self.samples.len(),
            "not_compared_before_first_attitude": self.before_first_attitude,
            "attitude_rms_error_deg": whole["attitude_rms_error_deg"],
            "attitude_max_error_deg": whole["attitude_max_error_deg"],
            "mahony": {
                "kp": MAHONY_KP,
                "ki": MAHONY_KI,
                "attitude_rms_error_deg": whole["mahony"]["attitude_rms_error_deg"],
                "attitude_max_error_deg": whole["mahony"]["attitude_max_error_deg"],
            },
            "segments": segments,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_known_offset_is_measured_and_relative_yaw_removes_the_start() {
        let truth = Quat::from_mat3(&Attitude::new(0.0, 0.0, 0.3).world_from_body());
        let ours = Quat::from_mat3(&Attitude::new(2f32.to_radians(), 0.0, 0.5).world_from_body());
        let mut s = ReferenceScore::new("test", false, [1.0, 0.0, 0.0]);
        for k in 1..=100u64 {
            let r = ReferenceState {
                time_us: k * 1000,
                q_world_body: [truth.w, truth.x, truth.y, truth.z],
                position_m: None,
                airborne: Some(k > 50),
            };
            s.reference(&r);
            let imu = ImuSample { time_us: k * 1000, gyro_rad_s: [0.0; 3], accel_m_s2: [0.0, 0.0, 9.81] };
            s.step(k * 1000, &[imu], None, &ours, true, true);
        }
        let j = s.json();
        // The first reference comes before the flight code's first attitude (its second IMU sample).
        assert_eq!(j["not_compared_before_first_attitude"], 1);
        assert_eq!(j["samples"], 99);
        assert!((j["attitude_rms_error_deg"]["roll"].as_f64().unwrap() - 2.0).abs() < 1e-3, "{j}");
        assert!(j["attitude_rms_error_deg"]["yaw"].as_f64().unwrap() < 1e-3, "{j}");
        let names: Vec<&str> =
            j["segments"].as_array().unwrap().iter().map(|s| s["name"].as_str().unwrap()).collect();
        assert_eq!(names, ["whole", "airborne", "ground_before_take_off"]);
        assert_eq!(j["segments"][1]["samples"], 50);
    }

    /// A reference with an attitude only (no position, no land detector).
    fn attitude_only(time_us: u64, q: &Quat) -> ReferenceState {
        ReferenceState { time_us, q_world_body: [q.w, q.x, q.y, q.z], position_m: None, airborne: None }
    }

    #[test]
    fn nothing_is_scored_before_the_flight_code_knows_its_tilt() {
        // The truth is pitched 20 deg; the flight code holds its level starting guess (tilt unknown) for the
        // first 50 ms, as it does when its first sample is too shaken to give the tilt, then has it right.
        let truth = Quat::from_mat3(&Attitude::new(0.0, 20f32.to_radians(), 0.0).world_from_body());
        let level = Quat::from_mat3(&Attitude::default().world_from_body());
        let mut s = ReferenceScore::new("test", false, [1.0, 0.0, 0.0]);
        for ms in 1..=200u64 {
            s.reference(&attitude_only(ms * 1000, &truth));
            let imu = ImuSample { time_us: ms * 1000, gyro_rad_s: [0.0; 3], accel_m_s2: [0.0, 0.0, 9.81] };
            let known = ms >= 50;
            s.step(ms * 1000, &[imu], None, if known { &truth } else { &level }, known, true);
        }
        let j = s.json();
        assert!(j["attitude_max_error_deg"]["pitch"].as_f64().unwrap() < 1e-3, "{j}");
        assert_eq!(j["not_compared_before_first_attitude"], 49);
        assert_eq!(j["samples"], 151);
    }

    #[test]
    fn mahony_levels_a_tilted_start_and_tracks_a_gyro_bias() {
        // At rest tilted 10 deg in roll with a gyro bias: the first sample aligns it; the bias is learned.
        let truth = Attitude::new(10f32.to_radians(), 0.0, 0.0);
        let f = truth.world_from_body().tmul_vec(Vec3::new(0.0, 0.0, 9.81));
        let mut m = Mahony::new(MAHONY_KP, MAHONY_KI, None);
        for k in 0..200_000u64 {
            m.update(&ImuSample {
                time_us: k * 1000,
                gyro_rad_s: [0.01, -0.005, 0.0],
                accel_m_s2: f.to_array(),
            });
        }
        let a = Attitude::from_world_from_body(&m.q.to_mat3());
        assert!((a.roll - truth.roll).abs() < 0.05f32.to_radians(), "{}", a.roll.to_degrees());
        assert!((m.bias - Vec3::new(0.01, -0.005, 0.0)).norm() < 1e-3, "{:?}", m.bias);
    }

    #[test]
    fn no_heading_error_is_scored_across_the_first_heading_fix() {
        // Absolute yaw: the truth heads 90 deg; our heading is unknown (0) until the step at 20 ms, then right.
        // References every millisecond, steps every 10 ms: the references between 10 and 20 ms must be scored
        // against the attitude with the heading, not a blend of before and after.
        let truth = Quat::from_mat3(&Attitude::new(0.0, 0.0, 90f32.to_radians()).world_from_body());
        let level = Quat::from_mat3(&Attitude::new(0.0, 0.0, 0.0).world_from_body());
        let mut s = ReferenceScore::new("test", true, [1.0, 0.0, 0.0]);
        for ms in 1..=40u64 {
            s.reference(&attitude_only(ms * 1000, &truth));
            if ms % 10 == 0 {
                let imu =
                    ImuSample { time_us: ms * 1000, gyro_rad_s: [0.0; 3], accel_m_s2: [0.0, 0.0, 9.81] };
                let known = ms >= 20;
                s.step(ms * 1000, &[imu, imu], None, if known { &truth } else { &level }, true, known);
            }
        }
        let j = s.json();
        assert!(j["attitude_max_error_deg"]["yaw"].as_f64().unwrap() < 1e-3, "{j}");
        // From the first step with an attitude (10 ms) on; those before the fix in roll and pitch only.
        assert_eq!(j["samples"], 31);
    }
}
