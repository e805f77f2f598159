//! The decoder and the accumulator as one resource.
//!
//! The EXTI task (highest priority) and the CAN side share exactly this struct. Keeping both
//! halves together makes the ISR one call under one lock, and lets the CAN side read the raw
//! count, the error count and the feed consistently.

use crate::accumulator::FeedAccumulator;
use crate::decoder::{AbLevels, DecoderConfig, EdgeOutcome, QuadratureDecoder};

/// Decoder plus accumulator.
#[derive(Clone, Debug)]
pub struct Handwheel {
    /// Quadrature decoder (object 0x2020).
    pub decoder: QuadratureDecoder,
    /// Feed accumulator (objects 0x2000, 0x2001, 0x2010, 0x2030, 0x6004).
    pub feed: FeedAccumulator,
}

impl Handwheel {
    /// A wheel at rest on `initial` levels, feed disabled.
    pub const fn new(config: DecoderConfig, initial: AbLevels) -> Self {
        Self {
            decoder: QuadratureDecoder::new(config, initial),
            feed: FeedAccumulator::new(),
        }
    }

    /// One EXTI edge. Returns `true` when a feed frame is due (position or status changed).
    #[inline]
    #[must_use = "a changed feed needs a TPDO"]
    pub fn on_edge(&mut self, levels: AbLevels) -> bool {
        match self.decoder.update(levels) {
            EdgeOutcome::Idle | EdgeOutcome::Counted => false,
            EdgeOutcome::Illegal => self.feed.note_encoder_error(),
            detent => self.feed.add_detents(detent.detents()),
        }
    }
}

/// Short, exclusive access to the shared [`Handwheel`].
///
/// The CAN side reaches the wheel only through this, one object access at a time, so on the
/// target each access is its own short RTIC lock and the EXTI task is never held off for a
/// whole frame's processing. On the host a plain `Handwheel` is its own access.
pub trait WheelAccess {
    /// Runs `f` with the wheel locked.
    fn with_wheel<R>(&mut self, f: impl FnOnce(&mut Handwheel) -> R) -> R;
}

impl WheelAccess for Handwheel {
    fn with_wheel<R>(&mut self, f: impl FnOnce(&mut Handwheel) -> R) -> R {
        f(self)
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
    use crate::pdo::FeedStatus;
    use crate::selector::{Axis, Multiplier, Selection};

    #[test]
    fn edges_become_feed_only_at_detents() {
        let mut wheel = Handwheel::new(DecoderConfig::default(), AbLevels::from_bits(0));
        let _ = wheel.feed.set_enabled(true);
        let _ = wheel.feed.set_selection(Selection {
            axis: Some(Axis::X),
            multiplier: Multiplier::X10,
        });
        let mut levels = AbLevels::from_bits(0);
        let mut due = [false; 8];
        for d in &mut due {
            levels = levels.next_forward();
            *d = wheel.on_edge(levels);
        }
        assert_eq!(due, [false, false, false, true, false, false, false, true]);
        assert_eq!(wheel.feed.position(), 20);
        assert_eq!(wheel.decoder.count(), 8);
    }

    #[test]
    fn illegal_jump_sets_status_once() {
        let mut wheel = Handwheel::new(DecoderConfig::default(), AbLevels::from_bits(0));
        assert!(wheel.on_edge(AbLevels::from_bits(3)));
        assert!(!wheel.on_edge(AbLevels::from_bits(0)));
        assert_eq!(wheel.decoder.illegal_transitions(), 2);
        assert!(wheel.feed.status().contains(FeedStatus::ENCODER_ERROR));
        assert_eq!(wheel.feed.position(), 0);
    }
}
