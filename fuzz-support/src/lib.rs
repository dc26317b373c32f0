//! What the fuzz targets share: a global allocator that aborts
//! on any single allocation over the limit a target documents, so that libFuzzer reports an
//! input that makes a parser ask for more than its limits allow as a crash (input saved).
//! With the `proptest` feature, [`mutated`]: the stable suite's mutations of a valid file.
//!
//! Not part of the main workspace: a dependency of the `fuzz` crates, and of the
//! workspace's `fuzz_inputs` tests.

use std::alloc::{GlobalAlloc, Layout, System};

/// The system allocator with a limit on each allocation's size.
pub struct LimitAlloc {
    /// Largest single allocation allowed [bytes].
    pub limit: usize,
}

impl LimitAlloc {
    /// An allocator aborting on allocations over `limit` bytes.
    pub const fn new(limit: usize) -> Self {
        Self { limit }
    }

    fn check(&self, size: usize) {
        if size > self.limit {
            // An allocator must not unwind: the message goes straight to stderr (no
            // allocation), then abort, which libFuzzer reports as a crash.
            use std::io::Write;
            let mut err = std::io::stderr().lock();
            let _ = writeln!(
                err,
                "LimitAlloc: an allocation of {size} bytes, over the documented limit of {} bytes",
                self.limit
            );
            std::process::abort();
        }
    }
}

// SAFETY: every call is passed to the system allocator unchanged; only sizes are looked at.
unsafe impl GlobalAlloc for LimitAlloc {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        self.check(layout.size());
        // SAFETY: the caller's layout, as given.
        unsafe { System.alloc(layout) }
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        self.check(layout.size());
        // SAFETY: as above.
        unsafe { System.alloc_zeroed(layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        self.check(new_size);
        // SAFETY: the caller's pointer and layout, as given.
        unsafe { System.realloc(ptr, layout, new_size) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: as above.
        unsafe { System.dealloc(ptr, layout) }
    }
}

/// A valid file `seed` under one to five mutations: bit flips, truncations, insertions of any
/// byte, and overwrites with a byte of `alphabet` (the bytes that matter to the format).
#[cfg(feature = "proptest")]
pub fn mutated(
    seed: Vec<u8>,
    alphabet: &'static [u8],
) -> impl proptest::strategy::Strategy<Value = Vec<u8>> {
    use proptest::prelude::*;
    let op = (
        0u8..4,
        any::<prop::sample::Index>(),
        any::<prop::sample::Index>(),
    );
    prop::collection::vec(op, 1..6).prop_map(move |ops| {
        let mut data = seed.clone();
        for (kind, at, pick) in ops {
            let i = at.index(data.len() + 1);
            let byte = pick.index(256) as u8;
            match kind {
                0 if i < data.len() => data[i] ^= 1 << (byte % 8),
                1 => data.truncate(i),
                2 => data.insert(i, byte),
                _ if i < data.len() && !alphabet.is_empty() => {
                    data[i] = alphabet[pick.index(alphabet.len())]
                }
                _ => {}
            }
        }
        data
    })
}
