//! The bit-level reference of the wire: what CS, SCK and MOSI do, half-period
//! by half-period, for a [`TransferPlan`], and when the master samples MISO.
//!
//! A transfer of n bits is 2n + 3 half-periods ([`HalfPeriod`] = the levels
//! held during it):
//!
//! | step | CS | SCK | MOSI | master samples MISO at its end |
//! |---|---|---|---|---|
//! | before | high (low if held from the last transfer) | CPOL | b0 | – |
//! | setup | low | CPOL | b0 | CPHA = 0 (bit 0) |
//! | lead *i* (i = 0..n) | low | !CPOL | b*i* | CPHA = 1 (bit *i*) |
//! | trail *i* | low | CPOL | CPHA = 0: b*i+1* (b*n−1* for the last); CPHA = 1: b*i* | CPHA = 0 and i < n − 1 (bit *i + 1*) |
//! | after | high (low if `cs_hold`) | CPOL | b*n−1* | – |
//!
//! So there are exactly n leading and n trailing edges, CS and SCK never
//! change at the same boundary, and with CPHA = 0 the data changes on
//! trailing edges and is sampled on leading edges, with CPHA = 1 the other
//! way round (the Copley note's waveforms). MOSI before the first leading
//! edge is b0 in both phases (Copley leaves it undefined; the timer engine
//! drives it, the SPI engine does not promise it for CPHA = 1).
//!
//! Edge convention, for the simulated slaves and for anything else reading
//! this sequence: at a boundary where SCK or CS changes, every device that
//! samples on that edge sees the levels of the half-period *before* it
//! (MOSI and MISO change as a consequence of an edge, after it). A master
//! sample at the end of a half-period sees MISO as the slaves drive it
//! during that half-period.

use super::plan::TransferPlan;

/// Line levels held for one half clock period (true = high).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct HalfPeriod {
    pub cs: bool,
    pub sck: bool,
    pub mosi: bool,
    /// The master samples MISO at the end of this half-period.
    pub sample: bool,
}

/// The half-periods of one transfer, in order.
#[derive(Clone, Debug)]
pub struct Wire {
    plan: TransferPlan,
    step: u32,
}

/// The wire of `plan` (see the module doc).
pub fn wire(plan: &TransferPlan) -> Wire {
    Wire {
        plan: *plan,
        step: 0,
    }
}

impl Wire {
    /// Number of half-periods: 2·bits + 3.
    pub fn steps(&self) -> u32 {
        u32::from(self.plan.bits.max(1))
            .saturating_mul(2)
            .saturating_add(3)
    }
}

impl Iterator for Wire {
    type Item = HalfPeriod;

    fn next(&mut self) -> Option<HalfPeriod> {
        let total = self.steps();
        let s = self.step;
        if s >= total {
            return None;
        }
        self.step = s.saturating_add(1);
        let p = &self.plan;
        let n = usize::from(p.bits.max(1));
        let cpol = p.mode.cpol;
        let cpha = p.mode.cpha;
        let b = |i: usize| p.tx.get(i.min(n.saturating_sub(1)));
        let h = match s {
            0 => HalfPeriod {
                cs: !p.cs_low_before,
                sck: cpol,
                mosi: b(0),
                sample: false,
            },
            1 => HalfPeriod {
                cs: false,
                sck: cpol,
                mosi: b(0),
                sample: !cpha,
            },
            s if s == total.saturating_sub(1) => HalfPeriod {
                cs: !p.cs_hold,
                sck: cpol,
                mosi: b(n.saturating_sub(1)),
                sample: false,
            },
            s => {
                // s = 2 + 2i (leading) or 3 + 2i (trailing).
                let i = usize::try_from(s.saturating_sub(2) / 2).unwrap_or(usize::MAX);
                if s % 2 == 0 {
                    HalfPeriod {
                        cs: false,
                        sck: !cpol,
                        mosi: b(i),
                        sample: cpha,
                    }
                } else {
                    HalfPeriod {
                        cs: false,
                        sck: cpol,
                        mosi: if cpha { b(i) } else { b(i.saturating_add(1)) },
                        sample: !cpha && i.saturating_add(1) < n,
                    }
                }
            }
        };
        Some(h)
    }
}

#[cfg(test)]
mod tests {
    #![allow(
        clippy::indexing_slicing,
        clippy::arithmetic_side_effects,
        clippy::unwrap_used
    )]
    #![allow(clippy::panic)]
    use super::super::clock::Clocks;
    use super::super::config::{SpiMode, WireBits};
    use super::*;

    fn plan(bits: u16, mode: SpiMode, tx: WireBits) -> TransferPlan {
        TransferPlan::single(bits, mode, 0, Clocks::BOARD, tx)
    }

    /// (leading edges, trailing edges) with CS low; panics if CS and SCK
    /// change together.
    fn edges(steps: &[HalfPeriod], cpol: bool) -> (usize, usize) {
        let (mut lead, mut trail) = (0, 0);
        for w in steps.windows(2) {
            let (a, b) = (w[0], w[1]);
            assert!(
                !(a.cs != b.cs && a.sck != b.sck),
                "CS and SCK change together"
            );
            if a.sck != b.sck {
                assert!(!b.cs, "clock edge with CS high");
                if b.sck != cpol {
                    lead += 1;
                } else {
                    trail += 1;
                }
            }
        }
        (lead, trail)
    }

    #[test]
    fn every_bit_count_has_exactly_n_leading_and_n_trailing_edges() {
        for n in [1u16, 7, 8, 9, 31, 32, 33, 255, 256] {
            for mode in SpiMode::ALL {
                let steps: Vec<_> = wire(&plan(n, mode, WireBits::ZERO)).collect();
                assert_eq!(steps.len(), 2 * usize::from(n) + 3);
                assert_eq!(edges(&steps, mode.cpol), (usize::from(n), usize::from(n)));
                assert_eq!(steps.iter().filter(|h| h.sample).count(), usize::from(n));
                // Clock idles at CPOL before and after, CS frames the transfer.
                assert!(steps[0].cs && steps[0].sck == mode.cpol);
                assert!(steps.last().unwrap().cs && steps.last().unwrap().sck == mode.cpol);
                assert!(steps[1..steps.len() - 1].iter().all(|h| !h.cs));
            }
        }
    }

    /// The MOSI level at each sampling edge (the half-period before it).
    fn sampled_mosi(steps: &[HalfPeriod], cpol: bool, cpha: bool) -> Vec<bool> {
        let mut out = vec![];
        for w in steps.windows(2) {
            let (a, b) = (w[0], w[1]);
            if a.sck != b.sck {
                let leading = b.sck != cpol;
                if leading != cpha {
                    out.push(a.mosi);
                }
            }
        }
        out
    }

    #[test]
    fn the_slave_sampling_edge_sees_each_bit_in_order_in_every_mode() {
        let mut tx = WireBits::ZERO;
        for i in [0, 2, 3, 8, 31, 32] {
            tx.set(i, true);
        }
        for n in [1u16, 7, 9, 33] {
            for mode in SpiMode::ALL {
                let steps: Vec<_> = wire(&plan(n, mode, tx)).collect();
                let want: Vec<bool> = (0..usize::from(n)).map(|i| tx.get(i)).collect();
                assert_eq!(
                    sampled_mosi(&steps, mode.cpol, mode.cpha),
                    want,
                    "{mode:?} n {n}"
                );
            }
        }
    }

    #[test]
    fn mosi_changes_only_on_the_non_sampling_edge_or_with_cs() {
        let mut tx = WireBits::ZERO;
        for i in (0..64).step_by(2) {
            tx.set(i, true);
        }
        for mode in SpiMode::ALL {
            let steps: Vec<_> = wire(&plan(33, mode, tx)).collect();
            for w in steps.windows(2) {
                let (a, b) = (w[0], w[1]);
                if a.mosi != b.mosi {
                    let leading = a.sck != b.sck && b.sck != mode.cpol;
                    let trailing = a.sck != b.sck && b.sck == mode.cpol;
                    assert!(if mode.cpha { leading } else { trailing }, "{mode:?}");
                }
            }
        }
    }

    #[test]
    fn master_samples_at_the_sampling_edges() {
        for mode in SpiMode::ALL {
            let steps: Vec<_> = wire(&plan(5, mode, WireBits::ZERO)).collect();
            for (k, w) in steps.windows(2).enumerate() {
                let (a, b) = (w[0], w[1]);
                let sampling = a.sck != b.sck && ((b.sck != mode.cpol) != mode.cpha);
                assert_eq!(a.sample, sampling, "{mode:?} step {k}");
            }
        }
    }

    #[test]
    fn held_cs_starts_low_and_hold_ends_low() {
        let mut p = plan(8, SpiMode::MODE0, WireBits::ZERO);
        p.cs_low_before = true;
        p.cs_hold = true;
        let steps: Vec<_> = wire(&p).collect();
        assert!(steps.iter().all(|h| !h.cs));
    }
}
