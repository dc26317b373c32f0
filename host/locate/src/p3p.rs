//! Lambda Twist P3P: the camera pose from three bearing / world point pairs.
//!
//! Persson & Nordberg, "Lambda Twist: An Accurate Fast Robust Perspective Three Point (P3P)
//! Solver", ECCV 2018. The solver finds the depths `λ_i` of the three points along their
//! bearings from the three distance constraints (Lambda Twist eq. 4), by turning the
//! intersection of two conics into the intersection of a degenerate conic (a pair of lines)
//! with one of them, then recovers the rotation and translation from the two triangles (world
//! and camera).
//!
//! Where this code differs from the paper's Algorithm 1, it is for robustness, not speed:
//! all real roots of the cubic are tried and the best-conditioned line pair is kept, the
//! lines are parametrised without dividing by one chosen coordinate, and the rotation is
//! projected onto SO(3) with an SVD.

use nalgebra::{Matrix2x3, Matrix3, Rotation3, UnitQuaternion, Vector3};

/// Gauss-Newton steps on the λ's (Lambda Twist Sec. 3.8: "a few verified steps").
const REFINE_ITERATIONS: usize = 5;

/// Below this sine, two bearings or two world edges count as parallel (degenerate input).
const PARALLEL_SINE: f64 = 1e-10;

/// A solution is kept only if, after refinement, Lambda Twist eq. 4 holds to this relative
/// residual.
const ACCEPT_RESIDUAL: f64 = 1e-6;

/// Up to four poses `(q_cw, t)` with `x_c = q_cw * x_w + t` such that the world points `x_w[i]`
/// lie along the unit bearings `y[i]` (camera frame).
///
/// Every returned pose puts the three points in front of the camera (positive depth). The
/// bearings are normalised here, so any non-zero length is accepted. Degenerate input
/// (collinear or coincident world points, parallel bearings, non-finite values) returns an
/// empty `Vec`.
pub fn p3p(
    y: &[Vector3<f64>; 3],
    x_w: &[Vector3<f64>; 3],
) -> Vec<(UnitQuaternion<f64>, Vector3<f64>)> {
    let mut out = Vec::new();
    if !y
        .iter()
        .chain(x_w.iter())
        .all(|v| v.iter().all(|c| c.is_finite()))
    {
        return out;
    }
    let mut yn = [Vector3::zeros(); 3];
    for (dst, src) in yn.iter_mut().zip(y.iter()) {
        let n = src.norm();
        if !(n > 0.0 && n.is_finite()) {
            return out;
        }
        *dst = src / n;
    }
    let [y1, y2, y3] = yn;
    for (a, b) in [(y1, y2), (y1, y3), (y2, y3)] {
        if a.cross(&b).norm() < PARALLEL_SINE {
            return out;
        }
    }

    // World triangle; its edges also build the rotation at the end (Alg. 1, the MIX step).
    let d12 = x_w[0] - x_w[1];
    let d13 = x_w[0] - x_w[2];
    let d23 = x_w[1] - x_w[2];
    let n_w = d12.cross(&d13);
    if !(n_w.norm() >= PARALLEL_SINE * d12.norm() * d13.norm() && n_w.norm() > 0.0) {
        return out;
    }
    let Some(x_mix_inv) = Matrix3::from_columns(&[d12, d13, n_w]).try_inverse() else {
        return out;
    };

    // Lambda Twist eq. 3; the a's are scaled so the largest is 1 (λ's then O(1)), which keeps
    // the cubic's coefficients well scaled whatever the object's size.
    let scale = d12
        .norm_squared()
        .max(d13.norm_squared())
        .max(d23.norm_squared());
    let a12 = d12.norm_squared() / scale;
    let a13 = d13.norm_squared() / scale;
    let a23 = d23.norm_squared() / scale;
    let b12 = y1.dot(&y2);
    let b13 = y1.dot(&y3);
    let b23 = y2.dot(&y3);
    let c = Constraints {
        a12,
        a13,
        a23,
        b12,
        b13,
        b23,
    };

    // Lambda Twist eq. 4: Λᵀ M_ij Λ = a_ij.
    let m12 = Matrix3::new(1.0, -b12, 0.0, -b12, 1.0, 0.0, 0.0, 0.0, 0.0);
    let m13 = Matrix3::new(1.0, 0.0, -b13, 0.0, 0.0, 0.0, -b13, 0.0, 1.0);
    let m23 = Matrix3::new(0.0, 0.0, 0.0, 0.0, 1.0, -b23, 0.0, -b23, 1.0);
    // Two homogeneous conics Λᵀ D_k Λ = 0 (eliminating the a's from Lambda Twist eq. 4).
    let d1 = m12 * a23 - m23 * a12;
    let d2 = m13 * a23 - m23 * a13;

    let Some(lines) = degenerate_conic(&d1, &d2) else {
        return out;
    };

    let mut lambdas: Vec<Vector3<f64>> = Vec::with_capacity(4);
    for n in lines {
        for lam in intersect_line(&n, &d1, &d2, &c) {
            let Some(lam) = refine_lambda(lam, &c) else {
                continue;
            };
            // Two lines through the same conic point would give the same solution twice.
            if lambdas
                .iter()
                .any(|l| (l - lam).norm() <= 1e-9 * lam.norm())
            {
                continue;
            }
            lambdas.push(lam);
        }
    }

    let s = scale.sqrt();
    for lam in lambdas {
        let lam = lam * s;
        let p = [y1 * lam[0], y2 * lam[1], y3 * lam[2]];
        // R maps the world triangle onto the camera one: R [d12 d13 n] = [e12 e13 m].
        let e12 = p[0] - p[1];
        let e13 = p[0] - p[2];
        let r = Matrix3::from_columns(&[e12, e13, e12.cross(&e13)]) * x_mix_inv;
        let Some(rot) = nearest_rotation(&r) else {
            continue;
        };
        let t = (p[0] - rot * x_w[0] + p[1] - rot * x_w[1] + p[2] - rot * x_w[2]) / 3.0;
        let q = UnitQuaternion::from_rotation_matrix(&rot);
        if t.iter().all(|v| v.is_finite()) && q.coords.iter().all(|v| v.is_finite()) {
            out.push((q, t));
        }
    }
    out
}

/// The data of Lambda Twist eq. 4 (squared distances, normalised, and bearing cosines).
struct Constraints {
    a12: f64,
    a13: f64,
    a23: f64,
    b12: f64,
    b13: f64,
    b23: f64,
}

impl Constraints {
    /// Residuals of Lambda Twist eq. 4: λ_i² + λ_j² − 2 b_ij λ_i λ_j − a_ij for (12, 13, 23).
    fn residual(&self, l: &Vector3<f64>) -> Vector3<f64> {
        Vector3::new(
            l[0] * l[0] + l[1] * l[1] - 2.0 * self.b12 * l[0] * l[1] - self.a12,
            l[0] * l[0] + l[2] * l[2] - 2.0 * self.b13 * l[0] * l[2] - self.a13,
            l[1] * l[1] + l[2] * l[2] - 2.0 * self.b23 * l[1] * l[2] - self.a23,
        )
    }

    /// Jacobian of [`Constraints::residual`] with respect to Λ.
    fn jacobian(&self, l: &Vector3<f64>) -> Matrix3<f64> {
        let (l1, l2, l3) = (l[0], l[1], l[2]);
        Matrix3::new(
            2.0 * (l1 - self.b12 * l2),
            2.0 * (l2 - self.b12 * l1),
            0.0,
            2.0 * (l1 - self.b13 * l3),
            0.0,
            2.0 * (l3 - self.b13 * l1),
            0.0,
            2.0 * (l2 - self.b23 * l3),
            2.0 * (l3 - self.b23 * l2),
        )
    }

    /// Squared distances of the camera triangle for unscaled depths (Λᵀ M_ij Λ), in (12, 13, 23).
    fn quad(&self, l: &Vector3<f64>) -> Vector3<f64> {
        self.residual(l) + Vector3::new(self.a12, self.a13, self.a23)
    }
}

/// The pair of lines `n·Λ = 0` (as normals `n`) of a degenerate member `D0 = D1 + γ D2` of the
/// pencil (Lambda Twist: the cubic det(D1 + γ D2) = 0 and the eigen-decomposition of D0,
/// Alg. 2 "eig3x3known0").
///
/// The paper takes one root of the cubic. A root whose D0 is semi-definite (a pair of complex
/// lines, meeting in one real point) cannot give the solutions, so every real root is tried and
/// the one whose two non-zero eigenvalues are best balanced (clearest pair of real lines) wins.
fn degenerate_conic(d1: &Matrix3<f64>, d2: &Matrix3<f64>) -> Option<[Vector3<f64>; 2]> {
    // det(D1 + γ D2) = c3 γ³ + c2 γ² + c1 γ + c0, by multilinearity in the columns.
    let col = |m: &Matrix3<f64>, j: usize| -> Vector3<f64> { m.column(j).into() };
    let (p1, p2, p3) = (col(d1, 0), col(d1, 1), col(d1, 2));
    let (q1, q2, q3) = (col(d2, 0), col(d2, 1), col(d2, 2));
    let c3 = d2.determinant();
    let c2 = p1.dot(&q2.cross(&q3)) + p2.dot(&q3.cross(&q1)) + p3.dot(&q1.cross(&q2));
    let c1 = q1.dot(&p2.cross(&p3)) + q2.dot(&p3.cross(&p1)) + q3.dot(&p1.cross(&p2));
    let c0 = d1.determinant();

    let mut candidates: Vec<Matrix3<f64>> = real_cubic_roots(c3, c2, c1, c0)
        .into_iter()
        .map(|g| d1 + d2 * g)
        .collect();
    // A (near) vanishing c3 means D2 itself is degenerate: the root γ = ∞.
    let cmax = c3.abs().max(c2.abs()).max(c1.abs()).max(c0.abs());
    if c3.abs() <= 1e-8 * cmax {
        candidates.push(*d2);
    }

    let mut best: Option<(f64, [Vector3<f64>; 2])> = None;
    for d0 in candidates {
        let norm = d0.norm();
        if !(norm > 0.0 && norm.is_finite()) {
            continue;
        }
        let d0 = d0 / norm;
        let Some((quality, lines)) = line_pair(&d0) else {
            continue;
        };
        if best.as_ref().is_none_or(|(q, _)| quality > *q) {
            best = Some((quality, lines));
        }
    }
    best.map(|(_, l)| l)
}

/// For a rank-2 symmetric `D0` (unit Frobenius norm) with eigenvalues σ1 > 0 > σ2 and
/// eigenvectors e1, e2: Λᵀ D0 Λ = σ1 (e1·Λ)² + σ2 (e2·Λ)² = 0 splits into the two planes
/// (√σ1 e1 ± √−σ2 e2)·Λ = 0. Returns min(σ1, −σ2) / max(σ1, −σ2) as the conditioning.
fn line_pair(d0: &Matrix3<f64>) -> Option<(f64, [Vector3<f64>; 2])> {
    // Alg. 2: with one eigenvalue known to be 0, the others solve σ² − tr σ + m = 0, m being
    // the sum of the principal 2×2 minors (= σ1 σ2).
    let tr = d0.trace();
    let m = d0[(0, 0)] * d0[(1, 1)] - d0[(0, 1)] * d0[(1, 0)] + d0[(0, 0)] * d0[(2, 2)]
        - d0[(0, 2)] * d0[(2, 0)]
        + d0[(1, 1)] * d0[(2, 2)]
        - d0[(1, 2)] * d0[(2, 1)];
    if m.is_nan() || m >= 0.0 {
        // Semi-definite: complex lines (or a double line), no real pair to intersect with.
        return None;
    }
    let disc = (tr * tr - 4.0 * m).sqrt();
    let s1 = 0.5 * (tr + disc);
    let s2 = 0.5 * (tr - disc);
    if !(s1 > 0.0 && s2 < 0.0) {
        return None;
    }
    let e1 = null_vector(&(d0 - Matrix3::identity() * s1))?;
    let e2 = null_vector(&(d0 - Matrix3::identity() * s2))?;
    let (a, b) = (s1.sqrt(), (-s2).sqrt());
    let quality = s1.min(-s2) / s1.max(-s2);
    Some((quality, [e1 * a + e2 * b, e1 * a - e2 * b]))
}

/// Unit null vector of a rank-2 3×3 matrix: the largest cross product of two of its columns.
fn null_vector(m: &Matrix3<f64>) -> Option<Vector3<f64>> {
    let c0: Vector3<f64> = m.column(0).into();
    let c1: Vector3<f64> = m.column(1).into();
    let c2: Vector3<f64> = m.column(2).into();
    let cands = [c0.cross(&c1), c0.cross(&c2), c1.cross(&c2)];
    let best = cands
        .iter()
        .copied()
        .max_by(|a, b| a.norm_squared().total_cmp(&b.norm_squared()))?;
    let n = best.norm();
    (n > 0.0 && n.is_finite()).then(|| best / n)
}

/// Points of the plane `n·Λ = 0` on the conics (Λᵀ D1 Λ = Λᵀ D2 Λ = 0), scaled by Lambda Twist
/// eq. 4 and with positive depths (the paper's τ step, written without dividing by one λ).
fn intersect_line(
    n: &Vector3<f64>,
    d1: &Matrix3<f64>,
    d2: &Matrix3<f64>,
    c: &Constraints,
) -> Vec<Vector3<f64>> {
    let mut out = Vec::new();
    let nn = n.norm();
    if !(nn > 0.0 && nn.is_finite()) {
        return out;
    }
    let n = n / nn;
    // Orthonormal basis (p, q) of the plane: Λ = α p + β q.
    let axis = if n[0].abs() <= n[1].abs() && n[0].abs() <= n[2].abs() {
        Vector3::x()
    } else if n[1].abs() <= n[2].abs() {
        Vector3::y()
    } else {
        Vector3::z()
    };
    let p = n.cross(&axis).normalize();
    let q = n.cross(&p);
    let basis = Matrix2x3::from_rows(&[p.transpose(), q.transpose()]);

    // On the plane both conics vanish together (D0 = D1 + γ D2 vanishes there): use whichever
    // restricts to the larger quadratic form, the other may be nearly D0 itself.
    let restrict = |d: &Matrix3<f64>| basis * d * basis.transpose();
    let r1 = restrict(d1) / d1.norm().max(f64::MIN_POSITIVE);
    let r2 = restrict(d2) / d2.norm().max(f64::MIN_POSITIVE);
    let r = if r1.norm() >= r2.norm() { r1 } else { r2 };
    let (qa, qb, qc) = (r[(0, 0)], r[(0, 1)], r[(1, 1)]);

    // qa α² + 2 qb αβ + qc β² = 0, solved for directions (α, β) without division.
    let disc = qb * qb - qa * qc;
    if disc.is_nan() || disc < 0.0 {
        return out;
    }
    let rt = -(qb + qb.signum() * disc.sqrt());
    let dirs: Vec<(f64, f64)> = if rt != 0.0 {
        vec![(rt, qa), (qc, rt)]
    } else if qa.abs() < qc.abs() {
        vec![(1.0, 0.0)]
    } else if qc.abs() < qa.abs() || qa != 0.0 {
        vec![(0.0, 1.0)]
    } else {
        // The whole plane lies on both conics: degenerate.
        vec![]
    };

    for (alpha, beta) in dirs {
        let mut l = p * alpha + q * beta;
        if l.sum() < 0.0 {
            l = -l;
        }
        if l.iter().any(|v| v.is_nan() || *v <= 0.0) {
            continue;
        }
        // Scale from Lambda Twist eq. 4 in least squares over the three constraints.
        let dq = c.quad(&l);
        let av = Vector3::new(c.a12, c.a13, c.a23);
        let den = dq.norm_squared();
        if den.is_nan() || den <= 0.0 {
            continue;
        }
        let k2 = av.dot(&dq) / den;
        if !(k2 > 0.0 && k2.is_finite()) {
            continue;
        }
        out.push(l * k2.sqrt());
    }
    out
}

/// Lambda Twist Sec. 3.8: Gauss-Newton on the sum of squares of eq. 4 (three equations, three
/// unknowns, so each step is a Newton step), each step kept only if it lowers the residual.
/// Returns `None` if the result does not satisfy Lambda Twist eq. 4 or has a non-positive depth.
fn refine_lambda(mut l: Vector3<f64>, c: &Constraints) -> Option<Vector3<f64>> {
    let mut r = c.residual(&l);
    let mut err = r.norm_squared();
    for _ in 0..REFINE_ITERATIONS {
        if err <= 1e-30 {
            break;
        }
        let Some(step) = c.jacobian(&l).lu().solve(&(-r)) else {
            break;
        };
        let cand = l + step;
        let rc = c.residual(&cand);
        let ec = rc.norm_squared();
        if ec.is_nan() || ec >= err {
            break;
        }
        l = cand;
        r = rc;
        err = ec;
    }
    // The a's are normalised to max 1, so this is a relative tolerance.
    (err.sqrt() <= ACCEPT_RESIDUAL && l.min() > 0.0 && l.iter().all(|v| v.is_finite())).then_some(l)
}

/// Closest rotation (Frobenius) to a nearly orthonormal matrix, by SVD with det = +1.
fn nearest_rotation(m: &Matrix3<f64>) -> Option<Rotation3<f64>> {
    if !m.iter().all(|v| v.is_finite()) {
        return None;
    }
    let svd = m.try_svd(true, true, f64::EPSILON, 200)?;
    let (mut u, v_t) = (svd.u?, svd.v_t?);
    if (u * v_t).determinant() < 0.0 {
        u.column_mut(2).neg_mut();
    }
    let r = u * v_t;
    // A P3P solution maps a triangle onto a congruent one: far from orthonormal means garbage.
    if (r - m).norm() > 1e-3 * m.norm().max(1.0) {
        return None;
    }
    Some(Rotation3::from_matrix_unchecked(r))
}

/// Real roots of c3 γ³ + c2 γ² + c1 γ + c0 (closed form, then polished by Newton).
fn real_cubic_roots(c3: f64, c2: f64, c1: f64, c0: f64) -> Vec<f64> {
    let s = c3.abs().max(c2.abs()).max(c1.abs()).max(c0.abs());
    if !(s > 0.0 && s.is_finite()) {
        return Vec::new();
    }
    let (c3, c2, c1, c0) = (c3 / s, c2 / s, c1 / s, c0 / s);
    let mut roots = Vec::with_capacity(3);
    if c3.abs() < 1e-14 {
        // Quadratic (or linear): one root has gone to infinity.
        if c2.abs() < 1e-14 {
            if c1 != 0.0 {
                roots.push(-c0 / c1);
            }
        } else {
            let disc = c1 * c1 - 4.0 * c2 * c0;
            if disc >= 0.0 {
                let qr = -0.5 * (c1 + c1.signum() * disc.sqrt());
                if qr != 0.0 {
                    roots.push(qr / c2);
                    roots.push(c0 / qr);
                } else {
                    roots.push(0.0);
                }
            }
        }
    } else {
        // Monic form and depressed cubic t³ + p t + q with γ = t − a/3.
        let (a, b, cc) = (c2 / c3, c1 / c3, c0 / c3);
        let p = b - a * a / 3.0;
        let q = 2.0 * a * a * a / 27.0 - a * b / 3.0 + cc;
        let disc = 0.25 * q * q + p * p * p / 27.0;
        if disc > 0.0 {
            let u = (-0.5 * q - q.signum() * disc.sqrt()).cbrt();
            let t = if u != 0.0 { u - p / (3.0 * u) } else { 0.0 };
            roots.push(t - a / 3.0);
        } else if p < 0.0 {
            let r = (-p / 3.0).sqrt();
            let arg = (-0.5 * q / (r * r * r)).clamp(-1.0, 1.0);
            let phi = arg.acos() / 3.0;
            for k in 0..3 {
                let t = 2.0 * r * (phi - 2.0 * std::f64::consts::PI * k as f64 / 3.0).cos();
                roots.push(t - a / 3.0);
            }
        } else {
            roots.push(-a / 3.0);
        }
    }
    let f = |g: f64| ((c3 * g + c2) * g + c1) * g + c0;
    let df = |g: f64| (3.0 * c3 * g + 2.0 * c2) * g + c1;
    for g in roots.iter_mut() {
        for _ in 0..3 {
            let (fg, dg) = (f(*g), df(*g));
            if dg == 0.0 || fg == 0.0 {
                break;
            }
            let cand = *g - fg / dg;
            if f(cand).abs() < fg.abs() {
                *g = cand;
            } else {
                break;
            }
        }
    }
    roots.retain(|g| g.is_finite());
    roots
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;
    use nalgebra::{Quaternion, Vector4};
    use rand::rngs::StdRng;
    use rand::{RngExt, SeedableRng};

    /// A rotation drawn uniformly (a normalised 4-vector from the unit ball).
    pub(crate) fn random_rotation(rng: &mut StdRng) -> UnitQuaternion<f64> {
        loop {
            let v = Vector4::new(
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
            );
            let n = v.norm();
            if n > 0.1 && n <= 1.0 {
                return UnitQuaternion::from_quaternion(Quaternion::from(v / n));
            }
        }
    }

    type Scene = (
        [Vector3<f64>; 3],
        [Vector3<f64>; 3],
        UnitQuaternion<f64>,
        Vector3<f64>,
    );

    /// A random scene: points in front of the camera within a 60° cone, depths 0.5..5, the
    /// world frame at a random pose. Returns (bearings, world points, true q_cw, true t).
    fn random_scene(rng: &mut StdRng) -> Scene {
        let q = random_rotation(rng);
        let t = Vector3::new(
            rng.random_range(-2.0..2.0),
            rng.random_range(-2.0..2.0),
            rng.random_range(-2.0..2.0),
        );
        let mut y = [Vector3::zeros(); 3];
        let mut x = [Vector3::zeros(); 3];
        for i in 0..3 {
            let xc = Vector3::new(
                rng.random_range(-0.6..0.6),
                rng.random_range(-0.6..0.6),
                1.0,
            ) * rng.random_range(0.5..5.0);
            y[i] = xc.normalize();
            x[i] = q.inverse() * (xc - t);
        }
        (y, x, q, t)
    }

    /// Well conditioned: bearings at least ~3° apart and a world triangle far from collinear.
    fn well_conditioned(y: &[Vector3<f64>; 3], x: &[Vector3<f64>; 3]) -> bool {
        let min_bearing_sine = [(0, 1), (0, 2), (1, 2)]
            .iter()
            .map(|&(i, j)| y[i].cross(&y[j]).norm())
            .fold(f64::INFINITY, f64::min);
        let e = [x[0] - x[1], x[0] - x[2], x[1] - x[2]];
        let longest = e.iter().map(|v| v.norm()).fold(0.0, f64::max);
        let area2 = e[0].cross(&e[1]).norm();
        min_bearing_sine > 0.05 && area2 > 0.1 * longest * longest
    }

    /// Smallest (rotation, translation) error over the solutions, both relative.
    fn best_error(
        sols: &[(UnitQuaternion<f64>, Vector3<f64>)],
        q: &UnitQuaternion<f64>,
        t: &Vector3<f64>,
    ) -> (f64, f64) {
        let rt = q.to_rotation_matrix().into_inner();
        sols.iter()
            .map(|(qs, ts)| {
                let dr = (qs.to_rotation_matrix().into_inner() - rt).norm();
                let dt = (ts - t).norm() / t.norm().max(1.0);
                (dr, dt)
            })
            .min_by(|a, b| a.0.max(a.1).total_cmp(&b.0.max(b.1)))
            .unwrap_or((f64::INFINITY, f64::INFINITY))
    }

    #[test]
    fn recovers_true_pose_random() {
        let mut rng = StdRng::seed_from_u64(0x5eed_0001);
        let (mut n, mut worst_r, mut worst_t, mut sols_total) = (0, 0.0f64, 0.0f64, 0);
        let mut counts = [0usize; 5];
        for _ in 0..20_000 {
            let (y, x, q, t) = random_scene(&mut rng);
            if !well_conditioned(&y, &x) {
                continue;
            }
            n += 1;
            let sols = p3p(&y, &x);
            assert!(sols.len() <= 4);
            counts[sols.len()] += 1;
            sols_total += sols.len();
            let (dr, dt) = best_error(&sols, &q, &t);
            assert!(
                dr < 1e-9 && dt < 1e-9,
                "pose not recovered: dr {dr:e} dt {dt:e}, {} sols",
                sols.len()
            );
            worst_r = worst_r.max(dr);
            worst_t = worst_t.max(dt);
        }
        println!(
            "p3p: {n} cases, worst |R-R*|_F {worst_r:.2e}, worst |t-t*|/|t*| {worst_t:.2e}, \
             solutions per case {:.2}, histogram {counts:?}",
            sols_total as f64 / n as f64
        );
        assert!(n > 10_000);
    }

    #[test]
    fn every_solution_is_consistent() {
        // Each returned pose must put all three points on their bearings, in front.
        let mut rng = StdRng::seed_from_u64(0x5eed_0002);
        for _ in 0..5_000 {
            let (y, x, _, _) = random_scene(&mut rng);
            for (q, t) in p3p(&y, &x) {
                for i in 0..3 {
                    let xc = q * x[i] + t;
                    assert!(xc.dot(&y[i]) > 0.0);
                    let sine = xc.normalize().cross(&y[i]).norm();
                    assert!(sine < 1e-7, "bearing mismatch {sine:e}");
                }
            }
        }
    }

    #[test]
    fn non_unit_bearings_and_scale_invariance() {
        let mut rng = StdRng::seed_from_u64(0x5eed_0003);
        let mut checked = 0;
        while checked < 200 {
            let (y, x, q, t) = random_scene(&mut rng);
            if !well_conditioned(&y, &x) {
                continue;
            }
            checked += 1;
            let ys = [y[0] * 3.0, y[1] * 0.2, y[2] * 17.0];
            let (dr, dt) = best_error(&p3p(&ys, &x), &q, &t);
            assert!(dr < 1e-9 && dt < 1e-9);
            // A millimetre-scale and a kilometre-scale copy of the same scene.
            for s in [1e-3, 1e3] {
                let xs = [x[0] * s, x[1] * s, x[2] * s];
                let (dr, dt) = best_error(&p3p(&y, &xs), &q, &(t * s));
                assert!(dr < 1e-9 && dt < 1e-9, "scale {s}: {dr:e} {dt:e}");
            }
        }
    }

    #[test]
    fn degenerate_inputs_return_empty() {
        let y = [
            Vector3::new(0.1, 0.0, 1.0).normalize(),
            Vector3::new(0.0, 0.1, 1.0).normalize(),
            Vector3::new(-0.1, -0.1, 1.0).normalize(),
        ];
        let x = [
            Vector3::new(0.0, 0.0, 0.0),
            Vector3::new(1.0, 0.0, 0.0),
            Vector3::new(0.0, 1.0, 0.0),
        ];
        // Collinear world points.
        let xc = [
            Vector3::new(0.0, 0.0, 0.0),
            Vector3::new(1.0, 1.0, 1.0),
            Vector3::new(2.0, 2.0, 2.0),
        ];
        assert!(p3p(&y, &xc).is_empty());
        // Coincident world points.
        let xd = [x[0], x[0], x[2]];
        assert!(p3p(&y, &xd).is_empty());
        let xz = [Vector3::zeros(); 3];
        assert!(p3p(&y, &xz).is_empty());
        // Parallel (equal or opposite) bearings.
        assert!(p3p(&[y[0], y[0], y[2]], &x).is_empty());
        assert!(p3p(&[y[0], -y[0], y[2]], &x).is_empty());
        // Zero bearing.
        assert!(p3p(&[Vector3::zeros(), y[1], y[2]], &x).is_empty());
        // Non-finite values anywhere.
        for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
            for i in 0..3 {
                for k in 0..3 {
                    let mut yb = y;
                    yb[i][k] = bad;
                    assert!(p3p(&yb, &x).is_empty());
                    let mut xb = x;
                    xb[i][k] = bad;
                    assert!(p3p(&y, &xb).is_empty());
                }
            }
        }
        // Huge but finite values: no panic, and anything returned is finite.
        let xh = [x[0] * 1e300, x[1] * 1e300, x[2] * 1e300];
        for (q, t) in p3p(&y, &xh) {
            assert!(q.coords.iter().all(|v| v.is_finite()) && t.iter().all(|v| v.is_finite()));
        }
    }

    #[test]
    fn random_garbage_never_panics() {
        let mut rng = StdRng::seed_from_u64(0x5eed_0004);
        for _ in 0..20_000 {
            let mut v = || {
                Vector3::new(
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                )
            };
            let y = [v(), v(), v()];
            let x = [v(), v(), v()];
            let sols = p3p(&y, &x);
            assert!(sols.len() <= 4);
            for (q, t) in sols {
                assert!(t.iter().all(|c| c.is_finite()));
                for i in 0..3 {
                    assert!((q * x[i] + t).dot(&y[i]) > 0.0);
                }
            }
        }
    }

    #[test]
    fn cubic_roots() {
        // (γ − 1)(γ + 2)(γ − 3) = γ³ − 2γ² − 5γ + 6
        let mut r = real_cubic_roots(1.0, -2.0, -5.0, 6.0);
        r.sort_by(f64::total_cmp);
        assert_eq!(r.len(), 3);
        for (a, b) in r.iter().zip([-2.0, 1.0, 3.0]) {
            assert!((a - b).abs() < 1e-12);
        }
        // γ³ + γ + 1: one real root.
        let r = real_cubic_roots(1.0, 0.0, 1.0, 1.0);
        assert_eq!(r.len(), 1);
        assert!((r[0] * r[0] * r[0] + r[0] + 1.0).abs() < 1e-14);
        assert!(real_cubic_roots(0.0, 0.0, 0.0, 0.0).is_empty());
        assert!(real_cubic_roots(f64::NAN, 1.0, 0.0, 0.0).is_empty());
    }
}
