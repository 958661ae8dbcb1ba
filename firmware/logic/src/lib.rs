//! stepbridge logic: every behaviour of the bridge, with no HAL, no RTIC and
//! no allocation, so the same code runs on the STM32F405 and in `cargo test`.
//!
//! Layers (each depends only on the ones above it in this list):
//! * [`powerstep`] — powerSTEP01 register map, commands, STATUS, units, and
//!   the daisy-chain owner that schedules every SPI byte.
//! * [`motion`] — trapezoidal profile generator (and axis output stage).
//! * `sim` (feature `sim`) — a byte-accurate powerSTEP01 and chain model used
//!   by host tests and by the QEMU image.
//!
//! Later layers (motion, postep, transport, bridge) are listed as missing in
//! the README until they exist.
#![cfg_attr(not(test), no_std)]
#![forbid(unsafe_code)]
#![warn(missing_debug_implementations)]

pub mod bridge;
pub mod motion;
pub mod persist;
pub mod postep60;
pub mod powerstep;
pub mod transport;

// The simulator is built for this crate's own tests and, with the `sim`
// feature, for host-tests and the QEMU image.
#[cfg(any(test, feature = "sim"))]
pub mod sim;

/// The layer's name before it became [`postep60`]; kept only until the
/// firmware crate's platform split lands (it still imports `postep`).
#[doc(hidden)]
pub use postep60 as postep;
