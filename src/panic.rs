//! Panics: log where, then stop the core on a permanently undefined instruction, which
//! probe-rs reports with a backtrace. The watchdog (if it runs) then resets the MCU.
//!
//! The release build logs only that a panic happened. Reading anything from the
//! `PanicInfo` keeps every panic site's file path, message and `core::fmt` number formatting
//! in the image (docs/CHANGELOG.md has the measured figure); the backtrace probe-rs prints at
//! the UDF names the place from the debug information instead. The dev build logs the
//! location as well. Panics raised through defmt (`defmt::panic!`, `defmt::unwrap!`,
//! `defmt::assert!`) log their message themselves before they get here.

use core::panic::PanicInfo;
use core::sync::atomic::{AtomicBool, Ordering};

#[panic_handler]
fn panic(info: &PanicInfo) -> ! {
    static PANICKED: AtomicBool = AtomicBool::new(false);
    cortex_m::interrupt::disable();
    // A panic inside the logger must not recurse into it.
    if !PANICKED.swap(true, Ordering::Relaxed) {
        log(info);
    }
    cortex_m::asm::udf()
}

#[cfg(debug_assertions)]
fn log(info: &PanicInfo) {
    match info.location() {
        Some(at) => defmt::error!("panic at {=str}:{=u32}", at.file(), at.line()),
        None => defmt::error!("panic"),
    }
}

#[cfg(not(debug_assertions))]
fn log(_: &PanicInfo) {
    defmt::error!("panic (location: see the probe-rs backtrace)");
}

/// defmt's own panics have logged their message already.
#[defmt::panic_handler]
fn defmt_panic() -> ! {
    cortex_m::interrupt::disable();
    cortex_m::asm::udf()
}
