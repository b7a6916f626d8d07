//! Firmware in the loop (`--features fil`): the flight loop with the simulator in place of the board's sensors,
//! motors and clock.
//!
//! The same flight stack and the same downlink logic as the board's loop, but paced by the simulator over the
//! radio UART (`flight_core::fil`): radio messages arrive as `FilToFc::Link`, each control period's sensors as
//! `FilToFc::Step`, upon which the step runs and the radio messages it produces and its report go back
//! (`FcToFil::Link`, then `FcToFil::Step` last). SysTick runs free, without interrupts, only to measure each
//! step and the background work (pose solves) that follows it: nothing else executes meanwhile, so under
//! QEMU's instruction counting their costs are exact.
use crate::board::{self, Board};
use crate::link;
use flight_core::fil::{FcToFil, FilToFc};
use flight_core::{FlightStack, StepInput};
use heapless::Vec;
use protocol::Uplink;
use protocol::frame::{Decoder, WIRE_VERSION};

/// Serves steps until the simulator says stop.
pub fn run(board: &mut Board, stack: &mut FlightStack) -> ! {
    let mut decoder = Decoder::new();
    let mut uplink: Vec<Uplink, 8> = Vec::new();
    let mut downlinks = flight_core::telemetry::DownlinkSchedule::new();
    let mut stats = board::RunStats::default();
    let (mut background_cycles, mut background_solves) = (0u32, 0u8);
    link::send_plain(board, &FcToFil::Hello { wire_version: WIRE_VERSION });
    loop {
        let Some(byte) = board.rx_byte_or_sleep() else { continue };
        match decoder.push::<FilToFc>(byte) {
            Some(Ok(FilToFc::Link(m))) => {
                if uplink.push(m).is_err() {
                    stats.uplink_dropped += 1;
                }
            }
            Some(Ok(FilToFc::Step(s))) => {
                let t0 = board::cycles();
                let out = stack.step(&StepInput {
                    time_us: s.time_us,
                    imu: &s.imu,
                    mag: s.mag,
                    baro_m: s.baro_m,
                    uplink: &uplink,
                    landed: s.landed,
                });
                let cost = board::cycles_since(t0);
                uplink.clear();
                stats.record_step(cost);
                stats.mode = out.control.status.mode;
                let every = out.telemetry_every;
                downlinks.after_step(
                    &out.control,
                    out.param_reply,
                    out.time_sync,
                    s.time_us,
                    cost,
                    every,
                    |m| link::send_plain(board, &FcToFil::Link(m)),
                );
                link::send_plain(
                    board,
                    &FcToFil::Step {
                        report: out.report(),
                        cost_cycles: cost,
                        background_cycles,
                        background_solves,
                    },
                );
                // Background work, as the board runs it between steps and the simulator after its step.
                let t1 = board::cycles();
                background_solves = stack.solve_pending().min(u8::MAX as usize) as u8;
                background_cycles = board::cycles_since(t1);
                stats.record_background(background_cycles);
            }
            Some(Ok(FilToFc::AuthCost)) => {
                let cost = flight_core::fil::measure_auth_cost(board::cycles);
                link::send_plain(board, &FcToFil::AuthCost(cost));
            }
            Some(Ok(FilToFc::Stop)) => {
                stats.link = decoder.counters();
                board.report_and_exit(&stats);
            }
            // Framing errors are counted by the decoder; the simulator times out on a lost step.
            Some(Err(_)) | None => {}
        }
    }
}
