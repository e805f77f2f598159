//! SYNC consumer (0x1005), CiA 301 7.2.5. The device never produces SYNC.

use crate::frame::{Frame, COB_EXTENDED, MAX_STANDARD_ID};
use crate::sdo::SdoAbort;

/// 0x1005 bit 30: this node generates SYNC.
const SYNC_PRODUCER: u32 = 1 << 30;

/// SYNC consumer configuration.
#[derive(Clone, Debug, PartialEq, Eq)]
pub(crate) struct SyncConsumer {
    cob_id: u32,
}

impl SyncConsumer {
    pub(crate) const fn new() -> Self {
        Self {
            cob_id: crate::frame::cob::SYNC as u32,
        }
    }

    /// The raw 0x1005 value.
    pub(crate) const fn cob_id(&self) -> u32 {
        self.cob_id
    }

    /// Checked write of 0x1005: a consumer-only device refuses to become the SYNC producer
    /// and has no 29-bit identifiers.
    pub(crate) fn write(&mut self, v: u32) -> Result<(), SdoAbort> {
        if v & (SYNC_PRODUCER | COB_EXTENDED) != 0 || v & 0x1FFF_F800 != 0 {
            return Err(SdoAbort::InvalidValue);
        }
        self.cob_id = v;
        Ok(())
    }

    /// Unchecked write (defaults, stored parameters).
    pub(crate) fn set(&mut self, v: u32) {
        self.cob_id = v;
    }

    /// Whether `frame` is a SYNC (with or without the 1-byte counter).
    pub(crate) fn is_sync(&self, frame: &Frame) -> bool {
        u32::from(frame.id()) == self.cob_id & u32::from(MAX_STANDARD_ID) && frame.dlc() <= 1
    }
}
