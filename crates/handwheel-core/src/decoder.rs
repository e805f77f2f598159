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
//! Counts become detents with hysteresis: a detent is reported when the count has moved a
//! full detent (`counts_per_detent` counts) past the point of the last report, in either
//! direction. After a report, the opposite report needs a full detent of travel back, so a
//! wheel shaking around the point where a detent was reported emits nothing more. The anchor
//! is the position at start-up; an untouched wheel rests on a detent, so reports line up with
//! the detents. With one count per detent no hysteresis is possible without swallowing real
//! motion: every count is a detent.
//!
//! Cost per edge: one table lookup, two additions, two comparisons. No loops, no division.

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
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
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

/// Counts per detent of the wheel: one full quadrature cycle (4) on a typical 100-detent MPG.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
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
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct DecoderConfig {
    /// Counts that make one detent.
    pub counts_per_detent: CountsPerDetent,
    /// Swap forward and reverse (a wheel wired B-for-A, or mounted facing the other way).
    pub invert: bool,
}

/// What one edge did.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
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

/// The quadrature decoder state. Lives with the feed accumulator in the resource the EXTI
/// task shares with the CAN side.
#[derive(Clone, Debug)]
pub struct QuadratureDecoder {
    previous: AbLevels,
    count: i32,
    /// Counts since the last reported detent; always strictly inside `(-cpd, cpd)`.
    residual: i8,
    counts_per_detent: i8,
    invert: bool,
    illegal: u32,
}

impl QuadratureDecoder {
    /// A decoder whose first comparison is against `initial`, the levels read at start-up.
    pub const fn new(config: DecoderConfig, initial: AbLevels) -> Self {
        Self {
            previous: initial,
            count: 0,
            residual: 0,
            counts_per_detent: config.counts_per_detent.get() as i8,
            invert: config.invert,
            illegal: 0,
        }
    }

    /// Feeds the levels read after an edge interrupt. Constant time; runs in the ISR.
    #[inline]
    pub fn update(&mut self, levels: AbLevels) -> EdgeOutcome {
        let transition = Transition::between(self.previous, levels);
        self.previous = levels;
        let step: i8 = match transition {
            Transition::Stay => return EdgeOutcome::Idle,
            Transition::Illegal => {
                self.illegal = self.illegal.wrapping_add(1);
                return EdgeOutcome::Illegal;
            }
            Transition::Forward => 1,
            Transition::Reverse => -1,
        };
        let step = if self.invert { -step } else { step };
        self.count = self.count.wrapping_add(i32::from(step));
        self.residual += step;
        if self.residual >= self.counts_per_detent {
            self.residual -= self.counts_per_detent;
            EdgeOutcome::DetentForward
        } else if self.residual <= -self.counts_per_detent {
            self.residual += self.counts_per_detent;
            EdgeOutcome::DetentReverse
        } else {
            EdgeOutcome::Counted
        }
    }

    /// Changes counts-per-detent and direction. The partial detent in progress is dropped so
    /// the new setting starts from the wheel's present position.
    pub fn configure(&mut self, config: DecoderConfig) {
        self.counts_per_detent = config.counts_per_detent.get() as i8;
        self.invert = config.invert;
        self.residual = 0;
    }

    /// The present settings.
    pub fn config(&self) -> DecoderConfig {
        DecoderConfig {
            counts_per_detent: CountsPerDetent::from_u8(self.counts_per_detent as u8)
                .unwrap_or_default(),
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

    /// Counts since the last reported detent, in `(-counts_per_detent, counts_per_detent)`.
    pub const fn residual(&self) -> i8 {
        self.residual
    }

    /// The last levels seen.
    pub const fn levels(&self) -> AbLevels {
        self.previous
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
        assert_eq!(d.residual(), 0);
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
    fn illegal_jump_is_counted_not_guessed_and_resynchronises() {
        let mut d = decoder(CountsPerDetent::Four, false);
        assert_eq!(d.update(AbLevels::from_bits(3)), EdgeOutcome::Illegal);
        assert_eq!((d.count(), d.illegal_transitions()), (0, 1));
        // Decoding continues from the new levels: 11 -> 10 is forward.
        assert_eq!(d.update(AbLevels::from_bits(2)), EdgeOutcome::Counted);
        assert_eq!(d.count(), 1);
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
    fn reconfigure_drops_partial_detent() {
        let mut d = decoder(CountsPerDetent::Four, false);
        let _ = d.update(AbLevels::from_bits(1));
        assert_eq!(d.residual(), 1);
        let cfg = DecoderConfig {
            counts_per_detent: CountsPerDetent::Two,
            invert: true,
        };
        d.configure(cfg);
        assert_eq!(d.config(), cfg);
        assert_eq!(d.residual(), 0);
        assert_eq!(d.count(), 1);
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
