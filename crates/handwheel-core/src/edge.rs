//! The wheel state the edge task and the CAN side share: the quadrature decoder and what it
//! has published, behind an exclusive access.
//!
//! On the MCU, [`EdgeState`] is an RTIC `#[shared]` resource of the wheel's edge task
//! (EXTI9_5, the highest priority) and of the CAN-side task. RTIC, not this module, makes
//! every access exclusive: the edge runs whole between two instructions of the CAN side,
//! and the CAN side reaches the state only through RTIC's lock (`rtic_core`'s [`Mutex`],
//! the trait RTIC's resource proxies implement) that holds the edge off for the few
//! instructions of a copy or a command. So nothing here is atomic
//! and nothing can be torn.
//!
//! What stays a protocol is the *time* between two locks: the CAN side decides on a
//! snapshot taken under one lock and acts under a later one, and the wheel may have moved
//! in between. [`EdgeState::settle_if_unmoved`] therefore names the snapshot it was decided
//! on (its sequence number, [`EdgeSnapshot::edges`]) and does nothing if an edge changed
//! anything since; the tests below run every edge that can come between the two.

pub use rtic_core::Mutex;

use crate::decoder::{AbLevels, DecoderConfig, EdgeOutcome, QuadratureDecoder};

/// One copy of what the edge has published, as the CAN side takes it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
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

/// The decoder and its running totals: the edge task's work, the CAN side's source.
#[derive(Clone, Debug, Hash)]
pub struct EdgeState {
    decoder: QuadratureDecoder,
    edges: u32,
    detents: i32,
    rests_learnt: u32,
}

impl EdgeState {
    /// A decoder at rest on `initial`, the levels read at start-up.
    pub const fn new(config: DecoderConfig, initial: AbLevels) -> Self {
        Self {
            decoder: QuadratureDecoder::new(config, initial),
            edges: 0,
            detents: 0,
            rests_learnt: 0,
        }
    }

    /// One edge interrupt with the levels it read. Returns `true` after a detent: the CAN
    /// side has feed to send. Illegal transitions wake nobody: a noisy encoder must not turn
    /// into a wake-up (and a log line) per edge; the CAN side finds them at its next round,
    /// at most one selector period (5 ms) later.
    ///
    /// Constant time, no loop, no call, no panic path: it runs in the edge's interrupt.
    #[inline]
    #[must_use = "a detent the CAN side is not told of waits for its next round"]
    pub fn on_edge(&mut self, levels: AbLevels) -> bool {
        // One arm per outcome, so that each of the decoder's exits goes straight to its own
        // few stores.
        match self.decoder.update(levels) {
            EdgeOutcome::Idle => false,
            EdgeOutcome::Counted | EdgeOutcome::Illegal => {
                self.edges = self.edges.wrapping_add(1);
                false
            }
            EdgeOutcome::DetentForward => {
                self.edges = self.edges.wrapping_add(1);
                self.detents = self.detents.wrapping_add(1);
                true
            }
            EdgeOutcome::DetentReverse => {
                self.edges = self.edges.wrapping_add(1);
                self.detents = self.detents.wrapping_sub(1);
                true
            }
        }
    }

    /// A copy of the totals.
    pub fn snapshot(&self) -> EdgeSnapshot {
        EdgeSnapshot {
            edges: self.edges,
            count: self.decoder.count(),
            detents: self.detents,
            illegal: self.decoder.illegal_transitions(),
        }
    }

    /// Changes counts-per-detent and direction; the present levels become the rest (see
    /// [`QuadratureDecoder::configure`]).
    pub fn configure(&mut self, config: DecoderConfig) {
        self.decoder.configure(config);
    }

    /// Settles the decoder on its present levels ([`QuadratureDecoder::settle`]) if no edge
    /// changed anything since the snapshot whose sequence number is `edges`. Returns whether
    /// the rest moved.
    pub fn settle_if_unmoved(&mut self, edges: u32) -> bool {
        let moved_rest = edges == self.edges && self.decoder.settle();
        if moved_rest {
            self.rests_learnt = self.rests_learnt.wrapping_add(1);
        }
        moved_rest
    }

    /// How many settles at standstill moved the rest.
    pub fn rests_learnt(&self) -> u32 {
        self.rests_learnt
    }

    /// The decoder itself.
    pub fn decoder(&self) -> &QuadratureDecoder {
        &self.decoder
    }
}

/// The edge state owned in place is its own lock: on the host (tests, benches, models) the
/// CAN side's [`LinkedWheel`](crate::LinkedWheel) holds it directly and runs its edges
/// synchronously, as the firmware's holds RTIC's proxy of the shared resource; both are
/// RTIC's [`Mutex`].
impl Mutex for EdgeState {
    type T = Self;

    #[inline]
    fn lock<R>(&mut self, f: impl FnOnce(&mut Self) -> R) -> R {
        f(self)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::decoder::CountsPerDetent;

    const START: AbLevels = AbLevels::from_bits(0);

    #[test]
    fn edges_publish_counts_detents_and_illegal_jumps() {
        let mut edge = EdgeState::new(DecoderConfig::default(), START);
        let mut levels = START;
        let mut due = [false; 4];
        for d in &mut due {
            levels = levels.next_forward();
            *d = edge.on_edge(levels);
        }
        assert_eq!(due, [false, false, false, true]);
        assert!(!edge.on_edge(levels), "no change: nothing published");
        assert!(!edge.on_edge(AbLevels::from_bits(levels.bits() ^ 0b11)));
        assert_eq!(
            edge.snapshot(),
            EdgeSnapshot {
                edges: 5,
                count: 4,
                detents: 1,
                illegal: 1
            }
        );
    }

    #[test]
    fn configure_takes_the_present_levels_as_the_rest() {
        let mut edge = EdgeState::new(DecoderConfig::default(), START);
        let half = START.next_forward().next_forward();
        let _ = edge.on_edge(START.next_forward());
        let _ = edge.on_edge(half);
        edge.configure(DecoderConfig {
            counts_per_detent: CountsPerDetent::Four,
            invert: false,
        });
        // A whole cycle from the new rest is one detent.
        let mut levels = half;
        let mut detents = 0;
        for _ in 0..4 {
            levels = levels.next_forward();
            detents += i32::from(edge.on_edge(levels));
        }
        assert_eq!(detents, 1);
        assert_eq!(edge.snapshot().detents, 1);
    }

    /// The one protocol left between the CAN side's locks: a settle decided on a snapshot
    /// applies only if no edge changed anything between that snapshot and the settle. Every
    /// sequence of up to three edges (each to any of the four level pairs) is run between
    /// the two, from a wheel stopped half a detent off its rest.
    #[test]
    fn a_settle_applies_only_if_no_edge_changed_anything_since_its_snapshot() {
        let off_rest = START.next_forward().next_forward();
        let mut runs = 0;
        for len in 0..=3u32 {
            for code in 0..4u32.pow(len) {
                let mut edge = EdgeState::new(DecoderConfig::default(), START);
                let _ = edge.on_edge(START.next_forward());
                let _ = edge.on_edge(off_rest);
                let decided_on = edge.snapshot();
                let mut changed = false;
                for i in 0..len {
                    let levels = AbLevels::from_bits(((code >> (2 * i)) & 0b11) as u8);
                    let before = edge.snapshot();
                    let _ = edge.on_edge(levels);
                    changed |= edge.snapshot() != before;
                }
                let still_off_rest = edge.decoder().levels() == off_rest;
                let settled = edge.settle_if_unmoved(decided_on.edges);
                assert_eq!(
                    settled,
                    !changed && still_off_rest,
                    "edges {code:#x} (len {len})"
                );
                assert_eq!(edge.rests_learnt(), u32::from(settled));
                if !changed {
                    assert!(settled, "nothing moved: the rest is learnt");
                }
                runs += 1;
            }
        }
        assert_eq!(runs, 1 + 4 + 16 + 64);
    }
}
