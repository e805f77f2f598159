//! Time as the caller tells it: the engine never reads a clock of its own.

/// A point in time in microseconds since an arbitrary origin chosen by the caller.
///
/// The engine only compares instants and adds durations to them, so any monotonic source
/// works (a SysTick-based monotonic on the board, a plain counter in tests). Additions
/// saturate: 2^64 µs is far beyond any uptime, and saturating keeps comparisons meaningful.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Instant(u64);

impl Instant {
    /// The origin.
    pub const ZERO: Self = Self(0);

    /// An instant `us` microseconds after the origin.
    pub const fn from_micros(us: u64) -> Self {
        Self(us)
    }

    /// An instant `ms` milliseconds after the origin.
    pub const fn from_millis(ms: u64) -> Self {
        Self(ms.saturating_mul(1000))
    }

    /// Microseconds since the origin.
    pub const fn as_micros(self) -> u64 {
        self.0
    }

    /// Whole milliseconds since the origin.
    pub const fn as_millis(self) -> u64 {
        self.0 / 1000
    }

    /// `self` plus `us` microseconds.
    #[must_use]
    pub const fn add_micros(self, us: u64) -> Self {
        Self(self.0.saturating_add(us))
    }

    /// `self` plus `ms` milliseconds.
    #[must_use]
    pub const fn add_millis(self, ms: u64) -> Self {
        self.add_micros(ms.saturating_mul(1000))
    }

    /// `self` plus `us` microseconds: the one out-of-line addition every engine timer goes
    /// through (engine durations are at most 65 535 ms, so they fit a `u32`).
    #[must_use]
    #[inline(never)]
    pub(crate) fn after_us(self, us: u32) -> Self {
        Self(self.0.saturating_add(us as u64))
    }

    /// `self` plus `ms` milliseconds (CiA 301 times are 16-bit millisecond counts).
    #[must_use]
    // Out of line: called from several places, inlined copies cost more flash.
    #[inline(never)]
    pub(crate) fn after_ms(self, ms: u16) -> Self {
        // u16 * 1000 always fits a u32: no overflow possible.
        self.after_us(ms as u32 * 1000)
    }

    /// `self` plus `n` units of 100 µs, the unit of CiA 301 inhibit times.
    #[must_use]
    pub(crate) fn add_100us(self, n: u16) -> Self {
        // u16 * 100 always fits a u32: no overflow possible.
        self.after_us(n as u32 * 100)
    }
}

/// The earlier of two optional deadlines.
pub(crate) fn earliest(a: Option<Instant>, b: Option<Instant>) -> Option<Instant> {
    match (a, b) {
        (Some(a), Some(b)) => Some(a.min(b)),
        (a, None) => a,
        (None, b) => b,
    }
}
