//! Time update (eq. 7, 12, 15).
//!
//! - gyro, gravity, vision (constant velocity): `s ← s + ṡT`, `ṡ ← ṡ + v_s̈ T`
//! - acc (constant acceleration): `s ← s + ṡT + s̈T²/2`, `ṡ ← ṡ + s̈T`, `s̈ ← s̈ + v`
//! - all: `q ← exp(−T/2 · ω) ⊙ q`, `ω ← ω + v_ω`, biases random walks (none in vision-only:
//!   13 states, the first four blocks).
//!
//! Process noises are continuous-time white-noise densities; their exact discretisation over
//! `T` gives the `Q` blocks below (integrated white acceleration / jerk / angular acceleration).

use nalgebra::{Matrix4, Matrix4x3, SMatrix};
use protocol::ModelKind;

use crate::params::Params;
use crate::quat;
use crate::scalar::Scalar;
use crate::state::{ACC, ACC_BIAS, GYRO_BIAS, N, OMEGA, POS, QUAT, State, VEL};

/// Normalises the quaternion before a time update, as the paper does: each measurement
/// update changes its norm a little (by `θ²/8` for a correct correction of `θ`; the
/// divergence monitor judges only an update's radial part, [`crate::ekf::radial_step`]).
pub fn normalise_quaternion<T: Scalar>(st: &mut State<T>) {
    let q = st.q();
    let norm = q.norm();
    if norm > T::zero() {
        st.set_q(&(q / norm));
    }
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

/// Rows of `F` that differ from the identity: position, velocity and quaternion.
const F_ROWS: usize = QUAT + 4;

/// `P ← F P Fᵀ` (eq. 7 / 12 / 15 linearised) for a symmetric `P`, touching only the rows and
/// columns where `F` differs from the identity (the first `F_ROWS`). `M = F P` column by column
/// (contiguous), then `P' = M Fᵀ` row by row (row `i` of `P'` is `F` applied to row `i` of `M`)
/// for the rows in `F_ROWS` only. In the other rows `i`, `P'_ij = M_ji` (as `P` is symmetric):
/// a mirror. Where neither row nor column is in `F_ROWS`, `P` does not change.
fn propagate_covariance<T: Scalar>(
    st: &mut State<T>,
    n: usize,
    acc_model: bool,
    dt: T,
    f_qq: &Matrix4<T>,
    f_qw: &Matrix4x3<T>,
) {
    let f = Transition {
        acc_model,
        dt,
        half_dt2: dt * dt * T::c(0.5),
        // ∂q'/∂q = L(δq): its first column is δq itself.
        dq: [f_qq[(0, 0)], f_qq[(1, 0)], f_qq[(2, 0)], f_qq[(3, 0)]],
        f_qw: core::array::from_fn(|r| [f_qw[(r, 0)], f_qw[(r, 1)], f_qw[(r, 2)]]),
    };
    let n = n.min(N);
    let p = st.p.as_mut_slice();
    // One loop over the columns with `f` inlined, so that its 16 coefficients stay in
    // registers rather than being reloaded for every column.
    for chunk in p.chunks_exact_mut(N).take(n) {
        if let Ok(col) = <&mut [T; N]>::try_from(chunk) {
            f.apply(col);
        }
    }
    // Row i of M: only the entries `F` reads, position to ω and, in the acc model, the
    // acceleration (the rest of `row` is never used; every model has at least 13 states).
    let mut row = [T::zero(); N];
    for i in 0..F_ROWS {
        for (v, col) in row[..OMEGA + 3].iter_mut().zip(p.chunks_exact(N)) {
            *v = col[i];
        }
        if acc_model {
            for (v, col) in row[ACC..].iter_mut().zip(p.chunks_exact(N).skip(ACC)) {
                *v = col[i];
            }
        }
        f.apply(&mut row);
        for (&v, col) in row.iter().zip(p.chunks_exact_mut(N)).take(F_ROWS) {
            col[i] = v;
        }
    }
    let (a, b) = p.split_at_mut(F_ROWS * N);
    for (i, col) in b.chunks_exact(N).enumerate().take(n.saturating_sub(F_ROWS)) {
        let i = F_ROWS + i;
        for (pij, a_col) in col[..F_ROWS].iter().zip(a.chunks_exact_mut(N)) {
            a_col[i] = *pij;
        }
    }
}

/// The rows of `F` that differ from the identity (see [`propagate_covariance`]).
struct Transition<T: Scalar> {
    acc_model: bool,
    dt: T,
    half_dt2: T,
    /// `δq = [w, x, y, z]`: `∂q'/∂q = L(δq)` ([`quat::left`]).
    dq: [T; 4],
    /// `∂q'/∂ω`, by rows.
    f_qw: [[T; 3]; 4],
}

impl<T: Scalar> Transition<T> {
    /// `v ← F v`, for a column of `P` or a row of `M` (see [`propagate_covariance`]).
    #[inline(always)]
    fn apply(&self, v: &mut [T; N]) {
        let (dt, half_dt2) = (self.dt, self.half_dt2);
        // Position first (it reads the old velocity).
        for k in 0..3 {
            let mut pos = v[POS + k] + v[VEL + k] * dt;
            if self.acc_model {
                pos += v[ACC + k] * half_dt2;
                v[VEL + k] += v[ACC + k] * dt;
            }
            v[POS + k] = pos;
        }
        let [q0, q1, q2, q3] = [v[QUAT], v[QUAT + 1], v[QUAT + 2], v[QUAT + 3]];
        let om = [v[OMEGA], v[OMEGA + 1], v[OMEGA + 2]];
        let [w, x, y, z] = self.dq;
        // The rows of L(δq) = [[w, −x, −y, −z], [x, w, −z, y], [y, z, w, −x], [z, −y, x, w]]
        // (signs applied by subtracting, which rounds the same), then ∂q'/∂ω ω.
        let lq = [
            w * q0 - x * q1 - y * q2 - z * q3,
            x * q0 + w * q1 - z * q2 + y * q3,
            y * q0 + z * q1 + w * q2 - x * q3,
            z * q0 - y * q1 + x * q2 + w * q3,
        ];
        for (r, (l, fw)) in lq.into_iter().zip(&self.f_qw).enumerate() {
            v[QUAT + r] = l + fw[0] * om[0] + fw[1] * om[1] + fw[2] * om[2];
        }
    }
}

/// Adds the discretised process noise `Q(T)`.
fn add_process_noise<T: Scalar>(st: &mut State<T>, prm: &Params<T>, dt: T, f_qw: &Matrix4x3<T>) {
    let p = st.p.as_mut_slice();
    // Adds `v` at (r, c) and, off the diagonal, at (c, r).
    let mut add = |r: usize, c: usize, v: T| {
        if let Some(x) = p.get_mut(c * N + r) {
            *x += v;
        }
        if r != c
            && let Some(x) = p.get_mut(r * N + c)
        {
            *x += v;
        }
    };
    let dt2 = dt * dt;
    let dt3 = dt2 * dt;
    let q2 = prm.q_motion * prm.q_motion;
    // Motion noise of one axis: `[[ss, sv, sa], [vv, va], [aa]]`.
    let (ss, sv, sa, vv, va, aa) = if prm.model == ModelKind::Acc {
        // White jerk integrated three times.
        let dt4 = dt3 * dt;
        let dt5 = dt4 * dt;
        (
            q2 * dt5 / T::c(20.0),
            q2 * dt4 / T::c(8.0),
            q2 * dt3 / T::c(6.0),
            q2 * dt3 / T::c(3.0),
            q2 * dt2 * T::c(0.5),
            q2 * dt,
        )
    } else {
        // White acceleration integrated twice.
        let z = T::zero();
        (q2 * dt3 / T::c(3.0), q2 * dt2 * T::c(0.5), z, q2 * dt, z, z)
    };
    // Biases the model lacks get zero (their entries stay zero: no IMU in vision-only, no
    // accelerometer in the gyro model).
    let gb2 = if prm.model.has_imu() {
        prm.q_gyro_bias * prm.q_gyro_bias * dt
    } else {
        T::zero()
    };
    let ab2 = if matches!(prm.model, ModelKind::Gyro | ModelKind::Vision) {
        T::zero()
    } else {
        prm.q_accel_bias * prm.q_accel_bias * dt
    };
    // White angular acceleration: ω gets q² T; the angle it integrates gets q² T³/3, with
    // covariance q² T²/2. Angles enter q through ∂q'/∂ω = T ∂q'/∂θ, i.e. ∂q'/∂θ = f_qw / T.
    let qa2 = prm.q_angular * prm.q_angular;
    for k in 0..3 {
        let (s, v, a) = (POS + k, VEL + k, ACC + k);
        add(s, s, ss);
        add(s, v, sv);
        add(v, v, vv);
        // Zero in the constant-velocity models (their ACC block stays zero).
        add(s, a, sa);
        add(v, a, va);
        add(a, a, aa);
        add(OMEGA + k, OMEGA + k, qa2 * dt);
        add(GYRO_BIAS + k, GYRO_BIAS + k, gb2);
        add(ACC_BIAS + k, ACC_BIAS + k, ab2);
    }
    let gq = qa2 * dt / T::c(3.0);
    let gw = qa2 * dt * T::c(0.5);
    for r in 0..4 {
        for c in r..4 {
            let v = (0..3).fold(T::zero(), |acc, k| acc + f_qw[(r, k)] * f_qw[(c, k)]);
            add(QUAT + r, QUAT + c, v * gq);
        }
        for c in 0..3 {
            add(QUAT + r, OMEGA + c, f_qw[(r, c)] * gw);
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
