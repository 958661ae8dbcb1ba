//! Arbitrary USB OUT reports and control ticks into the bridge (2 axes on
//! simulated chips), see `host_tests::usb_bench::check_usb_stream`: no
//! panic; no motion from a report that is not well formed or carries no
//! motion command; ill-formed reports are never executed.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    host_tests::usb_bench::check_usb_stream(data);
});
