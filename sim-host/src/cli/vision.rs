//! `sim-host vision`: the ground station's vision on recorded frames.
use super::common::parse_floats;
use anyhow::{Context, Result, bail};
use clap::{Args, Subcommand, ValueEnum};
use geometry::{Vec3, deg};
use sim_host::Scenario;
use sim_host::downward::{GroundFlow, flow_json, no_flow_json};
use sim_host::imageio::{GrayImage, read_image_gray, read_image_rgb, write_png_rgb};
use sim_host::vision::{GroundVision, PoseMethod, draw_overlay, no_target_json, pose_json};
use std::path::PathBuf;
use std::process::ExitCode;
use vision_core::AttitudeSource;

#[derive(Subcommand, Debug)]
pub(crate) enum VisionCommand {
    /// Pose of the forward camera (its centre and rotation in the wall's frame) from one frame: prints one JSON
    /// object.
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
pub(crate) struct FlowArgs {
    /// The earlier frame (PNG or JPEG; colour is converted to grey).
    #[arg(long)]
    pub(crate) prev: PathBuf,
    /// The later frame.
    #[arg(long)]
    pub(crate) next: PathBuf,
    /// Time between the frames in seconds.
    #[arg(long, allow_hyphen_values = true)]
    pub(crate) dt: Option<f64>,
    /// Body angular rates WX,WY,WZ in rad/s over the interval (x forward, y left, z up): removes the rotation's
    /// flow and seeds the tracking. Needs --dt.
    #[arg(long, allow_hyphen_values = true, value_name = "WX,WY,WZ")]
    pub(crate) gyro: Option<String>,
    /// Distance from the camera to the floor along the optical axis, in metres. With --dt, gives the velocity.
    #[arg(long, allow_hyphen_values = true)]
    pub(crate) range: Option<f64>,
    /// Scenario: a built-in name (`paper`, `webcam`) or a TOML file (the downward camera's intrinsics and mount).
    #[arg(long, default_value = "paper")]
    pub(crate) scenario: String,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
pub(crate) enum MethodChoice {
    /// Closed form refined by minimising the reprojection error.
    Refined,
    /// Closed form only (vanishing points, least-squares translation).
    ClosedForm,
    /// The paper's closed form (vanishing points, depth from the line's height).
    Paper,
}

#[derive(Args, Debug)]
pub(crate) struct PoseArgs {
    /// The frame (PNG, RGB or RGBA; or JPEG, as webcams deliver).
    #[arg(long)]
    pub(crate) image: PathBuf,
    /// Roll and pitch of the vehicle from the IMU, in degrees: selects the IMU-aided solver.
    #[arg(long, allow_hyphen_values = true, value_name = "ROLL,PITCH")]
    pub(crate) attitude: Option<String>,
    /// Standard deviation of the IMU roll and pitch, in degrees.
    #[arg(long, default_value_t = 0.5)]
    pub(crate) attitude_sigma: f64,
    /// Scenario: a built-in name (`paper`, `webcam`) or a TOML file (camera and line).
    #[arg(long, default_value = "paper")]
    pub(crate) scenario: String,
    /// Solver.
    #[arg(long, value_enum, default_value = "refined")]
    pub(crate) method: MethodChoice,
    /// Also write the frame with the measured edges and corners drawn on it.
    #[arg(long)]
    pub(crate) overlay: Option<PathBuf>,
}
pub(crate) fn vision_pose(a: &PoseArgs) -> Result<ExitCode> {
    if let Some(overlay) = &a.overlay {
        sim_host::files::refuse_overwrite(overlay, &[&a.image, std::path::Path::new(&a.scenario)])?;
    }
    let scenario = Scenario::load(&a.scenario)?;
    let mut img = read_image_rgb(&a.image).with_context(|| format!("{}", a.image.display()))?;
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

pub(crate) fn vision_flow(a: &FlowArgs) -> Result<ExitCode> {
    let scenario = Scenario::load(&a.scenario)?;
    let cam = scenario.down_camera_model();
    let load = |p: &PathBuf| -> Result<GrayImage> {
        let img = read_image_gray(p).with_context(|| format!("{}", p.display()))?;
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
        && !(dt.is_finite() && (1e-4..=1.0).contains(&dt))
    {
        // Between two frames of a camera: from 10 kHz to 1 Hz (a shorter interval turns pixel noise into
        // absurd speeds).
        bail!("--dt must lie in [1e-4, 1] s (the interval between the two frames)");
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
            println!("{}", flow_json(&stats, cam.fx, velocity));
            Ok(ExitCode::SUCCESS)
        }
        Err(why) => {
            println!("{}", no_flow_json(why, flow.repetition(), &flow.last_counts(), flow.params()));
            Ok(ExitCode::from(2))
        }
    }
}
