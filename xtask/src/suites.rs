//! The test suites outside `cargo test`: on the emulated board (interop, the documents'
//! snippets, LinuxCNC, the board's own unit tests), the host component's tests and the feed
//! contract's check.

use std::env;
use std::path::PathBuf;
use std::time::Instant;

use xshell::cmd;

use crate::fw::{
    firmware_elf, loader_build, loader_elf, overflow_build, release_build, update_file,
};
use crate::workspace::{cargo, root_shell, target_dir, workspace_root};
use crate::{board, host, linuxcnc, pyenv, shell};

/// The check that runs the README's and docs/' code blocks against the emulated board (their
/// marks, and the blocks checked against files: `tools/snippets/test_marks.py`, with the
/// documents' checks).
const SNIPPETS_RUN: &str = "tools/snippets/test_run.py";

/// Everything the emulated board needs: the image, its venv, `defmt-print`.
pub struct Board {
    pub python: PathBuf,
    pub defmt_print: PathBuf,
    pub elf: PathBuf,
    pub image: board::Image,
}

impl Board {
    /// The release image's board.
    pub fn prepare() -> Result<Self, String> {
        Self::prepare_image(board::Image::Release)
    }

    pub fn prepare_image(image: board::Image) -> Result<Self, String> {
        let elf = match image {
            board::Image::Release | board::Image::Broken(_) => {
                release_build()?;
                let elf = firmware_elf("release");
                // The board boots the loader, and the update tests send this file.
                loader_build()?;
                let update = update_file();
                crate::update::write(&elf, &update)?;
                env::set_var("HANDWHEEL_UPDATE_FILE", &update);
                elf
            }
            board::Image::StackOverflow => overflow_build()?,
        };
        let python = board::python(&workspace_root(), &target_dir())?;
        let defmt_print = host::defmt_print(&host::tools_root(&target_dir()))?;
        Ok(Self {
            python,
            defmt_print,
            elf,
            image,
        })
    }

    /// Lets the rig (`tools/rig/emulator.py`) start boards of this image by running their server
    /// itself instead of `cargo xtask board` (cargo and the task runner were most of a board's
    /// start: docs/TESTING.md): `HANDWHEEL_BOARD_SERVER` (the release image) or
    /// `HANDWHEEL_BOARD_SERVER_STACK_OVERFLOW` holds the server's command up to the board's
    /// own options, as a shell line. The release image boots the loader, as `cargo xtask
    /// board` does.
    pub fn export(&self) {
        let (variable, loader) = match self.image {
            // A broken image is installed into each board's flash file (`cargo xtask board`):
            // no server command to export.
            board::Image::Release | board::Image::Broken(_) => {
                ("HANDWHEEL_BOARD_SERVER", Some(loader_elf()))
            }
            board::Image::StackOverflow => ("HANDWHEEL_BOARD_SERVER_STACK_OVERFLOW", None),
        };
        let argv = board::server_argv(
            &self.python,
            &workspace_root(),
            Some(&self.elf),
            loader.as_deref(),
            &self.defmt_print,
        );
        env::set_var(variable, board::shell_line(&argv));
    }
}

/// The boards of the suites' tests, built once and started without cargo ([`Board::export`]).
fn export_boards() -> Result<(), String> {
    Board::prepare()?.export();
    // The stack-overflow test runs this image.
    Board::prepare_image(board::Image::StackOverflow)?.export();
    Ok(())
}

/// The emulated board's own unit tests (register models, exception model; pytest).
pub fn board_unit_tests() -> Result<(), String> {
    let setup = Board::prepare()?;
    let sh = &root_shell()?;
    shell::run(board::unit_tests(sh, &setup.python, &setup.elf, &[]))
        .map_err(|e| format!("the emulated board's unit tests failed: {e}"))
}

/// The interop suite: the release image, the emulated board and defmt-print first (so that
/// the first test does not spend its start-up time building), the venv, then pytest with
/// `pytest_args`.
pub fn interop(pytest_args: &[String]) -> Result<(), String> {
    let started = Instant::now();
    export_boards()?;
    let root = workspace_root();
    let python = pyenv::ensure(&root, &pyenv::venv_dir(&target_dir()))?;
    let sh = &shell::at(&root)?;
    let result = shell::run(pyenv::pytest(sh, &python, pytest_args));
    eprintln!(
        "xtask: interop suite took {:.0} s",
        started.elapsed().as_secs_f64()
    );
    result.map_err(|e| format!("the interop suite failed: {e}"))
}

/// The README's and docs/' code blocks that need no hardware, run against the emulated board
/// ([`SNIPPETS_RUN`], pytest in the interop venv).
pub fn snippets_run() -> Result<(), String> {
    let started = Instant::now();
    export_boards()?;
    let root = workspace_root();
    let python = pyenv::ensure(&root, &pyenv::venv_dir(&target_dir()))?;
    let sh = &shell::at(&root)?;
    let result = shell::run(cmd!(sh, "{python} -m pytest {SNIPPETS_RUN} -q"));
    eprintln!(
        "xtask: the documents' snippets took {:.0} s",
        started.elapsed().as_secs_f64()
    );
    result.map_err(|e| {
        format!(
            "a snippet of the README or docs/ failed: {e}\n(tools/snippets/snippets.py says \
             how the blocks are marked and run)"
        )
    })
}

/// `cargo xtask feed-check`: the feed contract's exhaustive bounded check, optimised with
/// overflow checks (the `harness` profile; a few million states), then the vectors for the component's rule, whose path the host tests
/// that follow read from `HANDWHEEL_FEED_VECTORS`.
pub fn feed_check(only: &[String]) -> Result<(), String> {
    let vectors = target_dir().join("feed-check").join("vectors.jsonl");
    std::fs::create_dir_all(vectors.parent().unwrap_or(&target_dir()))
        .map_err(|e| format!("cannot create {}: {e}", vectors.display()))?;
    let sh = &root_shell()?;
    cargo(cmd!(
        sh,
        "cargo run --locked --profile harness -q -p feed-check -- --vectors {vectors} {only...}"
    ))?;
    env::set_var("HANDWHEEL_FEED_VECTORS", &vectors);
    Ok(())
}

/// The host component's unit and property tests (`host/tests`) in `target/host-venv`, made
/// from the pinned `host/requirements.txt`.
pub fn host_tests(pytest_args: &[String]) -> Result<(), String> {
    let root = workspace_root();
    let python = pyenv::ensure_from(
        &root.join(pyenv::HOST_REQUIREMENTS),
        &target_dir().join("host-venv"),
    )?;
    let sh = &shell::at(&root.join(pyenv::HOST_PACKAGE))?;
    shell::run(pyenv::host_pytest(sh, &python, pytest_args))
        .map_err(|e| format!("the component's unit tests failed: {e}"))
}

/// The LinuxCNC suite (`tests/linuxcnc`): the emulated board and the component in the real
/// LinuxCNC 2.9, set up by [`linuxcnc::prepare`].
pub fn linuxcnc_suite(pytest_args: &[String]) -> Result<(), String> {
    let setup = linuxcnc::prepare(&workspace_root(), &target_dir())?;
    linuxcnc_suite_with(&setup, pytest_args)
}

/// [`linuxcnc_suite`] with LinuxCNC and the component set up already.
pub fn linuxcnc_suite_with(setup: &linuxcnc::Setup, pytest_args: &[String]) -> Result<(), String> {
    let started = Instant::now();
    Board::prepare()?.export();
    let root = workspace_root();
    let sh = &shell::at(&root)?;
    let (python, suite) = (&setup.python, linuxcnc::SUITE);
    let pytest = cmd!(sh, "{python} -m pytest {suite} {pytest_args...}");
    let result = shell::run(setup.apply(pytest));
    eprintln!(
        "xtask: LinuxCNC suite took {:.0} s",
        started.elapsed().as_secs_f64()
    );
    result.map_err(|e| format!("the LinuxCNC suite failed: {e}"))
}
