//! Flight firmware of the wall-line quadrotor for an STM32F405 autopilot board.
//!
//! One loop, paced by SysTick at 1 kHz:
//!
//! - every tick: one IMU sample (MPU-6000 on SPI1);
//! - every 20th tick: the magnetometer (HMC5883L on I2C1);
//! - every 2nd tick (500 Hz): the bytes the radio modem delivered (USART1, interrupt-driven queue) are decoded
//!   into link messages, `flight_core::FlightStack::step` runs (on-board pose solve, estimation, mission,
//!   failsafes, control laws, mixer), the rotor speeds go to the BL-Ctrl speed controllers (I2C1), and every
//!   20th step telemetry goes back down the link with the step's measured cost.
//!
//! The `qemu` feature builds the QEMU `netduinoplus2` variant (see `board.rs`). Scheduling choices are in
//! docs/firmware.md.
#![no_std]
#![no_main]
#![deny(unsafe_code)]

mod board;
mod link;
mod panic;

use control_core::CommandResult;
use control_core::estimator::ImuSample;
use cortex_m_rt::entry;
use defmt_rtt as _;
use drivers::blctrl::command_for_speed;
use flight_core::{FlightConfig, FlightStack, StepInput};
use geometry::Vec3;
use heapless::Vec;
use protocol::{Downlink, Telemetry, Uplink};

/// Control period in ticks (500 Hz).
const STEP_EVERY: u32 = 2;
/// Magnetometer period in ticks (50 Hz).
const MAG_EVERY: u32 = 20;
/// Telemetry period in control steps (25 Hz).
const TELEMETRY_EVERY: u32 = 20;

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
    let motor_max = cfg.control.vehicle.motor_speed_max_rad_s;
    let mut decoder = protocol::frame::Decoder::new();
    let mut imu: Vec<ImuSample, 4> = Vec::new();
    let mut mag: Option<Vec3> = None;
    let mut last_command: Option<CommandResult> = None;
    let mut steps: u32 = 0;
    let mut stats = board::RunStats::default();
    defmt::info!("flight firmware running");

    loop {
        let tick = board.wait_tick();
        let time_us = tick as u64 * 1000;
        match board.read_imu(time_us) {
            Some(s) => {
                // Keep the newest samples if the step fell behind.
                if imu.is_full() {
                    imu.remove(0);
                }
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
        // Link: decode what arrived.
        let mut uplink: Vec<Uplink, 8> = Vec::new();
        while let Some(byte) = board.rx_byte() {
            if let Some(Ok(msg)) = decoder.push::<Uplink>(byte)
                && uplink.push(msg).is_err()
            {
                stats.uplink_dropped += 1;
            }
        }
        let t0 = board.cycles();
        let out = stack.step(&StepInput { time_us, imu: &imu, mag: mag.take(), uplink: &uplink });
        let step_cost = board.cycles().wrapping_sub(t0);
        stats.record_step(step_cost);
        imu.clear();
        let cmd = out.control.motors_rad_s.map(|w| command_for_speed(w, motor_max));
        if board.set_motors(cmd).is_err() {
            stats.motor_errors += 1;
        }
        steps = steps.wrapping_add(1);
        // Downlink: command acknowledgements and periodic telemetry.
        let st = out.control.status;
        if st.last_command != last_command {
            last_command = st.last_command;
            if let Some(r) = st.last_command {
                link::send(&mut board, &Downlink::CommandAck(r));
            }
        }
        if let Some(r) = out.param_reply {
            link::send(&mut board, &Downlink::Param(r));
        }
        if steps.is_multiple_of(TELEMETRY_EVERY) {
            let t = Telemetry {
                time_us,
                mode: st.mode,
                failsafe: st.failsafe,
                estimate: out.control.estimate,
                setpoint: out.control.setpoint,
                motors_rad_s: out.control.motors_rad_s,
                fix_age_s: st.fix_age_s,
                step_cost,
            };
            link::send(&mut board, &Downlink::Telemetry(t));
        }
        stats.mode = st.mode;
        stats.link = decoder.counters();
        board.after_step(steps, &stats);
    }
}
