//! `sim-host configure`: a flight configuration uploaded to a vehicle on the ground and stored in its flash
//! (docs/firmware.md, "Parameters in flash").
//!
//! The station checks the set with the flight stack's own checks, cuts it into the pieces of
//! `flight_core::config_upload` (`Uplink::Config`, 32 bytes each behind the set's CRC-32), sends them one every
//! [`PIECE_PERIOD`] after the link's handshake, and waits for the vehicle's `Downlink::ConfigAck` with the
//! same CRC-32. The vehicle puts the pieces together in any order and takes repeats, so an upload whose answer
//! does not come in time (a piece lost on the radio) is sent again whole, up to `tries` times. A refusal is
//! final and named (armed, damaged, another layout, undecodable, invalid, too large).
use crate::link_key::{LinkReceiver, LinkSecurity};
use anyhow::{Context, Result, bail};
use flight_core::FlightConfig;
use ground_station::link::Link;
use ground_station::source::now_unix_us;
use protocol::auth::{Key, Role};
use protocol::{ConfigAck, ConfigOutcome, Downlink, Uplink};
use std::io::{Read, Write};
use std::time::{Duration, Instant};

/// The pause after each piece: a piece's frame is at most about 60 bytes, so the upload stays under 6 kB/s,
/// within a 57600-baud radio's rate (and the board's 1 KB receive queue, which its control loop empties every
/// 2 ms, never fills).
pub const PIECE_PERIOD: Duration = Duration::from_millis(10);

/// What the upload is to do.
#[derive(Clone, Debug)]
pub struct UploadOptions {
    /// The radio's key, or `None` for an unauthenticated development link.
    pub key: Option<Key>,
    /// How long to wait for the handshake's answer, and for the answer to each try (s). Storing the set
    /// erases a 128 KB flash sector on the board, about a second.
    pub answer_timeout_s: f64,
    /// How many times the whole upload is sent before giving up.
    pub tries: u32,
}

/// A configuration the vehicle took.
#[derive(Clone, Copy, Debug)]
pub struct Uploaded {
    /// Its answer.
    pub ack: ConfigAck,
    /// The set's bytes (schema key and postcard) and pieces.
    pub bytes: usize,
    /// See [`Uploaded::bytes`].
    pub pieces: usize,
    /// The tries it took.
    pub tries: u32,
    /// The vehicle's frames that could not be read or authenticated, and its messages other than the answer.
    pub refused_frames: u64,
    /// See [`Uploaded::refused_frames`].
    pub other_messages: u64,
}

/// Uploads `cfg` over `link` and waits for the vehicle's answer: an error unless the vehicle applied it.
/// `say` gets a line for each stage.
pub fn upload(
    mut link: Link,
    cfg: &FlightConfig,
    opts: &UploadOptions,
    mut say: impl FnMut(&str),
) -> Result<Uploaded> {
    let (crc32, pieces) = flight_core::config_upload::chunks(cfg).map_err(|r| {
        anyhow::anyhow!("the configuration cannot be uploaded: {r:?} (the flight stack's checks refuse it)")
    })?;
    let bytes = pieces.iter().map(|p| p.len as usize).sum();
    let mut sec = LinkSecurity::new(Role::Station, opts.key);
    let mut rx = LinkReceiver::default();
    let (mut refused_frames, mut other_messages) = (0u64, 0u64);
    let timeout = Duration::from_secs_f64(opts.answer_timeout_s);
    // Reads what arrived, returns the answer to this upload if it came.
    let mut read = |link: &mut Link, sec: &mut LinkSecurity| -> Result<Option<ConfigAck>> {
        let mut buf = [0u8; 1024];
        let n = link.reader.read(&mut buf).context("the radio")?;
        let mut answer = None;
        for &b in &buf[..n] {
            match rx.push::<Downlink>(sec, b, now_unix_us(), false, || [0; 16]) {
                Some(crate::link_key::Received::Message(Downlink::ConfigAck(a))) if a.crc32 == crc32 => {
                    answer = Some(a)
                }
                Some(crate::link_key::Received::Message(_)) => other_messages += 1,
                Some(crate::link_key::Received::Refused) => refused_frames += 1,
                Some(crate::link_key::Received::SessionStarted(_)) | None => {}
            }
        }
        Ok(answer)
    };
    // The handshake (a keyed link): a hello each second until the vehicle answers.
    if let LinkSecurity::Keyed(_) = sec {
        let start = Instant::now();
        let mut next_hello = start;
        while !sec.ready() {
            if start.elapsed() > timeout {
                bail!(
                    "the vehicle did not answer the link's hello within {} s: is its key this --key? (a vehicle \
                     without a key needs --no-key)",
                    opts.answer_timeout_s
                );
            }
            if Instant::now() >= next_hello
                && let LinkSecurity::Keyed(l) = &mut sec
            {
                let nonce = crate::link_key::random_nonce()?;
                let mut out = [0u8; protocol::frame::MAX_FRAME];
                let hello = l.hello(nonce, &mut out).map_err(|e| anyhow::anyhow!("the hello: {e:?}"))?;
                link.writer.write_all(hello).context("the radio")?;
                link.writer.flush().context("the radio")?;
                next_hello += Duration::from_secs(1);
            }
            read(&mut link, &mut sec)?;
        }
        say("link authenticated");
    }
    for t in 1..=opts.tries.max(1) {
        say(&format!(
            "sending {bytes} bytes in {} pieces (CRC-32 {crc32:08x}), try {t} of {}",
            pieces.len(),
            opts.tries.max(1)
        ));
        for p in &pieces {
            let frame = sec.frame(&Uplink::Config(*p))?;
            link.writer.write_all(&frame).context("the radio")?;
            link.writer.flush().context("the radio")?;
            let until = Instant::now() + PIECE_PERIOD;
            while Instant::now() < until {
                if let Some(a) = read(&mut link, &mut sec)? {
                    // An answer to an earlier try, complete before this one's pieces all went.
                    return finish(a, bytes, pieces.len(), t, refused_frames, other_messages);
                }
            }
        }
        let until = Instant::now() + timeout;
        while Instant::now() < until {
            if let Some(a) = read(&mut link, &mut sec)? {
                return finish(a, bytes, pieces.len(), t, refused_frames, other_messages);
            }
        }
    }
    bail!(
        "no answer from the vehicle to the configuration upload after {} tries ({} s each; {refused_frames} of \
         its frames refused, {other_messages} other messages received): is it a firmware with parameter \
         uploads, on this link?",
        opts.tries.max(1),
        opts.answer_timeout_s
    )
}

fn finish(
    ack: ConfigAck,
    bytes: usize,
    pieces: usize,
    tries: u32,
    refused_frames: u64,
    other_messages: u64,
) -> Result<Uploaded> {
    match ack.outcome {
        ConfigOutcome::Applied { .. } => {
            Ok(Uploaded { ack, bytes, pieces, tries, refused_frames, other_messages })
        }
        ConfigOutcome::Refused(r) => bail!("the vehicle refused the configuration: {}", refusal_text(r)),
    }
}

/// What a refusal means for the operator.
pub fn refusal_text(r: protocol::ConfigRefusal) -> String {
    use protocol::ConfigRefusal as R;
    let why = match r {
        R::Armed => "it is armed: land and disarm first",
        R::Damaged => "the pieces arrived damaged or do not fit together",
        R::OtherLayout => "its firmware has another layout of the configuration (another version)",
        R::Undecodable => "the bytes do not decode as its configuration",
        R::Invalid => "the configuration fails its flight stack's checks (its log names the field)",
        R::TooLarge => "the configuration is longer than it takes",
        R::Unauthenticated => {
            "the link is not authenticated: provision the radio's key and give it with --key \
             (docs/security.md)"
        }
    };
    format!("{r:?} ({why})")
}

#[cfg(test)]
mod tests {
    use super::*;
    use flight_core::config_upload::ConfigUpload;
    use protocol::ConfigRefusal;
    use protocol::frame::{Decoder, encode};
    use std::net::TcpListener;

    /// How the stand-in vehicle behaves.
    #[derive(Clone, Copy)]
    enum Vehicle {
        /// Loses the third piece the first time it comes, then applies the whole.
        LosesAPiece,
        /// Refuses the whole as armed.
        Armed,
        /// Never answers.
        Silent,
    }

    /// A vehicle on an unauthenticated link at a free port; returns the port and, when the station
    /// disconnects, the pieces it saw.
    fn vehicle(kind: Vehicle) -> (u16, std::thread::JoinHandle<usize>) {
        let listener = TcpListener::bind("127.0.0.1:0").unwrap();
        let port = listener.local_addr().unwrap().port();
        let h = std::thread::spawn(move || {
            let (mut s, _) = listener.accept().unwrap();
            let mut dec = Decoder::new();
            let mut upload = ConfigUpload::new();
            let (mut seen, mut lost) = (0usize, false);
            let mut buf = [0u8; 512];
            loop {
                let n = match s.read(&mut buf) {
                    Ok(0) | Err(_) => return seen,
                    Ok(n) => n,
                };
                for &b in &buf[..n] {
                    let Some(Ok(Uplink::Config(c))) = dec.push::<Uplink>(b) else { continue };
                    seen += 1;
                    if matches!(kind, Vehicle::LosesAPiece) && c.offset == 64 && !lost {
                        lost = true;
                        continue;
                    }
                    let Some((crc32, r)) = upload.push(&c) else { continue };
                    let outcome = match (kind, r) {
                        (Vehicle::Silent, _) => continue,
                        (Vehicle::Armed, _) => ConfigOutcome::Refused(ConfigRefusal::Armed),
                        (_, Ok(_)) => ConfigOutcome::Applied { saved_sequence: Some(7) },
                        (_, Err(r)) => ConfigOutcome::Refused(r),
                    };
                    let mut out = [0u8; protocol::frame::MAX_FRAME];
                    let ack = Downlink::ConfigAck(ConfigAck { crc32, outcome });
                    s.write_all(encode(&ack, &mut out).unwrap()).unwrap();
                }
            }
        });
        (port, h)
    }

    fn link(port: u16) -> Link {
        let spec = ground_station::link::LinkSpec::parse(&format!("tcp:127.0.0.1:{port}")).unwrap();
        ground_station::link::open(&spec, Duration::from_millis(2)).unwrap()
    }

    fn opts() -> UploadOptions {
        UploadOptions { key: None, answer_timeout_s: 0.5, tries: 2 }
    }

    #[test]
    fn a_lost_piece_is_made_good_by_the_next_try() {
        let (port, vehicle) = vehicle(Vehicle::LosesAPiece);
        let cfg = FlightConfig::paper();
        let up = upload(link(port), &cfg, &opts(), |_| {}).unwrap();
        let (crc32, pieces) = flight_core::config_upload::chunks(&cfg).unwrap();
        assert_eq!(up.ack, ConfigAck { crc32, outcome: ConfigOutcome::Applied { saved_sequence: Some(7) } });
        assert_eq!(
            (up.tries, up.pieces, up.bytes),
            (2, pieces.len(), pieces.iter().map(|p| p.len as usize).sum())
        );
        // The second try's pieces up to the lost one completed the upload: the answer stopped the sending.
        let seen = vehicle.join().unwrap();
        assert!((pieces.len() + 3..2 * pieces.len()).contains(&seen), "{seen} pieces sent");
    }

    #[test]
    fn a_refusal_is_final_and_named() {
        let (port, vehicle) = vehicle(Vehicle::Armed);
        let e = upload(link(port), &FlightConfig::paper(), &opts(), |_| {}).unwrap_err().to_string();
        assert!(e.contains("Armed") && e.contains("land and disarm first"), "{e}");
        // One try only.
        assert_eq!(
            vehicle.join().unwrap(),
            flight_core::config_upload::chunks(&FlightConfig::paper()).unwrap().1.len()
        );
    }

    #[test]
    fn no_answer_after_every_try_is_an_error_that_says_so() {
        let (port, vehicle) = vehicle(Vehicle::Silent);
        let e = upload(link(port), &FlightConfig::paper(), &opts(), |_| {}).unwrap_err().to_string();
        assert!(e.contains("no answer") && e.contains("after 2 tries"), "{e}");
        assert_eq!(
            vehicle.join().unwrap(),
            2 * flight_core::config_upload::chunks(&FlightConfig::paper()).unwrap().1.len()
        );
    }

    #[test]
    fn an_invalid_configuration_is_refused_before_anything_is_sent() {
        let (port, vehicle) = vehicle(Vehicle::Silent);
        let mut cfg = FlightConfig::paper();
        cfg.control.vehicle.mass_kg = -1.0;
        let e = upload(link(port), &cfg, &opts(), |_| {}).unwrap_err().to_string();
        assert!(e.contains("Invalid"), "{e}");
        assert_eq!(vehicle.join().unwrap(), 0);
    }
}
