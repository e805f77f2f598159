//! The firmware's linker: `tools/seal/linker` (`.cargo/config.toml` names it), which runs
//! flip-link and then seals the image header (`tools/seal/seal.py`: the image's length and
//! CRC-32, docs/FIRMWARE-UPDATE.md).
//!
//! flip-link links twice with rust-lld, the second time with static RAM moved to the top of
//! RAM and the stack below it, so that a stack overflow runs off the start of RAM and faults
//! instead of overwriting statics (`memory.x`).
//!
//! The images keep the configuration's `linker`, which finds flip-link on `PATH`,
//! exactly as the README's `cargo fw` and `cargo embed` link: the linker is part of cargo's
//! fingerprint, so any other value (such as another path) would make `cargo xtask fw` and
//! `cargo fw` rebuild every crate after each other. There is one flip-link: the one on
//! `PATH`, or, when there is none, the one `cargo install flip-link --locked` puts in cargo's
//! `bin` folder (the README's command, with the version pinned here), added to the builds'
//! `PATH` if the shell lacks it.

use std::ffi::OsString;

use crate::host;

/// The flip-link release xtask installs when none is on `PATH`.
pub const FLIP_LINK_VERSION: &str = "0.1.12";
/// The program the configuration's linker (`tools/seal/linker`) runs first.
pub const FLIP_LINK: &str = "flip-link";

/// The configuration's flip-link, found on [`FlipLink::path`].
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FlipLink {
    /// The `PATH` the firmware builds run with.
    pub path: OsString,
}

/// flip-link for the board's builds: the one on `PATH`, else the one in cargo's `bin`
/// folder, installed there with `cargo install flip-link --locked` on first use. Returns
/// the `PATH` the builds need to find it.
pub fn flip_link() -> Result<FlipLink, String> {
    let current = std::env::var_os("PATH").unwrap_or_default();
    if host::find_in_path(FLIP_LINK).is_some() {
        return Ok(FlipLink { path: current });
    }
    let bin = host::cargo_bin_dir()
        .ok_or("flip-link is not on PATH and neither CARGO_HOME nor HOME is set")?;
    if !bin.join(FLIP_LINK).is_file() {
        host::cargo_install(None, FLIP_LINK, FLIP_LINK_VERSION)?;
    }
    Ok(FlipLink {
        path: host::path_with(&bin),
    })
}
