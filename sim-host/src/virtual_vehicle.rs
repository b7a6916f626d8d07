//! The virtual vehicle: the simulated vehicle with the flight code on board, in real time, exposing only what
//! a real one exposes to its ground station: the radio (the protocol's byte stream on a TCP port) and its two
//! cameras' frame streams (`ground_station::stream`, on their own ports). No simulator state crosses.
//!
//! The cameras stamp each frame with the machine's clock at its capture (`X-Timestamp-Us`, us since the Unix
//! epoch), as a webcam's driver stamps its buffers with the station's clock; the station maps those times to
//! the vehicle's clock with its clock sync, as it must with a real vehicle.
use crate::link_key::random_nonce;
use crate::sil::{RunStats, Sil};
use anyhow::{Context, Result, bail};
use flight_core::radio::{Incoming, NotSent, Security, VehicleRadio};
use ground_station::source::now_unix_us;
use ground_station::stream::{Frame, PartEncoding, StreamWriter};
use protocol::Downlink;
use protocol::frame::MAX_FRAME;
use std::io::{ErrorKind, Read, Write};
use std::net::{TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, mpsc};
use std::time::{Duration, Instant};

/// Where the virtual vehicle listens.
#[derive(Clone, Debug)]
pub struct ServeOptions {
    /// The radio: `tcp:HOST:PORT` (port 0: any free port, printed).
    pub link: String,
    /// The forward camera's stream: `tcp:HOST:PORT`.
    pub forward: String,
    /// The downward camera's stream, when the vehicle has one.
    pub down: Option<String>,
    /// How long to wait for the station's radio to connect (s).
    pub connect_timeout_s: f64,
    /// Set to end the flight now (Ctrl-C): the summary and the log are written with what was flown.
    pub stop: Arc<AtomicBool>,
    /// The radio's key (`--key`), or `None` for an unauthenticated development link (`--no-key`).
    pub key: Option<protocol::auth::Key>,
}

/// What the serving counted.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct ServeStats {
    /// Uplink messages decoded from the station.
    pub uplink_messages: u64,
    /// Uplink frames refused: damaged, of another version, or (keyed) failing authentication.
    pub uplink_refused: u64,
    /// How the radio is secured: `hmac-sha256-48`, or `none (development, arming allowed)` (the virtual
    /// vehicle is a firmware built with `unauthenticated-link`, docs/security.md).
    pub link_security: &'static str,
    /// The authentication's counters: sessions, frames accepted and refused by reason (docs/security.md).
    pub auth: protocol::auth::AuthCounters,
    /// Downlink messages not sent because no session was up yet (keyed link).
    pub downlink_before_session: u64,
    /// Downlink messages that did not fit a frame (or a spent session counter).
    pub downlink_unframable: u64,
    /// Downlink messages sent (the radio's own `LinkStatus` once a second among them).
    pub downlink_messages: u64,
    /// Frames each camera sent to its client (forward, down).
    pub frames_sent: [u64; 2],
    /// Frames each camera dropped: no client yet, or the client did not keep up (forward, down).
    pub frames_dropped: [u64; 2],
    /// How far the simulation fell behind the wall clock at worst (s).
    pub max_lag_s: f64,
}

/// A camera's server: the first client to connect gets the stream (raw parts: no encoding on loopback);
/// frames with no client, or that the client does not take in time, are dropped and counted.
struct CameraServer {
    tx: mpsc::SyncSender<Frame>,
    sent: Arc<AtomicU64>,
    dropped: u64,
    connected: Arc<AtomicBool>,
}

impl CameraServer {
    fn start(listener: TcpListener, stop: Arc<AtomicBool>) -> Self {
        let (tx, rx) = mpsc::sync_channel::<Frame>(4);
        let sent = Arc::new(AtomicU64::new(0));
        let connected = Arc::new(AtomicBool::new(false));
        let (sent2, conn2) = (sent.clone(), connected.clone());
        std::thread::spawn(move || {
            listener.set_nonblocking(true).ok();
            let client = loop {
                if stop.load(Ordering::Relaxed) {
                    return;
                }
                match listener.accept() {
                    Ok((s, _)) => break s,
                    Err(e) if e.kind() == ErrorKind::WouldBlock => {
                        // Frames keep coming while nobody watches: drop them.
                        while rx.try_recv().is_ok() {}
                        std::thread::sleep(Duration::from_millis(5));
                    }
                    Err(_) => return,
                }
            };
            client.set_nonblocking(false).ok();
            client.set_nodelay(true).ok();
            // The client's request (one line and a blank one); its content does not matter.
            let mut req = [0u8; 1024];
            client.set_read_timeout(Some(Duration::from_secs(2))).ok();
            if (&client).read(&mut req).is_err() {
                // No request within the timeout: serve the stream anyway (a client that only listens).
            }
            let Ok(mut w) = StreamWriter::start(client, PartEncoding::Raw) else { return };
            conn2.store(true, Ordering::Relaxed);
            while let Ok(f) = rx.recv() {
                if w.write(&f).is_err() {
                    break;
                }
                sent2.fetch_add(1, Ordering::Relaxed);
            }
            conn2.store(false, Ordering::Relaxed);
        });
        Self { tx, sent, dropped: 0, connected }
    }

    /// Sends a frame captured at the machine's `captured_unix_us`.
    fn send(&mut self, mut f: Frame, captured_unix_us: u64) {
        if !self.connected.load(Ordering::Relaxed) {
            self.dropped += 1;
            return;
        }
        f.timestamp_us = Some(captured_unix_us);
        if self.tx.try_send(f).is_err() {
            self.dropped += 1;
        }
    }
}

/// The bound ports (printed by `sim-host fly --serve-*` so that a client asking for port 0 finds them).
pub struct Bound {
    link: TcpListener,
    forward: TcpListener,
    down: Option<TcpListener>,
}

impl Bound {
    /// Binds the ports.
    pub fn bind(opts: &ServeOptions) -> Result<Self> {
        let bind = |spec: &str, what: &str| -> Result<TcpListener> {
            let addr =
                ground_station::link::listen_address(spec).map_err(|e| anyhow::anyhow!("{what} {e}"))?;
            TcpListener::bind(&addr).with_context(|| format!("{what}: cannot listen on {addr}"))
        };
        Ok(Self {
            link: bind(&opts.link, "--serve-link")?,
            forward: bind(&opts.forward, "--serve-forward")?,
            down: opts.down.as_deref().map(|d| bind(d, "--serve-down")).transpose()?,
        })
    }

    /// The addresses (link, forward, down).
    pub fn addresses(&self) -> (String, String, Option<String>) {
        let a = |l: &TcpListener| l.local_addr().map_or_else(|e| e.to_string(), |a| a.to_string());
        (a(&self.link), a(&self.forward), self.down.as_ref().map(a))
    }
}

/// Flies `sil` in real time for at most `duration_s` against a station that connects to the ports: waits
/// for the radio's connection, then runs until the vehicle has landed and disarmed, crashed, the duration
/// ran out, `stop` is set (Ctrl-C), or the station hung up after the vehicle disarmed.
pub fn serve(
    sil: &mut Sil,
    bound: Bound,
    opts: &ServeOptions,
    duration_s: f64,
    stop: Arc<AtomicBool>,
    mut progress: impl FnMut(f64),
) -> Result<(RunStats, ServeStats)> {
    sil.serve_station()?;
    let mut stats = ServeStats::default();
    let mut forward = CameraServer::start(bound.forward, stop.clone());
    let mut down = bound.down.map(|l| CameraServer::start(l, stop.clone()));
    if sil.scenario().down_camera.enabled && down.is_none() {
        bail!("the scenario's vehicle has a downward camera: give --serve-down tcp:HOST:PORT");
    }
    // The station's radio.
    bound.link.set_nonblocking(true)?;
    let wait_until = Instant::now() + Duration::from_secs_f64(opts.connect_timeout_s);
    let mut link: TcpStream = loop {
        match bound.link.accept() {
            Ok((s, _)) => break s,
            Err(e) if e.kind() == ErrorKind::WouldBlock => {
                if stop.load(Ordering::Relaxed) {
                    bail!("stopped before a ground station connected");
                }
                if Instant::now() > wait_until {
                    bail!(
                        "no ground station connected to the radio port within {} s",
                        opts.connect_timeout_s
                    );
                }
                std::thread::sleep(Duration::from_millis(10));
            }
            Err(e) => return Err(e).context("accepting the radio's connection"),
        }
    };
    link.set_nonblocking(true)?;
    link.set_nodelay(true)?;
    // The firmware's radio code (flight_core::radio).
    let mut radio = VehicleRadio::new(radio_security(opts.key));
    stats.link_security = radio.describe();
    let mut reply = [0u8; MAX_FRAME];
    let mut frame_buf = [0u8; MAX_FRAME];
    // The nonce of the next session, drawn before it is needed (the handshake runs byte by byte).
    let mut next_nonce = random_nonce()?;
    let mut armed = false;
    let mut buf = [0u8; 4096];
    let end_us = (duration_s * 1e6).round() as u64;
    // The simulation is paced by the monotonic clock from here; frames are stamped on the machine's
    // system clock at their capture (`capture_stamp`).
    let start = Instant::now();
    let mut station_gone = false;
    let mut last_progress = 0.0;
    loop {
        if stop.load(Ordering::Relaxed) {
            break;
        }
        // Simulate up to the wall clock first, the clock read again at each step (the steps take time: a
        // catch-up after the process waited for a core renders frames). The uplink read below is then
        // handled at about the simulated time it was read, as a board's clock, which never stalls, would
        // stamp it: read before the catch-up, a time-sync request that arrived during a 40 ms stall was
        // answered with a clock 40 ms behind the station's, outside the exchange's causal interval.
        let mut running = true;
        let mut n = 0;
        while running && (sil.time_s() * 1e6) as u64 <= start.elapsed().as_micros() as u64 && n < 100 {
            running = sil.step(end_us);
            n += 1;
        }
        let wall_us = start.elapsed().as_micros() as u64;
        let unix_us = now_unix_us();
        let lag = wall_us as f64 * 1e-6 - sil.time_s();
        stats.max_lag_s = stats.max_lag_s.max(lag);
        // The uplink that arrived.
        if !station_gone {
            loop {
                match link.read(&mut buf) {
                    Ok(0) => {
                        station_gone = true;
                        break;
                    }
                    Ok(n) => {
                        let now_us = (sil.time_s() * 1e6) as u64;
                        for &b in &buf[..n] {
                            let (nonce, mut nonce_used) = (next_nonce, false);
                            let got = radio.push(
                                b,
                                now_us,
                                armed,
                                || {
                                    nonce_used = true;
                                    nonce
                                },
                                &mut reply,
                            );
                            if nonce_used {
                                next_nonce = random_nonce()?;
                            }
                            match got {
                                Some(Incoming::Message(m)) => {
                                    stats.uplink_messages += 1;
                                    sil.uplink(m);
                                }
                                Some(Incoming::Reply(len))
                                    if write_all_nonblocking(&mut link, &reply[..len]).is_err() =>
                                {
                                    station_gone = true;
                                }
                                Some(Incoming::Reply(_)) => {}
                                Some(Incoming::Refused) => stats.uplink_refused += 1,
                                None => {}
                            }
                        }
                    }
                    Err(e) if e.kind() == ErrorKind::WouldBlock => break,
                    Err(_) => {
                        station_gone = true;
                        break;
                    }
                }
            }
        }
        // What the vehicle exposes.
        if let Some(p) = sil.ports() {
            let frames: Vec<(u64, Frame)> = p.forward.drain(..).collect();
            let down_frames: Vec<(u64, Frame)> = p.down.drain(..).collect();
            let downlink: Vec<Downlink> = p.downlink.drain(..).collect();
            for (t_us, f) in frames {
                forward.send(f, capture_stamp(unix_us, wall_us, t_us));
            }
            if let Some(d) = down.as_mut() {
                for (t_us, f) in down_frames {
                    d.send(f, capture_stamp(unix_us, wall_us, t_us));
                }
            }
            for m in &downlink {
                if let Some(t) = m.telemetry() {
                    armed = t.mode != control_core::FlightMode::Disarmed;
                }
            }
            if !station_gone {
                let status = radio.status_due((sil.time_s() * 1e6) as u64);
                for m in downlink.into_iter().chain(status) {
                    match radio.frame(&m, &mut frame_buf) {
                        // A radio drops what it cannot send; the socket is local and never full in practice.
                        Ok(bytes) => match write_all_nonblocking(&mut link, bytes) {
                            Ok(()) => stats.downlink_messages += 1,
                            Err(_) => station_gone = true,
                        },
                        Err(NotSent::NoSession) => stats.downlink_before_session += 1,
                        Err(NotSent::Unframable) => stats.downlink_unframable += 1,
                    }
                }
            }
        }
        if sil.time_s() - last_progress >= 0.1 {
            last_progress = sil.time_s();
            progress(sil.time_s());
        }
        if !running {
            break;
        }
        let ahead = sil.time_s() - start.elapsed().as_secs_f64();
        if ahead > 0.0 {
            std::thread::sleep(Duration::from_secs_f64(ahead.min(0.002)));
        }
    }
    stop.store(true, Ordering::Relaxed);
    stats.frames_sent =
        [forward.sent.load(Ordering::Relaxed), down.as_ref().map_or(0, |d| d.sent.load(Ordering::Relaxed))];
    stats.frames_dropped = [forward.dropped, down.as_ref().map_or(0, |d| d.dropped)];
    stats.auth = radio.auth_counters();
    if link.flush().is_err() {
        // The station hung up; what it did not take is counted in neither direction's messages.
    }
    Ok((sil.finish(), stats))
}

/// The virtual vehicle's radio: keyed with `--key`; with `--no-key`, the development mode of a firmware built
/// with the `unauthenticated-link` feature (it arms: the simulator is a development tool).
pub fn radio_security(key: Option<protocol::auth::Key>) -> Security {
    match key {
        Some(k) => Security::Keyed(k),
        None => Security::Development { allow_arming: true },
    }
}

/// Writes all of `bytes` to a non-blocking socket, waiting briefly while it is full.
fn write_all_nonblocking(s: &mut TcpStream, mut bytes: &[u8]) -> std::io::Result<()> {
    let deadline = Instant::now() + Duration::from_millis(200);
    while !bytes.is_empty() {
        match s.write(bytes) {
            Ok(0) => return Err(ErrorKind::WriteZero.into()),
            Ok(n) => bytes = &bytes[n..],
            Err(e) if e.kind() == ErrorKind::WouldBlock && Instant::now() < deadline => {
                std::thread::sleep(Duration::from_micros(200))
            }
            Err(e) => return Err(e),
        }
    }
    Ok(())
}

/// The machine's system-clock time (us since the Unix epoch) of a frame captured at the simulation's
/// `t_us`, from the system clock `unix_us` read when the pacing clock said `wall_us` (the simulation keeps
/// `t = wall` within a control period): a camera stamps its exposure on the station's clock, not its
/// sending. Reading the system clock at every turn, rather than adding `t` to its reading at the start,
/// follows the system clock when it is slewed: this VM's ran 0.5 % faster than the monotonic clock for a
/// while, and frames stamped `start + t` drifted 5 ms a second from the station's clock, 20 ms after 4 s,
/// enough for the fixes to be fused against the wrong attitude and a hover test to crash.
pub fn capture_stamp(unix_us: u64, wall_us: u64, t_us: u64) -> u64 {
    (unix_us as i128 - wall_us as i128 + t_us as i128).max(0) as u64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_frame_is_stamped_on_the_system_clock_read_now_not_at_the_start() {
        // Captured 3 ms of simulation before the pacing clock's reading: 3 ms before the system clock's.
        assert_eq!(capture_stamp(1_000_000_000, 5_000_000, 4_997_000), 999_997_000);
        // The system clock slewed 0.5 % fast: after 4 s of pacing it reads 20 ms more than start + 4 s, and
        // the frame follows it (a stamp of start + t would be 20 ms behind the station's clock).
        let (start_unix, wall) = (1_000_000_000u64, 4_000_000u64);
        let unix_now = start_unix + wall + 20_000;
        assert_eq!(capture_stamp(unix_now, wall, wall), unix_now);
        // The simulation a little ahead of the pacing clock: after it.
        assert_eq!(capture_stamp(1_000, 500, 700), 1_200);
    }
}
