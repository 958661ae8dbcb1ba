//! The extension's promises (module doc of [`ioext`](super)), checked
//! through its registers and against simulated 74HC165/74HC595 chips.

#![allow(
    clippy::indexing_slicing,
    clippy::arithmetic_side_effects,
    clippy::unwrap_used
)]
#![allow(clippy::expect_used, clippy::panic)]

mod mapping;
mod props;
mod registers;
mod transfers;

use super::config::cfg;
use super::registers::addr;
use super::*;
use stepbridge_sim::shift::{Lines, ShiftChain};

/// The extension on the board's clocks with 32 '165s and 32 '595s.
pub(super) struct Rig {
    pub io: IoExtension,
    pub chain: ShiftChain,
    pub plans: Vec<TransferPlan>,
}

impl Rig {
    pub fn new() -> Rig {
        Rig::with(IoSettings::FACTORY)
    }

    pub fn with(settings: IoSettings) -> Rig {
        Rig {
            io: IoExtension::new(settings, Clocks::BOARD),
            chain: ShiftChain::new(32, 32),
            plans: vec![],
        }
    }

    pub fn write(&mut self, a: u16, data: &[u16]) -> Result<(), IoError> {
        self.io.write(a, data)
    }

    pub fn read(&mut self, a: u16, n: usize) -> Result<Vec<u16>, IoError> {
        let mut out = vec![0; n];
        self.io.read(a, &mut out)?;
        Ok(out)
    }

    pub fn config_reg(&mut self) -> u32 {
        let r = self.read(addr::CONFIG, 2).unwrap();
        (u32::from(r[0]) << 16) | u32::from(r[1])
    }

    pub fn set_config(&mut self, v: u32) -> Result<(), IoError> {
        self.write(addr::CONFIG, &[(v >> 16) as u16, v as u16])
    }

    pub fn enable(&mut self) {
        self.write(addr::IO_OPTIONS, &[0, 1]).unwrap();
    }

    /// Configure `bits` bits in `mode` at N, SPI mode, plus `extra` bits,
    /// and enable.
    pub fn setup(&mut self, bits: u16, mode: SpiMode, n: u8, extra: u32) {
        let c = Config::new(bits, mode, n).unwrap().register(false) | extra;
        self.set_config(c).unwrap();
        self.enable();
    }

    /// One control tick with these lamp states; a planned transfer runs
    /// through the simulated chain and completes at once.
    pub fn tick_with(&mut self, outs: &[AxisOutputs]) -> Option<TransferPlan> {
        match self.io.tick(outs)? {
            Action::Transfer(p) => {
                let rx = run(&mut self.chain, &p);
                self.io.complete(&rx).unwrap();
                self.plans.push(p);
                Some(p)
            }
            Action::Disable => None,
        }
    }

    pub fn tick(&mut self) -> Option<TransferPlan> {
        self.tick_with(&[])
    }
}

/// Clock `plan`'s wire ([`wire()`]) through the simulated chips, half
/// period by half period: the bits the master samples.
pub(super) fn run(chain: &mut ShiftChain, plan: &TransferPlan) -> WireBits {
    let halves = wire(plan).map(|h| (Lines::new(h.cs, h.sck, h.mosi), h.sample));
    WireBits::from_words(chain.clock_transfer(halves))
}

/// A bit pattern that tells positions apart.
pub(super) fn pattern(seed: u32) -> WireBits {
    let mut b = WireBits::ZERO;
    let mut x = seed.wrapping_mul(2_654_435_761) | 1;
    for i in 0..256 {
        x ^= x << 13;
        x ^= x >> 17;
        x ^= x << 5;
        b.set(i, x & 1 != 0);
    }
    b
}
