//! What the part is asked to do ([`Settings`]) and the one register sequence that does it
//! ([`Settings::register_writes`]), used by the driver's `init`, by its configuration check and
//! by the tests.

use core::fmt;

use crate::registers::{self as reg, bank};

/// Standard gravity, for scaling accelerometer counts to m/s².
pub const STANDARD_GRAVITY: f32 = 9.806_65;

/// Capacity of the list returned by [`Settings::register_writes`] (the longest sequence, with
/// CLKIN, has 26 writes).
pub const MAX_REGISTER_WRITES: usize = 32;

/// Output data rate of both sensors (GYRO_CONFIG0 / ACCEL_CONFIG0 bits 3:0, data sheet §14).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Odr {
    /// 8 kHz (code 0011).
    Hz8000,
    /// 4 kHz (code 0100).
    Hz4000,
    /// 2 kHz (code 0101).
    Hz2000,
    /// 1 kHz (code 0110, the reset value).
    Hz1000,
    /// 500 Hz (code 1111).
    Hz500,
    /// 200 Hz (code 0111).
    Hz200,
    /// 100 Hz (code 1000).
    Hz100,
    /// 50 Hz (code 1001).
    Hz50,
}

impl Odr {
    /// Every rate, fastest first.
    pub const ALL: [Odr; 8] = [
        Odr::Hz8000,
        Odr::Hz4000,
        Odr::Hz2000,
        Odr::Hz1000,
        Odr::Hz500,
        Odr::Hz200,
        Odr::Hz100,
        Odr::Hz50,
    ];

    /// The 4-bit ODR code of GYRO_CONFIG0 and ACCEL_CONFIG0 (the two share the table).
    pub const fn code(self) -> u8 {
        match self {
            Odr::Hz8000 => 0b0011,
            Odr::Hz4000 => 0b0100,
            Odr::Hz2000 => 0b0101,
            Odr::Hz1000 => 0b0110,
            Odr::Hz500 => 0b1111,
            Odr::Hz200 => 0b0111,
            Odr::Hz100 => 0b1000,
            Odr::Hz50 => 0b1001,
        }
    }

    /// The nominal rate in Hz.
    pub const fn hz(self) -> u32 {
        match self {
            Odr::Hz8000 => 8000,
            Odr::Hz4000 => 4000,
            Odr::Hz2000 => 2000,
            Odr::Hz1000 => 1000,
            Odr::Hz500 => 500,
            Odr::Hz200 => 200,
            Odr::Hz100 => 100,
            Odr::Hz50 => 50,
        }
    }

    /// The nominal sample period in µs (every rate divides 1 s exactly).
    pub const fn period_us(self) -> u32 {
        1_000_000 / self.hz()
    }
}

/// Gyro full-scale range (GYRO_CONFIG0 bits 7:5).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum GyroRange {
    /// ±2000 °/s (code 000).
    Dps2000,
    /// ±1000 °/s (code 001).
    Dps1000,
    /// ±500 °/s (code 010).
    Dps500,
    /// ±250 °/s (code 011).
    Dps250,
}

impl GyroRange {
    /// The 3-bit GYRO_FS_SEL code.
    pub const fn code(self) -> u8 {
        match self {
            GyroRange::Dps2000 => 0,
            GyroRange::Dps1000 => 1,
            GyroRange::Dps500 => 2,
            GyroRange::Dps250 => 3,
        }
    }

    /// Full scale in °/s.
    pub const fn full_scale_dps(self) -> f32 {
        match self {
            GyroRange::Dps2000 => 2000.0,
            GyroRange::Dps1000 => 1000.0,
            GyroRange::Dps500 => 500.0,
            GyroRange::Dps250 => 250.0,
        }
    }
}

/// Accelerometer full-scale range (ACCEL_CONFIG0 bits 7:5).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum AccelRange {
    /// ±16 g (code 000).
    G16,
    /// ±8 g (code 001).
    G8,
    /// ±4 g (code 010).
    G4,
    /// ±2 g (code 011).
    G2,
}

impl AccelRange {
    /// The 3-bit ACCEL_FS_SEL code.
    pub const fn code(self) -> u8 {
        match self {
            AccelRange::G16 => 0,
            AccelRange::G8 => 1,
            AccelRange::G4 => 2,
            AccelRange::G2 => 3,
        }
    }

    /// Full scale in g.
    pub const fn full_scale_g(self) -> f32 {
        match self {
            AccelRange::G16 => 16.0,
            AccelRange::G8 => 8.0,
            AccelRange::G4 => 4.0,
            AccelRange::G2 => 2.0,
        }
    }
}

/// Anti-alias filter 3 dB bandwidth: a subset of the table in data sheet §5.3 (the same table serves the
/// gyro, bank 1, and the accelerometer, bank 2).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Aaf {
    /// 42 Hz: DELT 1, DELTSQR 1, BITSHIFT 15.
    Hz42,
    /// 84 Hz: DELT 2, DELTSQR 4, BITSHIFT 13.
    Hz84,
    /// 126 Hz: DELT 3, DELTSQR 9, BITSHIFT 12.
    Hz126,
    /// 170 Hz: DELT 4, DELTSQR 16, BITSHIFT 11.
    Hz170,
    /// 213 Hz: DELT 5, DELTSQR 25, BITSHIFT 10.
    Hz213,
    /// 258 Hz: DELT 6, DELTSQR 36, BITSHIFT 10.
    Hz258,
    /// 303 Hz: DELT 7, DELTSQR 49, BITSHIFT 9.
    Hz303,
    /// 536 Hz: DELT 12, DELTSQR 144, BITSHIFT 8.
    Hz536,
    /// 997 Hz: DELT 21, DELTSQR 440, BITSHIFT 6.
    Hz997,
}

impl Aaf {
    /// Every bandwidth, lowest first.
    pub const ALL: [Aaf; 9] = [
        Aaf::Hz42,
        Aaf::Hz84,
        Aaf::Hz126,
        Aaf::Hz170,
        Aaf::Hz213,
        Aaf::Hz258,
        Aaf::Hz303,
        Aaf::Hz536,
        Aaf::Hz997,
    ];

    /// The 3 dB bandwidth in Hz.
    pub const fn bandwidth_hz(self) -> u32 {
        self.coefficients().0
    }

    /// `(bandwidth Hz, DELT, DELTSQR, BITSHIFT)` from data sheet §5.3.
    pub const fn coefficients(self) -> (u32, u8, u16, u8) {
        match self {
            Aaf::Hz42 => (42, 1, 1, 15),
            Aaf::Hz84 => (84, 2, 4, 13),
            Aaf::Hz126 => (126, 3, 9, 12),
            Aaf::Hz170 => (170, 4, 16, 11),
            Aaf::Hz213 => (213, 5, 25, 10),
            Aaf::Hz258 => (258, 6, 36, 10),
            Aaf::Hz303 => (303, 7, 49, 9),
            Aaf::Hz536 => (536, 12, 144, 8),
            Aaf::Hz997 => (997, 21, 440, 6),
        }
    }

    /// The default for an ODR: the highest bandwidth below 0.45 × ODR, keeping what aliases
    /// well down before the ODR's Nyquist frequency. At 50 Hz no entry is below 22.5 Hz, so the
    /// lowest (42 Hz) is used and the UI filter (ODR/2) does the rest.
    pub fn for_odr(odr: Odr) -> Aaf {
        // 0.45 × ODR, compared in integers: bandwidth × 100 < ODR × 45.
        let limit = odr.hz() * 45;
        Aaf::ALL
            .iter()
            .rev()
            .copied()
            .find(|aaf| aaf.bandwidth_hz() * 100 < limit)
            .unwrap_or(Aaf::Hz42)
    }
}

/// What drives the INT1 pin.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Interrupt {
    /// A pulse for every sample (UI_DRDY_INT1_EN).
    DataReady,
    /// A pulse on every sample while the FIFO holds at least `watermark` packets
    /// (FIFO_THS_INT1_EN with FIFO_WM_GT_TH), so a missed pulse is followed by another.
    Watermark,
}

/// The part's clock.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ClockSource {
    /// The internal oscillator (PLL when available).
    Internal,
    /// A 31–50 kHz clock on pin 9 (CLKIN, RTC mode): the ODR and the time stamps follow the
    /// MCU's crystal instead of the part's own oscillator.
    Clkin {
        /// The clock's frequency [Hz] (32 768 nominally): the time stamps' tick scales with it.
        hz: u32,
    },
}

/// The CLKIN frequencies the part takes [Hz] (data sheet §4.2, RTC mode).
pub const CLKIN_HZ: core::ops::RangeInclusive<u32> = 31_000..=50_000;

/// The FIFO time stamp's tick, `num / den` µs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct StampTick {
    /// Numerator [µs].
    pub num: u32,
    /// Denominator (never 0).
    pub den: u32,
}

/// A settings value that the part cannot be given.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SettingsError {
    /// The FIFO watermark is 0 or more packets than the FIFO holds.
    WatermarkOutOfRange {
        /// The watermark asked for, in packets.
        watermark: u16,
        /// The largest watermark allowed (the FIFO capacity in packets).
        max: u16,
    },
    /// The CLKIN frequency is outside what the part takes ([`CLKIN_HZ`]).
    ClkinOutOfRange {
        /// The frequency given [Hz].
        hz: u32,
    },
}

impl fmt::Display for SettingsError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            SettingsError::WatermarkOutOfRange { watermark, max } => write!(
                f,
                "FIFO watermark of {watermark} packets is outside 1..={max} (the FIFO holds {max} packets)"
            ),
            SettingsError::ClkinOutOfRange { hz } => write!(
                f,
                "CLKIN at {hz} Hz is outside the {}-{} Hz the part takes",
                CLKIN_HZ.start(),
                CLKIN_HZ.end()
            ),
        }
    }
}

impl core::error::Error for SettingsError {}

/// One register write of the configuration sequence.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct RegisterWrite {
    /// User bank (0, 1 or 2).
    pub bank: u8,
    /// Register address within the bank.
    pub address: u8,
    /// Value written, and expected on reading back, in the bits of `mask`.
    pub value: u8,
    /// The bits this configuration sets: 0xFF for a whole register; otherwise the register is
    /// read, and only these bits changed and checked (read-modify-write, as Betaflight does
    /// for INTF_CONFIG5, whose other bits are reserved).
    pub mask: u8,
}

/// The bits of a register the configuration sets (the rest it leaves as read): all, except
/// in INTF_CONFIG5, whose bits other than PIN9_FUNCTION are reserved (Betaflight writes it by
/// read-modify-write).
pub const fn owned_bits(bank: u8, address: u8) -> u8 {
    if bank == bank::BANK1 && address == reg::INTF_CONFIG5 {
        reg::INTF_CONFIG5_PIN9_MASK
    } else {
        0xFF
    }
}

/// How the part is configured.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Settings {
    /// Output data rate of both sensors.
    pub odr: Odr,
    /// Gyro full-scale range.
    pub gyro_range: GyroRange,
    /// Accelerometer full-scale range.
    pub accel_range: AccelRange,
    /// Gyro anti-alias filter.
    pub gyro_aaf: Aaf,
    /// Accelerometer anti-alias filter.
    pub accel_aaf: Aaf,
    /// FIFO watermark in packets, `1..=FIFO_CAPACITY`.
    pub watermark: u16,
    /// What drives INT1.
    pub interrupt: Interrupt,
    /// The part's clock.
    pub clock: ClockSource,
}

impl Settings {
    /// ±2000 °/s, ±16 g, the default anti-alias filters for `odr`, watermark 1, data-ready
    /// interrupt, internal clock.
    pub fn new(odr: Odr) -> Self {
        Settings {
            odr,
            gyro_range: GyroRange::Dps2000,
            accel_range: AccelRange::G16,
            gyro_aaf: Aaf::for_odr(odr),
            accel_aaf: Aaf::for_odr(odr),
            watermark: 1,
            interrupt: Interrupt::DataReady,
            clock: ClockSource::Internal,
        }
    }

    /// Checks what the types cannot: the watermark is within the FIFO, and a CLKIN within
    /// [`CLKIN_HZ`].
    pub fn validate(&self) -> Result<(), SettingsError> {
        if let ClockSource::Clkin { hz } = self.clock
            && !CLKIN_HZ.contains(&hz)
        {
            return Err(SettingsError::ClkinOutOfRange { hz });
        }
        // FIFO_CAPACITY is 128: the cast cannot truncate.
        let max = reg::FIFO_CAPACITY as u16;
        if self.watermark == 0 || self.watermark > max {
            return Err(SettingsError::WatermarkOutOfRange {
                watermark: self.watermark,
                max,
            });
        }
        Ok(())
    }

    /// Gyro scale in rad/s per count. The data sheet (data sheet §3.1) quotes 16.4 LSB/(°/s) at ±2000 °/s;
    /// that is 32768 / 2000 = 16.384 rounded, and the full scale maps to ±32768 counts, so the
    /// exact 32768 / range is used (the rounded figure is 0.1 % off).
    pub fn gyro_rad_s_per_lsb(&self) -> f32 {
        self.gyro_range.full_scale_dps() / 32768.0 * (core::f32::consts::PI / 180.0)
    }

    /// Accelerometer scale in m/s² per count: 2048 LSB/g at ±16 g, doubling per halving of the
    /// range (data sheet §3.2), i.e. 32768 / range.
    pub fn accel_m_s2_per_lsb(&self) -> f32 {
        self.accel_range.full_scale_g() / 32768.0 * STANDARD_GRAVITY
    }

    /// Nominal sample period of the ODR in µs (100 Hz → 10 000). The real period follows the
    /// part's clock (±a few % on the internal oscillator): measure it from the time stamps.
    pub fn period_us(&self) -> u32 {
        self.odr.period_us()
    }

    /// The FIFO time stamp's tick (TMST_RES = 0, "1 µs"). On the internal clock the part's PLL
    /// runs at 19.2 MHz where the counter assumes 20.48 MHz, so a tick lasts 32/30 µs of the
    /// part's clock (TDK's `inv_icm426xx_get_fifo_timestamp_resolution_us_q24`, PX4's
    /// `FIFO_TIMESTAMP_SCALING`). With CLKIN (RTC mode) that factor does not apply and the
    /// tick is one µs of a 32 768 Hz clock: `32768 / hz` µs.
    pub const fn stamp_tick(&self) -> StampTick {
        match self.clock {
            ClockSource::Internal => StampTick { num: 16, den: 15 },
            ClockSource::Clkin { hz } => StampTick {
                num: 32_768,
                den: if hz == 0 { 32_768 } else { hz },
            },
        }
    }

    /// The exact configuration sequence, written after a soft reset (every register at its
    /// reset value, sensors off) and read back by the configuration check.
    ///
    /// Order: bank 0 set-up (interface, interrupts, rates, filters, time stamps, FIFO); bank 1
    /// (gyro AAF, pin 9); bank 2 (accel AAF); then, back in bank 0, the clock source (once pin 9
    /// is CLKIN) and, last, PWR_MGMT0, which starts the sensors. The caller must wait 200 µs
    /// after that last write before any other write (PWR_MGMT0 description, data sheet §14). The AAF
    /// registers are written with the sensors off, as the data sheet asks for static filter
    /// settings.
    pub fn register_writes(&self) -> heapless::Vec<RegisterWrite, MAX_REGISTER_WRITES> {
        let mut writes = heapless::Vec::new();
        self.push_interface_and_int1(&mut writes);
        self.push_rates_and_ui_filters(&mut writes);
        self.push_time_stamps_and_fifo(&mut writes);
        self.push_bank1(&mut writes);
        self.push_bank2(&mut writes);
        self.push_clock_and_power(&mut writes);
        writes
    }

    /// Bank 0: the serial interface, and INT1's electrical behaviour.
    fn push_interface_and_int1(&self, writes: &mut Writes) {
        let b0 = bank::BANK0;
        let fast = matches!(self.odr, Odr::Hz8000 | Odr::Hz4000);
        // FIFO count in records, big-endian count and data, I²C off: SPI only, so a glitch
        // cannot switch the interface. FIFO_HOLD_LAST_DATA_EN stays 0 so that invalid samples
        // read −32768 and can be told apart.
        push(
            writes,
            b0,
            reg::INTF_CONFIG0,
            reg::INTF_CONFIG0_FIFO_COUNT_REC
                | reg::INTF_CONFIG0_FIFO_COUNT_ENDIAN
                | reg::INTF_CONFIG0_SENSOR_DATA_ENDIAN
                | reg::INTF_CONFIG0_UI_SIFS_DISABLE_I2C,
        );
        // INT1: pulsed, push-pull, active high = 0x03. (The brief's 0x02 sets only
        // INT1_DRIVE_CIRCUIT, which leaves INT1_POLARITY = 0: active low.)
        push(
            writes,
            b0,
            reg::INT_CONFIG,
            reg::INT_CONFIG_INT1_PUSH_PULL | reg::INT_CONFIG_INT1_ACTIVE_HIGH,
        );
        // Every status clears when INT_STATUS is read (the reset value, written so that the
        // check covers it): read_fifo reads INT_STATUS on every call.
        push(writes, b0, reg::INT_CONFIG0, 0x00);
        // INT_ASYNC_RESET must be 0 for the INT pins to work; at ≥ 4 kHz the 100 µs pulse and
        // de-assertion times do not fit a period, so 8 µs pulses and no de-assertion minimum.
        push(
            writes,
            b0,
            reg::INT_CONFIG1,
            if fast {
                reg::INT_CONFIG1_TPULSE_8US | reg::INT_CONFIG1_TDEASSERT_DISABLE
            } else {
                0x00
            },
        );
    }

    /// Bank 0: both sensors' range and rate, and their UI filters.
    fn push_rates_and_ui_filters(&self, writes: &mut Writes) {
        let b0 = bank::BANK0;
        let odr = self.odr.code();
        push(
            writes,
            b0,
            reg::GYRO_CONFIG0,
            (self.gyro_range.code() << reg::FS_SEL_SHIFT) | odr,
        );
        push(
            writes,
            b0,
            reg::ACCEL_CONFIG0,
            (self.accel_range.code() << reg::FS_SEL_SHIFT) | odr,
        );
        // UI filters at their lowest latency (1st order, bandwidth ODR/2), as PX4 does: the
        // anti-alias filters do the band limiting. Other bits keep their reset values
        // (GYRO_CONFIG1 0x16, ACCEL_CONFIG1 0x0D).
        push(
            writes,
            b0,
            reg::GYRO_CONFIG1,
            reg::reset_value(b0, reg::GYRO_CONFIG1) & !reg::GYRO_CONFIG1_UI_FILT_ORD_MASK,
        );
        push(writes, b0, reg::GYRO_ACCEL_CONFIG0, 0x00);
        push(
            writes,
            b0,
            reg::ACCEL_CONFIG1,
            reg::reset_value(b0, reg::ACCEL_CONFIG1) & !reg::ACCEL_CONFIG1_UI_FILT_ORD_MASK,
        );
    }

    /// Bank 0: time stamps, the FIFO's packets, watermark and mode, and what drives INT1.
    fn push_time_stamps_and_fifo(&self, writes: &mut Writes) {
        let b0 = bank::BANK0;
        // Absolute time stamps (TMST_DELTA_EN = 0) at 1 µs resolution (TMST_RES = 0); FSYNC
        // stamping off (it resets on) so every packet carries the ODR time stamp. Reserved bit
        // 5 keeps its reset value (TMST_CONFIG resets to 0x23).
        push(
            writes,
            b0,
            reg::TMST_CONFIG,
            (reg::reset_value(b0, reg::TMST_CONFIG)
                & !(reg::TMST_CONFIG_FSYNC_EN | reg::TMST_CONFIG_DELTA_EN | reg::TMST_CONFIG_RES))
                | reg::TMST_CONFIG_EN,
        );
        // No FSYNC tagging of sensor data (it resets to tagging TEMP_OUT's LSB).
        push(writes, b0, reg::FSYNC_CONFIG, 0x00);
        // Packet 3: accel + gyro + temperature + time stamp, 16 bytes. Partial reads resume
        // (read_fifo may leave packets for the next call); the watermark interrupt repeats on
        // every sample while count ≥ watermark.
        push(
            writes,
            b0,
            reg::FIFO_CONFIG1,
            reg::FIFO_CONFIG1_RESUME_PARTIAL_RD
                | reg::FIFO_CONFIG1_WM_GT_TH
                | reg::FIFO_CONFIG1_TEMP_EN
                | reg::FIFO_CONFIG1_GYRO_EN
                | reg::FIFO_CONFIG1_ACCEL_EN,
        );
        // Watermark in records (FIFO_COUNT_REC = 1), 12 bits.
        let [wm_high, wm_low] = self.watermark.to_be_bytes();
        push(writes, b0, reg::FIFO_CONFIG2, wm_low);
        push(writes, b0, reg::FIFO_CONFIG3, wm_high & 0x0F);
        // Stop-on-full, as PX4, ArduPilot and `icm426xx` use: a full FIFO keeps what it has,
        // so a read never meets packets overwritten under it; the time stamps count what the
        // part dropped meanwhile.
        push(
            writes,
            b0,
            reg::FIFO_CONFIG,
            reg::FIFO_CONFIG_MODE_STOP_ON_FULL,
        );
        // Clearing RESET_DONE_INT1_EN (it resets to 1) also makes INT_SOURCE0 a register that
        // a reset visibly changes.
        push(
            writes,
            b0,
            reg::INT_SOURCE0,
            match self.interrupt {
                Interrupt::DataReady => reg::INT_SOURCE0_UI_DRDY_INT1_EN,
                Interrupt::Watermark => reg::INT_SOURCE0_FIFO_THS_INT1_EN,
            },
        );
    }

    /// Bank 1: the gyro's anti-alias filter, and pin 9 as CLKIN when the clock is external.
    fn push_bank1(&self, writes: &mut Writes) {
        // Gyro anti-alias filter on; notch filter off (its centre frequency is not configured
        // here, so it is not left in the signal path). Reserved bits 7:2 keep their reset
        // value (0xA0).
        let b1 = bank::BANK1;
        push(
            writes,
            b1,
            reg::GYRO_CONFIG_STATIC2,
            (reg::reset_value(b1, reg::GYRO_CONFIG_STATIC2) & !reg::GYRO_CONFIG_STATIC2_AAF_DIS)
                | reg::GYRO_CONFIG_STATIC2_NF_DIS,
        );
        let (_, delt, deltsqr, bitshift) = self.gyro_aaf.coefficients();
        let [sqr_high, sqr_low] = deltsqr.to_be_bytes();
        push(writes, b1, reg::GYRO_CONFIG_STATIC3, delt & 0x3F);
        push(writes, b1, reg::GYRO_CONFIG_STATIC4, sqr_low);
        push(
            writes,
            b1,
            reg::GYRO_CONFIG_STATIC5,
            (bitshift << 4) | (sqr_high & 0x0F),
        );
        if let ClockSource::Clkin { .. } = self.clock {
            // PIN9_FUNCTION only (`owned_bits`).
            push(writes, b1, reg::INTF_CONFIG5, reg::INTF_CONFIG5_PIN9_CLKIN);
        }
    }

    /// Bank 2: the accelerometer's anti-alias filter, on (ACCEL_AAF_DIS = 0).
    fn push_bank2(&self, writes: &mut Writes) {
        let b2 = bank::BANK2;
        let (_, delt, deltsqr, bitshift) = self.accel_aaf.coefficients();
        let [sqr_high, sqr_low] = deltsqr.to_be_bytes();
        push(writes, b2, reg::ACCEL_CONFIG_STATIC2, (delt & 0x3F) << 1);
        push(writes, b2, reg::ACCEL_CONFIG_STATIC3, sqr_low);
        push(
            writes,
            b2,
            reg::ACCEL_CONFIG_STATIC4,
            (bitshift << 4) | (sqr_high & 0x0F),
        );
    }

    /// Back in bank 0: the clock source, then PWR_MGMT0, which starts the sensors (last).
    fn push_clock_and_power(&self, writes: &mut Writes) {
        let b0 = bank::BANK0;
        // Clock: PLL (the reset CLKSEL, with the reserved bits of the reset value 0x91); with
        // CLKIN, RTC_MODE once pin 9 has become CLKIN. AFSR off: the reset value has it on.
        let rtc = match self.clock {
            ClockSource::Internal => 0,
            ClockSource::Clkin { .. } => reg::INTF_CONFIG1_RTC_MODE,
        };
        push(
            writes,
            b0,
            reg::INTF_CONFIG1,
            (reg::reset_value(b0, reg::INTF_CONFIG1) & !reg::INTF_CONFIG1_AFSR_MASK)
                | reg::INTF_CONFIG1_AFSR_OFF
                | rtc,
        );
        // Last: gyro and accelerometer in low-noise mode, temperature sensor on.
        push(
            writes,
            b0,
            reg::PWR_MGMT0,
            reg::PWR_MGMT0_GYRO_LN | reg::PWR_MGMT0_ACCEL_LN,
        );
    }
}

/// The configuration sequence being built ([`Settings::register_writes`]).
type Writes = heapless::Vec<RegisterWrite, MAX_REGISTER_WRITES>;

/// Appends one write, its value limited to the bits the configuration owns ([`owned_bits`]).
fn push(writes: &mut Writes, bank: u8, address: u8, value: u8) {
    // The longest sequence is 26 writes, below the capacity of 32 (a test walks every
    // setting combination): the push cannot fail.
    let mask = owned_bits(bank, address);
    let _ = writes.push(RegisterWrite {
        bank,
        address,
        value: value & mask,
        mask,
    });
}
