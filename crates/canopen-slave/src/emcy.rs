//! Emergency producer (CiA 301 7.2.7): error register 0x1001, pre-defined error field
//! 0x1003, COB-ID 0x1014 and inhibit time 0x1015.

use crate::abort::SdoAbort;
use crate::cob_id::COB_INVALID;
use crate::frame::MAX_STANDARD_ID;
use crate::nmt::NmtState;
use crate::time::Instant;
use heapless::Vec;

/// Entries of the pre-defined error field (0x1003:01..).
pub const HISTORY: usize = 4;
/// Errors that can be active at the same time.
pub const ACTIVE_ERRORS: usize = 4;
/// EMCY frames waiting for the inhibit time to pass.
pub const QUEUE: usize = 4;

/// Error register (0x1001) bits.
pub mod register {
    /// Set while any error is active.
    pub const GENERIC: u8 = 1 << 0;
    /// Current.
    pub const CURRENT: u8 = 1 << 1;
    /// Voltage.
    pub const VOLTAGE: u8 = 1 << 2;
    /// Temperature.
    pub const TEMPERATURE: u8 = 1 << 3;
    /// Communication error (overrun, error state, heartbeat loss).
    pub const COMMUNICATION: u8 = 1 << 4;
    /// Device-profile specific.
    pub const DEVICE_PROFILE: u8 = 1 << 5;
    /// Manufacturer specific.
    pub const MANUFACTURER: u8 = 1 << 7;
}

/// Error codes the engine raises itself.
pub mod code {
    /// Heartbeat consumer timeout ("life guard error or heartbeat error").
    pub const HEARTBEAT: u16 = 0x8130;
    /// An RPDO's mapped values were refused by the dictionary or the application ("protocol
    /// error - generic": the frame was not processed, for a reason other than its length).
    pub const RPDO_REFUSED: u16 = 0x8200;
    /// An RPDO shorter than its mapping ("PDO not processed due to length error").
    pub const RPDO_SHORT: u16 = 0x8210;
    /// An RPDO longer than its mapping ("PDO length exceeded"); it was processed.
    pub const RPDO_LONG: u16 = 0x8220;
    /// Deadline monitoring: no RPDO within its event timer ("RPDO timeout").
    pub const RPDO_TIMEOUT: u16 = 0x8250;
}

/// Why an error could not be raised.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum EmcyError {
    /// 0x0000 means "error reset" and cannot be raised.
    ResetCode,
    /// [`ACTIVE_ERRORS`] errors are already active.
    TooManyErrors,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
struct ActiveError {
    code: u16,
    register: u8,
}

/// Emergency producer state.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub(crate) struct Emcy {
    cob_id: u32,
    inhibit_100us: u16,
    active: Vec<ActiveError, ACTIVE_ERRORS>,
    history: [u32; HISTORY],
    history_len: u8,
    /// FIFO; a Vec because four entries make shifting cheaper than a ring's code.
    queue: Vec<[u8; 8], QUEUE>,
    hold_until: Instant,
    overflow: u16,
}

impl Emcy {
    pub(crate) const fn new() -> Self {
        Self {
            cob_id: COB_INVALID,
            inhibit_100us: 0,
            active: Vec::new(),
            history: [0; HISTORY],
            history_len: 0,
            queue: Vec::new(),
            hold_until: Instant::ZERO,
            overflow: 0,
        }
    }

    /// 0x1001: the OR of the active errors' bits, plus the generic bit while any is active.
    pub(crate) fn error_register(&self) -> u8 {
        self.active
            .iter()
            .fold(0, |acc, e| acc | e.register | register::GENERIC)
    }

    /// EMCY frames lost because the queue was full.
    pub(crate) const fn overflow(&self) -> u16 {
        self.overflow
    }

    fn enqueue(&mut self, payload: [u8; 8]) {
        if self.queue.push(payload).is_err() {
            self.overflow = self.overflow.saturating_add(1);
        }
    }

    /// Records a new error; queues its EMCY if `transmit` (not in Stopped). Raising an
    /// error that is already active does nothing.
    pub(crate) fn raise(
        &mut self,
        code: u16,
        register_bits: u8,
        info: [u8; 5],
        transmit: bool,
    ) -> Result<(), EmcyError> {
        if code == 0 {
            return Err(EmcyError::ResetCode);
        }
        if self.active.iter().any(|e| e.code == code) {
            return Ok(());
        }
        self.active
            .push(ActiveError {
                code,
                register: register_bits,
            })
            .map_err(|_| EmcyError::TooManyErrors)?;
        // Newest first; the additional-information word carries the first two
        // manufacturer bytes (e.g. the lost node-ID of a heartbeat error).
        let [i0, i1, i2, i3, i4] = info;
        let [c0, c1] = code.to_le_bytes();
        // A rippling shift rather than `copy_within`, which would link a 1.6 KiB memmove.
        let mut carry = u32::from(code) | u32::from(u16::from_le_bytes([i0, i1])) << 16;
        for slot in &mut self.history {
            carry = core::mem::replace(slot, carry);
        }
        self.history_len = self.history_len.saturating_add(1).min(HISTORY as u8);
        let reg = self.error_register();
        info!("EMCY raised {=u16:#x} register {=u8:#x}", code, reg);
        if transmit {
            self.enqueue([c0, c1, reg, i0, i1, i2, i3, i4]);
        }
        Ok(())
    }

    /// Clears an active error; when it was the last one, queues the error-reset EMCY.
    pub(crate) fn clear(&mut self, code: u16, transmit: bool) -> bool {
        let Some(pos) = self.active.iter().position(|e| e.code == code) else {
            return false;
        };
        self.active.swap_remove(pos);
        info!("EMCY cleared {=u16:#x}", code);
        if self.active.is_empty() && transmit {
            self.enqueue([0, 0, self.error_register(), 0, 0, 0, 0, 0]);
        }
        true
    }

    /// Forgets errors and history (reset node: the application starts afresh).
    pub(crate) fn reset(&mut self) {
        self.active.clear();
        self.history_len = 0;
        self.queue.clear();
    }

    /// NMT state change: entering Stopped, where EMCY is not sent, drops queued frames.
    pub(crate) fn on_nmt_state(&mut self, next: NmtState) {
        if next == NmtState::Stopped {
            self.queue.clear();
        }
    }

    /// The next EMCY payload that may go out now, if any.
    pub(crate) fn next_frame(&mut self, now: Instant) -> Option<(u16, [u8; 8])> {
        if self.cob_id & COB_INVALID != 0 {
            // EMCY disabled by configuration: nothing will ever be sent.
            self.queue.clear();
            return None;
        }
        if now < self.hold_until {
            return None;
        }
        let payload = *self.queue.first()?;
        Some(((self.cob_id & u32::from(MAX_STANDARD_ID)) as u16, payload))
    }

    /// The frame from [`Emcy::next_frame`] was accepted (or, `sent == false`, refused).
    pub(crate) fn sent(&mut self, now: Instant, sent: bool) {
        if sent {
            // Drop the head: ripple every entry one place forward (no memmove), then the
            // last, now a duplicate, goes.
            let mut carry = [0; 8];
            for slot in self.queue.iter_mut().rev() {
                carry = core::mem::replace(slot, carry);
            }
            self.queue.pop();
            self.hold_until = now.add_100us(self.inhibit_100us);
        } else {
            self.hold_until = now.after_ms(1);
        }
    }

    /// When queued frames may go out.
    pub(crate) fn deadline(&self) -> Option<Instant> {
        (!self.queue.is_empty()).then_some(self.hold_until)
    }

    /// The raw 0x1014 entry.
    pub(crate) const fn cob_id(&self) -> u32 {
        self.cob_id
    }

    /// Reads 0x1003, 0x1014 or 0x1015.
    pub(crate) fn read(&self, index: u16, sub: u8) -> Result<u32, SdoAbort> {
        match (index, sub) {
            (0x1003, 0) => Ok(self.history_len.into()),
            (0x1003, n) if n > self.history_len => Err(SdoAbort::NoData),
            (0x1003, n) => usize::from(n)
                .checked_sub(1)
                .and_then(|i| self.history.get(i))
                .copied()
                .ok_or(SdoAbort::NoSubIndex),
            (0x1014, _) => Ok(self.cob_id),
            (0x1015, _) => Ok(self.inhibit_100us.into()),
            _ => Err(SdoAbort::NoObject),
        }
    }

    /// Checked write of 0x1003:00 (only 0, clearing the history) or 0x1015. 0x1014 is the
    /// engine's to check (its COB-ID must also be unique within the node), then `set`.
    pub(crate) fn write(&mut self, index: u16, sub: u8, v: u32) -> Result<(), SdoAbort> {
        match (index, sub) {
            (0x1003, 0) if v != 0 => return Err(SdoAbort::InvalidValue),
            (0x1003, 0) => self.history_len = 0,
            _ => self.set(index, v),
        }
        Ok(())
    }

    /// Unchecked write of 0x1014 / 0x1015 (defaults, stored parameters).
    pub(crate) fn set(&mut self, index: u16, v: u32) {
        match index {
            0x1014 => self.cob_id = v,
            0x1015 => self.inhibit_100us = v as u16,
            _ => {}
        }
    }
}
