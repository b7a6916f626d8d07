//! Scenario files (TOML): vehicle, cameras, scene, gains, noise, latency, trajectory.
//!
//! Unknown fields are rejected and every value is checked when the file loads; errors name the field.
use anyhow::{Context, Result, bail};
use control_core::params::{
    ControlGains, DownlinkParams, EstimatorParams, FailsafeParams, FlightParams, RcParams, TrajectoryParams,
    VehicleParams,
};
use flight_core::flow::FlowConfig;
use flight_core::{FlightConfig, VisionConfig};
use geometry::frames::{BODY_FROM_DOWN_CAMERA, BODY_FROM_FORWARD_CAMERA};
use geometry::{Mat3, Vec3};
use serde::{Deserialize, Serialize};
use std::path::Path;
use vision_core::{CameraModel, CameraMount, Distortion, LineTarget};

/// The built-in scenarios: `(name, TOML text)`.
pub const BUILT_IN: &[(&str, &str)] = &[
    ("paper", include_str!("../../scenarios/paper.toml")),
    ("webcam", include_str!("../../scenarios/webcam.toml")),
];

/// The scene: the wall with the painted line, the floor, the light.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SceneConfig {
    /// World x of the line's start end (m).
    pub line_x_start_m: f64,
    /// World x of the line's finish end (m).
    pub line_x_end_m: f64,
    /// Height of the line's lower edge (m).
    pub line_z_bottom_m: f64,
    /// Height of the line's upper edge (m).
    pub line_z_top_m: f64,
    /// Albedo of the red paint (linear RGB, 0..1).
    pub line_albedo_rgb: [f64; 3],
    /// Albedo of the wall.
    pub wall_albedo_rgb: [f64; 3],
    /// Albedo of the floor.
    pub floor_albedo_rgb: [f64; 3],
    /// Relative amplitude of the wall texture.
    pub wall_texture_contrast: f64,
    /// Relative amplitude of the floor texture (near 0: a nearly blank floor).
    pub floor_texture_contrast: f64,
    /// What the floor looks like.
    #[serde(default)]
    pub floor_texture: FloorTexture,
    /// Seed of the procedural textures.
    pub texture_seed: u64,
    /// Illumination gain.
    pub light_gain: f64,
    /// Relative change of the illumination per metre along the wall's x and z.
    pub light_gradient_per_m: [f64; 2],
    /// Whether the line is painted (scenes without it test the detector's rejections).
    #[serde(default = "yes")]
    pub line_visible: bool,
    /// Other shapes painted on the wall.
    #[serde(default)]
    pub shapes: Vec<WallShape>,
}

/// The floor's texture.
#[derive(Clone, Copy, Debug, Default, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum FloorTexture {
    /// Concrete: blotches, grain, sparse speckles.
    #[default]
    Concrete,
    /// Speckled vinyl: dense centimetre chips (good features for the downward camera).
    Speckled,
    /// Smooth plaster-like: soft blotches only.
    Plaster,
}

impl FloorTexture {
    /// The renderer's texture kind.
    pub fn kind(self) -> crate::render::texture::TextureKind {
        use crate::render::texture::TextureKind;
        match self {
            FloorTexture::Concrete => TextureKind::Concrete,
            FloorTexture::Speckled => TextureKind::Speckled,
            FloorTexture::Plaster => TextureKind::Plaster,
        }
    }
}

fn yes() -> bool {
    true
}

/// A shape painted on the wall, in wall coordinates `(x, z)` (metres).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum WallShape {
    /// A convex polygon.
    Polygon {
        /// Vertices `(x, z)` in order.
        points_m: Vec<[f64; 2]>,
        /// Albedo (linear RGB, 0..1).
        albedo_rgb: [f64; 3],
    },
    /// A disc.
    Disc {
        /// Centre `(x, z)`.
        center_m: [f64; 2],
        /// Radius.
        radius_m: f64,
        /// Albedo (linear RGB, 0..1).
        albedo_rgb: [f64; 3],
    },
}

impl WallShape {
    /// The shape as a convex polygon in wall coordinates (discs as 32-gons) and its albedo.
    pub fn polygon(&self) -> (Vec<[f64; 2]>, [f64; 3]) {
        match self {
            WallShape::Polygon { points_m, albedo_rgb } => (points_m.clone(), *albedo_rgb),
            WallShape::Disc { center_m, radius_m, albedo_rgb } => {
                let pts = (0..32)
                    .map(|i| {
                        let a = i as f64 * std::f64::consts::TAU / 32.0;
                        [center_m[0] + radius_m * a.cos(), center_m[1] + radius_m * a.sin()]
                    })
                    .collect();
                (pts, *albedo_rgb)
            }
        }
    }
}

fn is_convex(p: &[[f64; 2]]) -> bool {
    let n = p.len();
    let mut sign = 0.0f64;
    for k in 0..n {
        let (a, b, c) = (p[k], p[(k + 1) % n], p[(k + 2) % n]);
        let cross = (b[0] - a[0]) * (c[1] - b[1]) - (b[1] - a[1]) * (c[0] - b[0]);
        if cross.abs() < 1e-12 {
            continue;
        }
        if sign == 0.0 {
            sign = cross.signum();
        } else if cross.signum() != sign {
            return false;
        }
    }
    sign != 0.0
}

/// The forward camera.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ForwardCameraConfig {
    /// Image width (px).
    pub width_px: u16,
    /// Image height (px).
    pub height_px: u16,
    /// Focal length x (px).
    pub fx_px: f64,
    /// Focal length y (px).
    pub fy_px: f64,
    /// Principal point x (px).
    pub cx_px: f64,
    /// Principal point y (px).
    pub cy_px: f64,
    /// k1, k2, p1, p2, k3.
    pub distortion: [f64; 5],
    /// Camera centre in the body frame (m).
    pub mount_offset_body_m: [f64; 3],
    /// Roll, pitch, yaw of the camera relative to looking straight forward (deg).
    pub mount_rotation_deg: [f64; 3],
    /// Sensor noise (grey levels, 1 sigma).
    pub noise_sigma: f64,
    /// Optical blur (px, Gaussian sigma).
    pub blur_sigma_px: f64,
    /// Exposure gain.
    pub exposure: f64,
    /// The sensor's tone curve: `"srgb"` (the default, as webcams deliver) or `"linear"`. Each channel clips
    /// at full scale before it.
    #[serde(default)]
    pub response: vision_core::ToneCurve,
    /// Auto exposure: each frame's exposure is `exposure` times a factor drawn from `1 +- exposure_step` by the
    /// frame's seed (0: fixed exposure).
    #[serde(default)]
    pub exposure_step: f64,
    /// Light at the image corners relative to the centre is `1 - vignetting` (quadratic in the distance from
    /// the principal point).
    #[serde(default)]
    pub vignetting: f64,
    /// JPEG quality of the delivered frames, 4:2:2 chroma as webcams' MJPEG (1-100; 0: uncompressed).
    #[serde(default)]
    pub jpeg_quality: i32,
    /// Exposure time (s): the frame is the mean of the views over it while the vehicle moves (motion blur);
    /// 0 for an instantaneous exposure.
    #[serde(default)]
    pub exposure_time_s: f64,
    /// Rolling shutter: the delay between the exposures of consecutive rows (s; webcams 15-40 us); rows are
    /// timed from the middle one, which is the frame's time. 0 for a global shutter.
    #[serde(default)]
    pub line_delay_s: f64,
    /// Frame rate (Hz).
    #[serde(default = "default_camera_rate")]
    pub rate_hz: f64,
    /// Delay from capture to the measurement reaching the vehicle: processing and radio (s).
    #[serde(default = "default_camera_latency")]
    pub latency_s: f64,
    /// Uniform jitter added to the latency, +- (s).
    #[serde(default)]
    pub latency_jitter_s: f64,
    /// Edge noise of the `analytic` camera mode (px, 1 sigma per edge point).
    #[serde(default = "default_analytic_noise")]
    pub analytic_noise_px: f64,
}

/// The downward camera (optical flow).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct DownCameraConfig {
    /// Whether the vehicle has it; without it, velocity comes from the IMU and the forward camera only.
    pub enabled: bool,
    /// Image width (px).
    pub width_px: u16,
    /// Image height (px).
    pub height_px: u16,
    /// Focal length x (px).
    pub fx_px: f64,
    /// Focal length y (px).
    pub fy_px: f64,
    /// Principal point x (px).
    pub cx_px: f64,
    /// Principal point y (px).
    pub cy_px: f64,
    /// Camera centre in the body frame (m).
    pub mount_offset_body_m: [f64; 3],
    /// Roll, pitch, yaw of the camera relative to looking straight down, image top forward (deg).
    pub mount_rotation_deg: [f64; 3],
    /// Frame rate (Hz).
    pub rate_hz: f64,
    /// Delay from capture to the flow reaching the vehicle: processing and radio (s).
    pub latency_s: f64,
    /// Exposure time (s): the image integrates the motion over it (motion blur).
    pub exposure_time_s: f64,
    /// Exposure gain.
    pub exposure: f64,
    /// Sensor noise (grey levels, 1 sigma).
    pub noise_sigma: f64,
    /// Optical blur (px, Gaussian sigma, at most 1).
    pub blur_sigma_px: f64,
    /// Relative brightness loss in the image corners (0 = none).
    pub vignetting: f64,
    /// The sensor's tone curve: `"linear"` (the default: a grey machine-vision sensor, as optical-flow
    /// cameras use) or `"srgb"` (a webcam); the sensor clips at full scale before it.
    pub response: vision_core::ToneCurve,
}

impl Default for DownCameraConfig {
    fn default() -> Self {
        // 160x120 with a 60 degree horizontal field of view: f = 80 / tan(30 deg) = 138.6 px.
        Self {
            enabled: true,
            width_px: 160,
            height_px: 120,
            fx_px: 138.6,
            fy_px: 138.6,
            cx_px: 79.5,
            cy_px: 59.5,
            mount_offset_body_m: [0.0, 0.0, 0.0],
            mount_rotation_deg: [0.0, 0.0, 0.0],
            rate_hz: 60.0,
            latency_s: 0.03,
            exposure_time_s: 0.004,
            exposure: 1.0,
            noise_sigma: 2.0,
            blur_sigma_px: 1.0,
            vignetting: 0.2,
            response: vision_core::ToneCurve::Linear,
        }
    }
}

fn default_camera_rate() -> f64 {
    30.0
}
fn default_camera_latency() -> f64 {
    0.05
}
fn default_analytic_noise() -> f64 {
    0.15
}

/// Simulator-only physics, beyond what the flight code knows.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct ModelConfig {
    /// First-order motor time constant (s).
    pub motor_time_constant_s: f64,
    /// Linear translational drag (N per m/s); 0 gives the paper's model.
    pub linear_drag_n_s_per_m: f64,
    /// Rotor drag: force per (m/s of air-relative velocity in the rotor plane) per (rad/s of the sum of the
    /// rotor speeds) (N s^2 / (m rad)); 0 gives the paper's model. The default, 5.1e-5, is 0.3 (m/s^2)/(m/s)
    /// at the paper vehicle's hover (its flight code's `estimator.drag_coeff_per_s`).
    pub rotor_drag_coeff: f64,
    /// Rotor radius for the ground effect near the floor (m); 0 turns it off (the paper's model).
    pub ground_effect_rotor_radius_m: f64,
    /// Fixed physics step (s).
    pub physics_step_s: f64,
    /// Where the vehicle rests at the start (world, m); also the flight code's home.
    pub start_position_m: [f64; 3],
    /// Heading at the start (deg, from facing the wall).
    pub start_yaw_deg: f64,
}

impl Default for ModelConfig {
    fn default() -> Self {
        Self {
            motor_time_constant_s: 0.02,
            linear_drag_n_s_per_m: 0.0,
            rotor_drag_coeff: 5.1e-5,
            ground_effect_rotor_radius_m: 0.127,
            physics_step_s: 0.001,
            start_position_m: [0.0, 1.30, 0.06],
            start_yaw_deg: 0.0,
        }
    }
}

/// The IMU, magnetometer and barometer.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct ImuConfig {
    /// Sample rate (Hz); a whole number of physics steps.
    pub rate_hz: f64,
    /// Gyro white-noise density (rad/s/sqrt(Hz)).
    pub gyro_noise_density: f64,
    /// Accelerometer white-noise density (m/s^2/sqrt(Hz)).
    pub accel_noise_density: f64,
    /// Standard deviation of the constant gyro bias drawn per run (rad/s).
    pub gyro_bias_sigma_rad_s: f64,
    /// Standard deviation of the constant accelerometer bias drawn per run (m/s^2).
    pub accel_bias_sigma_m_s2: f64,
    /// Magnetometer rate (Hz).
    pub mag_rate_hz: f64,
    /// Magnetometer noise relative to the field strength (1 sigma).
    pub mag_noise_rel: f64,
    /// Magnetic field in the world frame (gauss).
    pub mag_field_world: [f64; 3],
    /// Vibration of the accelerometer at the rotors' frequencies, RMS at hover (m/s^2; scales with the
    /// square of the rotor speed).
    pub vibration_accel_m_s2: f64,
    /// Vibration of the gyro at the rotors' frequencies, RMS at hover (rad/s).
    pub vibration_gyro_rad_s: f64,
    /// The accelerometer's range: readings clip here (m/s^2; 16 g).
    pub accel_range_m_s2: f64,
    /// The gyro's range (rad/s; 2000 deg/s).
    pub gyro_range_rad_s: f64,
    /// The sensor's digital low-pass filter, first order (Hz; 0 turns it off): the anti-alias filter of a MEMS
    /// part such as the MPU-6000's DLPF (98 Hz in its setting 2).
    pub dlpf_hz: f64,
    /// Barometer rate (Hz; 0: the vehicle has none). Every STM32F405 flight controller carries one (BMP280,
    /// DPS310, MS5611).
    pub baro_rate_hz: f64,
    /// Barometer noise per reading (m, 1 sigma), the rotors' pressure disturbances included.
    pub baro_noise_m: f64,
    /// The floor's pressure altitude (m): the day's pressure, unknown to the flight code.
    pub baro_offset_m: f64,
    /// The barometer's drift, a random walk (m per sqrt(s)).
    pub baro_drift_m_per_sqrt_s: f64,
}

impl Default for ImuConfig {
    fn default() -> Self {
        Self {
            rate_hz: 1000.0,
            gyro_noise_density: 1.0e-3,
            accel_noise_density: 0.02,
            gyro_bias_sigma_rad_s: 0.01,
            accel_bias_sigma_m_s2: 0.03,
            mag_rate_hz: 50.0,
            mag_noise_rel: 0.01,
            mag_field_world: [0.2, -0.05, -0.4],
            vibration_accel_m_s2: 0.3,
            vibration_gyro_rad_s: 0.02,
            accel_range_m_s2: 16.0 * 9.80665,
            gyro_range_rad_s: 2000f64.to_radians(),
            dlpf_hz: 98.0,
            baro_rate_hz: 50.0,
            baro_noise_m: 0.1,
            baro_offset_m: 120.0,
            baro_drift_m_per_sqrt_s: 0.005,
        }
    }
}

/// The ground station's radio link.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct LinkConfig {
    /// Delay of operator commands and heartbeats (s).
    pub latency_s: f64,
    /// Heartbeat rate (Hz).
    pub heartbeat_hz: f64,
}

impl Default for LinkConfig {
    fn default() -> Self {
        Self { latency_s: 0.02, heartbeat_hz: 10.0 }
    }
}

/// The operator's script and the run's limits.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct MissionConfig {
    /// Control rate (Hz); a whole number of physics steps.
    pub control_rate_hz: f64,
    /// When the operator arms (s).
    pub arm_at_s: f64,
    /// When the operator commands the take-off (s).
    pub takeoff_at_s: f64,
    /// How long after the vehicle reports hovering the operator starts the sweep (s).
    pub track_after_hover_s: f64,
    /// Land when the sweep is done.
    pub land_when_done: bool,
    /// Longest run (s); `fly --duration` overrides it.
    pub max_duration_s: f64,
}

impl Default for MissionConfig {
    fn default() -> Self {
        Self {
            control_rate_hz: 500.0,
            arm_at_s: 1.0,
            takeoff_at_s: 1.5,
            track_after_hover_s: 1.0,
            land_when_done: true,
            max_duration_s: 120.0,
        }
    }
}

/// A whole scenario.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Scenario {
    /// Short name.
    pub name: String,
    /// One line of description.
    #[serde(default)]
    pub description: String,
    /// The scene.
    pub scene: SceneConfig,
    /// The forward camera.
    pub forward_camera: ForwardCameraConfig,
    /// The downward camera.
    #[serde(default)]
    pub down_camera: DownCameraConfig,
    /// The vehicle (shared by the model and the flight code).
    #[serde(default)]
    pub vehicle: VehicleParams,
    /// Simulator-only physics.
    #[serde(default)]
    pub model: ModelConfig,
    /// IMU and magnetometer.
    #[serde(default)]
    pub imu: ImuConfig,
    /// Radio link.
    #[serde(default)]
    pub link: LinkConfig,
    /// Control gains.
    #[serde(default)]
    pub gains: ControlGains,
    /// State estimator.
    #[serde(default)]
    pub estimator: EstimatorParams,
    /// Mission.
    #[serde(default)]
    pub trajectory: TrajectoryParams,
    /// Failsafes.
    #[serde(default)]
    pub failsafe: FailsafeParams,
    /// What the vehicle sends down the radio.
    #[serde(default)]
    pub downlink: DownlinkParams,
    /// The pilot's transmitter as the flight code uses it (`control_core::pilot`).
    #[serde(default)]
    pub rc: RcParams,
    /// The flight battery's monitoring in the flight code (`control_core::battery`).
    #[serde(default)]
    pub battery: control_core::battery::BatteryParams,
    /// The simulated flight battery (its sag, its charge, the readings).
    #[serde(default)]
    pub battery_model: crate::power::BatteryModelConfig,
    /// The simulated pilot: whether the vehicle has an RC receiver, and what the transmitter does when.
    #[serde(default)]
    pub transmitter: crate::transmitter::TransmitterConfig,
    /// Operator script and run limits.
    #[serde(default)]
    pub mission: MissionConfig,
    /// The simulated vehicle's departures from `[vehicle]` (the flight code keeps `[vehicle]`).
    #[serde(default)]
    pub mismatch: MismatchConfig,
    /// Wind.
    #[serde(default)]
    pub wind: WindConfig,
    /// Scheduled faults.
    #[serde(default)]
    pub faults: Vec<FaultConfig>,
}

pub mod limits;
mod robustness;
mod validate;
pub use limits::{DOWN_BLUR_MAX_PX, FORWARD_BLUR_MAX_PX};
pub use validate::Ranged;

pub use robustness::{FaultConfig, FaultKind, GustConfig, MismatchConfig, WindConfig};

impl Scenario {
    /// A built-in scenario by name, or a TOML file by path.
    pub fn load(name_or_path: &str) -> Result<Scenario> {
        if let Some((_, text)) = BUILT_IN.iter().find(|(n, _)| *n == name_or_path) {
            return Scenario::from_toml(text).with_context(|| format!("built-in scenario `{name_or_path}`"));
        }
        let path = Path::new(name_or_path);
        if !path.exists() {
            let names: Vec<&str> = BUILT_IN.iter().map(|(n, _)| *n).collect();
            bail!("no scenario file `{name_or_path}` (built-in scenarios: {})", names.join(", "));
        }
        let text =
            std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
        Scenario::from_toml(&text).with_context(|| format!("in scenario file {}", path.display()))
    }

    /// The built-in paper scenario.
    pub fn paper() -> Scenario {
        match Scenario::load("paper") {
            Ok(s) => s,
            Err(e) => panic!("the built-in paper scenario must parse: {e:#}"),
        }
    }

    /// Parses and validates a scenario.
    pub fn from_toml(text: &str) -> Result<Scenario> {
        let s: Scenario = toml::from_str(text).map_err(|e| anyhow::anyhow!("{e}"))?;
        s.validate()?;
        Ok(s)
    }

    /// The flight code's parameters.
    pub fn flight_params(&self) -> FlightParams {
        FlightParams {
            vehicle: self.vehicle,
            gains: self.gains,
            estimator: self.estimator,
            trajectory: self.trajectory,
            failsafe: self.failsafe,
            downlink: self.downlink,
            rc: self.rc,
            battery: self.battery,
            home_m: self.model.start_position_m.map(|v| v as f32),
        }
    }

    /// The flight stack's configuration.
    pub fn flight_config(&self) -> FlightConfig {
        FlightConfig {
            control: self.flight_params(),
            vision: VisionConfig {
                camera: self.forward_camera_model(),
                target: self.line_target(),
                mount: self.forward_camera_mount(),
                ..VisionConfig::default()
            },
            flow: FlowConfig {
                mount: self.down_camera_mount(),
                track_sigma: 0.05 / self.down_camera.fx_px as f32,
                ..FlowConfig::default()
            },
        }
    }

    /// The line's geometry for vision-core.
    pub fn line_target(&self) -> LineTarget {
        let s = &self.scene;
        LineTarget {
            x_start_m: s.line_x_start_m as f32,
            x_end_m: s.line_x_end_m as f32,
            z_bottom_m: s.line_z_bottom_m as f32,
            z_top_m: s.line_z_top_m as f32,
        }
    }

    /// The forward camera's intrinsics for vision-core.
    pub fn forward_camera_model(&self) -> CameraModel {
        let c = &self.forward_camera;
        let d = c.distortion.map(|v| v as f32);
        CameraModel {
            width: c.width_px,
            height: c.height_px,
            fx: c.fx_px as f32,
            fy: c.fy_px as f32,
            cx: c.cx_px as f32,
            cy: c.cy_px as f32,
            distortion: Distortion { k1: d[0], k2: d[1], p1: d[2], p2: d[3], k3: d[4] },
        }
    }

    /// The downward camera's intrinsics for vision-core (an ideal pinhole).
    pub fn down_camera_model(&self) -> CameraModel {
        let c = &self.down_camera;
        CameraModel {
            width: c.width_px,
            height: c.height_px,
            fx: c.fx_px as f32,
            fy: c.fy_px as f32,
            cx: c.cx_px as f32,
            cy: c.cy_px as f32,
            distortion: Distortion::default(),
        }
    }

    /// The downward camera's mount.
    pub fn down_camera_mount(&self) -> CameraMount {
        let c = &self.down_camera;
        let [r, p, y] = c.mount_rotation_deg.map(|a| geometry::deg(a as f32));
        let extra = Mat3::from_euler_zyx(r, p, y);
        CameraMount {
            body_from_camera: extra.mul_mat(&BODY_FROM_DOWN_CAMERA),
            offset_body_m: Vec3::from_array(c.mount_offset_body_m.map(|v| v as f32)),
        }
    }

    /// The forward camera's rolling-shutter timing for the detector when it has one (`line_delay_s` above 0),
    /// with the vehicle's body rates (rad/s) rotated into the camera: rows timed from the middle one.
    pub fn forward_row_timing(&self, rates_body_rad_s: Vec3) -> Option<vision_core::RowTiming> {
        let c = &self.forward_camera;
        (c.line_delay_s > 0.0).then(|| vision_core::RowTiming {
            rates_cam_rad_s: self
                .forward_camera_mount()
                .body_from_camera
                .transpose()
                .mul_vec(rates_body_rad_s),
            line_delay_s: c.line_delay_s as f32,
            reference_row: (c.height_px as f32 - 1.0) / 2.0,
        })
    }

    /// The forward camera's mount for vision-core.
    pub fn forward_camera_mount(&self) -> CameraMount {
        let c = &self.forward_camera;
        let [r, p, y] = c.mount_rotation_deg.map(|a| geometry::deg(a as f32));
        // The extra rotation is applied in the body frame around the nominal forward mount.
        let extra = Mat3::from_euler_zyx(r, p, y);
        let o = c.mount_offset_body_m.map(|v| v as f32);
        CameraMount {
            body_from_camera: extra.mul_mat(&BODY_FROM_FORWARD_CAMERA),
            offset_body_m: Vec3::from_array(o),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_webcam_scenario_is_the_paper_s_with_a_webcam() {
        let (paper, webcam) = (Scenario::paper(), Scenario::load("webcam").unwrap());
        let c = &webcam.forward_camera;
        assert_eq!(c.distortion, [-0.3, 0.08, 0.0, 0.0, 0.0]);
        assert_eq!((c.blur_sigma_px, c.vignetting, c.exposure_step), (1.0, 0.3, 0.3));
        assert_eq!((c.exposure_time_s, c.line_delay_s, c.jpeg_quality), (0.01, 30e-6, 85));
        assert_eq!(c.response, vision_core::ToneCurve::Srgb);
        // Everything but the forward camera (and the names) is the paper's.
        let mut same = webcam.clone();
        (same.name, same.description, same.forward_camera) =
            (paper.name.clone(), paper.description.clone(), paper.forward_camera.clone());
        assert_eq!(same, paper);
    }

    #[test]
    fn paper_scenario_matches_the_issue() {
        let s = Scenario::paper();
        let t = s.line_target();
        assert_eq!((t.x_start_m, t.x_end_m, t.z_bottom_m, t.z_top_m), (0.0, 2.30, 0.95, 1.05));
        let c = s.forward_camera_model();
        assert_eq!((c.width, c.height, c.fx, c.fy, c.cx, c.cy), (640, 480, 320.0, 320.0, 320.0, 240.0));
        assert_eq!(s.forward_camera_mount(), CameraMount::FORWARD_AT_CENTRE);
        // The flight code's configuration from the file is the firmware's built-in one, bit for bit (the
        // firmware-in-the-loop run compares motor commands with the simulator's).
        let (a, b) = (s.flight_config(), FlightConfig::paper());
        assert_eq!(a.control.vehicle, b.control.vehicle);
        assert_eq!(a.control.gains, b.control.gains);
        assert_eq!(a.control.estimator, b.control.estimator);
        assert_eq!(a.control.trajectory, b.control.trajectory);
        assert_eq!(a.control.failsafe, b.control.failsafe);
        assert_eq!(a.control.home_m, b.control.home_m);
        assert_eq!(a.vision, b.vision);
        assert_eq!(a.flow, b.flow);
        // The file's downward camera is the built-in default.
        assert_eq!(s.down_camera, DownCameraConfig::default());
        assert_eq!(s.down_camera_mount(), CameraMount::DOWN_AT_CENTRE);
    }

    #[test]
    fn unknown_and_invalid_fields_are_named() {
        let text = BUILT_IN[0].1;
        let unknown = text.replace("light_gain = 1.0", "light_gain = 1.0\nlight_colour = 3");
        let e = format!("{:#}", Scenario::from_toml(&unknown).unwrap_err());
        assert!(e.contains("light_colour"), "{e}");
        let bad = text.replace("line_z_top_m = 1.05", "line_z_top_m = 0.5");
        let e = format!("{:#}", Scenario::from_toml(&bad).unwrap_err());
        assert!(e.contains("scene.line_z_top_m"), "{e}");
        let bad = text.replace("fx_px = 320.0", "fx_px = -1.0");
        let e = format!("{:#}", Scenario::from_toml(&bad).unwrap_err());
        assert!(e.contains("forward_camera.fx_px"), "{e}");
        let bad = text.replace("rate_hz = 60.0", "rate_hz = 5.0");
        let e = format!("{:#}", Scenario::from_toml(&bad).unwrap_err());
        assert!(e.contains("down_camera.rate_hz"), "{e}");
        let bad = text.replace("floor_texture = \"speckled\"", "floor_texture = \"carpet\"");
        let e = format!("{:#}", Scenario::from_toml(&bad).unwrap_err());
        assert!(e.contains("carpet"), "{e}");
        assert!(Scenario::load("no-such-scenario").is_err());
    }

    #[test]
    fn a_control_rate_that_would_drop_imu_samples_is_refused() {
        // 1000 Hz IMU, 200 Hz control: five samples per step, one more than a step carries (it used to be
        // logged as a step without IMU, silently).
        let text = BUILT_IN[0].1;
        let slow = text.replace("control_rate_hz = 500.0", "control_rate_hz = 200.0");
        let e = format!("{:#}", Scenario::from_toml(&slow).unwrap_err());
        assert!(e.contains("mission.control_rate_hz") && e.contains("250 Hz"), "{e}");
        // Four samples per step still fit.
        let ok = text.replace("control_rate_hz = 500.0", "control_rate_hz = 250.0");
        Scenario::from_toml(&ok).unwrap();
        // Absurd vehicles: a typing or unit error, refused by name (they used to crash the simulated vehicle).
        for (from, to, field) in [
            (
                "inertia_kg_m2 = [3.9e-3, 3.9e-3, 7.1e-3]",
                "inertia_kg_m2 = [1e-30, 3.9e-3, 7.1e-3]",
                "vehicle.inertia_kg_m2",
            ),
            ("motor_time_constant_s = 0.02", "motor_time_constant_s = 1e-30", "model.motor_time_constant_s"),
            ("mass_kg = 0.38", "mass_kg = 3800.0", "vehicle.mass_kg"),
            ("thrust_coeff = 2.98e-6", "thrust_coeff = 2.98", "vehicle.thrust_coeff"),
        ] {
            assert!(text.contains(from), "{from}");
            let e = format!("{:#}", Scenario::from_toml(&text.replace(from, to)).unwrap_err());
            assert!(e.contains(field), "{to}: {e}");
        }
        // A physics step that would divide by (almost) zero.
        let tiny = text.replace("physics_step_s = 0.001", "physics_step_s = 1e-30");
        let e = format!("{:#}", Scenario::from_toml(&tiny).unwrap_err());
        assert!(e.contains("model.physics_step_s"), "{e}");
    }
}
