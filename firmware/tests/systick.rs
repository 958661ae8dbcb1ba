//! The SysTick monotonic (`drivers::clock`) on the target: the rate the
//! platform claims (`platform::systick_hz`: SYSCLK on the board, 168 MHz
//! under QEMU whatever the clocks say), µs stamps that never go back, and
//! wake-up instants rounded up. Board and QEMU (`cargo qemu-test`).
#![cfg_attr(target_os = "none", no_std, no_main)]
// An on-target test, not bus input: it may index, unwrap, panic and (like
// the drivers) touch registers in `unsafe` blocks.
#![allow(unsafe_code, clippy::indexing_slicing, clippy::arithmetic_side_effects)]
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
#[cfg(not(target_os = "none"))]
fn main() {}

#[cfg(target_os = "none")]
mod common;

#[cfg(target_os = "none")]
#[defmt_test::tests]
mod tests {
    use cortex_m::peripheral::SYST;
    use firmware::drivers::clock::{self, Mono};
    use firmware::platform;
    use rtic_monotonics::Timebase;

    use super::common::{self, Target};

    #[init]
    fn init() -> Target {
        common::setup()
    }

    #[test]
    fn reload_gives_the_10_khz_monotonic(t: &mut Target) {
        let per_tick = SYST::get_reload() + 1;
        defmt::assert_eq!(per_tick, t.systick_hz / clock::MONO_HZ);
    }

    #[test]
    fn now_us_never_goes_back() {
        let mut last = clock::now_us();
        for _ in 0..200_000 {
            let now = clock::now_us();
            defmt::assert!(now >= last, "{=u64} after {=u64}", now, last);
            last = now;
        }
    }

    #[test]
    fn now_us_lies_within_the_monotonic_tick() {
        for _ in 0..1_000 {
            let before = Mono::now().as_ticks();
            let us = clock::now_us();
            let after = Mono::now().as_ticks();
            defmt::assert!(us >= before * 100 && us < (after + 1) * 100);
        }
    }

    #[test]
    fn instant_at_us_rounds_up_to_a_tick() {
        for (us, ticks) in [
            (0, 0),
            (1, 1),
            (99, 1),
            (100, 1),
            (101, 2),
            (1_000_000, 10_000),
        ] {
            defmt::assert_eq!(clock::instant_at_us(us).as_ticks(), ticks);
        }
    }

    /// One second of `now_us` is one second of a clock that is not SysTick
    /// (the DWT cycle counter on the board, the host clock under QEMU): ±3 %
    /// for the measurement, plus the lag the platform admits (QEMU's).
    #[test]
    fn systick_counts_at_the_platform_rate(t: &mut Target) {
        let reference_us = platform::measure_us(t.sysclk_hz, || common::spin_us(1_000_000));
        defmt::info!(
            "1 s of the monotonic = {=u64} us of the reference",
            reference_us
        );
        let max = 1_030_000 + 10_000 * platform::SYSTICK_LAG_MAX_PERCENT;
        defmt::assert!((970_000..=max).contains(&reference_us));
    }
}
