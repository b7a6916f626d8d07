//! Shared helpers of the system tests: sampling the flight envelope and summarising errors.
use geometry::frames::Attitude;
use geometry::{Vec3, deg};
use sim_host::Scenario;
use sim_host::fly::tilt_bound_deg;
use sim_host::rng::SimRng;
use sim_host::sil::RunStats;

/// One test frame: a vehicle pose and the lighting and sensor effects to render it with.
#[derive(Clone, Copy, Debug)]
pub struct EnvelopeFrame {
    /// Vehicle position (world, m).
    pub position: Vec3,
    /// Vehicle attitude.
    pub attitude: Attitude,
    /// Illumination gain.
    pub light_gain: f64,
    /// Illumination gradient per metre (x, z).
    pub light_gradient_per_m: [f64; 2],
    /// Sensor noise seed.
    pub seed: u64,
    /// The camera's velocity (world, m/s) and angular velocity (world frame, rad/s) at the frame's time, for
    /// motion blur and rolling shutter (zero in [`envelope_frames`]; see [`with_motion`]).
    pub velocity_m_s: [f64; 3],
    /// See `velocity_m_s`.
    pub rates_rad_s: [f64; 3],
}

/// The frames moving: each component of the velocity uniform within `+-speed` (m/s) and of the angular
/// velocity within `+-rate` (rad/s).
pub fn with_motion(mut frames: Vec<EnvelopeFrame>, seed: u64, speed: f64, rate: f64) -> Vec<EnvelopeFrame> {
    let mut r = SimRng::stream(seed, "envelope-motion");
    for f in &mut frames {
        f.velocity_m_s = [0; 3].map(|_| r.range(-speed, speed));
        f.rates_rad_s = [0; 3].map(|_| r.range(-rate, rate));
    }
    frames
}

/// Frames spread over the flight envelope of the vision issue: distance 1.0-1.6 m, height 0.6-1.0 m, x over
/// 0-2.30 m, roll and pitch within 5 deg, yaw within 10 deg, lighting gain 0.5-1.3 with gradients.
pub fn envelope_frames(n: usize, seed: u64) -> Vec<EnvelopeFrame> {
    let mut r = SimRng::stream(seed, "vision-envelope");
    (0..n)
        .map(|i| EnvelopeFrame {
            // Stratified in x so that every part of the sweep (and both ends) is covered.
            position: Vec3::new(
                (2.30 * (i as f64 + r.uniform()) / n as f64) as f32,
                r.range(1.0, 1.6) as f32,
                r.range(0.6, 1.0) as f32,
            ),
            attitude: Attitude::new(
                deg(r.range(-5.0, 5.0) as f32),
                deg(r.range(-5.0, 5.0) as f32),
                deg(r.range(-10.0, 10.0) as f32),
            ),
            light_gain: r.range(0.5, 1.3),
            light_gradient_per_m: [r.range(-0.25, 0.25), r.range(-0.4, 0.4)],
            seed: r.next_u64(),
            velocity_m_s: [0.0; 3],
            rates_rad_s: [0.0; 3],
        })
        .collect()
}

/// Median and 95th percentile of absolute values.
pub fn median_p95(v: &[f64]) -> (f64, f64) {
    if v.is_empty() {
        return (f64::NAN, f64::NAN);
    }
    let mut a: Vec<f64> = v.iter().map(|x| x.abs()).collect();
    a.sort_by(f64::total_cmp);
    let q = |p: f64| a[((p * (a.len() - 1) as f64).round() as usize).min(a.len() - 1)];
    (q(0.5), q(0.95))
}

/// Whether all four corners of the line are in the forward camera's image for a vehicle pose, at least 10 px
/// inside its border (room for the edge profile window and the wall beyond it).
pub fn both_ends_in_view(scenario: &sim_host::Scenario, f: &EnvelopeFrame) -> bool {
    let cam = scenario.forward_camera_model();
    let mount = scenario.forward_camera_mount();
    let r_cw = f.attitude.world_from_body().mul_mat(&mount.body_from_camera).transpose();
    let t = scenario.line_target();
    vision_core::Corner::ALL.iter().all(|&c| {
        let p = r_cw.mul_vec(t.corner(c) - f.position);
        p.z > 0.0 && cam.contains(cam.normalized_to_pixel(geometry::Vec2::new(p.x / p.z, p.y / p.z)), 10.0)
    })
}

/// The bounds: RMS tracking error y, z <= 3 cm, x <= 5 cm; no crash; tilt within the bound; with the
/// downward camera, the flow velocity's RMS error <= 0.05 m/s in x and y and most frame pairs used.
pub fn check_flight(st: &RunStats, s: &Scenario, what: &str) {
    check_partial_flight(st, s, what);
    assert_eq!(st.passes_done, 2 * s.trajectory.sweeps as u16, "{what}: sweeps not completed");
}

/// The bounds of [`check_flight`] on a flight cut short: everything but the number of sweeps.
pub fn check_partial_flight(st: &RunStats, s: &Scenario, what: &str) {
    eprintln!(
        "{what}: rms x {:.1} y {:.1} z {:.1} mm, estimate {:.1} {:.1} {:.1} mm, max tilt {:.2} deg, passes {}, landed {}, \
         flow rms x {:.4} y {:.4} m/s ({} of {} pairs, {} fused, {} gated)",
        1e3 * st.rms_error_m[0],
        1e3 * st.rms_error_m[1],
        1e3 * st.rms_error_m[2],
        1e3 * st.estimate_rms_error_m[0],
        1e3 * st.estimate_rms_error_m[1],
        1e3 * st.estimate_rms_error_m[2],
        st.max_tilt_deg,
        st.passes_done,
        st.landed,
        st.flow_rms_error_m_s[0],
        st.flow_rms_error_m_s[1],
        st.flow.velocities,
        st.flow.pairs,
        st.flow_fused[0],
        st.flow_fused[1],
    );
    assert!(!st.crashed, "{what}: crashed: {:?}", st.crash_reason);
    if st.flow_camera {
        let [fx, fy] = st.flow_rms_error_m_s;
        assert!(fx <= 0.05 && fy <= 0.05, "{what}: flow velocity rms error {fx}, {fy} m/s");
        assert!(st.flow.velocities as f64 >= 0.8 * st.flow.pairs as f64, "{what}: {:?}", st.flow);
    }
    assert!(st.rms_error_m[0] <= 0.05, "{what}: x rms {}", st.rms_error_m[0]);
    assert!(st.rms_error_m[1] <= 0.03, "{what}: y rms {}", st.rms_error_m[1]);
    assert!(st.rms_error_m[2] <= 0.03, "{what}: z rms {}", st.rms_error_m[2]);
    assert!(
        st.max_tilt_deg <= tilt_bound_deg(s),
        "{what}: tilt {} > bound {}",
        st.max_tilt_deg,
        tilt_bound_deg(s)
    );
    assert!(st.failsafes.is_empty(), "{what}: failsafes {:?}", st.failsafes);
}

/// Flies the paper scenario for `duration_s` with its flight log (in a fresh temporary folder named after
/// `name`); returns the log's path.
pub fn fly_logged(
    name: &str,
    seed: u64,
    duration_s: f64,
    camera: sim_host::sil::CameraMode,
    frames: sim_host::flightlog::FramePolicy,
) -> std::path::PathBuf {
    let out = std::env::temp_dir().join(format!("{name}-{}", std::process::id()));
    let opts = sim_host::fly::FlyOptions {
        scenario: Scenario::paper(),
        seed,
        duration_s: Some(duration_s),
        camera,
        out: out.clone(),
        plots: false,
        fc: sim_host::sil::FcChoice::Sil,
        log: true,
        frames,
        serve: None,
        mavlink: None,
        live: None,
        real_time: None,
    };
    if let Err(e) = sim_host::fly::fly(&opts, |_, _| {}) {
        panic!("the flight failed: {e:#}");
    }
    out.join(sim_host::flightlog::LOG_FILE)
}

/// The Python (`WLQ_PYTHON`, default `python3`) that can run `import {modules}`, or `None` with the reason
/// printed as a skip; with `{require_var}=1` (as CI sets it) a missing peer is a failure instead. `install`
/// says how to get the modules, `what` which part of the test is skipped.
pub fn python_with(modules: &str, install: &str, require_var: &str, what: &str) -> Option<String> {
    let py = std::env::var("WLQ_PYTHON").unwrap_or_else(|_| "python3".into());
    let ok = std::process::Command::new(&py)
        .args(["-c", &format!("import {modules}")])
        .stderr(std::process::Stdio::null())
        .status()
        .is_ok_and(|s| s.success());
    if ok {
        return Some(py);
    }
    let why = format!("{py} has no {modules} ({install}; set WLQ_PYTHON)");
    if std::env::var(require_var).is_ok_and(|v| v == "1") {
        panic!("{require_var}=1 but {why}");
    }
    eprintln!("SKIPPED ({what}): {why}");
    None
}
