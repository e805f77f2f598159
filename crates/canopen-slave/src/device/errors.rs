//! Error policy: the application's errors, the CAN controller's error states and overruns,
//! and heartbeat losses become EMCYs (0x1001 / 0x1003 record them); the queued EMCYs go out
//! while the node communicates.

use super::{Application, Device, Inner};
use crate::bus::{self, BusEvent};
use crate::emcy::{self, EmcyError};
use crate::frame::{Frame, FrameSink};
use crate::indicators::ErrorIndication;
use crate::nmt::NmtState;
use crate::storage::Storage;
use crate::time::Instant;

impl<S: Storage> Device<S> {
    /// Raises an error: recorded in 0x1001/0x1003 and announced by an EMCY at the next
    /// `poll` (not in Stopped, where only the record is kept). `info` are the five
    /// manufacturer-specific bytes. Raising an active code again does nothing.
    pub fn raise_error(
        &mut self,
        code: u16,
        register_bits: u8,
        info: [u8; 5],
    ) -> Result<(), EmcyError> {
        let transmit = self.inner.comm.state != NmtState::Stopped;
        self.inner
            .comm
            .emcy
            .raise(code, register_bits, info, transmit)
    }

    /// Clears an active error; returns whether it was active. Clearing the last one sends
    /// the error-reset EMCY (code 0x0000).
    pub fn clear_error(&mut self, code: u16) -> bool {
        let transmit = self.inner.comm.state != NmtState::Stopped;
        self.inner.comm.emcy.clear(code, transmit)
    }

    /// Raises and clears the EMCYs CiA 301 asks for when the CAN controller's error state
    /// changes: error passive is a condition (0x8120 raised, then cleared when it is over);
    /// a bus-off recovery is an event (0x8140 raised and cleared at once: the EMCY, then the
    /// error reset), and it ends error passive too. Warning and bus-off send nothing (the
    /// ERR LED shows them; nothing can be sent in bus-off anyway).
    pub fn on_bus_event(&mut self, event: BusEvent) {
        match event {
            BusEvent::ErrorPassive => {
                // An error already active or a full history only means no new frame.
                let _ = self.raise_error(
                    bus::EMCY_CAN_ERROR_PASSIVE,
                    emcy::register::COMMUNICATION,
                    [0; 5],
                );
            }
            BusEvent::ErrorActiveAgain => {
                self.clear_error(bus::EMCY_CAN_ERROR_PASSIVE);
            }
            BusEvent::BusOffRecovered => {
                // The recovery EMCY first, while 0x8120 still holds the error register, so
                // that the end of both is a single error reset.
                let code = bus::EMCY_BUS_OFF_RECOVERED;
                let raised = self
                    .raise_error(code, emcy::register::COMMUNICATION, [0; 5])
                    .is_ok();
                self.clear_error(bus::EMCY_CAN_ERROR_PASSIVE);
                if raised {
                    self.clear_error(code);
                }
            }
            BusEvent::WarningLimit | BusEvent::BusOff => {}
        }
    }

    /// Received frames were lost (controller or receive queue overrun): EMCY 0x8110, an
    /// event, raised and cleared at once.
    pub fn on_rx_overrun(&mut self) {
        self.error_event(bus::EMCY_CAN_OVERRUN);
    }

    /// An error that is over as soon as it is reported: the EMCY, then its clearing.
    fn error_event(&mut self, code: u16) {
        if self
            .raise_error(code, emcy::register::COMMUNICATION, [0; 5])
            .is_ok()
        {
            self.clear_error(code);
        }
    }

    /// 0x1001.
    pub fn error_register(&self) -> u8 {
        self.inner.comm.emcy.error_register()
    }

    /// What the ERR LED shows on account of the engine (heartbeat loss); the firmware adds
    /// its CAN controller's warning / bus-off conditions with `max`.
    pub fn error_indication(&self) -> ErrorIndication {
        if self.inner.comm.heartbeat.any_lost() {
            ErrorIndication::ErrorControlEvent
        } else {
            ErrorIndication::NoError
        }
    }
}

impl<S: Storage> Inner<S> {
    /// Consumer heartbeats that timed out: EMCY 0x8130 (the lost node-ID in its first
    /// manufacturer byte) and the application is told, once per loss.
    pub(super) fn check_heartbeats(&mut self, now: Instant, app: &mut dyn Application) {
        while let Some(lost) = self.comm.heartbeat.take_timeout(now) {
            warn!("heartbeat of node {=u8} lost", lost);
            let transmit = self.comm.state.communicating();
            // With the error list full the loss is still reported to the application.
            let _ = self.comm.emcy.raise(
                emcy::code::HEARTBEAT,
                emcy::register::COMMUNICATION,
                [lost, 0, 0, 0, 0],
                transmit,
            );
            self.heartbeat_lost = true;
            app.on_heartbeat_lost(lost);
        }
    }

    /// Ends a reported heartbeat loss once no consumer is in timeout any more: clears
    /// EMCY 0x8130 and tells the application. The one place where a loss ends, whatever
    /// ended it (the node's heartbeat, a rewrite of 0x1016, a reset of communication).
    pub(super) fn settle_heartbeat(&mut self, app: &mut dyn Application) {
        if !self.heartbeat_lost || self.comm.heartbeat.any_lost() {
            return;
        }
        self.heartbeat_lost = false;
        debug!("heartbeat consumers healthy again");
        let transmit = self.comm.state.communicating();
        self.comm.emcy.clear(emcy::code::HEARTBEAT, transmit);
        app.on_heartbeat_restored();
    }

    /// Sends the queued EMCYs the inhibit time allows (while communicating).
    pub(super) fn service_emcy(&mut self, now: Instant, tx: &mut dyn FrameSink) {
        if !self.comm.state.communicating() {
            return;
        }
        while let Some((id, payload)) = self.comm.emcy.next_frame(now) {
            let sent = self.emit(tx, Frame::from_parts(id, payload, 8));
            self.comm.emcy.sent(now, sent);
            if !sent {
                break;
            }
        }
    }
}
