//! The blocking driver on an `embedded-hal` 1.0 [`SpiDevice`].
//!
//! SPI framing (data sheet §9): the first byte of a transaction is the register address with bit 7 set for
//! a read; the following bytes auto-increment the address, except at FIFO_DATA, where each byte
//! pops one FIFO byte. Registers are written one per transaction, `[address, value]`.
//!
//! The driver caches the selected bank and writes REG_BANK_SEL only when it changes; every
//! public call leaves bank 0 selected, so `read_fifo` needs no bank write.

use embedded_hal::delay::DelayNs;
use embedded_hal::spi::{Operation, SpiDevice};

use crate::error::Error;
use crate::packet::Packet;
use crate::registers::{self as reg, bank};
use crate::settings::{MAX_REGISTER_WRITES, RegisterWrite, Settings};

/// Soft reset to first register access (DEVICE_CONFIG description, data sheet §14: ≥ 1 ms),
/// and the interval at which the reset's end is then polled.
const SOFT_RESET_WAIT_US: u32 = 1_000;
/// Polls of a soft reset's end before giving up: 1 s (PX4's bound).
const RESET_TRIES: u32 = 1_000;
/// After the sensors are turned on, no register writes for 200 µs (PWR_MGMT0 description).
const SENSORS_ON_WAIT_US: u32 = 200;

/// INT_STATUS bits that concern the FIFO reader.
const FIFO_STATUS: u8 =
    reg::INT_STATUS_FIFO_FULL | reg::INT_STATUS_FIFO_THS | reg::INT_STATUS_DATA_RDY;

/// What one [`Icm42688::read_fifo`] found.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct FifoRead {
    /// Packets written to the start of `out`, in FIFO order (oldest first), the ones the
    /// part marked invalid among them: each has its time stamp, which places the others.
    pub packets: usize,
    /// FIFO_FULL_INT was set since the last read: the FIFO filled up, and in stream mode the
    /// part then overwrites its oldest packets, so samples were (or, if it filled exactly,
    /// may have been) lost before the oldest one read. The time stamps tell how many.
    pub overflowed: bool,
    /// A packet with a bad header was met: it and everything after it are not trusted, and
    /// the FIFO was flushed.
    pub corrupt: bool,
    /// How many of the `packets` the part marked invalid (−32768 in an axis: a sensor
    /// starting up); [`Packet::has_valid_data`] tells which.
    pub invalid: usize,
    /// Records left in the FIFO after this read (0 after a flush).
    pub remaining: u16,
}

/// Result of [`Icm42688::check`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Check {
    /// Every configured register reads back as written, and no reset was reported.
    Ok,
    /// The part had lost its configuration and was configured again. The first difference
    /// found is reported; for a reset seen through INT_STATUS's RESET_DONE bit it is
    /// `{ bank: 0, address: 0x2D, expected: 0x00, found: 0x10 }` (the bit alone).
    Repaired {
        /// Bank of the first register found different.
        bank: u8,
        /// Its address.
        address: u8,
        /// The value configured.
        expected: u8,
        /// The value read back.
        found: u8,
    },
}

/// Driver for one ICM-42688-P on an SPI device (mode 0 or 3, up to 24 MHz).
///
/// It holds a 2 KB buffer (one FIFO's worth of bytes) so that a full FIFO is read in one burst
/// without a 2 KB stack frame; place it in a static or a task's state rather than moving it
/// around.
pub struct Icm42688<SPI> {
    spi: SPI,
    settings: Settings,
    /// The bank last selected, `None` when unknown (before `init`, or after a failed write).
    bank: Option<u8>,
    /// INT_STATUS bits read (which clears them on the part) but not yet reported: `check`
    /// keeps FIFO_FULL for `read_fifo`, `read_fifo` keeps RESET_DONE for `check`.
    status: u8,
    /// FIFO bytes of one read: a whole FIFO's worth, held here rather than on the stack.
    raw: [u8; reg::FIFO_BYTES],
}

impl<SPI: SpiDevice> Icm42688<SPI> {
    /// Takes the SPI device and the settings; nothing is sent until [`Icm42688::init`].
    pub fn new(spi: SPI, settings: Settings) -> Self {
        Icm42688 {
            spi,
            settings,
            bank: None,
            status: 0,
            raw: [0; reg::FIFO_BYTES],
        }
    }

    /// The settings the part is (to be) configured with.
    pub fn settings(&self) -> &Settings {
        &self.settings
    }

    /// Gives the SPI device back.
    pub fn release(self) -> SPI {
        self.spi
    }

    /// Configures the part: validate the settings; select bank 0; soft reset; poll every 1 ms
    /// (up to 1 s) for WHO_AM_I, DEVICE_CONFIG's reset bit clear and RESET_DONE (clearing it);
    /// write [`Settings::register_writes`] (read-modify-write where a write owns only some
    /// bits; the last write starts the sensors); wait 200 µs; flush the FIFO.
    pub fn init(&mut self, delay: &mut impl DelayNs) -> Result<(), Error<SPI::Error>> {
        self.settings.validate()?;
        self.configure(delay)
    }

    /// PX4-style configuration check, cheap enough for every ~100 ms: read INT_STATUS (a
    /// RESET_DONE bit means the part was reset), then every configured register, in runs of
    /// consecutive addresses, one bank at a time. On the first difference the part was reset
    /// (brown-out) or glitched: configure it again, as `init` does, and report the difference.
    ///
    /// The reads skip every register with a read side effect (INT_STATUS is read on its own,
    /// FIFO_DATA never). FIFO bits of INT_STATUS read here are kept for the next `read_fifo`.
    pub fn check(&mut self, delay: &mut impl DelayNs) -> Result<Check, Error<SPI::Error>> {
        let mut status = [0u8];
        self.read_registers(bank::BANK0, reg::INT_STATUS, &mut status)?;
        self.status |= status[0];
        if self.status & reg::INT_STATUS_RESET_DONE != 0 {
            self.configure(delay)?;
            return Ok(Check::Repaired {
                bank: bank::BANK0,
                address: reg::INT_STATUS,
                expected: 0x00,
                found: reg::INT_STATUS_RESET_DONE,
            });
        }

        let mut writes = self.settings.register_writes();
        writes.sort_unstable_by_key(|w| (w.bank, w.address));
        let mut mismatch = None;
        let mut rest: &[RegisterWrite] = &writes;
        while let Some(first) = rest.first() {
            let run_len = run_length(rest);
            let (run, tail) = rest.split_at(run_len);
            rest = tail;
            let mut buf = [0u8; MAX_REGISTER_WRITES];
            let Some(read) = buf.get_mut(..run_len) else {
                break; // A run never exceeds the list; unreachable.
            };
            self.read_registers(first.bank, first.address, read)?;
            let differs = |(w, f): &(&RegisterWrite, &u8)| w.value != **f & w.mask;
            if let Some((w, &found)) = run.iter().zip(read.iter()).find(differs) {
                mismatch = Some(Check::Repaired {
                    bank: w.bank,
                    address: w.address,
                    expected: w.value,
                    found,
                });
                break;
            }
        }
        match mismatch {
            Some(repaired) => {
                self.configure(delay)?;
                Ok(repaired)
            }
            None => {
                self.select_bank(bank::BANK0)?;
                Ok(Check::Ok)
            }
        }
    }

    /// Reads the FIFO: one 3-byte read of INT_STATUS, FIFO_COUNTH, FIFO_COUNTL (count in
    /// records), then `min(count, out.len())` packets in one burst from FIFO_DATA. The packets
    /// are written to `out` in FIFO order, invalid ones too (counted in
    /// [`FifoRead::invalid`]). A bad header stops decoding and flushes the FIFO.
    pub fn read_fifo(&mut self, out: &mut [Packet]) -> Result<FifoRead, Error<SPI::Error>> {
        let mut head = [0u8; 3];
        self.read_registers(bank::BANK0, reg::INT_STATUS, &mut head)?;
        let [status, count_high, count_low] = head;
        self.status |= status;
        let overflowed = self.status & reg::INT_STATUS_FIFO_FULL != 0;
        self.status &= !FIFO_STATUS;
        let count = u16::from_be_bytes([count_high, count_low]);

        let n = usize::from(count).min(out.len()).min(reg::FIFO_CAPACITY);
        let mut result = FifoRead {
            overflowed,
            remaining: count,
            ..FifoRead::default()
        };
        if n == 0 {
            return Ok(result);
        }

        let raw = self.raw.get_mut(..n * Packet::LEN).unwrap_or_default();
        self.spi
            .transaction(&mut [
                Operation::Write(&[reg::FIFO_DATA | reg::SPI_READ]),
                Operation::Read(raw),
            ])
            .map_err(Error::Spi)?;
        // n ≤ count, so this cannot underflow; n ≤ 128 fits u16.
        result.remaining = count.saturating_sub(u16::try_from(n).unwrap_or(u16::MAX));

        let mut slots = out.iter_mut();
        for chunk in raw.chunks_exact(Packet::LEN) {
            let decoded = <&[u8; Packet::LEN]>::try_from(chunk)
                .ok()
                .and_then(|bytes| Packet::decode(bytes).ok());
            match decoded {
                Some(packet) => {
                    if let Some(slot) = slots.next() {
                        *slot = packet;
                        result.packets += 1;
                        result.invalid += usize::from(!packet.has_valid_data());
                    }
                }
                None => {
                    result.corrupt = true;
                    break;
                }
            }
        }
        if result.corrupt {
            // The rest of the FIFO may be misaligned too: drop it rather than decode garbage.
            self.flush_fifo()?;
            result.remaining = 0;
        }
        Ok(result)
    }

    /// Empties the FIFO (SIGNAL_PATH_RESET FIFO_FLUSH).
    pub fn flush_fifo(&mut self) -> Result<(), Error<SPI::Error>> {
        self.write_register(
            bank::BANK0,
            reg::SIGNAL_PATH_RESET,
            reg::SIGNAL_PATH_RESET_FIFO_FLUSH,
        )
    }

    /// The configuration sequence shared by `init` and the repair in `check`.
    fn configure(&mut self, delay: &mut impl DelayNs) -> Result<(), Error<SPI::Error>> {
        // The MCU may have restarted with the part left in another bank: select bank 0
        // unconditionally before the reset.
        self.bank = None;
        self.select_bank(bank::BANK0)?;
        self.write_register(
            bank::BANK0,
            reg::DEVICE_CONFIG,
            reg::DEVICE_CONFIG_SOFT_RESET,
        )?;
        // The reset returns the part to bank 0.
        self.bank = Some(bank::BANK0);
        self.await_reset(delay)?;
        self.status = 0;

        for w in self.settings.register_writes() {
            let value = if w.mask == 0xFF {
                w.value
            } else {
                let mut now = [0u8];
                self.read_registers(w.bank, w.address, &mut now)?;
                (now[0] & !w.mask) | w.value
            };
            self.write_register(w.bank, w.address, value)?;
        }
        self.select_bank(bank::BANK0)?;
        delay.delay_us(SENSORS_ON_WAIT_US);
        self.flush_fifo()
    }

    /// Waits for a soft reset to finish, PX4's way: every 1 ms, for up to 1 s, WHO_AM_I must
    /// name the part, DEVICE_CONFIG's reset bit must have cleared, and INT_STATUS must show
    /// RESET_DONE (the read clears it, so that the next check sees only a new one). A fixed
    /// 1 ms wait trusted a part still starting up.
    fn await_reset(&mut self, delay: &mut impl DelayNs) -> Result<(), Error<SPI::Error>> {
        let mut id = 0;
        for _ in 0..RESET_TRIES {
            delay.delay_us(SOFT_RESET_WAIT_US);
            let mut b = [0u8];
            self.read_registers(bank::BANK0, reg::WHO_AM_I, &mut b)?;
            id = b[0];
            if id != reg::WHO_AM_I_VALUE {
                continue;
            }
            self.read_registers(bank::BANK0, reg::DEVICE_CONFIG, &mut b)?;
            if b[0] & reg::DEVICE_CONFIG_SOFT_RESET != 0 {
                continue;
            }
            self.read_registers(bank::BANK0, reg::INT_STATUS, &mut b)?;
            if b[0] & reg::INT_STATUS_RESET_DONE != 0 {
                return Ok(());
            }
        }
        Err(if id == reg::WHO_AM_I_VALUE {
            Error::ResetTimeout
        } else {
            Error::WrongId(id)
        })
    }

    fn select_bank(&mut self, bank: u8) -> Result<(), Error<SPI::Error>> {
        if self.bank == Some(bank) {
            return Ok(());
        }
        // Unknown until the write is known to have gone through.
        self.bank = None;
        self.spi
            .write(&[reg::REG_BANK_SEL, bank])
            .map_err(Error::Spi)?;
        self.bank = Some(bank);
        Ok(())
    }

    fn write_register(
        &mut self,
        bank: u8,
        address: u8,
        value: u8,
    ) -> Result<(), Error<SPI::Error>> {
        self.select_bank(bank)?;
        self.spi
            .write(&[address & !reg::SPI_READ, value])
            .map_err(Error::Spi)
    }

    fn read_registers(
        &mut self,
        bank: u8,
        address: u8,
        buf: &mut [u8],
    ) -> Result<(), Error<SPI::Error>> {
        self.select_bank(bank)?;
        self.spi
            .transaction(&mut [
                Operation::Write(&[address | reg::SPI_READ]),
                Operation::Read(buf),
            ])
            .map_err(Error::Spi)
    }
}

/// Length of the leading run of `writes` (sorted by bank, address) with consecutive addresses
/// in one bank.
fn run_length(writes: &[RegisterWrite]) -> usize {
    let mut len = 0;
    let mut prev: Option<&RegisterWrite> = None;
    for w in writes {
        if let Some(p) = prev
            && (p.bank != w.bank || p.address.checked_add(1) != Some(w.address))
        {
            break;
        }
        prev = Some(w);
        len += 1;
    }
    len
}
