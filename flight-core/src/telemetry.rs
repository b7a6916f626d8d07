//! What the vehicle sends down the radio link after each control step: command acknowledgements, parameter
//! replies and periodic telemetry. One policy, run by the firmware on the board, by the firmware in the loop,
//! and by the simulator when it writes a flight log, so that a log holds the very `Downlink` records the
//! vehicle would have sent.
use control_core::{CommandResult, ControlOutputs, ParamReply};
use protocol::{Downlink, PackedTelemetry, Telemetry};

/// The default telemetry period in control steps (25 Hz at the 500 Hz control rate): the parameter
/// `downlink.telemetry_every_steps`, which a ground station on a slow radio raises.
pub const TELEMETRY_EVERY: u32 = 20;

/// The battery's report is sent this often (us), and at once when its level changes.
pub const BATTERY_PERIOD_US: u64 = 1_000_000;

/// The downlink schedule: which messages a step produces.
#[derive(Clone, Debug, Default)]
pub struct DownlinkSchedule {
    steps: u32,
    last_command: Option<CommandResult>,
    /// When the battery was last reported, and its level then.
    last_battery: Option<(u64, control_core::battery::BatteryLevel)>,
}

impl DownlinkSchedule {
    /// A schedule before the first step.
    pub const fn new() -> Self {
        Self { steps: 0, last_command: None, last_battery: None }
    }

    /// The messages of one step, in order: the acknowledgement of a command whose outcome changed, the reply
    /// to this step's parameter request, the answer to its clock-synchronisation request (`time_sync`, the
    /// station time to echo with `time_us`), and every `telemetry_every`th step (the step output's
    /// `telemetry_every`, [`TELEMETRY_EVERY`] by default) telemetry with the step's measured cost
    /// (`step_cost`, 0 when not measured), packed ([`protocol::packed`]); and the battery (when monitored)
    /// every [`BATTERY_PERIOD_US`] and when its level changes.
    #[allow(clippy::too_many_arguments)]
    pub fn after_step(
        &mut self,
        control: &ControlOutputs,
        param_reply: Option<ParamReply>,
        time_sync: Option<u64>,
        time_us: u64,
        step_cost: u32,
        telemetry_every: u32,
        battery: Option<control_core::battery::BatteryStatus>,
        mut send: impl FnMut(Downlink),
    ) {
        self.steps = self.steps.wrapping_add(1);
        let st = control.status;
        if st.last_command != self.last_command {
            self.last_command = st.last_command;
            if let Some(r) = st.last_command {
                send(Downlink::CommandAck(r));
            }
        }
        if let Some(r) = param_reply {
            send(Downlink::Param(r));
        }
        if let Some(station_time_us) = time_sync {
            send(Downlink::TimeSync { station_time_us, vehicle_time_us: time_us });
        }
        if self.steps.is_multiple_of(telemetry_every.max(1)) {
            send(Downlink::PackedTelemetry(PackedTelemetry::pack(&Telemetry {
                time_us,
                mode: st.mode,
                failsafe: st.failsafe,
                estimate: control.estimate,
                setpoint: control.setpoint,
                motors_rad_s: control.motors_rad_s,
                fix_age_s: st.fix_age_s,
                step_cost,
            })));
        }
        if let Some(b) = battery {
            let due = match self.last_battery {
                None => true,
                Some((t, level)) => level != b.level || time_us.saturating_sub(t) >= BATTERY_PERIOD_US,
            };
            if due {
                self.last_battery = Some((time_us, b.level));
                send(Downlink::Battery(b));
            }
        }
    }

    /// Steps seen.
    pub fn steps(&self) -> u32 {
        self.steps
    }
}
