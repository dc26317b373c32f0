//! Fuzz the reading of a dataset's `manifest.json` hints: numbers of zero or more, or an
//! error naming the field. The file is at most 1 MiB: any allocation over 64 MiB aborts.
#![no_main]

use fuzz_support::LimitAlloc;
use host_vision::eval::parse_dataset_hints;
use libfuzzer_sys::fuzz_target;

#[global_allocator]
static ALLOC: LimitAlloc = LimitAlloc::new(64 << 20);

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if let Ok(h) = parse_dataset_hints(text) {
        for v in [h.peak_accel, h.exposure].into_iter().flatten() {
            assert!(v.is_finite() && v > 0.0);
        }
    }
});
