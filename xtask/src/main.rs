//! Project tasks, run as `cargo xtask <task>` (an alias in `.cargo/config.toml`).
//!
//! `cargo xtask test` is the one test command of `docs/TESTING.md` and of `.ci/run`: everything a
//! change must pass, in the order that fails fastest, ending with the interop and LinuxCNC
//! suites (python-canopen and LinuxCNC against the release image on the emulated board).

mod board;
mod eds;
mod footprint;
mod host;
mod linker;
mod linuxcnc;
mod machine_bench;
mod pyenv;
mod shell;
mod wiring;

use std::env;
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Command, ExitCode};
use std::time::Instant;

use xshell::{cmd, Cmd, Shell};

const FIRMWARE_TARGET: &str = "thumbv7m-none-eabi";
/// Crates that must also build without `std` for the MCU.
const NO_STD_CRATES: &[&str] = &["handwheel-core", "canopen-slave", "handwheel-device"];
/// The cargo-fuzz package (its own workspace: `cargo fuzz run` needs nightly).
const FUZZ_MANIFEST: &str = "crates/canopen-slave/fuzz/Cargo.toml";
/// Random frame sequences `cargo xtask test` runs through the fuzz target's body.
const RANDOM_SEQUENCES: &str = "1000000";
/// The check that runs the README's and docs/' code blocks against the emulated board (their
/// marks, and the blocks checked against files: `tools/snippets/test_marks.py`, with the
/// documents' checks).
const SNIPPETS_RUN: &str = "tools/snippets/test_run.py";
/// The demo's master, run with the interop venv's Python.
const DEMO_SCRIPT: &str = "tools/demo.py";

const USAGE: &str = "usage: cargo xtask <task>

tasks:
  test                                  everything CI checks, the interop suite last
  fw                                    release firmware for the board, with its footprint checked
                                        against the budget and the README's statement of it
  board --can-port <P> --stim-port <Q>  the release image on the emulated board (tools/board-emu):
        [--flash FILE] [--dip N]        SLCAN on tcp:127.0.0.1:P (the CPU starts with the client),
        [--image release|stack-overflow] control line on tcp:127.0.0.1:Q, decoded defmt log on
                                        stderr; FILE keeps the parameter page (default
                                        target/board-emu/flash.bin); N: the DIP switch in
                                        binary, switches 8..1 (0b01100101: 1, 3, 6, 7 on; 0x65
                                        and 101 too); stack-overflow: the test build that
                                        overflows its stack right after boot
  snippets                              run the README's and docs/' code blocks that need no
                                        hardware against the emulated board (tools/snippets)
  lint                                  ruff check and ruff format --check over all Python
  interop [pytest args]                 only the interop suite (venv, emulated board, pytest)
  host [pytest args]                    only the LinuxCNC component's unit and property tests
  feed-check [setting names]            the feed contract's exhaustive check (crates/feed-check):
                                        the real device code against the host's rule; writes
                                        the vectors `host` replays through core.py
  linuxcnc [--script]                   LinuxCNC's sim XYZ mill with the emulated handwheel in
                                        the terminal: DRO, machine state, wheel from the keyboard
  linuxcnc-test [pytest args]           only the LinuxCNC suite (component in LinuxCNC 2.9, the
                                        emulated board)
  demo [--script]                       the handwheel on the emulated board with a live
                                        python-canopen master
  docs [--check]                        re-render docs/wiring/handwheel.svg from handwheel.yml
                                        (WireViz, Graphviz), then check it against the pin
                                        map, every relative link in the Markdown files and
                                        the marks of the README's and docs/' code blocks;
                                        --check: only the checks (no Graphviz)
  eds [--check]                         write eds/handwheel.eds from the object table, then check
                                        it with dcfchk (CiA 306); --check: fail if the committed
                                        file differs, and check it
  bench [linuxcnc]                      1. feed protocol comparison (writes docs/feed-protocols.svg),
                                        2. CPU cost of the wheel edge and SDO path on the release
                                        machine code (emulated), 3. footprint by section and
                                        worst-case stack, with their headroom, 4. detent to
                                        motion in LinuxCNC 2.9 (emulated board) and the run-on
                                        after a fast spin (`linuxcnc`: only that)";

fn main() -> ExitCode {
    let args: Vec<String> = env::args().skip(1).collect();
    let rest = args.get(1..).unwrap_or_default();
    let result = match args.first().map(String::as_str) {
        Some("test") => test(),
        Some("fw") => firmware_build(),
        Some("board") => board::Args::from_args(rest).and_then(run_board),
        Some("lint") => python_lint(),
        Some("snippets") => snippets_run(),
        Some("interop") => interop(rest),
        Some("host") => host_tests(rest),
        Some("feed-check") => feed_check(rest),
        Some("linuxcnc") => linuxcnc_console(rest),
        Some("linuxcnc-test") => linuxcnc_suite(rest),
        Some("demo") => demo(rest),
        Some("bench") => match rest {
            [] => bench(),
            [part] if part == "linuxcnc" => linuxcnc_bench(),
            _ => Err("usage: cargo xtask bench [linuxcnc]".into()),
        },
        Some("docs") => docs(rest),
        Some("eds") => eds::run(&workspace_root(), &target_dir(), rest),
        _ => {
            eprintln!("{USAGE}");
            return ExitCode::from(2);
        }
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(message) => {
            eprintln!("xtask: {message}");
            ExitCode::FAILURE
        }
    }
}

fn test() -> Result<(), String> {
    let started = Instant::now();
    let sh = &root_shell()?;
    cargo(cmd!(sh, "cargo fmt --all -- --check"))?;
    cargo(cmd!(
        sh,
        "cargo fmt --manifest-path {FUZZ_MANIFEST} -- --check"
    ))?;
    python_lint()?;
    cargo(cmd!(sh, "cargo test --locked"))?;
    feed_check(&[])?;
    random_frames()?;
    host_tests(&[])?;
    wiring_check()?;
    eds::run(&workspace_root(), &target_dir(), &["--check".into()])?;
    cargo(cmd!(
        sh,
        "cargo clippy --locked --all-targets -- -D warnings"
    ))?;
    for krate in NO_STD_CRATES {
        cargo(cmd!(
            sh,
            "cargo build --locked --release -p {krate} --target {FIRMWARE_TARGET}"
        ))?;
    }
    // The firmware, its library and its on-target tests, for the MCU.
    cargo(cmd!(
        sh,
        "cargo clippy --locked -p handwheel-firmware --target {FIRMWARE_TARGET} --all-targets
         -- -D warnings"
    ))?;
    firmware_build()?;
    one_build_check()?;
    // The release machine code in the emulator: CPU figures in one line, the stack and the
    // wheel edge's cycles and latency checked.
    stack_check(&machine_bench(true)?)?;
    board_unit_tests()?;
    // The on-target suites (defmt-test) cannot run here, but they must build.
    board_cargo(cmd!(
        sh,
        "cargo build --locked --release --tests -p handwheel-firmware --target {FIRMWARE_TARGET}"
    ))?;
    // The dev profile must fit the part too (the linker checks memory.x; this prints it).
    board_cargo(cmd!(
        sh,
        "cargo build --locked -p handwheel-firmware --target {FIRMWARE_TARGET}"
    ))?;
    footprint::check(
        &firmware_elf("debug"),
        "dev firmware",
        footprint::Budget {
            flash: 62 * 1024,
            ram: 20 * 1024,
        },
    )?;
    eprintln!(
        "xtask: build checks passed in {:.0} s; now the documents' snippets and the interop \
         suite",
        started.elapsed().as_secs_f64()
    );
    snippets_run()?;
    interop(&[])?;
    linuxcnc_suite(&[])?;
    eprintln!(
        "xtask: all checks passed in {:.0} s",
        started.elapsed().as_secs_f64()
    );
    Ok(())
}

/// The engine's fuzz target on the pinned stable toolchain: the target must build (without
/// coverage instrumentation, which needs nightly), and its body, `canopen_harness::frames`,
/// runs a million seeded random frame sequences (the `harness` profile: optimised, with
/// debug assertions and overflow checks).
fn random_frames() -> Result<(), String> {
    let sh = &root_shell()?;
    let fuzz_dir = target_dir().join("fuzz");
    cargo(cmd!(
        sh,
        "cargo build --locked --manifest-path {FUZZ_MANIFEST} --target-dir {fuzz_dir}"
    ))?;
    cargo(cmd!(
        sh,
        "cargo run --locked --profile harness -p canopen-harness -- --sequences {RANDOM_SEQUENCES}"
    ))
}

/// The four benchmarks: 1. the feed protocol simulation (paper vs this project,
/// with its plot), 2. the CPU cost of the release machine code in the emulator, 3. the
/// release footprint by section and the worst-case stack, with their headroom, 4. detent to
/// motion in LinuxCNC and the run-on after a fast spin ([`linuxcnc_bench`]).
fn bench() -> Result<(), String> {
    eprintln!("xtask: ## 1. Feed protocol");
    let sh = &root_shell()?;
    cargo(cmd!(
        sh,
        "cargo run --locked --release -q -p feed-bench -- docs/feed-protocols.svg"
    ))?;
    eprintln!("xtask: ## 2. CPU cost");
    release_build()?;
    let stack = machine_bench(false)?;
    eprintln!("xtask: ## 3. Footprint and stack");
    footprint_check()?;
    stack_check(&stack)?;
    eprintln!("xtask: ## 4. Detent to motion in LinuxCNC");
    linuxcnc_bench()
}

/// `tests/linuxcnc/bench_motion.py` (not part of the suite) with the emulated board, its
/// figures on stdout.
fn linuxcnc_bench() -> Result<(), String> {
    Board::prepare()?;
    let root = workspace_root();
    let setup = linuxcnc::prepare(&root, &target_dir())?;
    let sh = &shell::at(&root)?;
    let (python, bench) = (&setup.python, linuxcnc::BENCH);
    let pytest = cmd!(sh, "{python} -m pytest -q -s {bench}");
    shell::run(setup.apply(pytest)).map_err(|e| format!("the LinuxCNC benchmark failed: {e}"))
}

/// Runs the machine benchmark on the release ELF (built already): the full CPU report, or
/// with `quiet` a one-line summary. Returns the stack figures.
fn machine_bench(quiet: bool) -> Result<machine_bench::MachineReport, String> {
    machine_bench::run(
        &workspace_root(),
        &target_dir(),
        &firmware_elf("release"),
        quiet,
    )
}

/// Prints the worst-case stack with its headroom; fails above [`STACK_BUDGET`].
/// The stack budget and the wheel edge's limits, from the machine benchmark's report.
fn stack_check(report: &machine_bench::MachineReport) -> Result<(), String> {
    eprint!("{}", report.render(STACK_BUDGET));
    eprint!("{}", report.render_edge());
    report.check(STACK_BUDGET)?;
    report.check_edge()
}

/// Worst-case stack budget of the release firmware, checked by the machine benchmark (thread
/// mode plus every preemption level's deepest handler and exception frame; the measured
/// figures are in docs/PERFORMANCE.md). The room left covers paths the benchmark's scenarios
/// do not take. With the 4 KiB static RAM budget it keeps the
/// image within 8 KiB of the 20 KiB part.
const STACK_BUDGET: u32 = 4 * 1024;

/// Release footprint budget: 32 KiB flash (what the services need, the image's history in
/// docs/CHANGELOG.md), 4 KiB static RAM (RTT included). CI fails above it.
const RELEASE_BUDGET: footprint::Budget = footprint::Budget {
    flash: 32 * 1024,
    ram: 4 * 1024,
};

/// Builds the release firmware and fails if it is over its footprint budget or the README's
/// statement of its footprint is not the image's.
fn firmware_build() -> Result<(), String> {
    release_build()?;
    let footprint = footprint_check()?;
    let readme = std::fs::read_to_string(workspace_root().join("README.md"))
        .map_err(|e| format!("cannot read README.md: {e}"))?;
    footprint::check_readme(&readme, &footprint)
}

/// `cargo fw`, the README's build, right after xtask's: it must compile nothing, since both
/// build the same configuration into the same target directory (`linker.rs`).
fn one_build_check() -> Result<(), String> {
    eprintln!("xtask: cargo fw (the README's build: must compile nothing now)");
    let sh = &root_shell()?;
    let command = cmd!(sh, "cargo fw")
        .ignore_status()
        .env("PATH", linker::flip_link()?.path);
    let output = command
        .output()
        .map_err(|e| format!("cannot run cargo fw: {e}"))?;
    let log = String::from_utf8_lossy(&output.stderr);
    eprint!("{log}");
    if !output.status.success() {
        return Err(format!("`cargo fw` failed ({})", output.status));
    }
    let compiled: Vec<&str> = log
        .lines()
        .filter(|l| l.trim_start().starts_with("Compiling"))
        .collect();
    if compiled.is_empty() {
        Ok(())
    } else {
        Err(format!(
            "`cargo fw` after `cargo xtask fw` compiled {} crate(s): the two builds differ \
             (linker, flags or environment; xtask/src/linker.rs)",
            compiled.len()
        ))
    }
}

/// Builds the release firmware.
fn release_build() -> Result<(), String> {
    let sh = &root_shell()?;
    board_cargo(cmd!(
        sh,
        "cargo build --locked --release -p handwheel-firmware --target {FIRMWARE_TARGET}"
    ))
}

/// Prints the release firmware's footprint and fails if it is over its budget; returns it.
fn footprint_check() -> Result<footprint::Footprint, String> {
    footprint::check(&firmware_elf("release"), "release firmware", RELEASE_BUDGET)
}

/// Everything the emulated board needs: the image, its venv, `defmt-print`.
struct Board {
    python: PathBuf,
    defmt_print: PathBuf,
    elf: PathBuf,
}

impl Board {
    /// The release image's board.
    fn prepare() -> Result<Self, String> {
        Self::prepare_image(board::Image::Release)
    }

    fn prepare_image(image: board::Image) -> Result<Self, String> {
        let elf = match image {
            board::Image::Release => {
                release_build()?;
                firmware_elf("release")
            }
            board::Image::StackOverflow => overflow_build()?,
        };
        let python = board::python(&workspace_root(), &target_dir())?;
        let defmt_print = host::defmt_print(&host::tools_root(&target_dir()))?;
        Ok(Self {
            python,
            defmt_print,
            elf,
        })
    }
}

/// Builds the stack-overflow test image (release profile, feature `stack-overflow-test`, its
/// own target directory, linked like the release image); returns its ELF.
fn overflow_build() -> Result<PathBuf, String> {
    let dir = target_dir().join("stack-overflow");
    let sh = &root_shell()?;
    board_cargo(cmd!(
        sh,
        "cargo build --locked --release -p handwheel-firmware --target {FIRMWARE_TARGET}
         --features stack-overflow-test --target-dir {dir}"
    ))?;
    Ok(dir
        .join(FIRMWARE_TARGET)
        .join("release")
        .join("handwheel-firmware"))
}

/// `cargo xtask board --can-port P --stim-port Q`: the release image (or `--image`) on the
/// emulated board in the foreground, its decoded defmt log on stderr. This process becomes
/// the emulator.
fn run_board(args: board::Args) -> Result<(), String> {
    let setup = Board::prepare_image(args.image)?;
    let default_flash = target_dir().join("board-emu").join("flash.bin");
    if let Some(dir) = default_flash.parent() {
        std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    }
    let root = workspace_root();
    let sh = &shell::at(&root)?;
    let server = board::command(
        sh,
        &setup.python,
        &root,
        &setup.elf,
        &args,
        &default_flash,
        &setup.defmt_print,
    );
    eprintln!("xtask: {server}");
    // The server runs defmt-print itself (restarting it at every reset). It replaces this
    // process, which xshell (waiting for its commands) does not do.
    let error = Command::from(server)
        .stdin(std::process::Stdio::null())
        .exec();
    Err(format!("cannot start the board: {error}"))
}

/// The emulated board's own unit tests (register models, exception model; pytest).
fn board_unit_tests() -> Result<(), String> {
    let setup = Board::prepare()?;
    let sh = &root_shell()?;
    shell::run(board::unit_tests(sh, &setup.python, &setup.elf, &[]))
        .map_err(|e| format!("the emulated board's unit tests failed: {e}"))
}

/// The interop suite: the release image, the emulated board and defmt-print first (so that
/// the first test does not spend its start-up time building), the venv, then pytest with
/// `pytest_args`.
fn interop(pytest_args: &[String]) -> Result<(), String> {
    let started = Instant::now();
    Board::prepare()?;
    // The stack-overflow test runs this image.
    overflow_build()?;
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
fn snippets_run() -> Result<(), String> {
    let started = Instant::now();
    Board::prepare()?;
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

/// `ruff check` and `ruff format --check` over all of the project's Python (tests/, tools/,
/// host/; rules in ruff.toml), with the ruff pinned in `tools/lint/requirements.txt`, in its
/// own venv (`target/lint-venv`).
fn python_lint() -> Result<(), String> {
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

/// The host component's unit and property tests (`host/tests`) in `target/host-venv`, made
/// from the pinned `host/requirements.txt`.
/// `cargo xtask feed-check`: the feed contract's exhaustive bounded check, in release mode (a
/// few million states), then the vectors for the component's rule, whose path the host tests
/// that follow read from `HANDWHEEL_FEED_VECTORS`.
fn feed_check(only: &[String]) -> Result<(), String> {
    let vectors = target_dir().join("feed-check").join("vectors.jsonl");
    std::fs::create_dir_all(vectors.parent().unwrap_or(&target_dir()))
        .map_err(|e| format!("cannot create {}: {e}", vectors.display()))?;
    let sh = &root_shell()?;
    cargo(cmd!(
        sh,
        "cargo run --locked --release -q -p feed-check -- --vectors {vectors} {only...}"
    ))?;
    env::set_var("HANDWHEEL_FEED_VECTORS", &vectors);
    Ok(())
}

fn host_tests(pytest_args: &[String]) -> Result<(), String> {
    let root = workspace_root();
    let python = pyenv::ensure_from(
        &root.join(pyenv::HOST_REQUIREMENTS),
        &target_dir().join("host-venv"),
    )?;
    let sh = &shell::at(&root.join(pyenv::HOST_PACKAGE))?;
    shell::run(pyenv::host_pytest(sh, &python, pytest_args))
        .map_err(|e| format!("the component's unit tests failed: {e}"))
}

/// `cargo xtask docs [--check]`: re-renders the wiring diagram (unless `--check`), then
/// checks it against the firmware's and the README's pin maps, and the Markdown files' links.
fn docs(args: &[String]) -> Result<(), String> {
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
/// YAML's board pins against `src/board/pins.rs` and the README, and the SVG's stamp; every
/// relative link in the Markdown files (`tools/doclinks/test_doclinks.py`); and the marks of
/// the documents' code blocks with the checks that need no emulator
/// (`tools/snippets/test_marks.py`); and the no_std crates' import graph
/// (`tools/modgraph`).
fn wiring_check() -> Result<(), String> {
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

/// The LinuxCNC suite (`tests/linuxcnc`): the emulated board and the component in the real
/// LinuxCNC 2.9, set up by [`linuxcnc::prepare`].
fn linuxcnc_suite(pytest_args: &[String]) -> Result<(), String> {
    let started = Instant::now();
    Board::prepare()?;
    let root = workspace_root();
    let setup = linuxcnc::prepare(&root, &target_dir())?;
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

/// `cargo xtask linuxcnc [--script]`: prepares, then becomes the console
/// (`host/linuxcnc/console.py`), which starts the emulated board and LinuxCNC itself.
fn linuxcnc_console(args: &[String]) -> Result<(), String> {
    Board::prepare()?;
    let root = workspace_root();
    let setup = linuxcnc::prepare(&root, &target_dir())?;
    let sh = &shell::at(&root)?;
    let (python, console) = (&setup.python, root.join(linuxcnc::CONSOLE));
    let console = cmd!(sh, "{python} {console} {args...}")
        .env("HANDWHEEL_LOG_DIR", target_dir().join("linuxcnc"));
    let console = setup.apply(console);
    eprintln!("xtask: {console}");
    // xshell waits for its commands; this one replaces the process (the console owns the
    // terminal).
    let error = Command::from(console).exec();
    Err(format!("cannot run {}: {error}", setup.python.display()))
}

/// `cargo xtask demo [--script]`: prepares everything, then becomes the demo's master
/// (`tools/demo.py` with the interop venv's Python), which starts `cargo xtask board` itself.
fn demo(args: &[String]) -> Result<(), String> {
    Board::prepare()?;
    // The log goes beside the board's other files.
    let log_dir = target_dir().join("board-emu");
    std::fs::create_dir_all(&log_dir).map_err(|e| format!("{}: {e}", log_dir.display()))?;
    let root = workspace_root();
    let python = pyenv::ensure(&root, &pyenv::venv_dir(&target_dir()))?;
    let sh = &shell::at(&root)?;
    let script = root.join(DEMO_SCRIPT);
    let demo =
        cmd!(sh, "{python} {script} {args...}").env("HANDWHEEL_DEMO_LOG", log_dir.join("demo.log"));
    eprintln!("xtask: {demo}");
    // Replaces this process, so that Ctrl-C reaches the demo alone and it cleans up.
    let error = Command::from(demo).exec();
    Err(format!("cannot run {}: {error}", python.display()))
}

/// The target directory (`CARGO_TARGET_DIR` or `<root>/target`).
fn target_dir() -> PathBuf {
    env::var_os("CARGO_TARGET_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| workspace_root().join("target"))
}

/// The firmware ELF of a profile directory (`release` or `debug`).
fn firmware_elf(profile: &str) -> PathBuf {
    target_dir()
        .join(FIRMWARE_TARGET)
        .join(profile)
        .join("handwheel-firmware")
}

/// A shell in the workspace root, where the cargo commands run.
fn root_shell() -> Result<Shell, String> {
    shell::at(&workspace_root())
}

/// Runs a cargo command (from [`root_shell`]), echoing it.
fn cargo(command: Cmd<'_>) -> Result<(), String> {
    shell::run(command)
}

/// Runs cargo for a firmware image: linked by the configuration's flip-link, as `cargo fw`
/// links (installed on first use; see `linker.rs`).
fn board_cargo(command: Cmd<'_>) -> Result<(), String> {
    shell::run(command.env("PATH", linker::flip_link()?.path))
}

fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("xtask lives one level below the workspace root")
        .to_path_buf()
}
