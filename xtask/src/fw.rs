//! The firmware images: the release build with its footprint check, the stack-overflow test
//! build, and the check that `cargo fw` builds the same image.

use std::path::PathBuf;

use xshell::{cmd, Cmd};

use crate::workspace::{root_shell, target_dir, workspace_root};
use crate::{footprint, linker, shell};

/// The MCU's target (STM32F103: Cortex-M3).
pub const FIRMWARE_TARGET: &str = "thumbv7m-none-eabi";

/// Release footprint budget: 32 KiB flash (what the services need, the image's history in
/// docs/CHANGELOG.md), 4 KiB static RAM (RTT included). CI fails above it.
const RELEASE_BUDGET: footprint::Budget = footprint::Budget {
    flash: 32 * 1024,
    ram: 4 * 1024,
};

/// Builds the release firmware and fails if it is over its footprint budget or the README's
/// statement of its footprint is not the image's.
pub fn firmware_build() -> Result<(), String> {
    release_build()?;
    let footprint = footprint_check()?;
    let readme = std::fs::read_to_string(workspace_root().join("README.md"))
        .map_err(|e| format!("cannot read README.md: {e}"))?;
    footprint::check_readme(&readme, &footprint)
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

/// Prints the release firmware's footprint and fails if it is over its budget; returns it.
pub fn footprint_check() -> Result<footprint::Footprint, String> {
    footprint::check(&firmware_elf("release"), "release firmware", RELEASE_BUDGET)
}

/// Builds the stack-overflow test image (release profile, feature `stack-overflow-test`, its
/// own target directory, linked like the release image); returns its ELF.
pub fn overflow_build() -> Result<PathBuf, String> {
    let dir = target_dir().join("stack-overflow");
    let sh = &root_shell()?;
    board_cargo(cmd!(
        sh,
        "cargo build --locked --release -p handwheel-firmware --target {FIRMWARE_TARGET}
         --features stack-overflow-test --target-dir {dir}"
    ))?;
    Ok(dir
        .join(FIRMWARE_TARGET)
        .join("release")
        .join("handwheel-firmware"))
}

/// The firmware ELF of a profile directory (`release` or `debug`).
pub fn firmware_elf(profile: &str) -> PathBuf {
    target_dir()
        .join(FIRMWARE_TARGET)
        .join(profile)
        .join("handwheel-firmware")
}

/// Runs cargo for a firmware image: linked by the configuration's flip-link, as `cargo fw`
/// links (installed on first use; see `linker.rs`).
pub fn board_cargo(command: Cmd<'_>) -> Result<(), String> {
    shell::run(command.env("PATH", linker::flip_link()?.path))
}
