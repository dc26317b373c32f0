//! Divergence monitor (paper §4.6): any of three tests fires.
//!
//! 1. the low-passed normalised residual of vision measurements exceeds a threshold `τ`
//!    (catches divergence while vision is available). It is low-passed per camera frame,
//!    `g ← λg + (1−λ)s̄`, where `s̄` is the frame's mean normalised residual `s_i` (eq. 17), each
//!    `s_i` (a gated outlier's too: a diverged filter sees only "outliers") capped at
//!    `c = τ(2−λ) / (2(1−λ))`. A frame is one look at the model, so one wild correspondence, or
//!    a partly occluded frame, moves `g` by at most one frame's share, and the cap makes the
//!    test's promises independent of λ: from `g ≤ τ/2` no single frame can fire it
//!    (`λτ/2 + (1−λ)c = τ`), two consecutive frames of nothing but outliers always do
//!    (`(1−λ)(1+λ)c = τ(1 + λ(1−λ)/2) > τ`), and so does a sustained share of outliers above
//!    `τ/c = 2(1−λ)/(2−λ)` (a third at λ = 0.8). The frame that fires is not applied: its
//!    snapshot is dropped with the re-initialisation. The monitor restarts at every gap of
//!    [`crate::device::NO_VISION_FRAMES`] camera periods or more between the frames it judges
//!    ([`Monitor::look`]): frames on either side of a gap are not consecutive looks at one state;
//! 2. the Frobenius norm of the state covariance exceeds a threshold (catches the unbounded
//!    uncertainty growth of dead reckoning without vision);
//! 3. a measurement update moves the quaternion off the sphere: the radial part of its step
//!    exceeds a threshold ([`crate::ekf::radial_step`]; a correct update's step is tangential
//!    and only grows the norm by `θ²/8`, which the normalisation before each time update
//!    removes). An IMU sample's update is judged alone; a frame's correspondences together,
//!    from the quaternion before its first part ([`crate::delay::Snapshot::q_ref`]).

use protocol::StatusReason;

use crate::params::Params;
use crate::scalar::Scalar;
use crate::state::{N, QUAT, State, StateKernels, all_finite_generic};

/// State of the monitor.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Monitor<T: Scalar> {
    /// Low-passed per-frame normalised residual `g`.
    pub g: T,
    /// The frame whose residuals are being summed, if any.
    frame: Option<u32>,
    /// Sum of that frame's capped residuals.
    sum: T,
    /// How many.
    count: u32,
    /// Trigger time [µs] of the last frame whose residuals it took, if any.
    last_look_us: Option<u64>,
}

impl<T: Scalar> Monitor<T> {
    /// A fresh monitor.
    pub const fn new() -> Self {
        Monitor {
            g: T::ZERO,
            frame: None,
            sum: T::ZERO,
            count: 0,
            last_look_us: None,
        }
    }

    /// A frame triggered at `t_us` brings residuals: if `gap_us` or more passed since the last
    /// frame that did, the monitor restarts first. Frames on either side of a gap are not
    /// consecutive looks at one state (the ones after it judge a dead-reckoned prediction), so
    /// its memory ends at every gap, in whatever mode (issue 32: it ended only when tracking
    /// did, and frames before and after a second gap were joined).
    pub fn look(&mut self, t_us: u64, gap_us: u64) {
        if let Some(last) = self.last_look_us
            && t_us.saturating_sub(last) >= gap_us
        {
            *self = Self::new();
        }
        self.last_look_us = Some(t_us);
    }

    /// Adds one normalised residual of `frame_id`, capped (gated outliers and non-finite ones
    /// count as the cap). A residual of another frame first closes the open one (a frame whose
    /// last part never came), which may fire the test.
    pub fn residual(&mut self, frame_id: u32, s: T, prm: &Params<T>) -> Option<StatusReason> {
        let fired = match self.frame {
            Some(f) if f != frame_id => self.close_frame(prm),
            _ => None,
        };
        let cap = prm.residual_cap;
        self.sum += if s.is_finite() && s < cap { s } else { cap };
        self.count = self.count.saturating_add(1);
        self.frame = Some(frame_id);
        fired
    }

    /// Ends the open frame: low-passes its mean residual into `g` and tests it.
    pub fn close_frame(&mut self, prm: &Params<T>) -> Option<StatusReason> {
        let count = core::mem::take(&mut self.count);
        let sum = core::mem::replace(&mut self.sum, T::zero());
        self.frame = None;
        if count == 0 {
            return None;
        }
        let mean = sum / T::c(count as f64);
        self.g = prm.lowpass * self.g + (T::one() - prm.lowpass) * mean;
        (self.g > prm.residual_threshold).then_some(StatusReason::ResidualLowpass)
    }

    /// Test 3 and finiteness, after every IMU step (cheap: a non-finite covariance shows on
    /// its diagonal within a step; the diagonal is tested as [`crate::state::all_finite`] does).
    pub fn step(st: &State<T>, quat_norm_error: T, prm: &Params<T>) -> Option<StatusReason> {
        let zero = T::zero();
        let diag = st.p.as_slice().iter().step_by(N + 1).take(prm.n);
        let diag_finite = diag.fold(zero, |acc, &v| acc + v * zero) == zero;
        // Inside the IMU step's kernel: the generic body, inlined there.
        // ‖q‖ itself, beside the update's radial step: a tangential step can move the norm
        // as far (issue 55: rates of 10⁶ rad/s gave ‖q‖ ≈ 2·10³⁶ with a norm error of 0).
        // |‖q‖² − 1| ≈ 2 |‖q‖ − 1|.
        let q = st.x.as_slice().get(QUAT..QUAT + 4).unwrap_or_default();
        let norm2 = q.iter().fold(zero, |acc, &v| acc + v * v);
        let norm_off = (norm2 - T::one()).abs() > T::c(2.0) * prm.quat_norm_threshold;
        if !diag_finite || !all_finite_generic(st.x.as_slice()) {
            Some(StatusReason::NonFiniteState)
        } else if quat_norm_error > prm.quat_norm_threshold || norm_off {
            Some(StatusReason::QuaternionNorm)
        } else {
            None
        }
    }

    /// Test 2, and full finiteness, once per camera period of IMU time (at each trigger, and
    /// without triggers too): the covariance grows slowly, so checking it at frame rate costs
    /// a fraction and misses nothing.
    pub fn frame(st: &State<T>, prm: &Params<T>) -> Option<StatusReason>
    where
        T: StateKernels,
    {
        if !st.is_finite() {
            Some(StatusReason::NonFiniteState)
        } else if st.cov_frobenius() > prm.cov_threshold {
            Some(StatusReason::CovarianceNorm)
        } else {
            None
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::params;
    use protocol::ModelKind;

    /// Defect 8 of issue 12: per correspondence, λ = 0.3 and one gross outlier fired the test,
    /// and at λ = 0.95 so did 14 rejected correspondences in a row (one partly occluded frame).
    #[test]
    fn one_frame_of_outliers_cannot_fire_the_residual_test_but_two_do() {
        let mut prm = params::<f64>(ModelKind::Acc);
        for lambda in [0.3, 0.5, 0.8, 0.95] {
            prm.lowpass = lambda;
            prm.residual_cap = Params::<f64>::residual_cap_of(prm.residual_threshold, lambda);
            let mut m = Monitor::new();
            // Settled on good frames (s ≈ 2, a χ² with 2 degrees of freedom).
            for f in 0..200 {
                for _ in 0..30 {
                    assert_eq!(m.residual(f, 2.0, &prm), None);
                }
                assert_eq!(m.close_frame(&prm), None);
            }
            // One frame of nothing but gross outliers (and an infinite one).
            for k in 0..30 {
                let s = if k == 0 { f64::INFINITY } else { 1e9 };
                assert_eq!(m.residual(200, s, &prm), None, "λ {lambda}");
            }
            assert_eq!(m.close_frame(&prm), None, "λ {lambda}");
            // The second such frame fires.
            m.residual(201, 1e9, &prm);
            assert!(m.close_frame(&prm).is_some(), "λ {lambda}");
            // A sustained share of outliers fires the test above 2(1−λ)/(2−λ), not below.
            let limit = 2.0 * (1.0 - lambda) / (2.0 - lambda);
            for (share, fires) in [(0.8 * limit, false), (1.25 * limit, true)] {
                let mut m = Monitor::new();
                let fired = (0..400).any(|f| {
                    for k in 0..100 {
                        let s = if (k as f64) < share * 100.0 { 1e9 } else { 0.0 };
                        m.residual(f, s, &prm);
                    }
                    m.close_frame(&prm).is_some()
                });
                assert_eq!(fired, fires, "λ {lambda}, share {share}");
            }
        }
    }

    #[test]
    fn a_frame_left_open_is_closed_by_the_next_one() {
        let mut prm = params::<f64>(ModelKind::Acc);
        prm.lowpass = 0.9;
        let mut m = Monitor::new();
        m.residual(1, 10.0, &prm);
        m.residual(2, 0.0, &prm);
        assert!((m.g - 1.0).abs() < 1e-12);
    }
}
