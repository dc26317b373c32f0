//! RANSAC pose estimation from 2D-3D matches over the Lambda Twist P3P solver.
//!
//! Hypotheses come from random minimal samples of three matches. Each is scored by the pixel
//! reprojection error: inlier count first, then the sum of truncated squared errors (MSAC) to
//! break ties. The number of samples adapts to the best inlier ratio seen so far. The winner is
//! refined by Gauss-Newton on the pixel error of its inliers, and its inliers are counted
//! again.

use nalgebra::{Matrix3, Matrix6, UnitQuaternion, Vector2, Vector3, Vector6};
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};

use super::p3p::p3p;

/// Gauss-Newton iterations of the final refinement, per round.
const REFINE_ITERATIONS: usize = 10;
/// Refine / recount rounds: the inlier set may grow once the pose is better.
const REFINE_ROUNDS: usize = 2;
/// Points closer than this to the camera plane (in world units, along the optical axis)
/// count as behind it: their projection is meaningless.
const MIN_DEPTH: f64 = 1e-9;

/// Settings of [`ransac_pose`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RansacConfig {
    /// Largest reprojection error of an inlier, in pixels.
    pub threshold_px: f64,
    /// Most minimal samples drawn.
    pub max_iterations: usize,
    /// Wanted probability of drawing at least one all-inlier sample, for the adaptive stop.
    /// Not in (0, 1) or not finite: no early stop.
    pub confidence: f64,
    /// Fewest inliers of an accepted pose.
    pub min_inliers: usize,
    /// Seed of the sampler: the same input and seed give the same result.
    pub seed: u64,
}

impl Default for RansacConfig {
    /// 3 px, 2000 samples at most, 99.9 % confidence, 8 inliers, a fixed seed.
    fn default() -> Self {
        Self {
            threshold_px: 3.0,
            max_iterations: 2000,
            confidence: 0.999,
            min_inliers: 8,
            seed: 0x0c01_d57a_2700_5eed,
        }
    }
}

/// Result of [`ransac_pose`].
#[derive(Clone, Debug)]
pub struct RansacPose {
    /// World-to-camera rotation: `x_c = q_cw * x_w + t`.
    pub q_cw: UnitQuaternion<f64>,
    /// World-to-camera translation.
    pub t: Vector3<f64>,
    /// Per match: reprojects within the threshold, in front of the camera (after refinement).
    pub inliers: Vec<bool>,
    /// The best hypotheses of other poses (rotations 5° or more apart), refined, best first,
    /// each with at least `min_inliers`: where the matches fit several poses alike (a face
    /// seen nearly face on), the inlier count at the threshold does not tell them apart, and
    /// the verification is asked instead.
    pub runners_up: Vec<(UnitQuaternion<f64>, Vector3<f64>)>,
}

/// What a RANSAC search did, whether it found a pose or not.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RansacStats {
    /// Minimal samples drawn.
    pub iterations: usize,
    /// Inliers of the best hypothesis, after refinement (0 if none was scored).
    pub best_inliers: usize,
}

/// Pixels `u[i]` (undistorted, pinhole fx, fy, cx, cy) matched to world points `x_w[i]`.
///
/// Returns `None` when there are fewer than 4 matches, the lengths differ, the intrinsics or
/// the threshold are unusable, or the best pose has fewer than `cfg.min_inliers` inliers.
/// Matches with non-finite values are never inliers and never sampled.
pub fn ransac_pose(
    pinhole: [f64; 4],
    u: &[Vector2<f64>],
    x_w: &[Vector3<f64>],
    cfg: &RansacConfig,
) -> Option<RansacPose> {
    ransac_search(pinhole, u, x_w, cfg).0
}

/// [`ransac_pose`], with what the search did either way (a search that found no pose still
/// drew its samples: its report says how many, and how close the best came).
pub fn ransac_search(
    pinhole: [f64; 4],
    u: &[Vector2<f64>],
    x_w: &[Vector3<f64>],
    cfg: &RansacConfig,
) -> (Option<RansacPose>, RansacStats) {
    let nothing = (None, RansacStats::default());
    let n = u.len();
    if n < 4 || x_w.len() != n {
        return nothing;
    }
    let Some(cam) = Pinhole::new(pinhole) else {
        return nothing;
    };
    let thr2 = cfg.threshold_px * cfg.threshold_px;
    if !(cfg.threshold_px > 0.0 && thr2.is_finite()) {
        return nothing;
    }

    // Bearings of the usable matches; the rest stay out of the samples.
    let bearings: Vec<Option<Vector3<f64>>> = u
        .iter()
        .zip(x_w)
        .map(|(ui, xi)| {
            if !(ui.iter().chain(xi.iter()).all(|v| v.is_finite())) {
                return None;
            }
            let b = cam.bearing(ui);
            b.iter().all(|v| v.is_finite()).then_some(b)
        })
        .collect();
    let usable: Vec<usize> = (0..n).filter(|&i| bearings[i].is_some()).collect();
    if usable.len() < 3 {
        return nothing;
    }

    let mut rng = StdRng::seed_from_u64(cfg.seed);
    // The best hypotheses of distinct poses, best first: the first drives the adaptive stop.
    let mut top: Vec<Hypothesis> = Vec::with_capacity(RUNNERS_UP + 2);
    let mut needed = cfg.max_iterations;
    let mut iterations = 0;
    let m = usable.len();
    while iterations < needed.min(cfg.max_iterations) {
        iterations += 1;
        let [i0, i1, i2] = draw3(&mut rng, m);
        let idx = [usable[i0], usable[i1], usable[i2]];
        let (Some(y0), Some(y1), Some(y2)) = (bearings[idx[0]], bearings[idx[1]], bearings[idx[2]])
        else {
            continue;
        };
        for (q, t) in p3p(&[y0, y1, y2], &[x_w[idx[0]], x_w[idx[1]], x_w[idx[2]]]) {
            let h = score(&cam, u, x_w, &q, &t, thr2);
            if top.first().is_none_or(|b| h.better_than(b)) {
                // Adaptive stop: samples for `confidence` of one all-inlier draw (ratio w).
                needed = samples_needed(cfg.confidence, h.count as f64 / n as f64)
                    .unwrap_or(cfg.max_iterations);
            }
            keep_distinct(&mut top, h);
        }
    }

    let mut polished = top.into_iter().map(|h| polish(&cam, u, x_w, h, thr2));
    let Some(best) = polished.next() else {
        let stats = RansacStats {
            iterations,
            best_inliers: 0,
        };
        return (None, stats);
    };
    let stats = RansacStats {
        iterations,
        best_inliers: best.count,
    };
    let runners_up = polished
        .filter(|h| h.count >= cfg.min_inliers)
        .map(|h| (h.q, h.t))
        .collect();
    let pose = (best.count >= cfg.min_inliers).then_some(RansacPose {
        q_cw: best.q,
        t: best.t,
        inliers: best.inliers,
        runners_up,
    });
    (pose, stats)
}

/// Hypotheses kept besides the best, of poses distinct from it and from each other.
const RUNNERS_UP: usize = 2;

/// Two hypotheses whose rotations differ by less than this are one pose [rad].
const DISTINCT_RAD: f64 = 5.0 * std::f64::consts::PI / 180.0;

/// Inserts `h` into `top` (best first, at most `1 + RUNNERS_UP`, distinct poses): a
/// hypothesis of a pose already there replaces it only if better.
fn keep_distinct(top: &mut Vec<Hypothesis>, h: Hypothesis) {
    if let Some(k) = top.iter().position(|o| o.q.angle_to(&h.q) < DISTINCT_RAD) {
        if !h.better_than(&top[k]) {
            return;
        }
        top.remove(k);
    }
    let at = top
        .iter()
        .position(|o| h.better_than(o))
        .unwrap_or(top.len());
    if at <= RUNNERS_UP {
        top.insert(at, h);
        top.truncate(RUNNERS_UP + 1);
    }
}

/// Refines `h` on its inliers and recounts, keeping the refined pose unless it scores worse.
fn polish(
    cam: &Pinhole,
    u: &[Vector2<f64>],
    x_w: &[Vector3<f64>],
    mut best: Hypothesis,
    thr2: f64,
) -> Hypothesis {
    for _ in 0..REFINE_ROUNDS {
        let Some((q, t)) = refine(cam, u, x_w, &best.inliers, best.q, best.t) else {
            break;
        };
        let h = score(cam, u, x_w, &q, &t, thr2);
        if h.cost > best.cost {
            break;
        }
        let same_set = h.inliers == best.inliers;
        best = h;
        if same_set {
            break;
        }
    }
    best
}

/// The pose `x_c = q_cw x_w + t` with the best-fit plane of the model points `x_w` tilted the
/// other way about the line of sight to their centroid (docs/notes/issue15-cold-start.md §4,
/// eq. P1).
///
/// A plane seen from a distance large against its size shows the same image, to first order,
/// tilted by `+θ` or `−θ` about an axis across the line of sight: only the perspective's
/// second-order effects tell the two apart, so a fit may end in either. A cube showing one
/// face has this two-fold ambiguity. Returns `None` for fewer than 3 points, a value that is
/// not finite, or a plane that faces the camera (the two tilts are then one pose).
pub fn mirrored_pose(
    q_cw: &UnitQuaternion<f64>,
    t: &Vector3<f64>,
    x_w: &[Vector3<f64>],
) -> Option<(UnitQuaternion<f64>, Vector3<f64>)> {
    let x_c: Vec<Vector3<f64>> = x_w
        .iter()
        .map(|x| q_cw * x + t)
        .filter(|x| x.iter().all(|v| v.is_finite()))
        .collect();
    if x_c.len() < 3 {
        return None;
    }
    let centroid = x_c.iter().sum::<Vector3<f64>>() / x_c.len() as f64;
    let scatter = x_c
        .iter()
        .map(|x| (x - centroid) * (x - centroid).transpose())
        .sum::<Matrix3<f64>>();
    let eigen = scatter.symmetric_eigen();
    let (k, _) = eigen.eigenvalues.argmin();
    let normal = eigen.eigenvectors.column(k).into_owned();
    // Eq. P1: the normal mirrored about the line of sight to the centroid, and the rotation
    // about the centroid that takes the one to the other.
    let sight = centroid.try_normalize(MIN_DEPTH)?;
    let mirrored = 2.0 * normal.dot(&sight) * sight - normal;
    let axis = normal.cross(&mirrored);
    let turn = UnitQuaternion::from_axis_angle(
        &nalgebra::Unit::try_new(axis, 1e-9)?,
        axis.norm().atan2(normal.dot(&mirrored)),
    );
    Some((turn * q_cw, turn * (t - centroid) + centroid))
}

/// Samples needed so that one of them is all inliers with probability `confidence`, for an
/// inlier ratio `w` (`None`: no early stop).
fn samples_needed(confidence: f64, w: f64) -> Option<usize> {
    if !(confidence > 0.0 && confidence < 1.0) {
        return None;
    }
    let p_good = w.clamp(0.0, 1.0).powi(3);
    if p_good >= 1.0 {
        return Some(1);
    }
    let denom = (-p_good).ln_1p(); // ln(1 − w³) < 0
    if denom.is_nan() || denom >= 0.0 {
        return None;
    }
    let k = ((1.0 - confidence).ln() / denom).ceil();
    // `as` saturates at usize::MAX.
    (k.is_finite() && k >= 0.0).then_some(k as usize)
}

/// Three distinct indices in `0..m` (`m >= 3`), uniformly, with one draw each: each later
/// draw ranges over the values left and skips past the ones taken.
fn draw3(rng: &mut StdRng, m: usize) -> [usize; 3] {
    let i0 = rng.random_range(0..m);
    let mut i1 = rng.random_range(0..m - 1);
    if i1 >= i0 {
        i1 += 1;
    }
    let mut i2 = rng.random_range(0..m - 2);
    let (lo, hi) = if i0 < i1 { (i0, i1) } else { (i1, i0) };
    if i2 >= lo {
        i2 += 1;
    }
    if i2 >= hi {
        i2 += 1;
    }
    [i0, i1, i2]
}

/// Pinhole intrinsics.
#[derive(Clone, Copy)]
struct Pinhole {
    fx: f64,
    fy: f64,
    cx: f64,
    cy: f64,
}

impl Pinhole {
    /// `None` unless all finite and the focal lengths non-zero.
    fn new([fx, fy, cx, cy]: [f64; 4]) -> Option<Self> {
        let ok = [fx, fy, cx, cy].iter().all(|v| v.is_finite()) && fx != 0.0 && fy != 0.0;
        ok.then_some(Self { fx, fy, cx, cy })
    }

    /// Unit bearing of a pixel.
    fn bearing(&self, u: &Vector2<f64>) -> Vector3<f64> {
        Vector3::new((u.x - self.cx) / self.fx, (u.y - self.cy) / self.fy, 1.0).normalize()
    }

    /// Pixel of a camera-frame point (in front of the camera).
    fn project(&self, xc: &Vector3<f64>) -> Vector2<f64> {
        Vector2::new(
            self.fx * xc.x / xc.z + self.cx,
            self.fy * xc.y / xc.z + self.cy,
        )
    }
}

/// A scored pose.
struct Hypothesis {
    q: UnitQuaternion<f64>,
    t: Vector3<f64>,
    inliers: Vec<bool>,
    count: usize,
    /// MSAC cost: Σ min(e², threshold²) in px².
    cost: f64,
}

impl Hypothesis {
    /// More inliers, or as many with a lower truncated cost.
    fn better_than(&self, other: &Hypothesis) -> bool {
        self.count > other.count || (self.count == other.count && self.cost < other.cost)
    }
}

/// Squared pixel error of one match, `None` when behind the camera or not finite.
fn sq_error(
    cam: &Pinhole,
    u: &Vector2<f64>,
    x: &Vector3<f64>,
    q: &UnitQuaternion<f64>,
    t: &Vector3<f64>,
) -> Option<f64> {
    let xc = q * x + t;
    if xc.z.is_nan() || xc.z <= MIN_DEPTH {
        return None;
    }
    let e2 = (cam.project(&xc) - u).norm_squared();
    e2.is_finite().then_some(e2)
}

/// Inliers and MSAC cost of a pose over all matches.
fn score(
    cam: &Pinhole,
    u: &[Vector2<f64>],
    x_w: &[Vector3<f64>],
    q: &UnitQuaternion<f64>,
    t: &Vector3<f64>,
    thr2: f64,
) -> Hypothesis {
    let mut inliers = vec![false; u.len()];
    let (mut count, mut cost) = (0, 0.0);
    for ((ui, xi), inl) in u.iter().zip(x_w).zip(inliers.iter_mut()) {
        match sq_error(cam, ui, xi, q, t) {
            Some(e2) if e2 <= thr2 => {
                *inl = true;
                count += 1;
                cost += e2;
            }
            _ => cost += thr2,
        }
    }
    Hypothesis {
        q: *q,
        t: *t,
        inliers,
        count,
        cost,
    }
}

/// Gauss-Newton on the pixel reprojection error of the inliers, 6 dof: the update is
/// `q ← exp(δω) q`, `t ← t + δt`, so `∂x_c/∂δω = −[x_c − t]ₓ` and `∂x_c/∂δt = I`.
/// A step is kept only if it lowers the error; `None` if no step was kept.
fn refine(
    cam: &Pinhole,
    u: &[Vector2<f64>],
    x_w: &[Vector3<f64>],
    inliers: &[bool],
    mut q: UnitQuaternion<f64>,
    mut t: Vector3<f64>,
) -> Option<(UnitQuaternion<f64>, Vector3<f64>)> {
    let cost_of = |q: &UnitQuaternion<f64>, t: &Vector3<f64>| -> Option<f64> {
        let mut c = 0.0;
        for ((ui, xi), _) in u.iter().zip(x_w).zip(inliers).filter(|(_, inl)| **inl) {
            c += sq_error(cam, ui, xi, q, t)?;
        }
        Some(c)
    };
    let mut cost = cost_of(&q, &t)?;
    let mut improved = false;
    for _ in 0..REFINE_ITERATIONS {
        let mut jtj = Matrix6::<f64>::zeros();
        let mut jtr = Vector6::<f64>::zeros();
        for ((ui, xi), _) in u.iter().zip(x_w).zip(inliers).filter(|(_, inl)| **inl) {
            let rx = q * xi;
            let xc = rx + t;
            if xc.z.is_nan() || xc.z <= MIN_DEPTH {
                return improved.then_some((q, t));
            }
            let r = cam.project(&xc) - ui;
            let iz = 1.0 / xc.z;
            // ∂pixel/∂x_c of the pinhole projection.
            let dp = nalgebra::Matrix2x3::new(
                cam.fx * iz,
                0.0,
                -cam.fx * xc.x * iz * iz,
                0.0,
                cam.fy * iz,
                -cam.fy * xc.y * iz * iz,
            );
            let mut dx = nalgebra::Matrix3x6::<f64>::zeros();
            dx.fixed_view_mut::<3, 3>(0, 0).copy_from(&(-skew(&rx)));
            dx.fixed_view_mut::<3, 3>(0, 3)
                .copy_from(&Matrix3::identity());
            let j = dp * dx;
            jtj += j.transpose() * j;
            jtr += j.transpose() * r;
        }
        // A whisper of damping keeps the solve defined for near-degenerate inlier sets.
        let damp = 1e-12 * jtj.trace().max(f64::MIN_POSITIVE);
        for k in 0..6 {
            jtj[(k, k)] += damp;
        }
        let Some(chol) = jtj.cholesky() else {
            break;
        };
        let step = chol.solve(&(-jtr));
        if !step.iter().all(|v| v.is_finite()) {
            break;
        }
        let dw = Vector3::new(step[0], step[1], step[2]);
        let dt = Vector3::new(step[3], step[4], step[5]);
        let q_new = UnitQuaternion::from_scaled_axis(dw) * q;
        let t_new = t + dt;
        match cost_of(&q_new, &t_new) {
            Some(c) if c < cost => {
                let tiny = step.norm() < 1e-12 * (1.0 + t.norm());
                q = q_new;
                t = t_new;
                cost = c;
                improved = true;
                if tiny {
                    break;
                }
            }
            _ => break,
        }
    }
    improved.then_some((q, t))
}

/// Cross-product matrix: `skew(a) * b = a × b`.
fn skew(a: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -a.z, a.y, a.z, 0.0, -a.x, -a.y, a.x, 0.0)
}

#[cfg(test)]
mod tests;
