//! Matrices between numpy and nalgebra: 4×4 transforms and 3×3 intrinsics.

use nalgebra::Matrix4;
use numpy::PyArray2;
use numpy::ndarray::Array2;
use pyo3::prelude::*;

use crate::error::value_error;

/// A numpy copy of a matrix.
pub fn matrix<'py, const R: usize, const C: usize>(
    py: Python<'py>,
    m: &nalgebra::SMatrix<f64, R, C>,
) -> Bound<'py, PyArray2<f64>> {
    PyArray2::from_owned_array(py, Array2::from_shape_fn((R, C), |(i, j)| m[(i, j)]))
}

/// A 4×4 matrix from a numpy array or nested sequence (`what` names it in errors).
pub fn matrix4_of(value: &Bound<'_, PyAny>, what: &str) -> PyResult<Matrix4<f64>> {
    let rows: Vec<Vec<f64>> = value
        .call_method1("tolist", ())
        .unwrap_or_else(|_| value.clone())
        .extract()
        .map_err(|_| value_error(format!("{what}: expected a 4×4 matrix of numbers")))?;
    if rows.len() != 4 || rows.iter().any(|r| r.len() != 4) {
        return Err(value_error(format!(
            "{what}: expected a 4×4 matrix, got {} rows of {:?} numbers",
            rows.len(),
            rows.iter().map(Vec::len).collect::<Vec<_>>()
        )));
    }
    Ok(Matrix4::from_fn(|i, j| rows[i][j]))
}
