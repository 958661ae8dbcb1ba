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

use bridge_logic::postep60::Settings;
use host_tests::i2c_bench::I2cBench;
use libfuzzer_sys::fuzz_target;

/// Commands that may legitimately start or change motion.
const MOTION: [u8; 8] = [0x50, 0x54, 0x05, 0x55, 0x71, 0x5E, 0x70, 0x73];

fuzz_target!(|data: &[u8]| {
    let mut b = host_tests::sim_bridge::template(|| I2cBench::new(2, Settings::FACTORY));
    let mut moved_by_command = false;
    let mut it = data.iter().copied();
    while let Some(tag) = it.next() {
        match tag & 3 {
            0 => {
                let addr = it.next().unwrap_or(0) % 4;
                let len = usize::from(it.next().unwrap_or(0) % 24);
                let bytes: Vec<u8> = it.by_ref().take(len).collect();
                if bytes.first().is_some_and(|c| MOTION.contains(c)) {
                    moved_by_command = true;
                }
                b.write(addr, &bytes);
            }
            1 => {
                let addr = it.next().unwrap_or(0) % 4;
                let n = usize::from(it.next().unwrap_or(0) % 12);
                let _ = b.read(addr, n);
            }
            2 => b.slave.on_bus_error(),
            _ => b.run(u64::from(it.next().unwrap_or(0) % 20)),
        }
    }
    b.run(20);
    if !moved_by_command {
        for k in 0..2 {
            assert_eq!(b.chip(k).abs_pos(), 0, "chip {k} moved without a motion command");
        }
    }
});
