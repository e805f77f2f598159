//! bxCAN error state: reading what the controller reports. What a change means (event,
//! EMCY, ERR LED) is decided by `canopen_slave::bus`.
//!
//! The link reads it (`CanLink::status`): bxCAN's `CAN_ESR` (`bxcan_port`).
//!
//! bxCAN interrupts when a flag is set (warning limit, error passive, bus-off), never when
//! it clears. The SCE interrupt wakes the CAN-side task at once on the way down; the way back
//! up is seen by that task re-reading the state on every wake, every
//! `handwheel_device::duties::RECOVERY_POLL_MS` while the controller is not error-active.

pub use canopen_slave::bus::{BusEvent, BusState};

/// Error counters and the last error code, for the log.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, defmt::Format)]
pub struct ErrorCounters {
    /// Transmit error counter.
    pub tec: u8,
    /// Receive error counter.
    pub rec: u8,
    /// Last error code: 0 none, 1 stuff, 2 form, 3 ack, 4 bit recessive, 5 bit dominant,
    /// 6 CRC, 7 set by software.
    pub lec: u8,
}
