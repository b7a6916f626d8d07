//! Software in the loop: the flight stack (the same code as the firmware) flies the simulated quadrotor.
//!
//! Lockstep at the physics step (1 ms by default): each step integrates the model (RK4) with the rotor
//! commands held, samples the IMU, the magnetometer and, at the camera rate, the forward camera. The ground
//! station measures each frame (full rendered image through vision-core's detector, or the analytic
//! projection with edge noise) and sends the measurement over a link with latency and jitter; operator
//! commands and heartbeats go the same way. At the downward camera's rate it renders the floor (or projects
//! floor points analytically), computes the optical flow of each frame pair and sends its statistics. At the
//! control rate the flight computer's step runs with the IMU samples and the messages delivered since the last
//! step: the flight stack in this process, or the firmware in QEMU ([`crate::fil`]), which compute the same
//! bits. A run is a pure function of (scenario, seed, camera mode).
use crate::downward::{CamPose, GroundFlow, analytic_flow};
use crate::fil::{QemuFc, QemuOptions};
use crate::flightlog::LogRecord;
use crate::imageio::FrameImages;
use crate::mavlink_endpoint::{GroundRequest, MavlinkEndpoint};
use crate::model::{ModelParams, Quadrotor, quat_to_mat};
use crate::render::{DownPose, DownRenderer, ForwardRenderer};
use crate::rng::{SimRng, splitmix64};
use crate::scenario::FaultKind;
use crate::scenario::Scenario;
use crate::sensors::{ImuFaults, ImuModel};
use crate::vision::GroundVision;
use anyhow::Result;
use control_core::FlightMode;
use control_core::estimator::ImuSample;
use flight_core::flow::FlowOutcome;
use flight_core::{FlightStack, StepInput, StepReport};
use geometry::frames::Attitude;
use geometry::{Mat3, Vec2, Vec3};
use protocol::{FlowMeasurement, Uplink, VisionMeasurement};
use std::collections::VecDeque;
use vision_core::observation::LineObservation;
use vision_core::observation::project_observation;
use vision_core::observation::within_detector_limits;

/// How the forward camera is simulated.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CameraMode {
    /// Rendered images through the full vision pipeline.
    Rendered,
    /// The line's edges projected analytically, with edge noise (fast).
    Analytic,
}

impl CameraMode {
    /// Name used in files and reports.
    pub fn name(self) -> &'static str {
        match self {
            CameraMode::Rendered => "rendered",
            CameraMode::Analytic => "analytic",
        }
    }
}

/// Which flight computer flies.
#[derive(Clone, Debug)]
pub enum FcChoice {
    /// The flight stack compiled into this process (software in the loop).
    Sil,
    /// The firmware ELF in QEMU (firmware in the loop).
    Qemu(QemuOptions),
}

enum Fc {
    Sil(Box<FlightStack>),
    Qemu(Box<QemuFc>),
}

/// The firmware's cost per control step (firmware in the loop).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct FcCost {
    /// Steps measured.
    pub steps: u64,
    /// Instructions per step, mean.
    pub mean_instructions: f64,
    /// Instructions per step, largest.
    pub max_instructions: u32,
    /// Simulated time of the largest (s).
    pub max_at_s: f64,
    /// Pose solves the background work ran (frames).
    pub solves: u64,
    /// Instructions per pose solve, mean over the background runs (one frame each, mostly).
    pub solve_mean_instructions: f64,
    /// Instructions of the largest background run after one step.
    pub background_max_instructions: u32,
    /// Simulated time of the largest background run (s).
    pub background_max_at_s: f64,
    /// Share of the core the background work took over the flight (at one instruction per cycle, 168 MHz).
    pub background_cpu_share: f64,
    /// Share of the core the control steps took.
    pub step_cpu_share: f64,
    /// The firmware's stack report (`stack: used=.. of .. bytes, free=..`), when it gave one.
    pub stack_report: Option<String>,
}

/// One recorded instant (at the record rate).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Record {
    /// Time (s).
    pub t_s: f64,
    /// True position (m).
    pub true_p: [f64; 3],
    /// True velocity (m/s).
    pub true_v: [f64; 3],
    /// True roll, pitch, yaw (rad, from facing the wall).
    pub true_att: [f64; 3],
    /// Estimated position (m).
    pub est_p: [f32; 3],
    /// Estimated velocity (m/s).
    pub est_v: [f32; 3],
    /// Estimated roll, pitch, yaw (rad).
    pub est_att: [f32; 3],
    /// Desired position (m).
    pub des_p: [f32; 3],
    /// Desired velocity (m/s).
    pub des_v: [f32; 3],
    /// Commanded rotor speeds (rad/s).
    pub motor_cmd: [f32; 4],
    /// Actual rotor speeds (rad/s).
    pub motor: [f64; 4],
    /// Flight mode.
    pub mode: FlightMode,
    /// Age of the last accepted vision fix (s; infinite before the first).
    pub fix_age_s: f32,
    /// The estimator's roll and pitch standard deviation (rad).
    pub tilt_std_rad: f32,
}

/// One optical-flow velocity the flight code measured, against the truth (world frame).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FlowRecord {
    /// Mid-time of the frame pair (s).
    pub t_s: f64,
    /// Measured horizontal velocity, world x and y (m/s).
    pub measured: [f64; 2],
    /// True mean velocity over the frame pair, world x and y (m/s).
    pub truth: [f64; 2],
    /// Standard deviation the flight code gave it (m/s).
    pub std_m_s: f64,
}

/// Per-axis accumulator of squared errors.
#[derive(Clone, Copy, Debug, Default)]
struct Rms {
    sum: [f64; 3],
    n: u64,
}

impl Rms {
    fn add(&mut self, e: [f64; 3]) {
        for i in 0..3 {
            self.sum[i] += e[i] * e[i];
        }
        self.n += 1;
    }
    fn get(&self) -> [f64; 3] {
        if self.n == 0 { [f64::NAN; 3] } else { self.sum.map(|s| (s / self.n as f64).sqrt()) }
    }
}

/// The simulated battery of a run.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct BatteryStats {
    /// State of charge at the end (0-1).
    pub final_charge: f64,
    /// The lowest terminal voltage (V).
    pub min_voltage_v: f64,
}

/// What a run measured.
#[derive(Clone, Debug, Default)]
pub struct RunStats {
    /// Simulated time (s).
    pub sim_time_s: f64,
    /// Whether the vehicle crashed (tilt beyond 80 deg, hard touchdown, hit the wall or the floor).
    pub crashed: bool,
    /// Why, when it crashed.
    pub crash_reason: Option<String>,
    /// True minus desired position over the tracking phase, RMS per axis (m).
    pub rms_error_m: [f64; 3],
    /// Estimated minus true position over the tracking phase, RMS per axis (m).
    pub estimate_rms_error_m: [f64; 3],
    /// Largest true tilt while airborne (deg).
    pub max_tilt_deg: f64,
    /// Duration of the tracking phase (s).
    pub tracking_s: f64,
    /// Sweep passes completed.
    pub passes_done: u16,
    /// Forward-camera frames captured.
    pub frames: u32,
    /// Frames whose pose the vehicle solved.
    pub frames_solved: u32,
    /// Frames without the line.
    pub frames_no_target: u32,
    /// Rendered frames in which the ground station's detector found no line, by the detector's reason.
    pub ground_no_target: crate::vision::NoTargetCounts,
    /// Analytic frames without a measurement: the line hidden (`scene.line_visible = false`), out of view, or
    /// outside what the detector would report.
    pub analytic_not_in_view: u64,
    /// Frames the vehicle rejected.
    pub frames_rejected: u32,
    /// Frames the vehicle refused as repeats of the one before (a frozen camera).
    pub frames_frozen: u32,
    /// Failsafes that acted, in order: time (s) and which (`VisionLost`, ...).
    pub failsafes: Vec<(f64, String)>,
    /// Whether a rotor came within reach of the wall (the centre closer than the arm and a rotor radius).
    pub wall_contact: bool,
    /// The closest the vehicle's centre came to the wall (m).
    pub min_wall_distance_m: f64,
    /// Uplink messages lost to a `link_loss` or `link_corruption` fault.
    pub link_dropped: u64,
    /// The estimator's counters at the end (rejections by source).
    pub estimator: control_core::estimator::EstimatorCounters,
    /// The estimator's wind at the end (world x, y; m/s).
    pub wind_estimate_m_s: Option<[f32; 2]>,
    /// The flight code's last rotor-speed commands (rad/s).
    pub last_motor_cmd: [f32; 4],
    /// Largest tilt error of the estimate while tracking (deg).
    pub max_tilt_error_deg: f64,
    /// RMS tilt error of the estimate while tracking (deg).
    pub tilt_error_rms_deg: f64,
    /// Modes visited, with the time each began (s).
    pub modes: Vec<(f64, String)>,
    /// Whether the run ended landed and disarmed.
    pub landed: bool,
    /// Fastest touchdown (m/s).
    pub max_touchdown_speed_m_s: f64,
    /// The simulated battery at the end, when the scenario has one.
    pub battery: Option<BatteryStats>,
    /// Whether the vehicle has the downward camera.
    pub flow_camera: bool,
    /// Downward-camera frames captured.
    pub down_frames: u32,
    /// Flow measurements the flight code received, and what became of them.
    pub flow: flight_core::flow::FlowCounters,
    /// Flow velocities the estimator accepted and rejected (innovation gate).
    pub flow_fused: [u32; 2],
    /// Flow velocity minus the true mean velocity of its frame pair, RMS over world x and y while airborne
    /// (m/s; NaN without flow).
    pub flow_rms_error_m_s: [f64; 2],
    /// The firmware's cost per step, when the firmware flew.
    pub fc_cost: Option<FcCost>,
    /// Why the flight computer stopped answering, if it did (the run ends there).
    pub fc_error: Option<String>,
}

/// A software-in-the-loop run in progress.
pub struct Sil {
    scenario: Scenario,
    seed: u64,
    mode: CameraMode,
    quad: Quadrotor,
    fc: Option<Fc>,
    motor_log: Option<Vec<[u32; 4]>>,
    flight_log: Option<crate::flightlog::LogWriter>,
    log_frames: crate::flightlog::FramePolicy,
    log_downlinks: flight_core::telemetry::DownlinkSchedule,
    log_error: Option<String>,
    cost_sum: f64,
    background_sum: f64,
    imu: ImuModel,
    wind: crate::wind::Wind,
    wind_now: [f64; 3],
    fault_rng: SimRng,
    /// The frame a frozen camera repeats (`vision_freeze`).
    frozen_observation: Option<Option<vision_core::LineObservation>>,
    /// Uplink messages lost to `link_loss` or `link_corruption`.
    link_dropped: u64,
    tilt_err: Rms,
    renderer: Option<std::sync::Arc<ForwardRenderer>>,
    /// The ground station's line detector; away on the pool while `forward_job` measures a frame.
    vision: Option<GroundVision>,
    /// A forward frame being rendered and measured while the simulation goes on (`camera_worker`).
    forward_job: Option<crate::camera_worker::ForwardJob>,
    /// Forward frames measured on the pool while the simulation went on.
    pipelined_frames: u64,
    /// The buffer the pipelined forward frames are rendered into, between frames.
    forward_buffer: Option<crate::imageio::RgbImage>,
    down_renderer: Option<std::sync::Arc<DownRenderer>>,
    /// The ground station's flow tracker; away on the pool while `down_job` measures a frame.
    ground_flow: Option<GroundFlow>,
    /// A downward frame being rendered and measured while the simulation goes on (`camera_worker`).
    down_job: Option<crate::camera_worker::DownJob>,
    /// Downward frames measured on the pool while the simulation went on.
    pipelined_down_frames: u64,
    down_rng: SimRng,
    down_index: u64,
    next_down_us: u64,
    prev_down: Option<(u64, CamPose, [f64; 3], [f64; 4])>,
    flow_truth: VecDeque<(u64, [[f64; 3]; 3], [f64; 3])>,
    flow_records: Vec<FlowRecord>,
    flow_err: Rms,
    link: VecDeque<(u64, Uplink)>,
    link_rng: SimRng,
    edge_rng: SimRng,
    t_us: u64,
    dt_us: u64,
    imu_every: u64,
    ctrl_every: u64,
    mag_every: u64,
    record_every: u64,
    step_count: u64,
    frame_index: u64,
    next_frame_us: u64,
    next_heartbeat_us: u64,
    pending_imu: Vec<ImuSample>,
    pending_mag: Option<Vec3>,
    pending_baro: Option<f32>,
    /// Physics steps between barometer readings (`None`: the vehicle has no barometer).
    baro_every: Option<u64>,
    motor_cmd: [f32; 4],
    last_out: Option<StepReport>,
    records: Vec<Record>,
    stats: RunStats,
    tracking: Rms,
    estimate: Rms,
    tracking_since: Option<f64>,
    /// The ground station's operator (the mission's script).
    operator: ground_station::operator::Operator,
    /// The simulated pilot's transmitter and the vehicle's receiver, when the scenario has them.
    transmitter: Option<crate::transmitter::Transmitter>,
    /// The simulated flight battery, when the scenario has one, and its last reading not yet stepped on.
    power: Option<crate::power::Power>,
    pending_battery: Option<control_core::battery::BatteryReading>,
    /// Downlink messages on their way to the ground station, with their arrival times.
    downlink_queue: VecDeque<(u64, protocol::Downlink)>,
    /// The last telemetry the ground station received.
    station_telemetry: Option<protocol::Telemetry>,
    was_airborne: bool,
    done_at: Option<u64>,
    last_failsafe: Option<control_core::Failsafe>,
    /// A separate ground station's ports (the virtual vehicle): when set, the cameras' frames and the
    /// downlink go out through them and no ground station runs in this process.
    ports: Option<StationPorts>,
    /// A ground control station beside the in-process station (`fly --mavlink`).
    ground_hook: Option<Box<dyn GroundHook + Send>>,
    /// Whoever watches the flight as it happens (`fly --live`).
    tap: Option<Box<dyn FlightTap>>,
}

/// Whoever watches a flight as it happens (the live view, `crate::live`): the records the flight log gets,
/// as it gets them (with or without a log), and the rendered cameras' frames with what the in-process
/// ground station's vision made of them. Implementations hand the work to another thread: these are called
/// on the simulation's.
pub trait FlightTap: Send {
    /// Records of the flight, in the log's order (`crate::flightlog`).
    fn records(&mut self, records: &[LogRecord]);
    /// A forward frame captured at `t_us` and the ground station's detection in it (None: no line found, or
    /// a separate station detects).
    fn forward_frame(
        &mut self,
        t_us: u64,
        img: &crate::imageio::RgbImage,
        detection: Option<&LineObservation>,
    );
    /// A downward frame captured at `t_us` and the tracks of the pair it ends (position px, displacement px,
    /// inlier).
    fn down_frame(&mut self, t_us: u64, img: &crate::imageio::GrayImage, tracks: &[(Vec2, Vec2, bool)]);
}

/// A ground control station beside the in-process ground station (`sim-host fly --mavlink`): it sees what came
/// down the radio, when the station does, and what it asks goes up the radio as the station's.
pub trait GroundHook {
    /// A message that came down the radio.
    fn downlink(&mut self, d: &protocol::Downlink);
    /// What the ground control station asks at `t_us` (the simulated clock, paced to the wall clock).
    fn poll(&mut self, t_us: u64) -> Result<Vec<GroundRequest>>;
    /// Ends it: what it counted.
    fn finish(self: Box<Self>) -> crate::mavlink_endpoint::MavlinkStats;
}

impl GroundHook for MavlinkEndpoint {
    fn downlink(&mut self, d: &protocol::Downlink) {
        MavlinkEndpoint::downlink(self, d);
    }

    fn poll(&mut self, t_us: u64) -> Result<Vec<GroundRequest>> {
        self.tick(t_us);
        MavlinkEndpoint::poll(self, t_us)
    }

    fn finish(self: Box<Self>) -> crate::mavlink_endpoint::MavlinkStats {
        MavlinkEndpoint::finish(*self)
    }
}

/// What a virtual vehicle exposes to a separate ground station, as a real one does: its cameras' frames and
/// its radio's downlink; the station's uplink comes in through [`Sil::uplink`]. Nothing else of the
/// simulator crosses.
#[derive(Default)]
pub struct StationPorts {
    /// Forward frames captured since they were last taken: (the vehicle's clock at capture (us), frame).
    pub forward: VecDeque<(u64, ground_station::stream::Frame)>,
    /// Downward frames, the same way.
    pub down: VecDeque<(u64, ground_station::stream::Frame)>,
    /// Downlink messages the vehicle sent.
    pub downlink: VecDeque<protocol::Downlink>,
}

/// Roll, pitch, yaw (from facing the wall) of a world-from-body rotation, in f64.
fn attitude_of(r: &[[f64; 3]; 3]) -> [f64; 3] {
    // R_NB = R_WN^T R_WB: rows of R_NB are (-row 1, row 0, row 2) of R_WB.
    let n = [[-r[1][0], -r[1][1], -r[1][2]], [r[0][0], r[0][1], r[0][2]], [r[2][0], r[2][1], r[2][2]]];
    let pitch = (-n[2][0]).clamp(-1.0, 1.0).asin();
    let roll = n[2][1].atan2(n[2][2]);
    let yaw = n[1][0].atan2(n[0][0]);
    [roll, pitch, yaw]
}

impl Sil {
    /// Prepares a run with the flight stack in this process.
    pub fn new(scenario: &Scenario, seed: u64, mode: CameraMode) -> Result<Self> {
        Self::with_fc(scenario, seed, mode, &FcChoice::Sil)
    }

    /// Prepares a run with the chosen flight computer. The firmware flies its built-in configuration
    /// (`FlightConfig::paper()`): a scenario whose flight code configuration differs is refused.
    pub fn with_fc(scenario: &Scenario, seed: u64, mode: CameraMode, fc: &FcChoice) -> Result<Self> {
        scenario.validate()?;
        if mode == CameraMode::Analytic {
            let fields = scenario.analytic_unmodelled();
            if !fields.is_empty() {
                anyhow::bail!(
                    "the analytic camera cannot honour {} (fly it with --camera rendered):\n  {}",
                    if fields.len() == 1 { "this field" } else { "these fields" },
                    fields.join("\n  ")
                );
            }
        }
        let m = &scenario.model;
        let mm = &scenario.mismatch;
        let mut params = ModelParams::from_vehicle(
            &scenario.vehicle,
            m.motor_time_constant_s * mm.motor_time_constant_scale,
            m.linear_drag_n_s_per_m,
            Some(scenario.trajectory.ground_height_m as f64),
        );
        // The simulated vehicle is not the configured one (the flight code keeps `[vehicle]`).
        params.mass_kg *= mm.mass_scale;
        for k in 0..3 {
            params.inertia[k] *= mm.inertia_scale[k];
        }
        params.k *= mm.thrust_coeff_scale;
        params.k_tau *= mm.drag_torque_coeff_scale;
        params.rotor_drag = m.rotor_drag_coeff;
        params.ground_effect_rotor_radius_m =
            (m.ground_effect_rotor_radius_m > 0.0).then_some(m.ground_effect_rotor_radius_m);
        let yaw = geometry::deg(m.start_yaw_deg as f32);
        let r0 = Attitude::new(0.0, 0.0, yaw).world_from_body();
        let q0 = geometry::Quat::from_mat3(&r0);
        let quad =
            Quadrotor::new(params, m.start_position_m, [q0.w as f64, q0.x as f64, q0.y as f64, q0.z as f64]);
        let fc = match fc {
            FcChoice::Sil => Fc::Sil(Box::new(
                FlightStack::new(scenario.flight_config()).map_err(|e| anyhow::anyhow!("{e}"))?,
            )),
            FcChoice::Qemu(opts) => {
                // The scenario's flight configuration goes up before the first step, as a station uploads one
                // on the ground (the firmware rebuilds its flight stack from it and stores it).
                let mut q = QemuFc::start(opts)?;
                anyhow::Context::with_context(q.configure(&scenario.flight_config()), || {
                    format!("uploading scenario `{}`'s flight configuration", scenario.name)
                })?;
                Fc::Qemu(Box::new(q))
            }
        };
        let dt_us = (m.physics_step_s * 1e6).round() as u64;
        let every = |hz: f64| ((1e6 / hz) / dt_us as f64).round() as u64;
        let renderer = match mode {
            CameraMode::Rendered => Some(std::sync::Arc::new(ForwardRenderer::new(scenario)?)),
            CameraMode::Analytic => None,
        };
        let down = scenario.down_camera.enabled;
        let down_renderer = match mode {
            CameraMode::Rendered if down => Some(std::sync::Arc::new(DownRenderer::new(scenario)?)),
            _ => None,
        };
        Ok(Self {
            scenario: scenario.clone(),
            seed,
            mode,
            quad,
            fc: Some(fc),
            motor_log: None,
            flight_log: None,
            log_frames: crate::flightlog::FramePolicy::Drop,
            log_downlinks: flight_core::telemetry::DownlinkSchedule::new(),
            log_error: None,
            cost_sum: 0.0,
            background_sum: 0.0,
            imu: ImuModel::new(
                &scenario.imu,
                seed,
                scenario.mismatch.imu_misalignment_deg,
                params.hover_speed(),
            ),
            wind: crate::wind::Wind::new(&scenario.wind, seed),
            wind_now: [0.0; 3],
            fault_rng: SimRng::stream(seed, "link-faults"),
            frozen_observation: None,
            link_dropped: 0,
            tilt_err: Rms::default(),
            renderer,
            vision: Some(GroundVision::new(scenario)),
            forward_job: None,
            pipelined_frames: 0,
            forward_buffer: None,
            down_renderer,
            ground_flow: down.then(|| GroundFlow::new(scenario)),
            down_job: None,
            pipelined_down_frames: 0,
            down_rng: SimRng::stream(seed, "down-camera"),
            down_index: 0,
            next_down_us: 0,
            prev_down: None,
            flow_truth: VecDeque::new(),
            flow_records: Vec::new(),
            flow_err: Rms::default(),
            link: VecDeque::new(),
            link_rng: SimRng::stream(seed, "link-jitter"),
            edge_rng: SimRng::stream(seed, "analytic-edges"),
            t_us: 0,
            dt_us,
            imu_every: every(scenario.imu.rate_hz),
            ctrl_every: every(scenario.mission.control_rate_hz),
            mag_every: every(scenario.imu.mag_rate_hz),
            record_every: every(100.0).max(1),
            step_count: 0,
            frame_index: 0,
            next_frame_us: 0,
            next_heartbeat_us: 0,
            pending_imu: Vec::with_capacity(8),
            pending_mag: None,
            pending_baro: None,
            baro_every: (scenario.imu.baro_rate_hz > 0.0).then(|| every(scenario.imu.baro_rate_hz).max(1)),
            motor_cmd: [0.0; 4],
            last_out: None,
            records: Vec::new(),
            stats: RunStats { flow_camera: down, min_wall_distance_m: f64::INFINITY, ..RunStats::default() },
            tracking: Rms::default(),
            estimate: Rms::default(),
            tracking_since: None,
            operator: ground_station::operator::Operator::new(ground_station::operator::MissionScript {
                arm_at_s: scenario.mission.arm_at_s,
                takeoff_at_s: scenario.mission.takeoff_at_s,
                track_after_hover_s: scenario.mission.track_after_hover_s,
                land_when_done: scenario.mission.land_when_done,
                sweep: true,
            }),
            transmitter: crate::transmitter::Transmitter::new(&scenario.transmitter, scenario.rc.channel_map),
            power: crate::power::Power::new(
                &scenario.battery_model,
                scenario.vehicle.motor_speed_max_rad_s as f64,
                seed,
            ),
            pending_battery: None,
            downlink_queue: VecDeque::new(),
            station_telemetry: None,
            was_airborne: false,
            done_at: None,
            last_failsafe: None,
            ports: None,
            ground_hook: None,
            tap: None,
        })
    }

    /// Lets `tap` watch the flight as it happens ([`FlightTap`]).
    pub fn set_tap(&mut self, tap: Box<dyn FlightTap>) {
        self.tap = Some(tap);
    }

    /// The tap, taken back (to end it).
    pub fn take_tap(&mut self) -> Option<Box<dyn FlightTap>> {
        self.tap.take()
    }

    /// Lets a ground control station command the vehicle through the in-process station ([`GroundHook`]),
    /// in place of the mission's script (the operator's script is `manual`: nothing is sent unless it asks).
    pub fn set_ground_hook(&mut self, hook: Box<dyn GroundHook + Send>) {
        self.operator =
            ground_station::operator::Operator::with_script(ground_station::operator::Script::Manual);
        self.ground_hook = Some(hook);
    }

    /// The ground control station's hook, taken back.
    pub fn take_ground_hook(&mut self) -> Option<Box<dyn GroundHook + Send>> {
        self.ground_hook.take()
    }

    /// Serves a separate ground station ([`StationPorts`]): the frames and the downlink leave through the
    /// ports, the uplink comes through [`Sil::uplink`], and neither the vision nor the operator runs here.
    /// Rendered cameras only (a station needs images).
    pub fn serve_station(&mut self) -> Result<()> {
        if self.mode != CameraMode::Rendered {
            anyhow::bail!("a separate ground station needs images: fly with --camera rendered");
        }
        self.ports = Some(StationPorts::default());
        Ok(())
    }

    /// The ports of a separate ground station, when serving one.
    pub fn ports(&mut self) -> Option<&mut StationPorts> {
        self.ports.as_mut()
    }

    /// An uplink message that arrived now from a separate ground station (lost or damaged under the
    /// scenario's link faults, as the radio would).
    pub fn uplink(&mut self, msg: Uplink) {
        self.send(self.t_us, msg);
    }

    /// The scenario.
    pub fn scenario(&self) -> &Scenario {
        &self.scenario
    }

    /// Simulated time (s).
    pub fn time_s(&self) -> f64 {
        self.t_us as f64 * 1e-6
    }

    /// Forward frames rendered and measured on the pool while the simulation went on (`camera_worker`).
    pub fn pipelined_frames(&self) -> u64 {
        self.pipelined_frames
    }

    /// Downward frames rendered and measured on the pool while the simulation went on.
    pub fn pipelined_down_frames(&self) -> u64 {
        self.pipelined_down_frames
    }

    /// The recorded samples.
    pub fn records(&self) -> &[Record] {
        &self.records
    }

    /// The statistics so far.
    pub fn stats(&self) -> &RunStats {
        &self.stats
    }

    /// The flow velocities measured, against the truth.
    pub fn flow_records(&self) -> &[FlowRecord] {
        &self.flow_records
    }

    /// The simulated vehicle.
    pub fn vehicle(&self) -> &Quadrotor {
        &self.quad
    }

    /// Each rotor's thrust scale under the active motor faults.
    fn motor_faults(&self, t_s: f64) -> [f64; 4] {
        let mut scale = [1.0; 4];
        for f in self.scenario.faults.iter().filter(|f| f.active(t_s)) {
            match f.kind {
                FaultKind::MotorDegradation { motor, thrust_scale } => {
                    scale[(motor - 1) as usize] *= thrust_scale
                }
                FaultKind::MotorLoss { motor } => scale[(motor - 1) as usize] = 0.0,
                _ => {}
            }
        }
        scale
    }

    /// Whether a fault of this kind acts now.
    fn fault_active(&self, is: impl Fn(&FaultKind) -> bool) -> Option<&FaultKind> {
        let t = self.time_s();
        self.scenario.faults.iter().find(|f| f.active(t) && is(&f.kind)).map(|f| &f.kind)
    }

    /// Sends an uplink message over the radio: lost while the link is down, through the corrupting channel
    /// while it corrupts (the frame's bytes, decoded as the vehicle's decoder would: a frame that fails its
    /// checks is lost, one whose damage passes them is delivered damaged).
    fn send(&mut self, at_us: u64, msg: Uplink) {
        if self.fault_active(|k| matches!(k, FaultKind::LinkLoss)).is_some() {
            self.link_dropped += 1;
            return;
        }
        let msg = match self.fault_active(|k| matches!(k, FaultKind::LinkCorruption { .. })) {
            Some(FaultKind::LinkCorruption { byte_error_rate }) => {
                let p = *byte_error_rate;
                match corrupt(&msg, p, &mut self.fault_rng) {
                    Some(m) => m,
                    None => {
                        self.link_dropped += 1;
                        return;
                    }
                }
            }
            _ => msg,
        };
        self.deliver(at_us, msg);
    }

    fn deliver(&mut self, at_us: u64, msg: Uplink) {
        // Keep the queue ordered by delivery time (stable for equal times).
        let pos = self.link.iter().position(|(t, _)| *t > at_us).unwrap_or(self.link.len());
        self.link.insert(pos, (at_us, msg));
    }

    /// The forward camera's true pose: its mount is the configured one turned by the mount error.
    fn camera_pose(&self) -> (Mat3, Vec3) {
        let r = self.quad.rotation();
        let r_wb = Mat3 { m: r.map(|row| row.map(|v| v as f32)) };
        let mut mount = self.scenario.forward_camera_mount();
        let e = self.scenario.mismatch.forward_camera_mount_error_deg;
        if e != [0.0; 3] {
            let [r, p, y] = e.map(|a| geometry::deg(a as f32));
            mount.body_from_camera = Mat3::from_euler_zyx(r, p, y).mul_mat(&mount.body_from_camera);
        }
        let p = self.quad.state.p;
        let center = Vec3::new(p[0] as f32, p[1] as f32, p[2] as f32) + r_wb.mul_vec(mount.offset_body_m);
        (r_wb.mul_mat(&mount.body_from_camera), center)
    }

    /// Whether a frame can be rendered and measured on the pool while the simulation goes on
    /// (`camera_worker`): nothing else needs it at the capture (no station's stream, live view or log of
    /// frames, none of the faults `at_capture` names acting), and this run is not one of a sweep's.
    ///
    /// The forward camera measures at once while it is frozen or the link corrupts (the frozen frame and the
    /// corrupted bytes are the measurement's). The downward camera's message is sent only when its pair gives
    /// a result, so it also measures at once while the link drops or corrupts messages (a message queued
    /// ahead of the result could not be taken back from those counts and draws); the tracker gives no result
    /// only for its first frame, which has no pair and so no message, so the link-loss case is a safeguard
    /// that no flight exercises.
    fn may_pipeline(&self, at_capture: impl Fn(&FaultKind) -> bool) -> bool {
        self.ports.is_none()
            && self.tap.is_none()
            && self.frame_encoding().is_none()
            && self.fault_active(at_capture).is_none()
            && rayon::current_thread_index().is_none()
    }

    /// Waits for the downward frame in the works, if any: the tracker comes back; a flow fills its message
    /// on the link and keeps the pair's truth, no flow takes the message back.
    fn join_down_job(&mut self) {
        let Some(job) = self.down_job.take() else { return };
        let (flow, result) = job.work.join();
        self.ground_flow = Some(flow);
        let pos = if job.queued {
            self.link.iter().position(|(_, m)| {
                matches!(m, Uplink::Flow(f) if f.frame_seq == job.frame_seq && f.t_next_us == job.capture_us)
            })
        } else {
            None
        };
        match result {
            Some(result) => {
                if let Some(i) = pos
                    && let Some((_, Uplink::Flow(f))) = self.link.get_mut(i)
                {
                    f.result = result;
                }
                if let Some(truth) = job.truth {
                    self.keep_flow_truth(truth, job.capture_us);
                }
            }
            None => {
                if let Some(i) = pos {
                    self.link.remove(i);
                }
            }
        }
    }

    /// The truth over a downward frame pair ending now: the mean velocity and the attitude at mid-interval.
    fn pair_truth(&self, t_prev: u64, p_prev: [f64; 3], q_prev: [f64; 4]) -> crate::camera_worker::FlowTruth {
        let st = self.quad.state;
        let dts = (self.t_us - t_prev) as f64 * 1e-6;
        let v = [0, 1, 2].map(|k| (st.p[k] - p_prev[k]) / dts);
        let mut q = [0.0; 4];
        let sign = if (0..4).map(|k| st.q[k] * q_prev[k]).sum::<f64>() < 0.0 { -1.0 } else { 1.0 };
        for k in 0..4 {
            q[k] = q_prev[k] + sign * st.q[k];
        }
        let n = q.iter().map(|v| v * v).sum::<f64>().sqrt();
        (self.t_us, quat_to_mat(q.map(|v| v / n)), v)
    }

    /// Keeps a pair's truth for scoring its flow, and the last half second of them.
    fn keep_flow_truth(&mut self, truth: crate::camera_worker::FlowTruth, now_us: u64) {
        self.flow_truth.push_back(truth);
        while self.flow_truth.front().is_some_and(|(t, _, _)| t + 500_000 < now_us) {
            self.flow_truth.pop_front();
        }
    }

    /// Waits for the forward frame in the works, if any: the detector comes back, the no-target counts take
    /// its result, and its message on the link gets its observation.
    fn join_forward_job(&mut self) {
        let Some(job) = self.forward_job.take() else { return };
        let (seq, capture_us) = (job.frame_seq, job.capture_us);
        let (vision, detection, img) = job.work.join();
        self.vision = Some(vision);
        self.forward_buffer = Some(img);
        let observation = self.stats.ground_no_target.record(detection);
        for (_, m) in self.link.iter_mut() {
            if let Uplink::Vision(v) = m
                && v.frame_seq == seq
                && v.capture_time_us == capture_us
            {
                v.observation = observation;
                break;
            }
        }
    }

    /// The ground station's line detector (back from the pool first).
    fn ground_vision(&mut self) -> &GroundVision {
        self.join_forward_job();
        match self.vision.as_ref() {
            Some(v) => v,
            None => unreachable!("the detector is back from the pool after a join"),
        }
    }

    fn capture_frame(&mut self) {
        // The previous frame's measurement first: results come in order, and the detector is needed again.
        self.join_forward_job();
        let (r_wc, center) = self.camera_pose();
        // The frame to render and measure on the pool, if it goes there.
        let mut job = None;
        let observation = match self.mode {
            CameraMode::Rendered => {
                let renderer = self.renderer.clone().map(|r| {
                    let s = r.default_settings();
                    (r, s)
                });
                match renderer {
                    Some((r, mut settings)) => {
                        let mut s = self.seed ^ 0xF0F0_0000_0000_0000 ^ self.frame_index;
                        settings.seed = splitmix64(&mut s);
                        // The camera's motion, for the motion blur and the rolling shutter.
                        (settings.velocity_m_s, settings.rates_rad_s) =
                            self.camera_motion(self.scenario.forward_camera_mount().offset_body_m);
                        if self.may_pipeline(|k| {
                            matches!(k, FaultKind::VisionFreeze | FaultKind::LinkCorruption { .. })
                        }) && let Some(vision) = self.vision.take()
                        {
                            // Measured on the pool; its observation joins its message before it is due.
                            let rates =
                                self.station_telemetry.map(|t| t.estimate.rates_rad_s).unwrap_or(Vec3::ZERO);
                            let timing = self.scenario.forward_row_timing(rates);
                            job = Some((r, vision, settings, timing));
                            None
                        } else {
                            let img = r.render(&r_wc, center, &settings);
                            let observation = match self.ports.as_mut() {
                                Some(p) => {
                                    if !self.scenario.faults.iter().any(|f| {
                                        f.active(self.t_us as f64 * 1e-6)
                                            && matches!(f.kind, FaultKind::VisionDropout)
                                    }) {
                                        p.forward.push_back((
                                            self.t_us,
                                            station_frame(
                                                self.frame_index,
                                                &img.data,
                                                img.width,
                                                img.height,
                                                3,
                                            ),
                                        ));
                                    }
                                    None
                                }
                                None => {
                                    // A rolling shutter: the station corrects the rows with the vehicle's rates from
                                    // its last telemetry.
                                    let rates = self
                                        .station_telemetry
                                        .map(|t| t.estimate.rates_rad_s)
                                        .unwrap_or(Vec3::ZERO);
                                    let timing = self.scenario.forward_row_timing(rates);
                                    let detection = match self.vision.as_mut() {
                                        Some(v) => v.detect_timed(&img, timing.as_ref()),
                                        None => {
                                            unreachable!("the detector is back from the pool after a join")
                                        }
                                    };
                                    self.stats.ground_no_target.record(detection)
                                }
                            };
                            if let Some(tap) = self.tap.as_mut() {
                                tap.forward_frame(self.t_us, &img, observation.as_ref());
                            }
                            if let Some(enc) = self.frame_encoding() {
                                let f = crate::flightlog::CameraFrame::rgb(
                                    self.frame_index as u32,
                                    self.t_us,
                                    &img,
                                    enc,
                                );
                                self.log_frame(f);
                            }
                            observation
                        }
                    }
                    None => None,
                }
            }
            CameraMode::Analytic if !self.scenario.scene.line_visible => {
                self.stats.analytic_not_in_view += 1;
                None
            }
            CameraMode::Analytic => {
                let cam = self.scenario.forward_camera_model();
                let target = self.scenario.line_target();
                // Dimmer light, noisier edges: the noise scales with the inverse of the light reaching the
                // sensor (the renderer's gain times the exposure).
                let light =
                    (self.scenario.scene.light_gain * self.scenario.forward_camera.exposure).max(0.05);
                let sigma = self.scenario.forward_camera.analytic_noise_px / light.min(1.0);
                let rng = &mut self.edge_rng;
                // Only what the detector would report: a sliver of an edge in the image's corner is not a
                // target (vision_core::observation::within_detector_limits).
                let observation =
                    project_observation(&cam, &target, &r_wc.transpose(), center, 8.0, 2.0, || {
                        (sigma * rng.normal()) as f32
                    })
                    .and_then(|o| {
                        within_detector_limits(o, cam.focal_px(), self.ground_vision().detector_params())
                    });
                self.stats.analytic_not_in_view += observation.is_none() as u64;
                observation
            }
        };
        // A frozen camera delivers the frame it froze on, again and again.
        let observation = if self.fault_active(|k| matches!(k, FaultKind::VisionFreeze)).is_some() {
            *self.frozen_observation.get_or_insert(observation)
        } else {
            self.frozen_observation = None;
            observation
        };
        let lat = self.scenario.forward_camera.clone();
        let jitter = if lat.latency_jitter_s > 0.0 {
            self.link_rng.range(-lat.latency_jitter_s, lat.latency_jitter_s)
        } else {
            0.0
        };
        let deliver = self.t_us + ((lat.latency_s + jitter).max(0.0) * 1e6).round() as u64;
        let msg =
            VisionMeasurement { capture_time_us: self.t_us, frame_seq: self.frame_index as u32, observation };
        if self.ports.is_none() && self.fault_active(|k| matches!(k, FaultKind::VisionDropout)).is_none() {
            // At full precision: the simulated link delivers the measurement as the station made it. The radio
            // carries it packed (protocol::packed); the campaign's flights are chaotic enough that a one-ulp
            // change of a normal moves a 60-run p95 by millimetres (docs/ground-station.md, "Link budget").
            self.send(deliver, Uplink::Vision(msg));
        }
        if let Some((r, vision, settings, timing)) = job {
            self.pipelined_frames += 1;
            let img = self.forward_buffer.take().unwrap_or_else(|| crate::imageio::RgbImage::new(0, 0));
            self.forward_job = Some(crate::camera_worker::ForwardJob::spawn(
                r,
                vision,
                img,
                r_wc,
                center,
                settings,
                timing,
                self.t_us,
                self.frame_index as u32,
                deliver,
            ));
        }
        self.frame_index += 1;
        self.stats.frames += 1;
        self.next_frame_us = ((self.frame_index as f64) * 1e6 / lat.rate_hz).round() as u64;
    }

    /// The velocity (world) of a point at `offset_body_m` on the vehicle and the vehicle's angular velocity
    /// in the world frame.
    fn camera_motion(&self, offset_body_m: Vec3) -> ([f64; 3], [f64; 3]) {
        let st = &self.quad.state;
        let r = quat_to_mat(st.q);
        let off = offset_body_m.to_array().map(|v| v as f64);
        let mv = |v: [f64; 3]| [0, 1, 2].map(|i| r[i][0] * v[0] + r[i][1] * v[1] + r[i][2] * v[2]);
        let w = st.w;
        let wxr =
            mv([w[1] * off[2] - w[2] * off[1], w[2] * off[0] - w[0] * off[2], w[0] * off[1] - w[1] * off[0]]);
        ([0, 1, 2].map(|k| st.v[k] + wxr[k]), mv(w))
    }

    fn down_pose(&self) -> (DownPose, CamPose) {
        let st = &self.quad.state;
        let r = quat_to_mat(st.q);
        let mount = self.scenario.down_camera_mount();
        let r_bc = mount.body_from_camera.m.map(|row| row.map(|v| v as f64));
        let off = mount.offset_body_m.to_array().map(|v| v as f64);
        let mv = |m: &[[f64; 3]; 3], v: [f64; 3]| {
            [0, 1, 2].map(|i| m[i][0] * v[0] + m[i][1] * v[1] + m[i][2] * v[2])
        };
        let mut r_wc = [[0.0; 3]; 3];
        for i in 0..3 {
            for j in 0..3 {
                r_wc[i][j] = (0..3).map(|k| r[i][k] * r_bc[k][j]).sum();
            }
        }
        let off_w = mv(&r, off);
        let center = [0, 1, 2].map(|k| st.p[k] + off_w[k]);
        let w = st.w;
        let wxr =
            [w[1] * off[2] - w[2] * off[1], w[2] * off[0] - w[0] * off[2], w[0] * off[1] - w[1] * off[0]];
        let wxr_w = mv(&r, wxr);
        let pose = DownPose {
            r_wc,
            center,
            velocity: [0, 1, 2].map(|k| st.v[k] + wxr_w[k]),
            omega_world: mv(&r, w),
        };
        let cam = CamPose {
            r_wc: Mat3 { m: r_wc.map(|row| row.map(|v| v as f32)) },
            center: Vec3::new(center[0] as f32, center[1] as f32, center[2] as f32),
        };
        (pose, cam)
    }

    fn capture_down_frame(&mut self) {
        // The previous frame's flow first: the tracker pairs this frame with it.
        self.join_down_job();
        let cfg = self.scenario.down_camera.clone();
        let (pose, cam_pose) = self.down_pose();
        let dt = 1.0 / cfg.rate_hz;
        // The ground station's guess of the rotation over the interval: the rates of the last telemetry that
        // came down the radio.
        let rates = self.station_telemetry.map(|t| t.estimate.rates_rad_s).unwrap_or(Vec3::ZERO);
        let r_bc = self.scenario.down_camera_mount().body_from_camera;
        let predicted = r_bc.transpose().mul_vec(rates * dt as f32);
        let deliver = self.t_us + (cfg.latency_s * 1e6).round() as u64;
        if self.down_renderer.is_some()
            && self.ground_flow.is_some()
            && self.may_pipeline(|k| matches!(k, FaultKind::LinkLoss | FaultKind::LinkCorruption { .. }))
            && let (Some(r), Some(fl)) = (self.down_renderer.clone(), self.ground_flow.take())
        {
            // Measured on the pool; its message waits on the link for the flow, as the forward camera's does.
            let mut settings = r.default_settings();
            let mut s = self.seed ^ 0x0D0D_0000_0000_0000 ^ self.down_index;
            settings.seed = splitmix64(&mut s);
            let truth =
                self.prev_down.map(|(t_prev, _, p_prev, q_prev)| self.pair_truth(t_prev, p_prev, q_prev));
            let queued = self.fault_active(|k| matches!(k, FaultKind::FlowDropout)).is_none();
            let queued = match self.prev_down {
                Some((t_prev, ..)) if queued => {
                    let msg = FlowMeasurement {
                        t_prev_us: t_prev,
                        t_next_us: self.t_us,
                        frame_seq: self.down_index as u32,
                        result: Err(vision_core::flow::NoFlowReason::TooFewTracks),
                    };
                    self.send(deliver, Uplink::Flow(msg));
                    true
                }
                _ => false,
            };
            self.down_job = Some(crate::camera_worker::DownJob {
                work: crate::camera_worker::DownJob::spawn(r, fl, pose, settings, predicted),
                deliver_us: deliver,
                capture_us: self.t_us,
                frame_seq: self.down_index as u32,
                queued,
                truth,
            });
            self.pipelined_down_frames += 1;
        } else {
            self.capture_down_frame_now(pose, cam_pose, predicted, deliver);
        }
        let st = self.quad.state;
        self.prev_down = Some((self.t_us, cam_pose, st.p, st.q));
        self.down_index += 1;
        self.stats.down_frames += 1;
        self.next_down_us = ((self.down_index as f64) * 1e6 / cfg.rate_hz).round() as u64;
    }

    /// A downward frame rendered and measured at once.
    fn capture_down_frame_now(&mut self, pose: DownPose, cam_pose: CamPose, predicted: Vec3, deliver: u64) {
        let result = match (&self.down_renderer, &mut self.ground_flow) {
            (Some(r), Some(fl)) => {
                let mut settings = r.default_settings();
                let mut s = self.seed ^ 0x0D0D_0000_0000_0000 ^ self.down_index;
                settings.seed = splitmix64(&mut s);
                let img = r.render(&pose, &settings);
                let result = match self.ports.as_mut() {
                    Some(p) => {
                        p.down.push_back((
                            self.t_us,
                            station_frame(self.down_index, &img.data, img.width, img.height, 1),
                        ));
                        None
                    }
                    None => fl.add(&img, predicted),
                };
                if let Some(tap) = self.tap.as_mut() {
                    let tracks: Vec<_> = fl.last_tracks().collect();
                    tap.down_frame(self.t_us, &img, &tracks);
                }
                if let Some(enc) = self.frame_encoding() {
                    let f = crate::flightlog::CameraFrame::gray(
                        crate::flightlog::CameraId::Downward,
                        self.down_index as u32,
                        self.t_us,
                        &img,
                        predicted.to_array(),
                        enc,
                    );
                    self.log_frame(f);
                }
                result
            }
            (None, Some(fl)) => self.prev_down.map(|(_, prev, _, _)| {
                analytic_flow(fl.camera(), fl.params(), &prev, &cam_pose, 0.08, &mut self.down_rng, predicted)
            }),
            _ => None,
        };
        if let (Some(result), Some((t_prev, _, p_prev, q_prev))) = (result, self.prev_down) {
            let msg = FlowMeasurement {
                t_prev_us: t_prev,
                t_next_us: self.t_us,
                frame_seq: self.down_index as u32,
                result,
            };
            if self.fault_active(|k| matches!(k, FaultKind::FlowDropout)).is_none() {
                self.send(deliver, Uplink::Flow(msg));
            }
            let truth = self.pair_truth(t_prev, p_prev, q_prev);
            self.keep_flow_truth(truth, self.t_us);
        }
    }

    /// Compares a flow velocity of the flight code with the truth of its frame pair.
    fn score_flow(&mut self, t_next_us: u64, v_body: [f32; 2], std: f32) {
        let Some(&(_, r, v)) = self.flow_truth.iter().find(|(t, _, _)| *t == t_next_us) else { return };
        // The measured body velocity, with the true vertical body component, into the world frame.
        let vb_true = [0, 1, 2].map(|k| r[0][k] * v[0] + r[1][k] * v[1] + r[2][k] * v[2]);
        let vb = [v_body[0] as f64, v_body[1] as f64, vb_true[2]];
        let vw = [0, 1, 2].map(|i| r[i][0] * vb[0] + r[i][1] * vb[1] + r[i][2] * vb[2]);
        let t_s = t_next_us as f64 * 1e-6 - 0.5 / self.scenario.down_camera.rate_hz;
        self.flow_records.push(FlowRecord {
            t_s,
            measured: [vw[0], vw[1]],
            truth: [v[0], v[1]],
            std_m_s: std as f64,
        });
        if self.was_airborne && !self.quad.on_ground {
            self.flow_err.add([vw[0] - v[0], vw[1] - v[1], 0.0]);
        }
    }

    /// The ground station's operator: it sees the vehicle only through the telemetry that came down the
    /// radio, and runs the mission's script ([`ground_station::operator::Operator`], as the station does).
    fn operator(&mut self) {
        if self.ports.is_some() {
            // A separate station commands the vehicle.
            return;
        }
        while let Some(&(at, d)) = self.downlink_queue.front() {
            if at > self.t_us {
                break;
            }
            self.downlink_queue.pop_front();
            if let Some(t) = d.telemetry() {
                self.station_telemetry = Some(t);
            }
            if let Some(h) = self.ground_hook.as_mut() {
                h.downlink(&d);
            }
        }
        let lat = (self.scenario.link.latency_s * 1e6) as u64;
        let mode = self.station_telemetry.map(|t| t.mode);
        if let Some(mut h) = self.ground_hook.take() {
            match h.poll(self.t_us) {
                Ok(requests) => {
                    for r in requests {
                        match r {
                            GroundRequest::Kill => self.operator.kill(),
                            GroundRequest::Command(c) => self.operator.command(c),
                            GroundRequest::Uplink(m) => self.send(self.t_us + lat, m),
                        }
                    }
                }
                Err(e) => self.stats.fc_error = Some(format!("{e:#}")),
            }
            self.ground_hook = Some(h);
        }
        if let Some(c) = self.operator.tick(self.t_us, mode) {
            self.send(self.t_us + lat, Uplink::Command(c));
        }
        if self.t_us >= self.next_heartbeat_us {
            self.send(self.t_us + lat, Uplink::Heartbeat);
            self.next_heartbeat_us += (1e6 / self.scenario.link.heartbeat_hz) as u64;
        }
    }

    fn control_step(&mut self) {
        // Frames measured on the pool join their messages before the messages are due.
        if self.forward_job.as_ref().is_some_and(|j| j.deliver_us <= self.t_us) {
            self.join_forward_job();
        }
        if self.down_job.as_ref().is_some_and(|j| j.deliver_us <= self.t_us) {
            self.join_down_job();
        }
        let mut delivered: Vec<Uplink> = Vec::new();
        while let Some(&(at, msg)) = self.link.front() {
            if at > self.t_us {
                break;
            }
            self.link.pop_front();
            delivered.push(msg);
        }
        let step_mag = self.pending_mag.take();
        let step_baro = self.pending_baro.take();
        let heard = self.fault_active(|k| matches!(k, FaultKind::RcLoss)).is_none();
        let t_us = self.t_us;
        let pilot = self.transmitter.as_mut().and_then(|tx| tx.step(t_us, heard));
        let battery = self.pending_battery.take();
        let input = StepInput {
            time_us: self.t_us,
            imu: &self.pending_imu,
            mag: step_mag,
            baro_m: step_baro,
            uplink: &delivered,
            landed: None,
            pilot,
            battery,
        };
        let mut downlinks: Vec<protocol::Downlink> = Vec::new();
        let out = match self.fc.as_mut() {
            Some(Fc::Sil(stack)) => {
                let o = stack.step(&input);
                // Background work, in the firmware's order: after the step, fused by the next one.
                stack.solve_pending();
                // What the vehicle sends down the radio (the firmware's own schedule).
                self.log_downlinks.after_step(
                    &o.control,
                    o.param_reply,
                    o.time_sync,
                    self.t_us,
                    0,
                    o.telemetry_every,
                    o.battery,
                    |d| downlinks.push(d),
                );
                o.report()
            }
            Some(Fc::Qemu(q)) => match q.step(&input) {
                Ok(step) => {
                    let t_s = self.t_us as f64 * 1e-6;
                    let cost = self.stats.fc_cost.get_or_insert_with(FcCost::default);
                    let instr = step.instructions();
                    cost.steps += 1;
                    self.cost_sum += instr as f64;
                    cost.mean_instructions = self.cost_sum / cost.steps as f64;
                    if instr > cost.max_instructions {
                        cost.max_instructions = instr;
                        cost.max_at_s = t_s;
                    }
                    let bg = step.background_instructions();
                    if step.background_solves > 0 {
                        cost.solves += step.background_solves as u64;
                        self.background_sum += bg as f64;
                        cost.solve_mean_instructions = self.background_sum / cost.solves as f64;
                    }
                    if bg > cost.background_max_instructions {
                        cost.background_max_instructions = bg;
                        cost.background_max_at_s = t_s;
                    }
                    let flown = t_s.max(1e-6) * crate::fil::CORE_INSTRUCTIONS_PER_S;
                    cost.step_cpu_share = self.cost_sum / flown;
                    cost.background_cpu_share = self.background_sum / flown;
                    downlinks = step.downlink;
                    step.report
                }
                Err(e) => {
                    self.stats.fc_error = Some(format!("{e:#}"));
                    self.fc = None;
                    return;
                }
            },
            None => return,
        };
        if self.flight_log.is_some() || self.tap.is_some() {
            let step = flight_core::fil::SensorStep {
                time_us: self.t_us,
                // Scenario validation keeps a control step within `MAX_IMU_PER_STEP` samples
                // (`mission.control_rate_hz`): a step's samples always fit its record.
                imu: heapless::Vec::from_slice(&self.pending_imu)
                    .expect("scenario validation bounds the IMU samples per control step"),
                mag: step_mag,
                baro_m: step_baro,
                landed: None,
            };
            let mut records: Vec<LogRecord> = delivered.iter().map(|m| LogRecord::Link(*m)).collect();
            records.extend(pilot.map(LogRecord::Pilot));
            records.extend(battery.map(LogRecord::Battery));
            records.push(LogRecord::Step(step));
            records.push(LogRecord::Report(out));
            records.extend(downlinks.iter().map(|d| LogRecord::Downlink(*d)));
            self.write_log(&records);
        }
        // The ground station receives them after the link's latency (lost while the link is down).
        let lat = (self.scenario.link.latency_s * 1e6) as u64;
        let link_down = self.fault_active(|k| matches!(k, FaultKind::LinkLoss)).is_some();
        for d in downlinks {
            if link_down {
                self.link_dropped += 1;
            } else if let Some(p) = self.ports.as_mut() {
                p.downlink.push_back(d);
            } else {
                self.downlink_queue.push_back((self.t_us + lat, d));
            }
        }
        self.pending_imu.clear();
        if let Some(log) = self.motor_log.as_mut() {
            log.push(out.control.motors_rad_s.map(f32::to_bits));
        }
        self.motor_cmd = out.control.motors_rad_s;
        let st = out.control.status;
        let t = self.time_s();
        if self.stats.modes.last().is_none_or(|(_, m)| *m != format!("{:?}", st.mode)) {
            self.stats.modes.push((t, format!("{:?}", st.mode)));
        }
        if let Some(f) = st.failsafe
            && st.failsafe != self.last_failsafe
        {
            self.stats.failsafes.push((t, format!("{f:?}")));
        }
        self.stats.estimator = out.estimator;
        self.stats.last_motor_cmd = out.control.motors_rad_s;
        let w = out.control.estimate.wind_m_s;
        self.stats.wind_estimate_m_s = Some([w.x, w.y]);
        self.last_failsafe = st.failsafe;
        self.stats.frames_solved = out.vision.solved;
        self.stats.frames_no_target = out.vision.no_target;
        self.stats.frames_rejected = out.vision.rejected;
        self.stats.frames_frozen = out.vision.frozen;
        self.stats.flow = out.flow_counters;
        self.stats.flow_fused = [out.estimator.flow_accepted, out.estimator.flow_rejected];
        if let Some(FlowOutcome::Velocity { t_next_us, velocity, .. }) = out.flow {
            self.score_flow(t_next_us, velocity.velocity_m_s, velocity.std_m_s);
        }
        if st.passes_done > self.stats.passes_done {
            self.stats.passes_done = st.passes_done;
        }
        if st.mode.airborne() {
            self.was_airborne = true;
        }
        // Tracking-phase errors (at the control rate).
        let s = &self.quad.state;
        if st.mode == FlightMode::Tracking {
            self.tracking_since.get_or_insert(t);
            let sp = out.control.setpoint.position_m;
            let est = out.control.estimate.position_m;
            self.tracking.add([s.p[0] - sp.x as f64, s.p[1] - sp.y as f64, s.p[2] - sp.z as f64]);
            let att = attitude_of(&quat_to_mat(s.q));
            let e = &out.control.estimate.attitude;
            let (er, ep) = ((e.roll as f64 - att[0]).to_degrees(), (e.pitch as f64 - att[1]).to_degrees());
            self.tilt_err.add([er, ep, 0.0]);
            self.stats.max_tilt_error_deg = self.stats.max_tilt_error_deg.max(er.abs()).max(ep.abs());
            self.estimate.add([est.x as f64 - s.p[0], est.y as f64 - s.p[1], est.z as f64 - s.p[2]]);
            self.stats.tracking_s = t - self.tracking_since.unwrap_or(t);
        }
        if self.was_airborne && st.mode == FlightMode::Disarmed && self.done_at.is_none() {
            self.done_at = Some(self.t_us);
            self.stats.landed = self.quad.on_ground;
        }
        self.last_out = Some(out);
    }

    fn record(&mut self) {
        let Some(out) = self.last_out else { return };
        if self.flight_log.is_some() || self.tap.is_some() {
            let s = &self.quad.state;
            let att = attitude_of(&quat_to_mat(s.q));
            let truth = LogRecord::Truth {
                time_us: self.t_us,
                position_m: s.p.map(|v| v as f32),
                velocity_m_s: s.v.map(|v| v as f32),
                attitude_rad: att.map(|v| v as f32),
            };
            self.write_log(&[truth]);
        }
        let s = &self.quad.state;
        let e = &out.control.estimate;
        let sp = &out.control.setpoint;
        self.records.push(Record {
            t_s: self.time_s(),
            true_p: s.p,
            true_v: s.v,
            true_att: attitude_of(&quat_to_mat(s.q)),
            est_p: e.position_m.to_array(),
            est_v: e.velocity_m_s.to_array(),
            est_att: [e.attitude.roll, e.attitude.pitch, e.attitude.yaw],
            des_p: sp.position_m.to_array(),
            des_v: sp.velocity_m_s.to_array(),
            motor_cmd: out.control.motors_rad_s,
            motor: s.rotors,
            mode: out.control.status.mode,
            fix_age_s: out.control.status.fix_age_s,
            tilt_std_rad: e.tilt_std_rad,
        });
    }

    fn check_crash(&mut self) {
        let s = self.quad.state;
        self.stats.min_wall_distance_m = self.stats.min_wall_distance_m.min(s.p[1]);
        let reach = self.scenario.vehicle.arm_length_m as f64
            + self.scenario.model.ground_effect_rotor_radius_m.max(0.1);
        if s.p[1] < reach {
            self.stats.wall_contact = true;
        }
        self.stats.link_dropped = self.link_dropped;
        let r = quat_to_mat(s.q);
        let tilt = r[2][2].clamp(-1.0, 1.0).acos().to_degrees();
        if !self.quad.on_ground && self.was_airborne {
            self.stats.max_tilt_deg = self.stats.max_tilt_deg.max(tilt);
        }
        self.stats.max_touchdown_speed_m_s = self.quad.max_touchdown_speed;
        let reason = if tilt > 80.0 {
            Some("tilt beyond 80 deg".to_string())
        } else if self.quad.max_touchdown_speed > 1.5 {
            Some(format!("hard touchdown at {:.2} m/s", self.quad.max_touchdown_speed))
        } else if s.p[1] < 0.1 {
            Some("hit the wall".to_string())
        } else if !s.p.iter().chain(s.v.iter()).all(|v| v.is_finite()) {
            Some("non-finite state".to_string())
        } else {
            None
        };
        if let Some(r) = reason {
            self.stats.crashed = true;
            self.stats.crash_reason = Some(r);
        }
    }

    /// Advances one physics step. Returns `false` when the run is over (landed, crashed, or `end_us`).
    pub fn step(&mut self, end_us: u64) -> bool {
        // Physics with the rotor commands and the wind held.
        let cmd = self.motor_cmd.map(|w| w as f64);
        let t_s = self.time_s();
        self.quad.params.rotor_scale = self.motor_faults(t_s);
        let h = self.dt_us as f64 * 1e-6;
        // The battery: the charge the rotors draw, the sag's limit on their speed, its readings.
        if let Some(p) = self.power.as_mut() {
            self.quad.params.motor_limits[1] = p.step(self.quad.params.k_tau, self.quad.state.rotors, h);
            if let Some(r) = p.reading(self.t_us) {
                self.pending_battery = Some(r);
            }
            self.stats.battery =
                Some(BatteryStats { final_charge: p.charge(), min_voltage_v: p.min_voltage_v });
        }
        if !self.wind.is_calm() {
            self.wind_now = self.wind.step(t_s, h, self.quad.state.v);
        }
        self.quad.step_in_wind(h, cmd, self.wind_now);
        self.t_us += self.dt_us;
        self.step_count += 1;
        let faults = if self.scenario.faults.is_empty() {
            ImuFaults::default()
        } else {
            ImuFaults::at(&self.scenario.faults, self.time_s(), self.scenario.imu.rate_hz)
        };
        if self.step_count.is_multiple_of(self.imu_every) {
            let s = self.imu.sample(&self.quad, self.t_us, &faults);
            self.pending_imu.push(s);
        }
        if self.step_count.is_multiple_of(self.mag_every) {
            self.pending_mag = Some(self.imu.mag(&self.quad, &faults));
        }
        if let Some(n) = self.baro_every
            && self.step_count.is_multiple_of(n)
        {
            let dt = (n * self.dt_us) as f64 * 1e-6;
            self.pending_baro = Some(self.imu.baro(&self.quad, dt));
        }
        if self.t_us >= self.next_frame_us {
            self.capture_frame();
        }
        if self.scenario.down_camera.enabled && self.t_us >= self.next_down_us {
            self.capture_down_frame();
        }
        self.operator();
        if self.step_count.is_multiple_of(self.ctrl_every) {
            self.control_step();
        }
        if self.step_count.is_multiple_of(self.record_every) {
            self.record();
        }
        self.check_crash();
        self.stats.sim_time_s = self.time_s();
        let landed_done = self.done_at.is_some_and(|t| self.t_us >= t + 500_000);
        !(self.stats.crashed || landed_done || self.t_us >= end_us || self.stats.fc_error.is_some())
    }

    /// Runs to the end (landed and disarmed, crashed, or `duration_s`), calling `progress` with the simulated
    /// time about every 0.1 s of it.
    pub fn run(&mut self, duration_s: f64, mut progress: impl FnMut(f64)) -> RunStats {
        let end_us = (duration_s * 1e6).round() as u64;
        let every = (100_000 / self.dt_us).max(1);
        while self.step(end_us) {
            if self.step_count.is_multiple_of(every) {
                progress(self.time_s());
            }
        }
        progress(self.time_s());
        self.finish()
    }

    /// Records the flight into a log (`crate::flightlog`): every step's radio messages, sensors, report and
    /// downlink messages, the camera frames as `frames` says (rendered cameras only), and the ground truth at
    /// the record rate.
    pub fn record_log(&mut self, w: crate::flightlog::LogWriter, frames: crate::flightlog::FramePolicy) {
        self.flight_log = Some(w);
        self.log_frames = frames;
    }

    /// The frame encoding to log with, if frames are logged.
    fn frame_encoding(&self) -> Option<crate::flightlog::FrameEncoding> {
        use crate::flightlog::{FrameEncoding, FramePolicy};
        match (&self.flight_log, self.log_frames) {
            (None, _) | (_, FramePolicy::Drop) => None,
            (Some(_), FramePolicy::Png) => Some(FrameEncoding::Png),
            (Some(_), FramePolicy::Raw) => Some(FrameEncoding::Raw),
        }
    }

    fn log_frame(&mut self, frame: Result<crate::flightlog::CameraFrame>) {
        match frame {
            Ok(f) => self.write_log(&[LogRecord::Frame(f)]),
            Err(e) => {
                self.log_error = Some(format!("{e:#}"));
                self.flight_log = None;
            }
        }
    }

    /// Ends the log: flushes it and returns how many records it holds, or why writing failed.
    pub fn finish_log(&mut self) -> Result<u64> {
        if let Some(e) = self.log_error.take() {
            anyhow::bail!("writing the flight log failed: {e}");
        }
        match self.flight_log.take() {
            Some(w) => {
                let n = w.records;
                w.finish()?;
                Ok(n)
            }
            None => Ok(0),
        }
    }

    fn write_log(&mut self, records: &[LogRecord]) {
        if let Some(tap) = self.tap.as_mut() {
            tap.records(records);
        }
        let Some(w) = self.flight_log.as_mut() else { return };
        for r in records {
            if let Err(e) = w.write(r) {
                // Keep flying; the error is reported when the log is finished, with what was kept.
                let (n, bytes) = (w.records, w.bytes);
                let kept = match self.flight_log.take().map(|w| w.keep_partial()) {
                    Some(Ok(p)) => format!(
                        "{n} records ({bytes} bytes) had been written; what reached the disk is kept in {} (it \
                         reads as truncated after its last whole record)",
                        p.display()
                    ),
                    Some(Err(k)) => format!("and what was written could not be kept: {k:#}"),
                    None => String::new(),
                };
                self.log_error = Some(format!("{e:#}; {kept}"));
                return;
            }
        }
    }

    /// Keeps the bits of every control step's motor commands (for comparing flight computers).
    pub fn log_motor_commands(&mut self) {
        self.motor_log = Some(Vec::new());
    }

    /// The motor commands of every control step so far (bits of the f32 rotor speeds), when logged.
    pub fn motor_commands(&self) -> Option<&[[u32; 4]]> {
        self.motor_log.as_deref()
    }

    /// Final statistics. With the firmware in QEMU, ends it and keeps its stack report.
    pub fn finish(&mut self) -> RunStats {
        self.join_forward_job();
        self.join_down_job();
        if let Some(Fc::Qemu(q)) = self.fc.take() {
            match q.finish() {
                Ok(console) => {
                    if let Some(c) = self.stats.fc_cost.as_mut() {
                        c.stack_report =
                            console.lines().find(|l| l.starts_with("stack:")).map(str::to_string);
                    }
                }
                Err(e) => {
                    self.stats.fc_error.get_or_insert(format!("at the end of the run: {e:#}"));
                }
            }
        }
        self.stats.rms_error_m = self.tracking.get();
        let t = self.tilt_err.get();
        self.stats.tilt_error_rms_deg = ((t[0] * t[0] + t[1] * t[1]) / 2.0).sqrt();
        self.stats.estimate_rms_error_m = self.estimate.get();
        let f = self.flow_err.get();
        self.stats.flow_rms_error_m_s = [f[0], f[1]];
        self.stats.clone()
    }
}

/// A frame for a station's stream (no timestamp yet: the camera stamps it when it leaves).
fn station_frame(
    seq: u64,
    data: &[u8],
    width: usize,
    height: usize,
    channels: usize,
) -> ground_station::stream::Frame {
    ground_station::stream::Frame {
        seq: Some(seq),
        timestamp_us: None,
        width,
        height,
        channels,
        data: data.to_vec(),
    }
}

/// A message through a channel that flips one bit of each byte with probability `p`: what the vehicle's
/// decoder makes of the frame (`None`: rejected).
fn corrupt(msg: &Uplink, p: f64, rng: &mut SimRng) -> Option<Uplink> {
    let mut buf = [0u8; protocol::frame::MAX_FRAME];
    let mut bytes = protocol::frame::encode(msg, &mut buf).ok()?.to_vec();
    for b in bytes.iter_mut() {
        if rng.uniform() < p {
            *b ^= 1 << (rng.next_u64() % 8);
        }
    }
    let mut dec = protocol::frame::Decoder::new();
    let mut out = None;
    for b in bytes {
        if let Some(r) = dec.push::<Uplink>(b) {
            out = r.ok();
        }
    }
    out
}
