//! Property tests over random wheel walks: what the ISR would see from a real wheel, with
//! chatter and missed edges injected, against the ground truth of the walk.

use handwheel_core::{
    AbLevels, Axis, CountsPerDetent, DecoderConfig, FeedAccumulator, Handwheel, Multiplier,
    QuadratureDecoder, Selection,
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

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]

    /// The decoded count is the walk's legal net motion; jumps are counted exactly and add
    /// no motion; reported detents plus the residual account for every count.
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
        prop_assert_eq!(detents * cpd + i32::from(d.residual()), d.count());
        prop_assert!(i32::from(d.residual()).abs() < cpd);
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

    /// Whole detents turned with an axis and feed enabled become exactly detents x factor.
    #[test]
    fn wheel_position_is_detents_times_multiplier(
        detent_walk in prop::collection::vec(any::<bool>(), 0..200),
        chatter in prop::collection::vec(0..4u8, 0..200),
        factor in prop_oneof![Just(Multiplier::X1), Just(Multiplier::X10), Just(Multiplier::X100)],
        axis in 0..5usize,
    ) {
        let mut wheel = Handwheel::new(DecoderConfig::default(), AbLevels::from_bits(0));
        let _ = wheel.feed.set_selection(Selection { axis: Some(Axis::ALL[axis]), multiplier: factor });
        let _ = wheel.feed.set_enabled(true);
        let mut levels = AbLevels::from_bits(0);
        let mut net = 0i32;
        for (i, &forward) in detent_walk.iter().enumerate() {
            for _ in 0..4 {
                let bounces = chatter.get(i).copied().unwrap_or(0);
                let next = step(levels, forward);
                for _ in 0..bounces {
                    let _ = wheel.on_edge(next);
                    let _ = wheel.on_edge(levels);
                }
                levels = next;
                let _ = wheel.on_edge(levels);
            }
            net += if forward { 1 } else { -1 };
        }
        prop_assert_eq!(wheel.feed.position(), net * i32::from(factor.factor()));
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
        let _ = acc.set_unit_step_mode(true);
        let _ = acc.set_selection(Selection { axis: Some(Axis::X), multiplier: factor });
        let _ = acc.set_enabled(true);
        let mut added = 0i64;
        let mut sent = 0i64;
        for (detents, takes) in ops {
            let _ = acc.add_detents(detents);
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
