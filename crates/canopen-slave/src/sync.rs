//! SYNC consumer (0x1005), CiA 301 7.2.5. The device never produces SYNC.

use crate::abort::SdoAbort;
use crate::cob_id::{is_restricted, COB_EXTENDED};
use crate::frame::{Frame, MAX_STANDARD_ID};

/// 0x1005 bit 30: this node generates SYNC.
const SYNC_PRODUCER: u32 = 1 << 30;

/// SYNC consumer configuration.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
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

    /// Validates a write of 0x1005: a consumer-only device refuses to become the SYNC
    /// producer and has no 29-bit identifiers, and SYNC may not sit on an identifier that
    /// CiA 301 reserves (NMT, SDO, heartbeat, LSS): those frames would be taken for SYNC.
    pub(crate) fn check(v: u32) -> Result<(), SdoAbort> {
        let can_id = v & u32::from(MAX_STANDARD_ID);
        if v & (SYNC_PRODUCER | COB_EXTENDED) != 0 || v & 0x1FFF_F800 != 0 || is_restricted(can_id)
        {
            return Err(SdoAbort::InvalidValue);
        }
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
