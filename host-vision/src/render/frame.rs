//! What one rendering returns, and the view it was rendered from.

use image::{GrayImage, RgbaImage};

use super::RenderError;
use super::projection::depth_to_z;
use crate::camera::Gray32FImage;
use crate::camera::{CameraPose, Pinhole};

/// The view to render: ideal pinhole intrinsics (the live image is undistorted to match),
/// camera pose and clip distances in metres.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RenderView {
    /// Intrinsics for the renderer's image size.
    pub pinhole: Pinhole,
    /// Camera pose (`q_cw`, `c_w`).
    pub pose: CameraPose,
    /// Near clip distance along the optical axis, m (> 0).
    pub near: f64,
    /// Far clip distance, m (> near).
    pub far: f64,
}

impl RenderView {
    /// Checks intrinsics and clip distances.
    pub fn validate(&self) -> Result<(), RenderError> {
        self.pinhole
            .validate()
            .map_err(|e| RenderError::BadView(e.to_string()))?;
        if !(self.near.is_finite()
            && self.far.is_finite()
            && self.near > 0.0
            && self.far > self.near)
        {
            return Err(RenderError::BadView(format!(
                "need 0 < near < far, got near {} far {}",
                self.near, self.far
            )));
        }
        Ok(())
    }
}

/// One rendered frame, all images row-major with the top row first.
#[derive(Debug, Clone)]
pub struct Frame {
    /// The view this was rendered from.
    pub view: RenderView,
    /// Colour (RGBA8; alpha 0 on background).
    pub rgba: RgbaImage,
    /// Grayscale, ITU-R BT.601 luma of `rgba`.
    pub gray: GrayImage,
    /// Camera-frame depth `z` in metres (along the optical axis, not the ray); 0 on background.
    pub depth: Gray32FImage,
    /// 255 where the model was rendered, 0 on background.
    pub mask: GrayImage,
}

impl Frame {
    pub(crate) fn from_readback(
        view: RenderView,
        width: u32,
        height: u32,
        rgba: Vec<u8>,
        depth_bits: &[u32],
    ) -> Result<Self, RenderError> {
        let size_err = || RenderError::Readback("readback size mismatch".into());
        let rgba = RgbaImage::from_raw(width, height, rgba).ok_or_else(size_err)?;
        // BT.601 luma in 16.16 fixed point: one pass over the raw bytes.
        let gray_raw: Vec<u8> = rgba
            .as_raw()
            .chunks_exact(4)
            .map(|p| {
                ((19595 * p[0] as u32 + 38470 * p[1] as u32 + 7471 * p[2] as u32 + 32768) >> 16)
                    as u8
            })
            .collect();
        let gray = GrayImage::from_raw(width, height, gray_raw).ok_or_else(size_err)?;
        let (near, far) = (view.near, view.far);
        let mut mask_raw = Vec::with_capacity(depth_bits.len());
        let z: Vec<f32> = depth_bits
            .iter()
            .map(|&bits| {
                let z = depth_to_z(f32::from_bits(bits), near, far).unwrap_or(0.0) as f32;
                mask_raw.push(if z > 0.0 { 255 } else { 0 });
                z
            })
            .collect();
        let mask = GrayImage::from_raw(width, height, mask_raw).ok_or_else(size_err)?;
        let depth = Gray32FImage::from_raw(width, height, z).ok_or_else(size_err)?;
        Ok(Self {
            view,
            rgba,
            gray,
            depth,
            mask,
        })
    }

    /// Image size `(width, height)`.
    pub fn size(&self) -> (u32, u32) {
        self.rgba.dimensions()
    }

    /// Depth `z` (m) at pixel `(u, v)` where the model was rendered.
    pub fn depth_at(&self, u: u32, v: u32) -> Option<f64> {
        let z = self.depth.get_pixel_checked(u, v)?.0[0];
        (z > 0.0).then_some(z as f64)
    }
}
