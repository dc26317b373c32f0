//! Pinhole intrinsics with skew (docs/FILTER.md §2).

use nalgebra::{Matrix3, Vector2};

use super::CameraError;

/// Pinhole intrinsics `K = [[fx, s, cx], [0, fy, cy], [0, 0, 1]]`, in pixels.
///
/// Pixel convention (as OpenCV and EuRoC/Kalibr): integer pixel coordinates `(u, v)` are pixel
/// **centres**; pixel `(0, 0)` covers `[-0.5, 0.5]²`; `u` grows to the right, `v` downwards.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pinhole {
    /// Focal length along u, px.
    pub fx: f64,
    /// Focal length along v, px.
    pub fy: f64,
    /// Principal point u, px.
    pub cx: f64,
    /// Principal point v, px.
    pub cy: f64,
    /// Skew `s` (K[0][1]), px.
    pub skew: f64,
}

impl Pinhole {
    /// Intrinsics without skew.
    pub fn new(fx: f64, fy: f64, cx: f64, cy: f64) -> Self {
        Self {
            fx,
            fy,
            cx,
            cy,
            skew: 0.0,
        }
    }

    /// The same intrinsics with skew `s`.
    pub fn with_skew(self, skew: f64) -> Self {
        Self { skew, ..self }
    }

    /// Checks that the focal lengths are positive and everything is finite.
    pub fn validate(&self) -> Result<(), CameraError> {
        // Each wrong value by name (issue 33: the whole struct was printed as a debug dump).
        let named = [
            ("fx", self.fx),
            ("fy", self.fy),
            ("cx", self.cx),
            ("cy", self.cy),
            ("skew", self.skew),
        ];
        if let Some((name, v)) = named.iter().find(|(_, v)| !v.is_finite()) {
            return Err(CameraError::BadIntrinsics(format!(
                "{name} must be a finite number of pixels, got {v}"
            )));
        }
        if let Some((name, v)) = named[..2].iter().find(|(_, v)| *v <= 0.0) {
            return Err(CameraError::BadIntrinsics(format!(
                "the focal length {name} must be positive [px], got {v}"
            )));
        }
        Ok(())
    }

    /// The matrix `K`.
    pub fn k(&self) -> Matrix3<f64> {
        Matrix3::new(
            self.fx, self.skew, self.cx, 0.0, self.fy, self.cy, 0.0, 0.0, 1.0,
        )
    }

    /// Normalised image point → pixel: `K [x, y, 1]ᵀ`.
    pub fn to_pixel(&self, n: Vector2<f64>) -> Vector2<f64> {
        Vector2::new(
            self.fx * n.x + self.skew * n.y + self.cx,
            self.fy * n.y + self.cy,
        )
    }

    /// Pixel → normalised image point: `K⁻¹ [u, v, 1]ᵀ`.
    pub fn to_normalised(&self, p: Vector2<f64>) -> Vector2<f64> {
        let y = (p.y - self.cy) / self.fy;
        Vector2::new((p.x - self.cx - self.skew * y) / self.fx, y)
    }
}
