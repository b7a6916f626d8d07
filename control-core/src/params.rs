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

fn positive(v: f32, field: &'static str) -> Result<(), ParamError> {
    check(v.is_finite() && v > 0.0, field, "must be positive and finite")
}

fn non_negative(v: f32, field: &'static str) -> Result<(), ParamError> {
    check(v.is_finite() && v >= 0.0, field, "must be finite and not negative")
}

/// The airframe, rotors and motors ("+" configuration: M1 front, M2 left, M3 rear, M4 right).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "serde", serde(default, deny_unknown_fields))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct VehicleParams {
    /// Total mass (kg).
    pub mass_kg: f32,
    /// Distance from the centre of mass to each rotor axis (m).
    pub arm_length_m: f32,
    /// Principal moments of inertia `Ixx, Iyy, Izz` (kg m^2).
    pub inertia_kg_m2: [f32; 3],
    /// Thrust coefficient `k`: `f = k w^2` (N s^2).
    pub thrust_coeff: f32,
    /// Drag-torque coefficient `k_tau`: `tau = k_tau w^2` (N m s^2).
    pub drag_torque_coeff: f32,
    /// Moment of inertia of one rotor about its axis (kg m^2).
    pub rotor_inertia_kg_m2: f32,
    /// Lowest rotor speed while armed (idle) (rad/s).
    pub motor_speed_min_rad_s: f32,
    /// Highest rotor speed (rad/s).
    pub motor_speed_max_rad_s: f32,
}

impl Default for VehicleParams {
    /// The paper's 380 g X4, estimated from published parameter sets (see docs/architecture.md).
    fn default() -> Self {
        Self {
            mass_kg: 0.38,
            arm_length_m: 0.225,
            inertia_kg_m2: [3.9e-3, 3.9e-3, 7.1e-3],
            thrust_coeff: 2.98e-6,
            drag_torque_coeff: 1.14e-7,
            rotor_inertia_kg_m2: 3.357e-5,
            motor_speed_min_rad_s: 150.0,
            motor_speed_max_rad_s: 900.0,
        }
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

    /// The ranges are those of multirotors from a 50 g micro to a 20 kg heavy lifter: a value outside is a
    /// typing or unit error (1e-30 kg m^2 of inertia, a thrust coefficient in the wrong unit), not a vehicle.
    fn validate(&self) -> Result<(), ParamError> {
        let within = |v: f32, lo: f32, hi: f32, field: &'static str, problem: &'static str| {
            check(v.is_finite() && v >= lo && v <= hi, field, problem)
        };
        within(self.mass_kg, 0.05, 20.0, "vehicle.mass_kg", "must lie in [0.05, 20] kg")?;
        within(self.arm_length_m, 0.03, 1.5, "vehicle.arm_length_m", "must lie in [0.03, 1.5] m")?;
        for &i in &self.inertia_kg_m2 {
            within(i, 1e-5, 10.0, "vehicle.inertia_kg_m2", "each must lie in [1e-5, 10] kg m^2")?;
        }
        within(self.thrust_coeff, 1e-9, 1e-3, "vehicle.thrust_coeff", "must lie in [1e-9, 1e-3] N s^2")?;
        within(
            self.drag_torque_coeff,
            1e-11,
            1e-4,
            "vehicle.drag_torque_coeff",
            "must lie in [1e-11, 1e-4] N m s^2",
        )?;
        within(
            self.rotor_inertia_kg_m2,
            0.0,
            1e-2,
            "vehicle.rotor_inertia_kg_m2",
            "must lie in [0, 1e-2] kg m^2",
        )?;
        non_negative(self.motor_speed_min_rad_s, "vehicle.motor_speed_min_rad_s")?;
        within(
            self.motor_speed_max_rad_s,
            10.0,
            1e4,
            "vehicle.motor_speed_max_rad_s",
            "must lie in [10, 1e4] rad/s",
        )?;
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

/// Altitude law (paper eq. 30): `T/m = (g + z''_d - a_z1 e_z' - a_z2 e_z - i_z) / max(cos(theta) cos(phi), c_min)`,
/// with an optional bounded integral `i_z` (not in the paper).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "serde", serde(default, deny_unknown_fields))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct AltitudeGains {
    /// `a_z1`, on the vertical speed error (1/s).
    pub a_z1: f32,
    /// `a_z2`, on the altitude error (1/s^2).
    pub a_z2: f32,
    /// Integral gain on the altitude error (1/s^3); 0 gives the paper's law.
    pub integral_gain: f32,
    /// Bound of the integral term (m/s^2).
    pub integral_limit_m_s2: f32,
    /// Lower clamp of `cos(theta) cos(phi)` in the division.
    pub min_cos_tilt: f32,
    /// Thrust bound as a multiple of the weight.
    pub max_thrust_to_weight: f32,
}

impl Default for AltitudeGains {
    fn default() -> Self {
        // Poles of s^2 + a_z1 s + a_z2 at 2.5 rad/s, damping 0.9.
        Self {
            a_z1: 4.5,
            a_z2: 6.25,
            // With the PD poles above, s^3 + a_z1 s^2 + a_z2 s + k_i has its roots at -2.45 and
            // -1.03 +- 0.41j: a thrust error (mass, thrust coefficient, battery) is integrated out in about a
            // second, well damped.
            integral_gain: 3.0,
            integral_limit_m_s2: 4.0,
            min_cos_tilt: 0.5,
            max_thrust_to_weight: 2.0,
        }
    }
}

/// Yaw law (paper eq. 31): `tau/J_zz = -a_psi1 psi' - a_psi2 (psi - psi_d)`, bounded.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "serde", serde(default, deny_unknown_fields))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct YawGains {
    /// `a_psi1`, on the yaw rate (1/s).
    pub a_psi1: f32,
    /// `a_psi2`, on the yaw error (1/s^2).
    pub a_psi2: f32,
    /// Bound of the commanded yaw angular acceleration (rad/s^2).
    pub max_accel_rad_s2: f32,
    /// Gain of the integral of the yaw error (1/s^3): a steady yaw torque (a weaker rotor's neighbours spin
    /// faster, and their drag torque is not balanced) is taken without a steady yaw error. 0 gives the paper's
    /// law.
    pub integral_gain: f32,
    /// Bound of that integral (rad/s^2).
    pub integral_limit_rad_s2: f32,
}

impl Default for YawGains {
    fn default() -> Self {
        // s^3 + 6 s^2 + 9 s + 4: the poles at -4 and a double -1.
        Self {
            a_psi1: 6.0,
            a_psi2: 9.0,
            max_accel_rad_s2: 10.0,
            integral_gain: 4.0,
            integral_limit_rad_s2: 5.0,
        }
    }
}

/// One of the bounded lateral/longitudinal laws (paper eq. 33-34), a **sum** of saturations:
///
/// `u = -s sigma_b4(k4 e') - s sigma_b3(k3 e) - sigma_b2(k2 angle') - sigma_b1(k1 (angle - angle_ff))`
///
/// for the chain `e'' = s g angle` (`s = +1` for pitch and the forward error, `s = -1` for roll and the
/// leftward error), where `e` is the position error (m), `angle` the tilt (rad) and `u = tau / J` (rad/s^2).
/// Linear part: `s^4 + k2 s^3 + k1 s^2 + g k4 s + g k3`.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "serde", serde(default, deny_unknown_fields))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SaturatedAxisGains {
    /// `k1..k4`: on the angle (1/s^2), the angular rate (1/s), the position (1/(m s^2)... see the law), the
    /// velocity.
    pub k: [f32; 4],
    /// Saturation levels `b1..b4` of the four terms (rad/s^2).
    pub b: [f32; 4],
    /// Gain of the slow trim that integrates the position error into the angle reference (rad/(m s)); 0 gives
    /// the paper's law.
    pub trim_gain: f32,
    /// Bound of that trim (rad).
    pub trim_limit_rad: f32,
    /// Gain of the integral of the attitude error (the angle less the one the position terms ask for) added
    /// to the angular acceleration (1/s^3): it takes a steady torque (a weaker rotor, a centre of mass off the
    /// axis) that the angle term would otherwise hold with a steady attitude error, as the integrators of
    /// PX4's and ArduPilot's rate controllers do. 0 gives the paper's law.
    pub attitude_integral_gain: f32,
    /// Bound of that integral (rad/s^2).
    pub attitude_integral_limit_rad_s2: f32,
}

impl Default for SaturatedAxisGains {
    fn default() -> Self {
        // Poles: an attitude pair at 10 rad/s (damping 0.8) and a position pair at POSITION_POLE_RAD_S
        // (damping 0.9).
        Self::from_poles(10.0, 0.8, POSITION_POLE_RAD_S, 0.9, [40.0, 40.0, 8.0, 12.0], TRIM_GAIN, 0.05)
    }
}

const POSITION_POLE_RAD_S: f32 = 2.5;
const TRIM_GAIN: f32 = 0.05;

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
        for &k in &self.k {
            positive(k, f(names, 0))?;
        }
        for &b in &self.b {
            positive(b, f(names, 1))?;
        }
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
        non_negative(self.trim_gain, f(names, 4))?;
        non_negative(self.trim_limit_rad, f(names, 5))?;
        check(
            self.trim_limit_rad <= 0.2 * max_tilt_rad,
            f(names, 5),
            "must stay below a fifth of max_tilt_rad",
        )?;
        // The attitude integral on the attitude pair s^2 + k2 s + k1: s^3 + k2 s^2 + k1 s + k_i is stable for
        // k_i < k2 k1; kept a tenth of that.
        check(
            self.attitude_integral_gain >= 0.0 && self.attitude_integral_gain <= 0.1 * self.k[1] * self.k[0],
            f(names, 6),
            "must lie in [0, k2 k1 / 10] (the attitude pair with the integral stays well damped)",
        )?;
        check(
            self.attitude_integral_limit_rad_s2 >= 0.0 && self.attitude_integral_limit_rad_s2 <= self.b[0],
            f(names, 7),
            "must lie in [0, b1]",
        )?;
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

/// All the control gains.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "serde", serde(default, deny_unknown_fields))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ControlGains {
    /// Altitude (eq. 30).
    pub altitude: AltitudeGains,
    /// Yaw (eq. 31).
    pub yaw: YawGains,
    /// Roll, for the position error along the body's left axis (eq. 33).
    pub roll: SaturatedAxisGains,
    /// Pitch, for the position error along the body's forward axis (eq. 34).
    pub pitch: SaturatedAxisGains,
    /// Cancel the gyroscopic and Coriolis torques (paper eq. 23).
    pub compensate_gyroscopic: bool,
    /// Tilt beyond which the laws are no longer trusted; also the check on the saturation levels (rad).
    pub max_tilt_rad: f32,
}

impl Default for ControlGains {
    fn default() -> Self {
        Self {
            altitude: AltitudeGains::default(),
            yaw: YawGains::default(),
            roll: SaturatedAxisGains::default(),
            pitch: SaturatedAxisGains::default(),
            compensate_gyroscopic: true,
            max_tilt_rad: 0.35,
        }
    }
}

impl ControlGains {
    fn validate(&self, v: &VehicleParams) -> Result<(), ParamError> {
        let a = &self.altitude;
        positive(a.a_z1, "gains.altitude.a_z1")?;
        positive(a.a_z2, "gains.altitude.a_z2")?;
        non_negative(a.integral_gain, "gains.altitude.integral_gain")?;
        non_negative(a.integral_limit_m_s2, "gains.altitude.integral_limit_m_s2")?;
        // With the integral: s^3 + a_z1 s^2 + a_z2 s + k_i, stable iff a_z1 a_z2 > k_i.
        check(
            a.a_z1 * a.a_z2 > a.integral_gain,
            "gains.altitude.integral_gain",
            "must be below a_z1 a_z2 (Routh-Hurwitz)",
        )?;
        check(
            a.min_cos_tilt > 0.1 && a.min_cos_tilt <= 1.0,
            "gains.altitude.min_cos_tilt",
            "must lie in (0.1, 1]",
        )?;
        check(
            a.max_thrust_to_weight > 1.2 && a.max_thrust_to_weight.is_finite(),
            "gains.altitude.max_thrust_to_weight",
            "must exceed 1.2",
        )?;
        let y = &self.yaw;
        positive(y.a_psi1, "gains.yaw.a_psi1")?;
        positive(y.a_psi2, "gains.yaw.a_psi2")?;
        positive(y.max_accel_rad_s2, "gains.yaw.max_accel_rad_s2")?;
        check(
            y.integral_gain >= 0.0 && y.integral_gain < y.a_psi1 * y.a_psi2,
            "gains.yaw.integral_gain",
            "must lie in [0, a_psi1 a_psi2) (Routh-Hurwitz of s^3 + a_psi1 s^2 + a_psi2 s + k_i)",
        )?;
        check(
            y.integral_limit_rad_s2 >= 0.0 && y.integral_limit_rad_s2 <= y.max_accel_rad_s2,
            "gains.yaw.integral_limit_rad_s2",
            "must lie in [0, max_accel_rad_s2]",
        )?;
        check(
            self.max_tilt_rad > 0.05 && self.max_tilt_rad < 1.0,
            "gains.max_tilt_rad",
            "must lie in (0.05, 1) rad",
        )?;
        let auth = v.tilt_authority_rad_s2();
        self.roll.validate(auth, self.max_tilt_rad, Axis::Roll)?;
        self.pitch.validate(auth, self.max_tilt_rad, Axis::Pitch)
    }
}

/// Noise model and gates of the state estimator.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "serde", serde(default, deny_unknown_fields))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct EstimatorParams {
    /// Gyro white-noise density (rad/s/sqrt(Hz)).
    pub gyro_noise: f32,
    /// Accelerometer white-noise density, vibration included (m/s^2/sqrt(Hz)).
    pub accel_noise: f32,
    /// Gyro bias random walk (rad/s^2/sqrt(Hz)).
    pub gyro_bias_walk: f32,
    /// Accelerometer bias random walk (m/s^3/sqrt(Hz)).
    pub accel_bias_walk: f32,
    /// Lower bound of the vision position standard deviation (m).
    pub vision_position_floor_m: f32,
    /// Lower bound of the vision yaw standard deviation (rad).
    pub vision_yaw_floor_rad: f32,
    /// Magnetometer heading standard deviation (rad).
    pub mag_heading_sigma_rad: f32,
    /// While a vision yaw was accepted within `mag_vision_window_s`, a compass heading further than this from
    /// the estimate is refused (and counted) (rad).
    pub mag_consistency_rad: f32,
    /// How recent a vision yaw must be for the compass to be checked against it (s).
    pub mag_vision_window_s: f32,
    /// Rate at which the compass's heading offset from the vision yaw is learned, per reading (0..1).
    pub mag_offset_learn_rate: f32,
    /// Consecutive refused vision yaws after which the heading is reset to vision's.
    pub vision_yaw_reset_after: u8,
    /// Consecutive refused vision positions after which the position is reset to vision's (the estimate
    /// drifted while vision was out, as PX4's EKF2 resets to its aiding source after a fusion timeout); the
    /// tilt and the IMU biases go back to their initial uncertainty with it.
    pub vision_position_reset_after: u8,
    /// Standard deviation given to the velocity when the position is reset (m/s).
    pub reset_velocity_sigma_m_s: f32,
    /// Innovations beyond this many standard deviations are rejected.
    pub gate_sigma: f32,
    /// Fixes older than this are not fused (s).
    pub max_fix_age_s: f32,
    /// Magnetic field in the world frame (any unit; only its horizontal direction is used).
    pub mag_field_world: [f32; 3],
    /// At rest: standard deviation of the zero-velocity measurement, per block of samples (m/s).
    pub still_velocity_sigma_m_s: f32,
    /// At rest on the pad: standard deviation of the pad-height measurement, per block (m).
    pub ground_height_sigma_m: f32,
    /// At rest: standard deviation of a block's mean specific force as a gravity measurement (m/s^2).
    pub still_gravity_sigma_m_s2: f32,
    /// At rest: standard deviation of a block's mean angular rate as a gyro-bias measurement (rad/s).
    pub still_gyro_sigma_rad_s: f32,
    /// Carried by hand: standard deviation of a block's mean specific force as a gravity measurement, the
    /// hand's accelerations (m/s^2).
    pub handheld_gravity_sigma_m_s2: f32,
    /// Rotor-drag coefficient `k` of the drag model `f_perp = -k v_perp` (1/s); 0 turns the model off.
    pub drag_coeff_per_s: f32,
    /// Standard deviation of a block's mean specific force perpendicular to the thrust axis in the drag
    /// model: vibration and unmodelled aerodynamics (m/s^2).
    pub drag_sigma_m_s2: f32,
    /// Standard deviation of the horizontal wind before the drag model has seen any (m/s).
    pub initial_wind_sigma_m_s: f32,
    /// Random walk of the horizontal wind (m/s per sqrt(s)); its variance is capped at the initial one.
    pub wind_walk_m_s: f32,
    /// The rotors' thrust axis in the body frame (the drag model's reference; body z for this airframe).
    pub thrust_axis_body: [f32; 3],
    /// Time constant with which the thrust axis is learned in flight from the specific force's direction
    /// (s); 0 keeps `thrust_axis_body`. For recorded vehicles whose IMU mounting is unknown.
    pub thrust_axis_learn_s: f32,
    /// Longest gap between IMU samples that is integrated (s); longer ones are counted, not integrated.
    pub max_imu_gap_s: f32,
    /// Standard deviation of roll and pitch after the alignment from the first sample (rad).
    pub initial_tilt_sigma_rad: f32,
    /// Standard deviation of the gyro bias before any measurement (rad/s).
    pub initial_gyro_bias_sigma_rad_s: f32,
    /// Standard deviation of the accelerometer bias before any measurement (m/s^2).
    pub initial_accel_bias_sigma_m_s2: f32,
    /// The motion detector (still, carried, flying).
    pub motion: crate::motion::MotionParams,
}

impl Default for EstimatorParams {
    fn default() -> Self {
        Self {
            gyro_noise: 1e-3,
            accel_noise: 0.045,
            gyro_bias_walk: 1e-3,
            accel_bias_walk: 3e-3,
            vision_position_floor_m: 0.004,
            vision_yaw_floor_rad: 0.002,
            mag_heading_sigma_rad: 0.1,
            mag_consistency_rad: 0.15,
            mag_vision_window_s: 1.0,
            mag_offset_learn_rate: 0.02,
            vision_yaw_reset_after: 5,
            vision_position_reset_after: 10,
            reset_velocity_sigma_m_s: 0.5,
            gate_sigma: 5.0,
            max_fix_age_s: 0.25,
            mag_field_world: [0.2, -0.05, -0.4],
            still_velocity_sigma_m_s: 0.02,
            ground_height_sigma_m: 0.01,
            still_gravity_sigma_m_s2: 0.1,
            still_gyro_sigma_rad_s: 0.005,
            handheld_gravity_sigma_m_s2: 2.0,
            drag_coeff_per_s: 0.3,
            drag_sigma_m_s2: 0.3,
            initial_wind_sigma_m_s: 2.0,
            wind_walk_m_s: 0.1,
            thrust_axis_body: [0.0, 0.0, 1.0],
            thrust_axis_learn_s: 0.0,
            max_imu_gap_s: 0.25,
            initial_tilt_sigma_rad: 0.05,
            initial_gyro_bias_sigma_rad_s: 0.02,
            initial_accel_bias_sigma_m_s2: 0.1,
            motion: crate::motion::MotionParams::default(),
        }
    }
}

impl EstimatorParams {
    fn validate(&self) -> Result<(), ParamError> {
        positive(self.gyro_noise, "estimator.gyro_noise")?;
        positive(self.accel_noise, "estimator.accel_noise")?;
        positive(self.gyro_bias_walk, "estimator.gyro_bias_walk")?;
        positive(self.accel_bias_walk, "estimator.accel_bias_walk")?;
        positive(self.vision_position_floor_m, "estimator.vision_position_floor_m")?;
        positive(self.vision_yaw_floor_rad, "estimator.vision_yaw_floor_rad")?;
        positive(self.mag_heading_sigma_rad, "estimator.mag_heading_sigma_rad")?;
        check(
            self.mag_consistency_rad > 0.0 && self.mag_consistency_rad <= 3.2,
            "estimator.mag_consistency_rad",
            "must lie in (0, pi] rad",
        )?;
        check(
            self.mag_vision_window_s > 0.0 && self.mag_vision_window_s <= 10.0,
            "estimator.mag_vision_window_s",
            "must lie in (0, 10] s",
        )?;
        check(
            self.mag_offset_learn_rate > 0.0 && self.mag_offset_learn_rate <= 1.0,
            "estimator.mag_offset_learn_rate",
            "must lie in (0, 1]",
        )?;
        check(self.vision_yaw_reset_after >= 1, "estimator.vision_yaw_reset_after", "must be at least 1")?;
        check(
            self.reset_velocity_sigma_m_s > 0.0 && self.reset_velocity_sigma_m_s <= 10.0,
            "estimator.reset_velocity_sigma_m_s",
            "must lie in (0, 10] m/s",
        )?;
        check(
            self.vision_position_reset_after >= 1,
            "estimator.vision_position_reset_after",
            "must be at least 1",
        )?;
        check(
            self.gate_sigma >= 2.0 && self.gate_sigma.is_finite(),
            "estimator.gate_sigma",
            "must be at least 2",
        )?;
        check(
            self.max_fix_age_s > 0.0 && self.max_fix_age_s <= crate::estimator::HISTORY_S,
            "estimator.max_fix_age_s",
            "must be positive and within the state history (0.5 s)",
        )?;
        let m = self.mag_field_world;
        check(
            m.iter().all(|v| v.is_finite()) && m[0] * m[0] + m[1] * m[1] > 1e-12,
            "estimator.mag_field_world",
            "must be finite with a horizontal component",
        )?;
        positive(self.still_velocity_sigma_m_s, "estimator.still_velocity_sigma_m_s")?;
        positive(self.ground_height_sigma_m, "estimator.ground_height_sigma_m")?;
        positive(self.still_gravity_sigma_m_s2, "estimator.still_gravity_sigma_m_s2")?;
        positive(self.still_gyro_sigma_rad_s, "estimator.still_gyro_sigma_rad_s")?;
        positive(self.handheld_gravity_sigma_m_s2, "estimator.handheld_gravity_sigma_m_s2")?;
        check(
            self.drag_coeff_per_s.is_finite() && (0.0..=2.0).contains(&self.drag_coeff_per_s),
            "estimator.drag_coeff_per_s",
            "must lie in [0, 2] 1/s",
        )?;
        positive(self.drag_sigma_m_s2, "estimator.drag_sigma_m_s2")?;
        let n = self.thrust_axis_body;
        check(
            n.iter().all(|v| v.is_finite()) && n[0] * n[0] + n[1] * n[1] + n[2] * n[2] > 0.25,
            "estimator.thrust_axis_body",
            "must be finite and of length near 1",
        )?;
        non_negative(self.thrust_axis_learn_s, "estimator.thrust_axis_learn_s")?;
        check(
            self.max_imu_gap_s >= 0.005 && self.max_imu_gap_s <= 1.0,
            "estimator.max_imu_gap_s",
            "must lie in [0.005, 1] s",
        )?;
        check(
            self.initial_tilt_sigma_rad > 0.0 && self.initial_tilt_sigma_rad <= 1.0,
            "estimator.initial_tilt_sigma_rad",
            "must lie in (0, 1] rad",
        )?;
        check(
            self.initial_gyro_bias_sigma_rad_s > 0.0 && self.initial_gyro_bias_sigma_rad_s <= 1.0,
            "estimator.initial_gyro_bias_sigma_rad_s",
            "must lie in (0, 1] rad/s",
        )?;
        check(
            self.initial_accel_bias_sigma_m_s2 > 0.0 && self.initial_accel_bias_sigma_m_s2 <= 5.0,
            "estimator.initial_accel_bias_sigma_m_s2",
            "must lie in (0, 5] m/s^2",
        )?;
        check(
            self.initial_wind_sigma_m_s > 0.0 && self.initial_wind_sigma_m_s <= 20.0,
            "estimator.initial_wind_sigma_m_s",
            "must lie in (0, 20] m/s",
        )?;
        check(
            self.wind_walk_m_s > 0.0 && self.wind_walk_m_s <= 5.0,
            "estimator.wind_walk_m_s",
            "must lie in (0, 5] m/s per sqrt(s)",
        )?;
        self.motion.validate()
    }
}

/// The mission: take-off, the sweep of paper section 5.2, landing.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "serde", serde(default, deny_unknown_fields))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct TrajectoryParams {
    /// Distance to the wall to hold, `y_d` (m).
    pub y_d_m: f32,
    /// Altitude to hold, `z_d` (m).
    pub z_d_m: f32,
    /// Where each sweep starts and where it reverses (m).
    pub x_range_m: [f32; 2],
    /// Cruise speed along x (m/s).
    pub speed_m_s: f32,
    /// Acceleration at the start and end of each pass (m/s^2).
    pub accel_m_s2: f32,
    /// Number of sweeps (there and back).
    pub sweeps: u8,
    /// Heading to hold, from facing the wall (rad).
    pub yaw_d_rad: f32,
    /// Climb speed of the take-off (m/s).
    pub takeoff_speed_m_s: f32,
    /// Descent speed of the landing (m/s).
    pub landing_speed_m_s: f32,
    /// Hover time after take-off before tracking may start (s).
    pub settle_s: f32,
    /// Height of the centre of mass above the floor when landed (m).
    pub ground_height_m: f32,
    /// A take-off still not settled this long after its climb: the `TakeOffTimeout` failsafe (s).
    pub takeoff_timeout_s: f32,
}

impl Default for TrajectoryParams {
    fn default() -> Self {
        Self {
            y_d_m: 1.30,
            z_d_m: 0.80,
            x_range_m: [0.0, 2.30],
            speed_m_s: 0.25,
            accel_m_s2: 0.25,
            sweeps: 2,
            yaw_d_rad: 0.0,
            takeoff_speed_m_s: 0.4,
            landing_speed_m_s: 0.3,
            settle_s: 2.0,
            ground_height_m: 0.06,
            takeoff_timeout_s: 10.0,
        }
    }
}

impl TrajectoryParams {
    fn validate(&self) -> Result<(), ParamError> {
        positive(self.y_d_m, "trajectory.y_d_m")?;
        check(
            self.z_d_m > self.ground_height_m + 0.2 && self.z_d_m.is_finite(),
            "trajectory.z_d_m",
            "must be at least 0.2 m above the ground height",
        )?;
        check(
            self.x_range_m.iter().all(|v| v.is_finite()) && self.x_range_m[1] > self.x_range_m[0] + 0.1,
            "trajectory.x_range_m",
            "must be [start, end] with end at least 0.1 m past start",
        )?;
        check(
            self.speed_m_s > 0.0 && self.speed_m_s <= 2.0,
            "trajectory.speed_m_s",
            "must lie in (0, 2] m/s",
        )?;
        check(
            self.accel_m_s2 > 0.0 && self.accel_m_s2 <= 3.0,
            "trajectory.accel_m_s2",
            "must lie in (0, 3] m/s^2",
        )?;
        check(
            self.yaw_d_rad.abs() <= 1.0,
            "trajectory.yaw_d_rad",
            "must lie within 1 rad of facing the wall",
        )?;
        check(
            self.takeoff_speed_m_s > 0.0 && self.takeoff_speed_m_s <= 2.0,
            "trajectory.takeoff_speed_m_s",
            "must lie in (0, 2] m/s",
        )?;
        check(
            self.landing_speed_m_s > 0.0 && self.landing_speed_m_s <= 1.5,
            "trajectory.landing_speed_m_s",
            "must lie in (0, 1.5] m/s",
        )?;
        non_negative(self.settle_s, "trajectory.settle_s")?;
        check(
            self.takeoff_timeout_s > self.settle_s && self.takeoff_timeout_s <= 120.0,
            "trajectory.takeoff_timeout_s",
            "must exceed settle_s and be at most 120 s",
        )?;
        non_negative(self.ground_height_m, "trajectory.ground_height_m")
    }
}

/// Failsafe timings and limits.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "serde", serde(default, deny_unknown_fields))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FailsafeParams {
    /// No accepted vision fix for this long: hold attitude and altitude on the IMU (and flow) (s).
    pub vision_hold_after_s: f32,
    /// Still no fix this long after the hold began: land (s).
    pub vision_land_after_s: f32,
    /// No message from the ground station for this long: land (s). Before that the vehicle holds as when
    /// vision is lost (the fixes and the flow come over the link), and goes on when the link returns.
    pub link_land_after_s: f32,
    /// No IMU sample for this long: motors off (s).
    pub imu_timeout_s: f32,
    /// Arming is refused when the vehicle is tilted more than this (rad).
    pub max_arming_tilt_rad: f32,
    /// Tilt at which the vehicle is considered lost: motors off (rad).
    pub crash_tilt_rad: f32,
    /// Land detector: the thrust demand below this fraction of the weight...
    pub land_thrust_fraction: f32,
    /// ... the specific force's magnitude within this of gravity (m/s^2)...
    pub land_accel_tolerance_m_s2: f32,
    /// ... and the angular rate below this (rad/s)...
    pub land_rate_tolerance_rad_s: f32,
    /// ... for this long: landed, motors off (s).
    pub land_detect_s: f32,
    /// Landing: once the floor carries the vehicle, the thrust is wound down to idle over this time (s).
    pub ground_contact_ramp_s: f32,
}

impl Default for FailsafeParams {
    fn default() -> Self {
        Self {
            vision_hold_after_s: 0.5,
            vision_land_after_s: 3.0,
            link_land_after_s: 3.0,
            imu_timeout_s: 0.05,
            max_arming_tilt_rad: 0.15,
            crash_tilt_rad: 1.2,
            land_thrust_fraction: 0.3,
            land_accel_tolerance_m_s2: 1.0,
            land_rate_tolerance_rad_s: 0.3,
            land_detect_s: 0.5,
            ground_contact_ramp_s: 1.0,
        }
    }
}

impl FailsafeParams {
    fn validate(&self) -> Result<(), ParamError> {
        positive(self.vision_hold_after_s, "failsafe.vision_hold_after_s")?;
        positive(self.vision_land_after_s, "failsafe.vision_land_after_s")?;
        positive(self.link_land_after_s, "failsafe.link_land_after_s")?;
        positive(self.imu_timeout_s, "failsafe.imu_timeout_s")?;
        check(
            self.max_arming_tilt_rad > 0.0 && self.max_arming_tilt_rad < 0.5,
            "failsafe.max_arming_tilt_rad",
            "must lie in (0, 0.5) rad",
        )?;
        check(
            self.crash_tilt_rad > 0.5 && self.crash_tilt_rad < 3.0,
            "failsafe.crash_tilt_rad",
            "must lie in (0.5, 3) rad",
        )?;
        check(
            self.land_thrust_fraction > 0.0 && self.land_thrust_fraction < 0.9,
            "failsafe.land_thrust_fraction",
            "must lie in (0, 0.9)",
        )?;
        check(
            self.land_accel_tolerance_m_s2 > 0.0 && self.land_accel_tolerance_m_s2 < 5.0,
            "failsafe.land_accel_tolerance_m_s2",
            "must lie in (0, 5) m/s^2",
        )?;
        check(
            self.land_rate_tolerance_rad_s > 0.0 && self.land_rate_tolerance_rad_s < 3.0,
            "failsafe.land_rate_tolerance_rad_s",
            "must lie in (0, 3) rad/s",
        )?;
        check(
            self.land_detect_s > 0.0 && self.land_detect_s <= 5.0,
            "failsafe.land_detect_s",
            "must lie in (0, 5] s",
        )?;
        check(
            self.ground_contact_ramp_s > 0.0 && self.ground_contact_ramp_s <= 5.0,
            "failsafe.ground_contact_ramp_s",
            "must lie in (0, 5] s",
        )
    }
}

/// Everything the flight code needs.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FlightParams {
    /// Airframe and motors.
    pub vehicle: VehicleParams,
    /// Control laws.
    pub gains: ControlGains,
    /// State estimator.
    pub estimator: EstimatorParams,
    /// Mission.
    pub trajectory: TrajectoryParams,
    /// Failsafes.
    pub failsafe: FailsafeParams,
    /// Where the vehicle waits on the ground before take-off, world frame (m): the estimator's position
    /// until the first vision fix.
    pub home_m: [f32; 3],
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
        check(self.home_m.iter().all(|v| v.is_finite()), "home_m", "must be finite")
    }
}

/// A parameter that can be read and changed over the radio link (one `f32` each; counts are rounded).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
pub enum ParamId {
    /// `trajectory.y_d_m`.
    TrajectoryYd,
    /// `trajectory.z_d_m`.
    TrajectoryZd,
    /// `trajectory.x_range_m[0]`.
    TrajectoryXStart,
    /// `trajectory.x_range_m[1]`.
    TrajectoryXEnd,
    /// `trajectory.speed_m_s`.
    TrajectorySpeed,
    /// `trajectory.accel_m_s2`.
    TrajectoryAccel,
    /// `trajectory.sweeps`.
    TrajectorySweeps,
    /// `trajectory.yaw_d_rad`.
    TrajectoryYaw,
    /// `gains.altitude.a_z1`.
    AltitudeAz1,
    /// `gains.altitude.a_z2`.
    AltitudeAz2,
    /// `gains.altitude.integral_gain`.
    AltitudeIntegral,
    /// `gains.yaw.a_psi1`.
    YawApsi1,
    /// `gains.yaw.a_psi2`.
    YawApsi2,
    /// `gains.roll.k[0..4]` (k1..k4).
    RollK1,
    /// k2.
    RollK2,
    /// k3.
    RollK3,
    /// k4.
    RollK4,
    /// `gains.roll.b[0..4]` (b1..b4).
    RollB1,
    /// b2.
    RollB2,
    /// b3.
    RollB3,
    /// b4.
    RollB4,
    /// `gains.roll.trim_gain`.
    RollTrim,
    /// `gains.pitch.k[0..4]`.
    PitchK1,
    /// k2.
    PitchK2,
    /// k3.
    PitchK3,
    /// k4.
    PitchK4,
    /// `gains.pitch.b[0..4]`.
    PitchB1,
    /// b2.
    PitchB2,
    /// b3.
    PitchB3,
    /// b4.
    PitchB4,
    /// `gains.pitch.trim_gain`.
    PitchTrim,
    /// `failsafe.vision_hold_after_s`.
    VisionHoldAfter,
    /// `failsafe.vision_land_after_s`.
    VisionLandAfter,
    /// `failsafe.link_land_after_s`.
    LinkLandAfter,
    /// `vehicle.mass_kg`.
    Mass,
}

impl ParamId {
    /// Every parameter, in wire order.
    pub const ALL: [ParamId; 35] = [
        ParamId::TrajectoryYd,
        ParamId::TrajectoryZd,
        ParamId::TrajectoryXStart,
        ParamId::TrajectoryXEnd,
        ParamId::TrajectorySpeed,
        ParamId::TrajectoryAccel,
        ParamId::TrajectorySweeps,
        ParamId::TrajectoryYaw,
        ParamId::AltitudeAz1,
        ParamId::AltitudeAz2,
        ParamId::AltitudeIntegral,
        ParamId::YawApsi1,
        ParamId::YawApsi2,
        ParamId::RollK1,
        ParamId::RollK2,
        ParamId::RollK3,
        ParamId::RollK4,
        ParamId::RollB1,
        ParamId::RollB2,
        ParamId::RollB3,
        ParamId::RollB4,
        ParamId::RollTrim,
        ParamId::PitchK1,
        ParamId::PitchK2,
        ParamId::PitchK3,
        ParamId::PitchK4,
        ParamId::PitchB1,
        ParamId::PitchB2,
        ParamId::PitchB3,
        ParamId::PitchB4,
        ParamId::PitchTrim,
        ParamId::VisionHoldAfter,
        ParamId::VisionLandAfter,
        ParamId::LinkLandAfter,
        ParamId::Mass,
    ];

    /// The field's dotted name, as in scenario files.
    pub fn name(self) -> &'static str {
        match self {
            ParamId::TrajectoryYd => "trajectory.y_d_m",
            ParamId::TrajectoryZd => "trajectory.z_d_m",
            ParamId::TrajectoryXStart => "trajectory.x_range_m[0]",
            ParamId::TrajectoryXEnd => "trajectory.x_range_m[1]",
            ParamId::TrajectorySpeed => "trajectory.speed_m_s",
            ParamId::TrajectoryAccel => "trajectory.accel_m_s2",
            ParamId::TrajectorySweeps => "trajectory.sweeps",
            ParamId::TrajectoryYaw => "trajectory.yaw_d_rad",
            ParamId::AltitudeAz1 => "gains.altitude.a_z1",
            ParamId::AltitudeAz2 => "gains.altitude.a_z2",
            ParamId::AltitudeIntegral => "gains.altitude.integral_gain",
            ParamId::YawApsi1 => "gains.yaw.a_psi1",
            ParamId::YawApsi2 => "gains.yaw.a_psi2",
            ParamId::RollK1 => "gains.roll.k[0]",
            ParamId::RollK2 => "gains.roll.k[1]",
            ParamId::RollK3 => "gains.roll.k[2]",
            ParamId::RollK4 => "gains.roll.k[3]",
            ParamId::RollB1 => "gains.roll.b[0]",
            ParamId::RollB2 => "gains.roll.b[1]",
            ParamId::RollB3 => "gains.roll.b[2]",
            ParamId::RollB4 => "gains.roll.b[3]",
            ParamId::RollTrim => "gains.roll.trim_gain",
            ParamId::PitchK1 => "gains.pitch.k[0]",
            ParamId::PitchK2 => "gains.pitch.k[1]",
            ParamId::PitchK3 => "gains.pitch.k[2]",
            ParamId::PitchK4 => "gains.pitch.k[3]",
            ParamId::PitchB1 => "gains.pitch.b[0]",
            ParamId::PitchB2 => "gains.pitch.b[1]",
            ParamId::PitchB3 => "gains.pitch.b[2]",
            ParamId::PitchB4 => "gains.pitch.b[3]",
            ParamId::PitchTrim => "gains.pitch.trim_gain",
            ParamId::VisionHoldAfter => "failsafe.vision_hold_after_s",
            ParamId::VisionLandAfter => "failsafe.vision_land_after_s",
            ParamId::LinkLandAfter => "failsafe.link_land_after_s",
            ParamId::Mass => "vehicle.mass_kg",
        }
    }

    /// The parameter with a dotted name.
    pub fn from_name(name: &str) -> Option<ParamId> {
        ParamId::ALL.iter().copied().find(|p| p.name() == name)
    }

    /// The field behind a real-valued parameter (`None` for the count `sweeps`).
    fn slot(self, p: &mut FlightParams) -> Option<&mut f32> {
        let g = &mut p.gains;
        Some(match self {
            ParamId::TrajectoryYd => &mut p.trajectory.y_d_m,
            ParamId::TrajectoryZd => &mut p.trajectory.z_d_m,
            ParamId::TrajectoryXStart => &mut p.trajectory.x_range_m[0],
            ParamId::TrajectoryXEnd => &mut p.trajectory.x_range_m[1],
            ParamId::TrajectorySpeed => &mut p.trajectory.speed_m_s,
            ParamId::TrajectoryAccel => &mut p.trajectory.accel_m_s2,
            ParamId::TrajectorySweeps => return None,
            ParamId::TrajectoryYaw => &mut p.trajectory.yaw_d_rad,
            ParamId::AltitudeAz1 => &mut g.altitude.a_z1,
            ParamId::AltitudeAz2 => &mut g.altitude.a_z2,
            ParamId::AltitudeIntegral => &mut g.altitude.integral_gain,
            ParamId::YawApsi1 => &mut g.yaw.a_psi1,
            ParamId::YawApsi2 => &mut g.yaw.a_psi2,
            ParamId::RollK1 => &mut g.roll.k[0],
            ParamId::RollK2 => &mut g.roll.k[1],
            ParamId::RollK3 => &mut g.roll.k[2],
            ParamId::RollK4 => &mut g.roll.k[3],
            ParamId::RollB1 => &mut g.roll.b[0],
            ParamId::RollB2 => &mut g.roll.b[1],
            ParamId::RollB3 => &mut g.roll.b[2],
            ParamId::RollB4 => &mut g.roll.b[3],
            ParamId::RollTrim => &mut g.roll.trim_gain,
            ParamId::PitchK1 => &mut g.pitch.k[0],
            ParamId::PitchK2 => &mut g.pitch.k[1],
            ParamId::PitchK3 => &mut g.pitch.k[2],
            ParamId::PitchK4 => &mut g.pitch.k[3],
            ParamId::PitchB1 => &mut g.pitch.b[0],
            ParamId::PitchB2 => &mut g.pitch.b[1],
            ParamId::PitchB3 => &mut g.pitch.b[2],
            ParamId::PitchB4 => &mut g.pitch.b[3],
            ParamId::PitchTrim => &mut g.pitch.trim_gain,
            ParamId::VisionHoldAfter => &mut p.failsafe.vision_hold_after_s,
            ParamId::VisionLandAfter => &mut p.failsafe.vision_land_after_s,
            ParamId::LinkLandAfter => &mut p.failsafe.link_land_after_s,
            ParamId::Mass => &mut p.vehicle.mass_kg,
        })
    }
}

impl FlightParams {
    /// A parameter's value.
    pub fn get(&self, id: ParamId) -> f32 {
        let mut copy = *self;
        match id.slot(&mut copy) {
            Some(v) => *v,
            None => self.trajectory.sweeps as f32,
        }
    }

    /// A copy with one parameter changed, validated as a whole; the error names the offending field.
    pub fn with(&self, id: ParamId, value: f32) -> Result<FlightParams, ParamError> {
        let mut p = *self;
        if !value.is_finite() {
            return Err(ParamError { field: id.name(), problem: "must be finite" });
        }
        match id.slot(&mut p) {
            Some(v) => *v = value,
            None => {
                if !(0.0..=100.0).contains(&value) {
                    return Err(ParamError { field: id.name(), problem: "must lie in 0..=100" });
                }
                p.trajectory.sweeps = (value + 0.5) as u8;
            }
        }
        p.validate()?;
        Ok(p)
    }
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
