//! How old a pose is when it comes out (docs/ARCHITECTURE.md, "Live tracking"): per frame,
//! from its capture (or, where the program gave none, from when it was pushed) to its
//! correspondences sent and to the pose estimated with them; per IMU sample, from when it was
//! sent to the core to the core's pose for it. Times are on this machine's monotonic clock.

use std::collections::{BTreeMap, VecDeque};
use std::time::Instant;

use crate::event::LatencyNote;

/// One frame's ages [ms since its capture].
#[derive(Debug, Clone, Copy)]
pub struct FrameLatency {
    /// When it was captured.
    pub captured: Instant,
    /// Its age when the tracker took it (pushed) [ms].
    pub taken_ms: f64,
    /// Its age when its correspondences were sent to the core [ms]; `None` when none were.
    pub sent_ms: Option<f64>,
    /// Its age when the pose estimated with it came out [ms]; `None` when none did.
    pub pose_ms: Option<f64>,
    /// Frames of the input between it and the frame taken before it, never seen.
    pub dropped_before: usize,
}

/// Percentiles of a set of latencies [ms].
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Percentiles {
    /// How many values.
    pub n: usize,
    /// Median.
    pub p50: f64,
    /// 95th percentile.
    pub p95: f64,
    /// 99th percentile.
    pub p99: f64,
    /// Largest.
    pub max: f64,
}

impl Percentiles {
    /// The percentiles of `values` (nearest rank); `None` when there are none.
    pub fn of(values: impl IntoIterator<Item = f64>) -> Option<Self> {
        let mut v: Vec<f64> = values.into_iter().filter(|x| x.is_finite()).collect();
        if v.is_empty() {
            return None;
        }
        v.sort_by(f64::total_cmp);
        let rank = |p: f64| v[((p * v.len() as f64).ceil() as usize).clamp(1, v.len()) - 1];
        Some(Self {
            n: v.len(),
            p50: rank(0.50),
            p95: rank(0.95),
            p99: rank(0.99),
            max: v[v.len() - 1],
        })
    }
}

impl std::fmt::Display for Percentiles {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "p50 {:.1} ms, p95 {:.1} ms, p99 {:.1} ms, max {:.1} ms ({} values)",
            self.p50, self.p95, self.p99, self.max, self.n
        )
    }
}

/// The latencies of a run.
#[derive(Debug, Default, Clone)]
pub struct Latencies {
    /// Per frame taken, by its index in its input.
    pub frames: BTreeMap<usize, FrameLatency>,
    /// IMU sample sent → the core's pose for it [ms], per sample.
    pub samples_ms: Vec<f64>,
    /// Samples sent whose pose has not come yet: their time [µs] and when they were sent.
    waiting: VecDeque<(u64, Instant)>,
    /// Frames whose correspondences went out and whose pose has not come yet, with the time
    /// [µs] of the core's last clock message before them: their pose is the first state
    /// report after it.
    awaiting_pose: Vec<(usize, u64)>,
    /// The index of the frame taken last.
    last_index: Option<usize>,
}

/// Milliseconds from `from` to `to`.
fn ms(from: Instant, to: Instant) -> f64 {
    to.saturating_duration_since(from).as_secs_f64() * 1e3
}

impl Latencies {
    /// Keeps what a note says happened at `now`.
    pub fn apply(&mut self, note: LatencyNote, now: Instant) {
        match note {
            LatencyNote::Taken { index, captured } => self.taken(index, captured, now),
            LatencyNote::Sent { index, after_us } => self.sent(index, after_us, now),
            LatencyNote::SampleSent(t_us) => self.sample_sent(t_us, now),
            LatencyNote::PoseOut(t_us) => self.pose_out(t_us, now),
        }
    }

    /// A frame taken at `now`, captured at `captured`.
    pub fn taken(&mut self, index: usize, captured: Instant, now: Instant) {
        // Indices count the input's frames from 0: the gaps are the frames never taken.
        let dropped_before = match self.last_index {
            Some(last) if index > last => index - last - 1,
            Some(_) => 0,
            None => index,
        };
        self.last_index = Some(index);
        self.frames.insert(
            index,
            FrameLatency {
                captured,
                taken_ms: ms(captured, now),
                sent_ms: None,
                pose_ms: None,
                dropped_before,
            },
        );
    }

    /// The correspondences of frame `index` sent at `now`, after the clock message at
    /// `after_us`: its pose is the core's first state report for a later time.
    pub fn sent(&mut self, index: usize, after_us: u64, now: Instant) {
        if let Some(f) = self.frames.get_mut(&index) {
            f.sent_ms = Some(ms(f.captured, now));
            self.awaiting_pose.push((index, after_us));
        }
    }

    /// A sample at `t_us` sent to the core at `now`.
    pub fn sample_sent(&mut self, t_us: u64, now: Instant) {
        self.waiting.push_back((t_us, now));
        // A core that reports no state (or none for a while) must not grow this without end.
        if self.waiting.len() > 4096 {
            self.waiting.pop_front();
        }
    }

    /// The core's state report for `t_us` came out at `now`: the pose of the samples up to
    /// it, and of the frames whose correspondences went out before it.
    pub fn pose_out(&mut self, t_us: u64, now: Instant) {
        while let Some(&(t, sent)) = self.waiting.front() {
            if t > t_us {
                break;
            }
            self.waiting.pop_front();
            if t == t_us {
                self.samples_ms.push(ms(sent, now));
            }
        }
        let frames = &mut self.frames;
        self.awaiting_pose.retain(|&(index, after_us)| {
            if t_us <= after_us {
                return true;
            }
            if let Some(f) = frames.get_mut(&index) {
                f.pose_ms = Some(ms(f.captured, now));
            }
            false
        });
    }

    /// Frames of the input never taken: the gaps between the indices of the frames taken.
    pub fn dropped(&self) -> usize {
        self.frames.values().map(|f| f.dropped_before).sum()
    }

    /// Capture → pose over the frames with a pose.
    pub fn capture_to_pose(&self) -> Option<Percentiles> {
        Percentiles::of(self.frames.values().filter_map(|f| f.pose_ms))
    }

    /// Capture → correspondences sent.
    pub fn capture_to_sent(&self) -> Option<Percentiles> {
        Percentiles::of(self.frames.values().filter_map(|f| f.sent_ms))
    }

    /// Capture → taken: the age of the frames analysed.
    pub fn age_taken(&self) -> Option<Percentiles> {
        Percentiles::of(self.frames.values().map(|f| f.taken_ms))
    }

    /// IMU sample → pose.
    pub fn sample_to_pose(&self) -> Option<Percentiles> {
        Percentiles::of(self.samples_ms.iter().copied())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentiles_are_nearest_rank() {
        let p = Percentiles::of((1..=100).map(f64::from)).unwrap();
        assert_eq!(
            (p.n, p.p50, p.p95, p.p99, p.max),
            (100, 50.0, 95.0, 99.0, 100.0)
        );
        let one = Percentiles::of([7.0]).unwrap();
        assert_eq!((one.p50, one.p99), (7.0, 7.0));
        assert!(Percentiles::of([f64::NAN]).is_none());
    }

    #[test]
    fn gaps_in_the_indices_are_dropped_frames() {
        let mut l = Latencies::default();
        let now = Instant::now();
        for i in [2, 3, 6, 7, 11] {
            l.taken(i, now, now);
        }
        assert_eq!(l.dropped(), 2 + 2 + 3);
        assert_eq!(l.frames[&2].dropped_before, 2);
        assert_eq!(l.frames[&11].dropped_before, 3);
    }

    #[test]
    fn a_pose_closes_the_samples_up_to_it_and_the_frames_sent() {
        let mut l = Latencies::default();
        let now = Instant::now();
        l.taken(0, now, now);
        l.sample_sent(10, now);
        l.sample_sent(20, now);
        l.sent(0, 10, now);
        l.pose_out(10, now);
        assert_eq!(l.samples_ms.len(), 1);
        assert!(
            l.frames[&0].pose_ms.is_none(),
            "the state at 10 µs came before the update"
        );
        l.pose_out(20, now);
        assert!(l.frames[&0].pose_ms.is_some());
        l.sample_sent(30, now);
        l.pose_out(40, now);
        assert_eq!(l.samples_ms.len(), 2, "no state for the sample at 30 µs");
    }
}
