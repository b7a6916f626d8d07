//! EuRoC/ASL import: a dataset in the ASL folder layout (written here from a known pose: IMU in the EuRoC
//! MAV's axes, frames rendered through the dataset's own camera intrinsics) imports into a log whose replay
//! runs the attitude estimator and the vision on it; the estimated attitude is the pose's.
use geometry::frames::Attitude;
use geometry::{Vec3, deg};
use sim_host::Scenario;
use sim_host::flightlog::{CameraId, LogRecord, open_log, read_log};
use sim_host::import::{EUROC_IMU_TO_BODY, EurocOptions, import_euroc};
use sim_host::render::ForwardRenderer;
use sim_host::replay::{ReplayOptions, replay_stream};
use sim_host::rng::SimRng;
use std::fmt::Write as _;

const SENSOR_YAML: &str = "sensor_type: camera
comment: VI-Sensor cam0 (MT9M034)
rate_hz: 20
resolution: [752, 480]
camera_model: pinhole
intrinsics: [458.654, 457.296, 367.215, 248.375] #fu, fv, cu, cv
distortion_model: radial-tangential
distortion_coefficients: [0.0, 0.0, 0.0, 0.0]
";

#[test]
fn a_euroc_dataset_imports_and_replays_through_the_estimator_and_the_vision() {
    let dir = std::env::temp_dir().join(format!("euroc-test-{}", std::process::id()));
    let root = dir.join("mav0");
    std::fs::create_dir_all(root.join("imu0")).unwrap();
    std::fs::create_dir_all(root.join("cam0").join("data")).unwrap();
    std::fs::write(root.join("cam0").join("sensor.yaml"), SENSOR_YAML).unwrap();

    // The vehicle holds still, tilted, 1.30 m from the wall, facing it.
    let att = Attitude { roll: deg(4.0), pitch: deg(-3.0), yaw: deg(2.0) };
    let r_wb = att.world_from_body();
    let position = Vec3::new(1.0, 1.3, 0.95);
    let g = control_core::GRAVITY;
    let f_body = r_wb.transpose().mul_vec(Vec3::new(0.0, 0.0, g));
    // IMU axes from body axes: the transpose of body-from-IMU.
    let m = EUROC_IMU_TO_BODY;
    let to_imu = |v: Vec3| {
        let b = v.to_array();
        [0, 1, 2].map(|j| (0..3).map(|i| m[i][j] * b[i]).sum::<f32>())
    };
    let t0: u64 = 1_403_636_579_758_555_392;
    let seconds = 8u64;
    let mut rng = SimRng::stream(3, "euroc-imu");
    let mut imu = String::from(
        "#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],\
         a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]\n",
    );
    for k in 0..seconds * 200 {
        let gyro = to_imu(Vec3::new(0.0, 0.0, 0.0));
        let acc = to_imu(f_body);
        let n = |s: f64, rng: &mut SimRng| (s * rng.normal()) as f32;
        writeln!(
            imu,
            "{},{},{},{},{},{},{}",
            t0 + k * 5_000_000,
            gyro[0] + n(0.002, &mut rng),
            gyro[1] + n(0.002, &mut rng),
            gyro[2] + n(0.002, &mut rng),
            acc[0] + n(0.02, &mut rng),
            acc[1] + n(0.02, &mut rng),
            acc[2] + n(0.02, &mut rng)
        )
        .unwrap();
    }
    std::fs::write(root.join("imu0").join("data.csv"), imu).unwrap();

    // Frames at 20 Hz through the dataset's camera (752x480, EuRoC cam0 intrinsics).
    let mut scenario = Scenario::paper();
    let c = &mut scenario.forward_camera;
    (c.width_px, c.height_px, c.fx_px, c.fy_px, c.cx_px, c.cy_px) =
        (752, 480, 458.654, 457.296, 367.215, 248.375);
    let renderer = ForwardRenderer::new(&scenario).unwrap();
    let mount = scenario.forward_camera_mount();
    let r_wc = r_wb.mul_mat(&mount.body_from_camera);
    let mut cams = String::from("#timestamp [ns],filename\n");
    for k in 0..seconds * 20 {
        let ts = t0 + 2_500_000 + k * 50_000_000;
        let mut settings = renderer.default_settings();
        settings.seed = k + 1;
        let img = renderer.render(&r_wc, position, &settings);
        sim_host::imageio::write_png_rgb(&root.join("cam0").join("data").join(format!("{ts}.png")), &img)
            .unwrap();
        writeln!(cams, "{ts},{ts}.png").unwrap();
    }
    std::fs::write(root.join("cam0").join("data.csv"), cams).unwrap();

    // Import (the folder above mav0, as the datasets unpack).
    let log_path = dir.join("imported.log");
    let opts = EurocOptions {
        dir: dir.clone(),
        scenario: Scenario::paper(),
        cam0: CameraId::Forward,
        imu_to_body: EUROC_IMU_TO_BODY,
        latency_s: 0.0,
        window: Default::default(),
    };
    let s = import_euroc(&opts, &log_path, |_| {}).unwrap();
    assert_eq!(s.imu_samples, seconds * 200);
    assert_eq!(s.frames, seconds * 20);
    assert!(s.measured >= s.frames * 9 / 10, "the line is found in the frames: {s:?}");
    let log = read_log(&log_path).unwrap();
    assert!(log.damage.is_empty());
    // The camera came from sensor.yaml.
    let imported = Scenario::from_toml(&log.header.scenario_toml).unwrap();
    assert_eq!((imported.forward_camera.width_px, imported.forward_camera.fx_px), (752, 458.654));
    assert!(log.records.iter().all(|(_, r)| !matches!(r, LogRecord::Report(_))));

    // Replay through the flight code, writing the replayed log.
    let replayed_path = dir.join("replayed.log");
    let reader = open_log(&log_path).unwrap();
    let header = reader.header.clone();
    let mut w = sim_host::flightlog::LogWriter::create(&replayed_path, &header).unwrap();
    let sum = replay_stream(&header, reader, &ReplayOptions::default(), Some(&mut w)).unwrap();
    w.finish().unwrap();
    assert_eq!(sum.compared, 0);
    assert!(sum.steps + 5 >= seconds * 500, "{}", sum.steps);
    let replayed = read_log(&replayed_path).unwrap();
    let last = replayed
        .records
        .iter()
        .rev()
        .find_map(|(_, r)| match r {
            LogRecord::Report(rep) => Some(*rep),
            _ => None,
        })
        .unwrap();
    let e = last.control.estimate;
    let err = |a: f32, b: f32| (a - b).to_degrees().abs();
    eprintln!(
        "estimate: roll {:.3} pitch {:.3} deg (truth 4, -3); position {:?}; vision {:?}",
        e.attitude.roll.to_degrees(),
        e.attitude.pitch.to_degrees(),
        e.position_m,
        last.vision
    );
    // The attitude estimator levels on the imported IMU in the body frame (the axis mapping is right).
    assert!(err(e.attitude.roll, att.roll) < 0.5 && err(e.attitude.pitch, att.pitch) < 0.5);
    // The vision solved the imported frames on board.
    assert!(
        last.vision.frames as u64 == s.frames && last.vision.solved as u64 >= s.frames / 2,
        "{:?}",
        last.vision
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_malformed_camera_calibration_is_refused_naming_the_file_and_the_field() {
    let dir = std::env::temp_dir().join(format!("euroc-badcal-{}", std::process::id()));
    let root = dir.join("mav0");
    std::fs::create_dir_all(root.join("imu0")).unwrap();
    std::fs::create_dir_all(root.join("cam0")).unwrap();
    std::fs::write(root.join("imu0").join("data.csv"), "#timestamp\n1000,0,0,0,0,0,9.8\n").unwrap();
    // Three intrinsics instead of four: before, the camera silently stayed the scenario's.
    std::fs::write(root.join("cam0").join("sensor.yaml"), SENSOR_YAML.replace(", 248.375]", "]")).unwrap();
    let opts = EurocOptions {
        dir: dir.clone(),
        scenario: Scenario::paper(),
        cam0: CameraId::Forward,
        imu_to_body: EUROC_IMU_TO_BODY,
        latency_s: 0.0,
        window: Default::default(),
    };
    let e = import_euroc(&opts, &dir.join("out.log"), |_| {}).unwrap_err().to_string();
    std::fs::remove_dir_all(&dir).ok();
    assert!(e.contains("sensor.yaml") && e.contains("intrinsics"), "{e}");
}
