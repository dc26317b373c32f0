//! The searches for the model (the cold start, [`locate`]) and the losses they end.

/// One cold-start attempt of a tracking run.
#[derive(Debug, Clone, Copy)]
pub struct Search {
    /// The frame's index in the input.
    pub index: usize,
    /// Its time [s from the first frame].
    pub t: f64,
    /// Time of the attempt's stages on the vision thread [ms]: detection, matching, RANSAC
    /// and verification, not the database's load or build (once, before the first attempt).
    pub ms: f64,
    /// What it found.
    pub attempt: locate::Attempt,
    /// When its pose was given to the core [s from the first frame]: at a later frame (or
    /// sample) than its own where the answer came while the frames went on; `None` where
    /// it found none.
    pub applied_at: Option<f64>,
}

impl Search {
    /// The search of `attempt` on frame `index` at `t_us`.
    pub fn new(index: usize, t_us: u64, attempt: locate::Attempt) -> Self {
        let t = &attempt.times;
        Self {
            index,
            t: t_us as f64 * 1e-6,
            ms: (t.detect + t.matching + t.ransac + t.verify + t.choose) * 1e3,
            attempt,
            applied_at: None,
        }
    }

    /// Its pose given to the core at `t_us`.
    pub fn applied(mut self, t_us: u64) -> Self {
        self.applied_at = self.attempt.pose.map(|_| t_us as f64 * 1e-6);
        self
    }
}

/// A loss and its searches.
#[derive(Debug, Clone)]
pub struct Recovery {
    /// Since when the frames were not tracked [s from the first frame].
    pub lost_at: f64,
    /// The attempts, in order.
    pub searches: Vec<Search>,
    /// When it ended [s]: by a pose found (the last search's), or by tracking coming back by
    /// itself; `None` while still lost at the end of the run.
    pub ended_at: Option<f64>,
}
