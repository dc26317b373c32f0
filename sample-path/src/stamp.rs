//! Time stamps of the IMU's FIFO samples on the core's clock, PX4's way: one sample of a read is
//! stamped with the time of the interrupt it raised, the others back or forward from it by the
//! FIFO's own time stamps (the part's 16-bit counter), converted to the core's clock at the
//! measured rate. The same time stamps count the samples lost between two reads, whatever lost
//! them.
//!
//! Clocks: a *tick* is one count of the part's time-stamp counter, which runs on the IMU's
//! oscillator (as its output data rate does): nominally [`StampTick`] µs (32/30 µs on the
//! internal clock), but the oscillator drifts; `µs` are the core's. The stamper measures how
//! many core µs a tick lasts (the *rate*) over [`DRIFT_WINDOW_US`], and the sample period in
//! ticks from consecutive samples, so that neither the nominal tick nor the nominal ODR has
//! to be right for the counts to be.
//!
//! Which sample an interrupt stamps: the one whose predicted time (the last stamped sample plus
//! its ticks since, at the rate) lies within half a period of the interrupt's time. So an
//! interrupt that lands while the FIFO is read stamps its own sample whether or not that sample
//! made it into the read, and several interrupts served late at once stamp theirs. Without a
//! prediction (the first read, after a part reset, a long silence or before the rate is known
//! well enough) the newest interrupt stamps the newest sample.

use icm42688::StampTick;

/// Core µs over which the rate (the IMU's drift) is measured before the estimate is renewed:
/// long enough that the interrupt latency's jitter (a few µs) is below 1 ppm of it.
pub const DRIFT_WINDOW_US: u64 = 4_000_000;

/// How far the rate may be off before it was first measured [ppm]: the internal oscillator's
/// tolerance (±2 %).
const RATE_ERROR_UNMEASURED_PPM: u64 = 20_000;
/// How far the rate may be off while the first window fills [ppm] (see `EARLY_RATE_AFTER_US`).
const RATE_ERROR_EARLY_PPM: u64 = 2_000;
/// Core µs after which the first window's rate so far replaces the nominal one.
const EARLY_RATE_AFTER_US: u64 = 20_000;
/// How far a measured rate may be off [ppm]: drift of the oscillator within a window.
const RATE_ERROR_MEASURED_PPM: u64 = 500;

/// The 16-bit FIFO time stamp wraps every 65 536 ticks.
const WRAP: u64 = 1 << 16;

/// Fixed-point shift of the rate (core µs per tick) and of the period (ticks).
const Q: u32 = 32;

/// What stamping one read found.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Stamped {
    /// Samples lost before the read's first sample (from the time stamps).
    pub lost: u32,
    /// The core time [µs] of the last sample before the gap (when `lost > 0`).
    pub gap_from_us: u64,
    /// A new drift estimate was made with this read [ppm].
    pub drift_ppm: Option<i32>,
    /// The sample the time came from, and how it was chosen.
    pub anchor: Anchor,
}

/// Where a read's times come from.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Anchor {
    /// Nothing was stamped (an empty read).
    #[default]
    None,
    /// Sample `index` of the read is the one an interrupt's time was predicted for.
    Matched {
        /// The sample's index in the read.
        index: usize,
    },
    /// No prediction: the newest interrupt stamps the newest sample.
    Newest,
    /// The FIFO had filled and stopped, so its newest sample raised no interrupt of those
    /// known: the read's first sample is placed after the last stamped one by the part's
    /// ticks.
    Predicted,
    /// No interrupt: the newest sample is stamped with the time of the read (polling).
    Read,
}

/// The last sample stamped.
#[derive(Clone, Copy, Debug)]
struct Last {
    /// Its part time stamp (None after the part was reset: its counter restarted).
    stamp: Option<u16>,
    /// Its core time [µs].
    t_us: u64,
    /// Its unwrapped tick count since the counter was last known to restart.
    ticks: u64,
}

/// Stamps the samples of successive FIFO reads.
#[derive(Clone, Copy, Debug)]
pub struct Stamper {
    /// Nominal core µs per tick, Q32.
    nominal_q32: u64,
    /// Core µs per tick as measured (nominal until then), Q32.
    rate_q32: u64,
    /// Whether `rate_q32` was measured over a whole window.
    measured: bool,
    /// Whether `rate_q32` is the first window's so far.
    early: bool,
    /// The sample period in ticks, Q32: nominal, then measured.
    period_q32: u64,
    last: Option<Last>,
    /// Start of the drift window: core time and tick count of a matched sample.
    window: Option<(u64, u64)>,
    /// Ticks and periods of consecutive samples seen in the window.
    periods: (u64, u64),
    ppm: i32,
}

impl Stamper {
    /// A stamper for samples `period_part_us` apart on the part's clock (its ODR), whose
    /// counter ticks every `tick` µs of it.
    pub const fn new(period_part_us: u32, tick: StampTick) -> Self {
        let den = if tick.den == 0 { 1 } else { tick.den as u64 };
        let num = if tick.num == 0 { 1 } else { tick.num as u64 };
        let nominal_q32 = (num << Q) / den;
        Stamper {
            nominal_q32,
            rate_q32: nominal_q32,
            measured: false,
            early: false,
            period_q32: ((period_part_us as u64 * den) << Q) / num,
            last: None,
            window: None,
            periods: (0, 0),
            ppm: 0,
        }
    }

    /// The drift as last measured [ppm] (positive: the IMU runs fast).
    pub fn drift_ppm(&self) -> i32 {
        self.ppm
    }

    /// The sample period as last measured [ticks] (nominal until measured).
    pub fn period_ticks(&self) -> f64 {
        self.period_q32 as f64 / (1u64 << Q) as f64
    }

    /// The part was reset: its time-stamp counter restarted, so the next gap is measured on
    /// the core's clock, and the drift window starts again.
    pub fn part_restarted(&mut self) {
        if let Some(last) = &mut self.last {
            last.stamp = None;
        }
        self.window = None;
        self.periods = (0, 0);
    }

    /// Ticks to core µs at the rate.
    fn core_us(&self, ticks: u64) -> u64 {
        let t = (u128::from(ticks) * u128::from(self.rate_q32) + (1 << (Q - 1))) >> Q;
        u64::try_from(t).unwrap_or(u64::MAX)
    }

    /// Core µs to ticks at the rate.
    fn ticks(&self, core_us: u64) -> u64 {
        q_div(core_us, self.rate_q32)
    }

    /// The core time of the last sample stamped, if any.
    pub fn last_us(&self) -> Option<u64> {
        self.last.map(|l| l.t_us)
    }

    /// The sample period in core µs, at the measured rate.
    pub fn period_us(&self) -> u64 {
        let t = (u128::from(self.period_q32) * u128::from(self.rate_q32)) >> (2 * Q);
        u64::try_from(t).unwrap_or(u64::MAX).max(1)
    }

    /// Whole periods in `ticks`, rounded.
    fn periods_in(&self, ticks: u64) -> u64 {
        q_div(ticks, self.period_q32)
    }

    /// Stamps one read. `stamps` are the part time stamps of its samples, oldest first;
    /// `interrupts` the core times [µs] of the latest interrupts, oldest first, taken after the
    /// read (so that one landing during the read is among them); `read_us` the core time just
    /// after the read, which stamps the newest sample when there is no interrupt (polling).
    /// Writes each sample's core time to `out` (as many as `stamps`; strictly after the
    /// previous read's last).
    ///
    /// `full`: the FIFO filled (and, in stop-on-full mode, kept its oldest samples), so that the
    /// newest sample read is not the latest interrupt's.
    pub fn stamp(
        &mut self,
        stamps: &[u16],
        interrupts: &[u64],
        read_us: u64,
        full: bool,
        out: &mut [u64],
    ) -> Stamped {
        let n = stamps.len().min(out.len());
        let (Some(stamps), Some(out)) = (stamps.get(..n), out.get_mut(..n)) else {
            return Stamped::default();
        };
        if n == 0 {
            return Stamped::default();
        }
        // Ticks from the first sample of the read, into `out` for now.
        let mut rel = 0u64;
        let mut prev = stamps[0];
        for (o, &s) in out.iter_mut().zip(stamps) {
            rel += u64::from(s.wrapping_sub(prev));
            prev = s;
            *o = rel;
        }
        let span = rel;
        let (index, t_anchor, anchor) = self.anchor(stamps[0], out, interrupts, read_us, full);
        let rel_anchor = out[index];
        for o in out.iter_mut() {
            *o = if *o <= rel_anchor {
                t_anchor.saturating_sub(self.core_us(rel_anchor - *o))
            } else {
                t_anchor.saturating_add(self.core_us(*o - rel_anchor))
            };
        }

        let mut found = Stamped {
            anchor,
            ..Stamped::default()
        };
        let mut ticks_first = 0;
        if let Some(last) = self.last {
            let (intervals, gap_ticks) = match last.stamp {
                Some(ls) => {
                    let gap = self.unwrap(ls, stamps[0], out[0].saturating_sub(last.t_us));
                    (self.periods_in(gap), Some(gap))
                }
                // The counter restarted: the core's clock alone measures the gap.
                None => {
                    let since = out[0].saturating_sub(last.t_us);
                    let p = self.period_us();
                    ((since + p / 2) / p, None)
                }
            };
            if intervals > 1 {
                found.lost = u32::try_from(intervals - 1).unwrap_or(u32::MAX);
                found.gap_from_us = last.t_us;
            }
            match gap_ticks {
                Some(gap) => {
                    ticks_first = last.ticks + gap;
                    if intervals == 1 {
                        self.periods.0 += gap;
                        self.periods.1 += 1;
                    }
                }
                None => self.window = None,
            }
            // Never back in time: a stamp at or before the previous read's last moves just
            // after it (interrupt latency jitter larger than the sample interval).
            let mut floor = last.t_us;
            for t in out.iter_mut() {
                if *t <= floor {
                    *t = floor + 1;
                }
                floor = *t;
            }
        }
        if n > 1 {
            // Consecutive packets of one read are one period apart.
            self.periods.0 += span;
            self.periods.1 += n as u64 - 1;
        }
        // The rate is measured between matched samples; the first time also between newest
        // ones (a batch read before the rate is known cannot be matched: its error over the
        // batch may exceed a quarter period), which is right unless an interrupt landed
        // inside the window's last read (then the first estimate is off by a period over the
        // window, 1 250 ppm at 200 Hz, and the next one, matched, is right).
        let usable = match anchor {
            Anchor::Matched { .. } => true,
            Anchor::Newest => !self.measured,
            Anchor::None | Anchor::Read | Anchor::Predicted => false,
        };
        if usable {
            found.drift_ppm = self.measure(ticks_first + rel_anchor, out[index]);
        }
        self.last = Some(Last {
            stamp: Some(stamps[n - 1]),
            t_us: out[n - 1],
            ticks: ticks_first + span,
        });
        found
    }

    /// Which sample of the read gets which time: `(index, core time, how)`. `rel` holds each
    /// sample's ticks from the read's first.
    fn anchor(
        &self,
        first: u16,
        rel: &[u64],
        interrupts: &[u64],
        read_us: u64,
        full: bool,
    ) -> (usize, u64, Anchor) {
        let newest = rel.len() - 1;
        if full
            && let Some(Last {
                stamp: Some(ls),
                t_us,
                ..
            }) = self.last
        {
            // Nothing was lost before the oldest sample of a stopped FIFO: it follows the last
            // one read, within a wrap.
            let d16 = u64::from(first.wrapping_sub(ls));
            return (0, t_us.saturating_add(self.core_us(d16)), Anchor::Predicted);
        }
        let Some(&latest) = interrupts.last() else {
            return (newest, read_us, Anchor::Read);
        };
        let fallback = (newest, latest, Anchor::Newest);
        let Some(Last {
            stamp: Some(ls),
            t_us: last_t,
            ..
        }) = self.last
        else {
            return fallback;
        };
        let period = self.period_us();
        // The rough time of the first sample (the newest interrupt at the newest sample) is
        // within a period or so of the truth: it unwraps the 16-bit stamps when two periods
        // are shorter than a wrap.
        if self.ticks(2 * period) >= WRAP {
            return fallback;
        }
        let rough_first = latest.saturating_sub(self.core_us(rel[newest]));
        let gap = self.unwrap(ls, first, rough_first.saturating_sub(last_t));
        // A prediction is trusted while the rate's error over it is under a quarter period.
        let error_ppm = if self.measured {
            RATE_ERROR_MEASURED_PPM
        } else if self.early {
            RATE_ERROR_EARLY_PPM
        } else {
            RATE_ERROR_UNMEASURED_PPM
        };
        let reach = self.core_us(gap + rel[newest]);
        if u128::from(reach) * u128::from(error_ppm) >= u128::from(period) * 250_000 {
            return fallback;
        }
        let predicted = |i: usize| last_t.saturating_add(self.core_us(gap + rel[i]));
        for &t in interrupts.iter().rev() {
            // The sample whose predicted time is nearest `t`.
            let nearest = (0..rel.len()).min_by_key(|&i| predicted(i).abs_diff(t));
            if let Some(i) = nearest
                && predicted(i).abs_diff(t) < period / 2
            {
                return (i, t, Anchor::Matched { index: i });
            }
        }
        fallback
    }

    /// The ticks from stamp `from` to stamp `to`, `since_us` core µs apart: the 16-bit
    /// difference, unwrapped to the whole number of wraps that the core's clock says passed.
    fn unwrap(&self, from: u16, to: u16, since_us: u64) -> u64 {
        let d16 = u64::from(to.wrapping_sub(from));
        let est = self.ticks(since_us);
        let wraps = (est.saturating_sub(d16) + WRAP / 2) / WRAP;
        d16 + wraps * WRAP
    }

    /// Adds a matched sample (its tick count and core time) to the drift window; renews the
    /// rate, the drift and the period when the window is full.
    fn measure(&mut self, ticks: u64, t_us: u64) -> Option<i32> {
        let Some((t0, ticks0)) = self.window else {
            self.window = Some((t_us, ticks));
            self.periods = (0, 0);
            return None;
        };
        let core_us = t_us.saturating_sub(t0);
        let counted = ticks.saturating_sub(ticks0);
        if counted == 0 {
            return None;
        }
        let rate = q_div(core_us, counted).max(1);
        if core_us < DRIFT_WINDOW_US {
            // Until the first window is full, the rate so far (its error falls as the window
            // grows: 1 µs of interrupt jitter over 20 ms is 50 ppm): predictions from the
            // nominal tick would be off by the oscillator's tolerance, 200 µs a 10 ms period.
            if !self.measured && core_us >= EARLY_RATE_AFTER_US {
                self.rate_q32 = rate;
                self.early = true;
            }
            return None;
        }
        // The IMU fast: its ticks last fewer core µs than nominal.
        let ppm = (i128::from(self.nominal_q32) - i128::from(rate)) * 1_000_000 / i128::from(rate);
        let ppm = ppm.clamp(-100_000, 100_000) as i32;
        // A rate beyond the clamp is a wrong tick or clock source, not drift: keep what the
        // ticks say, report the clamp.
        self.rate_q32 = rate;
        self.measured = true;
        self.ppm = ppm;
        let (sum, count) = self.periods;
        if count >= 8 {
            self.period_q32 = u64::try_from((u128::from(sum) << Q) / u128::from(count))
                .unwrap_or(self.period_q32);
        }
        self.window = Some((t_us, ticks));
        self.periods = (0, 0);
        Some(self.ppm)
    }
}

/// `x · 2^32 / d` rounded, for a Q32 `d` (0 taken as 1): in 64-bit arithmetic while `x` is
/// below 2^31 (35 minutes of µs), since the Cortex-M4 divides 128-bit numbers in software.
fn q_div(x: u64, d: u64) -> u64 {
    let d = d.max(1);
    if x < 1 << 31 {
        ((x << (Q + 1)) / d).div_ceil(2)
    } else {
        let d = u128::from(d);
        u64::try_from(((u128::from(x) << Q) + d / 2) / d).unwrap_or(u64::MAX)
    }
}

#[cfg(test)]
mod tests;
