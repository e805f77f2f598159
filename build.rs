//! Puts the memory map where the linker finds it and passes the linker scripts.
//!
//! The board build links `board/memory.x` (STM32F103C8); the QEMU variant
//! (`--features qemu`) links `qemu/memory.x` (the emulated STM32F100: 8 KiB RAM). Either is
//! copied to `OUT_DIR` as `memory.x`, the name cortex-m-rt's `link.x` includes. Neither may
//! sit at the package root: the linker looks for an included script in its working
//! directory (the root) before the search paths, so a root `memory.x` would win for both.
//!
//! The link arguments live here (not in `.cargo/config.toml` rustflags) so that they apply to
//! this package's binary and its on-target tests only, exactly once each.
use std::{env, fs, path::PathBuf};

fn main() {
    let out = PathBuf::from(env::var_os("OUT_DIR").expect("cargo sets OUT_DIR"));
    let memory = if env::var_os("CARGO_FEATURE_QEMU").is_some() {
        "qemu/memory.x"
    } else {
        "board/memory.x"
    };
    fs::copy(memory, out.join("memory.x")).expect("the memory map is readable");
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rerun-if-changed=board/memory.x");
    println!("cargo:rerun-if-changed=qemu/memory.x");
    println!("cargo:rerun-if-changed=build.rs");

    // Only the MCU build links; a host `cargo check` of this package must not get these.
    if env::var("TARGET").is_ok_and(|t| t.starts_with("thumb")) {
        // cortex-m-rt's script (it INCLUDEs memory.x), then defmt's symbol table.
        println!("cargo:rustc-link-arg=-Tlink.x");
        println!("cargo:rustc-link-arg=-Tdefmt.x");
        // No page alignment of the output sections: the image is placed by memory.x alone.
        println!("cargo:rustc-link-arg=--nmagic");
    }
}
