//! The core's clock: a free-running 32-bit counter at 1 MHz (TIM2 or TIM5 on an STM32F4)
//! extended to 64-bit microseconds, so that time stamps never wrap (a 32-bit µs counter wraps
//! every 71.6 minutes; `u64` µs, in 585 000 years).

/// Half the counter's range: a reading more than this ahead of the last is taken as one from
/// before it (an interrupt's time read before the main loop's last reading).
const HALF: u32 = 1 << 31;

/// A 32-bit 1 MHz counter extended to 64 bits. [`Clock64::extend`] must see the counter at
/// least once per half wrap (35.8 min): the sample path reads it at every IMU interrupt.
/// Readings may come slightly out of order (an interrupt's captured time handled after a
/// later reading of the main loop): one up to half a wrap behind the latest maps to its past.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Clock64 {
    last: u32,
    now: u64,
}

impl Clock64 {
    /// A clock whose first reading is taken as is (the counter started at boot).
    pub const fn new() -> Self {
        Clock64 { last: 0, now: 0 }
    }

    /// The 64-bit time [µs] of a raw 32-bit reading.
    pub fn extend(&mut self, raw: u32) -> u64 {
        let ahead = raw.wrapping_sub(self.last);
        if ahead < HALF {
            self.last = raw;
            self.now += u64::from(ahead);
            self.now
        } else {
            self.now
                .saturating_sub(u64::from(self.last.wrapping_sub(raw)))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_extended_clock_runs_on_across_wraps() {
        let mut c = Clock64::new();
        assert_eq!(c.extend(5), 5);
        assert_eq!(c.extend(HALF), u64::from(HALF));
        assert_eq!(c.extend(u32::MAX), u64::from(u32::MAX));
        assert_eq!(c.extend(3), (1 << 32) + 3);
        assert_eq!(c.extend(3), (1 << 32) + 3);
        // A reading from just before the latest: its own past, and the clock stays.
        assert_eq!(c.extend(u32::MAX - 1), (1 << 32) - 2);
        assert_eq!(c.extend(10), (1 << 32) + 10);
        assert_eq!(c.extend(HALF + 9), (1 << 32) + u64::from(HALF) + 9);
        assert_eq!(c.extend(2), (2 << 32) + 2);
    }
}
