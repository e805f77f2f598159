//! Tells the linker where the memory map is and passes the linker scripts.
//!
//! `memory.x` at the package root is the board's map (STM32F103C8). cortex-m-rt's `link.x`
//! INCLUDEs it by that name, and the linker looks for an included script in its working
//! directory, the package root where cargo runs rustc, before its search paths; the root is
//! put on the search path as well, for flip-link, which relinks in a directory of its own
//! with a modified copy of this map.
//!
//! `header.x` (also at the root) places the application's image header in memory.x's HEADER
//! region, before the vector table; the configuration's linker (tools/seal/linker) then seals
//! it with the image's length and CRC.
//!
//! The link arguments live here (not in `.cargo/config.toml` rustflags) so that they apply to
//! this package's binary and its on-target tests only, exactly once each.
use std::{env, path::PathBuf};

fn main() {
    let root = PathBuf::from(env::var_os("CARGO_MANIFEST_DIR").expect("cargo sets it"));
    println!("cargo:rustc-link-search={}", root.display());
    println!("cargo:rerun-if-changed=memory.x");
    println!("cargo:rerun-if-changed=header.x");
    println!("cargo:rerun-if-changed=build.rs");

    // Only the MCU build links; a host `cargo check` of this package must not get these.
    if env::var("TARGET").is_ok_and(|t| t.starts_with("thumb")) {
        // cortex-m-rt's script (it INCLUDEs memory.x), then defmt's symbol table.
        println!("cargo:rustc-link-arg=-Tlink.x");
        println!("cargo:rustc-link-arg=-Tdefmt.x");
        // The image header before the vector table (it INSERTs into link.x's sections).
        println!("cargo:rustc-link-arg=-Theader.x");
        // No page alignment of the output sections: the image is placed by memory.x alone.
        println!("cargo:rustc-link-arg=--nmagic");
    }
}
