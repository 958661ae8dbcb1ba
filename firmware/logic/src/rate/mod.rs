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
    /// The tick runs overlapped (`Bridge::tick_overlapped`: the batch on
    /// the bus while the next is planned, a command one tick later): the
    /// computation and the batch in a row do not fit the period, the
    /// longer of the two does.
    pub overlapped: bool,
    /// The most CS windows a batch may take at this rate (a streaming
    /// batch is [`STREAM_WINDOWS`]; a longer one, e.g. a move's start
    /// with its register writes, must fit the period too: the axes send
    /// the rest at the next ticks).
    pub windows: u8,
}

/// What a streaming tick needs, ns, run in a row (the pipelined tick: the
/// computation, then the batch) and overlapped (the longer of the two),
/// and what sizes a batch: one CS window on this chain and, overlapped,
/// the time before the batch starts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Need {
    pub serial_ns: u64,
    pub overlapped_ns: u64,
    /// One window of the chain (0: the platform's batch is not timed by
    /// windows).
    pub window_ns: u64,
    pub launch_ns: u64,
}

impl Need {
    /// A platform whose tick cannot overlap (the QEMU image clocks its
    /// simulated chips on the CPU): both the same, batches not limited.
    pub const fn serial(ns: u64) -> Need {
        Need {
            serial_ns: ns,
            overlapped_ns: ns,
            window_ns: 0,
            launch_ns: 0,
        }
    }

    /// The most windows a batch may take in a period of `us` µs.
    const fn windows(&self, us: u32, overlapped: bool) -> u8 {
        if self.window_ns == 0 {
            return MAX_BATCH_WINDOWS;
        }
        let budget = us as u64 * 10 * BUDGET_PERCENT;
        let fixed = if overlapped {
            self.launch_ns
        } else {
            self.serial_ns
                .saturating_sub(STREAM_WINDOWS as u64 * self.window_ns)
        };
        let w = budget.saturating_sub(fixed) / self.window_ns;
        if w > MAX_BATCH_WINDOWS as u64 {
            MAX_BATCH_WINDOWS
        } else if w < STREAM_WINDOWS as u64 {
            STREAM_WINDOWS as u8
        } else {
            w as u8
        }
    }
}

/// The most windows the chain layer lays out in one batch
/// (`powerstep::chain::MAX_WINDOWS`).
pub const MAX_BATCH_WINDOWS: u8 = 16;

pub mod measured;

/// CS windows of a streaming batch (a read and a Run per axis).
pub const STREAM_WINDOWS: u32 = 5;
/// Share of the period the batch and the computation may take (the rest is
/// for the bus tasks and interrupt latency).
pub const BUDGET_PERCENT: u64 = 90;

/// How the chain driver times a batch (drivers-core `chain_spi`, which
/// works its own timing out with [`BusTiming::of`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BusTiming {
    /// SCK, Hz: the fastest APB2 division at most `sck_max_hz`.
    pub sck_hz: u32,
    /// TIM7's CS-high gap and CS set-up, ns (whole timer-clock periods).
    pub gap_ns: u32,
    pub setup_ns: u32,
    /// Per window besides the bytes: gap, set-up and [`WINDOW_SLACK_NS`],
    /// ns.
    pub window_ns: u32,
    /// One byte on the wire, ns (rounded up).
    pub byte_ns: u32,
}

/// Per window besides TIM7's gap and set-up: the window's three interrupts
/// at ~1 µs latency each, and the DMA request and SPI start latencies (the
/// RM0090 model with 1 µs of interrupt latency: a gap of 1 941 ns for
/// TIM7's 821, a set-up of 1 513 ns for 369; host-tests
/// `a_streaming_batch_takes_no_longer_than_the_timing_the_rate_is_fitted_to`).
pub const WINDOW_SLACK_NS: u32 = 4_000;

/// Smallest SPI baud-rate divider (2, 4, …, 256) giving at most `max_hz`,
/// and its CR1.BR code.
pub const fn sck_divider(pclk_hz: u32, max_hz: u32) -> (u32, u32) {
    let mut div = 2;
    let mut br = 0;
    while div < 256 && pclk_hz / div > max_hz {
        div *= 2;
        br += 1;
    }
    (div, br)
}

/// Clock cycles of `hz` for `ns` nanoseconds, rounded up.
pub const fn cycles(ns: u32, hz: u32) -> u32 {
    let c = (ns as u64 * hz as u64).div_ceil(1_000_000_000);
    if c > u32::MAX as u64 {
        u32::MAX
    } else {
        c as u32
    }
}

/// A one-pulse timer with ARR = `ticks` at `hz`: the pulse lasts ticks + 1
/// timer-clock periods, ns (rounded down).
const fn timer_pulse_ns(ticks: u32, hz: u32) -> u32 {
    let hz = if hz == 0 { 1 } else { hz } as u64;
    let t = (ticks as u64 + 1) * 1_000_000_000 / hz;
    if t > u32::MAX as u64 {
        u32::MAX
    } else {
        t as u32
    }
}

impl BusTiming {
    /// The timing of a chain on SPI at `pclk2_hz` (SCK at most
    /// `sck_max_hz`) with TIM7 at `timclk_hz` making a CS-high gap of at
    /// least `deselect_ns` and a set-up of at least `setup_ns`.
    pub const fn of(
        pclk2_hz: u32,
        timclk_hz: u32,
        sck_max_hz: u32,
        deselect_ns: u32,
        setup_ns: u32,
    ) -> BusTiming {
        let (div, _) = sck_divider(pclk2_hz, sck_max_hz);
        let sck_hz = pclk2_hz / div;
        let gap_ns = timer_pulse_ns(cycles(deselect_ns, timclk_hz), timclk_hz);
        let setup_ns = timer_pulse_ns(cycles(setup_ns, timclk_hz), timclk_hz);
        let byte = 8_000_000_000u64.div_ceil(if sck_hz == 0 { 1 } else { sck_hz } as u64);
        BusTiming {
            sck_hz,
            gap_ns,
            setup_ns,
            window_ns: gap_ns
                .saturating_add(setup_ns)
                .saturating_add(WINDOW_SLACK_NS),
            byte_ns: if byte > u32::MAX as u64 {
                u32::MAX
            } else {
                byte as u32
            },
        }
    }

    /// A batch of `windows` windows on `chips` chips, ns.
    pub const fn batch_ns(&self, windows: u32, chips: u32) -> u64 {
        windows as u64 * (self.window_ns as u64 + chips as u64 * self.byte_ns as u64)
    }
}

/// The board's chain (`platform/stm32f405.rs`'s clocks: APB2 84 MHz, TIM7
/// at 84 MHz; the driver's limits: SCK ≤ 4 MHz, t_disCS 800 ns, t_setCS
/// 350 ns). The firmware asks its driver instead; host-tests checks that
/// the driver on the RM0090 model at these clocks says the same.
pub const BOARD_BUS: BusTiming = BusTiming::of(84_000_000, 84_000_000, 4_000_000, 800, 350);

/// `cycles` of the measured core clock ([`measured::SYSCLK_HZ`]), ns
/// (rounded up).
const fn cycles_ns(cycles: u64) -> u64 {
    (cycles * 1_000_000_000).div_ceil(measured::SYSCLK_HZ as u64)
}

/// The tick's computation for `chips` axes, ns: the measured cycles of the
/// worst 8-axis tick ([`measured`]: every axis starting a move at once;
/// the costlier of the 1 and 5 kHz builds) per axis, plus the chain
/// driver's start and hand-over. A chain fitted to it holds every tick.
pub const fn compute_ns(chips: usize) -> u64 {
    let t1 = measured::TICK_CYCLES_8_AXES_1KHZ as u64;
    let t5 = measured::TICK_CYCLES_8_AXES_5KHZ as u64;
    let per_axis = (if t1 > t5 { t1 } else { t5 }).div_ceil(8);
    let cycles = chips as u64 * per_axis + measured::CHAIN_DRIVER_TICK_CYCLES as u64;
    cycles_ns(cycles)
}

/// Time one streaming tick needs with `chips` on a chain timed by `bus`,
/// ns: the computation before the batch starts, then the batch on the bus
/// (the pipelined tick absorbs the replies at the next tick).
pub const fn tick_need_ns_on(chips: usize, bus: BusTiming) -> u64 {
    compute_ns(chips) + bus.batch_ns(STREAM_WINDOWS, chips as u32)
}

/// [`tick_need_ns_on`] the board's chain ([`BOARD_BUS`]).
pub const fn tick_need_ns(chips: usize) -> u64 {
    tick_need_ns_on(chips, BOARD_BUS)
}

/// From the control tick's interrupt to its batch's start, besides the
/// chain driver's hand-over and start (in
/// [`measured::CHAIN_DRIVER_TICK_CYCLES`]): the interrupt's entry, the
/// watchdog's feed and the tick clock, ~100 instructions (an estimate
/// with room: 2 µs are 336 cycles).
pub const LAUNCH_SLACK_NS: u64 = 2_000;

/// From the control tick's interrupt to its batch's start, ns: the chain
/// driver's hand-over and start ([`measured::CHAIN_DRIVER_TICK_CYCLES`])
/// and [`LAUNCH_SLACK_NS`].
pub const fn launch_ns() -> u64 {
    cycles_ns(measured::CHAIN_DRIVER_TICK_CYCLES as u64) + LAUNCH_SLACK_NS
}

/// Time one overlapped streaming tick needs with `chips` on a chain timed
/// by `bus`, ns: the longer of the computation (with the chain driver's
/// interrupts, which preempt it) and the batch (started at the tick's
/// beginning, after the driver's hand-over and start).
pub const fn overlapped_need_ns_on(chips: usize, bus: BusTiming) -> u64 {
    let isr = cycles_ns(measured::CHAIN_DRIVER_ISR_CYCLES as u64);
    let compute = compute_ns(chips) + if chips == 0 { 0 } else { isr };
    let batch = launch_ns() + bus.batch_ns(STREAM_WINDOWS, chips as u32);
    if compute > batch {
        compute
    } else {
        batch
    }
}

/// Both needs of a streaming tick of `chips` on a chain timed by `bus`.
pub const fn need_on(chips: usize, bus: BusTiming) -> Need {
    Need {
        serial_ns: tick_need_ns_on(chips, bus),
        overlapped_ns: overlapped_need_ns_on(chips, bus),
        window_ns: bus.batch_ns(1, chips as u32),
        launch_ns: launch_ns(),
    }
}

/// [`need_on`] the board's chain ([`BOARD_BUS`]).
pub const fn need(chips: usize) -> Need {
    need_on(chips, BOARD_BUS)
}

/// The fastest rate at most `hz` whose period holds a streaming tick of
/// `chips` within [`BUDGET_PERCENT`], halving from `hz` (a period that
/// stays a whole number of µs), down to [`HZ_MIN`]: at each rate the
/// pipelined tick if it fits (a command reaches the chip at the next
/// tick), else the overlapped one (one tick later). A tick that does not
/// fit is skipped as an overrun, and every skipped tick is a tick of time
/// the profile loses: a box must not run its motors slow, so it runs
/// slower ticks instead and says so.
pub const fn fit(hz: u32, chips: usize) -> Rate {
    fit_need(hz, need(chips))
}

/// [`fit`] for a tick that needs `need` (a platform whose tick costs
/// something else than [`need`] says: the QEMU image's simulated chips).
pub const fn fit_need(hz: u32, need: Need) -> Rate {
    let mut h = hz;
    loop {
        let us = 1_000_000 / h;
        let budget = (us as u64) * 1000 * BUDGET_PERCENT;
        let serial = need.serial_ns * 100 <= budget;
        let overlapped = !serial && need.overlapped_ns * 100 <= budget;
        let next = h / 2;
        if serial || overlapped || next < HZ_MIN || 1_000_000 % next != 0 {
            return Rate {
                hz: h,
                us,
                derated: h != hz,
                overlapped,
                windows: need.windows(us, overlapped),
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

    /// A rate's hz, period, derating and overlap.
    fn shape(r: Rate) -> (u32, u32, bool, bool) {
        (r.hz, r.us, r.derated, r.overlapped)
    }

    #[test]
    fn a_batch_may_take_what_the_period_leaves() {
        // 8 chips at 5 kHz, overlapped: (180 − 5.8) µs / 29.6 µs per window.
        assert_eq!(fit(5000, 8).windows, 5);
        // 4 chips at 5 kHz in a row: (180 − ~48) µs / 17.4 µs.
        assert_eq!(fit(5000, 4).windows, 7);
        // 1 kHz: every batch the chain layer can lay out.
        assert_eq!(fit(1000, 8).windows, MAX_BATCH_WINDOWS);
        // A platform that does not time windows: no limit.
        assert_eq!(
            fit_need(5000, Need::serial(10_000)).windows,
            MAX_BATCH_WINDOWS
        );
    }

    #[test]
    fn eight_chips_fit_1_and_2_khz() {
        assert_eq!(shape(fit(1000, 8)), (1000, 1000, false, false));
        assert_eq!(shape(fit(2000, 8)), (2000, 500, false, false));
    }

    #[test]
    fn eight_chips_at_5_khz_run_overlapped() {
        // ~113 µs of computation (the worst tick) + 5 · (24 384 + 5 190) ns ≈ 261 µs > 90 % of 200 µs,
        // the longer of the two (the batch, ~152 µs) < 180 µs.
        assert!(tick_need_ns(8) > 180_000);
        assert!(need(8).overlapped_ns <= 180_000);
        assert_eq!(shape(fit(5000, 8)), (5000, 200, false, true));
    }

    #[test]
    fn four_chips_fit_5_khz_in_a_row() {
        assert!(tick_need_ns(4) <= 180_000);
        assert_eq!(shape(fit(5000, 4)), (5000, 200, false, false));
    }

    #[test]
    fn another_cost_fits_the_same_way() {
        assert_eq!(fit_need(5000, need(8)), fit(5000, 8));
        // 200 µs does not fit 90 % of 200 µs, it fits 400 µs.
        assert_eq!(fit_need(5000, Need::serial(200_000)).hz, 2500);
        assert_eq!(fit_need(1000, Need::serial(200_000)).hz, 1000);
        assert!(!fit_need(1000, Need::serial(900_000)).derated);
        assert_eq!(fit_need(1000, Need::serial(900_001)).hz, 500);
        // Overlapped only when the row does not fit.
        let both = Need {
            serial_ns: 250_000,
            overlapped_ns: 150_000,
            ..Need::serial(0)
        };
        assert_eq!(shape(fit_need(5000, both)), (5000, 200, false, true));
        assert!(!fit_need(2000, both).overlapped);
    }

    #[test]
    fn the_overlapped_need_is_the_longer_of_computation_and_batch() {
        for chips in 1..=8 {
            let n = need(chips);
            assert!(n.overlapped_ns < n.serial_ns, "{chips} chips");
            assert!(n.overlapped_ns >= compute_ns(chips));
            assert!(n.overlapped_ns >= BOARD_BUS.batch_ns(STREAM_WINDOWS, chips as u32));
        }
    }

    #[test]
    fn the_fastest_rate_of_each_chain_length_in_a_5_khz_build() {
        // The measured cost (rate/measured.rs) on the board's bus
        // (docs/performance.md, "the control tick", states this table).
        let hz: [(u32, bool); 8] = core::array::from_fn(|k| {
            let r = fit(5000, k + 1);
            (r.hz, r.overlapped)
        });
        let (row, over) = ((5000, false), (5000, true));
        assert_eq!(hz, [row, row, row, row, row, over, over, over]);
    }

    #[test]
    fn the_fastest_rate_of_each_chain_length_in_a_10_khz_build() {
        let hz: [(u32, bool); 8] = core::array::from_fn(|k| {
            let r = fit(10_000, k + 1);
            (r.hz, r.overlapped)
        });
        let (row, over) = ((10_000, false), (10_000, true));
        let half = ((5000, false), (5000, true));
        assert_eq!(hz, [row, row, over, half.0, half.0, half.1, half.1, half.1]);
    }

    #[test]
    fn the_board_bus_is_2_625_mhz_with_tim7_gaps_of_whole_cycles() {
        assert_eq!(BOARD_BUS.sck_hz, 2_625_000);
        // 68 + 1 and 30 + 1 periods of 84 MHz.
        assert_eq!((BOARD_BUS.gap_ns, BOARD_BUS.setup_ns), (821, 369));
        assert_eq!(BOARD_BUS.byte_ns, 3048);
    }

    #[test]
    fn no_chain_never_derates() {
        assert_eq!(fit(10_000, 0).hz, 10_000);
    }

    #[test]
    fn a_rate_that_cannot_halve_to_a_whole_period_stays() {
        // 10 kHz with 8 chips: 5 kHz (overlapped).
        assert_eq!(fit(10_000, 8).hz, 5000);
        // A tick that fits no rate ends at the last halving above the
        // floor: 10 kHz → … → 625 Hz (312.5 Hz is below 500).
        assert_eq!(fit_need(10_000, Need::serial(10_000_000)).hz, 625);
        // 500 Hz is the floor.
        assert_eq!(fit(500, 8).hz, 500);
    }
}
