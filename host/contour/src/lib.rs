#![deny(missing_docs)]
//! The contour modality (docs/VISION.md §9): objects without texture tracked by their
//! silhouette. Per frame:
//!
//! - [`silhouette`]: points on the outer contour of the model rendered at the predicted pose,
//!   spread along it, each with its outward normal and its model point (from the rendered
//!   depth);
//! - [`statistics`]: the grey-level statistics of the object and of its background next to
//!   the contour, for all of it and per region of the model, learnt while tracking, and the
//!   pixel-wise posterior they give;
//! - [`line`]: along each normal, a correspondence line in the live image: where the contour
//!   lies, with its variance, from the posteriors (eq. K1-K3), coarse to fine; lines that leave
//!   the image, cross another part of the model or say nothing are refused by name;
//! - [`outliers`]: the lines no rigid pose explains together with the others (eq. K6-K7), the
//!   contour form of the registrations' outlier rule, and how well the lines pin a pose and
//!   how far it is from their own fit (eq. K10-K11);
//! - [`measure`]: all of it for one frame, each line as long as the prediction's covariance
//!   asks (eq. K8), the contour correspondences sent to the fusion core
//!   (`protocol::ContourPoint`, docs/FILTER.md eq. 10c), and the judgement of a pose by its
//!   contour (the rms along the normals, the silhouette's agreement with the statistics).

pub mod line;
pub mod measure;
pub mod outliers;
pub mod silhouette;
pub mod statistics;

pub use line::{LineConfig, LineRejection, LineResult};
pub use measure::{ContourConfig, ContourMeasurement, Contours, Tally};
pub use silhouette::{ContourSample, SampleConfig};
pub use statistics::{ColourModel, Histograms};
