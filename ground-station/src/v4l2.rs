//! V4L2 cameras (UVC webcams, like the paper's two web cameras): the pixel formats they deliver (MJPEG and
//! YUYV) turned into the station's images, their buffer timestamps turned into capture times on the station's
//! clock, and their frame counters into counted drops. These parts are pure and always built (tested on
//! recorded buffers); the device itself (`V4l2Source`, the `v4l` crate) is behind the `v4l2` feature,
//! whose build needs libclang (the `v4l` crate generates its kernel bindings with bindgen).
//!
//! - MJPEG: a UVC camera's JPEG frames often leave out the Huffman tables (DHT) and rely on the standard
//!   ones (ITU T.81 annex K.3, the AVI1 convention); `zune-jpeg` fills them in.
//! - YUYV (YUY2, 4:2:2): `Y0 U Y1 V` per two pixels, BT.601 with studio range (Y 16-235, U and V 16-240), as
//!   UVC cameras send it. The grey image is the Y plane rescaled to full range; RGB uses both.
//! - Timestamps: the kernel stamps a buffer on CLOCK_MONOTONIC (`V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC`; uvcvideo
//!   at the start of the frame's transfer). The station's clock is the Unix time, so a timestamp is moved by
//!   the offset between the two clocks read together when the buffer is dequeued.
//! - Drops: the kernel numbers the buffers it fills (`sequence`); a jump means frames lost before the
//!   station saw them.
use crate::stream::Frame;

/// A camera's pixel format, as V4L2 names it (FourCC).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PixelFormat {
    /// `MJPG`: one JPEG per frame.
    Mjpeg,
    /// `YUYV`: 4:2:2 luma and chroma, 2 bytes per pixel.
    Yuyv,
}

impl PixelFormat {
    /// The V4L2 FourCC.
    pub fn fourcc(self) -> [u8; 4] {
        match self {
            PixelFormat::Mjpeg => *b"MJPG",
            PixelFormat::Yuyv => *b"YUYV",
        }
    }

    /// The format of a FourCC, if the station reads it.
    pub fn from_fourcc(f: [u8; 4]) -> Option<Self> {
        match &f {
            b"MJPG" => Some(PixelFormat::Mjpeg),
            b"YUYV" | b"YUY2" => Some(PixelFormat::Yuyv),
            _ => None,
        }
    }
}

/// Why a buffer gave no image.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum BufferError {
    /// The JPEG did not decode (the decoder's reason).
    Jpeg(String),
    /// The image is not of the size asked for.
    Size {
        /// Width and height asked for.
        want: (usize, usize),
        /// Width and height found.
        got: (usize, usize),
    },
    /// A YUYV buffer shorter than its image (bytes found, bytes needed).
    Short(usize, usize),
}

impl std::fmt::Display for BufferError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            BufferError::Jpeg(e) => write!(f, "the MJPEG frame did not decode: {e}"),
            BufferError::Size { want, got } => {
                write!(f, "a {}x{} frame where {}x{} was set", got.0, got.1, want.0, want.1)
            }
            BufferError::Short(got, need) => write!(f, "a YUYV buffer of {got} bytes, {need} needed"),
        }
    }
}

/// BT.601 studio-range luma (16-235) to full range (0-255).
fn luma_full(y: u8) -> f32 {
    (y as f32 - 16.0) * (255.0 / 219.0)
}

fn clamp_u8(v: f32) -> u8 {
    v.round().clamp(0.0, 255.0) as u8
}

/// A YUYV buffer as an image of `channels` (1: the luma, 3: RGB), `width` by `height` (`width` even).
pub fn yuyv_to_image(
    buf: &[u8],
    width: usize,
    height: usize,
    channels: usize,
) -> Result<Vec<u8>, BufferError> {
    let need = width * height * 2;
    if buf.len() < need {
        return Err(BufferError::Short(buf.len(), need));
    }
    let buf = &buf[..need];
    if channels == 1 {
        return Ok(buf.chunks_exact(2).map(|p| clamp_u8(luma_full(p[0]))).collect());
    }
    let mut out = Vec::with_capacity(width * height * 3);
    for q in buf.chunks_exact(4) {
        // BT.601, studio range: R = Y' + 1.596 V', G = Y' - 0.392 U' - 0.813 V', B = Y' + 2.017 U', with
        // Y' = 1.164 (Y - 16), U' = U - 128, V' = V - 128.
        let (u, v) = (q[1] as f32 - 128.0, q[3] as f32 - 128.0);
        for y in [q[0], q[2]] {
            let l = luma_full(y);
            out.extend_from_slice(&[
                clamp_u8(l + 1.596 * v),
                clamp_u8(l - 0.392 * u - 0.813 * v),
                clamp_u8(l + 2.017 * u),
            ]);
        }
    }
    Ok(out)
}

/// A JPEG (a file, or a UVC camera's MJPEG frame with or without its Huffman tables) as an image of
/// `channels` (1: grey, 3: RGB): width, height and the pixels, row by row.
pub fn decode_jpeg(jpeg: &[u8], channels: usize) -> Result<(usize, usize, Vec<u8>), BufferError> {
    use zune_jpeg::zune_core::bytestream::ZCursor;
    use zune_jpeg::zune_core::colorspace::ColorSpace;
    use zune_jpeg::zune_core::options::DecoderOptions;
    let colour = if channels == 1 { ColorSpace::Luma } else { ColorSpace::RGB };
    let options = DecoderOptions::default().jpeg_set_out_colorspace(colour);
    let jpeg = with_standard_tables_marked(jpeg);
    let mut dec = zune_jpeg::JpegDecoder::new_with_options(ZCursor::new(&jpeg[..]), options);
    let pixels = dec.decode().map_err(|e| BufferError::Jpeg(format!("{e:?}")))?;
    let (w, h) = dec.dimensions().ok_or_else(|| BufferError::Jpeg("no image size".into()))?;
    if pixels.len() != w * h * channels {
        return Err(BufferError::Jpeg(format!("{} bytes for {w}x{h}x{channels}", pixels.len())));
    }
    Ok((w, h, pixels))
}

/// A UVC camera's MJPEG frame as an image of `channels`, refused unless it is `width` by `height`.
pub fn mjpeg_to_image(
    jpeg: &[u8],
    width: usize,
    height: usize,
    channels: usize,
) -> Result<Vec<u8>, BufferError> {
    let (w, h, pixels) = decode_jpeg(jpeg, channels)?;
    if (w, h) != (width, height) {
        return Err(BufferError::Size { want: (width, height), got: (w, h) });
    }
    Ok(pixels)
}

/// A JPEG without Huffman tables before its scan marked as MJPEG (an APP0 `AVI1` segment after SOI), so
/// that the decoder uses the standard tables; others as they are. Cameras that leave the tables out do not
/// all say so: the decoder only supplies them for frames marked `AVI1`.
fn with_standard_tables_marked(jpeg: &[u8]) -> std::borrow::Cow<'_, [u8]> {
    let mut i = 2;
    while i + 4 <= jpeg.len() && jpeg[i] == 0xFF {
        match jpeg[i + 1] {
            0xC4 => return jpeg.into(),
            // The scan: no tables before it.
            0xDA => break,
            // Fill bytes before a marker.
            0xFF => i += 1,
            _ => i += 2 + u16::from_be_bytes([jpeg[i + 2], jpeg[i + 3]]) as usize,
        }
    }
    if jpeg.len() < 2 || jpeg[..2] != [0xFF, 0xD8] {
        return jpeg.into();
    }
    let mut out = Vec::with_capacity(jpeg.len() + 9);
    out.extend_from_slice(&[0xFF, 0xD8, 0xFF, 0xE0, 0x00, 0x07, b'A', b'V', b'I', b'1', 0x00]);
    out.extend_from_slice(&jpeg[2..]);
    out.into()
}

/// A buffer of `format` as the station's frame.
pub fn buffer_to_frame(
    format: PixelFormat,
    buf: &[u8],
    width: usize,
    height: usize,
    channels: usize,
) -> Result<Frame, BufferError> {
    let data = match format {
        PixelFormat::Mjpeg => mjpeg_to_image(buf, width, height, channels)?,
        PixelFormat::Yuyv => yuyv_to_image(buf, width, height, channels)?,
    };
    Ok(Frame { seq: None, timestamp_us: None, width, height, channels, data })
}

/// A kernel buffer timestamp (CLOCK_MONOTONIC, us) on the station's clock (Unix, us), from the two clocks
/// read together (`monotonic_now_us`, `unix_now_us`).
pub fn monotonic_to_unix_us(stamp_us: u64, monotonic_now_us: u64, unix_now_us: u64) -> u64 {
    (unix_now_us as i128 - monotonic_now_us as i128 + stamp_us as i128).max(0) as u64
}

/// What a camera delivered, and lost.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct CaptureCounters {
    /// Buffers dequeued.
    pub buffers: u64,
    /// Frames the kernel numbered but the station never got (gaps in `sequence`).
    pub dropped: u64,
    /// Buffers the driver flagged as damaged (`V4L2_BUF_FLAG_ERROR`), skipped.
    pub flagged: u64,
    /// Buffers that did not decode, skipped.
    pub undecodable: u64,
}

impl CaptureCounters {
    /// Counts a buffer with the kernel's sequence number `seq` after `previous` (the last one seen).
    pub fn sequence(&mut self, previous: Option<u32>, seq: u32) {
        self.buffers += 1;
        if let Some(p) = previous {
            self.dropped += seq.wrapping_sub(p).saturating_sub(1) as u64;
        }
    }
}

#[cfg(feature = "v4l2")]
pub use device::V4l2Source;

#[cfg(feature = "v4l2")]
mod device {
    use super::*;
    use crate::source::{FrameSource, SourceWant};
    use crate::stream::StreamError;
    use v4l::buffer::{Flags, Type};
    use v4l::io::traits::CaptureStream;
    use v4l::video::Capture;

    /// A V4L2 capture device, set to the calibration's size, the camera's rate and MJPEG or YUYV.
    pub struct V4l2Source {
        stream: v4l::io::mmap::Stream<'static>,
        format: PixelFormat,
        want: SourceWant,
        last_seq: Option<u32>,
        /// What was delivered and lost.
        pub counters: CaptureCounters,
        path: String,
    }

    /// CLOCK_MONOTONIC, the clock of the kernel's buffer timestamps (us).
    fn monotonic_us() -> u64 {
        let ts = rustix::time::clock_gettime(rustix::time::ClockId::Monotonic);
        ts.tv_sec as u64 * 1_000_000 + ts.tv_nsec as u64 / 1000
    }

    impl V4l2Source {
        /// Opens `path` (`/dev/videoN`) and sets the format: the calibration's size, MJPEG if the camera
        /// offers it at that size, else YUYV, and the camera's rate. A camera that cannot give that size or
        /// either format is refused, naming what it offers.
        pub fn open(path: &str, want: SourceWant) -> Result<Self, String> {
            let dev = v4l::Device::with_path(path).map_err(|e| format!("{path}: {e}"))?;
            let offered: Vec<[u8; 4]> = dev
                .enum_formats()
                .map_err(|e| format!("{path}: listing its formats: {e}"))?
                .iter()
                .map(|f| f.fourcc.repr)
                .collect();
            let mut last = String::new();
            for format in [PixelFormat::Mjpeg, PixelFormat::Yuyv] {
                if !offered.contains(&format.fourcc()) {
                    continue;
                }
                let asked = v4l::Format::new(
                    want.width as u32,
                    want.height as u32,
                    v4l::FourCC::new(&format.fourcc()),
                );
                let set = dev.set_format(&asked).map_err(|e| format!("{path}: setting the format: {e}"))?;
                if (set.width as usize, set.height as usize) != (want.width, want.height)
                    || set.fourcc.repr != format.fourcc()
                {
                    last = format!("{}x{} {}", set.width, set.height, set.fourcc);
                    continue;
                }
                if want.rate_hz > 0.0 {
                    let params = v4l::video::capture::Parameters::with_fps(want.rate_hz.round() as u32);
                    dev.set_params(&params)
                        .map_err(|e| format!("{path}: setting {} Hz: {e}", want.rate_hz))?;
                }
                // The stream holds the device's handle.
                let stream = v4l::io::mmap::Stream::with_buffers(&dev, Type::VideoCapture, 4)
                    .map_err(|e| format!("{path}: starting the stream (busy?): {e}"))?;
                return Ok(Self {
                    stream,
                    format,
                    want,
                    last_seq: None,
                    counters: CaptureCounters::default(),
                    path: path.to_string(),
                });
            }
            let names: Vec<String> =
                offered.iter().map(|f| String::from_utf8_lossy(f).into_owned()).collect();
            Err(format!(
                "{path}: no MJPEG or YUYV at {}x{} (it offers {}{})",
                want.width,
                want.height,
                names.join(", "),
                if last.is_empty() { String::new() } else { format!("; it set {last}") }
            ))
        }
    }

    impl FrameSource for V4l2Source {
        fn next_frame(&mut self) -> Result<Option<Frame>, StreamError> {
            loop {
                let (buf, meta) = self.stream.next().map_err(|e| {
                    StreamError::Io(std::io::Error::new(e.kind(), format!("{}: {e}", self.path)))
                })?;
                let (mono, unix) = (monotonic_us(), crate::source::now_unix_us());
                self.counters.sequence(self.last_seq, meta.sequence);
                self.last_seq = Some(meta.sequence);
                if meta.flags.contains(Flags::ERROR) {
                    self.counters.flagged += 1;
                    continue;
                }
                let used = (meta.bytesused as usize).min(buf.len());
                let stamp = meta.timestamp.sec as u64 * 1_000_000 + meta.timestamp.usec as u64;
                let w = &self.want;
                match buffer_to_frame(self.format, &buf[..used], w.width, w.height, w.channels) {
                    Ok(mut f) => {
                        f.seq = Some(meta.sequence as u64);
                        f.timestamp_us = Some(monotonic_to_unix_us(stamp, mono, unix));
                        return Ok(Some(f));
                    }
                    Err(_) => self.counters.undecodable += 1,
                }
            }
        }

        fn counters(&self) -> CaptureCounters {
            self.counters
        }
    }
}

#[cfg(test)]
mod tests;
