//! bxCAN error state: reading what the controller reports. What a change means (event,
//! EMCY, ERR LED) is decided by `canopen_slave::bus`.
//!
//! The error-state flags live in `CAN_ESR`, and neither bxcan 0.8 nor stm32f1xx-hal has an
//! accessor for them, nor for the `CAN_IER` bits that turn their changes into the
//! status-change (SCE) interrupt (bxcan's `Interrupts` has ERRIE, not EWGIE, EPVIE, BOFIE),
//! nor a way to acknowledge it (MSR.ERRI); the little register glue for these is here.
//!
//! bxCAN interrupts when a flag is set (warning limit, error passive, bus-off), never when
//! it clears. The SCE interrupt wakes the CAN-side task at once on the way down; the way back
//! up is seen by that task re-reading the state on every wake, every
//! `handwheel_device::duties::RECOVERY_POLL_MS` while the controller is not error-active.

#[cfg(not(feature = "qemu"))]
use crate::pac;

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

/// Reads the controller's error state.
#[cfg(not(feature = "qemu"))]
pub fn read_status() -> (BusState, ErrorCounters) {
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

/// The QEMU variant's SLCAN link has no error counters: it is always error-active.
#[cfg(feature = "qemu")]
pub fn read_status() -> (BusState, ErrorCounters) {
    let counters = ErrorCounters {
        tec: 0,
        rec: 0,
        lec: 0,
    };
    (BusState::ErrorActive, counters)
}

/// Routes warning, error-passive and bus-off changes to the SCE interrupt.
#[cfg(not(feature = "qemu"))]
pub(super) fn enable_status_interrupts() {
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
#[cfg(not(feature = "qemu"))]
pub(super) fn acknowledge_status_change() {
    // SAFETY: CAN_MSR's flags are write-one-to-clear; writing only ERRI clears that flag and
    // leaves WKUI, SLAKI and the mode request bits (in CAN_MCR) untouched. Called from the SCE
    // task, which holds the CAN port resource.
    unsafe {
        (*pac::CAN::ptr()).msr().write(|w| w.erri().set_bit());
    }
}
