//! Running the tasks' commands: written with xshell's `cmd!` in a [`Shell`] whose working
//! folder is where they run (the workspace root, unless a task says otherwise), each echoed as
//! `xtask: <command>` before it runs.

use std::path::Path;
use std::process::Command;

use xshell::{Cmd, Shell};

/// A shell whose commands run in `dir`.
pub fn at(dir: &Path) -> Result<Shell, String> {
    let sh = Shell::new().map_err(|e| format!("cannot start a shell: {e}"))?;
    sh.change_dir(dir);
    Ok(sh)
}

/// Runs `cmd`, echoing it; fails unless it exits successfully. It keeps the terminal's
/// stdin, which xshell's own `run` closes: `cargo xtask interop --pdb` needs it to stop at a
/// failing test.
pub fn run(cmd: Cmd<'_>) -> Result<(), String> {
    eprintln!("xtask: {cmd}");
    let shown = cmd.to_string();
    let started = std::time::Instant::now();
    let status = Command::from(cmd)
        .status()
        .map_err(|e| format!("cannot run `{shown}`: {e}"))?;
    // Each step's time, so that a CI log shows where the run's minutes go.
    eprintln!("xtask: ({:.0} s)", started.elapsed().as_secs_f64());
    if status.success() {
        Ok(())
    } else {
        Err(format!("`{shown}` failed ({status})"))
    }
}
