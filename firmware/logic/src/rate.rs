//! The control-tick rate, a build-time setting.
//!
//! `STEPBRIDGE_TICK_HZ` in the environment of the build (e.g.
//! `STEPBRIDGE_TICK_HZ=5000 cargo fw`) sets the rate the firmware ticks the
//! bridge at; without it the rate is 1 kHz. The rate must divide 10⁶ (the
//! tick period is a whole number of µs) and lie in 500..=10 000 Hz; anything
//! else fails the build. Everything below the firmware takes the period as a
//! parameter (the motion tests run at 1, 2 and 5 kHz whatever this says).

// Build-time rate arithmetic on small constants (µs periods, chip counts ≤ 8).
#![allow(clippy::arithmetic_side_effects)]

/// Ticks per second (build setting `STEPBRIDGE_TICK_HZ`, default 1000).
pub const TICK_HZ: u32 = match option_env!("STEPBRIDGE_TICK_HZ") {
    Some(s) => parse(s),
    None => 1000,
};

/// The tick period, µs.
pub const TICK_US: u32 = 1_000_000 / TICK_HZ;

/// The slowest tick the firmware runs at: the floor of the build setting
/// and of [`fit`]'s derating.
pub const HZ_MIN: u32 = 500;
/// The fastest build setting.
pub const HZ_MAX: u32 = 10_000;
/// The longest tick period, µs (at [`HZ_MIN`]): what the MCU's watchdog
/// window must comfortably outlast (`drivers_core::iwdg::SHORT`).
pub const PERIOD_MAX_US: u32 = 1_000_000 / HZ_MIN;

const _: () = assert!(
    TICK_HZ >= HZ_MIN && TICK_HZ <= HZ_MAX && 1_000_000 % TICK_HZ == 0,
    "STEPBRIDGE_TICK_HZ must divide 1 000 000 and lie in 500..=10000"
);

/// Decimal digits → u32 at compile time (anything else fails the build).
// Only ever const-evaluated: an index or an assertion that fails fails the build.
#[allow(clippy::indexing_slicing, clippy::panic)]
const fn parse(s: &str) -> u32 {
    let b = s.as_bytes();
    assert!(
        !b.is_empty() && b.len() <= 6,
        "STEPBRIDGE_TICK_HZ: 1 to 6 digits"
    );
    let mut i = 0;
    let mut v = 0u32;
    while i < b.len() {
        assert!(b[i].is_ascii_digit(), "STEPBRIDGE_TICK_HZ: digits only");
        v = v * 10 + (b[i] - b'0') as u32;
        i += 1;
    }
    v
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn digits_parse_as_decimal() {
        assert_eq!(parse("5000"), 5000);
        assert_eq!(parse("1000"), 1000);
    }
}

/// The control-tick rate the firmware runs at for a chain of `chips`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Rate {
    pub hz: u32,
    /// The period, µs (a whole number).
    pub us: u32,
    /// Slower than the build setting: the chain's batch and the tick's
    /// computation would not fit its period.
    pub derated: bool,
}

/// SPI1 clock of the chain (APB2 84 MHz / 32).
pub const CHAIN_SPI_HZ: u64 = 2_625_000;
/// CS windows of a streaming batch (a read and a Run per axis).
pub const STREAM_WINDOWS: u64 = 5;
/// Per window besides the bytes: ≥ 800 ns CS high, ≥ 350 ns set-up (the
/// DMA driver's TIM7 phases, 821 + 369 ns) and ~1 µs of interrupt latency.
pub const WINDOW_OVERHEAD_NS: u64 = 2_190;
/// The tick's computation per axis and its fixed part, ns at 168 MHz
/// (`cargo tick-cpu`, 5 kHz build: 16 309 cycles for 8 axes streaming
/// incl. flash wait states ≈ 12.1 µs per axis, taken as 12.5; the driver's
/// start and hand-over ≈ 3 µs).
pub const COMPUTE_NS_PER_AXIS: u64 = 12_500;
pub const COMPUTE_NS_FIXED: u64 = 5_000;
/// Share of the period the batch and the computation may take (the rest is
/// for the bus tasks and interrupt latency).
pub const BUDGET_PERCENT: u64 = 90;

/// Time one streaming tick needs with `chips` on the chain, ns: the
/// computation before the batch starts, then the batch on the bus (the
/// pipelined tick absorbs the replies at the next tick).
pub const fn tick_need_ns(chips: usize) -> u64 {
    let n = chips as u64;
    let bytes_ns = n * 8 * 1_000_000_000 / CHAIN_SPI_HZ;
    COMPUTE_NS_FIXED + n * COMPUTE_NS_PER_AXIS + STREAM_WINDOWS * (bytes_ns + WINDOW_OVERHEAD_NS)
}

/// The fastest rate at most `hz` whose period holds a streaming tick of
/// `chips` within [`BUDGET_PERCENT`], halving from `hz` (a period that
/// stays a whole number of µs), down to [`HZ_MIN`]. A tick that does not fit
/// is skipped as an overrun, and every skipped tick is a tick of time the
/// profile loses: a box must not run its motors slow, so it runs slower
/// ticks instead and says so.
pub const fn fit(hz: u32, chips: usize) -> Rate {
    fit_need(hz, tick_need_ns(chips))
}

/// [`fit`] for a tick that needs `need` ns (a platform whose tick costs
/// something else than [`tick_need_ns`] says: the QEMU image's simulated
/// chips).
pub const fn fit_need(hz: u32, need: u64) -> Rate {
    let mut h = hz;
    loop {
        let us = 1_000_000 / h;
        let fits = need * 100 <= (us as u64) * 1000 * BUDGET_PERCENT;
        let next = h / 2;
        if fits || next < HZ_MIN || 1_000_000 % next != 0 {
            return Rate {
                hz: h,
                us,
                derated: h != hz,
            };
        }
        h = next;
    }
}

/// The control loop's count of ticks as the bridge's millisecond clock and
/// the 10 Hz housekeeping cadence, without a division per tick (a 64-bit
/// division is a library call on the Cortex-M4): the period's µs are
/// accumulated, and the cadence counts down from a length worked out once.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TickClock {
    period_us: u32,
    /// µs past the last whole millisecond (< 1000).
    us: u32,
    ms: u64,
    housekeeping_every: u32,
    housekeeping_in: u32,
}

impl TickClock {
    pub const fn new(rate: Rate) -> TickClock {
        let every = if rate.hz / 10 == 0 { 1 } else { rate.hz / 10 };
        TickClock {
            period_us: rate.us,
            us: 0,
            ms: 0,
            housekeeping_every: every,
            housekeeping_in: every,
        }
    }

    /// One tick: the bridge's time after it, ms (`ticks · period / 1000`,
    /// rounded down), and whether the 10 Hz housekeeping is due.
    pub fn tick(&mut self) -> (u64, bool) {
        self.us = self.us.saturating_add(self.period_us);
        while self.us >= 1000 {
            self.us -= 1000;
            self.ms = self.ms.saturating_add(1);
        }
        self.housekeeping_in -= 1;
        let due = self.housekeeping_in == 0;
        if due {
            self.housekeeping_in = self.housekeeping_every;
        }
        (self.ms, due)
    }
}

#[cfg(test)]
mod tick_clock_tests {
    use super::*;

    /// What the control loop computed before, with a division per tick.
    fn by_division(rate: Rate, ticks: u64) -> (u64, bool) {
        (
            ticks * u64::from(rate.us) / 1000,
            ticks % (u64::from(rate.hz) / 10).max(1) == 0,
        )
    }

    #[test]
    fn the_clock_and_the_cadence_equal_the_divisions_at_every_rate() {
        for hz in [500, 1000, 2000, 2500, 5000] {
            let rate = fit(hz, 0);
            let mut c = TickClock::new(rate);
            for ticks in 1..=25_000u64 {
                assert_eq!(c.tick(), by_division(rate, ticks), "{hz} Hz, tick {ticks}");
            }
        }
    }

    #[test]
    fn housekeeping_is_due_ten_times_a_second() {
        let mut c = TickClock::new(fit(2500, 0));
        let due = (0..2500).filter(|_| c.tick().1).count();
        assert_eq!(due, 10);
    }
}

#[cfg(test)]
mod fit_tests {
    use super::*;

    #[test]
    fn eight_chips_fit_1_and_2_khz() {
        assert_eq!(
            fit(1000, 8),
            Rate {
                hz: 1000,
                us: 1000,
                derated: false
            }
        );
        assert_eq!(
            fit(2000, 8),
            Rate {
                hz: 2000,
                us: 500,
                derated: false
            }
        );
    }

    #[test]
    fn eight_chips_at_5_khz_run_at_2_5_khz() {
        // 5 k + 100 k + 5 · (24 381 + 2 190) ≈ 238 µs > 90 % of 200 µs.
        assert!(tick_need_ns(8) > 180_000);
        assert_eq!(
            fit(5000, 8),
            Rate {
                hz: 2500,
                us: 400,
                derated: true
            }
        );
    }

    #[test]
    fn four_chips_fit_5_khz() {
        assert!(tick_need_ns(4) <= 180_000);
        assert_eq!(
            fit(5000, 4),
            Rate {
                hz: 5000,
                us: 200,
                derated: false
            }
        );
    }

    #[test]
    fn another_cost_fits_the_same_way() {
        assert_eq!(fit_need(5000, tick_need_ns(8)), fit(5000, 8));
        // 200 µs does not fit 90 % of 200 µs, it fits 400 µs.
        assert_eq!(fit_need(5000, 200_000).hz, 2500);
        assert_eq!(fit_need(1000, 200_000).hz, 1000);
        assert!(!fit_need(1000, 900_000).derated);
        assert_eq!(fit_need(1000, 900_001).hz, 500);
    }

    #[test]
    fn no_chain_never_derates() {
        assert_eq!(fit(10_000, 0).hz, 10_000);
    }

    #[test]
    fn a_rate_that_cannot_halve_to_a_whole_period_stays() {
        // 10 kHz with 8 chips: 5 kHz no, 2.5 kHz yes.
        assert_eq!(fit(10_000, 8).hz, 2500);
        // 500 Hz is the floor.
        assert_eq!(fit(500, 8).hz, 500);
    }
}
