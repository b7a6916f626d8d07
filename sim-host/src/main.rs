//! `sim-host`: render camera frames, run the vision, fly the paper's experiment in simulation.
//!
//! Exit codes: 0 success; 1 bad input or option (message on stderr); 2 the frame has no target; 3 the
//! simulated vehicle crashed.
use anyhow::{Context, Result, bail};
use clap::{Args, Parser, Subcommand, ValueEnum};
use geometry::frames::Attitude;
use geometry::{Vec3, deg};
use sim_host::Scenario;
use sim_host::imageio::{read_png_rgb, write_png_rgb};
use sim_host::render::ForwardRenderer;
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
        and faces the wall.\n\nExit codes: 0 success, 1 bad input or option, 2 no target in the frame, 3 the \
        simulated vehicle crashed."
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
}

#[derive(Clone, Copy, Debug, ValueEnum)]
enum CameraChoice {
    /// The forward camera, looking at the wall.
    Forward,
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
}

#[derive(Subcommand, Debug)]
enum VisionCommand {
    /// Position of the vehicle from one forward-camera frame: prints one JSON object.
    Pose(PoseArgs),
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

fn render(a: &RenderArgs) -> Result<ExitCode> {
    let scenario = Scenario::load(&a.scenario)?;
    let [x, y, z, roll, pitch, yaw] = parse_floats::<6>(&a.pose, "--pose")?;
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
    let _ = a.camera;
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

fn fly(a: &FlyArgs) -> Result<ExitCode> {
    use indicatif::{ProgressBar, ProgressStyle};
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
    let opts = FlyOptions {
        scenario,
        seed: a.seed,
        duration_s: a.duration,
        camera,
        out: a.out.clone(),
        plots: !a.no_plots,
    };
    let bar = ProgressBar::new(1000);
    bar.set_style(
        ProgressStyle::with_template("{spinner} flying [{bar:40}] {msg} ({elapsed} elapsed)")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    let result = fly(&opts, |t, end| {
        bar.set_position((t / end * 1000.0).min(1000.0) as u64);
        bar.set_message(format!("{t:.1} s simulated"));
    })?;
    bar.finish_and_clear();
    let st = &result.stats;
    eprintln!(
        "{} s simulated in {:.1} s ({:.0}x real time), {} sweep passes, {}",
        format_args!("{:.1}", st.sim_time_s),
        result.wall_time_s,
        st.sim_time_s / result.wall_time_s.max(1e-9),
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
        Command::Fly(a) => fly(a),
    };
    match result {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::from(1)
        }
    }
}
