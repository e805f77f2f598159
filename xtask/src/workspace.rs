//! Where the tasks run: the workspace root, the target directory, the shell cargo runs in.

use std::env;
use std::path::{Path, PathBuf};

use xshell::{Cmd, Shell};

use crate::shell;

/// The target directory (`CARGO_TARGET_DIR` or `<root>/target`).
pub fn target_dir() -> PathBuf {
    env::var_os("CARGO_TARGET_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| workspace_root().join("target"))
}

/// A shell in the workspace root, where the cargo commands run.
pub fn root_shell() -> Result<Shell, String> {
    shell::at(&workspace_root())
}

/// Runs a cargo command (from [`root_shell`]), echoing it.
pub fn cargo(command: Cmd<'_>) -> Result<(), String> {
    shell::run(command)
}

pub fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("xtask lives one level below the workspace root")
        .to_path_buf()
}
