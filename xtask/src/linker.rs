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
use std::path::{Path, PathBuf};

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

/// cargo's `bin` folder for `cargo install` without `--root`: `$CARGO_INSTALL_ROOT/bin`,
/// else `$CARGO_HOME/bin`, else `~/.cargo/bin`.
pub fn cargo_bin_dir() -> Option<PathBuf> {
    let var = |name: &str| std::env::var_os(name).filter(|v| !v.is_empty());
    let root = var("CARGO_INSTALL_ROOT")
        .or_else(|| var("CARGO_HOME"))
        .map(PathBuf::from)
        .or_else(|| var("HOME").map(|home| Path::new(&home).join(".cargo")))?;
    Some(root.join("bin"))
}

/// `PATH` with `dir` in front, unless it is on it already.
pub fn path_with(dir: &Path) -> OsString {
    let current = std::env::var_os("PATH").unwrap_or_default();
    if std::env::split_paths(&current).any(|p| p == dir) {
        return current;
    }
    std::env::join_paths(std::iter::once(dir.to_path_buf()).chain(std::env::split_paths(&current)))
        .unwrap_or(current)
}

/// flip-link for the board's builds: the one on `PATH`, else the one in cargo's `bin`
/// folder, installed there with `cargo install flip-link --locked` on first use. Returns
/// the `PATH` the builds need to find it.
pub fn flip_link() -> Result<FlipLink, String> {
    let current = std::env::var_os("PATH").unwrap_or_default();
    if host::find_in_path(FLIP_LINK).is_some() {
        return Ok(FlipLink { path: current });
    }
    let bin =
        cargo_bin_dir().ok_or("flip-link is not on PATH and neither CARGO_HOME nor HOME is set")?;
    if !bin.join(FLIP_LINK).is_file() {
        host::cargo_install(None, FLIP_LINK, FLIP_LINK_VERSION)?;
    }
    Ok(FlipLink {
        path: path_with(&bin),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn path_with_puts_a_folder_first_once() {
        let dir = Path::new("/no/such/xtask-test-bin");
        let once = path_with(dir);
        assert_eq!(std::env::split_paths(&once).next().as_deref(), Some(dir));
        let current = std::env::var_os("PATH").unwrap_or_default();
        assert_eq!(
            std::env::split_paths(&once).count(),
            std::env::split_paths(&current).count() + 1
        );
    }
}
