//! The flight stack: the one [`FlightStack::step`] that the firmware, the simulator (software in the loop) and
//! log replay all call.
//!
//! It takes one control period's inputs (IMU samples, magnetometer, the radio link's messages) and returns the
//! rotor speed commands and a status. Vision measurements from the ground station arrive as line
//! observations ([`protocol::VisionMeasurement`]); the stack solves each one's pose **on board** with
//! [`vision_core::solve_pose`], taking roll and pitch from the estimator's attitude *at the frame's capture
//! time* (kept in the estimator's history), then fuses the fix. See `docs/architecture.md` for why the solve
//! runs on board rather than on the ground.
//!
//! The pose solve costs ten times a control step, so it is not part of one: [`FlightStack::step`] only
//! queues the frame with its capture-time attitude ([`SolveJob`]), [`FlightStack::solve_pending`] solves the
//! queue as background work (after the step, at lower priority), and the next step fuses the fixes. Every
//! caller runs them in this order (step, then background work), so that the simulator, replay and the
//! firmware in the loop compute the same bits; on the board the background work runs in thread mode, preempted
//! by the steps (in the tick's exception), taking each job ([`FlightStack::take_job`]) and handing its outcome
//! back ([`FlightStack::deliver`]).
//!
//! Optical-flow measurements of the downward camera arrive as flow statistics of a frame pair
//! ([`protocol::FlowMeasurement`]); [`flow`] derotates them with the gyro over exactly the frame interval and
//! scales them by the range into a body velocity for the estimator.
//!
//! `vision-core` and `control-core` do not depend on each other; this crate is the only place they meet.
#![cfg_attr(not(test), no_std)]
#![forbid(unsafe_code)]
#![warn(missing_docs)]
#![cfg_attr(not(test), deny(clippy::unwrap_used, clippy::expect_used, clippy::panic))]
// `!(x > 0.0)` deliberately rejects NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod config_upload;
pub mod fil;
pub mod flow;
pub mod param_store;
pub mod radio;
pub mod rc;
pub mod telemetry;

use control_core::estimator::{BodyVelocity, ImuSample, PositionFix};
use control_core::params::{FlightParams, ParamError};
use control_core::{Command, ControlCore, ControlInputs, ControlOutputs};
use flow::{FlowConfig, FlowCounters, FlowOutcome, GyroHistory};
use geometry::Vec3;
use protocol::{Uplink, VisionMeasurement};
use vision_core::{
    AttitudeSource, CameraModel, CameraMount, LineTarget, PoseError, PoseParams, PoseSolution,
};

/// What the on-board pose solve needs to know about the forward camera and the line.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize, postcard_schema::Schema)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct VisionConfig {
    /// Intrinsics of the forward camera.
    pub camera: CameraModel,
    /// The painted line.
    pub target: LineTarget,
    /// Where the camera sits on the vehicle.
    pub mount: CameraMount,
    /// Pose solver options.
    pub pose: PoseParams,
    /// Lower bound of the attitude standard deviation given to the solver (rad).
    pub attitude_sigma_floor_rad: f32,
}

impl Default for VisionConfig {
    /// The paper's camera and line.
    fn default() -> Self {
        Self {
            camera: CameraModel::PAPER_FORWARD,
            target: LineTarget::PAPER,
            mount: CameraMount::FORWARD_AT_CENTRE,
            pose: PoseParams::default(),
            attitude_sigma_floor_rad: 0.02,
        }
    }
}

/// Everything the flight stack needs.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize, postcard_schema::Schema)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FlightConfig {
    /// Control, estimation, mission, failsafes.
    pub control: FlightParams,
    /// The on-board pose solve.
    pub vision: VisionConfig,
    /// The use of the downward camera's flow.
    pub flow: FlowConfig,
}

impl FlightConfig {
    /// The paper's experiment.
    pub fn paper() -> Self {
        Self { control: FlightParams::paper(), vision: VisionConfig::default(), flow: FlowConfig::default() }
    }
}

/// The inputs of one control period.
#[derive(Clone, Copy, Debug)]
pub struct StepInput<'a> {
    /// Time of this step (us, vehicle clock).
    pub time_us: u64,
    /// IMU samples since the previous step, oldest first.
    pub imu: &'a [ImuSample],
    /// A new magnetometer reading (body frame), if any.
    pub mag: Option<Vec3>,
    /// A new barometric pressure altitude (m, any offset), if any.
    pub baro_m: Option<f32>,
    /// Messages received from the ground station since the previous step, in arrival order.
    pub uplink: &'a [Uplink],
    /// An external land detector's verdict (the recorded vehicle's, in imported logs); `None` in flight.
    pub landed: Option<bool>,
    /// The pilot's transmitter, when a receiver has been heard (`control_core::pilot`).
    pub pilot: Option<control_core::pilot::PilotInput>,
    /// A new reading of the flight battery, if any (`control_core::battery`).
    pub battery: Option<control_core::battery::BatteryReading>,
}

/// The outcome of this step's vision frame, if one arrived.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FrameOutcome {
    /// The frame had no line.
    NoTarget,
    /// No attitude stored for the capture time (too old, or from the future).
    NoAttitude,
    /// The solver rejected the measurement.
    Rejected(PoseError),
    /// A pose.
    Solved(PoseSolution),
    /// The same observation as the frame before, bit for bit: a frozen camera or driver repeating its last
    /// frame with new times (two real frames never agree to the last bit of their edge statistics).
    Frozen,
}

/// Counters of the vision frames the stack received.
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize, postcard_schema::Schema,
)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct VisionCounters {
    /// Frames received.
    pub frames: u32,
    /// Frames without the line.
    pub no_target: u32,
    /// Frames whose pose was solved.
    pub solved: u32,
    /// Frames the solver rejected or could not place in time.
    pub rejected: u32,
    /// Frames dropped unsolved because newer ones filled the solve queue (the background work fell behind).
    pub dropped: u32,
    /// Frames refused as repeats of the frame before ([`FrameOutcome::Frozen`]).
    pub frozen: u32,
}

/// A frame waiting for its pose solve: the measurement and the estimator's attitude at its capture time.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SolveJob {
    /// The frame's line observation and capture time.
    pub measurement: VisionMeasurement,
    /// What the solver takes from the IMU: roll and pitch at the capture time and their uncertainty.
    pub attitude: AttitudeSource,
}

/// Frames that may wait for the solver; a newer frame pushes out the oldest.
pub const SOLVE_QUEUE: usize = 2;

/// What one step returns.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StepOutput {
    /// Control outputs: rotor speeds, status, estimate, setpoint.
    pub control: ControlOutputs,
    /// The outcome of the frame this step used: solved since the previous step, or without a line or an
    /// attitude (the last one when several).
    pub frame: Option<FrameOutcome>,
    /// Vision counters since start.
    pub vision: VisionCounters,
    /// This step's flow measurement, if any (the last one when several arrived).
    pub flow: Option<FlowOutcome>,
    /// Flow counters since start.
    pub flow_counters: FlowCounters,
    /// The answer to a parameter request: this step's, or one that waited (several that arrive in one step
    /// are answered one a step, in order).
    pub param_reply: Option<control_core::ParamReply>,
    /// The station time of this step's clock-synchronisation request, to echo with this step's time (the last,
    /// when several arrived).
    pub time_sync: Option<u64>,
    /// What the estimator has used and rejected since start.
    pub estimator: control_core::estimator::EstimatorCounters,
    /// Telemetry every this many steps (the parameter `downlink.telemetry_every_steps` now), for
    /// [`telemetry::DownlinkSchedule::after_step`].
    pub telemetry_every: u32,
    /// The flight battery as the vehicle reports it (when monitored).
    pub battery: Option<control_core::battery::BatteryStatus>,
}

/// What a step returns, without the pose of this step's frame: what the simulator needs from a flight
/// computer, and what the firmware in the loop sends back each step (small enough for one link frame).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize, postcard_schema::Schema)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct StepReport {
    /// Control outputs: rotor speeds, status, estimate, setpoint.
    pub control: ControlOutputs,
    /// Vision counters since start.
    pub vision: VisionCounters,
    /// This step's flow measurement, if any.
    pub flow: Option<FlowOutcome>,
    /// Flow counters since start.
    pub flow_counters: FlowCounters,
    /// The answer to this step's parameter request.
    pub param_reply: Option<control_core::ParamReply>,
    /// The station time of this step's clock-synchronisation request, if any.
    pub time_sync: Option<u64>,
    /// What the estimator has used and rejected since start.
    pub estimator: control_core::estimator::EstimatorCounters,
}

impl StepOutput {
    /// The report of this output.
    pub fn report(&self) -> StepReport {
        StepReport {
            control: self.control,
            vision: self.vision,
            flow: self.flow,
            flow_counters: self.flow_counters,
            param_reply: self.param_reply,
            time_sync: self.time_sync,
            estimator: self.estimator,
        }
    }
}

/// Solves a frame's pose (the background work of [`FlightStack::solve_pending`], a pure function of the job
/// and the configuration).
pub fn solve_job(job: &SolveJob, v: &VisionConfig) -> FrameOutcome {
    let Some(obs) = job.measurement.observation else { return FrameOutcome::NoTarget };
    match vision_core::solve_pose(&obs, &v.camera, &v.target, &v.mount, job.attitude, &v.pose) {
        Ok(p) => FrameOutcome::Solved(p),
        Err(e) => FrameOutcome::Rejected(e),
    }
}

/// The flight stack.
#[derive(Clone)]
pub struct FlightStack {
    control: ControlCore,
    vision: VisionConfig,
    counters: VisionCounters,
    flow_cfg: FlowConfig,
    flow_counters: FlowCounters,
    gyro: GyroHistory,
    /// Frames waiting for the solver.
    jobs: heapless::Deque<SolveJob, SOLVE_QUEUE>,
    /// Solved frames waiting for the next step.
    solved: heapless::Vec<(u64, FrameOutcome), SOLVE_QUEUE>,
    /// The last frame's observation, to tell a frozen camera.
    last_observation: Option<vision_core::LineObservation>,
    /// Commands that arrived in a step that already had one: carried out one a step, in order.
    commands: heapless::Deque<Command, REQUEST_QUEUE>,
    /// Parameter answers waiting for a step of their own (a step reports one).
    param_replies: heapless::Deque<control_core::ParamReply, REQUEST_QUEUE>,
    /// Commands and parameter requests that found their queue full.
    requests_dropped: u32,
}

/// How many commands, and how many parameter answers, wait for a step of their own. A 115200-baud radio
/// carries about four of the smallest frames in a 2 ms step; the station sends parameter requests one at a
/// time and commands seconds apart.
pub const REQUEST_QUEUE: usize = 8;

impl FlightStack {
    /// A stack with validated parameters.
    ///
    /// Everything is checked before anything is built, and the value is built in one expression, so that the
    /// compiler can construct it in place (the firmware keeps it on the main stack: each extra copy of its
    /// tens of kilobytes would cost as much RAM).
    pub fn new(cfg: FlightConfig) -> Result<Self, ParamError> {
        Self::check_config(&cfg)?;
        Ok(Self::new_checked(cfg))
    }

    /// Every check [`FlightStack::new`] makes of a configuration.
    pub fn check_config(cfg: &FlightConfig) -> Result<(), ParamError> {
        Self::check(cfg)?;
        cfg.control.validate()
    }

    /// A stack for a configuration that passed [`FlightStack::check_config`] (for a caller that checks first and
    /// then builds in place, as the firmware does into its static; unchecked, the laws' bounds may not hold).
    pub fn new_checked(cfg: FlightConfig) -> Self {
        Self {
            control: ControlCore::new_checked(cfg.control),
            vision: cfg.vision,
            counters: VisionCounters::default(),
            flow_cfg: cfg.flow,
            flow_counters: FlowCounters::default(),
            gyro: GyroHistory::new(),
            jobs: heapless::Deque::new(),
            solved: heapless::Vec::new(),
            last_observation: None,
            commands: heapless::Deque::new(),
            param_replies: heapless::Deque::new(),
            requests_dropped: 0,
        }
    }

    /// A parameter answer: this step's, or queued for a later step when this one has its answer.
    fn reply(&mut self, r: control_core::ParamReply, slot: &mut Option<control_core::ParamReply>) {
        match slot {
            None => *slot = Some(r),
            Some(_) => self.requests_dropped += self.param_replies.push_back(r).is_err() as u32,
        }
    }

    /// Commands and parameter requests lost because more than [`REQUEST_QUEUE`] of a kind waited, and pieces of
    /// a configuration upload that reached the stack instead of its caller's [`config_upload::ConfigUpload`].
    pub fn link_requests_dropped(&self) -> u32 {
        self.requests_dropped
    }

    /// The checks of the vision and flow parts of a configuration.
    fn check(cfg: &FlightConfig) -> Result<(), ParamError> {
        if !cfg.vision.target.is_valid() {
            return Err(ParamError { field: "vision.target", problem: "line dimensions must be positive" });
        }
        if !(cfg.vision.attitude_sigma_floor_rad > 0.0) {
            return Err(ParamError { field: "vision.attitude_sigma_floor_rad", problem: "must be positive" });
        }
        let f = &cfg.flow;
        if !(f.min_quality >= 0.0 && f.min_quality <= 1.0) {
            return Err(ParamError { field: "flow.min_quality", problem: "must lie in [0, 1]" });
        }
        if !(f.min_height_m >= 0.0 && f.track_sigma > 0.0 && f.std_floor_m_s > 0.0 && f.scale_sigma >= 0.0) {
            return Err(ParamError {
                field: "flow",
                problem: "min_height_m and scale_sigma must be >= 0, track_sigma and std_floor_m_s positive",
            });
        }
        Ok(())
    }

    /// The control core (read-only).
    pub fn control(&self) -> &ControlCore {
        &self.control
    }

    /// The solve job of a frame: its capture-time attitude from the estimator's history; `None` without a
    /// line or an attitude.
    fn job(&self, m: &VisionMeasurement) -> Option<SolveJob> {
        m.observation?;
        let att = self.control.estimator().attitude_at(m.capture_time_us)?;
        let est = self.control.estimator().estimate(m.capture_time_us);
        let sigma = est.tilt_std_rad.max(self.vision.attitude_sigma_floor_rad);
        Some(SolveJob {
            measurement: *m,
            attitude: AttitudeSource::Imu { roll: att.roll, pitch: att.pitch, sigma_rad: sigma },
        })
    }

    /// Changes a parameter as a `ParamSet` message would (on the ground only), without a message: for replay
    /// with changed parameters.
    pub fn set_param(&mut self, id: control_core::params::ParamId, value: f32) -> control_core::ParamReply {
        self.control.set_param(id, value)
    }

    /// Frames waiting for [`FlightStack::solve_pending`].
    pub fn pending_solves(&self) -> usize {
        self.jobs.len()
    }

    /// Background work: solves the queued frames; the next [`FlightStack::step`] fuses them. Returns how many
    /// were solved.
    ///
    /// The same as taking each job ([`FlightStack::take_job`]), solving it ([`solve_job`]) and handing the
    /// outcome back ([`FlightStack::deliver`]), which is how a caller whose steps preempt the background work
    /// (the board's firmware: the step in an interrupt, the solve in thread mode) runs it.
    pub fn solve_pending(&mut self) -> usize {
        let mut n = 0;
        while let Some(job) = self.take_job() {
            let outcome = solve_job(&job, &self.vision);
            self.deliver(job.measurement.capture_time_us, outcome);
            n += 1;
        }
        n
    }

    /// The oldest frame waiting for its solve, taken off the queue.
    pub fn take_job(&mut self) -> Option<SolveJob> {
        self.jobs.pop_front()
    }

    /// A solved frame (the outcome of [`solve_job`] for a job of [`FlightStack::take_job`] with the frame's
    /// capture time), fused by the next step. When more than [`SOLVE_QUEUE`] wait, the oldest is dropped and
    /// counted (`VisionCounters::dropped`).
    pub fn deliver(&mut self, capture_time_us: u64, outcome: FrameOutcome) {
        if self.solved.is_full() {
            self.solved.remove(0);
            self.counters.dropped += 1;
        }
        // Cannot fail: a place was made above.
        let _ = self.solved.push((capture_time_us, outcome));
    }

    /// Counts a frame given up by a caller's own queue between [`FlightStack::take_job`] and
    /// [`FlightStack::deliver`] (the background work fell behind), as the stack's queues count theirs.
    pub fn count_dropped_frame(&mut self) {
        self.counters.dropped += 1;
    }

    /// What the pose solve of the background work needs ([`solve_job`]).
    pub fn vision_config(&self) -> &VisionConfig {
        &self.vision
    }

    fn count(&mut self, outcome: &FrameOutcome) {
        match outcome {
            FrameOutcome::NoTarget => self.counters.no_target += 1,
            FrameOutcome::NoAttitude | FrameOutcome::Rejected(_) => self.counters.rejected += 1,
            FrameOutcome::Solved(_) => self.counters.solved += 1,
            FrameOutcome::Frozen => self.counters.frozen += 1,
        }
    }

    /// One control period.
    pub fn step(&mut self, inp: &StepInput<'_>) -> StepOutput {
        let mut command: Option<Command> = self.commands.pop_front();
        let mut fix: Option<PositionFix> = None;
        let mut frame = None;
        let mut param_reply = self.param_replies.pop_front();
        let mut time_sync = None;
        let mut flow: Option<BodyVelocity> = None;
        let mut flow_outcome = None;
        // The frames solved since the previous step (oldest first; the estimator takes one fix per step, the
        // newest).
        let solved = core::mem::take(&mut self.solved);
        for (capture_time_us, outcome) in solved {
            self.count(&outcome);
            if let FrameOutcome::Solved(p) = &outcome {
                fix = Some(PositionFix {
                    capture_time_us,
                    position_m: p.vehicle_position_m,
                    position_std_m: p.position_std_m,
                    x_observed: p.x_observed,
                    yaw_rad: p.attitude.yaw,
                    yaw_std_rad: p.yaw_std_rad,
                });
            }
            frame = Some(outcome);
        }
        // The gyro history first, so that a flow interval ending at the newest sample is covered.
        let bias = self.control.estimator().estimate(inp.time_us).gyro_bias_rad_s;
        for s in inp.imu {
            self.gyro.push(s, bias);
        }
        for msg in inp.uplink {
            // The measurements, packed or not (protocol::packed): one path each.
            if let Some(m) = msg.vision() {
                self.counters.frames += 1;
                let repeated = m.observation.is_some() && m.observation == self.last_observation;
                self.last_observation = m.observation;
                if repeated {
                    self.count(&FrameOutcome::Frozen);
                    frame = Some(FrameOutcome::Frozen);
                    continue;
                }
                match self.job(&m) {
                    Some(job) => {
                        if self.jobs.is_full() {
                            self.jobs.pop_front();
                            self.counters.dropped += 1;
                        }
                        // Cannot fail: a place was made above.
                        let _ = self.jobs.push_back(job);
                    }
                    None => {
                        let outcome = if m.observation.is_none() {
                            FrameOutcome::NoTarget
                        } else {
                            FrameOutcome::NoAttitude
                        };
                        self.count(&outcome);
                        frame = Some(outcome);
                    }
                }
                continue;
            }
            if let Some(m) = msg.flow() {
                let c = &mut self.flow_counters;
                c.pairs += 1;
                let outcome = flow::flow_velocity(&m, &self.flow_cfg, &self.gyro, self.control.estimator());
                match outcome {
                    FlowOutcome::NoFlow(_) => c.no_flow += 1,
                    FlowOutcome::LowQuality => c.low_quality += 1,
                    FlowOutcome::Unusable | FlowOutcome::NoGyro => c.unusable += 1,
                    FlowOutcome::Velocity { velocity, .. } => {
                        c.velocities += 1;
                        flow = Some(velocity);
                    }
                }
                flow_outcome = Some(outcome);
                continue;
            }
            match msg {
                // A disarm is carried out at once and cancels the commands waiting (an arm queued before a
                // kill must not arm again); other commands in their order, one a step.
                Uplink::Command(Command::Disarm) => {
                    command = Some(Command::Disarm);
                    self.commands.clear();
                }
                Uplink::Command(c) => match command {
                    None => command = Some(*c),
                    Some(_) => self.requests_dropped += self.commands.push_back(*c).is_err() as u32,
                },
                Uplink::Heartbeat => {}
                Uplink::ParamSet { id, value } => {
                    let r = self.control.set_param(*id, *value);
                    self.reply(r, &mut param_reply);
                }
                Uplink::ParamGet(id) => {
                    let r = self.control.get_param(*id);
                    self.reply(r, &mut param_reply);
                }
                Uplink::TimeSync { station_time_us } => time_sync = Some(*station_time_us),
                // A configuration upload is put together and applied by the caller, which owns the stack
                // ([`config_upload`]); one that reaches the stack is counted as lost.
                Uplink::Config(_) => self.requests_dropped += 1,
                // Handled above.
                Uplink::Vision(_) | Uplink::PackedVision(_) | Uplink::Flow(_) | Uplink::PackedFlow(_) => {}
            }
        }
        let control = self.control.step(&ControlInputs {
            time_us: inp.time_us,
            imu: inp.imu,
            mag: inp.mag,
            baro_m: inp.baro_m,
            fix,
            flow,
            command,
            link_message: !inp.uplink.is_empty(),
            landed: inp.landed,
            pilot: inp.pilot,
            battery: inp.battery,
        });
        StepOutput {
            control,
            frame,
            vision: self.counters,
            flow: flow_outcome,
            flow_counters: self.flow_counters,
            param_reply,
            time_sync,
            estimator: self.control.estimator().counters(),
            telemetry_every: self.control.params().downlink.telemetry_every_steps as u32,
            battery: self.control.battery_status(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use control_core::params::ParamId;
    use control_core::{FlightMode, ParamOutcome};

    fn imu(t: u64) -> [ImuSample; 2] {
        [t - 1000, t].map(|time_us| ImuSample {
            time_us,
            gyro_rad_s: [0.0; 3],
            accel_m_s2: [0.0, 0.0, control_core::GRAVITY],
        })
    }

    #[test]
    fn several_requests_in_one_step_are_each_answered_and_a_disarm_goes_first() {
        let mut s = FlightStack::new(FlightConfig::paper()).unwrap();
        let mut t = 0;
        let mut step = |s: &mut FlightStack, uplink: &[Uplink]| {
            t += 2000;
            s.step(&StepInput {
                time_us: t,
                imu: &imu(t),
                mag: None,
                baro_m: None,
                uplink,
                landed: None,
                pilot: None,
                battery: None,
            })
        };
        for _ in 0..400 {
            step(&mut s, &[Uplink::Heartbeat]);
        }
        // Three parameter requests arrive within one step (a fast radio, a step late): three answers, one a
        // step, in their order.
        let asked = [
            Uplink::ParamGet(ParamId::TrajectoryYd),
            Uplink::ParamSet { id: ParamId::TrajectorySpeed, value: 0.3 },
            Uplink::ParamGet(ParamId::TrajectoryZd),
        ];
        let mut replies = std::vec::Vec::new();
        replies.extend(step(&mut s, &asked).param_reply);
        for _ in 0..5 {
            replies.extend(step(&mut s, &[Uplink::Heartbeat]).param_reply);
        }
        let ids: std::vec::Vec<ParamId> = replies.iter().map(|r| r.id).collect();
        assert_eq!(ids, [ParamId::TrajectoryYd, ParamId::TrajectorySpeed, ParamId::TrajectoryZd]);
        assert_eq!(replies[1].value, 0.3);
        assert_eq!(s.link_requests_dropped(), 0);
        // Two commands in one step: both carried out, one a step; a disarm among them goes first.
        let out = step(&mut s, &[Uplink::Command(Command::Arm), Uplink::Command(Command::TakeOff)]);
        assert_eq!(out.control.status.mode, FlightMode::Armed);
        let out = step(&mut s, &[Uplink::Heartbeat]);
        assert_eq!(out.control.status.mode, FlightMode::TakeOff, "the second command, a step later");
        let out = step(&mut s, &[Uplink::Command(Command::Land), Uplink::Command(Command::Disarm)]);
        assert_eq!(out.control.status.mode, FlightMode::Disarmed, "the disarm at once");
        // More than the step and the queue hold (one answered now, REQUEST_QUEUE later): the excess is
        // counted, never silent.
        let flood = [Uplink::ParamGet(ParamId::TrajectoryYd); REQUEST_QUEUE + 3];
        step(&mut s, &flood);
        assert_eq!(s.link_requests_dropped(), 2);
    }

    #[test]
    fn link_messages_reach_the_flight_code() {
        let mut s = FlightStack::new(FlightConfig::paper()).unwrap();
        let mut t = 0;
        for _ in 0..400 {
            t += 2000;
            s.step(&StepInput {
                time_us: t,
                imu: &imu(t),
                mag: None,
                baro_m: None,
                uplink: &[Uplink::Heartbeat],
                landed: None,
                pilot: None,
                battery: None,
            });
        }
        t += 2000;
        let out = s.step(&StepInput {
            time_us: t,
            imu: &imu(t),
            mag: None,
            baro_m: None,
            uplink: &[Uplink::ParamSet { id: ParamId::TrajectorySpeed, value: 0.3 }],
            landed: None,
            pilot: None,
            battery: None,
        });
        let r = out.param_reply.unwrap();
        assert_eq!((r.id, r.value, r.outcome), (ParamId::TrajectorySpeed, 0.3, ParamOutcome::Ok));
        assert_eq!(out.time_sync, None);
        // A clock-synchronisation request is answered with this step's time, the station's time echoed.
        t += 2000;
        let out = s.step(&StepInput {
            time_us: t,
            imu: &imu(t),
            mag: None,
            baro_m: None,
            uplink: &[Uplink::TimeSync { station_time_us: 77_000_123 }],
            landed: None,
            pilot: None,
            battery: None,
        });
        assert_eq!(out.time_sync, Some(77_000_123));
        assert_eq!(out.report().time_sync, Some(77_000_123));
        let mut sent = std::vec::Vec::new();
        telemetry::DownlinkSchedule::new().after_step(
            &out.control,
            None,
            out.time_sync,
            t,
            0,
            out.telemetry_every,
            out.battery,
            |d| sent.push(d),
        );
        assert_eq!(sent, [protocol::Downlink::TimeSync { station_time_us: 77_000_123, vehicle_time_us: t }]);
        // The telemetry period is a parameter the station sets over the link (its compact mode): the
        // schedule follows it from the next step.
        assert_eq!(out.telemetry_every, telemetry::TELEMETRY_EVERY);
        t += 2000;
        let out = s.step(&StepInput {
            time_us: t,
            imu: &imu(t),
            mag: None,
            baro_m: None,
            uplink: &[Uplink::ParamSet { id: ParamId::TelemetryEvery, value: 50.0 }],
            landed: None,
            pilot: None,
            battery: None,
        });
        assert_eq!(out.param_reply.unwrap().outcome, ParamOutcome::Ok);
        assert_eq!(out.telemetry_every, 50);
        let mut schedule = telemetry::DownlinkSchedule::new();
        let mut telemetry_steps = std::vec::Vec::new();
        for k in 1..=200u32 {
            schedule.after_step(&out.control, None, None, t, 0, out.telemetry_every, None, |d| {
                if matches!(d, protocol::Downlink::PackedTelemetry(_)) {
                    telemetry_steps.push(k)
                }
            });
        }
        assert_eq!(telemetry_steps, [50, 100, 150, 200]);
        for bad in [0.0, 0.4, 101.0, 1e9] {
            let r = FlightParams::paper().with(ParamId::TelemetryEvery, bad);
            assert!(r.is_err(), "{bad} accepted");
        }
        t += 2000;
        let out = s.step(&StepInput {
            time_us: t,
            imu: &imu(t),
            mag: None,
            baro_m: None,
            uplink: &[Uplink::Command(Command::Arm)],
            landed: None,
            pilot: None,
            battery: None,
        });
        assert_eq!(out.control.status.mode, FlightMode::Armed);
        // A frame without the line is counted, not solved.
        t += 2000;
        let m = VisionMeasurement { capture_time_us: t - 40_000, frame_seq: 0, observation: None };
        let out = s.step(&StepInput {
            time_us: t,
            imu: &imu(t),
            mag: None,
            baro_m: None,
            uplink: &[Uplink::Vision(m)],
            landed: None,
            pilot: None,
            battery: None,
        });
        assert_eq!(out.frame, Some(FrameOutcome::NoTarget));
        assert_eq!(out.vision.no_target, 1);
        assert_eq!(s.pending_solves(), 0);
    }

    /// The line as seen from 1.2 m in front of the wall, level, at the line's height (each frame from a
    /// tenth of a millimetre further along, as no two real frames are the same).
    fn frame_seen(capture_time_us: u64, frame_seq: u32) -> VisionMeasurement {
        let v = VisionConfig::default();
        let c = v.target.center() - Vec3::new(-1e-4 * frame_seq as f32, -1.2, 0.0);
        let r_wc = geometry::frames::Attitude::new(0.0, 0.0, 0.0)
            .world_from_body()
            .mul_mat(&v.mount.body_from_camera);
        let obs = vision_core::observation::project_observation(
            &v.camera,
            &v.target,
            &r_wc.transpose(),
            c,
            3.0,
            2.0,
            || 0.0,
        );
        assert!(obs.is_some(), "the line is in view");
        VisionMeasurement { capture_time_us, frame_seq, observation: obs }
    }

    #[test]
    fn frames_are_solved_as_background_work_and_fused_by_the_next_step() {
        let mut s = FlightStack::new(FlightConfig::paper()).unwrap();
        let mut t = 0;
        for _ in 0..100 {
            t += 2000;
            s.step(&StepInput {
                time_us: t,
                imu: &imu(t),
                mag: None,
                baro_m: None,
                uplink: &[],
                landed: None,
                pilot: None,
                battery: None,
            });
        }
        // The step queues the frame; nothing is solved within it.
        t += 2000;
        let m = frame_seen(t - 30_000, 1);
        let out = s.step(&StepInput {
            time_us: t,
            imu: &imu(t),
            mag: None,
            baro_m: None,
            uplink: &[Uplink::Vision(m)],
            landed: None,
            pilot: None,
            battery: None,
        });
        assert_eq!((out.frame, out.vision.solved, out.vision.frames), (None, 0, 1));
        assert_eq!(s.pending_solves(), 1);
        // Background work solves it; the next step fuses it (the first fix initialises x and y).
        assert_eq!(s.solve_pending(), 1);
        assert_eq!(s.pending_solves(), 0);
        let before = s.control().estimator().counters();
        t += 2000;
        let out = s.step(&StepInput {
            time_us: t,
            imu: &imu(t),
            mag: None,
            baro_m: None,
            uplink: &[],
            landed: None,
            pilot: None,
            battery: None,
        });
        let Some(FrameOutcome::Solved(p)) = out.frame else { panic!("solved: {:?}", out.frame) };
        let want = VisionConfig::default().target.center() - Vec3::new(0.0, -1.2, 0.0);
        assert!((p.vehicle_position_m - want).norm() < 1e-3, "{:?}", p.vehicle_position_m);
        assert_eq!(out.vision.solved, 1);
        assert!((out.control.estimate.position_m.y - want.y).abs() < 0.01, "fused");
        assert_ne!(s.control().estimator().counters(), before);
        // Three frames before the background work runs: the oldest is dropped and counted.
        t += 2000;
        let ms = [frame_seen(t - 30_000, 2), frame_seen(t - 28_000, 3), frame_seen(t - 26_000, 4)];
        let uplink = ms.map(Uplink::Vision);
        let out = s.step(&StepInput {
            time_us: t,
            imu: &imu(t),
            mag: None,
            baro_m: None,
            uplink: &uplink,
            landed: None,
            pilot: None,
            battery: None,
        });
        assert_eq!((out.vision.frames, out.vision.dropped), (4, 1));
        assert_eq!(s.solve_pending(), 2);
        t += 2000;
        let out = s.step(&StepInput {
            time_us: t,
            imu: &imu(t),
            mag: None,
            baro_m: None,
            uplink: &[],
            landed: None,
            pilot: None,
            battery: None,
        });
        assert_eq!(out.vision.solved, 3);
    }

    #[test]
    fn background_work_taken_job_by_job_is_solve_pending() {
        // Two stacks fed the same steps and frames: one runs `solve_pending`, the other takes each job, solves
        // it apart and delivers it, as the firmware's thread mode does; every step's output is the same.
        let mut a = FlightStack::new(FlightConfig::paper()).unwrap();
        let mut b = a.clone();
        let mut t = 0;
        for k in 0..400u32 {
            t += 2000;
            let frames: heapless::Vec<Uplink, 2> = if k > 100 && k % 15 == 0 {
                heapless::Vec::from_slice(&[Uplink::Vision(frame_seen(t - 30_000, k))]).unwrap()
            } else {
                heapless::Vec::new()
            };
            let inp = StepInput {
                time_us: t,
                imu: &imu(t),
                mag: None,
                baro_m: None,
                uplink: &frames,
                landed: None,
                pilot: None,
                battery: None,
            };
            assert_eq!(a.step(&inp), b.step(&inp), "step {k}");
            let n = a.solve_pending();
            let mut m = 0;
            while let Some(job) = b.take_job() {
                let outcome = solve_job(&job, b.vision_config());
                b.deliver(job.measurement.capture_time_us, outcome);
                m += 1;
            }
            assert_eq!(n, m);
        }
        assert!(
            a.step(&StepInput {
                time_us: t + 2000,
                imu: &imu(t + 2000),
                mag: None,
                baro_m: None,
                uplink: &[],
                landed: None,
                pilot: None,
                battery: None
            })
            .vision
            .solved
                > 10
        );
        // A caller's own queue that gave a frame up counts it as the stack's do.
        let before = b.counters.dropped;
        b.count_dropped_frame();
        assert_eq!(b.counters.dropped, before + 1);
    }

    #[test]
    fn a_repeated_frame_is_refused_as_frozen() {
        let mut s = FlightStack::new(FlightConfig::paper()).unwrap();
        let mut t = 0;
        for _ in 0..100 {
            t += 2000;
            s.step(&StepInput {
                time_us: t,
                imu: &imu(t),
                mag: None,
                baro_m: None,
                uplink: &[],
                landed: None,
                pilot: None,
                battery: None,
            });
        }
        let m = frame_seen(t - 30_000, 1);
        t += 2000;
        s.step(&StepInput {
            time_us: t,
            imu: &imu(t),
            mag: None,
            baro_m: None,
            uplink: &[Uplink::Vision(m)],
            landed: None,
            pilot: None,
            battery: None,
        });
        assert_eq!(s.pending_solves(), 1);
        s.solve_pending();
        // The same observation again, with a new time and number: a frozen camera.
        let mut again = m;
        again.capture_time_us += 33_000;
        again.frame_seq += 1;
        t += 2000;
        let out = s.step(&StepInput {
            time_us: t,
            imu: &imu(t),
            mag: None,
            baro_m: None,
            uplink: &[Uplink::Vision(again)],
            landed: None,
            pilot: None,
            battery: None,
        });
        assert_eq!(out.frame, Some(FrameOutcome::Frozen));
        assert_eq!((out.vision.frozen, out.vision.frames), (1, 2));
        assert_eq!(s.pending_solves(), 0, "not queued for the solver");
        // A new frame is taken again.
        let fresh = frame_seen(t - 20_000, 3);
        t += 2000;
        s.step(&StepInput {
            time_us: t,
            imu: &imu(t),
            mag: None,
            baro_m: None,
            uplink: &[Uplink::Vision(fresh)],
            landed: None,
            pilot: None,
            battery: None,
        });
        assert_eq!(s.pending_solves(), 1);
    }
}
