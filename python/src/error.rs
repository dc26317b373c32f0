//! The exceptions: Python's own where one fits (`ValueError` for a wrong dtype, shape, size,
//! order or setting; `FileNotFoundError` for a missing file), and [`TrackerError`] for the rest.
//! Each carries the message the command line prints for the same fault.

use pyo3::PyErr;
use pyo3::create_exception;
use pyo3::exceptions::{PyException, PyFileNotFoundError, PyValueError};

create_exception!(
    vitracker,
    TrackerError,
    PyException,
    "The tracker could not start, stopped, or lost its core: everything that is not a wrong argument or a missing file."
);

/// A `ValueError` with `message`.
pub fn value_error(message: impl Into<String>) -> PyErr {
    PyValueError::new_err(message.into())
}

/// The exception of a tracker's error.
pub fn of_tracker(e: tracker::TrackerError) -> PyErr {
    use tracker::TrackerError as E;
    let message = e.to_string();
    match e {
        E::ImageSize { .. }
        | E::TimeBackwards { .. }
        | E::NoTrigger { .. }
        | E::Config(_)
        | E::LatencyTooLong { .. }
        | E::NeedsStartPose => PyValueError::new_err(message),
        _ => TrackerError::new_err(message),
    }
}

/// The exception of a calibration file's error: a missing file, or a file that cannot be
/// used.
pub fn of_calib(e: camera::CalibError) -> PyErr {
    match &e {
        camera::CalibError::Io { source, .. } if source.kind() == std::io::ErrorKind::NotFound => {
            PyFileNotFoundError::new_err(e.to_string())
        }
        _ => PyValueError::new_err(e.to_string()),
    }
}

/// The exception of a model file's error.
pub fn of_model(path: &std::path::Path, e: model::ModelError) -> PyErr {
    let message = match &e {
        // It names the file already.
        model::ModelError::MissingFile { .. } => e.to_string(),
        _ => format!("model {}: {e}", path.display()),
    };
    match e {
        model::ModelError::MissingFile { .. } | model::ModelError::MissingTexture { .. } => {
            PyFileNotFoundError::new_err(message)
        }
        _ => PyValueError::new_err(message),
    }
}

/// The exception of a start pose file's error.
pub fn of_start_pose(path: &std::path::Path, e: camera::start_pose::StartPoseError) -> PyErr {
    let message = format!("start pose {}: {e}", path.display());
    match e {
        camera::start_pose::StartPoseError::Io(io) if io.kind() == std::io::ErrorKind::NotFound => {
            PyFileNotFoundError::new_err(message)
        }
        _ => PyValueError::new_err(message),
    }
}
