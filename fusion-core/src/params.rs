//! Filter parameters, converted once from the wire `Config` into the filter's scalar.

use protocol::{Config, ModelKind};

use crate::scalar::Scalar;
use crate::state::HandEye;

/// Largest cap on a residual fed to the monitor ([`Params::residual_cap_of`]): half of
/// `f32::MAX` shared by the most correspondences a frame holds (the half leaves the sum's
/// rounding room), the same for both scalars.
pub const RESIDUAL_CAP_MAX: f64 =
    f32::MAX as f64 / (2 * protocol::MAX_CORRESPONDENCES_PER_FRAME) as f64;

/// Everything the filter needs from `Configure`, in the filter's scalar.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Params<T: Scalar> {
    /// System model.
    pub model: ModelKind,
    /// Active state dimension.
    pub n: usize,
    /// Motion noise density (acceleration, or jerk in the acc model).
    pub q_motion: T,
    /// Angular-acceleration noise density.
    pub q_angular: T,
    /// Gyro bias random-walk density.
    pub q_gyro_bias: T,
    /// Accelerometer bias random-walk density.
    pub q_accel_bias: T,
    /// Gyro measurement variance.
    pub r_gyro: T,
    /// Accelerometer measurement variance.
    pub r_accel: T,
    /// Initial standard deviations.
    pub init_sigma: protocol::InitSigma,
    /// Hand-eye calibration.
    pub hand_eye: HandEye<T>,
    /// Outlier gate on `s_i` (eq. 17).
    pub gate: T,
    /// Low-pass factor λ of the residual monitor.
    pub lowpass: T,
    /// Threshold on the low-passed residual.
    pub residual_threshold: T,
    /// Cap on each residual fed to the monitor ([`crate::divergence`]).
    pub residual_cap: T,
    /// Threshold on ‖P‖_F.
    pub cov_threshold: T,
    /// Threshold on |‖q‖ − 1|.
    pub quat_norm_threshold: T,
    /// Nominal IMU period [µs].
    pub imu_period_us: u64,
    /// Nominal camera period [µs].
    pub camera_period_us: u64,
    /// Samples averaged for roll and pitch.
    pub still_samples: u16,
}

impl<T: Scalar> Params<T> {
    /// The residual monitor's cap `c = τ(2−λ) / (2(1−λ))` for threshold `τ` and low-pass `λ`
    /// (see [`crate::divergence`]), at most [`RESIDUAL_CAP_MAX`]: a frame's sum of capped
    /// residuals then stays finite in `f32`, so that `g` never exceeds the largest `τ`, and
    /// `τ = f32::MAX` switches the test off. (Unbounded, that `τ` made the cap infinite, and one
    /// frame with a single point behind the camera fired the test.) Below the bound the
    /// monitor's promises hold as stated; a bounded cap only weakens what a frame can add.
    pub fn residual_cap_of(threshold: T, lowpass: T) -> T {
        let cap = threshold * (T::c(2.0) - lowpass) / (T::c(2.0) * (T::one() - lowpass));
        let max = T::c(RESIDUAL_CAP_MAX);
        if cap < max { cap } else { max }
    }

    /// From a validated `Config`.
    pub fn from_config(c: &Config) -> Self {
        let sq = |s: f32| T::from_wire(s) * T::from_wire(s);
        Params {
            model: c.model,
            n: c.model.state_dim(),
            q_motion: T::from_wire(c.noise.motion),
            q_angular: T::from_wire(c.noise.angular),
            q_gyro_bias: T::from_wire(c.noise.gyro_bias_walk),
            q_accel_bias: T::from_wire(c.noise.accel_bias_walk),
            r_gyro: sq(c.noise.gyro_meas),
            r_accel: sq(c.noise.accel_meas),
            init_sigma: c.init_sigma,
            hand_eye: HandEye::from_wire(&c.hand_eye),
            gate: T::from_wire(c.gate),
            lowpass: T::from_wire(c.divergence.residual_lowpass),
            residual_threshold: T::from_wire(c.divergence.residual_threshold),
            residual_cap: Self::residual_cap_of(
                T::from_wire(c.divergence.residual_threshold),
                T::from_wire(c.divergence.residual_lowpass),
            ),
            cov_threshold: T::from_wire(c.divergence.covariance_frobenius),
            quat_norm_threshold: T::from_wire(c.divergence.quaternion_norm),
            // In f32, as the MCU computes it (no software doubles): exact for the usual rates,
            // and within 0.01 µs of the f64 period below 1 kHz.
            imu_period_us: (1e6 / c.imu_rate_hz) as u64,
            camera_period_us: (1e6 / c.camera_rate_hz) as u64,
            still_samples: c.still_samples,
        }
    }
}
