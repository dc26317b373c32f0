//! Choosing among verified poses (docs/notes/issue15-cold-start.md §5, eqs. P2 and P3).
//!
//! An attempt verifies up to four poses: RANSAC's best, its mirror about the inliers' plane
//! (eq. P1) and RANSAC's runners-up. Where one face of a cube is seen nearly face on, its two
//! tilts can both pass the tracked rule with nearly equal rms, each fitted to registrations of
//! its own. Two independent rms figures of ~40 features differ by ±11 % from noise alone, so
//! they cannot choose; the evidence must be taken where the two hypotheses differ:
//!
//! - eq. P2 ([`vision::assess::contrast`]): the live image where the two renderings
//!   disagree. A wrong tilt shows the sliver of a side face that the image does not (and hides
//!   one it does).
//! - eq. P3 ([`common_evidence`]): both poses re-fitted to the same registrations (those of
//!   both verifications), so the noise is common to both and only the misfit of the wrong
//!   pose remains.
//!
//! A pose is chosen when it is favoured over every other plausible pose that is not the same
//! minimum; otherwise the attempt is refused as ambiguous. A refusal costs a frame; a wrong
//! pose would cost the user the tracking.

use std::cmp::Ordering;

use image::GrayImage;
use serde::Serialize;

use crate::ransac::mirrored_pose;
use camera::{Camera, CameraPose};
use features::outliers::{Registration, robust_fit, robust_scale};
use nalgebra::Vector3;
use vision::{Contrast, TrackedRule, VisionError};
use vision::{Verified, Vision};

/// Two poses closer than this [m] and [`SAME_MINIMUM_RAD`] are one minimum: within what one
/// frame's registrations pin a one-face view down to (and the 1 cm, 2° a found pose is asked
/// to agree to).
const SAME_MINIMUM_M: f64 = 0.01;

/// See [`SAME_MINIMUM_M`] [rad].
const SAME_MINIMUM_RAD: f64 = 2.0 * std::f64::consts::PI / 180.0;

/// Eq. P2 decides when the two correlations differ by this much: half of what tells a right
/// pose from a wrong one over a whole model (about 0.6 against 0, the reasoning of
/// [`TrackedRule`]'s correlation bound).
const CONTRAST_MARGIN: f64 = 0.3;

/// Eq. P3 decides at a likelihood ratio of 100 to 1.
const LOG_ODDS: f64 = 4.605_170_185_988_091;

/// Registrations of one model point by both verifications (closer than this [m]) are one.
const SAME_POINT_M: f64 = 1e-3;

/// Residuals beyond this many scales count as outliers, at this cost (eq. P3).
const TRUNCATE_SCALES: f64 = 3.0;

/// Two poses re-fitted to the registrations of both (eq. P3).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Evidence {
    /// Registrations shared: both verifications' together, a point registered by both once.
    pub registrations: usize,
    /// The first pose re-fitted to them.
    #[serde(skip)]
    pub first: CameraPose,
    /// The second pose re-fitted to them.
    #[serde(skip)]
    pub second: CameraPose,
    /// Residual scale σ of the better fit [px].
    pub scale_px: f64,
    /// `ln L(first) − ln L(second)`: positive favours the first.
    pub log_odds: f64,
}

/// Eq. P3: the registrations of both verifications, `a`'s and `b`'s (a model point registered
/// by both once, at the mean of its two pixels), and each pose re-fitted to them from where it
/// is (eq. R1, docs/notes/issue14-registration.md). With `e_i` the residual magnitudes at a
/// re-fitted pose, σ the robust scale of the better fit, and `c = 3σ`,
///
/// `ln L = −Σ min(e_i², c²) / (2σ²)`,
///
/// Gaussian residuals with outliers at a flat cost. `None` when a fit fails.
pub fn common_evidence(camera: &Camera, a: &Verified, b: &Verified) -> Option<Evidence> {
    let shared = shared_registrations(&[a, b]);
    let (first, ea) = robust_fit(camera, &a.pose, &shared)?;
    let (second, eb) = robust_fit(camera, &b.pose, &shared)?;
    let sigma = robust_scale(&ea).min(robust_scale(&eb));
    let c2 = (TRUNCATE_SCALES * sigma).powi(2);
    let cost = |e: &[f64]| e.iter().map(|x| (x * x).min(c2)).sum::<f64>() / (2.0 * sigma * sigma);
    Some(Evidence {
        registrations: shared.len(),
        first,
        second,
        scale_px: sigma,
        log_odds: cost(&eb) - cost(&ea),
    })
}

/// The registrations of all of `verified` together, a model point registered by several of
/// them once, at the mean of their pixels.
fn shared_registrations(verified: &[&Verified]) -> Vec<Registration> {
    let mut shared: Vec<(Registration, f64)> = Vec::new();
    for (px, p) in verified.iter().flat_map(|v| &v.registered) {
        match shared
            .iter_mut()
            .find(|((_, q), _)| (q - p).norm() < SAME_POINT_M)
        {
            Some(((sum, _), n)) => {
                *sum += px;
                *n += 1.0;
            }
            None => shared.push(((*px, *p), 1.0)),
        }
    }
    shared
        .into_iter()
        .map(|((sum, p), n)| (sum / n, p))
        .collect()
}

/// Whether two poses are one minimum.
fn same_minimum(a: &CameraPose, b: &CameraPose) -> bool {
    (a.c_w - b.c_w).norm() < SAME_MINIMUM_M && a.q_cw.angle_to(&b.q_cw) < SAME_MINIMUM_RAD
}

/// Eq. P3's verdict (`Less`: the first), by the log-odds; none where the two re-fits end in
/// one minimum (the shared registrations know one pose there, see [`Comparison::one_minimum`]).
fn evidence_verdict(e: &Evidence) -> Option<Ordering> {
    if e.one_minimum() {
        None
    } else if e.log_odds >= LOG_ODDS {
        Some(Ordering::Less)
    } else if e.log_odds <= -LOG_ODDS {
        Some(Ordering::Greater)
    } else {
        None
    }
}

impl Evidence {
    /// Whether both re-fits ended in one minimum.
    pub fn one_minimum(&self) -> bool {
        same_minimum(&self.first, &self.second)
    }
}

/// Eq. P2's verdict (`Less`: the first).
fn contrast_verdict(c: &Contrast) -> Option<Ordering> {
    let (ca, cb) = (c.first?, c.second?);
    ((ca - cb).abs() >= CONTRAST_MARGIN).then(|| cb.total_cmp(&ca))
}

/// The two verdicts together: one decides unless the other decides the other way.
fn verdict(p2: Option<Ordering>, p3: Option<Ordering>) -> Option<Ordering> {
    match (p2, p3) {
        (Some(x), Some(y)) => (x == y).then_some(x),
        (x, None) | (None, x) => x,
    }
}

/// What [`choose`] chose among the verified poses.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Choice {
    /// This pose: the evidence favours it over every other plausible one.
    One(usize),
    /// Plausible poses the evidence cannot tell apart; the lowest-rms one, to be refused.
    Ambiguous(usize),
}

/// How the live image judges two verified poses against each other.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Comparison {
    /// Eq. P2: the first pose's rendering (`first`) and the second's against the image.
    pub contrast: Contrast,
    /// Eq. P3: both re-fitted to the registrations of both (`None` when a fit failed).
    pub evidence: Option<Evidence>,
    /// Which the two favour together (`Less`: the first), or `None` when they cannot tell or
    /// disagree.
    #[serde(skip)]
    pub verdict: Option<Ordering>,
}

impl Comparison {
    /// Whether the two are one pose after all: re-fitted to the registrations of both, they
    /// end in one minimum. Where one face is seen nearly face on, verifications walk a
    /// centimetre or two apart along the turn it pins down poorly, and are no rivals.
    pub fn one_minimum(&self) -> bool {
        self.evidence.is_some_and(|e| e.one_minimum())
    }

    /// The same comparison with the two poses swapped.
    fn swapped(&self) -> Self {
        Self {
            contrast: Contrast {
                first: self.contrast.second,
                second: self.contrast.first,
                ..self.contrast
            },
            evidence: self.evidence.map(|e| Evidence {
                first: e.second,
                second: e.first,
                log_odds: -e.log_odds,
                ..e
            }),
            verdict: self.verdict.map(Ordering::reverse),
        }
    }
}

/// Compares the verified poses `a` and `b` in the raw live image `raw` (eqs. P2 and P3).
pub fn compare(
    vision: &mut Vision,
    raw: &GrayImage,
    a: &Verified,
    b: &Verified,
) -> Result<Comparison, VisionError> {
    let contrast = vision.contrast(raw, &a.pose, &b.pose)?;
    let evidence = common_evidence(vision.ideal_camera(), a, b);
    let p3 = evidence.as_ref().and_then(evidence_verdict);
    Ok(Comparison {
        contrast,
        evidence,
        verdict: if evidence.is_some_and(|e| e.one_minimum()) {
            None
        } else {
            verdict(contrast_verdict(&contrast), p3)
        },
    })
}

/// Each compared pair, as `[i][j]` with pose `i` first.
pub type Comparisons = Vec<Vec<Option<Comparison>>>;

/// Chooses among the `verified` poses. Which are plausible is asked of `rule` with tracking's
/// feature count: a pose tracking would go on from. (Asking the cold start's stricter count
/// would take the wrong tilt whenever it happens to register more features than the right
/// one, which registers too few.) Of those, the one the evidence favours over every other
/// plausible pose that is not the same minimum ([`compare`]); the lowest-rms one where the
/// favoured poses are one minimum. The chosen one is then compared with its own mirror (the
/// mirror check, returned); where that does not favour it, the choice is ambiguous.
pub fn choose(
    vision: &mut Vision,
    raw: &GrayImage,
    verified: &[Verified],
    rule: &TrackedRule,
) -> Result<(Choice, Comparisons, Option<Comparison>), VisionError> {
    let n = verified.len();
    let mut compared: Comparisons = vec![vec![None; n]; n];
    let plausible_rule = TrackedRule {
        min_features: TrackedRule::default().min_features,
        ..*rule
    };
    let rms = |i: usize| verified[i].assessment.rms_px.unwrap_or(f64::INFINITY);
    let mut by_rms: Vec<usize> = (0..n).collect();
    by_rms.sort_by(|&i, &j| rms(i).total_cmp(&rms(j)));
    let plausible: Vec<usize> = by_rms
        .iter()
        .copied()
        .filter(|&i| plausible_rule.holds(&verified[i].assessment))
        .collect();
    let Some(&lowest) = plausible.first().or(by_rms.first()) else {
        return Ok((Choice::Ambiguous(0), compared, None));
    };
    let mut wins = vec![true; n];
    for (x, &i) in plausible.iter().enumerate() {
        for &j in &plausible[x + 1..] {
            if same_minimum(&verified[i].pose, &verified[j].pose) {
                continue;
            }
            let c = compare(vision, raw, &verified[i], &verified[j])?;
            match c.verdict {
                _ if c.one_minimum() => {}
                Some(Ordering::Less) => wins[j] = false,
                Some(_) => wins[i] = false,
                None => (wins[i], wins[j]) = (false, false),
            }
            compared[i][j] = Some(c);
            compared[j][i] = Some(c.swapped());
        }
    }
    let Some(&winner) = plausible.iter().find(|&&i| wins[i]) else {
        let choice = if plausible.is_empty() {
            Choice::One(lowest)
        } else {
            Choice::Ambiguous(lowest)
        };
        return Ok((choice, compared, None));
    };
    // The mirror check: the winner against its own mirror on its own registrations. The mirror
    // verified above may have walked back into the winner's basin, leaving the other tilt
    // untried although the registrations would fit it.
    let check = match mirror_of(&verified[winner]) {
        Some(m) if !same_minimum(&m.pose, &verified[winner].pose) => {
            Some(compare(vision, raw, &verified[winner], &m)?)
        }
        _ => None,
    };
    let holds = check
        .as_ref()
        .is_none_or(|c| c.one_minimum() || c.verdict == Some(Ordering::Less));
    let choice = if holds {
        Choice::One(winner)
    } else {
        Choice::Ambiguous(winner)
    };
    Ok((choice, compared, check))
}

/// What a tilt check found (docs/notes/issue15-cold-start.md §5.2): the evidence, and the
/// other tilt where that is the pose.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct TiltCheck {
    /// The tracked pose against its mirror (eqs. P2, P3); `None` where no comparison was
    /// made (the tracked pose failed the rule, or has no mirror that is another minimum).
    pub tracked_vs_mirror: Option<Comparison>,
    /// The verified mirror against the tracked pose, where the first comparison favoured the
    /// mirror and the mirror verified as another minimum.
    pub flipped_vs_tracked: Option<Comparison>,
    /// The verified mirror, where the image favoured it both times: the pose to flip to.
    #[serde(skip)]
    pub flip: Option<CameraPose>,
}

impl TiltCheck {
    /// Whether the image decisively favoured the mirror over the tracked pose: evidence that
    /// the tracked pose is on the wrong branch, whether or not the flip was confirmed.
    pub fn disfavours_tracked(&self) -> bool {
        self.tracked_vs_mirror
            .is_some_and(|c| !c.one_minimum() && c.verdict == Some(Ordering::Greater))
    }
}

/// The tilt check of a tracked pose (docs/notes/issue15-cold-start.md §5.2): `pose` verified
/// in the raw frame `raw`, against its own mirror (eqs. P1–P3). Where the image favours the
/// mirror decisively, the mirror is verified in its turn; it is the flip when it passes
/// `rule` (the cold start's: a flip re-initialises the core as a found pose does) and the
/// image favours it over the tracked pose again. Whether a flip is applied is tracking's
/// decision (the tracker's `tilt.rs`: it must hold).
///
/// Tracking follows a face that turns through face on along either branch of the two-fold
/// ambiguity, and can leave on the wrong one: on the cube video, 150 mm and 18° off for a
/// second (frames 779–796) while the rule held.
pub fn check_tilt(
    vision: &mut Vision,
    raw: &GrayImage,
    pose: &CameraPose,
    rule: &TrackedRule,
) -> Result<TiltCheck, VisionError> {
    let mut check = TiltCheck {
        tracked_vs_mirror: None,
        flipped_vs_tracked: None,
        flip: None,
    };
    let plausible_rule = TrackedRule {
        min_features: TrackedRule::default().min_features,
        ..*rule
    };
    let (tracked, _) = super::converged(vision, raw, pose, false)?;
    if !plausible_rule.holds(&tracked.assessment) {
        return Ok(check);
    }
    let Some(mirror) = mirror_of(&tracked) else {
        return Ok(check);
    };
    if same_minimum(&mirror.pose, &tracked.pose) {
        return Ok(check);
    }
    check.tracked_vs_mirror = Some(compare(vision, raw, &tracked, &mirror)?);
    if !check.disfavours_tracked() {
        return Ok(check);
    }
    let (flipped, _) = super::converged(vision, raw, &mirror.pose, false)?;
    if !rule.holds(&flipped.assessment) || same_minimum(&flipped.pose, &tracked.pose) {
        return Ok(check);
    }
    let second = compare(vision, raw, &flipped, &tracked)?;
    check.flipped_vs_tracked = Some(second);
    check.flip =
        (!second.one_minimum() && second.verdict == Some(Ordering::Less)).then_some(flipped.pose);
    Ok(check)
}

/// `pose` mirrored about the plane of the model points `x_w` (eq. P1,
/// [`mirrored_pose`]); `None` where the plane faces the camera.
pub fn mirrored(pose: &CameraPose, x_w: &[Vector3<f64>]) -> Option<CameraPose> {
    let (q_cw, t) = mirrored_pose(&pose.q_cw, &pose.translation(), x_w)?;
    Some(CameraPose::from_extrinsics(q_cw, &t))
}

/// `v`'s pose mirrored about the plane of its registrations' model points (eq. P1), as a
/// hypothesis with the same registrations; `None` where the plane faces the camera.
fn mirror_of(v: &Verified) -> Option<Verified> {
    let points: Vec<Vector3<f64>> = v.registered.iter().map(|r| r.1).collect();
    Some(Verified {
        pose: mirrored(&v.pose, &points)?,
        assessment: v.assessment,
        result: None,
        registered: v.registered.clone(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use camera::{Pinhole, pinhole_camera};
    use nalgebra::{UnitQuaternion, Vector2};
    use vision::Assessment;

    fn camera() -> Camera {
        pinhole_camera(
            640,
            480,
            Pinhole {
                fx: 600.0,
                fy: 600.0,
                cx: 320.0,
                cy: 240.0,
                skew: 0.0,
            },
        )
        .unwrap()
    }

    /// A square of `side` metres on the plane z = 0, seen from `distance` with the plane
    /// tilted by `tilt_deg` about the camera's x axis; registrations are its grid's exact
    /// projections plus a deterministic ±0.3 px noise. Returns the true pose and its mirror
    /// (eq. P1), each as a verification of the same registrations.
    fn plane_and_mirror(side: f64, distance: f64, tilt_deg: f64) -> (Verified, Verified) {
        let cam = camera();
        let q_cw = UnitQuaternion::from_euler_angles(tilt_deg.to_radians(), 0.0, 0.0);
        let c_w = -(q_cw.inverse() * Vector3::new(0.0, 0.0, distance));
        let truth = CameraPose { q_cw, c_w };
        let mut registered = Vec::new();
        let mut k = 0u32;
        for i in 0..8 {
            for j in 0..8 {
                let p = Vector3::new(
                    side * (f64::from(i) / 7.0 - 0.5),
                    side * (f64::from(j) / 7.0 - 0.5),
                    0.0,
                );
                let px = cam.project(truth.world_to_camera(&p)).unwrap();
                k = k.wrapping_mul(1_103_515_245).wrapping_add(12_345);
                let n = |s: u32| (f64::from((k >> s) & 0xff) / 255.0 - 0.5) * 0.6;
                registered.push((px + Vector2::new(n(8), n(16)), p));
            }
        }
        let points: Vec<Vector3<f64>> = registered.iter().map(|r| r.1).collect();
        let mirror = mirrored(&truth, &points).unwrap();
        let verified = |pose: CameraPose| Verified {
            pose,
            assessment: Assessment::default(),
            result: None,
            registered: registered.clone(),
        };
        (verified(truth), verified(mirror))
    }

    #[test]
    fn eq_p3_favours_the_true_tilt_where_the_perspective_shows_it_and_cannot_tell_where_it_does_not()
     {
        let cam = camera();
        // A 20 cm face at 40 cm, tilted 12°, and a 10 cm face at 60 cm (the cube video's),
        // tilted 10°: the perspective leaves the registrations no second minimum, and the
        // mirror's re-fit ends at the true pose: one pose, no rivals.
        for (side, distance, tilt) in [(0.2, 0.4, 12.0), (0.1, 0.6, 10.0)] {
            let (truth, mirror) = plane_and_mirror(side, distance, tilt);
            let e = common_evidence(&cam, &truth, &mirror).unwrap();
            assert!(e.one_minimum(), "{e:?}");
            assert!(same_minimum(&e.first, &truth.pose), "{e:?}");
            assert_eq!(evidence_verdict(&e), None);
        }
        // A 4 cm face at 1.5 m: two minima, which explain the registrations alike within
        // the noise, and the evidence does not choose.
        let (truth, mirror) = plane_and_mirror(0.04, 1.5, 10.0);
        let e = common_evidence(&cam, &truth, &mirror).unwrap();
        assert!(!e.one_minimum(), "{e:?}");
        assert!(e.log_odds.abs() < LOG_ODDS, "{e:?}");
        assert_eq!(evidence_verdict(&e), None, "{e:?}");
        // Where the tilt shows in the perspective but both minima survive (20 cm at 1 m,
        // 25°), the true one is favoured, and swapped, the verdict swaps.
        let (truth, mirror) = plane_and_mirror(0.2, 1.0, 25.0);
        let e = common_evidence(&cam, &truth, &mirror).unwrap();
        assert!(!e.one_minimum(), "{e:?}");
        assert_eq!(evidence_verdict(&e), Some(Ordering::Less), "{e:?}");
        let e = common_evidence(&cam, &mirror, &truth).unwrap();
        assert_eq!(evidence_verdict(&e), Some(Ordering::Greater), "{e:?}");
    }

    #[test]
    fn the_verdicts_combine_one_decides_unless_the_other_says_otherwise() {
        use Ordering::{Greater, Less};
        assert_eq!(verdict(Some(Less), None), Some(Less));
        assert_eq!(verdict(None, Some(Greater)), Some(Greater));
        assert_eq!(verdict(Some(Less), Some(Less)), Some(Less));
        assert_eq!(verdict(Some(Less), Some(Greater)), None);
        assert_eq!(verdict(None, None), None);
        let c = |a: Option<f64>, b: Option<f64>| Contrast {
            pixels: 1000,
            first: a,
            second: b,
        };
        assert_eq!(contrast_verdict(&c(Some(0.6), Some(0.1))), Some(Less));
        assert_eq!(contrast_verdict(&c(Some(0.05), Some(0.7))), Some(Greater));
        // Within the margin, or without a figure for one of the two: no verdict.
        assert_eq!(contrast_verdict(&c(Some(0.4), Some(0.2))), None);
        assert_eq!(contrast_verdict(&c(None, Some(0.7))), None);
    }

    #[test]
    fn shared_registrations_count_a_point_registered_twice_once_at_its_mean_pixel() {
        let p = Vector3::new(0.01, 0.02, 0.0);
        let q = Vector3::new(0.05, 0.0, 0.0);
        let v = |regs: Vec<Registration>| Verified {
            pose: CameraPose {
                q_cw: UnitQuaternion::identity(),
                c_w: Vector3::zeros(),
            },
            assessment: Assessment::default(),
            result: None,
            registered: regs,
        };
        let a = v(vec![(Vector2::new(10.0, 20.0), p)]);
        let b = v(vec![
            (Vector2::new(12.0, 20.0), p + Vector3::new(0.0002, 0.0, 0.0)),
            (Vector2::new(50.0, 60.0), q),
        ]);
        let shared = shared_registrations(&[&a, &b]);
        assert_eq!(shared.len(), 2);
        assert_eq!(shared[0].0, Vector2::new(11.0, 20.0));
        assert_eq!(shared[1], (Vector2::new(50.0, 60.0), q));
    }
}
