//! The tilt branch of vision-only tracking (docs/notes/issue15-cold-start.md §5.2): which of
//! the tilt checks' flips are applied, and which frames around them count as tracked.
//!
//! A check that finds the other tilt of a face favoured (eqs. P2, P3) gives a flip. A flip is
//! applied only while the tracked tilt is *settled*; the frames after it are *provisional*
//! (not tracked) until the next check confirms the flipped tilt. Where that check favours the
//! mirror again, tracking has walked back and the flip did not hold: flipping cannot keep
//! tracking on the favoured tilt, so no further flip is applied, and the frames are withheld
//! (not tracked) while the checks keep favouring the mirror. The tracked pose then disagrees
//! with what the image shows; reporting it as tracked would be silently wrong.

use std::collections::BTreeSet;

use serde::Serialize;

use camera::CameraPose;
use locate::choice::{Comparison, TiltCheck};

/// A flip to the other tilt of a face, with the evidence that decided it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct TiltFlip {
    /// The frame checked.
    pub frame: usize,
    /// When the flip was applied [s].
    pub at_s: f64,
    /// How far the flip moved the camera [m].
    pub jump_m: f64,
    /// How far it turned the camera [°].
    pub jump_deg: f64,
    /// The tracked pose against its mirror (eq. P2's correlations, eq. P3's log-odds).
    pub tracked_vs_mirror: Comparison,
    /// The verified mirror against the tracked pose.
    pub flipped_vs_tracked: Comparison,
    /// Whether the flipped tilt held: the next check did not favour the mirror again. `None`:
    /// no check came (tracking was lost, or the run ended) before it was confirmed.
    pub held: Option<bool>,
}

/// What a tilt check found and what the branch did, as told ([`crate::event::Detail::Tilt`]):
/// the branch keeps none of it, a [`TiltRecord`] does.
#[derive(Debug, Clone, PartialEq)]
pub enum TiltNote {
    /// A check was sent.
    Checked,
    /// These frames (by id) are withheld.
    Withheld(Vec<u32>),
    /// A flip was applied.
    Flip(Box<TiltFlip>),
    /// The last flip held, or did not.
    Held(bool),
    /// The check of this frame found a flip that was not applied: the last one had not held.
    Refused(usize),
}

/// The tilt checks of a run and what came of them.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct TiltRecord {
    /// Checks run.
    pub checks: usize,
    /// Flips applied.
    pub flips: Vec<TiltFlip>,
    /// The frames whose checks found a flip that was not applied: the last flip had not held.
    pub refused: Vec<usize>,
    /// Frames (by id) that pass the tracked rule but are not tracked: on the tilt the image
    /// disfavours, or flipped and never confirmed.
    #[serde(skip)]
    pub withheld: BTreeSet<u32>,
}

impl TiltRecord {
    /// Keeps what a note says.
    pub fn apply(&mut self, note: &TiltNote) {
        match note {
            TiltNote::Checked => self.checks += 1,
            TiltNote::Withheld(ids) => self.withheld.extend(ids),
            TiltNote::Flip(f) => self.flips.push(**f),
            TiltNote::Held(held) => {
                if let Some(f) = self.flips.last_mut() {
                    f.held = Some(*held);
                }
            }
            TiltNote::Refused(frame) => self.refused.push(*frame),
        }
    }
}

/// Where the tracked tilt stands.
#[derive(Debug, Clone, PartialEq)]
enum Branch {
    /// The tracked tilt stands.
    Settled,
    /// A flip was applied; the frames since (by id) wait for the next check.
    Provisional(Vec<u32>),
    /// The last flip did not hold, and the checks still favour the other tilt.
    Doubted,
}

/// The check in flight.
#[derive(Debug, Clone, PartialEq)]
struct InFlight {
    /// The frame checked.
    frame: usize,
    /// The pose checked.
    pose: CameraPose,
    /// The frames judged since it was sent (by id), its own first.
    frames: Vec<u32>,
}

/// The tilt branch of a vision-only run.
#[derive(Debug, Clone, PartialEq)]
pub struct TiltBranch {
    state: Branch,
    in_flight: Option<InFlight>,
    /// What the checks found and what was done, until taken ([`Self::take_notes`]).
    notes: Vec<TiltNote>,
}

impl Default for TiltBranch {
    fn default() -> Self {
        Self {
            state: Branch::Settled,
            in_flight: None,
            notes: Vec::new(),
        }
    }
}

impl TiltBranch {
    /// What the checks found and what was done since the last call, in order.
    pub fn take_notes(&mut self) -> Vec<TiltNote> {
        std::mem::take(&mut self.notes)
    }

    /// Whether a check is in flight.
    pub fn in_flight(&self) -> bool {
        self.in_flight.is_some()
    }

    /// A check was sent for frame `frame` (id `frame_id`), tracked at `pose`.
    pub fn sent(&mut self, frame: usize, frame_id: u32, pose: CameraPose) {
        self.notes.push(TiltNote::Checked);
        self.in_flight = Some(InFlight {
            frame,
            pose,
            frames: vec![frame_id],
        });
    }

    /// Frame `frame_id` was judged (after the check of its own frame, if one was sent).
    pub fn judged(&mut self, frame_id: u32) {
        if let Some(f) = &mut self.in_flight
            && f.frames.last() != Some(&frame_id)
        {
            f.frames.push(frame_id);
        }
        match &mut self.state {
            Branch::Settled => {}
            Branch::Provisional(frames) => frames.push(frame_id),
            Branch::Doubted => self.notes.push(TiltNote::Withheld(vec![frame_id])),
        }
    }

    /// The answer to the check in flight, taken at `at_s`: the pose to re-initialise the core
    /// at, where a flip is applied.
    pub fn answer(&mut self, check: &TiltCheck, at_s: f64) -> Option<CameraPose> {
        let sent = self.in_flight.take()?;
        let against = check.disfavours_tracked();
        let state = std::mem::replace(&mut self.state, Branch::Settled);
        match (state, against) {
            (Branch::Provisional(frames), true) => {
                self.notes.push(TiltNote::Withheld(frames));
                self.notes.push(TiltNote::Held(false));
                self.refuse_or_doubt(check, &sent);
                None
            }
            (Branch::Provisional(_), false) => {
                self.notes.push(TiltNote::Held(true));
                None
            }
            (Branch::Doubted, true) => {
                self.refuse_or_doubt(check, &sent);
                None
            }
            (Branch::Settled, true) => {
                let (Some(pose), Some(first), Some(second)) = (
                    check.flip,
                    check.tracked_vs_mirror,
                    check.flipped_vs_tracked,
                ) else {
                    // Favoured, but the mirror did not verify or was not favoured again: the
                    // evidence is not confirmed, and the tracked pose stands.
                    return None;
                };
                // The frames since the check are on the tilt the image disfavours.
                self.notes.push(TiltNote::Withheld(sent.frames.clone()));
                self.notes.push(TiltNote::Flip(Box::new(TiltFlip {
                    frame: sent.frame,
                    at_s,
                    jump_m: (pose.c_w - sent.pose.c_w).norm(),
                    jump_deg: pose.q_cw.angle_to(&sent.pose.q_cw).to_degrees(),
                    tracked_vs_mirror: first,
                    flipped_vs_tracked: second,
                    held: None,
                })));
                self.state = Branch::Provisional(Vec::new());
                Some(pose)
            }
            (Branch::Doubted | Branch::Settled, false) => None,
        }
    }

    /// Tracking starts afresh (a search's pose re-initialised the core) or the run ends: a
    /// flip not yet confirmed never held, and its frames are withheld.
    pub fn restart(&mut self) {
        if let Branch::Provisional(frames) = std::mem::replace(&mut self.state, Branch::Settled) {
            self.notes.push(TiltNote::Withheld(frames));
        }
        self.in_flight = None;
    }

    /// The checks favour the other tilt after a flip that did not hold: the frames since the
    /// check are withheld, and a flip found is refused.
    fn refuse_or_doubt(&mut self, check: &TiltCheck, sent: &InFlight) {
        self.notes.push(TiltNote::Withheld(sent.frames.clone()));
        if check.flip.is_some() {
            self.notes.push(TiltNote::Refused(sent.frame));
        }
        self.state = Branch::Doubted;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{UnitQuaternion, Vector3};
    use std::cmp::Ordering;
    use vision::Contrast;

    fn pose(x: f64) -> CameraPose {
        CameraPose {
            q_cw: UnitQuaternion::identity(),
            c_w: Vector3::new(x, 0.0, 0.5),
        }
    }

    fn comparison(verdict: Option<Ordering>) -> Comparison {
        Comparison {
            contrast: Contrast {
                pixels: 2000,
                first: Some(0.1),
                second: Some(0.5),
            },
            evidence: None,
            verdict,
        }
    }

    /// A check that favours the mirror (with the flip to `x`), or one that does not.
    fn check(favours_mirror: bool, flip_to: Option<f64>) -> TiltCheck {
        TiltCheck {
            tracked_vs_mirror: Some(comparison(Some(if favours_mirror {
                Ordering::Greater
            } else {
                Ordering::Less
            }))),
            flipped_vs_tracked: flip_to.map(|_| comparison(Some(Ordering::Less))),
            flip: flip_to.map(pose),
        }
    }

    /// A branch and the record of its notes.
    #[derive(Default)]
    struct Tested {
        branch: TiltBranch,
        record: TiltRecord,
    }

    impl Tested {
        fn sync(&mut self) {
            for n in self.branch.take_notes() {
                self.record.apply(&n);
            }
        }
        fn sent(&mut self, frame: usize, frame_id: u32, pose: CameraPose) {
            self.branch.sent(frame, frame_id, pose);
            self.sync();
        }
        fn judged(&mut self, frame_id: u32) {
            self.branch.judged(frame_id);
            self.sync();
        }
        fn answer(&mut self, check: &TiltCheck, at_s: f64) -> Option<CameraPose> {
            let pose = self.branch.answer(check, at_s);
            self.sync();
            pose
        }
        fn restart(&mut self) {
            self.branch.restart();
            self.sync();
        }
    }

    /// Frames `ids` judged, with a check sent at the first.
    fn frames(b: &mut Tested, ids: std::ops::RangeInclusive<u32>) {
        let first = *ids.start();
        b.sent(first as usize, first, pose(0.0));
        for id in ids {
            b.judged(id);
        }
    }

    #[test]
    fn a_flip_that_holds_withholds_only_the_frame_it_found_wrong() {
        let mut b = Tested::default();
        frames(&mut b, 10..=10);
        assert_eq!(b.answer(&check(true, Some(0.1)), 0.37), Some(pose(0.1)));
        let f = b.record.flips[0];
        assert_eq!((f.frame, f.held), (10, None));
        assert!((f.jump_m - 0.1).abs() < 1e-12);
        frames(&mut b, 11..=16);
        assert_eq!(b.answer(&check(false, None), 0.57), None);
        assert_eq!(b.record.flips[0].held, Some(true));
        assert_eq!(b.record.withheld, BTreeSet::from([10]));
        // Settled again: a later flip is applied.
        frames(&mut b, 17..=17);
        assert!(b.answer(&check(true, Some(0.2)), 0.6).is_some());
        assert_eq!(b.record.flips.len(), 2);
    }

    #[test]
    fn a_flip_that_does_not_hold_is_not_repeated_and_its_frames_are_not_tracked() {
        let mut b = Tested::default();
        frames(&mut b, 10..=10);
        assert!(b.answer(&check(true, Some(0.1)), 0.37).is_some());
        // Tracking walked back: the next check favours the mirror again.
        frames(&mut b, 11..=16);
        assert_eq!(b.answer(&check(true, Some(0.1)), 0.57), None);
        assert_eq!(b.record.flips[0].held, Some(false));
        assert_eq!(b.record.refused, vec![11]);
        frames(&mut b, 17..=22);
        assert_eq!(b.answer(&check(true, Some(0.1)), 0.77), None);
        assert_eq!(b.record.refused, vec![11, 17]);
        assert_eq!(b.record.withheld, (10..=22).collect());
        // A check that no longer favours the mirror settles it; frames count again.
        frames(&mut b, 23..=28);
        assert_eq!(b.answer(&check(false, None), 0.97), None);
        b.judged(29);
        assert!(!b.record.withheld.contains(&29));
        assert_eq!(b.record.flips.len(), 1);
    }

    #[test]
    fn evidence_not_confirmed_changes_nothing_and_an_unconfirmed_flip_is_withheld_at_a_restart() {
        let mut b = Tested::default();
        frames(&mut b, 10..=10);
        // The mirror was favoured, but did not verify: the tracked pose stands.
        assert_eq!(b.answer(&check(true, None), 0.37), None);
        assert!(b.record.flips.is_empty() && b.record.withheld.is_empty());
        frames(&mut b, 11..=11);
        assert!(b.answer(&check(true, Some(0.1)), 0.4).is_some());
        b.judged(12);
        b.judged(13);
        b.restart();
        assert_eq!(b.record.flips[0].held, None);
        assert_eq!(b.record.withheld, BTreeSet::from([11, 12, 13]));
        b.judged(14);
        assert!(!b.record.withheld.contains(&14));
    }
}
