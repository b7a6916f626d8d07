//! `sim-host render`: the frame a camera sees.
use super::common::parse_floats;
use anyhow::{Context, Result, bail};
use clap::{Args, ValueEnum};
use geometry::frames::Attitude;
use geometry::{Vec3, deg};
use sim_host::Scenario;
use sim_host::imageio::{write_png_gray, write_png_rgb};
use sim_host::render::{DownPose, DownRenderer, ForwardRenderer};
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Clone, Copy, Debug, ValueEnum, PartialEq, Eq)]
pub(crate) enum CameraChoice {
    /// The forward camera, looking at the wall (RGB).
    Forward,
    /// The downward camera, looking at the floor (grey), for optical flow.
    Down,
}

#[derive(Args, Debug)]
pub(crate) struct RenderArgs {
    /// Which camera.
    #[arg(long, value_enum, default_value = "forward")]
    pub(crate) camera: CameraChoice,
    /// Vehicle pose X,Y,Z,ROLL,PITCH,YAW: position in metres (world frame), angles in degrees.
    #[arg(long, allow_hyphen_values = true, value_name = "X,Y,Z,ROLL,PITCH,YAW")]
    pub(crate) pose: String,
    /// Output PNG file.
    #[arg(long)]
    pub(crate) out: PathBuf,
    /// Scenario: a built-in name (`paper`, `webcam`) or a TOML file.
    #[arg(long, default_value = "paper")]
    pub(crate) scenario: String,
    /// Seed of the sensor noise.
    #[arg(long, default_value_t = 0)]
    pub(crate) seed: u64,
    /// Illumination gain (default: the scenario's).
    #[arg(long)]
    pub(crate) light_gain: Option<f64>,
    /// Illumination gradient per metre along the wall's x and z, as GX,GZ (default: the scenario's).
    #[arg(long, allow_hyphen_values = true, value_name = "GX,GZ")]
    pub(crate) light_gradient: Option<String>,
    /// Sensor noise in grey levels (default: the scenario's).
    #[arg(long)]
    pub(crate) noise: Option<f64>,
    /// Gaussian blur in pixels (default: the scenario's).
    #[arg(long)]
    pub(crate) blur: Option<f64>,
    /// Downward camera: vehicle velocity VX,VY,VZ in m/s (world frame) during the exposure (motion blur).
    #[arg(long, allow_hyphen_values = true, value_name = "VX,VY,VZ")]
    pub(crate) velocity: Option<String>,
    /// Downward camera: body angular rates WX,WY,WZ in deg/s during the exposure (motion blur).
    #[arg(long, allow_hyphen_values = true, value_name = "WX,WY,WZ")]
    pub(crate) rates: Option<String>,
    /// Downward camera: exposure time in seconds (default: the scenario's).
    #[arg(long)]
    pub(crate) exposure_time: Option<f64>,
}
pub(crate) fn render_down(a: &RenderArgs, scenario: &Scenario, pose: [f64; 6]) -> Result<ExitCode> {
    let [x, y, z, roll, pitch, yaw] = pose;
    let renderer = DownRenderer::new(scenario)?;
    let mut settings = renderer.default_settings();
    settings.seed = a.seed;
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

/// The scenario with the options that override its values, validated as a scenario: an option has the same
/// limit as the field it sets (docs/parameters.md, "Simulator values"), and a refusal names both.
pub(crate) fn with_overrides(a: &RenderArgs, mut scenario: Scenario) -> Result<Scenario> {
    let down = a.camera == CameraChoice::Down;
    let mut set = Vec::new();
    if let Some(g) = a.light_gain {
        scenario.scene.light_gain = g;
        set.push(format!("--light-gain {g} sets scene.light_gain"));
    }
    if let Some(g) = &a.light_gradient {
        scenario.scene.light_gradient_per_m = parse_floats::<2>(g, "--light-gradient")?;
        set.push(format!("--light-gradient {g} sets scene.light_gradient_per_m"));
    }
    let camera = if down { "down_camera" } else { "forward_camera" };
    if let Some(n) = a.noise {
        if down {
            scenario.down_camera.noise_sigma = n
        } else {
            scenario.forward_camera.noise_sigma = n
        }
        set.push(format!("--noise {n} sets {camera}.noise_sigma"));
    }
    if let Some(b) = a.blur {
        if down {
            scenario.down_camera.blur_sigma_px = b
        } else {
            scenario.forward_camera.blur_sigma_px = b
        }
        set.push(format!("--blur {b} sets {camera}.blur_sigma_px"));
    }
    if let Some(e) = a.exposure_time {
        scenario.down_camera.exposure_time_s = e;
        set.push(format!("--exposure-time {e} sets down_camera.exposure_time_s"));
    }
    if !set.is_empty() {
        scenario.validate().with_context(|| set.join(", "))?;
    }
    Ok(scenario)
}

pub(crate) fn render(a: &RenderArgs) -> Result<ExitCode> {
    sim_host::files::refuse_overwrite(&a.out, &[std::path::Path::new(&a.scenario)])?;
    let scenario = Scenario::load(&a.scenario)?;
    let pose = parse_floats::<6>(&a.pose, "--pose")?;
    // A vehicle in the room: positions within 100 m of the origin, angles within one turn (a pose far outside
    // used to render a black frame with exit 0).
    if pose[..3].iter().any(|v| v.abs() > 100.0) || pose[3..].iter().any(|v| v.abs() > 360.0) {
        bail!("--pose: X,Y,Z must lie within 100 m of the origin and ROLL,PITCH,YAW within +-360 deg");
    }
    if a.camera == CameraChoice::Down {
        if a.light_gradient.is_some() {
            bail!(
                "--light-gradient applies to the forward camera (the floor takes the scenario's gradient along x)"
            );
        }
        return render_down(a, &with_overrides(a, scenario)?, pose);
    }
    if a.velocity.is_some() || a.rates.is_some() || a.exposure_time.is_some() {
        bail!(
            "--velocity, --rates and --exposure-time model the downward camera's motion blur (--camera down)"
        );
    }
    let scenario = with_overrides(a, scenario)?;
    let [x, y, z, roll, pitch, yaw] = pose;
    let renderer = ForwardRenderer::new(&scenario)?;
    let mut settings = renderer.default_settings();
    settings.seed = a.seed;
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
