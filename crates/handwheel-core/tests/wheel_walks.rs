//! Property tests over random wheel walks: what the ISR would see from a real wheel, with
//! chatter and missed edges injected, against the ground truth of the walk.
//!
//! The decoder reports detents when the wheel arrives at its rest levels (see its module
//! docs); `settle()` moves the rest to where the wheel stands still. The properties below
//! check that reporting against the walk that produced the edges.

use handwheel_core::{
    AbLevels, Axis, CountsPerDetent, DecoderConfig, FeedAccumulator, Intake, LinkedWheel,
    Multiplier, Mutex, QuadratureDecoder, Selection, Wheel,
};
use proptest::prelude::*;

/// One thing the wheel does between two looks of the ISR.
#[derive(Clone, Copy, Debug)]
enum Move {
    /// One count forward or back.
    Step(bool),
    /// The channel that would change next chatters: there and back `n` times.
    Chatter { forward: bool, n: u8 },
    /// Both channels change at once (an edge the ISR missed).
    Jump,
    /// The ISR runs but the levels have not changed.
    Repeat,
}

fn moves() -> impl Strategy<Value = Vec<Move>> {
    let m = prop_oneof![
        8 => any::<bool>().prop_map(Move::Step),
        2 => (any::<bool>(), 1..20u8).prop_map(|(forward, n)| Move::Chatter { forward, n }),
        1 => Just(Move::Jump),
        1 => Just(Move::Repeat),
    ];
    prop::collection::vec(m, 0..400)
}

fn cpd() -> impl Strategy<Value = CountsPerDetent> {
    prop_oneof![
        Just(CountsPerDetent::One),
        Just(CountsPerDetent::Two),
        Just(CountsPerDetent::Four)
    ]
}

fn step(levels: AbLevels, forward: bool) -> AbLevels {
    if forward {
        levels.next_forward()
    } else {
        levels.next_reverse()
    }
}

/// Ground truth of a walk: legal net counts and missed-edge jumps.
#[derive(Default, Debug)]
struct Truth {
    net_counts: i32,
    jumps: u32,
}

/// Plays `walk` into `decoder`, returning the truth and the detents the decoder reported.
fn play(decoder: &mut QuadratureDecoder, start: AbLevels, walk: &[Move]) -> (Truth, i32) {
    let mut truth = Truth::default();
    let mut levels = start;
    let mut detents = 0;
    for &m in walk {
        match m {
            Move::Step(forward) => {
                levels = step(levels, forward);
                truth.net_counts += if forward { 1 } else { -1 };
                detents += decoder.update(levels).detents();
            }
            Move::Chatter { forward, n } => {
                let rest = levels;
                let edge = step(levels, forward);
                for _ in 0..n {
                    detents += decoder.update(edge).detents();
                    detents += decoder.update(rest).detents();
                }
            }
            Move::Jump => {
                levels = AbLevels::from_bits(levels.bits() ^ 0b11);
                truth.jumps += 1;
                detents += decoder.update(levels).detents();
            }
            Move::Repeat => detents += decoder.update(levels).detents(),
        }
    }
    (truth, detents)
}

/// Returning chatter: the wheel's levels go `n` times to the neighbour on one side and back,
/// one channel toggling `2 n` times.
#[derive(Clone, Copy, Debug)]
struct Chatter {
    /// Before which edge of the detent, counted modulo the counts per detent.
    edge: u8,
    /// Towards the next state forward, or the next in reverse.
    forward: bool,
    n: u8,
}

/// One whole detent of a walk: its direction, the chatter on the way, and whether the wheel
/// stands still long enough after it for `settle()`.
#[derive(Clone, Debug)]
struct Detent {
    forward: bool,
    chatter: Vec<Chatter>,
    settle_after: bool,
}

fn detent_walk() -> impl Strategy<Value = Vec<Detent>> {
    let chatter =
        (0..4u8, any::<bool>(), 1..8u8).prop_map(|(edge, forward, n)| Chatter { edge, forward, n });
    let detent = (
        any::<bool>(),
        prop::collection::vec(chatter, 0..3),
        prop::bool::weighted(0.2),
    )
        .prop_map(|(forward, chatter, settle_after)| Detent {
            forward,
            chatter,
            settle_after,
        });
    prop::collection::vec(detent, 0..60)
}

/// Plays chatter at the present `levels`; returns the detents it reported.
fn chatter(decoder: &mut QuadratureDecoder, levels: AbLevels, c: Chatter) -> i32 {
    let edge = step(levels, c.forward);
    let mut detents = 0;
    for _ in 0..c.n {
        detents += decoder.update(edge).detents();
        detents += decoder.update(levels).detents();
    }
    detents
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]

    /// The decoded count is the walk's legal net motion and jumps are counted exactly, adding
    /// no motion. Reported detents account for every count up to the arrival at a rest state
    /// (`count - since_rest`): exactly without jumps, and with 1 or 2 counts per detent even
    /// with them. With 4, a jump shifts the levels by half a detent that was never counted,
    /// so each jump can leave at most 2 counts (half a detent) unreported or over-reported.
    #[test]
    fn decoded_count_matches_ground_truth(
        walk in moves(), start in 0..4u8, cpd in cpd(), invert in any::<bool>()
    ) {
        let start = AbLevels::from_bits(start);
        let mut d = QuadratureDecoder::new(DecoderConfig { counts_per_detent: cpd, invert }, start);
        let (truth, detents) = play(&mut d, start, &walk);
        let sign = if invert { -1 } else { 1 };
        prop_assert_eq!(d.count(), sign * truth.net_counts);
        prop_assert_eq!(d.illegal_transitions(), truth.jumps);
        let cpd = i32::from(cpd.get());
        let at_last_rest = d.count() - d.since_rest();
        let unreported = at_last_rest - detents * cpd;
        if truth.jumps == 0 || cpd < 4 {
            prop_assert_eq!(unreported, 0);
            prop_assert!(d.since_rest().abs() < cpd, "since_rest {}", d.since_rest());
        } else {
            prop_assert!(
                unreported.unsigned_abs() <= 2 * truth.jumps,
                "{} counts unreported after {} jumps", unreported, truth.jumps
            );
        }
    }

    /// A wheel that only ever jumps (missed edges, in whatever order) and repeats its levels
    /// never moves the count or reports a detent: a jump's direction is unknown.
    #[test]
    fn jumps_never_become_motion(
        walk in prop::collection::vec(any::<bool>(), 0..100),
        start in 0..4u8, cpd in cpd(), invert in any::<bool>()
    ) {
        let start = AbLevels::from_bits(start);
        let mut d = QuadratureDecoder::new(DecoderConfig { counts_per_detent: cpd, invert }, start);
        let walk: Vec<Move> = walk.iter().map(|&j| if j { Move::Jump } else { Move::Repeat }).collect();
        let (truth, detents) = play(&mut d, start, &walk);
        prop_assert_eq!(detents, 0);
        prop_assert_eq!(d.count(), 0);
        prop_assert_eq!(d.illegal_transitions(), truth.jumps);
        // An odd number of jumps leaves the wheel on the opposite levels, a rest state only
        // with 1 or 2 counts per detent; standing still there makes them the rest.
        let off_rest = cpd == CountsPerDetent::Four && truth.jumps % 2 == 1;
        prop_assert_eq!(d.settle(), off_rest);
        prop_assert_eq!(d.since_rest(), 0);
    }

    /// Chatter on one channel at any point of any walk nets to zero counts, and with two or
    /// more counts per detent reports at most one detent however long it lasts.
    #[test]
    fn dither_at_any_edge_nets_zero_and_does_not_toggle(
        prefix in moves(), start in 0..4u8, cpd in cpd(), forward in any::<bool>(), n in 1..200u8
    ) {
        let start = AbLevels::from_bits(start);
        let mut d = QuadratureDecoder::new(
            DecoderConfig { counts_per_detent: cpd, invert: false }, start);
        let _ = play(&mut d, start, &prefix);
        let rest = d.levels();
        let edge = step(rest, forward);
        let count_before = d.count();
        let mut reports = 0;
        let mut net = 0;
        for _ in 0..n {
            for levels in [edge, rest] {
                let detents = d.update(levels).detents();
                reports += detents.abs();
                net += detents;
            }
        }
        prop_assert_eq!(d.count(), count_before);
        prop_assert_eq!(d.illegal_transitions(), play(
            &mut QuadratureDecoder::new(DecoderConfig::default(), start), start, &prefix).0.jumps);
        if cpd == CountsPerDetent::One {
            prop_assert_eq!(net, 0);
        } else {
            prop_assert!(reports <= 1, "{reports} reports from chatter");
        }
    }

    /// Wherever the wheel rests (a misaligning prefix of 0..cpd counts,
    /// then a standstill), an arbitrary walk of whole detents with returning chatter anywhere,
    /// mid-detent included, and standstills between detents reports after every whole
    /// detent exactly the detents walked so far: the same as without the chatter.
    #[test]
    fn whole_detents_from_any_rest_are_reported_exactly_through_chatter(
        cpd in cpd(), invert in any::<bool>(), start in 0..4u8,
        prefix in prop::collection::vec(any::<bool>(), 0..4),
        walk in detent_walk(),
    ) {
        let start = AbLevels::from_bits(start);
        let mut d = QuadratureDecoder::new(DecoderConfig { counts_per_detent: cpd, invert }, start);
        let counts = cpd.get();
        let mut levels = start;
        let mut reported = 0;
        for &forward in prefix.iter().take(usize::from(counts - 1)) {
            levels = step(levels, forward);
            reported += d.update(levels).detents();
        }
        prop_assert_eq!(reported, 0, "less than a detent from the start-up rest");
        // The wheel came to rest there: the standstill makes that the rest, unless it is one
        // already (the start-up levels, or with 2 counts per detent their opposite).
        let was_rest = match cpd {
            CountsPerDetent::One => true,
            CountsPerDetent::Two => levels == start || levels.bits() == start.bits() ^ 0b11,
            CountsPerDetent::Four => levels == start,
        };
        prop_assert_eq!(d.settle(), !was_rest);
        prop_assert_eq!(d.since_rest(), 0);
        let rest_count = d.count();
        let sign = if invert { -1 } else { 1 };
        let mut walked = 0;
        for (i, detent) in walk.iter().enumerate() {
            for edge in 0..counts {
                for &c in detent.chatter.iter().filter(|c| c.edge % counts == edge) {
                    reported += chatter(&mut d, levels, c);
                }
                levels = step(levels, detent.forward);
                reported += d.update(levels).detents();
            }
            walked += if detent.forward { sign } else { -sign };
            prop_assert_eq!(reported, walked, "after detent {}", i);
            prop_assert_eq!(d.since_rest(), 0);
            if detent.settle_after {
                prop_assert!(!d.settle(), "a whole detent on is a rest state");
            }
        }
        prop_assert_eq!(d.count() - rest_count, walked * i32::from(counts));
    }

    /// Standstills at arbitrary points of a legal walk, mid-detent included: once the wheel
    /// has stood still at a true detent again, the feed is off the walk by at most one
    /// detent per standstill that was learnt mid-detent, and exact without one.
    #[test]
    fn standstills_anywhere_cost_at_most_one_detent_each(
        cpd in cpd(), invert in any::<bool>(), start in 0..4u8,
        walk in prop::collection::vec((any::<bool>(), prop::bool::weighted(0.1)), 0..300),
        finish in any::<bool>(),
    ) {
        let start = AbLevels::from_bits(start);
        let mut d = QuadratureDecoder::new(DecoderConfig { counts_per_detent: cpd, invert }, start);
        let counts = i32::from(cpd.get());
        let mut levels = start;
        let mut net = 0i32;
        let mut reported = 0;
        let mut mid_detent_settles = 0;
        for &(forward, settle) in &walk {
            levels = step(levels, forward);
            net += if forward { 1 } else { -1 };
            reported += d.update(levels).detents();
            if settle && d.settle() && net.rem_euclid(counts) != 0 {
                mid_detent_settles += 1;
            }
        }
        // On to the nearest true detent either way, and still there.
        while net.rem_euclid(counts) != 0 {
            levels = step(levels, finish);
            net += if finish { 1 } else { -1 };
            reported += d.update(levels).detents();
        }
        let _ = d.settle();
        let sign = if invert { -1 } else { 1 };
        let error = reported - sign * net / counts;
        prop_assert!(
            error.unsigned_abs() <= mid_detent_settles,
            "off by {} after {} mid-detent standstills", error, mid_detent_settles
        );
        // Realigned: the next detents are exact.
        for forward in [true, false, false, true] {
            let before = reported;
            for _ in 0..counts {
                levels = step(levels, forward);
                reported += d.update(levels).detents();
            }
            prop_assert_eq!(reported - before, if forward { sign } else { -sign });
        }
    }

    /// Whole detents turned with an axis and feed enabled become exactly detents x factor,
    /// wherever the CAN side happens to take the edge's publications in.
    #[test]
    fn wheel_position_is_detents_times_multiplier(
        detent_walk in prop::collection::vec(any::<bool>(), 0..200),
        chatter in prop::collection::vec(0..4u8, 0..200),
        syncs in prop::collection::vec(any::<bool>(), 0..800),
        factor in prop_oneof![Just(Multiplier::X1), Just(Multiplier::X10), Just(Multiplier::X100)],
        axis in 0..5usize,
    ) {
        let mut wheel = LinkedWheel::local(DecoderConfig::default(), AbLevels::from_bits(0));
        wheel.lock(|w| {
            w.feed.set_selection(Selection { axis: Some(Axis::ALL[axis]), multiplier: factor });
            w.feed.set_enabled(true);
        });
        let mut levels = AbLevels::from_bits(0);
        let mut net = 0i32;
        for (i, &forward) in detent_walk.iter().enumerate() {
            for _ in 0..4 {
                let bounces = chatter.get(i).copied().unwrap_or(0);
                let next = step(levels, forward);
                for _ in 0..bounces {
                    let _ = wheel.edge().on_edge(next);
                    let _ = wheel.edge().on_edge(levels);
                }
                levels = next;
                let _ = wheel.edge().on_edge(levels);
                if syncs.get(i * 4).copied().unwrap_or(false) {
                    wheel.take_motion(Intake::RoundStart);
                }
            }
            net += if forward { 1 } else { -1 };
        }
        wheel.take_motion(Intake::RoundStart);
        prop_assert_eq!(wheel.lock(|w| w.feed.position()), net * i32::from(factor.factor()));
    }

    /// The unit-step backlog never exceeds its bound, whatever the operator does, so the
    /// run-on after the wheel stops is at most `bound` frames; every unit turned is either
    /// sent, pending or counted as dropped.
    #[test]
    fn unit_step_backlog_is_bounded(
        ops in prop::collection::vec((-3..=3i32, 0..6usize), 0..300),
        bound in 1..200u16,
        factor in prop_oneof![Just(Multiplier::X1), Just(Multiplier::X10), Just(Multiplier::X100)],
    ) {
        let mut acc = FeedAccumulator::new();
        prop_assert!(acc.set_backlog_bound(bound));
        acc.set_unit_step_mode(true);
        let _ = acc.set_selection(Selection { axis: Some(Axis::X), multiplier: factor });
        acc.set_enabled(true);
        let mut added = 0i64;
        let mut sent = 0i64;
        for (detents, takes) in ops {
            acc.add_detents(detents);
            added += i64::from(detents) * i64::from(factor.factor());
            for _ in 0..takes {
                if let Some(s) = acc.take_unit_step() {
                    sent += if s.forward { 1 } else { -1 };
                }
            }
            prop_assert!(acc.pending_steps().unsigned_abs() <= u32::from(bound));
        }
        let unaccounted = (added - sent - i64::from(acc.pending_steps())).unsigned_abs();
        prop_assert!(unaccounted <= u64::from(acc.dropped_steps()));
        if acc.dropped_steps() == 0 {
            prop_assert_eq!(unaccounted, 0);
        }
        let mut run_on = 0;
        while acc.take_unit_step().is_some() {
            run_on += 1;
        }
        prop_assert!(run_on <= bound);
        prop_assert_eq!(acc.position() as i64, added);
    }
}
