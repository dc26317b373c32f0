//! Register addresses, bit fields and reset values of the ICM-42688-P (DS-000347 §13, with the
//! bank 0/1/2 descriptions in data sheet §14–§16). The driver and the simulated part both use this one map.
//!
//! Addresses are 7 bits: on SPI, bit 7 of the first byte is the read flag (data sheet §9, "SPI interface").

/// Bit 7 of the SPI address byte: set for a read, clear for a write.
pub const SPI_READ: u8 = 0x80;

/// The bank that each register lives in, as written to [`REG_BANK_SEL`].
pub mod bank {
    /// User bank 0: everything used at run time.
    pub const BANK0: u8 = 0;
    /// User bank 1: gyro anti-alias filter, pin 9 function.
    pub const BANK1: u8 = 1;
    /// User bank 2: accelerometer anti-alias filter.
    pub const BANK2: u8 = 2;
}

/// REG_BANK_SEL: present at the same address in every bank; bits 2:0 select the bank.
pub const REG_BANK_SEL: u8 = 0x76;

// ---------------------------------------------------------------------------------------------
// Bank 0
// ---------------------------------------------------------------------------------------------

/// DEVICE_CONFIG (bank 0).
pub const DEVICE_CONFIG: u8 = 0x11;
/// DEVICE_CONFIG bit 0: soft reset of the whole configuration; wait ≥ 1 ms afterwards.
pub const DEVICE_CONFIG_SOFT_RESET: u8 = 1 << 0;

/// INT_CONFIG (bank 0): INT1/INT2 pin mode, drive and polarity.
pub const INT_CONFIG: u8 = 0x14;
/// INT_CONFIG bit 2 INT1_MODE: 1 latched, 0 pulsed.
pub const INT_CONFIG_INT1_LATCHED: u8 = 1 << 2;
/// INT_CONFIG bit 1 INT1_DRIVE_CIRCUIT: 1 push-pull, 0 open drain.
pub const INT_CONFIG_INT1_PUSH_PULL: u8 = 1 << 1;
/// INT_CONFIG bit 0 INT1_POLARITY: 1 active high, 0 active low.
pub const INT_CONFIG_INT1_ACTIVE_HIGH: u8 = 1 << 0;

/// FIFO_CONFIG (bank 0): bits 7:6 FIFO_MODE.
pub const FIFO_CONFIG: u8 = 0x16;
/// FIFO_CONFIG FIFO_MODE mask.
pub const FIFO_CONFIG_MODE_MASK: u8 = 0b11 << 6;
/// FIFO_MODE 00: bypass (the FIFO is not fed).
pub const FIFO_CONFIG_MODE_BYPASS: u8 = 0b00 << 6;
/// FIFO_MODE 01: stream-to-FIFO (when full, new packets replace the oldest).
pub const FIFO_CONFIG_MODE_STREAM: u8 = 0b01 << 6;
/// FIFO_CONFIG FIFO_MODE = 10: stop-on-full (a full FIFO drops new packets and keeps its
/// contents aligned while it is read).
pub const FIFO_CONFIG_MODE_STOP_ON_FULL: u8 = 0b10 << 6;

/// TEMP_DATA1 (bank 0): first of the sensor data registers (temperature, accel, gyro).
pub const TEMP_DATA1: u8 = 0x1D;
/// ACCEL_DATA_X1 (bank 0).
pub const ACCEL_DATA_X1: u8 = 0x1F;
/// GYRO_DATA_X1 (bank 0).
pub const GYRO_DATA_X1: u8 = 0x25;

/// INT_STATUS (bank 0): cleared on read.
pub const INT_STATUS: u8 = 0x2D;
/// INT_STATUS bit 4: set when a (soft or power-on) reset has completed.
pub const INT_STATUS_RESET_DONE: u8 = 1 << 4;
/// INT_STATUS bit 3: new sample in the data registers.
pub const INT_STATUS_DATA_RDY: u8 = 1 << 3;
/// INT_STATUS bit 2: FIFO count reached the watermark.
pub const INT_STATUS_FIFO_THS: u8 = 1 << 2;
/// INT_STATUS bit 1: the FIFO reached its full size.
pub const INT_STATUS_FIFO_FULL: u8 = 1 << 1;

/// FIFO_COUNTH (bank 0). With FIFO_COUNT_ENDIAN = 1 (big) it holds the high byte; reading it
/// latches FIFO_COUNTL, so the two are read in one burst.
pub const FIFO_COUNTH: u8 = 0x2E;
/// FIFO_COUNTL (bank 0).
pub const FIFO_COUNTL: u8 = 0x2F;
/// FIFO_DATA (bank 0): each byte read pops one FIFO byte; a burst does not advance the address.
pub const FIFO_DATA: u8 = 0x30;
/// What FIFO_DATA reads when the FIFO is empty (its reset value, data sheet §14 register table): a header
/// byte with HEADER_MSG set.
pub const FIFO_EMPTY_BYTE: u8 = 0xFF;

/// SIGNAL_PATH_RESET (bank 0).
pub const SIGNAL_PATH_RESET: u8 = 0x4B;
/// SIGNAL_PATH_RESET bit 1: flush the FIFO (self-clearing).
pub const SIGNAL_PATH_RESET_FIFO_FLUSH: u8 = 1 << 1;

/// INTF_CONFIG0 (bank 0).
pub const INTF_CONFIG0: u8 = 0x4C;
/// INTF_CONFIG0 bit 7: sensor registers and FIFO repeat the last valid sample instead of
/// marking invalid ones with −32768.
pub const INTF_CONFIG0_FIFO_HOLD_LAST_DATA_EN: u8 = 1 << 7;
/// INTF_CONFIG0 bit 6: FIFO_COUNT and the watermark count records instead of bytes.
pub const INTF_CONFIG0_FIFO_COUNT_REC: u8 = 1 << 6;
/// INTF_CONFIG0 bit 5: FIFO_COUNT is big-endian (high byte at FIFO_COUNTH).
pub const INTF_CONFIG0_FIFO_COUNT_ENDIAN: u8 = 1 << 5;
/// INTF_CONFIG0 bit 4: sensor data (registers and FIFO) are big-endian.
pub const INTF_CONFIG0_SENSOR_DATA_ENDIAN: u8 = 1 << 4;
/// INTF_CONFIG0 bits 1:0 UI_SIFS_CFG = 11: I²C interface disabled (SPI only).
pub const INTF_CONFIG0_UI_SIFS_DISABLE_I2C: u8 = 0b11;

/// INTF_CONFIG1 (bank 0).
pub const INTF_CONFIG1: u8 = 0x4D;
/// INTF_CONFIG1 bit 2: RTC_MODE, a clock on pin 9 (CLKIN) is required and used.
pub const INTF_CONFIG1_RTC_MODE: u8 = 1 << 2;
/// INTF_CONFIG1 bits 1:0 CLKSEL = 01: PLL when available, else the RC oscillator.
pub const INTF_CONFIG1_CLKSEL_PLL: u8 = 0b01;
/// INTF_CONFIG1 bits 7:6: the adaptive full-scale range (AFSR) mode.
pub const INTF_CONFIG1_AFSR_MASK: u8 = 0b1100_0000;
/// INTF_CONFIG1 bits 7:6 = 01: AFSR off. At reset (10) it is on, and the part holds the gyro's
/// output for 1-2 ms when it switches its range near 100 °/s (ArduPilot #25025, Betaflight
/// #13132 and PX4 #22254 turn it off, TDK's driver likewise).
pub const INTF_CONFIG1_AFSR_OFF: u8 = 0b0100_0000;

/// PWR_MGMT0 (bank 0).
pub const PWR_MGMT0: u8 = 0x4E;
/// PWR_MGMT0 bits 3:2 GYRO_MODE = 11: low-noise mode.
pub const PWR_MGMT0_GYRO_LN: u8 = 0b11 << 2;
/// PWR_MGMT0 bits 1:0 ACCEL_MODE = 11: low-noise mode.
pub const PWR_MGMT0_ACCEL_LN: u8 = 0b11;

/// GYRO_CONFIG0 (bank 0): bits 7:5 GYRO_FS_SEL, bits 3:0 GYRO_ODR.
pub const GYRO_CONFIG0: u8 = 0x4F;
/// ACCEL_CONFIG0 (bank 0): bits 7:5 ACCEL_FS_SEL, bits 3:0 ACCEL_ODR.
pub const ACCEL_CONFIG0: u8 = 0x50;
/// Shift of the FS_SEL field in GYRO_CONFIG0 / ACCEL_CONFIG0.
pub const FS_SEL_SHIFT: u8 = 5;
/// Mask of the ODR field in GYRO_CONFIG0 / ACCEL_CONFIG0.
pub const ODR_MASK: u8 = 0x0F;

/// GYRO_CONFIG1 (bank 0): bits 3:2 GYRO_UI_FILT_ORD (00 = 1st order).
pub const GYRO_CONFIG1: u8 = 0x51;
/// GYRO_CONFIG1 GYRO_UI_FILT_ORD mask.
pub const GYRO_CONFIG1_UI_FILT_ORD_MASK: u8 = 0b11 << 2;
/// GYRO_ACCEL_CONFIG0 (bank 0): bits 7:4 ACCEL_UI_FILT_BW, bits 3:0 GYRO_UI_FILT_BW
/// (0 = ODR/2 in low-noise mode).
pub const GYRO_ACCEL_CONFIG0: u8 = 0x52;
/// ACCEL_CONFIG1 (bank 0): bits 4:3 ACCEL_UI_FILT_ORD (00 = 1st order).
pub const ACCEL_CONFIG1: u8 = 0x53;
/// ACCEL_CONFIG1 ACCEL_UI_FILT_ORD mask.
pub const ACCEL_CONFIG1_UI_FILT_ORD_MASK: u8 = 0b11 << 3;

/// TMST_CONFIG (bank 0).
pub const TMST_CONFIG: u8 = 0x54;
/// TMST_CONFIG bit 3 TMST_RES: 0 = "1 µs"; 1 = "16 µs", or one RTC period with RTC_MODE.
/// On the internal clock both are 32/30 of that ([`crate::Settings::stamp_tick`]).
pub const TMST_CONFIG_RES: u8 = 1 << 3;
/// TMST_CONFIG bit 2 TMST_DELTA_EN: time since the last ODR instead of an absolute count.
pub const TMST_CONFIG_DELTA_EN: u8 = 1 << 2;
/// TMST_CONFIG bit 1 TMST_FSYNC_EN: FSYNC time stamping.
pub const TMST_CONFIG_FSYNC_EN: u8 = 1 << 1;
/// TMST_CONFIG bit 0 TMST_EN: time stamps on.
pub const TMST_CONFIG_EN: u8 = 1 << 0;

/// FIFO_CONFIG1 (bank 0): what goes into the FIFO.
pub const FIFO_CONFIG1: u8 = 0x5F;
/// FIFO_CONFIG1 bit 6: a partial FIFO read resumes where it stopped.
pub const FIFO_CONFIG1_RESUME_PARTIAL_RD: u8 = 1 << 6;
/// FIFO_CONFIG1 bit 5: the watermark interrupt fires on every ODR while count ≥ watermark
/// (instead of once, when it equals the watermark).
pub const FIFO_CONFIG1_WM_GT_TH: u8 = 1 << 5;
/// FIFO_CONFIG1 bit 4: 20-bit packets (packet 4). Not used: we want packet 3.
pub const FIFO_CONFIG1_HIRES_EN: u8 = 1 << 4;
/// FIFO_CONFIG1 bit 3: FSYNC time stamps replace ODR time stamps in the FIFO.
pub const FIFO_CONFIG1_TMST_FSYNC_EN: u8 = 1 << 3;
/// FIFO_CONFIG1 bit 2: temperature in the FIFO.
pub const FIFO_CONFIG1_TEMP_EN: u8 = 1 << 2;
/// FIFO_CONFIG1 bit 1: gyro in the FIFO.
pub const FIFO_CONFIG1_GYRO_EN: u8 = 1 << 1;
/// FIFO_CONFIG1 bit 0: accelerometer in the FIFO.
pub const FIFO_CONFIG1_ACCEL_EN: u8 = 1 << 0;

/// FIFO_CONFIG2 (bank 0): watermark bits 7:0.
pub const FIFO_CONFIG2: u8 = 0x60;
/// FIFO_CONFIG3 (bank 0): watermark bits 11:8 (bits 3:0 of the register).
pub const FIFO_CONFIG3: u8 = 0x61;
/// FSYNC_CONFIG (bank 0): bits 6:4 FSYNC_UI_SEL (000 = no FSYNC tagging).
pub const FSYNC_CONFIG: u8 = 0x62;
/// INT_CONFIG0 (bank 0): how each interrupt status is cleared (00 = on reading INT_STATUS).
pub const INT_CONFIG0: u8 = 0x63;

/// INT_CONFIG1 (bank 0).
pub const INT_CONFIG1: u8 = 0x64;
/// INT_CONFIG1 bit 6: 8 µs interrupt pulses (required for ODR ≥ 4 kHz), else 100 µs.
pub const INT_CONFIG1_TPULSE_8US: u8 = 1 << 6;
/// INT_CONFIG1 bit 5: no minimum de-assertion time (required for ODR ≥ 4 kHz).
pub const INT_CONFIG1_TDEASSERT_DISABLE: u8 = 1 << 5;
/// INT_CONFIG1 bit 4 INT_ASYNC_RESET: resets to 1; must be cleared for proper INT1/INT2 use.
pub const INT_CONFIG1_ASYNC_RESET: u8 = 1 << 4;

/// INT_SOURCE0 (bank 0): what drives INT1.
pub const INT_SOURCE0: u8 = 0x65;
/// INT_SOURCE0 bit 4: reset done → INT1.
pub const INT_SOURCE0_RESET_DONE_INT1_EN: u8 = 1 << 4;
/// INT_SOURCE0 bit 3: data ready → INT1.
pub const INT_SOURCE0_UI_DRDY_INT1_EN: u8 = 1 << 3;
/// INT_SOURCE0 bit 2: FIFO watermark → INT1.
pub const INT_SOURCE0_FIFO_THS_INT1_EN: u8 = 1 << 2;
/// INT_SOURCE0 bit 1: FIFO full → INT1.
pub const INT_SOURCE0_FIFO_FULL_INT1_EN: u8 = 1 << 1;

/// WHO_AM_I (bank 0).
pub const WHO_AM_I: u8 = 0x75;
/// WHO_AM_I value of the ICM-42688-P.
pub const WHO_AM_I_VALUE: u8 = 0x47;

// ---------------------------------------------------------------------------------------------
// Bank 1
// ---------------------------------------------------------------------------------------------

/// GYRO_CONFIG_STATIC2 (bank 1): bit 1 GYRO_AAF_DIS, bit 0 GYRO_NF_DIS; bits 7:2 reserved.
pub const GYRO_CONFIG_STATIC2: u8 = 0x0B;
/// GYRO_CONFIG_STATIC2 bit 1: anti-alias filter off.
pub const GYRO_CONFIG_STATIC2_AAF_DIS: u8 = 1 << 1;
/// GYRO_CONFIG_STATIC2 bit 0: notch filter off.
pub const GYRO_CONFIG_STATIC2_NF_DIS: u8 = 1 << 0;
/// GYRO_CONFIG_STATIC3 (bank 1): bits 5:0 GYRO_AAF_DELT.
pub const GYRO_CONFIG_STATIC3: u8 = 0x0C;
/// GYRO_CONFIG_STATIC4 (bank 1): GYRO_AAF_DELTSQR bits 7:0.
pub const GYRO_CONFIG_STATIC4: u8 = 0x0D;
/// GYRO_CONFIG_STATIC5 (bank 1): bits 7:4 GYRO_AAF_BITSHIFT, bits 3:0 DELTSQR bits 11:8.
pub const GYRO_CONFIG_STATIC5: u8 = 0x0E;
/// INTF_CONFIG5 (bank 1): bits 2:1 PIN9_FUNCTION (00 INT2, 01 FSYNC, 10 CLKIN).
pub const INTF_CONFIG5: u8 = 0x7B;
/// INTF_CONFIG5 bits 2:1, PIN9_FUNCTION.
pub const INTF_CONFIG5_PIN9_MASK: u8 = 0b11 << 1;
/// INTF_CONFIG5 PIN9_FUNCTION = 10: pin 9 is CLKIN.
pub const INTF_CONFIG5_PIN9_CLKIN: u8 = 0b10 << 1;

// ---------------------------------------------------------------------------------------------
// Bank 2
// ---------------------------------------------------------------------------------------------

/// ACCEL_CONFIG_STATIC2 (bank 2): bits 6:1 ACCEL_AAF_DELT, bit 0 ACCEL_AAF_DIS.
pub const ACCEL_CONFIG_STATIC2: u8 = 0x03;
/// ACCEL_CONFIG_STATIC3 (bank 2): ACCEL_AAF_DELTSQR bits 7:0.
pub const ACCEL_CONFIG_STATIC3: u8 = 0x04;
/// ACCEL_CONFIG_STATIC4 (bank 2): bits 7:4 ACCEL_AAF_BITSHIFT, bits 3:0 DELTSQR bits 11:8.
pub const ACCEL_CONFIG_STATIC4: u8 = 0x05;

// ---------------------------------------------------------------------------------------------
// Reset values (data sheet §13 register map) of the registers that are configured or that the simulated
// part gives behaviour to. Where a configured register has reserved bits, the value written
// keeps them as they reset.
// ---------------------------------------------------------------------------------------------

/// Reset values, as `(bank, address, value)`; every register not listed resets to 0x00.
pub const RESET_VALUES: &[(u8, u8, u8)] = &[
    (bank::BANK0, 0x13, 0x05), // DRIVE_CONFIG
    // Sensor data registers read −32768 (invalid) until the sensors run.
    (bank::BANK0, TEMP_DATA1, 0x80),
    (bank::BANK0, ACCEL_DATA_X1, 0x80),
    (bank::BANK0, ACCEL_DATA_X1 + 2, 0x80),
    (bank::BANK0, ACCEL_DATA_X1 + 4, 0x80),
    (bank::BANK0, GYRO_DATA_X1, 0x80),
    (bank::BANK0, GYRO_DATA_X1 + 2, 0x80),
    (bank::BANK0, GYRO_DATA_X1 + 4, 0x80),
    (bank::BANK0, INT_STATUS, INT_STATUS_RESET_DONE),
    (bank::BANK0, INTF_CONFIG0, 0x30),
    (bank::BANK0, INTF_CONFIG1, 0x91),
    (bank::BANK0, GYRO_CONFIG0, 0x06),
    (bank::BANK0, ACCEL_CONFIG0, 0x06),
    (bank::BANK0, GYRO_CONFIG1, 0x16),
    (bank::BANK0, GYRO_ACCEL_CONFIG0, 0x11),
    (bank::BANK0, ACCEL_CONFIG1, 0x0D),
    (bank::BANK0, TMST_CONFIG, 0x23),
    (bank::BANK0, FSYNC_CONFIG, 0x10),
    (bank::BANK0, INT_CONFIG1, 0x10),
    (bank::BANK0, INT_SOURCE0, 0x10),
    (bank::BANK0, WHO_AM_I, WHO_AM_I_VALUE),
    (bank::BANK1, GYRO_CONFIG_STATIC2, 0xA0),
    (bank::BANK1, GYRO_CONFIG_STATIC3, 0x0D),
    (bank::BANK1, GYRO_CONFIG_STATIC4, 0xAA),
    (bank::BANK1, GYRO_CONFIG_STATIC5, 0x80),
    (bank::BANK2, ACCEL_CONFIG_STATIC2, 0x30),
    (bank::BANK2, ACCEL_CONFIG_STATIC3, 0x40),
    (bank::BANK2, ACCEL_CONFIG_STATIC4, 0x62),
];

/// The reset value of one register (0x00 where [`RESET_VALUES`] does not list it).
pub fn reset_value(bank: u8, address: u8) -> u8 {
    RESET_VALUES
        .iter()
        .find(|&&(b, a, _)| b == bank && a == address)
        .map_or(0x00, |&(_, _, v)| v)
}

// ---------------------------------------------------------------------------------------------
// FIFO
// ---------------------------------------------------------------------------------------------

/// FIFO size in bytes (data sheet §6: 2 KB).
pub const FIFO_BYTES: usize = 2048;
/// FIFO capacity in packet-3 records of 16 bytes: 2048 / 16 = 128.
pub const FIFO_CAPACITY: usize = FIFO_BYTES / 16;

/// FIFO header bit 7 HEADER_MSG: the FIFO is empty (or the packet is invalid).
pub const HEADER_MSG: u8 = 1 << 7;
/// FIFO header bit 6: the packet holds accelerometer data.
pub const HEADER_ACCEL: u8 = 1 << 6;
/// FIFO header bit 5: the packet holds gyro data.
pub const HEADER_GYRO: u8 = 1 << 5;
/// FIFO header bit 4: 20-bit (packet 4) data.
pub const HEADER_20: u8 = 1 << 4;
/// FIFO header bits 3:2 HEADER_TIMESTAMP_FSYNC = 10: the packet holds an ODR time stamp.
pub const HEADER_TIMESTAMP_ODR: u8 = 0b10 << 2;
/// FIFO header bits 1:0 HEADER_ODR_ACCEL, HEADER_ODR_GYRO: the sensor's ODR differs from the
/// previous packet's (a rate change): the packet's spacing is not the period.
pub const HEADER_ODR_CHANGED: u8 = 0b11;
/// Mask of the header bits that identify a packet 3 (bits 1:0 flag ODR changes and may be set).
pub const HEADER_PACKET3_MASK: u8 = 0xFC;
/// A packet-3 header with an ODR time stamp, under [`HEADER_PACKET3_MASK`]: 0x68.
pub const HEADER_PACKET3: u8 = HEADER_ACCEL | HEADER_GYRO | HEADER_TIMESTAMP_ODR;
/// The value that marks an invalid sensor sample (e.g. a sensor still starting up).
pub const INVALID_SAMPLE: i16 = i16::MIN;
