//! The deliberate stack overflow of the test build (feature `stack-overflow-test`): what a
//! runaway recursion does to this image.
//!
//! [`run`] digs [`DEPTH`] bytes into the stack, 256 bytes a call. The image's stack region
//! is its RAM less static RAM (about 17.5 KiB of the 20 KiB), so 19 KiB is an overflow,
//! yet less than all of RAM. With flip-link's layout (the stack below static RAM, `memory.x`)
//! the digging runs off the start of RAM into unmapped memory: a bus fault, escalated to
//! HardFault, and the watchdog (started in `init`) resets the MCU. With the classic layout
//! (static RAM at the start of RAM, the stack above it) the same digging stays inside RAM
//! and overwrites the statics, silently: the log line after it then comes out, if the
//! logger's own statics survived, and the firmware runs on with whatever was left of them.
//! The emulated board's test (`tests/interop/test_board.py`) tells the two apart.

/// Bytes the recursion digs below its caller.
pub const DEPTH: usize = 19 * 1024;
/// Stack bytes per call, besides the call's own frame.
const BLOCK: usize = 256;

/// Digs [`DEPTH`] bytes into the stack and climbs back.
pub fn run() {
    defmt::warn!(
        "stack overflow test: digging {=usize} bytes into the stack",
        DEPTH
    );
    let sum = dig((DEPTH / BLOCK) as u32);
    defmt::error!(
        "stack overflow test: back without a fault (sum {=u32})",
        sum
    );
}

/// One level: a block of stack the optimiser cannot drop, then the next level.
#[inline(never)]
fn dig(levels: u32) -> u32 {
    let block = core::hint::black_box([levels as u8; BLOCK]);
    if levels == 0 {
        return u32::from(block[0]);
    }
    let below = dig(core::hint::black_box(levels - 1));
    below.wrapping_add(u32::from(core::hint::black_box(&block)[BLOCK - 1]))
}
