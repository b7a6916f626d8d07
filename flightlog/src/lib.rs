//! Flight logs: every input the flight stack received and every output it gave, so that a flight can be
//! replayed bit for bit (`sim-host replay`). Specified in `docs/log-format.md`.
//!
//! ```text
//! file   = magic version header_len header header_crc frame* end
//! magic  = "WLQLOG" (6 bytes)
//! version = LOG_FORMAT_VERSION, u16 little endian
//! header_len = u32 little endian; header = that many bytes of UTF-8 JSON (LogHeader)
//! header_crc = CRC-32 (IEEE) of the header's JSON, u32 little endian
//! frame  = protocol::frame layout (COBS, wire version, CRC-16) of one `LogRecord`, up to MAX_LOG_FRAME bytes
//! end    = the frame of `LogRecord::End`: how many frames came before it and the CRC-32 of their bytes
//! ```
//!
//! A log without its end record was cut short (the writer was stopped, or the file truncated, at a record
//! boundary or inside one); one whose count or CRC-32 disagrees was damaged. Both are reported as damage,
//! with the intact records still read.
//!
//! The records are those of the firmware in the loop (`flight_core::fil`) and of the radio link: the radio
//! messages delivered before a step, the step's sensors, the step's report, the downlink messages the vehicle
//! sends after it (`flight_core::telemetry`), plus the camera frames the ground station measured and the
//! simulator's ground truth.
use anyhow::{Context, Result, bail};
use flight_core::StepReport;
use flight_core::fil::SensorStep;
use protocol::frame::{FrameError, WIRE_VERSION, cobs_decode_in_place, cobs_encode, crc16, decode_raw};
use protocol::{Downlink, Uplink};
use serde::{Deserialize, Serialize};
use std::io::{BufRead, Write};
use std::path::{Path, PathBuf};

/// The file's first bytes.
pub const LOG_MAGIC: &[u8; 6] = b"WLQLOG";
/// Version of the log layout (header and record kinds).
pub const LOG_FORMAT_VERSION: u16 = 10;
/// The record schema of format 5, whose records are those of format 6 without [`LogRecord::Station`] and
/// without the parameter id `downlink.telemetry_every_steps` (same variant indices and fields otherwise):
/// such logs are read as they are.
pub const SCHEMA_HASH_FORMAT_5: &str = "af873cc779970bb0";
/// The record schema of format 6, whose records are those of format 7 without the packed messages
/// (`Uplink::PackedVision`, `Uplink::PackedFlow`, `Downlink::PackedTelemetry`, appended variants): such
/// logs are read as they are.
pub const SCHEMA_HASH_FORMAT_6: &str = "2ddad16395ce5b28";
/// The record schema of format 7, whose records are those of format 8 without the radio's link status and
/// the arming refusal of an unauthenticated link (`Downlink::LinkStatus`, `Refusal::Unauthenticated`,
/// appended variants): such logs are read as they are.
pub const SCHEMA_HASH_FORMAT_7: &str = "6da2960026f0b4d8";
/// The record schema of format 8, whose records are those of format 9 without the flow's refusal of a
/// repeating floor (`NoFlowReason::RepeatingTexture`, an appended variant): such logs are read as they are.
pub const SCHEMA_HASH_FORMAT_8: &str = "586ae63c49f24cfc";
/// The record schema of format 9, whose records are those of format 10 without the configuration upload's
/// messages (`Uplink::Config`, `Downlink::ConfigAck`), the pilot's transmitter (`LogRecord::Pilot`, the mode
/// `FlightMode::Manual`, the failsafes `RcLost` and `Killed`, the refusals `KillSwitch`, `ArmSwitchOff` and
/// `NoRc`) and the battery (`LogRecord::Battery`, `Downlink::Battery`, `Failsafe::BatteryCritical`,
/// `Refusal::BatteryLow`), all appended variants: such logs are read as they are.
pub const SCHEMA_HASH_FORMAT_9: &str = "e1de2b7ec4b68d9c";

/// The record schema a log of format `version` was written in, for the versions this reader reads.
pub fn schema_hash_of_format(version: u16) -> Option<String> {
    match version {
        5 => Some(SCHEMA_HASH_FORMAT_5.to_string()),
        6 => Some(SCHEMA_HASH_FORMAT_6.to_string()),
        7 => Some(SCHEMA_HASH_FORMAT_7.to_string()),
        8 => Some(SCHEMA_HASH_FORMAT_8.to_string()),
        9 => Some(SCHEMA_HASH_FORMAT_9.to_string()),
        LOG_FORMAT_VERSION => Some(schema_hash()),
        _ => None,
    }
}
/// The longest record frame a reader accepts (a raw 4K RGB frame fits): longer ones are damage.
pub const MAX_LOG_FRAME: usize = 64 << 20;
/// File name `sim-host fly` writes in its output directory.
pub const LOG_FILE: &str = "flight.log";

/// One record.
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, postcard_schema::Schema)]
pub enum LogRecord {
    /// A radio message delivered to the flight stack before the next step.
    Link(Uplink),
    /// One control period's sensors: the stack steps on them with the `Link` records since the last step.
    Step(SensorStep),
    /// What that step returned.
    Report(StepReport),
    /// Ground truth of the simulation at a time (world frame).
    Truth {
        /// Time (us).
        time_us: u64,
        /// Position (m).
        position_m: [f32; 3],
        /// Velocity (m/s).
        velocity_m_s: [f32; 3],
        /// Roll, pitch, yaw (rad).
        attitude_rad: [f32; 3],
    },
    /// A camera frame the ground station measured (the input of the `Link` record that carries its result).
    Frame(CameraFrame),
    /// A message the vehicle sent down the radio link after the step before it: telemetry, command
    /// acknowledgement, parameter reply (the firmware's own records, `flight_core::telemetry`).
    Downlink(Downlink),
    /// A recorded reference of the vehicle's state from another source than this flight code (an imported
    /// dataset's ground truth, another estimator's output), what `replay --summary` compares against.
    Reference(ReferenceState),
    /// The last record: the writer finished. How many record frames came before it and the CRC-32 (IEEE) of
    /// their bytes (every byte from the end of the header to this frame's first).
    End {
        /// Record frames before this one.
        records: u64,
        /// CRC-32 of their bytes.
        crc32: u32,
    },
    /// What a ground station sent and received over the radio, on its own clock (`sim-host station`; format
    /// 6).
    Station(StationEvent),
    /// The pilot's transmitter as the flight stack got it for the next step, when the vehicle has an RC
    /// receiver and has heard it (format 10).
    Pilot(control_core::pilot::PilotInput),
    /// A reading of the flight battery for the next step (format 10).
    Battery(control_core::battery::BatteryReading),
}

/// A ground station's record of the radio: each message with the station's time (us since the Unix epoch),
/// and the clock sync's mapping to the vehicle's clock, so that both clocks' times of everything are known.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, postcard_schema::Schema)]
pub enum StationEvent {
    /// A message sent up the radio, when it left. Measurements carry their capture time on the vehicle's
    /// clock (as mapped by the clock sync).
    Sent {
        /// Station time (us).
        station_time_us: u64,
        /// The message.
        message: Uplink,
    },
    /// A message from the vehicle, when its last byte arrived.
    Received {
        /// Station time (us).
        station_time_us: u64,
        /// The message.
        message: Downlink,
    },
    /// The clock sync after a time-sync answer it accepted: the vehicle's clock read `vehicle_time_us` at
    /// `station_time_us`, within `bound_us`.
    Clock {
        /// Station time (us).
        station_time_us: u64,
        /// The vehicle's time then (us).
        vehicle_time_us: u64,
        /// The error bound (us).
        bound_us: u32,
    },
}

impl StationEvent {
    /// The station's time of the event (us since the Unix epoch).
    pub fn station_time_us(&self) -> u64 {
        match self {
            StationEvent::Sent { station_time_us, .. }
            | StationEvent::Received { station_time_us, .. }
            | StationEvent::Clock { station_time_us, .. } => *station_time_us,
        }
    }
}

/// A reference state at a time, in this project's frames (world `W`, body FLU).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, postcard_schema::Schema)]
pub struct ReferenceState {
    /// Time on the log's clock (us).
    pub time_us: u64,
    /// Attitude, world from body, unit quaternion `[w, x, y, z]`.
    pub q_world_body: [f32; 4],
    /// Position in the world frame (m), when the reference has one.
    pub position_m: Option<[f32; 3]>,
    /// Whether the recorded vehicle was flying, when the source says (a land detector).
    pub airborne: Option<bool>,
}

impl LogRecord {
    /// The record's kind, as named in docs/log-format.md.
    pub fn kind(&self) -> &'static str {
        match self {
            LogRecord::Link(_) => "link",
            LogRecord::Step(_) => "step",
            LogRecord::Report(_) => "report",
            LogRecord::Truth { .. } => "truth",
            LogRecord::Frame(_) => "frame",
            LogRecord::Downlink(_) => "downlink",
            LogRecord::Reference(_) => "reference",
            LogRecord::End { .. } => "end",
            LogRecord::Station(_) => "station",
            LogRecord::Pilot(_) => "pilot",
            LogRecord::Battery(_) => "battery",
        }
    }
}

/// The postcard variant index of [`LogRecord::Frame`].
pub const FRAME_RECORD_INDEX: u8 = 4;

/// Which camera took a frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, postcard_schema::Schema)]
pub enum CameraId {
    /// The forward camera (the line on the wall; RGB).
    Forward,
    /// The downward camera (optical flow; grey).
    Downward,
}

/// How a frame's pixels are stored.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, postcard_schema::Schema)]
pub enum FrameEncoding {
    /// Packed 8-bit pixels, row-major (RGB: R, G, B).
    Raw,
    /// A PNG file (lossless).
    Png,
}

/// Whether and how `sim-host fly` keeps the camera frames in the log.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FramePolicy {
    /// Only the vision results (the `Link` records): small logs, replay from vision results only.
    Drop,
    /// PNG (lossless, about a third of raw for the rendered frames).
    Png,
    /// Raw pixels (fastest to write and read, largest).
    Raw,
}

/// One camera frame.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, postcard_schema::Schema)]
pub struct CameraFrame {
    /// Which camera.
    pub camera: CameraId,
    /// The camera's frame counter (the `frame_seq` of the measurement made from it).
    pub seq: u32,
    /// Capture time (mid-exposure, us).
    pub capture_time_us: u64,
    /// Width (px).
    pub width: u16,
    /// Height (px).
    pub height: u16,
    /// Channels: 3 (RGB) or 1 (grey).
    pub channels: u8,
    /// How `data` stores the pixels.
    pub encoding: FrameEncoding,
    /// Downward camera: the camera rotation over the frame interval the ground station predicted and seeded
    /// the flow with (camera frame, rad); zero for the forward camera. Part of the measurement's input, so that
    /// a replay from frames recomputes it exactly.
    pub rotation_hint_cam: [f32; 3],
    /// The pixels (postcard: a varint length, then the bytes).
    #[serde(with = "serde_bytes")]
    pub data: Vec<u8>,
}

impl CameraFrame {
    /// Checks that an image decoded from the frame has the declared size: `w` x `h` with `pixels` pixels.
    pub fn check_size(&self, w: usize, h: usize, pixels: usize) -> Result<()> {
        if w != self.width as usize || h != self.height as usize || pixels != w * h {
            bail!(
                "frame {} of the {:?} camera: {}x{} declared, {w}x{h} with {pixels} pixels stored",
                self.seq,
                self.camera,
                self.width,
                self.height
            );
        }
        Ok(())
    }
}

/// The header: what flew and how.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LogHeader {
    /// [`LOG_FORMAT_VERSION`] (repeated for readers of the JSON alone).
    pub format_version: u16,
    /// [`schema_hash`] of the writer: a reader with another hash cannot decode the records.
    pub schema_hash: String,
    /// The protocol's wire version of the frames.
    pub wire_version: u8,
    /// Who wrote it (`sim-host 0.1.0`).
    pub writer: String,
    /// The scenario, as TOML (its parameters are the flight stack's).
    pub scenario_toml: String,
    /// The seed of every noise stream.
    pub seed: u64,
    /// The forward camera's simulation (`rendered` or `analytic`).
    pub camera: String,
    /// The flight computer (`sil` or the firmware ELF in QEMU).
    pub flight_computer: String,
    /// What the `Reference` records are (empty when there are none), e.g. `EuRoC ground truth
    /// (state_groundtruth_estimate0)` or `PX4 EKF2 vehicle_attitude`.
    #[serde(default)]
    pub reference: String,
    /// Whether the reference's yaw is absolute (comparable without removing the initial offset): true when
    /// both it and the flight code see an absolute heading (a magnetometer).
    #[serde(default)]
    pub reference_yaw_absolute: bool,
    /// How the radio link's frames were secured (docs/security.md): `hmac-sha256-48` (every frame logged from
    /// the link was authenticated; the refused ones are only counted), `none (development...)` (none was), or
    /// `in-process (no radio)` for a simulation that runs its station itself. Empty in logs before format 8
    /// and in imports.
    #[serde(default)]
    pub link_security: String,
}

/// A fingerprint of the record layout: postcard-schema's 64-bit key (FNV-1a over the path and the types'
/// schema: every type's name, its fields' names and types, its variants) of [`LogRecord`]. Adding, removing,
/// reordering, renaming or retyping a field of any record changes it; values never enter it.
pub fn schema_hash() -> String {
    const KEY: postcard_schema::key::Key = postcard_schema::key::Key::for_path::<LogRecord>("wlq/flight-log");
    KEY.to_bytes().iter().map(|b| format!("{b:02x}")).collect()
}

/// The frame of one record: postcard payload, wire version and CRC-16, COBS-encoded, delimiter (the layout of
/// `protocol::frame`, without its 512-byte limit; small records give the same bytes as `protocol::frame::encode`).
pub fn record_frame(r: &LogRecord) -> Result<Vec<u8>> {
    let mut body = Vec::with_capacity(64);
    body.push(WIRE_VERSION);
    let mut body = postcard::to_extend(r, body)?;
    let crc = crc16(&body);
    body.extend_from_slice(&crc.to_le_bytes());
    let mut out = vec![0u8; body.len() + body.len() / 254 + 2];
    let n = cobs_encode(&body, &mut out)
        .map_err(|e| anyhow::anyhow!("cannot frame a {} record: {e:?}", r.kind()))?;
    out.truncate(n);
    out.push(0);
    if out.len() > MAX_LOG_FRAME {
        bail!("a {} record of {} bytes exceeds the {MAX_LOG_FRAME}-byte record limit", r.kind(), out.len());
    }
    Ok(out)
}

/// The bytes before the first record: magic, format version, header length, header JSON, its CRC-32.
pub fn header_bytes(header: &LogHeader) -> Result<Vec<u8>> {
    let json = serde_json::to_vec(header)?;
    let mut out = Vec::with_capacity(16 + json.len());
    out.extend_from_slice(LOG_MAGIC);
    out.extend_from_slice(&LOG_FORMAT_VERSION.to_le_bytes());
    out.extend_from_slice(&(json.len() as u32).to_le_bytes());
    out.extend_from_slice(&json);
    out.extend_from_slice(&crc32fast::hash(&json).to_le_bytes());
    Ok(out)
}

/// The end record of a log whose record frames (after the header) are `frames`, concatenated.
pub fn end_record(frames: &[u8]) -> LogRecord {
    let records = frames.iter().filter(|&&b| b == 0).count() as u64;
    LogRecord::End { records, crc32: crc32fast::hash(frames) }
}

/// Writes a log.
pub struct LogWriter {
    out: crate::files::AtomicFile,
    /// Records written.
    pub records: u64,
    /// Bytes written.
    pub bytes: u64,
    crc: crc32fast::Hasher,
}

impl LogWriter {
    /// Creates `path` (under a temporary name until [`LogWriter::finish`]) and writes the header.
    pub fn create(path: &Path, header: &LogHeader) -> Result<Self> {
        Self::create_on(crate::files::AtomicFile::create(path)?, header)
    }

    /// Writes the header to `out`, then the records (a log on a given file, e.g. one with little space).
    /// The header's format version and schema hash are the writer's own (a replay of an older log writes
    /// this version).
    pub fn create_on(mut out: crate::files::AtomicFile, header: &LogHeader) -> Result<Self> {
        let header =
            LogHeader { format_version: LOG_FORMAT_VERSION, schema_hash: schema_hash(), ..header.clone() };
        let head = header_bytes(&header)?;
        out.write_all(&head)?;
        Ok(Self { out, records: 0, bytes: head.len() as u64, crc: crc32fast::Hasher::new() })
    }

    /// Appends one record (an `End` record is the writer's own: [`LogWriter::finish`] writes it).
    pub fn write(&mut self, r: &LogRecord) -> Result<()> {
        if matches!(r, LogRecord::End { .. }) {
            bail!("the end-of-log record is written by the writer's finish, not by its caller");
        }
        let frame = record_frame(r)?;
        self.out.write_all(&frame)?;
        self.crc.update(&frame);
        self.records += 1;
        self.bytes += frame.len() as u64;
        Ok(())
    }

    /// Gives up after a failed write (a full disk): what reached the disk is kept as `NAME.partial`, a log
    /// that reads as truncated after its last whole record. Returns that name.
    pub fn keep_partial(self) -> Result<PathBuf> {
        self.out.keep_partial()
    }

    /// Gives up after `error` (a failed write): what reached the disk is kept as `NAME.partial`, and the error
    /// returned says so, with the records written.
    pub fn give_up(self, error: anyhow::Error) -> anyhow::Error {
        let records = self.records;
        self.out.give_up(error.context(format!("{records} records had been written")))
    }

    /// Writes the end record, flushes to disk and moves the file into place under its name (a failure to
    /// write the end record keeps what was written, as [`LogWriter::give_up`]).
    pub fn finish(mut self) -> Result<()> {
        let end = LogRecord::End { records: self.records, crc32: self.crc.clone().finalize() };
        let frame = record_frame(&end)?;
        if let Err(e) = self.out.write_all(&frame) {
            return Err(self.give_up(e.into()));
        }
        self.bytes += frame.len() as u64;
        self.out.commit()
    }
}

pub mod files;
mod reader;
pub use reader::*;

#[cfg(test)]
mod tests;
