//! Fuzz the start pose reader (JSON `cMo` or a TUM line) and `--intrinsics fx,fy,cx,cy`. An
//! accepted pose is finite. Start pose files are at most 1 MiB: any allocation over 64 MiB
//! aborts.
#![no_main]

use fuzz_support::LimitAlloc;
use libfuzzer_sys::fuzz_target;

#[global_allocator]
static ALLOC: LimitAlloc = LimitAlloc::new(64 << 20);

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if let Ok(p) = camera::start_pose::parse_start_pose(text) {
        assert!(p.c_w.iter().all(|v| v.is_finite()));
        assert!(p.q_cw.coords.iter().all(|v| v.is_finite()));
    }
    if let Ok(p) = camera::parse_intrinsics(text) {
        assert!(p.validate().is_ok());
    }
});
