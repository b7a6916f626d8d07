//! `sim-host fly`: a software-in-the-loop flight and its outputs (summary, trajectory, plots).
use crate::fil::STEP_BUDGET_INSTRUCTIONS;
use crate::imageio::write_png_rgb;
use crate::plot::{Plot, Series, render};
use crate::scenario::Scenario;
use crate::sil::{CameraMode, FcChoice, FlowRecord, Record, RunStats, Sil};
use anyhow::{Context, Result};
use serde_json::{Value, json};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// What to fly.
#[derive(Clone, Debug)]
pub struct FlyOptions {
    /// The scenario.
    pub scenario: Scenario,
    /// Seed of every noise stream.
    pub seed: u64,
    /// Longest simulated time (s); the scenario's limit when `None`.
    pub duration_s: Option<f64>,
    /// Forward camera simulation.
    pub camera: CameraMode,
    /// Output directory.
    pub out: PathBuf,
    /// Write the PNG plots.
    pub plots: bool,
    /// The flight computer.
    pub fc: FcChoice,
    /// Write the flight log (`flight.log`) for replay.
    pub log: bool,
    /// Whether the log keeps the camera frames, and how.
    pub frames: crate::flightlog::FramePolicy,
    /// Serve a separate ground station in real time (the virtual vehicle) instead of running one here.
    pub serve: Option<crate::virtual_vehicle::ServeOptions>,
    /// Fly in real time with a MAVLink ground control station commanding the in-process station.
    pub mavlink: Option<MavlinkFly>,
    /// Publish the flight live for Foxglove or Lichtblick (`crate::live`, the `live` feature).
    pub live: Option<LiveFly>,
    /// Pace the flight to the wall clock; setting the flag (Ctrl-C) ends it with its outputs written.
    pub real_time: Option<std::sync::Arc<std::sync::atomic::AtomicBool>>,
}

/// `fly --live`: where the live view listens, and how long to wait for its first viewer before flying.
#[derive(Clone, Debug)]
pub struct LiveFly {
    /// `HOST:PORT` (port 0: any free one).
    pub addr: String,
    /// Seconds to wait for a viewer (0: none).
    pub wait_s: f64,
}

/// `fly --mavlink`: the ground control station's address, and the flag that stops the real-time flight.
#[derive(Clone, Debug)]
pub struct MavlinkFly {
    /// `udp:HOST:PORT` (docs/mavlink.md).
    pub spec: String,
    /// Set (by Ctrl-C) to end the flight with its outputs written.
    pub stop: std::sync::Arc<std::sync::atomic::AtomicBool>,
}

/// Runs `sil` paced to the wall clock (a ground control station commands it in real time) until it ends or
/// `stop` is set, calling `progress` with the simulated time about every 0.1 s of it.
pub fn run_real_time(
    sil: &mut Sil,
    duration_s: f64,
    stop: &std::sync::atomic::AtomicBool,
    mut progress: impl FnMut(f64),
) -> RunStats {
    let end_us = (duration_s * 1e6).round() as u64;
    let start = Instant::now();
    let mut last = -1.0;
    while !stop.load(std::sync::atomic::Ordering::Relaxed) && sil.step(end_us) {
        let t = sil.time_s();
        if t - last >= 0.1 {
            last = t;
            progress(t);
        }
        let ahead = t - start.elapsed().as_secs_f64();
        if ahead > 0.002 {
            std::thread::sleep(std::time::Duration::from_secs_f64(ahead));
        }
    }
    progress(sil.time_s());
    sil.finish()
}

/// The outcome of a flight.
#[derive(Clone, Debug)]
pub struct FlyResult {
    /// Measurements of the run.
    pub stats: RunStats,
    /// Wall-clock time of the simulation (s).
    pub wall_time_s: f64,
    /// `summary.json`'s content.
    pub summary: Value,
    /// Files written.
    pub files: Vec<PathBuf>,
}

fn r6(v: f64) -> Value {
    if v.is_finite() { json!((v * 1e6).round() / 1e6) } else { Value::Null }
}

/// The largest tilt the laws can command: the position terms' bound plus the trajectory's feed-forward and the
/// trims (deg).
pub fn tilt_bound_deg(s: &Scenario) -> f64 {
    let g = &s.gains;
    let ff = (s.trajectory.accel_m_s2 as f64 / control_core::GRAVITY as f64).atan();
    let per_axis =
        |a: &control_core::params::SaturatedAxisGains| a.tilt_bound_rad() as f64 + a.trim_limit_rad as f64;
    let roll = per_axis(&g.roll) + ff;
    let pitch = per_axis(&g.pitch);
    // Both axes at their bounds at once.
    (roll.tan().powi(2) + pitch.tan().powi(2)).sqrt().atan().to_degrees()
}

/// The plots [`write_plots`] writes, by file name.
pub const PLOT_FILES: [&str; 5] = ["x.png", "y.png", "z.png", "vx.png", "vy.png"];

/// Every file a flight may write into its output directory (the drawn scenario of a sweep's run, the log, the
/// CSV files, the plots, the summary), so that a command can refuse one that is an input before it starts.
pub fn output_files(out: &Path) -> Vec<PathBuf> {
    let mut names =
        vec!["scenario.toml", crate::flightlog::LOG_FILE, "trajectory.csv", "flow.csv", "summary.json"];
    names.extend(PLOT_FILES);
    names.into_iter().map(|n| out.join(n)).collect()
}

/// Flies the scenario; `progress(sim_time_s, end_s)` is called about every 0.1 s of simulated time.
pub fn fly(opts: &FlyOptions, mut progress: impl FnMut(f64, f64)) -> Result<FlyResult> {
    std::fs::create_dir_all(&opts.out).with_context(|| format!("cannot create {}", opts.out.display()))?;
    let end = opts.duration_s.unwrap_or(opts.scenario.mission.max_duration_s);
    #[cfg(not(feature = "live"))]
    if opts.live.is_some() {
        anyhow::bail!(
            "--live: this sim-host was built without the live view; build it with `--features live` \
             (`cargo run --release -p sim-host --features live -- fly --live ...`)"
        );
    }
    #[cfg(feature = "live")]
    let live_view = match &opts.live {
        None => None,
        Some(l) => {
            let view = crate::live::LiveView::start(&l.addr, &opts.scenario)?;
            // On stdout, for whoever connects a viewer (a port 0 was chosen here).
            println!("live view ws://{}", view.address());
            use std::io::Write as _;
            std::io::stdout().flush()?;
            eprintln!(
                "live view: in Foxglove or Lichtblick, Open connection > Foxglove WebSocket > ws://{} (layout: \
                 docs/foxglove-layout.json)",
                view.address()
            );
            if l.wait_s > 0.0 {
                eprintln!("waiting up to {} s for the first viewer", l.wait_s);
                let never = std::sync::atomic::AtomicBool::new(false);
                let stop = opts.real_time.as_deref().unwrap_or(&never);
                if !view.wait_for_client(stop, std::time::Duration::from_secs_f64(l.wait_s)) {
                    eprintln!("no viewer connected: flying anyway");
                }
            }
            Some(view)
        }
    };
    let mut sil = Sil::with_fc(&opts.scenario, opts.seed, opts.camera, &opts.fc)?;
    #[cfg(feature = "live")]
    if let Some(view) = &live_view {
        // Paced to the wall clock: --real-time, or a MAVLink flight (which runs in real time).
        sil.set_tap(Box::new(view.tap(opts.real_time.is_some() || opts.mavlink.is_some())));
    }
    let log_path = opts.out.join(crate::flightlog::LOG_FILE);
    if opts.log {
        let header = crate::flightlog::LogHeader {
            format_version: crate::flightlog::LOG_FORMAT_VERSION,
            schema_hash: crate::flightlog::schema_hash(),
            wire_version: protocol::frame::WIRE_VERSION,
            writer: format!("sim-host {}", env!("CARGO_PKG_VERSION")),
            scenario_toml: toml::to_string(&opts.scenario).context("the scenario as TOML")?,
            seed: opts.seed,
            camera: opts.camera.name().to_string(),
            flight_computer: match &opts.fc {
                FcChoice::Sil => "sil".to_string(),
                FcChoice::Qemu(q) => format!("qemu:{}", q.elf.display()),
            },
            reference: String::new(),
            reference_yaw_absolute: false,
            link_security: match &opts.serve {
                None => "in-process (no radio)".to_string(),
                Some(s) => {
                    flight_core::radio::VehicleRadio::new(crate::virtual_vehicle::radio_security(s.key))
                        .describe()
                        .to_string()
                }
            },
        };
        sil.record_log(crate::flightlog::LogWriter::create(&log_path, &header)?, opts.frames);
    }
    let t0 = Instant::now();
    let mut serve_stats = None;
    let mut mavlink_stats = None;
    let stats = match (&opts.serve, &opts.mavlink) {
        (Some(_), Some(_)) => {
            anyhow::bail!("--mavlink is for a flight without a separate station: give it to the station")
        }
        (None, Some(m)) => {
            let endpoint = crate::mavlink_endpoint::MavlinkEndpoint::open(&m.spec)?;
            eprintln!("MAVLink: sending to {} from {}", m.spec, endpoint.local_addr());
            sil.set_ground_hook(Box::new(endpoint));
            let st = run_real_time(&mut sil, end, &m.stop, |t| progress(t, end));
            mavlink_stats = sil.take_ground_hook().map(|h| h.finish());
            st
        }
        (None, None) => match &opts.real_time {
            Some(stop) => run_real_time(&mut sil, end, stop, |t| progress(t, end)),
            None => sil.run(end, |t| progress(t, end)),
        },
        (Some(serve), None) => {
            let bound = crate::virtual_vehicle::Bound::bind(serve)?;
            let (link, forward, down) = bound.addresses();
            // On stdout, one line each, for whoever starts the station (a port 0 was chosen here).
            println!("serving link tcp:{link}");
            println!("serving forward tcp:{forward}");
            if let Some(d) = down {
                println!("serving down tcp:{d}");
            }
            use std::io::Write as _;
            std::io::stdout().flush()?;
            let (st, ss) =
                crate::virtual_vehicle::serve(&mut sil, bound, serve, end, serve.stop.clone(), |t| {
                    progress(t, end)
                })?;
            serve_stats = Some(ss);
            st
        }
    };
    let wall = t0.elapsed().as_secs_f64();
    #[cfg(feature = "live")]
    let live_stats = live_view.map(|view| {
        drop(sil.take_tap());
        let st = view.finish();
        eprintln!("live view: {}", st.describe());
        st
    });
    let mut files = Vec::new();
    if opts.log {
        sil.finish_log()?;
        files.push(log_path);
    }
    if let Some(e) = &stats.fc_error {
        anyhow::bail!("the flight computer failed after {:.3} s of flight: {e}", stats.sim_time_s);
    }
    let csv = opts.out.join("trajectory.csv");
    write_trajectory_csv(&csv, sil.records())?;
    files.push(csv);
    if stats.flow_camera {
        let path = opts.out.join("flow.csv");
        write_flow_csv(&path, sil.flow_records())?;
        files.push(path);
    }
    if opts.plots {
        files.extend(write_plots(
            &opts.out,
            sil.records(),
            sil.flow_records(),
            opts.scenario.flight_params().trajectory.ground_height_m as f64,
        )?);
    }
    let mut summary = summary_json(opts, &stats, wall, &files);
    if let Some(ss) = serve_stats {
        summary["virtual_vehicle"] = serde_json::to_value(ss)?;
    }
    if let Some(ms) = mavlink_stats {
        summary["mavlink"] = serde_json::to_value(ms)?;
    }
    #[cfg(feature = "live")]
    if let Some(ls) = live_stats {
        summary["live"] = serde_json::to_value(ls)?;
    }
    let path = opts.out.join("summary.json");
    crate::files::write_atomic(&path, (serde_json::to_string_pretty(&summary)? + "\n").as_bytes())?;
    files.push(path);
    Ok(FlyResult { stats, wall_time_s: wall, summary, files })
}

/// The content of `summary.json`.
pub fn summary_json(opts: &FlyOptions, st: &RunStats, wall: f64, files: &[PathBuf]) -> Value {
    let xyz = |v: [f64; 3]| json!({"x": r6(v[0]), "y": r6(v[1]), "z": r6(v[2])});
    let fc = match &opts.fc {
        FcChoice::Sil => json!("sil"),
        FcChoice::Qemu(q) => json!({"qemu": q.elf.display().to_string()}),
    };
    let cost = st.fc_cost.as_ref().map(|c| {
        json!({
            "steps": c.steps,
            "mean": r6(c.mean_instructions),
            "max": c.max_instructions,
            "max_at_s": r6(c.max_at_s),
            "budget": STEP_BUDGET_INSTRUCTIONS,
            "within_budget": c.max_instructions <= STEP_BUDGET_INSTRUCTIONS,
            "cpu_share": r6(c.step_cpu_share),
            "background": {
                "solves": c.solves,
                "mean_per_solve": r6(c.solve_mean_instructions),
                "max": c.background_max_instructions,
                "max_at_s": r6(c.background_max_at_s),
                "cpu_share": r6(c.background_cpu_share),
            },
            "stack": c.stack_report,
        })
    });
    json!({
        "scenario": opts.scenario.name,
        "seed": opts.seed,
        "camera": opts.camera.name(),
        "flight_computer": fc,
        "fc_step_instructions": cost,
        "sim_time_s": r6(st.sim_time_s),
        "wall_time_s": r6(wall),
        "real_time_factor": r6(if wall > 0.0 { st.sim_time_s / wall } else { f64::NAN }),
        "crashed": st.crashed,
        "crash_reason": st.crash_reason,
        "rms_error_m": xyz(st.rms_error_m),
        "estimate_rms_error_m": xyz(st.estimate_rms_error_m),
        "max_tilt_deg": r6(st.max_tilt_deg),
        "tilt_bound_deg": r6(tilt_bound_deg(&opts.scenario)),
        "tracking_s": r6(st.tracking_s),
        "passes_done": st.passes_done,
        "landed": st.landed,
        "max_touchdown_speed_m_s": r6(st.max_touchdown_speed_m_s),
        "vision": {
            "frames": st.frames,
            "solved": st.frames_solved,
            "no_target": st.frames_no_target,
            "rejected": st.frames_rejected,
            "frozen": st.frames_frozen,
            "ground_station_no_target": st.ground_no_target.to_json(),
            "analytic_not_in_view": st.analytic_not_in_view,
        },
        "flow_velocity_rms_error_m_s": if st.flow_camera {
            json!({"x": r6(st.flow_rms_error_m_s[0]), "y": r6(st.flow_rms_error_m_s[1])})
        } else {
            Value::Null
        },
        "flow": if st.flow_camera {
            json!({
                "camera": "on",
                "frames": st.down_frames,
                "pairs": st.flow.pairs,
                "velocities": st.flow.velocities,
                "no_flow": st.flow.no_flow,
                "low_quality": st.flow.low_quality,
                "unusable": st.flow.unusable,
                "fused": st.flow_fused[0],
                "rejected_by_estimator": st.flow_fused[1],
            })
        } else {
            json!({
                "camera": "off",
                "degraded": "no downward camera: velocity from the IMU and the forward camera's fixes only",
            })
        },
        "failsafes": st.failsafes.iter().map(|(t, f)| json!({"t_s": r6(*t), "failsafe": f})).collect::<Vec<_>>(),
        "wall_contact": st.wall_contact,
        "min_wall_distance_m": r6(st.min_wall_distance_m),
        "link_messages_lost": st.link_dropped,
        "estimator": {
            "tilt_error_rms_deg": r6(st.tilt_error_rms_deg),
            "max_tilt_error_deg": r6(st.max_tilt_error_deg),
            "accepted": {
                "vision_fixes": st.estimator.fixes_accepted,
                "flow": st.estimator.flow_accepted,
                "magnetometer": st.estimator.mag_accepted,
            },
            "rejected": {
                "vision_position": st.estimator.fixes_rejected,
                "vision_yaw": st.estimator.vision_yaw_rejected,
                "vision_stale": st.estimator.fixes_stale,
                "flow": st.estimator.flow_rejected,
                "magnetometer": st.estimator.mag_rejected,
                "accelerometer": st.estimator.accel_rejected,
            },
            "imu_gaps": st.estimator.imu_gaps,
            "imu_spikes": st.estimator.imu_spikes,
            "gyro_clipped": st.estimator.gyro_clipped,
            "yaw_resets": st.estimator.yaw_resets,
            "position_resets": st.estimator.position_resets,
            "floor_constraints": st.estimator.floor_constraints,
            "wind_m_s": st.wind_estimate_m_s.map(|w| json!({"x": r6(w[0] as f64), "y": r6(w[1] as f64)})),
        },
        "modes": st.modes.iter().map(|(t, m)| json!({"t_s": r6(*t), "mode": m})).collect::<Vec<_>>(),
        "definitions": {
            "rms_error_m": "true minus desired position over the tracking phase",
            "estimate_rms_error_m": "estimated minus true position over the tracking phase",
            "max_tilt_deg": "largest true tilt while airborne",
            "wall_contact": "the vehicle's centre closer to the wall than its arm and a rotor radius",
            "estimator.tilt_error_rms_deg": "estimated minus true roll and pitch over the tracking phase",
            "estimator.wind_m_s": "the estimator's wind at the end of the flight (world frame); with the accelerometer bias it explains the rotor drag's specific force, the two told apart only as the heading changes",
            "fc_step_instructions": "the firmware's instructions per control step under QEMU (-icount shift=0: SysTick counts / 0.168); budget 20 % of the 2 ms period at 168 MHz; background: the pose solves run after the steps (instructions per solve, largest run, and the core's share at one instruction per cycle)",
            "flow_velocity_rms_error_m_s": "optical-flow velocity (body frame, taken to the world frame with the true attitude) minus the true mean velocity over its frame pair, world x and y, while airborne",
        },
        "files": files.iter().filter_map(|f| f.file_name()).map(|f| f.to_string_lossy().to_string()).collect::<Vec<_>>(),
    })
}

/// Writes the recorded samples as CSV (100 Hz; deterministic text for a given seed).
pub fn write_trajectory_csv(path: &Path, records: &[Record]) -> Result<()> {
    let mut s = String::with_capacity(records.len() * 400);
    s.push_str(
        "t_s,true_x_m,true_y_m,true_z_m,true_vx_m_s,true_vy_m_s,true_vz_m_s,true_roll_deg,true_pitch_deg,true_yaw_deg,\
         est_x_m,est_y_m,est_z_m,est_vx_m_s,est_vy_m_s,est_vz_m_s,est_roll_deg,est_pitch_deg,est_yaw_deg,\
         des_x_m,des_y_m,des_z_m,des_vx_m_s,des_vy_m_s,des_vz_m_s,\
         motor_cmd1_rad_s,motor_cmd2_rad_s,motor_cmd3_rad_s,motor_cmd4_rad_s,motor1_rad_s,motor2_rad_s,motor3_rad_s,motor4_rad_s,\
         mode,fix_age_s\n",
    );
    for r in records {
        s.push_str(&format!("{:.3}", r.t_s));
        for v in r.true_p.iter().chain(&r.true_v) {
            s.push_str(&format!(",{v:.6}"));
        }
        for v in &r.true_att {
            s.push_str(&format!(",{:.4}", v.to_degrees()));
        }
        for v in r.est_p.iter().chain(&r.est_v) {
            s.push_str(&format!(",{v:.6}"));
        }
        for v in &r.est_att {
            s.push_str(&format!(",{:.4}", (*v as f64).to_degrees()));
        }
        for v in r.des_p.iter().chain(&r.des_v) {
            s.push_str(&format!(",{v:.6}"));
        }
        for v in &r.motor_cmd {
            s.push_str(&format!(",{v:.2}"));
        }
        for v in &r.motor {
            s.push_str(&format!(",{v:.2}"));
        }
        let age = if r.fix_age_s.is_finite() { format!("{:.3}", r.fix_age_s) } else { String::new() };
        s.push_str(&format!(",{:?},{}\n", r.mode, age));
    }
    crate::files::write_atomic(path, s.as_bytes())
}

/// Writes the flow velocities against the truth as CSV.
pub fn write_flow_csv(path: &Path, records: &[FlowRecord]) -> Result<()> {
    let mut s = String::with_capacity(records.len() * 80);
    s.push_str("t_s,flow_vx_m_s,flow_vy_m_s,true_vx_m_s,true_vy_m_s,flow_std_m_s\n");
    for r in records {
        s.push_str(&format!(
            "{:.4},{:.6},{:.6},{:.6},{:.6},{:.6}\n",
            r.t_s, r.measured[0], r.measured[1], r.truth[0], r.truth[1], r.std_m_s
        ));
    }
    crate::files::write_atomic(path, s.as_bytes())
}

/// The setpoint as the plots draw it: what the controller used while it flew (the airborne modes), nothing
/// before the take-off or after the disarm (the reference then is not flown), and the height clipped at the
/// floor, `floor_z` being the centre of mass's height when the vehicle stands on it (`ground_height_m`; a
/// landing drives its reference below it to find the touchdown, docs/architecture.md, and the vehicle cannot
/// follow it there).
pub fn plotted_setpoint(records: &[Record], k: usize, vel: bool, floor_z: f64) -> Vec<f64> {
    records
        .iter()
        .map(|r| {
            if !r.mode.airborne() {
                return f64::NAN;
            }
            match (vel, k) {
                (true, _) => r.des_v[k] as f64,
                (false, 2) => (r.des_p[2] as f64).max(floor_z),
                (false, _) => r.des_p[k] as f64,
            }
        })
        .collect()
}

/// Writes x, y, z and the horizontal velocities over time (truth, estimate, desired, and the optical flow's
/// velocity), like the paper's figures 7-11 with the truth beside every estimate.
pub fn write_plots(
    dir: &Path,
    records: &[Record],
    flow: &[FlowRecord],
    floor_z: f64,
) -> Result<Vec<PathBuf>> {
    let t: Vec<f64> = records.iter().map(|r| r.t_s).collect();
    let col = |f: &dyn Fn(&Record) -> f64| records.iter().map(f).collect::<Vec<f64>>();
    let track = records
        .iter()
        .filter(|r| r.mode == control_core::FlightMode::Tracking)
        .map(|r| r.t_s)
        .collect::<Vec<_>>();
    let spans = match (track.first(), track.last()) {
        (Some(a), Some(b)) => vec![(*a, *b, "tracking")],
        _ => vec![],
    };
    let panels: [(&str, &str, &str, usize, bool); PLOT_FILES.len()] = [
        ("x.png", "x: along the line (paper Fig. 8)", "x (m)", 0, false),
        ("y.png", "y: distance to the wall (paper Fig. 7)", "y (m)", 1, false),
        ("z.png", "z: altitude (paper Fig. 9)", "z (m)", 2, false),
        ("vx.png", "x velocity (paper Fig. 11)", "vx (m/s)", 0, true),
        ("vy.png", "y velocity (paper Fig. 10)", "vy (m/s)", 1, true),
    ];
    let flow_t: Vec<f64> = flow.iter().map(|r| r.t_s).collect();
    // The plots are drawn and encoded in parallel (each is a pure function of the records).
    use rayon::prelude::*;
    panels
        .into_par_iter()
        .map(|(file, title, ylabel, k, vel)| {
            let truth = col(&|r| if vel { r.true_v[k] } else { r.true_p[k] });
            let est = col(&|r| (if vel { r.est_v[k] } else { r.est_p[k] }) as f64);
            let des = plotted_setpoint(records, k, vel, floor_z);
            let flow_v: Vec<f64> =
                if vel { flow.iter().map(|r| r.measured[k]).collect() } else { Vec::new() };
            let mut series = vec![
                Series { name: "desired", color: [110, 110, 110], xs: &t, ys: &des, dashed: true },
                Series { name: "truth", color: [30, 90, 200], xs: &t, ys: &truth, dashed: false },
                Series { name: "estimate", color: [220, 60, 30], xs: &t, ys: &est, dashed: false },
            ];
            if vel && !flow.is_empty() {
                series.insert(
                    1,
                    Series {
                        name: "optical flow",
                        color: [60, 170, 80],
                        xs: &flow_t,
                        ys: &flow_v,
                        dashed: false,
                    },
                );
            }
            let img = render(&Plot {
                title,
                x_label: "time (s)",
                y_label: ylabel,
                series,
                spans: spans.clone(),
                size: (1200, 420),
            });
            let path = dir.join(file);
            write_png_rgb(&path, &img)?;
            Ok(path)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use control_core::FlightMode;

    fn record(t_s: f64, mode: FlightMode, des_z: f32) -> Record {
        Record {
            t_s,
            true_p: [0.0; 3],
            true_v: [0.0; 3],
            true_att: [0.0; 3],
            est_p: [0.0; 3],
            est_v: [0.0; 3],
            est_att: [0.0; 3],
            des_p: [1.0, 1.3, des_z],
            des_v: [0.0, 0.0, -0.3],
            motor_cmd: [0.0; 4],
            motor: [0.0; 4],
            mode,
            fix_age_s: 0.0,
            tilt_std_rad: 0.0,
        }
    }

    #[test]
    fn the_plotted_height_setpoint_stops_at_the_floor_and_at_the_disarm() {
        // The landing's reference goes below the pad (-0.12 m) to find the touchdown; after the disarm the
        // reference is the mission height again (0.80 m), and before the take-off nothing is flown. The floor
        // for the centre of mass is the landed height, 0.06 m.
        let rs = [
            record(0.0, FlightMode::Disarmed, 0.8),
            record(0.5, FlightMode::Armed, 0.8),
            record(1.0, FlightMode::TakeOff, 0.1),
            record(2.0, FlightMode::Landing, 0.05),
            record(2.5, FlightMode::Landing, -0.12),
            record(3.0, FlightMode::Disarmed, 0.8),
        ];
        let z = plotted_setpoint(&rs, 2, false, 0.06);
        assert!(z[0].is_nan() && z[1].is_nan() && z[5].is_nan(), "{z:?}");
        assert_eq!(&z[2..5], &[0.1f32 as f64, 0.06, 0.06]);
        let y = plotted_setpoint(&rs, 1, false, 0.06);
        assert_eq!(y[3], 1.3f32 as f64);
        assert!(y[5].is_nan());
        let vz = plotted_setpoint(&rs, 2, true, 0.06);
        assert_eq!(vz[4], -0.3f32 as f64, "velocities are not clipped");
        assert!(vz[0].is_nan());
    }
}
