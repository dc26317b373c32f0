//! The tracker's clocks, one per input mode, each owning its time base (the input's time
//! [ns] its times [µs] count from) and what waits on it:
//!
//! - [`FrameClock`]: without an IMU the frames are the clock; the core's clock is the ticks
//!   sent at them (protocol 2.1), never more than [`MAX_TICK_GAP_US`] apart;
//! - [`SampleClock`]: with an IMU its samples are the clock, and a frame waits for the sample
//!   that triggered it. Where the core samples its own IMU, its samples are counted here too,
//!   and `tracker::on_core` relates the core's clock to the input's (the offset from the
//!   first pair of frame and trigger) and holds the frames and triggers waiting for each
//!   other.

use crate::error::TrackerError;
use crate::settings::Frame;

/// Longest interval between two ticks [µs]: frames further apart (a stalled camera, dropped
/// frames) are bridged by ticks without a trigger, as the core refuses clock gaps of a
/// second.
pub const MAX_TICK_GAP_US: u64 = 500_000;

/// The vision-only clock: the frames' times, and the ticks sent at them.
#[derive(Debug, Default)]
pub(crate) struct FrameClock {
    /// The first frame taken [ns, the input's clock].
    origin_ns: Option<i64>,
    /// The last tick's time [µs].
    last_us: Option<u64>,
}

impl FrameClock {
    /// The input's time the run's times count from [ns], once a frame set it.
    pub fn origin_ns(&self) -> Option<i64> {
        self.origin_ns
    }

    /// The last tick's time [µs].
    pub fn last_us(&self) -> Option<u64> {
        self.last_us
    }

    /// The time of frame `index` at `t_ns` [µs from the first frame taken, which sets the
    /// origin]: after the last tick, which is 1 µs past the last frame.
    pub fn time_of(&mut self, index: usize, t_ns: i64) -> Result<u64, TrackerError> {
        let t0 = *self.origin_ns.get_or_insert(t_ns);
        let t_us = t_ns.saturating_sub(t0) / 1000;
        if let Some(last) = self.last_us
            && t_us <= last as i64 + 1
        {
            return Err(TrackerError::TimeBackwards {
                what: format!("frame {index}"),
                t_us,
                previous_us: last.saturating_sub(1) as i64,
            });
        }
        Ok(u64::try_from(t_us).unwrap_or(0))
    }

    /// The ticks without a trigger that bridge the gap from the last tick to `t_us`.
    pub fn bridge(&self, t_us: u64) -> Vec<u64> {
        let mut ticks = Vec::new();
        if let Some(mut at) = self.last_us {
            while t_us - at > MAX_TICK_GAP_US {
                at += MAX_TICK_GAP_US;
                ticks.push(at);
            }
        }
        ticks
    }

    /// A tick was sent at `t_us`: its stamp [ns, the input's clock].
    pub fn ticked(&mut self, t_us: u64) -> u64 {
        self.last_us = Some(t_us);
        self.stamp_ns(t_us)
    }

    /// The input's stamp [ns] of the run's time `t_us`.
    pub fn stamp_ns(&self, t_us: u64) -> u64 {
        u64::try_from(self.origin_ns.unwrap_or(0)).unwrap_or(0) + t_us * 1000
    }
}

/// The clock of a run with an IMU: its samples, counted, and the frame waiting for the next.
#[derive(Debug, Default)]
pub(crate) struct SampleClock {
    /// The first sample pushed [ns, the input's clock].
    origin_ns: Option<i64>,
    /// The last sample pushed [ns].
    last_ns: Option<u64>,
    /// Samples taken so far (the next one's index).
    k: usize,
    /// The frame waiting for its trigger, the next sample pushed.
    queued: Option<Frame>,
}

impl SampleClock {
    /// The input's time the run's times count from [ns], once a sample set it.
    pub fn origin_ns(&self) -> Option<i64> {
        self.origin_ns
    }

    /// The next sample's index.
    pub fn next_index(&self) -> usize {
        self.k
    }

    /// Refuses a pushed sample at `t_ns` not after the one before.
    pub fn check(&self, t_ns: u64) -> Result<(), TrackerError> {
        match self.last_ns {
            Some(last) if t_ns <= last => {
                let t0 = self.origin_ns.unwrap_or(0);
                Err(TrackerError::TimeBackwards {
                    what: "IMU sample".into(),
                    t_us: (t_ns as i64 - t0) / 1000,
                    previous_us: (last as i64 - t0) / 1000,
                })
            }
            _ => Ok(()),
        }
    }

    /// Takes the pushed sample at `t_ns` (the first sets the origin): its index, its time [µs
    /// from the first sample], and the frame it triggered.
    pub fn take(&mut self, t_ns: u64) -> (usize, u64, Option<Frame>) {
        let t0 = *self
            .origin_ns
            .get_or_insert(i64::try_from(t_ns).unwrap_or(i64::MAX));
        let t0 = u64::try_from(t0).unwrap_or(0);
        self.last_ns = Some(t_ns);
        let t_us = (t_ns - t0) / 1000;
        (self.count(), t_us, self.queued.take())
    }

    /// Counts a sample (pushed, or the core's own): its index.
    pub fn count(&mut self) -> usize {
        self.k += 1;
        self.k - 1
    }

    /// A frame waits for its trigger, the next sample; one already waiting had none.
    pub fn queue(&mut self, frame: Frame) -> Result<(), TrackerError> {
        if self.queued.is_some() {
            return Err(TrackerError::NoTrigger { index: frame.index });
        }
        self.queued = Some(frame);
        Ok(())
    }
}
