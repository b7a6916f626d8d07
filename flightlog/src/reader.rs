//! Reading a log: the header's checks, then record by record with damage listed and skipped.
use super::*;

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
        let Some(ours) = schema_hash_of_format(version) else {
            bail!(
                "log format version {version} at byte 6; this reader reads versions 5 to {LOG_FORMAT_VERSION}"
            );
        };
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
        // Older formats' records are a prefix of today's variants: read with the schema they were written in.
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
