//! An I2C test bench: the bridge on simulated chips, a simulated I2C master
//! talking to it through the same `I2cSlave` state machine the firmware's
//! interrupt handlers drive, and the virtual clock ([`SimClock`]).

use crate::clock::SimClock;
use bridge_logic::bridge::Bridge;
use bridge_logic::postep60::{PowerStage, Settings};
use bridge_logic::transport::i2c::{I2cSlave, Which};
use stepbridge_sim::SimChain;

pub use crate::sim_bridge::TICK_US;

/// Bridge + simulated chain + I2C bus + virtual clock.
#[derive(Clone)]
pub struct I2cBench {
    pub bridge: Bridge<SimChain>,
    pub slave: I2cSlave,
    pub clock: SimClock,
}

impl I2cBench {
    /// A bridge on `n` simulated chips with `settings`, run until configured.
    pub fn new(n: usize, settings: Settings) -> I2cBench {
        Self::with_board(n, settings, PowerStage::REFERENCE)
    }

    pub fn with_board(n: usize, settings: Settings, board: PowerStage) -> I2cBench {
        let mut b = I2cBench {
            bridge: crate::sim_bridge::new_bridge(n, settings, board),
            slave: I2cSlave::new(),
            clock: SimClock::new(TICK_US),
        };
        b.run(20);
        b
    }

    /// Which own address (if any) `addr` matches.
    fn which(&self, addr: u8) -> Option<Which> {
        let (a, b) = self.bridge.i2c_addresses();
        if addr == a {
            Some(Which::Primary)
        } else if Some(addr) == b {
            Some(Which::Secondary)
        } else {
            None
        }
    }

    /// Master write `bytes` to `addr` (START, address+W, bytes, STOP).
    /// Returns false if nobody acknowledged the address.
    pub fn write(&mut self, addr: u8, bytes: &[u8]) -> bool {
        let Some(which) = self.which(addr) else {
            return false;
        };
        self.slave.on_address(which, false, &mut self.bridge);
        for b in bytes {
            self.slave.on_byte_received(*b);
        }
        self.slave.on_stop(&mut self.bridge);
        true
    }

    /// Master read of `n` bytes from `addr`.
    pub fn read(&mut self, addr: u8, n: usize) -> Option<Vec<u8>> {
        let which = self.which(addr)?;
        self.slave.on_address(which, true, &mut self.bridge);
        let out = (0..n).map(|_| self.slave.on_byte_requested()).collect();
        self.slave.on_stop(&mut self.bridge);
        Some(out)
    }

    /// Write a command, then read `n` bytes of its response.
    pub fn query(&mut self, addr: u8, cmd: u8, n: usize) -> Vec<u8> {
        assert!(self.write(addr, &[cmd]), "address {addr} not acknowledged");
        self.read(addr, n).expect("read")
    }

    /// Run the control loop for `ms` milliseconds of virtual time.
    pub fn run(&mut self, ms: u64) {
        self.clock
            .run(&mut self.bridge, ms * 1000 / u64::from(TICK_US));
    }

    /// Run until every axis is settled (panics after `cap` ms).
    pub fn settle(&mut self, cap: u64) {
        crate::sim_bridge::settle(self, cap, |h| &h.bridge, |h| h.run(1));
    }

    pub fn chip(&self, k: usize) -> &stepbridge_sim::Powerstep01 {
        crate::sim_bridge::chip(&self.bridge, k)
    }

    pub fn chip_mut(&mut self, k: usize) -> &mut stepbridge_sim::Powerstep01 {
        crate::sim_bridge::chip_mut(&mut self.bridge, k)
    }
}

/// Little-endian i32 from the first four bytes.
pub fn le_i32(b: &[u8]) -> i32 {
    i32::from_le_bytes([b[0], b[1], b[2], b[3]])
}

/// Little-endian u16 from the first two bytes.
pub fn le_u16(b: &[u8]) -> u16 {
    u16::from_le_bytes([b[0], b[1]])
}

/// I2C commands that may legitimately start or change motion.
pub const MOTION: [u8; 8] = [0x50, 0x54, 0x05, 0x55, 0x71, 0x5E, 0x70, 0x73];

/// The `i2c_stream` fuzz target's body (also replayed over its corpus by
/// `tests/fuzz_corpus.rs`): arbitrary I2C traffic into a 2-axis bridge.
/// Input: a stream of ops; each op is a tag byte (low 2 bits: 0 write,
/// 1 read, 2 bus error, 3 tick), then for a write: address byte, length
/// byte (mod 24) and that many data bytes; for a read: address, length;
/// for a tick: a count of milliseconds (mod 20). Checks: no panic, and no
/// chip moves unless a write started with a command that may move a motor.
pub fn check_i2c_stream(data: &[u8]) {
    let mut b = crate::sim_bridge::template("i2c_stream", || I2cBench::new(2, Settings::FACTORY));
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
            assert_eq!(
                b.chip(k).abs_pos(),
                0,
                "chip {k} moved without a motion command"
            );
        }
    }
}
