//! The simulated board: runs the fusion core on the PC behind a real byte transport, so that
//! the host talks to it exactly as to hardware; and the sensor simulation.
//!
//! Today it holds the transports ([`transport`]) and the loop-back peer of the protocol
//! self-test ([`loopback`]).

pub mod loopback;
pub mod transport;
