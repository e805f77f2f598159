//! Flash and static RAM use of a firmware image, read from its ELF section headers.
//!
//! Flash holds every allocated section placed in flash (vector table, code, read-only data)
//! plus the load image of initialised RAM (`.data`). Static RAM is every allocated section
//! placed in RAM: `.data`, `.bss` and `.uninit` (where the defmt RTT buffer lives). The stack
//! is not counted: it takes whatever RAM is left.
//!
//! The README states both figures, rounded to 0.1 KiB as the report prints them;
//! [`check_readme`] holds that statement to the image (`cargo xtask fw` and `cargo xtask test`
//! run it after the budget check), as `eds.rs`'s test holds the README's object table to the
//! object rows.

use std::fmt::Write as _;
use std::path::Path;

use crate::elf;

/// Where the STM32F103C8's memories sit (see `memory.x`): an image's flash is whatever it puts
/// there (the application's header slot and image, or the loader).
const FLASH: std::ops::Range<u32> = 0x0800_0000..0x0801_0000;
const RAM: std::ops::Range<u32> = 0x2000_0000..0x2000_5000;

/// Limits an image must stay within.
#[derive(Clone, Copy, Debug)]
pub struct Budget {
    /// Flash bytes.
    pub flash: u32,
    /// Static RAM bytes.
    pub ram: u32,
}

/// What an image uses.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Footprint {
    sections: Vec<(String, u32, u32)>,
    /// Flash bytes.
    pub flash: u32,
    /// Static RAM bytes.
    pub ram: u32,
}

/// Reads `elf` and checks it against `budget`: prints the table, and an error names every
/// limit that is exceeded.
pub fn check(elf: &Path, label: &str, budget: Budget) -> Result<Footprint, String> {
    let bytes = std::fs::read(elf).map_err(|e| format!("cannot read {}: {e}", elf.display()))?;
    let footprint = measure(&bytes).map_err(|e| format!("{}: {e}", elf.display()))?;
    eprint!("{}", report(&footprint, label, budget));
    let mut over = Vec::new();
    if footprint.flash > budget.flash {
        over.push(format!("flash {} B > {} B", footprint.flash, budget.flash));
    }
    if footprint.ram > budget.ram {
        over.push(format!("static RAM {} B > {} B", footprint.ram, budget.ram));
    }
    if over.is_empty() {
        Ok(footprint)
    } else {
        Err(format!("{label} is over budget: {}", over.join(", ")))
    }
}

fn report(footprint: &Footprint, label: &str, budget: Budget) -> String {
    let mut out = format!("xtask: footprint of the {label}\n");
    for (name, flash, ram) in &footprint.sections {
        let _ = writeln!(out, "  {name:<16} flash {flash:>6} B   RAM {ram:>6} B");
    }
    for (what, used, limit) in [
        ("flash", footprint.flash, budget.flash),
        ("static RAM", footprint.ram, budget.ram),
    ] {
        let _ = writeln!(
            out,
            "  {what:<10} {used:>6} B of {limit:>6} B ({} of {} KiB), headroom {} B",
            kib(used),
            kib(limit),
            i64::from(limit) - i64::from(used),
        );
    }
    out
}

/// Bytes in KiB with one decimal, as the report prints them and the README states them.
fn kib(bytes: u32) -> String {
    format!("{:.1}", f64::from(bytes) / 1024.0)
}

/// What precedes the footprint in the README ("Build the firmware"): "`cargo xtask fw` prints:
/// 31.7 KiB of flash and 2.6 KiB of static RAM", line breaks anywhere.
const README_STATEMENT: &str = "`cargo xtask fw` prints:";

/// The flash and static RAM figures (KiB, one decimal) the README states once, after
/// [`README_STATEMENT`].
fn stated(readme: &str) -> Result<(String, String), String> {
    let text = readme.split_whitespace().collect::<Vec<_>>().join(" ");
    let mut found = text.match_indices(README_STATEMENT);
    let Some((at, _)) = found.next() else {
        return Err(format!(
            "README.md does not state the footprint (\"{README_STATEMENT}\")"
        ));
    };
    if found.next().is_some() {
        return Err(format!(
            "README.md states the footprint twice (\"{README_STATEMENT}\")"
        ));
    }
    let rest = &text[at + README_STATEMENT.len()..];
    let words: Vec<&str> = rest.split(' ').filter(|w| !w.is_empty()).take(10).collect();
    let one_decimal = |figure: &str| {
        figure.split_once('.').is_some_and(|(whole, tenth)| {
            !whole.is_empty()
                && tenth.len() == 1
                && whole
                    .bytes()
                    .chain(tenth.bytes())
                    .all(|b| b.is_ascii_digit())
        })
    };
    match words[..] {
        [flash, "KiB", "of", "flash", "and", ram, "KiB", "of", "static", last]
            if last.starts_with("RAM") && one_decimal(flash) && one_decimal(ram) =>
        {
            Ok((flash.to_owned(), ram.to_owned()))
        }
        _ => Err(format!(
            "README.md's footprint after \"{README_STATEMENT}\" is not \"F KiB of flash and R KiB \
             of static RAM\" (one decimal each): `{}`",
            words.join(" ")
        )),
    }
}

/// Fails unless the README states `footprint` as the report rounds it.
pub fn check_readme(readme: &str, footprint: &Footprint) -> Result<(), String> {
    let (flash, ram) = stated(readme)?;
    let (image_flash, image_ram) = (kib(footprint.flash), kib(footprint.ram));
    if flash == image_flash && ram == image_ram {
        eprintln!(
            "xtask: README.md states this footprint ({flash} KiB flash, {ram} KiB static RAM)"
        );
        Ok(())
    } else {
        Err(format!(
            "README.md (\"Build the firmware\") states {flash} KiB of flash and {ram} KiB of \
             static RAM, the image has {image_flash} KiB ({} B) and {image_ram} KiB ({} B): write \
             the image's figures there (and record the change in docs/CHANGELOG.md)",
            footprint.flash, footprint.ram
        ))
    }
}

/// Sums the allocated sections of an ELF32 little-endian image by where they live.
pub fn measure(image: &[u8]) -> Result<Footprint, String> {
    let mut footprint = Footprint::default();
    for section in elf::allocated_sections(image)? {
        let in_flash = FLASH.contains(&section.addr);
        let in_ram = RAM.contains(&section.addr);
        let flash = if in_flash || (in_ram && !section.nobits) {
            section.size
        } else {
            0
        };
        let ram = if in_ram { section.size } else { 0 };
        if flash == 0 && ram == 0 {
            continue;
        }
        footprint.flash += flash;
        footprint.ram += ram;
        footprint.sections.push((section.name, flash, ram));
    }
    Ok(footprint)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::elf::build::{elf, PROGBITS, SHF_ALLOC, SHT_NOBITS};

    #[test]
    fn sums_flash_and_ram_by_address() {
        let image = elf(
            &[],
            &[
                (".vector_table", PROGBITS, SHF_ALLOC, 0x0800_0000, 304),
                (".text", PROGBITS, SHF_ALLOC | 0x4, 0x0800_0130, 10_000),
                (".rodata", PROGBITS, SHF_ALLOC, 0x0800_2840, 2_000),
                (".data", PROGBITS, SHF_ALLOC | 0x1, 0x2000_0000, 56),
                (".bss", SHT_NOBITS, SHF_ALLOC | 0x1, 0x2000_0038, 500),
                (".uninit", SHT_NOBITS, SHF_ALLOC | 0x1, 0x2000_022C, 1_300),
                (".defmt", PROGBITS, 0, 0, 40),
                (".debug_info", PROGBITS, 0, 0, 99_999),
            ],
        );
        let footprint = measure(&image).unwrap();
        assert_eq!(footprint.flash, 304 + 10_000 + 2_000 + 56);
        assert_eq!(footprint.ram, 56 + 500 + 1_300);
        assert_eq!(footprint.sections.len(), 6);
    }

    #[test]
    fn report_shows_headroom() {
        let footprint = Footprint {
            sections: vec![(".text".into(), 1000, 0)],
            flash: 1000,
            ram: 0,
        };
        let text = report(
            &footprint,
            "test",
            Budget {
                flash: 2048,
                ram: 1024,
            },
        );
        assert!(text.contains("headroom 1048 B"), "{text}");
        assert!(text.contains("headroom 1024 B"), "{text}");
        assert!(text.contains("(1.0 of 2.0 KiB)"), "{text}");
    }

    fn footprint(flash: u32, ram: u32) -> Footprint {
        Footprint {
            sections: Vec::new(),
            flash,
            ram,
        }
    }

    /// The README states the footprint once, in the form the check reads, within the budget
    /// (the check against the image itself runs after the release build).
    #[test]
    fn the_readme_states_the_footprint() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
        let readme = std::fs::read_to_string(root.join("README.md")).unwrap();
        let (flash, ram) = stated(&readme).unwrap();
        let flash: f64 = flash.parse().unwrap();
        let ram: f64 = ram.parse().unwrap();
        assert!(flash > 0.0 && flash <= 40.0, "{flash} KiB of flash");
        assert!(ram > 0.0 && ram <= 4.0, "{ram} KiB of static RAM");
    }

    #[test]
    fn the_readme_check_holds_both_figures_to_the_image() {
        let readme = "What goes into flash is what `cargo xtask fw` prints: 31.7 KiB of flash\n\
                      and 2.6 KiB of static RAM today.";
        assert_eq!(check_readme(readme, &footprint(32_496, 2_612)), Ok(()));
        // The same rounding, other bytes.
        assert_eq!(check_readme(readme, &footprint(32_420, 2_680)), Ok(()));
        // 31.8 KiB of flash; 2.7 KiB of RAM.
        let flash = check_readme(readme, &footprint(32_600, 2_612)).unwrap_err();
        assert!(
            flash.contains("the image has 31.8 KiB (32600 B)"),
            "{flash}"
        );
        let ram = check_readme(readme, &footprint(32_496, 2_800)).unwrap_err();
        assert!(ram.contains("and 2.7 KiB (2800 B)"), "{ram}");
    }

    #[test]
    fn the_readme_check_wants_one_statement_in_its_form() {
        let image = footprint(32_496, 2_612);
        let once = "`cargo xtask fw` prints: 31.7 KiB of flash and 2.6 KiB of static RAM.";
        assert!(check_readme("no figures", &image).is_err());
        assert!(check_readme(&format!("{once} {once}"), &image).is_err());
        for wrong in [
            "`cargo xtask fw` prints: about 32 KiB of flash and 2.6 KiB of static RAM.",
            "`cargo xtask fw` prints: 32 KiB of flash and 2.6 KiB of static RAM.",
            "`cargo xtask fw` prints: 31.7 KiB of flash and 2.6 KiB of RAM.",
            "`cargo xtask fw` prints: 31.70 KiB of flash and 2.6 KiB of static RAM.",
        ] {
            assert!(check_readme(wrong, &image).is_err(), "{wrong}");
        }
    }
}
