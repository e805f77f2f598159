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

/// Where the STM32F103C8's memories sit (see `memory.x`): an image's flash is whatever it puts
/// there (the application's header slot and image, or the loader).
const FLASH: std::ops::Range<u32> = 0x0800_0000..0x0801_0000;
const RAM: std::ops::Range<u32> = 0x2000_0000..0x2000_5000;

const SHF_ALLOC: u32 = 0x2;
const SHT_NOBITS: u32 = 8;

/// Limits an image must stay within.
#[derive(Clone, Copy, Debug)]
pub struct Budget {
    /// Flash bytes.
    pub flash: u32,
    /// Static RAM bytes.
    pub ram: u32,
}

/// One allocated section.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Section {
    /// Its name.
    pub name: String,
    /// Its address.
    pub addr: u32,
    /// Its size in bytes.
    pub size: u32,
    /// No bytes in the file (`.bss`, `.uninit`).
    pub nobits: bool,
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
pub fn measure(elf: &[u8]) -> Result<Footprint, String> {
    let mut footprint = Footprint::default();
    for section in elf_sections(elf)? {
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

/// The allocated sections of an ELF32 little-endian image.
pub fn elf_sections(elf: &[u8]) -> Result<Vec<Section>, String> {
    if elf.get(..4) != Some(b"\x7fELF".as_slice()) {
        return Err("not an ELF file".into());
    }
    if elf.get(4) != Some(&1) || elf.get(5) != Some(&1) {
        return Err("not a 32-bit little-endian ELF".into());
    }
    let shoff = u32_at(elf, 0x20)? as usize;
    let shentsize = usize::from(u16_at(elf, 0x2E)?);
    let shnum = usize::from(u16_at(elf, 0x30)?);
    let shstrndx = usize::from(u16_at(elf, 0x32)?);
    if shentsize < 40 {
        return Err("section header entries too small".into());
    }
    let header = |i: usize| shoff + i * shentsize;
    let names_offset = u32_at(elf, header(shstrndx) + 16)? as usize;

    let mut out = Vec::new();
    for i in 0..shnum {
        let h = header(i);
        let flags = u32_at(elf, h + 8)?;
        if flags & SHF_ALLOC == 0 {
            continue;
        }
        let name_offset = names_offset + u32_at(elf, h)? as usize;
        let name = elf
            .get(name_offset..)
            .and_then(|rest| rest.split(|&b| b == 0).next())
            .map(|name| String::from_utf8_lossy(name).into_owned())
            .ok_or("section name out of bounds")?;
        out.push(Section {
            name,
            addr: u32_at(elf, h + 12)?,
            size: u32_at(elf, h + 20)?,
            nobits: u32_at(elf, h + 4)? == SHT_NOBITS,
        });
    }
    Ok(out)
}

pub fn u32_at(bytes: &[u8], at: usize) -> Result<u32, String> {
    bytes
        .get(at..at + 4)
        .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .ok_or_else(|| format!("truncated ELF (offset {at:#x})"))
}

pub fn u16_at(bytes: &[u8], at: usize) -> Result<u16, String> {
    bytes
        .get(at..at + 2)
        .map(|b| u16::from_le_bytes([b[0], b[1]]))
        .ok_or_else(|| format!("truncated ELF (offset {at:#x})"))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A minimal ELF32 LE image: a null section, the given sections, and the name table.
    fn elf(sections: &[(&str, u32, u32, u32, u32)]) -> Vec<u8> {
        // (name, type, flags, addr, size)
        let mut names = vec![0u8];
        let mut name_offsets = Vec::new();
        for (name, ..) in sections {
            name_offsets.push(names.len() as u32);
            names.extend_from_slice(name.as_bytes());
            names.push(0);
        }
        let shstrtab_name = names.len() as u32;
        names.extend_from_slice(b".shstrtab\0");

        let mut image = vec![0u8; 0x34];
        image[..4].copy_from_slice(b"\x7fELF");
        image[4] = 1;
        image[5] = 1;
        let names_at = image.len() as u32;
        image.extend_from_slice(&names);
        let shoff = image.len() as u32;
        let shnum = sections.len() as u16 + 2;
        image[0x20..0x24].copy_from_slice(&shoff.to_le_bytes());
        image[0x2E..0x30].copy_from_slice(&40u16.to_le_bytes());
        image[0x30..0x32].copy_from_slice(&shnum.to_le_bytes());
        image[0x32..0x34].copy_from_slice(&(shnum - 1).to_le_bytes());

        let mut push = |name: u32, kind: u32, flags: u32, addr: u32, offset: u32, size: u32| {
            let mut h = [0u8; 40];
            for (at, v) in [
                (0, name),
                (4, kind),
                (8, flags),
                (12, addr),
                (16, offset),
                (20, size),
            ] {
                h[at..at + 4].copy_from_slice(&v.to_le_bytes());
            }
            image.extend_from_slice(&h);
        };
        push(0, 0, 0, 0, 0, 0);
        for ((_, kind, flags, addr, size), name) in sections.iter().zip(&name_offsets) {
            push(*name, *kind, *flags, *addr, 0, *size);
        }
        push(shstrtab_name, 3, 0, 0, names_at, names.len() as u32);
        image
    }

    const PROGBITS: u32 = 1;

    #[test]
    fn sums_flash_and_ram_by_address() {
        let image = elf(&[
            (".vector_table", PROGBITS, SHF_ALLOC, 0x0800_0000, 304),
            (".text", PROGBITS, SHF_ALLOC | 0x4, 0x0800_0130, 10_000),
            (".rodata", PROGBITS, SHF_ALLOC, 0x0800_2840, 2_000),
            (".data", PROGBITS, SHF_ALLOC | 0x1, 0x2000_0000, 56),
            (".bss", SHT_NOBITS, SHF_ALLOC | 0x1, 0x2000_0038, 500),
            (".uninit", SHT_NOBITS, SHF_ALLOC | 0x1, 0x2000_022C, 1_300),
            (".defmt", PROGBITS, 0, 0, 40),
            (".debug_info", PROGBITS, 0, 0, 99_999),
        ]);
        let footprint = measure(&image).unwrap();
        assert_eq!(footprint.flash, 304 + 10_000 + 2_000 + 56);
        assert_eq!(footprint.ram, 56 + 500 + 1_300);
        assert_eq!(footprint.sections.len(), 6);
    }

    #[test]
    fn rejects_what_is_not_elf32_le() {
        assert!(measure(b"not an elf").is_err());
        let mut image = elf(&[]);
        image[4] = 2;
        assert!(measure(&image).is_err());
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
