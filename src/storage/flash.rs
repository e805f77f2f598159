//! The parameter page in flash: the last 1 KiB page of the STM32F103C8.

use stm32f1xx_hal::flash::{self, FlashSize, SectorSize};

use super::{record, NodeSettings, Stored, RECORD_MAX};

/// Offset of the parameter page from the start of flash: the last 1 KiB page of the
/// 64 KiB part. `board/memory.x` keeps the linker out of it (its STORAGE region).
pub const PAGE_OFFSET: u32 = 63 * 1024;
/// Absolute address of the parameter page.
pub const PAGE_ADDRESS: u32 = flash::FLASH_START + PAGE_OFFSET;
const PAGE_SIZE: usize = 1024;

/// A failed store or erase.
#[derive(Clone, Copy, Debug, PartialEq, Eq, defmt::Format)]
pub enum StoreError {
    /// The device blob is longer than [`BLOB_MAX`](super::BLOB_MAX).
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
                dst.copy_from_slice(&stored.blob);
                stored.blob.len()
            }
            // A blob the engine cannot take is as good as none: defaults apply.
            None => 0,
        }
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
