//! `sim-host configure`: a scenario's flight configuration sent to a vehicle on the ground. Here the vehicle is
//! a stand-in on a local TCP port that puts the pieces together with the flight code's assembler and answers;
//! the firmware's own answer (in QEMU) is in tests/tests/firmware_radio.rs.
use flight_core::config_upload::ConfigUpload;
use protocol::frame::{Decoder, encode};
use protocol::{ConfigAck, ConfigOutcome, Downlink, Uplink};
use std::io::{Read, Write};
use std::net::TcpListener;
use std::process::Command;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_sim-host"))
}

/// A vehicle on an unauthenticated link at a free port: applies the first whole upload and returns it.
fn vehicle() -> (u16, std::thread::JoinHandle<flight_core::FlightConfig>) {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let port = listener.local_addr().unwrap().port();
    let h = std::thread::spawn(move || {
        let (mut s, _) = listener.accept().unwrap();
        let (mut dec, mut upload) = (Decoder::new(), ConfigUpload::new());
        let mut buf = [0u8; 512];
        loop {
            let n = s.read(&mut buf).unwrap();
            assert!(n > 0, "the station hung up before the upload was whole");
            for &b in &buf[..n] {
                let Some(Ok(Uplink::Config(c))) = dec.push::<Uplink>(b) else { continue };
                let Some((crc32, r)) = upload.push(&c) else { continue };
                let cfg = r.unwrap();
                let ack = Downlink::ConfigAck(ConfigAck {
                    crc32,
                    outcome: ConfigOutcome::Applied { saved_sequence: Some(3) },
                });
                let mut out = [0u8; protocol::frame::MAX_FRAME];
                s.write_all(encode(&ack, &mut out).unwrap()).unwrap();
                return cfg;
            }
        }
    });
    (port, h)
}

#[test]
fn configure_uploads_the_scenario_s_configuration_and_reports_where_it_was_stored() {
    let (port, vehicle) = vehicle();
    let r = bin()
        .args(["configure", "--link", &format!("tcp:127.0.0.1:{port}"), "--scenario", "paper", "--no-key"])
        .output()
        .unwrap();
    let (out, err) = (String::from_utf8_lossy(&r.stdout), String::from_utf8_lossy(&r.stderr));
    assert_eq!(r.status.code(), Some(0), "{out}\n{err}");
    assert!(
        out.contains("applied the configuration of `paper`") && out.contains("stored in its flash as set 3"),
        "{out}"
    );
    assert!(err.contains("try 1 of 3"), "{err}");
    // What the vehicle put together is the scenario's configuration, bit for bit.
    let got = vehicle.join().unwrap();
    assert_eq!(
        postcard::to_allocvec(&got).unwrap(),
        postcard::to_allocvec(&flight_core::FlightConfig::paper()).unwrap()
    );
}

#[test]
fn configure_says_what_is_missing_or_wrong() {
    // A port nobody listens on.
    let free = TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
    let link = format!("tcp:127.0.0.1:{free}");
    // No key and no --no-key.
    let r = bin().args(["configure", "--link", &link]).output().unwrap();
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(1), "{err}");
    assert!(err.contains("--key FILE") && err.contains("--no-key"), "{err}");
    // Nobody listening: the link is named.
    let r = bin().args(["configure", "--link", &link, "--no-key"]).output().unwrap();
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(1), "{err}");
    assert!(err.contains(&link), "{err}");
    // A scenario that is not one.
    let r = bin()
        .args(["configure", "--link", &link, "--no-key", "--scenario", "/nonexistent.toml"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(1), "{err}");
    assert!(err.contains("nonexistent.toml"), "{err}");
}
