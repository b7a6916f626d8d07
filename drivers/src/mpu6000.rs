//! InvenSense MPU-6000 on SPI: gyro (+-2000 deg/s) and accelerometer (+-8 g) at a 1 kHz sample rate with the
//! 98 Hz digital low-pass filter, read as one 14-byte burst.
use crate::SensorRotation;
use embedded_hal::delay::DelayNs;
use embedded_hal::spi::{Operation, SpiDevice};

/// Registers used.
pub mod reg {
    /// Sample-rate divider.
    pub const SMPLRT_DIV: u8 = 0x19;
    /// Digital low-pass filter configuration.
    pub const CONFIG: u8 = 0x1A;
    /// Gyro full scale.
    pub const GYRO_CONFIG: u8 = 0x1B;
    /// Accelerometer full scale.
    pub const ACCEL_CONFIG: u8 = 0x1C;
    /// First data register (ACCEL_XOUT_H); 14 bytes: accel, temperature, gyro.
    pub const ACCEL_XOUT_H: u8 = 0x3B;
    /// User control (I2C interface disable).
    pub const USER_CTRL: u8 = 0x6A;
    /// Power management 1 (reset, clock source).
    pub const PWR_MGMT_1: u8 = 0x6B;
    /// Identity register.
    pub const WHO_AM_I: u8 = 0x75;
}

/// The value of `WHO_AM_I`.
pub const DEVICE_ID: u8 = 0x68;
/// Gyro sensitivity at +-2000 deg/s (LSB per deg/s).
pub const GYRO_LSB_PER_DEG_S: f32 = 16.4;
/// Accelerometer sensitivity at +-8 g (LSB per g).
pub const ACCEL_LSB_PER_G: f32 = 4096.0;
const STANDARD_GRAVITY: f32 = 9.80665;

/// Errors.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Error<E> {
    /// The SPI bus failed.
    Bus(E),
    /// `WHO_AM_I` did not read 0x68: wrong chip or no chip.
    WrongDevice(u8),
}

impl<E> From<E> for Error<E> {
    fn from(e: E) -> Self {
        Error::Bus(e)
    }
}

/// One reading, in body axes.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Reading {
    /// Angular rate (rad/s).
    pub gyro_rad_s: [f32; 3],
    /// Specific force (m/s^2).
    pub accel_m_s2: [f32; 3],
    /// Die temperature (deg C).
    pub temperature_c: f32,
}

/// The driver. It owns its SPI device (bus plus chip select).
pub struct Mpu6000<SPI> {
    spi: SPI,
    rotation: SensorRotation,
}

impl<SPI: SpiDevice> Mpu6000<SPI> {
    /// A driver for a chip mounted with `rotation` relative to the body.
    pub fn new(spi: SPI, rotation: SensorRotation) -> Self {
        Self { spi, rotation }
    }

    /// Gives the SPI device back.
    pub fn release(self) -> SPI {
        self.spi
    }

    fn write(&mut self, reg: u8, value: u8) -> Result<(), Error<SPI::Error>> {
        self.spi.write(&[reg & 0x7F, value])?;
        Ok(())
    }

    fn read(&mut self, reg: u8, buf: &mut [u8]) -> Result<(), Error<SPI::Error>> {
        self.spi.transaction(&mut [Operation::Write(&[reg | 0x80]), Operation::Read(buf)])?;
        Ok(())
    }

    /// Resets and configures the chip; fails if it is not an MPU-6000.
    pub fn init(&mut self, delay: &mut impl DelayNs) -> Result<(), Error<SPI::Error>> {
        self.write(reg::PWR_MGMT_1, 0x80)?; // device reset
        delay.delay_ms(100);
        self.write(reg::PWR_MGMT_1, 0x03)?; // wake, clock from the Z gyro PLL
        self.write(reg::USER_CTRL, 0x10)?; // SPI only
        let mut id = [0u8];
        self.read(reg::WHO_AM_I, &mut id)?;
        if id[0] != DEVICE_ID {
            return Err(Error::WrongDevice(id[0]));
        }
        self.write(reg::SMPLRT_DIV, 0x00)?; // 1 kHz
        self.write(reg::CONFIG, 0x02)?; // DLPF 98 Hz
        self.write(reg::GYRO_CONFIG, 0x18)?; // +-2000 deg/s
        self.write(reg::ACCEL_CONFIG, 0x10)?; // +-8 g
        Ok(())
    }

    /// Reads accelerometer, temperature and gyro in one burst.
    pub fn read_sample(&mut self) -> Result<Reading, Error<SPI::Error>> {
        let mut b = [0u8; 14];
        self.read(reg::ACCEL_XOUT_H, &mut b)?;
        Ok(decode(&b, &self.rotation))
    }
}

/// Converts a 14-byte burst (big endian: accel x, y, z, temperature, gyro x, y, z) to SI units in body axes.
pub fn decode(b: &[u8; 14], rotation: &SensorRotation) -> Reading {
    let w = |i: usize| i16::from_be_bytes([b[i], b[i + 1]]) as f32;
    let a = STANDARD_GRAVITY / ACCEL_LSB_PER_G;
    let g = core::f32::consts::PI / 180.0 / GYRO_LSB_PER_DEG_S;
    Reading {
        accel_m_s2: rotation.apply([w(0) * a, w(2) * a, w(4) * a]),
        temperature_c: w(6) / 340.0 + 36.53,
        gyro_rad_s: rotation.apply([w(8) * g, w(10) * g, w(12) * g]),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use embedded_hal_mock::eh1::delay::NoopDelay;
    use embedded_hal_mock::eh1::spi::{Mock, Transaction as T};

    fn write(reg: u8, v: u8) -> [T<u8>; 3] {
        [T::transaction_start(), T::write_vec(vec![reg, v]), T::transaction_end()]
    }

    fn read(reg: u8, data: Vec<u8>) -> [T<u8>; 4] {
        [T::transaction_start(), T::write_vec(vec![reg | 0x80]), T::read_vec(data), T::transaction_end()]
    }

    #[test]
    fn init_configures_the_chip() {
        let mut ex = Vec::new();
        ex.extend(write(reg::PWR_MGMT_1, 0x80));
        ex.extend(write(reg::PWR_MGMT_1, 0x03));
        ex.extend(write(reg::USER_CTRL, 0x10));
        ex.extend(read(reg::WHO_AM_I, vec![0x68]));
        ex.extend(write(reg::SMPLRT_DIV, 0x00));
        ex.extend(write(reg::CONFIG, 0x02));
        ex.extend(write(reg::GYRO_CONFIG, 0x18));
        ex.extend(write(reg::ACCEL_CONFIG, 0x10));
        let mut imu = Mpu6000::new(Mock::new(&ex), SensorRotation::IDENTITY);
        imu.init(&mut NoopDelay::new()).unwrap();
        imu.release().done();
    }

    #[test]
    fn wrong_chip_is_reported() {
        let mut ex = Vec::new();
        ex.extend(write(reg::PWR_MGMT_1, 0x80));
        ex.extend(write(reg::PWR_MGMT_1, 0x03));
        ex.extend(write(reg::USER_CTRL, 0x10));
        ex.extend(read(reg::WHO_AM_I, vec![0x70]));
        let mut imu = Mpu6000::new(Mock::new(&ex), SensorRotation::IDENTITY);
        assert_eq!(imu.init(&mut NoopDelay::new()), Err(Error::WrongDevice(0x70)));
        imu.release().done();
    }

    #[test]
    fn burst_is_scaled_to_si_in_body_axes() {
        // Level and still: accel z = +1 g (4096), gyro x = 16.4 LSB (1 deg/s).
        let data = vec![0, 0, 0, 0, 0x10, 0x00, 0, 0, 0, 16, 0, 0, 0, 0];
        let mut imu = Mpu6000::new(Mock::new(&read(reg::ACCEL_XOUT_H, data)), SensorRotation::IDENTITY);
        let r = imu.read_sample().unwrap();
        assert!((r.accel_m_s2[2] - 9.80665).abs() < 1e-5);
        assert_eq!(r.accel_m_s2[0], 0.0);
        // 16 LSB at 16.4 LSB/(deg/s).
        assert!((r.gyro_rad_s[0] - (16.0 / 16.4f32).to_radians()).abs() < 1e-6);
        assert!((r.temperature_c - 36.53).abs() < 1e-4);
        imu.release().done();
        // Mounted upside down: z flips.
        let raw = [0, 0, 0, 0, 0x10, 0x00, 0, 0, 0, 0, 0, 0, 0, 0];
        assert!(decode(&raw, &SensorRotation::ROLL_180).accel_m_s2[2] < 0.0);
    }
}
