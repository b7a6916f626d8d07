//! Camera frames over TCP as IP cameras serve MJPEG: an HTTP response of type
//! `multipart/x-mixed-replace`, one part per frame (docs/ground-station.md).
//!
//! ```text
//! client:  GET / HTTP/1.0\r\n\r\n
//! server:  HTTP/1.0 200 OK\r\n
//!          Content-Type: multipart/x-mixed-replace; boundary=wlqframe\r\n\r\n
//! per frame:
//!          --wlqframe\r\n
//!          Content-Type: image/png | image/x-raw-gray | image/x-raw-rgb\r\n
//!          Content-Length: N\r\n
//!          X-Width: W\r\n  X-Height: H\r\n          (raw types only)
//!          X-Frame-Seq: S\r\n                       (optional)
//!          X-Timestamp-Us: T\r\n                    (optional: the capture time, us since the Unix epoch)
//!          \r\n
//!          N bytes\r\n
//! ```
//!
//! A browser shows such a stream; `curl` saves it. A camera that stamps its frames (the virtual vehicle
//! stamps them at capture, on the machine's clock) gives `X-Timestamp-Us`; without it the station stamps a
//! frame when it arrives, less the camera's delay.
use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;

/// The multipart boundary.
pub const BOUNDARY: &str = "wlqframe";
/// The largest part accepted (a 4K RGB frame raw is 25 MB).
pub const MAX_PART_BYTES: usize = 64 << 20;

/// A decoded frame.
#[derive(Clone, Debug, PartialEq)]
pub struct Frame {
    /// The sender's frame counter, if it gave one.
    pub seq: Option<u64>,
    /// The capture time the sender stamped (us since the Unix epoch), if any.
    pub timestamp_us: Option<u64>,
    /// Width and height (px).
    pub width: usize,
    /// Height (px).
    pub height: usize,
    /// 1 (grey) or 3 (RGB).
    pub channels: usize,
    /// Row-major pixels, `width * height * channels` bytes.
    pub data: Vec<u8>,
}

/// What went wrong with a stream.
#[derive(Debug)]
pub enum StreamError {
    /// The connection failed or closed.
    Io(std::io::Error),
    /// The bytes do not follow the format (with what was expected and where).
    Format(String),
    /// A part's image did not decode.
    Decode(String),
}

impl std::fmt::Display for StreamError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            StreamError::Io(e) => write!(f, "{e}"),
            StreamError::Format(s) => write!(f, "not a frame stream: {s}"),
            StreamError::Decode(s) => write!(f, "a frame did not decode: {s}"),
        }
    }
}

impl std::error::Error for StreamError {}

impl From<std::io::Error> for StreamError {
    fn from(e: std::io::Error) -> Self {
        StreamError::Io(e)
    }
}

/// How a frame is put in a part.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PartEncoding {
    /// Lossless PNG (the default: what a vision test needs).
    Png,
    /// The pixels as they are (`image/x-raw-gray` / `image/x-raw-rgb`): no encoding cost.
    Raw,
}

/// The server's side: the HTTP response head, then one part per frame.
pub struct StreamWriter<W: Write> {
    out: W,
    encoding: PartEncoding,
}

impl<W: Write> StreamWriter<W> {
    /// Writes the response head.
    pub fn start(mut out: W, encoding: PartEncoding) -> std::io::Result<Self> {
        write!(
            out,
            "HTTP/1.0 200 OK\r\nContent-Type: multipart/x-mixed-replace; boundary={BOUNDARY}\r\nCache-Control: no-cache\r\n\r\n"
        )?;
        out.flush()?;
        Ok(Self { out, encoding })
    }

    /// Writes one frame.
    pub fn write(&mut self, f: &Frame) -> std::io::Result<()> {
        let (kind, body) = match self.encoding {
            PartEncoding::Png => ("image/png", encode_png(f)?),
            PartEncoding::Raw => {
                (if f.channels == 1 { "image/x-raw-gray" } else { "image/x-raw-rgb" }, f.data.clone())
            }
        };
        let mut head = format!("--{BOUNDARY}\r\nContent-Type: {kind}\r\nContent-Length: {}\r\n", body.len());
        if self.encoding == PartEncoding::Raw {
            head += &format!("X-Width: {}\r\nX-Height: {}\r\n", f.width, f.height);
        }
        if let Some(s) = f.seq {
            head += &format!("X-Frame-Seq: {s}\r\n");
        }
        if let Some(t) = f.timestamp_us {
            head += &format!("X-Timestamp-Us: {t}\r\n");
        }
        head += "\r\n";
        self.out.write_all(head.as_bytes())?;
        self.out.write_all(&body)?;
        self.out.write_all(b"\r\n")?;
        self.out.flush()
    }
}

fn encode_png(f: &Frame) -> std::io::Result<Vec<u8>> {
    let mut out = Vec::new();
    let mut enc = png::Encoder::new(&mut out, f.width as u32, f.height as u32);
    enc.set_color(if f.channels == 1 { png::ColorType::Grayscale } else { png::ColorType::Rgb });
    enc.set_depth(png::BitDepth::Eight);
    enc.set_compression(png::Compression::Fast);
    let mut w = enc.write_header().map_err(std::io::Error::other)?;
    w.write_image_data(&f.data).map_err(std::io::Error::other)?;
    w.finish().map_err(std::io::Error::other)?;
    Ok(out)
}

/// Decodes a PNG (8-bit grey or RGB; RGBA and grey-alpha lose their alpha).
pub fn decode_png(bytes: &[u8]) -> Result<(usize, usize, usize, Vec<u8>), String> {
    let dec = png::Decoder::new(std::io::Cursor::new(bytes));
    let mut reader = dec.read_info().map_err(|e| e.to_string())?;
    let size = reader.output_buffer_size().ok_or("the image is too large")?;
    let mut buf = vec![0; size];
    let info = reader.next_frame(&mut buf).map_err(|e| e.to_string())?;
    if info.bit_depth != png::BitDepth::Eight {
        return Err(format!("{:?}-bit samples; 8-bit expected", info.bit_depth));
    }
    let (w, h) = (info.width as usize, info.height as usize);
    buf.truncate(info.buffer_size());
    let (channels, data) = match info.color_type {
        png::ColorType::Grayscale => (1, buf),
        png::ColorType::Rgb => (3, buf),
        png::ColorType::GrayscaleAlpha => (1, buf.chunks_exact(2).map(|p| p[0]).collect()),
        png::ColorType::Rgba => (3, buf.chunks_exact(4).flat_map(|p| [p[0], p[1], p[2]]).collect()),
        png::ColorType::Indexed => return Err("an indexed-colour PNG".into()),
    };
    Ok((w, h, channels, data))
}

/// The client's side: reads the frames of a stream.
pub struct StreamReader<R: Read> {
    input: BufReader<R>,
    /// Bytes read so far (for error positions).
    offset: u64,
}

impl StreamReader<TcpStream> {
    /// Connects to a server at `addr` (`host:port`) and asks for its stream; a server that does not answer
    /// within `answer_within` is an error saying so (after the response head, reads wait as long as the
    /// stream takes: the station watches for stalls itself).
    pub fn connect(addr: &str, answer_within: std::time::Duration) -> Result<Self, StreamError> {
        let mut s = TcpStream::connect(addr)?;
        s.set_nodelay(true)?;
        s.set_read_timeout(Some(answer_within))?;
        s.write_all(b"GET / HTTP/1.0\r\n\r\n")?;
        let r = Self::start(s).map_err(|e| match e {
            StreamError::Io(io)
                if matches!(io.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut) =>
            {
                StreamError::Format(format!("no answer within {} s", answer_within.as_secs_f64()))
            }
            other => other,
        })?;
        r.input.get_ref().set_read_timeout(None)?;
        Ok(r)
    }
}

impl<R: Read> StreamReader<R> {
    /// Reads the response head from `input`.
    pub fn start(input: R) -> Result<Self, StreamError> {
        let mut r = Self { input: BufReader::with_capacity(1 << 20, input), offset: 0 };
        let status = r.line()?;
        if !(status.starts_with("HTTP/1.") && status.split_whitespace().nth(1) == Some("200")) {
            return Err(StreamError::Format(format!("the response starts `{status}`, not `HTTP/1.x 200`")));
        }
        let mut multipart = false;
        loop {
            let l = r.line()?;
            if l.is_empty() {
                break;
            }
            if let Some((k, v)) = l.split_once(':')
                && k.trim().eq_ignore_ascii_case("content-type")
            {
                let v = v.trim();
                if !v.starts_with("multipart/x-mixed-replace") || !v.contains(&format!("boundary={BOUNDARY}"))
                {
                    return Err(StreamError::Format(format!(
                        "content type `{v}`: multipart/x-mixed-replace; boundary={BOUNDARY} expected"
                    )));
                }
                multipart = true;
            }
        }
        if !multipart {
            return Err(StreamError::Format("no Content-Type header in the response".into()));
        }
        Ok(r)
    }

    fn line(&mut self) -> Result<String, StreamError> {
        let mut l = String::new();
        let n = self.input.read_line(&mut l)?;
        if n == 0 {
            return Err(StreamError::Io(std::io::Error::new(
                std::io::ErrorKind::UnexpectedEof,
                "the stream ended",
            )));
        }
        if l.len() > 4096 {
            return Err(StreamError::Format(format!(
                "a header line of {} bytes at byte {}",
                l.len(),
                self.offset
            )));
        }
        self.offset += n as u64;
        Ok(l.trim_end_matches(['\r', '\n']).to_string())
    }

    /// The next frame; `Ok(None)` when the stream ended cleanly between frames.
    pub fn next_frame(&mut self) -> Result<Option<Frame>, StreamError> {
        let mut boundary = String::new();
        // Skip the blank line after the previous part's body.
        while boundary.is_empty() {
            match self.line() {
                Ok(l) => boundary = l,
                Err(StreamError::Io(e)) if e.kind() == std::io::ErrorKind::UnexpectedEof => return Ok(None),
                Err(e) => return Err(e),
            }
        }
        if boundary != format!("--{BOUNDARY}") {
            return Err(StreamError::Format(format!(
                "`{boundary}` at byte {} where the boundary --{BOUNDARY} was expected",
                self.offset
            )));
        }
        let (mut kind, mut len, mut w, mut h, mut seq, mut ts) = (None, None, None, None, None, None);
        loop {
            let l = self.line()?;
            if l.is_empty() {
                break;
            }
            let Some((k, v)) = l.split_once(':') else {
                return Err(StreamError::Format(format!(
                    "header `{l}` at byte {} has no colon",
                    self.offset
                )));
            };
            let v = v.trim();
            let num = |v: &str| {
                v.parse::<u64>().map_err(|_| StreamError::Format(format!("`{k}: {v}` is not a number")))
            };
            match k.trim().to_ascii_lowercase().as_str() {
                "content-type" => kind = Some(v.to_string()),
                "content-length" => len = Some(num(v)? as usize),
                "x-width" => w = Some(num(v)? as usize),
                "x-height" => h = Some(num(v)? as usize),
                "x-frame-seq" => seq = Some(num(v)?),
                "x-timestamp-us" => ts = Some(num(v)?),
                _ => {}
            }
        }
        let Some(len) = len else {
            return Err(StreamError::Format(format!(
                "a part without Content-Length before byte {}",
                self.offset
            )));
        };
        if len > MAX_PART_BYTES {
            return Err(StreamError::Format(format!("a part of {len} bytes (at most {MAX_PART_BYTES})")));
        }
        let mut body = vec![0u8; len];
        self.input.read_exact(&mut body)?;
        self.offset += len as u64;
        let kind = kind.unwrap_or_default();
        let (width, height, channels, data) = match kind.as_str() {
            "image/png" => decode_png(&body).map_err(StreamError::Decode)?,
            "image/x-raw-gray" | "image/x-raw-rgb" => {
                let c = if kind == "image/x-raw-gray" { 1 } else { 3 };
                let (Some(w), Some(h)) = (w, h) else {
                    return Err(StreamError::Format(format!("a {kind} part without X-Width and X-Height")));
                };
                if w * h * c != len {
                    return Err(StreamError::Format(format!("{w}x{h}x{c} pixels in a part of {len} bytes")));
                }
                (w, h, c, body)
            }
            other => {
                return Err(StreamError::Decode(format!("content type `{other}` (png or x-raw expected)")));
            }
        };
        Ok(Some(Frame { seq, timestamp_us: ts, width, height, channels, data }))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(seq: u64, channels: usize) -> Frame {
        let (width, height) = (7, 5);
        let data = (0..width * height * channels).map(|i| (i * 37 + seq as usize) as u8).collect();
        Frame {
            seq: Some(seq),
            timestamp_us: Some(1_700_000_000_000_000 + seq),
            width,
            height,
            channels,
            data,
        }
    }

    #[test]
    fn frames_round_trip_through_the_stream_in_both_encodings() {
        for enc in [PartEncoding::Png, PartEncoding::Raw] {
            let mut bytes = Vec::new();
            let mut w = StreamWriter::start(&mut bytes, enc).unwrap();
            let sent = [frame(0, 3), frame(1, 1), frame(2, 3)];
            for f in &sent {
                w.write(f).unwrap();
            }
            let mut r = StreamReader::start(&bytes[..]).unwrap();
            for f in &sent {
                assert_eq!(r.next_frame().unwrap().as_ref(), Some(f), "{enc:?}");
            }
            assert_eq!(r.next_frame().unwrap(), None);
        }
    }

    #[test]
    fn a_stream_that_is_not_one_is_refused_with_the_reason() {
        let e = StreamReader::start(&b"HTTP/1.0 404 Not Found\r\n\r\n"[..]).err().unwrap();
        assert!(e.to_string().contains("404"), "{e}");
        let e =
            StreamReader::start(&b"HTTP/1.0 200 OK\r\nContent-Type: text/html\r\n\r\n"[..]).err().unwrap();
        assert!(e.to_string().contains("text/html"), "{e}");
        let head = format!(
            "HTTP/1.0 200 OK\r\nContent-Type: multipart/x-mixed-replace; boundary={BOUNDARY}\r\n\r\n"
        );
        let mut bad = head.clone().into_bytes();
        bad.extend(b"--other\r\n\r\n");
        let e = StreamReader::start(&bad[..]).unwrap().next_frame().err().unwrap();
        assert!(e.to_string().contains("--other"), "{e}");
        let mut bad = head.clone().into_bytes();
        bad.extend(format!("--{BOUNDARY}\r\nContent-Type: image/x-raw-gray\r\nContent-Length: 3\r\nX-Width: 2\r\nX-Height: 2\r\n\r\nabc\r\n").as_bytes());
        let e = StreamReader::start(&bad[..]).unwrap().next_frame().err().unwrap();
        assert!(e.to_string().contains("2x2x1 pixels in a part of 3 bytes"), "{e}");
        let mut bad = head.into_bytes();
        bad.extend(
            format!("--{BOUNDARY}\r\nContent-Type: image/png\r\nContent-Length: 4\r\n\r\nnope\r\n")
                .as_bytes(),
        );
        let e = StreamReader::start(&bad[..]).unwrap().next_frame().err().unwrap();
        assert!(matches!(e, StreamError::Decode(_)), "{e}");
        // Cut in the middle of a part: an I/O error, not a panic and not a clean end.
        let mut bytes = Vec::new();
        StreamWriter::start(&mut bytes, PartEncoding::Raw).unwrap().write(&frame(0, 3)).unwrap();
        let cut = &bytes[..bytes.len() - 20];
        assert!(StreamReader::start(cut).unwrap().next_frame().is_err());
    }

    #[test]
    fn a_server_that_accepts_and_stays_silent_is_an_error_not_a_hang() {
        let server = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        let addr = server.local_addr().unwrap().to_string();
        let hold = std::thread::spawn(move || {
            let c = server.accept();
            std::thread::sleep(std::time::Duration::from_millis(600));
            drop(c);
        });
        let t = std::time::Instant::now();
        let e = StreamReader::connect(&addr, std::time::Duration::from_millis(200)).err().unwrap();
        assert!(e.to_string().contains("no answer within 0.2 s"), "{e}");
        assert!(t.elapsed() < std::time::Duration::from_millis(550), "{:?}", t.elapsed());
        hold.join().unwrap();
    }
}
