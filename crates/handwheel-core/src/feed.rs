//! The feed's vocabulary, shared by the accumulator that produces it, the outbox that holds
//! it for the bus and the PDO encodings that carry it: the status bits, the state a feed
//! record describes, and the unit step.

use crate::selector::{Axis, Multiplier};

/// Status bits of the feed record (object 0x2030).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, Hash)]
pub struct FeedStatus(u8);

impl FeedStatus {
    /// Feed is enabled (0x2000 = 1 and not stopped since).
    pub const ENABLED: Self = Self(1 << 0);
    /// An illegal quadrature transition (missed edge) happened in this epoch.
    pub const ENCODER_ERROR: Self = Self(1 << 1);
    /// Unit steps were dropped at the backlog bound in this epoch.
    pub const STEPS_DROPPED: Self = Self(1 << 2);
    /// The feed was stopped by a loss of communication (the master's heartbeat timed out, or
    /// the device's frames could not reach the bus); cleared by enabling.
    pub const MASTER_LOST: Self = Self(1 << 3);
    /// The wheel was turned while disabled or without an axis in this epoch.
    pub const IGNORED_MOTION: Self = Self(1 << 4);

    const DEFINED: u8 = 0b1_1111;

    /// No bit set.
    pub const fn empty() -> Self {
        Self(0)
    }

    /// The raw byte.
    pub const fn bits(self) -> u8 {
        self.0
    }

    /// From a raw byte; `None` if an undefined bit is set.
    pub const fn from_bits(bits: u8) -> Option<Self> {
        if bits & !Self::DEFINED == 0 {
            Some(Self(bits))
        } else {
            None
        }
    }

    /// Whether every bit of `other` is set.
    pub const fn contains(self, other: Self) -> bool {
        self.0 & other.0 == other.0
    }

    /// Sets the bits of `other`.
    pub fn insert(&mut self, other: Self) {
        self.0 |= other.0;
    }

    /// Clears the bits of `other`.
    pub fn remove(&mut self, other: Self) {
        self.0 &= !other.0;
    }

    /// The bits set in both.
    #[must_use]
    pub const fn intersection(self, other: Self) -> Self {
        Self(self.0 & other.0)
    }

    /// The bits set in either.
    #[must_use]
    pub const fn union(self, other: Self) -> Self {
        Self(self.0 | other.0)
    }
}

/// What one feed record says, without its sequence number: the feed as it is (or was, at the
/// end of a selection epoch).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct FeedState {
    /// Cumulative feed position in multiplied units, wrapping (object 0x6004).
    pub position: i32,
    /// Selected axis (object 0x2010:1).
    pub axis: Option<Axis>,
    /// Multiplier in force (object 0x2010:2).
    pub multiplier: Multiplier,
    /// Status flags, bits 0-4 of object 0x2030.
    pub status: FeedStatus,
    /// Selection epoch (object 0x2010:3); its low three bits are bits 5-7 of 0x2011.
    pub epoch: u8,
    /// The session a master opened (object 0x2002, 0 = none, 1..=7); bits 5-7 of 0x2030.
    pub session: u8,
}

impl FeedState {
    /// Where the epoch sits in the selection byte and the session in the status byte.
    pub const HIGH_SHIFT: u32 = 5;

    /// Every field at its zero (no axis, x1, no flags): the feed at power-on.
    pub const ZERO: Self = Self {
        position: 0,
        axis: None,
        multiplier: Multiplier::X1,
        status: FeedStatus::empty(),
        epoch: 0,
        session: 0,
    };

    /// The status byte as object 0x2030 and the feed record carry it: the flags in bits 0-4,
    /// the session in bits 5-7.
    pub const fn status_byte(&self) -> u8 {
        self.status.bits() | ((self.session & 0b111) << Self::HIGH_SHIFT)
    }

    /// The selection byte as object 0x2011 and the feed record carry it: the axis in bits
    /// 0-2, the multiplier's code in bits 3-4, the low three bits of the epoch in bits 5-7.
    pub const fn selection_byte(&self) -> u8 {
        Axis::option_value(self.axis)
            | (self.multiplier.code() << 3)
            | ((self.epoch & 0b111) << Self::HIGH_SHIFT)
    }
}

/// One unit step of the paper's format.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct UnitStep {
    /// The axis the step is for.
    pub axis: Axis,
    /// `true` = forward (positive).
    pub forward: bool,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn status_bits_are_distinct() {
        let all = [
            FeedStatus::ENABLED,
            FeedStatus::ENCODER_ERROR,
            FeedStatus::STEPS_DROPPED,
            FeedStatus::MASTER_LOST,
            FeedStatus::IGNORED_MOTION,
        ];
        let mut seen = 0u8;
        for s in all {
            assert_eq!(s.bits().count_ones(), 1);
            assert_eq!(seen & s.bits(), 0);
            seen |= s.bits();
        }
        assert_eq!(FeedStatus::from_bits(seen), Some(FeedStatus(seen)));
    }
}
