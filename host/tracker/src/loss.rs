//! The loss rule, one for every run (docs/notes/issue15-cold-start.md §6): the model is lost
//! after a divergence of the core, or when no frame has been tracked for [`LOST_AFTER_US`].
//! While lost, a search runs every [`SEARCH_EVERY`]-th frame, one at a time; a verified pose
//! ends the loss, and so does tracking that comes back by itself.

use protocol::{Mode, Status};

use crate::session::Recent;

/// Frames not tracked for this long [µs] (or a divergence) mean the model is lost: a hand
/// hides an object for longer than half a second only when it means to.
pub const LOST_AFTER_US: u64 = 500_000;

/// While lost, the frames between two searches: an attempt costs several frame periods, and
/// the frames between keep the loop going.
pub const SEARCH_EVERY: usize = 5;

/// The loss rule's state.
#[derive(Debug, Clone)]
pub struct LossRule {
    /// Since when no frame has been tracked [µs].
    untracked_since: Option<u64>,
    /// Whether the core diverged since a frame was last tracked.
    diverged: bool,
    /// The core's statuses already looked at ([`Recent::mark`]).
    statuses_seen: usize,
    /// Frames since the last search while lost.
    since_search: usize,
    /// A search was asked for ([`Self::force`]) and not sent yet: tracked frames do not end
    /// the loss before it goes (live, a tilt check may hold the search thread for a while).
    forced: bool,
}

impl Default for LossRule {
    fn default() -> Self {
        Self {
            untracked_since: None,
            diverged: false,
            statuses_seen: 0,
            since_search: SEARCH_EVERY,
            forced: false,
        }
    }
}

impl LossRule {
    /// Takes the core's statuses not yet seen: a divergence at `t_us` loses the model at
    /// once.
    pub(crate) fn note_statuses(&mut self, statuses: &Recent<Status>, t_us: u64) {
        if statuses
            .since(self.statuses_seen)
            .any(|s| s.mode == Mode::Diverged)
        {
            self.diverged = true;
            self.untracked_since.get_or_insert(t_us);
        }
        self.statuses_seen = statuses.mark();
    }

    /// Whether the model is lost at `t_us`.
    pub fn lost(&self, t_us: u64) -> bool {
        self.diverged
            || self
                .untracked_since
                .is_some_and(|since| t_us >= since + LOST_AFTER_US)
    }

    /// Whether the core diverged since a frame was last tracked.
    pub fn diverged(&self) -> bool {
        self.diverged
    }

    /// Since when no frame has been tracked [µs].
    pub fn untracked_since(&self) -> Option<u64> {
        self.untracked_since
    }

    /// The frame at `t_us` was tracked (`true`) or not.
    pub fn frame(&mut self, tracked: bool, t_us: u64) {
        if tracked && !self.forced {
            self.untracked_since = None;
            self.diverged = false;
        } else {
            self.untracked_since.get_or_insert(t_us);
        }
    }

    /// A search found the model, and the core was given its pose at `t_us`: the new start
    /// gets the same grace as a loss before it counts as lost (`Some`), or none is needed
    /// (`None`: the frames will tell).
    pub fn found(&mut self, grace_from_us: Option<u64>) {
        self.untracked_since = grace_from_us;
        self.diverged = false;
    }

    /// At a frame at `t_us` while the model is lost: whether a search is due, and if so since
    /// when the model is lost [µs]. `busy`: a search or a tilt check is already running.
    pub fn search_due(&mut self, t_us: u64, busy: bool) -> Option<u64> {
        if !self.lost(t_us) {
            return None;
        }
        if self.since_search >= SEARCH_EVERY && !busy {
            self.since_search = 0;
            self.forced = false;
            Some(self.untracked_since.unwrap_or(t_us))
        } else {
            self.since_search += 1;
            None
        }
    }

    /// Asks for a search at the next frame, whatever the frames say ([`crate::Tracker::relocate`]).
    pub fn force(&mut self, t_us: u64) {
        self.diverged = true;
        self.forced = true;
        self.untracked_since.get_or_insert(t_us);
        self.since_search = SEARCH_EVERY;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lost_after_half_a_second_untracked_then_a_search_after_every_five_frames() {
        let mut rule = LossRule::default();
        let period = 100_000;
        let mut due = Vec::new();
        for f in 0..20u64 {
            let t = f * period;
            if let Some(since) = rule.search_due(t, false) {
                due.push((f, since));
            }
            rule.frame(false, t);
        }
        // Untracked from frame 0, lost from frame 5 (0.5 s), then five frames between searches.
        assert_eq!(due, vec![(5, 0), (11, 0), (17, 0)]);
        rule.frame(true, 20 * period);
        assert!(!rule.lost(20 * period));
        assert_eq!(rule.search_due(20 * period, false), None);
    }

    #[test]
    fn a_divergence_loses_the_model_at_once_and_a_busy_search_thread_delays_the_next() {
        let mut rule = LossRule::default();
        let diverged = Status {
            t_us: 1_000,
            mode: Mode::Diverged,
            reason: protocol::StatusReason::ResidualLowpass,
        };
        let mut statuses = Recent::default();
        statuses.push(diverged);
        rule.note_statuses(&statuses, 1_000);
        assert!(rule.lost(1_000));
        assert_eq!(rule.search_due(1_000, true), None);
        assert_eq!(rule.search_due(2_000, false), Some(1_000));
        rule.found(Some(3_000));
        assert!(!rule.lost(3_000 + LOST_AFTER_US - 1));
        assert!(rule.lost(3_000 + LOST_AFTER_US));
    }

    #[test]
    fn a_forced_search_is_not_cancelled_by_tracked_frames_before_it_is_sent() {
        let mut rule = LossRule::default();
        rule.frame(true, 0);
        rule.force(0);
        // The search thread is busy (a tilt check): the frames go on being tracked.
        assert_eq!(rule.search_due(100, true), None);
        rule.frame(true, 100);
        assert!(rule.lost(200));
        assert_eq!(rule.search_due(200, false), Some(0));
        rule.frame(true, 200);
        assert!(!rule.lost(300));
    }
}
