//! Feed records on their way to the bus: every selection epoch's final state is sent before
//! anything of the next epoch, even when the bus is blocked, and every record or epoch that
//! can no longer reach the host shows as a gap in the sequence number.
//!
//! A feed record describes state, so the present state is all a record has to carry while the
//! selection stays the same. Across a change of epoch (axis, multiplier, enable, format, a
//! stop) that is not enough: a host that sees "X at 30" and then "Y at 37" can credit the 7 to
//! Y only if 30 was X's final position. When records cannot reach the bus (the transmit queue
//! is full), the present state moves on and an epoch may end unseen. The outbox closes it
//! instead: at the change it keeps the epoch's final state, unless the last record sent
//! already said exactly that, and the next records send what it holds, oldest first, before
//! the present state again. So each epoch costs at most one held record, however long the
//! bus is blocked, and every epoch's last position is delivered once the bus is back.
//!
//! The sequence number counts records and losses. It steps by one for every record handed
//! out, and by one for every *loss*: a held record dropped because the store is full
//! ([`HELD_EPOCHS`]), an epoch that ends while no record can hold it (the device is not
//! Operational, or no record went out since the start), what is held when records stop. A
//! *break* ([`FeedOutbox::break_continuity`]: a start, a stop, a reset, a blocked transmit
//! path) counts as losses up to the run's limit. A run of losses between two records moves the
//! sequence by at most [`MAX_DROP_GAP`], so that losses can never wrap the byte round to "no
//! gap"; a break always moves it that far. The host's rule (README "Feed record") reads a gap
//! of 7 or more as "start afresh": nothing after a break is ever taken as a continuation of
//! what came before it, and every epoch that ended unseen hides behind at least one missing
//! number.
//!
//! The sequence number also keeps a pace: a bucket of [`SEQUENCE_BURST`] numbers refilled by
//! one per millisecond ([`FeedOutbox::refill`]). Every number taken empties it by one; a
//! number taken from an empty bucket marks it overdrawn ([`FeedOutbox::take_overdrawn`]), and
//! the accumulator then ends the master's session before anything else goes out with it. So
//! between two records of one session made `t` ms apart the sequence moved by at most
//! `t + SEQUENCE_BURST`, whatever a master or the bus does: a copy of a record of that session
//! is at least `(numbers behind - SEQUENCE_BURST)` ms old, which is what lets the host tell
//! copies up to its stated age from new records with 16 bits.
//!
//! The state machine is checked exhaustively against the host's rule by `crates/feed-check`.

use crate::feed::FeedState;

/// What an unused slot holds (never read: `len` says which slots are in use).
const UNUSED: FeedState = FeedState::ZERO;

/// Closed epochs the outbox holds at most. An operator who changes the selection more often
/// than this while the bus is blocked loses the motion of the oldest ones (to no axis).
pub const HELD_EPOCHS: usize = 8;

/// Most the sequence number moves for one run of losses, and what a break moves it by.
pub const MAX_DROP_GAP: u8 = 8;

/// Sequence numbers the pace allows at once; the bucket refills by one per millisecond.
pub const SEQUENCE_BURST: u16 = 64;

/// The sequence's pace: how many numbers at once, and how often one more.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct SequencePace {
    /// Numbers at once.
    pub burst: u16,
    /// Microseconds per number refilled.
    pub us_per_number: u32,
}

impl SequencePace {
    /// The firmware's: [`SEQUENCE_BURST`] at once, one per millisecond.
    pub const SHIPPED: Self = Self {
        burst: SEQUENCE_BURST,
        us_per_number: 1000,
    };
}

/// A plausible bug in the pace, for the feed checker's mutation tests
/// (`crates/feed-check/tests/mutants.rs`). Compiled only with the hidden `mutants` feature.
#[cfg(feature = "mutants")]
#[doc(hidden)]
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum PaceMutant {
    /// One number more at once than the burst.
    BurstPlusOne,
    /// A number refilled as soon as the bucket is refilled up to now, a period early.
    RefillEarly,
    /// A number taken beyond the pace is never reported ([`FeedOutbox::take_overdrawn`]).
    NotEnforced,
}

/// Where the pace was refilled: the device's time (µs) of the last refill, and the sequence
/// at the first refill at that time. The feed checker reads it to keep its own bucket in
/// step with the order of refill and numbers in a round. Not part of the outbox's state (it
/// hashes to nothing): it only tells where the round the checker is running refilled.
#[cfg(feature = "mutants")]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct RefillMark {
    now_us: u64,
    sequence: u16,
}

#[cfg(feature = "mutants")]
impl core::hash::Hash for RefillMark {
    fn hash<H: core::hash::Hasher>(&self, _: &mut H) {}
}

/// The closed epochs' final states waiting for the bus, and the record sequence number.
#[derive(Clone, Debug, Hash)]
pub struct FeedOutbox {
    held: [FeedState; HELD_EPOCHS],
    /// Index of the oldest held record.
    head: usize,
    len: usize,
    last_sent: Option<FeedState>,
    reporting: bool,
    sequence: u16,
    drops_in_run: u8,
    dropped: u32,
    /// Numbers the pace allows now (at most [`SEQUENCE_BURST`]).
    allowance: u16,
    /// The time (µs) the allowance was last refilled up to.
    refilled_us: u64,
    /// A number was taken from an empty bucket since the last [`FeedOutbox::take_overdrawn`].
    overdrawn: bool,
    pace: SequencePace,
    #[cfg(feature = "mutants")]
    mutant: Option<PaceMutant>,
    #[cfg(feature = "mutants")]
    refill_mark: Option<RefillMark>,
}

impl Default for FeedOutbox {
    fn default() -> Self {
        Self::new()
    }
}

impl FeedOutbox {
    /// Stopped, nothing held, nothing sent, sequence 0.
    pub const fn new() -> Self {
        Self {
            held: [UNUSED; HELD_EPOCHS],
            head: 0,
            len: 0,
            last_sent: None,
            reporting: false,
            sequence: 0,
            drops_in_run: 0,
            dropped: 0,
            allowance: SEQUENCE_BURST,
            refilled_us: 0,
            overdrawn: false,
            pace: SequencePace::SHIPPED,
            #[cfg(feature = "mutants")]
            mutant: None,
            #[cfg(feature = "mutants")]
            refill_mark: None,
        }
    }

    /// Runs the pace bug `mutant` from now on (`None`: the real pace).
    #[cfg(feature = "mutants")]
    #[doc(hidden)]
    pub fn set_pace_mutant(&mut self, mutant: Option<PaceMutant>) {
        self.mutant = mutant;
    }

    /// The device's time (µs) of the last refill, and the sequence when the pace was first
    /// refilled at that time (`None`: never refilled), for the feed checker's pace.
    #[cfg(feature = "mutants")]
    #[doc(hidden)]
    pub fn mutant_refill_mark(&self) -> Option<(u64, u16)> {
        self.refill_mark.map(|mark| (mark.now_us, mark.sequence))
    }

    /// Another pace than [`SequencePace::SHIPPED`], for a checker that narrows the sequence
    /// (the bucket starts full). The firmware never calls it.
    pub fn set_pace(&mut self, pace: SequencePace) {
        self.pace = pace;
        self.allowance = pace.burst;
    }

    /// Time passes (`now_us`, the device's clock in µs): one number more per whole period of
    /// the pace since the last refill, up to its burst. (A loop of at most a burst of steps
    /// rather than a 64-bit division, which the firmware would have to link for this alone.)
    pub fn refill(&mut self, now_us: u64) {
        #[cfg(feature = "mutants")]
        if self.refill_mark.is_none_or(|mark| mark.now_us != now_us) {
            self.refill_mark = Some(RefillMark {
                now_us,
                sequence: self.sequence,
            });
        }
        #[allow(unused_mut, reason = "only the mutants change them")]
        let (mut burst, mut due) = (self.pace.burst, u64::from(self.pace.us_per_number));
        #[cfg(feature = "mutants")]
        match self.mutant {
            Some(PaceMutant::BurstPlusOne) => burst += 1,
            Some(PaceMutant::RefillEarly) => due = 0,
            _ => {}
        }
        let period = u64::from(self.pace.us_per_number);
        while self.allowance < burst && now_us >= self.refilled_us.saturating_add(due) {
            self.allowance += 1;
            self.refilled_us += period;
        }
        if self.allowance >= burst {
            self.refilled_us = self.refilled_us.max(now_us);
        }
    }

    /// Whether the next record may carry the session: the bucket holds a number for it.
    pub const fn paced(&self) -> bool {
        self.allowance > 0
    }

    /// Whether a number was taken from an empty bucket since the last call; clears it.
    pub fn take_overdrawn(&mut self) -> bool {
        #[cfg(feature = "mutants")]
        if self.mutant == Some(PaceMutant::NotEnforced) {
            self.overdrawn = false;
        }
        core::mem::take(&mut self.overdrawn)
    }

    /// The sequence moves on by one, taken from the bucket.
    fn advance(&mut self) {
        self.sequence = self.sequence.wrapping_add(1);
        match self.allowance.checked_sub(1) {
            Some(left) => self.allowance = left,
            None => self.overdrawn = true,
        }
    }

    /// The feed leaves an epoch whose final state is `closing`: hold it for the bus, unless
    /// nothing is held and the last record sent already said exactly this. While no record
    /// can hold it (stopped, or nothing sent since the start) the epoch ends as a loss. A full
    /// store drops its oldest record first (a loss).
    pub fn close_epoch(&mut self, closing: FeedState) {
        let Some(last_sent) = self.last_sent.filter(|_| self.reporting) else {
            self.count_loss();
            return;
        };
        if self.len == 0 && last_sent == closing {
            return;
        }
        if self.len == HELD_EPOCHS {
            let _ = self.pop();
            self.dropped = self.dropped.wrapping_add(1);
            self.count_loss();
        }
        let tail = (self.head + self.len) % HELD_EPOCHS;
        if let Some(slot) = self.held.get_mut(tail) {
            *slot = closing;
            self.len += 1;
        }
    }

    /// What the next feed record carries: the oldest held state, else `live`, the present
    /// one.
    pub fn next(&self, live: FeedState) -> FeedState {
        self.oldest().unwrap_or(live)
    }

    /// The sequence number the next record carries (object 0x2031).
    pub const fn sequence(&self) -> u16 {
        self.sequence
    }

    /// A feed record carrying `record` (what [`FeedOutbox::next`] gave when the record was
    /// built) went out; `live` is the present state. Returns whether another is due: more is
    /// held, or the present state differs from what just went out. The record, not the
    /// present state, is what the host now knows: detents counted while it was built are
    /// not in it.
    #[must_use = "a record that is due must be requested"]
    pub fn sent(&mut self, record: FeedState, live: FeedState) -> bool {
        if self.oldest() == Some(record) {
            let _ = self.pop();
        }
        self.last_sent = Some(record);
        self.advance();
        self.drops_in_run = 0;
        self.len != 0 || record != live
    }

    /// Records may flow (the device entered Operational): a break (unless nothing was ever
    /// sent or lost: the first start after power-on, whose boot-up tells the host already),
    /// and epochs are held from the first record on (before it, the host has nothing to
    /// continue from).
    pub fn start(&mut self) {
        self.reporting = true;
        self.last_sent = None;
        if self.sequence != 0 || self.drops_in_run != 0 {
            self.break_continuity();
        }
    }

    /// Records stop (the device left Operational): everything held is dropped (its motion
    /// reaches no axis), and a break, so that the next record after a start is never taken as
    /// a continuation.
    pub fn stop(&mut self) {
        if !self.reporting {
            return;
        }
        self.reporting = false;
        self.last_sent = None;
        while self.pop().is_some() {
            self.dropped = self.dropped.wrapping_add(1);
        }
        self.break_continuity();
    }

    /// A mutant of [`FeedOutbox::stop`] for the feed checker's mutation tests: records stop,
    /// but the held epochs stay and nothing breaks the sequence.
    #[cfg(feature = "mutants")]
    #[doc(hidden)]
    pub fn mutant_stop_keeping_held(&mut self) {
        if !self.reporting {
            return;
        }
        self.reporting = false;
        self.last_sent = None;
    }

    /// Nothing after this continues what came before: the next record's sequence number is
    /// at least [`MAX_DROP_GAP`] after the last one handed out. For a reset of the node or of
    /// communication, and for records that were discarded before they reached the bus.
    pub fn break_continuity(&mut self) {
        while self.drops_in_run < MAX_DROP_GAP {
            self.count_loss();
        }
    }

    /// One loss: the sequence moves on, at most [`MAX_DROP_GAP`] for a run of them.
    fn count_loss(&mut self) {
        if self.drops_in_run < MAX_DROP_GAP {
            self.drops_in_run += 1;
            self.advance();
        }
    }

    /// Closed epochs waiting for the bus.
    pub const fn held(&self) -> usize {
        self.len
    }

    /// Held records dropped (store full, or records stopped) since power-on, wrapping.
    pub const fn dropped(&self) -> u32 {
        self.dropped
    }

    fn oldest(&self) -> Option<FeedState> {
        if self.len == 0 {
            return None;
        }
        self.held.get(self.head).copied()
    }

    fn pop(&mut self) -> Option<FeedState> {
        let oldest = self.oldest()?;
        self.head = (self.head + 1) % HELD_EPOCHS;
        self.len -= 1;
        Some(oldest)
    }
}

#[cfg(test)]
mod tests {
    extern crate std;
    use std::vec;

    use super::*;
    use crate::feed::FeedStatus;
    use crate::selector::{Axis, Multiplier};

    fn state(position: i32, axis: Axis, epoch: u8) -> FeedState {
        FeedState {
            position,
            axis: Some(axis),
            multiplier: Multiplier::X1,
            status: FeedStatus::ENABLED,
            epoch,
            session: 0,
        }
    }

    fn started() -> FeedOutbox {
        let mut out = FeedOutbox::new();
        out.start();
        out
    }

    #[test]
    fn nothing_held_while_records_get_out() {
        let mut out = started();
        let x = state(3, Axis::X, 1);
        assert_eq!(out.next(x), x);
        assert!(
            !out.sent(x, x),
            "the present state went out: nothing more is due"
        );
        assert_eq!(out.sequence(), 1);
        // The epoch ends where the last record left it: nothing to hold.
        out.close_epoch(x);
        assert_eq!(out.held(), 0);
        let y = state(3, Axis::Y, 2);
        assert_eq!(out.next(y), y);
    }

    #[test]
    fn an_epoch_that_ended_unsent_goes_out_before_the_next() {
        let mut out = started();
        assert!(!out.sent(out.next(state(0, Axis::X, 1)), state(0, Axis::X, 1)));
        // X moved to 30 but the bus took nothing; then Y (epoch 2) and X again (epoch 3).
        out.close_epoch(state(30, Axis::X, 1));
        out.close_epoch(state(37, Axis::Y, 2));
        let live = state(39, Axis::X, 3);
        let mut seen = vec![];
        loop {
            let record = out.next(live);
            seen.push((record.position, record.axis, record.epoch, out.sequence()));
            if !out.sent(record, live) {
                break;
            }
        }
        assert_eq!(
            seen,
            [
                (30, Some(Axis::X), 1, 1),
                (37, Some(Axis::Y), 2, 2),
                (39, Some(Axis::X), 3, 3)
            ]
        );
    }

    #[test]
    fn a_full_store_drops_the_oldest_and_shows_a_gap() {
        let mut out = started();
        assert!(!out.sent(out.next(state(-1, Axis::X, 0)), state(-1, Axis::X, 0)));
        for epoch in 0..HELD_EPOCHS as u8 + 3 {
            out.close_epoch(state(i32::from(epoch), Axis::X, epoch));
        }
        assert_eq!(out.held(), HELD_EPOCHS);
        assert_eq!(out.dropped(), 3);
        let first = out.next(state(99, Axis::Z, 200));
        assert_eq!(first.epoch, 3, "the three oldest were dropped");
        assert_eq!(
            out.sequence(),
            1 + 3,
            "one sent, then three as if sent and lost"
        );
    }

    #[test]
    fn a_long_run_of_drops_moves_the_sequence_by_at_most_eight() {
        let mut out = started();
        assert!(!out.sent(out.next(state(0, Axis::X, 0)), state(0, Axis::X, 0)));
        for epoch in 1..=300u16 {
            out.close_epoch(state(0, Axis::X, epoch as u8));
        }
        assert_eq!(out.dropped(), 300 - HELD_EPOCHS as u32);
        assert_eq!(
            out.sequence(),
            1 + u16::from(MAX_DROP_GAP),
            "not wrapped round by 292 drops"
        );
        // Sending ends the run: the next drops show as a new gap.
        assert!(
            out.sent(out.next(state(0, Axis::X, 44)), state(0, Axis::X, 44)),
            "seven are still held"
        );
        out.close_epoch(state(0, Axis::X, 45));
        assert_eq!(
            out.sequence(),
            2 + u16::from(MAX_DROP_GAP),
            "room for one: no drop"
        );
        out.close_epoch(state(0, Axis::X, 46));
        assert_eq!(out.sequence(), 2 + u16::from(MAX_DROP_GAP) + 1);
    }

    #[test]
    fn stop_drops_what_is_held_and_breaks() {
        let mut out = started();
        assert!(!out.sent(out.next(state(0, Axis::X, 0)), state(0, Axis::X, 0)));
        out.close_epoch(state(5, Axis::X, 0));
        out.stop();
        assert_eq!(out.held(), 0);
        assert_eq!(out.dropped(), 1);
        assert_eq!(
            out.sequence(),
            1 + u16::from(MAX_DROP_GAP),
            "a full break after the record"
        );
        let live = state(5, Axis::X, 1);
        assert_eq!(out.next(live), live);
    }

    #[test]
    fn every_stop_and_start_is_a_break() {
        let mut out = FeedOutbox::new();
        out.stop();
        assert_eq!(out.sequence(), 0, "never started: nothing to break");
        out.start();
        assert_eq!(
            out.sequence(),
            0,
            "the first start after power-on has the boot-up"
        );
        assert!(!out.sent(out.next(state(0, Axis::X, 0)), state(0, Axis::X, 0)));
        out.stop();
        out.stop();
        assert_eq!(out.sequence(), 1 + u16::from(MAX_DROP_GAP));
        out.start();
        assert_eq!(
            out.sequence(),
            1 + u16::from(MAX_DROP_GAP),
            "the run is full already"
        );
        assert!(!out.sent(out.next(state(0, Axis::X, 0)), state(0, Axis::X, 0)));
        out.start();
        assert_eq!(
            out.sequence(),
            2 + 2 * u16::from(MAX_DROP_GAP),
            "a start after a record breaks too"
        );
        assert_eq!(out.dropped(), 0);
    }

    #[test]
    fn epochs_that_end_unrecorded_take_numbers() {
        let mut out = FeedOutbox::new();
        out.close_epoch(state(0, Axis::X, 0));
        out.close_epoch(state(0, Axis::Y, 1));
        assert_eq!((out.held(), out.sequence()), (0, 2), "stopped: two losses");
        out.start();
        assert_eq!(
            out.sequence(),
            u16::from(MAX_DROP_GAP),
            "the start fills the run"
        );
        out.close_epoch(state(0, Axis::Z, 2));
        assert_eq!(out.held(), 0, "no record yet: nothing to continue from");
        assert_eq!(out.sequence(), u16::from(MAX_DROP_GAP), "the run is full");
        assert!(!out.sent(out.next(state(0, Axis::Z, 3)), state(0, Axis::Z, 3)));
        out.close_epoch(state(4, Axis::Z, 3));
        assert_eq!(out.held(), 1);
        out.stop();
        out.start();
        out.close_epoch(state(4, Axis::Y, 4));
        assert_eq!(out.held(), 0, "a new start: nothing sent since");
    }

    #[test]
    fn a_break_moves_the_sequence_by_the_full_gap_once_per_run() {
        let mut out = started();
        assert!(!out.sent(out.next(state(0, Axis::X, 0)), state(0, Axis::X, 0)));
        out.close_epoch(state(3, Axis::X, 0));
        out.close_epoch(state(3, Axis::Y, 1));
        assert_eq!(out.held(), 2);
        out.break_continuity();
        assert_eq!(out.sequence(), 1 + u16::from(MAX_DROP_GAP));
        assert_eq!(
            out.held(),
            2,
            "a break keeps what is held: it still goes out in order"
        );
        out.break_continuity();
        assert_eq!(out.sequence(), 1 + u16::from(MAX_DROP_GAP));
    }

    #[test]
    fn what_the_host_knows_is_the_record_not_the_state_when_it_went_out() {
        let mut out = started();
        // Built at position 3; two more detents were counted before it went out.
        let built = state(3, Axis::X, 1);
        let live = state(5, Axis::X, 1);
        assert!(
            out.sent(built, live),
            "the present state differs: another record is due"
        );
        // The epoch ends at 5 before that record: its final state is not what the host has.
        out.close_epoch(live);
        assert_eq!(out.held(), 1, "the final state is held, not taken as sent");
        assert_eq!(out.next(state(5, Axis::Y, 2)), live);
    }

    #[test]
    fn the_pace_allows_a_burst_then_one_number_per_millisecond() {
        let mut out = started();
        out.refill(1_000_000);
        let x = state(0, Axis::X, 0);
        for n in 0..SEQUENCE_BURST {
            assert!(out.paced(), "number {n} of the burst");
            let _ = out.sent(x, x);
        }
        assert!(!out.paced(), "the burst is spent");
        assert!(
            !out.take_overdrawn(),
            "nothing was taken from an empty bucket"
        );
        out.refill(1_003_000);
        for _ in 0..3 {
            assert!(out.paced());
            let _ = out.sent(x, x);
        }
        assert!(!out.paced());
        // A loss takes a number whatever the bucket holds, and says so once.
        out.close_epoch(state(5, Axis::X, 0));
        out.close_epoch(state(5, Axis::Y, 1));
        out.break_continuity();
        assert!(out.take_overdrawn());
        assert!(!out.take_overdrawn(), "taken once");
        out.refill(u64::MAX);
        assert!(out.paced(), "full again, however long it waited");
        let before = out.sequence();
        for _ in 0..SEQUENCE_BURST {
            let _ = out.sent(x, x);
        }
        assert_eq!(out.sequence().wrapping_sub(before), SEQUENCE_BURST);
        assert!(!out.take_overdrawn(), "never more than the burst at once");
    }

    #[test]
    fn the_sequence_wraps_at_sixteen_bits() {
        let mut out = started();
        let x = state(0, Axis::X, 0);
        for t in 0..70_000u64 {
            out.refill(t * 1000);
            let _ = out.sent(x, x);
        }
        assert_eq!(out.sequence(), (70_000u32 % 65_536) as u16);
        assert!(
            !out.take_overdrawn(),
            "one record per millisecond keeps the pace"
        );
    }
}
