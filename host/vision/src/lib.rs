#![deny(missing_docs)]
//! One camera frame through the vision host (docs/ARCHITECTURE.md §3, docs/VISION.md): the live
//! image undistorted, the model rendered at the predicted pose, features registered with the
//! photometric KLT, outliers dropped, correspondences made ([`analysis`], [`Vision`]); and the
//! pose estimated with the frame judged without ground truth ([`assess`], [`TrackedRule`]); for
//! objects without texture, or beside it, the model's contour ([`contours`], docs/VISION.md
//! §9).
//!
//! The cold start (`locate`) and the tracker build on it.

pub mod analysis;
pub mod assess;
pub mod contours;

pub use analysis::{
    FrameImage, FrameJob, FrameResult, Verified, Vision, VisionOptions, prediction_pose,
};
pub use assess::{
    Assessment, Consistency, Contrast, RegistrationCov, TrackedRule, Verdicts, registration_chi2,
    success_bound_m,
};
pub use contours::{Modality, is_textured};

use std::path::PathBuf;

/// Why a frame could not be analysed, or the analysis could not start.
#[derive(Debug, thiserror::Error)]
pub enum VisionError {
    /// The renderer failed.
    #[error(transparent)]
    Render(#[from] render::RenderError),
    /// A camera parameter is invalid.
    #[error(transparent)]
    Camera(#[from] camera::CameraError),
    /// An image has no pixels or is too large.
    #[error(transparent)]
    Features(#[from] features::ImageError),
    /// A live image could not be read.
    #[error("{path}: {source}")]
    Image {
        /// File.
        path: PathBuf,
        /// Cause.
        #[source]
        source: image::ImageError,
    },
    /// A live image has the wrong size.
    #[error("{path}: the image is {}x{} pixels, the calibration's are {}x{}", got.0, got.1, expected.0, expected.1)]
    ImageSize {
        /// File (or the frame's name).
        path: PathBuf,
        /// Its size.
        got: (u32, u32),
        /// The calibration's.
        expected: (u32, u32),
    },
    /// The core predicted a pose that is no rotation and position.
    #[error("core: frame {frame_id}: bad predicted pose: {source}")]
    BadPrediction {
        /// The frame's id.
        frame_id: u32,
        /// What is wrong with it.
        #[source]
        source: camera::CameraError,
    },
}
