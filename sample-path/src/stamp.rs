//! Time stamps of the IMU's FIFO samples on the core's clock, PX4's way: the newest sample of a
//! read is stamped with the interrupt's time, the older ones back from it by the FIFO's own
//! time stamps (the part's 16-bit µs counter), converted to the core's clock with the measured
//! drift. The same time stamps count the samples lost between two reads, whatever lost them.
//!
//! Clocks: `part µs` is the IMU's counter, which runs on the IMU's oscillator (as its output
//! data rate does); `µs` is the core's. With the IMU `ppm` fast, a part interval `d` lasts
//! `d · 10⁶ / (10⁶ + ppm)` of the core's µs.

/// Part µs over which the drift is measured before the estimate is renewed: long enough that
/// the interrupt latency's jitter (a few µs) is below 1 ppm of it.
pub const DRIFT_WINDOW_PART_US: u64 = 4_000_000;

/// The 16-bit FIFO time stamp wraps every 65.536 ms.
const WRAP: u64 = 1 << 16;

/// What stamping one read found.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Stamped {
    /// Samples lost before the read's first sample (from the time stamps).
    pub lost: u32,
    /// The core time [µs] of the last sample before the gap (when `lost > 0`).
    pub gap_from_us: u64,
    /// A new drift estimate was made with this read [ppm].
    pub drift_ppm: Option<i32>,
}

/// Stamps the samples of successive FIFO reads.
#[derive(Clone, Copy, Debug)]
pub struct Stamper {
    period_part_us: u32,
    /// The last stamped sample: its part time stamp (None after the part was reset: its
    /// counter restarted) and its core time.
    last: Option<(Option<u16>, u64)>,
    /// Start of the drift window: core time, and part µs counted since.
    window: Option<(u64, u64)>,
    ppm: i32,
}

impl Stamper {
    /// A stamper for samples `period_part_us` apart on the part's clock (its ODR).
    pub const fn new(period_part_us: u32) -> Self {
        Stamper {
            period_part_us,
            last: None,
            window: None,
            ppm: 0,
        }
    }

    /// The drift as last measured [ppm] (positive: the IMU runs fast).
    pub fn drift_ppm(&self) -> i32 {
        self.ppm
    }

    /// The part was reset: its time-stamp counter restarted, so the next gap is measured on
    /// the core's clock, and the drift window starts again.
    pub fn part_restarted(&mut self) {
        if let Some((_, t)) = self.last {
            self.last = Some((None, t));
        }
        self.window = None;
    }

    /// Core µs to part µs at the measured drift, either sign (a slow IMU counts fewer).
    fn part_us(&self, core_us: u64) -> u64 {
        let num = (1_000_000 + i64::from(self.ppm)).max(1) as u128;
        u64::try_from((u128::from(core_us) * num + 500_000) / 1_000_000).unwrap_or(u64::MAX)
    }

    /// Part µs to core µs at the measured drift.
    fn core_us(&self, part_us: u64) -> u64 {
        let den = (1_000_000 + i64::from(self.ppm)).max(1) as u64;
        (part_us * 1_000_000 + den / 2) / den
    }

    /// Stamps one read: `stamps` are the part time stamps of its samples, oldest first, and
    /// `t_irq_us` the core time of the interrupt that brought the newest. Writes each sample's
    /// core time to `out` (as many as `stamps`; strictly after the previous read's last).
    pub fn stamp(&mut self, stamps: &[u16], t_irq_us: u64, out: &mut [u64]) -> Stamped {
        let n = stamps.len().min(out.len());
        let mut found = Stamped::default();
        let Some(&newest) = stamps[..n].last() else {
            return found;
        };
        // Back from the newest by the part's own intervals (telescoped from the newest, so the
        // µs rounding of each stamp does not add up).
        let mut back = 0u64;
        let mut next = newest;
        for i in (0..n).rev() {
            back += u64::from(next.wrapping_sub(stamps[i]));
            next = stamps[i];
            out[i] = t_irq_us.saturating_sub(self.core_us(back));
        }
        let first = stamps[0];
        let mut part_elapsed = back;
        if let Some((last_stamp, last_t)) = self.last {
            let since_us = out[0].saturating_sub(last_t);
            let gap_part = match last_stamp {
                // The 16-bit difference, unwrapped to the whole number of wraps that the
                // core's clock says passed.
                Some(ls) => {
                    let d16 = u64::from(first.wrapping_sub(ls));
                    let est = self.part_us(since_us);
                    let wraps = (est.saturating_sub(d16) + WRAP / 2) / WRAP;
                    d16 + wraps * WRAP
                }
                None => since_us,
            };
            let period = u64::from(self.period_part_us.max(1));
            let intervals = (gap_part + period / 2) / period;
            if intervals > 1 {
                found.lost = u32::try_from(intervals - 1).unwrap_or(u32::MAX);
                found.gap_from_us = last_t;
            }
            if last_stamp.is_some() {
                part_elapsed += gap_part;
            } else {
                self.window = None;
            }
            // Never back in time: a stamp at or before the previous read's last moves just
            // after it (interrupt latency jitter larger than the sample interval).
            let mut floor = last_t;
            for t in &mut out[..n] {
                if *t <= floor {
                    *t = floor + 1;
                }
                floor = *t;
            }
        }
        found.drift_ppm = self.measure(part_elapsed, out[n - 1]);
        self.last = Some((Some(newest), out[n - 1]));
        found
    }

    /// Adds part µs and the core time they ended at to the drift window; renews the estimate
    /// when the window is full.
    fn measure(&mut self, part_us: u64, t_us: u64) -> Option<i32> {
        let Some((t0, counted)) = self.window else {
            self.window = Some((t_us, 0));
            return None;
        };
        let counted = counted + part_us;
        if counted < DRIFT_WINDOW_PART_US {
            self.window = Some((t0, counted));
            return None;
        }
        let core_us = t_us.saturating_sub(t0).max(1) as i64;
        let ppm = (counted as i64 - core_us) * 1_000_000 / core_us;
        self.ppm = ppm.clamp(-100_000, 100_000) as i32;
        self.window = Some((t_us, 0));
        Some(self.ppm)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_newest_sample_gets_the_interrupts_time_and_the_older_ones_the_fifos_intervals() {
        let mut s = Stamper::new(10_000);
        let mut out = [0; 3];
        let found = s.stamp(&[100, 10_100, 20_100], 1_000_000, &mut out);
        assert_eq!(out, [980_000, 990_000, 1_000_000]);
        assert_eq!(found.lost, 0);
        // The next read: one sample, 10 ms later, across the 16-bit wrap.
        let found = s.stamp(&[30_100], 1_010_000, &mut out[..1]);
        assert_eq!((out[0], found.lost), (1_010_000, 0));
        let stamp = (30_100u32 + 10_000 * 4) as u16; // wrapped
        let found = s.stamp(&[stamp], 1_050_000, &mut out[..1]);
        assert_eq!(
            (out[0], found.lost, found.gap_from_us),
            (1_050_000, 3, 1_010_000)
        );
    }

    #[test]
    fn a_gap_longer_than_the_16_bit_wrap_is_counted_from_the_cores_clock() {
        let mut s = Stamper::new(10_000);
        let mut out = [0; 1];
        s.stamp(&[0], 1_000_000, &mut out);
        // 1.28 s later (128 samples): the 16-bit stamps wrapped 19 times.
        let later = (1_280_000u64 % WRAP) as u16;
        let found = s.stamp(&[later], 2_280_000, &mut out);
        assert_eq!(found.lost, 127);
        // After a part reset the stamps restart: the core's clock alone measures the gap.
        s.part_restarted();
        let found = s.stamp(&[7], 2_330_000, &mut out);
        assert_eq!(found.lost, 4);
    }

    #[test]
    fn the_drift_is_measured_and_corrects_the_back_stamps() {
        // The IMU 300 ppm fast: its 10 000 part µs last 9 997 core µs.
        let mut s = Stamper::new(10_000);
        let core = |k: u64| 1_000_000 + k * 10_000 * 1_000_000 / 1_000_300;
        let mut out = [0u64; 10];
        let mut measured = None;
        for batch in 0..100u64 {
            let stamps: [u16; 10] =
                core::array::from_fn(|i| ((batch * 10 + i as u64) * 10_000 % WRAP) as u16);
            let found = s.stamp(&stamps, core(batch * 10 + 9), &mut out);
            measured = found.drift_ppm.or(measured);
            if batch > 50 {
                for (i, t) in out.iter().enumerate() {
                    let truth = core(batch * 10 + i as u64);
                    assert!(t.abs_diff(truth) <= 1, "{t} vs {truth}");
                }
            }
        }
        assert!(
            measured.is_some_and(|p| (p - 300).abs() <= 1),
            "{measured:?}"
        );
    }

    /// Issue 55, point 8: the 16-bit stamps were unwrapped with a slow IMU taken as on time
    /// (`ppm.max(0)`): at −20 000 ppm a 3 s gap counted 307 samples lost for 300, 5 s 513 for
    /// 500. Exact now, at either sign of drift, over gaps of 0.1-10 s.
    #[test]
    fn lost_samples_are_counted_exactly_across_long_gaps_at_any_drift() {
        for ppm in [-20_000i64, -300, 0, 300, 20_000] {
            for gap in [10u64, 299, 300, 500, 1000] {
                let mut s = Stamper::new(10_000);
                // Part µs of sample `k` last `1e6 / (1e6 + ppm)` core µs each.
                let core = |k: u64| 1_000_000 + k * 10_000 * 1_000_000 / (1_000_000 + ppm) as u64;
                let stamp = |k: u64| (k * 10_000 % WRAP) as u16;
                let mut out = [0u64; 10];
                // 5 s of batches: the drift is measured (a 4 s window).
                for batch in 0..50u64 {
                    let stamps: [u16; 10] = core::array::from_fn(|i| stamp(batch * 10 + i as u64));
                    s.stamp(&stamps, core(batch * 10 + 9), &mut out);
                }
                assert!(
                    (i64::from(s.drift_ppm()) - ppm).abs() <= 2,
                    "{ppm}: {}",
                    s.drift_ppm()
                );
                // Then `gap` samples never read.
                let k = 499 + gap + 1;
                let found = s.stamp(&[stamp(k)], core(k), &mut out[..1]);
                assert_eq!(found.lost as u64, gap, "{ppm} ppm, {gap} samples");
            }
        }
    }
}
