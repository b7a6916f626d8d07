//! Renders a few forward frames (for profiling the renderer).
use geometry::frames::Attitude;
use geometry::{Vec3, deg};
use sim_host::Scenario;
use sim_host::render::ForwardRenderer;

fn main() {
    let s = Scenario::paper();
    let r = ForwardRenderer::new(&s).expect("renderer");
    let mount = s.forward_camera_mount();
    let att = Attitude::new(deg(1.5), deg(-2.0), deg(4.0));
    let r_wc = att.world_from_body().mul_mat(&mount.body_from_camera);
    let mut settings = r.default_settings();
    let mut sum = 0u64;
    for i in 0..4 {
        settings.seed = i;
        let img = r.render(&r_wc, Vec3::new(1.15, 1.45, 0.8), &settings);
        sum += img.data[1000] as u64;
    }
    println!("{sum}");
}
