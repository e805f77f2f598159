//! The machine xtask runs on: programs on `PATH`, whether we are root, Debian packages, and
//! the tools xtask installs with `cargo install` (`defmt-print`, flip-link) into cargo's `bin`
//! folder or the project's, with the `PATH` that finds them.
//!
//! Used by the tasks that install what they need on a fresh Debian machine when running as
//! root and explain what to install otherwise ([`crate::pyenv`], [`crate::linuxcnc`],
//! [`crate::wiring`], [`crate::linker`]); it uses none of them.

use std::env;
use std::ffi::OsString;
use std::path::{Path, PathBuf};
use std::process::Command;

use xshell::{cmd, Shell};

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

/// cargo's `bin` folder for `cargo install` without `--root`: `$CARGO_INSTALL_ROOT/bin`,
/// else `$CARGO_HOME/bin`, else `~/.cargo/bin`.
pub fn cargo_bin_dir() -> Option<PathBuf> {
    let var = |name: &str| env::var_os(name).filter(|v| !v.is_empty());
    let root = var("CARGO_INSTALL_ROOT")
        .or_else(|| var("CARGO_HOME"))
        .map(PathBuf::from)
        .or_else(|| var("HOME").map(|home| Path::new(&home).join(".cargo")))?;
    Some(root.join("bin"))
}

/// `PATH` with `dir` in front, unless it is on it already.
pub fn path_with(dir: &Path) -> OsString {
    let current = env::var_os("PATH").unwrap_or_default();
    if env::split_paths(&current).any(|p| p == dir) {
        return current;
    }
    env::join_paths(std::iter::once(dir.to_path_buf()).chain(env::split_paths(&current)))
        .unwrap_or(current)
}

/// The `defmt-print` release this project uses (supports defmt wire formats 3 and 4, i.e.
/// defmt 0.3 and 1.x).
pub const DEFMT_PRINT_VERSION: &str = "1.2.0";

/// Where project tools are installed (`cargo install --root`): beside cargo's own `bin`
/// folder, in a folder of the project's, so that a fresh clone (every CI run) finds them
/// built and a pinned version never replaces one the user installed. Below the target
/// directory when cargo's home is unknown.
pub fn tools_root(target_dir: &Path) -> PathBuf {
    cargo_bin_dir()
        .and_then(|bin| bin.parent().map(|home| home.join("handwheel-tools")))
        .unwrap_or_else(|| target_dir.join("tools"))
}

/// `defmt-print` [`DEFMT_PRINT_VERSION`] in `<tools_root>/bin`, installed with
/// `cargo install --locked` on first use and reused afterwards.
pub fn defmt_print(tools_root: &Path) -> Result<PathBuf, String> {
    let bin = tools_root.join("bin").join("defmt-print");
    let wanted = format!("defmt-print {DEFMT_PRINT_VERSION}");
    let installed = Command::new(&bin)
        .arg("--version")
        .output()
        .map(|o| String::from_utf8_lossy(&o.stdout).lines().next() == Some(wanted.as_str()))
        .unwrap_or(false);
    if installed {
        return Ok(bin);
    }
    cargo_install(Some(tools_root), "defmt-print", DEFMT_PRINT_VERSION)
}

/// `cargo install <name> --locked --version =<version>`, with `--root <root>` if given (else
/// into cargo's own `bin` folder, [`cargo_bin_dir`]); returns the installed
/// binary, which must exist afterwards. The one way xtask installs a tool. The install runs
/// with that `bin` folder on its `PATH`: xtask calls the tool by its path (or puts the folder
/// on its builds' `PATH`), so cargo's advice to add the folder to `PATH` would mislead.
pub fn cargo_install(root: Option<&Path>, name: &str, version: &str) -> Result<PathBuf, String> {
    let bin_dir = match root {
        Some(root) => root.join("bin"),
        None => cargo_bin_dir()
            .ok_or("cannot tell cargo's bin folder: neither CARGO_HOME nor HOME is set")?,
    };
    let bin = bin_dir.join(name);
    let version = format!("={version}");
    let sh = &Shell::new().map_err(|e| format!("cannot start a shell: {e}"))?;
    let root_option = root.map(|root| [Path::new("--root"), root]);
    let root_option = root_option.iter().flatten();
    let command = cmd!(
        sh,
        "cargo install {name} --locked --version {version} {root_option...}"
    )
    .env("PATH", path_with(&bin_dir));
    eprintln!(
        "xtask: cargo install {name} --locked --version {version}{} (once; it builds from \
         source, a few minutes)",
        root.map(|r| format!(" --root {}", r.display()))
            .unwrap_or_default()
    );
    command
        .quiet()
        .run()
        .map_err(|e| format!("installing {name} failed: {e}"))?;
    if bin.is_file() {
        Ok(bin)
    } else {
        Err(format!(
            "{name} not found at {} after install",
            bin.display()
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn finds_a_shell_and_not_nonsense() {
        assert!(find_in_path("sh").is_some());
        assert!(find_in_path("no-such-program-xtask-test").is_none());
    }

    #[test]
    fn path_with_puts_a_folder_first_once() {
        let dir = Path::new("/no/such/xtask-test-bin");
        let once = path_with(dir);
        assert_eq!(env::split_paths(&once).next().as_deref(), Some(dir));
        let current = env::var_os("PATH").unwrap_or_default();
        assert_eq!(
            env::split_paths(&once).count(),
            env::split_paths(&current).count() + 1
        );
    }
}
