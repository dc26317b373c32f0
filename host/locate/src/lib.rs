#![deny(missing_docs)]
//! Finding the model in an image with no pose given (the cold start; the method and its
//! equations are in docs/notes/issue15-cold-start.md):
//!
//! 1. [`database`]: the textured model rendered offline from viewpoints around it, with ORB
//!    keypoints ([`orb`]) and their model points, cached on disk;
//! 2. ORB keypoints of the live (undistorted) image, [`matching`] against the database;
//! 3. the pose by P3P ([`p3p`]) inside RANSAC ([`ransac`]), refined on the inliers;
//! 4. verification before use ([`vision::Vision::verify`]): the model rendered
//!    at the pose, its features registered with the photometric KLT, the pose re-fitted, and
//!    the tracked rule ([`vision::TrackedRule`]) applied. Only a verified pose is used;
//! 5. where several poses verify (the two tilts of a plane, RANSAC's runners-up), the one the
//!    image's evidence favours ([`choice`]), or none when it cannot tell.
//!
//! Errors: a frame's analysis fails with [`VisionError`]; the database with
//! [`database::DatabaseError`].

pub mod choice;
pub mod database;
pub mod index;
pub mod matching;
pub mod orb;
pub mod p3p;
pub mod ransac;

use std::time::Instant;

use image::GrayImage;
use nalgebra::{Vector2, Vector3};
use serde::Serialize;

use camera::CameraPose;
use choice::{Choice, choose};
pub use choice::{Comparison, Evidence, compare};
use database::Database;
use features::outliers::within_noise;
use index::Index;
use matching::{MatchConfig, match_descriptors};
use orb::{Descriptor, Orb, OrbConfig};
use ransac::{RansacConfig, RansacPose, ransac_search};
use vision::VisionError;
use vision::{Assessment, TrackedRule};
use vision::{FrameResult, Verified, Vision, VisionOptions};

/// Two candidate poses closer than this in rotation are one [rad].
const SAME_POSE_RAD: f64 = 0.5 * std::f64::consts::PI / 180.0;

/// Settings of an attempt.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LocateConfig {
    /// Keypoints of the live image.
    pub orb: OrbConfig,
    /// Matching.
    pub matching: MatchConfig,
    /// Pose estimation.
    pub ransac: RansacConfig,
    /// Acceptance of the verified pose.
    pub rule: TrackedRule,
}

impl Default for LocateConfig {
    fn default() -> Self {
        Self {
            // A global budget, ranked by corner strength: a busy background's sharp corners
            // take it before a small or blurred object's (issue15-cold-start.md §1).
            orb: OrbConfig {
                max_keypoints: 3000,
                ..OrbConfig::default()
            },
            matching: MatchConfig::default(),
            ransac: RansacConfig::default(),
            // Stricter on the count than tracking's rule: a pose found from nothing must be
            // confirmed by many features (a wrong pose must be rare enough never to be seen).
            rule: TrackedRule {
                min_features: 20,
                ..TrackedRule::default()
            },
        }
    }
}

/// The image analysis an attempt's [`Vision`] runs with: an object found from nothing is
/// verified as vision-only tracking would go on with it, the small-object cells giving a small
/// object enough features.
pub fn vision_options() -> VisionOptions {
    let mut options = VisionOptions::default();
    options.map.small_object_cells = true;
    options
}

/// Time per stage of an attempt [s].
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct AttemptTimes {
    /// Undistortion, detection and description of the live image.
    pub detect: f64,
    /// Matching against the database.
    pub matching: f64,
    /// RANSAC and refinement.
    pub ransac: f64,
    /// Verification (renderings, registration, judgement), the choice excluded.
    pub verify: f64,
    /// The choice among the verified poses and the mirror check (eqs. P2, P3).
    pub choose: f64,
}

/// What an attempt found.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Attempt {
    /// Keypoints in the live image.
    pub keypoints: usize,
    /// Matches that passed the ratio and mutual tests.
    pub matches: usize,
    /// RANSAC inliers (0 without a pose).
    pub inliers: usize,
    /// Inliers of RANSAC's best hypothesis, whether it made a pose or not.
    pub best_inliers: usize,
    /// RANSAC iterations (the samples drawn, whether a pose was found or not).
    pub iterations: usize,
    /// Features the verification registered.
    pub registered: usize,
    /// Their reprojection rms at the verified pose [px].
    pub rms_px: Option<f64>,
    /// Rendered-vs-live correlation at the verified pose.
    pub ncc: Option<f64>,
    /// The verified pose, when it passed the rule.
    #[serde(skip)]
    pub pose: Option<CameraPose>,
    /// The pose RANSAC found, verified or not.
    #[serde(skip)]
    pub candidate: Option<CameraPose>,
    /// The verified pose chosen, accepted or not.
    #[serde(skip)]
    pub chosen: Option<CameraPose>,
    /// Whether the verified pose's mirror about the inliers' plane (the planar two-fold
    /// ambiguity, [`ransac::mirrored_pose`]) was verified too.
    pub mirror_verified: bool,
    /// Whether the pose came from the mirror (it verified with the lower rms).
    pub mirror_chosen: bool,
    /// Other poses verified besides RANSAC's best: the mirror and RANSAC's runners-up.
    pub alternatives: usize,
    /// The chosen pose against its own mirror on its own registrations, where that is another
    /// pose (the mirror check of [`choice::choose`]).
    pub mirror_check: Option<Comparison>,
    /// Whether two of the poses verified were both plausible and the evidence could not tell
    /// them apart (eqs. P2, P3): the attempt is refused.
    pub ambiguous: bool,
    /// Stage times.
    pub times: AttemptTimes,
    /// The other poses verified, each with how the live image tells it from the chosen one.
    pub rivals: [Option<Rival>; 4],
}

/// A verified pose other than the chosen one.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Rival {
    /// The pose.
    #[serde(skip)]
    pub pose: CameraPose,
    /// Its judgement.
    pub assessment: Assessment,
    /// The chosen pose (first) and this one judged against each other (eqs. P2, P3), when
    /// both were plausible and not one minimum.
    pub compared: Option<Comparison>,
}

impl Attempt {
    /// Whether a pose was accepted.
    pub fn accepted(&self) -> bool {
        self.pose.is_some()
    }
}

/// The database ready for matching.
#[derive(Debug, Clone)]
pub struct Locator {
    orb: Orb,
    descriptors: Vec<Descriptor>,
    points: Vec<[f32; 3]>,
    index: Index,
    config: LocateConfig,
}

impl Locator {
    /// A locator over `db`.
    pub fn new(db: &Database, config: LocateConfig) -> Self {
        let descriptors = db.descriptors();
        Self {
            orb: Orb::new(config.orb),
            index: Index::new(&descriptors),
            descriptors,
            points: db.points(),
            config,
        }
    }

    /// The settings.
    pub fn config(&self) -> &LocateConfig {
        &self.config
    }

    /// The first steps of an attempt: ORB keypoints of the undistorted image, matched against
    /// the database, and the pose by P3P in RANSAC; the attempt's figures so far, and RANSAC's
    /// pose with the matches' model points, where it found one.
    #[allow(clippy::type_complexity)]
    fn ransac_candidate(
        &self,
        vision: &Vision,
        raw: &GrayImage,
    ) -> Result<(Attempt, Option<(RansacPose, Vec<Vector3<f64>>)>), VisionError> {
        let mut times = AttemptTimes::default();
        let t = Instant::now();
        let live = vision.undistort(raw)?;
        let keypoints = self.orb.detect(&live, None);
        times.detect = t.elapsed().as_secs_f64();

        let t = Instant::now();
        let query: Vec<Descriptor> = keypoints.iter().map(|k| k.descriptor).collect();
        let matches = match_descriptors(
            &query,
            &self.descriptors,
            &self.points,
            Some(&self.index),
            &self.config.matching,
        );
        times.matching = t.elapsed().as_secs_f64();

        let t = Instant::now();
        let pin = vision.ideal_camera().pinhole;
        let u: Vec<Vector2<f64>> = matches
            .iter()
            .map(|m| {
                let k = &keypoints[m.query];
                Vector2::new(f64::from(k.x), f64::from(k.y))
            })
            .collect();
        let x_w: Vec<Vector3<f64>> = matches
            .iter()
            .map(|m| {
                let p = self.points[m.entry];
                Vector3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2]))
            })
            .collect();
        let (found, stats) = ransac_search(
            [pin.fx, pin.fy, pin.cx, pin.cy],
            &u,
            &x_w,
            &self.config.ransac,
        );
        times.ransac = t.elapsed().as_secs_f64();
        let attempt = Attempt {
            keypoints: keypoints.len(),
            matches: matches.len(),
            inliers: 0,
            best_inliers: stats.best_inliers,
            iterations: stats.iterations,
            registered: 0,
            rms_px: None,
            ncc: None,
            pose: None,
            candidate: None,
            chosen: None,
            mirror_verified: false,
            mirror_chosen: false,
            ambiguous: false,
            mirror_check: None,
            alternatives: 0,
            times,
            rivals: [None; 4],
        };
        Ok((attempt, found.map(|f| (f, x_w))))
    }

    /// One attempt on the raw live image `raw`, with `vision` (its camera, renderer and
    /// feature map: a verified pose leaves the map ready for tracking from it). With
    /// `keep_image`, the verification's analysis comes back with its image, for an overlay.
    pub fn attempt(
        &self,
        vision: &mut Vision,
        raw: &GrayImage,
        keep_image: bool,
    ) -> Result<(Attempt, Option<FrameResult>), VisionError> {
        let (mut attempt, found) = self.ransac_candidate(vision, raw)?;
        let Some((found, x_w)) = found else {
            return Ok((attempt, None));
        };
        attempt.inliers = found.inliers.iter().filter(|&&i| i).count();
        let candidate = CameraPose::from_extrinsics(found.q_cw, &found.t);
        attempt.candidate = Some(candidate);

        let t = Instant::now();
        let (first, first_from) = converged(vision, raw, &candidate, keep_image)?;
        // The planar two-fold ambiguity (docs/notes/issue15-cold-start.md §4, eq. P1): where
        // the model points seen lie on one plane, the pose with the plane tilted the other way
        // explains them nearly as well, and the fit may have ended in either. The mirror of the
        // verified pose about the inliers' plane is verified too, and so are RANSAC's
        // runners-up: other poses the matches fit (docs/notes/issue15-cold-start.md §4).
        let inlier_points: Vec<Vector3<f64>> = x_w
            .iter()
            .zip(&found.inliers)
            .filter(|(_, inl)| **inl)
            .map(|(x, _)| *x)
            .collect();
        let mirror = choice::mirrored(&first.pose, &inlier_points);
        let runners_up = found
            .runners_up
            .iter()
            .map(|(q_cw, t)| CameraPose::from_extrinsics(*q_cw, t));
        let mut tried = vec![candidate, first.pose];
        // The verified poses, where each one's last verification ran from, and which is the
        // mirror.
        let mut verified = vec![first];
        let mut from = vec![first_from];
        let mut mirrored = vec![false];
        for (is_mirror, start) in mirror
            .map(|m| (true, m))
            .into_iter()
            .chain(runners_up.map(|p| (false, p)))
        {
            // Another pose only: a plane facing the camera has one.
            if tried
                .iter()
                .any(|p| p.q_cw.angle_to(&start.q_cw) < SAME_POSE_RAD)
            {
                continue;
            }
            tried.push(start);
            attempt.mirror_verified |= is_mirror;
            attempt.alternatives += 1;
            let (v, v_from) = converged(vision, raw, &start, keep_image)?;
            verified.push(v);
            from.push(v_from);
            mirrored.push(is_mirror);
        }
        let t_choose = Instant::now();
        let (chosen, compared, mirror_check) = choose(vision, raw, &verified, &self.config.rule)?;
        attempt.times.choose = t_choose.elapsed().as_secs_f64();
        attempt.mirror_check = mirror_check;
        let k = match chosen {
            Choice::One(k) => k,
            // Judged as the lowest-rms pose, refused below.
            Choice::Ambiguous(k) => {
                attempt.ambiguous = true;
                k
            }
        };
        attempt.mirror_chosen = mirrored[k];
        let mut r = 0;
        for (j, v) in verified.iter().enumerate() {
            if j != k && r < attempt.rivals.len() {
                attempt.rivals[r] = Some(Rival {
                    pose: v.pose,
                    assessment: v.assessment,
                    compared: compared[k][j],
                });
                r += 1;
            }
        }
        let last = verified.len() - 1;
        let mut best = verified.swap_remove(k);
        if k != last {
            // The feature map must be the chosen pose's, ready for tracking from it: the same
            // verification again.
            best = vision.verify(raw, &from[k], keep_image)?;
        }
        attempt.times.verify = t.elapsed().as_secs_f64() - attempt.times.choose;
        attempt.chosen = Some(best.pose);
        let a = best.assessment;
        attempt.registered = a.features;
        attempt.rms_px = a.rms_px;
        attempt.ncc = a.ncc;
        if !attempt.ambiguous && self.config.rule.holds(&a) {
            attempt.pose = Some(best.pose);
        }
        Ok((attempt, best.result))
    }
}

/// Verifications run from a pose before it is judged, at most: each re-registers the
/// features from the last re-fitted pose.
const MAX_VERIFICATIONS: usize = 4;

/// A verification has converged when it moves the pose less than this [m]...
const CONVERGED_M: f64 = 1e-3;

/// ... and less than this [rad].
const CONVERGED_RAD: f64 = 0.1 * std::f64::consts::PI / 180.0;

/// [`Vision::verify`] from `pose`, run again from its re-fitted pose until that stops moving
/// (or [`MAX_VERIFICATIONS`] times). One verification is two rounds of registration and
/// re-fit; where the pose is poorly pinned down (one face of a cube, seen nearly face on),
/// it is still moving after them, and a judgement or a comparison made there is a judgement
/// of an arbitrary point on the way (docs/notes/issue15-cold-start.md §5). It has stopped
/// moving when it moves less than 1 mm and 0.1°, or less than its registrations pin it down
/// (`features::outliers::within_noise`, eq. V1). Returns the last verification and the pose it ran from
/// (verifying from it again gives the same result, and its feature map).
pub fn converged(
    vision: &mut Vision,
    raw: &GrayImage,
    pose: &CameraPose,
    keep_image: bool,
) -> Result<(Verified, CameraPose), VisionError> {
    let mut from = *pose;
    let mut verified = vision.verify(raw, &from, keep_image)?;
    for _ in 1..MAX_VERIFICATIONS {
        let moved = (verified.pose.c_w - from.c_w).norm();
        let turned = verified.pose.q_cw.angle_to(&from.q_cw);
        if moved < CONVERGED_M && turned < CONVERGED_RAD
            || within_noise(
                vision.ideal_camera(),
                &from,
                &verified.pose,
                &verified.registered,
            )
        {
            break;
        }
        from = verified.pose;
        verified = vision.verify(raw, &from, keep_image)?;
    }
    Ok((verified, from))
}
