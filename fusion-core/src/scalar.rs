//! The filter's scalar: `f32` on the MCU, `f64` on the PC.

use nalgebra::RealField;

/// A floating-point scalar the filter runs on: its arithmetic. The functions that run the filter
/// also need its hot paths compiled in this crate ([`crate::kernels::Kernels`]).
pub trait Scalar: RealField + Copy + Default {
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
