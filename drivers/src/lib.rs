//! Drivers of the autopilot board's sensors and actuators, generic over the embedded-hal 1.0 traits and
//! tested on the host with embedded-hal-mock. Each driver owns its bus (or bus device).
//!
//! - [`mpu6000`]: InvenSense MPU-6000 6-axis IMU on SPI (gyro and accelerometer, SI units, body axes).
//! - [`hmc5883l`]: Honeywell HMC5883L 3-axis magnetometer on I2C.
//! - [`blctrl`]: the I2C brushless speed controllers of the paper's platform ("BL-Ctrl" protocol: one
//!   setpoint byte written to each motor's address).
//! - [`dshot`]: DShot150/300/600 ESCs on timer channels (frames, the DMA burst buffer, throttle, arming).
//! - [`crsf`]: a CRSF (ExpressLRS, TBS Crossfire) RC receiver on a UART: channels, switches, its failsafe.
//! - [`SensorRotation`]: how a chip is mounted relative to the body frame (FLU).
#![cfg_attr(not(test), no_std)]
#![forbid(unsafe_code)]
#![warn(missing_docs)]
#![cfg_attr(not(test), deny(clippy::unwrap_used, clippy::expect_used, clippy::panic))]
// `!(x > 0.0)` deliberately rejects NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod blctrl;
pub mod crsf;
pub mod dshot;
pub mod hmc5883l;
pub mod mpu6000;

/// A chip's mounting: a signed permutation taking sensor axes to body axes (FLU).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SensorRotation {
    /// Rows: body x, y, z as signed sensor axes.
    pub m: [[i8; 3]; 3],
}

impl SensorRotation {
    /// Sensor axes are the body axes.
    pub const IDENTITY: SensorRotation = SensorRotation { m: [[1, 0, 0], [0, 1, 0], [0, 0, 1]] };
    /// Chip turned 90 degrees counter-clockwise (seen from above) on the board.
    pub const YAW_90: SensorRotation = SensorRotation { m: [[0, -1, 0], [1, 0, 0], [0, 0, 1]] };
    /// Chip turned 180 degrees on the board.
    pub const YAW_180: SensorRotation = SensorRotation { m: [[-1, 0, 0], [0, -1, 0], [0, 0, 1]] };
    /// Chip turned 270 degrees counter-clockwise on the board.
    pub const YAW_270: SensorRotation = SensorRotation { m: [[0, 1, 0], [-1, 0, 0], [0, 0, 1]] };
    /// Chip upside down (rolled 180 degrees).
    pub const ROLL_180: SensorRotation = SensorRotation { m: [[1, 0, 0], [0, -1, 0], [0, 0, -1]] };

    /// Sensor-frame vector to body frame.
    pub fn apply(&self, v: [f32; 3]) -> [f32; 3] {
        let row = |r: [i8; 3]| r[0] as f32 * v[0] + r[1] as f32 * v[1] + r[2] as f32 * v[2];
        [row(self.m[0]), row(self.m[1]), row(self.m[2])]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rotations_are_proper() {
        for r in [
            SensorRotation::IDENTITY,
            SensorRotation::YAW_90,
            SensorRotation::YAW_180,
            SensorRotation::YAW_270,
            SensorRotation::ROLL_180,
        ] {
            let x = r.apply([1.0, 0.0, 0.0]);
            let y = r.apply([0.0, 1.0, 0.0]);
            let z = r.apply([0.0, 0.0, 1.0]);
            // Right-handed: x cross y = z.
            let c = [x[1] * y[2] - x[2] * y[1], x[2] * y[0] - x[0] * y[2], x[0] * y[1] - x[1] * y[0]];
            assert_eq!(c, z, "{r:?}");
        }
        // Turned 90 degrees: the chip's x axis points to the body's left.
        assert_eq!(SensorRotation::YAW_90.apply([1.0, 0.0, 0.0]), [0.0, 1.0, 0.0]);
    }
}
