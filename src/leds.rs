//! CiA 303-3 indicator patterns for the RUN and ERR LEDs.
//!
//! The patterns are a pure function of time. This module covers what the firmware knows by
//! itself: the controller's error state for ERR. The device's NMT state (RUN) and its error
//! control events (ERR double flash) come from the CANopen engine once it is integrated.

use crate::can::bus::BusState;

/// One CiA 303-3 pattern.
#[derive(Clone, Copy, Debug, PartialEq, Eq, defmt::Format)]
pub enum Pattern {
    /// Always off.
    Off,
    /// Always on.
    On,
    /// 2.5 Hz: 200 ms on, 200 ms off.
    Blinking,
    /// `n` flashes of 200 ms, 200 ms apart, then 1000 ms off.
    Flashes(u8),
}

impl Pattern {
    /// Whether the LED is lit at `now_ms`.
    pub const fn is_on(self, now_ms: u32) -> bool {
        match self {
            Self::Off => false,
            Self::On => true,
            Self::Blinking => now_ms % 400 < 200,
            Self::Flashes(n) => {
                let lit = 400 * n as u32;
                let t = now_ms % (lit + 800);
                t < lit && t % 400 < 200
            }
        }
    }
}

/// ERR pattern for the controller's error state: single flash at the warning limit (and in
/// error passive, which is past it), on while bus-off.
pub const fn err_pattern(bus: BusState) -> Pattern {
    match bus {
        BusState::ErrorActive => Pattern::Off,
        BusState::Warning | BusState::ErrorPassive => Pattern::Flashes(1),
        BusState::BusOff => Pattern::On,
    }
}
