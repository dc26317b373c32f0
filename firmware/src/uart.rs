//! The CMSDK APB UART0 of mps2-an386 at 0x4000_4000, polled.
//!
//! Registers: DATA (+0x00), STATE (+0x04: bit 0 TX full, bit 1 RX full), CTRL (+0x08: bit 0 TX
//! enable, bit 1 RX enable), INTSTATUS (+0x0C), BAUDDIV (+0x10). On a real board, replace this
//! module with the vendor's UART driver; nothing else depends on it.

use core::ptr::{read_volatile, write_volatile};

const BASE: usize = 0x4000_4000;
const DATA: *mut u32 = BASE as *mut u32;
const STATE: *mut u32 = (BASE + 0x04) as *mut u32;
const CTRL: *mut u32 = (BASE + 0x08) as *mut u32;
const BAUDDIV: *mut u32 = (BASE + 0x10) as *mut u32;

const TX_FULL: u32 = 1 << 0;
const RX_FULL: u32 = 1 << 1;

/// The UART, enabled for transmit and receive.
pub struct Uart(());

impl Uart {
    /// Enables the UART. QEMU ignores the baud rate; 16 is the smallest legal divider.
    pub fn init() -> Self {
        // SAFETY: fixed, valid MMIO addresses of the CMSDK UART on this board.
        unsafe {
            write_volatile(BAUDDIV, 16);
            write_volatile(CTRL, 0b11);
        }
        Uart(())
    }

    /// Waits for one received byte.
    pub fn read_byte(&mut self) -> u8 {
        // SAFETY: see `init`.
        unsafe {
            while read_volatile(STATE) & RX_FULL == 0 {}
            read_volatile(DATA) as u8
        }
    }

    /// A received byte, if one is waiting.
    pub fn try_read_byte(&mut self) -> Option<u8> {
        // SAFETY: see `init`.
        unsafe { (read_volatile(STATE) & RX_FULL != 0).then(|| read_volatile(DATA) as u8) }
    }

    /// Sends bytes, waiting while the transmit buffer is full.
    pub fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            // SAFETY: see `init`.
            unsafe {
                while read_volatile(STATE) & TX_FULL != 0 {}
                write_volatile(DATA, b as u32);
            }
        }
    }
}
