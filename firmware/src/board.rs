//! Board support: clocks, pins, sensors, speed controllers, the radio UART and the tick.
//!
//! Two variants, selected at build time:
//!
//! - **STM32F405 flight controller** (default): 8 MHz crystal, 168 MHz system clock; MPU-6000 on SPI1
//!   (PA5/PA6/PA7, chip select PA4); HMC5883L and four BL-Ctrl speed controllers on I2C1 (PB8 SCL, PB9 SDA,
//!   400 kHz); the radio modem on USART1 (PA9 TX, PA10 RX, 115200 baud).
//! - **QEMU `netduinoplus2`** (`--features qemu`): QEMU models neither the RCC (clock setup that waits on ready
//!   flags would hang) nor I2C, so the variant keeps the reset clock, has no sensors on the buses, feeds the flight
//!   code a synthetic IMU at rest, and reports over semihosting after a fixed number of steps.
//!
//! Both share the UART queues (interrupt-driven, so that no byte is lost at 115200 baud while a step runs), the
//! SysTick tick (whose exception runs the control loop, `sched.rs`) and the cycle counter.
use control_core::estimator::ImuSample;
use core::cell::RefCell;
use core::sync::atomic::{AtomicU32, Ordering};
use cortex_m::interrupt::Mutex;
use cortex_m::peripheral::syst::SystClkSource;
use geometry::Vec3;
use heapless::Deque;
use protocol::auth::Nonce;
use protocol::auth::provision::{KEY_BLOCK_ADDRESS, KEY_BLOCK_LEN};
use stm32f4xx_hal::pac::{self, USART1, interrupt};
use stm32f4xx_hal::prelude::*;
use stm32f4xx_hal::serial::{Config as SerialConfig, Rx, RxListen, Serial, Tx, TxListen};

/// Radio link baud rate.
pub const BAUD: u32 = 115_200;

/// The radio UART's interrupt priority (lower numbers are more urgent; the STM32F4 keeps the top four bits):
/// above the control loop, so that no byte is lost at 115200 baud while a step runs (a byte every 87 us; a step
/// takes up to 260 us).
pub const UART_PRIORITY: u8 = 0x20;
/// The control loop's (SysTick) priority (`sched.rs`).
pub const TICK_PRIORITY: u8 = 0x80;

/// Ticks (1 ms) since the tick started: the SysTick exception counts them (`sched.rs`).
pub static TICKS: AtomicU32 = AtomicU32::new(0);
static RX_QUEUE: Mutex<RefCell<Deque<u8, 1024>>> = Mutex::new(RefCell::new(Deque::new()));
static TX_QUEUE: Mutex<RefCell<Deque<u8, 2048>>> = Mutex::new(RefCell::new(Deque::new()));
/// The radio UART's two halves, owned by the interrupt handler once started.
type UartHalves = (Tx<USART1>, Rx<USART1>);
static UART: Mutex<RefCell<Option<UartHalves>>> = Mutex::new(RefCell::new(None));
static RX_OVERFLOW: AtomicU32 = AtomicU32::new(0);
/// The RC receiver's bytes (CRSF at 420 000 baud: a 26-byte RC frame every 2-20 ms), and those that found the
/// queue full.
static RC_QUEUE: Mutex<RefCell<Deque<u8, 256>>> = Mutex::new(RefCell::new(Deque::new()));
static RC_OVERFLOW: AtomicU32 = AtomicU32::new(0);

#[interrupt]
fn USART1() {
    cortex_m::interrupt::free(|cs| {
        let mut uart = UART.borrow(cs).borrow_mut();
        let Some((tx, rx)) = uart.as_mut() else { return };
        while let Ok(b) = embedded_hal_nb::serial::Read::read(rx) {
            if RX_QUEUE.borrow(cs).borrow_mut().push_back(b).is_err() {
                RX_OVERFLOW.fetch_add(1, Ordering::Relaxed);
            }
        }
        let mut q = TX_QUEUE.borrow(cs).borrow_mut();
        match q.front() {
            Some(&b) => {
                if embedded_hal_nb::serial::Write::write(tx, b).is_ok() {
                    q.pop_front();
                }
            }
            None => tx.unlisten(),
        }
    });
}

fn start_uart(serial: Serial<USART1>, nvic: &mut pac::NVIC) {
    let (tx, mut rx) = serial.split();
    rx.listen();
    cortex_m::interrupt::free(|cs| UART.borrow(cs).replace(Some((tx, rx))));
    pac::NVIC::unpend(pac::Interrupt::USART1);
    #[allow(unsafe_code)]
    // SAFETY: the handler only touches state behind critical sections (which mask every priority), set up
    // just above; its priority orders it before the control loop and changes no critical section's meaning.
    unsafe {
        nvic.set_priority(pac::Interrupt::USART1, UART_PRIORITY);
        pac::NVIC::unmask(pac::Interrupt::USART1);
    }
}

/// Starts the 1 ms tick whose exception runs the control loop (`sched.rs`), at its priority: every
/// `counts_per_tick` counts of the core clock.
#[cfg(not(feature = "fil"))]
fn start_tick(
    mut syst: cortex_m::peripheral::SYST,
    scb: &mut cortex_m::peripheral::SCB,
    counts_per_tick: u32,
) {
    #[allow(unsafe_code)]
    // SAFETY: the exception's state is its own or behind critical sections (which mask every priority).
    unsafe {
        scb.set_priority(cortex_m::peripheral::scb::SystemHandler::SysTick, TICK_PRIORITY);
    }
    syst.set_clock_source(SystClkSource::Core);
    syst.set_reload(counts_per_tick - 1);
    syst.clear_current();
    syst.enable_interrupt();
    syst.enable_counter();
}

/// Cycles from the tick that raised the running SysTick exception to now: SysTick counts down from its reload
/// value and raises the exception when it reloads, so the count since then is the reload value minus the
/// current one. Called first thing in the exception, it is the exception's start latency.
#[cfg(not(feature = "fil"))]
pub fn tick_latency() -> u32 {
    cortex_m::peripheral::SYST::get_reload().saturating_sub(cortex_m::peripheral::SYST::get_current())
}

/// A free-running cycle count for measuring costs: the DWT cycle counter on the board.
#[cfg(not(feature = "qemu"))]
pub fn cycles() -> u32 {
    cortex_m::peripheral::DWT::cycle_count()
}

/// A free-running cycle count for measuring costs: under QEMU (whose DWT reads 0) the tick number and the
/// SysTick count, which counts the emulated CPU clock (read twice over when a tick comes between the reads).
#[cfg(all(feature = "qemu", not(feature = "fil")))]
pub fn cycles() -> u32 {
    use cortex_m::peripheral::{SCB, SYST};
    let reload = SYST::get_reload() + 1;
    loop {
        // A tick whose exception has not run yet (pending while a critical section or a more urgent
        // interrupt runs) has reloaded the counter without being counted: count it here. Read again when a
        // tick comes between the reads.
        let (t1, p1) = (TICKS.load(Ordering::Acquire), SCB::is_pendst_pending());
        let val = SYST::get_current();
        let (t2, p2) = (TICKS.load(Ordering::Acquire), SCB::is_pendst_pending());
        if t1 == t2 && p1 == p2 {
            return t1.wrapping_add(p1 as u32).wrapping_mul(reload).wrapping_add(reload - 1 - val);
        }
    }
}

/// The firmware in the loop's cycle count: SysTick running free without interrupts, counting down from
/// 2^24 - 1: the elapsed count, modulo 2^24.
#[cfg(feature = "fil")]
pub fn cycles() -> u32 {
    0x00FF_FFFF - cortex_m::peripheral::SYST::get_current()
}

/// Cycles since `t0` (a value of [`cycles`]); with the free-running 24-bit SysTick of the firmware in the
/// loop, for spans under 0.1 s.
pub fn cycles_since(t0: u32) -> u32 {
    let d = cycles().wrapping_sub(t0);
    if cfg!(feature = "fil") { d & 0x00FF_FFFF } else { d }
}

/// Counters the loop keeps for reports.
#[derive(Clone, Copy, Debug, Default)]
pub struct RunStats {
    /// Control steps run.
    pub steps: u32,
    /// Largest step cost (cycles).
    pub max_cost: u32,
    /// Sum of step costs (cycles).
    pub sum_cost: u64,
    /// Largest cost of the background work after one step (pose solves; cycles; the firmware in the loop's,
    /// on the board `background.rs` counts them).
    #[cfg(feature = "fil")]
    pub max_background: u32,
    /// Sum of background costs (cycles).
    #[cfg(feature = "fil")]
    pub sum_background: u64,
    /// IMU reads that failed.
    pub imu_errors: u32,
    /// IMU samples dropped, oldest first, because the step fell behind and more than a step holds arrived.
    pub imu_dropped: u32,
    /// Motor command writes that failed.
    pub motor_errors: u32,
    /// Link messages dropped because more than a step's worth arrived.
    pub uplink_dropped: u32,
    /// Downlink frames that did not fit the UART's queue whole.
    pub downlink_dropped: u32,
    /// Largest cost of the radio's work around one step (decoding, authenticating, sealing; cycles).
    pub max_link: u32,
    /// The radio's mode (`flight_core::radio::VehicleRadio::describe`).
    pub radio: &'static str,
    /// The radio's state and counters.
    pub auth: protocol::LinkStatus,
    /// Configuration pieces refused for an unauthenticated link, and configuration uploads applied.
    pub config_refused: u32,
    /// See [`RunStats::config_refused`].
    pub configs_applied: u32,
    /// The flight mode after the last step.
    pub mode: control_core::FlightMode,
    /// The link decoder's counters.
    pub link: protocol::frame::DecodeCounters,
    /// Ticks run by the control loop.
    pub ticks: u32,
    /// The largest and the summed start latency of the tick's exception (cycles from the tick to its first
    /// instruction, `sched.rs`).
    pub tick_latency_max: u32,
    /// See `tick_latency_max`.
    pub tick_latency_sum: u64,
    /// The flight stack's vision counters after the last step.
    pub vision: flight_core::VisionCounters,
}

impl RunStats {
    /// Adds a step's cost.
    pub fn record_step(&mut self, cost: u32) {
        self.steps += 1;
        self.max_cost = self.max_cost.max(cost);
        self.sum_cost += cost as u64;
    }

    /// Adds a tick's start latency.
    pub fn record_tick_latency(&mut self, cycles: u32) {
        self.ticks += 1;
        self.tick_latency_max = self.tick_latency_max.max(cycles);
        self.tick_latency_sum += cycles as u64;
    }

    /// Adds the cost of the radio's work before or after a step.
    pub fn record_link(&mut self, cost: u32) {
        self.max_link = self.max_link.max(cost);
    }

    /// Adds the cost of the background work after a step (the firmware in the loop, which runs it after each
    /// step; on the board it runs in thread mode and counts itself, `background.rs`).
    #[cfg(feature = "fil")]
    pub fn record_background(&mut self, cost: u32) {
        self.max_background = self.max_background.max(cost);
        self.sum_background += cost as u64;
    }
}

/// The radio key's flash block as the debug probe left it (`protocol::auth::provision`, docs/security.md).
pub fn key_block() -> [u8; KEY_BLOCK_LEN] {
    let mut b = [0u8; KEY_BLOCK_LEN];
    for (i, x) in b.iter_mut().enumerate() {
        #[allow(unsafe_code)]
        // SAFETY: the block lies in the on-chip flash (the first bytes of sector 11), memory-mapped and always
        // readable; the linker script (memory.x) keeps the firmware out of that sector.
        unsafe {
            *x = core::ptr::read_volatile((KEY_BLOCK_ADDRESS as usize + i) as *const u8);
        }
    }
    b
}

/// Stops here for good (the speed controllers stop their motors when commands stop coming).
pub fn halt(why: &'static str) -> ! {
    defmt::error!("halted: {}", why);
    #[cfg(feature = "qemu")]
    {
        cortex_m_semihosting::hprintln!("halted: {}", why);
        cortex_m_semihosting::debug::exit(cortex_m_semihosting::debug::EXIT_FAILURE);
    }
    loop {
        cortex_m::asm::wfi();
    }
}

/// The board.
pub struct Board {
    /// The flash for the parameter store, until `main` takes it ([`Board::take_flash`]).
    flash: Option<crate::config::Flash>,
    /// Handshake nonces drawn.
    nonces: u32,
    /// Nonces the hardware RNG could not give.
    pub rng_errors: u32,
    hw: Hardware,
}

impl Board {
    /// The flash for the parameter store (once; the store owns it from then on).
    pub fn take_flash(&mut self) -> crate::config::Flash {
        match self.flash.take() {
            Some(f) => f,
            None => halt("the flash was taken twice"),
        }
    }

    /// A nonce unique within this run: SHA-256 of the count of nonces drawn, the cycle counter and the tick.
    fn fallback_nonce(&self) -> Nonce {
        use sha2::Digest;
        let mut h = sha2::Sha256::new();
        h.update(self.nonces.to_le_bytes());
        h.update(cycles().to_le_bytes());
        h.update(TICKS.load(Ordering::Relaxed).to_le_bytes());
        let d = h.finalize();
        let mut n = [0u8; 16];
        n.copy_from_slice(&d[..16]);
        n
    }

    /// One byte from the radio, if any arrived.
    pub fn rx_byte(&mut self) -> Option<u8> {
        cortex_m::interrupt::free(|cs| RX_QUEUE.borrow(cs).borrow_mut().pop_front())
    }

    /// One byte from the RC receiver, if any arrived.
    pub fn rc_byte(&mut self) -> Option<u8> {
        cortex_m::interrupt::free(|cs| RC_QUEUE.borrow(cs).borrow_mut().pop_front())
    }

    /// RC bytes lost because the queue was full.
    pub fn rc_overflow(&self) -> u32 {
        RC_OVERFLOW.load(Ordering::Relaxed)
    }

    /// Free space in the radio's transmit queue (bytes).
    pub fn tx_free(&self) -> usize {
        cortex_m::interrupt::free(|cs| {
            let q = TX_QUEUE.borrow(cs).borrow();
            q.capacity() - q.len()
        })
    }

    /// Queues bytes for the radio; returns how many fitted.
    #[cfg(not(feature = "qemu"))]
    pub fn tx_bytes(&mut self, bytes: &[u8]) -> usize {
        cortex_m::interrupt::free(|cs| {
            let mut q = TX_QUEUE.borrow(cs).borrow_mut();
            let mut n = 0;
            for &b in bytes {
                if q.push_back(b).is_err() {
                    break;
                }
                n += 1;
            }
            if let Some((tx, _)) = UART.borrow(cs).borrow_mut().as_mut() {
                tx.listen();
            }
            n
        })
    }

    /// Writes bytes to the radio UART, waiting on each (QEMU does not raise the transmit interrupt; its UART
    /// takes each byte at once).
    #[cfg(feature = "qemu")]
    pub fn tx_bytes(&mut self, bytes: &[u8]) -> usize {
        cortex_m::interrupt::free(|cs| {
            let mut uart = UART.borrow(cs).borrow_mut();
            let Some((tx, _)) = uart.as_mut() else { return 0 };
            for &b in bytes {
                if embedded_hal_nb::nb::block!(embedded_hal_nb::serial::Write::write(tx, b)).is_err() {
                    return 0;
                }
            }
            bytes.len()
        })
    }
}

/// The RC receiver's UART (board variant: USART3), owned by its interrupt once started.
#[cfg(not(feature = "qemu"))]
static RC_UART: Mutex<RefCell<Option<Rx<pac::USART3>>>> = Mutex::new(RefCell::new(None));

#[cfg(not(feature = "qemu"))]
#[interrupt]
fn USART3() {
    cortex_m::interrupt::free(|cs| {
        let mut uart = RC_UART.borrow(cs).borrow_mut();
        let Some(rx) = uart.as_mut() else { return };
        while let Ok(b) = embedded_hal_nb::serial::Read::read(rx) {
            if RC_QUEUE.borrow(cs).borrow_mut().push_back(b).is_err() {
                RC_OVERFLOW.fetch_add(1, Ordering::Relaxed);
            }
        }
    });
}

/// Starts the RC receiver's UART: its bytes go into [`RC_QUEUE`] from its interrupt, at the radio's priority.
#[cfg(not(feature = "qemu"))]
fn start_rc_uart(serial: Serial<pac::USART3>, nvic: &mut pac::NVIC) {
    let (_tx, mut rx) = serial.split();
    rx.listen();
    cortex_m::interrupt::free(|cs| RC_UART.borrow(cs).replace(Some(rx)));
    pac::NVIC::unpend(pac::Interrupt::USART3);
    #[allow(unsafe_code)]
    // SAFETY: the handler only touches state behind critical sections, set up just above.
    unsafe {
        nvic.set_priority(pac::Interrupt::USART3, UART_PRIORITY);
        pac::NVIC::unmask(pac::Interrupt::USART3);
    }
}

/// The boards' shared methods (the IMU, the RNG, the log line); the rest is the board's own (`board_*.rs`).
#[cfg(not(feature = "qemu"))]
impl Board {
    /// No synthetic frames on the board: its frames come over the radio.
    pub fn synthetic_frames(&mut self, _time_us: u64) -> [Option<protocol::VisionMeasurement>; 2] {
        [None; 2]
    }

    /// A fresh nonce for the link's handshake from the hardware RNG (RM0090, 24: 32 bits per 40 RNG
    /// clocks). After a seed or clock error (counted) the RNG is restarted; should it still fail, the nonce
    /// is the previous one's SHA-256 with the cycle counter and a count, unique but not unpredictable.
    pub fn nonce(&mut self) -> Nonce {
        let mut n = [0u8; 16];
        let mut ok = true;
        for chunk in n.chunks_mut(4) {
            match self.random_word() {
                Some(w) => chunk.copy_from_slice(&w.to_le_bytes()),
                None => ok = false,
            }
        }
        if !ok {
            self.rng_errors = self.rng_errors.saturating_add(1);
            n = self.fallback_nonce();
        }
        self.nonces = self.nonces.wrapping_add(1);
        n
    }

    fn random_word(&mut self) -> Option<u32> {
        let rng = &self.hw.rng;
        for _ in 0..2 {
            for _ in 0..10_000 {
                let sr = rng.sr().read();
                if sr.secs().bit() || sr.cecs().bit() {
                    break;
                }
                if sr.drdy().bit() {
                    return Some(rng.dr().read().rndata().bits());
                }
            }
            // Restart after an error (RM0090, 24.3.2): clear the flags, disable, enable.
            rng.sr().modify(|_, w| w.seis().clear_bit().ceis().clear_bit());
            rng.cr().modify(|_, w| w.rngen().clear_bit());
            rng.cr().modify(|_, w| w.rngen().set_bit());
        }
        None
    }

    /// One IMU sample stamped `time_us`.
    pub fn read_imu(&mut self, time_us: u64) -> Option<ImuSample> {
        let r = self.hw.imu.read_sample().ok()?;
        Some(ImuSample { time_us, gyro_rad_s: r.gyro_rad_s, accel_m_s2: r.accel_m_s2 })
    }

    /// Periodic log line.
    pub fn after_step(&mut self, steps: u32, s: &RunStats) {
        if steps.is_multiple_of(2500) {
            defmt::info!(
                "steps {} mode {} step max {} cycles mean {} tick latency max {} cycles solves {} link ok {} errors {} radio {} auth ok {} refused {} arm refused {} rng errors {} rc bytes lost {}",
                s.steps,
                s.mode,
                s.max_cost,
                (s.sum_cost / s.steps.max(1) as u64) as u32,
                s.tick_latency_max,
                crate::background::SOLVES.load(Ordering::Relaxed),
                s.link.ok,
                s.link.errors(),
                s.radio,
                s.auth.auth.ok,
                s.auth.auth.refused(),
                s.auth.arm_refused,
                self.rng_errors,
                self.rc_overflow()
            );
        }
    }
}

#[cfg(all(not(feature = "qemu"), not(feature = "matek-f405-se")))]
#[path = "board_wlq.rs"]
mod variant;

#[cfg(all(not(feature = "qemu"), feature = "matek-f405-se"))]
#[path = "board_matek.rs"]
mod variant;

#[cfg(feature = "qemu")]
mod variant {
    use super::*;

    /// QEMU's netduinoplus2 clocks SysTick at 168 MHz of virtual time whatever the RCC says; under `-icount
    /// shift=0` an instruction takes 1 ns of virtual time, so SysTick counts 0.168 per instruction. A tick of
    /// the board (1 ms at 168 MHz, one instruction per cycle: 168 000 instructions) is 28 224 counts: the
    /// control loop then has the share of the core it has on the board, and a solve spans ticks as it does
    /// there.
    pub const QEMU_COUNTS_PER_TICK: u32 = 28_224;
    /// Instructions per SysTick count under `-icount shift=0` (125 / 21 = 1 / 0.168).
    pub fn instructions(counts: u64) -> u64 {
        counts * 125 / 21
    }
    /// Control steps before the report.
    pub const QEMU_STEPS: u32 = 1000;

    /// Synthetic frames of the line (see [`Board::synthetic_frame`]).
    const SYNTHETIC_FRAMES: usize = 8;
    /// A synthetic frame every this many microseconds (29 Hz, about a camera's rate).
    const SYNTHETIC_FRAME_EVERY_US: u64 = 34_000;
    /// Synthetic frames start once the estimator has aligned (us).
    const SYNTHETIC_FRAMES_FROM_US: u64 = 600_000;

    pub struct Hardware {
        /// The line as the forward camera sees it from 1.2 m, level, each a tenth of a millimetre further
        /// along (a frame that repeats the one before bit for bit is refused as frozen).
        frames: [Option<vision_core::LineObservation>; SYNTHETIC_FRAMES],
        frame_seq: u32,
    }

    impl Hardware {
        fn new() -> Self {
            let v = flight_core::VisionConfig::default();
            // Frames across the flight envelope: distance 1.0-1.56 m, up to 1.6 m either side of the line's
            // centre (so that some see one end only, as during the sweep: their solves take the longest, up
            // to about 470 k instructions), yaw within 8 deg, roll and pitch within 0.8 deg, each edge point
            // scattered by up to 0.5 px as a detector's are (a fixed pseudo-random sequence). The firmware in
            // the loop takes its frames from the simulator.
            let frames = core::array::from_fn(|k| {
                if cfg!(feature = "fil") {
                    return None;
                }
                let kf = k as f32;
                let yaw = 0.14 * (kf / 3.5 - 1.0);
                // Roll and pitch within 0.8 deg of the IMU's level: the attitude the solve takes from the IMU is
                // off by that much, as an IMU's is in flight.
                let tilt = 0.014 * (kf % 3.0 - 1.0);
                let r_cw = geometry::frames::Attitude::new(tilt, -tilt, yaw)
                    .world_from_body()
                    .mul_mat(&v.mount.body_from_camera)
                    .transpose();
                let c =
                    v.target.center() + Vec3::new(0.45 * (kf - 3.5), 1.0 + 0.08 * kf, 0.1 * (kf % 3.0 - 1.0));
                let mut seed = 0x9E37_79B9u32.wrapping_mul(k as u32 + 1);
                let noise = move || {
                    seed ^= seed << 13;
                    seed ^= seed >> 17;
                    seed ^= seed << 5;
                    (seed >> 8) as f32 / (1u32 << 24) as f32 - 0.5
                };
                vision_core::observation::project_observation(&v.camera, &v.target, &r_cw, c, 3.0, 2.0, noise)
            });
            Self { frames, frame_seq: 0 }
        }
    }

    /// The pattern painted over the free stack.
    const PAINT: u32 = 0xA5A5_A5A5;
    /// End of RAM: the stack's top.
    const RAM_END: usize = 0x2002_0000;

    #[allow(unsafe_code)]
    unsafe extern "C" {
        /// End of the static data (cortex-m-rt's linker script): the stack may grow down to here.
        static __sheap: u32;
    }

    fn stack_floor() -> usize {
        (core::ptr::addr_of!(__sheap) as usize + 3) & !3
    }

    /// Paints the free stack below the caller (leaving 512 bytes for this function and interrupts), so that
    /// [`stack_used`] can find the deepest point the stack reached.
    pub fn paint_stack() {
        let sp = cortex_m::register::msp::read() as usize;
        let mut a = stack_floor();
        while a + 512 < sp {
            #[allow(unsafe_code)]
            // SAFETY: `a` lies between the end of the static data and 512 bytes below the current stack
            // pointer: memory no one uses yet.
            unsafe {
                core::ptr::write_volatile(a as *mut u32, PAINT)
            };
            a += 4;
        }
    }

    /// Bytes of stack used so far at most (from the top of RAM to the deepest overwritten paint), and the
    /// bytes between the static data and the top of RAM.
    pub fn stack_used() -> (usize, usize) {
        let floor = stack_floor();
        let mut a = floor;
        #[allow(unsafe_code)]
        // SAFETY: reads of plain RAM between the static data and the top of RAM.
        while a < RAM_END && unsafe { core::ptr::read_volatile(a as *const u32) } == PAINT {
            a += 4;
        }
        (RAM_END - a, RAM_END - floor)
    }

    impl Board {
        /// Reset clock (HSI), UART, tick; no sensors.
        pub fn init() -> Self {
            let (Some(dp), Some(mut cp)) = (pac::Peripherals::take(), cortex_m::Peripherals::take()) else {
                halt("peripherals already taken")
            };
            let mut rcc = dp.RCC.constrain();
            let gpioa = dp.GPIOA.split(&mut rcc);
            let Ok(serial) = Serial::new(
                dp.USART1,
                (gpioa.pa9, gpioa.pa10),
                SerialConfig::default().baudrate(BAUD.bps()),
                &mut rcc,
            ) else {
                halt("uart")
            };
            start_uart(serial, &mut cp.NVIC);
            let hw = Hardware::new();
            #[cfg(not(feature = "fil"))]
            {
                start_tick(cp.SYST, &mut cp.SCB, QEMU_COUNTS_PER_TICK);
                cortex_m_semihosting::hprintln!("firmware (qemu variant) started");
            }
            #[cfg(feature = "fil")]
            {
                // Free-running, no interrupt: measures steps without anything else running during them.
                let mut syst = cp.SYST;
                syst.set_clock_source(SystClkSource::Core);
                syst.set_reload(0x00FF_FFFF);
                syst.clear_current();
                syst.enable_counter();
                cortex_m_semihosting::hprintln!("firmware (firmware-in-the-loop variant) started");
            }
            Board { flash: Some(crate::config::Flash::new()), nonces: 0, rng_errors: 0, hw }
        }

        /// The synthetic forward camera: two frames of the line every 34 ms once the estimator has aligned (as
        /// if the second camera frame of a pair arrived with the first), captured 30 ms before they arrive, so
        /// that two pose solves run back to back as background work, over more than one tick and often over a
        /// control step, while the ticks and the steps go on.
        pub fn synthetic_frames(&mut self, time_us: u64) -> [Option<protocol::VisionMeasurement>; 2] {
            if cfg!(feature = "fil")
                || time_us < SYNTHETIC_FRAMES_FROM_US
                || !time_us.is_multiple_of(SYNTHETIC_FRAME_EVERY_US)
            {
                return [None; 2];
            }
            let hw = &mut self.hw;
            core::array::from_fn(|k| {
                hw.frame_seq = hw.frame_seq.wrapping_add(1);
                Some(protocol::VisionMeasurement {
                    capture_time_us: time_us - 30_000 + 1000 * k as u64,
                    frame_seq: hw.frame_seq,
                    observation: hw.frames[hw.frame_seq as usize % SYNTHETIC_FRAMES],
                })
            })
        }

        /// QEMU does not model the RNG: a nonce made unique (within a run) by a count and the cycle counter,
        /// not unpredictable. For tests under QEMU only; the board's comes from its hardware RNG.
        pub fn nonce(&mut self) -> Nonce {
            self.nonces = self.nonces.wrapping_add(1);
            self.fallback_nonce()
        }

        /// A synthetic IMU at rest: no rotation, gravity along body z.
        pub fn read_imu(&mut self, time_us: u64) -> Option<ImuSample> {
            Some(ImuSample { time_us, gyro_rad_s: [0.0; 3], accel_m_s2: [0.0, 0.0, control_core::GRAVITY] })
        }

        /// No magnetometer.
        pub fn read_mag(&mut self) -> Option<Vec3> {
            None
        }

        /// No battery sensor (the firmware in the loop takes the simulator's readings).
        pub fn read_battery(&mut self) -> Option<control_core::battery::BatteryReading> {
            None
        }

        /// No speed controllers (QEMU has no I2C).
        pub fn set_motors(&mut self, _speeds_rad_s: [f32; 4], _max_rad_s: f32) -> Result<(), ()> {
            Ok(())
        }

        /// After a fixed number of steps: report the counts over semihosting and exit.
        pub fn after_step(&mut self, steps: u32, s: &RunStats) {
            if steps >= QEMU_STEPS {
                self.report_and_exit(s);
            }
        }

        /// Reports the stack's high-water mark and the loop's counts over semihosting and exits.
        pub fn report_and_exit(&mut self, s: &RunStats) -> ! {
            // The firmware in the loop's background work after each step (cycles); on the board's schedule,
            // in the scheduling line.
            #[cfg(feature = "fil")]
            let background = (s.max_background, s.sum_background);
            #[cfg(not(feature = "fil"))]
            let background = (0u32, 0u64);
            let (used, room) = stack_used();
            cortex_m_semihosting::hprintln!("stack: used={} of {} bytes, free={}", used, room, room - used);
            #[cfg(not(feature = "fil"))]
            cortex_m_semihosting::hprintln!(
                "scheduling: tick_latency_max={} tick_latency_mean={} (instructions) ticks_during_solves={} steps_during_solves={} frames={} solves={} solved={} rejected={} frames_dropped={} solve_instructions_max={}",
                instructions(s.tick_latency_max as u64),
                instructions(s.tick_latency_sum / s.ticks.max(1) as u64),
                crate::background::TICKS_DURING_SOLVES.load(Ordering::Relaxed),
                crate::background::STEPS_DURING_SOLVES.load(Ordering::Relaxed),
                s.vision.frames,
                crate::background::SOLVES.load(Ordering::Relaxed),
                s.vision.solved,
                s.vision.rejected,
                s.vision.dropped,
                instructions(crate::background::SOLVE_CYCLES_MAX.load(Ordering::Relaxed) as u64),
            );
            cortex_m_semihosting::hprintln!(
                "loop ran: steps={} ticks={} imu_errors={} motor_errors={} imu_dropped={} step_cycles_max={} step_cycles_mean={} background_cycles_max={} background_cycles_total={} mode={:?} link_ok={} link_errors={} radio=\"{}\" auth_ok={} auth_refused={} arm_refused={} config_refused={} configs_applied={} link_cycles_max={} rng_errors={} rc_overflow={}",
                s.steps,
                TICKS.load(Ordering::Acquire),
                s.imu_errors,
                s.motor_errors,
                s.imu_dropped,
                s.max_cost,
                s.sum_cost / s.steps.max(1) as u64,
                background.0,
                background.1,
                s.mode,
                s.link.ok,
                s.link.errors(),
                s.radio,
                s.auth.auth.ok,
                s.auth.auth.refused(),
                s.auth.arm_refused,
                s.config_refused,
                s.configs_applied,
                s.max_link,
                self.rng_errors,
                self.rc_overflow()
            );
            cortex_m_semihosting::debug::exit(cortex_m_semihosting::debug::EXIT_SUCCESS);
            loop {
                cortex_m::asm::nop();
            }
        }
    }
}

use variant::Hardware;
#[cfg(feature = "qemu")]
pub use variant::paint_stack;
