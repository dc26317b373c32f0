//! Packet decoding and encoding, scale factors, rates, filters and the settings' checks.

use icm42688::{
    Aaf, AccelRange, ClockSource, GyroRange, Interrupt, MAX_REGISTER_WRITES, Odr, Packet,
    PacketError, Settings, SettingsError,
};

/// A packet 3 written out by hand (data sheet §6.1): header 0x68; accel 1000, -1000, 2048; gyro -2, 300,
/// 16; temperature 21 (35.1 °C); time stamp 0xABCD.
const BYTES: [u8; 16] = [
    0x68, 0x03, 0xE8, 0xFC, 0x18, 0x08, 0x00, 0xFF, 0xFE, 0x01, 0x2C, 0x00, 0x10, 0x15, 0xAB, 0xCD,
];

#[test]
fn decode_hand_written_packet() {
    let p = Packet::decode(&BYTES).unwrap();
    assert_eq!(
        p,
        Packet {
            header: 0x68,
            accel: [1000, -1000, 2048],
            gyro: [-2, 300, 16],
            temperature: 21,
            timestamp: 0xABCD,
        }
    );
    assert!((p.temperature_c() - (21.0 / 2.07 + 25.0)).abs() < 1e-5);
    assert!(p.has_valid_data());
}

#[test]
fn encode_is_decode_inverse() {
    let p = Packet::decode(&BYTES).unwrap();
    assert_eq!(p.encode(), BYTES);
    let q = Packet {
        header: 0x6B,
        accel: [i16::MAX, i16::MIN + 1, 0],
        gyro: [-1, 1, 12345],
        temperature: -128,
        timestamp: 0,
    };
    assert_eq!(Packet::decode(&q.encode()), Ok(q));
}

#[test]
fn decode_rejects_bad_headers() {
    let mut b = BYTES;
    for (header, want) in [
        (0xFF, Err(PacketError::Empty(0xFF))), // what an empty FIFO reads
        (0x80, Err(PacketError::Empty(0x80))),
        (0x78, Err(PacketError::BadHeader(0x78))), // HEADER_20: packet 4
        (0x60, Err(PacketError::BadHeader(0x60))), // no time stamp
        (0x6C, Err(PacketError::BadHeader(0x6C))), // FSYNC time stamp
        (0x48, Err(PacketError::BadHeader(0x48))), // accel only
        (0x00, Err(PacketError::BadHeader(0x00))),
    ] {
        b[0] = header;
        assert_eq!(Packet::decode(&b).map(|p| p.header), want, "0x{header:02X}");
    }
    // Bits 1:0 (ODR changed) decode, and mark the sample not to be used (issue 55, point 9).
    for header in 0x68..=0x6B {
        b[0] = header;
        let p = Packet::decode(&b).unwrap();
        assert_eq!(p.has_valid_data(), header == 0x68, "0x{header:02X}");
    }
    assert!(PacketError::BadHeader(0x78).to_string().contains("0x78"));
}

#[test]
fn invalid_sample_mark() {
    let mut b = BYTES;
    b[7] = 0x80; // gyro X = -32768
    b[8] = 0x00;
    assert!(!Packet::decode(&b).unwrap().has_valid_data());
}

#[test]
fn temperature_scale() {
    let p = |t: i8| Packet {
        temperature: t,
        ..Packet::default()
    };
    assert_eq!(p(0).temperature_c(), 25.0);
    assert!((p(-52).temperature_c() - (25.0 - 52.0 / 2.07)).abs() < 1e-5);
}

/// Counts per unit from a settings' scale.
fn gyro_lsb_per_dps(range: GyroRange) -> f32 {
    let s = Settings {
        gyro_range: range,
        ..Settings::new(Odr::Hz100)
    };
    1.0 / (s.gyro_rad_s_per_lsb() * 180.0 / core::f32::consts::PI)
}

fn accel_lsb_per_g(range: AccelRange) -> f32 {
    let s = Settings {
        accel_range: range,
        ..Settings::new(Odr::Hz100)
    };
    9.80665 / s.accel_m_s2_per_lsb()
}

#[test]
fn sensitivities() {
    // Data sheet data sheet §3.1 figures (rounded there): 16.4, 32.8, 65.5, 131 LSB/(°/s).
    for (range, datasheet) in [
        (GyroRange::Dps2000, 16.4),
        (GyroRange::Dps1000, 32.8),
        (GyroRange::Dps500, 65.5),
        (GyroRange::Dps250, 131.0),
    ] {
        let got = gyro_lsb_per_dps(range);
        assert!((got / datasheet - 1.0).abs() < 0.002, "{range:?}: {got}");
    }
    assert!((gyro_lsb_per_dps(GyroRange::Dps2000) - 16.384).abs() < 1e-3);
    // data sheet §3.2: 2048, 4096, 8192, 16384 LSB/g, exact.
    for (range, datasheet) in [
        (AccelRange::G16, 2048.0),
        (AccelRange::G8, 4096.0),
        (AccelRange::G4, 8192.0),
        (AccelRange::G2, 16384.0),
    ] {
        let got = accel_lsb_per_g(range);
        assert!((got - datasheet).abs() < 0.01, "{range:?}: {got}");
    }
}

#[test]
fn periods() {
    let period = |odr| Settings::new(odr).period_us();
    assert_eq!(period(Odr::Hz8000), 125);
    assert_eq!(period(Odr::Hz4000), 250);
    assert_eq!(period(Odr::Hz2000), 500);
    assert_eq!(period(Odr::Hz1000), 1000);
    assert_eq!(period(Odr::Hz500), 2000);
    assert_eq!(period(Odr::Hz200), 5000);
    assert_eq!(period(Odr::Hz100), 10_000);
    assert_eq!(period(Odr::Hz50), 20_000);
}

#[test]
fn default_anti_alias_filters() {
    assert_eq!(Aaf::for_odr(Odr::Hz50), Aaf::Hz42); // none below 22.5 Hz: the lowest
    assert_eq!(Aaf::for_odr(Odr::Hz100), Aaf::Hz42);
    assert_eq!(Aaf::for_odr(Odr::Hz200), Aaf::Hz84);
    assert_eq!(Aaf::for_odr(Odr::Hz500), Aaf::Hz213);
    assert_eq!(Aaf::for_odr(Odr::Hz1000), Aaf::Hz303);
    assert_eq!(Aaf::for_odr(Odr::Hz2000), Aaf::Hz536);
    assert_eq!(Aaf::for_odr(Odr::Hz4000), Aaf::Hz997);
    assert_eq!(Aaf::for_odr(Odr::Hz8000), Aaf::Hz997);
    let s = Settings::new(Odr::Hz200);
    assert_eq!((s.gyro_aaf, s.accel_aaf), (Aaf::Hz84, Aaf::Hz84));
}

#[test]
fn new_defaults() {
    let s = Settings::new(Odr::Hz100);
    assert_eq!(s.gyro_range, GyroRange::Dps2000);
    assert_eq!(s.accel_range, AccelRange::G16);
    assert_eq!(s.watermark, 1);
    assert_eq!(s.interrupt, Interrupt::DataReady);
    assert_eq!(s.clock, ClockSource::Internal);
    assert_eq!(s.validate(), Ok(()));
}

#[test]
fn watermark_validation() {
    let with = |watermark| Settings {
        watermark,
        ..Settings::new(Odr::Hz100)
    };
    assert_eq!(with(1).validate(), Ok(()));
    assert_eq!(with(128).validate(), Ok(()));
    for bad in [0, 129, u16::MAX] {
        let err = with(bad).validate().unwrap_err();
        assert_eq!(
            err,
            SettingsError::WatermarkOutOfRange {
                watermark: bad,
                max: 128
            }
        );
        assert!(err.to_string().contains(&bad.to_string()));
    }
}

#[test]
fn register_writes_fit_and_end_with_power_on() {
    for odr in Odr::ALL {
        for gyro_range in [
            GyroRange::Dps2000,
            GyroRange::Dps1000,
            GyroRange::Dps500,
            GyroRange::Dps250,
        ] {
            for clock in [ClockSource::Internal, ClockSource::Clkin { hz: 32_768 }] {
                for interrupt in [Interrupt::DataReady, Interrupt::Watermark] {
                    for aaf in Aaf::ALL {
                        let s = Settings {
                            gyro_range,
                            clock,
                            interrupt,
                            gyro_aaf: aaf,
                            accel_aaf: aaf,
                            watermark: 128,
                            ..Settings::new(odr)
                        };
                        let w = s.register_writes();
                        let want = if clock == ClockSource::Internal {
                            25
                        } else {
                            26
                        };
                        assert_eq!(w.len(), want);
                        assert!(w.len() < MAX_REGISTER_WRITES);
                        let last = w.last().unwrap();
                        assert_eq!((last.bank, last.address, last.value), (0, 0x4E, 0x0F));
                        // Each register once: the check compares one value per register.
                        for (i, a) in w.iter().enumerate() {
                            assert!(
                                w.iter()
                                    .skip(i + 1)
                                    .all(|b| (a.bank, a.address) != (b.bank, b.address))
                            );
                        }
                    }
                }
            }
        }
    }
}
