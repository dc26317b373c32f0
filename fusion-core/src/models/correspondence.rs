//! The implicit 2D/3D correspondence measurement (eq. 10) and the outlier gate (eq. 17).
//!
//! `0 = [I₂ | −m_n] · R(q_cs)(R(q_sw)(m_w − s_w) − c_s) + v_c`, `v_c ~ N(0, P_c)`, where `P_c`
//! propagates the covariances of `m_n` and `m_w` through the same expression.

use nalgebra::{Matrix2, Matrix2x3, Matrix2x4, Matrix3, Vector2, Vector3};

use crate::ekf::{Gains, Ldl, SparseRow, innovation_cov};
use crate::params::Params;
use crate::quat;
use crate::scalar::Scalar;
use crate::state::{HandEye, N, POS, QUAT, State, StateVec};

/// Nearest depth in front of the camera a model point may have [m].
pub const MIN_DEPTH: f64 = 1e-3;

/// One correspondence in the filter's scalar.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Observation<T: Scalar> {
    /// Registered point, normalised image coordinates.
    pub m_n: Vector2<T>,
    /// Its covariance.
    pub cov_n: Matrix2<T>,
    /// Model point in the world [m].
    pub m_w: Vector3<T>,
    /// Its covariance.
    pub cov_w: Matrix3<T>,
}

impl<T: Scalar> Observation<T> {
    /// From the wire form (symmetric matrices unpacked).
    pub fn from_wire(c: &protocol::Correspondence) -> Self {
        let f = T::from_wire;
        let [a, b, d] = c.cov_n;
        let [xx, xy, xz, yy, yz, zz] = c.cov_w;
        Observation {
            m_n: Vector2::new(f(c.m_n[0]), f(c.m_n[1])),
            cov_n: Matrix2::new(f(a), f(b), f(b), f(d)),
            m_w: Vector3::new(f(c.m_w[0]), f(c.m_w[1]), f(c.m_w[2])),
            cov_w: Matrix3::new(
                f(xx),
                f(xy),
                f(xz),
                f(xy),
                f(yy),
                f(yz),
                f(xz),
                f(yz),
                f(zz),
            ),
        }
    }
}

/// Why a correspondence was not applied.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Rejection {
    /// The normalised residual exceeds the gate (eq. 17).
    Gated,
    /// The model point is not in front of the camera at the current estimate.
    BehindCamera,
    /// The innovation covariance is singular.
    Singular,
}

/// The model point in the camera frame, `R(q_cs)(R(q_sw)(m_w − s_w) − c_s)`, at mean `x`.
pub fn camera_point<T: Scalar>(x: &StateVec<T>, he: &HandEye<T>, m_w: &Vector3<T>) -> Vector3<T> {
    let q = x.fixed_rows::<4>(QUAT).normalize();
    let s = x.fixed_rows::<3>(POS);
    he.r_cs * (quat::rot(&q) * (m_w - s) - he.c_s)
}

/// Projection of `m_w` to normalised image coordinates at mean `x`, if in front.
pub fn project<T: Scalar>(
    x: &StateVec<T>,
    he: &HandEye<T>,
    m_w: &Vector3<T>,
) -> Option<Vector2<T>> {
    let p = camera_point(x, he, m_w);
    (p[2] > T::c(MIN_DEPTH)).then(|| Vector2::new(p[0] / p[2], p[1] / p[2]))
}

/// The implicit measurement function `h = [I₂ | −m_n] p_c`.
pub fn residual<T: Scalar>(st: &State<T>, he: &HandEye<T>, obs: &Observation<T>) -> Vector2<T> {
    let p = camera_point(&st.x, he, &obs.m_w);
    Vector2::new(p[0] - obs.m_n[0] * p[2], p[1] - obs.m_n[1] * p[2])
}

/// Linearisation of eq. 10: `∂h/∂s_w` (2×3), `∂h/∂q_sw` (2×4) (all other state entries do not
/// enter `h`), `P_c`, the depth of the model point, and `h` itself.
fn blocks<T: Scalar>(
    st: &State<T>,
    he: &HandEye<T>,
    obs: &Observation<T>,
) -> (Matrix2x3<T>, Matrix2x4<T>, Matrix2<T>, T, Vector2<T>) {
    let q = st.q().normalize();
    let rot = quat::rot(&q);
    let v = obs.m_w - st.v3(POS);
    let p_c = he.r_cs * (rot * v - he.c_s);
    // [I₂ | −m_n] R(q_cs).
    let a_rcs = Matrix2x3::from_fn(|k, c| he.r_cs[(k, c)] - obs.m_n[k] * he.r_cs[(2, c)]);
    let d_mw: Matrix2x3<T> = a_rcs * rot; // ∂h/∂m_w = −∂h/∂s_w
    let d_q = a_rcs * quat::d_rotate_dq(&q, &v);
    // ∂h/∂m_n = −p_z I₂.
    let depth = p_c[2];
    let cov = obs.cov_n * (depth * depth) + d_mw * obs.cov_w * d_mw.transpose();
    let h = Vector2::new(p_c[0] - obs.m_n[0] * depth, p_c[1] - obs.m_n[1] * depth);
    (-d_mw, d_q, cov, depth, h)
}

/// Linearisation: rows of `∂h/∂x`, and `P_c`.
pub fn linearise<T: Scalar>(
    st: &State<T>,
    he: &HandEye<T>,
    obs: &Observation<T>,
) -> ([SparseRow<T>; 2], Matrix2<T>, T) {
    let (d_s, d_q, cov, depth, _) = blocks(st, he, obs);
    let d_s = core::array::from_fn(|k| core::array::from_fn(|c| d_s[(k, c)]));
    let d_q = core::array::from_fn(|k| core::array::from_fn(|c| d_q[(k, c)]));
    (pose_rows(&d_s, &d_q), cov, depth)
}

/// Applies one correspondence unless it is behind the camera, singular, or gated out.
/// Returns the normalised residual `s_i = zᵀ S⁻¹ z` (infinite when it cannot be computed), and
/// whether it was applied. (The quaternion test judges a whole part's step, not one
/// correspondence's: docs/FILTER.md §9.)
///
/// The covariance must be symmetric (every update and time update keeps it so).
pub fn update<T: UpdateKernel>(
    st: &mut State<T>,
    prm: &Params<T>,
    obs: &Observation<T>,
) -> (T, Result<(), Rejection>) {
    T::correspondence_update(st, prm, obs)
}

/// [`update`], instantiated through [`UpdateKernel`].
pub(crate) fn update_generic<T: Scalar>(
    st: &mut State<T>,
    prm: &Params<T>,
    obs: &Observation<T>,
) -> (T, Result<(), Rejection>) {
    let (d_s, d_q, r, depth, h) = blocks(st, &prm.hand_eye, obs);
    let rs = (r[(0, 1)] + r[(1, 0)]) * T::c(0.5);
    let pose = PoseRows {
        d_s: core::array::from_fn(|k| core::array::from_fn(|c| d_s[(k, c)])),
        d_q: core::array::from_fn(|k| core::array::from_fn(|c| d_q[(k, c)])),
        r: [[r[(0, 0)], rs], [rs, r[(1, 1)]]],
        h: [h[0], h[1]],
        depth,
    };
    pose.update(st, prm)
}

/// An implicit measurement `0 = h(x) + v` of dimension `M` on the pose alone: its rows on
/// `s_w` and `q_sw`, its noise covariance, `h` at the prior and the depth of its model point.
/// Eq. 10 (`M` = 2) and eq. 10c (`M` = 1, [`super::contour`]) are both applied by
/// [`PoseRows::update`].
pub(crate) struct PoseRows<T: Scalar, const M: usize> {
    /// `∂h/∂s_w`, row by row.
    pub d_s: [[T; 3]; M],
    /// `∂h/∂q_sw`, row by row.
    pub d_q: [[T; 4]; M],
    /// The noise covariance (symmetric).
    pub r: [[T; M]; M],
    /// `h` at the prior.
    pub h: [T; M],
    /// Depth of the model point in front of the camera.
    pub depth: T,
}

/// The sparse rows of `∂h/∂x` from their blocks on `s_w` and `q_sw`.
pub(crate) fn pose_rows<T: Scalar, const M: usize>(
    d_s: &[[T; 3]; M],
    d_q: &[[T; 4]; M],
) -> [SparseRow<T>; M] {
    core::array::from_fn(|k| {
        let mut row = SparseRow::default();
        row.push_slice(POS, &d_s[k]);
        row.push_slice(QUAT, &d_q[k]);
        row
    })
}

impl<T: Scalar, const M: usize> PoseRows<T, M> {
    /// Applies the measurement unless its point is behind the camera, its innovation
    /// covariance is singular, or it fails the gate (eq. 17). Returns the normalised residual
    /// `s = hᵀ S⁻¹ h` (infinite when it cannot be computed) and whether it was applied.
    #[inline(always)]
    pub(crate) fn update(&self, st: &mut State<T>, prm: &Params<T>) -> (T, Result<(), Rejection>) {
        let inf = T::c(f64::INFINITY);
        // Written so that a NaN depth is rejected too.
        if self.depth.partial_cmp(&T::c(MIN_DEPTH)) != Some(core::cmp::Ordering::Greater) {
            return (inf, Err(Rejection::BehindCamera));
        }
        // U = P Hᵀ from whole columns of the symmetric P, on the two blocks of H.
        // Built in place rather than zeroed first (a memset call per update).
        let n = prm.n.min(N);
        let p = st.p.as_slice();
        let mut u: Gains<T, M> = core::array::from_fn(|i| {
            let Some(col) = p.get(i * N..i * N + N).filter(|_| i < n) else {
                return [T::zero(); M];
            };
            core::array::from_fn(|k| {
                let mut a = T::zero();
                for c in 0..3 {
                    a += self.d_s[k][c] * col[POS + c];
                }
                for c in 0..4 {
                    a += self.d_q[k][c] * col[QUAT + c];
                }
                a
            })
        });
        let s = innovation_cov(&pose_rows(&self.d_s, &self.d_q), &u, &self.r);
        let f = Ldl::new(&s, &self.h.map(|v| -v));
        if f.rank < M || !f.nis.is_finite() {
            return (inf, Err(Rejection::Singular));
        }
        // Outlier gate (eq. 17): s = hᵀ S⁻¹ h, from the factorisation.
        if f.nis > prm.gate {
            return (f.nis, Err(Rejection::Gated));
        }
        f.apply(st, prm.n, &mut u);
        (f.nis, Ok(()))
    }
}

/// [`update`], compiled in this crate for each scalar (why: [`crate::kernels`]).
pub trait UpdateKernel: Scalar {
    /// [`update`] (every 2D/3D correspondence).
    fn correspondence_update(
        st: &mut State<Self>,
        prm: &Params<Self>,
        obs: &Observation<Self>,
    ) -> (Self, Result<(), Rejection>);
}

macro_rules! update_kernel {
    ($t:ty) => {
        impl UpdateKernel for $t {
            #[inline(never)]
            fn correspondence_update(
                st: &mut State<Self>,
                prm: &Params<Self>,
                obs: &Observation<Self>,
            ) -> (Self, Result<(), Rejection>) {
                update_generic(st, prm, obs)
            }
        }
    };
}
update_kernel!(f32);
update_kernel!(f64);

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::{params, random_state};
    use approx::assert_relative_eq;
    use protocol::ModelKind;

    fn obs(st: &State<f64>, he: &HandEye<f64>) -> Observation<f64> {
        // A point 2 m in front of the camera, slightly off-axis, with a noisy registration.
        let pose = crate::state::camera_pose(st, he);
        let r_wc = quat::rot(&pose.q_cw).transpose();
        let m_w = pose.c_w + r_wc * Vector3::new(0.3, -0.2, 2.0);
        Observation {
            m_n: Vector2::new(0.16, -0.09),
            cov_n: Matrix2::new(1e-6, 2e-7, 2e-7, 2e-6),
            m_w,
            cov_w: Matrix3::new(1e-4, 1e-5, 0.0, 1e-5, 2e-4, 0.0, 0.0, 0.0, 3e-4),
        }
    }

    #[test]
    fn jacobians_match_central_differences() {
        let prm = params::<f64>(ModelKind::Acc);
        let st = random_state(prm.n, 21);
        let o = obs(&st, &prm.hand_eye);
        let (h, cov, _) = linearise(&st, &prm.hand_eye, &o);
        for j in 0..prm.n {
            let mut plus = st.clone();
            let mut minus = st.clone();
            plus.x[j] += 1e-6;
            minus.x[j] -= 1e-6;
            let fd =
                (residual(&plus, &prm.hand_eye, &o) - residual(&minus, &prm.hand_eye, &o)) / 2e-6;
            assert_relative_eq!(h[0].dense()[j], fd[0], epsilon = 1e-7);
            assert_relative_eq!(h[1].dense()[j], fd[1], epsilon = 1e-7);
        }
        // P_c = J_n P_n J_nᵀ + J_w P_w J_wᵀ with J from central differences in m_n and m_w.
        let mut j_n = Matrix2::zeros();
        for k in 0..2 {
            let (mut a, mut b) = (o, o);
            a.m_n[k] += 1e-6;
            b.m_n[k] -= 1e-6;
            j_n.set_column(
                k,
                &((residual(&st, &prm.hand_eye, &a) - residual(&st, &prm.hand_eye, &b)) / 2e-6),
            );
        }
        let mut j_w = Matrix2x3::zeros();
        for k in 0..3 {
            let (mut a, mut b) = (o, o);
            a.m_w[k] += 1e-6;
            b.m_w[k] -= 1e-6;
            j_w.set_column(
                k,
                &((residual(&st, &prm.hand_eye, &a) - residual(&st, &prm.hand_eye, &b)) / 2e-6),
            );
        }
        let fd_cov = j_n * o.cov_n * j_n.transpose() + j_w * o.cov_w * j_w.transpose();
        assert_relative_eq!(cov, fd_cov, epsilon = 1e-10, max_relative = 1e-6);
    }

    #[test]
    fn points_behind_the_camera_are_rejected_without_touching_the_state() {
        let prm = params::<f64>(ModelKind::Gyro);
        let mut st = random_state(prm.n, 22);
        let mut o = obs(&st, &prm.hand_eye);
        let pose = crate::state::camera_pose(&st, &prm.hand_eye);
        o.m_w = pose.c_w - quat::rot(&pose.q_cw).transpose() * Vector3::new(0.0, 0.0, 1.0);
        let before = st.clone();
        let (s, r) = update(&mut st, &prm, &o);
        assert_eq!(r, Err(Rejection::BehindCamera));
        assert!(s.is_infinite());
        assert_eq!(st, before);
    }

    #[test]
    fn outliers_are_gated_without_touching_the_state() {
        let prm = params::<f64>(ModelKind::Gravity);
        let mut st = random_state(prm.n, 23);
        st.p *= 1e-4; // a confident filter: the prediction error below is 100s of σ
        let mut o = obs(&st, &prm.hand_eye);
        o.m_n += Vector2::new(0.5, 0.5); // far from the projection
        let before = st.clone();
        let (s, r) = update(&mut st, &prm, &o);
        assert_eq!(r, Err(Rejection::Gated));
        assert!(s > prm.gate);
        assert_eq!(st, before);
    }
}
