//! The update file (docs/FIRMWARE-UPDATE.md): the application slot's bytes from the image
//! header to the image's end, `slot + length` bytes, read from the sealed ELF, and the check
//! that the seal (`tools/seal/seal.py`, run at link time) wrote the header this code computes
//! on its own: the image's length and its CRC-32.

use std::path::Path;

use crate::footprint::{elf_sections, u16_at, u32_at};

/// The header's section (`header.x`), which fills the slot's first bytes.
const HEADER_SECTION: &str = ".image_header";
/// The validity mark, "HWIM".
const MAGIC: u32 = 0x4D49_5748;
const FORMAT: u16 = 1;
const HEADER_SIZE: u16 = 32;
/// Loadable bytes below this address are flash (the ARMv7-M code region).
const CODE_REGION_END: u32 = 0x2000_0000;
const PT_LOAD: u32 = 1;

/// A sealed application's update file.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct UpdateImage {
    /// The slot's bytes: the header slot, then the image.
    pub bytes: Vec<u8>,
    /// Where the slot starts in flash.
    pub address: u32,
    /// The header slot's size.
    pub slot: u32,
    /// The header's `crc`.
    pub crc: u32,
}

/// CRC-32/ISO-HDLC, zlib's `crc32`: reflected polynomial 0x04C11DB7, all ones in and out.
pub fn crc32(bytes: &[u8]) -> u32 {
    let mut crc = !0u32;
    for &byte in bytes {
        crc ^= u32::from(byte);
        for _ in 0..8 {
            crc = (crc >> 1) ^ (0xEDB8_8320 & (crc & 1).wrapping_neg());
        }
    }
    !crc
}

/// The flash bytes of every loadable segment: (load address, bytes).
fn flash_segments(elf: &[u8]) -> Result<Vec<(u32, &[u8])>, String> {
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
        if kind != PT_LOAD || filesz == 0 || paddr >= CODE_REGION_END {
            continue;
        }
        let data = elf
            .get(offset..offset + filesz)
            .ok_or_else(|| format!("truncated ELF (segment at {paddr:#x})"))?;
        out.push((paddr, data));
    }
    Ok(out)
}

/// The update file of a sealed application ELF; fails unless its header is one the loader
/// takes and carries this image's length and CRC.
pub fn from_elf(elf: &[u8]) -> Result<UpdateImage, String> {
    let header = elf_sections(elf)?
        .into_iter()
        .find(|s| s.name == HEADER_SECTION)
        .ok_or("no image header (section .image_header): not an application image")?;
    let (address, slot) = (header.addr, header.size);
    let segments = flash_segments(elf)?;
    let end = segments
        .iter()
        .map(|&(paddr, data)| paddr + data.len() as u32)
        .max()
        .unwrap_or(address);
    if let Some(&(below, _)) = segments.iter().find(|&&(paddr, _)| paddr < address) {
        return Err(format!(
            "a segment loads at {below:#x}, below the image header at {address:#x}"
        ));
    }
    if end <= address + slot {
        return Err("no image after the header slot".into());
    }
    let mut bytes = vec![0xFF; (end - address) as usize];
    for (paddr, data) in segments {
        let at = (paddr - address) as usize;
        bytes[at..at + data.len()].copy_from_slice(data);
    }
    let field = |at: usize| u32_at(&bytes, at);
    let (magic, format, size) = (field(0)?, u16_at(&bytes, 4)?, u16_at(&bytes, 6)?);
    if (magic, format, size) != (MAGIC, FORMAT, HEADER_SIZE) {
        return Err(format!(
            "the image header is not format {FORMAT} (magic {magic:#010x}, format {format}, \
             size {size})"
        ));
    }
    let image = &bytes[slot as usize..];
    let (length, crc) = (field(0x14)?, field(0x18)?);
    let want = (image.len() as u32, crc32(image));
    if (length, crc) != want {
        return Err(format!(
            "the image header says length {length} and CRC {crc:#010x}, the image has {} and \
             {:#010x}: not sealed (the linker must be tools/seal/linker, .cargo/config.toml)",
            want.0, want.1
        ));
    }
    Ok(UpdateImage {
        bytes,
        address,
        slot,
        crc,
    })
}

/// Reads the sealed application `elf`, checks its header and writes its update file to
/// `out`.
pub fn write(elf: &Path, out: &Path) -> Result<UpdateImage, String> {
    let bytes = std::fs::read(elf).map_err(|e| format!("cannot read {}: {e}", elf.display()))?;
    let image = from_elf(&bytes).map_err(|e| format!("{}: {e}", elf.display()))?;
    std::fs::write(out, &image.bytes)
        .map_err(|e| format!("cannot write {}: {e}", out.display()))?;
    Ok(image)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_crc_is_zlibs() {
        // The CRC-32/ISO-HDLC check value, and zlib.crc32(b"") and (b"a").
        assert_eq!(crc32(b"123456789"), 0xCBF4_3926);
        assert_eq!(crc32(b""), 0);
        assert_eq!(crc32(b"a"), 0xE8B7_BE43);
    }

    /// An ELF32 LE file with the given PT_LOAD segments (paddr, bytes) and one section
    /// header per named section (name, address, size).
    fn elf(segments: &[(u32, Vec<u8>)], sections: &[(&str, u32, u32)]) -> Vec<u8> {
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
        let names_offset = out.len() as u32;
        out.extend_from_slice(&names);
        let shoff = out.len() as u32;
        let mut header = |name: u32, flags: u32, addr: u32, offset: u32, size: u32| {
            let mut h = [0u8; 40];
            for (at, v) in [(0, name), (8, flags), (12, addr), (16, offset), (20, size)] {
                h[at..at + 4].copy_from_slice(&v.to_le_bytes());
            }
            out.extend_from_slice(&h);
        };
        header(0, 0, 0, 0, 0);
        for ((_, addr, size), name) in sections.iter().zip(&name_at) {
            header(*name, 2, *addr, 0, *size);
        }
        header(0, 0, 0, names_offset, names.len() as u32);
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

    const AT: u32 = 0x0800_3000;
    const SLOT: u32 = 512;

    fn header(length: u32, crc: u32) -> Vec<u8> {
        let mut h = Vec::new();
        for v in [
            MAGIC.to_le_bytes(),
            [1, 0, 32, 0],
            [0; 4],
            [1, 0, 0, 0],
            [1, 0, 0, 0],
        ] {
            h.extend_from_slice(&v);
        }
        for v in [length, crc, u32::MAX] {
            h.extend_from_slice(&v.to_le_bytes());
        }
        h.resize(SLOT as usize, 0xFF);
        h
    }

    /// Code after the header, `.data`'s load image after a 3-byte gap, a RAM segment.
    fn application(length: u32, crc: u32) -> Vec<u8> {
        let mut first = header(length, crc);
        first.extend_from_slice(&[0xA5; 100]);
        elf(
            &[
                (AT, first),
                (AT + SLOT + 103, vec![1, 2, 3, 4]),
                (0x2000_0000, vec![9; 8]),
            ],
            &[
                (".image_header", AT, SLOT),
                (".vector_table", AT + SLOT, 100),
            ],
        )
    }

    fn image() -> Vec<u8> {
        [&[0xA5; 100][..], &[0xFF; 3], &[1, 2, 3, 4]].concat()
    }

    #[test]
    fn a_sealed_image_gives_the_slots_bytes() {
        let crc = crc32(&image());
        let update = from_elf(&application(107, crc)).unwrap();
        assert_eq!((update.address, update.slot, update.crc), (AT, SLOT, crc));
        assert_eq!(update.bytes, [header(107, crc), image()].concat());
        assert_eq!(update.bytes.len(), 512 + 107);
    }

    #[test]
    fn an_unsealed_or_wrongly_sealed_image_is_refused() {
        let crc = crc32(&image());
        for (length, crc) in [(u32::MAX, u32::MAX), (107, crc ^ 1), (106, crc)] {
            let error = from_elf(&application(length, crc)).unwrap_err();
            assert!(error.contains("not sealed"), "{error}");
        }
        let loader = elf(
            &[(0x0800_0000, vec![0; 64])],
            &[(".vector_table", 0x0800_0000, 64)],
        );
        let error = from_elf(&loader).unwrap_err();
        assert!(error.contains("no image header"), "{error}");
    }
}
