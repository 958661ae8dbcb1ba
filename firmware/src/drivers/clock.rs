//! Time for the bus drivers: the SysTick monotonic [`Mono`] and µs
//! timestamps ([`now_us`]) for the Modbus RTU server.
//!
//! # What it guarantees
//!
//! * [`Mono`] ticks at [`MONO_HZ`] = 10 kHz with a 64-bit count (it never
//!   wraps): `Mono::delay_until` wakes a task at the first tick at or after
//!   the instant, i.e. at most 100 µs late (plus interrupt latency). The
//!   SysTick backend of rtic-monotonics interrupts on every tick, so the rate
//!   is a trade: 10 kHz costs ~1 % of the CPU at 168 MHz, while µs ticks
//!   would interrupt every 168 cycles and starve everything else (on the
//!   board and under QEMU alike).
//! * [`now_us`] still has 1 µs resolution: the tick count plus the cycles the
//!   SysTick counter has run since the tick began. It never goes back.
//! * [`instant_at_us`] maps a [`now_us`] time onto the monotonic, rounded up,
//!   so a task never wakes before the time it asked for.
//!
//! # Assumptions
//!
//! * `Mono::start` was called once (in `init`) with the SysTick input clock:
//!   the real SYSCLK on the board, 168 MHz under QEMU (whose SysTick counts at
//!   168 MHz whatever the clock tree says). Both are multiples of 10 kHz.
//! * Nothing else reads SYST_CSR (its COUNTFLAG is clear-on-read and belongs
//!   to the monotonic).

use cortex_m::interrupt;
use cortex_m::peripheral::SYST;
use rtic_monotonics::systick::prelude::*;

/// Monotonic tick rate.
pub const MONO_HZ: u32 = 10_000;
/// µs per monotonic tick.
const US_PER_TICK: u64 = 1_000_000 / MONO_HZ as u64;

systick_monotonic!(Mono, 10_000);
const _: () = assert!(
    MONO_HZ == 10_000,
    "the macro takes a literal: keep both in step"
);

/// An instant of [`Mono`].
pub type Instant = <Mono as rtic_monotonics::TimerQueueBasedMonotonic>::Instant;

/// µs since `Mono::start` (see the module docs).
pub fn now_us() -> u64 {
    // Interrupts off: SysTick cannot count a wrap between the two reads of
    // `now`, only `now` itself can (COUNTFLAG), which the loop catches.
    interrupt::free(|_| loop {
        let before = Mono::now().as_ticks();
        let current = SYST::get_current();
        let after = Mono::now().as_ticks();
        // A wrap between the two reads: `current` may belong to either tick,
        // so read again (at most once per 100 µs, and the reads take < 1 µs).
        if before == after {
            let reload = SYST::get_reload();
            let elapsed = u64::from(reload.saturating_sub(current));
            // elapsed ≤ reload < 2^24: the product and the sum stay in u64.
            #[allow(clippy::arithmetic_side_effects)]
            let sub_us = (elapsed * US_PER_TICK / (u64::from(reload) + 1)).min(US_PER_TICK - 1);
            return before.saturating_mul(US_PER_TICK).saturating_add(sub_us);
        }
    })
}

/// The monotonic instant of `us` (a [`now_us`] time), rounded up to a tick.
pub fn instant_at_us(us: u64) -> Instant {
    Instant::from_ticks(us.div_ceil(US_PER_TICK))
}
