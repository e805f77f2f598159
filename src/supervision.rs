//! What the CAN-side task watches between rounds: the controller's error state, lost
//! receive frames and the decoder's illegal transitions. Each change becomes a log line here
//! and, where CiA 301 asks for one, an EMCY request for the device.

use crate::can::bus::{self, BusEvent, BusState};

/// Counters as last seen, to report only what changed.
pub struct Supervision {
    bus: BusState,
    rx_overruns: u32,
    illegal_transitions: u32,
}

impl Supervision {
    /// Nothing seen yet; the controller starts error-active.
    pub const fn new() -> Self {
        Self {
            bus: BusState::ErrorActive,
            rx_overruns: 0,
            illegal_transitions: 0,
        }
    }

    /// The error state as last read.
    pub const fn bus_state(&self) -> BusState {
        self.bus
    }

    /// Re-reads the controller's error state; logs and returns a change worth an EMCY.
    /// `off_bus`: the controller is kept off the bus (a bit-rate switch that found no 11
    /// recessive bits, `handwheel_device::RateSwitch`), which counts as bus-off: the ERR LED
    /// is on, and its end is a recovery (EMCY 0x8140).
    pub fn check_bus(&mut self, off_bus: bool) -> Option<BusEvent> {
        let (mut state, counters) = bus::read_status();
        if off_bus {
            state = BusState::BusOff;
        }
        let event = canopen_slave::bus::transition(self.bus, state);
        match event {
            Some(e @ (BusEvent::BusOff | BusEvent::ErrorPassive)) => {
                defmt::error!("CAN {}: {}", e, counters)
            }
            Some(e @ BusEvent::WarningLimit) => defmt::warn!("CAN {}: {}", e, counters),
            Some(e @ (BusEvent::ErrorActiveAgain | BusEvent::BusOffRecovered)) => {
                defmt::info!("CAN {}: {}", e, counters)
            }
            None => {}
        }
        self.bus = state;
        event
    }

    /// Logs receive frames lost since the last call; `true` when there were any (EMCY 0x8110).
    pub fn check_rx_overruns(&mut self, total: u32) -> bool {
        let lost = total.wrapping_sub(self.rx_overruns);
        self.rx_overruns = total;
        if lost != 0 {
            defmt::warn!("CAN RX overrun: {=u32} frame(s) lost", lost);
        }
        lost != 0
    }

    /// Logs illegal quadrature transitions (missed edges) since the last call.
    pub fn check_encoder(&mut self, total: u32) {
        let new = total.wrapping_sub(self.illegal_transitions);
        self.illegal_transitions = total;
        if new != 0 {
            defmt::warn!(
                "encoder: {=u32} illegal transition(s), {=u32} since boot",
                new,
                total
            );
        }
    }
}

impl Default for Supervision {
    fn default() -> Self {
        Self::new()
    }
}
