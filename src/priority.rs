//! Interrupt priorities that the firmware sets outside RTIC's task attributes.
//!
//! RTIC's `priority = n` attributes in `src/main.rs` must be literals; these constants name
//! the same levels for the code that programs the NVIC itself (SysTick's level, set in
//! `init`). `src/main.rs` checks that they agree.

use crate::pac::NVIC_PRIO_BITS;

/// The wheel's edge task: the highest priority the part has (NVIC priority byte 0), so
/// nothing but a critical section delays its port read. At this ceiling RTIC's lock of the
/// shared wheel state is the critical section itself (PRIMASK) instead of a BASEPRI raise
/// with its barriers, which would cost every edge cycles it has no room for
/// (docs/PERFORMANCE.md, part 2).
pub const WHEEL: u8 = 16;
/// The CAN interrupts, the `feed_due` relay and SysTick.
pub const CAN: u8 = 3;

/// The NVIC's priority byte for an RTIC logical priority (higher logical = more urgent =
/// lower number, in the top `NVIC_PRIO_BITS` bits).
pub const fn hardware(logical: u8) -> u8 {
    ((1 << NVIC_PRIO_BITS) - logical) << (8 - NVIC_PRIO_BITS)
}
