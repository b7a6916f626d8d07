//! Export: an MCAP file read back by the `mcap` crate's own reader, and by Python's `mcap` and
//! `mcap-protobuf-support` readers, has one channel per topic, Foxglove's protobuf schemas for poses, images,
//! annotations, body frames and the scene, JSON Schemas for our records, and as many messages as the log has
//! records of each kind, with their content; the CSV files agree.
use foxglove::Decode;
use foxglove::messages::{
    CompressedImage, FrameTransforms, ImageAnnotations, PoseInFrame, SceneUpdate, points_annotation,
};
use sim_host::flightlog::{CameraId, FramePolicy, LogRecord, open_log, read_log};
use sim_host::scenario::Scenario;
use sim_host::sil::CameraMode;
use std::collections::BTreeMap;
use std::path::Path;
use std::process::{Command, Stdio};

/// The Python with `mcap` and `mcap-protobuf-support`, or why there is none (a failure when
/// `REQUIRE_PYTHON_MCAP=1`, as CI sets it).
fn python_mcap() -> Option<String> {
    system_tests::python_with(
        "mcap, mcap_protobuf",
        "pip install mcap mcap-protobuf-support",
        "REQUIRE_PYTHON_MCAP",
        "the Python readers' half",
    )
}

/// What tests/python/read_mcap.py decoded from `mcap`.
fn read_with_python(py: &str, mcap: &Path) -> serde_json::Value {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("python/read_mcap.py");
    let out = Command::new(py).arg(&script).arg(mcap).output().expect("running the Python reader");
    assert!(out.status.success(), "the Python reader failed: {}", String::from_utf8_lossy(&out.stderr));
    serde_json::from_slice(&out.stdout).expect("the Python reader's JSON")
}

fn sha256_hex(data: &[u8]) -> String {
    let out = Command::new("sha256sum")
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .and_then(|mut c| {
            use std::io::Write;
            c.stdin.take().expect("stdin").write_all(data)?;
            c.wait_with_output()
        })
        .expect("sha256sum");
    String::from_utf8_lossy(&out.stdout).split_whitespace().next().unwrap_or_default().to_string()
}

#[test]
fn an_exported_mcap_reads_back_with_the_expected_channels_and_counts() {
    let log_path = system_tests::fly_logged("export-test", 4, 3.0, CameraMode::Rendered, FramePolicy::Png);
    let out = log_path.parent().unwrap().to_path_buf();
    let log = read_log(&log_path).unwrap();

    // What the log holds, counted independently of the exporter.
    let mut expected: BTreeMap<&str, u64> = BTreeMap::new();
    let mut add = |t: &'static str, n: u64| *expected.entry(t).or_insert(0) += n;
    // The scene at the first report, then at the first report at least 0.1 s after the previous scene.
    let (mut step_us, mut next_scene_us) = (0u64, 0u64);
    for (_, r) in &log.records {
        match r {
            LogRecord::Step(s) => {
                step_us = s.time_us;
                add("/imu", s.imu.len() as u64);
                add("/mag", s.mag.is_some() as u64);
            }
            LogRecord::Report(rep) => {
                for t in ["/estimate/pose", "/estimate", "/setpoint", "/motors", "/status", "/counters"] {
                    add(t, 1);
                }
                add("/flow/outcome", rep.flow.is_some() as u64);
                add("/tf", 1);
                if step_us >= next_scene_us {
                    add("/scene", 1);
                    next_scene_us = step_us + 100_000;
                }
            }
            LogRecord::Link(m) if m.vision().is_some() => add("/link/vision", 1),
            LogRecord::Link(m) if m.flow().is_some() => add("/link/flow", 1),
            LogRecord::Link(_) => add("/link/other", 1),
            LogRecord::Downlink(d) if d.telemetry().is_some() => add("/downlink/telemetry", 1),
            LogRecord::Downlink(protocol::Downlink::Battery(_)) => add("/downlink/battery", 1),
            LogRecord::Downlink(_) => add("/downlink/other", 1),
            LogRecord::Truth { .. } => {
                add("/truth/pose", 1);
                add("/truth", 1);
            }
            LogRecord::Reference(_) => {
                add("/reference/pose", 1);
                add("/reference", 1);
            }
            LogRecord::Frame(f) if f.camera == CameraId::Forward => {
                add("/camera/forward/image", 1);
                add("/camera/forward/annotations", 1);
            }
            LogRecord::Frame(_) => add("/camera/down/image", 1),
            LogRecord::Pilot(_) => add("/pilot", 1),
            LogRecord::Battery(_) => add("/battery/reading", 1),
            // The file's end record has no topic; a simulated flight's log has no station records (the
            // station's export is checked by sim-host/tests/station_e2e.rs).
            LogRecord::End { .. } => {}
            LogRecord::Station(e) => panic!("a station record in a simulated flight's log: {e:?}"),
        }
    }
    expected.retain(|_, n| *n > 0);
    assert_eq!(expected["/camera/forward/image"], 91);
    assert_eq!(expected["/estimate"], 1500);
    assert_eq!(expected["/scene"], 30);

    let mcap_path = out.join("flight.mcap");
    let reader = open_log(&log_path).unwrap();
    let header = reader.header.clone();
    let s = sim_host::export::export_mcap(&header, reader, &mcap_path).unwrap();
    assert!(s.damage.is_empty() && s.notes.is_empty(), "{:?} {:?}", s.damage, s.notes);

    // Read back with the mcap crate: the summary section's statistics and channels.
    let bytes = std::fs::read(&mcap_path).unwrap();
    let summary = mcap::Summary::read(&bytes).unwrap().expect("a summary section");
    let stats = summary.stats.as_ref().expect("statistics");
    let mut counts: BTreeMap<String, u64> = BTreeMap::new();
    for (id, n) in &stats.channel_message_counts {
        counts.insert(summary.channels[id].topic.clone(), *n);
    }
    let expected_owned: BTreeMap<String, u64> = expected.iter().map(|(k, v)| (k.to_string(), *v)).collect();
    assert_eq!(counts, expected_owned);
    assert_eq!(stats.message_count, expected.values().sum::<u64>());
    // Foxglove's typed schemas (protobuf, the SDK's FileDescriptorSets) for what has one; JSON for ours.
    let foxglove_schema = |topic: &str| match topic {
        "/estimate/pose" | "/truth/pose" | "/reference/pose" => Some("foxglove.PoseInFrame"),
        "/camera/forward/image" | "/camera/down/image" => Some("foxglove.CompressedImage"),
        "/camera/forward/annotations" => Some("foxglove.ImageAnnotations"),
        "/tf" => Some("foxglove.FrameTransforms"),
        "/scene" => Some("foxglove.SceneUpdate"),
        _ => None,
    };
    for ch in summary.channels.values() {
        let schema = ch.schema.as_ref().expect("a schema");
        match foxglove_schema(&ch.topic) {
            Some(name) => {
                assert_eq!(
                    (ch.message_encoding.as_str(), schema.encoding.as_str()),
                    ("protobuf", "protobuf")
                );
                assert_eq!(schema.name, name, "{}", ch.topic);
                assert!(schema.data.len() > 100, "{}: a FileDescriptorSet", ch.topic);
            }
            None => {
                assert_eq!((ch.message_encoding.as_str(), schema.encoding.as_str()), ("json", "jsonschema"));
                assert!(schema.name.starts_with("wlq."), "{}: {}", ch.topic, schema.name);
                serde_json::from_slice::<serde_json::Value>(&schema.data).expect("the schema is JSON");
            }
        }
    }

    // Every message in order: the forward images are the logged frames, the poses the reports; the line
    // over the first image is where the estimate of the moment reprojects it; the last body frames are the
    // last estimate and truth; the scene has the wall, the estimate and the truth.
    let scenario = Scenario::from_toml(&header.scenario_toml).unwrap();
    let frames: Vec<_> = log
        .records
        .iter()
        .filter_map(|(_, r)| match r {
            LogRecord::Frame(f) if f.camera == CameraId::Forward => Some(f.clone()),
            _ => None,
        })
        .collect();
    let reports: Vec<_> = log
        .records
        .iter()
        .filter_map(|(_, r)| match r {
            LogRecord::Report(rep) => Some(rep.control.estimate),
            _ => None,
        })
        .collect();
    let mut last_truth = None;
    // The truth when the last report came (the last body frames are written with the report).
    let mut truth = None;
    for (_, r) in &log.records {
        match r {
            LogRecord::Truth { position_m, .. } => truth = Some(*position_m),
            LogRecord::Report(_) => last_truth = truth,
            _ => {}
        }
    }
    // The first forward frame after the first report, and the estimate it reprojects (an earlier frame has
    // no estimate yet, hence no line).
    let (mut latest, mut forward_seen, mut first_with_estimate) = (None, 0usize, None);
    for (_, r) in &log.records {
        match r {
            LogRecord::Report(rep) => {
                latest = Some((rep.control.estimate.position_m, rep.control.estimate.q))
            }
            LogRecord::Frame(f) if f.camera == CameraId::Forward => {
                if let Some(e) = latest {
                    first_with_estimate = Some((forward_seen, e));
                    break;
                }
                forward_seen += 1;
            }
            _ => {}
        }
    }
    let (line_frame, estimate) = first_with_estimate.expect("a forward frame after a report");
    let expected_line = sim_host::foxglove_msgs::reprojected_corners(&scenario, estimate)
        .expect("the line in front of the camera");
    let (mut images, mut poses, mut annotations) = (0, 0, 0);
    let (mut last_tf, mut last_scene) = (None, None);
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        let m = m.unwrap();
        match m.channel.topic.as_str() {
            "/camera/forward/image" => {
                let img = CompressedImage::decode(&m.data[..]).unwrap();
                assert_eq!(img.format, "png");
                assert_eq!(img.frame_id, "camera_forward");
                assert_eq!(&img.data[..], &frames[images].data[..]);
                assert_eq!(m.log_time, frames[images].capture_time_us * 1000);
                images += 1;
            }
            "/camera/forward/annotations" => {
                let a = ImageAnnotations::decode(&m.data[..]).unwrap();
                let lines = a.points.iter().filter(|p| p.r#type == points_annotation::Type::LineLoop as i32);
                assert_eq!(lines.count(), usize::from(annotations >= line_frame), "frame {annotations}");
                if annotations == line_frame {
                    let lines: Vec<_> = a
                        .points
                        .iter()
                        .filter(|p| p.r#type == points_annotation::Type::LineLoop as i32)
                        .collect();
                    assert_eq!(lines.len(), 1, "one reprojected line");
                    for (p, q) in lines[0].points.iter().zip(expected_line) {
                        assert!(
                            (p.x - q.x as f64).abs() < 1e-3 && (p.y - q.y as f64).abs() < 1e-3,
                            "{p:?} {q:?}"
                        );
                    }
                }
                annotations += 1;
            }
            "/estimate/pose" => {
                let v = PoseInFrame::decode(&m.data[..]).unwrap();
                let e = &reports[poses];
                let pose = v.pose.unwrap();
                let (p, q) = (pose.position.unwrap(), pose.orientation.unwrap());
                assert_eq!([p.x as f32, p.y as f32, p.z as f32], e.position_m.to_array());
                assert_eq!([q.w as f32, q.x as f32, q.y as f32, q.z as f32], [e.q.w, e.q.x, e.q.y, e.q.z]);
                assert_eq!(v.frame_id, "world");
                poses += 1;
            }
            "/tf" => last_tf = Some(FrameTransforms::decode(&m.data[..]).unwrap()),
            "/scene" => last_scene = Some(SceneUpdate::decode(&m.data[..]).unwrap()),
            _ => {}
        }
    }
    assert_eq!((images, poses, annotations), (91, 1500, 91));
    let tf = last_tf.expect("body frames");
    let by_child: BTreeMap<&str, [f64; 3]> = tf
        .transforms
        .iter()
        .map(|t| {
            assert_eq!(t.parent_frame_id, "world");
            let v = t.translation.unwrap();
            (t.child_frame_id.as_str(), [v.x, v.y, v.z])
        })
        .collect();
    let last = reports.last().unwrap().position_m.to_array().map(|v| v as f64);
    assert_eq!(by_child["base_link"], last);
    assert_eq!(by_child["base_link_truth"], last_truth.unwrap().map(|v| v as f64));
    let ids: Vec<_> = last_scene.expect("a scene").entities.iter().map(|e| e.id.clone()).collect();
    assert_eq!(ids, ["wall", "vehicle_estimate", "vehicle_truth"]);

    // The same file through Python's readers (Foxglove's own): the same channels, schemas and counts, every
    // message decoded, the poses, images, body frames and scene equal to the log's.
    if let Some(py) = python_mcap() {
        let v = read_with_python(&py, &mcap_path);
        let chans = v["channels"].as_object().unwrap();
        let py_counts: BTreeMap<String, u64> =
            chans.iter().map(|(k, c)| (k.clone(), c["count"].as_u64().unwrap())).collect();
        assert_eq!(py_counts, expected_owned);
        for (topic, c) in chans {
            match foxglove_schema(topic) {
                Some(name) => {
                    assert_eq!(c["message_encoding"], "protobuf", "{topic}");
                    assert_eq!(c["schema_name"], name, "{topic}");
                }
                None => assert_eq!(c["message_encoding"], "json", "{topic}"),
            }
        }
        let py_poses = v["estimate_poses"].as_array().unwrap();
        assert_eq!(py_poses.len(), reports.len());
        for (p, e) in py_poses.iter().zip(&reports) {
            let f = |i: usize| p[i].as_f64().unwrap() as f32;
            assert_eq!([f(1), f(2), f(3)], e.position_m.to_array());
            assert_eq!(f(7), e.q.w);
        }
        let py_images = v["forward_images"].as_array().unwrap();
        assert_eq!(py_images.len(), frames.len());
        for (i, f) in [0, frames.len() - 1].map(|i| (i, &frames[i])) {
            assert_eq!(py_images[i][0].as_u64().unwrap(), f.capture_time_us * 1000);
            assert_eq!(py_images[i][1], "png");
            assert_eq!(py_images[i][2].as_str().unwrap(), sha256_hex(&f.data));
        }
        let tf = &v["tf_last"]["base_link"];
        assert_eq!(tf[0], "world");
        assert_eq!([1, 2, 3].map(|i| tf[i].as_f64().unwrap()), last);
        assert_eq!(v["scene_last"], serde_json::json!(["wall", "vehicle_estimate", "vehicle_truth"]));
        let first = &v["forward_annotations_first"];
        assert_eq!(first["index"].as_u64(), Some(line_frame as u64));
        let line: Vec<_> = first["points"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|a| a["type"] == points_annotation::Type::LineLoop as i32)
            .collect();
        assert_eq!(line.len(), 1);
        for (p, q) in line[0]["points"].as_array().unwrap().iter().zip(expected_line) {
            assert!((p[0].as_f64().unwrap() - q.x as f64).abs() < 1e-3, "{p} {q:?}");
            assert!((p[1].as_f64().unwrap() - q.y as f64).abs() < 1e-3, "{p} {q:?}");
        }
        assert_eq!(v["metadata"]["flight"].as_array().unwrap().len(), 6);
    }

    // CSV: one file per topic, a header with the time first, one row per message.
    let csv = out.join("csv");
    let reader = open_log(&log_path).unwrap();
    sim_host::export::export_csv(&header, reader, &csv).unwrap();
    let est = std::fs::read_to_string(csv.join("estimate.csv")).unwrap();
    let mut lines = est.lines();
    let head: Vec<&str> = lines.next().unwrap().split(',').collect();
    assert_eq!(head[0], "t_s");
    assert!(head.contains(&"position_m.y") && head.contains(&"attitude_deg.roll"));
    assert_eq!(lines.count(), 1500);
    let frames = std::fs::read_to_string(csv.join("frames.csv")).unwrap();
    assert_eq!(frames.lines().count(), 1 + 91 + 181);
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn a_full_disk_keeps_what_the_mcap_export_wrote_and_says_so() {
    let log_path = system_tests::fly_logged("export-full", 2, 2.0, CameraMode::Analytic, FramePolicy::Drop);
    let out = log_path.parent().unwrap().join("full.mcap");
    let header = open_log(&log_path).unwrap().header.clone();
    let file = sim_host::files::AtomicFile::create_with_space(&out, 50_000).unwrap();
    let e = sim_host::export::export_mcap_to(&header, open_log(&log_path).unwrap(), file).unwrap_err();
    let msg = format!("{e:#}");
    let kept = sim_host::files::AtomicFile::partial_path(&out);
    assert!(msg.contains("full.mcap") && msg.contains(&*kept.to_string_lossy()), "{msg}");
    assert!(!out.exists(), "no file under the final name");
    let bytes = std::fs::read(&kept).unwrap();
    assert_eq!(bytes.len(), 50_000, "everything that reached the disk is kept");
    assert!(bytes.starts_with(b"\x89MCAP0\r\n"));
    std::fs::remove_file(&kept).unwrap();
}
