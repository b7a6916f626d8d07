//! The station's latency from a forward frame's arrival to its measurement leaving on the radio, one core:
//! the frame stream's part parsed (and its PNG decoded), the image checked against the calibration, the
//! line measured (`station::measure_forward`, what `sim-host station` runs), the message framed and written.
//! 240 rendered 640x480 frames over the flight envelope (distance 1.0-1.6 m, height 0.6-1.0 m, along the
//! whole line, roll and pitch within 5 deg, yaw within 10 deg), each as a raw part and as a PNG part; the
//! median and the 95th percentile of the per-frame time (a bench binary rather than criterion: criterion
//! reports means and medians of batches, the budget is about the tail of single frames).
use geometry::frames::Attitude;
use geometry::{Vec3, deg};
use ground_station::stream::{Frame, PartEncoding, StreamReader, StreamWriter};
use sim_host::Scenario;
use sim_host::render::ForwardRenderer;
use sim_host::station::{forward_image, measure_forward};
use sim_host::vision::GroundVision;
use std::time::Instant;

const FRAMES: usize = 240;

fn main() {
    let scenario = Scenario::paper();
    let renderer = ForwardRenderer::new(&scenario).expect("renderer");
    let mount = scenario.forward_camera_mount();
    let camera = scenario.forward_camera_model();
    // A fixed sequence of poses over the envelope (a small LCG: the same frames every run).
    let mut state = 0x2545_F491_4F6C_DD1Du64;
    let mut u = move || {
        state = state.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
        (state >> 40) as f32 / (1u64 << 24) as f32
    };
    let frames: Vec<Frame> = (0..FRAMES)
        .map(|k| {
            let att = Attitude::new(deg(10.0 * u() - 5.0), deg(10.0 * u() - 5.0), deg(20.0 * u() - 10.0));
            let r_wc = att.world_from_body().mul_mat(&mount.body_from_camera);
            let centre = Vec3::new(0.3 + 1.7 * u(), 1.0 + 0.6 * u(), 0.6 + 0.4 * u());
            let mut settings = renderer.default_settings();
            settings.seed = k as u64;
            let img = renderer.render(&r_wc, centre, &settings);
            Frame {
                seq: Some(k as u64),
                timestamp_us: Some(k as u64 * 33_333),
                width: img.width,
                height: img.height,
                channels: 3,
                data: img.data,
            }
        })
        .collect();
    println!(
        "station: forward frame (640x480) arrival to measurement on the radio, one core, {FRAMES} frames"
    );
    for (name, encoding) in [("raw part", PartEncoding::Raw), ("PNG part", PartEncoding::Png)] {
        let mut stream = Vec::new();
        {
            let mut w = StreamWriter::start(&mut stream, encoding).expect("stream head");
            for f in &frames {
                w.write(f).expect("part");
            }
        }
        let mut reader = StreamReader::start(&stream[..]).expect("stream");
        let mut vision = GroundVision::new(&scenario);
        let mut radio = Vec::with_capacity(1 << 20);
        let mut out = [0u8; protocol::frame::MAX_FRAME];
        let (mut total, mut decode, mut measured) = (Vec::new(), Vec::new(), 0);
        for _ in 0..FRAMES {
            let t0 = Instant::now();
            let f = reader.next_frame().expect("frame").expect("a frame");
            let t1 = Instant::now();
            let seq = f.seq.unwrap_or(0) as u32;
            let img = forward_image(f, &camera).expect("image");
            let m = measure_forward(&mut vision, &img, seq as u64 * 33_333, seq, None);
            measured += m.observation.is_some() as usize;
            let bytes = protocol::frame::encode(
                &protocol::Uplink::PackedVision(protocol::PackedVision::pack(&m)),
                &mut out,
            )
            .expect("frame");
            radio.extend_from_slice(bytes);
            let t2 = Instant::now();
            total.push((t2 - t0).as_secs_f64() * 1e3);
            decode.push((t1 - t0).as_secs_f64() * 1e3);
        }
        std::hint::black_box(&radio);
        let q = |v: &mut Vec<f64>, p: f64| {
            v.sort_by(f64::total_cmp);
            v[((v.len() - 1) as f64 * p).round() as usize]
        };
        println!(
            "  {name:8}  median {:.2} ms  p95 {:.2} ms  (of which the part's parsing and decoding: median {:.2} ms)  line found in {measured}/{FRAMES}",
            q(&mut total, 0.5),
            q(&mut total, 0.95),
            q(&mut decode, 0.5),
        );
    }
}
