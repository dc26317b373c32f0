//! The device-specific part of the vector table, for cortex-m-rt's `device` feature: one entry
//! per external interrupt line of the part, every one bound to cortex-m-rt's `DefaultHandler`
//! (the firmware polls its UART and uses no interrupt).
//!
//! QEMU's `mps2-an386` configures its NVIC with 32 lines (`num-irq` in `hw/arm/mps2.c`, as the
//! AN386 application note lists them). cortex-m-rt's generic table has the ARMv7-M maximum of
//! 240 entries, 832 bytes of flash more. **Porting:** set [`LINES`] to the part's count from its
//! reference manual (or take `__INTERRUPTS` from the part's PAC and drop this module).

/// External interrupt lines of the part (the AN386's NVIC).
pub const LINES: usize = 32;

unsafe extern "C" {
    /// cortex-m-rt's default exception handler (its linker script provides it).
    fn DefaultHandler();
}

/// The interrupt part of the vector table, placed by cortex-m-rt's `link.x` right after the 16
/// system exceptions.
// SAFETY: the name and section are the ones cortex-m-rt's linker script expects for this
// table, and no other object defines them once its `device` feature is on.
#[unsafe(link_section = ".vector_table.interrupts")]
#[unsafe(no_mangle)]
pub static __INTERRUPTS: [unsafe extern "C" fn(); LINES] = [DefaultHandler; LINES];
