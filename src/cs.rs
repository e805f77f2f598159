//! The image's critical section (the `critical-section` crate's implementation): BASEPRI
//! raised to the CAN side's priority, never PRIMASK.
//!
//! Every `critical-section` user in the image takes it: defmt's RTT logger for the whole of
//! a log frame, the monotonic's timer queue, the task wakers. Masking every interrupt
//! (cortex-m's `critical-section-single-core`) held the wheel off for a whole log line, up to
//! 1 608 cycles; this one leaves the wheel's interrupt alone.
//!
//! Why it is still a critical section: it must exclude every other context that can enter
//! one or touch what one protects. BASEPRI at [`priority::CAN`] holds off every interrupt of
//! that priority and below, and every context that enters a critical section runs there or
//! below: the CAN interrupts and `feed_due` (3), SysTick (set to 3 in `init` for this
//! reason), the QEMU board's USART handlers (3), the `canopen` dispatcher (2), `init` and
//! `idle`. Above it run only the wheel's edge interrupt ([`priority::WHEEL`]), which enters
//! no critical section and shares nothing but atomics and NVIC pends
//! (`handwheel_core::edge`), and the faults, which end in the panic handler's reset.
//!
//! Nesting: the previous BASEPRI is the restore state; BASEPRI is only ever raised here
//! (`basepri_max`), so a section inside an RTIC lock, or inside another section, changes
//! nothing and restores what it found.

use core::sync::atomic::{compiler_fence, Ordering};

use cortex_m::register::{basepri, basepri_max};

use crate::priority;

struct MaskCanSide;
critical_section::set_impl!(MaskCanSide);

// SAFETY: see the module docs: while BASEPRI is at the CAN side's level, no other context
// that enters a critical section can run, and the one context above never enters one.
unsafe impl critical_section::Impl for MaskCanSide {
    unsafe fn acquire() -> u8 {
        let previous = basepri::read();
        basepri_max::write(priority::hardware(priority::CAN));
        // The new level holds from the next instruction on; the ISB is also the compiler
        // barrier that keeps the section's accesses after it.
        cortex_m::asm::isb();
        previous
    }

    unsafe fn release(previous: u8) {
        compiler_fence(Ordering::SeqCst);
        // SAFETY: restores the level `acquire` found, which was in force before the section.
        unsafe { basepri::write(previous) };
    }
}
