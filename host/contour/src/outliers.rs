//! Contour findings that no rigid pose explains (docs/VISION.md §9.5, eq. K6-K7): the contour
//! form of the registrations' outlier rule (`features::outliers`, eq. R1-R2). Each line is
//! searched on its own; where the background holds the object's grey levels a line can lock
//! onto a step that is not the contour, tens of pixels out, with a small variance. The
//! frame's lines are judged together: a robust rigid pose fit through all of them along their
//! normals, then the X84 rule on the residuals there. The same fit judges a pose by its lines
//! (docs/VISION.md §9.4, eq. K10-K11).

use nalgebra::{Matrix6, Vector2, Vector6};

use camera::{CameraPose, Pinhole};
use features::OutlierRule;
use features::outliers::{median, perturbed, pixel_rows, x84};

use crate::measure::ContourMeasurement;

/// Gauss-Newton iterations of the fit (it starts within a few pixels).
const ITERATIONS: usize = 8;

/// Huber's constant for 95 % efficiency at the normal, in units of the residual scale.
const HUBER: f64 = 1.345;

/// Median of `|e|` for a normal `e` over its σ (the half-normal's median).
const HALF_NORMAL_MEDIAN: f64 = 0.674_489_750_196_081_7;

/// A residual scale below this is numerical noise [px].
const MIN_SCALE_PX: f64 = 0.05;

/// Fewest lines for a judgement: each constrains one of the pose's six degrees of freedom.
pub const MIN_LINES: usize = 12;

/// The scale of normally distributed residuals from their median magnitude (the half-normal's
/// median is 0.674 σ): robust to the few lines that locked elsewhere.
pub fn residual_scale(residuals: &[f64]) -> f64 {
    let mut mags: Vec<f64> = residuals.iter().map(|v| v.abs()).collect();
    median(&mut mags) / HALF_NORMAL_MEDIAN
}

/// Signed residuals [px] along the normals at `pose`: the model point's projection against
/// the contour found. `None` if a point is behind the camera.
fn residuals(pin: &Pinhole, pose: &CameraPose, lines: &[ContourMeasurement]) -> Option<Vec<f64>> {
    lines.iter().map(|m| m.residual_px(pose, pin)).collect()
}

/// Eq. K6: the pose minimising `Σ ρ_H(r_i)` over the lines' residuals along their normals,
/// `r_i = n_iᵀ(π(m_i) − p_i)`, from `start`, the Huber scale re-estimated at every step.
/// Returns the pose and the residuals there [px]; `None` when a point falls behind the camera
/// or the step is not finite. Directions the lines do not constrain are damped, not refused.
pub fn robust_fit(
    pin: &Pinhole,
    start: &CameraPose,
    lines: &[ContourMeasurement],
) -> Option<(CameraPose, Vec<f64>)> {
    let mut pose = *start;
    for _ in 0..ITERATIONS {
        let r = residuals(pin, &pose, lines)?;
        let scale = residual_scale(&r).max(MIN_SCALE_PX);
        let (mut a, mut b) = (Matrix6::<f64>::zeros(), Vector6::<f64>::zeros());
        for (m, &r) in lines.iter().zip(&r) {
            let [ju, jv] = pixel_rows(pin, &pose.world_to_camera(&m.sample.m_w));
            let n: Vector2<f64> = m.sample.normal;
            let j = ju * n.x + jv * n.y;
            let w = if r.abs() <= HUBER * scale {
                1.0
            } else {
                HUBER * scale / r.abs()
            };
            a += j * j.transpose() * w;
            b += j * r * w;
        }
        // Directions the contour does not see (a disc's roll, rotation against translation
        // for a flat silhouette) stay where they are: a little damping, relative to the
        // information in the others.
        let damping = 1e-6 * a.trace().max(f64::MIN_POSITIVE);
        a += Matrix6::identity() * damping;
        let delta = a.cholesky()?.solve(&(-b));
        if !delta.iter().all(|v| v.is_finite()) {
            return None;
        }
        pose = perturbed(&pose, &delta);
        if delta.norm() < 1e-10 {
            break;
        }
    }
    Some((pose, residuals(pin, &pose, lines)?))
}

/// The least scale of the lines' residuals that eq. K10 takes [px]: about a line's σ
/// (docs/VISION.md §9.3). A fit closer than that says more of the lines' agreement than of
/// the pose.
const SPREAD_MIN_SCALE_PX: f64 = 1.0;

/// Eq. K10: how well `lines` alone pin the pose at `pose`: the largest standard deviations of
/// the camera's position [m] and orientation [rad] under their information
/// `H = Σ j_i j_iᵀ / s²` (`j_i` a line's residual row, `s` the residuals' robust scale, at
/// least [`SPREAD_MIN_SCALE_PX`]). An outline that does not see a direction (a disc's roll,
/// a wall's depth) leaves it loose. `None` with fewer than [`MIN_LINES`] lines, a point
/// behind the camera, or a direction the lines do not see at all.
pub fn pose_spread(
    pin: &Pinhole,
    pose: &CameraPose,
    lines: &[ContourMeasurement],
) -> Option<[f64; 2]> {
    if lines.len() < MIN_LINES {
        return None;
    }
    let r = residuals(pin, pose, lines)?;
    let scale = residual_scale(&r).max(SPREAD_MIN_SCALE_PX);
    let mut h = Matrix6::<f64>::zeros();
    for m in lines {
        let [ju, jv] = pixel_rows(pin, &pose.world_to_camera(&m.sample.m_w));
        let n: Vector2<f64> = m.sample.normal;
        let j = ju * n.x + jv * n.y;
        h += j * j.transpose();
    }
    let cov = (h / (scale * scale)).try_inverse()?;
    // δ = (δθ, δt) in the camera frame: the camera centre moves by −Rᵀ δt, the same spread.
    let largest = |k: usize| {
        let block = cov.fixed_view::<3, 3>(k, k).into_owned();
        let block = (block + block.transpose()) / 2.0;
        block.symmetric_eigenvalues().max().max(0.0).sqrt()
    };
    let spread = [largest(3), largest(0)];
    spread.iter().all(|v| v.is_finite()).then_some(spread)
}

/// Huber's `ρ` of a residual `u` in units of the scale: `u²/2` within [`HUBER`], linear
/// beyond (a line locked elsewhere weighs as an outlier does in eq. K6's fit).
fn huber_rho(u: f64) -> f64 {
    let a = u.abs();
    if a <= HUBER {
        0.5 * a * a
    } else {
        HUBER * a - 0.5 * HUBER * HUBER
    }
}

/// Eq. K11: how much worse `pose` explains `lines` than the pose they fit alone (eq. K6's, from
/// `pose`): `2 Σ [ρ_H(r_i(pose)/s) − ρ_H(r_i(fit)/s)]`, with `s` the residuals' robust scale at
/// the fit, at least [`SPREAD_MIN_SCALE_PX`]. Where the lines hold and `pose` is within their
/// spread (eq. K10) it is distributed as χ² with 6 degrees of freedom (the likelihood ratio of
/// the two poses); a pose the lines fit within a pixel but that sits many of their σ along a
/// direction they do see (a prediction the lines pull back only by the filter's gain)
/// exceeds it. Directions the lines do not see change neither sum. `None` with fewer than
/// [`MIN_LINES`] lines or a fit that fails.
pub fn fit_excess(pin: &Pinhole, pose: &CameraPose, lines: &[ContourMeasurement]) -> Option<f64> {
    if lines.len() < MIN_LINES {
        return None;
    }
    let at_pose = residuals(pin, pose, lines)?;
    let (_, at_fit) = robust_fit(pin, pose, lines)?;
    let scale = residual_scale(&at_fit).max(SPREAD_MIN_SCALE_PX);
    let sum = |r: &[f64]| r.iter().map(|v| huber_rho(v / scale)).sum::<f64>();
    let excess = (2.0 * (sum(&at_pose) - sum(&at_fit))).max(0.0);
    excess.is_finite().then_some(excess)
}

/// Eq. K7: which of `lines` are outliers by `rule`, judged at their robust fit from
/// `predicted`: a residual beyond the median by more than `rule.mads` median absolute
/// deviations, and above `rule.floor_px`. Fewer than [`MIN_LINES`] lines, or a fit that fails,
/// judge none an outlier: the core's gate still applies.
pub fn outliers(
    pin: &Pinhole,
    predicted: &CameraPose,
    lines: &[ContourMeasurement],
    rule: &OutlierRule,
) -> Vec<bool> {
    if lines.len() < MIN_LINES.max(rule.min_features) {
        return vec![false; lines.len()];
    }
    let Some((_, r)) = robust_fit(pin, predicted, lines) else {
        return vec![false; lines.len()];
    };
    let mags: Vec<f64> = r.iter().map(|v| v.abs()).collect();
    x84(&mags, rule)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::line::LineResult;
    use crate::silhouette::{SampleConfig, sample, tests::disc_frame};

    /// The disc's contour found 3 px to the right (the object moved), with a few lines locked
    /// 20 px out: the fit explains the shift, and only the locked lines are outliers.
    #[test]
    fn lines_locked_on_another_step_are_outliers_the_shifted_rest_are_not() {
        let frame = disc_frame((320, 240), (160.0, 120.0), 50.0);
        let samples = sample(&frame, &SampleConfig::default());
        let wrong = [3usize, 11, 20, 31];
        let lines: Vec<ContourMeasurement> = samples
            .iter()
            .enumerate()
            .map(|(i, s)| ContourMeasurement {
                sample: *s,
                line: LineResult {
                    offset_px: if wrong.contains(&i) {
                        20.0
                    } else {
                        3.0 * s.normal.x
                    },
                    sigma_px: 1.0,
                },
            })
            .collect();
        let pin = frame.view.pinhole;
        let flags = outliers(&pin, &frame.view.pose, &lines, &OutlierRule::default());
        for (i, f) in flags.iter().enumerate() {
            assert_eq!(*f, wrong.contains(&i), "line {i}");
        }
        // The fit moved the disc: the inliers' residuals vanish there.
        let (_, r) = robust_fit(&pin, &frame.view.pose, &lines).unwrap();
        for (i, r) in r.iter().enumerate().filter(|(i, _)| !wrong.contains(i)) {
            assert!(r.abs() < 0.05, "line {i}: {r}");
        }
        // Too few lines: no judgement.
        assert!(
            outliers(&pin, &frame.view.pose, &lines[..8], &OutlierRule::default())
                .iter()
                .all(|f| !f)
        );
    }

    /// Eq. K11 on the disc's lines with 0.7 px of noise: at the pose they were found from,
    /// within χ²₆'s bulk; where the disc moved 3 px but the pose did not, far beyond it.
    #[test]
    fn the_fit_excess_is_chi2_at_the_pose_the_lines_hold_and_large_off_it() {
        let frame = disc_frame((320, 240), (160.0, 120.0), 50.0);
        let samples = sample(&frame, &SampleConfig::default());
        let lines = |shift: f64| -> Vec<ContourMeasurement> {
            samples
                .iter()
                .enumerate()
                .map(|(i, s)| ContourMeasurement {
                    sample: *s,
                    line: LineResult {
                        offset_px: shift * s.normal.x + 0.7 * (i as f64 * 2.3).sin(),
                        sigma_px: 1.0,
                    },
                })
                .collect()
        };
        let pin = frame.view.pinhole;
        let held = fit_excess(&pin, &frame.view.pose, &lines(0.0)).unwrap();
        assert!(held < 12.6, "{held}");
        let moved = fit_excess(&pin, &frame.view.pose, &lines(3.0)).unwrap();
        assert!(moved > 100.0, "{moved}");
        assert!(fit_excess(&pin, &frame.view.pose, &lines(0.0)[..8]).is_none());
    }
}
