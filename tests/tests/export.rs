//! Export: an MCAP file read back by the `mcap` crate's own reader has one channel per topic, the expected
//! schemas and as many messages as the log has records of each kind; the CSV files agree.
use sim_host::flightlog::{CameraId, FramePolicy, LogRecord, open_log, read_log};
use sim_host::sil::CameraMode;
use std::collections::BTreeMap;

fn base64_decode(s: &str) -> Vec<u8> {
    let val = |c: u8| match c {
        b'A'..=b'Z' => c - b'A',
        b'a'..=b'z' => c - b'a' + 26,
        b'0'..=b'9' => c - b'0' + 52,
        b'+' => 62,
        b'/' => 63,
        _ => panic!("not base64: {c}"),
    };
    let mut out = Vec::new();
    for chunk in s.as_bytes().chunks(4) {
        let n = chunk.iter().take_while(|&&c| c != b'=').count();
        let mut acc = 0u32;
        for (i, &c) in chunk.iter().enumerate() {
            acc |= (if i < n { val(c) as u32 } else { 0 }) << (18 - 6 * i);
        }
        out.extend_from_slice(&acc.to_be_bytes()[1..n]);
    }
    out
}

#[test]
fn an_exported_mcap_reads_back_with_the_expected_channels_and_counts() {
    let log_path = system_tests::fly_logged("export-test", 4, 3.0, CameraMode::Rendered, FramePolicy::Png);
    let out = log_path.parent().unwrap().to_path_buf();
    let log = read_log(&log_path).unwrap();

    // What the log holds, counted independently of the exporter.
    let mut expected: BTreeMap<&str, u64> = BTreeMap::new();
    let mut add = |t: &'static str, n: u64| *expected.entry(t).or_insert(0) += n;
    for (_, r) in &log.records {
        match r {
            LogRecord::Step(s) => {
                add("/imu", s.imu.len() as u64);
                add("/mag", s.mag.is_some() as u64);
            }
            LogRecord::Report(rep) => {
                for t in ["/estimate/pose", "/estimate", "/setpoint", "/motors", "/status", "/counters"] {
                    add(t, 1);
                }
                add("/flow/outcome", rep.flow.is_some() as u64);
            }
            LogRecord::Link(m) if m.vision().is_some() => add("/link/vision", 1),
            LogRecord::Link(m) if m.flow().is_some() => add("/link/flow", 1),
            LogRecord::Link(_) => add("/link/other", 1),
            LogRecord::Downlink(d) if d.telemetry().is_some() => add("/downlink/telemetry", 1),
            LogRecord::Downlink(_) => add("/downlink/other", 1),
            LogRecord::Truth { .. } => {
                add("/truth/pose", 1);
                add("/truth", 1);
            }
            LogRecord::Reference(_) => {
                add("/reference/pose", 1);
                add("/reference", 1);
            }
            LogRecord::Frame(f) if f.camera == CameraId::Forward => add("/camera/forward", 1),
            LogRecord::Frame(_) => add("/camera/down", 1),
            // The file's end record has no topic; a simulated flight's log has no station records (the
            // station's export is checked by sim-host/tests/station_e2e.rs).
            LogRecord::End { .. } => {}
            LogRecord::Station(e) => panic!("a station record in a simulated flight's log: {e:?}"),
        }
    }
    expected.retain(|_, n| *n > 0);
    assert_eq!(expected["/camera/forward"], 91);
    assert_eq!(expected["/estimate"], 1500);

    let mcap_path = out.join("flight.mcap");
    let reader = open_log(&log_path).unwrap();
    let header = reader.header.clone();
    let s = sim_host::export::export_mcap(&header, reader, &mcap_path).unwrap();
    assert!(s.damage.is_empty());

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
    for ch in summary.channels.values() {
        assert_eq!(ch.message_encoding, "json");
        let schema = ch.schema.as_ref().expect("a schema");
        assert_eq!(schema.encoding, "jsonschema");
        let want = match ch.topic.as_str() {
            "/estimate/pose" | "/truth/pose" => "foxglove.PoseInFrame",
            "/camera/forward" | "/camera/down" => "foxglove.CompressedImage",
            _ => "",
        };
        if !want.is_empty() {
            assert_eq!(schema.name, want, "{}", ch.topic);
        }
        serde_json::from_slice::<serde_json::Value>(&schema.data).expect("the schema is JSON");
    }

    // Every message in order; the first forward image decodes to the logged frame, the poses to the reports.
    let first_frame = log
        .records
        .iter()
        .find_map(|(_, r)| match r {
            LogRecord::Frame(f) if f.camera == CameraId::Forward => Some(f.clone()),
            _ => None,
        })
        .unwrap();
    let reports: Vec<_> = log
        .records
        .iter()
        .filter_map(|(_, r)| match r {
            LogRecord::Report(rep) => Some(rep.control.estimate),
            _ => None,
        })
        .collect();
    let (mut images, mut poses) = (0, 0);
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        let m = m.unwrap();
        let v: serde_json::Value = serde_json::from_slice(&m.data).unwrap();
        match m.channel.topic.as_str() {
            "/camera/forward" => {
                if images == 0 {
                    assert_eq!(v["format"], "png");
                    let png = base64_decode(v["data"].as_str().unwrap());
                    assert_eq!(png, first_frame.data);
                    assert_eq!(m.log_time, first_frame.capture_time_us * 1000);
                }
                images += 1;
            }
            "/estimate/pose" => {
                let e = &reports[poses];
                let p = &v["pose"]["position"];
                assert_eq!(p["y"].as_f64().unwrap() as f32, e.position_m.y);
                assert_eq!(v["pose"]["orientation"]["w"].as_f64().unwrap() as f32, e.q.w);
                assert_eq!(v["frame_id"], "world");
                poses += 1;
            }
            _ => {}
        }
    }
    assert_eq!((images, poses), (91, 1500));

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
