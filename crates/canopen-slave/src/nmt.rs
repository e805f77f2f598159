//! NMT states and module-control commands (CiA 301 7.3.2).

use crate::frame::{Frame, NodeId};

/// The NMT state machine of a CANopen device, named as in CiA 301.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum NmtState {
    /// Before [`Device::start`](crate::Device::start) and while a reset is being carried out.
    Initialising,
    /// SDO, SYNC, EMCY, NMT and heartbeat; no PDOs.
    PreOperational,
    /// Everything.
    Operational,
    /// Only NMT and heartbeat.
    Stopped,
}

impl NmtState {
    /// The state byte of a heartbeat (0x00 is the boot-up message).
    pub const fn heartbeat_byte(self) -> u8 {
        match self {
            Self::Initialising => 0x00,
            Self::Stopped => 0x04,
            Self::Operational => 0x05,
            Self::PreOperational => 0x7F,
        }
    }

    /// SDO and EMCY are served in Pre-operational and Operational only.
    pub(crate) const fn communicating(self) -> bool {
        matches!(self, Self::PreOperational | Self::Operational)
    }
}

/// An NMT module-control command.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum NmtCommand {
    /// 0x01: enter Operational.
    StartRemoteNode,
    /// 0x02: enter Stopped.
    StopRemoteNode,
    /// 0x80: enter Pre-operational.
    EnterPreOperational,
    /// 0x81: reset application and communication, boot up again.
    ResetNode,
    /// 0x82: reset the communication objects, boot up again.
    ResetCommunication,
}

impl NmtCommand {
    /// Decodes a command specifier; unknown values are `None` (and ignored by the device).
    pub const fn from_byte(cs: u8) -> Option<Self> {
        match cs {
            0x01 => Some(Self::StartRemoteNode),
            0x02 => Some(Self::StopRemoteNode),
            0x80 => Some(Self::EnterPreOperational),
            0x81 => Some(Self::ResetNode),
            0x82 => Some(Self::ResetCommunication),
            _ => None,
        }
    }

    /// The command specifier on the wire.
    pub const fn byte(self) -> u8 {
        match self {
            Self::StartRemoteNode => 0x01,
            Self::StopRemoteNode => 0x02,
            Self::EnterPreOperational => 0x80,
            Self::ResetNode => 0x81,
            Self::ResetCommunication => 0x82,
        }
    }

    /// The command in `frame` if it is an NMT frame (id 0, DLC 2) addressed to `node` or to
    /// all nodes (node-ID 0).
    #[must_use]
    pub fn parse(frame: &Frame, node: NodeId) -> Option<Self> {
        if frame.id() != crate::frame::cob::NMT {
            return None;
        }
        match *frame.data() {
            [cs, target] if target == 0 || target == node.get() => Self::from_byte(cs),
            _ => None,
        }
    }

    /// The NMT frame carrying this command to `target` (0 = all nodes); handy for tests and
    /// for a firmware that also acts as a minimal master.
    pub fn frame(self, target: u8) -> Frame {
        Frame::from_parts(
            crate::frame::cob::NMT,
            [self.byte(), target, 0, 0, 0, 0, 0, 0],
            2,
        )
    }
}
