//! Plain gray-image buffers for the feature code: `f32` intensities and a binary validity mask.
//!
//! The renderer and the image loaders hand over `image::GrayImage` (8 bit); registration works
//! in `f32` so that blurred, down-sampled and photometrically transformed values keep their
//! fractions. Pixel convention as in [`camera`]: integer coordinates are pixel centres.

use image::GrayImage;

use camera::Gray32FImage;

/// Largest accepted side, as for camera images (guards allocations driven by input sizes).
pub const MAX_SIDE: usize = camera::MAX_IMAGE_SIDE as usize;

/// A buffer whose size does not make an image.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ImageError {
    /// Zero or absurd width/height.
    #[error("invalid image size {width}x{height}")]
    BadSize {
        /// Width, px.
        width: usize,
        /// Height, px.
        height: usize,
    },
    /// The data length is not `width × height`.
    #[error("buffer of {len} values for a {width}x{height} image")]
    BadLength {
        /// Width, px.
        width: usize,
        /// Height, px.
        height: usize,
        /// Values given.
        len: usize,
    },
    /// Two images that must have the same size do not.
    #[error("size mismatch: {a:?} vs {b:?}")]
    SizeMismatch {
        /// First size `(width, height)`.
        a: (usize, usize),
        /// Second size `(width, height)`.
        b: (usize, usize),
    },
}

fn check_size(width: usize, height: usize, len: usize) -> Result<(), ImageError> {
    if width == 0 || height == 0 || width > MAX_SIDE || height > MAX_SIDE {
        return Err(ImageError::BadSize { width, height });
    }
    if len != width * height {
        return Err(ImageError::BadLength { width, height, len });
    }
    Ok(())
}

/// A single-channel `f32` image, row-major, top row first.
#[derive(Debug, Clone, PartialEq)]
pub struct GrayF32 {
    width: usize,
    height: usize,
    data: Vec<f32>,
}

impl GrayF32 {
    /// An image from raw row-major data.
    pub fn new(width: usize, height: usize, data: Vec<f32>) -> Result<Self, ImageError> {
        check_size(width, height, data.len())?;
        Ok(Self {
            width,
            height,
            data,
        })
    }

    /// A constant image.
    pub fn filled(width: usize, height: usize, value: f32) -> Result<Self, ImageError> {
        check_size(width, height, width.saturating_mul(height))?;
        Ok(Self {
            width,
            height,
            data: vec![value; width * height],
        })
    }

    /// From an 8-bit gray image (intensities kept in 0..=255).
    pub fn from_gray8(img: &GrayImage) -> Result<Self, ImageError> {
        let (w, h) = img.dimensions();
        Self::new(
            w as usize,
            h as usize,
            img.as_raw().iter().map(|&v| v as f32).collect(),
        )
    }

    /// From an `image` crate `f32` gray image.
    pub fn from_luma32f(img: &Gray32FImage) -> Result<Self, ImageError> {
        let (w, h) = img.dimensions();
        Self::new(w as usize, h as usize, img.as_raw().clone())
    }

    /// Rounds and clamps to 8 bit.
    pub fn to_gray8(&self) -> GrayImage {
        let raw = self
            .data
            .iter()
            .map(|&v| {
                if v.is_nan() {
                    0
                } else {
                    v.round().clamp(0.0, 255.0) as u8
                }
            })
            .collect();
        // Cannot fail: the size was checked at construction and fits in u32 (≤ MAX_SIDE).
        GrayImage::from_raw(self.width as u32, self.height as u32, raw)
            .unwrap_or_else(|| GrayImage::new(self.width as u32, self.height as u32))
    }

    /// Width, px.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Height, px.
    pub fn height(&self) -> usize {
        self.height
    }

    /// Row-major values.
    pub fn data(&self) -> &[f32] {
        &self.data
    }

    /// Mutable row-major values.
    pub fn data_mut(&mut self) -> &mut [f32] {
        &mut self.data
    }

    /// Value at integer pixel `(x, y)`, `None` outside.
    pub fn get(&self, x: usize, y: usize) -> Option<f32> {
        (x < self.width && y < self.height).then(|| self.data[y * self.width + x])
    }

    /// Bilinear sample at `(x, y)` (pixel centres at integers); `None` outside
    /// `[0, w−1] × [0, h−1]` or for non-finite coordinates.
    #[inline]
    pub fn sample(&self, x: f64, y: f64) -> Option<f32> {
        // The negated comparisons also reject NaN.
        if !(x >= 0.0 && y >= 0.0 && x <= (self.width - 1) as f64 && y <= (self.height - 1) as f64)
        {
            return None;
        }
        let x0 = (x as usize).min(self.width.saturating_sub(2));
        let y0 = (y as usize).min(self.height.saturating_sub(2));
        let fx = (x - x0 as f64) as f32;
        let fy = (y - y0 as f64) as f32;
        let x1 = (x0 + 1).min(self.width - 1);
        let y1 = (y0 + 1).min(self.height - 1);
        let r0 = y0 * self.width;
        let r1 = y1 * self.width;
        let top = self.data[r0 + x0] + fx * (self.data[r0 + x1] - self.data[r0 + x0]);
        let bottom = self.data[r1 + x0] + fx * (self.data[r1 + x1] - self.data[r1 + x0]);
        Some(top + fy * (bottom - top))
    }
}

/// A binary validity mask (true = valid), row-major.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Mask {
    width: usize,
    height: usize,
    data: Vec<bool>,
}

impl Mask {
    /// A mask from raw row-major flags.
    pub fn new(width: usize, height: usize, data: Vec<bool>) -> Result<Self, ImageError> {
        check_size(width, height, data.len())?;
        Ok(Self {
            width,
            height,
            data,
        })
    }

    /// All valid.
    pub fn full(width: usize, height: usize) -> Result<Self, ImageError> {
        check_size(width, height, width.saturating_mul(height))?;
        Ok(Self {
            width,
            height,
            data: vec![true; width * height],
        })
    }

    /// From an 8-bit mask such as the renderer's (`> 0` is valid).
    pub fn from_gray8(img: &GrayImage) -> Result<Self, ImageError> {
        let (w, h) = img.dimensions();
        Self::new(
            w as usize,
            h as usize,
            img.as_raw().iter().map(|&v| v > 0).collect(),
        )
    }

    /// Width, px.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Height, px.
    pub fn height(&self) -> usize {
        self.height
    }

    /// Row-major flags.
    pub fn data(&self) -> &[bool] {
        &self.data
    }

    /// Flag at `(x, y)`; outside the image is invalid.
    #[inline]
    pub fn get(&self, x: usize, y: usize) -> bool {
        x < self.width && y < self.height && self.data[y * self.width + x]
    }

    /// Sets the flag at `(x, y)` (ignored outside).
    pub fn set(&mut self, x: usize, y: usize, valid: bool) {
        if x < self.width && y < self.height {
            self.data[y * self.width + x] = valid;
        }
    }

    /// Whether every pixel a bilinear sample at `(x, y)` touches is valid.
    #[inline]
    pub fn valid_bilinear(&self, x: f64, y: f64) -> bool {
        if !(x >= 0.0 && y >= 0.0 && x <= (self.width - 1) as f64 && y <= (self.height - 1) as f64)
        {
            return false;
        }
        let (x0, y0) = (x.floor() as usize, y.floor() as usize);
        let (x1, y1) = (x.ceil() as usize, y.ceil() as usize);
        self.get(x0, y0) && self.get(x1, y0) && self.get(x0, y1) && self.get(x1, y1)
    }
}
