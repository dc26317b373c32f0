//! The view a rendering is made from: the ideal camera's intrinsics, its pose and the clip
//! planes.

use super::RenderError;
use camera::{CameraPose, Pinhole};

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
