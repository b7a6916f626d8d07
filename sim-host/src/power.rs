//! The simulated flight battery (`[battery_model]` of a scenario): the pack's charge and sag under the motors'
//! load (`vehicle_model::battery`), what the sag does to the motors' top speed, and the voltage and current
//! readings the flight code gets (`control_core::battery`), with their noise.
use crate::rng::SimRng;
use control_core::battery::BatteryReading;
use serde::{Deserialize, Serialize};
use vehicle_model::battery::{Battery, BatteryParams, shaft_power_w};

/// The scenario's `[battery_model]`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct BatteryModelConfig {
    /// Whether the vehicle flies on a simulated battery, read by the flight code. Without, the motors have
    /// their full speed and the flight code no reading (the paper's vehicle).
    pub enabled: bool,
    /// Cells in series.
    pub cells: u8,
    /// Capacity (mAh).
    pub capacity_mah: f64,
    /// Internal resistance of the pack and wiring (ohm).
    pub resistance_ohm: f64,
    /// Shaft power over electrical power of the drive (ESCs and motors).
    pub drive_efficiency: f64,
    /// Current of the electronics besides the motors (A).
    pub idle_current_a: f64,
    /// State of charge at the start (0-1).
    pub initial_charge: f64,
    /// Readings a second.
    pub rate_hz: f64,
    /// Noise of a voltage reading (V, 1 sigma).
    pub voltage_noise_v: f64,
    /// Whether the board measures the current.
    pub current_sensor: bool,
    /// Noise of a current reading (A, 1 sigma).
    pub current_noise_a: f64,
    /// Whether the motors' top speed falls with the voltage (a brushless motor's speed is its Kv times the
    /// voltage): at the pack's full open-circuit voltage they reach the vehicle's `motor_speed_max_rad_s`.
    pub sag_limits_motors: bool,
}

impl Default for BatteryModelConfig {
    fn default() -> Self {
        Self {
            enabled: false,
            cells: 3,
            capacity_mah: 1300.0,
            resistance_ohm: 0.04,
            drive_efficiency: 0.6,
            idle_current_a: 0.5,
            initial_charge: 1.0,
            rate_hz: 50.0,
            voltage_noise_v: 0.02,
            current_sensor: true,
            current_noise_a: 0.1,
            sag_limits_motors: true,
        }
    }
}

/// The battery of a run.
pub struct Power {
    cfg: BatteryModelConfig,
    battery: Battery,
    /// The vehicle's configured top rotor speed (rad/s).
    max_speed: f64,
    full_v: f64,
    next_reading_us: u64,
    rng: SimRng,
    /// The lowest terminal voltage seen (V).
    pub min_voltage_v: f64,
}

impl Power {
    /// The battery of a scenario, seeded; `None` when it has none.
    pub fn new(cfg: &BatteryModelConfig, max_speed_rad_s: f64, seed: u64) -> Option<Self> {
        if !cfg.enabled {
            return None;
        }
        let params = BatteryParams {
            cells: cfg.cells,
            capacity_mah: cfg.capacity_mah,
            resistance_ohm: cfg.resistance_ohm,
            drive_efficiency: cfg.drive_efficiency,
            idle_current_a: cfg.idle_current_a,
        };
        let battery = Battery::new(params, cfg.initial_charge);
        Some(Self {
            cfg: cfg.clone(),
            battery,
            max_speed: max_speed_rad_s,
            full_v: cfg.cells as f64 * vehicle_model::battery::cell_ocv(1.0),
            next_reading_us: 0,
            rng: SimRng::stream(seed, "battery"),
            min_voltage_v: battery.voltage_v,
        })
    }

    /// One physics step of `dt_s` with the rotors at `rotors` (rad/s) and drag-torque coefficient `k_tau`:
    /// the charge drawn. Returns the motors' top speed now (rad/s).
    pub fn step(&mut self, k_tau: f64, rotors: [f64; 4], dt_s: f64) -> f64 {
        self.battery.draw(shaft_power_w(k_tau, rotors), dt_s);
        self.min_voltage_v = self.min_voltage_v.min(self.battery.voltage_v);
        if self.cfg.sag_limits_motors {
            self.max_speed * (self.battery.voltage_v / self.full_v).min(1.0)
        } else {
            self.max_speed
        }
    }

    /// The reading due at `now_us`, if one is (at `rate_hz`).
    pub fn reading(&mut self, now_us: u64) -> Option<BatteryReading> {
        if now_us < self.next_reading_us {
            return None;
        }
        self.next_reading_us = now_us + (1e6 / self.cfg.rate_hz).round() as u64;
        let v = self.battery.voltage_v + self.cfg.voltage_noise_v * self.rng.normal();
        let i = self
            .cfg
            .current_sensor
            .then(|| self.battery.current_a + self.cfg.current_noise_a * self.rng.normal());
        Some(BatteryReading { voltage_v: v as f32, current_a: i.map(|i| i as f32) })
    }

    /// The state of charge now (0-1).
    pub fn charge(&self) -> f64 {
        self.battery.soc
    }
}
