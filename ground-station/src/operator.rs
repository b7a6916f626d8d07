//! The operator's commands: a script of the mission (the paper's: arm, take off, track, land), run against
//! the vehicle's mode as its telemetry reports it, with the retries a ground station makes for a command the
//! vehicle has not acted on (the radio may have lost it).
use control_core::{Command, FlightMode};

/// A command not acted on within this time is sent again (us).
pub const COMMAND_RETRY_US: u64 = 1_000_000;

/// When the script's steps happen.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MissionScript {
    /// Arm at this time after the start (s).
    pub arm_at_s: f64,
    /// Take off at this time after the start, once armed (s).
    pub takeoff_at_s: f64,
    /// Start the sweep after hovering this long (s).
    pub track_after_hover_s: f64,
    /// Land when the sweep is done (the vehicle hovers again after tracking).
    pub land_when_done: bool,
    /// Sweep; without it the vehicle lands after its hover (a short mission: take-off, hover, landing).
    pub sweep: bool,
}

impl MissionScript {
    /// The paper's mission: arm at 1 s, take off at 2 s, sweep after 2 s of hover, land when done.
    pub const PAPER: Self = Self {
        arm_at_s: 1.0,
        takeoff_at_s: 2.0,
        track_after_hover_s: 2.0,
        land_when_done: true,
        sweep: true,
    };

    /// The paper's mission without the sweep: arm, take off, hover 2 s, land.
    pub const HOVER: Self = Self { sweep: false, ..Self::PAPER };
}

/// The script's state: which commands were sent, when, and what the vehicle has been seen doing.
#[derive(Clone, Debug)]
pub struct Operator {
    script: MissionScript,
    sent: [bool; 4],
    sent_at: [u64; 4],
    hover_since: Option<u64>,
    tracked: bool,
    was_airborne: bool,
}

impl Operator {
    /// An operator that will run `script`.
    pub fn new(script: MissionScript) -> Self {
        Self {
            script,
            sent: [false; 4],
            sent_at: [0; 4],
            hover_since: None,
            tracked: false,
            was_airborne: false,
        }
    }

    /// The script.
    pub fn script(&self) -> &MissionScript {
        &self.script
    }

    /// Whether the vehicle has been seen tracking.
    pub fn tracked(&self) -> bool {
        self.tracked
    }

    /// The command to send at `t_us` (since the script's start), given the vehicle's last reported mode
    /// (`None` before any telemetry), if any.
    pub fn tick(&mut self, t_us: u64, mode: Option<FlightMode>) -> Option<Command> {
        let s = self.script;
        let t = t_us as f64 * 1e-6;
        if mode == Some(FlightMode::Tracking) {
            self.tracked = true;
        }
        if mode.is_some_and(|m| m.airborne()) {
            self.was_airborne = true;
        }
        if mode != Some(FlightMode::Hover) {
            self.hover_since = None;
        }
        let mut cmd = None;
        if !self.sent[0] && t >= s.arm_at_s {
            cmd = Some(Command::Arm);
        } else if !self.sent[1] && t >= s.takeoff_at_s && mode == Some(FlightMode::Armed) {
            cmd = Some(Command::TakeOff);
        } else if !self.sent[2] && !self.sent[3] && self.sent[1] && mode == Some(FlightMode::Hover) {
            let since = *self.hover_since.get_or_insert(t_us);
            if (t_us - since) as f64 * 1e-6 >= s.track_after_hover_s {
                cmd = Some(if s.sweep { Command::StartTracking } else { Command::Land });
            }
        } else if !self.sent[3]
            && self.sent[2]
            && s.land_when_done
            && mode == Some(FlightMode::Hover)
            && self.tracked
        {
            cmd = Some(Command::Land);
        }
        if cmd.is_none() {
            let waiting = [
                (0, Command::Arm, mode == Some(FlightMode::Disarmed) && !self.was_airborne),
                (1, Command::TakeOff, mode == Some(FlightMode::Armed)),
                (2, Command::StartTracking, mode == Some(FlightMode::Hover) && !self.tracked),
                (3, Command::Land, mode == Some(FlightMode::Hover) && (self.tracked || !s.sweep)),
            ];
            for (i, c, still) in waiting {
                if self.sent[i] && still && t_us.saturating_sub(self.sent_at[i]) >= COMMAND_RETRY_US {
                    cmd = Some(c);
                    break;
                }
            }
        }
        if let Some(c) = cmd {
            let i = match c {
                Command::Arm => 0,
                Command::TakeOff => 1,
                Command::StartTracking => 2,
                _ => 3,
            };
            self.sent[i] = true;
            self.sent_at[i] = t_us;
        }
        cmd
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_paper_script_follows_the_reported_mode_and_retries() {
        let mut op = Operator::new(MissionScript::PAPER);
        let s = |t: f64| (t * 1e6) as u64;
        assert_eq!(op.tick(s(0.5), None), None);
        assert_eq!(op.tick(s(1.0), Some(FlightMode::Disarmed)), Some(Command::Arm));
        // Not acted on: sent again after a second, not before.
        assert_eq!(op.tick(s(1.5), Some(FlightMode::Disarmed)), None);
        assert_eq!(op.tick(s(2.0), Some(FlightMode::Disarmed)), Some(Command::Arm));
        assert_eq!(op.tick(s(2.1), Some(FlightMode::Armed)), Some(Command::TakeOff));
        assert_eq!(op.tick(s(3.0), Some(FlightMode::TakeOff)), None);
        // Hovering for the script's time, then the sweep.
        assert_eq!(op.tick(s(5.0), Some(FlightMode::Hover)), None);
        assert_eq!(op.tick(s(6.9), Some(FlightMode::Hover)), None);
        assert_eq!(op.tick(s(7.0), Some(FlightMode::Hover)), Some(Command::StartTracking));
        assert_eq!(op.tick(s(8.0), Some(FlightMode::Tracking)), None);
        // Back in hover after tracking: land; a vision hold in between changes nothing.
        assert_eq!(op.tick(s(20.0), Some(FlightMode::VisionHold)), None);
        assert_eq!(op.tick(s(30.0), Some(FlightMode::Hover)), Some(Command::Land));
        assert_eq!(op.tick(s(30.5), Some(FlightMode::Landing)), None);
        assert_eq!(op.tick(s(40.0), Some(FlightMode::Disarmed)), None, "no re-arm after the flight");
    }

    #[test]
    fn the_hover_script_lands_after_the_hover_and_retries_the_landing() {
        let mut op = Operator::new(MissionScript::HOVER);
        let s = |t: f64| (t * 1e6) as u64;
        assert_eq!(op.tick(s(1.0), Some(FlightMode::Disarmed)), Some(Command::Arm));
        assert_eq!(op.tick(s(2.0), Some(FlightMode::Armed)), Some(Command::TakeOff));
        assert_eq!(op.tick(s(5.0), Some(FlightMode::Hover)), None);
        assert_eq!(op.tick(s(7.0), Some(FlightMode::Hover)), Some(Command::Land));
        // Still hovering (the command was lost): not at once, again after a second.
        assert_eq!(op.tick(s(7.1), Some(FlightMode::Hover)), None);
        assert_eq!(op.tick(s(8.0), Some(FlightMode::Hover)), Some(Command::Land));
        assert_eq!(op.tick(s(9.0), Some(FlightMode::Landing)), None);
    }
}
