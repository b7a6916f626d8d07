//! Parameters of the flight code, with their checks.
//!
//! Every parameter set is validated when it loads ([`FlightParams::validate`]); a bad one is rejected with
//! the name of the offending field and what is wrong with it. The checks of the bounded laws (paper eq. 33-34)
//! are those of their linear part (Routh-Hurwitz) and of the saturation levels (angle terms dominating the
//! position terms, torque authority of the vehicle, tilt bound), see [`SaturatedAxisGains`].
use crate::GRAVITY;

/// A rejected parameter: which field, and what is wrong with it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ParamError {
    /// Dotted path of the field, e.g. `gains.roll.k`.
    pub field: &'static str,
    /// What is wrong.
    pub problem: &'static str,
}

impl core::fmt::Display for ParamError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "invalid `{}`: {}", self.field, self.problem)
    }
}

pub(crate) fn check(ok: bool, field: &'static str, problem: &'static str) -> Result<(), ParamError> {
    if ok { Ok(()) } else { Err(ParamError { field, problem }) }
}

params_struct! {
    /// The airframe, rotors and motors ("+" configuration: M1 front, M2 left, M3 rear, M4 right). The
    /// defaults are the paper's 380 g X4, estimated from published parameter sets (see docs/architecture.md);
    /// the ranges those of multirotors from a 50 g micro to a 20 kg heavy lifter: a value outside is a typing
    /// or unit error (1e-30 kg m^2 of inertia, a thrust coefficient in the wrong unit), not a vehicle.
    #[derive(Clone, Copy, Debug, PartialEq)]
    #[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
    #[cfg_attr(feature = "serde", serde(default, deny_unknown_fields))]
    #[cfg_attr(feature = "defmt", derive(defmt::Format))]
    pub struct VehicleParams in ["vehicle"] {
        /// Total mass (kg).
        mass_kg: f32 = 0.38, { >= 0.05, <= 20 } "kg";
        /// Distance from the centre of mass to each rotor axis (m).
        arm_length_m: f32 = 0.225, { >= 0.03, <= 1.5 } "m";
        /// Principal moments of inertia `Ixx, Iyy, Izz` (kg m^2).
        inertia_kg_m2: [f32; 3] = [3.9e-3, 3.9e-3, 7.1e-3], { >= 1e-5, <= 10 } "kg m^2";
        /// Thrust coefficient `k`: `f = k w^2` (N s^2).
        thrust_coeff: f32 = 2.98e-6, { >= 1e-9, <= 1e-3 } "N s^2";
        /// Drag-torque coefficient `k_tau`: `tau = k_tau w^2` (N m s^2).
        drag_torque_coeff: f32 = 1.14e-7, { >= 1e-11, <= 1e-4 } "N m s^2";
        /// Moment of inertia of one rotor about its axis (kg m^2).
        rotor_inertia_kg_m2: f32 = 3.357e-5, { >= 0, <= 1e-2 } "kg m^2";
        /// Lowest rotor speed while armed (idle) (rad/s); idle thrust below 0.7 times the weight.
        motor_speed_min_rad_s: f32 = 150.0, { >= 0, <= 1e4 } "rad/s";
        /// Highest rotor speed (rad/s); above the idle speed, full thrust above 1.3 times the weight.
        motor_speed_max_rad_s: f32 = 900.0, { >= 10, <= 1e4 } "rad/s";
    }
}

impl VehicleParams {
    /// Rotor speed at which the four rotors hold the vehicle's weight (rad/s).
    pub fn hover_speed_rad_s(&self) -> f32 {
        libm::sqrtf(self.mass_kg * GRAVITY / (4.0 * self.thrust_coeff))
    }

    /// Largest roll or pitch angular acceleration available around hover without changing the thrust
    /// (rad/s^2): one rotor of the pair up, the other down, both within the motor limits.
    pub fn tilt_authority_rad_s2(&self) -> f32 {
        let s_hover = self.mass_kg * GRAVITY / (4.0 * self.thrust_coeff);
        let s_max = self.motor_speed_max_rad_s * self.motor_speed_max_rad_s;
        let s_min = self.motor_speed_min_rad_s * self.motor_speed_min_rad_s;
        let delta = (s_max - s_hover).min(s_hover - s_min).max(0.0);
        let torque = self.arm_length_m * self.thrust_coeff * 2.0 * delta;
        torque / self.inertia_kg_m2[0].max(self.inertia_kg_m2[1])
    }

    fn validate(&self) -> Result<(), ParamError> {
        self.check_declared(0)?;
        check(
            self.motor_speed_max_rad_s > self.motor_speed_min_rad_s,
            "vehicle.motor_speed_max_rad_s",
            "must exceed motor_speed_min_rad_s",
        )?;
        let t_max = 4.0 * self.thrust_coeff * self.motor_speed_max_rad_s * self.motor_speed_max_rad_s;
        check(
            t_max > 1.3 * self.mass_kg * GRAVITY,
            "vehicle.motor_speed_max_rad_s",
            "full thrust must exceed 1.3 times the weight",
        )?;
        let t_min = 4.0 * self.thrust_coeff * self.motor_speed_min_rad_s * self.motor_speed_min_rad_s;
        check(
            t_min < 0.7 * self.mass_kg * GRAVITY,
            "vehicle.motor_speed_min_rad_s",
            "idle thrust must stay below 0.7 times the weight",
        )
    }
}

params_struct! {
    /// Altitude law (paper eq. 30): `T/m = (g + z''_d - a_z1 e_z' - a_z2 e_z - i_z) / max(cos(theta) cos(phi), c_min)`,
    /// with an optional bounded integral `i_z` (not in the paper). Default poles of `s^2 + a_z1 s + a_z2` at
    /// 2.5 rad/s, damping 0.9; with the integral, `s^3 + a_z1 s^2 + a_z2 s + k_i` has its roots at -2.45 and
    /// -1.03 +- 0.41j: a thrust error (mass, thrust coefficient, battery) is integrated out in about a second,
    /// well damped.
    #[derive(Clone, Copy, Debug, PartialEq)]
    #[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
    #[cfg_attr(feature = "serde", serde(default, deny_unknown_fields))]
    #[cfg_attr(feature = "defmt", derive(defmt::Format))]
    pub struct AltitudeGains in ["gains.altitude"] {
        /// `a_z1`, on the vertical speed error (1/s).
        a_z1: f32 = 4.5, { > 0.0, <= 1000.0 } "1/s";
        /// `a_z2`, on the altitude error (1/s^2).
        a_z2: f32 = 6.25, { > 0.0, <= 1000.0 } "1/s^2";
        /// Integral gain on the altitude error (1/s^3); 0 gives the paper's law; below `a_z1 a_z2`.
        integral_gain: f32 = 3.0, { >= 0.0, <= 1000.0 } "1/s^3";
        /// Bound of the integral term (m/s^2).
        integral_limit_m_s2: f32 = 4.0, { >= 0.0, <= 50.0 } "m/s^2";
        /// Lower clamp of `cos(theta) cos(phi)` in the division.
        min_cos_tilt: f32 = 0.5, { > 0.1, <= 1.0 } "";
        /// Thrust bound as a multiple of the weight.
        max_thrust_to_weight: f32 = 2.0, { > 1.2, <= 10.0 } "";
    }
}

params_struct! {
    /// Yaw law (paper eq. 31): `tau/J_zz = -a_psi1 psi' - a_psi2 (psi - psi_d)`, bounded. Defaults:
    /// `s^3 + 6 s^2 + 9 s + 4`, the poles at -4 and a double -1.
    #[derive(Clone, Copy, Debug, PartialEq)]
    #[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
    #[cfg_attr(feature = "serde", serde(default, deny_unknown_fields))]
    #[cfg_attr(feature = "defmt", derive(defmt::Format))]
    pub struct YawGains in ["gains.yaw"] {
        /// `a_psi1`, on the yaw rate (1/s).
        a_psi1: f32 = 6.0, { > 0.0, <= 1000.0 } "1/s";
        /// `a_psi2`, on the yaw error (1/s^2).
        a_psi2: f32 = 9.0, { > 0.0, <= 1000.0 } "1/s^2";
        /// Bound of the commanded yaw angular acceleration (rad/s^2).
        max_accel_rad_s2: f32 = 10.0, { > 0.0, <= 1000.0 } "rad/s^2";
        /// Gain of the integral of the yaw error (1/s^3): a steady yaw torque (a weaker rotor's neighbours spin
        /// faster, and their drag torque is not balanced) is taken without a steady yaw error. 0 gives the
        /// paper's law; below `a_psi1 a_psi2`.
        integral_gain: f32 = 4.0, { >= 0.0, <= 1000.0 } "1/s^3";
        /// Bound of that integral (rad/s^2), at most `max_accel_rad_s2`.
        integral_limit_rad_s2: f32 = 5.0, { >= 0.0, <= 1000.0 } "rad/s^2";
    }
}

params_struct! {
    /// One of the bounded lateral/longitudinal laws (paper eq. 33-34), a **sum** of saturations:
    ///
    /// `u = -s sigma_b4(k4 e') - s sigma_b3(k3 e) - sigma_b2(k2 angle') - sigma_b1(k1 (angle - angle_ff))`
    ///
    /// for the chain `e'' = s g angle` (`s = +1` for pitch and the forward error, `s = -1` for roll and the
    /// leftward error), where `e` is the position error (m), `angle` the tilt (rad) and `u = tau / J`
    /// (rad/s^2). Linear part: `s^4 + k2 s^3 + k1 s^2 + g k4 s + g k3`. The default gains place its poles at
    /// an attitude pair at 10 rad/s (damping 0.8) and a position pair at 2.5 rad/s (damping 0.9).
    #[derive(Clone, Copy, Debug, PartialEq)]
    #[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
    #[cfg_attr(feature = "serde", serde(default, deny_unknown_fields))]
    #[cfg_attr(feature = "defmt", derive(defmt::Format))]
    pub struct SaturatedAxisGains in ["gains.roll", "gains.pitch"] {
        /// `k1..k4`: on the angle (1/s^2), the angular rate (1/s), the position (1/(m s^2)... see the law),
        /// the velocity; the linear part stable (Routh-Hurwitz).
        k: [f32; 4] = default_axis().k, { > 0.0 } "";
        /// Saturation levels `b1..b4` of the four terms (rad/s^2): b1 and b2 each above b3 + b4, b4 above
        /// b3, b1 + b2 within the rotors' authority, (b3 + b4) / k1 within `max_tilt_rad`.
        b: [f32; 4] = default_axis().b, { > 0.0 } "rad/s^2";
        /// Gain of the slow trim that integrates the position error into the angle reference (rad/(m s)); 0
        /// gives the paper's law.
        trim_gain: f32 = TRIM_GAIN, { >= 0.0 } "rad/(m s)";
        /// Bound of that trim (rad), at most a fifth of `max_tilt_rad`.
        trim_limit_rad: f32 = 0.05, { >= 0.0 } "rad";
        /// Gain of the integral of the attitude error (the angle less the one the position terms ask for)
        /// added to the angular acceleration (1/s^3): it takes a steady torque (a weaker rotor, a centre of
        /// mass off the axis) that the angle term would otherwise hold with a steady attitude error, as the
        /// integrators of PX4's and ArduPilot's rate controllers do. 0 gives the paper's law; at most
        /// `k2 k1 / 10`. With the default attitude pair, `s^3 + 16 s^2 + 100 s + 100`: the integral's pole
        /// at 1.2 rad/s, the pair kept near 9 rad/s.
        attitude_integral_gain: f32 = 100.0, { >= 0.0 } "1/s^3";
        /// Bound of that integral (rad/s^2), at most b1. A fifth of one rotor's thrust lost at hover asks
        /// about 11 rad/s^2 of this airframe.
        attitude_integral_limit_rad_s2: f32 = 20.0, { >= 0.0 } "rad/s^2";
    }
}

/// The position pair's default natural frequency (rad/s).
const POSITION_POLE_RAD_S: f32 = 2.5;
/// The trims' default gain (rad/(m s)).
const TRIM_GAIN: f32 = 0.05;

/// The default gains of both tilt axes (see [`SaturatedAxisGains`]).
fn default_axis() -> SaturatedAxisGains {
    SaturatedAxisGains::from_poles(
        10.0,
        0.8,
        POSITION_POLE_RAD_S,
        0.9,
        [40.0, 40.0, 8.0, 12.0],
        TRIM_GAIN,
        0.05,
    )
}

impl SaturatedAxisGains {
    /// Gains placing the linear part's poles at an attitude pair (`w_a` rad/s, damping `z_a`) and a position
    /// pair (`w_p`, `z_p`): `(s^2 + 2 z_a w_a s + w_a^2)(s^2 + 2 z_p w_p s + w_p^2)`.
    pub fn from_poles(
        w_a: f32,
        z_a: f32,
        w_p: f32,
        z_p: f32,
        b: [f32; 4],
        trim_gain: f32,
        trim_limit_rad: f32,
    ) -> Self {
        let (a, bb, c, d) = (2.0 * z_a * w_a, w_a * w_a, 2.0 * z_p * w_p, w_p * w_p);
        Self {
            k: [bb + a * c + d, a + c, bb * d / GRAVITY, (a * d + bb * c) / GRAVITY],
            b,
            trim_gain,
            trim_limit_rad,
            // With the attitude pair above, s^3 + 16 s^2 + 100 s + 100: the integral's pole at 1.2 rad/s, the
            // pair kept near 9 rad/s.
            attitude_integral_gain: 100.0,
            // A fifth of one rotor's thrust lost at hover asks about 11 rad/s^2 of this airframe.
            attitude_integral_limit_rad_s2: 20.0,
        }
    }

    /// Largest tilt the position and velocity terms can demand: `(b3 + b4) / k1` (rad).
    pub fn tilt_bound_rad(&self) -> f32 {
        (self.b[2] + self.b[3]) / self.k[0]
    }

    /// Coefficients `[c3, c2, c1, c0]` of the closed loop's linear part `s^4 + c3 s^3 + c2 s^2 + c1 s + c0`.
    pub fn characteristic(&self) -> [f32; 4] {
        [self.k[1], self.k[0], GRAVITY * self.k[3], GRAVITY * self.k[2]]
    }

    /// The checks of one axis: positive gains, Routh-Hurwitz on the linear part, angle terms dominating the
    /// position terms, saturation levels within the vehicle's authority, tilt bound within `max_tilt_rad`.
    pub fn validate(&self, authority_rad_s2: f32, max_tilt_rad: f32, axis: Axis) -> Result<(), ParamError> {
        let f = |which: &'static [&'static str; 8], i: usize| which[i];
        self.check_declared(match axis {
            Axis::Roll => 0,
            Axis::Pitch => 1,
        })?;
        let names: &'static [&'static str; 8] = match axis {
            Axis::Roll => &[
                "gains.roll.k",
                "gains.roll.b",
                "gains.roll",
                "gains.roll.b",
                "gains.roll.trim_gain",
                "gains.roll.trim_limit_rad",
                "gains.roll.attitude_integral_gain",
                "gains.roll.attitude_integral_limit_rad_s2",
            ],
            Axis::Pitch => &[
                "gains.pitch.k",
                "gains.pitch.b",
                "gains.pitch",
                "gains.pitch.b",
                "gains.pitch.trim_gain",
                "gains.pitch.trim_limit_rad",
                "gains.pitch.attitude_integral_gain",
                "gains.pitch.attitude_integral_limit_rad_s2",
            ],
        };
        let [c3, c2, c1, c0] = self.characteristic();
        // Routh-Hurwitz for a quartic: all coefficients positive, c3 c2 > c1, c3 c2 c1 > c1^2 + c3^2 c0.
        check(
            c3 * c2 > c1,
            f(names, 2),
            "Routh-Hurwitz fails: k2 k1 must exceed g k4 (linear part unstable)",
        )?;
        check(
            c3 * c2 * c1 > c1 * c1 + c3 * c3 * c0,
            f(names, 2),
            "Routh-Hurwitz fails: k2 k1 g k4 must exceed (g k4)^2 + k2^2 g k3 (linear part unstable)",
        )?;
        let pos = self.b[2] + self.b[3];
        check(
            self.b[0] > pos && self.b[1] > pos,
            f(names, 3),
            "the angle terms must dominate: b1 and b2 must each exceed b3 + b4",
        )?;
        // With b4 <= b3 the two terms can saturate against each other far from the reference and cancel: the
        // vehicle then coasts (or, with any integral, accelerates) past it. b4 > b3 caps the approach speed at
        // b3 / k4 instead, as the inner level of a nested saturation would.
        check(
            self.b[3] > self.b[2],
            f(names, 3),
            "the velocity term must saturate above the position term (b4 > b3), or far from the reference they cancel",
        )?;
        check(
            self.b[0] + self.b[1] <= authority_rad_s2,
            f(names, 3),
            "b1 + b2 exceeds the angular acceleration the rotors can give around hover",
        )?;
        check(
            self.tilt_bound_rad() <= max_tilt_rad,
            f(names, 3),
            "(b3 + b4) / k1, the largest tilt the position terms can ask for, exceeds max_tilt_rad",
        )?;
        check(
            self.trim_limit_rad <= 0.2 * max_tilt_rad,
            f(names, 5),
            "must stay below a fifth of max_tilt_rad",
        )?;
        // The attitude integral on the attitude pair s^2 + k2 s + k1: s^3 + k2 s^2 + k1 s + k_i is stable for
        // k_i < k2 k1; kept a tenth of that.
        check(
            self.attitude_integral_gain <= 0.1 * self.k[1] * self.k[0],
            f(names, 6),
            "must lie in [0, k2 k1 / 10] (the attitude pair with the integral stays well damped)",
        )?;
        check(self.attitude_integral_limit_rad_s2 <= self.b[0], f(names, 7), "must lie in [0, b1]")?;
        // The trim must be much slower than the position loop it sits on: k_i << k3 / k1 * (slowest pole).
        check(
            self.trim_gain <= 0.2 * self.k[2] / self.k[0] * libm::sqrtf(c0).min(c1 / c2.max(1e-6)),
            f(names, 4),
            "too fast for the position loop (it would destabilise it)",
        )
    }
}

/// Which tilt axis.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Axis {
    /// Roll (lateral, along the wall).
    Roll,
    /// Pitch (longitudinal, toward the wall).
    Pitch,
}

params_struct! {
    /// All the control gains.
    #[derive(Clone, Copy, Debug, PartialEq)]
    #[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
    #[cfg_attr(feature = "serde", serde(default, deny_unknown_fields))]
    #[cfg_attr(feature = "defmt", derive(defmt::Format))]
    pub struct ControlGains in ["gains"] {
        /// Altitude (eq. 30).
        altitude: AltitudeGains = AltitudeGains::default(), { section } "";
        /// Yaw (eq. 31).
        yaw: YawGains = YawGains::default(), { section } "";
        /// Roll, for the position error along the body's left axis (eq. 33).
        roll: SaturatedAxisGains = SaturatedAxisGains::default(), { section } "";
        /// Pitch, for the position error along the body's forward axis (eq. 34).
        pitch: SaturatedAxisGains = SaturatedAxisGains::default(), { section } "";
        /// Cancel the gyroscopic and Coriolis torques (paper eq. 23).
        compensate_gyroscopic: bool = true, { any } "";
        /// Tilt beyond which the laws are no longer trusted; also the check on the saturation levels (rad).
        max_tilt_rad: f32 = 0.35, { > 0.05, < 1.0 } "rad";
    }
}

impl ControlGains {
    fn validate(&self, v: &VehicleParams) -> Result<(), ParamError> {
        let a = &self.altitude;
        a.check_declared(0)?;
        // With the integral: s^3 + a_z1 s^2 + a_z2 s + k_i, stable iff a_z1 a_z2 > k_i.
        check(
            a.a_z1 * a.a_z2 > a.integral_gain,
            "gains.altitude.integral_gain",
            "must be below a_z1 a_z2 (Routh-Hurwitz)",
        )?;
        let y = &self.yaw;
        y.check_declared(0)?;
        check(
            y.integral_gain < y.a_psi1 * y.a_psi2,
            "gains.yaw.integral_gain",
            "must lie in [0, a_psi1 a_psi2) (Routh-Hurwitz of s^3 + a_psi1 s^2 + a_psi2 s + k_i)",
        )?;
        check(
            y.integral_limit_rad_s2 <= y.max_accel_rad_s2,
            "gains.yaw.integral_limit_rad_s2",
            "must lie in [0, max_accel_rad_s2]",
        )?;
        self.check_declared(0)?;
        let auth = v.tilt_authority_rad_s2();
        self.roll.validate(auth, self.max_tilt_rad, Axis::Roll)?;
        self.pitch.validate(auth, self.max_tilt_rad, Axis::Pitch)
    }
}

params_struct! {
    /// Noise model and gates of the state estimator.
    #[derive(Clone, Copy, Debug, PartialEq)]
    #[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
    #[cfg_attr(feature = "serde", serde(default, deny_unknown_fields))]
    #[cfg_attr(feature = "defmt", derive(defmt::Format))]
    pub struct EstimatorParams in ["estimator"] {
        /// Gyro white-noise density (rad/s/sqrt(Hz)).
        gyro_noise: f32 = 1e-3, { > 0.0, <= 1.0 } "rad/s/sqrt(Hz)";
        /// Accelerometer white-noise density, vibration included (m/s^2/sqrt(Hz)).
        accel_noise: f32 = 0.045, { > 0.0, <= 10.0 } "m/s^2/sqrt(Hz)";
        /// Gyro bias random walk (rad/s^2/sqrt(Hz)).
        gyro_bias_walk: f32 = 1e-3, { > 0.0, <= 1.0 } "rad/s^2/sqrt(Hz)";
        /// Accelerometer bias random walk (m/s^3/sqrt(Hz)).
        accel_bias_walk: f32 = 3e-3, { > 0.0, <= 10.0 } "m/s^3/sqrt(Hz)";
        /// The accelerometer bias estimate is held within +-this on each axis (m/s^2). A MEMS accelerometer's
        /// offset is some tens of mg, and unbounded the bias, the tilt and the wind can drift together, each
        /// explaining the others to the position fixes (PX4's EKF2 bounds its estimate the same way,
        /// `EKF2_ABL_LIM`, 0.4 m/s^2 by default).
        accel_bias_limit_m_s2: f32 = 0.6, { > 0.0, <= 10.0 } "m/s^2";
        /// Lower bound of the vision position standard deviation (m).
        vision_position_floor_m: f32 = 0.004, { > 0.0, <= 1.0 } "m";
        /// Lower bound of the vision yaw standard deviation (rad).
        vision_yaw_floor_rad: f32 = 0.002, { > 0.0, <= 1.0 } "rad";
        /// Magnetometer heading standard deviation (rad).
        mag_heading_sigma_rad: f32 = 0.1, { > 0.0, <= 3.2 } "rad";
        /// While a vision yaw was accepted within `mag_vision_window_s`, a compass heading further than this
        /// from the estimate is refused (and counted) (rad).
        mag_consistency_rad: f32 = 0.15, { > 0.0, <= 3.2 } "rad";
        /// How recent a vision yaw must be for the compass to be checked against it (s).
        mag_vision_window_s: f32 = 1.0, { > 0.0, <= 10.0 } "s";
        /// Rate at which the compass's heading offset from the vision yaw is learned, per reading (0..1).
        mag_offset_learn_rate: f32 = 0.02, { > 0.0, <= 1.0 } "";
        /// Consecutive refused vision yaws after which the heading is reset to vision's.
        vision_yaw_reset_after: u8 = 5, { >= 1, <= 255 } "";
        /// Consecutive refused vision positions after which the position is reset to vision's (the estimate
        /// drifted while vision was out, as PX4's EKF2 resets to its aiding source after a fusion timeout);
        /// the tilt and the IMU biases go back to their initial uncertainty with it.
        vision_position_reset_after: u8 = 10, { >= 1, <= 255 } "";
        /// Standard deviation given to the velocity when the position is reset (m/s).
        reset_velocity_sigma_m_s: f32 = 0.5, { > 0.0, <= 10.0 } "m/s";
        /// Innovations beyond this many standard deviations are rejected.
        gate_sigma: f32 = 5.0, { >= 2.0, <= 1000.0 } "";
        /// Fixes older than this are not fused (s); at most the state history's length
        /// (`estimator::HISTORY_S`).
        max_fix_age_s: f32 = 0.25, { > 0.0, <= 0.256 } "s";
        /// Magnetic field in the world frame (any unit; only its horizontal direction is used).
        mag_field_world: [f32; 3] = [0.2, -0.05, -0.4], { >= -1e6, <= 1e6 } "";
        /// Barometer: standard deviation of one pressure-altitude reading (m), its noise and the short-term
        /// pressure disturbances of the rotors' wash together.
        baro_noise_m: f32 = 0.1, { > 0.0, <= 100.0 } "m";
        /// Barometer: time constant (s) over which its offset (the day's pressure, its slow drift) is learned
        /// against a height that vision or the pad gives.
        baro_offset_tau_s: f32 = 5.0, { > 0.0, <= 3600.0 } "s";
        /// At rest: standard deviation of the zero-velocity measurement, per block of samples (m/s).
        still_velocity_sigma_m_s: f32 = 0.02, { > 0.0, <= 10.0 } "m/s";
        /// At rest on the pad: standard deviation of the pad-height measurement, per block (m).
        ground_height_sigma_m: f32 = 0.01, { > 0.0, <= 10.0 } "m";
        /// At rest: standard deviation of a block's mean specific force as a gravity measurement (m/s^2).
        still_gravity_sigma_m_s2: f32 = 0.1, { > 0.0, <= 10.0 } "m/s^2";
        /// At rest: standard deviation of a block's mean angular rate as a gyro-bias measurement (rad/s).
        still_gyro_sigma_rad_s: f32 = 0.005, { > 0.0, <= 1.0 } "rad/s";
        /// Carried by hand: standard deviation of a block's mean specific force as a gravity measurement,
        /// the hand's accelerations (m/s^2).
        handheld_gravity_sigma_m_s2: f32 = 2.0, { > 0.0, <= 50.0 } "m/s^2";
        /// Rotor-drag coefficient `k` of the drag model `f_perp = -k v_perp` (1/s); 0 turns the model off.
        drag_coeff_per_s: f32 = 0.3, { >= 0.0, <= 2.0 } "1/s";
        /// Standard deviation of a block's mean specific force perpendicular to the thrust axis in the drag
        /// model: vibration and unmodelled aerodynamics (m/s^2).
        drag_sigma_m_s2: f32 = 0.3, { > 0.0, <= 50.0 } "m/s^2";
        /// Standard deviation of the horizontal wind before the drag model has seen any (m/s).
        initial_wind_sigma_m_s: f32 = 2.0, { > 0.0, <= 20.0 } "m/s";
        /// Random walk of the horizontal wind (m/s per sqrt(s)); its variance is capped at the initial one.
        wind_walk_m_s: f32 = 0.1, { > 0.0, <= 5.0 } "m/s/sqrt(s)";
        /// The rotors' thrust axis in the body frame (the drag model's reference; body z for this airframe);
        /// of length near 1.
        thrust_axis_body: [f32; 3] = [0.0, 0.0, 1.0], { >= -2.0, <= 2.0 } "";
        /// Time constant with which the thrust axis is learned in flight from the specific force's direction
        /// (s); 0 keeps `thrust_axis_body`. For recorded vehicles whose IMU mounting is unknown.
        thrust_axis_learn_s: f32 = 0.0, { >= 0.0, <= 1e4 } "s";
        /// Longest gap between IMU samples that is integrated (s); longer ones are counted, not integrated.
        max_imu_gap_s: f32 = 0.25, { >= 0.005, <= 1.0 } "s";
        /// Standard deviation of roll and pitch after the alignment from the first sample (rad).
        initial_tilt_sigma_rad: f32 = 0.05, { > 0.0, <= 1.0 } "rad";
        /// Standard deviation of the gyro bias before any measurement (rad/s).
        initial_gyro_bias_sigma_rad_s: f32 = 0.02, { > 0.0, <= 1.0 } "rad/s";
        /// Standard deviation of the accelerometer bias before any measurement (m/s^2).
        initial_accel_bias_sigma_m_s2: f32 = 0.1, { > 0.0, <= 5.0 } "m/s^2";
        /// The motion detector (still, carried, flying).
        motion: crate::motion::MotionParams = crate::motion::MotionParams::default(), { section } "";
    }
}

impl EstimatorParams {
    pub(crate) fn validate(&self) -> Result<(), ParamError> {
        self.check_declared(0)?;
        let m = self.mag_field_world;
        check(
            m[0] * m[0] + m[1] * m[1] > 1e-12,
            "estimator.mag_field_world",
            "must have a horizontal component",
        )?;
        let n = self.thrust_axis_body;
        check(
            n[0] * n[0] + n[1] * n[1] + n[2] * n[2] > 0.25,
            "estimator.thrust_axis_body",
            "must be finite and of length near 1",
        )?;
        self.motion.validate()
    }
}

params_struct! {
    /// The mission: take-off, the sweep of paper section 5.2, landing.
    #[derive(Clone, Copy, Debug, PartialEq)]
    #[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
    #[cfg_attr(feature = "serde", serde(default, deny_unknown_fields))]
    #[cfg_attr(feature = "defmt", derive(defmt::Format))]
    pub struct TrajectoryParams in ["trajectory"] {
        /// Distance to the wall to hold, `y_d` (m).
        y_d_m: f32 = 1.30, { > 0.0, <= 20.0 } "m";
        /// Altitude to hold, `z_d` (m); at least 0.2 m above `ground_height_m`.
        z_d_m: f32 = 0.80, { > 0.0, <= 20.0 } "m";
        /// Where each sweep starts and where it reverses (m); the end at least 0.1 m past the start.
        x_range_m: [f32; 2] = [0.0, 2.30], { >= -100.0, <= 100.0 } "m";
        /// Cruise speed along x (m/s).
        speed_m_s: f32 = 0.25, { > 0.0, <= 2.0 } "m/s";
        /// Acceleration at the start and end of each pass (m/s^2).
        accel_m_s2: f32 = 0.25, { > 0.0, <= 3.0 } "m/s^2";
        /// Number of sweeps (there and back).
        sweeps: u8 = 2, { >= 0, <= 100 } "";
        /// Heading to hold, from facing the wall (rad).
        yaw_d_rad: f32 = 0.0, { >= -1.0, <= 1.0 } "rad";
        /// Climb speed of the take-off (m/s).
        takeoff_speed_m_s: f32 = 0.4, { > 0.0, <= 2.0 } "m/s";
        /// Descent speed of the landing (m/s).
        landing_speed_m_s: f32 = 0.3, { > 0.0, <= 1.5 } "m/s";
        /// Hover time after take-off before tracking may start (s).
        settle_s: f32 = 2.0, { >= 0.0, <= 60.0 } "s";
        /// Height of the centre of mass above the floor when landed (m).
        ground_height_m: f32 = 0.06, { >= 0.0, <= 10.0 } "m";
        /// A take-off still not settled this long after its climb: the `TakeOffTimeout` failsafe (s); longer
        /// than `settle_s`.
        takeoff_timeout_s: f32 = 10.0, { > 0.0, <= 120.0 } "s";
    }
}

impl TrajectoryParams {
    fn validate(&self) -> Result<(), ParamError> {
        self.check_declared(0)?;
        check(
            self.z_d_m > self.ground_height_m + 0.2,
            "trajectory.z_d_m",
            "must be at least 0.2 m above the ground height",
        )?;
        check(
            self.x_range_m[1] > self.x_range_m[0] + 0.1,
            "trajectory.x_range_m",
            "must be [start, end] with end at least 0.1 m past start",
        )?;
        check(
            self.takeoff_timeout_s > self.settle_s,
            "trajectory.takeoff_timeout_s",
            "must exceed settle_s and be at most 120 s",
        )
    }
}

params_struct! {
    /// Failsafe timings and limits.
    #[derive(Clone, Copy, Debug, PartialEq)]
    #[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
    #[cfg_attr(feature = "serde", serde(default, deny_unknown_fields))]
    #[cfg_attr(feature = "defmt", derive(defmt::Format))]
    pub struct FailsafeParams in ["failsafe"] {
        /// No accepted vision fix for this long: hold attitude and altitude on the IMU (and flow) (s).
        vision_hold_after_s: f32 = 0.5, { > 0.0, <= 60.0 } "s";
        /// Still no fix this long after the hold began: land (s).
        vision_land_after_s: f32 = 3.0, { > 0.0, <= 600.0 } "s";
        /// No message from the ground station for this long: land (s). Before that the vehicle holds as when
        /// vision is lost (the fixes and the flow come over the link), and goes on when the link returns.
        link_land_after_s: f32 = 3.0, { > 0.0, <= 600.0 } "s";
        /// With no position aid at all (no vision fix and no flow velocity accepted for `vision_hold_after_s`:
        /// a radio loss blinds both, since the ground station measures the frames) a hold or a landing moves
        /// away from the wall at this speed (m/s; 0: stays). Dead reckoning drifts a metre in a few seconds
        /// of turbulence, in any direction; the wall is the one obstacle the vehicle knows, and it is in front.
        blind_retreat_speed_m_s: f32 = 0.2, { >= 0.0, <= 1.0 } "m/s";
        /// ... as far as twice the estimate's standard deviation of its distance to the wall
        /// (`BLIND_RETREAT_SIGMAS`), and at most this far in one blind spell (m).
        blind_retreat_max_m: f32 = 1.0, { >= 0.0, <= 5.0 } "m";
        /// No IMU sample for this long: motors off (s).
        imu_timeout_s: f32 = 0.05, { > 0.0, <= 1.0 } "s";
        /// Arming is refused when the vehicle is tilted more than this (rad).
        max_arming_tilt_rad: f32 = 0.15, { > 0.0, < 0.5 } "rad";
        /// Tilt at which the vehicle is considered lost: motors off (rad).
        crash_tilt_rad: f32 = 1.2, { > 0.5, < 3.0 } "rad";
        /// Land detector: the thrust demand below this fraction of the weight...
        land_thrust_fraction: f32 = 0.3, { > 0.0, < 0.9 } "";
        /// ... the specific force's magnitude within this of gravity (m/s^2)...
        land_accel_tolerance_m_s2: f32 = 1.0, { > 0.0, < 5.0 } "m/s^2";
        /// ... and the angular rate below this (rad/s)...
        land_rate_tolerance_rad_s: f32 = 0.3, { > 0.0, < 3.0 } "rad/s";
        /// ... for this long: landed, motors off (s).
        land_detect_s: f32 = 0.5, { > 0.0, <= 5.0 } "s";
        /// Landing: once the floor carries the vehicle, the thrust is wound down to idle over this time (s).
        ground_contact_ramp_s: f32 = 1.0, { > 0.0, <= 5.0 } "s";
    }
}

impl FailsafeParams {
    fn validate(&self) -> Result<(), ParamError> {
        self.check_declared(0)
    }
}

params_struct! {
    /// What the vehicle sends down the radio.
    #[derive(Clone, Copy, Debug, PartialEq)]
    #[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
    #[cfg_attr(feature = "serde", serde(default, deny_unknown_fields))]
    #[cfg_attr(feature = "defmt", derive(defmt::Format))]
    pub struct DownlinkParams in ["downlink"] {
        /// Telemetry every this many control steps (20: 25 Hz at 500 Hz). A ground station on a slow radio
        /// (a 57600-baud modem) sets it higher over the link: its compact mode.
        telemetry_every_steps: u8 = 20, { >= 1, <= 100 } "steps";
    }
}

impl DownlinkParams {
    fn validate(&self) -> Result<(), ParamError> {
        self.check_declared(0)
    }
}

params_struct! {
    /// The pilot's RC transmitter (`crate::pilot`; docs/architecture.md, "The pilot's transmitter").
    #[derive(Clone, Copy, Debug, PartialEq)]
    #[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
    #[cfg_attr(feature = "serde", serde(default, deny_unknown_fields))]
    #[cfg_attr(feature = "defmt", derive(defmt::Format))]
    pub struct RcParams in ["rc"] {
        /// Whether the vehicle needs the RC link: arming waits for it, and losing it lands (after
        /// `loss_hold_s`) in every mode, and disarms on the ground. Without, only manual flight needs it.
        required: bool = false, { any } "";
        /// The receiver's channels (0-based) of the roll, pitch, throttle and yaw sticks and of the arm, mode
        /// and kill switches: AETR with arm, mode and kill on channels 5, 6 and 7 (counted from 1), as
        /// ExpressLRS and Betaflight number them. Each different.
        channel_map: [u8; 7] = [0, 1, 2, 3, 4, 5, 6], { >= 0, <= 15 } "";
        /// Manual mode: the tilt at full stick (rad); at most `gains.max_tilt_rad`.
        max_tilt_rad: f32 = 0.25, { > 0.0, < 1.0 } "rad";
        /// Manual mode: the climb or descent rate with the throttle stick at an end (m/s); the centre holds
        /// the height.
        max_climb_m_s: f32 = 0.5, { > 0.0, <= 3.0 } "m/s";
        /// Manual mode: the yaw rate at full stick (rad/s).
        max_yaw_rate_rad_s: f32 = 1.0, { > 0.0, <= 6.0 } "rad/s";
        /// Stick travel around the centre that counts as centred, as a fraction of the half travel.
        deadband: f32 = 0.05, { >= 0.0, <= 0.3 } "";
        /// RC lost where it matters: hold level at the height this long, then land (s).
        loss_hold_s: f32 = 1.0, { >= 0.0, <= 30.0 } "s";
    }
}

impl RcParams {
    fn validate(&self, gains: &ControlGains) -> Result<(), ParamError> {
        self.check_declared(0)?;
        let c = self.channel_map;
        check(
            c.iter().enumerate().all(|(i, a)| c[i + 1..].iter().all(|b| a != b)),
            "rc.channel_map",
            "each function needs a channel of its own",
        )?;
        check(
            self.max_tilt_rad <= gains.max_tilt_rad,
            "rc.max_tilt_rad",
            "must not exceed gains.max_tilt_rad",
        )
    }
}

params_struct! {
    /// Everything the flight code needs.
    #[derive(Clone, Copy, Debug, PartialEq)]
    #[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
    #[cfg_attr(feature = "defmt", derive(defmt::Format))]
    pub struct FlightParams in [""] {
        /// Airframe and motors.
        vehicle: VehicleParams = VehicleParams::default(), { section } "";
        /// Control laws.
        gains: ControlGains = ControlGains::default(), { section } "";
        /// State estimator.
        estimator: EstimatorParams = EstimatorParams::default(), { section } "";
        /// Mission.
        trajectory: TrajectoryParams = TrajectoryParams::default(), { section } "";
        /// Failsafes.
        failsafe: FailsafeParams = FailsafeParams::default(), { section } "";
        /// The downlink.
        downlink: DownlinkParams = DownlinkParams::default(), { section } "";
        /// The pilot's transmitter.
        rc: RcParams = RcParams::default(), { section } "";
        /// The flight battery.
        battery: crate::battery::BatteryParams = crate::battery::BatteryParams::default(), { section } "";
        /// Where the vehicle waits on the ground before take-off, world frame (m): the estimator's position
        /// until the first vision fix.
        home_m: [f32; 3] = [0.0; 3], { >= -1000.0, <= 1000.0 } "m";
    }
}

impl FlightParams {
    /// The paper's experiment with the take-off pad at the start of the sweep.
    pub fn paper() -> Self {
        let t = TrajectoryParams::default();
        Self { home_m: [t.x_range_m[0], t.y_d_m, t.ground_height_m], ..Self::default() }
    }

    /// Checks every parameter; the error names the first bad field.
    pub fn validate(&self) -> Result<(), ParamError> {
        self.vehicle.validate()?;
        self.gains.validate(&self.vehicle)?;
        self.estimator.validate()?;
        self.trajectory.validate()?;
        self.failsafe.validate()?;
        self.downlink.validate()?;
        self.rc.validate(&self.gains)?;
        self.battery.validate()?;
        self.check_declared(0)
    }
}

/// The parameters that can be read and changed over the radio link, in wire order (one `f32` each; counts
/// are rounded): each names its field's path once, and the enum, [`ParamId::ALL`], [`ParamId::name`] and the
/// accessors are generated from that line. A test checks every name against the declared parameters.
macro_rules! param_ids {
    ($( $(#[doc = $doc:literal])* $id:ident = $name:literal, $kind:ident => [$($path:tt)+]; )*) => {
        /// A parameter that can be read and changed over the radio link (one `f32` each; counts are rounded).
        #[derive(Clone, Copy, Debug, PartialEq, Eq)]
        #[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
        #[cfg_attr(feature = "defmt", derive(defmt::Format))]
        #[repr(u8)]
        pub enum ParamId {
            $( $(#[doc = $doc])* $id, )*
        }

        impl ParamId {
            /// Every parameter, in wire order.
            pub const ALL: [ParamId; [$(ParamId::$id),*].len()] = [$(ParamId::$id),*];

            /// The field's dotted name, as in scenario files.
            pub fn name(self) -> &'static str {
                match self {
                    $( ParamId::$id => $name, )*
                }
            }

            /// The parameter's short name, at most 16 characters (the enum variant's name): what a MAVLink
            /// ground control station shows (`param_id` holds 16 bytes).
            pub fn short_name(self) -> &'static str {
                match self {
                    $( ParamId::$id => stringify!($id), )*
                }
            }

            fn read(self, p: &FlightParams) -> f32 {
                match self {
                    $( ParamId::$id => param_ids!(@read $kind p.$($path)+), )*
                }
            }

            fn write(self, p: &mut FlightParams, value: f32) {
                match self {
                    $( ParamId::$id => param_ids!(@write $kind p.$($path)+, value), )*
                }
            }
        }
    };
    (@read real $v:expr) => { $v };
    (@read count $v:expr) => { $v as f32 };
    (@write real $v:expr, $value:ident) => { $v = $value };
    // Counts are rounded to the nearest (the range 0..=100 is checked first).
    (@write count $v:expr, $value:ident) => { $v = ($value + 0.5) as u8 };
}

param_ids! {
    /// `trajectory.y_d_m`.
    TrajectoryYd = "trajectory.y_d_m", real => [trajectory.y_d_m];
    /// `trajectory.z_d_m`.
    TrajectoryZd = "trajectory.z_d_m", real => [trajectory.z_d_m];
    /// `trajectory.x_range_m[0]`.
    TrajectoryXStart = "trajectory.x_range_m[0]", real => [trajectory.x_range_m[0]];
    /// `trajectory.x_range_m[1]`.
    TrajectoryXEnd = "trajectory.x_range_m[1]", real => [trajectory.x_range_m[1]];
    /// `trajectory.speed_m_s`.
    TrajectorySpeed = "trajectory.speed_m_s", real => [trajectory.speed_m_s];
    /// `trajectory.accel_m_s2`.
    TrajectoryAccel = "trajectory.accel_m_s2", real => [trajectory.accel_m_s2];
    /// `trajectory.sweeps` (a count: the value is rounded).
    TrajectorySweeps = "trajectory.sweeps", count => [trajectory.sweeps];
    /// `trajectory.yaw_d_rad`.
    TrajectoryYaw = "trajectory.yaw_d_rad", real => [trajectory.yaw_d_rad];
    /// `gains.altitude.a_z1`.
    AltitudeAz1 = "gains.altitude.a_z1", real => [gains.altitude.a_z1];
    /// `gains.altitude.a_z2`.
    AltitudeAz2 = "gains.altitude.a_z2", real => [gains.altitude.a_z2];
    /// `gains.altitude.integral_gain`.
    AltitudeIntegral = "gains.altitude.integral_gain", real => [gains.altitude.integral_gain];
    /// `gains.yaw.a_psi1`.
    YawApsi1 = "gains.yaw.a_psi1", real => [gains.yaw.a_psi1];
    /// `gains.yaw.a_psi2`.
    YawApsi2 = "gains.yaw.a_psi2", real => [gains.yaw.a_psi2];
    /// `gains.roll.k[0]`.
    RollK1 = "gains.roll.k[0]", real => [gains.roll.k[0]];
    /// `gains.roll.k[1]`.
    RollK2 = "gains.roll.k[1]", real => [gains.roll.k[1]];
    /// `gains.roll.k[2]`.
    RollK3 = "gains.roll.k[2]", real => [gains.roll.k[2]];
    /// `gains.roll.k[3]`.
    RollK4 = "gains.roll.k[3]", real => [gains.roll.k[3]];
    /// `gains.roll.b[0]`.
    RollB1 = "gains.roll.b[0]", real => [gains.roll.b[0]];
    /// `gains.roll.b[1]`.
    RollB2 = "gains.roll.b[1]", real => [gains.roll.b[1]];
    /// `gains.roll.b[2]`.
    RollB3 = "gains.roll.b[2]", real => [gains.roll.b[2]];
    /// `gains.roll.b[3]`.
    RollB4 = "gains.roll.b[3]", real => [gains.roll.b[3]];
    /// `gains.roll.trim_gain`.
    RollTrim = "gains.roll.trim_gain", real => [gains.roll.trim_gain];
    /// `gains.pitch.k[0]`.
    PitchK1 = "gains.pitch.k[0]", real => [gains.pitch.k[0]];
    /// `gains.pitch.k[1]`.
    PitchK2 = "gains.pitch.k[1]", real => [gains.pitch.k[1]];
    /// `gains.pitch.k[2]`.
    PitchK3 = "gains.pitch.k[2]", real => [gains.pitch.k[2]];
    /// `gains.pitch.k[3]`.
    PitchK4 = "gains.pitch.k[3]", real => [gains.pitch.k[3]];
    /// `gains.pitch.b[0]`.
    PitchB1 = "gains.pitch.b[0]", real => [gains.pitch.b[0]];
    /// `gains.pitch.b[1]`.
    PitchB2 = "gains.pitch.b[1]", real => [gains.pitch.b[1]];
    /// `gains.pitch.b[2]`.
    PitchB3 = "gains.pitch.b[2]", real => [gains.pitch.b[2]];
    /// `gains.pitch.b[3]`.
    PitchB4 = "gains.pitch.b[3]", real => [gains.pitch.b[3]];
    /// `gains.pitch.trim_gain`.
    PitchTrim = "gains.pitch.trim_gain", real => [gains.pitch.trim_gain];
    /// `failsafe.vision_hold_after_s`.
    VisionHoldAfter = "failsafe.vision_hold_after_s", real => [failsafe.vision_hold_after_s];
    /// `failsafe.vision_land_after_s`.
    VisionLandAfter = "failsafe.vision_land_after_s", real => [failsafe.vision_land_after_s];
    /// `failsafe.link_land_after_s`.
    LinkLandAfter = "failsafe.link_land_after_s", real => [failsafe.link_land_after_s];
    /// `vehicle.mass_kg`.
    Mass = "vehicle.mass_kg", real => [vehicle.mass_kg];
    /// `downlink.telemetry_every_steps` (a count: the value is rounded).
    TelemetryEvery = "downlink.telemetry_every_steps", count => [downlink.telemetry_every_steps];
}

impl ParamId {
    /// The parameter with a dotted name.
    pub fn from_name(name: &str) -> Option<ParamId> {
        ParamId::ALL.iter().copied().find(|p| p.name() == name)
    }

    /// The parameter with this short name ([`ParamId::short_name`]), if any.
    pub fn from_short_name(name: &str) -> Option<ParamId> {
        ParamId::ALL.iter().copied().find(|p| p.short_name() == name)
    }
}

impl FlightParams {
    /// A parameter's value.
    pub fn get(&self, id: ParamId) -> f32 {
        id.read(self)
    }

    /// A copy with one parameter changed, validated as a whole; the error names the offending field.
    pub fn with(&self, id: ParamId, value: f32) -> Result<FlightParams, ParamError> {
        let mut p = *self;
        if !value.is_finite() {
            return Err(ParamError { field: id.name(), problem: "must be finite" });
        }
        // Counts are checked before the rounding cast (which would saturate).
        if id == ParamId::TrajectorySweeps && !(0.0..=100.0).contains(&value) {
            return Err(ParamError { field: id.name(), problem: "must lie in 0..=100" });
        }
        if id == ParamId::TelemetryEvery && !(0.5..=100.0).contains(&value) {
            return Err(ParamError { field: id.name(), problem: "must lie in 1..=100" });
        }
        id.write(&mut p, value);
        p.validate()?;
        Ok(p)
    }
}

/// Every declared parameter (sections left out), section by section in the order of the tree.
pub fn declared() -> impl Iterator<Item = &'static crate::declare::ParamSpec> {
    let tables: [&'static [crate::declare::ParamSpec]; 14] = [
        VehicleParams::SPECS[0],
        AltitudeGains::SPECS[0],
        YawGains::SPECS[0],
        SaturatedAxisGains::SPECS[0],
        SaturatedAxisGains::SPECS[1],
        ControlGains::SPECS[0],
        EstimatorParams::SPECS[0],
        crate::motion::MotionParams::SPECS[0],
        TrajectoryParams::SPECS[0],
        FailsafeParams::SPECS[0],
        DownlinkParams::SPECS[0],
        RcParams::SPECS[0],
        crate::battery::BatteryParams::SPECS[0],
        FlightParams::SPECS[0],
    ];
    tables.into_iter().flatten().filter(|s| !s.section)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_valid() {
        FlightParams::paper().validate().unwrap();
        let v = VehicleParams::default();
        assert!((v.hover_speed_rad_s() - 559.0).abs() < 1.0, "{}", v.hover_speed_rad_s());
    }

    #[test]
    fn routh_hurwitz_rejects_a_known_bad_set() {
        let mut p = FlightParams::paper();
        // All poles at -2 is stable: k2 = 8, k1 = 24, k4 = 32/g, k3 = 16/g.
        p.gains.roll.k = [24.0, 8.0, 16.0 / GRAVITY, 32.0 / GRAVITY];
        p.gains.roll.b = [40.0, 40.0, 1.0, 1.5];
        p.gains.roll.trim_gain = 0.0;
        // The attitude integral's bound (k2 k1 / 10) is checked on its own; keep it out of this test.
        p.gains.roll.attitude_integral_gain = 0.0;
        p.validate().unwrap();
        // Too much velocity gain: k2 k1 < g k4.
        p.gains.roll.k = [24.0, 8.0, 16.0 / GRAVITY, 200.0 / GRAVITY];
        let e = p.validate().unwrap_err();
        assert_eq!(e.field, "gains.roll");
        assert!(e.problem.contains("Routh"));
        // Second condition: k2 k1 g k4 > (g k4)^2 + k2^2 g k3 fails with a large position gain.
        p.gains.roll.k = [24.0, 8.0, 150.0 / GRAVITY, 32.0 / GRAVITY];
        assert!(p.validate().unwrap_err().problem.contains("Routh"));
    }

    #[test]
    fn saturation_levels_are_checked() {
        let mut p = FlightParams::paper();
        // Position terms not dominated by the angle terms (the notes' diverging (4, 4, 4, 4)).
        p.gains.pitch.b = [4.0, 4.0, 4.0, 4.0];
        let e = p.validate().unwrap_err();
        assert_eq!(e.field, "gains.pitch.b");
        assert!(e.problem.contains("dominate"));
        // More than the rotors can give.
        p.gains.pitch.b = [80.0, 80.0, 7.0, 8.0];
        assert!(p.validate().unwrap_err().problem.contains("rotors"));
        // Position and velocity terms that can cancel far from the reference.
        p.gains.pitch.b = [40.0, 40.0, 8.0, 8.0];
        assert!(p.validate().unwrap_err().problem.contains("b4 > b3"));
        // A tilt bound (b3 + b4) / k1 beyond max_tilt.
        p.gains.pitch.b = [40.0, 40.0, 8.0, 12.0];
        p.gains.max_tilt_rad = 0.1;
        assert!(p.validate().unwrap_err().problem.contains("largest tilt"));
    }

    #[test]
    fn parameters_by_id() {
        let p = FlightParams::paper();
        for id in ParamId::ALL {
            assert_eq!(ParamId::from_name(id.name()), Some(id));
            let v = p.get(id);
            assert!(v.is_finite(), "{}", id.name());
            // Setting a parameter to its own value keeps the set valid.
            assert_eq!(p.with(id, v).unwrap().get(id), v, "{}", id.name());
        }
        let q = p.with(ParamId::TrajectoryZd, 1.0).unwrap();
        assert_eq!(q.trajectory.z_d_m, 1.0);
        assert_eq!(p.with(ParamId::TrajectorySweeps, 3.0).unwrap().trajectory.sweeps, 3);
        // Invalid values are refused with the field that the set-wide check names.
        assert_eq!(p.with(ParamId::RollK4, 1000.0).unwrap_err().field, "gains.roll");
        assert_eq!(p.with(ParamId::Mass, f32::NAN).unwrap_err().field, "vehicle.mass_kg");
        assert!(ParamId::from_name("gains.roll.k[9]").is_none());
    }

    #[test]
    fn short_names_fit_mavlink_s_16_bytes_and_are_unique() {
        let mut names: std::vec::Vec<&str> = ParamId::ALL.iter().map(|id| id.short_name()).collect();
        assert!(names.iter().all(|n| !n.is_empty() && n.len() <= 16 && n.is_ascii()), "{names:?}");
        assert_eq!(ParamId::TrajectoryXStart.short_name(), "TrajectoryXStart");
        names.sort_unstable();
        names.dedup();
        assert_eq!(names.len(), ParamId::ALL.len());
        for id in ParamId::ALL {
            assert_eq!(ParamId::from_short_name(id.short_name()), Some(id));
        }
        assert_eq!(ParamId::from_short_name("Nope"), None);
    }

    #[test]
    fn every_radio_parameter_is_a_declared_one_and_names_are_unique() {
        let names: std::vec::Vec<&str> = declared().map(|s| s.name).collect();
        for id in ParamId::ALL {
            let field = id.name().split('[').next().unwrap();
            assert!(names.contains(&field), "{} is not declared", id.name());
        }
        let mut sorted = names.clone();
        sorted.sort_unstable();
        sorted.dedup();
        assert_eq!(sorted.len(), names.len(), "a name declared twice");
        // The tree's two uses of the tilt-axis gains name their own fields.
        assert!(names.contains(&"gains.roll.trim_gain") && names.contains(&"gains.pitch.trim_gain"));
        assert!(names.len() > 90, "{}", names.len());
    }

    #[test]
    fn a_declared_range_refuses_with_its_field_and_states_the_range() {
        let mut p = FlightParams::paper();
        p.failsafe.imu_timeout_s = 2.0;
        let e = p.validate().unwrap_err();
        assert_eq!((e.field, e.problem), ("failsafe.imu_timeout_s", "must lie in (0.0, 1.0] s"));
        let mut p = FlightParams::paper();
        p.gains.pitch.trim_limit_rad = -0.01;
        let e = p.validate().unwrap_err();
        assert_eq!((e.field, e.problem), ("gains.pitch.trim_limit_rad", "must be finite and >= 0.0 rad"));
        let mut p = FlightParams::paper();
        p.estimator.motion.window_blocks = 17;
        assert_eq!(p.validate().unwrap_err().field, "estimator.motion.window_blocks");
        let mut p = FlightParams::paper();
        p.home_m[2] = f32::INFINITY;
        assert_eq!(p.validate().unwrap_err().field, "home_m");
        // Open and closed bounds: the bound itself is refused or accepted as declared.
        let mut p = FlightParams::paper();
        p.failsafe.imu_timeout_s = 1.0;
        p.validate().unwrap();
        p.failsafe.imu_timeout_s = 0.0;
        assert_eq!(p.validate().unwrap_err().field, "failsafe.imu_timeout_s");
    }

    #[test]
    fn other_fields_are_named() {
        let mut p = FlightParams::paper();
        p.vehicle.mass_kg = -1.0;
        assert_eq!(p.validate().unwrap_err().field, "vehicle.mass_kg");
        let mut p = FlightParams::paper();
        p.trajectory.x_range_m = [2.0, 1.0];
        assert_eq!(p.validate().unwrap_err().field, "trajectory.x_range_m");
        let mut p = FlightParams::paper();
        p.gains.altitude.integral_gain = 100.0;
        assert_eq!(p.validate().unwrap_err().field, "gains.altitude.integral_gain");
        let mut p = FlightParams::paper();
        p.estimator.gyro_noise = f32::NAN;
        assert_eq!(p.validate().unwrap_err().field, "estimator.gyro_noise");
    }
}
