//! The parameter pages in flash: the last two 1 KiB pages of the STM32F103C8 (memory.x's
//! STORAGE, the update contract's `STORAGE_ORIGIN`), erased and programmed through the
//! board's flash writer (`handwheel_board::flash::Region`) for `handwheel_storage::page`,
//! which decides what to write and when.

use canopen_loader::layout::{STORAGE_LENGTH, STORAGE_ORIGIN};
use handwheel_board::flash::Region;
use handwheel_storage::page::{PAGES, PAGE_SIZE};
use stm32f1xx_hal::flash::{self, FLASH_START};

/// Offset of the first parameter page from the start of flash (pages 62 and 63).
pub const PAGE_OFFSET: u32 = STORAGE_ORIGIN - FLASH_START;
// The contract's STORAGE holds the pages the parameter log uses.
const _: () = assert!(STORAGE_LENGTH as usize == PAGES * PAGE_SIZE);

/// The parameter pages, owning the flash controller (the HAL's constrained FLASH).
pub type FlashStorage = Region;

/// The parameter pages over the flash controller (after the clock setup used its ACR).
pub fn parameter_pages(flash: flash::Parts) -> FlashStorage {
    Region::new(flash, STORAGE_ORIGIN, PAGES)
}
