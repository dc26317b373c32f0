//! The driver's exact SPI traffic, against a scripted `embedded-hal-mock` SPI device. Expected
//! bytes are written out by hand from the data sheet, not computed by the crate.

use embedded_hal_mock::eh1::delay::{CheckedDelay, NoopDelay, Transaction as DelayTransaction};
use embedded_hal_mock::eh1::spi::{Mock, Transaction as T};
use icm42688::{
    AccelRange, Check, ClockSource, Error, FifoRead, GyroRange, Icm42688, Interrupt, Odr, Packet,
    Settings, SettingsError,
};

type Script = Vec<T<u8>>;

/// One register write: `[address, value]` in its own transaction.
fn write(address: u8, value: u8) -> Script {
    vec![
        T::transaction_start(),
        T::write_vec(vec![address, value]),
        T::transaction_end(),
    ]
}

/// One read: the address with bit 7 set, then the bytes read.
fn read(address: u8, response: &[u8]) -> Script {
    vec![
        T::transaction_start(),
        T::write_vec(vec![address | 0x80]),
        T::read_vec(response.to_vec()),
        T::transaction_end(),
    ]
}

fn script(parts: Vec<Script>) -> Script {
    parts.into_iter().flatten().collect()
}

/// `init` for 100 Hz, ±2000 °/s, ±16 g, AAF 42 Hz, watermark 1, data-ready, internal clock.
fn init_typical() -> Vec<Script> {
    vec![
        write(0x76, 0x00),   // REG_BANK_SEL = 0 (bank unknown before init)
        write(0x11, 0x01),   // DEVICE_CONFIG: soft reset
        read(0x75, &[0x47]), // WHO_AM_I
        read(0x11, &[0x00]), // DEVICE_CONFIG: the reset bit has cleared
        read(0x2D, &[0x10]), // INT_STATUS: RESET_DONE, cleared by the read
        write(0x4C, 0x73),   // INTF_CONFIG0: count in records, big-endian, I2C off
        write(0x14, 0x03),   // INT_CONFIG: INT1 pulsed, push-pull, active high
        write(0x63, 0x00),   // INT_CONFIG0: clear on INT_STATUS read
        write(0x64, 0x00),   // INT_CONFIG1: INT_ASYNC_RESET = 0
        write(0x4F, 0x08),   // GYRO_CONFIG0: ±2000 dps, 100 Hz
        write(0x50, 0x08),   // ACCEL_CONFIG0: ±16 g, 100 Hz
        write(0x51, 0x12),   // GYRO_CONFIG1: UI filter 1st order
        write(0x52, 0x00),   // GYRO_ACCEL_CONFIG0: UI filters ODR/2
        write(0x53, 0x05),   // ACCEL_CONFIG1: UI filter 1st order
        write(0x54, 0x21),   // TMST_CONFIG: TMST_EN, absolute, 1 us, no FSYNC
        write(0x62, 0x00),   // FSYNC_CONFIG: no FSYNC tagging
        write(0x5F, 0x67),   // FIFO_CONFIG1: resume partial, WM_GT_TH, temp, gyro, accel
        write(0x60, 0x01),   // FIFO_CONFIG2: watermark 1
        write(0x61, 0x00),   // FIFO_CONFIG3
        write(0x16, 0x80),   // FIFO_CONFIG: stop-on-full
        write(0x65, 0x08),   // INT_SOURCE0: data ready -> INT1
        write(0x76, 0x01),   // bank 1
        write(0x0B, 0xA1),   // GYRO_CONFIG_STATIC2: AAF on, notch off
        write(0x0C, 0x01),   // GYRO_AAF_DELT 1
        write(0x0D, 0x01),   // GYRO_AAF_DELTSQR 1
        write(0x0E, 0xF0),   // GYRO_AAF_BITSHIFT 15
        write(0x76, 0x02),   // bank 2
        write(0x03, 0x02),   // ACCEL_AAF_DELT 1, AAF on
        write(0x04, 0x01),   // ACCEL_AAF_DELTSQR 1
        write(0x05, 0xF0),   // ACCEL_AAF_BITSHIFT 15
        write(0x76, 0x00),   // bank 0
        write(0x4D, 0x51),   // INTF_CONFIG1: AFSR off, PLL, no RTC
        write(0x4E, 0x0F),   // PWR_MGMT0: gyro and accel low-noise
        write(0x4B, 0x02),   // SIGNAL_PATH_RESET: FIFO flush
    ]
}

/// `check` of a healthy part with the typical settings, after `init`.
fn check_healthy_typical() -> Vec<Script> {
    vec![
        read(0x2D, &[0x00]),
        read(0x14, &[0x03]),
        read(0x16, &[0x80]),
        read(
            0x4C,
            &[0x73, 0x51, 0x0F, 0x08, 0x08, 0x12, 0x00, 0x05, 0x21],
        ),
        read(0x5F, &[0x67, 0x01, 0x00, 0x00, 0x00, 0x00, 0x08]),
        write(0x76, 0x01),
        read(0x0B, &[0xA1, 0x01, 0x01, 0xF0]),
        write(0x76, 0x02),
        read(0x03, &[0x02, 0x01, 0xF0]),
        write(0x76, 0x00),
    ]
}

fn init_delays() -> Vec<DelayTransaction> {
    vec![
        DelayTransaction::delay_us(1000),
        DelayTransaction::delay_us(200),
    ]
}

#[test]
fn init_typical_writes_exact_sequence() {
    let mut spi = Mock::new(&script(init_typical()));
    let mut delay = CheckedDelay::new(&init_delays());
    let mut imu = Icm42688::new(spi.clone(), Settings::new(Odr::Hz100));
    imu.init(&mut delay).unwrap();
    spi.done();
    delay.done();
}

#[test]
fn init_watermark_clkin_writes_exact_sequence() {
    let settings = Settings {
        gyro_range: GyroRange::Dps500,
        accel_range: AccelRange::G4,
        watermark: 100,
        interrupt: Interrupt::Watermark,
        clock: ClockSource::Clkin { hz: 32_768 },
        ..Settings::new(Odr::Hz4000)
    };
    let expected = script(vec![
        write(0x76, 0x00),
        write(0x11, 0x01),
        read(0x75, &[0x47]),
        read(0x11, &[0x00]),
        read(0x2D, &[0x10]),
        write(0x4C, 0x73),
        write(0x14, 0x03),
        write(0x63, 0x00),
        write(0x64, 0x60), // 4 kHz: 8 us pulses, no de-assertion minimum
        write(0x4F, 0x44), // ±500 dps, 4 kHz
        write(0x50, 0x44), // ±4 g, 4 kHz
        write(0x51, 0x12),
        write(0x52, 0x00),
        write(0x53, 0x05),
        write(0x54, 0x21),
        write(0x62, 0x00),
        write(0x5F, 0x67),
        write(0x60, 0x64), // watermark 100 records
        write(0x61, 0x00),
        write(0x16, 0x80),
        write(0x65, 0x04), // FIFO threshold -> INT1
        write(0x76, 0x01),
        write(0x0B, 0xA1),
        write(0x0C, 0x15), // AAF 997 Hz: DELT 21
        write(0x0D, 0xB8), // DELTSQR 440 = 0x1B8
        write(0x0E, 0x61), // BITSHIFT 6, DELTSQR[11:8] 1
        // INTF_CONFIG5: pin 9 = CLKIN, read-modify-write (reserved bits 0x09 kept).
        read(0x7B, &[0x09]),
        write(0x7B, 0x0D),
        write(0x76, 0x02),
        write(0x03, 0x2A), // DELT 21 << 1
        write(0x04, 0xB8),
        write(0x05, 0x61),
        write(0x76, 0x00),
        write(0x4D, 0x55), // INTF_CONFIG1: AFSR off, RTC_MODE + PLL
        write(0x4E, 0x0F),
        write(0x4B, 0x02),
    ]);
    let mut spi = Mock::new(&expected);
    let mut imu = Icm42688::new(spi.clone(), settings);
    imu.init(&mut NoopDelay::new()).unwrap();
    spi.done();
}

#[test]
fn init_wrong_who_am_i() {
    // Polled every 1 ms for 1 s after the soft reset (issue 55, point 9), then refused.
    let mut parts = vec![write(0x76, 0x00), write(0x11, 0x01)];
    parts.extend((0..1000).map(|_| read(0x75, &[0x98])));
    let mut spi = Mock::new(&script(parts));
    let mut imu = Icm42688::new(spi.clone(), Settings::new(Odr::Hz100));
    let err = imu.init(&mut NoopDelay::new()).unwrap_err();
    assert_eq!(err, Error::WrongId(0x98));
    assert!(err.to_string().contains("0x98"), "{err}");
    spi.done();
}

/// Issue 55, point 9: a fixed 1 ms after the soft reset trusted a part still starting up. The
/// driver polls WHO_AM_I, DEVICE_CONFIG and RESET_DONE every 1 ms until all three say the
/// reset is over.
#[test]
fn init_waits_for_the_soft_reset_to_finish() {
    let mut parts = vec![
        write(0x76, 0x00),
        write(0x11, 0x01),
        read(0x75, &[0x00]), // not answering yet
        read(0x75, &[0x47]),
        read(0x11, &[0x01]), // still resetting
        read(0x75, &[0x47]),
        read(0x11, &[0x00]),
        read(0x2D, &[0x00]), // no RESET_DONE yet
    ];
    parts.extend(init_typical().into_iter().skip(2));
    let mut spi = Mock::new(&script(parts));
    let mut delay = CheckedDelay::new(&[
        DelayTransaction::delay_us(1000),
        DelayTransaction::delay_us(1000),
        DelayTransaction::delay_us(1000),
        DelayTransaction::delay_us(1000),
        DelayTransaction::delay_us(200),
    ]);
    let mut imu = Icm42688::new(spi.clone(), Settings::new(Odr::Hz100));
    imu.init(&mut delay).unwrap();
    spi.done();
    delay.done();
}

#[test]
fn init_rejects_bad_settings_without_spi_traffic() {
    let mut spi = Mock::new(&[]);
    let settings = Settings {
        watermark: 0,
        ..Settings::new(Odr::Hz100)
    };
    let mut imu = Icm42688::new(spi.clone(), settings);
    let err = imu.init(&mut NoopDelay::new()).unwrap_err();
    assert_eq!(
        err,
        Error::Settings(SettingsError::WatermarkOutOfRange {
            watermark: 0,
            max: 128
        })
    );
    spi.done();
}

/// Three packets written byte by byte from data sheet §6.1.
const THREE_PACKETS: [u8; 48] = [
    // header 0x68; accel 16, -16, 2048; gyro 1, -1, -32767; temp 10; time stamp 0x1234
    0x68, 0x00, 0x10, 0xFF, 0xF0, 0x08, 0x00, 0x00, 0x01, 0xFF, 0xFF, 0x80, 0x01, 0x0A, 0x12,
    0x34, //
    // header 0x69 (gyro ODR changed); accel 32767, -32767, 0; gyro 258, 772, 1286; temp -10;
    // time stamp 0x3944
    0x69, 0x7F, 0xFF, 0x80, 0x01, 0x00, 0x00, 0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0xF6, 0x39,
    0x44, //
    // header 0x6A (accel ODR changed); accel -2, 2, 16384; gyro 32767, -32767, 0; temp 0;
    // time stamp 0x6054
    0x6A, 0xFF, 0xFE, 0x00, 0x02, 0x40, 0x00, 0x7F, 0xFF, 0x80, 0x01, 0x00, 0x00, 0x00, 0x60, 0x54,
];

#[test]
fn read_fifo_three_packets_bit_exact() {
    let mut spi = Mock::new(&script(vec![
        write(0x76, 0x00),               // a fresh driver does not know the bank
        read(0x2D, &[0x08, 0x00, 0x03]), // INT_STATUS (DATA_RDY), FIFO_COUNT = 3 records
        read(0x30, &THREE_PACKETS),
        // Second call: bank known, FIFO empty: one transaction only.
        read(0x2D, &[0x00, 0x00, 0x00]),
    ]));
    let mut imu = Icm42688::new(spi.clone(), Settings::new(Odr::Hz100));
    let mut out = [Packet::default(); 8];
    let r = imu.read_fifo(&mut out).unwrap();
    assert_eq!(
        r,
        FifoRead {
            packets: 3,
            overflowed: false,
            corrupt: false,
            // Packets 2 and 3 say their ODR changed: kept, marked not to be used.
            invalid: 2,
            remaining: 0
        }
    );
    assert_eq!(
        out[0],
        Packet {
            header: 0x68,
            accel: [16, -16, 2048],
            gyro: [1, -1, -32767],
            temperature: 10,
            timestamp: 0x1234
        }
    );
    assert_eq!(
        out[1],
        Packet {
            header: 0x69,
            accel: [32767, -32767, 0],
            gyro: [258, 772, 1286],
            temperature: -10,
            timestamp: 0x3944
        }
    );
    assert_eq!(
        out[2],
        Packet {
            header: 0x6A,
            accel: [-2, 2, 16384],
            gyro: [32767, -32767, 0],
            temperature: 0,
            timestamp: 0x6054
        }
    );
    let r = imu.read_fifo(&mut out).unwrap();
    assert_eq!(r, FifoRead::default());
    spi.done();
}

#[test]
fn read_fifo_reads_only_what_fits_and_reports_overflow() {
    let first_two: Vec<u8> = THREE_PACKETS[..32].to_vec();
    let mut spi = Mock::new(&script(vec![
        write(0x76, 0x00),
        read(0x2D, &[0x02, 0x00, 0x05]), // FIFO_FULL, 5 records
        read(0x30, &first_two),
    ]));
    let mut imu = Icm42688::new(spi.clone(), Settings::new(Odr::Hz100));
    let mut out = [Packet::default(); 2];
    let r = imu.read_fifo(&mut out).unwrap();
    assert_eq!(r.packets, 2);
    assert!(r.overflowed);
    assert_eq!(r.remaining, 3);
    assert_eq!(out[1].timestamp, 0x3944);
    spi.done();
}

#[test]
fn read_fifo_bad_header_flushes() {
    let mut bytes = THREE_PACKETS.to_vec();
    bytes[16] = 0x78; // second header: HEADER_20 set, not a packet 3
    let mut spi = Mock::new(&script(vec![
        write(0x76, 0x00),
        read(0x2D, &[0x00, 0x00, 0x03]),
        read(0x30, &bytes),
        write(0x4B, 0x02), // FIFO flush
    ]));
    let mut imu = Icm42688::new(spi.clone(), Settings::new(Odr::Hz100));
    let mut out = [Packet::default(); 4];
    let r = imu.read_fifo(&mut out).unwrap();
    assert_eq!(
        r,
        FifoRead {
            packets: 1,
            overflowed: false,
            corrupt: true,
            invalid: 0,
            remaining: 0
        }
    );
    assert_eq!(out[0].timestamp, 0x1234);
    spi.done();
}

#[test]
fn read_fifo_empty_marker_is_corrupt_and_invalid_samples_are_kept_marked() {
    let mut bytes = THREE_PACKETS.to_vec();
    bytes[1] = 0x80; // first packet: accel X = -32768, the invalid-sample mark
    bytes[2] = 0x00;
    for b in &mut bytes[32..] {
        *b = 0xFF; // third packet: what an empty FIFO reads
    }
    let mut spi = Mock::new(&script(vec![
        write(0x76, 0x00),
        read(0x2D, &[0x00, 0x00, 0x03]),
        read(0x30, &bytes),
        write(0x4B, 0x02),
    ]));
    let mut imu = Icm42688::new(spi.clone(), Settings::new(Odr::Hz100));
    let mut out = [Packet::default(); 4];
    let r = imu.read_fifo(&mut out).unwrap();
    // The invalid packet keeps its place and its time stamp (issue 55, point 6).
    // (The second packet's header says its ODR changed: it is marked not to be used too.)
    assert_eq!(r.packets, 2);
    assert_eq!(r.invalid, 2);
    assert!(r.corrupt);
    assert!(!out[0].has_valid_data() && !out[1].has_valid_data());
    assert_eq!(out[1].timestamp, 0x3944);
    spi.done();
}

#[test]
fn check_healthy_part_reads_every_configured_register() {
    let mut spi = Mock::new(&script(
        init_typical()
            .into_iter()
            .chain(check_healthy_typical())
            // The FIFO read after the check needs no bank write: check ends in bank 0.
            .chain([read(0x2D, &[0x00, 0x00, 0x00])])
            .collect(),
    ));
    let mut imu = Icm42688::new(spi.clone(), Settings::new(Odr::Hz100));
    let mut delay = NoopDelay::new();
    imu.init(&mut delay).unwrap();
    assert_eq!(imu.check(&mut delay).unwrap(), Check::Ok);
    imu.read_fifo(&mut [Packet::default(); 4]).unwrap();
    spi.done();
}

#[test]
fn check_detects_register_at_reset_value_and_reconfigures() {
    // A reset whose RESET_DONE was lost: INTF_CONFIG0 reads its reset value 0x30.
    let mut parts = init_typical();
    parts.extend([
        read(0x2D, &[0x00]),
        read(0x14, &[0x03]),
        read(0x16, &[0x80]),
        read(
            0x4C,
            &[0x30, 0x91, 0x00, 0x06, 0x06, 0x16, 0x11, 0x0D, 0x23],
        ),
    ]);
    parts.extend(init_typical());
    let mut spi = Mock::new(&script(parts));
    let mut imu = Icm42688::new(spi.clone(), Settings::new(Odr::Hz100));
    let mut delay = NoopDelay::new();
    imu.init(&mut delay).unwrap();
    assert_eq!(
        imu.check(&mut delay).unwrap(),
        Check::Repaired {
            bank: 0,
            address: 0x4C,
            expected: 0x73,
            found: 0x30
        }
    );
    spi.done();
}

#[test]
fn check_detects_bank1_glitch_and_reconfigures() {
    let mut parts = init_typical();
    parts.extend([
        read(0x2D, &[0x00]),
        read(0x14, &[0x03]),
        read(0x16, &[0x80]),
        read(
            0x4C,
            &[0x73, 0x51, 0x0F, 0x08, 0x08, 0x12, 0x00, 0x05, 0x21],
        ),
        read(0x5F, &[0x67, 0x01, 0x00, 0x00, 0x00, 0x00, 0x08]),
        write(0x76, 0x01),
        read(0x0B, &[0xA0, 0x01, 0x01, 0xF0]), // AAF and notch both on: reset value
    ]);
    // The repair starts from bank 1: init's unconditional bank-0 write is what brings it back.
    parts.extend(init_typical());
    let mut spi = Mock::new(&script(parts));
    let mut imu = Icm42688::new(spi.clone(), Settings::new(Odr::Hz100));
    let mut delay = NoopDelay::new();
    imu.init(&mut delay).unwrap();
    assert_eq!(
        imu.check(&mut delay).unwrap(),
        Check::Repaired {
            bank: 1,
            address: 0x0B,
            expected: 0xA1,
            found: 0xA0
        }
    );
    spi.done();
}

#[test]
fn check_detects_reset_done_and_reconfigures() {
    let mut parts = init_typical();
    parts.push(read(0x2D, &[0x10]));
    parts.extend(init_typical());
    let mut spi = Mock::new(&script(parts));
    let mut imu = Icm42688::new(spi.clone(), Settings::new(Odr::Hz100));
    let mut delay = NoopDelay::new();
    imu.init(&mut delay).unwrap();
    assert_eq!(
        imu.check(&mut delay).unwrap(),
        Check::Repaired {
            bank: 0,
            address: 0x2D,
            expected: 0x00,
            found: 0x10
        }
    );
    spi.done();
}

#[test]
fn status_bits_are_kept_across_read_fifo_and_check() {
    let mut parts = init_typical();
    // read_fifo sees RESET_DONE (and clears it on the part by reading INT_STATUS) ...
    parts.push(read(0x2D, &[0x10, 0x00, 0x00]));
    // ... check's own INT_STATUS read is clean, yet it repairs.
    parts.push(read(0x2D, &[0x00]));
    parts.extend(init_typical());
    // check sees FIFO_FULL; the next read_fifo reports it.
    parts.extend(
        check_healthy_typical()
            .into_iter()
            .enumerate()
            .map(|(i, s)| if i == 0 { read(0x2D, &[0x02]) } else { s }),
    );
    parts.push(read(0x2D, &[0x00, 0x00, 0x00]));
    let mut spi = Mock::new(&script(parts));
    let mut imu = Icm42688::new(spi.clone(), Settings::new(Odr::Hz100));
    let mut delay = NoopDelay::new();
    let mut out = [Packet::default(); 4];
    imu.init(&mut delay).unwrap();
    assert_eq!(imu.read_fifo(&mut out).unwrap(), FifoRead::default());
    assert!(matches!(
        imu.check(&mut delay).unwrap(),
        Check::Repaired { address: 0x2D, .. }
    ));
    assert_eq!(imu.check(&mut delay).unwrap(), Check::Ok);
    assert!(imu.read_fifo(&mut out).unwrap().overflowed);
    spi.done();
}
