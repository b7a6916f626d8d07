//! Sensor models: the IMU (gyro and accelerometer) and the magnetometer.
//!
//! The IMU reads the body's rates and specific force in its own axes (turned from the body's by
//! `mismatch.imu_misalignment_deg`), plus per-run constant biases, white noise, and vibration at each
//! rotor's rotation frequency (amplitude scaling with the square of the rotor speed, random phases per run);
//! a first-order digital low-pass (`imu.dlpf_hz`, the anti-alias filter of a MEMS part) follows, then the
//! readings clip at the sensor's range (+-16 g, +-2000 deg/s by default). Faults (`[[faults]]`) add single-sample
//! spikes, bias steps and a lowered gyro range. Each noise source has its own seeded stream.
use crate::model::Quadrotor;
use crate::rng::SimRng;
use crate::scenario::{FaultConfig, FaultKind, ImuConfig};
use control_core::estimator::ImuSample;
use geometry::Vec3;

type M3 = [[f64; 3]; 3];

fn rot_zyx(deg: [f64; 3]) -> M3 {
    let [r, p, y] = deg.map(f64::to_radians);
    let (sr, cr, sp, cp, sy, cy) = (r.sin(), r.cos(), p.sin(), p.cos(), y.sin(), y.cos());
    [
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ]
}

fn mul(m: &M3, v: [f64; 3]) -> [f64; 3] {
    [0, 1, 2].map(|i| m[i][0] * v[0] + m[i][1] * v[1] + m[i][2] * v[2])
}

/// What the active faults do to the IMU at one instant.
#[derive(Clone, Copy, Debug, Default)]
pub struct ImuFaults {
    /// Spikes: (probability per sample, accelerometer amplitude, gyro amplitude).
    pub spike: Option<(f64, f64, f64)>,
    /// Bias steps: gyro, accelerometer.
    pub bias_step: ([f64; 3], [f64; 3]),
    /// A lowered gyro range (rad/s).
    pub gyro_limit: Option<f64>,
    /// The magnetic field's heading offset (rad) and strength scale.
    pub mag: Option<(f64, f64)>,
}

impl ImuFaults {
    /// The IMU's faults among `faults` at `t_s`, for samples at `rate_hz`.
    pub fn at(faults: &[FaultConfig], t_s: f64, rate_hz: f64) -> Self {
        let mut out = Self::default();
        for f in faults.iter().filter(|f| f.active(t_s)) {
            match &f.kind {
                FaultKind::ImuSpike { rate_hz: r, accel_m_s2, gyro_rad_s } => {
                    out.spike = Some(((r / rate_hz).min(1.0), *accel_m_s2, *gyro_rad_s));
                }
                FaultKind::ImuBiasStep { gyro_rad_s, accel_m_s2 } => {
                    for k in 0..3 {
                        out.bias_step.0[k] += gyro_rad_s[k];
                        out.bias_step.1[k] += accel_m_s2[k];
                    }
                }
                FaultKind::GyroSaturation { limit_rad_s } => {
                    out.gyro_limit = Some(out.gyro_limit.map_or(*limit_rad_s, |l: f64| l.min(*limit_rad_s)));
                }
                FaultKind::MagDisturbance { heading_offset_deg, field_scale } => {
                    out.mag = Some((heading_offset_deg.to_radians(), *field_scale));
                }
                _ => {}
            }
        }
        out
    }
}

/// The IMU, magnetometer and barometer of one run.
pub struct ImuModel {
    baro_rng: SimRng,
    baro_noise: f64,
    baro_offset: f64,
    baro_walk: f64,
    /// The barometer's drift so far (m).
    baro_drift: f64,
    gyro_bias: [f64; 3],
    accel_bias: [f64; 3],
    gyro_sigma: f64,
    accel_sigma: f64,
    mag_sigma: f64,
    mag_field: [f64; 3],
    gyro_rng: SimRng,
    accel_rng: SimRng,
    mag_rng: SimRng,
    fault_rng: SimRng,
    sensor_from_body: M3,
    vib_accel: f64,
    vib_gyro: f64,
    vib_phase: [[f64; 3]; 4],
    rotor_angle: [f64; 4],
    hover_speed: f64,
    dlpf_alpha: Option<f64>,
    lp: Option<([f64; 3], [f64; 3])>,
    accel_range: f64,
    gyro_range: f64,
    dt: f64,
}

impl ImuModel {
    /// Draws this run's biases and vibration phases from `seed`; `misalignment_deg` turns the sensor's axes
    /// from the body's; `hover_speed` is the rotor speed at which the vibration has its nominal amplitude.
    pub fn new(cfg: &ImuConfig, seed: u64, misalignment_deg: [f64; 3], hover_speed: f64) -> Self {
        let mut bias = SimRng::stream(seed, "imu-bias");
        let gyro_bias = [0; 3].map(|_| cfg.gyro_bias_sigma_rad_s * bias.normal());
        let accel_bias = [0; 3].map(|_| cfg.accel_bias_sigma_m_s2 * bias.normal());
        let norm = cfg.mag_field_world.iter().map(|v| v * v).sum::<f64>().sqrt();
        let mut phase = SimRng::stream(seed, "imu-vibration");
        let vib_phase = [0; 4].map(|_| [0; 3].map(|_| phase.range(0.0, std::f64::consts::TAU)));
        let dt = 1.0 / cfg.rate_hz;
        // The body-to-sensor rotation: the transpose of the sensor's attitude in the body.
        let r = rot_zyx(misalignment_deg);
        let sensor_from_body = [0, 1, 2].map(|i| [0, 1, 2].map(|j| r[j][i]));
        Self {
            baro_rng: SimRng::stream(seed, "barometer"),
            baro_noise: cfg.baro_noise_m,
            baro_offset: cfg.baro_offset_m,
            baro_walk: cfg.baro_drift_m_per_sqrt_s,
            baro_drift: 0.0,
            gyro_bias,
            accel_bias,
            gyro_sigma: cfg.gyro_noise_density * cfg.rate_hz.sqrt(),
            accel_sigma: cfg.accel_noise_density * cfg.rate_hz.sqrt(),
            mag_sigma: cfg.mag_noise_rel * norm,
            mag_field: cfg.mag_field_world,
            gyro_rng: SimRng::stream(seed, "imu-gyro"),
            accel_rng: SimRng::stream(seed, "imu-accel"),
            mag_rng: SimRng::stream(seed, "magnetometer"),
            fault_rng: SimRng::stream(seed, "imu-faults"),
            sensor_from_body,
            // A sinusoid of amplitude A has RMS A / sqrt 2; four rotors with independent phases add in power.
            vib_accel: cfg.vibration_accel_m_s2 * std::f64::consts::SQRT_2 / 2.0,
            vib_gyro: cfg.vibration_gyro_rad_s * std::f64::consts::SQRT_2 / 2.0,
            vib_phase,
            rotor_angle: [0.0; 4],
            hover_speed: hover_speed.max(1.0),
            dlpf_alpha: (cfg.dlpf_hz > 0.0).then(|| 1.0 - (-std::f64::consts::TAU * cfg.dlpf_hz * dt).exp()),
            lp: None,
            accel_range: cfg.accel_range_m_s2,
            gyro_range: cfg.gyro_range_rad_s,
            dt,
        }
    }

    /// The biases drawn for this run (gyro, accelerometer).
    pub fn biases(&self) -> ([f64; 3], [f64; 3]) {
        (self.gyro_bias, self.accel_bias)
    }

    /// One IMU sample of the vehicle's current state, with the faults active now.
    pub fn sample(&mut self, q: &Quadrotor, time_us: u64, faults: &ImuFaults) -> ImuSample {
        let f = mul(&self.sensor_from_body, q.specific_force_body());
        let w = mul(&self.sensor_from_body, q.state.w);
        let mut vib_a = [0.0; 3];
        let mut vib_g = [0.0; 3];
        for i in 0..4 {
            let speed = q.state.rotors[i];
            self.rotor_angle[i] = (self.rotor_angle[i] + speed * self.dt) % std::f64::consts::TAU;
            let scale = (speed / self.hover_speed).powi(2);
            for k in 0..3 {
                let s = (self.rotor_angle[i] + self.vib_phase[i][k]).sin() * scale;
                vib_a[k] += self.vib_accel * s;
                vib_g[k] += self.vib_gyro * s;
            }
        }
        let mut gyro = [0.0f64; 3];
        let mut accel = [0.0f64; 3];
        for i in 0..3 {
            gyro[i] = w[i]
                + self.gyro_bias[i]
                + faults.bias_step.0[i]
                + vib_g[i]
                + self.gyro_sigma * self.gyro_rng.normal();
            accel[i] = f[i]
                + self.accel_bias[i]
                + faults.bias_step.1[i]
                + vib_a[i]
                + self.accel_sigma * self.accel_rng.normal();
        }
        // The part's digital low-pass.
        if let Some(a) = self.dlpf_alpha {
            let (g, ac) = self.lp.get_or_insert((gyro, accel));
            for i in 0..3 {
                g[i] += a * (gyro[i] - g[i]);
                ac[i] += a * (accel[i] - ac[i]);
            }
            (gyro, accel) = (*g, *ac);
        }
        if let Some((p, amp_a, amp_g)) = faults.spike
            && self.fault_rng.uniform() < p
        {
            for i in 0..3 {
                accel[i] += amp_a * self.fault_rng.range(-1.0, 1.0);
                gyro[i] += amp_g * self.fault_rng.range(-1.0, 1.0);
            }
        }
        let g_range = faults.gyro_limit.map_or(self.gyro_range, |l| l.min(self.gyro_range));
        ImuSample {
            time_us,
            gyro_rad_s: gyro.map(|v| v.clamp(-g_range, g_range) as f32),
            accel_m_s2: accel.map(|v| v.clamp(-self.accel_range, self.accel_range) as f32),
        }
    }

    /// A barometer reading `dt_s` after the previous one: the pressure altitude of the vehicle's height, the
    /// floor's pressure altitude (`imu.baro_offset_m`) added, a random-walk drift and white noise (the rotors'
    /// wash near the floor is not modelled).
    pub fn baro(&mut self, q: &Quadrotor, dt_s: f64) -> f32 {
        self.baro_drift += self.baro_walk * dt_s.max(0.0).sqrt() * self.baro_rng.normal();
        let noise = self.baro_noise * self.baro_rng.normal();
        (q.state.p[2] + self.baro_offset + self.baro_drift + noise) as f32
    }

    /// One magnetometer reading (body frame), with a disturbance of the field when one is active.
    pub fn mag(&mut self, q: &Quadrotor, faults: &ImuFaults) -> Vec3 {
        let r = q.rotation();
        let mut b = self.mag_field;
        if let Some((offset, scale)) = faults.mag {
            let (s, c) = offset.sin_cos();
            b = [scale * (c * b[0] - s * b[1]), scale * (s * b[0] + c * b[1]), scale * b[2]];
        }
        let mut m = [0.0f32; 3];
        for i in 0..3 {
            let bi = r[0][i] * b[0] + r[1][i] * b[1] + r[2][i] * b[2];
            m[i] = (bi + self.mag_sigma * self.mag_rng.normal()) as f32;
        }
        Vec3::from_array(m)
    }
}
