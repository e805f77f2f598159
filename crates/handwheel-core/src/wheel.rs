//! The CAN side's half of the wheel: the decoder as the edge task last published it, the
//! settings asked of it, and the feed accumulator, which belongs to the CAN side alone.
//!
//! The decoder lives in the [`EdgeState`] the edge and the CAN side share. The CAN side
//! reaches its [`Handwheel`] through a [`LinkedWheel`], which is itself an RTIC [`Mutex`] of
//! the handwheel over an RTIC [`Mutex`] of the edge state: on the MCU the proxy of the RTIC
//! resource, on the host the [`EdgeState`] itself, owned in place. So the device's code is
//! generic over `impl Mutex<T = Handwheel>`, as RTIC's own generic code is over its
//! resources, and runs unchanged on both.

use crate::accumulator::FeedAccumulator;
use crate::decoder::{AbLevels, DecoderConfig};
use crate::edge::{EdgeSnapshot, EdgeState, Mutex};

/// The CAN side's wheel: the edge's decoder as last published and the settings asked of it
/// (object 0x2020, with the bases that a reset of the application moves), the feed
/// accumulator, and whether a feed record is due.
#[derive(Clone, Debug)]
pub struct Handwheel {
    /// Feed accumulator (objects 0x2000, 0x2001, 0x2010, 0x2030, 0x6004).
    pub feed: FeedAccumulator,
    /// What a feed record carries (position, status, selection) changed, or the outbox holds
    /// more to send: TPDO1 is due. Set by the edge's motion and errors as they are taken in,
    /// and by the device for what it changes itself; taken by
    /// [`Handwheel::take_record_due`].
    pub record_due: bool,
    snapshot: EdgeSnapshot,
    config: DecoderConfig,
    count_base: i32,
    illegal_base: u32,
    rests_learnt: u32,
    /// Decoder commands not yet applied to the edge state.
    settings_pending: bool,
    settle_pending: Option<u32>,
}

impl Handwheel {
    const fn new(config: DecoderConfig) -> Self {
        Self {
            feed: FeedAccumulator::new(),
            record_due: false,
            snapshot: EdgeSnapshot {
                edges: 0,
                count: 0,
                detents: 0,
                illegal: 0,
            },
            config,
            count_base: 0,
            illegal_base: 0,
            rests_learnt: 0,
            settings_pending: false,
            settle_pending: None,
        }
    }

    /// Whether a feed record is due ([`Handwheel::record_due`]); clears it.
    #[must_use = "a changed feed needs a TPDO"]
    pub fn take_record_due(&mut self) -> bool {
        core::mem::take(&mut self.record_due)
    }

    /// Changes counts-per-detent and direction; the edge takes the present levels as the rest
    /// (see
    /// [`QuadratureDecoder::configure`](crate::QuadratureDecoder::configure)).
    pub fn configure_decoder(&mut self, config: DecoderConfig) {
        self.config = config;
        self.settings_pending = true;
    }

    /// [`Handwheel::configure_decoder`], and the count and the illegal transitions start
    /// from 0.
    pub fn reset_decoder(&mut self, config: DecoderConfig) {
        self.count_base = self.snapshot.count;
        self.illegal_base = self.snapshot.illegal;
        self.configure_decoder(config);
    }

    /// Signed counts since start-up or the last reset, inversion applied, wrapping (object
    /// 0x2020 sub 1).
    pub fn count(&self) -> i32 {
        self.snapshot.count.wrapping_sub(self.count_base)
    }

    /// Illegal transitions since start-up or the last reset, wrapping (0x2020 sub 2).
    pub fn illegal_transitions(&self) -> u32 {
        self.snapshot.illegal.wrapping_sub(self.illegal_base)
    }

    /// Settles at standstill that moved the rest.
    pub fn rests_learnt(&self) -> u32 {
        self.rests_learnt
    }

    /// What the edge had published when last looked at.
    pub fn snapshot(&self) -> EdgeSnapshot {
        self.snapshot
    }

    /// Asks the edge to settle on its present levels unless the wheel moved since
    /// [`Handwheel::snapshot`] (see
    /// [`QuadratureDecoder::settle`](crate::QuadratureDecoder::settle)).
    pub fn request_settle(&mut self) {
        self.settle_pending = Some(self.snapshot.edges);
    }
}

/// [`Handwheel`] joined to the shared edge state through its RTIC [`Mutex`], and itself the
/// RTIC [`Mutex`] of the handwheel.
///
/// Every [`lock`](Mutex::lock) first takes the edge's new detents and illegal transitions
/// into the accumulator under one short lock of the edge state (in the order of the CAN
/// side's calls: motion before a change of selection or enable belongs to the old one), then
/// runs the closure without that lock, then applies the decoder commands it made under a
/// second one.
#[derive(Clone, Debug)]
pub struct LinkedWheel<L> {
    edge: L,
    wheel: Handwheel,
}

impl<L: Mutex<T = EdgeState>> LinkedWheel<L> {
    /// The CAN side of a wheel whose edge task started with `config`.
    pub fn new(edge: L, config: DecoderConfig) -> Self {
        Self {
            edge,
            wheel: Handwheel::new(config),
        }
    }

    /// The feed accumulator, with the edge's publications taken in.
    pub fn feed(&mut self) -> &FeedAccumulator {
        self.sync();
        &self.wheel.feed
    }

    /// The edge state's lock: on the host, the edge state itself, for the edges.
    pub fn edge(&mut self) -> &mut L {
        &mut self.edge
    }

    /// Takes the edge's publications since the last call into the accumulator.
    fn sync(&mut self) {
        let (now, rests_learnt) = self.edge.lock(|e| (e.snapshot(), e.rests_learnt()));
        let wheel = &mut self.wheel;
        wheel.rests_learnt = rests_learnt;
        let detents = now.detents.wrapping_sub(wheel.snapshot.detents);
        let errors = now.illegal != wheel.snapshot.illegal;
        wheel.snapshot = now;
        // Motion and errors commute in the accumulator: their order within one sync does not
        // matter.
        let moved = wheel.feed.add_detents(detents);
        let flagged = errors && wheel.feed.note_encoder_error();
        wheel.record_due |= moved | flagged;
    }

    /// Applies what the last access asked of the decoder, under one lock.
    fn post(&mut self) {
        let wheel = &mut self.wheel;
        let settings = core::mem::take(&mut wheel.settings_pending).then_some(wheel.config);
        let settle = wheel.settle_pending.take();
        if settings.is_none() && settle.is_none() {
            return;
        }
        let learnt = self.edge.lock(|e| {
            if let Some(config) = settings {
                e.configure(config);
            }
            if let Some(edges) = settle {
                let _ = e.settle_if_unmoved(edges);
            }
            e.rests_learnt()
        });
        wheel.rests_learnt = learnt;
    }
}

impl LinkedWheel<EdgeState> {
    /// A wheel run on the host: edge state and CAN side in one value; its edges go to
    /// [`edge`](LinkedWheel::edge).
    pub fn local(config: DecoderConfig, initial: AbLevels) -> Self {
        Self::new(EdgeState::new(config, initial), config)
    }
}

impl<L: Mutex<T = EdgeState>> Mutex for LinkedWheel<L> {
    type T = Handwheel;

    fn lock<R>(&mut self, f: impl FnOnce(&mut Handwheel) -> R) -> R {
        self.sync();
        let result = f(&mut self.wheel);
        self.post();
        result
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::decoder::CountsPerDetent;
    use crate::{Axis, Multiplier, Selection};

    const START: AbLevels = AbLevels::from_bits(0);

    fn enabled_wheel() -> LinkedWheel<EdgeState> {
        let mut wheel = LinkedWheel::local(DecoderConfig::default(), START);
        wheel.lock(|w| {
            let _ = w.feed.set_enabled(true);
            let _ = w.feed.set_selection(Selection {
                axis: Some(Axis::X),
                multiplier: Multiplier::X10,
            });
        });
        wheel
    }

    #[test]
    fn edges_become_feed_only_at_detents() {
        let mut wheel = enabled_wheel();
        let mut levels = START;
        let mut due = [false; 8];
        for d in &mut due {
            levels = levels.next_forward();
            *d = wheel.edge().on_edge(levels);
        }
        assert_eq!(due, [false, false, false, true, false, false, false, true]);
        assert!(wheel.lock(Handwheel::take_record_due));
        assert!(!wheel.lock(Handwheel::take_record_due), "taken once");
        assert_eq!(wheel.lock(|w| w.feed.position()), 20);
        assert_eq!(wheel.lock(|w| w.count()), 8);
    }

    #[test]
    fn illegal_jump_sets_status_once() {
        let mut wheel = enabled_wheel();
        assert!(
            !wheel.edge().on_edge(AbLevels::from_bits(3)),
            "no wake-up for an illegal jump"
        );
        assert!(
            wheel.lock(Handwheel::take_record_due),
            "but the status changed"
        );
        assert!(!wheel.edge().on_edge(AbLevels::from_bits(0)));
        assert!(
            !wheel.lock(Handwheel::take_record_due),
            "the status was already latched"
        );
        wheel.lock(|w| {
            assert_eq!(w.illegal_transitions(), 2);
            assert!(w.feed.status().contains(crate::FeedStatus::ENCODER_ERROR));
            assert_eq!(w.feed.position(), 0);
        });
    }

    #[test]
    fn settings_reach_the_edge_and_reset_rebases_the_counters() {
        let mut wheel = enabled_wheel();
        let two = DecoderConfig {
            counts_per_detent: CountsPerDetent::Two,
            invert: true,
        };
        wheel.lock(|w| w.configure_decoder(two));
        // Two counts forward with inversion: one detent in reverse.
        let _ = wheel.edge().on_edge(START.next_forward());
        let _ = wheel.edge().on_edge(START.next_forward().next_forward());
        wheel.lock(|w| {
            assert_eq!(w.feed.position(), -10);
            assert_eq!(w.count(), -2);
            w.reset_decoder(DecoderConfig::default());
            assert_eq!(w.count(), 0);
        });
        // Back by four counts at 4 per detent, not inverted: one detent back.
        let mut levels = START.next_forward().next_forward();
        for _ in 0..4 {
            levels = levels.next_reverse();
            let _ = wheel.edge().on_edge(levels);
        }
        wheel.lock(|w| {
            assert_eq!(w.feed.position(), -20);
            assert_eq!(w.count(), -4);
        });
    }

    #[test]
    fn settle_applies_only_if_nothing_moved_since_the_snapshot() {
        let mut wheel = enabled_wheel();
        // Half a detent: off the rest.
        let mut levels = START.next_forward().next_forward();
        let _ = wheel.edge().on_edge(START.next_forward());
        let _ = wheel.edge().on_edge(levels);
        // The CAN side decides on a snapshot, the wheel moves before the request lands.
        let decided_on = wheel.lock(|w| w.snapshot().edges);
        assert_eq!(decided_on, 2);
        levels = levels.next_forward();
        let _ = wheel.edge().on_edge(levels);
        let settled = wheel.edge().lock(|e| e.settle_if_unmoved(decided_on));
        assert!(!settled, "moved: no settle");
        assert_eq!(wheel.edge().rests_learnt(), 0);
        // Asked with the present snapshot, it settles.
        wheel.lock(|w| w.request_settle());
        assert_eq!(wheel.lock(|w| w.rests_learnt()), 1);
    }
}
