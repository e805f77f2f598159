//! Non-volatile parameters (0x1010 store, 0x1011 restore, LSS store).
//!
//! What is written, and when, is `handwheel_storage::page`: a log of records (layout in
//! [`record`]: node-ID, bit rate and the device's parameter blob under a CRC-32) over two
//! pages, nothing written when nothing changed, a full page erased only after the newest
//! record was programmed to the other one, and at most as often as the wear budget allows
//! (8 erases at once, then one per 24 h of powered time; refused: SDO abort 0x08000020). The
//! newest intact record is the stored state; empty or corrupt pages read as nothing stored,
//! so the device starts with its defaults.
//!
//! On the board the pages are the last two flash pages (`flash`: erase and program). While flash
//! is erased or programmed, the CPU stalls on every instruction fetch from flash, interrupts
//! included: an erase (20-40 ms) would hold off the wheel's EXTI too, so the device refuses
//! every store while the feed is enabled (0x08000022, `HandwheelDevice`'s application).

mod flash;
pub use handwheel_storage::page::{Flash, FlashError, ParameterPage, PAGE_SIZE};
pub use handwheel_storage::record;

pub use flash::{parameter_pages, FlashStorage, PAGE_OFFSET};
pub use record::{NodeSettings, BLOB_MAX, RECORD_MAX};

/// The CANopen engine's storage: the parameter page over the last two flash pages.
pub type DeviceStorage = ParameterPage<FlashStorage>;
