//! Frame sources behind one trait: a camera's frame stream over TCP ([`crate::stream::StreamReader`]) and a
//! recorded folder in the ASL/EuRoC layout ([`FolderSource`]). Each frame carries its capture time on the
//! station's clock (us since the Unix epoch), which the clock sync maps to the vehicle's.
//!
//! A source spec: `tcp:HOST:PORT`, `folder:PATH` (`PATH/data.csv` and `PATH/data/`), with
//! `folder:PATH@fast` to read a folder as fast as possible instead of at its recorded pace, or a V4L2
//! device `/dev/videoN` ([`crate::v4l2`], built with the `v4l2` feature).
use crate::stream::{Frame, StreamError, StreamReader, decode_png};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

/// A camera, live or recorded.
pub trait FrameSource: Send {
    /// The next frame (its `timestamp_us` the capture time on the station's clock), `Ok(None)` when the
    /// source ended.
    fn next_frame(&mut self) -> Result<Option<Frame>, StreamError>;

    /// What the source delivered and lost so far (a live camera's dropped and undecodable frames).
    fn counters(&self) -> crate::v4l2::CaptureCounters {
        crate::v4l2::CaptureCounters::default()
    }
}

/// What the station needs of a camera: the calibration's image size, the channels its vision reads (3 for
/// the forward camera, 1 for the downward one) and the camera's rate. A live camera is set to it; a recorded
/// or streamed one is checked against it frame by frame by the station.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SourceWant {
    /// Width (px).
    pub width: usize,
    /// Height (px).
    pub height: usize,
    /// Channels (1 grey, 3 RGB).
    pub channels: usize,
    /// Frames per second.
    pub rate_hz: f64,
}

impl<R: std::io::Read + Send> FrameSource for StreamReader<R> {
    fn next_frame(&mut self) -> Result<Option<Frame>, StreamError> {
        StreamReader::next_frame(self)
    }
}

/// The station's clock (us since the Unix epoch).
pub fn now_unix_us() -> u64 {
    SystemTime::now().duration_since(UNIX_EPOCH).map_or(0, |d| d.as_micros() as u64)
}

/// How long a camera stream's server may take to answer the request.
pub const STREAM_ANSWER_WITHIN: std::time::Duration = std::time::Duration::from_secs(5);

/// Opens a source from its spec (`tcp:HOST:PORT`, `folder:PATH`, `folder:PATH@fast`, `/dev/videoN`).
pub fn open(spec: &str, want: SourceWant) -> Result<Box<dyn FrameSource>, String> {
    if spec.starts_with("tcp:") {
        let addr = crate::link::tcp_address(spec)?;
        let r = StreamReader::connect(addr, STREAM_ANSWER_WITHIN)
            .map_err(|e| format!("the camera stream at {addr}: {e}"))?;
        Ok(Box::new(r))
    } else if let Some(rest) = spec.strip_prefix("folder:") {
        let (path, pace) = match rest.strip_suffix("@fast") {
            Some(p) => (p, Pacing::AsFastAsPossible),
            None => (rest, Pacing::RealTime),
        };
        Ok(Box::new(FolderSource::open(Path::new(path), pace)?))
    } else if spec.starts_with("/dev/") {
        open_v4l2(spec, want)
    } else {
        Err(format!("`{spec}`: tcp:HOST:PORT, folder:PATH or a V4L2 device /dev/videoN expected"))
    }
}

#[cfg(feature = "v4l2")]
fn open_v4l2(spec: &str, want: SourceWant) -> Result<Box<dyn FrameSource>, String> {
    Ok(Box::new(crate::v4l2::V4l2Source::open(spec, want)?))
}

#[cfg(not(feature = "v4l2"))]
fn open_v4l2(spec: &str, _want: SourceWant) -> Result<Box<dyn FrameSource>, String> {
    Err(format!(
        "`{spec}`: this build has no V4L2 capture; build with `--features v4l2` (needs libclang, e.g. the \
         Debian package libclang-dev)"
    ))
}

/// How a recording is played.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Pacing {
    /// Each frame when its recorded time comes, from the first frame's at the start.
    RealTime,
    /// Each frame at once.
    AsFastAsPossible,
}

/// A recorded camera in the ASL/EuRoC layout: `data.csv` (`#timestamp [ns],filename` and one row per frame,
/// in time order) and the images (8-bit PNG, grey or colour) in `data/`. Frames are stamped with the station's
/// clock at the start plus their recorded time since the first frame.
pub struct FolderSource {
    dir: PathBuf,
    rows: Vec<(u64, String)>,
    next: usize,
    pacing: Pacing,
    started: Option<(Instant, u64)>,
}

impl FolderSource {
    /// Reads the folder's index; a malformed row is refused with its file and line.
    pub fn open(dir: &Path, pacing: Pacing) -> Result<Self, String> {
        let csv = dir.join("data.csv");
        let text = std::fs::read_to_string(&csv).map_err(|e| format!("{}: {e}", csv.display()))?;
        let mut rows: Vec<(u64, String)> = Vec::new();
        for (i, line) in text.lines().enumerate() {
            let line = line.trim();
            if line.is_empty() || line.starts_with('#') {
                continue;
            }
            let at = || format!("{}:{}", csv.display(), i + 1);
            let (t, name) =
                line.split_once(',').ok_or_else(|| format!("{}: `timestamp,filename` expected", at()))?;
            let t: u64 = t
                .trim()
                .parse()
                .map_err(|_| format!("{}: the timestamp `{}` is not a number", at(), t.trim()))?;
            if rows.last().is_some_and(|(p, _)| t <= *p) {
                return Err(format!("{}: timestamp {t} is not after the previous row's", at()));
            }
            rows.push((t, name.trim().to_string()));
        }
        if rows.is_empty() {
            return Err(format!("{}: no frames", csv.display()));
        }
        Ok(Self { dir: dir.to_path_buf(), rows, next: 0, pacing, started: None })
    }

    /// Frames in the recording.
    pub fn len(&self) -> usize {
        self.rows.len()
    }

    /// Whether the recording has no frames (never: [`FolderSource::open`] refuses that).
    pub fn is_empty(&self) -> bool {
        self.rows.is_empty()
    }
}

impl FrameSource for FolderSource {
    fn next_frame(&mut self) -> Result<Option<Frame>, StreamError> {
        let Some((t_ns, name)) = self.rows.get(self.next).cloned() else { return Ok(None) };
        let t0_ns = self.rows[0].0;
        let (start, start_us) = *self.started.get_or_insert_with(|| (Instant::now(), now_unix_us()));
        let since_us = (t_ns - t0_ns) / 1000;
        if self.pacing == Pacing::RealTime {
            let due = start + Duration::from_micros(since_us);
            let now = Instant::now();
            if due > now {
                std::thread::sleep(due - now);
            }
        }
        let path = self.dir.join("data").join(&name);
        let bytes = std::fs::read(&path).map_err(|e| {
            StreamError::Io(std::io::Error::new(e.kind(), format!("{}: {e}", path.display())))
        })?;
        let (width, height, channels, data) =
            decode_png(&bytes).map_err(|e| StreamError::Decode(format!("{}: {e}", path.display())))?;
        self.next += 1;
        Ok(Some(Frame {
            seq: Some(self.next as u64 - 1),
            timestamp_us: Some(start_us + since_us),
            width,
            height,
            channels,
            data,
        }))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const WANT: SourceWant = SourceWant { width: 4, height: 2, channels: 1, rate_hz: 20.0 };

    fn png(w: usize, h: usize, channels: usize, fill: u8) -> Vec<u8> {
        let mut out = Vec::new();
        let mut enc = png::Encoder::new(&mut out, w as u32, h as u32);
        enc.set_color(if channels == 1 { png::ColorType::Grayscale } else { png::ColorType::Rgb });
        enc.set_depth(png::BitDepth::Eight);
        let mut wr = enc.write_header().unwrap();
        wr.write_image_data(&vec![fill; w * h * channels]).unwrap();
        wr.finish().unwrap();
        out
    }

    fn folder(name: &str, csv: &str, images: &[(&str, Vec<u8>)]) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("gs-folder-{name}-{}", std::process::id()));
        std::fs::remove_dir_all(&dir).ok();
        std::fs::create_dir_all(dir.join("data")).unwrap();
        std::fs::write(dir.join("data.csv"), csv).unwrap();
        for (n, b) in images {
            std::fs::write(dir.join("data").join(n), b).unwrap();
        }
        dir
    }

    #[test]
    fn a_recorded_folder_gives_its_frames_in_order_with_their_spacing() {
        let t0 = 1_403_636_579_763_555_584u64;
        let csv = format!(
            "#timestamp [ns],filename\n{t0},a.png\n{},b.png\n{},c.png\n",
            t0 + 50_000_000,
            t0 + 100_000_000
        );
        let dir = folder(
            "ok",
            &csv,
            &[("a.png", png(4, 3, 1, 10)), ("b.png", png(4, 3, 1, 20)), ("c.png", png(4, 3, 3, 30))],
        );
        let mut src = open(&format!("folder:{}@fast", dir.display()), WANT).unwrap();
        let before = now_unix_us();
        let a = src.next_frame().unwrap().unwrap();
        let b = src.next_frame().unwrap().unwrap();
        let c = src.next_frame().unwrap().unwrap();
        assert!(src.next_frame().unwrap().is_none());
        assert_eq!((a.width, a.height, a.channels, a.data[0], a.seq), (4, 3, 1, 10, Some(0)));
        assert_eq!((b.data[0], c.channels, c.data.len(), c.seq), (20, 3, 36, Some(2)));
        let (ta, tb, tc) = (a.timestamp_us.unwrap(), b.timestamp_us.unwrap(), c.timestamp_us.unwrap());
        // On the station's clock from the start, the recording's spacing kept.
        assert!(ta >= before && ta < before + 1_000_000, "{ta} {before}");
        assert_eq!((tb - ta, tc - ta), (50_000, 100_000));
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn real_time_pacing_waits_for_each_frame() {
        let csv = "0,a.png\n30000000,b.png\n";
        let dir = folder("paced", csv, &[("a.png", png(2, 2, 1, 0)), ("b.png", png(2, 2, 1, 0))]);
        let mut src = FolderSource::open(&dir, Pacing::RealTime).unwrap();
        let t = Instant::now();
        src.next_frame().unwrap().unwrap();
        src.next_frame().unwrap().unwrap();
        assert!(t.elapsed() >= Duration::from_millis(30), "{:?}", t.elapsed());
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn bad_folders_are_refused_naming_the_file_and_the_line() {
        let cases: &[(&str, &str)] = &[
            ("#timestamp,filename\n", "no frames"),
            ("10,a.png\nxx,b.png\n", "data.csv:2: the timestamp `xx`"),
            ("10,a.png\n10,b.png\n", "data.csv:2: timestamp 10 is not after"),
            ("10 a.png\n", "data.csv:1: `timestamp,filename` expected"),
        ];
        for (i, (csv, want)) in cases.iter().enumerate() {
            let dir = folder(&format!("bad{i}"), csv, &[]);
            let e = FolderSource::open(&dir, Pacing::AsFastAsPossible).err().unwrap();
            assert!(e.contains(want), "{csv:?}: `{e}` does not say `{want}`");
            std::fs::remove_dir_all(&dir).ok();
        }
        // A missing or broken image: an error naming it, not a panic.
        let dir = folder("missing", "10,a.png\n20,b.png\n", &[("b.png", b"not a png".to_vec())]);
        let mut src = FolderSource::open(&dir, Pacing::AsFastAsPossible).unwrap();
        let e = src.next_frame().unwrap_err().to_string();
        assert!(e.contains("a.png"), "{e}");
        let e = open(&format!("folder:{}", dir.join("nowhere").display()), WANT).err().unwrap();
        assert!(e.contains("nowhere") && e.contains("data.csv"), "{e}");
        // A device that is not there: named (with V4L2 built in), or the build's lack of V4L2 said.
        let e = open("/dev/video-none", WANT).err().unwrap();
        assert!(
            e.contains("/dev/video-none") && (cfg!(feature = "v4l2") || e.contains("--features v4l2")),
            "{e}"
        );
        assert!(open("udp:1.2.3.4:5", WANT).err().unwrap().contains("/dev/videoN"));
        std::fs::remove_dir_all(&dir).ok();
    }
}
