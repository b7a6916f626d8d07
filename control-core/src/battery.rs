//! The flight battery: its voltage (and current, where the board measures it) low-passed into a level, a
//! warning when low and a landing when critical (docs/architecture.md, "The battery").
//!
//! Voltage sag under load is the most common cause of a forced landing: a pack at 3.6 V per cell at rest reads
//! 3.3 V during a climb. The level therefore comes from the voltage low-passed over `battery.filter_tau_s` and,
//! where the current is measured, with the sag across `battery.resistance_ohm` added back (`V + I R`: the
//! open-circuit voltage, which the charge left decides). The level only goes down while the motors run: a
//! pack's voltage recovers when the load drops (on the descent of the very landing it triggered), and that
//! must not cancel the landing. It starts again from what the pack reads when disarmed.
use crate::params::{ParamError, check};

/// One reading of the battery.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct BatteryReading {
    /// Terminal voltage (V).
    pub voltage_v: f32,
    /// Current drawn (A), where the board has a sensor.
    pub current_a: Option<f32>,
}

/// What the flight code makes of the battery.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum BatteryLevel {
    /// Above the warning level.
    Ok,
    /// Below `battery.warn_cell_v`: a warning; arming refused.
    Low,
    /// Below `battery.critical_cell_v`: landing.
    Critical,
}

/// The battery as the vehicle reports it (the downlink's `Battery`, once a second).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct BatteryStatus {
    /// The last reading's voltage (V).
    pub voltage_v: f32,
    /// The low-passed voltage with the sag added back, per cell (V): what the level comes from.
    pub cell_v: f32,
    /// The last reading's current (A), where measured.
    pub current_a: Option<f32>,
    /// The level.
    pub level: BatteryLevel,
}

params_struct! {
    /// The flight battery's monitoring (`crate::battery`).
    #[derive(Clone, Copy, Debug, PartialEq)]
    #[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
    #[cfg_attr(feature = "serde", serde(default, deny_unknown_fields))]
    #[cfg_attr(feature = "defmt", derive(defmt::Format))]
    pub struct BatteryParams in ["battery"] {
        /// Cells in series; 0: the battery is not monitored (a vehicle without a voltage sensor).
        cells: u8 = 0, { >= 0, <= 14 } "";
        /// Below this per cell (low-passed, sag added back) a warning, and arming is refused (V). A LiPo cell
        /// at rest reads about 3.6 V with 10-15 % of its charge left.
        warn_cell_v: f32 = 3.6, { >= 2.8, <= 4.4 } "V";
        /// Below this per cell: land (V); under `warn_cell_v`. About 5 % left at rest: enough to land; without
        /// a current sensor the reading is the loaded voltage, some 0.1-0.2 V lower, so the landing starts
        /// earlier.
        critical_cell_v: f32 = 3.5, { >= 2.8, <= 4.4 } "V";
        /// Time constant of the voltage's low-pass (s).
        filter_tau_s: f32 = 2.0, { > 0.0, <= 60.0 } "s";
        /// The pack's and the wiring's resistance, to add the sag back where the current is measured (ohm).
        resistance_ohm: f32 = 0.0, { >= 0.0, <= 1.0 } "ohm";
    }
}

impl BatteryParams {
    pub(crate) fn validate(&self) -> Result<(), ParamError> {
        self.check_declared(0)?;
        check(self.critical_cell_v < self.warn_cell_v, "battery.critical_cell_v", "must be under warn_cell_v")
    }
}

/// The battery's monitor.
#[derive(Clone, Copy, Debug, Default)]
pub struct BatteryMonitor {
    /// The low-passed per-cell voltage with the sag added back, and when it was last updated (us).
    filtered: Option<(f32, u64)>,
    last: Option<BatteryReading>,
    level: Option<BatteryLevel>,
    /// Readings refused as impossible (not finite, negative).
    pub rejected: u32,
}

impl BatteryMonitor {
    /// Takes this step's reading, if any; `under_load`: the motors run (the level may only fall then). Returns
    /// the level (`None` when not monitored or before the first reading).
    pub fn update(
        &mut self,
        reading: Option<BatteryReading>,
        now_us: u64,
        under_load: bool,
        p: &BatteryParams,
    ) -> Option<BatteryLevel> {
        if p.cells == 0 {
            return None;
        }
        if let Some(r) = reading {
            let ok = r.voltage_v.is_finite() && r.voltage_v >= 0.0 && r.current_a.is_none_or(f32::is_finite);
            if ok {
                let v =
                    (r.voltage_v + r.current_a.unwrap_or(0.0).max(0.0) * p.resistance_ohm) / p.cells as f32;
                let f = match self.filtered {
                    Some((f, t)) => {
                        let a = geometry::clamp_finite(
                            now_us.saturating_sub(t) as f32 * 1e-6 / p.filter_tau_s,
                            0.0,
                            1.0,
                        );
                        f + (v - f) * a
                    }
                    None => v,
                };
                self.filtered = Some((f, now_us));
                self.last = Some(r);
                let now = if f < p.critical_cell_v {
                    BatteryLevel::Critical
                } else if f < p.warn_cell_v {
                    BatteryLevel::Low
                } else {
                    BatteryLevel::Ok
                };
                // Under load the level only falls; at rest it is what the pack reads.
                self.level = Some(match self.level {
                    Some(l) if under_load => l.max(now),
                    _ => now,
                });
            } else {
                self.rejected = self.rejected.saturating_add(1);
            }
        }
        self.level
    }

    /// What the vehicle reports, once a reading arrived.
    pub fn status(&self) -> Option<BatteryStatus> {
        let (last, (cell_v, _), level) = (self.last?, self.filtered?, self.level?);
        Some(BatteryStatus { voltage_v: last.voltage_v, cell_v, current_a: last.current_a, level })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn p() -> BatteryParams {
        BatteryParams { cells: 4, resistance_ohm: 0.05, ..Default::default() }
    }

    fn at(m: &mut BatteryMonitor, v: f32, i: Option<f32>, t_us: u64, load: bool) -> Option<BatteryLevel> {
        m.update(Some(BatteryReading { voltage_v: v, current_a: i }), t_us, load, &p())
    }

    #[test]
    fn levels_come_from_the_low_passed_voltage_with_the_sag_added_back() {
        let mut m = BatteryMonitor::default();
        assert_eq!(m.update(None, 0, false, &p()), None, "nothing read yet");
        assert_eq!(at(&mut m, 16.0, None, 0, false), Some(BatteryLevel::Ok));
        assert_eq!(m.status().unwrap().cell_v, 4.0);
        // A 0.5 s sag to 3.3 V per cell under a 20 A climb, with 0.05 ohm: 1 V of it is the sag, added back
        // (3.55 V: low, not critical), and the 2 s low-pass takes a quarter of the step.
        let mut t = 0;
        for _ in 0..25 {
            t += 20_000;
            at(&mut m, 13.2, Some(20.0), t, true);
        }
        let s = m.status().unwrap();
        assert!(s.cell_v > 3.6, "{s:?}");
        assert_eq!(s.level, BatteryLevel::Ok);
        // Held: it settles at 3.55 V per cell: low.
        for _ in 0..1000 {
            t += 20_000;
            at(&mut m, 13.2, Some(20.0), t, true);
        }
        assert_eq!(m.status().unwrap().level, BatteryLevel::Low);
        assert!((m.status().unwrap().cell_v - 3.55).abs() < 1e-3);
        // Lower: critical. The load drops and the voltage recovers: under load it stays critical.
        for _ in 0..1000 {
            t += 20_000;
            at(&mut m, 12.0, Some(20.0), t, true);
        }
        assert_eq!(m.status().unwrap().level, BatteryLevel::Critical);
        for _ in 0..1000 {
            t += 20_000;
            at(&mut m, 15.0, Some(2.0), t, true);
        }
        assert_eq!(m.status().unwrap().level, BatteryLevel::Critical);
        // At rest (disarmed) it reads what the pack reads.
        t += 20_000;
        assert_eq!(at(&mut m, 15.0, Some(0.5), t, false), Some(BatteryLevel::Ok));
        // Without a current sensor the sag is not added back.
        let mut m = BatteryMonitor::default();
        at(&mut m, 12.8, None, 0, false);
        assert_eq!(m.status().unwrap().level, BatteryLevel::Critical);
    }

    #[test]
    fn impossible_readings_are_counted_and_ignored_and_an_unmonitored_battery_gives_nothing() {
        let mut m = BatteryMonitor::default();
        at(&mut m, 16.0, None, 0, false);
        for v in [f32::NAN, -1.0, f32::INFINITY] {
            assert_eq!(at(&mut m, v, None, 1000, false), Some(BatteryLevel::Ok));
        }
        assert_eq!(at(&mut m, 16.0, Some(f32::NAN), 2000, false), Some(BatteryLevel::Ok));
        assert_eq!(m.rejected, 4);
        assert_eq!(m.status().unwrap().voltage_v, 16.0);
        let off = BatteryParams { cells: 0, ..p() };
        let mut m = BatteryMonitor::default();
        assert_eq!(m.update(Some(BatteryReading { voltage_v: 1.0, current_a: None }), 0, true, &off), None);
        assert_eq!(m.status(), None);
        // The warning must lie above the critical level.
        let mut q = FlightParamsProbe::paper();
        q.battery.critical_cell_v = q.battery.warn_cell_v;
        assert_eq!(q.validate().unwrap_err().field, "battery.critical_cell_v");
    }

    #[test]
    fn the_low_pass_follows_its_time_constant_and_the_levels_start_at_their_thresholds() {
        // One reading 0.2 s after the first with the 2 s time constant moves the level a tenth of the way.
        let mut m = BatteryMonitor::default();
        at(&mut m, 16.0, None, 0, false);
        at(&mut m, 14.2, None, 200_000, false);
        let want = 4.0 + (3.55 - 4.0) * 0.1;
        assert!((m.status().unwrap().cell_v - want).abs() < 1e-5, "{:?} against {want}", m.status());
        // Exactly at a threshold is the level above it (dividing by the 4 cells is exact in f32).
        let first = |v: f32| {
            BatteryMonitor::default().update(
                Some(BatteryReading { voltage_v: v, current_a: None }),
                0,
                false,
                &p(),
            )
        };
        assert_eq!(first(4.0 * p().warn_cell_v), Some(BatteryLevel::Ok));
        assert_eq!(first(4.0 * p().critical_cell_v), Some(BatteryLevel::Low));
        assert_eq!(first(4.0 * p().critical_cell_v - 0.01), Some(BatteryLevel::Critical));
    }

    use crate::params::FlightParams as FlightParamsProbe;
}
