//! The vision coprocessor beside the camera.
//!
//! Today it holds the host's end of the link to the fusion core ([`link`]) and the protocol's
//! loop-back self-test ([`selftest`]). Rendering, feature registration and the tracking
//! pipeline follow in their own issues.

pub mod link;
pub mod selftest;
