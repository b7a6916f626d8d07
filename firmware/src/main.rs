//! Flight firmware of the wall-line quadrotor for an STM32F405 autopilot board.
//!
//! One loop, paced by SysTick at 1 kHz:
//!
//! - every tick: one IMU sample (MPU-6000 on SPI1);
//! - every 20th tick: the magnetometer (HMC5883L on I2C1);
//! - every 2nd tick (500 Hz): the bytes the radio modem delivered (USART1, interrupt-driven queue) are decoded
//!   and authenticated into link messages (`flight_core::radio`, with the key the debug probe wrote into flash;
//!   without one the development mode, which refuses to arm unless built with `unauthenticated-link`), `flight_core::FlightStack::step` runs (on-board pose solve, estimation, mission,
//!   failsafes, control laws, mixer), the rotor speeds go to the BL-Ctrl speed controllers (I2C1), and every
//!   20th step telemetry goes back down the link (`flight_core::telemetry`) with the step's measured cost.
//!
//! The `qemu` feature builds the QEMU `netduinoplus2` variant (see `board.rs`); the `fil` feature its
//! firmware-in-the-loop form, where the simulator drives the same step over the UART (`fil.rs`). Scheduling
//! choices are in docs/firmware.md.
#![no_std]
#![no_main]
#![deny(unsafe_code)]
// With the simulator driving the steps, the board loop's tick and sensor functions go unused.
#![cfg_attr(feature = "fil", allow(dead_code))]

mod board;
#[cfg(feature = "fil")]
mod fil;
mod link;
mod panic;

use cortex_m_rt::entry;
use defmt_rtt as _;
use flight_core::{FlightConfig, FlightStack};

/// Control period in ticks (500 Hz).
#[cfg(not(feature = "fil"))]
const STEP_EVERY: u32 = 2;
/// Magnetometer period in ticks (50 Hz).
#[cfg(not(feature = "fil"))]
const MAG_EVERY: u32 = 20;
#[entry]
fn main() -> ! {
    #[cfg(feature = "qemu")]
    board::paint_stack();
    let mut board = board::Board::init();
    let cfg = FlightConfig::paper();
    // The flight stack lives on main's stack frame (main never returns): built in place, not copied into a
    // static.
    let mut stack = match FlightStack::new(cfg) {
        Ok(s) => s,
        Err(e) => {
            defmt::error!("invalid flight parameters: {} ({})", e.field, e.problem);
            board::halt("invalid flight parameters")
        }
    };
    #[cfg(feature = "fil")]
    fil::run(&mut board, &mut stack);
    #[cfg(not(feature = "fil"))]
    run(&mut board, &mut stack, &cfg, radio_security())
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

/// The flight loop on the board's own sensors and motors.
#[cfg(not(feature = "fil"))]
fn run(
    board: &mut board::Board,
    stack: &mut FlightStack,
    cfg: &FlightConfig,
    security: flight_core::radio::Security,
) -> ! {
    use control_core::estimator::ImuSample;
    use drivers::blctrl::command_for_speed;
    use flight_core::StepInput;
    use flight_core::radio::{Incoming, VehicleRadio};
    use geometry::Vec3;
    use heapless::Vec;
    use protocol::Uplink;
    use protocol::frame::MAX_FRAME;
    let motor_max = cfg.control.vehicle.motor_speed_max_rad_s;
    let mut radio = VehicleRadio::new(security);
    let mut reply = [0u8; MAX_FRAME];
    let mut imu: Vec<ImuSample, 4> = Vec::new();
    let mut mag: Option<Vec3> = None;
    let mut downlinks = flight_core::telemetry::DownlinkSchedule::new();
    let mut stats = board::RunStats::default();
    defmt::info!("flight firmware running");

    loop {
        let tick = board.wait_tick();
        let time_us = tick as u64 * 1000;
        match board.read_imu(time_us) {
            Some(s) => {
                // Keep the newest samples if the step fell behind, and count the one given up.
                if imu.is_full() {
                    imu.remove(0);
                    stats.imu_dropped += 1;
                }
                // Cannot fail: a place was made above.
                let _ = imu.push(s);
            }
            None => stats.imu_errors += 1,
        }
        if tick.is_multiple_of(MAG_EVERY) {
            mag = board.read_mag();
        }
        if !tick.is_multiple_of(STEP_EVERY) {
            continue;
        }
        // Link: decode and authenticate what arrived, outside the step's timing (docs/security.md, "Cost").
        let mut uplink: Vec<Uplink, 8> = Vec::new();
        let armed = stats.mode != control_core::FlightMode::Disarmed;
        let t_link = board.cycles();
        while let Some(byte) = board.rx_byte() {
            match radio.push(byte, time_us, armed, || board.nonce(), &mut reply) {
                Some(Incoming::Message(msg)) => {
                    if uplink.push(msg).is_err() {
                        stats.uplink_dropped += 1;
                    }
                }
                Some(Incoming::Reply(n)) => {
                    if !link::send_frame(board, &reply[..n]) {
                        stats.downlink_dropped += 1;
                    }
                }
                Some(Incoming::Refused) | None => {}
            }
        }
        stats.record_link(board.cycles_since(t_link));
        let t0 = board.cycles();
        let out = stack.step(&StepInput {
            time_us,
            imu: &imu,
            mag: mag.take(),
            baro_m: None,
            uplink: &uplink,
            landed: None,
        });
        let step_cost = board.cycles_since(t0);
        stats.record_step(step_cost);
        imu.clear();
        let cmd = out.control.motors_rad_s.map(|w| command_for_speed(w, motor_max));
        if board.set_motors(cmd).is_err() {
            stats.motor_errors += 1;
        }
        let every = out.telemetry_every;
        let t_link = board.cycles();
        downlinks.after_step(&out.control, out.param_reply, out.time_sync, time_us, step_cost, every, |m| {
            if !link::send(board, &mut radio, &m) {
                stats.downlink_dropped += 1;
            }
        });
        if let Some(status) = radio.status_due(time_us)
            && !link::send(board, &mut radio, &status)
        {
            stats.downlink_dropped += 1;
        }
        stats.record_link(board.cycles_since(t_link));
        stats.mode = out.control.status.mode;
        stats.link = radio.framing();
        stats.radio = radio.describe();
        stats.auth = radio.status();
        // Background work: the pose solves of the frames this step queued, fused by the next step. It runs
        // in this loop, so a solve delays the next tick's IMU read (see docs/firmware.md, "Timing").
        if stack.pending_solves() > 0 {
            let t1 = board.cycles();
            stack.solve_pending();
            stats.record_background(board.cycles_since(t1));
        }
        board.after_step(downlinks.steps(), &stats);
    }
}
