//! Arbitrary traffic into the I/O extension's register page: reads and
//! writes of any address and length, control ticks, transfers through
//! simulated 74HC165/74HC595 chips that complete or fail, input changes and
//! persistence round-trips, in any order. Checks: no panic, and the
//! invariants listed in `host_tests::ioext_fuzz` (a refused access
//! changes nothing, configuration bits, one transfer at a time, periods
//! never faster than asked, status and receive data rules, image
//! round-trip).
//!
//! The body lives in the logic crate so that a normal `#[test]` runs it
//! over a fixed corpus on stable (`ioext::tests::the_fuzz_body_holds_on_a_fixed_corpus`).
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    host_tests::ioext_fuzz::run(data);
});
