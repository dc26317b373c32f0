//! One IMU step of the filter: normalise, time update, gyro and accelerometer updates.

use nalgebra::Vector3;
use protocol::StatusReason;

use crate::divergence::Monitor;
use crate::models::{accel, gyro, motion};
use crate::params::Params;
use crate::scalar::Scalar;
use crate::state::State;

/// Longest single time-update step [µs]; longer intervals are split (the linearisation of the
/// quaternion increment and the Q discretisation stay accurate).
pub const MAX_STEP_US: u64 = 20_000;

/// One IMU sample in the filter's scalar.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImuSample<T: Scalar> {
    /// Time stamp [µs].
    pub t_us: u64,
    /// Angular rate [rad/s].
    pub gyro: Vector3<T>,
    /// Specific force [m/s²].
    pub accel: Vector3<T>,
}

impl<T: Scalar> ImuSample<T> {
    /// From the wire form.
    pub fn from_wire(s: &protocol::ImuSample) -> Self {
        let v =
            |a: [f32; 3]| Vector3::new(T::from_wire(a[0]), T::from_wire(a[1]), T::from_wire(a[2]));
        ImuSample {
            t_us: s.t_us,
            gyro: v(s.gyro),
            accel: v(s.accel),
        }
    }
}

/// The filter's running state: mean, covariance and time.
#[derive(Clone, Debug, PartialEq)]
pub struct Filter<T: Scalar> {
    /// Mean and covariance.
    pub st: State<T>,
    /// Time of the last applied sample [µs].
    pub t_us: u64,
    /// `|‖q‖ − 1|` before the last normalisation.
    pub quat_norm_error: T,
}

impl<T: Scalar> Filter<T> {
    /// A filter that has not started (zero state).
    pub const fn idle() -> Self {
        Filter {
            st: State::zeroed(),
            t_us: 0,
            quat_norm_error: T::ZERO,
        }
    }

    /// A filter at `state` and time `t_us`.
    pub fn new(st: State<T>, t_us: u64) -> Self {
        Filter {
            st,
            t_us,
            quat_norm_error: T::zero(),
        }
    }

    /// Applies one IMU sample (its time stamp must be after the filter's). Returns the reason
    /// if the state diverged.
    pub fn imu_step(&mut self, prm: &Params<T>, s: &ImuSample<T>) -> Result<(), StatusReason> {
        let mut remaining = s.t_us.saturating_sub(self.t_us);
        let mut worst = T::zero();
        while remaining > 0 {
            let step = remaining.min(MAX_STEP_US);
            remaining -= step;
            let err = motion::normalise_quaternion(&mut self.st);
            if err > worst {
                worst = err;
            }
            motion::time_update(&mut self.st, prm, T::c(step as f64 * 1e-6));
        }
        self.t_us = s.t_us;
        self.quat_norm_error = worst;
        // A singular innovation here means a broken covariance: the monitor reports it below.
        let updated = gyro::update(&mut self.st, prm, &s.gyro)
            .and_then(|_| accel::update(&mut self.st, prm, &s.accel));
        crate::ekf::condition(&mut self.st.p, prm.n);
        match Monitor::state(&self.st, worst, prm) {
            Some(reason) => Err(reason),
            None if updated.is_err() => Err(StatusReason::NonFiniteState),
            None => Ok(()),
        }
    }
}
