//! `cargo xtask node-master`: node-canopen (npm `canopen`, pinned in
//! `tests/node-master/package-lock.json`) as a second CANopen master, independent of
//! python-canopen, against the release image on the emulated board (`tests/node-master`:
//! plain `node:test` files; each group's board is started by `board.py` with the rig).
//!
//! Prints `node-canopen: N passed, N failed` and fails when a test failed, none ran, or
//! node or npm is missing: the suite never passes by not running.

use std::fs;
use std::path::Path;
use std::process::Command;
use std::time::{Instant, SystemTime};

use xshell::cmd;

use crate::suites::Board;
use crate::workspace::{target_dir, workspace_root};
use crate::{pyenv, shell};

/// The suite, relative to the workspace root.
const SUITE: &str = "tests/node-master";
/// Its test files, run one after the other (each boots its own board).
const TEST_FILES: [&str; 2] = ["services.test.js", "update.test.js"];
/// The oldest Node.js with everything the suite uses (`node:test` hooks, `zlib.crc32`).
const NODE_MIN: (u32, u32) = (20, 15);

/// Installs node-canopen if needed, builds the release image and the interop venv, runs the
/// suite and prints its counts.
pub fn run() -> Result<(), String> {
    let started = Instant::now();
    let root = workspace_root();
    let suite = root.join(SUITE);
    node_version()?;
    install(&suite)?;
    // The release image, the loader and the update file, built; boards then start without
    // cargo (`HANDWHEEL_BOARD_SERVER`), from the interop venv's rig.
    Board::prepare()?.export();
    let python = pyenv::ensure(&root, &pyenv::venv_dir(&target_dir()))?;

    // Spec for the terminal, TAP into a file for the counts.
    let tap = target_dir().join("node-master").join("results.tap");
    fs::create_dir_all(tap.parent().unwrap_or(&root))
        .map_err(|e| format!("cannot create {}: {e}", tap.display()))?;
    let _ = fs::remove_file(&tap);
    let options = [
        "--test-concurrency=1".to_string(),
        "--test-reporter=spec".into(),
        "--test-reporter-destination=stdout".into(),
        "--test-reporter=tap".into(),
        format!("--test-reporter-destination={}", tap.display()),
    ];
    let sh = &shell::at(&suite)?;
    let node = cmd!(sh, "node --test {options...} {TEST_FILES...}");
    let run = shell::run(node.env("NODE_MASTER_PYTHON", &python));
    let report = fs::read_to_string(&tap).unwrap_or_default();
    let count = |key: &str| -> u32 {
        let prefix = format!("# {key} ");
        report
            .lines()
            .filter_map(|line| line.strip_prefix(&prefix)?.trim().parse::<u32>().ok())
            .sum()
    };
    let passed = count("pass");
    let failed = count("fail") + count("cancelled");
    // A file that failed outside any test counts none: it still failed.
    let failed = if run.is_err() { failed.max(1) } else { failed };
    println!("node-canopen: {passed} passed, {failed} failed");
    eprintln!(
        "xtask: node-canopen suite took {:.0} s",
        started.elapsed().as_secs_f64()
    );
    run.map_err(|e| format!("the node-canopen suite failed: {e}"))?;
    if failed > 0 || passed == 0 {
        return Err(format!(
            "the node-canopen suite: {passed} passed, {failed} failed"
        ));
    }
    Ok(())
}

/// Fails unless `node` is on PATH and at least [`NODE_MIN`], and `npm` is there too.
fn node_version() -> Result<(), String> {
    let version = |program: &str| -> Result<String, String> {
        let out = Command::new(program)
            .arg("--version")
            .output()
            .map_err(|e| {
                format!(
                    "`{program}` not found ({e}): the node-canopen suite needs Node.js {}.{} or \
                 later and npm (Debian: nodejs, npm)",
                    NODE_MIN.0, NODE_MIN.1
                )
            })?;
        Ok(String::from_utf8_lossy(&out.stdout).trim().to_string())
    };
    let node = version("node")?;
    version("npm")?;
    let mut parts = node
        .trim_start_matches('v')
        .split('.')
        .map(str::parse::<u32>);
    let found = (
        parts.next().and_then(Result::ok).unwrap_or(0),
        parts.next().and_then(Result::ok).unwrap_or(0),
    );
    if found < NODE_MIN {
        return Err(format!(
            "node {node}: the node-canopen suite needs {}.{} or later",
            NODE_MIN.0, NODE_MIN.1
        ));
    }
    Ok(())
}

/// `npm ci` when `node_modules` is missing or older than the lock file (npm writes
/// `node_modules/.package-lock.json` at every install). node-canopen loads a native CRC
/// addon that npm builds with node-gyp: pointed at the headers of the node that runs it,
/// node-gyp downloads none.
fn install(suite: &Path) -> Result<(), String> {
    let modified = |path: &Path| fs::metadata(path).and_then(|m| m.modified()).ok();
    let installed = modified(&suite.join("node_modules").join(".package-lock.json"));
    let locked = modified(&suite.join("package-lock.json")).unwrap_or(SystemTime::now());
    if installed.is_some_and(|installed| installed >= locked) {
        return Ok(());
    }
    let sh = &shell::at(suite)?;
    let mut npm = cmd!(sh, "npm ci --no-audit --no-fund");
    if std::env::var_os("npm_config_nodedir").is_none() {
        let prefix = Command::new("node")
            .args(["-p", "require('path').resolve(process.execPath, '../..')"])
            .output()
            .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string())
            .unwrap_or_default();
        if Path::new(&prefix).join("include/node/node_api.h").exists() {
            npm = npm.env("npm_config_nodedir", prefix);
        }
    }
    shell::run(npm).map_err(|e| format!("installing node-canopen failed: {e}"))
}
