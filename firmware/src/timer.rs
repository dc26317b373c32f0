//! CMSDK timer0 at 0x4000_0000 (25 MHz), free-running down-counter. With QEMU's
//! `-icount shift=0` one instruction takes 1 ns of virtual time, so a tick is 40 instructions.

use core::ptr::{read_volatile, write_volatile};

const BASE: usize = 0x4000_0000;
const CTRL: *mut u32 = BASE as *mut u32;
const VALUE: *mut u32 = (BASE + 0x04) as *mut u32;
const RELOAD: *mut u32 = (BASE + 0x08) as *mut u32;

/// Instructions per timer tick under `-icount shift=0` (1 ns per instruction, 25 MHz timer).
pub const INSTRUCTIONS_PER_TICK: u64 = 40;

/// The free-running timer.
pub struct Timer(());

impl Timer {
    /// Starts counting down from the top.
    pub fn start() -> Self {
        // SAFETY: fixed, valid MMIO addresses of the CMSDK timer on this board.
        unsafe {
            write_volatile(CTRL, 0);
            write_volatile(RELOAD, u32::MAX);
            write_volatile(VALUE, u32::MAX);
            write_volatile(CTRL, 1);
        }
        Timer(())
    }

    /// Current count (decreasing).
    pub fn now(&self) -> u32 {
        // SAFETY: see `start`.
        unsafe { read_volatile(VALUE) }
    }

    /// Instructions spent in `f` (with `-icount shift=0`), resolution 40.
    pub fn instructions<R>(&self, f: impl FnOnce() -> R) -> (u64, R) {
        let a = self.now();
        let r = f();
        let b = self.now();
        (a.wrapping_sub(b) as u64 * INSTRUCTIONS_PER_TICK, r)
    }
}
