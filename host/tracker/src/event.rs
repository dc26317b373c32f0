//! What the tracker tells ([`crate::Tracker::poll`]): poses, frames' outcomes, searches'
//! answers and its state.

use camera::{CameraPose, PoseCovariance, WeakDirection};
use protocol::Mode;

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
    /// [`Record::tracked`] is final.
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
#[derive(Debug, Clone, PartialEq)]
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
}
