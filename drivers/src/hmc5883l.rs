//! Honeywell HMC5883L magnetometer on I2C: continuous measurement at 75 Hz, gain 1090 LSB/gauss.
use crate::SensorRotation;
use embedded_hal::i2c::I2c;

/// 7-bit I2C address.
pub const ADDRESS: u8 = 0x1E;
/// Registers.
pub mod reg {
    /// Configuration A (rate, averaging).
    pub const CONFIG_A: u8 = 0x00;
    /// Configuration B (gain).
    pub const CONFIG_B: u8 = 0x01;
    /// Mode.
    pub const MODE: u8 = 0x02;
    /// First data register (X MSB); order X, Z, Y.
    pub const DATA_X_MSB: u8 = 0x03;
    /// First identification register ("H43").
    pub const ID_A: u8 = 0x0A;
}
/// Counts per gauss at the configured gain.
pub const LSB_PER_GAUSS: f32 = 1090.0;

/// Errors.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Error<E> {
    /// The I2C bus failed.
    Bus(E),
    /// The identification registers did not read "H43".
    WrongDevice,
    /// An axis overflowed (the chip reports -4096).
    Overflow,
}

impl<E> From<E> for Error<E> {
    fn from(e: E) -> Self {
        Error::Bus(e)
    }
}

/// The driver; it owns its I2C bus (or a shared-bus device).
pub struct Hmc5883l<I2C> {
    i2c: I2C,
    rotation: SensorRotation,
}

impl<I2C: I2c> Hmc5883l<I2C> {
    /// A driver for a chip mounted with `rotation` relative to the body.
    pub fn new(i2c: I2C, rotation: SensorRotation) -> Self {
        Self { i2c, rotation }
    }

    /// Gives the bus back.
    pub fn release(self) -> I2C {
        self.i2c
    }

    /// Checks the identity and starts continuous measurement.
    pub fn init(&mut self) -> Result<(), Error<I2C::Error>> {
        let mut id = [0u8; 3];
        self.i2c.write_read(ADDRESS, &[reg::ID_A], &mut id)?;
        if &id != b"H43" {
            return Err(Error::WrongDevice);
        }
        self.i2c.write(ADDRESS, &[reg::CONFIG_A, 0x18])?; // 75 Hz, 1 sample
        self.i2c.write(ADDRESS, &[reg::CONFIG_B, 0x20])?; // +-1.3 gauss
        self.i2c.write(ADDRESS, &[reg::MODE, 0x00])?; // continuous
        Ok(())
    }

    /// The field in body axes (gauss).
    pub fn read_field(&mut self) -> Result<[f32; 3], Error<I2C::Error>> {
        let mut b = [0u8; 6];
        self.i2c.write_read(ADDRESS, &[reg::DATA_X_MSB], &mut b)?;
        let v = |i: usize| i16::from_be_bytes([b[i], b[i + 1]]);
        let (x, z, y) = (v(0), v(2), v(4));
        if x == -4096 || y == -4096 || z == -4096 {
            return Err(Error::Overflow);
        }
        let s = 1.0 / LSB_PER_GAUSS;
        Ok(self.rotation.apply([x as f32 * s, y as f32 * s, z as f32 * s]))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use embedded_hal_mock::eh1::i2c::{Mock, Transaction as T};

    #[test]
    fn init_and_read() {
        let ex = [
            T::write_read(ADDRESS, vec![reg::ID_A], b"H43".to_vec()),
            T::write(ADDRESS, vec![reg::CONFIG_A, 0x18]),
            T::write(ADDRESS, vec![reg::CONFIG_B, 0x20]),
            T::write(ADDRESS, vec![reg::MODE, 0x00]),
            // X = 1090 (1 G), Z = -545, Y = 218: the register order is X, Z, Y.
            T::write_read(ADDRESS, vec![reg::DATA_X_MSB], vec![0x04, 0x42, 0xFD, 0xDF, 0x00, 0xDA]),
        ];
        let mut m = Hmc5883l::new(Mock::new(&ex), SensorRotation::IDENTITY);
        m.init().unwrap();
        let f = m.read_field().unwrap();
        assert!((f[0] - 1.0).abs() < 1e-6 && (f[1] - 0.2).abs() < 1e-6 && (f[2] + 0.5).abs() < 1e-6, "{f:?}");
        m.release().done();
    }

    #[test]
    fn wrong_id_and_overflow() {
        let ex = [T::write_read(ADDRESS, vec![reg::ID_A], b"XYZ".to_vec())];
        let mut m = Hmc5883l::new(Mock::new(&ex), SensorRotation::IDENTITY);
        assert_eq!(m.init(), Err(Error::WrongDevice));
        m.release().done();
        let ex = [T::write_read(ADDRESS, vec![reg::DATA_X_MSB], vec![0xF0, 0x00, 0, 0, 0, 0])];
        let mut m = Hmc5883l::new(Mock::new(&ex), SensorRotation::IDENTITY);
        assert_eq!(m.read_field(), Err(Error::Overflow));
        m.release().done();
    }
}
