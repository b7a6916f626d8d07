//! Shared helpers of the system tests: sampling the flight envelope and summarising errors.
use geometry::frames::Attitude;
use geometry::{Vec3, deg};
use sim_host::rng::SimRng;

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
