//! Panics: log where, then stop the core on a permanently undefined instruction, which
//! probe-rs reports with a backtrace. The watchdog (if it runs) then resets the MCU.
//!
//! Only the location is logged, not the message: formatting a core panic message pulls
//! `core::fmt` into the image (about 4.8 KiB, a quarter of the flash budget). Panics raised
//! through defmt (`defmt::panic!`, `defmt::unwrap!`, `defmt::assert!`) log their message
//! themselves before they get here.

use core::panic::PanicInfo;
use core::sync::atomic::{AtomicBool, Ordering};

#[panic_handler]
fn panic(info: &PanicInfo) -> ! {
    static PANICKED: AtomicBool = AtomicBool::new(false);
    cortex_m::interrupt::disable();
    // A panic inside the logger must not recurse into it.
    if !PANICKED.swap(true, Ordering::Relaxed) {
        match info.location() {
            Some(at) => defmt::error!("panic at {=str}:{=u32}", at.file(), at.line()),
            None => defmt::error!("panic"),
        }
    }
    cortex_m::asm::udf()
}

/// defmt's own panics have logged their message already.
#[defmt::panic_handler]
fn defmt_panic() -> ! {
    cortex_m::interrupt::disable();
    cortex_m::asm::udf()
}
