//! `sim-host station`: the ground station for a real or a virtual vehicle.
use anyhow::{Context, Result};
use clap::Args;
use ground_station::console::{ConsoleView, KeyAction};
use sim_host::Scenario;
use sim_host::station::StationUi;
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Args, Debug)]
pub(crate) struct StationArgs {
    /// The radio: `serial:DEVICE:BAUD` (a SiK-type radio at 57600, the board's USART at 115200, 8N1) or
    /// `tcp:HOST:PORT` (the virtual vehicle's `--serve-link`).
    #[arg(long, value_name = "serial:DEV:BAUD|tcp:HOST:PORT")]
    pub(crate) link: String,
    /// The forward camera: `/dev/videoN`, a V4L2 webcam (built with `--features v4l2`; set to the
    /// calibration's size and the camera's rate, MJPEG or YUYV), `tcp:HOST:PORT`, a frame stream (the
    /// virtual vehicle's `--serve-forward`, or a camera served the same way; docs/ground-station.md), or
    /// `folder:PATH` a recording in the ASL/EuRoC layout (`PATH/data.csv`, `PATH/data/*.png`) played at its
    /// pace (`folder:PATH@fast`: at once).
    #[arg(long, value_name = "/dev/videoN|tcp:HOST:PORT|folder:PATH")]
    pub(crate) forward: String,
    /// The downward camera, when the vehicle has one (without it the vehicle flies without flow); as
    /// `--forward`.
    #[arg(long, value_name = "/dev/videoN|tcp:HOST:PORT|folder:PATH")]
    pub(crate) down: Option<String>,
    /// The forward camera's calibration: OpenCV/ROS camera_info YAML or Kalibr/EuRoC sensor.yaml (default:
    /// the scenario's camera).
    #[arg(long, value_name = "FILE")]
    pub(crate) calib_forward: Option<PathBuf>,
    /// The scenario that gives the line's geometry, the camera mounts and the link's rates.
    #[arg(long, default_value = "paper")]
    pub(crate) scenario: String,
    /// The operator's script: `paper` (arm at 1 s, take off at 2 s, sweep after 2 s of hover, land when
    /// done), `hover` (the same without the sweep: land after the hover), `manual` (nothing: the console's
    /// keys only), or a FILE of timed commands, a line each: `SECONDS COMMAND` with the commands arm,
    /// takeoff, track, stop, land, disarm and kill (`#` comments). A command of the operator's own, or a
    /// kill, ends the script.
    #[arg(long, default_value = "paper", value_name = "paper|hover|manual|FILE")]
    pub(crate) script: String,
    /// The operator's console in the terminal instead of a progress line: the vehicle's mode, failsafe,
    /// estimate and setpoint (from its telemetry), the radio, the clock sync and the cameras, and keys: a
    /// arm, t take off, s sweep, h hover, l land, d disarm, k or space KILL (motors off at once, in any
    /// mode, no confirmation), q quit.
    #[arg(long)]
    pub(crate) console: bool,
    /// The compact mode, for a 57600-baud radio (SiK-type): the line measured at 10 Hz, the flow at 20 Hz,
    /// time sync at 2 Hz, and the vehicle asked for telemetry at 10 Hz (the parameter
    /// downlink.telemetry_every_steps, set over the link at the start). About 2.5 kB/s each way.
    #[arg(long)]
    pub(crate) compact: bool,
    /// The longest run (s).
    #[arg(long, default_value_t = 300.0)]
    pub(crate) duration: f64,
    /// How long to wait for the vehicle's first telemetry (s).
    #[arg(long, default_value_t = 10.0)]
    pub(crate) answer_timeout: f64,
    /// Camera frames in the station's flight log: `none` (the default: the measurements only), `png` or
    /// `raw` (the frames the station measured, at their capture time on the vehicle's clock).
    #[arg(long, value_enum, default_value = "none")]
    pub(crate) frames: super::fly::FramesArg,
    /// Output directory: station.json (what was sent and received, the clock sync, the latency) and
    /// station.log (the flight log of the run: every message sent and received with the station's time, the
    /// clock sync; `sim-host export` reads it), written also when the run ends on an error.
    #[arg(long)]
    pub(crate) out: PathBuf,
    /// The radio's key (`sim-host keygen --out FILE`, mode 0600), the vehicle's too: every frame each way
    /// is authenticated and replay-protected (docs/security.md).
    #[arg(long, value_name = "FILE", conflicts_with = "no_key")]
    pub(crate) key: Option<PathBuf>,
    /// An unauthenticated radio, for development only: anyone on it may command the vehicle.
    #[arg(long)]
    pub(crate) no_key: bool,
    /// Serve a MAVLink 2 ground control station (QGroundControl, MAVProxy, pymavlink) at `udp:HOST:PORT`
    /// (QGroundControl listens on udp:127.0.0.1:14550): the vehicle's heartbeat, attitude and local
    /// position in NED, its status texts; the station's commands (arm, take-off, land, the custom modes)
    /// and its parameters. A loopback HOST binds the loopback interface only (docs/mavlink.md).
    #[arg(long, value_name = "udp:HOST:PORT")]
    pub(crate) mavlink: Option<String>,
    /// Publish the station live for Foxglove or Lichtblick over the Foxglove WebSocket protocol on HOST:PORT
    /// (default 127.0.0.1:8765; port 0: any free one, printed on stdout): the station's records (what it
    /// sent and received, the telemetry), both cameras' frames with what its vision found, the vehicle's
    /// estimate in 3D, at the station's clock (docs/live-view.md). Needs a build with `--features live`.
    #[arg(long, value_name = "HOST:PORT", num_args = 0..=1, default_missing_value = "127.0.0.1:8765")]
    pub(crate) live: Option<String>,
}

/// The scenario's forward camera replaced by a calibration file's (camera_info YAML or Kalibr sensor.yaml).
pub(crate) fn apply_calibration(scenario: &mut Scenario, path: &std::path::Path) -> Result<()> {
    let cal = ground_station::calib::load(path).map_err(anyhow::Error::msg)?;
    let c = &mut scenario.forward_camera;
    let [fx, fy, cx, cy] = cal.intrinsics_px;
    (c.width_px, c.height_px, c.fx_px, c.fy_px, c.cx_px, c.cy_px) =
        (cal.camera.width, cal.camera.height, fx, fy, cx, cy);
    c.distortion = cal.distortion;
    (c.response, c.line_delay_s) = (cal.tone_curve, cal.line_delay_s);
    scenario.validate().with_context(|| format!("the camera of {}", path.display()))
}

pub(crate) fn station(a: &StationArgs) -> Result<ExitCode> {
    use ground_station::operator::{MissionScript, Script, parse_script};
    let mut scenario = Scenario::load(&a.scenario)?;
    let out_file = a.out.join("station.json");
    let log_file = a.out.join("station.log");
    let mut inputs = vec![std::path::Path::new(&a.scenario)];
    inputs.extend(a.calib_forward.as_deref());
    inputs.push(std::path::Path::new(&a.script));
    sim_host::files::refuse_overwrites(&[out_file.as_path(), log_file.as_path()], &inputs)?;
    if let Some(path) = &a.calib_forward {
        apply_calibration(&mut scenario, path)?;
    }
    let script = match a.script.as_str() {
        "paper" => Script::Mission(MissionScript::PAPER),
        "hover" => Script::Mission(MissionScript::HOVER),
        "manual" => Script::Manual,
        file => {
            let text = std::fs::read_to_string(file)
                .with_context(|| format!("--script `{file}`: paper, hover, manual or a script file"))?;
            Script::Timed(parse_script(file, &text).map_err(|e| anyhow::anyhow!("--script {e}"))?)
        }
    };
    let key = match (&a.key, a.no_key) {
        (Some(f), _) => Some(sim_host::link_key::read_key(f).context("--key")?),
        (None, true) => {
            eprintln!("the radio is unauthenticated (--no-key): anyone on it may command the vehicle");
            None
        }
        (None, false) => anyhow::bail!(
            "give --key FILE (`sim-host keygen --out FILE`, the vehicle's key) or, for development only, --no-key"
        ),
    };
    let link = ground_station::link::LinkSpec::parse(&a.link).map_err(|e| anyhow::anyhow!("--link {e}"))?;
    std::fs::create_dir_all(&a.out).with_context(|| format!("cannot create {}", a.out.display()))?;
    let opts = sim_host::station::StationOptions {
        link,
        forward: a.forward.clone(),
        down: a.down.clone(),
        scenario,
        script,
        duration_s: a.duration,
        answer_timeout_s: a.answer_timeout,
        log: log_file.clone(),
        frames: a.frames.policy(),
        compact: a.compact,
        key,
        mavlink: a.mavlink.clone(),
        live: a.live.clone(),
    };
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    // Ctrl-C ends the run with station.json written (the motors are the vehicle's: a real operator lands or
    // kills first).
    let flag = stop.clone();
    ctrlc::set_handler(move || flag.store(true, std::sync::atomic::Ordering::Relaxed))
        .context("installing the Ctrl-C handler")?;
    let st = if a.console {
        let mut ui = ConsoleUi::start()?;
        let result = sim_host::station::run_station(&opts, stop, &mut ui);
        drop(ui);
        result?
    } else {
        let mut ui = ProgressUi {
            bar: super::common::progress_bar(1000, "{spinner} station [{bar:40}] {msg} ({elapsed})"),
            duration_s: a.duration,
        };
        let result = sim_host::station::run_station(&opts, stop, &mut ui);
        ui.bar.finish_and_clear();
        result?
    };
    sim_host::files::write_atomic(&out_file, (serde_json::to_string_pretty(&st)? + "\n").as_bytes())?;
    eprintln!(
        "{}: {:.1} s; forward frames {} ({} with the line), flow {} sent; clock bound {}; frame to radio median {:.2} ms, p95 {:.2} ms",
        st.ended,
        st.seconds,
        st.forward_frames,
        st.forward_measured,
        st.flow_sent,
        st.clock_bound_ms.map_or("none".to_string(), |b| format!("{b:.3} ms")),
        st.frame_to_uplink_ms[0],
        st.frame_to_uplink_ms[1]
    );
    eprintln!("wrote:\n  {}\n  {} ({} records)", out_file.display(), log_file.display(), st.log_records);
    Ok(ExitCode::SUCCESS)
}

/// The progress line: time, the vehicle's mode, stalled cameras.
struct ProgressUi {
    bar: indicatif::ProgressBar,
    duration_s: f64,
}

impl StationUi for ProgressUi {
    fn show(&mut self, v: &ConsoleView) {
        self.bar.set_position((v.t_s / self.duration_s * 1000.0).min(1000.0) as u64);
        let mut msg = match &v.telemetry {
            Some((tm, _)) => format!("{:.1} s, vehicle {:?}", v.t_s, tm.mode),
            None => format!("{:.1} s, no telemetry yet", v.t_s),
        };
        for ((stalled, _), name) in v.stalled.iter().zip(["forward", "down"]) {
            if *stalled {
                msg += &format!(", the {name} camera stalled");
            }
        }
        self.bar.set_message(msg);
    }
}

/// The operator's console (ratatui on crossterm): the terminal in raw mode on the alternate screen, given
/// back as it was when the console ends (also on a panic: ratatui's hook).
struct ConsoleUi {
    terminal: ratatui::DefaultTerminal,
    /// Draws that failed (a terminal gone): counted, said at the end.
    draw_errors: u64,
}

impl ConsoleUi {
    fn start() -> Result<Self> {
        let terminal = ratatui::try_init().context("--console: the terminal")?;
        Ok(Self { terminal, draw_errors: 0 })
    }
}

impl Drop for ConsoleUi {
    fn drop(&mut self) {
        ratatui::restore();
        if self.draw_errors > 0 {
            eprintln!("the console failed to draw {} times", self.draw_errors);
        }
    }
}

impl StationUi for ConsoleUi {
    fn show(&mut self, v: &ConsoleView) {
        if self.terminal.draw(|f| ground_station::console::draw(f, v)).is_err() {
            self.draw_errors += 1;
        }
    }

    fn actions(&mut self) -> Vec<KeyAction> {
        use ratatui::crossterm::event::{self, Event, KeyCode, KeyEventKind, KeyModifiers};
        let mut out = Vec::new();
        while event::poll(std::time::Duration::ZERO).unwrap_or(false) {
            let k = match event::read() {
                Ok(Event::Key(k)) => k,
                Ok(_) => continue,
                // The terminal went away: no more keys (Ctrl-C still ends the station).
                Err(_) => break,
            };
            if k.kind != KeyEventKind::Press {
                continue;
            }
            match k.code {
                // Raw mode: Ctrl-C is a key, not a signal.
                KeyCode::Char('c') if k.modifiers.contains(KeyModifiers::CONTROL) => {
                    out.push(KeyAction::Quit)
                }
                KeyCode::Char(c) => out.extend(ground_station::console::key_action(c)),
                _ => {}
            }
        }
        out
    }
}
