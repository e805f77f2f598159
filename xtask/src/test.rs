//! `cargo xtask test`: the one test command of `docs/TESTING.md` and of `.ci/run`, everything
//! a change must pass in the order that fails fastest.

use std::time::Instant;

use xshell::cmd;

use crate::bench::{machine_bench, stack_check};
use crate::docs::wiring_check;
use crate::fw::{
    board_cargo, firmware_build, firmware_elf, one_build_check, FIRMWARE_TARGET, LOADER_MANIFEST,
};
use crate::lint::python_lint;
use crate::suites::{board_unit_tests, feed_check, host_tests, interop, linuxcnc_suite_with};
use crate::workspace::{cargo, root_shell, target_dir, workspace_root};
use crate::{contract, dbc, eds, footprint, linuxcnc};

/// Crates that must also build without `std` for the MCU.
const NO_STD_CRATES: &[&str] = &[
    "handwheel-core",
    "handwheel-board",
    "handwheel-storage",
    "canopen-slave",
    "handwheel-device",
    "canopen-loader",
];
/// The cargo-fuzz package (its own workspace: `cargo fuzz run` needs nightly).
const FUZZ_MANIFEST: &str = "crates/canopen-slave/fuzz/Cargo.toml";
/// Random frame sequences `cargo xtask test` runs through the fuzz target's body.
const RANDOM_SEQUENCES: &str = "1000000";

pub fn test() -> Result<(), String> {
    let started = Instant::now();
    let sh = &root_shell()?;
    cargo(cmd!(sh, "cargo fmt --all -- --check"))?;
    cargo(cmd!(
        sh,
        "cargo fmt --manifest-path {FUZZ_MANIFEST} -- --check"
    ))?;
    cargo(cmd!(
        sh,
        "cargo fmt --manifest-path {LOADER_MANIFEST} -- --check"
    ))?;
    python_lint()?;
    cargo(cmd!(sh, "cargo test --locked"))?;
    feed_check(&[])?;
    random_frames()?;
    host_tests(&[])?;
    wiring_check()?;
    eds::run(&workspace_root(), &target_dir(), &["--check".into()])?;
    dbc::run(&workspace_root(), &["--check".into()])?;
    contract::run(&workspace_root(), &["--check".into()])?;
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
    // The resident loader (a workspace of its own), for the MCU; `firmware_build` builds it.
    let target = target_dir();
    board_cargo(cmd!(
        sh,
        "cargo clippy --locked --manifest-path {LOADER_MANIFEST} --target {FIRMWARE_TARGET}
         --target-dir {target} -- -D warnings"
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
    // The dev profile must fit the application's slot too (the linker checks memory.x;
    // this prints it): 50 KiB with the header, the RAM below HANDOFF.
    board_cargo(cmd!(
        sh,
        "cargo build --locked -p handwheel-firmware --target {FIRMWARE_TARGET}"
    ))?;
    footprint::check(
        &firmware_elf("debug"),
        "dev firmware",
        footprint::Budget {
            flash: 50 * 1024,
            ram: 20 * 1024 - 8,
        },
    )?;
    eprintln!(
        "xtask: build checks passed in {:.0} s; now the interop suite, then the LinuxCNC \
         suite with the documents' snippets and the other masters beside it",
        started.elapsed().as_secs_f64()
    );
    // LinuxCNC's set-up (its venvs, the component's install) runs beside the interop suite:
    // pip waits mostly on files, the suite mostly on the board's clock.
    let linuxcnc_setup = std::thread::spawn(|| linuxcnc::prepare(&workspace_root(), &target_dir()));
    let interop_result = interop(&[]);
    let linuxcnc_setup = linuxcnc_setup
        .join()
        .map_err(|_| "the LinuxCNC set-up panicked".to_string())?;
    interop_result?;
    let linuxcnc_setup = linuxcnc_setup?;
    // Beside the LinuxCNC suite: the documents' snippets, and two masters written elsewhere,
    // each with its own habits, on the same release image.
    beside(
        || linuxcnc_suite_with(&linuxcnc_setup, &[]),
        &["snippets", "node-master", "go-master"],
    )?;
    eprintln!(
        "xtask: all checks passed in {:.0} s",
        started.elapsed().as_secs_f64()
    );
    Ok(())
}

/// Runs `suite` while this program runs the `tasks` one after the other in children whose
/// output goes to a file, shown once `suite` is over. The LinuxCNC suite waits mostly on its
/// machine's clock and leaves more than a core idle; the snippets and the other masters'
/// suites each need about half of one (docs/TESTING.md has the figures), so beside it they
/// cost no time of their own.
fn beside(
    suite: impl FnOnce() -> Result<(), String>,
    tasks: &'static [&'static str],
) -> Result<(), String> {
    let log_path = target_dir().join("beside-linuxcnc.log");
    let log = std::fs::File::create(&log_path)
        .map_err(|e| format!("cannot create {}: {e}", log_path.display()))?;
    let program = std::env::current_exe().map_err(|e| format!("where is xtask? {e}"))?;
    // Each runs, whatever the one before did: each failure is its own news.
    let children = std::thread::spawn(move || -> Result<(), String> {
        let mut failed = Vec::new();
        for task in tasks {
            let output = |log: &std::fs::File| {
                log.try_clone()
                    .map_err(|e| format!("cannot write the tasks' log: {e}"))
            };
            let status = std::process::Command::new(&program)
                .arg(task)
                .stdout(output(&log)?)
                .stderr(output(&log)?)
                .status()
                .map_err(|e| format!("cannot run `xtask {task}`: {e}"))?;
            if !status.success() {
                failed.push(format!("`xtask {task}` failed ({status})"));
            }
        }
        if failed.is_empty() {
            Ok(())
        } else {
            Err(failed.join("; "))
        }
    });
    let suite_result = suite();
    let children_result = children
        .join()
        .map_err(|_| "the thread of the tasks beside it panicked".to_string())?;
    eprintln!(
        "xtask: {} ran beside it; their output (also in {}):",
        tasks.join(", "),
        log_path.display()
    );
    print!("{}", std::fs::read_to_string(&log_path).unwrap_or_default());
    suite_result?;
    children_result
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
