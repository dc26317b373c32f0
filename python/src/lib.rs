//! `vitracker`, the tracker from Python (pyo3, abi3): the `tracker` library's push-driven
//! `Tracker` with numpy frames and IMU samples in and poses out. Its stub `vitracker.pyi`
//! (beside `Cargo.toml`) is the Python user's documentation.
//!
//! - [`error`]: the exceptions, each with the message the command line would print;
//! - [`image`]: numpy frames read as the tracker's grey images; [`matrix`]: numpy matrices;
//! - [`camera`], [`model`], [`pose`]: what a tracker is made of;
//! - [`tracker`]: `Tracker`, its per-frame reports and the IMU's description;
//! - [`locate`]: one cold-start attempt on one image.

mod camera;
mod error;
mod image;
mod locate;
mod matrix;
mod model;
mod pose;
mod tracker;

use pyo3::prelude::*;

/// The module's contents, in the order of the stub.
#[pymodule]
fn vitracker(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("TrackerError", m.py().get_type::<error::TrackerError>())?;
    m.add_class::<camera::Camera>()?;
    m.add_class::<model::Model>()?;
    m.add_class::<pose::Pose>()?;
    m.add_function(wrap_pyfunction!(pose::read_pose, m)?)?;
    m.add_class::<tracker::Imu>()?;
    m.add_class::<tracker::FrameReport>()?;
    m.add_class::<tracker::Tracker>()?;
    m.add_class::<locate::Located>()?;
    m.add_function(wrap_pyfunction!(locate::locate_once, m)?)?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
