//! A camera pose's uncertainty: the core's covariance of `[c_w, θ]` (protocol `Sym6`), its
//! normalised estimation error squared against a true pose, and the direction it pins down
//! least (docs/VISION.md §10, eq. T6–T7).

use nalgebra::{Matrix3, Matrix6, SymmetricEigen, Vector3, Vector6};

use super::CameraPose;

/// The covariance of a camera pose `[c_w, θ]`: `c_w` the camera centre [m], θ the rotation
/// error of `q_cw` as a world-frame rotation vector [rad] (`q_cw = q̂_cw ⊗ exp(θ/2)`), as the
/// core sends it (protocol `PosePrediction::cov`, `StateReport::cov`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseCovariance(Matrix6<f64>);

/// What a weakly constrained direction moves.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Motion {
    /// The object's position in the camera.
    Translation,
    /// The object's orientation about its centre.
    Rotation,
}

/// The direction a covariance pins down least, in the object-in-camera frame (x right,
/// y down, z along the view): which motion dominates it, about or along which camera axis,
/// and its standard deviation in units of the success bound (eq. T7).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WeakDirection {
    /// Translation or rotation, whichever dominates the direction.
    pub motion: Motion,
    /// The dominant part's unit axis in the camera frame.
    pub axis_c: Vector3<f64>,
    /// Its standard deviation in units of the bound (1: one σ spans the whole bound).
    pub sigma: f64,
}

impl WeakDirection {
    /// A short name: "depth", "sideways", "up-down", "roll about the view", "pan", "tilt"
    /// (the camera axis the dominant part lies closest to).
    pub fn name(&self) -> &'static str {
        let a = self.axis_c.abs();
        let axis = if a.z >= a.x && a.z >= a.y {
            2
        } else if a.x >= a.y {
            0
        } else {
            1
        };
        match (self.motion, axis) {
            (Motion::Translation, 0) => "sideways",
            (Motion::Translation, 1) => "up-down",
            (Motion::Translation, _) => "depth",
            // About camera x the object tilts towards the camera; about y it turns side to side.
            (Motion::Rotation, 0) => "tilt",
            (Motion::Rotation, 1) => "pan",
            (Motion::Rotation, _) => "roll about the view",
        }
    }
}

impl PoseCovariance {
    /// From the upper triangle row by row (protocol `Sym6`); `None` unless finite, symmetric
    /// positive semi-definite to rounding.
    pub fn from_upper(upper: &[f32; 21]) -> Option<Self> {
        let mut m = Matrix6::zeros();
        let mut k = 0;
        for r in 0..6 {
            for c in r..6 {
                m[(r, c)] = f64::from(upper[k]);
                m[(c, r)] = f64::from(upper[k]);
                k += 1;
            }
        }
        Self::new(m)
    }

    /// From a full matrix; `None` unless finite and symmetric positive semi-definite to
    /// rounding.
    pub fn new(m: Matrix6<f64>) -> Option<Self> {
        if !m.iter().all(|v| v.is_finite()) {
            return None;
        }
        let m = (m + m.transpose()) * 0.5;
        let scale = m.diagonal().max().max(f64::MIN_POSITIVE);
        let smallest = SymmetricEigen::new(m).eigenvalues.min();
        (smallest >= -1e-6 * scale).then_some(Self(m))
    }

    /// The matrix.
    pub fn matrix(&self) -> &Matrix6<f64> {
        &self.0
    }

    /// The upper triangle row by row (as the wire and `frames.csv` hold it).
    pub fn upper(&self) -> [f64; 21] {
        let mut u = [0.0; 21];
        let mut k = 0;
        for r in 0..6 {
            for c in r..6 {
                u[k] = self.0[(r, c)];
                k += 1;
            }
        }
        u
    }

    /// The largest standard deviation of the camera centre along any direction [m].
    pub fn position_sigma_m(&self) -> f64 {
        largest_sigma(&self.0.fixed_view::<3, 3>(0, 0).into_owned())
    }

    /// The largest standard deviation of the orientation about any axis [rad].
    pub fn rotation_sigma_rad(&self) -> f64 {
        largest_sigma(&self.0.fixed_view::<3, 3>(3, 3).into_owned())
    }

    /// The normalised estimation error squared of `estimate` against `truth` (eq. T6):
    /// `eᵀ P⁻¹ e`, `e = [ĉ_w − c_w, θ]`, θ the world-frame rotation vector of `q_cw⁻¹ q̂_cw`.
    /// χ²₆ where the covariance is calibrated; `None` where `P` is singular.
    pub fn nees(&self, estimate: &CameraPose, truth: &CameraPose) -> Option<f64> {
        let d = estimate.c_w - truth.c_w;
        let theta = (truth.q_cw.inverse() * estimate.q_cw).scaled_axis();
        let e = Vector6::new(d.x, d.y, d.z, theta.x, theta.y, theta.z);
        let chol = self.0.cholesky()?;
        let v = e.dot(&chol.solve(&e));
        v.is_finite().then_some(v)
    }

    /// The direction pinned down least (eq. T7): the covariance moved to the object in the
    /// camera (its centre `centre_w` in the world, the pose `pose`), scaled by the success
    /// bound (`bound_m` on the translation, `bound_rad` on the rotation), its largest
    /// eigenvector.
    pub fn weakest(
        &self,
        pose: &CameraPose,
        centre_w: &Vector3<f64>,
        bound_m: f64,
        bound_rad: f64,
    ) -> WeakDirection {
        let r = pose.q_cw.to_rotation_matrix().into_inner();
        // The object's centre in the camera, t = R (p − c_w), with R̂ = R exp([θ]×):
        // δt = −R δc − R [p − c_w]× θ; its rotation φ = R θ.
        let mut j = Matrix6::zeros();
        j.fixed_view_mut::<3, 3>(0, 0).copy_from(&(-r));
        j.fixed_view_mut::<3, 3>(0, 3)
            .copy_from(&(-r * (centre_w - pose.c_w).cross_matrix()));
        j.fixed_view_mut::<3, 3>(3, 3).copy_from(&r);
        let scale = Matrix6::from_diagonal(&Vector6::new(
            1.0 / bound_m,
            1.0 / bound_m,
            1.0 / bound_m,
            1.0 / bound_rad,
            1.0 / bound_rad,
            1.0 / bound_rad,
        ));
        let s = scale * j * self.0 * j.transpose() * scale;
        let eigen = SymmetricEigen::new((s + s.transpose()) * 0.5);
        let i = eigen.eigenvalues.imax();
        let v = eigen.eigenvectors.column(i);
        let (t, phi) = (v.fixed_rows::<3>(0), v.fixed_rows::<3>(3));
        let (motion, part) = if t.norm() >= phi.norm() {
            (Motion::Translation, t.into_owned())
        } else {
            (Motion::Rotation, phi.into_owned())
        };
        WeakDirection {
            motion,
            axis_c: part.try_normalize(1e-12).unwrap_or_else(Vector3::z),
            sigma: eigen.eigenvalues[i].max(0.0).sqrt(),
        }
    }
}

/// The square root of a 3×3 covariance's largest eigenvalue.
fn largest_sigma(m: &Matrix3<f64>) -> f64 {
    SymmetricEigen::new(*m).eigenvalues.max().max(0.0).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::UnitQuaternion;

    fn pose() -> CameraPose {
        CameraPose::look_at(Vector3::new(0.0, -0.5, 0.3), Vector3::zeros(), Vector3::z()).unwrap()
    }

    #[test]
    fn the_upper_triangle_goes_both_ways_and_bad_matrices_are_refused() {
        let mut u = [0.0f32; 21];
        for (k, v) in u.iter_mut().enumerate() {
            *v = k as f32 * 1e-3;
        }
        // Diagonal entries dominate: positive definite.
        for (i, k) in [0, 6, 11, 15, 18, 20].into_iter().enumerate() {
            u[k] = 1.0 + i as f32;
        }
        let p = PoseCovariance::from_upper(&u).unwrap();
        for (a, b) in p.upper().iter().zip(u) {
            assert!((a - f64::from(b)).abs() < 1e-9);
        }
        assert_eq!(p.matrix()[(1, 0)], p.matrix()[(0, 1)]);
        u[0] = f32::NAN;
        assert!(PoseCovariance::from_upper(&u).is_none());
        let mut m = Matrix6::identity();
        m[(2, 2)] = -1.0;
        assert!(PoseCovariance::new(m).is_none());
    }

    #[test]
    fn the_nees_of_drawn_errors_averages_six() {
        // A correlated covariance; errors drawn from it by its Cholesky factor.
        let a = Matrix6::from_fn(|r, c| {
            ((r * 7 + c * 3) % 5) as f64 * 0.1 + f64::from(u8::from(r == c))
        });
        let p = PoseCovariance::new(a * a.transpose() * 1e-4).unwrap();
        let l = p.matrix().cholesky().unwrap().l();
        let truth = pose();
        let mut state = 1u64;
        let mut normal = || {
            // Box–Muller from a small LCG: deterministic, enough for a mean.
            let mut u = || {
                state = state
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                ((state >> 11) as f64 + 0.5) / (1u64 << 53) as f64
            };
            let (u1, u2) = (u(), u());
            (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
        };
        let n = 4000;
        let mut sum = 0.0;
        for _ in 0..n {
            let z = Vector6::from_fn(|_, _| normal());
            let e = l * z;
            let estimate = CameraPose {
                c_w: truth.c_w + e.fixed_rows::<3>(0),
                q_cw: truth.q_cw
                    * UnitQuaternion::from_scaled_axis(e.fixed_rows::<3>(3).into_owned()),
            };
            sum += p.nees(&estimate, &truth).unwrap();
        }
        let mean = sum / f64::from(n);
        assert!((5.7..6.3).contains(&mean), "{mean}");
    }

    #[test]
    fn the_weakest_direction_is_named_in_the_camera() {
        let pose = pose();
        let centre = Vector3::zeros();
        let r_wc = pose.q_cw.inverse().to_rotation_matrix().into_inner();
        // The camera centre uncertain along the view (world direction of camera z): depth.
        let view = r_wc.column(2).into_owned();
        let mut m = Matrix6::identity() * 1e-8;
        m.fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&(view * view.transpose() * 4e-4 + Matrix3::identity() * 1e-8));
        let w = PoseCovariance::new(m)
            .unwrap()
            .weakest(&pose, &centre, 0.01, 5f64.to_radians());
        assert_eq!((w.motion, w.name()), (Motion::Translation, "depth"));
        assert!((w.sigma - 2.0).abs() < 1e-3, "{}", w.sigma);
        // The orientation uncertain about the view axis, the centre with it (the camera
        // turning about its own axis): roll.
        let mut m = Matrix6::identity() * 1e-10;
        m.fixed_view_mut::<3, 3>(3, 3)
            .copy_from(&(view * view.transpose() * 1e-2 + Matrix3::identity() * 1e-10));
        let w = PoseCovariance::new(m).unwrap().weakest(
            &pose,
            &pose.c_w.clone(),
            0.01,
            5f64.to_radians(),
        );
        assert_eq!(
            (w.motion, w.name()),
            (Motion::Rotation, "roll about the view")
        );
        // An orbit: the camera carried about the object's vertical axis by α (its centre by
        // α u × (c − p), its q_cw by exp(−α u)) leaves the object's position in the camera
        // unchanged: a rotation.
        let up = Vector3::z();
        let mut orbit = Vector6::zeros();
        orbit
            .fixed_rows_mut::<3>(0)
            .copy_from(&up.cross(&(pose.c_w - centre)));
        orbit.fixed_rows_mut::<3>(3).copy_from(&(-up));
        let m = orbit * orbit.transpose() * 1e-2 + Matrix6::identity() * 1e-10;
        let w = PoseCovariance::new(m)
            .unwrap()
            .weakest(&pose, &centre, 0.01, 5f64.to_radians());
        assert_eq!(w.motion, Motion::Rotation, "{w:?}");
    }

    #[test]
    fn the_largest_sigmas_are_per_block() {
        let m = Matrix6::from_diagonal(&Vector6::new(1e-4, 4e-4, 1e-4, 1e-6, 1e-6, 9e-6));
        let p = PoseCovariance::new(m).unwrap();
        assert!((p.position_sigma_m() - 0.02).abs() < 1e-12);
        assert!((p.rotation_sigma_rad() - 3e-3).abs() < 1e-12);
    }
}
