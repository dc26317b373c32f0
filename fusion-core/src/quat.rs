//! Hamilton quaternions `[w, x, y, z]` as plain 4-vectors (the filter keeps the quaternion in
//! its state vector, so it needs the raw vector and its Jacobians, not a unit-quaternion type).
//! `q_ba` rotates vectors from frame `a` into frame `b`: `v_b = R(q_ba) v_a` (docs/FILTER.md §2).

use nalgebra::{Matrix3, Matrix3x4, Matrix4, Matrix4x3, Vector3, Vector4};

use crate::scalar::Scalar;

/// Quaternion as `[w, x, y, z]`.
pub type Quat<T> = Vector4<T>;

/// The identity rotation.
pub fn identity<T: Scalar>() -> Quat<T> {
    Vector4::new(T::one(), T::zero(), T::zero(), T::zero())
}

/// Vector part `[x, y, z]`.
pub fn vec_part<T: Scalar>(q: &Quat<T>) -> Vector3<T> {
    Vector3::new(q[1], q[2], q[3])
}

/// Conjugate (the inverse of a unit quaternion).
pub fn conj<T: Scalar>(q: &Quat<T>) -> Quat<T> {
    Vector4::new(q[0], -q[1], -q[2], -q[3])
}

/// Matrix `L(a)` with `a ⊙ b = L(a) b`.
pub fn left<T: Scalar>(a: &Quat<T>) -> Matrix4<T> {
    let (w, x, y, z) = (a[0], a[1], a[2], a[3]);
    Matrix4::new(w, -x, -y, -z, x, w, -z, y, y, z, w, -x, z, -y, x, w)
}

/// Matrix `R(b)` with `a ⊙ b = R(b) a`.
pub fn right<T: Scalar>(b: &Quat<T>) -> Matrix4<T> {
    let (w, x, y, z) = (b[0], b[1], b[2], b[3]);
    Matrix4::new(w, -x, -y, -z, x, w, z, -y, y, -z, w, x, z, y, -x, w)
}

/// Hamilton product `a ⊙ b`.
pub fn mul<T: Scalar>(a: &Quat<T>, b: &Quat<T>) -> Quat<T> {
    left(a) * b
}

/// Rotation matrix of a unit quaternion.
pub fn rot<T: Scalar>(q: &Quat<T>) -> Matrix3<T> {
    let (w, x, y, z) = (q[0], q[1], q[2], q[3]);
    let one = T::one();
    let two = T::c(2.0);
    Matrix3::new(
        one - two * (y * y + z * z),
        two * (x * y - w * z),
        two * (x * z + w * y),
        two * (x * y + w * z),
        one - two * (x * x + z * z),
        two * (y * z - w * x),
        two * (x * z - w * y),
        two * (y * z + w * x),
        one - two * (x * x + y * y),
    )
}

/// Jacobian of `R(q/‖q‖) v` with respect to `q`, at a unit `q`.
///
/// The normalised rotation does not change along `q`, so the Jacobian is tangent
/// (`J q = 0`): measurements never pull the quaternion's norm.
pub fn d_rotate_dq<T: Scalar>(q: &Quat<T>, v: &Vector3<T>) -> Matrix3x4<T> {
    let w = q[0];
    let u = vec_part(q);
    let two = T::c(2.0);
    // Homogeneous form R_h(q) v = (w² − u·u) v + 2 u (u·v) + 2 w (u × v), degree 2 in q.
    let d_w = v * (two * w) + u.cross(v) * two;
    let d_u = v * u.transpose() * (-two)
        + (u * v.transpose() + Matrix3::identity() * u.dot(v)) * two
        - v.cross_matrix() * (two * w);
    let mut d = Matrix3x4::zeros();
    d.set_column(0, &d_w);
    d.fixed_view_mut::<3, 3>(0, 1).copy_from(&d_u);
    // d/dq [R_h v / ‖q‖²] at ‖q‖ = 1 is D − 2 (R v) qᵀ, i.e. D (I − q qᵀ).
    let rv = rot(q) * v;
    d - rv * q.transpose() * two
}

/// `exp(v) = [cos‖v‖, v/‖v‖ · sin‖v‖]` of `v = −T/2 · ω` and its Jacobian with respect to `ω`
/// (the rotation increment of eq. 7).
pub fn exp_increment<T: Scalar>(omega: &Vector3<T>, dt: T) -> (Quat<T>, Matrix4x3<T>) {
    let v = omega * (-dt * T::c(0.5));
    let theta2 = v.norm_squared();
    let theta = theta2.sqrt();
    // cos θ, sin θ / θ and (θ cos θ − sin θ) / θ³. Below 0.1 rad (every IMU step but the
    // fastest spins) their Taylor series, to the last term that matters in f64 (the next is
    // below 3e-17 relative): no 0/0 near 0, and no libm `sinf`/`cosf`, which compute in
    // software doubles on the MCU.
    let (cos, sinc, dsinc) = if theta < T::c(0.1) {
        let t = theta2;
        let c = |x: f64| T::c(x);
        (
            T::one()
                - t * (c(0.5) - t * (c(1.0 / 24.0) - t * (c(1.0 / 720.0) - t * c(1.0 / 40320.0)))),
            T::one()
                - t * (c(1.0 / 6.0)
                    - t * (c(1.0 / 120.0) - t * (c(1.0 / 5040.0) - t * c(1.0 / 362880.0)))),
            -c(1.0 / 3.0)
                + t * (c(1.0 / 30.0)
                    - t * (c(1.0 / 840.0) - t * (c(1.0 / 45360.0) - t * c(1.0 / 3991680.0)))),
        )
    } else {
        let (s, c) = theta.sin_cos_of();
        (c, s / theta, (theta * c - s) / (theta2 * theta))
    };
    let dq = Vector4::new(cos, sinc * v[0], sinc * v[1], sinc * v[2]);
    let mut d_dv = Matrix4x3::zeros();
    d_dv.set_row(0, &(v.transpose() * (-sinc)));
    let block = Matrix3::identity() * sinc + v * v.transpose() * dsinc;
    d_dv.fixed_view_mut::<3, 3>(1, 0).copy_from(&block);
    (dq, d_dv * (-dt * T::c(0.5)))
}

/// Rotation about a unit axis by `angle`.
pub fn from_axis_angle<T: Scalar>(axis: &Vector3<T>, angle: T) -> Quat<T> {
    let h = angle * T::c(0.5);
    let (s, c) = h.sin_cos_of();
    Vector4::new(c, axis[0] * s, axis[1] * s, axis[2] * s)
}

/// `q_ws` of a body with yaw `ψ`, pitch `θ`, roll `φ` (z-y-x order): `R_z(ψ) R_y(θ) R_x(φ)`.
pub fn from_euler_zyx<T: Scalar>(yaw: T, pitch: T, roll: T) -> Quat<T> {
    let z = from_axis_angle(&Vector3::z(), yaw);
    let y = from_axis_angle(&Vector3::y(), pitch);
    let x = from_axis_angle(&Vector3::x(), roll);
    mul(&mul(&z, &y), &x)
}

/// Yaw of the body whose orientation is `q_ws` (z-y-x convention).
pub fn yaw_of<T: Scalar>(q_ws: &Quat<T>) -> T {
    let (w, x, y, z) = (q_ws[0], q_ws[1], q_ws[2], q_ws[3]);
    let two = T::c(2.0);
    (two * (w * z + x * y)).atan2(T::one() - two * (y * y + z * z))
}

/// Rotation vector `θ` of a small rotation error: for `q_true = q ⊙ [1, θ/2]`, the Jacobian
/// `∂θ/∂q_true = 2 · rows 1..4 of L(q̄)`.
pub fn d_theta_dq<T: Scalar>(q: &Quat<T>) -> Matrix3x4<T> {
    left(&conj(q)).fixed_rows::<3>(1) * T::c(2.0)
}

#[cfg(test)]
mod tests {
    extern crate std;

    use super::*;
    use approx::assert_relative_eq;

    fn q(w: f64, x: f64, y: f64, z: f64) -> Quat<f64> {
        Vector4::new(w, x, y, z).normalize()
    }

    #[test]
    fn rot_matches_the_sandwich_product() {
        let a = q(0.9, 0.1, -0.3, 0.2);
        let v = Vector3::new(0.3, -1.0, 2.0);
        let p = Vector4::new(0.0, v[0], v[1], v[2]);
        let sandwich = mul(&mul(&a, &p), &conj(&a));
        assert_relative_eq!(rot(&a) * v, vec_part(&sandwich), epsilon = 1e-12);
        assert_relative_eq!(mul(&a, &p), right(&p) * a, epsilon = 1e-12);
    }

    #[test]
    fn rotation_jacobian_matches_central_differences() {
        let a = q(0.7, -0.2, 0.4, 0.5);
        let v = Vector3::new(0.3, -1.0, 2.0);
        let f = |q: &Quat<f64>| rot(&q.normalize()) * v;
        let analytic = d_rotate_dq(&a, &v);
        for k in 0..4 {
            let mut e = Vector4::zeros();
            e[k] = 1e-6;
            let fd = (f(&(a + e)) - f(&(a - e))) / 2e-6;
            assert_relative_eq!(analytic.column(k).into_owned(), fd, epsilon = 1e-8);
        }
        assert_relative_eq!(analytic * a, Vector3::zeros(), epsilon = 1e-12);
    }

    #[test]
    fn increment_jacobian_matches_central_differences() {
        for omega in [Vector3::new(0.3, -2.0, 1.0), Vector3::new(1e-7, 0.0, -2e-7)] {
            let dt = 0.01;
            let (dq, d) = exp_increment(&omega, dt);
            assert_relative_eq!(dq.norm(), 1.0, epsilon = 1e-12);
            for k in 0..3 {
                let mut e = Vector3::zeros();
                e[k] = 1e-6;
                let fd =
                    (exp_increment(&(omega + e), dt).0 - exp_increment(&(omega - e), dt).0) / 2e-6;
                assert_relative_eq!(d.column(k).into_owned(), fd, epsilon = 1e-8);
            }
        }
    }

    #[test]
    fn increment_series_matches_the_closed_form() {
        // Just below and just above the series' 0.1 rad limit, and well below it.
        for theta in [0.0999999f64, 0.1000001, 0.05, 1e-3] {
            let omega = Vector3::new(0.6, -0.8, 0.0) * (theta / 0.005);
            let (dq, d) = exp_increment(&omega, 0.01);
            let axis = Vector3::new(-0.6, 0.8, 0.0);
            let exact = Vector4::new(
                theta.cos(),
                axis[0] * theta.sin(),
                axis[1] * theta.sin(),
                0.0,
            );
            assert_relative_eq!(dq, exact, epsilon = 1e-15);
            let e = Vector3::new(0.0, 0.0, 1e-6);
            let fd =
                (exp_increment(&(omega + e), 0.01).0 - exp_increment(&(omega - e), 0.01).0) / 2e-6;
            assert_relative_eq!(d.column(2).into_owned(), fd, epsilon = 1e-9);
        }
    }

    #[test]
    fn increment_rotates_by_minus_omega_dt() {
        // q_sw ← exp(−T/2 ω) ⊙ q_sw: a world vector seen from a sensor turning at +ω about z
        // turns by −ωT in the sensor frame.
        let (dq, _) = exp_increment(&Vector3::new(0.0, 0.0, 1.0), 0.5);
        let v = rot(&dq) * Vector3::x();
        assert_relative_eq!(
            v,
            Vector3::new(0.5f64.cos(), -(0.5f64.sin()), 0.0),
            epsilon = 1e-12
        );
    }

    #[test]
    fn euler_and_yaw_round_trip() {
        let q_ws = from_euler_zyx(1.2, -0.3, 0.4);
        assert_relative_eq!(yaw_of(&q_ws), 1.2, epsilon = 1e-12);
    }

    #[test]
    fn theta_jacobian_matches_central_differences() {
        let a = q(0.7, -0.2, 0.4, 0.5);
        let theta = |qt: &Quat<f64>| vec_part(&mul(&conj(&a), &qt.normalize())) * 2.0;
        let analytic = d_theta_dq(&a);
        for k in 0..4 {
            let mut e = Vector4::zeros();
            e[k] = 1e-6;
            let fd = (theta(&(a + e)) - theta(&(a - e))) / 2e-6;
            assert_relative_eq!(analytic.column(k).into_owned(), fd, epsilon = 1e-6);
        }
    }
}
