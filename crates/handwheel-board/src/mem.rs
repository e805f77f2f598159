//! Byte-wise memory routines in place of `compiler_builtins`' word-wise ones (weak symbols,
//! so these win at link time), in both images: the loader must fit its 12 KiB and the
//! application its 40 KiB budget, and those routines with their ARM EABI entry points take
//! about 2 KiB for speed neither needs. The largest copy the loader makes (its node, about
//! 1.2 KB, at start and at reset communication) takes some 10 000 cycles, 0.14 ms at 72 MHz,
//! byte by byte; the application copies CAN frames (16 bytes), defmt frames and a few hundred
//! bytes at start-up, none of it on the wheel's interrupt path.
//!
//! Every entry point goes to one of two loops, `copy` and `fill`, which no entry point's name
//! reaches: a call of `memset` or `memcpy` by name is a library call to the compiler, which
//! it lowers to the EABI entry point again (a function calling itself), and volatile accesses
//! keep it from recognising the loops as such calls. `tests/interop` boots both images in
//! every test: a routine that recursed would fault at its first use.

use core::ptr::{read_volatile, write_volatile};

/// Copies `n` bytes from `src` to `dest`, forwards or (`backwards`) from the end.
///
/// # Safety
/// `src` readable and `dest` writable for `n` bytes; overlapping only in the direction that
/// reads each byte before a write can reach it.
#[inline(never)]
unsafe fn copy(dest: *mut u8, src: *const u8, n: usize, backwards: bool) {
    for k in 0..n {
        let i = if backwards { n - 1 - k } else { k };
        // SAFETY: i < n, within the bytes the caller vouches for.
        unsafe { write_volatile(dest.add(i), read_volatile(src.add(i))) };
    }
}

/// Sets `n` bytes at `dest` to `c`.
///
/// # Safety
/// `dest` writable for `n` bytes.
#[inline(never)]
unsafe fn fill(dest: *mut u8, c: u8, n: usize) {
    for i in 0..n {
        // SAFETY: i < n, within the bytes the caller vouches for.
        unsafe { write_volatile(dest.add(i), c) };
    }
}

/// Copies `n` bytes from `src` to `dest`, which do not overlap.
///
/// # Safety
/// The C `memcpy` contract: `src` readable and `dest` writable for `n` bytes.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn memcpy(dest: *mut u8, src: *const u8, n: usize) -> *mut u8 {
    // SAFETY: the same contract.
    unsafe { copy(dest, src, n, false) };
    dest
}

/// Copies `n` bytes from `src` to `dest`, which may overlap.
///
/// # Safety
/// The C `memmove` contract.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn memmove(dest: *mut u8, src: *const u8, n: usize) -> *mut u8 {
    // SAFETY: the same contract; forwards when `dest` is below `src`, else backwards, so
    // that each byte is read before a write can reach it.
    unsafe { copy(dest, src, n, (dest as usize) > (src as usize)) };
    dest
}

/// Sets `n` bytes at `dest` to `c`.
///
/// # Safety
/// The C `memset` contract.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn memset(dest: *mut u8, c: i32, n: usize) -> *mut u8 {
    // SAFETY: the same contract.
    unsafe { fill(dest, c as u8, n) };
    dest
}

// The ARM EABI's entry points (RTABI 4.3.4), which the compiler calls for copies and fills
// of known alignment; note `__aeabi_memset`'s argument order (value last) and that
// `__aeabi_memclr` fills with zero.

/// # Safety
/// As [`memcpy`].
#[unsafe(no_mangle)]
pub unsafe extern "C" fn __aeabi_memcpy(dest: *mut u8, src: *const u8, n: usize) {
    // SAFETY: the same contract.
    unsafe { copy(dest, src, n, false) };
}

/// # Safety
/// As [`memcpy`].
#[unsafe(no_mangle)]
pub unsafe extern "C" fn __aeabi_memcpy4(dest: *mut u8, src: *const u8, n: usize) {
    // SAFETY: the same contract.
    unsafe { copy(dest, src, n, false) };
}

/// # Safety
/// As [`memcpy`].
#[unsafe(no_mangle)]
pub unsafe extern "C" fn __aeabi_memcpy8(dest: *mut u8, src: *const u8, n: usize) {
    // SAFETY: the same contract.
    unsafe { copy(dest, src, n, false) };
}

/// # Safety
/// As [`memmove`].
#[unsafe(no_mangle)]
pub unsafe extern "C" fn __aeabi_memmove(dest: *mut u8, src: *const u8, n: usize) {
    // SAFETY: the same contract.
    unsafe { copy(dest, src, n, (dest as usize) > (src as usize)) };
}

/// # Safety
/// As [`memmove`].
#[unsafe(no_mangle)]
pub unsafe extern "C" fn __aeabi_memmove4(dest: *mut u8, src: *const u8, n: usize) {
    // SAFETY: the same contract.
    unsafe { copy(dest, src, n, (dest as usize) > (src as usize)) };
}

/// # Safety
/// As [`memmove`].
#[unsafe(no_mangle)]
pub unsafe extern "C" fn __aeabi_memmove8(dest: *mut u8, src: *const u8, n: usize) {
    // SAFETY: the same contract.
    unsafe { copy(dest, src, n, (dest as usize) > (src as usize)) };
}

/// # Safety
/// As [`memset`].
#[unsafe(no_mangle)]
pub unsafe extern "C" fn __aeabi_memset(dest: *mut u8, n: usize, c: i32) {
    // SAFETY: the same contract.
    unsafe { fill(dest, c as u8, n) };
}

/// # Safety
/// As [`memset`].
#[unsafe(no_mangle)]
pub unsafe extern "C" fn __aeabi_memset4(dest: *mut u8, n: usize, c: i32) {
    // SAFETY: the same contract.
    unsafe { fill(dest, c as u8, n) };
}

/// # Safety
/// As [`memset`].
#[unsafe(no_mangle)]
pub unsafe extern "C" fn __aeabi_memset8(dest: *mut u8, n: usize, c: i32) {
    // SAFETY: the same contract.
    unsafe { fill(dest, c as u8, n) };
}

/// # Safety
/// As [`memset`] with 0.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn __aeabi_memclr(dest: *mut u8, n: usize) {
    // SAFETY: the same contract.
    unsafe { fill(dest, 0, n) };
}

/// # Safety
/// As [`memset`] with 0.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn __aeabi_memclr4(dest: *mut u8, n: usize) {
    // SAFETY: the same contract.
    unsafe { fill(dest, 0, n) };
}

/// # Safety
/// As [`memset`] with 0.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn __aeabi_memclr8(dest: *mut u8, n: usize) {
    // SAFETY: the same contract.
    unsafe { fill(dest, 0, n) };
}
