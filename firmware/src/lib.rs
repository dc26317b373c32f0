//! Board support for the fusion-core firmware on QEMU's `mps2-an386` (Cortex-M4F): the CMSDK
//! APB UART and timer, stack painting, and the panic handler. The device loop itself is
//! `fusion_core::DeviceIo`, wrapped unchanged by `bin/device.rs`.
#![no_std]

pub mod stack;
pub mod timer;
pub mod uart;

use core::panic::PanicInfo;

use cortex_m_semihosting::{debug, hprintln};

/// Panics are reported through semihosting (QEMU prints them) and halt with a failure code.
#[panic_handler]
fn panic(info: &PanicInfo) -> ! {
    hprintln!("firmware panic: {}", info);
    debug::exit(debug::EXIT_FAILURE);
    loop {
        cortex_m::asm::wfi();
    }
}
