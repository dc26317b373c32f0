//! Registered features → the fusion core's 2D/3D correspondences (docs/ARCHITECTURE.md §3,
//! docs/FILTER.md §5).
//!
//! A registered pixel becomes the undistorted normalised point `m_n` of docs/FILTER.md §2; its
//! covariance follows through the Jacobian of the camera model (`Σ_n = A Σ_p Aᵀ` with
//! `A = ∂m_n/∂p`, the inverse of the forward model's Jacobian), and it is paired with the
//! feature's model point `m_w` and covariance.

use nalgebra::{Matrix2, Matrix3, Vector2, Vector3};
use protocol::{Correspondence, Correspondences, TooManyCorrespondences};

use camera::Camera;

/// A registered point that cannot become a correspondence.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum CorrespondenceError {
    /// Non-finite pixel, point or covariance.
    #[error("non-finite input")]
    NotFinite,
    /// The camera model cannot be inverted at this pixel.
    #[error("pixel outside the invertible region of the camera model")]
    NotInvertible,
    /// A covariance that is not positive semi-definite.
    #[error("covariance not positive semi-definite")]
    BadCovariance,
}

/// `∂p/∂m_n` of the forward model (undistorted normalised point → distorted pixel) at `n`,
/// by central differences. The model is smooth and evaluated in `f64`: with a step of 1e-6
/// normalised units the truncation and round-off errors are ~1e-10 relative, far below any
/// pixel covariance.
fn forward_jacobian(camera: &Camera, n: Vector2<f64>) -> Matrix2<f64> {
    const H: f64 = 1e-6;
    let dx = (camera.normalised_to_pixel(n + Vector2::new(H, 0.0))
        - camera.normalised_to_pixel(n - Vector2::new(H, 0.0)))
        / (2.0 * H);
    let dy = (camera.normalised_to_pixel(n + Vector2::new(0.0, H))
        - camera.normalised_to_pixel(n - Vector2::new(0.0, H)))
        / (2.0 * H);
    Matrix2::from_columns(&[dx, dy])
}

fn psd2(m: &Matrix2<f64>) -> bool {
    m[(0, 0)] >= 0.0 && m[(1, 1)] >= 0.0 && m.determinant() >= -1e-12 * m.norm_squared()
}

/// Pixel `pixel` of `camera`'s image with covariance `cov_px` (px²) → undistorted normalised
/// point and its covariance.
pub fn pixel_to_normalised(
    camera: &Camera,
    pixel: Vector2<f64>,
    cov_px: &Matrix2<f64>,
) -> Result<(Vector2<f64>, Matrix2<f64>), CorrespondenceError> {
    if !pixel.iter().chain(cov_px.iter()).all(|v| v.is_finite()) {
        return Err(CorrespondenceError::NotFinite);
    }
    if !psd2(cov_px) {
        return Err(CorrespondenceError::BadCovariance);
    }
    let n = camera
        .pixel_to_normalised(pixel)
        .ok_or(CorrespondenceError::NotInvertible)?;
    let a = forward_jacobian(camera, n)
        .try_inverse()
        .ok_or(CorrespondenceError::NotInvertible)?;
    let cov = a * cov_px * a.transpose();
    // Symmetrise against round-off before packing as an upper triangle.
    let cov = (cov + cov.transpose()) * 0.5;
    if !cov.iter().all(|v| v.is_finite()) {
        return Err(CorrespondenceError::NotInvertible);
    }
    Ok((n, cov))
}

/// One correspondence: registered `pixel` (covariance `cov_px`, px²) with model point `p_w`
/// (covariance `cov_w`, m²).
pub fn correspondence(
    camera: &Camera,
    pixel: Vector2<f64>,
    cov_px: &Matrix2<f64>,
    p_w: &Vector3<f64>,
    cov_w: &Matrix3<f64>,
) -> Result<Correspondence, CorrespondenceError> {
    if !p_w.iter().chain(cov_w.iter()).all(|v| v.is_finite()) {
        return Err(CorrespondenceError::NotFinite);
    }
    let (n, cov_n) = pixel_to_normalised(camera, pixel, cov_px)?;
    let c = Correspondence {
        m_n: [n.x as f32, n.y as f32],
        cov_n: [
            cov_n[(0, 0)] as f32,
            cov_n[(0, 1)] as f32,
            cov_n[(1, 1)] as f32,
        ],
        m_w: [p_w.x as f32, p_w.y as f32, p_w.z as f32],
        cov_w: [
            cov_w[(0, 0)] as f32,
            (0.5 * (cov_w[(0, 1)] + cov_w[(1, 0)])) as f32,
            (0.5 * (cov_w[(0, 2)] + cov_w[(2, 0)])) as f32,
            cov_w[(1, 1)] as f32,
            (0.5 * (cov_w[(1, 2)] + cov_w[(2, 1)])) as f32,
            cov_w[(2, 2)] as f32,
        ],
    };
    // The f32 values must still be finite (huge f64 covariances overflow).
    let finite = c.m_n.iter().chain(&c.cov_n).chain(&c.m_w).chain(&c.cov_w);
    if !finite.clone().all(|v| v.is_finite()) {
        return Err(CorrespondenceError::NotFinite);
    }
    if !(protocol::validate::psd2(&c.cov_n) && protocol::validate::psd3(&c.cov_w)) {
        return Err(CorrespondenceError::BadCovariance);
    }
    Ok(c)
}

/// One frame's correspondences as protocol messages (as many parts as needed).
pub fn frame_messages(
    frame_id: u32,
    trigger_us: u64,
    all: &[Correspondence],
) -> Result<Vec<Correspondences>, TooManyCorrespondences> {
    Ok(Correspondences::split(frame_id, trigger_us, all)?.collect())
}
