//! Fuzz the OBJ + MTL loader: the input up to its first NUL byte is the OBJ, the rest (when
//! there is a NUL) the MTL library it names; textures are a small PNG. A loaded model must pass
//! its own checks. Allocations over 256 MiB abort: the limits (10M vertices of each kind, 10M
//! triangles) allow `tobj` 120 MB arrays, 240 MB while one grows.
#![no_main]

use std::path::Path;

use libfuzzer_sys::fuzz_target;
use model_fuzz::LimitAlloc;

#[global_allocator]
static ALLOC: LimitAlloc = LimitAlloc::new(256 << 20);

fuzz_target!(|data: &[u8]| {
    let (obj, mtl) = match data.iter().position(|&b| b == 0) {
        Some(i) => (&data[..i], Some(&data[i + 1..])),
        None => (data, None),
    };
    let files = model_fuzz::files(mtl);
    if let Ok(m) = model::parse_obj(obj, Path::new("fuzz/scene.obj"), &files) {
        m.check("fuzzed").expect("a loaded model passes its checks");
    }
});
