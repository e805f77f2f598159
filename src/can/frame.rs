//! The frame type the firmware queues, and its conversion to and from bxcan's.

use bxcan::{Id, StandardId};

/// A classic CAN data frame with an 11-bit identifier: the shape the CANopen engine uses.
///
/// Extended and remote frames never get here: the acceptance filters pass only standard
/// data frames, and [`Frame::from_bxcan`] drops anything else.
#[derive(Clone, Copy, Debug, PartialEq, Eq, defmt::Format)]
pub struct Frame {
    id: u16,
    dlc: u8,
    data: [u8; 8],
}

impl Frame {
    /// A frame with identifier `id` (11 bits) and up to 8 data bytes.
    pub fn new(id: u16, data: &[u8]) -> Option<Self> {
        if id > 0x7FF || data.len() > 8 {
            return None;
        }
        let mut bytes = [0; 8];
        bytes[..data.len()].copy_from_slice(data);
        Some(Self {
            id,
            dlc: data.len() as u8,
            data: bytes,
        })
    }

    /// The 11-bit identifier.
    pub const fn id(&self) -> u16 {
        self.id
    }

    /// The data bytes (DLC of them).
    pub fn data(&self) -> &[u8] {
        &self.data[..usize::from(self.dlc)]
    }

    /// The frame for bxcan's transmit mailboxes.
    pub fn to_bxcan(&self) -> bxcan::Frame {
        // `new` checked both bounds, so neither fallback is ever taken.
        let id = StandardId::new(self.id).unwrap_or(StandardId::MAX);
        let data = bxcan::Data::new(self.data()).unwrap_or_else(bxcan::Data::empty);
        bxcan::Frame::new_data(id, data)
    }

    /// A received (or mailbox-displaced) bxcan frame, or `None` for extended or remote
    /// frames.
    pub fn from_bxcan(frame: &bxcan::Frame) -> Option<Self> {
        let Id::Standard(id) = frame.id() else {
            return None;
        };
        Self::new(id.as_raw(), frame.data()?)
    }
}
