//! The words between this application and the resident loader (docs/FIRMWARE-UPDATE.md,
//! "Boot" and "Trial boot"): two words in memory.x's HANDOFF, the last 8 bytes of SRAM, which
//! no image uses, so that they survive a system reset. The loader reads them first at every
//! reset; power-on clears SRAM, so nothing stale outlives a power cut.
//!
//! - The request to stay in the loader, written before the reset into it (0x1F51 "stop").
//! - The trial: before each start the loader writes its count of the starts this image has
//!   not confirmed (`canopen_loader::boot`); the image clears it once it is healthy on the
//!   bus ([`confirm_start`]). Starts that end in a reset before that (a hang, a fault, the
//!   watchdog) add up, and at 3 the loader stays.

use cortex_m::peripheral::SCB;

/// memory.x's HANDOFF (the contract's, which a test holds to memory.x).
const HANDOFF: usize = canopen_loader::layout::HANDOFF_ORIGIN as usize;
/// Word 0 of the request ("LOAD" in ASCII, most significant byte first); word 1 is its
/// complement.
const REQUEST: u32 = canopen_loader::layout::HANDOFF_REQUEST;

/// The start is confirmed: clears the trial's count (both words), so that the next reset
/// (a reset node, the watchdog, NRST) starts a fresh trial.
pub fn confirm_start() {
    let words = HANDOFF as *mut u32;
    // SAFETY: as in `reset_into_loader`: SRAM outside every image's RAM region, two aligned
    // word writes that alias no Rust object.
    unsafe {
        words.write_volatile(0);
        words.add(1).write_volatile(0);
    }
}

/// Writes the request and resets the MCU: the loader runs next and stays.
pub fn reset_into_loader() -> ! {
    let words = HANDOFF as *mut u32;
    // SAFETY: HANDOFF is SRAM outside every image's RAM region (memory.x): no Rust object
    // lives there, so the two aligned word writes alias nothing.
    unsafe {
        words.write_volatile(REQUEST);
        words.add(1).write_volatile(!REQUEST);
    }
    // `sys_reset` orders the writes before the reset request (DSB) and waits for the reset.
    SCB::sys_reset()
}
