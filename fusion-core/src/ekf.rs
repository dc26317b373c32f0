//! Covariance arithmetic shared by all models: sparse measurement rows, the Joseph-form update,
//! and the guards that keep the covariance symmetric with bounded variances.

use nalgebra::{SMatrix, SVector};

use crate::scalar::Scalar;
use crate::state::{Cov, N, State};

/// Most non-zero entries of one measurement-Jacobian row (accelerometer: 4 + 3 + 1).
pub const ROW_NNZ: usize = 8;

/// One row of a measurement Jacobian, stored sparsely.
#[derive(Clone, Copy, Debug)]
pub struct SparseRow<T: Scalar> {
    idx: [u8; ROW_NNZ],
    val: [T; ROW_NNZ],
    len: usize,
}

impl<T: Scalar> Default for SparseRow<T> {
    fn default() -> Self {
        SparseRow {
            idx: [0; ROW_NNZ],
            val: [T::zero(); ROW_NNZ],
            len: 0,
        }
    }
}

impl<T: Scalar> SparseRow<T> {
    /// Adds `value` at state index `at` (callers add at most [`ROW_NNZ`] entries; more are a
    /// programming error and are dropped in release builds).
    pub fn push(&mut self, at: usize, value: T) {
        debug_assert!(self.len < ROW_NNZ && at < N);
        if self.len < ROW_NNZ {
            self.idx[self.len] = at as u8;
            self.val[self.len] = value;
            self.len += 1;
        }
    }

    /// Adds consecutive entries starting at `at`.
    pub fn push_slice(&mut self, at: usize, values: &[T]) {
        for (k, &v) in values.iter().enumerate() {
            self.push(at + k, v);
        }
    }

    /// Entries as `(index, value)`.
    pub fn iter(&self) -> impl Iterator<Item = (usize, T)> + '_ {
        self.idx[..self.len]
            .iter()
            .zip(&self.val[..self.len])
            .map(|(&i, &v)| (i as usize, v))
    }

    /// `P hᵀ` over the active block.
    pub fn p_ht(&self, p: &Cov<T>, n: usize) -> SVector<T, N> {
        let mut u = SVector::<T, N>::zeros();
        for (j, h) in self.iter() {
            for i in 0..n {
                u[i] += p[(i, j)] * h;
            }
        }
        u
    }

    /// `h v`.
    pub fn dot(&self, v: &SVector<T, N>) -> T {
        self.iter().fold(T::zero(), |acc, (j, h)| acc + h * v[j])
    }

    /// Dense form (tests and finite-difference checks).
    pub fn dense(&self) -> SVector<T, N> {
        let mut d = SVector::zeros();
        for (j, h) in self.iter() {
            d[j] += h;
        }
        d
    }
}

/// Why an update was not applied.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum UpdateError {
    /// The innovation covariance is not positive definite (or not finite).
    Singular,
}

/// `U = P Hᵀ` and `S = H P Hᵀ + R` of an `M`-dimensional measurement.
pub fn innovation<T: Scalar, const M: usize>(
    st: &State<T>,
    n: usize,
    h: &[SparseRow<T>; M],
    r: &SMatrix<T, M, M>,
) -> (SMatrix<T, N, M>, SMatrix<T, M, M>) {
    let mut u = SMatrix::<T, N, M>::zeros();
    for (m, row) in h.iter().enumerate() {
        u.set_column(m, &row.p_ht(&st.p, n));
    }
    let mut s = *r;
    for a in 0..M {
        for b in 0..M {
            s[(a, b)] += h[a].dot(&u.column(b).into_owned());
        }
    }
    // H P Hᵀ is symmetric in exact arithmetic; make it so in floating point.
    let s = (s + s.transpose()) * T::c(0.5);
    (u, s)
}

/// Joseph-form update with innovation `z`, `U = P Hᵀ`, `S = H P Hᵀ + R`:
/// `x ← x + K z`, `P ← (I − K H) P (I − K H)ᵀ + K R Kᵀ` with `K = U S⁻¹`.
///
/// Expanded, `P ← P − K Uᵀ − U Kᵀ + K S Kᵀ`: valid for any gain, so rounding in `K` only enters
/// to second order (the point of the Joseph form), symmetric by construction, and computed on
/// the upper triangle of the active block only (`O(n² M)` instead of a dense `O(n³)`).
pub fn joseph_update<T: Scalar, const M: usize>(
    st: &mut State<T>,
    n: usize,
    u: &SMatrix<T, N, M>,
    s: &SMatrix<T, M, M>,
    z: &SVector<T, M>,
) -> Result<(), UpdateError> {
    // Cholesky fails unless S is symmetric positive definite, as an innovation covariance is.
    let s_inv = s.cholesky().ok_or(UpdateError::Singular)?.inverse();
    if !s_inv.iter().all(|v| v.is_finite()) {
        return Err(UpdateError::Singular);
    }
    let k = u * s_inv;
    let ks = k * s;
    for i in 0..n {
        st.x[i] += (k.row(i) * z)[0];
    }
    for i in 0..n {
        for j in i..n {
            let mut d = T::zero();
            for m in 0..M {
                d += -k[(i, m)] * u[(j, m)] - u[(i, m)] * k[(j, m)] + ks[(i, m)] * k[(j, m)];
            }
            let v = st.p[(i, j)] + d;
            st.p[(i, j)] = v;
            st.p[(j, i)] = v;
        }
    }
    Ok(())
}

/// Keeps the active block symmetric with variances no smaller than the scalar's floor.
pub fn condition<T: Scalar>(p: &mut Cov<T>, n: usize) {
    let floor = T::c(T::VARIANCE_FLOOR);
    for i in 0..n {
        if p[(i, i)] < floor {
            p[(i, i)] = floor;
        }
        for j in i + 1..n {
            let v = (p[(i, j)] + p[(j, i)]) * T::c(0.5);
            p[(i, j)] = v;
            p[(j, i)] = v;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    fn random_spd(seed: u64) -> Cov<f64> {
        let mut s = seed;
        let mut next = || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((s >> 11) as f64 / (1u64 << 53) as f64) - 0.5
        };
        let a = Cov::<f64>::from_fn(|_, _| next());
        a * a.transpose() + Cov::identity() * 0.1
    }

    #[test]
    fn joseph_update_equals_the_textbook_update() {
        let mut st = State::<f64> {
            p: random_spd(7),
            ..Default::default()
        };
        let mut h = [SparseRow::default(), SparseRow::default()];
        h[0].push_slice(0, &[1.0, -0.5, 0.25]);
        h[0].push(12, 2.0);
        h[1].push_slice(6, &[0.3, 0.1, -0.2, 0.4]);
        let r = SMatrix::<f64, 2, 2>::new(0.5, 0.1, 0.1, 0.3);
        let z = SVector::<f64, 2>::new(0.2, -0.4);
        let hd =
            SMatrix::<f64, 2, N>::from_rows(&[h[0].dense().transpose(), h[1].dense().transpose()]);
        let p0 = st.p;
        let x0 = st.x;
        let s_ref = hd * p0 * hd.transpose() + r;
        let k_ref = p0 * hd.transpose() * s_ref.try_inverse().unwrap();
        let ikh = Cov::<f64>::identity() - k_ref * hd;
        let p_ref = ikh * p0 * ikh.transpose() + k_ref * r * k_ref.transpose();
        let (u, s) = innovation(&st, N, &h, &r);
        assert_relative_eq!(s, s_ref, epsilon = 1e-10);
        joseph_update(&mut st, N, &u, &s, &z).unwrap();
        assert_relative_eq!(st.p, p_ref, epsilon = 1e-10);
        assert_relative_eq!(st.x - x0, k_ref * z, epsilon = 1e-10);
    }

    #[test]
    fn singular_innovation_is_an_error() {
        let mut st = State::<f64>::default();
        let mut h = [SparseRow::default()];
        h[0].push(0, 1.0);
        let (u, s) = innovation(&st, N, &h, &SMatrix::<f64, 1, 1>::zeros());
        let before = st.clone();
        assert_eq!(
            joseph_update(&mut st, N, &u, &s, &SVector::<f64, 1>::new(1.0)),
            Err(UpdateError::Singular)
        );
        assert_eq!(st, before);
    }
}
