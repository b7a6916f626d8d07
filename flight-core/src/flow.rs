//! The downward camera's optical flow turned into a body velocity, on board.
//!
//! The ground station sends, per frame pair, the flow's statistics ([`vision_core::flow::FlowStats`]) with the
//! two frames' capture times. On board:
//!
//! 1. the rotation over **exactly** the frame interval comes from the gyro, bias removed, integrated sample by
//!    sample into a history of cumulative attitudes ([`GyroHistory`]) and interpolated at both capture times;
//! 2. the range along the optical axis and the floor's normal come from the estimator's altitude and attitude
//!    at mid-interval (the floor is the plane `z = 0`);
//! 3. [`FlowStats::velocity`](vision_core::flow::FlowStats::velocity) removes the rotational flow and scales
//!    the translational flow by the depth (the full pinhole model);
//! 4. the camera's velocity is taken to the body frame and the lever arm's `omega x r` removed; its variance
//!    adds the range's uncertainty to the tracking noise.
//!
//! The estimator then fuses it as a delayed body-velocity measurement at mid-interval.
use control_core::estimator::{BodyVelocity, Estimator, ImuSample};
use geometry::{Quat, Vec3};
use protocol::FlowMeasurement;
use vision_core::CameraMount;
use vision_core::flow::NoFlowReason;

/// IMU samples kept (at 1 kHz, 0.128 s: a flow's latency plus its frame interval must stay within it).
pub const GYRO_HISTORY_LEN: usize = 128;

/// How the flight code uses the downward camera.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize, postcard_schema::Schema)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FlowConfig {
    /// Where the camera sits on the vehicle.
    pub mount: CameraMount,
    /// Flows of lower quality (inlier fraction) are not used.
    pub min_quality: f32,
    /// Below this camera height above the floor (m) the flow is not used (take-off and landing).
    pub min_height_m: f32,
    /// Tracking noise floor per track (normalised image units: pixels over the focal length).
    pub track_sigma: f32,
    /// Lower bound of the velocity's standard deviation (m/s).
    pub std_floor_m_s: f32,
    /// Relative uncertainty of the flow's scale (sub-pixel tracking bias, texture), added to the variance in
    /// proportion to the speed.
    pub scale_sigma: f32,
}

impl Default for FlowConfig {
    fn default() -> Self {
        Self {
            mount: CameraMount::DOWN_AT_CENTRE,
            min_quality: 0.4,
            min_height_m: 0.25,
            // 0.05 px at the default camera's 138.6 px focal length.
            track_sigma: 0.05 / 138.6,
            std_floor_m_s: 0.01,
            // Measured on rendered floors: speeds read up to 2.3 % short (bilinear sub-pixel bias).
            scale_sigma: 0.03,
        }
    }
}

/// What became of a flow measurement.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize, postcard_schema::Schema)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FlowOutcome {
    /// The ground station found no flow.
    NoFlow(NoFlowReason),
    /// Quality below the threshold.
    LowQuality,
    /// Too close to the floor, or the camera looks too far from straight down.
    Unusable,
    /// The frame interval is not (or no longer) in the gyro history.
    NoGyro,
    /// A velocity, handed to the estimator.
    Velocity {
        /// Earlier frame (us).
        t_prev_us: u64,
        /// Later frame (us).
        t_next_us: u64,
        /// The measurement.
        velocity: BodyVelocity,
    },
}

/// Counters of the flow measurements received.
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize, postcard_schema::Schema,
)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FlowCounters {
    /// Measurements received.
    pub pairs: u32,
    /// Without flow.
    pub no_flow: u32,
    /// Below the quality threshold.
    pub low_quality: u32,
    /// Unusable geometry or no gyro history.
    pub unusable: u32,
    /// Turned into a velocity.
    pub velocities: u32,
}

#[derive(Clone, Copy, Debug)]
struct GyroEntry {
    time_us: u64,
    /// Cumulative attitude (body at the first sample to body now).
    q: Quat,
    /// Bias-corrected rate over the interval ending at `time_us` (rad/s).
    rate: Vec3,
}

/// The gyro integrated sample by sample, for rotations over arbitrary past intervals.
#[derive(Clone, Debug)]
pub struct GyroHistory {
    entries: [GyroEntry; GYRO_HISTORY_LEN],
    head: usize,
    len: usize,
}

impl Default for GyroHistory {
    fn default() -> Self {
        Self::new()
    }
}

impl GyroHistory {
    /// Empty.
    pub const fn new() -> Self {
        Self {
            entries: [GyroEntry { time_us: 0, q: Quat::IDENTITY, rate: Vec3::ZERO }; GYRO_HISTORY_LEN],
            head: 0,
            len: 0,
        }
    }

    fn newest(&self) -> Option<&GyroEntry> {
        (self.len > 0).then(|| &self.entries[(self.head + GYRO_HISTORY_LEN - 1) % GYRO_HISTORY_LEN])
    }

    /// Adds a sample, with the gyro bias to remove. Samples not newer than the last are ignored.
    pub fn push(&mut self, s: &ImuSample, bias: Vec3) {
        let rate = Vec3::from_array(s.gyro_rad_s) - bias;
        if !rate.is_finite() {
            return;
        }
        let entry = match self.newest() {
            None => GyroEntry { time_us: s.time_us, q: Quat::IDENTITY, rate },
            Some(last) if s.time_us > last.time_us => {
                let dt = (s.time_us - last.time_us) as f32 * 1e-6;
                // A gap (lost samples) longer than 20 ms restarts the integration rather than guessing.
                if dt > 0.02 {
                    self.len = 0;
                    GyroEntry { time_us: s.time_us, q: Quat::IDENTITY, rate }
                } else {
                    GyroEntry {
                        time_us: s.time_us,
                        q: last.q.mul(&Quat::from_rotvec(rate * dt)).normalized(),
                        rate,
                    }
                }
            }
            Some(_) => return,
        };
        self.entries[self.head] = entry;
        self.head = (self.head + 1) % GYRO_HISTORY_LEN;
        self.len = (self.len + 1).min(GYRO_HISTORY_LEN);
    }

    /// The cumulative attitude at `t_us`, interpolated within the sample interval that contains it.
    fn at(&self, t_us: u64) -> Option<Quat> {
        let newest = self.newest()?;
        if t_us > newest.time_us {
            return None;
        }
        let mut later = *newest;
        for k in 1..self.len {
            let e = self.entries[(self.head + GYRO_HISTORY_LEN - 1 - k) % GYRO_HISTORY_LEN];
            if e.time_us <= t_us {
                // The rate of `later` holds over (e.time, later.time].
                let dt = (t_us - e.time_us) as f32 * 1e-6;
                return Some(e.q.mul(&Quat::from_rotvec(later.rate * dt)));
            }
            later = e;
        }
        (later.time_us == t_us).then_some(later.q)
    }

    /// The body's rotation from `a_us` to `b_us`, as a rotation vector in the body frame at `a_us` (rad).
    pub fn rotation_between(&self, a_us: u64, b_us: u64) -> Option<Vec3> {
        if b_us < a_us {
            return None;
        }
        let (qa, qb) = (self.at(a_us)?, self.at(b_us)?);
        Some(qa.conj().mul(&qb).to_rotvec())
    }
}

/// Turns one flow measurement into a body velocity with the gyro history and the estimator's past state.
pub fn flow_velocity(
    m: &FlowMeasurement,
    cfg: &FlowConfig,
    gyro: &GyroHistory,
    est: &Estimator,
) -> FlowOutcome {
    let stats = match m.result {
        Ok(s) => s,
        Err(r) => return FlowOutcome::NoFlow(r),
    };
    if !(stats.quality >= cfg.min_quality) {
        return FlowOutcome::LowQuality;
    }
    if m.t_next_us <= m.t_prev_us {
        return FlowOutcome::Unusable;
    }
    let Some(rot_b) = gyro.rotation_between(m.t_prev_us, m.t_next_us) else { return FlowOutcome::NoGyro };
    let mid = m.t_prev_us + (m.t_next_us - m.t_prev_us) / 2;
    let Some(past) = est.past_state(mid) else { return FlowOutcome::NoGyro };
    let dt = (m.t_next_us - m.t_prev_us) as f32 * 1e-6;
    let r_wb = past.q.to_mat3();
    let r_bc = cfg.mount.body_from_camera;
    let r_wc = r_wb.mul_mat(&r_bc);
    let r_cw = r_wc.transpose();
    let height = past.position_m.z + r_wb.mul_vec(cfg.mount.offset_body_m).z;
    let axis_down = -r_wc.col(2).z;
    if !(height >= cfg.min_height_m) || !(axis_down > 0.5) {
        return FlowOutcome::Unusable;
    }
    let range = height / axis_down;
    let normal_cam = r_cw.mul_vec(Vec3::new(0.0, 0.0, -1.0));
    let v_cam_est = r_cw.mul_vec(past.velocity_m_s);
    let rot_cam = r_bc.transpose().mul_vec(rot_b);
    let Some(v) = stats.velocity(rot_cam, dt, range, normal_cam, v_cam_est.z, cfg.track_sigma) else {
        return FlowOutcome::Unusable;
    };
    let v_cam = Vec3::new(v.velocity_cam_m_s.x, v.velocity_cam_m_s.y, v_cam_est.z);
    // The camera moves with the body plus omega x r at its offset.
    let omega = rot_b * (1.0 / dt);
    let v_body = r_bc.mul_vec(v_cam) - omega.cross(cfg.mount.offset_body_m);
    // The depth's uncertainty and the tracking's scale bias scale the whole velocity.
    let sigma_h = est.estimate(mid).position_std_m.z;
    let speed = libm::sqrtf(v_body.x * v_body.x + v_body.y * v_body.y);
    let rel = libm::sqrtf((sigma_h / height) * (sigma_h / height) + cfg.scale_sigma * cfg.scale_sigma);
    let std = libm::sqrtf(v.std_m_s * v.std_m_s + speed * speed * rel * rel).max(cfg.std_floor_m_s);
    if !(v_body.is_finite() && std.is_finite()) {
        return FlowOutcome::Unusable;
    }
    FlowOutcome::Velocity {
        t_prev_us: m.t_prev_us,
        t_next_us: m.t_next_us,
        velocity: BodyVelocity { time_us: mid, velocity_m_s: [v_body.x, v_body.y], std_m_s: std },
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gyro_rotation_over_a_sub_sample_interval() {
        let mut g = GyroHistory::new();
        // 1 kHz, rate 0.5 rad/s about x for 60 ms, then 0.3 rad/s about z.
        for k in 0..=120u64 {
            let w = if k <= 60 { [0.5, 0.0, 0.0] } else { [0.0, 0.0, 0.3] };
            g.push(&ImuSample { time_us: 1000 * k, gyro_rad_s: w, accel_m_s2: [0.0; 3] }, Vec3::ZERO);
        }
        let r = g.rotation_between(20_500, 37_200).unwrap();
        assert!((r - Vec3::new(0.5 * 0.0167, 0.0, 0.0)).norm() < 1e-6, "{r:?}");
        let r = g.rotation_between(80_250, 96_950).unwrap();
        assert!((r - Vec3::new(0.0, 0.0, 0.3 * 0.0167)).norm() < 1e-6, "{r:?}");
        assert!(g.rotation_between(100_000, 121_000).is_none(), "beyond the newest sample");
        // The oldest samples fall out of the history (128 samples).
        for k in 121..200u64 {
            g.push(&ImuSample { time_us: 1000 * k, gyro_rad_s: [0.0; 3], accel_m_s2: [0.0; 3] }, Vec3::ZERO);
        }
        assert!(g.rotation_between(20_500, 37_200).is_none());
        assert!(g.rotation_between(150_000, 170_000).is_some());
        // Bias is removed.
        let mut g = GyroHistory::new();
        for k in 0..100u64 {
            g.push(
                &ImuSample { time_us: 1000 * k, gyro_rad_s: [0.01, 0.0, 0.0], accel_m_s2: [0.0; 3] },
                Vec3::new(0.01, 0.0, 0.0),
            );
        }
        assert!(g.rotation_between(10_000, 90_000).unwrap().norm() < 1e-7);
    }
}
