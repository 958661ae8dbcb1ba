//! The control tick's measured cost, written by the benchmarks (do not edit
//! by hand): `cargo tick-cpu --write` (the tick's computation, 8 axes
//! streaming, Thumb-2 under QEMU with the flash wait states of the ART
//! model; `STEPBRIDGE_TICK_HZ=5000 cargo tick-cpu --write` for the 5 kHz
//! build) and `cargo chain-cpu --write` (the chain driver's part in the
//! control tick: a batch's start and hand-over). Every run of either bench
//! checks its figure here and fails when the code costs more than it says,
//! so [`super::fit`] never fits a rate to a cost lower than measured.

/// The core clock the cycles are counted at.
pub const SYSCLK_HZ: u32 = 168_000_000;
/// Cycles of the worst 8-axis tick (plan, profile, schedule, encode,
/// decode, absorb; every axis starting a move at once), 1 kHz build
/// (`cargo tick-cpu`: the largest of the cruise tick, the moves workload's
/// mean tick and its worst tick).
pub const TICK_CYCLES_8_AXES_1KHZ: u32 = 15_914;
/// The same, 5 kHz build (`STEPBRIDGE_TICK_HZ=5000 cargo tick-cpu`).
pub const TICK_CYCLES_8_AXES_5KHZ: u32 = 15_823;
/// The chain driver's cycles in the control tick per streaming batch of 8
/// chips: start and hand-over (`cargo chain-cpu`).
pub const CHAIN_DRIVER_TICK_CYCLES: u32 = 676;
/// The chain driver's interrupts per streaming batch of 8 chips (15: a
/// gap, a set-up and a window end per window; `cargo chain-cpu`).
pub const CHAIN_DRIVER_ISR_CYCLES: u32 = 1_715;
