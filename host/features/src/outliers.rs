//! Registrations that no rigid pose explains (docs/notes/issue14-registration.md).
//!
//! The photometric KLT registers each feature on its own. A feature can converge on the wrong
//! structure: a finger over the object, a repeated texture, the occluder's edge. The fusion
//! core's gate judges each correspondence against the prediction alone, and under fast motion
//! its innovation covariance is wide enough to let such a feature through, so it drags the
//! pose. Here the frame's registrations are judged against one another: a robust rigid pose
//! fit through all of them (eq. R1, Huber-weighted Gauss-Newton from the predicted pose), then
//! the X84 rule on the residuals at that pose (eq. R2, Hampel's rule as Tommasini et al. used
//! it for KLT features): a feature more than 5.2 median absolute deviations beyond the median
//! residual is an outlier, unless its residual is within what a tracked frame tolerates.

use nalgebra::{Matrix6, UnitQuaternion, Vector2, Vector3, Vector6};

use camera::{Camera, CameraPose, Pinhole};

/// A registered pixel (undistorted image) and its model point.
pub type Registration = (Vector2<f64>, Vector3<f64>);

/// When registrations count as outliers.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OutlierRule {
    /// The X84 factor: median absolute deviations beyond the median (5.2 ≈ 3.5 σ of a normal).
    pub mads: f64,
    /// A residual at or below this is never an outlier [px] (the tracked rule's rms).
    pub floor_px: f64,
    /// Fewest registrations for a judgement: below, a rigid fit has too little redundancy.
    pub min_features: usize,
}

impl Default for OutlierRule {
    fn default() -> Self {
        Self {
            mads: 5.2,
            floor_px: 1.5,
            min_features: 8,
        }
    }
}

/// Gauss-Newton iterations of the robust fit (it starts within a few pixels, and converges in
/// three or four).
const ITERATIONS: usize = 8;

/// Huber's constant for 95 % efficiency at the normal, in units of the residual scale.
const HUBER: f64 = 1.345;

/// Median of the magnitude of a 2D normal error over its σ: `√(2 ln 2)` (Rayleigh).
const RAYLEIGH_MEDIAN: f64 = 1.177_410_022_515_474_7;

/// A residual scale below this is numerical noise [px], not a measured spread.
const MIN_SCALE_PX: f64 = 0.05;

/// The robust scale σ [px] of 2D residual magnitudes: their median over the Rayleigh median,
/// at least [`MIN_SCALE_PX`].
pub fn robust_scale(magnitudes: &[f64]) -> f64 {
    let mut m = magnitudes.to_vec();
    (median(&mut m) / RAYLEIGH_MEDIAN).max(MIN_SCALE_PX)
}

/// The median of `values` (sorted in place); 0 for none.
pub fn median(values: &mut [f64]) -> f64 {
    values.sort_by(f64::total_cmp);
    let n = values.len();
    match n {
        // No values: no spread either (callers judge at least a few).
        0 => 0.0,
        _ if n % 2 == 1 => values[n / 2],
        _ => 0.5 * (values[n / 2 - 1] + values[n / 2]),
    }
}

/// Pixel residuals (projection − registered) at `pose`; `None` if a point is behind the camera.
fn residuals(
    camera: &Camera,
    pose: &CameraPose,
    pairs: &[Registration],
) -> Option<Vec<Vector2<f64>>> {
    pairs
        .iter()
        .map(|(px, p_w)| Some(camera.project(pose.world_to_camera(p_w))? - px))
        .collect()
}

/// The rows `∂u/∂δ`, `∂v/∂δ` of the ideal pinhole `pin`'s pixel of the camera point `p` with
/// respect to a pose perturbation `δ = (δθ, δt)` in the camera frame, `p' = exp(δθ) p + δt`
/// (the Jacobian of eq. R1).
pub fn pixel_rows(pin: &Pinhole, p: &Vector3<f64>) -> [Vector6<f64>; 2] {
    let (z, x, y) = (p.z, p.x / p.z, p.y / p.z);
    // ∂(x, y)/∂p_c, then the pixel through fx, fy and the skew.
    let dx = Vector3::new(1.0 / z, 0.0, -x / z);
    let dy = Vector3::new(0.0, 1.0 / z, -y / z);
    let du = dx * pin.fx + dy * pin.skew;
    let dv = dy * pin.fy;
    // ∂p'/∂δθ = −[p]×, ∂p'/∂δt = I.
    let row = |d: Vector3<f64>| {
        let rot = p.cross(&d);
        Vector6::new(rot.x, rot.y, rot.z, d.x, d.y, d.z)
    };
    [row(du), row(dv)]
}

/// `pose` perturbed by `δ = (δθ, δt)` in the camera frame (see [`pixel_rows`]).
pub fn perturbed(pose: &CameraPose, delta: &Vector6<f64>) -> CameraPose {
    let rot = UnitQuaternion::from_scaled_axis(Vector3::new(delta[0], delta[1], delta[2]));
    let t = Vector3::new(delta[3], delta[4], delta[5]);
    let q_cw = rot * pose.q_cw;
    // R' (p_w − c') = exp(δθ) R (p_w − c) + δt  ⇒  c' = c − R'ᵀ δt.
    let c_w = pose.c_w - q_cw.inverse() * t;
    CameraPose { q_cw, c_w }
}

/// Eq. R1: the pose minimising `Σ ρ_H(|r_i|)` over `pairs` (registered pixel of the ideal
/// `camera`, model point), from `start`, with the Huber scale re-estimated from the residuals
/// at every step. Returns the pose and the residual magnitudes there [px], or `None` when a
/// point falls behind the camera, there are no pairs, or the normal equations are singular.
pub fn robust_fit(
    camera: &Camera,
    start: &CameraPose,
    pairs: &[Registration],
) -> Option<(CameraPose, Vec<f64>)> {
    if pairs.is_empty() {
        return None;
    }
    let pin = &camera.pinhole;
    let mut pose = *start;
    for _ in 0..ITERATIONS {
        let r = residuals(camera, &pose, pairs)?;
        let mags: Vec<f64> = r.iter().map(|v| v.norm()).collect();
        let scale = robust_scale(&mags);
        let (mut a, mut b) = (Matrix6::<f64>::zeros(), Vector6::<f64>::zeros());
        for ((_, p_w), r) in pairs.iter().zip(&r) {
            let [ju, jv] = pixel_rows(pin, &pose.world_to_camera(p_w));
            let e = r.norm();
            let w = if e <= HUBER * scale {
                1.0
            } else {
                HUBER * scale / e
            };
            a += (ju * ju.transpose() + jv * jv.transpose()) * w;
            b += (ju * r.x + jv * r.y) * w;
        }
        let delta = a.cholesky()?.solve(&(-b));
        if !delta.iter().all(|v| v.is_finite()) {
            return None;
        }
        pose = perturbed(&pose, &delta);
        if delta.norm() < 1e-10 {
            break;
        }
    }
    let mags = residuals(camera, &pose, pairs)?
        .iter()
        .map(|v| v.norm())
        .collect();
    Some((pose, mags))
}

/// Eq. R3: the information `H = Σ_i (J_uᵢ J_uᵢᵀ + J_vᵢ J_vᵢᵀ) / σ̂²` of a fit of `pose` to
/// `pairs`, over the pose perturbation of [`pixel_rows`]: `σ̂` the residuals' robust per-axis
/// scale there ([`robust_scale`]), so `H⁻¹` is the fit's covariance. `None` where a point is
/// behind the camera or there are no pairs.
pub fn fit_information(
    camera: &Camera,
    pose: &CameraPose,
    pairs: &[Registration],
) -> Option<Matrix6<f64>> {
    if pairs.is_empty() {
        return None;
    }
    let mags: Vec<f64> = residuals(camera, pose, pairs)?
        .iter()
        .map(|v| v.norm())
        .collect();
    let scale = robust_scale(&mags);
    let mut h = Matrix6::<f64>::zeros();
    for (_, p_w) in pairs {
        let [ju, jv] = pixel_rows(&camera.pinhole, &pose.world_to_camera(p_w));
        h += ju * ju.transpose() + jv * jv.transpose();
    }
    Some(h / (scale * scale))
}

/// The perturbation `δ = (δθ, δt)` that takes `from` to `to` ([`perturbed`]`(from, δ) = to`).
pub fn step_between(from: &CameraPose, to: &CameraPose) -> Vector6<f64> {
    let rot = (to.q_cw * from.q_cw.inverse()).scaled_axis();
    let t = to.q_cw * (from.c_w - to.c_w);
    Vector6::new(rot.x, rot.y, rot.z, t.x, t.y, t.z)
}

/// The 95 % quantile of χ² with 6 degrees of freedom ([`within_noise`]).
const CHI2_6_95: f64 = 12.592;

/// Eq. V1 (docs/notes/issue15-cold-start.md §5): whether a re-fit that took the pose `from` to
/// `to` over `pairs` moved it no more than noise would. Two fits to one frame's registrations
/// differ by `N(0, 2 H⁻¹)` (`H` their information at `to`, eq. R3), so for the step `δ` noise
/// alone gives `δᵀ H δ / 2 ~ χ²₆`; a step within its 95 % quantile is no evidence that the pose
/// is still moving. Fewer than six pairs (the pose's parameters) pin nothing down: `false`.
pub fn within_noise(
    camera: &Camera,
    from: &CameraPose,
    to: &CameraPose,
    pairs: &[Registration],
) -> bool {
    if pairs.len() < 6 {
        return false;
    }
    let Some(h) = fit_information(camera, to, pairs) else {
        return false;
    };
    let delta = step_between(from, to);
    (delta.transpose() * h * delta)[(0, 0)] / 2.0 <= CHI2_6_95
}

/// Which of `pairs` are outliers by `rule` (eq. R2), judged at their robust fit from
/// `predicted`. Too few pairs, or a fit that fails, judge none an outlier: the core's gate
/// still applies.
pub fn outliers(
    camera: &Camera,
    predicted: &CameraPose,
    pairs: &[Registration],
    rule: &OutlierRule,
) -> Vec<bool> {
    if pairs.len() < rule.min_features {
        return vec![false; pairs.len()];
    }
    let Some((_, mags)) = robust_fit(camera, predicted, pairs) else {
        return vec![false; pairs.len()];
    };
    x84(&mags, rule)
}

/// Eq. R2 on residual magnitudes `mags` [px]: which lie more than `rule.mads` median absolute
/// deviations beyond their median, and above `rule.floor_px`.
pub fn x84(mags: &[f64], rule: &OutlierRule) -> Vec<bool> {
    let med = median(&mut mags.to_vec());
    let mut deviations: Vec<f64> = mags.iter().map(|e| (e - med).abs()).collect();
    let mad = median(&mut deviations);
    let limit = (med + rule.mads * mad).max(rule.floor_px);
    mags.iter().map(|&e| e > limit).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use camera::{Pinhole, pinhole_camera};

    fn setup() -> (Camera, CameraPose, Vec<Registration>) {
        let camera = pinhole_camera(640, 480, Pinhole::new(600.0, 600.0, 320.0, 240.0)).unwrap();
        let pose = CameraPose::look_at(
            Vector3::new(0.05, -0.3, 0.1),
            Vector3::zeros(),
            Vector3::z(),
        )
        .unwrap();
        // Points on three faces of a 8 cm cube, with a deterministic sub-pixel jitter.
        let mut pairs = Vec::new();
        for i in 0..30 {
            let (a, b) = (
                (i % 5) as f64 * 0.02 - 0.04,
                (i / 5 % 5) as f64 * 0.02 - 0.04,
            );
            let p = match i % 3 {
                0 => Vector3::new(a, -0.04, b),
                1 => Vector3::new(-0.04, a, b),
                _ => Vector3::new(a, b, 0.04),
            };
            let px = camera.project(pose.world_to_camera(&p)).unwrap();
            let jitter = Vector2::new(((i * 7) % 11) as f64 - 5.0, ((i * 3) % 7) as f64 - 3.0);
            pairs.push((px + jitter * 0.06, p));
        }
        (camera, pose, pairs)
    }

    #[test]
    fn the_fit_finds_the_pose_from_a_wrong_start_despite_gross_errors() {
        let (camera, truth, mut pairs) = setup();
        pairs[4].0 += Vector2::new(12.0, -3.0);
        pairs[11].0 += Vector2::new(-6.0, 8.0);
        let start = CameraPose {
            q_cw: UnitQuaternion::from_scaled_axis(Vector3::new(0.01, -0.02, 0.015)) * truth.q_cw,
            c_w: truth.c_w + Vector3::new(0.004, -0.003, 0.002),
        };
        let (pose, mags) = robust_fit(&camera, &start, &pairs).unwrap();
        assert!((pose.c_w - truth.c_w).norm() < 1e-3, "{:?}", pose.c_w);
        assert!(pose.q_cw.angle_to(&truth.q_cw) < 2e-3);
        assert!(mags[4] > 10.0 && mags[11] > 8.0, "{} {}", mags[4], mags[11]);
    }

    #[test]
    fn x84_flags_the_gross_errors_only() {
        let (camera, truth, mut pairs) = setup();
        assert!(
            outliers(&camera, &truth, &pairs, &OutlierRule::default())
                .iter()
                .all(|o| !o),
            "jitter alone is no outlier"
        );
        pairs[4].0 += Vector2::new(12.0, -3.0);
        pairs[20].0 += Vector2::new(0.0, 4.0);
        let flags = outliers(&camera, &truth, &pairs, &OutlierRule::default());
        let flagged: Vec<usize> = (0..flags.len()).filter(|&i| flags[i]).collect();
        assert_eq!(flagged, vec![4, 20]);
        // Below the floor nothing is an outlier, however tight the rest.
        pairs[20].0 -= Vector2::new(0.0, 3.0);
        let flags = outliers(&camera, &truth, &pairs, &OutlierRule::default());
        assert!(!flags[20] && flags[4]);
        // Too few features: no judgement.
        assert!(
            outliers(&camera, &truth, &pairs[..5], &OutlierRule::default())
                .iter()
                .all(|o| !o)
        );
    }

    #[test]
    fn step_between_inverts_the_perturbation() {
        let (_, pose, _) = setup();
        let delta = Vector6::new(0.02, -0.01, 0.03, 0.005, -0.002, 0.01);
        let to = perturbed(&pose, &delta);
        let back = step_between(&pose, &to);
        assert!((back - delta).norm() < 1e-12, "{back:?}");
    }

    #[test]
    fn the_information_falls_with_the_residuals_square() {
        let (camera, truth, pairs) = setup();
        let (fitted, _) = robust_fit(&camera, &truth, &pairs).unwrap();
        let h = fit_information(&camera, &fitted, &pairs).unwrap();
        // Twice the jitter about the same points: a quarter of the information.
        let wider: Vec<Registration> = pairs
            .iter()
            .map(|(px, p)| {
                let exact = camera.project(fitted.world_to_camera(p)).unwrap();
                (exact + (px - exact) * 2.0, *p)
            })
            .collect();
        let h2 = fit_information(&camera, &fitted, &wider).unwrap();
        assert!((h2 * 4.0 - h).norm() < 1e-6 * h.norm());
        assert!(h.cholesky().is_some(), "three faces pin all six directions");
        assert!(fit_information(&camera, &fitted, &[]).is_none());
    }
}
