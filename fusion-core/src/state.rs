//! The state vector, its layout, and the camera pose derived from it (eq. 5-6).
//!
//! One layout serves all three models: the gyro model uses the first 16 entries, the gravity
//! model 19, the acc model all 22. Entries a model lacks stay zero with zero covariance, and
//! every loop runs over the active prefix only.

use nalgebra::{ArrayStorage, Matrix3, SMatrix, SVector, Vector3, Vector4};

use crate::quat::{self, Quat};
use crate::scalar::Scalar;

/// Largest state dimension (the acc model).
pub const N: usize = 22;
/// Position `s_w` [m].
pub const POS: usize = 0;
/// Velocity `ṡ_w` [m/s].
pub const VEL: usize = 3;
/// Orientation `q_sw` (4 entries).
pub const QUAT: usize = 6;
/// Angular velocity `ω_s` [rad/s].
pub const OMEGA: usize = 10;
/// Gyroscope bias `b_ω` [rad/s].
pub const GYRO_BIAS: usize = 13;
/// Accelerometer bias `b_a` [m/s²] (gravity and acc models).
pub const ACC_BIAS: usize = 16;
/// Free acceleration `s̈_w` [m/s²] (acc model).
pub const ACC: usize = 19;

/// State vector.
pub type StateVec<T> = SVector<T, N>;
/// State covariance.
pub type Cov<T> = SMatrix<T, N, N>;

/// Mean and covariance of the filter.
#[derive(Clone, Debug, PartialEq)]
pub struct State<T: Scalar> {
    /// Mean.
    pub x: StateVec<T>,
    /// Covariance (only the active `n × n` block is non-zero).
    pub p: Cov<T>,
}

impl<T: Scalar> Default for State<T> {
    fn default() -> Self {
        let mut x = StateVec::zeros();
        x[QUAT] = T::one();
        State { x, p: Cov::zeros() }
    }
}

impl<T: Scalar> State<T> {
    /// All zeros (not a valid state: the quaternion is zero too), built at compile time so
    /// that a `static` holding it lands in `.bss`.
    pub const fn zeroed() -> Self {
        State {
            x: SMatrix::from_array_storage(ArrayStorage([[T::ZERO; N]; 1])),
            p: SMatrix::from_array_storage(ArrayStorage([[T::ZERO; N]; N])),
        }
    }

    /// Three entries from `at`.
    pub fn v3(&self, at: usize) -> Vector3<T> {
        self.x.fixed_rows::<3>(at).into_owned()
    }

    /// Orientation `q_sw`.
    pub fn q(&self) -> Quat<T> {
        // Entry by entry: `fixed_rows().into_owned()` became a copy loop at every call site in
        // the firmware (flash).
        let x = &self.x;
        Quat::new(x[QUAT], x[QUAT + 1], x[QUAT + 2], x[QUAT + 3])
    }

    /// Sets three entries from `at`.
    pub fn set_v3(&mut self, at: usize, v: &Vector3<T>) {
        self.x.fixed_rows_mut::<3>(at).copy_from(v);
    }

    /// Sets the orientation.
    pub fn set_q(&mut self, q: &Quat<T>) {
        self.x.fixed_rows_mut::<4>(QUAT).copy_from(q);
    }

    /// Frobenius norm of the covariance, from its upper triangle (the covariance is
    /// symmetric): `‖P‖² = Σ P_ii² + 2 Σ_{i<j} P_ij²`, half the work of all entries.
    pub fn cov_frobenius(&self) -> T
    where
        T: StateKernels,
    {
        T::cov_frobenius(self)
    }

    /// [`Self::cov_frobenius`], compiled through [`StateKernels`].
    pub(crate) fn cov_frobenius_generic(&self) -> T {
        let mut diag = T::zero();
        let mut off = T::zero();
        for (j, col) in self.p.as_slice().chunks_exact(N).enumerate() {
            // Four at a time, in the same order (the loop's overhead was most of its cost).
            let mut quads = col[..j].chunks_exact(4);
            for q in &mut quads {
                off += q[0] * q[0];
                off += q[1] * q[1];
                off += q[2] * q[2];
                off += q[3] * q[3];
            }
            for &v in quads.remainder() {
                off += v * v;
            }
            diag += col[j] * col[j];
        }
        (diag + off * T::c(2.0)).sqrt()
    }

    /// Whether every entry of mean and covariance is finite.
    pub fn is_finite(&self) -> bool
    where
        T: StateKernels,
    {
        all_finite(self.x.as_slice()) && all_finite(self.p.as_slice())
    }
}

/// Whether every value is finite, branch-free: `v · 0` is `±0` for a finite `v` and NaN for
/// `±∞` and NaN, so the sum of those products is zero exactly when all are finite (one
/// multiply-add per value instead of a compare and branch).
pub fn all_finite<T: StateKernels>(values: &[T]) -> bool {
    T::all_finite(values)
}

/// [`all_finite`], compiled through [`StateKernels`].
pub(crate) fn all_finite_generic<T: Scalar>(values: &[T]) -> bool {
    let zero = T::zero();
    values.iter().fold(zero, |acc, &v| acc + v * zero) == zero
}

/// Hand-eye calibration, converted to the filter's scalar.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HandEye<T: Scalar> {
    /// Rotation sensor → camera.
    pub q_cs: Quat<T>,
    /// Its matrix.
    pub r_cs: Matrix3<T>,
    /// Camera origin in the sensor frame [m].
    pub c_s: Vector3<T>,
}

impl<T: Scalar> HandEye<T> {
    /// From the wire form (`q_cs` is re-normalised).
    pub fn from_wire(h: &protocol::HandEye) -> Self {
        let q = Vector4::from_iterator(h.q_cs.iter().map(|&v| T::from_wire(v))).normalize();
        HandEye {
            q_cs: q,
            r_cs: quat::rot(&q),
            c_s: Vector3::from_iterator(h.c_s.iter().map(|&v| T::from_wire(v))),
        }
    }
}

/// Camera pose and its covariance.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CameraPose<T: Scalar> {
    /// Camera origin in the world `c_w`.
    pub c_w: Vector3<T>,
    /// Orientation `q_cw`.
    pub q_cw: Quat<T>,
    /// Covariance of `[c_w, θ]` (θ: world-frame rotation vector of the error of `q_cw`).
    pub cov: SMatrix<T, 6, 6>,
}

/// Camera pose from the state (eq. 5-6): `c_w = s_w + R(q_sw)ᵀ c_s`, `q_cw = q_cs ⊙ q_sw`,
/// with its covariance `J P Jᵀ`.
pub fn camera_pose<T: StateKernels>(st: &State<T>, he: &HandEye<T>) -> CameraPose<T> {
    T::camera_pose(st, he)
}

/// [`camera_pose`], compiled through [`StateKernels`].
pub(crate) fn camera_pose_generic<T: Scalar>(st: &State<T>, he: &HandEye<T>) -> CameraPose<T> {
    let q = st.q().normalize();
    let r = quat::rot(&q);
    let c_w = st.v3(POS) + r.transpose() * he.c_s;
    let q_cw = quat::mul(&he.q_cs, &q);
    // J = ∂[c_w, θ]/∂[s_w, q_sw]; R(q)ᵀ c_s = R(q̄) c_s, and ∂q̄/∂q = diag(1, −1, −1, −1).
    let mut d_conj = quat::d_rotate_dq(&quat::conj(&q), &he.c_s);
    for mut col in d_conj.column_iter_mut().skip(1) {
        col.neg_mut();
    }
    // Right perturbation of q_sw is the same right perturbation of q_cw (world frame).
    let d_theta = quat::d_theta_dq(&q);
    let mut j = SMatrix::<T, 6, 7>::zeros();
    j.fixed_view_mut::<3, 3>(0, 0)
        .copy_from(&Matrix3::identity());
    j.fixed_view_mut::<3, 4>(0, 3).copy_from(&d_conj);
    j.fixed_view_mut::<3, 4>(3, 3).copy_from(&d_theta);
    let mut p = SMatrix::<T, 7, 7>::zeros();
    for (a, ia) in [(0usize, POS), (3, QUAT)] {
        for (b, ib) in [(0usize, POS), (3, QUAT)] {
            let (ra, rb) = (if a == 0 { 3 } else { 4 }, if b == 0 { 3 } else { 4 });
            for i in 0..ra {
                for k in 0..rb {
                    p[(a + i, b + k)] = st.p[(ia + i, ib + k)];
                }
            }
        }
    }
    CameraPose {
        c_w,
        q_cw,
        cov: j * p * j.transpose(),
    }
}

/// The state's hot functions, compiled in this crate for each scalar (why: [`crate::kernels`]).
pub trait StateKernels: Scalar {
    /// [`State::cov_frobenius`] (every `State` report).
    fn cov_frobenius(st: &State<Self>) -> Self;
    /// [`all_finite`] (every divergence check).
    fn all_finite(values: &[Self]) -> bool;
    /// [`camera_pose`] (every pose prediction).
    fn camera_pose(st: &State<Self>, he: &HandEye<Self>) -> CameraPose<Self>;
}

macro_rules! state_kernels {
    ($t:ty) => {
        impl StateKernels for $t {
            #[inline(never)]
            fn cov_frobenius(st: &State<Self>) -> Self {
                st.cov_frobenius_generic()
            }
            #[inline(never)]
            fn all_finite(values: &[Self]) -> bool {
                all_finite_generic(values)
            }
            #[inline(never)]
            fn camera_pose(st: &State<Self>, he: &HandEye<Self>) -> CameraPose<Self> {
                camera_pose_generic(st, he)
            }
        }
    };
}
state_kernels!(f32);
state_kernels!(f64);

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    #[test]
    fn camera_pose_jacobian_matches_central_differences() {
        let he = HandEye::<f64>::from_wire(&protocol::HandEye {
            q_cs: [0.5, -0.5, 0.5, -0.5],
            c_s: [0.05, -0.02, 0.1],
        });
        let mut st = State::<f64>::default();
        st.set_v3(POS, &Vector3::new(1.0, 2.0, 0.5));
        st.set_q(&Vector4::new(0.8, 0.1, -0.3, 0.2).normalize());
        let base = camera_pose(&st, &he);
        // Covariance with one unit entry at a time picks out J's columns.
        for k in (POS..POS + 3).chain(QUAT..QUAT + 4) {
            let mut plus = st.clone();
            let mut minus = st.clone();
            plus.x[k] += 1e-6;
            minus.x[k] -= 1e-6;
            let (a, b) = (camera_pose(&plus, &he), camera_pose(&minus, &he));
            let dc = (a.c_w - b.c_w) / 2e-6;
            let dtheta = (quat::vec_part(&quat::mul(&quat::conj(&base.q_cw), &a.q_cw.normalize()))
                - quat::vec_part(&quat::mul(&quat::conj(&base.q_cw), &b.q_cw.normalize())))
                / 1e-6;
            let mut unit = st.clone();
            unit.p[(k, k)] = 1.0;
            let cov = camera_pose(&unit, &he).cov;
            let fd = nalgebra::Vector6::new(dc[0], dc[1], dc[2], dtheta[0], dtheta[1], dtheta[2]);
            assert_relative_eq!(cov, fd * fd.transpose(), epsilon = 1e-6);
        }
    }
}
