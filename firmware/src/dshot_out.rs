//! DShot600 on the Matek F405-SE's motor pads (`--features matek-f405-se`): M1 PB7 (TIM4 channel 2), M2 PB6
//! (TIM4 channel 1), M3 PB0 (TIM3 channel 3), M4 PB1 (TIM3 channel 4) (Betaflight's `MATEKF405SE` target,
//! `src/config/MATEKF405SE/config.h`). Each timer runs at the DShot600 bit period (140 ticks of its 84 MHz
//! APB1 clock) in PWM mode 1 with preloaded compare registers; each control step the frames' duty cycles are
//! written by a DMA burst through the timer's DMA address register, one update event per bit: TIM3's two
//! channels from DMA1 stream 2 (channel 5, TIM3_UP), TIM4's from DMA1 stream 6 (channel 2, TIM4_UP) (RM0090,
//! table 42). The frames and the buffers' bit timing are `drivers::dshot`'s, tested on the host; this file is
//! the registers, which only a board can test: nothing here has run on one yet.
use drivers::dshot::{DshotOutput, FRAME_BITS, SLOTS, Speed};
use stm32f4xx_hal::pac;

/// The timers' clock (APB1 at 42 MHz, doubled for the timers).
pub const TIMER_CLOCK_HZ: u32 = 84_000_000;
/// The ESCs' arming time: motor-stop frames only.
pub const ARM_MS: u32 = 300;

/// A two-channel burst buffer: slot `k` of the timer's first channel at `2 k`, of its second at `2 k + 1`.
type Burst = [u16; SLOTS * 2];

/// The four DShot outputs.
pub struct DshotMotors {
    out: DshotOutput,
    tim3: pac::TIM3,
    tim4: pac::TIM4,
    dma: pac::DMA1,
    /// TIM4: CCR1 (M2), CCR2 (M1); TIM3: CCR3 (M3), CCR4 (M4).
    buf4: &'static mut Burst,
    buf3: &'static mut Burst,
    /// Frames not sent because the previous burst had not finished.
    pub busy: u32,
}

/// The DMA streams.
const TIM3_STREAM: usize = 2;
const TIM4_STREAM: usize = 6;

impl DshotMotors {
    /// Sets up the timers and the DMA streams (the pins are in their alternate function already) for a
    /// control period of `frame_period_us`; `None` when the timer clock cannot make DShot600.
    pub fn new(
        tim3: pac::TIM3,
        tim4: pac::TIM4,
        dma: pac::DMA1,
        max_rad_s: f32,
        frame_period_us: u32,
        bufs: (&'static mut Burst, &'static mut Burst),
    ) -> Option<Self> {
        let out =
            DshotOutput::new(Speed::Dshot600, TIMER_CLOCK_HZ, false, max_rad_s, frame_period_us, ARM_MS)?;
        let arr = out.auto_reload();
        // TIM4: channels 1 and 2, burst from CCR1 (DCR.DBA = 13, the CCR1 offset 0x34 over 4), two transfers.
        // TIM3: channels 3 and 4, burst from CCR3 (DBA = 15).
        Self::timer(&tim4, arr, 13, [true, true, false, false]);
        Self::timer(&tim3, arr, 15, [false, false, true, true]);
        let (buf4, buf3) = bufs;
        buf4.fill(0);
        buf3.fill(0);
        Some(Self { out, tim3, tim4, dma, buf4, buf3, busy: 0 })
    }

    fn timer(t: &pac::tim3::RegisterBlock, arr: u16, dba: u8, channels: [bool; 4]) {
        t.cr1().write(|w| w.arpe().set_bit());
        t.psc().write(|w| w.psc().set(0));
        t.arr().write(|w| w.arr().set(arr));
        // PWM mode 1 (OCxM = 110) with the compare registers preloaded, on the channels used.
        t.ccmr1_output()
            .write(|w| w.oc1m().pwm_mode1().oc1pe().set_bit().oc2m().pwm_mode1().oc2pe().set_bit());
        t.ccmr2_output()
            .write(|w| w.oc3m().pwm_mode1().oc3pe().set_bit().oc4m().pwm_mode1().oc4pe().set_bit());
        for k in 0..4 {
            t.ccr(k).write(|w| w.ccr().set(0));
        }
        t.ccer().write(|w| {
            w.cc1e().bit(channels[0]).cc2e().bit(channels[1]).cc3e().bit(channels[2]).cc4e().bit(channels[3])
        });
        // A DMA burst of two transfers from CCR(dba), one burst per update event.
        #[allow(unsafe_code)]
        // SAFETY: DBL = 1 (two transfers per burst) is a valid burst length (RM0090, TIMx_DCR).
        t.dcr().write(|w| unsafe { w.dba().set(dba).dbl().bits(1) });
        t.dier().write(|w| w.ude().set_bit());
        t.egr().write(|w| w.ug().set_bit());
        t.cr1().modify(|_, w| w.cen().set_bit());
    }

    /// Starts a burst of `buf` on `stream` (channel `chsel`) into the timer's DMA address register `dmar`;
    /// false when the previous one is still under way.
    fn start(dma: &pac::DMA1, stream: usize, chsel: u8, dmar: u32, buf: &Burst) -> bool {
        let st = dma.st(stream);
        if st.cr().read().en().bit_is_set() {
            return false;
        }
        // Clear the stream's flags (its transfer complete among them) before it is enabled again.
        match stream {
            TIM3_STREAM => dma.lifcr().write(|w| {
                w.ctcif2()
                    .set_bit()
                    .chtif2()
                    .set_bit()
                    .cteif2()
                    .set_bit()
                    .cdmeif2()
                    .set_bit()
                    .cfeif2()
                    .set_bit()
            }),
            _ => dma.hifcr().write(|w| {
                w.ctcif6()
                    .set_bit()
                    .chtif6()
                    .set_bit()
                    .cteif6()
                    .set_bit()
                    .cdmeif6()
                    .set_bit()
                    .cfeif6()
                    .set_bit()
            }),
        };
        #[allow(unsafe_code)]
        // SAFETY: the addresses are the timer's DMA register and a buffer with 'static life that only this
        // driver writes, and only while the stream is disabled.
        unsafe {
            st.par().write(|w| w.pa().bits(dmar));
            st.m0ar().write(|w| w.m0a().bits(buf.as_ptr() as u32));
        }
        st.ndtr().write(|w| w.ndt().set(buf.len() as u16));
        st.cr().write(|w| {
            w.chsel().set(chsel);
            // Memory to peripheral, memory address incremented, 16-bit both sides, high priority.
            w.dir().memory_to_peripheral().minc().set_bit().psize().bits16().msize().bits16();
            w.pl().high().en().set_bit()
        });
        true
    }

    /// Sends the rotor speeds `speeds_rad_s` (M1..M4; motor stop while `enabled` is false and during the
    /// ESCs' arming time), full throttle at `max_rad_s`.
    pub fn set(&mut self, speeds_rad_s: [f32; 4], enabled: bool, max_rad_s: f32) {
        self.out.set_max_rad_s(max_rad_s);
        let f = self.out.frames(speeds_rad_s, enabled);
        // TIM4: CCR1 is M2, CCR2 is M1; TIM3: CCR3 is M3, CCR4 is M4.
        let mut four = [0u16; SLOTS * 4];
        self.out.burst([f[1], f[0], f[2], f[3]], &mut four);
        for k in 0..SLOTS {
            self.buf4[2 * k] = four[4 * k];
            self.buf4[2 * k + 1] = four[4 * k + 1];
            self.buf3[2 * k] = four[4 * k + 2];
            self.buf3[2 * k + 1] = four[4 * k + 3];
        }
        let dmar4 = self.tim4.dmar().as_ptr() as u32;
        let dmar3 = self.tim3.dmar().as_ptr() as u32;
        let a = Self::start(&self.dma, TIM4_STREAM, 2, dmar4, self.buf4);
        let b = Self::start(&self.dma, TIM3_STREAM, 5, dmar3, self.buf3);
        if !(a && b) {
            self.busy = self.busy.saturating_add(1);
        }
        debug_assert_eq!(FRAME_BITS + 1, SLOTS);
    }
}

/// After a panic: the outputs low and the timers stopped (a DShot ESC stops its motor when frames stop).
#[allow(unsafe_code)]
pub fn stop_all() {
    // SAFETY: called once with interrupts masked after a panic; nothing else runs any more.
    let dp = unsafe { pac::Peripherals::steal() };
    dp.DMA1.st(TIM3_STREAM).cr().modify(|_, w| w.en().clear_bit());
    dp.DMA1.st(TIM4_STREAM).cr().modify(|_, w| w.en().clear_bit());
    for t in [&*dp.TIM3, &*dp.TIM4] {
        // Forced inactive (low) at once: a compare value written now would wait for the next update event,
        // and a timer stopped in a bit's high part would hold its line high.
        t.ccmr1_output().write(|w| w.oc1m().force_inactive().oc2m().force_inactive());
        t.ccmr2_output().write(|w| w.oc3m().force_inactive().oc4m().force_inactive());
        for k in 0..4 {
            t.ccr(k).write(|w| w.ccr().set(0));
        }
        t.cr1().modify(|_, w| w.cen().clear_bit());
    }
}
