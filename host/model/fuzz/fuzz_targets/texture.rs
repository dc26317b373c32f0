//! Fuzz texture decoding (PNG, JPEG) within the texture limits: a decoded texture is at most
//! `MAX_TEXTURE_SIDE` on a side, and no allocation may pass `MAX_TEXTURE_BYTES` (1 GiB).
#![no_main]

use std::path::Path;

use libfuzzer_sys::fuzz_target;
use model_fuzz::LimitAlloc;

#[global_allocator]
static ALLOC: LimitAlloc = LimitAlloc::new(model::MAX_TEXTURE_BYTES as usize);

fuzz_target!(|data: &[u8]| {
    if let Ok(t) = model::decode_texture(Path::new("fuzz.png"), data) {
        assert!(t.width() <= model::MAX_TEXTURE_SIDE && t.height() <= model::MAX_TEXTURE_SIDE);
    }
});
