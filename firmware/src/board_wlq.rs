//! The default pin map (`docs/firmware.md`, "Board"): the paper's setup on a common STM32F405 flight controller:
//! MPU-6000 on SPI1, HMC5883L and four BL-Ctrl speed controllers on I2C1, the battery's divider on PC1, the radio
//! modem on USART1 and the RC receiver on USART3 (PB10, PB11).
use super::*;
use core::cell::RefCell;
use drivers::SensorRotation;
use drivers::blctrl::{BlCtrl, DEFAULT_ADDRESSES};
use drivers::hmc5883l::Hmc5883l;
use drivers::mpu6000::Mpu6000;
use embedded_hal_bus::i2c::RefCellDevice;
use embedded_hal_bus::spi::{ExclusiveDevice, NoDelay};
use stm32f4xx_hal::adc::{Adc, config::AdcConfig, config::SampleTime};
use stm32f4xx_hal::gpio::{Analog, Output, PA4, PC1};
use stm32f4xx_hal::i2c::{I2c, Mode as I2cMode};
use stm32f4xx_hal::pac::{I2C1, SPI1};
use stm32f4xx_hal::rcc::Config;
use stm32f4xx_hal::spi::{Mode, Phase, Polarity, Spi};

type SharedI2c = RefCellDevice<'static, I2c<I2C1>>;

pub struct Hardware {
    pub(super) imu: Mpu6000<ExclusiveDevice<Spi<SPI1>, PA4<Output>, NoDelay>>,
    mag: Option<Hmc5883l<SharedI2c>>,
    esc: BlCtrl<SharedI2c>,
    pub(super) rng: pac::RNG,
    adc: Adc<pac::ADC1>,
    vbat: PC1<Analog>,
}

/// The battery voltage's divider on PC1 (10 k over 1 k: 11, Betaflight's `vbat_scale` 110).
pub const VBAT_SCALE: f32 = 11.0;
/// The ADC's reference (V) and full scale.
const ADC_VREF: f32 = 3.3;
const ADC_FULL_SCALE: f32 = 4095.0;

impl Board {
    /// Clocks, pins, sensors, speed controllers, UART, tick (counting from here; the control loop runs on it
    /// once `sched::start` hands it over).
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
        // The battery's voltage divider on PC1, read by ADC1.
        let adc = Adc::new(dp.ADC1, true, AdcConfig::default(), &mut rcc);
        let vbat = gpioc.pc1.into_analog();
        // IMU on SPI1, mode 3, 1 MHz (the MPU-6000's limit for its configuration registers).
        let spi = dp.SPI1.spi(
            (Some(gpioa.pa5), Some(gpioa.pa6), Some(gpioa.pa7)),
            Mode { polarity: Polarity::IdleHigh, phase: Phase::CaptureOnSecondTransition },
            1.MHz(),
            &mut rcc,
        );
        let cs = gpioa.pa4.into_push_pull_output_in_state(stm32f4xx_hal::gpio::PinState::High);
        let Ok(dev) = ExclusiveDevice::new_no_delay(spi, cs);
        let mut imu = Mpu6000::new(dev, SensorRotation::IDENTITY);
        if let Err(e) = imu.init(&mut delay) {
            defmt::error!("IMU init failed: {}", defmt::Debug2Format(&e));
            halt("no IMU");
        }
        // Magnetometer and speed controllers share I2C1.
        let i2c = dp.I2C1.i2c(
            (gpiob.pb8, gpiob.pb9),
            I2cMode::Fast { frequency: 400.kHz(), duty_cycle: stm32f4xx_hal::i2c::DutyCycle::Ratio2to1 },
            &mut rcc,
        );
        let Some(bus) = cortex_m::singleton!(: RefCell<I2c<I2C1>> = RefCell::new(i2c)) else {
            halt("i2c bus")
        };
        let mut esc = BlCtrl::new(RefCellDevice::new(bus), DEFAULT_ADDRESSES);
        if esc.stop().is_err() {
            defmt::warn!("a speed controller did not answer");
        }
        let mut mag = Hmc5883l::new(RefCellDevice::new(bus), SensorRotation::IDENTITY);
        let mag = match mag.init() {
            Ok(()) => Some(mag),
            Err(e) => {
                defmt::warn!("no magnetometer: {}", defmt::Debug2Format(&e));
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
        // The RC receiver (CRSF: ExpressLRS, TBS Crossfire) on USART3, PB10 TX, PB11 RX.
        match Serial::new(
            dp.USART3,
            (gpiob.pb10, gpiob.pb11),
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
            hw: Hardware { imu, mag, esc, rng: dp.RNG, adc, vbat },
        }
    }

    /// The magnetometer's field (body axes), if present and readable.
    pub fn read_mag(&mut self) -> Option<Vec3> {
        self.hw.mag.as_mut()?.read_field().ok().map(Vec3::from_array)
    }

    /// The battery's voltage (no current sensor on this board).
    pub fn read_battery(&mut self) -> Option<control_core::battery::BatteryReading> {
        let hw = &mut self.hw;
        let raw = hw.adc.convert(&hw.vbat, SampleTime::Cycles_480);
        let voltage_v = raw as f32 / ADC_FULL_SCALE * ADC_VREF * VBAT_SCALE;
        Some(control_core::battery::BatteryReading { voltage_v, current_a: None })
    }

    /// Commands the four speed controllers with the rotor speeds (rad/s; up to `max_rad_s`).
    pub fn set_motors(&mut self, speeds_rad_s: [f32; 4], max_rad_s: f32) -> Result<(), ()> {
        let cmd = speeds_rad_s.map(|w| drivers::blctrl::command_for_speed(w, max_rad_s));
        self.hw.esc.set(cmd).map_err(|_| ())
    }
}
