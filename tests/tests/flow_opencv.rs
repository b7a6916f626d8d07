//! The flow's tracking against OpenCV's pyramidal Lucas-Kanade with its default settings, side by side on the
//! same rendered frame pairs at 320x240 and 640x480 (tests/python/opencv_lk.py runs OpenCV).
//!
//! The pairs are the downward camera, level, moved sideways by a known amount: every floor point then moves by
//! the same image displacement, so each track's error is its distance from that displacement, whichever
//! features a tracker picks. The floors are the scenarios' three kinds; the sensor noise, blur and vignetting
//! are the paper scenario's, the focal length scaled with the resolution.
use geometry::Vec3;
use geometry::frames::{Attitude, BODY_FROM_DOWN_CAMERA};
use sim_host::Scenario;
use sim_host::imageio::{GrayImage, write_png_gray};
use sim_host::render::{DownPose, DownRenderer};
use sim_host::rng::SimRng;
use std::path::Path;
use std::process::Command;
use vision_core::flow::{self, FlowParams, FlowWorkspace};
use vision_core::image::Gray8View;

/// The Python with OpenCV, or why there is none (a failure when `REQUIRE_OPENCV=1`, as CI sets it).
fn python_opencv() -> Option<String> {
    system_tests::python_with(
        "cv2, numpy",
        "pip install opencv-python-headless",
        "REQUIRE_OPENCV",
        "OpenCV's side of the comparison",
    )
}

/// The paper scenario's downward camera at `w x h` (the focal length scaled with the width), on a floor kind.
fn scenario(w: u16, h: u16, floor: &str) -> Scenario {
    let text = include_str!("../../sim-host/scenarios/paper.toml")
        .replace("floor_texture = \"speckled\"", &format!("floor_texture = \"{floor}\""));
    let mut s = Scenario::from_toml(&text).expect("the paper scenario");
    let k = w as f64 / s.down_camera.width_px as f64;
    let c = &mut s.down_camera;
    c.width_px = w;
    c.height_px = h;
    c.fx_px *= k;
    c.fy_px *= k;
    c.cx_px = (w as f64 - 1.0) / 2.0;
    c.cy_px = (h as f64 - 1.0) / 2.0;
    s
}

/// One rendered pair and the image displacement of every floor point between its frames (px).
struct Pair {
    a: GrayImage,
    b: GrayImage,
    shift: [f32; 2],
}

/// A level camera at a random height, place and heading, moved so that the floor moves by a random
/// displacement of up to `max_shift_px` in the image.
/// The second frame's exposure is `gain` times the first's.
fn pair(s: &Scenario, r: &DownRenderer, rng: &mut SimRng, max_shift_px: f64, gain: f64) -> Pair {
    let (mag, dir) = (rng.range(0.1, max_shift_px), rng.range(0.0, std::f64::consts::TAU));
    pair_with_shift_and_gain(s, r, rng, [mag * dir.cos(), mag * dir.sin()], gain)
}

/// A level camera at a random height, place and heading, moved so that the floor moves by `shift` (px).
fn pair_with_shift(s: &Scenario, r: &DownRenderer, rng: &mut SimRng, shift: [f64; 2]) -> Pair {
    pair_with_shift_and_gain(s, r, rng, shift, 1.0)
}

/// [`pair_with_shift`] with the second frame's exposure `gain` times the first's (auto exposure).
fn pair_with_shift_and_gain(
    s: &Scenario,
    r: &DownRenderer,
    rng: &mut SimRng,
    shift: [f64; 2],
    gain: f64,
) -> Pair {
    let height = rng.range(0.5, 1.5);
    let yaw = rng.range(-180.0, 180.0) as f32;
    let r_wc = Attitude::new(0.0, 0.0, geometry::deg(yaw)).world_from_body().mul_mat(&BODY_FROM_DOWN_CAMERA);
    let r_wc64 = r_wc.m.map(|row| row.map(|v| v as f64));
    // The floor moves by `shift` in the image when the camera moves by `-shift * height / f` along its own x, y.
    let f = s.down_camera.fx_px;
    let move_cam = Vec3::new((-shift[0] * height / f) as f32, (-shift[1] * height / f) as f32, 0.0);
    let move_world = r_wc.mul_vec(move_cam);
    let c0 = [rng.range(0.5, 2.0), rng.range(1.0, 1.6), height];
    let c1 = [c0[0] + move_world.x as f64, c0[1] + move_world.y as f64, height];
    let mut set = r.default_settings();
    set.seed = rng.next_u64();
    let a = r.render(&DownPose::still(r_wc64, c0), &set);
    set.seed = rng.next_u64();
    set.light_gain *= gain;
    let b = r.render(&DownPose::still(r_wc64, c1), &set);
    Pair { a, b, shift: [shift[0] as f32, shift[1] as f32] }
}

/// A directory removed when dropped, also when the test fails.
struct TempDir(std::path::PathBuf);

impl TempDir {
    fn new(name: &str) -> Self {
        let p = std::env::temp_dir().join(format!("{name}-{}", std::process::id()));
        std::fs::create_dir_all(&p).expect("temp dir");
        Self(p)
    }
    fn path(&self) -> &Path {
        &self.0
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        if let Err(e) = std::fs::remove_dir_all(&self.0) {
            eprintln!("could not remove {}: {e}", self.0.display());
        }
    }
}

fn median(v: &mut [f64]) -> f64 {
    assert!(!v.is_empty(), "no tracks");
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn percentile(v: &mut [f64], p: f64) -> f64 {
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * p).round() as usize]
}

/// Per-track errors of ours and of OpenCV (its own features, and ours given to it) over `n` pairs per floor.
struct Comparison {
    ours: Vec<f64>,
    cv_own: Vec<f64>,
    cv_given: Vec<f64>,
    ours_pairs_failed: usize,
    /// Per pair: the error of the median displacement (px), ours and OpenCV's (own features).
    ours_flow: Vec<f64>,
    cv_flow: Vec<f64>,
}

/// `exposure_step`: each pair's second frame is exposed this many times more, or less, than its first
/// (alternately), as auto exposure does; 1 for none.
fn compare(
    py: &str,
    w: u16,
    h: u16,
    n: usize,
    max_shift_px: f64,
    exposure_step: f64,
    params: &FlowParams,
) -> Comparison {
    static RUN: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
    let run = RUN.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let dir = TempDir::new(&format!("flow-opencv-{w}-{run}"));
    let mut ws = Box::new(FlowWorkspace::new());
    let mut jobs = Vec::new();
    let mut shifts = Vec::new();
    let mut out = Comparison {
        ours: vec![],
        cv_own: vec![],
        cv_given: vec![],
        ours_pairs_failed: 0,
        ours_flow: vec![],
        cv_flow: vec![],
    };
    for floor in ["speckled", "concrete", "plaster"] {
        let s = scenario(w, h, floor);
        let r = DownRenderer::new(&s).expect("renderer");
        let cam = s.down_camera_model();
        let mut rng = SimRng::stream(7, &format!("flow-opencv-{w}-{floor}"));
        for i in 0..n {
            let gain = if i % 2 == 0 { exposure_step } else { 1.0 / exposure_step };
            let p = pair(&s, &r, &mut rng, max_shift_px, gain);
            let (va, vb) = (
                Gray8View::packed(&p.a.data, p.a.width, p.a.height).expect("frame a"),
                Gray8View::packed(&p.b.data, p.b.width, p.b.height).expect("frame b"),
            );
            let mut points = Vec::new();
            match flow::flow_between(&va, &vb, &cam, params, Vec3::ZERO, &mut ws) {
                Ok(st) => {
                    let m = st.median_flow_px;
                    out.ours_flow.push(f64::from((m.x - p.shift[0]).hypot(m.y - p.shift[1])));
                    for (q, d, _) in ws.last_tracks() {
                        out.ours.push(f64::from((d.x - p.shift[0]).hypot(d.y - p.shift[1])));
                        points.push([q.x, q.y]);
                    }
                }
                Err(e) => {
                    eprintln!("{w}x{h} {floor} pair {i}: ours refused ({e:?})");
                    out.ours_pairs_failed += 1;
                }
            }
            let (fa, fb) = (
                dir.path().join(format!("{floor}-{i}-a.png")),
                dir.path().join(format!("{floor}-{i}-b.png")),
            );
            write_png_gray(&fa, &p.a).expect("png");
            write_png_gray(&fb, &p.b).expect("png");
            jobs.push(serde_json::json!({"a": fa, "b": fb, "points": points}));
            shifts.push(p.shift);
        }
    }
    let list = dir.path().join("pairs.json");
    std::fs::write(&list, serde_json::to_vec(&jobs).expect("json")).expect("pairs.json");
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("python/opencv_lk.py");
    let res = Command::new(py).arg(&script).arg(&list).output().expect("running OpenCV");
    assert!(res.status.success(), "OpenCV's script failed: {}", String::from_utf8_lossy(&res.stderr));
    let v: serde_json::Value = serde_json::from_slice(&res.stdout).expect("OpenCV's JSON");
    let pairs = v["pairs"].as_array().expect("pairs");
    assert_eq!(pairs.len(), shifts.len());
    for (pr, s) in pairs.iter().zip(&shifts) {
        let own = pr["own"].as_array().expect("tracks");
        if !own.is_empty() {
            let mut dx: Vec<f64> = own.iter().map(|t| t[2].as_f64().expect("dx")).collect();
            let mut dy: Vec<f64> = own.iter().map(|t| t[3].as_f64().expect("dy")).collect();
            let (mx, my) = (median(&mut dx), median(&mut dy));
            out.cv_flow.push((mx - f64::from(s[0])).hypot(my - f64::from(s[1])));
        }
        for (key, errs) in [("own", &mut out.cv_own), ("given", &mut out.cv_given)] {
            for t in pr[key].as_array().expect("tracks") {
                let (dx, dy) = (t[2].as_f64().expect("dx"), t[3].as_f64().expect("dy"));
                errs.push((dx - f64::from(s[0])).hypot(dy - f64::from(s[1])));
            }
        }
    }
    println!("{w}x{h} OpenCV {}: {} pairs", v["opencv"], shifts.len());
    out
}

/// Medians of the errors (px): per track, ours and OpenCV's own; per pair, ours and OpenCV's.
struct Medians {
    track: f64,
    cv_track: f64,
    flow: f64,
    cv_flow: f64,
}

fn report(w: u16, h: u16, c: &mut Comparison) -> Medians {
    let (o, co, cg) = (median(&mut c.ours), median(&mut c.cv_own), median(&mut c.cv_given));
    println!(
        "{w}x{h}: median track error ours {o:.4} px ({} tracks, p90 {:.4}, {} pairs refused), OpenCV own features \
         {co:.4} px ({} tracks, p90 {:.4}), OpenCV on our features {cg:.4} px ({} tracks, p90 {:.4})",
        c.ours.len(),
        percentile(&mut c.ours, 0.9),
        c.ours_pairs_failed,
        c.cv_own.len(),
        percentile(&mut c.cv_own, 0.9),
        c.cv_given.len(),
        percentile(&mut c.cv_given, 0.9),
    );
    let (fo, fc) = (median(&mut c.ours_flow), median(&mut c.cv_flow));
    println!(
        "{w}x{h}: per pair, the median displacement's error: ours median {fo:.4} px (p90 {:.4}), OpenCV {fc:.4} px (p90 {:.4})",
        percentile(&mut c.ours_flow, 0.9),
        percentile(&mut c.cv_flow, 0.9)
    );
    Medians { track: o, cv_track: co, flow: fo, cv_flow: fc }
}

/// `n` pairs per floor at `w x h` with [`FlowParams::for_image`], shifts up to 6 px per 320 of width and the
/// given exposure step: none refused by ours, and ours at least as accurate as OpenCV per track and per pair.
fn assert_at_least_as_accurate_as_opencv(py: &str, w: u16, h: u16, n: usize, exposure_step: f64) {
    let params = FlowParams::for_image(w, h);
    let mut c = compare(py, w, h, n, 6.0 * w as f64 / 320.0, exposure_step, &params);
    let r = report(w, h, &mut c);
    assert_eq!(c.ours_pairs_failed, 0, "{w}x{h}: ours refused pairs OpenCV tracked");
    assert!(r.track <= r.cv_track, "{w}x{h}: per track ours {} px, OpenCV {} px", r.track, r.cv_track);
    assert!(r.flow <= r.cv_flow, "{w}x{h}: per pair ours {} px, OpenCV {} px", r.flow, r.cv_flow);
}

#[test]
fn tracking_at_320x240_and_640x480_is_at_least_as_accurate_as_opencv() {
    let Some(py) = python_opencv() else { return };
    for (w, h) in [(320u16, 240u16), (640, 480)] {
        assert_at_least_as_accurate_as_opencv(&py, w, h, 40, 1.0);
    }
}

/// Auto exposure: the second frame of each pair 30 % brighter or darker than the first.
#[test]
fn an_exposure_step_of_30_percent_between_frames_is_not_read_as_motion() {
    let Some(py) = python_opencv() else { return };
    for (w, h) in [(320u16, 240u16), (640, 480)] {
        assert_at_least_as_accurate_as_opencv(&py, w, h, 20, 1.3);
    }
}

/// Reach: the floor moved by a third of the image width between the frames, with no prediction of it.
#[test]
fn a_motion_of_a_third_of_the_width_is_tracked() {
    for (w, h) in [(320u16, 240u16), (640, 480)] {
        let params = FlowParams::for_image(w, h);
        let mut ws = Box::new(FlowWorkspace::new());
        let (mut worst, mut refused) = (0.0f32, Vec::new());
        for floor in ["speckled", "concrete", "plaster"] {
            let s = scenario(w, h, floor);
            let r = DownRenderer::new(&s).expect("renderer");
            let cam = s.down_camera_model();
            let mut rng = SimRng::stream(11, &format!("flow-reach-{w}-{floor}"));
            for i in 0..8 {
                let dir = rng.range(0.0, std::f64::consts::TAU);
                let reach = w as f64 / 3.0;
                let p = pair_with_shift(&s, &r, &mut rng, [reach * dir.cos(), reach * dir.sin()]);
                let (va, vb) = (
                    Gray8View::packed(&p.a.data, p.a.width, p.a.height).expect("frame a"),
                    Gray8View::packed(&p.b.data, p.b.width, p.b.height).expect("frame b"),
                );
                match flow::flow_between(&va, &vb, &cam, &params, Vec3::ZERO, &mut ws) {
                    Ok(st) => {
                        let m = st.median_flow_px;
                        worst = worst.max((m.x - p.shift[0]).hypot(m.y - p.shift[1]));
                    }
                    Err(e) => refused.push((floor, i, p.shift, e)),
                }
            }
        }
        println!(
            "{w}x{h}: shifts of {:.0} px, worst flow error {worst:.3} px, refused {refused:?}",
            w as f32 / 3.0
        );
        assert!(refused.is_empty() && worst < 0.1, "{w}x{h}: worst {worst} px, refused {refused:?}");
    }
}
