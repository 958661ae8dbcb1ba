//! Arbitrary I2C traffic into the bridge's I2C slave (2 axes on simulated
//! chips): writes of any bytes to any address, reads of any length, bus
//! errors and control ticks, in any order. Checks: no panic, and no chip
//! moves unless a write started with a command that may move a motor.
//!
//! Input: a stream of ops; each op is a tag byte (low 2 bits: 0 write,
//! 1 read, 2 bus error, 3 tick), then for a write: address byte, length
//! byte (mod 24) and that many data bytes; for a read: address, length;
//! for a tick: a count of milliseconds (mod 20).
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    host_tests::i2c_bench::check_i2c_stream(data);
});
