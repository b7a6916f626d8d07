//! Flight logs and replay: a flight's log replays bit for bit; a changed parameter shows as the first
//! difference; damaged logs give errors with byte offsets and keep every intact record.
use sim_host::flightlog::{
    CameraId, FrameEncoding, FramePolicy, LOG_FILE, LogReader, LogRecord, parse_log, read_log, record_frame,
};
use sim_host::imageio::FrameImages;
use sim_host::replay::{ReplayOptions, VisionSource, replay};
use sim_host::rng::SimRng;
use sim_host::sil::CameraMode;
use std::path::PathBuf;

/// A 12 s flight (take-off, hover, start of the sweep) with its log; the bytes of the log.
fn flown(name: &str) -> (PathBuf, Vec<u8>) {
    let path = system_tests::fly_logged(
        &format!("replay-test-{name}"),
        5,
        12.0,
        CameraMode::Analytic,
        FramePolicy::Drop,
    );
    let bytes = std::fs::read(&path).unwrap();
    (path, bytes)
}

#[test]
fn a_flight_replays_bit_for_bit_and_a_changed_parameter_is_found() {
    let (path, _) = flown("identical");
    let log = read_log(&path).unwrap();
    assert!(log.damage.is_empty());
    assert_eq!(log.header.seed, 5);
    let steps = log.records.iter().filter(|(_, r)| matches!(r, LogRecord::Step(_))).count();
    assert_eq!(steps, 6000, "12 s at 500 Hz");
    let s = replay(&log, &ReplayOptions::default()).unwrap();
    assert_eq!((s.steps, s.compared, s.differing), (6000, 6000, 0));
    assert!(s.first.is_none());
    // The vehicle's downlink (the firmware's schedule): telemetry at 25 Hz and command acknowledgements.
    assert!(s.downlinks_compared >= 300 && s.downlinks_differing == 0, "{s:?}");
    let telemetry = log
        .records
        .iter()
        .filter(|(_, r)| matches!(r, LogRecord::Downlink(protocol::Downlink::PackedTelemetry(_))))
        .count();
    assert_eq!(telemetry, 300, "12 s at 25 Hz");
    assert!(s.links > 300, "vision, flow, commands and heartbeats were fed: {}", s.links);

    // A changed altitude gain alters the motor commands from the first step in the air.
    let id = control_core::params::ParamId::from_name("gains.altitude.a_z1").unwrap();
    let s = replay(&log, &ReplayOptions { overrides: vec![(id, 3.0)], ..ReplayOptions::default() }).unwrap();
    let d = s.first.expect("a difference");
    assert!(s.differing > 100);
    assert!(d.field.starts_with("control."), "{d}");
    assert_ne!(d.logged, d.replayed);
    assert!(d.time_us > 0 && d.offset > 0);
    eprintln!("first difference: {d}");
}

#[test]
fn damaged_logs_give_offsets_and_keep_the_intact_records() {
    let (_, bytes) = flown("damaged");
    let good = parse_log(&bytes).unwrap();
    let n = good.records.len();
    let mid = good.records[n / 2].0;

    // The last record is the end record, and an intact log has no damage.
    assert!(good.damage.is_empty());
    assert!(matches!(good.records[n - 1].1, LogRecord::End { .. }));
    let end = good.records[n - 1].0;

    // Truncated in the middle of a record: every record before it is read, the tail is reported.
    let cut = &bytes[..mid + 5];
    let log = parse_log(cut).unwrap();
    assert_eq!(log.records.len(), n / 2);
    assert_eq!(log.damage.len(), 1);
    assert_eq!(log.damage[0].offset, mid);
    assert!(log.damage[0].what.contains("truncated"), "{}", log.damage[0]);

    // Truncated exactly between two records (it used to replay as a shorter, intact flight): the missing end
    // record is reported where the file ends.
    let log = parse_log(&bytes[..mid]).unwrap();
    assert_eq!(log.records.len(), n / 2);
    assert_eq!(log.damage.len(), 1);
    assert_eq!(log.damage[0].offset, mid);
    assert!(log.damage[0].what.contains("no end-of-log record"), "{}", log.damage[0]);

    // A flipped byte inside one record: that record is reported at its offset, all others are read, and the
    // end record says that what came before it is not what was written.
    let mut flipped = bytes.clone();
    flipped[mid + 3] ^= 0x5A;
    let log = parse_log(&flipped).unwrap();
    assert_eq!(log.records.len(), n - 2);
    assert_eq!(log.damage.len(), 2, "{:?}", log.damage);
    assert_eq!(log.damage[0].offset, mid);
    assert_eq!(log.damage[1].offset, end);
    assert!(log.damage[1].what.contains("CRC-32"), "{}", log.damage[1]);

    // Another format version: a clear error naming the byte.
    let mut v = bytes.clone();
    v[6] = 11;
    let e = format!("{:#}", parse_log(&v).unwrap_err());
    assert!(e.contains("version 11") && e.contains("byte 6"), "{e}");
    // Not a log at all.
    let e = format!("{:#}", parse_log(b"PNG and other things").unwrap_err());
    assert!(e.contains("not a flight log"), "{e}");

    // An unknown record kind (a well-framed record whose variant index is past the last): reported, skipped.
    let mut raw = vec![protocol::frame::WIRE_VERSION, 42, 1, 2, 3];
    raw.extend(protocol::frame::crc16(&raw).to_le_bytes());
    let mut enc = [0u8; 32];
    let k = protocol::frame::cobs_encode(&raw, &mut enc).unwrap();
    let mut unknown = bytes[..mid].to_vec();
    unknown.extend_from_slice(&enc[..k]);
    unknown.push(0);
    unknown.extend_from_slice(&bytes[mid..]);
    let log = parse_log(&unknown).unwrap();
    assert_eq!(
        log.records.len(),
        n - 1,
        "every written record but the end record, which counts one too many"
    );
    assert_eq!(log.damage.len(), 2);
    assert_eq!(log.damage[0].offset, mid);
    assert!(log.damage[0].what.contains("unknown record kind"), "{}", log.damage[0]);
    assert!(log.damage[1].what.contains(&format!("says {} records", n - 1)), "{}", log.damage[1]);
}

#[test]
fn the_reader_never_panics_on_mutated_logs() {
    let (_, bytes) = flown("fuzz");
    let body = parse_log(&bytes).unwrap().records[0].0;
    let mut rng = SimRng::stream(11, "log-fuzz");
    for case in 0..300 {
        let mut b = bytes[..bytes.len().min(body + 20_000)].to_vec();
        let edits = 1 + (rng.next_u64() % 8) as usize;
        for _ in 0..edits {
            let at = (rng.next_u64() as usize) % b.len();
            match rng.next_u64() % 4 {
                0 => b[at] ^= 1 << (rng.next_u64() % 8),
                1 => b[at] = 0,
                2 => b.truncate(at.max(1)),
                _ => {
                    let len = (rng.next_u64() % 64) as usize;
                    b.splice(at..at, (0..len).map(|_| rng.next_u64() as u8));
                }
            }
        }
        // Header damage is an error; anything else reads, with the damage listed. Never a panic.
        if let Ok(log) = parse_log(&b) {
            assert!(log.records.len() + log.damage.len() > 0 || b.len() <= body, "case {case}");
            for (off, _) in &log.records {
                assert!(*off < b.len());
            }
        }
    }
}

/// A short rendered flight with its frames: replay from the frames re-runs vision-core and matches; a frame
/// changed in the log shows as a vision difference at the measurement made from it.
#[test]
fn replay_from_frames_reruns_the_vision_and_finds_a_changed_frame() {
    let path = system_tests::fly_logged("replay-test-frames", 8, 3.0, CameraMode::Rendered, FramePolicy::Png);
    let out = path.parent().unwrap().to_path_buf();
    let log = read_log(&out.join(LOG_FILE)).unwrap();
    let frames = |cam: CameraId| {
        log.records.iter().filter(|(_, r)| matches!(r, LogRecord::Frame(f) if f.camera == cam)).count()
    };
    // 3 s at 30 Hz forward and 60 Hz downward, both ends included.
    assert_eq!(frames(CameraId::Forward), 91);
    assert_eq!(frames(CameraId::Downward), 181);
    for (_, r) in &log.records {
        if let LogRecord::Frame(f) = r {
            assert_eq!(f.encoding, FrameEncoding::Png);
            match f.camera {
                CameraId::Forward => assert_eq!((f.width, f.height, f.channels), (640, 480, 3)),
                CameraId::Downward => assert_eq!((f.width, f.height, f.channels), (160, 120, 1)),
            }
        }
    }

    let from_frames = ReplayOptions { vision: VisionSource::Frames, ..ReplayOptions::default() };
    let s = replay(&log, &from_frames).unwrap();
    assert!(s.identical(), "{:?}", s.first);
    assert_eq!(s.frames, 272);
    // Every forward frame's measurement and every flow pair delivered within the 3 s were recomputed.
    assert!(s.measurements_compared >= 80 + 170, "{s:?}");
    assert_eq!((s.measurements_differing, s.measurements_without_frame), (0, 0));

    // Paint the line out of a forward frame in which it was seen: the detector now finds nothing in it.
    let seen = log
        .records
        .iter()
        .find_map(|(_, r)| match r {
            LogRecord::Link(protocol::Uplink::Vision(v)) if v.observation.is_some() && v.frame_seq >= 30 => {
                Some(v.frame_seq)
            }
            _ => None,
        })
        .expect("the line seen in a frame");
    let mut changed = log.clone();
    let (at, mut frame) = changed
        .records
        .iter()
        .find_map(|(o, r)| match r {
            LogRecord::Frame(f) if f.camera == CameraId::Forward && f.seq == seen => Some((*o, f.clone())),
            _ => None,
        })
        .unwrap();
    let mut img = frame.to_rgb().unwrap();
    for p in img.data.chunks_exact_mut(3) {
        p[0] = p[1];
    }
    frame.data = sim_host::imageio::png_of_rgb(&img).unwrap();
    for (o, r) in changed.records.iter_mut() {
        if *o == at {
            *r = LogRecord::Frame(frame.clone());
        }
    }
    let s = replay(&changed, &from_frames).unwrap();
    let d = s.first.expect("a vision difference");
    assert_eq!(d.kind, "vision", "{d}");
    assert!(d.field.starts_with("observation"), "{d}");
    assert_eq!(d.replayed, "null", "no line in the frame: {d}");
    assert_eq!(d.time_us, frame.capture_time_us);
    assert_eq!(s.measurements_differing, 1);
    // From the logged vision results the same log still replays identically: the frames are not used.
    assert!(replay(&changed, &ReplayOptions::default()).unwrap().identical());

    // Skipping frames unread gives the same other records.
    let bytes = std::fs::read(out.join(LOG_FILE)).unwrap();
    let reader = LogReader::new(&bytes[..]).unwrap().skip_frames(true);
    let others: Vec<_> = reader.map(|r| r.unwrap()).collect();
    let expected: Vec<_> =
        log.records.iter().filter(|(_, r)| !matches!(r, LogRecord::Frame(_))).cloned().collect();
    assert_eq!(others, expected);

    // A frame record is framed like any other record: its bytes decode back to it.
    let framed = record_frame(&LogRecord::Frame(frame.clone())).unwrap();
    assert!(framed.len() > 512 && framed.iter().filter(|&&b| b == 0).count() == 1);
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn a_log_truncated_anywhere_is_damaged_never_identical() {
    // A short flight (1 s: take-off on the pad, about 1500 records): cut at every record boundary and at every
    // 997th byte; each cut log reads with damage listed, and its replay is not "identical".
    let path =
        system_tests::fly_logged("replay-test-truncated", 6, 1.0, CameraMode::Analytic, FramePolicy::Drop);
    let bytes = std::fs::read(&path).unwrap();
    let whole = parse_log(&bytes).unwrap();
    assert!(whole.damage.is_empty());
    let body = whole.records[0].0;
    let mut cuts: Vec<usize> = whole.records.iter().map(|(o, _)| *o).collect();
    cuts.extend((body..bytes.len()).step_by(997));
    cuts.sort_unstable();
    cuts.dedup();
    assert!(cuts.len() > 1000, "{} cuts", cuts.len());
    let mut replayed = 0;
    for (i, &cut) in cuts.iter().enumerate() {
        let log = parse_log(&bytes[..cut]).unwrap();
        assert!(!log.damage.is_empty(), "cut at byte {cut} of {} read as intact", bytes.len());
        // Replaying every cut would take minutes: one in 25, spread over the log.
        if i % 25 == 0 {
            let s = replay(&log, &ReplayOptions::default()).unwrap();
            assert!(!s.identical(), "cut at byte {cut} replayed as identical");
            replayed += 1;
        }
    }
    assert!(replayed > 40);
    let _ = std::fs::remove_dir_all(path.parent().unwrap());
}

/// Applies 1 to 8 random edits to `b` (after the header's first `keep` bytes when `keep` is given): a bit
/// flipped, a byte zeroed, a stretch deleted, duplicated or inserted at random, the tail cut.
fn mutate(b: &mut Vec<u8>, keep: usize, rng: &mut SimRng) {
    let edits = 1 + (rng.next_u64() % 8) as usize;
    for _ in 0..edits {
        if b.len() <= keep + 1 {
            return;
        }
        let at = keep + (rng.next_u64() as usize) % (b.len() - keep);
        let len = 1 + (rng.next_u64() % 96) as usize;
        let end = (at + len).min(b.len());
        match rng.next_u64() % 6 {
            0 => b[at] ^= 1 << (rng.next_u64() % 8),
            1 => b[at] = 0,
            2 => {
                b.drain(at..end);
            }
            3 => {
                let copy = b[at..end].to_vec();
                b.splice(end..end, copy);
            }
            4 => {
                b.splice(at..at, (0..len).map(|_| rng.next_u64() as u8));
            }
            _ => b.truncate(at.max(keep + 1)),
        }
    }
}

#[test]
fn twenty_thousand_mutated_logs_replay_and_export_without_aborting() {
    // A 0.3 s flight (steps, reports, links, downlinks, truth: every kind a flight writes). Each of
    // 20,000 mutated copies either is refused whole with an error (its header damaged) or reads with its damage
    // listed; then replay and both exports run to the end (never an error, never a panic), every report read
    // is compared or counted as without its step, every downlink read is compared, and every record read
    // reaches the export.
    let path =
        system_tests::fly_logged("replay-test-mutated", 9, 0.3, CameraMode::Analytic, FramePolicy::Drop);
    let bytes = std::fs::read(&path).unwrap();
    let whole = parse_log(&bytes).unwrap();
    let body = whole.records[0].0;
    for kind in ["Step", "Report", "Link", "Downlink", "Truth", "End"] {
        let n = whole.records.iter().filter(|(_, r)| format!("{r:?}").starts_with(kind)).count();
        assert!(n > 0, "the flight's log holds {kind} records");
    }
    let out = path.parent().unwrap().join("export");
    let mut rng = SimRng::stream(12, "log-mutations");
    let (mut refused, mut damaged, mut intact) = (0u32, 0u32, 0u32);
    for case in 0..20_000u32 {
        let mut b = bytes.clone();
        // One case in 20 edits the header too.
        mutate(&mut b, if case % 20 == 0 { 0 } else { body }, &mut rng);
        let log = match parse_log(&b) {
            Ok(log) => log,
            Err(e) => {
                let e = format!("{e:#}");
                assert!(
                    e.contains("byte") || e.contains("not a flight log") || e.contains("header"),
                    "case {case}: {e}"
                );
                refused += 1;
                continue;
            }
        };
        if log.damage.is_empty() {
            // Read as intact only when the edits cancelled out.
            assert_eq!(b, bytes, "case {case}: a changed log read as intact");
            intact += 1;
        } else {
            damaged += 1;
        }
        let count = |f: fn(&LogRecord) -> bool| log.records.iter().filter(|(_, r)| f(r)).count() as u64;
        let reports = count(|r| matches!(r, LogRecord::Report(_)));
        let downlinks = count(|r| matches!(r, LogRecord::Downlink(_)));
        let s = replay(&log, &ReplayOptions::default()).unwrap_or_else(|e| {
            panic!(
                "case {case}: replay aborted: {e:#}; damage {:?}; {} bytes of {}",
                log.damage,
                b.len(),
                bytes.len()
            )
        });
        assert_eq!(s.compared + s.reports_without_step, reports, "case {case}");
        assert_eq!(s.downlinks_compared, downlinks, "case {case}");
        // Every tenth case through both exports (each writes files): the streaming reader on the same bytes.
        if case % 10 == 0 {
            let reader = || LogReader::new(&b[..]).unwrap();
            let m = sim_host::export::export_mcap(&log.header, reader(), &out.with_extension("mcap"))
                .unwrap_or_else(|e| panic!("case {case}: MCAP export aborted: {e:#}"));
            let c = sim_host::export::export_csv(&log.header, reader(), &out)
                .unwrap_or_else(|e| panic!("case {case}: CSV export aborted: {e:#}"));
            for e in [&m, &c] {
                assert_eq!(e.damage.len(), log.damage.len(), "case {case}");
                assert_eq!(e.messages.get("/status").copied().unwrap_or(0), reports, "case {case}");
            }
        }
    }
    eprintln!(
        "20000 mutated logs: {refused} refused (header), {damaged} read with damage, {intact} read intact"
    );
    assert!(damaged > 15_000, "the mutations reach the records: {damaged}");
    let _ = std::fs::remove_dir_all(path.parent().unwrap());
}

#[test]
fn a_flight_on_a_full_disk_flies_on_and_keeps_its_log_so_far() {
    // The disk fills 200 kB into the log: the simulation goes on, finishing the log reports the failure and
    // where the records written so far are, and that file reads as a truncated log with every record whole.
    let dir = std::env::temp_dir().join(format!("replay-test-full-disk-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join(LOG_FILE);
    let s = sim_host::Scenario::paper();
    let mut sil = sim_host::sil::Sil::new(&s, 3, CameraMode::Analytic).unwrap();
    let header = sim_host::flightlog::LogHeader {
        format_version: sim_host::flightlog::LOG_FORMAT_VERSION,
        schema_hash: sim_host::flightlog::schema_hash(),
        wire_version: protocol::frame::WIRE_VERSION,
        writer: "test".into(),
        scenario_toml: String::new(),
        seed: 3,
        camera: "analytic".into(),
        flight_computer: "sil".into(),
        reference: String::new(),
        reference_yaw_absolute: false,
        link_security: String::new(),
    };
    let file = sim_host::files::AtomicFile::create_with_space(&path, 200_000).unwrap();
    sil.record_log(sim_host::flightlog::LogWriter::create_on(file, &header).unwrap(), FramePolicy::Drop);
    let stats = sil.run(3.0, |_| {});
    assert!(stats.sim_time_s >= 2.99, "the flight went on: {} s", stats.sim_time_s);
    let e = format!("{:#}", sil.finish_log().unwrap_err());
    assert!(e.contains("no space left") && e.contains("flight.log.partial"), "{e}");
    assert!(!path.exists());
    let log = read_log(&dir.join("flight.log.partial")).unwrap();
    assert!(log.records.len() > 500, "{} records kept", log.records.len());
    assert_eq!(log.damage.len(), 1, "{:?}", log.damage);
    std::fs::remove_dir_all(&dir).unwrap();
}
