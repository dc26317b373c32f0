//! `Camera`: intrinsics and image size, from numbers, a `camera.json`, a EuRoC `sensor.yaml`
//! or a Kalibr camchain; with the mount on the IMU and the frame rate where the file gives them.

use std::path::PathBuf;

use nalgebra::{Matrix4, Vector3};
use numpy::ndarray::Array2;
use numpy::{PyArray2, PyReadonlyArray2};
use pyo3::prelude::*;

use crate::error::{of_calib, value_error};
use crate::matrix::matrix;
use crate::pose::Pose;

/// A calibrated camera.
#[pyclass(module = "vitracker", frozen)]
#[derive(Debug, Clone)]
pub struct Camera {
    /// Intrinsics, distortion and image size.
    pub inner: camera::Camera,
    /// The camera's pose in the IMU's (body) frame, `T_BS`, where the file gives a mount.
    pub t_bs: Option<Matrix4<f64>>,
    /// The frame rate [Hz], where the file gives one.
    pub rate_hz: Option<f64>,
}

impl Camera {
    fn of_calib(c: camera::CameraCalib, t_bs: Option<Matrix4<f64>>) -> Self {
        Camera {
            inner: c.camera,
            t_bs,
            rate_hz: c.rate_hz,
        }
    }
}

/// A distortion from its coefficients' names: `radtan` (k1, k2, p1, p2[, k3]) or
/// `equidistant` (k1, k2, k3, k4).
fn distortion(model: &str, k: &[f64]) -> PyResult<camera::Distortion> {
    match (model, k) {
        ("none", []) => Ok(camera::Distortion::None),
        ("radtan", &[k1, k2, p1, p2]) => Ok(camera::Distortion::RadTan {
            k1,
            k2,
            p1,
            p2,
            k3: 0.0,
        }),
        ("radtan", &[k1, k2, p1, p2, k3]) => Ok(camera::Distortion::RadTan { k1, k2, p1, p2, k3 }),
        ("equidistant", &[k1, k2, k3, k4]) => {
            Ok(camera::Distortion::Equidistant { k1, k2, k3, k4 })
        }
        _ => Err(value_error(format!(
            "distortion {model:?} with {} coefficients: expected \"none\" with none, \"radtan\" with k1, k2, p1, p2[, k3], or \"equidistant\" with k1, k2, k3, k4",
            k.len()
        ))),
    }
}

#[pymethods]
impl Camera {
    /// A camera of `width × height` pixels with focal lengths and principal point [px].
    #[new]
    #[pyo3(signature = (width, height, fx, fy, cx, cy, distortion_model = "none", distortion = vec![], rate_hz = None))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        width: u32,
        height: u32,
        fx: f64,
        fy: f64,
        cx: f64,
        cy: f64,
        distortion_model: &str,
        distortion: Vec<f64>,
        rate_hz: Option<f64>,
    ) -> PyResult<Self> {
        let d = self::distortion(distortion_model, &distortion)?;
        let pinhole = camera::Pinhole::new(fx, fy, cx, cy);
        let inner = match d {
            camera::Distortion::None => camera::pinhole_camera(width, height, pinhole),
            _ => camera::Camera::new(width, height, pinhole, d),
        }
        .map_err(|e| value_error(format!("camera: {e}")))?;
        if let Some(r) = rate_hz.filter(|r| !(r.is_finite() && *r > 0.0)) {
            return Err(value_error(format!(
                "rate_hz must be a positive number of frames per second, got {r}"
            )));
        }
        Ok(Camera {
            inner,
            t_bs: None,
            rate_hz,
        })
    }

    /// A `camera.json` (pinhole, no distortion), as `host-vision --camera` reads it.
    #[staticmethod]
    fn from_json(path: PathBuf) -> PyResult<Self> {
        let inner = camera::read_camera_json(&path).map_err(of_calib)?;
        Ok(Camera {
            inner,
            t_bs: None,
            rate_hz: None,
        })
    }

    /// A EuRoC/ASL `sensor.yaml`: intrinsics, distortion, `T_BS` and `rate_hz`.
    #[staticmethod]
    fn from_euroc(path: PathBuf) -> PyResult<Self> {
        let c = camera::read_euroc_sensor_yaml(&path).map_err(of_calib)?;
        let t_bs = c.extrinsics;
        Ok(Self::of_calib(c, t_bs))
    }

    /// Camera `index` of a Kalibr camchain YAML; its `T_cam_imu` gives the mount.
    #[staticmethod]
    #[pyo3(signature = (path, index = 0))]
    fn from_kalibr(path: PathBuf, index: usize) -> PyResult<Self> {
        let mut cams = camera::read_kalibr_camchain(&path).map_err(of_calib)?;
        let n = cams.len();
        if index >= n {
            return Err(value_error(format!(
                "{}: no camera {index}: the camchain holds {n}",
                path.display()
            )));
        }
        let c = cams.swap_remove(index);
        let t_bs = match c.extrinsics {
            None => None,
            Some(t_cam_imu) => Some(t_cam_imu.try_inverse().ok_or_else(|| {
                value_error(format!("{}: T_cam_imu is singular", path.display()))
            })?),
        };
        Ok(Self::of_calib(c, t_bs))
    }

    /// Image width [px].
    #[getter]
    fn width(&self) -> u32 {
        self.inner.width
    }

    /// Image height [px].
    #[getter]
    fn height(&self) -> u32 {
        self.inner.height
    }

    /// The 3×3 intrinsic matrix `K`.
    #[getter]
    fn k<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        matrix(py, &self.inner.pinhole.k())
    }

    /// The camera's pose in the IMU's frame (`T_BS`, 4×4), or None.
    #[getter]
    fn t_bs<'py>(&self, py: Python<'py>) -> Option<Bound<'py, PyArray2<f64>>> {
        self.t_bs.as_ref().map(|t| matrix(py, t))
    }

    /// The frame rate [Hz] the file gives, or None.
    #[getter]
    fn rate_hz(&self) -> Option<f64> {
        self.rate_hz
    }

    /// Pixels `(N, 2)` of model points `(N, 3)` [m] seen from `pose`, lens distortion
    /// applied; NaN for points behind the camera.
    fn project<'py>(
        &self,
        py: Python<'py>,
        pose: &Pose,
        points: PyReadonlyArray2<'py, f64>,
    ) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let p = points.as_array();
        if p.ncols() != 3 {
            return Err(value_error(format!(
                "points: shape {:?}, expected (N, 3)",
                p.shape()
            )));
        }
        let mut out = Array2::from_elem((p.nrows(), 2), f64::NAN);
        for (r, mut o) in p.rows().into_iter().zip(out.rows_mut()) {
            let x_c = pose.camera.world_to_camera(&Vector3::new(r[0], r[1], r[2]));
            if let Some(u) = self.inner.project(x_c) {
                o[0] = u.x;
                o[1] = u.y;
            }
        }
        Ok(PyArray2::from_owned_array(py, out))
    }

    fn __repr__(&self) -> String {
        let p = &self.inner.pinhole;
        format!(
            "Camera({}x{}, fx={}, fy={}, cx={}, cy={}, distortion={:?})",
            self.inner.width, self.inner.height, p.fx, p.fy, p.cx, p.cy, self.inner.distortion
        )
    }
}
