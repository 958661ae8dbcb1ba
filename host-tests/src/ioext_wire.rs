//! The I/O extension's transfers clocked through the simulated shift
//! registers: `stepbridge_sim`'s [`ShiftChain`] takes line levels, not the
//! extension's plans, so the plan's wire ([`wire()`]) is turned into levels
//! here, half period by half period.

use bridge_logic::ioext::{wire, TransferPlan, WireBits};
use stepbridge_sim::{Lines, ShiftChain};

/// Run `plan` through `chain`: the bits the master samples, in wire order.
pub fn transfer(chain: &mut ShiftChain, plan: &TransferPlan) -> WireBits {
    let halves = wire(plan).map(|h| (Lines::new(h.cs, h.sck, h.mosi), h.sample));
    WireBits::from_words(chain.clock_transfer(halves))
}
