//! What the firmware executes: a [`TransferPlan`] is complete — bit count,
//! mode, engine with its register values, CS handling and the bits — so the
//! SPI2 / TIM1 driver takes no decision of its own.
//!
//! # What the driver does with a plan
//!
//! Pins (suggested, `pins.rs` decides): SCK = PB13 (SPI2_SCK AF5 for the
//! SPI engine, TIM1_CH1N AF1 for the timer engine), MISO = PB14, MOSI =
//! PB15, CS = a push-pull GPIO with an external pull-up (CS must read high
//! while the port is not configured). For every plan:
//!
//! 1. If the engine differs from the last plan's, switch SCK's alternate
//!    function; MOSI/MISO are AF5 for the SPI engine, GPIO output / input
//!    for the timer engine. SCK must keep the idle level `mode.cpol`
//!    throughout.
//! 2. Unless [`TransferPlan::cs_low_before`], drive CS low. The first clock
//!    edge must come at least [`TransferPlan::half_period_ns`] after CS fell
//!    (the timer engine's first phase, [`TimerSetup::ccr_sck`] ticks, lasts
//!    at least that; the SPI engine waits before it writes the first
//!    frame).
//! 3. Run the engine:
//!    * [`SpiSetup`] — SPI2 master, 8-bit frames, MSB first, software NSS,
//!      CR1.BR = `br`, CPOL/CPHA = `mode`; `frames` bytes out of
//!      [`TransferPlan::tx_byte`]`(0..frames)` and as many in, by DMA1
//!      (SPI2_TX stream 4, SPI2_RX stream 3, channel 0). At the end wait for
//!      BSY = 0; the received bytes, in order, go to
//!      [`WireBits::from_bytes`].
//!    * [`TimerSetup`] — TIM1: PSC, ARR, RCR (= bits − 1) as given, loaded
//!      with EGR.UG before any DMA request is enabled; one-pulse mode;
//!      CH1 in PWM mode 2 with CCR1 = `ccr_sck` and only the complementary
//!      output enabled (CC1E = 0, CC1NE = 1, CC1NP = `mode.cpol`, MOE = 1:
//!      OC1N = OC1REF xor CC1NP, so SCK is `cpol` while CNT < CCR1 and
//!      `!cpol` from CCR1 to ARR, and `cpol` once the timer stops). Before
//!      CEN: MOSI = [`TimerSetup::first_mosi`]. CC3 (CCR3 = `ccr_mosi`)
//!      requests DMA2 stream 6 / channel 6 to write the next entry of
//!      [`TransferPlan::mosi_bsrr`] to GPIO BSRR (`bits` entries); CC2
//!      (CCR2 = `ccr_sample`) requests DMA2 stream 2 / channel 6 to copy
//!      GPIO IDR into a buffer (`bits` half-words), which
//!      [`WireBits::from_port_samples`] turns into the received bits. The
//!      end is CEN reading 0 after the last sample.
//! 4. Wait [`TransferPlan::half_period_ns`] after the last clock edge,
//!    then raise CS unless [`TransferPlan::cs_hold`].
//! 5. Queue the received bits; the control tick hands them to
//!    [`IoExtension::complete`](super::IoExtension::complete) after its
//!    chain batch. On a DMA or bus error stop the engine, raise CS and queue
//!    a failure ([`IoExtension::fail`](super::IoExtension::fail)).
//!
//! The driver runs at the lowest priority (a software task that gets the
//! plan from the control tick and starts it, the DMA interrupt that ends
//! it) and never locks the extension's state, so it never holds up the
//! control tick; being preempted can only delay a start or lengthen the SPI
//! engine's gaps between frames — never shorten a clock period, which the
//! peripheral or the timer makes.
//!
//! [`Action::Disable`]: raise CS and stop driving the port (SCK, MOSI back
//! to inputs): the extension was switched off.
//!
//! The edges of the wire, half-period by half-period, are given by
//! [`wire`](super::wire::wire); the host tests check them against simulated
//! 74HC165/74HC595 chips.

use super::clock::{clock_plan, ClockPlan, Clocks, Engine};
use super::config::{SpiMode, WireBits};

/// What the firmware must do after a control tick.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Action {
    /// Run this transfer on the extension port.
    Transfer(TransferPlan),
    /// The extension was switched off: raise CS (if low) and release the port.
    Disable,
}

/// One transfer, ready to run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct TransferPlan {
    /// Bits to clock, 1..=256: exactly this many clock periods.
    pub bits: u16,
    pub mode: SpiMode,
    pub clock: ClockPlan,
    /// CS is still low from the previous transfer (it held CS): do not
    /// touch it at the start.
    pub cs_low_before: bool,
    /// Leave CS low at the end.
    pub cs_hold: bool,
    /// The bits to send, in wire order; bits from `bits` on are 0.
    pub tx: WireBits,
}

/// SPI2 settings of a plan on the SPI engine.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SpiSetup {
    /// CR1.BR: prescaler 2^(br + 1).
    pub br: u8,
    pub mode: SpiMode,
    /// 8-bit frames to move (bits / 8).
    pub frames: u16,
}

/// TIM1 settings of a plan on the timer engine (see the module doc).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct TimerSetup {
    pub psc: u16,
    /// Period − 1.
    pub arr: u16,
    /// Bits − 1: the timer makes RCR + 1 clock periods, then stops.
    pub rcr: u8,
    /// CCR1: the leading SCK edge of each period (the first phase is the
    /// idle level, `ccr_sck` ticks long). The first phase is also the CS
    /// set-up, so it lasts at least [`TransferPlan::half_period_ns`]: the
    /// fewest ticks that do (⌈period / 2⌉ for an odd period, one more than
    /// half where half the period is not a whole number of ns), the second
    /// phase the rest.
    pub ccr_sck: u16,
    /// CCR3: when MOSI takes its next bit (1 tick after the trailing edge
    /// for CPHA = 0, at the leading edge for CPHA = 1).
    pub ccr_mosi: u16,
    /// CCR2: when MISO is sampled — the middle of the half-period that ends
    /// at the sampling edge, where the slave's output is stable.
    pub ccr_sample: u16,
    /// MOSI level to set before the timer starts (bit 0).
    pub first_mosi: bool,
}

impl TransferPlan {
    /// A transfer on its own (CS neither held from the one before nor after
    /// it): `tx`'s first `bits` bits in `mode`, clock divider `n` on `clocks`.
    pub fn single(bits: u16, mode: SpiMode, n: u8, clocks: Clocks, tx: WireBits) -> TransferPlan {
        TransferPlan {
            bits,
            mode,
            clock: clock_plan(n, bits, clocks),
            cs_low_before: false,
            cs_hold: false,
            tx: tx.truncated(bits),
        }
    }

    /// Wire bit `i` of the data to send.
    pub fn mosi(&self, i: usize) -> bool {
        self.tx.get(i)
    }

    /// Byte `j` for the SPI engine's 8-bit frames.
    pub fn tx_byte(&self, j: usize) -> u8 {
        self.tx.byte(j)
    }

    /// Half a clock period, ns, rounded up: the least time from CS falling
    /// to the first clock edge, and from the last clock edge to CS rising.
    pub fn half_period_ns(&self) -> u64 {
        self.clock.period.nanos_ceil().div_ceil(2)
    }

    /// Time CS is low for this transfer at the nominal clock ((bits + ½)
    /// periods: half a period before the first edge, `bits` periods, and the
    /// last half-period before CS rises), ns rounded up. The real transfer
    /// takes longer by the driver's start and end latency.
    pub fn nominal_ns(&self) -> u64 {
        let half_periods = u64::from(self.bits).saturating_mul(2).saturating_add(1);
        let p = self.clock.period;
        u64::from(p.ticks)
            .saturating_mul(half_periods)
            .saturating_mul(1_000_000_000)
            .div_ceil(u64::from(p.hz).saturating_mul(2).max(1))
    }

    /// How long the driver waits for the end of this transfer before it
    /// gives up (stops the engine, raises CS and reports a failure), µs:
    /// twice the nominal duration ([`TransferPlan::nominal_ns`]) plus 2 ms
    /// for the start and end latency (higher-priority tasks, the 10 kHz
    /// monotonic's granularity). A transfer that works ends long before.
    pub fn timeout_us(&self) -> u64 {
        self.nominal_ns()
            .div_ceil(1_000)
            .saturating_mul(2)
            .saturating_add(2_000)
    }

    /// The SPI2 settings, for a plan on the SPI engine.
    pub fn spi(&self) -> Option<SpiSetup> {
        match self.clock.engine {
            Engine::Spi { br } => Some(SpiSetup {
                br,
                mode: self.mode,
                frames: self.bits / 8,
            }),
            Engine::Timer { .. } => None,
        }
    }

    /// The TIM1 settings, for a plan on the timer engine.
    pub fn timer(&self) -> Option<TimerSetup> {
        let Engine::Timer { psc, period } = self.clock.engine else {
            return None;
        };
        // period is 4..=65 536 (clock::timer_settings), so every value fits.
        let period = period.clamp(4, 65_536);
        // The first phase is the CS set-up: at least the half period the
        // plan promises, in whole timer ticks (⌊period / 2⌋ was 1 107 ns at
        // N = 22, where the promise is 1 111 ns), and at least ⌈period / 2⌉;
        // at most period − 1, so the leading edge is inside the period.
        let per_tick = 1_000_000_000u64.saturating_mul(u64::from(psc) + 1);
        let promised = self
            .half_period_ns()
            .saturating_mul(u64::from(self.clock.period.hz))
            .div_ceil(per_tick);
        let promised = u32::try_from(promised).unwrap_or(u32::MAX);
        let first = promised
            .max(period.div_ceil(2))
            .min(period.saturating_sub(1));
        let second = period.saturating_sub(first);
        let (ccr_mosi, ccr_sample) = if self.mode.cpha {
            (first, first.saturating_add(second / 2))
        } else {
            (1, first / 2)
        };
        let fit = |v: u32| u16::try_from(v).unwrap_or(u16::MAX);
        Some(TimerSetup {
            psc,
            arr: fit(period.saturating_sub(1)),
            rcr: u8::try_from(self.bits.saturating_sub(1)).unwrap_or(u8::MAX),
            ccr_sck: fit(first),
            ccr_mosi: fit(ccr_mosi),
            ccr_sample: fit(ccr_sample),
            first_mosi: self.mosi(0),
        })
    }

    /// The timer engine's MOSI DMA table: one GPIO BSRR word per bit (bit
    /// `k` sets or resets `pin`, 0..=15), written at CCR3 of period `k`.
    /// Fills `out` and returns the number of words (`bits`, or fewer if
    /// `out` is shorter).
    pub fn mosi_bsrr(&self, pin: u8, out: &mut [u32]) -> usize {
        let n = usize::from(self.bits).min(out.len());
        let (set, reset) = (bsrr(pin, true), bsrr(pin, false));
        let out = out.get_mut(..n).unwrap_or(&mut []);
        for (chunk, w) in out.chunks_mut(16).zip(self.tx.words()) {
            let mut w = *w;
            for slot in chunk {
                *slot = if w & 0x8000 != 0 { set } else { reset };
                w = w.wrapping_shl(1);
            }
        }
        n
    }
}

/// The GPIO BSRR word that drives `pin` (0..=15, taken modulo 16) to `level`.
pub const fn bsrr(pin: u8, level: bool) -> u32 {
    let bit = 1u32 << (pin % 16);
    if level {
        bit
    } else {
        bit << 16
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
    use super::super::clock::{clock_plan, Clocks, Engine, CLOCKS_UNDER_TEST};
    use super::*;

    fn plan(bits: u16, mode: SpiMode, n: u8) -> TransferPlan {
        let tx = WireBits::from_fn(bits, |i| i % 3 == 0);
        TransferPlan::single(bits, mode, n, Clocks::BOARD, tx)
    }

    #[test]
    fn spi_plans_move_bits_over_8_frames() {
        let p = plan(256, SpiMode::MODE3, 0);
        assert_eq!(
            p.spi(),
            Some(SpiSetup {
                br: 0,
                mode: SpiMode::MODE3,
                frames: 32
            })
        );
        assert_eq!(p.timer(), None);
        assert_eq!(p.tx_byte(0), 0b1001_0010);
    }

    #[test]
    fn timer_plans_make_exactly_bits_periods_with_compares_inside_the_period() {
        for bits in [1u16, 7, 9, 33, 255] {
            for mode in SpiMode::ALL {
                let p = plan(bits, mode, 50);
                assert_eq!(p.spi(), None);
                let t = p.timer().unwrap();
                assert_eq!(u16::from(t.rcr) + 1, bits);
                // 844 ticks = 5 023.8 ns: the promised half is 2 512 ns, 422
                // ticks would be 2 511.9 ns.
                assert_eq!((t.psc, t.arr, t.ccr_sck), (0, 843, 423));
                if mode.cpha {
                    // MOSI at the leading edge, sample in the middle of the active phase.
                    assert_eq!((t.ccr_mosi, t.ccr_sample), (423, 633));
                } else {
                    // MOSI just after the trailing edge, sample mid idle phase.
                    assert_eq!((t.ccr_mosi, t.ccr_sample), (1, 211));
                }
                assert!(t.first_mosi);
            }
        }
    }

    #[test]
    fn the_timer_engines_first_phase_lasts_at_least_the_promised_half_period() {
        // N = 22: 373 ticks (2 220.2 ns), an odd period; the promise is
        // 1 111 ns, ⌊373 / 2⌋ = 186 ticks would be 1 107.1 ns.
        let p = plan(9, SpiMode::MODE0, 22);
        assert_eq!(p.half_period_ns(), 1_111);
        let t = p.timer().unwrap();
        assert_eq!((t.arr, t.ccr_sck), (372, 187));
        for clocks in CLOCKS_UNDER_TEST.into_iter().chain([Clocks {
            spi_hz: 42_000_000,
            timer_hz: 100_000_001,
        }]) {
            for n in 0..=255u8 {
                for bits in [1u16, 9, 255] {
                    let mut p = plan(bits, SpiMode::MODE1, n);
                    p.clock = clock_plan(n, bits, clocks);
                    let Some(t) = p.timer() else {
                        continue;
                    };
                    let Engine::Timer { psc, period } = p.clock.engine else {
                        panic!("a timer plan on the SPI engine")
                    };
                    // ccr_sck ticks of (PSC + 1) / f ≥ the promise, exactly.
                    let first_ns_x_hz = u64::from(t.ccr_sck) * (u64::from(psc) + 1) * 1_000_000_000;
                    assert!(
                        first_ns_x_hz >= p.half_period_ns() * u64::from(clocks.timer_hz),
                        "{clocks:?} N {n}: {} ticks",
                        t.ccr_sck
                    );
                    assert!(u32::from(t.ccr_sck) >= period.div_ceil(2));
                    assert!(u32::from(t.ccr_sck) < period, "the leading edge is inside");
                    // The compare points stay in order inside the period.
                    assert!(t.ccr_sample <= t.arr && t.ccr_mosi <= t.ccr_sck);
                    assert!(t.ccr_sample > 0 && t.ccr_mosi > 0);
                }
            }
        }
    }

    #[test]
    fn bsrr_table_sets_and_resets_the_pin_bit_by_bit() {
        let p = plan(9, SpiMode::MODE0, 0);
        let mut out = [0u32; 256];
        assert_eq!(p.mosi_bsrr(15, &mut out), 9);
        assert_eq!(out[0], 1 << 15);
        assert_eq!(out[1], 1 << 31);
        assert_eq!(out[3], 1 << 15);
        assert_eq!(out[9], 0);
        let mut short = [0u32; 4];
        assert_eq!(p.mosi_bsrr(15, &mut short), 4);
    }

    #[test]
    fn half_period_and_nominal_duration() {
        // 256 bits at 47.619 ns: (512 + 1) half-periods = 12 214.3 ns.
        let p = plan(256, SpiMode::MODE0, 0);
        assert_eq!(p.half_period_ns(), 24);
        assert_eq!(p.nominal_ns(), 12_215);
        // 256 bits at N = 255 (25 523.8 ns): 6.546 ms.
        let p = plan(256, SpiMode::MODE0, 255);
        assert_eq!(p.nominal_ns(), 6_546_858);
        assert_eq!(p.half_period_ns(), 12_762);
    }

    #[test]
    fn the_timeout_is_twice_the_nominal_duration_plus_2_ms() {
        // 12.215 µs → 13 µs, twice that, plus 2 ms.
        assert_eq!(plan(256, SpiMode::MODE0, 0).timeout_us(), 2_026);
        // 6 546.858 µs → 6 547 µs, twice that, plus 2 ms: 15.1 ms.
        assert_eq!(plan(256, SpiMode::MODE0, 255).timeout_us(), 15_094);
        // Always longer than the transfer, whatever the plan.
        for bits in [1u16, 8, 9, 256] {
            for n in [0u8, 1, 5, 50, 255] {
                let p = plan(bits, SpiMode::MODE3, n);
                assert!(p.timeout_us() * 1_000 > 2 * p.nominal_ns());
            }
        }
    }
}
