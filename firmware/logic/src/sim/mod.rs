//! Byte-accurate powerSTEP01 simulator (feature `sim`), `no_std`, no allocation.
//!
//! * [`powerstep01`] — one chip: SPI parser and responses, registers, STATUS
//!   flags, the motion engine integrated exactly in chip units, SW input and
//!   fault injection. Its module docs list what is guaranteed and which
//!   behaviours are modelling choices.
//! * [`chain`] — N chips wired as one daisy-chain shift register, usable as
//!   the [`ChainBus`](crate::powerstep::ChainBus) of a
//!   [`Chain`](crate::powerstep::Chain).
//!
//! The settings store's simulated flash is `settings_store::sim` (re-exported
//! here), the virtual clock of simulated control loops is host-tests'
//! `clock`.
//! * [`shift`] — 74HC165/74HC595 shift registers on the I/O extension's SPI port.

// A test double (tests, host-tests, the QEMU image): it models a chip on its
// own bounded state and reads no untrusted input.
#![allow(
    clippy::indexing_slicing,
    clippy::arithmetic_side_effects,
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::panic
)]

pub mod chain;
pub mod powerstep01;
pub mod shift;

pub use chain::SimChain;
pub use powerstep01::{Fault, HomeCam, Powerstep01, TICK_NS};
pub use settings_store::sim as flash;
pub use settings_store::sim::{SimFlash, SimFlashError};
pub use shift::{ConsoleCommand, ConsoleLine, ShiftChain};
