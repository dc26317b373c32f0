//! Back-projection of rendered depth: pixel + depth → camera point → world point, with the
//! covariance the depth buffer's resolution implies.

use nalgebra::{Matrix3, Vector2, Vector3};

use crate::projection::depth_sigma;
use crate::{Frame, RenderView};

/// A back-projected pixel.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BackProjected {
    /// Point in the camera frame, m.
    pub p_c: Vector3<f64>,
    /// Point in the world frame, m.
    pub p_w: Vector3<f64>,
    /// Covariance of `p_c`, m².
    pub cov_c: Matrix3<f64>,
    /// Covariance of `p_w`, m².
    pub cov_w: Matrix3<f64>,
}

/// Back-projects pixel `(u, v)` (pixel-centre convention, ideal pinhole) at depth `z` (m,
/// along the optical axis): `p_c = z K⁻¹ [u, v, 1]ᵀ`, `p_w = R(q_cw)ᵀ p_c + c_w`.
///
/// The covariance is that of the depth alone, `σ_z² m mᵀ` with `m = K⁻¹ [u, v, 1]ᵀ` and
/// `σ_z` from [`depth_sigma`], plus an isotropic pixel uncertainty `sigma_px` (px, 0 for the
/// exact pixel centre a depth buffer samples) propagated through `z K⁻¹`.
pub fn backproject(view: &RenderView, u: f64, v: f64, z: f64, sigma_px: f64) -> BackProjected {
    let n = view.pinhole.to_normalised(Vector2::new(u, v));
    let m = Vector3::new(n.x, n.y, 1.0);
    let p_c = m * z;
    let sz = depth_sigma(z, view.near, view.far);
    let mut cov_c = m * m.transpose() * (sz * sz);
    if sigma_px > 0.0 {
        let k_inv = view
            .pinhole
            .k()
            .try_inverse()
            .unwrap_or_else(Matrix3::zeros);
        // ∂p_c/∂(u, v) = z · first two columns of K⁻¹.
        let j = k_inv.fixed_view::<3, 2>(0, 0) * z;
        cov_c += j * j.transpose() * (sigma_px * sigma_px);
    }
    let r_wc = view.pose.q_cw.inverse().to_rotation_matrix().into_inner();
    BackProjected {
        p_c,
        p_w: r_wc * p_c + view.pose.c_w,
        cov_c,
        cov_w: r_wc * cov_c * r_wc.transpose(),
    }
}

impl Frame {
    /// Back-projects rendered pixel `(u, v)`; `None` on background.
    pub fn backproject(&self, u: u32, v: u32) -> Option<BackProjected> {
        let z = self.depth_at(u, v)?;
        Some(backproject(&self.view, u as f64, v as f64, z, 0.0))
    }
}
