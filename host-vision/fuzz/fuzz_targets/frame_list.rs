//! Fuzz the reading of a EuRoC `cam0/data.csv` (the frame list): plain file names under the
//! data folder with increasing stamps, or an error. The file is at most 2 GiB and 5 million
//! rows (checked before the rows are allocated); the fuzzer's inputs are far smaller, so any
//! allocation over 64 MiB aborts.
#![no_main]

use std::path::Path;

use fuzz_support::LimitAlloc;
use frames::euroc::parse_frame_list;
use libfuzzer_sys::fuzz_target;

#[global_allocator]
static ALLOC: LimitAlloc = LimitAlloc::new(64 << 20);

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let dir = Path::new("cam0/data");
    if let Ok(list) = parse_frame_list(text, Path::new("cam0/data.csv"), dir) {
        assert!(!list.is_empty());
        assert!(list.windows(2).all(|w| w[0].stamp < w[1].stamp));
        assert!(list.iter().all(|f| f.path.parent() == Some(dir)));
    }
});
