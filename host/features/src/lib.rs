#![deny(missing_docs)]
//! Natural features (paper §3, docs/VISION.md §3-§5): FAST corners in free areas of the rendering,
//! Gaussian pyramids, the photometric KLT that registers rendered patches in the live image
//! while estimating contrast and brightness, the feature map, and the correspondences sent to
//! the fusion core.
//!
//! Per frame: blur the rendering and build its [`pyramid::TemplatePyramid`] (mask from the
//! depth buffer), build the live image's [`pyramid::Pyramid`], predict the visible map
//! features and [`map::FeatureMap::select`] a spread subset, [`klt::register`] each one
//! starting at its predicted pixel, drop the registrations no rigid pose explains
//! ([`outliers::outliers`]), [`map::FeatureMap::record`] the outcomes, turn the accepted ones into [`correspondence::correspondence`]s, and when too few are visible add new
//! ones with [`map::FeatureMap::add_from_rendering`].

pub mod correspondence;
pub mod fast;
pub mod gray;
pub mod grid;
pub mod klt;
pub mod map;
pub mod outliers;
pub mod pyramid;

pub use fast::Corner;
pub use gray::{GrayF32, ImageError, Mask};
pub use klt::{KltConfig, KltFailure, KltModel, KltResult, register};
pub use map::{FeatureMap, MapConfig, Outcome, Predicted};
pub use outliers::OutlierRule;
pub use pyramid::{MaskPyramid, Pyramid, TemplatePyramid};
