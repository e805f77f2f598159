//! Non-volatile parameters (0x1010 store, 0x1011 restore) in the last flash page.
//!
//! One page holds one record (layout in [`record`]): node-ID, bit rate and the device's own
//! parameter blob under a CRC-32. Storing erases the page and programs the new record; an
//! empty, half-written or corrupt page reads as nothing stored, so the device starts with its
//! defaults.
//!
//! Scheduling consequence: while flash is erased or programmed, the CPU stalls on every
//! instruction fetch from flash, interrupts included: a store (about 20-40 ms for the page
//! erase) holds off the wheel's EXTI too. Edges missed then show up as illegal transitions
//! (0x2020:2), never as motion. Stores happen on an SDO write to 0x1010, not while jogging.

pub mod record;

use stm32f1xx_hal::flash::{self, FlashSize, SectorSize};

pub use record::{NodeSettings, BLOB_MAX, RECORD_MAX};

/// Offset of the parameter page from the start of flash: the last 1 KiB page of the
/// 64 KiB part. `memory.x` keeps the linker out of it (its STORAGE region).
pub const PAGE_OFFSET: u32 = 63 * 1024;
/// Absolute address of the parameter page.
pub const PAGE_ADDRESS: u32 = flash::FLASH_START + PAGE_OFFSET;
const PAGE_SIZE: usize = 1024;

/// A failed store or erase.
#[derive(Clone, Copy, Debug, PartialEq, Eq, defmt::Format)]
pub enum StoreError {
    /// The device blob is longer than [`BLOB_MAX`].
    TooLarge,
    /// The page erase failed or did not read back as erased.
    Erase,
    /// Programming failed or did not read back as written.
    Program,
    /// The flash controller would not unlock or lock.
    Controller,
}

impl From<flash::Error> for StoreError {
    fn from(error: flash::Error) -> Self {
        match error {
            flash::Error::EraseError => Self::Erase,
            flash::Error::ProgrammingError
            | flash::Error::WriteError
            | flash::Error::VerifyError => Self::Program,
            flash::Error::UnlockError | flash::Error::LockError => Self::Controller,
            flash::Error::AddressLargerThanFlash
            | flash::Error::AddressMisaligned
            | flash::Error::LengthNotMultiple2
            | flash::Error::LengthTooLong => Self::TooLarge,
        }
    }
}

/// What a valid page holds.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Stored {
    /// Node-ID and bit rate stored with 0x1010.
    pub settings: NodeSettings,
    /// The device's parameter blob.
    pub blob: heapless::Vec<u8, BLOB_MAX>,
}

/// The parameter page, owning the flash controller.
pub struct FlashStorage {
    flash: flash::Parts,
}

impl FlashStorage {
    /// Takes the flash controller (after the clock setup used its ACR).
    pub fn new(flash: flash::Parts) -> Self {
        Self { flash }
    }

    fn writer(&mut self) -> flash::FlashWriter<'_> {
        // Medium density: 1 KiB pages. 64 KiB covers the page even on 128 KiB parts.
        self.flash.writer(SectorSize::Sz1K, FlashSize::Sz64K)
    }

    /// The stored record, or `None` when the page is empty or invalid.
    pub fn load(&mut self) -> Option<Stored> {
        let writer = self.writer();
        let page = writer.read(PAGE_OFFSET, PAGE_SIZE).ok()?;
        let (settings, blob) = record::decode(page)?;
        Some(Stored {
            settings,
            blob: heapless::Vec::from_slice(blob).ok()?,
        })
    }

    /// Replaces the stored record.
    pub fn store(&mut self, settings: NodeSettings, blob: &[u8]) -> Result<(), StoreError> {
        let mut buf = [0xFF; RECORD_MAX];
        let len = record::encode(settings, blob, &mut buf).ok_or(StoreError::TooLarge)?;
        let mut writer = self.writer();
        writer.page_erase(PAGE_OFFSET)?;
        writer.write(PAGE_OFFSET, &buf[..len])?;
        Ok(())
    }

    /// Gives the flash controller back (tests use it to damage a record on purpose).
    pub fn free(self) -> flash::Parts {
        self.flash
    }

    /// Erases the page: the next boot uses the defaults (0x1011 "restore defaults").
    pub fn erase(&mut self) -> Result<(), StoreError> {
        self.writer().page_erase(PAGE_OFFSET)?;
        Ok(())
    }
}
