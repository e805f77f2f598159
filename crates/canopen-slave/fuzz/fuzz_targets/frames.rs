//! The engine under libFuzzer: the harness body is `canopen_harness::frames`, which the
//! seeded random loop of `cargo xtask test` runs on stable too.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|input: &[u8]| {
    canopen_harness::frames(input);
});
