//! State estimation: an error-state Kalman filter (ESKF) on IMU kinematics.
//!
//! Nominal state: position and velocity (world), attitude (quaternion, world from body), gyro and
//! accelerometer biases, horizontal wind. Error state (17): `[dp, dv, dtheta, dbg, dba, dw]` with the attitude
//! error in the body frame (`q_true = q * exp(dtheta)`, as in Sola, "Quaternion kinematics for the error-state Kalman filter",
//! 2017). The IMU drives the prediction; corrections come from:
//!
//! - **vision fixes** (position and yaw of the forward camera's pose), which are *delayed*: each carries its
//!   capture time; the innovation is formed against the state stored at that time (a 0.256 s history, one
//!   state per 2 ms), and the measurement row maps the current error back with `dp(t_c) = dp - (t - t_c) dv`;
//! - **body velocity** (optical flow, from the downward camera);
//! - **magnetometer heading**;
//! - **the accelerometer itself**, with the model the motion calls for ([`crate::motion`]): at rest, zero
//!   velocity, gravity and zero rate (and the pad's height on the ground); carried by hand, gravity with the
//!   hand's accelerations as noise; flying, the rotor-drag model (the specific force perpendicular to the
//!   thrust axis is proportional to the body velocity).
//!
//! The first sample aligns roll and pitch with its specific force (unless its magnitude is far from gravity's:
//! the level starting guess then stays, with `UNALIGNED_TILT_SIGMA_RAD` as its uncertainty), the first block
//! of samples (50 ms) with its mean, and the first rest's window with its mean (whose mean rate measures the
//! gyro bias, weighed against what was learned before it). Gaps between IMU samples are integrated in
//! sub-steps of at most 20 ms up to `max_imu_gap_s`; a longer gap is not integrated (the rates across it are
//! unknown), only its process noise added, and counted (`imu_gaps`).
//!
//! Updates are sequential scalar updates with innovation gates; nothing allocates and no clock is read.
use crate::GRAVITY;
use crate::motion::{MotionDetector, MotionReport};
use crate::params::EstimatorParams;
use geometry::frames::{Attitude, WORLD_FROM_NAV};
use geometry::{Mat3, Quat, Vec3, wrap_pi};

mod aiding;
mod history;
#[cfg(test)]
mod tests;

pub use aiding::{AccelAiding, AccelContext};
use history::{Corrections, Snapshot};

/// The longest step of the nominal state's integration (s): longer intervals are integrated in sub-steps.
pub const MAX_PREDICT_STEP_S: f32 = 0.02;

/// A sample standing out from both neighbours by more than this on an accelerometer axis is a spike (m/s^2).
pub const SPIKE_ACCEL_M_S2: f32 = 5.0;
/// A sample standing out from both neighbours by more than this on a gyro axis is a spike (rad/s).
pub const SPIKE_GYRO_RAD_S: f32 = 0.5;

/// A repeated gyro reading counts as clipped above this rate (rad/s).
pub const CLIP_MIN_RATE_RAD_S: f32 = 0.2;
/// Barometer readings refused in a row, while nothing else gave the height, after which the height is reset to
/// the barometer's (25 readings: half a second at 50 Hz).
pub const BARO_RESET_AFTER: u16 = 25;

/// Length of the state history kept for delayed measurements (s).
pub const HISTORY_S: f32 = HISTORY_LEN as f32 * SNAPSHOT_EVERY_US as f32 * 1e-6;
const HISTORY_LEN: usize = 128;
/// The history keeps one state per 2 ms at most, whatever the control rate.
const SNAPSHOT_EVERY_US: u64 = 2000;
const N: usize = 17;
const IP: usize = 0;
const IV: usize = 3;
const ITH: usize = 6;
/// Roll and pitch standard deviation of the level starting guess, until the accelerometer gives the tilt
/// (rad): the first sample when its magnitude is gravity's, else the first block's mean 50 ms later. A
/// vehicle started on a sloped pad, in a hand or in flight can be tilted by tens of degrees, so the guess
/// says it knows little (`tilt_std_rad` reports it; replay's scoring starts once it is below half of this).
pub const UNALIGNED_TILT_SIGMA_RAD: f32 = 1.0;
const IBG: usize = 9;
const IBA: usize = 12;
/// The horizontal wind (world x, y): the air's velocity the rotor-drag model sees the vehicle move against.
const IW: usize = 15;

/// One IMU sample (body frame).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ImuSample {
    /// Sample time (us, vehicle clock).
    pub time_us: u64,
    /// Angular rate (rad/s).
    pub gyro_rad_s: [f32; 3],
    /// Specific force (m/s^2).
    pub accel_m_s2: [f32; 3],
}

/// A position (and yaw) fix from the forward camera, solved on board.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PositionFix {
    /// Capture time of the frame (us, vehicle clock).
    pub capture_time_us: u64,
    /// Vehicle position, world frame (m).
    pub position_m: Vec3,
    /// Its standard deviation (m); `x` infinite when unobserved.
    pub position_std_m: Vec3,
    /// Whether `x` is observed.
    pub x_observed: bool,
    /// Vehicle yaw from the image (rad, from facing the wall).
    pub yaw_rad: f32,
    /// Its standard deviation (rad).
    pub yaw_std_rad: f32,
}

/// A body-frame horizontal velocity measurement (optical flow).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct BodyVelocity {
    /// Mid-time of the measurement interval (us, vehicle clock).
    pub time_us: u64,
    /// Velocity along body x and y (m/s).
    pub velocity_m_s: [f32; 2],
    /// Standard deviation per axis (m/s).
    pub std_m_s: f32,
}

/// Outcome of fusing one measurement.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FuseOutcome {
    /// Used.
    Accepted,
    /// Used to initialise the state (first fix).
    Initialised,
    /// Outside the innovation gate.
    Rejected,
    /// Older than the history or the age limit, or from the future.
    Stale,
    /// Non-finite values.
    Invalid,
}

/// The estimate the controllers use.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct StateEstimate {
    /// Time of the estimate (us).
    pub time_us: u64,
    /// Position, world frame (m).
    pub position_m: Vec3,
    /// Velocity, world frame (m/s).
    pub velocity_m_s: Vec3,
    /// Attitude (from facing the wall).
    pub attitude: Attitude,
    /// Attitude quaternion, world from body.
    pub q: Quat,
    /// Body angular rates, bias removed (rad/s).
    pub rates_rad_s: Vec3,
    /// Gyro bias (rad/s).
    pub gyro_bias_rad_s: Vec3,
    /// Accelerometer bias (m/s^2).
    pub accel_bias_m_s2: Vec3,
    /// The wind (the air's velocity), world frame, horizontal (m/s): from the rotor-drag model in flight.
    pub wind_m_s: Vec3,
    /// Its standard deviation, world x and y (m/s).
    pub wind_std_m_s: [f32; 2],
    /// Position standard deviation (m).
    pub position_std_m: Vec3,
    /// Velocity standard deviation (m/s).
    pub velocity_std_m_s: Vec3,
    /// Roll and pitch standard deviation (rad, the larger).
    pub tilt_std_rad: f32,
    /// Yaw standard deviation (rad).
    pub yaw_std_rad: f32,
}

/// The estimated state at a past time.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PastState {
    /// The time asked for (us).
    pub time_us: u64,
    /// Position, world frame (m).
    pub position_m: Vec3,
    /// Velocity, world frame (m/s).
    pub velocity_m_s: Vec3,
    /// Attitude, world from body.
    pub q: Quat,
}

/// Counters of what the estimator used and rejected.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct EstimatorCounters {
    /// Vision fixes used.
    pub fixes_accepted: u32,
    /// Vision fixes (or axes of them) outside the gate.
    pub fixes_rejected: u32,
    /// Vision fixes too old or from the future.
    pub fixes_stale: u32,
    /// Flow measurements used.
    pub flow_accepted: u32,
    /// Flow measurements outside the gate.
    pub flow_rejected: u32,
    /// Magnetometer headings used.
    pub mag_accepted: u32,
    /// Magnetometer headings refused: outside the gate, or disagreeing with the vision yaw.
    pub mag_rejected: u32,
    /// Vision yaws outside the gate.
    pub vision_yaw_rejected: u32,
    /// Headings reset to the vision yaw after consistent refusals.
    pub yaw_resets: u32,
    /// Positions reset to the vision fix after consistent refusals.
    pub position_resets: u32,
    /// Blocks of samples at rest (zero velocity, gravity and zero rate fused).
    pub still_blocks: u32,
    /// Blocks in flight whose rotor-drag measurement was fused.
    pub drag_blocks: u32,
    /// Accelerometer measurements (gravity or drag) outside the gate.
    pub accel_rejected: u32,
    /// Gaps between IMU samples longer than `max_imu_gap_s` (not integrated).
    pub imu_gaps: u32,
    /// IMU samples replaced as single-sample spikes.
    pub imu_spikes: u32,
    /// Gyro samples that repeat the sample before exactly on an axis at a rate above [`CLIP_MIN_RATE_RAD_S`]:
    /// a sensor held at its range's end (noise never repeats to the last bit).
    pub gyro_clipped: u32,
    /// Steps in which the height estimate was held at the floor (it had sunk below).
    pub floor_constraints: u32,
    /// Barometer readings fused as a height.
    pub baro_accepted: u32,
    /// Barometer readings outside the gate (or not finite).
    pub baro_rejected: u32,
}

/// The error-state Kalman filter.
#[derive(Clone)]
pub struct Estimator {
    params: EstimatorParams,
    p: Vec3,
    v: Vec3,
    q: Quat,
    bg: Vec3,
    ba: Vec3,
    w: Vec3,
    cov: [[f32; N]; N],
    last_imu_us: Option<u64>,
    last_omega: Vec3,
    last_accel: Vec3,
    pending_dt: f32,
    history: [Snapshot; HISTORY_LEN],
    corr: Corrections,
    hist_len: usize,
    hist_head: usize,
    yaw_initialised: bool,
    xy_initialised: [bool; 2],
    counters: EstimatorCounters,
    motion: MotionDetector,
    motion_report: Option<MotionReport>,
    thrust_axis: Vec3,
    thrust_axis_blocks: u32,
    tilt_aligned: bool,
    still_initialised: bool,
    yaw_from_vision: bool,
    last_vision_yaw_us: Option<u64>,
    vision_yaw_rejections: u8,
    vision_position_rejections: u8,
    /// The two samples before the newest, for the spike test.
    imu_window: [Option<ImuSample>; 2],
    mag_offset: Option<f32>,
    /// The barometer's offset: its reading less the height (m), once learned.
    baro_offset: Option<f32>,
    /// Barometer readings refused in a row while they were the height's only measurement.
    baro_rejections: u16,
}

fn zero_cov() -> [[f32; N]; N] {
    [[0.0; N]; N]
}

impl Estimator {
    /// A filter at `home` (world, m), level and facing the wall, with wide uncertainty on the horizontal
    /// position and the yaw until the first fixes.
    pub fn new(params: EstimatorParams, home: Vec3) -> Self {
        let mut cov = zero_cov();
        let diag = [
            0.3f32,
            0.3,
            0.05, // position (m)
            0.05,
            0.05,
            0.05, // velocity (m/s)
            UNALIGNED_TILT_SIGMA_RAD,
            UNALIGNED_TILT_SIGMA_RAD,
            3.0, // attitude (rad): tilt, tilt, yaw
            params.initial_gyro_bias_sigma_rad_s,
            params.initial_gyro_bias_sigma_rad_s,
            params.initial_gyro_bias_sigma_rad_s,
            params.initial_accel_bias_sigma_m_s2,
            params.initial_accel_bias_sigma_m_s2,
            params.initial_accel_bias_sigma_m_s2,
            params.initial_wind_sigma_m_s, // wind (m/s)
            params.initial_wind_sigma_m_s,
        ];
        for (i, s) in diag.iter().enumerate() {
            cov[i][i] = s * s;
        }
        let q = Quat::from_mat3(&WORLD_FROM_NAV);
        let snap = Snapshot { time_us: 0, p: home, v: Vec3::ZERO, q, corr: Corrections::default() };
        Self {
            params,
            p: home,
            v: Vec3::ZERO,
            q,
            bg: Vec3::ZERO,
            ba: Vec3::ZERO,
            w: Vec3::ZERO,
            cov,
            last_imu_us: None,
            last_omega: Vec3::ZERO,
            last_accel: Vec3::new(0.0, 0.0, GRAVITY),
            pending_dt: 0.0,
            history: [snap; HISTORY_LEN],
            corr: Corrections::default(),
            hist_len: 0,
            hist_head: 0,
            yaw_initialised: false,
            xy_initialised: [false; 2],
            counters: EstimatorCounters::default(),
            motion: MotionDetector::new(params.motion),
            motion_report: None,
            thrust_axis: Vec3::from_array(params.thrust_axis_body).normalized().unwrap_or(Vec3::Z),
            thrust_axis_blocks: 0,
            tilt_aligned: false,
            still_initialised: false,
            yaw_from_vision: false,
            last_vision_yaw_us: None,
            vision_yaw_rejections: 0,
            vision_position_rejections: 0,
            imu_window: [None; 2],
            mag_offset: None,
            baro_offset: None,
            baro_rejections: 0,
        }
    }

    /// The motion detector's current class.
    pub fn motion_class(&self) -> crate::motion::MotionClass {
        self.motion.class()
    }

    /// The thrust axis in the body frame the drag model uses (configured, or learned in flight).
    pub fn thrust_axis(&self) -> Vec3 {
        self.thrust_axis
    }

    /// Counters of fused and rejected measurements.
    pub fn counters(&self) -> EstimatorCounters {
        self.counters
    }

    /// Whether the heading comes from vision (the line's frame), not only from the compass.
    pub fn yaw_from_vision(&self) -> bool {
        self.yaw_from_vision
    }

    /// Whether the yaw has been set from a measurement.
    pub fn yaw_initialised(&self) -> bool {
        self.yaw_initialised
    }

    /// Whether the nominal state and covariance are all finite.
    pub fn is_healthy(&self) -> bool {
        self.p.is_finite()
            && self.v.is_finite()
            && self.q.is_finite()
            && self.bg.is_finite()
            && self.ba.is_finite()
            && self.w.is_finite()
            && (0..N).all(|i| self.cov[i][i].is_finite() && self.cov[i][i] >= 0.0)
    }

    /// Takes one IMU sample. Returns `false` (and ignores the sample) when it is not finite or not newer
    /// than the previous one.
    ///
    /// The samples propagate the state one sample late (1 ms at 1 kHz), so that each can be compared with
    /// both its neighbours: a single-sample spike (an electrical glitch, a bus error) would otherwise enter
    /// the attitude whole (20 rad/s in one 1 ms sample turns it by 1.1 deg). A sample that stands out from two
    /// agreeing neighbours by more than [`SPIKE_ACCEL_M_S2`] or [`SPIKE_GYRO_RAD_S`] on an axis is replaced by
    /// their mean there, and counted (`imu_spikes`).
    pub fn predict(&mut self, s: &ImuSample) -> bool {
        let g = Vec3::from_array(s.gyro_rad_s);
        let a = Vec3::from_array(s.accel_m_s2);
        if !g.is_finite() || !a.is_finite() || self.imu_window[1].is_some_and(|w| s.time_us <= w.time_us) {
            return false;
        }
        let out = match self.imu_window {
            [Some(a0), Some(a1)] => {
                // The middle sample of three is a spike on an axis when it stands out from both neighbours,
                // on the same side, by more than the threshold while they agree with each other: it is
                // replaced by their mean. A real signal behind the sensor's anti-alias filter (under 100 Hz)
                // never does that at 1 kHz, so everything else passes bit for bit.
                let mut spike = false;
                let mut clean = |x: f32, y: f32, z: f32, lim: f32| {
                    let (dy, dz) = (y - x, y - z);
                    if libm::fabsf(x - z) <= lim
                        && libm::fabsf(dy) > lim
                        && libm::fabsf(dz) > lim
                        && dy * dz > 0.0
                    {
                        spike = true;
                        0.5 * (x + z)
                    } else {
                        y
                    }
                };
                let m = ImuSample {
                    time_us: a1.time_us,
                    gyro_rad_s: core::array::from_fn(|k| {
                        clean(a0.gyro_rad_s[k], a1.gyro_rad_s[k], s.gyro_rad_s[k], SPIKE_GYRO_RAD_S)
                    }),
                    accel_m_s2: core::array::from_fn(|k| {
                        clean(a0.accel_m_s2[k], a1.accel_m_s2[k], s.accel_m_s2[k], SPIKE_ACCEL_M_S2)
                    }),
                };
                if spike {
                    self.counters.imu_spikes += 1;
                }
                Some(m)
            }
            [_, Some(a1)] => Some(a1),
            _ => None,
        };
        if let Some(prev) = self.imu_window[1]
            && (0..3).any(|k| {
                s.gyro_rad_s[k] == prev.gyro_rad_s[k] && libm::fabsf(s.gyro_rad_s[k]) > CLIP_MIN_RATE_RAD_S
            })
        {
            self.counters.gyro_clipped += 1;
        }
        self.imu_window = [self.imu_window[1], Some(*s)];
        match out {
            Some(m) => self.integrate(&m),
            None => true,
        }
    }

    /// Propagates the nominal state with one (filtered) IMU sample. The first block of samples aligns roll
    /// and pitch.
    fn integrate(&mut self, s: &ImuSample) -> bool {
        let g = Vec3::from_array(s.gyro_rad_s);
        let a = Vec3::from_array(s.accel_m_s2);
        let Some(last) = self.last_imu_us else {
            // A first guess from this sample; the first block's mean refines it 50 ms later.
            self.align_tilt(a);
            self.last_imu_us = Some(s.time_us);
            self.last_omega = g - self.bg;
            self.last_accel = a - self.ba;
            self.push_motion(s);
            return true;
        };
        if s.time_us <= last {
            return false;
        }
        let gap = (s.time_us - last) as f32 * 1e-6;
        self.last_imu_us = Some(s.time_us);
        let omega = g - self.bg;
        let acc = a - self.ba;
        if gap > self.params.max_imu_gap_s {
            // The motion across the gap is unknown: hold the state, let the covariance grow over it.
            self.counters.imu_gaps += 1;
            self.pending_dt += gap;
        } else {
            // Trapezoidal rates and forces between the two samples, in sub-steps of at most 20 ms.
            let w_mid = (omega + self.last_omega) * 0.5;
            let a_mid = (acc + self.last_accel) * 0.5;
            let steps = libm::ceilf(gap / MAX_PREDICT_STEP_S).max(1.0);
            let dt = gap / steps;
            for _ in 0..steps as u32 {
                let r0 = self.q.to_mat3();
                self.q = self.q.mul(&Quat::from_rotvec(w_mid * dt)).normalized();
                let r1 = self.q.to_mat3();
                let a_w = (r0.mul_vec(a_mid) + r1.mul_vec(a_mid)) * 0.5 - Vec3::new(0.0, 0.0, GRAVITY);
                self.p += self.v * dt + a_w * (0.5 * dt * dt);
                self.v += a_w * dt;
            }
            self.pending_dt += gap;
        }
        self.last_omega = omega;
        self.last_accel = acc;
        self.push_motion(s);
        true
    }

    /// Feeds the motion detector; the first finished block aligns roll and pitch with its mean specific
    /// force (a block averages the accelerometer's noise: one sample at 1 kHz can be 10 deg off).
    fn push_motion(&mut self, s: &ImuSample) {
        if let Some(r) = self.motion.push(s, &self.q, self.bg) {
            if !self.tilt_aligned {
                self.tilt_aligned = true;
                self.align_tilt(r.block.mean_accel);
            }
            self.motion_report = Some(r);
        }
    }

    /// Propagates the covariance over the time accumulated since the last call (once per control step), and
    /// stores the state in the history for delayed measurements.
    pub fn propagate_covariance(&mut self, now_us: u64) {
        let dt = self.pending_dt;
        self.pending_dt = 0.0;
        if dt > 0.0 {
            let r = self.q.to_mat3();
            let ra = r.mul_mat(&Mat3::skew(self.last_accel));
            let w = self.last_omega;
            // A = F P with F sparse: dp' = dv; dv' = -R[a]x dth - R dba; dth' = -[w]x dth - dbg.
            let mut a = zero_cov();
            for j in 0..N {
                for i in 0..3 {
                    a[IP + i][j] = self.cov[IV + i][j];
                    let mut s = 0.0;
                    for k in 0..3 {
                        s -= ra.m[i][k] * self.cov[ITH + k][j] + r.m[i][k] * self.cov[IBA + k][j];
                    }
                    a[IV + i][j] = s;
                }
                // -[w]x dth: rows (0, -wz, wy), (wz, 0, -wx), (-wy, wx, 0), negated.
                let th = [self.cov[ITH][j], self.cov[ITH + 1][j], self.cov[ITH + 2][j]];
                a[ITH][j] = w.z * th[1] - w.y * th[2] - self.cov[IBG][j];
                a[ITH + 1][j] = w.x * th[2] - w.z * th[0] - self.cov[IBG + 1][j];
                a[ITH + 2][j] = w.y * th[0] - w.x * th[1] - self.cov[IBG + 2][j];
            }
            // F P F^T = F A^T, computed row by row with the same sparse F.
            let mut fpf = zero_cov();
            for j in 0..N {
                let col = |k: usize| a[j][k]; // (A^T)[k][j] = A[j][k]
                for i in 0..3 {
                    fpf[IP + i][j] = col(IV + i);
                    let mut s = 0.0;
                    for k in 0..3 {
                        s -= ra.m[i][k] * col(ITH + k) + r.m[i][k] * col(IBA + k);
                    }
                    fpf[IV + i][j] = s;
                }
                let th = [col(ITH), col(ITH + 1), col(ITH + 2)];
                fpf[ITH][j] = w.z * th[1] - w.y * th[2] - col(IBG);
                fpf[ITH + 1][j] = w.x * th[2] - w.z * th[0] - col(IBG + 1);
                fpf[ITH + 2][j] = w.y * th[0] - w.x * th[1] - col(IBG + 2);
            }
            let pr = &self.params;
            let q = [
                (IV, pr.accel_noise * pr.accel_noise),
                (ITH, pr.gyro_noise * pr.gyro_noise),
                (IBG, pr.gyro_bias_walk * pr.gyro_bias_walk),
                (IBA, pr.accel_bias_walk * pr.accel_bias_walk),
            ];
            for i in 0..N {
                for j in 0..N {
                    self.cov[i][j] += dt * (a[i][j] + a[j][i]) + dt * dt * fpf[i][j];
                }
            }
            for (start, var) in q {
                for k in 0..3 {
                    self.cov[start + k][start + k] += var * dt;
                }
            }
            // The wind walks, its variance capped at the initial one (without drag fusion, on the ground or
            // with the model off, it is not observed at all): a row and column scaled keep P positive.
            let cap = pr.initial_wind_sigma_m_s * pr.initial_wind_sigma_m_s;
            for k in 0..2 {
                let i = IW + k;
                self.cov[i][i] += pr.wind_walk_m_s * pr.wind_walk_m_s * dt;
                if self.cov[i][i] > cap {
                    let f = libm::sqrtf(cap / self.cov[i][i]);
                    for j in 0..N {
                        self.cov[i][j] *= f;
                        self.cov[j][i] *= f;
                    }
                }
            }
            self.symmetrise();
        }
        self.push_history(now_us);
    }

    fn symmetrise(&mut self) {
        for i in 0..N {
            for j in i + 1..N {
                let m = 0.5 * (self.cov[i][j] + self.cov[j][i]);
                self.cov[i][j] = m;
                self.cov[j][i] = m;
            }
            if !(self.cov[i][i] > 1e-12) {
                self.cov[i][i] = 1e-12;
            }
        }
    }

    /// Scalar measurement update with row `h`; returns whether it was accepted.
    ///
    /// The rows are sparse (one to six non-zero entries), so `P h` runs over those only, and the covariance
    /// update `P - P h h^T P / s` is computed on the upper triangle and mirrored: it stays exactly symmetric.
    fn update(&mut self, h: &[f32; N], innovation: f32, var: f32, gate: bool) -> bool {
        self.update_considering(h, innovation, var, gate, 0..0)
    }

    /// [`Self::update`] with the states in `consider` taken into account but not estimated (a Schmidt
    /// "consider" update): their uncertainty enters the innovation's variance and their correlations are
    /// updated, but their estimates and their own covariance are left as they are. For a measurement that
    /// sees a state through a combination it cannot resolve (gravity at rest: the tilt and the
    /// accelerometer bias), the other states then never claim more certainty than that state allows.
    fn update_considering(
        &mut self,
        h: &[f32; N],
        innovation: f32,
        var: f32,
        gate: bool,
        consider: core::ops::Range<usize>,
    ) -> bool {
        let mut nz = [0usize; N];
        let mut n_nz = 0;
        for (k, hv) in h.iter().enumerate() {
            if *hv != 0.0 {
                nz[n_nz] = k;
                n_nz += 1;
            }
        }
        let nz = &nz[..n_nz];
        let mut ph = [0.0f32; N];
        for (i, row) in self.cov.iter().enumerate() {
            let mut s = 0.0;
            for &k in nz {
                s += row[k] * h[k];
            }
            ph[i] = s;
        }
        let mut s = var;
        for &k in nz {
            s += h[k] * ph[k];
        }
        if !(s > 0.0) || !innovation.is_finite() {
            return false;
        }
        let g = self.params.gate_sigma;
        if gate && innovation * innovation > g * g * s {
            return false;
        }
        let inv_s = 1.0 / s;
        let mut gain = [0.0f32; N];
        let mut dx = [0.0f32; N];
        for i in 0..N {
            gain[i] = ph[i] * inv_s;
            if !consider.contains(&i) {
                dx[i] = gain[i] * innovation;
            }
        }
        for i in 0..N {
            for j in i..N {
                // With the considered states' gain zero (Joseph form), only their own block stays unchanged.
                if consider.contains(&i) && consider.contains(&j) {
                    continue;
                }
                let v = self.cov[i][j] - gain[i] * ph[j];
                self.cov[i][j] = v;
                self.cov[j][i] = v;
            }
            if !(self.cov[i][i] > 1e-12) {
                self.cov[i][i] = 1e-12;
            }
        }
        self.inject(&dx);
        true
    }

    /// Forgets what the state `k` knows: uncorrelated with the others, variance `var` (the covariance stays
    /// positive semi-definite: the state is marginalised out and comes back independent).
    fn open_variance(&mut self, k: usize, var: f32) {
        for i in 0..N {
            self.cov[k][i] = 0.0;
            self.cov[i][k] = 0.0;
        }
        self.cov[k][k] = var;
    }

    fn inject(&mut self, dx: &[f32; N]) {
        let v3 = |k: usize| Vec3::new(dx[k], dx[k + 1], dx[k + 2]);
        self.p += v3(IP);
        self.v += v3(IV);
        self.q = self.q.mul(&Quat::from_rotvec(v3(ITH))).normalized();
        self.corr.p += v3(IP);
        self.corr.v += v3(IV);
        self.corr.th += v3(ITH);
        self.bg += v3(IBG);
        let lim = self.params.accel_bias_limit_m_s2;
        let ba = self.ba + v3(IBA);
        // Not `f32::clamp`: no panic path (its assert on the bounds, with the float formatting it brings into
        // the firmware); a NaN stays NaN, for the health check to see.
        let c = |v: f32| if v.is_nan() { v } else { geometry::clamp_finite(v, -lim, lim) };
        self.ba = Vec3::new(c(ba.x), c(ba.y), c(ba.z));
        self.w += Vec3::new(dx[IW], dx[IW + 1], 0.0);
    }

    /// The current estimate.
    pub fn estimate(&self, time_us: u64) -> StateEstimate {
        let r = self.q.to_mat3();
        let sd = |i: usize| libm::sqrtf(self.cov[i][i].max(0.0));
        // Yaw variance: the attitude error projected on the vertical.
        let up = r.m[2];
        let mut yaw_var = 0.0;
        for a in 0..3 {
            for b in 0..3 {
                yaw_var += up[a] * self.cov[ITH + a][ITH + b] * up[b];
            }
        }
        StateEstimate {
            time_us,
            position_m: self.p,
            velocity_m_s: self.v,
            attitude: Attitude::from_world_from_body(&r),
            q: self.q,
            rates_rad_s: self.last_omega,
            gyro_bias_rad_s: self.bg,
            accel_bias_m_s2: self.ba,
            wind_m_s: self.w,
            wind_std_m_s: [sd(IW), sd(IW + 1)],
            position_std_m: Vec3::new(sd(IP), sd(IP + 1), sd(IP + 2)),
            velocity_std_m_s: Vec3::new(sd(IV), sd(IV + 1), sd(IV + 2)),
            tilt_std_rad: self.tilt_std_rad(),
            yaw_std_rad: libm::sqrtf(yaw_var.max(0.0)),
        }
    }

    /// Roll and pitch standard deviation relative to true gravity (rad, the larger): the attitude states'
    /// own, plus what the accelerometer bias across the axis may hide. The gravity updates align the tilt with
    /// the bias-corrected specific force and leave the bias alone (at rest the two are one unobservable
    /// combination, see `aiding`), so the bias's variance is the tilt's floor: a bias `b` across body y reads
    /// as a roll of `b / g`.
    pub fn tilt_std_rad(&self) -> f32 {
        let var = |th: usize, ba: usize| {
            self.cov[th][th].max(0.0) + self.cov[ba][ba].max(0.0) / (GRAVITY * GRAVITY)
        };
        // Roll is about body x (hidden by a bias along y), pitch about body y (a bias along x).
        libm::sqrtf(var(ITH, IBA + 1).max(var(ITH + 1, IBA)))
    }
}
