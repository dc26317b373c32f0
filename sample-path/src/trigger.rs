//! When to fire the camera: at the first interrupt by which `trigger_every` samples have come
//! since the last trigger, at that read's newest sample (the one the interrupt time stamps:
//! the pulse goes out at its time). With one interrupt per sample, or a watermark dividing
//! `trigger_every`, that is exactly every `trigger_every`-th sample; a late interrupt delays the
//! trigger to the sample it brings, and the `Trigger` message carries that sample's time.

/// Samples counted towards the next trigger.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct TriggerCount {
    every: u16,
    since: u32,
}

impl TriggerCount {
    /// Counts a read of `n` samples under `every` (0: no triggers); whether to fire now.
    pub fn due(&mut self, every: u16, n: u32) -> bool {
        if every != self.every {
            // A new choice of the host: count from here.
            *self = TriggerCount { every, since: 0 };
        }
        if every == 0 || n == 0 {
            return false;
        }
        let every = u32::from(every);
        // The first sample after the choice is a trigger (frame 0).
        let fire = self.since == 0 || self.since.saturating_add(n) > every;
        self.since = if fire {
            // Counted from the newest sample, which the trigger goes with.
            1
        } else {
            self.since + n
        };
        fire
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_kth_sample_fires_with_one_sample_per_read() {
        let mut t = TriggerCount::default();
        let fired: [bool; 12] = core::array::from_fn(|_| t.due(4, 1));
        let k = [true, false, false, false];
        assert_eq!(fired, [k, k, k].concat()[..]);
    }

    #[test]
    fn batches_fire_at_their_newest_sample_and_late_reads_delay_the_trigger() {
        let mut t = TriggerCount::default();
        // Watermark 2, a trigger every 4: samples 0(1st read: 1 sample), then pairs.
        assert!(t.due(4, 1));
        assert!(!t.due(4, 2));
        assert!(t.due(4, 2)); // samples 3, 4: fires at 4
        // A missed interrupt: 4 samples at once, fires at the newest.
        assert!(t.due(4, 4));
        assert!(!t.due(0, 3));
        assert!(t.due(5, 1));
    }
}
