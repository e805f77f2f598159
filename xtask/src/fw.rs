//! The firmware images: the release application and the resident loader with their
//! footprint checks and the application's update file, the stack-overflow test build, and
//! the check that `cargo fw` builds the same image.

use std::path::{Path, PathBuf};

use xshell::{cmd, Cmd};

use crate::workspace::{root_shell, target_dir, workspace_root};
use crate::{footprint, linker, shell, update};

/// The MCU's target (STM32F103: Cortex-M3).
pub const FIRMWARE_TARGET: &str = "thumbv7m-none-eabi";

/// The application's release footprint budget: 40 KiB flash with its image header (of the 50
/// KiB slot, docs/FIRMWARE-UPDATE.md; the image's history in docs/CHANGELOG.md), 4 KiB static
/// RAM (RTT included). CI fails above it.
const RELEASE_BUDGET: footprint::Budget = footprint::Budget {
    flash: 40 * 1024,
    ram: 4 * 1024,
};

/// The resident loader's budget: its 12 KiB of flash (memory.x's LOADER), 4 KiB static RAM.
const LOADER_BUDGET: footprint::Budget = footprint::Budget {
    flash: 12 * 1024,
    ram: 4 * 1024,
};

/// The loader's package (`loader/`) and binary.
const LOADER: &str = "handwheel-loader";

/// What `cargo xtask fw` prints before the update file's path, at the start of its line.
pub const UPDATE_LINE: &str = "update image:";

/// Builds the release application and the loader, fails if either is over its footprint
/// budget or the README's statement of the application's footprint is not the image's, and
/// writes the application's update file (printing `update image: PATH`).
pub fn firmware_build() -> Result<(), String> {
    release_build()?;
    let footprint = footprint_check()?;
    loader_build()?;
    footprint::check(&loader_elf(), "release loader", LOADER_BUDGET)?;
    let readme = std::fs::read_to_string(workspace_root().join("README.md"))
        .map_err(|e| format!("cannot read README.md: {e}"))?;
    footprint::check_readme(&readme, &footprint)?;
    let path = update_file();
    let image = update::write(&firmware_elf("release"), &path)?;
    eprintln!(
        "xtask: update file of {} B (header slot {} B, image {} B, CRC-32 {:#010x}) for {:#010x}",
        image.bytes.len(),
        image.slot,
        image.bytes.len() - image.slot as usize,
        image.crc,
        image.address
    );
    println!("{UPDATE_LINE} {}", path.display());
    Ok(())
}

/// `cargo fw`, the README's build, right after xtask's: it must compile nothing, since both
/// build the same configuration into the same target directory (`linker.rs`).
pub fn one_build_check() -> Result<(), String> {
    eprintln!("xtask: cargo fw (the README's build: must compile nothing now)");
    let sh = &root_shell()?;
    let command = cmd!(sh, "cargo fw")
        .ignore_status()
        .env("PATH", linker::flip_link()?.path);
    let output = command
        .output()
        .map_err(|e| format!("cannot run cargo fw: {e}"))?;
    let log = String::from_utf8_lossy(&output.stderr);
    eprint!("{log}");
    if !output.status.success() {
        return Err(format!("`cargo fw` failed ({})", output.status));
    }
    let compiled: Vec<&str> = log
        .lines()
        .filter(|l| l.trim_start().starts_with("Compiling"))
        .collect();
    if compiled.is_empty() {
        Ok(())
    } else {
        Err(format!(
            "`cargo fw` after `cargo xtask fw` compiled {} crate(s): the two builds differ \
             (linker, flags or environment; xtask/src/linker.rs)",
            compiled.len()
        ))
    }
}

/// Builds the release firmware.
pub fn release_build() -> Result<(), String> {
    let sh = &root_shell()?;
    board_cargo(cmd!(
        sh,
        "cargo build --locked --release -p handwheel-firmware --target {FIRMWARE_TARGET}"
    ))
}

/// Builds the release loader: a workspace of its own (`loader/Cargo.toml` says why), built
/// into the root's target directory as `cargo loader` does.
pub fn loader_build() -> Result<(), String> {
    let sh = &root_shell()?;
    let target = target_dir();
    board_cargo(cmd!(
        sh,
        "cargo build --locked --release --manifest-path {LOADER_MANIFEST} --target {FIRMWARE_TARGET} --target-dir {target}"
    ))
}

/// The loader's manifest, from the workspace root.
pub const LOADER_MANIFEST: &str = "loader/Cargo.toml";

/// The release loader's ELF.
pub fn loader_elf() -> PathBuf {
    target_dir()
        .join(FIRMWARE_TARGET)
        .join("release")
        .join(LOADER)
}

/// The release application's update file (docs/FIRMWARE-UPDATE.md).
pub fn update_file() -> PathBuf {
    target_dir()
        .join(FIRMWARE_TARGET)
        .join("release")
        .join("handwheel-firmware.update")
}

/// Prints the release firmware's footprint and fails if it is over its budget; returns it.
pub fn footprint_check() -> Result<footprint::Footprint, String> {
    footprint::check(&firmware_elf("release"), "release firmware", RELEASE_BUDGET)
}

/// Builds the stack-overflow test image (release profile, feature `stack-overflow-test`,
/// linked like the release image) and returns a copy of it in `target/stack-overflow/`.
///
/// It builds in the shared target directory, where only the firmware crate compiles anew
/// (the feature is its own), and then the release image again, which compiles nothing
/// (cargo keeps both builds) and puts the release image back at its path.
pub fn overflow_build() -> Result<PathBuf, String> {
    let sh = &root_shell()?;
    board_cargo(cmd!(
        sh,
        "cargo build --locked --release -p handwheel-firmware --target {FIRMWARE_TARGET}
         --features stack-overflow-test"
    ))?;
    let copy = target_dir()
        .join("stack-overflow")
        .join("handwheel-firmware");
    let dir = copy.parent().unwrap_or(Path::new("."));
    std::fs::create_dir_all(dir).map_err(|e| format!("cannot create {}: {e}", dir.display()))?;
    std::fs::copy(firmware_elf("release"), &copy)
        .map_err(|e| format!("cannot copy the stack-overflow image: {e}"))?;
    release_build()?;
    Ok(copy)
}

/// The firmware ELF of a profile directory (`release` or `debug`).
pub fn firmware_elf(profile: &str) -> PathBuf {
    target_dir()
        .join(FIRMWARE_TARGET)
        .join(profile)
        .join("handwheel-firmware")
}

/// Runs cargo for a firmware image: linked by the configuration's linker (flip-link, installed
/// on first use, and the seal; see `linker.rs`), as `cargo fw` links.
pub fn board_cargo(command: Cmd<'_>) -> Result<(), String> {
    shell::run(command.env("PATH", linker::flip_link()?.path))
}
