//! Firmware in the loop (`--features fil`): the flight loop with the simulator in place of the board's sensors,
//! motors and clock.
//!
//! The same flight stack and the same downlink logic as the board's loop, but paced by the simulator over two
//! host pipes (`fil_io.rs`, `flight_core::fil`): radio messages arrive as `FilToFc::Link`, each control
//! period's sensors as `FilToFc::Step`, upon which the step runs and the radio messages it produces and its
//! report go back (`FcToFil::Link`, then `FcToFil::Step` last), and then the background work (the pose solves)
//! runs before the next message is read, the order the simulator assumes. SysTick runs free, without
//! interrupts, only to measure each step and the background work: nothing else executes meanwhile, so under
//! QEMU's instruction counting their costs are exact.
use crate::board::{self, Board};
use crate::fil_io::FilIo;
use flight_core::config_upload::ConfigUpload;
use flight_core::fil::{FcToFil, FilToFc};
use flight_core::param_store::ParamStore;
use flight_core::{FlightStack, StepInput};
use heapless::Vec;
use protocol::frame::{Decoder, MAX_FRAME, WIRE_VERSION, encode};
use protocol::{Downlink, Uplink};

/// Frames `msg` and writes it to the simulator; a message that cannot be framed is counted.
fn send(io: &mut FilIo, msg: &FcToFil, stats: &mut board::RunStats) {
    let mut buf = [0u8; MAX_FRAME];
    match encode(msg, &mut buf) {
        Ok(frame) => io.write(frame),
        Err(_) => stats.downlink_dropped += 1,
    }
}

/// Serves steps until the simulator says stop.
pub fn run(
    board: &mut Board,
    stack: &mut FlightStack,
    mut store: Option<ParamStore<crate::config::Flash>>,
) -> ! {
    let Some(mut io) = FilIo::open() else {
        board::halt("no simulator: the firmware in the loop reads the pipes fil-to-fc and fil-from-fc")
    };
    let mut decoder = Decoder::new();
    let mut uplink: Vec<Uplink, 8> = Vec::new();
    let mut downlinks = flight_core::telemetry::DownlinkSchedule::new();
    let mut stats = board::RunStats::default();
    let (mut background_cycles, mut background_solves) = (0u32, 0u8);
    let mut rx = [0u8; 512];
    let mut upload = ConfigUpload::new();
    // The pilot's transmitter (the simulator's receiver's) and the battery's reading for the next step, when
    // there are.
    let mut pilot = None;
    let mut battery = None;
    send(&mut io, &FcToFil::Hello { wire_version: WIRE_VERSION }, &mut stats);
    loop {
        let n = io.read(&mut rx);
        if n == 0 {
            board::halt("the simulator closed the firmware in the loop's pipe")
        }
        for &byte in &rx[..n] {
            match decoder.push::<FilToFc>(byte) {
                // A configuration upload (the simulator sends the scenario's before the first step): put
                // together, applied and stored when whole, and answered at once, as the board does.
                Some(Ok(FilToFc::Link(Uplink::Config(c)))) => {
                    if let Some(ack) = crate::config::take_piece(&mut upload, &c, stack, &mut store, |_| {}) {
                        send(&mut io, &FcToFil::Link(Downlink::ConfigAck(ack)), &mut stats);
                    }
                }
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
                        pilot: pilot.take(),
                        battery: battery.take(),
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
                        out.battery,
                        |m| send(&mut io, &FcToFil::Link(m), &mut stats),
                    );
                    send(
                        &mut io,
                        &FcToFil::Step {
                            report: out.report(),
                            cost_cycles: cost,
                            background_cycles,
                            background_solves,
                        },
                        &mut stats,
                    );
                    // Background work, as the board runs it between steps and the simulator after its step.
                    let t1 = board::cycles();
                    background_solves = stack.solve_pending().min(u8::MAX as usize) as u8;
                    background_cycles = board::cycles_since(t1);
                    stats.record_background(background_cycles);
                }
                Some(Ok(FilToFc::Pilot(p))) => pilot = Some(p),
                Some(Ok(FilToFc::Battery(b))) => battery = Some(b),
                Some(Ok(FilToFc::AuthCost)) => {
                    let cost = flight_core::fil::measure_auth_cost(board::cycles);
                    send(&mut io, &FcToFil::AuthCost(cost), &mut stats);
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
}
