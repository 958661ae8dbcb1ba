//! stepbridge logic: every behaviour of the bridge, with no HAL, no RTIC and
//! no allocation, so the same code runs on the STM32F405 and in `cargo test`.
//!
//! Layers, each depending only on the layers listed before it:
//! * [`powerstep`] — powerSTEP01 register map, commands, STATUS, units, and
//!   the daisy-chain owner that schedules every SPI byte.
//! * [`motion`] — the trapezoidal profile generator and the axis output
//!   stage (setpoints → chain commands, read-back, landing, chip setup).
//! * [`postep60`] — one emulated PoStep60 per axis: settings, modes, faults,
//!   currents, the persistence image.
//! * [`transport`] — bytes ↔ PoStep60 commands for each bus (I2C, Modbus
//!   RTU); knows no hardware and not the bridge.
//! * [`persist`] — the power-cut-safe settings store over any NOR flash.
//! * [`rate`] — the control-tick rate (build setting `STEPBRIDGE_TICK_HZ`).
//! * [`bridge`] — the object the firmware owns: `tick(now)` for the control
//!   loop, requests and queries for the buses, and the adapters that connect
//!   each transport to the device models.
//!
//! The simulated hardware (powerSTEP01 chips and chain, the I/O extension's
//! shift registers) is its own crate, `stepbridge-sim`, which does not
//! depend on this one; the simulated flash is the settings store's (feature
//! `sim`).
#![cfg_attr(not(test), no_std)]
// Tests are not bus input: they may index, unwrap and panic.
#![cfg_attr(
    test,
    allow(
        clippy::indexing_slicing,
        clippy::arithmetic_side_effects,
        clippy::unwrap_used,
        clippy::expect_used,
        clippy::panic
    )
)]

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
