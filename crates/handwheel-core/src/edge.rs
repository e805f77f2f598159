//! The wheel's edge task and its lock-free channel to the CAN side.
//!
//! The edge interrupt owns the [`QuadratureDecoder`] outright ([`EdgeDecoder`]): nothing else
//! ever holds a reference to it, so the edge takes no lock, writes no BASEPRI and enters no
//! critical section. What the rest of the firmware needs crosses an [`EdgeChannel`]:
//!
//! - **edge to CAN side**: after every edge that changed something, the edge publishes its
//!   counters (count, detents, illegal transitions, levels) and then bumps a sequence number.
//!   [`EdgeChannel::snapshot`] reads the sequence, the counters and the sequence again, and
//!   retries if it changed: the classic sequence lock, reduced to what a single core needs.
//! - **CAN side to edge**: the decoder's settings and a request to settle at standstill, as
//!   whole words, announced by a generation number. The edge compares the generation with the
//!   last it applied (one load and one comparison per edge) and reads the words only when it
//!   changed. The CAN side makes the edge look at once by pending its interrupt
//!   ([`EdgeLink::kick`]).
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
//! - A command word is one atomic word: the edge sees it before or after a CAN-side store,
//!   never half of it. The generation is stored after the words it announces; an edge that
//!   runs between the two sees the new words with the old generation, ignores them, and
//!   applies them at the kick that follows the generation store.
//!
//! Every word is an atomic with relaxed ordering: on the Cortex-M3 a plain load or store,
//! no barrier and no exclusive access. The order of the snapshot's reads is fixed for the
//! compiler by [`compiler_fence`], which is the fence for code and the interrupts that preempt
//! it on one core; the hardware keeps program order for both. (On a multi-core host these
//! orderings would not be enough; the host tests run the protocol the way the MCU does, with
//! the writer preempting the reader at every possible point: see the tests below.)

use core::sync::atomic::{compiler_fence, AtomicI32, AtomicU32, AtomicU8, Ordering};

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
    /// The last levels read.
    pub levels: AbLevels,
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
    levels: AtomicU8,
    /// Settles that moved the rest: a diagnostic counter on its own, outside the sequence.
    rests_learnt: AtomicU32,
    // Written by the CAN side only.
    generation: AtomicU32,
    settings: AtomicU32,
    /// Settle if the edge's sequence number still equals this.
    settle_at: AtomicU32,
}

impl EdgeChannel {
    /// The channel of a wheel that starts at `initial` levels with `config`.
    pub const fn new(config: DecoderConfig, initial: AbLevels) -> Self {
        Self {
            edges: AtomicU32::new(0),
            count: AtomicI32::new(0),
            detents: AtomicI32::new(0),
            illegal: AtomicU32::new(0),
            levels: AtomicU8::new(initial.bits()),
            rests_learnt: AtomicU32::new(0),
            generation: AtomicU32::new(0),
            settings: AtomicU32::new(SettingsWord::new(config, 0).0),
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
            preempt();
            let levels = AbLevels::from_bits(self.levels.load(RELAXED));
            compiler_fence(Ordering::SeqCst);
            preempt();
            if self.edges.load(RELAXED) == before {
                return EdgeSnapshot {
                    edges: before,
                    count,
                    detents,
                    illegal,
                    levels,
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
        self.settings.store(word.0, RELAXED);
        self.announce();
    }

    /// CAN side: settle if no edge changed anything since publication `edges`.
    pub(crate) fn post_settle(&self, edges: u32) {
        self.settle_at.store(edges, RELAXED);
        self.announce();
    }

    fn announce(&self) {
        // After the word it announces (see the module docs).
        compiler_fence(Ordering::SeqCst);
        let next = self.generation.load(RELAXED).wrapping_add(1);
        self.generation.store(next, RELAXED);
    }
}

/// The edge interrupt's own state: the decoder and what it last took from the CAN side.
#[derive(Clone, Debug)]
pub struct EdgeDecoder {
    decoder: QuadratureDecoder,
    edges: u32,
    detents: i32,
    generation: u32,
    settings: u32,
    settle_at: Option<u32>,
}

impl EdgeDecoder {
    /// A decoder at rest on `initial`; pair it with `EdgeChannel::new(config, initial)`.
    pub const fn new(config: DecoderConfig, initial: AbLevels) -> Self {
        Self {
            decoder: QuadratureDecoder::new(config, initial),
            edges: 0,
            detents: 0,
            generation: 0,
            settings: SettingsWord::new(config, 0).0,
            settle_at: None,
        }
    }

    /// One run of the edge interrupt with the levels it read. Returns `true` when the CAN
    /// side has feed to look at (a detent, an illegal transition).
    ///
    /// Constant time on the path of an edge; commands from the CAN side take the cold path.
    #[inline]
    #[must_use = "a detent the CAN side is not told of waits for its next round"]
    pub fn on_edge(&mut self, levels: AbLevels, channel: &EdgeChannel) -> bool {
        if channel.generation.load(RELAXED) != self.generation {
            self.apply_commands(channel);
        }
        let outcome = self.decoder.update(levels);
        if outcome == EdgeOutcome::Idle {
            return false;
        }
        channel.count.store(self.decoder.count(), RELAXED);
        channel.levels.store(levels.bits(), RELAXED);
        let due = match outcome {
            EdgeOutcome::Illegal => {
                channel
                    .illegal
                    .store(self.decoder.illegal_transitions(), RELAXED);
                true
            }
            EdgeOutcome::DetentForward | EdgeOutcome::DetentReverse => {
                self.detents = self.detents.wrapping_add(outcome.detents());
                channel.detents.store(self.detents, RELAXED);
                true
            }
            EdgeOutcome::Idle | EdgeOutcome::Counted => false,
        };
        self.edges = self.edges.wrapping_add(1);
        channel.edges.store(self.edges, RELAXED);
        due
    }

    /// The CAN side announced new words: apply the settings if they changed, settle if asked
    /// and nothing moved since.
    #[cold]
    #[inline(never)]
    fn apply_commands(&mut self, channel: &EdgeChannel) {
        self.generation = channel.generation.load(RELAXED);
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
            if settle_at == self.edges && self.decoder.settle() {
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
    /// Makes the edge task run as soon as the CAN side lets it (on the MCU: pends its
    /// interrupt, which preempts the CAN side at once).
    fn kick(&mut self);
}

/// The edge task and its channel in one value, run synchronously: a kick runs the edge with
/// the present levels, as the pended interrupt would. For host tests, benches and models.
#[derive(Debug)]
pub struct LocalEdge {
    edge: EdgeDecoder,
    pub(crate) channel: EdgeChannel,
    levels: AbLevels,
}

impl LocalEdge {
    /// A wheel at rest on `initial`.
    pub const fn new(config: DecoderConfig, initial: AbLevels) -> Self {
        Self {
            edge: EdgeDecoder::new(config, initial),
            channel: EdgeChannel::new(config, initial),
            levels: initial,
        }
    }

    /// One edge interrupt that reads `levels`.
    #[must_use = "a detent the CAN side is not told of waits for its next round"]
    pub fn on_edge(&mut self, levels: AbLevels) -> bool {
        self.levels = levels;
        self.edge.on_edge(levels, &self.channel)
    }
}

impl EdgeLink for LocalEdge {
    fn channel(&self) -> &EdgeChannel {
        &self.channel
    }

    fn kick(&mut self) {
        // The interrupt finds the levels it already had: commands only.
        let _ = self.edge.on_edge(self.levels, &self.channel);
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
        const LOADS: u32 = 6;
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
            let channel = EdgeChannel::new(DecoderConfig::default(), START);
            let edge = RefCell::new((EdgeDecoder::new(DecoderConfig::default(), START), 0u32));
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
        assert_eq!(schedules, 531_441);
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
