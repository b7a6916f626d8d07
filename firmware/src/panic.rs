//! The panic and hard-fault handlers: stop the motors, say why, stop.
//!
//! The control code is written not to panic (no unwrap or indexing on the flight path, math saturates); this is
//! the last line of defence. It masks interrupts, sends a stop command to every speed controller by driving I2C1
//! at the register level with bounded waits (the bus may have been mid-transfer), logs the message, and halts. A
//! BL-Ctrl controller also stops its motor when commands stop arriving.
use core::panic::PanicInfo;

#[panic_handler]
fn panic(info: &PanicInfo) -> ! {
    cortex_m::interrupt::disable();
    #[cfg(not(feature = "qemu"))]
    stop_motors();
    defmt::error!("panic: {}", defmt::Display2Format(info));
    #[cfg(feature = "qemu")]
    {
        cortex_m_semihosting::hprintln!("panic: {}", info);
        cortex_m_semihosting::debug::exit(cortex_m_semihosting::debug::EXIT_FAILURE);
    }
    loop {
        cortex_m::asm::nop();
    }
}

/// A hard fault (a stack overflow into the static data, a bad memory access): the same as a panic. Without it
/// cortex-m-rt's default handler spins with the motors at their last command.
#[cortex_m_rt::exception]
#[allow(unsafe_code)]
unsafe fn HardFault(ef: &cortex_m_rt::ExceptionFrame) -> ! {
    cortex_m::interrupt::disable();
    #[cfg(not(feature = "qemu"))]
    stop_motors();
    defmt::error!("hard fault at pc {=u32:#x}, lr {=u32:#x}", ef.pc(), ef.lr());
    #[cfg(feature = "qemu")]
    {
        cortex_m_semihosting::hprintln!("hard fault at pc {:#x}, lr {:#x}", ef.pc(), ef.lr());
        cortex_m_semihosting::debug::exit(cortex_m_semihosting::debug::EXIT_FAILURE);
    }
    loop {
        cortex_m::asm::nop();
    }
}

/// DShot boards: the outputs low and the timers stopped (a DShot ESC stops its motor when frames stop).
#[cfg(all(feature = "matek-f405-se", not(feature = "qemu")))]
fn stop_motors() {
    crate::dshot_out::stop_all();
}

/// Writes 0 to each BL-Ctrl address on I2C1, register by register, never waiting more than a bounded count.
#[cfg(all(not(feature = "qemu"), not(feature = "matek-f405-se")))]
#[allow(unsafe_code)]
fn stop_motors() {
    use stm32f4xx_hal::pac;
    // SAFETY: called once with interrupts masked after a panic; nothing else runs any more.
    let dp = unsafe { pac::Peripherals::steal() };
    let i2c = dp.I2C1;
    let wait = |cond: &dyn Fn() -> bool| {
        for _ in 0..20_000 {
            if cond() {
                return true;
            }
        }
        false
    };
    // Reset the peripheral (it may be stuck mid-transfer), then 100 kHz at PCLK1 = 42 MHz.
    i2c.cr1().modify(|_, w| w.swrst().set_bit());
    i2c.cr1().modify(|_, w| w.swrst().clear_bit());
    i2c.cr2().write(|w| unsafe { w.freq().bits(42) });
    i2c.ccr().write(|w| unsafe { w.ccr().bits(210) });
    i2c.trise().write(|w| w.trise().set(43));
    i2c.cr1().modify(|_, w| w.pe().set_bit());
    for addr in drivers::blctrl::DEFAULT_ADDRESSES {
        i2c.cr1().modify(|_, w| w.start().set_bit());
        if !wait(&|| i2c.sr1().read().sb().bit_is_set()) {
            continue;
        }
        i2c.dr().write(|w| unsafe { w.bits((addr as u16) << 1) });
        if !wait(&|| i2c.sr1().read().addr().bit_is_set() || i2c.sr1().read().af().bit_is_set()) {
            i2c.cr1().modify(|_, w| w.stop().set_bit());
            continue;
        }
        let _ = i2c.sr2().read();
        i2c.dr().write(|w| unsafe { w.bits(0) });
        wait(&|| i2c.sr1().read().btf().bit_is_set());
        i2c.cr1().modify(|_, w| w.stop().set_bit());
        wait(&|| !i2c.cr1().read().stop().bit_is_set());
    }
}
