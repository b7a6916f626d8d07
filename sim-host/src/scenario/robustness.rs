//! The scenario's departures from the world the flight code was tuned for: the simulated vehicle differing from
//! its configuration (`[mismatch]`), wind (`[wind]`) and scheduled faults (`[[faults]]`). All apply to the
//! simulation only; the flight code keeps `[vehicle]` and its own parameters.
use serde::{Deserialize, Serialize};

/// Scale factors and errors of the simulated vehicle against the configured one (`[vehicle]`, which the
/// flight code keeps). 1.0 and 0 by default.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct MismatchConfig {
    /// The true mass over the configured one.
    pub mass_scale: f64,
    /// The true principal inertias over the configured ones.
    pub inertia_scale: [f64; 3],
    /// The true thrust coefficient over the configured one.
    pub thrust_coeff_scale: f64,
    /// The true drag-torque coefficient over the configured one.
    pub drag_torque_coeff_scale: f64,
    /// The true motor time constant over the scenario's `model.motor_time_constant_s`.
    pub motor_time_constant_scale: f64,
    /// The forward camera's true mount rotated from the configured one by roll, pitch, yaw (deg).
    pub forward_camera_mount_error_deg: [f64; 3],
    /// The IMU's axes rotated from the body's by roll, pitch, yaw (deg).
    pub imu_misalignment_deg: [f64; 3],
}

impl Default for MismatchConfig {
    fn default() -> Self {
        Self {
            mass_scale: 1.0,
            inertia_scale: [1.0; 3],
            thrust_coeff_scale: 1.0,
            drag_torque_coeff_scale: 1.0,
            motor_time_constant_scale: 1.0,
            forward_camera_mount_error_deg: [0.0; 3],
            imu_misalignment_deg: [0.0; 3],
        }
    }
}

/// A 1-cosine gust: the wind rises from zero to `velocity_m_s` and back over `duration_s`,
/// `v(t) = v_gust (1 - cos(2 pi (t - start) / duration)) / 2`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct GustConfig {
    /// Start (s).
    pub start_s: f64,
    /// Duration (s).
    pub duration_s: f64,
    /// The peak wind added, world frame (m/s).
    pub velocity_m_s: [f64; 3],
}

/// The air's motion, world frame. The drag terms of the model see the air-relative velocity.
#[derive(Clone, Debug, Default, Serialize, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct WindConfig {
    /// Mean wind (m/s).
    pub mean_m_s: [f64; 3],
    /// Turbulence intensity, each axis (m/s, 1 sigma): Dryden turbulence (MIL-HDBK-1797).
    pub turbulence_sigma_m_s: f64,
    /// Turbulence scale length (m).
    pub turbulence_length_m: f64,
    /// Discrete gusts.
    pub gusts: Vec<GustConfig>,
}

/// What goes wrong.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum FaultKind {
    /// The forward camera's measurements do not reach the vehicle.
    VisionDropout,
    /// The forward camera delivers the same frame again and again (a frozen driver), with new times.
    VisionFreeze,
    /// The downward camera's flow does not reach the vehicle.
    FlowDropout,
    /// Nothing from the ground station reaches the vehicle.
    LinkLoss,
    /// The uplink's bytes are corrupted: each byte of a frame flips one bit with this probability.
    LinkCorruption {
        /// Probability per byte (0..1).
        byte_error_rate: f64,
    },
    /// Spikes in single IMU samples.
    ImuSpike {
        /// Spikes per second.
        rate_hz: f64,
        /// Added to the accelerometer, each axis at most (m/s^2).
        accel_m_s2: f64,
        /// Added to the gyro, each axis at most (rad/s).
        gyro_rad_s: f64,
    },
    /// The IMU's biases jump.
    ImuBiasStep {
        /// Added to the gyro (rad/s).
        gyro_rad_s: [f64; 3],
        /// Added to the accelerometer (m/s^2).
        accel_m_s2: [f64; 3],
    },
    /// The gyro clips at a lower range.
    GyroSaturation {
        /// The range (rad/s).
        limit_rad_s: f64,
    },
    /// The magnetic field is disturbed (steel, currents).
    MagDisturbance {
        /// The field's heading turned by (deg).
        heading_offset_deg: f64,
        /// Its strength scaled by.
        field_scale: f64,
    },
    /// One rotor gives less thrust.
    MotorDegradation {
        /// Which rotor (1 front, 2 left, 3 rear, 4 right).
        motor: u8,
        /// Its thrust scaled by (0..1).
        thrust_scale: f64,
    },
    /// One rotor stops.
    MotorLoss {
        /// Which rotor (1-4).
        motor: u8,
    },
    /// The pilot's transmitter is not heard (out of range, switched off): the receiver gets no frame.
    RcLoss,
}

impl FaultKind {
    /// The kind's name, as in scenario files.
    pub fn name(&self) -> &'static str {
        match self {
            FaultKind::VisionDropout => "vision_dropout",
            FaultKind::VisionFreeze => "vision_freeze",
            FaultKind::FlowDropout => "flow_dropout",
            FaultKind::LinkLoss => "link_loss",
            FaultKind::LinkCorruption { .. } => "link_corruption",
            FaultKind::ImuSpike { .. } => "imu_spike",
            FaultKind::ImuBiasStep { .. } => "imu_bias_step",
            FaultKind::GyroSaturation { .. } => "gyro_saturation",
            FaultKind::MagDisturbance { .. } => "mag_disturbance",
            FaultKind::MotorDegradation { .. } => "motor_degradation",
            FaultKind::MotorLoss { .. } => "motor_loss",
            FaultKind::RcLoss => "rc_loss",
        }
    }
}

/// A fault active from `start_s` for `duration_s`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct FaultConfig {
    /// Start (s).
    pub start_s: f64,
    /// Duration (s).
    pub duration_s: f64,
    /// What.
    #[serde(flatten)]
    pub kind: FaultKind,
}

impl FaultConfig {
    /// Whether the fault acts at `t_s`.
    pub fn active(&self, t_s: f64) -> bool {
        t_s >= self.start_s && t_s < self.start_s + self.duration_s
    }
}
