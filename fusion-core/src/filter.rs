//! One IMU step of the filter: normalise, time update, gyro and accelerometer updates.

use nalgebra::{SMatrix, SVector, Vector3};
use protocol::{ModelKind, StatusReason};

use crate::divergence::Monitor;
use crate::ekf::{SparseRow, UpdateError, innovation, joseph_update};
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

    /// Becomes a copy of `other`, field by field (no stack temporary of the whole filter).
    pub fn copy_from(&mut self, other: &Filter<T>) {
        self.st.x.copy_from(&other.st.x);
        self.st.p.copy_from(&other.st.p);
        self.t_us = other.t_us;
        self.quat_norm_error = other.quat_norm_error;
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
        let updated = if prm.model == ModelKind::Gyro {
            imu_update::<T, 3>(&mut self.st, prm, s)
        } else {
            imu_update::<T, 6>(&mut self.st, prm, s)
        };
        crate::ekf::condition(&mut self.st.p, prm.n);
        match Monitor::step(&self.st, worst, prm) {
            Some(reason) => Err(reason),
            None if updated.is_err() => Err(StatusReason::NonFiniteState),
            None => Ok(()),
        }
    }
}

/// The gyro (eq. 9) and, except in the gyro model, accelerometer (eq. 13 / 16) readings of one
/// sample, one axis at a time (the noises are uncorrelated across axes), all linearised once
/// at the prior: axis k's innovation is `y_k − h_k(x₀) − H_k (x − x₀)`, so the sequence equals
/// one joint update while each step is a cheap scalar one (`M` = 3 or 6 axes).
fn imu_update<T: Scalar, const M: usize>(
    st: &mut State<T>,
    prm: &Params<T>,
    s: &ImuSample<T>,
) -> Result<(), UpdateError> {
    let mut rows = [SparseRow::default(); M];
    let mut y0 = [T::zero(); M];
    let mut var = [prm.r_gyro; M];
    let g = gyro::predict(st);
    for k in 0..3 {
        rows[k] = gyro::row(k);
        y0[k] = s.gyro[k] - g[k];
    }
    if M == 6 {
        let a = accel::predict(st);
        for (k, row) in accel::rows(st, prm.model).into_iter().enumerate() {
            rows[3 + k] = row;
            y0[3 + k] = s.accel[k] - a[k];
            var[3 + k] = prm.r_accel;
        }
    }
    let x0 = st.x;
    for ((row, &dy), &r) in rows.iter().zip(&y0).zip(&var) {
        let moved = row
            .iter()
            .fold(T::zero(), |acc, (j, h)| acc + h * (st.x[j] - x0[j]));
        let z = SVector::<T, 1>::new(dy - moved);
        let (u, sm) = innovation(st, prm.n, &[*row], &SMatrix::<T, 1, 1>::new(r));
        joseph_update(st, prm.n, &u, &sm, &z)?;
    }
    Ok(())
}
