//! The fusion core's device loop on the UART: bytes in, frames decoded and handled, answers
//! encoded and sent. Exactly `fusion_core::DeviceIo<f32>`, with its whole state in a `static`.
#![no_std]
#![no_main]

use cortex_m_rt::entry;
use firmware::uart::Uart;
use fusion_core::DeviceIo;

/// The device and its decoder: built at compile time (all zeros, `.bss`), never on the stack.
static mut DEVICE: DeviceIo<f32> = DeviceIo::new();

#[entry]
fn main() -> ! {
    firmware::stack::paint();
    // SAFETY: the only reference to DEVICE, taken once before the loop; no interrupts use it.
    // `&mut DEVICE` directly is refused for `static mut` in edition 2024; go through a raw
    // pointer, once.
    #[allow(clippy::deref_addrof)]
    let device = unsafe { &mut *(&raw mut DEVICE) };
    let mut uart = Uart::init();
    let mut buf = [0u8; 64];
    loop {
        // Block for one byte, then drain what else has arrived, and process the chunk.
        buf[0] = uart.read_byte();
        let mut n = 1;
        while n < buf.len() {
            match uart.try_read_byte() {
                Some(b) => {
                    buf[n] = b;
                    n += 1;
                }
                None => break,
            }
        }
        let (tx, rx) = (&mut uart, &buf[..n]);
        device.receive(rx, &mut |frame| tx.write(frame));
    }
}
