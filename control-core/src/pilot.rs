//! The pilot's RC transmitter: a kill switch, an arm switch, a mode switch and a manual attitude mode, and RC
//! loss as a failsafe (docs/architecture.md, "The pilot's transmitter").
//!
//! The receiver's driver decodes the radio (`drivers::crsf` for ExpressLRS and TBS Crossfire) into a
//! [`PilotInput`] every control step; `None` when no receiver has been heard. What it does, in this order of
//! precedence:
//!
//! 1. **Kill switch** high (with the RC link up): motors off at once, in any mode (`Failsafe::Killed`), and
//!    arming refused until it is low again (`Refusal::KillSwitch`).
//! 2. **Arm switch**: low to high arms (the checks of an `Arm` command, and the vehicle must see the switch low
//!    first, so that a switch left high at power-up arms nothing); high to low disarms. While a receiver is in
//!    use, the station's `Arm` is refused with the switch low (`Refusal::ArmSwitchOff`): the pilot has the last
//!    word.
//! 3. **Mode switch**, while armed: low is [`crate::FlightMode::Manual`] (stick tilt, climb rate and yaw rate;
//!    the vision and the mission are not used to steer), mid the automatic mode (the station's commands fly the
//!    paper's mission; from manual the vehicle holds where it is), high lands.
//! 4. **RC loss** (no frame for 300 ms, or the receiver reporting no uplink; `drivers::crsf`): in manual the
//!    vehicle holds level at its height for `rc.loss_hold_s`, then lands (`Failsafe::RcLost`); with
//!    `rc.required` the same in the automatic modes, and on the ground armed it disarms. The radio link's own
//!    failsafes (station lost, vision lost) stay as they are in the automatic modes.
use crate::estimator::StateEstimate;
use crate::{Command, ControlCore, Failsafe, FlightMode};

/// The RC link as the receiver reports it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum RcLink {
    /// Frames arrive and the receiver has its uplink.
    Ok,
    /// No frame for the receiver's timeout, or it reports no uplink (its failsafe).
    Lost,
}

/// The mode switch's position.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ModeSwitch {
    /// Low: manual attitude.
    Manual,
    /// Mid: the automatic mode (the station's mission).
    Auto,
    /// High: land.
    Land,
}

/// The pilot's transmitter this step, as the receiver's driver decodes it.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PilotInput {
    /// The RC link; the rest is the last frame's (meaningless while lost).
    pub link: RcLink,
    /// Roll stick, -1 (left) to 1 (right).
    pub roll: f32,
    /// Pitch stick, -1 (back) to 1 (forward: nose down).
    pub pitch: f32,
    /// Yaw stick, -1 (left, counter-clockwise from above) to 1 (right).
    pub yaw: f32,
    /// Throttle stick, 0 (down) to 1 (up); the centre holds the height in manual.
    pub throttle: f32,
    /// The arm switch (high: armed).
    pub arm: bool,
    /// The mode switch.
    pub mode: ModeSwitch,
    /// The kill switch (high: motors off).
    pub kill: bool,
}

/// What the flight code keeps of the pilot between steps.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct PilotState {
    /// A frame with the link up was seen since power-up: a receiver is in use.
    pub seen: bool,
    /// The arm switch's last position seen with the link up (`None` before the first).
    pub arm: Option<bool>,
    /// The kill switch was high at the last frame with the link up.
    pub killed: bool,
    /// Since when the link has been down while it mattered (us).
    pub lost_since_us: Option<u64>,
    /// Manual mode's references: yaw (rad) and height (m), from where the vehicle was when manual began.
    pub yaw_ref: f32,
    pub z_ref: f32,
}

/// A stick value with the dead band around the centre taken out (and the rest stretched back to +-1).
pub fn deadband(v: f32, band: f32) -> f32 {
    let v = geometry::clamp_finite(v, -1.0, 1.0);
    if libm::fabsf(v) <= band { 0.0 } else { (v - band * v.signum()) / (1.0 - band) }
}

/// Manual mode's references this step: roll and pitch (rad), the climb rate (m/s) and the yaw rate (rad/s).
pub(crate) fn manual_demand(p: &PilotInput, rc: &crate::params::RcParams) -> ([f32; 2], f32, f32) {
    let d = |v: f32| deadband(v, rc.deadband);
    let tilt = [d(p.roll) * rc.max_tilt_rad, d(p.pitch) * rc.max_tilt_rad];
    let climb = d(2.0 * p.throttle - 1.0) * rc.max_climb_m_s;
    // Yaw stick right turns clockwise seen from above: a negative yaw rate (z up).
    let yaw_rate = -d(p.yaw) * rc.max_yaw_rate_rad_s;
    (tilt, climb, yaw_rate)
}

impl ControlCore {
    /// The pilot's switches and the RC link, before the station's command (see the module's documentation).
    pub(crate) fn apply_pilot(
        &mut self,
        pilot: Option<PilotInput>,
        now: u64,
        est: &StateEstimate,
        imu_ok: bool,
        link_ok: bool,
    ) {
        let rc = self.params.rc;
        let up = pilot.filter(|p| p.link == RcLink::Ok);
        if let Some(p) = up {
            self.pilot.seen = true;
            self.pilot.lost_since_us = None;
            // 1. The kill switch wins over everything.
            self.pilot.killed = p.kill;
            if p.kill {
                if self.mode != FlightMode::Disarmed || self.failsafe != Some(Failsafe::Killed) {
                    self.motors_off(FlightMode::Disarmed);
                    self.failsafe = Some(Failsafe::Killed);
                }
                self.pilot.arm = Some(p.arm);
                return;
            }
            // 2. The arm switch: its edges.
            let was = self.pilot.arm.replace(p.arm);
            match (was, p.arm) {
                (Some(false), true) => self.handle_command(Command::Arm, now, est, imu_ok, link_ok),
                (Some(true), false) if self.mode != FlightMode::Disarmed => {
                    self.handle_command(Command::Disarm, now, est, imu_ok, link_ok)
                }
                _ => {}
            }
            // 3. The mode switch, while armed.
            if matches!(self.mode, FlightMode::Disarmed | FlightMode::Emergency) {
                return;
            }
            match p.mode {
                ModeSwitch::Manual if self.mode != FlightMode::Manual => self.begin_manual(est),
                ModeSwitch::Auto if self.mode == FlightMode::Manual => self.end_manual(now, est),
                ModeSwitch::Land if self.mode.airborne() && self.mode != FlightMode::Landing => {
                    self.begin_landing(now, est)
                }
                _ => {}
            }
            return;
        }
        // 4. No link: a failsafe where it matters.
        let matters = self.mode == FlightMode::Manual
            || (rc.required && self.pilot.seen && self.mode != FlightMode::Disarmed);
        if !matters {
            self.pilot.lost_since_us = None;
            return;
        }
        let since = *self.pilot.lost_since_us.get_or_insert(now);
        self.failsafe = Some(Failsafe::RcLost);
        if self.mode == FlightMode::Armed {
            self.motors_off(FlightMode::Disarmed);
        } else if now.saturating_sub(since) as f32 * 1e-6 >= rc.loss_hold_s
            && self.mode != FlightMode::Landing
        {
            self.begin_landing(now, est);
        }
    }

    /// Whether a receiver in use lets the station arm: its arm switch high and its kill switch low (`None` when
    /// it may), or the refusal.
    pub(crate) fn pilot_arm_refusal(&self, pilot: Option<PilotInput>) -> Option<crate::Refusal> {
        let up = pilot.filter(|p| p.link == RcLink::Ok);
        if self.pilot.killed || up.is_some_and(|p| p.kill) {
            return Some(crate::Refusal::KillSwitch);
        }
        if self.params.rc.required && up.is_none() {
            return Some(crate::Refusal::NoRc);
        }
        if self.pilot.seen && up.is_none_or(|p| !p.arm) {
            return Some(crate::Refusal::ArmSwitchOff);
        }
        None
    }

    /// Manual mode from here: its references start where the vehicle is.
    fn begin_manual(&mut self, est: &StateEstimate) {
        self.mode = FlightMode::Manual;
        self.sweep = None;
        self.paused_sweep = None;
        self.rejoin = None;
        self.vertical = None;
        self.pilot.yaw_ref = est.attitude.yaw;
        self.pilot.z_ref = est.position_m.z;
        self.hold = est.position_m;
        if self.failsafe == Some(Failsafe::RcLost) {
            self.failsafe = None;
        }
    }

    /// Back to the automatic mode: on the ground armed, in the air holding where the vehicle is (the station's
    /// commands go on from there).
    fn end_manual(&mut self, now: u64, est: &StateEstimate) {
        let airborne = est.position_m.z > self.params.trajectory.ground_height_m + crate::TAKEOFF_AIRBORNE_M;
        if airborne {
            self.mode = FlightMode::Hover;
            self.hold = est.position_m;
            self.yaw_d = est.attitude.yaw;
            self.airborne_since_us = now;
            self.limiter.restart(est.position_m);
        } else {
            self.mode = FlightMode::Armed;
            self.controller.reset();
        }
    }
}

impl ControlCore {
    /// The sticks' demands while the RC link is up; centred (level, the height held, no turn) while it is down
    /// (the hold before an RC-loss landing).
    fn manual_sticks(&self) -> ([f32; 2], f32, f32) {
        match self.pilot_input.filter(|p| p.link == RcLink::Ok) {
            Some(p) => manual_demand(&p, &self.params.rc),
            None => ([0.0; 2], 0.0, 0.0),
        }
    }

    /// Manual mode's roll and pitch references (rad).
    pub(crate) fn manual_tilt(&self) -> [f32; 2] {
        self.manual_sticks().0
    }

    /// Whether manual mode sits on the ground at idle: not off the pad and the throttle not asking to climb.
    pub(crate) fn manual_idle(&self, off_pad: bool) -> bool {
        self.mode == FlightMode::Manual && !off_pad && self.manual_sticks().1 <= 0.0
    }

    /// Manual mode's reference this step: the height moves at the throttle's climb rate (kept within
    /// [`MANUAL_HEIGHT_LEAD_M`] of the estimate, so that it never winds up), the yaw at the yaw stick's rate;
    /// the horizontal position is where the vehicle is (the horizontal axes follow the sticks' tilt).
    pub(crate) fn manual_setpoint(
        &mut self,
        est: &StateEstimate,
        dt: f32,
        idle: bool,
    ) -> crate::laws::Setpoint {
        let (_, climb, yaw_rate) = self.manual_sticks();
        let z = est.position_m.z;
        self.pilot.z_ref = if idle {
            z
        } else {
            geometry::clamp_finite(
                self.pilot.z_ref + climb * dt,
                z - MANUAL_HEIGHT_LEAD_M,
                z + MANUAL_HEIGHT_LEAD_M,
            )
        };
        self.pilot.yaw_ref = geometry::wrap_pi(self.pilot.yaw_ref + yaw_rate * dt);
        crate::laws::Setpoint {
            position_m: geometry::Vec3::new(est.position_m.x, est.position_m.y, self.pilot.z_ref),
            velocity_m_s: geometry::Vec3::new(0.0, 0.0, if idle { 0.0 } else { climb }),
            accel_m_s2: geometry::Vec3::ZERO,
            yaw_rad: self.pilot.yaw_ref,
        }
    }
}

/// Manual mode: the height reference stays within this of the estimate (m).
pub const MANUAL_HEIGHT_LEAD_M: f32 = 0.5;
