//! Accelerometer measurement.
//!
//! - gravity model (eq. 13): `y_a = R(q_sw)(−g_w) + b_a + v_ya` (free acceleration is noise);
//! - acc model (eq. 16): `y_a = R(q_sw)(s̈_w − g_w) + b_a + v_ya`.
//!
//! The gyro model does not use the accelerometer.

use nalgebra::{Matrix3, Matrix3x4, Vector3};
use protocol::ModelKind;

use crate::ekf::SparseRow;
use crate::quat;
use crate::scalar::Scalar;
use crate::state::{ACC, ACC_BIAS, QUAT, State};

/// Magnitude of gravity [m/s²]; `g_w = [0, 0, −GRAVITY]` (docs/FILTER.md §2).
pub const GRAVITY: f64 = 9.81;

/// `s̈_w − g_w` (the free acceleration is zero in the gravity model's state).
fn specific_force_world<T: Scalar>(st: &State<T>) -> Vector3<T> {
    st.v3(ACC) + Vector3::new(T::zero(), T::zero(), T::c(GRAVITY))
}

/// Predicted accelerometer reading.
pub fn predict<T: Scalar>(st: &State<T>) -> Vector3<T> {
    quat::rot(&st.q().normalize()) * specific_force_world(st) + st.v3(ACC_BIAS)
}

/// Jacobian row of axis `k`.
pub fn row<T: Scalar>(st: &State<T>, model: ModelKind, k: usize) -> SparseRow<T> {
    rows(st, model)[k]
}

/// Jacobian blocks of all three axes at the state: `∂y_a/∂q_sw` (3×4) and `∂y_a/∂s̈_w`
/// (`R(q_sw)`; zero in the gravity model). `∂y_a/∂b_a = I`; all other blocks are zero.
pub fn jacobian<T: Scalar>(st: &State<T>, model: ModelKind) -> (Matrix3x4<T>, Matrix3<T>) {
    let q = st.q().normalize();
    let d_q = quat::d_rotate_dq(&q, &specific_force_world(st));
    let d_acc = if model == ModelKind::Acc {
        quat::rot(&q)
    } else {
        Matrix3::zeros()
    };
    (d_q, d_acc)
}

/// Jacobian rows of all three axes at the state.
pub fn rows<T: Scalar>(st: &State<T>, model: ModelKind) -> [SparseRow<T>; 3] {
    let (d_q, d_acc) = jacobian(st, model);
    rows_of(&d_q, &d_acc, model)
}

/// Jacobian rows of all three axes from the blocks of [`jacobian`].
pub fn rows_of<T: Scalar>(
    d_q: &Matrix3x4<T>,
    d_acc: &Matrix3<T>,
    model: ModelKind,
) -> [SparseRow<T>; 3] {
    core::array::from_fn(|k| {
        let mut h = SparseRow::default();
        for c in 0..4 {
            h.push(QUAT + c, d_q[(k, c)]);
        }
        if model == ModelKind::Acc {
            for c in 0..3 {
                h.push(ACC + c, d_acc[(k, c)]);
            }
        }
        h.push(ACC_BIAS + k, T::one());
        h
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::{params, random_state};
    use approx::assert_relative_eq;

    #[test]
    fn jacobians_match_central_differences() {
        for model in [ModelKind::Gravity, ModelKind::Acc] {
            let prm = params::<f64>(model);
            let st = random_state(prm.n, 11);
            for k in 0..3 {
                let h = row(&st, model, k).dense();
                for j in 0..prm.n {
                    let mut plus = st.clone();
                    let mut minus = st.clone();
                    plus.x[j] += 1e-6;
                    minus.x[j] -= 1e-6;
                    let fd = (predict(&plus)[k] - predict(&minus)[k]) / 2e-6;
                    assert_relative_eq!(h[j], fd, epsilon = 1e-7);
                }
            }
        }
    }

    #[test]
    fn gyro_jacobian_matches_central_differences() {
        let prm = params::<f64>(ModelKind::Gyro);
        let st = random_state(prm.n, 12);
        for k in 0..3 {
            let h = crate::models::gyro::row::<f64>(k).dense();
            for j in 0..prm.n {
                let mut plus = st.clone();
                let mut minus = st.clone();
                plus.x[j] += 1e-6;
                minus.x[j] -= 1e-6;
                let fd = (crate::models::gyro::predict(&plus)[k]
                    - crate::models::gyro::predict(&minus)[k])
                    / 2e-6;
                assert_relative_eq!(h[j], fd, epsilon = 1e-8);
            }
        }
    }

    #[test]
    fn level_and_still_reads_plus_g_on_the_up_axis() {
        let st = State::<f64>::default();
        assert_relative_eq!(
            predict(&st),
            Vector3::new(0.0, 0.0, GRAVITY),
            epsilon = 1e-12
        );
    }
}
