//! The search machine of every run (docs/notes/issue15-cold-start.md §6): *locating* until a
//! search verifies a pose (the cold start), then *started*; while the loss rule ([`LossRule`])
//! says lost, a search every few frames, one at a time on the search thread, until one
//! verifies a pose again.
//!
//! Vision-only, the loss rule takes the frames' verdicts (`loss.frame`); with an IMU, the
//! core's mode at each trigger ([`SearchMachine::at_trigger`]), beside the verdicts' own rule
//! that the state follows. The tracker sends what the machine asks for, and tells it what the
//! search thread answered.

use protocol::{Mode, Status};

use crate::loss::LossRule;
use crate::session::Recent;

/// A search sent to the search thread.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Job {
    /// The frame's index.
    pub index: usize,
    /// Its time (vision-only) or its trigger's (with an IMU) [µs].
    pub t_us: u64,
    /// With an IMU: the sample after which the answer is applied (lock-step); 0 vision-only.
    pub due: usize,
    /// Since when the model was lost [µs]; `None` for the start's search.
    pub lost_at: Option<u64>,
}

/// What to do at a trigger (with an IMU).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum AtTrigger {
    /// Send a search: for the start (`None`), or for the loss since this time [µs].
    Attempt(Option<u64>),
    /// The core is tracking.
    Tracking,
    /// Nothing.
    Wait,
}

/// The search machine.
#[derive(Debug)]
pub(crate) struct SearchMachine {
    /// Whether searches are run at all: always vision-only; with an IMU, in runs that start
    /// cold or were asked to relocate.
    active: bool,
    /// Whether a pose was given to the core (the start's, or a found one).
    started: bool,
    /// The search with the search thread.
    job: Option<Job>,
    /// The loss rule that sends the searches.
    pub(crate) loss: LossRule,
}

impl SearchMachine {
    /// A machine that runs searches (`active`), with the core given its start pose or not
    /// (`started`).
    pub fn new(active: bool, started: bool) -> Self {
        Self {
            active,
            started,
            job: None,
            loss: LossRule::default(),
        }
    }

    /// Whether searches are run.
    pub fn active(&self) -> bool {
        self.active
    }

    /// Whether the core has been given a pose.
    pub fn started(&self) -> bool {
        self.started
    }

    /// Whether the model is lost at `t_us`.
    pub fn lost(&self, t_us: u64) -> bool {
        self.loss.lost(t_us)
    }

    /// The search with the search thread.
    pub fn job(&self) -> Option<Job> {
        self.job
    }

    /// A search was sent.
    pub fn sent(&mut self, job: Job) {
        self.job = Some(job);
    }

    /// The search's answer came: it is no longer in flight.
    pub fn answered(&mut self) -> Option<Job> {
        self.job.take()
    }

    /// The start's search found the model, and the core was given its pose.
    pub fn start(&mut self) {
        self.started = true;
    }

    /// A search found the model, and the core was given its pose at `grace_from_us`: the new
    /// start gets the same grace as a loss before it counts as lost (`Some`), or none
    /// (`None`: the frames will tell).
    pub fn found(&mut self, grace_from_us: Option<u64>) {
        self.started = true;
        self.loss.found(grace_from_us);
    }

    /// Asks for a search at the next frame or trigger, as after a divergence at `t_us`
    /// ([`crate::Tracker::relocate`]).
    pub fn force(&mut self, t_us: u64) {
        self.active = true;
        self.started = true;
        self.loss.force(t_us);
    }

    /// Vision-only, at a frame at `t_us` while lost: whether a search is due, and since when
    /// the model is lost [µs] (`busy`: the search thread has a tilt check).
    pub fn due(&mut self, t_us: u64, busy: bool) -> Option<u64> {
        let busy = busy || self.job.is_some();
        self.loss.search_due(t_us, busy)
    }

    /// With an IMU, at a trigger at `t_us`: the loss rule updated from the core's statuses,
    /// and what to do.
    pub fn at_trigger(&mut self, statuses: &Recent<Status>, t_us: u64) -> AtTrigger {
        if !self.active {
            return AtTrigger::Wait;
        }
        self.loss.note_statuses(statuses, t_us);
        if !self.started {
            return match self.job {
                None => AtTrigger::Attempt(None),
                Some(_) => AtTrigger::Wait,
            };
        }
        let tracking = statuses.last().is_some_and(|s| s.mode == Mode::Tracking);
        if tracking && !self.loss.diverged() {
            self.loss.frame(true, t_us);
            return AtTrigger::Tracking;
        }
        self.loss.frame(false, t_us);
        match self.loss.search_due(t_us, self.job.is_some()) {
            Some(since) => AtTrigger::Attempt(Some(since)),
            None => AtTrigger::Wait,
        }
    }
}
