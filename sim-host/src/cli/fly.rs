//! `sim-host fly`: a scenario flown in simulation.
use super::common::{progress_bar, rtf_text};
use anyhow::{Context, Result, bail};
use clap::{Args, ValueEnum};
use sim_host::Scenario;
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Clone, Copy, Debug, ValueEnum)]
pub(crate) enum FramesArg {
    /// Lossless PNG.
    Png,
    /// Raw 8-bit pixels.
    Raw,
    /// No frames, only the vision results.
    None,
}

impl FramesArg {
    pub(crate) fn policy(self) -> sim_host::flightlog::FramePolicy {
        match self {
            FramesArg::Png => sim_host::flightlog::FramePolicy::Png,
            FramesArg::Raw => sim_host::flightlog::FramePolicy::Raw,
            FramesArg::None => sim_host::flightlog::FramePolicy::Drop,
        }
    }
}

#[derive(Clone, Copy, Debug, ValueEnum)]
pub(crate) enum CameraSim {
    /// Rendered images through the full vision pipeline.
    Rendered,
    /// The line's edges projected analytically with edge noise (fast).
    Analytic,
}

impl CameraSim {
    pub(crate) fn mode(self) -> sim_host::sil::CameraMode {
        match self {
            CameraSim::Rendered => sim_host::sil::CameraMode::Rendered,
            CameraSim::Analytic => sim_host::sil::CameraMode::Analytic,
        }
    }
}

#[derive(Args, Debug)]
pub(crate) struct FlyArgs {
    /// Scenario: a built-in name (`paper`, `webcam`) or a TOML file.
    #[arg(long, default_value = "paper")]
    pub(crate) scenario: String,
    /// Seed of every noise stream (a run is a pure function of scenario, seed and camera mode). With `--vary`,
    /// the sweep's seed.
    #[arg(long, default_value_t = 1)]
    pub(crate) seed: u64,
    /// Fly one run of a sweep alone: the distributions the sweep drew from (docs/robustness.md), with `--run`.
    #[arg(long, value_name = "VARY.toml", requires = "run")]
    pub(crate) vary: Option<PathBuf>,
    /// The sweep's run index K (0-based, as in runs.csv): the scenario is the base drawn for run K and the
    /// seed is the one run K of `sim-host sweep --seed SEED` flew with.
    #[arg(long, value_name = "K", requires = "vary")]
    pub(crate) run: Option<u32>,
    /// Longest simulated time in seconds (default: the scenario's limit; the run ends when it has landed).
    #[arg(long)]
    pub(crate) duration: Option<f64>,
    /// How the forward camera is simulated.
    #[arg(long, value_enum, default_value = "rendered")]
    pub(crate) camera: CameraSim,
    /// Output directory (summary.json, trajectory.csv, x/y/z/vx/vy.png).
    #[arg(long)]
    pub(crate) out: PathBuf,
    /// Skip the PNG plots.
    #[arg(long)]
    pub(crate) no_plots: bool,
    /// Do not write the flight log (`flight.log`, for `sim-host replay` and `sim-host export`).
    #[arg(long)]
    pub(crate) no_log: bool,
    /// Camera frames in the flight log: `none` (the default: only the vision results, 0.2 MB per simulated
    /// second, replayable from them), `png` (lossless, about 17 MB/s and several times slower: for `replay
    /// --from-frames` and the images in `export`), or `raw` pixels. Only rendered cameras have frames.
    #[arg(long, value_enum, default_value = "none")]
    pub(crate) frames: FramesArg,
    /// The flight computer: `sil` (the flight code in this process) or `qemu:PATH` (the firmware ELF built with
    /// `--features fil`, run in qemu-system-arm's netduinoplus2 model, in lockstep over its UART).
    #[arg(long, default_value = "sil", value_name = "sil|qemu:ELF")]
    pub(crate) fc: String,
    /// Be a virtual vehicle for a separate ground station (`sim-host station`): fly in real time and expose
    /// only the radio, a byte stream on this TCP port (port 0: any free one, printed on stdout). `tcp:PORT`
    /// listens on 127.0.0.1 only; another interface has to be asked for (`tcp:0.0.0.0:PORT`).
    #[arg(long, value_name = "tcp:[HOST:]PORT", requires = "serve_forward")]
    pub(crate) serve_link: Option<String>,
    /// The virtual vehicle's forward camera: its frame stream on this port (docs/ground-station.md).
    #[arg(long, value_name = "tcp:[HOST:]PORT", requires = "serve_link")]
    pub(crate) serve_forward: Option<String>,
    /// The virtual vehicle's downward camera (when the scenario's vehicle has one).
    #[arg(long, value_name = "tcp:[HOST:]PORT", requires = "serve_link")]
    pub(crate) serve_down: Option<String>,
    /// With --serve-link: how long to wait for the station to connect to the radio (s).
    #[arg(long, default_value_t = 60.0)]
    pub(crate) connect_timeout: f64,
    /// With --serve-link: the radio's key (`sim-host keygen --out FILE`, mode 0600): only a station with the
    /// same key may command the vehicle (docs/security.md).
    #[arg(long, value_name = "FILE", requires = "serve_link", conflicts_with = "no_key")]
    pub(crate) key: Option<PathBuf>,
    /// With --serve-link: an unauthenticated radio, for development only: anyone on the radio may command
    /// the vehicle.
    #[arg(long, requires = "serve_link")]
    pub(crate) no_key: bool,
    /// Fly in real time for a MAVLink 2 ground control station at `udp:HOST:PORT` (QGroundControl listens on
    /// udp:127.0.0.1:14550), which commands the vehicle through the in-process station in place of the
    /// mission's script: arm, take-off, land, the custom modes, the kill, the parameters (docs/mavlink.md).
    /// The run ends when the vehicle has landed and disarmed after flying, at --duration, or on Ctrl-C.
    #[arg(long, value_name = "udp:HOST:PORT", conflicts_with = "serve_link")]
    pub(crate) mavlink: Option<String>,
    /// Publish the flight live for Foxglove or Lichtblick over the Foxglove WebSocket protocol on HOST:PORT
    /// (default 127.0.0.1:8765; port 0: any free one; the address is printed on stdout): the MCAP export's
    /// topics, both cameras' images with what the vision found in them, the vehicle, the wall and the line in
    /// 3D (docs/live-view.md). The flight starts when the first viewer connects (see --live-wait); add
    /// --real-time to watch it at the vehicle's pace. Needs a build with `--features live`.
    #[arg(long, value_name = "HOST:PORT", num_args = 0..=1, default_missing_value = "127.0.0.1:8765",
          conflicts_with = "serve_link")]
    pub(crate) live: Option<String>,
    /// With --live: seconds to wait for the first viewer before flying anyway (0: do not wait).
    #[arg(long, default_value_t = 60.0, value_name = "S", requires = "live")]
    pub(crate) live_wait: f64,
    /// Pace the flight to the wall clock (to watch it live); Ctrl-C ends it with its outputs written.
    #[arg(long, conflicts_with_all = ["serve_link", "mavlink"])]
    pub(crate) real_time: bool,
}
pub(crate) fn fly(a: &FlyArgs) -> Result<ExitCode> {
    use sim_host::fly::{FlyOptions, fly};
    // Nothing a flight writes may replace what it reads (the scenario, the sweep's draws, the firmware).
    let fc_elf = a.fc.strip_prefix("qemu:").map(std::path::Path::new);
    let mut inputs = vec![std::path::Path::new(&a.scenario)];
    inputs.extend(a.vary.as_deref());
    inputs.extend(fc_elf);
    let outputs = sim_host::fly::output_files(&a.out);
    sim_host::files::refuse_overwrites(&outputs.iter().map(|p| p.as_path()).collect::<Vec<_>>(), &inputs)?;
    let mut scenario = Scenario::load(&a.scenario)?;
    let mut seed = a.seed;
    if let (Some(vary), Some(k)) = (&a.vary, a.run) {
        let drawn = sim_host::sweep::vary::Vary::load(vary)?;
        let draw = sim_host::sweep::run_scenario(&scenario, &drawn, a.seed, k)?;
        seed = sim_host::sweep::run_seed(a.seed, k);
        eprintln!("run {k} of sweep seed {}: seed {seed}", a.seed);
        for (name, value) in &draw.values {
            eprintln!("  {name} = {value}");
        }
        scenario = draw.scenario;
        // The drawn scenario beside the outputs, to fly again or edit.
        std::fs::create_dir_all(&a.out)?;
        let path = a.out.join("scenario.toml");
        let text = format!(
            "# Run {k} of `sim-host sweep --scenario {} --vary {} --seed {}` (fly it with --seed {seed}).\n{}",
            a.scenario,
            vary.display(),
            a.seed,
            toml::to_string(&scenario)?
        );
        sim_host::files::write_atomic(&path, text.as_bytes())?;
        eprintln!("  the drawn scenario: {}", path.display());
    }
    if let Some(d) = a.duration {
        // The limit of the scenario's `mission.max_duration_s`, which the option overrides.
        sim_host::scenario::limits::MISSION_MAX_DURATION
            .check_as("--duration", &[d])
            .context("--duration overrides mission.max_duration_s")?;
    }
    let camera = a.camera.mode();
    let fc = match sim_host::fil::parse_fc(&a.fc)? {
        None => sim_host::sil::FcChoice::Sil,
        Some(elf) => sim_host::sil::FcChoice::Qemu(sim_host::fil::QemuOptions::new(elf)),
    };
    let mavlink = match &a.mavlink {
        None => None,
        Some(spec) => {
            let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
            let flag = stop.clone();
            ctrlc::set_handler(move || flag.store(true, std::sync::atomic::Ordering::Relaxed))
                .context("installing the Ctrl-C handler")?;
            Some(sim_host::fly::MavlinkFly { spec: spec.clone(), stop })
        }
    };
    if !(a.live_wait.is_finite() && a.live_wait >= 0.0) {
        bail!("--live-wait {}: must be a number of seconds, 0 or more", a.live_wait);
    }
    let real_time = if a.real_time {
        let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
        let flag = stop.clone();
        ctrlc::set_handler(move || flag.store(true, std::sync::atomic::Ordering::Relaxed))
            .context("installing the Ctrl-C handler")?;
        Some(stop)
    } else {
        None
    };
    let opts = FlyOptions {
        live: a.live.clone().map(|addr| sim_host::fly::LiveFly { addr, wait_s: a.live_wait }),
        real_time,
        mavlink,
        scenario,
        seed,
        duration_s: a.duration,
        camera,
        out: a.out.clone(),
        plots: !a.no_plots,
        fc,
        log: !a.no_log,
        frames: a.frames.policy(),
        serve: match &a.serve_link {
            None => None,
            Some(link) => {
                let key = match (&a.key, a.no_key) {
                    (Some(f), _) => Some(sim_host::link_key::read_key(f).context("--key")?),
                    (None, true) => {
                        eprintln!(
                            "the radio is unauthenticated (--no-key): anyone on it may command the vehicle"
                        );
                        None
                    }
                    (None, false) => bail!(
                        "--serve-link needs --key FILE (`sim-host keygen --out FILE`, the station's key) or, for \
                         development only, --no-key"
                    ),
                };
                // Ctrl-C ends the real-time flight with its summary and log written.
                let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
                let flag = stop.clone();
                ctrlc::set_handler(move || flag.store(true, std::sync::atomic::Ordering::Relaxed))
                    .context("installing the Ctrl-C handler")?;
                Some(sim_host::virtual_vehicle::ServeOptions {
                    link: link.clone(),
                    forward: a.serve_forward.clone().context("--serve-link needs --serve-forward")?,
                    down: a.serve_down.clone(),
                    connect_timeout_s: a.connect_timeout,
                    stop,
                    key,
                })
            }
        },
    };
    let bar = progress_bar(1000, "{spinner} flying [{bar:40}] {msg} ({elapsed} elapsed)");
    let result = fly(&opts, |t, end| {
        bar.set_position((t / end * 1000.0).min(1000.0) as u64);
        bar.set_message(format!("{t:.1} s simulated"));
    })?;
    bar.finish_and_clear();
    let st = &result.stats;
    eprintln!(
        "{} s simulated in {:.1} s ({} real time), {} sweep passes, {}",
        format_args!("{:.1}", st.sim_time_s),
        result.wall_time_s,
        rtf_text(st.sim_time_s / result.wall_time_s.max(1e-9)),
        st.passes_done,
        if st.crashed {
            format!("CRASHED: {}", st.crash_reason.clone().unwrap_or_default())
        } else if st.landed {
            "landed".to_string()
        } else {
            "not landed".to_string()
        }
    );
    let mm = |v: [f64; 3]| {
        if v.iter().all(|x| x.is_finite()) {
            format!("x {:.1} mm, y {:.1} mm, z {:.1} mm", 1e3 * v[0], 1e3 * v[1], 1e3 * v[2])
        } else {
            "none (no tracking phase)".to_string()
        }
    };
    eprintln!(
        "tracking RMS error {}; estimate RMS error {}; max tilt {:.2} deg",
        mm(st.rms_error_m),
        mm(st.estimate_rms_error_m),
        st.max_tilt_deg
    );
    if let Some(c) = &st.fc_cost {
        let budget = sim_host::fil::STEP_BUDGET_INSTRUCTIONS;
        eprintln!(
            "firmware control step: mean {:.0} instructions, max {} at {:.2} s (budget {budget}: {}); {:.1} % of the core",
            c.mean_instructions,
            c.max_instructions,
            c.max_at_s,
            if c.max_instructions <= budget { "within" } else { "OVER" },
            100.0 * c.step_cpu_share
        );
        eprintln!(
            "firmware pose solves (background): {} solves, mean {:.0} instructions each, largest run {} at {:.2} s; {:.1} % of the core",
            c.solves,
            c.solve_mean_instructions,
            c.background_max_instructions,
            c.background_max_at_s,
            100.0 * c.background_cpu_share
        );
        eprintln!("firmware {}", c.stack_report.as_deref().unwrap_or("gave no stack report"));
    }
    eprintln!("wrote:");
    for f in &result.files {
        eprintln!("  {}", f.display());
    }
    Ok(if st.crashed { ExitCode::from(3) } else { ExitCode::SUCCESS })
}
