//! The operator's console: one terminal screen (`ratatui`) with what the station knows of the vehicle (mode,
//! failsafe, estimate, setpoint: all from the downlinked telemetry), of the radio and of the cameras, and the
//! keys that command the vehicle. The kill (`k` or the space bar) is always available and asks for no
//! confirmation. The terminal itself (raw mode, events) is the caller's; this module draws into a ratatui
//! frame and maps keys, so it is tested on ratatui's test backend.
use control_core::Command;
use protocol::Telemetry;
use ratatui::Frame;
use ratatui::layout::{Constraint, Layout};
use ratatui::style::{Color, Modifier, Style};
use ratatui::text::{Line, Span};
use ratatui::widgets::{Block, Borders, Paragraph};

/// What a key asks for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum KeyAction {
    /// Send this command (the operator takes over from the script).
    Command(Command),
    /// Motors off now.
    Kill,
    /// End the station (the vehicle lands on its own after losing the link).
    Quit,
}

/// The keys: `a` arm, `t` take off, `s` start the sweep, `h` stop it and hover, `l` land, `d` disarm, `k`
/// or space kill, `q` quit.
pub const KEYS: [(char, &str, KeyAction); 9] = [
    ('a', "arm", KeyAction::Command(Command::Arm)),
    ('t', "take off", KeyAction::Command(Command::TakeOff)),
    ('s', "sweep", KeyAction::Command(Command::StartTracking)),
    ('h', "hover", KeyAction::Command(Command::StopTracking)),
    ('l', "land", KeyAction::Command(Command::Land)),
    ('d', "disarm", KeyAction::Command(Command::Disarm)),
    ('k', "KILL", KeyAction::Kill),
    (' ', "KILL", KeyAction::Kill),
    ('q', "quit", KeyAction::Quit),
];

/// The action of a key, if it has one (letters in either case).
pub fn key_action(c: char) -> Option<KeyAction> {
    let c = c.to_ascii_lowercase();
    KEYS.iter().find(|(k, _, _)| *k == c).map(|(_, _, a)| *a)
}

/// What the console shows.
#[derive(Clone, Debug, Default)]
pub struct ConsoleView {
    /// Seconds since the station started.
    pub t_s: f64,
    /// The radio (`serial:...`, `tcp:...`).
    pub link: String,
    /// The last telemetry, and how long ago it came (s).
    pub telemetry: Option<(Telemetry, f64)>,
    /// The clock sync's bound (ms), once it knows the vehicle's clock.
    pub clock_bound_ms: Option<f64>,
    /// Bytes per second up and down, over the run.
    pub bytes_per_s: [f64; 2],
    /// Radio frames refused by the decoder (any reason).
    pub link_refused: u64,
    /// Forward frames received, and with the line found.
    pub forward_frames: [u64; 2],
    /// Flow measurements sent.
    pub flow_sent: u64,
    /// Whether each camera (forward, down) is stalled now, and its stalls so far.
    pub stalled: [(bool, u64); 2],
    /// Frames each camera lost at the source (a webcam's drops and undecodable buffers).
    pub camera_lost: [u64; 2],
    /// The script: running, or why not.
    pub script: String,
    /// The last command acknowledgements, newest last.
    pub acks: Vec<String>,
    /// A kill was sent.
    pub killed: bool,
}

fn v3(v: [f32; 3]) -> String {
    format!("{:+.2} {:+.2} {:+.2}", v[0], v[1], v[2])
}

/// Draws the whole screen.
pub fn draw(f: &mut Frame, v: &ConsoleView) {
    let [head, body, keys] =
        Layout::vertical([Constraint::Length(1), Constraint::Min(8), Constraint::Length(1)]).areas(f.area());
    let [left, right] =
        Layout::horizontal([Constraint::Percentage(55), Constraint::Percentage(45)]).areas(body);
    f.render_widget(
        Paragraph::new(format!("wall-line station  {:.1} s  radio {}", v.t_s, v.link))
            .style(Style::default().add_modifier(Modifier::BOLD)),
        head,
    );

    let mut vehicle: Vec<Line> = Vec::new();
    match &v.telemetry {
        None => {
            vehicle.push(Line::from(Span::styled("no telemetry yet", Style::default().fg(Color::Yellow))))
        }
        Some((tm, age)) => {
            let stale = *age > 0.5;
            let style = if stale { Style::default().fg(Color::Red) } else { Style::default() };
            vehicle.push(Line::from(vec![
                Span::styled(format!("mode {:?}", tm.mode), Style::default().add_modifier(Modifier::BOLD)),
                Span::styled(format!("  telemetry {:.1} s ago", age), style),
            ]));
            let fs = match tm.failsafe {
                Some(f) => Span::styled(format!("failsafe {f:?}"), Style::default().fg(Color::Red)),
                None => Span::raw("failsafe none"),
            };
            vehicle.push(Line::from(fs));
            let e = &tm.estimate;
            let att = e.attitude;
            vehicle.push(Line::from(format!("position   {} m", v3(e.position_m.to_array()))));
            vehicle.push(Line::from(format!("velocity   {} m/s", v3(e.velocity_m_s.to_array()))));
            vehicle.push(Line::from(format!(
                "attitude   roll {:+.1} pitch {:+.1} yaw {:+.1} deg",
                att.roll.to_degrees(),
                att.pitch.to_degrees(),
                att.yaw.to_degrees()
            )));
            vehicle.push(Line::from(format!("setpoint   {} m", v3(tm.setpoint.position_m.to_array()))));
            vehicle.push(Line::from(format!(
                "rotors     {:.0} {:.0} {:.0} {:.0} rad/s",
                tm.motors_rad_s[0], tm.motors_rad_s[1], tm.motors_rad_s[2], tm.motors_rad_s[3]
            )));
            vehicle.push(Line::from(format!("last fix   {:.2} s ago", tm.fix_age_s)));
        }
    }
    f.render_widget(
        Paragraph::new(vehicle).block(Block::default().borders(Borders::ALL).title("vehicle")),
        left,
    );

    let camera = |name: &str, k: usize| {
        let (now, count) = v.stalled[k];
        let text = format!("{name} stalls {count}, lost {}", v.camera_lost[k]);
        if now {
            Line::from(Span::styled(format!("{text}  STALLED"), Style::default().fg(Color::Red)))
        } else {
            Line::from(text)
        }
    };
    let mut station = vec![
        Line::from(format!("up {:.0} B/s  down {:.0} B/s", v.bytes_per_s[0], v.bytes_per_s[1])),
        Line::from(format!("refused frames {}", v.link_refused)),
        Line::from(match v.clock_bound_ms {
            Some(b) => format!("vehicle clock within {b:.2} ms"),
            None => "vehicle clock unknown: no measurements sent".to_string(),
        }),
        Line::from(format!("forward {} frames, line in {}", v.forward_frames[0], v.forward_frames[1])),
        Line::from(format!("flow {} sent", v.flow_sent)),
        camera("forward", 0),
        camera("down", 1),
        Line::from(format!("script {}", v.script)),
    ];
    if v.killed {
        station.push(Line::from(Span::styled(
            "KILL SENT",
            Style::default().fg(Color::Red).add_modifier(Modifier::BOLD),
        )));
    }
    for a in v.acks.iter().rev().take(3) {
        station.push(Line::from(a.as_str()));
    }
    f.render_widget(
        Paragraph::new(station).block(Block::default().borders(Borders::ALL).title("station")),
        right,
    );

    let mut spans = Vec::new();
    for (k, name, action) in KEYS.iter().filter(|(k, _, _)| *k != ' ') {
        let style = if *action == KeyAction::Kill {
            Style::default().fg(Color::Red).add_modifier(Modifier::BOLD)
        } else {
            Style::default()
        };
        spans.push(Span::styled(format!("{k} {name}"), style));
        spans.push(Span::raw(if *action == KeyAction::Kill { " (or space)  " } else { "  " }));
    }
    f.render_widget(Paragraph::new(Line::from(spans)), keys);
}

#[cfg(test)]
mod tests {
    use super::*;
    use ratatui::Terminal;
    use ratatui::backend::TestBackend;

    fn screen(v: &ConsoleView) -> String {
        let mut t = Terminal::new(TestBackend::new(100, 16)).unwrap();
        t.draw(|f| draw(f, v)).unwrap();
        let buf = t.backend().buffer().clone();
        let mut out = String::new();
        for y in 0..buf.area.height {
            for x in 0..buf.area.width {
                out.push_str(buf[(x, y)].symbol());
            }
            out.push('\n');
        }
        out
    }

    #[test]
    fn keys_map_to_commands_and_the_kill_is_on_two_keys() {
        assert_eq!(key_action('a'), Some(KeyAction::Command(Command::Arm)));
        assert_eq!(key_action('L'), Some(KeyAction::Command(Command::Land)));
        assert_eq!(key_action('k'), Some(KeyAction::Kill));
        assert_eq!(key_action(' '), Some(KeyAction::Kill));
        assert_eq!(key_action('q'), Some(KeyAction::Quit));
        assert_eq!(key_action('x'), None);
        // Every command the vehicle takes has a key.
        for c in [
            Command::Arm,
            Command::TakeOff,
            Command::StartTracking,
            Command::StopTracking,
            Command::Land,
            Command::Disarm,
        ] {
            assert!(KEYS.iter().any(|(_, _, a)| *a == KeyAction::Command(c)), "{c:?}");
        }
    }

    #[test]
    fn the_screen_shows_the_vehicle_the_radio_the_cameras_and_the_keys() {
        let mut v = ConsoleView { t_s: 12.3, link: "tcp:127.0.0.1:5760".into(), ..Default::default() };
        let s = screen(&v);
        assert!(s.contains("no telemetry yet") && s.contains("vehicle clock unknown"), "{s}");
        assert!(s.contains("k KILL (or space)") && s.contains("a arm") && s.contains("q quit"), "{s}");
        let mut tm = Telemetry {
            time_us: 1,
            mode: control_core::FlightMode::Hover,
            failsafe: None,
            estimate: Default::default(),
            setpoint: Default::default(),
            motors_rad_s: [401.0, 402.0, 403.0, 404.0],
            fix_age_s: 0.03,
            step_cost: 0,
        };
        tm.estimate.position_m = geometry::Vec3::new(1.25, 1.3, 0.8);
        v.telemetry = Some((tm, 0.1));
        v.clock_bound_ms = Some(0.64);
        v.stalled = [(true, 2), (false, 0)];
        v.killed = true;
        v.acks = vec!["12.0 s: Refused(Arm, NotLevel)".into()];
        let s = screen(&v);
        for want in [
            "mode Hover",
            "position   +1.25 +1.30 +0.80 m",
            "rotors     401 402 403 404 rad/s",
            "within 0.64 ms",
            "forward stalls 2, lost 0  STALLED",
            "KILL SENT",
            "Refused(Arm, NotLevel)",
        ] {
            assert!(s.contains(want), "{want} missing from\n{s}");
        }
        // Stale telemetry is flagged, a failsafe named.
        tm.failsafe = Some(control_core::Failsafe::LinkLost);
        v.telemetry = Some((tm, 2.0));
        let s = screen(&v);
        assert!(s.contains("failsafe LinkLost") && s.contains("telemetry 2.0 s ago"), "{s}");
    }
}
