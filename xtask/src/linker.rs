//! The firmware's linker: flip-link for the board (`.cargo/config.toml` names it), installed
//! by xtask like `defmt-print`, and plain rust-lld for the QEMU variant.
//!
//! flip-link links twice with rust-lld, the second time with static RAM moved to the top of
//! RAM and the stack below it, so that a stack overflow runs off the start of RAM and faults
//! instead of overwriting statics (`memory.x`). The QEMU variant keeps the classic layout in
//! the emulated part's 8 KiB (`qemu/ram.x`, `build.rs`). xtask points every firmware build
//! at the right one through cargo's `CARGO_TARGET_<TRIPLE>_LINKER`, which overrides the
//! config, so `cargo xtask` needs no flip-link on `PATH`.

use std::path::{Path, PathBuf};

/// The flip-link release installed with `cargo install --locked`.
pub const FLIP_LINK_VERSION: &str = "0.1.12";
/// Cargo's per-target linker override for the firmware target.
pub const LINKER_ENV: &str = "CARGO_TARGET_THUMBV7M_NONE_EABI_LINKER";

/// Which linker a firmware build gets.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Linker {
    /// flip-link at this path: the board's images.
    FlipLink(PathBuf),
    /// rust-lld from the toolchain: the QEMU variant.
    RustLld,
}

impl Linker {
    /// The value for [`LINKER_ENV`].
    pub fn program(&self) -> &std::ffi::OsStr {
        match self {
            Self::FlipLink(path) => path.as_os_str(),
            Self::RustLld => "rust-lld".as_ref(),
        }
    }
}

/// Whether `cargo install --root <tools_root>` recorded `name` at `version`.
fn installed(tools_root: &Path, name: &str, version: &str) -> bool {
    let record = std::fs::read_to_string(tools_root.join(".crates.toml")).unwrap_or_default();
    record.contains(&format!("\"{name} {version} ("))
}

/// flip-link [`FLIP_LINK_VERSION`] in `<tools_root>/bin`, installed on first use.
pub fn flip_link(tools_root: &Path) -> Result<PathBuf, String> {
    let bin = tools_root.join("bin").join("flip-link");
    if bin.is_file() && installed(tools_root, "flip-link", FLIP_LINK_VERSION) {
        return Ok(bin);
    }
    crate::qemu::cargo_install(tools_root, "flip-link", FLIP_LINK_VERSION)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_install_record_names_the_version() {
        let dir = std::env::temp_dir().join(format!("xtask-linker-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        assert!(!installed(&dir, "flip-link", "0.1.12"));
        std::fs::write(
            dir.join(".crates.toml"),
            "[v1]\n\"flip-link 0.1.11 (registry+https://github.com/rust-lang/crates.io-index)\" \
             = [\"flip-link\"]\n",
        )
        .unwrap();
        assert!(!installed(&dir, "flip-link", "0.1.12"), "another version");
        std::fs::write(
            dir.join(".crates.toml"),
            "[v1]\n\"flip-link 0.1.12 (registry+https://github.com/rust-lang/crates.io-index)\" \
             = [\"flip-link\"]\n",
        )
        .unwrap();
        assert!(installed(&dir, "flip-link", "0.1.12"));
        std::fs::remove_dir_all(&dir).unwrap();
        assert_eq!(Linker::RustLld.program(), "rust-lld");
    }
}
