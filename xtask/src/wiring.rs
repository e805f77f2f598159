//! The wiring diagram (`tools/wiring`): `docs/wiring/handwheel.yml`, rendered by WireViz
//! through Graphviz into `docs/wiring/handwheel.svg`, and its checks against the firmware's
//! pin map (the table in `crates/handwheel-board/src/pins.rs`) and the README's; with them, the check that
//! every relative link in the repository's Markdown files resolves (`tools/doclinks`).
//!
//! `cargo xtask docs` re-renders the SVG (WireViz from the pinned venv `target/wiring-venv`,
//! Graphviz's `dot` installed with apt-get when root and missing), then runs the checks;
//! `cargo xtask docs --check` and `cargo xtask test` run only the checks, which need no
//! Graphviz: they read the YAML, the firmware's table, the README and the committed SVG.

use std::path::{Path, PathBuf};

use xshell::{cmd, Cmd, Shell};

use crate::{host, pyenv};

/// The package (render script, checks), relative to the workspace root.
pub const PACKAGE: &str = "tools/wiring";
/// The Markdown link check (standard library and pytest), relative to the workspace root.
pub const LINKS: &str = "tools/doclinks";
/// The marks of the documents' code blocks and the blocks checked against files
/// (standard library and pytest), relative to the workspace root.
pub const SNIPPET_MARKS: &str = "tools/snippets/test_marks.py";
/// The import graphs of the firmware crate, the no_std crates and xtask, and of the Python
/// modules of host/ and tools/, have no circle (standard library and pytest), relative to the
/// workspace root.
pub const MODULE_GRAPH: &str = "tools/modgraph";
/// Its pinned requirements (WireViz, PyYAML, pytest and their dependencies).
pub const REQUIREMENTS: &str = "tools/wiring/requirements.txt";

/// The venv's interpreter, made from [`REQUIREMENTS`] if needed.
pub fn python(root: &Path, target_dir: &Path) -> Result<PathBuf, String> {
    pyenv::ensure_from(&root.join(REQUIREMENTS), &target_dir.join("wiring-venv"))
}

/// Graphviz's `dot` (Debian package `graphviz`), installed as root when missing.
pub fn require_dot() -> Result<PathBuf, String> {
    host::require("dot", &["graphviz"])
}

/// `python tools/wiring/render.py`, in a shell in the workspace root: writes the SVG with its
/// source stamp.
pub fn render<'a>(sh: &'a Shell, python: &Path) -> Cmd<'a> {
    cmd!(sh, "{python} {PACKAGE}/render.py")
}

/// The checks under pytest (no cache folder left in the source tree), in a shell in the
/// workspace root: the wiring diagram's, the documents' links and the marks of their code
/// blocks.
pub fn tests<'a>(sh: &'a Shell, python: &Path, extra: &[&str]) -> Cmd<'a> {
    cmd!(
        sh,
        "{python} -m pytest -p no:cacheprovider {PACKAGE} {LINKS} {SNIPPET_MARKS} {MODULE_GRAPH} -q
         {extra...}"
    )
}
