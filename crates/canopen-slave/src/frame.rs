//! CAN frames as the engine sees them, node-IDs and the pre-defined connection set.
//!
//! Conversions to and from a driver's frame type belong to the firmware: this crate stays
//! independent of any HAL.

/// Largest 11-bit CAN identifier.
pub const MAX_STANDARD_ID: u16 = 0x7FF;

/// Function codes of the CiA 301 pre-defined connection set (COB-ID = code + node-ID).
pub mod cob {
    /// NMT module control (always 0x000, no node-ID).
    pub const NMT: u16 = 0x000;
    /// Default SYNC COB-ID.
    pub const SYNC: u16 = 0x080;
    /// Emergency.
    pub const EMCY: u16 = 0x080;
    /// First receive PDO.
    pub const RPDO1: u16 = 0x200;
    /// First transmit PDO.
    pub const TPDO1: u16 = 0x180;
    /// Second transmit PDO.
    pub const TPDO2: u16 = 0x280;
    /// SDO server to client.
    pub const SDO_TX: u16 = 0x580;
    /// SDO client to server.
    pub const SDO_RX: u16 = 0x600;
    /// Heartbeat and boot-up.
    pub const HEARTBEAT: u16 = 0x700;
}

/// A classic CAN data frame with an 11-bit identifier.
///
/// Remote frames are not represented: the firmware should drop them before they reach the
/// engine (RTR-triggered PDOs are not supported).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Frame {
    id: u16,
    dlc: u8,
    data: [u8; 8],
}

/// Why [`Frame::new`] refused its arguments.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FrameError {
    /// The identifier does not fit 11 bits.
    IdOutOfRange,
    /// More than 8 data bytes.
    TooLong,
}

impl Frame {
    /// A frame with identifier `id` (11 bits) and `data` (0..=8 bytes, DLC = its length).
    pub const fn new(id: u16, data: &[u8]) -> Result<Self, FrameError> {
        if id > MAX_STANDARD_ID {
            return Err(FrameError::IdOutOfRange);
        }
        if data.len() > 8 {
            return Err(FrameError::TooLong);
        }
        let mut buf = [0u8; 8];
        let mut i = 0;
        while i < data.len() {
            buf[i] = data[i];
            i += 1;
        }
        Ok(Self {
            id,
            dlc: data.len() as u8,
            data: buf,
        })
    }

    /// Engine-internal constructor: masks instead of failing because every caller builds the
    /// identifier from validated parts.
    pub(crate) const fn from_parts(id: u16, data: [u8; 8], dlc: u8) -> Self {
        Self {
            id: id & MAX_STANDARD_ID,
            dlc: if dlc > 8 { 8 } else { dlc },
            data,
        }
    }

    /// The 11-bit identifier.
    pub const fn id(&self) -> u16 {
        self.id
    }

    /// Data length code, 0..=8.
    pub const fn dlc(&self) -> u8 {
        self.dlc
    }

    /// The `dlc` data bytes.
    pub fn data(&self) -> &[u8] {
        self.data.get(..usize::from(self.dlc)).unwrap_or(&self.data)
    }

    /// All eight data bytes; bytes past the DLC are zero for frames built by this crate.
    pub const fn raw_data(&self) -> &[u8; 8] {
        &self.data
    }
}

/// The sink refused a frame (its queue is full).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SinkFull;

/// Where the engine puts outgoing frames (a TX queue drained by the CAN driver).
///
/// A refused TPDO or EMCY is retried by a later `poll`; any other refused frame is lost and
/// counted in [`Stats::tx_refused`](crate::Stats).
pub trait FrameSink {
    /// Queue `frame` for transmission.
    fn send(&mut self, frame: Frame) -> Result<(), SinkFull>;

    /// Discards every frame queued and not yet on the bus. A reset of communication or of the
    /// node calls it before the boot-up: what the node said before the reset must not arrive
    /// after it, and the boot-up must not wait behind it (nor be refused by a full queue).
    fn discard_pending(&mut self) {}
}

impl<const N: usize> FrameSink for heapless::Vec<Frame, N> {
    fn send(&mut self, frame: Frame) -> Result<(), SinkFull> {
        self.push(frame).map_err(|_| SinkFull)
    }

    fn discard_pending(&mut self) {
        self.clear();
    }
}

impl<const N: usize> FrameSink for heapless::Deque<Frame, N> {
    fn send(&mut self, frame: Frame) -> Result<(), SinkFull> {
        self.push_back(frame).map_err(|_| SinkFull)
    }

    fn discard_pending(&mut self) {
        self.clear();
    }
}

/// A CANopen node-ID, 1..=127.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct NodeId(u8);

/// The value is not a valid node-ID (1..=127).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct InvalidNodeId;

impl NodeId {
    /// Validates `id` (0 is the NMT broadcast address, not a node; 128.. do not fit 7 bits).
    pub const fn new(id: u8) -> Result<Self, InvalidNodeId> {
        if id >= 1 && id <= 127 {
            Ok(Self(id))
        } else {
            Err(InvalidNodeId)
        }
    }

    /// The raw node-ID.
    pub const fn get(self) -> u8 {
        self.0
    }

    /// The COB-ID `function_code + node-ID` of the pre-defined connection set.
    pub const fn cob_id(self, function_code: u16) -> u16 {
        function_code.wrapping_add(self.0 as u16) & MAX_STANDARD_ID
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_constructor_validates() {
        let f = Frame::new(0x7FF, &[1, 2, 3]).unwrap();
        assert_eq!((f.id(), f.dlc(), f.data()), (0x7FF, 3, &[1u8, 2, 3][..]));
        assert_eq!(f.raw_data(), &[1, 2, 3, 0, 0, 0, 0, 0]);
        assert_eq!(Frame::new(0x800, &[]), Err(FrameError::IdOutOfRange));
        assert_eq!(Frame::new(1, &[0; 9]), Err(FrameError::TooLong));
        assert_eq!(Frame::new(1, &[]).unwrap().data(), &[] as &[u8]);
    }

    #[test]
    fn node_ids() {
        assert_eq!(NodeId::new(0), Err(InvalidNodeId));
        assert_eq!(NodeId::new(128), Err(InvalidNodeId));
        assert_eq!(NodeId::new(127).unwrap().cob_id(cob::HEARTBEAT), 0x77F);
        assert_eq!(NodeId::new(1).unwrap().cob_id(cob::SDO_RX), 0x601);
    }
}
