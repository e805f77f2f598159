//! The QEMU board's parameter pages: 2 KiB of RAM under the same `ParameterPage` as the
//! board's flash pages (same records, same "unchanged means no write", same wear budget and
//! answers), so that a master sees the same device.
//!
//! They survive NMT reset node and reset communication (the device object lives on), not a
//! restart of the emulator, which is a power cycle: every boot starts from erased pages,
//! the defaults and a full wear budget.

use handwheel_device::page::{Flash, FlashError, PAGES, PAGE_SIZE};
use handwheel_device::record::NodeSettings;

/// The QEMU board's "parameter pages" in RAM: a static buffer (`init` takes it once), so
/// that the 2 KiB are never copied through the small stack of the emulated part.
pub struct RamStorage {
    bytes: &'static mut [[u8; PAGE_SIZE]; PAGES],
}

impl RamStorage {
    /// The pages in `bytes`, erased: a fresh boot.
    pub fn new(bytes: &'static mut [[u8; PAGE_SIZE]; PAGES]) -> Self {
        for page in bytes.iter_mut() {
            page.fill(0xFF);
        }
        Self { bytes }
    }
}

impl Flash for RamStorage {
    fn page(&self, page: usize) -> &[u8] {
        self.bytes.get(page).map_or(&[], |p| &p[..])
    }

    fn erase(&mut self, page: usize) -> Result<(), FlashError> {
        self.bytes.get_mut(page).ok_or(FlashError::Page)?.fill(0xFF);
        Ok(())
    }

    fn program(&mut self, page: usize, offset: usize, bytes: &[u8]) -> Result<(), FlashError> {
        let page = self.bytes.get_mut(page).ok_or(FlashError::Page)?;
        let end = offset.checked_add(bytes.len()).ok_or(FlashError::Program)?;
        let dst = page.get_mut(offset..end).ok_or(FlashError::Program)?;
        dst.copy_from_slice(bytes);
        Ok(())
    }

    /// Every initialisation (NMT reset node or communication) is the QEMU board's "boot":
    /// the stored node settings are reported here, as the board's boot line reports them
    /// after a power-on (the serial line has no bit rate to apply).
    fn on_load(&self, settings: NodeSettings) {
        defmt::info!("stored node settings: {}", settings);
    }
}
