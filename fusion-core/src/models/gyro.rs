//! Gyroscope measurement (eq. 9): `y_ω = ω_s + b_ω + v_yω`.

use nalgebra::{SMatrix, SVector, Vector3};

use crate::ekf::{SparseRow, UpdateError, innovation, joseph_update};
use crate::params::Params;
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

/// Applies one gyro sample, one axis at a time (the noise is uncorrelated across axes).
pub fn update<T: Scalar>(
    st: &mut State<T>,
    prm: &Params<T>,
    y: &Vector3<T>,
) -> Result<(), UpdateError> {
    let r = SMatrix::<T, 1, 1>::new(prm.r_gyro);
    for k in 0..3 {
        let h = [row::<T>(k)];
        let z = SVector::<T, 1>::new(y[k] - predict(st)[k]);
        let (u, s) = innovation(st, prm.n, &h, &r);
        joseph_update(st, prm.n, &u, &s, &z)?;
    }
    Ok(())
}
