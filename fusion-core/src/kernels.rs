//! The filter's hot paths, monomorphised for each scalar *in this crate*.
//!
//! Generic code is compiled, and optimised, in the crate that instantiates it: without this
//! hook the firmware would build the filter at its own size-first opt-level. Each module with a
//! hot path declares a trait for it next to the code, implemented for `f32` and `f64` by
//! functions that are not generic, so they are compiled here, with this crate's profile (the
//! firmware builds `fusion-core` at opt-level 3 and everything else for size):
//!
//! - [`StateKernels`]: the covariance norm, the finiteness test and the camera pose;
//! - [`UpdateKernel`]: the update by one 2D/3D correspondence;
//! - [`ContourKernel`]: the update by one contour correspondence;
//! - [`StepKernel`]: one IMU step.
//!
//! A trait of the scalar, [`crate::Scalar`], could not declare them: they take the state, the
//! filter and the observations, which are built on the scalar. [`Kernels`] is all of them: the
//! bound of the device loop, and of code generic over the scalar that runs the filter.

pub use crate::filter::StepKernel;
pub use crate::models::contour::ContourKernel;
pub use crate::models::correspondence::UpdateKernel;
pub use crate::state::StateKernels;

/// A scalar with every hot path of the filter compiled in this crate (`f32` and `f64`).
pub trait Kernels: StateKernels + UpdateKernel + ContourKernel + StepKernel {}

impl<T: StateKernels + UpdateKernel + ContourKernel + StepKernel> Kernels for T {}
