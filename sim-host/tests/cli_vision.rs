//! The `render` and `vision pose` commands, run as a user would: exit codes, JSON, error messages.
use serde_json::Value;
use std::path::PathBuf;
use std::process::{Command, Output};

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_sim-host"))
}

fn tmp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("sim-host-cli-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

fn run(args: &[&str]) -> Output {
    bin().args(args).output().unwrap()
}

fn json(out: &Output) -> Value {
    serde_json::from_slice(&out.stdout)
        .unwrap_or_else(|e| panic!("stdout is not JSON ({e}): {}", String::from_utf8_lossy(&out.stdout)))
}

fn render(pose: &str, name: &str, extra: &[&str]) -> PathBuf {
    let p = tmp(name);
    let mut args = vec!["render", "--camera", "forward", "--pose", pose, "--out", p.to_str().unwrap()];
    args.extend_from_slice(extra);
    let out = run(&args);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    p
}

#[test]
fn render_then_pose_round_trip() {
    let img = render("1.15,1.45,0.8,2,-3,4", "mid.png", &["--seed", "5"]);
    for (extra, solver) in [(vec![], "image_only"), (vec!["--attitude", "2,-3"], "imu_aided")] {
        let mut args = vec!["vision", "pose", "--image", img.to_str().unwrap()];
        args.extend(extra);
        let out = run(&args);
        assert_eq!(out.status.code(), Some(0), "{}", String::from_utf8_lossy(&out.stderr));
        let j = json(&out);
        assert_eq!(j["status"], "ok");
        assert_eq!(j["solver"], solver);
        let p = &j["position_m"];
        let (x, y, z) = (p["x"].as_f64().unwrap(), p["y"].as_f64().unwrap(), p["z"].as_f64().unwrap());
        assert!((x - 1.15).abs() < 0.02 && (y - 1.45).abs() < 0.02 && (z - 0.8).abs() < 0.02, "{j}");
        assert_eq!(j["real_corners"], 4);
        assert_eq!(j["corners_px"].as_array().unwrap().len(), 4);
        assert!(j["reprojection_rms_px"].as_f64().unwrap() < 0.5);
        assert!(j["ambiguity_ratio"].as_f64().is_some());
        let rot = j["rotation"].as_array().unwrap();
        assert_eq!(rot.len(), 3);
        assert!((j["attitude_deg"]["yaw"].as_f64().unwrap() - 4.0).abs() < 0.5);
    }
}

#[test]
fn no_end_in_view_gives_x_null() {
    // Close to the wall, facing the middle of the line: both ends are outside the image.
    let img = render("1.15,0.6,0.95,0,0,0", "close.png", &[]);
    let out = run(&["vision", "pose", "--image", img.to_str().unwrap(), "--attitude", "0,0"]);
    assert_eq!(out.status.code(), Some(0));
    let j = json(&out);
    assert!(j["position_m"]["x"].is_null(), "{j}");
    assert!((j["position_m"]["y"].as_f64().unwrap() - 0.6).abs() < 0.02);
    assert_eq!(j["real_corners"], 0);
    assert!(j["corners_px"].as_array().unwrap().iter().all(Value::is_null));
}

#[test]
fn frame_without_the_line_is_no_target_exit_2() {
    let scen = tmp("blank.toml");
    let text = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/scenarios/paper.toml")).unwrap();
    std::fs::write(
        &scen,
        text.replace(
            "light_gradient_per_m = [0.0, 0.0]",
            "light_gradient_per_m = [0.0, 0.0]\nline_visible = false",
        ),
    )
    .unwrap();
    let img = render("1.15,1.3,0.8,0,0,0", "blank.png", &["--scenario", scen.to_str().unwrap()]);
    let out = run(&["vision", "pose", "--image", img.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(2));
    let j = json(&out);
    assert_eq!(j["status"], "no_target");
    assert_eq!(j["reason"], "no_red_pixels");
}

#[test]
fn bad_input_is_a_message_and_exit_1() {
    let not_png = tmp("not.png");
    std::fs::write(&not_png, b"this is not an image").unwrap();
    let cases: Vec<(Vec<String>, &str)> = vec![
        (
            vec!["vision".into(), "pose".into(), "--image".into(), not_png.display().to_string()],
            "not a readable PNG",
        ),
        (vec!["vision".into(), "pose".into(), "--image".into(), "/no/such/file.png".into()], "cannot read"),
        (
            vec!["render".into(), "--pose".into(), "1,2,3".into(), "--out".into(), "/tmp/x.png".into()],
            "expected 6",
        ),
        (
            vec!["render".into(), "--pose".into(), "1,2,3,a,0,0".into(), "--out".into(), "/tmp/x.png".into()],
            "not a number",
        ),
        (vec!["vision".into(), "pose".into(), "--image".into(), "x.png".into(), "--bogus".into()], "--bogus"),
        (
            vec![
                "vision".into(),
                "pose".into(),
                "--image".into(),
                "x.png".into(),
                "--scenario".into(),
                "nope".into(),
            ],
            "no scenario",
        ),
    ];
    for (args, msg) in cases {
        let out = bin().args(&args).output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{args:?}: {err}");
        assert!(err.contains(msg), "{args:?}: `{err}` should mention `{msg}`");
        assert!(out.stdout.is_empty(), "{args:?}");
    }
}

#[test]
fn wrong_size_and_grey_images_are_rejected() {
    let grey = tmp("grey.png");
    let img = sim_host::imageio::GrayImage::new(640, 480);
    sim_host::imageio::write_png_gray(&grey, &img).unwrap();
    let out = run(&["vision", "pose", "--image", grey.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("colour"));
    let small = tmp("small.png");
    sim_host::imageio::write_png_rgb(&small, &sim_host::imageio::RgbImage::new(320, 240)).unwrap();
    let out = run(&["vision", "pose", "--image", small.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("320x240"));
}

#[test]
fn help_exits_0() {
    let out = run(&["--help"]);
    assert_eq!(out.status.code(), Some(0));
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("render") && text.contains("vision"));
}

#[test]
fn pose_and_flow_read_jpeg_frames_as_webcams_deliver_them() {
    // The rendered frame as a webcam's JPEG (quality 90, 4:2:2 with the chroma of each pair averaged).
    let png = render("1.15,1.45,0.8,2,-3,4", "for-jpeg.png", &["--seed", "6"]);
    let img = sim_host::imageio::read_png_rgb(&png).unwrap();
    let mut bytes = Vec::new();
    let mut enc = jpeg_encoder::Encoder::new(&mut bytes, 90);
    enc.set_sampling_factor(jpeg_encoder::SamplingFactor::R_4_2_2);
    enc.set_chroma_subsampling_method(jpeg_encoder::ChromaSubsamplingMethod::Average);
    enc.encode(&img.data, img.width as u16, img.height as u16, jpeg_encoder::ColorType::Rgb).unwrap();
    let jpg = tmp("frame.jpg");
    std::fs::write(&jpg, &bytes).unwrap();
    let out = run(&["vision", "pose", "--image", jpg.to_str().unwrap(), "--attitude", "2,-3"]);
    assert_eq!(out.status.code(), Some(0), "{}", String::from_utf8_lossy(&out.stderr));
    let j = json(&out);
    let p = &j["position_m"];
    let (x, y, z) = (p["x"].as_f64().unwrap(), p["y"].as_f64().unwrap(), p["z"].as_f64().unwrap());
    assert!((x - 1.15).abs() < 0.02 && (y - 1.45).abs() < 0.02 && (z - 0.8).abs() < 0.02, "{j}");
    // Flow between two JPEG frames of the downward camera (the same frame twice: no motion).
    let down = tmp("down.png");
    let r =
        run(&["render", "--camera", "down", "--pose", "0.5,1.0,0.7,0,0,0", "--out", down.to_str().unwrap()]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let g = sim_host::imageio::read_png_gray(&down).unwrap();
    let mut bytes = Vec::new();
    jpeg_encoder::Encoder::new(&mut bytes, 90)
        .encode(&g.data, g.width as u16, g.height as u16, jpeg_encoder::ColorType::Luma)
        .unwrap();
    let djpg = tmp("down.jpg");
    std::fs::write(&djpg, &bytes).unwrap();
    let out = run(&["vision", "flow", "--prev", djpg.to_str().unwrap(), "--next", djpg.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(0), "{}", String::from_utf8_lossy(&out.stderr));
    // A file that is neither: named as such.
    let bad = tmp("bad.jpg");
    std::fs::write(&bad, [0xFF, 0xD8, 0xFF, 0xE0, 1, 2, 3]).unwrap();
    let out = run(&["vision", "pose", "--image", bad.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("bad.jpg") && err.contains("JPEG"), "{err}");
}
