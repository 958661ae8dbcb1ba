//! The I/O extension's transfers clocked through the simulated shift
//! registers: `stepbridge_sim`'s [`ShiftChain`] takes line levels, not the
//! extension's plans, so the plan's wire ([`wire()`]) is turned into levels
//! here, half period by half period.

use bridge_logic::ioext::{wire, TransferPlan, WireBits};
use stepbridge_sim::{Lines, ShiftChain};

/// Run `plan` through `chain`: the bits the master samples, in wire order.
pub fn transfer(chain: &mut ShiftChain, plan: &TransferPlan) -> WireBits {
    let mut rx = WireBits::ZERO;
    let mut k = 0;
    let halves = wire(plan).map(|h| {
        (
            Lines {
                cs: h.cs,
                sck: h.sck,
                mosi: h.mosi,
            },
            h.sample,
        )
    });
    chain.clock_transfer(halves, |miso| {
        rx.set(k, miso);
        k += 1;
    });
    rx
}
