//! `sim-host configure`: a scenario's flight configuration uploaded to a vehicle on the ground.
use anyhow::{Context, Result};
use clap::Args;
use sim_host::Scenario;
use sim_host::station::configure::{UploadOptions, upload};
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

#[derive(Args, Debug)]
pub(crate) struct ConfigureArgs {
    /// The radio: `serial:DEVICE:BAUD` (a SiK-type radio at 57600, the board's USART at 115200, 8N1) or
    /// `tcp:HOST:PORT`.
    #[arg(long, value_name = "serial:DEV:BAUD|tcp:HOST:PORT")]
    pub(crate) link: String,
    /// The scenario whose flight configuration is uploaded (a name or a TOML file): the flight parameters
    /// (gains, limits, estimator, failsafes, RC, battery), the forward camera and the line, the use of the
    /// flow. Checked here with the flight stack's own checks before anything is sent.
    #[arg(long, default_value = "paper")]
    pub(crate) scenario: String,
    /// The forward camera's calibration (OpenCV/ROS camera_info YAML or Kalibr/EuRoC sensor.yaml), instead of
    /// the scenario's camera.
    #[arg(long, value_name = "FILE")]
    pub(crate) calib_forward: Option<PathBuf>,
    /// The radio's key (`sim-host keygen`), the vehicle's too.
    #[arg(long, value_name = "FILE", conflicts_with = "no_key")]
    pub(crate) key: Option<PathBuf>,
    /// An unauthenticated radio, for development only.
    #[arg(long)]
    pub(crate) no_key: bool,
    /// How long to wait for the handshake's answer and for the vehicle's answer to each try (s); storing
    /// the set erases a flash sector on the board (about a second).
    #[arg(long, default_value_t = 5.0)]
    pub(crate) answer_timeout: f64,
    /// How many times the whole upload is sent when no answer comes (a piece lost on the radio).
    #[arg(long, default_value_t = 3)]
    pub(crate) tries: u32,
}

pub(crate) fn configure(a: &ConfigureArgs) -> Result<ExitCode> {
    let mut scenario = Scenario::load(&a.scenario)?;
    if let Some(path) = &a.calib_forward {
        super::station::apply_calibration(&mut scenario, path)?;
    }
    let cfg = scenario.flight_config();
    let key = match (&a.key, a.no_key) {
        (Some(f), _) => Some(sim_host::link_key::read_key(f).context("--key")?),
        (None, true) => None,
        (None, false) => anyhow::bail!(
            "give --key FILE (`sim-host keygen --out FILE`, the vehicle's key) or, for development only, --no-key"
        ),
    };
    anyhow::ensure!(
        a.answer_timeout.is_finite() && a.answer_timeout > 0.0,
        "--answer-timeout must be a positive number of seconds, not {}",
        a.answer_timeout
    );
    let spec = ground_station::link::LinkSpec::parse(&a.link).map_err(|e| anyhow::anyhow!("--link {e}"))?;
    let link = ground_station::link::open(&spec, Duration::from_millis(5))
        .map_err(|e| anyhow::anyhow!("--link: {e}"))?;
    let opts = UploadOptions { key, answer_timeout_s: a.answer_timeout, tries: a.tries };
    let up = upload(link, &cfg, &opts, |line| eprintln!("{line}"))?;
    let stored = match up.ack.outcome {
        protocol::ConfigOutcome::Applied { saved_sequence: Some(s) } => {
            format!("stored in its flash as set {s}: it is loaded at the next boot")
        }
        _ => "NOT stored (its log says why): it lasts until the power goes".to_string(),
    };
    println!(
        "the vehicle applied the configuration of `{}` ({} bytes, {} pieces, CRC-32 {:08x}, try {}) and {stored}",
        a.scenario, up.bytes, up.pieces, up.ack.crc32, up.tries
    );
    Ok(ExitCode::SUCCESS)
}
