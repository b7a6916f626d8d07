//! `sim-host station`: the ground station for a real vehicle (or the virtual one, `sim-host fly
//! --serve-link ...`). It reads the cameras' frame streams, measures the line and the flow with the same
//! code as the simulator's station, stamps the measurements on the vehicle's clock (clock sync over the
//! radio), runs the operator's script against the mode the telemetry reports, and sends all of it up the
//! radio. It knows the vehicle only through the radio.
//!
//! Every run records a flight log (`station.log`, docs/log-format.md): each message sent and received with the
//! station's time (`LogRecord::Station`), the clock sync's mapping to the vehicle's clock after each answer
//! it accepted, and the camera frames if asked (at their capture time on the vehicle's clock). The log is
//! finished (with its end record) however the run ends, an error included.
mod cameras;
pub mod configure;
mod stats;

use crate::downward::GroundFlow;
use crate::flightlog::{
    CameraFrame, CameraId, FrameEncoding, FramePolicy, LogRecord, LogWriter, StationEvent,
};
use crate::imageio::{FrameImages, GrayImage};
use crate::link_key::{LinkReceiver, LinkSecurity, Received};
pub use crate::mavlink_endpoint::MavlinkStats;
use crate::mavlink_endpoint::{GroundRequest, MavlinkEndpoint};
use crate::scenario::Scenario;
use crate::vision::GroundVision;
use anyhow::{Context, Result, bail};
pub use cameras::{CAMERA_STALL_S, forward_image, measure_forward};
use cameras::{StallWatch, camera_thread};
use control_core::FlightMode;
use ground_station::clock::ClockSync;
use ground_station::console::{ConsoleView, KeyAction};
use ground_station::link::{Link, LinkSpec};
use ground_station::operator::{Operator, Script, command_name};
use ground_station::source::{SourceWant, now_unix_us};
use ground_station::v4l2::CaptureCounters;
use protocol::{Downlink, FlowMeasurement, PackedFlow, PackedVision, Telemetry, Uplink};
pub use stats::StationStats;
use std::io::ErrorKind;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, mpsc};
use std::time::{Duration, Instant};

/// Time-sync requests per second.
pub const TIME_SYNC_HZ: f64 = 10.0;

/// The compact mode, for a radio of 57600 baud (5760 bytes a second, 2880 with the 2x margin): the line
/// measured in every `COMPACT_VISION_EVERY`th forward frame (10 Hz of 30), the flow over every
/// `COMPACT_FLOW_EVERY`th downward frame (20 Hz of 60, pairs three frames apart), time sync at
/// `COMPACT_TIME_SYNC_HZ`, and the vehicle asked (`downlink.telemetry_every_steps`, over the link) for
/// telemetry every `COMPACT_TELEMETRY_EVERY` steps (10 Hz at 500 Hz). Measured budgets: docs/ground-station.md.
pub const COMPACT_VISION_EVERY: u64 = 3;
/// See [`COMPACT_VISION_EVERY`].
pub const COMPACT_FLOW_EVERY: u64 = 3;
/// See [`COMPACT_VISION_EVERY`].
pub const COMPACT_TIME_SYNC_HZ: f64 = 2.0;
/// See [`COMPACT_VISION_EVERY`].
pub const COMPACT_TELEMETRY_EVERY: f32 = 50.0;

/// What the station is to do.
#[derive(Clone, Debug)]
pub struct StationOptions {
    /// The radio.
    pub link: LinkSpec,
    /// The forward camera (`ground_station::source::open`: `tcp:HOST:PORT`, `folder:PATH`).
    pub forward: String,
    /// The downward camera's stream, if any.
    pub down: Option<String>,
    /// The line, the cameras (unless calibrations replace them) and the link's rates.
    pub scenario: Scenario,
    /// The operator's script.
    pub script: Script,
    /// The longest run (s).
    pub duration_s: f64,
    /// How long to wait for the first telemetry (s).
    pub answer_timeout_s: f64,
    /// The flight log to write.
    pub log: std::path::PathBuf,
    /// Camera frames in the log.
    pub frames: FramePolicy,
    /// The compact mode ([`COMPACT_VISION_EVERY`]).
    pub compact: bool,
    /// The radio's key, or `None` for an unauthenticated development link.
    pub key: Option<protocol::auth::Key>,
    /// A MAVLink ground control station to serve (`udp:HOST:PORT`, docs/mavlink.md), if any.
    pub mavlink: Option<String>,
    /// Publish the station live for Foxglove or Lichtblick on `HOST:PORT` (`crate::live`, the `live` feature).
    pub live: Option<String>,
}

/// The station's flight log.
struct Recorder {
    log: LogWriter,
    frames: Option<FrameEncoding>,
    /// The live view's hand-over (`--live`): the log's records and the frames with what the vision made of them.
    tap: Option<Box<dyn crate::sil::FlightTap>>,
}

impl Recorder {
    fn event(&mut self, e: StationEvent) -> Result<()> {
        let r = LogRecord::Station(e);
        if let Some(tap) = self.tap.as_mut() {
            tap.records(std::slice::from_ref(&r));
        }
        self.log.write(&r).context("the station's flight log")
    }

    fn frame(&mut self, f: Result<CameraFrame>) -> Result<()> {
        self.log.write(&LogRecord::Frame(f?)).context("the station's flight log")
    }
}

/// What the operator sees and does while the station runs: a progress line, or the console.
pub trait StationUi {
    /// The station's state, about ten times a second.
    fn show(&mut self, view: &ConsoleView);
    /// The operator's keys since the last call (called at every turn of the station's loop).
    fn actions(&mut self) -> Vec<KeyAction> {
        Vec::new()
    }
}

/// A keyed session with no authentic downlink for this long is taken as dead and a new hello sent (s): the
/// vehicle sends telemetry at 10-25 Hz and its link status every second, so 3 s of nothing is a session the
/// vehicle no longer shares (or a radio that is down, which the new hello does not harm: the vehicle takes it
/// once its own side has been quiet for `protocol::auth::HELLO_QUIET_US`).
pub const REHELLO_AFTER_S: f64 = 3.0;

/// Runs the station until the vehicle has landed and disarmed after flying, the duration ran out, `stop`
/// is set, or the vehicle went away. The flight log is written however it ends: on an error, the error says
/// where the log of the run so far is.
pub fn run_station(
    opts: &StationOptions,
    stop: Arc<AtomicBool>,
    ui: &mut dyn StationUi,
) -> Result<StationStats> {
    let header = crate::flightlog::LogHeader {
        format_version: crate::flightlog::LOG_FORMAT_VERSION,
        schema_hash: crate::flightlog::schema_hash(),
        wire_version: protocol::frame::WIRE_VERSION,
        writer: format!("sim-host {} station", env!("CARGO_PKG_VERSION")),
        scenario_toml: toml::to_string(&opts.scenario).context("the scenario as TOML")?,
        seed: 0,
        camera: format!("station: forward {}, down {}", opts.forward, opts.down.as_deref().unwrap_or("none")),
        flight_computer: format!("the vehicle at the other end of the radio ({})", opts.link),
        reference: String::new(),
        reference_yaw_absolute: false,
        link_security: LinkSecurity::new(protocol::auth::Role::Station, opts.key).describe().to_string(),
    };
    #[cfg(not(feature = "live"))]
    if opts.live.is_some() {
        bail!(
            "--live: this sim-host was built without the live view; build it with `--features live` \
             (`cargo run --release -p sim-host --features live -- station --live ...`)"
        );
    }
    #[cfg(feature = "live")]
    let live_view = match &opts.live {
        None => None,
        Some(addr) => {
            let view = crate::live::LiveView::start(addr, &opts.scenario)?;
            // On stdout, for whoever connects a viewer (a port 0 was chosen here).
            println!("live view ws://{}", view.address());
            use std::io::Write as _;
            std::io::stdout().flush()?;
            Some(view)
        }
    };
    #[cfg(feature = "live")]
    let tap = live_view.as_ref().map(|v| Box::new(v.tap(true)) as Box<dyn crate::sil::FlightTap>);
    #[cfg(not(feature = "live"))]
    let tap = None;
    let mut rec = Recorder {
        tap,
        log: LogWriter::create(&opts.log, &header)?,
        frames: match opts.frames {
            FramePolicy::Drop => None,
            FramePolicy::Png => Some(FrameEncoding::Png),
            FramePolicy::Raw => Some(FrameEncoding::Raw),
        },
    };
    #[allow(unused_mut)]
    let mut result = station_loop(opts, stop, ui, &mut rec);
    #[cfg(feature = "live")]
    if let Some(view) = live_view {
        drop(rec.tap.take());
        let ls = view.finish();
        eprintln!("live view: {}", ls.describe());
        if let Ok(st) = result.as_mut() {
            st.live = serde_json::to_value(ls).ok();
        }
    }
    let records = rec.log.records;
    let kept = rec.log.finish();
    match (result, kept) {
        (Ok(mut st), Ok(())) => {
            st.log_records = records;
            Ok(st)
        }
        (Ok(_), Err(e)) => Err(e),
        (Err(e), Ok(())) => Err(anyhow::anyhow!(
            "{e:#}\nthe log of the run so far ({records} records) is {}",
            opts.log.display()
        )),
        (Err(e), Err(log)) => Err(e.context(format!("and its flight log: {log:#}"))),
    }
}

fn station_loop(
    opts: &StationOptions,
    stop: Arc<AtomicBool>,
    ui: &mut dyn StationUi,
    rec: &mut Recorder,
) -> Result<StationStats> {
    let scenario = &opts.scenario;
    let Link { mut reader, mut writer } = ground_station::link::open(&opts.link, Duration::from_millis(1))
        .map_err(|e| anyhow::anyhow!("--link: {e}"))?;
    // The radio's bytes are read on their own thread (a serial read blocks up to its timeout).
    let (down_tx, down_rx) = mpsc::channel::<(Downlink, u64)>();
    let decoder_counts = Arc::new(std::sync::Mutex::new((protocol::frame::DecodeCounters::default(), 0u64)));
    let counts2 = decoder_counts.clone();
    let stop2 = stop.clone();
    // The link's security, shared by the reader (which opens the downlink and the vehicle's welcome) and the
    // sender (which seals the uplink).
    let security =
        Arc::new(std::sync::Mutex::new(LinkSecurity::new(protocol::auth::Role::Station, opts.key)));
    let security2 = security.clone();
    let link_reader = std::thread::spawn(move || -> Option<String> {
        let mut rx = LinkReceiver::default();
        let mut buf = [0u8; 4096];
        while !stop2.load(Ordering::Relaxed) {
            match reader.read(&mut buf) {
                Ok(0) => continue,
                Ok(n) => {
                    let t = now_unix_us();
                    let Ok(mut sec) = security2.lock() else { return None };
                    for &b in &buf[..n] {
                        // The station never takes a hello: its nonce source is never asked.
                        if let Some(Received::Message(m)) =
                            rx.push::<Downlink>(&mut sec, b, t, false, || [0; 16])
                            && down_tx.send((m, t)).is_err()
                        {
                            return None;
                        }
                    }
                    drop(sec);
                    if let Ok(mut c) = counts2.lock() {
                        *c = (rx.framing(), c.1 + n as u64);
                    }
                }
                Err(e)
                    if matches!(
                        e.kind(),
                        ErrorKind::WouldBlock | ErrorKind::TimedOut | ErrorKind::Interrupted
                    ) => {}
                Err(e) => return Some(format!("the radio: {e}")),
            }
        }
        None
    });
    let want = |c: &vision_core::CameraModel, channels, rate_hz| SourceWant {
        width: c.width as usize,
        height: c.height as usize,
        channels,
        rate_hz,
    };
    let forward_want = want(&scenario.forward_camera_model(), 3, scenario.forward_camera.rate_hz);
    let forward = camera_thread(&opts.forward, forward_want, "forward");
    let down_camera = scenario.down_camera_model();
    let down_want = want(&down_camera, 1, scenario.down_camera.rate_hz);
    let down = opts.down.as_deref().map(|d| camera_thread(d, down_want, "down"));
    let (mut forward_watch, mut down_watch) = (StallWatch::default(), StallWatch::default());

    let mut mav = opts.mavlink.as_deref().map(MavlinkEndpoint::open).transpose()?;
    let mut vision = GroundVision::new(scenario);
    let forward_camera = scenario.forward_camera_model();
    let mut flow = down.as_ref().map(|_| GroundFlow::new(scenario));
    let mut clock = ClockSync::default().with_answer_period((1e6 / scenario.mission.control_rate_hz) as u64);
    let mut operator = Operator::with_script(opts.script.clone());
    let mut telemetry_at = 0.0;
    let mut stats = StationStats::default();
    let mut telemetry: Option<Telemetry> = None;
    let mut was_airborne = false;
    let mut latencies_us: Vec<u64> = Vec::new();
    let sent_bytes = std::cell::Cell::new(0u64);
    let security3 = security.clone();
    let send = |m: &Uplink, w: &mut Box<dyn std::io::Write + Send>, rec: &mut Recorder| -> Result<()> {
        let bytes = {
            let mut sec = security3.lock().map_err(|_| anyhow::anyhow!("the radio's reader failed"))?;
            if !sec.ready() {
                bail!("{m:?} was to be sent before the link's handshake");
            }
            sec.frame(m).with_context(|| format!("framing {m:?}"))?
        };
        w.write_all(&bytes).context("the radio")?;
        w.flush().context("the radio")?;
        sent_bytes.set(sent_bytes.get() + bytes.len() as u64);
        rec.event(StationEvent::Sent { station_time_us: now_unix_us(), message: *m })
    };
    // A keyed link starts with the handshake: a hello, again each second until the vehicle answers, and anew
    // when the session goes quiet.
    let mut next_hello = 0.0;
    let (mut had_session, mut last_down) = (false, 0.0);
    let hello = |w: &mut Box<dyn std::io::Write + Send>, stats: &mut StationStats| -> Result<()> {
        let nonce = crate::link_key::random_nonce()?;
        let mut buf = [0u8; protocol::frame::MAX_FRAME];
        let bytes = {
            let mut sec = security.lock().map_err(|_| anyhow::anyhow!("the radio's reader failed"))?;
            let LinkSecurity::Keyed(l) = &mut *sec else { return Ok(()) };
            l.hello(nonce, &mut buf).map_err(|e| anyhow::anyhow!("the hello: {e:?}"))?.to_vec()
        };
        w.write_all(&bytes).context("the radio")?;
        w.flush().context("the radio")?;
        sent_bytes.set(sent_bytes.get() + bytes.len() as u64);
        stats.hellos_sent += 1;
        Ok(())
    };
    let start = Instant::now();
    let mut next_sync = 0.0;
    let mut sync_dither = now_unix_us() | 1;
    let mut next_announce = 0.0;
    let mut next_heartbeat = 0.0;
    let mut prev_down: Option<(u64, u32)> = None;
    let mut last_progress = -1.0;
    let ended = loop {
        let t = start.elapsed().as_secs_f64();
        if stop.load(Ordering::Relaxed) {
            break "stopped".to_string();
        }
        if t > opts.duration_s {
            break format!("the duration ({} s) ran out", opts.duration_s);
        }
        if let Some(m) = mav.as_mut() {
            m.tick(start.elapsed().as_micros() as u64);
        }
        let session = security.lock().map(|sec| sec.ready()).unwrap_or(false);
        if session && !had_session {
            last_down = t;
        }
        had_session |= session;
        if !session && t >= next_hello {
            hello(&mut writer, &mut stats)?;
            next_hello = t + 1.0;
        }
        if session && opts.key.is_some() && t - last_down > REHELLO_AFTER_S {
            // Nothing authentic for a while: the vehicle's session is not ours any more (it rebooted, or a
            // replayed hello replaced it while it was disarmed). A new handshake; nothing goes up until then.
            hello(&mut writer, &mut stats)?;
            stats.rehellos += 1;
            next_hello = t + 1.0;
            last_down = t;
            continue;
        }
        if !had_session && t > opts.answer_timeout_s {
            bail!(
                "the vehicle did not answer the link's hello within {} s ({} sent): is its key this --key? (a \
                 vehicle without a key needs --no-key)",
                opts.answer_timeout_s,
                stats.hellos_sent
            );
        }
        if telemetry.is_none() && t > opts.answer_timeout_s {
            bail!(
                "the vehicle did not answer on the radio within {} s (no telemetry)",
                opts.answer_timeout_s
            );
        }
        // What came down.
        while let Ok((m, at)) = down_rx.try_recv() {
            last_down = t;
            rec.event(StationEvent::Received { station_time_us: at, message: m })?;
            if let Some(mv) = mav.as_mut() {
                mv.downlink(&m);
            }
            if let Some(tm) = m.telemetry() {
                stats.telemetry += 1;
                let mode = format!("{:?}", tm.mode);
                if stats.modes.last().is_none_or(|(_, m)| *m != mode) {
                    stats.modes.push((t, mode));
                }
                was_airborne |= tm.mode.airborne();
                telemetry = Some(tm);
                telemetry_at = t;
                continue;
            }
            match m {
                // Taken above, packed or not.
                Downlink::Telemetry(_) | Downlink::PackedTelemetry(_) => {}
                Downlink::TimeSync { station_time_us, vehicle_time_us } => {
                    stats.time_sync_answers += 1;
                    // A refused exchange is counted by the clock sync itself (reported below).
                    if clock.observe(station_time_us, vehicle_time_us, at).is_err() {
                        continue;
                    }
                    if let (Some(v), Some(b)) = (clock.vehicle_time_us(at), clock.bound_us()) {
                        let bound_us = b.ceil().min(u32::MAX as f64) as u32;
                        rec.event(StationEvent::Clock { station_time_us: at, vehicle_time_us: v, bound_us })?;
                    }
                }
                Downlink::CommandAck(r) => stats.command_acks.push(format!("{t:.2} s: {r:?}")),
                Downlink::Battery(b) => stats.vehicle_battery = Some(b),
                Downlink::ConfigAck(a) => {
                    stats.config_acks.push(format!("{t:.2} s: {:08x} {:?}", a.crc32, a.outcome))
                }
                Downlink::LinkStatus(l) => stats.vehicle_link = Some(l),
                Downlink::Param(r) => {
                    if opts.compact && r.id == control_core::params::ParamId::TelemetryEvery {
                        stats.compact_announced = Some(r.outcome == control_core::ParamOutcome::Ok);
                    }
                }
            }
        }
        if link_reader.is_finished() {
            break "the radio closed".to_string();
        }
        if was_airborne && telemetry.is_some_and(|tm| tm.mode == FlightMode::Disarmed) {
            break "the vehicle landed and disarmed".to_string();
        }
        // Nothing goes up before the link's handshake (a keyed vehicle would refuse it).
        if !session {
            std::thread::sleep(Duration::from_millis(1));
            continue;
        }
        // Up: time sync, heartbeat, the operator.
        if t >= next_sync {
            send(&Uplink::TimeSync { station_time_us: now_unix_us() }, &mut writer, rec)?;
            stats.uplink_other += 1;
            // Dithered (0.5 to 1.5 periods): a request period that divides the telemetry's would meet the
            // vehicle's answers queued behind the same telemetry frame every time on a slow radio, and the
            // clock sync would never see a quick exchange.
            sync_dither ^= sync_dither << 13;
            sync_dither ^= sync_dither >> 7;
            sync_dither ^= sync_dither << 17;
            let u = (sync_dither >> 11) as f64 / (1u64 << 53) as f64;
            next_sync += (0.5 + u) / if opts.compact { COMPACT_TIME_SYNC_HZ } else { TIME_SYNC_HZ };
        }
        // The compact mode announced: the vehicle's telemetry period, sent once a second until answered.
        if opts.compact && stats.compact_announced.is_none() && telemetry.is_some() && t >= next_announce {
            let m = Uplink::ParamSet {
                id: control_core::params::ParamId::TelemetryEvery,
                value: COMPACT_TELEMETRY_EVERY,
            };
            send(&m, &mut writer, rec)?;
            stats.uplink_other += 1;
            next_announce = t + 1.0;
        }
        if t >= next_heartbeat {
            send(&Uplink::Heartbeat, &mut writer, rec)?;
            stats.uplink_other += 1;
            next_heartbeat += 1.0 / scenario.link.heartbeat_hz;
        }
        // The operator's keys: a kill before anything else.
        let mut quit = false;
        for a in ui.actions() {
            match a {
                KeyAction::Kill => {
                    operator.kill();
                    stats.operator_commands.push((t, "kill".into()));
                }
                KeyAction::Command(c) => {
                    operator.command(c);
                    stats.operator_commands.push((t, command_name(Some(c)).into()));
                }
                KeyAction::Quit => quit = true,
            }
        }
        // The ground control station's commands and parameter requests: commands and kills as the console's
        // keys give them (the operator's tick below sends them).
        if let Some(mv) = mav.as_mut() {
            let now_us = start.elapsed().as_micros() as u64;
            if let Ok(c) = decoder_counts.lock() {
                mv.set_link_errors(c.0.errors() as u64);
            }
            for r in mv.poll(now_us)? {
                match r {
                    GroundRequest::Kill => {
                        operator.kill();
                        stats.operator_commands.push((t, "kill (mavlink)".into()));
                    }
                    GroundRequest::Command(c) => {
                        operator.command(c);
                        stats.operator_commands.push((t, format!("{} (mavlink)", command_name(Some(c)))));
                    }
                    GroundRequest::Uplink(m) => {
                        send(&m, &mut writer, rec)?;
                        stats.uplink_other += 1;
                    }
                }
            }
        }
        // The operator's script runs on the station's monotonic clock (a step of the system clock must not
        // move it), as does everything the station reports in seconds since its start.
        let op_us = start.elapsed().as_micros() as u64;
        if let Some(c) = operator.tick(op_us, telemetry.map(|tm| tm.mode)) {
            send(&Uplink::Command(c), &mut writer, rec)?;
            stats.uplink_commands += 1;
        }
        // The cameras.
        let mut idle = true;
        while let Ok(r) = forward.try_recv() {
            idle = false;
            let (f, arrived, counters) = r.map_err(anyhow::Error::msg)?;
            stats.forward_frames += 1;
            stats.camera_counters[0] = counters;
            forward_watch.frame(t);
            let stamp = f.timestamp_us.unwrap_or(arrived);
            let Some(vehicle_us) = clock.vehicle_time_us(stamp) else {
                stats.frames_before_clock += 1;
                continue;
            };
            let frame_seq = f.seq.unwrap_or(stats.forward_frames) as u32;
            if opts.compact && !(stats.forward_frames - 1).is_multiple_of(COMPACT_VISION_EVERY) {
                stats.compact_skipped[0] += 1;
                continue;
            }
            let img = forward_image(f, &forward_camera)?;
            if let Some(enc) = rec.frames {
                rec.frame(CameraFrame::rgb(frame_seq, vehicle_us, &img, enc))?;
            }
            // A rolling shutter (the calibration's `line_delay_s`): its rows corrected with the rates of the
            // last telemetry.
            let rates = telemetry.map_or(geometry::Vec3::ZERO, |tm| tm.estimate.rates_rad_s);
            let timing = scenario.forward_row_timing(rates);
            let m = measure_forward(&mut vision, &img, vehicle_us, frame_seq, timing.as_ref());
            // The live view shows the station's records at the station's clock: the frame at its stamp.
            if let Some(tap) = rec.tap.as_mut() {
                tap.forward_frame(stamp, &img, m.observation.as_ref());
            }
            stats.forward_measured += m.observation.is_some() as u64;
            send(&Uplink::PackedVision(PackedVision::pack(&m)), &mut writer, rec)?;
            stats.uplink_vision += 1;
            latencies_us.push(now_unix_us().saturating_sub(arrived));
        }
        if let (Some(rx), Some(fl)) = (down.as_ref(), flow.as_mut()) {
            while let Ok(r) = rx.try_recv() {
                idle = false;
                let (f, arrived, counters) = r.map_err(anyhow::Error::msg)?;
                stats.down_frames += 1;
                stats.camera_counters[1] = counters;
                down_watch.frame(t);
                let Some(vehicle_us) = clock.vehicle_time_us(f.timestamp_us.unwrap_or(arrived)) else {
                    continue;
                };
                if opts.compact && !(stats.down_frames - 1).is_multiple_of(COMPACT_FLOW_EVERY) {
                    stats.compact_skipped[1] += 1;
                    continue;
                }
                if f.channels != 1 {
                    bail!("the down stream sent a {}-channel frame; grey expected", f.channels);
                }
                ground_station::calib::check_size(fl.camera(), f.width, f.height)
                    .map_err(|e| anyhow::anyhow!("the downward camera: {e}"))?;
                let seq = f.seq.unwrap_or(stats.down_frames) as u32;
                let img = GrayImage { width: f.width, height: f.height, data: f.data };
                // The rotation over the interval from the last telemetry's rates (what came down the radio).
                let dt = prev_down.map_or(0.0, |(t0, _)| vehicle_us.saturating_sub(t0) as f32 * 1e-6);
                let rates = telemetry.map_or(geometry::Vec3::ZERO, |tm| tm.estimate.rates_rad_s);
                let r_bc = scenario.down_camera_mount().body_from_camera;
                let predicted = r_bc.transpose().mul_vec(rates * dt);
                if let Some(enc) = rec.frames {
                    let hint = predicted.to_array();
                    rec.frame(CameraFrame::gray(CameraId::Downward, seq, vehicle_us, &img, hint, enc))?;
                }
                let flow_result = fl.add(&img, predicted);
                if let Some(tap) = rec.tap.as_mut() {
                    let tracks: Vec<_> = fl.last_tracks().collect();
                    tap.down_frame(f.timestamp_us.unwrap_or(arrived), &img, &tracks);
                }
                if let (Some(result), Some((t_prev, _))) = (flow_result, prev_down) {
                    let m =
                        FlowMeasurement { t_prev_us: t_prev, t_next_us: vehicle_us, frame_seq: seq, result };
                    send(&Uplink::PackedFlow(PackedFlow::pack(&m)), &mut writer, rec)?;
                    stats.uplink_flow += 1;
                    stats.flow_sent += 1;
                }
                prev_down = Some((vehicle_us, seq));
            }
        }
        stats.camera_stalls[0] += forward_watch.check(t) as u64;
        stats.camera_stalls[1] += down_watch.check(t) as u64;
        if t - last_progress >= 0.1 {
            last_progress = t;
            let (refused, received) = decoder_counts.lock().map_or((0, 0), |c| (c.0.errors() as u64, c.1));
            let lost = |c: &CaptureCounters| c.dropped + c.flagged + c.undecodable;
            ui.show(&ConsoleView {
                t_s: t,
                link: opts.link.to_string(),
                telemetry: telemetry.map(|tm| (tm, t - telemetry_at)),
                clock_bound_ms: clock.bound_us().map(|b| b * 1e-3),
                bytes_per_s: [sent_bytes.get() as f64 / t.max(1e-3), received as f64 / t.max(1e-3)],
                link_refused: refused,
                forward_frames: [stats.forward_frames, stats.forward_measured],
                flow_sent: stats.flow_sent,
                stalled: [
                    (forward_watch.stalled, stats.camera_stalls[0]),
                    (down_watch.stalled, stats.camera_stalls[1]),
                ],
                camera_lost: [lost(&stats.camera_counters[0]), lost(&stats.camera_counters[1])],
                script: if operator.script_running() { "running".into() } else { "ended".into() },
                acks: stats.command_acks.iter().rev().take(3).rev().cloned().collect(),
                killed: stats.operator_commands.iter().any(|(_, c)| c == "kill"),
            });
        }
        if quit {
            break "the operator quit".to_string();
        }
        if idle {
            std::thread::sleep(Duration::from_millis(1));
        }
    };
    stop.store(true, Ordering::Relaxed);
    let reader_error = link_reader.join().ok().flatten();
    stats.seconds = start.elapsed().as_secs_f64();
    stats.ended = match reader_error {
        Some(e) => format!("{ended} ({e})"),
        None => ended,
    };
    stats.clock_bound_ms = clock.bound_us().map(|b| b * 1e-3);
    let cc = clock.counters();
    stats.time_sync_refused = [cc.acausal, cc.too_slow];
    if let Ok(c) = decoder_counts.lock() {
        stats.link_decoder = c.0;
        stats.link_bytes = [sent_bytes.get(), c.1];
    }
    if let Ok(sec) = security.lock() {
        stats.link_security = sec.describe().to_string();
        stats.auth = sec.counters();
    }
    latencies_us.sort_unstable();
    let q = |p: f64| {
        latencies_us
            .get(((latencies_us.len() as f64 - 1.0) * p).round() as usize)
            .map_or(f64::NAN, |v| *v as f64 * 1e-3)
    };
    stats.frame_to_uplink_ms = [q(0.5), q(0.95)];
    stats.mavlink = mav.map(MavlinkEndpoint::finish);
    Ok(stats)
}
