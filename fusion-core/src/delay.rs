//! Delayed correspondences: snapshots at camera triggers and the IMU samples since, so that a
//! frame's correspondences, arriving after the core has integrated later samples, update the
//! state at the trigger time and are re-propagated to the present (docs/FILTER.md §8).

use heapless::Deque;

use crate::filter::{Filter, ImuSample, StepKernel};
use crate::params::Params;
use crate::quat::Quat;
use crate::scalar::Scalar;
use crate::state::StateVec;
use protocol::StatusReason;

/// IMU samples kept: 64 at 200 Hz is 320 ms, at 100 Hz 640 ms of correspondence latency.
pub const IMU_BUFFER: usize = 64;

/// Camera frames awaiting correspondences at once: 4 at 25 Hz is 160 ms, at 20 Hz 200 ms.
pub const MAX_PENDING_FRAMES: usize = 4;

const _: () = assert!(IMU_BUFFER >= 20, "at least 100 ms at 200 Hz");

/// Whether sequence number `a` comes before `b` (wrapping).
fn before(a: u32, b: u32) -> bool {
    let d = b.wrapping_sub(a);
    d != 0 && d < u32::MAX / 2
}

/// One buffered IMU sample with its sequence number.
#[derive(Clone, Copy, Debug)]
struct Record<T: Scalar> {
    seq: u32,
    sample: ImuSample<T>,
}

/// The filter at a camera trigger.
#[derive(Clone, Debug)]
pub struct Snapshot<T: Scalar> {
    /// Frame id given in the pose prediction.
    pub frame_id: u32,
    /// Trigger time stamp [µs].
    pub t_us: u64,
    /// Sequence number of the trigger's IMU sample.
    seq: u32,
    /// The filter right after the trigger sample (updated by the frame's correspondences, and
    /// refreshed when an older frame's update is re-propagated through it).
    pub filter: Filter<T>,
    /// The mean as predicted for the host (for the prediction error: before any update).
    pub predicted: StateVec<T>,
    /// The quaternion before the frame's first part: the covariance's tangent plane is its
    /// until the frame's updates end, so every correct update of the frame steps perpendicular
    /// to it, and the quaternion test judges the frame's updates from it (docs/FILTER.md §6).
    /// Set by the device at the first part.
    pub q_ref: Quat<T>,
    /// Parts applied so far (bit per part).
    pub parts_done: u8,
    /// Applied parts whose effect has not yet been propagated to the present.
    pub dirty: bool,
}

/// Why a frame's snapshot is not available.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Missing {
    /// It was dropped: its samples left the buffer, or newer frames replaced it.
    TooOld,
    /// No such frame was predicted.
    Unknown,
}

/// IMU ring buffer and snapshots.
#[derive(Clone, Debug)]
pub struct DelayLine<T: Scalar> {
    records: Deque<Record<T>, IMU_BUFFER>,
    snapshots: Deque<Snapshot<T>, MAX_PENDING_FRAMES>,
    next_seq: u32,
    next_frame_id: u32,
}

impl<T: Scalar> Default for DelayLine<T> {
    fn default() -> Self {
        Self::new()
    }
}

impl<T: Scalar> DelayLine<T> {
    /// Empty.
    pub const fn new() -> Self {
        DelayLine {
            records: Deque::new(),
            snapshots: Deque::new(),
            next_seq: 0,
            next_frame_id: 0,
        }
    }

    /// Drops all samples and snapshots (frame ids keep counting, so late answers to old frames
    /// are still recognised as too old).
    pub fn clear(&mut self) {
        self.records.clear();
        self.snapshots.clear();
    }

    /// The dirty snapshot that the next [`Self::push`] or [`Self::snapshot`] would drop, if any:
    /// the caller re-propagates it first so that no applied update is lost.
    pub fn expiring_dirty(&self, taking_snapshot: bool) -> Option<u32> {
        let oldest = self.snapshots.front()?;
        let drops_record = self.records.is_full()
            && self
                .records
                .front()
                .is_some_and(|r| before(oldest.seq, r.seq));
        let drops_snapshot = taking_snapshot && self.snapshots.is_full();
        ((drops_record || drops_snapshot) && oldest.dirty).then_some(oldest.frame_id)
    }

    /// Buffers a sample that the live filter has just applied.
    pub fn push(&mut self, sample: ImuSample<T>) {
        if self.records.is_full()
            && let Some(gone) = self.records.pop_front()
        {
            // A snapshot at seq k needs samples k+1.. to re-propagate.
            while self
                .snapshots
                .front()
                .is_some_and(|s| before(s.seq, gone.seq))
            {
                self.snapshots.pop_front();
            }
        }
        let seq = self.next_seq;
        self.next_seq = self.next_seq.wrapping_add(1);
        // Cannot fail: a slot was freed above.
        let _ = self.records.push_back(Record { seq, sample });
    }

    /// Takes a snapshot of the live filter at the last pushed sample; returns its frame id.
    pub fn snapshot(&mut self, filter: &Filter<T>) -> u32 {
        if self.snapshots.is_full() {
            self.snapshots.pop_front();
        }
        let frame_id = self.next_frame_id;
        self.next_frame_id = self.next_frame_id.wrapping_add(1);
        let snap = Snapshot {
            frame_id,
            t_us: filter.t_us,
            seq: self.next_seq.wrapping_sub(1),
            filter: Filter::idle(),
            predicted: filter.st.x,
            q_ref: filter.st.q(),
            parts_done: 0,
            dirty: false,
        };
        // Cannot fail: a slot was freed above. The covariance is copied in place afterwards.
        if self.snapshots.push_back(snap).is_ok()
            && let Some(s) = self.snapshots.back_mut()
        {
            s.filter.copy_from(filter);
        }
        frame_id
    }

    /// The snapshot of `frame_id` taken at `t_us`.
    pub fn find(&mut self, frame_id: u32, t_us: u64) -> Result<&mut Snapshot<T>, Missing> {
        let next = self.next_frame_id;
        match self.snapshots.iter_mut().find(|s| s.frame_id == frame_id) {
            Some(s) if s.t_us == t_us => Ok(s),
            Some(_) => Err(Missing::Unknown),
            // Frame ids count up from 0 (wrapping): an id already handed out is too old.
            None if before(frame_id, next) => Err(Missing::TooOld),
            None => Err(Missing::Unknown),
        }
    }

    /// Whether a frame newer than `frame_id` already had correspondences applied: updating
    /// `frame_id` now would overwrite them when re-propagating, so it is refused as too old.
    pub fn newer_frame_applied(&self, frame_id: u32) -> bool {
        self.snapshots
            .iter()
            .any(|s| before(frame_id, s.frame_id) && s.parts_done != 0)
    }

    /// Frame ids of dirty snapshots, oldest first.
    pub fn dirty_frames(&self) -> impl Iterator<Item = u32> + '_ {
        self.snapshots
            .iter()
            .filter(|s| s.dirty)
            .map(|s| s.frame_id)
    }

    /// Re-propagates `frame_id`'s snapshot through the buffered samples after it into `live`
    /// (the filter at the present); later snapshots on the way are refreshed (their predicted
    /// means, already sent to the host, stay). Returns `None` if the frame has no snapshot
    /// (then `live` is untouched). The time updates it runs are added to `steps` (saturating):
    /// at most [`IMU_BUFFER`] samples of [`crate::filter::MAX_STEPS_PER_SAMPLE`] each. Copies go
    /// field by field, never through a stack temporary: the firmware's stack is small.
    pub fn repropagate(
        &mut self,
        frame_id: u32,
        prm: &Params<T>,
        live: &mut Filter<T>,
        steps: &mut u32,
    ) -> Option<Result<(), StatusReason>>
    where
        T: StepKernel,
    {
        let start = self.snapshots.iter().position(|s| s.frame_id == frame_id)?;
        let seq = {
            let s = self.snapshots.iter_mut().nth(start)?;
            s.dirty = false;
            live.copy_from(&s.filter);
            s.seq
        };
        for rec in self.records.iter().filter(|r| before(seq, r.seq)) {
            if let Err(reason) = live.imu_step_counted(prm, &rec.sample, steps) {
                return Some(Err(reason));
            }
            if let Some(later) = self
                .snapshots
                .iter_mut()
                .skip(start + 1)
                .find(|s| s.seq == rec.seq)
            {
                later.filter.copy_from(live);
            }
        }
        Some(Ok(()))
    }
}

#[cfg(test)]
mod tests {
    extern crate std;
    use std::vec::Vec;

    use nalgebra::Vector3;
    use protocol::{InitAttitude, ModelKind};

    use super::*;
    use crate::init::{StillWindow, initial_state};
    use crate::state::State;
    use crate::testutil::params;

    /// Issue 17 (long runs): frame ids and IMU sequence numbers are `u32`s that wrap (after
    /// 2³² frames, or 2³² samples: 50 days at 1 kHz). Across the wrap the snapshots are found,
    /// ids handed out before are too old and ids not yet handed out unknown, the order of
    /// frames holds, and re-propagation walks the samples after a snapshot in order.
    #[test]
    fn frame_ids_and_sample_numbers_keep_their_order_across_the_u32_wrap() {
        let prm = params::<f64>(ModelKind::Acc);
        let still = ImuSample {
            t_us: 0,
            gyro: Vector3::new(0.01, -0.02, 0.005),
            accel: Vector3::new(0.1, -0.2, 9.81),
        };
        let mut window = StillWindow::default();
        window.add(&still.gyro, &still.accel, 1);
        let st = initial_state(&prm, &Vector3::zeros(), &InitAttitude::Gravity, &window);
        let mut live = Filter::new(st, 0);
        let mut line = DelayLine::<f64>::new();
        // Sample numbers wrap between the 41st and 42nd sample, frame ids at the fourth frame.
        line.next_seq = u32::MAX - 40;
        line.next_frame_id = u32::MAX - 2;
        let mut frames = Vec::new();
        for k in 1..=60u64 {
            let s = ImuSample {
                t_us: k * 5_000,
                gyro: Vector3::new(0.3 * (k as f64 * 0.1).sin(), 0.1, -0.2),
                accel: Vector3::new(0.5, 0.2 * (k as f64 * 0.2).cos(), 9.7),
            };
            live.imu_step(&prm, &s).unwrap();
            line.push(s);
            if k % 10 == 0 {
                frames.push((line.snapshot(&live), live.t_us));
            }
        }
        let ids: Vec<u32> = frames.iter().map(|f| f.0).collect();
        assert_eq!(ids, [u32::MAX - 2, u32::MAX - 1, u32::MAX, 0, 1, 2]);
        // The last four are kept; the first two were replaced and are too old.
        for &(id, t) in &frames[..2] {
            assert_eq!(line.find(id, t).err(), Some(Missing::TooOld), "frame {id}");
        }
        for &(id, t) in &frames[2..] {
            assert!(line.find(id, t).is_ok(), "frame {id}");
        }
        assert_eq!(line.find(3, 0).err(), Some(Missing::Unknown));
        assert_eq!(line.find(1000, 0).err(), Some(Missing::Unknown));
        // Order across the wrap: an update to frame 1 makes u32::MAX's too old, not 2's.
        if let Ok(s) = line.find(1, frames[4].1) {
            s.parts_done = 1;
        }
        assert!(line.newer_frame_applied(u32::MAX));
        assert!(line.newer_frame_applied(0));
        assert!(!line.newer_frame_applied(2));
        // Re-propagating the oldest kept snapshot (frame u32::MAX, at sample number
        // u32::MAX - 11) through the 30 samples after it, across the sample numbers' wrap,
        // gives the present again.
        let mut again = Filter::new(State::zeroed(), 0);
        let replayed = line.repropagate(u32::MAX, &prm, &mut again, &mut 0);
        assert_eq!(replayed, Some(Ok(())));
        assert_eq!(again.t_us, live.t_us);
        assert_eq!(again.st.x, live.st.x);
        assert_eq!(again.st.p, live.st.p);
    }
}
