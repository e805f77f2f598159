//! `cargo xtask docs`: the wiring diagram's rendering and the documents' checks
//! ([`crate::wiring`]).

use crate::workspace::{target_dir, workspace_root};
use crate::{shell, wiring, USAGE};

/// `cargo xtask docs [--check]`: re-renders the wiring diagram (unless `--check`), then
/// checks it against the firmware's and the README's pin maps, and the Markdown files' links.
pub fn docs(args: &[String]) -> Result<(), String> {
    let check_only = match args {
        [] => false,
        [flag] if flag == "--check" => true,
        _ => return Err(format!("usage: cargo xtask docs [--check]\n\n{USAGE}")),
    };
    if !check_only {
        let root = workspace_root();
        let python = wiring::python(&root, &target_dir())?;
        wiring::require_dot()?;
        let sh = &shell::at(&root)?;
        shell::run(wiring::render(sh, &python))
            .map_err(|e| format!("rendering the wiring diagram failed: {e}"))?;
    }
    wiring_check()
}

/// The wiring diagram's checks (`tools/wiring/test_wiring.py`) in `target/wiring-venv`: the
/// YAML's board pins against `crates/handwheel-board/src/pins.rs` and the README, and the SVG's stamp; every
/// relative link in the Markdown files (`tools/doclinks/test_doclinks.py`); and the marks of
/// the documents' code blocks with the checks that need no emulator
/// (`tools/snippets/test_marks.py`); and the import graphs of the firmware crate, the no_std
/// crates and xtask, and of host/'s and tools/' Python modules (`tools/modgraph`).
pub fn wiring_check() -> Result<(), String> {
    let root = workspace_root();
    let python = wiring::python(&root, &target_dir())?;
    let sh = &shell::at(&root)?;
    shell::run(wiring::tests(sh, &python, &[])).map_err(|e| {
        format!(
            "the documents' checks failed: {e}\n(after changing docs/wiring/handwheel.yml, \
             re-render with `cargo xtask docs`; a broken Markdown link: fix the link or the \
             heading it names; an unmarked code block: mark it as tools/snippets/snippets.py \
             says)"
        )
    })
}
