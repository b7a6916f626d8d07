//! The board's control loop: what happens on each 1 ms tick, run by the SysTick exception (`sched.rs`).
//!
//! - every tick: one IMU sample;
//! - every [`MAG_EVERY`]th tick: the magnetometer;
//! - every [`STEP_EVERY`]th tick (500 Hz): the radio's bytes are decoded and authenticated, the frames the
//!   background work solved are handed to the flight stack, `flight_core::FlightStack::step` runs, the rotor
//!   speeds go to the speed controllers, the downlink is queued, and the frames the step queued for their pose
//!   solve go to the background work (`background.rs`), which runs in thread mode, preempted by this.
use crate::background;
use crate::board::{self, Board, RunStats};
use crate::link;
use control_core::estimator::ImuSample;
use flight_core::config_upload::ConfigUpload;
use flight_core::param_store::ParamStore;
use flight_core::radio::{Incoming, Security, VehicleRadio};
use flight_core::telemetry::DownlinkSchedule;
use flight_core::{FlightConfig, FlightStack, StepInput};
use geometry::Vec3;
use heapless::Vec;
use protocol::frame::MAX_FRAME;
use protocol::{Downlink, Uplink};

/// Control period in ticks (500 Hz).
pub const STEP_EVERY: u32 = 2;
/// Magnetometer period in ticks (50 Hz).
pub const MAG_EVERY: u32 = 20;

/// The control loop's state, owned by the SysTick exception once the scheduler starts.
pub struct Flight {
    stack: &'static mut FlightStack,
    radio: VehicleRadio,
    reply: [u8; MAX_FRAME],
    imu: Vec<ImuSample, 4>,
    mag: Option<Vec3>,
    battery: Option<control_core::battery::BatteryReading>,
    downlinks: DownlinkSchedule,
    motor_max: f32,
    stats: RunStats,
    /// A configuration upload being put together, and the flash store it goes to.
    upload: ConfigUpload,
    store: Option<ParamStore<crate::config::Flash>>,
    /// The pilot's RC receiver (`flight_core::rc`): the RC UART's bytes in, the pilot's input out.
    rc: flight_core::rc::RcReceiver,
}

impl Flight {
    /// The loop's state around a flight stack built from `cfg`.
    pub fn new(
        stack: &'static mut FlightStack,
        cfg: &FlightConfig,
        security: Security,
        store: Option<ParamStore<crate::config::Flash>>,
    ) -> Self {
        Self {
            stack,
            radio: VehicleRadio::new(security),
            reply: [0u8; MAX_FRAME],
            imu: Vec::new(),
            mag: None,
            battery: None,
            downlinks: DownlinkSchedule::new(),
            motor_max: cfg.control.vehicle.motor_speed_max_rad_s,
            stats: RunStats::default(),
            upload: ConfigUpload::new(),
            store,
            rc: flight_core::rc::RcReceiver::new(cfg.control.rc.channel_map),
        }
    }

    /// The work of tick number `tick`, whose exception started `latency` cycles after the tick.
    pub fn tick(&mut self, board: &mut Board, tick: u32, latency: u32) {
        self.stats.record_tick_latency(latency);
        background::note_tick(tick.is_multiple_of(STEP_EVERY));
        let time_us = tick as u64 * 1000;
        match board.read_imu(time_us) {
            Some(s) => {
                // Keep the newest samples if a step was missed, and count the one given up.
                if self.imu.is_full() {
                    self.imu.remove(0);
                    self.stats.imu_dropped += 1;
                }
                // Cannot fail: a place was made above.
                let _ = self.imu.push(s);
            }
            None => self.stats.imu_errors += 1,
        }
        if tick.is_multiple_of(MAG_EVERY) {
            self.mag = board.read_mag();
            // The battery at the same 50 Hz.
            self.battery = board.read_battery();
        }
        if tick.is_multiple_of(STEP_EVERY) {
            self.step(board, time_us);
        }
    }

    fn step(&mut self, board: &mut Board, time_us: u64) {
        let stats = &mut self.stats;
        // Link: decode and authenticate what arrived, outside the step's timing (docs/security.md, "Cost").
        let mut uplink: Vec<Uplink, 8> = Vec::new();
        let armed = stats.mode != control_core::FlightMode::Disarmed;
        let t_link = board::cycles();
        while let Some(byte) = board.rx_byte() {
            match self.radio.push(byte, time_us, armed, || board.nonce(), &mut self.reply) {
                // A configuration upload's piece: put together here, applied and stored when whole
                // (docs/firmware.md, "Parameters in flash"); the flight stack never sees it.
                Some(Incoming::Message(Uplink::Config(c))) => {
                    let (motor_max, rc) = (&mut self.motor_max, &mut self.rc);
                    let ack =
                        crate::config::take_piece(&mut self.upload, &c, self.stack, &mut self.store, |cfg| {
                            *motor_max = cfg.control.vehicle.motor_speed_max_rad_s;
                            rc.set_channel_map(cfg.control.rc.channel_map);
                            background::set_vision(cfg.vision);
                        });
                    if let Some(ack) = ack {
                        if matches!(ack.outcome, protocol::ConfigOutcome::Applied { .. }) {
                            stats.configs_applied += 1;
                        }
                        if !link::send(board, &mut self.radio, &Downlink::ConfigAck(ack)) {
                            stats.downlink_dropped += 1;
                        }
                    }
                }
                Some(Incoming::Message(msg)) => {
                    if uplink.push(msg).is_err() {
                        stats.uplink_dropped += 1;
                    }
                }
                Some(Incoming::Reply(n)) => {
                    if !link::send_frame(board, &self.reply[..n]) {
                        stats.downlink_dropped += 1;
                    }
                }
                Some(Incoming::Refused) | None => {}
            }
        }
        // The QEMU variant's synthetic camera (a frame of the line now and then, so that pose solves run as
        // background work while the steps go on); none on the board, whose frames come over the radio.
        for m in board.synthetic_frames(time_us).into_iter().flatten() {
            if uplink.push(Uplink::Vision(m)).is_err() {
                stats.uplink_dropped += 1;
            }
        }
        stats.record_link(board::cycles_since(t_link));
        // The pilot's transmitter: the RC receiver's bytes since the last step.
        while let Some(b) = board.rc_byte() {
            self.rc.push(b, time_us);
        }
        let pilot = self.rc.pilot(time_us);
        // The frames the background work solved since the previous step, for this step to fuse.
        background::deliver_solved(self.stack);
        let t0 = board::cycles();
        let out = self.stack.step(&StepInput {
            time_us,
            imu: &self.imu,
            mag: self.mag.take(),
            baro_m: None,
            uplink: &uplink,
            landed: None,
            pilot,
            battery: self.battery.take(),
        });
        let step_cost = board::cycles_since(t0);
        stats.record_step(step_cost);
        self.imu.clear();
        // The frames this step queued, to the background work.
        background::hand_over_jobs(self.stack);
        if board.set_motors(out.control.motors_rad_s, self.motor_max).is_err() {
            stats.motor_errors += 1;
        }
        let every = out.telemetry_every;
        let t_link = board::cycles();
        let radio = &mut self.radio;
        self.downlinks.after_step(
            &out.control,
            out.param_reply,
            out.time_sync,
            time_us,
            step_cost,
            every,
            out.battery,
            |m| {
                if !link::send(board, radio, &m) {
                    stats.downlink_dropped += 1;
                }
            },
        );
        if let Some(status) = radio.status_due(time_us)
            && !link::send(board, radio, &status)
        {
            stats.downlink_dropped += 1;
        }
        stats.record_link(board::cycles_since(t_link));
        stats.mode = out.control.status.mode;
        stats.link = radio.framing();
        stats.radio = radio.describe();
        stats.auth = radio.status();
        stats.config_refused = radio.config_refused();
        stats.vision = out.vision;
        board.after_step(self.downlinks.steps(), stats);
    }
}
