//! Fuzz the EuRoC CSV readers (`imu0/data.csv`, `state_groundtruth_estimate0/data.csv`): rows
//! of finite numbers with increasing stamps and unit quaternions, or an error naming the line.
//! The files are at most 2 GiB and 5 million rows (checked before the rows are allocated); the
//! fuzzer's inputs are far smaller, so any allocation over 64 MiB aborts.
#![no_main]

use std::path::Path;

use firmware_sim::sim::scenario::euroc::{parse_groundtruth_csv, parse_imu_csv};
use fuzz_support::LimitAlloc;
use libfuzzer_sys::fuzz_target;

#[global_allocator]
static ALLOC: LimitAlloc = LimitAlloc::new(64 << 20);

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if let Ok(rows) = parse_imu_csv(text, Path::new("imu0/data.csv")) {
        for r in &rows {
            assert!(r.gyro.iter().chain(r.accel.iter()).all(|v| v.is_finite()));
        }
    }
    if let Ok(rows) = parse_groundtruth_csv(text, Path::new("gt/data.csv")) {
        for r in &rows {
            assert!(r.p_w.iter().all(|v| v.is_finite()));
            assert!((r.q_ws.norm() - 1.0).abs() < 1e-9);
        }
    }
});
