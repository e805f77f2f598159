//! Detents to feed: the cumulative feed position and the paper's unit-step backlog.
//!
//! It belongs to the CAN side alone: the detents come from the edge interrupt's channel
//! (taken in by [`LinkedWheel`](crate::LinkedWheel) before every access), the position, the
//! unit steps and the master's commands are the CAN side's; so it is a plain struct.
//!
//! Safety rules, all enforced here rather than in the firmware:
//! - the position moves only while feed is enabled and an axis is selected; turning the
//!   wheel otherwise is counted ([`FeedAccumulator::ignored_detents`]) and never becomes feed;
//! - a change of axis or multiplier, a disable and a stop (master lost, NMT state change)
//!   discard pending unit steps and start a new selection epoch, so motion meant for one axis
//!   or scale is never delivered to another;
//! - every epoch change closes the old epoch in the [`FeedOutbox`]: its final state goes out
//!   as a feed record before anything of the new epoch, however long the bus is blocked;
//! - a stop also disables feed: after the master comes back it must enable again;
//! - a change of the master's session (object 0x2002; ended by the device when the outbox's
//!   pace runs out, and by resets and configuration writes in the device) starts a new epoch
//!   and disables the feed, so no record of one session carries motion enabled in another;
//! - the unit-step backlog is bounded: steps beyond the bound are dropped and flagged, so
//!   run-on after the wheel stops can never exceed `bound x pacing`.
//!
//! It also knows when a feed record is due: every change of what a record carries (the
//! position, a status bit, the selection, the enable, the session, an epoch, more in the
//! outbox to send) marks one due inside it, as CANopenNode's `OD_requestTPDO` or zencan's
//! event flag would, and the device takes the mark when it requests TPDO1
//! ([`FeedAccumulator::take_record_due`]).

use crate::feed::{FeedState, FeedStatus, UnitStep};
use crate::outbox::FeedOutbox;
use crate::pdo::FeedRecord;
use crate::selector::{Multiplier, Selection};

/// Default bound of the unit-step backlog.
///
/// At the default TPDO inhibit time of 2 ms the backlog drains at most 500 steps/s, so 40
/// pending steps are at most 80 ms of run-on after the wheel stops. That stays under the
/// 100 ms an operator perceives as "the machine kept going" and leaves 20 ms for bus
/// arbitration and the controller's own cycle.
pub const DEFAULT_STEP_BACKLOG: u16 = 40;

/// Why the feed was stopped from outside.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum StopReason {
    /// The master's heartbeat timed out.
    MasterLost,
    /// The device left Operational (NMT stop, pre-operational or reset).
    NotOperational,
    /// The device's frames waited for the bus too long: what it reports would arrive late.
    TransmitBlocked,
}

/// The feed accumulator.
#[derive(Clone, Debug, Hash)]
pub struct FeedAccumulator {
    enabled: bool,
    unit_steps: bool,
    selection: Selection,
    position: i32,
    epoch: u8,
    /// The master's session (0 = none).
    session: u8,
    /// Flags latched in the current epoch (plus `MASTER_LOST`, latched until enabled).
    latched: FeedStatus,
    pending_steps: i32,
    backlog_bound: i32,
    ignored_detents: u32,
    dropped_steps: u32,
    outbox: FeedOutbox,
    /// What a record carries changed since the device last requested one.
    record_due: bool,
    /// The nonce a master last wrote to the sequence probe (object 0x2033).
    probe_nonce: u16,
    /// The key the session's master wrote (object 0x2034; 0 = none): it belongs to the
    /// session and goes with it.
    session_key: u16,
}

/// Why a write that belongs to a session was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[must_use]
pub enum SessionRefusal {
    /// No session is open: a key has nothing to belong to.
    NoSession,
    /// The probe carries a key that is not the session's: its master's session is not the
    /// one open here (ended, or opened again by someone else, in this power life or a new
    /// one).
    WrongKey,
}

/// The nonce's bits in the sequence probe (object 0x2033).
pub const PROBE_NONCE_MASK: u32 = 0x1FFF;

impl Default for FeedAccumulator {
    fn default() -> Self {
        Self::new()
    }
}

impl FeedAccumulator {
    /// Disabled, no axis, x1, position 0, backlog bound [`DEFAULT_STEP_BACKLOG`].
    pub const fn new() -> Self {
        Self {
            enabled: false,
            unit_steps: false,
            selection: Selection {
                axis: None,
                multiplier: Multiplier::X1,
            },
            position: 0,
            epoch: 0,
            session: 0,
            latched: FeedStatus::empty(),
            pending_steps: 0,
            backlog_bound: DEFAULT_STEP_BACKLOG as i32,
            ignored_detents: 0,
            dropped_steps: 0,
            outbox: FeedOutbox::new(),
            record_due: false,
            probe_nonce: 0,
            session_key: 0,
        }
    }

    /// Sets the unit-step backlog bound; 0 is rejected (the unit-step mode could never send).
    #[must_use = "a rejected bound leaves the previous one in force"]
    pub fn set_backlog_bound(&mut self, bound: u16) -> bool {
        if bound == 0 {
            return false;
        }
        self.backlog_bound = i32::from(bound);
        if self.pending_steps.abs() > self.backlog_bound {
            self.pending_steps = self.backlog_bound * self.pending_steps.signum();
        }
        true
    }

    /// Adds detents from the decoder: the position moves (a record is due), or, disabled or
    /// without an axis, they are counted as ignored (a record is due the first time).
    ///
    /// A wrapping difference of the edge's detent total: any count, either sign.
    #[inline]
    pub fn add_detents(&mut self, detents: i32) {
        if detents == 0 {
            return;
        }
        if !self.takes_motion() {
            self.ignored_detents = self.ignored_detents.wrapping_add(detents.unsigned_abs());
            self.latch(FeedStatus::IGNORED_MOTION);
            return;
        }
        let units = detents.wrapping_mul(i32::from(self.selection.multiplier.factor()));
        self.position = self.position.wrapping_add(units);
        self.record_due = true;
        if self.unit_steps {
            // `units` is at most |detents| x 100 and the backlog at most 65535: no overflow
            // for any detent count the decoder can deliver between two reads.
            let wanted = self.pending_steps.saturating_add(units);
            // max/min rather than clamp: clamp's min <= max assertion would link core::fmt
            // into the firmware, and the bound is positive by construction.
            let kept = wanted.max(-self.backlog_bound).min(self.backlog_bound);
            if kept != wanted {
                let dropped = wanted.abs_diff(kept);
                self.dropped_steps = self.dropped_steps.wrapping_add(dropped);
                self.latch(FeedStatus::STEPS_DROPPED);
            }
            self.pending_steps = kept;
        }
    }

    /// Whether a detent taken in now moves the position: the feed is enabled and an axis is
    /// selected. The one rule [`FeedAccumulator::add_detents`] follows; whatever else keeps
    /// motion off (NMT state, master loss, a blocked transmit path, the session) does so by
    /// disabling the feed. The device shows it as "jog live" (object 0x2036 and its LED).
    #[inline]
    pub const fn takes_motion(&self) -> bool {
        self.enabled && self.selection.axis.is_some()
    }

    /// Notes an illegal quadrature transition (a status bit, latched for the epoch).
    pub fn note_encoder_error(&mut self) {
        self.latch(FeedStatus::ENCODER_ERROR);
    }

    /// Feed enable (object 0x2000). Any change starts a new epoch; disabling discards pending
    /// steps.
    pub fn set_enabled(&mut self, enabled: bool) {
        if enabled == self.enabled {
            return;
        }
        let before = self.state();
        self.enabled = enabled;
        if enabled {
            self.latched.remove(FeedStatus::MASTER_LOST);
        }
        self.new_epoch(before);
    }

    /// Unit-step (paper) mode on or off (object 0x2001). Any change starts a new epoch.
    pub fn set_unit_step_mode(&mut self, on: bool) {
        if on == self.unit_steps {
            return;
        }
        let before = self.state();
        self.unit_steps = on;
        self.new_epoch(before);
    }

    /// The debounced selector state. A change of axis or multiplier starts a new epoch;
    /// returns whether it changed (the unit step prepared for the old one is withdrawn).
    pub fn set_selection(&mut self, selection: Selection) -> bool {
        if selection == self.selection {
            return false;
        }
        let before = self.state();
        self.selection = selection;
        self.new_epoch(before);
        true
    }

    /// Stops the feed from outside: disables it and discards pending steps, as a disable
    /// does.
    pub fn stop(&mut self, reason: StopReason) {
        // Disabled means no pending steps (disabling discards them, and nothing is added
        // while disabled), so disabling is all a stop has to do. It comes first: the epoch
        // it closes ended enabled, without the loss (never both in one record).
        self.set_enabled(false);
        if reason != StopReason::NotOperational {
            self.latch(FeedStatus::MASTER_LOST);
        }
    }

    /// The master's session (object 0x2002): 0 ends it, 1..=7 opens one (larger values keep
    /// their low three bits). A change starts a new epoch and disables the feed, so that
    /// records of the new session never carry motion enabled under the old one.
    pub fn set_session(&mut self, session: u8) {
        let session = session & 0b111;
        if session == self.session {
            return;
        }
        let before = self.state();
        self.enabled = false;
        self.session = session;
        self.session_key = 0;
        self.new_epoch(before);
    }

    /// The session's key (object 0x2034), written by the master that opened the session
    /// right after it: the probe's writes must carry it from then on
    /// ([`FeedAccumulator::write_probe`]). It is 0 again whenever the session changes or
    /// ends, so a session another master opened (with the same token, after a power cycle
    /// the first master never saw, say) never has the first master's key.
    pub fn set_session_key(&mut self, key: u16) -> Result<(), SessionRefusal> {
        if self.session == 0 {
            return Err(SessionRefusal::NoSession);
        }
        self.session_key = key;
        Ok(())
    }

    /// The master's session (object 0x2002).
    pub const fn session(&self) -> u8 {
        self.session
    }

    /// Time passes (`now_us`, the device's clock in µs): the outbox's pace refills.
    pub fn tick(&mut self, now_us: u64) {
        self.outbox.refill(now_us);
    }

    /// A number was taken beyond the outbox's pace: the session ends (a new epoch, feed
    /// off), so that no later record is taken as part of it.
    fn end_session_if_overdrawn(&mut self) {
        if !self.outbox.take_overdrawn() || self.session == 0 {
            return;
        }
        let before = self.state();
        self.enabled = false;
        self.session = 0;
        self.session_key = 0;
        self.new_epoch(before);
    }

    /// Takes the next unit step of the backlog, moving it one step toward zero.
    #[must_use = "a taken step that is not sent is lost motion"]
    pub fn take_unit_step(&mut self) -> Option<UnitStep> {
        let axis = self.selection.axis?;
        if !self.enabled || self.pending_steps == 0 {
            return None;
        }
        let forward = self.pending_steps > 0;
        self.pending_steps -= self.pending_steps.signum();
        Some(UnitStep { axis, forward })
    }

    /// The one place an epoch ends: `before` is its final state. The next record carries
    /// the new epoch: it is due.
    fn new_epoch(&mut self, before: FeedState) {
        self.outbox.close_epoch(before);
        self.epoch = self.epoch.wrapping_add(1);
        self.record_due = true;
        self.pending_steps = 0;
        self.latched = self.latched.intersection(FeedStatus::MASTER_LOST);
        // A loss the closing took beyond the pace: the new epoch starts without the session
        // (no record of it was made yet, so no further epoch is needed).
        if self.outbox.take_overdrawn() && self.session != 0 {
            self.session = 0;
            self.session_key = 0;
            self.enabled = false;
        }
    }

    /// Latches a status bit; a record is due if it was not latched yet.
    fn latch(&mut self, flag: FeedStatus) {
        self.record_due |= !self.latched.contains(flag);
        self.latched.insert(flag);
    }

    /// Whether a feed record is due: what a record carries changed since the device last
    /// took the mark ([`FeedAccumulator::take_record_due`]).
    pub const fn record_due(&self) -> bool {
        self.record_due
    }

    /// Whether a feed record is due ([`FeedAccumulator::record_due`]); clears the mark. The
    /// device takes it when it requests TPDO1.
    #[must_use = "a changed feed needs a TPDO"]
    pub fn take_record_due(&mut self) -> bool {
        core::mem::take(&mut self.record_due)
    }

    /// A record is due although nothing it carries changed: the device's parameters did
    /// (a record made after the master's write follows it).
    pub fn request_record(&mut self) {
        self.record_due = true;
    }

    /// Cumulative feed position in multiplied units (object 0x6004), wrapping.
    pub const fn position(&self) -> i32 {
        self.position
    }

    /// The selection in force.
    pub const fn selection(&self) -> Selection {
        self.selection
    }

    /// Selection epoch (object 0x2010 sub 3): steps on every axis, multiplier, enable, mode
    /// change and stop, wrapping.
    pub const fn epoch(&self) -> u8 {
        self.epoch
    }

    /// Whether feed is enabled.
    pub const fn enabled(&self) -> bool {
        self.enabled
    }

    /// Whether the unit-step (paper) mode is on.
    pub const fn unit_step_mode(&self) -> bool {
        self.unit_steps
    }

    /// Status flags of the feed record (bits 0-4 of object 0x2030; [`FeedState`] adds the
    /// epoch bits).
    pub fn status(&self) -> FeedStatus {
        let mut status = self.latched;
        if self.enabled {
            status.insert(FeedStatus::ENABLED);
        }
        status
    }

    /// What a feed record sent now would say.
    pub fn state(&self) -> FeedState {
        FeedState {
            position: self.position,
            axis: self.selection.axis,
            multiplier: self.selection.multiplier,
            status: self.status(),
            epoch: self.epoch,
            session: self.session,
        }
    }

    /// What the next feed record carries: the oldest closed epoch's final state the outbox
    /// holds, else the present state.
    pub fn record_to_send(&self) -> FeedState {
        self.outbox.next(self.state())
    }

    /// The sequence number the next feed record carries (object 0x2031).
    pub const fn record_sequence(&self) -> u16 {
        self.outbox.sequence()
    }

    /// The session's key (object 0x2034, write-only on the bus; 0 = none).
    pub const fn session_key(&self) -> u16 {
        self.session_key
    }

    /// A master's write of the sequence probe (object 0x2033): the nonce in its low 13 bits,
    /// a session key in bits 16-31 (0: none, as any master may probe). A key that is not the
    /// open session's key is refused and changes nothing: the master learns that its session
    /// is gone although the token it reads may be its own.
    pub fn write_probe(&mut self, value: u32) -> Result<(), SessionRefusal> {
        let key = (value >> 16) as u16;
        if key != 0 && key != self.session_key {
            return Err(SessionRefusal::WrongKey);
        }
        self.probe_nonce = (value & PROBE_NONCE_MASK) as u16;
        Ok(())
    }

    /// The sequence probe (object 0x2033): bits 16-31 the sequence number the next record
    /// carries, bits 13-15 the session, bits 0-12 the nonce last written. A master that
    /// writes a nonce of its own and then reads it back here with its session knows that
    /// every record numbered from bits 16-31 on was made after its write reached the device,
    /// so after it sent the write: a date for records that a gateway may have held, without
    /// a clock in the record.
    pub const fn sequence_probe(&self) -> u32 {
        (self.outbox.sequence() as u32) << 16
            | (self.session as u32) << 13
            | self.probe_nonce as u32
    }

    /// The next feed record, one consistent snapshot: what [`FeedAccumulator::record_to_send`]
    /// says and the sequence number it carries. TPDO1 is built from it, encoded by
    /// [`FeedRecord::to_bytes`].
    pub fn record(&self) -> FeedRecord {
        FeedRecord {
            state: self.record_to_send(),
            sequence: self.outbox.sequence(),
        }
    }

    /// The feed record `sent` (taken with [`FeedAccumulator::record`]) went out. Another
    /// one is due if the outbox holds more or the present state differs from it.
    pub fn record_sent(&mut self, sent: FeedState) {
        let live = self.state();
        self.record_due |= self.outbox.sent(sent, live);
        self.end_session_if_overdrawn();
    }

    /// Feed records may flow (the device entered Operational): epochs that end from now on
    /// are held until their final state is sent.
    pub fn start_records(&mut self) {
        self.outbox.start();
        self.end_session_if_overdrawn();
    }

    /// Feed records stop (the device left Operational): the closed epochs not sent yet are
    /// dropped, their motion reaches no axis, and the sequence number shows the gap.
    pub fn stop_records(&mut self) {
        self.outbox.stop();
        self.end_session_if_overdrawn();
    }

    /// A mutant of [`FeedAccumulator::stop_records`] for the feed checker's mutation tests
    /// (see [`FeedOutbox::mutant_stop_keeping_held`]).
    #[cfg(feature = "mutants")]
    #[doc(hidden)]
    pub fn mutant_stop_records_keeping_held(&mut self) {
        self.outbox.mutant_stop_keeping_held();
    }

    /// Reset node: back to power-on values, except what lets the host tell that a reset
    /// happened: the selection (hardware state) stays, the epoch steps and the record
    /// sequence goes on with a break ([`FeedOutbox::break_continuity`]), so that the first
    /// record after the reset never continues one from before it. The session ends, and a
    /// record is due (it would carry all that).
    pub fn reset(&mut self) {
        let selection = self.selection;
        let epoch = self.epoch.wrapping_add(1);
        let mut outbox = core::mem::take(&mut self.outbox);
        outbox.stop();
        outbox.break_continuity();
        // Numbers the break took beyond the pace belong to no session: there is none now.
        let _ = outbox.take_overdrawn();
        *self = Self::new();
        self.selection = selection;
        self.epoch = epoch;
        self.outbox = outbox;
        self.record_due = true;
    }

    /// Records that were handed out may not reach the bus (the transmit path discarded them):
    /// nothing after this continues what came before.
    pub fn break_records(&mut self) {
        self.outbox.break_continuity();
        self.end_session_if_overdrawn();
    }

    /// The outbox, for diagnostics.
    pub const fn outbox(&self) -> &FeedOutbox {
        &self.outbox
    }

    /// Another pace of the record sequence ([`FeedOutbox::set_pace`]), for a checker that
    /// narrows the sequence. The firmware never calls it.
    pub fn set_sequence_pace(&mut self, pace: crate::outbox::SequencePace) {
        self.outbox.set_pace(pace);
    }

    /// Runs the pace bug `mutant` from now on ([`FeedOutbox::set_pace_mutant`]), for the feed
    /// checker's mutation tests.
    #[cfg(feature = "mutants")]
    #[doc(hidden)]
    pub fn mutant_set_pace(&mut self, mutant: Option<crate::outbox::PaceMutant>) {
        self.outbox.set_pace_mutant(mutant);
    }

    /// Signed unit steps waiting to be sent.
    pub const fn pending_steps(&self) -> i32 {
        self.pending_steps
    }

    /// The backlog bound in unit steps.
    pub const fn backlog_bound(&self) -> u16 {
        self.backlog_bound as u16
    }

    /// Detents turned while disabled or without an axis, wrapping.
    pub const fn ignored_detents(&self) -> u32 {
        self.ignored_detents
    }

    /// Unit steps dropped at the backlog bound, wrapping.
    pub const fn dropped_steps(&self) -> u32 {
        self.dropped_steps
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::selector::Axis;

    fn active(axis: Axis, multiplier: Multiplier) -> FeedAccumulator {
        let mut acc = FeedAccumulator::new();
        assert!(acc.set_selection(Selection {
            axis: Some(axis),
            multiplier
        }));
        assert!(marks(&mut acc, |a| a.set_enabled(true)));
        acc
    }

    /// Runs `f` on `acc` and says whether it marked a record due.
    fn marks(acc: &mut FeedAccumulator, f: impl FnOnce(&mut FeedAccumulator)) -> bool {
        let _ = acc.take_record_due();
        f(acc);
        acc.take_record_due()
    }

    fn drain(acc: &mut FeedAccumulator) -> (usize, i32) {
        let mut n = 0;
        let mut net = 0;
        while let Some(step) = acc.take_unit_step() {
            n += 1;
            net += if step.forward { 1 } else { -1 };
        }
        (n, net)
    }

    #[test]
    fn position_moves_by_detents_times_multiplier() {
        let mut acc = active(Axis::X, Multiplier::X10);
        assert!(marks(&mut acc, |a| a.add_detents(3)));
        assert!(marks(&mut acc, |a| a.add_detents(-1)));
        assert_eq!(acc.position(), 20);
        assert!(acc.set_selection(Selection {
            axis: Some(Axis::X),
            multiplier: Multiplier::X100
        }));
        assert!(marks(&mut acc, |a| a.add_detents(-2)));
        assert_eq!(acc.position(), -180);
    }

    #[test]
    fn no_detents_is_no_change() {
        let mut acc = active(Axis::X, Multiplier::X1);
        assert!(!marks(&mut acc, |a| a.add_detents(0)));
        assert_eq!(acc.position(), 0);
    }

    #[test]
    fn disabled_turning_is_counted_but_never_feed() {
        let mut acc = FeedAccumulator::new();
        assert!(acc.set_selection(Selection {
            axis: Some(Axis::Y),
            multiplier: Multiplier::X100
        }));
        assert!(
            marks(&mut acc, |a| a.add_detents(5)),
            "first ignored motion latches a status bit"
        );
        assert!(
            !marks(&mut acc, |a| a.add_detents(-2)),
            "already latched: no new frame needed"
        );
        assert_eq!(acc.position(), 0);
        assert_eq!(acc.ignored_detents(), 7);
        assert!(acc.status().contains(FeedStatus::IGNORED_MOTION));
        assert!(!acc.status().contains(FeedStatus::ENABLED));
    }

    #[test]
    fn no_axis_turning_is_counted_but_never_feed() {
        let mut acc = FeedAccumulator::new();
        assert!(marks(&mut acc, |a| a.set_enabled(true)));
        assert!(marks(&mut acc, |a| a.add_detents(4)));
        assert_eq!(acc.position(), 0);
        assert_eq!(acc.ignored_detents(), 4);
    }

    #[test]
    fn position_wraps_at_i32_limits() {
        let mut acc = active(Axis::Z, Multiplier::X100);
        acc.position = i32::MAX - 50;
        assert!(marks(&mut acc, |a| a.add_detents(1)));
        assert_eq!(acc.position(), i32::MIN + 49);
        assert!(marks(&mut acc, |a| a.add_detents(-1)));
        assert_eq!(acc.position(), i32::MAX - 50);
        // The host's delta across the wrap is still +100.
        let before = i32::MAX - 50;
        let after = before.wrapping_add(100);
        assert_eq!(after.wrapping_sub(before), 100);
    }

    #[test]
    fn every_selection_change_bumps_epoch_and_discards_steps() {
        let mut acc = active(Axis::X, Multiplier::X1);
        assert!(marks(&mut acc, |a| a.set_unit_step_mode(true)));
        let epoch = acc.epoch();
        acc.add_detents(5);
        assert_eq!(acc.pending_steps(), 5);
        assert!(acc.set_selection(Selection {
            axis: Some(Axis::Y),
            multiplier: Multiplier::X1
        }));
        assert_eq!(
            (acc.pending_steps(), acc.epoch()),
            (0, epoch.wrapping_add(1))
        );

        acc.add_detents(5);
        assert!(acc.set_selection(Selection {
            axis: Some(Axis::Y),
            multiplier: Multiplier::X10
        }));
        assert_eq!(
            (acc.pending_steps(), acc.epoch()),
            (0, epoch.wrapping_add(2))
        );

        assert!(
            !acc.set_selection(acc.selection()),
            "same selection is no change"
        );
        assert_eq!(acc.epoch(), epoch.wrapping_add(2));
    }

    #[test]
    fn disable_discards_steps_and_stops_feed() {
        let mut acc = active(Axis::X, Multiplier::X10);
        assert!(marks(&mut acc, |a| a.set_unit_step_mode(true)));
        acc.add_detents(2);
        assert_eq!(acc.pending_steps(), 20);
        let epoch = acc.epoch();
        assert!(marks(&mut acc, |a| a.set_enabled(false)));
        assert_eq!(acc.pending_steps(), 0);
        assert_eq!(acc.epoch(), epoch.wrapping_add(1));
        assert_eq!(acc.take_unit_step(), None);
        acc.add_detents(2);
        assert_eq!(acc.position(), 20);
    }

    #[test]
    fn master_lost_stops_disables_and_latches_until_enabled() {
        let mut acc = active(Axis::W, Multiplier::X1);
        assert!(marks(&mut acc, |a| a.set_unit_step_mode(true)));
        acc.add_detents(3);
        assert!(marks(&mut acc, |a| a.stop(StopReason::MasterLost)));
        assert!(!acc.enabled());
        assert_eq!(acc.pending_steps(), 0);
        assert!(acc.status().contains(FeedStatus::MASTER_LOST));
        assert!(
            !marks(&mut acc, |a| a.stop(StopReason::MasterLost)),
            "second stop changes nothing"
        );
        // Feed does not resume by itself.
        acc.add_detents(3);
        assert_eq!(acc.position(), 3);
        assert!(marks(&mut acc, |a| a.set_enabled(true)));
        assert!(!acc.status().contains(FeedStatus::MASTER_LOST));
        acc.add_detents(1);
        assert_eq!(acc.position(), 4);
    }

    #[test]
    fn stop_when_already_disabled_is_no_change() {
        let mut acc = FeedAccumulator::new();
        let epoch = acc.epoch();
        assert!(!marks(&mut acc, |a| a.stop(StopReason::NotOperational)));
        assert_eq!(acc.epoch(), epoch);
    }

    #[test]
    fn unit_steps_drain_toward_zero_in_order() {
        let mut acc = active(Axis::V, Multiplier::X1);
        assert!(marks(&mut acc, |a| a.set_unit_step_mode(true)));
        acc.add_detents(2);
        acc.add_detents(-3);
        assert_eq!(acc.pending_steps(), -1);
        assert_eq!(
            acc.take_unit_step(),
            Some(UnitStep {
                axis: Axis::V,
                forward: false
            })
        );
        assert_eq!(acc.take_unit_step(), None);
    }

    #[test]
    fn no_unit_steps_outside_unit_step_mode() {
        let mut acc = active(Axis::X, Multiplier::X10);
        acc.add_detents(3);
        assert_eq!(acc.pending_steps(), 0);
        assert_eq!(acc.take_unit_step(), None);
    }

    #[test]
    fn backlog_is_bounded_and_overflow_is_flagged() {
        let mut acc = active(Axis::X, Multiplier::X100);
        assert!(marks(&mut acc, |a| a.set_unit_step_mode(true)));
        acc.add_detents(1);
        let bound = i32::from(DEFAULT_STEP_BACKLOG);
        assert_eq!(acc.pending_steps(), bound);
        assert_eq!(acc.dropped_steps(), 100 - DEFAULT_STEP_BACKLOG as u32);
        assert!(acc.status().contains(FeedStatus::STEPS_DROPPED));
        // The position still tells the truth.
        assert_eq!(acc.position(), 100);
        assert_eq!(drain(&mut acc), (DEFAULT_STEP_BACKLOG as usize, bound));
    }

    #[test]
    fn reversal_eats_into_the_backlog_before_anything_is_dropped() {
        let mut acc = active(Axis::X, Multiplier::X10);
        assert!(marks(&mut acc, |a| a.set_unit_step_mode(true)));
        acc.add_detents(3);
        acc.add_detents(-4);
        assert_eq!(acc.pending_steps(), -10);
        assert_eq!(acc.dropped_steps(), 0);
        assert!(!acc.status().contains(FeedStatus::STEPS_DROPPED));
    }

    #[test]
    fn custom_bound_and_zero_bound() {
        let mut acc = active(Axis::X, Multiplier::X1);
        assert!(marks(&mut acc, |a| a.set_unit_step_mode(true)));
        acc.add_detents(9);
        assert!(acc.set_backlog_bound(4));
        assert_eq!(
            acc.pending_steps(),
            4,
            "shrinking the bound clips the backlog"
        );
        assert!(!acc.set_backlog_bound(0));
        assert_eq!(acc.backlog_bound(), 4);
    }

    #[test]
    fn latched_flags_last_for_the_epoch() {
        let mut acc = active(Axis::X, Multiplier::X1);
        assert!(marks(&mut acc, |a| a.note_encoder_error()));
        assert!(!marks(&mut acc, |a| a.note_encoder_error()));
        acc.add_detents(1);
        assert!(acc.status().contains(FeedStatus::ENCODER_ERROR));
        assert!(acc.set_selection(Selection {
            axis: Some(Axis::Y),
            multiplier: Multiplier::X1
        }));
        assert!(!acc.status().contains(FeedStatus::ENCODER_ERROR));
        assert_eq!(
            acc.status(),
            FeedStatus::ENABLED,
            "new epoch starts with only the level bits"
        );
    }

    #[test]
    fn epoch_wraps() {
        let mut acc = FeedAccumulator::new();
        for i in 0..300u32 {
            assert!(marks(&mut acc, |a| a.set_enabled(i % 2 == 0)));
        }
        assert_eq!(acc.epoch(), (300 % 256) as u8);
    }

    #[test]
    fn a_record_is_due_while_the_outbox_holds_more_or_the_state_moved_on() {
        let mut acc = active(Axis::X, Multiplier::X1);
        acc.start_records();
        let first = acc.record();
        assert!(!marks(&mut acc, |a| a.record_sent(first.state)), "all said");
        acc.add_detents(2);
        // The epoch ends before its last detents went out: its final state is held.
        assert!(acc.set_selection(Selection {
            axis: Some(Axis::Y),
            multiplier: Multiplier::X1
        }));
        let held = acc.record();
        assert_eq!((held.state.axis, held.state.position), (Some(Axis::X), 2));
        assert!(
            marks(&mut acc, |a| a.record_sent(held.state)),
            "the present state (Y) is still to be said"
        );
        let live = acc.record();
        assert_eq!(live.state.axis, Some(Axis::Y));
        assert!(!marks(&mut acc, |a| a.record_sent(live.state)));
        assert!(marks(&mut acc, |a| a.request_record()), "asked for");
        assert!(marks(&mut acc, |a| a.reset()), "position 0, a new epoch");
    }

    #[test]
    fn a_session_the_pace_ends_is_due_wherever_it_ends() {
        let mut acc = active(Axis::X, Multiplier::X1);
        acc.start_records();
        acc.set_session(3);
        // Records at one instant until the bucket is empty.
        while acc.outbox().paced() {
            let record = acc.record();
            acc.record_sent(record.state);
        }
        assert_eq!(acc.session(), 3);
        // The stop is a break the empty bucket cannot pay for: the session ends there,
        // outside any record, and a record is due.
        assert!(marks(&mut acc, |a| a.stop_records()));
        assert_eq!((acc.session(), acc.enabled()), (0, false));
    }

    #[test]
    fn a_session_change_is_a_new_epoch_with_the_feed_off() {
        let mut acc = active(Axis::X, Multiplier::X1);
        acc.start_records();
        let epoch = acc.epoch();
        assert!(marks(&mut acc, |a| a.set_session(3)));
        assert_eq!((acc.session(), acc.enabled()), (3, false));
        assert_eq!(acc.epoch(), epoch.wrapping_add(1));
        assert_eq!(acc.state().session, 3);
        assert!(
            !marks(&mut acc, |a| a.set_session(3)),
            "the same session again changes nothing"
        );
        assert!(marks(&mut acc, |a| a.set_enabled(true)));
        assert!(marks(&mut acc, |a| a.set_session(0)));
        assert!(!acc.enabled(), "ending the session stops the feed");
        assert!(marks(&mut acc, |a| a.set_session(9 + 8)));
        assert_eq!(acc.session(), 1, "only three bits travel");
    }

    #[test]
    fn numbers_beyond_the_pace_end_the_session() {
        let mut acc = active(Axis::X, Multiplier::X1);
        acc.start_records();
        assert!(marks(&mut acc, |a| a.set_session(5)));
        assert!(marks(&mut acc, |a| a.set_enabled(true)));
        acc.tick(10_000);
        // A burst of records at one instant: the pace allows SEQUENCE_BURST of them.
        let mut ended_at = None;
        for n in 0..2 * usize::from(crate::SEQUENCE_BURST) {
            let record = acc.record();
            acc.record_sent(record.state);
            if acc.session() == 0 {
                ended_at = Some(n);
                break;
            }
        }
        assert_eq!(ended_at, Some(usize::from(crate::SEQUENCE_BURST)));
        assert!(!acc.enabled());
        // The last record said where the session's epoch ended: nothing is held, and the
        // next record is of no session.
        assert_eq!(acc.outbox().held(), 0);
        assert_eq!(acc.record().state.session, 0);
    }

    #[test]
    fn a_record_per_millisecond_keeps_the_session() {
        let mut acc = active(Axis::X, Multiplier::X1);
        acc.start_records();
        assert!(marks(&mut acc, |a| a.set_session(2)));
        assert!(marks(&mut acc, |a| a.set_enabled(true)));
        for t in 0..5_000u64 {
            acc.tick(t * 1000);
            assert!(marks(&mut acc, |a| a.add_detents(1)));
            let record = acc.record();
            acc.record_sent(record.state);
        }
        assert_eq!((acc.session(), acc.enabled()), (2, true));
    }

    #[test]
    fn reset_ends_the_session() {
        let mut acc = active(Axis::X, Multiplier::X1);
        acc.start_records();
        assert!(marks(&mut acc, |a| a.set_session(4)));
        acc.reset();
        assert_eq!(acc.session(), 0);
    }
}
