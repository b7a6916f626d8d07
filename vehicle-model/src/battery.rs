//! A lithium-polymer battery: open-circuit voltage from the state of charge, sag across an internal resistance
//! with the current the motors draw, charge drawn over time.
//!
//! The motors' electrical power is their shaft power (each rotor's drag torque `k_tau w^2` times `w`) over
//! the drive's efficiency (ESC and motor together, 0.5-0.8 for small multirotor drives); the current is that
//! power over the terminal voltage, solved with the sag (`V = E - I R`, `I = P / V`: the smaller root of
//! `I^2 R - E I + P = 0`). The open-circuit voltage per cell follows a common LiPo discharge curve (4.20 V full,
//! about 3.7 V at half, 3.3 V empty, steep at both ends; points read off manufacturers' 0.2C curves), linear
//! between the points.

/// Open-circuit voltage of one cell (V) at states of charge 0, 0.05, 0.1, 0.2, ..., 0.9, 1.
const OCV: [(f64, f64); 12] = [
    (0.00, 3.27),
    (0.05, 3.50),
    (0.10, 3.61),
    (0.20, 3.69),
    (0.30, 3.73),
    (0.40, 3.77),
    (0.50, 3.80),
    (0.60, 3.84),
    (0.70, 3.90),
    (0.80, 3.98),
    (0.90, 4.07),
    (1.00, 4.20),
];

/// A cell's open-circuit voltage at state of charge `soc` (0-1).
pub fn cell_ocv(soc: f64) -> f64 {
    let s = soc.clamp(0.0, 1.0);
    for w in OCV.windows(2) {
        let ((s0, v0), (s1, v1)) = (w[0], w[1]);
        if s <= s1 {
            return v0 + (v1 - v0) * (s - s0) / (s1 - s0);
        }
    }
    OCV[OCV.len() - 1].1
}

/// The battery's parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BatteryParams {
    /// Cells in series.
    pub cells: u8,
    /// Capacity (mAh).
    pub capacity_mah: f64,
    /// Internal resistance of the pack, wiring and connector (ohm).
    pub resistance_ohm: f64,
    /// Shaft power over electrical power of the drive (ESCs and motors).
    pub drive_efficiency: f64,
    /// Current the electronics draw besides the motors (A).
    pub idle_current_a: f64,
}

/// A battery's state.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Battery {
    /// Its parameters.
    pub params: BatteryParams,
    /// State of charge (0-1).
    pub soc: f64,
    /// The current drawn at the last step (A).
    pub current_a: f64,
    /// The terminal voltage at the last step (V).
    pub voltage_v: f64,
}

impl Battery {
    /// A battery at state of charge `soc`, at rest.
    pub fn new(params: BatteryParams, soc: f64) -> Self {
        let soc = soc.clamp(0.0, 1.0);
        let e = params.cells as f64 * cell_ocv(soc);
        Self { params, soc, current_a: 0.0, voltage_v: e }
    }

    /// The open-circuit voltage now (V).
    pub fn open_circuit_v(&self) -> f64 {
        self.params.cells as f64 * cell_ocv(self.soc)
    }

    /// Draws `shaft_power_w` (the motors' mechanical power) for `dt_s`: the current, the sag and the charge.
    /// A demand beyond what the pack can deliver (`P > E^2 / 4R`) is capped there (the voltage halves).
    pub fn draw(&mut self, shaft_power_w: f64, dt_s: f64) {
        let p = self.params;
        let e = self.open_circuit_v();
        let r = p.resistance_ohm.max(1e-9);
        let power = shaft_power_w.max(0.0) / p.drive_efficiency.max(1e-3) + p.idle_current_a * e;
        let disc = (e * e - 4.0 * r * power).max(0.0);
        let i = (e - disc.sqrt()) / (2.0 * r);
        self.current_a = i;
        self.voltage_v = e - i * r;
        self.soc = (self.soc - i * dt_s / (p.capacity_mah * 3.6)).max(0.0);
    }
}

/// The motors' shaft power (W): each rotor's drag torque times its speed.
pub fn shaft_power_w(k_tau: f64, rotors: [f64; 4]) -> f64 {
    rotors.iter().map(|w| k_tau * w.abs().powi(3)).sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pack() -> BatteryParams {
        BatteryParams {
            cells: 3,
            capacity_mah: 1000.0,
            resistance_ohm: 0.05,
            drive_efficiency: 0.6,
            idle_current_a: 0.3,
        }
    }

    #[test]
    fn the_discharge_curve_is_a_lipo_s() {
        assert_eq!(cell_ocv(1.0), 4.2);
        assert_eq!(cell_ocv(0.0), 3.27);
        assert!((cell_ocv(0.5) - 3.8).abs() < 1e-12);
        assert!((cell_ocv(0.25) - 3.71).abs() < 1e-12, "between the points");
        assert_eq!(cell_ocv(1.5), 4.2);
        assert_eq!(cell_ocv(-1.0), 3.27);
        for k in 0..100 {
            assert!(cell_ocv(k as f64 / 100.0) < cell_ocv((k + 1) as f64 / 100.0));
        }
    }

    #[test]
    fn the_voltage_sags_with_the_current_and_the_charge_goes_with_the_ampere_hours() {
        let mut b = Battery::new(pack(), 1.0);
        assert!((b.voltage_v - 12.6).abs() < 1e-12);
        // 60 W of shaft power at 60 %: 100 W, plus 0.3 A of electronics (3.8 W): 8.53 A at 12.17 V.
        let e = b.open_circuit_v();
        b.draw(60.0, 0.001);
        assert!((b.voltage_v - (e - b.current_a * 0.05)).abs() < 1e-9, "V = E - I R");
        assert!((b.voltage_v * b.current_a - (100.0 + 0.3 * e)).abs() < 1e-6, "P = V I");
        assert!((b.current_a - 8.525).abs() < 0.005, "{}", b.current_a);
        // Twice the power: about twice the sag.
        let sag1 = e - b.voltage_v;
        let e = b.open_circuit_v();
        b.draw(120.0, 0.001);
        let sag2 = e - b.voltage_v;
        assert!(sag2 > 1.9 * sag1 && sag2 < 2.2 * sag1, "{sag1} {sag2}");
        // 10 A for 36 s is 100 mAh: a tenth of the pack.
        let mut b = Battery::new(BatteryParams { drive_efficiency: 1.0, idle_current_a: 0.0, ..pack() }, 1.0);
        let soc0 = b.soc;
        for _ in 0..36_000 {
            // The power that draws 10 A at the present terminal voltage.
            let p = 10.0 * (b.open_circuit_v() - 10.0 * 0.05);
            b.draw(p, 0.001);
        }
        assert!((soc0 - b.soc - 0.1).abs() < 1e-6, "{}", soc0 - b.soc);
        // More than the pack can give: capped, never NaN.
        let e = b.open_circuit_v();
        b.draw(1e6, 0.001);
        assert!(b.voltage_v.is_finite() && (b.voltage_v - e / 2.0).abs() < 1e-6, "{} {e}", b.voltage_v);
    }

    #[test]
    fn the_shaft_power_is_the_drag_torque_times_the_speed() {
        assert!((shaft_power_w(1e-7, [500.0; 4]) - 4.0 * 1e-7 * 1.25e8).abs() < 1e-9);
        assert_eq!(shaft_power_w(1e-7, [0.0; 4]), 0.0);
    }
}
