//! The board firmware's radio in QEMU: with the key block a debug probe writes (here QEMU's loader at the
//! same address), only the station holding the key gets a session and commands; without one, the
//! development mode refuses to arm (docs/security.md).
//!
//! Needs `qemu-system-arm` and the firmware's QEMU variant, `cd firmware && cargo build --release --features
//! qemu --target-dir target/qemu` (`.ci/run` does both). Without them the test says what is missing and
//! passes, unless `REQUIRE_QEMU=1` (set in CI), which makes a missing piece a failure.
use control_core::{Command, CommandResult, Refusal};
use protocol::auth::provision::{KEY_BLOCK_ADDRESS, key_block};
use protocol::auth::{Key, Opened, Role, SecureLink};
use protocol::frame::{Decoder, MAX_FRAME, encode};
use protocol::{Downlink, Uplink};
use std::io::{Read, Write};
use std::net::{TcpListener, TcpStream};
use std::path::PathBuf;
use std::process::{Child, Command as Process, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

const QEMU: &str = "qemu-system-arm";
const KEY: Key = [0x3C; 32];

fn elf() -> PathBuf {
    match std::env::var_os("QEMU_ELF") {
        Some(p) => PathBuf::from(p),
        None => PathBuf::from(env!("CARGO_MANIFEST_DIR"))
            .join("../firmware/target/qemu/thumbv7em-none-eabihf/release/firmware"),
    }
}

fn available() -> bool {
    let required = std::env::var("REQUIRE_QEMU").is_ok_and(|v| v == "1");
    let qemu = Process::new(QEMU).arg("--version").output().is_ok_and(|o| o.status.success());
    let missing = if !qemu {
        Some(format!("{QEMU} is not installed"))
    } else if !elf().exists() {
        Some(format!(
            "no firmware ELF at {} (build it with --features qemu --target-dir target/qemu)",
            elf().display()
        ))
    } else {
        None
    };
    match missing {
        None => true,
        Some(why) if required => panic!("REQUIRE_QEMU=1 but {why}"),
        Some(why) => {
            eprintln!("skipped: {why}");
            false
        }
    }
}

/// QEMU, killed when dropped (also when the test fails), and the lines it printed (semihosting).
struct Qemu(Child, mpsc::Receiver<String>);

impl Drop for Qemu {
    fn drop(&mut self) {
        self.0.kill().ok();
        self.0.wait().ok();
    }
}

/// One test at a time: each QEMU has 2 s of emulated time for its exchange.
static ONE_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// The firmware in QEMU, its UART connected to the returned socket; `key_image` is written at the key block's
/// address before the firmware starts. The downlink's bytes arrive on the channel.
fn boot(key_image: Option<&[u8]>, dir: &std::path::Path) -> (Qemu, TcpStream, mpsc::Receiver<u8>) {
    let (qemu, stream) = boot_raw(key_image, dir);
    let mut reader = stream.try_clone().unwrap();
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        let mut buf = [0u8; 256];
        while let Ok(n) = reader.read(&mut buf) {
            if n == 0 {
                break;
            }
            for &b in &buf[..n] {
                if tx.send(b).is_err() {
                    return;
                }
            }
        }
    });
    (qemu, stream, rx)
}

/// As [`boot`], with the UART's socket as it is.
fn boot_raw(key_image: Option<&[u8]>, dir: &std::path::Path) -> (Qemu, TcpStream) {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let port = listener.local_addr().unwrap().port();
    let mut cmd = Process::new(QEMU);
    cmd.args(["-machine", "netduinoplus2", "-nographic", "-monitor", "none"])
        .args(["-semihosting-config", "enable=on,target=native", "-icount", "shift=0"])
        .args(["-chardev", &format!("socket,id=link,host=127.0.0.1,port={port},nodelay=on")])
        .args(["-serial", "chardev:link"]);
    if let Some(image) = key_image {
        std::fs::create_dir_all(dir).unwrap();
        let p = dir.join("key.bin");
        std::fs::write(&p, image).unwrap();
        cmd.args([
            "-device",
            &format!("loader,file={},addr={KEY_BLOCK_ADDRESS:#x},force-raw=on", p.display()),
        ]);
    }
    let child =
        cmd.arg("-kernel").arg(elf()).stdin(Stdio::null()).stdout(Stdio::piped()).stderr(Stdio::piped());
    let mut child = child.spawn().unwrap();
    let stdout = std::io::BufReader::new(child.stdout.take().unwrap());
    let (line_tx, lines) = mpsc::channel();
    std::thread::spawn(move || {
        for l in std::io::BufRead::lines(stdout).map_while(Result::ok) {
            if line_tx.send(l).is_err() {
                return;
            }
        }
    });
    let qemu = Qemu(child, lines);
    listener.set_nonblocking(true).unwrap();
    let deadline = Instant::now() + Duration::from_secs(30);
    let stream = loop {
        match listener.accept() {
            Ok((s, _)) => break s,
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock && Instant::now() < deadline => {
                std::thread::sleep(Duration::from_millis(10))
            }
            Err(e) => panic!("QEMU did not connect its UART: {e}"),
        }
    };
    stream.set_nonblocking(false).unwrap();
    // Bytes sent before the firmware started its UART are lost: wait for its first line, printed after.
    loop {
        let l = qemu.1.recv_timeout(Duration::from_secs(30)).expect("the firmware did not start");
        if l.contains("started") {
            break;
        }
    }
    (qemu, stream)
}

/// QEMU's report line (`loop ran: ...`), once the firmware printed it.
fn report(q: Qemu) -> String {
    loop {
        match q.1.recv_timeout(Duration::from_secs(60)) {
            Ok(l) if l.starts_with("loop ran:") => return l,
            Ok(_) => {}
            Err(e) => panic!("no report from the firmware: {e}"),
        }
    }
}

fn field<'a>(report: &'a str, name: &str) -> &'a str {
    let at = report.find(&format!(" {name}=")).unwrap_or_else(|| panic!("{name} not in {report}"));
    let rest = &report[at + name.len() + 2..];
    match rest.strip_prefix('"') {
        Some(quoted) => &quoted[..quoted.find('"').unwrap()],
        None => rest.split(' ').next().unwrap(),
    }
}

#[test]
fn without_a_key_the_firmware_refuses_to_arm_over_the_radio() {
    if !available() {
        return;
    }
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let dir = std::env::temp_dir().join(format!("fw-radio-dev-{}", std::process::id()));
    let (q, mut radio, rx) = boot(None, &dir);
    let mut buf = [0u8; MAX_FRAME];
    for m in [Uplink::Heartbeat, Uplink::Command(Command::Arm)] {
        radio.write_all(encode(&m, &mut buf).unwrap()).unwrap();
    }
    // The answer is the refusal, unauthenticated like everything on this link.
    let mut dec = Decoder::new();
    let deadline = Instant::now() + Duration::from_secs(30);
    let ack = loop {
        let b =
            rx.recv_timeout(deadline.saturating_duration_since(Instant::now())).expect("no acknowledgement");
        if let Some(Ok(Downlink::CommandAck(a))) = dec.push::<Downlink>(b) {
            break a;
        }
    };
    assert_eq!(ack, CommandResult::Refused(Command::Arm, Refusal::Unauthenticated));
    let r = report(q);
    eprintln!("{r}");
    assert_eq!(field(&r, "radio"), "none (development, arming refused)", "{r}");
    assert_eq!(field(&r, "arm_refused"), "1", "{r}");
    assert_eq!(field(&r, "mode"), "Disarmed", "{r}");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn with_the_probe_s_key_only_its_station_commands_the_firmware() {
    if !available() {
        return;
    }
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let dir = std::env::temp_dir().join(format!("fw-radio-keyed-{}", std::process::id()));
    let (q, mut radio, rx) = boot(Some(&key_block(&KEY)), &dir);
    let mut buf = [0u8; MAX_FRAME];
    // A plain Arm (a downgrade) and a hello under another key: refused, no answer.
    radio.write_all(encode(&Uplink::Command(Command::Arm), &mut buf).unwrap()).unwrap();
    let mut intruder = SecureLink::new(Role::Station, [0x77; 32]);
    radio.write_all(intruder.hello([9; 16], &mut buf).unwrap()).unwrap();
    // The station's hello: the welcome comes back, and the session carries the commands.
    let mut station = SecureLink::new(Role::Station, KEY);
    radio.write_all(station.hello([1; 16], &mut buf).unwrap()).unwrap();
    let mut dec = Decoder::new();
    let deadline = Instant::now() + Duration::from_secs(30);
    let mut next = |station: &mut SecureLink| -> Result<Opened<Downlink>, protocol::auth::AuthError> {
        loop {
            let b =
                rx.recv_timeout(deadline.saturating_duration_since(Instant::now())).expect("downlink ended");
            if let Some(Ok(body)) = dec.push_body(b) {
                return station.open::<Downlink>(body, 0, false, || [0; 16]);
            }
        }
    };
    // Nothing went down before the session: the first frame is the welcome.
    assert_eq!(next(&mut station), Ok(Opened::SessionStarted));
    for m in [Uplink::Heartbeat, Uplink::Command(Command::Arm)] {
        radio.write_all(station.seal(&m, &mut buf).unwrap()).unwrap();
    }
    let (mut ack, mut status) = (None, None);
    while ack.is_none() || status.is_none_or(|s: protocol::LinkStatus| s.auth.ok < 2) {
        match next(&mut station) {
            Ok(Opened::Message(Downlink::CommandAck(a))) => ack = Some(a),
            Ok(Opened::Message(Downlink::LinkStatus(s))) => status = Some(s),
            Ok(_) => {}
            Err(e) => panic!("a downlink frame failed: {e:?}"),
        }
    }
    // The Arm reached the flight stack (whatever it decided, not the radio's refusal).
    let ack = ack.unwrap();
    eprintln!("the Arm, answered by the flight stack: {ack:?}");
    let by_flight_stack = match ack {
        CommandResult::Accepted(c) => c == Command::Arm,
        CommandResult::Refused(c, r) => c == Command::Arm && r != Refusal::Unauthenticated,
    };
    assert!(by_flight_stack, "{ack:?}");
    let s = status.unwrap();
    assert!(s.authenticated, "{s:?}");
    assert_eq!((s.auth.sessions, s.auth.downgrade, s.auth.bad_tag, s.arm_refused), (1, 1, 1, 0), "{s:?}");
    let r = report(q);
    eprintln!("{r}");
    assert_eq!(field(&r, "radio"), "hmac-sha256-48", "{r}");
    assert_eq!(field(&r, "auth_refused"), "2", "{r}");
    std::fs::remove_dir_all(&dir).ok();
}

/// The socket as the station's link: reads wait at most 5 ms and read nothing when nothing came.
fn station_link(stream: &TcpStream) -> ground_station::link::Link {
    struct Polled(TcpStream);
    impl Read for Polled {
        fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
            match self.0.read(buf) {
                Err(e)
                    if matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut) =>
                {
                    Ok(0)
                }
                r => r,
            }
        }
    }
    let r = stream.try_clone().unwrap();
    r.set_read_timeout(Some(Duration::from_millis(5))).unwrap();
    ground_station::link::Link { reader: Box::new(Polled(r)), writer: Box::new(stream.try_clone().unwrap()) }
}

/// A configuration other than the built-in one: other gains, line and flow.
fn other_config(k: f32) -> flight_core::FlightConfig {
    let mut c = flight_core::FlightConfig::paper();
    c.control.gains.altitude.a_z1 *= k;
    c.vision.target.x_end_m = 2.0;
    c.flow.min_quality = 0.5;
    c
}

#[test]
fn the_station_s_upload_is_applied_and_stored_by_the_keyed_firmware() {
    use sim_host::station::configure::{UploadOptions, upload};
    if !available() {
        return;
    }
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let dir = std::env::temp_dir().join(format!("fw-radio-config-{}", std::process::id()));
    let (q, radio) = boot_raw(Some(&key_block(&KEY)), &dir);
    let opts = UploadOptions { key: Some(KEY), answer_timeout_s: 5.0, tries: 3 };
    let mut sequences = Vec::new();
    for k in [1.5, 1.25] {
        let up = upload(station_link(&radio), &other_config(k), &opts, |l| eprintln!("{l}")).unwrap();
        eprintln!("{up:?}");
        let (crc32, pieces) = flight_core::config_upload::chunks(&other_config(k)).unwrap();
        assert_eq!((up.ack.crc32, up.pieces), (crc32, pieces.len()));
        let protocol::ConfigOutcome::Applied { saved_sequence: Some(s) } = up.ack.outcome else {
            panic!("applied and stored: {up:?}")
        };
        sequences.push(s);
    }
    // Stored twice: the second set under the next sequence number (the other slot).
    assert_eq!(sequences[1], sequences[0].wrapping_add(1), "{sequences:?}");
    let r = report(q);
    eprintln!("{r}");
    assert_eq!(field(&r, "configs_applied"), "2", "{r}");
    assert_eq!(field(&r, "config_refused"), "0", "{r}");
    assert_eq!(field(&r, "mode"), "Disarmed", "{r}");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn without_a_key_the_firmware_refuses_the_station_s_upload_by_name() {
    use sim_host::station::configure::{UploadOptions, upload};
    if !available() {
        return;
    }
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let dir = std::env::temp_dir().join(format!("fw-radio-config-dev-{}", std::process::id()));
    let (q, radio) = boot_raw(None, &dir);
    let opts = UploadOptions { key: None, answer_timeout_s: 5.0, tries: 3 };
    let e = upload(station_link(&radio), &other_config(1.5), &opts, |l| eprintln!("{l}"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("Unauthenticated"), "{e}");
    let r = report(q);
    eprintln!("{r}");
    assert_eq!(field(&r, "configs_applied"), "0", "{r}");
    assert_ne!(field(&r, "config_refused"), "0", "{r}");
    std::fs::remove_dir_all(&dir).ok();
}
