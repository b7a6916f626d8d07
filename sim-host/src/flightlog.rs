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
pub const LOG_FORMAT_VERSION: u16 = 5;
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
    /// A forward (RGB) frame.
    pub fn rgb(
        seq: u32,
        capture_time_us: u64,
        img: &crate::imageio::RgbImage,
        enc: FrameEncoding,
    ) -> Result<Self> {
        let data = match enc {
            FrameEncoding::Raw => img.data.clone(),
            FrameEncoding::Png => crate::imageio::png_of_rgb(img)?,
        };
        Ok(Self {
            camera: CameraId::Forward,
            seq,
            capture_time_us,
            width: img.width as u16,
            height: img.height as u16,
            channels: 3,
            encoding: enc,
            rotation_hint_cam: [0.0; 3],
            data,
        })
    }

    /// A grey frame of a camera.
    pub fn gray(
        camera: CameraId,
        seq: u32,
        capture_time_us: u64,
        img: &crate::imageio::GrayImage,
        rotation_hint_cam: [f32; 3],
        enc: FrameEncoding,
    ) -> Result<Self> {
        let data = match enc {
            FrameEncoding::Raw => img.data.clone(),
            FrameEncoding::Png => crate::imageio::png_of_gray(img)?,
        };
        Ok(Self {
            camera,
            seq,
            capture_time_us,
            width: img.width as u16,
            height: img.height as u16,
            channels: 1,
            encoding: enc,
            rotation_hint_cam,
            data,
        })
    }

    /// The pixels as an RGB image (grey frames are expanded).
    pub fn to_rgb(&self) -> Result<crate::imageio::RgbImage> {
        let (w, h) = (self.width as usize, self.height as usize);
        let img = match (self.encoding, self.channels) {
            (FrameEncoding::Png, _) => crate::imageio::rgb_from_png(&self.data)
                .or_else(|_| crate::imageio::gray_from_png(&self.data).map(|g| gray_to_rgb(&g)))?,
            (FrameEncoding::Raw, 3) => {
                crate::imageio::RgbImage { width: w, height: h, data: self.data.clone() }
            }
            (FrameEncoding::Raw, 1) => {
                gray_to_rgb(&crate::imageio::GrayImage { width: w, height: h, data: self.data.clone() })
            }
            (_, c) => bail!("frame {} has {c} channels (1 or 3 expected)", self.seq),
        };
        self.check(img.width, img.height, img.data.len() / 3)?;
        Ok(img)
    }

    /// The pixels as a grey image (colour frames are converted with Rec. 601 luma weights).
    pub fn to_gray(&self) -> Result<crate::imageio::GrayImage> {
        let (w, h) = (self.width as usize, self.height as usize);
        let img = match (self.encoding, self.channels) {
            (FrameEncoding::Png, _) => crate::imageio::gray_from_png(&self.data)?,
            (FrameEncoding::Raw, 1) => {
                crate::imageio::GrayImage { width: w, height: h, data: self.data.clone() }
            }
            (FrameEncoding::Raw, 3) => crate::imageio::GrayImage {
                width: w,
                height: h,
                data: self.data.chunks_exact(3).map(|p| crate::imageio::luma(p[0], p[1], p[2])).collect(),
            },
            (_, c) => bail!("frame {} has {c} channels (1 or 3 expected)", self.seq),
        };
        self.check(img.width, img.height, img.data.len())?;
        Ok(img)
    }

    fn check(&self, w: usize, h: usize, pixels: usize) -> Result<()> {
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

fn gray_to_rgb(g: &crate::imageio::GrayImage) -> crate::imageio::RgbImage {
    crate::imageio::RgbImage {
        width: g.width,
        height: g.height,
        data: g.data.iter().flat_map(|&v| [v, v, v]).collect(),
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
    pub fn create_on(mut out: crate::files::AtomicFile, header: &LogHeader) -> Result<Self> {
        let head = header_bytes(header)?;
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

/// Reads a log record by record, without holding it in memory (logs with frames run to gigabytes).
pub struct LogReader<R: BufRead> {
    input: R,
    /// The header.
    pub header: LogHeader,
    offset: usize,
    frame: Vec<u8>,
    done: bool,
    skip_frames: bool,
    /// Camera frames skipped unread ([`LogReader::skip_frames`]).
    pub frames_skipped: u64,
    /// CRC-32 of every byte after the header read so far, and at the current frame's start.
    crc: crc32fast::Hasher,
    crc_at_frame: crc32fast::Hasher,
    /// Frames (delimited) read before the current one.
    frames_read: u64,
    /// Where the end record was, once read: anything after it is damage.
    end_seen: Option<usize>,
}

/// One item of a log: an intact record with its byte offset, or a damaged stretch.
pub type LogItem = std::result::Result<(usize, LogRecord), LogDamage>;

impl<R: BufRead> LogReader<R> {
    /// Reads and checks the header. A stream that is not a log, of another format version or record schema,
    /// or with an unreadable header is an error naming the byte.
    pub fn new(mut input: R) -> Result<Self> {
        let mut head = [0u8; 12];
        let got = read_full(&mut input, &mut head)?;
        if got < 6 || &head[..6] != LOG_MAGIC {
            bail!("not a flight log: it does not start with \"WLQLOG\" (byte 0)");
        }
        if got < 12 {
            bail!("truncated: the file ends at byte {got}, inside the 12-byte preamble");
        }
        let version = u16::from_le_bytes([head[6], head[7]]);
        if version == 3 {
            bail!(
                "log format version 3 at byte 6: written before logs had a header checksum and an end record; \
                 this reader reads version {LOG_FORMAT_VERSION} (replay it with the sim-host that wrote it, or fly it again)"
            );
        }
        if version == 4 {
            bail!(
                "log format version 4 at byte 6: written before a step's record carried the barometer; this \
                 reader reads version {LOG_FORMAT_VERSION} (replay it with the sim-host that wrote it, or fly it again)"
            );
        }
        if version != LOG_FORMAT_VERSION {
            bail!("log format version {version} at byte 6; this reader reads version {LOG_FORMAT_VERSION}");
        }
        let len = u32::from_le_bytes([head[8], head[9], head[10], head[11]]) as usize;
        if len > 16 << 20 {
            bail!("the header length at byte 8 says {len} bytes: not a plausible header (damaged?)");
        }
        let mut json = vec![0u8; len + 4];
        let got = read_full(&mut input, &mut json)?;
        if got < len + 4 {
            bail!(
                "the header and its checksum (bytes 12..{}) run past the end of the file ({} bytes): truncated",
                16 + len,
                12 + got
            );
        }
        let stored = u32::from_le_bytes([json[len], json[len + 1], json[len + 2], json[len + 3]]);
        json.truncate(len);
        let computed = crc32fast::hash(&json);
        if stored != computed {
            bail!(
                "the header's checksum at byte {} is {stored:08x}, its JSON (bytes 12..{}) gives {computed:08x}: \
                 the header is damaged",
                12 + len,
                12 + len
            );
        }
        let header: LogHeader = serde_json::from_slice(&json)
            .map_err(|e| anyhow::anyhow!("the header at byte 12 is not readable: {e}"))?;
        let ours = schema_hash();
        if header.schema_hash != ours {
            bail!(
                "the log's record schema {} differs from this reader's {ours} (header at byte 12): written by {}",
                header.schema_hash,
                header.writer
            );
        }
        Ok(Self {
            input,
            header,
            offset: 16 + len,
            frame: Vec::new(),
            done: false,
            skip_frames: false,
            frames_skipped: 0,
            crc: crc32fast::Hasher::new(),
            crc_at_frame: crc32fast::Hasher::new(),
            frames_read: 0,
            end_seen: None,
        })
    }

    /// Skips camera frame records without decoding or checking them (counted in `frames_skipped`): for
    /// readers that only need the vision results, a log with frames then reads almost as fast as one without.
    pub fn skip_frames(mut self, skip: bool) -> Self {
        self.skip_frames = skip;
        self
    }

    /// The byte offset of the next record.
    pub fn offset(&self) -> usize {
        self.offset
    }
}

fn read_full<R: std::io::Read>(r: &mut R, buf: &mut [u8]) -> Result<usize> {
    let mut n = 0;
    while n < buf.len() {
        match r.read(&mut buf[n..]) {
            Ok(0) => break,
            Ok(k) => n += k,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e.into()),
        }
    }
    Ok(n)
}

impl<R: BufRead> Iterator for LogReader<R> {
    type Item = LogItem;

    fn next(&mut self) -> Option<LogItem> {
        loop {
            if self.done {
                return None;
            }
            let start = self.offset;
            self.frame.clear();
            self.crc_at_frame = self.crc.clone();
            // Read up to the delimiter, but never more than the largest frame: a stretch without delimiters
            // (damage) is skipped in bounded memory.
            let mut oversized = false;
            let mut delimited = false;
            // A camera frame being skipped unread: its bytes are not copied.
            let mut skipping = false;
            loop {
                let buf = match self.input.fill_buf() {
                    Ok(b) => b,
                    Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
                    Err(e) => {
                        self.done = true;
                        return Some(Err(LogDamage { offset: start, what: format!("read error: {e}") }));
                    }
                };
                if buf.is_empty() {
                    break;
                }
                let (take, found) = match memchr::memchr(0, buf) {
                    Some(i) => (i + 1, true),
                    None => (buf.len(), false),
                };
                if !oversized && !skipping {
                    let body = if found { &buf[..take - 1] } else { buf };
                    if self.frame.len() + body.len() + 1 > MAX_LOG_FRAME {
                        oversized = true;
                        self.frame.clear();
                    } else {
                        self.frame.extend_from_slice(body);
                        skipping = self.skip_frames && is_frame_record(&self.frame);
                    }
                }
                self.crc.update(&buf[..take]);
                self.input.consume(take);
                self.offset += take;
                if found {
                    delimited = true;
                    break;
                }
            }
            if !delimited {
                self.done = true;
                if self.offset == start {
                    if self.end_seen.is_some() {
                        return None;
                    }
                    // Cut short at a record boundary: every frame intact, the end record missing.
                    return Some(Err(LogDamage {
                        offset: start,
                        what: format!(
                            "no end-of-log record: the log ends at byte {start} after {} records (the writer \
                             did not finish, or the file was truncated)",
                            self.frames_read
                        ),
                    }));
                }
                return Some(Err(LogDamage {
                    offset: start,
                    what: format!(
                        "truncated: {} bytes without a frame delimiter at the end",
                        self.offset - start
                    ),
                }));
            }
            if oversized {
                self.frames_read += 1;
                return Some(Err(LogDamage {
                    offset: start,
                    what: format!("oversized frame ({} bytes, at most {MAX_LOG_FRAME})", self.offset - start),
                }));
            }
            if self.frame.is_empty() {
                continue;
            }
            if let Some(end) = self.end_seen {
                return Some(Err(LogDamage {
                    offset: start,
                    what: format!("a record after the end-of-log record at byte {end}"),
                }));
            }
            self.frames_read += 1;
            if skipping {
                self.frames_skipped += 1;
                continue;
            }
            let result = match cobs_decode_in_place(&mut self.frame) {
                None => Err(FrameError::Cobs),
                Some(n) => decode_raw::<LogRecord>(&self.frame[..n]),
            };
            return Some(match result {
                Ok(LogRecord::End { records, crc32 }) => {
                    self.end_seen = Some(start);
                    let before = self.frames_read - 1;
                    let crc = self.crc_at_frame.clone().finalize();
                    if records != before || crc32 != crc {
                        Err(LogDamage {
                            offset: start,
                            what: format!(
                                "the end-of-log record says {records} records with CRC-32 {crc32:08x}; the \
                                 log holds {before} with CRC-32 {crc:08x} (records lost or damaged before it)"
                            ),
                        })
                    } else {
                        Ok((start, LogRecord::End { records, crc32 }))
                    }
                }
                Ok(r) => Ok((start, r)),
                Err(e) => Err(LogDamage { offset: start, what: frame_error_text(e) }),
            });
        }
    }
}

/// Whether the start of a COBS-encoded frame is a camera frame record. COBS keeps the body's leading non-zero
/// bytes in place after the first code byte: a code of 3 or more means byte 1 is the wire version and byte 2
/// the record kind.
fn is_frame_record(cobs: &[u8]) -> bool {
    cobs.len() > 3 && cobs[0] >= 3 && cobs[1] == WIRE_VERSION && cobs[2] == FRAME_RECORD_INDEX
}

/// Reads a log from bytes. A file that is not a log, of another format version or with an unreadable
/// header is an error; damaged records are listed in `damage` and every intact record is still read. Never
/// panics.
pub fn parse_log(bytes: &[u8]) -> Result<FlightLog> {
    collect(LogReader::new(bytes)?)
}

fn collect<R: BufRead>(reader: LogReader<R>) -> Result<FlightLog> {
    let header = reader.header.clone();
    let mut records = Vec::new();
    let mut damage = Vec::new();
    for item in reader {
        match item {
            Ok(r) => records.push(r),
            Err(d) => damage.push(d),
        }
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

/// Opens a log file for reading record by record.
pub fn open_log(path: &Path) -> Result<LogReader<std::io::BufReader<std::fs::File>>> {
    let f = std::fs::File::open(path).with_context(|| format!("cannot read {}", path.display()))?;
    LogReader::new(std::io::BufReader::with_capacity(1 << 20, f))
        .with_context(|| format!("{}", path.display()))
}

/// Reads a whole log file into memory.
pub fn read_log(path: &Path) -> Result<FlightLog> {
    collect(open_log(path)?)
}

#[cfg(test)]
mod tests {
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
        assert!(
            log.damage.iter().any(|d| d.what.contains("after the end-of-log record")),
            "{:?}",
            log.damage
        );
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
        // "WLQLOG", version 5 (u16 LE), JSON length (u32 LE), the JSON, its CRC-32 (u32 LE).
        assert_eq!(&b[..8], b"WLQLOG\x05\x00");
        let len = u32::from_le_bytes([b[8], b[9], b[10], b[11]]) as usize;
        assert_eq!(b.len(), 16 + len);
        let json = &b[12..12 + len];
        assert!(std::str::from_utf8(json).unwrap().starts_with("{\"format_version\":5,\"schema_hash\":\""));
        assert_eq!(b[12 + len..], crc32fast::hash(json).to_le_bytes());
        assert_eq!(crc32fast::hash(b"123456789"), 0xCBF4_3926, "CRC-32 (IEEE) check value");
        // The schema fingerprint of this version's records: any change to a record's fields changes it.
        assert_eq!(schema_hash(), "af873cc779970bb0");
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
}
