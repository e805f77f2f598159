//! The machine xtask runs on: programs on `PATH`, whether we are root, Debian packages.
//!
//! Shared by [`crate::qemu`] and [`crate::pyenv`], which install what they need on a fresh
//! Debian machine when running as root and explain what to install otherwise.

use std::env;
use std::path::{Path, PathBuf};
use std::process::Command;

use xshell::cmd;

use crate::shell;

/// The first executable `name` on `PATH`.
pub fn find_in_path(name: &str) -> Option<PathBuf> {
    let path = env::var_os("PATH")?;
    env::split_paths(&path)
        .map(|dir| dir.join(name))
        .find(|candidate| is_executable(candidate))
}

fn is_executable(path: &Path) -> bool {
    use std::os::unix::fs::PermissionsExt;
    path.metadata()
        .map(|m| m.is_file() && m.permissions().mode() & 0o111 != 0)
        .unwrap_or(false)
}

/// Whether the effective user is root (from `/proc/self/status`, else `id -u`).
pub fn is_root() -> bool {
    if let Ok(status) = std::fs::read_to_string("/proc/self/status") {
        if let Some(uids) = status.lines().find_map(|l| l.strip_prefix("Uid:")) {
            // Real, effective, saved, filesystem.
            return uids.split_whitespace().nth(1) == Some("0");
        }
    }
    Command::new("id")
        .arg("-u")
        .output()
        .map(|o| o.status.success() && o.stdout.trim_ascii() == b"0")
        .unwrap_or(false)
}

/// `apt-get update` then `apt-get install -y <packages>`, non-interactively. Only call as
/// root; fails with a message naming the packages.
pub fn apt_install(packages: &[&str]) -> Result<(), String> {
    let list = packages.join(" ");
    if find_in_path("apt-get").is_none() {
        return Err(format!(
            "apt-get not found: install the package(s) `{list}` by hand"
        ));
    }
    let sh = &shell::at(Path::new("/"))?;
    for apt_get in [
        cmd!(sh, "apt-get update"),
        cmd!(
            sh,
            "apt-get install -y --no-install-recommends {packages...}"
        ),
    ] {
        shell::run(apt_get.env("DEBIAN_FRONTEND", "noninteractive"))
            .map_err(|e| format!("{e}; install `{list}` by hand"))?;
    }
    Ok(())
}

/// `program` on `PATH`, or, when root, installed from the Debian `packages`; otherwise an
/// error naming the packages to install.
pub fn require(program: &str, packages: &[&str]) -> Result<PathBuf, String> {
    if let Some(path) = find_in_path(program) {
        return Ok(path);
    }
    let list = packages.join(" ");
    if !is_root() {
        return Err(format!(
            "`{program}` not found on PATH: install the Debian package(s) `{list}` \
             (e.g. `sudo apt-get install {list}`), or run this task as root to have it \
             installed"
        ));
    }
    apt_install(packages)?;
    find_in_path(program)
        .ok_or_else(|| format!("`{program}` still not on PATH after installing `{list}`"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn finds_a_shell_and_not_nonsense() {
        assert!(find_in_path("sh").is_some());
        assert!(find_in_path("no-such-program-xtask-test").is_none());
    }
}
