//! Interrupt priorities that the firmware sets outside RTIC's task attributes.
//!
//! RTIC's `priority = n` attributes in `src/main.rs` must be literals; these constants name
//! the same levels for the code that programs the NVIC itself (the wheel's edge interrupt,
//! SysTick, the critical section). `src/main.rs` checks that they agree.

use crate::pac::NVIC_PRIO_BITS;

/// The wheel's edge interrupt: above everything else, so nothing delays its port read.
pub const WHEEL: u8 = 4;
/// The CAN interrupts, the `feed_due` relay, SysTick, the QEMU board's USART handlers, and the
/// critical section's mask.
pub const CAN: u8 = 3;

/// The NVIC's priority byte for an RTIC logical priority (higher logical = more urgent =
/// lower number, in the top `NVIC_PRIO_BITS` bits).
pub const fn hardware(logical: u8) -> u8 {
    ((1 << NVIC_PRIO_BITS) - logical) << (8 - NVIC_PRIO_BITS)
}
