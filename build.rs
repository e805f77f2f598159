//! Puts `memory.x` where the linker finds it and passes the linker scripts.
//!
//! The link arguments live here (not in `.cargo/config.toml` rustflags) so that they apply to
//! this package's binary and its on-target tests only, exactly once each.
use std::{env, fs, path::PathBuf};

fn main() {
    let out = PathBuf::from(env::var_os("OUT_DIR").expect("cargo sets OUT_DIR"));
    fs::copy("memory.x", out.join("memory.x")).expect("memory.x is readable");
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rerun-if-changed=memory.x");
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
