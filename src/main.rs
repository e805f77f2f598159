//! Placeholder firmware: proves the workspace links for `thumbv7m-none-eabi` with
//! `handwheel-core`. The RTIC application replaces it.
#![no_std]
#![no_main]

use cortex_m_rt::entry;
use handwheel_core::{BitRate, BitTiming};
use panic_halt as _;

/// APB1 runs at 36 MHz when SYSCLK is 72 MHz.
const APB1_HZ: u32 = 36_000_000;

#[entry]
fn main() -> ! {
    // Keep the core crate in the image so the link is meaningful.
    let btr = BitTiming::for_bitrate(APB1_HZ, BitRate::Kbit1000.bits_per_second())
        .map(|t| t.btr())
        .unwrap_or(0);
    core::hint::black_box(btr);
    loop {
        cortex_m::asm::nop();
    }
}
