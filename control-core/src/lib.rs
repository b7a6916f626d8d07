//! Flight control for the wall-line quadrotor, `no_std` and without allocation.
//!
//! Everything runs behind one function, [`ControlCore::step`], that the firmware, the simulator and log replay
//! call with the sensor inputs of one control period (timestamps included) and that returns the rotor speed
//! commands and a status:
//!
//! - [`estimator`]: an error-state Kalman filter on the IMU, corrected by delayed vision fixes, optical-flow
//!   velocity, magnetometer heading and, on the ground, zero velocity and gravity;
//! - [`laws`]: the paper's altitude and yaw laws (eq. 30-31) and bounded lateral and longitudinal laws
//!   (eq. 33-34), with the traps fixed (clamped division, sums of saturations checked by Routh-Hurwitz);
//! - [`trajectory`]: the back-and-forth sweep with the direction flag (section 5.2), take-off and landing;
//! - [`mixer`]: thrust and torques to rotor speeds within the motor limits;
//! - modes and failsafes (this module): arming checks, vision lost, link lost, IMU fault, tilt;
//! - [`pilot`]: the pilot's RC transmitter: kill switch, arm switch, mode switch, manual mode, RC loss.
//!
//! Time enters only as timestamps; nothing reads a clock, logs or panics.
#![cfg_attr(not(test), no_std)]
#![forbid(unsafe_code)]
#![warn(missing_docs)]
#![cfg_attr(not(test), deny(clippy::unwrap_used, clippy::expect_used, clippy::panic))]
#![allow(clippy::needless_range_loop, clippy::neg_cmp_op_on_partial_ord)]

#[macro_use]
pub mod declare;
pub mod battery;
pub mod estimator;
pub mod laws;
pub mod mixer;
pub mod motion;
pub mod params;
pub mod pilot;
pub mod trajectory;

use estimator::{AccelContext, BodyVelocity, Estimator, FuseOutcome, ImuSample, PositionFix, StateEstimate};
use geometry::Vec3;
use laws::{Controller, Horizontal, LawStatus, Setpoint};
use mixer::MixerOutput;
use params::FlightParams;
use trajectory::{Move, Sweep};

/// Standard gravity (m/s^2).
pub const GRAVITY: f32 = 9.80665;

/// How far below the floor the landing's height reference goes on descending (m): far enough that the
/// altitude law's thrust reaches idle on the floor, whatever the height estimate's drift.
pub const LANDING_DEPTH_BELOW_FLOOR_M: f32 = 10.0;

/// Landing: a vertical speed above minus this counts as not descending (m/s).
pub const GROUND_CONTACT_SPEED_M_S: f32 = 0.05;

/// Landing: the estimate counts as stalled (not descending) only once the descending reference is this far
/// below it (m). At the start of a landing the vehicle hovers: not descending is no evidence of the floor.
pub const GROUND_CONTACT_LAG_M: f32 = 0.15;

/// Landing: a specific force this fraction of gravity beyond the thrust's share means the floor carries the
/// vehicle (above what a vehicle 20 % lighter than configured shows in flight).
pub const GROUND_CONTACT_EXCESS: f32 = 0.25;

/// Time constant of the specific force's magnitude that the land detector reads (s).
pub const ACCEL_FILTER_S: f32 = 0.1;

/// The setpoint limiter's rates over the mission's speeds (horizontal: the sweep's or the take-off's,
/// vertical: the take-off's or the landing's): above them, so that the mission's own profiles pass unchanged.
pub const SETPOINT_RATE_MARGIN: f32 = 1.5;

/// A take-off is done when the height is this close to the mission's, for `settle_s` (m).
pub const TAKEOFF_CLOSE_M: f32 = 0.05;

/// The yaw reference turns to the mission's yaw at most this fast once vision gives the heading (rad/s).
pub const YAW_SETPOINT_RATE_RAD_S: f32 = 0.5;

/// Landing: the specific force away from gravity for this long means the vehicle is not on the floor (a
/// bounce is shorter) (s).
pub const GROUND_CONTACT_LOST_S: f32 = 0.15;

/// A landing without vision asks for at most this multiple of the learned hover thrust: enough to brake the
/// descent, not to climb away on a drifting height estimate.
pub const BLIND_LANDING_THRUST_MARGIN: f32 = 1.05;

/// Time constant of the learned hover thrust (s).
pub const HOVER_THRUST_FILTER_S: f32 = 2.0;

/// Landing: when the reference is this far below the pad, touchdown is overdue and the thrust is wound down
/// while the floor carries the vehicle (m).
pub const TOUCHDOWN_EXPECTED_M: f32 = 0.2;

/// A take-off that timed out this high above the pad hovers; lower, it lands (m).
pub const TAKEOFF_AIRBORNE_M: f32 = 0.1;

/// The estimate's height moving this much in one control step is a jump (a fix accepted after a long
/// dead-reckoning, whose uncertainty lets it move the estimate at once), not motion (m): the references start
/// again from the new estimate, as after a position reset.
pub const HEIGHT_JUMP_M: f32 = 0.1;

/// A blind hold or landing backs away from the wall by this many standard deviations of the estimate's
/// distance to it (`failsafe.blind_retreat_speed_m_s`, at most `failsafe.blind_retreat_max_m`).
pub const BLIND_RETREAT_SIGMAS: f32 = 2.0;

/// A sweep slows to a stop while the gyro has read a held, clipped value within this time (s): a gyro that
/// saturates below the rates a manoeuvre needs cannot damp it (the estimator counts the clipped samples,
/// `gyro_clipped`); hovering needs far smaller rates.
pub const GYRO_CLIP_PAUSE_S: f32 = 3.0;

/// The time (s) a sweep's pace takes to go from full speed to a stop, or back: the sweep runs on its own clock,
/// which slows down (and speeds up again) at this rate, so that stopping a pass never steps the reference's
/// velocity (the extra acceleration is the pass's speed over this time).
pub const SWEEP_PACE_CHANGE_S: f32 = 2.0;

/// An operator command (from the ground station over the radio link).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Command {
    /// Arm (motors to idle); refused unless disarmed, level, sensors healthy.
    Arm,
    /// Stop the motors, at once, in any mode.
    Disarm,
    /// Climb to the mission altitude above the current position.
    TakeOff,
    /// Start the sweep.
    StartTracking,
    /// Stop the sweep and hover where the reference is.
    StopTracking,
    /// Descend and disarm on touchdown.
    Land,
}

/// Flight mode.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FlightMode {
    /// Motors off.
    #[default]
    Disarmed,
    /// On the ground, motors at idle.
    Armed,
    /// Climbing to the mission altitude.
    TakeOff,
    /// Holding a point.
    Hover,
    /// Sweeping along the line.
    Tracking,
    /// Failsafe: no vision; holding attitude and altitude on the IMU (and flow).
    VisionHold,
    /// Descending to touchdown.
    Landing,
    /// Motors off after a fault (IMU, estimator, excessive tilt).
    Emergency,
    /// The pilot flies: stick tilt, climb rate and yaw rate from the RC transmitter ([`pilot`]).
    Manual,
}

impl FlightMode {
    /// Whether the vehicle is (meant to be) flying.
    pub fn airborne(self) -> bool {
        matches!(
            self,
            FlightMode::TakeOff
                | FlightMode::Hover
                | FlightMode::Tracking
                | FlightMode::VisionHold
                | FlightMode::Landing
                | FlightMode::Manual
        )
    }
}

/// Why a failsafe acted.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Failsafe {
    /// Vision fixes stale: holding on the IMU.
    VisionLost,
    /// Vision lost for too long: landing.
    VisionLostLanding,
    /// No message from the ground station: landing.
    LinkLost,
    /// IMU silent or non-finite: motors off.
    ImuFault,
    /// Estimator diverged (non-finite): motors off.
    EstimatorFault,
    /// Tilt beyond the crash limit: motors off.
    ExcessiveTilt,
    /// The take-off did not reach and hold its height in time: hovering where it is when airborne, else
    /// landing.
    TakeOffTimeout,
    /// The RC link was lost where it matters (manual flight, or `rc.required`): holding level, then landing.
    RcLost,
    /// The pilot's kill switch: motors off.
    Killed,
    /// The battery below `battery.critical_cell_v`: landing ([`battery`]).
    BatteryCritical,
}

/// Why a command was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Refusal {
    /// Not possible in the current mode.
    WrongMode,
    /// Arming: tilted beyond the arming limit.
    NotLevel,
    /// Arming: IMU not delivering, estimator not aligned or unhealthy.
    SensorsUnhealthy,
    /// Arming or take-off: no link to the ground station.
    NoLink,
    /// Arming after a fault: disarm first.
    FaultLatched,
    /// Arming over a radio link that is not authenticated (no key provisioned), by a firmware built without
    /// the `unauthenticated-link` feature (docs/security.md). Refused by the vehicle's link layer.
    Unauthenticated,
    /// Arming: the pilot's kill switch is high.
    KillSwitch,
    /// Arming: a receiver is in use and the pilot's arm switch is low.
    ArmSwitchOff,
    /// Arming: `rc.required` and no RC link.
    NoRc,
    /// Arming: the battery below `battery.warn_cell_v`.
    BatteryLow,
}

/// The outcome of the last command.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum CommandResult {
    /// Carried out.
    Accepted(Command),
    /// Refused.
    Refused(Command, Refusal),
}

/// The answer to a parameter request.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ParamReply {
    /// Which parameter.
    pub id: params::ParamId,
    /// Its value now (after the change when accepted).
    pub value: f32,
    /// Outcome.
    pub outcome: ParamOutcome,
}

/// Outcome of a parameter request.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ParamOutcome {
    /// Read, or changed.
    Ok,
    /// Changes are refused while the motors run in flight (disarm or land first).
    Refused,
    /// The value fails the parameter checks (the whole set is validated, as when it loads).
    Invalid,
}

/// The sensor inputs of one control period.
#[derive(Clone, Copy, Debug)]
pub struct ControlInputs<'a> {
    /// Time of this step (us, vehicle clock).
    pub time_us: u64,
    /// IMU samples since the previous step, oldest first.
    pub imu: &'a [ImuSample],
    /// Magnetometer reading (body frame), when a new one arrived.
    pub mag: Option<Vec3>,
    /// Barometric pressure altitude (m, any offset), when a new reading arrived.
    pub baro_m: Option<f32>,
    /// Vision fix solved this step, when a frame arrived.
    pub fix: Option<PositionFix>,
    /// Optical-flow velocity, when one arrived.
    pub flow: Option<BodyVelocity>,
    /// Operator command, when one arrived.
    pub command: Option<Command>,
    /// Whether any message from the ground station arrived this step (link alive).
    pub link_message: bool,
    /// An external land detector's verdict, when there is one: the recorded vehicle's own in an imported log
    /// (`Some(true)` landed, `Some(false)` flying). `None` on this project's vehicles, whose flight mode
    /// says it.
    pub landed: Option<bool>,
    /// The pilot's transmitter, when a receiver has been heard ([`pilot`]).
    pub pilot: Option<pilot::PilotInput>,
    /// A new reading of the flight battery, if any ([`battery`]).
    pub battery: Option<battery::BatteryReading>,
}

/// Status of the flight code.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Status {
    /// Mode.
    pub mode: FlightMode,
    /// The active (or last) failsafe.
    pub failsafe: Option<Failsafe>,
    /// The last command's outcome.
    pub last_command: Option<CommandResult>,
    /// Age of the last accepted vision fix (s); infinite before the first.
    pub fix_age_s: f32,
    /// Outcome of this step's fix, if any.
    pub fix_outcome: Option<FuseOutcome>,
    /// Sweep passes completed.
    pub passes_done: u16,
    /// Sweep direction flag (toward the far end of the range).
    pub sweep_forward: bool,
    /// What the laws did.
    pub law: LawStatus,
    /// What the mixer had to give.
    pub mixer: MixerOutput,
    /// IMU samples rejected this step (non-finite or out of order).
    pub imu_rejected: u8,
}

/// What one step returns.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ControlOutputs {
    /// Rotor speed commands M1..M4 (rad/s); zeros when the motors are off.
    pub motors_rad_s: [f32; 4],
    /// Status.
    pub status: Status,
    /// State estimate after this step.
    pub estimate: StateEstimate,
    /// Reference of this step.
    pub setpoint: Setpoint,
}

/// The flight code.
#[derive(Clone)]
pub struct ControlCore {
    params: FlightParams,
    estimator: Estimator,
    controller: Controller,
    mode: FlightMode,
    failsafe: Option<Failsafe>,
    last_command: Option<CommandResult>,
    sweep: Option<Sweep>,
    vertical: Option<(Move, u64)>,
    hold: Vec3,
    yaw_d: f32,
    last_step_us: Option<u64>,
    last_imu_us: Option<u64>,
    first_imu_us: Option<u64>,
    last_fix_us: Option<u64>,
    /// When a flow velocity was last accepted.
    last_flow_us: Option<u64>,
    /// When the last barometer reading arrived.
    last_baro_us: Option<u64>,
    /// How far a blind hold or landing has moved away from the wall since it went blind (m).
    retreat_m: f32,
    /// The estimator's clipped-gyro count last seen, and when it last grew.
    gyro_clips_seen: u32,
    last_clip_us: Option<u64>,
    /// The sweep's clock (us) and the pace at which it runs (1 the mission's, 0 stopped).
    sweep_clock_us: u64,
    sweep_pace: f32,
    last_link_us: Option<u64>,
    airborne_since_us: u64,
    hold_since_us: u64,
    touchdown_since_us: Option<u64>,
    settled_since_us: Option<u64>,
    motors: [f32; 4],
    fault_latched: bool,
    last_thrust_n: f32,
    contact_since_us: Option<u64>,
    accel_lp: Option<f32>,
    resume_climb: bool,
    /// The vision-yaw state the yaw reference was last seeded for: (yaw from vision, yaw resets).
    yaw_frame: (bool, u32),
    /// Since when the specific force has not been that of a vehicle the floor carries (landing).
    unsupported_since_us: Option<u64>,
    /// The vertical thrust that hovers (N), low-passed while vision holds the height (see `step`).
    hover_thrust_n: Option<f32>,
    /// The estimator's position resets already acted on.
    position_resets_seen: u32,
    /// The estimate's height at the previous step (to see a jump).
    last_est_z: Option<f32>,
    /// The sweep a vision hold interrupted, resumed when vision returns.
    paused_sweep: Option<Sweep>,
    /// The way back to the sweep's distance and height after a hold (y, z), and when it began.
    rejoin: Option<(trajectory::Rejoin, trajectory::Rejoin, u64)>,
    limiter: laws::SetpointLimiter,
    /// The pilot's switches and manual references ([`pilot`]), and this step's input.
    pilot: pilot::PilotState,
    pilot_input: Option<pilot::PilotInput>,
    /// The flight battery ([`battery`]), and whether its critical level has already started a landing (once:
    /// the pilot may take over from it).
    battery: battery::BatteryMonitor,
    battery_landing: bool,
}

impl ControlCore {
    /// Flight code with validated parameters (see [`FlightParams::validate`]).
    pub fn new(params: FlightParams) -> Result<Self, params::ParamError> {
        params.validate()?;
        Ok(Self::new_checked(params))
    }

    /// A controller for parameters that have passed [`FlightParams::validate`] (for callers that check first
    /// and then build in place; with unchecked parameters the laws' bounds may not hold).
    pub fn new_checked(params: FlightParams) -> Self {
        let home = Vec3::from_array(params.home_m);
        Self {
            params,
            estimator: Estimator::new(params.estimator, home),
            controller: Controller::with_drag(
                params.gains,
                params.vehicle,
                params.estimator.drag_coeff_per_s,
            ),
            mode: FlightMode::Disarmed,
            failsafe: None,
            last_command: None,
            sweep: None,
            vertical: None,
            hold: home,
            yaw_d: params.trajectory.yaw_d_rad,
            last_step_us: None,
            last_imu_us: None,
            first_imu_us: None,
            last_fix_us: None,
            last_flow_us: None,
            last_baro_us: None,
            retreat_m: 0.0,
            gyro_clips_seen: 0,
            last_clip_us: None,
            sweep_clock_us: 0,
            sweep_pace: 1.0,
            last_link_us: None,
            airborne_since_us: 0,
            hold_since_us: 0,
            touchdown_since_us: None,
            settled_since_us: None,
            motors: [0.0; 4],
            fault_latched: false,
            last_thrust_n: 0.0,
            contact_since_us: None,
            accel_lp: None,
            resume_climb: false,
            paused_sweep: None,
            rejoin: None,
            position_resets_seen: 0,
            last_est_z: None,
            hover_thrust_n: None,
            unsupported_since_us: None,
            yaw_frame: (false, 0),
            limiter: laws::SetpointLimiter::new(),
            pilot: pilot::PilotState::default(),
            pilot_input: None,
            battery: battery::BatteryMonitor::default(),
            battery_landing: false,
        }
    }

    /// The parameters.
    pub fn params(&self) -> &FlightParams {
        &self.params
    }

    /// The current mode.
    pub fn mode(&self) -> FlightMode {
        self.mode
    }

    /// A parameter's value.
    pub fn get_param(&self, id: params::ParamId) -> ParamReply {
        ParamReply { id, value: self.params.get(id), outcome: ParamOutcome::Ok }
    }

    /// Changes a parameter. Only on the ground (disarmed or armed at idle); the new set is validated as a whole
    /// and the laws are rebuilt from it.
    pub fn set_param(&mut self, id: params::ParamId, value: f32) -> ParamReply {
        let refuse = |o| ParamReply { id, value: self.params.get(id), outcome: o };
        if !matches!(self.mode, FlightMode::Disarmed | FlightMode::Armed) {
            return refuse(ParamOutcome::Refused);
        }
        match self.params.with(id, value) {
            Ok(p) => {
                self.params = p;
                self.controller = Controller::with_drag(p.gains, p.vehicle, p.estimator.drag_coeff_per_s);
                self.yaw_d = p.trajectory.yaw_d_rad;
                ParamReply { id, value: p.get(id), outcome: ParamOutcome::Ok }
            }
            Err(_) => refuse(ParamOutcome::Invalid),
        }
    }

    /// The flight battery as the vehicle reports it, once a reading arrived (and it is monitored).
    pub fn battery_status(&self) -> Option<battery::BatteryStatus> {
        if self.params.battery.cells == 0 { None } else { self.battery.status() }
    }

    /// The estimator (read-only), e.g. for the attitude at a frame's capture time.
    pub fn estimator(&self) -> &Estimator {
        &self.estimator
    }

    fn motors_off(&mut self, mode: FlightMode) {
        self.mode = mode;
        self.sweep = None;
        self.paused_sweep = None;
        self.rejoin = None;
        self.vertical = None;
        self.controller.reset();
    }

    fn start_vertical(&mut self, from: f32, to: f32, speed: f32, now: u64) {
        self.vertical = Some((Move::new(from, to, speed, 1.0), now));
    }

    fn handle_command(&mut self, cmd: Command, now: u64, est: &StateEstimate, imu_ok: bool, link_ok: bool) {
        use FlightMode::{Armed, Disarmed, Hover, Tracking, VisionHold};
        let t = &self.params.trajectory;
        let result = match (cmd, self.mode) {
            (Command::Disarm, _) => {
                self.motors_off(Disarmed);
                self.failsafe = None;
                self.fault_latched = false;
                Ok(())
            }
            (Command::Arm, Disarmed) => {
                let tilt = libm::acosf(geometry::clamp_finite(
                    geometry::trig::cos(est.attitude.roll) * geometry::trig::cos(est.attitude.pitch),
                    -1.0,
                    1.0,
                ));
                let aligned = self.first_imu_us.is_some_and(|f| now.saturating_sub(f) > 500_000);
                if self.fault_latched {
                    Err(Refusal::FaultLatched)
                } else if let Some(r) = self.pilot_arm_refusal(self.pilot_input) {
                    Err(r)
                } else if self.battery.status().is_some_and(|b| b.level != battery::BatteryLevel::Ok) {
                    Err(Refusal::BatteryLow)
                } else if !imu_ok || !aligned || !self.estimator.is_healthy() {
                    Err(Refusal::SensorsUnhealthy)
                } else if tilt > self.params.failsafe.max_arming_tilt_rad {
                    Err(Refusal::NotLevel)
                } else if !link_ok {
                    Err(Refusal::NoLink)
                } else {
                    self.mode = Armed;
                    self.controller.reset();
                    // Every arming check passed: what stopped the last flight (a kill, a lost link on the
                    // ground) is history, not a failsafe in force.
                    self.failsafe = None;
                    Ok(())
                }
            }
            (Command::TakeOff, Armed) => {
                if !link_ok {
                    Err(Refusal::NoLink)
                } else {
                    self.mode = FlightMode::TakeOff;
                    self.hold = Vec3::new(est.position_m.x, est.position_m.y, t.z_d_m);
                    self.yaw_d = t.yaw_d_rad;
                    self.start_vertical(est.position_m.z, t.z_d_m, t.takeoff_speed_m_s, now);
                    self.limiter.restart(est.position_m);
                    self.airborne_since_us = now;
                    self.settled_since_us = None;
                    Ok(())
                }
            }
            (Command::StartTracking, Hover) => {
                self.mode = Tracking;
                self.sweep = Some(Sweep::new(
                    t.x_range_m,
                    t.speed_m_s,
                    t.accel_m_s2,
                    t.sweeps,
                    self.hold.x,
                    self.sweep_clock_us,
                ));
                // The sweep's distance and height from where the vehicle is (after a hold it may be well off).
                let (p, v) = (est.position_m, est.velocity_m_s);
                self.rejoin = Some((
                    trajectory::Rejoin::new(p.y, v.y, t.y_d_m, t.speed_m_s, t.accel_m_s2),
                    trajectory::Rejoin::new(p.z, v.z, t.z_d_m, t.speed_m_s, t.accel_m_s2),
                    now,
                ));
                Ok(())
            }
            (Command::StopTracking, Tracking) => {
                self.mode = Hover;
                self.sweep = None;
                Ok(())
            }
            (Command::Land, FlightMode::TakeOff | Hover | Tracking | VisionHold | FlightMode::Manual) => {
                self.begin_landing(now, est);
                Ok(())
            }
            _ => Err(Refusal::WrongMode),
        };
        self.last_command = Some(match result {
            Ok(()) => CommandResult::Accepted(cmd),
            Err(r) => CommandResult::Refused(cmd, r),
        });
    }

    fn begin_landing(&mut self, now: u64, est: &StateEstimate) {
        let t = self.params.trajectory;
        self.mode = FlightMode::Landing;
        self.sweep = None;
        self.paused_sweep = None;
        self.rejoin = None;
        self.hold.x = est.position_m.x;
        self.hold.y = est.position_m.y;
        // The descent does not stop at the floor: after touchdown the reference goes on down, the altitude
        // law's thrust falls to idle, and the land detector (thrust, specific force and rates; not the height
        // estimate, which vision no longer corrects near the floor) ends the flight.
        let floor = t.ground_height_m - LANDING_DEPTH_BELOW_FLOOR_M;
        self.start_vertical(est.position_m.z, floor, t.landing_speed_m_s, now);
        self.touchdown_since_us = None;
    }

    /// One control period: estimation, mission, failsafes, laws, mixer.
    pub fn step(&mut self, inp: &ControlInputs<'_>) -> ControlOutputs {
        let now = inp.time_us;
        let dt = self.last_step_us.map_or(0.0, |l| (now.saturating_sub(l) as f32 * 1e-6).min(0.05));
        self.last_step_us = Some(now);
        let fs = self.params.failsafe;
        let traj = self.params.trajectory;

        // Estimation: IMU prediction, covariance, measurements.
        let mut imu_rejected = 0u8;
        let (mut accel_sum, mut n_ok) = (Vec3::ZERO, 0u32);
        for s in inp.imu {
            if self.estimator.predict(s) {
                self.last_imu_us = Some(s.time_us);
                self.first_imu_us.get_or_insert(s.time_us);
                accel_sum += Vec3::from_array(s.accel_m_s2);
                n_ok += 1;
            } else {
                imu_rejected = imu_rejected.saturating_add(1);
            }
        }
        self.estimator.propagate_covariance(now);
        // The specific force's magnitude, low-passed over 0.1 s (one step's samples are too noisy to tell a
        // vehicle the floor carries from one that accelerates).
        if n_ok > 0 {
            let f = (accel_sum * (1.0 / n_ok as f32)).norm();
            let a = (dt / ACCEL_FILTER_S).clamp(0.0, 1.0);
            self.accel_lp = Some(match self.accel_lp {
                Some(lp) if dt > 0.0 => lp + (f - lp) * a,
                _ => f,
            });
        }
        let step_accel = self.accel_lp;
        let imu_ok =
            self.last_imu_us.is_some_and(|t| now.saturating_sub(t) as f32 * 1e-6 <= fs.imu_timeout_s);
        // The accelerometer's model: the flight mode says whether the vehicle flies; on the ground, at rest
        // or not is the IMU's to tell (see `motion`).
        let on_ground_mode = matches!(self.mode, FlightMode::Disarmed | FlightMode::Armed);
        let airborne = if self.mode.airborne() {
            Some(true)
        } else if let Some(landed) = inp.landed {
            Some(!landed)
        } else if self.mode == FlightMode::Armed {
            Some(false)
        } else {
            None
        };
        let pad = on_ground_mode && inp.landed != Some(false);
        self.estimator
            .fuse_accel(&AccelContext { airborne, pad_height_m: pad.then_some(traj.ground_height_m) });
        if let Some(m) = inp.mag {
            self.estimator.fuse_mag(m);
        }
        let mut fix_outcome = None;
        if let Some(fix) = inp.fix {
            let o = self.estimator.fuse_fix(&fix, now);
            if matches!(o, FuseOutcome::Accepted | FuseOutcome::Initialised) {
                self.last_fix_us = Some(now);
            }
            fix_outcome = Some(o);
        }
        if let Some(f) = inp.flow
            && self.estimator.fuse_body_velocity(&f, now) == FuseOutcome::Accepted
        {
            self.last_flow_us = Some(now);
        }
        // The barometer: its offset learned while vision (or the pad) gives the height, a height measurement
        // otherwise.
        if let Some(b) = inp.baro_m {
            let since = self.last_baro_us.map_or(0.0, |t| now.saturating_sub(t) as f32 * 1e-6);
            self.last_baro_us = Some(now);
            let fresh_fix = self
                .last_fix_us
                .is_some_and(|t| now.saturating_sub(t) as f32 * 1e-6 <= fs.vision_hold_after_s);
            self.estimator.fuse_baro(b, since, fresh_fix || pad);
        }
        // Nothing sinks through the floor (the pad's height is where the centre of mass rests on it).
        let at_floor = self.estimator.constrain_above_floor(traj.ground_height_m);
        if inp.link_message {
            self.last_link_us = Some(now);
        }
        let link_ok =
            self.last_link_us.is_some_and(|t| now.saturating_sub(t) as f32 * 1e-6 <= fs.link_land_after_s);
        let clips = self.estimator.counters().gyro_clipped;
        if clips != self.gyro_clips_seen {
            self.gyro_clips_seen = clips;
            self.last_clip_us = Some(now);
        }
        let gyro_clipping =
            self.last_clip_us.is_some_and(|t| now.saturating_sub(t) as f32 * 1e-6 <= GYRO_CLIP_PAUSE_S);
        // The sweep's clock: its pace falls to 0 while the gyro clips, and returns to 1, each over
        // SWEEP_PACE_CHANGE_S.
        let step = dt / SWEEP_PACE_CHANGE_S;
        self.sweep_pace =
            if gyro_clipping { self.sweep_pace - step } else { self.sweep_pace + step }.clamp(0.0, 1.0);
        self.sweep_clock_us += libm::roundf(dt * 1e6 * self.sweep_pace) as u64;
        let est = self.estimator.estimate(now);
        // A position reset or a jump (vision back after a long dead-reckoning) moves the estimate at once: the references
        // start again from the new estimate, at their bounded rates (a landing descends from the new height).
        let resets = self.estimator.counters().position_resets;
        let jumped = self
            .last_est_z
            .replace(est.position_m.z)
            .is_some_and(|z| libm::fabsf(est.position_m.z - z) > HEIGHT_JUMP_M);
        if resets != self.position_resets_seen || jumped {
            self.position_resets_seen = resets;
            self.limiter.restart(est.position_m);
            if self.mode == FlightMode::Landing {
                let floor = traj.ground_height_m - LANDING_DEPTH_BELOW_FLOOR_M;
                self.start_vertical(est.position_m.z, floor, traj.landing_speed_m_s, now);
                self.contact_since_us = None;
            } else if self.mode == FlightMode::TakeOff && self.vertical.is_some() {
                self.start_vertical(est.position_m.z, traj.z_d_m, traj.takeoff_speed_m_s, now);
            }
            if matches!(self.mode, FlightMode::VisionHold) {
                self.hold = est.position_m;
            }
        }

        // Faults: motors off.
        let tilt = libm::acosf(geometry::clamp_finite(
            geometry::trig::cos(est.attitude.roll) * geometry::trig::cos(est.attitude.pitch),
            -1.0,
            1.0,
        ));
        let fault = if self.last_imu_us.is_some() && !imu_ok && self.mode != FlightMode::Disarmed {
            Some(Failsafe::ImuFault)
        } else if !self.estimator.is_healthy() {
            Some(Failsafe::EstimatorFault)
        } else if self.mode.airborne() && tilt > fs.crash_tilt_rad {
            Some(Failsafe::ExcessiveTilt)
        } else {
            None
        };
        if let Some(f) = fault
            && self.mode != FlightMode::Emergency
            && (self.mode != FlightMode::Disarmed || f == Failsafe::EstimatorFault)
        {
            self.failsafe = Some(f);
            self.fault_latched = true;
            self.motors_off(FlightMode::Emergency);
        }

        // The battery: its level, from the readings (under load while the motors run).
        let under_load = !matches!(self.mode, FlightMode::Disarmed | FlightMode::Emergency);
        let battery = self.battery.update(inp.battery, now, under_load, &self.params.battery);
        if !under_load {
            self.battery_landing = false;
        }
        // The pilot's transmitter first: its kill switch wins over everything ([`pilot`]).
        self.pilot_input = inp.pilot;
        self.apply_pilot(inp.pilot, now, &est, imu_ok, link_ok);
        // A critical battery lands, once (the pilot may take over from that landing in manual).
        if battery == Some(battery::BatteryLevel::Critical)
            && self.mode.airborne()
            && self.mode != FlightMode::Landing
            && !self.battery_landing
        {
            self.battery_landing = true;
            self.failsafe = Some(Failsafe::BatteryCritical);
            self.begin_landing(now, &est);
        }
        if let Some(cmd) = inp.command {
            self.handle_command(cmd, now, &est, imu_ok, link_ok);
        }

        // Failsafes of the airborne modes (in manual the pilot flies; `pilot` has the RC link's).
        if self.mode.airborne() && self.mode != FlightMode::Manual {
            let since = self.last_fix_us.unwrap_or(0).max(self.airborne_since_us);
            let fix_age = now.saturating_sub(since) as f32 * 1e-6;
            // The take-off climbs on the IMU (the line is often out of view from the pad); vision is required
            // once the climb is done.
            let climbing = self.mode == FlightMode::TakeOff
                && self
                    .vertical
                    .is_some_and(|(mv, t0)| now.saturating_sub(t0) as f32 * 1e-6 < mv.duration_s());
            if !link_ok && self.mode != FlightMode::Landing {
                self.failsafe = Some(Failsafe::LinkLost);
                self.begin_landing(now, &est);
            } else if matches!(self.mode, FlightMode::Hover | FlightMode::Tracking | FlightMode::TakeOff)
                && !climbing
                && fix_age > fs.vision_hold_after_s
            {
                self.failsafe = Some(Failsafe::VisionLost);
                self.resume_climb = self.mode == FlightMode::TakeOff;
                self.paused_sweep = self.sweep.take();
                self.rejoin = None;
                self.mode = FlightMode::VisionHold;
                self.hold_since_us = now;
                // Hold where the vehicle is; the setpoint limiter ramps there from where it was.
                self.hold = est.position_m;
                self.vertical = None;
                self.limiter.restart(est.position_m);
            } else if self.mode == FlightMode::VisionHold {
                if fix_age <= fs.vision_hold_after_s {
                    // Vision is back: go on from where the vehicle is (a take-off climbs on from its height).
                    self.hold = Vec3::new(est.position_m.x, est.position_m.y, est.position_m.z);
                    if self.resume_climb {
                        self.mode = FlightMode::TakeOff;
                        self.hold.z = traj.z_d_m;
                        self.start_vertical(est.position_m.z, traj.z_d_m, traj.takeoff_speed_m_s, now);
                        self.settled_since_us = None;
                    } else if let Some(mut sw) = self.paused_sweep.take() {
                        // A sweep goes on with its pass from where the vehicle is; the distance and the height
                        // come back from where the vehicle is and how fast it moves.
                        sw.resume(est.position_m.x, self.sweep_clock_us);
                        self.sweep = Some(sw);
                        self.mode = FlightMode::Tracking;
                        let (p, v) = (est.position_m, est.velocity_m_s);
                        self.rejoin = Some((
                            trajectory::Rejoin::new(p.y, v.y, traj.y_d_m, traj.speed_m_s, traj.accel_m_s2),
                            trajectory::Rejoin::new(p.z, v.z, traj.z_d_m, traj.speed_m_s, traj.accel_m_s2),
                            now,
                        ));
                    } else {
                        self.mode = FlightMode::Hover;
                    }
                } else if now.saturating_sub(self.hold_since_us) as f32 * 1e-6 > fs.vision_land_after_s {
                    self.failsafe = Some(Failsafe::VisionLostLanding);
                    self.begin_landing(now, &est);
                }
            }
        }

        // The yaw reference. Until vision gives the heading in the line's frame the vehicle keeps the heading
        // it has (a disturbed compass must not turn it away from the line); when vision takes over, or resets
        // the heading, the reference starts from the new estimate and turns to the mission's yaw at a bounded
        // rate.
        if self.mode.airborne() && self.mode != FlightMode::Manual {
            let frame = (self.estimator.yaw_from_vision(), self.estimator.counters().yaw_resets);
            if !frame.0 || frame != self.yaw_frame {
                self.yaw_d = est.attitude.yaw;
            } else {
                let max = YAW_SETPOINT_RATE_RAD_S * dt;
                self.yaw_d = geometry::wrap_pi(
                    self.yaw_d
                        + geometry::clamp_finite(geometry::wrap_pi(traj.yaw_d_rad - self.yaw_d), -max, max),
                );
            }
            self.yaw_frame = frame;
        }

        // Vision holds the position (a fix accepted within `vision_hold_after_s`).
        let vision_fresh =
            self.last_fix_us.is_some_and(|t| now.saturating_sub(t) as f32 * 1e-6 <= fs.vision_hold_after_s);
        // Nothing measures the position or the velocity: a hold or a landing backs away from the wall (see
        // `failsafe.blind_retreat_speed_m_s`), at most `blind_retreat_max_m` per blind spell.
        let flow_fresh =
            self.last_flow_us.is_some_and(|t| now.saturating_sub(t) as f32 * 1e-6 <= fs.vision_hold_after_s);
        let blind =
            matches!(self.mode, FlightMode::VisionHold | FlightMode::Landing) && !vision_fresh && !flow_fresh;
        // How far: twice the estimate's own distance uncertainty (the wall kept two sigmas away), at most
        // `blind_retreat_max_m`. A short blind spell, whose estimate is still sharp, hardly moves the vehicle.
        let retreat_target =
            (BLIND_RETREAT_SIGMAS * est.position_std_m.y).min(fs.blind_retreat_max_m).max(0.0);
        let retreat_step = if blind && self.retreat_m < retreat_target {
            let d = (fs.blind_retreat_speed_m_s * dt).min(retreat_target - self.retreat_m);
            self.retreat_m += d;
            d
        } else {
            if !blind {
                self.retreat_m = 0.0;
            }
            0.0
        };
        let retreat_speed = if retreat_step > 0.0 { fs.blind_retreat_speed_m_s } else { 0.0 };

        // Mission progress and the reference.
        let mut sp = Setpoint { position_m: self.hold, yaw_rad: self.yaw_d, ..Setpoint::default() };
        match self.mode {
            FlightMode::TakeOff | FlightMode::Landing => {
                if self.mode == FlightMode::Landing && retreat_step > 0.0 {
                    self.hold.y += retreat_step;
                    sp.position_m.y = self.hold.y;
                    sp.velocity_m_s.y = retreat_speed;
                }
                if let Some((mv, t0)) = self.vertical {
                    let (z, vz, az) = mv.eval(now.saturating_sub(t0) as f32 * 1e-6);
                    sp.position_m.z = z;
                    sp.velocity_m_s.z = vz;
                    sp.accel_m_s2.z = az;
                }
                if self.mode == FlightMode::TakeOff {
                    let done = self
                        .vertical
                        .is_some_and(|(mv, t0)| now.saturating_sub(t0) as f32 * 1e-6 >= mv.duration_s());
                    let close = (est.position_m.z - traj.z_d_m).abs() < TAKEOFF_CLOSE_M;
                    if done && close {
                        let since = *self.settled_since_us.get_or_insert(now);
                        if now.saturating_sub(since) as f32 * 1e-6 >= traj.settle_s {
                            self.mode = FlightMode::Hover;
                            self.vertical = None;
                        }
                    } else {
                        self.settled_since_us = None;
                    }
                    // A take-off that has not settled in time: hover where it is when airborne, else land.
                    let late = self.vertical.is_some_and(|(mv, t0)| {
                        now.saturating_sub(t0) as f32 * 1e-6 > mv.duration_s() + traj.takeoff_timeout_s
                    });
                    if late && self.mode == FlightMode::TakeOff {
                        self.failsafe = Some(Failsafe::TakeOffTimeout);
                        if est.position_m.z > traj.ground_height_m + TAKEOFF_AIRBORNE_M {
                            self.mode = FlightMode::Hover;
                            self.vertical = None;
                        } else {
                            self.begin_landing(now, &est);
                        }
                    }
                } else {
                    // The land detector (as PX4's and ArduPilot's): the thrust demand near idle, the specific
                    // force that of gravity (the floor carries the vehicle: no vertical acceleration) and no
                    // rotation, for `land_detect_s`. It needs neither vision nor the height estimate.
                    let ld = &self.params.failsafe;
                    let weight = self.params.vehicle.mass_kg * GRAVITY;
                    let resting = self.last_thrust_n < ld.land_thrust_fraction * weight
                        && step_accel.is_some_and(|f| (f - GRAVITY).abs() < ld.land_accel_tolerance_m_s2)
                        && est.rates_rad_s.norm() < ld.land_rate_tolerance_rad_s;
                    if resting {
                        let since = *self.touchdown_since_us.get_or_insert(now);
                        if now.saturating_sub(since) as f32 * 1e-6 >= ld.land_detect_s {
                            self.motors_off(FlightMode::Disarmed);
                        }
                    } else {
                        self.touchdown_since_us = None;
                    }
                }
            }
            FlightMode::Tracking => {
                if let Some(sw) = self.sweep.as_mut() {
                    let (x, vx, ax) = sw.update(self.sweep_clock_us);
                    // On the sweep's clock, running at `pace`: d/dt = pace d/dtau (the pace's own change adds
                    // vx pace', at most the pass's speed over SWEEP_PACE_CHANGE_S, left out).
                    let pace = self.sweep_pace;
                    sp.position_m = Vec3::new(x, traj.y_d_m, traj.z_d_m);
                    sp.velocity_m_s.x = vx * pace;
                    sp.accel_m_s2.x = ax * pace * pace;
                    if let Some((ry, rz, t0)) = self.rejoin {
                        let t = now.saturating_sub(t0) as f32 * 1e-6;
                        let ((y, vy, ay), (z, vz, az)) = (ry.eval(t), rz.eval(t));
                        (sp.position_m.y, sp.velocity_m_s.y, sp.accel_m_s2.y) = (y, vy, ay);
                        (sp.position_m.z, sp.velocity_m_s.z, sp.accel_m_s2.z) = (z, vz, az);
                        if t >= ry.duration_s().max(rz.duration_s()) {
                            self.rejoin = None;
                        }
                    }
                    self.hold = sp.position_m;
                    if sw.finished() {
                        self.mode = FlightMode::Hover;
                    }
                }
            }
            FlightMode::VisionHold => {
                // Hold attitude and altitude: damp the horizontal velocity, no position reference (blind: back
                // away from the wall).
                sp.position_m.x = est.position_m.x;
                sp.position_m.y = est.position_m.y;
                sp.velocity_m_s.y = retreat_speed;
            }
            FlightMode::Manual => {
                let off_pad = est.position_m.z > traj.ground_height_m + TAKEOFF_AIRBORNE_M;
                let idle = self.manual_idle(off_pad);
                sp = self.manual_setpoint(&est, dt, idle);
            }
            _ => {}
        }

        // Every reference moves at a bounded rate from where it was (a failsafe restarts it where the vehicle
        // is): no step anywhere.
        if matches!(
            self.mode,
            FlightMode::Disarmed | FlightMode::Armed | FlightMode::Emergency | FlightMode::Manual
        ) {
            // On the ground nothing moves; in manual the sticks' references are rates already.
            self.limiter.restart(est.position_m);
        } else {
            let h = traj.speed_m_s.max(traj.takeoff_speed_m_s) * SETPOINT_RATE_MARGIN;
            let v = traj.takeoff_speed_m_s.max(traj.landing_speed_m_s) * SETPOINT_RATE_MARGIN;
            sp = self.limiter.limit(&sp, h, v, dt);
            if self.mode == FlightMode::VisionHold {
                // The hold has no horizontal position reference: it damps the velocity where the vehicle is
                // (blind, it backs away from the wall). Through the limiter an estimate that moves faster than
                // the limit would leave the reference behind, with a velocity along the motion.
                sp.position_m.x = est.position_m.x;
                sp.position_m.y = est.position_m.y;
                sp.velocity_m_s.x = 0.0;
                sp.velocity_m_s.y = retreat_speed;
                sp.accel_m_s2.x = 0.0;
                sp.accel_m_s2.y = 0.0;
                self.limiter.restart(sp.position_m);
            }
        }

        // Laws and mixer. The altitude integral works from lift-off (a vehicle heavier or lighter than
        // configured completes its take-off).
        let off_pad = est.position_m.z > traj.ground_height_m + TAKEOFF_AIRBORNE_M;
        let integrate =
            matches!(self.mode, FlightMode::Hover | FlightMode::Tracking | FlightMode::VisionHold)
                || (matches!(self.mode, FlightMode::TakeOff | FlightMode::Manual) && off_pad);
        let horizontal = match self.mode {
            FlightMode::Manual => {
                let [roll, pitch] = self.manual_tilt();
                Horizontal::Attitude { roll, pitch }
            }
            _ => Horizontal::Position,
        };
        let (mut demand, law) =
            self.controller.update_with(&est, &sp, horizontal, dt, integrate, self.motors);
        // The vertical thrust that holds the vehicle, learned while vision holds the height (the altitude
        // integral has found the real mass and thrust by then): without vision the height is dead-reckoned and
        // may drift either way by tens of centimetres in seconds, so a landing without vision may never ask for
        // more than this (it cannot climb away on a drifting estimate; it descends, and the land detector
        // ends it on the floor).
        let cos_tilt = geometry::clamp_finite(
            geometry::trig::cos(est.attitude.roll) * geometry::trig::cos(est.attitude.pitch),
            0.5,
            1.0,
        );
        if vision_fresh && matches!(self.mode, FlightMode::Hover | FlightMode::Tracking) {
            let a = (dt / HOVER_THRUST_FILTER_S).clamp(0.0, 1.0);
            let vertical = demand.thrust_n * cos_tilt;
            self.hover_thrust_n = Some(self.hover_thrust_n.map_or(vertical, |h| h + (vertical - h) * a));
        }
        if self.mode == FlightMode::Landing
            && !vision_fresh
            && let Some(h) = self.hover_thrust_n
        {
            demand.thrust_n = demand.thrust_n.min(BLIND_LANDING_THRUST_MARGIN * h / cos_tilt);
        }
        // Ground contact while landing. The thrust is wound down to idle in `ground_contact_ramp_s`, so that the
        // land detector sees it, once the floor may carry the vehicle: the estimate no longer descends although the
        // reference has left it `GROUND_CONTACT_LAG_M` behind, or the
        // specific force exceeds what the thrust explains, or the reference has gone `TOUCHDOWN_EXPECTED_M`
        // below the pad (touchdown is overdue: the height estimate, without vision near the floor, may have
        // drifted). The accelerometer decides, not the estimate: the wind-down goes on while the specific force
        // stays that of gravity (the floor carries what the rotors no longer do) and stops as soon as it falls
        // below (the vehicle was still in the air and sinks: the law takes over again).
        if self.mode == FlightMode::Landing {
            let fs = &self.params.failsafe;
            let supported = step_accel.is_some_and(|f| (f - GRAVITY).abs() < fs.land_accel_tolerance_m_s2);
            let weight_per_kg = self.last_thrust_n / self.params.vehicle.mass_kg;
            let carried = step_accel.is_some_and(|f| f - weight_per_kg > GROUND_CONTACT_EXCESS * GRAVITY);
            let overdue = sp.position_m.z < traj.ground_height_m - TOUCHDOWN_EXPECTED_M;
            // The height estimate held at the floor counts too (a landing without vision descends on the
            // estimate's speed, not to a height).
            let stalled = est.velocity_m_s.z > -GROUND_CONTACT_SPEED_M_S
                && est.position_m.z - sp.position_m.z > GROUND_CONTACT_LAG_M;
            let contact = stalled || carried || overdue || at_floor;
            // A bounce on touchdown unsettles the specific force for a few samples; sinking through the air
            // (the floor was not there) unsettles it for good: the wind-down stops after
            // `GROUND_CONTACT_LOST_S` without support.
            if supported {
                self.unsupported_since_us = None;
            } else {
                self.unsupported_since_us.get_or_insert(now);
            }
            let lost = self
                .unsupported_since_us
                .is_some_and(|t| now.saturating_sub(t) as f32 * 1e-6 > GROUND_CONTACT_LOST_S);
            if lost {
                self.contact_since_us = None;
            } else if (contact && supported) || self.contact_since_us.is_some() {
                let since = *self.contact_since_us.get_or_insert(now);
                let t = now.saturating_sub(since) as f32 * 1e-6;
                let cap =
                    (1.0 - t / fs.ground_contact_ramp_s).max(0.0) * self.params.vehicle.mass_kg * GRAVITY;
                demand.thrust_n = demand.thrust_n.min(cap);
            }
        } else {
            self.contact_since_us = None;
            self.unsupported_since_us = None;
        }
        self.last_thrust_n = if self.mode.airborne() { demand.thrust_n } else { 0.0 };
        let mut mix = MixerOutput::default();
        let manual_idle = self.manual_idle(off_pad);
        self.motors = match self.mode {
            FlightMode::Disarmed | FlightMode::Emergency => [0.0; 4],
            FlightMode::Armed => [self.params.vehicle.motor_speed_min_rad_s; 4],
            // Manual on the ground with the throttle not asking to climb: idle, as armed.
            FlightMode::Manual if manual_idle => [self.params.vehicle.motor_speed_min_rad_s; 4],
            _ => {
                mix = mixer::mix(&demand, &self.params.vehicle);
                mix.speeds_rad_s
            }
        };
        let sweep = self.sweep;
        let status = Status {
            mode: self.mode,
            failsafe: self.failsafe,
            last_command: self.last_command,
            fix_age_s: self.last_fix_us.map_or(f32::INFINITY, |t| now.saturating_sub(t) as f32 * 1e-6),
            fix_outcome,
            passes_done: sweep.map_or(0, |s| s.passes_done),
            sweep_forward: sweep.is_some_and(|s| s.forward),
            law,
            mixer: mix,
            imu_rejected,
        };
        ControlOutputs { motors_rad_s: self.motors, status, estimate: est, setpoint: sp }
    }
}

#[cfg(test)]
mod failsafe_tests;
#[cfg(test)]
mod pilot_tests;
#[cfg(test)]
mod test_harness;
