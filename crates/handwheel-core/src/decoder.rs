//! Quadrature decoding of the wheel's A/B channels.
//!
//! The EXTI interrupt fires on both edges of both channels and hands the decoder the two
//! levels read in one port read. The decoder compares them with the previous levels through a
//! 16-entry Gray-code table: one channel changed is a count forward or back, nothing changed
//! is a bounce the interrupt caught late, both changed is an illegal jump (an edge was
//! missed) which is counted and never turned into motion, because its direction is unknown.
//!
//! Because every edge of both channels counts, a channel that chatters while the wheel rests
//! on its edge produces +1, -1, +1, -1 ... and nets to zero, unlike the paper's
//! rising-edge-of-B scheme which turns the same chatter into motion.
//!
//! # Detents are reported at the wheel's rest levels
//!
//! A detent wheel can only come to rest at its detents, and at a detent its A/B levels are
//! always the same (with 4 counts per detent) or one of two opposite pairs (2 counts: a rest
//! and the levels two counts away) or anything (1 count). The decoder keeps those *rest
//! levels* as a 4-bit mask and reports motion only when the wheel arrives at one of them: the
//! count travelled since the previous arrival (`delta`) is then 0 (it went out and came back)
//! or a whole detent either way. A detent is reported when `|delta| >= cpd / 2 + 1`, so:
//!
//! - chatter anywhere, including on the edge that leads into a rest state, nets to zero: a
//!   chattering edge next to a rest completes the detent on its first arrival (one edge
//!   early, if the wheel then goes on), and every further arrival there has `delta` 0;
//! - a reversal costs nothing: going back from a rest state to the previous one is a whole
//!   detent of travel, reported as such. (Reporting a full detent past the last report point
//!   instead would, with the rest off that point's phase, lose a detent at every reversal
//!   and report no single-detent jog at all);
//! - `delta` is always even with 2 or 4 counts per detent; an illegal jump between two
//!   arrivals shifts the levels by two counts without counting, so with 4 counts per detent
//!   the next arrival can see `delta` = +-2 (half a detent of known travel: never turned into
//!   motion) or +-6 (one detent reported, not two). An illegal jump that lands on rest levels
//!   is not an arrival: the wheel's true position is unknown there, and resynchronising on it
//!   would turn the jump's unknown half detent into motion on the way back. Left alone,
//!   turning back over the same ground nets zero, as the wheel did.
//!
//! # Where the rest levels come from
//!
//! An untouched wheel rests on a detent, so the levels read at start-up are the rest;
//! [`QuadratureDecoder::configure`] takes the present levels as the rest. A wheel that comes
//! to rest anywhere else (the levels were read mid-detent at start-up, or the wheel was
//! nudged by half a detent and its detent spring did not take it back, as the emulated
//! board's control line can do) teaches the decoder its true rest through [`QuadratureDecoder::settle`]: the
//! CAN side calls it through [`Standstill`](crate::Standstill) once the levels have not
//! changed for [`STANDSTILL_MS`](crate::STANDSTILL_MS). Settling never reports a detent, so
//! it never moves an axis.
//!
//! Its accepted cost: a detent wheel held still mid-detent for at least the standstill time
//! (a hand holding it against its spring) has that position learnt as its rest. Finishing
//! that detent then reports nothing, and until the wheel next stands still at a true detent,
//! which becomes the rest again, the feed is either level with the wheel or that one detent
//! short of it (a reversal in between catches it up, the next turn the held way falls behind
//! again). So the hold can lose that one detent, never gain one.
//!
//! With one count per detent every level is a rest state and every count is a detent: no
//! hysteresis is possible without swallowing real motion.
//!
//! Cost per edge: one table lookup, a mask test, two additions and two comparisons. No
//! loops, no division.

/// The two channel levels as read from the port: bit 0 = A, bit 1 = B.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct AbLevels(u8);

impl AbLevels {
    /// Levels from the two channel states.
    #[inline]
    pub const fn new(a: bool, b: bool) -> Self {
        Self((a as u8) | ((b as u8) << 1))
    }

    /// Levels from bits (bit 0 = A, bit 1 = B); higher bits are ignored.
    #[inline]
    pub const fn from_bits(bits: u8) -> Self {
        Self(bits & 0b11)
    }

    /// Bit 0 = A, bit 1 = B.
    #[inline]
    pub const fn bits(self) -> u8 {
        self.0
    }

    /// Level of channel A.
    #[inline]
    pub const fn a(self) -> bool {
        self.0 & 1 != 0
    }

    /// Level of channel B.
    #[inline]
    pub const fn b(self) -> bool {
        self.0 & 2 != 0
    }

    /// The next state one count forward (A leads B): 00 -> A -> AB -> B -> 00.
    #[must_use]
    pub const fn next_forward(self) -> Self {
        // Gray order of the 2-bit value: 0 -> 1 -> 3 -> 2 -> 0.
        Self::from_bits([1, 3, 0, 2][self.0 as usize])
    }

    /// The next state one count in reverse (B leads A).
    #[must_use]
    pub const fn next_reverse(self) -> Self {
        Self::from_bits([2, 0, 3, 1][self.0 as usize])
    }
}

/// What one pair of levels means relative to the previous pair.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Transition {
    /// Same levels as before: a bounce already undone, or a late interrupt.
    Stay,
    /// One count with A leading B.
    Forward,
    /// One count with B leading A.
    Reverse,
    /// Both channels changed: at least one edge was missed.
    Illegal,
}

impl Transition {
    /// The transition from `from` to `to`.
    #[inline]
    pub const fn between(from: AbLevels, to: AbLevels) -> Self {
        // Both levels are masked to 2 bits on construction; the mask here lets the compiler
        // see it too, so the ISR has no bounds check.
        TRANSITIONS[(((from.0 << 2) | to.0) & 0xF) as usize]
    }
}

use Transition::{Forward as F, Illegal as X, Reverse as R, Stay as S};

/// Indexed by `previous << 2 | current` (each: bit 0 = A, bit 1 = B). Forward is the Gray
/// sequence 0 -> 1 -> 3 -> 2 -> 0 (A rises first, as in the paper: B rising with A high is
/// forward).
const TRANSITIONS: [Transition; 16] = [
    // to:  00 01 10 11
    S, F, R, X, // from 00
    R, S, X, F, // from 01 (A)
    F, X, S, R, // from 10 (B)
    X, R, F, S, // from 11 (A and B)
];

/// A step-table entry for an illegal transition (the others are 0, +1 and -1).
const ILLEGAL_STEP: i8 = 2;

/// [`TRANSITIONS`] as signed steps in the counting direction, so that the edge needs one
/// lookup and no test of the inversion: index 0 counts A-leading-B forward, index 1 backward.
static STEPS: [[i8; 16]; 2] = [steps(false), steps(true)];

const fn steps(invert: bool) -> [i8; 16] {
    let mut table = [0; 16];
    let mut i = 0;
    while i < 16 {
        let forward = if invert { -1 } else { 1 };
        table[i] = match TRANSITIONS[i] {
            Transition::Stay => 0,
            Transition::Forward => forward,
            Transition::Reverse => -forward,
            Transition::Illegal => ILLEGAL_STEP,
        };
        i += 1;
    }
    table
}

/// Counts per detent of the wheel: one full quadrature cycle (4) on a typical 100-detent MPG.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, Hash)]
#[repr(u8)]
pub enum CountsPerDetent {
    /// Every count is a detent.
    One = 1,
    /// Half a quadrature cycle per detent.
    Two = 2,
    /// A full quadrature cycle per detent (the usual MPG).
    #[default]
    Four = 4,
}

impl CountsPerDetent {
    /// From the object dictionary value; only 1, 2 and 4 are valid.
    pub const fn from_u8(value: u8) -> Option<Self> {
        match value {
            1 => Some(Self::One),
            2 => Some(Self::Two),
            4 => Some(Self::Four),
            _ => None,
        }
    }

    /// The number of counts.
    #[inline]
    pub const fn get(self) -> u8 {
        self as u8
    }
}

/// Decoder settings (object 0x2020 sub 3 and 4).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, Hash)]
pub struct DecoderConfig {
    /// Counts that make one detent.
    pub counts_per_detent: CountsPerDetent,
    /// Swap forward and reverse (a wheel wired B-for-A, or mounted facing the other way).
    pub invert: bool,
}

/// What one edge did.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[must_use = "a detent that is not passed on is lost motion"]
pub enum EdgeOutcome {
    /// No change of levels.
    Idle,
    /// A count that did not complete a detent.
    Counted,
    /// A count that completed a detent forward.
    DetentForward,
    /// A count that completed a detent in reverse.
    DetentReverse,
    /// Both channels changed; counted as an error, no motion.
    Illegal,
}

impl EdgeOutcome {
    /// Detents moved by this edge: -1, 0 or +1.
    #[inline]
    pub const fn detents(self) -> i32 {
        match self {
            Self::DetentForward => 1,
            Self::DetentReverse => -1,
            _ => 0,
        }
    }
}

/// The quadrature decoder state: the edge interrupt's own (see [`edge`](crate::edge)), and
/// the host tests'.
#[derive(Clone, Debug, Hash)]
pub struct QuadratureDecoder {
    /// [`STEPS`] for the counting direction: one lookup per edge, no test of `invert`.
    steps: &'static [i8; 16],
    previous: AbLevels,
    count: i32,
    /// The count at the last legal arrival at a rest state (or where the rest was set).
    last_rest: i32,
    /// Bit `i` set: levels with bits `i` are a rest state (see the module docs).
    rest_mask: u8,
    /// `cpd / 2 + 1`: the smallest travel between two arrivals that is a detent. Kept here so
    /// that `update` needs no division.
    threshold: i32,
    counts_per_detent: CountsPerDetent,
    invert: bool,
    illegal: u32,
}

/// The rest states for `cpd` counts per detent when the wheel rests at `rest`.
const fn rest_mask(cpd: CountsPerDetent, rest: AbLevels) -> u8 {
    let bits = rest.bits();
    match cpd {
        CountsPerDetent::One => 0b1111,
        // The opposite levels (both channels flipped) are two counts away either way.
        CountsPerDetent::Two => (1 << bits) | (1 << (bits ^ 0b11)),
        CountsPerDetent::Four => 1 << bits,
    }
}

/// The travel between two arrivals at rest states that counts as a detent: more than half a
/// detent. Legal motion only ever gives 0 or a whole detent; the margin matters after an
/// illegal jump (see the module docs).
const fn threshold(cpd: CountsPerDetent) -> i32 {
    (cpd.get() / 2 + 1) as i32
}

impl QuadratureDecoder {
    /// A decoder whose first comparison is against `initial`, the levels read at start-up,
    /// which are taken as the wheel's rest (an untouched wheel rests on a detent).
    pub const fn new(config: DecoderConfig, initial: AbLevels) -> Self {
        Self {
            steps: &STEPS[config.invert as usize],
            previous: initial,
            count: 0,
            last_rest: 0,
            rest_mask: rest_mask(config.counts_per_detent, initial),
            threshold: threshold(config.counts_per_detent),
            counts_per_detent: config.counts_per_detent,
            invert: config.invert,
            illegal: 0,
        }
    }

    /// Feeds the levels read after an edge interrupt. Constant time; runs in the edge's ISR.
    #[inline]
    pub fn update(&mut self, levels: AbLevels) -> EdgeOutcome {
        // Both levels are masked to 2 bits on construction; the masks let the compiler see
        // it too, so the ISR has no bounds check.
        let index = (((self.previous.0 << 2) | levels.0) & 0xF) as usize;
        self.previous = levels;
        let step = self.steps[index];
        if step == 0 {
            return EdgeOutcome::Idle;
        }
        if step == ILLEGAL_STEP {
            // Rare: keep the legal path the straight one.
            core::hint::cold_path();
            // Neither the count nor the last arrival moves: the jump's direction is unknown,
            // and landing on rest levels this way is not an arrival.
            self.illegal = self.illegal.wrapping_add(1);
            return EdgeOutcome::Illegal;
        }
        self.count = self.count.wrapping_add(i32::from(step));
        if !self.is_rest(levels) {
            return EdgeOutcome::Counted;
        }
        let delta = self.count.wrapping_sub(self.last_rest);
        self.last_rest = self.count;
        if delta >= self.threshold {
            EdgeOutcome::DetentForward
        } else if delta <= self.threshold.wrapping_neg() {
            EdgeOutcome::DetentReverse
        } else {
            EdgeOutcome::Counted
        }
    }

    /// The wheel has been still at its present levels for the standstill time
    /// ([`Standstill`](crate::Standstill) decides when). If those levels are not a rest
    /// state, the wheel evidently rests there: they become the rest, and the travel since
    /// the last arrival is dropped. Returns whether the rest changed.
    ///
    /// Never reports a detent, so settling never moves an axis. Settling mid-detent (the
    /// wheel held against its spring) can lose the detent being turned, never gain one: see
    /// the module docs.
    pub fn settle(&mut self) -> bool {
        if self.is_rest(self.previous) {
            return false;
        }
        self.rest_here();
        true
    }

    /// Changes counts-per-detent and direction. The present levels become the rest and the
    /// partial detent in progress is dropped, so the new setting starts from the wheel's
    /// present position.
    pub fn configure(&mut self, config: DecoderConfig) {
        self.counts_per_detent = config.counts_per_detent;
        self.threshold = threshold(config.counts_per_detent);
        self.invert = config.invert;
        self.steps = &STEPS[config.invert as usize];
        self.rest_here();
    }

    /// The present settings.
    pub fn config(&self) -> DecoderConfig {
        DecoderConfig {
            counts_per_detent: self.counts_per_detent,
            invert: self.invert,
        }
    }

    /// Signed counts since start-up, inversion applied, wrapping (object 0x2020 sub 1).
    pub const fn count(&self) -> i32 {
        self.count
    }

    /// Illegal transitions since start-up, wrapping (object 0x2020 sub 2).
    pub const fn illegal_transitions(&self) -> u32 {
        self.illegal
    }

    /// Counts since the last arrival at a rest state (or since the rest was set), wrapping.
    /// Without illegal jumps it stays inside `(-counts_per_detent, counts_per_detent)`; an
    /// illegal jump can carry the wheel past a rest state without an arrival, so then it is
    /// not bounded.
    pub const fn since_rest(&self) -> i32 {
        self.count.wrapping_sub(self.last_rest)
    }

    /// The last levels seen.
    pub const fn levels(&self) -> AbLevels {
        self.previous
    }

    /// Whether `levels` are a rest state.
    #[inline]
    const fn is_rest(&self, levels: AbLevels) -> bool {
        // The bits are masked on construction; masking again lets the compiler see that the
        // shift cannot overflow, so the ISR has no overflow check in a checked build.
        (self.rest_mask >> (levels.bits() & 0b11)) & 1 != 0
    }

    /// The present levels become the rest; the present count is the last arrival.
    fn rest_here(&mut self) {
        self.rest_mask = rest_mask(self.counts_per_detent, self.previous);
        self.last_rest = self.count;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const ALL: [AbLevels; 4] = [
        AbLevels::from_bits(0),
        AbLevels::from_bits(1),
        AbLevels::from_bits(2),
        AbLevels::from_bits(3),
    ];

    fn decoder(cpd: CountsPerDetent, invert: bool) -> QuadratureDecoder {
        QuadratureDecoder::new(
            DecoderConfig {
                counts_per_detent: cpd,
                invert,
            },
            AbLevels::from_bits(0),
        )
    }

    /// `counts` legal edges from `levels` (negative: in reverse), leaving `levels` where the
    /// wheel ends; returns the detents reported on the way.
    fn walk(d: &mut QuadratureDecoder, levels: &mut AbLevels, counts: i32) -> i32 {
        let mut detents = 0;
        for _ in 0..counts.unsigned_abs() {
            *levels = if counts > 0 {
                levels.next_forward()
            } else {
                levels.next_reverse()
            };
            detents += d.update(*levels).detents();
        }
        detents
    }

    #[test]
    fn table_classifies_every_pair_by_hamming_distance_and_gray_order() {
        for from in ALL {
            for to in ALL {
                let changed = (from.bits() ^ to.bits()).count_ones();
                let expected = match changed {
                    0 => Transition::Stay,
                    2 => Transition::Illegal,
                    _ if to == from.next_forward() => Transition::Forward,
                    _ => Transition::Reverse,
                };
                assert_eq!(
                    Transition::between(from, to),
                    expected,
                    "{from:?} -> {to:?}"
                );
            }
        }
    }

    #[test]
    fn forward_and_reverse_neighbours_are_inverse() {
        for s in ALL {
            assert_eq!(s.next_forward().next_reverse(), s);
            assert_eq!(s.next_reverse().next_forward(), s);
            assert_ne!(s.next_forward(), s.next_reverse());
        }
    }

    #[test]
    fn a_rises_first_when_moving_forward() {
        // The paper's convention: on the rising edge of B, A high means forward.
        let start = AbLevels::new(false, false);
        let one = start.next_forward();
        assert!(one.a() && !one.b());
        let two = one.next_forward();
        assert!(two.a() && two.b());
    }

    #[test]
    fn one_full_cycle_is_one_detent_at_four_counts() {
        let mut d = decoder(CountsPerDetent::Four, false);
        let mut levels = AbLevels::from_bits(0);
        let mut outcomes = [EdgeOutcome::Idle; 4];
        for o in &mut outcomes {
            levels = levels.next_forward();
            *o = d.update(levels);
        }
        assert_eq!(
            outcomes,
            [
                EdgeOutcome::Counted,
                EdgeOutcome::Counted,
                EdgeOutcome::Counted,
                EdgeOutcome::DetentForward
            ]
        );
        assert_eq!(d.count(), 4);
        assert_eq!(d.since_rest(), 0);
    }

    #[test]
    fn counts_per_detent_one_and_two() {
        for (cpd, detents_per_cycle) in [(CountsPerDetent::One, 4), (CountsPerDetent::Two, 2)] {
            let mut d = decoder(cpd, false);
            let mut levels = AbLevels::from_bits(0);
            let mut detents = 0;
            for _ in 0..4 {
                levels = levels.next_reverse();
                detents += d.update(levels).detents();
            }
            assert_eq!(detents, -detents_per_cycle, "{cpd:?}");
            assert_eq!(d.count(), -4);
        }
    }

    #[test]
    fn inversion_flips_counts_and_detents() {
        let mut d = decoder(CountsPerDetent::Four, true);
        let mut levels = AbLevels::from_bits(0);
        let mut detents = 0;
        for _ in 0..8 {
            levels = levels.next_forward();
            detents += d.update(levels).detents();
        }
        assert_eq!(detents, -2);
        assert_eq!(d.count(), -8);
    }

    #[test]
    fn same_levels_are_idle_and_change_nothing() {
        let mut d = decoder(CountsPerDetent::Four, false);
        assert_eq!(d.update(AbLevels::from_bits(0)), EdgeOutcome::Idle);
        assert_eq!((d.count(), d.illegal_transitions()), (0, 0));
    }

    #[test]
    fn illegal_jump_is_counted_not_guessed() {
        let mut d = decoder(CountsPerDetent::Four, false);
        assert_eq!(d.update(AbLevels::from_bits(3)), EdgeOutcome::Illegal);
        assert_eq!((d.count(), d.illegal_transitions()), (0, 1));
        // Decoding continues from the new levels: 11 -> 10 is forward.
        assert_eq!(d.update(AbLevels::from_bits(2)), EdgeOutcome::Counted);
        assert_eq!(d.count(), 1);
        // Arriving at the rest (00) after two known counts: half a detent, never motion.
        assert_eq!(d.update(AbLevels::from_bits(0)), EdgeOutcome::Counted);
        assert_eq!((d.count(), d.since_rest()), (2, 0));
    }

    #[test]
    fn illegal_jump_onto_the_rest_does_not_resynchronise() {
        let mut d = decoder(CountsPerDetent::Four, false);
        let mut levels = AbLevels::from_bits(0);
        // Half a detent forward (00 -> 01 -> 11), then the edge to 10 is missed and the
        // ISR sees 00: the wheel probably completed the detent, but that is not known.
        assert_eq!(walk(&mut d, &mut levels, 2), 0);
        assert_eq!(d.update(AbLevels::from_bits(0)), EdgeOutcome::Illegal);
        levels = AbLevels::from_bits(0);
        assert_eq!((d.count(), d.since_rest()), (2, 2), "no arrival, no resync");
        // The wheel turns back one detent: it is back where it started, and so is the feed.
        assert_eq!(walk(&mut d, &mut levels, -4), 0);
        assert_eq!((d.count(), d.since_rest()), (-2, 0));
        // Whole detents count again from there.
        assert_eq!(walk(&mut d, &mut levels, 4), 1);
        assert_eq!(walk(&mut d, &mut levels, -8), -2);
    }

    #[test]
    fn six_counts_between_arrivals_are_one_detent() {
        let mut d = decoder(CountsPerDetent::Four, false);
        let mut levels = AbLevels::from_bits(0);
        assert_eq!(walk(&mut d, &mut levels, 3), 0);
        // 10 -> 01 skips the rest (00) without an arrival.
        assert_eq!(d.update(AbLevels::from_bits(1)), EdgeOutcome::Illegal);
        let outcomes = [3, 2, 0].map(|bits| d.update(AbLevels::from_bits(bits)));
        assert_eq!(
            outcomes,
            [
                EdgeOutcome::Counted,
                EdgeOutcome::Counted,
                EdgeOutcome::DetentForward
            ]
        );
        assert_eq!((d.count(), d.since_rest()), (6, 0));
    }

    #[test]
    fn resting_on_the_report_point_does_not_toggle() {
        let mut d = decoder(CountsPerDetent::Four, false);
        let mut levels = AbLevels::from_bits(0);
        for _ in 0..3 {
            levels = levels.next_forward();
            let _ = d.update(levels);
        }
        // The fourth edge completes the detent; the channel then chatters on that edge.
        let edge = levels.next_forward();
        let mut reports = 0;
        for _ in 0..50 {
            reports += d.update(edge).detents().abs();
            reports += d.update(levels).detents().abs();
        }
        assert_eq!(reports, 1);
        assert_eq!(d.count(), 3);
    }

    #[test]
    fn chatter_at_rest_never_reports() {
        for cpd in [CountsPerDetent::Two, CountsPerDetent::Four] {
            for start in ALL {
                for invert in [false, true] {
                    let mut d = QuadratureDecoder::new(
                        DecoderConfig {
                            counts_per_detent: cpd,
                            invert,
                        },
                        start,
                    );
                    let mut levels = start;
                    // At the start-up rest and at the rest one detent on.
                    for _ in 0..2 {
                        for edge in [levels.next_forward(), levels.next_reverse()] {
                            for _ in 0..20 {
                                assert_eq!(d.update(edge), EdgeOutcome::Counted);
                                assert_eq!(d.update(levels), EdgeOutcome::Counted);
                            }
                        }
                        assert_eq!(d.since_rest(), 0);
                        let before = d.count();
                        let detents = walk(&mut d, &mut levels, i32::from(cpd.get()));
                        assert_eq!(detents, if invert { -1 } else { 1 }, "{cpd:?} {start:?}");
                        assert_eq!(d.count() - before, detents * i32::from(cpd.get()));
                    }
                }
            }
        }
    }

    /// A wheel moved off its start-up rest: it starts at 00 and is moved half a detent
    /// (01, then 11), where it stays; whole detents are then turned from 11.
    #[test]
    fn rest_learnt_at_standstill_keeps_reversals_whole() {
        const TURNS: [i32; 6] = [5, -5, 3, -3, 1, -1];
        let play = |settle: bool| {
            let mut d = decoder(CountsPerDetent::Four, false);
            assert_eq!(d.update(AbLevels::from_bits(1)), EdgeOutcome::Counted);
            assert_eq!(d.update(AbLevels::from_bits(3)), EdgeOutcome::Counted);
            if settle {
                assert!(d.settle(), "11 is not the start-up rest");
                assert_eq!((d.count(), d.since_rest()), (2, 0));
            }
            let mut levels = AbLevels::from_bits(3);
            TURNS.map(|detents| {
                let reported = walk(&mut d, &mut levels, detents * 4);
                assert_eq!(levels, AbLevels::from_bits(3), "turns end where they start");
                reported
            })
        };
        assert_eq!(play(true), TURNS);
        // Without the standstill the rest stays at 00, half a detent off: every reversal
        // and every single-detent jog loses one.
        assert_eq!(play(false), [5, -4, 2, -2, 0, 0]);
    }

    #[test]
    fn settle_at_a_rest_state_changes_nothing() {
        for cpd in [
            CountsPerDetent::One,
            CountsPerDetent::Two,
            CountsPerDetent::Four,
        ] {
            let mut d = decoder(cpd, false);
            let mut levels = AbLevels::from_bits(0);
            assert!(!d.settle(), "{cpd:?}: the start-up levels are the rest");
            assert_eq!(walk(&mut d, &mut levels, 4), 4 / i32::from(cpd.get()));
            assert!(!d.settle(), "{cpd:?}: one cycle on");
            // Two counts on: a rest state for 1 and 2 counts per detent only.
            assert_eq!(walk(&mut d, &mut levels, 2), 2 / i32::from(cpd.get()));
            assert_eq!(d.settle(), cpd == CountsPerDetent::Four, "{cpd:?}");
            assert!(!d.settle(), "{cpd:?}: settled once");
            assert_eq!((d.count(), d.since_rest()), (6, 0));
        }
    }

    #[test]
    fn settle_mid_detent_costs_at_most_that_detent() {
        let mut d = decoder(CountsPerDetent::Four, false);
        let mut levels = AbLevels::from_bits(0);
        // A detent is turned with a long pause three counts in (at 10), which is learnt as
        // the rest without reporting anything.
        assert_eq!(walk(&mut d, &mut levels, 3), 0);
        assert!(d.settle());
        assert_eq!((d.count(), d.since_rest()), (3, 0));
        // Finishing that detent reports nothing: the feed is one detent behind the wheel.
        assert_eq!(walk(&mut d, &mut levels, 1), 0);
        // While the learnt rest is off, whole detents are reported one edge early (at 10),
        // so the feed stays one detent behind going forward and catches up on a reversal.
        assert_eq!(walk(&mut d, &mut levels, 4), 1);
        assert_eq!(walk(&mut d, &mut levels, -4), 0);
        assert_eq!(walk(&mut d, &mut levels, 4), 0, "behind again");
        // The wheel stands still at its true detent (00): that becomes the rest, and the
        // feed stays one detent behind for good: that detent was lost, none was gained.
        assert_eq!(levels, AbLevels::from_bits(0));
        assert!(d.settle());
        assert_eq!(walk(&mut d, &mut levels, 8), 2);
        assert_eq!(walk(&mut d, &mut levels, -4), -1);
        assert_eq!(walk(&mut d, &mut levels, 4), 1);
        assert_eq!(d.count(), 16);
    }

    #[test]
    fn reconfigure_drops_partial_detent() {
        let mut d = decoder(CountsPerDetent::Four, false);
        let mut levels = AbLevels::from_bits(0);
        assert_eq!(walk(&mut d, &mut levels, 1), 0);
        assert_eq!(d.since_rest(), 1);
        let cfg = DecoderConfig {
            counts_per_detent: CountsPerDetent::Two,
            invert: true,
        };
        d.configure(cfg);
        assert_eq!(d.config(), cfg);
        assert_eq!(d.since_rest(), 0);
        assert_eq!(d.count(), 1);
        // The present levels (01) are the rest now, and with 2 counts per detent so are the
        // opposite ones (10): two edges forward (inverted: back) are one detent.
        assert!(!d.settle());
        assert_eq!(walk(&mut d, &mut levels, 2), -1);
        assert_eq!(levels, AbLevels::from_bits(2));
        assert_eq!((d.count(), d.since_rest()), (-1, 0));
    }

    #[test]
    fn count_wraps_at_i32_limits() {
        let mut d = decoder(CountsPerDetent::One, false);
        d.count = i32::MAX;
        let _ = d.update(AbLevels::from_bits(1));
        assert_eq!(d.count(), i32::MIN);
    }

    #[test]
    fn counts_per_detent_accepts_only_1_2_4() {
        let valid: [u8; 3] = [1, 2, 4];
        for v in 0..=u8::MAX {
            assert_eq!(
                CountsPerDetent::from_u8(v).is_some(),
                valid.contains(&v),
                "{v}"
            );
        }
        assert_eq!(CountsPerDetent::default().get(), 4);
    }
}
