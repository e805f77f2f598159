//! The memory map of docs/FIRMWARE-UPDATE.md as numbers (the root `memory.x` states the same
//! regions for the linker; a test reads it and compares).

/// Bytes in a flash page of the STM32F103C8 (medium density): the board's.
pub const PAGE_SIZE: usize = handwheel_board::flash::PAGE_SIZE;
/// Bytes of the chip's flash, from [`LOADER_ORIGIN`]: the loader's pages first, the
/// parameter pages last.
pub const CHIP_FLASH_SIZE: u32 = 64 * 1024;

/// The loader's region (`LOADER`): pages 0-11.
pub const LOADER_ORIGIN: u32 = 0x0800_0000;
/// Length of `LOADER`.
pub const LOADER_LENGTH: u32 = 12 * 1024;

/// The application slot: `HEADER` followed by `FLASH`, pages 12-61.
pub const SLOT_ORIGIN: u32 = 0x0800_3000;
/// Length of the slot (50 KiB).
pub const SLOT_SIZE: usize = 50 * 1024;
/// Pages in the slot.
pub const SLOT_PAGES: usize = SLOT_SIZE / PAGE_SIZE;
/// The header slot at the start of the slot (`HEADER`): the header, padded with 0xFF.
///
/// 512 bytes, not the contract's 256: the application's vector table follows it, and VTOR
/// on the STM32F10x takes only 512-byte aligned tables (PM0056 4.4.4: TBLOFF is bits 29:9,
/// bits 8:0 read as zero; a table of 76 vectors needs 512 anyway), so a table at 0x0800_3100
/// would be read from 0x0800_3000, the header.
pub const HEADER_SLOT: usize = 512;
/// The application's vector table and first byte (`FLASH`'s origin, VTOR's value).
pub const APP_ORIGIN: u32 = SLOT_ORIGIN + HEADER_SLOT as u32;
/// The most image bytes (after the header slot) the slot takes.
pub const MAX_IMAGE: usize = SLOT_SIZE - HEADER_SLOT;

/// The parameter pages (`STORAGE`), never written by the loader.
pub const STORAGE_ORIGIN: u32 = 0x0800_F800;
/// Length of `STORAGE`.
pub const STORAGE_LENGTH: u32 = 2 * 1024;

/// Static RAM of both images (`RAM`).
pub const RAM_ORIGIN: u32 = 0x2000_0000;
/// Length of `RAM`: 20 KiB less the hand-off words.
pub const RAM_LENGTH: u32 = 20 * 1024 - HANDOFF_LENGTH;
/// The words between loader and application (`HANDOFF`): two words, no image's RAM, that
/// hold the request to stay in the loader or the trial's count ([`crate::boot`]).
pub const HANDOFF_ORIGIN: u32 = RAM_ORIGIN + RAM_LENGTH;
/// Length of `HANDOFF`: two words, the last of SRAM.
pub const HANDOFF_LENGTH: u32 = 8;
/// Word 0 of a hand-off request ("LOAD"); word 1 is its complement.
pub const HANDOFF_REQUEST: u32 = 0x4C4F_4144;

/// Whether the two hand-off words hold the request to stay in the loader.
#[must_use]
pub const fn is_handoff_request(words: [u32; 2]) -> bool {
    words[0] == HANDOFF_REQUEST && words[1] == !HANDOFF_REQUEST
}

// The regions follow one another as the contract's table says.
const _: () = assert!(LOADER_ORIGIN + LOADER_LENGTH == SLOT_ORIGIN);
const _: () = assert!(SLOT_ORIGIN + SLOT_SIZE as u32 == STORAGE_ORIGIN);
const _: () = assert!(STORAGE_ORIGIN + STORAGE_LENGTH == LOADER_ORIGIN + CHIP_FLASH_SIZE);
const _: () = assert!(LOADER_ORIGIN + CHIP_FLASH_SIZE == 0x0801_0000);
const _: () = assert!(HANDOFF_ORIGIN + HANDOFF_LENGTH == 0x2000_5000);
const _: () = assert!(APP_ORIGIN.is_multiple_of(512));
const _: () = assert!(SLOT_ORIGIN.is_multiple_of(PAGE_SIZE as u32));
