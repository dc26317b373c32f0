//! Time update (eq. 7, 12, 15).
//!
//! - gyro, gravity (constant velocity): `s ← s + ṡT`, `ṡ ← ṡ + v_s̈ T`
//! - acc (constant acceleration): `s ← s + ṡT + s̈T²/2`, `ṡ ← ṡ + s̈T`, `s̈ ← s̈ + v`
//! - all: `q ← exp(−T/2 · ω) ⊙ q`, `ω ← ω + v_ω`, biases random walks.
//!
//! Process noises are continuous-time white-noise densities; their exact discretisation over
//! `T` gives the `Q` blocks below (integrated white acceleration / jerk / angular acceleration).

use nalgebra::{Matrix4, Matrix4x3, SMatrix};
use protocol::ModelKind;

use crate::params::Params;
use crate::quat;
use crate::scalar::Scalar;
use crate::state::{ACC, ACC_BIAS, GYRO_BIAS, N, OMEGA, POS, QUAT, State, VEL};

/// Normalises the quaternion before a time update (as the paper does) and returns
/// `|‖q‖ − 1|` before normalisation, for the divergence monitor.
pub fn normalise_quaternion<T: Scalar>(st: &mut State<T>) -> T {
    let q = st.q();
    let norm = q.norm();
    if norm > T::zero() {
        st.set_q(&(q / norm));
    }
    (norm - T::one()).abs()
}

/// Propagates mean and covariance over `dt` seconds (eq. 7 / 12 / 15).
pub fn time_update<T: Scalar>(st: &mut State<T>, prm: &Params<T>, dt: T) {
    let n = prm.n;
    let acc_model = prm.model == ModelKind::Acc;
    let half_dt2 = dt * dt * T::c(0.5);

    // Mean.
    let q = st.q();
    let omega = st.v3(OMEGA);
    let (dq, d_dq_domega) = quat::exp_increment(&omega, dt);
    let v = st.v3(VEL);
    let a = st.v3(ACC);
    let s = st.v3(POS);
    st.set_v3(POS, &(s + v * dt + a * half_dt2));
    st.set_v3(VEL, &(v + a * dt));
    st.set_q(&quat::mul(&dq, &q));

    // Jacobian blocks of F = I + ΔF: ∂q'/∂q = L(δq), ∂q'/∂ω = R(q) ∂δq/∂ω.
    let f_qq: Matrix4<T> = quat::left(&dq);
    let f_qw: Matrix4x3<T> = quat::right(&q) * d_dq_domega;

    propagate_covariance(st, n, acc_model, dt, &f_qq, &f_qw);
    add_process_noise(st, prm, dt, &f_qw);
}

/// `P ← F P Fᵀ`, touching only the rows and columns where `F` differs from the identity, on
/// contiguous columns of the column-major storage.
fn propagate_covariance<T: Scalar>(
    st: &mut State<T>,
    n: usize,
    acc_model: bool,
    dt: T,
    f_qq: &Matrix4<T>,
    f_qw: &Matrix4x3<T>,
) {
    let half_dt2 = dt * dt * T::c(0.5);
    // Plain arrays: the loops below index them n times per entry.
    let mut fq = [[T::zero(); 7]; 4];
    for (r, row) in fq.iter_mut().enumerate() {
        for c in 0..4 {
            row[c] = f_qq[(r, c)];
        }
        for c in 0..3 {
            row[4 + c] = f_qw[(r, c)];
        }
    }
    let p = st.p.as_mut_slice();
    // Rows: M = F P, applied within each column. Position first (it reads the old velocity).
    for chunk in p.chunks_exact_mut(N).take(n) {
        let Ok(col) = <&mut [T; N]>::try_from(chunk) else {
            continue;
        };
        for k in 0..3 {
            let mut pos = col[POS + k] + col[VEL + k] * dt;
            if acc_model {
                pos += col[ACC + k] * half_dt2;
                col[VEL + k] += col[ACC + k] * dt;
            }
            col[POS + k] = pos;
        }
        let old = [
            col[QUAT],
            col[QUAT + 1],
            col[QUAT + 2],
            col[QUAT + 3],
            col[OMEGA],
            col[OMEGA + 1],
            col[OMEGA + 2],
        ];
        for (r, f) in fq.iter().enumerate() {
            col[QUAT + r] = f
                .iter()
                .zip(&old)
                .fold(T::zero(), |acc, (&a, &b)| acc + a * b);
        }
    }
    // Columns: P' = M Fᵀ, the same transform applied to whole columns.
    for k in 0..3 {
        axpy_column(p, POS + k, VEL + k, dt, n);
        if acc_model {
            axpy_column(p, POS + k, ACC + k, half_dt2, n);
            axpy_column(p, VEL + k, ACC + k, dt, n);
        }
    }
    // The four quaternion columns mix the old quaternion and ω columns: work from copies.
    let mut old = [[T::zero(); N]; 7];
    for (c, o) in old.iter_mut().enumerate() {
        let src = if c < 4 { QUAT + c } else { OMEGA + c - 4 };
        o[..n].copy_from_slice(&p[src * N..src * N + n]);
    }
    for (r, f) in fq.iter().enumerate() {
        let dst = &mut p[(QUAT + r) * N..(QUAT + r) * N + n];
        dst.fill(T::zero());
        for (&fc, o) in f.iter().zip(&old) {
            for (d, &v) in dst.iter_mut().zip(&o[..n]) {
                *d += fc * v;
            }
        }
    }
}

/// Column `dst` += `a` · column `src` over the active rows.
fn axpy_column<T: Scalar>(p: &mut [T], dst: usize, src: usize, a: T, n: usize) {
    let (d, s) = if dst < src {
        let (lo, hi) = p.split_at_mut(src * N);
        (&mut lo[dst * N..dst * N + n], &hi[..n])
    } else {
        let (lo, hi) = p.split_at_mut(dst * N);
        (&mut hi[..n], &lo[src * N..src * N + n])
    };
    for (x, &y) in d.iter_mut().zip(s) {
        *x += a * y;
    }
}

/// Adds the discretised process noise `Q(T)`.
fn add_process_noise<T: Scalar>(st: &mut State<T>, prm: &Params<T>, dt: T, f_qw: &Matrix4x3<T>) {
    let p = &mut st.p;
    let dt2 = dt * dt;
    let dt3 = dt2 * dt;
    let third = T::c(1.0 / 3.0);
    let half = T::c(0.5);
    let q2 = prm.q_motion * prm.q_motion;
    for k in 0..3 {
        let (s, v, a) = (POS + k, VEL + k, ACC + k);
        if prm.model == ModelKind::Acc {
            // White jerk integrated three times.
            let dt4 = dt3 * dt;
            let dt5 = dt4 * dt;
            p[(s, s)] += q2 * dt5 / T::c(20.0);
            p[(s, v)] += q2 * dt4 / T::c(8.0);
            p[(v, s)] += q2 * dt4 / T::c(8.0);
            p[(s, a)] += q2 * dt3 / T::c(6.0);
            p[(a, s)] += q2 * dt3 / T::c(6.0);
            p[(v, v)] += q2 * dt3 * third;
            p[(v, a)] += q2 * dt2 * half;
            p[(a, v)] += q2 * dt2 * half;
            p[(a, a)] += q2 * dt;
        } else {
            // White acceleration integrated twice.
            p[(s, s)] += q2 * dt3 * third;
            p[(s, v)] += q2 * dt2 * half;
            p[(v, s)] += q2 * dt2 * half;
            p[(v, v)] += q2 * dt;
        }
    }
    // White angular acceleration: ω gets q² T; the angle it integrates gets q² T³/3, with
    // covariance q² T²/2. Angles enter q through ∂q'/∂ω = T ∂q'/∂θ, i.e. ∂q'/∂θ = f_qw / T.
    let qa2 = prm.q_angular * prm.q_angular;
    let gq: SMatrix<T, 4, 4> = f_qw * f_qw.transpose() * (qa2 * dt * third);
    let gw: Matrix4x3<T> = f_qw * (qa2 * dt * half);
    for r in 0..4 {
        for c in 0..4 {
            p[(QUAT + r, QUAT + c)] += gq[(r, c)];
        }
        for c in 0..3 {
            p[(QUAT + r, OMEGA + c)] += gw[(r, c)];
            p[(OMEGA + c, QUAT + r)] += gw[(r, c)];
        }
    }
    let gb2 = prm.q_gyro_bias * prm.q_gyro_bias * dt;
    let ab2 = prm.q_accel_bias * prm.q_accel_bias * dt;
    for k in 0..3 {
        p[(OMEGA + k, OMEGA + k)] += qa2 * dt;
        p[(GYRO_BIAS + k, GYRO_BIAS + k)] += gb2;
        if prm.model != ModelKind::Gyro {
            p[(ACC_BIAS + k, ACC_BIAS + k)] += ab2;
        }
    }
}

/// The dense `F` (tests and finite-difference checks).
pub fn transition_matrix<T: Scalar>(st: &State<T>, prm: &Params<T>, dt: T) -> SMatrix<T, N, N> {
    let mut f = SMatrix::<T, N, N>::identity();
    let (dq, d) = quat::exp_increment(&st.v3(OMEGA), dt);
    for k in 0..3 {
        f[(POS + k, VEL + k)] = dt;
        if prm.model == ModelKind::Acc {
            f[(POS + k, ACC + k)] = dt * dt * T::c(0.5);
            f[(VEL + k, ACC + k)] = dt;
        }
    }
    f.fixed_view_mut::<4, 4>(QUAT, QUAT)
        .copy_from(&quat::left(&dq));
    f.fixed_view_mut::<4, 3>(QUAT, OMEGA)
        .copy_from(&(quat::right(&st.q()) * d));
    f
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::{params, random_state};
    use approx::assert_relative_eq;

    #[test]
    fn transition_jacobian_matches_central_differences() {
        for model in ModelKind::ALL {
            let prm = params::<f64>(model);
            let st = random_state(prm.n, 3);
            let dt = 0.01;
            let f = transition_matrix(&st, &prm, dt);
            for k in 0..prm.n {
                let mut plus = st.clone();
                let mut minus = st.clone();
                plus.x[k] += 1e-6;
                minus.x[k] -= 1e-6;
                // Mean propagation only: no normalisation (it is applied before, not inside).
                time_update(&mut plus, &prm, dt);
                time_update(&mut minus, &prm, dt);
                let fd = (plus.x - minus.x) / 2e-6;
                assert_relative_eq!(f.column(k).into_owned(), fd, epsilon = 1e-7);
            }
        }
    }

    #[test]
    fn sparse_propagation_equals_dense_f_p_ft() {
        for model in ModelKind::ALL {
            let mut prm = params::<f64>(model);
            let st = random_state(prm.n, 5);
            let f = transition_matrix(&st, &prm, 0.005);
            // Without process noise, P' must be exactly F P Fᵀ.
            prm.q_motion = 0.0;
            prm.q_angular = 0.0;
            prm.q_gyro_bias = 0.0;
            prm.q_accel_bias = 0.0;
            let mut out = st.clone();
            time_update(&mut out, &prm, 0.005);
            assert_relative_eq!(out.p, f * st.p * f.transpose(), epsilon = 1e-12);
        }
    }

    #[test]
    fn process_noise_matches_its_continuous_time_integral() {
        // Position variance of integrated white acceleration grows as q² T³/3.
        let prm = params::<f64>(ModelKind::Gyro);
        let mut st = State::<f64>::default();
        let steps = 1000;
        let dt = 0.001;
        for _ in 0..steps {
            time_update(&mut st, &prm, dt);
        }
        let t = steps as f64 * dt;
        let q2 = prm.q_motion * prm.q_motion;
        assert_relative_eq!(st.p[(POS, POS)], q2 * t * t * t / 3.0, max_relative = 1e-6);
        assert_relative_eq!(st.p[(VEL, VEL)], q2 * t, max_relative = 1e-9);
    }
}
