//! The handwheel's board, stated once for the two images that run on it: the application
//! (`src/`) and the resident loader (`loader/`). A pin, a clock or the bit timing changed
//! here changes in both, so that the loader always listens where the application talks
//! (docs/FIRMWARE-UPDATE.md).
//!
//! - [`clocks`]: the crystal, the PLL and the bus clocks (the bxCAN kernel clock the bit
//!   timing table is computed for), and their set-up.
//! - [`pins`]: the pin map as data, and the DIP switch and bxCAN pins brought up in their
//!   modes (macros, as the HAL's pins are fields of its port structs).
//! - [`bit_timing`]: `CAN_BTR` for each bit-rate code.
//! - [`frame`]: the engine's frames to and from bxcan's, and 11-bit identifiers for filters.
//! - [`flash`]: the flash as both images drive it (one trait; its power-cut model for host
//!   tests with the `model` feature), and on the MCU its writer over a region of pages.
//! - `chip` (MCU only): the 96-bit unique ID.
//! - `watchdog` (MCU only): the independent watchdog as both images run it.
//! - `mem` (MCU only): byte-wise memory routines in place of `compiler_builtins`' larger ones.
#![no_std]

pub mod bit_timing;
pub mod clocks;
pub mod flash;
pub mod frame;
pub mod pins;

#[cfg(target_os = "none")]
pub mod chip;
#[cfg(target_os = "none")]
mod mem;
#[cfg(target_os = "none")]
pub mod watchdog;

#[cfg(target_os = "none")]
#[doc(hidden)]
pub use stm32f1xx_hal as hal;

/// Busy-waits about `cycles` core cycles (for [`read_dip_switch`]).
#[cfg(target_os = "none")]
#[doc(hidden)]
pub fn delay(cycles: u32) {
    cortex_m::asm::delay(cycles);
}
