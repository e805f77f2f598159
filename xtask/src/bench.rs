//! `cargo xtask bench`: the feed protocol comparison, the release machine code's CPU cost and
//! stack in the emulator, the footprint, and detent to motion in LinuxCNC.

use xshell::cmd;

use crate::fw::{firmware_elf, footprint_check, release_build};
use crate::suites::Board;
use crate::workspace::{cargo, root_shell, target_dir, workspace_root};
use crate::{linuxcnc, machine_bench, pyenv, shell};

/// The five benchmarks: 1. the feed protocol simulation (paper vs this project,
/// with its plot), 2. the CPU cost of the release machine code in the emulator, 3. the
/// release footprint by section and the worst-case stack, with their headroom, 4. detent to
/// motion in LinuxCNC and the run-on after a fast spin ([`linuxcnc_bench`]), 5. the update
/// over CAN at two bit rates ([`update_bench`]).
pub fn bench() -> Result<(), String> {
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
    linuxcnc_bench()?;
    eprintln!("xtask: ## 5. Update over CAN");
    update_bench()
}

/// `tests/interop/bench_update.py` (not part of the suite): the update over CAN of the
/// release image through the loader on the emulated board at 1 Mbit/s and 125 kbit/s.
pub fn update_bench() -> Result<(), String> {
    Board::prepare()?;
    let root = workspace_root();
    let python = pyenv::ensure(&root, &pyenv::venv_dir(&target_dir()))?;
    let sh = &shell::at(&root)?;
    shell::run(cmd!(
        sh,
        "{python} -m pytest -q -s -p no:cacheprovider {UPDATE_BENCH}"
    ))
    .map_err(|e| format!("the update benchmark failed: {e}"))
}

/// The update benchmark's script.
const UPDATE_BENCH: &str = "tests/interop/bench_update.py";

/// `tests/linuxcnc/bench_motion.py` (not part of the suite) with the emulated board, its
/// figures on stdout.
pub fn linuxcnc_bench() -> Result<(), String> {
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
pub fn machine_bench(quiet: bool) -> Result<machine_bench::MachineReport, String> {
    machine_bench::run(
        &workspace_root(),
        &target_dir(),
        &firmware_elf("release"),
        quiet,
    )
}

/// Prints the worst-case stack with its headroom; fails above [`STACK_BUDGET`].
/// The stack budget and the wheel edge's limits, from the machine benchmark's report.
pub fn stack_check(report: &machine_bench::MachineReport) -> Result<(), String> {
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
