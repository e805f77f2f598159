//! The deliberate stack overflow of the test build (feature `stack-overflow-test`): what a
//! runaway recursion does to this image.
//!
//! [`run`] digs [`DEPTH`] bytes into the stack below its own frame, a block of 256 bytes
//! (and the call's frame) a level, until a block lies that deep. The image's stack region is
//! the part's 20 KiB less static RAM, which is more than 1 KiB (RTT's buffers alone; the
//! measured region is in docs/PERFORMANCE.md), so 19 KiB is an overflow, yet less than all
//! of RAM. With flip-link's layout (the stack below static RAM, `memory.x`)
//! the digging runs off the start of RAM into unmapped memory: a bus fault, escalated to
//! HardFault, and the watchdog (started in `init`) resets the MCU. With the classic layout
//! (static RAM at the start of RAM, the stack above it) the same digging stays inside RAM
//! and overwrites the statics, silently: the log line after it then comes out, if the
//! logger's own statics survived, and the firmware runs on with whatever was left of them.
//! The emulated board's test (`tests/interop/test_board.py`) tells the two apart.

/// Bytes the recursion digs below its caller.
pub const DEPTH: usize = 19 * 1024;
/// Stack bytes per level, besides the call's own frame.
const BLOCK: usize = 256;

/// Digs [`DEPTH`] bytes into the stack and climbs back.
pub fn run() {
    defmt::warn!(
        "stack overflow test: digging {=usize} bytes into the stack",
        DEPTH
    );
    let here = core::hint::black_box(0u8);
    let bottom = (&raw const here as usize).saturating_sub(DEPTH);
    let sum = dig(bottom);
    defmt::error!(
        "stack overflow test: back without a fault (sum {=u32})",
        sum
    );
}

/// One level: a block of stack the optimiser cannot drop; the next level unless the block
/// lies at `bottom` or below.
#[inline(never)]
fn dig(bottom: usize) -> u32 {
    let block = [bottom as u8; BLOCK];
    let block = core::hint::black_box(&block);
    let first = u32::from(block[0]);
    if block.as_ptr() as usize <= bottom {
        return first;
    }
    dig(core::hint::black_box(bottom)).wrapping_add(first)
}
