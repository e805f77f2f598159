//! Flash as the loader sees it, through the board's flash trait and writer: the application
//! slot (read in place for the boot decision, then written through the flash controller,
//! the watchdog fed around each erase) and the parameter pages (read only: the loader never
//! writes them).

use canopen_loader::layout::{SLOT_ORIGIN, SLOT_PAGES, STORAGE_ORIGIN};
use handwheel_board::flash::{Flash, FlashError, Mapped, Region};
use handwheel_board::watchdog::Watchdog;
use handwheel_storage::page::PAGES;
use stm32f1xx_hal::flash;

/// The slot for the boot decision, before any peripheral is touched: reads only.
pub const MAPPED_SLOT: Mapped = Mapped::new(SLOT_ORIGIN, SLOT_PAGES);

/// The parameter pages, read as the application reads them (`ParameterPage`).
pub const PARAMETER_PAGES: Mapped = Mapped::new(STORAGE_ORIGIN, PAGES);

/// The slot, written through the flash controller.
pub struct Fpec {
    slot: Region,
    /// Fed around each page erase (the CPU stalls up to 40 ms in one).
    pub watchdog: Watchdog,
}

impl Fpec {
    /// Takes the flash controller (after the clock setup used its ACR) and the running
    /// watchdog.
    pub fn new(flash: flash::Parts, watchdog: Watchdog) -> Self {
        Self {
            slot: Region::new(flash, SLOT_ORIGIN, SLOT_PAGES),
            watchdog,
        }
    }
}

impl Flash for Fpec {
    fn page(&self, page: usize) -> &[u8] {
        self.slot.page(page)
    }

    fn erase(&mut self, page: usize) -> Result<(), FlashError> {
        self.watchdog.feed();
        let erased = self.slot.erase(page);
        self.watchdog.feed();
        erased
    }

    fn program(&mut self, page: usize, offset: usize, bytes: &[u8]) -> Result<(), FlashError> {
        self.slot.program(page, offset, bytes)
    }
}
