//! The log format's tests: golden bytes, damage, truncation, the writer's failures.
use super::*;

fn hex(b: &[u8]) -> String {
    b.iter().map(|x| format!("{x:02X}")).collect::<Vec<_>>().join(" ")
}

fn unhex(s: &str) -> Vec<u8> {
    s.split_whitespace().map(|h| u8::from_str_radix(h, 16).unwrap()).collect()
}

// Pinned bytes (docs/log-format.md, "Golden bytes"): changing them is a log format change: bump
// LOG_FORMAT_VERSION (or the wire version) and update the document.
#[test]
fn golden_bytes_of_log_records() {
    // Body 01 | 00 (Link) 02 (Heartbeat) | CRC 0xDBEE; COBS [02 01] [04 02 EE DB]; delimiter.
    let hb = record_frame(&LogRecord::Link(Uplink::Heartbeat)).unwrap();
    assert_eq!(hex(&hb), "02 01 04 02 EE DB 00");
    assert_eq!(crc16(&[1, 0, 2]), 0xDBEE);
    // Truth: 03, time 1000 as varint E8 07, nine f32 little endian (1.0, 2.0, 0.5, then zeros).
    let t = LogRecord::Truth {
        time_us: 1000,
        position_m: [1.0, 2.0, 0.5],
        velocity_m_s: [0.0; 3],
        attitude_rad: [0.0; 3],
    };
    let truth = "05 01 03 E8 07 01 03 80 3F 01 01 02 40 01 01 02 3F 01 01 01 01 01 01 01 01 01 01 01 01 01 01 01 \
                 01 01 01 01 01 01 01 01 03 20 AD 00";
    assert_eq!(record_frame(&t).unwrap(), unhex(truth));
    // Frame: 04, Downward 01, seq 03, time 200 = C8 01, width 02, height 01, channels 01, Raw 00, three
    // zero f32, data length 02 then 07 00.
    let f = LogRecord::Frame(CameraFrame {
        camera: CameraId::Downward,
        seq: 3,
        capture_time_us: 200,
        width: 2,
        height: 1,
        channels: 1,
        encoding: FrameEncoding::Raw,
        rotation_hint_cam: [0.0; 3],
        data: vec![7, 0],
    });
    let framed = record_frame(&f).unwrap();
    assert_eq!(
        framed,
        unhex("0A 01 04 01 03 C8 01 02 01 01 01 01 01 01 01 01 01 01 01 01 01 01 03 02 07 03 7E A0 00")
    );
    // The end record: 07, two records as varint 02, the CRC-32 of their 36 bytes (u32 varint).
    let mut frames = framed.clone();
    frames.extend_from_slice(&hb);
    let end = end_record(&frames);
    assert_eq!(end, LogRecord::End { records: 2, crc32: crc32fast::hash(&frames) });
    let end_frame = record_frame(&end).unwrap();
    // 01 | 07 (End) 02 | CRC-32 0x98F4688F as varint 8F D1 D1 C7 09 | CRC-16 0x3139; COBS, delimiter.
    assert_eq!(hex(&end_frame), "0B 01 07 02 8F D1 D1 C7 09 39 31 00");
    // Decodes back through the reader.
    let mut bytes = header_bytes(&sample_header()).unwrap();
    bytes.extend_from_slice(&frames);
    bytes.extend_from_slice(&end_frame);
    let log = parse_log(&bytes).unwrap();
    assert!(log.damage.is_empty(), "{:?}", log.damage);
    assert_eq!(
        log.records.iter().map(|(_, r)| r.clone()).collect::<Vec<_>>(),
        [f, LogRecord::Link(Uplink::Heartbeat), end]
    );
}

fn sample_log() -> Vec<u8> {
    let mut frames = Vec::new();
    for k in 0..5u64 {
        frames.extend(
            record_frame(&LogRecord::Truth {
                time_us: 1000 * k,
                position_m: [k as f32; 3],
                velocity_m_s: [0.0; 3],
                attitude_rad: [0.0; 3],
            })
            .unwrap(),
        );
    }
    let mut bytes = header_bytes(&sample_header()).unwrap();
    bytes.extend_from_slice(&frames);
    bytes.extend(record_frame(&end_record(&frames)).unwrap());
    bytes
}

#[test]
fn a_log_cut_at_a_record_boundary_is_damage_not_a_shorter_flight() {
    let bytes = sample_log();
    assert!(parse_log(&bytes).unwrap().damage.is_empty());
    // Cut after the third record: every frame intact, the end record missing.
    let head = header_bytes(&sample_header()).unwrap().len();
    let cut: Vec<u8> = {
        let mut zeros = bytes.iter().enumerate().skip(head).filter(|(_, b)| **b == 0).map(|(i, _)| i);
        let third = zeros.nth(2).unwrap();
        bytes[..=third].to_vec()
    };
    let log = parse_log(&cut).unwrap();
    assert_eq!(log.records.len(), 3);
    assert_eq!(log.damage.len(), 1);
    assert!(log.damage[0].what.contains("no end-of-log record"), "{}", log.damage[0]);
    assert_eq!(log.damage[0].offset, cut.len());
    // A record dropped from the middle (its frame removed whole): the end record's count says so.
    let mut zeros = bytes.iter().enumerate().skip(head).filter(|(_, b)| **b == 0).map(|(i, _)| i);
    let (a, b) = (zeros.next().unwrap(), zeros.next().unwrap());
    let mut dropped = bytes[..=a].to_vec();
    dropped.extend_from_slice(&bytes[b + 1..]);
    let log = parse_log(&dropped).unwrap();
    assert_eq!(log.records.len(), 4, "the other records are read");
    assert!(log.damage.iter().any(|d| d.what.contains("says 5 records")), "{:?}", log.damage);
    // Something after the end record.
    let mut extra = bytes.clone();
    extra.extend(record_frame(&LogRecord::Link(Uplink::Heartbeat)).unwrap());
    let log = parse_log(&extra).unwrap();
    assert!(log.damage.iter().any(|d| d.what.contains("after the end-of-log record")), "{:?}", log.damage);
}

#[test]
fn a_damaged_header_is_refused_and_an_older_format_named() {
    let bytes = sample_log();
    let head = header_bytes(&sample_header()).unwrap().len();
    // Every single-bit change in the header's JSON or its checksum is refused, naming the checksum.
    for i in 12..head {
        for bit in [0x01u8, 0x10] {
            let mut b = bytes.clone();
            b[i] ^= bit;
            let e = format!("{:#}", parse_log(&b).unwrap_err());
            assert!(e.contains("checksum") || e.contains("header"), "byte {i}: {e}");
        }
    }
    let mut v3 = bytes.clone();
    v3[6] = 3;
    let e = format!("{:#}", parse_log(&v3).unwrap_err());
    assert!(e.contains("version 3") && e.contains("end record"), "{e}");
    let mut v4 = bytes.clone();
    v4[6] = 4;
    let e = format!("{:#}", parse_log(&v4).unwrap_err());
    assert!(e.contains("version 4") && e.contains("barometer"), "{e}");
}

fn sample_header() -> LogHeader {
    LogHeader {
        format_version: LOG_FORMAT_VERSION,
        schema_hash: schema_hash(),
        wire_version: WIRE_VERSION,
        writer: "w".into(),
        scenario_toml: String::new(),
        seed: 1,
        camera: "analytic".into(),
        flight_computer: "sil".into(),
        reference: String::new(),
        reference_yaw_absolute: false,
        link_security: "hmac-sha256-48".to_string(),
    }
}

#[test]
fn a_full_disk_keeps_what_was_written() {
    // A disk with room for the header and a few hundred records: the write that fails is reported, the
    // records before it are kept under NAME.partial (read back whole, the tail reported as truncated),
    // and nothing appears under the final name.
    let dir = std::env::temp_dir().join(format!("wlq-full-disk-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("flight.log");
    let file = crate::files::AtomicFile::create_with_space(&path, 8_000).unwrap();
    let mut w = LogWriter::create_on(file, &sample_header()).unwrap();
    let record = |k: u64| LogRecord::Truth {
        time_us: k,
        position_m: [k as f32, 1.0, 2.0],
        velocity_m_s: [0.0; 3],
        attitude_rad: [0.0; 3],
    };
    let mut k = 0;
    let err = loop {
        match w.write(&record(k)) {
            Ok(()) => k += 1,
            Err(e) => break e,
        }
        assert!(k < 10_000, "the disk never filled");
    };
    assert!(format!("{err:#}").contains("no space left"), "{err:#}");
    assert_eq!(w.records, k);
    let kept = w.keep_partial().unwrap();
    assert_eq!(kept, dir.join("flight.log.partial"));
    assert!(!path.exists(), "no file under the final name");
    let bytes = std::fs::read(&kept).unwrap();
    assert_eq!(bytes.len(), 8_000, "every byte the disk took");
    let log = parse_log(&bytes).unwrap();
    assert_eq!(log.records.len() as u64, k, "every record written before the failure");
    for (i, (_, r)) in log.records.iter().enumerate() {
        assert_eq!(*r, record(i as u64));
    }
    assert_eq!(log.damage.len(), 1);
    assert!(log.damage[0].what.contains("truncated"), "{}", log.damage[0]);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn golden_bytes_of_the_header_and_the_schema_hash() {
    let b = header_bytes(&sample_header()).unwrap();
    // "WLQLOG", version 10 (u16 LE), JSON length (u32 LE), the JSON, its CRC-32 (u32 LE).
    assert_eq!(&b[..8], b"WLQLOG\x0a\x00");
    let len = u32::from_le_bytes([b[8], b[9], b[10], b[11]]) as usize;
    assert_eq!(b.len(), 16 + len);
    let json = &b[12..12 + len];
    assert!(std::str::from_utf8(json).unwrap().starts_with("{\"format_version\":10,\"schema_hash\":\""));
    assert_eq!(b[12 + len..], crc32fast::hash(json).to_le_bytes());
    assert_eq!(crc32fast::hash(b"123456789"), 0xCBF4_3926, "CRC-32 (IEEE) check value");
    // The schema fingerprint of this version's records: any change to a record's fields changes it.
    assert_eq!(schema_hash(), "2b0e5901a5b5c839");
}

#[test]
fn small_records_frame_exactly_as_the_radio_link_does() {
    let mut buf = [0u8; protocol::frame::MAX_FRAME];
    for r in [
        LogRecord::Link(Uplink::Command(control_core::Command::Arm)),
        LogRecord::Link(Uplink::Heartbeat),
        LogRecord::Truth {
            time_us: 123_456,
            position_m: [0.5; 3],
            velocity_m_s: [-1.0; 3],
            attitude_rad: [0.1; 3],
        },
    ] {
        let link = protocol::frame::encode(&r, &mut buf).unwrap().to_vec();
        assert_eq!(record_frame(&r).unwrap(), link);
    }
}

#[test]
fn golden_bytes_of_station_records() {
    // Body 01 | 08 (Station) 00 (Sent) E8 07 (station time 1000) 02 (Heartbeat) | CRC-16 0xF9D8; COBS
    // [03 01 08] [06 E8 07 02 D8 F9]; delimiter.
    let sent = LogRecord::Station(StationEvent::Sent { station_time_us: 1000, message: Uplink::Heartbeat });
    assert_eq!(hex(&record_frame(&sent).unwrap()), "03 01 08 06 E8 07 02 D8 F9 00");
    assert_eq!(crc16(&[1, 8, 0, 0xE8, 7, 2]), 0xF9D8);
    // Clock: 08 02, station time 5, vehicle time 7, bound 300 = AC 02 (varints) | CRC-16 0x41EA.
    let clock =
        LogRecord::Station(StationEvent::Clock { station_time_us: 5, vehicle_time_us: 7, bound_us: 300 });
    assert_eq!(hex(&record_frame(&clock).unwrap()), "0A 01 08 02 05 07 AC 02 EA 41 00");
    assert_eq!(crc16(&[1, 8, 2, 5, 7, 0xAC, 2]), 0x41EA);
    assert_eq!((sent.kind(), clock.kind()), ("station", "station"));
    // A received message: 08 01, the time, then the Downlink as on the radio.
    let ack = Downlink::CommandAck(control_core::CommandResult::Accepted(control_core::Command::Arm));
    let received = LogRecord::Station(StationEvent::Received { station_time_us: 1, message: ack });
    let mut payload = vec![8, 1, 1];
    payload.extend(postcard::to_allocvec(&ack).unwrap());
    let framed = record_frame(&received).unwrap();
    let mut body = framed[..framed.len() - 1].to_vec();
    let n = cobs_decode_in_place(&mut body).unwrap();
    assert_eq!(&body[1..n - 2], &payload[..]);
}

/// A log of an older `version` written in its schema `hash`: a header and a heartbeat.
fn older_log(version: u8, hash: &str) -> Vec<u8> {
    let mut header = sample_header();
    header.format_version = version.into();
    header.schema_hash = hash.into();
    let json = serde_json::to_vec(&header).unwrap();
    let mut bytes = vec![b'W', b'L', b'Q', b'L', b'O', b'G', version, 0];
    bytes.extend((json.len() as u32).to_le_bytes());
    bytes.extend(&json);
    bytes.extend(crc32fast::hash(&json).to_le_bytes());
    let hb = record_frame(&LogRecord::Link(Uplink::Heartbeat)).unwrap();
    bytes.extend(&hb);
    bytes.extend(record_frame(&end_record(&hb)).unwrap());
    bytes
}

#[test]
fn format_5_to_9_logs_read_as_they_were_written() {
    // Format 5 is format 6 without the station's records, format 6 format 7 without the packed messages,
    // format 7 format 8 without the link status and the unauthenticated arming refusal, format 8 format 9
    // without the flow's repeating-texture refusal, format 9 format 10 without the configuration upload's
    // messages: their headers (their version, their schema hash) and records read unchanged.
    for (version, hash) in [
        (5u8, SCHEMA_HASH_FORMAT_5),
        (6, SCHEMA_HASH_FORMAT_6),
        (7, SCHEMA_HASH_FORMAT_7),
        (8, SCHEMA_HASH_FORMAT_8),
        (9, SCHEMA_HASH_FORMAT_9),
    ] {
        let bytes = older_log(version, hash);
        let log = parse_log(&bytes).unwrap();
        assert!(log.damage.is_empty(), "{:?}", log.damage);
        assert_eq!(log.records.len(), 2);
        assert_eq!(log.header.format_version, u16::from(version));
        // As another version it is refused naming the byte.
        let mut bad = bytes.clone();
        bad[6] = 11;
        let e = parse_log(&bad).unwrap_err().to_string();
        assert!(e.contains("version 11 at byte 6"), "{e}");
        // With today's schema hash under the old version: refused, naming the schema it should have.
        let e = parse_log(&older_log(version, &schema_hash())).unwrap_err().to_string();
        assert!(e.contains("record schema") && e.contains(hash), "{e}");
    }
}
