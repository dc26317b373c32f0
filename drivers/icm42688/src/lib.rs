//! A `no_std`, allocation-free, blocking driver for the TDK ICM-42688-P IMU (data sheet
//! DS-000347) on an `embedded-hal` 1.0 [`SpiDevice`](embedded_hal::spi::SpiDevice), and a
//! simulated part for tests on the PC.
//!
//! # Design
//!
//! - **Batched FIFO reads with time stamps.** The part runs in stream-to-FIFO mode with
//!   packet 3 (accel, gyro, temperature, 16-bit time stamp on the part's clock, data sheet §6.1;
//!   its tick is 32/30 µs, [`Settings::stamp_tick`]).
//!   [`Icm42688::read_fifo`] reads INT_STATUS and FIFO_COUNT in one 3-byte transaction, then
//!   every packet it has room for in one burst, so the MCU can sleep through many samples
//!   (watermark interrupt) and still get each sample's time.
//! - **One configuration list.** [`Settings::register_writes`] is the exact `(bank, address,
//!   value)` sequence. `init` writes it, `check` reads it back, the tests compare against it,
//!   and the simulated part implements the same register map ([`registers`]).
//! - **PX4-style configuration check.** [`Icm42688::check`] reads back every configured register
//!   (and INT_STATUS's RESET_DONE); a part reset by a brown-out or glitch is configured again
//!   and reported.
//! - **CLKIN.** [`ClockSource::Clkin`] sets pin 9 to CLKIN and RTC mode, so the ODR follows the
//!   MCU's crystal.
//! - **Never panics on SPI data.** Bad headers, invalid samples and overflow are reported in
//!   [`FifoRead`]; nothing indexes on a value read from the bus.
//!
//! Why not the `icm426xx` 0.4 crate: its FIFO watermark is one packet (no batching), it has no
//! CLKIN set-up and no configuration check, and it is async-first. We need batched FIFO reads
//! with time stamps, the configuration check, and a simulated part sharing the register map.
//!
//! # Modules
//!
//! - [`registers`] — addresses, bit fields, reset values, FIFO constants.
//! - [`settings`] — [`Settings`] and its register sequence.
//! - [`packet`] — [`Packet`], FIFO packet 3.
//! - [`driver`] — [`Icm42688`], [`FifoRead`], [`Check`].
//! - [`error`] — [`Error`].
//! - [`sim`] — [`SimIcm42688`], the simulated part.
#![no_std]

pub mod driver;
pub mod error;
pub mod packet;
pub mod registers;
pub mod settings;
pub mod sim;

pub use driver::{Check, FifoRead, Icm42688};
pub use error::Error;
pub use packet::{Packet, PacketError};
pub use registers::FIFO_CAPACITY;
pub use settings::{
    Aaf, AccelRange, CLKIN_HZ, ClockSource, GyroRange, Interrupt, MAX_REGISTER_WRITES, Odr,
    RegisterWrite, STANDARD_GRAVITY, Settings, SettingsError, StampTick,
};
pub use sim::{SIM_FIFO_CAPACITY, SimIcm42688};
