//! The I2C brushless motor speed controllers of the paper's platform (the "BL-Ctrl" protocol of the
//! MikroKopter-style ESCs): each controller has its own address, `0x29 + i` (7-bit; `0x52 + 2i` as an 8-bit
//! write address), and takes one byte per command: 0 stops the motor, 255 is full throttle. A controller that
//! receives no command for a while stops its motor on its own.
use embedded_hal::i2c::I2c;

/// 7-bit addresses of motors M1..M4.
pub const DEFAULT_ADDRESSES: [u8; 4] = [0x29, 0x2A, 0x2B, 0x2C];

/// A command write failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct MotorError<E> {
    /// Index (0..4) of the first motor whose write failed.
    pub motor: u8,
    /// The bus error.
    pub error: E,
}

/// The four speed controllers on one I2C bus.
pub struct BlCtrl<I2C> {
    i2c: I2C,
    addresses: [u8; 4],
}

impl<I2C: I2c> BlCtrl<I2C> {
    /// Controllers at `addresses` (7-bit), motor M1 first.
    pub fn new(i2c: I2C, addresses: [u8; 4]) -> Self {
        Self { i2c, addresses }
    }

    /// Gives the bus back.
    pub fn release(self) -> I2C {
        self.i2c
    }

    /// Writes one command byte to each controller. Every motor is written even if an earlier write failed,
    /// so that one dead controller does not starve the others; the first failure is returned.
    pub fn set(&mut self, commands: [u8; 4]) -> Result<(), MotorError<I2C::Error>> {
        let mut first = None;
        for (i, (&addr, &c)) in self.addresses.iter().zip(commands.iter()).enumerate() {
            if let Err(e) = self.i2c.write(addr, &[c]) {
                first.get_or_insert(MotorError { motor: i as u8, error: e });
            }
        }
        first.map_or(Ok(()), Err)
    }

    /// Stops all motors.
    pub fn stop(&mut self) -> Result<(), MotorError<I2C::Error>> {
        self.set([0; 4])
    }
}

/// The command byte for a rotor speed, assuming the controller's speed is proportional to its command up to
/// `max_rad_s` at 255 (calibrate `max_rad_s` per airframe). Zero and below stop the motor; NaN stops it too.
pub fn command_for_speed(speed_rad_s: f32, max_rad_s: f32) -> u8 {
    if !(speed_rad_s > 0.0) || !(max_rad_s > 0.0) {
        return 0;
    }
    let c = speed_rad_s / max_rad_s * 255.0 + 0.5;
    if c >= 255.0 { 255 } else { c as u8 }
}

#[cfg(test)]
mod tests {
    use super::*;
    use embedded_hal::i2c::ErrorKind;
    use embedded_hal_mock::eh1::i2c::{Mock, Transaction as T};

    #[test]
    fn one_byte_per_motor_address() {
        let ex = [
            T::write(0x29, vec![10]),
            T::write(0x2A, vec![20]),
            T::write(0x2B, vec![30]),
            T::write(0x2C, vec![40]),
        ];
        let mut esc = BlCtrl::new(Mock::new(&ex), DEFAULT_ADDRESSES);
        esc.set([10, 20, 30, 40]).unwrap();
        esc.release().done();
    }

    #[test]
    fn a_failing_motor_does_not_starve_the_others() {
        let ex = [
            T::write(0x29, vec![0]),
            T::write(0x2A, vec![0]).with_error(ErrorKind::Other),
            T::write(0x2B, vec![0]),
            T::write(0x2C, vec![0]),
        ];
        let mut esc = BlCtrl::new(Mock::new(&ex), DEFAULT_ADDRESSES);
        let e = esc.stop().unwrap_err();
        assert_eq!(e.motor, 1);
        esc.release().done();
    }

    #[test]
    fn speed_mapping() {
        assert_eq!(command_for_speed(0.0, 900.0), 0);
        assert_eq!(command_for_speed(-5.0, 900.0), 0);
        assert_eq!(command_for_speed(f32::NAN, 900.0), 0);
        assert_eq!(command_for_speed(900.0, 900.0), 255);
        assert_eq!(command_for_speed(2000.0, 900.0), 255);
        assert_eq!(command_for_speed(450.0, 900.0), 128);
    }
}
