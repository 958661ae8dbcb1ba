//! The powerSTEP01 layer: everything about the chip and the SPI daisy chain,
//! nothing about PoStep60 or transports.

pub mod chain;
pub mod commands;
pub mod fields;
pub mod registers;
pub mod status;
pub mod units;

pub use chain::{Batch, Chain, ChainBus, ChainError, Plan, Replies, Reply, MAX_DEVICES};
pub use commands::{Command, Direction, SwitchAction};
pub use fields::{Config, DriveMode, StepMode, StepSel};
pub use registers::{Access, Register};
pub use status::{MotorStatus, Status, ThermalStatus};
