//! State estimation: an error-state Kalman filter (ESKF) on IMU kinematics.
//!
//! Nominal state: position and velocity (world), attitude (quaternion, world from body), gyro and
//! accelerometer biases. Error state (15): `[dp, dv, dtheta, dbg, dba]` with the attitude error in the body
//! frame (`q_true = q * exp(dtheta)`, as in Sola, "Quaternion kinematics for the error-state Kalman filter",
//! 2017). The IMU drives the prediction; corrections come from:
//!
//! - **vision fixes** (position and yaw of the forward camera's pose), which are *delayed*: each carries its
//!   capture time; the innovation is formed against the state stored at that time (a 0.256 s history, one
//!   state per 2 ms), and the measurement row maps the current error back with `dp(t_c) = dp - (t - t_c) dv`;
//! - **body velocity** (optical flow, from the downward camera);
//! - **magnetometer heading**;
//! - **on the ground**: zero velocity, the pad's height and the gravity direction (alignment).
//!
//! Updates are sequential scalar updates with innovation gates; nothing allocates and no clock is read.
use crate::GRAVITY;
use crate::params::EstimatorParams;
use geometry::frames::{Attitude, WORLD_FROM_NAV};
use geometry::{Mat3, Quat, Vec3, wrap_pi};

/// Length of the state history kept for delayed measurements (s).
pub const HISTORY_S: f32 = HISTORY_LEN as f32 * SNAPSHOT_EVERY_US as f32 * 1e-6;
const HISTORY_LEN: usize = 128;
/// The history keeps one state per 2 ms at most, whatever the control rate.
const SNAPSHOT_EVERY_US: u64 = 2000;
const N: usize = 15;
const IP: usize = 0;
const IV: usize = 3;
const ITH: usize = 6;
const IBG: usize = 9;
const IBA: usize = 12;

/// One IMU sample (body frame).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
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
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
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
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
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
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
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
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
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

/// A stored state, with the estimator's cumulative corrections when it was stored: corrections made later
/// are applied when the snapshot is read, so a delayed measurement's innovation is formed against the past
/// state *as corrected since*. Without that, the several measurements in flight during one latency would each
/// correct the same error again (with 60 Hz flow 40 ms late, three times: the estimate oscillates).
#[derive(Clone, Copy, Debug)]
struct Snapshot {
    time_us: u64,
    p: Vec3,
    v: Vec3,
    q: Quat,
    corr: Corrections,
}

/// Sums of the corrections injected into position, velocity and attitude (body frame, small angles).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct Corrections {
    p: Vec3,
    v: Vec3,
    th: Vec3,
}

impl Snapshot {
    /// The snapshot with the corrections made since it was stored.
    fn corrected(&self, now: &Corrections) -> Snapshot {
        let dth = now.th - self.corr.th;
        Snapshot {
            time_us: self.time_us,
            p: self.p + (now.p - self.corr.p),
            v: self.v + (now.v - self.corr.v),
            q: self.q.mul(&Quat::from_rotvec(dth)).normalized(),
            corr: *now,
        }
    }
}

/// Counters of what the estimator used and rejected.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
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
            0.3f32, 0.3, 0.05, // position (m)
            0.05, 0.05, 0.05, // velocity (m/s)
            0.1, 0.1, 3.0, // attitude (rad): tilt, tilt, yaw
            0.02, 0.02, 0.02, // gyro bias (rad/s)
            0.1, 0.1, 0.1, // accel bias (m/s^2)
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
        }
    }

    /// Counters of fused and rejected measurements.
    pub fn counters(&self) -> EstimatorCounters {
        self.counters
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
            && (0..N).all(|i| self.cov[i][i].is_finite() && self.cov[i][i] >= 0.0)
    }

    /// Propagates the nominal state with one IMU sample. Returns `false` (and ignores the sample) when it is
    /// not finite or not newer than the previous one.
    pub fn predict(&mut self, s: &ImuSample) -> bool {
        let g = Vec3::from_array(s.gyro_rad_s);
        let a = Vec3::from_array(s.accel_m_s2);
        if !g.is_finite() || !a.is_finite() {
            return false;
        }
        let Some(last) = self.last_imu_us else {
            self.last_imu_us = Some(s.time_us);
            self.last_omega = g - self.bg;
            self.last_accel = a - self.ba;
            return true;
        };
        if s.time_us <= last {
            return false;
        }
        let dt = ((s.time_us - last) as f32 * 1e-6).min(0.02);
        self.last_imu_us = Some(s.time_us);
        let omega = g - self.bg;
        let acc = a - self.ba;
        // Trapezoidal rates and forces between the two samples.
        let w_mid = (omega + self.last_omega) * 0.5;
        let a_mid = (acc + self.last_accel) * 0.5;
        let r0 = self.q.to_mat3();
        self.q = self.q.mul(&Quat::from_rotvec(w_mid * dt)).normalized();
        let r1 = self.q.to_mat3();
        let a_w = (r0.mul_vec(a_mid) + r1.mul_vec(a_mid)) * 0.5 - Vec3::new(0.0, 0.0, GRAVITY);
        self.p += self.v * dt + a_w * (0.5 * dt * dt);
        self.v += a_w * dt;
        self.last_omega = omega;
        self.last_accel = acc;
        self.pending_dt += dt;
        true
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

    fn push_history(&mut self, now_us: u64) {
        if self.hist_len > 0 {
            let newest = self.history[(self.hist_head + HISTORY_LEN - 1) % HISTORY_LEN].time_us;
            // Within 1 % of the spacing counts as due (control steps are not exactly periodic).
            if now_us < newest + SNAPSHOT_EVERY_US - SNAPSHOT_EVERY_US / 100 {
                return;
            }
        }
        let snap = Snapshot { time_us: now_us, p: self.p, v: self.v, q: self.q, corr: self.corr };
        self.history[self.hist_head] = snap;
        self.hist_head = (self.hist_head + 1) % HISTORY_LEN;
        self.hist_len = (self.hist_len + 1).min(HISTORY_LEN);
    }

    /// The stored state nearest before-or-at `t_us`, linearly interpolated with the next one.
    fn state_at(&self, t_us: u64) -> Option<Snapshot> {
        if self.hist_len == 0 {
            return None;
        }
        let newest = (self.hist_head + HISTORY_LEN - 1) % HISTORY_LEN;
        if t_us > self.history[newest].time_us {
            return None;
        }
        let mut later: Option<&Snapshot> = None;
        for k in 0..self.hist_len {
            let idx = (newest + HISTORY_LEN - k) % HISTORY_LEN;
            let s = &self.history[idx];
            if s.time_us <= t_us {
                let s = s.corrected(&self.corr);
                return Some(match later {
                    Some(l) if l.time_us > s.time_us => {
                        let l = l.corrected(&self.corr);
                        let f = (t_us - s.time_us) as f32 / (l.time_us - s.time_us) as f32;
                        // Attitude: the nearer sample (2 ms apart at most: below 0.1 deg at 1 rad/s).
                        let q = if f < 0.5 { s.q } else { l.q };
                        Snapshot {
                            time_us: t_us,
                            p: s.p + (l.p - s.p) * f,
                            v: s.v + (l.v - s.v) * f,
                            q,
                            corr: s.corr,
                        }
                    }
                    _ => s,
                });
            }
            later = Some(s);
        }
        None
    }

    /// Position, velocity and attitude at a past time (from the history, interpolated), for delayed
    /// measurements such as the optical flow of a frame pair.
    pub fn past_state(&self, t_us: u64) -> Option<PastState> {
        self.state_at(t_us).map(|s| PastState { time_us: t_us, position_m: s.p, velocity_m_s: s.v, q: s.q })
    }

    /// Attitude at a past time (from the history), for solving a delayed frame's pose.
    pub fn attitude_at(&self, t_us: u64) -> Option<Attitude> {
        self.state_at(t_us).map(|s| Attitude::from_world_from_body(&s.q.to_mat3()))
    }

    /// Scalar measurement update with row `h`; returns whether it was accepted.
    ///
    /// The rows are sparse (one to six non-zero entries), so `P h` runs over those only, and the covariance
    /// update `P - P h h^T P / s` is computed on the upper triangle and mirrored: it stays exactly symmetric.
    fn update(&mut self, h: &[f32; N], innovation: f32, var: f32, gate: bool) -> bool {
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
            dx[i] = gain[i] * innovation;
        }
        for i in 0..N {
            for j in i..N {
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

    fn inject(&mut self, dx: &[f32; N]) {
        let v3 = |k: usize| Vec3::new(dx[k], dx[k + 1], dx[k + 2]);
        self.p += v3(IP);
        self.v += v3(IV);
        self.q = self.q.mul(&Quat::from_rotvec(v3(ITH))).normalized();
        self.corr.p += v3(IP);
        self.corr.v += v3(IV);
        self.corr.th += v3(ITH);
        self.bg += v3(IBG);
        self.ba += v3(IBA);
    }

    fn yaw_row(r: &Mat3) -> [f32; N] {
        let mut h = [0.0; N];
        h[ITH..ITH + 3].copy_from_slice(&r.m[2]);
        h
    }

    /// Rotates the attitude (and the stored history) about the vertical by `dyaw` and resets the yaw
    /// covariance: used for the first yaw measurement, when the filter's linearisation cannot absorb a large
    /// error.
    fn reset_yaw(&mut self, dyaw: f32, var: f32) {
        let rz = Quat::from_rotvec(Vec3::new(0.0, 0.0, dyaw));
        self.q = rz.mul(&self.q).normalized();
        for s in self.history.iter_mut() {
            s.q = rz.mul(&s.q).normalized();
        }
        // Decorrelate the attitude errors and set the yaw variance (the vertical in body axes ~ z).
        for i in 0..N {
            for k in 0..3 {
                if i != ITH + k {
                    self.cov[i][ITH + k] = 0.0;
                    self.cov[ITH + k][i] = 0.0;
                }
            }
        }
        let up = self.q.to_mat3().m[2];
        let tilt_var = self.cov[ITH][ITH].max(self.cov[ITH + 1][ITH + 1]);
        for k in 0..3 {
            self.cov[ITH + k][ITH + k] = tilt_var + (var - tilt_var).max(0.0) * up[k] * up[k];
        }
        self.yaw_initialised = true;
    }

    /// Fuses a delayed vision fix (position and yaw) taken at `fix.capture_time_us`, received at `now_us`.
    pub fn fuse_fix(&mut self, fix: &PositionFix, now_us: u64) -> FuseOutcome {
        if !fix.position_m.is_finite() || !fix.yaw_rad.is_finite() {
            return FuseOutcome::Invalid;
        }
        let max_age = (self.params.max_fix_age_s * 1e6) as u64;
        if fix.capture_time_us > now_us || now_us - fix.capture_time_us > max_age {
            self.counters.fixes_stale += 1;
            return FuseOutcome::Stale;
        }
        let Some(past) = self.state_at(fix.capture_time_us) else {
            self.counters.fixes_stale += 1;
            return FuseOutcome::Stale;
        };
        let age = (now_us - fix.capture_time_us) as f32 * 1e-6;
        let mut outcome = FuseOutcome::Accepted;
        // Yaw first: the position's frame does not depend on it, but a first fix resets it.
        let yaw_past = Attitude::from_world_from_body(&past.q.to_mat3()).yaw;
        let yaw_innov = wrap_pi(fix.yaw_rad - yaw_past);
        let yaw_sd = fix.yaw_std_rad.max(self.params.vision_yaw_floor_rad);
        let yaw_var = yaw_sd * yaw_sd;
        if !self.yaw_initialised {
            self.reset_yaw(yaw_innov, yaw_var);
            outcome = FuseOutcome::Initialised;
        } else if !self.update(&Self::yaw_row(&self.q.to_mat3()), yaw_innov, yaw_var, true) {
            self.counters.fixes_rejected += 1;
        }
        // Position: the first fix of each horizontal axis initialises it.
        let floor = self.params.vision_position_floor_m;
        let mut corr = Vec3::ZERO;
        let mut any_rejected = false;
        for axis in 0..3 {
            if axis == 0 && !fix.x_observed {
                continue;
            }
            let meas = fix.position_m[axis];
            let std = fix.position_std_m[axis].max(floor);
            if axis < 2 && !self.xy_initialised[axis] {
                let moved = self.p[axis] - past.p[axis];
                let d = meas + moved - self.p[axis];
                let mut dx = [0.0; N];
                dx[IP + axis] = d;
                self.inject(&dx);
                for i in 0..N {
                    self.cov[IP + axis][i] = 0.0;
                    self.cov[i][IP + axis] = 0.0;
                }
                self.cov[IP + axis][IP + axis] = std * std;
                self.xy_initialised[axis] = true;
                outcome = FuseOutcome::Initialised;
                continue;
            }
            let mut h = [0.0; N];
            h[IP + axis] = 1.0;
            h[IV + axis] = -age;
            let before = (self.p, self.v);
            let innov = meas - (past.p[axis] + corr[axis]);
            if self.update(&h, innov, std * std, true) {
                corr += (self.p - before.0) - (self.v - before.1) * age;
            } else {
                any_rejected = true;
            }
        }
        if any_rejected {
            self.counters.fixes_rejected += 1;
            if outcome == FuseOutcome::Accepted {
                outcome = FuseOutcome::Rejected;
            }
        } else {
            self.counters.fixes_accepted += 1;
        }
        outcome
    }

    /// Fuses a body-frame horizontal velocity (optical flow) measured around `m.time_us`.
    pub fn fuse_body_velocity(&mut self, m: &BodyVelocity, now_us: u64) -> FuseOutcome {
        if !(m.velocity_m_s[0].is_finite() && m.velocity_m_s[1].is_finite() && m.std_m_s > 0.0) {
            return FuseOutcome::Invalid;
        }
        let max_age = (self.params.max_fix_age_s * 1e6) as u64;
        if m.time_us > now_us || now_us - m.time_us > max_age {
            return FuseOutcome::Stale;
        }
        let Some(past) = self.state_at(m.time_us) else { return FuseOutcome::Stale };
        let mut accepted = true;
        for axis in 0..2 {
            // v_body = R^T v: row `axis` of R^T is column `axis` of R.
            let r = self.q.to_mat3();
            let rp = past.q.to_mat3();
            let col = rp.col(axis);
            let pred = col.dot(past.v);
            let mut h = [0.0; N];
            let c = r.col(axis);
            h[IV..IV + 3].copy_from_slice(&c.to_array());
            // d(R^T v)/dtheta = [R^T v]x (body-frame error).
            let vb = r.tmul_vec(self.v);
            let sk = Mat3::skew(vb);
            h[ITH..ITH + 3].copy_from_slice(&sk.m[axis]);
            if !self.update(&h, m.velocity_m_s[axis] - pred, m.std_m_s * m.std_m_s, true) {
                accepted = false;
            }
        }
        if accepted {
            self.counters.flow_accepted += 1;
            FuseOutcome::Accepted
        } else {
            self.counters.flow_rejected += 1;
            FuseOutcome::Rejected
        }
    }

    /// Fuses the magnetometer's heading (tilt-compensated with the current attitude).
    pub fn fuse_mag(&mut self, field_body: Vec3) -> FuseOutcome {
        if !field_body.is_finite() {
            return FuseOutcome::Invalid;
        }
        let r = self.q.to_mat3();
        let m_w = r.mul_vec(field_body);
        let b = self.params.mag_field_world;
        if m_w.x * m_w.x + m_w.y * m_w.y < 1e-12 {
            return FuseOutcome::Invalid;
        }
        let innov = wrap_pi(libm::atan2f(b[1], b[0]) - libm::atan2f(m_w.y, m_w.x));
        let var = self.params.mag_heading_sigma_rad * self.params.mag_heading_sigma_rad;
        if !self.yaw_initialised {
            self.reset_yaw(innov, var);
            return FuseOutcome::Initialised;
        }
        if self.update(&Self::yaw_row(&r), innov, var, true) {
            self.counters.mag_accepted += 1;
            FuseOutcome::Accepted
        } else {
            FuseOutcome::Rejected
        }
    }

    /// On the ground: zero velocity, the pad's height, and the gravity direction from the mean specific force
    /// `accel_mean` (body, m/s^2), which aligns roll and pitch.
    pub fn fuse_ground(&mut self, accel_mean: Vec3, ground_height_m: f32) {
        for axis in 0..3 {
            let mut h = [0.0; N];
            h[IV + axis] = 1.0;
            self.update(&h, -self.v[axis], 0.02 * 0.02, false);
        }
        let mut h = [0.0; N];
        h[IP + 2] = 1.0;
        self.update(&h, ground_height_m - self.p.z, 0.01 * 0.01, false);
        if !accel_mean.is_finite() || (accel_mean.norm() - GRAVITY).abs() > 1.0 {
            return;
        }
        // f = R^T (0, 0, g) + ba; d f / d theta = [R^T g]x, d f / d ba = I.
        for axis in 0..2 {
            let r = self.q.to_mat3();
            let g_b = r.tmul_vec(Vec3::new(0.0, 0.0, GRAVITY));
            let pred = g_b[axis] + self.ba[axis];
            let sk = Mat3::skew(g_b);
            let mut h = [0.0; N];
            h[ITH..ITH + 3].copy_from_slice(&sk.m[axis]);
            h[IBA + axis] = 1.0;
            self.update(&h, accel_mean[axis] - pred, 0.3 * 0.3, false);
        }
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
            position_std_m: Vec3::new(sd(IP), sd(IP + 1), sd(IP + 2)),
            velocity_std_m_s: Vec3::new(sd(IV), sd(IV + 1), sd(IV + 2)),
            tilt_std_rad: sd(ITH).max(sd(ITH + 1)),
            yaw_std_rad: libm::sqrtf(yaw_var.max(0.0)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn level_imu(t_us: u64) -> ImuSample {
        ImuSample { time_us: t_us, gyro_rad_s: [0.0; 3], accel_m_s2: [0.0, 0.0, GRAVITY] }
    }

    #[test]
    fn stationary_imu_keeps_the_state() {
        let mut e = Estimator::new(EstimatorParams::default(), Vec3::new(1.0, 1.3, 0.06));
        for k in 0..1000u64 {
            e.predict(&level_imu(k * 1000));
            if k % 2 == 1 {
                e.propagate_covariance(k * 1000);
            }
        }
        let s = e.estimate(999_000);
        assert!((s.position_m - Vec3::new(1.0, 1.3, 0.06)).norm() < 1e-5);
        assert!(s.velocity_m_s.norm() < 1e-5);
        // Uncertainty grows without measurements.
        assert!(s.velocity_std_m_s.x > 0.05);
    }

    #[test]
    fn delayed_fixes_correct_a_drifting_state() {
        // The vehicle hovers at (1, 1.3, 0.8); the accelerometer has a 0.05 m/s^2 bias along body x (forward,
        // i.e. toward -y world when facing the wall). Fixes arrive 50 ms late at 30 Hz.
        let truth = Vec3::new(1.0, 1.3, 0.8);
        let mut e = Estimator::new(EstimatorParams::default(), Vec3::new(0.8, 1.2, 0.8));
        let mut t = 0u64;
        let mut next_frame = 0u64;
        let mut queue: Vec<(u64, u64)> = Vec::new();
        for _ in 0..20_000 {
            t += 1000;
            let s = ImuSample { time_us: t, gyro_rad_s: [0.0; 3], accel_m_s2: [0.05, 0.0, GRAVITY] };
            e.predict(&s);
            if t.is_multiple_of(2000) {
                e.propagate_covariance(t);
            }
            if t >= next_frame {
                queue.push((t, t + 50_000));
                next_frame += 33_333;
            }
            while let Some(&(cap, due)) = queue.first() {
                if due > t {
                    break;
                }
                queue.remove(0);
                let fix = PositionFix {
                    capture_time_us: cap,
                    position_m: truth,
                    position_std_m: Vec3::new(0.005, 0.005, 0.005),
                    x_observed: true,
                    yaw_rad: 0.0,
                    yaw_std_rad: 0.002,
                };
                e.fuse_fix(&fix, t);
            }
        }
        let s = e.estimate(t);
        assert!((s.position_m - truth).norm() < 0.005, "{:?}", s.position_m);
        assert!(s.velocity_m_s.norm() < 0.01, "{:?}", s.velocity_m_s);
        assert!(e.yaw_initialised());
        let c = e.counters();
        assert!(c.fixes_accepted > 500 && c.fixes_rejected < 5, "{c:?}");
    }

    #[test]
    fn stale_and_invalid_fixes_are_refused() {
        let mut e = Estimator::new(EstimatorParams::default(), Vec3::ZERO);
        for k in 1..=500u64 {
            e.predict(&level_imu(k * 1000));
            e.propagate_covariance(k * 1000);
        }
        let mut fix = PositionFix {
            capture_time_us: 100_000,
            position_m: Vec3::ZERO,
            position_std_m: Vec3::new(0.01, 0.01, 0.01),
            x_observed: true,
            yaw_rad: 0.0,
            yaw_std_rad: 0.01,
        };
        assert_eq!(e.fuse_fix(&fix, 500_000), FuseOutcome::Stale);
        fix.capture_time_us = 600_000;
        assert_eq!(e.fuse_fix(&fix, 500_000), FuseOutcome::Stale);
        fix.capture_time_us = 480_000;
        fix.position_m.x = f32::NAN;
        assert_eq!(e.fuse_fix(&fix, 500_000), FuseOutcome::Invalid);
        let bad = ImuSample { time_us: 501_000, gyro_rad_s: [f32::NAN, 0.0, 0.0], accel_m_s2: [0.0; 3] };
        assert!(!e.predict(&bad));
        assert!(e.is_healthy());
    }

    #[test]
    fn ground_alignment_finds_the_tilt() {
        // Resting with 3 degrees of roll: the accelerometer sees gravity tilted.
        let roll = 3f32.to_radians();
        let f = Vec3::new(0.0, GRAVITY * roll.sin(), GRAVITY * roll.cos());
        let mut e = Estimator::new(EstimatorParams::default(), Vec3::new(0.0, 1.3, 0.06));
        for k in 1..=1000u64 {
            let s = ImuSample { time_us: k * 1000, gyro_rad_s: [0.0; 3], accel_m_s2: f.to_array() };
            e.predict(&s);
            if k % 2 == 0 {
                e.propagate_covariance(k * 1000);
                e.fuse_ground(f, 0.06);
            }
        }
        let s = e.estimate(1_000_000);
        // Roll and accelerometer bias share the offset; their sum must explain it.
        let explained = s.attitude.roll * GRAVITY + s.accel_bias_m_s2.y;
        assert!((explained - GRAVITY * roll.sin()).abs() < 0.02, "{explained}");
        assert!((s.attitude.roll - roll).abs() < 0.6f32.to_radians(), "{}", s.attitude.roll.to_degrees());
    }
}
