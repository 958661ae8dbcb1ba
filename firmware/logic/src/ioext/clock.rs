//! The clock plan: how the bridge produces the configured SPI clock, and the
//! period it really produces.
//!
//! Copley asks for a period of (N·100 + 20) ns, N = 0..=255 (20 ns to
//! 25.52 µs) and any bit count 1..=256. The STM32F405's SPI2 divides its
//! kernel clock (APB1, 42 MHz on the board) by 2, 4, …, 256 and moves 8- or
//! 16-bit frames, so it cannot do every period nor every bit count. Two
//! engines, chosen per transfer:
//!
//! * **SPI engine** — SPI2 itself, 8-bit frames, when the bit count is a
//!   multiple of 8 and some prescaler 2^k (k = 1..=8) gives a period of at
//!   least the requested one: the smallest such k. Period = 2^k / f_SPI,
//!   exact (the peripheral makes every edge).
//! * **Timer engine** — for everything else (bit counts that are not a
//!   multiple of 8, periods longer than 256 / f_SPI = 6.095 µs): TIM1 in
//!   one-pulse PWM mode with the repetition counter set to n − 1 makes
//!   exactly n clock periods on its CH1N pin and stops (the repetition
//!   counter is 8 bits: exactly 1..=256). Period = (PSC + 1)·(ARR + 1) /
//!   f_TIM, f_TIM = 168 MHz on the board (5.95 ns steps), never shorter than
//!   [`TIMER_MIN_PERIOD_NS`]: MOSI and the MISO samples are moved by DMA
//!   from compare events, and the floor leaves every DMA request a quarter
//!   period (≥ 42 CPU cycles) to be served.
//!
//! Guarantee (checked for every N and both engines in the tests): the
//! produced period is never shorter than the requested one. All maths is
//! exact integer arithmetic on the clock frequencies in Hz.

/// Kernel clocks of the two engines, in Hz.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Clocks {
    /// SPI2's kernel clock (PCLK1).
    pub spi_hz: u32,
    /// TIM1's kernel clock (2 × PCLK2 when the APB2 prescaler is not 1).
    pub timer_hz: u32,
}

/// The clock trees the plans are tested on: the board's, a slow equal one
/// and one whose timer runs at 3× the SPI clock (the tests add their edge).
#[cfg(test)]
pub(super) const CLOCKS_UNDER_TEST: [Clocks; 3] = [
    Clocks::BOARD,
    Clocks {
        spi_hz: 16_000_000,
        timer_hz: 16_000_000,
    },
    Clocks {
        spi_hz: 1_000,
        timer_hz: 3_000,
    },
];

impl Clocks {
    /// The board: SYSCLK 168 MHz, APB1 = 42 MHz, APB2 = 84 MHz → TIM1 at
    /// 168 MHz.
    pub const BOARD: Clocks = Clocks {
        spi_hz: 42_000_000,
        timer_hz: 168_000_000,
    };
}

/// Shortest period of the timer engine (1 MHz), ns.
pub const TIMER_MIN_PERIOD_NS: u32 = 1000;

/// The period Copley's field N asks for: (N·100 + 20) ns.
pub const fn requested_period_ns(n: u8) -> u32 {
    // At most 25 520: never wraps.
    (n as u32).wrapping_mul(100).wrapping_add(20)
}

/// A duration of `ticks` periods of a `hz` clock (exact).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Period {
    pub ticks: u32,
    pub hz: u32,
}

const NS_PER_S: u64 = 1_000_000_000;
const PS_PER_S: u64 = 1_000_000_000_000;

impl Period {
    /// Picoseconds, rounded up (saturating).
    pub const fn picos_ceil(self) -> u64 {
        div_ceil((self.ticks as u64).saturating_mul(PS_PER_S), self.hz as u64)
    }

    /// Nanoseconds, rounded up (saturating).
    pub const fn nanos_ceil(self) -> u64 {
        div_ceil((self.ticks as u64).saturating_mul(NS_PER_S), self.hz as u64)
    }

    /// Whether this period is at least `ns` nanoseconds (exact).
    pub const fn at_least_ns(self, ns: u32) -> bool {
        // ticks / hz ≥ ns / 1e9  ⇔  ticks·1e9 ≥ ns·hz; both products of
        // two u32-range factors (1e9 < 2^30) stay below 2^64.
        (self.ticks as u64).saturating_mul(NS_PER_S) >= (ns as u64).saturating_mul(self.hz as u64)
    }
}

/// `a / b` rounded up; `u64::MAX` for `b = 0`.
const fn div_ceil(a: u64, b: u64) -> u64 {
    if b == 0 {
        u64::MAX
    } else {
        a.div_ceil(b)
    }
}

/// Which hardware makes the clock, with its exact settings.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Engine {
    /// SPI2, 8-bit frames, MSB first; SPI_CR1.BR = `br` (prescaler
    /// 2^(br + 1), br = 0..=7).
    Spi { br: u8 },
    /// TIM1 one-pulse PWM: PSC = `psc`, ARR = `period − 1` (`period` =
    /// 4..=65 536 prescaled ticks).
    Timer { psc: u16, period: u32 },
}

/// The engine for a configuration and the period it produces.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ClockPlan {
    pub engine: Engine,
    /// The real clock period.
    pub period: Period,
}

impl ClockPlan {
    /// Engine code as the diagnostics register shows it: 1 SPI, 2 timer.
    pub const fn engine_code(&self) -> u16 {
        match self.engine {
            Engine::Spi { .. } => 1,
            Engine::Timer { .. } => 2,
        }
    }
}

/// The SPI prescaler exponent k (1..=8, divider 2^k) for `ns`: the smallest
/// whose period 2^k / `spi_hz` is at least `ns`; `None` when even 256 is too
/// fast (or the clock is 0).
pub const fn spi_divider_log2(ns: u32, spi_hz: u32) -> Option<u8> {
    if spi_hz == 0 {
        return None;
    }
    let mut k = 1u8;
    while k <= 8 {
        let p = Period {
            ticks: 1 << k,
            hz: spi_hz,
        };
        if p.at_least_ns(ns) {
            return Some(k);
        }
        k = k.wrapping_add(1);
    }
    None
}

/// The timer settings for a period of at least `ns` (and at least
/// [`TIMER_MIN_PERIOD_NS`]): the smallest prescaler that lets ARR fit 16 bits,
/// then the smallest period in its ticks. At least 4 ticks, so the four
/// compare points of a bit are distinct.
pub const fn timer_settings(ns: u32, timer_hz: u32) -> (u16, u32) {
    let ns = if ns < TIMER_MIN_PERIOD_NS {
        TIMER_MIN_PERIOD_NS
    } else {
        ns
    };
    // Kernel ticks needed: ⌈ns · hz / 1e9⌉ ≤ 25 520 · 2^32 / 1e9 < 2^17.
    let need = div_ceil((ns as u64).saturating_mul(timer_hz as u64), NS_PER_S);
    let need = if need < 4 { 4 } else { need };
    let psc_plus_1 = div_ceil(need, 65_536);
    let period = div_ceil(need, psc_plus_1);
    // need < 2^17, so PSC ≤ 1 and period ≤ 65 536.
    (psc_plus_1.saturating_sub(1) as u16, period as u32)
}

/// The clock plan for field N and `bits` bits (see the module doc).
pub const fn clock_plan(n: u8, bits: u16, clocks: Clocks) -> ClockPlan {
    let ns = requested_period_ns(n);
    if bits % 8 == 0 {
        if let Some(k) = spi_divider_log2(ns, clocks.spi_hz) {
            return ClockPlan {
                engine: Engine::Spi {
                    br: k.saturating_sub(1),
                },
                period: Period {
                    ticks: 1 << k,
                    hz: clocks.spi_hz,
                },
            };
        }
    }
    let (psc, period) = timer_settings(ns, clocks.timer_hz);
    ClockPlan {
        engine: Engine::Timer { psc, period },
        period: Period {
            ticks: (psc as u32).saturating_add(1).saturating_mul(period),
            hz: clocks.timer_hz,
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ps(n: u8, bits: u16) -> u64 {
        clock_plan(n, bits, Clocks::BOARD).period.picos_ceil()
    }

    #[test]
    fn requested_period_is_n_times_100_plus_20_ns() {
        assert_eq!(requested_period_ns(0), 20);
        assert_eq!(requested_period_ns(1), 120);
        assert_eq!(requested_period_ns(255), 25_520);
    }

    #[test]
    fn spi_engine_periods_at_42_mhz_for_n_0_1_5_50() {
        // N = 0: 20 ns → /2 = 47.619 ns (21 MHz).
        assert_eq!(
            clock_plan(0, 8, Clocks::BOARD).engine,
            Engine::Spi { br: 0 }
        );
        assert_eq!(ps(0, 8), 47_620);
        // N = 1: 120 ns → /8 = 190.476 ns (/4 = 95.2 ns would be too fast).
        assert_eq!(
            clock_plan(1, 8, Clocks::BOARD).engine,
            Engine::Spi { br: 2 }
        );
        assert_eq!(ps(1, 8), 190_477);
        // N = 5: 520 ns → /32 = 761.905 ns.
        assert_eq!(
            clock_plan(5, 16, Clocks::BOARD).engine,
            Engine::Spi { br: 4 }
        );
        assert_eq!(ps(5, 16), 761_905);
        // N = 50: 5 020 ns → /256 = 6 095.238 ns.
        assert_eq!(
            clock_plan(50, 256, Clocks::BOARD).engine,
            Engine::Spi { br: 7 }
        );
        assert_eq!(ps(50, 256), 6_095_239);
    }

    #[test]
    fn n_255_needs_the_timer_engine_at_25_524_ns() {
        // 25 520 ns > 256 / 42 MHz: 4 288 ticks of 168 MHz = 25 523.810 ns.
        let p = clock_plan(255, 8, Clocks::BOARD);
        assert_eq!(
            p.engine,
            Engine::Timer {
                psc: 0,
                period: 4288
            }
        );
        assert_eq!(p.period.picos_ceil(), 25_523_810);
    }

    #[test]
    fn bit_counts_not_a_multiple_of_8_use_the_timer_engine() {
        // N = 0, 1, 5: below the 1 µs floor → 168 ticks = 1 000 ns exactly.
        for n in [0, 1, 5] {
            for bits in [1, 7, 9, 31, 33, 255] {
                let p = clock_plan(n, bits, Clocks::BOARD);
                assert_eq!(
                    p.engine,
                    Engine::Timer {
                        psc: 0,
                        period: 168
                    },
                    "N {n} bits {bits}"
                );
                assert_eq!(p.period.picos_ceil(), 1_000_000);
            }
        }
        // N = 50: ⌈5 020 · 0.168⌉ = 844 ticks = 5 023.810 ns.
        let p = clock_plan(50, 9, Clocks::BOARD);
        assert_eq!(
            p.engine,
            Engine::Timer {
                psc: 0,
                period: 844
            }
        );
        assert_eq!(p.period.picos_ceil(), 5_023_810);
        assert_eq!(ps(255, 9), 25_523_810);
    }

    #[test]
    fn the_period_is_never_shorter_than_requested_for_any_n_and_engine() {
        for clocks in CLOCKS_UNDER_TEST.into_iter().chain([Clocks {
            spi_hz: u32::MAX,
            timer_hz: u32::MAX,
        }]) {
            for n in 0..=255u8 {
                for bits in [1, 8, 9, 16, 256] {
                    let p = clock_plan(n, bits, clocks);
                    assert!(
                        p.period.at_least_ns(requested_period_ns(n)),
                        "{clocks:?} N {n}"
                    );
                    if let Engine::Timer { psc, period } = p.engine {
                        assert!((4..=65_536).contains(&period));
                        assert!(p.period.at_least_ns(TIMER_MIN_PERIOD_NS));
                        assert_eq!(p.period.ticks, (u32::from(psc) + 1) * period);
                    }
                }
            }
        }
    }

    #[test]
    fn the_spi_divider_is_the_fastest_that_is_slow_enough() {
        for n in 0..=255u8 {
            let ns = requested_period_ns(n);
            if let Some(k) = spi_divider_log2(ns, 42_000_000) {
                assert!(
                    k == 1
                        || !Period {
                            ticks: 1 << (k - 1),
                            hz: 42_000_000
                        }
                        .at_least_ns(ns)
                );
            } else {
                // 256 / 42 MHz = 6 095.2 ns: N ≥ 61 (6 120 ns) has no divider.
                assert!(n >= 61);
            }
        }
        assert_eq!(spi_divider_log2(6_020, 42_000_000), Some(8));
        assert_eq!(spi_divider_log2(6_120, 42_000_000), None);
        assert_eq!(spi_divider_log2(20, 0), None);
    }

    #[test]
    fn a_zero_clock_never_divides_by_zero() {
        let p = clock_plan(
            0,
            8,
            Clocks {
                spi_hz: 0,
                timer_hz: 0,
            },
        );
        assert_eq!(p.engine, Engine::Timer { psc: 0, period: 4 });
        assert_eq!(p.period.picos_ceil(), u64::MAX);
        assert!(p.period.at_least_ns(u32::MAX));
    }
}
