//! Sensor models: IMU (gyro and accelerometer with constant biases and white noise) and magnetometer.
use crate::model::Quadrotor;
use crate::rng::SimRng;
use crate::scenario::ImuConfig;
use control_core::estimator::ImuSample;
use geometry::Vec3;

/// The IMU and magnetometer of one run. Each noise source has its own seeded stream.
pub struct ImuModel {
    gyro_bias: [f64; 3],
    accel_bias: [f64; 3],
    gyro_sigma: f64,
    accel_sigma: f64,
    mag_sigma: f64,
    mag_field: [f64; 3],
    gyro_rng: SimRng,
    accel_rng: SimRng,
    mag_rng: SimRng,
}

impl ImuModel {
    /// Draws this run's biases from `seed`.
    pub fn new(cfg: &ImuConfig, seed: u64) -> Self {
        let mut bias = SimRng::stream(seed, "imu-bias");
        let gyro_bias = [0; 3].map(|_| cfg.gyro_bias_sigma_rad_s * bias.normal());
        let accel_bias = [0; 3].map(|_| cfg.accel_bias_sigma_m_s2 * bias.normal());
        let norm = cfg.mag_field_world.iter().map(|v| v * v).sum::<f64>().sqrt();
        Self {
            gyro_bias,
            accel_bias,
            gyro_sigma: cfg.gyro_noise_density * cfg.rate_hz.sqrt(),
            accel_sigma: cfg.accel_noise_density * cfg.rate_hz.sqrt(),
            mag_sigma: cfg.mag_noise_rel * norm,
            mag_field: cfg.mag_field_world,
            gyro_rng: SimRng::stream(seed, "imu-gyro"),
            accel_rng: SimRng::stream(seed, "imu-accel"),
            mag_rng: SimRng::stream(seed, "magnetometer"),
        }
    }

    /// The biases drawn for this run (gyro, accelerometer).
    pub fn biases(&self) -> ([f64; 3], [f64; 3]) {
        (self.gyro_bias, self.accel_bias)
    }

    /// One IMU sample of the vehicle's current state.
    pub fn sample(&mut self, q: &Quadrotor, time_us: u64) -> ImuSample {
        let f = q.specific_force_body();
        let w = q.state.w;
        let mut gyro = [0.0f32; 3];
        let mut accel = [0.0f32; 3];
        for i in 0..3 {
            gyro[i] = (w[i] + self.gyro_bias[i] + self.gyro_sigma * self.gyro_rng.normal()) as f32;
            accel[i] = (f[i] + self.accel_bias[i] + self.accel_sigma * self.accel_rng.normal()) as f32;
        }
        ImuSample { time_us, gyro_rad_s: gyro, accel_m_s2: accel }
    }

    /// One magnetometer reading (body frame).
    pub fn mag(&mut self, q: &Quadrotor) -> Vec3 {
        let r = q.rotation();
        let b = self.mag_field;
        let mut m = [0.0f32; 3];
        for i in 0..3 {
            let bi = r[0][i] * b[0] + r[1][i] * b[1] + r[2][i] * b[2];
            m[i] = (bi + self.mag_sigma * self.mag_rng.normal()) as f32;
        }
        Vec3::from_array(m)
    }
}
