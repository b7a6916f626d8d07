//! Frames without the line (blank walls, other red shapes) must give no pose.
use geometry::deg;
use sim_host::Scenario;
use sim_host::render::ForwardRenderer;
use sim_host::scenario::WallShape;
use sim_host::vision::{GroundVision, PoseMethod};
use system_tests::envelope_frames;
use vision_core::AttitudeSource;

const RED: [f64; 3] = [0.78, 0.12, 0.10];

fn rect(x0: f64, x1: f64, z0: f64, z1: f64) -> WallShape {
    WallShape::Polygon { points_m: vec![[x0, z0], [x1, z0], [x1, z1], [x0, z1]], albedo_rgb: RED }
}

/// Distractor scenes: (name, shapes). None of them is the 2.30 m x 0.10 m line.
fn distractors() -> Vec<(&'static str, Vec<WallShape>)> {
    vec![
        ("blank wall", vec![]),
        ("disc", vec![WallShape::Disc { center_m: [1.0, 1.0], radius_m: 0.15, albedo_rgb: RED }]),
        ("square", vec![rect(0.9, 1.2, 0.85, 1.15)]),
        ("thick bar", vec![rect(0.6, 1.4, 0.85, 1.15)]),
        (
            "triangle",
            vec![WallShape::Polygon { points_m: vec![[0.7, 0.9], [1.5, 0.9], [1.1, 1.3]], albedo_rgb: RED }],
        ),
        (
            "outline",
            vec![
                rect(0.4, 1.8, 0.9, 0.93),
                rect(0.4, 1.8, 1.07, 1.1),
                rect(0.4, 0.43, 0.9, 1.1),
                rect(1.77, 1.8, 0.9, 1.1),
            ],
        ),
        ("short bar", vec![rect(0.9, 1.3, 0.95, 1.05)]),
        (
            "dots",
            (0..6)
                .map(|i| WallShape::Disc {
                    center_m: [0.3 + 0.35 * i as f64, 1.0 + 0.1 * (i % 2) as f64],
                    radius_m: 0.04,
                    albedo_rgb: RED,
                })
                .collect(),
        ),
        ("bar 0.9 m", vec![rect(0.7, 1.6, 0.95, 1.05)]),
    ]
}

#[test]
fn frames_without_the_line_give_no_pose() {
    let base = Scenario::paper();
    let frames = envelope_frames(60, 77);
    let mut checked = 0;
    let mut failures = Vec::new();
    for (k, (name, shapes)) in distractors().into_iter().enumerate() {
        let mut s = base.clone();
        s.scene.line_visible = false;
        s.scene.shapes = shapes;
        s.validate().unwrap();
        let renderer = ForwardRenderer::new(&s).unwrap();
        let mut vision = GroundVision::new(&s);
        let mount = s.forward_camera_mount();
        for f in frames.iter().skip(k).step_by(9).take(7) {
            // Centre the camera on the shapes (x in 0.8-1.5 m) so they are in view.
            let mut pos = f.position;
            pos.x = 0.8 + (pos.x / 2.3) * 0.7;
            let mut settings = renderer.default_settings();
            settings.light_gain = f.light_gain;
            settings.light_gradient_per_m = f.light_gradient_per_m;
            settings.seed = f.seed;
            let r_wc = f.attitude.world_from_body().mul_mat(&mount.body_from_camera);
            let img = renderer.render(&r_wc, pos, &settings);
            let imu =
                AttitudeSource::Imu { roll: f.attitude.roll, pitch: f.attitude.pitch, sigma_rad: deg(0.5) };
            for source in [AttitudeSource::ImageOnly, imu] {
                checked += 1;
                match vision.pose(&img, source, PoseMethod::Refined) {
                    Ok(r) => failures.push(format!("{name} at {pos:?}: pose {:?}", r.pose.camera_position_m)),
                    Err(why) => eprintln!("{name}: {}", why.code()),
                }
            }
        }
    }
    assert!(checked >= 100, "{checked}");
    assert!(
        failures.is_empty(),
        "{} of {checked} distractor frames gave a pose:\n{}",
        failures.len(),
        failures.join("\n")
    );
}
