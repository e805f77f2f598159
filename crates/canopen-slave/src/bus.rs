//! The CAN controller's fault confinement state as CiA 301 and CiA 303-3 see it: which
//! changes are events, which EMCY each one calls for ([`Device::on_bus_event`]), and what
//! the ERR LED shows. The firmware reads its controller's flags; the decisions are here.
//!
//! [`Device::on_bus_event`]: crate::Device::on_bus_event

use crate::indicators::ErrorIndication;

/// EMCY error code: CAN overrun, objects lost (CiA 301).
pub const EMCY_CAN_OVERRUN: u16 = 0x8110;
/// EMCY error code: CAN in error passive mode (CiA 301).
pub const EMCY_CAN_ERROR_PASSIVE: u16 = 0x8120;
/// EMCY error code: recovered from bus-off (CiA 301).
pub const EMCY_BUS_OFF_RECOVERED: u16 = 0x8140;

/// Fault confinement state, in order of severity.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum BusState {
    /// Both error counters below 96.
    ErrorActive,
    /// An error counter reached the warning limit (96).
    Warning,
    /// An error counter passed 127: the node may only send passive error flags.
    ErrorPassive,
    /// Transmit error counter passed 255: off the bus until the controller has seen
    /// 128 x 11 recessive bits.
    BusOff,
}

impl BusState {
    /// What the ERR LED shows for this state (CiA 303-3): a warning and error passive are a
    /// single flash, bus-off is on. Combine with the device's own with `max`.
    pub const fn indication(self) -> ErrorIndication {
        match self {
            Self::ErrorActive => ErrorIndication::NoError,
            Self::Warning | Self::ErrorPassive => ErrorIndication::WarningLimit,
            Self::BusOff => ErrorIndication::BusOff,
        }
    }
}

/// A change of error state worth a log line or an EMCY.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum BusEvent {
    /// Warning limit reached (log only; the ERR LED follows the state).
    WarningLimit,
    /// Entered error passive: EMCY 0x8120 raised.
    ErrorPassive,
    /// Left error passive for error active or warning: EMCY 0x8120 cleared.
    ErrorActiveAgain,
    /// Went bus-off: nothing can be sent.
    BusOff,
    /// Back on the bus after bus-off: 0x8120 is over too, and EMCY 0x8140 is sent.
    BusOffRecovered,
}

/// The event for a change of error state from `from` to `to`, if any.
pub const fn transition(from: BusState, to: BusState) -> Option<BusEvent> {
    use BusState::*;
    match (from, to) {
        (BusOff, BusOff) => None,
        (_, BusOff) => Some(BusEvent::BusOff),
        (BusOff, _) => Some(BusEvent::BusOffRecovered),
        (ErrorPassive, ErrorPassive) => None,
        (_, ErrorPassive) => Some(BusEvent::ErrorPassive),
        (ErrorPassive, _) => Some(BusEvent::ErrorActiveAgain),
        (ErrorActive, Warning) => Some(BusEvent::WarningLimit),
        _ => None,
    }
}
