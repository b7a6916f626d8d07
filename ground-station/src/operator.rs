//! The operator's commands: a script of the mission (the paper's: arm, take off, track, land), run against
//! the vehicle's mode as its telemetry reports it, with the retries a ground station makes for a command the
//! vehicle has not acted on (the radio may have lost it); or a file of timed commands; and the operator's
//! own commands (the console's keys), of which the kill is always available: motors off now
//! (`Command::Disarm`, which the vehicle carries out in any mode), sent [`KILL_REPEATS`] times in case the
//! radio loses one, and the end of any script.
use control_core::{Command, FlightMode};

/// A command not acted on within this time is sent again (us).
pub const COMMAND_RETRY_US: u64 = 1_000_000;
/// How many times a kill is sent.
pub const KILL_REPEATS: u8 = 3;
/// Between two sends of a kill (us).
pub const KILL_SPACING_US: u64 = 50_000;

/// A timed command of a script file.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TimedCommand {
    /// Seconds after the station's start.
    pub at_s: f64,
    /// What to send; `None` is the kill.
    pub command: Option<Command>,
}

/// What the operator runs.
#[derive(Clone, Debug, PartialEq)]
pub enum Script {
    /// A mission that follows the vehicle's reported mode.
    Mission(MissionScript),
    /// Commands at fixed times (a script file), each sent once.
    Timed(Vec<TimedCommand>),
    /// Nothing: the operator's own commands only.
    Manual,
}

/// A command's name in a script file and on the console.
pub fn command_name(c: Option<Command>) -> &'static str {
    match c {
        None => "kill",
        Some(Command::Arm) => "arm",
        Some(Command::TakeOff) => "takeoff",
        Some(Command::StartTracking) => "track",
        Some(Command::StopTracking) => "stop",
        Some(Command::Land) => "land",
        Some(Command::Disarm) => "disarm",
    }
}

/// Reads a script file's text (`name` for the messages): one command per line, `SECONDS COMMAND`, the
/// commands `arm`, `takeoff`, `track` (start the sweep), `stop` (stop it and hover), `land`, `disarm` and
/// `kill`; `#` starts a comment. Times must not decrease.
pub fn parse_script(name: &str, text: &str) -> Result<Vec<TimedCommand>, String> {
    let mut out: Vec<TimedCommand> = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let line = line.split('#').next().unwrap_or("").trim();
        if line.is_empty() {
            continue;
        }
        let at = |what: String| format!("{name}:{}: {what}", i + 1);
        let mut words = line.split_whitespace();
        let (Some(t), Some(c), None) = (words.next(), words.next(), words.next()) else {
            return Err(at(format!("`{line}`: SECONDS COMMAND expected")));
        };
        let at_s: f64 = t.parse().map_err(|_| at(format!("the time `{t}` is not a number")))?;
        if !at_s.is_finite() || at_s < 0.0 {
            return Err(at(format!("the time `{t}` must be a finite number of seconds, not negative")));
        }
        if let Some(prev) = out.last()
            && at_s < prev.at_s
        {
            return Err(at(format!("{at_s} s comes before the line above's {} s", prev.at_s)));
        }
        let all = [
            None,
            Some(Command::Arm),
            Some(Command::TakeOff),
            Some(Command::StartTracking),
            Some(Command::StopTracking),
            Some(Command::Land),
            Some(Command::Disarm),
        ];
        let command = *all.iter().find(|k| command_name(**k) == c).ok_or_else(|| {
            let names: Vec<&str> = all.iter().map(|k| command_name(*k)).collect();
            at(format!("`{c}` is not a command ({})", names.join(", ")))
        })?;
        out.push(TimedCommand { at_s, command });
    }
    Ok(out)
}

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

/// The script's state: which commands were sent, when, and what the vehicle has been seen doing; the
/// operator's own commands waiting to go.
#[derive(Clone, Debug)]
pub struct Operator {
    script: MissionScript,
    timed: Option<Vec<TimedCommand>>,
    timed_next: usize,
    /// The script has ended (a kill, or the operator took over with a command of their own).
    script_stopped: bool,
    /// The operator's own commands, sent one a tick in their order.
    manual: std::collections::VecDeque<Command>,
    kill_left: u8,
    kill_sent_at: Option<u64>,
    sent: [bool; 4],
    sent_at: [u64; 4],
    hover_since: Option<u64>,
    tracked: bool,
    was_airborne: bool,
}

impl Operator {
    /// An operator that will run the mission `script`.
    pub fn new(script: MissionScript) -> Self {
        Self {
            script,
            timed: None,
            timed_next: 0,
            script_stopped: false,
            manual: std::collections::VecDeque::new(),
            kill_left: 0,
            kill_sent_at: None,
            sent: [false; 4],
            sent_at: [0; 4],
            hover_since: None,
            tracked: false,
            was_airborne: false,
        }
    }

    /// An operator that will run `script`.
    pub fn with_script(script: Script) -> Self {
        match script {
            Script::Mission(m) => Self::new(m),
            Script::Timed(t) => Self { timed: Some(t), ..Self::new(MissionScript::PAPER) },
            Script::Manual => Self { script_stopped: true, ..Self::new(MissionScript::PAPER) },
        }
    }

    /// Motors off now: the kill is sent [`KILL_REPEATS`] times from the next tick on, before anything else,
    /// and the script ends.
    pub fn kill(&mut self) {
        self.kill_left = KILL_REPEATS;
        self.kill_sent_at = None;
        self.script_stopped = true;
        self.manual.clear();
    }

    /// The operator's own command, sent at the next tick (after the ones given before it, one a tick); the
    /// script ends (the operator has taken over).
    pub fn command(&mut self, c: Command) {
        self.manual.push_back(c);
        self.script_stopped = true;
    }

    /// Whether the script still runs.
    pub fn script_running(&self) -> bool {
        !self.script_stopped
    }

    /// The mission script.
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
        if self.kill_left > 0 {
            if self.kill_sent_at.is_some_and(|at| t_us.saturating_sub(at) < KILL_SPACING_US) {
                return None;
            }
            self.kill_left -= 1;
            self.kill_sent_at = Some(t_us);
            return Some(Command::Disarm);
        }
        if let Some(c) = self.manual.pop_front() {
            return Some(c);
        }
        if self.script_stopped {
            return None;
        }
        if let Some(timed) = &self.timed {
            let next = timed.get(self.timed_next).copied()?;
            if t < next.at_s {
                return None;
            }
            self.timed_next += 1;
            return match next.command {
                Some(c) => Some(c),
                None => {
                    self.kill();
                    self.tick(t_us, mode)
                }
            };
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
    fn a_kill_goes_first_three_times_and_ends_the_script() {
        let mut op = Operator::new(MissionScript::PAPER);
        let s = |t: f64| (t * 1e6) as u64;
        assert_eq!(op.tick(s(1.0), Some(FlightMode::Disarmed)), Some(Command::Arm));
        op.command(Command::TakeOff);
        op.kill();
        assert!(!op.script_running());
        // The kill before the queued command (dropped), three times 50 ms apart, then nothing: the script
        // does not arm again.
        assert_eq!(op.tick(s(2.0), Some(FlightMode::Hover)), Some(Command::Disarm));
        assert_eq!(op.tick(s(2.01), Some(FlightMode::Hover)), None);
        assert_eq!(op.tick(s(2.06), Some(FlightMode::Hover)), Some(Command::Disarm));
        assert_eq!(op.tick(s(2.12), Some(FlightMode::Disarmed)), Some(Command::Disarm));
        for t in [2.2, 5.0, 10.0] {
            assert_eq!(op.tick(s(t), Some(FlightMode::Disarmed)), None);
        }
        // The operator's own commands still go, once each.
        op.command(Command::Arm);
        assert_eq!(op.tick(s(11.0), Some(FlightMode::Disarmed)), Some(Command::Arm));
        assert_eq!(op.tick(s(13.0), Some(FlightMode::Disarmed)), None);
    }

    #[test]
    fn commands_given_together_all_go_one_a_tick_in_their_order() {
        let mut op = Operator::with_script(Script::Manual);
        op.command(Command::Arm);
        op.command(Command::TakeOff);
        assert_eq!(op.tick(1, Some(FlightMode::Disarmed)), Some(Command::Arm));
        assert_eq!(op.tick(2, Some(FlightMode::Armed)), Some(Command::TakeOff));
        assert_eq!(op.tick(3, Some(FlightMode::TakeOff)), None);
    }

    #[test]
    fn a_script_file_sends_each_command_at_its_time() {
        let text = "# a short test\n0.5 arm\n2 takeoff   # climb\n\n6.0 land\n9 kill\n";
        let timed = parse_script("s.txt", text).unwrap();
        assert_eq!(timed.len(), 4);
        assert_eq!(timed[3], TimedCommand { at_s: 9.0, command: None });
        let mut op = Operator::with_script(Script::Timed(timed));
        let s = |t: f64| (t * 1e6) as u64;
        assert_eq!(op.tick(s(0.4), None), None);
        assert_eq!(op.tick(s(0.5), None), Some(Command::Arm));
        assert_eq!(op.tick(s(1.9), Some(FlightMode::Armed)), None);
        assert_eq!(op.tick(s(2.5), Some(FlightMode::Armed)), Some(Command::TakeOff));
        assert_eq!(op.tick(s(6.0), Some(FlightMode::Hover)), Some(Command::Land));
        assert_eq!(op.tick(s(8.0), Some(FlightMode::Landing)), None);
        let kills: Vec<_> = (0..40).filter_map(|k| op.tick(s(9.0 + k as f64 * 0.01), None)).collect();
        assert_eq!(kills, vec![Command::Disarm; KILL_REPEATS as usize]);
        // A manual script sends nothing by itself.
        let mut manual = Operator::with_script(Script::Manual);
        assert_eq!(manual.tick(s(100.0), Some(FlightMode::Disarmed)), None);
    }

    #[test]
    fn script_files_with_mistakes_are_refused_naming_the_line() {
        for (text, want) in [
            (
                "1 arm\n2 fly\n",
                "s.txt:2: `fly` is not a command (kill, arm, takeoff, track, stop, land, disarm)",
            ),
            ("x arm\n", "s.txt:1: the time `x` is not a number"),
            ("1 arm now\n", "s.txt:1: `1 arm now`: SECONDS COMMAND expected"),
            ("-1 arm\n", "s.txt:1: the time `-1` must be"),
            ("nan arm\n", "s.txt:1: the time `nan` must be"),
            ("3 arm\n2 land\n", "s.txt:2: 2 s comes before the line above's 3 s"),
        ] {
            let e = parse_script("s.txt", text).unwrap_err();
            assert!(e.starts_with(want), "{e}");
        }
        assert_eq!(parse_script("s.txt", "# nothing\n\n").unwrap(), vec![]);
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
