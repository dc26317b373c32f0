//! Fuzz the reading of ffmpeg's stderr (`showinfo` lines: a frame's number, time stamp and
//! size, the time base, errors) and the frame time it gives. ffmpeg prints what the file makes
//! it print (names, tags). Lines are short: any allocation over 64 MiB aborts.
#![no_main]

use fuzz_support::LimitAlloc;
use frames::showinfo::{Line, parse};
use frames::video::frame_time_ns;
use libfuzzer_sys::fuzz_target;

#[global_allocator]
static ALLOC: LimitAlloc = LimitAlloc::new(64 << 20);

fuzz_target!(|data: &[u8]| {
    let text = String::from_utf8_lossy(data);
    let mut time_base = (1, 1);
    for line in text.lines() {
        match parse(line) {
            Line::Config { time_base: tb, .. } => time_base = tb,
            Line::Frame { pts: Some(pts), .. } => {
                if let Some(t) = frame_time_ns(pts, time_base) {
                    let exact = i128::from(pts) * i128::from(time_base.0) * 1_000_000_000
                        / i128::from(time_base.1);
                    assert_eq!(i128::from(t), exact);
                }
            }
            _ => {}
        }
    }
});
