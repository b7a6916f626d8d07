//! Benchmarks of the forward-camera vision: the whole pipeline (detection and pose) on one 640x480 frame,
//! its parts, and the renderer.
use criterion::{Criterion, criterion_group, criterion_main};
use geometry::frames::Attitude;
use geometry::{Vec3, deg};
use sim_host::Scenario;
use sim_host::render::ForwardRenderer;
use std::hint::black_box;
use vision_core::{AttitudeSource, DetectorParams, DetectorWorkspace, PoseParams, detect_line, solve_pose};

fn bench(c: &mut Criterion) {
    let scenario = Scenario::paper();
    let renderer = ForwardRenderer::new(&scenario).expect("renderer");
    let mount = scenario.forward_camera_mount();
    let att = Attitude::new(deg(1.5), deg(-2.0), deg(4.0));
    let r_wc = att.world_from_body().mul_mat(&mount.body_from_camera);
    let mut settings = renderer.default_settings();
    settings.seed = 1;
    // Both ends in view (the most work: four edges) at the paper's distance and altitude.
    let img = renderer.render(&r_wc, Vec3::new(1.15, 1.45, 0.8), &settings);
    let cam = scenario.forward_camera_model();
    let target = scenario.line_target();
    let params = DetectorParams::default();
    let mut ws = Box::new(DetectorWorkspace::new());
    let obs = detect_line(&img.view(), &cam, &params, &mut ws).expect("line");
    assert_eq!(obs.real_corners(), 4);
    let imu = AttitudeSource::Imu { roll: att.roll, pitch: att.pitch, sigma_rad: deg(0.5) };
    let pp = PoseParams::default();

    let mut g = c.benchmark_group("forward_vision_640x480");
    g.bench_function("pipeline_imu_aided", |b| {
        b.iter(|| {
            let obs = detect_line(black_box(&img.view()), &cam, &params, &mut ws).expect("line");
            solve_pose(&obs, &cam, &target, &mount, imu, &pp).expect("pose")
        })
    });
    g.bench_function("pipeline_image_only", |b| {
        b.iter(|| {
            let obs = detect_line(black_box(&img.view()), &cam, &params, &mut ws).expect("line");
            solve_pose(&obs, &cam, &target, &mount, AttitudeSource::ImageOnly, &pp).expect("pose")
        })
    });
    g.bench_function("detect_only", |b| {
        b.iter(|| detect_line(black_box(&img.view()), &cam, &params, &mut ws))
    });
    g.bench_function("pose_only_imu_aided", |b| {
        b.iter(|| solve_pose(black_box(&obs), &cam, &target, &mount, imu, &pp))
    });
    g.finish();
    // The renderer side by side: the default (sRGB) sensor, a linear one, and 1.5 px of optical blur (the
    // blur's cost as a ratio to the plain frame).
    let mut g = c.benchmark_group("render_forward_640x480");
    g.bench_function("srgb", |b| {
        b.iter(|| renderer.render(black_box(&r_wc), Vec3::new(1.15, 1.45, 0.8), &settings))
    });
    let mut linear_scenario = scenario.clone();
    linear_scenario.forward_camera.response = vision_core::ToneCurve::Linear;
    let linear = ForwardRenderer::new(&linear_scenario).expect("renderer");
    g.bench_function("linear", |b| {
        b.iter(|| linear.render(black_box(&r_wc), Vec3::new(1.15, 1.45, 0.8), &settings))
    });
    let blurred = sim_host::render::RenderSettings { blur_sigma_px: 1.5, ..settings };
    g.bench_function("srgb_blur_1.5px", |b| {
        b.iter(|| renderer.render(black_box(&r_wc), Vec3::new(1.15, 1.45, 0.8), &blurred))
    });
    // The other camera effects, each on its own, moving at the sweep's speed and turning slowly.
    let moving = sim_host::render::RenderSettings {
        velocity_m_s: [0.25, 0.0, 0.0],
        rates_rad_s: [0.1, 0.1, 0.1],
        ..settings
    };
    type Change = fn(&mut Scenario);
    let variants: [(&str, Change); 4] = [
        ("lens_k1_-0.3", |s| s.forward_camera.distortion = [-0.3, 0.08, 0.0, 0.0, 0.0]),
        ("rolling_shutter_30us", |s| s.forward_camera.line_delay_s = 30e-6),
        ("motion_blur_10ms", |s| s.forward_camera.exposure_time_s = 0.01),
        ("jpeg_85", |s| s.forward_camera.jpeg_quality = 85),
    ];
    for (name, change) in variants {
        let mut sc = scenario.clone();
        change(&mut sc);
        let r = ForwardRenderer::new(&sc).expect("renderer");
        g.bench_function(name, |b| {
            b.iter(|| r.render(black_box(&r_wc), Vec3::new(1.15, 1.45, 0.8), &moving))
        });
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
