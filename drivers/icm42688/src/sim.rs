//! A simulated ICM-42688-P: an [`SpiDevice`] with the register file, banks, soft reset,
//! clear-on-read status, FIFO count and the FIFO itself, fed by [`SimIcm42688::sample`].
//! It shares the register map with the driver ([`crate::registers`]).
//!
//! What is simulated: SPI framing (address byte with the read flag, auto-increment, FIFO_DATA
//! not incrementing), REG_BANK_SEL in every bank, soft reset (DEVICE_CONFIG) and power-on
//! reset, FIFO_FLUSH, INT_STATUS clear-on-read (DATA_RDY, FIFO_THS, FIFO_FULL, RESET_DONE),
//! FIFO_COUNT in records or bytes and either byte order (with COUNTH latching COUNTL), the
//! sensor data registers, a stream-to-FIFO (or stop-on-full) FIFO of packet 3, and full-scale
//! ranges. Not simulated: timing (the 1 ms reset and 200 µs power-up waits, sensor start-up),
//! filters, packets other than packet 3 (HIRES), delta or FSYNC time stamps, the pin's pulse
//! shape, banks 3 and 4 (they read 0x00 and ignore writes).

use core::cell::RefCell;
use core::convert::Infallible;

use embedded_hal::spi::{ErrorKind, ErrorType, Operation, SpiDevice};

use crate::packet::Packet;
use crate::registers::{self as reg, bank};
use crate::settings::STANDARD_GRAVITY;

/// FIFO capacity of the simulated part, in packet-3 records (2 KB / 16 bytes).
pub const SIM_FIFO_CAPACITY: usize = reg::FIFO_CAPACITY;

/// Banks with a register file (0, 1, 2).
const BANKS: usize = 3;
/// Register addresses are 7 bits (bit 7 of the address byte is the read flag).
const BANK_SIZE: usize = 128;

/// Where an SPI transaction is: waiting for the address byte, then reading or writing at an
/// address that advances with each byte.
#[derive(Clone, Copy)]
enum Phase {
    Address,
    Read(u8),
    Write(u8),
}

/// The simulated part. Feed it with [`SimIcm42688::sample`]; inject faults with
/// [`SimIcm42688::corrupt_next_header`], [`SimIcm42688::invalid_next`],
/// [`SimIcm42688::power_on_reset`] and
/// [`SimIcm42688::poke`].
#[derive(Debug, Clone)]
pub struct SimIcm42688 {
    regs: [[u8; BANK_SIZE]; BANKS],
    bank: u8,
    fifo: [[u8; Packet::LEN]; SIM_FIFO_CAPACITY],
    /// Index of the oldest packet.
    fifo_head: usize,
    /// Packets held (the oldest possibly partly read).
    fifo_len: usize,
    /// Bytes of the oldest packet already read.
    fifo_head_read: usize,
    /// FIFO_COUNTL's value latched by reading FIFO_COUNTH.
    count_latch: Option<u8>,
    corrupt_next: bool,
    invalid_next: u32,
    /// Off the bus: reads 0xFF, writes lost (a part not powered, a loose connector).
    unplugged: bool,
    pushed: u64,
    dropped_on_overflow: u64,
    ignored_samples: u64,
    flushes: u64,
    soft_resets: u64,
    power_on_resets: u64,
}

impl Default for SimIcm42688 {
    fn default() -> Self {
        Self::new()
    }
}

impl SimIcm42688 {
    /// A part just powered on: registers at their reset values, FIFO empty, sensors off,
    /// RESET_DONE set in INT_STATUS.
    pub fn new() -> Self {
        let mut sim = SimIcm42688 {
            regs: [[0; BANK_SIZE]; BANKS],
            bank: 0,
            fifo: [[0; Packet::LEN]; SIM_FIFO_CAPACITY],
            fifo_head: 0,
            fifo_len: 0,
            fifo_head_read: 0,
            count_latch: None,
            corrupt_next: false,
            invalid_next: 0,
            unplugged: false,
            pushed: 0,
            dropped_on_overflow: 0,
            ignored_samples: 0,
            flushes: 0,
            soft_resets: 0,
            power_on_resets: 0,
        };
        sim.reset_state();
        sim
    }

    /// One sample at the part's time `t_part_us` (its own clock: the caller may run it fast or
    /// slow to simulate drift). Quantised with the configured full-scale ranges (round to
    /// nearest, saturated to ±32767 as −32768 marks invalid data), it updates the data
    /// registers and DATA_RDY and, when the FIFO is in stream (or stop-on-full) mode with
    /// accel, gyro and temperature enabled, is pushed as a packet 3 whose time stamp is the low
    /// 16 bits of the part's time-stamp counter at `t_part_us` (a tick of 32/30 µs on the
    /// internal clock, as the silicon's). Ignored (and counted) while the sensors are not both in
    /// low-noise mode.
    pub fn sample(
        &mut self,
        t_part_us: u64,
        gyro_rad_s: [f64; 3],
        accel_m_s2: [f64; 3],
        temperature_c: f64,
    ) {
        let pwr = self.reg(bank::BANK0, reg::PWR_MGMT0);
        let on = reg::PWR_MGMT0_GYRO_LN | reg::PWR_MGMT0_ACCEL_LN;
        if pwr & on != on {
            self.ignored_samples += 1;
            return;
        }
        let gyro_fs = self.gyro_full_scale_dps();
        let accel_fs = self.accel_full_scale_g();
        let gyro = gyro_rad_s.map(|w| quantise(w.to_degrees() * 32768.0 / gyro_fs, 32767.0));
        let accel = accel_m_s2.map(|a| {
            quantise(
                a / f64::from(STANDARD_GRAVITY) * 32768.0 / accel_fs,
                32767.0,
            )
        });
        // FIFO temperature: raw = (T − 25) × 2.07; registers: (T − 25) × 132.48 (data sheet §14 TEMP_DATA).
        let temp_fifo = quantise((temperature_c - 25.0) * 2.07, 127.0);
        let temp_reg = quantise((temperature_c - 25.0) * 132.48, 32767.0);

        let big = self.big_endian_data();
        let mut data = [0u8; 14];
        for (dst, v) in data
            .chunks_exact_mut(2)
            .zip(core::iter::once(temp_reg).chain(accel).chain(gyro))
        {
            let v = saturate_i16(v);
            dst.copy_from_slice(&if big {
                v.to_be_bytes()
            } else {
                v.to_le_bytes()
            });
        }
        for (offset, byte) in (0u8..).zip(data) {
            self.set_reg(bank::BANK0, reg::TEMP_DATA1 + offset, byte);
        }
        self.raise(reg::INT_STATUS_DATA_RDY);

        if self.fifo_fed() {
            let tmst = self.reg(bank::BANK0, reg::TMST_CONFIG);
            let (header, timestamp) = if tmst & reg::TMST_CONFIG_EN != 0 {
                let ticks = self.stamp_ticks(t_part_us, tmst & reg::TMST_CONFIG_RES != 0);
                // Low 16 bits of the counter, by construction.
                (reg::HEADER_PACKET3, (ticks & 0xFFFF) as u16)
            } else {
                (reg::HEADER_ACCEL | reg::HEADER_GYRO, 0)
            };
            let mut accel = accel.map(saturate_i16);
            if self.invalid_next > 0 {
                // A sensor starting up: the part marks the sample invalid (data sheet §6.1).
                self.invalid_next -= 1;
                accel[0] = reg::INVALID_SAMPLE;
            }
            let packet = Packet {
                header: if self.corrupt_next {
                    self.corrupt_next = false;
                    // A flipped HEADER_20 bit: a header claiming a 20-byte packet 4.
                    header ^ reg::HEADER_20
                } else {
                    header
                },
                accel,
                gyro: gyro.map(saturate_i16),
                // temp_fifo is within ±127.
                temperature: i8::try_from(temp_fifo).unwrap_or(0),
                timestamp,
            };
            let mut bytes = packet.encode();
            if !big {
                // Accel and gyro (bytes 1..13) and the time stamp (14..16) swap byte order;
                // the header and the 8-bit temperature do not.
                for pair in bytes.get_mut(1..13).unwrap_or_default().chunks_exact_mut(2) {
                    pair.reverse();
                }
                bytes.swap(14, 15);
            }
            self.push(bytes);
        }
    }

    /// True while INT1 would be asserted (as a level: the real pin pulses): data ready since
    /// the last INT_STATUS read, FIFO count ≥ watermark, FIFO full or reset done, each as
    /// enabled in INT_SOURCE0.
    pub fn interrupt_pending(&self) -> bool {
        let source = self.reg(bank::BANK0, reg::INT_SOURCE0);
        let status = self.reg(bank::BANK0, reg::INT_STATUS);
        let watermark = self.watermark();
        (source & reg::INT_SOURCE0_UI_DRDY_INT1_EN != 0 && status & reg::INT_STATUS_DATA_RDY != 0)
            || (source & reg::INT_SOURCE0_FIFO_THS_INT1_EN != 0
                && watermark != 0
                && self.fifo_count() >= watermark)
            || (source & reg::INT_SOURCE0_FIFO_FULL_INT1_EN != 0
                && status & reg::INT_STATUS_FIFO_FULL != 0)
            || (source & reg::INT_SOURCE0_RESET_DONE_INT1_EN != 0
                && status & reg::INT_STATUS_RESET_DONE != 0)
    }

    /// The next packet pushed gets an invalid header (HEADER_20 flipped).
    pub fn corrupt_next_header(&mut self) {
        self.corrupt_next = true;
    }

    /// The next `n` packets pushed are marked invalid (−32768 in accel X), as the part marks
    /// samples of a sensor starting up.
    pub fn invalid_next(&mut self, n: u32) {
        self.invalid_next = n;
    }

    /// Takes the part off the bus (`true`: every read gives 0xFF, writes are lost) or puts it
    /// back, as it was.
    pub fn set_unplugged(&mut self, unplugged: bool) {
        self.unplugged = unplugged;
    }

    /// A brown-out: registers back to their reset values, FIFO emptied, sensors off, bank 0,
    /// RESET_DONE set.
    pub fn power_on_reset(&mut self) {
        self.power_on_resets += 1;
        self.reset_state();
    }

    /// Fault injection: sets a register without side effects, as a glitch would.
    pub fn poke(&mut self, bank: u8, address: u8, value: u8) {
        self.set_reg(bank, address, value);
    }

    /// Reads a register without side effects (INT_STATUS is not cleared, FIFO_DATA not
    /// popped; FIFO_COUNT is not computed here: see [`SimIcm42688::fifo_len`]).
    pub fn peek(&self, bank: u8, address: u8) -> u8 {
        self.reg(bank, address)
    }

    /// Packets in the FIFO now (a partly read one included).
    pub fn fifo_len(&self) -> usize {
        self.fifo_len
    }

    /// Packets pushed into the FIFO since creation.
    pub fn pushed(&self) -> u64 {
        self.pushed
    }

    /// Packets lost to a full FIFO: the oldest dropped in stream mode, or the new one in
    /// stop-on-full mode.
    pub fn dropped_on_overflow(&self) -> u64 {
        self.dropped_on_overflow
    }

    /// Samples ignored because the sensors were off.
    pub fn ignored_samples(&self) -> u64 {
        self.ignored_samples
    }

    /// FIFO flushes through SIGNAL_PATH_RESET.
    pub fn flushes(&self) -> u64 {
        self.flushes
    }

    /// Soft resets through DEVICE_CONFIG.
    pub fn soft_resets(&self) -> u64 {
        self.soft_resets
    }

    /// Power-on resets injected with [`SimIcm42688::power_on_reset`].
    pub fn power_on_resets(&self) -> u64 {
        self.power_on_resets
    }

    fn reset_state(&mut self) {
        self.regs = [[0; BANK_SIZE]; BANKS];
        for &(b, a, v) in reg::RESET_VALUES {
            self.set_reg(b, a, v);
        }
        self.bank = bank::BANK0;
        self.clear_fifo();
        self.corrupt_next = false;
        self.invalid_next = 0;
    }

    fn clear_fifo(&mut self) {
        self.fifo_head = 0;
        self.fifo_len = 0;
        self.fifo_head_read = 0;
        self.count_latch = None;
    }

    fn reg(&self, bank: u8, address: u8) -> u8 {
        self.regs
            .get(usize::from(bank))
            .and_then(|b| b.get(usize::from(address)))
            .copied()
            .unwrap_or(0)
    }

    fn set_reg(&mut self, bank: u8, address: u8, value: u8) {
        if let Some(r) = self
            .regs
            .get_mut(usize::from(bank))
            .and_then(|b| b.get_mut(usize::from(address)))
        {
            *r = value;
        }
    }

    fn raise(&mut self, bits: u8) {
        let status = self.reg(bank::BANK0, reg::INT_STATUS);
        self.set_reg(bank::BANK0, reg::INT_STATUS, status | bits);
    }

    fn gyro_full_scale_dps(&self) -> f64 {
        let code = self.reg(bank::BANK0, reg::GYRO_CONFIG0) >> reg::FS_SEL_SHIFT;
        // 000 = ±2000 °/s, halving per code (down to ±15.625 at 111).
        2000.0 / f64::from(1u8 << (code & 0x07))
    }

    fn accel_full_scale_g(&self) -> f64 {
        let code = self.reg(bank::BANK0, reg::ACCEL_CONFIG0) >> reg::FS_SEL_SHIFT;
        // 000 = ±16 g … 011 = ±2 g; 1xx is reserved, read here as ±2 g.
        16.0 / f64::from(1u8 << (code.min(3)))
    }

    /// The time-stamp counter at part time `t_part_us`, as the silicon counts it. On the
    /// internal clock the counter assumes a 20.48 MHz PLL that runs at 19.2 MHz, so its "1 µs"
    /// tick lasts 32/30 µs (and "16 µs", 16 × 32/30). In RTC mode the counter runs on CLKIN,
    /// the part's clock then (the caller's `t_part_us` follows it): one tick per µs of it, or
    /// per 32 768 Hz period at the coarse resolution.
    fn stamp_ticks(&self, t_part_us: u64, coarse: bool) -> u64 {
        let rtc = self.reg(bank::BANK0, reg::INTF_CONFIG1) & reg::INTF_CONFIG1_RTC_MODE != 0;
        let t = u128::from(t_part_us);
        let ticks = match (rtc, coarse) {
            (false, false) => t * 30 / 32,
            (false, true) => t * 30 / (32 * 16),
            (true, false) => t,
            (true, true) => t * 32_768 / 1_000_000,
        };
        u64::try_from(ticks).unwrap_or(u64::MAX)
    }

    fn big_endian_data(&self) -> bool {
        self.reg(bank::BANK0, reg::INTF_CONFIG0) & reg::INTF_CONFIG0_SENSOR_DATA_ENDIAN != 0
    }

    fn fifo_fed(&self) -> bool {
        let mode = self.reg(bank::BANK0, reg::FIFO_CONFIG) & reg::FIFO_CONFIG_MODE_MASK;
        let config1 = self.reg(bank::BANK0, reg::FIFO_CONFIG1);
        let packet3 =
            reg::FIFO_CONFIG1_ACCEL_EN | reg::FIFO_CONFIG1_GYRO_EN | reg::FIFO_CONFIG1_TEMP_EN;
        mode != reg::FIFO_CONFIG_MODE_BYPASS
            && config1 & (packet3 | reg::FIFO_CONFIG1_HIRES_EN) == packet3
    }

    fn count_in_records(&self) -> bool {
        self.reg(bank::BANK0, reg::INTF_CONFIG0) & reg::INTF_CONFIG0_FIFO_COUNT_REC != 0
    }

    /// FIFO_COUNT as the part reports it: records or bytes per FIFO_COUNT_REC.
    fn fifo_count(&self) -> u16 {
        let count = if self.count_in_records() {
            self.fifo_len
        } else {
            self.fifo_len * Packet::LEN - self.fifo_head_read
        };
        // At most 2048.
        u16::try_from(count).unwrap_or(u16::MAX)
    }

    /// The 12-bit watermark of FIFO_CONFIG2/3, in FIFO_COUNT's unit.
    fn watermark(&self) -> u16 {
        let low = self.reg(bank::BANK0, reg::FIFO_CONFIG2);
        let high = self.reg(bank::BANK0, reg::FIFO_CONFIG3) & 0x0F;
        u16::from_be_bytes([high, low])
    }

    fn push(&mut self, bytes: [u8; Packet::LEN]) {
        if self.fifo_len >= SIM_FIFO_CAPACITY {
            self.dropped_on_overflow += 1;
            let mode = self.reg(bank::BANK0, reg::FIFO_CONFIG) & reg::FIFO_CONFIG_MODE_MASK;
            if mode != reg::FIFO_CONFIG_MODE_STREAM {
                // Stop-on-full: the new packet is lost.
                return;
            }
            // Stream-to-FIFO: the oldest packet makes room.
            self.fifo_head = (self.fifo_head + 1) % SIM_FIFO_CAPACITY;
            self.fifo_len -= 1;
            self.fifo_head_read = 0;
        }
        let tail = (self.fifo_head + self.fifo_len) % SIM_FIFO_CAPACITY;
        if let Some(slot) = self.fifo.get_mut(tail) {
            *slot = bytes;
        }
        self.fifo_len += 1;
        self.pushed += 1;
        // FIFO_FULL_INT sets when the FIFO reaches full size (INT_STATUS description), so also
        // when it fills exactly, before anything is lost.
        if self.fifo_len == SIM_FIFO_CAPACITY {
            self.raise(reg::INT_STATUS_FIFO_FULL);
        }
        let watermark = self.watermark();
        let count = self.fifo_count();
        let every = self.reg(bank::BANK0, reg::FIFO_CONFIG1) & reg::FIFO_CONFIG1_WM_GT_TH != 0;
        if watermark != 0 && (count == watermark || (every && count > watermark)) {
            self.raise(reg::INT_STATUS_FIFO_THS);
        }
    }

    fn pop_fifo_byte(&mut self) -> u8 {
        if self.fifo_len == 0 {
            return reg::FIFO_EMPTY_BYTE;
        }
        let byte = self
            .fifo
            .get(self.fifo_head)
            .and_then(|p| p.get(self.fifo_head_read))
            .copied()
            .unwrap_or(reg::FIFO_EMPTY_BYTE);
        self.fifo_head_read += 1;
        if self.fifo_head_read >= Packet::LEN {
            self.fifo_head = (self.fifo_head + 1) % SIM_FIFO_CAPACITY;
            self.fifo_len -= 1;
            self.fifo_head_read = 0;
        }
        byte
    }

    /// A register read over SPI, with its side effects.
    fn read_register(&mut self, address: u8) -> u8 {
        if address == reg::REG_BANK_SEL {
            return self.bank;
        }
        if self.bank != bank::BANK0 {
            return self.reg(self.bank, address);
        }
        match address {
            reg::INT_STATUS => {
                let status = self.reg(bank::BANK0, reg::INT_STATUS);
                self.set_reg(bank::BANK0, reg::INT_STATUS, 0);
                status
            }
            reg::FIFO_COUNTH | reg::FIFO_COUNTL => {
                let [high, low] = self.fifo_count().to_be_bytes();
                let big = self.reg(bank::BANK0, reg::INTF_CONFIG0)
                    & reg::INTF_CONFIG0_FIFO_COUNT_ENDIAN
                    != 0;
                let (first, second) = if big { (high, low) } else { (low, high) };
                if address == reg::FIFO_COUNTH {
                    // Reading COUNTH latches COUNTL, so the pair is consistent.
                    self.count_latch = Some(second);
                    first
                } else {
                    self.count_latch.take().unwrap_or(second)
                }
            }
            reg::FIFO_DATA => self.pop_fifo_byte(),
            _ => self.reg(bank::BANK0, address),
        }
    }

    /// A register write over SPI, with its side effects.
    fn write_register(&mut self, address: u8, value: u8) {
        if address == reg::REG_BANK_SEL {
            self.bank = value & 0x07;
            return;
        }
        if self.bank != bank::BANK0 {
            self.set_reg(self.bank, address, value);
            return;
        }
        match address {
            reg::DEVICE_CONFIG if value & reg::DEVICE_CONFIG_SOFT_RESET != 0 => {
                self.soft_resets += 1;
                self.reset_state();
            }
            reg::SIGNAL_PATH_RESET => {
                if value & reg::SIGNAL_PATH_RESET_FIFO_FLUSH != 0 {
                    self.flushes += 1;
                    self.clear_fifo();
                }
                // Its bits clear themselves.
            }
            // Read-only: data, status, FIFO, WHO_AM_I.
            reg::TEMP_DATA1..=0x38 | reg::WHO_AM_I => {}
            _ => self.set_reg(bank::BANK0, address, value),
        }
    }

    /// One byte on the bus: MOSI in, MISO out.
    fn clock(&mut self, phase: &mut Phase, mosi: u8) -> u8 {
        match *phase {
            Phase::Address => {
                let address = mosi & !reg::SPI_READ;
                *phase = if mosi & reg::SPI_READ != 0 {
                    Phase::Read(address)
                } else {
                    Phase::Write(address)
                };
                0x00
            }
            Phase::Read(address) => {
                let value = self.read_register(address);
                *phase = Phase::Read(self.next_address(address));
                value
            }
            Phase::Write(address) => {
                self.write_register(address, mosi);
                *phase = Phase::Write(self.next_address(address));
                0x00
            }
        }
    }

    /// Auto-increment within the 7-bit address space, except at FIFO_DATA in bank 0.
    fn next_address(&self, address: u8) -> u8 {
        if self.bank == bank::BANK0 && address == reg::FIFO_DATA {
            address
        } else {
            address.wrapping_add(1) & !reg::SPI_READ
        }
    }
}

/// Rounds to nearest (halves away from zero) and saturates to ±`limit`; NaN gives 0.
fn quantise(value: f64, limit: f64) -> i32 {
    let clamped = value.clamp(-limit, limit);
    // Within ±32767 after the clamp: the casts are exact and cannot saturate. `as` maps NaN
    // to 0.
    if clamped >= 0.0 {
        (clamped + 0.5) as i32
    } else {
        (clamped - 0.5) as i32
    }
}

/// A quantised value as i16 (already within ±32767).
fn saturate_i16(v: i32) -> i16 {
    i16::try_from(v.clamp(-32767, 32767)).unwrap_or(0)
}

impl ErrorType for SimIcm42688 {
    type Error = Infallible;
}

impl SpiDevice for SimIcm42688 {
    /// One chip-select assertion: the first byte clocked is the address.
    fn transaction(&mut self, operations: &mut [Operation<'_, u8>]) -> Result<(), Infallible> {
        if self.unplugged {
            // MISO floats high.
            for op in operations {
                match op {
                    Operation::Read(buf) | Operation::TransferInPlace(buf) => buf.fill(0xFF),
                    Operation::Transfer(read, _) => read.fill(0xFF),
                    Operation::Write(_) | Operation::DelayNs(_) => {}
                }
            }
            return Ok(());
        }
        let mut phase = Phase::Address;
        for op in operations {
            match op {
                // The bus sends 0x00 while reading.
                Operation::Read(buf) => {
                    for b in buf.iter_mut() {
                        *b = self.clock(&mut phase, 0x00);
                    }
                }
                Operation::Write(buf) => {
                    for &b in buf.iter() {
                        self.clock(&mut phase, b);
                    }
                }
                Operation::Transfer(read, write) => {
                    // Clocks max(len) bytes: write padded with 0x00, extra reads discarded.
                    let len = read.len().max(write.len());
                    for i in 0..len {
                        let mosi = write.get(i).copied().unwrap_or(0x00);
                        let miso = self.clock(&mut phase, mosi);
                        if let Some(r) = read.get_mut(i) {
                            *r = miso;
                        }
                    }
                }
                Operation::TransferInPlace(buf) => {
                    for b in buf.iter_mut() {
                        *b = self.clock(&mut phase, *b);
                    }
                }
                Operation::DelayNs(_) => {}
            }
        }
        Ok(())
    }
}

/// A shared handle on a [`SimIcm42688`], so that a test or simulation can feed samples and
/// inject faults while the driver owns the SPI device:
///
/// ```
/// # use core::cell::RefCell;
/// # use icm42688::{Icm42688, Odr, Settings, SimIcm42688, sim::SharedSim};
/// let part = RefCell::new(SimIcm42688::new());
/// let mut imu = Icm42688::new(SharedSim::new(&part), Settings::new(Odr::Hz100));
/// part.borrow_mut().sample(0, [0.0; 3], [0.0, 0.0, 9.8], 25.0);
/// ```
#[derive(Debug, Clone, Copy)]
pub struct SharedSim<'a> {
    part: &'a RefCell<SimIcm42688>,
}

impl<'a> SharedSim<'a> {
    /// A handle on `part`.
    pub fn new(part: &'a RefCell<SimIcm42688>) -> Self {
        SharedSim { part }
    }
}

impl ErrorType for SharedSim<'_> {
    /// [`ErrorKind::Other`] when the part is already borrowed (a transaction started while the
    /// caller holds `borrow_mut`).
    type Error = ErrorKind;
}

impl SpiDevice for SharedSim<'_> {
    fn transaction(&mut self, operations: &mut [Operation<'_, u8>]) -> Result<(), ErrorKind> {
        let mut part = self.part.try_borrow_mut().map_err(|_| ErrorKind::Other)?;
        match part.transaction(operations) {
            Ok(()) => Ok(()),
            Err(never) => match never {},
        }
    }
}
