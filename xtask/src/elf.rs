//! xtask's one ELF reader, for the 32-bit little-endian images of the board: the allocated
//! sections (their sizes make the footprint, [`crate::footprint`]; `.image_header` is the
//! header slot, [`crate::update`]) and the loadable segments (their bytes at their load
//! addresses are what a probe programs, the update file's bytes).
//!
//! The seal (`tools/seal/seal.py`) reads the same two tables at link time in Python: it runs
//! inside the link step of `cargo fw` and `cargo embed`, which never build xtask, so it
//! cannot use this one; [`crate::update`] checks what it wrote.

/// `e_ident`'s class and data bytes of ELF32 little-endian.
const ELF32_LE: [u8; 2] = [1, 1];
/// `sh_flags`: the section takes memory in the running image.
pub const SHF_ALLOC: u32 = 0x2;
/// `sh_type` of a section without bytes in the file.
pub const SHT_NOBITS: u32 = 8;
const PT_LOAD: u32 = 1;

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

/// One loadable segment with bytes in the file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Segment<'a> {
    /// Where its bytes are loaded (the physical address: flash for `.data`'s initial values).
    pub paddr: u32,
    /// Its bytes in the file.
    pub data: &'a [u8],
}

fn check_ident(elf: &[u8]) -> Result<(), String> {
    if elf.get(..4) != Some(b"\x7fELF".as_slice()) {
        return Err("not an ELF file".into());
    }
    if elf.get(4..6) != Some(ELF32_LE.as_slice()) {
        return Err("not a 32-bit little-endian ELF".into());
    }
    Ok(())
}

/// The allocated sections of an ELF32 little-endian image.
pub fn allocated_sections(elf: &[u8]) -> Result<Vec<Section>, String> {
    check_ident(elf)?;
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

/// The loadable segments of an ELF32 little-endian image that have bytes in the file.
pub fn loaded_segments(elf: &[u8]) -> Result<Vec<Segment<'_>>, String> {
    check_ident(elf)?;
    let phoff = u32_at(elf, 0x1C)? as usize;
    let phentsize = usize::from(u16_at(elf, 0x2A)?);
    let phnum = usize::from(u16_at(elf, 0x2C)?);
    let mut out = Vec::new();
    for i in 0..phnum {
        let h = phoff + i * phentsize;
        let (kind, offset, paddr, filesz) = (
            u32_at(elf, h)?,
            u32_at(elf, h + 4)? as usize,
            u32_at(elf, h + 12)?,
            u32_at(elf, h + 16)? as usize,
        );
        if kind != PT_LOAD || filesz == 0 {
            continue;
        }
        let data = elf
            .get(offset..offset + filesz)
            .ok_or_else(|| format!("truncated ELF (segment at {paddr:#x})"))?;
        out.push(Segment { paddr, data });
    }
    Ok(out)
}

/// The little-endian word at `at`.
pub fn u32_at(bytes: &[u8], at: usize) -> Result<u32, String> {
    bytes
        .get(at..at + 4)
        .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .ok_or_else(|| format!("truncated ELF (offset {at:#x})"))
}

/// The little-endian half-word at `at`.
pub fn u16_at(bytes: &[u8], at: usize) -> Result<u16, String> {
    bytes
        .get(at..at + 2)
        .map(|b| u16::from_le_bytes([b[0], b[1]]))
        .ok_or_else(|| format!("truncated ELF (offset {at:#x})"))
}

/// ELF files made by hand for the readers' tests.
#[cfg(test)]
pub mod build {
    pub use super::{SHF_ALLOC, SHT_NOBITS};

    /// `sh_type` of a section with bytes.
    pub const PROGBITS: u32 = 1;
    /// `sh_type` of the section names.
    const SHT_STRTAB: u32 = 3;

    /// A section header to write: name, type, flags, address, size.
    pub type SectionSpec<'a> = (&'a str, u32, u32, u32, u32);

    /// An ELF32 LE file: one PT_LOAD segment per (load address, bytes), then the section
    /// headers (a null one first, the name table last) with their names.
    pub fn elf(segments: &[(u32, Vec<u8>)], sections: &[SectionSpec<'_>]) -> Vec<u8> {
        let phoff = 0x34;
        let mut out = vec![0u8; phoff + 32 * segments.len()];
        out[..6].copy_from_slice(b"\x7fELF\x01\x01");
        let mut offsets = Vec::new();
        for (_, data) in segments {
            offsets.push(out.len() as u32);
            out.extend_from_slice(data);
        }
        for (i, ((paddr, data), offset)) in segments.iter().zip(&offsets).enumerate() {
            let h = phoff + 32 * i;
            for (at, v) in [(0, 1), (4, *offset), (12, *paddr), (16, data.len() as u32)] {
                out[h + at..h + at + 4].copy_from_slice(&v.to_le_bytes());
            }
        }
        let mut names = vec![0u8];
        let mut name_at = Vec::new();
        for (name, ..) in sections {
            name_at.push(names.len() as u32);
            names.extend_from_slice(name.as_bytes());
            names.push(0);
        }
        let shstrtab_name = names.len() as u32;
        names.extend_from_slice(b".shstrtab\0");
        let names_offset = out.len() as u32;
        out.extend_from_slice(&names);
        let shoff = out.len() as u32;
        let mut header = |name: u32, kind: u32, flags: u32, addr: u32, offset: u32, size: u32| {
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
            out.extend_from_slice(&h);
        };
        header(0, 0, 0, 0, 0, 0);
        for ((_, kind, flags, addr, size), name) in sections.iter().zip(&name_at) {
            header(*name, *kind, *flags, *addr, 0, *size);
        }
        header(
            shstrtab_name,
            SHT_STRTAB,
            0,
            0,
            names_offset,
            names.len() as u32,
        );
        let shnum = sections.len() as u16 + 2;
        out[0x1C..0x20].copy_from_slice(&(phoff as u32).to_le_bytes());
        out[0x20..0x24].copy_from_slice(&shoff.to_le_bytes());
        out[0x2A..0x2C].copy_from_slice(&32u16.to_le_bytes());
        out[0x2C..0x2E].copy_from_slice(&(segments.len() as u16).to_le_bytes());
        out[0x2E..0x30].copy_from_slice(&40u16.to_le_bytes());
        out[0x30..0x32].copy_from_slice(&shnum.to_le_bytes());
        out[0x32..0x34].copy_from_slice(&(shnum - 1).to_le_bytes());
        out
    }
}

#[cfg(test)]
mod tests {
    use super::build::{elf, PROGBITS};
    use super::*;

    #[test]
    fn reads_the_allocated_sections_and_the_loaded_segments() {
        let image = elf(
            &[
                (0x0800_0000, vec![1, 2, 3]),
                (0x0800_0100, Vec::new()),
                (0x0800_0200, vec![4]),
            ],
            &[
                (".text", PROGBITS, SHF_ALLOC | 0x4, 0x0800_0000, 3),
                (".bss", SHT_NOBITS, SHF_ALLOC | 0x1, 0x2000_0000, 500),
                (".debug_info", PROGBITS, 0, 0, 99),
            ],
        );
        let sections = allocated_sections(&image).unwrap();
        let seen: Vec<_> = sections
            .iter()
            .map(|s| (s.name.as_str(), s.addr, s.size, s.nobits))
            .collect();
        assert_eq!(
            seen,
            [
                (".text", 0x0800_0000, 3, false),
                (".bss", 0x2000_0000, 500, true)
            ]
        );
        let segments = loaded_segments(&image).unwrap();
        assert_eq!(
            segments,
            [
                Segment {
                    paddr: 0x0800_0000,
                    data: &[1, 2, 3]
                },
                Segment {
                    paddr: 0x0800_0200,
                    data: &[4]
                }
            ]
        );
    }

    #[test]
    fn rejects_what_is_not_elf32_le() {
        assert!(allocated_sections(b"not an elf").is_err());
        assert!(loaded_segments(b"not an elf").is_err());
        let mut image = elf(&[], &[]);
        image[4] = 2;
        assert!(allocated_sections(&image).is_err());
        assert!(loaded_segments(&image).is_err());
        let whole = elf(&[(0x0800_0000, vec![7; 16])], &[]);
        let cut = &whole[..0x34 + 32 + 8];
        let error = loaded_segments(cut).unwrap_err();
        assert!(error.contains("truncated"), "{error}");
    }
}
