//! Board support for the fusion-core firmware on QEMU's `mps2-an386` (Cortex-M4F): the CMSDK
//! APB UART and timer, stack painting, the interrupt vectors, and the panic handler. The device loop itself is
//! `fusion_core::DeviceIo`, wrapped unchanged by `bin/device.rs`.
#![no_std]

pub mod stack;
pub mod timer;
pub mod uart;
pub mod vectors;

use core::panic::PanicInfo;

use cortex_m_semihosting::{debug, hio};

/// Panics are reported through semihosting (QEMU prints them) with their source location, and
/// halt with a failure code. The message is not formatted: `core::fmt` would cost 2 KB of
/// flash (issue 18), and a location finds the line.
#[panic_handler]
fn panic(info: &PanicInfo) -> ! {
    if let Ok(mut out) = hio::hstderr() {
        let _ = out.write_all(b"firmware panic at ");
        if let Some(at) = info.location() {
            let _ = out.write_all(at.file().as_bytes());
            let _ = out.write_all(b":");
            let _ = out.write_all(decimal(at.line(), &mut [0; 10]));
        }
        let _ = out.write_all(b"\n");
    }
    debug::exit(debug::EXIT_FAILURE);
    loop {
        cortex_m::asm::wfi();
    }
}

/// `n` in decimal, written into the end of `buf`.
fn decimal(mut n: u32, buf: &mut [u8; 10]) -> &[u8] {
    let mut at = buf.len();
    loop {
        at -= 1;
        buf[at] = b'0' + (n % 10) as u8;
        n /= 10;
        if n == 0 {
            return &buf[at..];
        }
    }
}
