//! The device's microsecond clock from the SysTick monotonic's 32-bit millisecond ticks.
//!
//! The monotonic counts milliseconds in 32 bits (wrapping after 49.7 days; a 64-bit count
//! would need emulated 64-bit atomics, 2 KiB of RAM on this core). The CANopen device wants a
//! `u64` of microseconds that never wraps: [`WideClock`] extends the count, as long as it
//! sees it at least once per wrap, which the CAN-side task does every 100 ms at most.

/// Extends 32-bit millisecond ticks to 64-bit microseconds.
pub struct WideClock {
    last: u32,
    wraps: u64,
}

impl WideClock {
    /// A clock that starts at tick 0.
    pub const fn new() -> Self {
        Self { last: 0, wraps: 0 }
    }

    /// Microseconds since boot for the current tick count.
    pub fn now_us(&mut self, ticks_ms: u32) -> u64 {
        if ticks_ms < self.last {
            self.wraps += 1;
        }
        self.last = ticks_ms;
        ((self.wraps << 32) | u64::from(ticks_ms)) * 1000
    }
}

impl Default for WideClock {
    fn default() -> Self {
        Self::new()
    }
}

/// Whole milliseconds to sleep from `now_us` until `deadline_us` (rounded up, so the
/// deadline has passed on waking), at most `max_ms`. Only the difference is divided, in 32
/// bits: a 64-bit division would link about 1 KiB of runtime support.
pub fn sleep_ms(now_us: u64, deadline_us: u64, max_ms: u32) -> u32 {
    let ahead_us = deadline_us.saturating_sub(now_us);
    let cap_us = max_ms.saturating_mul(1000);
    if ahead_us >= u64::from(cap_us) {
        max_ms
    } else {
        (ahead_us as u32).div_ceil(1000)
    }
}
