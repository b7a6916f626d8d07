//! Matek F405-SE (`--features matek-f405-se`), pins from Betaflight's `MATEKF405SE` target
//! (`src/config/MATEKF405SE/config.h` of the Betaflight repository) and Matek's wiring diagram:
//!
//! - MPU-6000 on SPI1 (PA5, PA6, PA7; chip select PA4), mounted turned 270 degrees clockwise (`CW270_DEG`: 90
//!   degrees counter-clockwise seen from above, `SensorRotation::YAW_90`);
//! - motors M1 PB7, M2 PB6, M3 PB0, M4 PB1: DShot600 (`dshot_out.rs`);
//! - an external HMC5883L compass on I2C2 (PB10 SCL, PB11 SDA), when fitted (the board's DPS310 barometer on
//!   I2C1 has no driver yet);
//! - the radio modem on UART1 (PA9, PA10), the RC receiver on UART3 (PC10 TX, PC11 RX; UART2's RX has the
//!   board's SBUS inverter);
//! - the battery: voltage on PC0 (divider 11, Betaflight's `vbat_scale` 110), current on PC1 (the board's
//!   current sensor, 17.9 mV/A: Betaflight's `ibata_scale` 179).
use super::*;
use crate::dshot_out::DshotMotors;
use core::cell::RefCell;
use drivers::SensorRotation;
use drivers::hmc5883l::Hmc5883l;
use drivers::mpu6000::Mpu6000;
use embedded_hal_bus::i2c::RefCellDevice;
use embedded_hal_bus::spi::{ExclusiveDevice, NoDelay};
use stm32f4xx_hal::adc::{Adc, config::AdcConfig, config::SampleTime};
use stm32f4xx_hal::gpio::{Analog, Output, PA4, PC0, PC1};
use stm32f4xx_hal::i2c::{I2c, Mode as I2cMode};
use stm32f4xx_hal::pac::{I2C2, SPI1};
use stm32f4xx_hal::rcc::Config;
use stm32f4xx_hal::spi::{Mode, Phase, Polarity, Spi};

type CompassI2c = RefCellDevice<'static, I2c<I2C2>>;

pub struct Hardware {
    pub(super) imu: Mpu6000<ExclusiveDevice<Spi<SPI1>, PA4<Output>, NoDelay>>,
    mag: Option<Hmc5883l<CompassI2c>>,
    motors: Option<DshotMotors>,
    pub(super) rng: pac::RNG,
    adc: Adc<pac::ADC1>,
    vbat: PC0<Analog>,
    curr: PC1<Analog>,
}

/// The battery voltage's divider on PC0.
pub const VBAT_SCALE: f32 = 11.0;
/// The current sensor on PC1 (V per A).
pub const CURRENT_V_PER_A: f32 = 0.0179;
/// The ADC's reference (V) and full scale.
const ADC_VREF: f32 = 3.3;
const ADC_FULL_SCALE: f32 = 4095.0;

/// The DShot bursts' buffers (two channels a timer).
static DSHOT_BUFS: static_cell::StaticCell<(
    [u16; drivers::dshot::SLOTS * 2],
    [u16; drivers::dshot::SLOTS * 2],
)> = static_cell::StaticCell::new();

impl Board {
    /// Clocks, pins, sensors, motor outputs, UARTs, tick (counting from here; the control loop runs on it once
    /// `sched::start` hands it over).
    pub fn init() -> Self {
        let (Some(dp), Some(mut cp)) = (pac::Peripherals::take(), cortex_m::Peripherals::take()) else {
            halt("peripherals already taken")
        };
        // The 48 MHz clock feeds the hardware RNG (the link's handshake nonces).
        let mut rcc = dp.RCC.freeze(
            Config::hse(8.MHz()).sysclk(168.MHz()).pclk1(42.MHz()).pclk2(84.MHz()).require_pll48clk(),
        );
        <pac::RNG as stm32f4xx_hal::rcc::Enable>::enable(&mut rcc);
        dp.RNG.cr().modify(|_, w| w.rngen().set_bit());
        let gpioa = dp.GPIOA.split(&mut rcc);
        let gpiob = dp.GPIOB.split(&mut rcc);
        let gpioc = dp.GPIOC.split(&mut rcc);
        let mut delay = dp.TIM5.delay_us(&mut rcc);
        // Motors first, so that the ESCs see a low line, then motor-stop frames, from the start.
        <pac::TIM3 as stm32f4xx_hal::rcc::Enable>::enable(&mut rcc);
        <pac::TIM4 as stm32f4xx_hal::rcc::Enable>::enable(&mut rcc);
        <pac::DMA1 as stm32f4xx_hal::rcc::Enable>::enable(&mut rcc);
        let _m1 = gpiob.pb7.into_alternate::<2>();
        let _m2 = gpiob.pb6.into_alternate::<2>();
        let _m3 = gpiob.pb0.into_alternate::<2>();
        let _m4 = gpiob.pb1.into_alternate::<2>();
        let bufs = DSHOT_BUFS.init(([0; drivers::dshot::SLOTS * 2], [0; drivers::dshot::SLOTS * 2]));
        let motors = DshotMotors::new(
            dp.TIM3,
            dp.TIM4,
            dp.DMA1,
            control_core::params::VehicleParams::default().motor_speed_max_rad_s,
            2000,
            (&mut bufs.0, &mut bufs.1),
        );
        if motors.is_none() {
            defmt::error!("DShot600 cannot be made from the timers' clock: no motor output");
        }
        // The battery's voltage and current, read by ADC1.
        let adc = Adc::new(dp.ADC1, true, AdcConfig::default(), &mut rcc);
        let vbat = gpioc.pc0.into_analog();
        let curr = gpioc.pc1.into_analog();
        // IMU on SPI1, mode 3, 1 MHz (the MPU-6000's limit for its configuration registers).
        let spi = dp.SPI1.spi(
            (Some(gpioa.pa5), Some(gpioa.pa6), Some(gpioa.pa7)),
            Mode { polarity: Polarity::IdleHigh, phase: Phase::CaptureOnSecondTransition },
            1.MHz(),
            &mut rcc,
        );
        let cs = gpioa.pa4.into_push_pull_output_in_state(stm32f4xx_hal::gpio::PinState::High);
        let Ok(dev) = ExclusiveDevice::new_no_delay(spi, cs);
        let mut imu = Mpu6000::new(dev, SensorRotation::YAW_90);
        if let Err(e) = imu.init(&mut delay) {
            defmt::error!("IMU init failed: {}", defmt::Debug2Format(&e));
            halt("no IMU");
        }
        // An external compass on I2C2.
        let i2c = dp.I2C2.i2c(
            (gpiob.pb10, gpiob.pb11),
            I2cMode::Fast { frequency: 400.kHz(), duty_cycle: stm32f4xx_hal::i2c::DutyCycle::Ratio2to1 },
            &mut rcc,
        );
        let Some(bus) = cortex_m::singleton!(: RefCell<I2c<I2C2>> = RefCell::new(i2c)) else {
            halt("i2c bus")
        };
        let mut mag = Hmc5883l::new(RefCellDevice::new(bus), SensorRotation::IDENTITY);
        let mag = match mag.init() {
            Ok(()) => Some(mag),
            Err(e) => {
                defmt::warn!("no compass: {}", defmt::Debug2Format(&e));
                None
            }
        };
        let Ok(serial) = Serial::new(
            dp.USART1,
            (gpioa.pa9, gpioa.pa10),
            SerialConfig::default().baudrate(BAUD.bps()),
            &mut rcc,
        ) else {
            halt("uart")
        };
        start_uart(serial, &mut cp.NVIC);
        // The RC receiver (CRSF: ExpressLRS, TBS Crossfire) on UART3, PC10 TX, PC11 RX.
        match Serial::new(
            dp.USART3,
            (gpioc.pc10, gpioc.pc11),
            SerialConfig::default().baudrate(drivers::crsf::BAUD.bps()),
            &mut rcc,
        ) {
            Ok(rc) => start_rc_uart(rc, &mut cp.NVIC),
            Err(_) => defmt::warn!("the RC receiver's UART did not start: no RC"),
        }
        cp.DCB.enable_trace();
        cp.DWT.enable_cycle_counter();
        start_tick(cp.SYST, &mut cp.SCB, rcc.clocks.sysclk().raw() / 1000);
        let flash = crate::config::Flash(stm32f4xx_hal::flash::LockedFlash::new(dp.FLASH));
        Board {
            flash: Some(flash),
            nonces: 0,
            rng_errors: 0,
            hw: Hardware { imu, mag, motors, rng: dp.RNG, adc, vbat, curr },
        }
    }

    /// The compass's field (body axes), if one is fitted and readable.
    pub fn read_mag(&mut self) -> Option<Vec3> {
        self.hw.mag.as_mut()?.read_field().ok().map(Vec3::from_array)
    }

    /// The battery's voltage and current.
    pub fn read_battery(&mut self) -> Option<control_core::battery::BatteryReading> {
        let hw = &mut self.hw;
        let volts = |raw: u16| raw as f32 / ADC_FULL_SCALE * ADC_VREF;
        let voltage_v = volts(hw.adc.convert(&hw.vbat, SampleTime::Cycles_480)) * VBAT_SCALE;
        let current_a = volts(hw.adc.convert(&hw.curr, SampleTime::Cycles_480)) / CURRENT_V_PER_A;
        Some(control_core::battery::BatteryReading { voltage_v, current_a: Some(current_a) })
    }

    /// Sends the rotor speeds (rad/s) as DShot600 throttle up to `max_rad_s` (motor stop for zero).
    pub fn set_motors(&mut self, speeds_rad_s: [f32; 4], max_rad_s: f32) -> Result<(), ()> {
        let m = self.hw.motors.as_mut().ok_or(())?;
        let before = m.busy;
        m.set(speeds_rad_s, speeds_rad_s.iter().any(|w| *w > 0.0), max_rad_s);
        if m.busy == before { Ok(()) } else { Err(()) }
    }
}
