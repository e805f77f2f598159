//! The request to stay in the resident loader (docs/FIRMWARE-UPDATE.md, "Boot"): two words in
//! memory.x's HANDOFF, the last 8 bytes of SRAM, which no image uses, so that they survive the
//! system reset into the loader. The loader reads and clears them before it touches anything
//! else; power-on clears SRAM, so no stale request outlives a power cut.

use cortex_m::peripheral::SCB;

/// memory.x's HANDOFF: its ASSERTs hold it to the last 8 bytes of the 20 KiB SRAM.
const HANDOFF: usize = 0x2000_4FF8;
/// Word 0 of the request ("LOAD" in ASCII, most significant byte first); word 1 is its
/// complement.
pub const REQUEST: u32 = 0x4C4F_4144;

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
