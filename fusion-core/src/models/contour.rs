//! The implicit contour measurement (eq. 10c, since protocol 3.2): a model point on the
//! object's silhouette, found in the image along the contour's normal.
//!
//! `0 = nᵀ [I₂ | −u] p_c + v = n₁ p_x + n₂ p_y − d p_z + v`, with `p_c` the model point in the
//! camera frame (as in eq. 10), `n` the unit normal and `d = nᵀu` the found contour position
//! along it. The 2D/3D correspondence's `[I₂ | −m_n] p_c` projected onto the normal: it only
//! constrains the projection along `n`, which is all a contour tells (the aperture problem of
//! an edge). `v ~ N(0, r)` with `r = p_z² σ_d² + a P_w aᵀ`, `a = ∂h/∂m_w`.

use nalgebra::{RowVector3, Vector2, Vector3};

use crate::ekf::SparseRow;
use crate::models::correspondence::{PoseRows, Rejection, camera_point, pose_rows};
use crate::params::Params;
use crate::quat;
use crate::scalar::Scalar;
use crate::state::{HandEye, POS, State};
use nalgebra::Matrix3;

/// One contour correspondence in the filter's scalar.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ContourObservation<T: Scalar> {
    /// Model point on the silhouette, in the world [m].
    pub m_w: Vector3<T>,
    /// Its covariance.
    pub cov_w: Matrix3<T>,
    /// Unit normal of the contour, normalised image coordinates.
    pub n: Vector2<T>,
    /// The contour's position along the normal, `nᵀu`.
    pub d: T,
    /// Variance of `d`.
    pub var_d: T,
}

impl<T: Scalar> ContourObservation<T> {
    /// From the wire form (the symmetric matrix unpacked).
    pub fn from_wire(c: &protocol::ContourPoint) -> Self {
        let f = T::from_wire;
        let [xx, xy, xz, yy, yz, zz] = c.cov_w;
        ContourObservation {
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
            n: Vector2::new(f(c.n[0]), f(c.n[1])),
            d: f(c.d),
            var_d: f(c.var_d),
        }
    }

    /// The measurement's 1×3 row on the camera point, `nᵀ [I₂ | −u] = [n₁, n₂, −d]`.
    fn along(&self) -> RowVector3<T> {
        RowVector3::new(self.n[0], self.n[1], -self.d)
    }

    /// Signed distance along the normal from the contour to the projection of `m_w` at mean
    /// `x`, `nᵀπ(m_w) − d` (normalised units), if the point is in front: the prediction error.
    pub fn offset(&self, x: &crate::state::StateVec<T>, he: &HandEye<T>) -> Option<T> {
        crate::models::correspondence::project(x, he, &self.m_w).map(|u| self.n.dot(&u) - self.d)
    }
}

/// The implicit measurement function `h = n₁ p_x + n₂ p_y − d p_z`.
pub fn residual<T: Scalar>(st: &State<T>, he: &HandEye<T>, obs: &ContourObservation<T>) -> T {
    (obs.along() * camera_point(&st.x, he, &obs.m_w))[0]
}

/// Linearisation of eq. 10c: the 1×3 block `∂h/∂s_w`, the 1×4 block `∂h/∂q_sw`, the noise
/// variance `r`, the depth of the model point, and `h` itself.
fn blocks<T: Scalar>(
    st: &State<T>,
    he: &HandEye<T>,
    obs: &ContourObservation<T>,
) -> ([T; 3], [T; 4], T, T, T) {
    let q = st.q().normalize();
    let rot = quat::rot(&q);
    let v = obs.m_w - st.v3(POS);
    let p_c = he.r_cs * (rot * v - he.c_s);
    let a_rcs = obs.along() * he.r_cs;
    let d_mw = a_rcs * rot; // ∂h/∂m_w = −∂h/∂s_w
    let d_q = a_rcs * quat::d_rotate_dq(&q, &v);
    let depth = p_c[2];
    // ∂h/∂d = −p_z.
    let r = obs.var_d * depth * depth + (d_mw * obs.cov_w * d_mw.transpose())[0];
    let h = (obs.along() * p_c)[0];
    (
        [-d_mw[0], -d_mw[1], -d_mw[2]],
        [d_q[0], d_q[1], d_q[2], d_q[3]],
        r,
        depth,
        h,
    )
}

/// Linearisation: the row of `∂h/∂x`, the noise variance `r` and the depth.
pub fn linearise<T: Scalar>(
    st: &State<T>,
    he: &HandEye<T>,
    obs: &ContourObservation<T>,
) -> (SparseRow<T>, T, T) {
    let (d_s, d_q, r, depth, _) = blocks(st, he, obs);
    let [row] = pose_rows(&[d_s], &[d_q]);
    (row, r, depth)
}

/// Applies one contour correspondence unless it is behind the camera, singular, or gated out
/// (the gate of eq. 17 with one degree of freedom, docs/FILTER.md §7). Returns the normalised
/// residual `s = h² / S` (infinite when it cannot be computed), and whether it was applied.
///
/// The covariance must be symmetric (every update and time update keeps it so).
pub fn update<T: ContourKernel>(
    st: &mut State<T>,
    prm: &Params<T>,
    obs: &ContourObservation<T>,
) -> (T, Result<(), Rejection>) {
    T::contour_update(st, prm, obs)
}

/// [`update`], instantiated through [`ContourKernel`]: a one-row [`PoseRows`].
fn update_generic<T: Scalar>(
    st: &mut State<T>,
    prm: &Params<T>,
    obs: &ContourObservation<T>,
) -> (T, Result<(), Rejection>) {
    let (d_s, d_q, r, depth, h) = blocks(st, &prm.hand_eye, obs);
    PoseRows {
        d_s: [d_s],
        d_q: [d_q],
        r: [[r]],
        h: [h],
        depth,
    }
    .update(st, prm)
}

/// [`update`], compiled in this crate for each scalar (why: [`crate::kernels`]).
pub trait ContourKernel: Scalar {
    /// [`update`] (every contour correspondence).
    fn contour_update(
        st: &mut State<Self>,
        prm: &Params<Self>,
        obs: &ContourObservation<Self>,
    ) -> (Self, Result<(), Rejection>);
}

macro_rules! contour_kernel {
    ($t:ty) => {
        impl ContourKernel for $t {
            #[inline(never)]
            fn contour_update(
                st: &mut State<Self>,
                prm: &Params<Self>,
                obs: &ContourObservation<Self>,
            ) -> (Self, Result<(), Rejection>) {
                update_generic(st, prm, obs)
            }
        }
    };
}
contour_kernel!(f32);
contour_kernel!(f64);

#[cfg(test)]
mod tests {
    use super::*;
    use crate::models::correspondence::{self, Observation};
    use crate::testutil::{params, random_state};
    use approx::assert_relative_eq;
    use nalgebra::Matrix2;
    use protocol::ModelKind;

    /// A model point 2 m in front of the camera, slightly off-axis, and a contour through a
    /// point near its projection.
    fn obs(st: &State<f64>, he: &HandEye<f64>) -> ContourObservation<f64> {
        let pose = crate::state::camera_pose(st, he);
        let r_wc = quat::rot(&pose.q_cw).transpose();
        let m_w = pose.c_w + r_wc * Vector3::new(0.3, -0.2, 2.0);
        let n = Vector2::new(0.6, -0.8);
        ContourObservation {
            m_w,
            cov_w: Matrix3::new(1e-4, 1e-5, 0.0, 1e-5, 2e-4, 0.0, 0.0, 0.0, 3e-4),
            n,
            d: n.dot(&Vector2::new(0.16, -0.09)),
            var_d: 2e-6,
        }
    }

    #[test]
    fn jacobians_match_central_differences() {
        let prm = params::<f64>(ModelKind::Acc);
        let st = random_state(prm.n, 31);
        let o = obs(&st, &prm.hand_eye);
        let he = &prm.hand_eye;
        let (row, r, _) = linearise(&st, he, &o);
        let dense = row.dense();
        for j in 0..prm.n {
            let mut plus = st.clone();
            let mut minus = st.clone();
            plus.x[j] += 1e-6;
            minus.x[j] -= 1e-6;
            let fd = (residual(&plus, he, &o) - residual(&minus, he, &o)) / 2e-6;
            assert_relative_eq!(dense[j], fd, epsilon = 1e-7);
        }
        // r = (∂h/∂d)² σ_d² + J_w P_w J_wᵀ, J from central differences in d and m_w.
        let (mut a, mut b) = (o, o);
        a.d += 1e-6;
        b.d -= 1e-6;
        let j_d = (residual(&st, he, &a) - residual(&st, he, &b)) / 2e-6;
        let mut j_w = RowVector3::zeros();
        for k in 0..3 {
            let (mut a, mut b) = (o, o);
            a.m_w[k] += 1e-6;
            b.m_w[k] -= 1e-6;
            j_w[k] = (residual(&st, he, &a) - residual(&st, he, &b)) / 2e-6;
        }
        let fd_r = j_d * j_d * o.var_d + (j_w * o.cov_w * j_w.transpose())[0];
        assert_relative_eq!(r, fd_r, epsilon = 1e-12, max_relative = 1e-6);
    }

    /// A contour is the 2D/3D correspondence seen along its normal: with the image point's
    /// variance along the normal σ_d² and an infinite one across it, the 2D update would
    /// equal this one. Checked through the residual and the update's effect on the state.
    #[test]
    fn it_is_the_point_measurement_projected_on_the_normal() {
        let prm = params::<f64>(ModelKind::Acc);
        let st = random_state(prm.n, 32);
        let o = obs(&st, &prm.hand_eye);
        let u = Vector2::new(0.16, -0.09);
        let point = Observation {
            m_n: u,
            cov_n: Matrix2::identity() * 1e-6,
            m_w: o.m_w,
            cov_w: o.cov_w,
        };
        let h2 = correspondence::residual(&st, &prm.hand_eye, &point);
        assert_relative_eq!(
            residual(&st, &prm.hand_eye, &o),
            o.n.dot(&h2),
            epsilon = 1e-12
        );
    }

    #[test]
    fn an_update_moves_the_projection_onto_the_contour_along_the_normal_only() {
        let prm = params::<f64>(ModelKind::Acc);
        let mut st = random_state(prm.n, 33);
        let mut o = obs(&st, &prm.hand_eye);
        let he = prm.hand_eye;
        // The contour 0.01 normalised units (about 5 px) beyond the projection, found exactly.
        let before = o.offset(&st.x, &he).unwrap();
        o.d += before + 0.01;
        o.var_d = 1e-10;
        o.cov_w = Matrix3::zeros();
        let (s, result) = update(&mut st, &prm, &o);
        assert_eq!(result, Ok(()));
        assert!(s.is_finite() && s > 0.0);
        // After the update the projection lies (almost) on the contour: a confident
        // measurement against an uncertain state.
        let after = o.offset(&st.x, &he).unwrap();
        assert!(after.abs() < 1e-4, "{before} → {after}");
    }

    #[test]
    fn outliers_and_points_behind_are_refused_without_touching_the_state() {
        let prm = params::<f64>(ModelKind::Gravity);
        let mut st = random_state(prm.n, 34);
        st.p *= 1e-4;
        let mut o = obs(&st, &prm.hand_eye);
        o.d += 0.5;
        let before = st.clone();
        let (s, r) = update(&mut st, &prm, &o);
        assert_eq!(r, Err(Rejection::Gated));
        assert!(s > prm.gate);
        assert_eq!(st, before);

        let pose = crate::state::camera_pose(&st, &prm.hand_eye);
        o.m_w = pose.c_w - quat::rot(&pose.q_cw).transpose() * Vector3::new(0.0, 0.0, 1.0);
        let (s, r) = update(&mut st, &prm, &o);
        assert_eq!(r, Err(Rejection::BehindCamera));
        assert!(s.is_infinite());
        assert_eq!(st, before);
    }
}
