//! A webcam's buffers through the station's V4L2 decoding (`ground_station::v4l2`), on rendered frames
//! encoded as a UVC camera sends them: MJPEG at a webcam's quality with the Huffman tables left out (the
//! AVI1 convention: the decoder must supply the standard ones) and with them, and YUYV 4:2:2 in BT.601 studio
//! range. The line's corners measured on the decoded frames against those measured on the frames themselves,
//! over the flight envelope.
use geometry::frames::Attitude;
use geometry::{Vec3, deg};
use ground_station::v4l2::{BufferError, PixelFormat, buffer_to_frame};
use sim_host::Scenario;
use sim_host::imageio::RgbImage;
use sim_host::render::ForwardRenderer;
use sim_host::vision::GroundVision;

/// JPEG segments before the scan, without the Huffman tables (DHT, `FF C4`): a UVC camera's MJPEG frame.
fn without_huffman_tables(jpeg: &[u8]) -> Vec<u8> {
    assert_eq!(&jpeg[..2], [0xFF, 0xD8], "SOI");
    let mut out = vec![0xFF, 0xD8];
    let mut i = 2;
    let mut dropped = 0;
    loop {
        assert_eq!(jpeg[i], 0xFF, "a marker at byte {i}");
        let marker = jpeg[i + 1];
        let len = u16::from_be_bytes([jpeg[i + 2], jpeg[i + 3]]) as usize;
        if marker == 0xDA {
            // The scan and everything after it.
            out.extend_from_slice(&jpeg[i..]);
            break;
        }
        if marker == 0xC4 {
            dropped += 1;
        } else {
            out.extend_from_slice(&jpeg[i..i + 2 + len]);
        }
        i += 2 + len;
    }
    assert!(dropped > 0, "the encoder wrote Huffman tables");
    out
}

/// A webcam's MJPEG frame: 4:2:2 (the chroma of each pixel pair averaged, centred as JFIF sites it).
fn jpeg(img: &RgbImage, quality: u8) -> Vec<u8> {
    let mut out = Vec::new();
    let mut enc = jpeg_encoder::Encoder::new(&mut out, quality);
    enc.set_sampling_factor(jpeg_encoder::SamplingFactor::R_4_2_2);
    enc.set_chroma_subsampling_method(jpeg_encoder::ChromaSubsamplingMethod::Average);
    enc.encode(&img.data, img.width as u16, img.height as u16, jpeg_encoder::ColorType::Rgb).unwrap();
    out
}

/// BT.601 studio-range YUYV of an RGB image (chroma averaged over pixel pairs), as the camera computes it.
fn yuyv(img: &RgbImage) -> Vec<u8> {
    let f = |p: &[u8]| {
        let (r, g, b) = (p[0] as f32, p[1] as f32, p[2] as f32);
        (
            16.0 + (65.481 * r + 128.553 * g + 24.966 * b) / 255.0,
            128.0 + (-37.797 * r - 74.203 * g + 112.0 * b) / 255.0,
            128.0 + (112.0 * r - 93.786 * g - 18.214 * b) / 255.0,
        )
    };
    let q = |v: f32| v.round().clamp(0.0, 255.0) as u8;
    img.data
        .chunks_exact(6)
        .flat_map(|p| {
            let (a, b) = (f(&p[..3]), f(&p[3..]));
            [q(a.0), q((a.1 + b.1) / 2.0), q(b.0), q((a.2 + b.2) / 2.0)]
        })
        .collect()
}

#[test]
fn the_line_measured_on_decoded_webcam_buffers_matches_the_frames_own() {
    let scenario = Scenario::paper();
    let renderer = ForwardRenderer::new(&scenario).unwrap();
    let mount = scenario.forward_camera_mount();
    let camera = scenario.forward_camera_model();
    let (w, h) = (camera.width as usize, camera.height as usize);
    let mut vision = GroundVision::new(&scenario);
    // Worst corner offset (px) against the frame's own corners, per encoding; frames measured.
    let mut worst = [0.0f32; 3];
    let mut all: [Vec<f32>; 3] = Default::default();
    let mut measured = 0;
    for k in 0..24 {
        let s = k as f32 / 23.0;
        let att = Attitude::new(deg(5.0 * (s * 7.0).sin()), deg(-4.0 + 8.0 * s), deg(8.0 * (s * 5.0).cos()));
        let r_wc = att.world_from_body().mul_mat(&mount.body_from_camera);
        let centre = Vec3::new(0.2 + 2.0 * s, 1.0 + 0.6 * (s * 3.0).sin().abs(), 0.6 + 0.4 * s);
        let mut settings = renderer.default_settings();
        settings.seed = k;
        let img = renderer.render(&r_wc, centre, &settings);
        let Ok(truth) = vision.detect(&img) else { continue };
        measured += 1;
        let full = jpeg(&img, 85);
        let buffers = [
            (PixelFormat::Mjpeg, without_huffman_tables(&full)),
            (PixelFormat::Mjpeg, full),
            (PixelFormat::Yuyv, yuyv(&img)),
        ];
        for (i, (format, buf)) in buffers.iter().enumerate() {
            let f = buffer_to_frame(*format, buf, w, h, 3).unwrap();
            let decoded = RgbImage { width: f.width, height: f.height, data: f.data };
            let obs = vision.detect(&decoded).unwrap_or_else(|e| panic!("frame {k}, buffer {i}: {e:?}"));
            assert_eq!(obs.real_corners(), truth.real_corners(), "frame {k}, buffer {i}");
            for (a, b) in obs.corners_px(&camera).iter().zip(truth.corners_px(&camera)) {
                if let (Some(a), Some(b)) = (a, b) {
                    worst[i] = worst[i].max((*a - b).norm());
                    all[i].push((*a - b).norm());
                }
            }
        }
    }
    for (v, name) in all.iter_mut().zip(["MJPEG without tables", "MJPEG with tables", "YUYV"]) {
        v.sort_by(f32::total_cmp);
        eprintln!(
            "{name}: corner offset median {:.3} px, p90 {:.3} px, max {:.3} px over {} corners of {measured} frames",
            v[v.len() / 2],
            v[v.len() * 9 / 10],
            v[v.len() - 1],
            v.len()
        );
    }
    assert!(measured >= 20, "{measured} frames with the line");
    // Each corner comes from two fitted edges of hundreds of points: compression and chroma subsampling move
    // it by a fraction of a pixel. Measured on the sRGB camera (the encoder's errors are in encoded values,
    // and decoding to linear light multiplies them by up to 2 in the bright wall): MJPEG at quality 85
    // median 0.16 px, max 0.58 px; YUYV median 0.09 px, max 0.28 px (on a linear camera it was 0.12 / 0.37
    // and 0.03 / 0.16 px). Chroma sited otherwise than JFIF says (the top-left pixel of each pair instead of
    // their average) moves every corner by about 0.45 px to the right: the medians would fail here.
    let median = |v: &[f32]| v[v.len() / 2];
    assert!(all.iter().all(|v| median(v) < 0.25), "medians {:?}", all.each_ref().map(|v| median(v)));
    assert!(worst[0] < 0.7 && worst[1] < 0.7 && worst[2] < 0.35, "{worst:?}");
    // Stripping the tables changes nothing: the standard ones are what the encoder wrote.
    assert_eq!(worst[0], worst[1]);
}

#[test]
fn a_buffer_of_another_size_than_the_calibration_is_refused_with_both_sizes() {
    let img = RgbImage { width: 64, height: 48, data: vec![90; 64 * 48 * 3] };
    let e = buffer_to_frame(PixelFormat::Mjpeg, &jpeg(&img, 85), 640, 480, 3).unwrap_err();
    assert_eq!(e, BufferError::Size { want: (640, 480), got: (64, 48) });
    assert!(e.to_string().contains("64x48") && e.to_string().contains("640x480"), "{e}");
    // Grey from MJPEG: the luma.
    let f = buffer_to_frame(PixelFormat::Mjpeg, &jpeg(&img, 95), 64, 48, 1).unwrap();
    assert_eq!(f.channels, 1);
    assert!(f.data.iter().all(|&v| v.abs_diff(90) <= 1), "{:?}", &f.data[..8]);
}

#[test]
fn the_station_measures_a_streamed_frame_exactly_as_the_simulator_measures_it() {
    // The SIL's ground station measures the rendered frame in memory; the station gets it through the frame
    // stream (a raw or a PNG part, both lossless) and measures it with `station::measure_forward`: the same
    // measurement, byte for byte, frame after frame.
    use ground_station::stream::{Frame, PartEncoding, StreamReader, StreamWriter};
    let scenario = Scenario::paper();
    let renderer = ForwardRenderer::new(&scenario).unwrap();
    let mount = scenario.forward_camera_mount();
    let camera = scenario.forward_camera_model();
    for encoding in [PartEncoding::Raw, PartEncoding::Png] {
        let (mut sil, mut station) = (GroundVision::new(&scenario), GroundVision::new(&scenario));
        let mut images = Vec::new();
        let mut stream = Vec::new();
        {
            let mut w = StreamWriter::start(&mut stream, encoding).unwrap();
            for k in 0..12u64 {
                let s = k as f32 / 11.0;
                let att = Attitude::new(deg(2.0 * s), deg(-3.0 + 4.0 * s), deg(6.0 * s - 3.0));
                let r_wc = att.world_from_body().mul_mat(&mount.body_from_camera);
                let mut settings = renderer.default_settings();
                settings.seed = k;
                let img = renderer.render(&r_wc, Vec3::new(0.2 + 2.0 * s, 1.3, 0.8), &settings);
                let f = Frame {
                    seq: Some(k),
                    timestamp_us: Some(1_000 * k),
                    width: img.width,
                    height: img.height,
                    channels: 3,
                    data: img.data.clone(),
                };
                w.write(&f).unwrap();
                images.push(img);
            }
        }
        let mut reader = StreamReader::start(&stream[..]).unwrap();
        for (k, img) in images.iter().enumerate() {
            let f = reader.next_frame().unwrap().unwrap();
            let streamed = sim_host::station::forward_image(f, &camera).unwrap();
            let m = sim_host::station::measure_forward(&mut station, &streamed, 7, k as u32, None);
            let want = sil.detect(img).ok();
            assert_eq!(
                postcard::to_allocvec(&m.observation).unwrap(),
                postcard::to_allocvec(&want).unwrap(),
                "{encoding:?} frame {k}"
            );
            assert!(want.is_some(), "frame {k} has the line");
        }
    }
}
