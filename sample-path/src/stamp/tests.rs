use super::*;

/// The internal clock's tick, 32/30 µs.
const PLL: StampTick = StampTick { num: 16, den: 15 };
/// A 1 µs tick (CLKIN at 32 768 Hz).
const US: StampTick = StampTick {
    num: 32_768,
    den: 32_768,
};

/// A part at `ppm` (positive: fast) whose counter ticks every `tick` µs of its own clock, sampling
/// every `period_us` of it; the core's clock starts at 1 s.
struct Part {
    period_us: u64,
    tick: StampTick,
    ppm: i64,
}

impl Part {
    /// Core time of sample `k` [µs].
    fn core(&self, k: u64) -> u64 {
        1_000_000 + k * self.period_us * 1_000_000 / (1_000_000 + self.ppm) as u64
    }
    /// The 16-bit FIFO stamp of sample `k`, as the silicon counts (`SimIcm42688`'s rule).
    fn stamp(&self, k: u64) -> u16 {
        let part_us = 5_000 + k * self.period_us;
        (u128::from(part_us) * u128::from(self.tick.den) / u128::from(self.tick.num)) as u16
    }
    fn stamps<const N: usize>(&self, first: u64) -> [u16; N] {
        core::array::from_fn(|i| self.stamp(first + i as u64))
    }
}

#[test]
fn the_interrupted_sample_gets_the_interrupts_time_and_the_others_the_fifos_intervals() {
    let p = Part {
        period_us: 10_000,
        tick: US,
        ppm: 0,
    };
    let mut s = Stamper::new(10_000, US);
    let mut out = [0; 3];
    let found = s.stamp(&p.stamps::<3>(0), &[p.core(2)], 0, false, &mut out);
    assert_eq!(out, [p.core(0), p.core(1), p.core(2)]);
    assert_eq!((found.lost, found.anchor), (0, Anchor::Newest));
    let found = s.stamp(&p.stamps::<1>(3), &[p.core(3)], 0, false, &mut out[..1]);
    assert_eq!((out[0], found.lost), (p.core(3), 0));
    assert_eq!(found.anchor, Anchor::Matched { index: 0 });
    // Three samples never read, across the 16-bit wrap.
    let found = s.stamp(&p.stamps::<1>(7), &[p.core(7)], 0, false, &mut out[..1]);
    assert_eq!(
        (out[0], found.lost, found.gap_from_us),
        (p.core(7), 3, p.core(3))
    );
}

#[test]
fn a_gap_longer_than_the_16_bit_wrap_is_counted_from_the_cores_clock() {
    let p = Part {
        period_us: 10_000,
        tick: PLL,
        ppm: 0,
    };
    let mut s = Stamper::new(10_000, PLL);
    let mut out = [0; 1];
    s.stamp(&p.stamps::<1>(0), &[p.core(0)], 0, false, &mut out);
    // 1.28 s later (128 samples): the stamps wrapped 18 times.
    let found = s.stamp(&p.stamps::<1>(128), &[p.core(128)], 0, false, &mut out);
    assert_eq!(found.lost, 127);
    // After a part reset the stamps restart: the core's clock alone measures the gap.
    s.part_restarted();
    let found = s.stamp(&[7], &[p.core(133)], 0, false, &mut out);
    assert_eq!(found.lost, 4);
}

/// Issue 55, point 2: the FIFO's tick is 32/30 µs on the internal clock. Taken as 1 µs, the
/// drift read −62 500 ppm, lost counts were wrong from 8 samples up (8 → 7, 50 → 47, 127 →
/// 132, 300 → 294) and back-stamps within a batch were 6.25 % short.
#[test]
fn the_pll_tick_gives_true_back_stamps_drift_and_lost_counts() {
    for ppm in [-20_000i64, 0, 300, 20_000] {
        for lost in [1u64, 8, 50, 127, 300] {
            let p = Part {
                period_us: 5_000,
                tick: PLL,
                ppm,
            };
            let mut s = Stamper::new(5_000, PLL);
            let mut out = [0u64; 10];
            // A first batch of ten: back-stamped from the newest before any drift estimate.
            s.stamp(&p.stamps::<10>(0), &[p.core(9)], 0, false, &mut out);
            for (k, t) in out.iter().enumerate() {
                let tol = 2 + (p.core(9) - p.core(k as u64)) * ppm.unsigned_abs() / 1_000_000;
                assert!(t.abs_diff(p.core(k as u64)) <= tol, "{ppm}: {k} {t}");
            }
            // 5 s of batches: the drift is measured.
            let mut measured = None;
            for batch in 1..100u64 {
                let found = s.stamp(
                    &p.stamps::<10>(batch * 10),
                    &[p.core(batch * 10 + 9)],
                    0,
                    false,
                    &mut out,
                );
                assert_eq!(found.lost, 0);
                measured = found.drift_ppm.or(measured);
            }
            let m = i64::from(measured.expect("measured"));
            assert!((m - ppm).abs() <= 2, "{ppm} ppm measured as {m}");
            let k = 999 + lost + 1;
            let found = s.stamp(&p.stamps::<1>(k), &[p.core(k)], 0, false, &mut out[..1]);
            assert_eq!(u64::from(found.lost), lost, "{ppm} ppm");
        }
    }
}

/// Issue 55, point 8: the 16-bit stamps were unwrapped with a slow IMU taken as on time
/// (`ppm.max(0)`): at −20 000 ppm a 3 s gap counted 307 samples lost for 300, 5 s 513 for 500.
/// Exact now, at either sign of drift, over gaps of 0.1-10 s, with the internal clock's tick.
#[test]
fn lost_samples_are_counted_exactly_across_long_gaps_at_any_drift() {
    for ppm in [-20_000i64, -300, 0, 300, 20_000] {
        for gap in [10u64, 299, 300, 500, 1000] {
            let p = Part {
                period_us: 10_000,
                tick: PLL,
                ppm,
            };
            let mut s = Stamper::new(10_000, PLL);
            let mut out = [0u64; 10];
            for batch in 0..50u64 {
                s.stamp(
                    &p.stamps::<10>(batch * 10),
                    &[p.core(batch * 10 + 9)],
                    0,
                    false,
                    &mut out,
                );
            }
            assert!(
                (i64::from(s.drift_ppm()) - ppm).abs() <= 2,
                "{ppm}: {}",
                s.drift_ppm()
            );
            let k = 499 + gap + 1;
            let found = s.stamp(&p.stamps::<1>(k), &[p.core(k)], 0, false, &mut out[..1]);
            assert_eq!(found.lost as u64, gap, "{ppm} ppm, {gap} samples");
        }
    }
}

/// With CLKIN the tick is one µs of the input clock: at 32 000 Hz it lasts 1.024 µs.
#[test]
fn a_clkin_tick_scales_with_the_input_clock() {
    let tick = StampTick {
        num: 32_768,
        den: 32_000,
    };
    let p = Part {
        period_us: 5_000,
        tick,
        ppm: 150,
    };
    let mut s = Stamper::new(5_000, tick);
    let mut out = [0u64; 4];
    for batch in 0..300u64 {
        s.stamp(
            &p.stamps::<4>(batch * 4),
            &[p.core(batch * 4 + 3)],
            0,
            false,
            &mut out,
        );
    }
    assert!((s.drift_ppm() - 150).abs() <= 2, "{}", s.drift_ppm());
    assert!((s.period_ticks() - 5_000.0 * 32_000.0 / 32_768.0).abs() < 0.01);
    let found = s.stamp(
        &p.stamps::<1>(1199 + 64),
        &[p.core(1199 + 64)],
        0,
        false,
        &mut out[..1],
    );
    assert_eq!(found.lost, 63);
}

/// Issue 55, point 4: the loop takes the interrupt's time, then reads the FIFO; a sample whose
/// interrupt lands between the two was stamped with the older interrupt's time (samples 100
/// and 101 came out 1 495 001 and 1 500 000 µs for 1 500 000 and 1 505 000). Each now gets its
/// own interrupt's, whether the new sample made it into the read or not.
#[test]
fn an_interrupt_landing_inside_a_read_stamps_its_own_sample() {
    let p = Part {
        period_us: 5_000,
        tick: PLL,
        ppm: 0,
    };
    for in_read in [true, false] {
        let mut s = Stamper::new(5_000, PLL);
        let mut out = [0u64; 2];
        for k in 0..100u64 {
            s.stamp(&p.stamps::<1>(k), &[p.core(k)], 0, false, &mut out[..1]);
        }
        // Sample 100's interrupt is served; sample 101 arrives while the FIFO is read, and its
        // interrupt (taken after the read) is the newest.
        let irqs = [p.core(99), p.core(100), p.core(101)];
        if in_read {
            let found = s.stamp(&p.stamps::<2>(100), &irqs, 0, false, &mut out);
            // To the stamps' tick (1.07 µs).
            assert!(
                out[0].abs_diff(p.core(100)) <= 1 && out[1] == p.core(101),
                "{out:?}"
            );
            assert_eq!(found.anchor, Anchor::Matched { index: 1 });
        } else {
            let found = s.stamp(&p.stamps::<1>(100), &irqs, 0, false, &mut out[..1]);
            assert_eq!(out[0], p.core(100));
            assert_eq!(found.anchor, Anchor::Matched { index: 0 });
            // The next read has sample 101 alone, its interrupt among the latest.
            let found = s.stamp(&p.stamps::<1>(101), &irqs, 0, false, &mut out[..1]);
            assert_eq!(out[0], p.core(101));
            assert_eq!(
                (found.anchor, found.lost),
                (Anchor::Matched { index: 0 }, 0)
            );
        }
    }
}

/// Issue 55, point 7: the polling fallback (no interrupt) stamps the newest sample with the
/// time of the read, not of the loop's turn before it.
#[test]
fn a_read_without_interrupts_is_stamped_at_the_read() {
    let mut s = Stamper::new(5_000, PLL);
    let mut out = [0u64; 2];
    let found = s.stamp(&[0, 4_688], &[], 1_234_567, false, &mut out);
    assert_eq!(found.anchor, Anchor::Read);
    assert_eq!(out[1], 1_234_567);
    assert_eq!(out[1] - out[0], 5_001); // 4 688 ticks of 32/30 µs
}

/// Issue 55, point 9: in stop-on-full mode a full FIFO keeps its oldest samples, so the newest
/// one read raised none of the interrupts known: the read follows the last one by the ticks,
/// and the loss shows at the next read.
#[test]
fn a_stopped_full_fifo_is_placed_after_the_last_read() {
    let p = Part {
        period_us: 5_000,
        tick: PLL,
        ppm: 0,
    };
    let mut s = Stamper::new(5_000, PLL);
    let mut out = [0u64; 128];
    for k in 0..100u64 {
        s.stamp(&p.stamps::<1>(k), &[p.core(k)], 0, false, &mut out[..1]);
    }
    // Samples 100..228 fill the FIFO; 228..250 are dropped; the loop reads at sample 250.
    let irqs = [p.core(247), p.core(248), p.core(249), p.core(250)];
    let found = s.stamp(&p.stamps::<128>(100), &irqs, 0, true, &mut out);
    assert_eq!((found.anchor, found.lost), (Anchor::Predicted, 0));
    // At the rate measured so far (0.5 s of 1.07 µs ticks: a few ppm), over 0.64 s.
    for (i, t) in out.iter().enumerate() {
        assert!(t.abs_diff(p.core(100 + i as u64)) <= 5, "{i}: {t}");
    }
    let found = s.stamp(&p.stamps::<1>(251), &[p.core(251)], 0, false, &mut out[..1]);
    assert_eq!((out[0], found.lost), (p.core(251), 23));
}
