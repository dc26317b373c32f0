//! Divergence monitor (paper §4.6): any of three tests fires.
//!
//! 1. the low-passed normalised residual `g ← λg + (1−λ)s_i` of vision measurements exceeds a
//!    threshold (catches divergence while vision is available);
//! 2. the Frobenius norm of the state covariance exceeds a threshold (catches the unbounded
//!    uncertainty growth of dead reckoning without vision);
//! 3. the quaternion's norm before normalisation is far from 1 (a wild update).

use protocol::StatusReason;

use crate::params::Params;
use crate::scalar::Scalar;
use crate::state::State;

/// State of the monitor.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Monitor<T: Scalar> {
    /// Low-passed normalised residual `g`.
    pub g: T,
}

impl<T: Scalar> Monitor<T> {
    /// A fresh monitor.
    pub const fn new() -> Self {
        Monitor { g: T::ZERO }
    }

    /// Feeds one normalised residual; a gated outlier counts too (a diverged filter sees only
    /// "outliers"), clamped to twice the threshold so a single wild one cannot fire the test.
    pub fn residual(&mut self, s: T, prm: &Params<T>) -> Option<StatusReason> {
        let cap = prm.residual_threshold * T::c(2.0);
        let s = if s.is_finite() && s < cap { s } else { cap };
        self.g = prm.lowpass * self.g + (T::one() - prm.lowpass) * s;
        (self.g > prm.residual_threshold).then_some(StatusReason::ResidualLowpass)
    }

    /// Test 3 and finiteness, after every IMU step (cheap: a non-finite covariance shows on
    /// its diagonal within a step).
    pub fn step(st: &State<T>, quat_norm_error: T, prm: &Params<T>) -> Option<StatusReason> {
        let diag_finite = (0..prm.n).all(|i| st.p[(i, i)].is_finite());
        if !diag_finite || !st.x.iter().all(|v| v.is_finite()) {
            Some(StatusReason::NonFiniteState)
        } else if quat_norm_error > prm.quat_norm_threshold {
            Some(StatusReason::QuaternionNorm)
        } else {
            None
        }
    }

    /// Test 2, and full finiteness, at each camera trigger: the covariance grows slowly, so
    /// checking it at frame rate costs a fraction and misses nothing.
    pub fn frame(st: &State<T>, prm: &Params<T>) -> Option<StatusReason> {
        if !st.is_finite() {
            Some(StatusReason::NonFiniteState)
        } else if st.cov_frobenius() > prm.cov_threshold {
            Some(StatusReason::CovarianceNorm)
        } else {
            None
        }
    }
}
