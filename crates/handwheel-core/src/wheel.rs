//! The CAN side's half of the wheel: the decoder as the edge task last published it, the
//! settings asked of it, and the feed accumulator, which belongs to the CAN side alone.
//!
//! The decoder lives in the [`EdgeState`] the edge and the CAN side share. The CAN side
//! reaches its [`Handwheel`] through a [`LinkedWheel`], which is itself an RTIC [`Mutex`] of
//! the handwheel over an RTIC [`Mutex`] of the edge state: on the MCU the proxy of the RTIC
//! resource, on the host the [`EdgeState`] itself, owned in place. So the device's code is
//! generic over [`Wheel`], RTIC's `Mutex<T = Handwheel>` with the intake below, as RTIC's
//! own generic code is over its resources, and runs unchanged on both.
//!
//! # Where motion is taken in
//!
//! A lock of the wheel never looks at the edge. The edge's new detents and illegal
//! transitions reach the accumulator only where the CAN side takes them in
//! ([`Wheel::take_motion`], one short lock of the edge state), at the named points of a
//! round ([`Intake`]) that the ordering rule needs:
//! - [`Intake::RoundStart`], the round's first act: the motion that woke the round is in
//!   before anything in it looks at the wheel (the standstill sample, SDO reads, whether a
//!   record is due);
//! - [`Intake::BeforeChange`], right before every change of what motion counts for (feed
//!   enable, selection, session, unit-step format, a stop, a reset, and a sent record's
//!   number, which may end the session at the pace; [`Wheel::change`]):
//!   motion that came before the change belongs to the old state, so a detent turned while
//!   disabled is not made feed by the enable after it, nor one turned on X credited to Y;
//! - [`Intake::RecordSnapshot`], when TPDO1's record is taken: it carries all motion so far,
//!   and as nothing is taken in while its objects are read, they all read that one snapshot.
//!
//! Motion that comes after a round's last intake waits in the edge state for the next round,
//! which the edge's wake-up starts at once. The accumulator marks a feed record due itself
//! whenever what a record carries changes, motion taken in among it
//! ([`FeedAccumulator::take_record_due`]).

use crate::accumulator::FeedAccumulator;
use crate::decoder::{AbLevels, DecoderConfig};
use crate::edge::{EdgeSnapshot, EdgeState, Mutex};

/// The CAN side's wheel: the edge's decoder as last taken in and the settings asked of it
/// (object 0x2020, with the bases that a reset of the application moves), and the feed
/// accumulator.
#[derive(Clone, Debug, Hash)]
pub struct Handwheel {
    /// Feed accumulator (objects 0x2000, 0x2001, 0x2010, 0x2030, 0x6004).
    pub feed: FeedAccumulator,
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

    /// What the edge had published when its motion was last taken in.
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

/// A point of the CAN side's round where the edge's motion is taken in (see the module
/// docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Intake {
    /// The round's first act.
    RoundStart,
    /// Right before a change of what motion counts for ([`Wheel::change`]).
    BeforeChange,
    /// When TPDO1's record is taken.
    RecordSnapshot,
}

/// The CAN side's wheel as the device's code takes it: RTIC's lock of the [`Handwheel`],
/// which never looks at the edge, and the edge's motion taken in at the named points of a
/// round (see the module docs).
pub trait Wheel: Mutex<T = Handwheel> {
    /// Takes the edge's detents and illegal transitions since the last intake into the
    /// accumulator, under one short lock of the edge state. `at` names the point: the same
    /// intake at each, named for the reader and for the wheels of tests and the feed checker,
    /// which turn the wheel at a chosen one.
    fn take_motion(&mut self, at: Intake);

    /// A change of what motion counts for: the motion so far is taken in first
    /// ([`Intake::BeforeChange`]), so that it belongs to the old state, then `f` runs under
    /// the lock.
    fn change<R>(&mut self, f: impl FnOnce(&mut Handwheel) -> R) -> R {
        self.take_motion(Intake::BeforeChange);
        self.lock(f)
    }
}

/// [`Handwheel`] joined to the shared edge state through its RTIC [`Mutex`], and itself the
/// RTIC [`Mutex`] of the handwheel and a [`Wheel`].
///
/// A [`lock`](Mutex::lock) runs the closure without the edge's lock, then applies the decoder
/// commands it made under one short lock of the edge state; [`Wheel::take_motion`] takes the
/// edge's motion in under another.
#[derive(Clone, Debug, Hash)]
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

    /// The feed accumulator as the last intake left it (for tests and the checker).
    pub fn feed(&self) -> &FeedAccumulator {
        &self.wheel.feed
    }

    /// The edge state's lock: on the host, the edge state itself, for the edges.
    pub fn edge(&mut self) -> &mut L {
        &mut self.edge
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
        let result = f(&mut self.wheel);
        self.post();
        result
    }
}

impl<L: Mutex<T = EdgeState>> Wheel for LinkedWheel<L> {
    fn take_motion(&mut self, _at: Intake) {
        let (now, rests_learnt) = self.edge.lock(|e| (e.snapshot(), e.rests_learnt()));
        let wheel = &mut self.wheel;
        wheel.rests_learnt = rests_learnt;
        let detents = now.detents.wrapping_sub(wheel.snapshot.detents);
        let errors = now.illegal != wheel.snapshot.illegal;
        wheel.snapshot = now;
        // Motion and errors commute in the accumulator: their order within one intake does
        // not matter.
        wheel.feed.add_detents(detents);
        if errors {
            wheel.feed.note_encoder_error();
        }
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
            w.feed.set_enabled(true);
            w.feed.set_selection(Selection {
                axis: Some(Axis::X),
                multiplier: Multiplier::X10,
            });
            let _ = w.feed.take_record_due();
        });
        wheel
    }

    /// A round's first look at the wheel: the edge's motion taken in, then `f` under the lock.
    fn round<R>(wheel: &mut LinkedWheel<EdgeState>, f: impl FnOnce(&mut Handwheel) -> R) -> R {
        wheel.take_motion(Intake::RoundStart);
        wheel.lock(f)
    }

    fn take_due(w: &mut Handwheel) -> bool {
        w.feed.take_record_due()
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
        assert!(round(&mut wheel, take_due));
        assert!(!round(&mut wheel, take_due), "taken once");
        assert_eq!(wheel.lock(|w| w.feed.position()), 20);
        assert_eq!(wheel.lock(|w| w.count()), 8);
    }

    #[test]
    fn a_lock_takes_no_motion_in_only_an_intake_does() {
        let mut wheel = enabled_wheel();
        let mut levels = START;
        for _ in 0..4 {
            levels = levels.next_forward();
            let _ = wheel.edge().on_edge(levels);
        }
        let before = wheel.lock(|w| (w.feed.position(), w.count(), take_due(w)));
        assert_eq!(before, (0, 0, false), "the detent waits in the edge state");
        // A change made now comes after the detent, but the detent is taken in after it:
        // this is why every change takes the motion in first (`Wheel::change`).
        wheel.change(|w| w.feed.set_enabled(false));
        let after = wheel.lock(|w| (w.feed.position(), w.count(), w.feed.ignored_detents()));
        assert_eq!(
            after,
            (10, 4, 0),
            "taken in before the disable: feed at x10"
        );
        assert!(wheel.lock(take_due));
    }

    #[test]
    fn illegal_jump_sets_status_once() {
        let mut wheel = enabled_wheel();
        assert!(
            !wheel.edge().on_edge(AbLevels::from_bits(3)),
            "no wake-up for an illegal jump"
        );
        assert!(round(&mut wheel, take_due), "but the status changed");
        assert!(!wheel.edge().on_edge(AbLevels::from_bits(0)));
        assert!(
            !round(&mut wheel, take_due),
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
        round(&mut wheel, |w| {
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
        round(&mut wheel, |w| {
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
        let decided_on = round(&mut wheel, |w| w.snapshot().edges);
        assert_eq!(decided_on, 2);
        levels = levels.next_forward();
        let _ = wheel.edge().on_edge(levels);
        let settled = wheel.edge().lock(|e| e.settle_if_unmoved(decided_on));
        assert!(!settled, "moved: no settle");
        assert_eq!(wheel.edge().rests_learnt(), 0);
        // Asked with the present snapshot, it settles.
        round(&mut wheel, |w| w.request_settle());
        assert_eq!(wheel.lock(|w| w.rests_learnt()), 1);
    }
}
