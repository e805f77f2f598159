//! Project tasks, run as `cargo xtask <task>` (an alias in `.cargo/config.toml`).
//!
//! `cargo xtask test` is the one test command of `docs/TESTING.md` and of `.ci/run`: everything a
//! change must pass, in the order that fails fastest, ending with the interop and LinuxCNC
//! suites (python-canopen and LinuxCNC against the release image on the emulated board).
//!
//! This file is the dispatch and the usage; each task lives in the file named after what it
//! runs: `test.rs` (the whole sequence), `fw.rs` (firmware images), `suites.rs` (interop,
//! snippets, LinuxCNC, host, feed check), `bench.rs`, `docs.rs`, `lint.rs`, `eds.rs`, `dbc.rs`,
//! `contract.rs`, and `interactive.rs` (board, linuxcnc, demo: they take the terminal).

mod bench;
mod board;
mod contract;
mod dbc;
mod docs;
mod eds;
mod elf;
mod footprint;
mod fw;
mod go_master;
mod host;
mod interactive;
mod linker;
mod lint;
mod linuxcnc;
mod machine_bench;
mod node_master;
mod pyenv;
mod shell;
mod suites;
mod test;
mod update;
mod wiring;
mod workspace;

use std::env;
use std::process::ExitCode;

use bench::{bench, linuxcnc_bench, update_bench};
use docs::docs;
use fw::firmware_build;
use interactive::{demo, linuxcnc_console, run_board};
use lint::python_lint;
use suites::{feed_check, host_tests, interop, linuxcnc_suite, snippets_run};
use test::test;
use workspace::{target_dir, workspace_root};

const USAGE: &str = "usage: cargo xtask <task>

tasks:
  test                                  everything CI checks, the interop suite last
  fw                                    release firmware for the board: the application and the
                                        resident loader, their footprints checked against their
                                        budgets (and the README's statement of the
                                        application's), and the update file, its path printed
                                        on a line `update image: PATH`
  board --can-port <P> --stim-port <Q>  the loader and the release image on the emulated board
        [--flash FILE] [--dip N]        (tools/board-emu), flashed as a probe flashes them:
        [--image release|stack-overflow] SLCAN on tcp:127.0.0.1:P (the CPU starts with the
        [--loader auto|none|FILE]       client), control line on tcp:127.0.0.1:Q, decoded defmt
                                        log on stderr; FILE keeps the whole flash (default
                                        target/board-emu/flash.bin); N: the DIP switch in
                                        binary, switches 8..1 (0b01100101: 1, 3, 6, 7 on; 0x65
                                        and 101 too); stack-overflow: the test build that
                                        overflows its stack right after boot; hang, fault,
                                        lockup, silent, wrong-bit-rate: a broken application
                                        behind the loader (tools/rig/bad_images.py); --loader: auto
                                        (the workspace's loader/, if any), none (the
                                        application alone) or an ELF
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
  dbc [--check] | --node N              write eds/handwheel.dbc (the TPDOs as a CAN database for
                                        cantools, SavvyCAN, Wireshark) from the object table for
                                        the default node-ID; --check: fail if the committed file
                                        differs; --node N: print node N's to stdout
  contract [--check]                    write host/src/canopen_handwheel/update_contract.py (the
                                        update contract for Python: memory map, image header,
                                        hand-off words, the loader's identity and 0x1F57 codes)
                                        from crates/canopen-loader; --check: fail if the
                                        committed file differs
  bench [linuxcnc|update]               1. feed protocol comparison (writes docs/feed-protocols.svg),
                                        2. CPU cost of the wheel edge and SDO path on the release
                                        machine code (emulated), 3. footprint by section and
                                        worst-case stack, with their headroom, 4. detent to
                                        motion in LinuxCNC 2.9 (emulated board) and the run-on
                                        after a fast spin (`linuxcnc`: only that), 5. the update
                                        over CAN at 1 Mbit/s and 125 kbit/s (`update`: only that)
  go-master                             gocanopen (Go) as the master of the release image on
                                        the emulated board (tests/go-master; needs Go 1.22+)
  node-master                           node-canopen (npm canopen) as the master of the release
                                        image on the emulated board (tests/node-master; needs
                                        Node.js 20.15+ and npm)";

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
            [part] if part == "update" => update_bench(),
            _ => Err("usage: cargo xtask bench [linuxcnc|update]".into()),
        },
        Some("docs") => docs(rest),
        Some("eds") => eds::run(&workspace_root(), &target_dir(), rest),
        Some("dbc") => dbc::run(&workspace_root(), rest),
        Some("contract") => contract::run(&workspace_root(), rest),
        Some("go-master") => go_master::run(),
        Some("node-master") => node_master::run(),
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
