//! LinuxCNC for the host component's suite (`tests/linuxcnc`) and `cargo xtask linuxcnc`:
//! Debian's `linuxcnc-uspace` (installed with apt-get when root and missing), an
//! unprivileged user to run it as when this task runs as root (LinuxCNC's `rtapi_app`
//! refuses root), and the venv `target/linuxcnc-venv` made from `/usr/bin/python3
//! --system-site-packages` (so that Debian's `hal` and `linuxcnc` modules import) with the
//! pinned `host/requirements.txt` and the component from `host/` installed, so that the
//! component is `target/linuxcnc-venv/bin/canopen-handwheel`.

use std::path::{Path, PathBuf};
use std::process::Command;

use xshell::{cmd, Cmd};

use crate::{host, pyenv, shell};

/// The interpreter Debian's LinuxCNC Python modules are built for.
const SYSTEM_PYTHON: &str = "/usr/bin/python3";
/// The user LinuxCNC runs as when xtask runs as root.
pub const USER: &str = "handwheel-sim";
/// The LinuxCNC suite, relative to the workspace root.
pub const SUITE: &str = "tests/linuxcnc";
/// The detent-to-motion benchmark (`cargo xtask bench`), relative to the workspace root.
pub const BENCH: &str = "tests/linuxcnc/bench_motion.py";
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
    /// `cmd` with the environment the suite and the console read.
    pub fn apply<'a>(&self, cmd: Cmd<'a>) -> Cmd<'a> {
        cmd.env("HANDWHEEL_COMPONENT", &self.component)
            .env("HANDWHEEL_LINUXCNC_USER", self.user.unwrap_or(""))
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
    let (python, mut component) = component_venv(root, &target_dir.join("linuxcnc-venv"))?;
    let user = if host::is_root() {
        ensure_user()?;
        if !user_can_run(&component) {
            // The clone sits below a folder closed to others (a private home, a mktemp
            // folder): give LinuxCNC's user a venv of its own, in its home.
            let home = user_home()?;
            eprintln!(
                "xtask: `{USER}` cannot reach {}; installing the component for it in {}",
                component.display(),
                home.display()
            );
            component = component_venv(root, &home.join("linuxcnc-venv"))?.1;
            if !user_can_run(&component) {
                return Err(format!(
                    "the user `{USER}` that runs LinuxCNC cannot run {}",
                    component.display()
                ));
            }
        }
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

/// The venv at `venv` with the pinned requirements and the component from `host/`;
/// returns its interpreter and the component's console script.
fn component_venv(root: &Path, venv: &Path) -> Result<(PathBuf, PathBuf), String> {
    let python = pyenv::ensure_with(
        Path::new(SYSTEM_PYTHON),
        &["--system-site-packages"],
        &root.join(pyenv::HOST_REQUIREMENTS),
        venv,
    )?;
    // The dependencies are pinned and installed above; setuptools comes with the venv.
    let sh = &shell::at(root)?;
    let package = root.join(pyenv::HOST_PACKAGE);
    shell::run(
        pyenv::pip_install(sh, &python)
            .args(["--no-deps", "--no-build-isolation", "--force-reinstall"])
            .arg(package),
    )?;
    let component = venv.join("bin").join("canopen-handwheel");
    if !component.is_file() {
        return Err(format!("{} was not installed", component.display()));
    }
    Ok((python, component))
}

/// Creates [`USER`] when missing.
fn ensure_user() -> Result<(), String> {
    let exists = Command::new("id")
        .args(["-u", USER])
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false);
    if !exists {
        let sh = &shell::at(Path::new("/"))?;
        shell::run(cmd!(
            sh,
            "useradd --system --create-home --shell /bin/sh {USER}"
        ))?;
    }
    Ok(())
}

/// Whether [`USER`] can run `component` (every folder above it open to it). The sim
/// configuration needs no such check: `sim_machine.py` copies it to a folder of that user.
fn user_can_run(component: &Path) -> bool {
    let check = format!("test -x '{}'", component.display());
    Command::new("su")
        .args([USER, "-s", "/bin/sh", "-c", &check])
        .status()
        .map(|s| s.success())
        .unwrap_or(false)
}

/// [`USER`]'s home folder, from the password database.
fn user_home() -> Result<PathBuf, String> {
    let out = Command::new("getent")
        .args(["passwd", USER])
        .output()
        .map_err(|e| format!("getent passwd {USER}: {e}"))?;
    let line = String::from_utf8_lossy(&out.stdout);
    line.trim_end()
        .split(':')
        .nth(5)
        .filter(|home| !home.is_empty())
        .map(PathBuf::from)
        .ok_or_else(|| format!("no home folder for `{USER}` in the password database"))
}
