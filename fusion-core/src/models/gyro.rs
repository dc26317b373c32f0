//! Gyroscope measurement (eq. 9): `y_ω = ω_s + b_ω + v_yω`.

use nalgebra::Vector3;

use crate::ekf::SparseRow;
use crate::scalar::Scalar;
use crate::state::{GYRO_BIAS, OMEGA, State};

/// Predicted gyro reading.
pub fn predict<T: Scalar>(st: &State<T>) -> Vector3<T> {
    st.v3(OMEGA) + st.v3(GYRO_BIAS)
}

/// Jacobian row of axis `k`.
pub fn row<T: Scalar>(k: usize) -> SparseRow<T> {
    let mut h = SparseRow::default();
    h.push(OMEGA + k, T::one());
    h.push(GYRO_BIAS + k, T::one());
    h
}
