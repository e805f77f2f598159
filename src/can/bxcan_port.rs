//! The board's CAN link: bxCAN bit timing, acceptance filters, the three transmit mailboxes
//! and receive FIFO 0.

use bxcan::filter::{ListEntry16, Mask16};
use bxcan::{Fifo, Interrupts, Mailbox};
use canopen_slave::RxFilter;
use handwheel_core::BitRate;

use super::bus::{BusState, ErrorCounters};
use super::frame::{self, standard_id};
use super::port::{Busy, CanLink, Received};
use super::{Frame, Mode};
use crate::board::CanInstance;
use crate::pac;

/// The configured controller.
pub type Bxcan = bxcan::Can<CanInstance>;

/// `CAN_BTR` timing bits for every rate of [`BitRate::ALL`](handwheel_core::BitRate::ALL)
/// (by code) at the 36 MHz APB1 clock: the board's table, which the loader programs too.
pub use handwheel_board::bit_timing::BTR_TABLE;

/// `CAN_BTR`'s mode bits, silent and loopback (RM0008 24.9.7); the rest are timing bits.
const BTR_MODE_BITS: u32 = 0xC000_0000;

/// The `CAN_BTR` timing bits for `rate`.
pub const fn btr(rate: BitRate) -> u32 {
    handwheel_board::bit_timing::btr(rate.code())
}

/// Configures bit timing, the acceptance filters for `filter` and interrupts, and asks the
/// controller to join the bus.
///
/// Returns at once: the controller joins by itself once it has seen 11 recessive bits on RX
/// (RM0008 24.4.4), at once on a silent bus, after the frame under way on a busy one, never
/// on a dominant one (no transceiver, a short). Until then frames wait in the mailboxes. The
/// firmware looks with [`CanPort::switch_bit_rate`](super::CanPort::switch_bit_rate) at the
/// same rate, which is done once the controller is on the bus, and holds the device back
/// meanwhile (`handwheel_device::Node::poll`, joining the bus at power-on).
pub fn start(instance: CanInstance, bit_rate: BitRate, filter: RxFilter, mode: Mode) -> Bxcan {
    let loopback = mode == Mode::SilentLoopback;
    let mut can = bxcan::Can::builder(instance)
        .set_bit_timing(btr(bit_rate))
        .set_loopback(loopback)
        .set_silent(loopback)
        .leave_disabled();
    set_filters(&mut can, filter);
    // FIFO 0 pending covers "full" too; the overrun interrupt makes a lost frame visible
    // even if the FIFO had been drained in between.
    can.enable_interrupts(
        Interrupts::TRANSMIT_MAILBOX_EMPTY
            | Interrupts::FIFO0_MESSAGE_PENDING
            | Interrupts::FIFO0_OVERRUN,
    );
    enable_status_interrupts();
    // Leaves sleep mode, to normal mode once the bus is seen idle; also sets ABOM: after
    // bus-off the controller rejoins on its own once it has seen 128 x 11 recessive bits.
    // `WouldBlock` only says that it has not joined yet.
    let _ = can.enable_non_blocking();
    can
}

/// Programs the acceptance filters to pass exactly what `filter` accepts; everything else
/// is dropped in hardware.
///
/// Bank 0 lists NMT, SYNC (wherever 0x1005 put it), our SDO request and LSS (0x7E5); an
/// unconfigured node's filter repeats NMT and LSS in the SYNC and SDO entries. Bank 1 passes every
/// heartbeat (0x700..0x77F) for the heartbeat consumer, which picks its producers itself, and
/// the second SDO server's requests (0x1201:1; a repeat of our SDO request while it is not
/// valid) as a mask that compares all 11 bits. Bank 2 lists RPDO1 (0x1400:1 while it is
/// received; a repeat of our SDO request otherwise), so that a master that moves it is
/// heard on the new identifier only.
/// Data frames only: RTR is not served. Reprogramming while running (RM0008 24.7.4: the
/// banks are deactivated in filter init mode) can miss a frame that arrives in those few
/// register writes; only a master's reconfiguration triggers it.
pub fn set_filters(can: &mut Bxcan, filter: RxFilter) {
    let data = |id: u16| ListEntry16::data_frames_with_id(standard_id(id));
    let (base, mask) = filter.heartbeats();
    let mut heartbeats = Mask16::frames_with_std_id(standard_id(base), standard_id(mask));
    heartbeats.data_frames_only();
    let mut filters = can.modify_filters();
    filters.clear();
    filters.enable_bank(
        0,
        Fifo::Fifo0,
        [
            data(filter.nmt()),
            data(filter.sync()),
            data(filter.sdo_request()),
            // LSS requests (CiA 305), for node-ID and bit-rate configuration.
            data(filter.lss()),
        ],
    );
    let mut second_sdo =
        Mask16::frames_with_std_id(standard_id(filter.second_sdo_request()), standard_id(0x7FF));
    second_sdo.data_frames_only();
    filters.enable_bank(1, Fifo::Fifo0, [heartbeats, second_sdo]);
    filters.enable_bank(2, Fifo::Fifo0, [data(filter.rpdo()); 4]);
}

impl CanLink for Bxcan {
    fn transmit(&mut self, frame: &Frame) -> Result<Option<Frame>, Busy> {
        match bxcan::Can::transmit(self, &frame::to_bxcan(frame)) {
            Ok(status) => Ok(status.dequeued_frame().and_then(frame::from_bxcan)),
            // Every pending mailbox outranks the frame: the TX interrupt resumes.
            Err(nb::Error::WouldBlock) => Err(Busy),
            Err(nb::Error::Other(never)) => match never {},
        }
    }

    fn receive(&mut self) -> Option<Received> {
        loop {
            return match bxcan::Can::receive(self) {
                Ok(frame) => match frame::from_bxcan(&frame) {
                    Some(frame) => Some(Received::Frame(frame)),
                    // Not a frame the device can take (the filters pass none such).
                    None => continue,
                },
                Err(nb::Error::WouldBlock) => None,
                // bxcan reports the overrun once and clears the flag; the frames still in
                // the FIFO come on the next calls.
                Err(nb::Error::Other(_overrun)) => Some(Received::Overrun),
            };
        }
    }

    fn acknowledge_transmit(&mut self) -> bool {
        let acknowledged = transmitted_ok();
        self.clear_tx_interrupt();
        acknowledged
    }

    fn idle(&self) -> bool {
        self.is_transmitter_idle()
    }

    fn abort_pending(&mut self) {
        // A mailbox whose frame is on the bus finishes it (RM0008 24.7.1: ABRQ has no effect
        // then); the others are emptied, and their interrupt counts as progress.
        for mailbox in [Mailbox::Mailbox0, Mailbox::Mailbox1, Mailbox::Mailbox2] {
            let _ = self.abort(mailbox);
        }
    }

    fn acknowledge_status(&mut self) {
        acknowledge_status_change();
    }

    fn status(&self) -> (BusState, ErrorCounters) {
        read_status()
    }

    fn set_rx_filter(&mut self, filter: RxFilter) {
        set_filters(self, filter);
    }

    /// The controller goes through initialisation mode (RM0008 24.4.1), keeping filters and
    /// interrupts, and rejoins at the new rate after 11 recessive bits (24.4.2). bxcan's
    /// `modify_config` and `enable` wait for the acknowledges, the second for the bus, which
    /// a dominant bus never gives, and neither bxcan nor the HAL has a step that does not
    /// wait; so this stays register glue, which only requests and looks, a step per call:
    /// - on the bus at another rate: request initialisation mode (INRQ), which the
    ///   controller enters after the frame under way;
    /// - in initialisation mode (INAK, INRQ): program BTR and request normal mode;
    /// - waiting to synchronise (INAK, INRQ clear; or, after `start`, SLAK with SLEEP clear):
    ///   nothing, the hardware joins by itself;
    /// - in normal mode at `rate`: done.
    fn switch_bit_rate(&mut self, rate: BitRate) -> bool {
        let timing = btr(rate);
        // SAFETY: the controller (`self`, the bxcan handle inside the CAN port resource) is
        // borrowed mutably, so nothing else accesses CAN_MCR, CAN_MSR or CAN_BTR meanwhile;
        // reading MSR has no side effects and MCR's INRQ and SLEEP are mode requests that
        // bxcan keeps no copy of.
        let can = unsafe { &*pac::CAN::ptr() };
        let msr = can.msr().read();
        if msr.inak().bit_is_set() {
            if can.mcr().read().inrq().bit_is_set() {
                // SAFETY: BTR is writable in initialisation mode (24.9.7), which INAK
                // confirms; the value keeps the mode bits (silent, loopback) and takes a
                // timing of `BTR_TABLE`, all within BTR's fields.
                can.btr()
                    .modify(|r, w| unsafe { w.bits(r.bits() & BTR_MODE_BITS | timing) });
                can.mcr().modify(|_, w| w.inrq().clear_bit());
            }
            return false;
        }
        if can.btr().read().bits() & !BTR_MODE_BITS == timing {
            if msr.slak().bit_is_clear() {
                return true;
            }
            if can.mcr().read().sleep().bit_is_clear() {
                // Woken (`start`), not yet synchronised.
                return false;
            }
        }
        can.mcr()
            .modify(|_, w| w.sleep().clear_bit().inrq().set_bit());
        false
    }
}

// The error-state flags live in `CAN_ESR`, and neither bxcan 0.8 nor stm32f1xx-hal has an
// accessor for them, nor for the `CAN_IER` bits that turn their changes into the
// status-change (SCE) interrupt (bxcan's `Interrupts` has ERRIE, not EWGIE, EPVIE, BOFIE), nor
// a way to acknowledge it (MSR.ERRI); the little register glue for these follows.

/// Reads the controller's error state.
fn read_status() -> (BusState, ErrorCounters) {
    // SAFETY: a read of CAN_ESR, which has no side effects (its only writable field, LEC, is
    // not written here); the peripheral's clock is on since `board::init`.
    let esr = unsafe { (*pac::CAN::ptr()).esr().read() };
    let state = if esr.boff().bit_is_set() {
        BusState::BusOff
    } else if esr.epvf().bit_is_set() {
        BusState::ErrorPassive
    } else if esr.ewgf().bit_is_set() {
        BusState::Warning
    } else {
        BusState::ErrorActive
    };
    let counters = ErrorCounters {
        tec: esr.tec().bits(),
        rec: esr.rec().bits(),
        lec: esr.lec().bits(),
    };
    (state, counters)
}

/// Whether a mailbox's last request ended with its frame acknowledged (TXOK, RM0008 24.9.3:
/// set when the frame went out and another node acknowledged it; clear after an abort, and
/// cleared with RQCP). bxcan clears the flags without saying.
fn transmitted_ok() -> bool {
    // SAFETY: a read of CAN_TSR, which has no side effects; called from the transmit task,
    // which holds the CAN port resource, before it clears the flags.
    let tsr = unsafe { (*pac::CAN::ptr()).tsr().read() };
    tsr.txok0().bit_is_set() || tsr.txok1().bit_is_set() || tsr.txok2().bit_is_set()
}

/// Routes warning, error-passive and bus-off changes to the SCE interrupt.
fn enable_status_interrupts() {
    // SAFETY: called while the `bxcan::Can` that owns the peripheral is borrowed mutably
    // (configuration), so no other code writes CAN_IER concurrently; the modify keeps the
    // interrupt bits bxcan set and adds only the error-status ones.
    unsafe {
        (*pac::CAN::ptr()).ier().modify(|_, w| {
            w.ewgie().set_bit();
            w.epvie().set_bit();
            w.bofie().set_bit();
            w.errie().set_bit()
        });
    }
}

/// Acknowledges a status-change interrupt (clears `ERRI`).
fn acknowledge_status_change() {
    // SAFETY: CAN_MSR's flags are write-one-to-clear; writing only ERRI clears that flag and
    // leaves WKUI, SLAKI and the mode request bits (in CAN_MCR) untouched. Called from the SCE
    // task, which holds the CAN port resource.
    unsafe {
        (*pac::CAN::ptr()).msr().write(|w| w.erri().set_bit());
    }
}
