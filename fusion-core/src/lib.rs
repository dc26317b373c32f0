//! The fusion core: the EKF of Bleser & Stricker (2008) with its three system models, run at
//! IMU rate on a Cortex-M4F or on the PC. `no_std`, no allocation, fixed sizes, generic over
//! the scalar (`f32` on the MCU, `f64` on the PC).
//!
//! Where the equations of docs/FILTER.md live (its table at the end says the same):
//!
//! | equation | module |
//! |---|---|
//! | camera pose from the state (5-6) | [`state::camera_pose`] |
//! | time update (7, 12, 15) | [`models::motion`] |
//! | gyro measurement (9) | [`models::gyro`] |
//! | correspondence measurement (10), gate (17) | [`models::correspondence`] |
//! | contour measurement (10c) | [`models::contour`] |
//! | accelerometer measurement (13, 16) | [`models::accel`] |
//! | measurement update (LDLᵀ-decorrelated scalar updates, symmetric form) | [`ekf`] |
//! | outlier gate (17) | [`models::correspondence::update`] |
//! | divergence monitor (docs/FILTER.md §9) | [`divergence`] |
//! | (re)initialisation | [`init`] |
//! | delayed correspondences | [`delay`] |
//! | a frame's part of either kind, applied item by item | [`part`] |
//! | device loop (protocol messages in and out) | [`device`] |
//! | the core's own IMU: sampling mode, triggers, sampling reports | [`onboard`] |
//!
//! The hot paths of the filter are compiled in this crate for `f32` and `f64` ([`kernels`]):
//! code generic over the scalar that runs the filter or the device bounds it on [`Kernels`],
//! while [`Scalar`] is the arithmetic alone.
#![no_std]

#[cfg(test)]
extern crate std;

pub mod delay;
pub mod device;
pub mod divergence;
pub mod ekf;
pub mod filter;
pub mod init;
pub mod kernels;
pub mod models;
pub mod onboard;
pub mod params;
pub mod part;
pub mod quat;
pub mod scalar;
pub mod state;
#[cfg(test)]
mod testutil;
pub mod trig;

pub use device::{Device, DeviceIo};

/// The scalar a core is built with: what a host asks of a core it runs itself (the simulated
/// board, the core called in-process).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Precision {
    /// `f32`, as on the Cortex-M4F.
    F32,
    /// `f64`, the PC reference.
    F64,
}
pub use kernels::Kernels;
pub use protocol::{ModelKind, PROTOCOL_VERSION};
pub use scalar::Scalar;
