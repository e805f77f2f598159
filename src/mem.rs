//! `memcpy` for this image: a byte loop instead of compiler-builtins' word-wise one.
//!
//! The compiler calls `memcpy` (and the AEABI entry points below) for struct moves and slice
//! copies. compiler-builtins' implementation handles every alignment case with word copies
//! and shifts, and with its AEABI wrappers it costs more flash than the image's budget can
//! spare (docs/CHANGELOG.md has the measured figure). This image copies little:
//! CAN frames (16 bytes), defmt log frames, and a few hundred bytes once at start-up, none
//! of it on the wheel's interrupt path; a byte loop does that in a handful of microseconds at
//! most. compiler-builtins defines these symbols weak, so the definitions here replace them.
//!
//! The loop reads and writes through volatile accesses so that LLVM cannot recognise it as a
//! copy idiom and turn it back into a call to `memcpy`, which would recurse.

/// Copies `n` bytes from `src` to `dest`.
///
/// # Safety
/// The C `memcpy` contract: both ranges valid for `n` bytes, not overlapping.
unsafe fn copy_bytes(dest: *mut u8, src: *const u8, n: usize) {
    for i in 0..n {
        // SAFETY: the caller guarantees both ranges are valid for `n` bytes and disjoint;
        // `i < n` keeps each access inside them.
        unsafe { dest.add(i).write_volatile(src.add(i).read_volatile()) };
    }
}

/// The C library's `memcpy`.
///
/// # Safety
/// As for C `memcpy`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn memcpy(dest: *mut u8, src: *const u8, n: usize) -> *mut u8 {
    // SAFETY: forwarded contract.
    unsafe { copy_bytes(dest, src, n) };
    dest
}

/// AEABI `memcpy` (no return value).
///
/// # Safety
/// As for C `memcpy`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn __aeabi_memcpy(dest: *mut u8, src: *const u8, n: usize) {
    // SAFETY: forwarded contract.
    unsafe { copy_bytes(dest, src, n) }
}

/// AEABI `memcpy` with both pointers 4-byte aligned.
///
/// # Safety
/// As for C `memcpy`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn __aeabi_memcpy4(dest: *mut u8, src: *const u8, n: usize) {
    // SAFETY: forwarded contract; alignment is a promise we do not need.
    unsafe { copy_bytes(dest, src, n) }
}

/// AEABI `memcpy` with both pointers 8-byte aligned.
///
/// # Safety
/// As for C `memcpy`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn __aeabi_memcpy8(dest: *mut u8, src: *const u8, n: usize) {
    // SAFETY: forwarded contract; alignment is a promise we do not need.
    unsafe { copy_bytes(dest, src, n) }
}
