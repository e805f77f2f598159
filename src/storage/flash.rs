//! The parameter pages in flash: the last two 1 KiB pages of the STM32F103C8, erased and
//! programmed with the HAL's flash writer for `handwheel_device::page`, which decides what
//! to write and when.
//!
//! The writer (stm32f1xx-hal's `FlashWriter`) unlocks with the two keys, erases a page
//! (PER, AR, STRT) or programs half-words (PG), polls BSY, checks the error flags, reads
//! back what it wrote (verification on), and locks the controller again on every path
//! (RM0008, "Flash memory programming").

use handwheel_device::page::{Flash, FlashError, PAGES, PAGE_SIZE};
use stm32f1xx_hal::flash::{self, FlashSize, SectorSize};

/// Start of the main flash memory.
const FLASH_START: u32 = flash::FLASH_START;
/// Offset of the first parameter page from the start of flash: the last two 1 KiB pages of
/// the 64 KiB part (62 and 63) are the parameters'. `memory.x` keeps the linker out of them
/// (its STORAGE region).
pub const PAGE_OFFSET: u32 = 62 * 1024;
/// Absolute address of the first parameter page.
pub const PAGE_ADDRESS: u32 = FLASH_START + PAGE_OFFSET;
// Both pages must lie inside the 64 KiB part.
const _: () = assert!(PAGE_OFFSET as usize + PAGES * PAGE_SIZE == 64 * 1024);

/// The parameter pages, owning the flash controller (the HAL's constrained FLASH).
pub struct FlashStorage {
    flash: flash::Parts,
}

impl FlashStorage {
    /// Takes the flash controller (after the clock setup used its ACR).
    pub fn new(flash: flash::Parts) -> Self {
        Self { flash }
    }

    /// Gives the flash controller back (tests use it to damage a record on purpose).
    pub fn free(self) -> flash::Parts {
        self.flash
    }

    fn writer(&mut self) -> flash::FlashWriter<'_> {
        self.flash.writer(SectorSize::Sz1K, FlashSize::Sz64K)
    }
}

impl Flash for FlashStorage {
    fn page(&self, page: usize) -> &[u8] {
        // A read of memory, not of a register: the HAL's `FlashWriter::read` gives the same
        // slice but borrows the controller mutably, which a shared read of the page does not
        // need.
        // SAFETY: PAGE_ADDRESS..+PAGES * PAGE_SIZE are the last two pages of the 64 KiB
        // flash (asserted above): mapped, readable, and kept out of every linker section by
        // memory.x. They only change through the writer, which needs `&mut self`, so not
        // while this borrow lives.
        let pages =
            unsafe { core::slice::from_raw_parts(PAGE_ADDRESS as *const u8, PAGES * PAGE_SIZE) };
        pages
            .get(page * PAGE_SIZE..(page + 1) * PAGE_SIZE)
            .unwrap_or(&[])
    }

    fn erase(&mut self, page: usize) -> Result<(), FlashError> {
        let offset = page_offset(page)?;
        self.writer()
            .page_erase(offset)
            .map_err(|error| match error {
                flash::Error::UnlockError | flash::Error::LockError => FlashError::Controller,
                _ => FlashError::Erase,
            })
    }

    /// Programs `bytes` (an even number: the writer takes half-words) at `offset` of the
    /// page; fails without writing past the page's end.
    fn program(&mut self, page: usize, offset: usize, bytes: &[u8]) -> Result<(), FlashError> {
        let start = page_offset(page)?;
        if offset > PAGE_SIZE || bytes.len() > PAGE_SIZE - offset {
            return Err(FlashError::Program);
        }
        // `offset` is at most PAGE_SIZE, so this cannot overflow.
        let at = start + offset as u32;
        self.writer().write(at, bytes).map_err(|error| match error {
            flash::Error::UnlockError | flash::Error::LockError => FlashError::Controller,
            _ => FlashError::Program,
        })
    }
}

/// The offset of parameter page `page` from the start of flash.
fn page_offset(page: usize) -> Result<u32, FlashError> {
    if page >= PAGES {
        return Err(FlashError::Page);
    }
    // Below PAGES, so the product is at most 1 KiB.
    Ok(PAGE_OFFSET + (page * PAGE_SIZE) as u32)
}
