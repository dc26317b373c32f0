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

    /// `P hᵀ` over the active block, read from the upper triangle only (the lower one may be
    /// stale between a step's updates; see [`condition`]).
    pub fn p_ht(&self, p: &Cov<T>, n: usize) -> SVector<T, N> {
        let mut u = [T::zero(); N];
        let ps = p.as_slice();
        for (j, h) in self.iter() {
            // Column j holds P[0..=j, j] contiguously; P[i, j] for i > j is P[j, i], found in
            // column i at row j: a stride of N from (j, j + 1).
            for (ui, &v) in u[..=j].iter_mut().zip(&ps[j * N..=j * N + j]) {
                *ui += v * h;
            }
            if j + 1 < n {
                let strided = ps[(j + 1) * N + j..].iter().step_by(N);
                for (ui, &v) in u[j + 1..n].iter_mut().zip(strided) {
                    *ui += v * h;
                }
            }
        }
        SVector::from(u)
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
/// Expanded, `P ← P − K Uᵀ − U Kᵀ + K S Kᵀ = P + K Wᵀ − U Kᵀ` with `W = K S − U`: valid for
/// any gain, so rounding in `K` enters only to second order (the point of the Joseph form).
/// Only the upper triangle of the active block is written (column by column, contiguous), in
/// `O(n² M)`: callers finish a batch of updates with [`condition`], which mirrors it.
pub fn joseph_update<T: Scalar, const M: usize>(
    st: &mut State<T>,
    n: usize,
    u: &SMatrix<T, N, M>,
    s: &SMatrix<T, M, M>,
    z: &SVector<T, M>,
) -> Result<(), UpdateError> {
    let s_inv = spd_inverse(s).ok_or(UpdateError::Singular)?;
    let us = u.as_slice();
    // K = U S⁻¹ and W = K S − U, column by column, on plain arrays (no bounds checks in the
    // loops that run n² times below).
    let mut k = [[T::zero(); N]; M];
    let mut w = [[T::zero(); N]; M];
    for m in 0..M {
        for l in 0..M {
            let f = s_inv[(l, m)];
            for (ki, &ui) in k[m][..n].iter_mut().zip(&us[l * N..l * N + n]) {
                *ki += ui * f;
            }
        }
    }
    for m in 0..M {
        for l in 0..M {
            let f = s[(l, m)];
            let kl = k[l];
            for (wi, &ki) in w[m][..n].iter_mut().zip(&kl[..n]) {
                *wi += ki * f;
            }
        }
        for (wi, &ui) in w[m][..n].iter_mut().zip(&us[m * N..m * N + n]) {
            *wi -= ui;
        }
    }
    for m in 0..M {
        let zm = z[m];
        for (x, &ki) in st.x.as_mut_slice()[..n].iter_mut().zip(&k[m][..n]) {
            *x += ki * zm;
        }
    }
    // One pass over the upper triangle for all M columns: each P_ij is loaded and stored once.
    let p = st.p.as_mut_slice();
    for (j, col) in p.chunks_exact_mut(N).take(n).enumerate() {
        let wj: [T; M] = core::array::from_fn(|m| w[m][j]);
        let kj: [T; M] = core::array::from_fn(|m| k[m][j]);
        for (i, pij) in col[..=j].iter_mut().enumerate() {
            let mut acc = *pij;
            for m in 0..M {
                acc += k[m][i] * wj[m] - us[m * N + i] * kj[m];
            }
            *pij = acc;
        }
    }
    Ok(())
}

/// Inverse of a symmetric positive definite innovation covariance; `None` otherwise (closed
/// form for the 1×1 and 2×2 cases the filter uses, Cholesky beyond).
fn spd_inverse<T: Scalar, const M: usize>(s: &SMatrix<T, M, M>) -> Option<SMatrix<T, M, M>> {
    let inv = match M {
        1 => {
            let a = s[(0, 0)];
            (a > T::zero()).then(|| SMatrix::from_element(T::one() / a))?
        }
        2 => {
            let (a, b, d) = (s[(0, 0)], s[(0, 1)], s[(1, 1)]);
            let det = a * d - b * b;
            // A NaN passes here but not the finiteness check below.
            if a <= T::zero() || det <= T::zero() {
                return None;
            }
            let mut inv = SMatrix::zeros();
            inv[(0, 0)] = d / det;
            inv[(0, 1)] = -b / det;
            inv[(1, 0)] = -b / det;
            inv[(1, 1)] = a / det;
            inv
        }
        _ => s.cholesky()?.inverse(),
    };
    inv.iter().all(|v| v.is_finite()).then_some(inv)
}

/// Ends a batch of updates: mirrors the upper triangle of the active block into the lower one
/// (so the covariance is exactly symmetric) and keeps variances at or above the scalar's
/// floor.
pub fn condition<T: Scalar>(p: &mut Cov<T>, n: usize) {
    let floor = T::c(T::VARIANCE_FLOOR);
    let ps = p.as_mut_slice();
    for j in 0..n {
        if ps[j * N + j] < floor {
            ps[j * N + j] = floor;
        }
        for i in j + 1..n {
            // P[i, j] (column j, row i) ← P[j, i] (column i, row j).
            ps[j * N + i] = ps[i * N + j];
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
        condition(&mut st.p, N);
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
