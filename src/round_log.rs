//! The log lines of a `canopen` round: what the step function (`handwheel_device::Node`)
//! found worth reporting, in the firmware's words.

use defmt::{debug, error, info, warn};
use handwheel_device::{rate_switch::SYNC_LIMIT_MS, LogEvents};

use crate::can::bus::{BusEvent, ErrorCounters};

/// Prints `log`; `counters` are the controller's, read with the bus state in that round.
pub fn print(log: &LogEvents, counters: ErrorCounters) {
    if let Some((rate, at_boot)) = log.no_recessive_bits {
        let kbit = rate.kbit_per_second();
        if at_boot {
            error!(
                "CAN: no 11 recessive bits at {=u32} kbit/s within {=u32} ms of boot: \
                 waiting for the bus",
                kbit, SYNC_LIMIT_MS
            );
        } else {
            error!(
                "CAN: no 11 recessive bits at {=u32} kbit/s within {=u32} ms: off the bus \
                 until it is free",
                kbit, SYNC_LIMIT_MS
            );
        }
    }
    if log.on_bus {
        info!("CAN: on the bus");
    }
    if log.rest_learnt {
        debug!("wheel: rest learnt at standstill");
    }
    if let Some(selection) = log.selection {
        info!(
            "selection: axis {=u8}, x{=u8}",
            handwheel_core::Axis::option_value(selection.axis),
            selection.multiplier.factor()
        );
    }
    match log.bus {
        Some(e @ (BusEvent::BusOff | BusEvent::ErrorPassive)) => error!("CAN {}: {}", e, counters),
        Some(e @ BusEvent::WarningLimit) => warn!("CAN {}: {}", e, counters),
        Some(e @ (BusEvent::ErrorActiveAgain | BusEvent::BusOffRecovered)) => {
            info!("CAN {}: {}", e, counters)
        }
        None => {}
    }
    if log.rx_lost != 0 {
        warn!("CAN RX overrun: {=u32} frame(s) lost", log.rx_lost);
    }
    if let Some((new, total)) = log.illegal_transitions {
        warn!(
            "encoder: {=u32} illegal transition(s), {=u32} since boot",
            new, total
        );
    }
    if let Some(rate) = log.bit_rate {
        info!("LSS: bit rate now {=u32} kbit/s", rate.kbit_per_second());
    }
}
