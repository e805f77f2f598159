//! The wheel's edge task and its lock-free channel to the CAN side.
//!
//! The edge interrupt owns the [`QuadratureDecoder`] outright ([`EdgeDecoder`]): nothing else
//! ever holds a reference to it, so the edge takes no lock, writes no BASEPRI and enters no
//! critical section. What the rest of the firmware needs crosses an [`EdgeChannel`]:
//!
//! - **edge to CAN side**: after every edge that changed something, the edge publishes its
//!   counters (count, detents, illegal transitions) and then bumps a sequence number.
//!   [`EdgeChannel::snapshot`] reads the sequence, the counters and the sequence again, and
//!   retries if it changed: the classic sequence lock, reduced to what a single core needs.
//! - **CAN side to edge**: the decoder's settings and a request to settle at standstill, as
//!   whole words, announced by a generation number, applied by [`EdgeDecoder::on_kick`]
//!   when the CAN side kicks the edge task ([`EdgeLink::kick`]). On the MCU the kick is a
//!   second interrupt at the edge's priority, so an edge never spends a cycle on commands and
//!   the two never preempt each other: the decoder still has one owner at a time.
//!
//! # Why a torn read cannot happen
//!
//! The protocol relies on what the firmware guarantees about its two sides: one core; the
//! edge's interrupt has the highest priority of the two and the CAN side never runs while an
//! edge is being handled; and each side is the only writer of its words. So an edge handler
//! runs *between* two instructions of the CAN side, entirely, never the other way round:
//!
//! - A snapshot whose two sequence reads agree had no edge run between them, so every counter
//!   it read belongs to the same publication. If they differ, it reads again; an edge can
//!   only make it retry, and at most once per edge, so it ends as soon as the wheel leaves
//!   the CAN side one uninterrupted read (far faster than any wheel can turn).
//! - A command word is one atomic word: the edge task sees it before or after a CAN-side
//!   store, never half of it. The generation is stored after the words it announces; a kick
//!   that runs between the two (an earlier one, still pending) sees the new words with the
//!   old generation, ignores them, and the kick that follows the generation store applies
//!   them.
//!
//! Every word is an atomic with relaxed ordering: on the Cortex-M3 a plain load or store,
//! no barrier and no exclusive access. The order of the snapshot's reads is fixed for the
//! compiler by [`compiler_fence`], which is the fence for code and the interrupts that preempt
//! it on one core; the hardware keeps program order for both. (On a multi-core host these
//! orderings would not be enough; the host tests run the protocol the way the MCU does, with
//! the writer preempting the reader at every possible point: see the tests below.)

use core::sync::atomic::{compiler_fence, AtomicI32, AtomicU32, Ordering};

use crate::decoder::{AbLevels, CountsPerDetent, DecoderConfig, EdgeOutcome, QuadratureDecoder};

/// Relaxed everywhere: see the module docs for why that is enough on one core.
const RELAXED: Ordering = Ordering::Relaxed;

/// One publication of the edge, as the CAN side reads it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct EdgeSnapshot {
    /// Edges that changed something since start-up, wrapping: the sequence number.
    pub edges: u32,
    /// Signed counts, inversion applied, wrapping.
    pub count: i32,
    /// Detents reported, forward minus reverse, wrapping.
    pub detents: i32,
    /// Illegal transitions, wrapping.
    pub illegal: u32,
}

/// The settings word: counts per detent (bits 0-2), inversion (bit 3), and above them how
/// many times the CAN side has configured, so that configuring twice with the same settings
/// still takes the present levels as the rest twice, as [`QuadratureDecoder::configure`]
/// does.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct SettingsWord(u32);

impl SettingsWord {
    pub(crate) const fn new(config: DecoderConfig, serial: u32) -> Self {
        let invert = if config.invert { 1 << 3 } else { 0 };
        Self((serial << 4) | invert | config.counts_per_detent.get() as u32)
    }

    fn config(self) -> Option<DecoderConfig> {
        Some(DecoderConfig {
            counts_per_detent: CountsPerDetent::from_u8((self.0 & 0b111) as u8)?,
            invert: self.0 & (1 << 3) != 0,
        })
    }
}

/// The shared words between the edge and the CAN side. A `static` in the firmware.
#[derive(Debug)]
pub struct EdgeChannel {
    // Written by the edge only.
    edges: AtomicU32,
    count: AtomicI32,
    detents: AtomicI32,
    illegal: AtomicU32,
    /// Settles that moved the rest: a diagnostic counter on its own, outside the sequence.
    rests_learnt: AtomicU32,
    // Written by the CAN side only.
    generation: AtomicU32,
    settings: AtomicU32,
    /// Settle if the edge's sequence number still equals this.
    settle_at: AtomicU32,
}

impl Default for EdgeChannel {
    fn default() -> Self {
        Self::new()
    }
}

impl EdgeChannel {
    /// A channel with nothing published and nothing asked.
    pub const fn new() -> Self {
        Self {
            edges: AtomicU32::new(0),
            count: AtomicI32::new(0),
            detents: AtomicI32::new(0),
            illegal: AtomicU32::new(0),
            rests_learnt: AtomicU32::new(0),
            generation: AtomicU32::new(0),
            // No valid settings (counts per detent 0): nothing for the edge to apply.
            settings: AtomicU32::new(0),
            settle_at: AtomicU32::new(0),
        }
    }

    /// A consistent copy of the edge's last publication.
    pub fn snapshot(&self) -> EdgeSnapshot {
        self.snapshot_preempted(|| {})
    }

    /// [`EdgeChannel::snapshot`] with `preempt` called before each of its loads: the points
    /// where an interrupt can change what it reads. The tests run the edge there.
    #[inline(always)]
    fn snapshot_preempted(&self, mut preempt: impl FnMut()) -> EdgeSnapshot {
        loop {
            preempt();
            let before = self.edges.load(RELAXED);
            compiler_fence(Ordering::SeqCst);
            preempt();
            let count = self.count.load(RELAXED);
            preempt();
            let detents = self.detents.load(RELAXED);
            preempt();
            let illegal = self.illegal.load(RELAXED);
            compiler_fence(Ordering::SeqCst);
            preempt();
            if self.edges.load(RELAXED) == before {
                return EdgeSnapshot {
                    edges: before,
                    count,
                    detents,
                    illegal,
                };
            }
        }
    }

    /// How many settles at standstill moved the rest.
    pub fn rests_learnt(&self) -> u32 {
        self.rests_learnt.load(RELAXED)
    }

    /// CAN side: new settings; the edge applies them at its next run.
    pub(crate) fn post_settings(&self, word: SettingsWord) {
        self.post_settings_preempted(word, || {});
    }

    /// CAN side: settle if no edge changed anything since publication `edges`.
    pub(crate) fn post_settle(&self, edges: u32) {
        self.settle_at.store(edges, RELAXED);
        self.announce(|| {});
    }

    /// [`EdgeChannel::post_settings`] with `preempt` called before each of its accesses:
    /// the points where the kick interrupt can run. The tests run it there.
    #[inline(always)]
    fn post_settings_preempted(&self, word: SettingsWord, mut preempt: impl FnMut()) {
        preempt();
        self.settings.store(word.0, RELAXED);
        self.announce(preempt);
    }

    #[inline(always)]
    fn announce(&self, mut preempt: impl FnMut()) {
        // After the word it announces (see the module docs).
        compiler_fence(Ordering::SeqCst);
        preempt();
        let next = self.generation.load(RELAXED).wrapping_add(1);
        preempt();
        self.generation.store(next, RELAXED);
    }
}

/// The edge task's own state: the decoder and what it last took from the CAN side. Its
/// sequence number and detent total live in the channel only, which it alone writes.
#[derive(Clone, Debug)]
pub struct EdgeDecoder {
    decoder: QuadratureDecoder,
    generation: u32,
    settings: u32,
    settle_at: Option<u32>,
}

impl EdgeDecoder {
    /// A decoder at rest on `initial`, the levels read at start-up, for a fresh `channel`.
    pub fn new(config: DecoderConfig, initial: AbLevels, channel: &EdgeChannel) -> Self {
        Self {
            decoder: QuadratureDecoder::new(config, initial),
            generation: channel.generation.load(RELAXED),
            settings: channel.settings.load(RELAXED),
            settle_at: None,
        }
    }

    /// One edge interrupt with the levels it read. Returns `true` after a detent: the CAN side
    /// has feed to send. Illegal transitions wake nobody: a noisy encoder must not turn into
    /// a wake-up (and a log line) per edge; the CAN side finds them at its next round, at
    /// most one selector period (5 ms) later.
    ///
    /// Constant time, no loop, no lock; commands wait for [`EdgeDecoder::on_kick`].
    #[inline]
    #[must_use = "a detent the CAN side is not told of waits for its next round"]
    pub fn on_edge(&mut self, levels: AbLevels, channel: &EdgeChannel) -> bool {
        let outcome = self.decoder.update(levels);
        if outcome == EdgeOutcome::Idle {
            return false;
        }
        channel.count.store(self.decoder.count(), RELAXED);
        let due = match outcome {
            EdgeOutcome::Illegal => {
                channel
                    .illegal
                    .store(self.decoder.illegal_transitions(), RELAXED);
                false
            }
            EdgeOutcome::DetentForward | EdgeOutcome::DetentReverse => {
                let detents = channel
                    .detents
                    .load(RELAXED)
                    .wrapping_add(outcome.detents());
                channel.detents.store(detents, RELAXED);
                true
            }
            EdgeOutcome::Idle | EdgeOutcome::Counted => false,
        };
        // Last: this store is what makes the counters above one publication.
        let edges = channel.edges.load(RELAXED).wrapping_add(1);
        channel.edges.store(edges, RELAXED);
        due
    }

    /// The CAN side kicked: apply the settings if they changed, settle if asked and no edge
    /// changed anything since the CAN side looked. Must not run while [`EdgeDecoder::on_edge`]
    /// runs (on the MCU: an interrupt at the edge's priority).
    pub fn on_kick(&mut self, channel: &EdgeChannel) {
        let generation = channel.generation.load(RELAXED);
        if generation == self.generation {
            return;
        }
        self.generation = generation;
        let settings = channel.settings.load(RELAXED);
        if settings != self.settings {
            self.settings = settings;
            // The CAN side only posts valid settings; anything else is ignored.
            if let Some(config) = SettingsWord(settings).config() {
                self.decoder.configure(config);
            }
        }
        let settle_at = channel.settle_at.load(RELAXED);
        if self.settle_at != Some(settle_at) {
            self.settle_at = Some(settle_at);
            if settle_at == channel.edges.load(RELAXED) && self.decoder.settle() {
                let learnt = channel.rests_learnt.load(RELAXED).wrapping_add(1);
                channel.rests_learnt.store(learnt, RELAXED);
            }
        }
    }
}

/// How the CAN side reaches the edge task: its channel, and a way to make it run now.
pub trait EdgeLink {
    /// The channel shared with the edge task.
    fn channel(&self) -> &EdgeChannel;
    /// Makes the edge task apply the posted commands ([`EdgeDecoder::on_kick`]) as soon as
    /// the CAN side lets it (on the MCU: pends the kick interrupt, which preempts the CAN
    /// side at once).
    fn kick(&mut self);
}

/// The edge task and its channel in one value, run synchronously: a kick runs
/// [`EdgeDecoder::on_kick`] at once, as the pended interrupt would. For host tests, benches
/// and models.
#[derive(Debug)]
pub struct LocalEdge {
    edge: EdgeDecoder,
    pub(crate) channel: EdgeChannel,
}

impl LocalEdge {
    /// A wheel at rest on `initial`.
    pub fn new(config: DecoderConfig, initial: AbLevels) -> Self {
        let channel = EdgeChannel::new();
        Self {
            edge: EdgeDecoder::new(config, initial, &channel),
            channel,
        }
    }

    /// One edge interrupt that reads `levels`.
    #[must_use = "a detent the CAN side is not told of waits for its next round"]
    pub fn on_edge(&mut self, levels: AbLevels) -> bool {
        self.edge.on_edge(levels, &self.channel)
    }
}

impl EdgeLink for LocalEdge {
    fn channel(&self) -> &EdgeChannel {
        &self.channel
    }

    fn kick(&mut self) {
        self.edge.on_kick(&self.channel);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const START: AbLevels = AbLevels::from_bits(0);

    /// The snapshot protocol under every preemption the MCU allows: the edge runs whole
    /// before any load of the reader, any number of times. Whatever the schedule, the snapshot
    /// is one of the edge's publications, whole, and not older than the one in place when
    /// the read started.
    #[test]
    fn snapshot_is_never_torn_under_any_preemption() {
        extern crate std;
        use core::cell::RefCell;
        use std::vec;

        // Loads per pass of the reader; the schedules cover two passes.
        const LOADS: u32 = 5;
        const POINTS: u32 = 2 * LOADS;
        // Forward steps with an illegal jump and back now and then: every field changes.
        fn levels_at(i: u32) -> AbLevels {
            match i % 7 {
                5 => AbLevels::from_bits(START.bits() ^ 0b11),
                _ => (0..i % 4).fold(START, |l, _| l.next_forward()),
            }
        }

        let mut schedules = 0u32;
        for schedule in 0..3u32.pow(POINTS) {
            let channel = EdgeChannel::new();
            let decoder = EdgeDecoder::new(DecoderConfig::default(), START, &channel);
            let edge = RefCell::new((decoder, 0u32));
            let published = RefCell::new(vec![channel.snapshot()]);
            let run_edge = || {
                let (decoder, i) = &mut *edge.borrow_mut();
                *i += 1;
                let _ = decoder.on_edge(levels_at(*i), &channel);
                published.borrow_mut().push(channel.snapshot());
            };
            for _ in 0..5 {
                run_edge();
            }
            let oldest = published.borrow().len() - 1;
            let mut point = 0;
            let snapshot = channel.snapshot_preempted(|| {
                if point < POINTS {
                    for _ in 0..(schedule / 3u32.pow(point)) % 3 {
                        run_edge();
                    }
                }
                point += 1;
            });
            let published = published.borrow();
            let found = published.iter().rposition(|p| *p == snapshot);
            assert!(
                matches!(found, Some(i) if i >= oldest),
                "schedule {schedule}: {snapshot:?} is torn or stale"
            );
            schedules += 1;
        }
        assert_eq!(schedules, 59_049);
    }

    /// Two settings posted one after the other, with the kick interrupt running (or not)
    /// before every access of either post, then the kick that follows the last post: the
    /// edge always ends with the last settings, applied once each time they were new.
    #[test]
    fn posted_settings_survive_any_preemption() {
        use core::cell::RefCell;

        let first = DecoderConfig {
            counts_per_detent: CountsPerDetent::Two,
            invert: true,
        };
        let last = DecoderConfig {
            counts_per_detent: CountsPerDetent::One,
            invert: false,
        };
        // Three access points per post.
        for schedule in 0..(1u32 << 6) {
            let channel = EdgeChannel::new();
            let edge = RefCell::new(EdgeDecoder::new(DecoderConfig::default(), START, &channel));
            let mut point = 0;
            let mut preempt = || {
                if schedule & (1 << point) != 0 {
                    edge.borrow_mut().on_kick(&channel);
                }
                point += 1;
            };
            channel.post_settings_preempted(SettingsWord::new(first, 1), &mut preempt);
            channel.post_settings_preempted(SettingsWord::new(last, 2), &mut preempt);
            let mut edge = edge.into_inner();
            edge.on_kick(&channel);
            assert_eq!(edge.decoder.config(), last, "schedule {schedule:#08b}");
            assert_eq!(edge.settings, SettingsWord::new(last, 2).0);
            assert_eq!(edge.generation, channel.generation.load(RELAXED));
        }
    }

    #[test]
    fn settings_words_round_trip() {
        for cpd in [
            CountsPerDetent::One,
            CountsPerDetent::Two,
            CountsPerDetent::Four,
        ] {
            for invert in [false, true] {
                let config = DecoderConfig {
                    counts_per_detent: cpd,
                    invert,
                };
                for serial in [0, 1, 0x0FFF_FFFF] {
                    assert_eq!(SettingsWord::new(config, serial).config(), Some(config));
                }
            }
        }
        assert_eq!(SettingsWord(0).config(), None);
        assert_eq!(SettingsWord(3).config(), None);
    }
}
