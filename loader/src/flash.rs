//! Flash as the loader sees it: the application slot (read, and written through the flash
//! controller) and the parameter pages (read only: the loader never writes them).

use canopen_loader::layout::{PAGE_SIZE, SLOT_ORIGIN, SLOT_PAGES, SLOT_SIZE, STORAGE_ORIGIN};
use canopen_loader::{FlashError, SlotFlash};
use handwheel_device::page::{Flash, FlashError as PageError, PAGES};
use stm32f1xx_hal::flash::{self, FlashSize, SectorSize};
use stm32f1xx_hal::watchdog::IndependentWatchdog;

/// The slot's offset from the start of flash, as the HAL's writer counts.
const SLOT_OFFSET: u32 = SLOT_ORIGIN - flash::FLASH_START;

/// Copies slot bytes from `offset` into `buf` (0xFF past the slot).
fn read_slot(offset: usize, buf: &mut [u8]) {
    let inside = SLOT_SIZE.saturating_sub(offset).min(buf.len());
    let (mapped, past) = buf.split_at_mut(inside);
    if !mapped.is_empty() {
        // SAFETY: SLOT_ORIGIN + offset .. + inside lies within the slot (0x0800_3000 ..
        // 0x0800_F800), mapped flash that is always readable; the flash only changes through
        // `Fpec`, whose operations complete before they return, so no write runs during the
        // copy; `mapped` is a distinct RAM buffer.
        unsafe {
            core::ptr::copy_nonoverlapping(
                (SLOT_ORIGIN as usize + offset) as *const u8,
                mapped.as_mut_ptr(),
                inside,
            );
        }
    }
    past.fill(0xFF);
}

/// The slot for the boot decision, before any peripheral is touched: reads only.
pub struct MappedSlot;

impl SlotFlash for MappedSlot {
    fn erase(&mut self, _page: usize) -> Result<(), FlashError> {
        Err(FlashError)
    }

    fn program(&mut self, _offset: usize, _value: u16) -> Result<(), FlashError> {
        Err(FlashError)
    }

    fn read(&self, offset: usize, buf: &mut [u8]) {
        read_slot(offset, buf);
    }
}

/// The slot, written through the flash controller with the HAL's writer (unlock, erase or
/// program, BSY polled, error flags checked, read back, lock again on every path).
pub struct Fpec {
    flash: flash::Parts,
    /// Fed around each page erase (the CPU stalls up to 40 ms in one).
    pub watchdog: IndependentWatchdog,
}

impl Fpec {
    /// Takes the flash controller (after the clock setup used its ACR) and the running
    /// watchdog.
    pub fn new(flash: flash::Parts, watchdog: IndependentWatchdog) -> Self {
        Self { flash, watchdog }
    }
}

impl SlotFlash for Fpec {
    fn erase(&mut self, page: usize) -> Result<(), FlashError> {
        if page >= SLOT_PAGES {
            return Err(FlashError);
        }
        self.watchdog.feed();
        // page < SLOT_PAGES (50): the offset fits easily.
        let offset = SLOT_OFFSET + (page * PAGE_SIZE) as u32;
        let erased = self
            .flash
            .writer(SectorSize::Sz1K, FlashSize::Sz64K)
            .page_erase(offset);
        self.watchdog.feed();
        erased.map_err(|_| FlashError)
    }

    fn program(&mut self, offset: usize, value: u16) -> Result<(), FlashError> {
        if !offset.is_multiple_of(2) || offset + 2 > SLOT_SIZE {
            return Err(FlashError);
        }
        // offset < SLOT_SIZE: fits.
        let at = SLOT_OFFSET + offset as u32;
        self.flash
            .writer(SectorSize::Sz1K, FlashSize::Sz64K)
            .write(at, &value.to_le_bytes())
            .map_err(|_| FlashError)
    }

    fn read(&self, offset: usize, buf: &mut [u8]) {
        read_slot(offset, buf);
    }
}

/// The parameter pages, read as the application reads them (`ParameterPage`); the loader
/// never erases or programs them.
pub struct ParameterPages;

impl Flash for ParameterPages {
    fn page(&self, page: usize) -> &[u8] {
        // SAFETY: STORAGE_ORIGIN .. + PAGES * PAGE_SIZE are the last two pages of the 64 KiB
        // flash (memory.x's STORAGE): mapped and readable, and never written while the loader
        // runs (this type refuses to, and the slot's writer stays inside the slot).
        let pages = unsafe {
            core::slice::from_raw_parts(
                STORAGE_ORIGIN as *const u8,
                PAGES * handwheel_device::page::PAGE_SIZE,
            )
        };
        let size = handwheel_device::page::PAGE_SIZE;
        pages.get(page * size..(page + 1) * size).unwrap_or(&[])
    }

    fn erase(&mut self, _page: usize) -> Result<(), PageError> {
        Err(PageError::Controller)
    }

    fn program(&mut self, _page: usize, _offset: usize, _bytes: &[u8]) -> Result<(), PageError> {
        Err(PageError::Controller)
    }
}
