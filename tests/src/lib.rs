//! The in-process scenario harness shared by the end-to-end tests: drives a fusion-core
//! [`fusion_core::Device`] with simulated IMU samples and delayed correspondences exactly as the
//! host would over the wire, and records what it answers next to the ground truth; and a
//! sensor board whose core samples a simulated IMU ([`board`]).

pub mod board;
pub mod harness;
