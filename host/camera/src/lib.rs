#![deny(missing_docs)]
//! Camera geometry: pinhole intrinsics with skew, lens distortion, undistortion maps,
//! calibration files, the camera pose and its files ([`start_pose`]: a `cMo` in JSON or a TUM
//! line).
//!
//! Pixel convention (as OpenCV and EuRoC/Kalibr): integer pixel coordinates `(u, v)` are pixel
//! **centres**; pixel `(0, 0)` covers `[-0.5, 0.5]²`, `u` grows to the right and `v` downwards.
//! Camera frame (docs/FILTER.md §2, as OpenCV): x right, y down, z forward along the optical axis.

mod calib;
mod distortion;
pub mod frame_file;
mod intrinsics;
mod pinhole;
mod pose;
pub mod start_pose;
mod uncertainty;
mod undistort_map;

pub use calib::{
    CalibError, CameraCalib, parse_euroc_sensor_yaml, parse_kalibr_camchain,
    read_euroc_sensor_yaml, read_kalibr_camchain,
};
pub use distortion::Distortion;
pub use frame_file::{decode_frame, read_frame};
pub use intrinsics::{parse_camera_json, parse_intrinsics, pinhole_camera, read_camera_json};
pub use pinhole::Pinhole;
pub use pose::CameraPose;
pub use uncertainty::{Motion, PoseCovariance, WeakDirection};
pub use undistort_map::{Gray32FImage, UndistortMap};

use nalgebra::{Vector2, Vector3};

/// Invalid camera parameters.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CameraError {
    /// Non-positive focal length or non-finite value.
    #[error("invalid intrinsics: {0}")]
    BadIntrinsics(String),
    /// Non-finite distortion coefficient.
    #[error("invalid distortion coefficients: {0:?}")]
    BadDistortion(Distortion),
    /// Zero or absurd image size.
    #[error("invalid image size {width}x{height}")]
    BadSize {
        /// Width, px.
        width: u32,
        /// Height, px.
        height: u32,
    },
    /// Two poses or directions that cannot define a camera orientation.
    #[error("degenerate camera orientation: {0}")]
    DegeneratePose(&'static str),
}

/// Largest image side accepted (guards allocations driven by file contents).
pub const MAX_IMAGE_SIDE: u32 = 16384;

/// Largest calibration or start pose file read (`sensor.yaml`, camchain, `camera.json`, a
/// start pose), checked from its size before reading: such files are a few kilobytes, so
/// 1 MiB is far past any real one while bounding what a wrong file makes the YAML/JSON
/// readers hold.
pub const MAX_TEXT_FILE_BYTES: u64 = 1 << 20;

/// Reads a small text file, refusing one over [`MAX_TEXT_FILE_BYTES`] before reading it.
pub fn read_text_file(path: &std::path::Path) -> std::io::Result<String> {
    let len = std::fs::metadata(path)?.len();
    if len > MAX_TEXT_FILE_BYTES {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            format!(
                "{len} bytes: too large for a calibration or pose file (at most {MAX_TEXT_FILE_BYTES})"
            ),
        ));
    }
    std::fs::read_to_string(path)
}

/// A calibrated camera: image size, intrinsics and distortion.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    /// Image width, px.
    pub width: u32,
    /// Image height, px.
    pub height: u32,
    /// Intrinsics.
    pub pinhole: Pinhole,
    /// Lens distortion.
    pub distortion: Distortion,
}

impl Camera {
    /// A checked camera.
    pub fn new(
        width: u32,
        height: u32,
        pinhole: Pinhole,
        distortion: Distortion,
    ) -> Result<Self, CameraError> {
        if width == 0 || height == 0 || width > MAX_IMAGE_SIDE || height > MAX_IMAGE_SIDE {
            return Err(CameraError::BadSize { width, height });
        }
        pinhole.validate()?;
        if !distortion.is_finite() {
            return Err(CameraError::BadDistortion(distortion));
        }
        Ok(Self {
            width,
            height,
            pinhole,
            distortion,
        })
    }

    /// The same camera without distortion (what the renderer and undistorted images show).
    pub fn ideal(&self) -> Self {
        Self {
            distortion: Distortion::None,
            ..*self
        }
    }

    /// Projects a point in the camera frame to a (distorted) pixel; `None` behind the camera.
    pub fn project(&self, p_c: Vector3<f64>) -> Option<Vector2<f64>> {
        if p_c.z <= 0.0 {
            return None;
        }
        let n = Vector2::new(p_c.x / p_c.z, p_c.y / p_c.z);
        Some(self.normalised_to_pixel(n))
    }

    /// Undistorted normalised point → distorted pixel.
    pub fn normalised_to_pixel(&self, n: Vector2<f64>) -> Vector2<f64> {
        self.pinhole.to_pixel(self.distortion.distort(n))
    }

    /// Distorted pixel → undistorted normalised point (`m_n` of docs/FILTER.md §2).
    pub fn pixel_to_normalised(&self, p: Vector2<f64>) -> Option<Vector2<f64>> {
        self.distortion.undistort(self.pinhole.to_normalised(p))
    }

    /// Ideal (undistorted) pixel → distorted pixel, both with this camera's `K`.
    pub fn distort_pixel(&self, ideal: Vector2<f64>) -> Vector2<f64> {
        self.normalised_to_pixel(self.pinhole.to_normalised(ideal))
    }

    /// Distorted pixel → ideal (undistorted) pixel, both with this camera's `K`; converged
    /// far below 1e-6 px, `None` where the distortion cannot be inverted.
    pub fn undistort_pixel(&self, distorted: Vector2<f64>) -> Option<Vector2<f64>> {
        self.pixel_to_normalised(distorted)
            .map(|n| self.pinhole.to_pixel(n))
    }
}
