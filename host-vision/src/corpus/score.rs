//! The verdict scored against the truth (issue 56): per frame, whether the run flagged it
//! tracked and whether its pose is right; per run, the precision and recall of "tracked" and
//! how long a wrong pose went unreported.

use serde::Serialize;

/// When a pose is right: within `position_m` and `rotation_deg` of the truth.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Bound {
    /// Largest camera position error [m].
    pub position_m: f64,
    /// Largest rotation error [°].
    pub rotation_deg: f64,
}

impl Bound {
    /// Eq. T1 for an object of `size` [m], its model's bounding-box diagonal
    /// ([`vision::success_bound_m`]), and 5°.
    pub fn for_size(size: f64) -> Self {
        Bound {
            position_m: vision::success_bound_m(size),
            rotation_deg: 5.0,
        }
    }

    /// Whether an error `(position [m], rotation [°])` is within `factor` times the bound.
    pub fn holds(&self, error: (f64, f64), factor: f64) -> bool {
        error.0 <= factor * self.position_m && error.1 <= factor * self.rotation_deg
    }
}

/// One frame taken, as the score sees it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameTruth {
    /// Whether the run flagged it tracked (`None`: the run gave it no verdict).
    pub tracked: Option<bool>,
    /// The error of the pose estimated with it against the truth, `(position [m], rotation
    /// [°])`; `None` where it has no pose (not analysed) or no truth.
    pub error: Option<(f64, f64)>,
    /// That pose's normalised estimation error squared by the core's covariance (eq. T6).
    pub nees: Option<f64>,
    /// Whether at least half of the model's own pixels are in view, no occluder hiding them
    /// (`None`: the dataset does not say).
    pub half_visible: Option<bool>,
}

/// χ²₆'s 95 % quantile: a calibrated covariance's NEES lies below it on 95 % of frames.
pub const CHI2_6_95: f64 = 12.592;

/// How well the core's covariances describe the errors (eq. T6) over a set of frames.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct Calibration {
    /// Frames with a NEES.
    pub frames: usize,
    /// Their mean NEES (6 where calibrated).
    pub mean: f64,
    /// Their median (5.35 where calibrated).
    pub median: f64,
    /// The share below χ²₆'s 95 % quantile (0.95 where calibrated).
    pub inside_95: f64,
}

impl Calibration {
    /// The calibration of these NEES values; `None` without any.
    pub fn of(values: impl Iterator<Item = f64>) -> Option<Self> {
        let mut v: Vec<f64> = values.collect();
        if v.is_empty() {
            return None;
        }
        v.sort_by(f64::total_cmp);
        let n = v.len() as f64;
        Some(Calibration {
            frames: v.len(),
            mean: v.iter().sum::<f64>() / n,
            median: v[v.len() / 2],
            inside_95: v.iter().filter(|&&x| x <= CHI2_6_95).count() as f64 / n,
        })
    }
}

/// A run's verdicts against the truth.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct Score {
    /// Frames taken.
    pub frames: usize,
    /// Frames with a pose and a truth to compare it with.
    pub with_truth: usize,
    /// Of those, the right ones (within the bound).
    pub right: usize,
    /// Frames given a verdict (tracked or not).
    pub judged: usize,
    /// Frames flagged tracked.
    pub tracked: usize,
    /// Frames flagged tracked and right.
    pub tracked_right: usize,
    /// Frames flagged tracked and beyond twice the bound.
    pub tracked_far: usize,
    /// Frames flagged tracked with no truth to tell (past the ground truth's end): outside
    /// the precision.
    pub tracked_untold: usize,
    /// Share of the tracked frames with a truth that are right (`None`: none flagged).
    pub precision: Option<f64>,
    /// Share of the right frames flagged tracked (`None`: none right).
    pub recall: Option<f64>,
    /// Right frames with at least half of the model unoccluded.
    pub right_half_visible: usize,
    /// Of those, the ones flagged tracked.
    pub tracked_right_half_visible: usize,
    /// Share of the right frames with at least half of the model unoccluded that were flagged
    /// tracked (the goal's recall; `None`: none, or the dataset does not say).
    pub recall_half_visible: Option<f64>,
    /// Share of the frames with a truth that are right (the tracker's success, RBOT's
    /// measure, whatever the verdict said).
    pub success: Option<f64>,
    /// The largest error of a frame flagged tracked, `[m, °]`.
    pub worst_tracked: Option<[f64; 2]>,
    /// Per stretch of consecutive wrong frames: frames from its first one to the first frame
    /// not flagged tracked (0: the first wrong frame was itself not flagged); `None` where
    /// every frame of the stretch was flagged tracked (never reported).
    pub report_delays: Vec<Option<usize>>,
    /// The covariances' calibration over the frames flagged tracked (what a program uses).
    pub nees_tracked: Option<Calibration>,
    /// The same over every frame with a pose.
    pub nees_all: Option<Calibration>,
}

impl Score {
    /// The longest report delay [frames], `None` where some wrong stretch was never reported
    /// or there was none.
    pub fn worst_delay(&self) -> Option<usize> {
        if self.report_delays.iter().any(Option::is_none) {
            return None;
        }
        self.report_delays.iter().flatten().copied().max()
    }

    /// Wrong stretches whose every frame was flagged tracked.
    pub fn unreported(&self) -> usize {
        self.report_delays.iter().filter(|d| d.is_none()).count()
    }
}

/// Scores `frames` (in the order taken) against `bound` (eq. T2, T3).
pub fn score(frames: &[FrameTruth], bound: &Bound) -> Score {
    let mut s = Score {
        frames: frames.len(),
        ..Score::default()
    };
    let is_right = |f: &FrameTruth| f.error.is_some_and(|e| bound.holds(e, 1.0));
    for f in frames {
        let flagged = f.tracked == Some(true);
        s.judged += usize::from(f.tracked.is_some());
        s.with_truth += usize::from(f.error.is_some());
        s.right += usize::from(is_right(f));
        let counted = is_right(f) && f.half_visible == Some(true);
        s.right_half_visible += usize::from(counted);
        s.tracked_right_half_visible += usize::from(counted && flagged);
        if flagged {
            s.tracked += 1;
            s.tracked_right += usize::from(is_right(f));
            s.tracked_untold += usize::from(f.error.is_none());
            s.tracked_far += usize::from(f.error.is_some_and(|e| !bound.holds(e, 2.0)));
            if let Some((m, deg)) = f.error {
                let worst = s.worst_tracked.get_or_insert([m, deg]);
                *worst = [worst[0].max(m), worst[1].max(deg)];
            }
        }
    }
    let share = |n: usize, of: usize| (of > 0).then(|| n as f64 / of as f64);
    s.precision = share(s.tracked_right, s.tracked - s.tracked_untold);
    s.recall = share(s.tracked_right, s.right);
    s.recall_half_visible = share(s.tracked_right_half_visible, s.right_half_visible);
    s.success = share(s.right, s.with_truth);
    s.report_delays = report_delays(frames, &is_right);
    s.nees_tracked = Calibration::of(
        frames
            .iter()
            .filter(|f| f.tracked == Some(true))
            .filter_map(|f| f.nees),
    );
    s.nees_all = Calibration::of(frames.iter().filter_map(|f| f.nees));
    s
}

/// Eq. T3's delays: per maximal stretch of wrong frames (a pose and a truth, beyond the
/// bound), the frames until the first one not flagged tracked.
fn report_delays(
    frames: &[FrameTruth],
    is_right: &dyn Fn(&FrameTruth) -> bool,
) -> Vec<Option<usize>> {
    let wrong = |f: &FrameTruth| f.error.is_some() && !is_right(f);
    let mut delays = Vec::new();
    let mut k = 0;
    while k < frames.len() {
        if !wrong(&frames[k]) {
            k += 1;
            continue;
        }
        let start = k;
        while k < frames.len() && wrong(&frames[k]) {
            k += 1;
        }
        delays.push(
            frames[start..k]
                .iter()
                .position(|f| f.tracked != Some(true)),
        );
    }
    delays
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(tracked: Option<bool>, error: Option<(f64, f64)>) -> FrameTruth {
        FrameTruth {
            tracked,
            error,
            nees: None,
            half_visible: Some(true),
        }
    }

    #[test]
    fn the_calibration_counts_the_frames_inside_the_bound() {
        let c = Calibration::of([1.0, 5.0, 6.0, 12.0, 40.0].into_iter()).unwrap();
        assert_eq!((c.frames, c.mean, c.median), (5, 12.8, 6.0));
        assert!((c.inside_95 - 0.8).abs() < 1e-12);
        assert_eq!(Calibration::of(std::iter::empty()), None);
        let mut frames = [frame(Some(true), GOOD), frame(Some(false), BAD)];
        frames[0].nees = Some(3.0);
        frames[1].nees = Some(30.0);
        let s = score(&frames, &Bound::for_size(1.0));
        assert_eq!(s.nees_tracked.map(|c| c.frames), Some(1));
        assert_eq!(s.nees_all.map(|c| c.mean), Some(16.5));
    }

    const GOOD: Option<(f64, f64)> = Some((0.01, 1.0));
    const BAD: Option<(f64, f64)> = Some((0.08, 1.0));
    const FAR: Option<(f64, f64)> = Some((0.02, 12.0));

    #[test]
    fn the_bound_is_5_cm_and_5_degrees_or_a_tenth_of_a_small_object() {
        assert_eq!(Bound::for_size(1.0).position_m, 0.05);
        assert!((Bound::for_size(0.15).position_m - 0.015).abs() < 1e-12);
        assert_eq!(Bound::for_size(f64::NAN).position_m, 0.05);
        let b = Bound::for_size(1.0);
        assert!(b.holds((0.05, 5.0), 1.0));
        assert!(!b.holds((0.0501, 0.0), 1.0));
        assert!(!b.holds((0.0, 5.01), 1.0));
        assert!(b.holds((0.09, 9.0), 2.0));
    }

    #[test]
    fn precision_recall_and_success_count_what_they_say() {
        let frames = [
            frame(Some(true), GOOD),
            frame(Some(true), BAD),
            frame(Some(false), GOOD),
            frame(Some(true), FAR),
            frame(None, None),
            frame(Some(true), GOOD),
            frame(Some(true), None),
        ];
        let s = score(&frames, &Bound::for_size(1.0));
        assert_eq!((s.frames, s.with_truth, s.right, s.judged), (7, 5, 3, 6));
        assert_eq!((s.tracked, s.tracked_right, s.tracked_far), (5, 2, 1));
        assert_eq!(s.tracked_untold, 1);
        assert_eq!(s.precision, Some(0.5));
        assert_eq!(s.recall, Some(2.0 / 3.0));
        assert_eq!(s.success, Some(0.6));
        assert_eq!(s.worst_tracked, Some([0.08, 12.0]));
        // The goal's recall counts only the right frames with half the model in view.
        assert_eq!(s.recall_half_visible, Some(2.0 / 3.0));
        let mut hidden = frames;
        hidden[2].half_visible = Some(false);
        hidden[5].half_visible = None;
        let s = score(&hidden, &Bound::for_size(1.0));
        assert_eq!((s.right_half_visible, s.tracked_right_half_visible), (1, 1));
        assert_eq!(s.recall_half_visible, Some(1.0));
    }

    #[test]
    fn a_wrong_stretch_is_reported_at_its_first_frame_not_flagged() {
        let frames = [
            frame(Some(true), GOOD),
            // Reported at once.
            frame(Some(false), BAD),
            frame(Some(false), BAD),
            frame(Some(true), GOOD),
            // Reported two frames late.
            frame(Some(true), BAD),
            frame(Some(true), FAR),
            frame(None, BAD),
            frame(Some(true), GOOD),
            // Never reported.
            frame(Some(true), BAD),
        ];
        let s = score(&frames, &Bound::for_size(1.0));
        assert_eq!(s.report_delays, vec![Some(0), Some(2), None]);
        assert_eq!(s.unreported(), 1);
        assert_eq!(s.worst_delay(), None);
        let reported = score(&frames[..8], &Bound::for_size(1.0));
        assert_eq!(reported.worst_delay(), Some(2));
    }

    #[test]
    fn a_run_without_verdicts_has_no_precision_and_no_recall_of_its_verdict() {
        let frames = [frame(None, GOOD), frame(None, BAD)];
        let s = score(&frames, &Bound::for_size(1.0));
        assert_eq!((s.judged, s.tracked), (0, 0));
        assert_eq!(s.precision, None);
        assert_eq!(s.recall, Some(0.0));
        assert_eq!(s.report_delays, vec![Some(0)]);
    }
}
