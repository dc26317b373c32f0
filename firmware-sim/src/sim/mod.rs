//! Sensor simulation with exact ground truth: smooth trajectories with analytic derivatives
//! ([`trajectory`]), an IMU with white noise and bias random walks ([`imu`]), and 2D/3D
//! correspondences of a pinhole camera ([`camera`]); the paper's test cases as scenarios with
//! EuRoC writers ([`scenario`]); a sensor board whose core samples a simulated ICM-42688-P,
//! with faults injected ([`sensor_board`]).

pub mod camera;
pub mod imu;
pub mod scenario;
pub mod sensor_board;
pub mod trajectory;

/// Gravity in the world frame [m/s²] (z up, docs/FILTER.md §2).
pub const GRAVITY_W: [f64; 3] = [0.0, 0.0, -9.81];
