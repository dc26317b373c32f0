//! One IMU step of the filter: normalise, time update, gyro and accelerometer updates (the
//! vision-only model's tick: normalise and time update).

use nalgebra::{Matrix3, Matrix3x4, Vector3};
use protocol::{ModelKind, StatusReason};

use crate::divergence::Monitor;
use crate::ekf::{Gains, Ldl, SparseRow, UpdateError, innovation_cov, p_columns};
use crate::models::{accel, gyro, motion};
use crate::params::Params;
use crate::scalar::Scalar;
use crate::state::{ACC, ACC_BIAS, GYRO_BIAS, N, OMEGA, QUAT, State};

/// Longest single time-update step [µs]; longer intervals are split (the linearisation of the
/// quaternion increment and the Q discretisation stay accurate).
pub const MAX_STEP_US: u64 = 20_000;

/// Longest interval one sample may integrate [µs] (the device's largest accepted gap,
/// [`crate::device::MAX_GAP_US`]). A sample further from the filter's time, or before it, is
/// refused whatever its time stamp says, so one sample costs at most
/// [`MAX_STEPS_PER_SAMPLE`] time updates.
pub const MAX_INTERVAL_US: u64 = 1_000_000;

/// Most time updates one sample runs: [`MAX_INTERVAL_US`] in steps of [`MAX_STEP_US`].
pub const MAX_STEPS_PER_SAMPLE: u32 = MAX_INTERVAL_US.div_ceil(MAX_STEP_US) as u32;

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
    /// The radial part of the last IMU update's quaternion step
    /// ([`crate::ekf::radial_step`]).
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

    /// Applies one IMU sample. Returns the reason if the state diverged, or
    /// `StatusReason::TimeJump` (the filter unchanged) if the sample is before the filter's
    /// time or more than [`MAX_INTERVAL_US`] after it.
    pub fn imu_step(&mut self, prm: &Params<T>, s: &ImuSample<T>) -> Result<(), StatusReason>
    where
        T: StepKernel,
    {
        self.imu_step_counted(prm, s, &mut 0)
    }

    /// [`Self::imu_step`], adding the time updates it ran to `steps` (saturating): the work a
    /// sample costs, at most [`MAX_STEPS_PER_SAMPLE`].
    pub fn imu_step_counted(
        &mut self,
        prm: &Params<T>,
        s: &ImuSample<T>,
        steps: &mut u32,
    ) -> Result<(), StatusReason>
    where
        T: StepKernel,
    {
        T::imu_step(self, prm, s, steps)
    }

    /// [`Self::imu_step_counted`], instantiated through [`StepKernel`].
    pub(crate) fn imu_step_generic(
        &mut self,
        prm: &Params<T>,
        s: &ImuSample<T>,
        steps: &mut u32,
    ) -> Result<(), StatusReason> {
        let mut remaining = match s.t_us.checked_sub(self.t_us) {
            Some(dt) if dt <= MAX_INTERVAL_US => dt,
            _ => return Err(StatusReason::TimeJump),
        };
        while remaining > 0 {
            let step = remaining.min(MAX_STEP_US);
            remaining -= step;
            *steps = steps.saturating_add(1);
            motion::normalise_quaternion(&mut self.st);
            // `step` ≤ MAX_STEP_US is exact in an f32: no double arithmetic on the MCU.
            motion::time_update(
                &mut self.st,
                prm,
                T::c(1e-6) * T::from_wire(step as u32 as f32),
            );
        }
        self.t_us = s.t_us;
        // The vision-only model has no readings to update with: its step is the time update.
        // A singular innovation here means a broken covariance: the monitor reports it below.
        let updated = if prm.model.has_imu() {
            imu_update(&mut self.st, prm, s)
        } else {
            Ok(T::zero())
        };
        self.quat_norm_error = updated.unwrap_or(T::zero());
        match Monitor::step(&self.st, self.quat_norm_error, prm) {
            Some(reason) => Err(reason),
            None if updated.is_err() => Err(StatusReason::NonFiniteState),
            None => Ok(()),
        }
    }
}

/// [`Filter::imu_step`], compiled in this crate for each scalar (why: [`crate::kernels`]).
pub trait StepKernel: Scalar {
    /// [`Filter::imu_step_counted`] (every IMU sample).
    fn imu_step(
        f: &mut Filter<Self>,
        prm: &Params<Self>,
        s: &ImuSample<Self>,
        steps: &mut u32,
    ) -> Result<(), StatusReason>;
}

macro_rules! step_kernel {
    ($t:ty) => {
        impl StepKernel for $t {
            #[inline(never)]
            fn imu_step(
                f: &mut Filter<Self>,
                prm: &Params<Self>,
                s: &ImuSample<Self>,
                steps: &mut u32,
            ) -> Result<(), StatusReason> {
                f.imu_step_generic(prm, s, steps)
            }
        }
    };
}
step_kernel!(f32);
step_kernel!(f64);

/// The gyro (eq. 9) and, except in the gyro model, accelerometer (eq. 13 / 16) readings of one
/// sample as one measurement with uncorrelated noise (3 or 6 axes), linearised at the prior;
/// applied as the equivalent sequence of scalar updates ([`Ldl::apply`]). The gyro model's
/// accelerometer rows are left zero: the factorisation stops before them. Returns the update's
/// radial quaternion error ([`crate::ekf::radial_step`]).
fn imu_update<T: Scalar>(
    st: &mut State<T>,
    prm: &Params<T>,
    s: &ImuSample<T>,
) -> Result<T, UpdateError> {
    const M: usize = 6;
    let with_accel = prm.model != ModelKind::Gyro;
    let mut rows = [SparseRow::default(); M];
    let mut y = [T::zero(); M];
    let mut r = [[T::zero(); M]; M];
    let g = gyro::predict(st);
    for k in 0..3 {
        rows[k] = gyro::row(k);
        y[k] = s.gyro[k] - g[k];
        r[k][k] = prm.r_gyro;
    }
    let (d_q, d_acc) = if with_accel {
        let a = accel::predict(st);
        let (d_q, d_acc) = accel::jacobian(st, prm.model);
        for (k, row) in accel::rows_of(&d_q, &d_acc, prm.model)
            .into_iter()
            .enumerate()
        {
            rows[3 + k] = row;
            y[3 + k] = s.accel[k] - a[k];
            r[3 + k][3 + k] = prm.r_accel;
        }
        (d_q, d_acc)
    } else {
        (Matrix3x4::zeros(), Matrix3::zeros())
    };
    // U = P Hᵀ from whole columns of the symmetric P, on the rows' structure: eq. 9 is
    // ∂/∂ω = ∂/∂b_ω = I, eq. 13 / 16 the blocks of `accel::jacobian` and ∂/∂b_a = I.
    let mut u: Gains<T, M> = [[T::zero(); M]; N];
    for (ui, col) in u.iter_mut().zip(p_columns(&st.p, prm.n)) {
        for k in 0..3 {
            ui[k] = col[OMEGA + k] + col[GYRO_BIAS + k];
        }
        if with_accel {
            for k in 0..3 {
                let mut a = col[ACC_BIAS + k];
                for c in 0..4 {
                    a += d_q[(k, c)] * col[QUAT + c];
                }
                for c in 0..3 {
                    a += d_acc[(k, c)] * col[ACC + c];
                }
                ui[3 + k] = a;
            }
        }
    }
    let f = Ldl::new(&innovation_cov(&rows, &u, &r), &y);
    let radial = f.apply(st, prm.n, &mut u);
    if f.rank < if with_accel { M } else { 3 } {
        Err(UpdateError::Singular)
    } else {
        Ok(radial)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::state::Cov;
    use crate::testutil::{params, random_state};
    use approx::assert_relative_eq;
    use nalgebra::{SMatrix, SVector};

    /// A vision-only step never reads the sample's readings: it is the time update alone,
    /// and the 9 states past the model's 13 stay zero.
    #[test]
    fn a_vision_only_step_is_the_time_update_alone() {
        let prm = params::<f64>(ModelKind::Vision);
        let st = random_state(prm.n, 7);
        let mut f = Filter::new(st.clone(), 0);
        let s = ImuSample {
            t_us: 10_000,
            gyro: Vector3::new(5.0, -5.0, 5.0),
            accel: Vector3::new(1.0, 2.0, 3.0),
        };
        f.imu_step(&prm, &s).unwrap();
        let mut want = st;
        motion::normalise_quaternion(&mut want);
        motion::time_update(&mut want, &prm, 0.01);
        assert_eq!(f.st, want);
        assert!(f.st.x.iter().skip(prm.n).all(|&v| v == 0.0));
        assert!(f.st.p.iter().enumerate().all(|(k, &v)| {
            let (i, j) = (k % N, k / N);
            (i < prm.n && j < prm.n) || v == 0.0
        }));
    }

    #[test]
    fn imu_update_equals_the_dense_joseph_update() {
        for model in ModelKind::INERTIAL {
            let prm = params::<f64>(model);
            let mut st = random_state(prm.n, 31);
            let s = ImuSample {
                t_us: 0,
                gyro: Vector3::new(0.1, -0.2, 0.05),
                accel: Vector3::new(0.3, -0.1, 9.7),
            };
            // Dense reference: the gyro rows, then the accelerometer's (zero rows with unit
            // noise, which change nothing, in the gyro model).
            let mut h = SMatrix::<f64, 6, N>::zeros();
            let mut y = SVector::<f64, 6>::zeros();
            let mut r = SMatrix::<f64, 6, 6>::identity();
            let g = gyro::predict(&st);
            for k in 0..3 {
                h.set_row(k, &gyro::row::<f64>(k).dense().transpose());
                y[k] = s.gyro[k] - g[k];
                r[(k, k)] = prm.r_gyro;
            }
            if model != ModelKind::Gyro {
                let a = accel::predict(&st);
                for (k, row) in accel::rows(&st, model).iter().enumerate() {
                    h.set_row(3 + k, &row.dense().transpose());
                    y[3 + k] = s.accel[k] - a[k];
                    r[(3 + k, 3 + k)] = prm.r_accel;
                }
            }
            let p = st.p;
            let k = p * h.transpose() * (h * p * h.transpose() + r).try_inverse().unwrap();
            let ikh = Cov::<f64>::identity() - k * h;
            let p_ref = ikh * p * ikh.transpose() + k * r * k.transpose();
            let x_ref = st.x + k * y;
            imu_update(&mut st, &prm, &s).unwrap();
            assert_relative_eq!(st.x, x_ref, epsilon = 1e-10);
            assert_relative_eq!(st.p, p_ref, epsilon = 1e-10);
            assert_eq!(st.p, st.p.transpose());
        }
    }
}
