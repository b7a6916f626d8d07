//! Flight firmware of the wall-line quadrotor for an STM32F405 autopilot board.
//!
//! The control loop runs in the SysTick exception at 1 kHz (`sched.rs`, `control.rs`):
//!
//! - every tick: one IMU sample (MPU-6000 on SPI1);
//! - every 20th tick: the magnetometer (HMC5883L on I2C1);
//! - every 2nd tick (500 Hz): the bytes the radio modem delivered (USART1, interrupt-driven queue) are decoded
//!   and authenticated into link messages (`flight_core::radio`, with the key the debug probe wrote into flash;
//!   without one the development mode, which refuses to arm unless built with `unauthenticated-link`),
//!   `flight_core::FlightStack::step` runs (estimation, mission, failsafes, control laws, mixer), the rotor
//!   speeds go to the BL-Ctrl speed controllers (I2C1), and every 20th step telemetry goes back down the link
//!   (`flight_core::telemetry`) with the step's measured cost.
//!
//! Thread mode runs the background work (`background.rs`): the on-board pose solves of the vision frames, which
//! the control loop preempts.
//!
//! The `qemu` feature builds the QEMU `netduinoplus2` variant (see `board.rs`); the `fil` feature its
//! firmware-in-the-loop form, where the simulator drives the same step over the UART (`fil.rs`). Scheduling
//! choices are in docs/firmware.md.
#![no_std]
#![no_main]
#![deny(unsafe_code)]
// With the simulator driving the steps, the board loop's tick and sensor functions go unused.
#![cfg_attr(feature = "fil", allow(dead_code))]

#[cfg(not(feature = "fil"))]
mod background;
mod board;
mod config;
#[cfg(not(feature = "fil"))]
mod control;
#[cfg(all(feature = "matek-f405-se", not(feature = "qemu")))]
mod dshot_out;
#[cfg(feature = "fil")]
mod fil;
#[cfg(feature = "fil")]
mod fil_io;
mod link;
mod panic;
#[cfg(not(feature = "fil"))]
mod sched;

use cortex_m_rt::entry;
use defmt_rtt as _;
use flight_core::{FlightConfig, FlightStack};
use static_cell::StaticCell;

/// The flight stack (about 21 KB), built in place once at boot.
static STACK: StaticCell<FlightStack> = StaticCell::new();

#[entry]
fn main() -> ! {
    #[cfg(feature = "qemu")]
    board::paint_stack();
    #[cfg_attr(not(feature = "fil"), allow(unused_mut))]
    let mut board = board::Board::init();
    // The stored configuration, or the built-in one (docs/firmware.md, "Parameters in flash").
    let mut store = config::store(board.take_flash());
    let (mut cfg, report) = config::at_boot(&mut store);
    defmt::info!("flight configuration: {} ({})", config::describe(&report), report);
    // Checked first, so that the stack is built in its static place by one infallible constructor.
    if let Err(e) = FlightStack::check_config(&cfg) {
        // The store checks what it loads; the built-in configuration is checked by the tests.
        defmt::error!("invalid flight configuration: {} ({}); the built-in one instead", e.field, e.problem);
        cfg = FlightConfig::paper();
        if FlightStack::check_config(&cfg).is_err() {
            board::halt("invalid flight parameters")
        }
    }
    let stack = STACK.init_with(|| FlightStack::new_checked(cfg));
    #[cfg(feature = "fil")]
    fil::run(&mut board, stack, store);
    #[cfg(not(feature = "fil"))]
    {
        background::set_vision(*stack.vision_config());
        let flight = control::Flight::new(stack, &cfg, radio_security(), store);
        sched::start(sched::Control { board, flight });
        background::run()
    }
}

/// The radio's security from the key block in flash (docs/security.md, "Provisioning a board").
#[cfg(not(feature = "fil"))]
fn radio_security() -> flight_core::radio::Security {
    use flight_core::radio::Security;
    use protocol::auth::provision::{KeyBlockError, read_key_block};
    let allow = cfg!(feature = "unauthenticated-link");
    match read_key_block(&board::key_block()) {
        Ok(k) => {
            defmt::info!("radio key provisioned: authenticated link");
            Security::Keyed(k)
        }
        Err(KeyBlockError::Erased) => {
            defmt::warn!(
                "no radio key: development mode, arming {}",
                if allow { "allowed" } else { "refused" }
            );
            Security::Development { allow_arming: allow }
        }
        Err(e) => {
            // A damaged block is a fault, not a choice: never armed on an unauthenticated link.
            defmt::error!("radio key block unreadable ({}): development mode, arming refused", e);
            Security::Development { allow_arming: false }
        }
    }
}
