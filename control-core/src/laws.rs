//! The control laws of paper section 4.
//!
//! - Altitude, eq. 30: `T = m (g + z''_d - a_z1 e_z' - a_z2 e_z - i_z) / max(cos(theta) cos(phi), c_min)`;
//!   the division is clamped (the paper divides by `cos(theta) cos(phi)` unguarded).
//! - Yaw, eq. 31: `tau_psi = J_zz sigma(-a_psi1 psi' - a_psi2 (psi - psi_d))`.
//! - Lateral and longitudinal, eq. 33-34: sums of saturations on the position error, its rate, the tilt and
//!   the tilt rate ([`crate::params::SaturatedAxisGains`]). The errors are taken along the vehicle's heading
//!   (forward: pitch; left: roll). Eq. 34's `J_xx tau` and `k_g e_x = x - x_d` typos are read as `tau / J`
//!   and `e = x - x_d` (m).
//! - Eq. 23: the gyroscopic and Coriolis torques are cancelled (optional).
use crate::GRAVITY;
use crate::estimator::StateEstimate;
use crate::params::{ControlGains, SaturatedAxisGains, VehicleParams};
use geometry::frames::WORLD_FROM_NAV;
use geometry::{Vec3, clamp_finite, wrap_pi};

/// Saturation function `sigma_b(x) = clamp(x, -b, b)` (a NaN input gives 0).
pub fn sat(x: f32, b: f32) -> f32 {
    if x.is_nan() { 0.0 } else { clamp_finite(x, -b, b) }
}

/// Where the vehicle should be.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Setpoint {
    /// Position, world frame (m).
    pub position_m: Vec3,
    /// Velocity, world frame (m/s).
    pub velocity_m_s: Vec3,
    /// Acceleration, world frame (m/s^2).
    pub accel_m_s2: Vec3,
    /// Yaw from facing the wall (rad).
    pub yaw_rad: f32,
}

/// Moves a reference at bounded rates: each step the position goes at most `h` (horizontal, m/s) and `v`
/// (vertical) toward the wanted one, and while it is held back its velocity is the limiter's own and its
/// acceleration zero. [`SetpointLimiter::restart`] puts it where the vehicle is (after a failsafe, at take-off).
#[derive(Clone, Copy, Debug, Default)]
pub struct SetpointLimiter {
    position: Option<Vec3>,
}

impl SetpointLimiter {
    /// A limiter that starts at the first reference it sees.
    pub fn new() -> Self {
        Self { position: None }
    }

    /// Starts again from `p`.
    pub fn restart(&mut self, p: Vec3) {
        self.position = Some(p);
    }

    /// The reference `sp` limited; `dt` the step (s).
    pub fn limit(&mut self, sp: &Setpoint, h: f32, v: f32, dt: f32) -> Setpoint {
        let prev = *self.position.get_or_insert(sp.position_m);
        let d = sp.position_m - prev;
        let mut out = *sp;
        let (hmax, vmax) = (h * dt, v * dt);
        let dh = libm::sqrtf(d.x * d.x + d.y * d.y);
        if dh > hmax && dt > 0.0 {
            let k = hmax / dh;
            out.position_m.x = prev.x + d.x * k;
            out.position_m.y = prev.y + d.y * k;
            out.velocity_m_s.x = d.x * k / dt;
            out.velocity_m_s.y = d.y * k / dt;
            out.accel_m_s2.x = 0.0;
            out.accel_m_s2.y = 0.0;
        }
        if libm::fabsf(d.z) > vmax && dt > 0.0 {
            out.position_m.z = prev.z + vmax * d.z.signum();
            out.velocity_m_s.z = vmax * d.z.signum() / dt;
            out.accel_m_s2.z = 0.0;
        }
        self.position = Some(out.position_m);
        out
    }
}

/// Total thrust and body torques.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Demand {
    /// Thrust along body z (N).
    pub thrust_n: f32,
    /// Torques about body x, y, z (N m).
    pub torque_nm: Vec3,
}

/// What the laws did this step.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LawStatus {
    /// Tilt the position and velocity terms (plus feed-forward and trim) ask for: roll, pitch (rad).
    pub commanded_tilt_rad: [f32; 2],
    /// Position error along the heading: forward, left, up (m).
    pub error_m: Vec3,
    /// Trims: roll, pitch (rad).
    pub trim_rad: [f32; 2],
    /// Whether the position or velocity term of roll / pitch is saturated.
    pub saturated: [bool; 2],
}

/// One axis of eq. 33-34. `sign = +1` for the chain `e'' = g angle` (pitch, forward error), `-1` for
/// `e'' = -g angle` (roll, leftward error). Returns `u = tau / J` and the angle the position terms ask for.
pub fn bounded_axis(
    g: &SaturatedAxisGains,
    sign: f32,
    e: f32,
    e_dot: f32,
    angle: f32,
    rate: f32,
    angle_ref: f32,
) -> (f32, f32, bool) {
    let [k1, k2, k3, k4] = g.k;
    let [b1, b2, b3, b4] = g.b;
    let pos = sat(k4 * e_dot, b4) + sat(k3 * e, b3);
    let saturated = (k4 * e_dot).abs() > b4 || (k3 * e).abs() > b3;
    let u = -sign * pos - sat(k2 * rate, b2) - sat(k1 * (angle - angle_ref), b1);
    // In equilibrium (rate 0, u 0) the angle settles where k1 (angle - ref) = -sign * pos.
    (u, angle_ref - sign * pos / k1, saturated)
}

/// The controller: the laws plus their small internal states (integrals, trims).
#[derive(Clone, Copy, Debug)]
pub struct Controller {
    gains: ControlGains,
    vehicle: VehicleParams,
    drag_per_s: f32,
    altitude_integral: f32,
    trim: [f32; 2],
    /// Integrals of the attitude errors (roll, pitch, yaw), in angular acceleration (rad/s^2).
    attitude_integral: [f32; 3],
}

impl Controller {
    /// A controller with zeroed integrals and no drag feed-forward.
    pub fn new(gains: ControlGains, vehicle: VehicleParams) -> Self {
        Self::with_drag(gains, vehicle, 0.0)
    }

    /// A controller whose feed-forward also overcomes the rotors' drag at the reference velocity:
    /// `drag_per_s` is the drag model's coefficient (`estimator.drag_coeff_per_s`, 1/s).
    pub fn with_drag(gains: ControlGains, vehicle: VehicleParams, drag_per_s: f32) -> Self {
        Self {
            gains,
            vehicle,
            drag_per_s,
            altitude_integral: 0.0,
            trim: [0.0; 2],
            attitude_integral: [0.0; 3],
        }
    }

    /// Clears the integrals (on the ground).
    pub fn reset(&mut self) {
        self.altitude_integral = 0.0;
        self.trim = [0.0; 2];
        self.attitude_integral = [0.0; 3];
    }

    /// One step of the laws. `integrate` enables the integrals (airborne, tracking or hovering);
    /// `rotor_speeds` are the last commanded rotor speeds (for the gyroscopic compensation).
    pub fn update(
        &mut self,
        est: &StateEstimate,
        sp: &Setpoint,
        dt: f32,
        integrate: bool,
        rotor_speeds: [f32; 4],
    ) -> (Demand, LawStatus) {
        let g = &self.gains;
        let v = &self.vehicle;
        let att = est.attitude;
        let (roll, pitch, yaw) = (att.roll, att.pitch, att.yaw);
        let w = est.rates_rad_s;
        // Errors in the navigation frame, then along the heading (forward, left).
        let e_w = est.position_m - sp.position_m;
        let de_w = est.velocity_m_s - sp.velocity_m_s;
        let e_n = WORLD_FROM_NAV.tmul_vec(e_w);
        let de_n = WORLD_FROM_NAV.tmul_vec(de_w);
        // The reference acceleration plus what overcomes the rotors' drag at the reference velocity through
        // the estimated wind (the wind's push is fed forward, not left to the integrals).
        let air = sp.velocity_m_s - Vec3::new(est.wind_m_s.x, est.wind_m_s.y, 0.0);
        let a_n = WORLD_FROM_NAV.tmul_vec(sp.accel_m_s2 + air * self.drag_per_s);
        let (sy, cy) = geometry::trig::sin_cos(yaw);
        let head = |x: Vec3| Vec3::new(cy * x.x + sy * x.y, -sy * x.x + cy * x.y, x.z);
        let (e_h, de_h, a_h) = (head(e_n), head(de_n), head(a_n));

        // Trims: slow integrals of the position error into the angle references (zero gains: the paper).
        // Anti-windup: an axis integrates only while its position and velocity terms are unsaturated.
        let linear = |a: &SaturatedAxisGains, e: f32, de: f32| {
            (a.k[2] * e).abs() < a.b[2] && (a.k[3] * de).abs() < a.b[3]
        };
        if integrate && dt > 0.0 {
            let p = &g.pitch;
            let r = &g.roll;
            if linear(p, e_h.x, de_h.x) {
                self.trim[1] = clamp_finite(
                    self.trim[1] - p.trim_gain * e_h.x * dt,
                    -p.trim_limit_rad,
                    p.trim_limit_rad,
                );
            }
            if linear(r, e_h.y, de_h.y) {
                self.trim[0] = clamp_finite(
                    self.trim[0] + r.trim_gain * e_h.y * dt,
                    -r.trim_limit_rad,
                    r.trim_limit_rad,
                );
            }
        }
        // Feed-forward tilt for the desired acceleration: forward a = g tan(pitch), left a = -g tan(roll).
        let pitch_ff = libm::atanf(a_h.x / GRAVITY);
        let roll_ff = -libm::atanf(a_h.y / GRAVITY);
        let (u_pitch, cmd_pitch, sat_p) =
            bounded_axis(&g.pitch, 1.0, e_h.x, de_h.x, pitch, w.y, pitch_ff + self.trim[1]);
        let (u_roll, cmd_roll, sat_r) =
            bounded_axis(&g.roll, -1.0, e_h.y, de_h.y, roll, w.x, roll_ff + self.trim[0]);

        // Yaw (eq. 31).
        let y = &g.yaw;
        let yaw_err = wrap_pi(yaw - sp.yaw_rad);
        // The attitude integrals (not in the paper): the attitude error against the angle the position terms
        // ask for, and the yaw error, integrated into the angular acceleration, bounded.
        if integrate && dt > 0.0 {
            let mut step = |i: usize, gain: f32, err: f32, limit: f32| {
                self.attitude_integral[i] =
                    clamp_finite(self.attitude_integral[i] - gain * err * dt, -limit, limit);
            };
            step(0, g.roll.attitude_integral_gain, roll - cmd_roll, g.roll.attitude_integral_limit_rad_s2);
            step(
                1,
                g.pitch.attitude_integral_gain,
                pitch - cmd_pitch,
                g.pitch.attitude_integral_limit_rad_s2,
            );
            step(2, y.integral_gain, yaw_err, y.integral_limit_rad_s2);
        }
        let u_roll = u_roll + self.attitude_integral[0];
        let u_pitch = u_pitch + self.attitude_integral[1];
        let u_yaw = sat(-y.a_psi1 * w.z - y.a_psi2 * yaw_err + self.attitude_integral[2], y.max_accel_rad_s2);

        // Altitude (eq. 30) with the bounded integral.
        let a = &g.altitude;
        let (ez, dez) = (e_w.z, de_w.z);
        // Anti-windup: the error integrated at most +-0.3 m (a large offset, such as a heavier vehicle's, is
        // still integrated out, at a bounded rate), and not while the vertical speed is far off.
        if integrate && dt > 0.0 && dez.abs() < 0.5 {
            self.altitude_integral = clamp_finite(
                self.altitude_integral + a.integral_gain * clamp_finite(ez, -0.3, 0.3) * dt,
                -a.integral_limit_m_s2,
                a.integral_limit_m_s2,
            );
        }
        let cos_tilt = (geometry::trig::cos(roll) * geometry::trig::cos(pitch)).max(a.min_cos_tilt);
        let acc_z = GRAVITY + sp.accel_m_s2.z - a.a_z1 * dez - a.a_z2 * ez - self.altitude_integral;
        let t_max = a.max_thrust_to_weight * v.mass_kg * GRAVITY;
        let thrust = clamp_finite(v.mass_kg * acc_z / cos_tilt, 0.0, t_max);

        let j = v.inertia_kg_m2;
        let mut torque = Vec3::new(j[0] * u_roll, j[1] * u_pitch, j[2] * u_yaw);
        if g.compensate_gyroscopic {
            // Eq. 23: cancel w x (J w) and the rotor gyroscopic torque -w x h (h = sum s_i I_M w_i z).
            let jw = Vec3::new(j[0] * w.x, j[1] * w.y, j[2] * w.z);
            let h = Vec3::new(0.0, 0.0, v.rotor_inertia_kg_m2 * crate::mixer::signed_rotor_sum(rotor_speeds));
            torque += w.cross(jw) + w.cross(h);
        }
        let status = LawStatus {
            commanded_tilt_rad: [cmd_roll, cmd_pitch],
            error_m: e_h,
            trim_rad: self.trim,
            saturated: [sat_r, sat_p],
        };
        (Demand { thrust_n: thrust, torque_nm: torque }, status)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::params::FlightParams;

    #[test]
    fn saturation_bounds_hold_for_any_state() {
        // The commanded tilt of the position terms never exceeds (b3 + b4) / k1 plus the reference,
        // and u never exceeds b1 + b2 + b3 + b4, whatever the errors.
        let gains = SaturatedAxisGains::default();
        let bound = gains.tilt_bound_rad();
        let mut x = 12345u32;
        let mut rnd = |s: f32| {
            x = x.wrapping_mul(1_103_515_245).wrapping_add(12345);
            ((x >> 8) as f32 / (1u32 << 24) as f32 * 2.0 - 1.0) * s
        };
        for _ in 0..100_000 {
            let (e, de, ang, rate) = (rnd(100.0), rnd(20.0), rnd(1.5), rnd(10.0));
            for sign in [1.0, -1.0] {
                let (u, cmd, _) = bounded_axis(&gains, sign, e, de, ang, rate, 0.0);
                assert!(cmd.abs() <= bound + 1e-6, "{cmd} > {bound}");
                assert!(u.abs() <= gains.b.iter().sum::<f32>() + 1e-4);
            }
        }
    }

    #[test]
    fn signs_push_the_vehicle_back() {
        // Ahead of the setpoint (forward error > 0) and level: pitch torque negative (nose up, to go back).
        let p = FlightParams::paper();
        let mut c = Controller::new(p.gains, p.vehicle);
        let mut est = StateEstimate { q: geometry::Quat::from_mat3(&WORLD_FROM_NAV), ..Default::default() };
        // Facing the wall, forward is -y world: being 0.2 m closer to the wall is a forward error.
        est.position_m = Vec3::new(1.0, 1.1, 0.8);
        let sp = Setpoint { position_m: Vec3::new(1.0, 1.3, 0.8), ..Default::default() };
        let (d, s) = c.update(&est, &sp, 0.002, false, [559.0; 4]);
        assert!(s.error_m.x > 0.19 && d.torque_nm.y < 0.0, "{s:?} {d:?}");
        // Left of the setpoint (x world larger when facing the wall): roll positive (right side down).
        est.position_m = Vec3::new(1.2, 1.3, 0.8);
        let (d, s) = c.update(&est, &sp, 0.002, false, [559.0; 4]);
        assert!(s.error_m.y > 0.19 && d.torque_nm.x > 0.0, "{s:?} {d:?}");
        // Below the setpoint: more than the weight.
        est.position_m = Vec3::new(1.0, 1.3, 0.6);
        let (d, _) = c.update(&est, &sp, 0.002, false, [559.0; 4]);
        assert!(d.thrust_n > p.vehicle.mass_kg * GRAVITY);
    }

    #[test]
    fn altitude_division_is_clamped() {
        let p = FlightParams::paper();
        let mut c = Controller::new(p.gains, p.vehicle);
        let mut est = StateEstimate::default();
        est.attitude.roll = 1.5; // cos ~ 0.07
        let sp = Setpoint::default();
        let (d, _) = c.update(&est, &sp, 0.002, false, [0.0; 4]);
        assert!(d.thrust_n <= p.vehicle.mass_kg * GRAVITY / p.gains.altitude.min_cos_tilt + 1e-3);
    }
}
