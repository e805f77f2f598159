//! The boot decision across resets (docs/FIRMWARE-UPDATE.md, "Boot" and "Trial boot"): what
//! the two `HANDOFF` words say, what the loader does at a reset, and the request a master
//! sends in the listening window to keep the loader.
//!
//! The words live in SRAM outside every image's RAM, so they survive a system reset (the
//! watchdog, NRST, SYSRESETREQ) and are lost at a power-on. Each record is a word and its
//! complement, so that no other content (a power-on's random SRAM on a real chip, a half
//! written pair) reads as a record:
//! - the application's request to stay in the loader (`HANDOFF_REQUEST`, "LOAD"), written
//!   before its reset into the loader (0x1F51:1 = 0);
//! - a trial: the loader's count of the starts of the application that the application has
//!   not confirmed, written right before each start. The application clears the words once
//!   it is healthy on the bus. A count that reaches [`MAX_TRIAL_STARTS`] keeps the loader.
//!
//! Anything else (nothing, or a broken pair) is a fresh start: count 0.

use canopen_slave::frame::cob;
use canopen_slave::{Frame, NodeId};

use crate::layout::{is_handoff_request, HANDOFF_REQUEST};

/// Starts in a row the application may leave unconfirmed (a hang, a fault, a lock-up: each
/// ended by the watchdog) before the loader stays.
pub const MAX_TRIAL_STARTS: u8 = 3;
/// Word 0 of a trial record: "TRL" and the count in the low byte; word 1 is its complement.
pub const TRIAL_TAG: u32 = 0x5452_4C00;
/// The listening window before every start of the application, in milliseconds: a master
/// that sends [`is_rescue_request`]'s request meanwhile keeps the loader.
pub const LISTEN_MS: u16 = 100;

/// What the `HANDOFF` words hold.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum BootRecord {
    /// Nothing (power-on, a confirmed application, a broken pair).
    Fresh,
    /// The application asked to stay in the loader (0x1F51:1 = 0).
    StayRequest,
    /// The application was started this many times without confirming.
    Trial {
        /// Unconfirmed starts so far.
        starts: u8,
    },
}

impl BootRecord {
    /// Reads the two words.
    #[must_use]
    pub const fn decode(words: [u32; 2]) -> Self {
        if is_handoff_request(words) {
            return Self::StayRequest;
        }
        if words[1] == !words[0] && words[0] & !0xFF == TRIAL_TAG {
            // The low byte: the masks leave at most 8 bits.
            return Self::Trial {
                starts: (words[0] & 0xFF) as u8,
            };
        }
        Self::Fresh
    }

    /// The two words that say this.
    #[must_use]
    pub const fn encode(self) -> [u32; 2] {
        match self {
            Self::Fresh => [0, 0],
            Self::StayRequest => [HANDOFF_REQUEST, !HANDOFF_REQUEST],
            Self::Trial { starts } => {
                let word = TRIAL_TAG | starts as u32;
                [word, !word]
            }
        }
    }
}

/// Why the loader stays rather than starting the application.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum StayReason {
    /// The application asked (0x1F51:1 = 0).
    Requested,
    /// The slot holds no valid application.
    NoValidProgram,
    /// The application was started [`MAX_TRIAL_STARTS`] times and never confirmed.
    TrialFailed,
}

/// What the loader does at a reset.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Boot {
    /// Stays as a CANopen node.
    Stay(StayReason),
    /// Listens for [`LISTEN_MS`], then (unless a master asked it to stay) starts the
    /// application as start number `starts + 1` of its trial.
    Listen {
        /// Unconfirmed starts so far.
        starts: u8,
    },
}

impl Boot {
    /// The decision for `record`, with `valid` telling whether the slot holds a valid
    /// application (asked only when it matters: it costs a CRC over the image).
    pub fn decide(record: BootRecord, valid: impl FnOnce() -> bool) -> Self {
        match record {
            BootRecord::StayRequest => Self::Stay(StayReason::Requested),
            BootRecord::Trial { starts } if starts >= MAX_TRIAL_STARTS => {
                Self::Stay(StayReason::TrialFailed)
            }
            _ if !valid() => Self::Stay(StayReason::NoValidProgram),
            BootRecord::Trial { starts } => Self::Listen { starts },
            _ => Self::Listen { starts: 0 },
        }
    }

    /// What the words hold while the loader runs after this decision: a failed trial stays
    /// recorded (a reset node or NRST keeps the loader, a power-on starts a fresh trial);
    /// everything else is taken (a request is used once).
    #[must_use]
    pub const fn record_kept(self) -> BootRecord {
        match self {
            Self::Stay(StayReason::TrialFailed) => BootRecord::Trial {
                starts: MAX_TRIAL_STARTS,
            },
            _ => BootRecord::Fresh,
        }
    }

    /// The record to write right before the start that follows a window nobody used.
    #[must_use]
    pub const fn record_at_start(starts: u8) -> BootRecord {
        BootRecord::Trial {
            starts: starts.saturating_add(1),
        }
    }
}

/// Whether `frame` is the request that keeps the loader in its listening window: an SDO
/// expedited download of 0x1F51:1 (program control) = 0 ("stop", CiA 302-3) to `node`, as
/// any master writes it (`sdo[0x1F51][1].raw = 0`; the size indicated or not). Not an NMT
/// command: masters send those to every node at their own start-up.
#[must_use]
pub fn is_rescue_request(frame: &Frame, node: NodeId) -> bool {
    let data = frame.raw_data();
    frame.id() == node.cob_id(cob::SDO_RX)
        && frame.dlc() == 8
        // Client command specifier 1 (initiate download) with e = 1 (expedited).
        && data[0] & 0xE2 == 0x22
        && data[1..4] == [0x51, 0x1F, 0x01]
        && data[4] == 0
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn records_round_trip_and_anything_else_is_fresh() {
        for record in [
            BootRecord::Fresh,
            BootRecord::StayRequest,
            BootRecord::Trial { starts: 0 },
            BootRecord::Trial { starts: 3 },
            BootRecord::Trial { starts: 255 },
        ] {
            assert_eq!(BootRecord::decode(record.encode()), record);
        }
        let trial = BootRecord::Trial { starts: 2 }.encode();
        for broken in [
            [trial[0], 0],
            [0, trial[1]],
            [trial[0], !(TRIAL_TAG | 1)],
            [0xFFFF_FFFF, 0xFFFF_FFFF],
            [0x1234_5678, 0x9ABC_DEF0],
        ] {
            assert_eq!(BootRecord::decode(broken), BootRecord::Fresh, "{broken:x?}");
        }
    }
}
