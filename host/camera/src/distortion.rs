//! Lens distortion in normalised image coordinates: radial-tangential and equidistant.

use nalgebra::{Matrix2, Vector2};

/// Newton iterations allowed before undistortion gives up.
const MAX_ITERATIONS: usize = 50;

/// A lens distortion model acting on normalised image points (`z = 1` plane).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Distortion {
    /// An ideal pinhole.
    None,
    /// Radial-tangential (EuRoC `radial-tangential`, Kalibr `radtan`, OpenCV `plumb_bob`):
    /// `x_d = x (1 + k1 r² + k2 r⁴ + k3 r⁶) + 2 p1 x y + p2 (r² + 2x²)`,
    /// `y_d = y (1 + k1 r² + k2 r⁴ + k3 r⁶) + p1 (r² + 2y²) + 2 p2 x y`.
    RadTan {
        /// Radial r².
        k1: f64,
        /// Radial r⁴.
        k2: f64,
        /// Tangential 1.
        p1: f64,
        /// Tangential 2.
        p2: f64,
        /// Radial r⁶ (0 in EuRoC/Kalibr files).
        k3: f64,
    },
    /// Equidistant fisheye (Kalibr `equidistant`, OpenCV `fisheye`): with `θ = atan r`,
    /// `θ_d = θ (1 + k1 θ² + k2 θ⁴ + k3 θ⁶ + k4 θ⁸)` and `x_d = (θ_d / r) x`.
    Equidistant {
        /// θ² coefficient.
        k1: f64,
        /// θ⁴ coefficient.
        k2: f64,
        /// θ⁶ coefficient.
        k3: f64,
        /// θ⁸ coefficient.
        k4: f64,
    },
}

impl Distortion {
    /// Whether all coefficients are finite.
    pub fn is_finite(&self) -> bool {
        match *self {
            Self::None => true,
            Self::RadTan { k1, k2, p1, p2, k3 } => {
                [k1, k2, p1, p2, k3].iter().all(|v| v.is_finite())
            }
            Self::Equidistant { k1, k2, k3, k4 } => [k1, k2, k3, k4].iter().all(|v| v.is_finite()),
        }
    }

    /// Distorts an undistorted normalised point.
    pub fn distort(&self, n: Vector2<f64>) -> Vector2<f64> {
        match *self {
            Self::None => n,
            Self::RadTan { k1, k2, p1, p2, k3 } => {
                let (x, y) = (n.x, n.y);
                let r2 = x * x + y * y;
                let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
                Vector2::new(
                    x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
                    y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y,
                )
            }
            Self::Equidistant { .. } => {
                let r = n.norm();
                if r < 1e-12 {
                    // θ_d/r → 1 at the centre.
                    return n;
                }
                n * (self.theta_d(r.atan()) / r)
            }
        }
    }

    /// Undistorts a distorted normalised point by Newton's method. `None` if it does not
    /// converge (a point outside the region where the model is invertible).
    pub fn undistort(&self, d: Vector2<f64>) -> Option<Vector2<f64>> {
        if !d.x.is_finite() || !d.y.is_finite() {
            return None;
        }
        match *self {
            Self::None => Some(d),
            Self::RadTan { .. } => self.undistort_radtan(d),
            Self::Equidistant { .. } => self.undistort_equidistant(d),
        }
    }

    /// `θ_d(θ)` of the equidistant model (identity for the others).
    fn theta_d(&self, theta: f64) -> f64 {
        match *self {
            Self::Equidistant { k1, k2, k3, k4 } => {
                let t2 = theta * theta;
                theta * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))
            }
            _ => theta,
        }
    }

    /// Jacobian of [`Self::distort`] for radial-tangential.
    fn radtan_jacobian(&self, n: Vector2<f64>) -> Matrix2<f64> {
        let Self::RadTan { k1, k2, p1, p2, k3 } = *self else {
            return Matrix2::identity();
        };
        let (x, y) = (n.x, n.y);
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
        // d(radial)/d(r²)
        let dr = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2);
        Matrix2::new(
            radial + 2.0 * x * x * dr + 2.0 * p1 * y + 6.0 * p2 * x,
            2.0 * x * y * dr + 2.0 * p1 * x + 2.0 * p2 * y,
            2.0 * x * y * dr + 2.0 * p1 * x + 2.0 * p2 * y,
            radial + 2.0 * y * y * dr + 6.0 * p1 * y + 2.0 * p2 * x,
        )
    }

    fn undistort_radtan(&self, d: Vector2<f64>) -> Option<Vector2<f64>> {
        let mut n = d;
        for _ in 0..MAX_ITERATIONS {
            let residual = self.distort(n) - d;
            let step = self.radtan_jacobian(n).try_inverse()? * residual;
            n -= step;
            if !n.x.is_finite() || !n.y.is_finite() {
                return None;
            }
            // Quadratic convergence: once the step is at round-off level we are done.
            if step.norm() <= 1e-15 * (1.0 + n.norm()) {
                break;
            }
        }
        let residual = (self.distort(n) - d).norm();
        (residual <= 1e-12 * (1.0 + d.norm())).then_some(n)
    }

    fn undistort_equidistant(&self, d: Vector2<f64>) -> Option<Vector2<f64>> {
        let rd = d.norm();
        if rd < 1e-12 {
            return Some(d);
        }
        // Solve θ_d(θ) = r_d for θ in [0, π/2), then r = tan θ.
        let mut theta = rd.min(1.5);
        for _ in 0..MAX_ITERATIONS {
            let f = self.theta_d(theta) - rd;
            let Self::Equidistant { k1, k2, k3, k4 } = *self else {
                return None;
            };
            let t2 = theta * theta;
            let df = 1.0 + t2 * (3.0 * k1 + t2 * (5.0 * k2 + t2 * (7.0 * k3 + t2 * 9.0 * k4)));
            if df.abs() < 1e-12 {
                return None;
            }
            let step = f / df;
            theta -= step;
            if step.abs() <= 1e-16 * (1.0 + theta.abs()) {
                break;
            }
        }
        if !theta.is_finite()
            || !(0.0..std::f64::consts::FRAC_PI_2).contains(&theta)
            || (self.theta_d(theta) - rd).abs() > 1e-12 * (1.0 + rd)
        {
            return None;
        }
        Some(d * (theta.tan() / rd))
    }
}
