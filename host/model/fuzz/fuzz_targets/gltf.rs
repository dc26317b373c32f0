//! Fuzz the glTF loader (JSON or GLB, embedded or external buffers and images; external images
//! are a small PNG, other external files absent). A loaded model must pass its own checks.
//! Allocations over 1 GiB (`model::MAX_TEXTURE_BYTES`, the largest any limit allows) abort.
#![no_main]

use std::path::Path;

use libfuzzer_sys::fuzz_target;
use model_fuzz::LimitAlloc;

#[global_allocator]
static ALLOC: LimitAlloc = LimitAlloc::new(model::MAX_TEXTURE_BYTES as usize);

fuzz_target!(|data: &[u8]| {
    let files = model_fuzz::files(None);
    if let Ok(m) = model::parse_gltf(data, Path::new("fuzz/scene.gltf"), &files) {
        m.check("fuzzed").expect("a loaded model passes its checks");
    }
});
