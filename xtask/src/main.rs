//! Project tasks, run as `cargo xtask <task>` (an alias in `.cargo/config.toml`).
//!
//! `cargo xtask test` is the one test command of the README and of `.ci/run`: everything a
//! change must pass, in the order that fails fastest.

mod footprint;

use std::env;
use std::path::{Path, PathBuf};
use std::process::{Command, ExitCode};

const FIRMWARE_TARGET: &str = "thumbv7m-none-eabi";
/// Crates that must also build without `std` for the MCU.
const NO_STD_CRATES: &[&str] = &[
    "handwheel-core",
    "canopen-slave",
    "handwheel-device",
    "sim-io",
];

fn main() -> ExitCode {
    let args: Vec<String> = env::args().skip(1).collect();
    let result = match args.first().map(String::as_str) {
        Some("test") => test(),
        Some("fw") => firmware_build(),
        _ => {
            eprintln!("usage: cargo xtask <task>\n\ntasks:\n  test   everything CI checks\n  fw     release firmware for {FIRMWARE_TARGET}");
            return ExitCode::from(2);
        }
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(message) => {
            eprintln!("xtask: {message}");
            ExitCode::FAILURE
        }
    }
}

fn test() -> Result<(), String> {
    cargo(&["fmt", "--all", "--", "--check"])?;
    cargo(&["test", "--locked"])?;
    cargo(&[
        "clippy",
        "--locked",
        "--all-targets",
        "--",
        "-D",
        "warnings",
    ])?;
    for krate in NO_STD_CRATES {
        cargo(&[
            "build",
            "--locked",
            "--release",
            "-p",
            krate,
            "--target",
            FIRMWARE_TARGET,
        ])?;
    }
    // The firmware, its library and its on-target tests, for the MCU.
    cargo(&[
        "clippy",
        "--locked",
        "-p",
        "handwheel-firmware",
        "--target",
        FIRMWARE_TARGET,
        "--all-targets",
        "--",
        "-D",
        "warnings",
    ])?;
    firmware_build()?;
    // The on-target suites (defmt-test) cannot run here, but they must build.
    cargo(&[
        "build",
        "--locked",
        "--release",
        "--tests",
        "-p",
        "handwheel-firmware",
        "--target",
        FIRMWARE_TARGET,
    ])?;
    // The dev profile must fit the part too (the linker checks memory.x; this prints it).
    cargo(&[
        "build",
        "--locked",
        "-p",
        "handwheel-firmware",
        "--target",
        FIRMWARE_TARGET,
    ])?;
    footprint::check(
        &firmware_elf("debug"),
        "dev firmware",
        footprint::Budget {
            flash: 63 * 1024,
            ram: 20 * 1024,
        },
    )?;
    eprintln!("xtask: all checks passed");
    Ok(())
}

/// Release footprint budget of the issue: 20 KiB flash, 4 KiB static RAM (RTT included).
const RELEASE_BUDGET: footprint::Budget = footprint::Budget {
    flash: 20 * 1024,
    ram: 4 * 1024,
};

/// Builds the release firmware and fails if it is over its footprint budget.
fn firmware_build() -> Result<(), String> {
    cargo(&[
        "build",
        "--locked",
        "--release",
        "-p",
        "handwheel-firmware",
        "--target",
        FIRMWARE_TARGET,
    ])?;
    footprint::check(&firmware_elf("release"), "release firmware", RELEASE_BUDGET)?;
    Ok(())
}

/// The firmware ELF of a profile directory (`release` or `debug`).
fn firmware_elf(profile: &str) -> PathBuf {
    let target_dir = env::var_os("CARGO_TARGET_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| workspace_root().join("target"));
    target_dir
        .join(FIRMWARE_TARGET)
        .join(profile)
        .join("handwheel-firmware")
}

/// Runs cargo from the workspace root, echoing the command.
fn cargo(args: &[&str]) -> Result<(), String> {
    let cargo = env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
    eprintln!("xtask: cargo {}", args.join(" "));
    let status = Command::new(cargo)
        .args(args)
        .current_dir(workspace_root())
        .status()
        .map_err(|e| format!("cannot run cargo: {e}"))?;
    if status.success() {
        Ok(())
    } else {
        Err(format!("`cargo {}` failed ({status})", args.join(" ")))
    }
}

fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("xtask lives one level below the workspace root")
        .to_path_buf()
}
