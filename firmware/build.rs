//! Puts QEMU's memory map (`memory-qemu.x`, as `memory.x`) and an empty `device.x` on the
//! linker's search path and links with cortex-m-rt's `link.x`, only when building for a
//! Cortex-M target.
//!
//! The map is not named `memory.x` in this folder: the linker runs here for every member of the
//! firmware workspace and looks in its working directory first, so the board images found
//! QEMU's map before their own (issue 55: the F405 image had its vector table at 0 and its
//! stack at 0x2040_0000). `cargo xtask firmware` checks each image against its part's map.

use std::env;
use std::fs;
use std::path::PathBuf;

fn main() {
    let out = PathBuf::from(env::var_os("OUT_DIR").expect("OUT_DIR"));
    fs::copy("memory-qemu.x", out.join("memory.x")).expect("copy memory-qemu.x");
    // cortex-m-rt's `device` feature includes `device.x` for the interrupt handlers' names; the
    // table (`src/vectors.rs`) binds every line to `DefaultHandler`, so there are none to name.
    fs::write(
        out.join("device.x"),
        "/* No named interrupt handlers: see src/vectors.rs. */\n",
    )
    .expect("write device.x");
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rerun-if-changed=memory-qemu.x");
    println!("cargo:rerun-if-changed=build.rs");
    if env::var("TARGET").is_ok_and(|t| t.starts_with("thumb")) {
        println!("cargo:rustc-link-arg=-Tlink.x");
        println!("cargo:rustc-link-arg=--nmagic");
    }
}
