//! The parameter page in flash: the last 1 KiB page of the STM32F103C8.
//!
//! Erase and program go straight to the flash controller's registers (RM0008, "Flash
//! memory programming"): unlock with the two keys, page erase (PER, AR, STRT), half-word
//! programming (PG), BSY polled after each step, errors from SR, every half-word and the
//! erased page read back, and the controller locked again on every path. The HAL's flash
//! writer does the same with generic address checks whose panics would pull `core::fmt`
//! into the image; this page has one fixed address, so there is nothing to check at run
//! time.

use crate::pac;

use super::{record, NodeSettings, Stored, RECORD_MAX};

/// Start of the main flash memory.
const FLASH_START: u32 = 0x0800_0000;
/// Offset of the parameter page from the start of flash: the last 1 KiB page of the
/// 64 KiB part. `board/memory.x` keeps the linker out of it (its STORAGE region).
pub const PAGE_OFFSET: u32 = 63 * 1024;
/// Absolute address of the parameter page.
pub const PAGE_ADDRESS: u32 = FLASH_START + PAGE_OFFSET;
const PAGE_SIZE: usize = 1024;
// A record must fit the page, and programming goes by half-words.
const _: () = assert!(RECORD_MAX <= PAGE_SIZE && RECORD_MAX.is_multiple_of(2));

/// The unlock sequence of FLASH_KEYR.
const KEYS: [u32; 2] = [0x4567_0123, 0xCDEF_89AB];

/// A failed store or erase.
#[derive(Clone, Copy, Debug, PartialEq, Eq, defmt::Format)]
pub enum StoreError {
    /// The device blob is longer than [`BLOB_MAX`](super::BLOB_MAX).
    TooLarge,
    /// The page erase failed or did not read back as erased.
    Erase,
    /// Programming failed or did not read back as written.
    Program,
    /// The flash controller would not unlock.
    Controller,
}

/// The parameter page, owning the flash controller.
pub struct FlashStorage {
    /// Owned, so that nothing else reaches the flash controller; its registers are used
    /// through [`Unlocked`].
    flash: pac::FLASH,
}

impl FlashStorage {
    /// Takes the flash controller (after the clock setup used its ACR).
    pub fn new(flash: pac::FLASH) -> Self {
        Self { flash }
    }

    /// The page as it reads now.
    fn page(&self) -> &[u8] {
        // SAFETY: PAGE_ADDRESS..+PAGE_SIZE is the last page of the 64 KiB flash: mapped,
        // readable, and kept out of every linker section by memory.x. It only changes
        // through `Unlocked`, which needs `&mut self`, so not while this borrow lives.
        unsafe { core::slice::from_raw_parts(PAGE_ADDRESS as *const u8, PAGE_SIZE) }
    }

    /// The stored record, read in place, or `None` when the page is empty or invalid.
    pub fn load(&self) -> Option<Stored<'_>> {
        let (settings, blob) = record::decode(self.page())?;
        Some(Stored { settings, blob })
    }

    /// Replaces the stored record.
    pub fn store(&mut self, settings: NodeSettings, blob: &[u8]) -> Result<(), StoreError> {
        // Word-aligned, so that clearing it uses the word-wise `memclr4` the image already
        // has, not a second, byte-wise one.
        #[repr(align(4))]
        struct Aligned([u8; RECORD_MAX]);
        let mut buf = Aligned([0; RECORD_MAX]);
        let len = record::encode(settings, blob, &mut buf.0).ok_or(StoreError::TooLarge)?;
        let mut controller = self.unlock()?;
        controller.erase_page()?;
        controller.program(&buf.0[..len])
    }

    /// Gives the flash controller back (tests use it to damage a record on purpose).
    pub fn free(self) -> pac::FLASH {
        self.flash
    }

    /// Erases the page: the next boot uses the defaults (0x1011 "restore defaults").
    pub fn erase(&mut self) -> Result<(), StoreError> {
        self.unlock()?.erase_page()
    }

    fn unlock(&mut self) -> Result<Unlocked<'_>, StoreError> {
        // SAFETY: `self.flash` owns the FLASH peripheral (taken once from
        // `pac::Peripherals`), and `Unlocked` borrows `self` mutably, so these are the only
        // live accesses to its registers.
        let regs = unsafe { &*pac::FLASH::ptr() };
        let controller = Unlocked {
            regs,
            _owner: &mut self.flash,
        };
        controller.wait_idle();
        for key in KEYS {
            // SAFETY: writing the documented key sequence only unlocks FLASH_CR; a wrong
            // key would lock it until reset, and these are the right ones, in order.
            regs.keyr().write(|w| unsafe { w.key().bits(key) });
        }
        if regs.cr().read().lock().bit_is_set() {
            return Err(StoreError::Controller);
        }
        Ok(controller)
    }
}

/// The flash controller between unlock and lock; dropping it locks it again.
struct Unlocked<'a> {
    regs: &'a pac::flash::RegisterBlock,
    _owner: &'a mut pac::FLASH,
}

impl Unlocked<'_> {
    fn wait_idle(&self) {
        while self.regs.sr().read().bsy().bit_is_set() {}
    }

    /// Waits for the operation to end; `true` when it reported no error. Clears the
    /// end-of-operation and error flags (write 1 to clear) for the next one.
    fn finish(&self) -> bool {
        // BSY rises one cycle after the start (STM32F10x errata, "Flash BSY"): look later.
        cortex_m::asm::nop();
        self.wait_idle();
        let sr = self.regs.sr().read();
        let failed = sr.pgerr().bit_is_set() || sr.wrprterr().bit_is_set();
        self.regs
            .sr()
            .write(|w| w.eop().set_bit().pgerr().set_bit().wrprterr().set_bit());
        !failed
    }

    fn erase_page(&mut self) -> Result<(), StoreError> {
        self.regs.cr().modify(|_, w| w.per().set_bit());
        // SAFETY: the page address is a fixed, valid page of this part; with PER set, the
        // STRT below erases that page and nothing else.
        self.regs
            .ar()
            .write(|w| unsafe { w.far().bits(PAGE_ADDRESS) });
        self.regs.cr().modify(|_, w| w.strt().set_bit());
        let ok = self.finish();
        self.regs.cr().modify(|_, w| w.per().clear_bit());
        let base = PAGE_ADDRESS as *const u32;
        let erased = (0..PAGE_SIZE / 4).all(|word| {
            // SAFETY: inside the parameter page (see `FlashStorage::page`), word-aligned.
            unsafe { core::ptr::read_volatile(base.add(word)) == u32::MAX }
        });
        if ok && erased {
            Ok(())
        } else {
            Err(StoreError::Erase)
        }
    }

    /// Programs `bytes` (even length, at most a page) from the start of the erased page.
    fn program(&mut self, bytes: &[u8]) -> Result<(), StoreError> {
        let base = PAGE_ADDRESS as *mut u16;
        self.regs.cr().modify(|_, w| w.pg().set_bit());
        let result = bytes
            .chunks_exact(2)
            .take(PAGE_SIZE / 2)
            .enumerate()
            .try_for_each(|(i, pair)| {
                let half_word = u16::from_le_bytes([pair[0], pair[1]]);
                let at = base.wrapping_add(i);
                // SAFETY: `i` < PAGE_SIZE / 2 keeps `at` inside the parameter page, aligned;
                // with PG set the controller turns this store into a program operation.
                // `&mut self` means no reference into the page is alive.
                unsafe { core::ptr::write_volatile(at, half_word) };
                let ok = self.finish();
                // SAFETY: as above; a plain read of the programmed half-word.
                let written = ok && unsafe { core::ptr::read_volatile(at) } == half_word;
                if written {
                    Ok(())
                } else {
                    Err(StoreError::Program)
                }
            });
        self.regs.cr().modify(|_, w| w.pg().clear_bit());
        result
    }
}

impl Drop for Unlocked<'_> {
    fn drop(&mut self) {
        self.regs.cr().modify(|_, w| w.lock().set_bit());
    }
}

/// The CANopen engine's view of the parameter page: its blob, stored together with the
/// node-ID and bit rate in force, so that an all-off DIP switch finds them at the next boot.
pub struct DeviceStorage {
    flash: FlashStorage,
    settings: NodeSettings,
}

impl DeviceStorage {
    /// The page, storing `settings` alongside every blob the engine stores.
    pub fn new(flash: FlashStorage, settings: NodeSettings) -> Self {
        Self { flash, settings }
    }
}

impl canopen_slave::Storage for DeviceStorage {
    fn load(&mut self, buf: &mut [u8]) -> usize {
        let Some(stored) = self.flash.load() else {
            return 0;
        };
        match buf.get_mut(..stored.blob.len()) {
            Some(dst) => {
                dst.copy_from_slice(stored.blob);
                stored.blob.len()
            }
            // A blob the engine cannot take is as good as none: defaults apply.
            None => 0,
        }
    }

    /// LSS "store configuration": the same record with the new node-ID and bit rate and the
    /// blob stored now (if any), so that 0x1010 and LSS share one page and one layout.
    fn store_node(
        &mut self,
        node_id: u8,
        bit_timing: u8,
    ) -> Result<(), canopen_slave::StorageError> {
        let settings = NodeSettings::from_lss(node_id, bit_timing)
            .ok_or(canopen_slave::StorageError::Unsupported)?;
        let mut blob = [0u8; super::BLOB_MAX];
        let len = match self.flash.load() {
            Some(stored) => {
                let len = stored.blob.len().min(blob.len());
                blob[..len].copy_from_slice(&stored.blob[..len]);
                len
            }
            None => 0,
        };
        self.flash.store(settings, &blob[..len]).map_err(|error| {
            defmt::warn!("LSS store failed: {}", error);
            canopen_slave::StorageError::WriteFailed
        })?;
        // A later 0x1010 store keeps these settings in the record.
        self.settings = settings;
        defmt::info!("LSS stored {} (the next power-on uses it)", settings);
        Ok(())
    }

    fn store(&mut self, blob: &[u8]) -> Result<(), canopen_slave::StorageError> {
        let result = if blob.is_empty() {
            self.flash.erase()
        } else {
            self.flash.store(self.settings, blob)
        };
        result.map_err(|error| {
            defmt::warn!("parameter store failed: {}", error);
            canopen_slave::StorageError::WriteFailed
        })
    }
}
