//! Fuzz the frame image decoder (PNG, JPEG and the other formats `image` reads, from a
//! `cam0/data` folder, `--images` or `locate --image`). A decoded frame is within the side
//! limit. The decoder may allocate up to `MAX_FRAME_DECODED_BYTES` (1 GiB, a 16384² RGBA
//! image) plus its own rows: any single allocation over 1.25 GiB aborts.
#![no_main]

use fuzz_support::LimitAlloc;
use libfuzzer_sys::fuzz_target;

#[global_allocator]
static ALLOC: LimitAlloc = LimitAlloc::new(5 << 28);

fuzz_target!(|data: &[u8]| {
    if let Ok(img) = camera::decode_frame(data) {
        let side = camera::MAX_IMAGE_SIDE;
        assert!(img.width() >= 1 && img.width() <= side);
        assert!(img.height() >= 1 && img.height() <= side);
    }
});
