//! What a tracking run saw, kept for its reports from the tracker's events
//! ([`Record::observe`]): every message of the core, every frame's analysis and judgement, the
//! searches, the tilt checks, the outages and the latencies. The tracker keeps none of it: a
//! program that wants it keeps a `Record` (a run's report grows with the run; the tracker
//! does not).

use std::collections::BTreeMap;
use std::time::Instant;

use camera::{CameraPose, PoseCovariance, WeakDirection};
use nalgebra::Vector3;
use protocol::Mode;
use serde::Serialize;
use vision::{Assessment, FrameResult, TrackedRule};

use crate::event::{Detail, Event};
pub use crate::event::{Fate, Outage, OutageKind};
use crate::latency::Latencies;
use crate::log::CoreLog;
use crate::rig::HandEye;
use crate::search::{Recovery, Search};
use crate::tilt::TiltRecord;

/// Everything a run saw, in order.
#[derive(Debug)]
pub struct Record {
    /// The mount the core was configured with: the rig's, or none (the camera is the sensor)
    /// in vision-only runs.
    pub core_hand_eye: HandEye,
    /// The input's time [ns] that the run's times [µs] count from: its first IMU sample, or
    /// (vision-only) the first frame taken, whether or not the core's clock started there (a
    /// cold start ticks the core first at the frame the model was found in).
    pub origin_ns: Option<i64>,
    /// Time stamp [ns, the input's clock] of every clock message sent, in order: the IMU
    /// samples, or the vision-only ticks.
    pub clock: Vec<u64>,
    /// Per frame id, the vision-only frame's judgement at the pose estimated with its update.
    pub assessments: BTreeMap<u32, Assessment>,
    /// Per frame id, the run's verdict on it ([`vision::Verdicts`]): tracked or not, before
    /// the tilt branch withholds any.
    pub verdicts: BTreeMap<u32, bool>,
    /// The rule the verdicts were given by (its bounds scale with the model's size).
    pub rule: TrackedRule,
    /// What the core said.
    pub log: CoreLog,
    /// Every frame taken, in the order taken, with what became of it.
    pub frames: Vec<TakenFrame>,
    /// Frame results with the id the core gave them.
    pub results: Vec<(u32, FrameResult)>,
    /// Frames that could not be analysed, with why: the number of results before them, and
    /// the message.
    pub frame_errors: Vec<(usize, String)>,
    /// Correspondences sent.
    pub sent_correspondences: usize,
    /// Where the overlays draw the model's axes, and their length [m].
    pub axes: (Vector3<f64>, f64),
    /// The cold start's attempts, in order (runs with no start pose).
    pub searches: Vec<Search>,
    /// Searches after the model was lost, one entry per loss.
    pub recoveries: Vec<Recovery>,
    /// Where the searches' viewpoint database came from (read from the cache, or built and
    /// why).
    pub database: Option<locate::database::Provenance>,
    /// The tilt checks of tracked poses and their flips (vision-only runs).
    pub tilt: TiltRecord,
    /// This run's name for its configuration of the core (`Config::session`): a core that
    /// reports it in its `HelloAck` kept the state this run gave it.
    pub session_id: u32,
    /// Outages of the link or the core, and how each ended (protocol/PROTOCOL.md §8).
    pub outages: Vec<Outage>,
    /// Attached to a running core: the first sample sent, the one after the core's last.
    pub attached_at: Option<usize>,
    /// Attach asked for: what the tracker found, and what it did.
    pub attach_note: Option<String>,
    /// When the run started.
    pub started: Instant,
    /// How old the poses were when they came out, and the frames dropped.
    pub latency: Latencies,
}

impl Default for Record {
    /// An empty record, for the events of a run to fill ([`Detail::Started`] first).
    fn default() -> Self {
        Self::new(HandEye::IDENTITY, 0, (Vector3::zeros(), 0.0))
    }
}

impl Record {
    /// An empty record of a run with the core's mount `core_hand_eye`, named `session_id`.
    pub fn new(core_hand_eye: HandEye, session_id: u32, axes: (Vector3<f64>, f64)) -> Self {
        Self {
            core_hand_eye,
            origin_ns: None,
            clock: Vec::new(),
            assessments: BTreeMap::new(),
            verdicts: BTreeMap::new(),
            rule: TrackedRule::default(),
            log: CoreLog::default(),
            frames: Vec::new(),
            results: Vec::new(),
            frame_errors: Vec::new(),
            sent_correspondences: 0,
            axes,
            searches: Vec::new(),
            recoveries: Vec::new(),
            database: None,
            tilt: TiltRecord::default(),
            session_id,
            outages: Vec::new(),
            attached_at: None,
            attach_note: None,
            started: Instant::now(),
            latency: Latencies::default(),
        }
    }

    /// Keeps what `event` tells of the run (its details; the other events repeat them).
    pub fn observe(&mut self, event: &Event) {
        if let Event::Detail(d) = event {
            self.keep(d);
        }
    }

    /// Keeps what the events tell, in order.
    pub fn observe_all<'a>(&mut self, events: impl IntoIterator<Item = &'a Event>) {
        for e in events {
            self.observe(e);
        }
    }

    /// Keeps one detail.
    fn keep(&mut self, detail: &Detail) {
        match detail {
            Detail::Started {
                core_hand_eye,
                session_id,
                axes,
                rule,
                at,
            } => {
                self.core_hand_eye = *core_hand_eye;
                self.session_id = *session_id;
                self.axes = *axes;
                self.rule = *rule;
                self.started = *at;
            }
            Detail::Origin(t_ns) => self.origin_ns = Some(*t_ns),
            Detail::Clock(t_ns) => self.clock.push(*t_ns),
            Detail::Core(item) => self.log.take(item.clone()),
            Detail::HellosResent(n) => self.log.resent_hellos += n,
            Detail::Taken { index, t_ns } => self.take_frame(*index, *t_ns),
            Detail::Settled { index, fate } => self.settle(*index, *fate),
            Detail::Analysed {
                frame_id,
                result,
                sent,
            } => {
                self.sent_correspondences += sent;
                self.push_result(*frame_id, (**result).clone());
            }
            Detail::FrameError(why) => self.frame_errors.push((self.results.len(), why.clone())),
            Detail::Judged {
                frame_id,
                assessment,
                tracked,
            } => {
                self.assessments.insert(*frame_id, *assessment);
                self.verdicts.insert(*frame_id, *tracked);
            }
            Detail::Search { lost_at, search } => self.record_search(*lost_at, **search),
            Detail::Database(from) => self.keep_provenance(Some(from.clone())),
            Detail::RecoveryEnded(t_us) => self.end_recovery(*t_us),
            Detail::Tilt(note) => self.tilt.apply(note),
            Detail::Outage(o) => self.outages.push(o.clone()),
            Detail::AttachedAt(k) => self.attached_at = Some(*k),
            Detail::AttachNote(note) => self.attach_note = Some(note.clone()),
            Detail::Session(id) => self.session_id = *id,
            Detail::Latency(note, at) => self.latency.apply(*note, *at),
            Detail::End { interrupted } => {
                if !interrupted {
                    self.close_outages();
                }
            }
        }
    }

    /// Fills in, from the statuses, when the core reported `Tracking` again after each
    /// outage.
    fn close_outages(&mut self) {
        for o in &mut self.outages {
            let Some(resumed) = o.resumed_s else {
                continue;
            };
            o.tracking_s = self
                .log
                .statuses
                .iter()
                .map(|s| (s.t_us as f64 / 1e6, s.mode))
                .find(|&(t, m)| t >= resumed && m == Mode::Tracking)
                .map(|(t, _)| t);
        }
    }

    /// A frame taken: its fate is [`Fate::Unsettled`] until [`Self::settle`] says more.
    pub fn take_frame(&mut self, index: usize, t_ns: i64) {
        self.frames.push(TakenFrame {
            index,
            t_ns,
            fate: Fate::Unsettled,
        });
    }

    /// What became of the frame `index` (the last one taken with that index). An outcome
    /// replaces a fate it is [more certain than](Fate::replaces).
    pub fn settle(&mut self, index: usize, fate: Fate) {
        if let Some(f) = self.frames.iter_mut().rev().find(|f| f.index == index)
            && fate.replaces(&f.fate)
        {
            f.fate = fate;
        }
    }

    /// A frame's analysis, with the id the core gave it: kept, and its frame settled.
    pub fn push_result(&mut self, frame_id: u32, result: FrameResult) {
        self.settle(result.job.index, Fate::Analysed);
        self.results.push((frame_id, result));
    }

    /// The direction `pose`, of covariance `cov`, is pinned down least, in units of the
    /// rule's bounds, about the model's centre (docs/VISION.md eq. T7).
    pub fn weakest(&self, pose: &CameraPose, cov: &PoseCovariance) -> WeakDirection {
        crate::judge::weakest(&self.rule, &self.axes.0, pose, cov)
    }

    /// Seconds since the run started.
    pub fn elapsed(&self) -> f64 {
        self.started.elapsed().as_secs_f64()
    }

    /// Records a search: the start's (`lost_at` `None`), or a recovery's for the loss since
    /// `lost_at` [µs].
    pub fn record_search(&mut self, lost_at: Option<u64>, search: Search) {
        match lost_at {
            None => self.searches.push(search),
            Some(us) => self.record_recovery(us as f64 * 1e-6, search),
        }
    }

    /// Records a recovery search for a loss that began at `lost_at` [s]: one record per loss,
    /// also where tracking came back by itself before the search's answer arrived (live), in
    /// which case the loss ended at whichever came first.
    pub fn record_recovery(&mut self, lost_at: f64, search: Search) {
        let found = search.attempt.accepted().then_some(search.t);
        let same = |r: &Recovery| (r.lost_at - lost_at).abs() < 1e-9;
        let index = match self.recoveries.iter().rposition(same) {
            Some(i) => i,
            None => {
                self.recoveries.push(Recovery {
                    lost_at,
                    searches: Vec::new(),
                    ended_at: None,
                });
                self.recoveries.len() - 1
            }
        };
        let r = &mut self.recoveries[index];
        r.searches.push(search);
        if let Some(t) = found {
            r.ended_at = Some(r.ended_at.map_or(t, |e| e.min(t)));
        }
    }

    /// Keeps where the searches' database came from, told by the attempt that loaded it.
    pub fn keep_provenance(&mut self, from: Option<locate::database::Provenance>) {
        if self.database.is_none() {
            self.database = from;
        }
    }

    /// Closes an open recovery: tracking came back by itself at `t_us`.
    pub fn end_recovery(&mut self, t_us: u64) {
        if let Some(r) = self.recoveries.last_mut().filter(|r| r.ended_at.is_none()) {
            r.ended_at = Some(t_us as f64 * 1e-6);
        }
    }

    /// Whether the frame `frame_id` counts as tracked: judged so by the run
    /// ([`Self::verdicts`]), and not withheld by the tilt branch. `None` where it was not
    /// judged.
    pub fn tracked(&self, frame_id: u32) -> Option<bool> {
        self.verdicts
            .get(&frame_id)
            .map(|&t| t && !self.tilt.withheld.contains(&frame_id))
    }

    /// How many of the frames judged count as tracked ([`Self::tracked`]): `(tracked,
    /// judged)`.
    pub fn tracked_count(&self) -> (usize, usize) {
        let judged: Vec<bool> = self
            .results
            .iter()
            .filter_map(|(id, _)| self.tracked(*id))
            .collect();
        (judged.iter().filter(|&&t| t).count(), judged.len())
    }
}

/// A frame the tracker took, and what became of it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct TakenFrame {
    /// Its index in the input.
    pub index: usize,
    /// Its time stamp [ns, the input's clock].
    pub t_ns: i64,
    /// What became of it.
    pub fate: Fate,
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Issue 54, point 3: every frame taken ends with one outcome, the surest one said of it.
    #[test]
    fn a_frames_fate_is_the_surest_outcome_said_of_it() {
        let mut r = Record::new(HandEye::IDENTITY, 1, (Vector3::zeros(), 0.1));
        for i in 0..4 {
            r.take_frame(i, i as i64 * 1000);
        }
        r.settle(0, Fate::Searched);
        r.settle(0, Fate::NoPrediction);
        r.settle(1, Fate::NoPrediction);
        r.settle(1, Fate::Analysed);
        r.settle(2, Fate::Unusable);
        r.settle(2, Fate::Searched);
        // Settling a frame never taken changes nothing.
        r.settle(9, Fate::Analysed);
        let fates: Vec<Fate> = r.frames.iter().map(|f| f.fate).collect();
        assert_eq!(
            fates,
            [
                Fate::Searched,
                Fate::Analysed,
                Fate::Unusable,
                Fate::Unsettled
            ]
        );
        // A frame pushed twice with one index: the later one is settled.
        r.take_frame(3, 5000);
        r.settle(3, Fate::NoPrediction);
        assert_eq!(r.frames[3].fate, Fate::Unsettled);
        assert_eq!(r.frames[4].fate, Fate::NoPrediction);
    }
}
