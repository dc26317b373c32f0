//! The paper's system and measurement models (docs/FILTER.md §4, §5):
//!
//! - [`motion`]: time update, eq. 7 (gyro), 12 (gravity), 15 (acc);
//! - [`gyro`]: gyroscope measurement, eq. 9;
//! - [`accel`]: accelerometer measurement, eq. 13 (gravity) and 16 (acc);
//! - [`correspondence`]: the implicit 2D/3D correspondence measurement, eq. 10, with the
//!   outlier gate of eq. 17;
//! - [`contour`]: the implicit contour measurement, eq. 10c (a model point on the silhouette,
//!   found along the contour's normal).

pub mod accel;
pub mod contour;
pub mod correspondence;
pub mod gyro;
pub mod motion;
