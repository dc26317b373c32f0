//! When to fire the camera, and on which sample's time stamp (issue 55, point 5).
//!
//! The pulse must go out when the sample it is paired with is taken: the `Trigger` message
//! carries that sample's time, and the filter predicts the pose there. Fired by the main loop
//! when it reads the FIFO, the pulse left 0 to ~4 ms after its sample (the loop's latency: USB,
//! a frame's correspondences), a jitter no calibration removes. So the path **arms a timer**
//! ([`TriggerOutput::arm`], an output compare on the core's clock) for the predicted time of the
//! sample the trigger is due on (the last stamped sample plus whole periods at the measured
//! rate), and pairs the trigger with the sample stamped nearest that time when it is read. Only
//! a trigger that cannot be predicted (the first after the host's choice, with no sample stamped
//! before it) fires from the loop at once ([`TriggerOutput::fire_now`]), with the newest
//! sample.
//!
//! Counting: with every `every`-th sample a trigger, the next is due `every` samples after the
//! last triggered one; it is armed at the read after which the next read might come too late
//! (within `batch` samples, the reads' usual size), and later than due when the loop was so
//! late that the due sample's time is already past (then the next sample that can be reached).

/// The camera's trigger line, driven by a timer on the core's clock.
pub trait TriggerOutput {
    /// Why the line could not be driven.
    type Error: core::fmt::Debug;
    /// Arms one pulse to rise at core time `at_us` (an output compare), so that it rises then
    /// whatever the main loop is doing. `at_us` is in the future (at least [`ARM_LEAD_US`]).
    fn arm(&mut self, at_us: u64) -> Result<(), Self::Error>;
    /// Fires one pulse now.
    fn fire_now(&mut self) -> Result<(), Self::Error>;
}

/// How far ahead of the timer a pulse is armed at least [µs]: the time to program the compare.
/// A due sample closer than this is given up for the next one.
pub const ARM_LEAD_US: u64 = 50;

/// The trigger plan of one sampling choice.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct TriggerPlan {
    every: u16,
    /// Samples read since the last triggered one (None: none triggered since the choice).
    since: Option<u32>,
    /// The core time a pulse is armed for, not yet paired with its sample.
    armed: Option<u64>,
}

/// What a read's samples get from the plan.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Paired {
    /// The index (in the read) of the sample the trigger goes with, if one does.
    pub index: Option<usize>,
    /// The pulse was fired from the loop now (no prediction), not by the timer.
    pub fired_now: bool,
}

impl TriggerPlan {
    /// The host's choice: a trigger every `every` samples (0: none). A new choice counts from
    /// here; a pulse already armed still rises, and is paired with its sample.
    pub fn choose(&mut self, every: u16) {
        if every != self.every {
            self.every = every;
            self.since = None;
        }
    }

    /// The armed pulse's time, if one is armed and not yet paired.
    pub fn armed(&self) -> Option<u64> {
        self.armed
    }

    /// Takes a read's samples (their core times, `valid` telling which may carry a trigger)
    /// under the host's choice `every` (0: no triggers): pairs an armed pulse with the sample
    /// stamped nearest its time (within half a `period_us`; a pulse whose sample was lost
    /// goes with the next valid one), or, with no prediction possible, fires now with the
    /// newest valid sample.
    pub fn take<O: TriggerOutput>(
        &mut self,
        every: u16,
        times: &[u64],
        valid: impl Fn(usize) -> bool,
        period_us: u64,
        output: &mut O,
    ) -> Result<Paired, O::Error> {
        self.choose(every);
        let mut paired = Paired::default();
        if let Some(at) = self.armed {
            let from = at.saturating_sub(period_us / 2);
            if let Some(i) = (0..times.len()).find(|&i| times[i] >= from && valid(i)) {
                paired.index = Some(i);
                self.armed = None;
            }
        } else if every != 0 && self.since.is_none() {
            // Nothing to predict from: fire now, with the newest sample.
            if let Some(i) = (0..times.len()).rev().find(|&i| valid(i)) {
                output.fire_now()?;
                paired = Paired {
                    index: Some(i),
                    fired_now: true,
                };
            }
        }
        let n = times.len() as u32;
        self.since = match (paired.index, self.since) {
            (Some(i), _) if every != 0 => Some(n - 1 - i as u32),
            (_, Some(s)) => Some(s.saturating_add(n)),
            (_, None) => None,
        };
        Ok(paired)
    }

    /// After a read (or at the loop's turn): arms the next pulse if it is due within `batch`
    /// samples of the newest stamped one (at `newest_us`), at its predicted time, or at the
    /// first sample after it that lies at least [`ARM_LEAD_US`] after `now_us`. With no trigger
    /// yet since the choice, the next sample is due. Returns the time armed for.
    pub fn plan<O: TriggerOutput>(
        &mut self,
        newest_us: u64,
        now_us: u64,
        period_us: u64,
        batch: u32,
        output: &mut O,
    ) -> Result<Option<u64>, O::Error> {
        if self.every == 0 || self.armed.is_some() || period_us == 0 {
            return Ok(None);
        }
        let ahead = match self.since {
            Some(s) => u32::from(self.every).saturating_sub(s).max(1),
            None => 1,
        };
        if ahead > batch.max(1) {
            return Ok(None);
        }
        let mut at = newest_us.saturating_add(u64::from(ahead) * period_us);
        let earliest = now_us.saturating_add(ARM_LEAD_US);
        if at < earliest {
            // Whole periods on to the first sample that can be reached.
            at = at.saturating_add((earliest - at).div_ceil(period_us) * period_us);
        }
        output.arm(at)?;
        self.armed = Some(at);
        Ok(Some(at))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Records what the plan asked of the line.
    #[derive(Default)]
    struct Line {
        armed: [u64; 8],
        n_armed: usize,
        fired_now: u32,
    }

    impl TriggerOutput for Line {
        type Error = ();
        fn arm(&mut self, at_us: u64) -> Result<(), ()> {
            self.armed[self.n_armed] = at_us;
            self.n_armed += 1;
            Ok(())
        }
        fn fire_now(&mut self) -> Result<(), ()> {
            self.fired_now += 1;
            Ok(())
        }
    }

    const T: u64 = 5_000;

    #[test]
    fn every_kth_sample_is_armed_ahead_and_paired_with_its_sample() {
        let mut plan = TriggerPlan::default();
        let mut line = Line::default();
        let mut triggered = [false; 13];
        for (k, trig) in triggered.iter_mut().enumerate() {
            let t = 1_000_000 + k as u64 * T;
            let p = plan.take(4, &[t], |_| true, T, &mut line).unwrap();
            *trig = p.index.is_some();
            // The loop reads 300 µs after the sample.
            plan.plan(t, t + 300, T, 1, &mut line).unwrap();
        }
        let k = [true, false, false, false];
        assert_eq!(triggered[..12], [k, k, k].concat()[..]);
        // The first fired from the loop (nothing to predict from), the others armed.
        assert_eq!(line.fired_now, 1);
        assert_eq!(line.armed[..3], [1_020_000, 1_040_000, 1_060_000]);
    }

    #[test]
    fn a_late_loop_arms_the_first_sample_it_can_reach() {
        let mut plan = TriggerPlan::default();
        let mut line = Line::default();
        let t0 = 1_000_000;
        plan.take(2, &[t0], |_| true, T, &mut line).unwrap();
        // Due next (sample 2 at t0 + 10 ms); the loop reads sample 1 only at t0 + 9.98 ms.
        plan.take(2, &[t0 + T], |_| true, T, &mut line).unwrap();
        let at = plan.plan(t0 + T, t0 + 9_980, T, 1, &mut line).unwrap();
        assert_eq!(at, Some(t0 + 3 * T));
        // Samples 2 and 3 read together: the pulse goes with sample 3.
        let p = plan
            .take(2, &[t0 + 2 * T, t0 + 3 * T], |_| true, T, &mut line)
            .unwrap();
        assert_eq!(p.index, Some(1));
    }

    #[test]
    fn batches_arm_when_the_next_read_would_be_too_late() {
        let mut plan = TriggerPlan::default();
        let mut line = Line::default();
        let t = |k: u64| 1_000_000 + k * T;
        // Reads of 2 samples, a trigger every 4: samples 1 (fired now), then 5, 9.
        let mut paired = [None; 6];
        for (r, p) in paired.iter_mut().enumerate() {
            let k = 2 * r as u64;
            let times = [t(k), t(k + 1)];
            *p = plan
                .take(4, &times, |_| true, T, &mut line)
                .unwrap()
                .index
                .map(|i| k + i as u64);
            plan.plan(t(k + 1), t(k + 1) + 100, T, 2, &mut line)
                .unwrap();
        }
        assert_eq!(paired, [Some(1), None, Some(5), None, Some(9), None]);
    }

    #[test]
    fn an_armed_pulse_whose_sample_was_invalid_goes_with_the_next_valid_one() {
        let mut plan = TriggerPlan::default();
        let mut line = Line::default();
        for k in 0..3 {
            plan.take(3, &[k * T], |_| true, T, &mut line).unwrap();
            plan.plan(k * T, k * T + 10, T, 1, &mut line).unwrap();
        }
        assert_eq!(plan.armed(), Some(3 * T));
        let p = plan
            .take(3, &[3 * T, 4 * T], |i| i != 0, T, &mut line)
            .unwrap();
        assert_eq!(p.index, Some(1));
    }
}
