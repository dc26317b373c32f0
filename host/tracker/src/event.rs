//! What the tracker tells ([`crate::Tracker::poll`]): poses, frames' outcomes, searches'
//! answers and its state.

use std::time::Instant;

use camera::{CameraPose, PoseCovariance, WeakDirection};
use nalgebra::Vector3;
use protocol::Mode;
use serde::Serialize;
use vision::{Assessment, FrameResult, TrackedRule};

use crate::rig::HandEye;
use crate::search::Search;
use crate::tilt::TiltNote;
use crate::transport::Incoming;

/// Where the tracker stands (M3T's detecting, starting and tracking, with the loss).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum State {
    /// No pose yet: each frame gets a cold-start attempt.
    Locating,
    /// The core has a pose (given or found), and no frame has been tracked since.
    Starting,
    /// Frames are tracked (or were, less than the loss rule's half second ago).
    Tracking,
    /// The model is lost: searches run every few frames until one verifies a pose.
    Lost,
}

/// A camera pose estimated by the core.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    /// Its time [µs from the first frame].
    pub t_us: u64,
    /// The camera in the model's frame.
    pub camera: CameraPose,
    /// The core's mode then.
    pub mode: Option<Mode>,
    /// Its covariance (`[c_w, θ]`, docs/VISION.md eq. T6); `None` where the core's was not
    /// a covariance (never from a working core).
    pub cov: Option<PoseCovariance>,
}

/// What one frame gave.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameReport {
    /// The frame's index in its input.
    pub index: usize,
    /// Its time [µs from the first frame].
    pub t_us: u64,
    /// The pose its verdict is on, the core's pose at the frame's time: vision-only, the one
    /// estimated with the frame; with an IMU, the one put out at the frame's time (its
    /// prediction, with every earlier frame's update), as the frame's update is applied later.
    pub pose: Option<CameraPose>,
    /// Whether it counts as tracked (the tracked rule at that pose, docs/VISION.md §10); `None`
    /// where it was not analysed (no pose yet, or an unusable image). A later tilt check may still
    /// withhold it (the frames after a flip, until it is confirmed): the record's
    /// [`crate::record::Record::tracked`] is final.
    pub tracked: Option<bool>,
    /// Correspondences sent to the core, of both kinds (2D/3D and contour).
    pub correspondences: usize,
    /// The covariance of `pose` (`[c_w, θ]`, docs/VISION.md eq. T6).
    pub cov: Option<PoseCovariance>,
    /// Tracked, with this direction pinned down weakly: its σ is more than half the bound
    /// a right pose is held to (eq. T7); vision-only, more than the whole bound and the frame
    /// is not tracked (eq. T9). `None` where tracked with every direction pinned, and where not
    /// tracked.
    pub weak: Option<WeakDirection>,
}

/// What the tracker tells, in order ([`crate::Tracker::poll`]).
#[derive(Debug, Clone)]
pub enum Event {
    /// A pose of the core (two per frame: the prediction's time, and just after the update).
    Pose(Pose),
    /// A frame's outcome.
    Frame(FrameReport),
    /// A search's answer: its frame, and the pose it verified, if any.
    Located {
        /// The frame searched.
        index: usize,
        /// The verified pose.
        pose: Option<CameraPose>,
    },
    /// The state changed.
    State(State),
    /// A frame could not be used, and why (the tracker goes on).
    FrameSkipped {
        /// The frame's index in its input.
        index: usize,
        /// Why.
        why: String,
    },
    /// This many events were lost before this poll: the program did not poll for longer
    /// than [`crate::tracker::MAX_EVENTS`] events take (the oldest went).
    Missed(usize),
    /// What a run's report needs beyond the events above, in the order it happened: told
    /// only by a tracker asked for them ([`crate::TrackerBuilder::details`]), and kept by a
    /// [`crate::record::Record`] ([`crate::record::Record::observe`]).
    Detail(Box<Detail>),
}

/// What a run's report needs beyond the poses, frames and searches' answers: every message of
/// the core, every frame's analysis and judgement, the searches, the tilt checks, the
/// outages and the latencies. The tracker keeps none of it ([`crate::record`] does, from
/// these).
#[derive(Debug, Clone)]
pub enum Detail {
    /// The run started: what its report is relative to.
    Started {
        /// The mount the core was configured with (identity in vision-only runs).
        core_hand_eye: HandEye,
        /// The run's name for its configuration of the core.
        session_id: u32,
        /// Where the overlays draw the model's axes, and their length [m].
        axes: (Vector3<f64>, f64),
        /// The rule the verdicts are given by.
        rule: TrackedRule,
        /// When (the tracker's start).
        at: Instant,
    },
    /// The input's time [ns] the run's times [µs] count from.
    Origin(i64),
    /// A clock message sent: its time stamp [ns, the input's clock].
    Clock(u64),
    /// An item from the core (frame ids one per frame across cores that were reset).
    Core(Incoming),
    /// `Hello`s sent again on a lossy line.
    HellosResent(usize),
    /// A frame taken.
    Taken {
        /// Its index in the input.
        index: usize,
        /// Its time stamp [ns, the input's clock].
        t_ns: i64,
    },
    /// What became of the frame `index`, as far as known now.
    Settled {
        /// The frame's index.
        index: usize,
        /// Its fate.
        fate: Fate,
    },
    /// A frame's analysis, with the id the core gave it, and the correspondences sent.
    Analysed {
        /// The frame's id at the core.
        frame_id: u32,
        /// The analysis.
        result: Box<FrameResult>,
        /// Correspondences sent to the core (0 where none went).
        sent: usize,
    },
    /// A frame or trigger that could not be used, and why.
    FrameError(String),
    /// A frame's judgement at its pose.
    Judged {
        /// The frame's id at the core.
        frame_id: u32,
        /// What the judgement measured.
        assessment: Assessment,
        /// The verdict: tracked or not (before the tilt branch withholds any).
        tracked: bool,
    },
    /// A search's attempt: the start's (`lost_at` `None`), or a recovery's for the loss since
    /// `lost_at` [µs].
    Search {
        /// Since when the model was lost [µs].
        lost_at: Option<u64>,
        /// The attempt.
        search: Box<Search>,
    },
    /// Where the searches' database came from.
    Database(locate::database::Provenance),
    /// An open loss ended: tracking came back by itself at this time [µs].
    RecoveryEnded(u64),
    /// What a tilt check found and did.
    Tilt(TiltNote),
    /// An outage of the link or the core, resolved or (at the end) not.
    Outage(Outage),
    /// Attached to a running core: the first sample sent, the one after the core's last.
    AttachedAt(usize),
    /// Attach asked for: what the tracker found, and what it did.
    AttachNote(String),
    /// The session's id changed (attached to a running core's session).
    Session(u32),
    /// A moment a latency is measured from or to.
    Latency(LatencyNote, Instant),
    /// The run ended (`interrupted`: abandoned).
    End {
        /// Abandoned rather than finished.
        interrupted: bool,
    },
}

/// The moments of [`crate::latency::Latencies`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum LatencyNote {
    /// Frame `index`, captured at `captured`, was taken.
    Taken {
        /// The frame's index.
        index: usize,
        /// When it was captured.
        captured: Instant,
    },
    /// Frame `index`'s correspondences went out after the clock message at `after_us`.
    Sent {
        /// The frame's index.
        index: usize,
        /// The core's last clock message before them [µs].
        after_us: u64,
    },
    /// A sample at `t_us` was sent.
    SampleSent(u64),
    /// The core's state for `t_us` came out.
    PoseOut(u64),
}

/// What became of a frame the tracker took: every frame taken ends as one of these, so that a
/// run's outputs account for each.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Fate {
    /// Not settled when the run ended: it waited for its trigger, its prediction or its
    /// analysis (an interrupted run, an outage, the input's last frame).
    Unsettled,
    /// A search for the model (the cold start, or a recovery) ran on it instead of an
    /// analysis: the core had no pose to predict it at.
    Searched,
    /// The core predicted no pose for it: not initialised yet (the model not found, the
    /// search still running), or its prediction did not come in time.
    NoPrediction,
    /// Its image could not be used, or it was refused (size, time, no trigger): why is
    /// among [`crate::record::Record::frame_errors`].
    Unusable,
    /// Analysed at the core's prediction: its result is among [`crate::record::Record::results`].
    Analysed,
}

impl Fate {
    /// Its name in the outputs.
    pub fn name(self) -> &'static str {
        match self {
            Fate::Unsettled => "unsettled",
            Fate::Searched => "searched",
            Fate::NoPrediction => "no_prediction",
            Fate::Unusable => "unusable",
            Fate::Analysed => "analysed",
        }
    }

    /// Whether this outcome replaces `earlier`: anything replaces "unsettled"; an analysis
    /// or a refusal replaces anything; a frame searched stays so when no prediction came.
    pub fn replaces(self, earlier: &Fate) -> bool {
        match self {
            Fate::Analysed | Fate::Unusable => true,
            Fate::Searched | Fate::NoPrediction => *earlier == Fate::Unsettled,
            Fate::Unsettled => false,
        }
    }
}

/// What an outage of the link or the core turned out to be once the host reached the core
/// again (protocol/PROTOCOL.md §8).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum OutageKind {
    /// The core had lost its configuration (reset, or never configured by us): configured and
    /// initialised again from the last good pose.
    CoreReset,
    /// The core kept its state: it was sent the samples it missed and went on.
    LinkLost,
    /// Not resolved by the end of the run.
    Unresolved,
}

/// One outage of the link or the core, from its notice to the core's return.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Outage {
    /// What it was.
    pub kind: OutageKind,
    /// What revealed it.
    pub cause: String,
    /// The input's time of the sample being sent when it was noticed [s].
    pub noticed_s: f64,
    /// For an injected fault: when it was injected [s], and the wall-clock time until the
    /// host noticed it [ms].
    pub injected_s: Option<f64>,
    /// Wall-clock time from the injection to the notice [ms] (injected faults).
    pub notice_wall_ms: Option<f64>,
    /// Reconnection attempts (the last one succeeded, if it did).
    pub attempts: u32,
    /// Why the last failed attempt failed.
    pub last_failure: Option<String>,
    /// When the host reached the core again [s].
    pub resumed_s: Option<f64>,
    /// The device or address it reached it on (a serial pattern's match, say).
    pub resumed_on: Option<String>,
    /// Samples the core missed and was sent on its return (it dead-reckoned through them).
    pub backlog: usize,
    /// When the core reported `Tracking` again after the return [s].
    pub tracking_s: Option<f64>,
}
