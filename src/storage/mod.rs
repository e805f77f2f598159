//! Non-volatile parameters (0x1010 store, 0x1011 restore).
//!
//! On the board they live in the last flash page (`flash`): one page holds one record
//! (layout in [`record`]): node-ID, bit rate and the device's own parameter blob under a
//! CRC-32. Storing erases the page and programs the new record; an empty, half-written or
//! corrupt page reads as nothing stored, so the device starts with its defaults.
//!
//! Scheduling consequence: while flash is erased or programmed, the CPU stalls on every
//! instruction fetch from flash, interrupts included: a store (about 20-40 ms for the page
//! erase) holds off the wheel's EXTI too. Edges missed then show up as illegal transitions
//! (0x2020:2), never as motion. Stores happen on an SDO write to 0x1010, not while jogging.
//!
//! The QEMU variant keeps them in RAM (`crate::qemu::storage`): they survive NMT resets, not
//! a restart of the emulator.

#[cfg(not(feature = "qemu"))]
mod flash;
pub use handwheel_device::record;

#[cfg(feature = "qemu")]
pub use crate::qemu::storage::{DeviceStorage, RamStorage};
#[cfg(not(feature = "qemu"))]
pub use flash::{DeviceStorage, FlashStorage, StoreError, PAGE_ADDRESS, PAGE_OFFSET};
pub use record::{NodeSettings, BLOB_MAX, RECORD_MAX};

/// What a valid page holds, read in place.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Stored<'a> {
    /// Node-ID and bit rate stored with 0x1010.
    pub settings: NodeSettings,
    /// The device's parameter blob.
    pub blob: &'a [u8],
}
