//! LinuxCNC for the host component's suite (`tests/linuxcnc`) and `cargo xtask linuxcnc`:
//! Debian's `linuxcnc-uspace` (installed with apt-get when root and missing), an
//! unprivileged user to run it as when this task runs as root (LinuxCNC's `rtapi_app`
//! refuses root), and the venv `target/linuxcnc-venv` made from `/usr/bin/python3
//! --system-site-packages` (so that Debian's `hal` and `linuxcnc` modules import) with the
//! pinned `host/requirements.txt` and the component from `host/` installed, so that the
//! component is `target/linuxcnc-venv/bin/canopen-handwheel`.

use std::path::{Path, PathBuf};
use std::process::Command;

use crate::{host, pyenv};

/// The interpreter Debian's LinuxCNC Python modules are built for.
const SYSTEM_PYTHON: &str = "/usr/bin/python3";
/// The user LinuxCNC runs as when xtask runs as root.
pub const USER: &str = "handwheel-sim";
/// The LinuxCNC suite, relative to the workspace root.
pub const SUITE: &str = "tests/linuxcnc";
/// The console of `cargo xtask linuxcnc`, relative to the workspace root.
pub const CONSOLE: &str = "host/linuxcnc/console.py";

/// What the suite and the console need.
pub struct Setup {
    /// The venv's interpreter.
    pub python: PathBuf,
    /// The installed component.
    pub component: PathBuf,
    /// The user to run LinuxCNC as (`None`: this user).
    pub user: Option<&'static str>,
}

impl Setup {
    /// The environment the suite and the console read.
    pub fn apply(&self, cmd: &mut Command) {
        cmd.env("HANDWHEEL_COMPONENT", &self.component)
            .env("HANDWHEEL_LINUXCNC_USER", self.user.unwrap_or(""));
    }
}

/// Installs or checks everything; cheap when it is all there (the component is reinstalled
/// every time, a few seconds, so that it is always the working tree's).
pub fn prepare(root: &Path, target_dir: &Path) -> Result<Setup, String> {
    host::require("linuxcnc", &["linuxcnc-uspace"])?;
    let base = Path::new(SYSTEM_PYTHON);
    if !base.is_file() {
        return Err(format!(
            "{SYSTEM_PYTHON} not found: LinuxCNC's Python modules need Debian's python3"
        ));
    }
    let venv = target_dir.join("linuxcnc-venv");
    let python = pyenv::ensure_with(
        base,
        &["--system-site-packages"],
        &root.join(pyenv::HOST_REQUIREMENTS),
        &venv,
    )?;
    // The dependencies are pinned and installed above; setuptools comes with the venv.
    pyenv::run(
        Command::new(&python)
            .args([
                "-m",
                "pip",
                "install",
                "--disable-pip-version-check",
                "--no-input",
                "--quiet",
                "--no-deps",
                "--no-build-isolation",
                "--force-reinstall",
            ])
            .arg(root.join(pyenv::HOST_PACKAGE)),
    )?;
    let component = venv.join("bin").join("canopen-handwheel");
    if !component.is_file() {
        return Err(format!("{} was not installed", component.display()));
    }
    let user = if host::is_root() {
        ensure_user(root, &component)?;
        Some(USER)
    } else {
        None
    };
    Ok(Setup {
        python,
        component,
        user,
    })
}

/// Creates [`USER`] when missing and checks that it can run the component and read the
/// sim configuration (every folder above them must be open to others).
fn ensure_user(root: &Path, component: &Path) -> Result<(), String> {
    let exists = Command::new("id")
        .args(["-u", USER])
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false);
    if !exists {
        pyenv::run(Command::new("useradd").args([
            "--system",
            "--create-home",
            "--shell",
            "/bin/sh",
            USER,
        ]))?;
    }
    let sim = root.join("host/linuxcnc/sim/handwheel-display");
    let check = format!(
        "test -x '{}' && test -x '{}'",
        component.display(),
        sim.display()
    );
    let ok = Command::new("su")
        .args([USER, "-s", "/bin/sh", "-c", &check])
        .status()
        .map(|s| s.success())
        .unwrap_or(false);
    if ok {
        Ok(())
    } else {
        Err(format!(
            "the user `{USER}` that runs LinuxCNC cannot run {} or read {}: the folders \
             above the repository must be readable by others (chmod o+rx), or clone it \
             elsewhere",
            component.display(),
            sim.display()
        ))
    }
}
