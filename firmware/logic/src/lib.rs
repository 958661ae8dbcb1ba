//! stepbridge logic: every behaviour of the bridge, with no HAL, no RTIC and
//! no allocation, so the same code runs on the STM32F405 and in `cargo test`.
//!
//! Layers, bottom up; each module imports only modules of the rows above
//! it (`host-tests/tests/layers.rs` reads the sources and fails otherwise):
//!
//! | layer | modules | what |
//! |---|---|---|
//! | 0 | [`powerstep`], [`persist`] (crates of their own), [`rate`] | the powerSTEP01 driver and chain scheduler; the power-cut-safe settings store; the control-tick rate (build setting `STEPBRIDGE_TICK_HZ`) |
//! | 1 | [`motion`], [`ioext`] | the profile generator and the axis output stage (setpoints → chain commands, read-back, landing, chip set-up, homing); the Copley-style SPI I/O extension |
//! | 2 | [`postep60`], [`ext_space`] | one emulated PoStep60 per axis (settings, modes, faults, currents, the persistence image); the extension space's map, codecs and errors |
//! | 3 | [`transport`] | bytes ↔ requests for each bus (I2C, Modbus RTU, USB HID); knows no hardware and not the bridge |
//! | 4 | [`bridge`] | the object the firmware owns: `tick(now)` for the control loop, requests and queries for the buses, the extension space's behaviour |
//!
//! The simulated hardware (powerSTEP01 chips and chain, the I/O extension's
//! shift registers) is its own crate, `stepbridge-sim`, which does not
//! depend on this one; the simulated flash is the settings store's (feature
//! `sim`).
#![cfg_attr(not(test), no_std)]
// Tests are not bus input: they may index, unwrap and panic.
#![cfg_attr(test, allow(clippy::indexing_slicing, clippy::arithmetic_side_effects))]
#![cfg_attr(test, allow(clippy::unwrap_used, clippy::expect_used, clippy::panic))]

pub mod bridge;
pub mod ext_space;
pub mod ioext;
pub mod motion;
pub mod postep60;
pub mod rate;
pub mod transport;

/// The powerSTEP01 driver layer (its own crate, `powerstep01`).
pub use powerstep01 as powerstep;
/// The power-cut-safe settings store (its own crate, `settings-store`).
pub use settings_store as persist;
