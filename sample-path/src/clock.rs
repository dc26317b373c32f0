//! The core's clock: a free-running 32-bit counter at 1 MHz (TIM2 or TIM5 on an STM32F4)
//! extended to 64-bit microseconds, so that time stamps never wrap (a 32-bit µs counter wraps
//! every 71.6 minutes; `u64` µs, in 585 000 years).

/// A 32-bit 1 MHz counter extended to 64 bits. [`Clock64::extend`] must see the counter at
/// least once per wrap (71.6 min): the sample path reads it at every IMU interrupt.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Clock64 {
    last: u32,
    high: u64,
}

impl Clock64 {
    /// A clock whose first reading is taken as is (the counter started at boot).
    pub const fn new() -> Self {
        Clock64 { last: 0, high: 0 }
    }

    /// The 64-bit time [µs] of a raw 32-bit reading, taken after every earlier one.
    pub fn extend(&mut self, raw: u32) -> u64 {
        if raw < self.last {
            self.high += 1 << 32;
        }
        self.last = raw;
        self.high | u64::from(raw)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_extended_clock_runs_on_across_wraps() {
        let mut c = Clock64::new();
        assert_eq!(c.extend(5), 5);
        assert_eq!(c.extend(u32::MAX), u64::from(u32::MAX));
        assert_eq!(c.extend(3), (1 << 32) + 3);
        assert_eq!(c.extend(3), (1 << 32) + 3);
        assert_eq!(c.extend(2), (2 << 32) + 2);
    }
}
