//! `cargo xtask go-master`: gocanopen (a CANopen master in Go, written independently of this
//! project) against the release image on the emulated board: the suite in `tests/go-master`.
//!
//! Go 1.22 or newer must be installed (`go` on `PATH`, else `/usr/local/go/bin/go`); without it
//! the task fails, saying so. The Go module cache comes from the Go module proxy (`go.sum`
//! pins every module). The test binary is built first, then `tests/go-master/run_board.py`
//! (the interop venv's python, with the repository's rig) starts one board and runs it; the
//! task reads the binary's `-test.v` lines and ends with `gocanopen: N passed, N failed`.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Instant;

use crate::suites::Board;
use crate::workspace::{target_dir, workspace_root};
use crate::{host, pyenv};

/// gocanopen v1.4.4's `go.mod` asks for Go 1.22.
const MIN_GO_MINOR: u32 = 22;
const SUITE: &str = "tests/go-master";

/// Builds and runs the gocanopen suite; fails unless every test passed.
pub fn run() -> Result<(), String> {
    let started = Instant::now();
    let go = go_command()?;
    let root = workspace_root();
    let out = target_dir().join("go-master");
    let binary = out.join("gocanopen.test");
    // Built before the board starts, so that no board waits for a compiler.
    let status = Command::new(&go)
        .args(["test", "-c", "-o"])
        .arg(&binary)
        .arg(".")
        .current_dir(root.join(SUITE))
        // Never fetch another Go toolchain: this one was checked above.
        .env("GOTOOLCHAIN", "local")
        .status()
        .map_err(|e| format!("cannot run {}: {e}", go.display()))?;
    if !status.success() {
        return Err(format!("building the gocanopen suite failed ({status})"));
    }
    eprintln!(
        "xtask: gocanopen suite built ({:.0} s)",
        started.elapsed().as_secs_f64()
    );
    // The release image and the board's server, started without cargo (as the interop suite).
    Board::prepare()?.export();
    let python = pyenv::ensure(&root, &pyenv::venv_dir(&target_dir()))?;
    let mut child = Command::new(python)
        .arg(root.join(SUITE).join("run_board.py"))
        .arg(&out)
        .arg(&binary)
        // A hung test panics with every goroutine's stack instead of holding up CI.
        .args(["-test.v", "-test.timeout=120s"])
        .stdout(Stdio::piped())
        .spawn()
        .map_err(|e| format!("cannot start the gocanopen suite: {e}"))?;
    let (mut passed, mut failed) = (0, 0);
    if let Some(stdout) = child.stdout.take() {
        for line in BufReader::new(stdout).lines().map_while(Result::ok) {
            println!("{line}");
            // Top-level tests only: subtests' lines are indented.
            if line.starts_with("--- PASS: ") {
                passed += 1;
            } else if line.starts_with("--- FAIL: ") {
                failed += 1;
            }
        }
    }
    let status = child
        .wait()
        .map_err(|e| format!("the gocanopen suite: {e}"))?;
    println!("gocanopen: {passed} passed, {failed} failed");
    eprintln!(
        "xtask: gocanopen suite took {:.0} s",
        started.elapsed().as_secs_f64()
    );
    if failed > 0 || !status.success() {
        Err(format!("the gocanopen suite failed ({status})"))
    } else if passed == 0 {
        Err("the gocanopen suite ran no test".into())
    } else {
        Ok(())
    }
}

/// The `go` command, checked to be Go 1.22 or newer.
fn go_command() -> Result<PathBuf, String> {
    let fallback = Path::new("/usr/local/go/bin/go");
    let go = host::find_in_path("go")
        .or_else(|| fallback.is_file().then(|| fallback.to_path_buf()))
        .ok_or(
            "the gocanopen suite needs Go 1.22 or newer: no `go` on PATH nor in /usr/local/go/bin",
        )?;
    let output = Command::new(&go)
        .args(["env", "GOVERSION"])
        .env("GOTOOLCHAIN", "local")
        .output()
        .map_err(|e| format!("cannot run {}: {e}", go.display()))?;
    let version = String::from_utf8_lossy(&output.stdout).trim().to_string();
    match go_minor(&version) {
        Some(minor) if output.status.success() && minor >= MIN_GO_MINOR => Ok(go),
        _ => Err(format!(
            "the gocanopen suite needs Go 1.{MIN_GO_MINOR} or newer; {} is {version:?}",
            go.display()
        )),
    }
}

/// The minor version of a Go 1 release named like `go1.26.8` or `go1.22rc1`.
fn go_minor(version: &str) -> Option<u32> {
    let rest = version.strip_prefix("go1.")?;
    let digits: String = rest.chars().take_while(char::is_ascii_digit).collect();
    digits.parse().ok()
}

#[cfg(test)]
mod tests {
    use super::go_minor;

    #[test]
    fn go_versions() {
        assert_eq!(go_minor("go1.26.8"), Some(26));
        assert_eq!(go_minor("go1.22rc1"), Some(22));
        assert_eq!(go_minor("go1.9"), Some(9));
        assert_eq!(go_minor("devel go1.27-abcdef"), None);
        assert_eq!(go_minor(""), None);
    }
}
