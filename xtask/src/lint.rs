//! `cargo xtask lint`: ruff over the project's Python.

use xshell::cmd;

use crate::workspace::{target_dir, workspace_root};
use crate::{pyenv, shell};

/// `ruff check` and `ruff format --check` over all of the project's Python (tests/, tools/,
/// host/; rules in ruff.toml), with the ruff pinned in `tools/lint/requirements.txt`, in its
/// own venv (`target/lint-venv`).
pub fn python_lint() -> Result<(), String> {
    let root = workspace_root();
    let python = pyenv::ensure_from(
        &root.join(pyenv::LINT_REQUIREMENTS),
        &target_dir().join("lint-venv"),
    )?;
    let sh = &shell::at(&root)?;
    let paths = pyenv::LINT_PATHS;
    for check in [&["check"][..], &["format", "--check"]] {
        shell::run(cmd!(sh, "{python} -m ruff {check...} {paths...}")).map_err(|e| {
            format!(
                "Python lint: {e}\n(fix with target/lint-venv/bin/ruff format and ruff check \
                 --fix; docs/TESTING.md, \"Python: rig, tests, lint\")"
            )
        })?;
    }
    Ok(())
}
