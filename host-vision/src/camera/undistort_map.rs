//! A precomputed map that rectifies whole images (bilinear), like OpenCV's
//! `initUndistortRectifyMap` + `remap`.

use image::{GrayImage, ImageBuffer, Luma};
use nalgebra::Vector2;

use super::{Camera, CameraError, MAX_IMAGE_SIDE, Pinhole};

/// A single-channel `f32` image.
pub type Gray32FImage = ImageBuffer<Luma<f32>, Vec<f32>>;

/// For every pixel of the rectified (ideal pinhole) image, where to sample the distorted
/// source image.
///
/// Coordinates follow the pixel-centre convention of [`crate::camera`]. The map stores `f32`
/// coordinates (round-off ≤ 1e-4 px for images up to 2000 px, far below what bilinear
/// interpolation resolves); the point functions of [`Camera`] are the `f64` reference.
#[derive(Debug, Clone)]
pub struct UndistortMap {
    width: u32,
    height: u32,
    src_width: u32,
    src_height: u32,
    /// Source pixel of each target pixel, row-major; NaN where the source is outside the image.
    map: Vec<[f32; 2]>,
}

impl UndistortMap {
    /// Map to an ideal pinhole image with the source's size and intrinsics.
    pub fn new(camera: &Camera) -> Result<Self, CameraError> {
        Self::with_target(camera, &camera.pinhole, camera.width, camera.height)
    }

    /// Map to an ideal pinhole image with intrinsics `target` and size `width × height`.
    pub fn with_target(
        camera: &Camera,
        target: &Pinhole,
        width: u32,
        height: u32,
    ) -> Result<Self, CameraError> {
        if width == 0 || height == 0 || width > MAX_IMAGE_SIDE || height > MAX_IMAGE_SIDE {
            return Err(CameraError::BadSize { width, height });
        }
        if camera.width == 0 || camera.height == 0 {
            return Err(CameraError::BadSize {
                width: camera.width,
                height: camera.height,
            });
        }
        target.validate()?;
        let (sw, sh) = (camera.width as f64, camera.height as f64);
        let mut map = Vec::with_capacity(width as usize * height as usize);
        for v in 0..height {
            for u in 0..width {
                let n = target.to_normalised(Vector2::new(u as f64, v as f64));
                let s = camera.normalised_to_pixel(n);
                let inside = s.x >= 0.0 && s.y >= 0.0 && s.x <= sw - 1.0 && s.y <= sh - 1.0;
                // Clamped because the f32 rounding may step just outside the image.
                map.push(if inside {
                    [
                        (s.x as f32).clamp(0.0, (sw - 1.0) as f32),
                        (s.y as f32).clamp(0.0, (sh - 1.0) as f32),
                    ]
                } else {
                    [f32::NAN; 2]
                });
            }
        }
        Ok(Self {
            width,
            height,
            src_width: camera.width,
            src_height: camera.height,
            map,
        })
    }

    /// Rectified image size `(width, height)`.
    pub fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    /// Where rectified pixel `(u, v)` samples the source; `None` outside either image.
    pub fn source_of(&self, u: u32, v: u32) -> Option<[f32; 2]> {
        if u >= self.width || v >= self.height {
            return None;
        }
        let s = self.map[(v * self.width + u) as usize];
        (!s[0].is_nan()).then_some(s)
    }

    /// Rectifies an 8-bit image; pixels whose source is outside the image are 0.
    pub fn remap_gray(&self, src: &GrayImage) -> Result<GrayImage, CameraError> {
        self.check_source(src.width(), src.height())?;
        let raw = src.as_raw();
        let out = self.remap_with(src.width(), |i| raw[i] as f32);
        Ok(GrayImage::from_fn(self.width, self.height, |u, v| {
            let x = out[(v * self.width + u) as usize];
            Luma([(x + 0.5).clamp(0.0, 255.0) as u8])
        }))
    }

    /// Rectifies an `f32` image; pixels whose source is outside the image are 0.
    pub fn remap_f32(&self, src: &Gray32FImage) -> Result<Gray32FImage, CameraError> {
        self.check_source(src.width(), src.height())?;
        let raw = src.as_raw();
        let out = self.remap_with(src.width(), |i| raw[i]);
        Gray32FImage::from_raw(self.width, self.height, out).ok_or(CameraError::BadSize {
            width: self.width,
            height: self.height,
        })
    }

    fn check_source(&self, width: u32, height: u32) -> Result<(), CameraError> {
        if (width, height) != (self.src_width, self.src_height) {
            return Err(CameraError::BadSize { width, height });
        }
        Ok(())
    }

    fn remap_with(&self, src_width: u32, get: impl Fn(usize) -> f32) -> Vec<f32> {
        let sw = src_width as usize;
        let (max_x, max_y) = (self.src_width - 1, self.src_height - 1);
        self.map
            .iter()
            .map(|&[x, y]| {
                if x.is_nan() {
                    return 0.0;
                }
                // Bilinear on pixel centres; the map guarantees 0 ≤ x ≤ w−1, 0 ≤ y ≤ h−1.
                let (x0, y0) = (x.floor() as u32, y.floor() as u32);
                let (ax, ay) = (x - x0 as f32, y - y0 as f32);
                let (x1, y1) = ((x0 + 1).min(max_x), (y0 + 1).min(max_y));
                let at = |xx: u32, yy: u32| get(yy as usize * sw + xx as usize);
                let top = at(x0, y0) * (1.0 - ax) + at(x1, y0) * ax;
                let bottom = at(x0, y1) * (1.0 - ax) + at(x1, y1) * ax;
                top * (1.0 - ay) + bottom * ay
            })
            .collect()
    }
}
