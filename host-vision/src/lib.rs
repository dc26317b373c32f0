//! The vision coprocessor beside the camera.
//!
//! It holds the host's end of the link to the fusion core ([`link`]), the protocol's loop-back
//! self-test ([`selftest`]); synthetic EuRoC datasets of the paper's test cases ([`synth`]); EuRoC
//! datasets as the tracker reads them ([`dataset`]) and the tracking pipeline with its outputs
//! ([`track`]), and the checks of a run's output folder ([`out_folder`]); frame sources without
//! an IMU, a video through ffmpeg or an image folder ([`frames`]); the full 6-DoF start
//! pose file ([`start_pose`]) is the camera crate's, re-exported. The paper's experiments
//! ([`eval`]) and the robustness corpus that scores the verdict against the truth
//! ([`corpus`]) run on synthetic datasets.
//!
//! The camera model ([`camera`]), textured model loading ([`model`]), the offscreen renderer
//! ([`render`], with back-projection of rendered depth, [`backproject`]) and natural features
//! (FAST, pyramids, the photometric KLT, the feature map and correspondences, [`features`])
//! are crates of their own (`host/`), re-exported here under those names.

pub use ::camera;
pub use ::render::backproject;
pub mod corpus;
pub mod eval;
pub use ::features;
pub mod link;
pub mod locate;
pub use ::model;
pub mod out_folder;
pub use ::render;
pub mod selftest;
pub use camera::start_pose;
pub mod synth;
pub mod track;
