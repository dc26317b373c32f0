//! The simulated board: runs the fusion core on the PC behind a real byte transport, so that
//! the host talks to it exactly as to hardware; and the sensor simulation.
//!
//! - [`board`]: `fusion-core`'s device loop behind a transport (the simulated board);
//! - [`transport`]: pty pair, serial device, TCP, stdio;
//! - [`loopback`]: the board end of the protocol self-test;
//! - [`qemu`]: the firmware image on QEMU's Cortex-M4F board, its UART over TCP;
//! - [`sim`]: trajectories, IMU and camera simulation with exact ground truth.

pub mod board;
pub mod loopback;
pub mod qemu;
pub mod sim;
pub mod transport;
