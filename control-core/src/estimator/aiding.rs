//! The estimator's measurements: vision fixes, optical-flow velocity, magnetometer heading, and the
//! accelerometer's own aiding (still: zero velocity, gravity, zero rate; carried: gravity; flying: rotor drag).
use super::{BodyVelocity, Estimator, FuseOutcome, IBA, IBG, IP, ITH, IV, IW, N, PositionFix, wrap_pi};
use crate::GRAVITY;
use crate::motion::{MotionClass, MotionReport};
use geometry::frames::Attitude;
use geometry::{Mat3, Quat, Vec3};

/// What the caller knows about the vehicle when the accelerometer's model is chosen.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct AccelContext {
    /// Whether the vehicle flies: `Some(true)` when the flight mode says so (or a recorded vehicle's land
    /// detector), `Some(false)` when it is known to be on the ground, `None` when only the IMU can tell.
    pub airborne: Option<bool>,
    /// The pad's height when the vehicle rests on it (m): the ground constraint holds the height there while
    /// it is still.
    pub pad_height_m: Option<f32>,
}

/// Which accelerometer model was applied for a block.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum AccelAiding {
    /// At rest: zero velocity, gravity, zero rate (and the pad height).
    Still,
    /// Carried: gravity with the hand's accelerations as noise.
    Gravity,
    /// Flying: the rotor-drag model.
    Drag,
    /// None (flying without a drag model, or nothing known yet).
    None,
}

/// Two unit vectors spanning the plane perpendicular to `n` (unit).
pub(super) fn perpendicular_basis(n: Vec3) -> (Vec3, Vec3) {
    let a = if n.x.abs() < 0.8 { Vec3::X } else { Vec3::Y };
    let e1 = n.cross(a).normalized().unwrap_or(Vec3::X);
    (e1, n.cross(e1))
}

impl Estimator {
    fn yaw_row(r: &Mat3) -> [f32; N] {
        let mut h = [0.0; N];
        h[ITH..ITH + 3].copy_from_slice(&r.m[2]);
        h
    }

    /// Rotates the attitude (and the stored history) about the vertical by `dyaw` and resets the yaw
    /// covariance: used for the first yaw measurement, when the filter's linearisation cannot absorb a large
    /// error.
    pub(super) fn reset_yaw(&mut self, dyaw: f32, var: f32) {
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
        // The first vision yaw sets the heading, whatever the compass said before; after that vision and
        // compass are checked against each other, and the compass gives way (see `fuse_mag`).
        if !self.yaw_from_vision {
            self.reset_yaw(yaw_innov, yaw_var);
            self.yaw_from_vision = true;
            self.last_vision_yaw_us = Some(now_us);
            outcome = FuseOutcome::Initialised;
        } else if self.update(&Self::yaw_row(&self.q.to_mat3()), yaw_innov, yaw_var, true) {
            self.vision_yaw_rejections = 0;
            self.last_vision_yaw_us = Some(now_us);
        } else {
            self.counters.vision_yaw_rejected += 1;
            self.vision_yaw_rejections = self.vision_yaw_rejections.saturating_add(1);
            // Consistently refused: the heading has gone wrong (a compass dragged it while vision was out);
            // vision wins.
            if self.vision_yaw_rejections >= self.params.vision_yaw_reset_after {
                self.reset_yaw(yaw_innov, yaw_var);
                self.vision_yaw_rejections = 0;
                self.last_vision_yaw_us = Some(now_us);
                self.counters.yaw_resets += 1;
            }
        }
        // Position. The first fix of each horizontal axis initialises it. Then the fix is tested as a whole:
        // one axis outside its gate makes the fix inconsistent, and fusing the other axes would drag the
        // refused one along through their correlations (after a long dead-reckoning those are strong). A fix
        // refused `vision_position_reset_after` times in a row means the estimate has drifted (vision was
        // out): the position is reset to the fix.
        let floor = self.params.vision_position_floor_m;
        let observed = |axis: usize| axis != 0 || fix.x_observed;
        let std_of = |axis: usize| fix.position_std_m[axis].max(floor);
        let moved = self.p - past.p;
        let mut initialised = false;
        for axis in 0..2 {
            if observed(axis) && !self.xy_initialised[axis] {
                self.reset_position_axis(axis, fix.position_m[axis] + moved[axis], std_of(axis));
                self.xy_initialised[axis] = true;
                initialised = true;
            }
        }
        if initialised {
            self.counters.fixes_accepted += 1;
            return FuseOutcome::Initialised;
        }
        let g2 = self.params.gate_sigma * self.params.gate_sigma;
        let consistent = (0..3).filter(|a| observed(*a)).all(|a| {
            let (ip, iv) = (IP + a, IV + a);
            let s = self.cov[ip][ip] - 2.0 * age * self.cov[ip][iv]
                + age * age * self.cov[iv][iv]
                + std_of(a) * std_of(a);
            let innov = fix.position_m[a] - past.p[a];
            innov.is_finite() && innov * innov <= g2 * s
        });
        if !consistent {
            self.counters.fixes_rejected += 1;
            self.vision_position_rejections = self.vision_position_rejections.saturating_add(1);
            if self.vision_position_rejections >= self.params.vision_position_reset_after {
                for axis in (0..3).filter(|a| observed(*a)) {
                    self.reset_position_axis(axis, fix.position_m[axis] + moved[axis], std_of(axis));
                    // The velocity drifted with the position: its variance is opened (uncorrelated), so that
                    // the next fixes correct it instead of being refused again.
                    let sv = self.params.reset_velocity_sigma_m_s;
                    self.open_variance(IV + axis, sv * sv);
                }
                // Fixes refused again and again mean the model broke, and what breaks it without a word is
                // the IMU: a bias that stepped, a tilt that drifted with it. Those states start again from
                // their initial uncertainty, so that the fixes to come can correct them instead of being
                // refused against a confident and wrong estimate.
                let p = self.params;
                for (first, sigma) in [
                    (ITH, p.initial_tilt_sigma_rad),
                    (IBG, p.initial_gyro_bias_sigma_rad_s),
                    (IBA, p.initial_accel_bias_sigma_m_s2),
                ] {
                    for k in first..first + 3 {
                        self.open_variance(k, sigma * sigma);
                    }
                }
                self.vision_position_rejections = 0;
                self.counters.position_resets += 1;
            }
            return if outcome == FuseOutcome::Accepted { FuseOutcome::Rejected } else { outcome };
        }
        self.vision_position_rejections = 0;
        let mut corr = Vec3::ZERO;
        for axis in (0..3).filter(|a| observed(*a)) {
            let mut h = [0.0; N];
            h[IP + axis] = 1.0;
            h[IV + axis] = -age;
            let before = (self.p, self.v);
            let innov = fix.position_m[axis] - (past.p[axis] + corr[axis]);
            let std = std_of(axis);
            // Gated as a whole above; the sequential updates are not gated again.
            if self.update(&h, innov, std * std, false) {
                corr += (self.p - before.0) - (self.v - before.1) * age;
            }
        }
        self.counters.fixes_accepted += 1;
        outcome
    }

    /// The floor is a hard limit: a height estimate below `floor_z` (the centre of mass's height on the pad)
    /// is projected back onto it (a pseudo-measurement, as for inequality constraints in Simon and Chia,
    /// "Kalman filtering with state equality constraints", IEEE TAES 38(1), 2002). Without vision near the
    /// floor the height is dead-reckoned and may otherwise sink through it. The vertical velocity is left to
    /// the IMU: a dead-reckoned height at the floor does not mean the vehicle has stopped (it may still be in
    /// the air, descending). Returns whether the constraint acted.
    pub fn constrain_above_floor(&mut self, floor_z: f32) -> bool {
        if !(self.p.z < floor_z) {
            return false;
        }
        let s = self.params.ground_height_sigma_m;
        // The height alone: its correlations would otherwise drag the velocity along.
        let mut dx = [0.0; N];
        dx[IP + 2] = floor_z - self.p.z;
        self.inject(&dx);
        for i in 0..N {
            if i != IP + 2 {
                self.cov[IP + 2][i] = 0.0;
                self.cov[i][IP + 2] = 0.0;
            }
        }
        self.cov[IP + 2][IP + 2] = self.cov[IP + 2][IP + 2].max(s * s);
        self.counters.floor_constraints += 1;
        true
    }

    /// Sets one position axis to `value` with standard deviation `std`, uncorrelated with the rest.
    fn reset_position_axis(&mut self, axis: usize, value: f32, std: f32) {
        let mut dx = [0.0; N];
        dx[IP + axis] = value - self.p[axis];
        self.inject(&dx);
        for i in 0..N {
            self.cov[IP + axis][i] = 0.0;
            self.cov[i][IP + axis] = 0.0;
        }
        self.cov[IP + axis][IP + axis] = std * std;
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
            // The vertical velocity enters a body axis only through the tilt (sin of a few degrees); it is
            // considered, not corrected: with the vertical velocity far less certain than the horizontal (after
            // a reset), the flow's errors of scale and tilt would be read as a vertical speed magnified tens of
            // times (a 6 cm/s flow innovation turned into 1.4 m/s of climb, and a dive into the floor).
            if !self.update_considering(
                &h,
                m.velocity_m_s[axis] - pred,
                m.std_m_s * m.std_m_s,
                true,
                IV + 2..IV + 3,
            ) {
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

    /// A barometer's pressure altitude `baro_m` (any offset), `dt_s` after the previous reading.
    ///
    /// While `height_known` (vision fixes fresh, or at rest on the pad), the reading teaches the barometer's
    /// offset (its reading less the height estimate, low-passed over `baro_offset_tau_s`: the day's pressure
    /// and its slow drift); nothing else. Otherwise, once an offset is known, the reading less the offset is a
    /// height measurement of standard deviation `baro_noise_m`, gated: it bounds the height and the vertical
    /// velocity that the accelerometer alone lets drift by decimetres in seconds (every flight stack fuses
    /// one; PX4's EKF2 the same way, with the offset as a state). Returns `Accepted` when fused.
    ///
    /// A reading beyond the gate from a known height is refused and teaches nothing (the fixes may be the
    /// wrong ones); [`super::BARO_RESET_AFTER`] refusals in a row while it is the height's only measurement
    /// reset the height to it (counted as a position reset).
    pub fn fuse_baro(&mut self, baro_m: f32, dt_s: f32, height_known: bool) -> FuseOutcome {
        if !baro_m.is_finite() {
            self.counters.baro_rejected += 1;
            return FuseOutcome::Invalid;
        }
        let seen = baro_m - self.p.z;
        let sigma = self.params.baro_noise_m;
        // How far the reading may sit from the estimate: the gate on the height's and the reading's spread.
        let gate = self.params.gate_sigma * libm::sqrtf(self.cov[IP + 2][IP + 2].max(0.0) + sigma * sigma);
        if height_known {
            match self.baro_offset {
                // A reading that disagrees with the height the fixes give is not learned from: either the fixes
                // or the barometer are wrong, and an offset taught by wrong fixes would hide them afterwards.
                Some(o) if (seen - o).abs() > gate => {
                    self.counters.baro_rejected += 1;
                    return FuseOutcome::Rejected;
                }
                Some(o) => {
                    let a = (dt_s / self.params.baro_offset_tau_s).clamp(0.0, 1.0);
                    self.baro_offset = Some(o + (seen - o) * a);
                }
                None => self.baro_offset = Some(seen),
            }
            self.baro_rejections = 0;
            return FuseOutcome::Initialised;
        }
        let Some(offset) = self.baro_offset else { return FuseOutcome::Stale };
        let mut h = [0.0; N];
        h[IP + 2] = 1.0;
        if self.update(&h, baro_m - offset - self.p.z, sigma * sigma, true) {
            self.counters.baro_accepted += 1;
            self.baro_rejections = 0;
            FuseOutcome::Accepted
        } else {
            self.counters.baro_rejected += 1;
            self.baro_rejections = self.baro_rejections.saturating_add(1);
            // Refused again and again while nothing else gives the height: the estimate has gone (a reset to
            // bad fixes, a vertical velocity gone wrong), the barometer has not. The height is reset to it and
            // the vertical velocity forgotten, so that the next readings correct it.
            if self.baro_rejections >= super::BARO_RESET_AFTER {
                self.reset_position_axis(2, baro_m - offset, sigma);
                let sv = self.params.reset_velocity_sigma_m_s;
                self.open_variance(IV + 2, sv * sv);
                self.baro_rejections = 0;
                self.counters.position_resets += 1;
            }
            FuseOutcome::Rejected
        }
    }

    /// Fuses the magnetometer's heading (tilt-compensated with the current attitude).
    pub fn fuse_mag(&mut self, field_body: Vec3) -> FuseOutcome {
        if !field_body.is_finite() {
            return FuseOutcome::Invalid;
        }
        if !self.tilt_aligned {
            // Levelling the field needs the tilt: before the accelerometer's first block the attitude is
            // the starting guess, and a heading from it would be off by degrees on a tilted pad.
            return FuseOutcome::Stale;
        }
        let r = self.q.to_mat3();
        let m_w = r.mul_vec(field_body);
        let b = self.params.mag_field_world;
        if m_w.x * m_w.x + m_w.y * m_w.y < 1e-12 {
            return FuseOutcome::Invalid;
        }
        let raw = wrap_pi(libm::atan2f(b[1], b[0]) - libm::atan2f(m_w.y, m_w.x));
        let var = self.params.mag_heading_sigma_rad * self.params.mag_heading_sigma_rad;
        if !self.yaw_initialised {
            self.reset_yaw(raw, var);
            return FuseOutcome::Initialised;
        }
        let now = self.last_imu_us.unwrap_or(0);
        let vision_fresh = self
            .last_vision_yaw_us
            .is_some_and(|t| now.saturating_sub(t) as f32 * 1e-6 <= self.params.mag_vision_window_s);
        let innov = if vision_fresh {
            // Vision holds the heading: learn the compass's offset from it (steel, currents), and refuse a
            // compass that disagrees.
            let a = self.params.mag_offset_learn_rate;
            let off = self.mag_offset.map_or(raw, |o| o + a * wrap_pi(raw - o));
            self.mag_offset = Some(off);
            if libm::fabsf(raw) > self.params.mag_consistency_rad {
                self.counters.mag_rejected += 1;
                return FuseOutcome::Rejected;
            }
            raw
        } else {
            // Without vision the compass holds the heading, less its learned offset.
            wrap_pi(raw - self.mag_offset.unwrap_or(0.0))
        };
        if self.update(&Self::yaw_row(&r), innov, var, true) {
            self.counters.mag_accepted += 1;
            FuseOutcome::Accepted
        } else {
            self.counters.mag_rejected += 1;
            FuseOutcome::Rejected
        }
    }

    /// The accelerometer's aiding for the blocks of samples finished since the last call (the motion
    /// detector's reports, see [`crate::motion`]): returns the model applied, if a block ended.
    pub fn fuse_accel(&mut self, ctx: &AccelContext) -> Option<AccelAiding> {
        let report = self.motion_report.take()?;
        let still = report.class == MotionClass::Still;
        // Not known to be on the ground: only a rest that has lasted is one (`MotionParams::still_confirm_s`);
        // until then the class before the still stretch says which model applies.
        let aiding = match ctx.airborne {
            Some(true) => AccelAiding::Drag,
            Some(false) if still => AccelAiding::Still,
            None if still && report.rest_confirmed => AccelAiding::Still,
            Some(false) => AccelAiding::Gravity,
            None => match report.moving_class {
                MotionClass::ThrustBorne => AccelAiding::Drag,
                _ => AccelAiding::Gravity,
            },
        };
        let aiding = match aiding {
            AccelAiding::Drag if self.params.drag_coeff_per_s <= 0.0 => AccelAiding::None,
            a => a,
        };
        match aiding {
            AccelAiding::Still => self.fuse_still(&report, ctx.pad_height_m),
            AccelAiding::Gravity => {
                let sigma = self.params.handheld_gravity_sigma_m_s2;
                if !self.fuse_gravity(report.block.mean_accel, sigma, true) {
                    self.counters.accel_rejected += 1;
                }
            }
            AccelAiding::Drag => self.fuse_drag(&report),
            AccelAiding::None => {}
        }
        Some(aiding)
    }

    /// At rest: zero velocity, the pad's height, gravity from the block's mean specific force (roll and
    /// pitch), and the block's mean angular rate as the gyro bias.
    fn fuse_still(&mut self, report: &MotionReport, pad_height_m: Option<f32>) {
        let p = self.params;
        if !self.still_initialised
            && let Some((gyro, accel)) = report.still_window
        {
            // The first still window: its mean rate measures the gyro bias with the window's variance (a
            // measurement, not a reset: a bias learned in flight before a first rest keeps its weight), its
            // mean force sets the tilt (the first block's alignment may have been moving, and the bias has
            // turned it since).
            self.still_initialised = true;
            let blocks = p.motion.window_blocks as f32;
            let bv = p.still_gyro_sigma_rad_s * p.still_gyro_sigma_rad_s / blocks;
            for k in 0..3 {
                let mut h = [0.0; N];
                h[IBG + k] = 1.0;
                self.update(&h, gyro[k] - self.bg[k], bv, false);
            }
            self.align_tilt(accel - self.ba);
        }
        let vv = p.still_velocity_sigma_m_s * p.still_velocity_sigma_m_s;
        for axis in 0..3 {
            let mut h = [0.0; N];
            h[IV + axis] = 1.0;
            self.update(&h, -self.v[axis], vv, false);
        }
        if let Some(z) = pad_height_m {
            let mut h = [0.0; N];
            h[IP + 2] = 1.0;
            let s = p.ground_height_sigma_m;
            self.update(&h, z - self.p.z, s * s, false);
        }
        self.fuse_gravity(report.block.mean_accel, p.still_gravity_sigma_m_s2, false);
        let gv = p.still_gyro_sigma_rad_s * p.still_gyro_sigma_rad_s;
        for axis in 0..3 {
            let mut h = [0.0; N];
            h[IBG + axis] = 1.0;
            self.update(&h, report.block.mean_gyro[axis] - self.bg[axis], gv, false);
        }
        self.counters.still_blocks += 1;
    }

    /// Gravity from a mean specific force `f` (body): `f = R^T (0, 0, g) + b_a`, along the two directions
    /// perpendicular to the predicted gravity (the ones that tell the tilt). Returns whether it was used.
    ///
    /// It corrects the tilt only, with the bias removed by its estimate: at rest a tilt and an accelerometer
    /// bias are one unobservable combination, and letting this update move the bias made the pair drift
    /// along it (0.2 deg of pitch in a minute at rest on PX4's `sample.ulg`); the bias is learned from the
    /// velocity's dynamics instead (vision fixes, flow, zero velocity at rest, rotations between rests).
    pub(super) fn fuse_gravity(&mut self, f: Vec3, sigma: f32, gate: bool) -> bool {
        if !f.is_finite() || (f.norm() - GRAVITY).abs() > 3.0 * sigma.max(0.3) {
            return false;
        }
        let r = self.q.to_mat3();
        let g_b = r.tmul_vec(Vec3::new(0.0, 0.0, GRAVITY));
        let up = g_b * (1.0 / GRAVITY);
        let (e1, e2) = perpendicular_basis(up);
        let mut ok = true;
        for e in [e1, e2] {
            // d f / d theta = [R^T g]x (body-frame error).
            let r = self.q.to_mat3();
            let g_b = r.tmul_vec(Vec3::new(0.0, 0.0, GRAVITY));
            let row = Mat3::skew(g_b).tmul_vec(e);
            let mut h = [0.0; N];
            h[ITH..ITH + 3].copy_from_slice(&row.to_array());
            let pred = e.dot(g_b + self.ba);
            ok &= self.update(&h, e.dot(f) - pred, sigma * sigma, gate);
        }
        ok
    }

    /// Flying: the rotor-drag model. Perpendicular to the thrust axis `n` the specific force is the rotors'
    /// drag, proportional to the body velocity: `f_perp = -k (R^T v)_perp + b_a,perp` (Leishman, Macdonald,
    /// Beard and McLain, "Quadrotors and accelerometers: state estimation with an improved dynamic model",
    /// IEEE Control Systems Magazine 34(1), 2014; PX4's EKF2 fuses the same model as its multirotor drag
    /// fusion, coefficient `EKF2_MCOEF`). The velocity it observes makes the tilt observable through the
    /// velocity's dynamics; the gravity model would read the tilt of every acceleration as level.
    fn fuse_drag(&mut self, report: &MotionReport) {
        let f = report.block.mean_accel;
        let Some(u) = f.normalized() else { return };
        let learn = self.params.thrust_axis_learn_s > 0.0;
        if learn {
            // The recorded vehicle's thrust axis in the IMU's frame is learned: the specific force's mean
            // direction in flight (its drag part averages out).
            self.thrust_axis_blocks = self.thrust_axis_blocks.saturating_add(1);
            let a = (self.params.motion.block_s / self.params.thrust_axis_learn_s)
                .max(1.0 / self.thrust_axis_blocks as f32)
                .min(1.0);
            self.thrust_axis = (self.thrust_axis + (u - self.thrust_axis) * a).normalized().unwrap_or(u);
        }
        let k = self.params.drag_coeff_per_s;
        let s = self.params.drag_sigma_m_s2;
        let (e1, e2) = perpendicular_basis(self.thrust_axis);
        let mut ok = true;
        for e in [e1, e2] {
            let r = self.q.to_mat3();
            // The drag acts on the velocity through the air: the ground velocity less the wind.
            let vb = r.tmul_vec(self.v - self.w);
            // d(R^T (v - w))/dv = R^T = -d/dw, d(R^T (v - w))/dtheta = [R^T (v - w)]x.
            let row_v = r.mul_vec(e) * (-k);
            let row_th = Mat3::skew(vb).tmul_vec(e) * (-k);
            let mut h = [0.0; N];
            h[IV..IV + 3].copy_from_slice(&row_v.to_array());
            h[ITH..ITH + 3].copy_from_slice(&row_th.to_array());
            h[IW] = -row_v.x;
            h[IW + 1] = -row_v.y;
            let innovation = |bias: Vec3| e.dot(f) - e.dot(vb * (-k) + bias);
            ok &= if learn {
                // A learned axis has absorbed the bias across it, so the residual does not hold the bias; the
                // bias is learned through the velocity's dynamics it shares with the tilt, which turns apart
                // from the bias as the vehicle yaws (considered only, the bias learned as tilt at rest stayed
                // in flight as a tilt offset; docs/architecture.md, "Recordings that start later").
                self.update(&h, innovation(Vec3::ZERO), s * s, true)
            } else {
                // The configured axis: the bias enters the residual; it is considered but not corrected here,
                // since the model's errors (wind, an inexact k) would leak into it.
                h[IBA..IBA + 3].copy_from_slice(&e.to_array());
                self.update_considering(&h, innovation(self.ba), s * s, true, IBA..IBA + 3)
            };
        }
        if ok {
            self.counters.drag_blocks += 1;
        } else {
            self.counters.accel_rejected += 1;
        }
    }

    /// Initial roll and pitch from one specific force (body) at rest, keeping the yaw.
    pub(super) fn align_tilt(&mut self, f: Vec3) {
        if !f.is_finite() || (f.norm() - GRAVITY).abs() > 2.0 {
            return;
        }
        let roll = libm::atan2f(f.y, f.z);
        let pitch = libm::atan2f(-f.x, libm::sqrtf(f.y * f.y + f.z * f.z));
        let yaw = Attitude::from_world_from_body(&self.q.to_mat3()).yaw;
        self.q = Quat::from_mat3(&Attitude::new(roll, pitch, yaw).world_from_body());
        // The tilt is new: uncorrelated with the rest (keeping the old cross terms with the new variance would
        // leave the covariance indefinite).
        let var = self.params.initial_tilt_sigma_rad * self.params.initial_tilt_sigma_rad;
        for k in 0..2 {
            for i in 0..N {
                self.cov[ITH + k][i] = 0.0;
                self.cov[i][ITH + k] = 0.0;
            }
            self.cov[ITH + k][ITH + k] = var;
        }
    }
}
