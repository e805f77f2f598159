//! Project tasks, run as `cargo xtask <task>` (an alias in `.cargo/config.toml`).
//!
//! `cargo xtask test` is the one test command of the README and of `.ci/run`: everything a
//! change must pass, in the order that fails fastest.

use std::env;
use std::path::{Path, PathBuf};
use std::process::{Command, ExitCode};

const FIRMWARE_TARGET: &str = "thumbv7m-none-eabi";
/// Crates that must also build without `std` for the MCU.
const NO_STD_CRATES: &[&str] = &["handwheel-core", "canopen-slave", "handwheel-device"];

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
    cargo(&[
        "clippy",
        "--locked",
        "-p",
        "handwheel-firmware",
        "--target",
        FIRMWARE_TARGET,
        "--",
        "-D",
        "warnings",
    ])?;
    firmware_build()?;
    eprintln!("xtask: all checks passed");
    Ok(())
}

fn firmware_build() -> Result<(), String> {
    cargo(&[
        "build",
        "--locked",
        "--release",
        "-p",
        "handwheel-firmware",
        "--target",
        FIRMWARE_TARGET,
    ])
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
