//! The powerSTEP01 driver layer: everything about the chip and the SPI daisy
//! chain — register map, commands, STATUS, units, chain framing and the
//! pipeline contract of a chain driver — and nothing about PoStep60,
//! transports or motion. It imports no other stepbridge crate.
#![cfg_attr(not(test), no_std)]
// Tests are not bus input: they may index, unwrap and panic.
#![cfg_attr(test, allow(clippy::indexing_slicing, clippy::arithmetic_side_effects))]
#![cfg_attr(test, allow(clippy::unwrap_used, clippy::expect_used, clippy::panic))]

pub mod chain;
pub mod commands;
pub mod fields;
pub mod registers;
pub mod status;
pub mod units;

pub use chain::{
    Batch, BatchState, Chain, ChainBus, ChainError, Plan, Replies, Reply, MAX_DEVICES,
};
pub use commands::{Command, Direction, SwitchAction};
pub use fields::{Config, DriveMode, StepMode, StepSel};
pub use registers::{Access, Register};
pub use status::{MotorStatus, Status, ThermalStatus};
