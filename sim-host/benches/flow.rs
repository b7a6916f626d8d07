//! Benchmark of the downward camera's optical flow: one frame pair at the default resolution (160x120) with
//! the default features (an 8x6 grid), the downward renderer, and the flow's stages; then pairs at 320x240 and
//! 640x480 with the parameters for their size (`FlowParams::for_image`: more features, wider windows, deeper
//! pyramids, the whole-frame search, brightness gain and offset).
use criterion::{Criterion, criterion_group, criterion_main};
use geometry::frames::{Attitude, BODY_FROM_DOWN_CAMERA};
use geometry::{Vec3, deg};
use sim_host::Scenario;
use sim_host::downward::GroundFlow;
use sim_host::render::{DownPose, DownRenderer};
use std::hint::black_box;

fn bench(c: &mut Criterion) {
    let scenario = Scenario::paper();
    let renderer = DownRenderer::new(&scenario).expect("renderer");
    let r_wb = Attitude::new(deg(2.0), deg(-3.0), deg(5.0)).world_from_body();
    let r_wc = r_wb.mul_mat(&BODY_FROM_DOWN_CAMERA).m.map(|r| r.map(|v| v as f64));
    let mut settings = renderer.default_settings();
    settings.seed = 1;
    // The paper's altitude, moving at the sweep's speed and turning slowly.
    let pose = |t: f64| DownPose {
        r_wc,
        center: [1.0 + 0.25 * t, 1.3, 0.8],
        velocity: [0.25, 0.0, 0.0],
        omega_world: [0.0, 0.0, 0.0],
    };
    let mut moving = pose(0.0);
    moving.omega_world = [0.3, -0.2, 0.1];
    c.bench_function("render_down_160x120", |bch| {
        bch.iter(|| renderer.render(black_box(&moving), &settings))
    });
    let a = renderer.render(&pose(0.0), &settings);
    settings.seed = 2;
    let b = renderer.render(&pose(1.0 / 60.0), &settings);
    let mut flow = GroundFlow::new(&scenario);
    let s = flow.between(&a, &b, Vec3::ZERO).expect("flow");
    println!(
        "flow pair 160x120: {} of {} features tracked, median flow {:?} px",
        s.inliers, s.selected, s.median_flow_px
    );
    c.bench_function("flow_pair_160x120", |bch| {
        bch.iter(|| flow.between(black_box(&a), black_box(&b), Vec3::ZERO))
    });
    // The same pair without the repetition check, side by side (its cost as a ratio).
    let params = vision_core::flow::FlowParams { max_repetition_ratio: 0.0, ..Default::default() };
    let mut unchecked = GroundFlow::with_params(scenario.down_camera_model(), params);
    c.bench_function("flow_pair_160x120_without_repetition_check", |bch| {
        bch.iter(|| unchecked.between(black_box(&a), black_box(&b), Vec3::ZERO))
    });
    for (w, h) in [(320u16, 240u16), (640, 480)] {
        let mut s = Scenario::paper();
        let k = w as f64 / s.down_camera.width_px as f64;
        let cam = &mut s.down_camera;
        (cam.width_px, cam.height_px) = (w, h);
        (cam.fx_px, cam.fy_px) = (cam.fx_px * k, cam.fy_px * k);
        (cam.cx_px, cam.cy_px) = ((w as f64 - 1.0) / 2.0, (h as f64 - 1.0) / 2.0);
        let renderer = DownRenderer::new(&s).expect("renderer");
        let mut settings = renderer.default_settings();
        settings.seed = 1;
        let a = renderer.render(&pose(0.0), &settings);
        settings.seed = 2;
        let b = renderer.render(&pose(1.0 / 60.0), &settings);
        let mut flow = GroundFlow::new(&s);
        let st = flow.between(&a, &b, Vec3::ZERO).expect("flow");
        println!(
            "flow pair {w}x{h}: {} of {} features tracked, median flow {:?} px",
            st.inliers, st.selected, st.median_flow_px
        );
        c.bench_function(&format!("flow_pair_{w}x{h}"), |bch| {
            bch.iter(|| flow.between(black_box(&a), black_box(&b), Vec3::ZERO))
        });
    }
}

criterion_group!(benches, bench);
criterion_main!(benches);
