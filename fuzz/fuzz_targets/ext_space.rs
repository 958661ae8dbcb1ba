//! Arbitrary extension-space reads and writes (chip registers, I/O
//! extension, diagnostics, homing, watchdog, axis blocks) and control ticks
//! into the bridge, see `host_tests::ext_fuzz::check_ext_stream`: no panic,
//! no command a chip refuses, no motion without a homing start.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    host_tests::ext_fuzz::check_ext_stream(data);
});
