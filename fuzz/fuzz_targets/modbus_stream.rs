//! Arbitrary (byte, silence) streams into the Modbus RTU server and a
//! 2-axis bridge on simulated chips, polled at every deadline. Checks (in
//! `host_tests::modbus_bench::check_stream`): no panic; requests only from
//! frames an independent framing model and bitwise CRC call intact, only the
//! request named by the frame's command address, only for our ids or
//! broadcast; responses only to intact unicast frames for our ids, with a
//! right CRC; no chip moves unless a motion request was executed.
//!
//! Input: byte 0 bit 0 = fix up CRCs of would-be frames (so the fuzzer gets
//! past the CRC), then (byte, silence code × 20 µs) pairs.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let (records, fix_crc) = host_tests::modbus_bench::records_from_fuzz(data);
    host_tests::modbus_bench::check_stream(&records, fix_crc);
});
