//! `sim-host`: render camera frames, run the vision, fly the paper's experiment in simulation.
//!
//! Exit codes: 0 success; 1 bad input or option (message on stderr); 2 the frame has no target (or the frame
//! pair no flow); 3 the simulated vehicle crashed.
use anyhow::{Context, Result, bail};
use clap::{Args, Parser, Subcommand, ValueEnum};
use geometry::frames::Attitude;
use geometry::{Vec3, deg};
use indicatif::{ProgressBar, ProgressStyle};
use sim_host::Scenario;
use sim_host::downward::{GroundFlow, flow_json, no_flow_json};
use sim_host::imageio::{GrayImage, read_png_gray, read_png_rgb, write_png_gray, write_png_rgb};
use sim_host::render::{DownPose, DownRenderer, ForwardRenderer};
use sim_host::replay::{ReplayOptions, VisionSource, replay_stream};
use sim_host::vision::{GroundVision, PoseMethod, draw_overlay, no_target_json, pose_json};
use std::path::PathBuf;
use std::process::ExitCode;
use vision_core::AttitudeSource;

#[derive(Parser, Debug)]
#[command(
    name = "sim-host",
    version,
    about = "Simulator, ground-station vision and tools for the wall-line quadrotor",
    long_about = "Simulator, ground-station vision and tools for the wall-line quadrotor.\n\n\
        World frame: x along the wall and the line, y from the wall to the vehicle (the distance to the wall), \
        z up from the floor. Angles are in degrees; roll, pitch and yaw are all zero when the vehicle is level \
        and faces the wall. Body frame: x forward, y left, z up.\n\nExit codes: 0 success, 1 bad input or \
        option, 2 no target in the frame (or no flow between two frames), 3 the simulated vehicle crashed."
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Render the frame a camera sees from a vehicle pose.
    Render(RenderArgs),
    /// Run the vision on recorded frames.
    #[command(subcommand)]
    Vision(VisionCommand),
    /// Fly a scenario in simulation with the flight code (software in the loop).
    Fly(FlyArgs),
    /// Re-run the flight stack on a flight log's inputs and compare every output with the log, bit for bit.
    Replay(ReplayArgs),
    /// Export a flight log to MCAP (Foxglove, Lichtblick, PlotJuggler, Rerun) and/or CSV files.
    Export(ExportArgs),
    /// Import a recorded dataset into a flight log (then `replay --out` runs the flight code on it).
    #[command(subcommand)]
    Import(ImportCommand),
}

#[derive(Subcommand, Debug)]
enum ImportCommand {
    /// A dataset in the EuRoC/ASL folder layout: imu0/data.csv, cam0/data.csv with cam0/data/*.png and,
    /// if present, cam0/sensor.yaml for the camera's intrinsics.
    Euroc(EurocArgs),
}

#[derive(Args, Debug)]
struct EurocArgs {
    /// The dataset folder (holding imu0/ and cam0/, or mav0/ with them).
    dir: PathBuf,
    /// The flight log to write.
    #[arg(long, value_name = "LOG")]
    out: PathBuf,
    /// The scenario whose flight parameters the replay uses (its camera comes from cam0/sensor.yaml).
    #[arg(long, default_value = "paper")]
    scenario: String,
    /// Which camera cam0 is: the forward camera (line detection) or the downward one (optical flow).
    #[arg(long, value_enum, default_value = "forward")]
    cam0: CameraChoice,
    /// Body axes (x forward, y left, z up) in IMU axes, e.g. the EuRoC MAV's `z,-y,x` (body x = IMU z, ...).
    #[arg(long, default_value = "z,-y,x", value_name = "AXES")]
    imu_axes: String,
    /// Delay from a frame's capture to its measurement reaching the flight code (s).
    #[arg(long, default_value_t = 0.0)]
    latency: f64,
    /// Import only the first SECONDS of the dataset.
    #[arg(long, value_name = "SECONDS")]
    duration: Option<f64>,
}

/// Parses `z,-y,x` into body-from-IMU rows.
fn parse_axes(text: &str) -> Result<[[f32; 3]; 3]> {
    let parts: Vec<&str> = text.split(',').map(str::trim).collect();
    let bad = || anyhow::anyhow!("--imu-axes {text}: expected three signed axes such as `z,-y,x`");
    if parts.len() != 3 {
        return Err(bad());
    }
    let mut m = [[0f32; 3]; 3];
    let mut used = [false; 3];
    for (row, p) in parts.iter().enumerate() {
        let (sign, axis) = match p.strip_prefix('-') {
            Some(a) => (-1.0, a),
            None => (1.0, p.strip_prefix('+').unwrap_or(p)),
        };
        let k = match axis {
            "x" => 0,
            "y" => 1,
            "z" => 2,
            _ => return Err(bad()),
        };
        if used[k] {
            bail!("--imu-axes {text}: axis {axis} used twice");
        }
        used[k] = true;
        m[row][k] = sign;
    }
    let det = m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
        - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
        + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
    if det < 0.0 {
        bail!("--imu-axes {text}: a reflection, not a rotation (flip the sign of one axis)");
    }
    Ok(m)
}

fn import_euroc(a: &EurocArgs) -> Result<ExitCode> {
    let opts = sim_host::import::EurocOptions {
        dir: a.dir.clone(),
        scenario: Scenario::load(&a.scenario)?,
        cam0: match a.cam0 {
            CameraChoice::Forward => sim_host::flightlog::CameraId::Forward,
            CameraChoice::Down => sim_host::flightlog::CameraId::Downward,
        },
        imu_to_body: parse_axes(&a.imu_axes)?,
        latency_s: a.latency,
        max_seconds: a.duration,
    };
    if !(a.latency >= 0.0 && a.latency < 10.0) {
        bail!("--latency must be in [0, 10) s");
    }
    let bar = progress_bar(1000, "{spinner} importing [{bar:40}] ({elapsed} elapsed)");
    let s = sim_host::import::import_euroc(&opts, &a.out, |f| bar.set_position((f * 1000.0) as u64))?;
    bar.finish_and_clear();
    eprintln!(
        "wrote {}: {:.1} s, {} IMU samples in {} steps, {} frames ({} measured)",
        a.out.display(),
        s.seconds,
        s.imu_samples,
        s.steps,
        s.frames,
        s.measured
    );
    eprintln!(
        "next: sim-host replay {} --out replayed.log, then sim-host export replayed.log --mcap out.mcap",
        a.out.display()
    );
    Ok(ExitCode::SUCCESS)
}

#[derive(Args, Debug)]
struct ExportArgs {
    /// The flight log.
    log: PathBuf,
    /// Write an MCAP file: one channel per topic, JSON messages, Foxglove schemas for poses and images.
    #[arg(long, value_name = "FILE")]
    mcap: Option<PathBuf>,
    /// Write one CSV file per topic into this directory (nested fields as dotted columns).
    #[arg(long, value_name = "DIR")]
    csv: Option<PathBuf>,
}

#[derive(Args, Debug)]
struct ReplayArgs {
    /// The flight log (`flight.log` written by `sim-host fly`, or `sim-host import`).
    log: PathBuf,
    /// Re-run the ground station's vision (vision-core's line detector and optical flow) on the logged camera
    /// frames and compare each measurement with the logged one, instead of feeding the logged measurements.
    #[arg(long)]
    from_frames: bool,
    /// Write the replayed flight (inputs, recomputed measurements, reports, downlinks) as a new log, e.g. to
    /// export the estimates of an imported dataset.
    #[arg(long, value_name = "LOG")]
    out: Option<PathBuf>,
    /// Change a parameter before the first step, e.g. `--set trajectory.speed_m_s=0.3` (repeatable); the replay
    /// then reports the differences instead of failing on them.
    #[arg(long = "set", value_name = "NAME=VALUE")]
    set: Vec<String>,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
enum FramesArg {
    /// Lossless PNG.
    Png,
    /// Raw 8-bit pixels.
    Raw,
    /// No frames, only the vision results.
    None,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
enum CameraSim {
    /// Rendered images through the full vision pipeline.
    Rendered,
    /// The line's edges projected analytically with edge noise (fast).
    Analytic,
}

#[derive(Args, Debug)]
struct FlyArgs {
    /// Scenario: a built-in name (`paper`) or a TOML file.
    #[arg(long, default_value = "paper")]
    scenario: String,
    /// Seed of every noise stream (a run is a pure function of scenario, seed and camera mode).
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Longest simulated time in seconds (default: the scenario's limit; the run ends when it has landed).
    #[arg(long)]
    duration: Option<f64>,
    /// How the forward camera is simulated.
    #[arg(long, value_enum, default_value = "rendered")]
    camera: CameraSim,
    /// Output directory (summary.json, trajectory.csv, x/y/z/vx/vy.png).
    #[arg(long)]
    out: PathBuf,
    /// Skip the PNG plots.
    #[arg(long)]
    no_plots: bool,
    /// Do not write the flight log (`flight.log`, for `sim-host replay` and `sim-host export`).
    #[arg(long)]
    no_log: bool,
    /// Camera frames in the flight log: `png` (lossless), `raw` pixels, or `none` (only the vision results;
    /// a far smaller log, replayable from vision results only). Only rendered cameras have frames.
    #[arg(long, value_enum, default_value = "png")]
    frames: FramesArg,
    /// The flight computer: `sil` (the flight code in this process) or `qemu:PATH` (the firmware ELF built with
    /// `--features fil`, run in qemu-system-arm's netduinoplus2 model, in lockstep over its UART).
    #[arg(long, default_value = "sil", value_name = "sil|qemu:ELF")]
    fc: String,
}

#[derive(Clone, Copy, Debug, ValueEnum, PartialEq, Eq)]
enum CameraChoice {
    /// The forward camera, looking at the wall (RGB).
    Forward,
    /// The downward camera, looking at the floor (grey), for optical flow.
    Down,
}

#[derive(Args, Debug)]
struct RenderArgs {
    /// Which camera.
    #[arg(long, value_enum, default_value = "forward")]
    camera: CameraChoice,
    /// Vehicle pose X,Y,Z,ROLL,PITCH,YAW: position in metres (world frame), angles in degrees.
    #[arg(long, allow_hyphen_values = true, value_name = "X,Y,Z,ROLL,PITCH,YAW")]
    pose: String,
    /// Output PNG file.
    #[arg(long)]
    out: PathBuf,
    /// Scenario: a built-in name (`paper`) or a TOML file.
    #[arg(long, default_value = "paper")]
    scenario: String,
    /// Seed of the sensor noise.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Illumination gain (default: the scenario's).
    #[arg(long)]
    light_gain: Option<f64>,
    /// Illumination gradient per metre along the wall's x and z, as GX,GZ (default: the scenario's).
    #[arg(long, allow_hyphen_values = true, value_name = "GX,GZ")]
    light_gradient: Option<String>,
    /// Sensor noise in grey levels (default: the scenario's).
    #[arg(long)]
    noise: Option<f64>,
    /// Gaussian blur in pixels (default: the scenario's).
    #[arg(long)]
    blur: Option<f64>,
    /// Downward camera: vehicle velocity VX,VY,VZ in m/s (world frame) during the exposure (motion blur).
    #[arg(long, allow_hyphen_values = true, value_name = "VX,VY,VZ")]
    velocity: Option<String>,
    /// Downward camera: body angular rates WX,WY,WZ in deg/s during the exposure (motion blur).
    #[arg(long, allow_hyphen_values = true, value_name = "WX,WY,WZ")]
    rates: Option<String>,
    /// Downward camera: exposure time in seconds (default: the scenario's).
    #[arg(long)]
    exposure_time: Option<f64>,
}

#[derive(Subcommand, Debug)]
enum VisionCommand {
    /// Position of the vehicle from one forward-camera frame: prints one JSON object.
    Pose(PoseArgs),
    /// Optical flow between two downward-camera frames, and the velocity it gives: prints one JSON object.
    ///
    /// {"status": "ok", "flow_px": [dx, dy], "tracked": n, "quality": q, "velocity_m_s": [vx, vy]} with the
    /// velocity in the body frame (x forward, y left) when --dt and --range are given; the camera is taken to
    /// look straight down from --range metres with no vertical motion. {"status": "no_flow", "reason": ..}
    /// and exit code 2 when nothing can be tracked.
    Flow(FlowArgs),
}

#[derive(Args, Debug)]
struct FlowArgs {
    /// The earlier frame (PNG; colour is converted to grey).
    #[arg(long)]
    prev: PathBuf,
    /// The later frame.
    #[arg(long)]
    next: PathBuf,
    /// Time between the frames in seconds.
    #[arg(long, allow_hyphen_values = true)]
    dt: Option<f64>,
    /// Body angular rates WX,WY,WZ in rad/s over the interval (x forward, y left, z up): removes the rotation's
    /// flow and seeds the tracking. Needs --dt.
    #[arg(long, allow_hyphen_values = true, value_name = "WX,WY,WZ")]
    gyro: Option<String>,
    /// Distance from the camera to the floor along the optical axis, in metres. With --dt, gives the velocity.
    #[arg(long, allow_hyphen_values = true)]
    range: Option<f64>,
    /// Scenario: a built-in name (`paper`) or a TOML file (the downward camera's intrinsics and mount).
    #[arg(long, default_value = "paper")]
    scenario: String,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
enum MethodChoice {
    /// Closed form refined by minimising the reprojection error.
    Refined,
    /// Closed form only (vanishing points, least-squares translation).
    ClosedForm,
    /// The paper's closed form (vanishing points, depth from the line's height).
    Paper,
}

#[derive(Args, Debug)]
struct PoseArgs {
    /// The frame (PNG, RGB or RGBA).
    #[arg(long)]
    image: PathBuf,
    /// Roll and pitch of the vehicle from the IMU, in degrees: selects the IMU-aided solver.
    #[arg(long, allow_hyphen_values = true, value_name = "ROLL,PITCH")]
    attitude: Option<String>,
    /// Standard deviation of the IMU roll and pitch, in degrees.
    #[arg(long, default_value_t = 0.5)]
    attitude_sigma: f64,
    /// Scenario: a built-in name (`paper`) or a TOML file (camera and line).
    #[arg(long, default_value = "paper")]
    scenario: String,
    /// Solver.
    #[arg(long, value_enum, default_value = "refined")]
    method: MethodChoice,
    /// Also write the frame with the measured edges and corners drawn on it.
    #[arg(long)]
    overlay: Option<PathBuf>,
}

fn parse_floats<const N: usize>(s: &str, what: &str) -> Result<[f64; N]> {
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    if parts.len() != N {
        bail!("{what}: expected {N} comma-separated numbers, got `{s}`");
    }
    let mut out = [0.0; N];
    for (o, p) in out.iter_mut().zip(&parts) {
        *o = p.parse::<f64>().with_context(|| format!("{what}: `{p}` is not a number"))?;
        if !o.is_finite() {
            bail!("{what}: `{p}` is not finite");
        }
    }
    Ok(out)
}

fn render_down(a: &RenderArgs, scenario: &Scenario, pose: [f64; 6]) -> Result<ExitCode> {
    let [x, y, z, roll, pitch, yaw] = pose;
    if a.light_gradient.is_some() {
        bail!(
            "--light-gradient applies to the forward camera (the floor takes the scenario's gradient along x)"
        );
    }
    let renderer = DownRenderer::new(scenario)?;
    let mut settings = renderer.default_settings();
    settings.seed = a.seed;
    if let Some(g) = a.light_gain {
        if !(g > 0.0 && g.is_finite()) {
            bail!("--light-gain must be positive");
        }
        settings.light_gain = g;
    }
    if let Some(n) = a.noise {
        if !(n >= 0.0 && n.is_finite()) {
            bail!("--noise must be >= 0");
        }
        settings.noise_sigma = n;
    }
    if let Some(b) = a.blur {
        if !(0.0..=1.5).contains(&b) {
            bail!("--blur must lie in [0, 1.5] px for the downward camera");
        }
        settings.blur_sigma_px = b;
    }
    if let Some(e) = a.exposure_time {
        if !(0.0..=0.1).contains(&e) {
            bail!("--exposure-time must lie in [0, 0.1] s");
        }
        settings.exposure_time_s = e;
    }
    if z.is_nan() || z <= 0.0 {
        bail!("--pose: the downward camera needs the vehicle above the floor (z > 0)");
    }
    let att = Attitude::new(deg(roll as f32), deg(pitch as f32), deg(yaw as f32));
    let mount = scenario.down_camera_mount();
    let r_wb = att.world_from_body();
    let r_wc = r_wb.mul_mat(&mount.body_from_camera);
    let center = Vec3::new(x as f32, y as f32, z as f32) + r_wb.mul_vec(mount.offset_body_m);
    let velocity = match &a.velocity {
        Some(v) => parse_floats::<3>(v, "--velocity")?,
        None => [0.0; 3],
    };
    let omega = match &a.rates {
        Some(r) => {
            let w = parse_floats::<3>(r, "--rates")?.map(|v| deg(v as f32));
            r_wb.mul_vec(Vec3::from_array(w)).to_array().map(|v| v as f64)
        }
        None => [0.0; 3],
    };
    let pose = DownPose {
        r_wc: r_wc.m.map(|row| row.map(|v| v as f64)),
        center: center.to_array().map(|v| v as f64),
        velocity,
        omega_world: omega,
    };
    let img = renderer.render(&pose, &settings);
    write_png_gray(&a.out, &img).with_context(|| format!("writing {}", a.out.display()))?;
    eprintln!("wrote {} ({}x{}, grey)", a.out.display(), img.width, img.height);
    Ok(ExitCode::SUCCESS)
}

fn render(a: &RenderArgs) -> Result<ExitCode> {
    let scenario = Scenario::load(&a.scenario)?;
    let pose = parse_floats::<6>(&a.pose, "--pose")?;
    if a.camera == CameraChoice::Down {
        return render_down(a, &scenario, pose);
    }
    if a.velocity.is_some() || a.rates.is_some() || a.exposure_time.is_some() {
        bail!(
            "--velocity, --rates and --exposure-time model the downward camera's motion blur (--camera down)"
        );
    }
    let [x, y, z, roll, pitch, yaw] = pose;
    let renderer = ForwardRenderer::new(&scenario)?;
    let mut settings = renderer.default_settings();
    settings.seed = a.seed;
    if let Some(g) = a.light_gain {
        if !(g > 0.0 && g.is_finite()) {
            bail!("--light-gain must be positive");
        }
        settings.light_gain = g;
    }
    if let Some(g) = &a.light_gradient {
        settings.light_gradient_per_m = parse_floats::<2>(g, "--light-gradient")?;
    }
    if let Some(n) = a.noise {
        if !(n >= 0.0 && n.is_finite()) {
            bail!("--noise must be >= 0");
        }
        settings.noise_sigma = n;
    }
    if let Some(b) = a.blur {
        if !(0.0..=5.0).contains(&b) {
            bail!("--blur must lie in [0, 5] px");
        }
        settings.blur_sigma_px = b;
    }
    let att = Attitude::new(deg(roll as f32), deg(pitch as f32), deg(yaw as f32));
    let mount = scenario.forward_camera_mount();
    let r_wb = att.world_from_body();
    let r_wc = r_wb.mul_mat(&mount.body_from_camera);
    let center = Vec3::new(x as f32, y as f32, z as f32) + r_wb.mul_vec(mount.offset_body_m);
    let img = renderer.render(&r_wc, center, &settings);
    write_png_rgb(&a.out, &img).with_context(|| format!("writing {}", a.out.display()))?;
    eprintln!("wrote {} ({}x{})", a.out.display(), img.width, img.height);
    Ok(ExitCode::SUCCESS)
}

fn vision_pose(a: &PoseArgs) -> Result<ExitCode> {
    let scenario = Scenario::load(&a.scenario)?;
    let mut img = read_png_rgb(&a.image).with_context(|| format!("{}", a.image.display()))?;
    let cam = scenario.forward_camera_model();
    if img.width != cam.width as usize || img.height != cam.height as usize {
        bail!(
            "{}: the image is {}x{} but the scenario's camera is {}x{}",
            a.image.display(),
            img.width,
            img.height,
            cam.width,
            cam.height
        );
    }
    let source = match &a.attitude {
        Some(s) => {
            let [r, p] = parse_floats::<2>(s, "--attitude")?;
            if !(a.attitude_sigma > 0.0 && a.attitude_sigma.is_finite()) {
                bail!("--attitude-sigma must be positive");
            }
            AttitudeSource::Imu {
                roll: deg(r as f32),
                pitch: deg(p as f32),
                sigma_rad: deg(a.attitude_sigma as f32),
            }
        }
        None => AttitudeSource::ImageOnly,
    };
    let method = match a.method {
        MethodChoice::Refined => PoseMethod::Refined,
        MethodChoice::ClosedForm => PoseMethod::ClosedForm,
        MethodChoice::Paper => PoseMethod::Paper,
    };
    let mut vision = GroundVision::new(&scenario);
    let result = vision.pose(&img, source, method);
    if let Some(path) = &a.overlay {
        if let Ok(obs) = vision.detect(&img) {
            draw_overlay(&mut img, &obs, &scenario);
        }
        write_png_rgb(path, &img)?;
    }
    match result {
        Ok(r) => {
            println!("{}", pose_json(&r, &scenario, source));
            Ok(ExitCode::SUCCESS)
        }
        Err(why) => {
            println!("{}", no_target_json(why));
            Ok(ExitCode::from(2))
        }
    }
}

fn vision_flow(a: &FlowArgs) -> Result<ExitCode> {
    let scenario = Scenario::load(&a.scenario)?;
    let cam = scenario.down_camera_model();
    let load = |p: &PathBuf| -> Result<GrayImage> {
        let img = read_png_gray(p).with_context(|| format!("{}", p.display()))?;
        if img.width != cam.width as usize || img.height != cam.height as usize {
            bail!(
                "{}: the image is {}x{} but the scenario's downward camera is {}x{}",
                p.display(),
                img.width,
                img.height,
                cam.width,
                cam.height
            );
        }
        Ok(img)
    };
    let (prev, next) = (load(&a.prev)?, load(&a.next)?);
    if let Some(dt) = a.dt
        && !(dt > 0.0 && dt.is_finite() && dt <= 1.0)
    {
        bail!("--dt must lie in (0, 1] s");
    }
    if let Some(r) = a.range
        && !(r > 0.0 && r.is_finite())
    {
        bail!("--range must be positive");
    }
    if a.gyro.is_some() && a.dt.is_none() {
        bail!("--gyro needs --dt (the rotation over the interval is the rates times dt)");
    }
    let r_bc = scenario.down_camera_mount().body_from_camera;
    let rot_body = match (&a.gyro, a.dt) {
        (Some(g), Some(dt)) => Vec3::from_array(parse_floats::<3>(g, "--gyro")?.map(|v| (v * dt) as f32)),
        _ => Vec3::ZERO,
    };
    let rot_cam = r_bc.transpose().mul_vec(rot_body);
    let mut flow = GroundFlow::new(&scenario);
    match flow.between(&prev, &next, rot_cam) {
        Ok(stats) => {
            let velocity = match (a.dt, a.range) {
                (Some(dt), Some(range)) => {
                    let track_sigma = 0.05 / cam.fx;
                    let v = stats
                        .velocity(rot_cam, dt as f32, range as f32, Vec3::Z, 0.0, track_sigma)
                        .context("degenerate geometry for the velocity")?;
                    let vb = r_bc.mul_vec(Vec3::new(v.velocity_cam_m_s.x, v.velocity_cam_m_s.y, 0.0));
                    Some([vb.x, vb.y])
                }
                (None, None) => None,
                _ => bail!("the velocity needs both --dt and --range"),
            };
            println!("{}", flow_json(&stats, velocity));
            Ok(ExitCode::SUCCESS)
        }
        Err(why) => {
            println!("{}", no_flow_json(why));
            Ok(ExitCode::from(2))
        }
    }
}

fn fly(a: &FlyArgs) -> Result<ExitCode> {
    use sim_host::fly::{FlyOptions, fly};
    use sim_host::sil::CameraMode;
    let scenario = Scenario::load(&a.scenario)?;
    if let Some(d) = a.duration
        && !(d > 0.0 && d.is_finite())
    {
        bail!("--duration must be positive");
    }
    let camera = match a.camera {
        CameraSim::Rendered => CameraMode::Rendered,
        CameraSim::Analytic => CameraMode::Analytic,
    };
    let fc = match sim_host::fil::parse_fc(&a.fc)? {
        None => sim_host::sil::FcChoice::Sil,
        Some(elf) => sim_host::sil::FcChoice::Qemu(sim_host::fil::QemuOptions::new(elf)),
    };
    let opts = FlyOptions {
        scenario,
        seed: a.seed,
        duration_s: a.duration,
        camera,
        out: a.out.clone(),
        plots: !a.no_plots,
        fc,
        log: !a.no_log,
        frames: match a.frames {
            FramesArg::Png => sim_host::flightlog::FramePolicy::Png,
            FramesArg::Raw => sim_host::flightlog::FramePolicy::Raw,
            FramesArg::None => sim_host::flightlog::FramePolicy::Drop,
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
    eprintln!(
        "tracking RMS error x {:.1} mm, y {:.1} mm, z {:.1} mm; estimate RMS error x {:.1} mm, y {:.1} mm, z {:.1} mm; max tilt {:.2} deg",
        1e3 * st.rms_error_m[0],
        1e3 * st.rms_error_m[1],
        1e3 * st.rms_error_m[2],
        1e3 * st.estimate_rms_error_m[0],
        1e3 * st.estimate_rms_error_m[1],
        1e3 * st.estimate_rms_error_m[2],
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

fn main() -> ExitCode {
    let cli = match Cli::try_parse() {
        Ok(c) => c,
        Err(e) => {
            use clap::error::ErrorKind;
            let code = match e.kind() {
                ErrorKind::DisplayHelp
                | ErrorKind::DisplayVersion
                | ErrorKind::DisplayHelpOnMissingArgumentOrSubcommand => 0,
                _ => 1,
            };
            let _ = e.print();
            return ExitCode::from(code);
        }
    };
    let result = match &cli.command {
        Command::Render(a) => render(a),
        Command::Vision(VisionCommand::Pose(a)) => vision_pose(a),
        Command::Vision(VisionCommand::Flow(a)) => vision_flow(a),
        Command::Fly(a) => fly(a),
        Command::Replay(a) => replay(a),
        Command::Export(a) => run_export(a),
        Command::Import(ImportCommand::Euroc(a)) => import_euroc(a),
    };
    match result {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::from(1)
        }
    }
}

fn replay(a: &ReplayArgs) -> Result<ExitCode> {
    use control_core::params::ParamId;
    let mut overrides = Vec::new();
    for kv in &a.set {
        let Some((name, value)) = kv.split_once('=') else { bail!("--set {kv}: expected NAME=VALUE") };
        let Some(id) = ParamId::from_name(name.trim()) else {
            let names: Vec<&str> = ParamId::ALL.iter().map(|p| p.name()).collect();
            bail!("--set {kv}: unknown parameter `{name}`; known: {}", names.join(", "));
        };
        let v: f32 =
            value.trim().parse().map_err(|_| anyhow::anyhow!("--set {kv}: `{value}` is not a number"))?;
        overrides.push((id, v));
    }
    // Replaying from vision results without writing a new log never looks at the frames: skip them unread.
    let reader = sim_host::flightlog::open_log(&a.log)?.skip_frames(!a.from_frames && a.out.is_none());
    let header = reader.header.clone();
    let file_len = std::fs::metadata(&a.log).map(|m| m.len()).unwrap_or(0);
    let opts = ReplayOptions {
        overrides: overrides.clone(),
        vision: if a.from_frames { VisionSource::Frames } else { VisionSource::Logged },
    };
    let mut writer = match &a.out {
        Some(p) => {
            let mut h = header.clone();
            h.writer = format!("sim-host {} replay of {}", env!("CARGO_PKG_VERSION"), a.log.display());
            Some(sim_host::flightlog::LogWriter::create(p, &h)?)
        }
        None => None,
    };
    let bar = progress_bar(
        file_len.max(1),
        "{spinner} replaying [{bar:40}] {bytes}/{total_bytes} ({elapsed} elapsed)",
    );
    let t0 = std::time::Instant::now();
    let mut count = 0u64;
    let mut items = ProgressItems { inner: reader, bar: &bar, count: &mut count };
    let s = replay_stream(&header, &mut items, &opts, writer.as_mut())?;
    let skipped = items.inner.frames_skipped;
    bar.finish_and_clear();
    let wall = t0.elapsed().as_secs_f64();
    if let Some(w) = writer {
        w.finish()?;
    }
    eprintln!(
        "{}: {} steps ({:.1} s of flight) replayed in {:.2} s ({} real time){}; {} reports compared, {} differ; \
         {} downlinks compared, {} differ",
        a.log.display(),
        s.steps,
        s.sim_time_s,
        wall,
        rtf_text(s.sim_time_s / wall.max(1e-9)),
        if a.from_frames { " from frames" } else { "" },
        s.compared,
        s.differing,
        s.downlinks_compared,
        s.downlinks_differing,
    );
    if skipped > 0 {
        eprintln!(
            "{skipped} camera frames skipped (replayed from the logged vision results; --from-frames uses them)"
        );
    }
    if a.from_frames {
        eprintln!(
            "{} frames; {} measurements recomputed from frames, {} differ, {} without their frame",
            s.frames, s.measurements_compared, s.measurements_differing, s.measurements_without_frame
        );
    }
    if let Some(p) = &a.out {
        eprintln!("wrote {}", p.display());
    }
    for d in &s.damage {
        eprintln!("damaged record {d}");
    }
    if s.compared == 0 && s.steps > 0 {
        eprintln!("the log holds no reports (an imported dataset?): nothing to compare");
    }
    match (&s.first, overrides.is_empty()) {
        (None, _) if s.damage.is_empty() => {
            eprintln!("identical: every output matches the log bit for bit");
            Ok(ExitCode::SUCCESS)
        }
        (None, _) => {
            eprintln!("the intact records match, but {} were damaged", s.damage.len());
            Ok(ExitCode::from(1))
        }
        (Some(d), true) => {
            eprintln!("first difference: {d}");
            Ok(ExitCode::from(1))
        }
        (Some(d), false) => {
            eprintln!("with the changed parameters, first difference: {d}");
            Ok(ExitCode::SUCCESS)
        }
    }
}

fn run_export(a: &ExportArgs) -> Result<ExitCode> {
    if a.mcap.is_none() && a.csv.is_none() {
        bail!("nothing to export: give --mcap FILE and/or --csv DIR");
    }
    let file_len = std::fs::metadata(&a.log).map(|m| m.len()).unwrap_or(0);
    let mut damaged = false;
    let outputs: [(Option<&PathBuf>, bool); 2] = [(a.mcap.as_ref(), true), (a.csv.as_ref(), false)];
    for (path, mcap) in outputs {
        let Some(path) = path else { continue };
        // CSV files list the frames but do not hold their pixels: skip them unread.
        let reader = sim_host::flightlog::open_log(&a.log)?;
        let header = reader.header.clone();
        let bar = progress_bar(
            file_len.max(1),
            "{spinner} exporting [{bar:40}] {bytes}/{total_bytes} ({elapsed} elapsed)",
        );
        let mut count = 0u64;
        let items = ProgressItems { inner: reader, bar: &bar, count: &mut count };
        let s = if mcap {
            sim_host::export::export_mcap(&header, items, path)?
        } else {
            sim_host::export::export_csv(&header, items, path)?
        };
        bar.finish_and_clear();
        let total: u64 = s.messages.values().sum();
        eprintln!("wrote {} ({} topics, {total} messages)", path.display(), s.messages.len());
        for (topic, n) in &s.messages {
            eprintln!("  {topic:<22} {n}");
        }
        for d in &s.damage {
            eprintln!("damaged record {d} (skipped)");
        }
        damaged |= !s.damage.is_empty();
    }
    Ok(if damaged { ExitCode::from(1) } else { ExitCode::SUCCESS })
}

/// A progress bar of `len` steps with a template.
fn progress_bar(len: u64, template: &str) -> ProgressBar {
    let bar = ProgressBar::new(len);
    bar.set_style(
        ProgressStyle::with_template(template)
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    bar
}

/// Log records with a progress bar on their byte offsets.
struct ProgressItems<'a, R: std::io::BufRead> {
    inner: sim_host::flightlog::LogReader<R>,
    bar: &'a ProgressBar,
    count: &'a mut u64,
}

impl<R: std::io::BufRead> Iterator for ProgressItems<'_, R> {
    type Item = sim_host::flightlog::LogItem;
    fn next(&mut self) -> Option<Self::Item> {
        let item = self.inner.next();
        *self.count += 1;
        if self.count.is_multiple_of(4096) {
            self.bar.set_position(self.inner.offset() as u64);
        }
        item
    }
}

/// A real-time factor for people: "450x", "2.3x", "0.27x".
fn rtf_text(rtf: f64) -> String {
    if rtf >= 10.0 {
        format!("{rtf:.0}x")
    } else if rtf >= 1.0 {
        format!("{rtf:.1}x")
    } else {
        format!("{rtf:.2}x")
    }
}
