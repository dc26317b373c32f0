//! Covariance arithmetic shared by all models: sparse measurement rows, the measurement update
//! (an `LDLᵀ`-decorrelated sequence of scalar updates in symmetric form), and the guards that
//! keep the covariance symmetric with bounded variances.

use nalgebra::SVector;

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

/// Rows of `U = P Hᵀ` of an `M`-dimensional measurement (`u[i][m] = (P h_mᵀ)_i`): the update
/// pass reads all `M` entries of a row at once.
pub type Gains<T, const M: usize> = [[T; M]; N];

/// The first `n` columns of the symmetric `P`, as fixed-size arrays (column `i` is also row
/// `i`): [`Gains`] are built from whole columns, on the measurement's structure.
pub fn p_columns<T: Scalar>(p: &Cov<T>, n: usize) -> impl Iterator<Item = &[T; N]> {
    p.as_slice()
        .chunks_exact(N)
        .take(n)
        .filter_map(|col| <&[T; N]>::try_from(col).ok())
}

/// `S = H U + R`, with `U = P Hᵀ` from [`Gains`] and `H` from sparse rows.
#[allow(clippy::needless_range_loop)] // triangle index loops
pub fn innovation_cov<T: Scalar, const M: usize>(
    h: &[SparseRow<T>; M],
    u: &Gains<T, M>,
    r: &[[T; M]; M],
) -> [[T; M]; M] {
    let mut s = *r;
    for (sm, row) in s.iter_mut().zip(h) {
        for (j, hj) in row.iter() {
            for (a, &b) in sm.iter_mut().zip(&u[j]) {
                *a += hj * b;
            }
        }
    }
    // H P Hᵀ is symmetric in exact arithmetic; make it so in floating point.
    for a in 0..M {
        for b in a + 1..M {
            let v = (s[a][b] + s[b][a]) * T::c(0.5);
            s[a][b] = v;
            s[b][a] = v;
        }
    }
    s
}

/// `S = L D Lᵀ` (unit lower `L`) of an innovation covariance, with the innovation `y`
/// decorrelated: `ỹ = L⁻¹ y`. Its rows are independent scalar measurements with variances `D`.
#[derive(Clone, Copy, Debug)]
pub struct Ldl<T: Scalar, const M: usize> {
    l: [[T; M]; M],
    d_inv: [T; M],
    /// `ỹ_m / D_m`.
    e: [T; M],
    /// Leading rows with `D_m > 0` (finite): the ones that can be applied.
    pub rank: usize,
    /// Normalised residual `yᵀ S⁻¹ y = Σ ỹ_m² / D_m` over those rows.
    pub nis: T,
}

impl<T: Scalar, const M: usize> Ldl<T, M> {
    /// Factors `S` and decorrelates `y`; stops at the first non-positive or non-finite pivot.
    // Triangle index loops; the last row's `d` and `ỹ` are not read again.
    #[allow(clippy::needless_range_loop, unused_assignments)]
    pub fn new(s: &[[T; M]; M], y: &[T; M]) -> Self {
        // Locals rather than the struct's fields, assembled at the end, and the rows written
        // out for m = 0..6 (`row!`): the small loops inside each then unroll fully and the
        // factors stay in registers. As a loop over m (with the `break` of a refused pivot)
        // the 6×6 factorisation ran over memory, ~1k instructions (issue 18). The same
        // operations in the same order.
        const { assert!(M <= 6, "Ldl::new is written out for up to 6 rows") };
        let mut l = [[T::zero(); M]; M];
        let mut d_inv = [T::zero(); M];
        let mut e = [T::zero(); M];
        let mut rank = M;
        let mut nis = T::zero();
        let mut d = [T::zero(); M];
        let mut yt = [T::zero(); M];
        macro_rules! row {
            ($m:literal) => {
                if $m < M && rank == M {
                    let m = $m;
                    for k in 0..m {
                        let mut a = s[m][k];
                        for t in 0..k {
                            a -= l[m][t] * l[k][t] * d[t];
                        }
                        l[m][k] = a * d_inv[k];
                    }
                    let mut dm = s[m][m];
                    let mut ym = y[m];
                    for t in 0..m {
                        dm -= l[m][t] * l[m][t] * d[t];
                        ym -= l[m][t] * yt[t];
                    }
                    // Written so that a NaN is refused too.
                    if !(dm > T::zero() && dm.is_finite()) {
                        rank = m;
                        l[m] = [T::zero(); M];
                    } else {
                        d[m] = dm;
                        d_inv[m] = T::one() / dm;
                        yt[m] = ym;
                        e[m] = ym * d_inv[m];
                        nis += ym * e[m];
                    }
                }
            };
        }
        row!(0);
        row!(1);
        row!(2);
        row!(3);
        row!(4);
        row!(5);
        Ldl {
            l,
            d_inv,
            e,
            rank,
            nis,
        }
    }

    /// The update by the first [`Self::rank`] decorrelated rows, with `u` the rows of `P Hᵀ`
    /// (overwritten): `W = U L⁻ᵀ`, `x ← x + W D⁻¹ ỹ`, `P ← P − W D⁻¹ Wᵀ`. This is the Kalman
    /// update `K = U S⁻¹`, `P ← P − K S Kᵀ` in symmetric form, i.e. the sequence of scalar updates
    /// `P ← P − w wᵀ / d` (each symmetric, each removing variance only along its row).
    ///
    /// The rows of `W` and the mean step come first; then one pass over the upper triangle of
    /// the active block, a group of columns at a time, updates every `P_ij` once, mirrors it into
    /// the lower triangle and applies the variance floor (the work of [`condition`]).
    ///
    /// Returns the step's component along the quaternion (see [`radial_step`]) for the
    /// divergence monitor.
    pub fn apply(&self, st: &mut State<T>, n: usize, u: &mut Gains<T, M>) -> T {
        let q0 = st.q();
        let n = n.min(N);
        let r = self.rank;
        if r < M {
            // Rows past the rank do not apply (rare: a singular or non-finite pivot). Tested
            // once here, not per row: a fill of variable length per row cost ~20 instructions
            // (issue 18).
            for wj in u.iter_mut().take(n) {
                wj[r..].fill(T::zero());
            }
        }
        for (wj, xj) in u.iter_mut().zip(st.x.as_mut_slice()).take(n) {
            let mut w = *wj;
            // Rows of L past the rank are zero.
            for m in 1..M {
                for t in 0..m {
                    w[m] -= self.l[m][t] * w[t];
                }
            }
            *wj = w;
            let mut dx = T::zero();
            for (&wm, &em) in w.iter().zip(&self.e) {
                dx += wm * em;
            }
            *xj += dx;
        }
        self.downdate(&mut st.p, n, u);
        radial_step(&q0, &st.q())
    }

    /// `P ← P − W D⁻¹ Wᵀ` over the upper triangle of the first `n` columns, mirrored, with the
    /// variance floor. Columns go in groups of [`Self::GROUP`]: each row of `W` is loaded once
    /// for the whole group (the pass is load-bound on the MCU) and the group's mirrored entries
    /// of a row are adjacent. Every entry is its own `dot_sub` of its old value, so neither the
    /// grouping nor the order of the entries changes a bit of the result.
    fn downdate(&self, p: &mut Cov<T>, n: usize, w: &Gains<T, M>) {
        let cols = &mut p.data.0;
        let n = n.min(N);
        // The columns that do not fill a group come first: they have the fewest rows above.
        let lead = n % Self::GROUP;
        for j in 0..lead {
            self.columns::<1>(cols, j, w);
        }
        let mut j = lead;
        while j < n {
            // `GROUP` as a const argument (no generic const expressions on stable Rust).
            if Self::GROUP == 3 {
                self.columns::<3>(cols, j, w);
            } else {
                self.columns::<4>(cols, j, w);
            }
            j += Self::GROUP;
        }
    }

    /// Columns per group in [`Self::downdate`]: as many as keep the group's `G · M`
    /// coefficients, a row of `W` and `G` sums within the Cortex-M4F's 32 single-precision
    /// registers (`M` = 6: 3 · 6 + 6 + 3 = 27; `M` = 2: 4 · 2 + 2 + 4 = 14, where more columns
    /// gained no more than the code they cost).
    const GROUP: usize = if M > 3 { 3 } else { 4 };

    /// The downdate of columns `j .. j + G` (rows `0 .. j + G`), see [`Self::downdate`].
    #[inline(always)]
    fn columns<const G: usize>(&self, cols: &mut [[T; N]; N], j: usize, w: &Gains<T, M>) {
        let floor = T::c(T::VARIANCE_FLOOR);
        let (left, right) = cols.split_at_mut(j.min(N));
        let Some(group) = right.first_chunk_mut::<G>() else {
            return;
        };
        let Some(wg) = w.get(j..).and_then(|r| r.first_chunk::<G>()) else {
            return;
        };
        let c: [[T; M]; G] = core::array::from_fn(|g| self.scaled(&wg[g]));
        for (i, (other, wi)) in left.iter_mut().zip(w).enumerate() {
            let v: [T; G] = core::array::from_fn(|g| Self::dot_sub(group[g][i], wi, &c[g]));
            for (col, &vg) in group.iter_mut().zip(&v) {
                col[i] = vg;
            }
            // P[j + g, i] (column i, rows j .. j + G) ← P[i, j + g].
            if let Some(mirror) = other.get_mut(j..).and_then(|r| r.first_chunk_mut::<G>()) {
                *mirror = v;
            }
        }
        // The group's own triangle: P[j + a, j + b] for a ≤ b, the diagonal floored.
        for b in 0..G {
            for a in 0..=b {
                let v = Self::dot_sub(group[b][j + a], &wg[a], &c[b]);
                if a == b {
                    group[b][j + b] = if v < floor { floor } else { v };
                } else {
                    group[b][j + a] = v;
                    group[a][j + b] = v;
                }
            }
        }
    }

    /// `w D⁻¹`, a column's coefficients in [`Self::downdate`].
    #[inline(always)]
    fn scaled(&self, w: &[T; M]) -> [T; M] {
        core::array::from_fn(|m| w[m] * self.d_inv[m])
    }

    /// `p − w · c`, subtracting term by term in the order of the rows.
    #[inline(always)]
    fn dot_sub(p: T, w: &[T; M], c: &[T; M]) -> T {
        let mut acc = p;
        for (&wm, &cm) in w.iter().zip(c) {
            acc -= wm * cm;
        }
        acc
    }
}

/// The component along `q0` of a measurement update's step from `q0` to `q`,
/// `|q0ᵀ(q − q0)| / ‖q0‖²`: what the divergence monitor's quaternion test judges
/// (docs/FILTER.md §9, test 3).
///
/// Every measurement's Jacobian is tangent to the sphere through `q0` and the covariance's
/// radial part is uncorrelated with the rest, so a correct update moves `q` perpendicular to
/// itself: the norm then grows by `θ²/8` for a correction of `θ` (a 17° correction alone makes
/// 0.01), which says nothing about the estimate, and the normalisation before the next time
/// update removes it. What a wild or numerically broken update adds is a radial component:
/// that is what is measured.
pub fn radial_step<T: Scalar>(q0: &crate::quat::Quat<T>, q: &crate::quat::Quat<T>) -> T {
    let n0 = q0.norm_squared();
    if n0 > T::zero() {
        (q0.dot(&(q - q0)) / n0).abs()
    } else {
        T::zero()
    }
}

/// Ends a batch of updates: mirrors the upper triangle of the active block into the lower one
/// (so the covariance is exactly symmetric) and keeps variances at or above the scalar's
/// floor. [`Ldl::apply`] already does both as it goes; this is for covariances written by
/// other means, and a cheap guarantee at the end of a batch.
pub fn condition<T: Scalar>(p: &mut Cov<T>, n: usize) {
    let floor = T::c(T::VARIANCE_FLOOR);
    let n = n.min(N);
    let ps = p.as_mut_slice();
    for j in 0..n {
        // Column j below the diagonal from row j of the columns after it, by slices: indexed
        // (`ps[j * N + i] = ps[i * N + j]`) each copy carried two bounds checks at the device
        // loop's opt-level (~10 instructions per entry, issue 18).
        let (head, tail) = ps.split_at_mut((j + 1) * N);
        let col = &mut head[j * N..];
        if col[j] < floor {
            col[j] = floor;
        }
        for (dst, src) in col[j + 1..n].iter_mut().zip(tail.chunks_exact(N)) {
            // P[i, j] (column j, row i) ← P[j, i] (column i, row j).
            *dst = src[j];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;
    use nalgebra::SMatrix;

    /// Uniform values in [−0.5, 0.5) from a linear congruential generator.
    fn uniform(seed: u64) -> impl FnMut() -> f64 {
        let mut s = seed;
        move || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((s >> 11) as f64 / (1u64 << 53) as f64) - 0.5
        }
    }

    fn random_spd(seed: u64) -> Cov<f64> {
        let mut next = uniform(seed);
        let a = Cov::<f64>::from_fn(|_, _| next());
        a * a.transpose() + Cov::identity() * 0.1
    }

    #[test]
    fn update_equals_the_textbook_joseph_update() {
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
        let u_ref = p0 * hd.transpose();
        let mut u: Gains<f64, 2> = core::array::from_fn(|i| [u_ref[(i, 0)], u_ref[(i, 1)]]);
        let s = innovation_cov(&h, &u, &[[r[(0, 0)], r[(0, 1)]], [r[(1, 0)], r[(1, 1)]]]);
        assert_relative_eq!(
            SMatrix::<f64, 2, 2>::from_fn(|a, b| s[a][b]),
            s_ref,
            epsilon = 1e-10
        );
        let f = Ldl::new(&s, &[z[0], z[1]]);
        assert_eq!(f.rank, 2);
        assert_relative_eq!(
            f.nis,
            (z.transpose() * s_ref.try_inverse().unwrap() * z)[0],
            epsilon = 1e-12
        );
        f.apply(&mut st, N, &mut u);
        assert_relative_eq!(st.p, p_ref, epsilon = 1e-10);
        assert_eq!(st.p, st.p.transpose());
        assert_relative_eq!(st.x - x0, k_ref * z, epsilon = 1e-10);
    }

    /// The grouped downdate against the entry-by-entry formula, bit for bit, for both
    /// measurement sizes and every active block size (lead columns and groups alike).
    fn downdate_is_the_entrywise_formula<const M: usize>(seed: u64) {
        let mut uniform = uniform(seed);
        let mut next = || uniform() as f32;
        let ldl = Ldl::<f32, M> {
            l: [[0.0; M]; M],
            d_inv: core::array::from_fn(|_| next() + 1.0),
            e: [0.0; M],
            rank: M,
            nis: 0.0,
        };
        let w: Gains<f32, M> = core::array::from_fn(|_| core::array::from_fn(|_| next()));
        let p0 = Cov::<f32>::from_fn(|_, _| next() * 0.01);
        for n in 0..=N {
            let mut got = p0;
            ldl.downdate(&mut got, n, &w);
            let mut want = p0;
            for j in 0..n {
                let c = ldl.scaled(&w[j]);
                for i in 0..=j {
                    let mut v = Ldl::<f32, M>::dot_sub(p0[(i, j)], &w[i], &c);
                    let floor = <f32 as Scalar>::c(<f32 as Scalar>::VARIANCE_FLOOR);
                    if i == j && v < floor {
                        v = floor;
                    }
                    want[(i, j)] = v;
                    want[(j, i)] = v;
                }
            }
            for (k, (a, b)) in got.iter().zip(want.iter()).enumerate() {
                assert_eq!(a.to_bits(), b.to_bits(), "M {M}, n {n}, entry {k}");
            }
        }
    }

    #[test]
    fn grouped_downdate_is_bit_identical_to_the_entrywise_formula() {
        downdate_is_the_entrywise_formula::<6>(3);
        downdate_is_the_entrywise_formula::<2>(5);
        downdate_is_the_entrywise_formula::<1>(7);
        downdate_is_the_entrywise_formula::<3>(9);
    }

    #[test]
    fn singular_innovation_applies_only_the_rows_before_it() {
        let mut st = State::<f64> {
            p: random_spd(9),
            ..Default::default()
        };
        let before = st.clone();
        let mut u: Gains<f64, 1> = [[0.0]; N];
        let f = Ldl::new(&[[0.0]], &[1.0]);
        assert_eq!(f.rank, 0);
        f.apply(&mut st, N, &mut u);
        assert_eq!(st, before);
        let f = Ldl::new(&[[f64::NAN]], &[1.0]);
        assert_eq!(f.rank, 0);
    }
}
