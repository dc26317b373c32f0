//! `locate(image, model, camera)`: one cold-start attempt on one image, as `host-vision
//! locate` makes it: the pose, where one verifies, and the attempt's figures.

use std::path::PathBuf;

use ::locate::database::{Database, DatabaseConfig, Provenance};
use ::locate::{LocateConfig, Locator};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use vision::Vision;

use crate::camera::Camera;
use crate::error::{TrackerError, value_error};
use crate::image::{Channels, gray_of};
use crate::model::Model;
use crate::pose::Pose;

/// What an attempt found.
#[pyclass(module = "vitracker", frozen)]
#[derive(Debug, Clone)]
pub struct Located {
    /// The verified pose, or None.
    #[pyo3(get)]
    pose: Option<Pose>,
    /// ORB keypoints of the image.
    #[pyo3(get)]
    keypoints: usize,
    /// Matches that passed the ratio and mutual tests.
    #[pyo3(get)]
    matches: usize,
    /// RANSAC's inliers (0 without a pose).
    #[pyo3(get)]
    inliers: usize,
    /// Features the verification registered.
    #[pyo3(get)]
    registered: usize,
    /// Their reprojection rms at the verified pose [px].
    #[pyo3(get)]
    rms_px: Option<f64>,
    /// Rendered-against-live correlation at the verified pose.
    #[pyo3(get)]
    ncc: Option<f64>,
    /// Whether two plausible poses could not be told apart (the attempt refused both).
    #[pyo3(get)]
    ambiguous: bool,
    /// Stage times [s].
    stage_times: ::locate::AttemptTimes,
    /// The viewpoint database's cache file.
    #[pyo3(get)]
    database: PathBuf,
    /// Why the database was built, or None where it was read from the cache.
    #[pyo3(get)]
    database_built_because: Option<String>,
}

#[pymethods]
impl Located {
    /// Stage times [s]: detect, matching, ransac, verify, choose.
    #[getter]
    fn times<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let times = PyDict::new(py);
        let t = self.stage_times;
        for (k, v) in [
            ("detect", t.detect),
            ("matching", t.matching),
            ("ransac", t.ransac),
            ("verify", t.verify),
            ("choose", t.choose),
        ] {
            times.set_item(k, v)?;
        }
        Ok(times)
    }

    /// Whether a pose was accepted.
    #[getter]
    fn accepted(&self) -> bool {
        self.pose.is_some()
    }

    fn __repr__(&self) -> String {
        format!(
            "Located(accepted={}, keypoints={}, matches={}, inliers={}, registered={}, rms_px={:?})",
            self.pose.is_some(),
            self.keypoints,
            self.matches,
            self.inliers,
            self.registered,
            self.rms_px
        )
    }
}

/// One cold-start attempt on `image` (see the stub). The viewpoint database is built on the
/// model's first attempt (minutes) and read back from `cache` after.
#[pyfunction(name = "locate")]
#[pyo3(signature = (image, model, camera, *, cache = None, channels = "bgr"))]
pub fn locate_once(
    py: Python<'_>,
    image: &Bound<'_, PyAny>,
    model: &Model,
    camera: &Camera,
    cache: Option<PathBuf>,
    channels: &str,
) -> PyResult<Located> {
    let raw = gray_of(image, Channels::parse(channels)?, "image")?;
    let cam = camera.inner;
    if raw.dimensions() != (cam.width, cam.height) {
        return Err(value_error(format!(
            "image: {}x{} pixels, but the camera is {}x{}",
            raw.width(),
            raw.height(),
            cam.width,
            cam.height
        )));
    }
    if !vision::is_textured(&model.inner) {
        return Err(value_error(
            "the model has no textured material: the cold start finds a model by its texture, so an untextured model needs a start pose",
        ));
    }
    let cache = cache.unwrap_or_else(::locate::database::default_cache_dir);
    let m = model.inner.clone();
    let (attempt, path, built) = py
        .detach(move || -> Result<_, String> {
            let (db, provenance) =
                Database::load_or_build(&m, &DatabaseConfig::default(), &cache, &mut |_, _| {})
                    .map_err(|e| format!("cold start: {e}"))?;
            let (path, built) = match provenance {
                Provenance::Cached(path) => (path, None),
                Provenance::Built { path, why } => (path, Some(why)),
            };
            let mut vision =
                Vision::new(cam, &m, ::locate::vision_options()).map_err(|e| e.to_string())?;
            let locator = Locator::new(&db, LocateConfig::default());
            let (attempt, _) = locator
                .attempt(&mut vision, &raw, false)
                .map_err(|e| e.to_string())?;
            Ok((attempt, path, built))
        })
        .map_err(TrackerError::new_err)?;
    Ok(Located {
        pose: attempt.pose.map(|camera| Pose {
            camera,
            t: None,
            cov: None,
        }),
        keypoints: attempt.keypoints,
        matches: attempt.matches,
        inliers: attempt.inliers,
        registered: attempt.registered,
        rms_px: attempt.rms_px,
        ncc: attempt.ncc,
        ambiguous: attempt.ambiguous,
        stage_times: attempt.times,
        database: path,
        database_built_because: built,
    })
}
