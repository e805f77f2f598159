//! Noticing that the wheel stands still, so that the decoder can learn where it rests.
//!
//! The decoder reports detents at the wheel's rest levels (see [`decoder`](crate::decoder)).
//! Those are the levels at start-up; when the wheel comes to rest elsewhere for good (read
//! mid-detent at start-up, or moved by half a detent, as the emulated board's `ab` can do), the
//! decoder must be told, with [`QuadratureDecoder::settle`]. A wheel at rest makes no edges,
//! so the edge interrupt cannot notice standstill, and it has no cycles to spare for a clock
//! anyway: the CAN side samples the wheel on its 5 ms selector period instead, under one
//! short lock, through this type.

use crate::decoder::QuadratureDecoder;
use crate::wheel::Handwheel;

/// A decoder that [`Standstill`] can watch and settle: the edge's own
/// [`QuadratureDecoder`], or the CAN side's [`Handwheel`], which asks the edge's decoder
/// to settle.
pub trait Settle {
    /// Marks of motion: a change in any of them is motion (levels or the edge sequence,
    /// count, illegal transitions).
    fn motion_marks(&self) -> (u32, u32, u32);
    /// Takes the present levels as the rest if they are not one. Returns whether the rest
    /// changed, or for a view whether a settle was asked of the edge.
    fn settle(&mut self) -> bool;
}

impl Settle for QuadratureDecoder {
    fn motion_marks(&self) -> (u32, u32, u32) {
        (
            self.levels().bits().into(),
            self.count() as u32,
            self.illegal_transitions(),
        )
    }

    fn settle(&mut self) -> bool {
        QuadratureDecoder::settle(self)
    }
}

impl Settle for Handwheel {
    fn motion_marks(&self) -> (u32, u32, u32) {
        let s = self.snapshot();
        (s.edges, s.count as u32, s.illegal)
    }

    fn settle(&mut self) -> bool {
        self.request_settle();
        true
    }
}

/// How long the wheel must be still before its levels count as its rest, in ms.
///
/// Long against the gaps between the edges of a turning wheel (a slow turn of a 100-detent
/// wheel at one turn per minute still makes an edge every 150 ms), short against an
/// operator's pause between two jogs, which is when the rest has to be right.
pub const STANDSTILL_MS: u32 = 500;

/// What a sample of the wheel compares: any change in any mark is motion. The levels (or
/// the edge sequence) catch a turn between two samples; the count catches a whole cycle
/// turned (same levels); the illegal transitions catch a jump and back (same levels and
/// count).
/// (A tuple, not an array: comparing it needs no `memcmp` in the image.)
type Snapshot = (u32, u32, u32);

/// Calls [`Settle::settle`] once the wheel has been still for [`STANDSTILL_MS`],
/// once per standstill.
#[derive(Clone, Debug, Hash)]
pub struct Standstill {
    /// The previous sample; `None` before the first.
    last: Option<Snapshot>,
    /// When the wheel was first seen as it is now, ms (wrapping).
    since_ms: u32,
    /// `settle` is still to be called for this standstill.
    armed: bool,
}

impl Standstill {
    /// Nothing sampled yet.
    pub const fn new() -> Self {
        Self {
            last: None,
            since_ms: 0,
            armed: false,
        }
    }

    /// One periodic sample at `now_ms` (a wrapping millisecond clock). Returns what
    /// [`Settle::settle`] returned when this sample called it, else `false`.
    ///
    /// The standstill is timed from the first sample that saw the wheel as it is now, so the
    /// sampling period adds at most one period to [`STANDSTILL_MS`].
    pub fn sample(&mut self, now_ms: u32, decoder: &mut impl Settle) -> bool {
        let now = decoder.motion_marks();
        if self.last != Some(now) {
            self.last = Some(now);
            self.since_ms = now_ms;
            self.armed = true;
            return false;
        }
        // The difference of wrapping times is right across the wrap, as long as samples
        // come far more often than every 2^31 ms.
        if !self.armed || now_ms.wrapping_sub(self.since_ms) < STANDSTILL_MS {
            return false;
        }
        self.armed = false;
        decoder.settle()
    }
}

impl Default for Standstill {
    fn default() -> Self {
        Self::new()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::decoder::{AbLevels, CountsPerDetent, DecoderConfig, EdgeOutcome};

    const PERIOD_MS: u32 = 5;

    fn decoder() -> QuadratureDecoder {
        QuadratureDecoder::new(DecoderConfig::default(), AbLevels::from_bits(0))
    }

    /// `samples` samples 5 ms apart from `from_ms`; returns how many settled the decoder and
    /// the time of the last that did.
    fn run(
        s: &mut Standstill,
        d: &mut QuadratureDecoder,
        from_ms: u32,
        samples: u32,
    ) -> (u32, Option<u32>) {
        (0..samples)
            .map(|i| from_ms.wrapping_add(i * PERIOD_MS))
            .filter(|&t| s.sample(t, d))
            .fold((0, None), |(n, _), t| (n + 1, Some(t)))
    }

    const NONE: (u32, Option<u32>) = (0, None);

    /// Half a detent forward from 00: the wheel stays at 11, off the start-up rest.
    fn nudge(d: &mut QuadratureDecoder) {
        assert_eq!(d.update(AbLevels::from_bits(1)), EdgeOutcome::Counted);
        assert_eq!(d.update(AbLevels::from_bits(3)), EdgeOutcome::Counted);
    }

    #[test]
    fn settles_once_after_the_standstill_time() {
        let mut d = decoder();
        let mut s = Standstill::new();
        assert!(!s.sample(1_000, &mut d));
        nudge(&mut d);
        // Seen moved at 1005; still from then on: settled at 1005 + 500, not before.
        assert_eq!(run(&mut s, &mut d, 1_005, 200), (1, Some(1_505)));
        assert_eq!(d.since_rest(), 0);
        assert!(!d.settle(), "11 is the rest now");
        // Whole detents from 11 are reported.
        let mut levels = AbLevels::from_bits(3);
        let mut detents = 0;
        for _ in 0..4 {
            levels = levels.next_reverse();
            detents += d.update(levels).detents();
        }
        assert_eq!(detents, -1);
    }

    #[test]
    fn standstill_at_the_rest_changes_nothing() {
        let mut d = decoder();
        let mut s = Standstill::new();
        assert_eq!(run(&mut s, &mut d, 0, 1_000), NONE);
        assert_eq!((d.count(), d.since_rest()), (0, 0));
    }

    #[test]
    fn motion_restarts_the_clock() {
        let mut d = decoder();
        let mut s = Standstill::new();
        nudge(&mut d);
        assert_eq!(run(&mut s, &mut d, 0, 90), NONE, "450 ms still");
        // One edge back, seen by a sample, and forward again: the wheel is where it was, but
        // it moved, so the standstill starts over.
        let _ = d.update(AbLevels::from_bits(1));
        assert!(!s.sample(450, &mut d));
        let _ = d.update(AbLevels::from_bits(3));
        assert_eq!(run(&mut s, &mut d, 455, 200), (1, Some(955)));
    }

    #[test]
    fn a_whole_cycle_between_samples_is_motion() {
        let mut d = decoder();
        let mut s = Standstill::new();
        nudge(&mut d);
        assert_eq!(run(&mut s, &mut d, 0, 99), NONE, "490 ms still");
        // Four edges between two samples: same levels, count + 4.
        let mut levels = AbLevels::from_bits(3);
        for _ in 0..4 {
            levels = levels.next_forward();
            let _ = d.update(levels);
        }
        assert_eq!(levels, AbLevels::from_bits(3));
        assert_eq!(run(&mut s, &mut d, 495, 200), (1, Some(995)));
    }

    #[test]
    fn an_illegal_jump_and_back_between_samples_is_motion() {
        let mut d = decoder();
        let mut s = Standstill::new();
        nudge(&mut d);
        assert_eq!(run(&mut s, &mut d, 0, 99), NONE);
        assert_eq!(d.update(AbLevels::from_bits(0)), EdgeOutcome::Illegal);
        assert_eq!(d.update(AbLevels::from_bits(3)), EdgeOutcome::Illegal);
        assert_eq!(run(&mut s, &mut d, 495, 200), (1, Some(995)));
    }

    #[test]
    fn settles_again_only_after_the_wheel_moved() {
        let mut d = QuadratureDecoder::new(
            DecoderConfig {
                counts_per_detent: CountsPerDetent::Four,
                invert: false,
            },
            AbLevels::from_bits(0),
        );
        let mut s = Standstill::new();
        nudge(&mut d);
        assert_eq!(run(&mut s, &mut d, 0, 200), (1, Some(500)));
        // Still at 11 for a long time: no second call (it would return false anyway, but
        // `settle` must not run on every sample).
        assert_eq!(run(&mut s, &mut d, 1_000, 10_000), NONE);
        // Moved one count on (10) and still again: that is learnt too.
        let _ = d.update(AbLevels::from_bits(2));
        assert_eq!(run(&mut s, &mut d, 60_000, 200), (1, Some(60_500)));
        assert_eq!((d.count(), d.since_rest()), (3, 0));
    }

    #[test]
    fn the_millisecond_clock_may_wrap() {
        let mut d = decoder();
        let mut s = Standstill::new();
        nudge(&mut d);
        let start = u32::MAX - 200;
        // Still from 200 ms before the wrap to 300 ms after it.
        assert_eq!(
            run(&mut s, &mut d, start, 200),
            (1, Some(start.wrapping_add(500)))
        );
        assert_eq!(start.wrapping_add(500), 299);
    }
}
