//! Borrowed image views with a row stride (no copies, no allocation).

/// Why an image view could not be built.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ImageError {
    /// Width or height is zero.
    Empty,
    /// The stride is shorter than one row of pixels.
    StrideTooSmall,
    /// The buffer is shorter than `stride * (height - 1) + row length`.
    BufferTooSmall,
    /// Wider or taller than [`MAX_DIM`].
    TooLarge,
}

/// Largest accepted width or height (keeps the per-column buffers of the detector bounded).
pub const MAX_DIM: usize = 2048;

/// An interleaved 8-bit RGB image (`R, G, B` per pixel) borrowed from a caller's buffer.
#[derive(Clone, Copy, Debug)]
pub struct Rgb8View<'a> {
    data: &'a [u8],
    width: usize,
    height: usize,
    stride: usize,
}

/// An 8-bit grey image borrowed from a caller's buffer.
#[derive(Clone, Copy, Debug)]
pub struct Gray8View<'a> {
    data: &'a [u8],
    width: usize,
    height: usize,
    stride: usize,
}

fn check(len: usize, width: usize, height: usize, stride: usize, bpp: usize) -> Result<(), ImageError> {
    if width == 0 || height == 0 {
        return Err(ImageError::Empty);
    }
    if width > MAX_DIM || height > MAX_DIM {
        return Err(ImageError::TooLarge);
    }
    if stride < width * bpp {
        return Err(ImageError::StrideTooSmall);
    }
    if len < stride * (height - 1) + width * bpp {
        return Err(ImageError::BufferTooSmall);
    }
    Ok(())
}

impl<'a> Rgb8View<'a> {
    /// A view of `height` rows of `width` pixels, rows `stride` bytes apart.
    pub fn new(data: &'a [u8], width: usize, height: usize, stride: usize) -> Result<Self, ImageError> {
        check(data.len(), width, height, stride, 3)?;
        Ok(Self { data, width, height, stride })
    }

    /// A tightly packed view (`stride = 3 * width`).
    pub fn packed(data: &'a [u8], width: usize, height: usize) -> Result<Self, ImageError> {
        Self::new(data, width, height, 3 * width)
    }

    /// Width in pixels.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Height in pixels.
    pub fn height(&self) -> usize {
        self.height
    }

    /// Row `y` as `3 * width` bytes. `y` must be below the height.
    pub fn row(&self, y: usize) -> &'a [u8] {
        let start = y * self.stride;
        self.data.get(start..start + 3 * self.width).unwrap_or(&[])
    }

    /// The pixel at `(x, y)`, or black outside the image.
    pub fn pixel(&self, x: usize, y: usize) -> [u8; 3] {
        if x >= self.width || y >= self.height {
            return [0; 3];
        }
        let i = y * self.stride + 3 * x;
        match self.data.get(i..i + 3) {
            Some(p) => [p[0], p[1], p[2]],
            None => [0; 3],
        }
    }
}

impl<'a> Gray8View<'a> {
    /// A view of `height` rows of `width` pixels, rows `stride` bytes apart.
    pub fn new(data: &'a [u8], width: usize, height: usize, stride: usize) -> Result<Self, ImageError> {
        check(data.len(), width, height, stride, 1)?;
        Ok(Self { data, width, height, stride })
    }

    /// A tightly packed view (`stride = width`).
    pub fn packed(data: &'a [u8], width: usize, height: usize) -> Result<Self, ImageError> {
        Self::new(data, width, height, width)
    }

    /// Width in pixels.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Height in pixels.
    pub fn height(&self) -> usize {
        self.height
    }

    /// Row `y` as `width` bytes. `y` must be below the height.
    pub fn row(&self, y: usize) -> &'a [u8] {
        let start = y * self.stride;
        self.data.get(start..start + self.width).unwrap_or(&[])
    }

    /// The pixel at `(x, y)`, or 0 outside the image.
    pub fn pixel(&self, x: usize, y: usize) -> u8 {
        if x >= self.width || y >= self.height {
            return 0;
        }
        self.data.get(y * self.stride + x).copied().unwrap_or(0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn views_check_their_buffers() {
        let buf = [0u8; 3 * 4 * 3];
        assert!(Rgb8View::packed(&buf, 4, 3).is_ok());
        assert_eq!(Rgb8View::packed(&buf, 4, 4).unwrap_err(), ImageError::BufferTooSmall);
        assert_eq!(Rgb8View::new(&buf, 4, 3, 11).unwrap_err(), ImageError::StrideTooSmall);
        assert_eq!(Gray8View::packed(&buf, 0, 3).unwrap_err(), ImageError::Empty);
        // A padded stride: the last row may be short of a full stride.
        let padded = [7u8; 16 * 2 + 12];
        let v = Rgb8View::new(&padded, 4, 3, 16).unwrap();
        assert_eq!(v.row(2).len(), 12);
        assert_eq!(v.pixel(3, 2), [7, 7, 7]);
        assert_eq!(v.pixel(4, 2), [0, 0, 0]);
    }
}
