//! The CAN side's half of the wheel: a view of the decoder the edge task runs, and the feed
//! accumulator, which belongs to the CAN side alone.
//!
//! The decoder lives in the [`EdgeState`] the edge and the CAN side share; the CAN side
//! reaches the wheel only through [`WheelAccess`], whose implementation on the MCU and on the
//! host is the same [`LinkedWheel`] over a different RTIC [`Mutex`] of the edge state: the
//! firmware's is the proxy of the RTIC resource, the host's the [`EdgeState`] itself, owned
//! in place.

use crate::accumulator::FeedAccumulator;
use crate::decoder::{AbLevels, DecoderConfig};
use crate::edge::{EdgeSnapshot, EdgeState, Mutex};

/// The CAN side's view of the edge's decoder: the last snapshot, the settings it asked for,
/// and the bases that a reset of the application moves (0x2020 counts from there).
#[derive(Clone, Debug)]
pub struct DecoderView {
    snapshot: EdgeSnapshot,
    config: DecoderConfig,
    count_base: i32,
    illegal_base: u32,
    rests_learnt: u32,
    /// Commands not yet applied to the edge state.
    settings_pending: bool,
    settle_pending: Option<u32>,
}

impl DecoderView {
    const fn new(config: DecoderConfig) -> Self {
        Self {
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

    /// Changes counts-per-detent and direction; the edge takes the present levels as the rest
    /// (see
    /// [`QuadratureDecoder::configure`](crate::QuadratureDecoder::configure)).
    pub fn configure(&mut self, config: DecoderConfig) {
        self.config = config;
        self.settings_pending = true;
    }

    /// [`DecoderView::configure`], and the count and the illegal transitions start from 0.
    pub fn reset(&mut self, config: DecoderConfig) {
        self.count_base = self.snapshot.count;
        self.illegal_base = self.snapshot.illegal;
        self.configure(config);
    }

    /// The settings asked for.
    pub fn config(&self) -> DecoderConfig {
        self.config
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

    /// The last snapshot.
    pub fn snapshot(&self) -> EdgeSnapshot {
        self.snapshot
    }

    /// Asks the edge to settle on its present levels unless the wheel moved since this
    /// view's snapshot (see [`QuadratureDecoder::settle`](crate::QuadratureDecoder::settle)).
    pub fn request_settle(&mut self) {
        self.settle_pending = Some(self.snapshot.edges);
    }
}

/// The CAN side's half of the wheel, reached through
/// [`WheelAccess`]: a view of the edge's decoder and the feed
/// accumulator, which belongs to the CAN side alone.
#[derive(Clone, Debug)]
pub struct Handwheel {
    /// The edge's decoder (object 0x2020).
    pub decoder: DecoderView,
    /// Feed accumulator (objects 0x2000, 0x2001, 0x2010, 0x2030, 0x6004).
    pub feed: FeedAccumulator,
    /// What a feed record carries (position, status, selection) changed, or the outbox holds
    /// more to send: TPDO1 is due. Set by the edge's motion and errors as they are taken in,
    /// and by the device for what it changes itself; taken by [`WheelAccess::take_record_due`].
    pub record_due: bool,
}

/// [`Handwheel`] joined to the shared edge state through its RTIC [`Mutex`].
///
/// Every access first takes the edge's new detents and illegal transitions into the
/// accumulator under one short lock (in the order of the CAN side's calls: motion before a
/// change of selection or enable belongs to the old one), then runs the access without the
/// lock, then applies the decoder commands it made under a second one.
#[derive(Clone, Debug)]
pub struct LinkedWheel<L> {
    link: L,
    wheel: Handwheel,
}

impl<L: Mutex<T = EdgeState>> LinkedWheel<L> {
    /// The CAN side of a wheel whose edge task started with `config`.
    pub fn new(link: L, config: DecoderConfig) -> Self {
        Self {
            link,
            wheel: Handwheel {
                decoder: DecoderView::new(config),
                feed: FeedAccumulator::new(),
                record_due: false,
            },
        }
    }

    /// The feed accumulator, with the edge's publications taken in.
    pub fn feed(&mut self) -> &FeedAccumulator {
        self.sync();
        &self.wheel.feed
    }

    /// The edge state's lock, for the edge itself on the host.
    pub fn link_mut(&mut self) -> &mut L {
        &mut self.link
    }

    /// Takes the edge's publications since the last call into the accumulator.
    fn sync(&mut self) {
        let (now, rests_learnt) = self.link.lock(|e| (e.snapshot(), e.rests_learnt()));
        let view = &mut self.wheel.decoder;
        view.rests_learnt = rests_learnt;
        let detents = now.detents.wrapping_sub(view.snapshot.detents);
        let errors = now.illegal != view.snapshot.illegal;
        view.snapshot = now;
        let feed = &mut self.wheel.feed;
        // Motion and errors commute in the accumulator: their order within one sync does not
        // matter.
        let moved = feed.add_detents(detents);
        let flagged = errors && feed.note_encoder_error();
        self.wheel.record_due |= moved | flagged;
    }

    /// Applies what the last access asked of the decoder, under one lock.
    fn post(&mut self) {
        let view = &mut self.wheel.decoder;
        let settings = core::mem::take(&mut view.settings_pending).then_some(view.config);
        let settle = view.settle_pending.take();
        if settings.is_none() && settle.is_none() {
            return;
        }
        let learnt = self.link.lock(|e| {
            if let Some(config) = settings {
                e.configure(config);
            }
            if let Some(edges) = settle {
                let _ = e.settle_if_unmoved(edges);
            }
            e.rests_learnt()
        });
        view.rests_learnt = learnt;
    }
}

impl LinkedWheel<EdgeState> {
    /// A wheel run on the host: edge state and CAN side in one value.
    pub fn local(config: DecoderConfig, initial: AbLevels) -> Self {
        Self::new(EdgeState::new(config, initial), config)
    }

    /// One edge interrupt that reads `levels`; `true` when it would pend the CAN side's
    /// wake-up.
    #[must_use = "a detent the CAN side is not told of waits for its next round"]
    pub fn on_edge(&mut self, levels: AbLevels) -> bool {
        self.link.on_edge(levels)
    }
}

impl<L: Mutex<T = EdgeState>> WheelAccess for LinkedWheel<L> {
    fn with_wheel<R>(&mut self, f: impl FnOnce(&mut Handwheel) -> R) -> R {
        self.sync();
        let result = f(&mut self.wheel);
        self.post();
        result
    }
}

/// Access to the CAN side's [`Handwheel`].
///
/// Each access first takes in what the edge task published since the last one, so the
/// accumulator sees motion in the order of the CAN side's own calls.
pub trait WheelAccess {
    /// Runs `f` on the wheel.
    fn with_wheel<R>(&mut self, f: impl FnOnce(&mut Handwheel) -> R) -> R;

    /// Whether a feed record is due ([`Handwheel::record_due`]); clears it.
    #[must_use = "a changed feed needs a TPDO"]
    fn take_record_due(&mut self) -> bool {
        self.with_wheel(|w| core::mem::take(&mut w.record_due))
    }
}

impl<W: WheelAccess + ?Sized> WheelAccess for &mut W {
    fn with_wheel<R>(&mut self, f: impl FnOnce(&mut Handwheel) -> R) -> R {
        (**self).with_wheel(f)
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
        wheel.with_wheel(|w| {
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
            *d = wheel.on_edge(levels);
        }
        assert_eq!(due, [false, false, false, true, false, false, false, true]);
        assert!(wheel.take_record_due());
        assert!(!wheel.take_record_due(), "taken once");
        assert_eq!(wheel.with_wheel(|w| w.feed.position()), 20);
        assert_eq!(wheel.with_wheel(|w| w.decoder.count()), 8);
    }

    #[test]
    fn illegal_jump_sets_status_once() {
        let mut wheel = enabled_wheel();
        assert!(
            !wheel.on_edge(AbLevels::from_bits(3)),
            "no wake-up for an illegal jump"
        );
        assert!(wheel.take_record_due(), "but the status changed");
        assert!(!wheel.on_edge(AbLevels::from_bits(0)));
        assert!(!wheel.take_record_due(), "the status was already latched");
        wheel.with_wheel(|w| {
            assert_eq!(w.decoder.illegal_transitions(), 2);
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
        wheel.with_wheel(|w| w.decoder.configure(two));
        // Two counts forward with inversion: one detent in reverse.
        let _ = wheel.on_edge(START.next_forward());
        let _ = wheel.on_edge(START.next_forward().next_forward());
        wheel.with_wheel(|w| {
            assert_eq!(w.feed.position(), -10);
            assert_eq!(w.decoder.count(), -2);
            w.decoder.reset(DecoderConfig::default());
            assert_eq!(w.decoder.count(), 0);
        });
        // Back by four counts at 4 per detent, not inverted: one detent back.
        let mut levels = START.next_forward().next_forward();
        for _ in 0..4 {
            levels = levels.next_reverse();
            let _ = wheel.on_edge(levels);
        }
        wheel.with_wheel(|w| {
            assert_eq!(w.feed.position(), -20);
            assert_eq!(w.decoder.count(), -4);
        });
    }

    #[test]
    fn settle_applies_only_if_nothing_moved_since_the_snapshot() {
        let mut wheel = enabled_wheel();
        // Half a detent: off the rest.
        let mut levels = START.next_forward().next_forward();
        let _ = wheel.on_edge(START.next_forward());
        let _ = wheel.on_edge(levels);
        // The CAN side decides on a snapshot, the wheel moves before the request lands.
        let view_edges = wheel.with_wheel(|w| w.decoder.snapshot().edges);
        assert_eq!(view_edges, 2);
        levels = levels.next_forward();
        let _ = wheel.link_mut().on_edge(levels);
        let settled = wheel.link_mut().lock(|e| e.settle_if_unmoved(view_edges));
        assert!(!settled, "moved: no settle");
        assert_eq!(wheel.link_mut().rests_learnt(), 0);
        // Asked with the present snapshot, it settles.
        wheel.with_wheel(|w| w.decoder.request_settle());
        assert_eq!(wheel.with_wheel(|w| w.decoder.rests_learnt()), 1);
    }
}
