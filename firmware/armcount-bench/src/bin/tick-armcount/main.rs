//! The control tick's CPU work on the real target (thumbv7em, release),
//! region by region, between marker functions that `cargo xtask tick-cpu`
//! hands to the armcount plugin (tools/armcount). The workload is `cargo
//! xtask bench`'s (host-tests/src/bin/bench-tick.rs): 8 axes (logical
//! step modes 1/1 … 1/256 on 1/128 chips) streaming long moves against 8
//! simulated powerSTEP01s.
//!
//! Counters: 1 `AxisGroup::prepare` (plan: profile generator, setpoints,
//! schedule and encode), 2 `Chain::begin` and `Chain::clock` without the
//! simulated bus (the window loop), 3 `AxisGroup::tick_end` (decode and
//! absorb the replies), 4 one `Profile::tick` of a long move, 5 an empty
//! marker pair (calibration).
//! The simulated chips' own work (the bus window and the chip physics) is
//! outside every counter.
//!
//! The image is `image.rs`, built for the target only (`cargo xtask
//! tick-cpu`); on the host this bin is an empty `main`.
#![cfg_attr(target_os = "none", no_std, no_main)]

/// The 8 axes against simulated chips, their markers and the measured loops
/// (the panic handler and `__pre_init` are the library's, src/lib.rs).
#[cfg(target_os = "none")]
mod image;

#[cfg(not(target_os = "none"))]
fn main() {}
