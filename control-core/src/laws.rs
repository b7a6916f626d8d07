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

/// The altitude integral takes the height error clamped to this (m).
pub const ALTITUDE_INTEGRAL_ERROR_M: f32 = 0.3;
/// The altitude integral holds while the vertical speed error is this or more (m/s).
pub const ALTITUDE_INTEGRAL_HOLD_SPEED_M_S: f32 = 0.5;

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

/// What the horizontal axes follow.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Horizontal {
    /// The position and velocity references (paper eq. 33-34).
    Position,
    /// Roll and pitch references (rad): the pilot's manual mode.
    Attitude {
        /// Roll (rad).
        roll: f32,
        /// Pitch (rad).
        pitch: f32,
    },
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
        self.update_with(est, sp, Horizontal::Position, dt, integrate, rotor_speeds)
    }

    /// [`Controller::update`] with the horizontal axes as `horizontal` says: the position laws (eq. 33-34), or
    /// a given roll and pitch (the pilot's manual mode), the altitude and yaw laws as ever.
    pub fn update_with(
        &mut self,
        est: &StateEstimate,
        sp: &Setpoint,
        horizontal: Horizontal,
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
        let (mut e_h, mut de_h, a_h) = (head(e_n), head(de_n), head(a_n));
        // Attitude only: no position terms, the references are the given angles.
        let given = match horizontal {
            Horizontal::Position => None,
            Horizontal::Attitude { roll, pitch } => {
                (e_h.x, e_h.y, de_h.x, de_h.y) = (0.0, 0.0, 0.0, 0.0);
                Some((roll, pitch))
            }
        };
        let integrate_trims = integrate && given.is_none();

        // Trims: slow integrals of the position error into the angle references (zero gains: the paper).
        // Anti-windup: an axis integrates only while its position and velocity terms are unsaturated.
        let linear = |a: &SaturatedAxisGains, e: f32, de: f32| {
            (a.k[2] * e).abs() < a.b[2] && (a.k[3] * de).abs() < a.b[3]
        };
        if integrate_trims && dt > 0.0 {
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
        let (roll_ref, pitch_ref) = given.unwrap_or((roll_ff + self.trim[0], pitch_ff + self.trim[1]));
        let (u_pitch, cmd_pitch, sat_p) = bounded_axis(&g.pitch, 1.0, e_h.x, de_h.x, pitch, w.y, pitch_ref);
        let (u_roll, cmd_roll, sat_r) = bounded_axis(&g.roll, -1.0, e_h.y, de_h.y, roll, w.x, roll_ref);

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
        // Anti-windup: the error integrated at most +-ALTITUDE_INTEGRAL_ERROR_M (a large offset, such as a
        // heavier vehicle's, is still integrated out, at a bounded rate), and not while the vertical speed is far
        // off.
        if integrate && dt > 0.0 && dez.abs() < ALTITUDE_INTEGRAL_HOLD_SPEED_M_S {
            let e = clamp_finite(ez, -ALTITUDE_INTEGRAL_ERROR_M, ALTITUDE_INTEGRAL_ERROR_M);
            self.altitude_integral = clamp_finite(
                self.altitude_integral + a.integral_gain * e * dt,
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

    #[test]
    fn the_limiter_moves_the_reference_at_its_rates_and_passes_it_within_them() {
        let mut l = SetpointLimiter::new();
        let at = |p: Vec3| Setpoint {
            position_m: p,
            velocity_m_s: Vec3::new(0.1, 0.2, 0.3),
            accel_m_s2: Vec3::new(0.4, 0.5, 0.6),
            yaw_rad: 0.7,
        };
        // It starts at the first reference: passed whole.
        let first = at(Vec3::new(1.0, 2.0, 3.0));
        assert_eq!(l.limit(&first, 1.0, 0.4, 0.5), first);
        // 5 m away horizontally (3, 4), 2 m up: 0.5 m along the horizontal direction, 0.2 m up, at the limiter's
        // own velocity and no acceleration on the limited axes; the yaw passes.
        let far = at(Vec3::new(4.0, 6.0, 5.0));
        let out = l.limit(&far, 1.0, 0.4, 0.5);
        assert!((out.position_m - Vec3::new(1.3, 2.4, 3.2)).norm() < 1e-6, "{:?}", out.position_m);
        assert!((out.velocity_m_s - Vec3::new(0.6, 0.8, 0.4)).norm() < 1e-6, "{:?}", out.velocity_m_s);
        assert_eq!(out.accel_m_s2, Vec3::ZERO);
        assert_eq!(out.yaw_rad, 0.7);
        // Downward, and the next step from where it got to.
        let low = at(Vec3::new(1.3, 2.4, 0.0));
        let out = l.limit(&low, 1.0, 0.4, 0.5);
        assert!((out.position_m - Vec3::new(1.3, 2.4, 3.0)).norm() < 1e-6, "{:?}", out.position_m);
        assert!((out.velocity_m_s.z + 0.4).abs() < 1e-6 && out.accel_m_s2.z == 0.0);
        // Horizontal within the rate: x and y, their velocity and acceleration pass.
        assert_eq!((out.velocity_m_s.x, out.velocity_m_s.y), (0.1, 0.2));
        assert_eq!((out.accel_m_s2.x, out.accel_m_s2.y), (0.4, 0.5));
        // A reference within both rates passes whole.
        let near = at(Vec3::new(1.5, 2.4, 2.9));
        assert_eq!(l.limit(&near, 1.0, 0.4, 0.5), near);
        // A zero step moves nothing and divides by nothing.
        let out = l.limit(&far, 1.0, 0.4, 0.0);
        assert_eq!(out, far);
        // Restarted: measured from the new point.
        l.restart(Vec3::new(0.0, 0.0, 0.0));
        let out = l.limit(&at(Vec3::new(0.0, 10.0, 0.0)), 2.0, 0.4, 0.25);
        assert!((out.position_m - Vec3::new(0.0, 0.5, 0.0)).norm() < 1e-6, "{:?}", out.position_m);
        assert!((out.velocity_m_s.y - 2.0).abs() < 1e-6);
    }

    #[test]
    fn one_axis_is_the_sum_of_four_saturations() {
        let g = SaturatedAxisGains {
            k: [8.0, 4.0, 2.0, 3.0],
            b: [5.0, 6.0, 1.0, 1.5],
            ..SaturatedAxisGains::default()
        };
        // Unsaturated: u = -sign (k4 e' + k3 e) - k2 rate - k1 (angle - ref); the angle asked is
        // ref - sign (k4 e' + k3 e) / k1.
        for sign in [1.0, -1.0] {
            let (e, de, angle, rate, r) = (0.2, 0.1, 0.05, 0.3, 0.01);
            let pos = 3.0 * de + 2.0 * e;
            let (u, ang, sat) = bounded_axis(&g, sign, e, de, angle, rate, r);
            let want = -sign * pos - 4.0 * rate - 8.0 * (angle - r);
            assert!((u - want).abs() < 1e-6, "sign {sign}: u {u} want {want}");
            assert!((ang - (r - sign * pos / 8.0)).abs() < 1e-6, "sign {sign}: angle {ang}");
            assert!(!sat);
        }
        // Each term at its own bound: position 1, velocity 1.5, rate 6, angle 5.
        let (u, ang, sat) = bounded_axis(&g, 1.0, 10.0, 10.0, 2.0, 10.0, 0.0);
        assert!((u - (-(1.5 + 1.0) - 6.0 - 5.0)).abs() < 1e-6, "{u}");
        assert!((ang + 2.5 / 8.0).abs() < 1e-6, "{ang}");
        assert!(sat);
        // The velocity term alone saturated, then the position term alone: each flags it.
        assert!(bounded_axis(&g, 1.0, 0.0, 0.6, 0.0, 0.0, 0.0).2);
        assert!(bounded_axis(&g, 1.0, 0.6, 0.0, 0.0, 0.0, 0.0).2);
        assert!(!bounded_axis(&g, 1.0, 0.4, 0.4, 0.0, 0.0, 0.0).2);
        // Negative errors saturate at the negative bounds.
        let (u, _, _) = bounded_axis(&g, -1.0, -10.0, -10.0, -2.0, -10.0, 0.0);
        assert!((u - (-(2.5) + 6.0 + 5.0)).abs() < 1e-6, "{u}");
    }

    /// The laws written out from the equations (eq. 30, 31, 33-34, 23) for a state, a reference and
    /// integrals at zero: the oracle the controller's one step is checked against.
    fn laws_by_hand(
        p: &FlightParams,
        est: &StateEstimate,
        sp: &Setpoint,
        drag: f32,
        w_rot: [f32; 4],
    ) -> Demand {
        let (g, v) = (&p.gains, &p.vehicle);
        let (r, th, psi) = (est.attitude.roll, est.attitude.pitch, est.attitude.yaw);
        let w = est.rates_rad_s;
        // World (x along the wall, y away from it) to the navigation frame (x toward the wall, y along it).
        let nav = |x: Vec3| WORLD_FROM_NAV.tmul_vec(x);
        let e = nav(est.position_m - sp.position_m);
        let de = nav(est.velocity_m_s - sp.velocity_m_s);
        let air = sp.velocity_m_s - Vec3::new(est.wind_m_s.x, est.wind_m_s.y, 0.0);
        let a = nav(sp.accel_m_s2 + air * drag);
        // Along the heading: forward and left.
        let (c, s) = (psi.cos(), psi.sin());
        let fwd = |x: Vec3| c * x.x + s * x.y;
        let left = |x: Vec3| -s * x.x + c * x.y;
        let pitch_ref = (fwd(a) / GRAVITY).atan();
        let roll_ref = -(left(a) / GRAVITY).atan();
        let (u_pitch, _, _) = bounded_axis(&g.pitch, 1.0, fwd(e), fwd(de), th, w.y, pitch_ref);
        let (u_roll, _, _) = bounded_axis(&g.roll, -1.0, left(e), left(de), r, w.x, roll_ref);
        let yaw_err = wrap_pi(psi - sp.yaw_rad);
        let u_yaw = sat(-g.yaw.a_psi1 * w.z - g.yaw.a_psi2 * yaw_err, g.yaw.max_accel_rad_s2);
        let ez = est.position_m.z - sp.position_m.z;
        let dez = est.velocity_m_s.z - sp.velocity_m_s.z;
        let acc = GRAVITY + sp.accel_m_s2.z - g.altitude.a_z1 * dez - g.altitude.a_z2 * ez;
        let cos_tilt = (r.cos() * th.cos()).max(g.altitude.min_cos_tilt);
        let t_max = g.altitude.max_thrust_to_weight * v.mass_kg * GRAVITY;
        let thrust = (v.mass_kg * acc / cos_tilt).clamp(0.0, t_max);
        let j = v.inertia_kg_m2;
        let jw = Vec3::new(j[0] * w.x, j[1] * w.y, j[2] * w.z);
        let spin = -w_rot[0] + w_rot[1] - w_rot[2] + w_rot[3];
        let h = Vec3::new(0.0, 0.0, v.rotor_inertia_kg_m2 * spin);
        let gyro = if g.compensate_gyroscopic { w.cross(jw) + w.cross(h) } else { Vec3::ZERO };
        Demand { thrust_n: thrust, torque_nm: Vec3::new(j[0] * u_roll, j[1] * u_pitch, j[2] * u_yaw) + gyro }
    }

    #[test]
    fn one_step_of_the_laws_is_the_equations() {
        let p = FlightParams::paper();
        let mut x = 7u32;
        let mut rnd = |s: f32| {
            x = x.wrapping_mul(1_103_515_245).wrapping_add(12345);
            ((x >> 8) as f32 / (1u32 << 24) as f32 * 2.0 - 1.0) * s
        };
        for case in 0..2000 {
            let mut est = StateEstimate {
                position_m: Vec3::new(1.0 + rnd(0.3), 1.3 + rnd(0.3), 0.8 + rnd(0.3)),
                velocity_m_s: Vec3::new(rnd(0.5), rnd(0.5), rnd(0.5)),
                rates_rad_s: Vec3::new(rnd(1.0), rnd(1.0), rnd(1.0)),
                wind_m_s: Vec3::new(rnd(1.0), rnd(1.0), 0.0),
                ..StateEstimate::default()
            };
            est.attitude = geometry::frames::Attitude::new(rnd(0.3), rnd(0.3), rnd(0.5));
            let sp = Setpoint {
                position_m: Vec3::new(1.0 + rnd(0.3), 1.3 + rnd(0.3), 0.8 + rnd(0.3)),
                velocity_m_s: Vec3::new(rnd(0.5), rnd(0.2), rnd(0.3)),
                accel_m_s2: Vec3::new(rnd(1.0), rnd(0.5), rnd(0.5)),
                yaw_rad: rnd(0.3),
            };
            let w_rot = [500.0 + rnd(100.0), 500.0 + rnd(100.0), 500.0 + rnd(100.0), 500.0 + rnd(100.0)];
            let drag = if case % 2 == 0 { 0.3 } else { 0.0 };
            let mut c = Controller::with_drag(p.gains, p.vehicle, drag);
            let (d, status) = c.update(&est, &sp, 0.002, false, w_rot);
            let want = laws_by_hand(&p, &est, &sp, drag, w_rot);
            assert!(
                (d.thrust_n - want.thrust_n).abs() < 1e-4 * want.thrust_n.abs().max(1.0),
                "case {case}: thrust"
            );
            let scale = want.torque_nm.norm().max(1e-4);
            assert!(
                (d.torque_nm - want.torque_nm).norm() < 1e-4 * scale,
                "case {case}: {:?} {:?}",
                d.torque_nm,
                want.torque_nm
            );
            // No integral without `integrate`.
            assert_eq!(status.trim_rad, [0.0; 2]);
            assert_eq!(c.attitude_integral, [0.0; 3]);
            assert_eq!(c.altitude_integral, 0.0);
        }
    }

    /// The integrals (trims, attitude integrals, altitude integral) as the equations state them, one step from
    /// `state`, and the demand with them: the oracle for `integrals_follow_their_equations_step_by_step`.
    fn integrals_by_hand(
        p: &FlightParams,
        state: ([f32; 2], [f32; 3], f32),
        est: &StateEstimate,
        sp: &Setpoint,
        dt: f32,
    ) -> (([f32; 2], [f32; 3], f32), Demand) {
        let (g, v) = (&p.gains, &p.vehicle);
        let (mut trim, mut att, mut alt) = state;
        let (r, th, psi) = (est.attitude.roll, est.attitude.pitch, est.attitude.yaw);
        let w = est.rates_rad_s;
        let nav = |x: Vec3| WORLD_FROM_NAV.tmul_vec(x);
        let e = nav(est.position_m - sp.position_m);
        let de = nav(est.velocity_m_s - sp.velocity_m_s);
        let a = nav(sp.accel_m_s2);
        let (c, s) = (psi.cos(), psi.sin());
        let fwd = |x: Vec3| c * x.x + s * x.y;
        let left = |x: Vec3| -s * x.x + c * x.y;
        // Trims: -k_t e (pitch, forward error) and +k_t e (roll, leftward error), only while the axis's position
        // and velocity terms are both inside their saturations; bounded.
        let (pg, rg) = (&g.pitch, &g.roll);
        if (pg.k[2] * fwd(e)).abs() < pg.b[2] && (pg.k[3] * fwd(de)).abs() < pg.b[3] {
            trim[1] = (trim[1] - pg.trim_gain * fwd(e) * dt).clamp(-pg.trim_limit_rad, pg.trim_limit_rad);
        }
        if (rg.k[2] * left(e)).abs() < rg.b[2] && (rg.k[3] * left(de)).abs() < rg.b[3] {
            trim[0] = (trim[0] + rg.trim_gain * left(e) * dt).clamp(-rg.trim_limit_rad, rg.trim_limit_rad);
        }
        let pitch_ref = (fwd(a) / GRAVITY).atan() + trim[1];
        let roll_ref = -(left(a) / GRAVITY).atan() + trim[0];
        let (u_pitch, cmd_pitch, _) = bounded_axis(pg, 1.0, fwd(e), fwd(de), th, w.y, pitch_ref);
        let (u_roll, cmd_roll, _) = bounded_axis(rg, -1.0, left(e), left(de), r, w.x, roll_ref);
        let yaw_err = wrap_pi(psi - sp.yaw_rad);
        // Attitude integrals: minus the gain times the error (angle less the one asked for), bounded.
        att[0] = (att[0] - rg.attitude_integral_gain * (r - cmd_roll) * dt)
            .clamp(-rg.attitude_integral_limit_rad_s2, rg.attitude_integral_limit_rad_s2);
        att[1] = (att[1] - pg.attitude_integral_gain * (th - cmd_pitch) * dt)
            .clamp(-pg.attitude_integral_limit_rad_s2, pg.attitude_integral_limit_rad_s2);
        att[2] = (att[2] - g.yaw.integral_gain * yaw_err * dt)
            .clamp(-g.yaw.integral_limit_rad_s2, g.yaw.integral_limit_rad_s2);
        // Altitude integral: the height error clamped to 0.3 m, only while the vertical speed is within 0.5 m/s.
        let ez = est.position_m.z - sp.position_m.z;
        let dez = est.velocity_m_s.z - sp.velocity_m_s.z;
        let ga = &g.altitude;
        if dez.abs() < 0.5 {
            alt = (alt + ga.integral_gain * ez.clamp(-0.3, 0.3) * dt)
                .clamp(-ga.integral_limit_m_s2, ga.integral_limit_m_s2);
        }
        let u_yaw = sat(-g.yaw.a_psi1 * w.z - g.yaw.a_psi2 * yaw_err + att[2], g.yaw.max_accel_rad_s2);
        let acc = GRAVITY + sp.accel_m_s2.z - ga.a_z1 * dez - ga.a_z2 * ez - alt;
        let cos_tilt = (r.cos() * th.cos()).max(ga.min_cos_tilt);
        let thrust = (v.mass_kg * acc / cos_tilt).clamp(0.0, ga.max_thrust_to_weight * v.mass_kg * GRAVITY);
        let j = v.inertia_kg_m2;
        let torque = Vec3::new(j[0] * (u_roll + att[0]), j[1] * (u_pitch + att[1]), j[2] * u_yaw);
        ((trim, att, alt), Demand { thrust_n: thrust, torque_nm: torque })
    }

    #[test]
    fn integrals_follow_their_equations_step_by_step() {
        // Gains and bounds chosen so that within a few steps every integral reaches its bound, and errors that
        // cross each anti-windup threshold: 400 runs of 25 random steps, each step checked against the
        // equations (the state of every integral and the demand it gives).
        let mut p = FlightParams::paper();
        p.gains.compensate_gyroscopic = false;
        for axis in [&mut p.gains.roll, &mut p.gains.pitch] {
            axis.trim_gain = 1.6;
            axis.trim_limit_rad = 0.01;
            axis.attitude_integral_limit_rad_s2 = 0.6;
        }
        p.gains.pitch.trim_gain = 1.2;
        p.gains.pitch.attitude_integral_gain = 60.0;
        p.gains.yaw.integral_limit_rad_s2 = 0.08;
        p.gains.altitude.integral_limit_m_s2 = 0.12;
        p.gains.altitude.integral_gain = 2.0;
        let mut x = 99u32;
        let mut rnd = |s: f32| {
            x = x.wrapping_mul(1_103_515_245).wrapping_add(12345);
            ((x >> 8) as f32 / (1u32 << 24) as f32 * 2.0 - 1.0) * s
        };
        let (mut clamped, mut held) = ([0usize; 6], [0usize; 3]);
        for run in 0..400 {
            let mut c = Controller::new(p.gains, p.vehicle);
            let mut state = ([0.0f32; 2], [0.0f32; 3], 0.0f32);
            let dt = 0.02 + rnd(0.01).abs();
            // Each run errs mostly to one side (so that the integrals run into their bounds), with steps that
            // cross the thresholds: position errors up to 0.5 m (the position terms saturate beyond about
            // 0.3 m), vertical speed errors up to 0.8 m/s (the altitude integral holds beyond 0.5).
            let bias = Vec3::new(rnd(0.3), rnd(0.3), rnd(0.3));
            for step in 0..25 {
                let mut est = StateEstimate {
                    position_m: Vec3::new(1.0, 1.3, 0.8) + bias + Vec3::new(rnd(0.2), rnd(0.2), rnd(0.2)),
                    velocity_m_s: Vec3::new(rnd(0.4), rnd(0.4), rnd(0.8)),
                    rates_rad_s: Vec3::new(rnd(0.5), rnd(0.5), rnd(0.5)),
                    ..StateEstimate::default()
                };
                est.attitude = geometry::frames::Attitude::new(rnd(0.2), rnd(0.2), rnd(0.4));
                let sp = Setpoint {
                    position_m: Vec3::new(1.0, 1.3, 0.8),
                    velocity_m_s: Vec3::new(rnd(0.2), rnd(0.2), rnd(0.2)),
                    accel_m_s2: Vec3::new(rnd(0.5), rnd(0.5), rnd(0.5)),
                    yaw_rad: rnd(0.2),
                };
                let (d, status) = c.update(&est, &sp, dt, true, [0.0; 4]);
                let (next, want) = integrals_by_hand(&p, state, &est, &sp, dt);
                let ctx = format!("run {run} step {step}");
                for k in 0..2 {
                    assert!(
                        (c.trim[k] - next.0[k]).abs() < 1e-6,
                        "{ctx}: trim {k} {} {}",
                        c.trim[k],
                        next.0[k]
                    );
                    assert_eq!(status.trim_rad[k], c.trim[k], "{ctx}");
                }
                for k in 0..3 {
                    let tol = 1e-5 * next.1[k].abs().max(1e-2);
                    assert!((c.attitude_integral[k] - next.1[k]).abs() < tol, "{ctx}: attitude integral {k}");
                }
                assert!((c.altitude_integral - next.2).abs() < 1e-6, "{ctx}: altitude integral");
                assert!((d.thrust_n - want.thrust_n).abs() < 1e-4 * want.thrust_n.max(1.0), "{ctx}: thrust");
                let scale = want.torque_nm.norm().max(1e-4);
                assert!((d.torque_nm - want.torque_nm).norm() < 1e-4 * scale, "{ctx}: torque");
                // What the random steps covered: each bound reached, each anti-windup hold taken.
                let bounds = [
                    p.gains.roll.trim_limit_rad,
                    p.gains.pitch.trim_limit_rad,
                    p.gains.roll.attitude_integral_limit_rad_s2,
                    p.gains.pitch.attitude_integral_limit_rad_s2,
                    p.gains.yaw.integral_limit_rad_s2,
                    p.gains.altitude.integral_limit_m_s2,
                ];
                let values = [next.0[0], next.0[1], next.1[0], next.1[1], next.1[2], next.2];
                for k in 0..6 {
                    clamped[k] += usize::from(values[k].abs() >= bounds[k]);
                }
                held[0] += usize::from(next.0[0] == state.0[0]);
                held[1] += usize::from(next.0[1] == state.0[1]);
                held[2] += usize::from(next.2 == state.2);
                state = next;
            }
        }
        assert!(clamped.iter().all(|&n| n > 100), "bounds reached {clamped:?}");
        assert!(held.iter().all(|&n| n > 100), "anti-windup holds {held:?}");
    }

    #[test]
    fn the_thresholds_are_strict() {
        // A limiter step of exactly the rate passes whole (its own velocity only beyond the rate).
        let mut l = SetpointLimiter::new();
        let at = |p: Vec3| Setpoint {
            position_m: p,
            velocity_m_s: Vec3::new(0.1, 0.2, 0.3),
            ..Setpoint::default()
        };
        l.limit(&at(Vec3::new(1.0, 2.0, 3.0)), 1.0, 0.5, 0.5);
        let exact = at(Vec3::new(1.0, 2.5, 3.25));
        assert_eq!(l.limit(&exact, 1.0, 0.5, 0.5), exact);
        // A term exactly at its saturation level is not saturated.
        let g = SaturatedAxisGains {
            k: [8.0, 4.0, 2.0, 3.0],
            b: [5.0, 6.0, 1.0, 1.5],
            ..SaturatedAxisGains::default()
        };
        assert!(!bounded_axis(&g, 1.0, 0.0, 0.5, 0.0, 0.0, 0.0).2);
        assert!(!bounded_axis(&g, 1.0, 0.5, 0.0, 0.0, 0.0, 0.0).2);
        // The trim integrates only strictly inside the position term's saturation: facing the wall at yaw 0,
        // a world y error is the forward error exactly.
        let mut p = FlightParams::paper();
        p.gains.pitch.k[2] = 2.0;
        p.gains.pitch.b[2] = 1.0;
        p.gains.roll.k[2] = 2.0;
        p.gains.roll.b[2] = 1.0;
        let sp = Setpoint { position_m: Vec3::new(1.0, 1.5, 0.8), ..Setpoint::default() };
        for (pos, moves) in [(Vec3::new(1.0, 1.0, 0.8), false), (Vec3::new(1.0, 1.25, 0.8), true)] {
            let est = StateEstimate {
                position_m: pos,
                q: geometry::Quat::from_mat3(&WORLD_FROM_NAV),
                ..Default::default()
            };
            let mut c = Controller::new(p.gains, p.vehicle);
            let (_, s) = c.update(&est, &sp, 0.01, true, [0.0; 4]);
            assert_eq!(s.trim_rad[1] != 0.0, moves, "forward error {}: {:?}", s.error_m.x, s.trim_rad);
        }
        for (pos, moves) in [(Vec3::new(1.5, 1.5, 0.8), false), (Vec3::new(1.25, 1.5, 0.8), true)] {
            let est = StateEstimate {
                position_m: pos,
                q: geometry::Quat::from_mat3(&WORLD_FROM_NAV),
                ..Default::default()
            };
            let mut c = Controller::new(p.gains, p.vehicle);
            let (_, s) = c.update(&est, &sp, 0.01, true, [0.0; 4]);
            assert_eq!(s.trim_rad[0] != 0.0, moves, "left error {}: {:?}", s.error_m.y, s.trim_rad);
        }
        // And strictly inside the velocity term's: a forward speed error at exactly b4 / k4 holds it.
        p.gains.pitch.k[3] = 3.0;
        p.gains.pitch.b[3] = 1.5;
        for (vy, moves) in [(0.5, false), (0.25, true)] {
            let est = StateEstimate {
                position_m: Vec3::new(1.0, 1.25, 0.8),
                velocity_m_s: Vec3::new(0.0, vy, 0.0),
                q: geometry::Quat::from_mat3(&WORLD_FROM_NAV),
                ..Default::default()
            };
            let mut c = Controller::new(p.gains, p.vehicle);
            let (_, s) = c.update(&est, &sp, 0.01, true, [0.0; 4]);
            assert_eq!(s.trim_rad[1] != 0.0, moves, "forward speed error {vy}: {:?}", s.trim_rad);
        }
        // The altitude integral holds from a vertical speed error of exactly 0.5 m/s.
        for (vz, moves) in [(-0.5, false), (-0.25, true)] {
            let est = StateEstimate {
                position_m: Vec3::new(1.0, 1.5, 0.7),
                velocity_m_s: Vec3::new(0.0, 0.0, vz),
                ..Default::default()
            };
            let mut c = Controller::new(p.gains, p.vehicle);
            c.update(&est, &sp, 0.01, true, [0.0; 4]);
            assert_eq!(c.altitude_integral != 0.0, moves, "vz {vz}");
        }
    }

    #[test]
    fn the_thrust_is_bounded_by_the_thrust_to_weight_ratio() {
        let p = FlightParams::paper();
        let mut c = Controller::new(p.gains, p.vehicle);
        // 5 m below the reference: eq. 30 asks for far more than the bound.
        let est = StateEstimate { position_m: Vec3::new(1.0, 1.3, -4.2), ..Default::default() };
        let sp = Setpoint { position_m: Vec3::new(1.0, 1.3, 0.8), ..Setpoint::default() };
        let (d, _) = c.update(&est, &sp, 0.002, false, [0.0; 4]);
        let t_max = p.gains.altitude.max_thrust_to_weight * p.vehicle.mass_kg * GRAVITY;
        assert!((d.thrust_n - t_max).abs() < 1e-5, "{} {t_max}", d.thrust_n);
        // 5 m above: no thrust (never negative).
        let est = StateEstimate { position_m: Vec3::new(1.0, 1.3, 5.8), ..Default::default() };
        assert_eq!(c.update(&est, &sp, 0.002, false, [0.0; 4]).0.thrust_n, 0.0);
    }

    #[test]
    fn the_integrals_grow_against_the_error_and_reset_clears_them() {
        let p = FlightParams::paper();
        let mut c = Controller::new(p.gains, p.vehicle);
        // Hovering 0.1 m low, 2 deg of pitch and roll from what the position asks, yaw 0.1 rad off.
        let est = StateEstimate {
            position_m: Vec3::new(1.0, 1.3, 0.7),
            attitude: geometry::frames::Attitude::new(0.035, 0.035, 0.1),
            ..StateEstimate::default()
        };
        let sp = Setpoint { position_m: Vec3::new(1.0, 1.3, 0.8), ..Setpoint::default() };
        let fresh = c.update(&est, &sp, 0.002, false, [0.0; 4]).0;
        let dt = 0.002;
        c.update(&est, &sp, dt, true, [0.0; 4]);
        // One step: the altitude integral gains k_i e dt (e = -0.1 m), the attitude ones -k e dt.
        let a = &p.gains.altitude;
        assert!((c.altitude_integral - a.integral_gain * -0.1 * dt).abs() < 1e-6, "{}", c.altitude_integral);
        assert!((c.attitude_integral[2] + p.gains.yaw.integral_gain * 0.1 * dt).abs() < 1e-6);
        assert!(c.attitude_integral[0] < 0.0 && c.attitude_integral[1] < 0.0, "{:?}", c.attitude_integral);
        // A height error beyond 0.3 m is integrated as 0.3 m; none while the vertical speed is 0.5 m/s off.
        let mut c2 = Controller::new(p.gains, p.vehicle);
        let low = StateEstimate { position_m: Vec3::new(1.0, 1.3, 0.2), ..est };
        c2.update(&low, &sp, dt, true, [0.0; 4]);
        assert!(
            (c2.altitude_integral - a.integral_gain * -0.3 * dt).abs() < 1e-6,
            "{}",
            c2.altitude_integral
        );
        let mut c3 = Controller::new(p.gains, p.vehicle);
        let falling = StateEstimate { velocity_m_s: Vec3::new(0.0, 0.0, -0.6), ..est };
        c3.update(&falling, &sp, dt, true, [0.0; 4]);
        assert_eq!(c3.altitude_integral, 0.0);
        for _ in 0..5000 {
            c.update(&est, &sp, dt, true, [0.0; 4]);
        }
        // Bounded, and they change the demand.
        assert!(c.altitude_integral.abs() <= a.integral_limit_m_s2 + 1e-6);
        let wound = c.update(&est, &sp, dt, false, [0.0; 4]).0;
        assert!(wound.thrust_n > fresh.thrust_n, "{} {}", wound.thrust_n, fresh.thrust_n);
        c.reset();
        assert_eq!(c.update(&est, &sp, dt, false, [0.0; 4]).0, fresh);
    }
}
