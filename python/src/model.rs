//! `Model`: a textured (or untextured) triangle model, OBJ + MTL or glTF, in metres.

use std::path::PathBuf;
use std::sync::Arc;

use numpy::PyArray3;
use numpy::ndarray::Array3;
use pyo3::prelude::*;

use crate::error::of_model;

/// A model as the tracker renders it.
#[pyclass(module = "vitracker", frozen)]
#[derive(Debug, Clone)]
pub struct Model {
    /// The meshes and materials.
    pub inner: Arc<model::Model>,
    /// The file it came from.
    pub path: PathBuf,
}

#[pymethods]
impl Model {
    /// Loads an OBJ (`.obj`, with its MTL and textures) or glTF (`.gltf`, `.glb`) file.
    #[new]
    fn new(py: Python<'_>, path: PathBuf) -> PyResult<Self> {
        let inner = py
            .detach(|| model::load(&path))
            .map_err(|e| of_model(&path, e))?;
        Ok(Model {
            inner: Arc::new(inner),
            path,
        })
    }

    /// Its triangles.
    #[getter]
    fn triangles(&self) -> usize {
        self.inner.triangle_count()
    }

    /// Whether a material has a texture (untextured models are tracked by their contour,
    /// from a start pose).
    #[getter]
    fn textured(&self) -> bool {
        self.inner.materials.iter().any(|m| m.texture.is_some())
    }

    /// Its edges as a person would draw them, `(N, 2, 3)` segments in the model's frame [m]:
    /// creases sharper than `angle_deg` and open boundaries.
    #[pyo3(signature = (angle_deg = 30.0))]
    fn edges<'py>(&self, py: Python<'py>, angle_deg: f32) -> Bound<'py, PyArray3<f64>> {
        let e = self.inner.crease_edges(angle_deg.to_radians());
        let a = Array3::from_shape_fn((e.len(), 2, 3), |(i, j, k)| f64::from(e[i][j][k]));
        PyArray3::from_owned_array(py, a)
    }

    fn __repr__(&self) -> String {
        format!(
            "Model({:?}, {} triangles, {})",
            self.path.display().to_string(),
            self.inner.triangle_count(),
            if self.textured() {
                "textured"
            } else {
                "untextured"
            }
        )
    }
}
