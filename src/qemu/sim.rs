//! The simulated input lines of the QEMU board: what GPIO would read on the real one.
//!
//! Written by the stimulus line's interrupt handler (USART2), read by the wheel's EXTI task
//! and by the `canopen` task, which samples the switches, through
//! [`board::WheelInputs`](super::board::WheelInputs) and
//! [`board::Selectors`](super::board::Selectors). Single bytes, so plain atomics suffice on
//! this single core. All lines start inactive: A = B = 0, no axis and no multiplier line
//! active (the DIP switch reads all off too).

use core::sync::atomic::{AtomicU8, Ordering};

use handwheel_core::AbLevels;

/// Wheel channel levels, bit 0 = A, bit 1 = B.
static AB: AtomicU8 = AtomicU8::new(0);
/// Active axis lines, bit 0 = X .. bit 4 = V.
static AXIS: AtomicU8 = AtomicU8::new(0);
/// Active multiplier lines, bit 0 = x1, bit 1 = x10, bit 2 = x100.
static MULTIPLIER: AtomicU8 = AtomicU8::new(0);

/// The wheel's A/B levels.
#[inline(always)]
pub fn ab() -> AbLevels {
    AbLevels::from_bits(AB.load(Ordering::Acquire))
}

/// Sets the wheel's A/B levels (the edge interrupt is the caller's business).
pub fn set_ab(levels: AbLevels) {
    AB.store(levels.bits(), Ordering::Release);
}

/// The masks of active lines `(axis, multiplier)`, as the board's `SelectorInput` gives them.
pub fn selector_masks() -> (u8, u8) {
    (
        AXIS.load(Ordering::Relaxed),
        MULTIPLIER.load(Ordering::Relaxed),
    )
}

/// Makes exactly the axis lines in `mask` active.
pub fn set_axis_mask(mask: u8) {
    AXIS.store(mask, Ordering::Relaxed);
}

/// Makes exactly the multiplier lines in `mask` active.
pub fn set_multiplier_mask(mask: u8) {
    MULTIPLIER.store(mask, Ordering::Relaxed);
}
