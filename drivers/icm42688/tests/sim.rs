//! The driver against the simulated part: data round trip, time stamps, overflow, corruption,
//! power-on reset and repair, interrupts.

use core::cell::RefCell;

use embedded_hal::spi::SpiDevice;
use embedded_hal_mock::eh1::delay::NoopDelay;
use icm42688::registers as reg;
use icm42688::sim::SharedSim;
use icm42688::{
    AccelRange, Check, FifoRead, GyroRange, Icm42688, Interrupt, Odr, Packet, SIM_FIFO_CAPACITY,
    Settings, SimIcm42688,
};

const GYRO: [f64; 3] = [0.5, -1.25, 3.0];
const ACCEL: [f64; 3] = [0.1, -0.2, 9.80665];

type Imu<'a> = Icm42688<SharedSim<'a>>;

fn started(part: &RefCell<SimIcm42688>, settings: Settings) -> Imu<'_> {
    let mut imu = Icm42688::new(SharedSim::new(part), settings);
    imu.init(&mut NoopDelay::new()).unwrap();
    imu
}

/// Runs `f` on the simulated part while the driver holds its handle.
fn with<R>(part: &RefCell<SimIcm42688>, f: impl FnOnce(&mut SimIcm42688) -> R) -> R {
    f(&mut part.borrow_mut())
}

/// The FIFO time stamp of a sample at part time `part_us` on the internal clock: the counter's
/// "1 µs" tick lasts 32/30 µs (its PLL runs at 19.2 MHz, not 20.48: TDK's
/// `inv_icm426xx_get_fifo_timestamp_resolution_us_q24`, PX4's `FIFO_TIMESTAMP_SCALING`).
fn stamp(part_us: u64) -> u16 {
    (part_us * 30 / 32) as u16
}

/// Pushes `n` samples at `period_us` from `t0`, sample i with gyro X = GYRO[0] + i × 0.001.
fn push(sim: &mut SimIcm42688, t0: u64, period_us: u64, n: usize) {
    for i in 0..n {
        let mut gyro = GYRO;
        gyro[0] += i as f64 * 0.001;
        sim.sample(t0 + i as u64 * period_us, gyro, ACCEL, 31.0);
    }
}

#[test]
fn init_configures_every_register() {
    let settings = Settings::new(Odr::Hz1000);
    let part = RefCell::new(SimIcm42688::new());
    started(&part, settings);
    let sim = part.into_inner();
    assert_eq!(sim.soft_resets(), 1);
    for w in settings.register_writes() {
        assert_eq!(sim.peek(w.bank, w.address), w.value, "{w:?}");
    }
    // RESET_DONE read (cleared) by init.
    assert_eq!(sim.peek(0, reg::INT_STATUS), 0);
}

#[test]
fn samples_round_trip_within_one_lsb_with_time_stamps() {
    for (gyro_range, accel_range) in [
        (GyroRange::Dps2000, AccelRange::G16),
        (GyroRange::Dps250, AccelRange::G2),
    ] {
        let settings = Settings {
            gyro_range,
            accel_range,
            ..Settings::new(Odr::Hz1000)
        };
        let part = RefCell::new(SimIcm42688::new());
        let mut imu = started(&part, settings);
        // 65 500 µs start: the time stamps wrap past 65 535 during the run.
        with(&part, |sim| push(sim, 65_500, 1000, 10));
        let mut out = [Packet::default(); 16];
        let r = imu.read_fifo(&mut out).unwrap();
        assert_eq!(
            r,
            FifoRead {
                packets: 10,
                ..FifoRead::default()
            }
        );
        let g_lsb = f64::from(settings.gyro_rad_s_per_lsb());
        let a_lsb = f64::from(settings.accel_m_s2_per_lsb());
        for (i, p) in out[..10].iter().enumerate() {
            assert_eq!(p.header, 0x68);
            assert_eq!(p.timestamp, stamp(65_500 + i as u64 * 1000));
            let mut want = GYRO;
            want[0] += i as f64 * 0.001;
            for (got, want) in p.gyro_rad_s(&settings).iter().zip(want) {
                assert!((f64::from(*got) - want).abs() <= g_lsb, "{got} vs {want}");
            }
            for (got, want) in p.accel_m_s2(&settings).iter().zip(ACCEL) {
                assert!((f64::from(*got) - want).abs() <= a_lsb, "{got} vs {want}");
            }
            assert!((p.temperature_c() - 31.0).abs() <= 0.5 / 2.07 + 1e-4);
        }
        // Consecutive time stamps differ by the period in ticks (937 or 938 of 32/30 µs),
        // across the wrap.
        for pair in out[..10].windows(2) {
            let d = pair[1].timestamp.wrapping_sub(pair[0].timestamp);
            assert!(d == 937 || d == 938, "{d}");
        }
    }
}

#[test]
fn part_clock_drift_shows_in_time_stamps() {
    let part = RefCell::new(SimIcm42688::new());
    let mut imu = started(&part, Settings::new(Odr::Hz100));
    // The part's clock runs 1 % fast: 10 100 µs of part time per nominal 10 ms period.
    with(&part, |sim| push(sim, 0, 10_100, 5));
    let mut out = [Packet::default(); 8];
    assert_eq!(imu.read_fifo(&mut out).unwrap().packets, 5);
    for pair in out[..5].windows(2) {
        // 10 100 µs are 9 468.75 ticks of 32/30 µs.
        let d = pair[1].timestamp.wrapping_sub(pair[0].timestamp);
        assert!(d == 9_468 || d == 9_469, "{d}");
    }
}

#[test]
fn partial_reads_continue_in_order() {
    let part = RefCell::new(SimIcm42688::new());
    let mut imu = started(&part, Settings::new(Odr::Hz1000));
    with(&part, |sim| push(sim, 0, 1000, 10));
    let mut out = [Packet::default(); 4];
    let r = imu.read_fifo(&mut out).unwrap();
    assert_eq!((r.packets, r.remaining), (4, 6));
    assert_eq!(out[3].timestamp, stamp(3000));
    let r = imu.read_fifo(&mut out).unwrap();
    assert_eq!((r.packets, r.remaining), (4, 2));
    assert_eq!(out[0].timestamp, stamp(4000));
    let r = imu.read_fifo(&mut out).unwrap();
    assert_eq!((r.packets, r.remaining), (2, 0));
    assert_eq!(out[1].timestamp, stamp(9000));
}

#[test]
fn overflow_is_flagged_and_the_oldest_128_remain() {
    let part = RefCell::new(SimIcm42688::new());
    let mut imu = started(&part, Settings::new(Odr::Hz1000));
    let dropped = with(&part, |sim| {
        push(sim, 0, 1000, 200);
        sim.dropped_on_overflow()
    });
    assert_eq!(dropped, 200 - SIM_FIFO_CAPACITY as u64);
    let mut out = [Packet::default(); 256];
    let r = imu.read_fifo(&mut out).unwrap();
    assert_eq!(
        r,
        FifoRead {
            packets: 128,
            overflowed: true,
            ..FifoRead::default()
        }
    );
    // Stop-on-full (issue 55, point 9): the newest 72 were dropped.
    for (i, p) in out[..128].iter().enumerate() {
        assert_eq!(p.timestamp, stamp(i as u64 * 1000));
    }
    // The flag is reported once.
    with(&part, |sim| push(sim, 200_000, 1000, 1));
    assert!(!imu.read_fifo(&mut out).unwrap().overflowed);
}

#[test]
fn a_full_fifo_is_flagged_even_before_a_loss() {
    // FIFO_FULL_INT sets when the FIFO reaches full size (data sheet), so exactly 128 packets
    // are flagged though none were lost: `overflowed` means "may have lost samples".
    let part = RefCell::new(SimIcm42688::new());
    let mut imu = started(&part, Settings::new(Odr::Hz1000));
    with(&part, |sim| push(sim, 0, 1000, 128));
    let mut out = [Packet::default(); 128];
    let r = imu.read_fifo(&mut out).unwrap();
    assert_eq!((r.packets, r.overflowed), (128, true));
    assert_eq!(out[0].timestamp, 0);
}

#[test]
fn corrupt_header_is_flagged_and_fifo_flushed() {
    let part = RefCell::new(SimIcm42688::new());
    let mut imu = started(&part, Settings::new(Odr::Hz1000));
    let flushes = with(&part, |sim| {
        push(sim, 0, 1000, 2);
        sim.corrupt_next_header();
        push(sim, 2000, 1000, 3);
        sim.flushes()
    });
    let mut out = [Packet::default(); 8];
    let r = imu.read_fifo(&mut out).unwrap();
    assert_eq!(
        r,
        FifoRead {
            packets: 2,
            corrupt: true,
            ..FifoRead::default()
        }
    );
    assert_eq!(out[1].timestamp, stamp(1000));
    let after = with(&part, |sim| {
        assert_eq!(sim.fifo_len(), 0);
        let f = sim.flushes();
        push(sim, 10_000, 1000, 3);
        f
    });
    assert_eq!(after, flushes + 1);
    // Samples flow again.
    let r = imu.read_fifo(&mut out).unwrap();
    assert_eq!((r.packets, r.corrupt), (3, false));
    assert_eq!(out[0].timestamp, stamp(10_000));
}

#[test]
fn power_on_reset_is_detected_by_check_and_repaired() {
    let settings = Settings::new(Odr::Hz1000);
    let part = RefCell::new(SimIcm42688::new());
    let mut imu = started(&part, settings);
    let mut delay = NoopDelay::new();
    assert_eq!(imu.check(&mut delay).unwrap(), Check::Ok);
    with(&part, |sim| {
        push(sim, 0, 1000, 5);
        sim.power_on_reset();
        // Sensors off: nothing reaches the FIFO.
        push(sim, 5000, 1000, 5);
        assert_eq!(sim.ignored_samples(), 5);
    });
    let mut out = [Packet::default(); 8];
    assert_eq!(imu.read_fifo(&mut out).unwrap().packets, 0);
    // read_fifo consumed INT_STATUS (RESET_DONE); the driver kept it for check.
    assert_eq!(
        imu.check(&mut delay).unwrap(),
        Check::Repaired {
            bank: 0,
            address: reg::INT_STATUS,
            expected: 0,
            found: reg::INT_STATUS_RESET_DONE
        }
    );
    with(&part, |sim| {
        for w in settings.register_writes() {
            assert_eq!(sim.peek(w.bank, w.address), w.value, "{w:?}");
        }
        push(sim, 20_000, 1000, 4);
    });
    let r = imu.read_fifo(&mut out).unwrap();
    assert_eq!(r.packets, 4);
    assert_eq!(out[0].timestamp, stamp(20_000));
    assert_eq!(imu.check(&mut delay).unwrap(), Check::Ok);
}

#[test]
fn power_on_reset_seen_directly_by_check() {
    let part = RefCell::new(SimIcm42688::new());
    let mut imu = started(&part, Settings::new(Odr::Hz100));
    with(&part, |sim| sim.power_on_reset());
    assert!(matches!(
        imu.check(&mut NoopDelay::new()).unwrap(),
        Check::Repaired { address: 0x2D, .. }
    ));
}

#[test]
fn register_glitch_is_detected_and_repaired() {
    let settings = Settings::new(Odr::Hz200);
    let part = RefCell::new(SimIcm42688::new());
    let mut imu = started(&part, settings);
    with(&part, |sim| {
        sim.poke(1, reg::GYRO_CONFIG_STATIC3, 0x3F);
    });
    let mut delay = NoopDelay::new();
    assert_eq!(
        imu.check(&mut delay).unwrap(),
        Check::Repaired {
            bank: 1,
            address: reg::GYRO_CONFIG_STATIC3,
            expected: 2, // AAF 84 Hz at 200 Hz: DELT 2
            found: 0x3F
        }
    );
    assert_eq!(imu.check(&mut delay).unwrap(), Check::Ok);
    let soft_resets = with(&part, |sim| sim.soft_resets());
    assert_eq!(soft_resets, 2);
}

#[test]
fn data_ready_interrupt() {
    let part = RefCell::new(SimIcm42688::new());
    let mut imu = started(&part, Settings::new(Odr::Hz100));
    let pending = with(&part, |sim| {
        let before = sim.interrupt_pending();
        push(sim, 0, 10_000, 1);
        (before, sim.interrupt_pending())
    });
    assert_eq!(pending, (false, true));
    imu.read_fifo(&mut [Packet::default(); 4]).unwrap();
    assert!(!with(&part, |sim| sim.interrupt_pending()));
}

#[test]
fn watermark_interrupt() {
    let settings = Settings {
        watermark: 10,
        interrupt: Interrupt::Watermark,
        ..Settings::new(Odr::Hz1000)
    };
    let part = RefCell::new(SimIcm42688::new());
    let mut imu = started(&part, settings);
    let pending = with(&part, |sim| {
        push(sim, 0, 1000, 9);
        let at_9 = sim.interrupt_pending();
        push(sim, 9000, 1000, 1);
        (at_9, sim.interrupt_pending())
    });
    assert_eq!(pending, (false, true));
    let mut out = [Packet::default(); 16];
    assert_eq!(imu.read_fifo(&mut out).unwrap().packets, 10);
    assert!(!with(&part, |sim| sim.interrupt_pending()));
}

#[test]
fn sim_spi_framing() {
    let mut sim = SimIcm42688::new();
    // WHO_AM_I, with transfer_in_place: the address byte clocks out 0x00.
    let mut buf = [0x75 | 0x80, 0];
    sim.transfer_in_place(&mut buf).unwrap();
    assert_eq!(buf, [0x00, 0x47]);
    // INT_STATUS is cleared on read.
    let mut s = [0u8; 1];
    sim.transaction(&mut [
        embedded_hal::spi::Operation::Write(&[0x2D | 0x80]),
        embedded_hal::spi::Operation::Read(&mut s),
    ])
    .unwrap();
    assert_eq!(s, [0x10]);
    sim.transfer_in_place(&mut [0x2D | 0x80, 0]).unwrap();
    let mut buf = [0x2D | 0x80, 0xAA];
    sim.transfer_in_place(&mut buf).unwrap();
    assert_eq!(buf[1], 0x00);
    // Bank select from bank 0 and from bank 1 (REG_BANK_SEL is in every bank), auto-increment
    // write and read in bank 1.
    sim.write(&[0x76, 1]).unwrap();
    sim.write(&[0x0C, 0x11, 0x22, 0x33]).unwrap();
    let mut buf = [0x0C | 0x80, 0, 0, 0];
    sim.transfer_in_place(&mut buf).unwrap();
    assert_eq!(buf[1..], [0x11, 0x22, 0x33]);
    sim.write(&[0x76, 0]).unwrap();
    assert_eq!(sim.peek(1, 0x0D), 0x22);
    // Empty FIFO reads 0xFF; the address does not advance at FIFO_DATA.
    let mut buf = [0x30 | 0x80, 0, 0, 0];
    sim.transfer_in_place(&mut buf).unwrap();
    assert_eq!(buf[1..], [0xFF, 0xFF, 0xFF]);
}

#[test]
fn sim_fifo_count_in_bytes_and_records() {
    let part = RefCell::new(SimIcm42688::new());
    started(&part, Settings::new(Odr::Hz1000));
    let mut sim = part.into_inner();
    push(&mut sim, 0, 1000, 3);
    let count = |sim: &mut SimIcm42688| {
        let mut buf = [0x2E | 0x80, 0, 0];
        sim.transfer_in_place(&mut buf).unwrap();
        u16::from_be_bytes([buf[1], buf[2]])
    };
    assert_eq!(count(&mut sim), 3);
    // Pop 5 bytes of the first packet: the record count still includes it; bytes do not.
    sim.transfer_in_place(&mut [0x30 | 0x80, 0, 0, 0, 0, 0])
        .unwrap();
    assert_eq!(count(&mut sim), 3);
    sim.write(&[0x4C, 0x33]).unwrap(); // FIFO_COUNT_REC = 0: bytes
    assert_eq!(count(&mut sim), 48 - 5);
    // Little-endian count: FIFO_COUNTH holds the low byte.
    sim.write(&[0x4C, 0x13]).unwrap();
    let mut buf = [0x2E | 0x80, 0, 0];
    sim.transfer_in_place(&mut buf).unwrap();
    assert_eq!(u16::from_le_bytes([buf[1], buf[2]]), 43);
    // Bypass mode: the FIFO is no longer fed.
    sim.write(&[0x16, 0x00]).unwrap();
    let pushed = sim.pushed();
    push(&mut sim, 3000, 1000, 2);
    assert_eq!(sim.pushed(), pushed);
}
