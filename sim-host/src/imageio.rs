//! Owned images and PNG input/output.
use std::fs::File;
use std::io::BufReader;
use std::path::Path;

/// An owned, tightly packed 8-bit RGB image.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RgbImage {
    /// Width (px).
    pub width: usize,
    /// Height (px).
    pub height: usize,
    /// `3 * width * height` bytes, row-major, `R, G, B`.
    pub data: Vec<u8>,
}

/// An owned, tightly packed 8-bit grey image.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct GrayImage {
    /// Width (px).
    pub width: usize,
    /// Height (px).
    pub height: usize,
    /// `width * height` bytes, row-major.
    pub data: Vec<u8>,
}

impl RgbImage {
    /// A black image.
    pub fn new(width: usize, height: usize) -> Self {
        Self { width, height, data: vec![0; 3 * width * height] }
    }

    /// A borrowed view for vision-core.
    pub fn view(&self) -> vision_core::Rgb8View<'_> {
        // The buffer is exactly the right size by construction.
        match vision_core::Rgb8View::packed(&self.data, self.width, self.height) {
            Ok(v) => v,
            Err(e) => unreachable_image(e),
        }
    }

    /// Sets a pixel (ignored outside the image).
    pub fn put(&mut self, x: i64, y: i64, rgb: [u8; 3]) {
        if x >= 0 && y >= 0 && (x as usize) < self.width && (y as usize) < self.height {
            let i = 3 * (y as usize * self.width + x as usize);
            self.data[i..i + 3].copy_from_slice(&rgb);
        }
    }
}

impl GrayImage {
    /// A black image.
    pub fn new(width: usize, height: usize) -> Self {
        Self { width, height, data: vec![0; width * height] }
    }

    /// A borrowed view for vision-core.
    pub fn view(&self) -> vision_core::Gray8View<'_> {
        match vision_core::Gray8View::packed(&self.data, self.width, self.height) {
            Ok(v) => v,
            Err(e) => unreachable_image(e),
        }
    }
}

fn unreachable_image(e: vision_core::image::ImageError) -> ! {
    // Owned images always hold exactly width * height pixels; a failure here is a programming error.
    panic!("owned image does not match its dimensions: {e:?}")
}

/// Why an image file could not be read.
#[derive(Debug)]
pub enum ImageIoError {
    /// The file could not be opened or read.
    Io(std::io::Error),
    /// The file is not a PNG, or is corrupt.
    NotPng(String),
    /// The PNG has a pixel format the tool does not accept.
    Unsupported(String),
}

impl std::fmt::Display for ImageIoError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            ImageIoError::Io(e) => write!(f, "cannot read the file: {e}"),
            ImageIoError::NotPng(e) => write!(f, "not a readable PNG or JPEG file: {e}"),
            ImageIoError::Unsupported(e) => write!(f, "unsupported PNG: {e}"),
        }
    }
}

impl std::error::Error for ImageIoError {}

fn decode(path: &Path) -> Result<(png::OutputInfo, Vec<u8>), ImageIoError> {
    let file = File::open(path).map_err(ImageIoError::Io)?;
    decode_from(BufReader::new(file))
}

fn decode_from<R: std::io::BufRead + std::io::Seek>(
    input: R,
) -> Result<(png::OutputInfo, Vec<u8>), ImageIoError> {
    let mut decoder = png::Decoder::new(input);
    decoder.set_transformations(png::Transformations::normalize_to_color8());
    let mut reader = decoder.read_info().map_err(|e| ImageIoError::NotPng(e.to_string()))?;
    let size =
        reader.output_buffer_size().ok_or_else(|| ImageIoError::Unsupported("image too large".into()))?;
    let mut buf = vec![0; size];
    let info = reader.next_frame(&mut buf).map_err(|e| ImageIoError::NotPng(e.to_string()))?;
    buf.truncate(info.buffer_size());
    Ok((info, buf))
}

/// Reads a PNG as RGB (8-bit; 16-bit is reduced, palettes expanded, alpha dropped). Grey images are
/// rejected: the red line needs colour.
pub fn read_png_rgb(path: &Path) -> Result<RgbImage, ImageIoError> {
    to_rgb(decode(path)?)
}

/// Decodes PNG bytes as RGB, like [`read_png_rgb`].
pub fn rgb_from_png(bytes: &[u8]) -> Result<RgbImage, ImageIoError> {
    to_rgb(decode_from(std::io::Cursor::new(bytes))?)
}

fn to_rgb((info, buf): (png::OutputInfo, Vec<u8>)) -> Result<RgbImage, ImageIoError> {
    let (w, h) = (info.width as usize, info.height as usize);
    let data = match info.color_type {
        png::ColorType::Rgb => buf,
        png::ColorType::Rgba => buf.chunks_exact(4).flat_map(|p| [p[0], p[1], p[2]]).collect(),
        other => {
            return Err(ImageIoError::Unsupported(format!(
                "{other:?} image: a colour (RGB or RGBA) image is needed"
            )));
        }
    };
    if data.len() != 3 * w * h {
        return Err(ImageIoError::NotPng("pixel data shorter than the header says".into()));
    }
    Ok(RgbImage { width: w, height: h, data })
}

/// Whether the bytes start as a JPEG does (SOI and a marker).
pub fn is_jpeg(bytes: &[u8]) -> bool {
    bytes.len() > 3 && bytes[..3] == [0xFF, 0xD8, 0xFF]
}

fn read_bytes(path: &Path) -> Result<Vec<u8>, ImageIoError> {
    std::fs::read(path).map_err(ImageIoError::Io)
}

/// Reads a PNG or a JPEG (a webcam's frame) as RGB; grey images are refused as by [`read_png_rgb`].
pub fn read_image_rgb(path: &Path) -> Result<RgbImage, ImageIoError> {
    let bytes = read_bytes(path)?;
    if !is_jpeg(&bytes) {
        return rgb_from_png(&bytes);
    }
    let (width, height, data) = ground_station::v4l2::decode_jpeg(&bytes, 3)
        .map_err(|e| ImageIoError::NotPng(format!("a JPEG that does not decode: {e}")))?;
    Ok(RgbImage { width, height, data })
}

/// Reads a PNG or a JPEG as 8-bit grey (a JPEG's luma).
pub fn read_image_gray(path: &Path) -> Result<GrayImage, ImageIoError> {
    let bytes = read_bytes(path)?;
    if !is_jpeg(&bytes) {
        return gray_from_png(&bytes);
    }
    let (width, height, data) = ground_station::v4l2::decode_jpeg(&bytes, 1)
        .map_err(|e| ImageIoError::NotPng(format!("a JPEG that does not decode: {e}")))?;
    Ok(GrayImage { width, height, data })
}

/// Rec. 601 luma of an 8-bit RGB pixel, rounded.
pub fn luma(r: u8, g: u8, b: u8) -> u8 {
    ((299 * r as u32 + 587 * g as u32 + 114 * b as u32 + 500) / 1000) as u8
}

/// Reads a PNG as 8-bit grey (colour images are converted with Rec. 601 luma weights).
pub fn read_png_gray(path: &Path) -> Result<GrayImage, ImageIoError> {
    to_gray(decode(path)?)
}

/// Decodes PNG bytes as 8-bit grey, like [`read_png_gray`].
pub fn gray_from_png(bytes: &[u8]) -> Result<GrayImage, ImageIoError> {
    to_gray(decode_from(std::io::Cursor::new(bytes))?)
}

fn to_gray((info, buf): (png::OutputInfo, Vec<u8>)) -> Result<GrayImage, ImageIoError> {
    let (w, h) = (info.width as usize, info.height as usize);
    let data = match info.color_type {
        png::ColorType::Grayscale => buf,
        png::ColorType::GrayscaleAlpha => buf.chunks_exact(2).map(|p| p[0]).collect(),
        png::ColorType::Rgb => buf.chunks_exact(3).map(|p| luma(p[0], p[1], p[2])).collect(),
        png::ColorType::Rgba => buf.chunks_exact(4).map(|p| luma(p[0], p[1], p[2])).collect(),
        other => return Err(ImageIoError::Unsupported(format!("{other:?}"))),
    };
    if data.len() != w * h {
        return Err(ImageIoError::NotPng("pixel data shorter than the header says".into()));
    }
    Ok(GrayImage { width: w, height: h, data })
}

/// Encodes and writes through a temporary file renamed into place ([`crate::files::AtomicFile`]).
fn write(path: &Path, w: usize, h: usize, color: png::ColorType, data: &[u8]) -> anyhow::Result<()> {
    let mut bytes = Vec::new();
    encode_to(&mut bytes, w, h, color, data)?;
    crate::files::write_atomic(path, &bytes)
}

fn encode_to<W: std::io::Write>(
    out: W,
    w: usize,
    h: usize,
    color: png::ColorType,
    data: &[u8],
) -> anyhow::Result<()> {
    let mut enc = png::Encoder::new(out, w as u32, h as u32);
    enc.set_color(color);
    enc.set_depth(png::BitDepth::Eight);
    enc.set_compression(png::Compression::Fast);
    let mut writer = enc.write_header()?;
    writer.write_image_data(data)?;
    writer.finish()?;
    Ok(())
}

/// An RGB image as PNG bytes (lossless).
pub fn png_of_rgb(img: &RgbImage) -> anyhow::Result<Vec<u8>> {
    let mut out = Vec::new();
    encode_to(&mut out, img.width, img.height, png::ColorType::Rgb, &img.data)?;
    Ok(out)
}

/// A grey image as PNG bytes (lossless).
pub fn png_of_gray(img: &GrayImage) -> anyhow::Result<Vec<u8>> {
    let mut out = Vec::new();
    encode_to(&mut out, img.width, img.height, png::ColorType::Grayscale, &img.data)?;
    Ok(out)
}

/// Writes an RGB PNG.
pub fn write_png_rgb(path: &Path, img: &RgbImage) -> anyhow::Result<()> {
    write(path, img.width, img.height, png::ColorType::Rgb, &img.data)
}

/// Writes a grey PNG.
pub fn write_png_gray(path: &Path, img: &GrayImage) -> anyhow::Result<()> {
    write(path, img.width, img.height, png::ColorType::Grayscale, &img.data)
}

/// A logged camera frame's pixels as images: built from an image (raw or PNG) and decoded back, the frame
/// checking the size it declares (`flightlog::CameraFrame::check_size`).
pub trait FrameImages: Sized {
    /// A forward (RGB) frame.
    fn rgb(seq: u32, capture_time_us: u64, img: &RgbImage, enc: FrameEncoding) -> anyhow::Result<Self>;
    /// A grey frame of a camera.
    fn gray(
        camera: CameraId,
        seq: u32,
        capture_time_us: u64,
        img: &GrayImage,
        rotation_hint_cam: [f32; 3],
        enc: FrameEncoding,
    ) -> anyhow::Result<Self>;
    /// The pixels as an RGB image (grey frames are expanded).
    fn to_rgb(&self) -> anyhow::Result<RgbImage>;
    /// The pixels as a grey image (colour frames are converted with Rec. 601 luma weights).
    fn to_gray(&self) -> anyhow::Result<GrayImage>;
}

use crate::flightlog::{CameraFrame, CameraId, FrameEncoding};

impl FrameImages for CameraFrame {
    fn rgb(seq: u32, capture_time_us: u64, img: &RgbImage, enc: FrameEncoding) -> anyhow::Result<Self> {
        let data = match enc {
            FrameEncoding::Raw => img.data.clone(),
            FrameEncoding::Png => png_of_rgb(img)?,
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

    fn gray(
        camera: CameraId,
        seq: u32,
        capture_time_us: u64,
        img: &GrayImage,
        rotation_hint_cam: [f32; 3],
        enc: FrameEncoding,
    ) -> anyhow::Result<Self> {
        let data = match enc {
            FrameEncoding::Raw => img.data.clone(),
            FrameEncoding::Png => png_of_gray(img)?,
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

    fn to_rgb(&self) -> anyhow::Result<RgbImage> {
        let (w, h) = (self.width as usize, self.height as usize);
        let img = match (self.encoding, self.channels) {
            (FrameEncoding::Png, _) => {
                rgb_from_png(&self.data).or_else(|_| gray_from_png(&self.data).map(|g| gray_to_rgb(&g)))?
            }
            (FrameEncoding::Raw, 3) => RgbImage { width: w, height: h, data: self.data.clone() },
            (FrameEncoding::Raw, 1) => {
                gray_to_rgb(&GrayImage { width: w, height: h, data: self.data.clone() })
            }
            (_, c) => anyhow::bail!("frame {} has {c} channels (1 or 3 expected)", self.seq),
        };
        self.check_size(img.width, img.height, img.data.len() / 3)?;
        Ok(img)
    }

    fn to_gray(&self) -> anyhow::Result<GrayImage> {
        let (w, h) = (self.width as usize, self.height as usize);
        let img = match (self.encoding, self.channels) {
            (FrameEncoding::Png, _) => gray_from_png(&self.data)?,
            (FrameEncoding::Raw, 1) => GrayImage { width: w, height: h, data: self.data.clone() },
            (FrameEncoding::Raw, 3) => GrayImage {
                width: w,
                height: h,
                data: self.data.chunks_exact(3).map(|p| luma(p[0], p[1], p[2])).collect(),
            },
            (_, c) => anyhow::bail!("frame {} has {c} channels (1 or 3 expected)", self.seq),
        };
        self.check_size(img.width, img.height, img.data.len())?;
        Ok(img)
    }
}

fn gray_to_rgb(g: &GrayImage) -> RgbImage {
    RgbImage { width: g.width, height: g.height, data: g.data.iter().flat_map(|&v| [v, v, v]).collect() }
}
