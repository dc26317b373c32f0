//! The Gauss-Newton step of the KLT: the 4×4 normal equations solved by a Cholesky
//! factorisation in the order `[a, b, d₁, d₂]`, whose last 2×2 block is then the position
//! block's Schur complement (the position information left after eliminating `λ, δ`,
//! docs/VISION.md §5) for the texture test, at no extra cost.

use nalgebra::Matrix4;

use super::KltModel;
use super::window::Normal;

/// The parameters in factorisation order.
const ORDER: [usize; 4] = [2, 3, 0, 1];

/// A factorised normal matrix.
pub(super) struct Factor {
    /// Lower-triangular `L` of `H = L Lᵀ`, in [`ORDER`].
    l: [[f64; 4]; 4],
}

impl Factor {
    /// Factorises the normal matrix restricted to `model`'s parameters (fixed `λ, δ` as unit
    /// rows, so the same solve applies); `None` if it is not positive definite or the position
    /// block's smallest eigenvalue, after eliminating `λ, δ`, is below `min_eigenvalue` per
    /// pixel used (no usable texture; censored pixels, eq. 5.6, carry none and do not count).
    pub fn new(n: &Normal, model: KltModel, min_eigenvalue: f64) -> Option<Self> {
        let mut h = [[0f64; 4]; 4];
        for (i, row) in h.iter_mut().enumerate() {
            for (j, v) in row.iter_mut().enumerate() {
                let (p, q) = (ORDER[i], ORDER[j]);
                *v = if model == KltModel::Translation && (p >= 2 || q >= 2) {
                    if p == q { 1.0 } else { 0.0 }
                } else {
                    n.h[p][q]
                };
            }
        }
        let mut l = [[0f64; 4]; 4];
        for j in 0..4 {
            let d = h[j][j] - l[j][..j].iter().map(|v| v * v).sum::<f64>();
            // Not positive definite, or NaN.
            if d.is_nan() || d <= 0.0 {
                return None;
            }
            let djj = d.sqrt();
            l[j][j] = djj;
            for i in j + 1..4 {
                let dot: f64 = l[i][..j].iter().zip(&l[j][..j]).map(|(a, b)| a * b).sum();
                l[i][j] = (h[i][j] - dot) / djj;
            }
        }
        // Schur complement S = L₂₂ L₂₂ᵀ of the position block; its smaller eigenvalue.
        let (s11, s12, s22) = (
            l[2][2] * l[2][2],
            l[2][2] * l[3][2],
            l[3][2] * l[3][2] + l[3][3] * l[3][3],
        );
        let min_eig = 0.5 * (s11 + s22 - (s11 - s22).hypot(2.0 * s12));
        if !min_eig.is_finite() || min_eig < min_eigenvalue * n.used {
            return None;
        }
        Some(Self { l })
    }

    /// `H⁻¹ v` in parameter order `[d₁, d₂, a, b]`.
    pub fn solve(&self, v: [f64; 4]) -> [f64; 4] {
        let l = &self.l;
        let mut y = [0f64; 4];
        for i in 0..4 {
            let mut s = v[ORDER[i]];
            for k in 0..i {
                s -= l[i][k] * y[k];
            }
            y[i] = s / l[i][i];
        }
        let mut x = [0f64; 4];
        for i in (0..4).rev() {
            let mut s = y[i];
            for k in i + 1..4 {
                s -= l[k][i] * x[k];
            }
            x[i] = s / l[i][i];
        }
        let mut out = [0f64; 4];
        for (i, &p) in ORDER.iter().enumerate() {
            out[p] = x[i];
        }
        out
    }

    /// `H⁻¹` in parameter order.
    pub fn inverse(&self) -> Matrix4<f64> {
        let mut inv = Matrix4::zeros();
        for c in 0..4 {
            let mut e = [0.0; 4];
            e[c] = 1.0;
            let col = self.solve(e);
            for (r, v) in col.iter().enumerate() {
                inv[(r, c)] = *v;
            }
        }
        inv
    }
}
