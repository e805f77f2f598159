//! The tasks that hand the terminal over: the emulated board, the LinuxCNC console and the
//! demo each replace this process once prepared.

use std::os::unix::process::CommandExt;
use std::process::Command;

use xshell::cmd;

use crate::fw::update_file;
use crate::suites::Board;
use crate::workspace::{target_dir, workspace_root};
use crate::{board, linuxcnc, pyenv, shell};

/// The demo's master, run with the interop venv's Python.
const DEMO_SCRIPT: &str = "tools/demo.py";

/// `cargo xtask board --can-port P --stim-port Q`: the release image (or `--image`) on the
/// emulated board in the foreground, its decoded defmt log on stderr. This process becomes
/// the emulator.
pub fn run_board(args: board::Args) -> Result<(), String> {
    let setup = Board::prepare_image(args.image)?;
    let loader = board::loader_elf(&args)?;
    let default_flash = target_dir().join("board-emu").join("flash.bin");
    if let Some(dir) = default_flash.parent() {
        std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    }
    let root = workspace_root();
    let sh = &shell::at(&root)?;
    let elf = match args.image {
        board::Image::Broken(kind) => {
            // The broken image goes into the flash file's slot; the board boots what the
            // flash file holds there.
            let flash = args.flash.as_deref().unwrap_or(&default_flash);
            let (python, script, update) =
                (&setup.python, root.join(board::BAD_IMAGES), update_file());
            shell::run(cmd!(
                sh,
                "{python} {script} {kind} {update} --install {flash}"
            ))?;
            None
        }
        _ => Some(setup.elf.as_path()),
    };
    let argv = board::server_argv(
        &setup.python,
        &root,
        elf,
        loader.as_deref(),
        &setup.defmt_print,
    );
    let server = board::command(sh, &argv, &args, &default_flash);
    eprintln!("xtask: {server}");
    // The server runs defmt-print itself (restarting it at every reset). It replaces this
    // process, which xshell (waiting for its commands) does not do.
    let error = Command::from(server)
        .stdin(std::process::Stdio::null())
        .exec();
    Err(format!("cannot start the board: {error}"))
}

/// `cargo xtask linuxcnc [--script]`: prepares, then becomes the console
/// (`host/linuxcnc/console.py`), which starts the emulated board and LinuxCNC itself.
pub fn linuxcnc_console(args: &[String]) -> Result<(), String> {
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
pub fn demo(args: &[String]) -> Result<(), String> {
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
