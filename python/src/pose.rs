//! `Pose`: the camera's pose in the model's frame, as the 4×4 `cMo` (model → camera) and as
//! a TUM position and quaternion; and the start pose a tracker takes.

use std::path::PathBuf;

use camera::start_pose::{cmo_of_pose, pose_of_cmo, read_start_pose};
use camera::{CameraPose, PoseCovariance};
use numpy::PyArray1;
use numpy::PyArray2;
use pyo3::prelude::*;

use crate::error::{of_start_pose, value_error};
use crate::matrix::{matrix, matrix4_of};

/// A camera pose in the model's frame (which is the world frame of tracking).
#[pyclass(module = "vitracker", frozen)]
#[derive(Debug, Clone, Copy)]
pub struct Pose {
    /// The pose.
    pub camera: CameraPose,
    /// Its time [s from the first frame or sample], where it is an estimate.
    pub t: Option<f64>,
    /// The core's covariance of it, where it is an estimate.
    pub cov: Option<PoseCovariance>,
}

#[pymethods]
impl Pose {
    /// The pose of a rigid 4×4 `cMo` (model → camera, metres): `X_c = R X_o + t`.
    #[new]
    fn new(c_m_o: &Bound<'_, PyAny>) -> PyResult<Self> {
        let m = matrix4_of(c_m_o, "cMo")?;
        let camera = pose_of_cmo(&m).map_err(|e| value_error(format!("start pose: {e}")))?;
        Ok(Pose {
            camera,
            t: None,
            cov: None,
        })
    }

    /// The 4×4 `cMo` (model → camera).
    #[getter]
    fn matrix<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        matrix(py, &cmo_of_pose(&self.camera))
    }

    /// The camera's centre in the model's frame [m] (TUM's `tx ty tz`).
    #[getter]
    fn position<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, self.camera.c_w.as_slice())
    }

    /// The camera's orientation in the model's frame, camera → model, as `(x, y, z, w)`
    /// (TUM's `qx qy qz qw`).
    #[getter]
    fn quaternion<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        let q = self.camera.q_cw.inverse();
        PyArray1::from_slice(py, &[q.i, q.j, q.k, q.w])
    }

    /// Its time [s from the first frame or sample]; None for a pose that is no estimate.
    #[getter]
    fn t(&self) -> Option<f64> {
        self.t
    }

    /// The core's 6×6 covariance of `[position, θ]` [m², rad²]: `position` as above, θ the
    /// orientation's error as a rotation vector in the model's frame (docs/VISION.md
    /// eq. T6); None for a pose that is no estimate.
    #[getter]
    fn covariance<'py>(&self, py: Python<'py>) -> Option<Bound<'py, PyArray2<f64>>> {
        let m = self.cov?;
        let rows: Vec<Vec<f64>> = m
            .matrix()
            .row_iter()
            .map(|r| r.iter().copied().collect())
            .collect();
        PyArray2::from_vec2(py, &rows).ok()
    }

    /// The TUM line `t tx ty tz qx qy qz qw` (time 0 where the pose has none).
    fn tum(&self) -> String {
        let c = self.camera.c_w;
        let q = self.camera.q_cw.inverse();
        format!(
            "{:.6} {:.9} {:.9} {:.9} {:.9} {:.9} {:.9} {:.9}",
            self.t.unwrap_or(0.0),
            c.x,
            c.y,
            c.z,
            q.i,
            q.j,
            q.k,
            q.w
        )
    }

    fn __repr__(&self) -> String {
        let c = self.camera.c_w;
        let (r, p, y) = self.camera.q_cw.inverse().euler_angles();
        let t = self.t.map_or(String::new(), |t| format!("t={t:.6} s, "));
        format!(
            "Pose({t}position=[{:.4}, {:.4}, {:.4}] m, roll/pitch/yaw=[{:.2}, {:.2}, {:.2}]°)",
            c.x,
            c.y,
            c.z,
            r.to_degrees(),
            p.to_degrees(),
            y.to_degrees()
        )
    }
}

/// Reads a start pose file: JSON with a 4×4 `cMo`, or one TUM line (as `host-vision track
/// --start-pose` does).
#[pyfunction]
pub fn read_pose(path: PathBuf) -> PyResult<Pose> {
    let camera = read_start_pose(&path).map_err(|e| of_start_pose(&path, e))?;
    Ok(Pose {
        camera,
        t: None,
        cov: None,
    })
}

/// The start pose a tracker is given: a [`Pose`], a 4×4 `cMo`, or a start pose file.
pub fn start_pose_of(value: &Bound<'_, PyAny>) -> PyResult<CameraPose> {
    if let Ok(p) = value.cast::<Pose>() {
        return Ok(p.get().camera);
    }
    if let Ok(path) = value.extract::<PathBuf>() {
        return read_pose(path).map(|p| p.camera);
    }
    Pose::new(value).map(|p| p.camera)
}
