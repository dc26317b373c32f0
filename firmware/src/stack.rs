//! Stack high-water measurement by painting: fill the unused stack with a pattern at boot, and
//! later find the deepest word that was overwritten.

const PAINT: u32 = 0xDEAD_BEEF;

unsafe extern "C" {
    /// End of `.bss`/`.uninit`: the lowest address the stack may reach (cortex-m-rt).
    static mut __sheap: u32;
    /// Initial stack pointer: top of RAM (cortex-m-rt).
    static _stack_start: u32;
}

fn bottom() -> *mut u32 {
    &raw mut __sheap
}

fn top() -> *const u32 {
    &raw const _stack_start
}

/// Paints the free stack below the current stack pointer (minus a margin for this function).
pub fn paint() {
    let sp = cortex_m::register::msp::read() as usize - 64;
    let mut p = bottom();
    while (p as usize) < sp {
        // SAFETY: between the end of static data and below the live stack: unused RAM.
        unsafe {
            p.write_volatile(PAINT);
            p = p.add(1);
        }
    }
}

/// Deepest stack use since [`paint`], in bytes.
pub fn high_water() -> usize {
    let mut p = bottom() as *const u32;
    // SAFETY: reads within the painted region only.
    unsafe {
        while (p as usize) < top() as usize && p.read_volatile() == PAINT {
            p = p.add(1);
        }
    }
    top() as usize - p as usize
}

/// Bytes of static data (`.data` + `.bss`), from the start of RAM to the heap start.
pub fn static_ram() -> usize {
    bottom() as usize - 0x2000_0000
}
