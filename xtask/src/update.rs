//! The update file (docs/FIRMWARE-UPDATE.md): the application slot's bytes from the image
//! header to the image's end, `slot + length` bytes, read from the sealed ELF, and the check
//! that the seal (`tools/seal/seal.py`, run at link time) wrote the header this code computes
//! on its own: the image's length and its CRC-32.

use std::path::Path;

use canopen_loader::header::{
    CRC_AT, FORMAT, FORMAT_AT, HEADER_LEN, HEADER_SIZE_AT, LENGTH_AT, MAGIC, MAGIC_AT,
};
use canopen_slave::crc::crc32;

use crate::elf::{self, u16_at, u32_at};

/// The header's section (`header.x`), which fills the slot's first bytes.
const HEADER_SECTION: &str = ".image_header";
/// Loadable bytes below this address are flash (the ARMv7-M code region).
const CODE_REGION_END: u32 = 0x2000_0000;

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

/// The update file of a sealed application ELF; fails unless its header is one the loader
/// takes and carries this image's length and CRC.
pub fn from_elf(elf: &[u8]) -> Result<UpdateImage, String> {
    let header = elf::allocated_sections(elf)?
        .into_iter()
        .find(|s| s.name == HEADER_SECTION)
        .ok_or("no image header (section .image_header): not an application image")?;
    let (address, slot) = (header.addr, header.size);
    let segments: Vec<_> = elf::loaded_segments(elf)?
        .into_iter()
        .filter(|s| s.paddr < CODE_REGION_END)
        .collect();
    let end = segments
        .iter()
        .map(|s| s.paddr + s.data.len() as u32)
        .max()
        .unwrap_or(address);
    if let Some(below) = segments.iter().find(|s| s.paddr < address) {
        return Err(format!(
            "a segment loads at {:#x}, below the image header at {address:#x}",
            below.paddr
        ));
    }
    if end <= address + slot {
        return Err("no image after the header slot".into());
    }
    let mut bytes = vec![0xFF; (end - address) as usize];
    for segment in segments {
        let at = (segment.paddr - address) as usize;
        bytes[at..at + segment.data.len()].copy_from_slice(segment.data);
    }
    let field = |at: usize| u32_at(&bytes, at);
    let (magic, format, size) = (
        field(MAGIC_AT)?,
        u16_at(&bytes, FORMAT_AT)?,
        u16_at(&bytes, HEADER_SIZE_AT)?,
    );
    if (magic, format, usize::from(size)) != (MAGIC, FORMAT, HEADER_LEN) {
        return Err(format!(
            "the image header is not format {FORMAT} (magic {magic:#010x}, format {format}, \
             size {size})"
        ));
    }
    let image = &bytes[slot as usize..];
    let (length, crc) = (field(LENGTH_AT)?, field(CRC_AT)?);
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
    use crate::elf::build::{elf, PROGBITS, SHF_ALLOC};

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

    /// The code after the header slot: a vector table the loader takes (the stack pointer at
    /// the top of RAM, the reset vector a Thumb address in the image), then filler.
    fn code() -> Vec<u8> {
        let (stack_top, reset) = (0x2000_4FF8u32, AT + SLOT + 9);
        [
            &stack_top.to_le_bytes()[..],
            &reset.to_le_bytes(),
            &[0xA5; 92],
        ]
        .concat()
    }

    /// Code after the header, `.data`'s load image after a 3-byte gap, a RAM segment.
    fn application(length: u32, crc: u32) -> Vec<u8> {
        let mut first = header(length, crc);
        first.extend_from_slice(&code());
        elf(
            &[
                (AT, first),
                (AT + SLOT + 103, vec![1, 2, 3, 4]),
                (0x2000_0000, vec![9; 8]),
            ],
            &[
                (".image_header", PROGBITS, SHF_ALLOC, AT, SLOT),
                (".vector_table", PROGBITS, SHF_ALLOC, AT + SLOT, 100),
            ],
        )
    }

    fn image() -> Vec<u8> {
        [&code()[..], &[0xFF; 3], &[1, 2, 3, 4]].concat()
    }

    #[test]
    fn a_sealed_image_gives_the_slots_bytes() {
        let crc = crc32(&image());
        let update = from_elf(&application(107, crc)).unwrap();
        assert_eq!((update.address, update.slot, update.crc), (AT, SLOT, crc));
        assert_eq!(update.bytes, [header(107, crc), image()].concat());
        assert_eq!(update.bytes.len(), 512 + 107);
    }

    /// The application slot as the loader reads it once the update file is in flash.
    fn slot(file: &[u8]) -> handwheel_board::flash::model::CutFlash {
        let mut bytes = file.to_vec();
        bytes.resize(canopen_loader::layout::SLOT_SIZE, 0xFF);
        handwheel_board::flash::model::CutFlash::holding(bytes)
    }

    /// The image xtask accepts is one the loader starts: its boot check computes, over the
    /// update file's bytes, the CRC xtask held the seal's to.
    #[test]
    fn the_loader_starts_the_update_files_image() {
        let update = from_elf(&application(107, crc32(&image()))).unwrap();
        let device = canopen_loader::header::PRODUCT;
        let header = canopen_loader::valid_application(&slot(&update.bytes), device)
            .expect("the loader refuses the update file");
        assert_eq!((header.length, header.crc), (107, update.crc));
        let mut damaged = update.bytes;
        damaged[SLOT as usize + 20] ^= 1;
        assert_eq!(
            canopen_loader::valid_application(&slot(&damaged), device),
            None
        );
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
            &[(".vector_table", PROGBITS, SHF_ALLOC, 0x0800_0000, 64)],
        );
        let error = from_elf(&loader).unwrap_err();
        assert!(error.contains("no image header"), "{error}");
    }
}
