//! The on-board sample path of a sensor board (issue 36): the core reads its own IMU, fires
//! the camera and time-stamps both on one clock. Portable `no_std` code, without allocation,
//! run by the firmware's main loop with the times its IMU interrupt captured ([`Timing`]), and tested on the
//! PC against the simulated part
//! ([`icm42688::SimIcm42688`]).
//!
//! - [`clock`]: the core's 1 MHz 32-bit timer extended to 64-bit µs;
//! - [`stamp`]: the FIFO's samples time-stamped PX4's way (each interrupt's sample at its time,
//!   the others by the part's own time stamps), lost samples counted, the IMU's clock drift and
//!   its time stamps' tick measured;
//! - [`trigger`]: when to fire the camera: a timer armed for the predicted time of the sample
//!   the trigger is due on, and the trigger paired with that sample;
//! - [`path`]: [`SamplePath`], which reads the part, scales to SI units, arms the camera's
//!   trigger and hands every sample, gap and fault to [`fusion_core::Device::onboard`]
//!   (protocol/PROTOCOL.md §7).
#![no_std]

pub mod clock;
pub mod path;
pub mod stamp;
pub mod trigger;

pub use clock::Clock64;
pub use path::{
    At, INTERRUPTS_KEPT, PathError, ReadSummary, START_RETRY_US, SamplePath, Served,
    TRIGGER_PULSE_US, Timing,
};
pub use stamp::{Anchor, Stamped, Stamper};
pub use trigger::{ARM_LEAD_US, Paired, TriggerOutput, TriggerPlan};
