//! The Python environments: the interop suite's venv in `target/interop-venv` made from
//! `tests/interop/requirements.txt` (pinned python-can, canopen, pyserial, pytest), and any
//! other pinned requirements file through [`ensure_from`] (the chip model's, shared by the
//! emulated board and the machine benchmark; the component's; the linter's).
//!
//! The venv is rebuilt only when the requirements file or the interpreter changes: a stamp
//! file in the venv records a hash of both, and is written last, so an interrupted install
//! is redone next time. On a fresh Debian machine, running as root, a missing `python3` or
//! `venv` module (packages `python3`, `python3-venv`) is installed with apt-get.

use std::path::{Path, PathBuf};
use std::process::Command;

use xshell::{cmd, Cmd, Shell};

use crate::{host, shell};

/// The requirements file, relative to the workspace root.
pub const REQUIREMENTS: &str = "tests/interop/requirements.txt";
/// The suite, relative to the workspace root.
pub const SUITE: &str = "tests/interop";
/// The host component's pinned requirements (its dependencies and its tests').
pub const HOST_REQUIREMENTS: &str = "host/requirements.txt";
/// The host component's package folder (pyproject.toml, its unit tests).
pub const HOST_PACKAGE: &str = "host";
/// The pinned Python linter and formatter (ruff; its rules are in `ruff.toml`).
pub const LINT_REQUIREMENTS: &str = "tools/lint/requirements.txt";
/// What ruff checks: all of the project's Python, relative to the workspace root.
pub const LINT_PATHS: &[&str] = &["tests", "tools", "host"];
/// The chip model's pinned requirements (`tools/stm32emu`: unicorn, pyelftools, capstone,
/// pytest), for the emulated board and the machine benchmark alike.
pub const EMU_REQUIREMENTS: &str = "tools/stm32emu/requirements.txt";
/// Stamp file inside the venv.
const STAMP: &str = "requirements.stamp";

/// The venv folder below the target directory.
pub fn venv_dir(target_dir: &Path) -> PathBuf {
    target_dir.join("interop-venv")
}

/// The chip model's venv (`target/emu-venv`), made from [`EMU_REQUIREMENTS`] if needed;
/// returns its interpreter.
pub fn emu_python(root: &Path, target_dir: &Path) -> Result<PathBuf, String> {
    ensure_from(&root.join(EMU_REQUIREMENTS), &target_dir.join("emu-venv"))
}

/// The venv's interpreter.
pub fn venv_python(venv: &Path) -> PathBuf {
    venv.join("bin").join("python")
}

/// 64-bit FNV-1a: enough to notice that a file changed.
fn fnv1a(chunks: &[&[u8]]) -> u64 {
    let mut hash: u64 = 0xcbf2_9ce4_8422_2325;
    for chunk in chunks {
        for &b in *chunk {
            hash ^= u64::from(b);
            hash = hash.wrapping_mul(0x0000_0100_0000_01b3);
        }
        // Separate the chunks, so that ("ab", "c") and ("a", "bc") differ.
        hash ^= 0xff;
        hash = hash.wrapping_mul(0x0000_0100_0000_01b3);
    }
    hash
}

/// `python3 --version` of the base interpreter (empty if it does not run).
fn interpreter_version(python: &Path) -> String {
    Command::new(python)
        .arg("--version")
        .output()
        .map(|o| {
            let mut v = o.stdout;
            v.extend_from_slice(&o.stderr);
            String::from_utf8_lossy(&v).trim().to_string()
        })
        .unwrap_or_default()
}

/// The base interpreter: `$PYTHON` if set, else `python3` on PATH (installed as root).
pub fn base_python() -> Result<PathBuf, String> {
    if let Some(p) = std::env::var_os("PYTHON") {
        return Ok(PathBuf::from(p));
    }
    host::require("python3", &["python3", "python3-venv"])
}

/// Creates or refreshes the venv at `venv` from `<root>/tests/interop/requirements.txt`;
/// returns the venv's interpreter. Does nothing when the stamp matches.
pub fn ensure(root: &Path, venv: &Path) -> Result<PathBuf, String> {
    ensure_from(&root.join(REQUIREMENTS), venv)
}

/// Creates or refreshes the venv at `venv` from the pinned `requirements` file; returns the
/// venv's interpreter. Does nothing when the stamp matches.
///
/// When the base interpreter's pip can install into another environment (`pip --python`,
/// pip 22.3 and later), the venv gets no pip of its own and the base's pip fills it: making
/// a venv with its own pip is most of the time a venv takes.
pub fn ensure_from(requirements: &Path, venv: &Path) -> Result<PathBuf, String> {
    let base = base_python()?;
    let pip = if pip_can_target(&base) {
        Pip::Base
    } else {
        Pip::Own
    };
    make_venv(&base, &[], pip, requirements, venv)
}

/// Like [`ensure_from`], with the base interpreter `base` and extra `venv_options` (such as
/// `--system-site-packages`, which then become part of the stamp), and a pip (and
/// setuptools) of the venv's own.
pub fn ensure_with(
    base: &Path,
    venv_options: &[&str],
    requirements: &Path,
    venv: &Path,
) -> Result<PathBuf, String> {
    make_venv(base, venv_options, Pip::Own, requirements, venv)
}

/// Which pip fills a venv.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Pip {
    /// The venv's own (`ensurepip`).
    Own,
    /// The base interpreter's, with `--python` (the venv has none).
    Base,
}

/// Whether `base -m pip` is pip 22.3 or later, which takes `--python`.
fn pip_can_target(base: &Path) -> bool {
    Command::new(base)
        .args(["-m", "pip", "--version"])
        .output()
        .is_ok_and(|out| {
            out.status.success() && pip_takes_python(&String::from_utf8_lossy(&out.stdout))
        })
}

/// Whether the pip of `pip --version`'s line (`pip 23.2.1 from ...`) is 22.3 or later.
fn pip_takes_python(version_line: &str) -> bool {
    let version: Vec<u32> = version_line
        .split_whitespace()
        .nth(1)
        .unwrap_or("")
        .split('.')
        .map_while(|part| part.parse().ok())
        .collect();
    version.as_slice() >= [22, 3].as_slice()
}

fn make_venv(
    base: &Path,
    venv_options: &[&str],
    pip: Pip,
    requirements: &Path,
    venv: &Path,
) -> Result<PathBuf, String> {
    let pinned = std::fs::read(requirements)
        .map_err(|e| format!("cannot read {}: {e}", requirements.display()))?;
    let base = base.to_path_buf();
    let without_pip: &[&str] = if pip == Pip::Base {
        &["--without-pip"]
    } else {
        &[]
    };
    let version = [
        interpreter_version(&base),
        base.display().to_string(),
        without_pip.join(" "),
        venv_options.join(" "),
    ]
    .iter()
    .filter(|part| !part.is_empty())
    .cloned()
    .collect::<Vec<_>>()
    .join(" ");
    let stamp = format!("{:016x} {version}\n", fnv1a(&[&pinned, version.as_bytes()]));
    let python = venv_python(venv);
    let stamp_path = venv.join(STAMP);
    if python.is_file() && std::fs::read_to_string(&stamp_path).ok().as_deref() == Some(&stamp) {
        return Ok(python);
    }
    // A half-made or outdated venv is rebuilt from scratch: `--clear` empties it.
    let _ = std::fs::remove_file(&stamp_path);
    let sh = &Shell::new().map_err(|e| format!("cannot start a shell: {e}"))?;
    let make = |python: &Path| {
        shell::run(cmd!(
            sh,
            "{python} -m venv --clear {without_pip...} {venv_options...} {venv}"
        ))
    };
    if let Err(first) = make(&base) {
        // Debian's python3 lacks `ensurepip` until python3-venv is installed.
        if !host::is_root() {
            return Err(format!(
                "{first}\nthe Python `venv` module does not work: install the Debian \
                 package `python3-venv` (or run this task as root to have it installed)"
            ));
        }
        host::apt_install(&["python3-venv"])?;
        make(&base)?;
    }
    let install = match pip {
        Pip::Own => pip_install(sh, &python),
        Pip::Base => cmd!(
            sh,
            "{base} -m pip --python {python} install --disable-pip-version-check --no-input
             --quiet"
        ),
    };
    shell::run(install.arg("-r").arg(requirements))?;
    std::fs::write(&stamp_path, stamp)
        .map_err(|e| format!("cannot write {}: {e}", stamp_path.display()))?;
    Ok(python)
}

/// `python -m pip install` with the options every install here uses (quiet, no prompts);
/// the caller adds what to install.
pub fn pip_install<'a>(sh: &'a Shell, python: &Path) -> Cmd<'a> {
    cmd!(
        sh,
        "{python} -m pip install --disable-pip-version-check --no-input --quiet"
    )
}

/// `python -m pytest` on [`HOST_WORKERS`] workers (pytest-xdist), then `<extra>` (`-n 0`
/// there runs in one process), in a shell in `host/`: the component's unit and property tests
/// (its pyproject puts `src` on the path).
pub fn host_pytest<'a>(sh: &'a Shell, python: &Path, extra: &[String]) -> Cmd<'a> {
    cmd!(sh, "{python} -m pytest -n {HOST_WORKERS} {extra...}")
}

/// The component's tests' pytest-xdist workers: most of their time is the shell's tests
/// waiting on the wall clock (heartbeats, stalls, floods), so two workers halve the step.
pub const HOST_WORKERS: &str = "2";

/// `python -m pytest tests/interop` on [`INTEROP_WORKERS`] workers (pytest-xdist), then
/// `<extra>` (`-n 0` there runs in one process), in a shell in the workspace root.
pub fn pytest<'a>(sh: &'a Shell, python: &Path, extra: &[String]) -> Cmd<'a> {
    cmd!(
        sh,
        "{python} -m pytest {SUITE} -n {INTEROP_WORKERS} --durations=12 {extra...}"
    )
}

/// The interop suite's pytest-xdist workers: every test runs its own board on free ports in
/// its own folder, and a test spends most of its time waiting on the board's clock (one
/// board and its master use under one core), so two workers keep a 2-core machine busy.
pub const INTEROP_WORKERS: &str = "2";

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pip_takes_python_from_22_3_on() {
        assert!(pip_takes_python(
            "pip 23.2.1 from /usr/lib/python3/dist-packages/pip"
        ));
        assert!(pip_takes_python("pip 22.3 from x"));
        assert!(!pip_takes_python("pip 22.2.2 from x"));
        assert!(!pip_takes_python("pip 9.0.1 from x"));
        assert!(!pip_takes_python("/usr/bin/python3: No module named pip"));
        assert!(!pip_takes_python(""));
    }

    #[test]
    fn hash_notices_changes_and_chunk_boundaries() {
        assert_eq!(fnv1a(&[b"abc"]), fnv1a(&[b"abc"]));
        assert_ne!(fnv1a(&[b"abc"]), fnv1a(&[b"abd"]));
        assert_ne!(fnv1a(&[b"ab", b"c"]), fnv1a(&[b"a", b"bc"]));
    }
}
