//! The emulated board: `qemu-system-arm -M stm32vldiscovery` with the CAN link (SLCAN) on
//! USART1 and the stimulus line on USART2, both bridged to TCP, and the defmt log decoded
//! from semihosting.
//!
//! Facts checked with Debian's QEMU 7.2 (`qemu-system-arm` 7.2.22):
//! - The `n`-th `-serial` is `serial_hd(n)`, which the STM32F100 SoC wires to its `n`-th
//!   USART: the first is USART1 (0x4001_3800), the second USART2 (0x4000_4400).
//! - `server=on,wait=on` makes QEMU block *before starting the CPU* until a client connects;
//!   the chardevs are opened in order, so while QEMU waits on the first port the second one
//!   is not even listening. With `wait=on` on both, a harness that connects the stimulus
//!   port before the CAN port gets "connection refused" until it gives up (or deadlocks if it
//!   waits for the second before opening the first). Hence `wait=on` for CAN only (the
//!   firmware must not run before the master listens) and `wait=off` for the stimulus port,
//!   which listens as soon as the CAN client is in.
//! - A probe connection counts as "the client": a harness must not test the CAN port with a
//!   throw-away connect, but retry its real connection while it is refused.
//! - QEMU's STM32 USART model drops received bytes while the USART is not enabled (CR1 UE
//!   and RE): the first bytes a client sends right after connecting (python-can's `O\r`)
//!   can be lost because the firmware has not enabled USART1 yet. So the firmware's SLCAN
//!   channel powers up open (`sim_io::slcan::SlcanPort::new_open`) and no client re-sends
//!   `O`.
//! - `-nographic` alone puts QEMU's monitor on stdio: its banner (`QEMU 7.2.22 monitor -
//!   type 'help' ...`, `(qemu)`) would be mixed into the defmt stream on stdout.
//!   `-monitor none` keeps stdout for semihosting only.
//! - Semihosting with `target=native` writes the guest's `:tt` output to QEMU's stdout;
//!   `defmt-print -e <elf>` reads it from stdin and prints the decoded log on its stdout.
//!   `cortex_m_semihosting::debug::exit` ends QEMU with the given code.
//! - Without `nodelay=on` every small reply stalls about 40 ms (Nagle); with it a SLCAN
//!   request / reply round trip takes a few milliseconds.

use std::ffi::OsString;
use std::io;
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use xshell::{cmd, Shell};

use crate::host;

/// The Debian package with `qemu-system-arm`.
pub const QEMU_PACKAGE: &str = "qemu-system-arm";
/// The emulator binary.
pub const QEMU_BINARY: &str = "qemu-system-arm";
/// The emulated board: STM32F100RB (Cortex-M3), 128 KiB flash, 8 KiB RAM.
pub const MACHINE: &str = "stm32vldiscovery";

/// The `defmt-print` release this project uses (supports defmt wire formats 3 and 4, i.e.
/// defmt 0.3 and 1.x).
pub const DEFMT_PRINT_VERSION: &str = "1.2.0";

/// The TCP ports of the two serial bridges.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Ports {
    /// USART1, SLCAN: QEMU waits for this client before it starts the CPU.
    pub can: u16,
    /// USART2, stimulus commands: QEMU does not wait for it.
    pub stim: u16,
}

impl Ports {
    /// From `--can-port <P> --stim-port <Q>` (either order; `--x=P` accepted too).
    pub fn from_args(args: &[String]) -> Result<Self, String> {
        let mut can = None;
        let mut stim = None;
        let mut it = args.iter();
        while let Some(arg) = it.next() {
            let (flag, inline) = match arg.split_once('=') {
                Some((f, v)) => (f, Some(v.to_string())),
                None => (arg.as_str(), None),
            };
            let slot = match flag {
                "--can-port" => &mut can,
                "--stim-port" => &mut stim,
                other => return Err(format!("unknown argument `{other}`")),
            };
            let value = inline
                .or_else(|| it.next().cloned())
                .ok_or_else(|| format!("{flag} needs a port number"))?;
            let port: u16 = value
                .parse()
                .ok()
                .filter(|&p| p != 0)
                .ok_or_else(|| format!("{flag}: `{value}` is not a TCP port"))?;
            *slot = Some(port);
        }
        match (can, stim) {
            (Some(can), Some(stim)) if can != stim => Ok(Self { can, stim }),
            (Some(_), Some(_)) => Err("--can-port and --stim-port must differ".into()),
            _ => Err("usage: cargo xtask qemu --can-port <P> --stim-port <Q>".into()),
        }
    }
}

/// `qemu-system-arm` on `PATH`; as root, installed with apt-get when missing; otherwise an
/// error that names the Debian package.
pub fn find_or_install() -> Result<PathBuf, String> {
    host::require(QEMU_BINARY, &[QEMU_PACKAGE])
}

/// The arguments that run `elf` on the emulated board with both serial bridges on
/// 127.0.0.1.
pub fn args(elf: &Path, ports: Ports) -> Vec<OsString> {
    let serial =
        |port: u16, wait: &str| format!("tcp:127.0.0.1:{port},server=on,wait={wait},nodelay=on");
    let mut args: Vec<OsString> = [
        "-M",
        MACHINE,
        "-nographic",
        "-monitor",
        "none",
        "-semihosting-config",
        "enable=on,target=native",
    ]
    .iter()
    .map(OsString::from)
    .collect();
    // Order matters: the first -serial is USART1, the second USART2.
    for s in [serial(ports.can, "on"), serial(ports.stim, "off")] {
        args.push("-serial".into());
        args.push(s.into());
    }
    args.push("-kernel".into());
    args.push(elf.into());
    args
}

/// The QEMU command for `elf`; stdin is closed (nothing reads it with `-monitor none`).
pub fn command(qemu: &Path, elf: &Path, ports: Ports) -> Command {
    let mut cmd = Command::new(qemu);
    cmd.args(args(elf, ports)).stdin(Stdio::null());
    cmd
}

/// Where project tools are installed (`cargo install --root`), below the target directory.
pub fn tools_root(target_dir: &Path) -> PathBuf {
    target_dir.join("tools")
}

/// `defmt-print` [`DEFMT_PRINT_VERSION`] in `<tools_root>/bin`, installed with
/// `cargo install --locked` on first use and reused afterwards.
pub fn defmt_print(tools_root: &Path) -> Result<PathBuf, String> {
    let bin = tools_root.join("bin").join("defmt-print");
    let wanted = format!("defmt-print {DEFMT_PRINT_VERSION}");
    let installed = Command::new(&bin)
        .arg("--version")
        .output()
        .map(|o| String::from_utf8_lossy(&o.stdout).lines().next() == Some(wanted.as_str()))
        .unwrap_or(false);
    if installed {
        return Ok(bin);
    }
    cargo_install(Some(tools_root), "defmt-print", DEFMT_PRINT_VERSION)
}

/// `cargo install <name> --locked --version =<version>`, with `--root <root>` if given (else
/// into cargo's own `bin` folder, [`crate::linker::cargo_bin_dir`]); returns the installed
/// binary, which must exist afterwards. The one way xtask installs a tool. The install runs
/// with that `bin` folder on its `PATH`: xtask calls the tool by its path (or puts the folder
/// on its builds' `PATH`), so cargo's advice to add the folder to `PATH` would mislead.
pub fn cargo_install(root: Option<&Path>, name: &str, version: &str) -> Result<PathBuf, String> {
    let bin_dir = match root {
        Some(root) => root.join("bin"),
        None => crate::linker::cargo_bin_dir()
            .ok_or("cannot tell cargo's bin folder: neither CARGO_HOME nor HOME is set")?,
    };
    let bin = bin_dir.join(name);
    let version = format!("={version}");
    let sh = &Shell::new().map_err(|e| format!("cannot start a shell: {e}"))?;
    let root_option = root.map(|root| [Path::new("--root"), root]);
    let root_option = root_option.iter().flatten();
    let command = cmd!(
        sh,
        "cargo install {name} --locked --version {version} {root_option...}"
    )
    .env("PATH", crate::linker::path_with(&bin_dir));
    eprintln!(
        "xtask: cargo install {name} --locked --version {version}{} (once; it builds from \
         source, a few minutes)",
        root.map(|r| format!(" --root {}", r.display()))
            .unwrap_or_default()
    );
    command
        .quiet()
        .run()
        .map_err(|e| format!("installing {name} failed: {e}"))?;
    if bin.is_file() {
        Ok(bin)
    } else {
        Err(format!(
            "{name} not found at {} after install",
            bin.display()
        ))
    }
}

/// Becomes `qemu` (from [`command`]): starts `defmt-print -e <elf>` writing the decoded log
/// to this process's stderr, then replaces this process with QEMU, its stdout (the
/// semihosting defmt stream) piped into `defmt-print`. QEMU's own messages go to stderr.
///
/// Replacing rather than waiting for a child keeps the process that the caller started the
/// emulator itself (`cargo xtask` execs the task runner too): killing it (SIGTERM, SIGINT,
/// SIGKILL) ends QEMU and no orphan keeps the TCP ports. `defmt-print` then reads the end of
/// its input, prints what is left and exits. Returns only if QEMU could not be started.
pub fn exec_with_log(mut qemu: Command, defmt_print: &Path, elf: &Path) -> String {
    eprintln!(
        "xtask: {qemu:?} | {} -e {}",
        defmt_print.display(),
        elf.display()
    );
    let decoder = Command::new(defmt_print)
        .arg("-e")
        .arg(elf)
        .stdin(Stdio::piped())
        .stdout(Stdio::from(io::stderr()))
        .spawn();
    let mut decoder = match decoder {
        Ok(child) => child,
        Err(e) => return format!("cannot start {}: {e}", defmt_print.display()),
    };
    let Some(stream) = decoder.stdin.take() else {
        let _ = decoder.kill();
        return "defmt-print's stdin was not captured".into();
    };
    let error = qemu.stdout(Stdio::from(stream)).exec();
    let _ = decoder.kill();
    let _ = decoder.wait();
    format!("cannot start QEMU: {error}")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn strings(v: &[&str]) -> Vec<String> {
        v.iter().map(|s| s.to_string()).collect()
    }

    #[test]
    fn command_line_has_both_bridges_in_usart_order() {
        let args: Vec<String> = args(
            Path::new("/fw.elf"),
            Ports {
                can: 5001,
                stim: 5002,
            },
        )
        .into_iter()
        .map(|a| a.into_string().unwrap())
        .collect();
        assert_eq!(
            args.join(" "),
            "-M stm32vldiscovery -nographic -monitor none \
             -semihosting-config enable=on,target=native \
             -serial tcp:127.0.0.1:5001,server=on,wait=on,nodelay=on \
             -serial tcp:127.0.0.1:5002,server=on,wait=off,nodelay=on \
             -kernel /fw.elf"
        );
    }

    #[test]
    fn ports_from_args() {
        let want = Ports { can: 1, stim: 2 };
        assert_eq!(
            Ports::from_args(&strings(&["--can-port", "1", "--stim-port", "2"])),
            Ok(want)
        );
        assert_eq!(
            Ports::from_args(&strings(&["--stim-port=2", "--can-port=1"])),
            Ok(want)
        );
        for bad in [
            &["--can-port", "1"][..],
            &["--can-port", "1", "--stim-port", "1"],
            &["--can-port", "x", "--stim-port", "2"],
            &["--can-port", "0", "--stim-port", "2"],
            &["--can-port", "70000", "--stim-port", "2"],
            &["--can-port", "1", "--stim-port"],
            &["--can-port", "1", "--stim-port", "2", "--bogus"],
        ] {
            assert!(Ports::from_args(&strings(bad)).is_err(), "{bad:?}");
        }
    }
}
