//! Flight logs: every input the flight stack received and every output it gave, so that a flight can be
//! replayed bit for bit (`sim-host replay`). Specified in `docs/log-format.md`.
//!
//! ```text
//! file   = magic version header_len header frame*
//! magic  = "WLQLOG" (6 bytes)
//! version = LOG_FORMAT_VERSION, u16 little endian
//! header_len = u32 little endian; header = that many bytes of UTF-8 JSON (LogHeader)
//! frame  = protocol::frame (COBS, wire version, CRC-16) of one `LogRecord`
//! ```
//!
//! The records are those of the firmware in the loop (`flight_core::fil`): the radio messages delivered before
//! a step, the step's sensors, the step's report, plus the simulator's ground truth.
use anyhow::{Context, Result, bail};
use control_core::estimator::ImuSample;
use flight_core::StepReport;
use flight_core::fil::SensorStep;
use geometry::Vec3;
use protocol::Uplink;
use protocol::frame::{FrameError, MAX_FRAME, cobs_decode_in_place, decode_raw, encode};
use serde::{Deserialize, Serialize};
use std::io::Write;
use std::path::Path;

/// The file's first bytes.
pub const LOG_MAGIC: &[u8; 6] = b"WLQLOG";
/// Version of the log layout (header and record kinds).
pub const LOG_FORMAT_VERSION: u16 = 1;
/// File name `sim-host fly` writes in its output directory.
pub const LOG_FILE: &str = "flight.log";

/// One record.
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
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
}

/// A fingerprint of the record encoding: FNV-1a (64 bits) of the postcard bytes of one sample of each
/// record kind, with every field set. Adding, removing, reordering or retyping a field changes those bytes.
pub fn schema_hash() -> String {
    let imu = ImuSample { time_us: 1, gyro_rad_s: [0.5, -0.25, 2.0], accel_m_s2: [1.0, -3.0, 9.5] };
    let step = SensorStep {
        time_us: 3,
        imu: heapless::Vec::from_slice(&[imu]).unwrap_or_default(),
        mag: Some(Vec3::new(0.25, 0.5, -0.75)),
    };
    let samples = [
        LogRecord::Link(Uplink::Heartbeat),
        LogRecord::Link(Uplink::ParamGet(control_core::params::ParamId::TrajectorySpeed)),
        LogRecord::Step(step),
        LogRecord::Truth {
            time_us: 7,
            position_m: [1.0, 2.0, 3.0],
            velocity_m_s: [4.0, 5.0, 6.0],
            attitude_rad: [7.0, 8.0, 9.0],
        },
    ];
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    let mut eat = |bytes: &[u8]| {
        for &b in bytes {
            h ^= b as u64;
            h = h.wrapping_mul(0x0000_0100_0000_01b3);
        }
    };
    for s in &samples {
        eat(&postcard::to_allocvec(s).unwrap_or_default());
    }
    // A report: the first step of a stack with the paper's configuration (deterministic).
    if let Ok(mut stack) = flight_core::FlightStack::new(flight_core::FlightConfig::paper()) {
        let out = stack.step(&flight_core::StepInput { time_us: 2000, imu: &[imu], mag: None, uplink: &[] });
        eat(&postcard::to_allocvec(&LogRecord::Report(out.report())).unwrap_or_default());
    }
    format!("{h:016x}")
}

/// Writes a log.
pub struct LogWriter {
    out: std::io::BufWriter<std::fs::File>,
    buf: Vec<u8>,
    /// Records written.
    pub records: u64,
}

impl LogWriter {
    /// Creates `path` and writes the header.
    pub fn create(path: &Path, header: &LogHeader) -> Result<Self> {
        let f = std::fs::File::create(path).with_context(|| format!("cannot create {}", path.display()))?;
        let mut out = std::io::BufWriter::new(f);
        let json = serde_json::to_vec(header)?;
        out.write_all(LOG_MAGIC)?;
        out.write_all(&LOG_FORMAT_VERSION.to_le_bytes())?;
        out.write_all(&(json.len() as u32).to_le_bytes())?;
        out.write_all(&json)?;
        Ok(Self { out, buf: vec![0; MAX_FRAME], records: 0 })
    }

    /// Appends one record.
    pub fn write(&mut self, r: &LogRecord) -> Result<()> {
        let frame =
            encode(r, &mut self.buf).map_err(|e| anyhow::anyhow!("record too large to frame: {e:?}"))?;
        self.out.write_all(frame)?;
        self.records += 1;
        Ok(())
    }

    /// Flushes to disk.
    pub fn finish(mut self) -> Result<()> {
        self.out.flush()?;
        Ok(())
    }
}

/// What went wrong with a stretch of a log, and where.
#[derive(Clone, Debug, PartialEq)]
pub struct LogDamage {
    /// Byte offset of the damaged frame's first byte.
    pub offset: usize,
    /// What is wrong.
    pub what: String,
}

impl std::fmt::Display for LogDamage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "at byte {}: {}", self.offset, self.what)
    }
}

/// A log read whole: the header, every intact record with its byte offset, and what was damaged.
#[derive(Clone, Debug)]
pub struct FlightLog {
    /// The header.
    pub header: LogHeader,
    /// Intact records and their offsets.
    pub records: Vec<(usize, LogRecord)>,
    /// Damaged frames (each skipped; the reader resynchronises at the next delimiter).
    pub damage: Vec<LogDamage>,
}

/// Reads a log from bytes. A file that is not a log, of another format version or with an unreadable
/// header is an error; damaged records are listed in `damage` and every intact record is still read. Never
/// panics.
pub fn parse_log(bytes: &[u8]) -> Result<FlightLog> {
    if bytes.len() < 12 || &bytes[..6] != LOG_MAGIC {
        bail!("not a flight log: it does not start with \"WLQLOG\" (byte 0)");
    }
    let version = u16::from_le_bytes([bytes[6], bytes[7]]);
    if version != LOG_FORMAT_VERSION {
        bail!("log format version {version} at byte 6; this reader reads version {LOG_FORMAT_VERSION}");
    }
    let len = u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize;
    let Some(json) = bytes.get(12..12 + len) else {
        bail!(
            "the header (bytes 12..{}) runs past the end of the file ({} bytes): truncated",
            12 + len,
            bytes.len()
        );
    };
    let header: LogHeader = serde_json::from_slice(json)
        .map_err(|e| anyhow::anyhow!("the header at byte 12 is not readable: {e}"))?;
    let ours = schema_hash();
    if header.schema_hash != ours {
        bail!(
            "the log's record schema {} differs from this reader's {ours} (header at byte 12): written by {}",
            header.schema_hash,
            header.writer
        );
    }
    let mut records = Vec::new();
    let mut damage = Vec::new();
    let mut start = 12 + len;
    let mut scratch = Vec::with_capacity(MAX_FRAME);
    while start < bytes.len() {
        let Some(rel) = bytes[start..].iter().position(|&b| b == 0) else {
            damage.push(LogDamage {
                offset: start,
                what: format!(
                    "truncated: {} bytes without a frame delimiter at the end",
                    bytes.len() - start
                ),
            });
            break;
        };
        let frame = &bytes[start..start + rel];
        let next = start + rel + 1;
        if frame.is_empty() {
            start = next;
            continue;
        }
        if frame.len() + 1 > MAX_FRAME {
            damage.push(LogDamage {
                offset: start,
                what: format!("oversized frame ({} bytes)", frame.len() + 1),
            });
            start = next;
            continue;
        }
        scratch.clear();
        scratch.extend_from_slice(frame);
        let result = match cobs_decode_in_place(&mut scratch) {
            None => Err(FrameError::Cobs),
            Some(n) => decode_raw::<LogRecord>(&scratch[..n]),
        };
        match result {
            Ok(r) => records.push((start, r)),
            Err(e) => damage.push(LogDamage { offset: start, what: frame_error_text(e) }),
        }
        start = next;
    }
    Ok(FlightLog { header, records, damage })
}

fn frame_error_text(e: FrameError) -> String {
    match e {
        FrameError::Cobs => "invalid COBS encoding (flipped bytes?)".into(),
        FrameError::Oversized => "oversized frame".into(),
        FrameError::Truncated => "frame too short".into(),
        FrameError::BadCrc => "CRC mismatch (flipped bytes?)".into(),
        FrameError::UnknownVersion(v) => format!("unknown wire version {v}"),
        FrameError::Malformed => "unknown record kind or malformed record".into(),
    }
}

/// Reads a log file.
pub fn read_log(path: &Path) -> Result<FlightLog> {
    let bytes = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    parse_log(&bytes).with_context(|| format!("{}", path.display()))
}
