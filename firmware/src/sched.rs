//! Scheduling on the board: the control loop in the SysTick exception at 1 kHz, above thread mode, where the
//! background work runs (docs/firmware.md, "Scheduling").
//!
//! Priorities (lower number, more urgent; the STM32F4 keeps the top four bits):
//!
//! | what | where | priority |
//! |---|---|---|
//! | radio UART bytes in and out | USART1 interrupt | `board::UART_PRIORITY` |
//! | IMU, step, motors, downlink | SysTick exception | `board::TICK_PRIORITY` |
//! | pose solves | thread mode ([`crate::background::run`]) | lowest |
//!
//! A tick's exception starts as soon as the tick is due unless a UART interrupt or a critical section (a few
//! hundred cycles at most: a byte queued, a job handed over) is running: the background work never delays
//! it. Its latency (cycles from the tick to the exception's first instruction) is measured on every tick
//! (`RunStats::tick_latency_max`).
use crate::board::{self, Board, TICKS};
use crate::control::Flight;
use core::cell::RefCell;
use core::sync::atomic::Ordering;
use cortex_m::interrupt::Mutex;
use cortex_m_rt::exception;
use static_cell::StaticCell;

/// What the control loop owns.
pub struct Control {
    /// The board's peripherals.
    pub board: Board,
    /// The loop's state and the flight stack.
    pub flight: Flight,
}

// SAFETY: the one `Control` is built in thread mode, handed over once through `HANDOFF` and from then on used
// by the SysTick exception alone (single core): the peripherals it holds (the I2C bus the magnetometer and the
// speed controllers share through a `RefCell`) are never used from two contexts.
#[allow(unsafe_code)]
unsafe impl Send for Control {}

static CONTROL: StaticCell<Control> = StaticCell::new();
/// The control loop's state, from `start` until the first tick takes it.
static HANDOFF: Mutex<RefCell<Option<&'static mut Control>>> = Mutex::new(RefCell::new(None));

/// Hands the board and the loop to the SysTick exception; the ticks (already counting) run the loop from the
/// next one on.
pub fn start(control: Control) {
    let control = CONTROL.init(control);
    cortex_m::interrupt::free(|cs| HANDOFF.borrow(cs).replace(Some(control)));
}

#[exception]
fn SysTick() {
    static mut MINE: Option<&'static mut Control> = None;
    let latency = board::tick_latency();
    let tick = TICKS.fetch_add(1, Ordering::AcqRel).wrapping_add(1);
    if MINE.is_none() {
        *MINE = cortex_m::interrupt::free(|cs| HANDOFF.borrow(cs).take());
    }
    if let Some(c) = MINE.as_deref_mut() {
        c.flight.tick(&mut c.board, tick, latency);
    }
}
