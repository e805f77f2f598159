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

    /// `self` plus `us` microseconds: the addition every engine timer goes through (engine
    /// durations are at most 65 535 ms, so they fit a `u32`).
    #[must_use]
    pub(crate) fn after_us(self, us: u32) -> Self {
        Self(self.0.saturating_add(us as u64))
    }

    /// `self` plus `ms` milliseconds (CiA 301 times are 16-bit millisecond counts).
    #[must_use]
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

/// Extends a 32-bit millisecond tick count (a typical MCU monotonic, wrapping after 49.7
/// days) to the engine's [`Instant`], which never wraps. It must see the count at least
/// once per wrap; a caller that polls the engine at its deadlines and at least every few
/// seconds does.
#[derive(Clone, Debug, Default, PartialEq, Eq, Hash)]
pub struct WideClock {
    last: u32,
    wraps: u64,
}

impl WideClock {
    /// A clock that starts at tick 0.
    pub const fn new() -> Self {
        Self { last: 0, wraps: 0 }
    }

    /// The instant of `ticks_ms`, the current tick count.
    pub fn now(&mut self, ticks_ms: u32) -> Instant {
        if ticks_ms < self.last {
            self.wraps += 1;
        }
        self.last = ticks_ms;
        Instant::from_millis((self.wraps << 32) | u64::from(ticks_ms))
    }
}

/// Whole milliseconds to sleep from `now` until `deadline` (rounded up, so that the
/// deadline has passed on waking), at most `max_ms`. Only the difference is divided, in 32
/// bits: a 64-bit division would link about 1 KiB of runtime support on a Cortex-M3.
pub fn sleep_ms(now: Instant, deadline: Instant, max_ms: u32) -> u32 {
    let ahead_us = deadline.as_micros().saturating_sub(now.as_micros());
    let cap_us = max_ms.saturating_mul(1000);
    if ahead_us >= u64::from(cap_us) {
        max_ms
    } else {
        (ahead_us as u32).div_ceil(1000)
    }
}

/// A periodic duty on a wrapping 32-bit millisecond tick (switch sampling, LED update).
///
/// After a late round the next one is a full period away, never sooner: a duty that counts
/// its rounds (a debouncer) must not be caught up in a burst.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Periodic {
    next_ms: u32,
    period_ms: u32,
}

impl Periodic {
    /// Due at `now_ms`, then every `period_ms`.
    pub const fn new(now_ms: u32, period_ms: u32) -> Self {
        Self {
            next_ms: now_ms,
            period_ms,
        }
    }

    /// The tick at which it is due next.
    pub const fn next_ms(&self) -> u32 {
        self.next_ms
    }

    /// Whether the duty is due at `now_ms`; if so, schedules the next round. Ticks compare
    /// by wrapping difference, so the wrap of the count does not matter.
    pub fn is_due(&mut self, now_ms: u32) -> bool {
        let reached = |at: u32| now_ms.wrapping_sub(at) < 1 << 31;
        if !reached(self.next_ms) {
            return false;
        }
        self.next_ms = self.next_ms.wrapping_add(self.period_ms);
        if reached(self.next_ms) {
            self.next_ms = now_ms.wrapping_add(self.period_ms);
        }
        true
    }
}
