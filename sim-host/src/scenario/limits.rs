//! The simulator's values, each with its physical range declared once, here: the scenario's validation checks
//! every number of the scenario against its declaration (the error names the field and states the range), and
//! the command-line options that override a scenario value (`render --blur`, `--noise`, `--light-gain`,
//! `--exposure-time`, `fly --duration`) go through the same validation, so one quantity has one limit.
//! The flight code's parameters (`[vehicle]`, `[gains]`, `[estimator]`, `[trajectory]`, `[failsafe]`, `[downlink]`,
//! `[rc]`, `[battery]`) are
//! declared in control-core (`control_core::declare`, docs/parameters.md); these are the simulator's own.
//! `sim-host params` prints both tables.
//!
//! Relations between values (a latency plus a frame interval within the gyro history, a rate that divides the
//! physics rate, one end of the line after the other) are checked after the ranges, in `validate.rs`.
use anyhow::{Result, bail};

/// A declared range of a simulator value.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Limit {
    /// Dotted name, as in scenario files (`forward_camera.fx_px`; `faults.imu_spike.rate_hz` for a fault's).
    pub name: &'static str,
    /// Lower bound.
    pub lo: f64,
    /// Whether the lower bound itself is excluded.
    pub lo_open: bool,
    /// Upper bound.
    pub hi: f64,
    /// Unit (empty for counts and ratios).
    pub unit: &'static str,
}

impl Limit {
    /// Whether `v` is finite and within the range.
    pub fn contains(&self, v: f64) -> bool {
        v.is_finite() && (if self.lo_open { v > self.lo } else { v >= self.lo }) && v <= self.hi
    }

    /// The range as a refusal states it: `must lie in (0, 10000] px`.
    pub fn problem(&self) -> String {
        let open = if self.lo_open { "(" } else { "[" };
        let unit = if self.unit.is_empty() { String::new() } else { format!(" {}", self.unit) };
        format!("must lie in {open}{}, {}]{unit}", self.lo, self.hi)
    }

    /// Checks every value of a field; the error names `field` (the declared name, or an indexed one such as
    /// `faults[2] (imu_spike).rate_hz`) and states the range.
    pub fn check_as(&self, field: &str, values: &[f64]) -> Result<()> {
        match values.iter().find(|v| !self.contains(**v)) {
            Some(v) => bail!("invalid value of `{field}`: {} (got {v})", self.problem()),
            None => Ok(()),
        }
    }

    /// [`Limit::check_as`] under the declared name.
    pub fn check(&self, values: &[f64]) -> Result<()> {
        self.check_as(self.name, values)
    }
}

macro_rules! limits {
    ($($(#[doc = $doc:literal])* $id:ident = $name:literal $kind:ident [$lo:expr, $hi:expr] $unit:literal;)*) => {
        $(
            #[doc = concat!("The range of `", $name, "`.")]
            $(#[doc = $doc])*
            pub const $id: Limit = Limit {
                name: $name,
                lo: $lo as f64,
                lo_open: limits!(@open $kind),
                hi: $hi as f64,
                unit: $unit,
            };
        )*
        /// Every declared limit.
        pub const ALL: &[Limit] = &[$($id),*];
    };
    (@open closed) => { false };
    (@open above) => { true };
}

/// Largest image dimension of the forward camera (the detector's buffers).
const FWD_DIM: usize = vision_core::detect::MAX_DETECT_DIM;
const DOWN_W: usize = vision_core::flow::FLOW_MAX_W;
const DOWN_H: usize = vision_core::flow::FLOW_MAX_H;
/// The forward camera's largest Gaussian blur (px).
pub const FORWARD_BLUR_MAX_PX: f64 = 5.0;
/// The downward camera's largest Gaussian blur (px): the flow's image pyramid assumes a sharp image.
pub const DOWN_BLUR_MAX_PX: f64 = 1.0;
/// The longest scheduled time of a fault (s): beyond any run.
const FAULT_TIME_MAX_S: f64 = 1e6;

limits! {
    SCENE_LINE_X_START = "scene.line_x_start_m" closed [-100, 100] "m";
    SCENE_LINE_X_END = "scene.line_x_end_m" closed [-100, 100] "m";
    SCENE_LINE_Z_BOTTOM = "scene.line_z_bottom_m" closed [0, 20] "m";
    SCENE_LINE_Z_TOP = "scene.line_z_top_m" closed [0, 20] "m";
    SCENE_LINE_ALBEDO = "scene.line_albedo_rgb" closed [0, 1] "";
    SCENE_WALL_ALBEDO = "scene.wall_albedo_rgb" closed [0, 1] "";
    SCENE_FLOOR_ALBEDO = "scene.floor_albedo_rgb" closed [0, 1] "";
    SCENE_WALL_TEXTURE_CONTRAST = "scene.wall_texture_contrast" closed [0, 1] "";
    SCENE_FLOOR_TEXTURE_CONTRAST = "scene.floor_texture_contrast" closed [0, 1] "";
    /// Illumination gain (1 is the paper's lighting; 1.45 and above clip a white wall).
    SCENE_LIGHT_GAIN = "scene.light_gain" above [0, 10] "";
    SCENE_LIGHT_GRADIENT = "scene.light_gradient_per_m" closed [-5, 5] "1/m";
    SCENE_SHAPE_POINTS = "scene.shapes.points_m" closed [-100, 100] "m";
    SCENE_SHAPE_CENTER = "scene.shapes.center_m" closed [-100, 100] "m";
    SCENE_SHAPE_RADIUS = "scene.shapes.radius_m" above [0, 100] "m";
    SCENE_SHAPE_ALBEDO = "scene.shapes.albedo_rgb" closed [0, 1] "";

    FORWARD_WIDTH = "forward_camera.width_px" closed [16, FWD_DIM] "px";
    FORWARD_HEIGHT = "forward_camera.height_px" closed [16, FWD_DIM] "px";
    FORWARD_FX = "forward_camera.fx_px" above [0, 10000] "px";
    FORWARD_FY = "forward_camera.fy_px" above [0, 10000] "px";
    FORWARD_CX = "forward_camera.cx_px" closed [0, FWD_DIM] "px";
    FORWARD_CY = "forward_camera.cy_px" closed [0, FWD_DIM] "px";
    /// k1, k2, p1, p2, k3 of the Brown-Conrady model.
    FORWARD_DISTORTION = "forward_camera.distortion" closed [-5, 5] "";
    FORWARD_MOUNT_OFFSET = "forward_camera.mount_offset_body_m" closed [-0.5, 0.5] "m";
    FORWARD_MOUNT_ROTATION = "forward_camera.mount_rotation_deg" closed [-45, 45] "deg";
    FORWARD_NOISE = "forward_camera.noise_sigma" closed [0, 64] "grey levels";
    FORWARD_BLUR = "forward_camera.blur_sigma_px" closed [0, FORWARD_BLUR_MAX_PX] "px";
    FORWARD_EXPOSURE = "forward_camera.exposure" above [0, 10] "";
    /// Auto exposure: each frame's exposure is the configured one times a factor within 1 +- this.
    FORWARD_EXPOSURE_STEP = "forward_camera.exposure_step" closed [0, 0.5] "";
    /// Light at the image corners relative to the centre is 1 minus this (quadratic fall-off).
    FORWARD_VIGNETTING = "forward_camera.vignetting" closed [0, 0.9] "";
    /// MJPEG as webcams send it (4:2:2 chroma); 0: uncompressed.
    FORWARD_JPEG_QUALITY = "forward_camera.jpeg_quality" closed [0, 100] "";
    /// Motion blur: the frame integrates the views over this time.
    FORWARD_EXPOSURE_TIME = "forward_camera.exposure_time_s" closed [0, 0.05] "s";
    /// Rolling shutter: the delay between consecutive rows' exposures.
    FORWARD_LINE_DELAY = "forward_camera.line_delay_s" closed [0, 0.0001] "s";
    FORWARD_RATE = "forward_camera.rate_hz" above [0, 200] "Hz";
    /// The estimator keeps 0.25 s of history.
    FORWARD_LATENCY = "forward_camera.latency_s" closed [0, 0.2] "s";
    FORWARD_LATENCY_JITTER = "forward_camera.latency_jitter_s" closed [0, 0.2] "s";
    FORWARD_ANALYTIC_NOISE = "forward_camera.analytic_noise_px" closed [0, 10] "px";

    DOWN_WIDTH = "down_camera.width_px" closed [32, DOWN_W] "px";
    DOWN_HEIGHT = "down_camera.height_px" closed [32, DOWN_H] "px";
    DOWN_FX = "down_camera.fx_px" above [0, 10000] "px";
    DOWN_FY = "down_camera.fy_px" above [0, 10000] "px";
    DOWN_CX = "down_camera.cx_px" closed [0, DOWN_W] "px";
    DOWN_CY = "down_camera.cy_px" closed [0, DOWN_H] "px";
    DOWN_MOUNT_OFFSET = "down_camera.mount_offset_body_m" closed [-0.5, 0.5] "m";
    DOWN_MOUNT_ROTATION = "down_camera.mount_rotation_deg" closed [-30, 30] "deg";
    DOWN_RATE = "down_camera.rate_hz" closed [10, 400] "Hz";
    /// With the frame interval, within the flight code's 0.128 s of gyro history.
    DOWN_LATENCY = "down_camera.latency_s" closed [0, 0.12] "s";
    /// At most one frame interval.
    DOWN_EXPOSURE_TIME = "down_camera.exposure_time_s" closed [0, 0.1] "s";
    DOWN_EXPOSURE = "down_camera.exposure" above [0, 10] "";
    DOWN_NOISE = "down_camera.noise_sigma" closed [0, 64] "grey levels";
    DOWN_BLUR = "down_camera.blur_sigma_px" closed [0, DOWN_BLUR_MAX_PX] "px";
    DOWN_VIGNETTING = "down_camera.vignetting" closed [0, 0.9] "";

    /// At least one physics step (RK4 resolves the motors' decay).
    MODEL_MOTOR_TAU = "model.motor_time_constant_s" closed [1e-3, 1] "s";
    MODEL_LINEAR_DRAG = "model.linear_drag_n_s_per_m" closed [0, 10] "N s/m";
    MODEL_ROTOR_DRAG = "model.rotor_drag_coeff" closed [0, 1e-3] "N s^2/(m rad)";
    MODEL_GROUND_EFFECT_RADIUS = "model.ground_effect_rotor_radius_m" closed [0, 0.5] "m";
    MODEL_PHYSICS_STEP = "model.physics_step_s" closed [1e-5, 1e-3] "s";
    /// And at least 0.2 m from the wall (y).
    MODEL_START_POSITION = "model.start_position_m" closed [-100, 100] "m";
    MODEL_START_YAW = "model.start_yaw_deg" closed [-45, 45] "deg";

    /// A whole number of physics steps.
    IMU_RATE = "imu.rate_hz" closed [50, 100000] "Hz";
    IMU_GYRO_NOISE = "imu.gyro_noise_density" closed [0, 0.1] "rad/s/sqrt(Hz)";
    IMU_ACCEL_NOISE = "imu.accel_noise_density" closed [0, 2] "m/s^2/sqrt(Hz)";
    IMU_GYRO_BIAS = "imu.gyro_bias_sigma_rad_s" closed [0, 0.5] "rad/s";
    IMU_ACCEL_BIAS = "imu.accel_bias_sigma_m_s2" closed [0, 2] "m/s^2";
    /// At most the IMU's rate.
    IMU_MAG_RATE = "imu.mag_rate_hz" above [0, 1000] "Hz";
    IMU_MAG_NOISE = "imu.mag_noise_rel" closed [0, 1] "";
    /// Earth's field is 0.25-0.65 gauss; not all zero.
    IMU_MAG_FIELD = "imu.mag_field_world" closed [-2, 2] "gauss";
    IMU_VIBRATION_ACCEL = "imu.vibration_accel_m_s2" closed [0, 20] "m/s^2";
    IMU_VIBRATION_GYRO = "imu.vibration_gyro_rad_s" closed [0, 2] "rad/s";
    IMU_ACCEL_RANGE = "imu.accel_range_m_s2" closed [20, 1000] "m/s^2";
    IMU_GYRO_RANGE = "imu.gyro_range_rad_s" closed [1, 100] "rad/s";
    /// 0 (off), or from 5 Hz to half the IMU's rate.
    IMU_DLPF = "imu.dlpf_hz" closed [0, 50000] "Hz";
    /// 0 (none), or at most the IMU's rate.
    IMU_BARO_RATE = "imu.baro_rate_hz" closed [0, 1000] "Hz";
    IMU_BARO_NOISE = "imu.baro_noise_m" closed [0, 10] "m";
    /// From the Dead Sea to the highest airfields.
    IMU_BARO_OFFSET = "imu.baro_offset_m" closed [-500, 9000] "m";
    IMU_BARO_DRIFT = "imu.baro_drift_m_per_sqrt_s" closed [0, 1] "m/sqrt(s)";

    LINK_LATENCY = "link.latency_s" closed [0, 0.5] "s";
    LINK_HEARTBEAT = "link.heartbeat_hz" above [0, 1000] "Hz";

    /// A whole number of physics steps, at most the IMU's rate, at least a fifth of it.
    MISSION_CONTROL_RATE = "mission.control_rate_hz" closed [100, 100000] "Hz";
    MISSION_ARM_AT = "mission.arm_at_s" closed [0, 3600] "s";
    /// Not before the arming.
    MISSION_TAKEOFF_AT = "mission.takeoff_at_s" closed [0, 3600] "s";
    MISSION_TRACK_AFTER_HOVER = "mission.track_after_hover_s" closed [0, 3600] "s";
    /// Also the limit of `fly --duration`.
    MISSION_MAX_DURATION = "mission.max_duration_s" above [0, 3600] "s";

    MISMATCH_MASS = "mismatch.mass_scale" closed [0.2, 5] "";
    MISMATCH_INERTIA = "mismatch.inertia_scale" closed [0.2, 5] "";
    MISMATCH_THRUST = "mismatch.thrust_coeff_scale" closed [0.2, 5] "";
    MISMATCH_DRAG_TORQUE = "mismatch.drag_torque_coeff_scale" closed [0.2, 5] "";
    MISMATCH_MOTOR_TAU = "mismatch.motor_time_constant_scale" closed [0.2, 5] "";
    MISMATCH_FORWARD_MOUNT = "mismatch.forward_camera_mount_error_deg" closed [-20, 20] "deg";
    MISMATCH_IMU = "mismatch.imu_misalignment_deg" closed [-20, 20] "deg";

    WIND_MEAN = "wind.mean_m_s" closed [-15, 15] "m/s";
    WIND_TURBULENCE = "wind.turbulence_sigma_m_s" closed [0, 5] "m/s";
    /// Checked when there is turbulence.
    WIND_TURBULENCE_LENGTH = "wind.turbulence_length_m" closed [0.1, 1000] "m";
    WIND_GUST_START = "wind.gusts.start_s" closed [0, 3600] "s";
    WIND_GUST_DURATION = "wind.gusts.duration_s" above [0, 3600] "s";
    WIND_GUST_VELOCITY = "wind.gusts.velocity_m_s" closed [-15, 15] "m/s";

    FAULT_START = "faults.start_s" closed [0, FAULT_TIME_MAX_S] "s";
    FAULT_DURATION = "faults.duration_s" above [0, FAULT_TIME_MAX_S] "s";
    FAULT_BYTE_ERROR_RATE = "faults.link_corruption.byte_error_rate" closed [0, 1] "";
    FAULT_SPIKE_RATE = "faults.imu_spike.rate_hz" closed [0, 1000] "Hz";
    FAULT_SPIKE_ACCEL = "faults.imu_spike.accel_m_s2" closed [0, 500] "m/s^2";
    FAULT_SPIKE_GYRO = "faults.imu_spike.gyro_rad_s" closed [0, 50] "rad/s";
    FAULT_BIAS_STEP_GYRO = "faults.imu_bias_step.gyro_rad_s" closed [-1, 1] "rad/s";
    FAULT_BIAS_STEP_ACCEL = "faults.imu_bias_step.accel_m_s2" closed [-5, 5] "m/s^2";
    FAULT_GYRO_SATURATION = "faults.gyro_saturation.limit_rad_s" above [0, 100] "rad/s";
    FAULT_MAG_HEADING = "faults.mag_disturbance.heading_offset_deg" closed [-180, 180] "deg";
    FAULT_MAG_SCALE = "faults.mag_disturbance.field_scale" closed [0, 10] "";
    FAULT_DEGRADED_MOTOR = "faults.motor_degradation.motor" closed [1, 4] "";
    FAULT_DEGRADED_THRUST = "faults.motor_degradation.thrust_scale" closed [0, 1] "";
    FAULT_LOST_MOTOR = "faults.motor_loss.motor" closed [1, 4] "";

    BATTERY_MODEL_CELLS = "battery_model.cells" closed [1, 14] "";
    BATTERY_MODEL_CAPACITY = "battery_model.capacity_mah" above [0, 1e6] "mAh";
    BATTERY_MODEL_RESISTANCE = "battery_model.resistance_ohm" closed [0, 1] "ohm";
    BATTERY_MODEL_EFFICIENCY = "battery_model.drive_efficiency" above [0, 1] "";
    BATTERY_MODEL_IDLE_CURRENT = "battery_model.idle_current_a" closed [0, 50] "A";
    BATTERY_MODEL_CHARGE = "battery_model.initial_charge" closed [0, 1] "";
    BATTERY_MODEL_RATE = "battery_model.rate_hz" closed [1, 1000] "Hz";
    BATTERY_MODEL_VOLTAGE_NOISE = "battery_model.voltage_noise_v" closed [0, 5] "V";
    BATTERY_MODEL_CURRENT_NOISE = "battery_model.current_noise_a" closed [0, 50] "A";

    TRANSMITTER_FRAME_RATE = "transmitter.frame_rate_hz" closed [10, 1000] "Hz";
    TRANSMITTER_AT = "transmitter.script.at_s" closed [0, FAULT_TIME_MAX_S] "s";
    TRANSMITTER_ROLL = "transmitter.script.roll" closed [-1, 1] "";
    TRANSMITTER_PITCH = "transmitter.script.pitch" closed [-1, 1] "";
    TRANSMITTER_YAW = "transmitter.script.yaw" closed [-1, 1] "";
    TRANSMITTER_THROTTLE = "transmitter.script.throttle" closed [0, 1] "";
}

/// Scenario values with no range, and why.
pub const UNRANGED: &[(&str, &str)] = &[("scene.texture_seed", "any 64-bit seed")];

/// The limits as a Markdown table (for docs/parameters.md).
pub fn markdown_table() -> String {
    let mut s = String::from("| value | range | unit |\n|---|---|---|\n");
    for l in ALL {
        let open = if l.lo_open { "(" } else { "[" };
        let unit = if l.unit.is_empty() { "-" } else { l.unit };
        s.push_str(&format!("| `{}` | {open}{}, {}] | {unit} |\n", l.name, l.lo, l.hi));
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scenario::{FaultConfig, FaultKind, GustConfig, Scenario, WallShape};

    /// The paper scenario with one of every list entry: shapes, a gust, every kind of fault, turbulence.
    fn full() -> Scenario {
        let mut s = Scenario::paper();
        s.scene.shapes = vec![
            WallShape::Polygon {
                points_m: vec![[3.0, 0.5], [3.5, 0.5], [3.2, 0.9]],
                albedo_rgb: [0.1, 0.2, 0.3],
            },
            WallShape::Disc { center_m: [4.0, 1.0], radius_m: 0.1, albedo_rgb: [0.5; 3] },
        ];
        s.wind.turbulence_sigma_m_s = 0.5;
        s.wind.turbulence_length_m = 5.0;
        s.wind.gusts = vec![GustConfig { start_s: 5.0, duration_s: 2.0, velocity_m_s: [1.0, 0.0, 0.0] }];
        let kinds = [
            FaultKind::VisionDropout,
            FaultKind::LinkCorruption { byte_error_rate: 0.01 },
            FaultKind::ImuSpike { rate_hz: 2.0, accel_m_s2: 20.0, gyro_rad_s: 1.0 },
            FaultKind::ImuBiasStep { gyro_rad_s: [0.01, 0.0, 0.0], accel_m_s2: [0.1, 0.0, 0.0] },
            FaultKind::GyroSaturation { limit_rad_s: 5.0 },
            FaultKind::MagDisturbance { heading_offset_deg: 10.0, field_scale: 1.2 },
            FaultKind::MotorDegradation { motor: 2, thrust_scale: 0.8 },
            FaultKind::MotorLoss { motor: 3 },
        ];
        s.faults =
            kinds.into_iter().map(|kind| FaultConfig { start_s: 10.0, duration_s: 1.0, kind }).collect();
        s.transmitter.enabled = true;
        s.transmitter.script = vec![crate::transmitter::TxEvent {
            at_s: 1.0,
            arm: Some(true),
            mode: Some(crate::transmitter::TxMode::Auto),
            kill: Some(false),
            roll: Some(0.1),
            pitch: Some(-0.1),
            yaw: Some(0.2),
            throttle: Some(0.6),
        }];
        s.validate().expect("the full scenario is valid");
        s
    }

    /// Sections that hold the flight code's parameters, declared in control-core.
    const FLIGHT_SECTIONS: &[&str] =
        &["vehicle", "gains", "estimator", "trajectory", "failsafe", "downlink", "rc", "battery"];

    /// A numeric leaf of the scenario's TOML: its path (keys and indices) and its declared name.
    struct Leaf {
        path: Vec<toml::Value>,
        name: String,
    }

    fn leaves(v: &toml::Value, path: &mut Vec<toml::Value>, name: &str, out: &mut Vec<Leaf>) {
        match v {
            toml::Value::Table(t) => {
                for (k, child) in t {
                    if path.is_empty() && FLIGHT_SECTIONS.contains(&k.as_str()) {
                        continue;
                    }
                    path.push(toml::Value::String(k.clone()));
                    let child_name = if name.is_empty() { k.clone() } else { format!("{name}.{k}") };
                    leaves(child, path, &child_name, out);
                    path.pop();
                }
            }
            toml::Value::Array(a) => {
                let numeric = a.iter().all(|x| x.is_float() || x.is_integer() || x.is_array());
                if numeric && !a.is_empty() && !a.iter().any(|x| x.is_table()) {
                    out.push(Leaf { path: path.clone(), name: name.to_string() });
                    return;
                }
                for (i, child) in a.iter().enumerate() {
                    path.push(toml::Value::Integer(i as i64));
                    // A fault's own values are declared under its kind.
                    let kind = child.get("kind").and_then(|k| k.as_str());
                    let child_name = match kind {
                        Some(kind) if name == "faults" => format!("faults.{kind}"),
                        _ => name.to_string(),
                    };
                    leaves(child, path, &child_name, out);
                    path.pop();
                }
            }
            toml::Value::Float(_) | toml::Value::Integer(_) => {
                // A fault's start and duration are common to every kind.
                let name = match name.strip_prefix("faults.") {
                    Some(rest) if rest.ends_with(".start_s") || rest.ends_with(".duration_s") => {
                        format!("faults.{}", rest.rsplit('.').next().unwrap_or_default())
                    }
                    _ => name.to_string(),
                };
                out.push(Leaf { path: path.clone(), name });
            }
            _ => {}
        }
    }

    fn toml_of(s: &Scenario) -> toml::Value {
        toml::Value::try_from(s).expect("a scenario serialises")
    }

    fn leaf_mut<'a>(v: &'a mut toml::Value, path: &[toml::Value]) -> &'a mut toml::Value {
        path.iter().fold(v, |v, key| match key {
            toml::Value::String(k) => v.get_mut(k.as_str()).expect("key"),
            toml::Value::Integer(i) => v.get_mut(*i as usize).expect("index"),
            _ => unreachable!(),
        })
    }

    /// The first number of a value (an array's first element, in depth).
    fn first_number(v: &mut toml::Value) -> &mut toml::Value {
        match v {
            toml::Value::Array(a) => first_number(&mut a[0]),
            v => v,
        }
    }

    #[test]
    fn every_number_of_a_scenario_is_declared_and_every_declaration_is_checked() {
        let s = full();
        let mut out = Vec::new();
        leaves(&toml_of(&s), &mut Vec::new(), "", &mut out);
        let declared: Vec<&str> = ALL.iter().map(|l| l.name).collect();
        let unranged: Vec<&str> = UNRANGED.iter().map(|(n, _)| *n).collect();
        let missing: Vec<&str> = out
            .iter()
            .map(|l| l.name.as_str())
            .filter(|n| !declared.contains(n) && !unranged.contains(n))
            .collect();
        assert!(missing.is_empty(), "numbers without a declared range: {missing:?}");
        assert!(out.len() > 100, "{} numeric leaves", out.len());
        // Every declaration is checked by the validation (appears among the ranged values), and names a
        // value that exists.
        let checked: Vec<&str> = s.ranged_values().iter().map(|r| r.limit.name).collect();
        let leaf_names: Vec<&str> = out.iter().map(|l| l.name.as_str()).collect();
        for l in ALL {
            assert!(checked.contains(&l.name), "{} is declared but not checked", l.name);
            assert!(leaf_names.contains(&l.name), "{} names no value of a scenario", l.name);
        }
        let mut names = declared.clone();
        names.sort_unstable();
        names.dedup();
        assert_eq!(names.len(), ALL.len(), "a name is declared twice");
    }

    #[test]
    fn every_declared_range_refuses_a_value_just_outside_and_names_the_field() {
        let s = full();
        let base = toml_of(&s);
        let mut out = Vec::new();
        leaves(&base, &mut Vec::new(), "", &mut out);
        let mut refused = 0;
        for leaf in &out {
            let Some(limit) = ALL.iter().find(|l| l.name == leaf.name) else { continue };
            let integer = {
                let mut b = base.clone();
                let v = leaf_mut(&mut b, &leaf.path);
                first_number(v).is_integer()
            };
            let step = if integer { 1.0 } else { limit.lo.abs().max(limit.hi.abs()).max(1.0) * 1e-6 };
            let below = if limit.lo_open { limit.lo } else { limit.lo - step };
            for outside in [below, limit.hi + step, f64::NAN] {
                if integer && outside.is_nan() {
                    continue;
                }
                let mut b = base.clone();
                let v = leaf_mut(&mut b, &leaf.path);
                *first_number(v) =
                    if integer { toml::Value::Integer(outside as i64) } else { toml::Value::Float(outside) };
                let text = toml::to_string(&b).expect("serialise");
                let err = match Scenario::from_toml(&text) {
                    Ok(_) => panic!("{} = {outside} accepted ({})", leaf.name, limit.problem()),
                    Err(e) => format!("{e:#}"),
                };
                let field = leaf.name.rsplit('.').next().unwrap_or_default();
                assert!(
                    err.contains(field) && err.contains(&limit.problem()),
                    "{} = {outside}: {err}",
                    leaf.name
                );
                refused += 1;
            }
        }
        assert!(refused > 250, "{refused} refusals checked");
    }

    #[test]
    fn a_refusal_states_the_range_and_the_value() {
        assert_eq!(FORWARD_FX.problem(), "must lie in (0, 10000] px");
        assert_eq!(MISMATCH_MASS.problem(), "must lie in [0.2, 5]");
        let e = DOWN_BLUR.check(&[1.4]).unwrap_err().to_string();
        assert_eq!(e, "invalid value of `down_camera.blur_sigma_px`: must lie in [0, 1] px (got 1.4)");
        assert!(FORWARD_FX.check(&[0.0]).is_err() && FORWARD_FX.check(&[1e-9]).is_ok());
        assert!(DOWN_BLUR.check(&[0.0, 1.0]).is_ok() && DOWN_BLUR.check(&[0.5, f64::INFINITY]).is_err());
        assert!(markdown_table().lines().count() == ALL.len() + 2);
    }
}
