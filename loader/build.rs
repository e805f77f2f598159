//! Derives the loader's memory map from the root `memory.x`, the one statement of the
//! regions (docs/FIRMWARE-UPDATE.md): the loader's `FLASH` is the root's `LOADER`, its `RAM`
//! the root's `RAM`. Writes it as `memory.x` into OUT_DIR, on the linker's search path, where
//! cortex-m-rt's `link.x` INCLUDEs it (and flip-link finds it).
use std::{env, fs, path::PathBuf};

/// The `NAME : ORIGIN = .., LENGTH = ..` line of region `name` in the MEMORY block.
fn region<'a>(map: &'a str, name: &str) -> &'a str {
    let block = map
        .split_once("MEMORY")
        .and_then(|(_, rest)| rest.split_once('{'))
        .and_then(|(_, rest)| rest.split_once('}'))
        .map(|(block, _)| block)
        .expect("memory.x has a MEMORY { .. } block");
    block
        .lines()
        .map(str::trim)
        .find(|line| {
            line.split_once(':')
                .is_some_and(|(n, rest)| n.trim() == name && rest.contains("ORIGIN"))
        })
        .unwrap_or_else(|| panic!("memory.x has no region {name}"))
}

fn main() {
    let manifest = PathBuf::from(env::var_os("CARGO_MANIFEST_DIR").expect("cargo sets it"));
    let root_map = manifest.join("../memory.x");
    let map = fs::read_to_string(&root_map).expect("the root memory.x");
    let (_, loader) = region(&map, "LOADER")
        .split_once(':')
        .expect("a region line");
    let (_, ram) = region(&map, "RAM").split_once(':').expect("a region line");
    let derived = format!(
        "/* The loader's map, derived by loader/build.rs from the root memory.x: its FLASH is\n \
         * the root's LOADER, its RAM the root's RAM. */\n\
         MEMORY\n{{\n  FLASH : {}\n  RAM : {}\n}}\n",
        loader.trim(),
        ram.trim()
    );
    let out = PathBuf::from(env::var_os("OUT_DIR").expect("cargo sets it"));
    fs::write(out.join("memory.x"), derived).expect("OUT_DIR is writable");
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rerun-if-changed={}", root_map.display());
    println!("cargo:rerun-if-changed=build.rs");
    if env::var("TARGET").is_ok_and(|t| t.starts_with("thumb")) {
        println!("cargo:rustc-link-arg=-Tlink.x");
        println!("cargo:rustc-link-arg=--nmagic");
        // defmt's symbol table for the log (`defmt-rtt`).
        println!("cargo:rustc-link-arg=-Tdefmt.x");
    }
}
