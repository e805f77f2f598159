//! The emulated board (`tools/board-emu`): the release ELFs, the exact images a builder
//! flashes (the resident loader and the application, docs/FIRMWARE-UPDATE.md), on the
//! Python model of the STM32F103 in `tools/stm32emu` (unicorn for the core; NVIC, bxCAN,
//! FPEC over the whole flash, IWDG, GPIO/EXTI modelled), paced in real time, with SLCAN and
//! a control line on TCP.
//!
//! `cargo xtask board --can-port P --stim-port Q [--flash FILE] [--dip N] [--image NAME]
//! [--loader auto|none|FILE]` runs it in the foreground: SLCAN on P (the CPU starts when the
//! first client connects), the control line on Q, the firmware's RTT defmt stream decoded by
//! `defmt-print` on stderr (the server runs the decoder and starts it anew at every reset
//! and with the other image's ELF when the CPU goes from loader to application, so that a
//! log frame cut off by a power cut never stops the log). The board is flashed as a probe
//! flashes: the loader's and the application's pages erased and written, the rest of the
//! flash (an application an update wrote, the parameter pages) as `--flash` FILE holds it
//! across runs (default: `target/board-emu/flash.bin`; the whole 64 KiB flash). The CPU
//! boots the loader, which starts the application. `--loader auto` (the default) builds
//! and flashes the loader (`loader/`) when the image is
//! the release image; `none` runs the application alone, as before the loader (it starts
//! as the loader would start it); FILE flashes that loader ELF. `--image stack-overflow`
//! runs the test build that overflows its stack on purpose (feature `stack-overflow-test`)
//! instead of the release image, alone unless `--loader FILE`. `--image hang|fault|lockup|
//! silent|wrong-bit-rate` boots the loader with a broken application in the slot: the
//! release update file changed by `tools/rig/bad_images.py` (header, vector table and CRC
//! genuine; docs/FIRMWARE-UPDATE.md, "Trial boot"), installed into the flash file, which the
//! board then boots without flashing an application of its own.

use std::ffi::OsString;
use std::path::{Path, PathBuf};

use xshell::{cmd, Cmd, Shell};

use crate::pyenv;

/// The server and launcher, relative to the workspace root.
pub const PACKAGE: &str = "tools/board-emu";
/// The chip model it runs (its unit tests run with the board's).
pub const CHIP: &str = "tools/stm32emu";
/// The image header's seal at link time (`tools/seal/linker`); its unit tests run with the
/// board's, as the board boots what it seals.
pub const SEAL: &str = "tools/seal";

/// The usage line of `cargo xtask board`.
const USAGE: &str = "usage: cargo xtask board --can-port <P> --stim-port <Q> [--flash FILE] \
                     [--dip N] [--image release|stack-overflow|hang|fault|lockup|silent|\
                     wrong-bit-rate] [--loader auto|none|FILE]";

/// The broken applications of `tools/rig/bad_images.py`, by the name it takes.
pub const BROKEN: [&str; 5] = ["hang", "fault", "lockup", "silent", "wrong-bit-rate"];

/// The script that makes them from the release update file.
pub const BAD_IMAGES: &str = "tools/rig/bad_images.py";

/// The board's two TCP ports.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Ports {
    /// SLCAN: the board starts its CPU once this client is in.
    pub can: u16,
    /// The control line (wheel, switches, power, bus faults): listening at once.
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
            _ => Err(USAGE.into()),
        }
    }
}

/// Which firmware image the board runs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Image {
    /// The release image, the one that ships.
    #[default]
    Release,
    /// The release profile with feature `stack-overflow-test`: it overflows its stack on
    /// purpose right after boot.
    StackOverflow,
    /// The release image broken as [`BROKEN`] names it, installed behind the loader.
    Broken(&'static str),
}

impl Image {
    fn parse(name: &str) -> Result<Self, String> {
        match name {
            "release" => Ok(Self::Release),
            "stack-overflow" => Ok(Self::StackOverflow),
            other => BROKEN
                .iter()
                .find(|&&kind| kind == other)
                .map(|&kind| Self::Broken(kind))
                .ok_or_else(|| {
                    format!(
                        "--image: `{other}` is not `release`, `stack-overflow` or one of {}",
                        BROKEN.join(", ")
                    )
                }),
        }
    }
}

/// Which resident loader the board boots.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub enum Loader {
    /// The workspace's loader, built, with the release image (when `loader/` exists).
    #[default]
    Auto,
    /// None: the application alone, started as the loader would start it.
    Off,
    /// This loader ELF.
    File(PathBuf),
}

impl Loader {
    fn parse(value: &str) -> Result<Self, String> {
        match value {
            "auto" => Ok(Self::Auto),
            "none" => Ok(Self::Off),
            "" => Err("--loader: give auto, none or an ELF file".into()),
            file => Ok(Self::File(PathBuf::from(file))),
        }
    }
}

/// `cargo xtask board` arguments: the two ports, and the board's own options.
#[derive(Debug, PartialEq, Eq)]
pub struct Args {
    pub ports: Ports,
    pub flash: Option<PathBuf>,
    pub dip: Option<u8>,
    pub image: Image,
    pub loader: Loader,
}

impl Args {
    pub fn from_args(args: &[String]) -> Result<Self, String> {
        let mut rest = Vec::new();
        let mut flash = None;
        let mut dip = None;
        let mut image = Image::Release;
        let mut loader = Loader::Auto;
        let mut it = args.iter();
        while let Some(arg) = it.next() {
            let (flag, inline) = match arg.split_once('=') {
                Some((f, v)) => (f, Some(v.to_string())),
                None => (arg.as_str(), None),
            };
            match flag {
                "--flash" | "--dip" | "--image" | "--loader" => {
                    let value = inline
                        .or_else(|| it.next().cloned())
                        .ok_or_else(|| format!("{flag} needs a value"))?;
                    match flag {
                        "--flash" => flash = Some(PathBuf::from(value)),
                        "--image" => image = Image::parse(&value)?,
                        "--loader" => loader = Loader::parse(&value)?,
                        _ => dip = Some(parse_dip(&value)?),
                    }
                }
                _ => rest.push(arg.clone()),
            }
        }
        let ports = Ports::from_args(&rest)?;
        Ok(Self {
            ports,
            flash,
            dip,
            image,
            loader,
        })
    }
}

/// The loader ELF the board boots for `args`, None for the application alone: `auto` builds
/// the workspace's loader for the release image when the workspace has it (the
/// stack-overflow image runs alone: it is a test of the application's stack, not of the
/// boot).
pub fn loader_elf(args: &Args) -> Result<Option<PathBuf>, String> {
    match &args.loader {
        Loader::Off => Ok(None),
        Loader::File(path) => Ok(Some(path.clone())),
        Loader::Auto => {
            if args.image == Image::StackOverflow {
                return Ok(None);
            }
            crate::fw::loader_build()?;
            Ok(Some(crate::fw::loader_elf()))
        }
    }
}

/// The DIP switch as `--dip` takes it: binary `0b01100101` (switch n on = bit n-1, so the
/// digits read switches 8..1), hexadecimal `0x65` or decimal `101`.
pub fn parse_dip(value: &str) -> Result<u8, String> {
    let lower = value.to_ascii_lowercase();
    let parsed = if let Some(bits) = lower.strip_prefix("0b") {
        u8::from_str_radix(&bits.replace('_', ""), 2)
    } else if let Some(hex) = lower.strip_prefix("0x") {
        u8::from_str_radix(hex, 16)
    } else {
        lower.parse()
    };
    parsed.map_err(|_| {
        format!(
            "--dip: `{value}` is not 0b00000000..0b11111111 (switches 8..1), 0x00..0xFF or 0..255"
        )
    })
}

/// The chip model venv's interpreter, made if needed.
pub fn python(root: &Path, target_dir: &Path) -> Result<PathBuf, String> {
    pyenv::emu_python(root, target_dir)
}

/// The emulator's command line for the application `elf` (None: the slot as the flash file
/// holds it) and the `loader` (None: the application alone), its log decoded by
/// `defmt_print`, up to the board's own options (ports, flash file, DIP switch).
pub fn server_argv(
    python: &Path,
    root: &Path,
    elf: Option<&Path>,
    loader: Option<&Path>,
    defmt_print: &Path,
) -> Vec<OsString> {
    let mut argv: Vec<OsString> = vec![python.into(), root.join(PACKAGE).join("server.py").into()];
    if let Some(loader) = loader {
        argv.extend(["--loader".into(), loader.into()]);
    }
    if let Some(elf) = elf {
        argv.extend(["--elf".into(), elf.into()]);
    }
    argv.extend(["--defmt-print".into(), defmt_print.into()]);
    argv
}

/// [`server_argv`] with the board's own options from `args`.
pub fn command<'a>(
    sh: &'a Shell,
    server: &[OsString],
    args: &Args,
    default_flash: &Path,
) -> Cmd<'a> {
    let (can, stim) = (args.ports.can.to_string(), args.ports.stim.to_string());
    let flash = args.flash.as_deref().unwrap_or(default_flash);
    let dip = args.dip.map(|dip| ["--dip".to_string(), dip.to_string()]);
    let dip = dip.iter().flatten();
    let (program, server) = server
        .split_first()
        .expect("the server's command has a program");
    cmd!(
        sh,
        "{program} {server...} --can-port {can} --stim-port {stim} --flash {flash} {dip...}"
    )
}

/// `argv` as one line that a POSIX shell, and Python's `shlex.split`, read back into the
/// same words: each word in single quotes, a quote inside as `'\''`.
pub fn shell_line(argv: &[OsString]) -> String {
    let words: Vec<String> = argv
        .iter()
        .map(|word| format!("'{}'", word.to_string_lossy().replace('\'', r"'\''")))
        .collect();
    words.join(" ")
}

/// The chip model's, the board's and the seal's unit tests (`tools/stm32emu/test_*.py`,
/// `tools/board-emu/test_*.py`, `tools/seal/test_*.py`, pytest) with extra arguments, in a
/// shell in the workspace root; the tests of loader and application together find the loader
/// beside `elf` (they are skipped while it is not built).
pub fn unit_tests<'a>(sh: &'a Shell, python: &Path, elf: &Path, extra: &[&str]) -> Cmd<'a> {
    cmd!(
        sh,
        "{python} -m pytest {CHIP} {PACKAGE} {SEAL} -q {extra...}"
    )
    .env("HANDWHEEL_BOARD_ELF", elf)
    .env("HANDWHEEL_LOADER_ELF", crate::fw::loader_elf())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn strings(v: &[&str]) -> Vec<String> {
        v.iter().map(|s| s.to_string()).collect()
    }

    #[test]
    fn args_take_ports_and_board_options() {
        let args = Args::from_args(&strings(&[
            "--can-port",
            "1",
            "--dip=33",
            "--stim-port",
            "2",
            "--flash",
            "f.bin",
        ]))
        .unwrap();
        assert_eq!(args.ports, Ports { can: 1, stim: 2 });
        assert_eq!(args.flash, Some(PathBuf::from("f.bin")));
        assert_eq!(args.dip, Some(33));
        assert_eq!(args.image, Image::Release);
        assert_eq!(args.loader, Loader::Auto);
        for (written, loader) in [
            ("none", Loader::Off),
            ("auto", Loader::Auto),
            ("l.elf", Loader::File(PathBuf::from("l.elf"))),
        ] {
            let args = Args::from_args(&strings(&[
                "--can-port",
                "1",
                "--stim-port",
                "2",
                &format!("--loader={written}"),
            ]))
            .unwrap();
            assert_eq!(args.loader, loader, "{written}");
        }
        assert!(Args::from_args(&strings(&[
            "--can-port",
            "1",
            "--stim-port",
            "2",
            "--loader"
        ]))
        .is_err());
        let overflow = Args::from_args(&strings(&[
            "--can-port",
            "1",
            "--stim-port",
            "2",
            "--image=stack-overflow",
        ]))
        .unwrap();
        assert_eq!(overflow.image, Image::StackOverflow);
        for kind in BROKEN {
            let broken = Args::from_args(&strings(&[
                "--can-port",
                "1",
                "--stim-port",
                "2",
                &format!("--image={kind}"),
            ]))
            .unwrap();
            assert_eq!(broken.image, Image::Broken(kind));
        }
        assert!(Args::from_args(&strings(&[
            "--can-port",
            "1",
            "--stim-port",
            "2",
            "--image",
            "debug"
        ]))
        .unwrap_err()
        .contains("debug"));
        assert!(Args::from_args(&strings(&[
            "--can-port",
            "1",
            "--stim-port",
            "2",
            "--dip",
            "256"
        ]))
        .is_err());
        assert!(Args::from_args(&strings(&[
            "--can-port",
            "1",
            "--stim-port",
            "2",
            "--flash"
        ]))
        .is_err());
        for (written, value) in [("0b01100101", 0x65), ("0B1000_0001", 0x81), ("0x65", 0x65)] {
            assert_eq!(parse_dip(written), Ok(value), "{written}");
        }
        assert_eq!(parse_dip("101"), Ok(101));
        for bad in ["0b100000000", "0b102", "0x100", "256", "-1", ""] {
            assert!(parse_dip(bad).is_err(), "{bad}");
        }
        let usage = Args::from_args(&strings(&["--can-port", "1"])).unwrap_err();
        assert!(usage.contains("cargo xtask board"), "{usage}");
    }

    #[test]
    fn a_shell_line_keeps_every_word() {
        let argv: Vec<OsString> = ["/a b/python", "it's", "", "--elf"]
            .iter()
            .map(OsString::from)
            .collect();
        assert_eq!(shell_line(&argv), r"'/a b/python' 'it'\''s' '' '--elf'");
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
