//! The filter's scalar: `f32` on the MCU, `f64` on the PC.

use nalgebra::RealField;
use protocol::StatusReason;

use crate::filter::{Filter, ImuSample};
use crate::models::correspondence::{self, Observation, Rejection};
use crate::params::Params;
use crate::state::{self, CameraPose, HandEye, State};

/// The filter's hot paths, monomorphised for each scalar *in this crate*.
///
/// Generic code is compiled, and optimised, in the crate that instantiates it: without this
/// hook the firmware would build the filter at its own size-first opt-level. The impls below are
/// not generic, so they are compiled here, with this crate's profile (the firmware builds
/// `fusion-core` at opt-level 3 and everything else for size).
pub trait Kernels: Sized {
    /// [`Filter::imu_step`].
    fn imu_step(
        f: &mut Filter<Self>,
        prm: &Params<Self>,
        s: &ImuSample<Self>,
    ) -> Result<(), StatusReason>
    where
        Self: Scalar;
    /// [`correspondence::update`].
    fn correspondence_update(
        st: &mut State<Self>,
        prm: &Params<Self>,
        obs: &Observation<Self>,
    ) -> (Self, Result<Self, Rejection>)
    where
        Self: Scalar;
    /// [`State::cov_frobenius`] (every `State` report).
    fn cov_frobenius(st: &State<Self>) -> Self
    where
        Self: Scalar;
    /// [`state::all_finite`] (every divergence check).
    fn all_finite(values: &[Self]) -> bool
    where
        Self: Scalar;
    /// [`state::camera_pose`] (every pose prediction).
    fn camera_pose(st: &State<Self>, he: &HandEye<Self>) -> CameraPose<Self>
    where
        Self: Scalar;
}

macro_rules! kernels {
    ($t:ty) => {
        impl Kernels for $t {
            #[inline(never)]
            fn imu_step(
                f: &mut Filter<Self>,
                prm: &Params<Self>,
                s: &ImuSample<Self>,
            ) -> Result<(), StatusReason> {
                f.imu_step_generic(prm, s)
            }
            #[inline(never)]
            fn correspondence_update(
                st: &mut State<Self>,
                prm: &Params<Self>,
                obs: &Observation<Self>,
            ) -> (Self, Result<Self, Rejection>) {
                correspondence::update_generic(st, prm, obs)
            }
            #[inline(never)]
            fn cov_frobenius(st: &State<Self>) -> Self {
                st.cov_frobenius_generic()
            }
            #[inline(never)]
            fn all_finite(values: &[Self]) -> bool {
                state::all_finite_generic(values)
            }
            #[inline(never)]
            fn camera_pose(st: &State<Self>, he: &HandEye<Self>) -> CameraPose<Self> {
                state::camera_pose_generic(st, he)
            }
        }
    };
}
kernels!(f32);
kernels!(f64);

/// A floating-point scalar the filter runs on.
pub trait Scalar: RealField + Copy + Default + Kernels {
    /// Bits of the type (reported to the host in `HelloAck`).
    const BITS: u8;
    /// Smallest variance a covariance diagonal entry of an active state may reach.
    const VARIANCE_FLOOR: f64;
    /// Zero, usable in `const` constructors (the firmware's state lives in a `static`).
    const ZERO: Self;

    /// Conversion from an `f64` constant.
    fn c(x: f64) -> Self;
    /// Conversion from a wire `f32`.
    fn from_wire(x: f32) -> Self;
    /// Conversion to a wire `f32`.
    fn to_wire(self) -> f32;
    /// Conversion to `f64` (host-side analysis).
    fn to_f64(self) -> f64;
    /// `(sin x, cos x)`: for `f32` in `f32` arithmetic alone ([`crate::trig`]), the same on
    /// the PC and the MCU; for `f64` the platform's.
    fn sin_cos_of(self) -> (Self, Self);
}

impl Scalar for f32 {
    const BITS: u8 = 32;
    const VARIANCE_FLOOR: f64 = 1e-12;
    const ZERO: Self = 0.0;

    fn c(x: f64) -> Self {
        x as f32
    }
    fn from_wire(x: f32) -> Self {
        x
    }
    fn to_wire(self) -> f32 {
        self
    }
    fn to_f64(self) -> f64 {
        self as f64
    }
    fn sin_cos_of(self) -> (Self, Self) {
        crate::trig::sin_cos_f32(self)
    }
}

impl Scalar for f64 {
    const BITS: u8 = 64;
    const VARIANCE_FLOOR: f64 = 1e-20;
    const ZERO: Self = 0.0;

    fn c(x: f64) -> Self {
        x
    }
    fn from_wire(x: f32) -> Self {
        x as f64
    }
    fn to_wire(self) -> f32 {
        self as f32
    }
    fn to_f64(self) -> f64 {
        self
    }
    fn sin_cos_of(self) -> (Self, Self) {
        (
            nalgebra::ComplexField::sin(self),
            nalgebra::ComplexField::cos(self),
        )
    }
}
