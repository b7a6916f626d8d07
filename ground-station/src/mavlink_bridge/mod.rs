//! The vehicle as a MAVLink 2 system, so that QGroundControl, MAVProxy or pymavlink see and command it: a
//! bridge between what comes down our radio (telemetry, acknowledgements, parameter replies) and the common
//! dialect's messages (the `mavlink` crate), and back from a ground control station's commands to our
//! operator commands and parameter requests. The bridge is pure (no socket, no clock): the caller gives
//! it the time and carries its messages ([`udp`] is the transport the station uses).
//!
//! What it sends (docs/mavlink.md has the whole mapping):
//! - `HEARTBEAT` once a second: `MAV_TYPE_QUADROTOR`, `MAV_AUTOPILOT_GENERIC`, the armed flag, and our
//!   [`FlightMode`] as the custom mode ([`custom_mode`]);
//! - `SYS_STATUS` once a second; `ATTITUDE`, `ATTITUDE_QUATERNION` and `LOCAL_POSITION_NED` with every
//!   telemetry, our frames converted to NED / FRD ([`ned_from_world`], [`frd_in_ned`]); `time_boot_ms` is
//!   the vehicle's clock;
//! - `STATUSTEXT` when a failsafe starts and when the vehicle refuses a command or a parameter;
//! - `COMMAND_ACK` with the vehicle's own answer; `PARAM_VALUE` with the vehicle's own value.
//!
//! What it takes: `COMMAND_LONG` `MAV_CMD_COMPONENT_ARM_DISARM` (param2 21196, the force-disarm magic
//! value, is our kill), `MAV_CMD_NAV_TAKEOFF`, `MAV_CMD_NAV_LAND`, `MAV_CMD_DO_SET_MODE` (custom modes
//! Tracking, Hover and Landing; the deprecated `SET_MODE` is not taken); `PARAM_REQUEST_LIST`, `PARAM_REQUEST_READ` and `PARAM_SET`
//! on our parameter table by [`ParamId::short_name`].
pub mod udp;

use control_core::params::ParamId;
use control_core::{Command, CommandResult, Failsafe, FlightMode, ParamOutcome, ParamReply};
use geometry::{Quat, Vec3};
use mavlink::dialects::common as mav;
use protocol::{Telemetry, Uplink};

pub use mav::MavMessage;

/// Our system id on MAVLink (the first vehicle).
pub const SYSTEM_ID: u8 = 1;
/// Our component id: the autopilot (`MAV_COMP_ID_AUTOPILOT1`).
pub const COMPONENT_ID: u8 = 1;
/// `MAV_CMD_COMPONENT_ARM_DISARM`'s param2 that forces a disarm in flight: our kill.
pub const FORCE_DISARM_MAGIC: f32 = 21196.0;
/// Between two heartbeats and two `SYS_STATUS` (us).
pub const HEARTBEAT_PERIOD_US: u64 = 1_000_000;
/// A command the vehicle has not answered within this time gets no `COMMAND_ACK` (the ground control
/// station sends it again) (us).
pub const ACK_WAIT_US: u64 = 3_000_000;

/// What the bridge asks of the station.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Request {
    /// An operator command.
    Command(Command),
    /// Motors off now: the station's kill (a disarm sent several times, ahead of anything else).
    Kill,
    /// Read a parameter on the vehicle.
    ParamGet(ParamId),
    /// Change a parameter on the vehicle.
    ParamSet(ParamId, f32),
}

/// What the bridge counted.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct BridgeCounters {
    /// Messages taken from the ground control station and acted on.
    pub taken: u64,
    /// Messages from the ground control station addressed to another system, or of a kind the bridge does
    /// not act on (heartbeats, for instance).
    pub ignored: u64,
    /// Commands answered `MAV_RESULT_UNSUPPORTED`.
    pub unsupported_commands: u64,
    /// Commands the vehicle did not answer within [`ACK_WAIT_US`].
    pub unanswered_commands: u64,
    /// Parameter requests naming no parameter of ours.
    pub unknown_params: u64,
}

/// The custom mode a heartbeat carries for a flight mode (documented in docs/mavlink.md).
pub fn custom_mode(m: FlightMode) -> u32 {
    match m {
        FlightMode::Disarmed => 0,
        FlightMode::Armed => 1,
        FlightMode::TakeOff => 2,
        FlightMode::Hover => 3,
        FlightMode::Tracking => 4,
        FlightMode::VisionHold => 5,
        FlightMode::Landing => 6,
        FlightMode::Emergency => 7,
        FlightMode::Manual => 8,
    }
}

/// The command a ground control station's mode change asks for: Tracking starts the sweep, Hover stops
/// it, Landing lands; other modes are not entered on request.
pub fn command_for_custom_mode(mode: u32) -> Option<Command> {
    match mode {
        3 => Some(Command::StopTracking),
        4 => Some(Command::StartTracking),
        6 => Some(Command::Land),
        _ => None,
    }
}

/// A world-frame vector (`W`: x along the wall, y from the wall, z up; docs/frames.md) in the local NED
/// frame: north is the navigation frame's x (toward the wall, `-y_W`), east `-x_W`, down `-z_W`.
pub fn ned_from_world(v: Vec3) -> [f32; 3] {
    [-v.y, -v.x, -v.z]
}

/// A body vector in FLU (ours) as FRD (MAVLink's body frame).
pub fn frd_from_flu(v: Vec3) -> [f32; 3] {
    [v.x, -v.y, -v.z]
}

/// The attitude `q_WB` (body FLU in the world frame) as MAVLink's: the FRD body in NED, `(w, x, y, z)`.
/// NED is our navigation frame `N` turned half a turn about its x axis, as FRD is FLU: the rotation
/// `R_NED_FRD = Rx(pi) R_NB Rx(pi)`, whose quaternion is `R_NB`'s with y and z negated.
pub fn frd_in_ned(q_wb: Quat) -> Quat {
    let r_nb = geometry::frames::WORLD_FROM_NAV.transpose().mul_mat(&q_wb.to_mat3());
    // `from_mat3` gives the sign with w >= 0; negating y and z keeps it.
    let q = Quat::from_mat3(&r_nb);
    Quat::new(q.w, q.x, -q.y, -q.z)
}

/// Roll, pitch and yaw (rad, ZYX) of the FRD body in NED: ours with pitch and yaw negated.
pub fn euler_ned(q_wb: Quat) -> (f32, f32, f32) {
    frd_in_ned(q_wb).to_mat3().to_euler_zyx()
}

/// `s` in a fixed-length MAVLink string: NUL-padded, cut at `N` bytes.
fn char_array<const N: usize>(s: &str) -> mavlink::types::CharArray<N> {
    let mut b = [0u8; N];
    let n = s.len().min(N);
    b[..n].copy_from_slice(&s.as_bytes()[..n]);
    b.into()
}

/// The name a `param_id` holds (up to its first NUL).
fn param_id_str(c: &mavlink::types::CharArray<16>) -> &str {
    let bytes: &[u8; 16] = c;
    let n = bytes.iter().position(|&b| b == 0).unwrap_or(16);
    core::str::from_utf8(&bytes[..n]).unwrap_or("")
}

/// The bridge's state: the vehicle's last report, the commands waiting for the vehicle's answer, what
/// was counted.
#[derive(Debug, Default)]
pub struct Bridge {
    telemetry: Option<Telemetry>,
    next_status_us: u64,
    /// Commands sent to the vehicle, waiting for its acknowledgement: what was asked, the MAVLink command
    /// to answer, and when.
    pending: Vec<(Command, mav::MavCmd, u64)>,
    counters: BridgeCounters,
    /// Link errors the station counted (for `SYS_STATUS`).
    link_errors: u64,
    /// The vehicle's last battery report (for `SYS_STATUS`).
    battery: Option<control_core::battery::BatteryStatus>,
}

impl Bridge {
    /// A bridge that has heard nothing yet.
    pub fn new() -> Self {
        Self::default()
    }

    /// What was counted.
    pub fn counters(&self) -> BridgeCounters {
        self.counters
    }

    /// The station's count of refused radio frames, reported in `SYS_STATUS`.
    pub fn set_link_errors(&mut self, n: u64) {
        self.link_errors = n;
    }

    /// The heartbeat for the vehicle's last reported state.
    pub fn heartbeat(&self) -> MavMessage {
        let mode = self.telemetry.map(|t| t.mode);
        let armed = mode.is_some_and(|m| m != FlightMode::Disarmed);
        let mut base = mav::MavModeFlag::MAV_MODE_FLAG_CUSTOM_MODE_ENABLED;
        if armed {
            base |= mav::MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED;
            // The pilot's manual mode takes the sticks, not the station's guidance.
            base |= if mode == Some(FlightMode::Manual) {
                mav::MavModeFlag::MAV_MODE_FLAG_MANUAL_INPUT_ENABLED
                    | mav::MavModeFlag::MAV_MODE_FLAG_STABILIZE_ENABLED
            } else {
                mav::MavModeFlag::MAV_MODE_FLAG_GUIDED_ENABLED
            };
        }
        let status = match (mode, self.telemetry.and_then(|t| t.failsafe)) {
            (None, _) => mav::MavState::MAV_STATE_BOOT,
            (Some(FlightMode::Emergency), _) => mav::MavState::MAV_STATE_EMERGENCY,
            (Some(m), Some(_)) if m.airborne() => mav::MavState::MAV_STATE_CRITICAL,
            (Some(FlightMode::Disarmed), _) => mav::MavState::MAV_STATE_STANDBY,
            (Some(_), _) => mav::MavState::MAV_STATE_ACTIVE,
        };
        MavMessage::HEARTBEAT(mav::HEARTBEAT_DATA {
            custom_mode: mode.map_or(0, custom_mode),
            mavtype: mav::MavType::MAV_TYPE_QUADROTOR,
            autopilot: mav::MavAutopilot::MAV_AUTOPILOT_GENERIC,
            base_mode: base,
            system_status: status,
            mavlink_version: 3,
        })
    }

    fn sys_status(&self) -> MavMessage {
        use mav::MavSysStatusSensor as S;
        let present = S::MAV_SYS_STATUS_SENSOR_3D_GYRO
            | S::MAV_SYS_STATUS_SENSOR_3D_ACCEL
            | S::MAV_SYS_STATUS_SENSOR_VISION_POSITION
            | S::MAV_SYS_STATUS_SENSOR_OPTICAL_FLOW
            | S::MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION
            | S::MAV_SYS_STATUS_SENSOR_Z_ALTITUDE_CONTROL
            | S::MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL
            | S::MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS;
        let mut health = present;
        match self.telemetry.and_then(|t| t.failsafe) {
            Some(Failsafe::VisionLost | Failsafe::VisionLostLanding) => {
                health.remove(S::MAV_SYS_STATUS_SENSOR_VISION_POSITION)
            }
            Some(Failsafe::ImuFault) => {
                health.remove(S::MAV_SYS_STATUS_SENSOR_3D_GYRO | S::MAV_SYS_STATUS_SENSOR_3D_ACCEL)
            }
            Some(Failsafe::EstimatorFault | Failsafe::ExcessiveTilt) => {
                health.remove(S::MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION)
            }
            _ => {}
        }
        MavMessage::SYS_STATUS(mav::SYS_STATUS_DATA {
            onboard_control_sensors_present: present,
            onboard_control_sensors_enabled: present,
            onboard_control_sensors_health: health,
            load: 0,
            // The vehicle's battery report (mV and cA); without one, "not sent by autopilot".
            voltage_battery: self
                .battery
                .map_or(u16::MAX, |b| (b.voltage_v * 1000.0).round().clamp(0.0, 65534.0) as u16),
            current_battery: self
                .battery
                .and_then(|b| b.current_a)
                .map_or(-1, |i| (i * 100.0).round().clamp(0.0, 32767.0) as i16),
            drop_rate_comm: 0,
            errors_comm: self.link_errors.min(u16::MAX as u64) as u16,
            errors_count1: 0,
            errors_count2: 0,
            errors_count3: 0,
            errors_count4: 0,
            battery_remaining: -1,
        })
    }

    /// The periodic messages due at `now_us` (the station's clock): a heartbeat and `SYS_STATUS` once a
    /// second; the `COMMAND_ACK`s given up on.
    pub fn tick(&mut self, now_us: u64) -> Vec<MavMessage> {
        let mut out = Vec::new();
        if now_us >= self.next_status_us {
            self.next_status_us = now_us + HEARTBEAT_PERIOD_US;
            out.push(self.heartbeat());
            out.push(self.sys_status());
        }
        let before = self.pending.len();
        self.pending.retain(|&(_, _, at)| now_us.saturating_sub(at) < ACK_WAIT_US);
        self.counters.unanswered_commands += (before - self.pending.len()) as u64;
        out
    }

    /// A telemetry message from the vehicle: its attitude and position, and a `STATUSTEXT` when a failsafe
    /// starts.
    pub fn telemetry(&mut self, tm: &Telemetry) -> Vec<MavMessage> {
        let mut out = Vec::new();
        let previous = self.telemetry.replace(*tm);
        if let Some(f) = tm.failsafe
            && previous.is_none_or(|p| p.failsafe != Some(f))
        {
            out.push(statustext(mav::MavSeverity::MAV_SEVERITY_CRITICAL, &format!("failsafe: {f:?}")));
        }
        if previous.is_some_and(|p| p.mode != tm.mode) {
            out.push(statustext(mav::MavSeverity::MAV_SEVERITY_INFO, &format!("mode: {:?}", tm.mode)));
        }
        let e = &tm.estimate;
        let time_boot_ms = (tm.time_us / 1000) as u32;
        let (roll, pitch, yaw) = euler_ned(e.q);
        let [p, q, r] = frd_from_flu(e.rates_rad_s);
        out.push(MavMessage::ATTITUDE(mav::ATTITUDE_DATA {
            time_boot_ms,
            roll,
            pitch,
            yaw,
            rollspeed: p,
            pitchspeed: q,
            yawspeed: r,
        }));
        let qn = frd_in_ned(e.q);
        out.push(MavMessage::ATTITUDE_QUATERNION(mav::ATTITUDE_QUATERNION_DATA {
            time_boot_ms,
            q1: qn.w,
            q2: qn.x,
            q3: qn.y,
            q4: qn.z,
            rollspeed: p,
            pitchspeed: q,
            yawspeed: r,
        }));
        let [x, y, z] = ned_from_world(e.position_m);
        let [vx, vy, vz] = ned_from_world(e.velocity_m_s);
        out.push(MavMessage::LOCAL_POSITION_NED(mav::LOCAL_POSITION_NED_DATA {
            time_boot_ms,
            x,
            y,
            z,
            vx,
            vy,
            vz,
        }));
        out
    }

    /// The vehicle's battery report: kept for `SYS_STATUS`, and a `STATUSTEXT` when its level falls (a warning
    /// when low, critical when the vehicle lands on it).
    pub fn battery(&mut self, b: &control_core::battery::BatteryStatus) -> Vec<MavMessage> {
        use control_core::battery::BatteryLevel;
        let previous = self.battery.replace(*b).map(|p| p.level);
        let text = |sev, what: &str| statustext(sev, &format!("battery {what}: {:.2} V a cell", b.cell_v));
        match (previous, b.level) {
            (p, BatteryLevel::Low) if p != Some(BatteryLevel::Low) => {
                vec![text(mav::MavSeverity::MAV_SEVERITY_WARNING, "low")]
            }
            (p, BatteryLevel::Critical) if p != Some(BatteryLevel::Critical) => {
                vec![text(mav::MavSeverity::MAV_SEVERITY_CRITICAL, "critical")]
            }
            _ => Vec::new(),
        }
    }

    /// The vehicle's answer to a command: the `COMMAND_ACK` of the MAVLink command that asked for it
    /// (accepted, or denied with a `STATUSTEXT` naming the vehicle's reason).
    pub fn command_result(&mut self, r: CommandResult) -> Vec<MavMessage> {
        let (c, refusal) = match r {
            CommandResult::Accepted(c) => (c, None),
            CommandResult::Refused(c, why) => (c, Some(why)),
        };
        let mut out = Vec::new();
        if let Some(why) = refusal {
            out.push(statustext(mav::MavSeverity::MAV_SEVERITY_WARNING, &format!("{c:?} refused: {why:?}")));
        }
        if let Some(i) = self.pending.iter().position(|p| p.0 == c) {
            let (_, command, _) = self.pending.remove(i);
            let result = match refusal {
                None => mav::MavResult::MAV_RESULT_ACCEPTED,
                Some(control_core::Refusal::WrongMode | control_core::Refusal::NotLevel) => {
                    mav::MavResult::MAV_RESULT_TEMPORARILY_REJECTED
                }
                Some(_) => mav::MavResult::MAV_RESULT_DENIED,
            };
            out.push(MavMessage::COMMAND_ACK(mav::COMMAND_ACK_DATA { command, result }));
        }
        out
    }

    /// The vehicle's answer to a parameter request: its value now as `PARAM_VALUE` (after a refused change,
    /// the unchanged value, as MAVLink has it, with a `STATUSTEXT` saying why).
    pub fn param_reply(&mut self, r: ParamReply) -> Vec<MavMessage> {
        let mut out = Vec::new();
        match r.outcome {
            ParamOutcome::Ok => {}
            ParamOutcome::Refused => out.push(statustext(
                mav::MavSeverity::MAV_SEVERITY_WARNING,
                &format!("{} not changed: in flight", r.id.short_name()),
            )),
            ParamOutcome::Invalid => out.push(statustext(
                mav::MavSeverity::MAV_SEVERITY_WARNING,
                &format!("{} not changed: invalid", r.id.short_name()),
            )),
        }
        out.push(MavMessage::PARAM_VALUE(mav::PARAM_VALUE_DATA {
            param_value: r.value,
            param_count: ParamId::ALL.len() as u16,
            param_index: r.id as u16,
            param_id: char_array(r.id.short_name()),
            param_type: mav::MavParamType::MAV_PARAM_TYPE_REAL32,
        }));
        out
    }

    /// A message from the ground control station (system `_from_system`: any may command, the radio link is
    /// what is keyed), at `now_us`: what to ask of the
    /// station, and the answers due at once (an unsupported command's `COMMAND_ACK`, the kill's).
    pub fn take(
        &mut self,
        _from_system: u32,
        m: &MavMessage,
        now_us: u64,
    ) -> (Vec<Request>, Vec<MavMessage>) {
        let ours = |target: u8| target == 0 || target == SYSTEM_ID;
        let mut requests = Vec::new();
        let mut replies = Vec::new();
        match m {
            MavMessage::COMMAND_LONG(c) if ours(c.target_system) => {
                self.counters.taken += 1;
                let asked = match c.command {
                    mav::MavCmd::MAV_CMD_COMPONENT_ARM_DISARM if c.param1 == 1.0 => {
                        Some(Request::Command(Command::Arm))
                    }
                    mav::MavCmd::MAV_CMD_COMPONENT_ARM_DISARM
                        if c.param1 == 0.0 && c.param2 == FORCE_DISARM_MAGIC =>
                    {
                        Some(Request::Kill)
                    }
                    mav::MavCmd::MAV_CMD_COMPONENT_ARM_DISARM if c.param1 == 0.0 => {
                        Some(Request::Command(Command::Disarm))
                    }
                    mav::MavCmd::MAV_CMD_NAV_TAKEOFF => Some(Request::Command(Command::TakeOff)),
                    mav::MavCmd::MAV_CMD_NAV_LAND => Some(Request::Command(Command::Land)),
                    mav::MavCmd::MAV_CMD_DO_SET_MODE if c.param1 as u32 & 1 == 1 => {
                        command_for_custom_mode(c.param2 as u32).map(Request::Command)
                    }
                    _ => None,
                };
                self.ask(asked, c.command, now_us, &mut requests, &mut replies);
            }
            MavMessage::PARAM_REQUEST_LIST(p) if ours(p.target_system) => {
                self.counters.taken += 1;
                requests.extend(ParamId::ALL.iter().map(|&id| Request::ParamGet(id)));
            }
            MavMessage::PARAM_REQUEST_READ(p) if ours(p.target_system) => {
                self.counters.taken += 1;
                let id = if p.param_index >= 0 {
                    ParamId::ALL.get(p.param_index as usize).copied()
                } else {
                    ParamId::from_short_name(param_id_str(&p.param_id))
                };
                match id {
                    Some(id) => requests.push(Request::ParamGet(id)),
                    None => self.counters.unknown_params += 1,
                }
            }
            MavMessage::PARAM_SET(p) if ours(p.target_system) => {
                self.counters.taken += 1;
                match ParamId::from_short_name(param_id_str(&p.param_id)) {
                    Some(id) => requests.push(Request::ParamSet(id, p.param_value)),
                    None => {
                        self.counters.unknown_params += 1;
                        replies.push(statustext(
                            mav::MavSeverity::MAV_SEVERITY_WARNING,
                            &format!("no parameter {}", param_id_str(&p.param_id)),
                        ));
                    }
                }
            }
            _ => self.counters.ignored += 1,
        }
        (requests, replies)
    }

    fn ask(
        &mut self,
        asked: Option<Request>,
        command: mav::MavCmd,
        now_us: u64,
        requests: &mut Vec<Request>,
        replies: &mut Vec<MavMessage>,
    ) {
        match asked {
            Some(Request::Command(c)) => {
                self.pending.retain(|p| p.0 != c);
                self.pending.push((c, command, now_us));
                requests.push(Request::Command(c));
            }
            Some(Request::Kill) => {
                // Always carried out, never refused: acknowledged at once.
                requests.push(Request::Kill);
                replies.push(MavMessage::COMMAND_ACK(mav::COMMAND_ACK_DATA {
                    command,
                    result: mav::MavResult::MAV_RESULT_ACCEPTED,
                }));
            }
            _ => {
                self.counters.unsupported_commands += 1;
                replies.push(MavMessage::COMMAND_ACK(mav::COMMAND_ACK_DATA {
                    command,
                    result: mav::MavResult::MAV_RESULT_UNSUPPORTED,
                }));
            }
        }
    }
}

/// Parameter requests for the vehicle, one at a time: the vehicle answers one parameter per control step and
/// queues only a few more (`flight_core::REQUEST_QUEUE`), so a whole `PARAM_REQUEST_LIST` sent at once would
/// lose answers, and a radio loses frames. The next goes when the last is
/// answered, or after [`PARAM_RETRY_US`]; after [`PARAM_TRIES`] tries a request is given up and counted.
#[derive(Debug, Default)]
pub struct ParamQueue {
    /// Waiting: the parameter, and the value to set (`None`: a read).
    queue: std::collections::VecDeque<(ParamId, Option<f32>)>,
    /// In flight: the request, when it was last sent, how often.
    in_flight: Option<((ParamId, Option<f32>), u64, u32)>,
    /// Requests given up after [`PARAM_TRIES`] tries.
    pub given_up: u64,
    /// Requests resent.
    pub resent: u64,
}

/// How long a parameter request waits for its answer before it is sent again (us).
pub const PARAM_RETRY_US: u64 = 300_000;
/// How often a parameter request is sent before it is given up.
pub const PARAM_TRIES: u32 = 3;

impl ParamQueue {
    /// Queues a parameter request (other requests are not queued here; a request already waiting is not
    /// queued twice).
    pub fn push(&mut self, r: Request) {
        let p = match r {
            Request::ParamGet(id) => (id, None),
            Request::ParamSet(id, v) => (id, Some(v)),
            Request::Command(_) | Request::Kill => return,
        };
        if !self.queue.contains(&p) {
            self.queue.push_back(p);
        }
    }

    /// Requests waiting, the one in flight included.
    pub fn len(&self) -> usize {
        self.queue.len() + self.in_flight.is_some() as usize
    }

    /// Whether nothing waits.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The vehicle answered for `id`: the request in flight for it is done.
    pub fn answered(&mut self, id: ParamId) {
        if self.in_flight.is_some_and(|((i, _), ..)| i == id) {
            self.in_flight = None;
        }
    }

    /// The message to send up at `now_us`, if one is due.
    pub fn next(&mut self, now_us: u64) -> Option<Uplink> {
        let uplink = |(id, v): (ParamId, Option<f32>)| match v {
            None => Uplink::ParamGet(id),
            Some(value) => Uplink::ParamSet { id, value },
        };
        if let Some((p, at, tries)) = self.in_flight {
            if now_us.saturating_sub(at) < PARAM_RETRY_US {
                return None;
            }
            if tries < PARAM_TRIES {
                self.in_flight = Some((p, now_us, tries + 1));
                self.resent += 1;
                return Some(uplink(p));
            }
            self.given_up += 1;
            self.in_flight = None;
        }
        let p = self.queue.pop_front()?;
        self.in_flight = Some((p, now_us, 1));
        Some(uplink(p))
    }
}

fn statustext(severity: mav::MavSeverity, s: &str) -> MavMessage {
    MavMessage::STATUSTEXT(mav::STATUSTEXT_DATA { severity, text: char_array(s) })
}

#[cfg(test)]
mod tests;
