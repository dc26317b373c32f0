//! Test helpers: parameters and random but valid states.

use nalgebra::Vector4;
use protocol::ModelKind;

use crate::params::Params;
use crate::scalar::Scalar;
use crate::state::{Cov, N, State};

/// Parameters of the sample configuration with the given model.
pub fn params<T: Scalar>(model: ModelKind) -> Params<T> {
    let mut c = protocol::samples::config();
    c.model = model;
    Params::from_config(&c)
}

/// A deterministic pseudo-random state: unit quaternion, non-zero entries in the active
/// block, symmetric positive definite covariance there.
pub fn random_state(n: usize, seed: u64) -> State<f64> {
    let mut s = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    let mut next = || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 11) as f64 / (1u64 << 53) as f64 - 0.5
    };
    let mut st = State::<f64>::default();
    for i in 0..n {
        st.x[i] = next();
    }
    let q = Vector4::new(1.0 + next(), next(), next(), next()).normalize();
    st.set_q(&q);
    let a = Cov::<f64>::from_fn(|i, j| if i < n && j < n { next() * 0.1 } else { 0.0 });
    st.p = a * a.transpose();
    for i in 0..n {
        st.p[(i, i)] += 1e-3;
    }
    st
}

/// Whether the active `n × n` block is symmetric positive definite (the inactive diagonal is
/// set to 1 so that a fixed-size Cholesky decides).
pub fn active_block_is_pd(p: &Cov<f64>, n: usize) -> bool {
    let mut m = *p;
    for i in n..N {
        m[(i, i)] = 1.0;
    }
    (m - m.transpose()).abs().max() < 1e-12 && m.cholesky().is_some()
}
