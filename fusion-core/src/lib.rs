//! The fusion core: the EKF of Bleser & Stricker (2008) with its three system models, run at
//! IMU rate on a Cortex-M4F or on the PC. `no_std`, no allocation, fixed sizes.
//!
//! Its filter arrives with its own issue; today the crate fixes the contract it will be built
//! against: the protocol version it speaks and the model sizes it supports.
#![no_std]

pub use protocol::{ModelKind, PROTOCOL_VERSION};

/// Largest state dimension of any model (the acc model, DESIGN.md §4).
pub const MAX_STATE_DIM: usize = {
    let mut max = 0;
    let mut i = 0;
    while i < ModelKind::ALL.len() {
        let n = ModelKind::ALL[i].state_dim();
        if n > max {
            max = n;
        }
        i += 1;
    }
    max
};

#[cfg(test)]
mod tests {
    #[test]
    fn acc_model_is_the_largest() {
        assert_eq!(super::MAX_STATE_DIM, 22);
    }
}
