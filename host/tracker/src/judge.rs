//! The judge of every run (docs/VISION.md §10): a frame's assessment at its pose against the
//! tracked rule, the direction the pose pins down least (eq. T7), and the tally of the
//! verdicts, with the frames the tilt branch withholds taken out.

use std::collections::BTreeMap;

use camera::{CameraPose, PoseCovariance, WeakDirection};
use nalgebra::Vector3;
use vision::{Assessment, TrackedRule, Verdicts};

/// Verdicts kept for the tilt branch to withhold: it withholds frames judged since its check
/// or its flip, a few frames back.
const VERDICTS_KEPT: usize = 256;

/// How many frames were judged, and how many of them count as tracked.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Tally {
    /// Frames that count as tracked (judged so, and not withheld by the tilt branch).
    pub tracked: usize,
    /// Frames judged.
    pub judged: usize,
}

/// A frame's verdict, with what it was given on.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Verdict {
    /// Whether the frame counts as tracked (the tracked rule).
    pub(crate) tracked: bool,
    /// The assessment, with the weakest direction's σ where it was judged by it.
    pub(crate) assessment: Assessment,
    /// The direction the pose pins down least (eq. T7), where it has a covariance.
    pub(crate) weakest: Option<WeakDirection>,
}

/// The judge of a run.
#[derive(Debug)]
pub(crate) struct Judge {
    /// The rule (its bounds scale with the model's size).
    rule: TrackedRule,
    /// The model's centre: the weakest direction is measured about it.
    centre: Vector3<f64>,
    /// The verdicts so far (the contour form's confirmation).
    verdicts: Verdicts,
    tally: Tally,
    /// The recent verdicts by frame id, for [`Self::withhold`].
    recent: BTreeMap<u32, bool>,
}

impl Judge {
    /// The judge of a model of diagonal `diagonal` [m] centred at `centre`.
    pub(crate) fn new(diagonal: f64, centre: Vector3<f64>) -> Self {
        Self {
            rule: TrackedRule::for_object(diagonal),
            centre,
            verdicts: Verdicts::default(),
            tally: Tally::default(),
            recent: BTreeMap::new(),
        }
    }

    /// The rule.
    pub(crate) fn rule(&self) -> &TrackedRule {
        &self.rule
    }

    /// The verdict on frame `frame_id` assessed as `a` at `pose` of covariance `cov`.
    /// `by_weakest`: the weakest direction's σ is part of the verdict (eq. T9, vision-only
    /// poses); else it is only reported.
    pub(crate) fn judge(
        &mut self,
        frame_id: u32,
        mut a: Assessment,
        pose: &CameraPose,
        cov: Option<&PoseCovariance>,
        by_weakest: bool,
    ) -> Verdict {
        let weakest = cov.map(|c| weakest(&self.rule, &self.centre, pose, c));
        if by_weakest {
            a.weakest_sigma = weakest.map(|w| w.sigma);
        }
        let tracked = self.verdicts.judge(&self.rule, &a);
        self.tally.judged += 1;
        self.tally.tracked += usize::from(tracked);
        self.recent.insert(frame_id, tracked);
        while self.recent.len() > VERDICTS_KEPT {
            self.recent.pop_first();
        }
        Verdict {
            tracked,
            assessment: a,
            weakest,
        }
    }

    /// A tracked pose's weak direction: its `weakest`, where that exceeds the rule's
    /// `weak_sigma` (eq. T7).
    pub(crate) fn weak(
        &self,
        weakest: Option<WeakDirection>,
        tracked: bool,
    ) -> Option<WeakDirection> {
        weakest.filter(|w| tracked && w.sigma > self.rule.weak_sigma)
    }

    /// The tilt branch withholds these frames: they no longer count as tracked.
    pub(crate) fn withhold(&mut self, frame_ids: &[u32]) {
        for id in frame_ids {
            if let Some(t) = self.recent.get_mut(id)
                && *t
            {
                *t = false;
                self.tally.tracked -= 1;
            }
        }
    }

    /// The tally so far.
    pub(crate) fn tally(&self) -> Tally {
        self.tally
    }
}

/// The direction `pose`, of covariance `cov`, is pinned down least, in units of `rule`'s
/// bounds, about `centre` (docs/VISION.md eq. T7).
pub(crate) fn weakest(
    rule: &TrackedRule,
    centre: &Vector3<f64>,
    pose: &CameraPose,
    cov: &PoseCovariance,
) -> WeakDirection {
    cov.weakest(
        pose,
        centre,
        rule.max_offset_m,
        rule.max_offset_deg.to_radians(),
    )
}
